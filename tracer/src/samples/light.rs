//! `light` samples for soft shadows in the temporal light field reconstruction (Lehtinen et al.
//! 2011, Section 5 and Appendix B).
//!
//! The planar area light is parameterised by two parallel planes: the light's own plane, where
//! (l_u, l_v) ∈ [0, 1]² address its bounding rectangle (`corner + l_u·edge_u + l_v·edge_v`), and a
//! plane Π at light-space depth d (`plane_distance`) where a ray's direction is encoded by the
//! point (l_x, l_y) it crosses (scene units along `edge_u` and `edge_v` from the corner's
//! projection). Light-space depth is the distance from the light's plane along its emitting
//! normal. For every camera sample (the same x, y, u, v, t as the `lens-time` sample of the same
//! seed and index) the tracer finds the visible point p, draws a point on the light, and casts
//! the ray from the light towards p. Fields, in record order:
//!
//! | field | components | present | meaning |
//! |---|---|---|---|
//! | `lu`, `lv` | 1 each | always | point on the light, [0, 1]² over its bounding rectangle |
//! | `lx`, `ly` | 1 each | always | where the ray crosses Π, scene units |
//! | `t` | 1 | motion | time in [0, 1] |
//! | `z` | 1 | always | light-space depth of the first surface the ray hits (p itself when nothing blocks it) |
//! | `radiance` | 3 | always | radiance the ray carries from the light (0 where the point lies outside the emitter or p is behind the light) |
//! | `density` | 1 | always | ρ = sqrt(\|det ∂(l_x, l_y)/∂(x, y)\|), scene units per pixel; 0 marks a sample without a visible point |
//! | `motion` | 3 | motion | light-space displacement (along edge_u, edge_v, normal) of the hit over the shutter |
//!
//! ρ follows Appendix B: the surface at p is linearised with the camera sample's depth gradient,
//! and (l_x, l_y) is its projection from the centre of the light (a point light) seen through a
//! pinhole camera, as the paper does.

use glam::{Mat3, Vec2, Vec3};
use sampleio::{FieldSpec, FieldType, HeaderSpec, LightGeometry, SampleKind};

use super::{camera_header, write_samples, DumpReport, DumpTarget, FieldSelection};
use crate::accel::Accel;
use crate::camera::{depth_gradient, Camera, CameraSample};
use crate::error::RenderError;
use crate::integrator::{PathStart, SurfacePoint};
use crate::lights::{triangle_at, LightSampler};
use crate::render::RenderSettings;
use crate::sampler::Sampler;
use crate::scene::Scene;

/// A planar area light and its two-plane parameterisation.
#[derive(Clone, Debug, PartialEq)]
pub struct PlanarLight {
    pub mesh: u32,
    pub corner: Vec3,
    pub edge_u: Vec3,
    pub edge_v: Vec3,
    /// Unit normal of the emitting side.
    pub normal: Vec3,
    /// Light-space depth of the plane Π.
    pub plane_distance: f32,
    /// World-space motion of the light over the shutter.
    pub motion: Vec3,
}

