//! User map tiles layered over a body's global maps: DEM tiles (heights,
//! `[[body.dem_tiles]]`) and albedo tiles (`[[body.albedo_tiles]]`), each an
//! equirectangular image (float GeoTIFF, 8/16-bit PNG or TIFF) with its
//! latitude/longitude limits given in the scene. This module owns their
//! checks, the blended lookup (the finest tile covering a point wins; a
//! tile fades into what lies under it over a border band of `blend`
//! cells), and the per-tile horizon maps that let the DEM tiles cast
//! shadows: each tile's horizon map is marched at the tile's resolution
//! over the tile (blended over the global DEM) and continues on the global
//! DEM where the march leaves the tile; cached on disk like the global one.

use std::f64::consts::PI;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::DVec3;
use rayon::prelude::*;
use serde::Deserialize;
use sha2::{Digest, Sha256};

use super::horizon::{self, HorizonMap, HorizonOverlay};
use super::maps::EquirectMap;
use crate::error::{Error, Result};

/// Most tiles of one kind on a body.
pub const MAX_TILES: usize = 64;
/// Width [cells] of the blend band unless the scene says otherwise.
pub const DEFAULT_BLEND_CELLS: f64 = 4.0;
/// Tiles whose latitude cells differ by less than this factor are at the
/// same resolution: overlapping, neither would win, so they are refused.
pub const SAME_RESOLUTION: f64 = 1.01;
/// Version of the tile march, part of its cache key.
const TILE_ALGORITHM_VERSION: u32 = 1;

/// Where a tile lies: latitude/longitude limits [rad] of its outer pixel
/// edges (pixel-is-area), and its size in pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TileGrid {
    /// Southern edge [rad].
    pub lat_min: f64,
    /// Northern edge [rad].
    pub lat_max: f64,
    /// Western edge [rad].
    pub lon_min: f64,
    /// Eastern edge [rad].
    pub lon_max: f64,
    /// Columns.
    pub width: usize,
    /// Rows (row 0 at the northern edge).
    pub height: usize,
    /// Width [cells] of the band along the edges over which the tile fades
    /// out.
    pub blend: f64,
}

impl TileGrid {
    /// Latitude cell [rad].
    pub fn cell_lat(&self) -> f64 {
        (self.lat_max - self.lat_min) / self.height as f64
    }

    /// Longitude cell [rad].
    pub fn cell_lon(&self) -> f64 {
        (self.lon_max - self.lon_min) / self.width as f64
    }

    /// Continuous texel coordinates (integer = texel centre) of lat/lon.
    #[inline]
    pub fn texel(&self, lat: f64, lon: f64) -> (f64, f64) {
        let x = (lon - self.lon_min) / self.cell_lon() - 0.5;
        let y = (self.lat_max - lat) / self.cell_lat() - 0.5;
        (x, y)
    }

    /// Latitude/longitude [rad] of continuous texel coordinates.
    #[inline]
    pub fn lat_lon_of(&self, x: f64, y: f64) -> (f64, f64) {
        (
            self.lat_max - (y + 0.5) * self.cell_lat(),
            self.lon_min + (x + 0.5) * self.cell_lon(),
        )
    }

    /// Weight of the tile at lat/lon: 0 outside it, rising as a smoothstep
    /// of the distance from the nearest edge over `blend` cells, 1 deeper
    /// inside. Continuous with a continuous slope, so a blended surface
    /// has no step at the edge.
    #[inline]
    pub fn weight(&self, lat: f64, lon: f64) -> f64 {
        if !(lat > self.lat_min && lat < self.lat_max && lon > self.lon_min && lon < self.lon_max) {
            return 0.0;
        }
        if self.blend <= 0.0 {
            return 1.0;
        }
        let (x, y) = self.texel(lat, lon);
        let dx = (x + 0.5).min(self.width as f64 - 0.5 - x);
        let dy = (y + 0.5).min(self.height as f64 - 0.5 - y);
        let t = (dx.min(dy) / self.blend).clamp(0.0, 1.0);
        t * t * (3.0 - 2.0 * t)
    }

