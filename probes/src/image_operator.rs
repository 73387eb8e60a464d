//! The image's lookups kept for a fixed camera: a sparse pixel × receiver operator.
//!
//! Not in the paper, whose final image reads its light map by texture filtering on the GPU. For
//! one (geometry, precompute, camera, image settings) the primary rays, their hits, the
//! surfaces' albedo and emission, and which receivers each hit reads with which weights
//! (`lookup`, hidden receivers already dropped and the rest renormalised) do not depend on the
//! light. [`ImageOperator::build`] traces and looks them up once; a frame's image is then one
//! short weighted sum of receiver irradiance per primary ray ([`ImageOperator::render`]), with
//! no ray traced unless the image wants direct light at the pixels (`light_samples` > 0: the
//! shadow rays from the kept hit points, the only light-dependent part).
//!
//! Storage is CSR-like: every pixel has `pixel_samples` consecutive samples; a sample that hit
//! a surface holds its range in one flat list of (receiver index, weight). The sums run in the
//! order of `image::render_image` (receivers in surfel order, samples in pixel order), with the
//! same f32 operations, so the image is the same bit for bit (test
//! `the_kept_operator_gives_the_lookups_image_bit_for_bit`); `render_image` stays as the
//! oracle.

use glam::{Vec2, Vec3};
use rayon::prelude::*;
use tracer::integrator::SurfacePoint;
use tracer::lights::LightSampler;
use tracer::sampler::Sampler;
use tracer::{Accel, Scene};

use crate::direct::direct_at;
use crate::image::{ImageSettings, ProbeImage};
use crate::lookup::{lookup, Found, LookupStats};
use crate::precompute::Precompute;
use crate::ProbesError;

/// What one primary ray keeps: its hit (or a miss) and the range of its receivers.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Sample {
    /// `None`: the ray hit nothing (the environment, no indirect light).
    hit: Option<Hit>,
}

#[derive(Clone, Copy, Debug, PartialEq)]
struct Hit {
    position: Vec3,
    /// The shading normal facing the camera (the direct light's hemisphere).
    normal: Vec3,
    albedo: Vec3,
    emission: Vec3,
    /// The direct light's sample pattern (numbered as `render_image` numbers it).
    pattern: u32,
    /// `weights[start..end]`.
    start: u32,
    end: u32,
}

/// The light-independent layers of one pixel, averaged over its samples.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct PixelLayers {
    albedo: Vec3,
    unseen: f32,
    probes: f32,
    hole: f32,
}

/// The kept lookups of one camera (see the module's documentation).
#[derive(Clone, Debug, PartialEq)]
pub struct ImageOperator {
    pub settings: ImageSettings,
    /// Receivers (surfels) of the precompute it was built for.
    pub receivers: usize,
    scale: f32,
    samples: Vec<Sample>,
    /// (receiver index, weight), per sample in receiver order.
    weights: Vec<(u32, f32)>,
    layers: Vec<PixelLayers>,
    lookups: LookupStats,
    misses: u64,
}

