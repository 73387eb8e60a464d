//! `cross_bilateral`: the joint (cross) bilateral filter of a noisy RGB image guided by the
//! per-pixel normal and depth buffers — the baseline the guided-image-filtering paper (Bauszat,
//! Eisemann, Magnor, GI 2011, Section 4 and Table 2) compares against as "what would be
//! achievable with a perfect geometry-aware filtering" [Petschnigg et al. 2004, Eisemann and
//! Durand 2004], run there with window radii 16, 24 and 32 pixels.
//!
//! For a pixel `p` the output is `Σ_q w(p,q) N_q / Σ_q w(p,q)` over the square window
//! `|q.x − p.x| ≤ r, |q.y − p.y| ≤ r` clipped to the image, with
//!
//! ```text
//! w(p,q) = exp(−‖p − q‖² / (2σ_s²))                  spatial, in pixels
//!        · exp(−‖n_p − n_q‖² / (2σ_n²))              normal
//!        · exp(−((z_p − z_q) / (σ_z · z_p))² / 2)     depth, relative to the centre's depth
//! ```
//!
//! All three are Gaussians in the usual bilateral form. For unit normals
//! `‖n_p − n_q‖² = 2(1 − n_p·n_q)`, so the normal term is a Gaussian in the angle for small
//! angles. The depth difference is divided by the centre's depth so that one `σ_z` fits any
//! scene scale and any distance from the camera (a pixel's footprint grows linearly with depth,
//! and so do the depth differences between neighbours on one surface).
//!
//! Defaults (`BilateralParams::with_radius`, `Default` is radius 24):
//! - `radius` 24: the middle of the paper's Table 2 (16/24/32), and the lower end of the radii
//!   (24–32) the paper uses for its own guided filter, so the comparison is at equal support.
//! - `sigma_spatial = radius / 2` (at least 0.5): the window ends at 2σ_s, where the spatial
//!   weight has fallen to e⁻² ≈ 0.14 — wide enough that the window is used, small enough that
//!   truncating there does not leave a visible box edge.
//! - `sigma_normal = 0.1`: the paper's guided filter uses ε = 0.01 for the normals, a variance;
//!   its square root 0.1 is the same scale as a standard deviation. Normals 5° apart keep weight
//!   0.68, 10° apart 0.22, 20° apart 0.002, so creases and silhouettes stop the filter while a
//!   finely tessellated curved surface is still smoothed locally.
//! - `sigma_depth = 0.05` (relative): a depth step of 5% of the centre's depth keeps weight
//!   0.61, 15% keeps 0.011. Depth on one surface changes by far less than that between
//!   neighbouring pixels except at grazing angles, where the normal term does the work anyway.
//!
//! Escaped pixels (guide ray missed the scene: zero normal or depth ≤ 0) have no geometry; they
//! mix only with other escaped pixels, with the spatial weight alone, and surface pixels never
//! read them. Non-finite colour values are replaced by 0 before filtering; guide pixels with a
//! non-finite normal or depth are treated as escaped; every such value is counted in
//! `FilterReport::sanitised_values` and nothing non-finite reaches the output: sums are kept
//! in f32 per window row and in f64 across rows, and an image with values beyond 2¹⁰⁰ is
//! scaled by a power of two (exact) before filtering and back after (`range_scale`), so even
//! values near `f32::MAX` average without overflow.
//!
//! Implementation: rows run in parallel; within a row, tiles of `TILE` pixels accumulate one
//! window offset at a time over contiguous structure-of-arrays slices, and the exponential is
//! a branch-free polynomial (`exp_neg`, relative error < 10⁻⁶), so the inner loop
//! vectorises. Each range exponent is evaluated as `((a − b)/σ)²` (`normalised_sq`), which
//! neither overflows nor underflows for differences of any sensible magnitude. Weights below
//! e⁻⁸⁰ are set to 0 (`MAX_EXPONENT`).

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::Error;
use crate::guide::GuideBuffers;
use crate::image::Image;

