//! `lens-time` sample dumps: fields present only when needed, values consistent with the
//! scene, and the paper's reprojection (Eq. 2–4) mapping samples back onto the geometry they
//! came from, which checks the signs and units of C1, C2 and the motion vectors.

use crate::common;

use common::{emissive_polygon, SQUARE_AT_DEPTH_4};
use sampleio::SampleFile;
use tracer::samples::lens_time;
use tracer::RenderSettings;
use tracer::{Accel, Scene};

fn dump(scene: &Scene, width: u32, height: u32, spp: u32, threads: usize) -> (tempfile::TempDir, std::path::PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("samples.lfrs");
    let accel = Accel::build(scene).unwrap();
    let settings =
        RenderSettings { width, height, spp, seed: 3, max_bounces: scene.max_bounces, threads, progress: false };
    lens_time::dump(scene, &accel, &settings, &tracer::samples::FieldSelection::All, &path).unwrap();
    (dir, path)
}

fn field_names(file: &SampleFile) -> Vec<String> {
    file.fields().iter().map(|f| f.name.clone()).collect()
}

/// An emissive square (radiance 2) 0.5 wide at depth 4 in front of a black void.
fn square(aperture: f32, motion: [f32; 3]) -> Scene {
    emissive_polygon(aperture, 2.0, 2.0, &SQUARE_AT_DEPTH_4, motion)
}

#[test]
fn a_static_pinhole_scene_gets_no_lens_time_or_motion_fields() {
    let (_dir, path) = dump(&square(0.0, [0.0; 3]), 8, 8, 2, 0);
    let file = SampleFile::open(&path).unwrap();
    assert_eq!(field_names(&file), ["x", "y", "z", "radiance", "depth_gradient"]);
    assert_eq!(file.header().record_size, 32);
}

#[test]
fn lens_and_motion_add_exactly_their_fields_within_64_bytes() {
    let (_dir, path) = dump(&square(0.1, [0.3, 0.0, 0.5]), 8, 8, 2, 0);
    let file = SampleFile::open(&path).unwrap();
    assert_eq!(field_names(&file), ["x", "y", "u", "v", "t", "z", "motion", "radiance", "depth_gradient"]);
    assert!(file.header().record_size <= 64, "TLFR used 64 bytes per sample");
    let camera = file.header().camera.as_ref().unwrap();
    assert!(camera.coc.c1 < 0.0 && camera.coc.c2 > 0.0);
    let motion = file.column("motion").unwrap();
    let z = file.column("z").unwrap();
    for i in 0..file.len() {
        if z[i].is_finite() {
            // World +x is image left (camera X = right = -x), so the camera-space motion is (-0.3, 0, 0.5).
            assert_eq!(&motion[3 * i..3 * i + 3], &[-0.3, 0.0, 0.5]);
        }
    }
}

#[test]
fn samples_are_consistent_with_the_scene() {
    let (_dir, path) = dump(&square(0.05, [0.0; 3]), 16, 16, 4, 0);
    let file = SampleFile::open(&path).unwrap();
    let (x, y, u, v) =
        (file.column("x").unwrap(), file.column("y").unwrap(), file.column("u").unwrap(), file.column("v").unwrap());
    let (z, radiance, gradient) =
        (file.column("z").unwrap(), file.column("radiance").unwrap(), file.column("depth_gradient").unwrap());
    let mut hits = 0;
    for i in 0..file.len() {
        let pixel = i / 4;
        let (px, py) = ((pixel % 16) as f32, (pixel / 16) as f32);
        assert!(x[i] >= px && x[i] < px + 1.0 && y[i] >= py && y[i] < py + 1.0, "sample {i} outside its pixel");
        assert!(u[i] * u[i] + v[i] * v[i] <= 1.0 + 1e-6);
        if z[i].is_finite() {
            hits += 1;
            assert!((z[i] - 4.0).abs() < 1e-4, "depth {}", z[i]);
            assert_eq!(&radiance[3 * i..3 * i + 3], &[2.0, 2.0, 2.0]);
            assert!(gradient[2 * i].abs() < 1e-3 && gradient[2 * i + 1].abs() < 1e-3);
        } else {
            assert_eq!(&radiance[3 * i..3 * i + 3], &[0.0, 0.0, 0.0]);
        }
    }
    assert!(hits > 0 && hits < file.len());
}

