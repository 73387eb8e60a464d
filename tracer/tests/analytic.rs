//! Renders of scenes with known answers (pbrt-v4 style): the furnace, a Lambertian plane under
//! a point light and under a square area light, motion-blur coverage, and the stiff cases.

use crate::common;

use std::f32::consts::PI;

use common::{camera_a_millionth_from_a_wall, furnace, mean, render, render_with_threads, scene_from_toml, SceneToml};

/// A 20×20 floor at y = 0, facing up.
const BIG_FLOOR: [[f32; 3]; 4] = [[-10.0, 0.0, -10.0], [-10.0, 0.0, 10.0], [10.0, 0.0, 10.0], [10.0, 0.0, -10.0]];
use glam::Vec3;

/// A white (albedo 1) Lambertian object inside a uniform environment of radiance E looks like E
/// from everywhere, however many bounces it takes (concave objects included).
#[test]
fn white_furnace_radiance_equals_the_environment() {
    let scene = furnace().scene();
    let frame = render(&scene, 32, 32, 64, 1);
    let m = mean(&frame.beauty);
    let expected = Vec3::new(0.5, 1.0, 2.0);
    let relative = ((m - expected) / expected).abs();
    assert!(relative.max_element() < 0.005, "furnace mean {m} vs {expected}");
    assert_eq!(frame.invalid_samples, 0);
}

/// The emissive furnace: inside a closed cube whose six faces are rectangle lights (sampled by
/// solid angle, two-sided radiance L_e = 1) that also reflect diffusely with albedo ρ = 0.5,
/// the radiance is L_e / (1 − ρ) = 2 everywhere, however the light and BSDF samples share the
/// work (a wrong rectangle pdf in either strategy's MIS weight would break the balance).
#[test]
fn a_box_of_rectangle_lights_is_a_furnace_of_radiance_le_over_one_minus_albedo() {
    let faces: [[[f32; 3]; 4]; 6] = [
        [[-1.0, -1.0, -1.0], [1.0, -1.0, -1.0], [1.0, 1.0, -1.0], [-1.0, 1.0, -1.0]],
        [[-1.0, -1.0, 1.0], [1.0, -1.0, 1.0], [1.0, 1.0, 1.0], [-1.0, 1.0, 1.0]],
        [[-1.0, -1.0, -1.0], [1.0, -1.0, -1.0], [1.0, -1.0, 1.0], [-1.0, -1.0, 1.0]],
        [[-1.0, 1.0, -1.0], [1.0, 1.0, -1.0], [1.0, 1.0, 1.0], [-1.0, 1.0, 1.0]],
        [[-1.0, -1.0, -1.0], [-1.0, 1.0, -1.0], [-1.0, 1.0, 1.0], [-1.0, -1.0, 1.0]],
        [[1.0, -1.0, -1.0], [1.0, 1.0, -1.0], [1.0, 1.0, 1.0], [1.0, -1.0, 1.0]],
    ];
    let mut toml = SceneToml::new(1000, None).camera([0.2, -0.1, 0.3], [1.0, 0.5, -0.4], 90.0, "").raw(
        "[[material]]\nname = \"glow\"\nbase_color = [0.5, 0.5, 0.5]\nspecular = 0\nemission = [1, 1, 1]\n\
         two_sided_emission = true",
    );
    for face in &faces {
        toml = toml.polygon("glow", face, "");
    }
    let frame = render(&toml.scene(), 16, 16, 64, 4);
    let m = mean(&frame.beauty);
    assert!((m - Vec3::splat(2.0)).abs().max_element() < 0.01, "furnace mean {m}, expected 2");
    assert_eq!(frame.invalid_samples, 0);
}

