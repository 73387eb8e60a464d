//! Low-discrepancy sampling: Owen-scrambled Sobol' points, two dimensions at a time.
//!
//! Each pair of dimensions of a pixel's sample sequence is the first two Sobol' dimensions
//! (which together form a (0,2)-sequence in base 2), nested-uniform (Owen) scrambled with a
//! hash of (seed, pixel, dimension), and the sample index is itself shuffled per pixel and
//! dimension pair by the same scrambling so that pairs stay decorrelated ("padding", after
//! Burley 2020, "Practical Hash-based Owen Scrambling"). Every value depends only on
//! (seed, pixel, sample index, dimension), never on thread scheduling, so renders are
//! bit-identical for any thread count.

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

#[inline]
pub fn hash_combine(a: u32, b: u32) -> u32 {
    hash_u32(a ^ b.wrapping_add(0x9e37_79b9).wrapping_add(a << 6).wrapping_add(a >> 2))
}

/// Laine-Karras style permutation of the bits of `x`, applied from the low bit upwards: each
/// output bit depends only on the input bits below it. Applied to a bit-reversed value it is a
/// nested uniform scramble.
#[inline]
fn laine_karras_permutation(mut x: u32, seed: u32) -> u32 {
    x ^= x.wrapping_mul(0x3d20_adea);
    x = x.wrapping_add(seed);
    x = x.wrapping_mul((seed >> 16) | 1);
    x ^= x.wrapping_mul(0x0552_6c56);
    x ^= x.wrapping_mul(0x53a2_2864);
    x
}

/// Nested uniform (Owen) scramble of a 32-bit fixed-point value in [0, 1).
#[inline]
pub fn nested_uniform_scramble(x: u32, seed: u32) -> u32 {
    laine_karras_permutation(x.reverse_bits(), seed).reverse_bits()
}

/// First Sobol' dimension: the van der Corput sequence in base 2.
#[cfg(test)]
fn sobol_dim0(index: u32) -> u32 {
    index.reverse_bits()
}

