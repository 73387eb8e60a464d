//! Bounding planes of reprojected samples (paper Section 4 "Node bounds", Eq. 6, and
//! Appendix A; design `docs/tlfr-design.md` §2 "Bounds (App. A)"): for a sample, or a node of
//! the hierarchy, four planes
//!
//! ```text
//! Xmin(t, u) = A₁·t + B₁·u + D₁  ≤  x'(u, t)  ≤  A₂·t + B₂·u + D₂ = Xmax(t, u)
//! Ymin(t, v) = …                 ≤  y'(v, t)  ≤  …               = Ymax(t, v)
//! ```
//!
//! valid for every lens coordinate |u|, |v| ≤ 1 and every time t of the time span, outside of
//! which no sample of the node can be seen or come near the image. (x' depends on (u, t) only
//! and y' on (v, t) only: defocus is separable, paper footnote 5.)
//!
//! One sample (in f64, rounded outwards to f32 at the end):
//! 1. the time span: the times in [0, 1] where its depth is at least the near limit
//!    (`valid_span`, exactly the times where `reprojection::reproject` is `Some`);
//! 2. trimmed to "potentially on screen": the lens-centre position
//!    x(t) = (x̄z + (t − tᵢ)·m_x) / z'(t) is a ratio of linear functions whose denominator keeps
//!    its sign on the span, hence monotone, so the times where it lies in
//!    [−margin, W + margin] form an interval, found in closed form (likewise y). The margin is
//!    the largest |C| on the span plus the largest query reach (16R after three widenings):
//!    beyond it the sample cannot come within reach of any location of the image;
//! 3. x(t) is convex or concave on the span (x'' has the sign of −m_z·(m_x·z'(t) − x·z'(t)·m_z),
//!    a constant), so the tangent at the span's midpoint bounds it on one side and the chord
//!    between the span's ends on the other;
//! 4. the lens term û·C(z'(t)): C is monotone in t on the span, so with C₀, C₁ its values at
//!    the span's ends, û·C = û·B + û·(C − B) with B = (C₀ + C₁)/2 and |C − B| ≤ H = |C₁ − C₀|/2:
//!    slope B in u and the constants widened by H bound it exactly for all |û| ≤ 1.
//!
//! The planes are widened by a bound on the rounding error of the f32 reprojection the queries
//! use, and their f32 coefficients are chosen so that evaluating them in f32 stays on the safe
//! side of the f64 plane.
//!
//! Merging two bounds (Appendix A): the time span is the union; each plane is a least-squares
//! fit to the children's planes at the four corners of the union's (t, u) rectangle (each child's
//! plane read at its own span's nearest time), then shifted until it bounds both children's
//! planes at the corners of the children's own rectangles — the difference of two planes is
//! linear, so that bounds them everywhere on those rectangles. (The paper fits at the union's
//! corners only; reading each child on its own span keeps a short-lived child's steep plane
//! from being extrapolated over the whole shutter.)

use super::lens::LensModel;
use super::reprojection::{depth_at, LensTime, LensTimeSample};

/// `time·t + lens·w + constant`, w the lens coordinate of the plane's axis (u for x, v for y).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Plane {
    pub time: f32,
    pub lens: f32,
    pub constant: f32,
}

impl Plane {
    /// The plane's value in f32, as queries evaluate it.
    #[inline]
    pub fn at(&self, t: f32, lens: f32) -> f32 {
        self.time * t + self.lens * lens + self.constant
    }

    /// The plane's value in f64.
    fn at_f64(&self, t: f64, lens: f64) -> f64 {
        self.time as f64 * t + self.lens as f64 * lens + self.constant as f64
    }
}

/// Bounds of one sample or of a node's samples.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Bounds {
    pub x_min: Plane,
    pub x_max: Plane,
    pub y_min: Plane,
    pub y_max: Plane,
    /// The times [t0, t1] outside of which none of the samples can be seen near the image.
    pub span: [f32; 2],
}

