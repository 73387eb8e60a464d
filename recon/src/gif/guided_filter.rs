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

#[derive(Clone, Copy, Debug)]
struct Grid {
    width: usize,
    height: usize,
    /// Already bounded by the image size.
    radius: usize,
}

/// Pixels per lane block of the per-pixel work (the solve, the evaluation): written as loops over
/// `[f64; LANES]` arrays, which the compiler turns into SIMD instructions.
const LANES: usize = 8;
type Lanes = [f64; LANES];

/// Pixels per chunk of a row whose window sums `SlidingBox::row` hands on at once
/// (a multiple of LANES; 32 rows of them fill 32 KiB).
const CHUNK: usize = 128;

/// Rows of box sums summed together in `box_rows`.
const SCAN_ROWS: usize = 4;

/// Strips are at least this many rows, and at least 8 r, where the image has room for two such.
const MIN_STRIP_ROWS: usize = 256;

/// Otherwise an image is still cut in two where each half has at least this many rows and 4 r.
const MIN_HALF_ROWS: usize = 64;

impl Grid {
    /// Length of the per-row work arrays: the width rounded up to whole lane blocks.
    fn padded(&self) -> usize {
        self.width.div_ceil(LANES) * LANES
    }

    /// Rows per strip. From the image and the radius only, never from the number of threads:
    /// where a strip starts decides how its sums are rounded, so a fixed split gives the same
    /// bits for any thread count. Each boundary between strips costs about 3r rows of stage 1
    /// (the r coefficient rows beyond the strip on each side, and the first window), so strips
    /// are long: at least `MIN_STRIP_ROWS` and 8r rows, and an even number of them where there
    /// are several (two cores share the work evenly). A shorter image is still cut in two halves
    /// of at least `MIN_HALF_ROWS` and 4r rows, so that both cores work on it.
    fn strip_rows(&self) -> usize {
        let count = self.height / MIN_STRIP_ROWS.max(8 * self.radius);
        let count = if count >= 2 {
            count / 2 * 2
        } else if self.height >= 2 * MIN_HALF_ROWS.max(4 * self.radius) {
            2
        } else {
            1
        };
        self.height.div_ceil(count)
    }

    /// Rows in the (clipped) window of row y.
    fn window_rows(&self, y: usize) -> usize {
        (y + self.radius).min(self.height - 1) - y.saturating_sub(self.radius) + 1
    }

    /// 1 / (columns in the clipped window of column x) per column; 0 in the padding.
    fn inverse_columns(&self) -> Vec<f64> {
        let Grid { width, radius, .. } = *self;
        (0..self.padded())
            .map(|x| {
                if x < width {
                    1.0 / ((x + radius).min(width - 1) - x.saturating_sub(radius) + 1) as f64
                } else {
                    0.0
                }
            })
            .collect()
    }
}

/// Box-filtered values of stage 1 for a d-channel guide, per pixel: E[I_j] (d), E[I_j I_k] for
/// j ≤ k (d(d+1)/2), E[N_c] (3), E[N_c I_j] (3d, c-major).
const fn moment_count(d: usize) -> usize {
    d + d * (d + 1) / 2 + 3 + 3 * d
}

/// Coefficients per pixel: a_c (d values for each colour c, c-major), then b_c (3).
const fn coefficient_count(d: usize) -> usize {
    3 * d + 3
}

/// One box-filtered quantity: the source row `.0`, or the product of source rows `.0` and `.1`.
type Term = (usize, Option<usize>);

/// Stage 1's terms (layout of `moment_count`) over the source rows I_0..I_{d−1}, N_0..N_2.
fn moment_terms<const D: usize>() -> Vec<Term> {
    let mut terms: Vec<Term> = (0..D).map(|j| (j, None)).collect();
    terms.extend((0..D).flat_map(|j| (j..D).map(move |k| (j, Some(k)))));
    terms.extend((0..3).map(|c| (D + c, None)));
    terms.extend((0..3).flat_map(|c| (0..D).map(move |j| (D + c, Some(j)))));
    terms
}

/// Where a box pass reads row y: its source rows, one after the other, `padded` values each
/// (zero past the width), either written to `scratch` or stored.
trait RowSource {
    /// f32, or f64 holding f32 values (converted once per row rather than once per product).
    type Value: Copy + Default + Into<f64>;
    fn row<'a>(&'a self, y: usize, scratch: &'a mut [Self::Value]) -> &'a [Self::Value];
}

/// Stage 1's source rows: the d guide channels and the three colour channels of the input.
struct Channels<'a> {
    planes: &'a [Vec<f32>],
    input: &'a [[f32; 3]],
    width: usize,
    padded: usize,
}

impl RowSource for Channels<'_> {
    type Value = f64;

    #[inline(always)]
    fn row<'a>(&'a self, y: usize, scratch: &'a mut [f64]) -> &'a [f64] {
        let (width, padded, d) = (self.width, self.padded, self.planes.len());
        for (plane, out) in self.planes.iter().zip(scratch.chunks_exact_mut(padded)) {
            for (out, &v) in out.iter_mut().zip(&plane[y * width..(y + 1) * width]) {
                *out = f64::from(v);
            }
        }
        let (red, rest) = scratch[d * padded..].split_at_mut(padded);
        let (green, blue) = rest.split_at_mut(padded);
        for (((pixel, r), g), b) in self.input[y * width..(y + 1) * width].iter().zip(red).zip(green).zip(blue) {
            (*r, *g, *b) = (f64::from(pixel[0]), f64::from(pixel[1]), f64::from(pixel[2]));
        }
        scratch
    }
}

/// Stage 2's source rows: the coefficient rows of a strip, row y in slot y mod `slots`.
struct CoefficientRing<'a> {
    values: &'a [f32],
    slots: usize,
    row_len: usize,
}

impl RowSource for CoefficientRing<'_> {
    type Value = f32;

    #[inline(always)]
    fn row<'a>(&'a self, y: usize, _: &'a mut [f32]) -> &'a [f32] {
        &self.values[y % self.slots * self.row_len..][..self.row_len]
    }
}

/// What both stages share: the grid, stage 1's source rows and the ε.
struct Context<const D: usize, R> {
    grid: Grid,
    source: R,
    eps: [f64; D],
    /// Every Cholesky pivot of Σ + diag ε is at least min ε in exact arithmetic.
    min_pivot: f64,
    inverse_columns: Vec<f64>,
}

impl<const D: usize, R: RowSource<Value = f64>> Context<D, R> {
    fn new(grid: Grid, source: R, eps: &[f64; MAX_GUIDE_CHANNELS]) -> Self {
        let eps: [f64; D] = std::array::from_fn(|j| eps[j]);
        let min_eps = eps.iter().fold(f64::INFINITY, |m, &e| m.min(e));
        Context { grid, source, eps, min_pivot: 0.5 * min_eps, inverse_columns: grid.inverse_columns() }
    }
}

/// The two stages for a d-channel guide (`M`, `Q`: `moment_count(D)`, `coefficient_count(D)`,
/// spelled out because stable Rust cannot compute array lengths from `D`): per-window
/// coefficients from box-filtered moments, then their box mean evaluated against the guide.
/// Returns the pixels and the number of fallback windows.
fn filter<const D: usize, const M: usize, const Q: usize>(
    grid: Grid,
    input: &[[f32; 3]],
    planes: &[Vec<f32>],
    eps: &[f64; MAX_GUIDE_CHANNELS],
) -> (Vec<[f32; 3]>, usize) {
    let channels = Channels { planes, input, width: grid.width, padded: grid.padded() };
    let context = Context::<D, _>::new(grid, channels, eps);
    let strip = grid.strip_rows();
    let mut pixels = vec![[0.0f32; 3]; grid.width * grid.height];
    let fallback_windows = pixels
        .par_chunks_mut(strip * grid.width)
        .enumerate()
        .map(|(s, out)| {
            let y0 = s * strip;
            let rows = y0..y0 + out.len() / grid.width;
            let mut sink = Evaluate { planes, width: grid.width, y0, out };
            filter_strip::<D, M, Q, _, _>(&context, rows.clone(), rows.end, &mut sink)
        })
        .sum();
    (pixels, fallback_windows)
}

/// What stage 2 does with the window means of the coefficients, block by block.
trait CoefficientSink<const D: usize, const Q: usize> {
    /// The LANES pixels of row y from x0 on (`n` of them inside the image): their coefficient
    /// means are `sums` (Q rows of `CHUNK`, this block's at `at`) times `scale`.
    fn block(&mut self, y: usize, x0: usize, n: usize, sums: &[f64], at: usize, scale: &Lanes);
    /// Called after the last block of row y.
    fn row_done(&mut self, y: usize);
}

/// The exact filter's stage 2: `F = ā·I + b̄` per pixel, written to whole output rows from row
/// `y0` on.
struct Evaluate<'a> {
    planes: &'a [Vec<f32>],
    width: usize,
    y0: usize,
    out: &'a mut [[f32; 3]],
}

impl<const D: usize, const Q: usize> CoefficientSink<D, Q> for Evaluate<'_> {
    #[inline(always)]
    fn block(&mut self, y: usize, x0: usize, n: usize, sums: &[f64], at: usize, scale: &Lanes) {
        let width = self.width;
        let mut g = [[0.0f64; LANES]; D];
        for (g, plane) in g.iter_mut().zip(self.planes) {
            for (g, &v) in g.iter_mut().zip(&plane[y * width + x0..][..n]) {
                *g = v as f64;
            }
        }
        let f = evaluate::<D, Q>(sums, at, scale, &g);
        for (l, pixel) in self.out[(y - self.y0) * width + x0..][..n].iter_mut().enumerate() {
            *pixel = [f[0][l], f[1][l], f[2][l]];
        }
    }

    #[inline(always)]
    fn row_done(&mut self, _: usize) {}
}

