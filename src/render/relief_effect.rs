//! How much a body's relief can change a frame's pixels: the estimate
//! behind `mode = "auto"` ([`super::relief::decide_for_frame`]), compared
//! with the frame's per-pixel error target.
//!
//! Each effect is the largest change of one pixel, relative to the value
//! of a whole pixel of that surface (a partly covered limb pixel's change
//! is counted against a whole pixel there), with pixels darker than
//! [`PIXEL_FLOOR`] of the frame's brightest counted against that floor,
//! as the planner's error does (`crate::planner`):
//!
//! - Cast shadows. A relief of height h with the Sun at elevation e casts
//!   a shadow h / tan e long; seen at phase α in the Sun's vertical plane
//!   it shows h sin α / sin e of it across the line of sight (the rest
//!   hides behind the relief), L = that × f / d pixels at distance d. A
//!   shadow L px long across a pixel darkens min(L, 1) of it:
//!   `shadow = min(L, 1)`. h is the DEM's height range (a bound) and
//!   1/sin e is capped where the shadow would outrun the curvature's reach
//!   √(2 R h).
//! - Shading. A pixel's mean normal is the sphere's tilted by the mean
//!   slope of the DEM over its footprint d / f [m] (at most s(d / f), the
//!   DEM's steepest slope at that baseline, `scene::relief_slopes`). The
//!   radiance then changes by |I(n_s) − I(n)| ≈ |∂I/∂n| s; it is
//!   evaluated with the frame's own model for n tilted by s toward and away
//!   from the Sun's and the camera's azimuths (where μ0 and μ change
//!   fastest; a facet tilted past the camera's horizon is left to the
//!   limb's term) and divided by max(I(n), floor · brightest).
//! - The limb ([`super::relief::decide_for_frame`]). The DEM's largest
//!   |height| moves the limb by `limb_px`; a limb pixel changes by
//!   min(limb_px, 1) of a whole pixel.
//!
//! All are bounds taken at the worst of a 32 × 32 scan of the visible lit
//! disk (the largest height, the steepest slope), so a frame whose
//! estimate lies below its target differs from its relief render by less;
//! `tests/relief_switch.rs` checks both sides against renders with and
//! without relief.

use glam::DVec3;

use super::caps::Frame;
use crate::radiometry::ScatteringGeometry;
use crate::scene::horizon::ReliefShadows;

/// Pixels below this fraction of the frame's brightest are judged against
/// it (the planner's `PIXEL_FLOOR`).
pub const PIXEL_FLOOR: f64 = 0.01;

/// Samples per axis of the lune scanned.
const SCAN: usize = 32;

/// The per-pixel effects of a frame's relief (see the module).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ReliefEffect {
    /// Longest visible shadow on the image [px].
    pub shadow_px: f64,
    /// Largest relative change of a pixel by cast shadows: min(shadow_px, 1).
    pub shadow: f64,
    /// Largest relative change of a pixel by the DEM's slopes.
    pub shading: f64,
    /// Lowest Sun elevation over the visible lit disk [deg].
    pub min_sun_elevation_deg: f64,
    /// Surface footprint [m] of a pixel where the shadow is longest.
    pub pixel_footprint_m: f64,
}

/// One scanned point: its radiance and its change under the tilt.
struct Point {
    radiance: f64,
    change: f64,
}

/// The effects of `shadows`' relief on `frame` (see the module).
pub fn estimate(shadows: &ReliefShadows, frame: &Frame) -> ReliefEffect {
    let lune = &frame.lune;
    let (h, r) = (shadows.relief, frame.radius);
    let f = frame.camera.fx.max(frame.camera.fy);
    let cam = lune.camera_local();
    let min_sin_e = h / (2.0 * r * h).sqrt().max(h);
    let mut e = ReliefEffect {
        min_sun_elevation_deg: 90.0,
        ..Default::default()
    };
    let mut points = Vec::with_capacity(SCAN * SCAN);
    let (t_lo, t_hi) = (lune.theta_min, std::f64::consts::PI - lune.theta_min);
    for a in 0..SCAN {
        let theta = t_lo + (a as f64 + 0.5) / SCAN as f64 * (t_hi - t_lo);
        let (st, ct) = theta.sin_cos();
        let (lo, hi) = lune.phi_range(st);
        for b in 0..SCAN {
            let phi = lo + (b as f64 + 0.5) / SCAN as f64 * (hi - lo);
            let n = DVec3::new(st * phi.cos(), st * phi.sin(), ct);
            let to_cam = cam - n * r;
            let dist = to_cam.length();
            let sin_e = n.x.max(0.0);
            let px = h * lune.alpha.sin() / sin_e.max(min_sin_e) * f / dist;
            e.min_sun_elevation_deg = e.min_sun_elevation_deg.min(sin_e.asin().to_degrees());
            if px >= e.shadow_px {
                e.shadow_px = px;
                e.pixel_footprint_m = dist / f;
            }
            let tilt = shadows.slopes.at(dist / f);
            points.push(shading_change(frame, n, to_cam / dist, tilt));
        }
    }
    e.shadow = e.shadow_px.min(1.0);
    let brightest = points.iter().map(|p| p.radiance).fold(0.0, f64::max);
    let floor = PIXEL_FLOOR * brightest;
    e.shading = points
        .iter()
        .filter(|p| p.change > 0.0)
        .map(|p| p.change / p.radiance.max(floor))
        .fold(0.0, f64::max);
    e
}

/// The radiance at normal `n` (the Sun along +x, the camera along `v`)
/// and its largest change when `n` tilts by `tilt` [rad] toward or away
/// from the Sun's or the camera's azimuth, the camera still above the
/// tilted facet's horizon (a facet tilted past it is the limb's effect).
fn shading_change(frame: &Frame, n: DVec3, v: DVec3, tilt: f64) -> Point {
    let l = DVec3::X;
    let radiance = radiance_at(frame, n, l, v);
    let mut change = 0.0f64;
    if tilt > 0.0 {
        let (s, c) = tilt.sin_cos();
        for toward in [l, v] {
            let t = toward - n * toward.dot(n);
            if t.length_squared() < 1e-24 {
                continue;
            }
            let t = t.normalize();
            for sign in [1.0, -1.0] {
                let tilted = n * c + t * (sign * s);
                // A facet tilted away from the camera is hidden: the
                // limb's effect, not the shading's.
                if tilted.dot(v) > 0.0 {
                    change = change.max((radiance_at(frame, tilted, l, v) - radiance).abs());
                }
            }
        }
    }
    Point { radiance, change }
}

/// The frame's radiance factor at normal `n` (0 where the Sun or the
/// camera is below its horizontal).
fn radiance_at(frame: &Frame, n: DVec3, l: DVec3, v: DVec3) -> f64 {
    let g = ScatteringGeometry::from_vectors(n, l, v);
    if g.mu0 <= 0.0 || g.mu <= 0.0 {
        return 0.0;
    }
    let i = frame.model.radiance_factor(&g, frame.albedo);
    if i.is_finite() {
        i.max(0.0)
    } else {
        0.0
    }
}
