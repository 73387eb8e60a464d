//! Recursive filtering, paper Section 4 (design: docs/ilfr-design.md §2 "Recursive step",
//! §3 #18, gap G3).
//!
//! The paper: "a quick reconstruction of the incident lighting at the secondary hits, replacing
//! the secondary hits' radiances with the reconstructed values before reconstructing incident
//! lighting at the primary hits" (16 reconstruction rays, Figure 13). The radiance L_j of an
//! input sample is one noisy path beyond its secondary hit h_j; this step swaps the noisy part
//! for a reconstruction from all the samples' splats.
//!
//! What `radiance` holds (docs/sample-format.md, the tracer's `TracedRay`): the light arriving at
//! o_j from h_j *without h_j's own emission*, split as `secondary_direct` (what h_j reflects
//! straight from emitters and the environment: next-event estimation at h_j plus the emitters its
//! BSDF ray hits, MIS-weighted) plus the light that bounced at least twice. For a Lambertian h_j
//! the second part is albedo_h · E[L_in(h_j ← ω)] with ω cosine-distributed about n_j, and
//! L_in excludes the emission of what ω hits — exactly what RECONSTRUCT returns (the splats'
//! radiances exclude their own hit's emission too). So
//!
//! ```text
//! L_j' = secondary_direct_j + secondary_albedo_j · (1/M') Σ_{k ≤ M} RECONSTRUCT(h_j + ε n_j, ω_k)
//! ```
//!
//! counts direct light at h_j once (in `secondary_direct`) and nothing twice. ω_k: M
//! cosine-distributed directions about n_j (`hit_normal`, facing o_j), the Owen-scrambled 2D
//! Sobol' points of the gather with a scramble hashed from (seed, sample index), so each L_j' is
//! a pure function of the input: the result is the same for any thread count. A ray with no
//! splat takes the nearest sky sample of the pixel neighbourhood of sample j (as the gather; an
//! escaped input ray carries no reflected light, so this is the environment's reflected part, 0
//! in tracer files) or is left out; M' = the supported rays; M' = 0 keeps L_j.
//!
//! Glossy files carry h's BSDF (`hit_base_color` and the rest, design gap G3): there every h
//! reflects with it, L_j' = secondary_direct_j + (1/M') Σ f·cos/p · RECONSTRUCT, directions and
//! weights from [`super::bsdf_rays`] with ωo = −ω_j (towards o_j). Skipped (L_j kept): samples
//! without a secondary hit and, in files without h's BSDF, glossy hits (κ_j ≥ [`GLOSSY_KAPPA`]);
//! there hits below the threshold are treated as Lambertian. A glossy file (`weight`) without
//! h's BSDF is refused.
//!
//! Several passes (Jacobi: each pass reconstructs from the previous pass's radiances) add one
//! bounce of filtered light each: in a furnace of albedo a and emission E, one pass maps a
//! sample radiance c to aE + a·c.

use rayon::prelude::*;
use shading::sampling::hash_u32;

use super::bsdf_rays::{bsdf_rays, WeightedRay};
use super::directions::cosine_rays;
use super::disc::Ray;
use super::filter::GLOSSY_KAPPA;
use super::gather::sky_samples;
use super::reconstruct::{ReconstructStats, Reconstructor, Scratch, SkyFallbacks};
use super::samples::{IndirectSamples, PrimaryShading, SampleClass};
use crate::error::Error;

/// How a recursive pass runs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RecursiveSettings {
    /// Reconstruction rays per secondary hit (the paper: 16).
    pub rays_per_hit: u32,
    /// Seed of the directions.
    pub seed: u32,
    /// How far the rays start above the secondary hit, along its normal (scene units).
    pub offset: f32,
    /// The sky neighbourhood reaches this many pixels either side of the sample's pixel.
    pub sky_pixel_radius: u32,
    /// A sky sample counts within this many angular spacings of the ray.
    pub sky_spacing_factor: f32,
}

impl Default for RecursiveSettings {
    fn default() -> Self {
        RecursiveSettings { rays_per_hit: 16, seed: 0, offset: 1e-4, sky_pixel_radius: 2, sky_spacing_factor: 2.0 }
    }
}

