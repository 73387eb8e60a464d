//! Integration (paper Eq. 1): each pixel's value is the mean of RECONSTRUCT over N locations
//! drawn from the pixel (box filter) × lens × time, "reconstruction and integration combined":
//! no upsampled light field is stored.
//!
//! Locations: the Halton sequence in bases 2, 3 (screen), 5, 7 (lens, mapped to the unit disk
//! by Shirley's concentric map) and 11 (time), each dimension shifted per pixel by a hash of
//! (seed, pixel) (Cranley–Patterson rotation), so neighbouring pixels do not share a pattern and
//! the image depends only on the seed. Lens and time dimensions the file lacks stay at 0 and
//! 0.5. A location with nothing within 16R is left out (`query::reconstruct` = `None`); a pixel
//! with no location left gets the mean of its own input samples, or 0 without any.
//!
//! Adaptive locations (not in the paper, which spends the same N everywhere;
//! `AdaptiveRule`): a pixel whose first few locations all saw one surface and agree stops
//! there.
//!
//! Rows run in parallel (rayon); every value depends only on its pixel, so the image is the
//! same for any thread count.

use glam::Vec2;
use rayon::prelude::*;
use shading::concentric_disk;
use shading::sampling::{hash_u32, radical_inverse, to_unit_float};

use super::coverage::Point;
use super::query::{reconstruct, reconstruct_clocked, QueryStats, Scene, Scratch, StageTimes};
use super::reprojection::LensTime;
use crate::image::Image;

/// The Halton dimensions of pixel (x, y)'s locations, each Cranley–Patterson rotated by a hash
/// of (seed, pixel, dimension): dimension `dimension` of location `j` is the radical inverse of
/// j in `base` plus the pixel's shift for that dimension, modulo 1.
pub(crate) struct RotatedHalton {
    /// The pixel's shift of each dimension (0-4: screen, lens, time; 5-6: the light's point).
    shifts: [f32; 7],
}

impl RotatedHalton {
    pub(crate) fn new(seed: u32, x: u32, y: u32) -> RotatedHalton {
        let pixel_hash = hash_u32(seed ^ hash_u32(x.wrapping_mul(0x9e37_79b9) ^ hash_u32(y)));
        let shifts =
            std::array::from_fn(|d| to_unit_float(hash_u32(pixel_hash ^ (d as u32).wrapping_mul(0x85eb_ca6b))));
        RotatedHalton { shifts }
    }

    pub(crate) fn dimension(&self, j: u32, base: u32, dimension: u32) -> f32 {
        let v = radical_inverse(j, base) + self.shifts[dimension as usize];
        v - v.floor()
    }

    /// Location `j` of pixel (x, y) (`location`).
    pub(crate) fn location(&self, x: u32, y: u32, j: u32, has_lens: bool, has_time: bool) -> ([f32; 2], LensTime) {
        let dim = |base: u32, dimension: u32| self.dimension(j, base, dimension);
        let screen = [x as f32 + dim(2, 0), y as f32 + dim(3, 1)];
        let (u, v) = if has_lens { concentric_disk(Vec2::new(dim(5, 2), dim(7, 3))).into() } else { (0.0, 0.0) };
        let t = if has_time { dim(11, 4) } else { 0.5 };
        (screen, LensTime { u, v, t })
    }
}

/// Location `j` of pixel (x, y): screen position and lens-time coordinates.
pub fn location(seed: u32, x: u32, y: u32, j: u32, has_lens: bool, has_time: bool) -> ([f32; 2], LensTime) {
    RotatedHalton::new(seed, x, y).location(x, y, j, has_lens, has_time)
}

/// The value of one location (`query::reconstruct`, `nearest::reconstruct_nearest`).
pub type Reconstruct = fn(&Scene, Point, LensTime, &mut Scratch, &mut QueryStats) -> Option<[f32; 3]>;

