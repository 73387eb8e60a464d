//! The ILFR pipeline that the methods of [`super::method`] run: reads the effect's `indirect`,
//! `glossy` or `ao` file ([`run_ilfr`]) or a `lens-time` file's camera rays ([`run_lens`]),
//! sizes the splats (§2.2), builds the hierarchy (§2.3), shrinks (§2.3.1), runs the passes of
//! recursive filtering (§4, [`super::recursive`]) if any and gathers `recon_rays` reconstruction
//! rays per pixel (Eq. 3, §3.3, §3.4; [`reconstruct_samples`]). Its notes give the time split
//! (read, splat sizing, hierarchy, shrinking, recursive filtering, reconstruction) and the counts
//! of each stage.
//!
//! The image is the quantity the harness's reference measures: for `indirect` the light the
//! primary hit reflects after at least one more bounce (albedo × reconstructed incident
//! radiance, or o's BSDF-weighted sum in glossy files; `direct` is not added), for `ao` the ambient visibility within the AO radius
//! (1 = unoccluded, 1 where the camera ray escaped); on camera rays, the radiance through pixel,
//! lens and shutter.

use std::time::Instant;

use sampleio::SampleFile;

use super::bvh::DiscBvh;
use super::cache::CacheParams;
use super::disc::Disc;
use super::filter::SplatShading;
use super::gather::{gather_with_spread, rays_per_hit, GatherSettings, GatherStats};
use super::lens::gather_lens;
use super::lens::read_primary_rays;
use super::neighbours::KdTree;
use super::prefilter::{prefiltered_radiance, PrefilterParams};
use super::reconstruct::Reconstructor;
use super::reconstruct::{NearestSplat, RayModel};
use super::recursive::{recursive_pass, RecursiveSettings, RecursiveStats};
use super::robust::{robust_radiance_with_juries, RobustMode, RobustParams, RobustStats};
use super::samples::{read_indirect, IndirectSamples};
use super::shrink::{input_rays, scene_diagonal, shrink_splats, ShrinkParams, ShrinkStats};
use super::sparse::SparseParams;
use super::splats::{size_splats_with_juries, GatheredPoints, SplatParams, SplatStats};
use super::surfaces::SurfaceParams;
use crate::error::Error;
use crate::image::Image;
use crate::method::{Effect, Inputs, MethodError, Output, Stats};
/// Reconstructs the effect's image from its `indirect`, `glossy` or `ao` file (`ao` without
/// recursive passes) for the method `name`.
pub fn run_ilfr(name: &str, inputs: &Inputs, settings: IlfrSettings) -> Result<Output, MethodError> {
    let path = inputs.samples(name)?;
    let target = match inputs.effect {
        Effect::Indirect | Effect::Glossy => GatherTarget::Indirect,
        Effect::Ao if settings.recursive_passes == 0 => GatherTarget::Visibility { ao_radius: inputs.ao_radius },
        other => return Err(MethodError::Unsupported(format!("{name} does not reconstruct {}", other.name()))),
    };
    if !grain_choice_handles(settings.filter_grain, inputs.effect) {
        let message = format!("{name}: grain=filter applies to --effect indirect only, not {}", inputs.effect.name());
        return Err(MethodError::Unsupported(message));
    }
    let start = Instant::now();
    let file = SampleFile::open(path)?;
    let samples = read_indirect(&file)?;
    drop(file);
    let read_s = start.elapsed().as_secs_f64();
    if (samples.width, samples.height) != (inputs.width, inputs.height) {
        let message = format!(
            "{}: samples are {}x{}, the comparison is {}x{}",
            path.display(),
            samples.width,
            samples.height,
            inputs.width,
            inputs.height
        );
        return Err(Error::size_mismatch("samples", message).into());
    }
    if settings.filter_grain {
        super::grain::check_input(&samples)?;
    }
    let mut result = reconstruct_samples(&samples, target, &settings)?;
    result.timings.read_s = read_s;
    let notes = result.notes(&samples, &settings);
    let stats = result.stats();
    Ok(output(result, notes, stats))
}

