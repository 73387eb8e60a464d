//! `lfr filter` end to end (the filtered path-tracing pipeline of Bauszat et al. 2011) and the
//! tracer's additional eye rays it reads.

use crate::common;

use std::path::Path;
use std::process::{Command, Output};

use common::{exr_channel, furnace, project_root, SceneToml};
use glam::{Vec2, Vec3};
use tracer::Accel;
use tracer::RenderSettings;

fn lfr(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_lfr")).args(args).current_dir(project_root()).output().expect("lfr runs")
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn run_filter(dir: &Path, scene: &Path, name: &str, extra: &[&str]) -> std::path::PathBuf {
    let out = dir.join(name);
    let mut args = vec![
        "filter",
        "--scene",
        scene.to_str().unwrap(),
        "--width",
        "24",
        "--height",
        "20",
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ];
    args.extend_from_slice(extra);
    let result = lfr(&args);
    assert!(result.status.success(), "{}", stderr(&result));
    out
}

#[test]
fn the_composite_of_a_white_furnace_is_the_environment() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("furnace.toml");
    std::fs::write(&scene, furnace().text()).unwrap();
    let environment = [0.5f32, 1.0, 2.0];
    let runs: [(&str, &[&str]); 4] =
        [("gif", &[]), ("gif", &["--subsample", "2"]), ("bilateral", &[]), ("atrous-sn", &[])];
    for (index, (filter, extra)) in runs.into_iter().enumerate() {
        let mut args = vec!["--spp", "4", "--filter", filter];
        args.extend_from_slice(extra);
        let out = run_filter(dir.path(), &scene, &format!("{filter}-{index}.exr"), &args);
        assert!(out.with_extension("png").is_file());
        for (c, channel) in ["R", "G", "B"].iter().enumerate() {
            let beauty = exr_channel(&out, channel);
            let direct = exr_channel(&out, &format!("direct.{channel}"));
            let indirect = exr_channel(&out, &format!("indirect.{channel}"));
            let mean = beauty.iter().map(|v| *v as f64).sum::<f64>() / beauty.len() as f64;
            let relative = (mean - environment[c] as f64).abs() / environment[c] as f64;
            assert!(relative < 0.03, "{filter} {channel}: mean {mean} vs {}", environment[c]);
            for i in 0..beauty.len() {
                assert!((beauty[i] - direct[i] - indirect[i]).abs() <= 1e-5 * beauty[i].abs().max(1.0));
                assert!(beauty[i].is_finite() && indirect[i] >= 0.0);
            }
        }
    }
}

#[test]
fn the_pipeline_is_deterministic_for_any_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    let scene = project_root().join("scenes/cornell.toml");
    let one = run_filter(dir.path(), &scene, "one.exr", &["--spp", "3", "--threads", "1"]);
    let two = run_filter(dir.path(), &scene, "two.exr", &["--spp", "3", "--threads", "2"]);
    for channel in ["R", "G", "B", "indirect.R", "direct.G", "indirect_unfiltered.B", "albedo.R", "depth.Z"] {
        let (a, b) = (exr_channel(&one, channel), exr_channel(&two, channel));
        assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()), "{channel} differs");
    }
    let other = run_filter(dir.path(), &scene, "other.exr", &["--spp", "3", "--seed", "7"]);
    assert_ne!(exr_channel(&one, "R"), exr_channel(&other, "R"), "another seed gives another image");
}

#[test]
fn bad_filter_options_are_clear_errors_without_output() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.exr");
    let out = out.to_str().unwrap();
    let cases: [(&[&str], &str); 9] = [
        (&["--filter", "median"], "gif-normal"),
        (&["--epsilon-normal", "0"], "--epsilon-normal"),
        (&["--epsilon-depth", "nan"], "--epsilon-depth"),
        (&["--filter", "atrous", "--radius", "8"], "does not apply"),
        (&["--iterations", "5"], "does not apply"),
        (&["--filter", "atrous", "--iterations", "40"], "iterations"),
        (&["--spp", "0"], "--spp"),
        (&["--subsample", "0"], "at least 1"),
        (&["--filter", "atrous", "--subsample", "2"], "does not apply"),
    ];
    for (extra, needle) in cases {
        let mut args = vec!["filter", "--width", "8", "--height", "8", "--out", out, "--quiet"];
        args.extend_from_slice(extra);
        let result = lfr(&args);
        let message = stderr(&result);
        assert!(!result.status.success(), "{extra:?} must fail");
        assert!(message.contains(needle) && !message.contains("panicked"), "{extra:?}: {message}");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "{extra:?} left output");
    }
    let result = lfr(&["filter", "--out", dir.path().join("x.png").to_str().unwrap()]);
    assert!(stderr(&result).contains(".exr"));
}

/// The additional eye rays: `spp − 1` per pixel inside their pixel, misses see the environment,
/// hits on a unit sphere have unit normals pointing outwards and the depth of a point on it;
/// the secondary-hit normal is a unit vector wherever a path reached a second surface.
#[test]
fn eye_rays_lie_in_their_pixels_and_see_the_geometry() {
    let scene = SceneToml::new(8, Some([0.5, 1.0, 2.0]))
        .camera([0.0, 0.0, 4.0], [0.0; 3], 40.0, "")
        .diffuse("white", [0.8; 3])
        .sphere("white", [0.0; 3], 1.0, "subdivisions = 5\n")
        .raw("[[mesh]]\nshape = \"box\"\nmin = [-3, -1.6, -3]\nmax = [3, -1.5, 3]\nmaterial = \"white\"")
        .scene();
    let accel = Accel::build(&scene).unwrap();
    let (width, height, spp) = (10, 8, 4);
    let settings = RenderSettings { width, height, spp, seed: 3, max_bounces: 8, threads: 0, progress: false };
    let guide = tracer::samples::guide::guide_buffers(&scene, &accel, &settings).unwrap();
    assert_eq!(guide.eye_rays_per_pixel, spp - 1);
    assert_eq!(guide.eye_rays.len(), (width * height * (spp - 1)) as usize);
    let (mut hits, mut misses) = (0, 0);
    for (i, ray) in guide.eye_rays.iter().enumerate() {
        let pixel = i / (spp - 1) as usize;
        let corner = Vec2::new((pixel as u32 % width) as f32, (pixel as u32 / width) as f32);
        let offset = ray.film - corner;
        assert!(
            offset.min_element() >= 0.0 && offset.max_element() < 1.0,
            "eye ray {i} at {} off pixel {pixel}",
            ray.film
        );
        if ray.depth == 0.0 {
            misses += 1;
            assert_eq!(ray.direct, Vec3::new(0.5, 1.0, 2.0), "a miss sees the environment");
            assert_eq!(ray.normal, Vec3::ZERO);
            continue;
        }
        hits += 1;
        assert!((ray.normal.length() - 1.0).abs() < 1e-3 && ray.direct.is_finite());
        assert!(ray.direct.min_element() >= 0.0 && ray.albedo.max_element() <= 1.0);
    }
    assert!(hits > 20 && misses > 20, "{hits} hits, {misses} misses");
    let with_secondary = guide.secondary_normal.iter().filter(|n| **n != Vec3::ZERO).count();
    assert!(with_secondary > 10);
    assert!(guide.secondary_normal.iter().all(|n| *n == Vec3::ZERO || (n.length() - 1.0).abs() < 1e-3));
    let one = tracer::samples::guide::guide_buffers(&scene, &accel, &RenderSettings { spp: 1, ..settings }).unwrap();
    assert!(one.eye_rays.is_empty() && one.eye_rays_per_pixel == 0, "1 spp: the guide ray only");
}