impl PlanarLight {
    /// The emissive mesh of largest power; it must be planar.
    pub fn find(scene: &Scene) -> Result<PlanarLight, RenderError> {
        let power = |mi: usize| -> f32 {
            let mesh = &scene.meshes[mi];
            let material = &scene.materials[mesh.material as usize];
            let area: f32 = (0..mesh.indices.len()).map(|t| mesh.triangle_area(t)).sum();
            crate::bsdf::luminance(material.emission) * area
        };
        let mesh_index = (0..scene.meshes.len())
            .filter(|&mi| scene.materials[scene.meshes[mi].material as usize].is_emissive())
            .max_by(|&a, &b| power(a).total_cmp(&power(b)))
            .ok_or_else(|| {
                RenderError::Settings(format!("{}: light samples need an emissive mesh", scene.source.display()))
            })?;
        let mesh = &scene.meshes[mesh_index];
        let [a, b, c] = triangle_at(scene, mesh_index as u32, 0, 0.0);
        let normal = shading::triangle_normal_and_area(a, b, c).0;
        let edge = (b - a).normalize();
        let other = normal.cross(edge);
        let (mut lo, mut hi) = (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY));
        let mut off_plane = 0.0f32;
        for &p in &mesh.positions {
            let d = p - a;
            let q = Vec2::new(d.dot(edge), d.dot(other));
            lo = lo.min(q);
            hi = hi.max(q);
            off_plane = off_plane.max(d.dot(normal).abs());
        }
        let size = (hi - lo).max_element();
        if !(size > 0.0) || off_plane > 1e-4 * size {
            return Err(RenderError::Settings(format!(
                "{}: the light '{}' is not planar (vertices {off_plane} off its plane); light samples need a planar area light",
                scene.source.display(),
                mesh.name
            )));
        }
        Ok(PlanarLight {
            mesh: mesh_index as u32,
            corner: a + edge * lo.x + other * lo.y,
            edge_u: edge * (hi.x - lo.x),
            edge_v: other * (hi.y - lo.y),
            normal,
            plane_distance: size,
            motion: mesh.motion,
        })
    }

    /// Light-space depth of a world point at time `time`.
    pub fn depth(&self, p: Vec3, time: f32) -> f32 {
        (p - self.corner - self.motion * time).dot(self.normal)
    }

    /// World point at (l_u, l_v).
    pub fn point(&self, lu: f32, lv: f32, time: f32) -> Vec3 {
        self.corner + self.edge_u * lu + self.edge_v * lv + self.motion * time
    }

    /// (l_x, l_y) of the ray from `from` (on the light) through `towards`.
    pub fn plane_coordinates(&self, from: Vec3, towards: Vec3, time: f32) -> Option<Vec2> {
        let direction = towards - from;
        let along = direction.dot(self.normal);
        if !(along > 0.0) {
            return None;
        }
        let on_plane = from + direction * ((self.plane_distance - self.depth(from, time)) / along);
        let rel = on_plane - self.corner - self.motion * time;
        Some(Vec2::new(rel.dot(self.edge_u.normalize()), rel.dot(self.edge_v.normalize())))
    }

    pub fn header(&self) -> LightGeometry {
        let f = |v: Vec3| [v.x as f64, v.y as f64, v.z as f64];
        LightGeometry {
            corner: Some(f(self.corner)),
            edge_u: Some(f(self.edge_u)),
            edge_v: Some(f(self.edge_v)),
            normal: Some(f(self.normal)),
            plane_distance: Some(self.plane_distance as f64),
        }
    }
}

/// ρ = sqrt(|det J|), J = ∂(l_x, l_y)/∂(x, y) (Appendix B): the surface through `point`
/// linearised with the depth gradient, projected from the light's centre, seen by a pinhole.
pub fn view_light_density(
    camera: &Camera,
    light: &PlanarLight,
    film: Vec2,
    depth: f32,
    gradient: Vec2,
    (width, height): (u32, u32),
    time: f32,
) -> f32 {
    let (focal, centre) = camera.pixel_projection(width, height);
    let k = Vec3::new((film.x - centre.x) / focal.x, (film.y - centre.y) / focal.y, 1.0);
    // Camera space to world: columns right, down, forward.
    let to_world = Mat3::from_cols(camera.right, -camera.up, camera.forward);
    let point = camera.position + to_world * (k * depth);
    let d_point_dx = to_world * (k * gradient.x + Vec3::new(depth / focal.x, 0.0, 0.0));
    let d_point_dy = to_world * (k * gradient.y + Vec3::new(0.0, depth / focal.y, 0.0));
    let light_centre = light.point(0.5, 0.5, time);
    let rel = point - light_centre;
    let s = rel.dot(light.normal);
    if !(s > 0.0) {
        return 0.0;
    }
    // f(P) = c + (P - c) d / s: ∂f/∂P · v = d/s (v - (P - c)(n·v)/s).
    let project = |v: Vec3| (v - rel * (light.normal.dot(v) / s)) * (light.plane_distance / s);
    let (eu, ev) = (light.edge_u.normalize(), light.edge_v.normalize());
    let (dx, dy) = (project(d_point_dx), project(d_point_dy));
    let det = dx.dot(eu) * dy.dot(ev) - dx.dot(ev) * dy.dot(eu);
    let rho = det.abs().sqrt();
    if rho.is_finite() {
        rho
    } else {
        0.0
    }
}

