//! The fast filter (subsampling factor s > 1): block means of the guide and input, the
//! regression at the subsampled resolution, and the coefficients upsampled bilinearly and
//! evaluated against the full-resolution guide (`Upsample`, `Resampling`).

use super::*;

/// The fast guided filter (module's "Subsampling"): both stages on s×s block means of the guide
/// and the input with radius r / s (rounded, at least 1), then the coefficient means upsampled
/// bilinearly and evaluated against the full-resolution guide, `F = ā↑·I + b̄↑`. Returns the
/// pixels and the number of fallback windows (of the subsampled image).
pub(super) fn filter_subsampled<const D: usize, const M: usize, const Q: usize>(
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
pub(super) struct BlockMeans {
    pub(super) values: Vec<f32>,
    pub(super) width: usize,
    pub(super) padded: usize,
    pub(super) channels: usize,
}

impl BlockMeans {
    /// The block means of `planes` and `input` on `grid` (full resolution).
    pub(super) fn new(grid: Grid, planes: &[Vec<f32>], input: &[[f32; 3]], s: usize) -> BlockMeans {
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
pub(super) struct Resampling {
    pub(super) lower: Vec<usize>,
    pub(super) upper: Vec<usize>,
    pub(super) t: Vec<f32>,
    /// s, and the number of subsampled values.
    pub(super) phases: usize,
    pub(super) low: usize,
}

impl Resampling {
    pub(super) fn new(full: usize, low: usize, s: usize) -> Resampling {
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
    pub(super) fn upsample(&self, low: &[f32], full: &mut [f32]) {
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
    pub(super) fn upsample_interior<const S: usize>(
        &self,
        low: &[f32],
        full: &mut [f32],
        interior: std::ops::Range<usize>,
    ) {
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
pub(super) struct Upsample<'a, const D: usize, const Q: usize> {
    pub(super) planes: &'a [Vec<f32>],
    pub(super) width: usize,
    pub(super) low_padded: usize,
    pub(super) low_height: usize,
    pub(super) rows: &'a Resampling,
    pub(super) columns: &'a Resampling,
    /// The output rows from full-resolution row `first_row` on, and the next one to write.
    pub(super) first_row: usize,
    pub(super) next_row: usize,
    pub(super) out: &'a mut [[f32; 3]],
    /// Coefficient means of the current subsampled row (Q rows of `low_padded`).
    pub(super) low: Vec<f32>,
    /// Those of the previous and the current subsampled row upsampled along the row (Q rows of
    /// `width`); whether `previous` holds a row yet.
    pub(super) previous: Vec<f32>,
    pub(super) current: Vec<f32>,
    pub(super) have_previous: bool,
    /// The output accumulators (3 rows of `width`).
    pub(super) sums: Vec<f64>,
}

impl<'a, const D: usize, const Q: usize> Upsample<'a, D, Q> {
    pub(super) fn new(
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
    pub(super) fn emit(&mut self, lower: usize, use_previous: bool) {
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
