//! A small seeded random number generator (SplitMix64).
//!
//! Every random choice in btfrs takes a `seed`; results must not change when a dependency
//! updates its generator, so we keep our own. SplitMix64 passes BigCrush and is plenty for
//! sampling splits, noise lattices and k-means initialisation.

/// SplitMix64 (Steele, Lea, Flood 2014).
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    /// A generator for `seed`; different seeds give independent-looking streams.
    pub fn new(seed: u64) -> Self {
        Rng(seed ^ 0x6A09_E667_F3BC_C909)
    }

    /// The next 64 random bits.
    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        mix(self.0)
    }

    /// Uniform in [0, 1).
    #[inline]
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform integer in [0, n); n must be > 0. Lemire's multiply-shift (bias < 2^-64 * n).
    #[inline]
    pub fn below(&mut self, n: usize) -> usize {
        ((self.next_u64() as u128 * n as u128) >> 64) as usize
    }
}

/// The SplitMix64 finaliser: a good 64-bit hash, used for lattice noise keyed by coordinates.
#[inline]
pub fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A hash of (seed, a, b) mapped to [0, 1).
#[inline]
pub fn hash01(seed: u64, a: i64, b: i64) -> f64 {
    let h = mix(seed ^ mix((a as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ mix(b as u64)));
    (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deterministic_and_roughly_uniform() {
        let mut a = Rng::new(5);
        let mut b = Rng::new(5);
        let xs: Vec<f64> = (0..20000).map(|_| a.next_f64()).collect();
        let ys: Vec<f64> = (0..20000).map(|_| b.next_f64()).collect();
        assert_eq!(xs, ys);
        let mean = xs.iter().sum::<f64>() / xs.len() as f64;
        assert!((mean - 0.5).abs() < 0.01, "{mean}");
        let mut c = Rng::new(6);
        assert_ne!(c.next_u64(), Rng::new(5).next_u64());
        let mut hist = [0usize; 10];
        for _ in 0..100_000 {
            hist[c.below(10)] += 1;
        }
        assert!(hist.iter().all(|&h| (9_500..10_500).contains(&h)), "{hist:?}");
    }
}
