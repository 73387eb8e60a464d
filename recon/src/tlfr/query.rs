//! RECONSTRUCT for one location (x̂, ŷ, û, v̂, t̂) (paper Section 3, steps 1–4):
//!
//! 1. the hierarchy's leaves near (x̂, ŷ) at (û, v̂, t̂) (`hierarchy::Hierarchy::leaves_near`);
//!    their samples reprojected to (û, v̂, t̂), those within 2R of (x̂, ŷ) kept;
//! 2. grouped into apparent surfaces front to back leaf by leaf (Section 4 "Query", Figure 7):
//!    the leaves sorted by the depth z' at t̂ of their first sample (at least the near limit;
//!    ties by node index), walked in that order; a leaf that contributed samples opens a new
//!    surface when SAMESURFACE (Eq. 5, δ window, 0.1-pixel tolerance) fails between its
//!    representative (its first sample within reach) and the representative of any leaf of the
//!    current surface; a leaf whose representative leaves the window through the camera plane is
//!    a surface of its own. Each leaf holds samples of one surface (the hierarchy guarantees it),
//!    so one sample speaks for it. (The paper compares the leaves' bounding planes; planes of
//!    leaves whose samples move in depth are thick and sloped in t, and comparing them split one
//!    surface into many that each failed the coverage test: a card flying at the camera lost a
//!    third of its locations that way, mean 1.51 against 1.57 with the representatives, truth
//!    1.81. The samples' positions at the four corners are exact and cost four reprojections
//!    per contributing leaf.)
//! 3. the nearest surface that covers the location (Section 3.3: one surface is trivially
//!    covered; surfaces with fewer than `MIN_SURFACE_SAMPLES` samples are merged into the next;
//!    the last surface is taken without a test);
//! 4. its samples filtered with the circular tent of radius R (`coverage::tent_filter`), each
//!    weighted also by its BRDF bandwidth when the extension of Figure 14 is on
//!    (`bandwidth::weighted_tent_filter`).
//!
//! Where nothing lies within 2R the radius doubles, up to 16R (the authors' code does the same),
//! then the location returns `None` (the caller leaves it out of the pixel's average). The
//! hierarchy must have been built with a reach of at least 16R (`max_reach`).

use super::bandwidth::{weighted_tent_filter, ViewBandwidth};
use super::coverage::{is_covered, tent_filter, CoverageStats, Point};
use super::hierarchy::Hierarchy;
use super::lens::LensModel;
use super::reprojection::{depth_at, reproject, LensTime, LensTimeSample};
use super::same_surface::{consistent, corners, CROSSING_TOLERANCE_PX};

/// Surfaces with fewer samples are merged into the next (paper: "surfaces with only one or two
/// samples").
pub const MIN_SURFACE_SAMPLES: usize = 3;
/// Samples entering the cubic triangle search at most.
pub const MAX_TRIANGLE_CANDIDATES: usize = 24;
/// Radius doublings before giving up on a location.
pub const MAX_WIDENINGS: u32 = 3;

/// The largest distance from a location at which a query with radius `radius` looks for
/// samples: 2R, doubled `MAX_WIDENINGS` times (16R). Hierarchies must be built for it.
pub fn max_reach(radius: f32) -> f32 {
    2.0 * radius * (1u32 << MAX_WIDENINGS) as f32
}

/// Everything a query reads.
pub struct Scene<'a> {
    pub samples: &'a [LensTimeSample],
    pub radiance: &'a [[f32; 3]],
    pub lens: &'a LensModel,
    /// The hierarchy over `samples`, which are in its order (`hierarchy::reorder`).
    pub hierarchy: &'a Hierarchy,
    pub radius: f32,
    pub z_near: f32,
    /// SAMESURFACE's δ.
    pub delta: f32,
    /// The bandwidth extension (Figure 14), when on: step 4 weights each sample by how far its
    /// lens position is from the location's, for its BRDF's bandwidth (`bandwidth`).
    pub view_bandwidth: Option<&'a ViewBandwidth>,
}

/// Counters over many queries.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct QueryStats {
    pub locations: u64,
    pub one_surface: u64,
    pub widened: u64,
    pub dropped: u64,
    /// Leaves the hierarchy returned, over all passes.
    pub leaves: u64,
    pub coverage: CoverageStats,
}

impl QueryStats {
    pub fn add(&mut self, other: &QueryStats) {
        self.locations += other.locations;
        self.one_surface += other.one_surface;
        self.widened += other.widened;
        self.dropped += other.dropped;
        self.leaves += other.leaves;
        self.coverage.quadrant_accepts += other.coverage.quadrant_accepts;
        self.coverage.triangle_searches += other.coverage.triangle_searches;
        self.coverage.triangles_tested += other.coverage.triangles_tested;
    }
}

