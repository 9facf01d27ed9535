//! The charge of pixels whose only light is their column's frame-transfer
//! smear, drawn by inversion of one table per column.
//!
//! Smear is charge a packet collects in the photosites it crosses during
//! the transfer, so it is the same mean s_c for every pixel of column c;
//! a pixel there without light of its own (rate 0) holds DSNU_k plus
//! Poisson(d + s_c): one distribution per column. [`PoissonTable`] holds
//! its CDF with 32-bit steps and a guide table (Chen and Asau), so a draw
//! is one lookup and about one comparison, where Ahrens and Dieter's PD
//! (the lit pixels' draw, [`super::sampler`]) takes a normal, a square
//! root and its acceptance tests. A column gets a table only when its
//! mean is at most [`MAX_MEAN`] and more of its pixels draw from it than
//! the table has entries (so building it costs less than it saves).

/// Largest mean tabulated: the table spans about 14 √mean values.
pub const MAX_MEAN: f64 = 1e4;

/// Poisson(`mean`) by inversion of 32 random bits b: the least value
/// whose CDF exceeds the uniform (b + ½) / 2³², so each value's
/// probability is within 2⁻³² of the pmf's.
#[derive(Clone, Debug)]
pub struct PoissonTable {
    /// The smallest value tabulated.
    first: f64,
    /// last_bits[i]: the largest b drawn as first + i (u32::MAX last).
    last_bits: Vec<u32>,
    /// guide[g] = the least i with last_bits[i] ≥ g << shift.
    guide: Vec<u16>,
    shift: u32,
}

impl PoissonTable {
    /// The table of Poisson(`mean`), or None when the mean is not finite,
    /// negative or above [`MAX_MEAN`]. It spans mean ± (7 √mean + 12):
    /// beyond, the tails hold less than 2⁻³³ (Chernoff's bound), below
    /// what 32 bits resolve.
    pub fn new(mean: f64) -> Option<PoissonTable> {
        if !(mean.is_finite() && (0.0..=MAX_MEAN).contains(&mean)) {
            return None;
        }
        let (first, pmf) = pmf_span(mean, 7.0);
        let scale = 4_294_967_296.0;
        let mut sum = 0.0;
        let mut last_bits: Vec<u32> = pmf
            .iter()
            .map(|p| {
                sum += p;
                // u < F(i) ⇔ b < F(i) 2³² − ½.
                ((sum * scale - 0.5).ceil() - 1.0).clamp(0.0, u32::MAX as f64) as u32
            })
            .collect();
        *last_bits.last_mut()? = u32::MAX;
        let cells = last_bits.len().next_power_of_two().max(2);
        let shift = 32 - cells.trailing_zeros();
        let mut guide = Vec::with_capacity(cells);
        let mut i = 0usize;
        for g in 0..cells as u64 {
            while (last_bits[i] as u64) < g << shift {
                i += 1;
            }
            guide.push(i as u16);
        }
        Some(PoissonTable {
            first,
            last_bits,
            guide,
            shift,
        })
    }

    /// Values the table holds.
    pub fn len(&self) -> usize {
        self.last_bits.len()
    }

    /// Never: a table holds at least one value.
    pub fn is_empty(&self) -> bool {
        self.last_bits.is_empty()
    }

    /// The draw of the 32 random bits `b`.
    #[inline]
    pub fn draw(&self, b: u32) -> f64 {
        let mut i = self.guide[(b >> self.shift) as usize] as usize;
        // The last entry is u32::MAX ≥ b: the search stays inside.
        while self.last_bits[i] < b {
            i += 1;
        }
        self.first + i as f64
    }
}

