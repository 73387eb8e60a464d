//! The unit tests of `integrate.rs`, in a file of their own beside it for their length.

use super::*;

#[test]
fn locations_lie_in_their_pixel_lens_and_shutter() {
    for j in 0..256 {
        let (screen, at) = location(3, 7, 5, j, true, true);
        assert!((7.0..8.0).contains(&screen[0]) && (5.0..6.0).contains(&screen[1]));
        assert!(at.u * at.u + at.v * at.v <= 1.0 + 1e-5);
        assert!((0.0..1.0).contains(&at.t));
    }
    let (_, still) = location(3, 7, 5, 9, false, false);
    assert_eq!((still.u, still.v, still.t), (0.0, 0.0, 0.5));
    // Stratified: the first 64 locations' screen x fill the pixel's 64 strips of width 1/64.
    let mut strips = [false; 64];
    for j in 0..64 {
        let (screen, _) = location(1, 0, 0, j, false, false);
        strips[(screen[0] * 64.0) as usize] = true;
    }
    assert!(strips.iter().all(|&s| s));
}

use crate::tlfr::lens::LensModel;
use crate::tlfr::reprojection::{near_limit, LensTimeSample};
use crate::tlfr::test_scenes::indexed;

/// Jittered samples over a `size`² image, `spp` per pixel, each given depth, motion and
/// colour by `surface(x, y)`.
fn samples(
    size: u32,
    spp: u32,
    surface: impl Fn(f32, f32) -> (f32, [f32; 3], [f32; 3]),
) -> (Vec<LensTimeSample>, Vec<[f32; 3]>) {
    let mut state = 7u32;
    let mut next = move || {
        state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        (state >> 8) as f32 / (1u32 << 24) as f32
    };
    let (mut out, mut colours) = (Vec::new(), Vec::new());
    for y in 0..size {
        for x in 0..size {
            for _ in 0..spp {
                let (px, py) = (x as f32 + next(), y as f32 + next());
                let (z, motion, colour) = surface(px, py);
                out.push(LensTimeSample { x: px, y: py, u: 0.0, v: 0.0, t: next(), z, motion });
                colours.push(colour);
            }
        }
    }
    (out, colours)
}

fn run(samples: &[LensTimeSample], colours: &[[f32; 3]], size: u32, lens: LensModel, time: bool) -> Image {
    let z_near = near_limit(samples.iter().map(|s| s.z));
    let (tree, samples, colours) = indexed(samples, colours, &lens, z_near, (size, size), 0.7);
    let scene = Scene {
        samples: &samples,
        radiance: &colours,
        lens: &lens,
        hierarchy: &tree,
        radius: 0.7,
        z_near,
        delta: 0.125,
        view_bandwidth: None,
    };
    integrate(&scene, (size, size), 16, (false, time), 1, |_, _| [-1.0; 3]).0
}

const PINHOLE: LensModel = LensModel { c1: 0.0, c2: 0.0, fx: 16.0, fy: 16.0, cx: 8.0, cy: 8.0 };

/// Stiff cases with exact answers: the output is a convex combination of
/// the input radiance, so a constant scene must come back exactly.
#[test]
fn constant_scenes_come_back_exactly() {
    // C = 0 (pinhole, static), one plane, one sample per pixel.
    let (plane, colours) = samples(12, 1, |_, _| (3.0, [0.0; 3], [0.7, 0.2, 0.1]));
    let image = run(&plane, &colours, 12, PINHOLE, false);
    assert!(image.pixels.iter().all(|p| *p == [0.7, 0.2, 0.1]), "{:?}", image.pixels);
    // Only misses (the environment): every pixel is its colour, nothing divides by z = ∞.
    let (misses, colours) = samples(8, 2, |_, _| (f32::INFINITY, [0.0; 3], [0.5; 3]));
    let image = run(&misses, &colours, 8, LensModel { c1: -4.0, c2: 1.0, ..PINHOLE }, false);
    assert!(image.pixels.iter().all(|p| *p == [0.5; 3]));
}

