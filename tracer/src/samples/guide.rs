//! `guide` buffers for the guided image filter (Bauszat, Eisemann, Magnor 2011, Section 3):
//! one guide ray per pixel through the pixel centre (lens centre, shutter open) records the
//! surface it hits, and the direct and indirect light at that very point are estimated with
//! `spp` samples each, so the noisy indirect map is aligned with its guide.
//!
//! Layers of the multi-layer EXR:
//!
//! | channels | meaning |
//! |---|---|
//! | `normal.X,Y,Z` | world-space shading normal at the guide hit, facing the camera (0 for a miss) |
//! | `depth.Z` | camera-space depth of the guide hit (0 for a miss) |
//! | `position.X,Y,Z` | world-space guide hit |
//! | `albedo.R,G,B` | reflectance at the guide hit |
//! | `direct.R,G,B` | emission of the hit plus light reflected straight from emitters, mean of `spp` estimates (the environment for a miss) |
//! | `indirect.R,G,B` | light reflected after at least one more bounce, mean of `spp` estimates (noisy: the filter's input) |
//! | `indirect_variance.R,G,B` | variance of that mean |
//! | `secondary_normal.X,Y,Z` | mean shading normal at the secondary hits of those paths (0 where none hit) |
//!
//! Additional eye rays (Section 3.2, supersampling): with `spp` = N, each pixel also gets N − 1
//! eye rays at low-discrepancy positions inside it (box pixel filter). Each records what the
//! geometry-aware lookup (Eq. 3–5) compares against the neighbouring guide rays (normal,
//! depth) and what the composite needs (albedo, one direct-light estimate: emission, one
//! next-event sample and one BSDF sample towards emitters, MIS-weighted as the path tracer's
//! first bounce). The eye rays trace no indirect light: that comes from the filtered map. So at
//! N spp a pixel costs N eye rays and N indirect paths, the path budget of path tracing at
//! N spp. The eye rays live in memory only (`GuideBuffers::eye_rays`); the EXR holds the
//! per-pixel buffers.

use std::path::Path;
use std::time::Instant;

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use super::DumpReport;
use crate::accel::Accel;
use crate::bsdf::Frame;
use crate::error::RenderError;
use crate::integrator::{Integrator, NoRecording, PathStart, SurfacePoint};
use crate::lights::LightSampler;
use crate::output::{write_exr, Layer};
use crate::render::RenderSettings;
use crate::sampler::Sampler;
use crate::scene::Scene;
use shading::sampling::hash_combine;

/// The guide buffers of one image.
#[derive(Clone, Debug, Default)]
pub struct GuideBuffers {
    pub width: u32,
    pub height: u32,
    pub normal: Vec<Vec3>,
    pub depth: Vec<f32>,
    pub position: Vec<Vec3>,
    pub albedo: Vec<Vec3>,
    pub direct: Vec<Vec3>,
    pub indirect: Vec<Vec3>,
    pub indirect_variance: Vec<Vec3>,
    /// Mean shading normal (renormalised) at the secondary hits of the pixel's indirect paths;
    /// zero where none hit anything.
    pub secondary_normal: Vec<Vec3>,
    /// Additional eye rays per pixel: `spp − 1`.
    pub eye_rays_per_pixel: u32,
    /// `eye_rays_per_pixel` eye rays of each pixel, pixels row-major.
    pub eye_rays: Vec<EyeRay>,
    /// Path contributions and per-sample light estimates that were NaN or infinite (an
    /// emitter too bright for f32) and were dropped: the integrator's count
    /// (`Integrator::dropped_contributions`) and the estimates this module adds up.
    pub dropped_contributions: u64,
    /// `indirect_variance` (or `direct`) values beyond f32's range, stored as `f32::MAX`.
    pub clamped_values: u64,
}

impl GuideBuffers {
    /// One line per kind of value these buffers dropped or clamped (none for clean buffers),
    /// for the commands to print as warnings; the same counts and words as a render's
    /// (`Frame::warnings`).
    pub fn warnings(&self) -> Vec<String> {
        crate::render::value_warnings(self.dropped_contributions, 0, self.clamped_values)
    }
}

