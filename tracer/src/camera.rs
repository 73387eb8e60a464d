//! Thin-lens perspective camera with a shutter interval.
//!
//! Conventions: right-handed world; the image's +x runs along `forward × up` and its +y
//! (downwards in the image) along `-up`; pixel (0, 0) is the top-left corner. A sample at film
//! position (x, y) in pixels and lens position (u, v) on the unit disk leaves the lens at
//! `position + aperture_radius · (u · right + v · up)` towards the point that the pinhole ray
//! through (x, y) meets on the plane of focus at distance `focus_distance` along `forward`.

use std::path::Path;

use glam::{Vec2, Vec3};

use crate::error::SceneError;

/// Which image axis the field of view spans.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum FovAxis {
    X,
    #[default]
    Y,
    /// The shorter image side (Mitsuba's `fov_axis = "smaller"`).
    Smaller,
    Larger,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    pub position: Vec3,
    /// Unit viewing direction.
    pub forward: Vec3,
    /// Unit up vector, orthogonal to `forward`.
    pub up: Vec3,
    /// Unit right vector, `forward × up`.
    pub right: Vec3,
    /// Full field of view in degrees along `fov_axis`.
    pub fov_deg: f32,
    pub fov_axis: FovAxis,
    /// Lens radius in world units; 0 is a pinhole.
    pub aperture_radius: f32,
    /// Distance of the plane in focus along `forward`.
    pub focus_distance: f32,
    /// Shutter open and close times; ray time t in [0, 1] maps linearly onto it.
    pub shutter: [f32; 2],
}

impl Default for Camera {
    fn default() -> Self {
        Camera::look_at(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y, 40.0, FovAxis::Y)
    }
}

impl Camera {
    pub fn look_at(position: Vec3, target: Vec3, up: Vec3, fov_deg: f32, fov_axis: FovAxis) -> Camera {
        // Scale-free: a camera 3e19 from its target still has a direction.
        let forward = shading::normalize_any_scale(target - position);
        let right = shading::normalize_any_scale(forward.cross(up));
        let up = right.cross(forward);
        // The length overflows past about 1.8e19; the projection on `forward` does not.
        let focus_distance = Some((target - position).length())
            .filter(|d| d.is_finite())
            .unwrap_or_else(|| (target - position).dot(forward));
        Camera {
            position,
            forward,
            up,
            right,
            fov_deg,
            fov_axis,
            aperture_radius: 0.0,
            focus_distance: focus_distance.max(f32::MIN_POSITIVE),
            shutter: [0.0, 1.0],
        }
    }

    /// A camera on the +z side of `bounds` looking along -z, far enough that the bounding
    /// sphere fits the field of view on the shorter image side.
    pub fn framing(bounds: &(Vec3, Vec3), _aspect: f32) -> Camera {
        let (lo, hi) = *bounds;
        let centre = 0.5 * (lo + hi);
        // Any positive size frames (a scene 1e-6 across included); an empty or point scene
        // gets a unit radius.
        let radius = Some(0.5 * (hi - lo).length()).filter(|r| *r > 0.0 && r.is_finite()).unwrap_or(1.0);
        let fov: f32 = 40.0;
        let distance = radius / (0.5 * fov.to_radians()).sin();
        Camera::look_at(centre + Vec3::new(0.0, 0.0, distance), centre, Vec3::Y, fov, FovAxis::Smaller)
    }

    pub fn has_lens(&self) -> bool {
        self.aperture_radius > 0.0
    }

    pub fn validate(&self, source: &Path) -> Result<(), SceneError> {
        let finite = self.position.is_finite() && self.forward.is_finite() && self.up.is_finite();
        if !finite || self.forward.length_squared() < 0.5 || self.right.length_squared() < 0.5 {
            return Err(SceneError::new(
                source,
                "camera",
                "position, look_at and up must be finite, distinct, and up must not be parallel to the view direction",
            ));
        }
        if !(self.fov_deg > 0.0 && self.fov_deg < 180.0) {
            return Err(SceneError::new(source, "camera.fov", "must be in (0, 180) degrees"));
        }
        if !(self.aperture_radius >= 0.0 && self.aperture_radius.is_finite()) {
            return Err(SceneError::new(source, "camera.aperture_radius", "must be finite and >= 0"));
        }
        if !(self.focus_distance > 0.0 && self.focus_distance.is_finite()) {
            return Err(SceneError::new(source, "camera.focus_distance", "must be finite and > 0"));
        }
        if !(self.shutter[0].is_finite() && self.shutter[1].is_finite() && self.shutter[0] <= self.shutter[1]) {
            return Err(SceneError::new(source, "camera.shutter", "must be finite with open <= close"));
        }
        Ok(())
    }

