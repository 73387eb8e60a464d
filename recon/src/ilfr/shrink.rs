//! Consistent visibility, paper Section 2.3.1 (design: docs/ilfr-design.md §2 "Shrinking",
//! §3 #9–10).
//!
//! Paper → code:
//! - "we know, with certainty, that a ray from o_i terminated at h_i without being blocked in
//!   between": [`InputRay`] — every traced secondary ray, finite (o → h) or escaped (o + tω,
//!   t ∈ (0, ∞)), built from the samples by [`input_rays`].
//! - "we retrace all the input rays using the BVH and shrink splats that intersect rays they
//!   should not": [`shrink_splats`] — for every ray j and every splat i ≠ j's own that it hits
//!   with ε_j < t < |h_j − o_j| − ε_j, r_i ← min(r_i, s_i) (s_i: the ray's distance from h_i on
//!   i's tangent plane; a ray exactly at the rim misses, see [`super::disc::intersect`]). The
//!   window leaves alone the splats the ray meets within ε_j of its own hit (the surface around
//!   h_j itself) and of its origin; ε_j = max(1e-3·|h_j − o_j|, 1e-5 · scene diagonal), the scene
//!   being the box of the splat centres and ray origins ([`ShrinkParams`]).
//! - "Finally, the bounding boxes of the BVH nodes are recomputed": the refit
//!   ([`DiscBvh::set_radii`]) at the end of [`shrink_splats`].
//!
//! - Beyond the paper ([`Trim::Wedges`]): each of a splat's eight 45° wedges keeps its
//!   own radius, and a blocking ray bounds only the wedges towards it, by
//!   [`half_plane_wedge_radii`] (the crossing's own wedge to s_i exactly).
//!
//! The result is min(r_i, min of the s_i of the rays that block i), independent of the order in
//! which rays are processed, so the rays run in parallel with an atomic minimum on the radius's
//! bits (non-negative floats order like their bit patterns): exact and the same for any thread
//! count. One pass, as in the paper: a splat shrunk here cannot block a ray it did not block
//! before, so a second retrace finds nothing (tested).

use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};

use rayon::prelude::*;

use super::bvh::{DiscBvh, SplatHit};
use super::disc::{half_plane_wedge_radii, tangent_coordinates, Ray, WEDGES};
use super::samples::{IndirectSamples, SampleClass};
use crate::error::Error;
use crate::vector::{dot, length};

/// One traced secondary ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InputRay {
    /// o, the primary hit.
    pub origin: [f32; 3],
    /// ω, unit.
    pub direction: [f32; 3],
    /// |h − o|, or +inf when the ray escaped.
    pub length: f32,
    /// The splat of its own hit (an index into the discs of the hierarchy), never shrunk by it.
    pub own_splat: Option<u32>,
    /// Its time over the shutter (moving splats are tested where they were then; 0 when
    /// nothing moves).
    pub time: f32,
}

/// The ε of the window (design §3 #10).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShrinkParams {
    /// ε_j ≥ this × the ray's length …
    pub relative_epsilon: f32,
    /// … and ≥ this × the scene diagonal.
    pub scene_epsilon: f32,
    /// Whether input rays that escaped the scene shrink the splats they cross (the paper's
    /// "all the input rays", our default) or only rays that hit (the authors' code: +0.5 dB on
    /// the glossy monkeys, −0.2 dB on Cornell, ±0 on Sponza, and silhouettes that overhang the
    /// sky in the lens mode; docs/history/ilfr.md, "Shrinking with escaped rays").
    pub escaped_rays: bool,
    /// What a blocked ray trims: the whole disc (the paper) or the disc's wedges towards it.
    pub trim: Trim,
}

/// What a ray that crosses a splat it should not trims.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Trim {
    /// The paper: the disc's radius falls to the ray's distance from its centre, all round.
    Disc,
    /// Beyond the paper: the disc's eight 45° wedges ([`super::disc::wedge_at`]) are trimmed
    /// one by one, each only as far as a straight edge through the crossing, across its
    /// direction, needs ([`half_plane_wedge_radii`]): the crossing's wedge to the ray's
    /// distance, wedges facing away not at all. A rim splat trimmed on its outer side then
    /// leaves no hole on its inner side (docs/history/ilfr.md, "trimming wedges, not whole discs").
    Wedges,
}