/// An additional eye ray through a jittered position of its pixel.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EyeRay {
    /// Film position in pixels from the image's top-left corner.
    pub film: Vec2,
    /// Shading normal facing the camera; zero for a miss.
    pub normal: Vec3,
    /// Camera-space depth; 0 for a miss.
    pub depth: f32,
    /// Reflectance at the hit; zero for a miss.
    pub albedo: Vec3,
    /// Emission of the hit plus one estimate of the light it reflects straight from emitters
    /// (the environment for a miss).
    pub direct: Vec3,
}

/// Sampler stream of the additional eye rays, apart from the guide hit's paths.
const EYE_RAY_STREAM: u32 = 0x6579_6573;

struct GuidePixel {
    normal: Vec3,
    depth: f32,
    position: Vec3,
    albedo: Vec3,
    direct: Vec3,
    indirect: Vec3,
    indirect_variance: Vec3,
    secondary_normal: Vec3,
    eye_rays: Vec<EyeRay>,
    /// Light estimates of this pixel (guide hit and eye rays) that were not finite and were
    /// dropped.
    dropped: u64,
    /// Values beyond f32's range stored as `f32::MAX`.
    clamped: u64,
}

/// `value` (a sum or mean in f64) as f32; beyond f32's range it is stored as `f32::MAX` (with
/// its sign) and counted in `clamped`.
fn clamped_f32(value: f64, clamped: &mut u64) -> f32 {
    let narrow = value as f32;
    if narrow.is_finite() {
        narrow
    } else {
        *clamped += 1;
        f32::MAX.copysign(value as f32)
    }
}

/// The ray leaving `surface` towards a BSDF sample (as the path tracer's first bounce, MIS
/// data included) and the sample's weight; `None` when the BSDF gives no direction or it points
/// into the surface.
fn continuation(
    surface: &SurfacePoint,
    frame: &Frame,
    wo: Vec3,
    u_lobe: f32,
    u_bsdf: [f32; 2],
) -> Option<(PathStart, Vec3)> {
    let sample = surface.bsdf.sample(frame.to_local(wo), u_lobe, u_bsdf)?;
    let wi = frame.to_world(sample.wi);
    (wi.dot(surface.geometric_normal) > 0.0).then(|| {
        let start = PathStart {
            origin: surface.spawn_origin(wi),
            direction: wi,
            time: 0.0,
            bounce: 1,
            previous: Some((sample.pdf, surface.position)),
        };
        (start, sample.weight)
    })
}

/// The camera ray through `film` at the lens centre and time 0 (the guide buffers are static
/// and pinhole), with the image's field of view computed once by the integrator.
fn pinhole_ray(integrator: &Integrator, film: Vec2) -> PathStart {
    integrator.camera_path_start(&crate::camera::CameraSample { film, lens: Vec2::ZERO, time: 0.0 })
}

/// One additional eye ray of pixel (x, y): sample `index` of the eye-ray stream. `direct_only`
/// is the integrator limited to one bounce, so a BSDF-sampled ray only collects emission.
fn eye_ray(
    integrator: &Integrator,
    direct_only: &Integrator,
    settings: &RenderSettings,
    x: u32,
    y: u32,
    index: u32,
) -> EyeRay {
    let scene = integrator.scene;
    let mut sampler = Sampler::new(hash_combine(settings.seed, EYE_RAY_STREAM), x, y, index);
    let [jitter_x, jitter_y] = sampler.next_2d();
    let film = Vec2::new(x as f32 + jitter_x, y as f32 + jitter_y);
    let PathStart { origin, direction, .. } = pinhole_ray(integrator, film);
    let Some(hit) = integrator.accel.intersect(origin, direction, 0.0, f32::INFINITY, 0.0) else {
        return EyeRay { film, direct: scene.environment, ..EyeRay::default() };
    };
    let wo = -direction;
    let surface = SurfacePoint::new(scene, &hit, wo, 0.0, integrator.camera_cone().width_at(hit.distance));
    let frame = Frame::new(surface.shading_normal);
    let [u_select, u_lobe] = sampler.next_2d();
    let u_light = sampler.next_2d();
    let u_bsdf = sampler.next_2d();
    let mut rays = 0;
    let mut direct = surface.emission(scene, &hit, wo);
    if integrator.max_bounces > 0 {
        direct +=
            integrator.next_event(&surface, wo, 0.0, [u_select, u_light[0], u_light[1]], &mut rays, &mut NoRecording);
        if let Some((start, weight)) = continuation(&surface, &frame, wo, u_lobe, u_bsdf) {
            direct += weight * direct_only.trace_ray(&start, &mut sampler, &mut NoRecording).emitted;
        }
    }
    EyeRay {
        film,
        normal: surface.shading_normal,
        depth: scene.camera.depth(surface.position),
        albedo: surface.bsdf.albedo(),
        direct,
    }
}

