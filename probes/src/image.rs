//! The image from the receivers at the camera's hits (Section 4.2, "the final image"; the
//! paper reads its light map, we read the surfels through `lookup`).
//!
//! One primary ray through each pixel's centre, or `pixel_samples` stratified ones averaged
//! (lens centre, shutter open). At each hit, with the
//! surface's diffuse albedo ρ = base colour × (1 − metallic) (textured) and the shading normal
//! facing the camera:
//! - `indirect = ρ / π · E`, E the receivers' indirect irradiance interpolated at the hit;
//! - `direct = emission + ρ / π · E_direct`, E_direct from the same deterministic light samples
//!   as the senders (`direct::direct_at`), numbered by pixel;
//! - a miss sees the environment (direct) and no indirect light.
//!
//! Diffuse only: a glossy surface's specular reflection of indirect light is not in the image
//! (the paper's order-1 glossy transport, Eq. 8–9, is not planned). Also per pixel: the
//! interpolated irradiance, the albedo, the receivers' unseen-direction fraction and covering
//! probe count, and whether the lookup found no receiver (a hole: E = 0, counted).
//! [`specular_share`] measures how much of the image that leaves out, so that the front ends
//! warn instead of showing a near-black metal without a word.

use glam::{Vec2, Vec3};
use rayon::prelude::*;
use tracer::integrator::SurfacePoint;
use tracer::lights::LightSampler;
use tracer::sampler::Sampler;
use tracer::{Accel, Scene};

use crate::direct::{direct_at, MAX_SAMPLES};
use crate::lookup::{lookup, Found, LookupStats};
use crate::precompute::Precompute;
use crate::ProbesError;

/// The largest image side.
pub const MAX_SIDE: u32 = 16384;
/// The most primary rays per pixel.
pub const MAX_PIXEL_SAMPLES: u32 = 1024;

/// How the image is made.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImageSettings {
    pub width: u32,
    pub height: u32,
    /// Light samples per primary ray for its direct light; 0 for no direct light at the pixels
    /// (the indirect layer alone, as `lfr compare --effect indirect` scores it).
    pub light_samples: u32,
    /// Primary rays per pixel: 1 through the centre, more at stratified (Owen-scrambled
    /// Sobol') positions inside the pixel, every layer averaged (a box filter, as `lfr render`).
    pub pixel_samples: u32,
    pub seed: u32,
}

impl ImageSettings {
    pub fn validate(&self) -> Result<(), ProbesError> {
        for (field, v) in [("width", self.width), ("height", self.height)] {
            if v == 0 || v > MAX_SIDE {
                return Err(ProbesError::parameter(field, format!("must be between 1 and {MAX_SIDE}, got {v}")));
            }
        }
        if self.pixel_samples == 0 || self.pixel_samples > MAX_PIXEL_SAMPLES {
            return Err(ProbesError::parameter(
                "pixel-samples",
                format!("must be between 1 and {MAX_PIXEL_SAMPLES}, got {}", self.pixel_samples),
            ));
        }
        if self.light_samples > MAX_SAMPLES {
            return Err(ProbesError::parameter(
                "light-samples",
                format!("must be between 0 and {MAX_SAMPLES}, got {}", self.light_samples),
            ));
        }
        Ok(())
    }
}

/// The image's layers, row-major from the top-left pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct ProbeImage {
    pub width: u32,
    pub height: u32,
    /// `direct + indirect`.
    pub beauty: Vec<Vec3>,
    pub direct: Vec<Vec3>,
    pub indirect: Vec<Vec3>,
    /// Indirect irradiance E at the hit (0 for a miss or a hole).
    pub irradiance: Vec<Vec3>,
    pub albedo: Vec<Vec3>,
    /// The interpolated fraction of the receivers' hit directions no covering probe sees.
    pub unseen: Vec<f32>,
    /// The interpolated number of probes covering the receivers.
    pub probes: Vec<f32>,
    /// The share of the pixel's rays whose lookup found no receiver.
    pub hole: Vec<f32>,
    /// Lookup outcomes over the primary hits.
    pub lookups: LookupStats,
    /// Primary rays that hit nothing.
    pub misses: u64,
}

