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
//!
//! Order of work (speed only): the image is gathered in 16 × 16-pixel tiles; a tile's rays are
//! all drawn first and reconstructed in the order of their directions
//! (`trace_in_direction_order`), so that consecutive walks of the splat hierarchy reuse the
//! nodes in the cache, and each hit's estimate is then formed from its own rays in their own
//! order — the pixels of a ray-by-ray gather bit for bit (tested against one).

use rayon::prelude::*;
use shading::sampling::hash_u32;

use super::bsdf_rays::{bsdf_rays, single_lobe, WeightedRay};
use super::cache::{cached_radiance, CacheParams, CacheStats};
use super::directions::cosine_rays;
use super::disc::Ray;
use super::ray_order::{direction_order, trace_in_direction_order};
use std::ops::Range;

use super::reconstruct::{or_sky, ReconstructStats, Reconstructor, Scratch, SkyFallbacks, SkySample};
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
    /// Gather indirect light at Lambertian hits through records and interpolation
    /// ([`super::cache`]); `None`: every hit gathers its own rays.
    pub cache: Option<CacheParams>,
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
            cache: None,
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
    /// With records ([`super::cache`]): (records, hits interpolated, hits gathered on their own).
    pub cache: Option<(u64, u64, u64)>,
    /// With the sparse gather ([`super::sparse`]): (grid pixels, pixels interpolated whole,
    /// pixels with hits refined by a gather of their own, those hits, of those the ones refined
    /// for their corners' disagreement rather than their geometry).
    pub sparse: Option<(u64, u64, u64, u64, u64)>,
}

