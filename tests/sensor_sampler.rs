//! The lit pixels' samplers (`src/sensor/sampler.rs`) against distributions
//! written here: the normal from 32 bits against Φ⁻¹ by bisection of
//! erfc, and the Poisson draw (inversion below 10, PD above) against the
//! Poisson pmf by chi-square, Kolmogorov–Smirnov and its mean and
//! variance, at means from 0.5 to 10⁵ and several seeds. The rounded
//! normal the sensor drew before fails the same chi-square at μ = 30,
//! which shows the test can tell.

use optistim::sensor::rng::Stream;
use optistim::sensor::sampler::{
    normal_of_bits, poisson, poisson_inverse, poisson_of_hash, uniform_of_bits,
};

/// Φ(z) = erfc(−z/√2)/2.
fn phi(z: f64) -> f64 {
    0.5 * libm::erfc(-z / std::f64::consts::SQRT_2)
}

/// Φ⁻¹(p) by bisection.
fn quantile(p: f64) -> f64 {
    let (mut lo, mut hi) = (-40.0, 40.0);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if phi(mid) < p {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

#[test]
fn normal_of_bits_is_the_quantile_of_its_uniform() {
    // Bit patterns spread over all 32-bit values, and the extremes.
    let mut patterns: Vec<u32> = (0..20_000u64)
        .map(|i| (i.wrapping_mul(0x9e37_79b9_7f4a_7c15) >> 32) as u32)
        .collect();
    patterns.extend([0, 1, 2, u32::MAX, u32::MAX - 1, 1 << 31, (1 << 31) - 1]);
    for b in patterns {
        let p = uniform_of_bits(b);
        // Φ⁻¹(p) = −Φ⁻¹(1 − p): bisect the smaller one (erfc keeps it exact).
        let want = if p < 0.5 {
            quantile(p)
        } else {
            -quantile(1.0 - p)
        };
        let got = normal_of_bits(b);
        assert!((got - want).abs() < 1e-6, "{b}: {got} vs {want}");
    }
}

/// ln pmf of Poisson(μ) at k = 0..=last, by ln k! summed.
fn poisson_pmf(mean: f64, last: usize) -> Vec<f64> {
    let mut ln_factorial = 0.0;
    (0..=last)
        .map(|k| {
            if k > 0 {
                ln_factorial += (k as f64).ln();
            }
            (k as f64 * mean.ln() - mean - ln_factorial).exp()
        })
        .collect()
}

/// χ² of `counts` against `n · pmf`, bins with fewer than 10 expected
/// merged into their neighbour; (χ², degrees of freedom, √n · KS D).
fn fit(counts: &[f64], pmf: &[f64], n: f64) -> (f64, f64, f64) {
    let (mut chi2, mut bins) = (0.0, 0.0);
    let (mut c, mut e) = (0.0, 0.0);
    let tail: f64 = 1.0 - pmf.iter().sum::<f64>();
    for (k, &p) in pmf.iter().enumerate() {
        c += counts[k];
        e += n * p;
        if e >= 10.0 {
            chi2 += (c - e) * (c - e) / e;
            bins += 1.0;
            (c, e) = (0.0, 0.0);
        }
    }
    c += counts[pmf.len()..].iter().sum::<f64>();
    e += n * tail.max(0.0);
    if e > 0.0 {
        chi2 += (c - e) * (c - e) / e;
    }
    let (mut cc, mut ce, mut ks) = (0.0f64, 0.0f64, 0.0f64);
    for (k, &p) in pmf.iter().enumerate() {
        cc += counts[k];
        ce += n * p;
        ks = ks.max((cc - ce).abs() / n);
    }
    (chi2, bins - 1.0, ks * n.sqrt())
}

/// χ² limit at p ≈ 10⁻⁴ (Wilson–Hilferty, z = 3.72).
fn chi2_limit(df: f64) -> f64 {
    let a = 2.0 / (9.0 * df);
    df * (1.0 - a + 3.72 * a.sqrt()).powi(3)
}

/// `n` draws at `mean` as the sensor wires them: pixel k's hash gives 32
/// bits to the draw, its generator the rest. Each mean has its own
/// stream `case` (shared uniforms would make the means' tests one test).
fn draws(mean: f64, seed: u64, case: u64, n: usize) -> Vec<f64> {
    let stream = Stream::new(seed, (1 << 32) + case);
    (0..n as u64)
        .map(|k| {
            let high = (stream.bits(k) >> 32) as u32;
            poisson(mean, high, &mut stream.at(k), || (-mean).exp())
        })
        .collect()
}

/// [`draws`] as the sensor wires them now: one hash per pixel, 48 of its
/// bits to the draw ([`poisson_of_hash`]), its generator for PD's rare
/// steps.
fn draws_of_hash(mean: f64, seed: u64, case: u64, n: usize) -> Vec<f64> {
    let stream = Stream::new(seed, (1 << 32) + 100 + case);
    (0..n as u64)
        .map(|k| {
            let mut more = stream.at(k);
            poisson_of_hash(mean, stream.bits(k), || more.uniform(), || (-mean).exp())
        })
        .collect()
}

fn histogram(values: &[f64], bins: usize) -> Vec<f64> {
    let mut counts = vec![0.0; bins + 1];
    for &v in values {
        assert!(v >= 0.0 && v.fract() == 0.0, "{v}");
        counts[(v as usize).min(bins)] += 1.0;
    }
    counts
}

#[test]
fn poisson_draws_follow_the_pmf_at_every_mean() {
    check_draws(draws);
}

#[test]
fn one_hash_poisson_draws_follow_the_pmf_at_every_mean() {
    check_draws(draws_of_hash);
}

/// The draws of `draw` (mean, seed, case, n) against the pmf.
fn check_draws(draw: fn(f64, u64, u64, usize) -> Vec<f64>) {
    let n = 200_000;
    for (case, mean) in [0.5, 5.0, 9.99, 10.0, 30.0, 1e3, 1e5]
        .into_iter()
        .enumerate()
    {
        let last = (mean + 12.0 * f64::sqrt(mean) + 30.0) as usize;
        let pmf = poisson_pmf(mean, last);
        for seed in [1u64, 2, 3] {
            let x = draw(mean, seed, case as u64, n);
            let (chi2, df, ks) = fit(&histogram(&x, last + 1), &pmf, n as f64);
            assert!(
                chi2 < chi2_limit(df),
                "μ = {mean}, seed {seed}: χ² {chi2:.1} on {df} df (limit {:.1})",
                chi2_limit(df)
            );
            assert!(ks < 1.95, "μ = {mean}, seed {seed}: KS {ks:.3}");
            // Mean and variance within 5 standard errors.
            let m = x.iter().sum::<f64>() / n as f64;
            let v = x.iter().map(|y| (y - m) * (y - m)).sum::<f64>() / n as f64;
            let se_mean = (mean / n as f64).sqrt();
            let se_var = ((mean + 2.0 * mean * mean) / n as f64).sqrt();
            assert!((m - mean).abs() < 5.0 * se_mean, "μ = {mean}: mean {m}");
            assert!((v - mean).abs() < 5.0 * se_var, "μ = {mean}: variance {v}");
        }
    }
}

#[test]
fn the_rounded_normal_fails_the_same_test_at_30() {
    let (mean, n): (f64, usize) = (30.0, 200_000);
    let last = 120;
    let stream = Stream::new(1, 1 << 32);
    let x: Vec<f64> = (0..n as u64)
        .map(|k| {
            let z = normal_of_bits((stream.bits(k) >> 32) as u32);
            (mean + mean.sqrt() * z).round().max(0.0)
        })
        .collect();
    let (chi2, df, _) = fit(&histogram(&x, last + 1), &poisson_pmf(mean, last), n as f64);
    assert!(chi2 > 2.0 * chi2_limit(df), "χ² {chi2} on {df} df");
}

/// Inversion is exact up to the uniform's resolution: over a grid of N
/// uniforms, the share giving k is pmf(k) within 1/N.
#[test]
fn inversion_maps_a_uniform_grid_onto_the_pmf() {
    let grid = 1usize << 20;
    for mean in [0.5, 3.0, 9.5] {
        let pmf = poisson_pmf(mean, 80);
        let mut counts = vec![0usize; 81];
        for i in 0..grid {
            let u = (i as f64 + 0.5) / grid as f64;
            counts[poisson_inverse(u, mean, || (-mean).exp()) as usize] += 1;
        }
        for (k, &c) in counts.iter().enumerate() {
            let share = c as f64 / grid as f64;
            assert!(
                (share - pmf[k]).abs() <= 1.0 / grid as f64 + 1e-12,
                "μ = {mean}, k = {k}: {share} vs {}",
                pmf[k]
            );
        }
    }
}
