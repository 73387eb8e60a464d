//! `ilfr` as a `lfr compare` method (effects `indirect`, `glossy` and `ao`): reads the effect's `indirect`
//! or `ao` file, sizes the splats (§2.2), builds the hierarchy (§2.3), shrinks (§2.3.1) and
//! gathers `recon_rays` reconstruction rays per pixel (Eq. 3, §3.3). Its notes give the time
//! split (read, splat sizing, hierarchy, shrinking, recursive filtering, reconstruction) and the
//! counts of each stage.
//!
//! `ilfr-recursive` (effects `indirect`, `glossy`) is the same with passes of recursive filtering (§4,
//! [`super::recursive`]) with 16 rays per secondary hit before the final gather: one by default,
//! `ilfr-recursive:passes=N` for more (`crate::registry`).
//!
//! The image is the quantity the harness's reference measures: for `indirect` the light the
//! primary hit reflects after at least one more bounce (albedo × reconstructed incident
//! radiance, or o's BSDF-weighted sum in glossy files; `direct` is not added), for `ao` the ambient visibility within the AO radius
//! (1 = unoccluded, 1 where the camera ray escaped).

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
use super::shrink::{input_rays, scene_diagonal, shrink_splats, ShrinkParams, ShrinkStats, Trim};
use super::sparse::SparseParams;
use super::splats::{size_splats_with_juries, GatheredPoints, SplatParams, SplatStats};
use super::surfaces::{ConflictTest, SurfaceParams};
use crate::error::Error;
use crate::image::Image;
use crate::method::{Effect, Input, Inputs, Method, MethodError, Output, Stats};

/// `ilfr`: the paper's reconstruction (indirect light, glossy reflections, ambient occlusion).
#[derive(Debug, Default)]
pub struct Ilfr {
    pub choices: IlfrChoices,
}

/// The choices the paper leaves open that a user can switch (`ilfr:conflict=…:shrink=…`);
/// docs/history/ilfr.md measures each.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IlfrChoices {
    /// `None`: [`conflict_test_for`] the effect.
    pub conflict_test: Option<ConflictTest>,
    /// Whether escaped input rays shrink splats ([`ShrinkParams::escaped_rays`]).
    pub shrink_with_escaped_rays: bool,
    /// What a blocked input ray trims ([`ShrinkParams::trim`]); `None`: [`trim_for`] the effect.
    pub trim: Option<Trim>,
    /// What is done with outliers of the splat radiance ([`super::robust`]).
    pub robust: RobustMode,
    /// Whether the small-surface rule (§2.5) runs; `None`: [`merge_small_surfaces_for`] the
    /// effect.
    pub merge_small_surfaces: Option<bool>,
    /// Whether the final gather's grain is filtered ([`super::grain`]; indirect light only).
    pub filter_grain: bool,
    /// The gather's design; `None`: [`variant_for`] the effect.
    pub variant: Option<Variant>,
    /// Where the final gather runs for indirect light at Lambertian hits (`ilfr:gather=…`).
    pub gather: GatherChoice,
    /// The sparse gather's grid ([`super::sparse`]) where it runs.
    pub sparse: SparseParams,
}

/// Where the final gather runs for indirect light at Lambertian hits (`ilfr:gather=…`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GatherChoice {
    /// The sparse gather where the design is not chosen ([`IlfrChoices::resolved_sparse`]),
    /// otherwise every pixel.
    Auto,
    /// Every pixel.
    Full,
    /// A grid of pixels, the others interpolated or refined ([`super::sparse`]).
    Sparse,
}

/// The final gather's design (`ilfr:variant=…`; docs/ilfr.md measures each).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Variant {
    /// The paper's: every primary hit gathers its own rays, and every ray groups the splats it
    /// meets into apparent surfaces and filters the nearest ([`RayModel::ApparentSurfaces`]).
    Paper,
    /// Every primary hit gathers its own rays; a ray reads the nearest splat it meets, whose
    /// radiance is prefiltered over its neighbours ([`RayModel::NearestSplat`]).
    NearestSplat,
    /// As [`Variant::NearestSplat`], but at Lambertian hits of indirect light records gather at
    /// a subset of the hits and the others interpolate them ([`super::cache`]).
    Records,
}