impl GatherStats {
    pub(super) fn add(&mut self, other: &GatherStats) {
        self.reconstruct.add(&other.reconstruct);
        self.primary_hits += other.primary_hits;
        self.fallbacks.add(&other.fallbacks);
        self.unsupported_hits += other.unsupported_hits;
        if let Some((r, i, u)) = other.cache {
            let (a, b, c) = self.cache.unwrap_or_default();
            self.cache = Some((a + r, b + i, c + u));
        }
        if let Some((g, i, r, h, l)) = other.sparse {
            let (a, b, c, d, e) = self.sparse.unwrap_or_default();
            self.sparse = Some((a + g, b + i, c + r, d + h, e + l));
        }
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
            Some(samples.albedo.as_deref().ok_or_else(|| content("indirect light needs the field `albedo`"))?)
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
    if let (Some(cache), Some(albedo), None) = (&settings.cache, albedo, &samples.primary_shading) {
        return Ok(gather_cached(samples, reconstructor, albedo, cache, (per_hit, settings)));
    }
    let layout = TileLayout::of(samples, per_hit);
    crate::progress::begin("gather", layout.count() as u64, "tiles");
    let tiles: Vec<TileGather> = (0..layout.count())
        .into_par_iter()
        // One tile per job: tiles differ in cost several times over, and a run of tiles that
        // rayon hands one thread whole cannot be shared (the other thread idled up to 0.15 s
        // at the end of Sponza's gather).
        .with_max_len(1)
        .map(|t| {
            let tile = layout.tile(t);
            let gathered = gather_tile(samples, reconstructor, (albedo, ao_radius), tile, (per_hit, settings));
            crate::progress::advance(1);
            gathered
        })
        .collect();
    crate::progress::end();
    let pixel_count = width as usize * height as usize;
    let mut pixels = vec![[0.0f32; 3]; pixel_count];
    let mut variance = if ao_radius.is_none() { vec![f32::INFINITY; pixel_count] } else { Vec::new() };
    let mut stats = GatherStats::default();
    for gathered in &tiles {
        for (k, (x, y)) in gathered.tile.pixels().enumerate() {
            let p = y as usize * width as usize + x as usize;
            pixels[p] = gathered.pixels[k];
            if let Some(v) = gathered.variance.get(k) {
                variance[p] = *v;
            }
        }
        stats.add(&gathered.stats);
    }
    Ok((Image::from_pixels(width, height, pixels), stats, variance))
}

/// The indirect light at Lambertian primary hits through records and interpolation
/// ([`super::cache`]); a hit no record covers gathers its own `per_hit` rays, as the plain gather
/// does, and one without any support keeps its input estimate. Variances are unknown (+inf).
fn gather_cached(
    samples: &IndirectSamples,
    reconstructor: &Reconstructor,
    albedo: &[[f32; 3]],
    cache: &CacheParams,
    (per_hit, settings): (u32, &GatherSettings),
) -> (Image, GatherStats, Vec<f32>) {
    let (width, height, spp) = (samples.width, samples.height, samples.spp.max(1) as usize);
    let sky = |x: u32, y: u32| {
        let mut sky = Vec::new();
        let spacing = sky_samples(samples, x, y, settings.sky_pixel_radius, &mut sky);
        let min_cosine = spacing.map(|s| (settings.sky_spacing_factor * s).min(std::f32::consts::PI).cos());
        (sky, min_cosine)
    };
    let per_hit_gather = |i: usize, scratch: &mut Scratch, stats: &mut CacheStats| {
        let pixel = (i / spp) as u32;
        let (sky, min_cosine) = sky(pixel % width, pixel / width);
        let (mut sum, mut supported) = ([0.0f64; 3], 0u32);
        for ray in hit_rays(samples, i, per_hit, settings) {
            let found = reconstructor.radiance(&ray, scratch, &mut stats.reconstruct).map(|f| f.radiance);
            if let Some(l) = or_sky(found, ray.direction, (&sky, min_cosine), &mut stats.fallbacks) {
                (0..3).for_each(|c| sum[c] += l[c] as f64);
                supported += 1;
            }
        }
        (supported > 0).then(|| sum.map(|s| (s / supported as f64) as f32))
    };
    let (radiance, cached) =
        cached_radiance(samples, reconstructor, cache, (settings.seed, settings.offset), &sky, &per_hit_gather);
    let mut stats = GatherStats {
        reconstruct: cached.reconstruct,
        fallbacks: cached.fallbacks,
        cache: Some((cached.records, cached.interpolated, cached.uncovered)),
        ..GatherStats::default()
    };
    let mut pixels = Vec::with_capacity(width as usize * height as usize);
    for p in 0..width as usize * height as usize {
        let mut sum = [0.0f64; 3];
        for i in p * spp..(p + 1) * spp {
            let value = match (samples.class[i], radiance[i]) {
                (SampleClass::CameraMiss, _) => [0.0; 3],
                (_, Some(l)) => {
                    stats.primary_hits += 1;
                    [0, 1, 2].map(|c| albedo[i][c] * l[c])
                }
                (class, None) => {
                    stats.primary_hits += 1;
                    stats.unsupported_hits += 1;
                    match class {
                        SampleClass::Hit | SampleClass::Escaped => {
                            let l = samples.radiance.as_ref().map_or([0.0; 3], |r| r[i]);
                            [0, 1, 2].map(|c| albedo[i][c] * l[c])
                        }
                        _ => [0.0; 3],
                    }
                }
            };
            (0..3).for_each(|c| sum[c] += value[c] as f64);
        }
        pixels.push(sum.map(|s| (s / spp as f64) as f32));
    }
    let variance = vec![f32::INFINITY; pixels.len()];
    (Image::from_pixels(width, height, pixels), stats, variance)
}

/// Pixels per side of the square tiles the gather works in: a tile's rays are reconstructed in
/// direction order ([`trace_in_direction_order`]); 16 unless that would hold more than
/// [`MAX_TILE_RAYS`] rays.
pub(super) const TILE: u32 = 16;

/// The most rays a tile holds at once (≈ 4 MB of rays and results), so that the tiles' memory
/// stays bounded at any number of rays per pixel.
const MAX_TILE_RAYS: u64 = 1 << 16;

/// The side of the gather's tiles for `rays_per_pixel`: [`TILE`], or less (at least 1) so
/// that a tile holds at most [`MAX_TILE_RAYS`] rays where a pixel has fewer than that.
pub(super) fn tile_side(rays_per_pixel: u64) -> u32 {
    let rays = rays_per_pixel.max(1);
    (1..=TILE).rev().find(|&side| (side as u64 * side as u64).saturating_mul(rays) <= MAX_TILE_RAYS).unwrap_or(1)
}

/// How the gather cuts the image into tiles: `side` × `side` pixels, row by row.
struct TileLayout {
    width: u32,
    height: u32,
    side: u32,
}

impl TileLayout {
    /// The layout for `samples` with `per_hit` rays per primary hit ([`tile_side`]).
    fn of(samples: &IndirectSamples, per_hit: u32) -> TileLayout {
        let side = tile_side(samples.spp.max(1) as u64 * per_hit as u64);
        TileLayout { width: samples.width, height: samples.height, side }
    }

