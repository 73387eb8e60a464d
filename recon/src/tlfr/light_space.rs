//! The planar area light as a second "camera" (paper Section 5, Appendix B): light samples are
//! rays from a point on the light through the plane Π at light-space depth d, so they reproject
//! exactly as camera samples do, with the light's rectangle as the lens.
//!
//! In the `light` file (docs/sample-format.md) a ray leaves the light point at (l_u, l_v) ∈
//! [0, 1]² of the rectangle and crosses Π at (l_x, l_y), scene units along the normalised edges
//! from the corner's projection. With the light-space position of a receiver relative to the
//! rectangle's centre (Q_u, Q_v) and its depth z below the light, the crossing is
//!
//! ```text
//! l_x − a_u/2 = Q_u·d/z + ũ·(a_u/2)·(1 − d/z),   ũ = 2·l_u − 1
//! ```
//!
//! (a_u the rectangle's width). Measured in units of `scale`·(a_u/2) along u and
//! `scale`·(a_v/2) along v, both axes share one thin-lens model: C(z) = c1/z + c2 with
//! c1 = −scale·d, c2 = scale, focal lengths fx = scale·d/(a_u/2), fy = scale·d/(a_v/2) and the
//! principal point at 0 (`LightSpace::lens_model`). `scale` is chosen so one unit is about one
//! pixel's footprint on the receivers (the light samples' median `density`), so the pixel
//! tolerances of SAMESURFACE and the reconstruction radius keep their meaning; the tent and the
//! valid-triangle circles are then circles in these units (ellipses on Π for a non-square light).

use sampleio::SampleFile;

use super::lens::LensModel;
use crate::error::Error;
use crate::vector::{add_scaled, dot, length, sub};

type Vec3 = [f32; 3];

/// The light-space domain (`LightSpace::is_grazing`): directions within atan(1/20) ≈ 2.9° of the
/// light's plane are outside it. The Lambertian term of a receiver there is below 5 % of its
/// value at normal incidence (cos θ_light = z/r < 1/20).
pub const GRAZING_LIMIT: f32 = 20.0;

/// The light's frame, from a `light` file's header.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightSpace {
    pub corner: Vec3,
    /// Unit edge directions and the rectangle's side lengths.
    pub axis_u: Vec3,
    pub axis_v: Vec3,
    pub width_u: f32,
    pub width_v: f32,
    /// Unit normal of the emitting side.
    pub normal: Vec3,
    /// Light-space depth d of the plane Π.
    pub plane_distance: f32,
    /// World-space displacement of the light over the shutter (`extra.light_motion`).
    pub motion: Vec3,
    /// Units per half-width of the rectangle (see the module documentation).
    pub scale: f32,
    /// Subtracted from every screen position so the samples' positions start near 0.
    pub offset: [f32; 2],
}

impl LightSpace {
    /// Reads the header's `light` block (and `extra.light_motion`); the error names the file
    /// and the field.
    pub fn from_file(file: &SampleFile) -> Result<LightSpace, Error> {
        let content = |message: String| Error::sample_content(file.path(), message);
        let header = file.header();
        let light = header.light.as_ref().ok_or_else(|| content("the header has no `light` block".to_string()))?;
        let vector = |name: &str, value: Option<[f64; 3]>| -> Result<Vec3, Error> {
            let v = value.ok_or_else(|| content(format!("the `light` block lacks `{name}`")))?;
            let v = [v[0] as f32, v[1] as f32, v[2] as f32];
            if v.iter().all(|c| c.is_finite()) {
                Ok(v)
            } else {
                Err(content(format!("`light.{name}` is not finite")))
            }
        };
        let corner = vector("corner", light.corner)?;
        let edge_u = vector("edge_u", light.edge_u)?;
        let edge_v = vector("edge_v", light.edge_v)?;
        let normal = vector("normal", light.normal)?;
        let plane_distance =
            light.plane_distance.ok_or_else(|| content("the `light` block lacks `plane_distance`".to_string()))? as f32;
        let (width_u, width_v) = (length(edge_u), length(edge_v));
        if !(width_u > 0.0 && width_v > 0.0 && width_u.is_finite() && width_v.is_finite()) {
            return Err(content("`light.edge_u` and `light.edge_v` must have positive length".to_string()));
        }
        if !(plane_distance > 0.0 && plane_distance.is_finite()) {
            return Err(content(format!("`light.plane_distance` must be positive, got {plane_distance}")));
        }
        if (length(normal) - 1.0).abs() > 1e-3 {
            return Err(content("`light.normal` is not a unit vector".to_string()));
        }
        let motion = match header.extra.as_ref().and_then(|extra| extra.get("light_motion")) {
            None => [0.0; 3],
            Some(value) => {
                let parsed: Option<Vec<f64>> = value.as_array().map(|a| a.iter().filter_map(|c| c.as_f64()).collect());
                match parsed {
                    Some(c) if c.len() == 3 && c.iter().all(|v| v.is_finite()) => {
                        [c[0] as f32, c[1] as f32, c[2] as f32]
                    }
                    _ => return Err(content("`extra.light_motion` must be three finite numbers".to_string())),
                }
            }
        };
        let scale_of = |v: Vec3| v.map(|c| c / length(v));
        Ok(LightSpace {
            corner,
            axis_u: scale_of(edge_u),
            axis_v: scale_of(edge_v),
            width_u,
            width_v,
            normal,
            plane_distance,
            motion,
            scale: 1.0,
            offset: [0.0; 2],
        })
    }

