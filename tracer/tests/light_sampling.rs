//! Light selection by contribution and sphere lights by solid angle: on a
//! sphere light over a large floor under a dim sky, the beauty's mean relative variance at
//! 16 spp falls by at least 30 % against the sampling before (kept as
//! `LightStrategy::Legacy`, the oracle), with the same mean within noise.

use crate::common;

use glam::Vec3;
use tracer::lights::{LightSampler, LightStrategy};
use tracer::{Accel, RenderSettings, RenderedImage, Scene};

/// A sphere light (radius 0.5, radiance 30) 2 units over a grey floor `half_width` wide each
/// way, a dim uniform sky, seen from above and in front.
fn sphere_over_floor(half_width: f32) -> Scene {
    let w = half_width;
    common::scene_from_toml(&format!(
        r#"
        [render]
        max_bounces = 4
        environment = [0.02, 0.02, 0.02]
        [camera]
        position = [0, 3, 6]
        look_at = [0, 0, 0]
        fov = 50
        [[material]]
        name = "floor"
        base_color = [0.5, 0.5, 0.5]
        specular = 0
        [[mesh]]
        shape = "polygon"
        points = [[-{w}, 0, -{w}], [-{w}, 0, {w}], [{w}, 0, {w}], [{w}, 0, -{w}]]
        material = "floor"
        [[light]]
        type = "sphere"
        center = [0, 2, 0]
        radius = 0.5
        radiance = [30, 30, 30]
        "#
    ))
}

fn render(scene: &Scene, strategy: LightStrategy) -> RenderedImage {
    let accel = Accel::build(scene).expect("accelerator builds");
    let mut settings = RenderSettings::from_scene(scene);
    (settings.width, settings.height, settings.spp, settings.seed) = (64, 48, 16, 7);
    let lights = LightSampler::with_strategy(scene, strategy);
    tracer::render::render_with_lights(scene, &accel, &settings, &lights).expect("render succeeds")
}

/// Mean over the lit pixels of the variance of the pixel mean over its square (green), and the
/// image mean with its standard error.
fn statistics(frame: &RenderedImage) -> (f64, f64, f64) {
    let lit = frame.beauty.iter().filter(|b| b.y > 0.0).count();
    assert!(lit as f64 > 0.9 * frame.beauty.len() as f64, "the floor fills the view");
    lit_statistics(frame)
}

/// [`statistics`] of a view that may show the black outside (the Cornell boxes' open front).
fn lit_statistics(frame: &RenderedImage) -> (f64, f64, f64) {
    let n = frame.beauty.len() as f64;
    let lit: Vec<f64> = frame
        .beauty
        .iter()
        .zip(&frame.variance)
        .filter(|(b, _)| b.y > 0.0)
        .map(|(b, v)| v.y as f64 / (b.y as f64 * b.y as f64))
        .collect();
    let relative = lit.iter().sum::<f64>() / lit.len() as f64;
    let mean = frame.beauty.iter().map(|b| b.y as f64).sum::<f64>() / n;
    let error = (frame.variance.iter().map(|v| v.y as f64).sum::<f64>() / (n * n)).sqrt();
    (relative, mean, error)
}

#[test]
fn a_sphere_light_over_a_large_floor_is_sampled_with_less_variance_and_the_same_mean() {
    let scene = sphere_over_floor(600.0);
    let (old, old_mean, old_error) = statistics(&render(&scene, LightStrategy::Legacy));
    let (new, new_mean, new_error) = statistics(&render(&scene, LightStrategy::ByContribution));
    let ratio = new / old;
    eprintln!("mean relative variance at 16 spp: legacy {old:.4}, by contribution {new:.4}, ratio {ratio:.3}");
    eprintln!("image mean: legacy {old_mean:.5} ± {old_error:.5}, by contribution {new_mean:.5} ± {new_error:.5}");
    assert!(ratio <= 0.7, "variance ratio {ratio}");
    let difference = (new_mean - old_mean).abs();
    assert!(difference < 4.0 * (old_error.powi(2) + new_error.powi(2)).sqrt(), "means differ by {difference}");
}

#[test]
fn the_new_sampling_renders_the_same_for_any_thread_count() {
    let scene = sphere_over_floor(600.0);
    let accel = Accel::build(&scene).unwrap();
    let mut settings = RenderSettings::from_scene(&scene);
    (settings.width, settings.height, settings.spp, settings.seed, settings.threads) = (32, 24, 4, 3, 1);
    let one = tracer::render(&scene, &accel, &settings).unwrap();
    settings.threads = 3;
    let three = tracer::render(&scene, &accel, &settings).unwrap();
    assert_eq!(one.beauty, three.beauty);
}

