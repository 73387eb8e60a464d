//! Light sampling for next-event estimation.
//!
//! Every emitter (each emissive triangle, each punctual light, the constant environment) is
//! one entry of a table chosen in proportion to an estimate of its emitted power. Emissive
//! triangles are sampled uniformly by area and converted to solid angle; the environment is
//! sampled uniformly over the sphere. `pdf_*` functions give the densities the integrator needs
//! for multiple importance sampling when a BSDF-sampled ray hits an emitter.

use std::f32::consts::PI;

use glam::{Vec2, Vec3};

use crate::bsdf::luminance;
use crate::scene::{PunctualLight, Scene};

#[derive(Clone, Debug)]
enum Emitter {
    Triangle(EmissiveTriangle),
    Punctual(PunctualLight),
    Environment,
}

/// An emissive triangle with what sampling it needs, computed once when the table is built
/// instead of at every shading point: its corner `a` and edges at shutter open, its unit
/// normal (counter-clockwise winding) and area, and its emission when no texture modulates it.
/// Motion is a translation, so only the corner moves with time.
#[derive(Clone, Debug)]
struct EmissiveTriangle {
    mesh: u32,
    triangle: u32,
    corner: Vec3,
    edge_b: Vec3,
    edge_c: Vec3,
    motion: Vec3,
    normal: Vec3,
    area: f32,
    /// Emission towards either side (`two_sided`) or the front side; `None` when a texture
    /// modulates it and `triangle_emission` must look it up.
    constant_emission: Option<Vec3>,
    two_sided: bool,
}

impl EmissiveTriangle {
    fn new(scene: &Scene, mesh: u32, triangle: u32) -> EmissiveTriangle {
        let [a, b, c] = triangle_at(scene, mesh, triangle, 0.0);
        let m = &scene.meshes[mesh as usize];
        let material = &scene.materials[m.material as usize];
        let cross = (b - a).cross(c - a);
        let area = 0.5 * cross.length();
        let textured = material.emission_texture.is_some() && m.uvs.is_some();
        EmissiveTriangle {
            mesh,
            triangle,
            corner: a,
            edge_b: b - a,
            edge_c: c - a,
            motion: m.motion,
            normal: if area > 0.0 { cross / (2.0 * area) } else { Vec3::ZERO },
            area,
            constant_emission: (!textured).then_some(material.emission),
            two_sided: material.two_sided_emission,
        }
    }
}

/// Light arriving at a point from one sampled emitter.
#[derive(Clone, Copy, Debug)]
pub struct LightSample {
    /// Unit direction from the shading point towards the light.
    pub wi: Vec3,
    /// Distance to the light sample (infinite for directional and environment light).
    pub distance: f32,
    /// Incident radiance (or irradiance-like quantity for delta lights) divided by the
    /// solid-angle pdf including the selection probability.
    pub weighted_radiance: Vec3,
    /// Solid-angle pdf including selection; `None` for delta lights (no MIS).
    pub pdf: Option<f32>,
    /// The emissive mesh the point lies on (`None` for punctual and environment light).
    pub mesh: Option<u32>,
}

/// Power-proportional emitter table.
pub struct LightSampler {
    emitters: Vec<Emitter>,
    /// Cumulative selection probabilities (last = 1).
    cdf: Vec<f32>,
    /// Selection probability of each emitter.
    probability: Vec<f32>,
    /// For each mesh, the table index of its first triangle when the mesh emits.
    mesh_offset: Vec<Option<u32>>,
    environment_index: Option<u32>,
}

/// Barycentric interpolation helper: the triangle's vertices at ray time `time`.
pub fn triangle_at(scene: &Scene, mesh: u32, triangle: u32, time: f32) -> [Vec3; 3] {
    let m = &scene.meshes[mesh as usize];
    let [a, b, c] = m.indices[triangle as usize];
    let shift = m.motion * time;
    [m.positions[a as usize] + shift, m.positions[b as usize] + shift, m.positions[c as usize] + shift]
}

