//! TLFR speed on the synthetic layered scene of `tlfr::test_scenes` (defocus, motion, a static
//! wall, a sliding plane and a near card), 96×54 pixels at 8 samples per pixel, 8 locations per
//! pixel: the hierarchy's build time, and the reconstruction's locations per second for `tlfr`
//! (tent filter over the covering surface) and `tlfr-nn` (nearest sample of the covering
//! surface) in the same run, with their ratio and their errors against the converged image.
//!
//! `cargo bench -p recon --bench tlfr` (about half a minute); `-- --test` runs each case once.

use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use recon::tlfr::bounds::ScreenArea;
use recon::tlfr::hierarchy::{reorder, Hierarchy};
use recon::tlfr::integrate::{integrate_with, Reconstruct};
use recon::tlfr::nearest::reconstruct_nearest;
use recon::tlfr::query::{max_reach, reconstruct, Scene};
use recon::tlfr::reprojection::{near_limit, LensTimeSample};
use recon::tlfr::test_scenes::{layered_scene, sample_scene};

const WIDTH: u32 = 96;
const HEIGHT: u32 = 54;
const SPP: u32 = 8;
const LOCATIONS: u32 = 8;
const RADIUS: f32 = 0.72;

struct Input {
    samples: Vec<LensTimeSample>,
    colours: Vec<[f32; 3]>,
    lens: recon::tlfr::lens::LensModel,
    z_near: f32,
    area: ScreenArea,
}

fn input() -> Input {
    let (lens, rects) = layered_scene(WIDTH, HEIGHT, false);
    let (samples, colours) = sample_scene(&lens, &rects, SPP, [0.5; 3], 3);
    let z_near = near_limit(samples.iter().map(|s| s.z));
    let area = ScreenArea { width: WIDTH as f32, height: HEIGHT as f32, max_reach: max_reach(RADIUS) };
    Input { samples, colours, lens: lens.model(), z_near, area }
}

/// The image with `value` per location, and the number of locations.
fn run(value: Reconstruct, scene: &Scene) -> (Vec<[f32; 3]>, u64) {
    let (image, stats) = integrate_with(value, scene, (WIDTH, HEIGHT), LOCATIONS, (true, true), 1, |_, _| [0.0; 3]);
    (image.pixels, stats.locations)
}

fn bench(c: &mut Criterion) {
    let input = input();
    let (tree, order) = Hierarchy::build(&input.samples, &input.lens, input.z_near, &input.area);
    let (samples, colours) = (reorder(&input.samples, &order), reorder(&input.colours, &order));
    let scene = Scene {
        samples: &samples,
        radiance: &colours,
        lens: &input.lens,
        hierarchy: &tree,
        radius: RADIUS,
        z_near: input.z_near,
        delta: (1.0 / LOCATIONS as f32).sqrt(),
        view_bandwidth: None,
    };
    let locations = (WIDTH * HEIGHT * LOCATIONS) as u64;

    // One timed run of each, side by side, for the ratio and the errors.
    let (lens, rects) = layered_scene(WIDTH, HEIGHT, false);
    let (_, truth) = sample_scene(&lens, &rects, 256, [0.5; 3], 9);
    let rmse = |image: &[[f32; 3]]| {
        let squared: f64 = image
            .iter()
            .zip(truth.chunks(256))
            .map(|(p, pixel)| {
                (0..3)
                    .map(|ch| {
                        let mean = pixel.iter().map(|c| c[ch] as f64).sum::<f64>() / 256.0;
                        (p[ch] as f64 - mean).powi(2)
                    })
                    .sum::<f64>()
            })
            .sum();
        (squared / (3 * image.len()) as f64).sqrt()
    };
    // The best of three runs each, alternating, on a machine others may share.
    let timed = |value: Reconstruct| {
        let start = Instant::now();
        let (image, count) = run(value, &scene);
        (count as f64 / start.elapsed().as_secs_f64(), rmse(&image))
    };
    let (mut filter_rate, mut nearest_rate, mut filter_error, mut nearest_error) = (0.0f64, 0.0f64, 0.0, 0.0);
    for _ in 0..3 {
        let (rate, error) = timed(reconstruct);
        (filter_rate, filter_error) = (filter_rate.max(rate), error);
        let (rate, error) = timed(reconstruct_nearest);
        (nearest_rate, nearest_error) = (nearest_rate.max(rate), error);
    }
    println!(
        "tlfr: {filter_rate:.0} locations/s, RMSE {filter_error:.4}; tlfr-nn: {nearest_rate:.0} locations/s, RMSE \
         {nearest_error:.4}; time ratio tlfr/tlfr-nn {:.2} ({} samples, {} leaves)",
        nearest_rate / filter_rate,
        input.samples.len(),
        tree.leaf_count()
    );

    let mut group = c.benchmark_group("tlfr");
    group.sample_size(10).measurement_time(Duration::from_secs(5)).warm_up_time(Duration::from_secs(1));
    group.throughput(Throughput::Elements(input.samples.len() as u64));
    group.bench_function("hierarchy build", |b| {
        b.iter(|| Hierarchy::build(&input.samples, &input.lens, input.z_near, &input.area))
    });
    group.throughput(Throughput::Elements(locations));
    group.bench_function("tlfr locations", |b| b.iter(|| run(reconstruct, &scene)));
    group.bench_function("tlfr-nn locations", |b| b.iter(|| run(reconstruct_nearest, &scene)));
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
