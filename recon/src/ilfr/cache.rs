//! Beyond the paper: the final gather (Eq. 3) at a subset of the Lambertian primary hits, the
//! others interpolated from them (irradiance caching: Ward, Rubinstein, Clear 1988, with the
//! weights of Tabellion and Lamorlette 2004), and a full gather wherever the interpolation's
//! error estimate leaves a hit uncovered. The indirect light a Lambertian hit reflects is its
//! albedo times the mean radiance of its cosine-distributed reconstruction rays, a smooth
//! function of position and normal on a surface; a *record* gathers that mean with many rays at
//! one hit and serves every hit near it.
//!
//! - A record at primary hit p with normal n: the mean radiance L̄ of `record_rays` cosine rays
//!   (the gather's directions, one scrambled Sobol' sequence per record; rays without support
//!   take a sky sample as the gather's do, or are left out), and its radius R, the harmonic mean
//!   of the distances at which the rays met a surface (Ward's split-sphere estimate of how fast
//!   the light changes), clamped to [`CacheParams::min_radius_pixels`] …
//!   [`CacheParams::max_radius_pixels`] times the image's pixel footprint there.
//! - The error estimate of record i at a hit x with normal m: ε_i = max(|x − p_i| / R_i,
//!   sqrt(1 − m·n_i) / sqrt(1 − cos θ_max)); its weight w_i = 1 − ε_i / a (a =
//!   [`CacheParams::accuracy`]), counted where positive and where p_i does not lie in front of x
//!   (Ward's test, (x − p_i)·(m + n_i)/2 ≥ −R_i / 20). L̄(x) = Σ w_i L̄_i / Σ w_i where
//!   Σ w_i ≥ [`CacheParams::min_weight`]; elsewhere x is *uncovered*.
//! - Records are placed coarse to fine: at pixel spacings [`CacheParams::coarsest_spacing`],
//!   its half, …, 1, a pixel of the grid whose first primary hit the records of the coarser
//!   levels leave uncovered becomes a record. Each level decides against the coarser levels
//!   only, so the records and the image are the same for any number of threads. A hit that all
//!   the records leave uncovered is gathered on its own, as the plain gather does.
//!
//! Ambient occlusion and glossy primary hits keep the per-hit gather.

use rayon::prelude::*;
use shading::sampling::hash_u32;

use super::bsdf_rays::WeightedRay;
use super::directions::cosine_rays;
use super::ray_order::trace_in_direction_order;
use super::reconstruct::{or_sky, ReconstructStats, Reconstructor, Scratch, SkyFallbacks, SkySample};
use super::samples::{IndirectSamples, SampleClass};
use crate::vector::{dot, length, sub};

/// How records are placed and interpolated (see the module documentation).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CacheParams {
    /// a: a record serves hits whose error estimate ε is below a.
    pub accuracy: f32,
    /// θ_max: normals this far apart give ε = 1.
    pub max_normal_degrees: f32,
    /// A record's radius R is at least this many pixel footprints …
    pub min_radius_pixels: f32,
    /// … and at most this many.
    pub max_radius_pixels: f32,
    /// The first level's pixel spacing (a power of two).
    pub coarsest_spacing: u32,
    /// Σ w below this leaves a hit uncovered.
    pub min_weight: f32,
    /// Reconstruction rays per record.
    pub record_rays: u32,
}

impl Default for CacheParams {
    fn default() -> Self {
        CacheParams {
            accuracy: 0.5,
            max_normal_degrees: 25.0,
            min_radius_pixels: 2.0,
            max_radius_pixels: 12.0,
            coarsest_spacing: 8,
            min_weight: 0.3,
            record_rays: 256,
        }
    }
}

/// One gather at a primary hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Record {
    pub position: [f32; 3],
    pub normal: [f32; 3],
    /// Its pixel.
    pub pixel: (u32, u32),
    /// Mean radiance of its supported rays; `None`: none had support.
    pub radiance: Option<[f32; 3]>,
    /// R, world units.
    pub radius: f32,
}

/// Counts of a cached gather.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct CacheStats {
    pub records: u64,
    /// Hits interpolated from records.
    pub interpolated: u64,
    /// Hits no record covered, gathered on their own.
    pub uncovered: u64,
    pub reconstruct: ReconstructStats,
    pub fallbacks: SkyFallbacks,
}

