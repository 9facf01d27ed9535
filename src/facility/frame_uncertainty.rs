//! A frame's radiometric uncertainty: the display LUT's per-level budget
//! (k = 2: noise, fit, the meter's scale, the spectrum, drift; see
//! docs/CALIBRATION.md) weighted by the flux each pixel asks of the screen.
//!
//! The LUT's errors at neighbouring levels come from the same meter scale
//! and the same spectrum, so they are taken as fully correlated across the
//! frame: the disk flux's uncertainty is the flux-weighted mean of the
//! per-pixel ones (an upper bound for partly correlated errors).

use super::lut::DisplayLut;

/// Mantissa bits kept in a bucket index: 2⁷ = 128 buckets per octave of
/// radiance, so that the LUT's uncertainty (piecewise linear in level)
/// changes by far less than its own resolution within a bucket.
const MANTISSA_BITS: u32 = 7;
const SHIFT: u32 = 52 - MANTISSA_BITS;
/// Largest table: 64 octaves.
const MAX_BUCKETS: usize = 64 << MANTISSA_BITS;
/// Above this many pixels, every second row and column is enough for a
/// flux-weighted mean (and a quarter of the cost).
const FULL_PASS_PIXELS: usize = 1 << 16;

/// The LUT's k = 2 uncertainty tabulated over the screen radiance in
/// logarithmic buckets, for a lookup of a shift and a load per pixel.
#[derive(Debug, Clone)]
pub struct UncertaintyTable {
    base: u64,
    table: Vec<f32>,
}

impl UncertaintyTable {
    /// The table of `lut`'s uncertainty column; None for a LUT without it.
    pub fn new(lut: &DisplayLut) -> Option<UncertaintyTable> {
        lut.uncertainty_k2_percent(lut.max_radiance())?;
        let lowest = lut
            .level_radiances()
            .iter()
            .copied()
            .find(|&v| v > 0.0)
            .unwrap_or(lut.max_radiance());
        let base = lowest.to_bits() >> SHIFT;
        let last = lut.max_radiance().to_bits() >> SHIFT;
        let len = ((last - base + 1) as usize).min(MAX_BUCKETS);
        let table = (0..len)
            .map(|b| {
                // The bucket's geometric middle.
                let lo = f64::from_bits((base + b as u64) << SHIFT);
                let hi = f64::from_bits((base + b as u64 + 1) << SHIFT);
                let mid = (lo * hi).sqrt().min(lut.max_radiance());
                lut.uncertainty_k2_percent(mid).unwrap_or(0.0) as f32
            })
            .collect();
        Some(UncertaintyTable { base, table })
    }

    /// The uncertainty (k = 2, %) at screen radiance `l > 0`.
    #[inline]
    pub fn at(&self, l: f64) -> f64 {
        let b = (l.to_bits() >> SHIFT).saturating_sub(self.base) as usize;
        self.table[b.min(self.table.len() - 1)] as f64
    }

    /// The flux-weighted uncertainty (k = 2, %) of the frame whose
    /// camera-side target radiances are `target` (`width` per row), shown
    /// at `factor` = k ÷ τ times them; None when nothing is lit.
    pub fn frame(&self, target: &[f32], width: usize, factor: f64) -> Option<f64> {
        let step = if target.len() > FULL_PASS_PIXELS {
            2
        } else {
            1
        };
        let (mut flux, mut weighted) = (0.0, 0.0);
        for row in target.chunks(width.max(1)).step_by(step) {
            for &t in row.iter().step_by(step) {
                let l = t as f64 * factor;
                if l > 0.0 && l.is_finite() {
                    flux += l;
                    weighted += l * self.at(l);
                }
            }
        }
        (flux > 0.0).then(|| weighted / flux)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A gamma-2.2 LUT whose uncertainty falls from 8 % at black to 1 %
    /// at the top.
    fn lut() -> DisplayLut {
        let mut csv = String::from("drive_level,radiance_w_m2_sr,uncertainty_k2_percent\n");
        for v in (0..=255).step_by(5) {
            let l = 1e-3 + 2.0 * (v as f64 / 255.0).powf(2.2);
            let u = 8.0 - 7.0 * v as f64 / 255.0;
            csv += &format!("{v},{l},{u}\n");
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("lut.csv");
        std::fs::write(&path, csv).unwrap();
        DisplayLut::load(&path, 8).unwrap()
    }

    #[test]
    fn table_matches_the_luts_own_interpolation() {
        let lut = lut();
        let table = UncertaintyTable::new(&lut).unwrap();
        for i in 0..2000 {
            let l = lut.black() * (lut.max_radiance() / lut.black()).powf(i as f64 / 1999.0);
            let exact = lut.uncertainty_k2_percent(l).unwrap();
            assert!(
                (table.at(l) - exact).abs() < 0.02,
                "{l}: {} vs {exact}",
                table.at(l)
            );
        }
    }

    #[test]
    fn frame_is_the_flux_weighted_mean() {
        let lut = lut();
        let table = UncertaintyTable::new(&lut).unwrap();
        // Two pixels: the bright one dominates by its flux.
        let (factor, bright, dim) = (1.0, 1.5f32, 0.01f32);
        let target = [bright, 0.0, dim, f32::NAN];
        let (ub, ud) = (
            lut.uncertainty_k2_percent(bright as f64).unwrap(),
            lut.uncertainty_k2_percent(dim as f64).unwrap(),
        );
        let expected = (bright as f64 * ub + dim as f64 * ud) / (bright + dim) as f64;
        let got = table.frame(&target, 2, factor).unwrap();
        assert!((got - expected).abs() < 0.02, "{got} vs {expected}");
        assert_eq!(table.frame(&[0.0; 4], 2, factor), None);
    }
}
