//! The thin-lens model of the sample files (paper Eq. 4): the signed circle of confusion
//! `C(z) = c1 / z + c2` in pixels per unit lens coordinate, and the pinhole intrinsics that turn
//! a camera-space motion into the homogeneous screen motion of Eq. 3.
//!
//! With lens radius a (scene units), focus distance F and focal length fx in pixels, a point at
//! depth z seen through the lens point (a·u, a·v) lands at `x = cx + fx·X/z + u·fx·a·(1/F − 1/z)`
//! (the ray from the lens point through the point meets the plane in focus where the chief ray
//! does), so `c1 = −fx·a` and `c2 = fx·a/F`. `refocused` re-derives them for another focus
//! distance and aperture (Section 6: refocusing after the fact).

use sampleio::Camera;

use crate::error::Error;

/// The per-frame lens and projection constants the reconstruction needs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LensModel {
    /// `C(z) = c1 / z + c2`, pixels per unit lens coordinate.
    pub c1: f32,
    pub c2: f32,
    /// Focal length in pixels along x and y, and the principal point in pixels.
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
}

impl LensModel {
    /// The model of a sample file's camera block: `coc` and the intrinsics of
    /// `pixel_to_camera` (fx = 1 / `M[0][0]`, fy = 1 / `M[1][1]`, cx = −`M[0][2]`·fx, cy = −`M[1][2]`·fy).
    pub fn from_camera(camera: &Camera) -> Result<LensModel, Error> {
        let m = &camera.pixel_to_camera;
        let (sx, sy) = (m[0][0], m[1][1]);
        if !(sx.is_finite() && sy.is_finite() && sx != 0.0 && sy != 0.0) {
            let message = format!("camera.pixel_to_camera has no usable focal length (diagonal {sx}, {sy})");
            return Err(Error::parameter("camera", message));
        }
        let (fx, fy) = (1.0 / sx, 1.0 / sy);
        let model = LensModel {
            c1: camera.coc.c1 as f32,
            c2: camera.coc.c2 as f32,
            fx: fx as f32,
            fy: fy as f32,
            cx: (-m[0][2] * fx) as f32,
            cy: (-m[1][2] * fy) as f32,
        };
        let values = [model.c1, model.c2, model.fx, model.fy, model.cx, model.cy];
        if values.iter().any(|v| !v.is_finite()) {
            return Err(Error::parameter("camera", format!("camera: non-finite lens constants {values:?}")));
        }
        Ok(model)
    }

    /// The signed circle of confusion at depth `z` (pixels per unit lens coordinate); `c2` for
    /// z = ∞.
    #[inline]
    pub fn coc(&self, z: f32) -> f32 {
        if z.is_infinite() {
            self.c2
        } else {
            self.c1 / z + self.c2
        }
    }

    /// The lens radius a in scene units (`c1 = −fx·a`); 0 for a pinhole.
    pub fn aperture_radius(&self) -> f32 {
        (self.c1 / self.fx).abs()
    }

    /// Whether every sample stays put on the lens (a pinhole, or a lens with C ≡ 0).
    pub fn is_pinhole(&self) -> bool {
        self.c1 == 0.0 && self.c2 == 0.0
    }

    /// The same camera focused at `focus_distance` with lens radius `aperture_radius` (scene
    /// units): `c1 = −fx·A`, `c2 = fx·A/D`.
    pub fn refocused(&self, focus_distance: f32, aperture_radius: f32) -> Result<LensModel, Error> {
        if !(focus_distance.is_finite() && focus_distance > 0.0) {
            let message = format!("the focus distance must be positive and finite, got {focus_distance}");
            return Err(Error::parameter("focus_distance", message));
        }
        if !(aperture_radius.is_finite() && aperture_radius >= 0.0) {
            let message = format!("the aperture radius must be finite and ≥ 0, got {aperture_radius}");
            return Err(Error::parameter("aperture_radius", message));
        }
        Ok(LensModel { c1: -self.fx * aperture_radius, c2: self.fx * aperture_radius / focus_distance, ..*self })
    }