impl ImageOperator {
    /// Traces the primary rays of `settings` through `scene`'s camera and keeps each hit's
    /// receivers and weights (the work `render_image` does every frame).
    pub fn build(
        scene: &Scene,
        accel: &Accel,
        pre: &Precompute,
        settings: &ImageSettings,
    ) -> Result<ImageOperator, ProbesError> {
        settings.validate()?;
        let (w, h) = (settings.width, settings.height);
        let tan = scene.camera.tan_half_fov(w, h);
        let per_receiver: Vec<(f32, f32)> = pre
            .transports
            .iter()
            .map(|t| (if t.hits > 0 { t.unseen as f32 / t.hits as f32 } else { 0.0 }, t.probes.len() as f32))
            .collect();
        // One primary ray: its sample, its receivers, its unseen fraction and probe count, and
        // how its lookup was answered (`None` for a miss).
        type Traced = (Sample, Vec<(u32, f32)>, f32, f32, Option<Found>);
        let one = |found: &mut Vec<(u32, f32)>, film: Vec2, pattern: u32| -> Traced {
            let (origin, dir) = scene.camera.generate_ray_with_tan(tan, film, Vec2::ZERO, w, h);
            let Some(hit) = accel.intersect(origin, dir, 0.0, f32::INFINITY, 0.0) else {
                return (Sample { hit: None }, Vec::new(), 0.0, 0.0, None);
            };
            let surface = SurfacePoint::new(scene, &hit, -dir, 0.0, 0.0);
            let albedo = surface.bsdf.base_color * (1.0 - surface.bsdf.metallic);
            let normal = surface.shading_normal;
            let how = lookup(&pre.surfels, surface.position, normal, found);
            let valid: f32 = found.iter().filter(|(s, _)| per_receiver[*s as usize].1 > 0.0).map(|(_, w)| w).sum();
            if valid > 0.0 {
                found.retain(|(s, _)| per_receiver[*s as usize].1 > 0.0);
                found.iter_mut().for_each(|(_, w)| *w /= valid);
            }
            let (mut unseen, mut probes) = (0.0f32, 0.0f32);
            for &(s, wt) in found.iter() {
                let (u, p) = per_receiver[s as usize];
                unseen += u * wt;
                probes += p * wt;
            }
            let emission = surface.emission(scene, &hit, -dir);
            let kept = Hit { position: surface.position, normal, albedo, emission, pattern, start: 0, end: 0 };
            (Sample { hit: Some(kept) }, found.clone(), unseen, probes, Some(how))
        };
        let spp = settings.pixel_samples;
        let traced: Vec<Vec<Traced>> = (0..w * h)
            .into_par_iter()
            .map_init(Vec::new, |found, index| {
                let corner = Vec2::new((index % w) as f32, (index / w) as f32);
                if spp == 1 {
                    return vec![one(found, corner + Vec2::splat(0.5), index)];
                }
                (0..spp)
                    .map(|k| {
                        let u = Sampler::new(settings.seed, index, 0x3fff_ffff, k).next_2d();
                        one(found, corner + Vec2::from_array(u), index.wrapping_mul(spp).wrapping_add(k))
                    })
                    .collect()
            })
            .collect();
        let inv = 1.0 / spp as f32;
        let mut op = ImageOperator {
            settings: *settings,
            receivers: pre.surfels.surfels.len(),
            scale: pre.scale as f32,
            samples: Vec::with_capacity((w * h * spp) as usize),
            weights: Vec::new(),
            layers: Vec::with_capacity((w * h) as usize),
            lookups: LookupStats::default(),
            misses: 0,
        };
        for list in traced {
            // The same sums, in the same order, as `render_image`'s pixel average.
            let mut layers = PixelLayers::default();
            let mut holes = 0.0f32;
            for (mut sample, found, unseen, probes, how) in list {
                match how {
                    None => op.misses += 1,
                    Some(how) => op.lookups.add(how),
                }
                if let Some(hit) = &mut sample.hit {
                    hit.start = op.weights.len() as u32;
                    op.weights.extend_from_slice(&found);
                    hit.end = op.weights.len() as u32;
                    layers.albedo += hit.albedo * inv;
                }
                layers.unseen += unseen * inv;
                layers.probes += probes * inv;
                holes += f32::from(u8::from(how == Some(Found::Hole))) * inv;
                op.samples.push(sample);
            }
            layers.hole = holes;
            op.layers.push(layers);
        }
        if op.weights.len() > u32::MAX as usize {
            return Err(ProbesError::parameter(
                "width",
                format!("{} receiver weights over {}x{}: too many to keep", op.weights.len(), w, h),
            ));
        }
        Ok(op)
    }

    /// Bytes held (samples, weights and the light-independent layers).
    pub fn bytes(&self) -> usize {
        self.samples.len() * std::mem::size_of::<Sample>()
            + self.weights.len() * std::mem::size_of::<(u32, f32)>()
            + self.layers.len() * std::mem::size_of::<PixelLayers>()
    }

    /// Receiver weights kept per primary ray that hit a surface, on average.
    pub fn mean_weights_per_hit(&self) -> f64 {
        let hits = self.samples.iter().filter(|s| s.hit.is_some()).count();
        self.weights.len() as f64 / hits.max(1) as f64
    }

