//! RECONSTRUCT (paper Section 3, steps 1–4) as one pass per sample: the fused kernel that
//! `tlfr` runs, with `query` kept as its oracle.
//!
//! `query` takes each sample of each leaf through separate loops (reprojection, reach test,
//! compaction into a list, grouping, the coverage test over the list, the tent filter over the
//! covering surface's list). Here every entry of every leaf the location needs is visited once,
//! `LANES` entries at a time from a structure of arrays (`Entries`, the per-entry constants of
//! Eq. 2–3 computed once), and that one visit reprojects it (Eq. 2–3), tests its time segment,
//! the near limit and the reach 2R, and adds it to its leaf's sums (`LeafSums`): the count within
//! reach, the first entry within reach (the leaf's representative), the nearest entry, the
//! quadrants occupied within R (the paper's early-out), and the tent's Σw and Σw·L over R
//! (with the light side's lit test folded in, so each light sample carries L or 0). Nothing is
//! stored per sample.
//!
//! The grouping then runs on the leaves alone (Section 4 "Query", Figure 7, as in `query`):
//! the leaves with an entry within reach, sorted by the depth at t̂ of their first entry, cut
//! into surfaces by SAMESURFACE (Eq. 5) between their representatives at the window's corners.
//! Each leaf holds one surface, so a surface's sums are its leaves' sums added: the surface
//! choice (Section 3.3: small surfaces merged into the next, the quadrant early-out, the rim of
//! a blocker on the light side) and the tent filter (step 4) read sums only. Only a surface
//! that the quadrant test cannot decide (2–7 % of the locations measured) needs its points:
//! its leaves are reprojected once more and the valid-triangle search of `coverage` runs on
//! them, exactly as in `query`.
//!
//! The leaves: for the first pass (reach 2R) the leaves any location of the pixel can need are
//! found by one walk per pixel over the window pixel × lens × shutter
//! (`Hierarchy::leaves_near_window`), and each location tests only those leaves' own bounds,
//! `LANES` at a time. The bounds are conservative for every sample below them, so a leaf whose
//! ancestors would have failed holds no sample within reach and changes nothing. Wider passes
//! (4R–16R, where nothing lay within 2R) walk the hierarchy per location (`leaves_near`).
//!
//! Against `query` (tested, per location and whole images): the same positions bit for bit (the
//! same f32 operations on constants computed the same way), so the same samples within reach,
//! the same representatives, surfaces, covering surface, coverage counters and nearest samples;
//! the filter's sums are added per lane in f32 and across leaves in f64 where `query` adds each
//! sample in f64, so a value differs by a few f32 roundings (relative 1e-5 in the tests). Ties
//! of the nearest sample go to the lower entry index in both.
//!
//! SIMD: the pass is written on arrays of `LANES` lanes with selects instead of branches, which
//! the compiler vectorises; `multiversion` compiles it for AVX2 (8 f32 lanes) and for baseline
//! x86-64 and picks at run time. Rust never fuses a multiply and an add on its own, so every
//! path does the same IEEE operations in the same order; the tests check the pass against a
//! scalar loop that calls `reprojection::reproject` per sample, bit for bit.
//!
//! Why one file of about 1,100 code lines: the entries' layout (`Entries`), the passes over them
//! (`leaf_pass`, `lean_pass`), their scalar oracles and the grouping that reads the sums share one
//! set of invariants (the same f32 operations in the same order as `query`, lane by lane), which
//! is what the tests check; apart, a change to one side could not be read against the other.

use multiversion::multiversion;

use super::bounds::Window;
use super::coverage::{is_covered, Point};
use super::hierarchy::Hierarchy;
use super::integrate::{integrate_locations, AdaptiveRule, Clocked};
use super::lens::LensModel;
use super::query::{
    takes_rim_distances, NoClock, QueryStats, Scene, Stage, StageClock, MAX_TRIANGLE_CANDIDATES, MAX_WIDENINGS,
    MIN_SURFACE_SAMPLES,
};
use super::reprojection::{LensTime, LensTimeSample};
use super::same_surface::{corners, CROSSING_TOLERANCE_PX};
use crate::image::Image;

/// Entries per SIMD step (8 f32 lanes of AVX2).
pub const LANES: usize = 8;

/// The entries of a hierarchy (its reordered samples, time segments apart) as a structure of
/// arrays with the per-entry constants of Eq. 2–3, padded by `LANES` entries that take no time.
///
/// For a sample at depth z (finite): `xc = (x − u·C(z))·z`, the screen motion (`LensModel::
/// screen_motion`) and the depth motion, each computed by the same f32 expression as
/// `reprojection::reproject`, so that Eq. 3 becomes `x′ = (xc + (t̂ − t)·m_x) / z′ + û·C(z′)`
/// with the same roundings. For a miss (z = ∞): `xc = x − u·c2` (it moves only with the lens at
/// infinity) and no motion.
#[derive(Clone, Debug, Default)]
pub struct Entries {
    xc: Vec<f32>,
    yc: Vec<f32>,
    mx: Vec<f32>,
    my: Vec<f32>,
    mz: Vec<f32>,
    z: Vec<f32>,
    t: Vec<f32>,
    /// The query times the entry takes, half-open (`Hierarchy::entry_times`).
    t_lo: Vec<f32>,
    t_hi: Vec<f32>,
    /// The value each entry carries into the filter, per channel.
    value: [Vec<f32>; 3],
    /// For a static entry (no motion, or a miss): its lens-centre position and C(z), so that
    /// x′ = x0 + û·C with the roundings of Eq. 3 (0 for the others).
    x0: Vec<f32>,
    y0: Vec<f32>,
    coc: Vec<f32>,
    /// Per node of the hierarchy: whether it is a leaf of static entries only.
    static_leaf: Vec<bool>,
    len: usize,
}