/// Both stages for the strip of rows `own`: stage 2 runs over rows `own.start..end` (`end` may
/// reach a row past the strip, for a sink that needs it) and hands its coefficient means to
/// `sink`. Stage 1 runs r rows ahead of stage 2, computing the coefficient rows the strip's
/// windows reach (r rows beyond it on either side, computed again by the neighbouring strip)
/// into a ring of 2r + 2 rows, so no coefficient image is stored (see the module's "Memory").
/// Returns the fallback windows among the rows `own`. Compiled for AVX-512 and AVX2 as well,
/// picked at run time; everything it calls in its loops is inlined into it.
#[multiversion::multiversion(targets("x86_64+avx512f+avx512vl+avx512dq+avx512bw+avx2+fma", "x86_64+avx2+fma"))]
fn filter_strip<const D: usize, const M: usize, const Q: usize, R: RowSource<Value = f64>, S: CoefficientSink<D, Q>>(
    context: &Context<D, R>,
    own: std::ops::Range<usize>,
    end: usize,
    sink: &mut S,
) -> usize {
    const { assert!(M == moment_count(D) && Q == coefficient_count(D)) };
    let grid = context.grid;
    let Grid { width, height, radius } = grid;
    let padded = grid.padded();
    let row_len = Q * padded;
    let slots = (2 * radius + 2).min(height);
    let mut ring = vec![0.0f32; slots * row_len];
    let mut stage1 = SlidingBox::new(grid, moment_terms::<D>(), D + 3);
    let mut stage2 = SlidingBox::new(grid, (0..Q).map(|q| (q, None)).collect(), 0);
    let mut next_coefficient_row = own.start.saturating_sub(radius);
    let mut fallbacks = 0;
    for y in own.start..end {
        // Stage 1 (Eq. 8–9): window means of I, I Iᵀ, N and N I → a_k, b_k, up to row y + r.
        while next_coefficient_row <= (y + radius).min(height - 1) {
            let k = next_coefficient_row;
            let inverse_rows = 1.0 / grid.window_rows(k) as f64;
            let coefficients = &mut ring[k % slots * row_len..][..row_len];
            stage1.row(&context.source, k, |start, sums| {
                for x0 in (start..(start + CHUNK).min(width)).step_by(LANES) {
                    let scale = scale_block(context, x0, inverse_rows);
                    let fell_back = coefficient_block::<D, M, Q>(sums, x0 - start, x0, &scale, context, coefficients);
                    if own.contains(&k) {
                        fallbacks += fell_back[..LANES.min(width - x0)].iter().filter(|f| **f).count();
                    }
                }
            });
            next_coefficient_row += 1;
        }
        // Stage 2 (Eq. 6 averaged over the windows containing each pixel): ā and b̄.
        let inverse_rows = 1.0 / grid.window_rows(y) as f64;
        stage2.row(&CoefficientRing { values: &ring, slots, row_len }, y, |start, sums| {
            for x0 in (start..(start + CHUNK).min(width)).step_by(LANES) {
                let scale = scale_block(context, x0, inverse_rows);
                sink.block(y, x0, LANES.min(width - x0), sums, x0 - start, &scale);
            }
        });
        sink.row_done(y);
    }
    fallbacks
}

/// The fast guided filter (module's "Subsampling"): both stages on s×s block means of the guide
/// and the input with radius r / s (rounded, at least 1), then the coefficient means upsampled
/// bilinearly and evaluated against the full-resolution guide, `F = ā↑·I + b̄↑`. Returns the
/// pixels and the number of fallback windows (of the subsampled image).
fn filter_subsampled<const D: usize, const M: usize, const Q: usize>(
    grid: Grid,
    input: &[[f32; 3]],
    planes: &[Vec<f32>],
    eps: &[f64; MAX_GUIDE_CHANNELS],
    s: usize,
) -> (Vec<[f32; 3]>, usize) {
    let (low_width, low_height) = (grid.width.div_ceil(s), grid.height.div_ceil(s));
    let low_radius = ((grid.radius + s / 2) / s).max(1).min(low_width.max(low_height));
    let low = Grid { width: low_width, height: low_height, radius: low_radius };
    let means = BlockMeans::new(grid, planes, input, s);
    let context = Context::<D, _>::new(low, means, eps);
    let rows = Resampling::new(grid.height, low_height, s);
    let columns = Resampling::new(grid.width, low_width, s);
    // The strips of the subsampled image, and for each the full-resolution rows whose bilinear
    // neighbour above (`rows.lower`, the smaller row index; it never decreases) lies in it.
    let strip = low.strip_rows();
    let mut jobs = Vec::new();
    let mut pixels = vec![[0.0f32; 3]; grid.width * grid.height];
    let mut rest = pixels.as_mut_slice();
    let mut first_row = 0;
    for y0 in (0..low_height).step_by(strip) {
        let own = y0..(y0 + strip).min(low_height);
        let end_row = rows.lower.partition_point(|&lower| lower < own.end);
        let (out, tail) = std::mem::take(&mut rest).split_at_mut((end_row - first_row) * grid.width);
        jobs.push((own, first_row, out));
        rest = tail;
        first_row = end_row;
    }
    let fallback_windows = jobs
        .into_par_iter()
        .map(|(own, first_row, out)| {
            let mut sink = Upsample::<D, Q>::new(planes, grid.width, low, &rows, &columns, first_row, out);
            // One stage-2 row past the strip: the bilinear neighbour below its last row.
            let end = (own.end + 1).min(low_height);
            filter_strip::<D, M, Q, _, _>(&context, own, end, &mut sink)
        })
        .sum();
    (pixels, fallback_windows)
}

/// Stage 1's source rows for the fast guided filter: the means of the d guide planes and the
/// three colour channels over s×s blocks of pixels (clipped at the right and bottom edges),
/// summed in f64 and stored as f32, row by row: row j holds the d + 3 channels of subsampled
/// row j one after the other, `width` values each.
struct BlockMeans {
    values: Vec<f32>,
    width: usize,
    padded: usize,
    channels: usize,
}

impl BlockMeans {
    /// The block means of `planes` and `input` on `grid` (full resolution).
    fn new(grid: Grid, planes: &[Vec<f32>], input: &[[f32; 3]], s: usize) -> BlockMeans {
        let Grid { width, height, .. } = grid;
        let low_width = width.div_ceil(s);
        let channels = planes.len() + 3;
        let mut values = vec![0.0f32; channels * low_width * height.div_ceil(s)];
        // 1 / (columns of block i); the rows of a block divide later.
        let inverse_columns: Vec<f64> =
            (0..low_width).map(|i| 1.0 / (((i + 1) * s).min(width) - i * s) as f64).collect();
        values.par_chunks_mut(channels * low_width).enumerate().for_each_init(
            || vec![0.0f64; channels * width],
            |sums, (j, out)| {
                let rows = j * s..((j + 1) * s).min(height);
                let inverse_rows = 1.0 / rows.len() as f64;
                sums.fill(0.0);
                // Down the columns: s rows of each channel, one row of sums per channel.
                for y in rows {
                    let row = y * width..(y + 1) * width;
                    let (guide, colours) = sums.split_at_mut(planes.len() * width);
                    for (sums, plane) in guide.chunks_exact_mut(width).zip(planes) {
                        for (sum, &v) in sums.iter_mut().zip(&plane[row.clone()]) {
                            *sum += v as f64;
                        }
                    }
                    let (red, rest) = colours.split_at_mut(width);
                    let (green, blue) = rest.split_at_mut(width);
                    for (((r, g), b), pixel) in red.iter_mut().zip(green).zip(blue).zip(&input[row]) {
                        *r += pixel[0] as f64;
                        *g += pixel[1] as f64;
                        *b += pixel[2] as f64;
                    }
                }
                // Along the rows: s columns at a time, divided by the block's pixels.
                for (out, sums) in out.chunks_exact_mut(low_width).zip(sums.chunks_exact(width)) {
                    for ((out, columns), inverse) in out.iter_mut().zip(sums.chunks(s)).zip(&inverse_columns) {
                        *out = (columns.iter().sum::<f64>() * inverse * inverse_rows) as f32;
                    }
                }
            },
        );
        BlockMeans { values, width: low_width, padded: low_width.div_ceil(LANES) * LANES, channels }
    }
}

impl RowSource for BlockMeans {
    type Value = f64;

    #[inline(always)]
    fn row<'a>(&'a self, y: usize, scratch: &'a mut [f64]) -> &'a [f64] {
        let row = &self.values[y * self.channels * self.width..][..self.channels * self.width];
        for (out, values) in scratch.chunks_exact_mut(self.padded).zip(row.chunks_exact(self.width)) {
            for (out, &v) in out.iter_mut().zip(values) {
                *out = f64::from(v);
            }
        }
        scratch
    }
}

/// Bilinear resampling from a subsampled axis (`low` samples, sample i centred on full
/// coordinate (i + ½) s − ½) to every full-resolution index: the neighbours `lower` and
/// `upper` (clamped to the axis) and the weight `t` of the upper one.
struct Resampling {
    lower: Vec<usize>,
    upper: Vec<usize>,
    t: Vec<f32>,
    /// s, and the number of subsampled values.
    phases: usize,
    low: usize,
}

impl Resampling {
    fn new(full: usize, low: usize, s: usize) -> Resampling {
        let (mut lower, mut upper, mut t) = (Vec::with_capacity(full), Vec::with_capacity(full), Vec::new());
        for i in 0..full {
            let v = (i as f64 + 0.5) / s as f64 - 0.5;
            let below = (v.floor().max(0.0) as usize).min(low - 1);
            let above = (below + 1).min(low - 1);
            lower.push(below);
            upper.push(above);
            t.push(if above == below { 0.0 } else { (v - below as f64).clamp(0.0, 1.0) as f32 });
        }
        Resampling { lower, upper, t, phases: s, low }
    }

    /// Resamples one row: `full[i] = (1 − t_i) low[lower_i] + t_i low[upper_i]`. Away from the
    /// ends, full index i s + p has the neighbours i + o_p and i + o_p + 1 with the weight t_p
    /// of its phase p (o_p is −1 or 0), so there each phase runs as a loop over contiguous
    /// values instead of a gather.
    #[inline(always)]
    fn upsample(&self, low: &[f32], full: &mut [f32]) {
        // Blocks 1 .. n − 1 are whole and interior: their neighbours lie within 0 ..= n − 1.
        let interior = 1..(self.low - 1).max(1);
        match self.phases {
            2 => self.upsample_interior::<2>(low, full, interior.clone()),
            3 => self.upsample_interior::<3>(low, full, interior.clone()),
            4 => self.upsample_interior::<4>(low, full, interior.clone()),
            s => {
                for p in 0..s {
                    let x = interior.start * s + p;
                    let Some((&first, &t)) = self.lower.get(x).zip(self.t.get(x)) else { break };
                    let blocks = full[interior.start * s..interior.end * s].chunks_exact_mut(s);
                    for ((block, &a), &b) in blocks.zip(&low[first..]).zip(&low[first + 1..]) {
                        block[p] = (1.0 - t) * a + t * b;
                    }
                }
            }
        }
        let s = self.phases;
        let count = full.len();
        let edges = (0..interior.start * s).chain(interior.end * s..count);
        for x in edges {
            full[x] = (1.0 - self.t[x]) * low[self.lower[x]] + self.t[x] * low[self.upper[x]];
        }
    }