impl Variant {
    pub fn name(self) -> &'static str {
        match self {
            Variant::Paper => "paper",
            Variant::NearestSplat => "nearest-splat",
            Variant::Records => "records",
        }
    }
}

/// The gather's design for `effect` unless one is chosen (with `filter_grain`, the grain filter,
/// which needs the per-pixel variances of a gather at every hit): records for indirect light
/// (Cornell 128², 4 spp: 5.3–6.6× path tracing's speed to equal PSNR against the paper's
/// gather's 0.9–1.3×; Sponza 160 × 90, 8 spp: 1.2–2.8× against 1.2–2.3×, level with the nearest
/// splat at every hit within the spread), the nearest splat at every hit with the grain filter
/// (5.0× / 6.8× against the paper's gather's 3.9× / 6.0×) and for ambient occlusion (the paper's
/// PSNR within 0.2 dB at a half to a third of its time), the paper's gather for glossy
/// reflections, whose anisotropic nearest neighbour the prefiltered splats do not reproduce
/// (docs/ilfr.md, "Variants and today's results").
pub fn variant_for(effect: Effect, filter_grain: bool) -> Variant {
    match effect {
        Effect::Indirect if !filter_grain => Variant::Records,
        Effect::Indirect | Effect::Ao => Variant::NearestSplat,
        _ => Variant::Paper,
    }
}

impl Default for IlfrChoices {
    fn default() -> Self {
        IlfrChoices {
            conflict_test: None,
            shrink_with_escaped_rays: ShrinkParams::default().escaped_rays,
            trim: None,
            robust: RobustParams::default().mode,
            merge_small_surfaces: None,
            filter_grain: false,
            variant: None,
            gather: GatherChoice::Auto,
            sparse: SparseParams::default(),
        }
    }
}

/// The conflict test used for `effect` unless one is chosen: the event line asked off the
/// tangent planes ([`SurfaceParams::default`]), except for ambient occlusion, where the paper's
/// plain event line measured better (Sponza's foliage: +0.4 to +0.5 dB at 4 and 16 spp;
/// docs/history/ilfr.md, "The conflict test").
pub fn conflict_test_for(effect: Effect) -> ConflictTest {
    match effect {
        Effect::Ao => ConflictTest::EventLine,
        _ => SurfaceParams::default().conflict_test,
    }
}

/// Whether the small-surface rule of §2.5 runs for `effect` unless chosen: yes, except for
/// ambient occlusion. There a one- to three-splat surface in front is far more often a real
/// occluder within the radius than a spurious one: on Sponza (160 × 90, 4 spp) the rule turned
/// 1.8 % of the rays from occluded to visible against 1.2 % from spuriously occluded to
/// visible, and without it ILFR gains 1.2 dB at 4 spp and 2.3 dB at 16 spp, relative MSE −42 %
/// and −51 % (docs/history/ilfr.md, "ambient occlusion (Deliver 4)").
pub fn merge_small_surfaces_for(effect: Effect) -> bool {
    effect != Effect::Ao
}

/// What a blocked input ray trims for `effect` unless chosen: for indirect light and glossy
/// reflections the wedges towards the crossing ([`Trim::Wedges`]: no holes behind trimmed rim
/// splats; +0.6 to +3 dB on Sponza, the glossy monkeys, the roughness sweep and the bunny,
/// Cornell unchanged), otherwise the whole disc (the paper): for ambient occlusion, which has
/// no small-surface rule, the wedges left whole beside a trimmed one overhang silhouettes as
/// false occluders (Sponza −3.4 dB), and in the lens mode they measured no better (docs/history/ilfr.md,
/// "trimming wedges, not whole discs").
pub fn trim_for(effect: Effect) -> Trim {
    match effect {
        Effect::Indirect | Effect::Glossy => Trim::Wedges,
        _ => Trim::Disc,
    }
}

