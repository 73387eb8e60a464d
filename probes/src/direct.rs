//! Direct irradiance at the senders, every frame, through the tracer's own light model
//! (`tracer::lights::LightSampler`: emissive triangles, point, spot and directional lights, the
//! constant environment), so the method and the path tracer light the scene identically.
//!
//! Per surfel, `samples` light samples in a fixed Owen-scrambled Sobol' pattern seeded by the
//! surfel index (the same every frame: no flicker), each with one shadow ray:
//! `E = (1/S) Σ max(0, n·ω_i) L_i / p_i · V`. With one emitter (a point, spot or directional
//! light alone) every sample is exact; with several, the tracer's power-proportional selection
//! makes it an unbiased estimate (a per-light deterministic loop is a planned refinement).

use glam::Vec3;
use rayon::prelude::*;
use tracer::lights::LightSampler;
use tracer::sampler::Sampler;
use tracer::{Accel, Scene};

use crate::surfels::Surfels;
use crate::visibility::offset;
use crate::ProbesError;

/// The most light samples per sender.
pub const MAX_SAMPLES: u32 = 4096;

/// Direct irradiance at every surfel (on its side), from `samples` light samples each.
pub fn direct_irradiance(
    scene: &Scene,
    accel: &Accel,
    surfels: &Surfels,
    samples: u32,
    seed: u32,
    scale: f32,
) -> Result<Vec<Vec3>, ProbesError> {
    if samples == 0 || samples > MAX_SAMPLES {
        return Err(ProbesError::parameter(
            "light samples",
            format!("must be between 1 and {MAX_SAMPLES}, got {samples}"),
        ));
    }
    let lights = LightSampler::new(scene);
    if lights.is_empty() {
        return Ok(vec![Vec3::ZERO; surfels.surfels.len()]);
    }
    Ok(surfels
        .surfels
        .par_iter()
        .enumerate()
        .map(|(i, s)| direct_at(scene, accel, &lights, s.position, s.normal, i as u32, samples, seed, scale))
        .collect())
}