/// The region a sample must be able to come near to matter: the image and the largest reach
/// of a query around a location.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScreenArea {
    pub width: f32,
    pub height: f32,
    /// The largest distance (pixels) from a location at which a query looks for samples.
    pub max_reach: f32,
}

/// A box of locations: screen x̂ and ŷ, lens û and v̂, time t̂, each a closed interval
/// [low, high] (a pixel's locations over the whole lens and shutter, for one walk per pixel).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Window {
    pub x: [f32; 2],
    pub y: [f32; 2],
    pub u: [f32; 2],
    pub v: [f32; 2],
    pub t: [f32; 2],
}

/// The unit roundoff of f32.
const F32_EPSILON: f64 = f32::EPSILON as f64 * 0.5;

/// The times in [0, 1] at which the sample's depth (Eq. 2, in f32 as `reprojection::depth_at`
/// computes it) is at least `z_near`; `None` if there are none. Exactly the times at which
/// `reprojection::reproject` gives a position: the depth is monotone in t also after rounding,
/// and the ends are moved to the last representable time on either side.
pub fn valid_span(sample: &LensTimeSample, z_near: f32) -> Option<(f32, f32)> {
    if sample.z.is_infinite() || sample.motion[2] == 0.0 {
        return (sample.z >= z_near).then_some((0.0, 1.0));
    }
    let valid = |t: f32| depth_at(sample, t) >= z_near;
    // z + (t − tᵢ)·m_z ≥ z_near ⇔ t ≥ t* (m_z > 0) or t ≤ t* (m_z < 0).
    let crossing = sample.t + (z_near - sample.z) / sample.motion[2];
    if sample.motion[2] > 0.0 {
        let mut lo = crossing.clamp(0.0, 1.0);
        while lo > 0.0 && valid(step_down(lo)) {
            lo = step_down(lo);
        }
        while lo <= 1.0 && !valid(lo) {
            lo = step_up(lo);
        }
        (lo <= 1.0).then_some((lo, 1.0))
    } else {
        let mut hi = crossing.clamp(0.0, 1.0);
        while hi < 1.0 && valid(step_up(hi)) {
            hi = step_up(hi);
        }
        while hi >= 0.0 && !valid(hi) {
            hi = step_down(hi);
        }
        (hi >= 0.0).then_some((0.0, hi))
    }
}

/// The next f32 above `x`.
fn step_up(x: f32) -> f32 {
    if x.is_nan() || x == f32::INFINITY {
        x
    } else if x == 0.0 {
        f32::from_bits(1)
    } else if x > 0.0 {
        f32::from_bits(x.to_bits() + 1)
    } else {
        f32::from_bits(x.to_bits() - 1)
    }
}

/// The next f32 below `x`.
fn step_down(x: f32) -> f32 {
    -step_up(-x)
}

/// The largest f32 ≤ `x`.
fn f32_below(x: f64) -> f32 {
    let r = x as f32;
    if r as f64 > x {
        step_down(r)
    } else {
        r
    }
}

/// The smallest f32 ≥ `x`.
fn f32_above(x: f64) -> f32 {
    let r = x as f32;
    if (r as f64) < x {
        step_up(r)
    } else {
        r
    }
}

/// An f64 plane (time, lens, constant) as an f32 plane that, evaluated in f32 for t ∈ [0, 1]
/// and |w| ≤ 1, is never above (`upper` false) or below (`upper` true) the f64 plane.
fn round_plane(time: f64, lens: f64, constant: f64, upper: bool) -> Plane {
    let (time32, lens32) = (time as f32, lens as f32);
    // The coefficients' rounding, and f32 evaluation: three roundings of terms at most
    // |time| + |lens| + |constant|.
    let error = (time - time32 as f64).abs()
        + (lens - lens32 as f64).abs()
        + 4.0 * F32_EPSILON * (time.abs() + lens.abs() + constant.abs());
    let constant32 = if upper { f32_above(constant + error) } else { f32_below(constant - error) };
    Plane { time: time32, lens: lens32, constant: constant32 }
}

/// One axis of a sample in homogeneous form: position·depth = `p + t·q`, depth = `pw + t·qw`.
#[derive(Clone, Copy)]
struct Axis {
    p: f64,
    q: f64,
}