/// Per-thread scratch space.
#[derive(Default)]
pub struct Scratch {
    leaves: Vec<u32>,
    /// (depth key, leaf) of the leaves near the location.
    sorted_leaves: Vec<(f32, u32)>,
    /// The representatives of the current surface's leaves at the window's corners.
    surface_traces: Vec<[[f32; 2]; 4]>,
    /// The samples within reach, surface by surface, and the surfaces' ranges of it.
    near: Vec<(u32, Point)>,
    surfaces: Vec<(usize, usize)>,
    /// The covering surface's samples and their reprojected positions (`covering_surface`).
    pub covering: Vec<u32>,
    pub points: Vec<Point>,
    values: Vec<[f32; 3]>,
    log_weights: Vec<f64>,
}

/// The stages of one location that `lfr bench-tlfr` times: the hierarchy walk with the
/// reprojection and grouping of steps 1–2 (`Query`), the surface choice of step 3 (`Coverage`)
/// and the filter of step 4 (`Filter`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    Query,
    Coverage,
    Filter,
}

/// Where a location's time goes: `start` at its beginning, `lap(stage)` charges the time since
/// the last call to `stage`. `NoClock` (every plain reconstruction) compiles to nothing.
pub trait StageClock {
    fn start(&mut self);
    fn lap(&mut self, stage: Stage);
}

/// The clock of every plain reconstruction: no timing.
pub struct NoClock;

impl StageClock for NoClock {
    #[inline(always)]
    fn start(&mut self) {}
    #[inline(always)]
    fn lap(&mut self, _: Stage) {}
}

/// Seconds spent per stage (`lfr bench-tlfr`), summed over locations.
#[derive(Clone, Debug, Default)]
pub struct StageTimes {
    pub query_s: f64,
    pub coverage_s: f64,
    pub filter_s: f64,
    last: Option<std::time::Instant>,
}

impl StageTimes {
    pub fn add(&mut self, other: &StageTimes) {
        self.query_s += other.query_s;
        self.coverage_s += other.coverage_s;
        self.filter_s += other.filter_s;
    }
}

impl StageClock for StageTimes {
    fn start(&mut self) {
        self.last = Some(std::time::Instant::now());
    }

    fn lap(&mut self, stage: Stage) {
        let now = std::time::Instant::now();
        let seconds = self.last.map_or(0.0, |last| (now - last).as_secs_f64());
        self.last = Some(now);
        match stage {
            Stage::Query => self.query_s += seconds,
            Stage::Coverage => self.coverage_s += seconds,
            Stage::Filter => self.filter_s += seconds,
        }
    }
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
    reconstruct_clocked(scene, location, at, scratch, stats, &mut NoClock)
}

/// `reconstruct` with its stages timed by `clock`.
pub fn reconstruct_clocked(
    scene: &Scene,
    location: Point,
    at: LensTime,
    scratch: &mut Scratch,
    stats: &mut QueryStats,
    clock: &mut impl StageClock,
) -> Option<[f32; 3]> {
    clock.start();
    let radius = covering_surface_clocked(scene, location, at, scratch, stats, clock)?;
    let value = filter(scene, location, at, radius, scratch);
    clock.lap(Stage::Filter);
    value
}

/// Step 4 over the covering surface left in `scratch` by `covering_surface`.
fn filter(scene: &Scene, location: Point, at: LensTime, radius: f32, scratch: &mut Scratch) -> Option<[f32; 3]> {
    scratch.values.clear();
    scratch.values.extend(scratch.covering.iter().map(|&i| scene.radiance[i as usize]));
    let Some(view) = scene.view_bandwidth else {
        return tent_filter(&scratch.points, &scratch.values, location, radius);
    };
    scratch.log_weights.clear();
    scratch.log_weights.extend(scratch.covering.iter().map(|&i| {
        let sample = &scene.samples[i as usize];
        view.log_weight(i as usize, [sample.u, sample.v], sample.z, [at.u, at.v])
    }));
    if scratch.log_weights.iter().all(|&l| l == 0.0) {
        // No glossy sample here (or all on the location's lens point): the plain filter, the
        // same value, without an exponential per sample.
        return tent_filter(&scratch.points, &scratch.values, location, radius);
    }
    weighted_tent_filter(&scratch.points, &scratch.values, &scratch.log_weights, location, radius)
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
    covering_surface_clocked(scene, location, at, scratch, stats, &mut NoClock)
}