/// Parameters of `cross_bilateral`; see the module documentation for the weight formulas.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BilateralParams {
    /// Half-width of the square window in pixels; 0 returns the (sanitised) input.
    pub radius: u32,
    /// Standard deviation of the spatial Gaussian, in pixels.
    pub sigma_spatial: f32,
    /// Standard deviation of the Gaussian on the normal difference `‖n_p − n_q‖`.
    pub sigma_normal: f32,
    /// Standard deviation of the Gaussian on the relative depth difference `(z_p − z_q) / z_p`.
    pub sigma_depth: f32,
}

impl BilateralParams {
    pub const DEFAULT_RADIUS: u32 = 24;
    pub const DEFAULT_SIGMA_NORMAL: f32 = 0.1;
    pub const DEFAULT_SIGMA_DEPTH: f32 = 0.05;

    /// The defaults for a window radius: `sigma_spatial = max(radius / 2, 0.5)`.
    pub fn with_radius(radius: u32) -> BilateralParams {
        BilateralParams {
            radius,
            sigma_spatial: (radius as f32 / 2.0).max(0.5),
            sigma_normal: Self::DEFAULT_SIGMA_NORMAL,
            sigma_depth: Self::DEFAULT_SIGMA_DEPTH,
        }
    }

    /// Errors unless every σ is positive and finite.
    pub fn validate(&self) -> Result<(), Error> {
        check_sigma("sigma_spatial", self.sigma_spatial)?;
        check_sigma("sigma_normal", self.sigma_normal)?;
        check_sigma("sigma_depth", self.sigma_depth)
    }
}

impl Default for BilateralParams {
    fn default() -> BilateralParams {
        BilateralParams::with_radius(Self::DEFAULT_RADIUS)
    }
}

/// What a filter reports besides its image.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct FilterReport {
    /// Non-finite input values (colour channels, and guide components the filter reads) that
    /// were replaced by 0 or made their guide pixel count as escaped.
    pub sanitised_values: usize,
}

/// Per-pixel inputs of `cross_bilateral`, one plane per component.
struct Planes {
    red: Vec<f32>,
    green: Vec<f32>,
    blue: Vec<f32>,
    nx: Vec<f32>,
    ny: Vec<f32>,
    nz: Vec<f32>,
    depth: Vec<f32>,
    /// 1 for a surface, 0 for an escaped pixel.
    surface: Vec<f32>,
    /// `1 / (√2 σ_z z_p)`, 0 for escaped pixels.
    inv_depth: Vec<f32>,
}

/// The cross-bilateral filter of `noisy` guided by `guide`'s normal and depth buffers.
pub fn cross_bilateral(
    noisy: &Image,
    guide: &GuideBuffers,
    params: &BilateralParams,
) -> Result<(Image, FilterReport), Error> {
    check_inputs(noisy, guide)?;
    params.validate()?;
    let (width, height) = (noisy.width as usize, noisy.height as usize);
    let (colour, mut sanitised) = sanitised_colours(noisy);
    if colour.is_empty() || params.radius == 0 {
        return Ok((
            Image::from_pixels(noisy.width, noisy.height, colour),
            FilterReport { sanitised_values: sanitised },
        ));
    }

    let n = width * height;
    let scale = range_scale(&colour);
    let mut planes = Planes {
        red: colour.iter().map(|c| c[0] * scale).collect(),
        green: colour.iter().map(|c| c[1] * scale).collect(),
        blue: colour.iter().map(|c| c[2] * scale).collect(),
        nx: vec![0.0; n],
        ny: vec![0.0; n],
        nz: vec![0.0; n],
        depth: vec![0.0; n],
        surface: vec![0.0; n],
        inv_depth: vec![0.0; n],
    };
    for (i, (normal, &z)) in guide.normal.iter().zip(&guide.depth).enumerate() {
        let bad = normal.iter().filter(|v| !v.is_finite()).count() + usize::from(!z.is_finite());
        sanitised += bad;
        if bad == 0 && is_surface(*normal, z) {
            [planes.nx[i], planes.ny[i], planes.nz[i]] = *normal;
            planes.depth[i] = z;
            planes.surface[i] = 1.0;
            // Clamped, so that a zero difference never meets an infinite factor.
            planes.inv_depth[i] = inverse_root_two_sigma(params.sigma_depth as f64 * z as f64);
        }
    }

    // Spatial exponents d²/(2σ_s²) for d = 0..=r, r clipped to the largest useful offset.
    let radius = (params.radius as usize).min(width.max(height) - 1);
    let sigma_spatial = params.sigma_spatial as f64;
    let spatial: Vec<f32> =
        (0..=radius).map(|d| ((d * d) as f64 / (2.0 * sigma_spatial * sigma_spatial)) as f32).collect();
    let inv_normal = inverse_root_two_sigma(params.sigma_normal as f64);

    let mut out = vec![[0.0f32; 3]; n];
    out.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
        let mut acc = Accumulator::new();
        let (y0, y1) = (y.saturating_sub(radius), (y + radius).min(height - 1));
        for tile_start in (0..width).step_by(TILE) {
            let tile_end = (tile_start + TILE).min(width);
            acc.clear();
            for yy in y0..=y1 {
                let ey = spatial[yy.abs_diff(y)];
                for dx in -(radius as isize)..=radius as isize {
                    let e0 = ey + spatial[dx.unsigned_abs()];
                    // Only offsets that land inside the image, and only if any weight survives.
                    let lo = tile_start.max((-dx).max(0) as usize);
                    let hi = tile_end.min((width as isize - dx).max(0) as usize);
                    if e0 > MAX_EXPONENT || lo >= hi {
                        continue;
                    }
                    let p = y * width + lo;
                    let q = (yy * width + lo).wrapping_add_signed(dx);
                    accumulate_offset(&planes, p, q, hi - lo, e0, inv_normal, &mut acc, lo - tile_start);
                }
                acc.flush();
            }
            acc.write(&mut row[tile_start..tile_end], 1.0 / scale as f64);
        }
    });
    Ok((Image::from_pixels(noisy.width, noisy.height, out), FilterReport { sanitised_values: sanitised }))
}