impl IlfrChoices {
    /// `settings` with these choices, for `effect`.
    pub fn apply(&self, settings: IlfrSettings, effect: Effect) -> IlfrSettings {
        let conflict_test = self.conflict_test.unwrap_or_else(|| conflict_test_for(effect));
        let merge_small_surfaces = self.merge_small_surfaces.unwrap_or_else(|| merge_small_surfaces_for(effect));
        let variant = self.resolved_variant(effect);
        IlfrSettings {
            surfaces: SurfaceParams { conflict_test, merge_small_surfaces, ..settings.surfaces },
            shrink: ShrinkParams {
                escaped_rays: self.shrink_with_escaped_rays,
                trim: self.trim.unwrap_or_else(|| trim_for(effect)),
                ..settings.shrink
            },
            robust: RobustParams { mode: self.robust, ..settings.robust },
            filter_grain: self.filter_grain,
            ray_model: match variant {
                Variant::Paper => RayModelChoice::ApparentSurfaces,
                Variant::NearestSplat | Variant::Records => RayModelChoice::NearestSplat,
            },
            cache: (variant == Variant::Records).then(CacheParams::default),
            sparse: self.resolved_sparse(effect),
            ..settings
        }
    }

    /// The variant that runs for `effect`: the chosen one, else [`variant_for`] the effect, with
    /// the nearest splat in place of records under the sparse gather (records interpolate
    /// themselves).
    pub fn resolved_variant(&self, effect: Effect) -> Variant {
        match (self.variant, variant_for(effect, self.filter_grain)) {
            (Some(chosen), _) => chosen,
            (None, Variant::Records) if self.resolved_sparse(effect).is_some() => Variant::NearestSplat,
            (None, auto) => auto,
        }
    }

    /// The sparse gather's grid for `effect`, `None` where every pixel gathers: chosen with
    /// `gather=sparse`; with `gather=auto` for indirect light when neither the variant nor the
    /// grain filter is chosen. Against the records at every hit, in two runs each (`lfr compare
    /// --effect indirect`, 2048-spp references, 2026-12-07 and 2026-12-08, loaded machine), a
    /// 4-pixel grid gathering 4× the rays reached equal PSNR 1.1× (Cornell 128², 4 spp: 35.08
    /// dB at 64 rays against 34.99 dB at 16) and 1.2× (Sponza 160 × 90, 8 spp: 27.89 dB at 64
    /// rays against 25.85 dB at 64) sooner than path tracing and 1.1× / 3.4× sooner against OIDN
    /// (docs/ilfr.md, "The sparse gather").
    pub fn resolved_sparse(&self, effect: Effect) -> Option<SparseParams> {
        let auto = effect == Effect::Indirect && self.variant.is_none() && !self.filter_grain;
        match self.gather {
            GatherChoice::Sparse => Some(self.sparse),
            GatherChoice::Auto if auto => Some(self.sparse),
            GatherChoice::Auto | GatherChoice::Full => None,
        }
    }
}

impl Method for Ilfr {
    fn input(&self) -> Input {
        Input::Samples
    }

    /// 256 for the paper's gather; 16 and 64 under the sparse gather (whose grid gathers
    /// `grid_rays` times the budget); 16 and 128 otherwise (records gather 16 rays per ray of a
    /// pixel's budget, [`IlfrSettings::rays_per_record_ray`]).
    fn default_recon_rays(&self, effect: Effect) -> Vec<u32> {
        match self.choices.resolved_variant(effect) {
            Variant::Paper => vec![256],
            Variant::NearestSplat if self.choices.resolved_sparse(effect).is_some() => vec![16, 64],
            Variant::NearestSplat | Variant::Records => vec![16, 128],
        }
    }

    /// With `grain=filter`, diffuse indirect light only ([`super::grain`]).
    fn handles(&self, effect: Effect) -> bool {
        grain_choice_handles(self.choices.filter_grain, effect)
    }