/// The records, bucketed by pixel for lookups.
struct Records {
    records: Vec<Record>,
    /// Records per bucket of `BUCKET` × `BUCKET` pixels, row by row.
    buckets: Vec<Vec<u32>>,
    buckets_x: u32,
    buckets_y: u32,
}

const BUCKET: u32 = 8;

impl Records {
    fn new(width: u32, height: u32) -> Records {
        let (buckets_x, buckets_y) = (width.div_ceil(BUCKET), height.div_ceil(BUCKET));
        Records {
            records: Vec::new(),
            buckets: vec![Vec::new(); (buckets_x * buckets_y) as usize],
            buckets_x,
            buckets_y,
        }
    }

    fn add(&mut self, record: Record) {
        let (x, y) = record.pixel;
        let bucket = (y / BUCKET) * self.buckets_x + x / BUCKET;
        self.buckets[bucket as usize].push(self.records.len() as u32);
        self.records.push(record);
    }

    /// Σ w_i L̄_i and Σ w_i at `position` with `normal` in pixel (x, y), over the records within
    /// `reach` pixels, in record order.
    fn interpolate(
        &self,
        (x, y): (u32, u32),
        position: [f32; 3],
        normal: [f32; 3],
        reach: u32,
        params: &CacheParams,
    ) -> ([f64; 3], f64) {
        let (mut sum, mut weight) = ([0.0f64; 3], 0.0f64);
        let normal_scale = 1.0 / (1.0 - params.max_normal_degrees.to_radians().cos()).sqrt();
        let (bx0, bx1) = (x.saturating_sub(reach) / BUCKET, ((x + reach) / BUCKET).min(self.buckets_x - 1));
        let (by0, by1) = (y.saturating_sub(reach) / BUCKET, ((y + reach) / BUCKET).min(self.buckets_y - 1));
        let mut found: Vec<u32> = Vec::new();
        for by in by0..=by1 {
            for bx in bx0..=bx1 {
                found.extend(&self.buckets[(by * self.buckets_x + bx) as usize]);
            }
        }
        found.sort_unstable();
        for &k in &found {
            let r = &self.records[k as usize];
            let Some(radiance) = r.radiance else { continue };
            let offset = sub(position, r.position);
            let spatial = length(offset) / r.radius;
            let angular = (1.0 - dot(normal, r.normal)).max(0.0).sqrt() * normal_scale;
            let w = 1.0 - spatial.max(angular) / params.accuracy;
            if w.is_nan() || w <= 0.0 {
                continue;
            }
            // Ward's test: the record lies in front of the hit (on an occluder above it).
            let mean_normal = [0, 1, 2].map(|a| 0.5 * (normal[a] + r.normal[a]));
            if dot(offset, mean_normal) < -0.05 * r.radius {
                continue;
            }
            for c in 0..3 {
                sum[c] += w as f64 * radiance[c] as f64;
            }
            weight += w as f64;
        }
        (sum, weight)
    }
}

/// Records per job: their rays are reconstructed together in direction order
/// ([`trace_in_direction_order`]), so that consecutive walks meet the same nodes.
const RECORDS_PER_JOB: usize = 16;

