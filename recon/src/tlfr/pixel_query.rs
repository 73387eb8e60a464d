//! One hierarchy query per pixel (issue 24, item 2; not in the paper, whose GPU walks the
//! hierarchy once per location, Section 4 "Query"). Every location of a pixel asks the
//! hierarchy for nearly the same leaves, so the pixel walks it once for the union of its
//! locations' query windows and each location then works on the small list found:
//!
//! 1. `PixelQuery::prepare`: the bounding window of the pixel's locations in (x̂, ŷ, û, v̂, t̂)
//!    (`bounds::Window`), grown by the first pass's reach 2R, goes down the hierarchy once
//!    (`Hierarchy::leaves_near_window`): the leaves some location of the window may find, and
//!    the nodes on their paths whose test a location can fail (the gates; a node that every
//!    location of the window passes needs no test per location). The candidate leaves' samples
//!    are copied into one contiguous structure of arrays with the per-sample constants of
//!    Eq. 2–3 taken out of the loop: (x − u·C(z))·z, (y − v·C(z))·z, z, t, the homogeneous
//!    screen motion, and the query times the entry takes (`Hierarchy::entry_times`).
//! 2. Per location (`query::gather` when `PixelQuery::serving` finds its part): the gates,
//!    tested at the location in one loop over their planes copied into arrays (`Gates`, the
//!    f32 operations of `Bounds::near`, as `Hierarchy::open_gates`), give exactly the leaves
//!    `Hierarchy::leaves_near` gives there; each leaf's samples are reprojected in one loop over
//!    its arrays (`near_in_leaf`, three divisions per sample instead of four plus the screen
//!    motion) with the very operations of `reprojection::reproject` in the same order, so
//!    every position is the same f32 bit for bit; the grouping into surfaces is `query`'s own.
//!
//! A pixel may split its locations by slices of the shutter, one walk per slice
//! (`integrate::pixel_windows`); on monkeys-defocus-motion the window is dominated by the lens
//! and the pixel, and 4 or 8 slices only made more work (docs/tlfr.md), so the default is one.
//!
//! The result is the per-location query's (`query::gather` through the tree, kept as the
//! oracle and as the path of widened passes, whose reach the window was not walked for, and of
//! locations outside the window): the same leaves, samples, positions, surfaces and image, bit
//! for bit (tested in `query`).

use super::bounds::Window;
use super::coverage::Point;
use super::hierarchy::{Hierarchy, WindowLeaves, NO_GATE};
use super::lens::LensModel;
use super::reprojection::{LensTime, LensTimeSample};

/// The samples of the candidate leaves of one pixel, structure of arrays, with the constants of
/// their reprojection (`reprojection::reproject`).
#[derive(Clone, Debug, Default)]
struct Candidates {
    /// The entry (index into the scene's samples).
    entry: Vec<u32>,
    /// (x − u·C(z))·z and (y − v·C(z))·z; for a miss (z = +∞) x − u·c2 and y − v·c2.
    ax: Vec<f32>,
    ay: Vec<f32>,
    z: Vec<f32>,
    t: Vec<f32>,
    /// The homogeneous screen motion (`LensModel::screen_motion`).
    mx: Vec<f32>,
    my: Vec<f32>,
    mz: Vec<f32>,
    /// The query times the entry takes, half-open (`Hierarchy::entry_times`).
    from: Vec<f32>,
    until: Vec<f32>,
}

impl Candidates {
    fn clear(&mut self) {
        for v in [
            &mut self.ax,
            &mut self.ay,
            &mut self.z,
            &mut self.t,
            &mut self.mx,
            &mut self.my,
            &mut self.mz,
            &mut self.from,
            &mut self.until,
        ] {
            v.clear();
        }
        self.entry.clear();
    }

    fn push(&mut self, entry: u32, sample: &LensTimeSample, lens: &LensModel, times: [f32; 2]) {
        let (ax, ay) = if sample.z.is_infinite() {
            (sample.x - sample.u * lens.c2, sample.y - sample.v * lens.c2)
        } else {
            let c_old = lens.coc(sample.z);
            ((sample.x - sample.u * c_old) * sample.z, (sample.y - sample.v * c_old) * sample.z)
        };
        let m = lens.screen_motion(sample.motion);
        self.entry.push(entry);
        self.ax.push(ax);
        self.ay.push(ay);
        self.z.push(sample.z);
        self.t.push(sample.t);
        self.mx.push(m[0]);
        self.my.push(m[1]);
        self.mz.push(sample.motion[2]);
        self.from.push(times[0]);
        self.until.push(times[1]);
    }
}

