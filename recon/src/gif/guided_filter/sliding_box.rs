//! The sliding window sums: the vertical running sums of the moments' columns and each row
//! summed over the horizontal window; the cost per pixel does not depend on the radius.

use super::*;

/// Box sums of `terms` down consecutive rows of a strip: f64 column sums over the rows of the
/// current window, slid down a row at a time (add the row entering, subtract the row leaving;
/// rows are re-read from the source, products recomputed, rather than kept), then each row of
/// them summed over the horizontal window (`box_rows`). The cost per pixel does not depend on
/// the radius; a strip pays once for its first window.
pub(super) struct SlidingBox<T> {
    pub(super) grid: Grid,
    pub(super) terms: Vec<Term>,
    /// Row length of `columns`: term k's column sums lie at `k * stride + r + 1 ..` (width
    /// values), with r + 1 zeros before them and r or more after, so that `box_rows` can read
    /// a window's columns past the image's edges.
    pub(super) stride: usize,
    pub(super) columns: Vec<f64>,
    /// The window sums of the current chunk of the row: rows of `CHUNK`.
    pub(super) sums: Vec<f64>,
    /// The running window sums along the row, per row of `columns`.
    pub(super) carry: Vec<f64>,
    pub(super) entering: Vec<T>,
    pub(super) leaving: Vec<T>,
    /// The row whose window `columns` holds.
    pub(super) row: Option<usize>,
}

impl<T: Copy + Default + Into<f64>> SlidingBox<T> {
    pub(super) fn new(grid: Grid, terms: Vec<Term>, source_rows: usize) -> Self {
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
    pub(super) fn row<S: RowSource<Value = T>>(&mut self, source: &S, y: usize, mut f: impl FnMut(usize, &[f64])) {
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
pub(super) struct Columns {
    pub(super) padded: usize,
    pub(super) stride: usize,
    pub(super) offset: usize,
}

/// Adds the terms of the `enter` rows to the column sums and subtracts those of the `leave`
/// rows, for the columns `pixels`; the products of two f32 values are exact in f64.
#[inline(always)]
pub(super) fn update_columns<'a, T: Copy + Into<f64>>(
    columns: &mut [f64],
    layout: Columns,
    terms: &[Term],
    enter: Option<&'a [T]>,
    leave: Option<&'a [T]>,
    pixels: std::ops::Range<usize>,
) {
    pub(super) fn product<'a, T: Copy + Into<f64>>(p: &'a [T], q: &'a [T]) -> impl Iterator<Item = f64> + 'a {
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
pub(super) fn box_rows(
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