    /// The interior blocks of `upsample` for a known s = S: all S phases of a block in one
    /// loop body over the block's low neighbours i − 1, i and i + 1, which the compiler turns
    /// into vector loads and interleaved stores.
    #[inline(always)]
    fn upsample_interior<const S: usize>(&self, low: &[f32], full: &mut [f32], interior: std::ops::Range<usize>) {
        if interior.is_empty() {
            return;
        }
        // Phase p's neighbours are i + o_p and i + o_p + 1, where o_p = −1 for the phases left
        // of the block's centre (2p + 1 < S) and 0 for the others.
        let weight: [f32; S] = std::array::from_fn(|p| {
            let x = interior.start * S + p;
            debug_assert_eq!(self.lower[x] + 1 - interior.start, usize::from(2 * p + 1 >= S));
            self.t[x]
        });
        let blocks = full[interior.start * S..interior.end * S].chunks_exact_mut(S);
        let (previous, current, next) =
            (&low[interior.start - 1..], &low[interior.start..], &low[interior.start + 1..]);
        for (((block, &previous), &current), &next) in blocks.zip(previous).zip(current).zip(next) {
            for p in 0..S {
                let (a, b) = if 2 * p + 1 < S { (previous, current) } else { (current, next) };
                block[p] = (1.0 - weight[p]) * a + weight[p] * b;
            }
        }
    }
}

/// The fast guided filter's stage 2: upsamples each subsampled row's coefficient means along
/// the row, keeps the last two such rows and, once both bilinear neighbours of a
/// full-resolution row are there, blends them and evaluates `F = ā↑·I + b̄↑` against the full
/// guide.
struct Upsample<'a, const D: usize, const Q: usize> {
    planes: &'a [Vec<f32>],
    width: usize,
    low_padded: usize,
    low_height: usize,
    rows: &'a Resampling,
    columns: &'a Resampling,
    /// The output rows from full-resolution row `first_row` on, and the next one to write.
    first_row: usize,
    next_row: usize,
    out: &'a mut [[f32; 3]],
    /// Coefficient means of the current subsampled row (Q rows of `low_padded`).
    low: Vec<f32>,
    /// Those of the previous and the current subsampled row upsampled along the row (Q rows of
    /// `width`); whether `previous` holds a row yet.
    previous: Vec<f32>,
    current: Vec<f32>,
    have_previous: bool,
    /// The output accumulators (3 rows of `width`).
    sums: Vec<f64>,
}

impl<'a, const D: usize, const Q: usize> Upsample<'a, D, Q> {
    fn new(
        planes: &'a [Vec<f32>],
        width: usize,
        low: Grid,
        rows: &'a Resampling,
        columns: &'a Resampling,
        first_row: usize,
        out: &'a mut [[f32; 3]],
    ) -> Self {
        let low_padded = low.padded();
        Upsample {
            planes,
            width,
            low_padded,
            low_height: low.height,
            rows,
            columns,
            first_row,
            next_row: first_row,
            out,
            low: vec![0.0; Q * low_padded],
            previous: vec![0.0; Q * width],
            current: vec![0.0; Q * width],
            have_previous: false,
            sums: vec![0.0; 3 * width],
        }
    }

    /// Writes the full-resolution rows whose bilinear neighbour above (the smaller row index) is
    /// subsampled row `lower`, blending `previous` (row `lower`) and `current` (the row below), or `current`
    /// alone when `lower` is the last row.
    #[inline(always)]
    fn emit(&mut self, lower: usize, use_previous: bool) {
        let width = self.width;
        let end_row = self.first_row + self.out.len() / width;
        while self.next_row < end_row && self.rows.lower[self.next_row] == lower {
            let y = self.next_row;
            let t = self.rows.t[y];
            let above = if use_previous { &self.previous } else { &self.current };
            let blended = |q: usize| {
                let range = q * width..(q + 1) * width;
                above[range.clone()]
                    .iter()
                    .zip(&self.current[range])
                    .map(move |(&p, &c)| ((1.0 - t) * p + t * c) as f64)
            };
            for (c, sums) in self.sums.chunks_exact_mut(width).enumerate() {
                for (sum, b) in sums.iter_mut().zip(blended(3 * D + c)) {
                    *sum = b;
                }
                for j in 0..D {
                    let guide = &self.planes[j][y * width..][..width];
                    for ((sum, a), &g) in sums.iter_mut().zip(blended(c * D + j)).zip(guide) {
                        *sum += a * g as f64;
                    }
                }
            }
            let out = &mut self.out[(y - self.first_row) * width..][..width];
            let (red, rest) = self.sums.split_at(width);
            let (green, blue) = rest.split_at(width);
            let finite = |v: f64| v.clamp(-(f32::MAX as f64), f32::MAX as f64) as f32;
            for (((pixel, &r), &g), &b) in out.iter_mut().zip(red).zip(green).zip(blue) {
                *pixel = [finite(r), finite(g), finite(b)];
            }
            self.next_row += 1;
        }
    }
}

impl<const D: usize, const Q: usize> CoefficientSink<D, Q> for Upsample<'_, D, Q> {
    #[inline(always)]
    fn block(&mut self, _: usize, x0: usize, _: usize, sums: &[f64], at: usize, scale: &Lanes) {
        for (q, row) in self.low.chunks_exact_mut(self.low_padded).enumerate() {
            for ((mean, &sum), &scale) in
                row[x0..x0 + LANES].iter_mut().zip(&sums[q * CHUNK + at..][..LANES]).zip(scale)
            {
                *mean = (sum * scale) as f32;
            }
        }
    }

    #[inline(always)]
    fn row_done(&mut self, y: usize) {
        std::mem::swap(&mut self.previous, &mut self.current);
        for (up, low) in self.current.chunks_exact_mut(self.width).zip(self.low.chunks_exact(self.low_padded)) {
            self.columns.upsample(low, up);
        }
        if self.have_previous {
            self.emit(y - 1, true);
        }
        if y + 1 == self.low_height {
            self.emit(y, false);
        }
        self.have_previous = true;
    }
}

/// 1 / (pixels in the window) for the LANES columns from x0 on, in a row whose window has
/// 1 / `inverse_rows` rows.
#[inline(always)]
fn scale_block<const D: usize, R>(context: &Context<D, R>, x0: usize, inverse_rows: f64) -> Lanes {
    let mut scale = [0.0; LANES];
    for (s, c) in scale.iter_mut().zip(&context.inverse_columns[x0..x0 + LANES]) {
        *s = c * inverse_rows;
    }
    scale
}

/// Stage 1 for the LANES windows from x0 on: `window_coefficients` per lane, from the moment
/// sums (`sums`: term-major rows of `CHUNK`, layout of `moment_count`, this block's at `at`)
/// times `scale` (1 / pixels in the window), written as f32 to `out` (Q rows of
/// `grid.padded()`, at x0). Returns which lanes fell back. The loop over the lanes has a
/// branch-free body whose inner loops all have constant bounds (so they unroll completely),
/// which lets the compiler run the lanes in SIMD.
#[inline(always)]
fn coefficient_block<const D: usize, const M: usize, const Q: usize>(
    sums: &[f64],
    at: usize,
    x0: usize,
    scale: &Lanes,
    context: &Context<D, impl Sized>,
    out: &mut [f32],
) -> [bool; LANES] {
    let padded = context.grid.padded();
    let mut block = [[0.0f64; LANES]; M];
    for (k, block) in block.iter_mut().enumerate() {
        let sums = &sums[k * CHUNK + at..][..LANES];
        for l in 0..LANES {
            block[l] = sums[l] * scale[l];
        }
    }
    let mut result = [[0.0f32; LANES]; Q];
    let mut fell_back = [false; LANES];
    for l in 0..LANES {
        let mut means = [0.0f64; M];
        for k in 0..M {
            means[k] = block[k][l];
        }
        let (values, ok) = window_coefficients::<D, M, Q>(&means, &context.eps, context.min_pivot);
        for q in 0..Q {
            result[q][l] = values[q];
        }
        fell_back[l] = !ok;
    }
    for (row, result) in out.chunks_exact_mut(padded).zip(&result) {
        row[x0..x0 + LANES].copy_from_slice(result);
    }
    fell_back
}

/// Eq. 8–9 for one window from its moments (layout of `moment_count`): per colour channel c,
/// `a_c = (Σ + diag ε)⁻¹ (E[N_c I] − E[N_c] E[I])` and `b_c = E[N_c] − a_cᵀ E[I]`, solved by the
/// square-root-free Cholesky factorisation `Σ + diag ε = L D Lᵀ` (L unit lower triangular;
/// without square roots the dependency chain per column is one division). Returns a_c (at
/// c d + j) and b_c (at 3d + c) in f32, and true; or, when a pivot falls below `min_pivot` (or
/// is not a number) or a coefficient is not finite in f32, a = 0, b = E[N] (the box mean, the
/// ε → ∞ limit) and false. Branch-free: a failed window goes on with pivot 1 and its results
/// are replaced at the end. Loops run over all of 0..D with conditions inside, so that their
/// bounds are constants.
#[inline(always)]
#[allow(clippy::needless_range_loop)]
fn window_coefficients<const D: usize, const M: usize, const Q: usize>(
    moments: &[f64; M],
    eps: &[f64; D],
    min_pivot: f64,
) -> ([f32; Q], bool) {
    let mut mean_i = [0.0f64; D];
    mean_i.copy_from_slice(&moments[..D]);
    // Σ + diag ε; only the lower triangle (row ≥ column) is used, and becomes L.
    let mut matrix = [[0.0f64; D]; D];
    let mut slot = D;
    for j in 0..D {
        for k in 0..D {
            if k >= j {
                matrix[k][j] = moments[slot] - mean_i[j] * mean_i[k];
                slot += 1;
            }
        }
    }
    for j in 0..D {
        matrix[j][j] = matrix[j][j].max(0.0) + eps[j];
    }
    let mean_n = [moments[slot], moments[slot + 1], moments[slot + 2]];
    slot += 3;
    let mut a = [[0.0f64; D]; 3];
    for c in 0..3 {
        for j in 0..D {
            a[c][j] = moments[slot + c * D + j] - mean_i[j] * mean_n[c];
        }
    }

    let mut ok = true;
    let mut pivots = [0.0f64; D];
    let mut inverse = [0.0f64; D];
    for j in 0..D {
        // L_jk D_k for k < j: row j of L D, shared by the pivot and the column below it.
        let mut scaled = [0.0f64; D];
        for k in 0..D {
            if k < j {
                scaled[k] = matrix[j][k] * pivots[k];
            }
        }
        let mut pivot = matrix[j][j];
        for k in 0..D {
            if k < j {
                pivot -= matrix[j][k] * scaled[k];
            }
        }
        ok &= pivot >= min_pivot;
        pivots[j] = if pivot >= min_pivot { pivot } else { 1.0 };
        inverse[j] = 1.0 / pivots[j];
        for i in 0..D {
            if i > j {
                let mut v = matrix[i][j];
                for k in 0..D {
                    if k < j {
                        v -= matrix[i][k] * scaled[k];
                    }
                }
                matrix[i][j] = v * inverse[j];
            }
        }
    }
    for x in a.iter_mut() {
        // L y = rhs, then Lᵀ x = D⁻¹ y.
        for i in 0..D {
            for k in 0..D {
                if k < i {
                    x[i] -= matrix[i][k] * x[k];
                }
            }
        }
        for i in (0..D).rev() {
            let mut v = x[i] * inverse[i];
            for k in 0..D {
                if k > i {
                    v -= matrix[k][i] * x[k];
                }
            }
            x[i] = v;
        }
    }
    let mut b = mean_n;
    for c in 0..3 {
        for j in 0..D {
            b[c] -= a[c][j] * mean_i[j];
        }
    }
    let mut values = [0.0f32; Q];
    for c in 0..3 {
        for j in 0..D {
            values[c * D + j] = a[c][j] as f32;
        }
        values[3 * D + c] = b[c] as f32;
    }
    // v · 0 is 0 for finite v and NaN otherwise: one test for all 3d + 3 values.
    let mut poison = 0.0f32;
    for v in values {
        poison += v * 0.0;
    }
    let ok = ok & (poison == 0.0);
    for q in 0..Q {
        let fallback = if q < 3 * D { 0.0 } else { mean_n[q - 3 * D] as f32 };
        values[q] = if ok { values[q] } else { fallback };
    }
    (values, ok)
}