/// Lambertian plane (albedo ρ) under a point light of intensity I at height h:
/// L(p) = ρ/π · I · h / d³ with d the distance from p to the light.
#[test]
fn lambertian_plane_under_a_point_light_matches_the_inverse_square_law() {
    let scene = SceneToml::new(4, None)
        .camera([0.0, 5.0, 0.0], [0.0; 3], 60.0, "up = [0, 0, 1]\n")
        .diffuse("grey", [0.5; 3])
        .polygon("grey", &BIG_FLOOR, "")
        .raw("[[light]]\ntype = \"point\"\nposition = [0.5, 2, 0]\nintensity = [10, 20, 40]")
        .scene();
    let frame = render(&scene, 24, 24, 16, 2);
    let light = Vec3::new(0.5, 2.0, 0.0);
    let intensity = Vec3::new(10.0, 20.0, 40.0);
    let mut worst = 0.0f32;
    for i in 0..frame.pixel_count() {
        let p = frame.position[i];
        let d = (light - p).length();
        let expected = 0.5 / PI * intensity * 2.0 / (d * d * d);
        let relative = ((frame.beauty[i] - expected) / expected).abs().max_element();
        worst = worst.max(relative);
    }
    // Pixel footprints average a smooth function over ~0.25 m: well under 2%.
    assert!(worst < 0.02, "worst relative error {worst}");
}

/// Irradiance below the centre of a square Lambertian emitter of radiance L_e, half-side a, at
/// height h: E = 4 · L_e · π · F_corner with the corner form factor
/// F = 1/(2π) [A/√(1+A²) atan(B/√(1+A²)) + B/√(1+B²) atan(A/√(1+B²))], A = B = a/h.
#[test]
fn lambertian_plane_under_a_square_area_light_matches_the_form_factor() {
    // The emitter faces down (its points turn clockwise seen from below).
    let scene = SceneToml::new(1, None)
        .camera([0.0, 0.5, 0.0], [0.0; 3], 0.5, "up = [0, 0, 1]\n")
        .diffuse("grey", [0.6; 3])
        .emitter("lamp", [3.0; 3], "")
        .polygon("grey", &BIG_FLOOR, "")
        .polygon("lamp", &[[-0.5, 1.0, -0.5], [0.5, 1.0, -0.5], [0.5, 1.0, 0.5], [-0.5, 1.0, 0.5]], "")
        .scene();
    let frame = render(&scene, 4, 4, 1024, 3);
    let a: f32 = 0.5 / 1.0;
    let s = (1.0 + a * a).sqrt();
    let corner = 1.0 / (2.0 * PI) * 2.0 * (a / s * (a / s).atan());
    let irradiance = 4.0 * 3.0 * PI * corner;
    let expected = 0.6 / PI * irradiance;
    let got = mean(&frame.beauty).x;
    assert!((got - expected).abs() / expected < 0.01, "{got} vs {expected}");
}

/// An emitter sliding across the view during the shutter covers a pixel on its path for
/// (its width) / (distance travelled) of the time.
#[test]
fn motion_blur_coverage_is_the_time_fraction() {
    let scene = SceneToml::new(0, None)
        .camera([0.0, 0.0, 10.0], [0.0; 3], 2.0, "")
        .emitter("lamp", [1.0; 3], "")
        // 0.5 wide, moves 2.0 to the right: a point on its path is covered 25% of the time.
        .polygon(
            "lamp",
            &[[-1.25, -1.0, 0.0], [-0.75, -1.0, 0.0], [-0.75, 1.0, 0.0], [-1.25, 1.0, 0.0]],
            "motion = [2.0, 0, 0]\n",
        )
        .scene();
    assert!(scene.has_motion());
    let frame = render(&scene, 4, 4, 512, 4);
    let got = mean(&frame.beauty).x;
    assert!((got - 0.25).abs() < 0.01, "coverage {got}");
}

/// Same seed, same image, bit for bit, whatever the thread count.
#[test]
fn renders_are_bit_identical_across_thread_counts() {
    let scene = scene_from_toml(include_str!("../../scenes/cornell.toml"));
    let one = render_with_threads(&scene, 40, 24, 4, 7, 1);
    let two = render_with_threads(&scene, 40, 24, 4, 7, 2);
    let three = render_with_threads(&scene, 40, 24, 4, 7, 3);
    let bits =
        |f: &tracer::RenderedImage| f.beauty.iter().flat_map(|v| v.to_array().map(f32::to_bits)).collect::<Vec<_>>();
    assert_eq!(bits(&one), bits(&two));
    assert_eq!(bits(&one), bits(&three));
    assert_eq!(one.rays, two.rays);
    // A different seed gives a different image.
    let other = render_with_threads(&scene, 40, 24, 4, 8, 2);
    assert_ne!(bits(&one), bits(&other));
}

