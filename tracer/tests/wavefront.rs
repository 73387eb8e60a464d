//! `render` advances the paths of a tile together, one ray at a time (a wavefront); the samples
//! tracers hand out trace one path at a time (`Integrator::trace`). Both must be the same
//! estimator: this test recomputes every pixel one path at a time and asks for equality, bit for
//! bit, of every layer and of the ray count.

use crate::common;

use common::scene_from_toml;
use glam::Vec3;
use tracer::integrator::{Integrator, NoRecording};
use tracer::lights::LightSampler;
use tracer::sampler::Sampler;
use tracer::{Accel, RenderSettings, Scene};

/// The layers `render` averages, recomputed with one `Integrator::trace` call per sample and
/// the same double-precision sums, in the same order.
struct PathAtATime {
    beauty: Vec<Vec3>,
    direct: Vec<Vec3>,
    indirect: Vec<Vec3>,
    albedo: Vec<Vec3>,
    depth: Vec<f32>,
    rays: u64,
}

fn path_at_a_time(scene: &Scene, accel: &Accel, settings: &RenderSettings) -> PathAtATime {
    let lights = LightSampler::new(scene);
    let integrator = Integrator::new(scene, accel, &lights, settings.max_bounces, settings.width, settings.height);
    let n = (settings.width * settings.height) as usize;
    let mut out = PathAtATime {
        beauty: vec![Vec3::ZERO; n],
        direct: vec![Vec3::ZERO; n],
        indirect: vec![Vec3::ZERO; n],
        albedo: vec![Vec3::ZERO; n],
        depth: vec![0.0; n],
        rays: 0,
    };
    for py in 0..settings.height {
        for px in 0..settings.width {
            let (mut sum, mut direct, mut indirect) = ([0.0f64; 3], [0.0f64; 3], [0.0f64; 3]);
            let (mut albedo, mut depth, mut hits, mut valid) = (Vec3::ZERO, 0.0f64, 0u32, 0u32);
            for index in 0..settings.spp {
                let mut sampler = Sampler::new(settings.seed, px, py, index);
                let sample = integrator.trace(px, py, &mut sampler, &mut NoRecording);
                out.rays += sample.rays as u64;
                if !sample.radiance().is_finite() {
                    continue;
                }
                valid += 1;
                for c in 0..3 {
                    sum[c] += sample.radiance()[c] as f64;
                    direct[c] += sample.direct[c] as f64;
                    indirect[c] += sample.indirect[c] as f64;
                }
                if let Some(first) = sample.first_hit {
                    hits += 1;
                    albedo += first.albedo;
                    depth += first.depth as f64;
                }
            }
            let p = (py * settings.width + px) as usize;
            let mean = |s: [f64; 3]| Vec3::from(s.map(|v| (v / valid as f64) as f32));
            if valid > 0 {
                out.beauty[p] = mean(sum);
                out.direct[p] = mean(direct);
                out.indirect[p] = mean(indirect);
            }
            if hits > 0 {
                out.albedo[p] = albedo / hits as f32;
                out.depth[p] = (depth / hits as f64) as f32;
            }
        }
    }
    out
}

fn assert_wavefront_matches_path_at_a_time(scene: &Scene, width: u32, height: u32, spp: u32, seed: u32) {
    let accel = Accel::build(scene).expect("accelerator builds");
    let settings =
        RenderSettings { width, height, spp, seed, max_bounces: scene.max_bounces, threads: 2, progress: false };
    let frame = tracer::render(scene, &accel, &settings).expect("render");
    let reference = path_at_a_time(scene, &accel, &settings);
    let bits = |v: &[Vec3]| v.iter().flat_map(|x| x.to_array().map(f32::to_bits)).collect::<Vec<_>>();
    assert_eq!(bits(&frame.beauty), bits(&reference.beauty), "beauty");
    assert_eq!(bits(&frame.direct), bits(&reference.direct), "direct");
    assert_eq!(bits(&frame.indirect), bits(&reference.indirect), "indirect");
    assert_eq!(bits(&frame.albedo), bits(&reference.albedo), "albedo");
    let depth_bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(depth_bits(&frame.depth), depth_bits(&reference.depth), "depth");
    assert_eq!(frame.rays, reference.rays, "rays");
    // Not a vacuous comparison: the scene shows light, and paths go on past the first hit.
    assert!(frame.beauty.iter().any(|v| v.max_element() > 0.0));
    assert!(frame.rays > 2 * (width * height * spp) as u64, "{} rays", frame.rays);
}

#[test]
fn wavefront_render_equals_one_path_at_a_time_on_the_cornell_box() {
    // A width that is not a multiple of the 16-pixel tile, so partial tiles are covered too.
    let scene = scene_from_toml(include_str!("../../scenes/cornell.toml"));
    assert_wavefront_matches_path_at_a_time(&scene, 21, 18, 3, 5);
}

