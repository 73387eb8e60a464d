//! RECONSTRUCT for one location (x̂, ŷ, û, v̂, t̂) (paper Section 3, steps 1–4):
//!
//! 1. reproject the candidate samples (`index::SampleGrid`) to (û, v̂, t̂) and keep those
//!    within 2R of (x̂, ŷ);
//! 2. group them into apparent surfaces front to back (Section 3.2, Figure 7);
//! 3. find the nearest surface that covers the location (Section 3.3: one surface is trivially
//!    covered; surfaces with fewer than `MIN_SURFACE_SAMPLES` samples are merged into the next;
//!    the last surface is taken without a test);
//! 4. filter its samples with the circular tent of radius R (`coverage::tent_filter`).
//!
//! Where nothing lies within 2R the radius doubles, up to 16R (the authors' code does the same),
//! then the location returns `None` (the caller leaves it out of the pixel's average).
//!
//! Grouping (interim, until the hierarchy's leaves carry the one-surface guarantee of Section 4):
//! the samples sorted by z' join the current surface while SAMESURFACE holds against the
//! surface's first (front-most) sample and its most recently added one, an O(n) stand-in for
//! Figure 7's test against every node of the surface.

use super::coverage::{is_covered, tent_filter, CoverageStats, Point};
use super::index::SampleGrid;
use super::lens::LensModel;
use super::reprojection::{reproject, LensTime, LensTimeSample};
use super::same_surface::{same_surface, CROSSING_TOLERANCE_PX};

/// Surfaces with fewer samples are merged into the next (paper: "surfaces with only one or two
/// samples").
pub const MIN_SURFACE_SAMPLES: usize = 3;
/// Samples entering the cubic triangle search at most.
pub const MAX_TRIANGLE_CANDIDATES: usize = 24;
/// Radius doublings before giving up on a location.
pub const MAX_WIDENINGS: u32 = 3;

/// Everything a query reads.
pub struct Scene<'a> {
    pub samples: &'a [LensTimeSample],
    pub radiance: &'a [[f32; 3]],
    pub lens: &'a LensModel,
    pub grid: &'a SampleGrid,
    pub radius: f32,
    pub z_near: f32,
    /// SAMESURFACE's δ.
    pub delta: f32,
}

/// Counters over many queries.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct QueryStats {
    pub locations: u64,
    pub one_surface: u64,
    pub widened: u64,
    pub dropped: u64,
    pub coverage: CoverageStats,
}

impl QueryStats {
    pub fn add(&mut self, other: &QueryStats) {
        self.locations += other.locations;
        self.one_surface += other.one_surface;
        self.widened += other.widened;
        self.dropped += other.dropped;
        self.coverage.quadrant_accepts += other.coverage.quadrant_accepts;
        self.coverage.triangle_searches += other.coverage.triangle_searches;
        self.coverage.triangles_tested += other.coverage.triangles_tested;
    }
}

/// Per-thread scratch space.
#[derive(Default)]
pub struct Scratch {
    candidates: Vec<u32>,
    near: Vec<(f32, u32, Point)>,
    /// The covering surface's samples and their reprojected positions (`covering_surface`).
    pub covering: Vec<u32>,
    pub points: Vec<Point>,
    values: Vec<[f32; 3]>,
}

/// The reconstructed radiance at `location` = (x̂, ŷ) and `at` = (û, v̂, t̂), or `None` when no
/// sample reprojects within 16R.
pub fn reconstruct(
    scene: &Scene,
    location: Point,
    at: LensTime,
    scratch: &mut Scratch,
    stats: &mut QueryStats,
) -> Option<[f32; 3]> {
    let radius = covering_surface(scene, location, at, scratch, stats)?;
    scratch.values.clear();
    scratch.values.extend(scratch.covering.iter().map(|&i| scene.radiance[i as usize]));
    tent_filter(&scratch.points, &scratch.values, location, radius)
}

/// Steps 1–3 of RECONSTRUCT: the samples of the surface that covers the location, left in
/// `scratch.covering` (indices into `scene.samples`, front to back) with their reprojected
/// positions in `scratch.points`; returns the filter radius (R, or R widened), or `None` when
/// no sample reprojects within 16R. Soft shadows filter other values over the same samples.
pub fn covering_surface(
    scene: &Scene,
    location: Point,
    at: LensTime,
    scratch: &mut Scratch,
    stats: &mut QueryStats,
) -> Option<f32> {
    stats.locations += 1;
    let mut radius = scene.radius;
    for widening in 0..=MAX_WIDENINGS {
        let reach = 2.0 * radius;
        scene.grid.candidates(location, reach, &mut scratch.candidates);
        scratch.near.clear();
        for &i in &scratch.candidates {
            let Some(p) = reproject(&scene.samples[i as usize], scene.lens, at, scene.z_near) else {
                continue;
            };
            let (dx, dy) = (p.x - location[0], p.y - location[1]);
            if dx * dx + dy * dy <= reach * reach {
                scratch.near.push((p.z, i, [p.x, p.y]));
            }
        }
        if scratch.near.is_empty() {
            radius *= 2.0;
            continue;
        }
        if widening > 0 {
            stats.widened += 1;
        }
        // Front to back; ties by index keep the order deterministic.
        scratch.near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let surfaces = group(scene, at, &scratch.near);
        if surfaces.len() == 1 {
            stats.one_surface += 1;
        }
        let chosen = choose_surface(&surfaces, &scratch.near, location, radius, &mut scratch.points, stats);
        scratch.points.clear();
        scratch.covering.clear();
        for &(_, i, p) in &scratch.near[chosen.0..chosen.1] {
            scratch.points.push(p);
            scratch.covering.push(i);
        }
        return Some(radius);
    }
    stats.dropped += 1;
    None
}

/// Consecutive ranges of `near` (sorted front to back) that form apparent surfaces.
fn group(scene: &Scene, at: LensTime, near: &[(f32, u32, Point)]) -> Vec<(usize, usize)> {
    let mut surfaces = Vec::new();
    let mut start = 0;
    for k in 1..near.len() {
        let sample = &scene.samples[near[k].1 as usize];
        let first = &scene.samples[near[start].1 as usize];
        let last = &scene.samples[near[k - 1].1 as usize];
        let test = |other: &LensTimeSample| {
            same_surface(sample, other, scene.lens, at, scene.delta, CROSSING_TOLERANCE_PX, scene.z_near)
        };
        if !(test(first) && (k - 1 == start || test(last))) {
            surfaces.push((start, k));
            start = k;
        }
    }
    surfaces.push((start, near.len()));
    surfaces
}

/// The range of the covering surface: the first (front-most) that covers the location; small
/// surfaces merge into the next; the last is taken as it is.
fn choose_surface(
    surfaces: &[(usize, usize)],
    near: &[(f32, u32, Point)],
    location: Point,
    radius: f32,
    points: &mut Vec<Point>,
    stats: &mut QueryStats,
) -> (usize, usize) {
    let mut start = surfaces[0].0;
    for (k, &(_, end)) in surfaces.iter().enumerate() {
        if k + 1 == surfaces.len() {
            return (start, end);
        }
        if end - start < MIN_SURFACE_SAMPLES {
            continue; // merged into the next surface
        }
        points.clear();
        points.extend(near[start..end].iter().map(|n| n.2));
        if is_covered(points, location, radius, MAX_TRIANGLE_CANDIDATES, &mut stats.coverage) {
            return (start, end);
        }
        start = end;
    }
    unreachable!("the last surface is always returned")
}
