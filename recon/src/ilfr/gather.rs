//! The final gather, paper Eq. 1 and Eq. 3, and ambient occlusion, Section 3.3 (design:
//! docs/ilfr-design.md §2 "Final gather", §3 #13, #17, #19).
//!
//! Paper → code:
//! - Eq. 3, L(p → c) ≈ (1/N) Σ_j (1/π) f_r cosθ_j / p(ω_j) · RECONSTRUCT(p, ω_j): for every
//!   primary hit o_i of a pixel, N = ceil(rays per pixel / spp) reconstruction rays, cosine-
//!   distributed about its shading normal m_i, from o_i lifted by `offset` along m_i. For a
//!   Lambertian o the sampling weight f·cos/p is its albedo, so the hit's value is
//!   albedo_i · (1/N') Σ RECONSTRUCT over the N' rays that found support (the authors
//!   normalise by the supported count as well). Glossy files carry o's BSDF: there the N
//!   directions and their weights f·cos/p come from it (`bsdf_rays`), the hit's value is
//!   (1/N') Σ weight_j · RECONSTRUCT, and directions below o's geometric normal count as
//!   supported samples of value 0. A glossy file without o's BSDF (an older dump) is refused.
//! - Support: a ray that meets no splat takes the radiance of the nearest *sky sample* (an
//!   input ray that escaped, with the environment radiance it carried) among the primary hits
//!   of the pixel's 5×5 neighbourhood, if that one lies within twice the neighbourhood's angular
//!   spacing sqrt(2π / n) (n secondary rays in the neighbourhood); otherwise it has no support
//!   and is left out. A primary hit without a supported ray keeps its own input estimate
//!   albedo · L (the box value of that sample).
//! - "thresholding the distance to the closest apparent surface found" (§3.3): the same rays,
//!   weight 1, value = mean ambient visibility ([`super::reconstruct::Reconstructor::visibility`],
//!   1 where no surface lies within the radius). A camera ray that escaped counts as visible, as
//!   in the harness's reference.
//! - A pixel is the mean over its spp records (sample i belongs to pixel i / spp), a camera miss
//!   giving 0 indirect light (the box value: its radiance is zero) or visibility 1.
//! - Beyond the paper, for `grain=filter` ([`super::grain`]): each pixel's variance of the mean
//!   luminance of its supported rays' radiance at Lambertian hits ([`gather_with_spread`]).
//!
//! Directions: the 2D Sobol' (0, 2)-sequence, Owen-scrambled by a hash of (seed, pixel), hit k
//! of the pixel taking block k of it ([`GatherSettings::pixel_stratified`]; a hash of (seed,
//! sample index) per hit without it), mapped by the concentric disk map and lifted to the
//! hemisphere (Malley) — or, at glossy hits, through each lobe's sampling map (`bsdf_rays`). Each pixel is a pure
//! function of the input, so the image is bit-identical for any number of threads.

use rayon::prelude::*;
use shading::sampling::hash_u32;

use super::bsdf_rays::{bsdf_rays, single_lobe, WeightedRay};
use super::directions::cosine_rays;
use super::disc::Ray;
use super::reconstruct::{ReconstructStats, Reconstructor, Scratch, SkyFallbacks, SkySample};
use super::samples::{IndirectSamples, PrimaryShading, SampleClass};
use crate::error::Error;
use crate::image::Image;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GatherSettings {
    /// Reconstruction rays per pixel (spread over its primary hits, at least one each).
    pub rays_per_pixel: u32,
    /// Seed of the directions.
    pub seed: u32,
    /// How far reconstruction rays start above the primary hit, along its normal (scene units).
    pub offset: f32,
    /// The sky neighbourhood reaches this many pixels either side (2: 5×5).
    pub sky_pixel_radius: u32,
    /// A sky sample counts within this many angular spacings of the ray.
    pub sky_spacing_factor: f32,
    /// The directions of a pixel's primary hits as consecutive blocks of one scrambled sequence
    /// per pixel (one stratification over the pixel), instead of one sequence per hit: cosine
    /// rays, and at glossy hits each BSDF lobe's directions (`bsdf_rays`).
    pub pixel_stratified: bool,
}

