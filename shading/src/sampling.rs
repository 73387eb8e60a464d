//! The sampling numerics the tracer and the reconstructions share: an integer hash, Owen
//! (nested uniform) scrambling, the first two Sobol' dimensions, the radical inverse, and the
//! conversion of 32-bit fixed point to [0, 1). The square-to-disk and hemisphere maps are in
//! `warp.rs`, the orthonormal basis in `frame.rs`.
//!
//! One copy for every user: the tracer's per-pixel sample streams (`tracer::sampler`), ILFR's
//! gather directions and lens locations, and TLFR's Halton locations draw from these, so a
//! change here changes them all (and is caught by the bit-identity tests beside each).

/// 32-bit integer hash (the "lowbias32" finaliser).
#[inline]
pub fn hash_u32(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb_352d);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846c_a68b);
    x ^= x >> 16;
    x
}

/// Combines a running hash `a` with a value `b` (boost's `hash_combine`, finalised).
#[inline]
pub fn hash_combine(a: u32, b: u32) -> u32 {
    hash_u32(a ^ b.wrapping_add(0x9e37_79b9).wrapping_add(a << 6).wrapping_add(a >> 2))
}

/// Laine–Karras style permutation of the bits of `x` (Vegdahl's constants), applied from the
/// low bit upwards: each output bit depends only on the input bits below it, so it permutes
/// every block of 2^k consecutive values among themselves. Applied to a bit-reversed value it
/// is a nested uniform scramble.
#[inline]
pub fn laine_karras_permutation(mut x: u32, seed: u32) -> u32 {
    x ^= x.wrapping_mul(0x3d20_adea);
    x = x.wrapping_add(seed);
    x = x.wrapping_mul((seed >> 16) | 1);
    x ^= x.wrapping_mul(0x0552_6c56);
    x ^= x.wrapping_mul(0x53a2_2864);
    x
}

/// Nested uniform (Owen) scramble of a 32-bit fixed-point value in [0, 1): each bit depends
/// only on the bits above it.
#[inline]
pub fn nested_uniform_scramble(x: u32, seed: u32) -> u32 {
    laine_karras_permutation(x.reverse_bits(), seed).reverse_bits()
}

/// First Sobol' dimension: the van der Corput sequence in base 2, as 32-bit fixed point.
#[inline]
pub fn sobol_dim0(index: u32) -> u32 {
    index.reverse_bits()
}

/// Second Sobol' dimension (primitive polynomial x + 1, direction numbers
/// v_1 = 1/2, v_{k+1} = v_k ⊕ v_k/2), by its bit-by-bit definition: the oracle of the tables.
pub fn sobol_dim1_by_definition(mut index: u32) -> u32 {
    let mut v: u32 = 1 << 31;
    let mut result = 0;
    while index != 0 {
        if index & 1 != 0 {
            result ^= v;
        }
        index >>= 1;
        v ^= v >> 1;
    }
    result
}

/// The generator matrix is linear over GF(2), so the image of an index is the XOR of the images
/// of its four bytes: four tables of 256 entries, built at compile time.
const SOBOL_DIM1_TABLES: [[u32; 256]; 4] = {
    let mut directions = [0u32; 32];
    let mut v: u32 = 1 << 31;
    let mut k = 0;
    while k < 32 {
        directions[k] = v;
        v ^= v >> 1;
        k += 1;
    }
    let mut tables = [[0u32; 256]; 4];
    let mut byte = 0;
    while byte < 4 {
        let mut value = 0;
        while value < 256 {
            let mut result = 0u32;
            let mut bit = 0;
            while bit < 8 {
                if value & (1 << bit) != 0 {
                    result ^= directions[byte * 8 + bit];
                }
                bit += 1;
            }
            tables[byte][value] = result;
            value += 1;
        }
        byte += 1;
    }
    tables
};

/// The tables with every entry bit-reversed: reversal is linear over GF(2) too.
const SOBOL_DIM1_REVERSED_TABLES: [[u32; 256]; 4] = {
    let mut tables = SOBOL_DIM1_TABLES;
    let mut byte = 0;
    while byte < 4 {
        let mut value = 0;
        while value < 256 {
            tables[byte][value] = tables[byte][value].reverse_bits();
            value += 1;
        }
        byte += 1;
    }
    tables
};

#[inline]
fn by_bytes(tables: &[[u32; 256]; 4], index: u32) -> u32 {
    tables[0][(index & 0xff) as usize]
        ^ tables[1][((index >> 8) & 0xff) as usize]
        ^ tables[2][((index >> 16) & 0xff) as usize]
        ^ tables[3][(index >> 24) as usize]
}

/// Second Sobol' dimension, as 32-bit fixed point.
#[inline]
pub fn sobol_dim1(index: u32) -> u32 {
    by_bytes(&SOBOL_DIM1_TABLES, index)
}

/// Second Sobol' dimension with its bits reversed (`sobol_dim1(i).reverse_bits()`), for
/// scrambles that work on reversed values.
#[inline]
pub fn sobol_dim1_reversed(index: u32) -> u32 {
    by_bytes(&SOBOL_DIM1_REVERSED_TABLES, index)
}

