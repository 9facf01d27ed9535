//! Horizon maps: cast shadows of relief. For every cell of an
//! equirectangular DEM on a sphere, the elevation angle of the local
//! horizon in N azimuths, found by marching outward along great circles
//! over the bilinear DEM with the sphere's curvature (each row's great
//! circles traced once and shared by its cells, the sphere being symmetric
//! about its axis). Computed once (over rayon's workers) and cached on disk, keyed by the DEM file's SHA-256
//! and the parameters; a cache that fails any check is rebuilt. A lookup
//! is bilinear in space and linear in azimuth; [`disk_fraction_above`]
//! turns the horizon into the lit share of the solar disk (penumbra).
//!
//! Elevations are stored clamped at 0: the sphere's own terminator is the
//! renderer's (μ0 > 0), so only relief above the local horizontal plane
//! casts a shadow here.

use std::f64::consts::{FRAC_PI_2, PI, TAU};
use std::io::Write;
use std::path::{Path, PathBuf};

use glam::DVec3;
use rayon::prelude::*;
use sha2::{Digest, Sha256};

use super::maps::EquirectMap;
use crate::error::{Error, Result};

/// Azimuths of a horizon map unless the scene says otherwise.
pub const DEFAULT_AZIMUTHS: usize = 16;
/// Accepted azimuth counts.
pub const AZIMUTH_RANGE: (usize, usize) = (4, 64);
/// Largest |height| [m] accepted in a DEM (the Moon spans −9.1 … +10.8 km,
/// Mars −8.2 … +21.2 km).
pub const MAX_ABS_HEIGHT: f64 = 25_000.0;
/// Largest horizon map, in stored values (cells × azimuths): 1 GiB of f32.
pub const MAX_HORIZON_VALUES: u64 = 1 << 28;
/// Version of the marching algorithm, part of the cache key.
const ALGORITHM_VERSION: u32 = 2;
const MAGIC: &[u8; 8] = b"OPTSHZN1";

/// Horizon elevation angles [rad, ≥ 0] per DEM cell and azimuth.
/// Azimuth k points 2πk/N counter-clockwise from local east (k = N/4:
/// north).
#[derive(Clone)]
pub struct HorizonMap {
    width: usize,
    height: usize,
    azimuths: usize,
    /// One plane per azimuth, `[(k · height + row) · width + col]`, row 0
    /// at the north edge: neighbouring pixels of a frame read neighbouring
    /// values of the same two planes, so a lookup mostly hits cache lines
    /// the previous one loaded (cell-major, each lookup would load four
    /// new 64-byte lines of 16 azimuths).
    planes: Vec<f32>,
    /// Largest value of `data`.
    max: f64,
    /// Per cell: the sine of the largest elevation of the 2 × 2 cells from
    /// it east and south (those a bilinear lookup there reads), over all
    /// azimuths, rounded up.
    block_max: Vec<f32>,
    /// Finer horizon maps layered over this one (DEM tiles), consulted
    /// first by [`Self::elevation`].
    overlay: Option<std::sync::Arc<dyn HorizonOverlay>>,
}

/// Finer horizon maps over parts of a global one (`scene::tiles`): the
/// lookup asks the overlay first, which blends its own value over the
/// global one where it covers the point.
pub trait HorizonOverlay: Send + Sync {
    /// Horizon elevation [rad] at latitude/longitude [rad] toward
    /// `azimuth`, `global` giving the global map's value there (called
    /// only where the overlay does not cover the point wholly).
    fn compose(&self, lat: f64, lon: f64, azimuth: f64, global: &dyn Fn() -> f64) -> f64;
    /// Latitude/longitude boxes [rad] `[lat_min, lat_max, lon_min,
    /// lon_max]` the overlay covers, each with its largest elevation [rad].
    fn regions(&self) -> Vec<([f64; 4], f64)>;
}

impl std::fmt::Debug for HorizonMap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "HorizonMap({}×{}, {} azimuths)",
            self.width, self.height, self.azimuths
        )
    }
}

/// When a render applies the relief's cast shadows (`[body.shadows]
/// mode`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ShadowMode {
    /// Where the frame resolves them (see `render::relief`).
    #[default]
    Auto,
    /// In every frame.
    Always,
    /// Never (the map is still loaded).
    Never,
}

