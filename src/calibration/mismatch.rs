//! Camera-effective radiance and the spectral mismatch factor (the
//! convention of docs/CALIBRATION.md):
//!
//! ```text
//! R(λ)  = QE(λ)·T(λ)·λ/(h c)                      inside the camera's band, 0 outside
//! L_eff = ∫ L R dλ · ∫_band E☉ dλ / ∫ E☉ R dλ
//! F     = [∫ S R dλ / ∫ S M dλ] · [∫_band E☉ dλ / ∫ E☉ R dλ],   L_eff = F · V
//! ```
//!
//! for a source of spectral radiance L(λ), a screen spectrum S(λ) and a
//! broadband meter of spectral response M(λ) reading V = ∫ S M dλ.
//! Integrals are trapezoidal on a 0.25 nm grid over the spectra's overlap
//! (the tables are piecewise linear at coarser steps, so this is close to
//! exact).

use crate::error::{Error, Result};
use crate::radiometry::spectrum::{electron_response, Response, SolarSpectrum, Table};
use crate::scene::Scene;

/// Integration step, nm.
const STEP_NM: f64 = 0.25;

/// The camera's spectral weighting and the Sun of the scene.
#[derive(Debug, Clone)]
pub struct CameraSpectral {
    /// Band, nm.
    pub band_nm: [f64; 2],
    pub qe: Response,
    pub transmission: Response,
    pub sun: SolarSpectrum,
}

/// A spectrum `(wavelength_nm, value per nm)`, wavelengths increasing.
pub type Spectrum = [(f64, f64)];

/// Linear interpolation in a `(nm, value)` list; zero outside.
pub fn interp(s: &Spectrum, nm: f64) -> f64 {
    if s.is_empty() || nm < s[0].0 || nm > s[s.len() - 1].0 {
        return 0.0;
    }
    let k = s.partition_point(|p| p.0 <= nm).clamp(1, s.len() - 1);
    let (a, b) = (s[k - 1], s[k]);
    if b.0 == a.0 {
        return a.1;
    }
    a.1 + (nm - a.0) / (b.0 - a.0) * (b.1 - a.1)
}

/// ∫_lo^hi f(λ_nm) dλ_nm by the trapezoid rule on the fixed grid.
fn integrate(lo: f64, hi: f64, f: impl Fn(f64) -> f64) -> f64 {
    if !(hi > lo) {
        return 0.0;
    }
    let n = ((hi - lo) / STEP_NM).ceil().max(1.0) as usize;
    let h = (hi - lo) / n as f64;
    let mut total = 0.5 * (f(lo) + f(hi));
    for k in 1..n {
        total += f(lo + k as f64 * h);
    }
    total * h
}

impl CameraSpectral {
    /// From a scene's flight camera and Sun.
    pub fn from_scene(scene: &Scene) -> CameraSpectral {
        let c = &scene.camera;
        CameraSpectral {
            band_nm: [c.band[0] * 1e9, c.band[1] * 1e9],
            qe: c.quantum_efficiency.clone(),
            transmission: c.transmission.clone(),
            sun: scene.sun.clone(),
        }
    }

    /// R(λ), electrons per joule (0 outside the band).
    pub fn responsivity(&self, nm: f64) -> f64 {
        if nm < self.band_nm[0] || nm > self.band_nm[1] {
            return 0.0;
        }
        electron_response(&self.qe, &self.transmission, nm * 1e-9)
    }

    /// ∫_band E☉ / ∫ E☉ R: turns an electron-weighted integral into the band
    /// radiance of a solar-shaped source.
    pub fn solar_norm(&self) -> Result<f64> {
        let [lo, hi] = self.band_nm;
        let e = integrate(lo, hi, |nm| self.sun.eval(nm * 1e-9));
        let er = integrate(lo, hi, |nm| {
            self.sun.eval(nm * 1e-9) * self.responsivity(nm)
        });
        if !(e > 0.0 && er > 0.0) {
            return Err(Error::Other(
                "the camera sees no sunlight in its band (QE × T × E☉ integrates to 0)".into(),
            ));
        }
        Ok(e / er)
    }