impl Default for ShrinkParams {
    fn default() -> Self {
        ShrinkParams { relative_epsilon: 1e-3, scene_epsilon: 1e-5, escaped_rays: true, trim: Trim::Disc }
    }
}

/// What shrinking did, for reports.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ShrinkStats {
    /// Input rays retraced.
    pub rays: usize,
    /// Rays too short to have a window (|h − o| ≤ 2ε_j), skipped.
    pub short_rays: usize,
    /// Rays that crossed at least one splat.
    pub blocked_rays: usize,
    /// (ray, splat) crossings.
    pub crossings: u64,
    /// Splats whose radius went down.
    pub shrunk_splats: usize,
    /// Of those, splats shrunk to radius 0 (a ray through the centre): never hit again.
    pub dead_splats: usize,
    /// The absolute floor of ε_j (scene_epsilon × scene diagonal).
    pub epsilon_floor: f32,
}

/// The input rays of `samples` (classes `Hit` and `Escaped`), with `own_splat` the index of the
/// sample in `splat_sample_index` (the sample index of each splat, ascending, as
/// [`super::splats::GatheredPoints::sample_index`]).
pub fn input_rays(samples: &IndirectSamples, splat_sample_index: &[u32]) -> Vec<InputRay> {
    let mut rays = Vec::new();
    let mut next_splat = 0usize;
    for i in 0..samples.len() {
        let own_splat = if splat_sample_index.get(next_splat) == Some(&(i as u32)) {
            next_splat += 1;
            Some(next_splat as u32 - 1)
        } else {
            None
        };
        let length = match samples.class[i] {
            SampleClass::Hit => length(crate::vector::sub(samples.secondary_hit[i], samples.primary_hit[i])),
            SampleClass::Escaped => f32::INFINITY,
            SampleClass::CameraMiss | SampleClass::NoSecondaryRay => continue,
        };
        rays.push(InputRay {
            time: samples.time_of(i),
            origin: samples.primary_hit[i],
            direction: samples.direction[i],
            length,
            own_splat,
        });
    }
    rays
}

/// The open t interval in which `ray` must not meet any splat, or `None` when it is empty.
pub fn blocking_window(ray: &InputRay, epsilon_floor: f32, params: &ShrinkParams) -> Option<(f32, f32)> {
    let epsilon =
        if ray.length.is_finite() { (params.relative_epsilon * ray.length).max(epsilon_floor) } else { epsilon_floor };
    let end = ray.length - epsilon;
    (epsilon < end).then_some((epsilon, end))
}

/// Calls `visit` for every splat that blocks `ray` (not its own) within its window.
pub fn for_each_blocker(
    bvh: &DiscBvh,
    ray: &InputRay,
    window: (f32, f32),
    stack: &mut Vec<u32>,
    mut visit: impl FnMut(SplatHit),
) {
    let geometric = Ray { time: ray.time, origin: ray.origin, direction: ray.direction };
    bvh.for_each_hit(&geometric, window.0, window.1, stack, |hit| {
        if Some(hit.id) != ray.own_splat {
            visit(hit)
        }
    });
}

/// The diagonal of the box of the splat centres and the ray origins.
pub fn scene_diagonal(bvh: &DiscBvh, rays: &[InputRay]) -> f32 {
    let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for p in bvh.discs().map(|(_, d)| d.centre).chain(rays.iter().map(|r| r.origin)) {
        for axis in 0..3 {
            lo[axis] = lo[axis].min(p[axis]);
            hi[axis] = hi[axis].max(p[axis]);
        }
    }
    if lo[0] <= hi[0] {
        length(crate::vector::sub(hi, lo))
    } else {
        0.0
    }
}