#[test]
fn direct_plus_indirect_is_the_beauty_and_layers_are_finite() {
    let scene = scene_from_toml(include_str!("../../scenes/cornell.toml"));
    let frame = render(&scene, 16, 16, 8, 5);
    for i in 0..frame.pixel_count() {
        let sum = frame.direct[i] + frame.indirect[i];
        assert!((sum - frame.beauty[i]).abs().max_element() <= 1e-4 * (1.0 + frame.beauty[i].max_element()));
        assert!(frame.variance[i].is_finite() && frame.variance[i].min_element() >= 0.0);
        assert!(frame.depth[i] > 0.0, "every pixel of the closed box hits something");
        assert!((frame.normal[i].length() - 1.0).abs() < 1e-3);
    }
    // Indirect light is a substantial part of a Cornell box.
    let indirect = mean(&frame.indirect).length();
    let direct = mean(&frame.direct).length();
    assert!(indirect > 0.2 * direct && indirect < direct, "direct {direct} indirect {indirect}");
}

#[test]
fn stiff_cases_one_pixel_one_sample_empty_scene_and_spikes_stay_finite() {
    let cornell = scene_from_toml(include_str!("../../scenes/cornell.toml"));
    let frame = render(&cornell, 1, 1, 1, 0);
    assert!(frame.beauty[0].is_finite());
    assert_eq!(frame.variance[0], Vec3::ZERO, "one sample has no variance estimate");

    // No geometry at all: the environment, everywhere.
    let empty = SceneToml::lit_by_environment([0.25, 0.5, 1.0]).scene();
    let frame = render(&empty, 3, 2, 2, 0);
    assert!(frame.beauty.iter().all(|&v| v == Vec3::new(0.25, 0.5, 1.0)));
    assert!(frame.depth.iter().all(|&d| d == 0.0));

    // A tiny, enormously bright emitter and a near-mirror: huge but finite values.
    let spiky = scene_from_toml(
        r#"
        [render]
        max_bounces = 8
        [camera]
        position = [0, 1, 4]
        look_at = [0, 0, 0]
        fov = 40
        [[material]]
        name = "mirror"
        base_color = [1, 1, 1]
        metallic = 1
        roughness = 0.001
        [[material]]
        name = "rough"
        base_color = [0.5, 0.5, 0.5]
        roughness = 1
        [[mesh]]
        shape = "polygon"
        material = "mirror"
        points = [[-2, 0, -2], [-2, 0, 2], [2, 0, 2], [2, 0, -2]]
        [[mesh]]
        shape = "sphere"
        center = [0, 0.5, 0]
        radius = 0.5
        material = "rough"
        [[light]]
        type = "sphere"
        center = [0.3, 2, -0.5]
        radius = 0.001
        radiance = [1e9, 1e9, 1e9]
        "#,
    );
    let frame = render(&spiky, 16, 16, 4, 0);
    assert!(frame.beauty.iter().all(|v| v.is_finite()));
    assert_eq!(frame.invalid_samples, 0);

    // Radiance of 1e30 half the time: its variance (~1e59) is beyond f32 and is stored as
    // f32::MAX and counted, never as infinity.
    let blinding = SceneToml::new(0, None)
        .camera([0.0, 0.0, 4.0], [0.0; 3], 40.0, "")
        .emitter("sun", [1e30; 3], "")
        .polygon("sun", &[[-9.0, -9.0, 0.0], [0.13, -9.0, 0.0], [0.13, 9.0, 0.0], [-9.0, 9.0, 0.0]], "")
        .scene();
    let frame = render(&blinding, 8, 8, 16, 0);
    assert!(frame.beauty.iter().chain(&frame.variance).all(|v| v.is_finite()));
    assert!(frame.clamped_variances > 0, "the edge pixels straddle the emitter's border");
    assert!(frame.variance.iter().any(|v| v.x == f32::MAX));
}

#[test]
fn camera_at_near_zero_distance_from_a_surface_stays_finite() {
    let scene = camera_a_millionth_from_a_wall("");
    let frame = render(&scene, 8, 8, 4, 0);
    assert!(frame.beauty.iter().all(|v| v.is_finite()));
    assert!(frame.depth.iter().all(|&d| d.is_finite() && d >= 0.0));
}
