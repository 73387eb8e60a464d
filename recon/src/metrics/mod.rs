//! The error metrics of `lfr compare`: how far a reconstructed image (`test`) is from a
//! high-spp `reference` of the same size. Every function returns `Err(SizeMismatch)` when the
//! two sizes differ (`expected` is the reference's size, `found` the test's).
//!
//! # Display transform
//!
//! PSNR, SSIM and the error map compare *display values*, not linear radiance. A linear channel
//! value `v` becomes `d(v) = clamp(v * exposure, 0, 1)^(1 / gamma)` with `gamma` = 2.2
//! ([`ToneMap::GAMMA`]), computed in `f32` and not quantised to 8 bits. Every display value lies
//! in [0, 1].
//!
//! [`ToneMap::auto`] picks the exposure from the reference alone, so every method of a
//! comparison is measured under the same transform: `exposure = 1 / p99`, where `p99` is the
//! nearest-rank 99th percentile of the Rec. 709 luminance of the reference's pixels, taken over
//! the `n` pixels whose luminance is finite and positive: with those luminances sorted
//! ascending, `p99` is the one at 0-based index `ceil(0.99 n) - 1` (for 100 such pixels, the
//! 99th smallest). When no pixel has a finite positive luminance (an all-black reference), or
//! `1 / p99` overflows, the exposure is 1. [`ToneMap::with_exposure`] sets the exposure by hand
//! and rejects one that is not finite and positive.
//!
//! # PSNR
//!
//! `MSE` is the mean, over all pixels and the three channels, of the squared difference of the
//! display values of test and reference (summed in `f64`), and
//! `PSNR = 10 log10(1 / max(MSE, 1e-10))` dB. This is the PSNR of the temporal light field
//! paper (Lehtinen et al. 2011), which measured after gamma and clamping to [0, 255] but before
//! quantisation; on the [0, 1] scale used here the value is the same. Identical display values
//! (an all-black result for an all-black reference included) give exactly
//! [`PSNR_CEILING_DB`] = 100 dB; since `MSE <= 1`, the PSNR is never below 0 dB.
//!
//! # Relative MSE
//!
//! Computed on the linear (HDR) values, without the display transform: the mean, over all
//! pixels and the three channels, of `(t - r)^2 / (r^2 + 0.01)`, with `t` the test's and `r` the
//! reference's channel value, in `f64`. The epsilon [`REL_MSE_EPSILON`] = 0.01 is that of
//! Rousselle et al. 2011; it keeps the measure defined where the reference is black.
//!
//! # SSIM
//!
//! The SSIM of Wang et al. 2004, computed per channel on display values and averaged over the
//! three channels. For a window with weights `w` (summing to 1) over reference values `x` and
//! test values `y`: `mu_x = sum w x`, `sigma_x^2 = sum w x^2 - mu_x^2` (likewise for `y`),
//! `sigma_xy = sum w x y - mu_x mu_y`, and
//! `SSIM = (2 mu_x mu_y + C1) (2 sigma_xy + C2) / ((mu_x^2 + mu_y^2 + C1) (sigma_x^2 + sigma_y^2 + C2))`
//! with `C1 = (0.01 L)^2`, `C2 = (0.03 L)^2` and `L = 1`.
//!
//! * When both width and height are at least 11, the window is the 11x11 Gaussian with standard
//!   deviation 1.5 pixels (weights `exp(-(dx^2 + dy^2) / (2 * 1.5^2))` for `dx, dy` in -5..=5,
//!   normalised to sum 1), and a channel's SSIM is the mean of the SSIM map over the "valid"
//!   window positions, those where the window lies entirely inside the image
//!   (`(width - 10) * (height - 10)` of them).
//! * Otherwise (either dimension below 11, down to 1x1), a channel's SSIM is that of one global
//!   window with uniform weights over the whole image.
//!
//! The SSIM is 1 for identical display values and lies in [-1, 1].
//!
//! # Error map
//!
//! [`error_map`] gives, per pixel (row-major like [`Image::pixels`]), the root mean square over
//! the three channels of the difference of the display values, in [0, 1], for false-colour
//! maps.
//!
//! # Non-finite values
//!
//! A method's output may hold NaN or infinite channels; they never improve a score.
//!
//! * For PSNR, SSIM and the error map, a non-finite test channel takes the worst display value
//!   for that channel: 1 where the reference's display value is below 0.5, else 0.
//! * For the relative MSE, a non-finite test channel contributes exactly 1, more than a black
//!   (zero) result would contribute for that channel (`r^2 / (r^2 + 0.01) < 1`). Finite
//!   contributions are not capped and may exceed 1.
//! * [`Metrics::nonfinite_pixels`] counts the test's pixels with at least one non-finite
//!   channel.
//!
//! Huge finite test values are handled like any other: the display transform clamps them, and
//! the relative MSE stays finite because it is accumulated in `f64`.
//!
//! A non-finite reference channel is a caller error (the reference should be clean), but it does
//! not panic: it is treated as 0 in every metric and ignored by [`ToneMap::auto`].
//!
//! # Empty images
//!
//! Two 0-pixel images compare as identical: PSNR 100 dB, relative MSE 0, SSIM 1.
//!
//! The images must hold `width * height` pixels, as [`Image::from_pixels`] ensures; the
//! metrics panic on an image that breaks this invariant.
//!
//! HDR-FLIP, the perceptual metric computed by NVIDIA's Python package, is in `flip`.

