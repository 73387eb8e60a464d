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
//!    the last surface is taken without a test); on the light side of soft shadows also a
//!    blocker at its rim (`covering_blocker`, `takes_rim`);
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

/// The stages of one location that `lfr-bench tlfr` times: the hierarchy walk with the
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

/// Seconds spent per stage (`lfr-bench tlfr`), summed over locations.
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
    let radius = covering_surface_clocked(scene, location, at, None, scratch, stats, clock)?;
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
    covering_surface_clocked(scene, location, at, None, scratch, stats, &mut NoClock)
}

/// `covering_surface` for the light side of soft shadows (Section 5): a surface whose first
/// sample `blocks` (it ends in front of the receiver) that no valid triangle of it covers is
/// still taken at its rim (`takes_rim`). The valid triangles' coverage ends at the hull of a
/// surface's samples, a fraction of their spacing inside its silhouette; on the camera side
/// that rim goes to the surface behind, shaded alike, but here it lets light through a
/// blocker's edge (the lamp's bright bias, docs/tlfr.md).
pub fn covering_blocker(
    scene: &Scene,
    location: Point,
    at: LensTime,
    blocks: &dyn Fn(u32) -> bool,
    scratch: &mut Scratch,
    stats: &mut QueryStats,
) -> Option<f32> {
    covering_surface_clocked(scene, location, at, Some(blocks), scratch, stats, &mut NoClock)
}

fn covering_surface_clocked(
    scene: &Scene,
    location: Point,
    at: LensTime,
    blocks: Option<&dyn Fn(u32) -> bool>,
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
        let chosen =
            choose_surface(&scratch.surfaces, &scratch.near, location, radius, blocks, &mut scratch.points, stats);
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

/// The range of the covering surface: the first (front-most) that covers the location, or a
/// blocker at its rim when `blocks` is given (`takes_rim`); small surfaces merge into the next;
/// the last is taken as it is.
fn choose_surface(
    surfaces: &[(usize, usize)],
    near: &[(u32, Point)],
    location: Point,
    radius: f32,
    blocks: Option<&dyn Fn(u32) -> bool>,
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
        if blocks.is_some_and(|blocks| blocks(near[start].0)) && takes_rim(&near[start..end], &near[end..], location) {
            return (start, end);
        }
        start = end;
    }
    unreachable!("the last surface is always returned")
}

/// Whether an uncovered surface (`front`) holds the location against the samples behind it
/// (`behind`, non-empty), all within 2R of it: when its nearest sample is nearer than theirs,
/// each distance in units of its own set's spacing. Both sets lie in the same disc, so a set of
/// n samples there has its spacing ∝ 1/√n and the test is d_front²·n_front < d_behind²·n_behind:
/// the boundary of the nearest-sample decision between two patterns, whatever their densities.
/// It neither erodes a silhouette (as the hull of its samples does) nor dilates it towards the
/// denser pattern (as the plain nearest sample does: a blocker's samples are dense where the
/// receiver beside it is mostly shadowed, sparse in an outer penumbra, docs/history/tlfr.md).
pub fn takes_rim(front: &[(u32, Point)], behind: &[(u32, Point)], location: Point) -> bool {
    let nearest = |set: &[(u32, Point)]| {
        set.iter()
            .map(|(_, p)| (p[0] - location[0]).powi(2) + (p[1] - location[1]).powi(2))
            .fold(f32::INFINITY, f32::min)
    };
    takes_rim_distances((nearest(front), front.len()), (nearest(behind), behind.len()))
}