/// Stage 2 for the LANES pixels of a block: `F_c = (Σ_j S[a_cj] I_j + S[b_c]) · scale` from the
/// coefficient sums (`sums`: Q rows of `CHUNK`, this block's at `at`) and the guide `g`.
#[inline(always)]
fn evaluate<const D: usize, const Q: usize>(
    sums: &[f64],
    at: usize,
    scale: &Lanes,
    g: &[Lanes; D],
) -> [[f32; LANES]; 3] {
    let mut block = [[0.0f64; LANES]; Q];
    for (q, block) in block.iter_mut().enumerate() {
        block.copy_from_slice(&sums[q * CHUNK + at..][..LANES]);
    }
    let mut f = [[0.0f32; LANES]; 3];
    for l in 0..LANES {
        for c in 0..3 {
            let mut v = block[3 * D + c][l];
            for j in 0..D {
                v += block[c * D + j][l] * g[j][l];
            }
            f[c][l] = (v * scale[l]).clamp(-(f32::MAX as f64), f32::MAX as f64) as f32;
        }
    }
    f
}

/// Box sums of `terms` down consecutive rows of a strip: f64 column sums over the rows of the
/// current window, slid down a row at a time (add the row entering, subtract the row leaving;
/// rows are re-read from the source, products recomputed, rather than kept), then each row of
/// them summed over the horizontal window (`box_rows`). The cost per pixel does not depend on
/// the radius; a strip pays once for its first window.
struct SlidingBox<T> {
    grid: Grid,
    terms: Vec<Term>,
    /// Row length of `columns`: term k's column sums lie at `k * stride + r + 1 ..` (width
    /// values), with r + 1 zeros before them and r or more after, so that `box_rows` can read
    /// a window's columns past the image's edges.
    stride: usize,
    columns: Vec<f64>,
    /// The window sums of the current chunk of the row: rows of `CHUNK`.
    sums: Vec<f64>,
    /// The running window sums along the row, per row of `columns`.
    carry: Vec<f64>,
    entering: Vec<T>,
    leaving: Vec<T>,
    /// The row whose window `columns` holds.
    row: Option<usize>,
}

impl<T: Copy + Default + Into<f64>> SlidingBox<T> {
    fn new(grid: Grid, terms: Vec<Term>, source_rows: usize) -> Self {
        let padded = grid.padded();
        let stride = padded + 2 * grid.radius + 1;
        // Whole groups of `SCAN_ROWS` rows for `box_rows`; the rows past the terms stay zero.
        let rows = terms.len().div_ceil(SCAN_ROWS) * SCAN_ROWS;
        SlidingBox {
            grid,
            stride,
            columns: vec![0.0; rows * stride],
            sums: vec![0.0; rows * CHUNK],
            carry: vec![0.0; rows],
            entering: vec![T::default(); source_rows * padded],
            leaving: vec![T::default(); source_rows * padded],
            terms,
            row: None,
        }
    }

    /// Moves the column sums to row y's window (y is the row after the previous call's, or the
    /// first) and calls `f(start, sums)` for the chunks of the row from left to right: `sums`
    /// holds the (unscaled) window sums of pixels start.. (`CHUNK` of them, fewer at the end),
    /// term-major rows of `CHUNK`. The column sums are updated chunk by chunk just ahead of the
    /// horizontal sums that read them, and a chunk's sums are used at once, so both are still
    /// in the L1 cache.
    #[inline(always)]
    fn row<S: RowSource<Value = T>>(&mut self, source: &S, y: usize, mut f: impl FnMut(usize, &[f64])) {
        let Grid { width, height, radius } = self.grid;
        let layout = Columns { padded: self.grid.padded(), stride: self.stride, offset: radius + 1 };
        let (mut enter, mut leave) = (None, None);
        match self.row {
            None => {
                for k in y.saturating_sub(radius)..=(y + radius).min(height - 1) {
                    let row = Some(source.row(k, &mut self.entering));
                    update_columns(&mut self.columns, layout, &self.terms, row, None, 0..width);
                }
            }
            Some(previous) => {
                debug_assert_eq!(previous + 1, y);
                enter = (y + radius < height).then(|| source.row(y + radius, &mut self.entering));
                leave = (y > radius).then(|| source.row(y - radius - 1, &mut self.leaving));
            }
        }
        self.row = Some(y);
        let chunk = |c: usize| c * CHUNK..((c + 1) * CHUNK).min(width);
        let chunks = width.div_ceil(CHUNK);
        // Chunk c's window sums reach r columns into the chunks after it.
        let ahead = radius.div_ceil(CHUNK);
        let mut updated = 0;
        for c in 0..chunks {
            while updated < chunks && updated <= c + ahead {
                update_columns(&mut self.columns, layout, &self.terms, enter, leave, chunk(updated));
                updated += 1;
            }
            if c == 0 {
                // The window sum before pixel 0: columns 0..r.
                for (carry, column) in self.carry.iter_mut().zip(self.columns.chunks_exact(self.stride)) {
                    *carry = column[radius + 1..][..radius.min(width)].iter().sum();
                }
            }
            box_rows(&self.columns, self.stride, chunk(c), radius, &mut self.sums, &mut self.carry);
            f(c * CHUNK, &self.sums);
        }
    }
}

/// Where `update_columns` finds things: source rows `padded` apart, column sums `stride` apart
/// from `offset` on.
#[derive(Clone, Copy)]
struct Columns {
    padded: usize,
    stride: usize,
    offset: usize,
}

/// Adds the terms of the `enter` rows to the column sums and subtracts those of the `leave`
/// rows, for the columns `pixels`; the products of two f32 values are exact in f64.
#[inline(always)]
fn update_columns<'a, T: Copy + Into<f64>>(
    columns: &mut [f64],
    layout: Columns,
    terms: &[Term],
    enter: Option<&'a [T]>,
    leave: Option<&'a [T]>,
    pixels: std::ops::Range<usize>,
) {
    fn product<'a, T: Copy + Into<f64>>(p: &'a [T], q: &'a [T]) -> impl Iterator<Item = f64> + 'a {
        p.iter().zip(q).map(|(&p, &q)| p.into() * q.into())
    }
    let Columns { padded, stride, offset } = layout;
    let (start, len) = (pixels.start, pixels.len());
    let slice = |rows: Option<&'a [T]>, k: usize| rows.map(|rows| &rows[k * padded + start..][..len]);
    for (column, &(p, q)) in columns.chunks_exact_mut(stride).zip(terms) {
        let column = &mut column[offset + start..][..len];
        match (slice(enter, p), q.and_then(|q| slice(enter, q)), slice(leave, p), q.and_then(|q| slice(leave, q))) {
            (Some(ep), Some(eq), Some(lp), Some(lq)) => {
                for ((c, e), l) in column.iter_mut().zip(product(ep, eq)).zip(product(lp, lq)) {
                    *c += e - l;
                }
            }
            (Some(ep), None, Some(lp), None) => {
                for ((c, &e), &l) in column.iter_mut().zip(ep).zip(lp) {
                    *c += e.into() - l.into();
                }
            }
            (Some(ep), Some(eq), None, None) => {
                for (c, e) in column.iter_mut().zip(product(ep, eq)) {
                    *c += e;
                }
            }
            (Some(ep), None, None, None) => {
                for (c, &e) in column.iter_mut().zip(ep) {
                    *c += e.into();
                }
            }
            (None, None, Some(lp), Some(lq)) => {
                for (c, l) in column.iter_mut().zip(product(lp, lq)) {
                    *c -= l;
                }
            }
            (None, None, Some(lp), None) => {
                for (c, &l) in column.iter_mut().zip(lp) {
                    *c -= l.into();
                }
            }
            _ => {}
        }
    }
}

