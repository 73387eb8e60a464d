//! Low-discrepancy sampling: Owen-scrambled Sobol' points, two dimensions at a time.
//!
//! Each pair of dimensions of a pixel's sample sequence is the first two Sobol' dimensions
//! (which together form a (0,2)-sequence in base 2), nested-uniform (Owen) scrambled with a
//! hash of (seed, pixel, dimension), and the sample index is itself shuffled per pixel and
//! dimension pair by the same scrambling so that pairs stay decorrelated ("padding", after
//! Burley 2020, "Practical Hash-based Owen Scrambling"). Every value depends only on
//! (seed, pixel, sample index, dimension), never on thread scheduling, so renders are
//! bit-identical for any thread count. The hash, scrambles and Sobol' dimensions are
//! `shading::sampling`'s, shared with the reconstructions.

use shading::sampling::{hash_combine, hash_u32, laine_karras_permutation, sobol_dim1_reversed, to_unit_float};
#[cfg(test)]
use shading::sampling::{nested_uniform_scramble, sobol_dim0, sobol_dim1};

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
    /// then to both Sobol' coordinates of the shuffled index (`Sampler::next_2d_by_definition`).
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