/// A body's cast shadows: its horizon map and what the per-frame decision
/// needs to know about the DEM.
#[derive(Clone, Debug)]
pub struct ReliefShadows {
    /// The horizon map.
    pub map: HorizonMap,
    /// When to apply it.
    pub mode: ShadowMode,
    /// DEM cell size along latitude [m] on the reference sphere.
    pub cell: f64,
    /// Height range of the DEM, max − min [m].
    pub relief: f64,
    /// The DEM's (and its tiles') steepest slope per baseline: how far
    /// relief can tilt a pixel's mean normal.
    pub slopes: super::relief_slopes::SlopeScales,
    /// How the map was obtained, and the cache file.
    pub cache: CacheOutcome,
    /// The cache file.
    pub cache_file: PathBuf,
    /// Wall time [s] of loading or computing the map.
    pub seconds: f64,
    /// The DEM file the map was made from.
    pub dem_path: PathBuf,
    /// The map's parameters (with the DEM's bytes, its cache key).
    pub params: HorizonParams,
}

/// How [`HorizonMap::load_or_compute`] got its map.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum CacheOutcome {
    /// A valid cache file was read.
    Loaded,
    /// No cache file: computed and written.
    Computed,
    /// A cache file was there but failed a check: recomputed and rewritten.
    Rebuilt,
}

impl HorizonMap {
    /// Width (longitude cells).
    pub fn width(&self) -> usize {
        self.width
    }
    /// Height (latitude cells).
    pub fn height(&self) -> usize {
        self.height
    }
    /// Azimuths per cell.
    pub fn azimuths(&self) -> usize {
        self.azimuths
    }

    /// Stored elevation [rad] at cell (col, row) and azimuth index k.
    pub fn cell(&self, col: usize, row: usize, k: usize) -> f64 {
        self.planes[(k * self.height + row) * self.width + col] as f64
    }

    /// Largest elevation stored [rad].
    pub fn max_elevation(&self) -> f64 {
        self.max
    }

    /// All stored values, one plane per azimuth:
    /// `[(k · height + row) · width + col]`.
    pub fn values(&self) -> &[f32] {
        &self.planes
    }

    /// This map with `overlay` layered over it: the lookup asks the
    /// overlay first, and the bounds ([`Self::max_elevation`],
    /// [`Self::sin_elevation_bound`]) rise to cover its values.
    pub fn with_overlay(mut self, overlay: std::sync::Arc<dyn HorizonOverlay>) -> HorizonMap {
        let (w, h) = (self.width, self.height);
        for ([lat0, lat1, lon0, lon1], top) in overlay.regions() {
            self.max = self.max.max(top);
            let bound = (top.sin() + 1e-6) as f32;
            // Every block whose lookup can land in the box, one cell of
            // margin on each side.
            let y = |lat: f64| (FRAC_PI_2 - lat) / PI * h as f64 - 0.5;
            let x = |lon: f64| (lon + PI) / TAU * w as f64 - 0.5;
            let (r0, r1) = (y(lat1).floor() - 1.0, y(lat0).ceil() + 1.0);
            let (c0, c1) = (x(lon0).floor() as i64 - 1, x(lon1).ceil() as i64 + 1);
            let rows = (r0.max(0.0) as usize)..=(r1.min((h - 1) as f64) as usize);
            for row in rows {
                for c in c0..=c1 {
                    let col = c.rem_euclid(w as i64) as usize;
                    let b = &mut self.block_max[row * w + col];
                    *b = b.max(bound);
                }
            }
        }
        self.overlay = Some(overlay);
        self
    }

    /// The map of cell-major `data`, `[(row · width + col) · azimuths + k]`
    /// (as computed and cached).
    pub(crate) fn from_data(
        width: usize,
        height: usize,
        azimuths: usize,
        data: Vec<f32>,
    ) -> HorizonMap {
        let max = data.iter().fold(0.0f32, |a, &b| a.max(b)) as f64;
        let cell_max: Vec<f32> = data
            .chunks(azimuths)
            .map(|c| c.iter().fold(0.0f32, |a, &b| a.max(b)))
            .collect();
        let mut block_max = vec![0.0f32; width * height];
        for j in 0..height {
            let j1 = (j + 1).min(height - 1);
            for i in 0..width {
                let i1 = if i + 1 == width { 0 } else { i + 1 };
                let top = cell_max[j * width + i]
                    .max(cell_max[j * width + i1])
                    .max(cell_max[j1 * width + i])
                    .max(cell_max[j1 * width + i1]);
                block_max[j * width + i] = ((top as f64).sin() + 1e-6) as f32;
            }
        }
        let mut planes = vec![0.0f32; data.len()];
        for (cell, values) in data.chunks_exact(azimuths).enumerate() {
            for (k, &v) in values.iter().enumerate() {
                planes[k * width * height + cell] = v;
            }
        }
        HorizonMap {
            width,
            height,
            azimuths,
            planes,
            max,
            block_max,
            overlay: None,
        }
    }

