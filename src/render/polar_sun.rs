//! The Sun seen from surface points near a pole, in quantities that stay
//! smooth across the pole, so the interior lattice ([`super::interior`])
//! can interpolate them there too.
//!
//! Near a pole the map longitude and the local east turn as fast as
//! 1/cos latitude, so the equatorial lattice ([`SunAtPoint`]'s x and
//! east/north components) cannot be interpolated. A polar node holds
//! instead: the normal's body-fixed x and y, the squared colatitude from
//! the cap's pole, sin(Sun elevation), and the Sun's (east, north)
//! components rotated by s·longitude (s = +1 in the north cap, −1 in the
//! south), which tend to components along fixed body axes at the pole.
//! All six are smooth functions of the normal. A pixel gets its longitude
//! back with one `atan2`, its latitude with a square root and its local
//! (east, north) components by rotating back with cos/sin of longitude
//! read off the normal (no trigonometry); no ray–sphere hit.

use std::f64::consts::FRAC_PI_2;

use glam::DVec3;

use super::relief::{FrameShadows, SunAtPoint};
use crate::scene::horizon::HorizonMap;

/// The Sun at a polar node: normal x, y (body-fixed), colatitude² [rad²],
/// sin(elevation), and the (east, north) components rotated by s·longitude.
pub(super) type PolarNode = [f64; 6];

/// Component of [`PolarNode`] holding sin(Sun elevation).
pub(super) const SIN_E: usize = 3;

/// Nodes whose |sin latitude| is below this take the equatorial lattice
/// (or none): 0.9 is 64° of latitude, where 1/cos latitude is 2.3, so the
/// two lattices overlap (the equatorial one stops at |cos lat| = 0.3).
pub(super) const POLAR_MIN_SIN_LAT: f64 = 0.9;

/// Unit (cos, sin) of the longitude of a normal with components `x`, `y`
/// (east = +y at the pole itself, as [`FrameShadows::geometry`] takes it).
#[inline]
fn lon_cos_sin(x: f64, y: f64) -> (f64, f64) {
    let rxy = (x * x + y * y).sqrt();
    if rxy > 1e-12 {
        (x / rxy, y / rxy)
    } else {
        (1.0, 0.0)
    }
}

/// The polar node at body-fixed unit normal `n` with the Sun along
/// body-fixed unit `l`, in the cap of sign `cap` (±1); None outside it.
pub(super) fn polar_node(
    shadows: &FrameShadows,
    n: DVec3,
    l: DVec3,
    cap: f64,
) -> Option<PolarNode> {
    if n.z * cap < POLAR_MIN_SIN_LAT {
        return None;
    }
    let g = shadows.geometry(n, l);
    let (c, s) = lon_cos_sin(n.x, n.y);
    let s = cap * s;
    let colat = n.x.hypot(n.y).atan2(cap * n.z);
    Some([
        n.x,
        n.y,
        colat * colat,
        g.sin_e,
        g.east * c - g.north * s,
        g.east * s + g.north * c,
    ])
}

/// The Sun at a pixel whose interpolated polar node is `q`, in the cap of
/// sign `cap`, as the horizon lookup takes it.
#[inline]
pub(super) fn sun_at(map: &HorizonMap, q: &PolarNode, cap: f64) -> SunAtPoint {
    let [nx, ny, colat2, sin_e, east_rot, north_rot] = *q;
    let lon = ny.atan2(nx);
    let lat = cap * (FRAC_PI_2 - colat2.max(0.0).sqrt());
    let (x, y) = map.cell_coords(lat, lon);
    let (c, s) = lon_cos_sin(nx, ny);
    let s = cap * s;
    SunAtPoint {
        x,
        y,
        sin_e,
        east: east_rot * c + north_rot * s,
        north: north_rot * c - east_rot * s,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::EquirectMap;

    /// At points around both poles (one on the pole itself), a node read
    /// back gives the exact geometry: the same map cell and the same
    /// Sun components, within rounding.
    #[test]
    fn a_node_read_back_is_the_exact_geometry() {
        let dem = EquirectMap::new(64, 32, vec![0.0f32; 64 * 32]);
        let map = HorizonMap::compute(&dem, 1e5, 8);
        let shadows = FrameShadows::new(&map, 0.004);
        let l = DVec3::new(0.8, -0.3, 0.2).normalize();
        for cap in [1.0, -1.0] {
            for (colat, lon) in [(0.3, 2.0), (0.01, -3.0), (1e-6, 0.7), (0.4, -0.2)] {
                let n = DVec3::new(
                    f64::sin(colat) * f64::cos(lon),
                    f64::sin(colat) * f64::sin(lon),
                    cap * f64::cos(colat),
                );
                let q = polar_node(&shadows, n, l, cap).expect("inside the cap");
                let got = sun_at(&map, &q, cap);
                let want = shadows.geometry(n, l);
                for (a, b) in [
                    (got.x, want.x),
                    (got.y, want.y),
                    (got.sin_e, want.sin_e),
                    (got.east, want.east),
                    (got.north, want.north),
                ] {
                    assert!((a - b).abs() < 1e-9, "cap {cap} colat {colat}: {a} vs {b}");
                }
                assert!(polar_node(&shadows, n, l, -cap).is_none());
            }
        }
    }
}