/// Writes `light` samples of `scene` to `path`, the fields `fields` selects.
pub fn dump<'a>(
    scene: &Scene,
    accel: &Accel,
    settings: &RenderSettings,
    fields: &FieldSelection,
    target: impl Into<DumpTarget<'a>>,
) -> Result<DumpReport, RenderError> {
    settings.validate()?;
    let light = PlanarLight::find(scene)?;
    let emission = scene.materials[scene.meshes[light.mesh as usize].material as usize].emission;
    let time_field = scene.has_motion();
    let lights = LightSampler::new(scene);
    let integrator = super::integrator(scene, accel, &lights, settings);
    let f = |name: &str, n: u32, unit: &str, meaning: &str| {
        FieldSpec::new(name, FieldType::F32, n).unit(unit).meaning(meaning)
    };
    let mut spec = HeaderSpec::new(SampleKind::Light, settings.width, settings.height, settings.spp)
        .field(f("lu", 1, "light rectangle", "point on the light along edge_u, [0, 1]"))
        .field(f("lv", 1, "light rectangle", "point on the light along edge_v, [0, 1]"))
        .field(f("lx", 1, "scene units", "ray crossing of plane Pi along edge_u"))
        .field(f("ly", 1, "scene units", "ray crossing of plane Pi along edge_v"));
    if time_field {
        spec = spec.field(f("t", 1, "shutter fraction", "time in [0, 1]"));
    }
    spec = spec
        .field(f("z", 1, "scene units", "light-space depth of the first hit from the light"))
        .field(f("radiance", 3, "W/(m^2 sr)", "radiance carried from the light"))
        .field(f("density", 1, "scene units/px", "sqrt |det d(lx, ly)/d(x, y)|; 0 = no visible point"));
    if time_field {
        spec = spec.field(f("motion", 3, "scene units", "light-space displacement of the hit over the shutter"));
    }
    spec.camera = Some(camera_header(&scene.camera, settings.width, settings.height));
    spec.light = Some(light.header());
    if light.motion != Vec3::ZERO {
        // Format v1 has no light-motion key; `extra` carries it (world-space displacement of the
        // whole light over the shutter, scene units).
        spec.extra = Some(serde_json::json!({ "light_motion": light.motion.to_array() }));
    }
    spec.scene = Some(scene.source.display().to_string());
    spec.seed = Some(settings.seed);
    let values_per_sample = 4 + time_field as usize + 1 + 3 + 1 + 3 * time_field as usize;
    let light_mesh = &scene.meshes[light.mesh as usize];
    write_samples(target, spec, fields, settings, values_per_sample, |x, y, samples, out| {
        for index in samples {
            let mut sampler = Sampler::new(settings.seed, x, y, index);
            let camera_sample = integrator.camera_sample(x, y, &mut sampler);
            let [lu, lv] = sampler.next_2d();
            let time = camera_sample.time;
            let from = light.point(lu, lv, time);
            out.extend_from_slice(&[lu, lv]);
            let PathStart { origin, direction, .. } = integrator.camera_path_start(&camera_sample);
            let visible = accel.intersect(origin, direction, 0.0, f32::INFINITY, time).map(|hit| {
                let surface =
                    SurfacePoint::new(scene, &hit, -direction, time, integrator.camera_cone().width_at(hit.distance));
                (surface.position, surface.geometric_normal)
            });
            let Some((p, p_normal)) = visible else {
                // No visible point: an inert sample.
                out.extend_from_slice(&[0.0, 0.0]);
                if time_field {
                    out.push(time);
                }
                out.extend_from_slice(&[f32::INFINITY, 0.0, 0.0, 0.0, 0.0]);
                if time_field {
                    out.extend_from_slice(&[0.0; 3]);
                }
                continue;
            };
            let plane = light.plane_coordinates(from, p, time).unwrap_or(Vec2::ZERO);
            out.extend_from_slice(&plane.to_array());
            if time_field {
                out.push(time);
            }
            // The ray from the light towards p and the first surface it meets.
            let to_p = p - from;
            let distance = to_p.length();
            let mut z = light.depth(p, time);
            let mut hit_mesh = None;
            let mut radiance = Vec3::ZERO;
            if light.depth(p, time) > 0.0 && distance > 0.0 {
                let dir = to_p / distance;
                let start = from + light.normal * (1e-5 * light.plane_distance);
                if let Some(hit) = accel.intersect(start, dir, 0.0, distance * (1.0 + 1e-4), time) {
                    let q = start + dir * hit.distance;
                    if hit.mesh != light.mesh {
                        z = light.depth(q, time);
                        hit_mesh = Some(hit.mesh);
                    }
                }
                if point_on_mesh(scene, light_mesh, light.mesh, from, time) {
                    radiance = emission;
                }
            }
            out.push(z);
            out.extend_from_slice(&radiance.to_array());
            let depth = scene.camera.depth(p);
            let pinhole = CameraSample { film: camera_sample.film, lens: Vec2::ZERO, time };
            let gradient = depth_gradient(&scene.camera, &pinhole, p, p_normal, settings.width, settings.height);
            out.push(view_light_density(
                &scene.camera,
                &light,
                camera_sample.film,
                depth,
                gradient,
                (settings.width, settings.height),
                time,
            ));
            if time_field {
                let motion = hit_mesh.map_or(Vec3::ZERO, |m| scene.meshes[m as usize].motion) - light.motion;
                let (eu, ev) = (light.edge_u.normalize(), light.edge_v.normalize());
                out.extend_from_slice(&[motion.dot(eu), motion.dot(ev), motion.dot(light.normal)]);
            }
        }
    })
}

