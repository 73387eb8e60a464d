//! How close to raw Embree can *any* path tracer with next-event estimation get on a scene?
//!
//! An experiment for `docs/performance.md`, not part of `lfr`: the least work a unidirectional
//! path tracer with light sampling and MIS does per vertex, measured against raw Embree on its
//! own rays in the same run, the way `lfr bench` measures the real tracer.
//!
//! Per vertex this tracer does only: the hit point from the ray, the geometric normal Embree
//! returns (no vertex fetch, no shading normal, no textures), a Lambertian BSDF of the mesh's
//! constant base colour, one light sample (emissive triangles uniformly by area, directional
//! lights, the environment uniformly over the sphere) with its shadow ray and the power
//! heuristic, a cosine-weighted bounce, Russian roulette after three bounces, and a PCG32
//! random stream per path. Everything else the real tracer does (low-discrepancy samples,
//! GGX, texture filtering, shading normals, ray cones, motion, lenses, the first-hit layers)
//! is left out, so its tracer/raw ratio bounds what scalar shading of this design can reach.
//!
//! `cargo run --release -p tracer --example shading_floor -- SCENE.toml [SPP] [REPEATS]`

use std::f32::consts::{FRAC_1_PI, PI};
use std::path::PathBuf;
use std::time::Instant;

use embree3::Ray;
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use tracer::lights::triangle_at;
use tracer::render::thread_pool;
use tracer::scene::{PunctualLight, Scene};
use tracer::{Accel, RenderSettings};

const WIDTH: u32 = 256;
const HEIGHT: u32 = 256;
const TILE: u32 = 16;

/// PCG32 (O'Neill 2014): one multiply-add and a permutation per value.
struct Pcg32 {
    state: u64,
}

impl Pcg32 {
    fn new(seed: u64) -> Pcg32 {
        let mut rng = Pcg32 { state: seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1 };
        rng.next_u32();
        rng
    }

    #[inline]
    fn next_u32(&mut self) -> u32 {
        let old = self.state;
        self.state = old.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        xorshifted.rotate_right((old >> 59) as u32)
    }

    #[inline]
    fn next_f32(&mut self) -> f32 {
        (self.next_u32() >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
    }
}

struct AreaLight {
    corner: Vec3,
    edge_b: Vec3,
    edge_c: Vec3,
    normal: Vec3,
    emission: Vec3,
}

/// Lights chosen uniformly: emissive triangles (by area among themselves), directional lights,
/// the environment.
struct Lights {
    triangles: Vec<AreaLight>,
    triangle_cdf: Vec<f32>,
    triangle_area: f32,
    /// (direction towards the light, irradiance)
    directional: Vec<(Vec3, Vec3)>,
    environment: Vec3,
    choices: u32,
}

impl Lights {
    fn new(scene: &Scene) -> Lights {
        let mut triangles = Vec::new();
        let mut triangle_cdf = Vec::new();
        let mut triangle_area = 0.0;
        for (mesh_index, mesh) in scene.meshes.iter().enumerate() {
            let material = &scene.materials[mesh.material as usize];
            if !material.is_emissive() {
                continue;
            }
            for triangle in 0..mesh.indices.len() {
                let [a, b, c] = triangle_at(scene, mesh_index as u32, triangle as u32, 0.0);
                let cross = (b - a).cross(c - a);
                let area = 0.5 * cross.length();
                if area > 0.0 {
                    triangle_area += area;
                    triangle_cdf.push(triangle_area);
                    triangles.push(AreaLight {
                        corner: a,
                        edge_b: b - a,
                        edge_c: c - a,
                        normal: cross.normalize(),
                        emission: material.emission,
                    });
                }
            }
        }
        let directional: Vec<(Vec3, Vec3)> = scene
            .lights
            .iter()
            .filter_map(|light| match light {
                PunctualLight::Directional { direction, irradiance } => Some((-direction.normalize(), *irradiance)),
                _ => None,
            })
            .collect();
        let environment = scene.environment;
        let choices =
            (!triangles.is_empty()) as u32 + directional.len() as u32 + (environment.max_element() > 0.0) as u32;
        Lights { triangles, triangle_cdf, triangle_area, directional, environment, choices }
    }

