//! Cast shadows of relief in a frame: the per-sample factor from the
//! body's horizon map ([`crate::scene::horizon`]) and the per-frame
//! decision whether the frame resolves them at all.
//!
//! A sample's factor is one horizon lookup: the Sun's elevation and
//! azimuth in the sphere's local frame at the sample, and the lit share
//! of the solar disk above the relief's horizon there.

use glam::DVec3;
use serde::Serialize;

use super::caps::Frame;
use crate::scene::horizon::{HorizonMap, ReliefShadows, ShadowMode};

/// What the per-sample loops need of the horizon map in one frame.
#[derive(Clone, Copy, Debug)]
pub struct FrameShadows<'a> {
    /// The body's horizon map.
    pub map: &'a HorizonMap,
    /// The Sun's apparent radius at the body [rad].
    pub sun_radius: f64,
    /// sin(highest horizon + Sun radius): a sample whose Sun stands higher
    /// is wholly lit and skips the lookup.
    sin_clear: f64,
    /// sin(Sun radius): a sample whose Sun stands lower is dark.
    sin_radius: f64,
    /// sin(highest horizon): a camera standing higher sees the point.
    sin_max: f64,
}

impl<'a> FrameShadows<'a> {
    /// Shadows from `map` with the Sun `sun_radius` [rad] across.
    pub fn new(map: &'a HorizonMap, sun_radius: f64) -> Self {
        let clear = (map.max_elevation() + sun_radius).min(std::f64::consts::FRAC_PI_2);
        FrameShadows {
            map,
            sun_radius,
            sin_clear: clear.sin(),
            sin_radius: sun_radius.sin(),
            sin_max: map.max_elevation().min(std::f64::consts::FRAC_PI_2).sin(),
        }
    }

    /// Whether a point whose Sun stands at sin(elevation) `sin_e` is
    /// wholly lit wherever it is (above the highest horizon).
    #[inline]
    pub fn is_clear(&self, sin_e: f64) -> bool {
        sin_e >= self.sin_clear
    }

    /// Lit share at the point of body-fixed unit direction `n` (the
    /// sphere's normal), the Sun along body-fixed unit vector `l` from it.
    #[inline]
    pub fn factor(&self, n: DVec3, l: DVec3) -> f64 {
        let sin_e = l.dot(n);
        if sin_e >= self.sin_clear {
            return 1.0;
        }
        if sin_e <= -self.sin_radius {
            return 0.0;
        }
        self.factor_at(&self.geometry(n, l))
    }

    /// Whether the camera, along body-fixed unit vector `v` from the point
    /// of body-fixed unit normal `n` (the sphere's normal), stands above
    /// the relief's horizon in its azimuth there: 1 or 0 (a point, no
    /// disk). Like the Sun's factor, a horizon at or below the horizontal
    /// hides nothing.
    #[inline]
    pub fn camera_visible(&self, n: DVec3, v: DVec3) -> f64 {
        if v.dot(n) >= self.sin_max {
            return 1.0;
        }
        let g = self.geometry(n, v);
        if g.sin_e >= self.map.sin_elevation_bound_at(g.x, g.y) {
            return 1.0;
        }
        let horizon = self.map.elevation_at(g.x, g.y, g.north.atan2(g.east));
        let elevation = g.sin_e.clamp(-1.0, 1.0).asin();
        if horizon > 0.0 && elevation < horizon {
            0.0
        } else {
            1.0
        }
    }

    /// The Sun as seen from the point of body-fixed unit normal `n`: map
    /// coordinates, sin(elevation) and the Sun's local east and north
    /// components (east arbitrary at a pole).
    #[inline]
    pub fn geometry(&self, n: DVec3, l: DVec3) -> SunAtPoint {
        let rxy = n.x.hypot(n.y);
        let lat = n.z.atan2(rxy);
        let lon = n.y.atan2(n.x);
        let (x, y) = self.map.cell_coords(lat, lon);
        let east = if rxy > 1e-12 {
            DVec3::new(-n.y / rxy, n.x / rxy, 0.0)
        } else {
            DVec3::Y
        };
        let north = n.cross(east);
        SunAtPoint {
            x,
            y,
            sin_e: l.dot(n),
            east: l.dot(east),
            north: l.dot(north),
        }
    }

    /// Lit share for the Sun seen as `g` says: one bound read, and past it
    /// one horizon lookup. Every path of the factor ends here, so the
    /// interpolated geometry of the interior lattice
    /// ([`crate::render::interior`]) differs from the exact one only in `g`.
    #[inline]
    pub fn factor_at(&self, g: &SunAtPoint) -> f64 {
        if g.sin_e >= self.sin_clear {
            return 1.0;
        }
        // Wholly above every horizon the lookup would read (sin(b + ρ) ≤
        // sin b + ρ): lit.
        if g.sin_e >= self.map.sin_elevation_bound_at(g.x, g.y) + self.sun_radius {
            return 1.0;
        }
        let azimuth = g.north.atan2(g.east);
        let elevation = g.sin_e.clamp(-1.0, 1.0).asin();
        self.map
            .relief_factor_at(g.x, g.y, azimuth, elevation, self.sun_radius)
    }