    /// L_eff of a spectral radiance (W m⁻² sr⁻¹ nm⁻¹ against nm).
    pub fn effective_radiance(&self, spectrum: &Spectrum) -> Result<f64> {
        let [lo, hi] = self.band_nm;
        let lr = integrate(lo, hi, |nm| interp(spectrum, nm) * self.responsivity(nm));
        Ok(lr * self.solar_norm()?)
    }

    /// F for a screen spectrum `s` (any scale) and a meter response `m`.
    pub fn mismatch_factor(&self, s: &Spectrum, m: &Table) -> Result<f64> {
        if s.len() < 2 {
            return Err(Error::Other(
                "screen spectrum needs at least two rows".into(),
            ));
        }
        let (lo, hi) = (s[0].0, s[s.len() - 1].0);
        let sm = integrate(lo, hi, |nm| interp(s, nm) * m.eval(nm * 1e-9));
        if !(sm > 0.0) {
            return Err(Error::Other(
                "the meter's spectral response does not overlap the screen spectrum".into(),
            ));
        }
        let [blo, bhi] = self.band_nm;
        let sr = integrate(blo.max(lo), bhi.min(hi), |nm| {
            interp(s, nm) * self.responsivity(nm)
        });
        Ok(sr / sm * self.solar_norm()?)
    }
}

/// Largest spacing of a screen spectrum's rows inside the camera's band,
/// nm: an LCD's primaries are 20–40 nm wide, so a wider step interpolates
/// straight across a peak.
pub const MAX_SPECTRUM_STEP_NM: f64 = 20.0;

/// Checks that a screen spectrum can give F for a camera band `band_nm`:
/// no gap wider than [`MAX_SPECTRUM_STEP_NM`] inside the band, and it
/// covers the band or ends where the screen has stopped emitting (its end
/// value below 1 % of its peak). The error says what is wrong, in nm.
pub fn check_screen_spectrum(s: &Spectrum, band_nm: [f64; 2]) -> Result<()> {
    let peak = s.iter().fold(0.0f64, |m, p| m.max(p.1));
    if s.len() < 2 || !(peak > 0.0) {
        return Err(Error::Other(
            "needs at least two rows and a positive value".into(),
        ));
    }
    let [blo, bhi] = band_nm;
    for w in s.windows(2) {
        let (a, b) = (w[0].0, w[1].0);
        if b - a > MAX_SPECTRUM_STEP_NM && b > blo && a < bhi {
            return Err(Error::Other(format!(
                "a gap of {:.1} nm between {a} and {b} nm, inside the camera's band {blo}–{bhi} nm (at most {MAX_SPECTRUM_STEP_NM} nm)",
                b - a
            )));
        }
    }
    let (first, last) = (s[0], s[s.len() - 1]);
    for (end, beyond, name) in [
        (first, first.0 > blo, "starts"),
        (last, last.0 < bhi, "ends"),
    ] {
        if beyond && end.1 > 0.01 * peak {
            return Err(Error::Other(format!(
                "{name} at {} nm at {:.1} % of its peak, inside the camera's band {blo}–{bhi} nm: extend it to where the screen stops emitting",
                end.0,
                100.0 * end.1 / peak
            )));
        }
    }
    Ok(())
}

