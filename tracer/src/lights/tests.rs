//! The unit tests of `lights.rs`, in a file of their own beside it for their length.

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
    let corners =
        [Vec3::new(-0.5, -0.5, 1.0), Vec3::new(-0.5, 0.5, 1.0), Vec3::new(0.5, 0.5, 1.0), Vec3::new(0.5, -0.5, 1.0)];
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

/// A 2 × 0.5 rectangle light tilted 30° about x, centred 1 above the origin, facing
/// roughly down, alone in a scene (`two_sided` or not).
fn tilted_rectangle_scene(two_sided: bool) -> (Scene, Vec<Vec3>) {
    let mut scene = Scene::empty("rectangle-light");
    scene.materials.push(Material { emission: Vec3::splat(2.0), two_sided_emission: two_sided, ..Material::default() });
    let tilt = glam::Quat::from_rotation_x(30f32.to_radians());
    let corners: Vec<Vec3> = [[-1.0, -0.25], [-1.0, 0.25], [1.0, 0.25], [1.0, -0.25]]
        .iter()
        .map(|&[x, y]| tilt * Vec3::new(x, y, 0.0) + Vec3::new(0.0, 0.0, 1.0))
        .collect();
    scene.meshes.push(polygon("rectangle", &corners, 1));
    (scene, corners)
}

/// Mean and variance per sample of the irradiance estimate at `point` (normal +z).
fn irradiance_statistics(lights: &LightSampler, scene: &Scene, point: Vec3, n: usize) -> (f64, f64) {
    let (mut sum, mut sum2) = (0.0f64, 0.0f64);
    for i in 0..n {
        let u_select = (i as f32 + 0.5) / n as f32;
        let u = [(i as f32 * 0.754_877_7).fract(), (i as f32 * 0.569_840_3).fract()];
        let value = lights
            .sample(scene, point, 0.0, u_select, u)
            .map_or(0.0, |s| (s.weighted_radiance.x * s.wi.z.max(0.0)) as f64);
        sum += value;
        sum2 += value * value;
    }
    let mean = sum / n as f64;
    (mean, sum2 / n as f64 - mean * mean)
}

/// Rectangle lights are sampled by solid angle (constant pdf 1/Ω) with Lambert's irradiance
/// as the expected value, near, oblique, far (area sampling beyond two diagonals) and from behind (nothing for a one-sided light, Lambert for a two-sided
/// one), and with much less variance than area sampling close to the light.
#[test]
fn rectangle_lights_are_sampled_by_solid_angle_with_the_analytic_irradiance() {
    for two_sided in [false, true] {
        let (scene, corners) = tilted_rectangle_scene(two_sided);
        let lights = LightSampler::new(&scene);
        assert!(matches!(lights.emitters[0], Emitter::Rectangle(_)), "{:?}", lights.emitters[0]);
        for point in [
            Vec3::ZERO,
            Vec3::new(0.9, 0.1, 0.75),
            Vec3::new(0.0, 0.05, 0.84),
            Vec3::new(-3.0, 1.5, -0.5),
            Vec3::new(0.0, 0.0, -200.0),
            Vec3::new(0.0, -10.0, 0.0),
        ] {
            // (Every point has the whole rectangle above its horizon, as Lambert's formula
            // assumes.)
            let behind = (point - corners[0]).dot(Vec3::new(0.0, 0.5, -(0.75f32.sqrt()))) < 0.0;
            let expected = if behind && !two_sided { 0.0 } else { lambert_polygon_irradiance(point, &corners, 2.0) };
            let (estimate, _) = irradiance_statistics(&lights, &scene, point, 1 << 16);
            let error = (estimate - expected as f64).abs();
            assert!(
                error <= 2e-3 * expected as f64 + 1e-7,
                "two-sided {two_sided}, {point}: {estimate} against Lambert {expected}"
            );
        }
    }
    // The density is 1/Ω wherever the sample lands (here Ω from a point below the centre).
    let (scene, _) = tilted_rectangle_scene(false);
    let lights = LightSampler::new(&scene);
    let Emitter::Rectangle(rectangle) = &lights.emitters[0] else { unreachable!() };
    let omega = rectangle.spherical(Vec3::ZERO).expect("sampled by solid angle").solid_angle as f32;
    for i in 0..64 {
        let u = [(i as f32 * 0.754_877_7).fract(), (i as f32 * 0.569_840_3).fract()];
        let sample = lights.sample(&scene, Vec3::ZERO, 0.0, 0.5, u).unwrap();
        assert!((sample.pdf.unwrap() * omega - 1.0).abs() < 1e-5);
        let hit = sample.wi * sample.distance;
        assert!((hit - rectangle.corner).dot(rectangle.normal).abs() < 1e-5, "on the plane");
        assert!((lights.pdf_triangle(0, (i % 2) as u32, Vec3::ZERO, hit) * omega - 1.0).abs() < 1e-5);
    }
    // Close to the light, area sampling (the legacy strategy) is far noisier.
    let point = Vec3::new(0.0, 0.05, 0.8);
    let (new_mean, new_variance) = irradiance_statistics(&lights, &scene, point, 1 << 16);
    let legacy = LightSampler::with_strategy(&scene, LightStrategy::Legacy);
    let (old_mean, old_variance) = irradiance_statistics(&legacy, &scene, point, 1 << 16);
    assert!((new_mean / old_mean - 1.0).abs() < 5e-3, "{new_mean} vs {old_mean}");
    assert!(new_variance < 0.2 * old_variance, "variance {new_variance} vs {old_variance} by area");
}

