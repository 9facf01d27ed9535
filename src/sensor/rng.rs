//! Counter-based random numbers for the detector models (`sensor` and the
//! simulated facility): every draw is a pure function of (seed, stream,
//! index), so a frame is the same whatever the thread count or the order
//! pixels are processed in.

/// Poisson draws of this mean and above are the rounded normal N(μ, μ).
pub const NORMAL_POISSON: f64 = 30.0;

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
            let mut p = self.uniform();
            // e^(−mean) ≥ 1 − mean: below that no exponential is needed
            // for Knuth's first step (a faint pixel: most of them).
            if p <= 1.0 - mean {
                return 0.0;
            }
            let limit = (-mean).exp();
            let mut k = 0.0;
            while p > limit {
                k += 1.0;
                p *= self.uniform();
            }
            return k;
        }
        (mean + mean.sqrt() * self.normal()).round().max(0.0)
    }
}

/// One random stream's key, hashed once: [`Stream::at`] seeds the
/// generator of index `index` with one hash where [`Rng::new`] takes four
/// (the sensor chain seeds one generator per pixel and frame).
#[derive(Clone, Copy, Debug)]
pub struct Stream {
    key: u64,
}

impl Stream {
    /// The stream `stream` of `seed`.
    pub fn new(seed: u64, stream: u64) -> Stream {
        Stream {
            key: mix(
                mix(seed ^ 0x9e37_79b9_7f4a_7c15) ^ mix(stream.wrapping_add(0x632b_e59b_d9b4_e019))
            ),
        }
    }

    /// The generator of `index` in this stream (an odd multiplier keeps
    /// distinct indices distinct before the hash).
    #[inline]
    pub fn at(&self, index: u64) -> Rng {
        Rng {
            state: self.bits(index),
        }
    }

    /// 64 random bits of `index`: one hash (SplitMix64's finaliser of the
    /// key and the index), for callers that need no more than 64 bits per
    /// index (the sensor's dark pixels take 16 bits each, 4 per index).
    #[inline]
    pub fn bits(&self, index: u64) -> u64 {
        mix(self.key ^ index.wrapping_mul(0xd1b5_4a32_d192_ed03).wrapping_add(1))
    }
}

/// The two uniforms in (0, 1) of 32 bits each in `bits` (high, low).
#[inline]
pub fn two_uniforms_of(bits: u64) -> (f64, f64) {
    let scale = 1.0 / (1u64 << 32) as f64;
    (
        ((bits >> 32) as f64 + 0.5) * scale,
        ((bits & 0xffff_ffff) as f64 + 0.5) * scale,
    )
}

/// Acklam's rational approximation of the standard normal quantile:
/// absolute error < 3e-9 for p in [0.02425, 0.97575], < 1.3e-5 in the
/// tails beyond (measured against Python's `statistics.NormalDist` over
/// p ∈ [1e-16, 0.5]), far below the noise it draws. Coefficients of the
/// central region …
const ACKLAM_A: [f64; 6] = [
    -3.969_683_028_665_376e1,
    2.209_460_984_245_205e2,
    -2.759_285_104_469_687e2,
    1.383_577_518_672_69e2,
    -3.066_479_806_614_716e1,
    2.506_628_277_459_239,
];
const ACKLAM_B: [f64; 5] = [
    -5.447_609_879_822_406e1,
    1.615_858_368_580_409e2,
    -1.556_989_798_598_866e2,
    6.680_131_188_771_972e1,
    -1.328_068_155_288_572e1,
];
/// … and of the tails.
const ACKLAM_C: [f64; 6] = [
    -7.784_894_002_430_293e-3,
    -3.223_964_580_411_365e-1,
    -2.400_758_277_161_838,
    -2.549_671_348_850_926,
    4.374_664_141_464_968,
    2.938_163_982_698_783,
];
const ACKLAM_D: [f64; 4] = [
    7.784_695_709_041_462e-3,
    3.224_671_290_700_398e-1,
    2.445_134_137_142_996,
    3.754_408_661_907_416,
];

/// Where Acklam's central region ends.
const P_LOW: f64 = 0.02425;

/// Acklam's lower-tail formula at p (< 0.5; used below P_LOW).
fn acklam_tail(p: f64) -> f64 {
    let q = (-2.0 * p.ln()).sqrt();
    let c = &ACKLAM_C;
    let d = &ACKLAM_D;
    (((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5])
        / ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1.0)
}