    /// The grain filter smooths the image across pixels by geometry alone ([`super::grain`]).
    fn blurs_glossy_reflections(&self) -> bool {
        self.choices.filter_grain
    }

    fn sample_needs(&self, effect: Effect) -> Option<Vec<&'static sampleio::Needs>> {
        crate::needs::ilfr(effect.sample_kind()).map(|needs| vec![needs])
    }

    fn run(&self, inputs: &Inputs, recon_rays: u32) -> Result<Output, MethodError> {
        let settings = IlfrSettings { recon_rays, seed: inputs.seed, ..IlfrSettings::default() };
        run_ilfr("ilfr", inputs, self.choices.apply(settings, inputs.effect))
    }
}

/// `ilfr` with `passes` passes of recursive filtering (paper §4) before the final gather.
#[derive(Debug)]
pub struct IlfrRecursive {
    pub passes: u32,
    pub choices: IlfrChoices,
}

impl Method for IlfrRecursive {
    fn input(&self) -> Input {
        Input::Samples
    }

    fn default_recon_rays(&self, _effect: Effect) -> Vec<u32> {
        vec![256]
    }

    fn sample_needs(&self, effect: Effect) -> Option<Vec<&'static sampleio::Needs>> {
        crate::needs::ilfr(effect.sample_kind()).map(|needs| vec![needs])
    }

    /// The paper's gather unless a variant is chosen (`auto` is measured for one pass only).
    fn run(&self, inputs: &Inputs, recon_rays: u32) -> Result<Output, MethodError> {
        let settings =
            IlfrSettings { recon_rays, seed: inputs.seed, recursive_passes: self.passes, ..IlfrSettings::default() };
        let choices = IlfrChoices { variant: Some(self.choices.variant.unwrap_or(Variant::Paper)), ..self.choices };
        run_ilfr("ilfr-recursive", inputs, choices.apply(settings, inputs.effect))
    }
}

/// `ilfr` on camera rays (paper §3.4): defocus and motion blur from a `lens-time` file, the
/// input of `tlfr`, so that both reconstruct the very same samples ([`super::lens`]).
#[derive(Debug, Default)]
pub struct IlfrDof {
    pub choices: IlfrChoices,
}

impl Method for IlfrDof {
    fn input(&self) -> Input {
        Input::Samples
    }

    fn default_recon_rays(&self, _effect: Effect) -> Vec<u32> {
        vec![128]
    }

    fn sample_needs(&self, _effect: Effect) -> Option<Vec<&'static sampleio::Needs>> {
        Some(vec![&crate::needs::ILFR_LENS])
    }

    fn run(&self, inputs: &Inputs, recon_rays: u32) -> Result<Output, MethodError> {
        let name = "ilfr-dof";
        if !matches!(inputs.effect, Effect::Dof | Effect::Motion | Effect::DofMotion) {
            return Err(MethodError::Unsupported(format!("{name} does not reconstruct {}", inputs.effect.name())));
        }
        let path = inputs.samples(name)?;
        let settings = self
            .choices
            .apply(IlfrSettings { recon_rays, seed: inputs.seed, ..IlfrSettings::default() }, inputs.effect);
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
            "{} camera rays: {hits} splats, {escaped} escaped; {recon_rays} reconstruction rays per pixel; {} hits took \
             the normal of their ray (depth gradient not usable)",
            samples.len(),
            ray_stats.normals_from_the_ray
        );
        Ok(Output {
            image: result.image,
            preprocess_s: result.timings.preprocess_s(),
            recon_s: result.timings.recon_s(),
            external_peak_rss_mb: None,
            notes,
            stats,
        })
    }
}

fn run_ilfr(name: &str, inputs: &Inputs, settings: IlfrSettings) -> Result<Output, MethodError> {
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
    Ok(Output {
        image: result.image,
        preprocess_s: result.timings.preprocess_s(),
        recon_s: result.timings.recon_s(),
        external_peak_rss_mb: None,
        notes,
        stats,
    })
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
fn grain_choice_handles(filter_grain: bool, effect: Effect) -> bool {
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
