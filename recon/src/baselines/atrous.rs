//! `atrous`: the edge-avoiding À-Trous wavelet filter of Dammertz, Sewtz, Hanika and Lensch
//! ("Edge-Avoiding À-Trous Wavelet Transform for fast Global Illumination Filtering", HPG
//! 2010) — the fast approximation of the cross-bilateral filter that the guided-image-filtering
//! paper (GI 2011, Section 4, Table 2) compares against with 4, 5 and 6 iterations, and the
//! baseline of the indirect light field paper (SIGGRAPH 2012, Section 3.1, "Comparison methods"),
//! which drops the colour term for its very noisy input and, for glossy scenes, adds a range
//! term on the normal at the secondary hit ("A-Trous + secondary normal", Figure 9).
//!
//! Iteration `i = 0..k` convolves the current image `c_i` with the 5×5 B3-spline kernel
//! `h = [1/16, 1/4, 3/8, 1/4, 1/16] ⊗ [1/16, 1/4, 3/8, 1/4, 1/16]` dilated by `2^i` (taps
//! `q = p + 2^i·(a, b)`, `a, b ∈ −2..=2`), weighted by edge-stopping functions:
//!
//! ```text
//! c_{i+1}(p) = Σ_q h(a,b) w_i(p,q) c_i(q) / Σ_q h(a,b) w_i(p,q)
//! w_i(p,q)   = w_rt · w_n · w_x [· w_sn]
//! w_rt = exp(−‖c_i(p) − c_i(q)‖² / σ_rt,i²),  σ_rt,i = 2^−i σ_rt   colour (optional)
//! w_n  = exp(−‖n_p − n_q‖² / σ_n²)                                  primary normal
//! w_x  = exp(−‖x_p − x_q‖² / σ_x²)                                  world position
//! w_sn = exp(−‖s_p − s_q‖² / σ_sn²)                                 secondary-hit normal (optional)
//! ```
//!
//! These are the forms of Dammertz et al. (their Eq. for `w_rt`, `w_n`, `w_x`, no factor 2 in
//! the denominators, σ_rt halved every iteration so that coarse levels smooth only small
//! remaining colour differences). Their GLSL listing additionally divides the normal distance
//! by the squared step width; we follow the paper's equation, not the listing. `w_sn` takes the
//! same form as `w_n`. Taps outside the image are skipped and the weights renormalised.
//!
//! Defaults (`AtrousParams::default`):
//! - `iterations` 5: the middle of the GI 2011 comparison (4/5/6); the footprint is then
//!   `4·(2^k − 1) + 1` = 125 pixels wide. 1..=8 are allowed.
//! - `sigma_color` None: the indirect light field paper dropped the colour term for its very
//!   noisy input ("using it gave worse results": on noise the colour distance stops the filter
//!   at the noise itself and keeps fireflies); `Some(σ_rt)` enables it, as in Dammertz et al.
//! - `sigma_normal` 0.2: normals 10° apart keep 0.47 per level, 20° apart 0.05, 90° e⁻⁵⁰.
//!   Looser than the cross-bilateral filter's 0.1 because the term applies once per level.
//! - `sigma_position` None: `σ_x = 2^k · d̃`, with `d̃` the median world distance between
//!   horizontally or vertically adjacent surface pixels (the typical pixel footprint). The
//!   widest level's taps lie up to `2^k` pixels apart, so on a fronto-parallel surface `w_x` is
//!   e⁻¹ at the farthest tap of the last level and near 1 on earlier levels: position alone
//!   never stops the filter from spreading over one surface, while a depth gap of 3σ_x
//!   (≈ 10% of the depth at k = 5 with ~1 mrad pixels) weighs e⁻⁹ at every level.
//!   If no two adjacent surface pixels lie apart, the term is off. `default_sigma_position`
//!   returns the value.
//! - `use_secondary_normal` false, `sigma_secondary_normal` 0.5: secondary normals are
//!   per-pixel means over a few samples and so are themselves noisy; 0.5 tolerates that
//!   noise while regions whose secondary hits face 90° apart still get e⁻⁸ per level.
//!
//! Escaped pixels (zero normal or depth ≤ 0) mix only with escaped pixels, by `h · w_rt`
//! alone; surfaces never read them. Non-finite colour values are replaced by 0 (and the
//! secondary normals' by 0) before filtering; guide pixels with a non-finite normal, depth or
//! position count as escaped; all are counted in `FilterReport::sanitised_values`. The 25 taps
//! are summed in f32 and normalised in f64, after the same power-of-two range scaling as in
//! `bilateral` (colours beyond 2¹⁰⁰ only), so nothing non-finite reaches the output.
//!
//! Implementation: as `bilateral` — rows in parallel, row tiles accumulating one kernel tap at
//! a time over contiguous structure-of-arrays slices with the branch-free `exp_neg`, so the
//! inner loop vectorises; exponents as `Σ((a − b)/σ)²`, so colours and world positions of any
//! scale keep their terms; weights below e⁻⁸⁰ are set to 0.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::baselines::bilateral::{
    check_inputs, check_sigma, exp_neg, finite, is_surface, normalised_sq, range_scale, sanitised_colours, Accumulator,
    FilterReport, MAX_EXPONENT, TILE,
};
use crate::error::Error;
use crate::guide::GuideBuffers;
use crate::image::Image;