    /// An upper bound of sin [`Self::elevation`] at latitude/longitude
    /// [rad] in every azimuth: one read.
    #[inline]
    pub fn sin_elevation_bound(&self, lat: f64, lon: f64) -> f64 {
        let (x, y) = self.cell_coords(lat, lon);
        self.sin_elevation_bound_at(x, y)
    }

    /// Continuous (column, row) of latitude/longitude [rad]: cell centres
    /// at integers, row 0 at the north edge (unclamped, unwrapped).
    #[inline]
    pub fn cell_coords(&self, lat: f64, lon: f64) -> (f64, f64) {
        (
            (lon + PI) / TAU * self.width as f64 - 0.5,
            (FRAC_PI_2 - lat) / PI * self.height as f64 - 0.5,
        )
    }

    /// [`Self::sin_elevation_bound`] at continuous cell coordinates (x
    /// wraps, y is clamped).
    #[inline]
    pub fn sin_elevation_bound_at(&self, x: f64, y: f64) -> f64 {
        let (w, h) = (self.width, self.height);
        let y = y.clamp(0.0, (h - 1) as f64);
        let y0 = (y as usize).min(h - 2);
        let i0 = (x.floor() as i64).rem_euclid(w as i64) as usize;
        self.block_max[y0 * w + i0] as f64
    }

    /// Horizon map of `dem` (heights [m] above a sphere of `radius` [m])
    /// with `azimuths` directions. Each cell marches from its centre along
    /// the great circle of each azimuth in steps of half a latitude cell,
    /// reading the DEM bilinearly, and keeps the largest elevation angle
    /// seen from the cell's own height; the march stops where no height in
    /// the DEM could rise above the best angle found.
    pub fn compute(dem: &EquirectMap, radius: f64, azimuths: usize) -> HorizonMap {
        let (w, h) = (dem.width, dem.height);
        let (h_min, h_max) = dem.range();
        let step = 0.5 * PI / h as f64;
        // The farthest any cell needs to look: from the lowest point to
        // where the highest one sinks below its horizontal plane.
        let reach = ((radius + h_min as f64) / (radius + h_max as f64))
            .clamp(-1.0, 1.0)
            .acos();
        let steps = (reach / step).ceil() as usize + 1;
        let trig: Vec<(f64, f64)> = (1..=steps)
            .map(|k| {
                let (s, c) = (k as f64 * step).sin_cos();
                (c, s)
            })
            .collect();
        let directions: Vec<(f64, f64)> = (0..azimuths)
            .map(|k| (TAU * k as f64 / azimuths as f64).sin_cos())
            .map(|(s, c)| (c, s))
            .collect();
        let tops = LocalTops::new(dem, reach);
        let mut data = vec![0.0f32; w * h * azimuths];
        data.par_chunks_mut(w * azimuths)
            .enumerate()
            .for_each(|(row, out)| {
                let path = RowPath::new(dem, row, &directions, &trig);
                for (col, cell) in out.chunks_mut(azimuths).enumerate() {
                    let march = March {
                        dem,
                        radius,
                        r_max: radius + tops.at(col, row),
                        trig: &trig,
                    };
                    march.cell(col, row, &path, cell);
                }
            });
        HorizonMap::from_data(w, h, azimuths, data)
    }

    /// Horizon elevation [rad] at latitude/longitude [rad] toward azimuth
    /// `azimuth` [rad, counter-clockwise from east]: bilinear between the
    /// four nearest cell centres (wrapping in longitude, clamped in
    /// latitude), linear between the two nearest azimuths.
    /// Where an overlay (DEM tiles) covers the point, its value is blended
    /// over this one ([`HorizonOverlay::compose`]).
    #[inline]
    pub fn elevation(&self, lat: f64, lon: f64, azimuth: f64) -> f64 {
        let (x, y) = self.cell_coords(lat, lon);
        self.elevation_at(x, y, azimuth)
    }

    /// [`Self::elevation`] at continuous cell coordinates
    /// ([`Self::cell_coords`]); an overlay (DEM tiles) is asked first.
    #[inline]
    pub fn elevation_at(&self, x: f64, y: f64, azimuth: f64) -> f64 {
        match &self.overlay {
            None => self.own_elevation_at(x, y, azimuth),
            Some(o) => {
                let lon = (x + 0.5) / self.width as f64 * TAU - PI;
                let lat = FRAC_PI_2 - (y + 0.5) / self.height as f64 * PI;
                o.compose(lat, lon, azimuth, &|| self.own_elevation_at(x, y, azimuth))
            }
        }
    }