    /// tan of half the field of view along x and y for an image of the given size.
    pub fn tan_half_fov(&self, width: u32, height: u32) -> Vec2 {
        let t = (0.5 * self.fov_deg.to_radians()).tan();
        let (w, h) = (width.max(1) as f32, height.max(1) as f32);
        let along_x = match self.fov_axis {
            FovAxis::X => true,
            FovAxis::Y => false,
            FovAxis::Smaller => w <= h,
            FovAxis::Larger => w > h,
        };
        if along_x {
            Vec2::new(t, t * h / w)
        } else {
            Vec2::new(t * w / h, t)
        }
    }

    /// Primary ray through film position `film` (pixels, origin top-left) and `lens` (a point
    /// on the unit disk). Returns origin and unit direction.
    pub fn generate_ray(&self, film: Vec2, lens: Vec2, width: u32, height: u32) -> (Vec3, Vec3) {
        self.generate_ray_with_tan(self.tan_half_fov(width, height), film, lens, width, height)
    }

    /// `generate_ray` with `tan_half_fov(width, height)` computed by the caller once per image.
    #[inline]
    pub fn generate_ray_with_tan(&self, tan: Vec2, film: Vec2, lens: Vec2, width: u32, height: u32) -> (Vec3, Vec3) {
        let ndc_x = 2.0 * film.x / width as f32 - 1.0;
        let ndc_y = 1.0 - 2.0 * film.y / height as f32;
        let pinhole_dir = self.forward + self.right * (ndc_x * tan.x) + self.up * (ndc_y * tan.y);
        if self.aperture_radius <= 0.0 {
            return (self.position, pinhole_dir.normalize());
        }
        let focus_point = self.position + pinhole_dir * self.focus_distance;
        let origin = self.position + (self.right * lens.x + self.up * lens.y) * self.aperture_radius;
        (origin, (focus_point - origin).normalize())
    }

    /// Camera-space depth (distance along `forward`) of a world-space point.
    pub fn depth(&self, p: Vec3) -> f32 {
        (p - self.position).dot(self.forward)
    }

    /// Camera space of the sample files: X along `right` (image +x), Y along `-up` (image +y,
    /// downwards), Z along `forward` (depth); right-handed, origin at the lens centre.
    pub fn to_camera_space(&self, p: Vec3) -> Vec3 {
        self.vector_to_camera_space(p - self.position)
    }

    pub fn vector_to_camera_space(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.right), -v.dot(self.up), v.dot(self.forward))
    }

    /// Focal lengths (fx, fy) and principal point (cx, cy) in pixels: a camera-space point
    /// (X, Y, Z) seen from the lens centre lands on pixel (cx + fx X/Z, cy + fy Y/Z).
    pub fn pixel_projection(&self, width: u32, height: u32) -> (Vec2, Vec2) {
        let tan = self.tan_half_fov(width, height);
        let focal = Vec2::new(width as f32 / (2.0 * tan.x), height as f32 / (2.0 * tan.y));
        (focal, Vec2::new(width as f32 / 2.0, height as f32 / 2.0))
    }

    /// Constants (C1, C2) of the signed circle of confusion C(z) = C1/z + C2 in pixels: a point
    /// at depth z seen through lens position (u, v) (unit disk, u along image +x, v along image
    /// +y) appears shifted by (u, v)·C(z) from where the lens centre sees it. Zero without a lens.
    pub fn circle_of_confusion(&self, width: u32, height: u32) -> (f32, f32) {
        let (focal, _) = self.pixel_projection(width, height);
        let a = self.aperture_radius;
        (-focal.x * a, focal.x * a / self.focus_distance)
    }

    /// Film position (pixels) at which the ray through lens position `lens` (unit disk, as
    /// passed to `generate_ray`) sees the world point `p`; `None` behind the lens.
    pub fn project(&self, p: Vec3, lens: Vec2, width: u32, height: u32) -> Option<Vec2> {
        let (focal, centre) = self.pixel_projection(width, height);
        let point = self.to_camera_space(p);
        if !(point.z > 0.0) {
            return None;
        }
        // Lens point in camera space (v runs along -up, i.e. +Y).
        let lens_point = Vec3::new(self.aperture_radius * lens.x, -self.aperture_radius * lens.y, 0.0);
        let on_focus_plane = lens_point + (point - lens_point) * (self.focus_distance / point.z);
        Some(centre + focal * Vec2::new(on_focus_plane.x, on_focus_plane.y) / self.focus_distance)
    }
}