    /// Solid-angle density of reaching an emissive triangle point `light_point` with normal
    /// `light_normal` from `from` by light sampling.
    #[inline]
    fn triangle_pdf(&self, from: Vec3, light_point: Vec3, light_normal: Vec3) -> f32 {
        let to_light = light_point - from;
        let distance2 = to_light.length_squared();
        let cos_light = (light_normal.dot(to_light) / distance2.sqrt()).abs();
        distance2 / (cos_light * self.triangle_area * self.choices as f32)
    }
}

/// One light sample: direction, distance, radiance / pdf, pdf (None for delta lights).
struct LightSample {
    wi: Vec3,
    distance: f32,
    weighted_radiance: Vec3,
    pdf: Option<f32>,
}

fn sample_light(lights: &Lights, point: Vec3, rng: &mut Pcg32) -> Option<LightSample> {
    if lights.choices == 0 {
        return None;
    }
    let choices = lights.choices as f32;
    let mut choice = ((rng.next_f32() * choices) as u32).min(lights.choices - 1);
    if !lights.triangles.is_empty() {
        if choice == 0 {
            let target = rng.next_f32() * lights.triangle_area;
            let index = lights.triangle_cdf.partition_point(|&c| c <= target).min(lights.triangles.len() - 1);
            let light = &lights.triangles[index];
            let (mut b, mut c) = (rng.next_f32(), rng.next_f32());
            if b + c > 1.0 {
                (b, c) = (1.0 - b, 1.0 - c);
            }
            let light_point = light.corner + light.edge_b * b + light.edge_c * c;
            let to_light = light_point - point;
            let distance = to_light.length();
            let wi = to_light / distance;
            if light.normal.dot(wi) >= 0.0 {
                return None;
            }
            let pdf = lights.triangle_pdf(point, light_point, light.normal);
            return Some(LightSample { wi, distance, weighted_radiance: light.emission / pdf, pdf: Some(pdf) });
        }
        choice -= 1;
    }
    if let Some(&(wi, irradiance)) = lights.directional.get(choice as usize) {
        return Some(LightSample { wi, distance: f32::INFINITY, weighted_radiance: irradiance * choices, pdf: None });
    }
    let z = 1.0 - 2.0 * rng.next_f32();
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * rng.next_f32();
    let wi = Vec3::new(r * phi.cos(), r * phi.sin(), z);
    let pdf = 1.0 / (4.0 * PI * choices);
    Some(LightSample { wi, distance: f32::INFINITY, weighted_radiance: lights.environment / pdf, pdf: Some(pdf) })
}

#[inline]
fn power_heuristic(a: f32, b: f32) -> f32 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 > 0.0 {
        a2 / (a2 + b2)
    } else {
        0.0
    }
}

/// An orthonormal basis around `n` (Duff et al. 2017).
#[inline]
fn basis(n: Vec3) -> (Vec3, Vec3) {
    let sign = 1.0f32.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x), Vec3::new(b, sign + n.y * n.y * a, -n.y))
}

/// Where rays go: nowhere when timing, into vectors when recording for the replay.
trait Rays {
    fn closest(&mut self, origin: Vec3, direction: Vec3);
    fn shadow(&mut self, origin: Vec3, direction: Vec3, t_max: f32);
}

struct Count;
impl Rays for Count {
    #[inline(always)]
    fn closest(&mut self, _: Vec3, _: Vec3) {}
    #[inline(always)]
    fn shadow(&mut self, _: Vec3, _: Vec3, _: f32) {}
}

#[derive(Default)]
struct Record {
    closest: Vec<Ray>,
    shadow: Vec<Ray>,
}
impl Rays for Record {
    fn closest(&mut self, origin: Vec3, direction: Vec3) {
        self.closest.push(Ray::segment(origin.to_array(), direction.to_array(), 0.0, f32::INFINITY));
    }
    fn shadow(&mut self, origin: Vec3, direction: Vec3, t_max: f32) {
        self.shadow.push(Ray::segment(origin.to_array(), direction.to_array(), 0.0, t_max));
    }
}

struct Setup<'a> {
    scene: &'a Scene,
    accel: &'a Accel,
    lights: Lights,
    base_colors: Vec<Vec3>,
    emissions: Vec<Vec3>,
    film_tan: Vec2,
    max_bounces: u32,
}

