//! The sensor's lit pixels and its pixels lit by smear alone, whole
//! frames against distributions written here: a pixel of mean μ reads
//! round(offset + K (Poisson(μ) + σ N(0, 1))), whose DN histogram is
//! Σ_k pmf(k) [Φ((m + ½ − o)/Kσ − k/σ) − Φ((m − ½ − o)/Kσ − k/σ)] (the pmf
//! summed in logs, so large means do not underflow). Checked by chi-square
//! and Kolmogorov–Smirnov over 6.5·10⁴ to 2.6·10⁵ pixels: flat frames at
//! means drawn by inversion (3 e⁻) and by PD (40, 400 e⁻), and the
//! columns a bright row smears, whose other pixels draw from their
//! column's inversion table; the smear is computed here from the PRNU
//! map as transfer_time / height · Σ_column PRNU · rate.

use optistim::sensor::{Readout, Sensor, SensorParams};

const SIDE: usize = 512;
const OFFSET: f64 = 100.0;

fn sensor(seed: u64, dark: f64, sigma: f64, prnu: f64, transfer: f64) -> Sensor {
    let params = SensorParams {
        seed,
        dark_current: dark, // over an exposure of 1 s
        read_noise: sigma,
        prnu,
        dsnu: 0.0,
        offset: OFFSET,
        transfer_time: transfer,
        blooming: false,
        nonlinearity: 0.0,
        row_noise: 0.0,
        shot_noise: true,
    };
    let readout = Readout {
        full_well: 1e6,
        gain: 1.0,
        bits: 16,
    };
    Sensor::new(params, readout, SIDE, SIDE)
}

/// Φ(z).
fn phi(z: f64) -> f64 {
    0.5 * libm::erfc(-z / std::f64::consts::SQRT_2)
}

/// P(DN = m) for m in `lo..=hi` (the ends take the tails) of a pixel of
/// mean `mean` with read noise `sigma`, gain 1.
fn expected_dn(mean: f64, sigma: f64, lo: usize, hi: usize) -> Vec<f64> {
    let last = (mean + 15.0 * mean.sqrt() + 30.0) as usize;
    let mut ln_factorial = 0.0;
    let pmf: Vec<f64> = (0..=last)
        .map(|k| {
            if k > 0 {
                ln_factorial += (k as f64).ln();
            }
            (k as f64 * mean.ln() - mean - ln_factorial).exp()
        })
        .collect();
    let cdf = |y: f64| -> f64 {
        pmf.iter()
            .enumerate()
            .map(|(k, p)| p * phi((y - k as f64) / sigma))
            .sum()
    };
    (lo..=hi)
        .map(|m| {
            let low = if m == lo {
                0.0
            } else {
                cdf(m as f64 - 0.5 - OFFSET)
            };
            let high = if m == hi {
                1.0
            } else {
                cdf(m as f64 + 0.5 - OFFSET)
            };
            high - low
        })
        .collect()
}

/// Chi-square of `counts` against `n · p` over bins merged until each
/// expects ≥ 20, its degrees of freedom, and √n times the KS distance.
fn fit(counts: &[f64], p: &[f64]) -> (f64, f64, f64) {
    let n: f64 = counts.iter().sum();
    let (mut chi2, mut bins) = (0.0, 0.0);
    let (mut c, mut e) = (0.0, 0.0);
    for (&ci, &pi) in counts.iter().zip(p) {
        c += ci;
        e += n * pi;
        if e >= 20.0 {
            chi2 += (c - e) * (c - e) / e;
            bins += 1.0;
            (c, e) = (0.0, 0.0);
        }
    }
    if e > 0.0 {
        chi2 += (c - e) * (c - e) / e;
        bins += 1.0;
    }
    let (mut cc, mut ce, mut ks) = (0.0f64, 0.0f64, 0.0f64);
    for (&ci, &pi) in counts.iter().zip(p) {
        cc += ci;
        ce += n * pi;
        ks = ks.max((cc - ce).abs() / n);
    }
    (chi2, bins - 1.0, ks * n.sqrt())
}

