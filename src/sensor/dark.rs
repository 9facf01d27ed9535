//! The charge of a pixel that receives no light, drawn from one table.
//!
//! Without light a pixel's charge is Poisson(d) + DSNU_k + σ·N(0, 1),
//! d = dark current × exposure, σ the read noise: apart from the fixed
//! DSNU_k shift every such pixel has the same distribution, that of
//! Y = Poisson(d) + σ·N(0, 1). [`DarkTable`] holds Y's inverse CDF once
//! per (d, σ):
//! [`LEVELS`] equally likely cells of probability, each drawn as the mean
//! of Y over its cell (so the table's mean is Y's and it loses only the
//! spread inside a cell), from the exact CDF F(y) = Σ_k pmf(k) Φ((y − k)/σ)
//! on a grid of σ/128. A pixel draws a cell with 16 random bits.

use std::sync::Arc;

use crate::memo::Memo;

/// Cells of the table: a pixel's draw is 16 random bits.
pub const LEVELS: usize = 1 << 16;
/// Steps of the CDF grid per σ.
const STEPS_PER_SIGMA: f64 = 128.0;
/// Largest CDF work (grid points × Poisson terms per point) a table is
/// built with; beyond it the sensor draws dark pixels one by one.
const MAX_WORK: f64 = 4e7;
/// Half-width of the normal's support considered, in σ (Φ(−9) ≈ 1e-19).
const NORMAL_REACH: f64 = 9.0;

/// Tables of the most recent (d, σ): a frame loop at a few exposures
/// builds each once.
static TABLES: Memo<(u64, u64), Option<DarkTable>> = Memo::new(4);

/// Y = Poisson(`mean`) + `sigma` · N(0, 1) as [`LEVELS`] equally likely
/// values [e⁻].
#[derive(Debug, Clone, PartialEq)]
pub struct DarkTable {
    /// The mean of Y over each probability cell, increasing.
    pub values: Vec<f64>,
    /// Y stays below this but with probability < 1e-15 [e⁻].
    pub upper: f64,
}

impl DarkTable {
    /// The table of (`mean`, `sigma`), or None when σ is 0 (Y is then
    /// discrete and 2⁻¹⁶ cells would not resolve its small probabilities)
    /// or the CDF would take more than [`MAX_WORK`] terms to tabulate.
    pub fn new(mean: f64, sigma: f64) -> Option<DarkTable> {
        if !(sigma > 0.0 && mean >= 0.0 && mean.is_finite() && sigma.is_finite()) {
            return None;
        }
        let poisson = PoissonSpan::new(mean);
        let h = sigma / STEPS_PER_SIGMA;
        let lo = poisson.first as f64 - NORMAL_REACH * sigma;
        let hi = poisson.last() as f64 + NORMAL_REACH * sigma;
        let steps = ((hi - lo) / h).ceil();
        let terms = poisson
            .pmf
            .len()
            .min((2.0 * NORMAL_REACH * sigma) as usize + 2);
        if steps * terms as f64 > MAX_WORK {
            return None;
        }
        let cdf = |y: f64| poisson.convolved_cdf(y, sigma);
        let grid = (0..=steps as usize).map(|i| {
            let y = lo + i as f64 * h;
            (y, cdf(y))
        });
        Some(DarkTable {
            values: cell_means(grid),
            upper: hi,
        })
    }

    /// The table of (`mean`, `sigma`), built once per process for the
    /// four most recent pairs.
    pub fn shared(mean: f64, sigma: f64) -> Arc<Option<DarkTable>> {
        let built = TABLES.get_or_build((mean.to_bits(), sigma.to_bits()), || {
            Ok::<_, std::convert::Infallible>(DarkTable::new(mean, sigma))
        });
        match built {
            Ok(table) => table,
            Err(never) => match never {},
        }
    }
}

/// N(0, 1) as [`LEVELS`] equally likely cells, each the normal's mean over
/// its cell (the table of Poisson(0) + N(0, 1)): the lit pixels' read
/// noise is σ times a cell drawn with 16 random bits, as the dark pixels'
/// is inside their table. Built once per process.
pub fn standard_normal_cells() -> &'static [f32] {
    static CELLS: std::sync::OnceLock<Vec<f32>> = std::sync::OnceLock::new();
    CELLS.get_or_init(|| match DarkTable::new(0.0, 1.0) {
        Some(t) => t.values.iter().map(|&v| v as f32).collect(),
        None => unreachable!("σ = 1 always has a table"),
    })
}

/// The Poisson pmf over the span holding all but ~1e-16 of it.
struct PoissonSpan {
    first: usize,
    pmf: Vec<f64>,
    /// cumulative[i] = Σ pmf[..i].
    cumulative: Vec<f64>,
}

