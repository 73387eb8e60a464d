//! The temporal light field reconstruction's pieces on the tracer's own `lens-time` files:
//! reprojection (Eq. 2–4) against the tracer's projection of the moving geometry, and the
//! radius R measured on the tracer's sampling pattern.

use crate::common;

use common::{emissive_polygon, SceneToml, FLOOR, LAMP, SQUARE_AT_DEPTH_4};
use glam::{Vec2, Vec3};
use recon::tlfr::dispersion::measure_radius;
use recon::tlfr::reprojection::{near_limit, reproject, LensTime};
use recon::tlfr::samples::read_lens_time;
use sampleio::SampleFile;
use tracer::samples::lens_time;
use tracer::RenderSettings;
use tracer::{Accel, Scene};

/// An emissive square 0.5 wide at depth 4, seen through an open lens focused at 2, moving by
/// (0.4, 0.1, 1.0) over the shutter.
fn moving_square() -> Scene {
    emissive_polygon(0.2, 2.0, 2.0, &SQUARE_AT_DEPTH_4, [0.4, 0.1, 1.0])
}

fn dump(scene: &Scene, width: u32, height: u32, spp: u32) -> (tempfile::TempDir, std::path::PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("samples.lfrs");
    let accel = Accel::build(scene).unwrap();
    let settings = RenderSettings { width, height, spp, seed: 5, max_bounces: 0, threads: 0, progress: false };
    lens_time::dump(scene, &accel, &settings, &tracer::samples::FieldSelection::All, &path).unwrap();
    (dir, path)
}

/// Every sample that hit the square, reprojected to a random (û, v̂, t̂), lands inside the
/// image of the square moved to t̂ and seen through the lens point (û, v̂), as the tracer's own
/// camera projects it.
#[test]
fn reprojected_tracer_samples_land_on_the_moved_square() {
    let scene = moving_square();
    let (width, height) = (32, 32);
    let (_dir, path) = dump(&scene, width, height, 8);
    let loaded = read_lens_time(&SampleFile::open(&path).unwrap()).unwrap();
    assert!(loaded.has_lens && loaded.has_time && loaded.dropped == 0);
    let z_near = near_limit(loaded.samples.iter().map(|s| s.z));
    let motion = Vec3::new(0.4, 0.1, 1.0);
    let corners = [[-0.25, -0.25], [0.25, -0.25], [0.25, 0.25], [-0.25, 0.25]];
    let mut state = 99u32;
    let mut next = move || {
        state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        (state >> 8) as f32 / (1u32 << 24) as f32
    };
    let mut hits = 0;
    for (sample, _) in loaded.samples.iter().zip(&loaded.radiance) {
        if sample.z.is_infinite() {
            continue;
        }
        hits += 1;
        let (r, phi) = (next().sqrt(), std::f32::consts::TAU * next());
        let at = LensTime { u: r * phi.cos(), v: r * phi.sin(), t: next() };
        let image: Vec<Vec2> = corners
            .iter()
            .map(|c| {
                let corner = Vec3::new(c[0], c[1], 4.0) + at.t * motion;
                // The file's v runs along image +y, the tracer's lens coordinate along up.
                scene.camera.project(corner, Vec2::new(at.u, -at.v), width, height).unwrap()
            })
            .collect();
        let lo = image.iter().fold(Vec2::splat(f32::INFINITY), |m, p| m.min(*p));
        let hi = image.iter().fold(Vec2::splat(f32::NEG_INFINITY), |m, p| m.max(*p));
        let p = reproject(sample, &loaded.lens, at, z_near).expect("the square stays in front of the camera");
        assert!(
            p.x > lo.x - 2e-2 && p.x < hi.x + 2e-2 && p.y > lo.y - 2e-2 && p.y < hi.y + 2e-2,
            "{sample:?} at {at:?} → ({}, {}), outside {lo}..{hi}",
            p.x,
            p.y
        );
        assert!((p.z - (4.0 + at.t)).abs() < 1e-3, "depth {}", p.z);
    }
    assert!(hits > 100, "{hits}");
}

/// The paper measures R ≈ 2/sqrt(N) for its Sobol' patterns; ours pairs the screen, lens and
/// time dimensions by per-pixel shuffling. The measured R must fall as 1/sqrt(spp) within a
/// band around the paper's value.
#[test]
fn the_tracers_pattern_has_a_radius_near_two_over_root_spp() {
    let scene = moving_square();
    let mut previous = f32::INFINITY;
    for spp in [1u32, 4, 16] {
        let (width, height) = (64, 48);
        let (_dir, path) = dump(&scene, width, height, spp);
        let loaded = read_lens_time(&SampleFile::open(&path).unwrap()).unwrap();
        let r = measure_radius(&loaded.samples, width, height, spp, 16, 0).unwrap();
        let scaled = r * (spp as f32).sqrt();
        println!("spp {spp}: R = {r:.3} px, R·sqrt(spp) = {scaled:.3} (paper: about 2)");
        assert!((1.2..=3.0).contains(&scaled), "spp {spp}: R·sqrt(spp) = {scaled}");
        assert!(r < previous);
        previous = r;
    }
}

