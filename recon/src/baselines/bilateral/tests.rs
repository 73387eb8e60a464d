//! The unit tests of `bilateral.rs`, in a file of their own beside it for their length.

use super::*;
use crate::lcg::Lcg;

fn flat_guide(width: u32, height: u32) -> GuideBuffers {
    let n = (width * height) as usize;
    GuideBuffers {
        width,
        height,
        normal: vec![[0.0, 0.0, 1.0]; n],
        depth: vec![2.0; n],
        position: vec![[0.0; 3]; n],
        secondary_normal: None,
    }
}

/// Random normals, depths and a few escaped pixels.
fn messy_guide(width: u32, height: u32, seed: u64) -> GuideBuffers {
    let mut rng = Lcg(seed);
    let mut guide = flat_guide(width, height);
    for i in 0..guide.pixel_count() {
        if rng.uniform() < 0.1 {
            guide.normal[i] = [0.0; 3];
            guide.depth[i] = 0.0;
        } else {
            let n = [rng.uniform() - 0.5, rng.uniform() - 0.5, 1.0];
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            guide.normal[i] = n.map(|c| c / len);
            guide.depth[i] = 0.5 + 10.0 * rng.uniform();
        }
    }
    guide
}

fn noise_image(width: u32, height: u32, seed: u64) -> Image {
    let mut rng = Lcg(seed);
    let pixels = (0..width * height).map(|_| [rng.uniform(), 2.0 * rng.uniform(), rng.uniform() - 0.5]).collect();
    Image::from_pixels(width, height, pixels)
}

fn max_abs_diff(a: &Image, b: &Image) -> f32 {
    a.pixels.iter().zip(&b.pixels).flat_map(|(p, q)| (0..3).map(move |c| (p[c] - q[c]).abs())).fold(0.0, f32::max)
}

/// Spatial-only Gaussian over the clipped window, written from the definition.
fn naive_gaussian(image: &Image, radius: i64, sigma: f64) -> Image {
    let (w, h) = (image.width as i64, image.height as i64);
    let mut out = Image::new(image.width, image.height);
    for y in 0..h {
        for x in 0..w {
            let (mut sum, mut total) = ([0.0f64; 3], 0.0f64);
            for dy in -radius..=radius {
                for dx in -radius..=radius {
                    let (qx, qy) = (x + dx, y + dy);
                    if qx < 0 || qy < 0 || qx >= w || qy >= h {
                        continue;
                    }
                    let wgt = (-((dx * dx + dy * dy) as f64) / (2.0 * sigma * sigma)).exp();
                    let c = image.get(qx as u32, qy as u32);
                    for k in 0..3 {
                        sum[k] += wgt * c[k] as f64;
                    }
                    total += wgt;
                }
            }
            out.set(x as u32, y as u32, sum.map(|s| (s / total) as f32));
        }
    }
    out
}

fn geometry_blind(radius: u32, sigma_spatial: f32) -> BilateralParams {
    BilateralParams { radius, sigma_spatial, sigma_normal: 1e30, sigma_depth: 1e30 }
}

#[test]
fn exp_neg_is_accurate_over_its_range() {
    let mut worst = 0.0f64;
    for i in 0..=800_000 {
        let x = -(i as f32) * (MAX_EXPONENT / 800_000.0);
        let exact = (x as f64).exp();
        worst = worst.max(((exp_neg(x) as f64 - exact) / exact).abs());
    }
    assert!(worst < 1e-6, "worst relative error {worst}");
    assert_eq!(exp_neg(0.0), 1.0);
}

#[test]
fn constant_input_is_unchanged_everywhere() {
    for (w, h) in [(1, 1), (2, 2), (7, 5), (23, 17)] {
        let guide = messy_guide(w, h, 7);
        let noisy = Image::from_pixels(w, h, vec![[0.3, 1.7, 42.0]; (w * h) as usize]);
        for radius in [0, 1, 3, 8, 40] {
            let (out, report) = cross_bilateral(&noisy, &guide, &BilateralParams::with_radius(radius)).unwrap();
            assert_eq!(report.sanitised_values, 0);
            for p in &out.pixels {
                for (c, e) in p.iter().zip([0.3, 1.7, 42.0]) {
                    assert!((c - e).abs() <= 1e-5 * e, "{w}x{h} r{radius}: {p:?}");
                }
            }
        }
    }
}