/// Reconstructs defocus and motion blur (effects `dof`, `motion`, `dof-motion`) from the camera
/// rays of a `lens-time` file, the input of `tlfr`, so that both reconstruct the very same samples
/// (§3.4, [`super::lens`]), for the method `name`.
pub fn run_lens(name: &str, inputs: &Inputs, settings: IlfrSettings) -> Result<Output, MethodError> {
    if !matches!(inputs.effect, Effect::Dof | Effect::Motion | Effect::DofMotion) {
        return Err(MethodError::Unsupported(format!("{name} does not reconstruct {}", inputs.effect.name())));
    }
    let path = inputs.samples(name)?;
    let start = Instant::now();
    let file = SampleFile::open(path)?;
    let (samples, camera, ray_stats) =
        read_primary_rays(&file).map_err(|error| MethodError::Unsupported(error.to_string()))?;
    drop(file);
    let read_s = start.elapsed().as_secs_f64();
    let mut result = reconstruct_samples(&samples, GatherTarget::Lens(camera), &settings)?;
    result.timings.read_s = read_s;
    let mut notes = result.notes(&samples, &settings);
    let stats = result.stats();
    let [_, _, escaped, hits] = samples.class_counts();
    // The second note speaks of primary hits; here the input rays are the camera rays.
    notes[1] = format!(
        "{} camera rays: {hits} splats, {escaped} escaped; {} reconstruction rays per pixel; {} hits took \
         the normal of their ray (depth gradient not usable)",
        samples.len(),
        settings.recon_rays,
        ray_stats.normals_from_the_ray
    );
    Ok(output(result, notes, stats))
}

/// The method's output: the reconstruction's image and times with `notes` and `stats`.
fn output(result: Reconstructed, notes: Vec<String>, stats: Stats) -> Output {
    Output {
        image: result.image,
        preprocess_s: result.timings.preprocess_s(),
        recon_s: result.timings.recon_s(),
        external_peak_rss_mb: None,
        notes,
        stats,
    }
}

/// What the gather computes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GatherTarget {
    /// Indirect light reflected towards the camera (the harness's `indirect` layer).
    Indirect,
    /// Ambient visibility within `ao_radius` (the harness's `ao` image).
    Visibility { ao_radius: f32 },
    /// Radiance along camera rays through the pixel and the lens (§3.4; the input rays are
    /// camera rays, [`super::lens`]).
    Lens(super::lens::LensCamera),
}

/// Whether the grain choice leaves `effect` to the method: the grain filter
/// ([`super::grain`]) only takes diffuse indirect light.
pub fn grain_choice_handles(filter_grain: bool, effect: Effect) -> bool {
    !filter_grain || effect == Effect::Indirect
}

/// How [`reconstruct_samples`] runs.
#[derive(Clone, Debug, PartialEq)]
pub struct IlfrSettings {
    /// Reconstruction rays per pixel.
    pub recon_rays: u32,
    pub seed: u32,
    pub splats: SplatParams,
    pub shrink: ShrinkParams,
    pub surfaces: SurfaceParams,
    /// Outliers of the splat radiance ([`super::robust`]; indirect and glossy light only, not
    /// the lens mode).
    pub robust: RobustParams,
    /// The final gather's directions (cosine rays, and each BSDF lobe's at glossy hits) of a
    /// pixel's primary hits as one stratified set ([`GatherSettings::pixel_stratified`]);
    /// false: one set per hit.
    pub pixel_stratified: bool,
    /// Reconstruction rays start this fraction of the scene diagonal above their primary (and,
    /// recursing, secondary) hit.
    pub relative_offset: f32,
    /// Passes of recursive filtering (§4) before the final gather; 0: none.
    pub recursive_passes: u32,
    /// Reconstruction rays per secondary hit in a recursive pass.
    pub recursive_rays: u32,
    /// Filter the final gather's per-pixel grain ([`super::grain`]; diffuse indirect light).
    pub filter_grain: bool,
    /// What a reconstruction ray reads from the splats (not in the lens mode, which keeps the
    /// paper's apparent surfaces).
    pub ray_model: RayModelChoice,
    /// [`NearestSplat::visibility_scale`].
    pub visibility_scale: f32,
    /// Which neighbours a splat's filtered radiance takes ([`RayModelChoice::NearestSplat`]).
    pub prefilter: PrefilterParams,
    /// Records and interpolation for indirect light at Lambertian hits ([`super::cache`]), with
    /// [`Self::rays_per_record_ray`] × `recon_rays` rays per record; `None`: every hit gathers.
    pub cache: Option<CacheParams>,
    pub rays_per_record_ray: u32,
    /// The final gather at a sparse grid of pixels for indirect light at Lambertian hits
    /// ([`super::sparse`]); `None`: every pixel gathers.
    pub sparse: Option<SparseParams>,
}