impl Entries {
    /// The arrays of `samples` (in the hierarchy's entry order) carrying `values`.
    pub fn new(samples: &[LensTimeSample], values: &[[f32; 3]], lens: &LensModel, tree: &Hierarchy) -> Entries {
        let n = samples.len();
        assert_eq!(values.len(), n, "one value per entry");
        let padded = n + LANES;
        let mut e = Entries {
            xc: Vec::with_capacity(padded),
            yc: Vec::with_capacity(padded),
            mx: Vec::with_capacity(padded),
            my: Vec::with_capacity(padded),
            mz: Vec::with_capacity(padded),
            z: Vec::with_capacity(padded),
            t: Vec::with_capacity(padded),
            t_lo: Vec::with_capacity(padded),
            t_hi: Vec::with_capacity(padded),
            value: [Vec::with_capacity(padded), Vec::with_capacity(padded), Vec::with_capacity(padded)],
            x0: Vec::with_capacity(padded),
            y0: Vec::with_capacity(padded),
            coc: Vec::with_capacity(padded),
            static_leaf: Vec::new(),
            len: n,
        };
        let mut is_static = Vec::with_capacity(n);
        for (k, (s, value)) in samples.iter().zip(values).enumerate() {
            let whole = k >= tree.entry_count() || tree.entry_times(k) == [f32::NEG_INFINITY, f32::INFINITY];
            if s.z.is_infinite() {
                let c = lens.c2;
                e.xc.push(s.x - s.u * c);
                e.yc.push(s.y - s.v * c);
                e.mx.push(0.0);
                e.my.push(0.0);
                e.mz.push(0.0);
                e.x0.push(s.x - s.u * c);
                e.y0.push(s.y - s.v * c);
                e.coc.push(c);
                is_static.push(whole);
            } else if s.motion == [0.0; 3] {
                // (xc + (t̂ − t)·0) / (z + (t̂ − t)·0) = xc / z: Eq. 3 without motion.
                let c_old = lens.coc(s.z);
                let xc = (s.x - s.u * c_old) * s.z;
                let yc = (s.y - s.v * c_old) * s.z;
                e.xc.push(xc);
                e.yc.push(yc);
                e.mx.push(0.0);
                e.my.push(0.0);
                e.mz.push(0.0);
                e.x0.push(xc / s.z);
                e.y0.push(yc / s.z);
                e.coc.push(c_old);
                is_static.push(whole);
            } else {
                let c_old = lens.coc(s.z);
                let m = lens.screen_motion(s.motion);
                e.xc.push((s.x - s.u * c_old) * s.z);
                e.yc.push((s.y - s.v * c_old) * s.z);
                e.mx.push(m[0]);
                e.my.push(m[1]);
                e.mz.push(s.motion[2]);
                e.x0.push(0.0);
                e.y0.push(0.0);
                e.coc.push(0.0);
                is_static.push(false);
            }
            e.z.push(s.z);
            e.t.push(s.t);
            let [lo, hi] = if k < tree.entry_count() { tree.entry_times(k) } else { [f32::INFINITY; 2] };
            e.t_lo.push(lo);
            e.t_hi.push(hi);
            for (array, &v) in e.value.iter_mut().zip(value) {
                array.push(v);
            }
        }
        e.static_leaf = tree
            .nodes()
            .iter()
            .map(|node| node.is_leaf() && node.samples().all(|i| is_static.get(i).copied().unwrap_or(false)))
            .collect();
        for _ in 0..LANES {
            let arrays =
                [&mut e.xc, &mut e.yc, &mut e.mx, &mut e.my, &mut e.mz, &mut e.t, &mut e.x0, &mut e.y0, &mut e.coc];
            for array in arrays {
                array.push(0.0);
            }
            e.z.push(1.0);
            e.t_lo.push(f32::INFINITY);
            e.t_hi.push(f32::INFINITY);
            for c in 0..3 {
                e.value[c].push(0.0);
            }
        }
        e
    }

    /// The number of entries (without the padding).
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Bytes of the arrays.
    pub fn bytes(&self) -> usize {
        (12 + 3) * self.xc.len() * std::mem::size_of::<f32>() + self.static_leaf.len()
    }

    /// Eq. 2–3 for entry `i` at `at`: `reprojection::reproject`'s position and depth bit for
    /// bit, `None` where its depth at t̂ is below `z_near`.
    #[inline]
    pub fn position(&self, i: usize, at: LensTime, lens: &LensModel, z_near: f32) -> Option<[f32; 3]> {
        let z = self.z[i];
        if z.is_infinite() {
            let c = lens.c2;
            return Some([self.xc[i] + at.u * c, self.yc[i] + at.v * c, z]);
        }
        let dt = at.t - self.t[i];
        let z_new = z + dt * self.mz[i];
        if z_new.is_nan() || z_new < z_near {
            return None;
        }
        let c = lens.coc(z_new);
        Some([
            (self.xc[i] + dt * self.mx[i]) / z_new + at.u * c,
            (self.yc[i] + dt * self.my[i]) / z_new + at.v * c,
            z_new,
        ])
    }

    /// `position` of entry `i` at the four corners of a window (`same_surface::corners`), `None`
    /// when any lies below the near limit; `static_entry` when the entry is static (its
    /// position is then x0 + û·C, `position`'s value without a division).
    #[inline]
    pub fn trace(
        &self,
        i: usize,
        window: &[LensTime; 4],
        static_entry: bool,
        lens: &LensModel,
        z_near: f32,
    ) -> Option<[[f32; 2]; 4]> {
        let u = window.map(|c| c.u);
        let v = window.map(|c| c.v);
        let mut x = [0.0f32; 4];
        let mut y = [0.0f32; 4];
        if static_entry {
            for k in 0..4 {
                x[k] = self.x0[i] + u[k] * self.coc[i];
                y[k] = self.y0[i] + v[k] * self.coc[i];
            }
        } else {
            if self.z[i].is_infinite() {
                let c = lens.c2;
                return Some([0, 1, 2, 3].map(|k| [self.xc[i] + u[k] * c, self.yc[i] + v[k] * c]));
            }
            let t = window.map(|c| c.t);
            let mut valid = true;
            for k in 0..4 {
                let dt = t[k] - self.t[i];
                let z_new = self.z[i] + dt * self.mz[i];
                valid &= z_new >= z_near;
                let c = lens.c1 / z_new + lens.c2;
                x[k] = (self.xc[i] + dt * self.mx[i]) / z_new + u[k] * c;
                y[k] = (self.yc[i] + dt * self.my[i]) / z_new + v[k] * c;
            }
            if !valid {
                return None;
            }
        }
        Some([[x[0], y[0]], [x[1], y[1]], [x[2], y[2]], [x[3], y[3]]])
    }

    /// Eq. 2: the depth of entry `i` at `t` (`reprojection::depth_at`).
    #[inline]
    pub fn depth_at(&self, i: usize, t: f32) -> f32 {
        let z = self.z[i];
        if z.is_infinite() {
            z
        } else {
            z + (t - self.t[i]) * self.mz[i]
        }
    }

    /// Whether entry `i` takes query time `t` (`Hierarchy::entry_takes`).
    #[inline]
    fn takes(&self, i: usize, t: f32) -> bool {
        self.t_lo[i] <= t && t < self.t_hi[i]
    }

    /// The value entry `i` carries.
    #[inline]
    pub fn value(&self, i: usize) -> [f32; 3] {
        [self.value[0][i], self.value[1][i], self.value[2][i]]
    }
}