#[test]
fn without_range_terms_it_is_the_naive_gaussian() {
    for (w, h, radius, sigma) in [(13, 9, 3, 1.5), (20, 11, 6, 3.0), (5, 4, 10, 2.0), (1, 1, 2, 1.0), (2, 2, 1, 0.7)] {
        let noisy = noise_image(w, h, 3);
        // Random (non-escaped) geometry: the huge σ must make it irrelevant.
        let mut guide = messy_guide(w, h, 11);
        for i in 0..guide.pixel_count() {
            if guide.depth[i] == 0.0 {
                guide.depth[i] = 1.0;
                guide.normal[i] = [1.0, 0.0, 0.0];
            }
        }
        let (out, _) = cross_bilateral(&noisy, &guide, &geometry_blind(radius, sigma)).unwrap();
        let expected = naive_gaussian(&noisy, radius as i64, sigma as f64);
        assert!(max_abs_diff(&out, &expected) < 1e-5, "{w}x{h} r{radius}");
    }
}

#[test]
fn all_terms_match_the_formula() {
    // Naive evaluation of the documented weight, escaped pixels included.
    let (w, h) = (15u32, 11u32);
    let noisy = noise_image(w, h, 6);
    let guide = messy_guide(w, h, 8);
    let params = BilateralParams { radius: 4, sigma_spatial: 2.5, sigma_normal: 0.3, sigma_depth: 0.4 };
    let (out, _) = cross_bilateral(&noisy, &guide, &params).unwrap();
    let surface = |i: usize| guide.depth[i] > 0.0;
    for y in 0..h as i64 {
        for x in 0..w as i64 {
            let p = (y * w as i64 + x) as usize;
            let (mut sum, mut total) = ([0.0f64; 3], 0.0f64);
            for qy in (y - 4).max(0)..=(y + 4).min(h as i64 - 1) {
                for qx in (x - 4).max(0)..=(x + 4).min(w as i64 - 1) {
                    let q = (qy * w as i64 + qx) as usize;
                    if surface(p) != surface(q) {
                        continue;
                    }
                    let d2 = ((qx - x).pow(2) + (qy - y).pow(2)) as f64;
                    let mut wgt = (-d2 / (2.0 * 2.5 * 2.5)).exp();
                    if surface(p) {
                        let (np, nq) = (guide.normal[p], guide.normal[q]);
                        let dn2: f64 = (0..3).map(|k| (np[k] as f64 - nq[k] as f64).powi(2)).sum();
                        let (zp, zq) = (guide.depth[p] as f64, guide.depth[q] as f64);
                        wgt *= (-dn2 / (2.0 * 0.3 * 0.3)).exp() * (-((zp - zq) / (0.4 * zp)).powi(2) / 2.0).exp();
                    }
                    let c = noisy.pixels[q];
                    for k in 0..3 {
                        sum[k] += wgt * c[k] as f64;
                    }
                    total += wgt;
                }
            }
            let got = out.pixels[p];
            for k in 0..3 {
                assert!((got[k] as f64 - sum[k] / total).abs() < 1e-5, "({x},{y})");
            }
        }
    }
}

#[test]
fn radius_zero_is_identity() {
    let noisy = noise_image(9, 6, 5);
    let (out, _) = cross_bilateral(&noisy, &messy_guide(9, 6, 1), &BilateralParams::with_radius(0)).unwrap();
    assert_eq!(out, noisy);
}

#[test]
fn radius_larger_than_the_image_and_tiny_images() {
    for (w, h) in [(1, 1), (2, 2), (3, 1), (1, 4)] {
        let noisy = noise_image(w, h, 9);
        let params = geometry_blind(100, 50.0);
        let (out, _) = cross_bilateral(&noisy, &flat_guide(w, h), &params).unwrap();
        let expected = naive_gaussian(&noisy, 100, 50.0);
        assert!(max_abs_diff(&out, &expected) < 1e-5, "{w}x{h}");
    }
    // 1x1 with real parameters: the single pixel is returned.
    let noisy = Image::from_pixels(1, 1, vec![[1.0, 2.0, 3.0]]);
    let (out, _) = cross_bilateral(&noisy, &flat_guide(1, 1), &BilateralParams::default()).unwrap();
    assert_eq!(out, noisy);
}

