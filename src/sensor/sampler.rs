//! The lit pixels' draws from raw random bits: a standard normal from 32
//! bits by one table lookup without branches, and an exact Poisson draw
//! at any mean (inversion below [`PD_MEAN`], Ahrens and Dieter's
//! algorithm PD above). A lit pixel takes one 64-bit hash
//! ([`poisson_of_hash`]; a second only for PD's rare steps), so these are
//! the sensor chain's inner loop.
//!
//! PD (Ahrens & Dieter 1982, ACM TOMS 8, 163–179) draws K = ⌊μ + √μ T⌋
//! from a normal T and accepts it at once when K ≥ ⌊μ − 1.1484⌋ or, with
//! one more uniform, when 6μ²U ≥ (μ − K)³; the rest (about 1 % of draws
//! at μ = 30, fewer above) goes through the pmf ratio test and the
//! double-exponential fallback, which make the result Poisson exactly.
//! Here the pmf's log is exact (a log-gamma and `ln_1p`, not the paper's
//! 7-digit series).

use std::sync::OnceLock;

use crate::sensor::rng::Rng;

/// Poisson draws of this mean and above use PD, below it inversion.
pub const PD_MEAN: f64 = 10.0;
/// Octaves of the normal table: q = min(p, 1 − p) ∈ [2⁻³³, 2⁻¹).
const OCTAVES: usize = 32;
/// Nodes per octave (the top 8 bits of q's mantissa).
const NODES: usize = 256;

/// The uniform in (0, 1) of 32 bits: (b + ½) / 2³².
#[inline(always)]
pub fn uniform_of_bits(b: u32) -> f64 {
    (b as f64 + 0.5) * (1.0 / 4_294_967_296.0)
}

/// Φ⁻¹(q) for 0 < q ≤ ½: the rational approximation polished by three
/// Halley steps on Φ = erfc / 2 (to ~10⁻¹⁵).
pub fn normal_quantile_exact(q: f64) -> f64 {
    let mut z = crate::sensor::rng::normal_quantile(q);
    for _ in 0..3 {
        let e = 0.5 * libm::erfc(-z / std::f64::consts::SQRT_2) - q;
        let u = e * (std::f64::consts::TAU).sqrt() * (0.5 * z * z).exp();
        z -= u / (1.0 + 0.5 * z * u);
    }
    z
}

/// Φ⁻¹ at q = 2^−(o+2) (1 + j / NODES), octave o < OCTAVES, j ≤ NODES.
fn normal_table() -> &'static [f64] {
    static TABLE: OnceLock<Vec<f64>> = OnceLock::new();
    TABLE.get_or_init(|| {
        (0..OCTAVES)
            .flat_map(|o| {
                let base = 0.5f64.powi(o as i32 + 2);
                (0..=NODES)
                    .map(move |j| normal_quantile_exact(base * (1.0 + j as f64 / NODES as f64)))
            })
            .collect()
    })
}

/// Φ⁻¹((b + ½) / 2³²): q = min(p, 1 − p) = (2m + 1) / 2³³ is found in
/// its octave by the leading zeros of 2m + 1 and interpolated linearly
/// between 257 nodes per octave (within 8·10⁻⁷ of Φ⁻¹; the sign is
/// the top bit of b). Reaches ±6.23 at the ends.
#[inline(always)]
pub fn normal_of_bits(b: u32) -> f64 {
    normal_in(normal_table(), b)
}

#[inline(always)]
fn normal_in(table: &[f64], b: u32) -> f64 {
    let upper = b >> 31;
    // !b for p > ½: 1 − p = (!b + ½) / 2³².
    let m = b ^ 0u32.wrapping_sub(upper);
    let x = (m << 1) | 1;
    let octave = x.leading_zeros() as usize;
    let mantissa = (x << octave) & 0x7fff_ffff;
    let j = (mantissa >> 23) as usize;
    let t = (mantissa & 0x7f_ffff) as f64 * (1.0 / (1u32 << 23) as f64);
    let row = &table[octave * (NODES + 1)..][..NODES + 1];
    let z = row[j] + t * (row[j + 1] - row[j]);
    f64::from_bits(z.to_bits() ^ ((upper as u64) << 63))
}