/// A red plane at depth 1 moving through the camera plane (depth 0 at t = 0.5) in front of a
/// static blue one: after it has passed, no location may see red, and nothing is NaN.
#[test]
fn a_surface_passing_behind_the_camera_vanishes() {
    let (mut both, mut colours) = samples(12, 4, |_, _| (5.0, [0.0; 3], [0.0, 0.0, 1.0]));
    let (front, front_colours) = samples(12, 4, |_, _| (1.0, [0.0, 0.0, -2.0], [1.0, 0.0, 0.0]));
    // The red samples were taken before they passed (t < 0.5): keep those.
    for (s, c) in front.into_iter().zip(front_colours) {
        if s.t < 0.45 {
            both.push(LensTimeSample { z: 1.0 - 2.0 * s.t, ..s });
            colours.push(c);
        }
    }
    let lens = PINHOLE;
    let z_near = near_limit(both.iter().map(|s| s.z));
    let (tree, both, colours) = indexed(&both, &colours, &lens, z_near, (12, 12), 0.7);
    let scene = Scene {
        samples: &both,
        radiance: &colours,
        lens: &lens,
        hierarchy: &tree,
        radius: 0.7,
        z_near,
        delta: 0.125,
        view_bandwidth: None,
    };
    let (mut scratch, mut stats) = (Scratch::default(), QueryStats::default());
    for j in 0..200 {
        let screen = [2.0 + 8.0 * radical_inverse(j, 2), 2.0 + 8.0 * radical_inverse(j, 3)];
        let late = LensTime { u: 0.0, v: 0.0, t: 0.55 + 0.45 * radical_inverse(j, 5) };
        let value = reconstruct(&scene, screen, late, &mut scratch, &mut stats).unwrap();
        assert_eq!(value, [0.0, 0.0, 1.0], "red after it passed the camera, at {screen:?} {late:?}");
        let early = LensTime { t: 0.3 * radical_inverse(j, 5), ..late };
        let value = reconstruct(&scene, screen, early, &mut scratch, &mut stats).unwrap();
        assert!(value.iter().all(|v| v.is_finite()));
    }
}

/// Each pixel's value and the number of locations it evaluated, with `rule`.
fn adaptive_run(scene: &Scene, size: (u32, u32), n: u32, rule: Option<AdaptiveRule>) -> (Image, Vec<u32>) {
    use std::sync::atomic::{AtomicU32, Ordering};
    let counts: Vec<AtomicU32> = (0..size.0 * size.1).map(|_| AtomicU32::new(0)).collect();
    let (image, _) = integrate_locations(
        size,
        (n, rule),
        (scene.lens.c1 != 0.0, true),
        1,
        |(x, y, _), screen, at, scratch: &mut Scratch, stats: &mut QueryStats| {
            counts[(y * size.0 + x) as usize].fetch_add(1, Ordering::Relaxed);
            reconstruct(scene, screen, at, scratch, stats)
        },
        |_, _| [-1.0; 3],
    );
    (image, counts.into_iter().map(|c| c.into_inner()).collect())
}

fn scene_of<'a>(
    tree: &'a crate::tlfr::hierarchy::Hierarchy,
    samples: &'a [LensTimeSample],
    colours: &'a [[f32; 3]],
    lens: &'a LensModel,
    z_near: f32,
) -> Scene<'a> {
    Scene { samples, radiance: colours, lens, hierarchy: tree, radius: 0.7, z_near, delta: 0.125, view_bandwidth: None }
}

/// `AdaptiveRule` on a single surface: every pixel stops after its first locations, and
/// the constant comes back exactly.
#[test]
fn a_single_surface_pixel_stops_after_its_first_locations() {
    let (plane, colours) = samples(12, 2, |_, _| (3.0, [0.0; 3], [0.7, 0.2, 0.1]));
    let z_near = near_limit(plane.iter().map(|s| s.z));
    let (tree, plane, colours) = indexed(&plane, &colours, &PINHOLE, z_near, (12, 12), 0.7);
    let scene = scene_of(&tree, &plane, &colours, &PINHOLE, z_near);
    let rule = AdaptiveRule { first: 8, spread: 0.05 };
    let (image, counts) = adaptive_run(&scene, (12, 12), 64, Some(rule));
    assert!(counts.iter().all(|&c| c == 8), "{counts:?}");
    assert!(image.pixels.iter().all(|p| *p == [0.7, 0.2, 0.1]));
    // A shaded plane whose value varies more than the spread across a pixel goes on.
    let (ramp, colours) = samples(12, 2, |x, _| (3.0, [0.0; 3], [0.1 + 0.2 * x, 0.2, 0.1]));
    let (tree, ramp, colours) = indexed(&ramp, &colours, &PINHOLE, z_near, (12, 12), 0.7);
    let scene = scene_of(&tree, &ramp, &colours, &PINHOLE, z_near);
    let (_, counts) = adaptive_run(&scene, (12, 12), 64, Some(AdaptiveRule { first: 8, spread: 0.01 }));
    assert!(counts.iter().all(|&c| c == 64), "{counts:?}");
}