impl Default for GatherSettings {
    fn default() -> Self {
        GatherSettings {
            rays_per_pixel: 256,
            seed: 0,
            offset: 1e-4,
            sky_pixel_radius: 2,
            sky_spacing_factor: 2.0,
            pixel_stratified: true,
        }
    }
}

/// Counts of a gather, for reports.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct GatherStats {
    pub reconstruct: ReconstructStats,
    /// Primary hits gathered.
    pub primary_hits: u64,
    /// Rays with no surface that took a sky sample's radiance, and those with neither (left out
    /// of their hit's average).
    pub fallbacks: SkyFallbacks,
    /// Primary hits none of whose rays had support (they kept their own input estimate).
    pub unsupported_hits: u64,
}

impl GatherStats {
    pub(super) fn add(&mut self, other: &GatherStats) {
        self.reconstruct.add(&other.reconstruct);
        self.primary_hits += other.primary_hits;
        self.fallbacks.add(&other.fallbacks);
        self.unsupported_hits += other.unsupported_hits;
    }
}

/// Reconstruction rays per primary hit for `rays_per_pixel` and `spp`: ceil(rays / spp), ≥ 1.
pub fn rays_per_hit(rays_per_pixel: u32, spp: u32) -> u32 {
    rays_per_pixel.div_ceil(spp.max(1)).max(1)
}

/// The luminance of the radiance of a pixel's supported rays at its Lambertian hits: Σ y, Σ y²
/// and how many, for the variance of the pixel's estimate.
#[derive(Clone, Copy, Debug, Default)]
struct RaySpread {
    sum: f64,
    sum_squares: f64,
    count: u32,
}

impl RaySpread {
    fn add(&mut self, l: [f32; 3]) {
        let y = super::robust::luminance(l) as f64;
        if y.is_finite() {
            self.sum += y;
            self.sum_squares += y * y;
            self.count += 1;
        }
    }

    /// The variance of the rays' mean luminance (sample variance / count); +inf with fewer than
    /// two rays (unknown).
    fn variance_of_mean(&self) -> f32 {
        if self.count < 2 {
            return f32::INFINITY;
        }
        let n = self.count as f64;
        let mean = self.sum / n;
        let variance = ((self.sum_squares / n - mean * mean) * n / (n - 1.0)).max(0.0);
        (variance / n) as f32
    }
}

