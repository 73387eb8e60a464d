//! The oracle of the probes' reconstruction: brute-force surfel radiosity. Every receiver with
//! a transport gathers the senders' radiance along `rays` cosine-distributed rays, each hit read
//! through the image lookup, E = (π / N) Σ B(hit); iterated like the probes' bounces. Same
//! receivers, senders, albedo and direct light as the probes, no probes: the difference
//! between the two is the probes' reconstruction alone (Eq. 2–7, the relight projection),
//! and the difference between this and the path tracer is the surfels' discretisation. Slow
//! (a ray per direction per receiver per run); for diagnosis (`lfr probes relight
//! --brute-force-rays`).

use glam::Vec3;
use rayon::prelude::*;
use shading::{sample_cosine_hemisphere, Frame};
use tracer::sampler::Sampler;
use tracer::Accel;

use crate::lookup::lookup;
use crate::surfels::Surfels;
use crate::transport::Transport;
use crate::visibility::offset;

/// Per receiver, the senders its rays read with their weights (π / N × lookup weight).
pub struct Gathers {
    pub rows: Vec<Vec<(u32, f32)>>,
}

impl Gathers {
    /// Traces `rays` cosine rays from every receiver that has a transport (the others, hidden,
    /// gather nothing).
    pub fn build(accel: &Accel, surfels: &Surfels, transports: &[Transport], rays: u32, scale: f32) -> Gathers {
        let rows = surfels
            .surfels
            .par_iter()
            .zip(transports)
            .enumerate()
            .map(|(i, (s, t))| {
                let mut row: Vec<(u32, f32)> = Vec::new();
                if t.probes.is_empty() || rays == 0 {
                    return row;
                }
                let frame = Frame::new(s.normal);
                let origin = s.position + s.normal * offset(s.position, scale);
                let mut found = Vec::new();
                let w = std::f32::consts::PI / rays as f32;
                for k in 0..rays {
                    let u = Sampler::new(0x6a7, i as u32, 0x1ffe, k).next_2d();
                    let dir = frame.to_world(sample_cosine_hemisphere(u)).normalize();
                    let Some(hit) = accel.intersect(origin, dir, 0.0, f32::INFINITY, 0.0) else { continue };
                    let ng = hit.geometric_normal.normalize_or_zero();
                    let side = if ng.dot(dir) > 0.0 { -ng } else { ng };
                    lookup(surfels, origin + dir * hit.distance, side, &mut found);
                    row.extend(found.iter().map(|&(s, f)| (s, f * w)));
                }
                row
            })
            .collect();
        Gathers { rows }
    }

    /// The indirect irradiance after at most `iterations` bounces (stopping when the largest
    /// change falls under `tolerance` of the largest value), from `albedo` and `direct` per
    /// surfel.
    pub fn indirect(&self, albedo: &[Vec3], direct: &[Vec3], iterations: usize, tolerance: f32) -> Vec<Vec3> {
        let mut e = vec![Vec3::ZERO; self.rows.len()];
        for _ in 0..iterations {
            let b: Vec<Vec3> =
                albedo.iter().zip(direct).zip(&e).map(|((a, d), e)| *a * (*d + *e) / std::f32::consts::PI).collect();
            let next: Vec<Vec3> = self
                .rows
                .par_iter()
                .map(|row| row.iter().fold(Vec3::ZERO, |acc, &(s, w)| acc + b[s as usize] * w))
                .collect();
            let largest = next.iter().map(|v| v.max_element()).fold(0.0f32, f32::max);
            let change = next.iter().zip(&e).map(|(a, b)| (*a - *b).abs().max_element()).fold(0.0f32, f32::max);
            e = next;
            if largest > 0.0 && change < tolerance * largest {
                break;
            }
        }
        e
    }
}