    /// [`Self::elevation`] of this map alone, without the overlay.
    #[inline]
    pub fn own_elevation(&self, lat: f64, lon: f64, azimuth: f64) -> f64 {
        let (x, y) = self.cell_coords(lat, lon);
        self.own_elevation_at(x, y, azimuth)
    }

    /// [`Self::own_elevation`] at continuous cell coordinates.
    #[inline]
    fn own_elevation_at(&self, x: f64, y: f64, azimuth: f64) -> f64 {
        let (w, h, n) = (self.width, self.height, self.azimuths);
        let y = y.clamp(0.0, (h - 1) as f64);
        let y0 = (y as usize).min(h - 2);
        let ty = y - y0 as f64;
        let x0 = x.floor();
        let tx = x - x0;
        let i0 = (x0 as i64).rem_euclid(w as i64) as usize;
        let i1 = if i0 + 1 == w { 0 } else { i0 + 1 };
        let a = azimuth.rem_euclid(TAU) / TAU * n as f64;
        let k0 = (a as usize).min(n - 1);
        let ta = a - k0 as f64;
        let k1 = if k0 + 1 == n { 0 } else { k0 + 1 };
        let (p0, p1) = (k0 * w * h, k1 * w * h);
        let at = |i: usize, j: usize| {
            let c = j * w + i;
            let (v0, v1) = (self.planes[p0 + c] as f64, self.planes[p1 + c] as f64);
            v0 + (v1 - v0) * ta
        };
        let top = at(i0, y0) + (at(i1, y0) - at(i0, y0)) * tx;
        let bottom = at(i0, y0 + 1) + (at(i1, y0 + 1) - at(i0, y0 + 1)) * tx;
        top + (bottom - top) * ty
    }

    /// Share of the Sun's power that clears the relief at a point, relative
    /// to what the smooth sphere lets through: the Sun's centre at
    /// elevation `sun_elevation` [rad] above the sphere's local horizontal,
    /// toward `azimuth`, with apparent radius `sun_radius` [rad]. Where
    /// the relief's horizon is at or below the horizontal this is exactly
    /// 1; else the disk's share above the horizon over its share above the
    /// horizontal.
    #[inline]
    pub fn relief_factor(
        &self,
        lat: f64,
        lon: f64,
        azimuth: f64,
        sun_elevation: f64,
        sun_radius: f64,
    ) -> f64 {
        let (x, y) = self.cell_coords(lat, lon);
        self.relief_factor_at(x, y, azimuth, sun_elevation, sun_radius)
    }

    /// [`Self::relief_factor`] at continuous cell coordinates
    /// ([`Self::cell_coords`]).
    #[inline]
    pub fn relief_factor_at(
        &self,
        x: f64,
        y: f64,
        azimuth: f64,
        sun_elevation: f64,
        sun_radius: f64,
    ) -> f64 {
        let horizon = self.elevation_at(x, y, azimuth);
        if horizon <= 0.0 {
            return 1.0;
        }
        let sphere = disk_fraction_above(sun_elevation, 0.0, sun_radius);
        if sphere <= 0.0 {
            return 0.0;
        }
        disk_fraction_above(sun_elevation, horizon, sun_radius) / sphere
    }

    /// The cached map for `dem` (read from `dem_path`, heights [m] after
    /// `scale`) if `cache_dir` holds a valid one, else computed and written
    /// there (to a temporary name, then renamed; a directory that cannot be
    /// written only loses the cache, with a warning). A cache file whose
    /// key, size, checksum or values do not check out is rebuilt.
    pub fn load_or_compute(
        dem_path: &Path,
        dem: &EquirectMap,
        params: &HorizonParams,
        cache_dir: &Path,
    ) -> Result<(HorizonMap, CacheOutcome, PathBuf)> {
        let bytes = std::fs::read(dem_path).map_err(|e| Error::io(dem_path, e))?;
        let key = cache_key(&Sha256::digest(&bytes), dem, params);
        let hex: String = key.iter().take(16).map(|b| format!("{b:02x}")).collect();
        let file = cache_dir.join(format!("horizon-{hex}.bin"));
        let existed = file.exists();
        if existed {
            if let Some(map) = read_cache(&file, &key, dem.width, dem.height, params.azimuths) {
                return Ok((map, CacheOutcome::Loaded, file));
            }
        }
        let map = HorizonMap::compute(dem, params.radius, params.azimuths);
        // A cache that cannot be written costs the next run the compute,
        // not this one its render.
        if let Err(e) = write_cache(&file, &key, &map) {
            tracing::warn!("horizon map not cached: {e}");
        }
        let outcome = if existed {
            CacheOutcome::Rebuilt
        } else {
            CacheOutcome::Computed
        };
        Ok((map, outcome, file))
    }
}