#[test]
fn a_depth_step_is_not_blurred_across() {
    // Two parallel planes at depth 1 (left, lit) and 2 (right, dark), with noise.
    let (w, h) = (40u32, 24u32);
    let mut guide = flat_guide(w, h);
    let mut truth = Image::new(w, h);
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            guide.depth[i] = if x < w / 2 { 1.0 } else { 2.0 };
            truth.set(x, y, if x < w / 2 { [1.0; 3] } else { [0.0; 3] });
        }
    }
    let mut rng = Lcg(17);
    let noisy =
        Image::from_pixels(w, h, truth.pixels.iter().map(|p| p.map(|c| c + 0.2 * (rng.uniform() - 0.5))).collect());
    let params = BilateralParams::with_radius(6);
    let (edge_aware, _) = cross_bilateral(&noisy, &guide, &params).unwrap();
    let (blind, _) = cross_bilateral(&noisy, &guide, &geometry_blind(6, params.sigma_spatial)).unwrap();
    // Mean absolute error over the four columns on each side of the step.
    let edge_error = |image: &Image| {
        let mut total = 0.0;
        for y in 0..h {
            for x in w / 2 - 4..w / 2 + 4 {
                total += (image.get(x, y)[0] - truth.get(x, y)[0]).abs();
            }
        }
        total / (8 * h) as f32
    };
    let (aware, plain) = (edge_error(&edge_aware), edge_error(&blind));
    assert!(plain > 0.15, "the plain Gaussian must blur the step: {plain}");
    assert!(aware < 0.1 * plain, "edge-aware error {aware} vs plain {plain}");
}

#[test]
fn non_finite_values_are_sanitised_and_counted() {
    let mut noisy = noise_image(8, 8, 2);
    noisy.set(3, 3, [f32::NAN, 1.0, f32::INFINITY]);
    noisy.set(0, 7, [0.0, f32::NEG_INFINITY, 0.0]);
    let mut guide = flat_guide(8, 8);
    guide.normal[10] = [f32::NAN, 0.0, 1.0];
    guide.depth[20] = f32::INFINITY;
    let (out, report) = cross_bilateral(&noisy, &guide, &BilateralParams::with_radius(3)).unwrap();
    assert_eq!(report.sanitised_values, 5);
    assert_eq!(out.nonfinite_pixels(), 0);
}

#[test]
fn black_stays_black_and_spikes_stay_finite() {
    let guide = messy_guide(16, 12, 4);
    let black = Image::new(16, 12);
    let (out, _) = cross_bilateral(&black, &guide, &BilateralParams::with_radius(5)).unwrap();
    assert_eq!(out, black);

    let mut spiky = noise_image(16, 12, 8);
    spiky.set(5, 5, [1e9, 1e9, 1e9]);
    spiky.set(6, 5, [f32::MAX, -f32::MAX, f32::MAX]);
    let (out, _) = cross_bilateral(&spiky, &flat_guide(16, 12), &BilateralParams::with_radius(5)).unwrap();
    assert_eq!(out.nonfinite_pixels(), 0);
    let huge = Image::from_pixels(4, 4, vec![[f32::MAX; 3]; 16]);
    let (out, _) = cross_bilateral(&huge, &flat_guide(4, 4), &BilateralParams::with_radius(3)).unwrap();
    assert!(out.pixels.iter().all(|p| p.iter().all(|c| c.is_finite() && *c > 0.9 * f32::MAX)));
}

#[test]
fn values_beyond_the_summing_range_are_filtered_like_any_other() {
    // Scaling the input by 2^110 (past `MAX_FILTERED_MAGNITUDE`) scales the output by it.
    let noisy = noise_image(12, 9, 4);
    let guide = messy_guide(12, 9, 5);
    let factor = 2f32.powi(110);
    let big = Image::from_pixels(12, 9, noisy.pixels.iter().map(|p| p.map(|c| c * factor)).collect());
    let params = BilateralParams::with_radius(4);
    let (small_out, _) = cross_bilateral(&noisy, &guide, &params).unwrap();
    let (big_out, _) = cross_bilateral(&big, &guide, &params).unwrap();
    for (s, b) in small_out.pixels.iter().zip(&big_out.pixels) {
        for k in 0..3 {
            assert!((b[k] / factor - s[k]).abs() <= 1e-6 * (1.0 + s[k].abs()), "{s:?} vs {b:?}");
        }
    }
}