/// Second Sobol' dimension (primitive polynomial x + 1, direction numbers
/// v_k = v_{k-1} ^ (v_{k-1} >> 1)), by the bit-by-bit definition (reference for the tables).
#[cfg(test)]
fn sobol_dim1_reference(mut index: u32) -> u32 {
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

/// Second Sobol' dimension.
#[cfg(test)]
fn sobol_dim1(index: u32) -> u32 {
    let t = &SOBOL_DIM1_TABLES;
    t[0][(index & 0xff) as usize]
        ^ t[1][((index >> 8) & 0xff) as usize]
        ^ t[2][((index >> 16) & 0xff) as usize]
        ^ t[3][(index >> 24) as usize]
}

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

/// Second Sobol' dimension with its bits reversed.
#[inline]
fn sobol_dim1_reversed(index: u32) -> u32 {
    let t = &SOBOL_DIM1_REVERSED_TABLES;
    t[0][(index & 0xff) as usize]
        ^ t[1][((index >> 8) & 0xff) as usize]
        ^ t[2][((index >> 16) & 0xff) as usize]
        ^ t[3][(index >> 24) as usize]
}

#[inline]
fn to_unit_float(x: u32) -> f32 {
    // 24 significant bits so the result is exactly representable and < 1.
    (x >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
}

/// Sample stream for one pixel and one sample index; dimensions are consumed in pairs.
#[derive(Clone, Debug)]
pub struct Sampler {
    pixel_seed: u32,
    /// The sample index with its bits reversed (the form the index shuffle scrambles).
    reversed_index: u32,
    dimension: u32,
}

impl Sampler {
    pub fn new(seed: u32, pixel_x: u32, pixel_y: u32, index: u32) -> Sampler {
        let pixel_seed = hash_combine(hash_combine(hash_u32(seed), pixel_x), pixel_y);
        Sampler { pixel_seed, reversed_index: index.reverse_bits(), dimension: 0 }
    }

    /// The next two dimensions as a point in [0, 1)².
    ///
    /// By definition this is `nested_uniform_scramble` applied to the index (the shuffle) and
    /// then to both Sobol' coordinates of the shuffled index ([`Sampler::next_2d_by_definition`]).
    /// Each scramble reverses its input's bits, permutes and reverses back; here the reversals
    /// that cancel are left out: the index is kept reversed, the first Sobol' dimension is the
    /// reversed index so its scramble starts from the shuffled index itself, and the second's
    /// table holds its values already reversed. Three bit reversals instead of seven, same bits.
    #[inline]
    pub fn next_2d(&mut self) -> [f32; 2] {
        let pair_seed = hash_combine(self.pixel_seed, self.dimension);
        self.dimension += 1;
        let shuffled = laine_karras_permutation(self.reversed_index, pair_seed).reverse_bits();
        let seed_x = hash_u32(pair_seed ^ 0x68e3_1da4);
        let seed_y = hash_u32(pair_seed ^ 0xb529_7a4d);
        [
            to_unit_float(laine_karras_permutation(shuffled, seed_x).reverse_bits()),
            to_unit_float(laine_karras_permutation(sobol_dim1_reversed(shuffled), seed_y).reverse_bits()),
        ]
    }

    /// `next_2d` written as its definition: the reference its shortcut is tested against.
    #[cfg(test)]
    fn next_2d_by_definition(&mut self) -> [f32; 2] {
        let pair_seed = hash_combine(self.pixel_seed, self.dimension);
        self.dimension += 1;
        let shuffled = nested_uniform_scramble(self.reversed_index.reverse_bits(), pair_seed);
        let seed_x = hash_u32(pair_seed ^ 0x68e3_1da4);
        let seed_y = hash_u32(pair_seed ^ 0xb529_7a4d);
        [
            to_unit_float(nested_uniform_scramble(sobol_dim0(shuffled), seed_x)),
            to_unit_float(nested_uniform_scramble(sobol_dim1(shuffled), seed_y)),
        ]
    }

    /// One dimension (uses up a pair).
    #[inline]
    pub fn next_1d(&mut self) -> f32 {
        self.next_2d()[0]
    }
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
            assert_eq!(sobol_dim1(x), sobol_dim1_reference(x));
            assert_eq!(sobol_dim1(i), sobol_dim1_reference(i));
        }
    }

    #[test]
    fn next_2d_gives_the_bits_of_its_definition() {
        // The shortcut drops only bit reversals that cancel, so it must agree bit for bit with
        // the scrambles written out, over many seeds, pixels, indices and dimensions.
        let mut x = 12345u32;
        for _ in 0..2000 {
            x = hash_u32(x);
            let (seed, px, py, index) = (x % 7, x % 613, (x >> 10) % 479, hash_u32(x ^ 1) % 100_000);
            let mut fast = Sampler::new(seed, px, py, index);
            let mut reference = fast.clone();
            for _ in 0..40 {
                assert_eq!(fast.next_2d().map(f32::to_bits), reference.next_2d_by_definition().map(f32::to_bits));
            }
        }
        for i in 0..1000u32 {
            assert_eq!(sobol_dim1_reversed(hash_u32(i)), sobol_dim1(hash_u32(i)).reverse_bits());
        }
    }

    #[test]
    fn scrambled_pairs_stay_stratified() {
        // Owen scrambling preserves the net property: 16 samples of one pixel and dimension
        // pair land one per cell of a 4x4 grid.
        for dim_pairs in 0..4 {
            let mut cells = std::collections::HashSet::new();
            for i in 0..16 {
                let mut s = Sampler::new(7, 3, 5, i);
                let mut p = [0.0; 2];
                for _ in 0..=dim_pairs {
                    p = s.next_2d();
                }
                cells.insert(((p[0] * 4.0) as u32, (p[1] * 4.0) as u32));
            }
            assert_eq!(cells.len(), 16);
        }
    }

    #[test]
    fn values_are_in_unit_interval_and_depend_on_seed() {
        let mut a = Sampler::new(1, 0, 0, 3);
        let mut b = Sampler::new(2, 0, 0, 3);
        let (pa, pb) = (a.next_2d(), b.next_2d());
        assert_ne!(pa, pb);
        for v in pa.iter().chain(pb.iter()) {
            assert!((0.0..1.0).contains(v));
        }
    }

    #[test]
    fn mean_of_many_samples_is_one_half() {
        let n = 4096;
        let mut sum = [0.0f64; 2];
        for i in 0..n {
            let p = Sampler::new(11, 9, 9, i).next_2d();
            sum[0] += p[0] as f64;
            sum[1] += p[1] as f64;
        }
        assert!((sum[0] / n as f64 - 0.5).abs() < 1e-3);
        assert!((sum[1] / n as f64 - 0.5).abs() < 1e-3);
    }
}