    /// The shared lens model of the light samples in units of `scale`·half-width.
    pub fn lens_model(&self) -> LensModel {
        let d = self.plane_distance;
        LensModel {
            c1: -self.scale * d,
            c2: self.scale,
            fx: self.scale * d / (0.5 * self.width_u),
            fy: self.scale * d / (0.5 * self.width_v),
            cx: 0.0,
            cy: 0.0,
        }
    }

    /// Light-space position of a world point at time `t`: (Q_u, Q_v) relative to the
    /// rectangle's centre and the depth below the light.
    pub fn to_light(&self, world: Vec3, t: f32) -> Vec3 {
        let relative = sub(world, add_scaled(self.corner, self.motion, t));
        [
            dot(relative, self.axis_u) - 0.5 * self.width_u,
            dot(relative, self.axis_v) - 0.5 * self.width_v,
            dot(relative, self.normal),
        ]
    }

    /// World point of the light at lens coordinates (ũ, ṽ) ∈ [−1, 1]² and time `t`.
    pub fn light_point(&self, u: f32, v: f32, t: f32) -> Vec3 {
        let centre = add_scaled(
            add_scaled(add_scaled(self.corner, self.motion, t), self.axis_u, 0.5 * self.width_u),
            self.axis_v,
            0.5 * self.width_v,
        );
        add_scaled(add_scaled(centre, self.axis_u, 0.5 * self.width_u * u), self.axis_v, 0.5 * self.width_v * v)
    }

    /// A file's (l_x, l_y) crossing of Π in this space's units.
    pub fn screen_of_crossing(&self, lx: f32, ly: f32) -> [f32; 2] {
        [
            (lx - 0.5 * self.width_u) * self.scale / (0.5 * self.width_u) - self.offset[0],
            (ly - 0.5 * self.width_v) * self.scale / (0.5 * self.width_v) - self.offset[1],
        ]
    }

    /// Whether a point at light-space `position` (`to_light`) lies outside the light-space
    /// domain: seen from the light's centre within atan(1/`GRAZING_LIMIT`) of the light's plane
    /// (|Q_u| or |Q_v| above `GRAZING_LIMIT`·z), or so close to the plane that the light's
    /// circle of confusion there exceeds `GRAZING_LIMIT` half-widths (z below
    /// d/(`GRAZING_LIMIT` + 1)), or not below the light at all. Screen positions grow like 1/z
    /// towards the plane; bounding them keeps the f32 positions of the samples that matter
    /// exact to far below a filter radius.
    pub fn is_grazing(&self, position: Vec3) -> bool {
        let z = position[2];
        !(z >= self.plane_distance / (GRAZING_LIMIT + 1.0)
            && position[0].abs() <= GRAZING_LIMIT * z
            && position[1].abs() <= GRAZING_LIMIT * z)
    }

    /// The light-space position of the end of the ray that leaves the light at (ũ, ṽ) ∈
    /// [−1, 1]², crosses Π at the file's (l_x, l_y) and ends at light-space depth `z`, in scene
    /// units (not through the screen units, so it is as exact as the file's values).
    pub fn ray_end(&self, u: f32, v: f32, lx: f32, ly: f32, z: f32) -> Vec3 {
        let (half_u, half_v) = (0.5 * self.width_u, 0.5 * self.width_v);
        let along = z / self.plane_distance;
        [(lx - half_u) * along + u * half_u * (1.0 - along), (ly - half_v) * along + v * half_v * (1.0 - along), z]
    }