/// The adaptive number of locations per pixel: a pixel first evaluates `first` locations (the
/// start of its Halton sequence, stratified over pixel × lens × time). When every one of them
/// found exactly one surface within 2R without widening (so no occlusion boundary came near any
/// of them) and their values agree (each channel's range at most `spread` times the mean of
/// the three channels' means, or below 1e-4), the pixel is their mean; otherwise it evaluates
/// all N. The values of the first locations are those of the full run, so a pixel that goes on
/// is the same as without the rule.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdaptiveRule {
    pub first: u32,
    pub spread: f32,
}

/// Per-pixel bookkeeping of `AdaptiveRule`.
struct Agreement {
    simple: bool,
    low: [f32; 3],
    high: [f32; 3],
}

impl AdaptiveRule {
    /// Whether a pixel may stop after its first locations: `simple` when all of them were
    /// single-surface, `low`/`high` their values' extremes per channel, `mean` their mean.
    pub fn stops(&self, simple: bool, low: [f32; 3], high: [f32; 3], mean: [f64; 3]) -> bool {
        let level = (mean[0] + mean[1] + mean[2]) / 3.0;
        simple && (0..3).all(|c| ((high[c] - low[c]) as f64) <= (self.spread as f64 * level).max(1e-4))
    }
}

/// The image of `scene` at `width` × `height` with `locations` per pixel; `fallback(x, y)` is a
/// pixel's value when none of its locations found a sample.
pub fn integrate(
    scene: &Scene,
    size: (u32, u32),
    locations: u32,
    has: (bool, bool),
    seed: u32,
    fallback: impl Fn(u32, u32) -> [f32; 3] + Sync,
) -> (Image, QueryStats) {
    integrate_with(reconstruct, scene, size, locations, has, seed, fallback)
}

/// `integrate` with another value per location, `value`.
pub fn integrate_with(
    value: Reconstruct,
    scene: &Scene,
    size: (u32, u32),
    locations: u32,
    has: (bool, bool),
    seed: u32,
    fallback: impl Fn(u32, u32) -> [f32; 3] + Sync,
) -> (Image, QueryStats) {
    integrate_adaptive(value, scene, size, (locations, None), has, seed, fallback)
}

/// `integrate_with` with an optional `AdaptiveRule`: `(N, rule)` locations per pixel.
pub fn integrate_adaptive(
    value: Reconstruct,
    scene: &Scene,
    size: (u32, u32),
    (locations, rule): (u32, Option<AdaptiveRule>),
    has: (bool, bool),
    seed: u32,
    fallback: impl Fn(u32, u32) -> [f32; 3] + Sync,
) -> (Image, QueryStats) {
    integrate_locations(
        size,
        (locations, rule),
        has,
        seed,
        |_, screen, at, scratch: &mut Scratch, stats: &mut QueryStats| value(scene, screen, at, scratch, stats),
        fallback,
    )
}

/// Counters and stage times of `integrate_clocked`.
#[derive(Default)]
pub struct Clocked {
    pub stats: QueryStats,
    pub times: StageTimes,
}

impl Counters for Clocked {
    fn add(&mut self, other: &Self) {
        self.stats.add(&other.stats);
        self.times.add(&other.times);
    }

    fn surface_counts(&self) -> (u64, u64) {
        self.stats.surface_counts()
    }
}

/// `integrate_adaptive` of `reconstruct` with every location's stages timed
/// (`query::StageTimes`; `lfr-bench tlfr`): the same image, bit for bit, at the cost of a few
/// clock reads per location.
pub fn integrate_clocked(
    scene: &Scene,
    size: (u32, u32),
    locations: (u32, Option<AdaptiveRule>),
    has: (bool, bool),
    seed: u32,
    fallback: impl Fn(u32, u32) -> [f32; 3] + Sync,
) -> (Image, Clocked) {
    integrate_locations(
        size,
        locations,
        has,
        seed,
        |_, screen, at, scratch: &mut Scratch, clocked: &mut Clocked| {
            reconstruct_clocked(scene, screen, at, scratch, &mut clocked.stats, &mut clocked.times)
        },
        fallback,
    )
}

