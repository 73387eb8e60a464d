//! The unit tests of `sparse.rs`, in a file of their own beside it for their length.

use super::*;
use crate::ilfr::pipeline::tests::{box_samples, settings};
use crate::ilfr::pipeline::{reconstruct_samples, GatherTarget, IlfrSettings, Reconstructed};
use sampleio::SampleKind;

/// The full gather's settings (the oracle) with `rays` rays per pixel, and the same with the
/// sparse gather of `params`.
fn pair(rays: u32, params: SparseParams) -> (IlfrSettings, IlfrSettings) {
    let full = settings(rays);
    (full.clone(), IlfrSettings { sparse: Some(params), ..full })
}

/// The grid these tests measure: stride 2 at the pixel budget (grid pixels gather what the full
/// gather's pixels do), with the default thresholds. The method's default grid (4 pixels, 4×
/// the rays) is checked in `registry.rs`.
fn unit_grid() -> SparseParams {
    SparseParams { stride: 2, grid_ray_factor: 1, ..SparseParams::default() }
}

fn bits(r: &Reconstructed) -> Vec<u32> {
    r.image.pixels.iter().flatten().map(|v| v.to_bits()).collect()
}

/// The wall radiance of the tests: a ramp in height and x, and a constant third channel.
fn ramp(h: [f32; 3]) -> [f32; 3] {
    [h[2], 0.5 + 0.25 * h[0], 0.25]
}

/// Grid lines: the multiples of the stride and the last line; a cell's two lines carry linear
/// weights that sum to one; a line on the grid is its own cell.
#[test]
fn the_grid_holds_the_multiples_of_the_stride_and_the_last_line() {
    let lines: Vec<u32> = (0..8).filter(|&x| on_grid(x, 8, 3)).collect();
    assert_eq!(lines, [0, 3, 6, 7]);
    let [(a, wa), (b, wb)] = cell(4, 8, 3);
    assert!((a, b) == (3, 6) && (wa - 2.0 / 3.0).abs() < 1e-6 && (wb - 1.0 / 3.0).abs() < 1e-6);
    assert_eq!(cell(6, 8, 3), [(6, 1.0), (6, 0.0)]);
    assert!(on_grid(0, 1, 2), "a one-pixel image is all grid");
    for (n, stride) in [(13u32, 2u32), (13, 3), (5, 4), (2, 16)] {
        for x in 0..n {
            let [(a, wa), (b, wb)] = cell(x, n, stride);
            assert!(on_grid(a, n, stride) && on_grid(b, n, stride) && a <= x && x <= b.max(a));
            assert!((wa + wb - 1.0).abs() < 1e-6, "{n} {stride} {x}");
        }
    }
}

/// Similarity: 1 on one plane with one normal, falling linearly with the distance from the
/// tangent plane to 0 at the tolerance, 0 beyond 25° between the normals, finite at zero
/// footprint (coincident hits similar, others not).
#[test]
fn similar_hits_share_a_plane_and_a_normal() {
    let up = [0.0, 0.0, 1.0];
    let cos = 25f32.to_radians().cos();
    let g = |p: [f32; 3], n: [f32; 3], footprint: f32| similarity(([0.0; 3], up), (p, n), (footprint, 2.0), (cos, 1.0));
    assert_eq!(g([5.0, -3.0, 0.0], up, 0.1), 1.0);
    assert!((g([0.1, 0.0, 0.1], up, 0.1) - 0.5).abs() < 1e-6, "half the tolerance of 2 footprints");
    assert_eq!(g([0.0, 0.0, 0.3], up, 0.1), 0.0);
    let tilted = |degrees: f32| [degrees.to_radians().sin(), 0.0, degrees.to_radians().cos()];
    assert_eq!(g([0.0; 3], tilted(26.0), 0.1), 0.0);
    assert!(g([0.0; 3], tilted(5.0), 0.1) > 0.5);
    assert_eq!(g([0.0; 3], up, 0.0), 1.0);
    assert_eq!(g([0.0, 0.0, 1e-9], up, 0.0), 0.0);
    assert_eq!(g([0.0; 3], [f32::NAN; 3], 0.1), 0.0);
}

