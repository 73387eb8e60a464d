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
mod tests {
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
        for (w, h, radius, sigma) in
            [(13, 9, 3, 1.5), (20, 11, 6, 3.0), (5, 4, 10, 2.0), (1, 1, 2, 1.0), (2, 2, 1, 0.7)]
        {
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
                assert!(cross_bilateral(&noisy, &guide, &params)
                    .unwrap_err()
                    .to_string()
                    .contains("positive and finite"));
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
}