struct Pixel {
    direct: Vec3,
    indirect: Vec3,
    irradiance: Vec3,
    albedo: Vec3,
    unseen: f32,
    probes: f32,
    found: Found,
    miss: bool,
    /// The share of the pixel's rays whose lookup was a hole (after averaging).
    hole_share: f32,
}

/// The image of `scene` lit by the receivers' indirect irradiance `irradiance` (one value per
/// surfel of `pre`) and the scene's lights directly.
pub fn render_image(
    scene: &Scene,
    accel: &Accel,
    pre: &Precompute,
    irradiance: &[Vec3],
    settings: &ImageSettings,
) -> Result<ProbeImage, ProbesError> {
    settings.validate()?;
    let n = pre.surfels.surfels.len();
    if irradiance.len() != n {
        return Err(ProbesError::parameter(
            "irradiance",
            format!("{} values for {n} receivers: one per surfel", irradiance.len()),
        ));
    }
    if let Some(i) = irradiance.iter().position(|e| !e.is_finite()) {
        return Err(ProbesError::parameter("irradiance", format!("value {i} is not finite")));
    }
    let (w, h) = (settings.width, settings.height);
    let lights = LightSampler::new(scene);
    let scale = pre.scale as f32;
    let tan = scene.camera.tan_half_fov(w, h);
    let per_receiver: Vec<(f32, f32)> = pre
        .transports
        .iter()
        .map(|t| (if t.hits > 0 { t.unseen as f32 / t.hits as f32 } else { 0.0 }, t.probes.len() as f32))
        .collect();
    let one = |found: &mut Vec<(u32, f32)>, film: Vec2, pattern: u32| -> Pixel {
        let (origin, dir) = scene.camera.generate_ray_with_tan(tan, film, Vec2::ZERO, w, h);
        let Some(hit) = accel.intersect(origin, dir, 0.0, f32::INFINITY, 0.0) else {
            return Pixel {
                direct: scene.environment,
                indirect: Vec3::ZERO,
                irradiance: Vec3::ZERO,
                albedo: Vec3::ZERO,
                unseen: 0.0,
                probes: 0.0,
                found: Found::Hole,
                miss: true,
                hole_share: 0.0,
            };
        };
        let surface = SurfacePoint::new(scene, &hit, -dir, 0.0, 0.0);
        let albedo = surface.bsdf.base_color * (1.0 - surface.bsdf.metallic);
        let normal = surface.shading_normal;
        let how = lookup(&pre.surfels, surface.position, normal, found);
        // Receivers without a transport (hidden) know nothing of the light there: they take no
        // weight beside ones that have a transport.
        let valid: f32 = found.iter().filter(|(s, _)| per_receiver[*s as usize].1 > 0.0).map(|(_, w)| w).sum();
        if valid > 0.0 {
            found.retain(|(s, _)| per_receiver[*s as usize].1 > 0.0);
            found.iter_mut().for_each(|(_, w)| *w /= valid);
        }
        let (mut e, mut unseen, mut probes) = (Vec3::ZERO, 0.0f32, 0.0f32);
        for &(s, wt) in found.iter() {
            e += irradiance[s as usize] * wt;
            let (u, p) = per_receiver[s as usize];
            unseen += u * wt;
            probes += p * wt;
        }
        let e_direct = direct_at(
            scene,
            accel,
            &lights,
            surface.position,
            normal,
            pattern,
            settings.light_samples,
            settings.seed,
            scale,
        );
        let emission = surface.emission(scene, &hit, -dir);
        Pixel {
            direct: emission + albedo * e_direct / std::f32::consts::PI,
            indirect: albedo * e / std::f32::consts::PI,
            irradiance: e,
            albedo,
            unseen,
            probes,
            found: how,
            miss: false,
            hole_share: 0.0,
        }
    };
    let spp = settings.pixel_samples;
    let samples: Vec<Vec<Pixel>> = (0..w * h)
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
    let mut lookups = LookupStats::default();
    let mut misses = 0;
    for p in samples.iter().flatten() {
        if p.miss {
            misses += 1;
        } else {
            lookups.add(p.found);
        }
    }
    let inv = 1.0 / spp as f32;
    let pixels: Vec<Pixel> = samples
        .iter()
        .map(|list| {
            let mut sum = Pixel {
                direct: Vec3::ZERO,
                indirect: Vec3::ZERO,
                irradiance: Vec3::ZERO,
                albedo: Vec3::ZERO,
                unseen: 0.0,
                probes: 0.0,
                found: Found::Weighted,
                miss: false,
                hole_share: 0.0,
            };
            let mut holes = 0.0;
            for p in list {
                sum.direct += p.direct * inv;
                sum.indirect += p.indirect * inv;
                sum.irradiance += p.irradiance * inv;
                sum.albedo += p.albedo * inv;
                sum.unseen += p.unseen * inv;
                sum.probes += p.probes * inv;
                holes += f32::from(u8::from(!p.miss && p.found == Found::Hole)) * inv;
            }
            sum.hole_share = holes;
            sum
        })
        .collect();
    Ok(ProbeImage {
        width: w,
        height: h,
        beauty: pixels.iter().map(|p| p.direct + p.indirect).collect(),
        direct: pixels.iter().map(|p| p.direct).collect(),
        indirect: pixels.iter().map(|p| p.indirect).collect(),
        irradiance: pixels.iter().map(|p| p.irradiance).collect(),
        albedo: pixels.iter().map(|p| p.albedo).collect(),
        unseen: pixels.iter().map(|p| p.unseen).collect(),
        probes: pixels.iter().map(|p| p.probes).collect(),
        hole: pixels.iter().map(|p| p.hole_share).collect(),
        lookups,
        misses,
    })
}