/// The oracle: with a coverage threshold no hit off the grid can meet (every one refined), the
/// sparse gather is the full gather bit for bit, image and counts, whatever the stride and the
/// image's size (13 × 13, not a multiple of 2 or 3); with the default thresholds the grid
/// pixels still are, and only the grid's and the refined hits' rays are traced.
#[test]
fn gathered_pixels_are_the_full_gathers_bit_for_bit() {
    let samples = box_samples(13, 2, SampleKind::Indirect, None, ramp);
    let (full, _) = pair(16, unit_grid());
    let oracle = reconstruct_samples(&samples, GatherTarget::Indirect, &full).unwrap();
    for stride in [2, 3] {
        let everything = SparseParams { stride, min_coverage: 2.0, ..unit_grid() };
        let (_, sparse) = pair(16, everything);
        let result = reconstruct_samples(&samples, GatherTarget::Indirect, &sparse).unwrap();
        assert_eq!(bits(&result), bits(&oracle), "stride {stride}");
        let (grid, interpolated, refined, hits, _) = result.gather.sparse.unwrap();
        assert_eq!((grid + refined, interpolated, hits), (169, 0, 2 * refined));
        assert_eq!(result.gather.reconstruct, oracle.gather.reconstruct);

        let (_, sparse) = pair(16, SparseParams { stride, ..unit_grid() });
        let result = reconstruct_samples(&samples, GatherTarget::Indirect, &sparse).unwrap();
        let (grid, interpolated, refined, hits, _) = result.gather.sparse.unwrap();
        assert!(interpolated > 0 && grid + interpolated + refined == 169, "{:?}", result.gather.sparse);
        let lines = (0..13).filter(|&x| on_grid(x, 13, stride)).count() as u64;
        assert_eq!(grid, lines * lines);
        let mut same = 0;
        for y in 0..13 {
            for x in 0..13 {
                if on_grid(x, 13, stride) && on_grid(y, 13, stride) {
                    assert_eq!(result.image.get(x, y), oracle.image.get(x, y), "grid pixel ({x}, {y})");
                }
                same += (result.image.get(x, y) == oracle.image.get(x, y)) as u64;
            }
        }
        assert!(same >= grid, "{same} pixels equal the oracle's");
        // Fewer rays: the grid's (16 a pixel) and the refined hits' (8 each) only.
        assert_eq!(result.gather.reconstruct.rays, grid * 16 + hits * 8);
    }
    // More rays at the grid pixels (and the refined ones): those are the full gather's at that
    // budget.
    let (full, sparse) = pair(16, SparseParams { grid_ray_factor: 4, ..unit_grid() });
    let oracle =
        reconstruct_samples(&samples, GatherTarget::Indirect, &IlfrSettings { recon_rays: 64, ..full }).unwrap();
    let result = reconstruct_samples(&samples, GatherTarget::Indirect, &sparse).unwrap();
    for y in (0..13).filter(|&y| on_grid(y, 13, 2)) {
        for x in (0..13).filter(|&x| on_grid(x, 13, 2)) {
            assert_eq!(result.image.get(x, y), oracle.image.get(x, y), "grid pixel ({x}, {y}) at 4× rays");
        }
    }
    let (grid, _, _, hits, _) = result.gather.sparse.unwrap();
    assert_eq!(result.gather.reconstruct.rays, grid * 64 + hits * 32);
}