/// Everything else a path can meet: an environment that escaping rays see, a point light and a
/// sphere light, a mirror-like and a rough metal, a thin lens, a moving emitter (so rays carry
/// time), and a bounce limit that ends paths.
#[test]
fn wavefront_render_equals_one_path_at_a_time_with_lens_motion_environment_and_glossy_metal() {
    let scene = scene_from_toml(
        r#"
        [render]
        max_bounces = 5
        environment = [0.2, 0.3, 0.4]
        [camera]
        position = [0, 1, -4]
        look_at = [0, 0.5, 0]
        fov = 45
        aperture_radius = 0.05
        focus_distance = 4
        [[material]]
        name = "floor"
        base_color = [0.8, 0.8, 0.8]
        [[material]]
        name = "mirror"
        base_color = [0.9, 0.9, 0.9]
        metallic = 1
        roughness = 0.001
        [[material]]
        name = "rough"
        base_color = [0.9, 0.6, 0.3]
        metallic = 1
        roughness = 1
        [[material]]
        name = "lamp"
        base_color = [0, 0, 0]
        emission = [5, 5, 5]
        [[mesh]]
        shape = "polygon"
        material = "floor"
        points = [[-3, 0, -3], [-3, 0, 3], [3, 0, 3], [3, 0, -3]]
        [[mesh]]
        shape = "sphere"
        material = "mirror"
        center = [-0.7, 0.5, 0]
        radius = 0.5
        [[mesh]]
        shape = "box"
        material = "rough"
        min = [0.3, 0, -0.4]
        max = [1.1, 0.8, 0.4]
        [[mesh]]
        shape = "polygon"
        material = "lamp"
        points = [[-0.5, 2, -0.5], [0.5, 2, -0.5], [0.5, 2, 0.5], [-0.5, 2, 0.5]]
        motion = [0.5, 0, 0]
        [[light]]
        type = "point"
        position = [1, 3, -1]
        intensity = [4, 4, 4]
        [[light]]
        type = "sphere"
        center = [-1.5, 1.5, -1]
        radius = 0.2
        radiance = [3, 2, 1]
        "#,
    );
    assert!(scene.has_motion() && scene.camera.has_lens());
    assert_wavefront_matches_path_at_a_time(&scene, 20, 17, 4, 9);
}

/// `render_pixels` traces a sparse list of pixels: each pixel's means must be those of the
/// whole-image render bit for bit (the pixel's random numbers depend on nothing else), in the
/// list's order, with repeats, and for 1 and 2 threads; a pixel outside the image is refused.
#[test]
fn rendering_a_list_of_pixels_equals_those_pixels_of_the_whole_image() {
    let scene = scene_from_toml(include_str!("../../scenes/cornell.toml"));
    let accel = Accel::build(&scene).expect("accelerator builds");
    let (width, height) = (21u32, 18u32);
    let settings =
        RenderSettings { width, height, spp: 3, seed: 7, max_bounces: scene.max_bounces, threads: 2, progress: false };
    let frame = tracer::render(&scene, &accel, &settings).expect("render");
    // Scattered over several tiles (an odd stride), the last pixel, a repeat, unsorted; more
    // than one 256-pixel group so the parallel split is exercised.
    let mut pixels: Vec<(u32, u32)> = (0..300u32).map(|i| ((i * 7) % width, (i * 11 + i / 5) % height)).collect();
    pixels.extend([(width - 1, height - 1), (0, 0), (0, 0)]);
    for threads in [1, 2] {
        let settings = RenderSettings { threads, ..settings.clone() };
        let means = tracer::render::render_pixels(&scene, &accel, &settings, &pixels).expect("render pixels");
        assert_eq!(means.len(), pixels.len());
        for (&(x, y), m) in pixels.iter().zip(&means) {
            let p = (y * width + x) as usize;
            let bits = |v: Vec3| v.to_array().map(f32::to_bits);
            assert_eq!(bits(m.beauty), bits(frame.beauty[p]), "beauty at ({x}, {y}), {threads} threads");
            assert_eq!(bits(m.direct), bits(frame.direct[p]), "direct at ({x}, {y})");
            assert_eq!(bits(m.indirect), bits(frame.indirect[p]), "indirect at ({x}, {y})");
        }
    }
    assert!(frame.indirect.iter().any(|v| v.max_element() > 0.0), "not vacuous: the box has indirect light");
    let outside = tracer::render::render_pixels(&scene, &accel, &settings, &[(3, 2), (width, 0)]).unwrap_err();
    assert!(outside.to_string().contains(&format!("({width}, 0) is outside the {width}x{height} image")), "{outside}");
    assert!(tracer::render::render_pixels(&scene, &accel, &settings, &[]).unwrap().is_empty());
}
