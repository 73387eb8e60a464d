//! A splat as an oriented disc, paper Section 2.3 (design: docs/ilfr-design.md §2 "Splat").
//!
//! Paper → code:
//! - "we treat the input samples as circular disks (splats) in 3D on their individual tangent
//!   planes" (§2.2): [`Disc`] — centre h_i, unit normal n_i, radius r_i.
//! - "intersecting the reconstruction ray with the splats" (§2.3): [`intersect`] — the ray's
//!   point on the tangent plane, t_i = n_i·(h_i − p) / (n_i·d), and its distance from the centre,
//!   s_i = |p + t_i d − h_i|; a hit iff |n_i·d| > [`GRAZING_COSINE`], t_min < t_i < t_max and
//!   s_i < r_i. Along with it, what a reconstruction needs about a hit ([`DiscHit`]): the depth of
//!   the centre along the ray z_i = d·(h_i − p) (the sort key of §2.3.2), s_i (the tent of §2.4,
//!   the shrunk radius of §2.3.1) and whether the splat faces away from the ray (§2.5).
//! - The bounding box of a disc for the hierarchy (§2.3): [`Disc::bounds`], exact half-extent
//!   r·sqrt(1 − n_a²) along each axis a.
//!
//! Stiff input stays finite: a zero radius never hits (s < 0 is false), a grazing ray
//! (|n·d| ≤ 1e-7) never hits, so t is bounded by |h − p| / 1e-7, and every comparison is written
//! so that a NaN fails it.

use crate::vector::{dot, length, sub};

/// Rays closer to the tangent plane than this (|n·d|, the cosine between the ray and the plane's
/// normal) do not hit the disc: the plane intersection would be ill-conditioned.
pub const GRAZING_COSINE: f32 = 1e-7;

/// A ray p + t·d with a unit direction d, at a time in [0, 1] over the shutter (only moving
/// discs look at it; 0 where nothing moves).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub time: f32,
    pub origin: [f32; 3],
    pub direction: [f32; 3],
}

/// An oriented disc: a splat on the tangent plane of its secondary hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Disc {
    /// h_i, the secondary hit.
    pub centre: [f32; 3],
    /// n_i, unit.
    pub normal: [f32; 3],
    /// r_i ≥ 0 (0: a dead splat, never hit).
    pub radius: f32,
    /// Displacement over the shutter (zero for a static splat); `centre` is the position at
    /// time 0.5 (§3.4 with moving geometry).
    pub motion: [f32; 3],
}

impl Disc {
    /// A disc with `normal` scaled to unit length; a zero or non-finite normal gives a dead disc
    /// (radius 0) so that nothing downstream divides by it.
    pub fn new(centre: [f32; 3], normal: [f32; 3], radius: f32) -> Disc {
        let l = length(normal);
        if l.is_finite() && l > 0.0 {
            Disc { centre, normal: [normal[0] / l, normal[1] / l, normal[2] / l], radius, motion: [0.0; 3] }
        } else {
            Disc { centre, normal: [0.0, 0.0, 1.0], radius: 0.0, motion: [0.0; 3] }
        }
    }

    /// The same disc translating by `motion` over the shutter, `centre` being where it is at
    /// time 0.5 (a non-finite motion is taken as none).
    pub fn with_motion(self, motion: [f32; 3]) -> Disc {
        let motion = if motion.iter().all(|c| c.is_finite()) { motion } else { [0.0; 3] };
        Disc { motion, ..self }
    }

    /// Whether the disc moves.
    #[inline]
    pub fn moves(&self) -> bool {
        self.motion != [0.0; 3]
    }

    /// The centre at `time` ∈ [0, 1]: centre + (time − 0.5)·motion (exactly `centre` for a
    /// static disc).
    #[inline]
    pub fn centre_at(&self, time: f32) -> [f32; 3] {
        if !self.moves() {
            return self.centre;
        }
        let shift = time - 0.5;
        [0, 1, 2].map(|a| self.centre[a] + shift * self.motion[a])
    }