/// One bounce of sun or lamp light split in two (diagnosis): over every `stride`-th receiver
/// with a transport and `rays` cosine rays each, the senders' direct radiance read through the
/// lookup at the hits, against the direct light evaluated at each hit itself (`samples` light
/// samples, the albedo of the hit's own material and textures). Returns both sums of
/// (π / N) × radiance, RGB: their ratio is how well the senders stand for the surfaces.
#[allow(clippy::too_many_arguments)]
pub fn one_bounce_split(
    scene: &tracer::Scene,
    accel: &Accel,
    surfels: &Surfels,
    transports: &[Transport],
    sender_direct_radiance: &[Vec3],
    rays: u32,
    stride: usize,
    samples: u32,
    scale: f32,
) -> (Vec3, Vec3) {
    let lights = tracer::lights::LightSampler::new(scene);
    let footprint = surfels.h as f32;
    let parts: Vec<(glam::DVec3, glam::DVec3)> = surfels
        .surfels
        .par_iter()
        .zip(transports)
        .enumerate()
        .step_by(stride.max(1))
        .map(|(i, (s, t))| {
            let (mut via, mut exact) = (glam::DVec3::ZERO, glam::DVec3::ZERO);
            if t.probes.is_empty() {
                return (via, exact);
            }
            let frame = Frame::new(s.normal);
            let origin = s.position + s.normal * offset(s.position, scale);
            let mut found = Vec::new();
            for k in 0..rays {
                let u = Sampler::new(0x51, i as u32, 0x77, k).next_2d();
                let dir = frame.to_world(sample_cosine_hemisphere(u)).normalize();
                let Some(hit) = accel.intersect(origin, dir, 0.0, f32::INFINITY, 0.0) else { continue };
                let ng = hit.geometric_normal.normalize_or_zero();
                let side = if ng.dot(dir) > 0.0 { -ng } else { ng };
                let y = origin + dir * hit.distance;
                lookup(surfels, y, side, &mut found);
                for &(s, w) in &found {
                    via += (sender_direct_radiance[s as usize] * w).as_dvec3();
                }
                let surface = tracer::integrator::SurfacePoint::new(scene, &hit, -dir, 0.0, footprint);
                let rho = surface.bsdf.base_color * (1.0 - surface.bsdf.metallic);
                let e =
                    crate::direct::direct_at(scene, accel, &lights, y, side, k + 7919 * i as u32, samples, 0, scale);
                exact += (rho * e / std::f32::consts::PI).as_dvec3();
            }
            (via, exact)
        })
        .collect();
    let w = std::f64::consts::PI / rays.max(1) as f64;
    let (a, b) = parts.iter().fold((glam::DVec3::ZERO, glam::DVec3::ZERO), |(a, b), (x, y)| (a + *x, b + *y));
    ((a * w).as_vec3(), (b * w).as_vec3())
}

/// The indirect image gathered at the camera's own hits (diagnosis): one primary ray through
/// each pixel centre, `rays` cosine rays about the hit's shading normal reading the senders'
/// radiance `sender_radiance` through the lookup, ρ/π × E. No receivers: against the image
/// from the receivers it measures what the receivers' discretisation costs.
pub fn pixel_gather(
    scene: &tracer::Scene,
    accel: &Accel,
    surfels: &Surfels,
    sender_radiance: &[Vec3],
    (width, height): (u32, u32),
    rays: u32,
    scale: f32,
) -> Vec<Vec3> {
    let tan = scene.camera.tan_half_fov(width, height);
    (0..width * height)
        .into_par_iter()
        .map(|index| {
            let film = glam::Vec2::new((index % width) as f32 + 0.5, (index / width) as f32 + 0.5);
            let (o, d) = scene.camera.generate_ray_with_tan(tan, film, glam::Vec2::ZERO, width, height);
            let Some(hit) = accel.intersect(o, d, 0.0, f32::INFINITY, 0.0) else { return Vec3::ZERO };
            let surface = tracer::integrator::SurfacePoint::new(scene, &hit, -d, 0.0, 0.0);
            let rho = surface.bsdf.base_color * (1.0 - surface.bsdf.metallic);
            let ng = hit.geometric_normal.normalize_or_zero();
            let n = if ng.dot(d) > 0.0 { -ng } else { ng };
            let x = surface.position + n * offset(surface.position, scale);
            let frame = Frame::new(surface.shading_normal);
            let mut found = Vec::new();
            let mut e = Vec3::ZERO;
            for k in 0..rays {
                let u = Sampler::new(0x99, index, 0x55, k).next_2d();
                let dir = frame.to_world(sample_cosine_hemisphere(u)).normalize();
                if dir.dot(n) <= 0.0 {
                    continue;
                }
                let Some(h) = accel.intersect(x, dir, 0.0, f32::INFINITY, 0.0) else { continue };
                let g = h.geometric_normal.normalize_or_zero();
                let side = if g.dot(dir) > 0.0 { -g } else { g };
                lookup(surfels, x + dir * h.distance, side, &mut found);
                for &(s, w) in &found {
                    e += sender_radiance[s as usize] * w;
                }
            }
            rho * e / rays.max(1) as f32
        })
        .collect()
}