/// The gates of a pixel's walk (`WindowLeaves::gates`) as a structure of arrays, so that a
/// location tests all of them in one loop: per gate the time span and the four planes
/// (`bounds::Bounds`; time, lens and constant coefficients), and the gate above it.
#[derive(Clone, Debug, Default)]
struct Gates {
    span: [Vec<f32>; 2],
    /// x_min, x_max, y_min, y_max; each [time, lens, constant].
    planes: [[Vec<f32>; 3]; 4],
    above: Vec<u32>,
    /// Per location: whether each gate's own test passes, then whether it and every gate above.
    passes: Vec<bool>,
}

impl Gates {
    fn collect(&mut self, hierarchy: &Hierarchy, found: &WindowLeaves) {
        self.span.iter_mut().for_each(Vec::clear);
        self.planes.iter_mut().flatten().for_each(Vec::clear);
        self.above.clear();
        for &(node, above) in &found.gates {
            let bounds = &hierarchy.node(node).bounds;
            self.span[0].push(bounds.span[0]);
            self.span[1].push(bounds.span[1]);
            for (arrays, plane) in self.planes.iter_mut().zip([bounds.x_min, bounds.x_max, bounds.y_min, bounds.y_max])
            {
                arrays[0].push(plane.time);
                arrays[1].push(plane.lens);
                arrays[2].push(plane.constant);
            }
            self.above.push(above);
        }
    }

    /// `Hierarchy::open_gates` over the arrays: each gate's `Bounds::near` with the same f32
    /// operations, in one branch-free loop, then the gates above in depth-first order.
    fn open(&mut self, location: Point, at: LensTime, reach: f32) -> &[bool] {
        let n = self.above.len();
        self.passes.resize(n, false);
        let passes = &mut self.passes[..n];
        let (s0, s1) = (&self.span[0][..n], &self.span[1][..n]);
        let plane = |k: usize| (&self.planes[k][0][..n], &self.planes[k][1][..n], &self.planes[k][2][..n]);
        let ((a0, a1, a2), (b0, b1, b2)) = (plane(0), plane(1));
        let ((c0, c1, c2), (d0, d1, d2)) = (plane(2), plane(3));
        for i in 0..n {
            let x_min = a0[i] * at.t + a1[i] * at.u + a2[i];
            let x_max = b0[i] * at.t + b1[i] * at.u + b2[i];
            let y_min = c0[i] * at.t + c1[i] * at.v + c2[i];
            let y_max = d0[i] * at.t + d1[i] * at.v + d2[i];
            passes[i] = (at.t >= s0[i])
                & (at.t <= s1[i])
                & (location[0] >= x_min - reach)
                & (location[0] <= x_max + reach)
                & (location[1] >= y_min - reach)
                & (location[1] <= y_max + reach);
        }
        for i in 0..n {
            let above = self.above[i];
            // Gates are depth first: the one above was decided before.
            passes[i] &= above == NO_GATE || passes[above as usize];
        }
        &self.passes[..n]
    }
}

/// Eq. 2–3 from the constants of `Candidates`: the position at `at` and whether the sample can
/// be seen there (depth at t̂ at least `z_near`; always for a miss). The same operations in the
/// same order as `reprojection::reproject`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn reprojected(
    ax: f32,
    ay: f32,
    z: f32,
    t: f32,
    mx: f32,
    my: f32,
    mz: f32,
    lens: (f32, f32),
    at: LensTime,
    z_near: f32,
) -> (f32, f32, bool) {
    let (c1, c2) = lens;
    let dt = at.t - t;
    let z_new = z + dt * mz;
    let c_new = if z_new.is_infinite() { c2 } else { c1 / z_new + c2 };
    let miss = z.is_infinite();
    let x = if miss { ax + at.u * c2 } else { (ax + dt * mx) / z_new + at.u * c_new };
    let y = if miss { ay + at.v * c2 } else { (ay + dt * my) / z_new + at.v * c_new };
    let seen = miss || !(z_new.is_nan() || z_new < z_near);
    (x, y, seen)
}

/// One pixel's walks of the hierarchy and their candidates (per thread, reused from pixel to
/// pixel; `query::Scratch` holds one): one part per slice of the shutter that holds locations
/// (`TIME_SLICES`).
#[derive(Clone, Debug, Default)]
pub struct PixelQuery {
    /// What the parts were collected for: the hierarchy (by address) and the reach; `None`
    /// before the first `prepare`.
    prepared_for: Option<(usize, f32)>,
    parts: Vec<Part>,
    used: usize,
}

