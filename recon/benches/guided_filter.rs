//! Guided filter speed on the paper's image size (Table 2: 1024×768, d = 1 / 3 / 4, "the same
//! for every radius"): a synthetic guide of planar pieces (floor, back wall, two boxes, a
//! tilted panel) with normal and depth edges, and a noisy RGB input, all seeded.
//!
//! `cargo bench -p recon --bench guided_filter` (the target: ≤ 30 ms per megapixel for d = 4 on
//! the project's 2-core machine, flat in the radius). Each case reports ms per run and, as
//! throughput, pixels per second.

use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use recon::gif::guided_filter::guided_filter_planes_subsampled;
use recon::image::Image;
use recon::lcg::Lcg;

const WIDTH: usize = 1024;
const HEIGHT: usize = 768;

fn normalize(v: [f32; 3]) -> [f32; 3] {
    let length = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    v.map(|c| c / length)
}

/// The planar piece seen at pixel (x, y): its normal, depth and albedo.
fn surface(x: usize, y: usize) -> ([f32; 3], f32, [f32; 3]) {
    let (u, v) = (x as f32 / WIDTH as f32, y as f32 / HEIGHT as f32);
    if (0.15..0.4).contains(&u) && (0.45..0.85).contains(&v) {
        // A box's front face, then its top.
        if v < 0.52 {
            ([0.0, 1.0, 0.0], 3.2 + 0.5 * (v - 0.45), [0.8, 0.3, 0.2])
        } else {
            ([0.0, 0.0, 1.0], 3.0, [0.8, 0.3, 0.2])
        }
    } else if (0.55..0.8).contains(&u) && (0.35..0.8).contains(&v) {
        // A box turned by 30°: two faces meeting at a vertical edge.
        if u < 0.66 {
            (normalize([-0.5, 0.0, 0.87]), 3.5 + 2.0 * (0.66 - u), [0.2, 0.6, 0.3])
        } else {
            (normalize([0.87, 0.0, 0.5]), 3.5 + 1.2 * (u - 0.66), [0.2, 0.6, 0.3])
        }
    } else if (0.82..0.95).contains(&u) && (0.1..0.4).contains(&v) {
        // A tilted panel on the wall.
        (normalize([-0.3, -0.4, 0.87]), 5.5 + 0.8 * (v - 0.1), [0.9, 0.9, 0.5])
    } else if v > 0.6 {
        // The floor, receding towards the horizon.
        ([0.0, 1.0, 0.0], 2.0 + 4.0 * (1.0 - v) / 0.4, [0.7, 0.7, 0.7])
    } else {
        // The back wall.
        ([0.0, 0.0, 1.0], 6.0, [0.75, 0.75, 0.8])
    }
}

/// Guide planes as `guide_channels` builds them ((n + 1) / 2 per normal component, the grey
/// normal their mean, depth over the scene extent) and a noisy input: shaded albedo times a
/// heavy-tailed per-channel noise factor, as a few path-traced samples give.
fn scene() -> (Image, Vec<Vec<f32>>) {
    let mut rng = Lcg(0x5EED);
    let extent = 6.5;
    let light = normalize([0.4, 0.8, 0.45]);
    let mut planes: Vec<Vec<f32>> = (0..5).map(|_| Vec::with_capacity(WIDTH * HEIGHT)).collect();
    let mut pixels = Vec::with_capacity(WIDTH * HEIGHT);
    for y in 0..HEIGHT {
        for x in 0..WIDTH {
            let (n, depth, albedo) = surface(x, y);
            let scaled = n.map(|c| (c + 1.0) * 0.5);
            planes[0].push((scaled[0] + scaled[1] + scaled[2]) / 3.0);
            for j in 0..3 {
                planes[1 + j].push(scaled[j]);
            }
            planes[4].push((depth / extent).clamp(0.0, 1.0));
            let shade = 0.2 + (n[0] * light[0] + n[1] * light[1] + n[2] * light[2]).max(0.0);
            pixels.push(albedo.map(|a| a * shade * -(1.0 - rng.uniform()).ln()));
        }
    }
    (Image::from_pixels(WIDTH as u32, HEIGHT as u32, pixels), planes)
}

fn bench(c: &mut Criterion) {
    let (noisy, planes) = scene();
    let (grey, normal_depth) = (&planes[..1], &planes[1..]);
    let mut group = c.benchmark_group("guided_filter_1024x768");
    group.sample_size(10).warm_up_time(Duration::from_millis(500)).measurement_time(Duration::from_secs(2));
    group.throughput(Throughput::Elements((WIDTH * HEIGHT) as u64));
    for subsample in [1u32, 2] {
        for d in [1usize, 3, 4] {
            let guide = if d == 1 { grey } else { &normal_depth[..d] };
            let eps = &[0.01, 0.01, 0.01, 0.02][..d];
            for radius in [8u32, 16, 24, 32] {
                // The exact filter keeps its old names (d1, d3, d4) so criterion's history holds.
                let name = if subsample == 1 { format!("d{d}") } else { format!("d{d}_s{subsample}") };
                group.bench_with_input(BenchmarkId::new(name, radius), &radius, |b, &radius| {
                    b.iter(|| guided_filter_planes_subsampled(&noisy, guide, eps, radius, subsample).unwrap())
                });
            }
        }
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