/// Emitted radiance of a mesh triangle at barycentrics (u, v) towards `wo` (unit, pointing away
/// from the surface); `geometric_normal` follows the triangle's winding.
pub fn triangle_emission(
    scene: &Scene,
    mesh: u32,
    triangle: u32,
    bary: Vec2,
    geometric_normal: Vec3,
    wo: Vec3,
) -> Vec3 {
    let m = &scene.meshes[mesh as usize];
    let material = &scene.materials[m.material as usize];
    if !material.is_emissive() {
        return Vec3::ZERO;
    }
    if !material.two_sided_emission && geometric_normal.dot(wo) <= 0.0 {
        return Vec3::ZERO;
    }
    let mut emission = material.emission;
    if let (Some(tex), Some(uvs)) = (&material.emission_texture, &m.uvs) {
        let [a, b, c] = m.indices[triangle as usize];
        let uv = uvs[a as usize] * (1.0 - bary.x - bary.y) + uvs[b as usize] * bary.x + uvs[c as usize] * bary.y;
        let texel = scene.textures[tex.index as usize].sample(tex.apply(uv));
        emission *= texel.truncate();
    }
    emission
}

impl LightSampler {
    pub fn new(scene: &Scene) -> LightSampler {
        let (lo, hi) = scene.bounds();
        let radius = (0.5 * (hi - lo).length()).max(1e-3);
        let mut emitters = Vec::new();
        let mut power = Vec::new();
        let mut mesh_offset = vec![None; scene.meshes.len()];
        for (mi, mesh) in scene.meshes.iter().enumerate() {
            let material = &scene.materials[mesh.material as usize];
            if !material.is_emissive() {
                continue;
            }
            mesh_offset[mi] = Some(emitters.len() as u32);
            let sides = if material.two_sided_emission { 2.0 } else { 1.0 };
            let lum = luminance(material.emission);
            for t in 0..mesh.indices.len() {
                let emitter = EmissiveTriangle::new(scene, mi as u32, t as u32);
                power.push(lum * emitter.area * PI * sides);
                emitters.push(Emitter::Triangle(emitter));
            }
        }
        for light in &scene.lights {
            let p = match light {
                PunctualLight::Point { intensity, .. } => 4.0 * PI * luminance(*intensity),
                PunctualLight::Spot { intensity, inner_cone, outer_cone, .. } => {
                    2.0 * PI * (1.0 - (0.5 * (inner_cone + outer_cone)).cos()) * luminance(*intensity)
                }
                PunctualLight::Directional { irradiance, .. } => PI * radius * radius * luminance(*irradiance),
            };
            emitters.push(Emitter::Punctual(light.clone()));
            power.push(p);
        }
        let mut environment_index = None;
        if scene.environment.max_element() > 0.0 {
            environment_index = Some(emitters.len() as u32);
            emitters.push(Emitter::Environment);
            power.push(PI * 4.0 * PI * radius * radius * luminance(scene.environment));
        }
        // Emitters with zero luminance but some colour still need a chance.
        for (p, e) in power.iter_mut().zip(&emitters) {
            if !(*p > 0.0) || !p.is_finite() {
                *p = match e {
                    Emitter::Triangle(_) => 1e-6,
                    _ => 1e-3,
                };
            }
        }
        let total: f64 = power.iter().map(|&p| p as f64).sum();
        let mut cdf = Vec::with_capacity(power.len());
        let mut probability = Vec::with_capacity(power.len());
        let mut running = 0.0f64;
        for &p in &power {
            running += p as f64;
            cdf.push((running / total) as f32);
            probability.push((p as f64 / total) as f32);
        }
        if let Some(last) = cdf.last_mut() {
            *last = 1.0;
        }
        LightSampler { emitters, cdf, probability, mesh_offset, environment_index }
    }

    pub fn is_empty(&self) -> bool {
        self.emitters.is_empty()
    }

