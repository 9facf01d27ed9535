//! DEM tiles feed the cast shadows: the horizon map of a tile holding one
//! paraboloid crater puts the shadow edge where the exact rim geometry
//! (written here) does, within a fraction of a tile cell; outside the tile
//! the global map's value is returned unchanged; and a tile that is only a
//! resampling of the global DEM changes the horizon by little.

mod common;

use std::f64::consts::{FRAC_PI_2, PI, TAU};
use std::sync::Arc;

use glam::DVec3;
use optistim::render::relief::FrameShadows;
use optistim::scene::horizon::HorizonMap;
use optistim::scene::tiles::{Tile, TileGrid, TileHorizon, TileHorizons};
use optistim::scene::EquirectMap;

/// The Moon's radius [m].
const R: f64 = 1737.4e3;

fn unit(lat: f64, lon: f64) -> DVec3 {
    DVec3::new(lat.cos() * lon.cos(), lat.cos() * lon.sin(), lat.sin())
}

fn lat_lon(p: DVec3) -> (f64, f64) {
    let p = p.normalize();
    (p.z.clamp(-1.0, 1.0).asin(), p.y.atan2(p.x))
}

fn east_north(p: DVec3) -> (DVec3, DVec3) {
    let east = DVec3::new(-p.y, p.x, 0.0).normalize();
    (east, p.cross(east))
}

/// A global map of `w` × `h` cells from a height function of direction,
/// sampled at the cell centres (pixel-is-area, longitude −180° at the
/// left edge, north up), written out here.
fn global_dem(w: usize, h: usize, f: impl Fn(DVec3) -> f64) -> EquirectMap {
    let mut data = vec![0.0f32; w * h];
    for row in 0..h {
        for col in 0..w {
            let lat = FRAC_PI_2 - (row as f64 + 0.5) / h as f64 * PI;
            let lon = (col as f64 + 0.5) / w as f64 * TAU - PI;
            data[row * w + col] = f(unit(lat, lon)) as f32;
        }
    }
    EquirectMap::new(w, h, data)
}

/// A tile on limits [deg] of `n` × `n` cells from a height function of
/// (lat, lon) at its cell centres.
fn tile(limits: [f64; 4], n: usize, blend: f64, f: impl Fn(f64, f64) -> f64) -> Tile {
    let [s, nn, w, e] = limits.map(f64::to_radians);
    let (dlat, dlon) = ((nn - s) / n as f64, (e - w) / n as f64);
    let mut data = vec![0.0f32; n * n];
    for row in 0..n {
        for col in 0..n {
            let lat = nn - (row as f64 + 0.5) * dlat;
            let lon = w + (col as f64 + 0.5) * dlon;
            data[row * n + col] = f(lat, lon) as f32;
        }
    }
    Tile {
        grid: TileGrid {
            lat_min: s,
            lat_max: nn,
            lon_min: w,
            lon_max: e,
            width: n,
            height: n,
            blend,
        },
        map: EquirectMap::new(n, n, data),
        path: "synthetic".into(),
        scale: 1.0,
    }
}

// The crater case: a 6 km tile at the equator, 128 cells of 47 m, one
// paraboloid bowl (radius A, depth D) at its centre; a Gaussian hill on the
// global DEM 90 km west of it.
const TILE_DEG: [f64; 4] = [0.0, 0.2, 0.0, 0.2];
const N: usize = 128;
const A: f64 = 1500.0;
const D: f64 = 300.0;

/// The crater's centre: the tile's centre moved east by `phase` tile
/// cells (where the rim falls between the DEM's samples depends on it).
fn crater_centre(phase: f64) -> DVec3 {
    unit(
        0.1f64.to_radians(),
        (0.1 + phase * 0.2 / N as f64).to_radians(),
    )
}

fn hill(p: DVec3) -> f64 {
    let c = unit(0.1f64.to_radians(), -2.9f64.to_radians());
    let t = R * p.dot(c).clamp(-1.0, 1.0).acos();
    1500.0 * (-0.5 * (t / 15e3).powi(2)).exp()
}

fn bowl(c: DVec3, p: DVec3) -> f64 {
    let s = R * p.dot(c).clamp(-1.0, 1.0).acos();
    if s < A {
        -D * (1.0 - s * s / (A * A))
    } else {
        0.0
    }
}

fn tile_cell() -> f64 {
    R * (0.2f64.to_radians() / N as f64)
}

/// Exact elevation of the crater's rim from the bowl point p (on the
/// exact surface) toward azimuth `az`: where the great circle leaves the
/// bowl (bisection), from exact vectors.
fn rim_horizon(c: DVec3, p: DVec3, az: f64) -> f64 {
    let (east, north) = east_north(p);
    let dir = east * az.cos() + north * az.sin();
    let rim = common::crater_exit(p, dir, c, A, R);
    let v = rim - p * (R + bowl(c, p));
    (v.dot(p) / v.length()).asin()
}