/// Counters summed over the rows of `integrate_locations`.
pub trait Counters: Default + Send {
    fn add(&mut self, other: &Self);

    /// (locations that saw one surface, locations widened) so far, for `AdaptiveRule`; counters
    /// without them never let a pixel stop early.
    fn surface_counts(&self) -> (u64, u64) {
        (0, 0)
    }
}

impl Counters for QueryStats {
    fn add(&mut self, other: &Self) {
        QueryStats::add(self, other)
    }

    fn surface_counts(&self) -> (u64, u64) {
        (self.one_surface, self.widened)
    }
}

/// Eq. 1 for any value per location: pixel (x, y) is the mean of `value((x, y, j), screen, at,
/// scratch, counters)` over its locations j (`location`), or `fallback(x, y)` when every one
/// returned `None`; with `AdaptiveRule` `rule`, over fewer where the rule says so. Rows run in
/// parallel with a scratch `Sc` per worker and counters per row, summed in row order.
pub fn integrate_locations<Sc: Default + Send, St: Counters>(
    (width, height): (u32, u32),
    (locations, rule): (u32, Option<AdaptiveRule>),
    (has_lens, has_time): (bool, bool),
    seed: u32,
    value: impl Fn((u32, u32, u32), Point, LensTime, &mut Sc, &mut St) -> Option<[f32; 3]> + Sync,
    fallback: impl Fn(u32, u32) -> [f32; 3] + Sync,
) -> (Image, St) {
    let locations = locations.max(1);
    let rule = rule.filter(|r| r.first >= 1 && r.first < locations);
    crate::progress::begin("locations", height as u64, "rows");
    let rows: Vec<(Vec<[f32; 3]>, St)> = (0..height)
        .into_par_iter()
        .map_init(Sc::default, |scratch, y| {
            let mut stats = St::default();
            let row = (0..width)
                .map(|x| {
                    let (mut sum, mut count) = ([0.0f64; 3], 0u32);
                    let mut agreement =
                        Agreement { simple: true, low: [f32::INFINITY; 3], high: [f32::NEG_INFINITY; 3] };
                    let halton = RotatedHalton::new(seed, x, y);
                    for j in 0..locations {
                        let (screen, at) = halton.location(x, y, j, has_lens, has_time);
                        let before = stats.surface_counts();
                        let found = value((x, y, j), screen, at, scratch, &mut stats);
                        if let Some(found) = found {
                            for c in 0..3 {
                                sum[c] += found[c] as f64;
                            }
                            count += 1;
                        }
                        let Some(rule) = rule else { continue };
                        if j >= rule.first {
                            continue;
                        }
                        let after = stats.surface_counts();
                        match found {
                            Some(found) if after.0 == before.0 + 1 && after.1 == before.1 => {
                                for (c, &v) in found.iter().enumerate() {
                                    agreement.low[c] = agreement.low[c].min(v);
                                    agreement.high[c] = agreement.high[c].max(v);
                                }
                            }
                            _ => agreement.simple = false,
                        }
                        if j + 1 == rule.first {
                            let mean = sum.map(|s| s / count.max(1) as f64);
                            if rule.stops(agreement.simple, agreement.low, agreement.high, mean) {
                                break;
                            }
                        }
                    }
                    if count == 0 {
                        fallback(x, y)
                    } else {
                        sum.map(|s| (s / count as f64) as f32)
                    }
                })
                .collect();
            crate::progress::advance(1);
            (row, stats)
        })
        .collect();
    crate::progress::end();
    let mut stats = St::default();
    let mut pixels = Vec::with_capacity((width * height) as usize);
    for (row, row_stats) in rows {
        pixels.extend(row);
        stats.add(&row_stats);
    }
    (Image::from_pixels(width, height, pixels), stats)
}

#[cfg(test)]
mod tests;