/// Gathers from `samples` with the splats of `reconstructor` the indirect light towards the
/// camera, or with `ao_radius` the ambient visibility within it; for indirect light also each
/// pixel's `RaySpread::variance_of_mean`, the variance of its gathered irradiance's luminance
/// from the spread of its rays (+inf where unknown; empty for ambient occlusion). Errors name
/// the file and the field: a glossy file (`weight`, gap G1), an `indirect` file without
/// `albedo`, an AO target on a file without `distance` and the reverse.
pub fn gather_with_spread(
    samples: &IndirectSamples,
    reconstructor: &Reconstructor,
    ao_radius: Option<f32>,
    settings: &GatherSettings,
) -> Result<(Image, GatherStats, Vec<f32>), Error> {
    let content = |message: &str| Error::sample_content(&samples.path, message);
    let albedo = match ao_radius {
        None => {
            if samples.weight.is_some() && samples.primary_shading.is_none() {
                return Err(content(
                    "the file has the field `weight` (a glossy scene) but not `origin_base_color` and the other \
                     fields of o's BSDF that the final gather at glossy primary hits samples: dump the samples again",
                ));
            }
            if samples.radiance.is_none() {
                return Err(content("indirect light needs the field `radiance`"));
            }
            Some(samples.albedo.as_ref().ok_or_else(|| content("indirect light needs the field `albedo`"))?)
        }
        Some(ao_radius) => {
            if !(ao_radius.is_finite() && ao_radius > 0.0) {
                return Err(Error::parameter("ao_radius", format!("the AO radius must be positive, got {ao_radius}")));
            }
            None
        }
    };
    if !(settings.offset.is_finite() && settings.offset >= 0.0) {
        let message = format!("the reconstruction ray offset must be finite and ≥ 0, got {}", settings.offset);
        return Err(Error::parameter("offset", message));
    }
    let (width, height, spp) = (samples.width, samples.height, samples.spp.max(1));
    let expected = width as usize * height as usize * spp as usize;
    if samples.len() != expected {
        let message =
            format!("{} samples for {width}x{height} pixels at {spp} spp ({expected} expected)", samples.len());
        return Err(Error::sample_content(&samples.path, message));
    }
    let per_hit = rays_per_hit(settings.rays_per_pixel, spp);
    crate::progress::begin("gather", height as u64, "rows");
    let rows: Vec<(Vec<[f32; 3]>, Vec<f32>, GatherStats)> = (0..height)
        .into_par_iter()
        .map(|y| {
            let mut scratch = Scratch::default();
            let mut stats = GatherStats::default();
            let mut sky = Vec::new();
            let mut variance = Vec::with_capacity(width as usize);
            let row = (0..width)
                .map(|x| {
                    let mut spread = RaySpread::default();
                    let first = (y as usize * width as usize + x as usize) * spp as usize;
                    let sky_spacing = match ao_radius {
                        None => sky_samples(samples, x, y, settings.sky_pixel_radius, &mut sky),
                        Some(_) => None,
                    };
                    let min_cosine = sky_spacing.map(|spacing| {
                        let angle = (settings.sky_spacing_factor * spacing).min(std::f32::consts::PI);
                        angle.cos()
                    });
                    let mut sum = [0.0f64; 3];
                    for i in first..first + spp as usize {
                        let value = match ao_radius {
                            None => indirect_at(
                                samples,
                                i,
                                albedo.map(|a| a[i]).unwrap_or([0.0; 3]),
                                reconstructor,
                                (&sky, min_cosine),
                                (per_hit, settings),
                                &mut scratch,
                                (&mut stats, &mut spread),
                            ),
                            Some(ao_radius) => visibility_at(
                                samples,
                                i,
                                ao_radius,
                                reconstructor,
                                (per_hit, settings),
                                &mut scratch,
                                &mut stats,
                            ),
                        };
                        for c in 0..3 {
                            sum[c] += value[c] as f64;
                        }
                    }
                    if ao_radius.is_none() {
                        variance.push(spread.variance_of_mean());
                    }
                    sum.map(|s| (s / spp as f64) as f32)
                })
                .collect();
            crate::progress::advance(1);
            (row, variance, stats)
        })
        .collect();
    crate::progress::end();
    let mut variance = Vec::new();
    let rows = rows
        .into_iter()
        .map(|(row, row_variance, stats)| {
            variance.extend(row_variance);
            (row, stats)
        })
        .collect();
    let (image, stats) = assemble_rows(width, height, rows);
    Ok((image, stats, variance))
}

/// The image and the summed counts of rows gathered in parallel, in row order.
pub(super) fn assemble_rows(width: u32, height: u32, rows: Vec<(Vec<[f32; 3]>, GatherStats)>) -> (Image, GatherStats) {
    let mut stats = GatherStats::default();
    let mut pixels = Vec::with_capacity(width as usize * height as usize);
    for (row, row_stats) in rows {
        pixels.extend(row);
        stats.add(&row_stats);
    }
    (Image::from_pixels(width, height, pixels), stats)
}

/// Every ray the gather of the `indirect` target reconstructs, primary hit by primary hit in
/// file order (`None` where a BSDF direction points below the surface and nothing is traced):
/// for benchmarks that trace the same rays with another engine.
pub fn reconstruction_rays(samples: &IndirectSamples, settings: &GatherSettings) -> Vec<Ray> {
    let per_hit = rays_per_hit(settings.rays_per_pixel, samples.spp.max(1));
    let mut rays = Vec::new();
    for i in 0..samples.len() {
        if samples.class[i] == SampleClass::CameraMiss {
            continue;
        }
        match &samples.primary_shading {
            None => rays.extend(hit_rays(samples, i, per_hit, settings)),
            Some(shading) => {
                rays.extend(weighted_rays(samples, shading, i, per_hit, settings).filter_map(|w| w.ray));
            }
        }
    }
    rays
}