/// The lens-centre position on one axis at t.
fn centre(axis: Axis, depth: Axis, t: f64) -> f64 {
    (axis.p + t * axis.q) / (depth.p + t * depth.q)
}

/// The sub-interval of [t0, t1] where the monotone centre position lies in [lo, hi]; `None`
/// if it stays outside.
fn trim(axis: Axis, depth: Axis, (t0, t1): (f64, f64), (lo, hi): (f64, f64)) -> Option<(f64, f64)> {
    let (f0, f1) = (centre(axis, depth, t0), centre(axis, depth, t1));
    if f0.max(f1) < lo || f0.min(f1) > hi {
        return None;
    }
    // position = c ⇔ p + t·q = c·(pw + t·qw).
    let solve = |c: f64, fallback: f64| {
        let t = (c * depth.p - axis.p) / (axis.q - c * depth.q);
        if t.is_finite() {
            t.clamp(t0, t1)
        } else {
            fallback
        }
    };
    let (mut a, mut b) = (t0, t1);
    if f1 >= f0 {
        if f0 < lo {
            a = solve(lo, t0);
        }
        if f1 > hi {
            b = solve(hi, t1);
        }
    } else {
        if f0 > hi {
            a = solve(hi, t0);
        }
        if f1 < lo {
            b = solve(lo, t1);
        }
    }
    Some((a.min(b), b.max(a)))
}

/// Lines (time, constant) below and above the centre position on [t0, t1]: tangent at the
/// midpoint and chord, by the sign of the (constant-signed) curvature; checked at five times
/// and widened if rounding made the curvature's sign wrong.
fn lines(axis: Axis, depth: Axis, (t0, t1): (f64, f64)) -> ((f64, f64), (f64, f64)) {
    let f = |t: f64| centre(axis, depth, t);
    let mid = 0.5 * (t0 + t1);
    let w = depth.p + mid * depth.q;
    let determinant = axis.q * depth.p - axis.p * depth.q;
    let slope = determinant / (w * w);
    let tangent = (slope, f(mid) - slope * mid);
    let chord = if t1 > t0 {
        let s = (f(t1) - f(t0)) / (t1 - t0);
        (s, f(t0) - s * t0)
    } else {
        (0.0, f(t0))
    };
    // x'' = −2·q_w·determinant / w³ with w > 0.
    let convex = -depth.q * determinant >= 0.0;
    let (mut lower, mut upper) = if convex { (tangent, chord) } else { (chord, tangent) };
    for k in 0..=4 {
        let t = t0 + (t1 - t0) * k as f64 / 4.0;
        let value = f(t);
        lower.1 -= (lower.0 * t + lower.1 - value).max(0.0) * 2.0;
        upper.1 += (value - upper.0 * t - upper.1).max(0.0) * 2.0;
    }
    (lower, upper)
}

/// The largest number of time segments a sample is split into (`sample_segments`).
pub const MAX_SEGMENTS: usize = 8;
/// A sample's time span is split while a segment's bounds are thicker than this (pixels): the
/// largest distance between its lower and upper plane at one lens position.
pub const MAX_SEGMENT_THICKNESS_PX: f32 = 2.0;
/// Segments are cut where the depth crosses 2^(k/`DEPTH_STEPS_PER_OCTAVE`) for an integer k.
pub const DEPTH_STEPS_PER_OCTAVE: u32 = 2;

/// One entry of a sample in the hierarchy: bounds over part of its time span, and the times
/// `times[0] ≤ t̂ < times[1]` at which a query takes the sample from this entry. The times of a
/// sample's entries are consecutive pieces of one partition of the real line (the first
/// starts at −∞, the last ends at +∞; a piece whose sample cannot come near the image has no
/// entry), so a query time falls in at most one entry of each sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Segment {
    pub bounds: Bounds,
    pub times: [f32; 2],
}

/// A sample prepared for bounds: fixed bounds (a miss, or a sample whose position f32 rounding
/// dominates), or a trajectory with its valid span.
enum Prepared {
    Fixed(Bounds),
    Moving(Trajectory, [f32; 2]),
}

