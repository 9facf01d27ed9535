//! The paper's (θ, φ) frame and the lit, visible part of the sphere in it.
//!
//! Frame (Lester et al. 1979): x̂ toward the Sun, the camera in the x̂–ŷ
//! plane at longitude φ = α (the phase angle at the body centre), ẑ the pole
//! of that scattering plane. A unit normal is
//! n = (sinθ cosφ, sinθ sinφ, cosθ), so for a distant Sun and camera
//! μ0 = sinθ cosφ and μ = sinθ cos(α − φ).
//!
//! At finite distance the camera sees the cap n·ĉ > R/D and the Sun lights
//! n·ŝ > R/D_sun. For every θ both conditions are arcs of φ, so the lit and
//! visible region is, exactly, θ ∈ [θ_min, π − θ_min] and
//! φ ∈ [lo(θ), hi(θ)]. Caps are laid out in the unit square (t, s):
//! θ = θ_min + t (π − 2θ_min), φ = lo(θ) + s (hi(θ) − lo(θ)).

use glam::DVec3;

/// Lester frame of one body–camera–Sun configuration and its lit, visible
/// region. Vectors are in the world frame, relative to the body centre.
#[derive(Clone, Copy, Debug)]
pub struct Lune {
    /// Unit vector toward the Sun.
    pub x: DVec3,
    /// Completes the frame; the camera has a non-negative ŷ component.
    pub y: DVec3,
    /// Pole of the scattering plane.
    pub z: DVec3,
    /// Phase angle at the body centre [rad].
    pub alpha: f64,
    /// Camera distance from the body centre [m].
    pub camera_range: f64,
    /// Sun distance from the body centre [m].
    pub sun_range: f64,
    /// R / camera_range (0 in the distant-observer limit).
    pub k_view: f64,
    /// R / sun_range (0 in the distant-Sun limit).
    pub k_sun: f64,
    /// Cosine of the largest angle from the camera's direction of a point
    /// the frame treats as visible: `k_view` (the sphere's limb), lower
    /// when relief can rise over the limb ([`Lune::widen_view`]).
    pub view_cos: f64,
    /// Smallest colatitude with lit, visible points.
    pub theta_min: f64,
    /// Whether any point is both lit and visible.
    pub empty: bool,
}

impl Lune {
    /// Frame for a body of radius `radius` with the camera at `camera` and
    /// the Sun at `sun` (both relative to the body centre). With `distant`,
    /// the paper's far-field limit: every cap sees the camera and the Sun
    /// along the centre's directions.
    pub fn new(camera: DVec3, sun: DVec3, radius: f64, distant: bool) -> Self {
        let camera_range = camera.length();
        let sun_range = sun.length();
        let x = sun / sun_range;
        let view = camera / camera_range;
        let mut z = x.cross(view);
        if z.length() < 1e-12 {
            // Sun and camera aligned: any pole perpendicular to x̂ will do.
            z = x.any_orthonormal_vector();
        }
        let z = z.normalize();
        let y = z.cross(x);
        let alpha = view.dot(y).max(0.0).atan2(view.dot(x));
        let (k_view, k_sun) = if distant {
            (0.0, 0.0)
        } else {
            (radius / camera_range, radius / sun_range)
        };
        let mut lune = Lune {
            x,
            y,
            z,
            alpha,
            camera_range,
            sun_range,
            k_view,
            k_sun,
            view_cos: k_view,
            theta_min: 0.0,
            empty: false,
        };
        lune.find_theta_range();
        lune
    }

    /// Half-widths (a_view, a_sun) of the visible and lit arcs at sinθ.
    #[inline]
    fn half_widths(&self, sin_theta: f64) -> (f64, f64) {
        // Half-width of the arc n·d̂ > k of the row at sinθ (d̂ in the
        // equator plane): 0 when none of it, π when all of it qualifies.
        let a = |k: f64| {
            if k == 0.0 {
                std::f64::consts::FRAC_PI_2
            } else if sin_theta <= k {
                0.0
            } else if sin_theta <= -k {
                std::f64::consts::PI
            } else {
                let x = k / sin_theta;
                if x.abs() < 1e-3 {
                    // acos x = π/2 − x − x³/6 − 3x⁵/40 − …, next term < 1e-21.
                    let x2 = x * x;
                    std::f64::consts::FRAC_PI_2 - x * (1.0 + x2 * (1.0 / 6.0 + x2 * 3.0 / 40.0))
                } else {
                    x.min(1.0).acos()
                }
            }
        };
        (a(self.view_cos), a(self.k_sun))
    }

    /// Longitude range [lo, hi] of the lit, visible points at sinθ (lo ≥ hi
    /// when there are none).
    #[inline]
    pub fn phi_range(&self, sin_theta: f64) -> (f64, f64) {
        let (av, asun) = self.half_widths(sin_theta);
        ((self.alpha - av).max(-asun), (self.alpha + av).min(asun))
    }