/// The Poisson pmf over mean ± (`reach` √mean + 12), from its mode both
/// ways by the ratio of neighbours (the mode's value from the log-gamma:
/// e^(−mean) alone underflows above ~745): (first value, pmf).
pub fn pmf_span(mean: f64, reach: f64) -> (f64, Vec<f64>) {
    let half = reach * mean.sqrt() + 12.0;
    let first = (mean - half).max(0.0).floor();
    let len = ((mean + half).ceil() - first) as usize + 1;
    let mode = mean.floor();
    let m = (mode - first) as usize;
    let mut pmf = vec![0.0; len];
    pmf[m] = if mean == 0.0 {
        1.0
    } else {
        (mode * mean.ln() - mean - libm::lgamma(mode + 1.0)).exp()
    };
    // Ratios first: the divisions stay off the recurrence's chain.
    for i in m + 1..len {
        pmf[i] = pmf[i - 1] * (mean / (first + i as f64));
    }
    if mean > 0.0 {
        let inverse = 1.0 / mean;
        for i in (0..m).rev() {
            pmf[i] = pmf[i + 1] * ((first + i as f64 + 1.0) * inverse);
        }
    }
    (first, pmf)
}

/// The 32 random bits of `bits` a column table draws with (its top half;
/// the low 16 are the read noise's).
#[inline(always)]
pub fn table_bits(bits: u64) -> u32 {
    (bits >> 32) as u32
}

/// Per column of a frame: its table, when it has one (see the module).
/// `smear[c]` is column c's smear [e⁻], `dark` the dark charge's mean and
/// `smear_only[c]` how many of its pixels would draw from the table.
pub fn column_tables(dark: f64, smear: &[f64], smear_only: &[usize]) -> Vec<Option<PoissonTable>> {
    use rayon::prelude::*;
    smear
        .par_iter()
        .zip(smear_only)
        .map(|(&s, &count)| {
            let mean = dark + s;
            let size = 14.0 * mean.sqrt() + 25.0;
            if s > 0.0 && (count as f64) > size {
                PoissonTable::new(mean)
            } else {
                None
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// ln pmf(k) by ln k! summed, independent of the table's recurrence.
    fn ln_pmf(mean: f64, k: u64) -> f64 {
        let ln_factorial: f64 = (1..=k).map(|i| (i as f64).ln()).sum();
        if mean == 0.0 {
            return if k == 0 { 0.0 } else { f64::NEG_INFINITY };
        }
        k as f64 * mean.ln() - mean - ln_factorial
    }

    /// Each value's probability under the table, (its bits' count) / 2³²,
    /// within 2⁻³² of the pmf (plus 10⁻¹³ of it, the recurrence's
    /// rounding); the tails left out hold less than 2⁻³³.
    #[test]
    fn the_table_draws_each_value_with_its_probability() {
        let scale = 4_294_967_296.0;
        for mean in [0.0, 0.3, 7.5, 98.6, 431.0, 9999.0] {
            let t = PoissonTable::new(mean).unwrap();
            let first = t.first as u64;
            let mut previous = -1.0;
            for (i, &last) in t.last_bits.iter().enumerate() {
                let p = (last as f64 - previous) / scale;
                previous = last as f64;
                let want = ln_pmf(mean, first + i as u64).exp();
                let bound = 1.0 / scale + 1e-13 * want + 1e-300;
                assert!((p - want).abs() <= bound, "{mean} {i}: {p} vs {want}");
            }
            let below: f64 = (0..first).map(|k| ln_pmf(mean, k).exp()).sum();
            let end = first + t.len() as u64;
            let above: f64 = (end..end + 2000).map(|k| ln_pmf(mean, k).exp()).sum();
            assert!(
                below < 0.5 / scale && above < 0.5 / scale,
                "{mean}: {below} {above}"
            );
            // The guide: the least value whose bits reach each cell's
            // first b, by search.
            for (g, &i) in t.guide.iter().enumerate() {
                let start = (g as u64) << t.shift;
                let least = t.last_bits.iter().position(|&l| l as u64 >= start);
                assert_eq!(Some(i as usize), least, "{mean}: cell {g}");
            }
            // Draws at the edges of each value's bits.
            let mut b = 0u64;
            for (i, &last) in t.last_bits.iter().enumerate() {
                if last as u64 >= b {
                    assert_eq!(t.draw(b as u32), (first + i as u64) as f64, "{mean}");
                    assert_eq!(t.draw(last), (first + i as u64) as f64, "{mean}");
                    b = last as u64 + 1;
                }
            }
        }
        assert!(PoissonTable::new(MAX_MEAN * 1.01).is_none());
        assert!(PoissonTable::new(f64::NAN).is_none());
    }
}
