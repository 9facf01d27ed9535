//! DEM tiles drive the displaced surface (`scene::tile_surface`): on a
//! tile holding one crater the renderer's radius and normals match the
//! tile's bilinear surface and finite differences of it written here; in
//! the seam they follow the smoothstep blend written here; outside every
//! tile they are the global DEM's, bit for bit.

use std::f64::consts::{FRAC_PI_2, PI, TAU};
use std::sync::Arc;

use glam::DVec3;
use optistim::scene::surface::{
    displaced, displaced_radius, displaced_radius_tiled, displaced_tiled,
};
use optistim::scene::tile_surface::HeightTiles;
use optistim::scene::tiles::{Tile, TileGrid, TileSet};
use optistim::scene::EquirectMap;

/// The Moon's radius [m].
const R: f64 = 1737.4e3;
/// Tile: 0 … 0.2° in latitude and longitude, N × N cells of 47 m.
const LIMIT: f64 = 0.2;
const N: usize = 128;
const BLEND: f64 = 4.0;
/// The tile's level [m] and its crater: a smooth bowl with a raised rim,
/// −D (1 − q²) exp(−q²) with q = s / A, s the distance from the centre.
const LEVEL: f64 = 100.0;
const A: f64 = 700.0;
const D: f64 = 200.0;

fn unit(lat: f64, lon: f64) -> DVec3 {
    DVec3::new(lat.cos() * lon.cos(), lat.cos() * lon.sin(), lat.sin())
}

fn centre() -> DVec3 {
    let c = (0.5 * LIMIT).to_radians();
    unit(c, c)
}

fn crater(lat: f64, lon: f64) -> f64 {
    let s = R * unit(lat, lon).dot(centre()).clamp(-1.0, 1.0).acos();
    let q2 = (s / A).powi(2);
    LEVEL - D * (1.0 - q2) * (-q2).exp()
}

fn cell() -> f64 {
    LIMIT.to_radians() / N as f64
}

/// The tile's cells at their centres (pixel-is-area, row 0 north).
fn tile_data() -> Vec<f32> {
    let (top, c) = (LIMIT.to_radians(), cell());
    let mut data = vec![0.0f32; N * N];
    for row in 0..N {
        for col in 0..N {
            let lat = top - (row as f64 + 0.5) * c;
            let lon = (col as f64 + 0.5) * c;
            data[row * N + col] = crater(lat, lon) as f32;
        }
    }
    data
}

fn tiles() -> HeightTiles {
    let top = LIMIT.to_radians();
    let tile = Tile {
        grid: TileGrid {
            lat_min: 0.0,
            lat_max: top,
            lon_min: 0.0,
            lon_max: top,
            width: N,
            height: N,
            blend: BLEND,
        },
        map: EquirectMap::new(N, N, tile_data()),
        path: "crater".into(),
        scale: 1.0,
    };
    HeightTiles::new(Arc::new(TileSet::new(vec![tile])))
}

/// A global DEM of `w` × `h` cells from `f(lat, lon)` at its cell centres.
fn global(
    w: usize,
    h: usize,
    f: impl Fn(f64, f64) -> f64,
) -> (EquirectMap, EquirectMap, EquirectMap) {
    let mut data = vec![0.0f32; w * h];
    for j in 0..h {
        for i in 0..w {
            let lat = FRAC_PI_2 - (j as f64 + 0.5) * PI / h as f64;
            let lon = (i as f64 + 0.5) * TAU / w as f64 - PI;
            data[j * w + i] = f(lat, lon) as f32;
        }
    }
    let height = EquirectMap::new(w, h, data);
    let (d_lat, d_lon) = height.gradients();
    (height, d_lat, d_lon)
}

/// The test's own bilinear read of the tile, clamped at its edges.
fn tile_bilinear(data: &[f32], lat: f64, lon: f64) -> f64 {
    let c = cell();
    let x = (lon / c - 0.5).clamp(0.0, (N - 1) as f64);
    let y = ((LIMIT.to_radians() - lat) / c - 0.5).clamp(0.0, (N - 1) as f64);
    let (i, j) = ((x as usize).min(N - 2), (y as usize).min(N - 2));
    let (tx, ty) = (x - i as f64, y - j as f64);
    let v = |i: usize, j: usize| data[j * N + i] as f64;
    let top = v(i, j) * (1.0 - tx) + v(i + 1, j) * tx;
    let bottom = v(i, j + 1) * (1.0 - tx) + v(i + 1, j + 1) * tx;
    top * (1.0 - ty) + bottom * ty
}