/// Shrinks every splat that blocks an input ray (see the module documentation) and refits the
/// hierarchy. Rays must have finite origins, unit directions, lengths > 0 (or +inf) and own
/// splats within the hierarchy; otherwise an error names the ray.
pub fn shrink_splats(bvh: &mut DiscBvh, rays: &[InputRay], params: &ShrinkParams) -> Result<ShrinkStats, Error> {
    let bad = |message: String| Error::parameter("rays", message);
    for (j, ray) in rays.iter().enumerate() {
        if !ray.origin.iter().all(|c| c.is_finite()) {
            return Err(bad(format!("shrinking: the origin of input ray {j} is not finite: {:?}", ray.origin)));
        }
        let l = dot(ray.direction, ray.direction);
        if !(l.is_finite() && (l - 1.0).abs() <= 1e-3) {
            return Err(bad(format!(
                "shrinking: the direction of input ray {j} is not a unit vector: {:?}",
                ray.direction
            )));
        }
        let length_ok = ray.length >= 0.0; // false for NaN
        if !length_ok {
            return Err(bad(format!("shrinking: the length of input ray {j} is {}", ray.length)));
        }
        if ray.own_splat.is_some_and(|s| s as usize >= bvh.len()) {
            return Err(bad(format!("shrinking: input ray {j} names splat {:?} of {}", ray.own_splat, bvh.len())));
        }
    }
    let epsilon_floor = params.scene_epsilon * scene_diagonal(bvh, rays);
    // Radii by slot (leaf order) and wedge (one per disc when trimming whole discs), as bits:
    // fetch_min on non-negative f32 bits is the float minimum.
    let wedges = match params.trim {
        Trim::Disc => 1,
        Trim::Wedges => WEDGES,
    };
    // Each starts from what the disc has now (a disc trimmed by wedges before and shrunk whole
    // starts from its smallest wedge).
    let now = bvh.wedge_radii();
    let initial = |id: u32, wedge: usize| match params.trim {
        Trim::Disc => now[id as usize].iter().copied().fold(f32::INFINITY, f32::min),
        Trim::Wedges => now[id as usize][wedge],
    };
    let radius_bits: Vec<AtomicU32> =
        bvh.discs().flat_map(|(id, _)| (0..wedges).map(move |w| AtomicU32::new(initial(id, w).to_bits()))).collect();
    let crossings = AtomicU64::new(0);
    let (short_rays, blocked_rays) = rays
        .par_iter()
        .with_max_len(super::PARALLEL_ITEMS)
        .filter(|ray| params.escaped_rays || ray.length.is_finite())
        .map_init(Vec::new, |stack, ray| {
            let Some(window) = blocking_window(ray, epsilon_floor, params) else {
                return (1usize, 0usize);
            };
            let mut count = 0u64;
            let geometric = Ray { time: ray.time, origin: ray.origin, direction: ray.direction };
            for_each_blocker(bvh, ray, window, stack, |hit| {
                // s ≥ 0 (a square root of a sum of squares, never −0).
                let first = hit.slot as usize * wedges;
                match params.trim {
                    Trim::Disc => {
                        radius_bits[first].fetch_min(hit.hit.spatial.to_bits(), Ordering::Relaxed);
                    }
                    Trim::Wedges => {
                        let (centre, normal) = bvh.placed_at(hit.slot, ray.time);
                        let (x, y) = tangent_coordinates(centre, normal, &geometric, hit.hit.t);
                        for (w, r) in half_plane_wedge_radii(x, y, hit.hit.spatial).into_iter().enumerate() {
                            if r.is_finite() {
                                radius_bits[first + w].fetch_min(r.to_bits(), Ordering::Relaxed);
                            }
                        }
                    }
                }
                count += 1;
            });
            crossings.fetch_add(count, Ordering::Relaxed);
            (0, (count > 0) as usize)
        })
        .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    let mut stats = ShrinkStats {
        rays: rays.iter().filter(|ray| params.escaped_rays || ray.length.is_finite()).count(),
        short_rays,
        blocked_rays,
        crossings: crossings.into_inner(),
        epsilon_floor,
        ..ShrinkStats::default()
    };
    let mut radii_by_id = vec![[0.0f32; WEDGES]; bvh.len()];
    for ((id, _), bits) in bvh.discs().zip(radius_bits.chunks_exact(wedges)) {
        let radii = &mut radii_by_id[id as usize][..wedges];
        for (radius, bits) in radii.iter_mut().zip(bits) {
            *radius = f32::from_bits(bits.load(Ordering::Relaxed));
        }
        if radii.iter().enumerate().any(|(w, &r)| r < initial(id, w)) {
            stats.shrunk_splats += 1;
            stats.dead_splats += radii.iter().all(|&r| r == 0.0) as usize;
        }
    }
    match params.trim {
        Trim::Disc => bvh.set_radii(&radii_by_id.iter().map(|r| r[0]).collect::<Vec<_>>())?,
        Trim::Wedges => bvh.set_wedge_radii(&radii_by_id)?,
    }
    Ok(stats)
}

#[cfg(test)]
mod tests;