/// The 1D B3-spline kernel; the 2D kernel is its outer product.
pub const B3: [f32; 5] = [1.0 / 16.0, 1.0 / 4.0, 3.0 / 8.0, 1.0 / 4.0, 1.0 / 16.0];

/// The largest allowed number of iterations (last step 128, footprint 1021 pixels).
pub const MAX_ITERATIONS: u32 = 8;

/// Parameters of `atrous`; see the module documentation for the weight formulas.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AtrousParams {
    /// Number of levels `k`, 1..=8; level `i` uses step `2^i`.
    pub iterations: u32,
    /// σ_rt of the colour term at level 0 (halved every level); None disables the term.
    pub sigma_color: Option<f32>,
    /// σ_n of the primary-normal term.
    pub sigma_normal: f32,
    /// σ_x of the world-position term in scene units; None derives it from the guide
    /// (`default_sigma_position`).
    pub sigma_position: Option<f32>,
    /// Add the range term on `guide.secondary_normal` (which must then be present).
    pub use_secondary_normal: bool,
    /// σ_sn of the secondary-normal term.
    pub sigma_secondary_normal: f32,
}

impl Default for AtrousParams {
    fn default() -> AtrousParams {
        AtrousParams {
            iterations: 5,
            sigma_color: None,
            sigma_normal: 0.2,
            sigma_position: None,
            use_secondary_normal: false,
            sigma_secondary_normal: 0.5,
        }
    }
}

impl AtrousParams {
    /// Errors unless the iteration count is in 1..=8 and every σ is positive and finite.
    pub fn validate(&self) -> Result<(), Error> {
        if !(1..=MAX_ITERATIONS).contains(&self.iterations) {
            let message = format!("iterations must be in 1..={MAX_ITERATIONS}, got {}", self.iterations);
            return Err(Error::parameter("iterations", message));
        }
        if let Some(sigma) = self.sigma_color {
            check_sigma("sigma_color", sigma)?;
        }
        check_sigma("sigma_normal", self.sigma_normal)?;
        if let Some(sigma) = self.sigma_position {
            check_sigma("sigma_position", sigma)?;
        }
        check_sigma("sigma_secondary_normal", self.sigma_secondary_normal)
    }
}

/// Per-pixel geometry, one plane per component; normal, position and secondary normal are
/// zero for escaped pixels, so that between two escaped pixels those terms vanish.
struct Planes {
    normal: [Vec<f32>; 3],
    position: [Vec<f32>; 3],
    secondary: Option<[Vec<f32>; 3]>,
    /// 1 for a surface, 0 for an escaped pixel.
    surface: Vec<f32>,
}

/// The factors `1/σ` of one level's terms (0: term off).
#[derive(Clone, Copy)]
struct Factors {
    colour: f32,
    normal: f32,
    position: f32,
    secondary: f32,
}