/// One path: returns its radiance and the number of rays it traced.
fn trace_path<R: Rays>(setup: &Setup, px: u32, py: u32, index: u32, rays: &mut R) -> (Vec3, u32) {
    let mut rng = Pcg32::new(((py as u64 * WIDTH as u64 + px as u64) << 20) ^ index as u64);
    let film = Vec2::new(px as f32 + rng.next_f32(), py as f32 + rng.next_f32());
    let (mut origin, mut direction) =
        setup.scene.camera.generate_ray_with_tan(setup.film_tan, film, Vec2::ZERO, WIDTH, HEIGHT);
    let mut throughput = Vec3::ONE;
    let mut radiance = Vec3::ZERO;
    let mut traced = 0;
    let mut previous_pdf: Option<f32> = None;
    for bounce in 0..=setup.max_bounces {
        traced += 1;
        rays.closest(origin, direction);
        let Some(hit) = setup.accel.intersect(origin, direction, 0.0, f32::INFINITY, 0.0) else {
            if setup.lights.environment.max_element() > 0.0 {
                let weight = match previous_pdf {
                    None => 1.0,
                    Some(pdf) => power_heuristic(pdf, 1.0 / (4.0 * PI * setup.lights.choices as f32)),
                };
                radiance += throughput * setup.lights.environment * weight;
            }
            break;
        };
        let position = origin + direction * hit.distance;
        let winding_normal = hit.geometric_normal.normalize();
        let normal = if winding_normal.dot(direction) < 0.0 { winding_normal } else { -winding_normal };
        let emission = setup.emissions[hit.mesh as usize];
        if emission != Vec3::ZERO && winding_normal.dot(direction) < 0.0 {
            let weight = match previous_pdf {
                None => 1.0,
                Some(pdf) => power_heuristic(pdf, setup.lights.triangle_pdf(origin, position, winding_normal)),
            };
            radiance += throughput * emission * weight;
        }
        if bounce == setup.max_bounces {
            break;
        }
        let albedo = setup.base_colors[hit.mesh as usize];
        let epsilon = (position.abs().max_element() + 1e-3) * 4e-6;
        let spawn = position + normal * epsilon;
        if let Some(light) = sample_light(&setup.lights, position, &mut rng) {
            let cos = light.wi.dot(normal);
            if cos > 0.0 {
                let t_max = if light.distance.is_finite() { light.distance * (1.0 - 2e-4) } else { f32::INFINITY };
                traced += 1;
                rays.shadow(spawn, light.wi, t_max);
                if !setup.accel.occluded(spawn, light.wi, 0.0, t_max, 0.0) {
                    let weight = light.pdf.map_or(1.0, |pdf| power_heuristic(pdf, cos * FRAC_1_PI));
                    radiance += throughput * albedo * FRAC_1_PI * cos * light.weighted_radiance * weight;
                }
            }
        }
        // Cosine-weighted bounce: f cos / pdf = albedo.
        let (r, phi) = (rng.next_f32().sqrt(), 2.0 * PI * rng.next_f32());
        let (sin_phi, cos_phi) = phi.sin_cos();
        let z = (1.0 - r * r).max(0.0).sqrt();
        let (tangent, bitangent) = basis(normal);
        direction = tangent * (r * cos_phi) + bitangent * (r * sin_phi) + normal * z;
        previous_pdf = Some(z * FRAC_1_PI);
        origin = spawn;
        throughput *= albedo;
        if bounce >= 3 {
            let survive = throughput.max_element().min(0.95);
            // `min` drops a NaN maximum, so `survive` is a number.
            if survive <= 0.0 || rng.next_f32() >= survive {
                break;
            }
            throughput /= survive;
        }
    }
    (radiance, traced)
}

fn tiles() -> Vec<(u32, u32)> {
    (0..HEIGHT).step_by(TILE as usize).flat_map(|y| (0..WIDTH).step_by(TILE as usize).map(move |x| (x, y))).collect()
}

