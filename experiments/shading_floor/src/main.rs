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
//! `cargo run --release --manifest-path experiments/shading_floor/Cargo.toml -- SCENE.toml [SPP] [REPEATS] [batched]`
//!
//! With `batched`, the same estimator runs as a wavefront: a tile's paths advance together in
//! structure-of-arrays lanes, and all per-vertex arithmetic (`shade_lanes`) runs 8 lanes per
//! instruction with `wide::f32x8`, with counter-based hash random numbers; the Embree calls, the
//! material and light gathers and the compaction of finished paths stay scalar. This bounds what
//! SIMD shading of this design could reach (emissive triangles and the environment only). Build
//! with `RUSTFLAGS="-C target-cpu=native"` for native 8-wide AVX; without, each `f32x8` is two
//! SSE halves.

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
use wide::{f32x8, CmpGt, CmpLt};

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

    /// The emissive triangle at fraction `u` ∈ [0, 1) of the total emissive area (chosen by
    /// area); the scene must have one.
    #[inline]
    fn triangle_by_area(&self, u: f32) -> &AreaLight {
        let target = u * self.triangle_area;
        &self.triangles[self.triangle_cdf.partition_point(|&c| c <= target).min(self.triangles.len() - 1)]
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
            let light = lights.triangle_by_area(rng.next_f32());
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

/// A 32-bit counter-based random value (the lowbias32 finaliser of seed and counter), the kind a
/// SIMD loop computes for 8 or 16 paths at once.
#[inline(always)]
fn hash_random(seed: u32, counter: u32) -> f32 {
    let mut x = seed ^ counter.wrapping_mul(0x9e37_79b9);
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb_352d);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846c_a68b);
    x ^= x >> 16;
    (x >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
}

/// Three coordinates of one quantity over the lanes of a batch.
#[derive(Clone, Default)]
struct Lanes3 {
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
}

impl Lanes3 {
    fn resize(&mut self, n: usize) {
        self.x.resize(n, 0.0);
        self.y.resize(n, 0.0);
        self.z.resize(n, 0.0);
    }
    #[inline(always)]
    fn get(&self, k: usize) -> Vec3 {
        Vec3::new(self.x[k], self.y[k], self.z[k])
    }
    #[inline(always)]
    fn set(&mut self, k: usize, v: Vec3) {
        (self.x[k], self.y[k], self.z[k]) = (v.x, v.y, v.z);
    }
}

/// The live paths of a tile, structure of arrays, compacted after every bounce; and per lane the
/// current vertex's hit, material, light sample and shadow ray.
#[derive(Default)]
struct Batch {
    /// Each live path's random seed; the first `live` entries (`render_tile_batched`) are paths.
    seed: Vec<u32>,
    origin: Lanes3,
    direction: Lanes3,
    throughput: Lanes3,
    radiance: Lanes3,
    /// BSDF density of the last bounce; 0 for camera rays (no MIS).
    previous_pdf: Vec<f32>,
    distance: Vec<f32>,
    winding_normal: Lanes3,
    albedo: Lanes3,
    emission: Lanes3,
    light_corner: Lanes3,
    light_edge_b: Lanes3,
    light_edge_c: Lanes3,
    light_normal: Lanes3,
    light_emission: Lanes3,
    random: [Vec<f32>; 6],
    shadow_origin: Lanes3,
    shadow_direction: Lanes3,
    shadow_t_max: Vec<f32>,
    shadow_value: Lanes3,
    alive: Vec<bool>,
}

impl Batch {
    fn resize_vertex(&mut self, n: usize) {
        self.distance.resize(n, 0.0);
        for lanes in [
            &mut self.winding_normal,
            &mut self.albedo,
            &mut self.emission,
            &mut self.light_corner,
            &mut self.light_edge_b,
            &mut self.light_edge_c,
            &mut self.light_normal,
            &mut self.light_emission,
            &mut self.shadow_origin,
            &mut self.shadow_direction,
            &mut self.shadow_value,
        ] {
            lanes.resize(n);
        }
        for random in &mut self.random {
            random.resize(n, 0.0);
        }
        self.shadow_t_max.resize(n, 0.0);
        self.alive.resize(n, false);
    }
}