    /// Samples one emitter and a point on it as seen from `point` at ray time `time`.
    pub fn sample(&self, scene: &Scene, point: Vec3, time: f32, u_select: f32, u: [f32; 2]) -> Option<LightSample> {
        if self.emitters.is_empty() {
            return None;
        }
        let index = self.cdf.partition_point(|&c| c <= u_select).min(self.emitters.len() - 1);
        let select = self.probability[index];
        match &self.emitters[index] {
            Emitter::Triangle(emitter) => {
                if !(emitter.area > 0.0) {
                    return None;
                }
                // Uniform point on the triangle; (b1, b2) are Embree's (u, v) barycentrics.
                let su = u[0].sqrt();
                let b1 = u[1] * su;
                let b2 = su - b1;
                let p = emitter.corner + emitter.motion * time + emitter.edge_b * b1 + emitter.edge_c * b2;
                let to_light = p - point;
                let dist2 = to_light.length_squared();
                if !(dist2 > 0.0) {
                    return None;
                }
                let distance = dist2.sqrt();
                let wi = to_light / distance;
                let cos_signed = emitter.normal.dot(-wi);
                let cos_light = cos_signed.abs();
                if cos_light <= 1e-7 {
                    return None;
                }
                let le = match emitter.constant_emission {
                    Some(emission) if emitter.two_sided || cos_signed > 0.0 => emission,
                    Some(_) => return None,
                    None => {
                        triangle_emission(scene, emitter.mesh, emitter.triangle, Vec2::new(b1, b2), emitter.normal, -wi)
                    }
                };
                if le == Vec3::ZERO {
                    return None;
                }
                let pdf = select * dist2 / (emitter.area * cos_light);
                Some(LightSample {
                    wi,
                    distance,
                    weighted_radiance: le / pdf,
                    pdf: Some(pdf),
                    mesh: Some(emitter.mesh),
                })
            }
            Emitter::Punctual(light) => {
                let (wi, distance, radiance) = punctual_incident(light, point)?;
                Some(LightSample { wi, distance, weighted_radiance: radiance / select, pdf: None, mesh: None })
            }
            Emitter::Environment => {
                let z = 1.0 - 2.0 * u[0];
                let r = (1.0 - z * z).max(0.0).sqrt();
                let phi = 2.0 * PI * u[1];
                let wi = Vec3::new(r * phi.cos(), r * phi.sin(), z);
                let pdf = select / (4.0 * PI);
                Some(LightSample {
                    wi,
                    distance: f32::INFINITY,
                    weighted_radiance: scene.environment / pdf,
                    pdf: Some(pdf),
                    mesh: None,
                })
            }
        }
    }

    /// Solid-angle pdf with which `sample` would have chosen the point `hit` on a mesh
    /// triangle, seen from `from`.
    pub fn pdf_triangle(&self, mesh: u32, triangle: u32, from: Vec3, hit: Vec3) -> f32 {
        let Some(offset) = self.mesh_offset.get(mesh as usize).copied().flatten() else {
            return 0.0;
        };
        let index = (offset + triangle) as usize;
        let Some(Emitter::Triangle(emitter)) = self.emitters.get(index) else {
            return 0.0;
        };
        let to_light = hit - from;
        let dist2 = to_light.length_squared();
        if !(emitter.area > 0.0) || !(dist2 > 0.0) {
            return 0.0;
        }
        let cos_light = emitter.normal.dot(to_light / dist2.sqrt()).abs();
        if cos_light <= 1e-7 {
            return 0.0;
        }
        self.probability[index] * dist2 / (emitter.area * cos_light)
    }

    /// Solid-angle pdf of sampling the environment in any direction.
    pub fn pdf_environment(&self) -> f32 {
        match self.environment_index {
            Some(i) => self.probability[i as usize] / (4.0 * PI),
            None => 0.0,
        }
    }
}