/// What besides the DEM's bytes decides a horizon map.
#[derive(Clone, Copy, Debug)]
pub struct HorizonParams {
    /// Sphere radius [m].
    pub radius: f64,
    /// Factor from DEM values to metres.
    pub scale: f64,
    /// Azimuth count.
    pub azimuths: usize,
}

/// Side [cells] of the tiles of [`LocalTops`].
const TILE: usize = 8;

/// For each tile of TILE × TILE cells, the highest DEM value within the
/// march's reach of any of its cells: the bound that ends a march early
/// (a cell on a plain far from any peak marches not at all).
struct LocalTops {
    tiles_x: usize,
    tops: Vec<f32>,
}

impl LocalTops {
    fn new(dem: &EquirectMap, reach: f64) -> LocalTops {
        let (w, h) = (dem.width, dem.height);
        let (tx, ty) = (w.div_ceil(TILE), h.div_ceil(TILE));
        let mut tile_max = vec![f32::NEG_INFINITY; tx * ty];
        for row in 0..h {
            for col in 0..w {
                let t = &mut tile_max[(row / TILE) * tx + col / TILE];
                *t = t.max(dem.data[row * w + col]);
            }
        }
        let (d_lat, d_lon) = (PI / h as f64, TAU / w as f64);
        // Tile rows within reach, one tile of margin.
        let ry = (reach / d_lat / TILE as f64).ceil() as usize + 1;
        let mut tops = vec![0.0f32; tx * ty];
        let mut column = vec![f32::NEG_INFINITY; tx];
        for band in 0..ty {
            let (r0, r1) = (band.saturating_sub(ry), (band + ry).min(ty - 1));
            column.fill(f32::NEG_INFINITY);
            for r in r0..=r1 {
                for (c, v) in column.iter_mut().zip(&tile_max[r * tx..(r + 1) * tx]) {
                    *c = c.max(*v);
                }
            }
            // Longitudes within reach of the band's most poleward cell:
            // |Δlon| ≤ asin(sin reach / cos lat), all of them past a pole.
            let lat_edge = |row: usize| (FRAC_PI_2 - row as f64 * d_lat).abs();
            let pole_lat = lat_edge(band * TILE).max(lat_edge(((band + 1) * TILE).min(h)));
            let ratio = reach.sin() / pole_lat.cos().max(0.0);
            let rx = if ratio < 1.0 && pole_lat + reach < FRAC_PI_2 {
                (ratio.asin() / d_lon / TILE as f64).ceil() as usize + 1
            } else {
                tx
            };
            for c in 0..tx {
                let top = if 2 * rx + 1 >= tx {
                    column.iter().fold(f32::NEG_INFINITY, |a, &b| a.max(b))
                } else {
                    (0..=2 * rx)
                        .map(|k| column[(c + tx + k - rx) % tx])
                        .fold(f32::NEG_INFINITY, f32::max)
                };
                tops[band * tx + c] = top;
            }
        }
        LocalTops { tiles_x: tx, tops }
    }

    /// The bound for cell (col, row).
    #[inline]
    fn at(&self, col: usize, row: usize) -> f64 {
        self.tops[(row / TILE) * self.tiles_x + col / TILE] as f64
    }
}

/// The march of one DEM cell.
struct March<'a> {
    dem: &'a EquirectMap,
    radius: f64,
    r_max: f64,
    /// (cos γ, sin γ) of the march's angular steps.
    trig: &'a [(f64, f64)],
}

impl March<'_> {
    fn cell(&self, col: usize, row: usize, path: &RowPath, out: &mut [f32]) {
        let dem = self.dem;
        let r0 = self.radius + dem.data[row * dem.width + col] as f64;
        if r0 >= self.r_max {
            out.fill(0.0);
            return;
        }
        let n = self.trig.len();
        for (k, o) in out.iter_mut().enumerate() {
            *o = self
                .along(r0, col as f64, &path.texels[k * n..(k + 1) * n])
                .atan() as f32;
        }
    }

    /// Largest tan(elevation) (≥ 0) from height r0 at column `col` along
    /// the steps `texels` of one azimuth ([`RowPath`]).
    #[inline]
    fn along(&self, r0: f64, col: f64, texels: &[(f64, f64)]) -> f64 {
        let mut best = 0.0f64;
        for (&(cg, sg), &(dx, y)) in self.trig.iter().zip(texels) {
            // No point higher than r_max can beat `best` from here on
            // (the bound decreases with γ).
            let bound = (self.r_max * cg - r0) / (self.r_max * sg);
            if bound <= best {
                break;
            }
            let r1 = self.radius + self.dem.sample_texel(col + dx, y);
            let t = (r1 * cg - r0) / (r1 * sg);
            best = best.max(t);
        }
        best
    }
}

