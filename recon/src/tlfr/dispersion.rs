//! The radius R of the paper's coverage test (Section 3.3, "Determining R"): "the dispersion of
//! a point set is the radius of the largest circle that does not contain any of the points ...
//! When measuring R, we take the maximum dispersion under a large number of random
//! reprojections. The measured values for R are approximately 2/sqrt(N) for our Sobol
//! sequences". Holes smaller than R are beyond the resolution of the input sampling.
//!
//! `dispersion` measures the largest empty circle whose centre lies in a rectangle, by the
//! distance from every point of a fine grid to its nearest sample (a bucket grid answers the
//! nearest-neighbour queries); the result is exact up to the grid step times 1/√2 from below.
//!
//! `measure_radius` takes the input file's own (x, y, u, v, t) pattern — not an assumed one:
//! our tracer pairs its Sobol' dimensions by per-pixel shuffling, so its dispersion under
//! reprojection need not be the paper's — in a window of about `WINDOW_SAMPLES` samples at the
//! image centre, applies `trials` random reprojections of a plane (a constant circle of
//! confusion c ∈ [−8, 8] px and a screen velocity m ∈ [−8, 8]² px over the shutter, towards a
//! random (û, v̂, t̂): x + (û − u)·c + (t̂ − t)·m_x) plus the identity, and returns the largest
//! dispersion. Samples from an apron of `MAX_SHIFT_PX` around the window keep it populated
//! after the shift. The random numbers come from a fixed seed: the same file gives the same R.

use std::sync::atomic::{AtomicU32, Ordering};

use rayon::prelude::*;

use super::reprojection::LensTimeSample;

/// Samples per measurement window.
pub const WINDOW_SAMPLES: usize = 2048;
/// The largest shift of a random reprojection, pixels (|û − u|·8 + |t̂ − t|·8 ≤ 24).
pub const MAX_SHIFT_PX: f32 = 24.0;

/// A bucket grid over 2D points for nearest-neighbour distances.
struct Buckets<'a> {
    points: &'a [[f32; 2]],
    origin: [f32; 2],
    cell: f32,
    columns: usize,
    rows: usize,
    /// `starts[c]..starts[c + 1]` index `order` for cell c.
    starts: Vec<u32>,
    order: Vec<u32>,
}