/// Adds the taps at one window offset for `len` consecutive centres starting at pixel `p`,
/// whose taps start at pixel `q`, into `acc` from `offset` on.
#[allow(clippy::too_many_arguments)]
#[inline]
fn accumulate_offset(
    planes: &Planes,
    p: usize,
    q: usize,
    len: usize,
    e0: f32,
    inv_normal: f32,
    acc: &mut Accumulator,
    offset: usize,
) {
    let (pnx, pny, pnz) = (&planes.nx[p..p + len], &planes.ny[p..p + len], &planes.nz[p..p + len]);
    let (pz, ps, pinv) = (&planes.depth[p..p + len], &planes.surface[p..p + len], &planes.inv_depth[p..p + len]);
    let (qnx, qny, qnz) = (&planes.nx[q..q + len], &planes.ny[q..q + len], &planes.nz[q..q + len]);
    let (qz, qs) = (&planes.depth[q..q + len], &planes.surface[q..q + len]);
    let (qr, qg, qb) = (&planes.red[q..q + len], &planes.green[q..q + len], &planes.blue[q..q + len]);
    let (ar, ag) = (&mut acc.red[offset..offset + len], &mut acc.green[offset..offset + len]);
    let (ab, aw) = (&mut acc.blue[offset..offset + len], &mut acc.weight[offset..offset + len]);
    for i in 0..len {
        let (dnx, dny, dnz, dz) = (pnx[i] - qnx[i], pny[i] - qny[i], pnz[i] - qnz[i], pz[i] - qz[i]);
        // Escaped pixels have zero normal and depth, so between two of them only the spatial
        // term is left; a surface and an escaped pixel are masked out.
        let exponent = e0
            + normalised_sq(dnx, inv_normal)
            + normalised_sq(dny, inv_normal)
            + normalised_sq(dnz, inv_normal)
            + normalised_sq(dz, pinv[i]);
        // `<=` is false for NaN, and `min` ignores NaN, so no NaN reaches a sum.
        let keep = (ps[i] == qs[i]) & (exponent <= MAX_EXPONENT);
        let w = if keep { exp_neg(-exponent.min(MAX_EXPONENT)) } else { 0.0 };
        ar[i] += w * qr[i];
        ag[i] += w * qg[i];
        ab[i] += w * qb[i];
        aw[i] += w;
    }
}