/// Constant light (the furnace: every wall at L) and a floor under a uniform sky (every
/// secondary ray escaped with the sky's radiance): every hit's gathered mean is L exactly, so
/// an interpolated pixel is a convex combination of equal values, albedo × L within 2^-22
/// relative (f64 weights rounded to f32); at 1, 1e-6 and 1e9 scale, strides 2 and 4 on an image
/// of 11 pixels (not a multiple of either), and most pixels interpolated.
#[test]
fn constant_light_is_interpolated_within_rounding() {
    let l = [0.5f32, 2.0, 1e6];
    let expected = [0.5 * l[0], 0.25 * l[1], l[2]];
    let close = |p: [f32; 3]| (0..3).all(|c| (p[c] - expected[c]).abs() <= expected[c] * 2f32.powi(-22));
    for sky in [false, true] {
        for scale in [1.0f32, 1e-6, 1e9] {
            for stride in [2, 4] {
                let mut samples = box_samples(11, 4, SampleKind::Indirect, None, |_| l);
                for v in samples.primary_hit.iter_mut().chain(samples.secondary_hit.iter_mut()) {
                    *v = v.map(|c| c * scale);
                }
                if sky {
                    for i in 0..samples.len() {
                        samples.class[i] = SampleClass::Escaped;
                        samples.secondary_hit[i] = samples.primary_hit[i];
                        samples.secondary_normal[i] = [0.0; 3];
                    }
                }
                let (_, sparse) = pair(16, SparseParams { stride, ..unit_grid() });
                let result = reconstruct_samples(&samples, GatherTarget::Indirect, &sparse).unwrap();
                let (grid, interpolated, refined, _, _) = result.gather.sparse.unwrap();
                assert!(result.image.pixels.iter().all(|p| close(*p)), "sky {sky}, scale {scale}, stride {stride}");
                assert!(interpolated > 2 * (grid + refined) / 3, "{:?}", result.gather.sparse);
                assert_eq!(refined, 0, "constant light on one plane: nothing to refine");
            }
        }
    }
}

/// Stiff images: a 1×1 image at 1 spp (all grid) and 1 × 7, 7 × 1 and 2 × 2 images give the
/// furnace's albedo × L; 1 spp with the ramp is finite everywhere.
#[test]
fn tiny_images_and_one_sample_per_pixel_stay_exact() {
    let l = [3.0f32, 0.5, 1e6];
    let expected = [0.5 * l[0], 0.25 * l[1], l[2]];
    let (_, sparse) = pair(16, unit_grid());
    let one = box_samples(1, 1, SampleKind::Indirect, None, |_| l);
    let result = reconstruct_samples(&one, GatherTarget::Indirect, &sparse).unwrap();
    assert_eq!(result.image.pixels, vec![expected]);
    assert_eq!(result.gather.sparse, Some((1, 0, 0, 0, 0)));
    for (w, h) in [(1u32, 7u32), (7, 1), (2, 2)] {
        // A w × h window of a 7 × 7 image's samples, at 1 spp.
        let full = box_samples(7, 1, SampleKind::Indirect, None, |_| l);
        let mut cut = IndirectSamples::empty("cut.lfrs".into(), SampleKind::Indirect, (w, h, 1), (w * h) as usize);
        let mut radiance = Vec::new();
        let mut albedo = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let i = (y * 7 + x) as usize;
                cut.film.push(full.film[i]);
                cut.primary_hit.push(full.primary_hit[i]);
                cut.primary_normal.push(full.primary_normal[i]);
                cut.direction.push(full.direction[i]);
                cut.class.push(full.class[i]);
                cut.secondary_hit.push(full.secondary_hit[i]);
                cut.secondary_normal.push(full.secondary_normal[i]);
                radiance.push(full.radiance.as_ref().unwrap()[i]);
                albedo.push(full.albedo.as_ref().unwrap()[i]);
            }
        }
        cut.radiance = Some(radiance);
        cut.albedo = Some(albedo);
        let result = reconstruct_samples(&cut, GatherTarget::Indirect, &sparse).unwrap();
        let close = |p: &[f32; 3]| (0..3).all(|c| (p[c] - expected[c]).abs() <= expected[c] * 2f32.powi(-22));
        assert!(result.image.pixels.iter().all(close), "{w}x{h}: {:?}", result.image.pixels);
    }
    let samples = box_samples(9, 1, SampleKind::Indirect, None, ramp);
    let result = reconstruct_samples(&samples, GatherTarget::Indirect, &sparse).unwrap();
    assert!(result.image.pixels.iter().flatten().all(|v| v.is_finite()));
}