/// Counts of a recursive pass, for reports.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RecursiveStats {
    pub reconstruct: ReconstructStats,
    /// Secondary hits whose radiance was replaced.
    pub replaced: u64,
    /// Glossy secondary hits (κ ≥ the glossy threshold) left as they were: files without h's BSDF.
    pub glossy_kept: u64,
    /// Lambertian secondary hits none of whose rays had support (left as they were).
    pub unsupported_kept: u64,
    /// Rays with no surface that took a sky sample's radiance, and those with neither (left out
    /// of their hit's average).
    pub fallbacks: SkyFallbacks,
}

impl RecursiveStats {
    pub fn add(&mut self, other: &RecursiveStats) {
        self.reconstruct.add(&other.reconstruct);
        self.replaced += other.replaced;
        self.glossy_kept += other.glossy_kept;
        self.unsupported_kept += other.unsupported_kept;
        self.fallbacks.add(&other.fallbacks);
    }
}

/// Samples per parallel work item.
const CHUNK: usize = 256;

/// One recursive pass: the radiance of every sample (indexed like `samples`) after replacing
/// that of its Lambertian secondary hit by `secondary_direct + secondary_albedo × the mean
/// reconstructed incident radiance`. `current` is the radiance per sample before the pass (the
/// file's `radiance`, or the previous pass's output); `reconstructor`'s splats must carry the
/// same values. Errors name the file and the missing field.
pub fn recursive_pass(
    samples: &IndirectSamples,
    current: &[[f32; 3]],
    reconstructor: &Reconstructor,
    settings: &RecursiveSettings,
) -> Result<(Vec<[f32; 3]>, RecursiveStats), Error> {
    let content = |message: String| Error::sample_content(&samples.path, message);
    let field = |name: &str| content(format!("recursive filtering needs the field `{name}` (docs/sample-format.md)"));
    let secondary_albedo = samples.secondary_albedo.as_ref().ok_or_else(|| field("secondary_albedo"))?;
    if samples.weight.is_some() && samples.secondary_bsdf.is_none() {
        return Err(content(
            "a glossy file (it has `weight`) without `hit_base_color` and the other fields of h's BSDF: recursive \
             filtering at glossy secondary hits needs them; dump the samples again"
                .to_string(),
        ));
    }
    let secondary_direct = samples.secondary_direct.as_ref().ok_or_else(|| field("secondary_direct"))?;
    if current.len() != samples.len() {
        let message = format!("{}: {} radiances for {} samples", samples.path, current.len(), samples.len());
        return Err(Error::size_mismatch("radiances and samples", message));
    }
    if settings.rays_per_hit == 0 {
        return Err(Error::parameter("rays_per_hit", "recursive filtering needs at least one ray per secondary hit"));
    }
    if !(settings.offset.is_finite() && settings.offset >= 0.0) {
        let message = format!("the reconstruction ray offset must be finite and ≥ 0, got {}", settings.offset);
        return Err(Error::parameter("offset", message));
    }
    let (width, spp) = (samples.width.max(1) as usize, samples.spp.max(1) as usize);
    let chunks: Vec<(Vec<[f32; 3]>, RecursiveStats)> = (0..samples.len().div_ceil(CHUNK))
        .into_par_iter()
        .map(|chunk| {
            let mut scratch = Scratch::default();
            let mut stats = RecursiveStats::default();
            let mut sky = Vec::new();
            let range = chunk * CHUNK..((chunk + 1) * CHUNK).min(samples.len());
            let values = range
                .map(|i| {
                    if samples.class[i] != SampleClass::Hit {
                        return current[i];
                    }
                    if samples.secondary_bsdf.is_none() && samples.kappa_of(i) >= GLOSSY_KAPPA {
                        stats.glossy_kept += 1;
                        return current[i];
                    }
                    let pixel = i / spp;
                    let spacing = sky_samples(
                        samples,
                        (pixel % width) as u32,
                        (pixel / width) as u32,
                        settings.sky_pixel_radius,
                        &mut sky,
                    );
                    let min_cosine = spacing.map(|s| (settings.sky_spacing_factor * s).min(std::f32::consts::PI).cos());
                    // h's BSDF when the file has it (weights f·cos/p from it), else a Lambertian
                    // h: cosine rays, `secondary_albedo` as their common weight.
                    let (rays, scale): (Vec<WeightedRay>, [f32; 3]) = match &samples.secondary_bsdf {
                        Some(bsdfs) => {
                            let h = PrimaryShading {
                                bsdf: bsdfs[i],
                                geometric_normal: samples.secondary_normal[i],
                                to_eye: samples.direction[i].map(|c| -c),
                            };
                            let weighted = bsdf_rays(
                                &h,
                                samples.secondary_hit[i],
                                samples.secondary_normal[i],
                                (0, settings.rays_per_hit),
                                hit_scramble(i, settings),
                                settings.offset,
                            );
                            (weighted.collect(), [1.0; 3])
                        }
                        None => (
                            secondary_rays(samples, i, settings)
                                .map(|r| WeightedRay { ray: Some(r), weight: [1.0; 3] })
                                .collect(),
                            secondary_albedo[i],
                        ),
                    };
                    let (mut sum, mut supported) = ([0.0f64; 3], 0u32);
                    for WeightedRay { ray, weight } in rays {
                        // A direction below h's surface: a sample of value 0.
                        let Some(ray) = ray else {
                            supported += 1;
                            continue;
                        };
                        let radiance = reconstructor.radiance_or_sky(
                            &ray,
                            (&sky, min_cosine),
                            &mut scratch,
                            &mut stats.reconstruct,
                            &mut stats.fallbacks,
                        );
                        if let Some(l) = radiance {
                            for c in 0..3 {
                                sum[c] += (weight[c] * l[c]) as f64;
                            }
                            supported += 1;
                        }
                    }
                    if supported == 0 {
                        stats.unsupported_kept += 1;
                        return current[i];
                    }
                    stats.replaced += 1;
                    let direct = secondary_direct[i];
                    [0, 1, 2].map(|c| (direct[c] as f64 + scale[c] as f64 * sum[c] / supported as f64) as f32)
                })
                .collect();
            (values, stats)
        })
        .collect();
    let mut stats = RecursiveStats::default();
    let mut radiance = Vec::with_capacity(samples.len());
    for (values, chunk_stats) in chunks {
        radiance.extend(values);
        stats.add(&chunk_stats);
    }
    Ok((radiance, stats))
}