/// Poisson(`mean`), any mean ≥ 0, from 32 random bits `bits` (PD's
/// normal, or the uniform inverted below [`PD_MEAN`]) and the generator
/// `more` (PD's further uniforms); `p0()` is e^(−mean), asked for only
/// below [`PD_MEAN`] (a caller drawing many times at one mean passes it
/// once computed).
#[inline]
pub fn poisson(mean: f64, bits: u32, more: &mut Rng, p0: impl FnOnce() -> f64) -> f64 {
    if mean >= PD_MEAN {
        let u = uniform_of_bits(more.next_u64() as u32);
        poisson_pd(mean, normal_of_bits(bits), u, || more.uniform())
    } else {
        poisson_inverse(uniform_of_bits(bits), mean, p0)
    }
}

/// Poisson(`mean`), any mean ≥ 0, from one 64-bit hash `bits`: its top
/// 24 bits give PD's normal (to ±5.4; or, below [`PD_MEAN`], the uniform
/// inverted), bits 16 to 39 PD's step-S uniform; the low 16 bits are left
/// to the caller (the sensor's read noise). `more` gives the rare steps
/// Q and E their uniforms; `p0()` is e^(−mean), asked for only below
/// [`PD_MEAN`].
#[inline]
pub fn poisson_of_hash(
    mean: f64,
    bits: u64,
    more: impl FnMut() -> f64,
    p0: impl FnOnce() -> f64,
) -> f64 {
    // The middle of the 24-bit cell as a 32-bit pattern.
    let top = (((bits >> 40) as u32) << 8) | 0x80;
    if mean >= PD_MEAN {
        let u = (((bits >> 16) & 0xff_ffff) as f64 + 0.5) * (1.0 / (1u32 << 24) as f64);
        poisson_pd(mean, normal_of_bits(top), u, more)
    } else {
        poisson_inverse(uniform_of_bits(top), mean, p0)
    }
}

/// Poisson(`mean`) by inversion of the uniform `u` ∈ (0, 1), for means
/// below [`PD_MEAN`]: the least k with F(k) ≥ u, F summed by the pmf's
/// recurrence from `p0` = e^(−mean). u ≤ 1 − mean ≤ e^(−mean) gives 0
/// without the exponential (most of a faint pixel's draws).
#[inline]
pub fn poisson_inverse(u: f64, mean: f64, p0: impl FnOnce() -> f64) -> f64 {
    if u <= 1.0 - mean {
        return 0.0;
    }
    let mut p = p0();
    let mut f = p;
    let mut k = 0.0;
    // F reaches 1 − 10⁻¹⁶ long before k = 200 for means below 10.
    while u > f && k < 200.0 {
        k += 1.0;
        p *= mean / k;
        f += p;
    }
    k
}

/// Poisson(`mean`), `mean` ≥ [`PD_MEAN`], by PD from the normal `t`
/// (step N) and the uniform `u` ∈ (0, 1) (step S, which about half the
/// draws need: taking it always keeps the test free of branches); `more`
/// gives the further uniforms of the rare steps Q and E (about 1 % of
/// the draws at μ = 30, fewer above).
#[inline]
pub fn poisson_pd(mean: f64, t: f64, u: f64, mut more: impl FnMut() -> f64) -> f64 {
    let s = mean.sqrt();
    let g = mean + s * t;
    let k = g.floor();
    let d = mean - k;
    // Step N accepts K ≥ L = ⌊μ − 1.1484⌋ (then G ≥ 0), step S when
    // 6μ²U ≥ (μ − K)³ (never when G < 0: K ≤ −1 makes (μ − K)³ > 6μ² for
    // μ > 6). One test of the larger margin: half the draws fail step N
    // at random, a branch on it would be mispredicted half the time.
    let margin = (g - (mean - 1.1484).floor()).max(6.0 * mean * mean * u - d * d * d);
    if margin >= 0.0 {
        return k;
    }
    pd_slow(mean, s, g, u, &mut more)
}

