//! Beyond the paper: the final gather (Eq. 3) at a sparse grid of pixels, the light of the
//! others interpolated from the grid with geometry-aware weights (a joint-bilateral upsample
//! guided by the primary hits, as in irradiance caching's error estimate), and a full gather
//! wherever the interpolation's error estimate says it cannot be trusted.
//!
//! - The grid: every pixel whose column and row are multiples of [`SparseParams::stride`], and
//!   the last column and row, so that every pixel lies in a cell of up to four grid corners.
//!   Grid pixels gather [`SparseParams::grid_ray_factor`] times the pixel budget of rays,
//!   exactly as the full gather does at that budget ([`super::gather::gather_indirect_pixels`]);
//!   so do refined hits (below), so that the gathered values share one noise level.
//! - What is interpolated is each Lambertian hit's mean radiance L̄ (the light before its albedo);
//!   a hit x with normal m of another pixel takes L̄(x) = Σ b_k g(x, j) L̄_j / Σ b_k g(x, j) over the
//!   hits j of its cell's corners k, b_k the bilinear weight of corner k and g the geometric
//!   similarity of the two hits ([`similarity`]: normals within
//!   [`SparseParams::max_normal_degrees`], and each hit near the other's tangent plane, within
//!   [`SparseParams::plane_tolerance`] pixel footprints per pixel of distance), and reflects its
//!   own albedo times L̄(x): texture stays sharp.
//! - The error estimate: a hit is gathered on its own (*refined*) where it finds too
//!   little similar light among its corners (Σ b_k · mean_j g / Σ b_k below
//!   [`SparseParams::min_coverage`]: an edge, a silhouette, a crease), or where the similar
//!   corner hits disagree beyond their noise (max − min luminance of L̄ above
//!   [`SparseParams::contrast`] times their weighted mean plus [`SparseParams::noise_sigmas`]
//!   standard errors of the two, from the spread of their rays: a contact shadow, a light edge).
//!   A refined hit is the full gather's at the grid's budget, bit for bit, and a pixel all of
//!   whose hits are refined is the full gather's pixel.
//!
//! Each pixel is a function of the grid and its own rays only, so the image is the same for any
//! number of threads. Ambient occlusion and glossy primary hits keep the full gather.

use rayon::prelude::*;

use super::gather::{
    gather_indirect_hits, gather_indirect_pixels, gather_with_spread, rays_per_hit, tile_side, GatherSettings,
    GatherStats, TILE,
};
use super::reconstruct::Reconstructor;
use super::robust::luminance;
use super::samples::{IndirectSamples, SampleClass};
use crate::error::Error;
use crate::image::Image;
use crate::vector::{dot, sub};

/// Where the sparse gather gathers and how it interpolates (see the module documentation).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SparseParams {
    /// Pixels between grid columns (and rows).
    pub stride: u32,
    /// Grid pixels (and refined ones) gather this many times the pixel budget of rays.
    pub grid_ray_factor: u32,
    /// Normals this far apart are not similar.
    pub max_normal_degrees: f32,
    /// A hit is similar to another within this many pixel footprints of its tangent plane per
    /// pixel of image distance.
    pub plane_tolerance: f32,
    /// A pixel is refined where a hit's similar share of its corners is below this.
    pub min_coverage: f32,
    /// … or where its similar corner hits' luminance spreads by more than this fraction of
    /// their mean …
    pub contrast: f32,
    /// … plus this many of the two extremes' combined standard errors.
    pub noise_sigmas: f32,
}

impl Default for SparseParams {
    fn default() -> Self {
        SparseParams {
            stride: 4,
            grid_ray_factor: 4,
            max_normal_degrees: 25.0,
            plane_tolerance: 1.0,
            min_coverage: 0.6,
            contrast: 0.5,
            noise_sigmas: 2.0,
        }
    }
}

/// Whether column (or row) `x` of `n` is a grid line: a multiple of `stride`, or the last.
pub fn on_grid(x: u32, n: u32, stride: u32) -> bool {
    x % stride.max(1) == 0 || x + 1 == n
}