fn guide_pixel(
    integrator: &Integrator,
    direct_only: &Integrator,
    settings: &RenderSettings,
    x: u32,
    y: u32,
) -> GuidePixel {
    let scene = integrator.scene;
    let mut dropped = 0u64;
    let mut clamped = 0u64;
    let eye_rays: Vec<EyeRay> = (0..settings.spp - 1)
        .map(|k| {
            let ray = eye_ray(integrator, direct_only, settings, x, y, k);
            if ray.direct.is_finite() {
                ray
            } else {
                dropped += 1;
                EyeRay { direct: Vec3::ZERO, ..ray }
            }
        })
        .collect();
    let film = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
    let PathStart { origin, direction, .. } = pinhole_ray(integrator, film);
    let Some(hit) = integrator.accel.intersect(origin, direction, 0.0, f32::INFINITY, 0.0) else {
        return GuidePixel {
            normal: Vec3::ZERO,
            depth: 0.0,
            position: Vec3::ZERO,
            albedo: Vec3::ZERO,
            direct: scene.environment,
            indirect: Vec3::ZERO,
            indirect_variance: Vec3::ZERO,
            secondary_normal: Vec3::ZERO,
            eye_rays,
            dropped,
            clamped,
        };
    };
    let wo = -direction;
    let surface = SurfacePoint::new(scene, &hit, wo, 0.0, integrator.camera_cone().width_at(hit.distance));
    let frame = Frame::new(surface.shading_normal);
    let emitted = surface.emission(scene, &hit, wo);
    let mut direct_sum = [0.0f64; 3];
    let mut indirect_sum = [0.0f64; 3];
    let mut indirect_sum_sq = [0.0f64; 3];
    let mut rays = 0;
    let mut secondary_normal_sum = Vec3::ZERO;
    for index in 0..settings.spp {
        let mut sampler = Sampler::new(settings.seed, x, y, index);
        let [u_select, u_lobe] = sampler.next_2d();
        let u_light = sampler.next_2d();
        let u_bsdf = sampler.next_2d();
        let _roulette = sampler.next_2d();
        let mut direct =
            integrator.next_event(&surface, wo, 0.0, [u_select, u_light[0], u_light[1]], &mut rays, &mut NoRecording);
        let mut indirect = Vec3::ZERO;
        let continued = continuation(&surface, &frame, wo, u_lobe, u_bsdf).filter(|_| integrator.max_bounces > 0);
        if let Some((start, weight)) = continued {
            let traced = integrator.trace_ray(&start, &mut sampler, &mut NoRecording);
            if let Some(secondary) = traced.first_hit {
                secondary_normal_sum += secondary.normal;
            }
            direct += weight * traced.emitted;
            indirect = weight * traced.reflected();
        }
        // A non-finite estimate is dropped and counted, as the path tracer drops its
        // contributions; the sums are in f64, so finite estimates never overflow them.
        let mut finite_or_dropped = |v: Vec3| {
            if v.is_finite() {
                v
            } else {
                dropped += 1;
                Vec3::ZERO
            }
        };
        let direct = finite_or_dropped(direct);
        let indirect = finite_or_dropped(indirect);
        for c in 0..3 {
            direct_sum[c] += direct[c] as f64;
            indirect_sum[c] += indirect[c] as f64;
            indirect_sum_sq[c] += (indirect[c] as f64).powi(2);
        }
    }
    let n = settings.spp as f64;
    let mean = indirect_sum.map(|s| s / n);
    // The variance of radiance above about 1.8e19 leaves f32's range (its square does):
    // stored as f32::MAX and counted, as the render's variance is.
    let variance = [0, 1, 2].map(|c| {
        if settings.spp > 1 {
            clamped_f32(((indirect_sum_sq[c] - n * mean[c] * mean[c]) / (n - 1.0)).max(0.0) / n, &mut clamped)
        } else {
            0.0
        }
    });
    let direct = [0, 1, 2].map(|c| clamped_f32(emitted[c] as f64 + direct_sum[c] / n, &mut clamped));
    GuidePixel {
        normal: surface.shading_normal,
        depth: scene.camera.depth(surface.position),
        position: surface.position,
        albedo: surface.bsdf.albedo(),
        direct: Vec3::from(direct),
        indirect: Vec3::new(mean[0] as f32, mean[1] as f32, mean[2] as f32),
        indirect_variance: Vec3::from(variance),
        secondary_normal: secondary_normal_sum.normalize_or_zero(),
        eye_rays,
        dropped,
        clamped,
    }
}