/// The share of the pixels whose surface, seen through the pixel's centre, has a specular
/// lobe that outweighs its diffuse one (`shading::Bsdf::specular_outweighs_diffuse`, textures
/// resolved): metals and coats over dark bases, whose indirect light the probes' diffuse image
/// leaves out. 0 for an image of diffuse surfaces and sky; 1 when every pixel sees a metal.
pub fn specular_share(scene: &Scene, accel: &Accel, width: u32, height: u32) -> f64 {
    let tan = scene.camera.tan_half_fov(width, height);
    let specular: u64 = (0..width * height)
        .into_par_iter()
        .map(|index| {
            let film = Vec2::new((index % width) as f32 + 0.5, (index / width) as f32 + 0.5);
            let (origin, dir) = scene.camera.generate_ray_with_tan(tan, film, Vec2::ZERO, width, height);
            let Some(hit) = accel.intersect(origin, dir, 0.0, f32::INFINITY, 0.0) else { return 0 };
            u64::from(SurfacePoint::new(scene, &hit, -dir, 0.0, 0.0).bsdf.specular_outweighs_diffuse())
        })
        .sum();
    specular as f64 / (u64::from(width) * u64::from(height)).max(1) as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::placement::PlacementSettings;
    use crate::precompute::PrecomputeSettings;
    use crate::surfels::SurfelSettings;
    use crate::test_scenes::{room, scene_of, unit_quad};
    use crate::transport::TransportSettings;
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

    /// A camera just inside the unit room's z = 0 wall, looking along +z at its centre line.
    fn camera_in_the_unit_room() -> Camera {
        Camera::look_at(
            Vec3::new(0.5, 0.5, 0.05),
            Vec3::new(0.5, 0.5, 1.0),
            Vec3::Y,
            70.0,
            tracer::camera::FovAxis::Smaller,
        )
    }

    fn image_settings() -> ImageSettings {
        ImageSettings { width: 24, height: 16, light_samples: 4, pixel_samples: 1, seed: 0 }
    }

    /// Inside a diffuse room with a metal plate across the right half of the view (in a plane
    /// facing the camera, its edge on the optical axis): half of the columns see the metal, so
    /// the share is exactly 1/2; 0 with the plate diffuse and 1 with the room metal too.
    #[test]
    fn the_specular_share_counts_the_pixels_that_see_a_metal() {
        use tracer::scene::shapes::polygon;
        let plate = polygon(
            "plate",
            &[Vec3::new(0.5, -2.0, 0.9), Vec3::new(3.0, -2.0, 0.9), Vec3::new(3.0, 3.0, 0.9), Vec3::new(0.5, 3.0, 0.9)],
            1,
        );
        let mut scene = scene_of(vec![room(Vec3::new(-3.0, -3.0, 0.0), Vec3::new(4.0, 4.0, 1.0)), plate], Vec3::ZERO);
        scene.camera = camera_in_the_unit_room();
        scene.materials[0].metallic = 0.0;
        scene.materials[0].specular = 1.0;
        let mut metal = scene.materials[0].clone();
        metal.metallic = 1.0;
        scene.materials.push(metal.clone());
        let share = |scene: &Scene| specular_share(scene, &Accel::build(scene).unwrap(), 24, 16);
        assert_eq!(share(&scene), 0.5);
        scene.materials[1].metallic = 0.0;
        assert_eq!(share(&scene), 0.0, "a coat over a light base is diffuse-dominated");
        scene.materials = vec![metal.clone(), metal];
        assert_eq!(share(&scene), 1.0);
        // Stiff cases: one pixel, the scene at 1e-6 and 1e9 of its size, and nothing to hit.
        assert_eq!(specular_share(&scene, &Accel::build(&scene).unwrap(), 1, 1), 1.0);
        for s in [1e-6, 1e9] {
            assert_eq!(share(&crate::test_scenes::scaled(&scene, s)), 1.0, "scale {s}");
        }
        let empty = scene_of(Vec::new(), Vec3::ZERO);
        assert_eq!(specular_share(&empty, &Accel::build(&empty).unwrap(), 24, 16), 0.0, "no surface, no share");
    }

    #[test]
    fn constant_receiver_irradiance_gives_albedo_over_pi_at_every_hit() {
        let mut scene = scene_of(vec![room(Vec3::ZERO, Vec3::ONE)], Vec3::new(0.5, 0.5, 0.1));
        scene.camera = camera_in_the_unit_room();
        scene.materials[0].base_color = Vec3::new(0.6, 0.4, 0.2);
        scene.materials[0].metallic = 0.0;
        let pre = Precompute::build(&scene, &settings(), &mut |_| {}).unwrap();
        let accel = Accel::build(&scene).unwrap();
        let e = Vec3::new(2.0, 1.0, 0.5);
        let irradiance = vec![e; pre.surfels.surfels.len()];
        let image = render_image(&scene, &accel, &pre, &irradiance, &image_settings()).unwrap();
        assert_eq!(image.misses, 0);
        assert_eq!(image.lookups.holes, 0);
        let expected = Vec3::new(0.6, 0.4, 0.2) * e / std::f32::consts::PI;
        for (i, (ind, irr)) in image.indirect.iter().zip(&image.irradiance).enumerate() {
            assert!((*ind - expected).abs().max_element() < 1e-5, "pixel {i}: {ind} against {expected}");
            assert!((*irr - e).abs().max_element() < 1e-5, "pixel {i}: {irr}");
            assert_eq!(image.beauty[i], image.direct[i] + *ind);
        }
        // Four stratified rays per pixel: the same constant.
        let four = ImageSettings { pixel_samples: 4, ..image_settings() };
        let image4 = render_image(&scene, &accel, &pre, &irradiance, &four).unwrap();
        assert_eq!(image4.lookups.total(), 4 * 24 * 16);
        assert!(image4.indirect.iter().all(|v| (*v - expected).abs().max_element() < 1e-5));
        let bad = ImageSettings { pixel_samples: 0, ..image_settings() };
        let err = render_image(&scene, &accel, &pre, &irradiance, &bad).unwrap_err();
        assert!(err.to_string().starts_with("pixel-samples:"), "{err}");
        // No lights: no direct light; all layers finite.
        assert!(image.direct.iter().all(|d| *d == Vec3::ZERO));
        assert!(image.probes.iter().all(|p| p.is_finite() && *p >= 0.0));
        assert!(image.unseen.iter().all(|u| (0.0..=1.0).contains(u)));
        // Mismatched or non-finite irradiance is refused by name.
        let err = render_image(&scene, &accel, &pre, &irradiance[1..], &image_settings()).unwrap_err();
        assert!(err.to_string().starts_with("irradiance:"), "{err}");
        let bad = ImageSettings { width: 0, ..image_settings() };
        assert!(render_image(&scene, &accel, &pre, &irradiance, &bad).unwrap_err().to_string().starts_with("width:"));
    }

    #[test]
    fn hidden_receivers_take_no_weight_beside_receivers_with_a_transport() {
        // Every third receiver made hidden (no transport) with a wrong irradiance: each pixel
        // still reads the constant E of the valid ones (before the fix the hidden ones' share
        // darkened it: Sponza's image was 0.56 as bright as the path tracer's instead of 0.67).
        let mut scene = scene_of(vec![room(Vec3::ZERO, Vec3::ONE)], Vec3::new(0.5, 0.5, 0.1));
        scene.camera = camera_in_the_unit_room();
        scene.materials[0].base_color = Vec3::splat(0.5);
        scene.materials[0].metallic = 0.0;
        let mut pre = Precompute::build(&scene, &settings(), &mut |_| {}).unwrap();
        let accel = Accel::build(&scene).unwrap();
        let e = Vec3::new(2.0, 1.0, 0.5);
        let mut irradiance = vec![e; pre.surfels.surfels.len()];
        let mut hidden = 0;
        for (i, (t, v)) in pre.transports.iter_mut().zip(&mut irradiance).enumerate() {
            if i % 3 == 0 {
                *t = crate::transport::Transport::empty();
                *v = Vec3::ZERO;
                hidden += 1;
            }
        }
        assert!(hidden > 10);
        let image = render_image(&scene, &accel, &pre, &irradiance, &image_settings()).unwrap();
        let expected = Vec3::splat(0.5) * e / std::f32::consts::PI;
        for (i, ind) in image.indirect.iter().enumerate() {
            if image.probes[i] > 0.0 {
                assert!((*ind - expected).abs().max_element() < 1e-5, "pixel {i}: {ind} against {expected}");
            }
        }
        assert!(image.probes.iter().filter(|&&p| p > 0.0).count() > image.probes.len() * 9 / 10);
    }

    #[test]
    fn a_point_light_gives_the_inverse_square_cosine_law_and_any_thread_count_the_same_image() {
        let mut scene = scene_of(vec![unit_quad()], Vec3::new(0.5, 0.5, 2.0));
        scene.camera = Camera::look_at(
            Vec3::new(0.5, 0.5, 2.0),
            Vec3::new(0.5, 0.5, 0.0),
            Vec3::Y,
            20.0,
            tracer::camera::FovAxis::Smaller,
        );
        scene.materials[0].base_color = Vec3::splat(0.5);
        let light = Vec3::new(0.3, 0.6, 0.8);
        let intensity = Vec3::new(1.0, 2.0, 3.0);
        scene.lights.push(PunctualLight::Point { position: light, intensity });
        let pre = Precompute::build(&scene, &settings(), &mut |_| {}).unwrap();
        let accel = Accel::build(&scene).unwrap();
        let zero = vec![Vec3::ZERO; pre.surfels.surfels.len()];
        let s = image_settings();
        let run = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| render_image(&scene, &accel, &pre, &zero, &s).unwrap())
        };
        let image = run(2);
        assert_eq!(image, run(1));
        let tan = scene.camera.tan_half_fov(s.width, s.height);
        let mut checked = 0;
        for i in 0..s.width * s.height {
            let film = Vec2::new((i % s.width) as f32 + 0.5, (i / s.width) as f32 + 0.5);
            let (o, d) = scene.camera.generate_ray_with_tan(tan, film, Vec2::ZERO, s.width, s.height);
            let Some(hit) = accel.intersect(o, d, 0.0, f32::INFINITY, 0.0) else {
                assert_eq!(image.direct[i as usize], scene.environment);
                continue;
            };
            let x = o + d * hit.distance;
            let to = light - x;
            let expected =
                Vec3::splat(0.5) / std::f32::consts::PI * intensity * (to.z / to.length()) / to.length_squared();
            let got = image.direct[i as usize];
            assert!(((got - expected) / expected).abs().max_element() < 1e-3, "pixel {i}: {got} against {expected}");
            assert_eq!(image.indirect[i as usize], Vec3::ZERO);
            checked += 1;
        }
        assert!(checked > 100, "{checked}");
    }
}