/// The records at `candidates` (pixel, primary hit): each the mean radiance of
/// `params.record_rays` cosine rays (one scrambled sequence per record; a ray without support
/// takes a sky sample or is left out) and the harmonic mean of its rays' distances to the
/// surfaces they met, clamped in pixel footprints.
fn make_records(
    samples: &IndirectSamples,
    reconstructor: &Reconstructor,
    candidates: &[(u32, u32, usize)],
    (params, seed, offset): (&CacheParams, u32, f32),
    (footprint, sky): (&[f32], &SkyOfPixel),
) -> Vec<(Record, CacheStats)> {
    let count = params.record_rays;
    candidates
        .par_chunks(RECORDS_PER_JOB)
        .flat_map_iter(|group| {
            let rays: Vec<WeightedRay> = group
                .iter()
                .flat_map(|&(_, _, i)| {
                    let scramble = hash_u32(seed ^ hash_u32(i as u32 ^ 0x5be0_cd19));
                    let (hit, normal) = (samples.primary_hit[i], samples.primary_normal[i]);
                    cosine_rays(hit, normal, offset, (0, count), scramble)
                        .map(|ray| WeightedRay { ray: Some(ray), weight: [1.0; 3] })
                })
                .collect();
            let (found, reconstruct) = trace_in_direction_order(&rays, |ray, scratch, stats| {
                reconstructor.radiance(ray, scratch, stats).map(|f| (f.radiance, f.distance))
            });
            let mut out = Vec::with_capacity(group.len());
            for (k, &(x, y, i)) in group.iter().enumerate() {
                let mut local = CacheStats::default();
                if k == 0 {
                    local.reconstruct = reconstruct.clone();
                }
                let (sky_samples, min_cosine) = sky(x, y);
                let (mut sum, mut supported) = ([0.0f64; 3], 0u32);
                let mut inverse_distances = 0.0f64;
                let range = k * count as usize..(k + 1) * count as usize;
                for (weighted, found) in rays[range.clone()].iter().zip(&found[range]) {
                    let direction = weighted.ray.map_or([0.0; 3], |r| r.direction);
                    if let Some((_, distance)) = found {
                        if *distance > 0.0 && distance.is_finite() {
                            inverse_distances += 1.0 / *distance as f64;
                        }
                    }
                    let sky = (&sky_samples[..], min_cosine);
                    if let Some(l) = or_sky(found.map(|f| f.0), direction, sky, &mut local.fallbacks) {
                        (0..3).for_each(|c| sum[c] += l[c] as f64);
                        supported += 1;
                    }
                }
                let radiance = (supported > 0).then(|| sum.map(|s| (s / supported as f64) as f32));
                let distance =
                    if inverse_distances > 0.0 { (count as f64 / inverse_distances) as f32 } else { f32::INFINITY };
                let pixel = footprint[(y * samples.width + x) as usize];
                let radius = distance.clamp(params.min_radius_pixels * pixel, params.max_radius_pixels * pixel);
                let (position, normal) = (samples.primary_hit[i], samples.primary_normal[i]);
                out.push((Record { position, normal, pixel: (x, y), radiance, radius }, local));
            }
            out
        })
        .collect()
}

/// Per pixel, the world-space distance between its primary hits' mean and its neighbours'
/// (the median over the four neighbours on the same surface, normals within 25°), or the
/// image's median where a pixel has none; for a record's radius in pixels.
pub(super) fn pixel_footprints(samples: &IndirectSamples) -> Vec<f32> {
    let (width, height, spp) = (samples.width as usize, samples.height as usize, samples.spp.max(1) as usize);
    let mean_hit: Vec<Option<([f32; 3], [f32; 3])>> = (0..width * height)
        .map(|p| {
            let hits: Vec<usize> =
                (p * spp..(p + 1) * spp).filter(|&i| samples.class[i] != SampleClass::CameraMiss).collect();
            if hits.is_empty() {
                return None;
            }
            let mean = |v: &[[f32; 3]]| {
                let mut m = [0.0f32; 3];
                for &i in &hits {
                    for a in 0..3 {
                        m[a] += v[i][a] / hits.len() as f32;
                    }
                }
                m
            };
            Some((mean(&samples.primary_hit), crate::vector::normalize(mean(&samples.primary_normal))))
        })
        .collect();
    let cos_limit = 25f32.to_radians().cos();
    let mut footprint: Vec<Option<f32>> = (0..width * height)
        .map(|p| {
            let (x, y) = (p % width, p / width);
            let (position, normal) = mean_hit[p]?;
            let mut d: Vec<f32> = [(x.wrapping_sub(1), y), (x + 1, y), (x, y.wrapping_sub(1)), (x, y + 1)]
                .into_iter()
                .filter(|&(qx, qy)| qx < width && qy < height)
                .filter_map(|(qx, qy)| mean_hit[qy * width + qx])
                .filter(|(_, n)| dot(*n, normal) >= cos_limit)
                .map(|(q, _)| length(sub(q, position)))
                .filter(|d| d.is_finite() && *d > 0.0)
                .collect();
            d.sort_by(f32::total_cmp);
            d.get(d.len().saturating_sub(1) / 2).copied()
        })
        .collect();
    let mut known: Vec<f32> = footprint.iter().flatten().copied().collect();
    known.sort_by(f32::total_cmp);
    let median = known.get(known.len().saturating_sub(1) / 2).copied().unwrap_or(1.0);
    footprint.iter_mut().map(|f| f.unwrap_or(median)).collect()
}