/// One moving sample in f64: the homogeneous form of its lens-centre position and depth.
struct Trajectory {
    depth: Axis,
    axis_x: Axis,
    axis_y: Axis,
    c1: f64,
    c2: f64,
    /// Depth, time, and |Δz| at the sample's own time; x̄, ȳ; screen motion; the sample's
    /// own (u, v) times C(z), for the rounding bound.
    z: f64,
    ts: f64,
    dz: f64,
    bar: [f64; 2],
    motion: [f64; 2],
    own_lens_term: [f64; 2],
}

impl Trajectory {
    fn depth_at(&self, t: f64) -> f64 {
        self.depth.p + t * self.depth.q
    }

    fn coc(&self, depth: f64) -> f64 {
        self.c1 / depth + self.c2
    }

    /// Step 2 of the module comment on [t0, t1]: the times where the sample can come near the
    /// image, rounded outwards in f32 but within [t0, t1]; the margin is the largest |C| on
    /// [t0, t1] plus the largest reach.
    fn trim(&self, [t0, t1]: [f32; 2], area: &ScreenArea) -> Option<[f32; 2]> {
        let (a, b) = (t0 as f64, t1 as f64);
        let largest_coc = self.coc(self.depth_at(a)).abs().max(self.coc(self.depth_at(b)).abs());
        let margin = largest_coc + area.max_reach as f64;
        let (a, b) = trim(self.axis_x, self.depth, (a, b), (-margin, area.width as f64 + margin))?;
        let (a, b) = trim(self.axis_y, self.depth, (a, b), (-margin, area.height as f64 + margin))?;
        Some([f32_below(a).max(t0), f32_above(b).min(t1)])
    }

    /// Steps 3–4 and the rounding bound over `span` (within the valid span).
    fn bounds(&self, span: [f32; 2]) -> Bounds {
        let (t0, t1) = (span[0] as f64, span[1] as f64);
        let (coc0, coc1) = (self.coc(self.depth_at(t0)), self.coc(self.depth_at(t1)));
        let (lens_slope, lens_half) = (0.5 * (coc0 + coc1), 0.5 * (coc1 - coc0).abs());
        // Rounding of the f32 reprojection: relative errors of a few units in the magnitudes it
        // adds, amplified by the division by the depth (itself rounded) where the depth is small.
        let nearest = self.depth_at(t0).min(self.depth_at(t1));
        let amplification = 1.0 + (self.z + self.dz.abs()) / nearest;
        let slack = |k: usize| {
            let (bar, motion) = (self.bar[k], self.motion[k]);
            let magnitude = (bar.abs() * self.z + motion.abs() + self.ts * motion.abs()) / nearest
                + (self.c1.abs() / nearest + self.c2.abs())
                + bar.abs()
                + self.own_lens_term[k].abs();
            16.0 * F32_EPSILON * magnitude * amplification + 1e-6
        };
        let planes = |axis: Axis, k: usize| {
            let (lower, upper) = lines(axis, self.depth, (t0, t1));
            let s = slack(k) + lens_half;
            (round_plane(lower.0, lens_slope, lower.1 - s, false), round_plane(upper.0, lens_slope, upper.1 + s, true))
        };
        let (x_min, x_max) = planes(self.axis_x, 0);
        let (y_min, y_max) = planes(self.axis_y, 1);
        Bounds { x_min, x_max, y_min, y_max, span }
    }