    /// [`Self::factor_at`] for the Sun given in angles: its elevation
    /// [rad] and sine, and its azimuth [rad, counter-clockwise from local
    /// east]: no trigonometry before the lookup (the shadow-edge pass
    /// interpolates these across a pixel, `render::shadow_edges`).
    #[inline]
    pub fn factor_of_angles(&self, a: &SunAngles) -> f64 {
        if a.sin_e >= self.sin_clear {
            return 1.0;
        }
        if a.sin_e <= -self.sin_radius {
            return 0.0;
        }
        if a.sin_e >= self.map.sin_elevation_bound_at(a.x, a.y) + self.sun_radius {
            return 1.0;
        }
        self.map
            .relief_factor_at(a.x, a.y, a.azimuth, a.elevation, self.sun_radius)
    }
}

/// The Sun seen from one surface point, in what [`FrameShadows::factor_at`]
/// needs: smooth in the point away from the poles and the subsolar point,
/// so it can be interpolated.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SunAtPoint {
    /// Continuous horizon-map column (cell centres at integers; may lie a
    /// map width outside [0, width): it wraps).
    pub x: f64,
    /// Continuous horizon-map row (row 0 at the north edge).
    pub y: f64,
    /// sin(Sun elevation) above the sphere's local horizontal.
    pub sin_e: f64,
    /// Component of the unit Sun vector along local east.
    pub east: f64,
    /// Component of the unit Sun vector along local north.
    pub north: f64,
}

/// The Sun seen from one surface point as angles: what
/// [`FrameShadows::factor_of_angles`] needs, linear enough across a
/// pixel to be interpolated from its corners (away from the poles and the
/// subsolar point, where the azimuth turns fast).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SunAngles {
    /// Continuous horizon-map column (may lie outside [0, width): it wraps).
    pub x: f64,
    /// Continuous horizon-map row.
    pub y: f64,
    /// sin(Sun elevation) above the sphere's local horizontal.
    pub sin_e: f64,
    /// Sun elevation [rad].
    pub elevation: f64,
    /// Sun azimuth [rad, counter-clockwise from local east].
    pub azimuth: f64,
}

impl SunAngles {
    /// The angles of `g`.
    pub fn of(g: &SunAtPoint) -> SunAngles {
        SunAngles {
            x: g.x,
            y: g.y,
            sin_e: g.sin_e,
            elevation: g.sin_e.clamp(-1.0, 1.0).asin(),
            azimuth: g.north.atan2(g.east),
        }
    }
}

/// Which path a frame took for cast shadows, and why (`summary.json`).
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq)]
pub struct ShadowDecision {
    /// Whether the frame applied the horizon map.
    pub applied: bool,
    /// Why: `"mode = always"`, `"mode = never"`, `"auto: no shadow in the
    /// DEM"`, `"auto: resolved"` or `"auto: below a pixel"`.
    pub reason: &'static str,
    /// Longest visible shadow on the image [px] (`auto`'s measure).
    pub shadow_px: f64,
    /// Lowest Sun elevation over the visible lit disk [deg].
    pub min_sun_elevation_deg: f64,
    /// Surface footprint [m] of a pixel where the shadow is longest.
    pub pixel_footprint_m: f64,
    /// The DEM's cell [m].
    pub dem_cell_m: f64,
    /// Whether the frame moved the limb and tilted the normals with the
    /// DEM (`shadows.displace`; see [`decide_displacement`]).
    pub displaced: bool,
    /// How far [px] the DEM's highest point can move the limb on the image.
    pub limb_px: f64,
    /// Whether terrain hidden from the camera by nearer relief was dropped
    /// (a horizon lookup in the camera's azimuth): with both the shadows
    /// and the displacement.
    pub hidden_applied: bool,
    /// Interior pixels a shadow's edge crosses, whose factor was averaged
    /// over their preimage ([`crate::render::shadow_edges`]): 0 without
    /// shadows, with `[render] shadow_edges = false`, or where the caps
    /// integrate every pixel.
    pub edge_pixels: usize,
}

/// Length on the image [px] that a shadow must reach to be applied in
/// `auto` mode.
pub const AUTO_MIN_PIXELS: f64 = 0.1;

/// Samples per axis of the lune scanned by [`decide_for_frame`].
const SCAN: usize = 32;