    fn count(&self) -> u32 {
        self.width.div_ceil(self.side) * self.height.div_ceil(self.side)
    }

    /// Tile `t`, counted row by row.
    fn tile(&self, t: u32) -> Tile {
        let tiles_x = self.width.div_ceil(self.side);
        let (x0, y0) = ((t % tiles_x) * self.side, (t / tiles_x) * self.side);
        Tile { xs: x0..(x0 + self.side).min(self.width), ys: y0..(y0 + self.side).min(self.height) }
    }
}

/// The pixels of one tile.
struct Tile {
    xs: Range<u32>,
    ys: Range<u32>,
}

impl Tile {
    /// Its pixels, row by row.
    fn pixels(&self) -> impl Iterator<Item = (u32, u32)> + '_ {
        self.ys.clone().flat_map(move |y| self.xs.clone().map(move |x| (x, y)))
    }
}

/// A tile, its pixels row by row, their variances (indirect light only) and its counts.
struct TileGather {
    tile: Tile,
    pixels: Vec<[f32; 3]>,
    variance: Vec<f32>,
    stats: GatherStats,
}

/// Gathers one tile: every reconstruction ray of its primary hits is generated first, the rays
/// are reconstructed in direction order, and then each hit's estimate is formed from its own
/// rays in their order — each ray's result is a pure function of the ray, so the pixels are
/// those of a gather ray by ray, bit for bit.
fn gather_tile(
    samples: &IndirectSamples,
    reconstructor: &Reconstructor,
    (albedo, ao_radius): (Option<&[[f32; 3]]>, Option<f32>),
    tile: Tile,
    (per_hit, settings): (u32, &GatherSettings),
) -> TileGather {
    let pixel_list: Vec<(u32, u32)> = tile.pixels().collect();
    let Some(ao_radius) = ao_radius else {
        let gathered = gather_indirect_pixels(samples, reconstructor, albedo, &pixel_list, (per_hit, settings));
        return TileGather { tile, pixels: gathered.values, variance: gathered.variance, stats: gathered.stats };
    };
    let spp = samples.spp.max(1) as usize;
    let width = samples.width as usize;
    let (rays, ends) = tile_rays(samples, &pixel_list, true, (per_hit, settings));
    let mut stats = GatherStats::default();
    let mut pixels = Vec::with_capacity(pixel_list.len());
    let (visible, reconstruct) =
        trace_in_direction_order(&rays, |ray, scratch, stats| reconstructor.visibility(ray, ao_radius, scratch, stats));
    stats.reconstruct = reconstruct;
    let mut begin = 0;
    for (pixel, &(x, y)) in pixel_list.iter().enumerate() {
        let mut sum = 0.0f64;
        let first = (y as usize * width + x as usize) * spp;
        for (k, i) in (first..first + spp).enumerate() {
            let end = ends[pixel * spp + k];
            sum += visibility_at(samples, i, &visible[begin..end], per_hit, &mut stats) as f64;
            begin = end;
        }
        pixels.push([(sum / spp as f64) as f32; 3]);
    }
    TileGather { tile, pixels, variance: Vec::new(), stats }
}

/// The indirect light of a list of pixels, each gathered as the full gather gathers it.
pub(super) struct IndirectPixels {
    /// Per pixel of the list, in its order.
    pub values: Vec<[f32; 3]>,
    /// Per pixel, [`RaySpread::variance_of_mean`].
    pub variance: Vec<f32>,
    /// Per primary hit of each pixel (spp per pixel, in order): the mean radiance of its
    /// supported cosine rays, the light before its albedo (`None`: a camera miss, a hit without
    /// support, or a glossy hit).
    pub hit_radiance: Vec<Option<[f32; 3]>>,
    pub stats: GatherStats,
}