/// The light side's lit test in the form the pass evaluates per sample (`shadows::ReceiverPlane`
/// and `shadows::reaches`): a light sample ending at (x′, y′, z′) reaches the receiver when
/// z′ ≥ d − `SHADOW_BIAS_RELATIVE`·d − `footprint_tolerance`, d the depth at which its ray from
/// the location's light point meets the receiver's plane (`fallback` where the ray runs nearly
/// parallel to the plane or meets it behind the light).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LitTest {
    pub normal: [f32; 3],
    /// offset − n·from, as `ReceiverPlane::depth_at` computes it.
    pub numerator: f32,
    pub from: [f32; 3],
    pub per_unit: [f32; 2],
    pub screen_offset: [f32; 2],
    pub plane_distance: f32,
    pub fallback: f32,
    pub relative: f32,
    /// `SHADOW_BIAS_FOOTPRINTS` × the footprint of the pass's radius.
    pub footprint_tolerance: f32,
}

impl LitTest {
    /// The scalar form of the pass's test: whether a light sample ending at `end` reaches.
    #[inline]
    pub fn reaches(&self, end: [f32; 3]) -> bool {
        let depth = self.depth_at(end[0], end[1]);
        end[2] >= depth - self.relative * depth - self.footprint_tolerance
    }

    #[inline(always)]
    fn depth_at(&self, x: f32, y: f32) -> f32 {
        let on_pi = [
            (x + self.screen_offset[0]) * self.per_unit[0],
            (y + self.screen_offset[1]) * self.per_unit[1],
            self.plane_distance,
        ];
        let direction = [on_pi[0] - self.from[0], on_pi[1] - self.from[1], on_pi[2] - self.from[2]];
        let along = self.normal[0] * direction[0] + self.normal[1] * direction[1] + self.normal[2] * direction[2];
        let t = self.numerator / along;
        let depth = t * self.plane_distance;
        let length = (direction[0] * direction[0] + direction[1] * direction[1] + direction[2] * direction[2]).sqrt();
        if (depth.abs() < f32::INFINITY) & (depth > 0.0) & (along.abs() > 1e-6 * length) {
            depth
        } else {
            self.fallback
        }
    }
}

/// A location's constants for one pass.
#[derive(Clone, Copy, Debug)]
pub struct Probe {
    pub x: f32,
    pub y: f32,
    pub at: LensTime,
    pub c1: f32,
    pub c2: f32,
    pub z_near: f32,
    /// The filter radius, (2R)², R² and the tent's reach R²·(1 + 1e-5) (`coverage::tent_filter`).
    pub radius: f32,
    pub reach_squared: f32,
    pub radius_squared: f32,
    pub tent_squared: f32,
}

impl Probe {
    pub fn new(location: Point, at: LensTime, lens: &LensModel, z_near: f32, radius: f32) -> Probe {
        let reach = 2.0 * radius;
        Probe {
            x: location[0],
            y: location[1],
            at,
            c1: lens.c1,
            c2: lens.c2,
            z_near,
            radius,
            reach_squared: reach * reach,
            radius_squared: radius * radius,
            tent_squared: radius * radius * (1.0 + 1e-5),
        }
    }
}

/// One leaf's entries at one location, summed in one pass.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LeafSums {
    /// Entries within reach (2R), and of those the ones the lit test lets through.
    pub count: u32,
    pub lit: u32,
    /// The first entry within reach: the leaf's representative.
    pub first: u32,
    /// The least squared distance within reach and its entry (the lower index on ties).
    pub nearest: f32,
    pub nearest_entry: u32,
    /// Bits 0–3: an entry within R in the open quadrant (+,+), (−,+), (−,−), (+,−).
    pub quadrants: u32,
    /// The tent over R: Σw and Σw·value (0 for light samples that do not reach).
    pub weight: f32,
    pub weighted: [f32; 3],
}

impl Default for LeafSums {
    fn default() -> Self {
        LeafSums {
            count: 0,
            lit: 0,
            first: u32::MAX,
            nearest: f32::INFINITY,
            nearest_entry: u32::MAX,
            quadrants: 0,
            weight: 0.0,
            weighted: [0.0; 3],
        }
    }
}

/// Per-lane partial sums of `LeafSums`, reduced in a fixed order.
pub struct LaneSums {
    pub count: [u32; LANES],
    pub lit: [u32; LANES],
    pub first: [u32; LANES],
    pub nearest: [f32; LANES],
    pub nearest_entry: [u32; LANES],
    pub quadrants: [u32; LANES],
    pub weight: [f32; LANES],
    pub weighted: [[f32; LANES]; 3],
}

impl Default for LaneSums {
    fn default() -> Self {
        LaneSums {
            count: [0; LANES],
            lit: [0; LANES],
            first: [u32::MAX; LANES],
            nearest: [f32::INFINITY; LANES],
            nearest_entry: [u32::MAX; LANES],
            quadrants: [0; LANES],
            weight: [0.0; LANES],
            weighted: [[0.0; LANES]; 3],
        }
    }
}

impl LaneSums {
    /// Adds one entry's contribution to lane `k`: `inside` (within reach), its squared distance
    /// and offsets, tent weight, value and whether it reaches.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub fn add(
        &mut self,
        k: usize,
        index: u32,
        inside: bool,
        offset: [f32; 2],
        squared: f32,
        weight: f32,
        value: [f32; 3],
        lit: bool,
        radius_squared: f32,
    ) {
        self.count[k] += inside as u32;
        self.lit[k] += (inside && lit) as u32;
        self.first[k] = self.first[k].min(if inside { index } else { u32::MAX });
        let closer = inside && squared < self.nearest[k];
        self.nearest[k] = if closer { squared } else { self.nearest[k] };
        self.nearest_entry[k] = if closer { index } else { self.nearest_entry[k] };
        let [dx, dy] = offset;
        let bits = ((dx > 0.0 && dy > 0.0) as u32)
            | (((dx < 0.0 && dy > 0.0) as u32) << 1)
            | (((dx < 0.0 && dy < 0.0) as u32) << 2)
            | (((dx > 0.0 && dy < 0.0) as u32) << 3);
        self.quadrants[k] |= if inside && squared <= radius_squared { bits } else { 0 };
        self.weight[k] += weight;
        for (sum, v) in self.weighted.iter_mut().zip(value) {
            sum[k] += weight * v;
        }
    }

    /// The lanes reduced in lane order.
    #[inline(always)]
    pub fn reduce(&self) -> LeafSums {
        let mut sums = LeafSums::default();
        for k in 0..LANES {
            sums.count += self.count[k];
            sums.lit += self.lit[k];
            sums.first = sums.first.min(self.first[k]);
            let (d, i) = (self.nearest[k], self.nearest_entry[k]);
            if d < sums.nearest || (d == sums.nearest && i < sums.nearest_entry) {
                sums.nearest = d;
                sums.nearest_entry = i;
            }
            sums.quadrants |= self.quadrants[k];
            sums.weight += self.weight[k];
            for c in 0..3 {
                sums.weighted[c] += self.weighted[c][k];
            }
        }
        sums
    }
}