/// Whether `point` (on the light's plane) lies on one of the light mesh's triangles.
fn point_on_mesh(scene: &Scene, mesh: &crate::scene::Mesh, mesh_index: u32, point: Vec3, time: f32) -> bool {
    (0..mesh.indices.len()).any(|t| {
        let [a, b, c] = triangle_at(scene, mesh_index, t as u32, time);
        let (normal, area) = shading::triangle_normal_and_area(a, b, c);
        let inside = |p0: Vec3, p1: Vec3| (p1 - p0).cross(point - p0).dot(normal) >= -2e-6 * area;
        inside(a, b) && inside(b, c) && inside(c, a)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::FovAxis;

    fn square_light() -> PlanarLight {
        PlanarLight {
            mesh: 0,
            corner: Vec3::new(-0.5, 2.0, -0.5),
            edge_u: Vec3::new(1.0, 0.0, 0.0),
            edge_v: Vec3::new(0.0, 0.0, 1.0),
            normal: Vec3::new(0.0, -1.0, 0.0),
            plane_distance: 1.0,
            motion: Vec3::ZERO,
        }
    }

    #[test]
    fn plane_coordinates_are_linear_in_the_light_point_with_the_depth_slope() {
        // Like the circle of confusion: l_x(l_u) = l_u (1 - d/z) + const for a receiver at depth z.
        let light = square_light();
        let receiver = Vec3::new(0.3, 0.0, 0.1); // light-space depth 2
        let a = light.plane_coordinates(light.point(0.0, 0.5, 0.0), receiver, 0.0).unwrap();
        let b = light.plane_coordinates(light.point(1.0, 0.5, 0.0), receiver, 0.0).unwrap();
        assert!(((b.x - a.x) - (1.0 - 1.0 / 2.0)).abs() < 1e-5, "{}", b.x - a.x);
        // A receiver on Π itself sees the same (l_x, l_y) from every light point.
        let on_plane = Vec3::new(0.1, 1.0, 0.2);
        let c = light.plane_coordinates(light.point(0.1, 0.9, 0.0), on_plane, 0.0).unwrap();
        let d = light.plane_coordinates(light.point(0.8, 0.2, 0.0), on_plane, 0.0).unwrap();
        assert!((c - d).length() < 1e-5);
        // Behind the light: no coordinates.
        assert!(light.plane_coordinates(light.point(0.5, 0.5, 0.0), Vec3::new(0.0, 3.0, 0.0), 0.0).is_none());
    }

    #[test]
    fn density_matches_finite_differences_of_the_projection() {
        let light = square_light();
        let camera = Camera::look_at(Vec3::new(0.0, 1.0, -3.0), Vec3::new(0.0, 0.0, 0.5), Vec3::Y, 40.0, FovAxis::Y);
        let (w, h) = (64, 48);
        // Receiver: the plane y = 0.
        let point_at = |film: Vec2| {
            let (o, d) = camera.generate_ray(film, Vec2::ZERO, w, h);
            o + d * (-o.y / d.y)
        };
        let film = Vec2::new(30.0, 30.0);
        let p = point_at(film);
        let sample = CameraSample { film, lens: Vec2::ZERO, time: 0.0 };
        let gradient = depth_gradient(&camera, &sample, p, Vec3::Y, w, h);
        let rho = view_light_density(&camera, &light, film, camera.depth(p), gradient, (w, h), 0.0);
        let centre = light.point(0.5, 0.5, 0.0);
        let l = |film: Vec2| light.plane_coordinates(centre, point_at(film), 0.0).unwrap();
        let e = 0.01;
        let dx = (l(film + Vec2::new(e, 0.0)) - l(film - Vec2::new(e, 0.0))) / (2.0 * e);
        let dy = (l(film + Vec2::new(0.0, e)) - l(film - Vec2::new(0.0, e))) / (2.0 * e);
        let expected = (dx.x * dy.y - dx.y * dy.x).abs().sqrt();
        assert!((rho - expected).abs() < 1e-2 * expected, "{rho} vs {expected}");
        assert!(rho > 0.0);
    }
}