/// One walk for a window of locations and its candidates.
#[derive(Clone, Debug, Default)]
pub struct Part {
    window: Window,
    reach: f32,
    found: WindowLeaves,
    /// Per leaf of `found.leaves`: its samples' range in `candidates`.
    ranges: Vec<(u32, u32)>,
    candidates: Candidates,
    gates: Gates,
    /// Per-location work space: a leaf's positions and verdicts.
    xs: Vec<f32>,
    ys: Vec<f32>,
    keep: Vec<bool>,
}

impl PixelQuery {
    /// Walks `hierarchy` once for every window of `windows` (the pixel's locations, one window
    /// per slice of the shutter) with reach `reach` and collects each one's candidates
    /// (`samples` in the hierarchy's order, seen through `lens`).
    pub fn prepare(
        &mut self,
        hierarchy: &Hierarchy,
        samples: &[LensTimeSample],
        lens: &LensModel,
        windows: &[Window],
        reach: f32,
    ) {
        if self.parts.len() < windows.len() {
            self.parts.resize_with(windows.len(), Part::default);
        }
        for (part, window) in self.parts.iter_mut().zip(windows) {
            part.prepare(hierarchy, samples, lens, *window, reach);
        }
        self.used = windows.len();
        self.prepared_for = Some((hierarchy as *const Hierarchy as usize, reach));
    }

    /// The part whose candidates answer a query of `hierarchy` at this location with this
    /// reach: prepared for that hierarchy and reach, with the location inside its window.
    #[inline]
    pub fn serving(&self, hierarchy: &Hierarchy, location: Point, at: LensTime, reach: f32) -> Option<usize> {
        let (tree, prepared_reach) = self.prepared_for?;
        if tree != hierarchy as *const Hierarchy as usize || prepared_reach != reach {
            return None;
        }
        self.parts[..self.used].iter().position(|part| part.window.contains(location, at))
    }

    /// Part `k` (`serving`).
    #[inline]
    pub(crate) fn part(&mut self, k: usize) -> &mut Part {
        &mut self.parts[k]
    }

    /// The candidate leaves (`leaves_near_window`) and the gates (the nodes tested per
    /// location), summed over the parts.
    pub fn counts(&self) -> (usize, usize) {
        self.parts[..self.used].iter().fold((0, 0), |(l, g), p| (l + p.found.leaves.len(), g + p.found.gates.len()))
    }
}

impl Part {
    fn prepare(
        &mut self,
        hierarchy: &Hierarchy,
        samples: &[LensTimeSample],
        lens: &LensModel,
        window: Window,
        reach: f32,
    ) {
        hierarchy.leaves_near_window(&window, reach, &mut self.found);
        self.gates.collect(hierarchy, &self.found);
        self.ranges.clear();
        self.candidates.clear();
        for &(leaf, _) in &self.found.leaves {
            let start = self.candidates.entry.len() as u32;
            for i in hierarchy.node(leaf).samples() {
                self.candidates.push(i as u32, &samples[i], lens, hierarchy.entry_times(i));
            }
            self.ranges.push((start, self.candidates.entry.len() as u32));
        }
        self.window = window;
        self.reach = reach;
    }

    /// The leaves `Hierarchy::leaves_near` returns at the location (which `PixelQuery::serving` must have given to this part),
    /// appended to `out` as (the depth of the leaf's first entry at t̂ as `query` sorts them,
    /// node index, candidate leaf index); `z_near` clamps the depth.
    pub(crate) fn leaves_at(&mut self, location: Point, at: LensTime, z_near: f32, out: &mut Vec<(f32, u32, u32)>) {
        let open = self.gates.open(location, at, self.reach);
        for (k, &(leaf, _)) in self.found.leaves.iter().enumerate() {
            if self.found.found(k, open) {
                let first = self.ranges[k].0 as usize;
                let (z, t, mz) = (self.candidates.z[first], self.candidates.t[first], self.candidates.mz[first]);
                // `reprojection::depth_at` of the leaf's first entry.
                let depth = if z.is_infinite() { z } else { z + (at.t - t) * mz };
                out.push((depth.max(z_near), leaf, k as u32));
            }
        }
    }