/// The standard normal quantile Φ⁻¹(p), p ∈ (0, 1).
#[inline]
pub fn normal_quantile(p: f64) -> f64 {
    let tail = |q: f64| {
        let c = &ACKLAM_C;
        let d = &ACKLAM_D;
        (((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5])
            / ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1.0)
    };
    if p < P_LOW {
        tail((-2.0 * p.ln()).sqrt())
    } else if p > 1.0 - P_LOW {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    } else {
        let (a, b) = (&ACKLAM_A, &ACKLAM_B);
        let q = p - 0.5;
        let r = q * q;
        (((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5]) * q
            / (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1.0)
    }
}

/// Nodes of the central table of [`normal_quantile_fast`].
const CENTRAL_NODES: usize = 8192;

/// Φ⁻¹ at `CENTRAL_NODES + 1` equally spaced p over [P_LOW, 1 − P_LOW].
fn central_table() -> &'static [f64] {
    static TABLE: std::sync::OnceLock<Vec<f64>> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        let step = (1.0 - 2.0 * P_LOW) / CENTRAL_NODES as f64;
        (0..=CENTRAL_NODES)
            .map(|i| normal_quantile(P_LOW + i as f64 * step))
            .collect()
    })
}

/// Octaves of p below P_LOW the tail table covers: down to 2⁻³⁴, below
/// the smallest 32-bit uniform's 2⁻³³.
const TAIL_OCTAVES: usize = 34;
/// Nodes per octave of the tail table.
const TAIL_NODES: usize = 128;

/// Φ⁻¹ at p = 2^−(e+1) · (1 + j / TAIL_NODES), octave e < TAIL_OCTAVES,
/// j ≤ TAIL_NODES, row-major by octave.
fn tail_table() -> &'static [f64] {
    static TABLE: std::sync::OnceLock<Vec<f64>> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        (0..TAIL_OCTAVES)
            .flat_map(|e| {
                let base = 0.5f64.powi(e as i32 + 1);
                // The tail formula at every node, also those of the octave
                // holding P_LOW that lie above it: Acklam's two regions
                // differ by ~10⁻⁵ there, which would bend the last segment.
                (0..=TAIL_NODES)
                    .map(move |j| acklam_tail(base * (1.0 + j as f64 / TAIL_NODES as f64)))
            })
            .collect()
    })
}

/// Φ⁻¹(p) for p < P_LOW from the tail table, linear in p within an
/// octave [2^−(e+1), 2^−e): with Φ⁻¹'' ≈ 1 / (p² |z|) there, the
/// interpolation error is below 1 / (8 TAIL_NODES² |z|) < 4·10⁻⁶ (|z| > 1.97;
/// 2.6·10⁻⁶ measured against Python's `statistics.NormalDist`).
#[inline]
fn lower_tail(p: f64) -> f64 {
    let bits = p.to_bits();
    // p = (1 + f) · 2^exponent, exponent = −(e + 1).
    let exponent = ((bits >> 52) & 0x7ff) as i64 - 1023;
    let octave = (-exponent - 1) as usize;
    if octave >= TAIL_OCTAVES || exponent >= 0 {
        return normal_quantile(p);
    }
    let f = f64::from_bits((bits & ((1u64 << 52) - 1)) | (1023u64 << 52)) - 1.0;
    let x = f * TAIL_NODES as f64;
    let j = (x as usize).min(TAIL_NODES - 1);
    let row = &tail_table()[octave * (TAIL_NODES + 1)..][..TAIL_NODES + 1];
    row[j] + (x - j as f64) * (row[j + 1] - row[j])
}

/// [`normal_quantile_fast`] outside [P_LOW, 1 − P_LOW] (and of NaN).
#[inline(never)]
fn tails(p: f64) -> f64 {
    if p < P_LOW {
        lower_tail(p)
    } else if p > 1.0 - P_LOW {
        -lower_tail(1.0 - p)
    } else {
        normal_quantile(p)
    }
}

/// Φ⁻¹(p) as [`normal_quantile`], linear between tabulated nodes over
/// [P_LOW, 1 − P_LOW]: the interpolation error is below
/// h²/8 · max|Φ⁻¹''| = (1.16·10⁻⁴)²/8 · 609 < 1.1·10⁻⁶ (Φ⁻¹'' = z/φ(z)²,
/// largest at the region's ends, z = ±1.97); the tails from a table per
/// octave of p (`lower_tail`, within 4·10⁻⁶ of [`normal_quantile`] down to
/// p = 2⁻³⁴, exactly it below).
#[inline(always)]
pub fn normal_quantile_fast(p: f64) -> f64 {
    if !(P_LOW..=1.0 - P_LOW).contains(&p) {
        return tails(p);
    }
    let table = central_table();
    let x = (p - P_LOW) * (CENTRAL_NODES as f64 / (1.0 - 2.0 * P_LOW));
    let i = (x as usize).min(CENTRAL_NODES - 1);
    let t = x - i as f64;
    table[i] + t * (table[i + 1] - table[i])
}

impl Rng {
    /// Standard normal by inversion ([`normal_quantile_fast`]): a table
    /// lookup for 95 % of the draws, several times cheaper than
    /// [`Rng::normal`] (the sensor chain draws one or two per pixel).
    #[inline]
    pub fn normal_fast(&mut self) -> f64 {
        normal_quantile_fast(self.uniform())
    }

