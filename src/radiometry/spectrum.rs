//! Solar spectra, detector response tables and band integrals (the spectral
//! part of the paper's Eq. 2).
//!
//! Every spectrum here is a spectral irradiance at 1 au in W m⁻² m⁻¹ (per
//! metre of wavelength, SI), every response a dimensionless factor. Tables are
//! read from CSV files with wavelengths in nanometres, as published.

use std::path::Path;

use crate::error::{Error, Result};
use crate::infile::csv_table;

/// Planck constant [J s].
pub const PLANCK: f64 = 6.626_070_15e-34;
/// Speed of light [m/s].
pub const LIGHT_SPEED: f64 = 299_792_458.0;
/// Boltzmann constant [J/K].
pub const BOLTZMANN: f64 = 1.380_649e-23;
/// Stefan–Boltzmann constant [W m⁻² K⁻⁴].
pub const STEFAN_BOLTZMANN: f64 = 5.670_374_419e-8;
/// Astronomical unit [m].
pub const AU: f64 = 149_597_870_700.0;

/// A function of wavelength given at knots and linearly interpolated;
/// zero outside the knots.
#[derive(Clone, Debug)]
pub struct Table {
    /// Knot wavelengths [m], strictly increasing.
    pub wavelengths: Vec<f64>,
    /// Values at the knots.
    pub values: Vec<f64>,
}

impl Table {
    /// Table from knots; wavelengths must be strictly increasing and every
    /// value finite and non-negative.
    pub fn new(wavelengths: Vec<f64>, values: Vec<f64>, what: &str) -> Result<Self> {
        if wavelengths.len() < 2 || wavelengths.len() != values.len() {
            return Err(Error::invalid(what, "a table needs at least two rows"));
        }
        if wavelengths
            .windows(2)
            .any(|w| w[1] <= w[0] || !w[1].is_finite())
        {
            return Err(Error::invalid(what, "wavelengths must increase strictly"));
        }
        if values.iter().any(|v| !v.is_finite() || *v < 0.0) {
            return Err(Error::invalid(what, "values must be finite and >= 0"));
        }
        Ok(Self {
            wavelengths,
            values,
        })
    }

    /// Read a two-column table (`wavelength_nm, value`) separated by
    /// commas, semicolons, tabs or spaces; a non-numeric first row is a
    /// header. Errors name the file and line.
    pub fn from_csv(path: &Path) -> Result<Self> {
        let bytes = crate::infile::read_bounded(path, crate::infile::TABLE_LIMIT)?;
        Table::from_csv_bytes(&bytes, path)
    }

    /// [`Table::from_csv`] on a file's bytes; `path` names it in errors.
    pub fn from_csv_bytes(bytes: &[u8], path: &Path) -> Result<Self> {
        let delimiter = csv_table::sniff_delimiter(bytes);
        let mut wavelengths = Vec::new();
        let mut values = Vec::new();
        for (index, row) in csv_table::rows(path, bytes, delimiter).enumerate() {
            let row = row?;
            let err = |msg: String| Error::parse(path, format!("line {}: {msg}", row.line));
            // Runs of spaces leave empty cells between the numbers.
            let mut fields = row.cells.iter().filter(|f| !f.is_empty());
            let (Some(a), Some(b)) = (fields.next(), fields.next()) else {
                return Err(err("expected two columns".into()));
            };
            match (a.parse::<f64>(), b.parse::<f64>()) {
                (Ok(nm), Ok(v)) => {
                    if !nm.is_finite() || !v.is_finite() || v < 0.0 {
                        return Err(err("non-finite or negative value".into()));
                    }
                    if wavelengths.last().is_some_and(|&last| nm * 1e-9 <= last) {
                        return Err(err("wavelength does not increase".into()));
                    }
                    wavelengths.push(nm * 1e-9);
                    values.push(v);
                }
                _ if index == 0 => {}
                _ => {
                    let text = crate::error::abbreviate(&row.joined(), 60);
                    return Err(err(format!("cannot parse `{text}` as numbers")));
                }
            }
        }
        Table::new(wavelengths, values, &path.display().to_string())
            .map_err(|e| Error::parse(path, e.to_string()))
    }

    /// Linear interpolation; zero outside the table.
    pub fn eval(&self, wavelength: f64) -> f64 {
        let w = &self.wavelengths;
        if wavelength < w[0] || wavelength > w[w.len() - 1] {
            return 0.0;
        }
        let k = w
            .partition_point(|&x| x <= wavelength)
            .clamp(1, w.len() - 1);
        let t = (wavelength - w[k - 1]) / (w[k] - w[k - 1]);
        self.values[k - 1] + t * (self.values[k] - self.values[k - 1])
    }
}

/// Elementary charge [C].
pub const ELEMENTARY_CHARGE: f64 = 1.602_176_634e-19;

