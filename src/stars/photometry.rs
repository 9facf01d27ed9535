//! A star's light: its spectral irradiance at the camera from its V
//! magnitude and B−V colour, and the electron rate it gives through the
//! camera's QE × transmission.
//!
//! Zero point: V = 0 is f_λ = 363.1 × 10⁻¹¹ erg cm⁻² s⁻¹ Å⁻¹ =
//! 3.631 × 10⁻¹¹ W m⁻² nm⁻¹ at λ = 545 nm (Bessell, Castelli & Plez 1998,
//! A&A 333, 231, Table A2), i.e. 9.96 × 10⁷ photons s⁻¹ m⁻² nm⁻¹. The
//! spectrum is a blackbody at the temperature of the star's B−V
//! (Ballesteros 2012, EPL 97, 34008), scaled to that flux at 545 nm.

use crate::radiometry::spectrum::{electron_response, integrate, planck_radiance, Response};

/// Spectral irradiance of a V = 0 star at [`V_WAVELENGTH`] [W m⁻² m⁻¹].
pub const V_ZERO_POINT: f64 = 3.631e-2;
/// Effective wavelength of Johnson V [m].
pub const V_WAVELENGTH: f64 = 545e-9;

/// Blackbody temperature [K] of a star of colour `b_v` (Ballesteros'
/// formula): 4600 K × (1/(0.92 (B−V) + 1.7) + 1/(0.92 (B−V) + 0.62)).
pub fn temperature_from_b_v(b_v: f64) -> f64 {
    4600.0 * (1.0 / (0.92 * b_v + 1.7) + 1.0 / (0.92 * b_v + 0.62))
}

/// Spectral irradiance of the star at the camera at `wavelength` [m]
/// [W m⁻² m⁻¹].
pub fn spectral_irradiance(v_mag: f64, b_v: f64, wavelength: f64) -> f64 {
    let t = temperature_from_b_v(b_v);
    V_ZERO_POINT * 10f64.powf(-0.4 * v_mag) * planck_radiance(wavelength, t)
        / planck_radiance(V_WAVELENGTH, t)
}

/// Electrons per second per m² of pupil facing the star:
/// ∫_band F_λ QE T λ/(hc) dλ.
pub fn electron_rate_per_area(
    v_mag: f64,
    b_v: f64,
    qe: &Response,
    transmission: &Response,
    band: [f64; 2],
) -> f64 {
    let t = temperature_from_b_v(b_v);
    let scale = V_ZERO_POINT * 10f64.powf(-0.4 * v_mag) / planck_radiance(V_WAVELENGTH, t);
    scale
        * integrate(band[0], band[1], &[], |l| {
            planck_radiance(l, t) * electron_response(qe, transmission, l)
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sun_like_colour_gives_a_sun_like_temperature() {
        // Ballesteros' formula gives 5778 K for the Sun's B−V = 0.65
        // (4600 (1/2.298 + 1/1.218)), and Vega's ~0 gives ~10 100 K.
        let sun = temperature_from_b_v(0.65);
        assert!((sun - 4600.0 * (1.0 / 2.298 + 1.0 / 1.218)).abs() < 1e-9);
        assert!((5700.0..6000.0).contains(&sun));
        assert!((10_000.0..10_200.0).contains(&temperature_from_b_v(0.0)));
    }

    #[test]
    fn five_magnitudes_are_a_factor_100() {
        let a = spectral_irradiance(0.0, 0.5, 600e-9);
        let b = spectral_irradiance(5.0, 0.5, 600e-9);
        assert!((a / b - 100.0).abs() < 1e-9);
        // At 545 nm the zero point itself.
        assert!((spectral_irradiance(0.0, 1.2, V_WAVELENGTH) - V_ZERO_POINT).abs() < 1e-15);
    }
}
