//! The unit tests of `metrics/mod.rs`, in a file of their own beside it for their length.

use super::*;

/// xorshift64*: a deterministic source of test images, no crates needed.
struct TestRng(u64);

impl TestRng {
    fn new(seed: u64) -> TestRng {
        TestRng(seed.max(1))
    }

    /// Uniform in [0, 1).
    fn uniform(&mut self) -> f32 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let bits = self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 40;
        bits as f32 / (1u64 << 24) as f32
    }

    /// Zero-mean, roughly Gaussian (sum of four uniforms), unit variance.
    fn gaussianish(&mut self) -> f32 {
        let sum: f32 = (0..4).map(|_| self.uniform()).sum();
        (sum - 2.0) * 3.0f32.sqrt()
    }
}

fn constant_image(width: u32, height: u32, value: f32) -> Image {
    Image::from_pixels(width, height, vec![[value; 3]; width as usize * height as usize])
}

fn random_image(width: u32, height: u32, scale: f32, rng: &mut TestRng) -> Image {
    let pixels = (0..width as usize * height as usize)
        .map(|_| [rng.uniform() * scale, rng.uniform() * scale, rng.uniform() * scale])
        .collect();
    Image::from_pixels(width, height, pixels)
}

/// The display transform in f64, written out independently of `ToneMap::apply`.
fn display_f64(value: f32, exposure: f64) -> f64 {
    (value as f64 * exposure).clamp(0.0, 1.0).powf(1.0 / 2.2)
}

fn unit_exposure() -> ToneMap {
    ToneMap::with_exposure(1.0).expect("1 is a valid exposure")
}

const C1: f64 = 0.0001;
const C2: f64 = 0.0009;

fn close(actual: f64, expected: f64, tolerance: f64) -> bool {
    (actual - expected).abs() <= tolerance
}

#[test]
fn psnr_of_a_uniform_offset_matches_the_tone_curve() {
    let reference = constant_image(8, 6, 0.25);
    let test = constant_image(8, 6, 0.25 * 1.1);
    let difference = display_f64(0.25 * 1.1, 1.0) - display_f64(0.25, 1.0);
    let expected = 10.0 * (1.0 / (difference * difference)).log10();
    let psnr = psnr_db(&reference, &test, &unit_exposure()).unwrap();
    assert!(close(psnr, expected, 1e-3), "psnr {psnr}, expected {expected}");
}

#[test]
fn psnr_of_a_two_pixel_image_matches_a_hand_computed_mse() {
    // Display values with exposure 1: reference (1, 0, 0), (0, 0, 0) (4 clamps to 1);
    // test (1, 1, 0), (0, 0, 1) (-3 clamps to 0). Two of six channels differ by 1: MSE 1/3.
    let reference = Image::from_pixels(2, 1, vec![[4.0, 0.0, 0.0], [0.0, 0.0, 0.0]]);
    let test = Image::from_pixels(2, 1, vec![[1.0, 1.0, 0.0], [0.0, -3.0, 1.0]]);
    let psnr = psnr_db(&reference, &test, &unit_exposure()).unwrap();
    assert!(close(psnr, 10.0 * 3.0f64.log10(), 1e-9), "psnr {psnr}");

    // Per pixel one channel of three differs by 1: RMS sqrt(1/3).
    let map = error_map(&reference, &test, &unit_exposure()).unwrap();
    assert_eq!(map.len(), 2);
    for error in map {
        assert!(close(error as f64, (1.0f64 / 3.0).sqrt(), 1e-6), "error {error}");
    }
}

#[test]
fn identical_images_score_perfectly() {
    let mut rng = TestRng::new(7);
    let image = random_image(24, 17, 3.0, &mut rng);
    let tone = ToneMap::auto(&image);
    let metrics = evaluate(&image, &image, &tone).unwrap();
    assert_eq!(metrics.psnr_db, PSNR_CEILING_DB);
    assert_eq!(metrics.rel_mse, 0.0);
    assert!(close(metrics.ssim, 1.0, 1e-12), "ssim {}", metrics.ssim);
    assert_eq!(metrics.nonfinite_pixels, 0);
    assert!(error_map(&image, &image, &tone).unwrap().iter().all(|&e| e == 0.0));
}

