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
use super::bounds::Window;
use super::coverage::{is_covered, tent_filter, CoverageStats, Point};
use super::hierarchy::Hierarchy;
use super::lens::LensModel;
use super::pixel_query::PixelQuery;
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
    /// Whether `integrate` walks the hierarchy once per pixel (`pixel_query`) instead of once
    /// per location; the same image bit for bit either way.
    pub one_query_per_pixel: bool,
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
    /// The current pixel's walk and candidates (`begin_pixel`), and the leaves a location
    /// found among them: (depth key, node, candidate leaf).
    pixel: PixelQuery,
    pixel_leaves: Vec<(f32, u32, u32)>,
}

impl Scratch {
    /// Walks `scene`'s hierarchy once per window of `windows` (one pixel's locations, by slice
    /// of the shutter), for the first pass's reach 2R (`pixel_query`): queries of those
    /// locations then start from the candidates found.
    pub fn begin_pixel(&mut self, scene: &Scene, windows: &[Window]) {
        self.pixel.prepare(scene.hierarchy, scene.samples, scene.lens, windows, 2.0 * scene.radius);
    }

    /// The current pixel's (candidate leaves, gates), for the bench and the tests.
    pub fn pixel_counts(&self) -> (usize, usize) {
        self.pixel.counts()
    }
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
    /// The pixels' walks of the hierarchy and candidate collection (`Scratch::begin_pixel`),
    /// timed by `integrate::integrate_clocked` outside the locations.
    pub pixel_s: f64,
    pub query_s: f64,
    pub coverage_s: f64,
    pub filter_s: f64,
    last: Option<std::time::Instant>,
}

impl StageTimes {
    pub fn add(&mut self, other: &StageTimes) {
        self.pixel_s += other.pixel_s;
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
/// (`scratch.surfaces`, front to back) leaf by leaf; from the pixel's candidates where
/// `Scratch::begin_pixel` prepared them for this location and reach (`gather_from_pixel`),
/// else through the tree (`gather_per_location`). Both give the same result bit for bit.
fn gather(scene: &Scene, location: Point, at: LensTime, reach: f32, scratch: &mut Scratch, stats: &mut QueryStats) {
    if let Some(part) = scratch.pixel.serving(scene.hierarchy, location, at, reach) {
        gather_from_pixel(scene, location, at, (reach, part), scratch, stats);
    } else {
        gather_per_location(scene, location, at, reach, scratch, stats);
    }
}

/// `gather` from the candidates of the location's pixel (`pixel_query`): the same leaves as
/// the tree walk (the pixel's gates tested here), sorted the same way, each leaf's samples
/// reprojected from the candidates' arrays to the same positions.
fn gather_from_pixel(
    scene: &Scene,
    location: Point,
    at: LensTime,
    (reach, part): (f32, usize),
    scratch: &mut Scratch,
    stats: &mut QueryStats,
) {
    let pixel = scratch.pixel.part(part);
    scratch.pixel_leaves.clear();
    pixel.leaves_at(location, at, scene.z_near, &mut scratch.pixel_leaves);
    stats.leaves += scratch.pixel_leaves.len() as u64;
    scratch.pixel_leaves.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    scratch.near.clear();
    scratch.surfaces.clear();
    scratch.surface_traces.clear();
    let window = corners(at, scene.delta);
    let mut surface_start = 0;
    for &(_, _, k) in &scratch.pixel_leaves {
        let before = scratch.near.len();
        let first = pixel.near_in_leaf(k as usize, scene.lens, location, at, reach, scene.z_near, &mut scratch.near);
        let Some(first) = first else {
            continue; // no samples within reach: the leaf plays no part in the grouping
        };
        let mut trace = [[0.0f32; 2]; 4];
        let mut seen_throughout = true;
        for (slot, corner) in trace.iter_mut().zip(window) {
            match pixel.position(first, scene.lens, corner, scene.z_near) {
                Some(p) => *slot = p,
                None => seen_throughout = false,
            }
        }
        let grouping = Grouping {
            surfaces: &mut scratch.surfaces,
            surface_traces: &mut scratch.surface_traces,
            surface_start: &mut surface_start,
        };
        grouping.add_leaf(before, scratch.near.len(), seen_throughout.then_some(trace));
    }
    if scratch.near.len() > surface_start {
        scratch.surfaces.push((surface_start, scratch.near.len()));
    }
}

/// Step 2's bookkeeping: the surfaces closed so far, the representatives of the current
/// surface's leaves at the window's corners and where the current surface starts in `near`.
struct Grouping<'a> {
    surfaces: &'a mut Vec<(usize, usize)>,
    surface_traces: &'a mut Vec<[[f32; 2]; 4]>,
    surface_start: &'a mut usize,
}

impl Grouping<'_> {
    /// A leaf whose samples within reach are `near[before..end]` (at least one), with its
    /// representative's positions at the window's corners, or `None` when the representative
    /// leaves the window through the camera plane (then the leaf is a surface of its own).
    /// It opens a new surface when Eq. 5 fails against a representative of the current one.
    fn add_leaf(self, before: usize, end: usize, trace: Option<[[f32; 2]; 4]>) {
        let same = trace.is_some_and(|trace| {
            self.surface_traces.iter().all(|other| {
                (0..2).all(|axis| consistent((0..4).map(|k| trace[k][axis] - other[k][axis]), CROSSING_TOLERANCE_PX))
            })
        });
        if !same && before > *self.surface_start {
            self.surfaces.push((*self.surface_start, before));
            *self.surface_start = before;
            self.surface_traces.clear();
        }
        match trace {
            Some(trace) => self.surface_traces.push(trace),
            None => {
                // Leaving the window (through the camera plane): a surface of its own.
                self.surfaces.push((*self.surface_start, end));
                *self.surface_start = end;
                self.surface_traces.clear();
            }
        }
    }
}