/// The pass over the entries `first..end` of one leaf, `LANES` at a time; `LIT` folds the lit
/// test into each light sample's value.
#[inline(always)]
fn leaf_pass<const LIT: bool>(e: &Entries, first: usize, end: usize, p: &Probe, lit: &LitTest) -> LeafSums {
    let mut lanes = LaneSums::default();
    let mut base = first;
    while base < end {
        let active = end - base;
        let load = |array: &Vec<f32>| -> [f32; LANES] { array[base..base + LANES].try_into().expect("padded") };
        let (xc, yc, mx, my, mz) = (load(&e.xc), load(&e.yc), load(&e.mx), load(&e.my), load(&e.mz));
        let (z, t, t_lo, t_hi) = (load(&e.z), load(&e.t), load(&e.t_lo), load(&e.t_hi));
        let values = [load(&e.value[0]), load(&e.value[1]), load(&e.value[2])];
        for k in 0..LANES {
            let miss = z[k].abs() == f32::INFINITY;
            let dt = p.at.t - t[k];
            let z_new = z[k] + dt * mz[k];
            let x_moved = (xc[k] + dt * mx[k]) / z_new;
            let y_moved = (yc[k] + dt * my[k]) / z_new;
            let coc = p.c1 / z_new + p.c2;
            let x_centre = if miss { xc[k] } else { x_moved };
            let y_centre = if miss { yc[k] } else { y_moved };
            let c = if miss { p.c2 } else { coc };
            let x = x_centre + p.at.u * c;
            let y = y_centre + p.at.v * c;
            let (dx, dy) = (x - p.x, y - p.y);
            let squared = dx * dx + dy * dy;
            let takes = (k < active) & (t_lo[k] <= p.at.t) & (p.at.t < t_hi[k]) & (z_new >= p.z_near);
            let inside = takes & (squared <= p.reach_squared);
            let tent = (1.0 - squared.sqrt() / p.radius).max(0.0);
            let weight = if inside & (squared <= p.tent_squared) { tent } else { 0.0 };
            let reaches = !LIT || lit.reaches([x, y, z_new]);
            let value = [0, 1, 2].map(|c| if reaches { values[c][k] } else { 0.0 });
            lanes.add(k, (base + k) as u32, inside, [dx, dy], squared, weight, value, reaches, p.radius_squared);
        }
        base += LANES;
    }
    lanes.reduce()
}

/// The tent's per-lane sums of a leaf (Σw, Σw·value per channel), added lane by lane across the
/// leaves of a surface and reduced once.
pub type TentLanes = [[f32; LANES]; 4];

/// What the lean pass finds in one leaf.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LeafCount {
    /// Entries within reach (2R); of those, the ones the lit test lets through.
    pub count: u32,
    pub lit: u32,
    /// The first entry within reach: the leaf's representative (`u32::MAX` when none).
    pub first: u32,
}

/// The lean pass over the entries `first..end` of one leaf: positions, the reach test and the
/// tent's sums, nothing else (the nearest entry and the quadrants, which only some locations
/// need, come from `leaf_pass`). `STATIC`: every entry is static (`Entries::x0`), so that Eq. 3
/// needs no division; `LIT`: the lit test folded into each light sample's value.
#[inline(always)]
fn lean_pass<const STATIC: bool, const LIT: bool>(
    e: &Entries,
    first: usize,
    end: usize,
    p: &Probe,
    lit: &LitTest,
    tent: &mut TentLanes,
) -> LeafCount {
    let mut count = [0u32; LANES];
    let mut lit_count = [0u32; LANES];
    let mut first_inside = [u32::MAX; LANES];
    let lane_index: [u32; LANES] = std::array::from_fn(|k| k as u32);
    let mut base = first;
    while base < end {
        let active = (end - base) as u32;
        let load = |array: &Vec<f32>| -> [f32; LANES] { array[base..base + LANES].try_into().expect("padded") };
        let values = [load(&e.value[0]), load(&e.value[1]), load(&e.value[2])];
        if STATIC {
            let (x0, y0, coc, z) = (load(&e.x0), load(&e.y0), load(&e.coc), load(&e.z));
            for k in 0..LANES {
                let x = x0[k] + p.at.u * coc[k];
                let y = y0[k] + p.at.v * coc[k];
                let (dx, dy) = (x - p.x, y - p.y);
                let squared = dx * dx + dy * dy;
                let inside = (lane_index[k] < active) & (squared <= p.reach_squared);
                let reaches = !LIT || lit.reaches([x, y, z[k]]);
                accumulate(k, inside, squared, reaches, p, &values, tent);
                count[k] += inside as u32;
                if LIT {
                    lit_count[k] += (inside & reaches) as u32;
                }
                first_inside[k] = first_inside[k].min(if inside { base as u32 + lane_index[k] } else { u32::MAX });
            }
        } else {
            let (xc, yc, mx, my, mz) = (load(&e.xc), load(&e.yc), load(&e.mx), load(&e.my), load(&e.mz));
            let (z, t, t_lo, t_hi) = (load(&e.z), load(&e.t), load(&e.t_lo), load(&e.t_hi));
            for k in 0..LANES {
                let miss = z[k].abs() == f32::INFINITY;
                let dt = p.at.t - t[k];
                let z_new = z[k] + dt * mz[k];
                let x_moved = (xc[k] + dt * mx[k]) / z_new;
                let y_moved = (yc[k] + dt * my[k]) / z_new;
                let coc = p.c1 / z_new + p.c2;
                let c = if miss { p.c2 } else { coc };
                let x = if miss { xc[k] } else { x_moved } + p.at.u * c;
                let y = if miss { yc[k] } else { y_moved } + p.at.v * c;
                let (dx, dy) = (x - p.x, y - p.y);
                let squared = dx * dx + dy * dy;
                let takes = (lane_index[k] < active) & (t_lo[k] <= p.at.t) & (p.at.t < t_hi[k]) & (z_new >= p.z_near);
                let inside = takes & (squared <= p.reach_squared);
                let reaches = !LIT || lit.reaches([x, y, z_new]);
                accumulate(k, inside, squared, reaches, p, &values, tent);
                count[k] += inside as u32;
                if LIT {
                    lit_count[k] += (inside & reaches) as u32;
                }
                first_inside[k] = first_inside[k].min(if inside { base as u32 + lane_index[k] } else { u32::MAX });
            }
        }
        base += LANES;
    }
    let mut found = LeafCount { count: 0, lit: 0, first: u32::MAX };
    for k in 0..LANES {
        found.count += count[k];
        found.lit += if LIT { lit_count[k] } else { count[k] };
        found.first = found.first.min(first_inside[k]);
    }
    found
}

