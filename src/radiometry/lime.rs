//! LIME, the Lunar Irradiance Model of ESA: the real Moon's disk
//! reflectance from the observation geometry, fitted to SI-traceable
//! photometry (about 2 % at k = 2, over 2–90° phase). A render of a body
//! marked `lime_reference` reports its disk irradiance against LIME
//! (`summary.json`, `lime`), so every frame carries a radiometric error
//! that can be quoted.
//!
//! The coefficients (release 2025-10-10) and the composite reflectance
//! spectrum LIME interpolates its six bands with are embedded from
//! `data/lime/` (LGPL-3.0; provenance in its README). The tests hold an
//! independent implementation (`tests/moon_lime.rs`).

use std::path::Path;
use std::sync::OnceLock;

use glam::DVec3;
use serde::Serialize;

use super::spectrum::{integrate, SolarSpectrum, Table, AU};
use crate::error::{Error, Result};
use crate::infile::csv_table;

/// LIME's band centres [nm].
pub const BANDS_NM: [f64; 6] = [440.0, 500.0, 675.0, 870.0, 1020.0, 1640.0];
/// Phases [deg] LIME was fitted over; beyond them it extrapolates.
pub const FITTED_PHASE_DEG: [f64; 2] = [2.0, 90.0];
/// The Moon's solid angle at LIME's reference distance [sr].
const OMEGA: f64 = 6.4177e-5;
/// LIME's reference observer–Moon distance [m].
const REFERENCE_DISTANCE: f64 = 384_400e3;
/// Coefficient rows, in the order of [`Coefficients`].
const NAMES: [&str; 18] = [
    "a0", "a1", "a2", "a3", "b1", "b2", "b3", "c1", "c2", "c3", "c4", "d1", "d2", "d3", "p1", "p2",
    "p3", "p4",
];
const COEFFICIENTS_CSV: &str = "data/lime/lime_coefficients_20251010_v01.csv";
const COMPOSITE_CSV: &str = "data/lime/composite_reflectance.csv";

/// One band's coefficients, named as in LIME's formula.
#[derive(Clone, Copy, Debug, Default)]
struct Coefficients([f64; 18]);

impl Coefficients {
    /// ln A: g phase [rad], Φ the Sun's selenographic longitude [rad],
    /// θ, φ the observer's selenographic latitude and longitude [deg].
    fn ln_reflectance(&self, g: f64, sun_lon: f64, lat: f64, lon: f64) -> f64 {
        let [a0, a1, a2, a3, b1, b2, b3, c1, c2, c3, c4, d1, d2, d3, p1, p2, p3, p4] = self.0;
        let g_deg = g.to_degrees();
        let p = sun_lon;
        a0 + g * (a1 + g * (a2 + g * a3))
            + p * (b1 + p * p * (b2 + p * p * b3))
            + c1 * lat
            + c2 * lon
            + p * (c3 * lat + c4 * lon)
            + d1 * (-g_deg / p1).exp()
            + d2 * (-g_deg / p2).exp()
            + d3 * ((g_deg - p3) / p4).cos()
    }
}

/// The model: per-band coefficients and the composite spectrum.
pub struct Lime {
    bands: [Coefficients; 6],
    composite: Table,
    /// The composite spectrum at the band centres (looked up once: the
    /// facility evaluates LIME every frame).
    composite_at_bands: [f64; 6],
}

/// The geometry LIME takes, from the Moon's centre in Moon-fixed
/// (Mean Earth/polar axis) axes; longitudes east-positive.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct LunarGeometry {
    /// Sun–Moon–observer angle [deg].
    pub phase_deg: f64,
    /// Selenographic latitude and longitude of the sub-observer point [deg].
    pub observer_selenographic_lat_deg: f64,
    pub observer_selenographic_lon_deg: f64,
    /// Selenographic latitude and longitude of the sub-solar point [deg].
    pub sun_selenographic_lat_deg: f64,
    pub sun_selenographic_lon_deg: f64,
    /// Moon-centre distances of the observer and the Sun [m].
    pub observer_distance_m: f64,
    pub sun_distance_m: f64,
}

fn lat_lon_deg(v: DVec3) -> (f64, f64) {
    let n = v.normalize();
    (
        n.z.clamp(-1.0, 1.0).asin().to_degrees(),
        n.y.atan2(n.x).to_degrees(),
    )
}