/// The bowl point x [m] east of the centre along the great circle east.
fn on_axis(c: DVec3, x: f64) -> DVec3 {
    let (east, _) = east_north(c);
    c * (x / R).cos() + east * (x / R).sin()
}

/// The westmost x in (−a, a) where `f` turns positive (shadow), scanned
/// in steps of 1/20 cell from the west rim, then bisected.
fn crossing(f: impl Fn(f64) -> f64) -> f64 {
    common::first_crossing(f, A, tile_cell() / 20.0)
}

/// Local elevation and azimuth of the (distant) Sun direction s at p.
fn local(p: DVec3, s: DVec3) -> (f64, f64) {
    let (east, north) = east_north(p);
    (s.dot(p).asin(), s.dot(north).atan2(s.dot(east)))
}

/// Horizon [rad] from the point p on the tile's own (bilinear) surface
/// toward azimuth `az`: a march in steps of 1/20 tile cell out to two
/// crater radii (beyond, the plain and the sphere's fall hide nothing
/// higher than the rim), written here.
fn tile_surface_horizon(t: &Tile, p: DVec3, az: f64) -> f64 {
    let (east, north) = east_north(p);
    let dir = east * az.cos() + north * az.sin();
    let height = |q: DVec3| {
        let (lat, lon) = lat_lon(q);
        t.sample(lat, lon)
    };
    let r0 = R + height(p);
    let step = tile_cell() / R / 20.0;
    let mut best = 0.0f64;
    let mut g = step;
    while g < 2.0 * A / R {
        let q = p * g.cos() + dir * g.sin();
        let r1 = R + height(q);
        best = best.max((r1 * g.cos() - r0) / (r1 * g.sin()));
        g += step;
    }
    best.atan()
}

/// The crater at three sub-cell positions (its rim falls on the tile's
/// samples or between them), the Sun due east of its centre at 5°, 10°
/// and 15°: the shadow edge along the east–west axis lies within 0.05
/// tile cells of the exact horizon of the tile's bilinear surface (a fine
/// march written here), and from the exact rim geometry of the analytic
/// crater within the bound of the bilinear tile's cut of the rim's crease.
#[test]
fn a_tile_crater_casts_the_exact_shadow_and_the_global_map_rules_outside() {
    let global = global_dem(720, 360, hill);
    let base = HorizonMap::compute(&global, R, 16);
    let cell = tile_cell();
    let mut worst = 0.0f64;
    for phase in [0.0, 0.25, 0.5] {
        let c = crater_centre(phase);
        let t = tile(TILE_DEG, N, 4.0, |lat, lon| {
            bowl(c, unit(lat, lon)) + global.sample(lat, lon)
        });
        let layer = TileHorizon::compute(&t, &global, R, 16);
        let map = base
            .clone()
            .with_overlay(Arc::new(TileHorizons::new(vec![layer])));
        let (east, _) = east_north(c);
        for e_deg in [5.0f64, 10.0, 15.0] {
            let e = e_deg.to_radians();
            let sun = (c * e.sin() + east * e.cos()).normalize();
            let exact = crossing(|x| {
                let p = on_axis(c, x);
                let (el, az) = local(p, sun);
                rim_horizon(c, p, az) - el
            });
            let got = crossing(|x| {
                let p = on_axis(c, x);
                let (el, az) = local(p, sun);
                let (lat, lon) = lat_lon(p);
                map.elevation(lat, lon, az) - el
            });
            let on_tile = crossing(|x| {
                let p = on_axis(c, x);
                let (el, az) = local(p, sun);
                tile_surface_horizon(&t, p, az) - el
            });
            // The flat closed form, for the record: x = a² tan e / D − a.
            let flat = A * A * e.tan() / D - A;
            let err = (got - exact) / cell;
            println!(
                "phase {phase}, e {e_deg}°: shadow edge {got:.2} m, exact {exact:.2} m (flat {flat:.2} m), on the tile's surface {on_tile:.2} m; error {err:.4} cells, map vs surface {:.4} cells",
                (got - on_tile) / cell
            );
            // The horizon map against the exact horizon of the surface it
            // was given (the bilinear tile): a small fraction of a cell.
            let map_err = (got - on_tile) / cell;
            worst = worst.max(map_err.abs());
            assert!(
                map_err.abs() < 0.05,
                "phase {phase}, e {e_deg}°: {map_err} cells"
            );
            // Against the analytic crater: the bilinear tile lowers the
            // rim's crease (slope 2D/a to 0) by at most √2 (2D/a) c / 4
            // (a crease across the cell's diagonal), which moves the edge
            // by that over d/dx[(a − x) tan e − (0 − z(x))] = tan e − z'(x)
            // (flat geometry, z' = 2Dx/a²).
            let sag = 2f64.sqrt() * (2.0 * D / A) * cell / 4.0;
            let shift = sag / (e.tan() - 2.0 * D * exact / (A * A));
            assert!(
                (got - exact).abs() < shift + 0.05 * cell,
                "phase {phase}, e {e_deg}°: {err} cells, DEM bound {} cells",
                shift / cell
            );
            // The global map alone (15 km cells) sees no crater at all.
            let (lat, lon) = lat_lon(on_axis(c, 0.5 * (exact + A)));
            assert_eq!(base.elevation(lat, lon, 0.0), 0.0);
            // The renderer's per-sample factor (a point Sun) reads the
            // tile: dark midway from the edge to the east rim, lit midway
            // to the west rim.
            let factor = FrameShadows::new(&map, 0.0);
            let dark = on_axis(c, 0.5 * (exact + A));
            let lit = on_axis(c, 0.5 * (exact - A));
            assert_eq!(factor.factor(dark, sun), 0.0, "e {e_deg}°");
            assert_eq!(factor.factor(lit, sun), 1.0, "e {e_deg}°");
        }
        // Outside the tile the global map's value, bit for bit, where the
        // hill stands above the horizon in the west; the lookup's bound
        // holds inside.
        let (lat, lon) = (0.1f64.to_radians(), -1.2f64.to_radians());
        let west = base.elevation(lat, lon, PI);
        assert!(west > 0.01, "{west}");
        assert_eq!(map.elevation(lat, lon, PI), west);
        let mut checked = 0;
        for i in 0..40 {
            for j in 0..40 {
                let lat = (0.2 * (i as f64 + 0.5) / 40.0).to_radians();
                let lon = (0.2 * (j as f64 + 0.5) / 40.0).to_radians();
                for k in 0..8 {
                    let v = map.elevation(lat, lon, k as f64 * 0.8).sin();
                    assert!(v <= map.sin_elevation_bound(lat, lon), "({i}, {j}, {k})");
                    checked += usize::from(v > 0.0);
                }
            }
        }
        assert!(checked > 100);
    }
    println!("worst shadow-edge error of the map on the tile's surface {worst:.4} tile cells");
}