    /// The exact axis-aligned box of the disc, (lo, hi): a disc of radius r with unit normal n
    /// reaches r·sqrt(1 − n_a²) from its centre along axis a. A moving disc's box holds it over
    /// the whole shutter (the union of its boxes at times 0 and 1: linear motion).
    pub fn bounds(&self) -> ([f32; 3], [f32; 3]) {
        let (start, end) = (self.centre_at(0.0), self.centre_at(1.0));
        let mut lo = [0, 1, 2].map(|a| start[a].min(end[a]));
        let mut hi = [0, 1, 2].map(|a| start[a].max(end[a]));
        for axis in 0..3 {
            let n = self.normal[axis];
            let half = self.radius * (1.0 - n * n).max(0.0).sqrt();
            lo[axis] -= half;
            hi[axis] += half;
        }
        (lo, hi)
    }
}

/// What a ray learns from hitting a disc.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DiscHit {
    /// Ray parameter of the tangent-plane point.
    pub t: f32,
    /// s_i: distance of the tangent-plane point from the centre, in [0, r_i).
    pub spatial: f32,
    /// z_i = d·(h_i − p): depth of the centre along the ray (distance from the st plane).
    pub depth: f32,
    /// n_i·d > 0: the ray meets the disc's back side.
    pub back_facing: bool,
}

/// The ray's hit on `disc` with t in the open interval (t_min, t_max), or `None`; see the module
/// documentation. `t_max` may be +inf.
#[inline]
pub fn intersect(disc: &Disc, ray: &Ray, t_min: f32, t_max: f32) -> Option<DiscHit> {
    intersect_placed(disc.centre_at(ray.time), disc.normal, disc.radius, ray, t_min, t_max)
}

/// [`intersect`] for a disc already placed at the ray's time: `centre` (where it is then),
/// unit `normal`, `radius`. The one implementation of the test, so that the hierarchy's compact
/// records ([`super::bvh`]) give bit for bit the hits of [`intersect`].
#[inline(always)]
pub fn intersect_placed(
    centre: [f32; 3],
    normal: [f32; 3],
    radius: f32,
    ray: &Ray,
    t_min: f32,
    t_max: f32,
) -> Option<DiscHit> {
    let to_centre = sub(centre, ray.origin);
    let cosine = dot(normal, ray.direction);
    // Each test is written so that NaN fails it.
    let steep_enough = cosine.abs() > GRAZING_COSINE;
    if !steep_enough {
        return None;
    }
    let t = dot(normal, to_centre) / cosine;
    if !(t > t_min && t < t_max) {
        return None;
    }
    let d = ray.direction;
    let offset = [t * d[0] - to_centre[0], t * d[1] - to_centre[1], t * d[2] - to_centre[2]];
    let spatial = length(offset);
    let inside = spatial < radius;
    if !inside {
        return None;
    }
    Some(DiscHit { t, spatial, depth: dot(d, to_centre), back_facing: cosine > 0.0 })
}

/// Wedges around a disc's centre on its tangent plane that anisotropic shrinking trims one by
/// one ([`super::shrink::Trim::Wedges`]): eight of 45°.
pub const WEDGES: usize = 8;

/// The wedge (0 .. [`WEDGES`]) that holds the point at ray parameter `t` of `ray` on the
/// tangent plane of the disc at `centre` with unit `normal`: the point's offset from the centre
/// in a tangent frame fixed by the normal alone (Duff et al. 2017, "Building an Orthonormal
/// Basis, Revisited"), classified by the signs of its two coordinates and which is larger. The
/// offset is computed as in [`intersect_placed`], so the same ray and disc give the same wedge
/// bit for bit wherever it is asked (shrinking and the walks).
#[inline]
pub fn wedge_at(centre: [f32; 3], normal: [f32; 3], ray: &Ray, t: f32) -> usize {
    let (x, y) = tangent_coordinates(centre, normal, ray, t);
    wedge_of(x, y)
}