    /// Appends to `near` the samples of candidate leaf `k` that take t̂ and reproject within
    /// `reach` of `location` at `at`, in entry order, as (entry, position); returns the index
    /// of the first one among the candidates (for `position`), if any.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn near_in_leaf(
        &mut self,
        k: usize,
        lens: &LensModel,
        location: Point,
        at: LensTime,
        reach: f32,
        z_near: f32,
        near: &mut Vec<(u32, Point)>,
    ) -> Option<usize> {
        let (start, end) = (self.ranges[k].0 as usize, self.ranges[k].1 as usize);
        let n = end - start;
        let c = &self.candidates;
        let (ax, ay, z, t) = (&c.ax[start..end], &c.ay[start..end], &c.z[start..end], &c.t[start..end]);
        let (mx, my, mz) = (&c.mx[start..end], &c.my[start..end], &c.mz[start..end]);
        let (from, until) = (&c.from[start..end], &c.until[start..end]);
        self.xs.resize(n, 0.0);
        self.ys.resize(n, 0.0);
        self.keep.resize(n, false);
        let (xs, ys, keep) = (&mut self.xs[..n], &mut self.ys[..n], &mut self.keep[..n]);
        let reach2 = reach * reach;
        // One branch-free pass over the leaf's arrays.
        for i in 0..n {
            let (x, y, seen) =
                reprojected(ax[i], ay[i], z[i], t[i], mx[i], my[i], mz[i], (lens.c1, lens.c2), at, z_near);
            let takes = from[i] <= at.t && at.t < until[i];
            let (dx, dy) = (x - location[0], y - location[1]);
            xs[i] = x;
            ys[i] = y;
            keep[i] = takes & seen & (dx * dx + dy * dy <= reach2);
        }
        // Compaction without a branch: every sample is written, the kept ones advance.
        let first = keep.iter().position(|&k| k)? + start;
        let base = near.len();
        near.resize(base + n, (0, [0.0; 2]));
        let (out, entry) = (&mut near[base..], &c.entry[start..end]);
        let mut written = 0;
        for i in 0..n {
            out[written] = (entry[i], [xs[i], ys[i]]);
            written += keep[i] as usize;
        }
        near.truncate(base + written);
        Some(first)
    }

    /// Candidate `index`'s position at `at`, or `None` where it cannot be seen (as
    /// `reprojection::reproject`, bit for bit).
    #[inline]
    pub(crate) fn position(&self, index: usize, lens: &LensModel, at: LensTime, z_near: f32) -> Option<Point> {
        let c = &self.candidates;
        let (x, y, seen) = reprojected(
            c.ax[index],
            c.ay[index],
            c.z[index],
            c.t[index],
            c.mx[index],
            c.my[index],
            c.mz[index],
            (lens.c1, lens.c2),
            at,
            z_near,
        );
        seen.then_some([x, y])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tlfr::reprojection::reproject;
    use crate::tlfr::test_scenes::Lcg;

    /// The constants taken out of the loop change nothing: every position and every verdict
    /// equals `reproject`'s bit for bit, for samples moving through the camera plane, misses,
    /// lenses with and without defocus, and query times at the edges of the shutter.
    #[test]
    fn reprojection_from_the_arrays_equals_reproject_bit_for_bit() {
        let mut rng = Lcg(41);
        let mut candidates = Candidates::default();
        let mut query = Part::default();
        let (mut seen, mut unseen) = (0, 0);
        for case in 0..4000 {
            let f = 50.0 + 300.0 * rng.uniform();
            let a = if case % 5 == 0 { 0.0 } else { 0.3 * rng.uniform() };
            let lens =
                LensModel { c1: -f * a, c2: f * a / (0.5 + 8.0 * rng.uniform()), fx: f, fy: f, cx: 64.0, cy: 36.0 };
            let (u, v) = rng.disk();
            let t = rng.uniform();
            let z = 0.2 + 10.0 * rng.uniform();
            let motion = match case % 4 {
                0 => [0.0; 3],
                1 => [rng.uniform() - 0.5, rng.uniform() - 0.5, 2.0 * (rng.uniform() - 0.5)],
                // Through the camera plane within the shutter.
                2 => [rng.uniform() - 0.5, 0.1, -z / (0.05 + 0.9 * rng.uniform())],
                _ => [0.0, 0.0, 0.0],
            };
            let z = if case % 4 == 3 { f32::INFINITY } else { z };
            let sample = LensTimeSample { x: 128.0 * rng.uniform(), y: 72.0 * rng.uniform(), u, v, t, z, motion };
            candidates.clear();
            candidates.push(0, &sample, &lens, [f32::NEG_INFINITY, f32::INFINITY]);
            query.candidates = candidates.clone();
            let z_near = 1e-3;
            for k in 0..8 {
                let (u, v) = rng.disk();
                let t = [0.0, 1.0, rng.uniform()][k % 3];
                let at = LensTime { u, v, t };
                let expected = reproject(&sample, &lens, at, z_near).map(|p| [p.x.to_bits(), p.y.to_bits()]);
                let found = query.position(0, &lens, at, z_near).map(|p| [p[0].to_bits(), p[1].to_bits()]);
                assert_eq!(found, expected, "{sample:?} at {at:?}");
                if expected.is_some() {
                    seen += 1;
                } else {
                    unseen += 1;
                }
            }
        }
        assert!(seen > 20_000 && unseen > 500, "{seen} seen, {unseen} not");
    }
}