pub mod flip;

use std::fmt;

use rayon::prelude::*;

use crate::image::{luminance, Image, SizeMismatch};

/// PSNR reported for identical display values: the MSE is floored at `1e-10`.
pub const PSNR_CEILING_DB: f64 = 100.0;

/// The epsilon in the relative MSE's denominator `r^2 + REL_MSE_EPSILON`.
pub const REL_MSE_EPSILON: f64 = 0.01;

/// The MSE floor that sets [`PSNR_CEILING_DB`].
const MSE_FLOOR: f64 = 1e-10;

/// Side of the SSIM's Gaussian window, in pixels.
const SSIM_WINDOW: usize = 11;

/// Standard deviation of the SSIM's Gaussian window, in pixels.
const SSIM_SIGMA: f64 = 1.5;

/// SSIM stabilising constants for the dynamic range `L = 1`.
const SSIM_C1: f64 = 0.01 * 0.01;
const SSIM_C2: f64 = 0.03 * 0.03;

/// Pixels per parallel task in the sums; fixed so that the summation order, and with it every
/// result, is the same from run to run.
const SUM_CHUNK_PIXELS: usize = 4096;

/// Display transform of the PSNR, SSIM and error map:
/// `v -> clamp(v * exposure, 0, 1)^(1 / gamma)`, no quantisation.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ToneMap {
    pub exposure: f32,
    pub gamma: f32,
}

/// An exposure that is not finite and positive.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InvalidExposure(pub f32);

impl fmt::Display for InvalidExposure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "exposure must be finite and positive, got {}", self.0)
    }
}

impl std::error::Error for InvalidExposure {}

impl ToneMap {
    pub const GAMMA: f32 = 2.2;

    /// The exposure that maps the reference's 99th-percentile luminance to 1 (see the module
    /// documentation for the exact percentile); exposure 1 when the reference has no pixel with
    /// a finite, positive luminance. Gamma [`ToneMap::GAMMA`].
    pub fn auto(reference: &Image) -> ToneMap {
        let mut luminances: Vec<f32> =
            reference.pixels.iter().map(|&rgb| luminance(rgb)).filter(|lum| lum.is_finite() && *lum > 0.0).collect();
        let exposure = match nearest_rank_99th_percentile(&mut luminances) {
            Some(p99) => {
                let exposure = 1.0 / p99;
                if exposure.is_finite() {
                    exposure
                } else {
                    1.0
                }
            }
            None => 1.0,
        };
        ToneMap { exposure, gamma: ToneMap::GAMMA }
    }

    /// A tone map with the given exposure and gamma [`ToneMap::GAMMA`]; errors unless the
    /// exposure is finite and positive.
    pub fn with_exposure(exposure: f32) -> Result<ToneMap, InvalidExposure> {
        if exposure.is_finite() && exposure > 0.0 {
            Ok(ToneMap { exposure, gamma: ToneMap::GAMMA })
        } else {
            Err(InvalidExposure(exposure))
        }
    }