/// The tile's weight: the smoothstep of the distance [cells] from the
/// nearest edge over the blend band.
fn weight(lat: f64, lon: f64) -> f64 {
    let c = cell();
    let top = LIMIT.to_radians();
    let d = (lat / c)
        .min((top - lat) / c)
        .min(lon / c)
        .min((top - lon) / c);
    let t = (d / BLEND).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Unit normal of the surface n (R + height) at lat/lon from central
/// differences over ±`step` [rad].
fn fd_normal(height: &dyn Fn(f64, f64) -> f64, lat: f64, lon: f64, step: f64) -> DVec3 {
    let p = |la: f64, lo: f64| unit(la, lo) * (R + height(la, lo));
    let e = p(lat, lon + step) - p(lat, lon - step);
    let n = p(lat + step, lon) - p(lat - step, lon);
    e.cross(n).normalize()
}

/// Inside the tile (past its seam) the radius is R plus the tile's
/// bilinear height, and the normal is that of central differences of the
/// tile's bilinear surface over ±1 cell (which equal the tile's
/// interpolated central differences); the crater tilts it by up to 0.3 rad.
#[test]
fn normals_on_a_tile_match_finite_differences_of_its_dem() {
    let tiles = tiles();
    let data = tile_data();
    let flat = global(360, 180, |_, _| 0.0);
    let bilinear = |lat: f64, lon: f64| tile_bilinear(&data, lat, lon);
    let (mut worst, mut tilt, mut worst_r) = (0.0f64, 0.0f64, 0.0f64);
    let c = cell();
    for k in 0..4000 {
        let t = k as f64;
        // Over the tile's inner 60 %: past the blend band and its ±1 cell.
        let lat = (0.2 + 0.6 * (0.5 + 0.5 * (t * 0.618_034).sin())) * N as f64 * c;
        let lon = (0.2 + 0.6 * (0.5 + 0.5 * (t * 0.414_214).sin())) * N as f64 * c;
        let n = unit(lat, lon);
        let (r, normal) = displaced_tiled(&flat, Some(&tiles), R, n);
        worst_r = worst_r.max((r - R - bilinear(lat, lon)).abs());
        assert_eq!(displaced_radius_tiled(&flat.0, Some(&tiles), R, n), r);
        let want = fd_normal(&bilinear, lat, lon, c);
        worst = worst.max(normal.angle_between(want));
        tilt = tilt.max(normal.angle_between(n));
    }
    eprintln!("tile normals: worst {worst:e} rad, tilt {tilt} rad, radius {worst_r:e} m");
    assert!(
        worst_r < 1e-6,
        "radius off the tile's surface by {worst_r} m"
    );
    assert!(worst < 1e-6, "normal off the tile's surface by {worst} rad");
    assert!(tilt > 0.2, "the crater tilts the normals ({tilt} rad)");
}

/// In the seam the tile (flat at LEVEL there, but for the crater's
/// faint tail) fades into the flat global DEM: the height is the tile's
/// bilinear height times the smoothstep weight written here, and the
/// normal that of its infinitesimal central differences.
#[test]
fn normals_in_the_seam_follow_the_smoothstep_blend() {
    let tiles = tiles();
    let flat = global(360, 180, |_, _| 0.0);
    let data = tile_data();
    let blended = |lat: f64, lon: f64| weight(lat, lon) * tile_bilinear(&data, lat, lon);
    let c = cell();
    let (mut worst, mut tilt) = (0.0f64, 0.0f64);
    for k in 0..400 {
        // Across the southern and western bands, away from the corners.
        let d = (0.05 + 3.9 * k as f64 / 400.0) * c;
        let along = (20.0 + 0.2 * k as f64) * c;
        for (lat, lon) in [(d, along), (along, d)] {
            let (r, normal) = displaced_tiled(&flat, Some(&tiles), R, unit(lat, lon));
            assert!(
                (r - R - blended(lat, lon)).abs() < 1e-6,
                "radius at {lat} {lon}: {} vs {}",
                r - R,
                blended(lat, lon)
            );
            let want = fd_normal(&blended, lat, lon, 1e-4 * c);
            worst = worst.max(normal.angle_between(want));
            tilt = tilt.max(normal.angle_between(unit(lat, lon)));
        }
    }
    eprintln!("seam normals: worst {worst:e} rad, tilt {tilt} rad");
    assert!(worst < 1e-6, "seam normal off by {worst} rad");
    // The steepest slope of the smoothstep: 1.5 LEVEL over BLEND cells.
    let steepest = (1.5 * LEVEL / (BLEND * c * R)).atan();
    assert!(
        (tilt - steepest).abs() < 0.02 * steepest,
        "{tilt} vs {steepest}"
    );
}

/// Outside every tile the radius and normal are the global DEM's, bit for
/// bit, on a global DEM with relief.
#[test]
fn outside_the_tiles_the_surface_is_unchanged_bit_for_bit() {
    let tiles = tiles();
    let maps = global(256, 128, |lat, lon| {
        900.0 * (3.0 * lon).sin() * (2.0 * lat).cos() + 400.0 * lat.sin()
    });
    let mut checked = 0;
    for k in 0..3000 {
        let t = k as f64;
        let lat = (t * 0.618_034).sin() * 1.5;
        let lon = (t * 0.414_214).sin() * 3.1;
        let n = unit(lat, lon);
        if weight(lat, lon) > 0.0
            || (lat >= 0.0 && lon >= 0.0 && lat.max(lon) <= LIMIT.to_radians())
        {
            continue;
        }
        checked += 1;
        let (r0, n0) = displaced(&maps, R, n);
        let (r1, n1) = displaced_tiled(&maps, Some(&tiles), R, n);
        assert_eq!(
            (r0.to_bits(), n0.to_array().map(f64::to_bits)),
            (r1.to_bits(), n1.to_array().map(f64::to_bits))
        );
        assert_eq!(
            displaced_radius(&maps.0, R, n).to_bits(),
            displaced_radius_tiled(&maps.0, Some(&tiles), R, n).to_bits()
        );
    }
    assert!(checked > 2900, "{checked}");
    // And inside, the tile does change them.
    let inside = unit(0.1f64.to_radians(), 0.098f64.to_radians());
    assert_ne!(
        displaced(&maps, R, inside).1,
        displaced_tiled(&maps, Some(&tiles), R, inside).1
    );
}