/// The coordinates (x, y) in the tangent frame of [`wedge_at`] of the point at ray parameter `t`
/// of `ray`, relative to the centre.
#[inline]
pub fn tangent_coordinates(centre: [f32; 3], normal: [f32; 3], ray: &Ray, t: f32) -> (f32, f32) {
    let to_centre = sub(centre, ray.origin);
    let d = ray.direction;
    let offset = [t * d[0] - to_centre[0], t * d[1] - to_centre[1], t * d[2] - to_centre[2]];
    let (tangent, bitangent) = tangent_frame(normal);
    (dot(offset, tangent), dot(offset, bitangent))
}

/// The wedge radii that keep a disc out of the half-plane beyond a crossing: a ray crossed the
/// disc's plane at tangent coordinates (x, y), `distance` from the centre, where no surface may
/// be, and the disc's edge there is taken as a straight line across that direction (a
/// silhouette, locally). A wedge whose angles φ come no nearer than δ to the crossing's angle
/// θ keeps within distance / cos δ, the line's distance at the wedge's nearest angle; the
/// crossing's own wedge keeps within `distance` exactly (so the ray misses it), wedges 90° or
/// more away are not bounded (+inf). A crossing through the centre (`distance` 0, no direction)
/// bounds every wedge to 0, as the paper's rule does.
pub fn half_plane_wedge_radii(x: f32, y: f32, distance: f32) -> [f32; WEDGES] {
    let length = (x * x + y * y).sqrt();
    if distance.is_nan() || distance <= 0.0 || length.is_nan() || length <= 0.0 {
        return [0.0; WEDGES];
    }
    // The crossing's direction u; per span, u inside it (between its two edge directions, no
    // angle off: cos δ = 1) or cos δ = u · the nearer edge direction.
    let u = [x / length, y / length];
    let mut radii = [f32::INFINITY; WEDGES];
    for &(start, end, wedge) in wedge_spans() {
        let cos_off = if inside_span(start, end, u) {
            1.0
        } else {
            (u[0] * start[0] + u[1] * start[1]).max(u[0] * end[0] + u[1] * end[1])
        };
        // Within 90° (less a milliradian): bounded by the edge line's distance at that angle.
        if cos_off > 1e-3 {
            radii[wedge] = radii[wedge].min(distance / cos_off);
        }
    }
    radii[wedge_of(x, y)] = distance;
    radii
}

/// A wedge as a span of angle: the unit direction where it starts, where it ends
/// (counter-clockwise, 45° on), and the wedge index [`wedge_of`] gives its interior.
type WedgeSpan = ([f32; 2], [f32; 2], usize);

/// The wedges' spans, computed once.
fn wedge_spans() -> &'static [WedgeSpan; WEDGES] {
    static SPANS: std::sync::OnceLock<[WedgeSpan; WEDGES]> = std::sync::OnceLock::new();
    SPANS.get_or_init(|| {
        let step = std::f32::consts::TAU / WEDGES as f32;
        let direction = |a: f32| [a.cos(), a.sin()];
        std::array::from_fn(|span| {
            let (start, end) = (span as f32 * step, (span as f32 + 1.0) * step);
            let middle = direction(0.5 * (start + end));
            (direction(start), direction(end), wedge_of(middle[0], middle[1]))
        })
    })
}

/// The tangent frame of [`wedge_at`]: two unit vectors orthogonal to the unit `normal` and to
/// each other, a continuous function of the normal except across n_z = 0 (Duff et al. 2017).
#[inline]
fn tangent_frame(normal: [f32; 3]) -> ([f32; 3], [f32; 3]) {
    let [nx, ny, nz] = normal;
    let sign = 1.0f32.copysign(nz);
    let a = -1.0 / (sign + nz);
    let b = nx * ny * a;
    ([1.0 + sign * nx * nx * a, sign * b, -sign * nx], [b, sign + ny * ny * a, -ny])
}

/// The wedge of tangent-plane coordinates (x, y): the signs of both and whether |y| > |x|, one
/// 45° wedge each. NaN coordinates land in wedge 0 (comparisons with NaN are false).
#[inline]
fn wedge_of(x: f32, y: f32) -> usize {
    (((y < 0.0) as usize) << 2) | (((x < 0.0) as usize) << 1) | ((y.abs() > x.abs()) as usize)
}