#[test]
fn black_reference_gives_the_ceiling_or_the_analytic_psnr() {
    let black = constant_image(12, 12, 0.0);
    let tone = ToneMap::auto(&black);
    assert_eq!(tone.exposure, 1.0);
    assert_eq!(psnr_db(&black, &black, &tone).unwrap(), PSNR_CEILING_DB);

    // Every display value differs by 0.5^(1/2.2): PSNR = -20 log10(0.5^(1/2.2)).
    let grey = constant_image(12, 12, 0.5);
    let psnr = psnr_db(&black, &grey, &tone).unwrap();
    let expected = -20.0 * 0.5f64.powf(1.0 / 2.2).log10();
    assert!(psnr.is_finite());
    assert!(close(psnr, expected, 1e-5), "psnr {psnr}, expected {expected}");
}

#[test]
fn ssim_of_two_constant_images_is_the_luminance_term() {
    let (linear_a, linear_b) = (0.2, 0.7);
    let (a, b) = (display_f64(linear_a, 1.0), display_f64(linear_b, 1.0));
    let expected = (2.0 * a * b + C1) / (a * a + b * b + C1);
    // 32x32 uses the Gaussian valid windows, 5x5 the global window.
    for size in [32, 5] {
        let reference = constant_image(size, size, linear_a);
        let test = constant_image(size, size, linear_b);
        let value = ssim(&reference, &test, &unit_exposure()).unwrap();
        assert!(close(value, expected, 1e-6), "{size}x{size}: ssim {value}, expected {expected}");
    }
}