/// The sky samples of the pixels within `radius` of (x, y) into `out`, and the angular spacing
/// sqrt(2π / n) of the n secondary rays there (`None` without any).
pub(super) fn sky_samples(
    samples: &IndirectSamples,
    x: u32,
    y: u32,
    radius: u32,
    out: &mut Vec<SkySample>,
) -> Option<f32> {
    out.clear();
    let Some(radiance) = &samples.radiance else { return None };
    let spp = samples.spp.max(1) as usize;
    let mut rays = 0usize;
    for py in y.saturating_sub(radius)..(y + radius + 1).min(samples.height) {
        for px in x.saturating_sub(radius)..(x + radius + 1).min(samples.width) {
            let first = (py as usize * samples.width as usize + px as usize) * spp;
            let range = first..first + spp;
            let records =
                samples.class[range.clone()].iter().zip(&samples.direction[range.clone()]).zip(&radiance[range]);
            for ((class, direction), radiance) in records {
                match class {
                    SampleClass::Hit => rays += 1,
                    SampleClass::Escaped => {
                        rays += 1;
                        out.push(SkySample { direction: *direction, radiance: *radiance });
                    }
                    SampleClass::CameraMiss | SampleClass::NoSecondaryRay => {}
                }
            }
        }
    }
    (rays > 0 && !out.is_empty()).then(|| (std::f32::consts::TAU / rays as f32).sqrt())
}

/// Where primary hit `i`'s directions start in which scrambled sequence: with
/// [`GatherSettings::pixel_stratified`] hit k of pixel p takes block k (points k·`per_hit` on)
/// of the pixel's sequence, else the start of its own.
fn direction_block(samples: &IndirectSamples, i: usize, per_hit: u32, settings: &GatherSettings) -> (u32, u32) {
    if settings.pixel_stratified {
        let spp = samples.spp.max(1) as usize;
        let (pixel, k) = (i / spp, (i % spp) as u32);
        (k.saturating_mul(per_hit), hash_u32(settings.seed ^ hash_u32(pixel as u32 ^ 0x243f_6a88)))
    } else {
        (0, hit_scramble(i, settings))
    }
}

/// The reconstruction rays of primary hit `i`: origin lifted along the normal, directions
/// cosine-distributed about it.
fn hit_rays(samples: &IndirectSamples, i: usize, per_hit: u32, settings: &GatherSettings) -> impl Iterator<Item = Ray> {
    let (block, scramble) = direction_block(samples, i, per_hit, settings);
    cosine_rays(samples.primary_hit[i], samples.primary_normal[i], settings.offset, (block, per_hit), scramble)
}

/// The weighted reconstruction rays of glossy primary hit `i`, drawn from its own BSDF
/// (`bsdf_rays`): from the block of [`direction_block`] where they all come from one lobe,
/// else from a sequence of the hit's own ([`single_lobe`] says why).
fn weighted_rays<'a>(
    samples: &IndirectSamples,
    shading: &'a [PrimaryShading],
    i: usize,
    per_hit: u32,
    settings: &GatherSettings,
) -> impl Iterator<Item = WeightedRay> + 'a {
    let (o, normal) = (samples.primary_hit[i], samples.primary_normal[i]);
    let (block, scramble) = if single_lobe(&shading[i], normal, per_hit) {
        direction_block(samples, i, per_hit, settings)
    } else {
        (0, hit_scramble(i, settings))
    };
    bsdf_rays(&shading[i], o, normal, (block, per_hit), scramble, settings.offset)
}

/// The seed of primary hit i's directions.
fn hit_scramble(i: usize, settings: &GatherSettings) -> u32 {
    hash_u32(settings.seed ^ hash_u32(i as u32 ^ 0x6a09_e667))
}