#[test]
fn only_rectangles_become_rectangle_lights() {
    let light = Material { emission: Vec3::ONE, ..Material::default() };
    let kind = |corners: &[Vec3]| {
        let mut scene = Scene::empty("quad");
        scene.materials.push(light.clone());
        scene.meshes.push(polygon("quad", corners, 1));
        matches!(LightSampler::new(&scene).emitters[0], Emitter::Rectangle(_))
    };
    let square = [Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y];
    assert!(kind(&square));
    // A parallelogram, a trapezoid, a non-planar quad and a triangle are sampled by area.
    assert!(!kind(&[Vec3::ZERO, Vec3::X, Vec3::new(1.5, 1.0, 0.0), Vec3::new(0.5, 1.0, 0.0)]));
    assert!(!kind(&[Vec3::ZERO, Vec3::X, Vec3::new(0.8, 1.0, 0.0), Vec3::new(0.2, 1.0, 0.0)]));
    assert!(!kind(&[Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.3), Vec3::Y]));
    assert!(!kind(&square[..3]));
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

/// A sphere light of radiance `radiance` and radius 0.5 at (0, 0, 3) (two-sided when asked,
/// so that it also lights points inside it), a dim environment, and a floor polygon of
/// half-width `floor` at z = -1.
fn sphere_light_scene(radiance: f32, two_sided: bool, floor: f32) -> Scene {
    let mut scene = Scene::empty("sphere-light");
    scene.materials.push(Material {
        emission: Vec3::splat(radiance),
        two_sided_emission: two_sided,
        ..Material::default()
    });
    scene.meshes.push(crate::scene::shapes::sphere("light", Vec3::new(0.0, 0.0, 3.0), 0.5, 3, 1));
    let corners = [
        Vec3::new(-floor, -floor, -1.0),
        Vec3::new(floor, -floor, -1.0),
        Vec3::new(floor, floor, -1.0),
        Vec3::new(-floor, floor, -1.0),
    ];
    scene.meshes.push(polygon("floor", &corners, 0));
    scene.environment = Vec3::splat(0.01);
    scene
}

/// Irradiance at `point` with normal +z from the sphere light (mesh 0) by next-event samples.
fn sphere_irradiance(lights: &LightSampler, scene: &Scene, point: Vec3) -> f64 {
    let n = 1 << 18;
    let mut sum = 0.0f64;
    for i in 0..n {
        let u_select = (i as f32 + 0.5) / n as f32;
        let u = [(i as f32 * 0.754_877_7).fract(), (i as f32 * 0.569_840_3).fract()];
        if let Some(sample) = lights.sample(scene, point, 0.0, u_select, u) {
            if sample.mesh == Some(0) {
                sum += (sample.weighted_radiance.x * sample.wi.z.max(0.0)) as f64;
            }
        }
    }
    sum / n as f64
}