/// The grid lines either side of column (or row) `x` of `n` and their linear weights: one line
/// (weight 1) where `x` is on the grid, else the two around it.
fn cell(x: u32, n: u32, stride: u32) -> [(u32, f32); 2] {
    let stride = stride.max(1);
    if on_grid(x, n, stride) {
        return [(x, 1.0), (x, 0.0)];
    }
    let x0 = x / stride * stride;
    let x1 = (x0 + stride).min(n - 1);
    let t = (x - x0) as f32 / (x1 - x0) as f32;
    [(x0, 1.0 - t), (x1, t)]
}

/// The similarity in [0, 1] of hit x (normal m) to hit p (normal n) `pixels` apart in the image,
/// with `footprint` the world size of a pixel at x: 0 unless the normals lie within
/// `cos_max` of each other and each hit within `tolerance` × footprint × pixels of the other's
/// tangent plane; falling linearly to 0 towards both limits.
pub fn similarity(
    (x, m): ([f32; 3], [f32; 3]),
    (p, n): ([f32; 3], [f32; 3]),
    (footprint, pixels): (f32, f32),
    (cos_max, tolerance): (f32, f32),
) -> f32 {
    let c = dot(m, n);
    if !(c >= cos_max) {
        return 0.0;
    }
    let normal = if cos_max < 1.0 { ((c - cos_max) / (1.0 - cos_max)).min(1.0) } else { 1.0 };
    let offset = sub(x, p);
    let off_plane = dot(offset, n).abs().max(dot(offset, m).abs());
    let limit = tolerance * footprint * pixels;
    let plane = if limit > 0.0 {
        1.0 - off_plane / limit
    } else if off_plane == 0.0 {
        1.0
    } else {
        0.0
    };
    let g = normal * plane;
    if g > 0.0 {
        g
    } else {
        0.0
    }
}

/// What the grid gathered: per primary hit its mean radiance (grid pixels only), per pixel its
/// value and the variance of its mean luminance.
struct Grid {
    hit_radiance: Vec<Option<[f32; 3]>>,
    value: Vec<[f32; 3]>,
    variance: Vec<f32>,
}

/// A primary hit off the grid: interpolated (its value), or to be gathered in full for its
/// geometry (too little similar light among its corners) or for its corners' disagreeing light.
#[derive(Clone, Copy)]
enum Decision {
    Interpolated([f32; 3]),
    RefineForGeometry,
    RefineForLight,
}

/// The indirect light of `samples` by the sparse gather of `params` where it applies (an
/// all-Lambertian file with albedo and radiance, without records): the image, its counts, and
/// per pixel the variance of its gathered mean luminance (+inf for interpolated pixels:
/// unknown); elsewhere the full gather, which also reports what is wrong with an input.
pub fn gather_indirect(
    samples: &IndirectSamples,
    reconstructor: &Reconstructor,
    params: &SparseParams,
    settings: &GatherSettings,
) -> Result<(Image, GatherStats, Vec<f32>), Error> {
    let expected = samples.width as usize * samples.height as usize * samples.spp.max(1) as usize;
    let plain = samples.primary_shading.is_none()
        && samples.weight.is_none()
        && samples.radiance.is_some()
        && settings.cache.is_none()
        && settings.offset.is_finite()
        && settings.offset >= 0.0
        && samples.len() == expected;
    match (&samples.albedo, plain) {
        (Some(albedo), true) => Ok(gather_sparse(samples, reconstructor, albedo, params, settings)),
        _ => gather_with_spread(samples, reconstructor, None, settings),
    }
}