    /// The lens-centre screen position of a receiver at light-space `position` (`to_light`):
    /// where the ray from the light's centre crosses Π, in this space's units; `None` for a
    /// receiver that is not below the light.
    pub fn centre_screen(&self, position: Vec3) -> Option<[f32; 2]> {
        if position[2].is_nan() || position[2] <= 0.0 {
            return None;
        }
        let model = self.lens_model();
        Some([
            model.fx * position[0] / position[2] - self.offset[0],
            model.fy * position[1] / position[2] - self.offset[1],
        ])
    }
}

/// Octahedral decoding of a `u16 × 2` unit vector (docs/sample-format.md): (0, 0), "none",
/// decodes to the zero vector.
pub fn decode_octahedral(q: [f32; 2]) -> Vec3 {
    crate::octahedral::decode(q).unwrap_or([0.0; 3])
}

/// The direct light a Lambertian receiver at `receiver` (unit `normal`, reflectance `albedo`)
/// reflects from the light point `light_point` (emitting along `light_normal`) of a light of
/// area `area` when the light there sends `radiance` towards it: the one-sample estimate
/// (albedo/π)·L·cosθ_receiver·cosθ_light·A/r² of the light's integral for a light point drawn
/// uniformly over the rectangle. Zero for back-facing configurations.
pub fn lambertian_direct(
    albedo: Vec3,
    normal: Vec3,
    receiver: Vec3,
    light_point: Vec3,
    light_normal: Vec3,
    area: f32,
    radiance: Vec3,
) -> Vec3 {
    let to_light = sub(light_point, receiver);
    let distance_squared = dot(to_light, to_light);
    if distance_squared.is_nan() || distance_squared <= 0.0 || distance_squared.is_infinite() {
        return [0.0; 3];
    }
    let distance = distance_squared.sqrt();
    let cos_receiver = dot(normal, to_light) / distance;
    let cos_light = -dot(light_normal, to_light) / distance;
    if !(cos_receiver > 0.0 && cos_light > 0.0) {
        return [0.0; 3];
    }
    let geometry = cos_receiver * cos_light * area / distance_squared / std::f32::consts::PI;
    [albedo[0] * radiance[0] * geometry, albedo[1] * radiance[1] * geometry, albedo[2] * radiance[2] * geometry]
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A 1 × 0.5 light at y = 2 facing down, Π at depth 1.
    pub(crate) fn light() -> LightSpace {
        LightSpace {
            corner: [-0.5, 2.0, -0.25],
            axis_u: [1.0, 0.0, 0.0],
            axis_v: [0.0, 0.0, 1.0],
            width_u: 1.0,
            width_v: 0.5,
            normal: [0.0, -1.0, 0.0],
            plane_distance: 1.0,
            motion: [0.0; 3],
            scale: 7.0,
            offset: [0.0; 2],
        }
    }

    /// Where the ray from `from` through `towards` crosses Π, as the file writes (l_x, l_y):
    /// by intersecting the plane y = 1 directly.
    fn crossing(from: Vec3, towards: Vec3) -> [f32; 2] {
        let s = (1.0 - from[1]) / (towards[1] - from[1]);
        let on_plane = add_scaled(from, sub(towards, from), s);
        [on_plane[0] + 0.5, on_plane[2] + 0.25]
    }

    #[test]
    fn light_samples_reproject_like_camera_samples() {
        // Eq. 3 with the light's lens model maps the crossing seen from one light point to the
        // crossing seen from another, for receivers at several depths.
        let light = light();
        let model = light.lens_model();
        for receiver in [[0.3, 0.0, 0.1], [-0.2, 1.5, 0.05], [0.05, -3.0, -0.4]] {
            let q = light.to_light(receiver, 0.0);
            let centre = light.centre_screen(q).unwrap();
            for (u, v) in [(-1.0, -1.0), (0.3, -0.7), (1.0, 0.5)] {
                let from = light.light_point(u, v, 0.0);
                let [lx, ly] = crossing(from, receiver);
                let screen = light.screen_of_crossing(lx, ly);
                let coc = model.coc(q[2]);
                let expected = [centre[0] + u * coc, centre[1] + v * coc];
                for axis in 0..2 {
                    assert!(
                        (screen[axis] - expected[axis]).abs() < 1e-3 * (1.0 + expected[axis].abs()),
                        "receiver {receiver:?} light point ({u}, {v}): {screen:?} vs {expected:?}"
                    );
                }
            }
        }
        // A receiver on Π is "in focus": every light point sees it at the same place.
        assert!(model.coc(light.plane_distance).abs() < 1e-6);
    }

    #[test]
    fn ray_ends_and_the_grazing_domain() {
        // `ray_end` of the file's values for a ray from a light point through a receiver gives
        // the receiver's light-space position, as `to_light` does.
        let light = light();
        for receiver in [[0.3, 0.0, 0.1], [-0.9, 1.7, 0.05], [3.0, 1.9, -0.4]] {
            for (u, v) in [(-1.0, -1.0), (0.3, -0.7), (1.0, 0.5)] {
                let [lx, ly] = crossing(light.light_point(u, v, 0.0), receiver);
                let expected = light.to_light(receiver, 0.0);
                let end = light.ray_end(u, v, lx, ly, expected[2]);
                assert!(length(sub(end, expected)) < 1e-5 * (1.0 + length(expected)), "{end:?} vs {expected:?}");
            }
        }
        // Within atan(1/20) of the light's plane, or closer to it than d/21, or above it.
        let d = light.plane_distance;
        assert!(!light.is_grazing([10.0, -10.0, 1.0]) && !light.is_grazing([0.0, 0.0, d / 20.0]));
        assert!(light.is_grazing([25.0, 0.0, 1.0]) && light.is_grazing([0.0, -21.0, 1.0]));
        assert!(light.is_grazing([0.0, 0.0, d / 22.0]) && light.is_grazing([0.0, 0.0, -1.0]));
        assert!(light.is_grazing([0.0, 0.0, f32::NAN]));
    }

    #[test]
    fn light_space_follows_the_moving_light() {
        let mut light = light();
        light.motion = [0.2, 0.0, 0.0];
        let point = [0.0, 0.0, 0.0];
        let early = light.to_light(point, 0.0);
        let late = light.to_light(point, 1.0);
        assert!((early[0] - late[0] - 0.2).abs() < 1e-6 && early[2] == late[2]);
        let centre_late = light.light_point(0.0, 0.0, 1.0);
        assert!((centre_late[0] - 0.2).abs() < 1e-6 && centre_late[1] == 2.0);
        // Behind the light: no screen position.
        assert!(light.centre_screen(light.to_light([0.0, 3.0, 0.0], 0.0)).is_none());
    }

    #[test]
    fn direct_light_matches_the_point_source_limit_and_rejects_back_faces() {
        // A small light straight above a floor point: E = L·A/r², radiance (ρ/π)·E.
        let value =
            lambertian_direct([0.5; 3], [0.0, 1.0, 0.0], [0.0; 3], [0.0, 2.0, 0.0], [0.0, -1.0, 0.0], 0.01, [4.0; 3]);
        let expected = 0.5 / std::f32::consts::PI * 4.0 * 0.01 / 4.0;
        assert!((value[0] - expected).abs() < 1e-7, "{value:?} vs {expected}");
        let below =
            lambertian_direct([0.5; 3], [0.0, -1.0, 0.0], [0.0; 3], [0.0, 2.0, 0.0], [0.0, -1.0, 0.0], 0.01, [4.0; 3]);
        assert_eq!(below, [0.0; 3]);
        let light_facing_away =
            lambertian_direct([0.5; 3], [0.0, 1.0, 0.0], [0.0; 3], [0.0, 2.0, 0.0], [0.0, 1.0, 0.0], 0.01, [4.0; 3]);
        assert_eq!(light_facing_away, [0.0; 3]);
        let coincident =
            lambertian_direct([0.5; 3], [0.0, 1.0, 0.0], [0.0; 3], [0.0; 3], [0.0, -1.0, 0.0], 0.01, [4.0; 3]);
        assert_eq!(coincident, [0.0; 3]);
    }

    #[test]
    fn octahedral_decoding_inverts_the_tracers_encoding() {
        // The encoding of docs/sample-format.md, written out independently here.
        let encode = |n: Vec3| -> [f32; 2] {
            let l1 = n[0].abs() + n[1].abs() + n[2].abs();
            let (mut x, mut y) = (n[0] / l1, n[1] / l1);
            if n[2] < 0.0 {
                let sign = |v: f32| if v >= 0.0 { 1.0 } else { -1.0 };
                (x, y) = ((1.0 - y.abs()) * sign(x), (1.0 - x.abs()) * sign(y));
            }
            [((x * 0.5 + 0.5) * 65534.0).round() + 1.0, ((y * 0.5 + 0.5) * 65534.0).round() + 1.0]
        };
        for n in [[0.0, 1.0, 0.0], [0.6, 0.0, -0.8], [-0.48, 0.6, 0.64], [0.0, 0.0, -1.0]] {
            let back = decode_octahedral(encode(n));
            assert!(length(sub(back, n)) < 1e-3, "{n:?} → {back:?}");
        }
        assert_eq!(decode_octahedral([0.0, 0.0]), [0.0; 3]);
    }
}
