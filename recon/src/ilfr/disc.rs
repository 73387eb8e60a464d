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

/// Rays closer to the tangent plane than this (|n·d|, the cosine between the ray and the plane's
/// normal) do not hit the disc: the plane intersection would be ill-conditioned.
pub const GRAZING_COSINE: f32 = 1e-7;

#[inline]
pub fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline]
pub fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[inline]
pub fn length(a: [f32; 3]) -> f32 {
    dot(a, a).sqrt()
}

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lcg::Lcg;

    fn normalize(v: [f32; 3]) -> [f32; 3] {
        let l = length(v);
        [v[0] / l, v[1] / l, v[2] / l]
    }

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
            // Two tangent vectors.
            let n = disc.normal;
            let helper = if n[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
            let u = normalize([
                helper[1] * n[2] - helper[2] * n[1],
                helper[2] * n[0] - helper[0] * n[2],
                helper[0] * n[1] - helper[1] * n[0],
            ]);
            let v = [n[1] * u[2] - n[2] * u[1], n[2] * u[0] - n[0] * u[2], n[0] * u[1] - n[1] * u[0]];
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
}
