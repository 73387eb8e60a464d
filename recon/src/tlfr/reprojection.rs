//! Reprojection of a sample through the lens × time cube (paper Section 3.1, Eq. 2–3):
//!
//! ```text
//! z'(t̂)    = z + (t̂ − t)·m_z                                        (Eq. 2)
//! x'(û, t̂) = [(x − u·C(z))·z + (t̂ − t)·m_x] / z'(t̂) + û·C(z'(t̂))      (Eq. 3)
//! y'(v̂, t̂) = [(y − v·C(z))·z + (t̂ − t)·m_y] / z'(t̂) + v̂·C(z'(t̂))
//! ```
//!
//! with m the homogeneous screen motion over the shutter (`LensModel::screen_motion`): the
//! sample is moved to the lens centre, back-projected, moved along its 3D motion to t̂,
//! projected again and moved to the lens point (û, v̂).
//!
//! Robustness: a sample whose depth at t̂ falls below `z_near` (it nears or
//! passes the camera plane, where Eq. 3 divides by ~0 or changes sign) cannot be seen at t̂ and
//! reprojects to `None`, before any division. Misses (z = +∞: the ray escaped) never move on
//! screen except by û·C(∞) = û·c2 and keep depth +∞.

use super::lens::LensModel;

/// A lens-time sample as the reprojection reads it (docs/sample-format.md, `lens-time`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LensTimeSample {
    /// Screen position, pixels.
    pub x: f32,
    pub y: f32,
    /// Lens position on the unit disk (0 for a pinhole file).
    pub u: f32,
    pub v: f32,
    /// Time in [0, 1] (0.5 for a static file).
    pub t: f32,
    /// Camera-space depth; +∞ for a miss.
    pub z: f32,
    /// Camera-space displacement over the whole shutter (0 for a static file).
    pub motion: [f32; 3],
}

/// Where a sample lands at a reconstruction location's (û, v̂, t̂).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reprojected {
    pub x: f32,
    pub y: f32,
    /// Depth at t̂ (z').
    pub z: f32,
}

/// A lens-time coordinate (û, v̂, t̂) of a reconstruction location.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LensTime {
    pub u: f32,
    pub v: f32,
    pub t: f32,
}

/// Eq. 2: the sample's depth at `t`.
#[inline]
pub fn depth_at(sample: &LensTimeSample, t: f32) -> f32 {
    if sample.z.is_infinite() {
        sample.z
    } else {
        sample.z + (t - sample.t) * sample.motion[2]
    }
}

/// Eq. 2–3: the sample's screen position and depth at `at`, or `None` where its depth there is
/// below `z_near` (behind or too close to the camera plane: not visible at t̂).
#[inline]
pub fn reproject(sample: &LensTimeSample, lens: &LensModel, at: LensTime, z_near: f32) -> Option<Reprojected> {
    if sample.z.is_infinite() {
        // A miss: C(∞) = c2, no motion, no depth.
        let c = lens.c2;
        return Some(Reprojected {
            x: sample.x - sample.u * c + at.u * c,
            y: sample.y - sample.v * c + at.v * c,
            z: f32::INFINITY,
        });
    }
    let z_new = depth_at(sample, at.t);
    if z_new.is_nan() || z_new < z_near {
        return None;
    }
    let c_old = lens.coc(sample.z);
    let c_new = lens.coc(z_new);
    let m = lens.screen_motion(sample.motion);
    let dt = at.t - sample.t;
    let x_centre = ((sample.x - sample.u * c_old) * sample.z + dt * m[0]) / z_new;
    let y_centre = ((sample.y - sample.v * c_old) * sample.z + dt * m[1]) / z_new;
    Some(Reprojected { x: x_centre + at.u * c_new, y: y_centre + at.v * c_new, z: z_new })
}

