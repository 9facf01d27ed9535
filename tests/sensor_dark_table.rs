//! The sensor's dark pixels (`src/sensor/dark.rs`): a pixel without light
//! draws Poisson(d) + σ N(0, 1) from one table of 2¹⁶ equally likely cells.
//! Against the exact distribution written here (the Poisson pmf by its
//! recurrence convolved with the normal CDF): the table's mean, variance
//! and cells; and the DN histograms of whole dark frames (10⁶ pixels,
//! several seeds and frames, with and without DSNU) against the exact
//! quantised distribution by chi-square and Kolmogorov–Smirnov.

use optistim::sensor::dark::{DarkTable, LEVELS};
use optistim::sensor::{Readout, Sensor, SensorParams};

/// P(Poisson(d) + σ N(0, 1) ≤ y), by direct convolution (d ≤ 150, so
/// e^(−d) does not underflow).
fn exact_cdf(y: f64, d: f64, sigma: f64) -> f64 {
    let normal = |z: f64| 0.5 * libm::erfc(-z / std::f64::consts::SQRT_2);
    let mut pmf = (-d).exp();
    let mut sum = 0.0;
    let last = (d + 15.0 * d.sqrt() + 30.0) as usize;
    for k in 0..=last {
        sum += pmf * normal((y - k as f64) / sigma);
        pmf *= d / (k + 1) as f64;
    }
    sum
}