/// SSIM computed directly: for every valid position and channel, the 11x11 window's
/// weighted statistics by a double loop, in f64; or the global window for small images.
fn naive_ssim(reference: &Image, test: &Image, exposure: f64) -> f64 {
    let (width, height) = (reference.width as usize, reference.height as usize);
    let display = |image: &Image, x: usize, y: usize, c: usize| display_f64(image.pixels[y * width + x][c], exposure);
    let window_ssim = |c: usize, x0: usize, y0: usize, w: usize, h: usize, weight: &dyn Fn(usize, usize) -> f64| {
        let (mut mx, mut my, mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for dy in 0..h {
            for dx in 0..w {
                let wgt = weight(dx, dy);
                mx += wgt * display(reference, x0 + dx, y0 + dy, c);
                my += wgt * display(test, x0 + dx, y0 + dy, c);
            }
        }
        for dy in 0..h {
            for dx in 0..w {
                let wgt = weight(dx, dy);
                let x = display(reference, x0 + dx, y0 + dy, c) - mx;
                let y = display(test, x0 + dx, y0 + dy, c) - my;
                sxx += wgt * x * x;
                syy += wgt * y * y;
                sxy += wgt * x * y;
            }
        }
        ((2.0 * mx * my + C1) * (2.0 * sxy + C2)) / ((mx * mx + my * my + C1) * (sxx + syy + C2))
    };
    let mut total = 0.0;
    if width >= 11 && height >= 11 {
        let mut weights = [[0.0f64; 11]; 11];
        let mut weight_sum = 0.0;
        for (dy, row) in weights.iter_mut().enumerate() {
            for (dx, w) in row.iter_mut().enumerate() {
                let (ox, oy) = (dx as f64 - 5.0, dy as f64 - 5.0);
                *w = (-(ox * ox + oy * oy) / (2.0 * 1.5 * 1.5)).exp();
                weight_sum += *w;
            }
        }
        let weight = |dx: usize, dy: usize| weights[dy][dx] / weight_sum;
        let positions = (width - 10) * (height - 10);
        for c in 0..3 {
            for y0 in 0..=height - 11 {
                for x0 in 0..=width - 11 {
                    total += window_ssim(c, x0, y0, 11, 11, &weight) / positions as f64;
                }
            }
        }
    } else {
        let uniform = 1.0 / (width * height) as f64;
        for c in 0..3 {
            total += window_ssim(c, 0, 0, width, height, &|_, _| uniform);
        }
    }
    total / 3.0
}

#[test]
fn ssim_matches_a_naive_implementation() {
    let mut rng = TestRng::new(12345);
    let exposure = 0.8;
    let tone = ToneMap::with_exposure(exposure as f32).unwrap();
    // Two independent random images, and a reference against a noisy copy of itself.
    let reference = random_image(40, 23, 1.5, &mut rng);
    let unrelated = random_image(40, 23, 1.5, &mut rng);
    let mut noisy = reference.clone();
    for pixel in &mut noisy.pixels {
        for channel in pixel.iter_mut() {
            *channel += 0.05 * rng.gaussianish();
        }
    }
    for test in [&unrelated, &noisy] {
        let fast = ssim(&reference, test, &tone).unwrap();
        let naive = naive_ssim(&reference, test, exposure);
        assert!(close(fast, naive, 1e-5), "ssim {fast}, naive {naive}");
    }
    // One dimension below 11: the global window.
    let narrow_reference = random_image(7, 30, 1.0, &mut rng);
    let narrow_test = random_image(7, 30, 1.0, &mut rng);
    let fast = ssim(&narrow_reference, &narrow_test, &tone).unwrap();
    let naive = naive_ssim(&narrow_reference, &narrow_test, exposure);
    assert!(close(fast, naive, 1e-5), "global window: ssim {fast}, naive {naive}");
}

#[test]
fn relative_mse_matches_a_hand_computation() {
    // Channel contributions (t - r)^2 / (r^2 + 0.01):
    // 0.1^2 / 1.01, 0.1^2 / 0.01 = 1, 0, 0.5^2 / 0.01 = 25 (black reference), 0, 0.
    let reference = Image::from_pixels(2, 1, vec![[1.0, 0.0, 2.0], [0.0, 0.0, 0.0]]);
    let test = Image::from_pixels(2, 1, vec![[1.1, 0.1, 2.0], [0.5, 0.0, 0.0]]);
    let expected = (0.01 / 1.01 + 1.0 + 25.0) / 6.0;
    let value = relative_mse(&reference, &test).unwrap();
    assert!(close(value, expected, 1e-6 * expected), "rel mse {value}, expected {expected}");
}

#[test]
fn nonfinite_test_values_never_improve_a_score() {
    let mut rng = TestRng::new(99);
    let reference = random_image(16, 16, 1.0, &mut rng);
    let mut clean = reference.clone();
    for pixel in &mut clean.pixels {
        for channel in pixel.iter_mut() {
            *channel += 0.02 * rng.gaussianish();
        }
    }
    let (nan_index, inf_index) = (37, 200);
    clean.pixels[nan_index] = reference.pixels[nan_index];
    clean.pixels[inf_index] = reference.pixels[inf_index];
    let mut broken = clean.clone();
    broken.pixels[nan_index][0] = f32::NAN;
    broken.pixels[inf_index][1] = f32::INFINITY;

    let tone = ToneMap::auto(&reference);
    let clean_metrics = evaluate(&reference, &clean, &tone).unwrap();
    let broken_metrics = evaluate(&reference, &broken, &tone).unwrap();
    assert_eq!(broken_metrics.nonfinite_pixels, 2);
    assert_eq!(clean_metrics.nonfinite_pixels, 0);
    assert!(broken_metrics.psnr_db.is_finite());
    assert!(broken_metrics.psnr_db < clean_metrics.psnr_db);
    assert!(broken_metrics.rel_mse.is_finite());
    assert!(broken_metrics.rel_mse > clean_metrics.rel_mse);
    assert!(broken_metrics.ssim.is_finite() && broken_metrics.ssim.abs() <= 1.0);

    let clean_map = error_map(&reference, &clean, &tone).unwrap();
    let broken_map = error_map(&reference, &broken, &tone).unwrap();
    for index in [nan_index, inf_index] {
        assert_eq!(clean_map[index], 0.0);
        // The replaced channel is at least 0.5 away from the reference: RMS >= 0.5 / sqrt(3).
        assert!(broken_map[index] >= 0.5 / 3.0f32.sqrt(), "error {}", broken_map[index]);
    }
    assert!(broken_map.iter().all(|e| e.is_finite() && (0.0..=1.0).contains(e)));
}

#[test]
fn nonfinite_channels_take_the_worst_display_value() {
    // Reference display values 0 and 1; a non-finite channel lands on the opposite end.
    let reference = Image::from_pixels(2, 1, vec![[0.0; 3], [1.0; 3]]);
    let test = Image::from_pixels(2, 1, vec![[f32::NAN, f32::NEG_INFINITY, 0.0], [f32::INFINITY, f32::NAN, 1.0]]);
    let map = error_map(&reference, &test, &unit_exposure()).unwrap();
    let expected = (2.0f32 / 3.0).sqrt();
    assert!(map.iter().all(|&e| (e - expected).abs() < 1e-6), "map {map:?}");
    // Four of six relative-MSE contributions are 1.
    assert!(close(relative_mse(&reference, &test).unwrap(), 4.0 / 6.0, 1e-12));
}

#[test]
fn huge_finite_spikes_stay_finite() {
    let mut rng = TestRng::new(5);
    let reference = random_image(13, 12, 1.0, &mut rng);
    for spike in [1e30, f32::MAX, -f32::MAX] {
        let mut test = reference.clone();
        test.pixels[20] = [spike; 3];
        let tone = ToneMap::auto(&reference);
        let metrics = evaluate(&reference, &test, &tone).unwrap();
        assert!(metrics.psnr_db.is_finite() && metrics.psnr_db < PSNR_CEILING_DB);
        assert!(metrics.rel_mse.is_finite() && metrics.rel_mse > 0.0);
        assert!(metrics.ssim.is_finite());
        assert_eq!(metrics.nonfinite_pixels, 0);
        assert!(error_map(&reference, &test, &tone).unwrap().iter().all(|e| e.is_finite()));
    }
}

#[test]
fn nonfinite_reference_channels_count_as_zero() {
    let mut reference = constant_image(3, 2, 0.4);
    reference.pixels[1] = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY];
    let mut test = reference.clone();
    test.pixels[1] = [0.0; 3];
    let tone = unit_exposure();
    let metrics = evaluate(&reference, &test, &tone).unwrap();
    assert_eq!(metrics.psnr_db, PSNR_CEILING_DB);
    assert_eq!(metrics.rel_mse, 0.0);
    assert!(close(metrics.ssim, 1.0, 1e-12));
}