impl LunarGeometry {
    /// From the observer's and the Sun's positions relative to the Moon's
    /// centre, in Moon-fixed axes [m]; None for a zero or non-finite one.
    pub fn from_moon_fixed(observer: DVec3, sun: DVec3) -> Option<Self> {
        let (d_obs, d_sun) = (observer.length(), sun.length());
        let usable = |d: f64| d.is_finite() && d > 0.0;
        if !(usable(d_obs) && usable(d_sun)) {
            return None;
        }
        let (obs_lat, obs_lon) = lat_lon_deg(observer);
        let (sun_lat, sun_lon) = lat_lon_deg(sun);
        Some(LunarGeometry {
            phase_deg: observer.angle_between(sun).to_degrees(),
            observer_selenographic_lat_deg: obs_lat,
            observer_selenographic_lon_deg: obs_lon,
            sun_selenographic_lat_deg: sun_lat,
            sun_selenographic_lon_deg: sun_lon,
            observer_distance_m: d_obs,
            sun_distance_m: d_sun,
        })
    }

    /// Where LIME is an extrapolation here (empty: within its fit).
    fn extrapolations(&self, band_nm: [f64; 2]) -> Vec<String> {
        let mut out = Vec::new();
        let [lo, hi] = FITTED_PHASE_DEG;
        if !(lo..=hi).contains(&self.phase_deg) {
            out.push(format!(
                "phase {:.2}° outside LIME's fitted {lo}–{hi}°",
                self.phase_deg
            ));
        }
        if band_nm[0] < BANDS_NM[0] || band_nm[1] > BANDS_NM[5] {
            out.push(format!(
                "band {:.0}–{:.0} nm reaches beyond LIME's bands ({:.0}–{:.0} nm): the composite spectrum's shape there",
                band_nm[0], band_nm[1], BANDS_NM[0], BANDS_NM[5]
            ));
        }
        out
    }
}

/// A render's disk irradiance against LIME's (`summary.json`, `lime`).
#[derive(Clone, Debug, Serialize)]
pub struct LimeComparison {
    /// LIME's disk irradiance at the camera over the band [W m⁻²].
    pub disk_irradiance_w_m2: f64,
    /// The render's (`irradiance_all_caps_w_m2`) over LIME's.
    pub render_over_lime: f64,
    /// LIME's camera-effective disk irradiance [W m⁻²]: the in-band
    /// irradiance of a solar-spectrum source that gives the camera the
    /// electrons LIME's Moon would ([`Lime::camera_band`]); None without a
    /// camera response in the band.
    pub effective_disk_irradiance_w_m2: Option<f64>,
    /// The render's (`effective_irradiance_all_caps_w_m2`) over it: the
    /// error in the camera's own electrons.
    pub effective_render_over_lime: Option<f64>,
    /// The geometry LIME was evaluated at.
    #[serde(flatten)]
    pub geometry: LunarGeometry,
    /// Why LIME is an extrapolation here, if it is.
    pub extrapolated: Vec<String>,
}