/// The near limit of a file: 1e-3 of its smallest finite depth (every sample was visible at its
/// own time, so this is below every observed depth and scales with the scene), or 1e-6 when no
/// depth is finite.
pub fn near_limit(depths: impl IntoIterator<Item = f32>) -> f32 {
    let smallest = depths.into_iter().filter(|z| z.is_finite() && *z > 0.0).fold(f32::INFINITY, f32::min);
    if smallest.is_finite() {
        1e-3 * smallest
    } else {
        1e-6
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lcg::Lcg;

    fn lens() -> LensModel {
        // fx = fy = 80, principal point (32, 24), lens radius 0.1, focus 4.
        LensModel { c1: -8.0, c2: 2.0, fx: 80.0, fy: 80.0, cx: 32.0, cy: 24.0 }
    }

    /// An independent thin-lens projection: the camera-space point seen through lens point
    /// (a·u, a·v) lands where the ray from there through the point meets the plane in focus.
    fn project(point: [f32; 3], u: f32, v: f32) -> [f32; 2] {
        let (a, focus, f, cx, cy) = (0.1f32, 4.0f32, 80.0f32, 32.0f32, 24.0f32);
        let lens_point = [a * u, a * v];
        let s = focus / point[2];
        let on_focus_plane =
            [lens_point[0] + (point[0] - lens_point[0]) * s, lens_point[1] + (point[1] - lens_point[1]) * s];
        [cx + f * on_focus_plane[0] / focus, cy + f * on_focus_plane[1] / focus]
    }

    #[test]
    fn the_own_coordinates_leave_a_sample_in_place() {
        let mut rng = Lcg(7);
        for _ in 0..1000 {
            let sample = LensTimeSample {
                x: 64.0 * rng.uniform(),
                y: 48.0 * rng.uniform(),
                u: 2.0 * rng.uniform() - 1.0,
                v: 2.0 * rng.uniform() - 1.0,
                t: rng.uniform(),
                z: 0.5 + 10.0 * rng.uniform(),
                motion: [rng.uniform() - 0.5, rng.uniform() - 0.5, rng.uniform() - 0.5],
            };
            let at = LensTime { u: sample.u, v: sample.v, t: sample.t };
            let same = reproject(&sample, &lens(), at, 1e-3).unwrap();
            assert!((same.x - sample.x).abs() < 1e-4 && (same.y - sample.y).abs() < 1e-4, "{sample:?} → {same:?}");
            assert_eq!(same.z, sample.z);
        }
    }

    #[test]
    fn reprojection_agrees_with_projecting_the_moving_point() {
        let mut rng = Lcg(11);
        for _ in 0..1000 {
            let start = [2.0 * rng.uniform() - 1.0, 2.0 * rng.uniform() - 1.0, 1.0 + 6.0 * rng.uniform()];
            let motion = [rng.uniform() - 0.5, rng.uniform() - 0.5, 1.5 * (rng.uniform() - 0.5)];
            let at_time = |t: f32| [start[0] + t * motion[0], start[1] + t * motion[1], start[2] + t * motion[2]];
            let (u, v, t) = (2.0 * rng.uniform() - 1.0, 2.0 * rng.uniform() - 1.0, rng.uniform());
            let [x, y] = project(at_time(t), u, v);
            let sample = LensTimeSample { x, y, u, v, t, z: at_time(t)[2], motion };
            let target = LensTime { u: 2.0 * rng.uniform() - 1.0, v: 2.0 * rng.uniform() - 1.0, t: rng.uniform() };
            let expected = project(at_time(target.t), target.u, target.v);
            let found = reproject(&sample, &lens(), target, 1e-3).unwrap();
            assert!(
                (found.x - expected[0]).abs() < 2e-3 && (found.y - expected[1]).abs() < 2e-3,
                "{found:?} vs {expected:?}"
            );
            assert!((found.z - at_time(target.t)[2]).abs() < 1e-5);
        }
    }

    #[test]
    fn a_sample_passing_behind_the_camera_is_not_reprojected() {
        // Depth 1 at t = 0, moving by −2 over the shutter: it crosses the camera plane at t = 0.5.
        let sample = LensTimeSample { x: 40.0, y: 20.0, u: 0.0, v: 0.0, t: 0.0, z: 1.0, motion: [0.3, 0.0, -2.0] };
        let z_near = near_limit([1.0, 3.0]);
        assert_eq!(z_near, 1e-3);
        for t in [0.0f32, 0.2, 0.49] {
            let at = LensTime { u: 0.5, v: -0.5, t };
            let p = reproject(&sample, &lens(), at, z_near).unwrap();
            assert!(p.x.is_finite() && p.y.is_finite() && p.z > 0.0);
        }
        for t in [0.4996f32, 0.5, 0.75, 1.0] {
            assert_eq!(reproject(&sample, &lens(), LensTime { u: 0.0, v: 0.0, t }, z_near), None, "t = {t}");
        }
    }

    #[test]
    fn misses_only_follow_the_lens_at_infinity() {
        let miss = LensTimeSample { x: 10.0, y: 5.0, u: 0.5, v: -0.5, t: 0.3, z: f32::INFINITY, motion: [0.0; 3] };
        let p = reproject(&miss, &lens(), LensTime { u: -0.5, v: 0.5, t: 0.9 }, 1e-3).unwrap();
        assert_eq!((p.x, p.y, p.z), (10.0 - 1.0 - 1.0, 5.0 + 1.0 + 1.0, f32::INFINITY));
        assert_eq!(near_limit([f32::INFINITY]), 1e-6);
    }
}