#[test]
fn size_mismatch_is_an_error_everywhere() {
    let reference = Image::new(4, 3);
    let test = Image::new(3, 4);
    let tone = unit_exposure();
    let expected = SizeMismatch { expected: (4, 3), found: (3, 4) };
    assert_eq!(evaluate(&reference, &test, &tone), Err(expected.clone()));
    assert_eq!(psnr_db(&reference, &test, &tone), Err(expected.clone()));
    assert_eq!(relative_mse(&reference, &test), Err(expected.clone()));
    assert_eq!(ssim(&reference, &test, &tone), Err(expected.clone()));
    assert_eq!(error_map(&reference, &test, &tone), Err(expected));
}

#[test]
fn auto_exposure_maps_the_nearest_rank_99th_percentile_to_one() {
    // Grey pixels of luminance 0..=99 in scrambled order. Zero is not positive, leaving the
    // n = 99 values 1..=99; the percentile is at index ceil(0.99 * 99) - 1 = 98: 99.
    let mut values: Vec<f32> = (0..100).map(|v| v as f32).collect();
    values.reverse();
    values.swap(3, 70);
    let pixels: Vec<[f32; 3]> = values.iter().map(|&v| [v; 3]).collect();
    let reference = Image::from_pixels(10, 10, pixels.clone());
    let p99 = luminance([99.0; 3]);
    let exposure = ToneMap::auto(&reference).exposure;
    assert!(close(exposure as f64, 1.0 / p99 as f64, 1e-6 / p99 as f64), "exposure {exposure}");
    assert!(close(exposure as f64, 1.0 / 99.0, 1e-6 / 99.0));
    assert_eq!(ToneMap::auto(&reference).gamma, ToneMap::GAMMA);

    // Non-finite and non-positive pixels are ignored.
    let mut with_invalid = pixels;
    with_invalid.extend([[f32::NAN; 3], [f32::INFINITY; 3], [f32::NAN, 1e3, 1e3], [-5.0; 3]]);
    with_invalid.extend([[0.0; 3]; 4]);
    let reference = Image::from_pixels(12, 9, with_invalid);
    assert_eq!(ToneMap::auto(&reference).exposure, exposure);

    // A single pixel is its own percentile.
    assert_eq!(ToneMap::auto(&constant_image(1, 1, 4.0)).exposure, 1.0 / luminance([4.0; 3]));
}

#[test]
fn auto_exposure_of_a_black_or_empty_reference_is_one() {
    assert_eq!(ToneMap::auto(&constant_image(5, 4, 0.0)).exposure, 1.0);
    assert_eq!(ToneMap::auto(&Image::new(0, 0)).exposure, 1.0);
    assert_eq!(ToneMap::auto(&constant_image(2, 2, f32::NAN)).exposure, 1.0);
}

#[test]
fn with_exposure_rejects_invalid_exposures() {
    assert_eq!(ToneMap::with_exposure(2.0), Ok(ToneMap { exposure: 2.0, gamma: 2.2 }));
    for bad in [0.0, -1.0, f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        assert!(ToneMap::with_exposure(bad).is_err(), "exposure {bad}");
    }
    assert_eq!(InvalidExposure(-1.0).to_string(), "exposure must be finite and positive, got -1");
}