/// The same estimator as `trace_path`, for emissive triangles and the environment only, with a
/// tile's paths advanced together and the vertex arithmetic in SIMD (`shade_lanes`). Embree
/// calls, material and light look-ups stay scalar.
fn render_tile_batched<R: Rays>(setup: &Setup, x0: u32, y0: u32, spp: u32, rays: &mut R) -> (u64, f32) {
    let lights = &setup.lights;
    let mut b = Batch::default();
    let (mut count, mut sum) = (0u64, 0.0f32);
    for index in 0..spp {
        b.seed.clear();
        for lanes in [&mut b.origin, &mut b.direction, &mut b.throughput, &mut b.radiance] {
            lanes.x.clear();
            lanes.y.clear();
            lanes.z.clear();
        }
        b.previous_pdf.clear();
        for py in y0..(y0 + TILE).min(HEIGHT) {
            for px in x0..(x0 + TILE).min(WIDTH) {
                let seed = ((py * WIDTH + px) << 8) ^ index.wrapping_mul(0x2c1b_3c6d);
                let film = Vec2::new(px as f32 + hash_random(seed, 0), py as f32 + hash_random(seed, 1));
                let (origin, direction) =
                    setup.scene.camera.generate_ray_with_tan(setup.film_tan, film, Vec2::ZERO, WIDTH, HEIGHT);
                b.seed.push(seed);
                for (lanes, v) in [
                    (&mut b.origin, origin),
                    (&mut b.direction, direction),
                    (&mut b.throughput, Vec3::ONE),
                    (&mut b.radiance, Vec3::ZERO),
                ] {
                    lanes.x.push(v.x);
                    lanes.y.push(v.y);
                    lanes.z.push(v.z);
                }
                b.previous_pdf.push(0.0);
            }
        }
        let mut live = b.seed.len();
        for bounce in 0..=setup.max_bounces {
            let n = live;
            if n == 0 {
                break;
            }
            // Pad to whole vectors of 8 lanes; padding lanes miss and end.
            let padded = n.div_ceil(8) * 8;
            for lanes in [&mut b.origin, &mut b.direction, &mut b.throughput, &mut b.radiance] {
                lanes.resize(padded);
            }
            b.previous_pdf.resize(padded, 0.0);
            b.seed.resize(padded, 0);
            b.resize_vertex(padded);
            for k in n..padded {
                b.distance[k] = f32::INFINITY;
                b.winding_normal.set(k, Vec3::Z);
                b.light_emission.set(k, Vec3::ZERO);
            }
            // Closest hits (scalar Embree calls) and the materials there.
            for k in 0..n {
                let (origin, direction) = (b.origin.get(k), b.direction.get(k));
                count += 1;
                rays.closest(origin, direction);
                match setup.accel.intersect(origin, direction, 0.0, f32::INFINITY, 0.0) {
                    Some(hit) => {
                        b.distance[k] = hit.distance;
                        b.winding_normal.set(k, hit.geometric_normal);
                        b.albedo.set(k, setup.base_colors[hit.mesh as usize]);
                        b.emission.set(k, setup.emissions[hit.mesh as usize]);
                    }
                    None => {
                        b.distance[k] = f32::INFINITY;
                        b.winding_normal.set(k, Vec3::Z);
                        b.albedo.set(k, Vec3::ZERO);
                        b.emission.set(k, Vec3::ZERO);
                    }
                }
            }
            // Random numbers for every lane, in a plain loop.
            let counter = 2 + 6 * bounce;
            for (j, random) in b.random.iter_mut().enumerate() {
                for (value, &seed) in random.iter_mut().zip(&b.seed) {
                    *value = hash_random(seed, counter + j as u32);
                }
            }
            // Light choice and its data (scalar gathers); a lane whose choice is not a
            // triangle gets a zero-emission light and the environment handles it below.
            for k in 0..n {
                let u_select = b.random[0][k] * lights.choices as f32;
                let light = (u_select < 1.0 && !lights.triangles.is_empty()).then(|| lights.triangle_by_area(u_select));
                match light {
                    Some(l) => {
                        b.light_corner.set(k, l.corner);
                        b.light_edge_b.set(k, l.edge_b);
                        b.light_edge_c.set(k, l.edge_c);
                        b.light_normal.set(k, l.normal);
                        b.light_emission.set(k, l.emission);
                    }
                    None => {
                        b.light_emission.set(k, Vec3::ZERO);
                        b.light_normal.set(k, Vec3::Z);
                    }
                }
            }
            shade_lanes(&mut b, padded, bounce, setup.max_bounces, lights);
            // Shadow rays (scalar Embree calls).
            for k in 0..n {
                let t_max = b.shadow_t_max[k];
                if t_max > 0.0 {
                    let (origin, direction) = (b.shadow_origin.get(k), b.shadow_direction.get(k));
                    count += 1;
                    rays.shadow(origin, direction, t_max);
                    if !setup.accel.occluded(origin, direction, 0.0, t_max, 0.0) {
                        b.radiance.set(k, b.radiance.get(k) + b.shadow_value.get(k));
                    }
                }
            }
            // Compaction: finished paths leave the batch.
            let mut kept = 0;
            for k in 0..n {
                if b.alive[k] {
                    b.seed[kept] = b.seed[k];
                    for lanes in [&mut b.origin, &mut b.direction, &mut b.throughput, &mut b.radiance] {
                        lanes.x[kept] = lanes.x[k];
                        lanes.y[kept] = lanes.y[k];
                        lanes.z[kept] = lanes.z[k];
                    }
                    b.previous_pdf[kept] = b.previous_pdf[k];
                    kept += 1;
                } else {
                    sum += b.radiance.get(k).element_sum();
                }
            }
            live = kept;
            b.seed.truncate(kept);
            for lanes in [&mut b.origin, &mut b.direction, &mut b.throughput, &mut b.radiance] {
                lanes.x.truncate(kept);
                lanes.y.truncate(kept);
                lanes.z.truncate(kept);
            }
            b.previous_pdf.truncate(kept);
        }
        for k in 0..live {
            sum += b.radiance.get(k).element_sum();
        }
    }
    (count, sum)
}