#[allow(clippy::too_many_arguments)]
fn indirect_at(
    samples: &IndirectSamples,
    i: usize,
    albedo: [f32; 3],
    reconstructor: &Reconstructor,
    sky: (&[SkySample], Option<f32>),
    (per_hit, settings): (u32, &GatherSettings),
    scratch: &mut Scratch,
    (stats, spread): (&mut GatherStats, &mut RaySpread),
) -> [f32; 3] {
    let class = samples.class[i];
    if class == SampleClass::CameraMiss {
        return [0.0; 3];
    }
    stats.primary_hits += 1;
    let (mut sum, mut supported) = ([0.0f64; 3], 0u32);
    let mut add = |l: [f32; 3], weight: [f32; 3]| {
        for c in 0..3 {
            sum[c] += (weight[c] * l[c]) as f64;
        }
        supported += 1;
    };
    let scale = match &samples.primary_shading {
        // Lambertian o (all-diffuse files): cosine rays, the albedo as their common weight.
        None => {
            for ray in hit_rays(samples, i, per_hit, settings) {
                if let Some(l) =
                    reconstructor.radiance_or_sky(&ray, sky, scratch, &mut stats.reconstruct, &mut stats.fallbacks)
                {
                    add(l, [1.0; 3]);
                    spread.add(l);
                }
            }
            albedo
        }
        // o's own BSDF: directions and weights f·cos/p from it (`bsdf_rays`).
        Some(shading) => {
            for weighted in weighted_rays(samples, shading, i, per_hit, settings) {
                match weighted.ray {
                    // Below the surface: a sample of value 0, as the tracer counts it.
                    None => add([0.0; 3], [0.0; 3]),
                    Some(ray) => {
                        if let Some(l) = reconstructor.radiance_or_sky(
                            &ray,
                            sky,
                            scratch,
                            &mut stats.reconstruct,
                            &mut stats.fallbacks,
                        ) {
                            add(l, weighted.weight);
                        }
                    }
                }
            }
            [1.0; 3]
        }
    };
    if supported > 0 {
        return [0, 1, 2].map(|c| scale[c] * (sum[c] / supported as f64) as f32);
    }
    // No support at all: the sample's own estimate, weight · L (the box value).
    stats.unsupported_hits += 1;
    match class {
        SampleClass::Hit | SampleClass::Escaped => {
            let weight = samples.weight.as_ref().map_or(albedo, |w| w[i]);
            let radiance = samples.radiance.as_ref().map_or([0.0; 3], |r| r[i]);
            [0, 1, 2].map(|c| weight[c] * radiance[c])
        }
        SampleClass::CameraMiss | SampleClass::NoSecondaryRay => [0.0; 3],
    }
}

fn visibility_at(
    samples: &IndirectSamples,
    i: usize,
    ao_radius: f32,
    reconstructor: &Reconstructor,
    (per_hit, settings): (u32, &GatherSettings),
    scratch: &mut Scratch,
    stats: &mut GatherStats,
) -> [f32; 3] {
    if samples.class[i] == SampleClass::CameraMiss {
        return [1.0; 3];
    }
    stats.primary_hits += 1;
    let mut sum = 0.0f64;
    for ray in hit_rays(samples, i, per_hit, settings) {
        sum += reconstructor.visibility(&ray, ao_radius, scratch, &mut stats.reconstruct) as f64;
    }
    [(sum / per_hit as f64) as f32; 3]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The variance of the mean from Σ y, Σ y²: the unbiased sample variance over the count,
    /// computed directly for four rays; fewer than two rays are unknown; non-finite radiance
    /// is not counted.
    #[test]
    fn a_pixels_spread_is_the_variance_of_its_rays_mean() {
        let mut spread = RaySpread::default();
        assert_eq!(spread.variance_of_mean(), f32::INFINITY);
        spread.add([2.0; 3]);
        assert_eq!(spread.variance_of_mean(), f32::INFINITY, "one ray: unknown");
        spread.add([f32::NAN; 3]);
        for y in [4.0, 6.0, 8.0] {
            spread.add([y; 3]); // grey: luminance y
        }
        // y = 2, 4, 6, 8: mean 5, unbiased variance (9 + 1 + 1 + 9) / 3 = 20/3, of the mean 5/3.
        assert!((spread.variance_of_mean() - 5.0 / 3.0).abs() < 1e-5, "{}", spread.variance_of_mean());
    }

    #[test]
    fn rays_per_hit_rounds_up_and_gives_every_hit_one() {
        assert_eq!(rays_per_hit(256, 4), 64);
        assert_eq!(rays_per_hit(10, 4), 3);
        assert_eq!(rays_per_hit(0, 4), 1);
    }
}