/// Pixels per row tile: the tile's planes and accumulators stay in the L1 cache.
pub(crate) const TILE: usize = 128;

/// Weighted sums for one row tile: `red`, `green`, `blue`, `weight` collect a few taps in
/// f32 (fast, and vectorised 4 or 8 wide), `flush` moves them into f64 totals.
pub(crate) struct Accumulator {
    pub red: [f32; TILE],
    pub green: [f32; TILE],
    pub blue: [f32; TILE],
    pub weight: [f32; TILE],
    totals: [[f64; TILE]; 4],
}

impl Accumulator {
    pub fn new() -> Accumulator {
        Accumulator {
            red: [0.0; TILE],
            green: [0.0; TILE],
            blue: [0.0; TILE],
            weight: [0.0; TILE],
            totals: [[0.0; TILE]; 4],
        }
    }

    pub fn clear(&mut self) {
        *self = Accumulator::new();
    }

    /// Adds the f32 partial sums to the f64 totals and zeroes them.
    pub fn flush(&mut self) {
        for (total, partial) in
            self.totals.iter_mut().zip([&mut self.red, &mut self.green, &mut self.blue, &mut self.weight])
        {
            for (t, p) in total.iter_mut().zip(partial.iter_mut()) {
                *t += *p as f64;
                *p = 0.0;
            }
        }
    }

    /// The normalised totals times `unscale` into `out` (at most `TILE` pixels); flushes
    /// first. Every centre's own tap has a positive weight, so no weight sum is zero.
    pub fn write(&mut self, out: &mut [[f32; 3]], unscale: f64) {
        self.flush();
        for (i, result) in out.iter_mut().enumerate() {
            *result = self.normalised(i).map(|c| finite(c * unscale));
        }
    }

    /// As `write` without scaling, into one plane per channel.
    pub fn write_planes(&mut self, red: &mut [f32], green: &mut [f32], blue: &mut [f32]) {
        self.flush();
        for (i, ((r, g), b)) in red.iter_mut().zip(green.iter_mut()).zip(blue.iter_mut()).enumerate() {
            [*r, *g, *b] = self.normalised(i).map(|c| c as f32);
        }
    }

    #[inline]
    fn normalised(&self, i: usize) -> [f64; 3] {
        let w = self.totals[3][i];
        [self.totals[0][i] / w, self.totals[1][i] / w, self.totals[2][i] / w]
    }
}

/// `value` as f32, clamped to the finite range: a weighted mean of finite values is within
/// their range, but rounding can carry a mean of values at `±f32::MAX` just beyond it.
#[inline]
pub(crate) fn finite(value: f64) -> f32 {
    value.clamp(-f32::MAX as f64, f32::MAX as f64) as f32
}

/// Colours are kept at most this large in magnitude while filtering (`range_scale`), so that
/// f32 partial sums over one window row (fewer than 2²⁷ taps, each of weight ≤ 1) cannot
/// overflow.
pub(crate) const MAX_FILTERED_MAGNITUDE: f32 = 1.267_650_6e30; // 2^100

/// The power of two by which to multiply the colours so that none exceeds
/// `MAX_FILTERED_MAGNITUDE` in magnitude: 1 for any ordinary image. Multiplying by a power
/// of two, and by its inverse afterwards, is exact (but for values pushed below f32's normal
/// range next to values beyond 2¹⁰⁰, which do not matter then).
pub(crate) fn range_scale(colour: &[[f32; 3]]) -> f32 {
    let max = colour.iter().flatten().fold(0.0f32, |m, c| m.max(c.abs()));
    if max <= MAX_FILTERED_MAGNITUDE {
        return 1.0;
    }
    let exponent = (max as f64 / MAX_FILTERED_MAGNITUDE as f64).log2().ceil() as i32;
    2f64.powi(-exponent) as f32
}

/// Weights below e^−MAX_EXPONENT ≈ 1.8·10⁻³⁵ are set to 0: their contribution is far below
/// f32 resolution next to the centre's weight, and it keeps the arithmetic out of subnormal
/// numbers and the exponential's argument in `exp_neg`'s range.
pub(crate) const MAX_EXPONENT: f32 = 80.0;

