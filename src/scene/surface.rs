//! The displaced surface of a body: the local radius and the geometric
//! normal of r(n) = R + h(n) for a height map h read bilinearly. The
//! renderer's caps (their corners on the image, the limb) and their
//! shading both come from here, so the limb, the incidence and emission
//! angles and the horizon map's DEM are one surface. DEM tiles, where they
//! cover a point, replace the global DEM's height and slopes there
//! ([`super::tile_surface`]).

use glam::DVec3;

use super::maps::EquirectMap;
use super::tile_surface::HeightTiles;

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
    let slopes = (
        height.sample(lat, lon),
        d_lat.sample(lat, lon),
        d_lon.sample(lat, lon),
    );
    normal_of(slopes, radius, n, lat, lon)
}

/// [`displaced`] with DEM `tiles` over the global DEM: where a tile covers
/// `n`, its blended height and slopes; elsewhere the same values as
/// [`displaced`], bit for bit.
#[inline]
pub fn displaced_tiled(
    maps: &(EquirectMap, EquirectMap, EquirectMap),
    tiles: Option<&HeightTiles>,
    radius: f64,
    n: DVec3,
) -> (f64, DVec3) {
    let Some(tiles) = tiles else {
        return displaced(maps, radius, n);
    };
    let (lat, lon) = super::maps::lat_lon(n);
    let (height, d_lat, d_lon) = maps;
    let base = || {
        (
            height.sample(lat, lon),
            d_lat.sample(lat, lon),
            d_lon.sample(lat, lon),
        )
    };
    normal_of(
        tiles.height_and_slopes(lat, lon, &base),
        radius,
        n,
        lat,
        lon,
    )
}

/// Radius and unit normal at `n` (latitude `lat`, longitude `lon`) from a
/// height [m] and its latitude and longitude slopes [m/rad].
#[inline]
fn normal_of(
    (height, d_lat, d_lon): (f64, f64, f64),
    radius: f64,
    n: DVec3,
    lat: f64,
    lon: f64,
) -> (f64, DVec3) {
    let east = DVec3::new(-lon.sin(), lon.cos(), 0.0);
    let north = n.cross(east);
    let r = radius + height;
    let cos_lat = lat.cos().max(1e-6);
    let g_north = d_lat / r;
    let g_east = d_lon / (r * cos_lat);
    (r, (n - north * g_north - east * g_east).normalize())
}

/// Local radius [m] alone (the limb needs no normal).
#[inline]
pub fn displaced_radius(height: &EquirectMap, radius: f64, n: DVec3) -> f64 {
    radius + height.sample_dir(n)
}

/// [`displaced_radius`] with DEM `tiles` over the global DEM (the same
/// value outside them, bit for bit).
#[inline]
pub fn displaced_radius_tiled(
    height: &EquirectMap,
    tiles: Option<&HeightTiles>,
    radius: f64,
    n: DVec3,
) -> f64 {
    match tiles {
        Some(t) => {
            let (lat, lon) = super::maps::lat_lon(n);
            if !t.covers(lat, lon) {
                return displaced_radius(height, radius, n);
            }
            radius + t.height(lat, lon, &|| height.sample(lat, lon))
        }
        None => displaced_radius(height, radius, n),
    }
}