    /// Eq. 3's homogeneous screen motion of a camera-space displacement (ΔX, ΔY, ΔZ) over the
    /// shutter: `(fx ΔX + cx ΔZ, fy ΔY + cy ΔZ, ΔZ)`, because x·z = fx·X + cx·Z.
    #[inline]
    pub fn screen_motion(&self, motion: [f32; 3]) -> [f32; 3] {
        [self.fx * motion[0] + self.cx * motion[2], self.fy * motion[1] + self.cy * motion[2], motion[2]]
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A camera block as the tracer writes it: 64×48 pixels, fx = fy = 80, principal point at
    /// the image centre, lens radius 0.1, focus at 4.
    pub(crate) fn camera() -> Camera {
        let (fx, a, focus) = (80.0, 0.1, 4.0);
        Camera {
            position: [0.0; 3],
            forward: [0.0, 0.0, 1.0],
            up: [0.0, -1.0, 0.0],
            right: [1.0, 0.0, 0.0],
            fov_deg: 40.0,
            fov_axis: sampleio::FovAxis::Y,
            aperture_radius: a,
            focus_distance: focus,
            coc: sampleio::Coc { c1: -fx * a, c2: fx * a / focus },
            shutter: [0.0, 1.0],
            pixel_to_camera: [
                [1.0 / fx, 0.0, -32.0 / fx, 0.0],
                [0.0, 1.0 / fx, -24.0 / fx, 0.0],
                [0.0, 0.0, 1.0, 0.0],
                [0.0, 0.0, 0.0, 1.0],
            ],
            world_to_camera: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]],
        }
    }

    #[test]
    fn intrinsics_and_coc_come_from_the_camera_block() {
        let lens = LensModel::from_camera(&camera()).unwrap();
        assert!((lens.fx - 80.0).abs() < 1e-4 && (lens.fy - 80.0).abs() < 1e-4);
        assert!((lens.cx - 32.0).abs() < 1e-4 && (lens.cy - 24.0).abs() < 1e-4);
        // In focus at 4, C(∞) = c2, and the thin-lens value fx·a·(1/F − 1/z) elsewhere.
        assert!(lens.coc(4.0).abs() < 1e-6);
        assert_eq!(lens.coc(f32::INFINITY), lens.c2);
        for z in [0.5f32, 2.0, 8.0, 100.0] {
            assert!((lens.coc(z) - 80.0 * 0.1 * (0.25 - 1.0 / z)).abs() < 1e-5, "z = {z}");
        }
    }

    #[test]
    fn refocusing_rederives_the_constants_and_round_trips() {
        let lens = LensModel::from_camera(&camera()).unwrap();
        let near = lens.refocused(2.0, 0.3).unwrap();
        for z in [1.0f32, 2.0, 5.0] {
            assert!((near.coc(z) - 80.0 * 0.3 * (0.5 - 1.0 / z)).abs() < 1e-4);
        }
        assert!(near.coc(2.0).abs() < 1e-6);
        let back = near.refocused(4.0, 0.1).unwrap();
        assert!((back.c1 - lens.c1).abs() < 1e-6 && (back.c2 - lens.c2).abs() < 1e-6);
        assert!(lens.refocused(10.0, 0.0).unwrap().is_pinhole());
        assert!(lens.refocused(0.0, 0.1).is_err());
        assert!(lens.refocused(f32::NAN, 0.1).is_err());
        assert!(lens.refocused(2.0, -1.0).is_err());
    }

    #[test]
    fn screen_motion_is_the_derivative_of_x_times_z() {
        let lens = LensModel::from_camera(&camera()).unwrap();
        let (point, motion) = ([0.3f32, -0.2, 3.0], [0.5f32, 0.25, -1.0]);
        let xz = |p: [f32; 3]| [lens.fx * p[0] + lens.cx * p[2], lens.fy * p[1] + lens.cy * p[2]];
        let moved = [point[0] + motion[0], point[1] + motion[1], point[2] + motion[2]];
        let m = lens.screen_motion(motion);
        let (before, after) = (xz(point), xz(moved));
        assert!((after[0] - before[0] - m[0]).abs() < 1e-4 && (after[1] - before[1] - m[1]).abs() < 1e-4);
        assert_eq!(m[2], -1.0);
    }

    #[test]
    fn a_camera_without_focal_length_is_an_error() {
        let mut bad = camera();
        bad.pixel_to_camera[0][0] = 0.0;
        assert!(LensModel::from_camera(&bad).unwrap_err().to_string().contains("focal length"));
    }
}