/// The sparse gather proper (module documentation).
fn gather_sparse(
    samples: &IndirectSamples,
    reconstructor: &Reconstructor,
    albedo: &[[f32; 3]],
    params: &SparseParams,
    settings: &GatherSettings,
) -> (Image, GatherStats, Vec<f32>) {
    let (width, height, spp) = (samples.width, samples.height, samples.spp.max(1));
    let stride = params.stride.max(1);
    let grid_per_hit = rays_per_hit(settings.rays_per_pixel.saturating_mul(params.grid_ray_factor.max(1)), spp);
    let side = tile_side(spp as u64 * grid_per_hit as u64).min(TILE);
    let (tiles_x, tiles_y) = (width.div_ceil(side), height.div_ceil(side));
    let tile_pixels = |t: u32| {
        let (x0, y0) = ((t % tiles_x) * side, (t / tiles_x) * side);
        (y0..(y0 + side).min(height)).flat_map(move |y| (x0..(x0 + side).min(width)).map(move |x| (x, y)))
    };
    let is_grid = |(x, y): (u32, u32)| on_grid(x, width, stride) && on_grid(y, height, stride);
    let pixel_count = width as usize * height as usize;
    crate::progress::begin("gather", 2 * (tiles_x * tiles_y) as u64, "tiles");

    // The grid, tile by tile (its pixels' rays reconstructed together in direction order).
    let gathered: Vec<(Vec<(u32, u32)>, _)> = (0..tiles_x * tiles_y)
        .into_par_iter()
        .with_max_len(1)
        .map(|t| {
            let pixels: Vec<(u32, u32)> = tile_pixels(t).filter(|&p| is_grid(p)).collect();
            let out = gather_indirect_pixels(samples, reconstructor, Some(albedo), &pixels, (grid_per_hit, settings));
            crate::progress::advance(1);
            (pixels, out)
        })
        .collect();
    let mut grid = Grid {
        hit_radiance: vec![None; samples.len()],
        value: vec![[0.0; 3]; pixel_count],
        variance: vec![f32::INFINITY; pixel_count],
    };
    let mut stats = GatherStats::default();
    let mut grid_pixels = 0u64;
    for (pixels, out) in &gathered {
        for (k, &(x, y)) in pixels.iter().enumerate() {
            let p = (y * width + x) as usize;
            grid.value[p] = out.values[k];
            grid.variance[p] = out.variance[k];
            let hits = p * spp as usize..(p + 1) * spp as usize;
            grid.hit_radiance[hits].copy_from_slice(&out.hit_radiance[k * spp as usize..(k + 1) * spp as usize]);
        }
        grid_pixels += pixels.len() as u64;
        stats.add(&out.stats);
    }
    drop(gathered);

    // Off the grid: interpolated, or refined with the grid's budget, tile by tile.
    let footprint = super::cache::pixel_footprints(samples);
    let decided: Vec<_> = (0..tiles_x * tiles_y)
        .into_par_iter()
        .with_max_len(1)
        .map(|t| {
            let pixels: Vec<(u32, u32)> = tile_pixels(t).filter(|&p| !is_grid(p)).collect();
            let decisions: Vec<Vec<Decision>> =
                pixels.iter().map(|&pixel| decide(samples, albedo, &grid, &footprint, params, pixel)).collect();
            let refine: Vec<usize> = (pixels.iter().zip(&decisions))
                .flat_map(|(&(x, y), hits)| {
                    let first = (y * width + x) as usize * spp as usize;
                    (hits.iter().enumerate())
                        .filter(|(_, d)| !matches!(d, Decision::Interpolated(_)))
                        .map(move |(k, _)| first + k)
                })
                .collect();
            let (refined, refined_stats) =
                gather_indirect_hits(samples, reconstructor, albedo, &refine, (grid_per_hit, settings));
            crate::progress::advance(1);
            (pixels, decisions, refined, refined_stats)
        })
        .collect();
    crate::progress::end();
    let mut pixels = grid.value;
    let mut variance = grid.variance;
    let (mut interpolated_count, mut refined_count, mut refined_hits, mut by_light) = (0u64, 0u64, 0u64, 0u64);
    for (tile_pixels, decisions, refined, refined_stats) in &decided {
        let mut gathered = refined.iter();
        for (&(x, y), hits) in tile_pixels.iter().zip(decisions) {
            // The hits in their order, summed as the full gather sums them.
            let mut sum = [0.0f64; 3];
            let mut any = false;
            for decision in hits {
                let value = match decision {
                    Decision::Interpolated(value) => *value,
                    refine => {
                        any = true;
                        refined_hits += 1;
                        by_light += matches!(refine, Decision::RefineForLight) as u64;
                        *gathered.next().expect("one gathered value per refined hit")
                    }
                };
                for c in 0..3 {
                    sum[c] += value[c] as f64;
                }
            }
            pixels[(y * width + x) as usize] = sum.map(|s| (s / spp as f64) as f32);
            variance[(y * width + x) as usize] = f32::INFINITY;
            if any {
                refined_count += 1;
            } else {
                interpolated_count += 1;
            }
        }
        stats.add(refined_stats);
    }
    stats.sparse = Some((grid_pixels, interpolated_count, refined_count, refined_hits, by_light));
    (Image::from_pixels(width, height, pixels), stats, variance)
}