/// A dimensionless spectral factor: quantum efficiency or transmission.
#[derive(Clone, Debug)]
pub enum Response {
    /// Same value at every wavelength.
    Constant(f64),
    /// Tabulated against wavelength (photon-normalised: electrons per
    /// photon for a QE, a fraction for a transmission).
    Table(Table),
    /// An energy-normalised responsivity table in A/W (electrons per joule
    /// times e): the quantum efficiency it stands for is v hc/(λ e), so
    /// the electron rate ∫ QE λ/(hc) F dλ = ∫ v/e F dλ stays the integral
    /// of the table's own piecewise-linear values (exact between nodes).
    AmpsPerWatt(Table),
}

impl Response {
    /// Value (quantum efficiency or transmission) at a wavelength [m].
    pub fn eval(&self, wavelength: f64) -> f64 {
        match self {
            Response::Constant(v) => *v,
            Response::Table(t) => t.eval(wavelength),
            Response::AmpsPerWatt(t) => {
                t.eval(wavelength) * PLANCK * LIGHT_SPEED / (wavelength * ELEMENTARY_CHARGE)
            }
        }
    }

    fn knots(&self) -> &[f64] {
        match self {
            Response::Constant(_) => &[],
            Response::Table(t) | Response::AmpsPerWatt(t) => &t.wavelengths,
        }
    }
}

/// ∫_band QE T λ/(hc) dλ [e⁻ J⁻¹ m]: the camera's photon responsivity R(λ)
/// integrated over its band, exact for piecewise-linear tables (their
/// nodes are quadrature breakpoints).
pub fn response_integral(qe: &Response, transmission: &Response, band: [f64; 2]) -> f64 {
    let mut knots: Vec<f64> = qe
        .knots()
        .iter()
        .chain(transmission.knots())
        .copied()
        .collect();
    knots.sort_by(f64::total_cmp);
    integrate(band[0], band[1], &knots, |l| {
        electron_response(qe, transmission, l)
    })
}

/// A camera's electrons per joule of light at `wavelength` [m]:
/// QE T λ/(hc).
pub fn electron_response(qe: &Response, transmission: &Response, wavelength: f64) -> f64 {
    qe.eval(wavelength) * transmission.eval(wavelength) * wavelength / (PLANCK * LIGHT_SPEED)
}

/// Solar spectral irradiance at 1 au [W m⁻² m⁻¹].
#[derive(Clone, Debug)]
pub enum SolarSpectrum {
    /// Planck blackbody of the given temperature, scaled so that its total
    /// irradiance is `irradiance_1au`.
    Blackbody {
        /// Temperature [K].
        temperature: f64,
        /// Total irradiance at 1 au [W m⁻²].
        irradiance_1au: f64,
    },
    /// Tabulated spectrum (already scaled to W m⁻² m⁻¹).
    Table(Table),
}

impl SolarSpectrum {
    /// A blackbody spectrum.
    pub fn blackbody(temperature: f64, irradiance_1au: f64) -> Result<Self> {
        // Below ~1 K the Planck exponent overflows in any optical band;
        // above 1e6 K nothing is a sun.
        if !(temperature.is_finite() && (1.0..=1e6).contains(&temperature)) {
            return Err(Error::invalid(
                "sun.temperature",
                format!("must be within [1, 1e6] K, got {temperature:e}"),
            ));
        }
        if !(irradiance_1au.is_finite() && (1e-12..=1e12).contains(&irradiance_1au)) {
            return Err(Error::invalid(
                "sun.irradiance_1au",
                format!("must be within [1e-12, 1e12] W m-2, got {irradiance_1au:e}"),
            ));
        }
        Ok(SolarSpectrum::Blackbody {
            temperature,
            irradiance_1au,
        })
    }

    /// A tabulated spectrum read from CSV in W m⁻² nm⁻¹; when
    /// `irradiance_1au` is given the table is scaled so that its integral over
    /// the whole table equals it.
    pub fn from_csv(path: &Path, irradiance_1au: Option<f64>) -> Result<Self> {
        let mut table = Table::from_csv(path)?;
        for v in &mut table.values {
            *v *= 1e9; // per nm -> per m
        }
        if let Some(total) = irradiance_1au {
            if !(total.is_finite() && (1e-12..=1e12).contains(&total)) {
                return Err(Error::invalid(
                    "sun.irradiance_1au",
                    format!("must be within [1e-12, 1e12] W m-2, got {total:e}"),
                ));
            }
            let lo = table.wavelengths[0];
            let hi = *table.wavelengths.last().unwrap();
            let have = integrate(lo, hi, &table.wavelengths, |l| table.eval(l));
            let scale = total / have;
            if !(have > 0.0 && scale.is_finite()) {
                return Err(Error::parse(
                    path,
                    format!("integrates to {have:e} W m-2: cannot be scaled to sun.irradiance_1au"),
                ));
            }
            for v in &mut table.values {
                *v *= scale;
            }
        }
        Ok(SolarSpectrum::Table(table))
    }

