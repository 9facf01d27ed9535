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

/// Half-step [rad] of the central differences of [`surface_normal_tiled`]:
/// far below any DEM cell, far above f64 rounding of the heights.
const SURFACE_STEP: f64 = 1e-7;

/// Unit normal at `n` of the bilinear surface r(n) = R + h(n) itself, the
/// surface the caps' corners and the limb sit on (`r` its radius there):
/// central differences of its height over ±[`SURFACE_STEP`], exact inside
/// a DEM cell, where the bilinear height is linear along each axis. The
/// slope maps' normal ([`displaced_tiled`], central differences between
/// cells, interpolated) is smooth instead; seen at a grazing angle the two
/// give projected areas tens of per cent apart (`render::occlusion`).
#[inline]
pub fn surface_normal_tiled(
    height: &EquirectMap,
    tiles: Option<&HeightTiles>,
    radius: f64,
    n: DVec3,
    r: f64,
) -> DVec3 {
    let (lat, lon) = super::maps::lat_lon(n);
    let h = |la: f64, lo: f64| height_at(height, tiles, la, lo);
    let d = SURFACE_STEP;
    let d_lat = (h(lat + d, lon) - h(lat - d, lon)) / (2.0 * d);
    let d_lon = (h(lat, lon + d) - h(lat, lon - d)) / (2.0 * d);
    normal_of((r - radius, d_lat, d_lon), radius, n, lat, lon).1
}

/// Height [m] at (`lat`, `lon`): the tiles' where they cover it, else the
/// global DEM's (as [`displaced_radius_tiled`]).
#[inline]
fn height_at(height: &EquirectMap, tiles: Option<&HeightTiles>, lat: f64, lon: f64) -> f64 {
    match tiles {
        Some(t) if t.covers(lat, lon) => t.height(lat, lon, &|| height.sample(lat, lon)),
        _ => height.sample(lat, lon),
    }
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