impl<'a> Buckets<'a> {
    fn new(points: &'a [[f32; 2]], cell: f32) -> Buckets<'a> {
        let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
        for p in points {
            for k in 0..2 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        let columns = (((hi[0] - lo[0]) / cell) as usize + 1).min(1 << 12);
        let rows = (((hi[1] - lo[1]) / cell) as usize + 1).min(1 << 12);
        let mut buckets =
            Buckets { points, origin: lo, cell, columns, rows, starts: vec![0; columns * rows + 1], order: Vec::new() };
        let cells: Vec<usize> = points.iter().map(|p| buckets.cell_of(*p)).collect();
        for &c in &cells {
            buckets.starts[c + 1] += 1;
        }
        for c in 0..columns * rows {
            buckets.starts[c + 1] += buckets.starts[c];
        }
        let mut fill = buckets.starts.clone();
        buckets.order = vec![0; points.len()];
        for (i, &c) in cells.iter().enumerate() {
            buckets.order[fill[c] as usize] = i as u32;
            fill[c] += 1;
        }
        buckets
    }

    fn coordinates(&self, p: [f32; 2]) -> (usize, usize) {
        let column = ((p[0] - self.origin[0]) / self.cell).max(0.0) as usize;
        let row = ((p[1] - self.origin[1]) / self.cell).max(0.0) as usize;
        (column.min(self.columns - 1), row.min(self.rows - 1))
    }

    fn cell_of(&self, p: [f32; 2]) -> usize {
        let (column, row) = self.coordinates(p);
        row * self.columns + column
    }

    /// Distance from `q` to the nearest point (∞ when there is none).
    fn nearest_distance(&self, q: [f32; 2]) -> f32 {
        let (column, row) = self.coordinates(q);
        let mut best = f32::INFINITY;
        let max_ring = self.columns.max(self.rows);
        for ring in 0..=max_ring {
            // Every point in ring r + 1 or beyond is at least r cells away.
            if ring > 0 && (ring - 1) as f32 * self.cell >= best {
                break;
            }
            let (r0, r1) = (row.saturating_sub(ring), (row + ring).min(self.rows - 1));
            let (c0, c1) = (column.saturating_sub(ring), (column + ring).min(self.columns - 1));
            for y in r0..=r1 {
                for x in c0..=c1 {
                    if y.abs_diff(row) != ring && x.abs_diff(column) != ring {
                        continue;
                    }
                    let cell = y * self.columns + x;
                    for &i in &self.order[self.starts[cell] as usize..self.starts[cell + 1] as usize] {
                        let p = self.points[i as usize];
                        let d = ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt();
                        best = best.min(d);
                    }
                }
            }
        }
        best
    }
}

/// Grid steps per side of the coarsest blocks that `dispersion` bounds; each level halves them
/// down to single grid points (8, 4, 2, 1).
const COARSEST_BLOCK_STEPS: usize = 8;

/// The radius of the largest circle free of `points` whose centre lies in `region`
/// ([x0, y0, x1, y1]), measured on a grid of step `step` (at most `step / √2` too small).
/// `None` when there are no points or the region is empty.
///
/// Branch and bound, exact: see `dispersion_above`, here with no floor. The result is the
/// maximum over the full grid, bit for bit (the test compares it with the plain scan).
pub fn dispersion(points: &[[f32; 2]], region: [f32; 4], step: f32) -> Option<f32> {
    dispersion_above(points, region, step, &AtomicU32::new(0))
}

/// `dispersion` for a caller that only needs the maximum where it exceeds `floor` (the bits of
/// a non-negative f32, shared between measurements whose largest value is wanted): returns the
/// grid maximum when it exceeds the floor, otherwise a value that is no larger than the
/// maximum; raises the floor to every grid value it finds.
///
/// The distance to the nearest point is 1-Lipschitz, so a block of s × s grid points whose
/// representative (the grid point s/2 steps in from its first corner, clamped to the grid)
/// lies at distance d holds no grid point farther than d + (s/2)·√2 steps. Blocks of
/// `COARSEST_BLOCK_STEPS` steps are bounded first; those whose bound reaches the largest value
/// found (or the floor) are split into four, down to single grid points. A block is dropped
/// only when its bound is below a value some grid point has, with room for f32 rounding of the
/// grid positions and distances, so the grid maximum is never dropped.
fn dispersion_above(points: &[[f32; 2]], region: [f32; 4], step: f32, floor: &AtomicU32) -> Option<f32> {
    let [x0, y0, x1, y1] = region;
    let usable = x1 >= x0 && y1 >= y0 && step > 0.0;
    if points.is_empty() || !usable {
        return None;
    }
    let area = ((x1 - x0) * (y1 - y0)).max(step * step);
    let spacing = (area / points.len() as f32).sqrt().max(1e-6);
    let buckets = Buckets::new(points, spacing);
    let nx = ((x1 - x0) / step).round() as usize;
    let ny = ((y1 - y0) / step).round() as usize;
    let grid_point = |i: usize, j: usize| [x0 + i as f32 * step, y0 + j as f32 * step];
    // Rounding of the grid positions (each coordinate within an ulp of its magnitude, two
    // points) and of the distances (a few ulps each).
    let magnitude = [x0, y0, x1, y1].iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let slack = 8.0 * magnitude * f32::EPSILON + 1e-5 * step;
    let reach = |size: usize| step * (size / 2) as f32 * std::f32::consts::SQRT_2 * (1.0 + 1e-4) + slack;
    // A block: its first grid indices and its representative's distance.
    let evaluate = |bi: usize, bj: usize, size: usize| {
        let distance = buckets.nearest_distance(grid_point((bi + size / 2).min(nx), (bj + size / 2).min(ny)));
        (bi, bj, distance)
    };
    let mut size = COARSEST_BLOCK_STEPS;
    let mut blocks: Vec<(usize, usize, f32)> = (0..=ny / size)
        .flat_map(|bj| (0..=nx / size).map(move |bi| (bi * size, bj * size)))
        .map(|(bi, bj)| evaluate(bi, bj, size))
        .collect();
    let mut largest = blocks.iter().fold(0.0f32, |m, b| m.max(b.2));
    while size > 1 {
        floor.fetch_max(largest.to_bits(), Ordering::Relaxed);
        let cut = largest.max(f32::from_bits(floor.load(Ordering::Relaxed)));
        let bound = reach(size);
        let half = size / 2;
        let mut children = Vec::new();
        for &(bi, bj, distance) in &blocks {
            if distance * (1.0 + 1e-5) + bound < cut {
                continue;
            }
            for (ci, cj) in [(bi, bj), (bi + half, bj), (bi, bj + half), (bi + half, bj + half)] {
                if ci <= nx && cj <= ny {
                    children.push(evaluate(ci, cj, half));
                }
            }
        }
        largest = children.iter().fold(largest, |m, b| m.max(b.2));
        blocks = children;
        size = half;
    }
    floor.fetch_max(largest.to_bits(), Ordering::Relaxed);
    Some(largest)
}

/// The plain scan `dispersion` must agree with.
#[cfg(test)]
fn dispersion_by_scan(points: &[[f32; 2]], region: [f32; 4], step: f32) -> Option<f32> {
    let [x0, y0, x1, y1] = region;
    if points.is_empty() || x1 < x0 || y1 < y0 || step <= 0.0 {
        return None;
    }
    let nx = ((x1 - x0) / step).round() as usize;
    let ny = ((y1 - y0) / step).round() as usize;
    let mut largest = 0.0f32;
    for j in 0..=ny {
        for i in 0..=nx {
            let q = [x0 + i as f32 * step, y0 + j as f32 * step];
            let nearest =
                points.iter().fold(f32::INFINITY, |m, p| m.min(((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt()));
            largest = largest.max(nearest);
        }
    }
    Some(largest)
}

struct SplitMix(u64);

impl SplitMix {
    fn next(&mut self) -> f32 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// The seed of `measure_radius`'s reprojections, combined with the run's seed (seed 0 keeps it).
const REPROJECTION_SEED: u64 = 0x5eed_0fd1_5e75_0000;

/// R measured from a file's samples (`samples` row-major by pixel, `spp` per pixel, image
/// `width` × `height`): the largest dispersion over the identity and `trials` random
/// reprojections drawn from `seed` (see the module notes). `None` when there is no sample.
pub fn measure_radius(
    samples: &[LensTimeSample],
    width: u32,
    height: u32,
    spp: u32,
    trials: u32,
    seed: u32,
) -> Option<f32> {
    let trials = Trials::new(samples, width, height, spp, trials, seed)?;
    // The trials run in parallel and share the largest value found so far: a trial skips what
    // cannot beat it, and the maximum over the trials stays exact (`dispersion_above`) whatever
    // order they finish in.
    let floor = AtomicU32::new(0);
    let largest = (0..trials.reprojections.len())
        .into_par_iter()
        .map(|k| dispersion_above(&trials.points(k), trials.region, trials.step, &floor).unwrap_or(0.0))
        .reduce(|| 0.0f32, f32::max);
    Some(largest)
}

/// The point sets `measure_radius` takes the dispersion of: the window's samples, and their
/// region and grid step.
struct Trials<'a> {
    chosen: Vec<&'a LensTimeSample>,
    /// The window's corner and side, pixels.
    lo: [f32; 2],
    size: f32,
    /// Copies across the window's edges within this margin make the window a torus.
    margin: f32,
    step: f32,
    region: [f32; 4],
    /// Per trial: circle of confusion, velocity and the target (û, v̂, t̂) (`None`: the identity).
    reprojections: Vec<(f32, [f32; 2], Option<[f32; 3]>)>,
}

impl<'a> Trials<'a> {
    fn new(samples: &'a [LensTimeSample], width: u32, height: u32, spp: u32, trials: u32, seed: u32) -> Option<Self> {
        if samples.is_empty() || spp == 0 || width == 0 || height == 0 {
            return None;
        }
        let side = ((WINDOW_SAMPLES as f32 / spp as f32).sqrt().ceil() as u32).clamp(1, width.min(height));
        let x0 = (width - side) / 2;
        let y0 = (height - side) / 2;
        let mut chosen: Vec<&LensTimeSample> = Vec::new();
        for y in y0..y0 + side {
            for x in x0..x0 + side {
                let first = (y as usize * width as usize + x as usize) * spp as usize;
                let pixel = samples.iter().skip(first).take(spp as usize);
                chosen
                    .extend(pixel.filter(|s| s.x.is_finite() && s.y.is_finite() && s.u.is_finite() && s.t.is_finite()));
            }
        }
        if chosen.is_empty() {
            return None;
        }
        let (lo, size) = ([x0 as f32, y0 as f32], side as f32);
        let margin = (3.0 + 4.0 / (spp as f32).sqrt()).min(size);
        let step = 0.1 / (spp as f32).sqrt();
        let region = [lo[0], lo[1], lo[0] + size, lo[1] + size];
        let mut rng = SplitMix(REPROJECTION_SEED ^ u64::from(seed));
        // The trials' random reprojections, drawn in order.
        let reprojections = (0..=trials)
            .map(|trial| {
                if trial == 0 {
                    (0.0, [0.0, 0.0], None)
                } else {
                    let coc = 16.0 * rng.next() - 8.0;
                    let velocity = [16.0 * rng.next() - 8.0, 16.0 * rng.next() - 8.0];
                    (coc, velocity, Some([2.0 * rng.next() - 1.0, 2.0 * rng.next() - 1.0, rng.next()]))
                }
            })
            .collect();
        Some(Trials { chosen, lo, size, margin, step, region, reprojections })
    }

    /// The points of trial `k`: the window's samples reprojected, wrapped into the window and
    /// copied across its edges within the margin.
    fn points(&self, k: usize) -> Vec<[f32; 2]> {
        let (coc, velocity, target) = self.reprojections[k];
        let (lo, size, margin) = (self.lo, self.size, self.margin);
        let mut points = Vec::with_capacity(self.chosen.len() * 2);
        for s in &self.chosen {
            let shifted = match target {
                None => [s.x, s.y],
                Some([u, v, t]) => {
                    let dt = t - s.t;
                    [s.x + (u - s.u) * coc + dt * velocity[0], s.y + (v - s.v) * coc + dt * velocity[1]]
                }
            };
            let wrapped = [0, 1].map(|k| lo[k] + (shifted[k] - lo[k]).rem_euclid(size));
            for dy in [-1.0f32, 0.0, 1.0] {
                for dx in [-1.0f32, 0.0, 1.0] {
                    let copy = [wrapped[0] + dx * size, wrapped[1] + dy * size];
                    let inside = |k: usize| copy[k] >= lo[k] - margin && copy[k] <= lo[k] + size + margin;
                    if inside(0) && inside(1) {
                        points.push(copy);
                    }
                }
            }
        }
        points
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lcg::Lcg;

    #[test]
    fn lattices_have_their_known_dispersion() {
        // Square lattice of spacing 1: the largest empty circle is centred in a cell, radius
        // √2/2. The grid step divides the spacing, so the cell centres are on the grid.
        let square: Vec<[f32; 2]> = (0..21).flat_map(|j| (0..21).map(move |i| [i as f32, j as f32])).collect();
        let d = dispersion(&square, [5.0, 5.0, 15.0, 15.0], 0.05).unwrap();
        assert!((d - 0.5f32.sqrt()).abs() < 1e-4, "{d}");
        // Hexagonal (triangular) lattice of spacing 1: radius 1/√3, the triangles' circumradius.
        let h = 3.0f32.sqrt() / 2.0;
        let hex: Vec<[f32; 2]> =
            (0..24).flat_map(|j| (0..24).map(move |i| [i as f32 + 0.5 * (j % 2) as f32, j as f32 * h])).collect();
        let d = dispersion(&hex, [6.0, 6.0, 14.0, 14.0], 0.01).unwrap();
        let expected = 1.0 / 3.0f32.sqrt();
        assert!(d <= expected + 1e-4 && d > expected - 0.01, "{d} vs {expected}");
        assert_eq!(dispersion(&[], [0.0, 0.0, 1.0, 1.0], 0.1), None);
        // One point: the farthest region corner.
        let one = dispersion(&[[0.0, 0.0]], [0.0, 0.0, 3.0, 4.0], 0.5).unwrap();
        assert!((one - 5.0).abs() < 1e-5);
    }

    /// The branch and bound returns exactly the plain scan's maximum: uniform points, a
    /// cluster leaving most of the region empty, a single point, points outside the region.
    #[test]
    fn bounded_scan_equals_the_plain_scan() {
        let mut rng = Lcg(17);
        for case in 0..12 {
            let count = [1usize, 7, 60, 400][case % 4];
            let spread = if case < 4 {
                10.0
            } else if case < 8 {
                2.5
            } else {
                30.0
            };
            let points: Vec<[f32; 2]> =
                (0..count).map(|_| [spread * rng.uniform() - 1.0, spread * rng.uniform() - 2.0]).collect();
            let region = [0.0, -1.0, 8.0, 7.5];
            let step = [0.05, 0.13, 0.3][case % 3];
            // Far from the origin as well, where the grid positions round coarsely.
            let offset = if case % 2 == 0 { 0.0 } else { 900.0 };
            let points: Vec<[f32; 2]> = points.iter().map(|p| [p[0] + offset, p[1] + offset]).collect();
            let region = [region[0] + offset, region[1] + offset, region[2] + offset, region[3] + offset];
            let bounded = dispersion(&points, region, step);
            let scanned = dispersion_by_scan(&points, region, step);
            assert_eq!(bounded.map(f32::to_bits), scanned.map(f32::to_bits), "case {case}: {bounded:?} {scanned:?}");
            // A floor below the maximum changes nothing; one above it gives at most the
            // maximum and is not lowered.
            let maximum = scanned.unwrap();
            let below = AtomicU32::new((0.5 * maximum).to_bits());
            assert_eq!(dispersion_above(&points, region, step, &below).map(f32::to_bits), Some(maximum.to_bits()));
            assert_eq!(below.load(Ordering::Relaxed), maximum.to_bits());
            let above = AtomicU32::new((2.0 * maximum + 1.0).to_bits());
            assert!(dispersion_above(&points, region, step, &above).unwrap() <= maximum);
            assert_eq!(above.load(Ordering::Relaxed), (2.0 * maximum + 1.0).to_bits());
        }
    }

    /// R is the largest of the trials' dispersions, each measured alone, bit for bit, with 1 and
    /// 3 threads sharing the floor.
    #[test]
    fn shared_floor_keeps_the_largest_trial_for_any_thread_count() {
        for (spp, seed) in [(1u32, 0u32), (4, 3), (16, 7)] {
            let (w, h) = (40, 36);
            let samples = jittered(w, h, spp, 11 + spp as u64);
            let trials = Trials::new(&samples, w, h, spp, 12, seed).unwrap();
            let alone = (0..trials.reprojections.len())
                .map(|k| dispersion(&trials.points(k), trials.region, trials.step).unwrap())
                .fold(0.0f32, f32::max);
            for threads in [1, 3] {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
                let measured = pool.install(|| measure_radius(&samples, w, h, spp, 12, seed)).unwrap();
                assert_eq!(measured.to_bits(), alone.to_bits(), "spp {spp}, {threads} threads: {measured} vs {alone}");
            }
        }
    }

    /// Stratified (jittered) screen positions with independent random lens and time values,
    /// `spp` per pixel.
    fn jittered(width: u32, height: u32, spp: u32, seed: u64) -> Vec<LensTimeSample> {
        let mut rng = Lcg(seed);
        let n = (spp as f32).sqrt().ceil() as u32;
        let mut samples = Vec::new();
        for y in 0..height {
            for x in 0..width {
                for s in 0..spp {
                    let (i, j) = (s % n, s / n);
                    samples.push(LensTimeSample {
                        x: x as f32 + (i as f32 + rng.uniform()) / n as f32,
                        y: y as f32 + (j as f32 + rng.uniform()) / (spp.div_ceil(n)) as f32,
                        u: 2.0 * rng.uniform() - 1.0,
                        v: 2.0 * rng.uniform() - 1.0,
                        t: rng.uniform(),
                        z: 1.0,
                        motion: [0.0; 3],
                    });
                }
            }
        }
        samples
    }

    #[test]
    fn measured_radius_scales_as_one_over_root_spp() {
        let mut previous = f32::INFINITY;
        for spp in [1u32, 4, 16, 64] {
            let (w, h) = (72, 64);
            let r = measure_radius(&jittered(w, h, spp, 3 + spp as u64), w, h, spp, 16, 0).unwrap();
            let scaled = r * (spp as f32).sqrt();
            assert!((1.2..=3.0).contains(&scaled), "spp {spp}: R = {r}, R·sqrt(spp) = {scaled}");
            assert!(r < previous, "R must fall as spp grows");
            previous = r;
        }
    }

    #[test]
    fn reprojection_makes_a_stratified_pattern_less_uniform() {
        // Without reprojection a jittered pattern with 16 spp has dispersion well below its
        // reprojected value (the paper's observation for Sobol' patterns).
        let (w, h, spp) = (48, 48, 16);
        let samples = jittered(w, h, spp, 5);
        let identity = measure_radius(&samples, w, h, spp, 0, 0).unwrap();
        let reprojected = measure_radius(&samples, w, h, spp, 16, 0).unwrap();
        assert!(reprojected > 1.2 * identity, "{identity} vs {reprojected}");
        // Tiny images and one pixel still give a finite radius.
        let one = jittered(1, 1, 4, 9);
        let r = measure_radius(&one, 1, 1, 4, 8, 0).unwrap();
        assert!(r.is_finite() && r > 0.0);
        assert_eq!(measure_radius(&[], 1, 1, 4, 8, 0), None);
    }
}