    /// Spectral irradiance at 1 au [W m⁻² m⁻¹].
    pub fn eval(&self, wavelength: f64) -> f64 {
        match self {
            SolarSpectrum::Blackbody {
                temperature,
                irradiance_1au,
            } => {
                let exitance = std::f64::consts::PI * planck_radiance(wavelength, *temperature);
                exitance * irradiance_1au / (STEFAN_BOLTZMANN * temperature.powi(4))
            }
            SolarSpectrum::Table(t) => t.eval(wavelength),
        }
    }

    fn knots(&self) -> &[f64] {
        match self {
            SolarSpectrum::Blackbody { .. } => &[],
            SolarSpectrum::Table(t) => &t.wavelengths,
        }
    }
}

/// Planck spectral radiance B_λ(T) [W m⁻² sr⁻¹ m⁻¹].
pub fn planck_radiance(wavelength: f64, temperature: f64) -> f64 {
    let a = 2.0 * PLANCK * LIGHT_SPEED * LIGHT_SPEED / wavelength.powi(5);
    let x = PLANCK * LIGHT_SPEED / (wavelength * BOLTZMANN * temperature);
    a / x.exp_m1()
}

/// Band integrals of one (sub-)band, at 1 au from the Sun.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BandIntegral {
    /// Lower and upper wavelength [m].
    pub band: [f64; 2],
    /// Representative wavelength (irradiance-weighted mean) [m].
    pub centroid: f64,
    /// ∫ F_λ dλ [W m⁻²]: scales radiance images.
    pub irradiance_1au: f64,
    /// ∫ QE_λ T_λ (λ / hc) F_λ dλ [e⁻ s⁻¹ m⁻²]: scales electron images.
    pub electron_rate_1au: f64,
}

/// Integrate sunlight over `band` split into `sub_bands` equal parts.
pub fn band_integrals(
    sun: &SolarSpectrum,
    qe: &Response,
    transmission: &Response,
    band: [f64; 2],
    sub_bands: usize,
) -> Vec<BandIntegral> {
    let n = sub_bands.max(1);
    let mut knots: Vec<f64> = sun
        .knots()
        .iter()
        .chain(qe.knots())
        .chain(transmission.knots())
        .copied()
        .collect();
    knots.sort_by(f64::total_cmp);
    (0..n)
        .map(|k| {
            let lo = band[0] + (band[1] - band[0]) * k as f64 / n as f64;
            let hi = band[0] + (band[1] - band[0]) * (k + 1) as f64 / n as f64;
            let irradiance = integrate(lo, hi, &knots, |l| sun.eval(l));
            let weighted = integrate(lo, hi, &knots, |l| l * sun.eval(l));
            let electrons = integrate(lo, hi, &knots, |l| {
                electron_response(qe, transmission, l) * sun.eval(l)
            });
            BandIntegral {
                band: [lo, hi],
                centroid: if irradiance > 0.0 {
                    weighted / irradiance
                } else {
                    0.5 * (lo + hi)
                },
                irradiance_1au: irradiance,
                electron_rate_1au: electrons,
            }
        })
        .collect()
}

