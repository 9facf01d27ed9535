//! Photometric geometry of one scattering event: incidence, emission and
//! phase, all given as cosines computed from unit vectors.

/// Cosines of one scattering event at a surface point.
///
/// `mu0 = n·l`, `mu = n·v`, `cos_g = l·v`, with `n` the surface normal, `l`
/// the unit vector toward the Sun and `v` the unit vector toward the camera.
/// The phase angle is always taken from `l·v`, never as `i + e`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScatteringGeometry {
    /// cos i (incidence).
    pub mu0: f64,
    /// cos e (emission).
    pub mu: f64,
    /// cos g (phase).
    pub cos_g: f64,
}

impl ScatteringGeometry {
    /// Geometry from unit vectors (normal, to-Sun, to-camera).
    #[inline]
    pub fn from_vectors(n: glam::DVec3, l: glam::DVec3, v: glam::DVec3) -> Self {
        Self {
            mu0: n.dot(l),
            mu: n.dot(v),
            cos_g: l.dot(v).clamp(-1.0, 1.0),
        }
    }

    /// Geometry from the angles i, e (incidence, emission) and ψ, the azimuth
    /// between the incidence and emission planes (ψ = 0: Sun and camera on the
    /// same side, so g = |i - e|). Angles in radians.
    pub fn from_angles(i: f64, e: f64, psi: f64) -> Self {
        let (si, ci) = i.sin_cos();
        let (se, ce) = e.sin_cos();
        Self {
            mu0: ci,
            mu: ce,
            cos_g: (ci * ce + si * se * psi.cos()).clamp(-1.0, 1.0),
        }
    }

    /// Phase angle g in radians.
    #[inline]
    pub fn phase(&self) -> f64 {
        self.cos_g.clamp(-1.0, 1.0).acos()
    }

    /// cos ψ, the azimuth between the incidence and emission planes.
    ///
    /// Undefined when i = 0 or e = 0; there every model's dependence on ψ
    /// vanishes, and 1 is returned. The result is clamped to [-1, 1].
    #[inline]
    pub fn cos_azimuth(&self) -> f64 {
        let si2 = (1.0 - self.mu0 * self.mu0).max(0.0);
        let se2 = (1.0 - self.mu * self.mu).max(0.0);
        let denom = (si2 * se2).sqrt();
        if denom < 1e-12 {
            return 1.0;
        }
        ((self.cos_g - self.mu0 * self.mu) / denom).clamp(-1.0, 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn azimuth_round_trip() {
        for &(i, e, psi) in &[(0.3, 0.7, 0.0), (1.0, 0.2, 2.0), (0.5, 1.2, 3.0)] {
            let g = ScatteringGeometry::from_angles(i, e, psi);
            assert!((g.cos_azimuth() - f64::cos(psi)).abs() < 1e-9);
        }
    }

    #[test]
    fn azimuth_defined_at_normal_incidence() {
        let g = ScatteringGeometry::from_angles(0.0, 0.4, 1.0);
        assert!(g.cos_azimuth().is_finite());
        assert!((g.phase() - 0.4).abs() < 1e-12);
    }
}