/// Steps P, Q and E of PD.
#[cold]
#[inline(never)]
fn pd_slow(mean: f64, s: f64, g: f64, u: f64, more: &mut impl FnMut() -> f64) -> f64 {
    if !mean.is_finite() {
        // An infinite mean (its margin is NaN) would never be accepted.
        return mean;
    }
    let pd = PdConstants::new(mean, s);
    // Step Q: accept K with the ratio of the pmf to the normal's density.
    if g >= 0.0 {
        let k = g.floor();
        let (px, py, fx, fy) = pd.f(k);
        if fy * (1.0 - u) <= py * (px - fx).exp() {
            return k;
        }
    }
    // Step E: double-exponential proposals until one is accepted.
    loop {
        let e = -more().ln();
        let v = 2.0 * more() - 1.0;
        let t = 1.8 + if v < 0.0 { -e } else { e };
        if t <= -0.6744 {
            continue;
        }
        let k = (mean + s * t).floor();
        let (px, py, fx, fy) = pd.f(k);
        if pd.c * v.abs() <= py * (px + e).exp() - fy * (fx + e).exp() {
            return k;
        }
    }
}

/// PD's constants of one mean (step P).
struct PdConstants {
    mean: f64,
    s: f64,
    omega: f64,
    c: f64,
    c0: f64,
    c1: f64,
    c2: f64,
    c3: f64,
}

impl PdConstants {
    fn new(mean: f64, s: f64) -> PdConstants {
        let b1 = 1.0 / (24.0 * mean);
        let b2 = 0.3 * b1 * b1;
        let c3 = b1 * b2 / 7.0;
        let c2 = b2 - 15.0 * c3;
        let c1 = b1 - 6.0 * b2 + 45.0 * c3;
        let c0 = 1.0 - b1 + 3.0 * b2 - 15.0 * c3;
        PdConstants {
            mean,
            s,
            omega: 1.0 / (std::f64::consts::TAU.sqrt() * s),
            c: 0.1069 / mean,
            c0,
            c1,
            c2,
            c3,
        }
    }

    /// Procedure F: pmf(k) = py e^px and the normal-based density
    /// fy e^fx it is compared with.
    fn f(&self, k: f64) -> (f64, f64, f64, f64) {
        let mu = self.mean;
        let (px, py) = if k < 10.0 {
            let mut py = 1.0;
            for i in 1..=k as u32 {
                py *= mu / i as f64;
            }
            (-mu, py)
        } else {
            // ln pmf = k ln(1 + v) − (μ − k) − ½ ln(2πk) − δ(k), v = (μ − k)/k,
            // δ(k) = ln k! − ((k + ½) ln k − k + ½ ln 2π), Stirling's series
            // (its next term is below 10⁻¹² at k = 10).
            let r = 1.0 / (k * k);
            let delta = (1.0 / 12.0 - r * (1.0 / 360.0 - r * (1.0 / 1260.0 - r / 1680.0))) / k;
            let v = (mu - k) / k;
            (
                k * v.ln_1p() - (mu - k) - delta,
                1.0 / (std::f64::consts::TAU * k).sqrt(),
            )
        };
        let x = (k - mu + 0.5) / self.s;
        let xx = x * x;
        let fx = -0.5 * xx;
        let fy = self.omega * (((self.c3 * xx + self.c2) * xx + self.c1) * xx + self.c0);
        (px, py, fx, fy)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every 2²⁰th pattern of 32 bits: within 8·10⁻⁷ of the polished
    /// quantile (checked against bisection in tests/sensor_sampler.rs),
    /// antisymmetric, and monotone.
    #[test]
    fn normal_of_bits_follows_the_quantile() {
        let mut last = f64::NEG_INFINITY;
        for i in 0..=4096u64 {
            let b = (i * (1 << 20)).min(u32::MAX as u64) as u32;
            let p = uniform_of_bits(b);
            let want = if p < 0.5 {
                normal_quantile_exact(p)
            } else {
                -normal_quantile_exact(1.0 - p)
            };
            let z = normal_of_bits(b);
            assert!((z - want).abs() < 8.5e-7, "{b}: {z} vs {want}");
            assert_eq!(z, -normal_of_bits(!b));
            assert!(z >= last);
            last = z;
        }
    }
}