#[test]
fn escaped_pixels_do_not_bleed_into_surfaces() {
    // A 5x5 surface with one escaped pixel in the middle and one in a corner.
    let mut guide = flat_guide(5, 5);
    let mut noisy = Image::from_pixels(5, 5, vec![[1.0; 3]; 25]);
    for (x, y) in [(2, 2), (0, 0)] {
        let i = y * 5 + x;
        guide.normal[i] = [0.0; 3];
        guide.depth[i] = 0.0;
    }
    noisy.set(2, 2, [5.0; 3]);
    noisy.set(0, 0, [3.0; 3]);
    let (out, _) = cross_bilateral(&noisy, &guide, &BilateralParams::with_radius(1)).unwrap();
    assert_eq!(out.get(2, 2), [5.0; 3]);
    assert_eq!(out.get(0, 0), [3.0; 3]);
    for y in 0..5 {
        for x in 0..5 {
            if (x, y) != (2, 2) && (x, y) != (0, 0) {
                assert!(out.get(x, y).iter().all(|c| (c - 1.0).abs() < 1e-6), "({x},{y}): {:?}", out.get(x, y));
            }
        }
    }
    // With a wider window the two escaped pixels mix with each other only.
    let (out, _) = cross_bilateral(&noisy, &guide, &BilateralParams::with_radius(3)).unwrap();
    let (a, b) = (out.get(2, 2)[0], out.get(0, 0)[0]);
    assert!(a > 3.0 && a < 5.0 && b > 3.0 && b < 5.0 && (a + b - 8.0).abs() < 1e-5);
}

#[test]
fn mismatched_inputs_and_bad_parameters_are_errors() {
    let noisy = noise_image(4, 3, 1);
    let params = BilateralParams::default();
    assert!(cross_bilateral(&noisy, &flat_guide(3, 4), &params).unwrap_err().to_string().contains("4x3"));
    let mut inconsistent = flat_guide(4, 3);
    inconsistent.depth.pop();
    assert!(cross_bilateral(&noisy, &inconsistent, &params).unwrap_err().to_string().contains("inconsistent"));
    let mut short = noisy.clone();
    short.pixels.pop();
    assert!(cross_bilateral(&short, &flat_guide(4, 3), &params).is_err());
    let guide = flat_guide(4, 3);
    for bad in [0.0, -1.0, f32::NAN, f32::INFINITY] {
        for params in [
            BilateralParams { sigma_spatial: bad, ..params },
            BilateralParams { sigma_normal: bad, ..params },
            BilateralParams { sigma_depth: bad, ..params },
        ] {
            assert!(cross_bilateral(&noisy, &guide, &params).unwrap_err().to_string().contains("positive and finite"));
        }
    }
}

#[test]
fn empty_images_are_fine() {
    let (out, _) = cross_bilateral(&Image::new(0, 0), &flat_guide(0, 0), &BilateralParams::default()).unwrap();
    assert_eq!(out.pixel_count(), 0);
}

/// `cargo test --release -p recon --lib timing_cross_bilateral -- --ignored --nocapture`
#[test]
#[ignore]
fn timing_cross_bilateral_1024x768() {
    let (w, h) = (1024, 768);
    let noisy = noise_image(w, h, 1);
    let guide = messy_guide(w, h, 2);
    for radius in [16, 24, 32] {
        let start = std::time::Instant::now();
        let (out, _) = cross_bilateral(&noisy, &guide, &BilateralParams::with_radius(radius)).unwrap();
        let elapsed = start.elapsed();
        assert_eq!(out.nonfinite_pixels(), 0);
        println!(
            "cross_bilateral 1024x768 radius {radius}: {:.0} ms on {} threads",
            elapsed.as_secs_f64() * 1e3,
            rayon::current_num_threads()
        );
    }
}
