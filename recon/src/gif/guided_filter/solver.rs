//! The per-window regression (Eq. 6–9 with the guide's covariance): each window's
//! coefficients solved from its moments, LANES columns at a time, and evaluated.

use super::*;

/// 1 / (pixels in the window) for the LANES columns from x0 on, in a row whose window has
/// 1 / `inverse_rows` rows.
#[inline(always)]
pub(super) fn scale_block<const D: usize, R>(context: &Context<D, R>, x0: usize, inverse_rows: f64) -> Lanes {
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
pub(super) fn coefficient_block<const D: usize, const M: usize, const Q: usize>(
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
pub(super) fn window_coefficients<const D: usize, const M: usize, const Q: usize>(
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
pub(super) fn evaluate<const D: usize, const Q: usize>(
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
