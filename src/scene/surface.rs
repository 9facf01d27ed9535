//! The displaced surface of a body: the local radius and the geometric
//! normal of r(n) = R + h(n) for a height map h read bilinearly. The
//! renderer's caps (their corners on the image, the limb) and their
//! shading both come from here, so the limb, the incidence and emission
//! angles and the horizon map's DEM are one surface.

use glam::DVec3;

use super::maps::EquirectMap;

/// Radius [m] and unit geometric normal at the body-fixed unit direction
/// `n`, on a sphere of `radius` [m] raised by `height` [m] (with its
/// latitude and longitude derivatives [m/rad], [`EquirectMap::gradients`]):
/// the normal of p = n (R + h) is n − north h_lat / r − east h_lon / (r cos
/// lat), normalised (the cross product of ∂p/∂lon and ∂p/∂lat over
/// r² cos lat).
#[inline]
pub fn displaced(
    (height, d_lat, d_lon): &(EquirectMap, EquirectMap, EquirectMap),
    radius: f64,
    n: DVec3,
) -> (f64, DVec3) {
    let (lat, lon) = super::maps::lat_lon(n);
    let east = DVec3::new(-lon.sin(), lon.cos(), 0.0);
    let north = n.cross(east);
    let r = radius + height.sample(lat, lon);
    let cos_lat = lat.cos().max(1e-6);
    let g_north = d_lat.sample(lat, lon) / r;
    let g_east = d_lon.sample(lat, lon) / (r * cos_lat);
    (r, (n - north * g_north - east * g_east).normalize())
}

/// Local radius [m] alone (the limb needs no normal).
#[inline]
pub fn displaced_radius(height: &EquirectMap, radius: f64, n: DVec3) -> f64 {
    radius + height.sample_dir(n)
}