/// `gather` through the tree, one walk per location (the first form, kept as the oracle of
/// `gather_from_pixel` and for the passes and locations the pixel's walk does not serve).
fn gather_per_location(
    scene: &Scene,
    location: Point,
    at: LensTime,
    reach: f32,
    scratch: &mut Scratch,
    stats: &mut QueryStats,
) {
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
        let grouping = Grouping {
            surfaces: &mut scratch.surfaces,
            surface_traces: &mut scratch.surface_traces,
            surface_start: &mut surface_start,
        };
        grouping.add_leaf(before, scratch.near.len(), seen_throughout.then_some(trace));
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tlfr::integrate::{integrate_adaptive, location, pixel_windows, AdaptiveRule, Reconstruct};
    use crate::tlfr::nearest::reconstruct_nearest;
    use crate::tlfr::reprojection::near_limit;
    use crate::tlfr::test_scenes::{indexed, layered_scene, random_scene, sample_scene, MovingRect, ThinLens};

    /// The samples of `rects` through `lens` at `spp`, indexed for radius `radius`.
    fn indexed_scene(
        lens: &ThinLens,
        rects: &[MovingRect],
        spp: u32,
        radius: f32,
    ) -> (Hierarchy, Vec<LensTimeSample>, Vec<[f32; 3]>, LensModel, f32) {
        let (samples, colours) = sample_scene(lens, rects, spp, [0.5; 3], 5);
        let model = lens.model();
        let z_near = near_limit(samples.iter().map(|s| s.z));
        let (tree, samples, colours) = indexed(&samples, &colours, &model, z_near, (lens.width, lens.height), radius);
        (tree, samples, colours, model, z_near)
    }

    /// The scenes of the tests below: the layered scene with a card flying through the camera
    /// plane (time segments), without it, and random moving rectangles; (lens, rects, spp,
    /// radius). The third's radius is a quarter of its pattern's, so that many locations find
    /// nothing within 2R and widen.
    fn scenes() -> Vec<(ThinLens, Vec<MovingRect>, u32, f32)> {
        let mut scenes = vec![(layered_scene(48, 27, true), 4), (layered_scene(48, 27, false), 8)];
        scenes.extend((0..3).map(|seed| (random_scene(seed + 50, 48, 27), [2, 4, 16][seed as usize])));
        let radius = |k: usize, spp: u32| if k == 2 { 0.35 } else { 1.4 } / (spp as f32).sqrt();
        scenes.into_iter().enumerate().map(|(k, ((lens, rects), spp))| (lens, rects, spp, radius(k, spp))).collect()
    }

    /// The per-pixel path (`Scratch::begin_pixel`, `pixel_query`) against the per-location walk
    /// kept as the oracle, location by location: the same samples within reach with the same
    /// positions (bit for bit), the same surfaces, the same covering surface and radius, the
    /// same counters. Every location of the pixels is served by the pixel's candidates in its
    /// first pass; widened passes fall back to the tree.
    #[test]
    fn one_query_per_pixel_finds_what_each_location_finds() {
        let (mut served, mut total, mut compared, mut several_surfaces) = (0, 0, 0, 0);
        let mut widened = 0;
        for (lens, rects, spp, radius) in scenes() {
            let (tree, samples, colours, model, z_near) = indexed_scene(&lens, &rects, spp, radius);
            let locations = 32;
            let scene = Scene {
                samples: &samples,
                radiance: &colours,
                lens: &model,
                hierarchy: &tree,
                radius,
                z_near,
                delta: (1.0 / locations as f32).sqrt(),
                view_bandwidth: None,
                one_query_per_pixel: true,
            };
            let (mut fast, mut oracle) = (Scratch::default(), Scratch::default());
            for y in 0..lens.height {
                for x in (y % 3..lens.width).step_by(3) {
                    fast.begin_pixel(&scene, &pixel_windows(9, x, y, locations, (true, true)));
                    for j in 0..locations {
                        let (screen, at) = location(9, x, y, j, true, true);
                        served += fast.pixel.serving(scene.hierarchy, screen, at, 2.0 * radius).is_some() as usize;
                        total += 1;
                        let (mut fast_stats, mut oracle_stats) = (QueryStats::default(), QueryStats::default());
                        let a = covering_surface(&scene, screen, at, &mut fast, &mut fast_stats);
                        let b = covering_surface(&scene, screen, at, &mut oracle, &mut oracle_stats);
                        let what = format!("pixel ({x}, {y}) location {j}: {screen:?} {at:?}");
                        assert_eq!(a.map(f32::to_bits), b.map(f32::to_bits), "{what}");
                        assert_eq!(fast_stats, oracle_stats, "{what}");
                        widened += oracle_stats.widened;
                        if a.is_none() {
                            continue;
                        }
                        let bits = |near: &[(u32, Point)]| {
                            near.iter().map(|(i, p)| (*i, p[0].to_bits(), p[1].to_bits())).collect::<Vec<_>>()
                        };
                        assert_eq!(bits(&fast.near), bits(&oracle.near), "{what}");
                        assert_eq!(fast.surfaces, oracle.surfaces, "{what}");
                        assert_eq!(fast.covering, oracle.covering, "{what}");
                        several_surfaces += (oracle.surfaces.len() > 1) as usize;
                        compared += 1;
                    }
                }
            }
        }
        assert_eq!(served, total);
        assert!(compared > 20_000 && widened > 100, "{compared} compared, {widened} widened");
        assert!(several_surfaces > 1000, "{several_surfaces} locations with more than one surface");
    }

    /// Whole images through `integrate_adaptive` with one walk per pixel and with one per
    /// location: the same pixels bit for bit and the same counters, for `tlfr` and `tlfr-nn`,
    /// with N in every pixel and with the adaptive rule, on one thread and on three.
    #[test]
    fn one_query_per_pixel_gives_the_same_image_bit_for_bit() {
        let mut widened = 0;
        for (k, (lens, rects, spp, radius)) in scenes().into_iter().enumerate() {
            let (tree, samples, colours, model, z_near) = indexed_scene(&lens, &rects, spp, radius);
            let locations = [16, 64][k % 2];
            let scene = Scene {
                samples: &samples,
                radiance: &colours,
                lens: &model,
                hierarchy: &tree,
                radius,
                z_near,
                delta: (1.0 / locations as f32).sqrt(),
                view_bandwidth: None,
                one_query_per_pixel: true,
            };
            let per_location = Scene { one_query_per_pixel: false, ..scene };
            let size = (lens.width, lens.height);
            let rule = Some(AdaptiveRule { first: 8, spread: 0.05 });
            for (value, rule) in [(reconstruct as Reconstruct, None), (reconstruct, rule), (reconstruct_nearest, None)]
            {
                let run = |scene: &Scene, threads: usize| {
                    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
                    pool.install(|| {
                        integrate_adaptive(value, scene, size, (locations, rule), (true, true), 3, |_, _| [-1.0; 3])
                    })
                };
                let (expected, expected_stats) = run(&per_location, 1);
                for threads in [1, 3] {
                    let (image, stats) = run(&scene, threads);
                    assert_eq!(stats, expected_stats, "scene {k}, {rule:?}, {threads} threads");
                    for (p, q) in image.pixels.iter().zip(&expected.pixels) {
                        assert_eq!(p.map(f32::to_bits), q.map(f32::to_bits), "scene {k}, {rule:?}, {threads} threads");
                    }
                }
                widened += expected_stats.widened;
            }
        }
        assert!(widened > 100, "{widened}");
    }
}