/// Sums each row of `columns` over the horizontal window clipped to the image, for the pixels
/// `pixels`: `sums[x − start] = Σ columns[x − r ..= x + r]` (rows of `CHUNK` in `sums`; in
/// `columns`, rows of `stride` with the column sums at r + 1 .., zeros around them), as a
/// running sum along the row (`carry`, per row: the sum at the pixel before) that takes one
/// step per pixel, the column entering minus the column leaving. Four rows at a time, so that
/// the adds do not wait on each other (the arrays hold whole groups of rows).
#[inline(always)]
fn box_rows(
    columns: &[f64],
    stride: usize,
    pixels: std::ops::Range<usize>,
    radius: usize,
    sums: &mut [f64],
    carry: &mut [f64],
) {
    let (start, len) = (pixels.start, pixels.len());
    for ((columns, sums), carry) in columns
        .chunks_exact(SCAN_ROWS * stride)
        .zip(sums.chunks_exact_mut(SCAN_ROWS * CHUNK))
        .zip(carry.chunks_exact_mut(SCAN_ROWS))
    {
        let column = |k: usize| &columns[k * stride..][..stride];
        // Pixel x gains column x + r (at x + 2r + 1) and loses column x − r − 1 (at x).
        let enter = |k: usize| column(k)[start + 2 * radius + 1..][..len].iter();
        let leave = |k: usize| column(k)[start..][..len].iter();
        let mut rows = sums.chunks_exact_mut(CHUNK).map(|row| row[..len].iter_mut());
        let mut row = || rows.next().unwrap();
        let (o0, o1, o2, o3) = (row(), row(), row(), row());
        let mut s = [carry[0], carry[1], carry[2], carry[3]];
        for ((((o0, o1), (o2, o3)), ((e0, e1), (e2, e3))), ((l0, l1), (l2, l3))) in o0
            .zip(o1)
            .zip(o2.zip(o3))
            .zip(enter(0).zip(enter(1)).zip(enter(2).zip(enter(3))))
            .zip(leave(0).zip(leave(1)).zip(leave(2).zip(leave(3))))
        {
            s = [s[0] + (e0 - l0), s[1] + (e1 - l1), s[2] + (e2 - l2), s[3] + (e3 - l3)];
            (*o0, *o1, *o2, *o3) = (s[0], s[1], s[2], s[3]);
        }
        carry.copy_from_slice(&s);
    }
}