/// `AdaptiveRule` at an occlusion edge: a defocused near plane (circle of confusion 3 px)
/// over the left half of an in-focus far one, both the same colour so that only the
/// one-surface test can tell. Pixels at the edge take all N, pixels far from it stop early,
/// and pixels that go on are the full run's bit for bit.
#[test]
fn pixels_at_an_occlusion_edge_take_every_location() {
    let grey = [0.4f32; 3];
    let size = 24u32;
    let (both, colours) = samples(size, 4, |x, _| if x < 12.0 { (1.0, [0.0; 3], grey) } else { (4.0, [0.0; 3], grey) });
    let lens = LensModel { c1: -4.0, c2: 1.0, cx: 12.0, cy: 12.0, ..PINHOLE };
    let z_near = near_limit(both.iter().map(|s| s.z));
    let (tree, both, colours) = indexed(&both, &colours, &lens, z_near, (size, size), 0.7);
    let scene = scene_of(&tree, &both, &colours, &lens, z_near);
    let rule = AdaptiveRule { first: 8, spread: 0.05 };
    let (image, counts) = adaptive_run(&scene, (size, size), 64, Some(rule));
    let (full, full_counts) = adaptive_run(&scene, (size, size), 64, None);
    assert!(full_counts.iter().all(|&c| c == 64));
    for y in 4..size - 4 {
        for x in 0..size {
            let k = (y * size + x) as usize;
            match x {
                11 | 12 => assert_eq!(counts[k], 64, "edge pixel ({x}, {y})"),
                5..=6 | 18..=19 => assert_eq!(counts[k], 8, "pixel ({x}, {y}) far from the edge"),
                _ => {}
            }
            if counts[k] == 64 {
                assert_eq!(image.pixels[k], full.pixels[k]);
            }
        }
    }
}

/// The adaptive image against the full run (the oracle) on the layered scene with defocus
/// and motion: pixels that go on are identical, the others differ by little.
#[test]
fn adaptive_locations_keep_the_layered_scenes_image() {
    use crate::tlfr::test_scenes::{layered_scene, sample_scene};
    let (width, height) = (48u32, 27u32);
    let (lens, rects) = layered_scene(width, height, false);
    let (samples, colours) = sample_scene(&lens, &rects, 4, [0.5; 3], 3);
    let model = lens.model();
    let z_near = near_limit(samples.iter().map(|s| s.z));
    let (tree, samples, colours) = indexed(&samples, &colours, &model, z_near, (width, height), 0.7);
    let scene = scene_of(&tree, &samples, &colours, &model, z_near);
    let rule = AdaptiveRule { first: 8, spread: 0.05 };
    let (image, counts) = adaptive_run(&scene, (width, height), 64, Some(rule));
    let (full, _) = adaptive_run(&scene, (width, height), 64, None);
    let stopped = counts.iter().filter(|&&c| c == 8).count();
    assert!(stopped > counts.len() / 3 && stopped < counts.len(), "{stopped} of {} stopped", counts.len());
    let mut worst = 0.0f32;
    for (k, &count) in counts.iter().enumerate() {
        if count == 64 {
            assert_eq!(image.pixels[k], full.pixels[k]);
        } else {
            for c in 0..3 {
                worst = worst.max((image.pixels[k][c] - full.pixels[k][c]).abs());
            }
        }
    }
    // The layered scene's flat colours agree within the spread wherever a pixel stopped.
    assert!(worst <= 0.05, "{worst}");
}

/// The CPU time of this process (user + system), seconds, where /proc tells it.
fn process_cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // The fields after the command's closing parenthesis; utime and stime are 14 and 15.
    let fields: Vec<&str> = stat.rsplit_once(')')?.1.split_whitespace().collect();
    let ticks: f64 = fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// Throughput on a synthetic layered scene with defocus and motion (run with
