//! A tiny deterministic generator for test data, the synthetic scenes and the benches (64-bit
//! linear congruential generator, Knuth's MMIX constants, top 24 bits): the same numbers on every
//! machine, so that test inputs never change. Not for rendering or reconstruction.

/// The generator's state; `Lcg(seed)` starts a sequence.
#[derive(Clone, Debug)]
pub struct Lcg(pub u64);

impl Lcg {
    /// Uniform in [0, 1), exactly representable (24 bits).
    pub fn uniform(&mut self) -> f32 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }

    /// A point of the unit disk (rejection sampling).
    pub fn disk(&mut self) -> (f32, f32) {
        loop {
            let (u, v) = (2.0 * self.uniform() - 1.0, 2.0 * self.uniform() - 1.0);
            if u * u + v * v <= 1.0 {
                return (u, v);
            }
        }
    }

    /// A direction uniform on the unit sphere (z uniform in [−1, 1), azimuth uniform).
    pub fn unit_vector(&mut self) -> [f32; 3] {
        let (z, azimuth) = (self.uniform() * 2.0 - 1.0, self.uniform() * std::f32::consts::TAU);
        let r = (1.0 - z * z).max(0.0).sqrt();
        [r * azimuth.cos(), r * azimuth.sin(), z]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_stay_in_range_and_spread_evenly() {
        let mut rng = Lcg(1);
        let values: Vec<f32> = (0..10_000).map(|_| rng.uniform()).collect();
        assert!(values.iter().all(|&v| (0.0..1.0).contains(&v)));
        let mean = values.iter().sum::<f32>() / values.len() as f32;
        // The mean of 10^4 uniforms has a standard deviation of 0.0029.
        assert!((mean - 0.5).abs() < 0.012, "{mean}");
        for _ in 0..1000 {
            let (u, v) = rng.disk();
            assert!(u * u + v * v <= 1.0);
            let d = rng.unit_vector();
            assert!(((d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) - 1.0).abs() < 1e-5);
        }
    }

    #[test]
    fn the_same_seed_gives_the_same_sequence() {
        let (mut a, mut b) = (Lcg(42), Lcg(42));
        assert!((0..100).all(|_| a.uniform() == b.uniform()));
        assert_ne!(Lcg(1).uniform(), Lcg(2).uniform());
    }
}