#[test]
fn sphere_lights_are_sampled_in_the_cone_they_subtend_with_the_analytic_irradiance() {
    let scene = sphere_light_scene(4.0, false, 2.0);
    let lights = LightSampler::new(&scene);
    let legacy = LightSampler::with_strategy(&scene, LightStrategy::Legacy);
    let Some(Emitter::Sphere(sphere)) = lights.emitters.first() else { panic!("the sphere is one entry") };
    let (r_in, r_out) = (sphere.radius_in as f64, sphere.radius_out as f64);
    assert!((r_out - 0.5).abs() < 1e-6 && r_in < r_out && r_in > 0.49, "{r_in} {r_out}");
    // On the axis below the centre at distance h, facing it, a sphere of radius r gives
    // E = π L (r / h)²; the tessellation lies between its inscribed and circumscribed spheres.
    for h in [1.5f64, 3.0, 8.0] {
        let point = Vec3::new(0.0, 0.0, 3.0 - h as f32);
        let (lo, hi) = (PI as f64 * 4.0 * (r_in / h).powi(2), PI as f64 * 4.0 * (r_out / h).powi(2));
        for (name, sampler) in [("cone", &lights), ("legacy area", &legacy)] {
            let e = sphere_irradiance(sampler, &scene, point);
            assert!(e > lo * 0.995 && e < hi * 1.005, "{name}, h = {h}: {e} not in [{lo}, {hi}]");
        }
    }
}

#[test]
fn the_sphere_density_matches_the_density_of_hitting_the_same_point() {
    // From outside (cone) and from inside a two-sided sphere (area).
    let scene = sphere_light_scene(2.0, true, 2.0);
    let lights = LightSampler::new(&scene);
    for point in [Vec3::new(0.3, -0.2, 0.0), Vec3::new(0.1, 0.05, 3.1)] {
        let mut checked = 0;
        for i in 0..400 {
            let u_select = (i as f32 + 0.5) / 400.0;
            let u = [(i as f32 * 0.754_877_7).fract(), (i as f32 * 0.569_840_3).fract()];
            let Some(sample) = lights.sample(&scene, point, 0.0, u_select, u) else { continue };
            if sample.mesh != Some(0) {
                continue;
            }
            let hit = point + sample.wi * sample.distance;
            // The triangles holding the sampled point (more than one on an edge: the
            // density of one of them must match).
            let m = &scene.meshes[0];
            let sampled = sample.pdf.unwrap();
            let matches = (0..m.indices.len() as u32).any(|t| {
                let [a, b, c] = triangle_at(&scene, 0, t, 0.0);
                let n = (b - a).cross(c - a).normalize();
                let on_plane = n.dot(hit - a).abs() < 1e-4;
                let inside = [(a, b), (b, c), (c, a)].iter().all(|&(p, r)| (r - p).cross(hit - p).dot(n) >= -1e-5);
                let pdf = lights.pdf_triangle(0, t, point, hit);
                on_plane && inside && (pdf / sampled - 1.0).abs() < 1e-3
            });
            // From outside the sampled point lies on the circumscribed sphere, just before
            // the mesh, and the density depends on the direction only.
            let outside = lights.pdf_triangle(0, 0, point, hit);
            assert!(matches || (outside / sampled - 1.0).abs() < 1e-4, "{point}: {sampled} vs {outside}");
            checked += 1;
        }
        assert!(checked > 200, "{checked}");
    }
}

#[test]
fn the_environments_share_does_not_grow_with_the_scene() {
    // The same point near the light with a small and a huge floor: the environment's and
    // the sphere's selection are the same; the legacy table gave the environment more.
    let point = Vec3::new(0.5, 0.0, -1.0);
    let (small, huge) = (sphere_light_scene(20.0, false, 5.0), sphere_light_scene(20.0, false, 600.0));
    let env = |scene: &Scene, strategy| LightSampler::with_strategy(scene, strategy).pdf_environment(point);
    assert_eq!(env(&small, LightStrategy::ByContribution), env(&huge, LightStrategy::ByContribution));
    let legacy_share = |scene: &Scene| env(scene, LightStrategy::Legacy) * 4.0 * PI;
    assert!(
        legacy_share(&small) < 0.2 && legacy_share(&huge) > 0.9,
        "{} {}",
        legacy_share(&small),
        legacy_share(&huge)
    );
    // Near a bright light, most samples go to it: the environment gets its uniform share
    // (2.5 %) and its irradiance's (π 0.01 against about 1 from the light: 3 %).
    let share = env(&huge, LightStrategy::ByContribution) * 4.0 * PI;
    assert!(share > 0.025 && share < 0.07, "environment share {share}");
}