/// The sky samples of pixel (x, y) and the cosine within which one stands in for a ray
/// ([`super::gather::sky_samples`]).
pub type SkyOfPixel<'a> = dyn Fn(u32, u32) -> (Vec<SkySample>, Option<f32>) + Sync + 'a;

/// The mean radiance of primary hit i gathered on its own (`None`: no ray had support).
pub type HitGather<'a> = dyn Fn(usize, &mut Scratch, &mut CacheStats) -> Option<[f32; 3]> + Sync + 'a;

/// The indirect light of every Lambertian primary hit's mean radiance (`None`: a camera miss, or a
/// hit none of whose rays found support), from records and interpolation; `per_hit_gather(i)`
/// gathers an uncovered hit on its own. `sky(x, y)` gives the sky samples of pixel (x, y) for
/// rays without support.
pub fn cached_radiance(
    samples: &IndirectSamples,
    reconstructor: &Reconstructor,
    params: &CacheParams,
    (seed, offset): (u32, f32),
    sky: &SkyOfPixel,
    per_hit_gather: &HitGather,
) -> (Vec<Option<[f32; 3]>>, CacheStats) {
    let (width, height, spp) = (samples.width, samples.height, samples.spp.max(1) as usize);
    let footprint = pixel_footprints(samples);
    let first_hit = |x: u32, y: u32| {
        let p = (y * width + x) as usize;
        (p * spp..(p + 1) * spp).find(|&i| samples.class[i] != SampleClass::CameraMiss)
    };
    let reach = (params.accuracy * params.max_radius_pixels).ceil() as u32 + 1;
    let mut records = Records::new(width, height);
    let mut stats = CacheStats::default();
    let mut spacing = params.coarsest_spacing.max(1).next_power_of_two();
    loop {
        let coarser = spacing * 2;
        let candidates: Vec<(u32, u32, usize)> = (0..height)
            .step_by(spacing as usize)
            .flat_map(|y| (0..width).step_by(spacing as usize).map(move |x| (x, y)))
            .filter(|&(x, y)| {
                spacing == params.coarsest_spacing.max(1).next_power_of_two() || x % coarser != 0 || y % coarser != 0
            })
            .filter_map(|(x, y)| first_hit(x, y).map(|i| (x, y, i)))
            .filter(|&(x, y, i)| {
                let (_, weight) =
                    records.interpolate((x, y), samples.primary_hit[i], samples.primary_normal[i], reach, params);
                weight < params.min_weight as f64
            })
            .collect();
        let made = make_records(samples, reconstructor, &candidates, (params, seed, offset), (&footprint, sky));
        for (record, local) in made {
            stats.records += 1;
            stats.reconstruct.add(&local.reconstruct);
            stats.fallbacks.add(&local.fallbacks);
            records.add(record);
        }
        if spacing == 1 {
            break;
        }
        spacing /= 2;
    }
    // Every hit: interpolated, or gathered on its own.
    let rows: Vec<(Vec<Option<[f32; 3]>>, CacheStats)> = (0..height)
        .into_par_iter()
        .map_init(Scratch::default, |scratch, y| {
            let mut local = CacheStats::default();
            let mut out = Vec::with_capacity(width as usize * spp);
            for x in 0..width {
                let p = (y * width + x) as usize;
                for i in p * spp..(p + 1) * spp {
                    if samples.class[i] == SampleClass::CameraMiss {
                        out.push(None);
                        continue;
                    }
                    let (sum, weight) =
                        records.interpolate((x, y), samples.primary_hit[i], samples.primary_normal[i], reach, params);
                    if weight >= params.min_weight as f64 {
                        local.interpolated += 1;
                        out.push(Some(sum.map(|s| (s / weight) as f32)));
                    } else {
                        local.uncovered += 1;
                        out.push(per_hit_gather(i, scratch, &mut local));
                    }
                }
            }
            (out, local)
        })
        .collect();
    let mut radiance = Vec::with_capacity(samples.len());
    for (row, local) in rows {
        radiance.extend(row);
        stats.interpolated += local.interpolated;
        stats.uncovered += local.uncovered;
        stats.reconstruct.add(&local.reconstruct);
        stats.fallbacks.add(&local.fallbacks);
    }
    (radiance, stats)
}
