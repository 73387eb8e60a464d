//! Guided image filter (He, Sun, Tang 2010) with a multi-channel geometric guide, as Bauszat,
//! Eisemann and Magnor use it to denoise the indirect illumination of a path tracer ("Guided
//! Image Filtering for Interactive High-quality Global Illumination", EGSR 2011; the text is in
//! `shared/papers/guided-image-filtering-gi-2011.txt`). The noisy input N is the RGB indirect
//! image; the guide I holds d = 1..=4 noise-free channels built from the guide rays' normal and
//! depth (`GuideBuffers`).
//!
//! Paper → code:
//! - Section 3.3, Eq. 6, the local linear model `F_i = a_kᵀ I_i + b_k` for every pixel i of the
//!   window w_k (a (2r+1)² square centred on k): `window_coefficients` fits (a_k, b_k) per
//!   window and colour channel; the second stage of `filter_strip` evaluates the model.
//! - Eq. 7, the cost `Σ_{i∈w_k} ((a_kᵀ I_i + b_k − N_i)² + ε a_k²)`: minimised per window, with
//!   one ε per guide channel, i.e. the regulariser `Σ_j ε_j a_kj²` of He et al.'s
//!   multi-channel form that Section 3.3 points to ("the extension for a multi-dimensional I is
//!   possible").
//! - Eq. 8–9, `a_k = Cov_k(I, N) / (Var_k(I) + ε)`, `b_k = E_k[N] − a_kᵀ E_k[I]`: with a d-channel
//!   guide Cov_k is a d-vector and Var_k the d×d covariance Σ_k, so
//!   `a_k = (Σ_k + diag ε)⁻¹ Cov_k(I, N_c)` per colour channel c (`window_coefficients`, solved
//!   by square-root-free Cholesky, L D Lᵀ).
//! - "the coefficients are averaged for each overlapping window at each pixel": the second
//!   stage of `filter_strip` box-means the a and b maps, `F_i = āᵢᵀ I_i + b̄_i`.
//! - "linear runtime by calculating a series of mean values exploiting summed area tables":
//!   `SlidingBox` computes every box mean with sliding sums, so the cost does not depend on r.
//! - Section 4, Figure 5 (guide dimensionality: grey normal, normal, normal + depth) and "the
//!   values of the normal and depth map are all scaled to [0, 1]; we divided the depth map
//!   values by a constant depending on the overall scene extent": `GuideKind`,
//!   `guide_channels`.
//! - Section 4 parameters, "a radius of 24–32 pixels and an epsilon value of 0.01 for the
//!   normals and 0.01–0.03 for the depth values": `GuidedFilterParams::default` (24, 0.01,
//!   0.02).
//! - Table 2 (1024×768 on a GTX 285: 16 / 71 / 80 ms for d = 1 / 3 / 4, the same for every
//!   radius): `benches/guided_filter.rs` (criterion, d = 1 / 3 / 4, radius 8–32, exact and
//!   subsampled) and the ignored test `tests::timing_1024x768` time this implementation.
//!
//! Choices the paper leaves open, and why:
//! - Borders: windows are clipped to the image and every mean is taken over the pixels actually
//!   inside, as He et al.'s reference code does (box sums divided by the box sum of ones). No
//!   padding, so no invented values; a radius beyond the image makes every window the whole
//!   image (one global regression). The averaging of a and b likewise runs over the windows
//!   whose centre lies in the image.
//! - Guide scaling: normal components map to `(n + 1) / 2`, the grey guide is the mean of the
//!   three mapped components, depth is `depth / extent` clamped to [0, 1]. All channels share
//!   one range, so ε means the same for each.
//! - Depth extent: `GuidedFilterParams::depth_extent`, a constant the caller derives from the
//!   scene, so that ε_depth keeps its meaning from frame to frame (the paper's reason for a
//!   constant). `None` uses the frame's largest finite hit depth: right for a single image,
//!   not stable over an animation.
//! - Escaped pixels (zero normal, depth 0 in `GuideBuffers`): normal channels 0.5 (where the
//!   zero vector maps anyway; grey 0.5) and depth 1, the far end, so the background differs
//!   from near geometry in depth and forms a region of its own.
//! - Precision: everything that is summed is summed in f64. The source rows (guide channels,
//!   input colours) are converted to f64 once per row, so the products of two f32 values are
//!   exact; the column sums slide down in f64, the horizontal window sums run along the row in
//!   f64, and `E[I²] − E[I]²`, `E[IN] − E[I]E[N]` are formed and solved in f64. So the
//!   differences do not cancel catastrophically even for large inputs (a 1e3 offset) or images
//!   of 4096², and a sliding sum's rounding stays at f64 level relative to the window sums it
//!   passes. The per-pixel coefficients a and b are values, not sums, and are kept in f32
//!   (half the memory of f64) before their f64 box mean; the output is f32. No f32 shortcut
//!   was taken for the sums or the solve: the speed-up below comes from layout, not precision
//!   (an f32 solve for well-conditioned windows was tried and was slower, as its conversions
//!   cost more than the narrower lanes saved).
//! - Memory: no per-pixel plane of moments or coefficients is stored. The image is cut into
//!   horizontal strips; each strip keeps f64 column sums per term (8 / 14 / 21 / 29 moments for
//!   d = 1..=4, 3d + 3 coefficients) and slides them down, re-reading the row leaving the window
//!   and recomputing its products instead of keeping 2r + 1 rows. Stage 1 runs r rows ahead of
//!   stage 2 and writes its coefficient rows into a ring of 2r + 2 rows, from which stage 2
//!   slides its sums; the r coefficient rows beyond each end of a strip are computed by both
//!   strips that need them. (A whole coefficient image, 60 bytes per pixel at d = 4, is freshly
//!   allocated memory whose page faults alone cost about 30 ms per megapixel here.)
//! - Speed: the per-row work runs on structure-of-arrays rows (one row of f64 per term), so the
//!   column updates are plain slice loops, the horizontal running sums take one add per value
//!   with four rows in flight, and the per-pixel solve and evaluation run on blocks of `LANES`
//!   pixels whose loop bodies are branch-free with constant-bound inner loops, all of which the
//!   compiler vectorises. `filter_strip` is compiled for AVX-512, AVX2 and baseline x86-64 and
//!   picked at run time (`multiversion`); the binary stays portable. Rust never fuses a multiply
//!   and an add on its own, so every path does the same IEEE operations in the same order.
//! - Threads: the strips are fixed by the image size and the radius (`Grid::strip_rows`), never
//!   by the number of threads; rayon runs them in parallel. Where a strip starts decides how
//!   its sliding sums round, so a fixed split gives the same bits for any thread count.
//! - Numerical safety: the variances are clamped to ≥ 0 before adding ε, so Σ_k + diag ε is SPD
//!   even for a constant (flat wall) or rank-deficient (normals in a plane) guide. In exact
//!   arithmetic every Cholesky pivot D_jj is ≥ min ε; a pivot below half that can only come from
//!   rounding (an ε far below the moments' precision) and the window then falls back to a = 0,
//!   the box mean (the ε → ∞ limit), counted in `FilterReport::fallback_windows`; so does a
//!   window whose coefficients are not finite in f32. ε ≤ 0 or non-finite is rejected.
//! - Non-finite input values are replaced by 0 and counted (`FilterReport::sanitised_values`),
//!   never propagated; non-finite explicit guide planes are rejected (`guide_channels` never
//!   produces them: non-finite normals count as escaped, non-finite depth as far).
//!
//! Subsampling (not in the paper; He and Sun, "Fast Guided Filter", 2015), opt-in with
//! `GuidedFilterParams::subsample` = s > 1 (`gif:subsample=2`):
//! - `BlockMeans`: the guide planes and the input are averaged over s×s blocks (clipped at the
//!   right and bottom edges), in f64, stored as f32.
//! - Both stages run unchanged on the subsampled image with radius round(r / s) (at least 1),
//!   so the window covers about the same pixels; stage 2 hands the coefficient means ā, b̄ to
//!   `Upsample` instead of evaluating them.
//! - `Upsample`: ā and b̄ are interpolated bilinearly (sample i centred on full coordinate
//!   (i + ½)s − ½, clamped at the ends; `Resampling`) and evaluated against the
//!   full-resolution guide, `F = ā↑ᵀ I + b̄↑`, so edges in the guide stay sharp at full
//!   resolution while the regression sees s² fewer, less noisy pixels.
//! - Cost: the two stages shrink by s²; what remains per full-resolution pixel is the block
//!   mean, the bilinear blend of 3d + 3 coefficients and the evaluation. Measured quality and
//!   speed are in `docs/guided-filter.md`.
//! - Strips are cut on the subsampled image; each also computes the stage-2 row below its
//!   last, the lower bilinear neighbour of its last full-resolution rows, so the result is the
//!   same bit for bit for any thread count (tested) and matches the definition (a per-window
//!   regression on explicit block means, explicit averaging and interpolation; tested).