/// Three coordinates of 8 lanes.
#[derive(Clone, Copy)]
struct V3 {
    x: f32x8,
    y: f32x8,
    z: f32x8,
}

impl V3 {
    #[inline(always)]
    fn load(l: &Lanes3, k: usize) -> V3 {
        V3 { x: load(&l.x, k), y: load(&l.y, k), z: load(&l.z, k) }
    }
    #[inline(always)]
    fn store(self, l: &mut Lanes3, k: usize) {
        store(self.x, &mut l.x, k);
        store(self.y, &mut l.y, k);
        store(self.z, &mut l.z, k);
    }
    #[inline(always)]
    fn splat(v: Vec3) -> V3 {
        V3 { x: f32x8::splat(v.x), y: f32x8::splat(v.y), z: f32x8::splat(v.z) }
    }
    #[inline(always)]
    fn add(self, o: V3) -> V3 {
        V3 { x: self.x + o.x, y: self.y + o.y, z: self.z + o.z }
    }
    #[inline(always)]
    fn sub(self, o: V3) -> V3 {
        V3 { x: self.x - o.x, y: self.y - o.y, z: self.z - o.z }
    }
    #[inline(always)]
    fn mul(self, o: V3) -> V3 {
        V3 { x: self.x * o.x, y: self.y * o.y, z: self.z * o.z }
    }
    #[inline(always)]
    fn scale(self, s: f32x8) -> V3 {
        V3 { x: self.x * s, y: self.y * s, z: self.z * s }
    }
    #[inline(always)]
    fn dot(self, o: V3) -> f32x8 {
        self.x * o.x + self.y * o.y + self.z * o.z
    }
    #[inline(always)]
    fn select(mask: f32x8, t: V3, f: V3) -> V3 {
        V3 { x: mask.blend(t.x, f.x), y: mask.blend(t.y, f.y), z: mask.blend(t.z, f.z) }
    }
}

#[inline(always)]
fn load(v: &[f32], k: usize) -> f32x8 {
    f32x8::new(v[k..k + 8].try_into().expect("8 lanes"))
}

#[inline(always)]
fn store(value: f32x8, v: &mut [f32], k: usize) {
    v[k..k + 8].copy_from_slice(&value.to_array());
}