/// Direct irradiance at the point `x` on the side of unit normal `n` from `samples` light
/// samples of the pattern numbered `index` (a surfel's index, or a pixel's in the image).
#[allow(clippy::too_many_arguments)]
pub fn direct_at(
    scene: &Scene,
    accel: &Accel,
    lights: &LightSampler,
    x: Vec3,
    n: Vec3,
    index: u32,
    samples: u32,
    seed: u32,
    scale: f32,
) -> Vec3 {
    if lights.is_empty() || samples == 0 {
        return Vec3::ZERO;
    }
    let origin = x + n * offset(x, scale);
    let mut sum = Vec3::ZERO;
    for k in 0..samples {
        let mut sampler = Sampler::new(seed, index, 0x2fff_ffff, k);
        let select = sampler.next_1d();
        let u = sampler.next_2d();
        let Some(light) = lights.sample(scene, origin, 0.0, select, u) else {
            continue;
        };
        let cos = n.dot(light.wi);
        if !(cos > 0.0) {
            continue;
        }
        let t_max = if light.distance.is_finite() { light.distance * (1.0 - 1e-4) } else { f32::INFINITY };
        if !accel.occluded(origin, light.wi, 0.0, t_max, 0.0) {
            sum += light.weighted_radiance * cos;
        }
    }
    sum / samples as f32
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::surfels::SurfelSettings;
    use crate::test_scenes::{scene_of, unit_quad};
    use tracer::scene::shapes::polygon;
    use tracer::scene::{Material, PunctualLight};

    fn quad_surfels(scene: &Scene) -> (Accel, Surfels) {
        let accel = Accel::build(scene).unwrap();
        let surfels = Surfels::build(scene, &SurfelSettings { budget: 400, ..Default::default() }).unwrap();
        (accel, surfels)
    }

    #[test]
    fn a_point_light_gives_the_inverse_square_cosine_law_on_the_lit_side_only() {
        let mut scene = scene_of(vec![unit_quad()], Vec3::new(0.5, 0.5, 3.0));
        let position = Vec3::new(0.3, 0.6, 0.8);
        let intensity = Vec3::new(2.0, 1.0, 0.5);
        scene.lights.push(PunctualLight::Point { position, intensity });
        let (accel, surfels) = quad_surfels(&scene);
        let e = direct_irradiance(&scene, &accel, &surfels, 4, 0, 1.0).unwrap();
        for (s, e) in surfels.surfels.iter().zip(&e) {
            let d = position - s.position;
            let expected = if s.normal.z > 0.0 {
                intensity * s.normal.dot(d.normalize()) / d.length_squared()
            } else {
                Vec3::ZERO
            };
            assert!((*e - expected).abs().max_element() <= 1e-4 * expected.max_element().max(1.0), "{e} vs {expected}");
        }
    }

    #[test]
    fn a_blocker_casts_a_shadow_from_the_sun_and_no_lights_give_zero() {
        let blocker = polygon(
            "blocker",
            &[Vec3::new(0.0, 0.0, 0.5), Vec3::new(0.5, 0.0, 0.5), Vec3::new(0.5, 1.0, 0.5), Vec3::new(0.0, 1.0, 0.5)],
            0,
        );
        let mut scene = scene_of(vec![unit_quad(), blocker], Vec3::new(0.5, 0.5, 3.0));
        let (accel, surfels) = quad_surfels(&scene);
        assert!(direct_irradiance(&scene, &accel, &surfels, 2, 0, 1.0).unwrap().iter().all(|e| *e == Vec3::ZERO));
        scene.lights.push(PunctualLight::Directional { direction: -Vec3::Z, irradiance: Vec3::splat(3.0) });
        let e = direct_irradiance(&scene, &accel, &surfels, 2, 0, 1.0).unwrap();
        for (s, e) in surfels.surfels.iter().zip(&e) {
            let on_floor_top = s.position.z == 0.0 && s.normal.z > 0.0;
            let lit = on_floor_top && s.position.x > 0.5 || s.position.z == 0.5 && s.normal.z > 0.0;
            let expected = if lit { 3.0 } else { 0.0 };
            assert_eq!(e.x, expected, "{} {}", s.position, s.normal);
        }
        let err = direct_irradiance(&scene, &accel, &surfels, 0, 0, 1.0).unwrap_err();
        assert!(err.to_string().starts_with("light samples:"), "{err}");
    }

    /// A spot light pointing down: inside its inner cone the point light's law, outside its
    /// outer cone nothing (between them the glTF falloff, not checked here).
    #[test]
    fn a_spot_light_lights_its_inner_cone_as_a_point_light_and_nothing_outside_its_outer_cone() {
        let mut scene = scene_of(vec![unit_quad()], Vec3::new(0.5, 0.5, 3.0));
        let (position, intensity) = (Vec3::new(0.5, 0.5, 0.6), Vec3::new(1.5, 1.0, 0.5));
        let (inner_cone, outer_cone) = (0.25f32, 0.45f32);
        scene.lights.push(PunctualLight::Spot { position, direction: -Vec3::Z, intensity, inner_cone, outer_cone });
        let (accel, surfels) = quad_surfels(&scene);
        let e = direct_irradiance(&scene, &accel, &surfels, 4, 0, 1.0).unwrap();
        let (mut inside, mut outside) = (0, 0);
        for (s, e) in surfels.surfels.iter().zip(&e) {
            let d = position - s.position;
            let angle = (-d.normalize()).dot(-Vec3::Z).clamp(-1.0, 1.0).acos();
            if s.normal.z > 0.0 && angle < inner_cone - 0.02 {
                let expected = intensity * s.normal.dot(d.normalize()) / d.length_squared();
                assert!((*e - expected).abs().max_element() <= 1e-4 * expected.max_element(), "{e} vs {expected}");
                inside += 1;
            } else if s.normal.z < 0.0 || angle > outer_cone + 0.02 {
                assert_eq!(*e, Vec3::ZERO, "{} {}", s.position, s.normal);
                outside += 1;
            }
        }
        assert!(inside > 10 && outside > 10, "{inside} inside, {outside} outside");
    }

    /// A constant environment over a lone quad: each side sees a whole unoccluded hemisphere,
    /// so E = π L on both, up to the light samples' noise.
    #[test]
    fn a_constant_environment_gives_pi_times_its_radiance_on_an_open_quad() {
        let mut scene = scene_of(vec![unit_quad()], Vec3::new(0.5, 0.5, 3.0));
        scene.environment = Vec3::new(0.2, 0.5, 1.0);
        let (accel, surfels) = quad_surfels(&scene);
        let e = direct_irradiance(&scene, &accel, &surfels, MAX_SAMPLES, 0, 1.0).unwrap();
        let expected = scene.environment * std::f32::consts::PI;
        for e in &e {
            assert!(((*e - expected) / expected).abs().max_element() < 0.15, "{e} vs {expected}");
        }
        let mean = e.iter().fold(Vec3::ZERO, |sum, e| sum + *e) / e.len() as f32;
        assert!(((mean - expected) / expected).abs().max_element() < 0.01, "mean {mean} vs {expected}");
    }

    /// A sphere light (a tessellated emissive sphere, sampled in its cone) above a quad: on the
    /// lit side E = π L sin²α cos θ with sin α = r / d (the sphere wholly above the horizon),
    /// within the tessellation's and the samples' few per cent; the far side gets nothing.
    #[test]
    fn a_sphere_light_gives_the_analytic_irradiance_of_a_sphere() {
        let (centre, radius) = (Vec3::new(0.45, 0.55, 0.6), 0.1f32);
        let mut scene = scene_of(
            vec![unit_quad(), tracer::scene::shapes::sphere("lamp", centre, radius, 4, 1)],
            Vec3::new(0.5, 0.5, 3.0),
        );
        let radiance = Vec3::new(3.0, 2.0, 1.0);
        scene.materials.push(Material { emission: radiance, ..Default::default() });
        let (accel, surfels) = quad_surfels(&scene);
        let e = direct_irradiance(&scene, &accel, &surfels, 256, 0, 1.0).unwrap();
        let mut checked = 0;
        for (s, e) in surfels.surfels.iter().zip(&e) {
            if s.position.z != 0.0 {
                continue; // the lamp's own surfels
            }
            if s.normal.z < 0.0 {
                assert_eq!(*e, Vec3::ZERO, "{}", s.position);
                continue;
            }
            let d = centre - s.position;
            let sin2 = radius * radius / d.length_squared();
            let expected = radiance * std::f32::consts::PI * sin2 * s.normal.dot(d.normalize());
            assert!(((*e - expected) / expected).abs().max_element() < 0.05, "{} {e} vs {expected}", s.position);
            checked += 1;
        }
        assert!(checked > 50, "{checked}");
    }

    #[test]
    fn an_emissive_triangle_matches_brute_force_quadrature() {
        // A floor quad under an emissive triangle facing down at height 0.6.
        let mut emitter =
            polygon("emitter", &[Vec3::new(0.2, 0.2, 0.6), Vec3::new(0.2, 0.9, 0.6), Vec3::new(0.9, 0.5, 0.6)], 1);
        emitter.name = "emitter".into();
        let mut scene = scene_of(vec![unit_quad(), emitter], Vec3::new(0.5, 0.5, 3.0));
        let radiance = Vec3::new(4.0, 2.0, 1.0);
        scene.materials.push(Material { emission: radiance, ..Default::default() });
        let [a, b, c] = [Vec3::new(0.2, 0.2, 0.6), Vec3::new(0.2, 0.9, 0.6), Vec3::new(0.9, 0.5, 0.6)];
        assert!((b - a).cross(c - a).z < 0.0, "the emitter faces the floor");
        let (accel, surfels) = quad_surfels(&scene);
        let e = direct_irradiance(&scene, &accel, &surfels, 256, 0, 1.0).unwrap();
        let mut checked = 0;
        for (s, e) in surfels.surfels.iter().zip(&e).step_by(5) {
            if !(s.position.z == 0.0 && s.normal.z > 0.0) {
                continue;
            }
            // E = ∫ L cos θ_r cos θ_l / d² dA by a 300² midpoint rule over the triangle.
            let n = 300;
            let area = 0.5 * (b - a).cross(c - a).length();
            let mut sum = 0.0f64;
            for i in 0..n {
                for j in 0..n - i {
                    let (u, v) = ((i as f32 + 1.0 / 3.0) / n as f32, (j as f32 + 1.0 / 3.0) / n as f32);
                    let p = a + (b - a) * u + (c - a) * v;
                    let d = p - s.position;
                    let cos_r = d.z / d.length();
                    sum += (cos_r * cos_r / d.length_squared()) as f64;
                }
            }
            let expected = radiance * (sum * area as f64 / (n * n) as f64 * 2.0) as f32;
            assert!((*e - expected).abs().max_element() < 0.03 * expected.max_element(), "{e} vs {expected}");
            checked += 1;
        }
        assert!(checked > 20);
    }
}