/// Adds lane `k`'s tent weight and weighted value to `tent`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn accumulate(
    k: usize,
    inside: bool,
    squared: f32,
    reaches: bool,
    p: &Probe,
    values: &[[f32; LANES]; 3],
    tent: &mut TentLanes,
) {
    let weight = (1.0 - squared.sqrt() / p.radius).max(0.0);
    let weight = if inside & (squared <= p.tent_squared) { weight } else { 0.0 };
    tent[0][k] += weight;
    for c in 0..3 {
        tent[c + 1][k] += weight * if reaches { values[c][k] } else { 0.0 };
    }
}

/// A leaf with an entry within reach: its depth key, index, what the pass found and where its
/// tent sums are (`FusedScratch::tents`).
#[derive(Clone, Copy, Debug)]
pub struct Contribution {
    pub key: f32,
    pub leaf: u32,
    pub found: LeafCount,
    pub slot: u32,
}

/// The lean pass over every leaf of `leaves`: the leaves with an entry within reach, in the
/// order given, with their depth keys (the depth at t̂ of their first entry, at least the near
/// limit) and their tent sums in `tents` (indexed by `Contribution::slot`).
#[multiversion(targets("x86_64+avx2+fma"))]
fn pass_leaves(
    e: &Entries,
    tree: &Hierarchy,
    leaves: &[u32],
    p: &Probe,
    lit: Option<&LitTest>,
    out: &mut Vec<Contribution>,
    tents: &mut Vec<TentLanes>,
) {
    out.clear();
    tents.clear();
    let mut tent = [[0.0f32; LANES]; 4];
    for &leaf in leaves {
        let range = tree.node(leaf).samples();
        let (first, end) = (range.start, range.end);
        let found = match (e.static_leaf[leaf as usize], lit) {
            (true, None) => lean_pass::<true, false>(e, first, end, p, &NO_LIT, &mut tent),
            (false, None) => lean_pass::<false, false>(e, first, end, p, &NO_LIT, &mut tent),
            (true, Some(lit)) => lean_pass::<true, true>(e, first, end, p, lit, &mut tent),
            (false, Some(lit)) => lean_pass::<false, true>(e, first, end, p, lit, &mut tent),
        };
        if found.count > 0 {
            let key = e.depth_at(first, p.at.t).max(p.z_near);
            out.push(Contribution { key, leaf, found, slot: tents.len() as u32 });
            tents.push(tent);
            tent = [[0.0f32; LANES]; 4];
        }
    }
}

/// The full sums of some leaves (`leaf_pass`, for the locations that need the nearest entry or
/// the quadrants), in the order given.
#[multiversion(targets("x86_64+avx2+fma"))]
fn full_sums(e: &Entries, tree: &Hierarchy, leaves: &[Contribution], p: &Probe, lit: Option<&LitTest>) -> LeafSums {
    let mut total = LeafSums::default();
    for c in leaves {
        let range = tree.node(c.leaf).samples();
        let sums = match lit {
            None => leaf_pass::<false>(e, range.start, range.end, p, &NO_LIT),
            Some(lit) => leaf_pass::<true>(e, range.start, range.end, p, lit),
        };
        total.add(&sums);
    }
    total
}

impl LeafSums {
    /// Adds another set of entries' sums (the nearest: the lower entry index on ties).
    pub fn add(&mut self, other: &LeafSums) {
        self.count += other.count;
        self.lit += other.lit;
        self.first = self.first.min(other.first);
        if other.nearest < self.nearest || (other.nearest == self.nearest && other.nearest_entry < self.nearest_entry) {
            self.nearest = other.nearest;
            self.nearest_entry = other.nearest_entry;
        }
        self.quadrants |= other.quadrants;
        self.weight += other.weight;
        for c in 0..3 {
            self.weighted[c] += other.weighted[c];
        }
    }
}

const NO_LIT: LitTest = LitTest {
    normal: [0.0; 3],
    numerator: 0.0,
    from: [0.0; 3],
    per_unit: [0.0; 2],
    screen_offset: [0.0; 2],
    plane_distance: 0.0,
    fallback: 0.0,
    relative: 0.0,
    footprint_tolerance: 0.0,
};

/// One entry of a leaf through `reprojection::reproject` (the oracle of the passes): its lane,
/// whether it lies within reach, its offset, squared distance, tent weight, value and whether
/// it reaches.
struct ScalarEntry {
    lane: usize,
    inside: bool,
    offset: [f32; 2],
    squared: f32,
    weight: f32,
    value: [f32; 3],
    reaches: bool,
}

fn scalar_entries<'a>(
    samples: &'a [LensTimeSample],
    e: &'a Entries,
    tree: &'a Hierarchy,
    leaf: u32,
    lens: &'a LensModel,
    p: &'a Probe,
    lit: Option<&'a LitTest>,
) -> impl Iterator<Item = (usize, ScalarEntry)> + 'a {
    let range = tree.node(leaf).samples();
    let start = range.start;
    range.map(move |i| {
        let lane = (i - start) % LANES;
        let found = if tree.entry_takes(i, p.at.t) {
            super::reprojection::reproject(&samples[i], lens, p.at, p.z_near)
        } else {
            None
        };
        let Some(q) = found else {
            let entry = ScalarEntry {
                lane,
                inside: false,
                offset: [0.0; 2],
                squared: f32::INFINITY,
                weight: 0.0,
                value: [0.0; 3],
                reaches: false,
            };
            return (i, entry);
        };
        let (dx, dy) = (q.x - p.x, q.y - p.y);
        let squared = dx * dx + dy * dy;
        let inside = squared <= p.reach_squared;
        let weight = if inside && squared <= p.tent_squared { (1.0 - squared.sqrt() / p.radius).max(0.0) } else { 0.0 };
        let reaches = lit.map_or(true, |lit| lit.reaches([q.x, q.y, q.z]));
        let value = if reaches { e.value(i) } else { [0.0; 3] };
        (i, ScalarEntry { lane, inside, offset: [dx, dy], squared, weight, value, reaches })
    })
}

/// `leaf_pass` one entry at a time through `reprojection::reproject` (the oracle of the SIMD
/// path: the same sums bit for bit).
pub fn leaf_pass_scalar(
    samples: &[LensTimeSample],
    e: &Entries,
    tree: &Hierarchy,
    leaf: u32,
    lens: &LensModel,
    p: &Probe,
    lit: Option<&LitTest>,
) -> LeafSums {
    let mut lanes = LaneSums::default();
    for (i, s) in scalar_entries(samples, e, tree, leaf, lens, p, lit) {
        lanes.add(s.lane, i as u32, s.inside, s.offset, s.squared, s.weight, s.value, s.reaches, p.radius_squared);
    }
    lanes.reduce()
}