/// `takes_rim` on each set's least squared distance and size: d_front²·n_front < d_behind²·n_behind.
pub fn takes_rim_distances((front, front_count): (f32, usize), (behind, behind_count): (f32, usize)) -> bool {
    front * (front_count as f32) < behind * (behind_count as f32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tlfr::reprojection::near_limit;
    use crate::tlfr::test_scenes::indexed;

    /// The rim test compares nearest distances in units of each set's spacing: a set four times
    /// denser needs its nearest sample half as far.
    #[test]
    fn the_rim_test_weighs_distance_by_density() {
        let one = |p: Point| vec![(0u32, p)];
        let four = |p: Point| vec![(0u32, p), (1, [9.0, 9.0]), (2, [9.0, -9.0]), (3, [-9.0, 9.0])];
        assert!(takes_rim(&one([0.4, 0.0]), &one([0.0, 0.5]), [0.0; 2]));
        assert!(!takes_rim(&one([0.6, 0.0]), &one([0.0, 0.5]), [0.0; 2]));
        // 0.55² < 4·0.3²: farther, but nearer in its own spacing.
        assert!(takes_rim(&one([0.55, 0.0]), &four([0.0, 0.3]), [0.0; 2]));
        assert!(!takes_rim(&one([0.65, 0.0]), &four([0.0, 0.3]), [0.0; 2]));
    }

    /// A blocker whose samples are a quarter of a pattern (the penumbra of a soft shadow seen
    /// from the light: a fraction of the rays towards the receivers ends on it) in front of a
    /// receiver holding the pattern around it (its samples behind the blocker are hidden from
    /// this light point). Samples are jittered 4 per pixel with random lens positions; the
    /// blocker covers the square [5, 11]² seen from the lens centre at depth 0.8 (circle of
    /// confusion −4 px per lens unit, so that SAMESURFACE separates it from the receiver within
    /// the window), the receiver is in focus at depth 4; R = 1, the blocker's own spacing.
    /// Every location a pixel or more inside the square must find the blocker, every location
    /// 1.5 px or more outside the receiver. Near the edge the plain query erodes the square
    /// (the blocker's valid triangles end at the hull of its samples; measured: of the 204
    /// locations less than a pixel inside, 123 taken as lit), the rim rule must neither erode
    /// nor dilate it by a third of that (measured: 18 more locations found blocked than lie
    /// inside, between 1.5 px outside and 1 px inside).
    #[test]
    fn a_blocker_keeps_the_rim_of_its_silhouette() {
        let lens = LensModel { c1: -4.0, c2: 1.0, fx: 16.0, fy: 16.0, cx: 8.0, cy: 8.0 };
        let mut state = 11u32;
        let mut next = move || {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (state >> 8) as f32 / (1u32 << 24) as f32
        };
        // The signed distance to the square's edge, positive inside.
        let depth_inside =
            |p: [f32; 2]| [p[0] - 5.0, 11.0 - p[0], p[1] - 5.0, 11.0 - p[1]].into_iter().fold(f32::INFINITY, f32::min);
        let (mut samples, mut colours) = (Vec::new(), Vec::new());
        for y in 0..16 {
            for x in 0..16 {
                let quarter = (4.0 * next()) as u32;
                for s in 0..4 {
                    let centre =
                        [x as f32 + 0.5 * ((s % 2) as f32 + next()), y as f32 + 0.5 * ((s / 2) as f32 + next())];
                    let blocker = depth_inside(centre) > 0.0;
                    if blocker && s != quarter {
                        continue; // the rays that passed the blocker: behind it from here
                    }
                    let (u, v) = (2.0 * next() - 1.0, 2.0 * next() - 1.0);
                    let z = if blocker { 0.8 } else { 4.0 };
                    let coc = lens.coc(z);
                    samples.push(LensTimeSample {
                        x: centre[0] + u * coc,
                        y: centre[1] + v * coc,
                        u,
                        v,
                        t: next(),
                        z,
                        motion: [0.0; 3],
                    });
                    colours.push(if blocker { [0.0; 3] } else { [1.0; 3] });
                }
            }
        }
        let radius = 1.0;
        let z_near = near_limit(samples.iter().map(|s| s.z));
        let (tree, samples, colours) = indexed(&samples, &colours, &lens, z_near, (16, 16), radius);
        let scene = Scene {
            samples: &samples,
            radiance: &colours,
            lens: &lens,
            hierarchy: &tree,
            radius,
            z_near,
            delta: 0.5,
            view_bandwidth: None,
        };
        let blocks = |i: u32| samples[i as usize].z < 1.0;
        let (mut scratch, mut stats) = (Scratch::default(), QueryStats::default());
        let at = LensTime { u: 0.0, v: 0.0, t: 0.5 };
        let front = |scratch: &Scratch| scratch.covering.iter().all(|&i| samples[i as usize].z < 1.0);
        // Near the edge: the locations inside, and (found blocked − inside) of each rule.
        let (mut band_inside, mut plain_error, mut rim_error) = (0i32, 0i32, 0i32);
        for j in 0..1600u32 {
            let location = [2.0 + 12.0 * ((j % 40) as f32 + 0.5) / 40.0, 2.0 + 12.0 * ((j / 40) as f32 + 0.5) / 40.0];
            covering_blocker(&scene, location, at, &blocks, &mut scratch, &mut stats).unwrap();
            let with_rim = front(&scratch);
            covering_surface(&scene, location, at, &mut scratch, &mut stats).unwrap();
            let plain = front(&scratch);
            let depth = depth_inside(location);
            if depth >= 1.0 {
                assert!(with_rim, "{location:?}: the receiver behind the blocker was taken");
            } else if depth <= -1.5 {
                assert!(!with_rim, "{location:?}: the blocker spread beyond its silhouette");
            } else {
                let inside = i32::from(depth > 0.0);
                band_inside += inside;
                plain_error += i32::from(plain) - inside;
                rim_error += i32::from(with_rim) - inside;
            }
        }
        assert!(band_inside > 200 && plain_error < -band_inside / 5, "plain: {plain_error} of {band_inside}");
        assert!(3 * rim_error.abs() < -plain_error, "rim: {rim_error}, plain: {plain_error} of {band_inside}");
    }
}