    /// Candidate times to cut [t0, t1] at, strictly inside it in f32: where z' crosses a
    /// depth of the global grid 2^(k/`DEPTH_STEPS_PER_OCTAVE`) nearest the geometric mean of
    /// its depths at the ends (so that samples of one surface, whose depths move together, are
    /// cut at the same times and their segments share leaves); `None` without depth motion or
    /// where no grid depth lies strictly inside.
    fn split_times(&self, [t0, t1]: [f32; 2]) -> [Option<f32>; 1] {
        if self.depth.q == 0.0 {
            return [None];
        }
        let (za, zb) = (self.depth_at(t0 as f64), self.depth_at(t1 as f64));
        let steps = DEPTH_STEPS_PER_OCTAVE as f64;
        let level = |z: f64| z.log2() * steps;
        let (la, lb) = (level(za).min(level(zb)), level(za).max(level(zb)));
        let at_level = |k: f64| ((k / steps).exp2() - self.depth.p) / self.depth.q;
        let inside = |t: f64| {
            let t = t as f32;
            (t > t0 && t < t1).then_some(t)
        };
        // The grid levels strictly between the ends, nearest the middle first.
        let middle = 0.5 * (la + lb);
        let (low, high) = (la.floor() + 1.0, lb.ceil() - 1.0);
        if low > high {
            return [None];
        }
        let k = middle.round().clamp(low, high);
        [inside(at_level(k))]
    }
}

/// The work a segment's bounds cost the queries, up to a constant: its duration times the
/// image area (with the largest reach around it) that its bounds cover at one lens position.
fn segment_work(bounds: &Bounds, area: &ScreenArea) -> f64 {
    let reach = 2.0 * area.max_reach as f64;
    let [x, y] = bounds.thickness();
    let duration = (bounds.span[1] - bounds.span[0]) as f64;
    duration * (x + reach).min(area.width as f64 + reach) * (y + reach).min(area.height as f64 + reach)
}

/// Step 1 for one sample: `None` when it is never in front of the camera.
fn prepare(sample: &LensTimeSample, lens: &LensModel, z_near: f32, area: &ScreenArea) -> Option<Prepared> {
    let (t0, t1) = valid_span(sample, z_near)?;
    let (c1, c2) = (lens.c1 as f64, lens.c2 as f64);
    let (width, height, reach) = (area.width as f64, area.height as f64, area.max_reach as f64);
    let (x, y, u, v) = (sample.x as f64, sample.y as f64, sample.u as f64, sample.v as f64);
    if sample.z.is_infinite() {
        // A miss: x' = x − u·c2 + û·c2 at every time.
        let (xc, yc) = (x - u * c2, y - v * c2);
        let margin = c2.abs() + reach;
        if !(-margin..=width + margin).contains(&xc) || !(-margin..=height + margin).contains(&yc) {
            return None;
        }
        let slack = 4.0 * F32_EPSILON * (x.abs() + y.abs() + 2.0 * c2.abs()) + 1e-6;
        return Some(Prepared::Fixed(Bounds {
            x_min: round_plane(0.0, c2, xc - slack, false),
            x_max: round_plane(0.0, c2, xc + slack, true),
            y_min: round_plane(0.0, c2, yc - slack, false),
            y_max: round_plane(0.0, c2, yc + slack, true),
            span: [0.0, 1.0],
        }));
    }
    let z = sample.z as f64;
    let coc = |depth: f64| c1 / depth + c2;
    let c_old = coc(z);
    let (x_bar, y_bar) = (x - u * c_old, y - v * c_old);
    let (dx, dy, dz) = (sample.motion[0] as f64, sample.motion[1] as f64, sample.motion[2] as f64);
    let m = [lens.fx as f64 * dx + lens.cx as f64 * dz, lens.fy as f64 * dy + lens.cy as f64 * dz, dz];
    let ts = sample.t as f64;
    // Homogeneous position at t: (x̄·z + (t − tᵢ)·m) / (z + (t − tᵢ)·m_z).
    let trajectory = Trajectory {
        depth: Axis { p: z - ts * m[2], q: m[2] },
        axis_x: Axis { p: x_bar * z - ts * m[0], q: m[0] },
        axis_y: Axis { p: y_bar * z - ts * m[1], q: m[1] },
        c1,
        c2,
        z,
        ts,
        dz,
        bar: [x_bar, y_bar],
        motion: [m[0], m[1]],
        own_lens_term: [c_old * u, c_old * v],
    };
    if trajectory.depth_at(t0 as f64).min(trajectory.depth_at(t1 as f64)) < 0.5 * z_near as f64 {
        // The f32 depth passes the near limit where the exact one is (almost) zero: f32
        // rounding dominates the position there. Bound it by everything.
        return Some(Prepared::Fixed(Bounds::everywhere([t0, t1])));
    }
    Some(Prepared::Moving(trajectory, [t0, t1]))
}