    /// [`Self::weight`] and its derivatives with respect to latitude and
    /// longitude [1/rad]: the smoothstep's slope 6t(1 − t) times that of
    /// the distance from the nearest edge (0 outside, beyond the band, and
    /// without one).
    #[inline]
    pub fn weight_and_gradient(&self, lat: f64, lon: f64) -> (f64, f64, f64) {
        let w = self.weight(lat, lon);
        if w <= 0.0 || self.blend <= 0.0 {
            return (w, 0.0, 0.0);
        }
        let (x, y) = self.texel(lat, lon);
        let (west, east) = (x + 0.5, self.width as f64 - 0.5 - x);
        let (north, south) = (y + 0.5, self.height as f64 - 0.5 - y);
        let t = west.min(east).min(north).min(south) / self.blend;
        if t >= 1.0 {
            return (w, 0.0, 0.0);
        }
        let slope = 6.0 * t * (1.0 - t) / self.blend;
        // d(texel x)/d lon = 1 / cell_lon; d(texel y)/d lat = −1 / cell_lat.
        let (d_lat, d_lon) = if west.min(east) <= north.min(south) {
            let sign = if west <= east { 1.0 } else { -1.0 };
            (0.0, sign / self.cell_lon())
        } else {
            let sign = if north <= south { -1.0 } else { 1.0 };
            (sign / self.cell_lat(), 0.0)
        };
        (w, slope * d_lat, slope * d_lon)
    }

    /// Whether this tile's box and `other`'s share a positive area.
    pub fn overlaps(&self, other: &TileGrid) -> bool {
        self.lat_min < other.lat_max
            && other.lat_min < self.lat_max
            && self.lon_min < other.lon_max
            && other.lon_min < self.lon_max
    }

    /// The box `[lat_min, lat_max, lon_min, lon_max]` [rad].
    pub fn bounds(&self) -> [f64; 4] {
        [self.lat_min, self.lat_max, self.lon_min, self.lon_max]
    }
}

/// Bilinear sample of a row-major `w` × `h` grid at continuous texel
/// coordinates, clamped at every edge (a tile does not wrap).
#[inline]
fn bilinear_clamped(data: &[f32], w: usize, h: usize, x: f64, y: f64) -> f64 {
    let x = x.clamp(0.0, (w - 1) as f64);
    let y = y.clamp(0.0, (h - 1) as f64);
    let (i0, j0) = ((x as usize).min(w - 2), (y as usize).min(h - 2));
    let (tx, ty) = (x - i0 as f64, y - j0 as f64);
    let at = |i: usize, j: usize| data[j * w + i] as f64;
    let top = at(i0, j0) + (at(i0 + 1, j0) - at(i0, j0)) * tx;
    let bottom = at(i0, j0 + 1) + (at(i0 + 1, j0 + 1) - at(i0, j0 + 1)) * tx;
    top + (bottom - top) * ty
}

/// One tile: its grid, its values, and the file it came from.
#[derive(Clone, Debug)]
pub struct Tile {
    /// Where it lies.
    pub grid: TileGrid,
    /// Its values (heights [m] after `scale`, or albedo after the stretch).
    pub map: EquirectMap,
    /// The file.
    pub path: PathBuf,
    /// Factor applied to the file's values (metres per value for a DEM
    /// tile; 1 for an albedo tile, which is stretched instead).
    pub scale: f64,
}

impl Tile {
    /// Bilinear value at lat/lon (clamped at the tile's edges).
    #[inline]
    pub fn sample(&self, lat: f64, lon: f64) -> f64 {
        let (x, y) = self.grid.texel(lat, lon);
        bilinear_clamped(&self.map.data, self.map.width, self.map.height, x, y)
    }
}

/// Blends per-layer values finest first: each covering layer takes its
/// weight of what is left, and `base` the rest. `layers` must be sorted
/// finest first.
#[inline]
fn compose<T>(
    layers: &[T],
    grid: impl Fn(&T) -> &TileGrid,
    value: impl Fn(&T) -> f64,
    lat: f64,
    lon: f64,
    base: &dyn Fn() -> f64,
) -> f64 {
    let (mut acc, mut rest) = (0.0, 1.0);
    for layer in layers {
        let w = grid(layer).weight(lat, lon);
        if w > 0.0 {
            acc += rest * w * value(layer);
            rest *= 1.0 - w;
            if rest <= 0.0 {
                return acc;
            }
        }
    }
    acc + rest * base()
}