/// [`RayModel`] as a setting.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RayModelChoice {
    /// The paper's apparent surfaces along every ray ([`RayModel::ApparentSurfaces`]).
    ApparentSurfaces,
    /// The nearest splat and its prefiltered radiance ([`RayModel::NearestSplat`]).
    NearestSplat,
}

impl RayModelChoice {
    /// The model over the splats' `radiance` (prefiltered for the nearest splat).
    fn over(self, radiance: &[[f32; 3]], visibility_scale: f32) -> RayModel<'_> {
        match self {
            RayModelChoice::ApparentSurfaces => RayModel::ApparentSurfaces,
            RayModelChoice::NearestSplat => RayModel::NearestSplat(NearestSplat { radiance, visibility_scale }),
        }
    }
}

impl Default for IlfrSettings {
    fn default() -> Self {
        IlfrSettings {
            recon_rays: 256,
            seed: 0,
            splats: SplatParams::default(),
            shrink: ShrinkParams::default(),
            surfaces: SurfaceParams::default(),
            robust: RobustParams::default(),
            pixel_stratified: true,
            relative_offset: 1e-4,
            recursive_passes: 0,
            recursive_rays: 16,
            filter_grain: false,
            ray_model: RayModelChoice::ApparentSurfaces,
            visibility_scale: 0.7,
            prefilter: PrefilterParams::default(),
            cache: None,
            rays_per_record_ray: 16,
            sparse: None,
        }
    }
}

/// Seconds per stage.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Timings {
    pub read_s: f64,
    pub sizing_s: f64,
    pub hierarchy_s: f64,
    pub shrinking_s: f64,
    /// Recursive filtering (§4), all passes.
    pub recursive_s: f64,
    /// The robust radiance of the final gather's splats ([`super::robust`]).
    pub robust_s: f64,
    /// The final gather (reconstruction rays) alone.
    pub reconstruct_s: f64,
    /// The grain filter after the gather (`grain=filter`; 0 without).
    pub grain_s: f64,
}

impl Timings {
    pub fn preprocess_s(&self) -> f64 {
        self.read_s + self.sizing_s + self.hierarchy_s + self.shrinking_s
    }

    /// Everything after the preprocess: recursive passes, robust radiance, gather, grain filter.
    pub fn recon_s(&self) -> f64 {
        self.recursive_s + self.robust_s + self.reconstruct_s + self.grain_s
    }
}

/// An image with what it took.
#[derive(Clone, Debug)]
pub struct Reconstructed {
    pub image: Image,
    pub timings: Timings,
    pub splats: usize,
    pub sizing: SplatStats,
    pub shrinking: ShrinkStats,
    pub gather: GatherStats,
    /// One entry per recursive pass.
    pub recursive: Vec<RecursiveStats>,
    /// Robust radiance ([`super::robust`]) of the final gather's splats, and the mode that
    /// applied (off for the lens mode and ambient occlusion).
    pub robust: RobustStats,
    pub robust_mode: RobustMode,
    /// The gather's settings (offset in scene units included), so that a benchmark can trace
    /// its very rays elsewhere ([`super::gather::reconstruction_rays`]).
    pub gather_settings: GatherSettings,
}