impl PoissonSpan {
    fn new(mean: f64) -> PoissonSpan {
        let reach = 12.0 * mean.sqrt() + 12.0;
        let first = (mean - reach).max(0.0).floor() as usize;
        let last = (mean + reach).ceil() as usize;
        let pmf: Vec<f64> = (first..=last)
            .map(|k| {
                if mean == 0.0 {
                    f64::from(k == 0)
                } else {
                    let k = k as f64;
                    (k * mean.ln() - mean - libm::lgamma(k + 1.0)).exp()
                }
            })
            .collect();
        let mut cumulative = Vec::with_capacity(pmf.len() + 1);
        let mut sum = 0.0;
        cumulative.push(0.0);
        for p in &pmf {
            sum += p;
            cumulative.push(sum);
        }
        PoissonSpan {
            first,
            pmf,
            cumulative,
        }
    }

    fn last(&self) -> usize {
        self.first + self.pmf.len() - 1
    }

    /// P(Poisson + σ N(0, 1) ≤ y): the terms with k more than
    /// [`NORMAL_REACH`] σ below y count whole, those above count nothing.
    fn convolved_cdf(&self, y: f64, sigma: f64) -> f64 {
        let index = |x: f64| (x - self.first as f64).clamp(0.0, self.pmf.len() as f64) as usize;
        let (a, b) = (
            index((y - NORMAL_REACH * sigma).ceil()),
            index((y + NORMAL_REACH * sigma).floor() + 1.0),
        );
        let window: f64 = (a..b)
            .map(|i| {
                let z = (y - (self.first + i) as f64) / sigma;
                self.pmf[i] * 0.5 * libm::erfc(-z / std::f64::consts::SQRT_2)
            })
            .sum();
        self.cumulative[a] + window
    }
}

/// The mean of Y over each of the [`LEVELS`] probability cells, from its
/// CDF on a grid `(y, F(y))` taken as linear between the nodes (a constant
/// density in each step); the grid's first F counts as 0, its last as 1.
fn cell_means(grid: impl Iterator<Item = (f64, f64)>) -> Vec<f64> {
    let levels = LEVELS as f64;
    let mut sums = vec![0.0; LEVELS];
    let mut cell = 0usize;
    let mut prev: Option<(f64, f64)> = None;
    let mut nodes = grid.peekable();
    while let Some((y, f)) = nodes.next() {
        let f = if nodes.peek().is_none() { 1.0 } else { f };
        let Some((y0, f0)) = prev else {
            prev = Some((y, 0.0));
            continue;
        };
        let f = f.max(f0);
        if f > f0 {
            // Q(p) over this step, linear in p; split at the cells' edges.
            let q = |p: f64| y0 + (p - f0) / (f - f0) * (y - y0);
            let mut p = f0;
            while p < f {
                let edge = ((cell + 1) as f64 / levels).min(1.0);
                let end = if cell + 1 < LEVELS { edge.min(f) } else { f };
                sums[cell] += (end - p) * 0.5 * (q(p) + q(end));
                p = end;
                if end == edge && cell + 1 < LEVELS {
                    cell += 1;
                }
            }
        }
        prev = Some((y, f));
    }
    sums.iter().map(|s| s * levels).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// With d = 0 Y is σ N(0, 1): a central cell's mean is the normal's
    /// quantile at the cell's middle to O(Φ⁻¹'' / LEVELS²) ~ 10⁻¹⁰ (the
    /// rational quantile is accurate to 3·10⁻⁹ there). The table's CDF,
    /// linear over steps h = σ/128, moves a quantile by up to
    /// h²/8 · |f'/f| = 7.6·10⁻⁶ |z| σ.
    #[test]
    fn normal_cells_take_their_conditional_means() {
        let t = DarkTable::new(0.0, 1.0).unwrap();
        for i in [20_000usize, 32_767, 32_768, 50_000, 60_000] {
            let want = crate::sensor::rng::normal_quantile((i as f64 + 0.5) / LEVELS as f64);
            let bound = 7.7e-6 * want.abs() + 1e-8;
            let got = t.values[i];
            assert!((got - want).abs() < bound, "{i}: {got} vs {want}");
        }
        assert!(t.values.windows(2).all(|w| w[0] <= w[1]));
    }

    #[test]
    fn no_table_without_read_noise_or_for_huge_work() {
        assert!(DarkTable::new(5.0, 0.0).is_none());
        assert!(DarkTable::new(1e9, 1e-3).is_none());
        assert!(DarkTable::new(f64::NAN, 1.0).is_none());
    }
}