/// The floor pixels' radiance against the analytic direct light of a sphere fully above the
/// horizon (E = π L r² cos θ / d², radiance ρ E / π), over the whole view.
fn direct_light_ratio(scene: &Scene, strategy: LightStrategy) -> f64 {
    let accel = Accel::build(scene).unwrap();
    let mut settings = RenderSettings::from_scene(scene);
    (settings.width, settings.height, settings.spp, settings.seed, settings.max_bounces) = (32, 24, 256, 5, 1);
    let lights = LightSampler::with_strategy(scene, strategy);
    let frame = tracer::render::render_with_lights(scene, &accel, &settings, &lights).unwrap();
    let (mut got, mut want) = (0.0f64, 0.0f64);
    for ((b, p), depth) in frame.beauty.iter().zip(&frame.position).zip(&frame.depth) {
        if *depth > 0.0 && p.y.abs() < 1e-3 && b.y < 5.0 {
            let to = Vec3::new(0.0, 2.0, 0.0) - *p;
            let d2 = to.length_squared() as f64;
            want += 0.5 * 30.0 * 0.25 * (to.y as f64 / d2.sqrt()) / d2;
            got += b.y as f64;
        }
    }
    got / want
}

#[test]
fn a_sphere_light_gives_the_analytic_direct_light_on_a_floor_of_any_size() {
    // Shadow rays used to leave from the surface's pushed-off origin along the direction from
    // the unpushed point, ending beside the light point; the push grows with the surface's
    // coordinates, and on a 1200-unit floor the segments ended inside the sphere: a quarter of
    // its direct light was lost (legacy sampling lost 6 % even at 200 units).
    for half_width in [5.0, 600.0] {
        let mut scene = sphere_over_floor(half_width);
        scene.environment = Vec3::ZERO;
        for strategy in [LightStrategy::ByContribution, LightStrategy::Legacy] {
            let ratio = direct_light_ratio(&scene, strategy);
            // The tessellation (subdivision 4) lies inside the sphere: up to 0.3 % less.
            assert!((ratio - 0.998).abs() < 0.01, "floor {half_width}, {strategy:?}: {ratio}");
        }
    }
}

/// A 1 × 1 rectangle light of radiance 10 facing down, `height` over a grey 200 × 200 floor, seen
/// from above and in front, no environment.
fn rectangle_over_floor(height: f32) -> Scene {
    common::scene_from_toml(&format!(
        r#"
        [render]
        max_bounces = 4
        [camera]
        position = [0, 3, 6]
        look_at = [0, 0, 0]
        fov = 50
        [[material]]
        name = "floor"
        base_color = [0.5, 0.5, 0.5]
        specular = 0
        [[material]]
        name = "lamp"
        emission = [10, 10, 10]
        [[mesh]]
        shape = "polygon"
        points = [[-100, 0, -100], [-100, 0, 100], [100, 0, 100], [100, 0, -100]]
        material = "floor"
        [[mesh]]
        shape = "polygon"
        points = [[-0.5, {height}, -0.5], [0.5, {height}, -0.5], [0.5, {height}, 0.5], [-0.5, {height}, 0.5]]
        material = "lamp"
        "#
    ))
}

/// Rectangle lights by solid angle: against `LightStrategy::Legacy`, which samples them by
/// area, the same image mean within noise and no more variance than noise allows on any scene, and much less where the
/// light is close to what it lights. The ratios go to docs/performance.md.
#[test]
fn rectangle_lights_by_solid_angle_keep_the_mean_and_lower_the_variance() {
    let root = common::project_root();
    let scenes = [
        ("rectangle 0.25 over a floor", rectangle_over_floor(0.25), 0.7),
        ("rectangle 2 over a floor", rectangle_over_floor(2.0), 0.95),
        // The Cornell boxes' light is small and far from most of what the camera sees, and
        // their noise is mostly indirect light: under 2 % less (a paired, seeded comparison).
        ("cornell.toml", Scene::load(&root.join("scenes/cornell.toml")).unwrap(), 1.0),
        ("cbox-mitsuba.toml", Scene::load(&root.join("scenes/cbox-mitsuba.toml")).unwrap(), 1.0),
        // The soft-shadow scene's lamp is a small rectangle close to the bunny; with its sky the
        // legacy strategy also differs in how it chooses between lamp and sky.
        ("soft-shadow.toml", Scene::load(&root.join("scenes/soft-shadow.toml")).unwrap(), 1.0),
        // Alone, the small lamp gains nothing, and this measurement's noise is large there (the
        // two strategies map the same random numbers to different light points, and the
        // penumbrae's dark pixels dominate the mean relative variance): 1.03 with solid angles
        // everywhere, 1.13 with the reach of two diagonals.
        (
            "soft-shadow.toml without its sky",
            without_sky(Scene::load(&root.join("scenes/soft-shadow.toml")).unwrap()),
            1.2,
        ),
    ];
    for (name, scene, bound) in scenes {
        let (old, old_mean, old_error) = lit_statistics(&render(&scene, LightStrategy::Legacy));
        let (new, new_mean, new_error) = lit_statistics(&render(&scene, LightStrategy::ByContribution));
        let ratio = new / old;
        eprintln!(
            "{name}: mean relative variance at 16 spp: by area {old:.4}, by solid angle {new:.4}, ratio {ratio:.3}; \
             image mean {old_mean:.5} ± {old_error:.5} / {new_mean:.5} ± {new_error:.5}"
        );
        assert!(ratio <= bound, "{name}: variance ratio {ratio}");
        let difference = (new_mean - old_mean).abs();
        assert!(
            difference < 4.0 * (old_error.powi(2) + new_error.powi(2)).sqrt(),
            "{name}: means differ by {difference}"
        );
    }
}

fn without_sky(mut scene: Scene) -> Scene {
    scene.environment = Vec3::ZERO;
    scene
}