impl Reconstructed {
    /// The run's statistics as named numbers (`results.json`'s `stats`): `rays` (the final
    /// gather's), `splats`, `merged_fraction` (rays whose surface absorbed small surfaces in
    /// front of it, §2.5, over the rays that met a surface), `shrunk_fraction` (splats shrunk,
    /// §2.3.1, over all splats), per-ray walk counts (`nodes_per_ray`, `discs_tested_per_ray`,
    /// `collected_per_ray`, `surface_members_per_ray`), `no_surface_fraction`,
    /// `glossy_fraction`, `blocked_input_fraction` and the stage times in seconds.
    pub fn stats(&self) -> Stats {
        let r = &self.gather.reconstruct;
        let ratio = |n: u64, d: u64| if d == 0 { 0.0 } else { n as f64 / d as f64 };
        let t = &self.timings;
        [
            ("rays", r.rays as f64),
            ("splats", self.splats as f64),
            ("merged_fraction", ratio(r.merged_small_surfaces, r.surfaces)),
            ("shrunk_fraction", ratio(self.shrinking.shrunk_splats as u64, self.splats as u64)),
            ("dead_splat_fraction", ratio(self.shrinking.dead_splats as u64, self.splats as u64)),
            ("blocked_input_fraction", ratio(self.shrinking.blocked_rays as u64, self.shrinking.rays as u64)),
            ("nodes_per_ray", ratio(r.nodes, r.rays)),
            ("discs_tested_per_ray", ratio(r.discs_tested, r.rays)),
            ("collected_per_ray", ratio(r.collected, r.rays)),
            ("surface_members_per_ray", ratio(r.surface_members, r.surfaces)),
            ("no_surface_fraction", ratio(r.no_surface, r.rays)),
            ("glossy_fraction", ratio(r.glossy, r.rays)),
            ("outlier_fraction", ratio(self.robust.outliers as u64, self.splats as u64)),
            ("outlier_excess_fraction", self.robust.excess_fraction),
            ("sizing_s", t.sizing_s),
            ("hierarchy_s", t.hierarchy_s),
            ("shrinking_s", t.shrinking_s),
            ("recursive_s", t.recursive_s),
            ("robust_s", t.robust_s),
            ("gather_s", t.reconstruct_s),
            ("grain_filter_s", t.grain_s),
            ("cache_records", self.gather.cache.map_or(0.0, |c| c.0 as f64)),
            ("cache_uncovered_fraction", self.gather.cache.map_or(0.0, |c| ratio(c.2, c.1 + c.2))),
            ("sparse_grid_fraction", self.gather.sparse.map_or(0.0, |s| ratio(s.0, s.0 + s.1 + s.2))),
            ("sparse_refined_fraction", self.gather.sparse.map_or(0.0, |s| ratio(s.2, s.0 + s.1 + s.2))),
            ("sparse_refined_hits", self.gather.sparse.map_or(0.0, |s| s.3 as f64)),
            ("sparse_refined_by_light_hits", self.gather.sparse.map_or(0.0, |s| s.4 as f64)),
        ]
        .into_iter()
        .map(|(name, value)| (name.to_string(), value))
        .collect()
    }