/// The exact quantile, by bisection of [`exact_cdf`].
fn exact_quantile(p: f64, d: f64, sigma: f64) -> f64 {
    let (mut lo, mut hi) = (-12.0 * sigma, d + 15.0 * d.sqrt() + 30.0 + 12.0 * sigma);
    for _ in 0..80 {
        let mid = 0.5 * (lo + hi);
        if exact_cdf(mid, d, sigma) < p {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// [`exact_cdf`] at steps of σ/400, linear between them (within 10⁻⁶ of
/// it: the many DSNU values of a frame each need the CDF at every DN).
struct TabulatedCdf {
    lo: f64,
    step: f64,
    values: Vec<f64>,
}

impl TabulatedCdf {
    fn new(d: f64, sigma: f64) -> TabulatedCdf {
        let (lo, hi) = (-12.0 * sigma, d + 15.0 * d.sqrt() + 30.0 + 12.0 * sigma);
        let step = sigma / 400.0;
        let n = ((hi - lo) / step).ceil() as usize + 1;
        let values = (0..n)
            .map(|i| exact_cdf(lo + i as f64 * step, d, sigma))
            .collect();
        TabulatedCdf { lo, step, values }
    }

    fn at(&self, y: f64) -> f64 {
        let x = (y - self.lo) / self.step;
        if x <= 0.0 {
            return 0.0;
        }
        let i = x as usize;
        if i + 1 >= self.values.len() {
            return 1.0;
        }
        let t = x - i as f64;
        self.values[i] + t * (self.values[i + 1] - self.values[i])
    }
}

const CASES: [(f64, f64); 5] = [
    (1e-3, 6.0),
    (0.7, 1.0),
    (2.0, 0.3),
    (12.0, 3.0),
    (150.0, 8.0),
];

/// The table's mean is d and its variance d + σ² (each cell takes its
/// mean, losing only the spread inside cells), and each sampled cell's
/// value lies between the exact quantiles at its edges.
#[test]
fn the_table_has_the_exact_moments_and_cells() {
    for (d, sigma) in CASES {
        let table = DarkTable::new(d, sigma).expect("a table");
        assert_eq!(table.values.len(), LEVELS);
        let n = LEVELS as f64;
        let mean = table.values.iter().sum::<f64>() / n;
        let var = table.values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
        let var_exact = d + sigma * sigma;
        println!(
            "d = {d}, σ = {sigma}: mean {mean:.6} (exact {d}), variance {var:.6} (exact {var_exact}, ratio {:.2e})",
            var / var_exact - 1.0
        );
        assert!((mean - d).abs() < 1e-4 * sigma, "mean {mean} vs {d}");
        assert!(
            (var / var_exact - 1.0).abs() < 3e-5,
            "variance {var} vs {var_exact}"
        );
        for cell in [1usize, 655, 6_553, 32_768, 58_982, 64_880, LEVELS - 2] {
            let lo = exact_quantile(cell as f64 / n, d, sigma);
            let hi = exact_quantile((cell + 1) as f64 / n, d, sigma);
            let v = table.values[cell];
            let slack = 1e-3 * sigma;
            println!("  cell {cell}: {v:.5} within [{lo:.5}, {hi:.5}]");
            assert!(
                v >= lo - slack && v <= hi + slack,
                "cell {cell}: {v} not in [{lo}, {hi}]"
            );
        }
    }
}

fn dark_sensor(seed: u64, d: f64, sigma: f64, dsnu: f64, gain: f64, side: usize) -> Sensor {
    let params = SensorParams {
        seed,
        dark_current: d, // over an exposure of 1 s
        read_noise: sigma,
        prnu: 0.01,
        dsnu,
        offset: 100.0,
        transfer_time: 1e-3,
        blooming: true,
        nonlinearity: 0.0,
        row_noise: 0.0,
        shot_noise: true,
    };
    let readout = Readout {
        full_well: 1e5,
        gain,
        bits: 16,
    };
    Sensor::new(params, readout, side, side)
}

/// Chi-square of `counts` against `expected` over bins merged until each
/// expects ≥ 20, and its degrees of freedom; and the Kolmogorov–Smirnov
/// distance of the cumulative counts times √n.
fn fit(counts: &[f64], expected: &[f64]) -> (f64, f64, f64) {
    let n: f64 = counts.iter().sum();
    let (mut chi2, mut bins) = (0.0, 0.0);
    let (mut c, mut e) = (0.0, 0.0);
    for (&ci, &ei) in counts.iter().zip(expected) {
        c += ci;
        e += ei;
        if e >= 20.0 {
            chi2 += (c - e) * (c - e) / e;
            bins += 1.0;
            (c, e) = (0.0, 0.0);
        }
    }
    chi2 += if e > 0.0 { (c - e) * (c - e) / e } else { 0.0 };
    let (mut cc, mut ce, mut ks) = (0.0f64, 0.0f64, 0.0f64);
    for (&ci, &ei) in counts.iter().zip(expected) {
        cc += ci;
        ce += ei;
        ks = ks.max((cc - ce).abs() / n);
    }
    (chi2, bins, ks * n.sqrt())
}

/// Chi-square's critical value at about p = 10⁻⁴ (Wilson–Hilferty).
fn chi2_limit(df: f64) -> f64 {
    let z = 3.72;
    df * (1.0 - 2.0 / (9.0 * df) + z * (2.0 / (9.0 * df)).sqrt()).powi(3)
}

/// DN histograms of dark frames against P(DN = m) = Σ_k [F((m + ½ − o)/K −
/// DSNU_k) − F((m − ½ − o)/K − DSNU_k)] / N, the exact distribution of
/// round(offset + K (Y + DSNU_k)).
fn check_frames(d: f64, sigma: f64, dsnu: f64, gain: f64, side: usize, seeds: &[u64]) {
    let dark = vec![0.0f32; side * side];
    for &seed in seeds {
        let sensor = dark_sensor(seed, d, sigma, dsnu, gain, side);
        let (lo, hi) = (
            (100.0 + gain * (-7.0 * sigma - 4.0 * dsnu))
                .floor()
                .max(0.0) as usize,
            (100.0 + gain * (d + 8.0 * d.sqrt() + 7.0 * sigma + 4.0 * dsnu)).ceil() as usize + 2,
        );
        // Pixels of one DSNU share their expected histogram: DSNU per
        // distinct value (all 0 without DSNU).
        let mut offsets: Vec<f32> = sensor.dsnu_map().to_vec();
        offsets.sort_by(f32::total_cmp);
        let cdf = TabulatedCdf::new(d, sigma);
        let mut expected = vec![0.0; hi - lo + 1];
        let mut run = 0usize;
        while run < offsets.len() {
            let same = offsets[run..]
                .iter()
                .take_while(|&&o| o == offsets[run])
                .count();
            let o = offsets[run] as f64;
            for (m, e) in (lo..=hi).zip(expected.iter_mut()) {
                let edge = |x: f64| cdf.at((x - 100.0) / gain - o);
                let low = if m == lo { 0.0 } else { edge(m as f64 - 0.5) };
                let high = if m == hi { 1.0 } else { edge(m as f64 + 0.5) };
                *e += same as f64 * (high - low);
            }
            run += same;
        }
        for frame in [0, 1, 7] {
            let dn = sensor.expose(&dark, 1.0, frame).dn;
            let mut counts = vec![0.0; hi - lo + 1];
            for &v in &dn {
                counts[(v as usize).clamp(lo, hi) - lo] += 1.0;
            }
            let (chi2, bins, ks) = fit(&counts, &expected);
            let df = bins - 1.0;
            println!(
                "d = {d}, σ = {sigma}, DSNU {dsnu}, K = {gain}, seed {seed}, frame {frame}: χ² = {chi2:.1} on {df} df (limit {:.1}), KS √n D = {ks:.3}",
                chi2_limit(df)
            );
            assert!(chi2 < chi2_limit(df), "χ² {chi2} on {df} df");
            assert!(ks < 1.95, "KS {ks}");
        }
    }
}

#[test]
fn dark_frames_follow_the_exact_quantised_distribution() {
    // 10⁶ pixels a frame; a gain that resolves the read noise in DN.
    check_frames(1e-3, 6.0, 0.0, 1.0, 1024, &[1, 2]);
    check_frames(2.5, 3.0, 0.0, 2.0, 1024, &[3]);
}

#[test]
fn dark_frames_with_dsnu_follow_the_exact_distribution() {
    check_frames(0.8, 1.5, 2.0, 1.0, 512, &[4, 5]);
}

/// Dark-frame statistics, with and without DSNU: the frame mean is
/// offset + K (d + mean DSNU) and its spatial variance K² (d + σ² +
/// var DSNU) + 1/12 (rounding), within 4 standard errors.
#[test]
fn dark_frame_mean_and_variance() {
    let (d, sigma, gain, side) = (5.0, 4.0, 1.0, 1024);
    for dsnu in [0.0, 3.0] {
        let sensor = dark_sensor(9, d, sigma, dsnu, gain, side);
        let map: Vec<f64> = sensor.dsnu_map().iter().map(|&v| v as f64).collect();
        let n = map.len() as f64;
        let map_mean = map.iter().sum::<f64>() / n;
        let map_var = map.iter().map(|v| (v - map_mean).powi(2)).sum::<f64>() / n;
        let dn = sensor.expose(&vec![0.0f32; side * side], 1.0, 3).dn;
        let mean = dn.iter().map(|&v| v as f64).sum::<f64>() / n;
        let var = dn.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / n;
        let want_mean = 100.0 + gain * (d + map_mean);
        let want_var = gain * gain * (d + sigma * sigma + map_var) + 1.0 / 12.0;
        println!("DSNU {dsnu}: mean {mean:.4} ({want_mean:.4}), variance {var:.4} ({want_var:.4})");
        assert!((mean - want_mean).abs() < 4.0 * (want_var / n).sqrt());
        assert!((var - want_var).abs() < 4.0 * want_var * (2.0 / n).sqrt() + 0.01);
    }
}

/// A row offset shifts a row of dark pixels like DSNU: over 512 rows the
/// variance of the row means is K² σ_row² plus the pixels' own
/// (K² (d + σ²) + 1/12) / width, within 4 standard errors (√(2/rows) of
/// it); without the offset the rows would scatter 300 times less.
#[test]
fn dark_frames_with_row_noise_shift_whole_rows() {
    let (d, sigma, row_noise, side) = (5.0, 4.0, 3.0, 512);
    let params = SensorParams {
        seed: 11,
        dark_current: d,
        read_noise: sigma,
        prnu: 0.0,
        dsnu: 0.0,
        offset: 100.0,
        transfer_time: 0.0,
        blooming: false,
        nonlinearity: 0.0,
        row_noise,
        shot_noise: true,
    };
    let readout = Readout {
        full_well: 1e5,
        gain: 1.0,
        bits: 16,
    };
    let sensor = Sensor::new(params, readout, side, side);
    let dn = sensor.expose(&vec![0.0f32; side * side], 1.0, 2).dn;
    let rows: Vec<f64> = dn
        .chunks(side)
        .map(|r| r.iter().map(|&v| v as f64).sum::<f64>() / side as f64)
        .collect();
    let n = rows.len() as f64;
    let mean = rows.iter().sum::<f64>() / n;
    let var = rows.iter().map(|m| (m - mean).powi(2)).sum::<f64>() / (n - 1.0);
    let want = row_noise * row_noise + (d + sigma * sigma + 1.0 / 12.0) / side as f64;
    println!("row means: variance {var:.4} ({want:.4}), mean {mean:.4}");
    assert!(
        (var - want).abs() < 4.0 * want * (2.0 / n).sqrt(),
        "{var} vs {want}"
    );
    assert!((mean - 100.0 - d).abs() < 4.0 * (want / n).sqrt(), "{mean}");
}