fn covering_surface_clocked(
    scene: &Scene,
    location: Point,
    at: LensTime,
    scratch: &mut Scratch,
    stats: &mut QueryStats,
    clock: &mut impl StageClock,
) -> Option<f32> {
    stats.locations += 1;
    let mut radius = scene.radius;
    for widening in 0..=MAX_WIDENINGS {
        let reach = 2.0 * radius;
        gather(scene, location, at, reach, scratch, stats);
        clock.lap(Stage::Query);
        if scratch.near.is_empty() {
            radius *= 2.0;
            continue;
        }
        if widening > 0 {
            stats.widened += 1;
        }
        if scratch.surfaces.len() == 1 {
            stats.one_surface += 1;
        }
        let chosen = choose_surface(&scratch.surfaces, &scratch.near, location, radius, &mut scratch.points, stats);
        scratch.points.clear();
        scratch.covering.clear();
        for &(i, p) in &scratch.near[chosen.0..chosen.1] {
            scratch.points.push(p);
            scratch.covering.push(i);
        }
        clock.lap(Stage::Coverage);
        return Some(radius);
    }
    stats.dropped += 1;
    None
}

/// Steps 1–2: the samples within `reach` into `scratch.near`, grouped into surfaces
/// (`scratch.surfaces`, front to back) leaf by leaf.
fn gather(scene: &Scene, location: Point, at: LensTime, reach: f32, scratch: &mut Scratch, stats: &mut QueryStats) {
    let tree = scene.hierarchy;
    tree.leaves_near(location, at, reach, &mut scratch.leaves);
    stats.leaves += scratch.leaves.len() as u64;
    scratch.sorted_leaves.clear();
    scratch.sorted_leaves.extend(scratch.leaves.iter().map(|&leaf| {
        let first = &scene.samples[tree.node(leaf).samples().start];
        (depth_at(first, at.t).max(scene.z_near), leaf)
    }));
    scratch.sorted_leaves.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    scratch.near.clear();
    scratch.surfaces.clear();
    scratch.surface_traces.clear();
    let window = corners(at, scene.delta);
    let mut surface_start = 0;
    for &(_, leaf) in &scratch.sorted_leaves {
        let node = tree.node(leaf);
        let before = scratch.near.len();
        for i in node.samples() {
            if !tree.entry_takes(i, at.t) {
                continue; // another time segment of the sample takes t̂
            }
            let Some(p) = reproject(&scene.samples[i], scene.lens, at, scene.z_near) else {
                continue;
            };
            let (dx, dy) = (p.x - location[0], p.y - location[1]);
            if dx * dx + dy * dy <= reach * reach {
                scratch.near.push((i as u32, [p.x, p.y]));
            }
        }
        if scratch.near.len() == before {
            continue; // no samples within reach: the leaf plays no part in the grouping
        }
        // The leaf's representative: its first sample within reach, at the window's corners.
        let representative = &scene.samples[scratch.near[before].0 as usize];
        let mut trace = [[0.0f32; 2]; 4];
        let mut seen_throughout = true;
        for (slot, corner) in trace.iter_mut().zip(window) {
            match reproject(representative, scene.lens, corner, scene.z_near) {
                Some(p) => *slot = [p.x, p.y],
                None => seen_throughout = false,
            }
        }
        // Eq. 5 against every representative of the current surface.
        let same = seen_throughout
            && scratch.surface_traces.iter().all(|other| {
                (0..2).all(|axis| consistent((0..4).map(|k| trace[k][axis] - other[k][axis]), CROSSING_TOLERANCE_PX))
            });
        if !same && before > surface_start {
            scratch.surfaces.push((surface_start, before));
            surface_start = before;
            scratch.surface_traces.clear();
        }
        if seen_throughout {
            scratch.surface_traces.push(trace);
        } else {
            // Leaving the window (through the camera plane): a surface of its own.
            scratch.surfaces.push((surface_start, scratch.near.len()));
            surface_start = scratch.near.len();
            scratch.surface_traces.clear();
        }
    }
    if scratch.near.len() > surface_start {
        scratch.surfaces.push((surface_start, scratch.near.len()));
    }
}

/// The range of the covering surface: the first (front-most) that covers the location; small
/// surfaces merge into the next; the last is taken as it is.
fn choose_surface(
    surfaces: &[(usize, usize)],
    near: &[(u32, Point)],
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
        points.extend(near[start..end].iter().map(|n| n.1));
        if is_covered(points, location, radius, MAX_TRIANGLE_CANDIDATES, &mut stats.coverage) {
            return (start, end);
        }
        start = end;
    }
    unreachable!("the last surface is always returned")
}