/// Where the marches of one DEM row read the DEM: per azimuth and step,
/// the texel row and the column offset from the marching cell. The sphere
/// is symmetric about its axis, so every cell of a row marches the same
/// path shifted in longitude: its great circles are traced once per row
/// (an `asin` and an `atan2` per step), not once per cell.
struct RowPath {
    /// `[k · steps + s]`: (Δcolumn, row) in continuous texels.
    texels: Vec<(f64, f64)>,
}

impl RowPath {
    fn new(dem: &EquirectMap, row: usize, directions: &[(f64, f64)], trig: &[(f64, f64)]) -> Self {
        let (w, h) = (dem.width as f64, dem.height as f64);
        // The row's cell at longitude 0; cell col sits col columns east.
        let (lat, _) = dem.lat_lon_of(0.0, row as f64);
        let (up, east, north) = local_frame(lat, 0.0);
        let mut texels = Vec::with_capacity(directions.len() * trig.len());
        for &(c, s) in directions {
            let dir = east * c + north * s;
            for &(cg, sg) in trig {
                let p = up * cg + dir * sg;
                let lat = p.z.clamp(-1.0, 1.0).asin();
                let lon = p.y.atan2(p.x);
                texels.push((lon / TAU * w, (FRAC_PI_2 - lat) / PI * h - 0.5));
            }
        }
        RowPath { texels }
    }
}

/// Radial unit vector, local east and north at latitude/longitude [rad]
/// (body-fixed: +z north, +x through lat 0, lon 0).
pub fn local_frame(lat: f64, lon: f64) -> (DVec3, DVec3, DVec3) {
    let (sl, cl) = lat.sin_cos();
    let (so, co) = lon.sin_cos();
    (
        DVec3::new(cl * co, cl * so, sl),
        DVec3::new(-so, co, 0.0),
        DVec3::new(-sl * co, -sl * so, cl),
    )
}

/// Share of a uniform disk of angular radius `radius` [rad] whose centre
/// is at elevation `centre` [rad] that lies above a horizontal horizon
/// line at elevation `horizon`: with u = (centre − horizon)/radius in
/// (−1, 1), 1 − (acos u − u √(1 − u²))/π (the circular segment below
/// the line removed); 0 and 1 beyond. Flat-sky approximation: the Sun's
/// radius (4.7 mrad at 1 au) is small.
#[inline]
pub fn disk_fraction_above(centre: f64, horizon: f64, radius: f64) -> f64 {
    if radius <= 0.0 {
        return if centre > horizon { 1.0 } else { 0.0 };
    }
    let u = (centre - horizon) / radius;
    if u >= 1.0 {
        1.0
    } else if u <= -1.0 {
        0.0
    } else {
        1.0 - (u.acos() - u * (1.0 - u * u).sqrt()) / PI
    }
}

/// Checks a DEM (heights [m] after scale) for a horizon map: heights
/// within ±[`MAX_ABS_HEIGHT`] (and finite) and a map of bounded size.
/// Errors name `key` and the file.
pub fn check_dem(dem: &EquirectMap, azimuths: usize, path: &Path, key: &str) -> Result<()> {
    let (lo, hi) = AZIMUTH_RANGE;
    if !(lo..=hi).contains(&azimuths) {
        return Err(Error::invalid(
            format!("{key}.azimuths"),
            format!("need {lo} … {hi}, got {azimuths}"),
        ));
    }
    let values = dem.width as u64 * dem.height as u64 * azimuths as u64;
    if values > MAX_HORIZON_VALUES {
        return Err(Error::invalid(
            format!("{key}.dem"),
            format!(
                "{}: {}×{} cells × {azimuths} azimuths = {values} horizon values; at most {MAX_HORIZON_VALUES}",
                path.display(),
                dem.width,
                dem.height
            ),
        ));
    }
    if let Some(k) = dem
        .data
        .iter()
        .position(|v| !(v.abs() as f64 <= MAX_ABS_HEIGHT))
    {
        return Err(Error::invalid(
            format!("{key}.dem"),
            format!(
                "{}: height {} m at pixel ({}, {}) is not within ±{MAX_ABS_HEIGHT} m (check `{key}.scale`)",
                path.display(),
                dem.data[k],
                k % dem.width,
                k / dem.width
            ),
        ));
    }
    Ok(())
}