    fn notes(&self, samples: &IndirectSamples, settings: &IlfrSettings) -> Vec<String> {
        let t = &self.timings;
        let r = &self.gather.reconstruct;
        let per_ray = |n: u64| n as f64 / r.rays.max(1) as f64;
        let percent = |n: u64| 100.0 * n as f64 / r.rays.max(1) as f64;
        let [camera_miss, no_ray, escaped, hit] = samples.class_counts();
        let mut notes = vec![
            format!(
                "time: read {:.3} s, splat sizing {:.3} s, hierarchy {:.3} s, shrinking {:.3} s, recursive filtering {:.3} s, \
                 robust radiance {:.3} s, reconstruction {:.3} s{}",
                t.read_s,
                t.sizing_s,
                t.hierarchy_s,
                t.shrinking_s,
                t.recursive_s,
                t.robust_s,
                t.reconstruct_s,
                if settings.filter_grain { format!(", grain filter {:.3} s", t.grain_s) } else { String::new() }
            ),
            format!(
                "{} samples: {hit} splats, {escaped} escaped, {no_ray} without a secondary ray, {camera_miss} camera misses; \
                 {} reconstruction rays per primary hit",
                samples.len(),
                rays_per_hit(settings.recon_rays, samples.spp)
            ),
            format!(
                "splat sizing: lobe levels {:?}, {} partial, {} direction-blind, {} isolated; shrinking: {} of {} rays \
                 blocked, {} splats shrunk ({} to zero)",
                self.sizing.lobe,
                self.sizing.partial,
                self.sizing.direction_blind,
                self.sizing.isolated,
                self.shrinking.blocked_rays,
                self.shrinking.rays,
                self.shrinking.shrunk_splats,
                self.shrinking.dead_splats
            ),
            format!(
                "{} rays: {:.1} nodes visited, {:.1} discs tested, {:.1} splats collected, {:.1} in the surface, {:.2}% no surface ({:.2}% sky, {:.2}% unsupported), \
                 {:.2}% small surfaces merged, {:.2}% glossy; {} primary hits without support",
                r.rays,
                per_ray(r.nodes),
                per_ray(r.discs_tested),
                per_ray(r.collected),
                per_ray(r.surface_members),
                percent(r.no_surface),
                percent(self.gather.fallbacks.sky_rays),
                percent(self.gather.fallbacks.unsupported_rays),
                percent(r.merged_small_surfaces),
                percent(r.glossy),
                self.gather.unsupported_hits
            ),
            format!(
                "robust radiance ({}): {} of {} splats judged, {} outliers, their excess {:.3}% of the splats' power",
                self.robust_mode.name(),
                self.robust.judged,
                self.splats,
                self.robust.outliers,
                100.0 * self.robust.excess_fraction
            ),
        ];
        if let Some((grid, interpolated, refined, hits, by_light)) = self.gather.sparse {
            notes.push(format!(
                "sparse gather: {grid} grid pixels gathered, {interpolated} interpolated whole, {refined} with {hits} hits \
                 refined by a gather of their own ({} for their geometry, {by_light} for their corners' disagreeing light)",
                hits - by_light
            ));
        }
        for (pass, r) in self.recursive.iter().enumerate() {
            let rays = r.reconstruct.rays.max(1) as f64;
            notes.push(format!(
                "recursive pass {}: {} rays per secondary hit, {} hits replaced, {} glossy kept (no BSDF of h in the file), {} kept without \
                 support; {:.2}% of rays no surface ({:.2}% sky, {:.2}% unsupported)",
                pass + 1,
                settings.recursive_rays,
                r.replaced,
                r.glossy_kept,
                r.unsupported_kept,
                100.0 * r.reconstruct.no_surface as f64 / rays,
                100.0 * r.fallbacks.sky_rays as f64 / rays,
                100.0 * r.fallbacks.unsupported_rays as f64 / rays,
            ));
        }
        notes
    }
}