/// A step edge: the floor's right half (x > 0) raised to z = 0.3, a step of many pixel
/// footprints. Every pixel off the grid whose cell holds corners on both sides (here half its
/// corners' weight or more across the step, above 1 − [`SparseParams::min_coverage`]) is refined
/// (the full gather's bits); pixels whose corners all lie on their own level are interpolated.
#[test]
fn a_step_edge_is_gathered_in_full() {
    let mut samples = box_samples(16, 1, SampleKind::Indirect, None, ramp);
    for p in samples.primary_hit.iter_mut() {
        if p[0] > 0.0 {
            p[2] = 0.3;
        }
    }
    let (full, sparse) = pair(16, unit_grid());
    let oracle = reconstruct_samples(&samples, GatherTarget::Indirect, &full).unwrap();
    let result = reconstruct_samples(&samples, GatherTarget::Indirect, &sparse).unwrap();
    let raised = |x: u32, y: u32| samples.primary_hit[(y * 16 + x) as usize][2] > 0.0;
    let (mut edge, mut flat_interpolated) = (0, 0);
    for y in 0..16u32 {
        for x in 0..16u32 {
            if on_grid(x, 16, 2) && on_grid(y, 16, 2) {
                continue;
            }
            let corners: Vec<bool> = cell(y, 16, 2)
                .iter()
                .filter(|c| c.1 > 0.0)
                .flat_map(|&(cy, _)| cell(x, 16, 2).into_iter().filter(|c| c.1 > 0.0).map(move |(cx, _)| (cx, cy)))
                .map(|(cx, cy)| raised(cx, cy))
                .collect();
            if corners.contains(&true) && corners.contains(&false) {
                edge += 1;
                assert_eq!(result.image.get(x, y), oracle.image.get(x, y), "edge pixel ({x}, {y}) refined");
            } else if result.image.get(x, y) != oracle.image.get(x, y) {
                flat_interpolated += 1;
            }
        }
    }
    let (_, interpolated, refined, hits, by_light) = result.gather.sparse.unwrap();
    assert!(edge >= 16 && hits - by_light >= edge && refined == hits, "{edge} edge pixels, {hits} hits refined");
    assert!(flat_interpolated > 64 && interpolated >= flat_interpolated, "{flat_interpolated} {interpolated}");
}

/// A smooth ramp of light: interpolated pixels stay within a stated bound of the full gather
/// at the same rays (both against a 1024-ray full gather: the sparse image's mean error at
/// most that of the full gather's at 64 rays plus 0.01, its worst pixel within 0.1 of light in
/// 0 … 1).
#[test]
fn a_ramp_is_interpolated_within_the_stated_bound() {
    let samples = box_samples(16, 4, SampleKind::Indirect, None, ramp);
    let (full, sparse) = pair(64, unit_grid());
    let truth =
        reconstruct_samples(&samples, GatherTarget::Indirect, &IlfrSettings { recon_rays: 1024, ..full.clone() })
            .unwrap();
    let errors = |r: &Reconstructed| {
        let d: Vec<f64> = r
            .image
            .pixels
            .iter()
            .flatten()
            .zip(truth.image.pixels.iter().flatten())
            .map(|(a, b)| (a - b).abs() as f64)
            .collect();
        (d.iter().sum::<f64>() / d.len() as f64, d.iter().copied().fold(0.0, f64::max))
    };
    let (full_mean, full_worst) = errors(&reconstruct_samples(&samples, GatherTarget::Indirect, &full).unwrap());
    let result = reconstruct_samples(&samples, GatherTarget::Indirect, &sparse).unwrap();
    let (mean, worst) = errors(&result);
    let (_, interpolated, _, _, _) = result.gather.sparse.unwrap();
    assert!(interpolated > 100, "{:?}", result.gather.sparse);
    assert!(mean <= full_mean + 0.01 && worst < 0.1, "sparse {mean} / {worst}, full {full_mean} / {full_worst}");
}

/// The same image and counts on 1 and 2 threads.
#[test]
fn the_image_does_not_depend_on_the_thread_count() {
    let mut samples = box_samples(13, 2, SampleKind::Indirect, None, ramp);
    for p in samples.primary_hit.iter_mut() {
        if p[1] > 0.2 {
            p[2] = 0.2;
        }
    }
    let (_, sparse) = pair(16, SparseParams { stride: 3, grid_ray_factor: 2, ..unit_grid() });
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| reconstruct_samples(&samples, GatherTarget::Indirect, &sparse).unwrap())
    };
    let (one, two) = (run(1), run(2));
    assert_eq!(bits(&one), bits(&two));
    assert_eq!(one.gather, two.gather);
    let (_, interpolated, refined, _, _) = one.gather.sparse.unwrap();
    assert!(interpolated > 0 && refined > 0, "{:?}", one.gather.sparse);
}