    /// The display value of a linear value, in [0, 1]: +inf maps to 1, -inf and NaN to 0.
    /// Stays in [0, 1] even for nonsensical fields set by hand.
    pub fn apply(&self, value: f32) -> f32 {
        let clamped = clamp_unit(value * self.exposure);
        clamp_unit(clamped.powf(1.0 / self.gamma))
    }
}

/// Clamps to [0, 1], mapping NaN to 0.
fn clamp_unit(value: f32) -> f32 {
    if value.is_nan() {
        0.0
    } else {
        value.clamp(0.0, 1.0)
    }
}

/// The nearest-rank 99th percentile: the value at 0-based index `ceil(0.99 n) - 1` of the `n`
/// values sorted ascending. Reorders `values`; `None` when it is empty.
fn nearest_rank_99th_percentile(values: &mut [f32]) -> Option<f32> {
    if values.is_empty() {
        return None;
    }
    let index = (99 * values.len()).div_ceil(100) - 1;
    let (_, p99, _) = values.select_nth_unstable_by(index, f32::total_cmp);
    Some(*p99)
}

/// Every metric of one comparison.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Metrics {
    /// PSNR of the display values, in dB, at most [`PSNR_CEILING_DB`].
    pub psnr_db: f64,
    /// Relative MSE of the linear values.
    pub rel_mse: f64,
    /// SSIM of the display values, averaged over the channels.
    pub ssim: f64,
    /// Pixels of the test image with a NaN or infinite channel.
    pub nonfinite_pixels: usize,
}

/// Every metric of `test` against `reference`, the display values computed once.
pub fn evaluate(reference: &Image, test: &Image, tone: &ToneMap) -> Result<Metrics, SizeMismatch> {
    let display = DisplayPair::new(reference, test, tone)?;
    Ok(Metrics {
        psnr_db: display.psnr_db(),
        rel_mse: relative_mse(reference, test)?,
        ssim: display.ssim(),
        nonfinite_pixels: test.nonfinite_pixels(),
    })
}

/// PSNR of the display values, in dB (see the module documentation).
pub fn psnr_db(reference: &Image, test: &Image, tone: &ToneMap) -> Result<f64, SizeMismatch> {
    Ok(DisplayPair::new(reference, test, tone)?.psnr_db())
}

/// Relative MSE of the linear values (see the module documentation).
pub fn relative_mse(reference: &Image, test: &Image) -> Result<f64, SizeMismatch> {
    reference.check_same_size(test)?;
    assert_pixel_counts(reference, test);
    let values = reference.pixels.len() * 3;
    if values == 0 {
        return Ok(0.0);
    }
    let chunk_sums: Vec<f64> = reference
        .pixels
        .par_chunks(SUM_CHUNK_PIXELS)
        .zip(test.pixels.par_chunks(SUM_CHUNK_PIXELS))
        .map(|(reference_chunk, test_chunk)| {
            reference_chunk
                .iter()
                .zip(test_chunk)
                .flat_map(|(r, t)| r.iter().zip(t))
                .map(|(&r, &t)| relative_squared_error(r, t))
                .sum()
        })
        .collect();
    Ok(chunk_sums.iter().sum::<f64>() / values as f64)
}

/// One channel's contribution to the relative MSE.
fn relative_squared_error(reference: f32, test: f32) -> f64 {
    if !test.is_finite() {
        return 1.0;
    }
    let r = finite_or_zero(reference) as f64;
    let t = test as f64;
    (t - r) * (t - r) / (r * r + REL_MSE_EPSILON)
}

/// SSIM of the display values, averaged over the channels (see the module documentation).
pub fn ssim(reference: &Image, test: &Image, tone: &ToneMap) -> Result<f64, SizeMismatch> {
    Ok(DisplayPair::new(reference, test, tone)?.ssim())
}

/// Per-pixel error for false-colour maps, row-major: the root mean square over the three
/// channels of the difference of the display values, in [0, 1].
pub fn error_map(reference: &Image, test: &Image, tone: &ToneMap) -> Result<Vec<f32>, SizeMismatch> {
    let display = DisplayPair::new(reference, test, tone)?;
    Ok(display
        .reference
        .par_iter()
        .zip(&display.test)
        .map(|(r, t)| {
            let mean_square: f32 = r.iter().zip(t).map(|(r, t)| (t - r) * (t - r)).sum::<f32>() / 3.0;
            mean_square.sqrt().min(1.0)
        })
        .collect())
}