/// `lean_pass` one entry at a time through `reprojection::reproject` (its oracle: the same
/// counts and lane sums bit for bit).
pub fn lean_pass_scalar(
    samples: &[LensTimeSample],
    e: &Entries,
    tree: &Hierarchy,
    leaf: u32,
    lens: &LensModel,
    p: &Probe,
    lit: Option<&LitTest>,
) -> (LeafCount, TentLanes) {
    let mut found = LeafCount { count: 0, lit: 0, first: u32::MAX };
    let mut tent = [[0.0f32; LANES]; 4];
    for (i, s) in scalar_entries(samples, e, tree, leaf, lens, p, lit) {
        if !s.inside {
            continue;
        }
        found.count += 1;
        found.lit += s.reaches as u32;
        found.first = found.first.min(i as u32);
        tent[0][s.lane] += s.weight;
        for c in 0..3 {
            tent[c + 1][s.lane] += s.weight * s.value[c];
        }
    }
    (found, tent)
}

/// The SIMD passes on one leaf (for the tests): `leaf_pass` and `lean_pass` through the
/// dispatching functions `tlfr` calls.
pub fn leaf_passes_simd(
    e: &Entries,
    tree: &Hierarchy,
    leaf: u32,
    p: &Probe,
    lit: Option<&LitTest>,
) -> (LeafSums, LeafCount, TentLanes) {
    let whole = Contribution { key: 0.0, leaf, found: LeafCount { count: 0, lit: 0, first: u32::MAX }, slot: 0 };
    let sums = full_sums(e, tree, &[whole], p, lit);
    let (mut out, mut tents) = (Vec::new(), Vec::new());
    pass_leaves(e, tree, &[leaf], p, lit, &mut out, &mut tents);
    match out.first() {
        Some(c) => (sums, c.found, tents[0]),
        None => (sums, LeafCount { count: 0, lit: 0, first: u32::MAX }, [[0.0; LANES]; 4]),
    }
}

/// The candidate leaves of one pixel, with their bounds as arrays for the per-location test.
#[derive(Default)]
struct PixelLeaves {
    /// (pixel, reach) the candidates were found for.
    key: Option<((u32, u32), f32)>,
    leaves: Vec<u32>,
    /// Bounds per candidate, padded to a multiple of `LANES` with leaves that are never near.
    planes: [Vec<f32>; 14],
}

impl PixelLeaves {
    fn find(&mut self, tree: &Hierarchy, window: &Window, reach: f32) {
        tree.leaves_near_window(window, reach, &mut self.leaves);
        for array in self.planes.iter_mut() {
            array.clear();
        }
        for &leaf in &self.leaves {
            let b = &tree.node(leaf).bounds;
            let values = [
                b.span[0],
                b.span[1],
                b.x_min.time,
                b.x_min.lens,
                b.x_min.constant,
                b.x_max.time,
                b.x_max.lens,
                b.x_max.constant,
                b.y_min.time,
                b.y_min.lens,
                b.y_min.constant,
                b.y_max.time,
                b.y_max.lens,
                b.y_max.constant,
            ];
            for (array, v) in self.planes.iter_mut().zip(values) {
                array.push(v);
            }
        }
        while self.planes[0].len() % LANES != 0 || self.planes[0].is_empty() {
            self.planes[0].push(f32::INFINITY); // a span that starts after every time
            for array in self.planes.iter_mut().skip(1) {
                array.push(0.0);
            }
        }
    }
}

/// The candidates whose bounds come within `reach` of `location` at `at` (`Bounds::near`, the
/// same f32 operations), appended to `out` in candidate order.
#[multiversion(targets("x86_64+avx2+fma"))]
fn near_candidates(candidates: &PixelLeaves, location: Point, at: LensTime, reach: f32, out: &mut Vec<u32>) {
    out.clear();
    let planes = &candidates.planes;
    let chunks = planes[0].len() / LANES;
    for chunk in 0..chunks {
        let base = chunk * LANES;
        let load = |k: usize| -> [f32; LANES] { planes[k][base..base + LANES].try_into().expect("padded") };
        let (s0, s1) = (load(0), load(1));
        let (xa, xb, xc, xd, xe, xf) = (load(2), load(3), load(4), load(5), load(6), load(7));
        let (ya, yb, yc, yd, ye, yf) = (load(8), load(9), load(10), load(11), load(12), load(13));
        let mut mask = [false; LANES];
        for k in 0..LANES {
            let (t, u, v) = (at.t, at.u, at.v);
            mask[k] = (t >= s0[k])
                & (t <= s1[k])
                & (location[0] >= xa[k] * t + xb[k] * u + xc[k] - reach)
                & (location[0] <= xd[k] * t + xe[k] * u + xf[k] + reach)
                & (location[1] >= ya[k] * t + yb[k] * v + yc[k] - reach)
                & (location[1] <= yd[k] * t + ye[k] * v + yf[k] + reach);
        }
        let mut bits = 0u32;
        for (k, &near) in mask.iter().enumerate() {
            bits |= (near as u32) << k;
        }
        while bits != 0 {
            let k = bits.trailing_zeros() as usize;
            out.push(candidates.leaves[base + k]);
            bits &= bits - 1;
        }
    }
}

/// What the fused kernel reads: the query's scene, its entries as arrays, and whether the
/// locations vary over the lens and the shutter (for the window of a pixel's walk).
pub struct Fused<'a> {
    pub scene: &'a Scene<'a>,
    pub entries: &'a Entries,
    pub has_lens: bool,
    pub has_time: bool,
}

/// Per-thread scratch of the fused kernel.
#[derive(Default)]
pub struct FusedScratch {
    pixel: PixelLeaves,
    leaves: Vec<u32>,
    contributing: Vec<Contribution>,
    tents: Vec<TentLanes>,
    /// The representatives of the current surface's leaves at the window's corners.
    traces: Vec<[[f32; 2]; 4]>,
    /// Surfaces as ranges of `contributing`.
    surfaces: Vec<(usize, usize)>,
    points: Vec<Point>,
}

/// The surface a location takes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Covering {
    /// The filter radius (R, or R widened).
    pub radius: f32,
    /// Entries within reach, and of those the ones the lit test let through.
    pub count: u32,
    pub lit: u32,
    /// The tent's Σw and Σw·value (per-lane f32 sums reduced in f64).
    pub weight: f64,
    pub weighted: [f64; 3],
    /// The least squared distance within reach and its entry (the lower index on ties): when
    /// asked for, or when no entry lies within R.
    pub nearest: Option<(f32, u32)>,
}