/// The vertex arithmetic of every lane, 8 lanes per instruction (`wide::f32x8`): emission
/// with MIS, the light sample and its shadow ray, the cosine-weighted bounce and roulette.
/// Branch-free: every lane computes every case and masks pick the results.
#[inline(never)]
fn shade_lanes(b: &mut Batch, n: usize, bounce: u32, max_bounces: u32, lights: &Lights) {
    let zero = f32x8::ZERO;
    let one = f32x8::ONE;
    let tiny = f32x8::splat(1e-30);
    let all = f32x8::splat(f32::from_bits(u32::MAX));
    let mask_of = |flag: bool| if flag { all } else { zero };
    let not_last = mask_of(bounce != max_bounces);
    let roulette = mask_of(bounce >= 3);
    let has_environment = mask_of(lights.environment.max_element() > 0.0);
    let environment = V3::splat(lights.environment);
    let environment_pdf = f32x8::splat(1.0 / (4.0 * PI * lights.choices as f32));
    let triangle_area = f32x8::splat(lights.triangle_area);
    let triangle_choice = f32x8::splat(1.0 / lights.choices as f32);
    let frac_1_pi = f32x8::splat(FRAC_1_PI);
    let power = |a: f32x8, b: f32x8| a * a / (a * a + b * b).max(tiny);
    for k in (0..n).step_by(8) {
        let origin = V3::load(&b.origin, k);
        let direction = V3::load(&b.direction, k);
        let throughput = V3::load(&b.throughput, k);
        let previous_pdf = load(&b.previous_pdf, k);
        let had_bounce = previous_pdf.cmp_gt(zero);
        let distance = load(&b.distance, k);
        let hit = distance.cmp_lt(f32x8::splat(f32::INFINITY));
        let mut radiance = V3::load(&b.radiance, k);
        // Miss: the environment, MIS against its light sampling.
        let env_weight = had_bounce.blend(power(previous_pdf, environment_pdf), one);
        let env_factor = (!hit & has_environment).blend(env_weight, zero);
        radiance = radiance.add(throughput.mul(environment).scale(env_factor));
        let distance = hit.blend(distance, zero);
        let position = origin.add(direction.scale(distance));
        let winding = V3::load(&b.winding_normal, k);
        let winding = winding.scale(one / winding.dot(winding).sqrt().max(tiny));
        let facing = winding.dot(direction).cmp_lt(zero);
        let normal = V3::select(facing, winding, V3 { x: -winding.x, y: -winding.y, z: -winding.z });
        // Emission, MIS against light sampling of the triangle.
        let emission = V3::load(&b.emission, k);
        let to_hit = position.sub(origin);
        let distance2 = to_hit.dot(to_hit);
        let cos_light = (winding.dot(to_hit) / distance2.sqrt().max(tiny)).abs();
        let light_pdf = distance2 / (cos_light * triangle_area).max(tiny) * triangle_choice;
        let emission_weight = had_bounce.blend(power(previous_pdf, light_pdf), one);
        let emission_factor = (hit & facing).blend(emission_weight, zero);
        radiance = radiance.add(throughput.mul(emission).scale(emission_factor));
        // Light sample on the chosen triangle, or the environment.
        let albedo = V3::load(&b.albedo, k);
        let largest = position.x.abs().max(position.y.abs()).max(position.z.abs());
        let epsilon = (largest + f32x8::splat(1e-3)) * f32x8::splat(4e-6);
        let spawn = position.add(normal.scale(epsilon));
        let (u1, u2) = (load(&b.random[1], k), load(&b.random[2], k));
        let flip = (u1 + u2).cmp_gt(one);
        let bary_b = flip.blend(one - u1, u1);
        let bary_c = flip.blend(one - u2, u2);
        let light_point = V3::load(&b.light_corner, k)
            .add(V3::load(&b.light_edge_b, k).scale(bary_b))
            .add(V3::load(&b.light_edge_c, k).scale(bary_c));
        let light_emission = V3::load(&b.light_emission, k);
        let is_triangle = (light_emission.x + light_emission.y + light_emission.z).cmp_gt(zero);
        let to_light = light_point.sub(position);
        let light_distance = to_light.dot(to_light).sqrt();
        let triangle_wi = to_light.scale(one / light_distance.max(tiny));
        let cos_at_light = zero - V3::load(&b.light_normal, k).dot(triangle_wi);
        let triangle_pdf = light_distance * light_distance / (cos_at_light * triangle_area).max(tiny) * triangle_choice;
        // Environment direction, uniform on the sphere.
        let z = one - f32x8::splat(2.0) * u1;
        let r = (one - z * z).max(zero).sqrt();
        let (sin_phi, cos_phi) = (u2 * f32x8::splat(2.0 * PI)).sin_cos();
        let environment_wi = V3 { x: r * cos_phi, y: r * sin_phi, z };
        let wi = V3::select(is_triangle, triangle_wi, environment_wi);
        let pdf = is_triangle.blend(triangle_pdf, environment_pdf);
        let incident = V3::select(is_triangle, light_emission, environment);
        let cos = wi.dot(normal);
        let weight = power(pdf, cos * frac_1_pi);
        let value = throughput.mul(albedo).mul(incident).scale(frac_1_pi * cos * weight / pdf.max(tiny));
        let valid = hit
            & not_last
            & cos.cmp_gt(zero)
            & (!is_triangle | cos_at_light.cmp_gt(zero))
            & (is_triangle | has_environment);
        let t_max = is_triangle.blend(light_distance * f32x8::splat(1.0 - 2e-4), f32x8::splat(f32::INFINITY));
        spawn.store(&mut b.shadow_origin, k);
        wi.store(&mut b.shadow_direction, k);
        store(valid.blend(t_max, zero), &mut b.shadow_t_max, k);
        value.store(&mut b.shadow_value, k);
        // Cosine-weighted bounce.
        let radius = load(&b.random[3], k).sqrt();
        let (sin_phi, cos_phi) = (load(&b.random[4], k) * f32x8::splat(2.0 * PI)).sin_cos();
        let z = (one - radius * radius).max(zero).sqrt();
        let sign = one.copysign(normal.z);
        let a = (zero - one) / (sign + normal.z);
        let bb = normal.x * normal.y * a;
        let tangent = V3 { x: one + sign * normal.x * normal.x * a, y: sign * bb, z: zero - sign * normal.x };
        let bitangent = V3 { x: bb, y: sign + normal.y * normal.y * a, z: zero - normal.y };
        let new_direction = tangent.scale(radius * cos_phi).add(bitangent.scale(radius * sin_phi)).add(normal.scale(z));
        let mut new_throughput = throughput.mul(albedo);
        let survive = new_throughput.x.max(new_throughput.y).max(new_throughput.z).min(f32x8::splat(0.95));
        let survives = !roulette | (survive.cmp_gt(zero) & load(&b.random[5], k).cmp_lt(survive));
        new_throughput = V3::select(roulette, new_throughput.scale(one / survive.max(tiny)), new_throughput);
        radiance.store(&mut b.radiance, k);
        spawn.store(&mut b.origin, k);
        new_direction.store(&mut b.direction, k);
        new_throughput.store(&mut b.throughput, k);
        store(z * frac_1_pi, &mut b.previous_pdf, k);
        let alive = (hit & not_last & survives).to_array();
        for (lane, &flag) in alive.iter().enumerate() {
            b.alive[k + lane] = flag.to_bits() != 0;
        }
    }
}