/// `--ignored --nocapture` in release): index build time, locations per second, image mean.
#[test]
#[ignore]
fn bench_layered_scene() {
    use crate::tlfr::dispersion::measure_radius;
    use crate::tlfr::test_scenes::{layered_scene, sample_scene};
    let (width, height, spp) = (160u32, 90u32, 8u32);
    let through_camera = std::env::var("TLFR_BENCH_THROUGH_CAMERA").is_ok();
    let (lens, rects) = layered_scene(width, height, through_camera);
    let (samples, colours) = sample_scene(&lens, &rects, spp, [0.5; 3], 3);
    let model = lens.model();
    let z_near = near_limit(samples.iter().map(|s| s.z));
    let radius = measure_radius(&samples, width, height, spp, 8, 0).unwrap();
    let start = std::time::Instant::now();
    let (tree, samples, colours) = indexed(&samples, &colours, &model, z_near, (width, height), radius);
    let build_s = start.elapsed().as_secs_f64();
    let scene = Scene {
        samples: &samples,
        radiance: &colours,
        lens: &model,
        hierarchy: &tree,
        radius,
        z_near,
        delta: 0.125,
        view_bandwidth: None,
    };
    let start = std::time::Instant::now();
    let cpu_start = process_cpu_seconds();
    let (image, stats) = integrate(&scene, (width, height), 32, (true, true), 1, |_, _| [0.0; 3]);
    let recon_s = start.elapsed().as_secs_f64();
    if let (Some(a), Some(b)) = (cpu_start, process_cpu_seconds()) {
        // Less sensitive to other processes on a shared machine than the wall clock.
        println!("{:.0} locations per CPU second ({:.2} CPU s)", stats.locations as f64 / (b - a), b - a);
    }
    let mean: f64 =
        image.pixels.iter().map(|p| p[0] as f64 + p[1] as f64 + p[2] as f64).sum::<f64>() / image.pixels.len() as f64;
    println!(
        "{} samples, R = {radius:.3}: build {build_s:.3} s, {} locations in {recon_s:.2} s = {:.0} locations/s; \
         mean {mean:.6}; {stats:?}",
        samples.len(),
        stats.locations,
        stats.locations as f64 / recon_s
    );
    // The converged image (mean of 256 samples per pixel of the same scene) and the error.
    let (_, truth) = sample_scene(&lens, &rects, 256, [0.5; 3], 9);
    let mut reference = vec![[0.0f64; 3]; (width * height) as usize];
    for (k, c) in truth.iter().enumerate() {
        for ch in 0..3 {
            reference[k / 256][ch] += c[ch] as f64 / 256.0;
        }
    }
    let squared: f64 = image
        .pixels
        .iter()
        .zip(&reference)
        .map(|(p, r)| (0..3).map(|ch| (p[ch] as f64 - r[ch]).powi(2)).sum::<f64>())
        .sum();
    let reference_mean = reference.iter().map(|r| r[0] + r[1] + r[2]).sum::<f64>() / reference.len() as f64;
    println!("reference mean {reference_mean:.6}, RMSE {:.5}", (squared / (3 * reference.len()) as f64).sqrt());
    // Memory per input sample: the entries' records (a sample split into time segments has
    // one per segment), the nodes and the segments' times.
    let record = std::mem::size_of::<LensTimeSample>() + std::mem::size_of::<[f32; 3]>();
    let inputs = (width * height * spp) as f64;
    println!(
        "{} entries ({} time segments) for {inputs} samples, {} leaves ({:.1} entries each), {} nodes: \
         {:.1} + {:.1} = {:.1} bytes per sample; {:.1} leaves per location and pass",
        tree.entry_count(),
        tree.segment_entries(),
        tree.leaf_count(),
        samples.len() as f64 / tree.leaf_count() as f64,
        tree.nodes().len(),
        (record * samples.len()) as f64 / inputs,
        tree.node_bytes() as f64 / inputs,
        ((record * samples.len()) as f64 + tree.node_bytes() as f64) / inputs,
        stats.leaves as f64 / stats.locations as f64
    );
}