/// Chi-square's critical value at about p = 10⁻⁴ (Wilson–Hilferty).
fn chi2_limit(df: f64) -> f64 {
    let a = 2.0 / (9.0 * df);
    df * (1.0 - a + 3.72 * a.sqrt()).powi(3)
}

/// The DN histogram of `values` against the mixture of pixels of the
/// means `means` in equal numbers.
fn check(values: &[u16], means: &[f64], sigma: f64, what: &str) {
    let (low, high) = means
        .iter()
        .fold((f64::MAX, 0.0f64), |(a, b), &m| (a.min(m), b.max(m)));
    let spread = |m: f64| 7.0 * (m + sigma * sigma).sqrt() + 3.0;
    let lo = (OFFSET + low - spread(low)).floor().max(0.0) as usize;
    let hi = (OFFSET + high + spread(high)).ceil() as usize;
    let mut p = vec![0.0; hi - lo + 1];
    for &m in means {
        for (a, b) in p.iter_mut().zip(expected_dn(m, sigma, lo, hi)) {
            *a += b / means.len() as f64;
        }
    }
    let mut counts = vec![0.0; hi - lo + 1];
    for &v in values {
        counts[(v as usize).clamp(lo, hi) - lo] += 1.0;
    }
    let (chi2, df, ks) = fit(&counts, &p);
    println!(
        "{what}: μ = {low:.3}–{high:.3}, {} pixels: χ² = {chi2:.1} on {df} df (limit {:.1}), KS √n D = {ks:.3}",
        values.len(),
        chi2_limit(df)
    );
    assert!(chi2 < chi2_limit(df), "{what}: χ² {chi2} on {df} df");
    assert!(ks < 1.95, "{what}: KS {ks}");
}

#[test]
fn flat_lit_frames_follow_poisson_plus_read_noise() {
    let (dark, sigma) = (0.5, 2.0);
    for (case, light) in [3.0, 40.0, 400.0].into_iter().enumerate() {
        let s = sensor(20 + case as u64, dark, sigma, 0.0, 0.0);
        let rate = vec![light as f32; SIDE * SIDE];
        for frame in [0, 5] {
            let dn = s.expose(&rate, 1.0, frame).dn;
            check(&dn, &[light + dark], sigma, &format!("flat, frame {frame}"));
        }
    }
}

/// A bright first row smears every column; the other rows have no light
/// of their own, so rows 1.. of column c all have mean d + smear_c. The
/// columns of each of four rates (128 each) are checked together against
/// the mixture of their 128 means.
#[test]
fn smear_only_pixels_follow_their_columns_poisson() {
    let (dark, sigma, transfer) = (0.2, 1.5, 1e-3);
    // Smear ≈ 0.4, 7.8, 39 and 195 e⁻.
    let rates = [2.0e5, 4.0e6, 2.0e7, 1.0e8];
    for seed in [31u64, 32] {
        // PRNU 2 %: the smear sums PRNU · rate over the column.
        let s = sensor(seed, dark, sigma, 0.02, transfer);
        let mut rate = vec![0.0f32; SIDE * SIDE];
        for (i, r) in rate[..SIDE].iter_mut().enumerate() {
            *r = rates[i % 4] as f32;
        }
        let prnu = s.prnu_map();
        let dn = s.expose(&rate, 1.0, 3).dn;
        for group in 0..rates.len() {
            let columns: Vec<usize> = (group..SIDE).step_by(rates.len()).collect();
            let means: Vec<f64> = columns
                .iter()
                .map(|&i| dark + transfer / SIDE as f64 * prnu[i] as f64 * rate[i] as f64)
                .collect();
            let values: Vec<u16> = columns
                .iter()
                .flat_map(|&i| (1..SIDE).map(move |j| j * SIDE + i))
                .map(|k| dn[k])
                .collect();
            check(&values, &means, sigma, &format!("smear, seed {seed}"));
        }
    }
}