/// Computes the guide buffers.
pub fn guide_buffers(scene: &Scene, accel: &Accel, settings: &RenderSettings) -> Result<GuideBuffers, RenderError> {
    settings.validate()?;
    let lights = LightSampler::new(scene);
    let integrator = super::integrator(scene, accel, &lights, settings);
    let mut direct_only = super::integrator(scene, accel, &lights, settings);
    direct_only.max_bounces = 1;
    let pool = crate::render::thread_pool(settings.threads)?;
    let pixel_count = settings.width * settings.height;
    let bar = crate::progress::StepProgress::begin(settings.progress, "guide buffers", pixel_count as u64, "pixels");
    let pixels: Vec<GuidePixel> = pool.install(|| {
        (0..pixel_count)
            .into_par_iter()
            .map(|i| {
                let pixel = guide_pixel(&integrator, &direct_only, settings, i % settings.width, i / settings.width);
                bar.advance(1);
                pixel
            })
            .collect()
    });
    bar.finish();
    Ok(GuideBuffers {
        width: settings.width,
        height: settings.height,
        normal: pixels.iter().map(|p| p.normal).collect(),
        depth: pixels.iter().map(|p| p.depth).collect(),
        position: pixels.iter().map(|p| p.position).collect(),
        albedo: pixels.iter().map(|p| p.albedo).collect(),
        direct: pixels.iter().map(|p| p.direct).collect(),
        indirect: pixels.iter().map(|p| p.indirect).collect(),
        indirect_variance: pixels.iter().map(|p| p.indirect_variance).collect(),
        secondary_normal: pixels.iter().map(|p| p.secondary_normal).collect(),
        eye_rays_per_pixel: settings.spp - 1,
        eye_rays: pixels.iter().flat_map(|p| p.eye_rays.iter().copied()).collect(),
        dropped_contributions: integrator.dropped_contributions()
            + direct_only.dropped_contributions()
            + pixels.iter().map(|p| p.dropped).sum::<u64>(),
        clamped_values: pixels.iter().map(|p| p.clamped).sum(),
    })
}

/// Writes the guide buffers of `scene` as a multi-layer EXR.
pub fn dump(scene: &Scene, accel: &Accel, settings: &RenderSettings, path: &Path) -> Result<DumpReport, RenderError> {
    let start = Instant::now();
    let buffers = guide_buffers(scene, accel, settings)?;
    let trace_seconds = start.elapsed().as_secs_f64();
    let split = |name: &'static str, data: &[Vec3], labels: [&'static str; 3]| Layer {
        name,
        channels: (0..3).map(|c| (labels[c], data.iter().map(|v| v[c]).collect())).collect(),
    };
    let layers = vec![
        split("normal", &buffers.normal, ["X", "Y", "Z"]),
        Layer { name: "depth", channels: vec![("Z", buffers.depth.clone())] },
        split("position", &buffers.position, ["X", "Y", "Z"]),
        split("albedo", &buffers.albedo, ["R", "G", "B"]),
        split("direct", &buffers.direct, ["R", "G", "B"]),
        split("indirect", &buffers.indirect, ["R", "G", "B"]),
        split("indirect_variance", &buffers.indirect_variance, ["R", "G", "B"]),
        split("secondary_normal", &buffers.secondary_normal, ["X", "Y", "Z"]),
    ];
    write_exr(path, settings.width, settings.height, &layers)?;
    let bytes = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
    let samples = settings.width as u64 * settings.height as u64 * settings.spp as u64;
    Ok(DumpReport {
        samples,
        bytes,
        record_size: 19 * 4,
        fields: layers.iter().map(|l| l.name.to_string()).collect(),
        seconds: start.elapsed().as_secs_f64(),
        trace_seconds,
        dropped_contributions: buffers.dropped_contributions,
        clamped_values: buffers.clamped_values,
    })
}