/// The bounds of one sample over its whole (trimmed) span, for lens model `lens`, near limit
/// `z_near` and the image area `area`; `None` when it is never in front of the camera while
/// potentially near the image.
pub fn sample_bounds(sample: &LensTimeSample, lens: &LensModel, z_near: f32, area: &ScreenArea) -> Option<Bounds> {
    match prepare(sample, lens, z_near, area)? {
        Prepared::Fixed(bounds) => Some(bounds),
        Prepared::Moving(trajectory, valid) => Some(trajectory.bounds(trajectory.trim(valid, area)?)),
    }
}

/// A sample's entries for the hierarchy: its valid span cut into time segments, each trimmed
/// and bounded on its own (steps 2–4 on the segment). A plane linear in t bounds x ∝ 1/z'(t)
/// loosely where z' nears zero, and the lens term's spread |C₁ − C₀|/2 grows like 1/z' there;
/// so while some segment's bounds are thicker than `MAX_SEGMENT_THICKNESS_PX`
/// (`Bounds::thickness`), and at most into `MAX_SEGMENTS`, the thick segment costing the
/// queries the most (`segment_work`) is cut, at the candidate time (`Trajectory::split_times`)
/// that leaves the least work. Pieces trimmed away entirely have no entry. A sample with a
/// single entry (no depth motion, a miss, or one piece near the image) has the times (−∞, +∞).
/// Empty when the sample is never in front of the camera near the image.
pub fn sample_segments(sample: &LensTimeSample, lens: &LensModel, z_near: f32, area: &ScreenArea) -> Vec<Segment> {
    let whole = [f32::NEG_INFINITY, f32::INFINITY];
    let (trajectory, valid) = match prepare(sample, lens, z_near, area) {
        None => return Vec::new(),
        Some(Prepared::Fixed(bounds)) => return vec![Segment { bounds, times: whole }],
        Some(Prepared::Moving(trajectory, valid)) => (trajectory, valid),
    };
    // (piece of the valid span, its trimmed bounds, whether it may still be split)
    let piece = |span: [f32; 2]| (span, trajectory.trim(span, area).map(|s| trajectory.bounds(s)), true);
    let mut pieces = vec![piece(valid)];
    while pieces.len() < MAX_SEGMENTS {
        let thick = |(_, bounds, splittable): &([f32; 2], Option<Bounds>, bool)| {
            let bounds = bounds.as_ref().filter(|_| *splittable)?;
            let [x, y] = bounds.thickness();
            (x.max(y) > MAX_SEGMENT_THICKNESS_PX as f64).then(|| segment_work(bounds, area))
        };
        // The first of the largest, so that ties go the same way every time.
        let chosen = pieces.iter().enumerate().filter_map(|(k, p)| thick(p).map(|w| (k, w))).fold(
            None,
            |best: Option<(usize, f64)>, (k, w)| if best.is_some_and(|(_, b)| b >= w) { best } else { Some((k, w)) },
        );
        let Some((k, _)) = chosen else {
            break;
        };
        let (span, bounds, _) = pieces[k];
        let trimmed = bounds.expect("only bounded pieces are chosen").span;
        // The cut of the candidates (`Trajectory::split_times`) that leaves the least work.
        let work = |p: &([f32; 2], Option<Bounds>, bool)| p.1.as_ref().map_or(0.0, |b| segment_work(b, area));
        let best = trajectory
            .split_times(trimmed)
            .into_iter()
            .flatten()
            .map(|t| {
                let (left, right) = (piece([span[0], t]), piece([t, span[1]]));
                (work(&left) + work(&right), left, right)
            })
            .fold(
                None,
                |best: Option<(f64, _, _)>, candidate| {
                    if best.as_ref().is_some_and(|b| b.0 <= candidate.0) {
                        best
                    } else {
                        Some(candidate)
                    }
                },
            );
        match best {
            Some((_, left, right)) => {
                pieces[k] = left;
                pieces.insert(k + 1, right);
            }
            None => pieces[k].2 = false,
        }
    }
    let last = pieces.len() - 1;
    let mut segments: Vec<Segment> = pieces
        .iter()
        .enumerate()
        .filter_map(|(k, (span, bounds, _))| {
            let start = if k == 0 { f32::NEG_INFINITY } else { span[0] };
            let end = if k == last { f32::INFINITY } else { span[1] };
            bounds.map(|bounds| Segment { bounds, times: [start, end] })
        })
        .collect();
    if let [only] = segments.as_mut_slice() {
        // The other pieces are never near the image: one entry for all times.
        only.times = whole;
    }
    segments
}