/// Gathers the indirect light of `pixels` (any set, in any order): their rays are generated
/// first and reconstructed together in direction order, then each hit's estimate is formed
/// from its own rays in their order, so that every pixel is the one the ray-by-ray gather
/// gives it, bit for bit, whatever else is in the list.
pub(super) fn gather_indirect_pixels(
    samples: &IndirectSamples,
    reconstructor: &Reconstructor,
    albedo: Option<&[[f32; 3]]>,
    pixels: &[(u32, u32)],
    (per_hit, settings): (u32, &GatherSettings),
) -> IndirectPixels {
    let spp = samples.spp.max(1) as usize;
    let width = samples.width as usize;
    let (rays, ends) = tile_rays(samples, pixels, false, (per_hit, settings));
    let (found, reconstruct) = trace_in_direction_order(&rays, |ray, scratch, stats| {
        reconstructor.radiance(ray, scratch, stats).map(|f| f.radiance)
    });
    let mut out = IndirectPixels {
        values: Vec::with_capacity(pixels.len()),
        variance: Vec::with_capacity(pixels.len()),
        hit_radiance: Vec::with_capacity(pixels.len() * spp),
        stats: GatherStats { reconstruct, ..GatherStats::default() },
    };
    let mut sky = Vec::new();
    let mut begin = 0;
    for (pixel, &(x, y)) in pixels.iter().enumerate() {
        let sky_spacing = sky_samples(samples, x, y, settings.sky_pixel_radius, &mut sky);
        let min_cosine = sky_spacing.map(|spacing| {
            let angle = (settings.sky_spacing_factor * spacing).min(std::f32::consts::PI);
            angle.cos()
        });
        let mut spread = RaySpread::default();
        let mut sum = [0.0f64; 3];
        let first = (y as usize * width + x as usize) * spp;
        for (k, i) in (first..first + spp).enumerate() {
            let end = ends[pixel * spp + k];
            let (value, mean) = indirect_at(
                samples,
                i,
                albedo.map(|a| a[i]).unwrap_or([0.0; 3]),
                (&rays[begin..end], &found[begin..end]),
                (&sky, min_cosine),
                (&mut out.stats, &mut spread),
            );
            out.hit_radiance.push(mean);
            begin = end;
            for c in 0..3 {
                sum[c] += value[c] as f64;
            }
        }
        out.variance.push(spread.variance_of_mean());
        out.values.push(sum.map(|s| (s / spp as f64) as f32));
    }
    out
}