#[test]
fn apply_follows_the_display_curve_and_stays_in_unit_range() {
    let tone = ToneMap::with_exposure(2.0).unwrap();
    assert_eq!(tone.apply(0.0), 0.0);
    assert_eq!(tone.apply(0.5), 1.0);
    assert_eq!(tone.apply(7.0), 1.0);
    assert_eq!(tone.apply(-1.0), 0.0);
    assert_eq!(tone.apply(f32::INFINITY), 1.0);
    assert_eq!(tone.apply(f32::NEG_INFINITY), 0.0);
    assert_eq!(tone.apply(f32::NAN), 0.0);
    assert!(close(tone.apply(0.1) as f64, 0.2f64.powf(1.0 / 2.2), 1e-6));
    // Nonsensical fields set by hand still give values in [0, 1].
    for (exposure, gamma) in [(f32::NAN, 2.2), (1.0, -2.0), (1.0, 0.0), (1.0, f32::NAN)] {
        let tone = ToneMap { exposure, gamma };
        for value in [0.0, 0.3, 1.0, 5.0] {
            let display = tone.apply(value);
            assert!((0.0..=1.0).contains(&display), "{tone:?} maps {value} to {display}");
        }
    }
}

#[test]
fn one_pixel_images_work_everywhere() {
    let reference = Image::from_pixels(1, 1, vec![[0.3, 0.6, 0.1]]);
    let test = Image::from_pixels(1, 1, vec![[0.4, 0.5, 0.1]]);
    let tone = unit_exposure();
    let metrics = evaluate(&reference, &test, &tone).unwrap();
    let squared: Vec<f64> = reference.pixels[0]
        .iter()
        .zip(&test.pixels[0])
        .map(|(&r, &t)| (display_f64(t, 1.0) - display_f64(r, 1.0)).powi(2))
        .collect();
    let mse = squared.iter().sum::<f64>() / 3.0;
    assert!(close(metrics.psnr_db, -10.0 * mse.log10(), 1e-4), "psnr {}", metrics.psnr_db);
    let expected_rel_mse = (0.01 / 0.1 + 0.01 / 0.37 + 0.0) / 3.0;
    assert!(close(metrics.rel_mse, expected_rel_mse, 1e-6), "rel mse {}", metrics.rel_mse);
    // One pixel: no variance, SSIM is the luminance term per channel.
    let expected_ssim = reference.pixels[0]
        .iter()
        .zip(&test.pixels[0])
        .map(|(&r, &t)| {
            let (a, b) = (display_f64(r, 1.0), display_f64(t, 1.0));
            (2.0 * a * b + C1) / (a * a + b * b + C1)
        })
        .sum::<f64>()
        / 3.0;
    assert!(close(metrics.ssim, expected_ssim, 1e-6), "ssim {}", metrics.ssim);
    assert_eq!(metrics.nonfinite_pixels, 0);
    let map = error_map(&reference, &test, &tone).unwrap();
    assert_eq!(map.len(), 1);
    assert!(close(map[0] as f64, mse.sqrt(), 1e-6));
    assert_eq!(ToneMap::auto(&reference).exposure, 1.0 / luminance([0.3, 0.6, 0.1]));
}

#[test]
fn empty_images_compare_as_identical() {
    let empty = Image::new(0, 0);
    let metrics = evaluate(&empty, &empty, &unit_exposure()).unwrap();
    assert_eq!(metrics, Metrics { psnr_db: PSNR_CEILING_DB, rel_mse: 0.0, ssim: 1.0, nonfinite_pixels: 0 });
    assert!(error_map(&empty, &empty, &unit_exposure()).unwrap().is_empty());
}

#[test]
fn psnr_falls_as_noise_grows() {
    // One noise pattern scaled by growing amplitudes: the display curve is monotone, so
    // every channel's display error can only grow with the amplitude.
    let mut rng = TestRng::new(2024);
    let reference = random_image(32, 20, 0.5, &mut rng);
    let noise: Vec<[f32; 3]> =
        reference.pixels.iter().map(|_| [rng.gaussianish(), rng.gaussianish(), rng.gaussianish()]).collect();
    let tone = unit_exposure();
    let psnrs: Vec<f64> = [0.005, 0.02, 0.08, 0.3]
        .iter()
        .map(|&amplitude| {
            let mut test = reference.clone();
            for (pixel, n) in test.pixels.iter_mut().zip(&noise) {
                for (channel, n) in pixel.iter_mut().zip(n) {
                    *channel += amplitude * n;
                }
            }
            psnr_db(&reference, &test, &tone).unwrap()
        })
        .collect();
    assert!(psnrs.windows(2).all(|pair| pair[1] < pair[0]), "psnrs {psnrs:?}");
    assert!(psnrs.iter().all(|p| p.is_finite() && *p < PSNR_CEILING_DB));
}