impl Covering {
    /// Step 4: the tent filter's value, or the nearest entry's where no entry lies within R.
    pub fn value(
        &self,
        entries: &Entries,
        lit: Option<&LitTest>,
        lens: &LensModel,
        at: LensTime,
        z_near: f32,
    ) -> [f32; 3] {
        if self.weight > 0.0 {
            return self.weighted.map(|s| (s / self.weight) as f32);
        }
        let Some((_, i)) = self.nearest else {
            return [0.0; 3];
        };
        let i = i as usize;
        let reaches = lit.map_or(true, |lit| entries.position(i, at, lens, z_near).is_some_and(|end| lit.reaches(end)));
        if reaches {
            entries.value(i)
        } else {
            [0.0; 3]
        }
    }
}

/// The reconstructed radiance at `location` and `at` of pixel `pixel` (`query::reconstruct`
/// through the fused pass), or `None` when nothing lies within 16R.
pub fn reconstruct(
    fused: &Fused,
    pixel: (u32, u32),
    location: Point,
    at: LensTime,
    scratch: &mut FusedScratch,
    stats: &mut QueryStats,
) -> Option<[f32; 3]> {
    reconstruct_clocked(fused, pixel, location, at, scratch, stats, &mut NoClock)
}

/// `reconstruct` with its stages timed by `clock` (`Stage::Query`: the leaves and the pass;
/// `Stage::Coverage`: grouping and the surface choice; `Stage::Filter`: the value).
pub fn reconstruct_clocked(
    fused: &Fused,
    pixel: (u32, u32),
    location: Point,
    at: LensTime,
    scratch: &mut FusedScratch,
    stats: &mut QueryStats,
    clock: &mut impl StageClock,
) -> Option<[f32; 3]> {
    clock.start();
    let query = Query { pixel: Some(pixel), location, at, light: None, nearest: false };
    let covering = covering_surface_clocked(fused, &query, scratch, stats, clock)?;
    let scene = fused.scene;
    let value = covering.value(fused.entries, None, scene.lens, at, scene.z_near);
    clock.lap(Stage::Filter);
    Some(value)
}

/// Eq. 1 through the fused kernel: `integrate::integrate_adaptive` of `query::reconstruct`
/// with `reconstruct` in its place.
pub fn integrate(
    fused: &Fused,
    size: (u32, u32),
    locations: (u32, Option<AdaptiveRule>),
    seed: u32,
    fallback: impl Fn(u32, u32) -> [f32; 3] + Sync,
) -> (Image, QueryStats) {
    integrate_locations(
        size,
        locations,
        (fused.has_lens, fused.has_time),
        seed,
        |(x, y, _), screen, at, scratch: &mut FusedScratch, stats: &mut QueryStats| {
            reconstruct(fused, (x, y), screen, at, scratch, stats)
        },
        fallback,
    )
}

/// `integrate` with every location's stages timed (`lfr-bench tlfr`): the same image bit for bit.
pub fn integrate_clocked(
    fused: &Fused,
    size: (u32, u32),
    locations: (u32, Option<AdaptiveRule>),
    seed: u32,
    fallback: impl Fn(u32, u32) -> [f32; 3] + Sync,
) -> (Image, Clocked) {
    integrate_locations(
        size,
        locations,
        (fused.has_lens, fused.has_time),
        seed,
        |(x, y, _), screen, at, scratch: &mut FusedScratch, clocked: &mut Clocked| {
            reconstruct_clocked(fused, (x, y), screen, at, scratch, &mut clocked.stats, &mut clocked.times)
        },
        fallback,
    )
}

/// The light side's lit test for a pass of filter radius r.
pub type LitFor<'a> = &'a dyn Fn(f32) -> LitTest;

/// One location's question to `covering_surface`.
pub struct Query<'a> {
    /// The pixel whose candidate leaves serve the first pass, or `None`: a walk per location.
    pub pixel: Option<(u32, u32)>,
    pub location: Point,
    pub at: LensTime,
    /// The light side (`query::covering_blocker`): the lit test for a pass of radius r, and
    /// whether an entry blocks (judged at the unwidened radius).
    pub light: Option<(LitFor<'a>, &'a dyn Fn(u32) -> bool)>,
    /// Whether the caller needs the covering surface's nearest entry.
    pub nearest: bool,
}

/// Steps 1–3 (`query::covering_surface`, or `query::covering_blocker` on the light side) and
/// the covering surface's sums, or `None` when nothing lies within 16R.
pub fn covering_surface(
    fused: &Fused,
    query: &Query,
    scratch: &mut FusedScratch,
    stats: &mut QueryStats,
) -> Option<Covering> {
    covering_surface_clocked(fused, query, scratch, stats, &mut NoClock)
}

fn covering_surface_clocked(
    fused: &Fused,
    query: &Query,
    scratch: &mut FusedScratch,
    stats: &mut QueryStats,
    clock: &mut impl StageClock,
) -> Option<Covering> {
    let scene = fused.scene;
    let tree = scene.hierarchy;
    let (location, at) = (query.location, query.at);
    stats.locations += 1;
    let mut radius = scene.radius;
    for widening in 0..=MAX_WIDENINGS {
        let reach = 2.0 * radius;
        match query.pixel {
            Some((x, y)) if widening == 0 => {
                let key = Some(((x, y), reach));
                if scratch.pixel.key != key {
                    let window = Window {
                        x: [x as f32, x as f32 + 1.0],
                        y: [y as f32, y as f32 + 1.0],
                        u: if fused.has_lens { [-1.0, 1.0] } else { [0.0, 0.0] },
                        v: if fused.has_lens { [-1.0, 1.0] } else { [0.0, 0.0] },
                        t: if fused.has_time { [0.0, 1.0] } else { [0.5, 0.5] },
                    };
                    scratch.pixel.find(tree, &window, reach);
                    scratch.pixel.key = key;
                }
                near_candidates(&scratch.pixel, location, at, reach, &mut scratch.leaves);
            }
            _ => tree.leaves_near(location, at, reach, &mut scratch.leaves),
        }
        stats.leaves += scratch.leaves.len() as u64;
        let probe = Probe::new(location, at, scene.lens, scene.z_near, radius);
        let lit = query.light.map(|(lit_for, _)| lit_for(radius));
        let lit = lit.as_ref();
        pass_leaves(fused.entries, tree, &scratch.leaves, &probe, lit, &mut scratch.contributing, &mut scratch.tents);
        clock.lap(Stage::Query);
        if scratch.contributing.is_empty() {
            radius *= 2.0;
            continue;
        }
        if widening > 0 {
            stats.widened += 1;
        }
        scratch.contributing.sort_unstable_by(|a, b| a.key.total_cmp(&b.key).then(a.leaf.cmp(&b.leaf)));
        group(fused, at, scratch);
        if scratch.surfaces.len() == 1 {
            stats.one_surface += 1;
        }
        let blocks = query.light.map(|(_, blocks)| blocks);
        let (start, end) = choose(fused, &probe, lit, blocks, scratch, stats);
        let covering = sum_range(fused, &scratch.contributing[start..end], &scratch.tents, &probe, lit, query.nearest);
        clock.lap(Stage::Coverage);
        return Some(covering);
    }
    stats.dropped += 1;
    None
}