/// The reconstruction rays of secondary hit `i`: origin lifted along its normal, directions
/// cosine-distributed about it.
fn secondary_rays(samples: &IndirectSamples, i: usize, settings: &RecursiveSettings) -> impl Iterator<Item = Ray> {
    let scramble = hit_scramble(i, settings);
    cosine_rays(
        samples.secondary_hit[i],
        samples.secondary_normal[i],
        settings.offset,
        (0, settings.rays_per_hit),
        scramble,
    )
}

/// The seed of secondary hit i's directions: a constant apart from the gather's, so that the
/// two direction sets are not correlated.
fn hit_scramble(i: usize, settings: &RecursiveSettings) -> u32 {
    hash_u32(settings.seed ^ hash_u32(i as u32 ^ 0xbb67_ae85))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ilfr::bvh::DiscBvh;
    use crate::ilfr::disc::Disc;
    use crate::ilfr::filter::SplatShading;
    use crate::ilfr::pipeline::tests::{box_exit, box_samples, settings};
    use crate::ilfr::pipeline::GatherTarget;
    use crate::ilfr::pipeline::{reconstruct_samples, IlfrSettings};
    use crate::ilfr::reconstruct::RayModel;
    use crate::ilfr::shrink::{input_rays, scene_diagonal, shrink_splats, ShrinkParams};
    use crate::ilfr::splats::{size_splats, GatheredPoints, SplatParams};
    use crate::ilfr::surfaces::SurfaceParams;
    use crate::vector::normalize;
    use sampleio::SampleKind;

    /// Sizes, indexes and shrinks the splats of `samples` (as `reconstruct_samples` does) and
    /// runs one recursive pass from the file's radiances.
    fn one_pass(samples: &IndirectSamples, rays_per_hit: u32) -> Result<(Vec<[f32; 3]>, RecursiveStats), Error> {
        let storage = GatheredPoints::from_samples(samples);
        let points = storage.points();
        let sized = size_splats(&points, &SplatParams::default())?;
        let discs: Vec<Disc> = (0..points.position.len())
            .map(|k| Disc::new(points.position[k], points.normal[k], sized.radius[k]))
            .collect();
        let mut bvh = DiscBvh::build(&discs)?;
        let rays = input_rays(samples, &storage.sample_index);
        shrink_splats(&mut bvh, &rays, &ShrinkParams::default())?;
        let offset = 1e-4 * scene_diagonal(&bvh, &rays);
        let current = samples.radiance.clone().unwrap();
        let radiance: Vec<[f32; 3]> = storage.sample_index.iter().map(|&i| current[i as usize]).collect();
        let shading =
            SplatShading { radiance: &radiance, direction: &storage.direction, kappa: storage.kappa.as_deref() };
        let reconstructor =
            Reconstructor { bvh: &bvh, shading, surfaces: SurfaceParams::default(), model: RayModel::ApparentSurfaces };
        let settings = RecursiveSettings { rays_per_hit, offset, ..RecursiveSettings::default() };
        recursive_pass(samples, &current, &reconstructor, &settings)
    }

    /// Secondary albedo and direct light for every sample of `samples` (zero where no hit).
    fn with_secondary(mut samples: IndirectSamples, albedo: [f32; 3], direct: [f32; 3]) -> IndirectSamples {
        let hit = |i: usize| samples.class[i] == SampleClass::Hit;
        let albedos = (0..samples.len()).map(|i| if hit(i) { albedo } else { [0.0; 3] }).collect();
        let directs = (0..samples.len()).map(|i| if hit(i) { direct } else { [0.0; 3] }).collect();
        samples.secondary_albedo = Some(albedos);
        samples.secondary_direct = Some(directs);
        samples
    }

    fn close(got: f32, expected: f64) -> bool {
        (got as f64 - expected).abs() <= 1e-6 * expected.abs().max(1.0)
    }

    #[test]
    fn glossy_secondary_hits_reflect_with_their_own_bsdf() {
        // Every sample carries the same radiance c, h's direct part d and h's BSDF (a rough
        // metal, a rough dielectric, a mirror): one pass gives d + (directional albedo of h's
        // BSDF towards o) × c per hit, the albedo estimated independently by the BSDF's own
        // one-sample mixture.
        let (c, d) = (2.0f32, [0.1f32, 0.2, 0.3]);
        for (roughness, metallic) in [(0.3f32, 1.0f32), (0.7, 0.0), (0.0, 1.0)] {
            let bsdf = shading::Bsdf::new(glam::Vec3::new(0.9, 0.6, 0.3), metallic, roughness, 1.0);
            let mut samples = with_secondary(box_samples(8, 2, SampleKind::Indirect, None, |_| [c; 3]), [0.5; 3], d);
            samples.secondary_bsdf = Some(vec![bsdf; samples.len()]);
            samples.kappa = Some(vec![40.0; samples.len()]);
            let (once, stats) = one_pass(&samples, 512).unwrap();
            assert_eq!(stats.glossy_kept, 0);
            assert_eq!(stats.replaced as usize + stats.unsupported_kept as usize, samples.len());
            assert!(stats.unsupported_kept * 50 <= stats.replaced, "{stats:?}");
            for (i, l) in once.iter().enumerate() {
                if *l == [c; 3] {
                    continue; // kept: no ray of this hit found support
                }
                let frame = shading::Frame::new(glam::Vec3::from(samples.secondary_normal[i]));
                let wo = frame.to_local(-glam::Vec3::from(samples.direction[i]));
                let albedo = crate::ilfr::bsdf_rays::mixture_albedo(&bsdf, wo, 1 << 14);
                for k in 0..3 {
                    let expected = d[k] + albedo[k] * c;
                    assert!(
                        (l[k] - expected).abs() < 0.015 * expected,
                        "r {roughness} m {metallic} sample {i}: {l:?} vs {expected}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_pass_in_a_furnace_adds_exactly_one_bounce() {
        // Every wall emits E and reflects with albedo a. A path truncated two reflections past
        // o carries c = aE + a²E (h's own emission excluded), of which aE is h's direct part. One
        // pass: aE + a·(mean reconstructed c) = aE + a²E + a³E, one bounce nearer the converged
        // aE/(1 − a); two passes add a⁴E. Direct light is counted once: double counting would
        // give 2aE + ….
        let (a, e) = ([0.5f64, 0.8, 0.25], [1.0f64, 2.0, 4.0]);
        let c = [0, 1, 2].map(|k| (a[k] * e[k] + a[k] * a[k] * e[k]) as f32);
        let direct = [0, 1, 2].map(|k| (a[k] * e[k]) as f32);
        let albedo = a.map(|v| v as f32);
        let samples = with_secondary(box_samples(8, 4, SampleKind::Indirect, None, |_| c), albedo, direct);
        let hits = samples.class.iter().filter(|&&k| k == SampleClass::Hit).count() as u64;
        assert_eq!(hits, samples.len() as u64, "a closed box: every secondary ray hits");

        let (once, stats) = one_pass(&samples, 16).unwrap();
        let bounces = |n: i32| [0, 1, 2].map(|k| (1..=n).map(|j| a[k].powi(j) * e[k]).sum::<f64>());
        let three = bounces(3);
        for (i, l) in once.iter().enumerate() {
            assert!((0..3).all(|k| close(l[k], three[k])), "sample {i}: {l:?}, expected {three:?}");
        }
        assert_eq!((stats.replaced, stats.glossy_kept, stats.unsupported_kept), (hits, 0, 0));
        assert_eq!(stats.reconstruct.rays, hits * 16);

        // Through the method: one pass, then the final gather; pixel = albedo(o) × (aE + a²E + a³E).
        let mut settings = settings(64);
        settings.recursive_passes = 1;
        let result = reconstruct_samples(&samples, GatherTarget::Indirect, &settings).unwrap();
        let albedo_o = [0.5, 0.25, 1.0]; // box_samples' primary albedo
        for (k, p) in result.image.pixels.iter().enumerate() {
            assert!((0..3).all(|c| close(p[c], albedo_o[c] * three[c])), "pixel {k}: {p:?}");
        }
        assert_eq!(result.recursive.len(), 1);
        settings.recursive_passes = 2;
        let result = reconstruct_samples(&samples, GatherTarget::Indirect, &settings).unwrap();
        let four = bounces(4);
        for (k, p) in result.image.pixels.iter().enumerate() {
            assert!((0..3).all(|c| close(p[c], albedo_o[c] * four[c])), "pixel {k}: {p:?}");
        }
    }

    #[test]
    fn a_radiance_ramp_is_gathered_at_the_secondary_hits() {
        // L(h) = h_z + 1 on the walls and ceiling of the box (the floor holds the primary hits
        // and no splat). With direct part 0.25 and albedo 0.5 the pass gives 0.25 + 0.5 × the
        // mean of L over cosine directions from h that reach a wall or the ceiling (rays towards
        // the floor find no splat and are left out): by brute force, 64² stratified directions.
        let samples =
            with_secondary(box_samples(8, 8, SampleKind::Indirect, None, |h| [h[2] + 1.0; 3]), [0.5; 3], [0.25; 3]);
        let (once, stats) = one_pass(&samples, 32).unwrap();
        let (mut mean_error, mut count) = (0.0f64, 0usize);
        for (i, reconstructed) in once.iter().enumerate() {
            let (h, n) = (samples.secondary_hit[i], samples.secondary_normal[i]);
            let frame = shading::Frame::new(glam::Vec3::from(n));
            let (t, b) = (frame.tangent.to_array(), frame.bitangent.to_array());
            let origin = [0, 1, 2].map(|a| h[a] + 1e-4 * n[a]);
            let (mut sum, mut reached) = (0.0f64, 0usize);
            let m = 64;
            for p in 0..m {
                for q in 0..m {
                    let l =
                        shading::sample_cosine_hemisphere([(p as f32 + 0.5) / m as f32, (q as f32 + 0.5) / m as f32])
                            .to_array();
                    let d = normalize([0, 1, 2].map(|a| l[0] * t[a] + l[1] * b[a] + l[2] * n[a]));
                    let (exit, exit_normal) = box_exit(origin, d, 2.0, false).unwrap();
                    if exit_normal[2] != 1.0 {
                        sum += exit[2] as f64 + 1.0;
                        reached += 1;
                    }
                }
            }
            if reached == 0 {
                continue;
            }
            let expected = 0.25 + 0.5 * sum / reached as f64;
            mean_error += (reconstructed[0] as f64 - expected).abs();
            count += 1;
        }
        mean_error /= count as f64;
        // 32 rays per hit over a ramp of values 1 to 3 (so 0.75 to 1.75 after the pass).
        assert!(mean_error < 0.05, "mean error {mean_error} over {count} hits");
        assert!(stats.replaced as usize >= count * 9 / 10, "{stats:?}");
        assert!(once.iter().flatten().all(|v| v.is_finite()));
    }

    #[test]
    fn glossy_secondary_hits_keep_their_radiance() {
        // Ceiling hits are glossy (κ = 40 ≥ the threshold 1): kept bit for bit (gap G3); the
        // others are replaced by 0.5 × a mean of radiances ≤ 3 (never 3 itself).
        let mut samples =
            with_secondary(box_samples(8, 4, SampleKind::Indirect, None, |h| [h[2] + 1.0; 3]), [0.5; 3], [0.0; 3]);
        let on_ceiling = |i: usize| samples.class[i] == SampleClass::Hit && samples.secondary_hit[i][2] > 1.999;
        let glossy: Vec<bool> = (0..samples.len()).map(on_ceiling).collect();
        samples.kappa = Some(glossy.iter().map(|&g| if g { 40.0 } else { 0.0 }).collect());
        let input = samples.radiance.clone().unwrap();
        let (once, stats) = one_pass(&samples, 16).unwrap();
        let glossy_count = glossy.iter().filter(|&&g| g).count();
        assert!(glossy_count > 10);
        assert_eq!(stats.glossy_kept as usize, glossy_count);
        for i in 0..samples.len() {
            if glossy[i] {
                assert_eq!(once[i].map(f32::to_bits), input[i].map(f32::to_bits), "sample {i}");
            } else {
                assert!(once[i][0] <= 1.5 + 1e-6, "sample {i}: {:?}", once[i]);
            }
        }
    }

    #[test]
    fn the_pass_does_not_depend_on_the_thread_count() {
        let samples = with_secondary(
            box_samples(8, 4, SampleKind::Indirect, None, |h| [h[0] + 1.0, h[1] * h[2], h[2]]),
            [0.7, 0.5, 0.3],
            [0.1, 0.2, 0.3],
        );
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| {
                let pass = one_pass(&samples, 16).unwrap();
                let settings = IlfrSettings { recon_rays: 32, recursive_passes: 1, ..IlfrSettings::default() };
                let image = reconstruct_samples(&samples, GatherTarget::Indirect, &settings).unwrap().image;
                (pass, image)
            })
        };
        let bits = |v: &[[f32; 3]]| v.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
        let ((one, one_stats), one_image) = run(1);
        let ((two, two_stats), two_image) = run(2);
        assert_eq!(bits(&one), bits(&two));
        assert_eq!(one_stats, two_stats);
        assert_eq!(bits(&one_image.pixels), bits(&two_image.pixels));
        // And the pass changed something (it is not the identity).
        assert_ne!(bits(&one), bits(samples.radiance.as_ref().unwrap()));
    }

    #[test]
    fn missing_secondary_fields_are_named() {
        let mut samples =
            with_secondary(box_samples(2, 1, SampleKind::Indirect, None, |_| [1.0; 3]), [0.5; 3], [0.0; 3]);
        samples.secondary_direct = None;
        let error = one_pass(&samples, 4).unwrap_err().to_string();
        assert!(error.contains("synthetic.lfrs") && error.contains("`secondary_direct`"), "{error}");
        let settings = IlfrSettings { recon_rays: 4, recursive_passes: 1, ..IlfrSettings::default() };
        let error = reconstruct_samples(&samples, GatherTarget::Indirect, &settings).unwrap_err();
        assert!(error.to_string().contains("`secondary_direct`"), "{error}");
    }
}