/// A body's tiles of one kind, finest first.
#[derive(Clone, Debug, Default)]
pub struct TileSet {
    tiles: Vec<Tile>,
}

impl TileSet {
    /// The tiles, finest first (checked by [`check_layout`]).
    pub fn new(mut tiles: Vec<Tile>) -> TileSet {
        tiles.sort_by(|a, b| a.grid.cell_lat().total_cmp(&b.grid.cell_lat()));
        TileSet { tiles }
    }

    /// The tiles, finest first.
    pub fn tiles(&self) -> &[Tile] {
        &self.tiles
    }

    /// The tiles' value at lat/lon blended over `base` (the global map's
    /// value there, asked for only where no tile covers the point wholly).
    #[inline]
    pub fn value(&self, lat: f64, lon: f64, base: &dyn Fn() -> f64) -> f64 {
        compose(
            &self.tiles,
            |t| &t.grid,
            |t| t.sample(lat, lon),
            lat,
            lon,
            base,
        )
    }

    /// [`Self::value`] at a body-fixed direction (any length).
    #[inline]
    pub fn value_dir(&self, n: DVec3, base: &dyn Fn() -> f64) -> f64 {
        let (lat, lon) = super::maps::lat_lon(n);
        self.value(lat, lon, base)
    }

    /// Whether a tile covers the body-fixed direction `n` (weight > 0).
    #[inline]
    pub fn covers_dir(&self, n: DVec3) -> bool {
        let (lat, lon) = super::maps::lat_lon(n);
        self.tiles.iter().any(|t| t.grid.weight(lat, lon) > 0.0)
    }

    /// The renderer's albedo at body-fixed `n`: the tiles' values times
    /// `scale` (the band's factor on map values) blended over `base`, the
    /// albedo without tiles there.
    #[inline]
    pub fn albedo_dir(&self, n: DVec3, scale: f64, base: f64) -> f64 {
        let (lat, lon) = super::maps::lat_lon(n);
        compose(
            &self.tiles,
            |t| &t.grid,
            |t| t.sample(lat, lon) * scale,
            lat,
            lon,
            &|| base,
        )
    }
}

/// `[[body.dem_tiles]]`: a DEM tile.
#[derive(Deserialize, Clone, Debug)]
#[serde(deny_unknown_fields)]
pub struct DemTileFile {
    /// Image file (relative to the scene or body file).
    pub path: PathBuf,
    /// Limits [deg] of the outer pixel edges.
    pub lat_min: f64,
    /// Northern edge [deg].
    pub lat_max: f64,
    /// Western edge [deg].
    pub lon_min: f64,
    /// Eastern edge [deg].
    pub lon_max: f64,
    /// Metres per file value.
    pub scale: f64,
    /// Blend band [cells].
    #[serde(default = "default_blend")]
    pub blend: f64,
}

/// `[[body.albedo_tiles]]`: an albedo tile, its own value range stretched
/// linearly to [min, max] like `albedo_map`.
#[derive(Deserialize, Clone, Debug)]
#[serde(deny_unknown_fields)]
pub struct AlbedoTileFile {
    /// Image file.
    pub path: PathBuf,
    /// Southern edge [deg].
    pub lat_min: f64,
    /// Northern edge [deg].
    pub lat_max: f64,
    /// Western edge [deg].
    pub lon_min: f64,
    /// Eastern edge [deg].
    pub lon_max: f64,
    /// Albedo of the tile's darkest value.
    pub min: f64,
    /// Albedo of its brightest value.
    pub max: f64,
    /// Blend band [cells].
    #[serde(default = "default_blend")]
    pub blend: f64,
}

fn default_blend() -> f64 {
    DEFAULT_BLEND_CELLS
}