/// The surfaces front to back (`query`'s grouping on the leaves' representatives).
fn group(fused: &Fused, at: LensTime, scratch: &mut FusedScratch) {
    let scene = fused.scene;
    let window = corners(at, scene.delta);
    scratch.surfaces.clear();
    scratch.traces.clear();
    let mut surface_start = 0;
    for position in 0..scratch.contributing.len() {
        let Contribution { leaf, found, .. } = scratch.contributing[position];
        let static_entry = fused.entries.static_leaf[leaf as usize];
        let traced = fused.entries.trace(found.first as usize, &window, static_entry, scene.lens, scene.z_near);
        let seen_throughout = traced.is_some();
        let trace = traced.unwrap_or_default();
        let same = seen_throughout && scratch.traces.iter().all(|other| !crosses(&trace, other, CROSSING_TOLERANCE_PX));
        if !same && position > surface_start {
            scratch.surfaces.push((surface_start, position));
            surface_start = position;
            scratch.traces.clear();
        }
        if seen_throughout {
            scratch.traces.push(trace);
        } else {
            scratch.surfaces.push((surface_start, position + 1));
            surface_start = position + 1;
            scratch.traces.clear();
        }
    }
    if scratch.contributing.len() > surface_start {
        scratch.surfaces.push((surface_start, scratch.contributing.len()));
    }
}

/// Whether two traces at the window's corners cross (Eq. 5 fails): on either axis, one
/// difference at least `tolerance` and another at most −`tolerance` (`same_surface::consistent`
/// without the iterator: a difference counts as negative also when it is NaN, as there).
#[inline]
pub fn crosses(a: &[[f32; 2]; 4], b: &[[f32; 2]; 4], tolerance: f32) -> bool {
    let mut crossing = false;
    for axis in 0..2 {
        let (mut positive, mut negative) = (false, false);
        for k in 0..4 {
            let d = a[k][axis] - b[k][axis];
            positive |= d >= tolerance;
            negative |= (d <= -tolerance) | d.is_nan();
        }
        crossing |= positive & negative;
    }
    crossing
}

/// The covering surface's sums over the leaves `range`: counts added, the tent's lanes added
/// leaf by leaf and reduced in f64, the nearest entry from the full pass when `nearest` asks
/// for it or no entry lies within R.
fn sum_range(
    fused: &Fused,
    range: &[Contribution],
    tents: &[TentLanes],
    p: &Probe,
    lit: Option<&LitTest>,
    nearest: bool,
) -> Covering {
    let mut lanes = [[0.0f32; LANES]; 4];
    let (mut count, mut lit_count) = (0, 0);
    for c in range {
        count += c.found.count;
        lit_count += c.found.lit;
        let tent = &tents[c.slot as usize];
        for (sum, leaf) in lanes.iter_mut().zip(tent) {
            for k in 0..LANES {
                sum[k] += leaf[k];
            }
        }
    }
    let reduce = |lane: &[f32; LANES]| lane.iter().fold(0.0f64, |s, &v| s + v as f64);
    let weight = reduce(&lanes[0]);
    let weighted = [reduce(&lanes[1]), reduce(&lanes[2]), reduce(&lanes[3])];
    let nearest = (nearest || weight <= 0.0).then(|| {
        let sums = full_sums(fused.entries, fused.scene.hierarchy, range, p, lit);
        (sums.nearest, sums.nearest_entry)
    });
    Covering { radius: p.radius, count, lit: lit_count, weight, weighted, nearest }
}

/// The range of `scratch.contributing` of the covering surface (`query`'s `choose_surface`):
/// small surfaces merge into the next; a surface before the last is taken when the quadrant
/// early-out (from the full pass over its leaves) or the valid-triangle search on its points
/// finds it covering, or on the light side at a blocker's rim; the last surface is taken as it
/// is.
fn choose(
    fused: &Fused,
    p: &Probe,
    lit: Option<&LitTest>,
    blocks: Option<&dyn Fn(u32) -> bool>,
    scratch: &mut FusedScratch,
    stats: &mut QueryStats,
) -> (usize, usize) {
    let (entries, tree) = (fused.entries, fused.scene.hierarchy);
    let surfaces = &scratch.surfaces;
    let contributing = &scratch.contributing;
    let location = [p.x, p.y];
    let mut start = surfaces[0].0;
    for (k, &(_, end)) in surfaces.iter().enumerate() {
        if k + 1 == surfaces.len() {
            return (start, end);
        }
        let count: u32 = contributing[start..end].iter().map(|c| c.found.count).sum();
        if (count as usize) < MIN_SURFACE_SAMPLES {
            continue;
        }
        let front = full_sums(entries, tree, &contributing[start..end], p, lit);
        if front.quadrants == 0b1111 {
            stats.coverage.quadrant_accepts += 1;
            return (start, end);
        }
        gather_points(fused, &contributing[start..end], p, &mut scratch.points);
        if is_covered(&scratch.points, location, p.radius, MAX_TRIANGLE_CANDIDATES, &mut stats.coverage) {
            return (start, end);
        }
        if let Some(blocks) = blocks {
            if blocks(contributing[start].found.first) {
                let behind = full_sums(entries, tree, &contributing[end..], p, lit);
                let front_set = (front.nearest, front.count as usize);
                if takes_rim_distances(front_set, (behind.nearest, behind.count as usize)) {
                    return (start, end);
                }
            }
        }
        start = end;
    }
    unreachable!("the last surface is always returned")
}

/// The reprojected positions of the entries within reach of the leaves of `range`, in order.
fn gather_points(fused: &Fused, range: &[Contribution], p: &Probe, out: &mut Vec<Point>) {
    let scene = fused.scene;
    out.clear();
    for c in range {
        for i in scene.hierarchy.node(c.leaf).samples() {
            if !fused.entries.takes(i, p.at.t) {
                continue;
            }
            let Some(q) = fused.entries.position(i, p.at, scene.lens, scene.z_near) else {
                continue;
            };
            let (dx, dy) = (q[0] - p.x, q[1] - p.y);
            if dx * dx + dy * dy <= p.reach_squared {
                out.push([q[0], q[1]]);
            }
        }
    }
}

#[cfg(test)]
mod tests;