    /// Two uniforms in (0, 1) of 32 bits each from one draw (a dark
    /// pixel's Poisson step and read noise: 2⁻³² resolves a dark mean of
    /// 10⁻⁹ e⁻ and normal tails to 6.2 σ).
    #[inline]
    pub fn two_uniforms(&mut self) -> (f64, f64) {
        two_uniforms_of(self.next_u64())
    }

    /// Poisson of a mean below 30 whose e^(−mean) is `limit` (Knuth's
    /// method, as [`Rng::poisson`]): a caller drawing many times at one
    /// mean computes the exponential once.
    #[inline]
    pub fn poisson_small(&mut self, limit: f64) -> f64 {
        let first = self.uniform();
        self.poisson_small_from(first, limit)
    }

    /// [`Rng::poisson_small`] given its first uniform `first`.
    #[inline]
    pub fn poisson_small_from(&mut self, first: f64, limit: f64) -> f64 {
        let mut k = 0.0;
        let mut p = first;
        while p > limit {
            k += 1.0;
            p *= self.uniform();
        }
        k
    }

    /// Poisson with mean `mean` ≥ 0 as [`Rng::poisson`], with
    /// [`Rng::normal_fast`] above 30.
    #[inline]
    pub fn poisson_fast(&mut self, mean: f64) -> f64 {
        if mean < 30.0 {
            return self.poisson(mean);
        }
        (mean + mean.sqrt() * self.normal_fast()).round().max(0.0)
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
    fn normal_quantile_matches_tabulated_values() {
        // Φ⁻¹ from standard tables; the central region and the tails have
        // their own accuracy.
        for (p, z, tolerance) in [
            (0.5, 0.0, 1e-8),
            (0.975, 1.959_963_984_540_054, 1e-8),
            (0.1, -1.281_551_565_544_601, 1e-8),
            (0.01, -2.326_347_874_040_841, 2e-5),
            (0.999, 3.090_232_306_167_813, 2e-5),
            (1e-9, -5.997_807_015_007_686, 2e-5),
        ] {
            let got = normal_quantile(p);
            assert!((got - z).abs() < tolerance, "{p}: {got}");
        }
        let mut r = Rng::new(3, 4, 5);
        let n = 200_000;
        let xs: Vec<f64> = (0..n).map(|_| r.normal_fast()).collect();
        let mean = xs.iter().sum::<f64>() / n as f64;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64;
        assert!(
            mean.abs() < 0.01 && (var - 1.0).abs() < 0.01,
            "{mean} {var}"
        );
    }

    /// The table's interpolation stays within its stated bound of the
    /// rational approximation, over 10⁶ points and at the region's ends.
    #[test]
    fn fast_quantile_matches_the_rational_one() {
        let n = 1_000_000;
        let worst = (0..=n)
            .map(|i| 0.0243 + 0.9514 * i as f64 / n as f64)
            .map(|p| (normal_quantile_fast(p) - normal_quantile(p)).abs())
            .fold(0.0, f64::max);
        assert!(worst < 1.1e-6, "{worst}");
        // The tails, log-spaced from 2⁻³⁶ to P_LOW, both sides.
        let worst = (0..=n)
            .map(|i| (P_LOW.ln() + (2f64.powi(-36) / P_LOW).ln() * i as f64 / n as f64).exp())
            .flat_map(|p| [p, 1.0 - p])
            .map(|p| (normal_quantile_fast(p) - normal_quantile(p)).abs())
            .fold(0.0, f64::max);
        assert!(worst < 4e-6, "{worst}");
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
        let s = Stream::new(1, 2);
        assert_eq!(s.at(3).next_u64(), Stream::new(1, 2).at(3).next_u64());
        assert_ne!(s.at(3).next_u64(), s.at(4).next_u64());
        assert_ne!(s.at(3).next_u64(), Stream::new(1, 3).at(3).next_u64());
    }

    /// Neighbouring indices of one stream are uncorrelated: the Pearson
    /// correlation of the first uniform of index k and of k + 1 over 10⁵
    /// indices is within 4 standard errors (4/√n) of 0, and their mean
    /// and variance are a uniform's.
    #[test]
    fn stream_indices_are_uncorrelated_uniforms() {
        let s = Stream::new(9, 1 << 32);
        let n = 100_000;
        let u: Vec<f64> = (0..=n).map(|k| s.at(k as u64).uniform()).collect();
        let m = u.iter().sum::<f64>() / u.len() as f64;
        let v = u.iter().map(|x| (x - m).powi(2)).sum::<f64>() / u.len() as f64;
        assert!(
            (m - 0.5).abs() < 0.005 && (v - 1.0 / 12.0).abs() < 0.002,
            "{m} {v}"
        );
        let c = (0..n).map(|k| (u[k] - m) * (u[k + 1] - m)).sum::<f64>() / n as f64 / v;
        assert!(c.abs() < 4.0 / (n as f64).sqrt(), "{c}");
    }
}