pub use shading::concentric_disk;

/// The camera coordinates of one sample.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CameraSample {
    /// Film position in pixels (origin top-left).
    pub film: Vec2,
    /// Position on the unit lens disk (zero for a pinhole).
    pub lens: Vec2,
    /// Time in [0, 1] over the shutter (zero without motion).
    pub time: f32,
}

/// ∂z/∂x and ∂z/∂y at the hit: depths where the rays through film ± half a pixel (same lens
/// point) meet the hit's tangent plane. Clamped to |∂z| ≤ z per pixel so grazing surfaces stay
/// finite.
pub fn depth_gradient(
    camera: &Camera,
    sample: &CameraSample,
    hit: Vec3,
    normal: Vec3,
    width: u32,
    height: u32,
) -> Vec2 {
    let depth = camera.depth(hit);
    let depth_at = |film: Vec2| -> Option<f32> {
        let (origin, direction) = camera.generate_ray(film, sample.lens, width, height);
        let denominator = normal.dot(direction);
        if denominator.abs() < 1e-8 {
            return None;
        }
        let t = normal.dot(hit - origin) / denominator;
        (t > 0.0 && t.is_finite()).then(|| camera.depth(origin + direction * t))
    };
    let limit = depth.abs();
    let derivative = |offset: Vec2| -> f32 {
        match (depth_at(sample.film + offset * 0.5), depth_at(sample.film - offset * 0.5)) {
            (Some(a), Some(b)) => (a - b).clamp(-limit, limit),
            _ => 0.0,
        }
    };
    Vec2::new(derivative(Vec2::X), derivative(Vec2::Y))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centre_pixel_looks_forward_and_corners_span_the_fov() {
        let cam = Camera::look_at(Vec3::ZERO, Vec3::new(0.0, 0.0, 1.0), Vec3::Y, 90.0, FovAxis::Y);
        let (_, d) = cam.generate_ray(Vec2::new(50.0, 50.0), Vec2::ZERO, 100, 100);
        assert!((d - Vec3::Z).length() < 1e-6);
        // Top edge centre: 45 degrees up.
        let (_, d) = cam.generate_ray(Vec2::new(50.0, 0.0), Vec2::ZERO, 100, 100);
        assert!((d.y - std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-6);
        // Image right is forward x up = -x for a camera looking down +z.
        let (_, d) = cam.generate_ray(Vec2::new(100.0, 50.0), Vec2::ZERO, 100, 100);
        assert!(d.x < -0.7);
    }

    #[test]
    fn smaller_axis_fov_applies_to_the_short_side() {
        let cam = Camera::look_at(Vec3::ZERO, Vec3::Z, Vec3::Y, 60.0, FovAxis::Smaller);
        let wide = cam.tan_half_fov(200, 100);
        let tall = cam.tan_half_fov(100, 200);
        let t = (30f32).to_radians().tan();
        assert!((wide.y - t).abs() < 1e-6 && (wide.x - 2.0 * t).abs() < 1e-6);
        assert!((tall.x - t).abs() < 1e-6 && (tall.y - 2.0 * t).abs() < 1e-6);
    }

    #[test]
    fn thin_lens_rays_converge_on_the_focus_plane() {
        let mut cam = Camera::look_at(Vec3::ZERO, Vec3::Z, Vec3::Y, 40.0, FovAxis::Y);
        cam.aperture_radius = 0.5;
        cam.focus_distance = 3.0;
        let film = Vec2::new(30.0, 70.0);
        let (o1, d1) = cam.generate_ray(film, Vec2::new(0.9, 0.0), 100, 100);
        let (o2, d2) = cam.generate_ray(film, Vec2::new(-0.3, -0.6), 100, 100);
        let p1 = o1 + d1 * ((3.0 - o1.z) / d1.z);
        let p2 = o2 + d2 * ((3.0 - o2.z) / d2.z);
        assert!((p1 - p2).length() < 1e-5, "{p1} vs {p2}");
    }

    #[test]
    fn projection_inverts_ray_generation_and_coc_is_the_lens_derivative() {
        let mut cam = Camera::look_at(Vec3::new(1.0, 2.0, 3.0), Vec3::new(0.0, 1.0, -4.0), Vec3::Y, 50.0, FovAxis::X);
        cam.aperture_radius = 0.2;
        cam.focus_distance = 4.0;
        let (w, h) = (120, 80);
        let p = Vec3::new(-0.5, 0.7, -6.0);
        let z = cam.depth(p);
        for lens in [Vec2::ZERO, Vec2::new(0.5, -0.3), Vec2::new(-0.9, 0.1)] {
            let film = cam.project(p, lens, w, h).unwrap();
            // The ray through that film position and lens point passes through p.
            let (o, d) = cam.generate_ray(film, lens, w, h);
            let closest = o + d * (p - o).dot(d);
            assert!((closest - p).length() < 1e-4, "{closest} vs {p}");
        }
        // x(u) - x(0) = u C(z) and y(v) - y(0) = v C(z) with v along image +y (= -lens.y).
        let (c1, c2) = cam.circle_of_confusion(w, h);
        let coc = c1 / z + c2;
        let centre = cam.project(p, Vec2::ZERO, w, h).unwrap();
        let shifted = cam.project(p, Vec2::new(0.6, -0.4), w, h).unwrap();
        assert!((shifted.x - centre.x - 0.6 * coc).abs() < 1e-3, "{} vs {}", shifted.x - centre.x, 0.6 * coc);
        assert!((shifted.y - centre.y - 0.4 * coc).abs() < 1e-3);
        // In focus: no shift.
        let focused = cam.position + cam.forward * 4.0 + cam.right * 0.3;
        let a = cam.project(focused, Vec2::ZERO, w, h).unwrap();
        let b = cam.project(focused, Vec2::new(0.9, 0.2), w, h).unwrap();
        assert!((a - b).length() < 1e-3);
        assert!((c1 / 4.0 + c2).abs() < 1e-4);
    }

    #[test]
    fn depth_gradient_of_a_fronto_parallel_plane_is_zero_and_of_a_tilted_plane_matches_finite_differences() {
        let camera = Camera::look_at(Vec3::ZERO, Vec3::Z, Vec3::Y, 60.0, FovAxis::Y);
        let sample = CameraSample { film: Vec2::new(20.0, 12.0), lens: Vec2::ZERO, time: 0.0 };
        let (o, d) = camera.generate_ray(sample.film, sample.lens, 40, 30);
        let flat_hit = o + d * (5.0 / d.z);
        let g = depth_gradient(&camera, &sample, flat_hit, -Vec3::Z, 40, 30);
        assert!(g.length() < 1e-5, "{g}");

        // Plane through (0, 0, 5) tilted about the y axis: z = 5 + 0.5 X.
        let normal = Vec3::new(-0.5, 0.0, 1.0).normalize();
        let depth_of = |film: Vec2| {
            let (o, d) = camera.generate_ray(film, Vec2::ZERO, 40, 30);
            let t = normal.dot(Vec3::new(0.0, 0.0, 5.0) - o) / normal.dot(d);
            (o + d * t).z
        };
        let hit = {
            let (o, d) = camera.generate_ray(sample.film, Vec2::ZERO, 40, 30);
            o + d * (normal.dot(Vec3::new(0.0, 0.0, 5.0) - o) / normal.dot(d))
        };
        let g = depth_gradient(&camera, &sample, hit, -normal, 40, 30);
        let expected_x = depth_of(sample.film + Vec2::new(0.01, 0.0)) - depth_of(sample.film - Vec2::new(0.01, 0.0));
        assert!(
            (g.x - expected_x / 0.02).abs() < 1e-2 * expected_x.abs() / 0.02 + 1e-4,
            "{} vs {}",
            g.x,
            expected_x / 0.02
        );
        assert!(g.y.abs() < 1e-4);
    }
}