fn tiles() -> Vec<(u32, u32)> {
    (0..HEIGHT).step_by(TILE as usize).flat_map(|y| (0..WIDTH).step_by(TILE as usize).map(move |x| (x, y))).collect()
}

/// Renders every tile; returns the rays traced and a checksum of the image (kept so that
/// the shading cannot be optimised away).
fn render<R: Rays + Send>(setup: &Setup, spp: u32, batched: bool, make: impl Fn() -> R + Sync) -> (Vec<R>, u64, f32) {
    let per_tile: Vec<(R, u64, f32)> = tiles()
        .par_iter()
        .map(|&(x0, y0)| {
            let mut rays = make();
            if batched {
                let (count, sum) = render_tile_batched(setup, x0, y0, spp, &mut rays);
                return (rays, count, sum);
            }
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
    let batched = args.next().as_deref() == Some("batched");
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
    if batched && !setup.lights.directional.is_empty() {
        return Err(format!(
            "{}: the batched floor handles emissive triangles and the environment only",
            path.display()
        )
        .into());
    }
    let threads = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
    let pool = thread_pool(threads)?;
    let mut best_floor = f64::INFINITY;
    let mut ray_count = 0;
    let mut checksum = 0.0;
    for _ in 0..repeats {
        let start = Instant::now();
        let (_, count, sum) = pool.install(|| render(&setup, spp, batched, || Count));
        best_floor = best_floor.min(start.elapsed().as_secs_f64());
        (ray_count, checksum) = (count, sum);
    }
    let (recorded, recorded_count, _) = pool.install(|| render(&setup, spp, batched, Record::default));
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
        "{}: minimal NEE path tracer{}, {WIDTH}x{HEIGHT} at {spp} spp, {threads} threads\n  floor    {:8.3} s  {:7.2} Mrays/s ({} rays: {} closest, {} shadow; mean radiance {:.4}, lfr render's {:.4})\n  raw      {:8.3} s  {:7.2} Mrays/s (same rays, Embree only)\n  floor/raw = {:.2}",
        path.display(),
        if batched { " (batched, SIMD shading)" } else { "" },
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
