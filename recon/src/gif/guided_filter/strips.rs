//! Stage 1 and 2 of the filter over strips of rows: the image's grid and its strips, the
//! guide's moment terms, the rows a strip reads (the guide and input channels, or the
//! coefficient ring) and the per-window regression's driver (`filter`, `filter_strip`).

use super::*;

#[derive(Clone, Copy, Debug)]
pub(super) struct Grid {
    pub(super) width: usize,
    pub(super) height: usize,
    /// Already bounded by the image size.
    pub(super) radius: usize,
}

/// Pixels per lane block of the per-pixel work (the solve, the evaluation): written as loops over
/// `[f64; LANES]` arrays, which the compiler turns into SIMD instructions.
pub(super) const LANES: usize = 8;
pub(super) type Lanes = [f64; LANES];

/// Pixels per chunk of a row whose window sums `SlidingBox::row` hands on at once
/// (a multiple of LANES; 32 rows of them fill 32 KiB).
pub(super) const CHUNK: usize = 128;

/// Rows of box sums summed together in `box_rows`.
pub(super) const SCAN_ROWS: usize = 4;

/// Strips are at least this many rows, and at least 8 r, where the image has room for two such.
pub(super) const MIN_STRIP_ROWS: usize = 256;

/// Otherwise an image is still cut in two where each half has at least this many rows and 4 r.
pub(super) const MIN_HALF_ROWS: usize = 64;

impl Grid {
    /// Length of the per-row work arrays: the width rounded up to whole lane blocks.
    pub(super) fn padded(&self) -> usize {
        self.width.div_ceil(LANES) * LANES
    }

    /// Rows per strip. From the image and the radius only, never from the number of threads:
    /// where a strip starts decides how its sums are rounded, so a fixed split gives the same
    /// bits for any thread count. Each boundary between strips costs about 3r rows of stage 1
    /// (the r coefficient rows beyond the strip on each side, and the first window), so strips
    /// are long: at least `MIN_STRIP_ROWS` and 8r rows, and an even number of them where there
    /// are several (two cores share the work evenly). A shorter image is still cut in two halves
    /// of at least `MIN_HALF_ROWS` and 4r rows, so that both cores work on it.
    pub(super) fn strip_rows(&self) -> usize {
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
    pub(super) fn window_rows(&self, y: usize) -> usize {
        (y + self.radius).min(self.height - 1) - y.saturating_sub(self.radius) + 1
    }

    /// 1 / (columns in the clipped window of column x) per column; 0 in the padding.
    pub(super) fn inverse_columns(&self) -> Vec<f64> {
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
pub(super) const fn moment_count(d: usize) -> usize {
    d + d * (d + 1) / 2 + 3 + 3 * d
}

/// Coefficients per pixel: a_c (d values for each colour c, c-major), then b_c (3).
pub(super) const fn coefficient_count(d: usize) -> usize {
    3 * d + 3
}

/// One box-filtered quantity: the source row `.0`, or the product of source rows `.0` and `.1`.
pub(super) type Term = (usize, Option<usize>);

/// Stage 1's terms (layout of `moment_count`) over the source rows I_0..I_{d−1}, N_0..N_2.
pub(super) fn moment_terms<const D: usize>() -> Vec<Term> {
    let mut terms: Vec<Term> = (0..D).map(|j| (j, None)).collect();
    terms.extend((0..D).flat_map(|j| (j..D).map(move |k| (j, Some(k)))));
    terms.extend((0..3).map(|c| (D + c, None)));
    terms.extend((0..3).flat_map(|c| (0..D).map(move |j| (D + c, Some(j)))));
    terms
}

/// Where a box pass reads row y: its source rows, one after the other, `padded` values each
/// (zero past the width), either written to `scratch` or stored.
pub(super) trait RowSource {
    /// f32, or f64 holding f32 values (converted once per row rather than once per product).
    type Value: Copy + Default + Into<f64>;
    fn row<'a>(&'a self, y: usize, scratch: &'a mut [Self::Value]) -> &'a [Self::Value];
}

/// Stage 1's source rows: the d guide channels and the three colour channels of the input.
pub(super) struct Channels<'a> {
    pub(super) planes: &'a [Vec<f32>],
    pub(super) input: &'a [[f32; 3]],
    pub(super) width: usize,
    pub(super) padded: usize,
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
pub(super) struct CoefficientRing<'a> {
    pub(super) values: &'a [f32],
    pub(super) slots: usize,
    pub(super) row_len: usize,
}

impl RowSource for CoefficientRing<'_> {
    type Value = f32;

    #[inline(always)]
    fn row<'a>(&'a self, y: usize, _: &'a mut [f32]) -> &'a [f32] {
        &self.values[y % self.slots * self.row_len..][..self.row_len]
    }
}

/// What both stages share: the grid, stage 1's source rows and the ε.
pub(super) struct Context<const D: usize, R> {
    pub(super) grid: Grid,
    pub(super) source: R,
    pub(super) eps: [f64; D],
    /// Every Cholesky pivot of Σ + diag ε is at least min ε in exact arithmetic.
    pub(super) min_pivot: f64,
    pub(super) inverse_columns: Vec<f64>,
}

impl<const D: usize, R: RowSource<Value = f64>> Context<D, R> {
    pub(super) fn new(grid: Grid, source: R, eps: &[f64; MAX_GUIDE_CHANNELS]) -> Self {
        let eps: [f64; D] = std::array::from_fn(|j| eps[j]);
        let min_eps = eps.iter().fold(f64::INFINITY, |m, &e| m.min(e));
        Context { grid, source, eps, min_pivot: 0.5 * min_eps, inverse_columns: grid.inverse_columns() }
    }
}

/// The two stages for a d-channel guide (`M`, `Q`: `moment_count(D)`, `coefficient_count(D)`,
/// spelled out because stable Rust cannot compute array lengths from `D`): per-window
/// coefficients from box-filtered moments, then their box mean evaluated against the guide.
/// Returns the pixels and the number of fallback windows.
pub(super) fn filter<const D: usize, const M: usize, const Q: usize>(
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
pub(super) trait CoefficientSink<const D: usize, const Q: usize> {
    /// The LANES pixels of row y from x0 on (`n` of them inside the image): their coefficient
    /// means are `sums` (Q rows of `CHUNK`, this block's at `at`) times `scale`.
    fn block(&mut self, y: usize, x0: usize, n: usize, sums: &[f64], at: usize, scale: &Lanes);
    /// Called after the last block of row y.
    fn row_done(&mut self, y: usize);
}

/// The exact filter's stage 2: `F = ā·I + b̄` per pixel, written to whole output rows from row
/// `y0` on.
pub(super) struct Evaluate<'a> {
    pub(super) planes: &'a [Vec<f32>],
    pub(super) width: usize,
    pub(super) y0: usize,
    pub(super) out: &'a mut [[f32; 3]],
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
pub(super) fn filter_strip<
    const D: usize,
    const M: usize,
    const Q: usize,
    R: RowSource<Value = f64>,
    S: CoefficientSink<D, Q>,
>(
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