/// A 32-bit fixed-point value in [0, 1) as an `f32` with its 24 high bits: exactly
/// representable and < 1.
#[inline]
pub fn to_unit_float(x: u32) -> f32 {
    (x >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
}

/// Point `index` of the first two Sobol' dimensions in [0, 1)², each Owen-scrambled with its
/// own seed derived from `seed`: a (0, 2)-sequence in base 2 for any seed. (The tracer's
/// `Sampler` also shuffles the index per pixel; a caller that wants that shuffles before.)
pub fn sobol_2d_scrambled(index: u32, seed: u32) -> (f32, f32) {
    let x = nested_uniform_scramble(sobol_dim0(index), hash_u32(seed ^ 0x243f_6a88));
    let y = nested_uniform_scramble(sobol_dim1(index), hash_u32(seed ^ 0x85a3_08d3));
    (to_unit_float(x), to_unit_float(y))
}

/// The radical inverse of `index` in `base` (the Halton sequence's dimension of that base),
/// accumulated in f64 and rounded once.
pub fn radical_inverse(mut index: u32, base: u32) -> f32 {
    let (mut result, mut scale) = (0.0f64, 1.0f64 / base as f64);
    while index > 0 {
        result += (index % base) as f64 * scale;
        index /= base;
        scale /= base as f64;
    }
    result as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sobol_pairs_are_a_0_2_net_in_every_elementary_interval() {
        // The first 16 points of Sobol' dims 0 and 1 put exactly one point in every
        // elementary interval of area 1/16 (1x16, 2x8, 4x4, 8x2, 16x1).
        let pts: Vec<(u32, u32)> = (0..16).map(|i| (sobol_dim0(i) >> 28, sobol_dim1(i) >> 28)).collect();
        for log_x in 0..=4u32 {
            let log_y = 4 - log_x;
            let mut seen = std::collections::HashSet::new();
            for &(x, y) in &pts {
                seen.insert((x >> (4 - log_x), y >> (4 - log_y)));
            }
            assert_eq!(seen.len(), 16, "interval shape 2^{log_x} x 2^{log_y}");
        }
    }

    #[test]
    fn table_driven_sobol_matches_the_definition() {
        let mut x = 1u32;
        for i in 0..10_000u32 {
            x = hash_u32(x ^ i);
            assert_eq!(sobol_dim1(x), sobol_dim1_by_definition(x));
            assert_eq!(sobol_dim1(i), sobol_dim1_by_definition(i));
            assert_eq!(sobol_dim1_reversed(x), sobol_dim1_by_definition(x).reverse_bits());
        }
    }

    #[test]
    fn scrambled_sobol_points_are_stratified() {
        // A (0, 2)-net: 2^m points put exactly one in every elementary interval of area 2^−m,
        // after nested scrambling too.
        for seed in [0u32, 1, 0xdead_beef] {
            let points: Vec<(f32, f32)> = (0..16).map(|j| sobol_2d_scrambled(j, seed)).collect();
            for (nx, ny) in [(16usize, 1usize), (8, 2), (4, 4), (2, 8), (1, 16)] {
                let mut cells = vec![0; 16];
                for &(u, v) in &points {
                    assert!((0.0..1.0).contains(&u) && (0.0..1.0).contains(&v));
                    cells[(u * nx as f32) as usize * ny + (v * ny as f32) as usize] += 1;
                }
                assert!(cells.iter().all(|&c| c == 1), "seed {seed}, {nx}x{ny}: {cells:?}");
            }
        }
        assert_ne!(sobol_2d_scrambled(3, 1), sobol_2d_scrambled(3, 2), "seeds give other points");
    }

    #[test]
    fn nested_scrambling_permutes_every_dyadic_block() {
        // Each output bit depends only on the input bits above it, so the 256 values sharing
        // their top 24 bits map onto one block of 256 values sharing theirs, one to one.
        for seed in [3u32, 0x1234_5678] {
            let mut seen: Vec<u32> = (0..256u32).map(|low| nested_uniform_scramble(0xabcd_ef00 | low, seed)).collect();
            let top = seen[0] & !0xff;
            assert!(seen.iter().all(|v| v & !0xff == top));
            seen.sort_unstable();
            seen.dedup();
            assert_eq!(seen.len(), 256);
        }
    }

    #[test]
    fn unit_floats_are_exact_and_below_one() {
        assert_eq!(to_unit_float(0), 0.0);
        assert!(to_unit_float(u32::MAX) < 1.0);
        assert_eq!(to_unit_float(1 << 31), 0.5);
    }

    #[test]
    fn radical_inverse_mirrors_the_digits() {
        assert_eq!(radical_inverse(1, 2), 0.5);
        assert_eq!(radical_inverse(6, 2), 0.375); // 110 -> 0.011
        assert_eq!(radical_inverse(5, 3), (2.0 / 3.0 + 1.0 / 9.0) as f32); // 12 -> 0.21
        assert_eq!(radical_inverse(0, 7), 0.0);
    }
}