/// Renders every tile; returns the rays traced and a checksum of the image (kept so that
/// the shading cannot be optimised away).
fn render<R: Rays + Send>(setup: &Setup, spp: u32, make: impl Fn() -> R + Sync) -> (Vec<R>, u64, f32) {
    let per_tile: Vec<(R, u64, f32)> = tiles()
        .par_iter()
        .map(|&(x0, y0)| {
            let mut rays = make();
            let (mut count, mut sum) = (0u64, 0.0f32);
            for py in y0..(y0 + TILE).min(HEIGHT) {
                for px in x0..(x0 + TILE).min(WIDTH) {
                    for index in 0..spp {
                        let (radiance, traced) = trace_path(setup, px, py, index, &mut rays);
                        count += traced as u64;
                        sum += radiance.element_sum();
                    }
                }
            }
            (rays, count, sum)
        })
        .collect();
    let count = per_tile.iter().map(|t| t.1).sum();
    let sum = per_tile.iter().map(|t| t.2).sum();
    (per_tile.into_iter().map(|t| t.0).collect(), count, sum)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let path = PathBuf::from(args.next().unwrap_or_else(|| "scenes/cornell.toml".into()));
    let spp: u32 = args.next().map(|s| s.parse()).transpose()?.unwrap_or(16);
    let repeats: u32 = args.next().map(|s| s.parse()).transpose()?.unwrap_or(3);
    let scene = Scene::load(&path)?;
    let accel = Accel::build(&scene)?;
    let setup = Setup {
        scene: &scene,
        accel: &accel,
        lights: Lights::new(&scene),
        base_colors: scene.meshes.iter().map(|m| scene.materials[m.material as usize].base_color).collect(),
        emissions: scene
            .meshes
            .iter()
            .map(|m| {
                let material = &scene.materials[m.material as usize];
                if material.is_emissive() {
                    material.emission
                } else {
                    Vec3::ZERO
                }
            })
            .collect(),
        film_tan: scene.camera.tan_half_fov(WIDTH, HEIGHT),
        max_bounces: scene.max_bounces,
    };
    let threads = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
    let pool = thread_pool(threads)?;
    let mut best_floor = f64::INFINITY;
    let mut ray_count = 0;
    let mut checksum = 0.0;
    for _ in 0..repeats {
        let start = Instant::now();
        let (_, count, sum) = pool.install(|| render(&setup, spp, || Count));
        best_floor = best_floor.min(start.elapsed().as_secs_f64());
        (ray_count, checksum) = (count, sum);
    }
    let (recorded, recorded_count, _) = pool.install(|| render(&setup, spp, Record::default));
    assert_eq!(recorded_count, ray_count);
    let closest: Vec<Ray> = recorded.iter().flat_map(|r| r.closest.iter().copied()).collect();
    let shadow: Vec<Ray> = recorded.iter().flat_map(|r| r.shadow.iter().copied()).collect();
    drop(recorded);
    let mut best_raw = f64::INFINITY;
    for _ in 0..repeats {
        let start = Instant::now();
        pool.install(|| {
            closest.par_chunks(4096).map(|c| accel.intersect_batch(c)).sum::<usize>()
                + shadow.par_chunks(4096).map(|c| accel.occluded_batch(c)).sum::<usize>()
        });
        best_raw = best_raw.min(start.elapsed().as_secs_f64());
    }
    // The real tracer's image of the same scene, for comparison of the means (the floor
    // ignores textures, so only untextured Lambertian scenes such as the Cornell box agree).
    let mut settings = RenderSettings::from_scene(&scene);
    (settings.width, settings.height, settings.spp, settings.threads) = (WIDTH, HEIGHT, spp, threads);
    let frame = tracer::render(&scene, &accel, &settings)?;
    let tracer_mean =
        frame.beauty.iter().map(|p| p.element_sum() as f64).sum::<f64>() / (3 * frame.beauty.len()) as f64;
    println!(
        "{}: minimal NEE path tracer, {WIDTH}x{HEIGHT} at {spp} spp, {threads} threads\n  floor    {:8.3} s  {:7.2} Mrays/s ({} rays: {} closest, {} shadow; mean radiance {:.4}, lfr render's {:.4})\n  raw      {:8.3} s  {:7.2} Mrays/s (same rays, Embree only)\n  floor/raw = {:.2}",
        path.display(),
        best_floor,
        ray_count as f64 / best_floor / 1e6,
        ray_count,
        closest.len(),
        shadow.len(),
        checksum / (3 * WIDTH * HEIGHT * spp) as f32,
        tracer_mean,
        best_raw,
        ray_count as f64 / best_raw / 1e6,
        best_raw / best_floor,
    );
    Ok(())
}