/// The weighted rays of every primary hit of `pixels` (in their order, each pixel's hits in
/// order; for ambient occlusion `ao`, cosine rays at every hit), and where each hit's rays end
/// in that list (camera misses have none).
fn tile_rays(
    samples: &IndirectSamples,
    pixels: &[(u32, u32)],
    ao: bool,
    (per_hit, settings): (u32, &GatherSettings),
) -> (Vec<WeightedRay>, Vec<usize>) {
    let spp = samples.spp.max(1) as usize;
    let width = samples.width as usize;
    let (mut rays, mut ends) = (Vec::new(), Vec::new());
    for &(x, y) in pixels {
        let first = (y as usize * width + x as usize) * spp;
        for i in first..first + spp {
            if samples.class[i] != SampleClass::CameraMiss {
                match (&samples.primary_shading, ao) {
                    (Some(shading), false) => rays.extend(weighted_rays(samples, shading, i, per_hit, settings)),
                    _ => rays.extend(
                        hit_rays(samples, i, per_hit, settings)
                            .map(|ray| WeightedRay { ray: Some(ray), weight: [1.0; 3] }),
                    ),
                }
            }
            ends.push(rays.len());
        }
    }
    (rays, ends)
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

/// Gathers the indirect light of single Lambertian primary hits (`hits`, sample indices, any
/// set, in any order): their rays reconstructed together in direction order, then each hit's
/// value formed from its own rays as the full gather forms it, bit for bit.
pub(super) fn gather_indirect_hits(
    samples: &IndirectSamples,
    reconstructor: &Reconstructor,
    albedo: &[[f32; 3]],
    hits: &[usize],
    (per_hit, settings): (u32, &GatherSettings),
) -> (Vec<[f32; 3]>, GatherStats) {
    let spp = samples.spp.max(1) as usize;
    let (mut rays, mut ends) = (Vec::new(), Vec::with_capacity(hits.len()));
    for &i in hits {
        if samples.class[i] != SampleClass::CameraMiss {
            rays.extend(
                hit_rays(samples, i, per_hit, settings).map(|ray| WeightedRay { ray: Some(ray), weight: [1.0; 3] }),
            );
        }
        ends.push(rays.len());
    }
    let (found, reconstruct) = trace_in_direction_order(&rays, |ray, scratch, stats| {
        reconstructor.radiance(ray, scratch, stats).map(|f| f.radiance)
    });
    let mut stats = GatherStats { reconstruct, ..GatherStats::default() };
    let (mut sky, mut spread) = (Vec::new(), RaySpread::default());
    let mut values = Vec::with_capacity(hits.len());
    let mut begin = 0;
    for (k, &i) in hits.iter().enumerate() {
        let pixel = (i / spp) as u32;
        let (x, y) = (pixel % samples.width, pixel / samples.width);
        let sky_spacing = sky_samples(samples, x, y, settings.sky_pixel_radius, &mut sky);
        let min_cosine = sky_spacing.map(|spacing| {
            let angle = (settings.sky_spacing_factor * spacing).min(std::f32::consts::PI);
            angle.cos()
        });
        let end = ends[k];
        let (value, _) = indirect_at(
            samples,
            i,
            albedo[i],
            (&rays[begin..end], &found[begin..end]),
            (&sky, min_cosine),
            (&mut stats, &mut spread),
        );
        begin = end;
        values.push(value);
    }
    (values, stats)
}

/// Every ray the gather of the `indirect` target reconstructs (none where a BSDF direction
/// points below the surface), in the order the gather reconstructs them — tile by tile, each
/// tile's in `direction_order` — so that a benchmark tracing the same rays with another
/// engine gets the same coherence.
pub fn reconstruction_rays(samples: &IndirectSamples, settings: &GatherSettings) -> Vec<Ray> {
    let per_hit = rays_per_hit(settings.rays_per_pixel, samples.spp.max(1));
    let layout = TileLayout::of(samples, per_hit);
    let mut out = Vec::new();
    for t in 0..layout.count() {
        let pixels: Vec<(u32, u32)> = layout.tile(t).pixels().collect();
        let (rays, _) = tile_rays(samples, &pixels, false, (per_hit, settings));
        out.extend(direction_order(&rays).filter_map(|k| rays[k].ray));
    }
    out
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

/// Primary hit `i`'s indirect light from its weighted `rays` and what the reconstruction
/// found along each (`found`, the same length; a sky sample where it found nothing), and at a
/// Lambertian hit with support the mean radiance of its rays (the light before the albedo).
fn indirect_at(
    samples: &IndirectSamples,
    i: usize,
    albedo: [f32; 3],
    (rays, found): (&[WeightedRay], &[Option<[f32; 3]>]),
    sky: (&[SkySample], Option<f32>),
    (stats, spread): (&mut GatherStats, &mut RaySpread),
) -> ([f32; 3], Option<[f32; 3]>) {
    let class = samples.class[i];
    if class == SampleClass::CameraMiss {
        return ([0.0; 3], None);
    }
    stats.primary_hits += 1;
    let (mut sum, mut supported) = ([0.0f64; 3], 0u32);
    let lambertian = samples.primary_shading.is_none();
    for (weighted, found) in rays.iter().zip(found) {
        let Some(ray) = weighted.ray else {
            // Below the surface (glossy o only): a supported sample of value 0, as the tracer
            // counts it.
            supported += 1;
            continue;
        };
        if let Some(l) = or_sky(*found, ray.direction, sky, &mut stats.fallbacks) {
            for c in 0..3 {
                sum[c] += (weighted.weight[c] * l[c]) as f64;
            }
            supported += 1;
            if lambertian {
                spread.add(l);
            }
        }
    }
    // Lambertian o (all-diffuse files): cosine rays, the albedo as their common weight; else
    // o's own BSDF's weights f·cos/p (`bsdf_rays`), already applied.
    let scale = if lambertian { albedo } else { [1.0; 3] };
    if supported > 0 {
        let mean = [0, 1, 2].map(|c| (sum[c] / supported as f64) as f32);
        return ([0, 1, 2].map(|c| scale[c] * mean[c]), lambertian.then_some(mean));
    }
    // No support at all: the sample's own estimate, weight · L (the box value).
    stats.unsupported_hits += 1;
    match class {
        SampleClass::Hit | SampleClass::Escaped => {
            let weight = samples.weight.as_ref().map_or(albedo, |w| w[i]);
            let radiance = samples.radiance.as_ref().map_or([0.0; 3], |r| r[i]);
            ([0, 1, 2].map(|c| weight[c] * radiance[c]), None)
        }
        SampleClass::CameraMiss | SampleClass::NoSecondaryRay => ([0.0; 3], None),
    }
}

/// Primary hit `i`'s ambient visibility, the mean of its `per_hit` rays' (`visible`).
fn visibility_at(samples: &IndirectSamples, i: usize, visible: &[f32], per_hit: u32, stats: &mut GatherStats) -> f32 {
    if samples.class[i] == SampleClass::CameraMiss {
        return 1.0;
    }
    stats.primary_hits += 1;
    let sum: f64 = visible.iter().map(|&v| v as f64).sum();
    (sum / per_hit as f64) as f32
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ilfr::bvh::DiscBvh;
    use crate::ilfr::disc::Disc;
    use crate::ilfr::filter::SplatShading;
    use crate::ilfr::pipeline::tests::box_samples;
    use crate::ilfr::ray_order::direction_key;
    use crate::ilfr::reconstruct::RayModel;
    use crate::ilfr::surfaces::SurfaceParams;
    use crate::lcg::Lcg;
    use sampleio::SampleKind;

    /// The gather written ray by ray, pixel by pixel, each ray reconstructed where it is drawn
    /// (the gather before its tiles, kept as the oracle of the tiled, direction-ordered one):
    /// the indirect light and variances, or with `ao_radius` the visibility.
    fn gather_ray_by_ray(
        samples: &IndirectSamples,
        reconstructor: &Reconstructor,
        ao_radius: Option<f32>,
        settings: &GatherSettings,
    ) -> (Vec<[f32; 3]>, Vec<f32>, GatherStats) {
        let spp = samples.spp as usize;
        let per_hit = rays_per_hit(settings.rays_per_pixel, samples.spp);
        let (mut scratch, mut stats, mut sky) = (Scratch::default(), GatherStats::default(), Vec::new());
        let (mut pixels, mut variances) = (Vec::new(), Vec::new());
        for y in 0..samples.height {
            for x in 0..samples.width {
                let spacing = sky_samples(samples, x, y, settings.sky_pixel_radius, &mut sky);
                let min_cosine = spacing.map(|s| (settings.sky_spacing_factor * s).min(std::f32::consts::PI).cos());
                let (mut pixel, mut spread) = ([0.0f64; 3], RaySpread::default());
                let first = (y * samples.width + x) as usize * spp;
                for i in first..first + spp {
                    if samples.class[i] == SampleClass::CameraMiss {
                        let miss = if ao_radius.is_some() { 1.0 } else { 0.0 };
                        pixel = pixel.map(|v| v + miss);
                        continue;
                    }
                    stats.primary_hits += 1;
                    let value = match ao_radius {
                        Some(radius) => {
                            let mut sum = 0.0f64;
                            for ray in hit_rays(samples, i, per_hit, settings) {
                                sum +=
                                    reconstructor.visibility(&ray, radius, &mut scratch, &mut stats.reconstruct) as f64;
                            }
                            [(sum / per_hit as f64) as f32; 3]
                        }
                        None => {
                            let (mut sum, mut supported) = ([0.0f64; 3], 0u32);
                            for ray in hit_rays(samples, i, per_hit, settings) {
                                let found = reconstructor.radiance_or_sky(
                                    &ray,
                                    (&sky, min_cosine),
                                    &mut scratch,
                                    &mut stats.reconstruct,
                                    &mut stats.fallbacks,
                                );
                                if let Some(l) = found {
                                    (0..3).for_each(|c| sum[c] += l[c] as f64);
                                    supported += 1;
                                    spread.add(l);
                                }
                            }
                            let albedo = samples.albedo.as_ref().unwrap()[i];
                            assert!(supported > 0, "the oracle's scene supports every hit");
                            [0, 1, 2].map(|c| albedo[c] * (sum[c] / supported as f64) as f32)
                        }
                    };
                    (0..3).for_each(|c| pixel[c] += value[c] as f64);
                }
                pixels.push(pixel.map(|v| (v / spp as f64) as f32));
                variances.push(spread.variance_of_mean());
            }
        }
        (pixels, variances, stats)
    }

    /// Splats on the floor, walls and ceiling of the box of `box_samples`, with random normals
    /// tilted up to ~25°, radii and radiance, plus a cloud of small splats inside it: rays meet
    /// stacked surfaces, small ones and (through gaps, the ceiling being open) the sky.
    fn cluttered_box() -> (Vec<Disc>, Vec<[f32; 3]>, Vec<[f32; 3]>) {
        let mut rng = Lcg(99);
        let (mut discs, mut radiance, mut direction) = (Vec::new(), Vec::new(), Vec::new());
        for k in 0..1500 {
            let (u, v) = (rng.uniform() * 2.0 - 1.0, rng.uniform() * 2.0 - 1.0);
            let (centre, normal) = match k % 6 {
                0 => ([u, v, 0.0], [0.0, 0.0, 1.0]),
                1 => ([-1.0, u, 1.0 + v], [1.0, 0.0, 0.0]),
                2 => ([1.0, u, 1.0 + v], [-1.0, 0.0, 0.0]),
                3 => ([u, -1.0, 1.0 + v], [0.0, 1.0, 0.0]),
                4 => ([u, 1.0, 1.0 + v], [0.0, -1.0, 0.0]),
                _ => ([0.6 * u, 0.6 * v, 0.3 + 1.2 * rng.uniform()], [u, v, 1.0]),
            };
            let tilt = [rng.uniform() - 0.5, rng.uniform() - 0.5, rng.uniform() - 0.5].map(|t| 0.9 * t);
            let normal = [0, 1, 2].map(|a| normal[a] + tilt[a]);
            let radius = if k % 6 == 5 { 0.03 + 0.05 * rng.uniform() } else { 0.05 + 0.15 * rng.uniform() };
            discs.push(Disc::new(centre, normal, radius));
            radiance.push([rng.uniform(), 2.0 * rng.uniform(), 0.5]);
            direction.push([0.0, 0.0, -1.0]);
        }
        (discs, radiance, direction)
    }

    /// The tiled gather (rays reconstructed in direction order, tiles in parallel) gives the
    /// ray-by-ray gather's pixels, variances and counts bit for bit: indirect light and ambient
    /// occlusion, images whose sides are not multiples of the tile (16 and, at 3000 rays per
    /// pixel, 4 pixels), 1 and 3 threads.
    #[test]
    fn the_tiled_gather_is_the_ray_by_ray_gather_bit_for_bit() {
        let (discs, radiance, direction) = cluttered_box();
        let bvh = DiscBvh::build(&discs).unwrap();
        let shading = SplatShading { radiance: &radiance, direction: &direction, kappa: None };
        let reconstructor =
            Reconstructor { bvh: &bvh, shading, surfaces: SurfaceParams::default(), model: RayModel::ApparentSurfaces };
        let settings = GatherSettings { rays_per_pixel: 12, seed: 5, ..GatherSettings::default() };
        let indirect = box_samples(21, 3, SampleKind::Indirect, Some(1.5), |h| [h[2], 1.0, 0.25]);
        let ao = box_samples(21, 3, SampleKind::Ao, Some(1.5), |_| [0.0; 3]);
        // Many rays per pixel: tiles 4 pixels wide (`tile_side(3000)`), 7 not a multiple of it.
        let many = box_samples(7, 3, SampleKind::Indirect, Some(1.5), |h| [h[2], 1.0, 0.25]);
        let many_settings = GatherSettings { rays_per_pixel: 3000, ..settings };
        for (samples, ao_radius, settings) in
            [(&indirect, None, settings), (&ao, Some(0.7f32), settings), (&many, None, many_settings)]
        {
            let settings = &settings;
            let (pixels, variances, stats) = gather_ray_by_ray(samples, &reconstructor, ao_radius, settings);
            assert!(stats.fallbacks.sky_rays > 0 || ao_radius.is_some(), "some rays take the sky: {stats:?}");
            assert!(stats.reconstruct.merged_small_surfaces > 0, "small surfaces occur: {stats:?}");
            for threads in [1, 3] {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
                let (image, tiled_stats, tiled_variances) =
                    pool.install(|| gather_with_spread(samples, &reconstructor, ao_radius, settings)).unwrap();
                assert_eq!(image.pixels, pixels, "{ao_radius:?}, {threads} threads");
                assert_eq!(tiled_stats, stats, "{ao_radius:?}, {threads} threads");
                if ao_radius.is_none() {
                    assert_eq!(
                        tiled_variances.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                        variances.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
                    );
                } else {
                    assert!(tiled_variances.is_empty());
                }
            }
        }
    }

    /// The benchmark's replay holds every ray the gather draws, hit by hit, once (the same
    /// multiset), and within each tile in non-decreasing direction key.
    #[test]
    fn the_replayed_rays_are_the_gathers_in_its_order() {
        let samples = box_samples(21, 3, SampleKind::Indirect, Some(1.5), |h| [h[2], 1.0, 0.25]);
        let settings = GatherSettings { rays_per_pixel: 12, seed: 5, ..GatherSettings::default() };
        let replayed = reconstruction_rays(&samples, &settings);
        let per_hit = rays_per_hit(settings.rays_per_pixel, samples.spp);
        let by_hit: Vec<Ray> = (0..samples.len()).flat_map(|i| hit_rays(&samples, i, per_hit, &settings)).collect();
        let bits = |rays: &[Ray]| {
            let mut b: Vec<_> =
                rays.iter().map(|r| (r.origin.map(f32::to_bits), r.direction.map(f32::to_bits))).collect();
            b.sort();
            b
        };
        assert_eq!(bits(&replayed), bits(&by_hit));
        // 21² pixels in 16-pixel tiles: 16², 5 × 16, 16 × 5 and 5² pixels, 12 rays each.
        let mut start = 0;
        for pixels in [256, 80, 80, 25] {
            let tile = &replayed[start..start + pixels * 12];
            assert!(tile.windows(2).all(|w| direction_key(w[0].direction) <= direction_key(w[1].direction)));
            start += pixels * 12;
        }
        assert_eq!(start, replayed.len());
    }

    /// Tiles are 16 pixels wide up to 256 rays per pixel, then narrower so that they hold at
    /// most 2^16 rays, and one pixel wide past that.
    #[test]
    fn tiles_hold_a_bounded_number_of_rays() {
        assert_eq!(tile_side(0), 16);
        assert_eq!(tile_side(32), 16);
        assert_eq!(tile_side(256), 16);
        assert_eq!(tile_side(257), 15);
        assert_eq!(tile_side(3000), 4);
        assert_eq!(tile_side(1 << 16), 1);
        assert_eq!(tile_side(u64::MAX), 1);
        for rays in [1u64, 100, 300, 1000, 5000, 20000, 1 << 16] {
            let side = tile_side(rays) as u64;
            assert!(side * side * rays <= MAX_TILE_RAYS, "{rays} rays per pixel: side {side}");
            assert!(
                (side + 1) * (side + 1) * rays > MAX_TILE_RAYS || side == 16,
                "{rays}: side {side} could be larger"
            );
        }
    }

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