/// Direction, distance and incident radiance-times-solid-angle of a punctual light at `point`.
fn punctual_incident(light: &PunctualLight, point: Vec3) -> Option<(Vec3, f32, Vec3)> {
    match light {
        PunctualLight::Point { position, intensity } => {
            let d = *position - point;
            let dist2 = d.length_squared();
            if !(dist2 > 0.0) {
                return None;
            }
            let distance = dist2.sqrt();
            Some((d / distance, distance, *intensity / dist2))
        }
        PunctualLight::Spot { position, direction, intensity, inner_cone, outer_cone } => {
            let d = *position - point;
            let dist2 = d.length_squared();
            if !(dist2 > 0.0) {
                return None;
            }
            let distance = dist2.sqrt();
            let wi = d / distance;
            let cos_angle = (-wi).dot(direction.normalize());
            let (cos_inner, cos_outer) = (inner_cone.cos(), outer_cone.cos());
            let falloff = if cos_angle >= cos_inner {
                1.0
            } else if cos_angle <= cos_outer {
                0.0
            } else {
                let x = (cos_angle - cos_outer) / (cos_inner - cos_outer).max(1e-6);
                x * x
            };
            if falloff <= 0.0 {
                return None;
            }
            Some((wi, distance, *intensity * falloff / dist2))
        }
        PunctualLight::Directional { direction, irradiance } => {
            Some((-direction.normalize(), f32::INFINITY, *irradiance))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::shapes::polygon;
    use crate::scene::Material;

    /// A scene whose only emitter is the unit square at height 1 above the origin, spanning
    /// [-0.5, 0.5]² and facing down (-z), plus a second, dim emitter far away so that selection
    /// matters.
    fn square_light_scene(radiance: Vec3, two_sided: bool, motion: Vec3) -> Scene {
        let mut scene = Scene::empty("square-light");
        scene.materials.push(Material { emission: radiance, two_sided_emission: two_sided, ..Material::default() });
        scene.materials.push(Material { emission: Vec3::splat(0.01), ..Material::default() });
        // Clockwise seen from above = counter-clockwise seen from below: faces -z.
        let corners = [
            Vec3::new(-0.5, -0.5, 1.0),
            Vec3::new(-0.5, 0.5, 1.0),
            Vec3::new(0.5, 0.5, 1.0),
            Vec3::new(0.5, -0.5, 1.0),
        ];
        let mut light = polygon("light", &corners, 1);
        light.motion = motion;
        scene.meshes.push(light);
        let far = [Vec3::new(10.0, 0.0, 5.0), Vec3::new(11.0, 0.0, 5.0), Vec3::new(10.0, 1.0, 5.0)];
        scene.meshes.push(polygon("dim", &far, 2));
        scene
    }

    /// Irradiance at `point` (normal +z) from a uniformly emitting polygon, by Lambert's
    /// formula: E = L/2 Σ Θ_i (n · unit(r_i × r_{i+1})).
    fn lambert_polygon_irradiance(point: Vec3, corners: &[Vec3], radiance: f32) -> f32 {
        let mut sum = 0.0f64;
        for i in 0..corners.len() {
            let r0 = (corners[i] - point).normalize().as_dvec3();
            let r1 = (corners[(i + 1) % corners.len()] - point).normalize().as_dvec3();
            let angle = r0.dot(r1).clamp(-1.0, 1.0).acos();
            sum += angle * r0.cross(r1).normalize().z;
        }
        (0.5 * radiance as f64 * sum.abs()) as f32
    }

    /// Monte Carlo irradiance at `point` (normal +z) from next-event samples, over a
    /// rank-1 lattice in (u_select, u).
    fn estimated_irradiance(lights: &LightSampler, scene: &Scene, point: Vec3, time: f32, only_mesh: u32) -> f32 {
        let n = 1 << 18;
        let mut sum = 0.0f64;
        for i in 0..n {
            let u_select = (i as f32 + 0.5) / n as f32;
            let u = [(i as f32 * 0.754_877_7).fract(), (i as f32 * 0.569_840_3).fract()];
            if let Some(sample) = lights.sample(scene, point, time, u_select, u) {
                if sample.mesh == Some(only_mesh) {
                    sum += (sample.weighted_radiance.x * sample.wi.z.max(0.0)) as f64;
                }
            }
        }
        (sum / n as f64) as f32
    }

    #[test]
    fn area_light_sampling_gives_lamberts_polygon_irradiance() {
        let scene = square_light_scene(Vec3::splat(3.0), false, Vec3::ZERO);
        let lights = LightSampler::new(&scene);
        for point in [Vec3::ZERO, Vec3::new(0.4, -0.2, 0.3), Vec3::new(-1.5, 0.5, 0.0)] {
            let expected = lambert_polygon_irradiance(point, &scene.meshes[0].positions, 3.0);
            let estimate = estimated_irradiance(&lights, &scene, point, 0.0, 0);
            assert!((estimate / expected - 1.0).abs() < 5e-3, "{point}: {estimate} vs Lambert {expected}");
        }
    }

    #[test]
    fn a_moving_area_light_is_sampled_where_it_is_at_the_ray_time() {
        let motion = Vec3::new(2.0, 0.0, 0.0);
        let scene = square_light_scene(Vec3::splat(3.0), false, motion);
        let lights = LightSampler::new(&scene);
        let (time, point) = (0.7, Vec3::new(1.0, 0.3, 0.2));
        let moved: Vec<Vec3> = scene.meshes[0].positions.iter().map(|&p| p + motion * time).collect();
        let expected = lambert_polygon_irradiance(point, &moved, 3.0);
        let estimate = estimated_irradiance(&lights, &scene, point, time, 0);
        assert!((estimate / expected - 1.0).abs() < 5e-3, "{estimate} vs Lambert {expected}");
    }

    #[test]
    fn sampled_density_matches_the_density_of_hitting_the_same_point() {
        let scene = square_light_scene(Vec3::new(1.0, 2.0, 3.0), false, Vec3::new(0.0, 0.5, -0.25));
        let lights = LightSampler::new(&scene);
        let (time, point) = (0.3, Vec3::new(0.2, 0.1, 0.0));
        let mut checked = 0;
        for i in 0..500 {
            let u_select = (i as f32 + 0.5) / 500.0;
            let u = [(i as f32 * 0.754_877_7).fract(), (i as f32 * 0.569_840_3).fract()];
            let Some(sample) = lights.sample(&scene, point, time, u_select, u) else { continue };
            let Some(mesh) = sample.mesh else { continue };
            // Which triangle holds the sampled point: the one whose plane-space barycentrics
            // are all non-negative.
            let hit = point + sample.wi * sample.distance;
            let m = &scene.meshes[mesh as usize];
            let triangle = (0..m.indices.len() as u32)
                .find(|&t| {
                    let [a, b, c] = triangle_at(&scene, mesh, t, time);
                    let n = (b - a).cross(c - a);
                    [(a, b), (b, c), (c, a)].iter().all(|&(p, q)| (q - p).cross(hit - p).dot(n) >= -1e-5)
                })
                .expect("the sampled point lies on a triangle of the mesh");
            let pdf = lights.pdf_triangle(mesh, triangle, point, hit);
            let sampled = sample.pdf.unwrap();
            assert!((pdf / sampled - 1.0).abs() < 1e-3, "{pdf} vs {sampled}");
            checked += 1;
        }
        assert!(checked > 400);
    }

    #[test]
    fn one_sided_emitters_are_dark_from_behind_and_two_sided_ones_are_not() {
        let above = Vec3::new(0.0, 0.0, 2.0);
        let one_sided = square_light_scene(Vec3::ONE, false, Vec3::ZERO);
        let lights = LightSampler::new(&one_sided);
        let from_above = (0..100).filter_map(|i| lights.sample(&one_sided, above, 0.0, i as f32 / 100.0, [0.3, 0.6]));
        assert_eq!(from_above.filter(|s| s.mesh == Some(0)).count(), 0);

        let two_sided = square_light_scene(Vec3::ONE, true, Vec3::ZERO);
        let lights = LightSampler::new(&two_sided);
        let expected = lambert_polygon_irradiance(above, &two_sided.meshes[0].positions, 1.0);
        // The receiver above faces down (normal -z), towards the light's back.
        let estimate = {
            let n = 1 << 16;
            let mut sum = 0.0f64;
            for i in 0..n {
                let u_select = (i as f32 + 0.5) / n as f32;
                let u = [(i as f32 * 0.754_877_7).fract(), (i as f32 * 0.569_840_3).fract()];
                if let Some(s) = lights.sample(&two_sided, above, 0.0, u_select, u) {
                    if s.mesh == Some(0) {
                        sum += (s.weighted_radiance.x * (-s.wi.z).max(0.0)) as f64;
                    }
                }
            }
            (sum / n as f64) as f32
        };
        assert!((estimate / expected - 1.0).abs() < 1e-2, "{estimate} vs Lambert {expected}");
    }
}