fn compare(out: &std::path::Path, cache: &std::path::Path, threads: &str) -> serde_json::Value {
    let result = std::process::Command::new(env!("CARGO_BIN_EXE_lfr"))
        .args(["compare", "--scene", "scenes/monkeys-defocus-motion.toml", "--effect", "dof-motion"])
        .args(["--width", "64", "--height", "36", "--spp", "4", "--recon-rays", "16", "--reference-spp", "256"])
        .args(["--pt-max-spp", "16", "--methods", "box,tlfr", "--threads", threads, "--quiet"])
        .args(["--out", out.to_str().unwrap(), "--cache-dir", cache.to_str().unwrap()])
        .current_dir(common::project_root())
        .env("LFR_SCENES", common::shared_scenes())
        .output()
        .unwrap();
    assert!(result.status.success(), "{}", String::from_utf8_lossy(&result.stderr));
    serde_json::from_slice(&std::fs::read(out.join("results.json")).unwrap()).unwrap()
}

/// End to end through `lfr compare`: at equal input (4 spp) the reconstruction has a lower
/// error than the per-pixel average of the same samples, its output is finite, and it is the
/// same for 1 and 2 threads, bit for bit.
#[test]
fn tlfr_beats_the_box_filter_of_its_input_and_is_deterministic() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let results = compare(&dir.path().join("two"), &cache, "2");
    let run =
        |method: &str| results["runs"].as_array().unwrap().iter().find(|r| r["method"] == method).unwrap().clone();
    let (tlfr, boxed) = (run("tlfr"), run("box"));
    let (ours, theirs) = (tlfr["psnr_db"].as_f64().unwrap(), boxed["psnr_db"].as_f64().unwrap());
    assert!(ours > theirs + 1.5, "tlfr {ours} dB vs box {theirs} dB at 4 spp");
    assert!(tlfr["valid"].as_bool().unwrap());
    let notes = tlfr["notes"].to_string();
    assert!(notes.contains("R = ") && notes.contains("bytes per sample"), "{notes}");
    let one = compare(&dir.path().join("one"), &cache, "1");
    let image = |dir: &str| {
        let path = dir.to_string() + "/images/tlfr-4spp-16rays.exr";
        tracer::output::read_exr(std::path::Path::new(&path)).unwrap().2
    };
    assert_eq!(
        image(dir.path().join("one").to_str().unwrap()),
        image(dir.path().join("two").to_str().unwrap()),
        "1 and 2 threads differ"
    );
    assert!(one["runs"].as_array().unwrap().iter().any(|r| r["method"] == "tlfr"));
}

/// Refocusing after the fact (`lfr reconstruct --focus-distance --aperture`): samples of a
/// static emissive square at depth 4 taken through a lens focused at 2 (a blur of about 2 px)
/// and refocused onto the square give its sharp image: full brightness a pixel and a half inside
/// its edges, black a pixel and a half outside; without refocusing light spills beyond them.
/// A static 1 × 1 emitting square at depth 4 seen through a 0.2 lens focused at 2.
fn still_square() -> Scene {
    emissive_polygon(0.2, 2.0, 2.0, &[[-0.5, -0.5, 4.0], [0.5, -0.5, 4.0], [0.5, 0.5, 4.0], [-0.5, 0.5, 4.0]], [0.0; 3])
}

#[test]
fn refocusing_onto_the_square_makes_it_sharp() {
    let scene = still_square();
    let (width, height) = (32u32, 32u32);
    let (dir, path) = dump(&scene, width, height, 8);
    let out = |name: &str| dir.path().join(name);
    let run = |extra: &[&str], name: &str| {
        let mut args = vec!["reconstruct", "--samples", path.to_str().unwrap(), "--locations", "32"];
        args.extend_from_slice(extra);
        let target = out(name);
        args.extend_from_slice(&["--out", target.to_str().unwrap()]);
        let result = std::process::Command::new(env!("CARGO_BIN_EXE_lfr")).args(&args).output().unwrap();
        assert!(result.status.success(), "{}", String::from_utf8_lossy(&result.stderr));
        assert!(out(name).with_extension("png").is_file());
        tracer::output::read_exr(&out(name)).unwrap().2.into_iter().find(|(n, _)| n == "R").unwrap().1
    };
    let sharp = run(&["--focus-distance", "4", "--aperture", "0.2"], "sharp.exr");
    let blurred = run(&[], "blurred.exr");
    let corner = scene.camera.project(Vec3::new(0.5, 0.5, 4.0), Vec2::ZERO, width, height).unwrap();
    let other = scene.camera.project(Vec3::new(-0.5, -0.5, 4.0), Vec2::ZERO, width, height).unwrap();
    let (lo, hi) = (corner.min(other), corner.max(other));
    let (mut inside, mut outside, mut blurred_edges) = (0, 0, 0);
    for y in 0..height {
        for x in 0..width {
            let centre = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
            let i = (y * width + x) as usize;
            let depth_inside = (centre - lo).min(hi - centre).min_element();
            if depth_inside > 1.5 {
                inside += 1;
                assert!(sharp[i] > 1.9, "pixel ({x}, {y}) inside: {}", sharp[i]);
            } else if depth_inside < -1.5 {
                outside += 1;
                assert!(sharp[i] < 0.1, "pixel ({x}, {y}) outside: {}", sharp[i]);
            }
            // The 2.2-px blur spills light up to two pixels beyond the edges.
            blurred_edges += (depth_inside > -2.5 && depth_inside < -0.5 && blurred[i] > 0.1) as usize;
        }
    }
    assert!(inside > 20 && outside > 100, "{inside} inside, {outside} outside");
    assert!(blurred_edges > 8, "the unfocused reconstruction must spill beyond the edges ({blurred_edges})");
    let bad = std::process::Command::new(env!("CARGO_BIN_EXE_lfr"))
        .args(["reconstruct", "--samples", path.to_str().unwrap(), "--aperture", "0.1", "--out"])
        .arg(out("bad.exr"))
        .output()
        .unwrap();
    assert!(!bad.status.success() && String::from_utf8_lossy(&bad.stderr).contains("go together"));
    assert!(!out("bad.exr").exists());
    // The bandwidth extension on a file without glossy surfaces (no `bandwidth` field) changes
    // nothing, bit for bit; an impossible scale is refused before anything is written.
    assert_eq!(run(&["--bandwidth"], "bandwidth.exr"), blurred);
    for scale in ["0", "-1", "nan", "inf"] {
        let bad = std::process::Command::new(env!("CARGO_BIN_EXE_lfr"))
            .args(["reconstruct", "--samples", path.to_str().unwrap(), &format!("--bandwidth={scale}"), "--out"])
            .arg(out("bad.exr"))
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&bad.stderr);
        assert!(!bad.status.success() && stderr.contains("--bandwidth"), "{scale}: {stderr}");
        assert!(!out("bad.exr").exists());
    }
}