impl Lime {
    /// The embedded release (parsed once).
    pub fn embedded() -> &'static Lime {
        static MODEL: OnceLock<Lime> = OnceLock::new();
        MODEL.get_or_init(|| {
            Lime::parse(
                include_bytes!("../../data/lime/lime_coefficients_20251010_v01.csv"),
                include_bytes!("../../data/lime/composite_reflectance.csv"),
            )
            .expect("the embedded LIME tables parse (checked by a unit test)")
        })
    }

    fn parse(coefficients: &[u8], composite: &[u8]) -> Result<Lime> {
        let path = Path::new(COEFFICIENTS_CSV);
        let mut bands = [Coefficients::default(); 6];
        let mut seen = [false; 18];
        for row in csv_table::rows(path, coefficients, b',') {
            let row = row?;
            let Some(k) = NAMES.iter().position(|n| &row.cells[0] == *n) else {
                continue; // the header
            };
            let bad = || Error::parse(path, format!("line {}: expected 6 numbers", row.line));
            if row.cells.len() != 7 {
                return Err(bad());
            }
            for (b, cell) in row.cells.iter().skip(1).enumerate() {
                let value = cell.parse::<f64>().ok().filter(|v| v.is_finite());
                bands[b].0[k] = value.ok_or_else(bad)?;
            }
            seen[k] = true;
        }
        if let Some(k) = seen.iter().position(|s| !s) {
            return Err(Error::parse(path, format!("no row `{}`", NAMES[k])));
        }
        let composite = Table::from_csv_bytes(composite, Path::new(COMPOSITE_CSV))?;
        let composite_at_bands = BANDS_NM.map(|nm| composite.eval(nm * 1e-9));
        Ok(Lime {
            bands,
            composite,
            composite_at_bands,
        })
    }

    /// Disk reflectance A in LIME band `k` ([`BANDS_NM`]).
    pub fn band_reflectance(&self, k: usize, geo: &LunarGeometry) -> f64 {
        self.bands[k]
            .ln_reflectance(
                geo.phase_deg.to_radians(),
                geo.sun_selenographic_lon_deg.to_radians(),
                geo.observer_selenographic_lat_deg,
                geo.observer_selenographic_lon_deg,
            )
            .exp()
    }

    /// Disk reflectance at any wavelength [m], as LIME interpolates: the
    /// composite spectrum times the band values' ratio to it, linear in λ
    /// between the bands and constant beyond them.
    pub fn reflectance(&self, wavelength_m: f64, geo: &LunarGeometry) -> f64 {
        let ratios = self.ratios(geo);
        let hats = band_weights(wavelength_m);
        let ratio: f64 = hats.iter().zip(ratios).map(|(h, r)| h * r).sum();
        self.composite.eval(wavelength_m) * ratio
    }

    /// Each band's reflectance over the composite spectrum there.
    fn ratios(&self, geo: &LunarGeometry) -> [f64; 6] {
        std::array::from_fn(|k| self.band_reflectance(k, geo) / self.composite_at_bands[k])
    }

    /// What LIME needs of a band and a solar spectrum, computed once:
    /// W_k = ∫ C(λ) h_k(λ) E☉(λ) dλ, with C the composite spectrum and h_k
    /// the weights of the linear interpolation between the bands, so that
    /// ∫ A E☉ dλ = Σ_k (A_k / C(λ_k)) W_k at any geometry. None where the
    /// band leaves the composite spectrum (350–2550 nm).
    pub fn band(&self, sun: &SolarSpectrum, band: [f64; 2]) -> Option<LimeBand> {
        self.weighted_band(sun, band, |_| 1.0)
    }

    /// [`Lime::band`] as a camera sees it: each W_k weighted by the camera's
    /// electron response R(λ) (QE T λ/(hc)) and scaled by ∫E☉ / ∫E☉R over
    /// the band, so that [`Lime::disk_irradiance`] gives LIME's
    /// camera-effective irradiance: the in-band irradiance of a
    /// solar-spectrum source that gives the camera the same electrons
    /// (what `effective_irradiance_*` are for a render). None also where
    /// the camera has no response in the band.
    pub fn camera_band(
        &self,
        sun: &SolarSpectrum,
        band: [f64; 2],
        response: impl Fn(f64) -> f64,
    ) -> Option<LimeBand> {
        let mut weighted = self.weighted_band(sun, band, &response)?;
        let knots = self.knots();
        let solar = integrate(band[0], band[1], &knots, |l| sun.eval(l));
        let electrons = integrate(band[0], band[1], &knots, |l| sun.eval(l) * response(l));
        let scale = solar / electrons;
        if !(electrons > 0.0 && scale.is_finite()) {
            return None;
        }
        weighted.weights = weighted.weights.map(|w| w * scale);
        Some(weighted)
    }

    /// The composite spectrum's knots and the band centres [m], sorted.
    fn knots(&self) -> Vec<f64> {
        let mut knots: Vec<f64> = self.composite.wavelengths.clone();
        knots.extend(BANDS_NM.map(|nm| nm * 1e-9));
        knots.sort_by(f64::total_cmp);
        knots
    }

    /// W_k = ∫ C h_k E☉ `weight` dλ over `band`.
    fn weighted_band(
        &self,
        sun: &SolarSpectrum,
        band: [f64; 2],
        weight: impl Fn(f64) -> f64,
    ) -> Option<LimeBand> {
        let table = &self.composite.wavelengths;
        if !(band[0] >= table[0] && band[1] <= table[table.len() - 1] && band[1] > band[0]) {
            return None;
        }
        let knots = self.knots();
        let weights = std::array::from_fn(|k| {
            integrate(band[0], band[1], &knots, |l| {
                self.composite.eval(l) * band_weights(l)[k] * sun.eval(l) * weight(l)
            })
        });
        Some(LimeBand { band, weights })
    }

    /// LIME's disk irradiance at the observer over `band` [W m⁻²]:
    /// Ω/π (1 au/d_sun)² (d₀/d_obs)² ∫ A(λ) E☉(λ) dλ.
    pub fn disk_irradiance(&self, band: &LimeBand, geo: &LunarGeometry) -> f64 {
        let ratios = self.ratios(geo);
        let reflected: f64 = ratios.iter().zip(band.weights).map(|(r, w)| r * w).sum();
        reflected * OMEGA / std::f64::consts::PI
            * (AU / geo.sun_distance_m).powi(2)
            * (REFERENCE_DISTANCE / geo.observer_distance_m).powi(2)
    }

    /// The render's disk irradiance against LIME's at `geo`: `rendered`
    /// [W m⁻²] over `band`, and `effective` (the camera-effective one) over
    /// `camera` ([`Lime::camera_band`]). None where LIME's is not positive
    /// and finite, or the ratio is not finite.
    pub fn compare(
        &self,
        band: &LimeBand,
        camera: Option<(&LimeBand, f64)>,
        geo: LunarGeometry,
        rendered: f64,
    ) -> Option<LimeComparison> {
        let ratio_to = |lime: f64, render: f64| {
            let ratio = render / lime;
            (lime > 0.0 && lime.is_finite() && ratio.is_finite()).then_some((lime, ratio))
        };
        let (lime, ratio) = ratio_to(self.disk_irradiance(band, &geo), rendered)?;
        let effective =
            camera.and_then(|(b, effective)| ratio_to(self.disk_irradiance(b, &geo), effective));
        Some(LimeComparison {
            disk_irradiance_w_m2: lime,
            render_over_lime: ratio,
            effective_disk_irradiance_w_m2: effective.map(|e| e.0),
            effective_render_over_lime: effective.map(|e| e.1),
            geometry: geo,
            extrapolated: geo.extrapolations([band.band[0] * 1e9, band.band[1] * 1e9]),
        })
    }
}