fn finite_or_zero(value: f32) -> f32 {
    if value.is_finite() {
        value
    } else {
        0.0
    }
}

/// Panics unless both images hold `width * height` pixels (the invariant of [`Image`]).
fn assert_pixel_counts(reference: &Image, test: &Image) {
    for image in [reference, test] {
        assert_eq!(image.pixels.len(), image.pixel_count(), "an image must hold width * height pixels");
    }
}

/// The display values of a reference and a test image of the same size, with the test's
/// non-finite channels replaced by the worst display value and the reference's by that of 0.
struct DisplayPair {
    width: usize,
    height: usize,
    reference: Vec<[f32; 3]>,
    test: Vec<[f32; 3]>,
}

impl DisplayPair {
    fn new(reference: &Image, test: &Image, tone: &ToneMap) -> Result<DisplayPair, SizeMismatch> {
        reference.check_same_size(test)?;
        assert_pixel_counts(reference, test);
        let (reference_display, test_display): (Vec<[f32; 3]>, Vec<[f32; 3]>) =
            reference.pixels.par_iter().zip(&test.pixels).map(|(r, t)| display_pixel_pair(r, t, tone)).unzip();
        Ok(DisplayPair {
            width: reference.width as usize,
            height: reference.height as usize,
            reference: reference_display,
            test: test_display,
        })
    }

    fn psnr_db(&self) -> f64 {
        let values = self.reference.len() * 3;
        if values == 0 {
            return PSNR_CEILING_DB;
        }
        let chunk_sums: Vec<f64> = self
            .reference
            .par_chunks(SUM_CHUNK_PIXELS)
            .zip(self.test.par_chunks(SUM_CHUNK_PIXELS))
            .map(|(reference_chunk, test_chunk)| {
                reference_chunk
                    .iter()
                    .zip(test_chunk)
                    .flat_map(|(r, t)| r.iter().zip(t))
                    .map(|(&r, &t)| {
                        let difference = t as f64 - r as f64;
                        difference * difference
                    })
                    .sum()
            })
            .collect();
        let mse = chunk_sums.iter().sum::<f64>() / values as f64;
        10.0 * (1.0 / mse.max(MSE_FLOOR)).log10()
    }

    fn ssim(&self) -> f64 {
        if self.reference.is_empty() {
            return 1.0;
        }
        let channel_ssim = |channel| {
            if self.width >= SSIM_WINDOW && self.height >= SSIM_WINDOW {
                self.gaussian_window_ssim(channel)
            } else {
                self.global_window_ssim(channel)
            }
        };
        (0..3).map(channel_ssim).sum::<f64>() / 3.0
    }

    /// Mean SSIM map of one channel over the valid positions of the 11x11 Gaussian window,
    /// filtered separably: each row horizontally, then the horizontal sums vertically.
    fn gaussian_window_ssim(&self, channel: usize) -> f64 {
        let kernel = gaussian_kernel();
        let out_width = self.width - (SSIM_WINDOW - 1);
        let out_height = self.height - (SSIM_WINDOW - 1);

        // Horizontal pass: every row, valid columns only.
        let mut horizontal = vec![Moments::default(); out_width * self.height];
        horizontal.par_chunks_mut(out_width).enumerate().for_each(|(y, out_row)| {
            let row = y * self.width..(y + 1) * self.width;
            let products: Vec<Moments> = self.reference[row.clone()]
                .iter()
                .zip(&self.test[row])
                .map(|(r, t)| Moments::of_pair(r[channel] as f64, t[channel] as f64))
                .collect();
            for (x, out) in out_row.iter_mut().enumerate() {
                let mut sum = Moments::default();
                for (weight, moments) in kernel.iter().zip(&products[x..x + SSIM_WINDOW]) {
                    sum.add_weighted(*weight, moments);
                }
                *out = sum;
            }
        });

        // Vertical pass: one output row per task, its SSIM values summed.
        let row_sums: Vec<f64> = (0..out_height)
            .into_par_iter()
            .map(|y| {
                let mut sums = vec![Moments::default(); out_width];
                for (offset, weight) in kernel.iter().enumerate() {
                    let start = (y + offset) * out_width;
                    for (sum, moments) in sums.iter_mut().zip(&horizontal[start..start + out_width]) {
                        sum.add_weighted(*weight, moments);
                    }
                }
                sums.iter().map(Moments::ssim).sum::<f64>()
            })
            .collect();
        row_sums.iter().sum::<f64>() / (out_width * out_height) as f64
    }