use rayon::prelude::*;

use crate::error::Error;
use crate::guide::GuideBuffers;
use crate::image::Image;

/// Which guide the filter uses (paper, Figure 5: guide dimensionality).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GuideKind {
    /// One channel: the mean of the normal's three [0, 1]-scaled components.
    GreyNormal,
    /// Three channels: the [0, 1]-scaled normal.
    Normal,
    /// Four channels: the [0, 1]-scaled normal and the depth divided by the scene extent.
    NormalDepth,
}

impl GuideKind {
    /// The number of guide channels d.
    pub fn channels(self) -> usize {
        match self {
            GuideKind::GreyNormal => 1,
            GuideKind::Normal => 3,
            GuideKind::NormalDepth => 4,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GuidedFilterParams {
    /// Window radius r: windows are (2r+1)² squares clipped to the image.
    pub radius: u32,
    pub guide: GuideKind,
    /// ε of each normal channel (and of the grey normal).
    pub epsilon_normal: f32,
    /// ε of the depth channel.
    pub epsilon_depth: f32,
    /// Scene-extent constant depth is divided by; `None` = the largest finite hit depth of the
    /// image.
    pub depth_extent: Option<f32>,
    /// Subsampling factor s of the fast guided filter (He and Sun 2015): the coefficients are
    /// fitted and box-averaged on s×s block means of the guide and the input with radius
    /// `radius / s`, then bilinearly upsampled and evaluated against the full-resolution guide.
    /// 1 (the default) is the exact filter of the paper.
    pub subsample: u32,
}

impl Default for GuidedFilterParams {
    /// The paper's settings (Section 4): radius 24, ε 0.01 for normals and 0.02 for depth.
    fn default() -> Self {
        GuidedFilterParams {
            radius: 24,
            guide: GuideKind::NormalDepth,
            epsilon_normal: 0.01,
            epsilon_depth: 0.02,
            depth_extent: None,
            subsample: 1,
        }
    }
}

impl GuidedFilterParams {
    /// ε per guide channel, in the order of `guide_channels`.
    pub fn epsilons(&self) -> Vec<f32> {
        match self.guide {
            GuideKind::GreyNormal => vec![self.epsilon_normal],
            GuideKind::Normal => vec![self.epsilon_normal; 3],
            GuideKind::NormalDepth => {
                vec![self.epsilon_normal, self.epsilon_normal, self.epsilon_normal, self.epsilon_depth]
            }
        }
    }
}

/// The most guide channels `guided_filter_planes` accepts.
pub const MAX_GUIDE_CHANNELS: usize = 4;

/// Normal value of escaped pixels, per [0, 1]-scaled component.
const ESCAPED_NORMAL: f32 = 0.5;
/// Depth value of escaped pixels, after scaling.
const ESCAPED_DEPTH: f32 = 1.0;

/// What the filter had to repair.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FilterReport {
    /// Non-finite input values (per colour channel) replaced by 0 before filtering.
    pub sanitised_values: usize,
    /// Windows whose system `Σ_k + diag ε` was not numerically positive definite (only possible
    /// for ε far below the moments' rounding error) and fell back to a = 0, the box mean.
    pub fallback_windows: usize,
}

fn is_escaped(normal: [f32; 3]) -> bool {
    normal == [0.0; 3] || !normal.iter().all(|c| c.is_finite())
}

/// Builds the guide channels (d planes of `width * height` values, each in [0, 1]): normal
/// components as `(n + 1) / 2`, the grey normal as their mean, depth as `depth / extent`
/// clamped to [0, 1]. Escaped pixels (zero or non-finite normal) get normal 0.5 and depth 1;
/// a non-finite depth on a hit counts as far (1). Errors on inconsistent buffers or a depth
/// extent that is not finite and positive.
pub fn guide_channels(guide: &GuideBuffers, params: &GuidedFilterParams) -> Result<Vec<Vec<f32>>, Error> {
    if !guide.is_consistent() {
        let message = format!("guide buffers are inconsistent with their size {}x{}", guide.width, guide.height);
        return Err(Error::size_mismatch("guide buffers", message));
    }
    let scale = |n: f32| ((n + 1.0) * 0.5).clamp(0.0, 1.0);
    let extent = match (params.guide, params.depth_extent) {
        (GuideKind::NormalDepth, Some(extent)) if !(extent.is_finite() && extent > 0.0) => {
            return Err(Error::parameter(
                "depth_extent",
                format!("the depth extent must be finite and positive, got {extent}"),
            ));
        }
        (GuideKind::NormalDepth, Some(extent)) => extent,
        (GuideKind::NormalDepth, None) => {
            let max = guide
                .normal
                .par_iter()
                .zip(&guide.depth)
                .map(|(&n, &z)| if !is_escaped(n) && z.is_finite() { z } else { 0.0 })
                .reduce(|| 0.0f32, f32::max);
            if max > 0.0 {
                max
            } else {
                1.0
            }
        }
        _ => 1.0,
    };
    // One pass over the pixels writes every channel, a row at a time.
    let d = params.guide.channels();
    if guide.normal.is_empty() {
        return Ok(vec![Vec::new(); d]);
    }
    let width = guide.width as usize;
    let mut planes = vec![vec![0.0f32; guide.normal.len()]; d];
    let mut rows: Vec<_> = planes.iter_mut().map(|plane| plane.chunks_mut(width)).collect();
    let row_sets: Vec<Vec<&mut [f32]>> =
        (0..guide.height as usize).map(|_| rows.iter_mut().filter_map(|r| r.next()).collect()).collect();
    row_sets.into_par_iter().enumerate().for_each(|(y, mut row)| {
        let pixels = y * width..(y + 1) * width;
        for (x, (&n, &z)) in guide.normal[pixels.clone()].iter().zip(&guide.depth[pixels]).enumerate() {
            let escaped = is_escaped(n);
            match params.guide {
                GuideKind::GreyNormal => {
                    row[0][x] = if escaped { ESCAPED_NORMAL } else { (scale(n[0]) + scale(n[1]) + scale(n[2])) / 3.0 }
                }
                GuideKind::Normal | GuideKind::NormalDepth => {
                    for c in 0..3 {
                        row[c][x] = if escaped { ESCAPED_NORMAL } else { scale(n[c]) };
                    }
                    if d == 4 {
                        row[3][x] =
                            if escaped || !z.is_finite() { ESCAPED_DEPTH } else { (z / extent).clamp(0.0, 1.0) };
                    }
                }
            }
        }
    });
    Ok(planes)
}

/// Filters `noisy` guided by `guide` with the channels and ε of `params`.
pub fn guided_filter(
    noisy: &Image,
    guide: &GuideBuffers,
    params: &GuidedFilterParams,
) -> Result<(Image, FilterReport), Error> {
    if (noisy.width, noisy.height) != (guide.width, guide.height) {
        let message =
            format!("the noisy image is {}x{}, the guide {}x{}", noisy.width, noisy.height, guide.width, guide.height);
        return Err(Error::size_mismatch("noisy image and guide buffers", message));
    }
    let planes = guide_channels(guide, params)?;
    guided_filter_planes_subsampled(noisy, &planes, &params.epsilons(), params.radius, params.subsample)
}

/// Filters `noisy` guided by explicit guide planes (1..=4 planes of `width * height` finite
/// values, best scaled to [0, 1]) with one ε per plane and window radius `radius`.
pub fn guided_filter_planes(
    noisy: &Image,
    planes: &[Vec<f32>],
    epsilons: &[f32],
    radius: u32,
) -> Result<(Image, FilterReport), Error> {
    guided_filter_planes_subsampled(noisy, planes, epsilons, radius, 1)
}

/// `guided_filter_planes` as the fast guided filter with subsampling factor `subsample` (≥ 1;
/// 1 is the exact filter): see `GuidedFilterParams::subsample` and the module's "Subsampling".
pub fn guided_filter_planes_subsampled(
    noisy: &Image,
    planes: &[Vec<f32>],
    epsilons: &[f32],
    radius: u32,
    subsample: u32,
) -> Result<(Image, FilterReport), Error> {
    if subsample == 0 {
        return Err(Error::parameter("subsample", "the subsampling factor must be at least 1, got 0"));
    }
    let (width, height) = (noisy.width as usize, noisy.height as usize);
    let count = width * height;
    if noisy.pixels.len() != count {
        let message =
            format!("the noisy image has {} pixels, its size {width}x{height} needs {count}", noisy.pixels.len());
        return Err(Error::size_mismatch("noisy image", message));
    }
    let d = planes.len();
    if !(1..=MAX_GUIDE_CHANNELS).contains(&d) {
        return Err(Error::parameter("planes", format!("the guide needs 1 to {MAX_GUIDE_CHANNELS} channels, got {d}")));
    }
    if epsilons.len() != d {
        let message = format!("{d} guide channels need {d} epsilons, got {}", epsilons.len());
        return Err(Error::size_mismatch("guide channels and epsilons", message));
    }
    if let Some((j, e)) = epsilons.iter().enumerate().find(|(_, e)| !(e.is_finite() && **e > 0.0)) {
        return Err(Error::parameter("epsilons", format!("epsilon {j} must be finite and positive, got {e}")));
    }
    for (j, plane) in planes.iter().enumerate() {
        if plane.len() != count {
            let message =
                format!("guide channel {j} has {} values, the {width}x{height} image needs {count}", plane.len());
            return Err(Error::size_mismatch("guide channel", message));
        }
        // A branch-free pass first (it vectorises); the position only on failure.
        if !plane.par_chunks(1 << 16).all(|chunk| chunk.iter().fold(true, |ok, v| ok & v.is_finite())) {
            let i = plane.iter().position(|v| !v.is_finite()).unwrap_or_default();
            let message = format!("guide channel {j} has the non-finite value {} at pixel {i}", plane[i]);
            return Err(Error::parameter("planes", message));
        }
    }

    let sanitised_values: usize = noisy
        .pixels
        .par_chunks(1 << 14)
        .map(|chunk| chunk.iter().flatten().map(|c| usize::from(!c.is_finite())).sum::<usize>())
        .sum();
    let cleaned: Option<Vec<[f32; 3]>> = (sanitised_values > 0)
        .then(|| noisy.pixels.par_iter().map(|p| p.map(|c| if c.is_finite() { c } else { 0.0 })).collect());
    let input = cleaned.as_deref().unwrap_or(&noisy.pixels);
    if count == 0 {
        return Ok((noisy.clone(), FilterReport { sanitised_values, fallback_windows: 0 }));
    }

    // A radius beyond the image changes nothing (windows are clipped), and this bound keeps
    // the index arithmetic far from overflow.
    let radius = (radius as usize).min(width.max(height));
    let eps: [f64; MAX_GUIDE_CHANNELS] = std::array::from_fn(|j| epsilons.get(j).map_or(0.0, |&e| e as f64));
    let grid = Grid { width, height, radius };
    // Subsampling only where there is a window to shrink and the image is larger than a block.
    let subsample = (subsample as usize).min(width.max(height));
    let (pixels, fallback_windows) = if subsample > 1 && radius > 0 {
        match d {
            1 => filter_subsampled::<1, 8, 6>(grid, input, planes, &eps, subsample),
            2 => filter_subsampled::<2, 14, 9>(grid, input, planes, &eps, subsample),
            3 => filter_subsampled::<3, 21, 12>(grid, input, planes, &eps, subsample),
            _ => filter_subsampled::<4, 29, 15>(grid, input, planes, &eps, subsample),
        }
    } else {
        match d {
            1 => filter::<1, 8, 6>(grid, input, planes, &eps),
            2 => filter::<2, 14, 9>(grid, input, planes, &eps),
            3 => filter::<3, 21, 12>(grid, input, planes, &eps),
            _ => filter::<4, 29, 15>(grid, input, planes, &eps),
        }
    };
    Ok((Image::from_pixels(noisy.width, noisy.height, pixels), FilterReport { sanitised_values, fallback_windows }))
}

mod sliding_box;
mod solver;
mod strips;
mod subsampled;
#[cfg(test)]
mod tests;

use sliding_box::*;
use solver::*;
use strips::*;
use subsampled::*;