/// The directory horizon maps are cached in when the scene names none:
/// `$XDG_CACHE_HOME/optistim`, `$HOME/.cache/optistim`, or the system's
/// temporary directory.
pub fn default_cache_dir() -> PathBuf {
    if let Some(d) = std::env::var_os("XDG_CACHE_HOME").filter(|d| !d.is_empty()) {
        return PathBuf::from(d).join("optistim");
    }
    if let Some(h) = std::env::var_os("HOME").filter(|d| !d.is_empty()) {
        return PathBuf::from(h).join(".cache").join("optistim");
    }
    std::env::temp_dir().join("optistim-cache")
}

fn cache_key(dem_hash: &[u8], dem: &EquirectMap, p: &HorizonParams) -> [u8; 32] {
    let mut h = Sha256::new();
    h.update(MAGIC);
    h.update(dem_hash);
    h.update((dem.width as u64).to_le_bytes());
    h.update((dem.height as u64).to_le_bytes());
    h.update((p.azimuths as u64).to_le_bytes());
    h.update(p.radius.to_le_bytes());
    h.update(p.scale.to_le_bytes());
    h.update(ALGORITHM_VERSION.to_le_bytes());
    h.finalize().into()
}

/// The map in `file` if its magic, key, size, checksum and every value
/// check out; None otherwise (the caller rebuilds).
pub(crate) fn read_cache(
    file: &Path,
    key: &[u8; 32],
    width: usize,
    height: usize,
    azimuths: usize,
) -> Option<HorizonMap> {
    let n = width * height * azimuths;
    let header = MAGIC.len() + 32 + 12;
    let meta = std::fs::metadata(file).ok()?;
    if meta.len() != (header + 4 * n + 32) as u64 {
        return None;
    }
    let bytes = std::fs::read(file).ok()?;
    let (head, rest) = bytes.split_at(header);
    let (payload, checksum) = rest.split_at(4 * n);
    let dims = |i: usize| u32::from_le_bytes(head[40 + 4 * i..44 + 4 * i].try_into().unwrap());
    let ok = &head[..8] == MAGIC
        && &head[8..40] == key
        && dims(0) as usize == width
        && dims(1) as usize == height
        && dims(2) as usize == azimuths
        && Sha256::digest(payload).as_slice() == checksum;
    if !ok {
        return None;
    }
    let data: Vec<f32> = payload
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect();
    if !data.iter().all(|v| (0.0..=FRAC_PI_2 as f32).contains(v)) {
        return None;
    }
    Some(HorizonMap::from_data(width, height, azimuths, data))
}