/// `e^x` for `x ∈ [−MAX_EXPONENT, 0]` (callers clamp), relative error below 10⁻⁶:
/// `e^x = 2^n · e^r` with `n = round(x / ln 2)`, `r = x − n ln 2` (Cody–Waite split,
/// `|r| ≤ ln 2 / 2`) and `e^r` by its degree-7 Taylor polynomial. Branch-free and inlined so
/// that the filters' inner loops vectorise, unlike a call to the C library's `expf`.
#[inline(always)]
pub(crate) fn exp_neg(x: f32) -> f32 {
    // 1.5 · 2²³: adding it rounds to an integer, held in the low mantissa bits.
    const ROUND: f32 = 12_582_912.0;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    let shifted = x * std::f32::consts::LOG2_E + ROUND;
    let n = shifted - ROUND;
    let n_bits = shifted.to_bits().wrapping_sub(ROUND.to_bits()) as i32;
    let r = (x - n * LN2_HI) - n * LN2_LO;
    let poly = 1.0
        + r * (1.0
            + r * (1.0 / 2.0
                + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0 + r * (1.0 / 5040.0)))))));
    poly * f32::from_bits(((n_bits + 127) as u32) << 23)
}

/// Errors unless `value` is a positive finite σ.
pub(crate) fn check_sigma(name: &'static str, value: f32) -> Result<(), Error> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(Error::parameter(name, format!("{name} must be positive and finite, got {value}")))
    }
}

/// Errors unless `noisy` and `guide` are self-consistent and of one size.
pub(crate) fn check_inputs(noisy: &Image, guide: &GuideBuffers) -> Result<(), Error> {
    if noisy.pixels.len() != noisy.pixel_count() {
        let message =
            format!("noisy image is {}x{} but holds {} pixels", noisy.width, noisy.height, noisy.pixels.len());
        return Err(Error::size_mismatch("noisy image", message));
    }
    if !guide.is_consistent() {
        let message =
            format!("guide buffers are inconsistent: each must hold {}x{} entries", guide.width, guide.height);
        return Err(Error::size_mismatch("guide buffers", message));
    }
    if (noisy.width, noisy.height) != (guide.width, guide.height) {
        let message = format!(
            "noisy image is {}x{} but the guide buffers are {}x{}",
            noisy.width, noisy.height, guide.width, guide.height
        );
        return Err(Error::size_mismatch("noisy image and guide buffers", message));
    }
    Ok(())
}

/// The image's pixels with non-finite channels replaced by 0, and how many were replaced.
pub(crate) fn sanitised_colours(noisy: &Image) -> (Vec<[f32; 3]>, usize) {
    let mut count = 0;
    let pixels = noisy
        .pixels
        .iter()
        .map(|p| {
            p.map(|c| {
                if c.is_finite() {
                    c
                } else {
                    count += 1;
                    0.0
                }
            })
        })
        .collect();
    (pixels, count)
}

/// Whether a (finite) guide pixel saw a surface: non-zero normal and positive depth.
#[inline]
pub(crate) fn is_surface(normal: [f32; 3], depth: f32) -> bool {
    depth > 0.0 && normal != [0.0; 3]
}

/// `1 / (√2 σ)` computed in f64 and clamped to `f32::MAX`, for `normalised_sq`: the Gaussian
/// exponent `d² / (2σ²)` is `normalised_sq(d, inverse_root_two_sigma(σ))`.
#[inline]
pub(crate) fn inverse_root_two_sigma(sigma: f64) -> f32 {
    (std::f64::consts::FRAC_1_SQRT_2 / sigma).min(f32::MAX as f64) as f32
}

/// `(d · inverse_sigma)²`. Dividing by σ before squaring keeps a range term meaningful for
/// differences of any finite magnitude (`d²` alone overflows f32 beyond 1.8·10¹⁹), a zero
/// difference gives 0 even for the largest factor, and anything that does overflow gives +∞,
/// weight 0. (Only an infinite difference times a zero factor gives NaN; `keep` masks that.)
#[inline(always)]
pub(crate) fn normalised_sq(d: f32, inverse_sigma: f32) -> f32 {
    let t = d * inverse_sigma;
    t * t
}

#[cfg(test)]
mod tests;