/// The primary hits of pixel (x, y) off the grid: each one's value (albedo × L̄) interpolated
/// from its cell's corners, or refined where the error estimate says so (module documentation);
/// a camera miss is 0.
fn decide(
    samples: &IndirectSamples,
    albedo: &[[f32; 3]],
    grid: &Grid,
    footprint: &[f32],
    params: &SparseParams,
    (x, y): (u32, u32),
) -> Vec<Decision> {
    let (width, height, spp) = (samples.width, samples.height, samples.spp.max(1) as usize);
    let cos_max = params.max_normal_degrees.to_radians().cos();
    let (columns, rows) = (cell(x, width, params.stride), cell(y, height, params.stride));
    let mut corners: Vec<(usize, f32, f32)> = Vec::with_capacity(4);
    for &(cy, by) in &rows {
        for &(cx, bx) in &columns {
            let b = bx * by;
            if b > 0.0 {
                let pixels = x.abs_diff(cx).max(y.abs_diff(cy)) as f32;
                corners.push(((cy * width + cx) as usize, b, pixels));
            }
        }
    }
    let p = (y * width + x) as usize;
    let mut out = Vec::with_capacity(spp);
    for (i, own_albedo) in albedo.iter().enumerate().take((p + 1) * spp).skip(p * spp) {
        if samples.class[i] == SampleClass::CameraMiss {
            out.push(Decision::Interpolated([0.0; 3]));
            continue;
        }
        let here = (samples.primary_hit[i], samples.primary_normal[i]);
        let (mut covered, mut total) = (0.0f64, 0.0f64);
        let (mut sum, mut weight) = ([0.0f64; 3], 0.0f64);
        // The luminance and standard error of the brightest and the darkest similar hit.
        let (mut low, mut high) = ((f32::INFINITY, 0.0f32), (f32::NEG_INFINITY, 0.0f32));
        for &(q, b, pixels) in &corners {
            total += b as f64;
            let error = (grid.variance[q] * spp as f32).sqrt();
            for j in q * spp..(q + 1) * spp {
                if samples.class[j] == SampleClass::CameraMiss {
                    continue;
                }
                let there = (samples.primary_hit[j], samples.primary_normal[j]);
                let g = similarity(here, there, (footprint[p], pixels), (cos_max, params.plane_tolerance));
                covered += (b * g) as f64 / spp as f64;
                let (Some(l), true) = (grid.hit_radiance[j], g > 0.0) else { continue };
                let w = (b * g) as f64;
                for c in 0..3 {
                    sum[c] += w * l[c] as f64;
                }
                weight += w;
                let y = luminance(l);
                if y < low.0 {
                    low = (y, error);
                }
                if y > high.0 {
                    high = (y, error);
                }
            }
        }
        if !(weight > 0.0) || covered < params.min_coverage as f64 * total {
            out.push(Decision::RefineForGeometry);
            continue;
        }
        let mean = [0, 1, 2].map(|c| (sum[c] / weight) as f32);
        let noise = (high.1 * high.1 + low.1 * low.1).sqrt();
        if high.0 - low.0 > params.contrast * luminance(mean) + params.noise_sigmas * noise {
            out.push(Decision::RefineForLight);
            continue;
        }
        out.push(Decision::Interpolated([0, 1, 2].map(|c| own_albedo[c] * mean[c])));
    }
    out
}

#[cfg(test)]
mod tests;