/// ∫_lo^hi f dλ by 3-point Gauss–Legendre on every interval between the
/// merged table knots, in steps of at most max(1 nm, 0.2 % of λ): exact for
/// products of piecewise-linear tables and λ, and 1e-12 for a Planck curve,
/// which varies on the scale of λ itself (so a band from 10 nm to 1 mm
/// takes ~6000 steps rather than a million). `knots` must be sorted.
pub fn integrate(lo: f64, hi: f64, knots: &[f64], f: impl Fn(f64) -> f64) -> f64 {
    const NODES: [f64; 3] = [-0.774_596_669_241_483_4, 0.0, 0.774_596_669_241_483_4];
    const WEIGHTS: [f64; 3] = [5.0 / 9.0, 8.0 / 9.0, 5.0 / 9.0];
    const MAX_STEP: f64 = 1e-9;
    const MAX_RELATIVE_STEP: f64 = 2e-3;
    let start = knots.partition_point(|&k| k <= lo);
    let mut edges = vec![lo];
    edges.extend(knots[start..].iter().copied().take_while(|&k| k < hi));
    edges.push(hi);
    let mut total = 0.0;
    for w in edges.windows(2) {
        let mut a = w[0];
        while a < w[1] {
            let step = MAX_STEP.max(MAX_RELATIVE_STEP * a);
            // The last step absorbs a sliver rather than leaving one.
            let b = if w[1] - a < 1.001 * step {
                w[1]
            } else {
                a + step
            };
            let (mid, half) = (0.5 * (a + b), 0.5 * (b - a));
            for (x, wt) in NODES.iter().zip(WEIGHTS) {
                total += wt * f(mid + half * x) * half;
            }
            a = b;
        }
    }
    total
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blackbody_total_matches_stefan_boltzmann() {
        // Integrating the scaled Planck curve over a wide band gives the total.
        let sun = SolarSpectrum::blackbody(5772.0, 1361.0).unwrap();
        let one = Response::Constant(1.0);
        let b = band_integrals(&sun, &one, &one, [50e-9, 200e-6], 1)[0];
        assert!((b.irradiance_1au / 1361.0 - 1.0).abs() < 1e-6, "{b:?}");
    }

    #[test]
    fn blackbody_over_10_nm_to_1_mm_matches_its_closed_form_tail() {
        // Outside 10 nm-1 mm a 5772 K Planck curve holds, in closed form,
        // the Rayleigh-Jeans tail (15/π⁴)·x³/3 with x = hc/(λkT) at 1 mm
        // (to 1e-12 relative), and nothing measurable below 10 nm.
        let (t, e0) = (5772.0, 1361.0);
        let sun = SolarSpectrum::blackbody(t, e0).unwrap();
        let one = Response::Constant(1.0);
        let b = band_integrals(&sun, &one, &one, [10e-9, 1e-3], 1)[0];
        let x = PLANCK * LIGHT_SPEED / (1e-3 * 1.380_649e-23 * t);
        let tail = 15.0 / std::f64::consts::PI.powi(4) * (x.powi(3) / 3.0 - x.powi(4) / 8.0);
        assert!(
            (b.irradiance_1au / (e0 * (1.0 - tail)) - 1.0).abs() < 1e-9,
            "{b:?}"
        );
    }

    #[test]
    fn photon_rate_of_a_narrow_band_is_energy_over_photon_energy() {
        let sun = SolarSpectrum::blackbody(5772.0, 1361.0).unwrap();
        let one = Response::Constant(1.0);
        let b = band_integrals(&sun, &one, &one, [600e-9, 600.01e-9], 1)[0];
        let expected = b.irradiance_1au * 600.005e-9 / (PLANCK * LIGHT_SPEED);
        assert!((b.electron_rate_1au / expected - 1.0).abs() < 1e-6);
    }

    #[test]
    fn astm_e490_band_irradiance_matches_published_integral() {
        // ASTM E-490 integrates to 1366.1 W/m2 (published total). The data
        // README quotes 590.1 W/m2 for 450-820 nm; a trapezoid over the
        // table gives 592.2, so the band is checked to 0.5 %.
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/solar/astm_e490_am0.csv");
        let sun = SolarSpectrum::from_csv(&path, None).unwrap();
        let one = Response::Constant(1.0);
        let all = band_integrals(&sun, &one, &one, [119.5e-9, 1e-3], 1)[0];
        assert!(
            (all.irradiance_1au - 1366.1).abs() < 0.1,
            "{}",
            all.irradiance_1au
        );
        let b = band_integrals(&sun, &one, &one, [450e-9, 820e-9], 1)[0];
        assert!(
            (b.irradiance_1au / 590.1 - 1.0).abs() < 5e-3,
            "{}",
            b.irradiance_1au
        );
        let scaled = SolarSpectrum::from_csv(&path, Some(1361.0)).unwrap();
        let s = band_integrals(&scaled, &one, &one, [450e-9, 820e-9], 1)[0];
        assert!((s.irradiance_1au / b.irradiance_1au - 1361.0 / 1366.1).abs() < 1e-3);
    }

    #[test]
    fn sub_bands_add_up() {
        let sun = SolarSpectrum::blackbody(5772.0, 1361.0).unwrap();
        let qe = Response::Table(Table::new(vec![400e-9, 900e-9], vec![0.2, 0.8], "qe").unwrap());
        let one = Response::Constant(0.9);
        let whole = band_integrals(&sun, &qe, &one, [450e-9, 820e-9], 1)[0];
        let parts = band_integrals(&sun, &qe, &one, [450e-9, 820e-9], 7);
        let sum: f64 = parts.iter().map(|b| b.electron_rate_1au).sum();
        assert!((sum / whole.electron_rate_1au - 1.0).abs() < 1e-12);
    }

    #[test]
    fn bad_tables_name_file_and_line() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("qe.csv");
        std::fs::write(&p, "wavelength_nm,qe\n400,0.5\n390,0.6\n").unwrap();
        let e = Table::from_csv(&p).unwrap_err().to_string();
        assert!(e.contains("qe.csv") && e.contains("line 3"), "{e}");
        std::fs::write(&p, "wavelength_nm,qe\n400,0.5\n500,NaN\n").unwrap();
        let e = Table::from_csv(&p).unwrap_err().to_string();
        assert!(e.contains("line 3"), "{e}");
    }
}