/// Writes `map` to `file` via a temporary name in the same directory and a
/// rename, so a reader never sees a partial file.
pub(crate) fn write_cache(file: &Path, key: &[u8; 32], map: &HorizonMap) -> Result<()> {
    let dir = file.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let cells = map.width * map.height;
    let mut payload = Vec::with_capacity(4 * map.planes.len());
    for cell in 0..cells {
        for k in 0..map.azimuths {
            payload.extend_from_slice(&map.planes[k * cells + cell].to_le_bytes());
        }
    }
    let mut out = Vec::with_capacity(payload.len() + 84);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(key);
    for d in [map.width, map.height, map.azimuths] {
        out.extend_from_slice(&(d as u32).to_le_bytes());
    }
    out.extend_from_slice(&payload);
    out.extend_from_slice(&Sha256::digest(&payload));
    let tmp = file.with_extension(format!("tmp{}", std::process::id()));
    let write = || -> std::io::Result<()> {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(&out)?;
        f.sync_all()?;
        std::fs::rename(&tmp, file)
    };
    write().map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        Error::io(file, e)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The disk share against a direct count over a fine grid of the disk.
    #[test]
    fn disk_fraction_matches_a_grid_count() {
        let r = 0.01;
        let n = 800;
        for u in [-1.2, -0.9, -0.5, -0.1, 0.0, 0.3, 0.77, 0.99, 1.5] {
            let centre = u * r;
            let (mut inside, mut above) = (0usize, 0usize);
            for a in 0..n {
                for b in 0..n {
                    let x = (a as f64 + 0.5) / n as f64 * 2.0 - 1.0;
                    let y = (b as f64 + 0.5) / n as f64 * 2.0 - 1.0;
                    if x * x + y * y <= 1.0 {
                        inside += 1;
                        above += usize::from(centre + y * r > 0.0);
                    }
                }
            }
            let want = above as f64 / inside as f64;
            let got = disk_fraction_above(centre, 0.0, r);
            assert!((got - want).abs() < 2e-3, "u {u}: {got} vs {want}");
        }
    }

    /// On a flat DEM (constant height) every horizon is at or below the
    /// horizontal: the stored map is exactly zero, the factor exactly 1.
    #[test]
    fn a_flat_dem_has_no_horizon() {
        let dem = EquirectMap::new(64, 32, vec![120.0; 64 * 32]);
        let map = HorizonMap::compute(&dem, 1e5, 8);
        assert_eq!(map.max_elevation(), 0.0);
        assert_eq!(map.relief_factor(0.3, 1.0, 2.0, 0.001, 0.0047), 1.0);
    }

    /// The local bound (tiles) ends marches early but changes no value:
    /// the same DEM marched with the global maximum as the bound agrees,
    /// also across the poles and the date line.
    #[test]
    fn local_bounds_change_no_value() {
        let (w, h) = (96, 48);
        let mut data = vec![0.0f32; w * h];
        for (k, v) in data.iter_mut().enumerate() {
            let (i, j) = ((k % w) as f64, (k / w) as f64);
            *v = (400.0 * (0.7 * i).sin() * (0.45 * j).cos() + 250.0 * (0.13 * i * j).sin()) as f32;
        }
        let dem = EquirectMap::new(w, h, data);
        let radius = 2e4;
        let fast = HorizonMap::compute(&dem, radius, 8);
        let (lo, hi) = dem.range();
        let reach = ((radius + lo as f64) / (radius + hi as f64)).acos();
        let step = 0.5 * PI / h as f64;
        let trig: Vec<(f64, f64)> = (1..=(reach / step).ceil() as usize + 1)
            .map(|k| ((k as f64 * step).cos(), (k as f64 * step).sin()))
            .collect();
        let dirs: Vec<(f64, f64)> = (0..8)
            .map(|k| ((TAU * k as f64 / 8.0).cos(), (TAU * k as f64 / 8.0).sin()))
            .collect();
        let march = March {
            dem: &dem,
            radius,
            r_max: radius + hi as f64,
            trig: &trig,
        };
        let mut cell = [0.0f32; 8];
        for row in 0..h {
            let path = RowPath::new(&dem, row, &dirs, &trig);
            for col in 0..w {
                march.cell(col, row, &path, &mut cell);
                for (k, v) in cell.iter().enumerate() {
                    assert_eq!(*v as f64, fast.cell(col, row, k), "({col}, {row}, {k})");
                }
            }
        }
        assert!(fast.max_elevation() > 0.05);
        // The lookup's bound holds everywhere, and is reached somewhere.
        let mut tight = false;
        for k in 0..20_000 {
            let t = k as f64;
            let (lat, lon, az) = ((t * 0.618).sin() * 1.57, (t * 0.377).sin() * 3.3, t * 0.7);
            let e = fast.elevation(lat, lon, az).sin();
            let b = fast.sin_elevation_bound(lat, lon);
            assert!(e <= b, "({lat}, {lon}, {az}): sin {e} > bound {b}");
            tight |= b > 1e-5 && e > 0.9 * b;
        }
        assert!(tight);
    }

    /// A single tall column: a cell next to it sees it at the elevation
    /// the exact geometry gives, in the azimuth pointing at it.
    #[test]
    fn a_lone_peak_stands_at_its_exact_elevation() {
        let (w, h) = (256, 128);
        let mut data = vec![0.0f32; w * h];
        // Peak at (col 130, row 64); observer at (col 126, row 64): 4 cells
        // east along the equator... row 64 is just south of it.
        data[64 * w + 130] = 500.0;
        let dem = EquirectMap::new(w, h, data);
        // 4 cells = 982 m at R = 10 km: the sphere drops 48 m there.
        let radius = 1e4;
        let map = HorizonMap::compute(&dem, radius, 16);
        let (lat0, lon0) = dem.lat_lon_of(126.0, 64.0);
        let (lat1, lon1) = dem.lat_lon_of(130.0, 64.0);
        assert_eq!(lat0, lat1);
        let (up0, _, _) = local_frame(lat0, lon0);
        let (up1, _, _) = local_frame(lat1, lon1);
        let v = up1 * (radius + 500.0) - up0 * radius;
        let want = (v.dot(up0) / v.length()).asin();
        // Azimuth 0 is east; the great circle bends from the row by
        // 0.0024 cells on the way, so the march reads the bilinear peak a
        // little lower: within 1 % of the elevation.
        let got = map.cell(126, 64, 0);
        assert!(
            (got - want).abs() < 0.01 * want,
            "{got} vs {want} (0 west: {})",
            map.cell(126, 64, 8)
        );
        assert_eq!(map.cell(126, 64, 8), 0.0, "nothing to the west");
    }
}