    /// Widens the visible region for relief of at most `h` [m] over and
    /// under the sphere of radius `radius` [m]: a point seeing the camera
    /// over terrain nowhere lower than R − h, itself no higher than R + h,
    /// lies within ψ = acos((R − h)/D) + acos((R − h)/(R + h)) of the
    /// camera's direction (π/2 for the first term at infinite range).
    /// Points past the sphere's limb (`k_view`) then need a line-of-sight
    /// test (`render::sight`).
    pub fn widen_view(&mut self, radius: f64, h: f64) {
        if !(h > 0.0) || self.empty {
            return;
        }
        let low = (radius - h).max(0.0);
        let limb = if self.k_view > 0.0 {
            (low / self.camera_range).min(1.0).acos()
        } else {
            std::f64::consts::FRAC_PI_2
        };
        let psi = (limb + (low / (radius + h)).acos()).min(std::f64::consts::PI);
        self.view_cos = self.view_cos.min(psi.cos());
        self.theta_min = 0.0;
        self.find_theta_range();
    }

    /// Whether [`Lune::widen_view`] took the region past the sphere's limb.
    pub fn widened(&self) -> bool {
        self.view_cos < self.k_view
    }

    fn find_theta_range(&mut self) {
        let width = |s: f64| {
            let (lo, hi) = self.phi_range(s);
            hi - lo
        };
        if width(1.0) <= 0.0 {
            self.empty = true;
            return;
        }
        let k = self.view_cos.max(self.k_sun);
        if width(k.max(0.0)) > 0.0 {
            self.theta_min = k.max(0.0).asin();
            return;
        }
        // Bisection on sinθ for the row where the arcs start to overlap.
        let (mut lo, mut hi) = (k, 1.0);
        for _ in 0..100 {
            let mid = 0.5 * (lo + hi);
            if width(mid) > 0.0 {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        self.theta_min = lo.asin();
    }

    /// Largest colatitude with lit, visible points.
    pub fn theta_max(&self) -> f64 {
        std::f64::consts::PI - self.theta_min
    }

    /// Camera position in the frame's coordinates.
    pub fn camera_local(&self) -> DVec3 {
        DVec3::new(self.alpha.cos(), self.alpha.sin(), 0.0) * self.camera_range
    }

    /// Unit normal of (θ, φ) in world coordinates.
    pub fn normal(&self, theta: f64, phi: f64) -> DVec3 {
        let (st, ct) = theta.sin_cos();
        let (sp, cp) = phi.sin_cos();
        self.x * (st * cp) + self.y * (st * sp) + self.z * ct
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distant_lune_is_the_papers_rectangle() {
        let alpha = 1.0f64;
        let cam = DVec3::new(alpha.cos(), alpha.sin(), 0.0) * 1e12;
        let l = Lune::new(cam, DVec3::X * 1e15, 1.0, true);
        assert!((l.alpha - alpha).abs() < 1e-12);
        let (lo, hi) = l.phi_range(0.3);
        assert!((lo - (alpha - std::f64::consts::FRAC_PI_2)).abs() < 1e-12);
        assert!((hi - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert_eq!(l.theta_min, 0.0);
    }

    #[test]
    fn finite_range_boundaries_are_the_visibility_circle() {
        // Points on the φ boundary satisfy n·c = R exactly.
        let cam = DVec3::new(0.3, 2.0, 0.4);
        let sun = DVec3::new(1e9, 1.0, 0.0);
        let l = Lune::new(cam, sun, 1.0, false);
        for theta in [0.8f64, 1.2, 1.57, 2.0] {
            let (lo, hi) = l.phi_range(theta.sin());
            assert!(hi > lo);
            for phi in [lo, hi] {
                let n = l.normal(theta, phi);
                let visible = n.dot(cam) - 1.0;
                let lit = n.dot(sun) - 1.0;
                assert!(visible.abs() < 1e-9 || lit.abs() < 1e-3 * sun.length());
                assert!(visible > -1e-9 && lit > -1e-6);
            }
        }
    }

    /// Widened for relief h, the view boundary is the circle n·ĉ =
    /// cos ψ with ψ written out here, and the lit boundary is unchanged.
    #[test]
    fn widened_view_reaches_past_the_limb_by_the_reliefs_reach() {
        let cam = DVec3::new(0.0, 4.0, 0.0);
        let sun = DVec3::new(1e9, 0.0, 0.0);
        let mut l = Lune::new(cam, sun, 1.0, false);
        assert!(!l.widened());
        l.widen_view(1.0, 0.04);
        assert!(l.widened());
        let psi = (0.96f64 / 4.0).acos() + (0.96f64 / 1.04).acos();
        assert!((l.view_cos - psi.cos()).abs() < 1e-12);
        let (mut on_view, mut on_lit) = (0, 0);
        for theta in [0.5f64, 1.0, 1.3, 1.57, 2.2] {
            let (lo, hi) = l.phi_range(theta.sin());
            assert!(hi > lo);
            for phi in [lo, hi] {
                let n = l.normal(theta, phi);
                let view = n.dot(cam.normalize()) - psi.cos();
                let lit = n.dot(sun.normalize()) - 1e-9;
                assert!(view > -1e-9 && lit > -1e-6, "θ {theta} φ {phi}");
                on_view += (view.abs() < 1e-9) as usize;
                on_lit += (lit.abs() < 1e-6) as usize;
            }
        }
        assert!(on_view > 0 && on_lit > 0, "{on_view} {on_lit}");
        let mut flat = Lune::new(cam, sun, 1.0, false);
        flat.widen_view(1.0, 0.0);
        assert!(!flat.widened() && flat.theta_min == Lune::new(cam, sun, 1.0, false).theta_min);
    }

    #[test]
    fn full_phase_has_nothing_lit_and_visible() {
        let l = Lune::new(-DVec3::X * 1e9, DVec3::X * 1e11, 1.0, false);
        assert!(l.empty);
    }
}
