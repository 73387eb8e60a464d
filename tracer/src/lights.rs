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
    Triangle { mesh: u32, triangle: u32 },
    Punctual(PunctualLight),
    Environment,
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
                emitters.push(Emitter::Triangle { mesh: mi as u32, triangle: t as u32 });
                power.push(lum * mesh.triangle_area(t) * PI * sides);
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
                    Emitter::Triangle { .. } => 1e-6,
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
            Emitter::Triangle { mesh, triangle } => {
                let [a, b, c] = triangle_at(scene, *mesh, *triangle, time);
                // Uniform point on the triangle; (b1, b2) are Embree's (u, v) barycentrics.
                let su = u[0].sqrt();
                let b1 = u[1] * su;
                let b2 = su - b1;
                let p = a * (1.0 - su) + b * b1 + c * b2;
                let cross = (b - a).cross(c - a);
                let area = 0.5 * cross.length();
                if !(area > 0.0) {
                    return None;
                }
                let ng = cross / (2.0 * area);
                let to_light = p - point;
                let dist2 = to_light.length_squared();
                if !(dist2 > 0.0) {
                    return None;
                }
                let distance = dist2.sqrt();
                let wi = to_light / distance;
                let cos_light = ng.dot(-wi).abs();
                if cos_light <= 1e-7 {
                    return None;
                }
                let le = triangle_emission(scene, *mesh, *triangle, Vec2::new(b1, b2), ng, -wi);
                if le == Vec3::ZERO {
                    return None;
                }
                let pdf = select * dist2 / (area * cos_light);
                Some(LightSample { wi, distance, weighted_radiance: le / pdf, pdf: Some(pdf), mesh: Some(*mesh) })
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
    pub fn pdf_triangle(&self, scene: &Scene, mesh: u32, triangle: u32, time: f32, from: Vec3, hit: Vec3) -> f32 {
        let Some(offset) = self.mesh_offset.get(mesh as usize).copied().flatten() else {
            return 0.0;
        };
        let select = self.probability[(offset + triangle) as usize];
        let [a, b, c] = triangle_at(scene, mesh, triangle, time);
        let cross = (b - a).cross(c - a);
        let area = 0.5 * cross.length();
        let to_light = hit - from;
        let dist2 = to_light.length_squared();
        if !(area > 0.0) || !(dist2 > 0.0) {
            return 0.0;
        }
        let cos_light = (cross / (2.0 * area)).dot(to_light / dist2.sqrt()).abs();
        if cos_light <= 1e-7 {
            return 0.0;
        }
        select * dist2 / (area * cos_light)
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