    /// SSIM of one channel over a single window with uniform weights over the whole image.
    fn global_window_ssim(&self, channel: usize) -> f64 {
        let count = self.reference.len() as f64;
        let values = || self.reference.iter().zip(&self.test).map(|(r, t)| (r[channel] as f64, t[channel] as f64));
        let (sum_x, sum_y) = values().fold((0.0, 0.0), |(sx, sy), (x, y)| (sx + x, sy + y));
        let (mean_x, mean_y) = (sum_x / count, sum_y / count);
        let (sum_xx, sum_yy, sum_xy) = values().fold((0.0, 0.0, 0.0), |(sxx, syy, sxy), (x, y)| {
            let (dx, dy) = (x - mean_x, y - mean_y);
            (sxx + dx * dx, syy + dy * dy, sxy + dx * dy)
        });
        ssim_from_statistics(mean_x, mean_y, sum_xx / count, sum_yy / count, sum_xy / count)
    }
}

/// The display values of one reference pixel and the matching test pixel.
fn display_pixel_pair(reference: &[f32; 3], test: &[f32; 3], tone: &ToneMap) -> ([f32; 3], [f32; 3]) {
    let reference_display = reference.map(|r| tone.apply(finite_or_zero(r)));
    let mut test_display = [0.0; 3];
    for ((out, &t), &r) in test_display.iter_mut().zip(test).zip(&reference_display) {
        *out = if t.is_finite() {
            tone.apply(t)
        } else if r < 0.5 {
            1.0
        } else {
            0.0
        };
    }
    (reference_display, test_display)
}

/// The normalised 1-D Gaussian whose outer product with itself is the SSIM window.
fn gaussian_kernel() -> [f64; SSIM_WINDOW] {
    let centre = (SSIM_WINDOW / 2) as f64;
    let mut kernel = [0.0; SSIM_WINDOW];
    for (i, weight) in kernel.iter_mut().enumerate() {
        let offset = i as f64 - centre;
        *weight = (-offset * offset / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp();
    }
    let total: f64 = kernel.iter().sum();
    kernel.map(|weight| weight / total)
}

/// Weighted sums of `x`, `y`, `x^2`, `y^2` and `x y` over a window (`x` reference, `y` test).
#[derive(Clone, Copy, Debug, Default)]
struct Moments {
    x: f64,
    y: f64,
    xx: f64,
    yy: f64,
    xy: f64,
}

impl Moments {
    fn of_pair(x: f64, y: f64) -> Moments {
        Moments { x, y, xx: x * x, yy: y * y, xy: x * y }
    }

    fn add_weighted(&mut self, weight: f64, other: &Moments) {
        self.x += weight * other.x;
        self.y += weight * other.y;
        self.xx += weight * other.xx;
        self.yy += weight * other.yy;
        self.xy += weight * other.xy;
    }

    /// SSIM of a window whose weights sum to 1.
    fn ssim(&self) -> f64 {
        ssim_from_statistics(
            self.x,
            self.y,
            self.xx - self.x * self.x,
            self.yy - self.y * self.y,
            self.xy - self.x * self.y,
        )
    }
}

fn ssim_from_statistics(mean_x: f64, mean_y: f64, variance_x: f64, variance_y: f64, covariance: f64) -> f64 {
    let luminance_term = (2.0 * mean_x * mean_y + SSIM_C1) / (mean_x * mean_x + mean_y * mean_y + SSIM_C1);
    let structure_term = (2.0 * covariance + SSIM_C2) / (variance_x + variance_y + SSIM_C2);
    luminance_term * structure_term
}

#[cfg(test)]
mod tests;