/// The edge-avoiding À-Trous filter of `noisy` guided by `guide`.
pub fn atrous(noisy: &Image, guide: &GuideBuffers, params: &AtrousParams) -> Result<(Image, FilterReport), Error> {
    check_inputs(noisy, guide)?;
    params.validate()?;
    if params.use_secondary_normal && guide.secondary_normal.is_none() {
        return Err(Error::missing_input(
            "guide secondary_normal",
            "use_secondary_normal needs the guide's secondary_normal buffer, which is absent",
        ));
    }
    let (width, height) = (noisy.width as usize, noisy.height as usize);
    let (colour, mut sanitised) = sanitised_colours(noisy);
    if colour.is_empty() {
        return Ok((
            Image::from_pixels(noisy.width, noisy.height, colour),
            FilterReport { sanitised_values: sanitised },
        ));
    }
    let (planes, bad) = planes(guide, params.use_secondary_normal);
    sanitised += bad;
    let sigma_position = match params.sigma_position {
        Some(sigma) => Some(sigma as f64),
        None => sigma_position_from(&planes, width, height, params.iterations),
    };

    // Colours beyond 2^100 are scaled down by a power of two (and σ_rt with them), and back at
    // the end, so that no sum overflows.
    let scale = range_scale(&colour);
    let mut current: [Vec<f32>; 3] = std::array::from_fn(|c| colour.iter().map(|p| p[c] * scale).collect());
    let mut next: [Vec<f32>; 3] = std::array::from_fn(|_| vec![0.0; width * height]);
    for level in 0..params.iterations {
        let step = 1isize << level;
        let factors = Factors {
            colour: params.sigma_color.map_or(0.0, |s| inverse_sigma(s as f64 * scale as f64 / (1u32 << level) as f64)),
            normal: inverse_sigma(params.sigma_normal as f64),
            position: sigma_position.map_or(0.0, inverse_sigma),
            secondary: inverse_sigma(params.sigma_secondary_normal as f64),
        };
        let source = &current;
        let planes = &planes;
        let [next_red, next_green, next_blue] = &mut next;
        next_red
            .par_chunks_mut(width)
            .zip(next_green.par_chunks_mut(width))
            .zip(next_blue.par_chunks_mut(width))
            .enumerate()
            .for_each(|(y, ((red, green), blue))| {
                let mut acc = Accumulator::new();
                for tile_start in (0..width).step_by(TILE) {
                    let tile_end = (tile_start + TILE).min(width);
                    acc.clear();
                    for (b, &hy) in B3.iter().enumerate() {
                        let yy = y as isize + (b as isize - 2) * step;
                        if !(0..height as isize).contains(&yy) {
                            continue;
                        }
                        for (a, &hx) in B3.iter().enumerate() {
                            let dx = (a as isize - 2) * step;
                            // Centres whose tap lands inside the image.
                            let lo = tile_start.max((-dx).max(0) as usize);
                            let hi = tile_end.min((width as isize - dx).max(0) as usize);
                            if lo >= hi {
                                continue;
                            }
                            let tap = Tap {
                                p: y * width + lo,
                                q: (yy as usize * width + lo).wrapping_add_signed(dx),
                                len: hi - lo,
                                h: hx * hy,
                                offset: lo - tile_start,
                            };
                            if planes.secondary.is_some() {
                                accumulate_tap::<true>(planes, source, tap, factors, &mut acc);
                            } else {
                                accumulate_tap::<false>(planes, source, tap, factors, &mut acc);
                            }
                        }
                    }
                    acc.write_planes(
                        &mut red[tile_start..tile_end],
                        &mut green[tile_start..tile_end],
                        &mut blue[tile_start..tile_end],
                    );
                }
            });
        std::mem::swap(&mut current, &mut next);
    }
    let [red, green, blue] = &current;
    let unscale = 1.0 / scale as f64;
    let pixels =
        red.iter().zip(green).zip(blue).map(|((&r, &g), &b)| [r, g, b].map(|c| finite(c as f64 * unscale))).collect();
    Ok((Image::from_pixels(noisy.width, noisy.height, pixels), FilterReport { sanitised_values: sanitised }))
}

/// One kernel tap for a run of consecutive centres: centres from pixel `p`, their taps from
/// pixel `q`, `len` of them, kernel weight `h`, accumulated from `offset` in the tile.
#[derive(Clone, Copy)]
struct Tap {
    p: usize,
    q: usize,
    len: usize,
    h: f32,
    offset: usize,
}

#[inline(always)]
fn accumulate_tap<const SECONDARY: bool>(
    planes: &Planes,
    colour: &[Vec<f32>; 3],
    tap: Tap,
    factors: Factors,
    acc: &mut Accumulator,
) {
    let Tap { p, q, len, h, offset } = tap;
    let (pc, qc) = (slices(colour, p, len), slices(colour, q, len));
    let (pn, qn) = (slices(&planes.normal, p, len), slices(&planes.normal, q, len));
    let (px, qx) = (slices(&planes.position, p, len), slices(&planes.position, q, len));
    // Without the term the normal planes stand in, unread, so every slice has length `len`.
    let secondary = planes.secondary.as_ref().unwrap_or(&planes.normal);
    let (psn, qsn) = (slices(secondary, p, len), slices(secondary, q, len));
    let (ps, qs) = (&planes.surface[p..p + len], &planes.surface[q..q + len]);
    let (ar, ag) = (&mut acc.red[offset..offset + len], &mut acc.green[offset..offset + len]);
    let (ab, aw) = (&mut acc.blue[offset..offset + len], &mut acc.weight[offset..offset + len]);
    // ‖a − b‖² / σ², as a sum of normalised squares.
    let term = |a: [&[f32]; 3], b: [&[f32]; 3], i: usize, inverse_sigma: f32| {
        normalised_sq(a[0][i] - b[0][i], inverse_sigma)
            + normalised_sq(a[1][i] - b[1][i], inverse_sigma)
            + normalised_sq(a[2][i] - b[2][i], inverse_sigma)
    };
    for i in 0..len {
        let mut exponent =
            term(pc, qc, i, factors.colour) + term(pn, qn, i, factors.normal) + term(px, qx, i, factors.position);
        if SECONDARY {
            exponent += term(psn, qsn, i, factors.secondary);
        }
        // `<=` is false for NaN, and `min` ignores NaN, so no NaN reaches a sum.
        let keep = (ps[i] == qs[i]) & (exponent <= MAX_EXPONENT);
        let w = if keep { h * exp_neg(-exponent.min(MAX_EXPONENT)) } else { 0.0 };
        ar[i] += w * qc[0][i];
        ag[i] += w * qc[1][i];
        ab[i] += w * qc[2][i];
        aw[i] += w;
    }
}