/// Whether `frame` resolves the relief's shadows. `auto` applies them when
/// the longest visible shadow on the image reaches [`AUTO_MIN_PIXELS`].
/// A step of height h with the Sun at elevation e and the camera at phase
/// α in the same vertical plane shows a shadow of h sin α / sin e across
/// the line of sight (the rest hides behind the step); h is the DEM's
/// height range and 1/sin e is capped where the shadow would outrun the
/// curvature's reach √(2 R h). Scanned over a 32 × 32 grid of the
/// visible lit lune, each point's length over its pixel footprint d/f.
pub fn decide_for_frame(shadows: &ReliefShadows, frame: &Frame) -> ShadowDecision {
    let lune = &frame.lune;
    let (h, r) = (shadows.relief, frame.radius);
    let f = frame.camera.fx.max(frame.camera.fy);
    let cam = lune.camera_local();
    let min_sin_e = h / (2.0 * r * h).sqrt().max(h);
    let mut d = ShadowDecision {
        dem_cell_m: shadows.cell,
        min_sun_elevation_deg: 90.0,
        ..Default::default()
    };
    let (t_lo, t_hi) = (lune.theta_min, std::f64::consts::PI - lune.theta_min);
    for a in 0..SCAN {
        let theta = t_lo + (a as f64 + 0.5) / SCAN as f64 * (t_hi - t_lo);
        let (st, ct) = theta.sin_cos();
        let (lo, hi) = lune.phi_range(st);
        for b in 0..SCAN {
            let phi = lo + (b as f64 + 0.5) / SCAN as f64 * (hi - lo);
            let n = DVec3::new(st * phi.cos(), st * phi.sin(), ct);
            let dist = (cam - n * r).length();
            let sin_e = n.x.max(0.0);
            let px = h * lune.alpha.sin() / sin_e.max(min_sin_e) * f / dist;
            d.min_sun_elevation_deg = d.min_sun_elevation_deg.min(sin_e.asin().to_degrees());
            if px >= d.shadow_px {
                d.shadow_px = px;
                d.pixel_footprint_m = dist / f;
            }
        }
    }
    let any = shadows.map.max_elevation() > 0.0;
    (d.applied, d.reason) = match shadows.mode {
        ShadowMode::Never => (false, "mode = never"),
        ShadowMode::Always => (true, "mode = always"),
        ShadowMode::Auto if !any => (false, "auto: no shadow in the DEM"),
        ShadowMode::Auto if d.shadow_px >= AUTO_MIN_PIXELS => (true, "auto: resolved"),
        ShadowMode::Auto => (false, "auto: below a pixel"),
    };
    d
}

/// Whether `frame` keeps the body's displacement from the shadows' DEM
/// (`shadows.displace`): with the shadows, or where the DEM's highest
/// point moves the limb by [`AUTO_MIN_PIXELS`] or more (a far full Moon's
/// limb mountains can show where no shadow does); never with `mode =
/// never`. Records the outcome in `decision`.
pub fn decide_displacement(
    shadows: &ReliefShadows,
    frame: &mut Frame,
    decision: &mut ShadowDecision,
) {
    if frame.height.is_none() {
        return;
    }
    decision.limb_px = frame.relief_margin_px();
    decision.displaced = match shadows.mode {
        ShadowMode::Never => false,
        ShadowMode::Always => true,
        ShadowMode::Auto => decision.applied || decision.limb_px >= AUTO_MIN_PIXELS,
    };
    if !decision.displaced {
        frame.height = None;
    }
    decision.hidden_applied = decision.applied && decision.displaced;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::horizon::local_frame;
    use crate::scene::EquirectMap;

    /// A wall east of a point: the factor equals the disk share above the
    /// wall's elevation for a Sun in the east, 1 for a Sun in the west.
    #[test]
    fn the_factor_reads_the_horizon_in_the_suns_azimuth() {
        let (w, h) = (128, 64);
        let mut data = vec![0.0f32; w * h];
        for row in 0..h {
            data[row * w + 70] = 3000.0;
        }
        let dem = EquirectMap::new(w, h, data);
        let map = HorizonMap::compute(&dem, 1e5, 16);
        let (lat, lon) = dem.lat_lon_of(67.0, 31.0);
        let (up, east, _) = local_frame(lat, lon);
        let horizon = map.cell(67, 31, 0);
        assert!(horizon > 0.0);
        let rho = 0.005;
        let shadows = FrameShadows::new(&map, rho);
        for e in [horizon - 0.004, horizon, horizon + 0.002] {
            let sun_east = (up * e.sin() + east * e.cos()).normalize();
            let want = crate::scene::horizon::disk_fraction_above(e, horizon, rho)
                / crate::scene::horizon::disk_fraction_above(e, 0.0, rho);
            let got = shadows.factor(up, sun_east);
            assert!((got - want).abs() < 1e-9, "e {e}: {got} vs {want}");
            let sun_west = (up * e.sin() - east * e.cos()).normalize();
            assert_eq!(shadows.factor(up, sun_west), 1.0);
        }
    }
}