/// Checked limits [deg → rad]: within ±90° and ±180°, south < north and
/// west < east (a tile across ±180° is split in two). Errors name `key`.
pub fn check_limits(lat: [f64; 2], lon: [f64; 2], key: &str) -> Result<[f64; 4]> {
    let [s, n] = lat;
    let [w, e] = lon;
    let bad = |k: &str, msg: String| Err(Error::invalid(format!("{key}.{k}"), msg));
    for (k, v, lim) in [
        ("lat_min", s, 90.0),
        ("lat_max", n, 90.0),
        ("lon_min", w, 180.0),
        ("lon_max", e, 180.0),
    ] {
        if !(v.abs() <= lim) {
            return bad(k, format!("need a value within ±{lim}°, got {v}"));
        }
    }
    if !(s < n) {
        return bad("lat_max", format!("need lat_min < lat_max, got {s} … {n}"));
    }
    if !(w < e) {
        return bad(
            "lon_max",
            format!("need lon_min < lon_max (split a tile across ±180°), got {w} … {e}"),
        );
    }
    Ok([
        s.to_radians(),
        n.to_radians(),
        w.to_radians(),
        e.to_radians(),
    ])
}

fn check_blend(blend: f64, key: &str) -> Result<f64> {
    if !(blend.is_finite() && (0.0..=1e4).contains(&blend)) {
        return Err(Error::invalid(
            format!("{key}.blend"),
            format!("need 0 … 10000 cells, got {blend}"),
        ));
    }
    Ok(blend)
}

/// Loads a tile's image and places it on its limits; the blend band must
/// leave an interior (2 · blend < width and height).
fn load_tile(path: &Path, limits: [f64; 4], blend: f64, key: &str) -> Result<Tile> {
    if !path.exists() {
        return Err(Error::invalid(
            format!("{key}.path"),
            format!("tile file {} does not exist", path.display()),
        ));
    }
    let map = EquirectMap::load(path)
        .map_err(|e| Error::invalid(format!("{key}.path"), e.to_string()))?;
    if 2.0 * blend >= map.width.min(map.height) as f64 {
        return Err(Error::invalid(
            format!("{key}.blend"),
            format!(
                "{}: a band of {blend} cells leaves no interior in {}×{} cells",
                path.display(),
                map.width,
                map.height
            ),
        ));
    }
    let [lat_min, lat_max, lon_min, lon_max] = limits;
    let grid = TileGrid {
        lat_min,
        lat_max,
        lon_min,
        lon_max,
        width: map.width,
        height: map.height,
        blend,
    };
    Ok(Tile {
        grid,
        map,
        path: path.to_path_buf(),
        scale: 1.0,
    })
}