/// The box, relative to the centre, of a disc with unit `normal` whose wedges ([`wedge_at`])
/// have the radii `wedge_radii`: (lo ≤ 0, hi ≥ 0). Exact: along each axis a wedge, a 45° sector
/// of radius r, reaches farthest at one of its two rim ends or, where the rim's extreme along
/// that axis falls inside the wedge's angles, there (r·sqrt(1 − n_a²), as in [`Disc::bounds`]).
pub fn wedge_extent(normal: [f32; 3], wedge_radii: &[f32; WEDGES]) -> ([f32; 3], [f32; 3]) {
    let (tangent, bitangent) = tangent_frame(normal);
    let (mut lo, mut hi) = ([0.0f32; 3], [0.0f32; 3]);
    for &(start, end, wedge) in wedge_spans() {
        let radius = wedge_radii[wedge];
        for axis in 0..3 {
            // The rim's point in direction (c, s) of the tangent plane, along the axis.
            let (t, b) = (tangent[axis], bitangent[axis]);
            for [c, s] in [start, end] {
                lo[axis] = lo[axis].min(radius * (c * t + s * b));
                hi[axis] = hi[axis].max(radius * (c * t + s * b));
            }
            // The rim's extreme along the axis: c·t_a + s·b_a is largest in the direction
            // (t_a, b_a), with value sqrt(t_a² + b_a²) = sqrt(1 − n_a²), smallest opposite.
            let reach = radius * (1.0 - normal[axis] * normal[axis]).max(0.0).sqrt();
            if inside_span(start, end, [t, b]) {
                hi[axis] = hi[axis].max(reach);
            }
            if inside_span(start, end, [-t, -b]) {
                lo[axis] = lo[axis].min(-reach);
            }
        }
    }
    (lo, hi)
}