/// `len` values from `start` of each of three planes.
#[inline(always)]
fn slices(planes: &[Vec<f32>; 3], start: usize, len: usize) -> [&[f32]; 3] {
    [&planes[0][start..start + len], &planes[1][start..start + len], &planes[2][start..start + len]]
}

/// The σ_x `atrous` uses when `sigma_position` is None: `2^iterations` times the median world
/// distance between horizontally or vertically adjacent surface pixels. None when no two
/// adjacent surface pixels lie apart (the position term is then off) or the guide is
/// inconsistent.
pub fn default_sigma_position(guide: &GuideBuffers, iterations: u32) -> Option<f32> {
    if !guide.is_consistent() {
        return None;
    }
    let (planes, _) = planes(guide, false);
    sigma_position_from(&planes, guide.width as usize, guide.height as usize, iterations).map(|s| s as f32)
}

fn sigma_position_from(planes: &Planes, width: usize, height: usize, iterations: u32) -> Option<f64> {
    // In f64: squared differences of f32 positions may overflow f32.
    let distance = |p: usize, q: usize| {
        planes.position.iter().map(|plane| (plane[p] as f64 - plane[q] as f64).powi(2)).sum::<f64>().sqrt()
    };
    let mut distances = Vec::with_capacity(2 * width * height);
    for y in 0..height {
        for x in 0..width {
            let p = y * width + x;
            if planes.surface[p] == 0.0 {
                continue;
            }
            let right = (x + 1 < width).then_some(p + 1);
            let below = (y + 1 < height).then_some(p + width);
            for q in [right, below].into_iter().flatten() {
                let d = distance(p, q);
                if planes.surface[q] != 0.0 && d.is_finite() && d > 0.0 {
                    distances.push(d);
                }
            }
        }
    }
    if distances.is_empty() {
        return None;
    }
    let middle = distances.len() / 2;
    let median = *distances.select_nth_unstable_by(middle, f64::total_cmp).1;
    let sigma = median * 2f64.powi(iterations as i32);
    (sigma.is_finite() && sigma > 0.0).then_some(sigma)
}

/// The guide's geometry planes, with the secondary normals if `secondary`, and the number of
/// non-finite values read (which make a pixel escaped, or a secondary normal component 0).
fn planes(guide: &GuideBuffers, secondary: bool) -> (Planes, usize) {
    let n = guide.pixel_count();
    let mut bad_values = 0;
    let mut planes = Planes {
        normal: std::array::from_fn(|_| vec![0.0; n]),
        position: std::array::from_fn(|_| vec![0.0; n]),
        secondary: None,
        surface: vec![0.0; n],
    };
    for (i, ((normal, &depth), position)) in guide.normal.iter().zip(&guide.depth).zip(&guide.position).enumerate() {
        let bad = normal.iter().chain(position).filter(|v| !v.is_finite()).count() + usize::from(!depth.is_finite());
        bad_values += bad;
        if bad == 0 && is_surface(*normal, depth) {
            for c in 0..3 {
                planes.normal[c][i] = normal[c];
                planes.position[c][i] = position[c];
            }
            planes.surface[i] = 1.0;
        }
    }
    if let (true, Some(normals)) = (secondary, &guide.secondary_normal) {
        let mut sec: [Vec<f32>; 3] = std::array::from_fn(|_| vec![0.0; n]);
        for (i, normal) in normals.iter().enumerate() {
            for c in 0..3 {
                if !normal[c].is_finite() {
                    bad_values += 1;
                } else if planes.surface[i] != 0.0 {
                    sec[c][i] = normal[c];
                }
            }
        }
        planes.secondary = Some(sec);
    }
    (planes, bad_values)
}

/// `1 / σ` in f64, clamped to `f32::MAX`, for `normalised_sq`.
#[inline]
fn inverse_sigma(sigma: f64) -> f32 {
    (1.0 / sigma).min(f32::MAX as f64) as f32
}

#[cfg(test)]
mod tests;