/// Refuses more than [`MAX_TILES`] tiles and overlapping tiles at the same
/// resolution (latitude cells within [`SAME_RESOLUTION`]): neither would
/// win. `key` is the array's key.
pub fn check_layout(tiles: &[Tile], key: &str) -> Result<()> {
    if tiles.len() > MAX_TILES {
        return Err(Error::invalid(
            key,
            format!("at most {MAX_TILES} tiles, got {}", tiles.len()),
        ));
    }
    for (i, a) in tiles.iter().enumerate() {
        for (j, b) in tiles.iter().enumerate().skip(i + 1) {
            let (ca, cb) = (a.grid.cell_lat(), b.grid.cell_lat());
            if a.grid.overlaps(&b.grid) && ca.max(cb) < SAME_RESOLUTION * ca.min(cb) {
                return Err(Error::invalid(
                    format!("{key}[{j}]"),
                    format!(
                        "{} overlaps {key}[{i}] ({}) at the same resolution ({:.4} vs {:.4} arcsec): neither would win",
                        b.path.display(),
                        a.path.display(),
                        cb.to_degrees() * 3600.0,
                        ca.to_degrees() * 3600.0
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// Loads and checks `[[body.dem_tiles]]`: heights [m] after `scale`, each
/// within ±`max_abs_height`, paths resolved against `base`.
pub fn load_dem_tiles(
    files: &[DemTileFile],
    base: &Path,
    max_abs_height: f64,
    key: &str,
) -> Result<TileSet> {
    let mut tiles = Vec::with_capacity(files.len().min(MAX_TILES));
    if files.len() > MAX_TILES {
        return Err(Error::invalid(
            key,
            format!("at most {MAX_TILES} tiles, got {}", files.len()),
        ));
    }
    for (i, f) in files.iter().enumerate() {
        let k = format!("{key}[{i}]");
        let limits = check_limits([f.lat_min, f.lat_max], [f.lon_min, f.lon_max], &k)?;
        let blend = check_blend(f.blend, &k)?;
        if !(f.scale.is_finite() && f.scale > 0.0) {
            return Err(Error::invalid(
                format!("{k}.scale"),
                format!("need a finite value > 0, got {}", f.scale),
            ));
        }
        let path = resolve(base, &f.path);
        let mut tile = load_tile(&path, limits, blend, &k)?;
        tile.map.scale(f.scale);
        tile.scale = f.scale;
        check_heights(&tile, max_abs_height, &k)?;
        tiles.push(tile);
    }
    check_layout(&tiles, key)?;
    Ok(TileSet::new(tiles))
}

/// Heights within ±`limit` [m] (and finite).
fn check_heights(tile: &Tile, limit: f64, key: &str) -> Result<()> {
    let m = &tile.map;
    if let Some(k) = m.data.iter().position(|v| !(v.abs() as f64 <= limit)) {
        return Err(Error::invalid(
            format!("{key}.path"),
            format!(
                "{}: height {} m at pixel ({}, {}) is not within ±{limit} m (check `{key}.scale` or `body.max_abs_height`)",
                tile.path.display(),
                m.data[k],
                k % m.width,
                k / m.width
            ),
        ));
    }
    Ok(())
}

/// Loads and checks `[[body.albedo_tiles]]`: each stretched to its
/// [min, max] (0 ≤ min ≤ max, finite).
pub fn load_albedo_tiles(files: &[AlbedoTileFile], base: &Path, key: &str) -> Result<TileSet> {
    if files.len() > MAX_TILES {
        return Err(Error::invalid(
            key,
            format!("at most {MAX_TILES} tiles, got {}", files.len()),
        ));
    }
    let mut tiles = Vec::with_capacity(files.len());
    for (i, f) in files.iter().enumerate() {
        let k = format!("{key}[{i}]");
        let limits = check_limits([f.lat_min, f.lat_max], [f.lon_min, f.lon_max], &k)?;
        let blend = check_blend(f.blend, &k)?;
        if !(f.min.is_finite() && f.max.is_finite() && 0.0 <= f.min && f.min <= f.max) {
            return Err(Error::invalid(
                &k,
                format!("need finite 0 <= min <= max, got {} … {}", f.min, f.max),
            ));
        }
        let path = resolve(base, &f.path);
        let mut tile = load_tile(&path, limits, blend, &k)?;
        tile.map.stretch(f.min, f.max);
        tiles.push(tile);
    }
    check_layout(&tiles, key)?;
    Ok(TileSet::new(tiles))
}

fn resolve(base: &Path, p: &Path) -> PathBuf {
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        base.join(p)
    }
}

/// The heights the tile marches read: the tile blended over the global DEM.
struct Surface<'a> {
    tile: &'a Tile,
    global: &'a EquirectMap,
}

impl Surface<'_> {
    #[inline]
    fn height(&self, lat: f64, lon: f64) -> f64 {
        let w = self.tile.grid.weight(lat, lon);
        let g = self.global.sample(lat, lon);
        if w <= 0.0 {
            g
        } else {
            w * self.tile.sample(lat, lon) + (1.0 - w) * g
        }
    }
}

/// A tile's horizon map: elevations [rad, ≥ 0] per tile cell and azimuth,
/// stored as a [`HorizonMap`] of the tile's size (its own lookup is the
/// tile's, not the global one's).
#[derive(Clone, Debug)]
pub struct TileHorizon {
    /// Where it lies.
    pub grid: TileGrid,
    /// The elevations.
    pub map: HorizonMap,
}

impl TileHorizon {
    /// Elevation [rad] at lat/lon toward `azimuth` [rad from east,
    /// counter-clockwise]: bilinear in space (clamped at the tile's
    /// edges), linear in azimuth.
    #[inline]
    pub fn elevation(&self, lat: f64, lon: f64, azimuth: f64) -> f64 {
        let (w, h, n) = (self.grid.width, self.grid.height, self.map.azimuths());
        let (x, y) = self.grid.texel(lat, lon);
        let x = x.clamp(0.0, (w - 1) as f64);
        let y = y.clamp(0.0, (h - 1) as f64);
        let (i0, j0) = ((x as usize).min(w - 2), (y as usize).min(h - 2));
        let (tx, ty) = (x - i0 as f64, y - j0 as f64);
        let a = azimuth.rem_euclid(std::f64::consts::TAU) / std::f64::consts::TAU * n as f64;
        let k0 = (a as usize).min(n - 1);
        let ta = a - k0 as f64;
        let k1 = if k0 + 1 == n { 0 } else { k0 + 1 };
        let at = |i: usize, j: usize| {
            let c0 = self.map.cell(i, j, k0);
            c0 + (self.map.cell(i, j, k1) - c0) * ta
        };
        let top = at(i0, j0) + (at(i0 + 1, j0) - at(i0, j0)) * tx;
        let bottom = at(i0, j0 + 1) + (at(i0 + 1, j0 + 1) - at(i0, j0 + 1)) * tx;
        top + (bottom - top) * ty
    }

    /// The horizon map of `tile` over `global` (heights [m] above a sphere
    /// of `radius` [m]) with `azimuths` directions. Each tile cell marches
    /// along the great circle of each azimuth in steps of half a tile cell
    /// while inside the tile and half a global cell outside it, reading
    /// the tile blended over the global DEM, and keeps the largest
    /// elevation angle; it stops where no height of either could rise
    /// above the best angle found, or past the sphere's reach.
    pub fn compute(tile: &Tile, global: &EquirectMap, radius: f64, azimuths: usize) -> Self {
        let g = &tile.grid;
        let (w, h) = (g.width, g.height);
        let (t_lo, t_hi) = tile.map.range();
        let (g_lo, g_hi) = global.range();
        let (lo, hi) = (t_lo.min(g_lo) as f64, t_hi.max(g_hi) as f64);
        let reach = ((radius + lo) / (radius + hi)).clamp(-1.0, 1.0).acos();
        let surface = Surface { tile, global };
        let step_out = 0.5 * PI / global.height as f64;
        let directions: Vec<(f64, f64)> = (0..azimuths)
            .map(|k| (std::f64::consts::TAU * k as f64 / azimuths as f64).sin_cos())
            .map(|(s, c)| (c, s))
            .collect();
        let mut data = vec![0.0f32; w * h * azimuths];
        data.par_chunks_mut(w * azimuths)
            .enumerate()
            .for_each(|(row, out)| {
                for (col, cell) in out.chunks_mut(azimuths).enumerate() {
                    let (lat, lon) = g.lat_lon_of(col as f64, row as f64);
                    let step_in = 0.5
                        * g.cell_lat()
                            .min(g.cell_lon() * lat.cos())
                            .max(0.25 * g.cell_lat());
                    let march = TileMarch {
                        surface: &surface,
                        radius,
                        r_max: radius + hi,
                        reach,
                        step_in,
                        step_out,
                    };
                    march.cell(lat, lon, &directions, cell);
                }
            });
        TileHorizon {
            grid: *g,
            map: HorizonMap::from_data(w, h, azimuths, data),
        }
    }

    /// The cached horizon map of `tile` if `cache_dir` holds a valid one,
    /// else computed and written there. The key hashes the tile's and the
    /// global DEM's files, the tile's limits and blend, and the parameters.
    pub fn load_or_compute(
        tile: &Tile,
        global_path: &Path,
        global: &EquirectMap,
        params: &horizon::HorizonParams,
        cache_dir: &Path,
    ) -> Result<(TileHorizon, horizon::CacheOutcome)> {
        let read = |p: &Path| std::fs::read(p).map_err(|e| Error::io(p, e));
        let mut hasher = Sha256::new();
        hasher.update(b"OPTSTILE");
        hasher.update(Sha256::digest(read(&tile.path)?));
        hasher.update(Sha256::digest(read(global_path)?));
        let g = &tile.grid;
        for v in [
            g.lat_min, g.lat_max, g.lon_min, g.lon_max, g.blend, tile.scale,
        ] {
            hasher.update(v.to_le_bytes());
        }
        for d in [
            g.width,
            g.height,
            global.width,
            global.height,
            params.azimuths,
        ] {
            hasher.update((d as u64).to_le_bytes());
        }
        hasher.update(params.radius.to_le_bytes());
        hasher.update(params.scale.to_le_bytes());
        hasher.update(TILE_ALGORITHM_VERSION.to_le_bytes());
        let key: [u8; 32] = hasher.finalize().into();
        let hex: String = key.iter().take(16).map(|b| format!("{b:02x}")).collect();
        let file = cache_dir.join(format!("horizon-tile-{hex}.bin"));
        let existed = file.exists();
        if existed {
            if let Some(map) = horizon::read_cache(&file, &key, g.width, g.height, params.azimuths)
            {
                return Ok((TileHorizon { grid: *g, map }, horizon::CacheOutcome::Loaded));
            }
        }
        let t = TileHorizon::compute(tile, global, params.radius, params.azimuths);
        if let Err(e) = horizon::write_cache(&file, &key, &t.map) {
            tracing::warn!("tile horizon map not cached: {e}");
        }
        let outcome = if existed {
            horizon::CacheOutcome::Rebuilt
        } else {
            horizon::CacheOutcome::Computed
        };
        Ok((t, outcome))
    }
}

/// The march of one tile cell.
struct TileMarch<'a> {
    surface: &'a Surface<'a>,
    radius: f64,
    r_max: f64,
    reach: f64,
    step_in: f64,
    step_out: f64,
}

impl TileMarch<'_> {
    fn cell(&self, lat: f64, lon: f64, directions: &[(f64, f64)], out: &mut [f32]) {
        let r0 = self.radius + self.surface.height(lat, lon);
        if r0 >= self.r_max {
            out.fill(0.0);
            return;
        }
        let (up, east, north) = horizon::local_frame(lat, lon);
        for (o, &(c, s)) in out.iter_mut().zip(directions) {
            *o = self.along(r0, up, east * c + north * s).atan() as f32;
        }
    }

    /// Largest tan(elevation) (≥ 0) along `dir` from height r0 at `up`.
    fn along(&self, r0: f64, up: DVec3, dir: DVec3) -> f64 {
        let grid = &self.surface.tile.grid;
        let mut best = 0.0f64;
        let mut gamma = 0.0;
        let mut inside = true;
        loop {
            gamma += if inside { self.step_in } else { self.step_out };
            if gamma > self.reach + self.step_out {
                return best;
            }
            let (sg, cg) = gamma.sin_cos();
            // No point higher than r_max can beat `best` from here on.
            if (self.r_max * cg - r0) / (self.r_max * sg) <= best {
                return best;
            }
            let p = up * cg + dir * sg;
            let lat = p.z.clamp(-1.0, 1.0).asin();
            let lon = p.y.atan2(p.x);
            inside = grid.weight(lat, lon) > 0.0;
            let r1 = self.radius + self.surface.height(lat, lon);
            best = best.max((r1 * cg - r0) / (r1 * sg));
        }
    }
}

/// The tiles' horizon maps, finest first: the overlay of the global map.
#[derive(Clone, Debug)]
pub struct TileHorizons {
    layers: Vec<TileHorizon>,
}

impl TileHorizons {
    /// The layers, sorted finest first.
    pub fn new(mut layers: Vec<TileHorizon>) -> Self {
        layers.sort_by(|a, b| a.grid.cell_lat().total_cmp(&b.grid.cell_lat()));
        TileHorizons { layers }
    }

    /// The layers, finest first.
    pub fn layers(&self) -> &[TileHorizon] {
        &self.layers
    }
}

impl HorizonOverlay for TileHorizons {
    #[inline]
    fn compose(&self, lat: f64, lon: f64, azimuth: f64, global: &dyn Fn() -> f64) -> f64 {
        compose(
            &self.layers,
            |t| &t.grid,
            |t| t.elevation(lat, lon, azimuth),
            lat,
            lon,
            global,
        )
    }

    fn regions(&self) -> Vec<([f64; 4], f64)> {
        self.layers
            .iter()
            .map(|t| (t.grid.bounds(), t.map.max_elevation()))
            .collect()
    }
}

/// The horizon maps of `tiles` over the global DEM, each checked for a
/// bounded size first (tile cells × azimuths, summed over tiles, at most
/// [`horizon::MAX_HORIZON_VALUES`]), loaded from or written to the cache.
/// Returns the overlay and, per tile, how its map was obtained.
pub fn tile_horizons(
    tiles: &TileSet,
    global_path: &Path,
    global: &EquirectMap,
    params: &horizon::HorizonParams,
    cache_dir: &Path,
    key: &str,
) -> Result<(Arc<TileHorizons>, Vec<horizon::CacheOutcome>)> {
    let mut total = 0u64;
    for (i, t) in tiles.tiles().iter().enumerate() {
        total += t.grid.width as u64 * t.grid.height as u64 * params.azimuths as u64;
        if total > horizon::MAX_HORIZON_VALUES {
            return Err(Error::invalid(
                key,
                format!(
                    "{}: the tiles' horizon maps need {total} values up to this tile (tile {i} by resolution); at most {}",
                    t.path.display(),
                    horizon::MAX_HORIZON_VALUES
                ),
            ));
        }
    }
    let mut layers = Vec::new();
    let mut outcomes = Vec::new();
    for t in tiles.tiles() {
        let (h, o) = TileHorizon::load_or_compute(t, global_path, global, params, cache_dir)?;
        layers.push(h);
        outcomes.push(o);
    }
    Ok((Arc::new(TileHorizons::new(layers)), outcomes))
}

/// Largest |height| [m] a body's DEM tiles accept unless the body says
/// otherwise (`max_abs_height`).
pub const DEFAULT_MAX_ABS_HEIGHT: f64 = horizon::MAX_ABS_HEIGHT;

/// Range of `[body] max_abs_height` [m].
pub const MAX_ABS_HEIGHT_RANGE: (f64, f64) = (1.0, 1.0e6);

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(blend: f64) -> TileGrid {
        TileGrid {
            lat_min: 0.1,
            lat_max: 0.2,
            lon_min: -0.3,
            lon_max: -0.1,
            width: 40,
            height: 20,
            blend,
        }
    }

    /// The weight: 0 outside and at the edge, 1 beyond the band, and the
    /// smoothstep of the distance in cells inside it.
    #[test]
    fn the_weight_ramps_over_the_band() {
        let g = grid(4.0);
        let cell = g.cell_lat();
        assert_eq!(g.weight(0.05, -0.2), 0.0);
        assert_eq!(g.weight(0.15, -0.2), 1.0);
        for d in [0.5, 1.0, 2.0, 3.5] {
            // d cells in from the southern edge, far from the others.
            let t: f64 = d / 4.0;
            let want = t * t * (3.0 - 2.0 * t);
            let got = g.weight(0.1 + d * cell, -0.2);
            assert!((got - want).abs() < 1e-9, "{d}: {got} vs {want}");
        }
        assert_eq!(grid(0.0).weight(0.1 + 1e-9, -0.2), 1.0);
    }

    /// Texel coordinates and back are inverse; the cell centres are where
    /// pixel-is-area puts them.
    #[test]
    fn texels_round_trip() {
        let g = grid(2.0);
        let (lat, lon) = g.lat_lon_of(0.0, 0.0);
        assert!((lat - (0.2 - 0.5 * 0.1 / 20.0)).abs() < 1e-15);
        assert!((lon - (-0.3 + 0.5 * 0.2 / 40.0)).abs() < 1e-15);
        let (x, y) = g.texel(0.137, -0.25);
        let (a, b) = g.lat_lon_of(x, y);
        assert!((a - 0.137).abs() < 1e-14 && (b + 0.25).abs() < 1e-14);
    }
}