impl Bounds {
    /// Bounds that contain every position a query can ask about, over `span`.
    pub fn everywhere(span: [f32; 2]) -> Bounds {
        let (low, high) = (Plane { constant: -1e12, ..Plane::default() }, Plane { constant: 1e12, ..Plane::default() });
        Bounds { x_min: low, x_max: high, y_min: low, y_max: high, span }
    }

    /// Whether (x̂, ŷ) lies within `reach` pixels (per axis) of the bounds at `at`, with t̂ in
    /// the span: then a sample of the node may reproject within `reach` of it.
    #[inline]
    pub fn near(&self, location: [f32; 2], at: LensTime, reach: f32) -> bool {
        at.t >= self.span[0]
            && at.t <= self.span[1]
            && location[0] >= self.x_min.at(at.t, at.u) - reach
            && location[0] <= self.x_max.at(at.t, at.u) + reach
            && location[1] >= self.y_min.at(at.t, at.v) - reach
            && location[1] <= self.y_max.at(at.t, at.v) + reach
    }

    /// Whether `near(location, at, reach)` can hold for some location of `window`: each side of
    /// the test compared at the window's corner most in its favour. f32 products and sums are
    /// monotone in each operand, so a plane evaluated in f32 at that corner bounds its f32 value
    /// anywhere in the window, and the test is conservative bit for bit.
    #[inline]
    pub fn may_be_near(&self, window: &Window, reach: f32) -> bool {
        let lowest = |plane: &Plane, lens: [f32; 2]| {
            let t = if plane.time >= 0.0 { window.t[0] } else { window.t[1] };
            let w = if plane.lens >= 0.0 { lens[0] } else { lens[1] };
            plane.at(t, w)
        };
        let highest = |plane: &Plane, lens: [f32; 2]| {
            let t = if plane.time >= 0.0 { window.t[1] } else { window.t[0] };
            let w = if plane.lens >= 0.0 { lens[1] } else { lens[0] };
            plane.at(t, w)
        };
        window.t[1] >= self.span[0]
            && window.t[0] <= self.span[1]
            && window.x[1] >= lowest(&self.x_min, window.u) - reach
            && window.x[0] <= highest(&self.x_max, window.u) + reach
            && window.y[1] >= lowest(&self.y_min, window.v) - reach
            && window.y[0] <= highest(&self.y_max, window.v) + reach
    }

    /// Bounds of the union of two nodes' samples (Appendix A; see the module comment).
    pub fn merge(&self, other: &Bounds) -> Bounds {
        merge_children(&[self, other])
    }