#[cfg(test)]
// The reference computations index like the formulas they spell out.
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;
    use crate::lcg::Lcg;
    use std::time::Instant;

    fn random_image(width: u32, height: u32, rng: &mut Lcg) -> Image {
        let pixels =
            (0..width * height).map(|_| [rng.uniform(), rng.uniform() * 2.0, rng.uniform() * 0.5 + 3.0]).collect();
        Image::from_pixels(width, height, pixels)
    }

    fn random_planes(d: usize, count: usize, rng: &mut Lcg) -> Vec<Vec<f32>> {
        (0..d).map(|_| (0..count).map(|_| rng.uniform()).collect()).collect()
    }

    fn flat_guide(width: u32, height: u32, normal: [f32; 3], depth: f32) -> GuideBuffers {
        let count = (width * height) as usize;
        GuideBuffers {
            width,
            height,
            normal: vec![normal; count],
            depth: vec![depth; count],
            position: vec![[0.0; 3]; count],
            secondary_normal: None,
        }
    }

    /// Gaussian elimination with partial pivoting (independent of the Cholesky under test).
    fn gauss_solve(mut a: Vec<Vec<f64>>, mut b: Vec<f64>) -> Vec<f64> {
        let n = b.len();
        for col in 0..n {
            let pivot = (col..n).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs())).unwrap();
            a.swap(col, pivot);
            b.swap(col, pivot);
            for row in col + 1..n {
                let factor = a[row][col] / a[col][col];
                for k in col..n {
                    a[row][k] -= factor * a[col][k];
                }
                b[row] -= factor * b[col];
            }
        }
        let mut x = vec![0.0; n];
        for row in (0..n).rev() {
            let s: f64 = (row + 1..n).map(|k| a[row][k] * x[k]).sum();
            x[row] = (b[row] - s) / a[row][row];
        }
        x
    }

    /// Pixels of the window of radius `r` around (x, y), clipped to the image.
    fn window(x: usize, y: usize, r: usize, width: usize, height: usize) -> Vec<usize> {
        let mut pixels = Vec::new();
        for wy in y.saturating_sub(r)..=(y + r).min(height - 1) {
            for wx in x.saturating_sub(r)..=(x + r).min(width - 1) {
                pixels.push(wy * width + wx);
            }
        }
        pixels
    }

    /// a (d × 3) and b (3) of the regression of `noisy` on `planes` over `pixels`, with
    /// centred two-pass (co)variances and Gaussian elimination.
    fn naive_regression(
        noisy: &Image,
        planes: &[Vec<f32>],
        eps: &[f32],
        pixels: &[usize],
    ) -> (Vec<[f64; 3]>, [f64; 3]) {
        let d = planes.len();
        let n = pixels.len() as f64;
        let mean_i: Vec<f64> = planes.iter().map(|p| pixels.iter().map(|&i| p[i] as f64).sum::<f64>() / n).collect();
        let mean_n: Vec<f64> =
            (0..3).map(|c| pixels.iter().map(|&i| noisy.pixels[i][c] as f64).sum::<f64>() / n).collect();
        let mut matrix = vec![vec![0.0; d]; d];
        for j in 0..d {
            for k in 0..d {
                matrix[j][k] = pixels
                    .iter()
                    .map(|&i| (planes[j][i] as f64 - mean_i[j]) * (planes[k][i] as f64 - mean_i[k]))
                    .sum::<f64>()
                    / n;
            }
            matrix[j][j] += eps[j] as f64;
        }
        let mut a = vec![[0.0; 3]; d];
        let mut b = [0.0; 3];
        for c in 0..3 {
            let cov: Vec<f64> = (0..d)
                .map(|j| {
                    pixels
                        .iter()
                        .map(|&i| (planes[j][i] as f64 - mean_i[j]) * (noisy.pixels[i][c] as f64 - mean_n[c]))
                        .sum::<f64>()
                        / n
                })
                .collect();
            let x = gauss_solve(matrix.clone(), cov);
            for j in 0..d {
                a[j][c] = x[j];
            }
            b[c] = mean_n[c] - (0..d).map(|j| x[j] * mean_i[j]).sum::<f64>();
        }
        (a, b)
    }

    /// The guided filter by its definition: per-window regression, then the explicit average
    /// of a_kᵀ I_i + b_k over the windows containing each pixel.
    fn naive_filter(noisy: &Image, planes: &[Vec<f32>], eps: &[f32], r: usize) -> Vec<[f64; 3]> {
        let (width, height) = (noisy.width as usize, noisy.height as usize);
        let d = planes.len();
        let coefficients: Vec<_> = (0..width * height)
            .map(|k| naive_regression(noisy, planes, eps, &window(k % width, k / width, r, width, height)))
            .collect();
        (0..width * height)
            .map(|i| {
                let windows = window(i % width, i / width, r, width, height);
                let mut f = [0.0; 3];
                for &k in &windows {
                    let (a, b) = &coefficients[k];
                    for c in 0..3 {
                        f[c] += b[c] + (0..d).map(|j| a[j][c] * planes[j][i] as f64).sum::<f64>();
                    }
                }
                f.map(|v| v / windows.len() as f64)
            })
            .collect()
    }

    /// The fast guided filter (He and Sun 2015) by its definition: block means of the input and
    /// the guide, the per-window regression on them with radius r / s, the explicit average of
    /// a_k and b_k over the windows containing each subsampled pixel, then a and b bilinearly
    /// interpolated at each pixel's position (clamped to the subsampled image) and applied to the
    /// full-resolution guide.
    fn naive_subsampled(noisy: &Image, planes: &[Vec<f32>], eps: &[f32], r: usize, s: usize) -> Vec<[f64; 3]> {
        let (width, height) = (noisy.width as usize, noisy.height as usize);
        let (low_width, low_height) = (width.div_ceil(s), height.div_ceil(s));
        let block = |i: usize, j: usize| -> Vec<usize> {
            let xs = i * s..((i + 1) * s).min(width);
            (j * s..((j + 1) * s).min(height)).flat_map(|y| xs.clone().map(move |x| y * width + x)).collect()
        };
        let low_count = low_width * low_height;
        let mean_of = |value: &dyn Fn(usize) -> f64, k: usize| {
            let pixels = block(k % low_width, k / low_width);
            (pixels.iter().map(|&p| value(p)).sum::<f64>() / pixels.len() as f64) as f32
        };
        let low_planes: Vec<Vec<f32>> =
            planes.iter().map(|plane| (0..low_count).map(|k| mean_of(&|p| plane[p] as f64, k)).collect()).collect();
        let low_pixels =
            (0..low_count).map(|k| [0, 1, 2].map(|c| mean_of(&|p| noisy.pixels[p][c] as f64, k))).collect();
        let low_noisy = Image::from_pixels(low_width as u32, low_height as u32, low_pixels);
        let low_radius = ((r + s / 2) / s).max(1);
        let d = planes.len();
        let fitted: Vec<_> = (0..low_count)
            .map(|k| {
                let window = window(k % low_width, k / low_width, low_radius, low_width, low_height);
                naive_regression(&low_noisy, &low_planes, eps, &window)
            })
            .collect();
        // Per subsampled pixel: a (d × 3) then b (3), averaged over the windows containing it.
        let averaged: Vec<Vec<f64>> = (0..low_count)
            .map(|i| {
                let windows = window(i % low_width, i / low_width, low_radius, low_width, low_height);
                let mut sum = vec![0.0; 3 * d + 3];
                for &k in &windows {
                    let (a, b) = &fitted[k];
                    for c in 0..3 {
                        for j in 0..d {
                            sum[c * d + j] += a[j][c];
                        }
                        sum[3 * d + c] += b[c];
                    }
                }
                sum.iter().map(|v| v / windows.len() as f64).collect()
            })
            .collect();
        let neighbours = |x: usize, n: usize| {
            let u = ((x as f64 + 0.5) / s as f64 - 0.5).clamp(0.0, (n - 1) as f64);
            let below = (u.floor() as usize).min(n - 1);
            (below, (below + 1).min(n - 1), u - below as f64)
        };
        (0..width * height)
            .map(|p| {
                let ((x0, x1, wx), (y0, y1, wy)) =
                    (neighbours(p % width, low_width), neighbours(p / width, low_height));
                let at = |q: usize| {
                    let row =
                        |y: usize| (1.0 - wx) * averaged[y * low_width + x0][q] + wx * averaged[y * low_width + x1][q];
                    (1.0 - wy) * row(y0) + wy * row(y1)
                };
                [0, 1, 2].map(|c| at(3 * d + c) + (0..d).map(|j| at(c * d + j) * planes[j][p] as f64).sum::<f64>())
            })
            .collect()
    }

    fn assert_close(found: &Image, expected: &[[f64; 3]], tolerance: f64, what: &str) {
        assert_eq!(found.pixels.len(), expected.len());
        for (i, (f, e)) in found.pixels.iter().zip(expected).enumerate() {
            for c in 0..3 {
                let error = (f[c] as f64 - e[c]).abs();
                assert!(error <= tolerance * (1.0 + e[c].abs()), "{what}: pixel {i} channel {c}: {} vs {}", f[c], e[c]);
            }
        }
    }

    fn in_pool<R: Send>(threads: usize, job: impl FnOnce() -> R + Send) -> R {
        rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(job)
    }

    #[test]
    fn matches_naive_per_window_definition() {
        let mut rng = Lcg(1);
        let (width, height) = (23, 17);
        let noisy = random_image(width, height, &mut rng);
        let planes = random_planes(4, (width * height) as usize, &mut rng);
        let eps = [0.01, 0.02, 0.005, 0.03];
        for radius in [0u32, 1, 3, 30] {
            let expected = naive_filter(&noisy, &planes, &eps, radius as usize);
            // The thread count does not change the strips (`same_bits_for_any_thread_count`).
            for threads in [1, 2, 5, 17] {
                let (found, report) = in_pool(threads, || guided_filter_planes(&noisy, &planes, &eps, radius).unwrap());
                assert_eq!(report, FilterReport::default());
                assert_close(&found, &expected, 1e-4, &format!("radius {radius}, {threads} threads"));
            }
        }
        // Fewer guide channels go through the other monomorphisations.
        for d in 1..=3 {
            let expected = naive_filter(&noisy, &planes[..d], &eps[..d], 2);
            let (found, _) = guided_filter_planes(&noisy, &planes[..d], &eps[..d], 2).unwrap();
            assert_close(&found, &expected, 1e-4, &format!("d = {d}"));
        }
    }

    #[test]
    fn subsampled_matches_its_definition() {
        // Sizes that s divides and sizes it does not (partial blocks at the right and bottom),
        // an image a single block tall, windows larger than the subsampled image; s = 2, 3, 4
        // (the upsampling's unrolled loops) and 5 (its general one).
        let cases =
            [(13u32, 11u32, 2usize, 3u32), (16, 9, 3, 4), (7, 20, 2, 2), (10, 2, 2, 5), (9, 9, 4, 40), (31, 12, 5, 9)];
        let mut rng = Lcg(21);
        for (width, height, s, radius) in cases {
            let noisy = random_image(width, height, &mut rng);
            for d in [1usize, 3, 4] {
                let planes = random_planes(d, (width * height) as usize, &mut rng);
                let eps = &[0.01, 0.02, 0.005, 0.03][..d];
                let expected = naive_subsampled(&noisy, &planes, eps, radius as usize, s);
                let run = || guided_filter_planes_subsampled(&noisy, &planes, eps, radius, s as u32).unwrap();
                let (one, report) = in_pool(1, run);
                let what = format!("{width}x{height}, s = {s}, radius {radius}, d = {d}");
                assert_eq!(report, FilterReport::default(), "{what}");
                assert_close(&one, &expected, 1e-4, &what);
                let (many, _) = in_pool(3, run);
                assert!(one == many, "{what}: threads change the result");
            }
        }
    }

    #[test]
    fn subsampled_strips_give_the_same_bits_for_any_thread_count() {
        // Tall enough that the subsampled image is cut into strips, whose boundaries need the
        // row past each strip for the bilinear blend.
        let mut rng = Lcg(22);
        let (width, height) = (11u32, 700u32);
        let noisy = random_image(width, height, &mut rng);
        let planes = random_planes(4, (width * height) as usize, &mut rng);
        let eps = [0.01, 0.02, 0.005, 0.03];
        let low = Grid { width: 6, height: 350, radius: 3 };
        assert!(low.strip_rows() < 350, "one strip");
        let run = || guided_filter_planes_subsampled(&noisy, &planes, &eps, 6, 2).unwrap();
        let (one, _) = in_pool(1, run);
        for threads in [2, 5] {
            assert!(one == in_pool(threads, run).0, "{threads} threads");
        }
        assert_close(&one, &naive_subsampled(&noisy, &planes, &eps, 6, 2), 1e-4, "strips");
    }

    #[test]
    fn same_bits_for_any_thread_count() {
        // Tall enough for several strips, which then run on different threads; the strips'
        // boundaries (coefficient rows computed by both neighbours) match the definition.
        let mut rng = Lcg(14);
        let (width, height) = (9u32, 1100u32);
        let noisy = random_image(width, height, &mut rng);
        let planes = random_planes(4, (width * height) as usize, &mut rng);
        let eps = [0.01, 0.02, 0.005, 0.03];
        let bits = |image: &Image| -> Vec<[u32; 3]> { image.pixels.iter().map(|p| p.map(f32::to_bits)).collect() };
        for radius in [3u32, 40] {
            let grid = Grid { width: width as usize, height: height as usize, radius: radius as usize };
            assert!(grid.strip_rows() < height as usize, "radius {radius}: one strip");
            let (one, report) = in_pool(1, || guided_filter_planes(&noisy, &planes, &eps, radius).unwrap());
            for threads in [2, 3, 8] {
                let (many, many_report) =
                    in_pool(threads, || guided_filter_planes(&noisy, &planes, &eps, radius).unwrap());
                assert!(bits(&one) == bits(&many), "radius {radius}, {threads} threads");
                assert_eq!(report, many_report);
            }
            let expected = naive_filter(&noisy, &planes, &eps, radius as usize);
            assert_close(&one, &expected, 1e-4, &format!("strips, radius {radius}"));
        }
    }

    #[test]
    fn constant_guide_gives_the_box_mean() {
        let mut rng = Lcg(2);
        let (width, height) = (19u32, 13u32);
        let noisy = random_image(width, height, &mut rng);
        let guide = flat_guide(width, height, [0.0, 0.0, 1.0], 3.0);
        for guide_kind in [GuideKind::GreyNormal, GuideKind::Normal, GuideKind::NormalDepth] {
            for radius in [0u32, 2, 5, 40] {
                let params = GuidedFilterParams { radius, guide: guide_kind, ..Default::default() };
                let (found, _) = guided_filter(&noisy, &guide, &params).unwrap();
                let expected: Vec<[f64; 3]> = (0..(width * height) as usize)
                    .map(|i| {
                        let pixels = window(i % width as usize, i / width as usize, radius as usize, 19, 13);
                        let mut sum = [0.0f64; 3];
                        for &p in &pixels {
                            for c in 0..3 {
                                sum[c] += noisy.pixels[p][c] as f64;
                            }
                        }
                        sum.map(|s| s / pixels.len() as f64)
                    })
                    .collect();
                // The box mean of the box mean of N when a = 0: compare with the explicit one.
                let twice: Vec<[f64; 3]> = (0..(width * height) as usize)
                    .map(|i| {
                        let windows = window(i % width as usize, i / width as usize, radius as usize, 19, 13);
                        let mut sum = [0.0f64; 3];
                        for &k in &windows {
                            for c in 0..3 {
                                sum[c] += expected[k][c];
                            }
                        }
                        sum.map(|s| s / windows.len() as f64)
                    })
                    .collect();
                assert_close(&found, &twice, 1e-5, &format!("{guide_kind:?} radius {radius}"));
                if radius == 0 {
                    assert_close(&found, &expected, 1e-6, "radius 0 returns the input");
                }
            }
        }
    }

    fn step_scene(rng: &mut Lcg) -> (Image, GuideBuffers) {
        let (width, height) = (32u32, 32u32);
        let mut guide = flat_guide(width, height, [0.0, 0.0, 1.0], 2.0);
        let mut noisy = Image::new(width, height);
        for y in 0..height {
            for x in 0..width {
                let i = (y * width + x) as usize;
                let base = if x < 16 { 1.0 } else { 5.0 };
                if x >= 16 {
                    guide.depth[i] = 10.0;
                }
                noisy.pixels[i] = [0; 3].map(|_| base + (rng.uniform() - 0.5) * 0.8);
            }
        }
        (noisy, guide)
    }

    /// Worst and mean absolute error against the clean step over the columns whose windows
    /// reach across it (x in 10..22 for radius 6).
    fn step_errors(image: &Image) -> (f64, f64) {
        let (mut worst, mut sum, mut n) = (0.0f64, 0.0f64, 0.0f64);
        for y in 0..32usize {
            for x in 10..22usize {
                let truth = if x < 16 { 1.0 } else { 5.0 };
                for c in 0..3 {
                    let error = (image.pixels[y * 32 + x][c] as f64 - truth).abs();
                    (worst, sum, n) = (worst.max(error), sum + error, n + 1.0);
                }
            }
        }
        (worst, sum / n)
    }

    #[test]
    fn subsampled_constant_and_rank_deficient_guides_stay_finite() {
        // A flat wall (Σ = 0) and two identical channels (Σ singular) with s = 2: the solve's
        // ε keeps both well posed; the result matches the definition and stays finite.
        let mut rng = Lcg(25);
        let noisy = random_image(14, 9, &mut rng);
        let flat = vec![vec![0.5f32; 126]; 4];
        let plane = random_planes(1, 126, &mut rng).remove(0);
        let twins = vec![plane.clone(), plane];
        for (planes, eps) in [(flat, vec![0.01; 4]), (twins, vec![0.01, 0.02])] {
            let (found, _) = guided_filter_planes_subsampled(&noisy, &planes, &eps, 3, 2).unwrap();
            assert_eq!(found.nonfinite_pixels(), 0);
            assert_close(&found, &naive_subsampled(&noisy, &planes, &eps, 3, 2), 1e-4, "degenerate guide, s = 2");
        }
    }

    #[test]
    fn subsampled_keeps_a_depth_step() {
        // A depth step (a silhouette) on a block boundary (x = 16) and inside a block (x = 17,
        // whose block mean mixes the two surfaces): the fast filter fits its coefficients on
        // block means but applies them to the full-resolution guide, so the step stays sharp.
        let mut rng = Lcg(24);
        for step in [16usize, 17] {
            let (width, height) = (32u32, 32u32);
            let mut guide = flat_guide(width, height, [0.0, 0.0, 1.0], 2.0);
            let mut noisy = Image::new(width, height);
            let truth = |x: usize| if x < step { 1.0f32 } else { 5.0 };
            for i in 0..(width * height) as usize {
                if i % 32 >= step {
                    guide.depth[i] = 10.0;
                }
                noisy.pixels[i] = [0; 3].map(|_| truth(i % 32) + (rng.uniform() - 0.5) * 0.8);
            }
            let errors = |image: &Image| {
                let (mut worst, mut sum) = (0.0f64, 0.0f64);
                let columns = step - 6..step + 6;
                for i in (0..32 * 32).filter(|i| columns.contains(&(i % 32))) {
                    for c in 0..3 {
                        let error = (image.pixels[i][c] as f64 - truth(i % 32) as f64).abs();
                        (worst, sum) = (worst.max(error), sum + error);
                    }
                }
                (worst, sum / (32 * 12 * 3) as f64)
            };
            let exact = GuidedFilterParams { radius: 6, ..Default::default() };
            let flat = flat_guide(width, height, [0.0, 0.0, 1.0], 2.0);
            let (box_worst, box_mean) = errors(&guided_filter(&noisy, &flat, &exact).unwrap().0);
            let (exact_worst, exact_mean) = errors(&guided_filter(&noisy, &guide, &exact).unwrap().0);
            let fast = GuidedFilterParams { subsample: 2, ..exact };
            let (worst, mean) = errors(&guided_filter(&noisy, &guide, &fast).unwrap().0);
            println!(
                "step at {step}: s = 2 worst {worst:.3} mean {mean:.3}; exact {exact_worst:.3} {exact_mean:.3}; \
                 box {box_worst:.3} {box_mean:.3}"
            );
            assert!(box_worst > 1.5, "the box filter blurs the step: {box_worst}");
            // Measured: about 0.25 of the box's worst and 0.2 of its mean error, 1.1–1.4 times
            // the exact filter's mean error (the mixed block costs most).
            assert!(worst < 0.3 * box_worst && mean < 0.25 * box_mean, "step at {step}: {worst}, {mean}");
            assert!(mean < 1.6 * exact_mean, "step at {step}: {mean} against the exact filter's {exact_mean}");
        }
    }

    #[test]
    fn depth_step_is_preserved() {
        let mut rng = Lcg(3);
        let (noisy, guide) = step_scene(&mut rng);
        let radius = 6u32;
        let boxed: Vec<[f32; 3]> = (0..32 * 32)
            .map(|i| {
                let pixels = window(i % 32, i / 32, radius as usize, 32, 32);
                std::array::from_fn(|c| {
                    (pixels.iter().map(|&p| noisy.pixels[p][c] as f64).sum::<f64>() / pixels.len() as f64) as f32
                })
            })
            .collect();
        let (box_worst, box_mean) = step_errors(&Image::from_pixels(32, 32, boxed));
        assert!(box_worst > 1.5, "the box filter blurs the step: {box_worst}");
        // The paper's ε (0.02 on depth; the step is 0.2 → 1 in scaled depth): windows reaching a
        // few pixels across the step shrink a (Var ≈ ε there), a mild halo remains.
        let params = GuidedFilterParams { radius, ..Default::default() };
        let (found, _) = guided_filter(&noisy, &guide, &params).unwrap();
        let (worst, mean) = step_errors(&found);
        println!("paper's epsilon: worst {worst:.3} mean {mean:.3}; box: worst {box_worst:.3} mean {box_mean:.3}");
        assert!(worst < 0.25 * box_worst, "worst: guided {worst} vs box {box_worst}");
        assert!(mean < 0.2 * box_mean, "mean: guided {mean} vs box {box_mean}");
        // ε sets the edge detection's accuracy: small ε keeps the step nearly exactly.
        let sharp = GuidedFilterParams { epsilon_depth: 1e-4, epsilon_normal: 1e-4, ..params };
        let (found, _) = guided_filter(&noisy, &guide, &sharp).unwrap();
        let (worst, mean) = step_errors(&found);
        println!("epsilon 1e-4: worst {worst:.3} mean {mean:.3}");
        assert!(worst < 0.1 && mean < 0.03, "small epsilon: worst {worst}, mean {mean}");
    }

    #[test]
    fn affine_input_is_reproduced() {
        let mut rng = Lcg(4);
        let (width, height) = (21u32, 18u32);
        let count = (width * height) as usize;
        let planes = random_planes(4, count, &mut rng);
        let pixels = (0..count).map(|i| [2.0 * planes[0][i] + 3.0 * planes[3][i] + 1.0; 3]).collect();
        let noisy = Image::from_pixels(width, height, pixels);
        let eps = [1e-6; 4];
        // Block means of an affine function of the guide are the same function of the guide's
        // block means, so the fast filter reproduces it too (with windows of 5 × 5 blocks or
        // more: 3 × 3 block means of a random 4-channel guide are too close to degenerate for
        // ε = 1e-6 to leave the fit at 1e-3).
        for subsample in [1u32, 2, 3] {
            for radius in [0u32, 2, 5, 100].into_iter().filter(|&r| subsample == 1 || r >= 2 * subsample) {
                let (found, _) = guided_filter_planes_subsampled(&noisy, &planes, &eps, radius, subsample).unwrap();
                for (f, n) in found.pixels.iter().zip(&noisy.pixels) {
                    for c in 0..3 {
                        assert!((f[c] - n[c]).abs() < 1e-3, "s = {subsample}, radius {radius}: {} vs {}", f[c], n[c]);
                    }
                }
            }
        }
    }

    #[test]
    fn huge_radius_is_the_global_regression() {
        let mut rng = Lcg(5);
        let (width, height) = (40u32, 27u32);
        let count = (width * height) as usize;
        let noisy = random_image(width, height, &mut rng);
        let planes = random_planes(3, count, &mut rng);
        let eps = [0.01, 0.02, 0.03];
        let everything: Vec<usize> = (0..count).collect();
        let (a, b) = naive_regression(&noisy, &planes, &eps, &everything);
        let expected: Vec<[f64; 3]> = (0..count)
            .map(|i| std::array::from_fn(|c| b[c] + (0..3).map(|j| a[j][c] * planes[j][i] as f64).sum::<f64>()))
            .collect();
        for radius in [40u32, 1000, u32::MAX] {
            let (found, _) = guided_filter_planes(&noisy, &planes, &eps, radius).unwrap();
            assert_close(&found, &expected, 1e-5, &format!("radius {radius}"));
        }
        let (found, _) = guided_filter_planes(&noisy, &planes, &eps, 8).unwrap();
        assert_eq!(found.nonfinite_pixels(), 0);
    }

    #[test]
    fn nonfinite_input_is_sanitised_and_counted() {
        let mut rng = Lcg(6);
        let mut noisy = random_image(9, 7, &mut rng);
        let mut zeroed = noisy.clone();
        noisy.pixels[3] = [f32::NAN, 1.0, f32::INFINITY];
        noisy.pixels[40] = [0.5, f32::NEG_INFINITY, 0.5];
        zeroed.pixels[3] = [0.0, 1.0, 0.0];
        zeroed.pixels[40] = [0.5, 0.0, 0.5];
        let planes = random_planes(4, 63, &mut rng);
        let eps = [0.01; 4];
        for subsample in [1, 2] {
            let (found, report) = guided_filter_planes_subsampled(&noisy, &planes, &eps, 2, subsample).unwrap();
            assert_eq!(report.sanitised_values, 3);
            assert_eq!(found.nonfinite_pixels(), 0);
            let (expected, report) = guided_filter_planes_subsampled(&zeroed, &planes, &eps, 2, subsample).unwrap();
            assert_eq!(report.sanitised_values, 0);
            assert_eq!(found, expected);
        }
    }

    #[test]
    fn subsampled_extremes_stay_finite() {
        let mut rng = Lcg(23);
        // A spike of 1e30 among values near 1, and f32::MAX: finite output, spike-free far away.
        let mut noisy = random_image(12, 10, &mut rng);
        noisy.pixels[5] = [1e30; 3];
        noisy.pixels[100] = [f32::MAX; 3];
        let planes = random_planes(4, 120, &mut rng);
        for subsample in [2u32, 3, 1000] {
            let (found, _) = guided_filter_planes_subsampled(&noisy, &planes, &[0.01; 4], 3, subsample).unwrap();
            assert_eq!(found.nonfinite_pixels(), 0, "s = {subsample}");
        }
        // 1×1 and 2×2 images with blocks larger than the image: one block, the global mean
        // regression, which for a single pixel is the pixel.
        let one = random_image(1, 1, &mut rng);
        let (found, _) =
            guided_filter_planes_subsampled(&one, &random_planes(4, 1, &mut rng), &[0.01; 4], 5, 2).unwrap();
        assert!(found.pixels[0].iter().zip(&one.pixels[0]).all(|(f, o)| (f - o).abs() < 1e-6));
        let two = random_image(2, 2, &mut rng);
        let planes = random_planes(4, 4, &mut rng);
        for subsample in [2u32, 3] {
            let (found, _) = guided_filter_planes_subsampled(&two, &planes, &[0.01; 4], 4, subsample).unwrap();
            assert_close(&found, &naive_subsampled(&two, &planes, &[0.01; 4], 4, 2), 1e-5, "2x2");
        }
        // Black stays black; s = 0 is refused.
        let black = Image::new(9, 5);
        let (found, _) =
            guided_filter_planes_subsampled(&black, &random_planes(3, 45, &mut rng), &[0.01; 3], 2, 2).unwrap();
        assert!(found.pixels.iter().flatten().all(|&v| v == 0.0));
        assert!(guided_filter_planes_subsampled(&black, &random_planes(3, 45, &mut rng), &[0.01; 3], 2, 0).is_err());
    }

    #[test]
    fn black_stays_black() {
        let mut rng = Lcg(7);
        let noisy = Image::new(11, 6);
        let planes = random_planes(4, 66, &mut rng);
        for radius in [0u32, 1, 4, 50] {
            let (found, _) = guided_filter_planes(&noisy, &planes, &[0.01; 4], radius).unwrap();
            assert!(found.pixels.iter().flatten().all(|&v| v == 0.0), "radius {radius}");
        }
    }

    #[test]
    fn tiny_images() {
        let mut rng = Lcg(8);
        let one = random_image(1, 1, &mut rng);
        for radius in [0u32, 1, 24] {
            let (found, _) = guided_filter_planes(&one, &random_planes(4, 1, &mut rng), &[0.01; 4], radius).unwrap();
            for c in 0..3 {
                assert!((found.pixels[0][c] - one.pixels[0][c]).abs() < 1e-6);
            }
        }
        let two = random_image(2, 2, &mut rng);
        let planes = random_planes(4, 4, &mut rng);
        let eps = [0.01; 4];
        for radius in [0u32, 1, 2, 24] {
            let (found, _) = guided_filter_planes(&two, &planes, &eps, radius).unwrap();
            assert_close(&found, &naive_filter(&two, &planes, &eps, radius as usize), 1e-5, "2x2");
        }
        let guide = flat_guide(1, 1, [0.0, 1.0, 0.0], 1.0);
        let (found, _) = guided_filter(&one, &guide, &GuidedFilterParams::default()).unwrap();
        assert_eq!(found.nonfinite_pixels(), 0);
        let empty = Image::new(0, 0);
        let (found, _) = guided_filter(&empty, &flat_guide(0, 0, [0.0; 3], 0.0), &Default::default()).unwrap();
        assert_eq!(found, empty);
    }

    #[test]
    fn rank_deficient_guide_stays_finite() {
        let mut rng = Lcg(9);
        let (width, height) = (24u32, 20u32);
        let mut guide = flat_guide(width, height, [0.0, 0.0, 1.0], 4.0);
        for (i, n) in guide.normal.iter_mut().enumerate() {
            // Normals in the xy plane (z = 0): the z channel and depth are constant.
            let t = (i % width as usize) as f32 * 0.2 + (i / width as usize) as f32 * 0.05;
            *n = [t.cos(), t.sin(), 0.0];
        }
        let noisy = random_image(width, height, &mut rng);
        for epsilon in [0.01f32, 1e-6, 1e-12, 1e-30] {
            let params =
                GuidedFilterParams { radius: 3, epsilon_normal: epsilon, epsilon_depth: epsilon, ..Default::default() };
            let (found, _) = guided_filter(&noisy, &guide, &params).unwrap();
            assert_eq!(found.nonfinite_pixels(), 0, "epsilon {epsilon}");
            let max = found.pixels.iter().flatten().fold(0.0f32, |m, v| m.max(v.abs()));
            assert!(max < 100.0, "epsilon {epsilon}: {max}");
        }
        // With a sane ε the result matches the definition.
        let planes = guide_channels(&guide, &GuidedFilterParams::default()).unwrap();
        let eps = GuidedFilterParams::default().epsilons();
        let (found, _) = guided_filter_planes(&noisy, &planes, &eps, 3).unwrap();
        assert_close(&found, &naive_filter(&noisy, &planes, &eps, 3), 1e-4, "rank-deficient");
        // A constant guide and a rounding-level ε: Σ is zero up to rounding, and whether a
        // window solves or falls back, a ≈ 0 and the result is the ε = 0.01 one (a box mean).
        let planes = vec![vec![0.5f32; 480]; 4];
        let (found, _) = guided_filter_planes(&noisy, &planes, &[1e-30; 4], 3).unwrap();
        let (expected, report) = guided_filter_planes(&noisy, &planes, &[0.01; 4], 3).unwrap();
        assert_eq!(report.fallback_windows, 0);
        let expected: Vec<[f64; 3]> = expected.pixels.iter().map(|p| p.map(f64::from)).collect();
        assert_close(&found, &expected, 1e-5, "constant guide, epsilon 1e-30");
    }

    #[test]
    fn fallback_when_epsilon_is_below_rounding() {
        // Two identical guide channels: Σ is singular with entries ~1/12, ε = 1e-30 is far below
        // the rounding error of the moments, so some windows must fall back to the box mean.
        let mut rng = Lcg(10);
        let plane: Vec<f32> = (0..200).map(|_| rng.uniform()).collect();
        let noisy = random_image(20, 10, &mut rng);
        let (found, report) =
            guided_filter_planes(&noisy, &[plane.clone(), plane.clone()], &[1e-30, 1e-30], 2).unwrap();
        assert_eq!(found.nonfinite_pixels(), 0);
        let max = found.pixels.iter().flatten().fold(0.0f32, |m, v| m.max(v.abs()));
        assert!(max < 100.0, "{max} after {} fallbacks", report.fallback_windows);
        assert!(report.fallback_windows > 0, "the fallback path was not exercised");
    }

    #[test]
    fn bad_arguments_are_rejected() {
        let mut rng = Lcg(11);
        let noisy = random_image(4, 3, &mut rng);
        let planes = random_planes(2, 12, &mut rng);
        for bad in [0.0f32, -0.01, f32::NAN, f32::INFINITY] {
            assert!(guided_filter_planes(&noisy, &planes, &[0.01, bad], 1).is_err(), "epsilon {bad}");
        }
        assert!(guided_filter_planes(&noisy, &planes, &[0.01], 1).is_err(), "epsilon count");
        assert!(guided_filter_planes(&noisy, &[], &[], 1).is_err(), "no channel");
        let five = random_planes(5, 12, &mut rng);
        assert!(guided_filter_planes(&noisy, &five, &[0.01; 5], 1).is_err(), "five channels");
        let short = vec![planes[0].clone(), vec![0.5; 11]];
        assert!(guided_filter_planes(&noisy, &short, &[0.01; 2], 1).is_err(), "plane size");
        let mut nan_guide = planes.clone();
        nan_guide[1][5] = f32::NAN;
        assert!(guided_filter_planes(&noisy, &nan_guide, &[0.01; 2], 1).is_err(), "non-finite guide");

        let guide = flat_guide(4, 3, [0.0, 0.0, 1.0], 1.0);
        assert!(guided_filter(&noisy, &flat_guide(3, 4, [0.0, 0.0, 1.0], 1.0), &Default::default()).is_err());
        let mut inconsistent = guide.clone();
        inconsistent.depth.pop();
        assert!(guided_filter(&noisy, &inconsistent, &Default::default()).is_err());
        let zero_eps = GuidedFilterParams { epsilon_normal: 0.0, ..Default::default() };
        assert!(guided_filter(&noisy, &guide, &zero_eps).is_err());
        let zero_extent = GuidedFilterParams { depth_extent: Some(0.0), ..Default::default() };
        assert!(guided_filter(&noisy, &guide, &zero_extent).is_err());
        assert!(guided_filter(&noisy, &guide, &GuidedFilterParams::default()).is_ok());
    }

    #[test]
    fn guide_channels_scale_to_unit_range() {
        let mut guide = flat_guide(3, 1, [0.0, 0.0, 1.0], 2.0);
        guide.normal[1] = [-1.0, 0.0, 0.0];
        guide.depth[1] = 8.0;
        guide.normal[2] = [0.0; 3]; // escaped
        guide.depth[2] = 0.0;
        let params = GuidedFilterParams::default();
        let planes = guide_channels(&guide, &params).unwrap();
        assert_eq!(planes.len(), 4);
        assert_eq!(planes[0], vec![0.5, 0.0, 0.5]);
        assert_eq!(planes[1], vec![0.5, 0.5, 0.5]);
        assert_eq!(planes[2], vec![1.0, 0.5, 0.5]);
        assert_eq!(planes[3], vec![0.25, 1.0, 1.0], "extent = the largest hit depth, escaped = 1");
        let fixed = GuidedFilterParams { depth_extent: Some(4.0), ..params };
        assert_eq!(guide_channels(&guide, &fixed).unwrap()[3], vec![0.5, 1.0, 1.0]);
        let grey = GuidedFilterParams { guide: GuideKind::GreyNormal, ..params };
        let planes = guide_channels(&guide, &grey).unwrap();
        assert_eq!(planes.len(), 1);
        assert!((planes[0][0] - 2.0 / 3.0).abs() < 1e-6 && (planes[0][1] - 1.0 / 3.0).abs() < 1e-6);
        assert_eq!(planes[0][2], 0.5);
        let normal = GuidedFilterParams { guide: GuideKind::Normal, ..params };
        assert_eq!(guide_channels(&guide, &normal).unwrap().len(), 3);
        assert_eq!(normal.epsilons(), vec![0.01; 3]);
        assert_eq!(params.epsilons(), vec![0.01, 0.01, 0.01, 0.02]);
    }

    #[test]
    fn large_image_keeps_f64_accuracy() {
        let mut rng = Lcg(12);
        let (width, height) = (2048u32, 2048u32);
        let count = (width * height) as usize;
        let pixels = (0..count).map(|_| [0; 3].map(|_| 1000.0 + (rng.uniform() - 0.5) * 2e-4)).collect();
        let noisy = Image::from_pixels(width, height, pixels);
        let planes: Vec<Vec<f32>> = (0..4)
            .map(|j| {
                (0..count)
                    .map(|i| {
                        let (x, y) = ((i % 2048) as f32, (i / 2048) as f32);
                        0.5 + 0.5 * ((x * 0.01 + y * 0.003) * (j + 1) as f32).sin()
                    })
                    .collect()
            })
            .collect();
        let start = Instant::now();
        let (found, _) = guided_filter_planes(&noisy, &planes, &[0.01, 0.01, 0.01, 0.02], 24).unwrap();
        println!("2048x2048, d = 4, radius 24: {:.0} ms", start.elapsed().as_secs_f64() * 1e3);
        let worst = found.pixels.iter().flatten().fold(0.0f64, |m, &v| m.max((v as f64 - 1000.0).abs() / 1000.0));
        println!("worst relative deviation from the mean: {worst:.2e}");
        assert!(worst < 1e-6, "relative error {worst}");
        // Tighter: an average of values within ±1e-4 of 1000 stays within that (plus an ulp of
        // 1000 in f32, 6e-5); sums in f32 would drift far beyond.
        assert!(worst * 1000.0 < 1e-4 + 6.2e-5, "absolute error {}", worst * 1000.0);
    }

    /// Table 2's setting: 1024×768, d = 1, 3, 4, radius 8 and 32. Prints, asserts nothing.
    /// `cargo test --release -p recon --lib guided_filter::tests::timing -- --ignored --nocapture`
    #[test]
    #[ignore]
    fn timing_1024x768() {
        let mut rng = Lcg(13);
        let (width, height) = (1024u32, 768u32);
        let noisy = random_image(width, height, &mut rng);
        let mut guide = flat_guide(width, height, [0.0, 0.0, 1.0], 1.0);
        for (i, (n, z)) in guide.normal.iter_mut().zip(guide.depth.iter_mut()).enumerate() {
            let t = (i % 1024) as f32 * 0.01;
            *n = [t.sin(), 0.0, t.cos()];
            *z = 1.0 + (i / 1024) as f32 * 0.01;
        }
        let all = rayon::current_num_threads();
        for threads in [1, all] {
            in_pool(threads, || {
                for kind in [GuideKind::GreyNormal, GuideKind::Normal, GuideKind::NormalDepth] {
                    for radius in [8u32, 32] {
                        let params = GuidedFilterParams { radius, guide: kind, ..Default::default() };
                        guided_filter(&noisy, &guide, &params).unwrap();
                        // The best of a few runs: the least disturbed by other load.
                        let ms = (0..5)
                            .map(|_| {
                                let start = Instant::now();
                                guided_filter(&noisy, &guide, &params).unwrap();
                                start.elapsed().as_secs_f64() * 1e3
                            })
                            .fold(f64::INFINITY, f64::min);
                        println!("1024x768 d = {} radius {radius}, {threads} threads: {ms:.1} ms", kind.channels());
                    }
                }
            });
        }
    }
}