    /// The image for receiver irradiance `irradiance` (one value per surfel of the precompute
    /// it was built for), lit directly by `scene`'s lights when `settings.light_samples` > 0.
    /// `scene` and `accel` are the scene it was built for with any lights (the geometry, camera
    /// and materials the same).
    pub fn render(&self, scene: &Scene, accel: &Accel, irradiance: &[Vec3]) -> Result<ProbeImage, ProbesError> {
        if irradiance.len() != self.receivers {
            return Err(ProbesError::parameter(
                "irradiance",
                format!("{} values for {} receivers: one per surfel", irradiance.len(), self.receivers),
            ));
        }
        if let Some(i) = irradiance.iter().position(|e| !e.is_finite()) {
            return Err(ProbesError::parameter("irradiance", format!("value {i} is not finite")));
        }
        let s = &self.settings;
        let spp = s.pixel_samples as usize;
        let inv = 1.0 / s.pixel_samples as f32;
        let lights = (s.light_samples > 0).then(|| LightSampler::new(scene));
        // Per pixel: direct, indirect, irradiance.
        let sums: Vec<[Vec3; 3]> = self
            .samples
            .par_chunks(spp)
            .map(|samples| {
                let mut sum = [Vec3::ZERO; 3];
                for sample in samples {
                    let (direct, indirect, e) = match &sample.hit {
                        None => (scene.environment, Vec3::ZERO, Vec3::ZERO),
                        Some(hit) => {
                            let mut e = Vec3::ZERO;
                            for &(r, wt) in &self.weights[hit.start as usize..hit.end as usize] {
                                e += irradiance[r as usize] * wt;
                            }
                            let e_direct = match &lights {
                                None => Vec3::ZERO,
                                Some(lights) => direct_at(
                                    scene,
                                    accel,
                                    lights,
                                    hit.position,
                                    hit.normal,
                                    hit.pattern,
                                    s.light_samples,
                                    s.seed,
                                    self.scale,
                                ),
                            };
                            (
                                hit.emission + hit.albedo * e_direct / std::f32::consts::PI,
                                hit.albedo * e / std::f32::consts::PI,
                                e,
                            )
                        }
                    };
                    sum[0] += direct * inv;
                    sum[1] += indirect * inv;
                    sum[2] += e * inv;
                }
                sum
            })
            .collect();
        Ok(ProbeImage {
            width: s.width,
            height: s.height,
            beauty: sums.iter().map(|p| p[0] + p[1]).collect(),
            direct: sums.iter().map(|p| p[0]).collect(),
            indirect: sums.iter().map(|p| p[1]).collect(),
            irradiance: sums.iter().map(|p| p[2]).collect(),
            albedo: self.layers.iter().map(|p| p.albedo).collect(),
            unseen: self.layers.iter().map(|p| p.unseen).collect(),
            probes: self.layers.iter().map(|p| p.probes).collect(),
            hole: self.layers.iter().map(|p| p.hole).collect(),
            lookups: self.lookups,
            misses: self.misses,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::render_image;
    use crate::placement::PlacementSettings;
    use crate::precompute::PrecomputeSettings;
    use crate::surfels::SurfelSettings;
    use crate::test_scenes::{room, scene_of, unit_quad};
    use crate::transport::{Transport, TransportSettings};
    use shading::sampling::{hash_u32, to_unit_float};
    use tracer::camera::FovAxis;
    use tracer::scene::PunctualLight;
    use tracer::Camera;

    fn settings() -> PrecomputeSettings {
        PrecomputeSettings {
            surfels: SurfelSettings { budget: 600, ..Default::default() },
            placement: PlacementSettings { probes: 2, overlap: 2.0, ..Default::default() },
            transport: TransportSettings { order: 1, directions: 16, ..Default::default() },
            relight_rays: 64,
        }
    }

    /// Irradiance that differs from receiver to receiver (hashed), scaled by `k`.
    fn varying(n: usize, k: f32) -> Vec<Vec3> {
        (0..n as u32)
            .map(|i| {
                let a = hash_u32(i.wrapping_mul(3) ^ 0x9e37);
                let b = hash_u32(a);
                let c = hash_u32(b);
                k * Vec3::new(to_unit_float(a), to_unit_float(b), to_unit_float(c))
            })
            .collect()
    }

    /// A room seen from inside with a box in it and a point light, every third receiver made
    /// hidden; and a quad under a sky, half the rays missing it.
    fn scenes() -> Vec<(Scene, Precompute)> {
        let mut inside = scene_of(
            vec![
                room(Vec3::ZERO, Vec3::ONE),
                tracer::scene::shapes::axis_aligned_box("box", Vec3::splat(0.3), Vec3::new(0.6, 0.4, 0.6), 0),
            ],
            Vec3::ZERO,
        );
        inside.camera =
            Camera::look_at(Vec3::new(0.5, 0.7, 0.05), Vec3::new(0.5, 0.3, 1.0), Vec3::Y, 70.0, FovAxis::Smaller);
        inside.materials[0].base_color = Vec3::new(0.6, 0.4, 0.2);
        inside.materials[0].metallic = 0.0;
        inside
            .lights
            .push(PunctualLight::Point { position: Vec3::new(0.4, 0.9, 0.5), intensity: Vec3::new(1.0, 0.8, 0.5) });
        let mut pre = Precompute::build(&inside, &settings(), &mut |_| {}).unwrap();
        for t in pre.transports.iter_mut().step_by(3) {
            *t = Transport::empty();
        }
        let mut open = scene_of(vec![unit_quad()], Vec3::ZERO);
        open.camera =
            Camera::look_at(Vec3::new(0.5, -0.3, 1.2), Vec3::new(0.5, 0.8, 0.0), Vec3::Y, 50.0, FovAxis::Smaller);
        open.environment = Vec3::new(0.2, 0.3, 0.4);
        open.materials[0].base_color = Vec3::splat(0.5);
        let open_pre = Precompute::build(&open, &settings(), &mut |_| {}).unwrap();
        vec![(inside, pre), (open, open_pre)]
    }

    #[test]
    fn the_kept_operator_gives_the_lookups_image_bit_for_bit() {
        for (which, (scene, pre)) in scenes().into_iter().enumerate() {
            let accel = Accel::build(&scene).unwrap();
            let n = pre.surfels.surfels.len();
            for (pixel_samples, light_samples) in [(1, 0), (1, 4), (3, 2)] {
                let s = ImageSettings { width: 20, height: 14, light_samples, pixel_samples, seed: 5 };
                let op = ImageOperator::build(&scene, &accel, &pre, &s).unwrap();
                assert_eq!(op.receivers, n);
                // Two frames of different light from the same operator: the oracle's images.
                for k in [1.0, 7.5] {
                    let e = varying(n, k);
                    let oracle = render_image(&scene, &accel, &pre, &e, &s).unwrap();
                    let kept = op.render(&scene, &accel, &e).unwrap();
                    assert_eq!(kept, oracle, "scene {which}, {pixel_samples} rays, {light_samples} light samples");
                }
                let e = varying(n, 1.0);
                let image = op.render(&scene, &accel, &e).unwrap();
                assert!(image.indirect.iter().any(|v| v.max_element() > 0.0));
                if which == 1 {
                    // Pixels whose rays all miss see the sky (averaged over the pixel's rays).
                    let sky = image.direct.iter().filter(|d| (**d - scene.environment).abs().max_element() < 1e-6);
                    assert!(image.misses > 0 && sky.count() > 0, "{}", image.misses);
                }
                // Linear in the irradiance: twice the light, twice the indirect layer (a power
                // of two, exact in f32).
                let doubled: Vec<Vec3> = e.iter().map(|v| *v * 2.0).collect();
                let twice = op.render(&scene, &accel, &doubled).unwrap();
                assert!(twice.indirect.iter().zip(&image.indirect).all(|(a, b)| *a == *b * 2.0));
            }
        }
    }

    #[test]
    fn any_thread_count_gives_the_same_operator_and_image_and_bad_input_is_refused_by_name() {
        let (scene, pre) = scenes().swap_remove(0);
        let accel = Accel::build(&scene).unwrap();
        let s = ImageSettings { width: 16, height: 12, light_samples: 2, pixel_samples: 2, seed: 1 };
        let e = varying(pre.surfels.surfels.len(), 3.0);
        let run = |threads| {
            rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| {
                let op = ImageOperator::build(&scene, &accel, &pre, &s).unwrap();
                let image = op.render(&scene, &accel, &e).unwrap();
                (op, image)
            })
        };
        let (op1, image1) = run(1);
        let (op3, image3) = run(3);
        assert_eq!(op1, op3);
        assert_eq!(image1, image3);
        assert!(op1.bytes() > 0 && op1.mean_weights_per_hit() >= 1.0);
        let err = op1.render(&scene, &accel, &e[1..]).unwrap_err();
        assert!(err.to_string().starts_with("irradiance:"), "{err}");
        let mut bad = e.clone();
        bad[4] = Vec3::splat(f32::INFINITY);
        assert!(op1.render(&scene, &accel, &bad).unwrap_err().to_string().starts_with("irradiance:"));
        let zero_width = ImageSettings { width: 0, ..s };
        let err = ImageOperator::build(&scene, &accel, &pre, &zero_width).unwrap_err();
        assert!(err.to_string().starts_with("width:"), "{err}");
    }
}