    /// Bounds of the union of several nodes' (or samples') bounds; the default bounds for none.
    pub fn merge_all<'a>(items: impl IntoIterator<Item = &'a Bounds>) -> Bounds {
        let items: Vec<&Bounds> = items.into_iter().collect();
        match items.len() {
            0 => Bounds::default(),
            1 => *items[0],
            _ => merge_children(&items),
        }
    }

    /// The largest distance between the lower and the upper plane of each axis at one lens
    /// position, over the span and |u|, |v| ≤ 1: [x, y], pixels. Zero for the exact bounds of a
    /// sample whose position is linear in t; what splitting a span in time can reduce.
    pub fn thickness(&self) -> [f64; 2] {
        let gap = |low: &Plane, high: &Plane| {
            let mut largest = f64::NEG_INFINITY;
            for t in self.span {
                for w in [-1.0, 1.0] {
                    largest = largest.max(high.at_f64(t as f64, w) - low.at_f64(t as f64, w));
                }
            }
            largest.max(0.0)
        };
        [gap(&self.x_min, &self.x_max), gap(&self.y_min, &self.y_max)]
    }

    /// The extents of the bounds over their span and |u|, |v| ≤ 1: (width, height), pixels.
    pub fn extent(&self) -> (f32, f32) {
        let [x0, x1, y0, y1] = self.extent_box();
        ((x1 - x0).max(0.0) as f32, (y1 - y0).max(0.0) as f32)
    }

    /// The box [x_lo, x_hi, y_lo, y_hi] the planes span over the time span and the whole lens.
    pub fn extent_box(&self) -> [f64; 4] {
        let corners = |plane: &Plane, upper: bool| {
            let values = [
                plane.at_f64(self.span[0] as f64, -1.0),
                plane.at_f64(self.span[0] as f64, 1.0),
                plane.at_f64(self.span[1] as f64, -1.0),
                plane.at_f64(self.span[1] as f64, 1.0),
            ];
            if upper {
                values.into_iter().fold(f64::NEG_INFINITY, f64::max)
            } else {
                values.into_iter().fold(f64::INFINITY, f64::min)
            }
        };
        [
            corners(&self.x_min, false),
            corners(&self.x_max, true),
            corners(&self.y_min, false),
            corners(&self.y_max, true),
        ]
    }
}

/// The bounds of several children.
fn merge_children(children: &[&Bounds]) -> Bounds {
    let span =
        children.iter().fold([f32::INFINITY, f32::NEG_INFINITY], |s, c| [s[0].min(c.span[0]), s[1].max(c.span[1])]);
    let pick = |b: &Bounds, k: usize| [b.x_min, b.x_max, b.y_min, b.y_max][k];
    let mut planes = [Plane::default(); 4];
    for (k, plane) in planes.iter_mut().enumerate() {
        *plane = merge_planes(children.iter().map(|c| (pick(c, k), c.span)), span, k % 2 == 1);
    }
    let [x_min, x_max, y_min, y_max] = planes;
    Bounds { x_min, x_max, y_min, y_max, span }
}

/// A plane above (`upper`) or below planes, each on its own span, over `span`.
fn merge_planes(children: impl Iterator<Item = (Plane, [f32; 2])> + Clone, span: [f32; 2], upper: bool) -> Plane {
    let (t0, t1) = (span[0] as f64, span[1] as f64);
    let outer = |p: f64, q: f64| if upper { p.max(q) } else { p.min(q) };
    let start = if upper { f64::NEG_INFINITY } else { f64::INFINITY };
    // Each child read at its own span's nearest time.
    let value = |t: f64, w: f64| {
        children
            .clone()
            .fold(start, |acc, (plane, own)| outer(acc, plane.at_f64(t.clamp(own[0] as f64, own[1] as f64), w)))
    };
    // Least squares over the 2 × 2 corners: the main effects.
    let (v00, v01, v10, v11) = (value(t0, -1.0), value(t0, 1.0), value(t1, -1.0), value(t1, 1.0));
    let lens = 0.25 * ((v01 - v00) + (v11 - v10));
    let time = if t1 > t0 { 0.5 * ((v10 - v00) + (v11 - v01)) / (t1 - t0) } else { 0.0 };
    let mean = 0.25 * (v00 + v01 + v10 + v11);
    let mut constant = mean - time * 0.5 * (t0 + t1);
    // Shift until it bounds every child at its own corners.
    let mut shift = 0.0f64;
    for (plane, own) in children {
        for t in [own[0] as f64, own[1] as f64] {
            for w in [-1.0, 1.0] {
                let gap = plane.at_f64(t, w) - (time * t + lens * w + constant);
                shift = if upper { shift.max(gap) } else { shift.min(gap) };
            }
        }
    }
    constant += shift;
    round_plane(time, lens, constant, upper)
}

#[cfg(test)]
mod tests;
