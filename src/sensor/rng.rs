//! Counter-based random numbers for the detector models (`sensor` and the
//! simulated facility): every draw is a pure function of (seed, stream,
//! index), so a frame is the same whatever the thread count or the order
//! pixels are processed in.

/// SplitMix64 finaliser: a well-mixed 64-bit hash.
#[inline]
fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// A small generator seeded from (seed, stream, index).
#[derive(Debug, Clone)]
pub struct Rng {
    state: u64,
}

impl Rng {
    /// Generator for one (seed, stream, index) triple.
    pub fn new(seed: u64, stream: u64, index: u64) -> Rng {
        let s = mix(seed ^ 0x9e37_79b9_7f4a_7c15)
            ^ mix(stream.wrapping_add(0x632b_e59b_d9b4_e019))
            ^ mix(index.wrapping_mul(0xd1b5_4a32_d192_ed03).wrapping_add(1));
        Rng { state: mix(s) }
    }

    /// Next 64 random bits.
    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        mix(self.state)
    }

    /// Uniform in (0, 1).
    #[inline]
    pub fn uniform(&mut self) -> f64 {
        ((self.next_u64() >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }

    /// Standard normal (Box–Muller).
    #[inline]
    pub fn normal(&mut self) -> f64 {
        let (u1, u2) = (self.uniform(), self.uniform());
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    /// Poisson with mean `mean` ≥ 0: exact (Knuth) below 30, else the
    /// normal approximation N(mean, mean), rounded and kept ≥ 0 (its
    /// mean and variance differ from Poisson's by less than 0.1 % there).
    pub fn poisson(&mut self, mean: f64) -> f64 {
        if !(mean > 0.0) {
            return 0.0;
        }
        if mean < 30.0 {
            let limit = (-mean).exp();
            let mut k = 0.0;
            let mut p = self.uniform();
            while p > limit {
                k += 1.0;
                p *= self.uniform();
            }
            return k;
        }
        (mean + mean.sqrt() * self.normal()).round().max(0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_and_poisson_moments() {
        let mut r = Rng::new(7, 1, 2);
        let n = 200_000;
        let xs: Vec<f64> = (0..n).map(|_| r.normal()).collect();
        let mean = xs.iter().sum::<f64>() / n as f64;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64;
        assert!(
            mean.abs() < 0.01 && (var - 1.0).abs() < 0.01,
            "{mean} {var}"
        );
        for lambda in [3.5, 200.0] {
            let ks: Vec<f64> = (0..n).map(|_| r.poisson(lambda)).collect();
            let m = ks.iter().sum::<f64>() / n as f64;
            let v = ks.iter().map(|x| (x - m).powi(2)).sum::<f64>() / n as f64;
            assert!((m / lambda - 1.0).abs() < 0.01, "{lambda}: {m}");
            assert!((v / lambda - 1.0).abs() < 0.02, "{lambda}: {v}");
        }
    }

    #[test]
    fn same_triple_same_draws() {
        let a: Vec<u64> = {
            let mut r = Rng::new(1, 2, 3);
            (0..4).map(|_| r.next_u64()).collect()
        };
        let mut r = Rng::new(1, 2, 3);
        assert_eq!(a, (0..4).map(|_| r.next_u64()).collect::<Vec<_>>());
        assert_ne!(Rng::new(1, 2, 4).next_u64(), a[0]);
    }
}