/// Reference horizon [rad, ≥ 0] from the global cell (col, row) toward
/// azimuth index k of 16: a march over the global DEM's bilinear surface
/// in steps of 1/20 cell out to the sphere's reach, written here.
fn fine_march(global: &EquirectMap, col: usize, row: usize, k: usize) -> f64 {
    let (w, h) = (global.width as f64, global.height as f64);
    let lat = FRAC_PI_2 - (row as f64 + 0.5) / h * PI;
    let lon = (col as f64 + 0.5) / w * TAU - PI;
    let up = unit(lat, lon);
    let (east, north) = east_north(up);
    let az = TAU * k as f64 / 16.0;
    let dir = east * az.cos() + north * az.sin();
    let r0 = R + global.data[row * global.width + col] as f64;
    let (lo, hi) = global.range();
    let reach = ((R + lo as f64) / (R + hi as f64)).acos();
    let step = PI / h / 20.0;
    let mut best = 0.0f64;
    let mut g = step;
    while g < reach + step {
        let p = up * g.cos() + dir * g.sin();
        let (la, lo) = lat_lon(p);
        let r1 = R + global.sample(la, lo);
        best = best.max((r1 * g.cos() - r0) / (r1 * g.sin()));
        g += step;
    }
    best.atan()
}

/// A tile that only resamples the global DEM (5 tile cells per global
/// cell, so every fifth tile centre is a global centre) changes the
/// horizon there only within the bilinear resampling's chord error: both
/// against a fine march over the global DEM's own surface.
#[test]
fn a_tile_resampling_the_global_dem_changes_the_horizon_little() {
    // 0.25° cells (7.6 km); a 3 km hill of σ 25 km straddling the tile.
    let (w, h) = (1440usize, 720usize);
    let (height, sigma) = (3000.0, 25e3);
    let hill_at = unit(0.0, 1.0f64.to_radians());
    let global = global_dem(w, h, |p| {
        let t = R * p.dot(hill_at).clamp(-1.0, 1.0).acos();
        height * (-0.5 * (t / sigma).powi(2)).exp()
    });
    // Tile: global cells 722 … 729 in longitude (0.5° … 2.5°), rows
    // 356 … 363 (+1° … −1°): 8 × 8 global cells, 40 × 40 tile cells.
    let limits = [-1.0, 1.0, 0.5, 2.5];
    let t = tile(limits, 40, 4.0, |lat, lon| global.sample(lat, lon));
    let base = HorizonMap::compute(&global, R, 16);
    let layer = TileHorizon::compute(&t, &global, R, 16);
    let (mut tile_worst, mut global_worst, mut diff_worst) = (0.0f64, 0.0f64, 0.0f64);
    // Interior global cells (beyond the 4-tile-cell band): 1 … 6.
    for gj in 1..7 {
        for gi in 1..7 {
            let (ti, tj) = (5 * gi + 2, 5 * gj + 2);
            let (col, row) = (722 + gi, 356 + gj);
            for k in 0..16 {
                let reference = fine_march(&global, col, row, k);
                let (a, b) = (layer.map.cell(ti, tj, k), base.cell(col, row, k));
                tile_worst = tile_worst.max((a - reference).abs());
                global_worst = global_worst.max((b - reference).abs());
                diff_worst = diff_worst.max((a - b).abs());
            }
        }
    }
    let top = base.max_elevation();
    // The tile's bilinear surface departs from the global one's by at
    // most the chord error |h''| c² / 8 (|h''| ≤ height / σ², c the tile
    // cell), seen no closer than the march's first step (half a cell).
    let c = R * (2.0f64.to_radians() / 40.0);
    let bound = (height / (sigma * sigma)) * c * c / 8.0 / (0.5 * c);
    println!(
        "resampled tile: worst |tile − fine march| {tile_worst:.2e} rad, |global − fine march| {global_worst:.2e} rad, |tile − global| {diff_worst:.2e} rad, bound {bound:.2e} rad (largest horizon {top:.3} rad)"
    );
    assert!(top > 0.05, "the hill casts horizons: {top}");
    assert!(tile_worst < bound, "tile {tile_worst} vs bound {bound}");
}