/// Eq. 3 with t̂ = t: the lens-centre screen position is x − u·C(z). Every sample that hit the
/// square must land inside the square's pinhole image there, however large the defocus.
#[test]
fn defocused_samples_reproject_to_the_lens_centre_inside_the_pinhole_image() {
    let scene = square(0.3, [0.0; 3]);
    let (_dir, path) = dump(&scene, 32, 32, 16, 0);
    let file = SampleFile::open(&path).unwrap();
    let coc = file.header().camera.as_ref().unwrap().coc;
    let (x, y, u, v, z) = (
        file.column("x").unwrap(),
        file.column("y").unwrap(),
        file.column("u").unwrap(),
        file.column("v").unwrap(),
        file.column("z").unwrap(),
    );
    // Pinhole image of the square: corners at (±0.25, ±0.25, 4).
    let corner = scene.camera.project(glam::Vec3::new(0.25, 0.25, 4.0), glam::Vec2::ZERO, 32, 32).unwrap();
    let other = scene.camera.project(glam::Vec3::new(-0.25, -0.25, 4.0), glam::Vec2::ZERO, 32, 32).unwrap();
    let (lo, hi) = (corner.min(other), corner.max(other));
    let c = (coc.c1 / 4.0 + coc.c2) as f32;
    assert!(c.abs() > 1.0, "the test needs a defocus of more than a pixel, got {c}");
    let mut hits = 0;
    for i in 0..file.len() {
        if !z[i].is_finite() {
            continue;
        }
        hits += 1;
        let (cx, cy) = (x[i] - u[i] * c, y[i] - v[i] * c);
        assert!(
            cx > lo.x - 1e-2 && cx < hi.x + 1e-2 && cy > lo.y - 1e-2 && cy < hi.y + 1e-2,
            "sample {i} reprojects to ({cx}, {cy}), outside {lo}..{hi}"
        );
    }
    assert!(hits > 100);
}

/// Eq. 2–3 with û = 0, t̂ = 0: moving every hit back along its motion vector lands it inside
/// the square's image at shutter open.
#[test]
fn moving_samples_reproject_to_their_position_at_shutter_open() {
    let scene = square(0.0, [0.4, 0.1, 1.0]);
    let (_dir, path) = dump(&scene, 32, 32, 8, 0);
    let file = SampleFile::open(&path).unwrap();
    let camera = file.header().camera.as_ref().unwrap();
    let (fx, fy) = (1.0 / camera.pixel_to_camera[0][0], 1.0 / camera.pixel_to_camera[1][1]);
    let (cx, cy) = (-camera.pixel_to_camera[0][2] * fx, -camera.pixel_to_camera[1][2] * fy);
    let (x, y, t, z, motion) = (
        file.column("x").unwrap(),
        file.column("y").unwrap(),
        file.column("t").unwrap(),
        file.column("z").unwrap(),
        file.column("motion").unwrap(),
    );
    let corner = scene.camera.project(glam::Vec3::new(0.25, 0.25, 4.0), glam::Vec2::ZERO, 32, 32).unwrap();
    let other = scene.camera.project(glam::Vec3::new(-0.25, -0.25, 4.0), glam::Vec2::ZERO, 32, 32).unwrap();
    let (lo, hi) = (corner.min(other), corner.max(other));
    let mut hits = 0;
    for i in 0..file.len() {
        if !z[i].is_finite() {
            continue;
        }
        hits += 1;
        let (zi, ti) = (z[i] as f64, t[i] as f64);
        // Homogeneous screen motion (Eq. 3): v = (fx ΔX + cx ΔZ, fy ΔY + cy ΔZ, ΔZ).
        let (dx, dy, dz) = (motion[3 * i] as f64, motion[3 * i + 1] as f64, motion[3 * i + 2] as f64);
        let (vx, vy, vz) = (fx * dx + cx * dz, fy * dy + cy * dz, dz);
        let z0 = zi + (0.0 - ti) * vz;
        let x0 = (x[i] as f64 * zi + (0.0 - ti) * vx) / z0;
        let y0 = (y[i] as f64 * zi + (0.0 - ti) * vy) / z0;
        assert!((z0 - 4.0).abs() < 1e-3, "depth at shutter open {z0}");
        assert!(
            x0 > lo.x as f64 - 1e-2 && x0 < hi.x as f64 + 1e-2 && y0 > lo.y as f64 - 1e-2 && y0 < hi.y as f64 + 1e-2,
            "sample {i} reprojects to ({x0}, {y0}), outside {lo}..{hi}"
        );
    }
    assert!(hits > 100);
}