/// A `(nm, value)` spectrum from a [`Table`] (metres → nm).
pub fn table_spectrum(t: &Table) -> Vec<(f64, f64)> {
    t.wavelengths
        .iter()
        .zip(&t.values)
        .map(|(w, v)| (w * 1e9, *v))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::radiometry::spectrum::{LIGHT_SPEED, PLANCK};

    fn flat_camera(band: [f64; 2]) -> CameraSpectral {
        CameraSpectral {
            band_nm: band,
            qe: Response::Constant(0.6),
            transmission: Response::Constant(0.9),
            sun: SolarSpectrum::blackbody(5778.0, 1361.0).unwrap(),
        }
    }

    /// A solar-shaped source: L_eff equals its band radiance (the first
    /// property of the convention).
    #[test]
    fn screen_spectrum_gaps_and_truncation_are_refused() {
        let band = [450.0, 820.0];
        let lcd: Vec<(f64, f64)> = (380..=780)
            .step_by(5)
            .map(|nm| (nm as f64, (-(((nm as f64) - 550.0) / 60.0).powi(2)).exp()))
            .collect();
        assert!(check_screen_spectrum(&lcd, band).is_ok());
        // A 50 nm hole at the green peak.
        let holed: Vec<_> = lcd
            .iter()
            .copied()
            .filter(|p| p.0 <= 520.0 || p.0 >= 570.0)
            .collect();
        let e = check_screen_spectrum(&holed, band).unwrap_err().to_string();
        assert!(e.contains("gap of 50.0 nm between 520 and 570"), "{e}");
        // Cut at 600 nm where the screen still emits 37 % of its peak.
        let cut: Vec<_> = lcd.iter().copied().filter(|p| p.0 <= 600.0).collect();
        let e = check_screen_spectrum(&cut, band).unwrap_err().to_string();
        assert!(e.contains("ends at 600 nm"), "{e}");
        // A gap outside the band is harmless.
        let uv_gap: Vec<_> = lcd
            .iter()
            .copied()
            .filter(|p| p.0 <= 380.0 || p.0 >= 420.0)
            .collect();
        assert!(check_screen_spectrum(&uv_gap, band).is_ok());
    }

    #[test]
    fn solar_shaped_source_gives_its_band_radiance() {
        let cam = flat_camera([450.0, 820.0]);
        let sun: Vec<(f64, f64)> = (300..=1000)
            .map(|nm| (nm as f64, 3e-9 * cam.sun.eval(nm as f64 * 1e-9)))
            .collect();
        let band: f64 = integrate(450.0, 820.0, |nm| interp(&sun, nm));
        let eff = cam.effective_radiance(&sun).unwrap();
        // The source is the Sun tabulated every 1 nm (linear between): it
        // differs from the analytic Sun by ~h²/8·|E''/E| ~ 1e-7.
        assert!((eff / band - 1.0).abs() < 1e-6, "{eff} vs {band}");
    }

    /// F for a flat meter over the band and a monochromatic-like screen
    /// line against the closed form: S = narrow box at λ0, M = 1 on
    /// [300, 1000] nm → F = R(λ0)·∫E☉/∫E☉R.
    #[test]
    fn mismatch_factor_of_a_narrow_line() {
        let cam = flat_camera([450.0, 820.0]);
        let l0 = 600.0;
        let s = vec![(l0 - 1.0, 0.0), (l0, 1.0), (l0 + 1.0, 0.0)];
        let m = Table::new(vec![300e-9, 1000e-9], vec![1.0, 1.0], "m").unwrap();
        let f = cam.mismatch_factor(&s, &m).unwrap();
        // Independent: R(λ) linear in λ over the ±1 nm triangle, whose mean
        // is λ0; solar_norm by brute force below.
        let r0 = 0.6 * 0.9 * l0 * 1e-9 / (PLANCK * LIGHT_SPEED);
        let (mut e, mut er) = (0.0, 0.0);
        for k in 0..370_000 {
            let nm = 450.0 + (k as f64 + 0.5) * 0.001;
            let sun = cam.sun.eval(nm * 1e-9);
            e += sun;
            er += sun * 0.6 * 0.9 * nm * 1e-9 / (PLANCK * LIGHT_SPEED);
        }
        let expect = r0 * e / er;
        assert!((f / expect - 1.0).abs() < 1e-6, "{f} vs {expect}");
    }
}