/// Sizes, indexes and shrinks the splats of `samples` and gathers the image of `target`.
pub fn reconstruct_samples(
    samples: &IndirectSamples,
    target: GatherTarget,
    settings: &IlfrSettings,
) -> Result<Reconstructed, MethodError> {
    if target == GatherTarget::Indirect && samples.weight.is_some() && samples.primary_shading.is_none() {
        return Err(MethodError::Unsupported(format!(
            "{}: the field `weight` marks a glossy scene, but the file lacks `origin_base_color` and the other fields \
             of o's BSDF that the final gather at glossy primary hits samples (written by the tracer since \
             docs/ilfr-design.md G1): dump the samples again",
            samples.path
        )));
    }
    let failed = |error: Error| MethodError::Failed(error.in_file(&samples.path));

    // Sizing, hierarchy and shrinking, for the caller's progress bar.
    crate::progress::begin("preprocessing", 3, "steps");
    let start = Instant::now();
    let storage = GatheredPoints::from_samples(samples);
    let points = storage.points();
    // One kd-tree of the hits for the sizing and every robust-radiance pass (built once the
    // hits are known to be finite).
    points.validate().map_err(failed)?;
    let tree = KdTree::build(points.position);
    // Outliers are judged for indirect light (and in every recursive pass), not in the lens
    // mode (camera rays' radiance) or for ambient occlusion (no radiance).
    let robust = if target == GatherTarget::Indirect {
        RobustParams { alpha: settings.splats.alpha, lobe_threshold: settings.splats.lobe_threshold, ..settings.robust }
    } else {
        RobustParams { mode: RobustMode::Off, ..settings.robust }
    };
    let ray_model = match target {
        GatherTarget::Lens(_) => RayModelChoice::ApparentSurfaces,
        _ => settings.ray_model,
    };
    // The robust radiance's juries (and the prefilter's neighbours) come from the sizing's walk.
    let wants_juries = robust.mode != RobustMode::Off || ray_model == RayModelChoice::NearestSplat;
    let (sized, juries) =
        size_splats_with_juries(&tree, &points, &settings.splats, wants_juries.then(|| robust.jury_rule()))
            .map_err(failed)?;
    let sizing_s = start.elapsed().as_secs_f64();
    crate::progress::advance(1);

    let start = Instant::now();
    let motion = |k: usize| storage.motion.as_ref().map_or([0.0; 3], |m| m[k]);
    let discs: Vec<Disc> = (0..points.position.len())
        .map(|k| Disc::new(points.position[k], points.normal[k], sized.radius[k]).with_motion(motion(k)))
        .collect();
    let mut bvh = DiscBvh::build(&discs).map_err(failed)?;
    drop(discs);
    let hierarchy_s = start.elapsed().as_secs_f64();
    crate::progress::advance(1);

    let start = Instant::now();
    let rays = input_rays(samples, &storage.sample_index);
    let shrinking = shrink_splats(&mut bvh, &rays, &settings.shrink).map_err(failed)?;
    let diagonal = scene_diagonal(&bvh, &rays);
    drop(rays);
    let shrinking_s = start.elapsed().as_secs_f64();
    crate::progress::end();

    let offset = if diagonal > 0.0 { settings.relative_offset * diagonal } else { settings.relative_offset };
    let radii = bvh.area_radii();
    // Each splat's robust radiance, and for the nearest-splat model that radiance prefiltered.
    let splat_radiance = |per_sample: &[[f32; 3]]| -> Result<(Vec<[f32; 3]>, RobustStats), MethodError> {
        let raw: Vec<[f32; 3]> = storage.sample_index.iter().map(|&i| per_sample[i as usize]).collect();
        let (robust, stats) =
            robust_radiance_with_juries(&tree, &points, (&radii, &raw), &robust, juries.as_ref()).map_err(failed)?;
        match (ray_model, &juries) {
            (RayModelChoice::NearestSplat, Some(juries)) => {
                Ok((prefiltered_radiance(&points, &radii, &robust, juries, &settings.prefilter), stats))
            }
            _ => Ok((robust, stats)),
        }
    };

    // §4: each pass reconstructs at the Lambertian secondary hits from the previous radiances.
    let start = Instant::now();
    let mut recursive = Vec::new();
    let mut recursed: Option<IndirectSamples> = None;
    if settings.recursive_passes > 0 {
        if target != GatherTarget::Indirect {
            return Err(MethodError::Unsupported("recursive filtering applies to indirect light only".into()));
        }
        let mut current = samples.radiance.clone().ok_or_else(|| {
            MethodError::Failed(Error::sample_content(&samples.path, "recursive filtering needs the field `radiance`"))
        })?;
        let recursive_settings = RecursiveSettings {
            rays_per_hit: settings.recursive_rays,
            seed: settings.seed,
            offset,
            ..RecursiveSettings::default()
        };
        for _ in 0..settings.recursive_passes {
            let (radiance, _) = splat_radiance(&current)?;
            let shading =
                SplatShading { radiance: &radiance, direction: &storage.direction, kappa: storage.kappa.as_deref() };
            let reconstructor = Reconstructor {
                bvh: &bvh,
                shading,
                surfaces: settings.surfaces,
                model: ray_model.over(&radiance, settings.visibility_scale),
            };
            let (next, stats) = recursive_pass(samples, &current, &reconstructor, &recursive_settings)?;
            current = next;
            recursive.push(stats);
        }
        recursed = Some(IndirectSamples { radiance: Some(current), ..samples.clone() });
    }
    let samples = recursed.as_ref().unwrap_or(samples);
    let recursive_s = start.elapsed().as_secs_f64();

    let start = Instant::now();
    let (radiance, robust_stats) = match &samples.radiance {
        Some(r) => splat_radiance(r)?,
        None => (vec![[0.0; 3]; storage.sample_index.len()], RobustStats::default()),
    };
    let robust_s = start.elapsed().as_secs_f64();
    let start = Instant::now();
    let shading = SplatShading { radiance: &radiance, direction: &storage.direction, kappa: storage.kappa.as_deref() };
    let reconstructor = Reconstructor {
        bvh: &bvh,
        shading,
        surfaces: settings.surfaces,
        model: ray_model.over(&radiance, settings.visibility_scale),
    };
    let gather_settings = GatherSettings {
        rays_per_pixel: settings.recon_rays,
        seed: settings.seed,
        offset,
        pixel_stratified: settings.pixel_stratified,
        cache: settings.cache.map(|c| CacheParams {
            record_rays: settings.recon_rays.saturating_mul(settings.rays_per_record_ray).max(1),
            ..c
        }),
        ..GatherSettings::default()
    };
    // With each pixel's variance (indirect light only), for the grain filter.
    let gathered = match target {
        GatherTarget::Lens(camera) => {
            gather_lens(samples, &reconstructor, &camera, &gather_settings).map(|(i, s)| (i, s, Vec::new()))
        }
        GatherTarget::Indirect => match &settings.sparse {
            Some(sparse) => super::sparse::gather_indirect(samples, &reconstructor, sparse, &gather_settings),
            None => gather_with_spread(samples, &reconstructor, None, &gather_settings),
        },
        GatherTarget::Visibility { ao_radius } => {
            gather_with_spread(samples, &reconstructor, Some(ao_radius), &gather_settings)
        }
    };
    let (image, gathered, variance) = gathered.map_err(failed)?;
    let reconstruct_s = start.elapsed().as_secs_f64();
    let start = Instant::now();
    let image = match target {
        GatherTarget::Indirect if settings.filter_grain => {
            super::grain::filter_grain(samples, &image, &variance).map_err(failed)?
        }
        _ => image,
    };
    let grain_s = start.elapsed().as_secs_f64();
    Ok(Reconstructed {
        image,
        timings: Timings {
            read_s: 0.0,
            sizing_s,
            hierarchy_s,
            shrinking_s,
            recursive_s,
            robust_s,
            reconstruct_s,
            grain_s,
        },
        splats: bvh.len(),
        sizing: sized.stats,
        shrinking,
        gather: gathered,
        recursive,
        robust: robust_stats,
        robust_mode: robust.mode,
        gather_settings,
    })
}

#[cfg(test)]
pub(crate) mod tests;