/// A band's integrals for [`Lime::disk_irradiance`] ([`Lime::band`]).
#[derive(Clone, Debug)]
pub struct LimeBand {
    /// The band [m].
    band: [f64; 2],
    /// W_k [W m⁻²].
    weights: [f64; 6],
}

/// Weights of the six bands in the linear interpolation at a wavelength
/// [m] (the end bands' values held beyond them); they sum to 1.
fn band_weights(wavelength_m: f64) -> [f64; 6] {
    let nm = (wavelength_m * 1e9).clamp(BANDS_NM[0], BANDS_NM[5]);
    let k = BANDS_NM.partition_point(|&b| b <= nm).clamp(1, 5);
    let t = (nm - BANDS_NM[k - 1]) / (BANDS_NM[k] - BANDS_NM[k - 1]);
    let mut w = [0.0; 6];
    w[k - 1] = 1.0 - t;
    w[k] = t;
    w
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_tables_parse_and_match_the_published_rows() {
        let lime = Lime::embedded();
        // The first and last coefficients of the 440 nm column and the
        // composite's first row, as printed in data/lime.
        assert_eq!(lime.bands[0].0[0], -2.8458263848079355);
        assert_eq!(lime.bands[5].0[17], 8.973326631015963);
        assert_eq!(lime.composite.values[0], 0.09966);
    }

    #[test]
    fn geometry_of_known_directions() {
        let obs = DVec3::new(0.0, 1.0, 1.0) * 1e8;
        let sun = DVec3::new(1.0, 0.0, 0.0) * AU;
        let g = LunarGeometry::from_moon_fixed(obs, sun).unwrap();
        assert!((g.observer_selenographic_lat_deg - 45.0).abs() < 1e-12);
        assert!((g.observer_selenographic_lon_deg - 90.0).abs() < 1e-12);
        assert!(g.sun_selenographic_lon_deg.abs() < 1e-12);
        assert!((g.phase_deg - 90.0).abs() < 1e-12);
        assert!(LunarGeometry::from_moon_fixed(DVec3::ZERO, sun).is_none());
    }

    #[test]
    fn reflectance_passes_through_the_band_values() {
        let lime = Lime::embedded();
        let g = LunarGeometry::from_moon_fixed(
            DVec3::new(1.0, 0.0, 0.0) * REFERENCE_DISTANCE,
            DVec3::new(0.5, 0.8660254037844386, 0.0) * AU,
        )
        .unwrap();
        for (k, nm) in BANDS_NM.iter().enumerate() {
            let a = lime.reflectance(nm * 1e-9, &g);
            assert!((a / lime.band_reflectance(k, &g) - 1.0).abs() < 1e-12);
        }
    }
}