/// A huge aperture (stiff case): the refocusing scene's samples (traced with a 0.2 lens) are
/// reconstructed for a lens of radius 2 focused at 1000, which spreads the 11-px square at depth
/// 4 over a disc of radius f·a·(1/4 − 1/1000) ≈ 22 px, larger than the 32-px image, while the
/// black background (misses) stays sharp. Analytically every pixel whose disc holds the whole
/// square sees radiance 2 × (square area)/(disc area) ≈ 0.16; the reconstruction must give that
/// in the middle of the image, finite everywhere. (Focused near, the background's own blur
/// would need samples from far outside the frame, which no file has.)
#[test]
fn a_huge_aperture_spreads_the_square_as_the_thin_lens_does() {
    let scene = still_square();
    let (width, height) = (32u32, 32u32);
    let (dir, path) = dump(&scene, width, height, 8);
    let target = dir.path().join("huge.exr");
    let result = std::process::Command::new(env!("CARGO_BIN_EXE_lfr"))
        .args(["reconstruct", "--samples", path.to_str().unwrap(), "--locations", "64"])
        .args(["--focus-distance", "1000", "--aperture", "2", "--out", target.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(result.status.success(), "{}", String::from_utf8_lossy(&result.stderr));
    let red = tracer::output::read_exr(&target).unwrap().2.into_iter().find(|(n, _)| n == "R").unwrap().1;
    assert!(red.iter().all(|v| v.is_finite()));
    let focal_px = 0.5 * height as f32 / (20.0f32.to_radians()).tan();
    let (square_px, disc_px) = (focal_px * 1.0 / 4.0, focal_px * 2.0 * (1.0 / 4.0 - 1.0 / 1000.0));
    let expected = 2.0 * square_px * square_px / (std::f32::consts::PI * disc_px * disc_px);
    let (mut sum, mut count) = (0.0f64, 0usize);
    for y in 0..height {
        for x in 0..width {
            let offset = Vec2::new(x as f32 + 0.5 - 16.0, y as f32 + 0.5 - 16.0).length();
            // Whole square inside the disc with a pixel to spare: offset + half diagonal + 1 < disc.
            if offset + square_px * std::f32::consts::FRAC_1_SQRT_2 + 1.0 < disc_px {
                // Each location sees the square (2) or not (0): single pixels are binomial noise
                // (about 40 % at 64 locations), so the check is on the mean over the region.
                sum += red[(y * width + x) as usize] as f64;
                count += 1;
            }
        }
    }
    let mean = sum / count as f64;
    eprintln!("huge aperture: {count} pixels, mean {mean} vs analytic {expected}");
    assert!(
        count > 400 && (mean - expected as f64).abs() < 0.05 * expected as f64,
        "{count} px, mean {mean} vs {expected}"
    );
}

/// The lamp-and-blocker scene of the soft-shadow tests; the lamp moves by `lamp_motion` over the
/// shutter.
fn lamp_and_blocker(lamp_motion: [f32; 3]) -> Scene {
    lamp_and_blocker_at(lamp_motion, 1.0)
}

/// `lamp_and_blocker` with every length (positions, motion) multiplied by `scale`: the same
/// image, since the lamp's radiance subtends the same solid angles.
fn lamp_and_blocker_at(lamp_motion: [f32; 3], scale: f32) -> Scene {
    let at = |p: [f32; 3]| p.map(|v| v * scale);
    let all = |points: &[[f32; 3]]| points.iter().map(|&p| at(p)).collect::<Vec<_>>();
    SceneToml::new(1, None)
        .camera(at([0.3, 1.6, 1.2]), [0.0; 3], 60.0, "")
        .emitter("lamp", [4.0; 3], "")
        .diffuse("grey", [0.5; 3])
        .polygon("lamp", &all(&LAMP), &format!("motion = {:?}\n", at(lamp_motion)))
        .polygon("grey", &all(&[[-0.2, 0.8, -0.2], [0.2, 0.8, -0.2], [0.2, 0.8, 0.2], [-0.2, 0.8, 0.2]]), "")
        .polygon("grey", &all(&FLOOR), "")
        .scene()
}

/// Stiff cases of the soft-shadow reconstruction with the light query's rim rule: the lamp scene
/// at 1e-6 and 1e9 of its size gives the unit scene's image (mean within 1 %, error against the
/// unit scene's converged image below the box filter's of the same samples, as at unit scale),
/// and a 1×1 image from 1 spp is finite.
#[test]
fn soft_shadows_keep_their_image_at_extreme_scales_and_on_one_pixel() {
    let reference = common::render(&lamp_and_blocker([0.0; 3]), 32, 32, 1024, 11);
    let keep = vec![true; 32 * 32];
    let unit = soft_shadow_run(&lamp_and_blocker([0.0; 3]), (32, 32), 4, &reference.beauty, &keep);
    for scale in [1e-6, 1e9] {
        let run = soft_shadow_run(&lamp_and_blocker_at([0.0; 3], scale), (32, 32), 4, &reference.beauty, &keep);
        assert!(
            (run.tlfr_mean / unit.tlfr_mean - 1.0).abs() < 0.01,
            "scale {scale}: mean {} against {} at unit scale",
            run.tlfr_mean,
            unit.tlfr_mean
        );
        assert!(
            run.tlfr_error < run.box_error,
            "scale {scale}: {} against the box's {}",
            run.tlfr_error,
            run.box_error
        );
    }
    let one = lamp_and_blocker([0.0; 3]);
    let pixel = common::render(&one, 1, 1, 64, 11);
    let run = soft_shadow_run(&one, (1, 1), 1, &pixel.beauty, &[true]);
    assert!(run.output.image.pixels.iter().flatten().all(|v| v.is_finite() && *v >= 0.0));
}

/// Reconstructs the soft shadows of `scene` from 4 spp at 32² and returns the image with the
/// RMSE of it and of the box filter of its input against 4096 spp.
fn soft_shadow_errors(scene: &Scene) -> (recon::tlfr::reconstruction::Reconstruction, f64, f64) {
    let reference = common::render(scene, 32, 32, 4096, 11);
    let run = soft_shadow_run(scene, (32, 32), 4, &reference.beauty, &vec![true; 32 * 32]);
    (run.output, run.tlfr_error, run.box_error)
}

/// One soft-shadow reconstruction (32 locations per pixel) against a converged image.
struct SoftShadowRun {
    output: recon::tlfr::reconstruction::Reconstruction,
    tlfr_error: f64,
    box_error: f64,
    /// Mean over pixels and channels of the reconstruction and of the box filter.
    tlfr_mean: f64,
    box_mean: f64,
}

/// Errors and means are taken over the pixels where `keep` is true.
fn soft_shadow_run(
    scene: &Scene,
    (width, height): (u32, u32),
    spp: u32,
    reference: &[Vec3],
    keep: &[bool],
) -> SoftShadowRun {
    let dir = tempfile::tempdir().unwrap();
    let (camera_path, light_path) = (dir.path().join("lens-time.lfrs"), dir.path().join("light.lfrs"));
    let accel = Accel::build(scene).unwrap();
    let settings = RenderSettings { width, height, spp, seed: 5, max_bounces: 1, threads: 0, progress: false };
    lens_time::dump_for_soft_shadows(scene, &accel, &settings, &tracer::samples::FieldSelection::All, &camera_path)
        .unwrap();
    tracer::samples::light::dump(scene, &accel, &settings, &tracer::samples::FieldSelection::All, &light_path).unwrap();
    let tlfr_settings = recon::tlfr::settings::TlfrSettings { locations: 32, ..Default::default() };
    let output = recon::tlfr::shadows::reconstruct_soft_shadow(&camera_path, &light_path, &tlfr_settings).unwrap();
    let (box_image, _) =
        recon::baselines::box_filter::average(&SampleFile::open(&camera_path).unwrap(), recon::Effect::SoftShadow, 0.0)
            .unwrap();
    let kept = keep.iter().filter(|&&k| k).count() as f64;
    let rmse = |pixels: &[[f32; 3]]| {
        let sum: f64 = (pixels.iter().zip(reference).zip(keep))
            .filter(|(_, &k)| k)
            .map(|((p, r), _)| (0..3).map(|c| (p[c] as f64 - r[c] as f64).powi(2)).sum::<f64>())
            .sum();
        (sum / (3.0 * kept)).sqrt()
    };
    let mean = |pixels: &[[f32; 3]]| {
        let sum: f64 =
            pixels.iter().zip(keep).filter(|(_, &k)| k).map(|(p, _)| p.iter().map(|&v| v as f64).sum::<f64>()).sum();
        sum / (3.0 * kept)
    };
    assert!(output.image.pixels.iter().flatten().all(|v| v.is_finite()));
    SoftShadowRun {
        tlfr_error: rmse(&output.image.pixels),
        box_error: rmse(&box_image.pixels),
        tlfr_mean: mean(&output.image.pixels),
        box_mean: mean(&box_image.pixels),
        output,
    }
}

fn image_mean(pixels: &[Vec3], keep: &[bool]) -> f64 {
    let kept = keep.iter().filter(|&&k| k).count() as f64;
    pixels.iter().zip(keep).filter(|(_, &k)| k).map(|(p, _)| (p.x + p.y + p.z) as f64).sum::<f64>() / (3.0 * kept)
}

/// On the Cornell box, whose ceiling light (130 × 105 mm, 0.5 mm below the ceiling)
/// lights the whole room from close by, the reconstruction was biased dark, and more so with
/// more input samples (29.98 / 31.81 dB at 4 / 16 spp against the box filter's 30.95 / 33.10 at
/// 64×48): rays to the walls' tops cross the light's plane Π far away, the light-space offset
/// became 1e7 units and every f32 position was rounded to a whole unit, ten times the filter
/// radius on the walls; and a receiver seen steeply from the light was shadowed by its own
/// surface's light samples. Direct light against 1024 spp, over the pixels away from the
/// emitter: the mean within 1 % at 4 and 16 spp (measured +0.19 / +0.55 %), the error below 0.85×
/// the box filter's at 4 spp (0.78×; 0.63× before the tracer's rectangle-light sampling made
/// the inputs less noisy) and falling by more than a fifth from 4 to 16 spp (0.72×).
#[test]
fn the_cornell_ceiling_light_is_not_biased_dark() {
    let scene = Scene::load(&common::project_root().join("scenes/cornell.toml")).unwrap();
    let (width, height) = (64, 48);
    let accel = Accel::build(&scene).unwrap();
    let settings = RenderSettings { width, height, spp: 1024, seed: 11, max_bounces: 1, threads: 0, progress: false };
    let reference = tracer::render(&scene, &accel, &settings).unwrap();
    // The receivers: pixels with no part of the emitter (radiance 18 / 11 / 2.8) within one pixel.
    let bright: Vec<bool> = reference.beauty.iter().map(|p| p.max_element() > 3.0).collect();
    let keep: Vec<bool> = (0..(width * height) as i64)
        .map(|i| {
            let (x, y) = (i % width as i64, i / width as i64);
            !(-1..=1).any(|dy| {
                (-1..=1).any(|dx| {
                    let (nx, ny) = (x + dx, y + dy);
                    (0..width as i64).contains(&nx)
                        && (0..height as i64).contains(&ny)
                        && bright[(ny * width as i64 + nx) as usize]
                })
            })
        })
        .collect();
    let truth = image_mean(&reference.beauty, &keep);
    let mut errors = Vec::new();
    for spp in [4, 16] {
        let run = soft_shadow_run(&scene, (width, height), spp, &reference.beauty, &keep);
        let bias = run.tlfr_mean / truth - 1.0;
        eprintln!(
            "cornell {spp} spp: tlfr mean {:+.2} % (box {:+.2} %), RMSE {:.5} (box {:.5}); {:?}",
            100.0 * bias,
            100.0 * (run.box_mean / truth - 1.0),
            run.tlfr_error,
            run.box_error,
            run.output.notes
        );
        assert!(bias.abs() < 0.01, "{spp} spp: mean {:+.2} % off the reference", 100.0 * bias);
        // At 16 spp the bright bias the lamp test shows (+0.5 %) holds the error near the box
        // filter's (measured 1.07×), hence the looser bound there. Since the tracer samples
        // rectangle lights by solid angle near them, the inputs, and so the box
        // filter, are less noisy: 4 spp measured 0.63× the box before, 0.78× after, with tlfr's
        // own error unchanged (0.0037); at 16 spp 1.44× (0.0027 against the box's 0.0019, which
        // fell from about 0.0025): tlfr's +0.55 % bright bias now dominates there (not
        // solved: docs/tlfr.md, "Limits"). The bounds follow the box, not tlfr; the bias bound above is the point.
        let bound = if spp == 4 { 0.85 } else { 1.6 };
        assert!(run.tlfr_error < bound * run.box_error, "{spp} spp: RMSE {} vs box {}", run.tlfr_error, run.box_error);
        errors.push(run.tlfr_error);
    }
    assert!(errors[1] < 0.8 * errors[0], "more input samples, lower error: {errors:?}");
}

/// Soft shadows (Section 5): a 1 × 1 lamp 2 above a grey floor and a 0.4 × 0.4 blocker at
/// height 0.8 between them, which throws a wide penumbra. The reconstruction from 4 spp must
/// be far closer to a 4096-spp path-traced image than the 4-spp pixel average is, stay finite,
/// and keep the penumbra soft (values between umbra and full light).
#[test]
fn soft_shadows_from_4_spp_approach_the_converged_image() {
    let (output, tlfr_error, box_error) = soft_shadow_errors(&lamp_and_blocker([0.0; 3]));
    // 0.62× the box measured (0.0062 against 0.0096; the box's input is the tracer's solid-angle
    // sampling of the rectangular lamp by solid angle, 0.0131 by area before).
    assert!(tlfr_error < 0.7 * box_error, "tlfr RMSE {tlfr_error} vs box {box_error}: {:?}", output.notes);
    // The penumbra stays soft: many floor pixels lie well between the darkest and brightest.
    let luminance: Vec<f32> = output.image.pixels.iter().map(|p| p[0]).collect();
    let (dark, bright) = luminance.iter().fold((f32::INFINITY, 0.0f32), |(lo, hi), &v| (lo.min(v), hi.max(v)));
    let between = luminance.iter().filter(|&&v| v > dark + 0.2 * (bright - dark) && v < bright - 0.2 * (bright - dark));
    assert!(between.count() > 40, "a soft penumbra, not a hard edge");
}

/// The soft-shadow reconstruction gives the same bits on 1 and 3 threads (Cornell, 32×24,
/// 2 spp, 8 locations per pixel).
#[test]
fn soft_shadows_do_not_depend_on_the_thread_count() {
    let scene = Scene::load(&common::project_root().join("scenes/cornell.toml")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let (camera_path, light_path) = (dir.path().join("lens-time.lfrs"), dir.path().join("light.lfrs"));
    let accel = Accel::build(&scene).unwrap();
    let settings =
        RenderSettings { width: 32, height: 24, spp: 2, seed: 3, max_bounces: 1, threads: 0, progress: false };
    lens_time::dump_for_soft_shadows(&scene, &accel, &settings, &tracer::samples::FieldSelection::All, &camera_path)
        .unwrap();
    tracer::samples::light::dump(&scene, &accel, &settings, &tracer::samples::FieldSelection::All, &light_path)
        .unwrap();
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        let tlfr = recon::tlfr::settings::TlfrSettings { locations: 8, ..Default::default() };
        let output =
            pool.install(|| recon::tlfr::shadows::reconstruct_soft_shadow(&camera_path, &light_path, &tlfr).unwrap());
        output.image.pixels.iter().flatten().map(|v| v.to_bits()).collect::<Vec<u32>>()
    };
    let one = run(1);
    assert!(one.iter().all(|&b| f32::from_bits(b).is_finite()));
    assert_eq!(one, run(3));
}

/// The fused kernel's soft shadows against its oracle (the per-location code of `query` on both
/// sides): every pixel within 1e-5 relative (the filters add the same samples in another order)
/// on Cornell (32×24, 2 spp, 16 locations per pixel) and on the lamp and blocker (32², 4 spp).
#[test]
fn fused_soft_shadows_match_the_oracle() {
    use recon::tlfr::settings::{Kernel, TlfrSettings};
    let cornell = Scene::load(&common::project_root().join("scenes/cornell.toml")).unwrap();
    for (scene, (width, height), spp) in [(cornell, (32, 24), 2), (lamp_and_blocker([0.0; 3]), (32, 32), 4)] {
        let dir = tempfile::tempdir().unwrap();
        let (camera_path, light_path) = (dir.path().join("lens-time.lfrs"), dir.path().join("light.lfrs"));
        let accel = Accel::build(&scene).unwrap();
        let settings = RenderSettings { width, height, spp, seed: 3, max_bounces: 1, threads: 0, progress: false };
        let all = tracer::samples::FieldSelection::All;
        lens_time::dump_for_soft_shadows(&scene, &accel, &settings, &all, &camera_path).unwrap();
        tracer::samples::light::dump(&scene, &accel, &settings, &all, &light_path).unwrap();
        let run = |kernel| {
            let tlfr = TlfrSettings { locations: 16, kernel, ..Default::default() };
            recon::tlfr::shadows::reconstruct_soft_shadow(&camera_path, &light_path, &tlfr).unwrap().image
        };
        let (fused, oracle) = (run(Kernel::Fused), run(Kernel::Oracle));
        let mut lit = 0;
        for (p, q) in fused.pixels.iter().zip(&oracle.pixels) {
            for c in 0..3 {
                assert!((p[c] - q[c]).abs() <= 1e-5 * q[c].abs().max(1e-3), "{p:?} vs {q:?}");
            }
            lit += usize::from(q[0] > 0.0);
        }
        assert!(lit > fused.pixels.len() / 2);
    }
}

/// The lamp-and-blocker image's mean within 0.2 % of the converged image's, at 4 and
/// 16 spp. Measured −0.06 % / +0.12 % since the light side keeps a blocker's rim
/// (`query::takes_rim`; before: +0.80 % / +0.58 %, the box filter of the same samples −0.34 % /
/// −0.10 %). The margin is small against the input's own noise: over the seeds 5–9 the mean is
/// +0.13 % / +0.18 % (sd 0.17 / 0.06 % per seed), the box's −0.18 % / −0.14 %; see docs/tlfr.md.
#[test]
fn the_lamp_images_mean_matches_the_reference() {
    let scene = lamp_and_blocker([0.0; 3]);
    let reference = common::render(&scene, 32, 32, 4096, 11);
    let keep = vec![true; 32 * 32];
    let truth = image_mean(&reference.beauty, &keep);
    let biases = [4, 16].map(|spp| {
        let run = soft_shadow_run(&scene, (32, 32), spp, &reference.beauty, &keep);
        let bias = run.tlfr_mean / truth - 1.0;
        eprintln!(
            "lamp {spp} spp: tlfr mean {:+.3} %, box {:+.3} %; RMSE {:.5} (box {:.5})",
            100.0 * bias,
            100.0 * (run.box_mean / truth - 1.0),
            run.tlfr_error,
            run.box_error
        );
        (spp, bias)
    });
    for (spp, bias) in biases {
        assert!(bias.abs() < 0.002, "{spp} spp: mean {:+.3} % off the reference", 100.0 * bias);
    }
}

/// A lamp sliding by 0.6 (more than half its width) over the shutter: the light samples
/// reproject along the light's motion (`extra.light_motion`), and the result still beats the
/// box filter against the converged moving-light image. Checked that it can fail: with the
/// light's motion ignored in `LightSpace` the error was 0.0173 against the box filter's 0.0121
/// (with it: 0.0059).
#[test]
fn soft_shadows_of_a_moving_light_follow_its_motion() {
    let (output, tlfr_error, box_error) = soft_shadow_errors(&lamp_and_blocker([0.6, 0.0, 0.0]));
    eprintln!("moving light: tlfr RMSE {tlfr_error} vs box {box_error}: {:?}", output.notes);
    assert!(tlfr_error < 0.6 * box_error, "tlfr RMSE {tlfr_error} vs box {box_error}: {:?}", output.notes);
}

#[test]
fn soft_shadow_inputs_that_do_not_belong_together_are_clear_errors() {
    let scene = moving_square();
    let dir = tempfile::tempdir().unwrap();
    let accel = Accel::build(&scene).unwrap();
    let settings =
        |spp| RenderSettings { width: 8, height: 8, spp, seed: 1, max_bounces: 0, threads: 0, progress: false };
    let plain = dir.path().join("plain.lfrs");
    lens_time::dump(&scene, &accel, &settings(2), &tracer::samples::FieldSelection::All, &plain).unwrap();
    // The square is the scene's only emitter and planar: it serves as the light.
    let light = dir.path().join("light.lfrs");
    tracer::samples::light::dump(&scene, &accel, &settings(4), &tracer::samples::FieldSelection::All, &light).unwrap();
    let shading = dir.path().join("shading.lfrs");
    lens_time::dump_for_soft_shadows(&scene, &accel, &settings(2), &tracer::samples::FieldSelection::All, &shading)
        .unwrap();
    let run = |camera: &std::path::Path, light: &std::path::Path| {
        let tlfr = recon::tlfr::settings::TlfrSettings { locations: 4, ..Default::default() };
        recon::tlfr::shadows::reconstruct_soft_shadow(camera, light, &tlfr).unwrap_err().to_string()
    };
    let error = run(&plain, &light);
    assert!(error.contains("plain.lfrs") && error.contains("`albedo`"), "{error}");
    let error = run(&shading, &light);
    assert!(error.contains("light.lfrs") && error.contains("256 light samples for 128"), "{error}");
    let error = run(&light, &light);
    assert!(error.contains("light.lfrs") && error.contains("lens-time"), "{error}");
}

/// `--seed` reaches the reconstructions' own random numbers: through the registry,
/// as `lfr compare` runs them, one seed gives the same bits twice, another seed other bits of
/// the same quality (error against a converged render within noise), for TLFR's locations on
/// the moving square and ILFR's reconstruction rays on the Cornell box.
#[test]
fn the_seed_reaches_every_reconstruction_and_keeps_its_quality() {
    use recon::method::{InputData, Inputs};
    let run = |name: &str, effect: recon::Effect, path: &std::path::Path, size: u32, seed: u32| {
        let method = recon::registry::find(name).unwrap().unwrap();
        let inputs = Inputs {
            effect,
            width: size,
            height: size,
            spp: 4,
            data: InputData::Samples { samples: path, light_samples: None },
            ao_radius: 1.0,
            seed,
            threads: 0,
        };
        method.run(&inputs, 64).unwrap().image.pixels
    };
    let bits = |pixels: &[[f32; 3]]| pixels.iter().flatten().map(|v| v.to_bits()).collect::<Vec<_>>();
    let rmse = |pixels: &[[f32; 3]], reference: &[Vec3]| {
        let sum: f64 = pixels
            .iter()
            .zip(reference)
            .map(|(p, r)| (0..3).map(|c| (p[c] as f64 - r[c] as f64).powi(2)).sum::<f64>())
            .sum();
        (sum / (3 * pixels.len()) as f64).sqrt()
    };

    let square = moving_square();
    let (_dir, lens_time_path) = dump(&square, 24, 24, 4);
    let converged = common::render(&square, 24, 24, 1024, 11);
    let cornell = Scene::load(&common::project_root().join("scenes/cornell.toml")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let indirect_path = dir.path().join("indirect.lfrs");
    let settings =
        RenderSettings { width: 16, height: 16, spp: 4, seed: 5, max_bounces: 4, threads: 0, progress: false };
    let accel = Accel::build(&cornell).unwrap();
    tracer::samples::secondary::dump(
        &cornell,
        &accel,
        &settings,
        tracer::samples::secondary::SecondaryKind::Indirect,
        &tracer::samples::FieldSelection::All,
        &indirect_path,
    )
    .unwrap();
    let cornell_converged = common::render(&cornell, 16, 16, 1024, 11);

    for (name, effect, path, size, reference) in [
        // The moving square's file has no `direct` field (one bounce): the whole radiance.
        ("tlfr:gi=whole", recon::Effect::Motion, &lens_time_path, 24, &converged.beauty),
        ("ilfr", recon::Effect::Indirect, &indirect_path, 16, &cornell_converged.indirect),
    ] {
        let first = run(name, effect, path, size, 0);
        assert_eq!(bits(&first), bits(&run(name, effect, path, size, 0)), "{name}: one seed, one image");
        let other = run(name, effect, path, size, 7);
        assert_ne!(bits(&first), bits(&other), "{name}: the seed must reach the reconstruction");
        // Within noise: on these small images eight seeds of tlfr spanned RMSE 0.026-0.037,
        // ±1.6 dB about their mean; every seed must stay within 3 dB of the four seeds' mean.
        let errors: Vec<f64> = [&first, &other, &run(name, effect, path, size, 13), &run(name, effect, path, size, 21)]
            .iter()
            .map(|image| rmse(image, reference))
            .collect();
        let mean = errors.iter().sum::<f64>() / errors.len() as f64;
        for error in &errors {
            let db = 20.0 * (error / mean).log10();
            assert!(db.abs() < 3.0, "{name}: RMSE {errors:?}, one {db:.2} dB from their mean");
        }
    }
}

/// `tlfr:gi=split` (the default) on the monkeys' full global illumination, run through the
/// registry as `lfr compare` runs it, against second computations: with one bounce (no light
/// beyond the first hit) it is `tlfr`'s image bit for bit; with four bounces and `gi_radius=0`
/// it is `tlfr` on the one-bounce file (whose radiance is the direct part, tested in the
/// tracer) plus each pixel's mean of `radiance − direct`, computed here from the file; and with
/// the default smoothing it is closer to a converged render than `tlfr` on the whole radiance.
#[test]
fn gi_split_reconstructs_the_direct_part_and_adds_the_filtered_rest() {
    use recon::method::{InputData, Inputs};
    let _ = common::shared_scenes();
    let mut scene = Scene::load(&common::project_root().join("scenes/monkeys-defocus-motion.toml")).unwrap();
    let (width, height, spp) = (48u32, 27u32, 4u32);
    let dir = tempfile::tempdir().unwrap();
    let fields = tracer::samples::FieldSelection::named(["x", "y", "u", "v", "t", "z", "motion", "radiance", "direct"]);
    let mut dump_bounces = |bounces: u32, name: &str| {
        scene.max_bounces = bounces;
        let path = dir.path().join(name);
        let settings =
            RenderSettings { width, height, spp, seed: 2, max_bounces: bounces, threads: 0, progress: false };
        lens_time::dump(&scene, &Accel::build(&scene).unwrap(), &settings, &fields, &path).unwrap();
        path
    };
    let (one, four) = (dump_bounces(1, "one.lfrs"), dump_bounces(4, "four.lfrs"));
    let run = |name: &str, path: &std::path::Path| {
        let inputs = Inputs {
            effect: recon::Effect::DofMotion,
            width,
            height,
            spp,
            data: InputData::Samples { samples: path, light_samples: None },
            ao_radius: 1.0,
            seed: 2,
            threads: 0,
        };
        recon::registry::find(name).unwrap().unwrap().run(&inputs, 32).unwrap().image.pixels
    };
    assert_eq!(run("tlfr", &one), run("tlfr:gi=whole", &one), "without indirect light the split changes nothing");

    let file = SampleFile::open(&four).unwrap();
    let (radiance, direct) = (file.column("radiance").unwrap(), file.column("direct").unwrap());
    let per_pixel = 3 * spp as usize;
    let expected: Vec<[f32; 3]> = run("tlfr:gi=whole", &one)
        .iter()
        .enumerate()
        .map(|(pixel, value)| {
            std::array::from_fn(|c| {
                let rest: f64 = (0..spp as usize)
                    .map(|s| pixel * per_pixel + 3 * s + c)
                    .map(|i| radiance[i] as f64 - direct[i] as f64)
                    .sum();
                value[c] + (rest / spp as f64) as f32
            })
        })
        .collect();
    let split = run("tlfr:gi=split:gi_radius=0", &four);
    for (got, want) in split.iter().zip(&expected) {
        for c in 0..3 {
            assert!((got[c] - want[c]).abs() <= 1e-5 * (1.0 + want[c].abs()), "{got:?} vs {want:?}");
        }
    }

    scene.max_bounces = 4;
    let converged = common::render(&scene, width, height, 1024, 11);
    let rmse = |pixels: &[[f32; 3]]| {
        let sum: f64 = (pixels.iter().zip(&converged.beauty))
            .map(|(p, r)| (0..3).map(|c| (p[c] as f64 - r[c] as f64).powi(2)).sum::<f64>())
            .sum();
        (sum / (3 * pixels.len()) as f64).sqrt()
    };
    let (whole, split) = (rmse(&run("tlfr:gi=whole", &four)), rmse(&run("tlfr", &four)));
    assert!(split < 0.9 * whole, "RMSE against 1024 spp: split {split:.4}, whole {whole:.4}");

    // `lfr reconstruct --gi-split` without a radius takes the registry's default radius; a
    // radius beyond 64 is refused before anything is written.
    let cli = |extra: &[&str], name: &str| {
        let out = dir.path().join(name);
        let result = std::process::Command::new(env!("CARGO_BIN_EXE_lfr"))
            .args(["reconstruct", "--samples", four.to_str().unwrap(), "--locations", "8", "--quiet", "--out"])
            .arg(&out)
            .args(extra)
            .output()
            .unwrap();
        (result, out)
    };
    let channel = |out: &std::path::Path| tracer::output::read_exr(out).unwrap().2;
    let (default, default_out) = cli(&["--gi-split"], "default.exr");
    let (three, three_out) =
        cli(&["--gi-split", &recon::tlfr::global_illumination::DEFAULT_GI_RADIUS.to_string()], "r.exr");
    let (zero, zero_out) = cli(&["--gi-split", "0"], "zero.exr");
    for result in [&default, &three, &zero] {
        assert!(result.status.success(), "{}", String::from_utf8_lossy(&result.stderr));
    }
    assert_eq!(channel(&default_out), channel(&three_out));
    assert_ne!(channel(&default_out), channel(&zero_out), "the radius reaches the reconstruction");
    let (bad, bad_out) = cli(&["--gi-split", "65"], "bad.exr");
    assert!(!bad.status.success() && String::from_utf8_lossy(&bad.stderr).contains("--gi-split"));
    assert!(!bad_out.exists());
}