/// Diagnosis of the brightness deficit (docs/history/probes.md, "Brightness"): the one-bounce
/// gather at the camera's own hits of [`pixel_gather`], with the same rays, reading at each
/// secondary hit (a) the senders through the lookup, as `pixel_gather` does, (b) the direct light
/// evaluated there exactly through the tracer's surface (textured albedo at the hit, `samples`
/// light samples about the geometric normal facing the ray, as the senders are lit), and (c) the
/// same about the hit's shading normal (as the path tracer's next-event estimation). Returns the
/// three images' sums (radiance summed over the pixels). (a) ≈ (b) clears the senders and the
/// lookup from the camera's side; (b) against (c) measures the shading normals; (d) is (a) with
/// hidden senders (no transport) dropped beside valid ones.
#[allow(clippy::too_many_arguments)]
pub fn pixel_gather_split(
    scene: &tracer::Scene,
    accel: &Accel,
    surfels: &Surfels,
    transports: &[Transport],
    sender_radiance: &[Vec3],
    (width, height): (u32, u32),
    rays: u32,
    samples: u32,
    scale: f32,
) -> [glam::DVec3; 4] {
    let lights = tracer::lights::LightSampler::new(scene);
    let tan = scene.camera.tan_half_fov(width, height);
    let parts: Vec<[glam::DVec3; 4]> = (0..width * height)
        .into_par_iter()
        .map(|index| {
            let film = glam::Vec2::new((index % width) as f32 + 0.5, (index / width) as f32 + 0.5);
            let (o, d) = scene.camera.generate_ray_with_tan(tan, film, glam::Vec2::ZERO, width, height);
            let Some(hit) = accel.intersect(o, d, 0.0, f32::INFINITY, 0.0) else {
                return [glam::DVec3::ZERO; 4];
            };
            let surface = tracer::integrator::SurfacePoint::new(scene, &hit, -d, 0.0, 0.0);
            let rho = surface.bsdf.base_color * (1.0 - surface.bsdf.metallic);
            let ng = hit.geometric_normal.normalize_or_zero();
            let n = if ng.dot(d) > 0.0 { -ng } else { ng };
            let x = surface.position + n * offset(surface.position, scale);
            let frame = Frame::new(surface.shading_normal);
            let mut found = Vec::new();
            let (mut via, mut exact, mut shading, mut valid) = (Vec3::ZERO, Vec3::ZERO, Vec3::ZERO, Vec3::ZERO);
            for k in 0..rays {
                let u = Sampler::new(0x99, index, 0x55, k).next_2d();
                let dir = frame.to_world(sample_cosine_hemisphere(u)).normalize();
                if dir.dot(n) <= 0.0 {
                    continue;
                }
                let Some(h) = accel.intersect(x, dir, 0.0, f32::INFINITY, 0.0) else { continue };
                let g = h.geometric_normal.normalize_or_zero();
                let side = if g.dot(dir) > 0.0 { -g } else { g };
                let y = x + dir * h.distance;
                lookup(surfels, y, side, &mut found);
                for &(s, w) in &found {
                    via += sender_radiance[s as usize] * w;
                }
                // The same with hidden senders (no transport) dropped beside the others.
                let total: f32 =
                    found.iter().filter(|(s, _)| !transports[*s as usize].probes.is_empty()).map(|(_, w)| w).sum();
                for &(s, w) in &found {
                    if total == 0.0 {
                        valid += sender_radiance[s as usize] * w;
                    } else if !transports[s as usize].probes.is_empty() {
                        valid += sender_radiance[s as usize] * w / total;
                    }
                }
                let second = tracer::integrator::SurfacePoint::new(scene, &h, -dir, 0.0, 0.0);
                let rho2 = second.bsdf.base_color * (1.0 - second.bsdf.metallic);
                let pattern = index.wrapping_mul(rays).wrapping_add(k);
                let e = crate::direct::direct_at(scene, accel, &lights, y, side, pattern, samples, 0, scale);
                exact += rho2 * e / std::f32::consts::PI;
                let ns = second.shading_normal;
                let e = crate::direct::direct_at(scene, accel, &lights, y, ns, pattern, samples, 0, scale);
                shading += rho2 * e / std::f32::consts::PI;
            }
            let w = 1.0 / rays.max(1) as f32;
            [via, exact, shading, valid].map(|v| (rho * v * w).as_dvec3())
        })
        .collect();
    parts.iter().fold([glam::DVec3::ZERO; 4], |acc, p| [acc[0] + p[0], acc[1] + p[1], acc[2] + p[2], acc[3] + p[3]])
}