/// Whether direction `u` (any length) of the tangent plane lies in the span from `start`
/// counter-clockwise to `end` (less than half a turn apart), edges included.
#[inline]
fn inside_span(start: [f32; 2], end: [f32; 2], u: [f32; 2]) -> bool {
    start[0] * u[1] - start[1] * u[0] >= 0.0 && u[0] * end[1] - u[1] * end[0] >= 0.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lcg::Lcg;
    use crate::vector::normalize;

    #[test]
    fn a_tilted_disc_is_hit_where_the_geometry_says() {
        // Disc in the plane x + z = 2 (normal (1, 0, 1)/√2) centred at (1, 0, 1), radius 1. A ray
        // from the origin along +z meets the plane at z = 2, x = 0: t = 2, and the point (0, 0, 2)
        // is √2 from the centre — outside. Shifted to start at x = 0.5: the point is (0.5, 0, 1.5),
        // t = 1.5, s = √0.5 ≈ 0.707 — inside; the centre's depth is 1.
        let disc = Disc::new([1.0, 0.0, 1.0], [1.0, 0.0, 1.0], 1.0);
        let up = [0.0, 0.0, 1.0];
        assert_eq!(intersect(&disc, &Ray { time: 0.0, origin: [0.0; 3], direction: up }, 0.0, f32::INFINITY), None);
        let hit =
            intersect(&disc, &Ray { time: 0.0, origin: [0.5, 0.0, 0.0], direction: up }, 0.0, f32::INFINITY).unwrap();
        assert!((hit.t - 1.5).abs() < 1e-6, "{hit:?}");
        assert!((hit.spatial - 0.5f32.sqrt()).abs() < 1e-6, "{hit:?}");
        assert!((hit.depth - 1.0).abs() < 1e-6);
        // n·d = 1/√2 > 0: the ray sees the back of the disc; reversed, the front.
        assert!(hit.back_facing);
        let down =
            intersect(&disc, &Ray { time: 0.0, origin: [0.5, 0.0, 3.0], direction: [0.0, 0.0, -1.0] }, 0.0, 10.0);
        assert!(!down.unwrap().back_facing);
        // The t window is open at both ends.
        assert!(intersect(&disc, &Ray { time: 0.0, origin: [0.5, 0.0, 0.0], direction: up }, 1.5, 10.0).is_none());
        assert!(intersect(&disc, &Ray { time: 0.0, origin: [0.5, 0.0, 0.0], direction: up }, 0.0, 1.5).is_none());
        assert!(intersect(&disc, &Ray { time: 0.0, origin: [0.5, 0.0, 0.0], direction: up }, 0.0, 1.5001).is_some());
        // Behind the origin: no hit.
        assert!(
            intersect(&disc, &Ray { time: 0.0, origin: [0.5, 0.0, 5.0], direction: up }, 0.0, f32::INFINITY).is_none()
        );
    }

    #[test]
    fn the_rim_is_where_the_distance_reaches_the_radius() {
        // Disc z = 0, radius 1; vertical rays at x = 1 ∓ 1e-5 hit and miss.
        let disc = Disc::new([0.0; 3], [0.0, 0.0, 1.0], 1.0);
        let ray = |x: f32| Ray { time: 0.0, origin: [x, 0.0, 1.0], direction: [0.0, 0.0, -1.0] };
        assert!(intersect(&disc, &ray(1.0 - 1e-5), 0.0, 2.0).is_some());
        assert!(intersect(&disc, &ray(1.0 + 1e-5), 0.0, 2.0).is_none());
        // Exactly at the rim: s = r is a miss (the shrinking of §2.3.1 relies on this).
        assert!(intersect(&disc, &ray(1.0), 0.0, 2.0).is_none());
        // A slanted ray, 60° from the normal, through a point 0.9 from the centre.
        let d = normalize([3f32.sqrt(), 0.0, -1.0]);
        let origin = [0.9 - d[0] * 4.0, 0.0, -d[2] * 4.0];
        let hit = intersect(&disc, &Ray { time: 0.0, origin, direction: d }, 0.0, f32::INFINITY).unwrap();
        assert!((hit.t - 4.0).abs() < 1e-5 && (hit.spatial - 0.9).abs() < 1e-5, "{hit:?}");
    }

    #[test]
    fn grazing_and_degenerate_discs_stay_finite() {
        let disc = Disc::new([0.0; 3], [0.0, 0.0, 1.0], 1.0);
        // A ray in the plane of the disc: n·d = 0, no hit (not a t of 0/0).
        let in_plane = Ray { time: 0.0, origin: [-5.0, 0.0, 0.0], direction: [1.0, 0.0, 0.0] };
        assert!(intersect(&disc, &in_plane, 0.0, f32::INFINITY).is_none());
        // Nearly grazing, aimed at the centre from half a unit away: n·d = 1e-8 is below the
        // threshold (no hit, although the exact plane point is the centre), 1e-6 above it.
        for (cosine, expect_hit) in [(1e-8f32, false), (1e-6, true)] {
            let d = normalize([1.0, 0.0, -cosine]);
            let ray = Ray { time: 0.0, origin: [-0.5, 0.0, 0.5 * cosine], direction: d };
            let hit = intersect(&disc, &ray, 0.0, f32::INFINITY);
            assert_eq!(hit.is_some(), expect_hit, "{cosine}: {hit:?}");
            if let Some(hit) = hit {
                assert!((hit.t - 0.5).abs() < 1e-3 && hit.spatial < 1e-3, "{hit:?}");
            }
        }
        // Grazing rays far from the disc: a finite t, a finite distance, a miss.
        let far = Ray { time: 0.0, origin: [-1e4, 3.0, 1.0], direction: normalize([1.0, 0.0, -1e-5]) };
        assert!(intersect(&disc, &far, 0.0, f32::INFINITY).is_none());
        // Radius 0: even the ray through the exact centre misses.
        let dead = Disc::new([0.0; 3], [0.0, 0.0, 1.0], 0.0);
        assert!(intersect(&dead, &Ray { time: 0.0, origin: [0.0, 0.0, 1.0], direction: [0.0, 0.0, -1.0] }, 0.0, 2.0)
            .is_none());
        // A zero or NaN normal makes a dead disc, not NaN.
        for normal in [[0.0; 3], [f32::NAN, 0.0, 1.0]] {
            let disc = Disc::new([0.0; 3], normal, 1.0);
            assert_eq!(disc.radius, 0.0);
            assert!(intersect(
                &disc,
                &Ray { time: 0.0, origin: [0.0, 0.0, 1.0], direction: [0.0, 0.0, -1.0] },
                0.0,
                2.0
            )
            .is_none());
        }
        // A NaN ray fails every comparison.
        let nan = Ray { time: 0.0, origin: [f32::NAN; 3], direction: [0.0, 0.0, -1.0] };
        assert!(intersect(&disc, &nan, 0.0, f32::INFINITY).is_none());
    }

    #[test]
    fn a_moving_disc_is_hit_where_it_is_at_the_rays_time_and_boxed_over_the_shutter() {
        let motion = [2.0, -1.0, 0.5];
        let moving = Disc::new([1.0, 0.0, 1.0], [1.0, 0.0, 1.0], 0.7).with_motion(motion);
        let (lo, hi) = moving.bounds();
        for time in [0.0f32, 0.3, 0.5, 1.0] {
            let centre = moving.centre_at(time);
            let fixed = Disc::new(centre, [1.0, 0.0, 1.0], 0.7);
            let (flo, fhi) = fixed.bounds();
            assert!((0..3).all(|a| lo[a] <= flo[a] && fhi[a] <= hi[a]), "time {time}: {flo:?}..{fhi:?} outside");
            for origin in [[0.5, 0.0, 0.0], [1.9, -0.4, 0.0], [0.0, 0.3, -1.0]] {
                let ray = Ray { time, origin, direction: normalize([0.1, 0.05, 1.0]) };
                let at_rest = Ray { time: 0.0, ..ray };
                assert_eq!(
                    intersect(&moving, &ray, 0.0, f32::INFINITY),
                    intersect(&fixed, &at_rest, 0.0, f32::INFINITY)
                );
            }
        }
        assert_eq!(moving.centre_at(0.5), [1.0, 0.0, 1.0]);
        let still = Disc::new([1.0, 0.0, 1.0], [0.0, 0.0, 1.0], 1.0);
        assert_eq!(still.with_motion([f32::NAN, 0.0, 0.0]), still, "non-finite motion is none");
    }

    #[test]
    fn bounds_are_exact_for_tilted_discs() {
        // The box must hold every rim point and touch the rim on each side.
        let mut rng = Lcg(7u64);
        let mut next = move || rng.uniform() * 2.0 - 1.0;
        for _ in 0..50 {
            let disc = Disc::new([next(), next(), next()], [next(), next(), next() + 0.01], 0.5 + next().abs());
            let (lo, hi) = disc.bounds();
            let (u, v) = own_frame(disc.normal);
            let mut reach_lo = [f32::INFINITY; 3];
            let mut reach_hi = [f32::NEG_INFINITY; 3];
            for k in 0..3600 {
                let a = k as f32 / 3600.0 * std::f32::consts::TAU;
                for axis in 0..3 {
                    let x = disc.centre[axis] + disc.radius * (a.cos() * u[axis] + a.sin() * v[axis]);
                    reach_lo[axis] = reach_lo[axis].min(x);
                    reach_hi[axis] = reach_hi[axis].max(x);
                }
            }
            for axis in 0..3 {
                assert!(reach_lo[axis] >= lo[axis] - 1e-5 && reach_hi[axis] <= hi[axis] + 1e-5);
                assert!(reach_lo[axis] - lo[axis] < 1e-4 && hi[axis] - reach_hi[axis] < 1e-4);
            }
        }
    }

    /// Our own frame of the tangent plane (not [`tangent_frame`]'s), and the ray that meets the
    /// disc's plane at angle `angle` and distance `reach` from the centre, from 1 unit off the
    /// plane on the normal's side.
    fn own_frame(n: [f32; 3]) -> ([f32; 3], [f32; 3]) {
        let helper = if n[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
        let u = normalize([
            helper[1] * n[2] - helper[2] * n[1],
            helper[2] * n[0] - helper[0] * n[2],
            helper[0] * n[1] - helper[1] * n[0],
        ]);
        (u, [n[1] * u[2] - n[2] * u[1], n[2] * u[0] - n[0] * u[2], n[0] * u[1] - n[1] * u[0]])
    }

    fn ray_to(disc: &Disc, (u, v): ([f32; 3], [f32; 3]), angle: f32, reach: f32) -> (Ray, f32) {
        let point = [0, 1, 2].map(|a| disc.centre[a] + reach * (angle.cos() * u[a] + angle.sin() * v[a]));
        let origin = [0, 1, 2].map(|a| point[a] + disc.normal[a]);
        (Ray { time: 0.0, origin, direction: disc.normal.map(|c| -c) }, 1.0)
    }

    #[test]
    fn the_wedges_are_eight_runs_of_45_degrees_round_the_centre() {
        // Round the centre in our own frame, the wedge changes exactly 8 times, each wedge is one
        // run of 45° (± the step), and every wedge index appears once: whatever the normal,
        // including normals along the axes and with n_z = 0 or negative.
        let mut rng = Lcg(5);
        let mut normals: Vec<[f32; 3]> =
            vec![[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.6, 0.8, 0.0]];
        normals.extend((0..40).map(|_| [rng.uniform() - 0.5, rng.uniform() - 0.5, rng.uniform() - 0.5]));
        let steps = 7200;
        for n in normals {
            let disc = Disc::new([rng.uniform(), rng.uniform(), rng.uniform()], n, 1.0);
            let frame = own_frame(disc.normal);
            let wedges: Vec<usize> = (0..steps)
                .map(|k| {
                    let (ray, t) = ray_to(&disc, frame, (k as f32 + 0.5) / steps as f32 * std::f32::consts::TAU, 0.7);
                    wedge_at(disc.centre, disc.normal, &ray, t)
                })
                .collect();
            let changes: Vec<usize> = (0..steps).filter(|&k| wedges[k] != wedges[(k + 1) % steps]).collect();
            assert_eq!(changes.len(), WEDGES, "normal {n:?}");
            for (i, &k) in changes.iter().enumerate() {
                let run = (changes[(i + 1) % WEDGES] + steps - k) % steps;
                assert!((run as i64 - steps as i64 / 8).abs() <= 2, "normal {n:?}: a run of {run} steps");
            }
            let mut seen = [false; WEDGES];
            changes.iter().for_each(|&k| seen[wedges[k]] = true);
            assert!(seen.iter().all(|&s| s), "normal {n:?}");
        }
    }

    #[test]
    fn the_wedge_box_holds_every_point_of_the_trimmed_disc_and_no_more() {
        let mut rng = Lcg(9);
        for case in 0..60 {
            let n = [rng.uniform() - 0.5, rng.uniform() - 0.5, rng.uniform() - 0.5 + 1e-3];
            let disc = Disc::new([0.0; 3], n, 1.0);
            let radii: [f32; WEDGES] =
                std::array::from_fn(|w| if case % 3 == 0 && w % 2 == 0 { 0.0 } else { rng.uniform() });
            let (lo, hi) = wedge_extent(disc.normal, &radii);
            let frame = own_frame(disc.normal);
            let (mut reach_lo, mut reach_hi) = ([0.0f32; 3], [0.0f32; 3]);
            for k in 0..7200 {
                let angle = k as f32 / 7200.0 * std::f32::consts::TAU;
                let (ray, t) = ray_to(&disc, frame, angle, 1e-3);
                let r = radii[wedge_at(disc.centre, disc.normal, &ray, t)] * 0.9999;
                for axis in 0..3 {
                    let x = r * (angle.cos() * frame.0[axis] + angle.sin() * frame.1[axis]);
                    assert!(x >= lo[axis] - 1e-5 && x <= hi[axis] + 1e-5, "case {case}, angle {angle}");
                    reach_lo[axis] = reach_lo[axis].min(x);
                    reach_hi[axis] = reach_hi[axis].max(x);
                }
            }
            // Tight: no farther than the sampling's resolution beyond the farthest point sampled.
            for axis in 0..3 {
                assert!(reach_lo[axis] - lo[axis] <= 1e-3, "case {case}: {lo:?} {reach_lo:?}");
                assert!(hi[axis] - reach_hi[axis] <= 1e-3, "case {case}: {hi:?} {reach_hi:?}");
            }
            // Equal wedges: the whole disc's box.
            let r = radii[0];
            let (whole_lo, whole_hi) = Disc { radius: r, ..disc }.bounds();
            let (equal_lo, equal_hi) = wedge_extent(disc.normal, &[r; WEDGES]);
            for axis in 0..3 {
                assert!(
                    (whole_lo[axis] - equal_lo[axis]).abs() <= 1e-6 && (whole_hi[axis] - equal_hi[axis]).abs() <= 1e-6
                );
            }
        }
    }

    #[test]
    fn half_plane_wedges_stay_inside_the_half_plane_and_keep_the_far_side() {
        // For random crossings, every point the trimmed wedges keep lies on the near side of the
        // line through the crossing across its direction (the crossing itself excluded), and
        // every point 90° or more from the crossing's direction keeps the whole radius.
        let mut rng = Lcg(21);
        let n = normalize([0.3, -0.2, 0.9]);
        let disc = Disc::new([0.0; 3], n, 1.0);
        let (u, v) = own_frame(disc.normal);
        for _ in 0..200 {
            let (angle, distance) = (rng.uniform() * std::f32::consts::TAU, 0.05 + 0.9 * rng.uniform());
            let (crossing, t) = ray_to(&disc, (u, v), angle, distance);
            let (x, y) = tangent_coordinates(disc.centre, disc.normal, &crossing, t);
            assert!(((x * x + y * y).sqrt() - distance).abs() < 1e-5);
            let radii = half_plane_wedge_radii(x, y, distance);
            assert_eq!(radii[wedge_at(disc.centre, disc.normal, &crossing, t)], distance);
            for k in 0..2000 {
                let phi = k as f32 / 2000.0 * std::f32::consts::TAU;
                let (ray, t) = ray_to(&disc, (u, v), phi, 1e-3);
                let bound = radii[wedge_at(disc.centre, disc.normal, &ray, t)].min(1.0);
                // Along the crossing's direction, the kept point farthest out at this angle.
                let along = bound * 0.9999 * (phi - angle).cos();
                assert!(along < distance, "crossing {angle} at {distance}: angle {phi} keeps {bound}");
                let off = (phi - angle).rem_euclid(std::f32::consts::TAU);
                let away = off.min(std::f32::consts::TAU - off);
                if away >= std::f32::consts::FRAC_PI_2 + std::f32::consts::FRAC_PI_4 {
                    assert_eq!(bound, 1.0, "crossing {angle}: angle {phi} was trimmed");
                }
            }
        }
        // Through the centre there is no edge direction: the whole disc goes, as in the paper;
        // so do non-finite crossings (no NaN radius ever reaches the hierarchy).
        assert_eq!(half_plane_wedge_radii(0.0, 0.0, 0.0), [0.0; WEDGES]);
        assert_eq!(half_plane_wedge_radii(f32::NAN, 0.3, 0.3), [0.0; WEDGES]);
        assert_eq!(half_plane_wedge_radii(0.3, 0.0, f32::NAN), [0.0; WEDGES]);
        // Scale-free: at 1e-6 and 1e9 the radii are the unit case's times the scale.
        let unit = half_plane_wedge_radii(0.6, -0.8, 1.0);
        for scale in [1e-6f32, 1e9] {
            let scaled = half_plane_wedge_radii(0.6 * scale, -0.8 * scale, scale);
            for (a, b) in unit.iter().zip(scaled) {
                assert!(
                    a.is_infinite() && b.is_infinite() || ((b / scale) - a).abs() <= 1e-5 * a,
                    "{unit:?} {scaled:?}"
                );
            }
        }
    }
}