#[test]
fn dumps_are_byte_identical_for_any_thread_count() {
    let scene = square(0.1, [0.2, 0.0, 0.3]);
    let (_a, one) = dump(&scene, 12, 10, 3, 1);
    let (_b, two) = dump(&scene, 12, 10, 3, 2);
    assert_eq!(std::fs::read(one).unwrap(), std::fs::read(two).unwrap());
}

#[test]
fn glossy_scenes_add_the_brdf_bandwidth_within_64_bytes() {
    let _ = common::shared_scenes();
    let scene = Scene::load(&common::project_root().join("scenes/monkeys-defocus-motion.toml")).unwrap();
    let (_dir, path) = dump(&scene, 24, 16, 2, 0);
    let file = SampleFile::open(&path).unwrap();
    assert_eq!(field_names(&file), ["x", "y", "u", "v", "t", "z", "motion", "radiance", "depth_gradient", "bandwidth"]);
    assert!(file.header().record_size <= 64, "{} bytes", file.header().record_size);
    let (bandwidth, z) = (file.column("bandwidth").unwrap(), file.column("z").unwrap());
    for (k, z) in bandwidth.iter().zip(&z) {
        assert!(k.is_finite() && *k >= 0.0);
        if !z.is_finite() {
            assert_eq!(*k, 0.0, "a miss has no BRDF");
        }
    }
    assert!(bandwidth.iter().any(|&k| k > 0.0), "the metal heads and floor are glossy");
}

/// `direct`: written only when a selection names it, so full dumps keep their
/// size. With one bounce every sample's radiance is its direct part; with more bounces the
/// direct part is the one-bounce radiance of the same seed (the first hit draws the same
/// numbers), and the rest is what the longer paths add (never negative per channel here: every
/// contribution is).
#[test]
fn direct_is_written_when_named_and_is_the_one_bounce_radiance() {
    let _ = common::shared_scenes();
    let mut scene = Scene::load(&common::project_root().join("scenes/monkeys-defocus-motion.toml")).unwrap();
    let dump_named = |scene: &Scene, fields: &tracer::samples::FieldSelection| {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("samples.lfrs");
        let accel = Accel::build(scene).unwrap();
        let settings = RenderSettings {
            width: 24,
            height: 16,
            spp: 2,
            seed: 3,
            max_bounces: scene.max_bounces,
            threads: 0,
            progress: false,
        };
        lens_time::dump(scene, &accel, &settings, fields, &path).unwrap();
        (dir, path)
    };
    let (_full_dir, full) = dump(&scene, 24, 16, 2, 0);
    assert!(
        !field_names(&SampleFile::open(&full).unwrap()).contains(&"direct".to_string()),
        "a full dump leaves it out"
    );
    let named = tracer::samples::FieldSelection::parse_strict("z,radiance,direct").unwrap();
    scene.max_bounces = 4;
    let (_many_dir, many) = dump_named(&scene, &named);
    scene.max_bounces = 1;
    let (_one_dir, one) = dump_named(&scene, &named);
    let (many, one) = (SampleFile::open(&many).unwrap(), SampleFile::open(&one).unwrap());
    assert_eq!(field_names(&many), ["z", "radiance", "direct"]);
    let column = |file: &SampleFile, name: &str| file.column(name).unwrap();
    assert_eq!(column(&one, "direct"), column(&one, "radiance"), "one bounce: all of it is direct");
    assert_eq!(column(&many, "direct"), column(&one, "radiance"), "the same first bounce");
    let (radiance, direct) = (column(&many, "radiance"), column(&many, "direct"));
    assert!(radiance.iter().zip(&direct).all(|(r, d)| r >= d));
    let longer = radiance.iter().zip(&direct).filter(|(r, d)| r > d).count();
    assert!(longer > radiance.len() / 20, "indirect light in {longer} of {} values", radiance.len());
}