/// A tile's cached horizon map: computed once, then loaded with the same
/// values; a cache with a flipped byte or cut short is rebuilt, never
/// used; another tile file (a changed height) gets its own cache.
#[test]
fn a_corrupt_or_stale_tile_cache_is_rebuilt() {
    use optistim::render::output::write_f32_tiff;
    use optistim::scene::horizon::{CacheOutcome, HorizonParams};
    use optistim::scene::tiles::{load_dem_tiles, DemTileFile};

    let dir = tempfile::tempdir().unwrap();
    let (gw, gh) = (64usize, 32usize);
    let global_path = dir.path().join("global.tiff");
    let gdata: Vec<f32> = (0..gw * gh)
        .map(|k| ((k * 37) % 11) as f32 * 50.0)
        .collect();
    write_f32_tiff(&global_path, gw, gh, &gdata).unwrap();
    let global = EquirectMap::load(&global_path).unwrap();
    let tile_path = dir.path().join("tile.tiff");
    let tdata: Vec<f32> = (0..24 * 24).map(|k| ((k * 13) % 7) as f32 * 40.0).collect();
    write_f32_tiff(&tile_path, 24, 24, &tdata).unwrap();
    let file = DemTileFile {
        path: tile_path.clone(),
        lat_min: 10.0,
        lat_max: 14.0,
        lon_min: 20.0,
        lon_max: 24.0,
        scale: 1.0,
        blend: 3.0,
    };
    let params = HorizonParams {
        radius: 1e5,
        scale: 1.0,
        azimuths: 8,
    };
    let cache = dir.path().join("cache");
    let load = || {
        let set = load_dem_tiles(std::slice::from_ref(&file), dir.path(), 25e3, "t").unwrap();
        TileHorizon::load_or_compute(&set.tiles()[0], &global_path, &global, &params, &cache)
            .unwrap()
    };
    let (first, o1) = load();
    assert_eq!(o1, CacheOutcome::Computed);
    assert!(first.map.max_elevation() > 0.0);
    let (again, o2) = load();
    assert_eq!(o2, CacheOutcome::Loaded);
    assert_eq!(again.map.values(), first.map.values());
    let cached = std::fs::read_dir(&cache)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.to_string_lossy().contains("horizon-tile-"))
        .unwrap();
    let mut bytes = std::fs::read(&cached).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x40;
    std::fs::write(&cached, &bytes).unwrap();
    let (rebuilt, o3) = load();
    assert_eq!(o3, CacheOutcome::Rebuilt);
    assert_eq!(rebuilt.map.values(), first.map.values());
    std::fs::write(&cached, &bytes[..mid]).unwrap();
    assert_eq!(load().1, CacheOutcome::Rebuilt);
    // A changed tile is another key: computed afresh, not the old map.
    let mut changed = tdata.clone();
    changed[300] += 900.0;
    write_f32_tiff(&tile_path, 24, 24, &changed).unwrap();
    let (fresh, o4) = load();
    assert_eq!(o4, CacheOutcome::Computed);
    assert_ne!(fresh.map.values(), first.map.values());
}
