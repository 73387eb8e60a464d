//! The unit tests of `atrous.rs`, in a file of their own beside it for their length.

use super::*;
use crate::lcg::Lcg;

/// A fronto-parallel plane at depth 2 with positions 0.01 apart.
fn flat_guide(width: u32, height: u32) -> GuideBuffers {
    let n = (width * height) as usize;
    GuideBuffers {
        width,
        height,
        normal: vec![[0.0, 0.0, 1.0]; n],
        depth: vec![2.0; n],
        position: (0..n)
            .map(|i| [(i % width as usize) as f32 * 0.01, (i / width as usize) as f32 * 0.01, 2.0])
            .collect(),
        secondary_normal: None,
    }
}

/// Random normals, depths, positions and secondary normals, with a few escaped pixels.
fn messy_guide(width: u32, height: u32, seed: u64) -> GuideBuffers {
    let mut rng = Lcg(seed);
    let mut guide = flat_guide(width, height);
    let mut secondary = Vec::with_capacity(guide.pixel_count());
    for i in 0..guide.pixel_count() {
        secondary.push([rng.uniform(), rng.uniform(), rng.uniform()]);
        if rng.uniform() < 0.1 {
            guide.normal[i] = [0.0; 3];
            guide.depth[i] = 0.0;
            guide.position[i] = [0.0; 3];
        } else {
            let n = [rng.uniform() - 0.5, rng.uniform() - 0.5, 1.0];
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            guide.normal[i] = n.map(|c| c / len);
            guide.depth[i] = 0.5 + 10.0 * rng.uniform();
            guide.position[i] = [rng.uniform(), rng.uniform(), guide.depth[i]];
        }
    }
    guide.secondary_normal = Some(secondary);
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

fn no_edges(iterations: u32) -> AtrousParams {
    AtrousParams { iterations, sigma_color: None, sigma_normal: 1e30, sigma_position: Some(1e30), ..Default::default() }
}

/// One dilated B3 convolution, taps outside the image dropped and the rest renormalised,
/// written from the definition.
fn naive_b3(image: &Image, step: i64) -> Image {
    let h = [1.0f64 / 16.0, 0.25, 0.375, 0.25, 1.0 / 16.0];
    let (w, ht) = (image.width as i64, image.height as i64);
    let mut out = Image::new(image.width, image.height);
    for y in 0..ht {
        for x in 0..w {
            let (mut sum, mut total) = ([0.0f64; 3], 0.0f64);
            for j in -2i64..=2 {
                for i in -2i64..=2 {
                    let (qx, qy) = (x + i * step, y + j * step);
                    if qx < 0 || qy < 0 || qx >= w || qy >= ht {
                        continue;
                    }
                    let wgt = h[(i + 2) as usize] * h[(j + 2) as usize];
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

#[test]
fn constant_input_is_unchanged_everywhere() {
    for (w, h) in [(1, 1), (2, 2), (7, 5), (41, 23)] {
        let guide = messy_guide(w, h, 7);
        let noisy = Image::from_pixels(w, h, vec![[0.3, 1.7, 42.0]; (w * h) as usize]);
        for iterations in [1, 3, 5, 8] {
            for (sigma_color, use_secondary_normal) in [(None, false), (Some(0.5), true)] {
                let params = AtrousParams { iterations, sigma_color, use_secondary_normal, ..Default::default() };
                let (out, report) = atrous(&noisy, &guide, &params).unwrap();
                assert_eq!(report.sanitised_values, 0);
                for p in &out.pixels {
                    for (c, e) in p.iter().zip([0.3, 1.7, 42.0]) {
                        assert!((c - e).abs() <= 1e-5 * e, "{w}x{h} k{iterations}: {p:?}");
                    }
                }
            }
        }
    }
}

#[test]
fn one_level_without_edge_terms_is_the_b3_convolution() {
    for (w, h) in [(1, 1), (2, 2), (3, 7), (19, 13)] {
        let noisy = noise_image(w, h, 3);
        // Random geometry without escaped pixels: the huge σ must make it irrelevant.
        let mut guide = messy_guide(w, h, 5);
        for i in 0..guide.pixel_count() {
            if guide.depth[i] == 0.0 {
                guide.depth[i] = 1.0;
                guide.normal[i] = [0.0, 1.0, 0.0];
            }
        }
        let (out, _) = atrous(&noisy, &guide, &no_edges(1)).unwrap();
        assert!(max_abs_diff(&out, &naive_b3(&noisy, 1)) < 1e-5, "{w}x{h}");
    }
}

#[test]
fn all_terms_match_the_formula() {
    // Naive evaluation of the documented cascade with every term on, escaped pixels
    // included; σ_rt halves per level.
    let (w, h) = (17i64, 12i64);
    let noisy = noise_image(w as u32, h as u32, 6);
    let guide = messy_guide(w as u32, h as u32, 8);
    let (sr, sn, sx, ss) = (0.8f64, 0.5f64, 0.7f64, 0.6f64);
    let params = AtrousParams {
        iterations: 3,
        sigma_color: Some(sr as f32),
        sigma_normal: sn as f32,
        sigma_position: Some(sx as f32),
        use_secondary_normal: true,
        sigma_secondary_normal: ss as f32,
    };
    let (out, _) = atrous(&noisy, &guide, &params).unwrap();
    let secondary = guide.secondary_normal.as_ref().unwrap();
    let d2 = |a: [f32; 3], b: [f32; 3]| -> f64 { (0..3).map(|k| (a[k] as f64 - b[k] as f64).powi(2)).sum() };
    let kernel = [1.0f64 / 16.0, 0.25, 0.375, 0.25, 1.0 / 16.0];
    let mut current: Vec<[f64; 3]> = noisy.pixels.iter().map(|p| p.map(|c| c as f64)).collect();
    for level in 0..3 {
        let step = 1i64 << level;
        let sigma_colour = sr / (1 << level) as f64;
        let mut next = current.clone();
        for y in 0..h {
            for x in 0..w {
                let p = (y * w + x) as usize;
                let (mut sum, mut total) = ([0.0f64; 3], 0.0f64);
                for j in -2i64..=2 {
                    for i in -2i64..=2 {
                        let (qx, qy) = (x + i * step, y + j * step);
                        if qx < 0 || qy < 0 || qx >= w || qy >= h {
                            continue;
                        }
                        let q = (qy * w + qx) as usize;
                        if (guide.depth[p] > 0.0) != (guide.depth[q] > 0.0) {
                            continue;
                        }
                        let dc: f64 = (0..3).map(|k| (current[p][k] - current[q][k]).powi(2)).sum();
                        let mut wgt = kernel[(i + 2) as usize] * kernel[(j + 2) as usize];
                        wgt *= (-dc / (sigma_colour * sigma_colour)).exp();
                        if guide.depth[p] > 0.0 {
                            wgt *= (-d2(guide.normal[p], guide.normal[q]) / (sn * sn)).exp()
                                * (-d2(guide.position[p], guide.position[q]) / (sx * sx)).exp()
                                * (-d2(secondary[p], secondary[q]) / (ss * ss)).exp();
                        }
                        for k in 0..3 {
                            sum[k] += wgt * current[q][k];
                        }
                        total += wgt;
                    }
                }
                next[p] = sum.map(|s| s / total);
            }
        }
        current = next;
    }
    for (got, expected) in out.pixels.iter().zip(&current) {
        for k in 0..3 {
            assert!((got[k] as f64 - expected[k]).abs() < 1e-4, "{got:?} vs {expected:?}");
        }
    }
}

#[test]
fn k_levels_without_edge_terms_are_the_dilated_cascade() {
    let (w, h) = (37, 29);
    let noisy = noise_image(w, h, 13);
    let guide = flat_guide(w, h);
    for iterations in 1..=MAX_ITERATIONS {
        let (out, _) = atrous(&noisy, &guide, &no_edges(iterations)).unwrap();
        let mut expected = noisy.clone();
        for level in 0..iterations {
            expected = naive_b3(&expected, 1 << level);
        }
        assert!(max_abs_diff(&out, &expected) < 1e-5, "k = {iterations}");
    }
}

/// A crease: a floor (normal +z) on the left meeting a wall (normal +x) on the right,
/// positions continuous across the crease; the floor is lit, the wall dark, plus noise.
fn crease(width: u32, height: u32, seed: u64) -> (GuideBuffers, Image, Image) {
    let mut guide = flat_guide(width, height);
    let mut truth = Image::new(width, height);
    let half = width / 2;
    for y in 0..height {
        for x in 0..width {
            let i = (y * width + x) as usize;
            let (fx, fy) = (x as f32 * 0.01, y as f32 * 0.01);
            if x < half {
                guide.normal[i] = [0.0, 0.0, 1.0];
                guide.position[i] = [fx, fy, 0.0];
                truth.set(x, y, [1.0; 3]);
            } else {
                guide.normal[i] = [1.0, 0.0, 0.0];
                guide.position[i] = [half as f32 * 0.01, fy, fx - half as f32 * 0.01];
            }
        }
    }
    let mut rng = Lcg(seed);
    let noisy = Image::from_pixels(
        width,
        height,
        truth.pixels.iter().map(|p| p.map(|c| c + 0.3 * (rng.uniform() - 0.5))).collect(),
    );
    (guide, truth, noisy)
}

/// Mean absolute error of channel 0 over the `band` columns each side of the middle.
fn edge_error(image: &Image, truth: &Image, band: u32) -> f32 {
    let (w, h) = (image.width, image.height);
    let mut total = 0.0;
    for y in 0..h {
        for x in w / 2 - band..w / 2 + band {
            total += (image.get(x, y)[0] - truth.get(x, y)[0]).abs();
        }
    }
    total / (2 * band * h) as f32
}

#[test]
fn a_normal_discontinuity_is_preserved() {
    let (guide, truth, noisy) = crease(64, 32, 21);
    let (aware, _) = atrous(&noisy, &guide, &AtrousParams::default()).unwrap();
    let (blind, _) = atrous(&noisy, &guide, &no_edges(5)).unwrap();
    let (aware, plain) = (edge_error(&aware, &truth, 6), edge_error(&blind, &truth, 6));
    assert!(plain > 0.2, "the plain cascade must blur the crease: {plain}");
    assert!(aware < 0.1 * plain, "edge-aware error {aware} vs plain {plain}");
}

#[test]
fn the_secondary_normal_term_acts_only_where_secondary_normals_differ() {
    // One plane; the left half's secondary hits face +y, the right half's +x.
    let (w, h) = (48u32, 24u32);
    let mut guide = flat_guide(w, h);
    let mut truth = Image::new(w, h);
    let mut secondary = vec![[0.0; 3]; guide.pixel_count()];
    for y in 0..h {
        for x in 0..w {
            let left = x < w / 2;
            secondary[(y * w + x) as usize] = if left { [0.0, 1.0, 0.0] } else { [1.0, 0.0, 0.0] };
            truth.set(x, y, if left { [1.0; 3] } else { [0.0; 3] });
        }
    }
    let mut rng = Lcg(3);
    let noisy =
        Image::from_pixels(w, h, truth.pixels.iter().map(|p| p.map(|c| c + 0.3 * (rng.uniform() - 0.5))).collect());
    guide.secondary_normal = Some(secondary);
    let without = AtrousParams::default();
    let with = AtrousParams { use_secondary_normal: true, ..without };
    let (plain, _) = atrous(&noisy, &guide, &without).unwrap();
    let (extra, _) = atrous(&noisy, &guide, &with).unwrap();
    assert!(max_abs_diff(&plain, &extra) > 0.1);
    let (plain_error, extra_error) = (edge_error(&plain, &truth, 6), edge_error(&extra, &truth, 6));
    assert!(extra_error < 0.2 * plain_error, "with {extra_error} vs without {plain_error}");

    // All secondary normals equal: the term is exactly 1 and changes nothing.
    guide.secondary_normal = Some(vec![[0.3, 0.4, 0.5]; guide.pixel_count()]);
    let (extra, _) = atrous(&noisy, &guide, &with).unwrap();
    assert_eq!(extra, plain);
}

#[test]
fn the_colour_term_keeps_colour_edges() {
    // A sharp colour edge on one flat plane: with σ_rt the edge survives, without it blurs.
    let (w, h) = (32u32, 8u32);
    let pixels = (0..w * h).map(|i| if i % w < w / 2 { [1.0; 3] } else { [0.0; 3] }).collect();
    let noisy = Image::from_pixels(w, h, pixels);
    let guide = flat_guide(w, h);
    let (kept, _) = atrous(&noisy, &guide, &AtrousParams { sigma_color: Some(0.3), ..Default::default() }).unwrap();
    let (blurred, _) = atrous(&noisy, &guide, &AtrousParams::default()).unwrap();
    assert!(max_abs_diff(&kept, &noisy) < 1e-3);
    assert!(max_abs_diff(&blurred, &noisy) > 0.2);
}

#[test]
fn default_sigma_position_is_the_scaled_median_footprint() {
    let guide = flat_guide(20, 10);
    let sigma = default_sigma_position(&guide, 5).unwrap();
    assert!((sigma - 0.32).abs() < 1e-4, "{sigma}");
    let mut empty = flat_guide(4, 4);
    empty.position = vec![[1.0; 3]; 16];
    assert_eq!(default_sigma_position(&empty, 5), None);
    // Still filters (term off) when every position coincides.
    let (out, _) = atrous(&noise_image(4, 4, 1), &empty, &AtrousParams::default()).unwrap();
    assert_eq!(out.nonfinite_pixels(), 0);
}

#[test]
fn tiny_images() {
    let one = Image::from_pixels(1, 1, vec![[1.0, 2.0, 3.0]]);
    let (out, _) = atrous(&one, &flat_guide(1, 1), &AtrousParams::default()).unwrap();
    assert_eq!(out, one);
    let two = noise_image(2, 2, 4);
    let (out, _) = atrous(&two, &flat_guide(2, 2), &no_edges(8)).unwrap();
    let mut expected = two.clone();
    for level in 0..8 {
        expected = naive_b3(&expected, 1 << level);
    }
    assert!(max_abs_diff(&out, &expected) < 1e-5);
    let (out, _) = atrous(&Image::new(0, 0), &flat_guide(0, 0), &AtrousParams::default()).unwrap();
    assert_eq!(out.pixel_count(), 0);
}

#[test]
fn non_finite_values_are_sanitised_and_counted() {
    let mut noisy = noise_image(8, 8, 2);
    noisy.set(3, 3, [f32::NAN, 1.0, f32::INFINITY]);
    noisy.set(0, 7, [0.0, f32::NEG_INFINITY, 0.0]);
    let mut guide = messy_guide(8, 8, 9);
    guide.normal[10] = [f32::NAN, 0.0, 1.0];
    guide.depth[20] = f32::INFINITY;
    guide.position[30] = [0.0, f32::NAN, 0.0];
    guide.secondary_normal.as_mut().unwrap()[40] = [f32::INFINITY, 0.0, 0.0];
    let params = AtrousParams { sigma_color: Some(1.0), use_secondary_normal: true, ..Default::default() };
    let (out, report) = atrous(&noisy, &guide, &params).unwrap();
    assert_eq!(report.sanitised_values, 7);
    assert_eq!(out.nonfinite_pixels(), 0);
    // The unused secondary normals are not read, so not counted.
    let (_, report) = atrous(&noisy, &guide, &AtrousParams::default()).unwrap();
    assert_eq!(report.sanitised_values, 6);
}

#[test]
fn black_stays_black_and_spikes_stay_finite() {
    let guide = messy_guide(16, 12, 4);
    let black = Image::new(16, 12);
    let (out, _) = atrous(&black, &guide, &AtrousParams { sigma_color: Some(0.1), ..Default::default() }).unwrap();
    assert_eq!(out, black);

    let mut spiky = noise_image(16, 12, 8);
    spiky.set(5, 5, [1e9, 1e9, 1e9]);
    spiky.set(6, 5, [f32::MAX, -f32::MAX, f32::MAX]);
    for sigma_color in [None, Some(0.5)] {
        let (out, _) = atrous(&spiky, &guide, &AtrousParams { sigma_color, ..Default::default() }).unwrap();
        assert_eq!(out.nonfinite_pixels(), 0);
    }
    let huge = Image::from_pixels(4, 4, vec![[f32::MAX; 3]; 16]);
    let (out, _) = atrous(&huge, &flat_guide(4, 4), &AtrousParams::default()).unwrap();
    assert!(out.pixels.iter().all(|p| p.iter().all(|c| c.is_finite() && *c > 0.9 * f32::MAX)));
}

#[test]
fn values_beyond_the_summing_range_are_filtered_like_any_other() {
    // Scaling the input and σ_rt by 2^110 (past the summing range) scales the output.
    let noisy = noise_image(12, 9, 4);
    let guide = messy_guide(12, 9, 5);
    let factor = 2f32.powi(110);
    let big = Image::from_pixels(12, 9, noisy.pixels.iter().map(|p| p.map(|c| c * factor)).collect());
    let params = AtrousParams { iterations: 3, sigma_color: Some(0.7), ..Default::default() };
    let big_params = AtrousParams { sigma_color: Some(0.7 * factor), ..params };
    let (small_out, _) = atrous(&noisy, &guide, &params).unwrap();
    let (big_out, _) = atrous(&big, &guide, &big_params).unwrap();
    for (s, b) in small_out.pixels.iter().zip(&big_out.pixels) {
        for k in 0..3 {
            assert!((b[k] / factor - s[k]).abs() <= 1e-5 * (1.0 + s[k].abs()), "{s:?} vs {b:?}");
        }
    }
}

#[test]
fn the_derived_position_sigma_makes_the_filter_scale_free() {
    // The crease scene in units 2^80 times larger filters identically.
    let (guide, _, noisy) = crease(40, 20, 8);
    let mut huge = guide.clone();
    let factor = 2f32.powi(80);
    for x in huge.position.iter_mut() {
        *x = x.map(|c| c * factor);
    }
    let (a, _) = atrous(&noisy, &guide, &AtrousParams::default()).unwrap();
    let (b, _) = atrous(&noisy, &huge, &AtrousParams::default()).unwrap();
    assert!(max_abs_diff(&a, &b) < 1e-6);
    let sigma = default_sigma_position(&guide, 5).unwrap();
    assert!((default_sigma_position(&huge, 5).unwrap() / factor - sigma).abs() < 1e-6 * sigma);
}

#[test]
fn escaped_pixels_do_not_bleed_into_surfaces() {
    let escape = |guide: &mut GuideBuffers, x: usize, y: usize| {
        let i = y * guide.width as usize + x;
        guide.normal[i] = [0.0; 3];
        guide.depth[i] = 0.0;
        guide.position[i] = [0.0; 3];
    };
    // One escaped pixel amid a surface keeps its own value; the surface keeps its own.
    let mut guide = flat_guide(5, 5);
    escape(&mut guide, 2, 2);
    let mut noisy = Image::from_pixels(5, 5, vec![[1.0; 3]; 25]);
    noisy.set(2, 2, [5.0; 3]);
    for iterations in [1, 5] {
        let (out, _) = atrous(&noisy, &guide, &AtrousParams { iterations, ..Default::default() }).unwrap();
        assert_eq!(out.get(2, 2), [5.0; 3]);
        for y in 0..5 {
            for x in 0..5 {
                if (x, y) != (2, 2) {
                    assert!(out.get(x, y).iter().all(|c| (c - 1.0).abs() < 1e-6), "({x},{y}): {:?}", out.get(x, y));
                }
            }
        }
    }
    // Two escaped pixels (a tap apart) mix with each other only.
    escape(&mut guide, 0, 0);
    noisy.set(0, 0, [3.0; 3]);
    let (out, _) = atrous(&noisy, &guide, &AtrousParams::default()).unwrap();
    let (a, b) = (out.get(2, 2)[0], out.get(0, 0)[0]);
    assert!(a > 3.0 && a < 5.0 && b > 3.0 && b < 5.0 && (a + b - 8.0).abs() < 1e-4, "{a} {b}");
    for y in 0..5 {
        for x in 0..5 {
            if (x, y) != (2, 2) && (x, y) != (0, 0) {
                assert!(out.get(x, y).iter().all(|c| (c - 1.0).abs() < 1e-6), "({x},{y}): {:?}", out.get(x, y));
            }
        }
    }
}

#[test]
fn mismatched_inputs_and_bad_parameters_are_errors() {
    let noisy = noise_image(4, 3, 1);
    let params = AtrousParams::default();
    assert!(atrous(&noisy, &flat_guide(3, 4), &params).unwrap_err().to_string().contains("4x3"));
    let mut inconsistent = flat_guide(4, 3);
    inconsistent.position.pop();
    assert!(atrous(&noisy, &inconsistent, &params).unwrap_err().to_string().contains("inconsistent"));
    let guide = flat_guide(4, 3);
    for iterations in [0, MAX_ITERATIONS + 1] {
        assert!(atrous(&noisy, &guide, &AtrousParams { iterations, ..params })
            .unwrap_err()
            .to_string()
            .contains("iterations"));
    }
    for bad in [0.0, -1.0, f32::NAN, f32::INFINITY] {
        for params in [
            AtrousParams { sigma_color: Some(bad), ..params },
            AtrousParams { sigma_normal: bad, ..params },
            AtrousParams { sigma_position: Some(bad), ..params },
            AtrousParams { sigma_secondary_normal: bad, ..params },
        ] {
            assert!(atrous(&noisy, &guide, &params).unwrap_err().to_string().contains("positive and finite"));
        }
    }
    let with = AtrousParams { use_secondary_normal: true, ..params };
    assert!(atrous(&noisy, &guide, &with).unwrap_err().to_string().contains("secondary_normal"));
}

/// `cargo test --release -p recon --lib timing_atrous -- --ignored --nocapture`
#[test]
#[ignore]
fn timing_atrous_1024x768() {
    let (w, h) = (1024, 768);
    let noisy = noise_image(w, h, 1);
    let guide = messy_guide(w, h, 2);
    for iterations in [4, 5, 6] {
        for (sigma_color, use_secondary_normal) in [(None, false), (Some(0.5), true)] {
            let params = AtrousParams { iterations, sigma_color, use_secondary_normal, ..Default::default() };
            let start = std::time::Instant::now();
            let (out, _) = atrous(&noisy, &guide, &params).unwrap();
            let elapsed = start.elapsed();
            assert_eq!(out.nonfinite_pixels(), 0);
            println!(
                "atrous 1024x768 {iterations} iterations (colour {}, secondary normal {}): {:.0} ms on {} threads",
                sigma_color.is_some(),
                use_secondary_normal,
                elapsed.as_secs_f64() * 1e3,
                rayon::current_num_threads()
            );
        }
    }
}
