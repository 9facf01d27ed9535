//! DEM tiles in the displaced surface: the height of the finest tile
//! covering a point blended over the global DEM with the tiles' own
//! smoothstep seam ([`TileSet::value`]), and its slopes, so that the limb,
//! the shading normals and the tiles' horizon maps read one surface.
//!
//! Each tile's slopes are central differences of its cells (one-sided at
//! its edges) read bilinearly, as the global DEM's are
//! ([`EquirectMap::gradients`]); the seam adds the weight's own slope
//! times the step between the tile and what lies under it.

use std::sync::Arc;

use super::maps::EquirectMap;
use super::tiles::{Tile, TileSet};

/// The DEM tiles of a displacement with their slope maps [m/rad].
#[derive(Clone, Debug)]
pub struct HeightTiles {
    tiles: Arc<TileSet>,
    /// Per tile (finest first): d/dlat and d/dlon of its heights, as tiles
    /// on its grid.
    slopes: Vec<(Tile, Tile)>,
    bound: f64,
}

/// A height [m] and its derivatives with respect to latitude and
/// longitude [m/rad].
pub type HeightSlopes = (f64, f64, f64);

impl HeightTiles {
    /// The displacement's tiles (heights [m]), their slopes computed once.
    pub fn new(tiles: Arc<TileSet>) -> HeightTiles {
        let slopes = tiles.tiles().iter().map(tile_slopes).collect();
        let bound = tiles
            .tiles()
            .iter()
            .map(|t| {
                let (lo, hi) = t.map.range();
                lo.abs().max(hi.abs()) as f64
            })
            .fold(0.0, f64::max);
        HeightTiles {
            tiles,
            slopes,
            bound,
        }
    }

    /// The tiles, finest first.
    pub fn tiles(&self) -> &TileSet {
        &self.tiles
    }

    /// Largest |height| [m] of any tile.
    pub fn bound(&self) -> f64 {
        self.bound
    }

    /// Whether any tile reaches lat/lon (weight > 0).
    #[inline]
    pub fn covers(&self, lat: f64, lon: f64) -> bool {
        self.tiles
            .tiles()
            .iter()
            .any(|t| t.grid.weight(lat, lon) > 0.0)
    }

    /// Height [m] at lat/lon: the tiles blended over `base` (the global
    /// DEM's height there).
    #[inline]
    pub fn height(&self, lat: f64, lon: f64, base: &dyn Fn() -> f64) -> f64 {
        self.tiles.value(lat, lon, base)
    }

    /// Height and slopes at lat/lon, blended finest first over `base` (the
    /// global DEM's): each covering tile takes its weight w of what is
    /// left, so with what is left written ρ the blend is Σ ρ w T + ρ_N G;
    /// the slopes follow by the product rule, the weights' own slopes
    /// included.
    #[inline]
    pub fn height_and_slopes(
        &self,
        lat: f64,
        lon: f64,
        base: &dyn Fn() -> HeightSlopes,
    ) -> HeightSlopes {
        let mut acc = (0.0, 0.0, 0.0);
        let mut rest = (1.0, 0.0, 0.0);
        let mut covered = false;
        for (tile, (s_lat, s_lon)) in self.tiles.tiles().iter().zip(&self.slopes) {
            let (w, w_lat, w_lon) = tile.grid.weight_and_gradient(lat, lon);
            if w <= 0.0 {
                continue;
            }
            covered = true;
            let v = (
                tile.sample(lat, lon),
                s_lat.sample(lat, lon),
                s_lon.sample(lat, lon),
            );
            let wv = product((w, w_lat, w_lon), v);
            acc = add(acc, product(rest, wv));
            rest = product(rest, (1.0 - w, -w_lat, -w_lon));
            if rest.0 <= 0.0 {
                return acc;
            }
        }
        if !covered {
            // Outside every tile: the global DEM's values bit for bit.
            return base();
        }
        add(acc, product(rest, base()))
    }
}

/// (a, ∂a) · (b, ∂b) by the product rule.
#[inline]
fn product(a: HeightSlopes, b: HeightSlopes) -> HeightSlopes {
    (a.0 * b.0, a.1 * b.0 + a.0 * b.1, a.2 * b.0 + a.0 * b.2)
}

#[inline]
fn add(a: HeightSlopes, b: HeightSlopes) -> HeightSlopes {
    (a.0 + b.0, a.1 + b.1, a.2 + b.2)
}

/// A tile's d/dlat and d/dlon [m/rad]: central differences of its cells,
/// one-sided at its edges (a tile does not wrap); rows run southward.
fn tile_slopes(tile: &Tile) -> (Tile, Tile) {
    let (w, h) = (tile.map.width, tile.map.height);
    let at = |i: usize, j: usize| tile.map.data[j * w + i] as f64;
    let (cell_lat, cell_lon) = (tile.grid.cell_lat(), tile.grid.cell_lon());
    let mut d_lat = vec![0.0f32; w * h];
    let mut d_lon = vec![0.0f32; w * h];
    for j in 0..h {
        let (up, down) = (j.saturating_sub(1), (j + 1).min(h - 1));
        for i in 0..w {
            let (left, right) = (i.saturating_sub(1), (i + 1).min(w - 1));
            let dx = (at(right, j) - at(left, j)) / ((right - left) as f64 * cell_lon);
            let dy = (at(i, down) - at(i, up)) / ((down - up) as f64 * cell_lat);
            d_lon[j * w + i] = dx as f32;
            d_lat[j * w + i] = -dy as f32;
        }
    }
    let slope = |data: Vec<f32>| Tile {
        grid: tile.grid,
        map: EquirectMap::new(w, h, data),
        path: tile.path.clone(),
        scale: 1.0,
    };
    (slope(d_lat), slope(d_lon))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::tiles::TileGrid;

    fn plane_tile(blend: f64) -> Tile {
        let grid = TileGrid {
            lat_min: 0.1,
            lat_max: 0.2,
            lon_min: -0.3,
            lon_max: -0.1,
            width: 40,
            height: 20,
            blend,
        };
        let mut data = vec![0.0f32; 800];
        for j in 0..20 {
            for i in 0..40 {
                let (lat, lon) = grid.lat_lon_of(i as f64, j as f64);
                data[j * 40 + i] = (1000.0 * lat - 300.0 * lon) as f32;
            }
        }
        Tile {
            grid,
            map: EquirectMap::new(40, 20, data),
            path: "plane".into(),
            scale: 1.0,
        }
    }

    /// A tilted plane (heights 1000 lat − 300 lon m) over a flat base: deep
    /// inside, the slopes are the plane's; in the seam, central
    /// differences of the blended height; outside, the base bit for bit.
    #[test]
    fn slopes_follow_the_blended_height() {
        let tiles = HeightTiles::new(Arc::new(TileSet::new(vec![plane_tile(4.0)])));
        // A flat base: its slopes are those of its height.
        let base = || (7.0, 0.0, 0.0);
        let (h, d_lat, d_lon) = tiles.height_and_slopes(0.15, -0.2, &base);
        assert!((h - (150.0 + 60.0)).abs() < 1e-3, "{h}");
        assert!((d_lat - 1000.0).abs() < 1e-3 && (d_lon + 300.0).abs() < 1e-3);
        let height = |lat: f64, lon: f64| tiles.height_and_slopes(lat, lon, &base).0;
        let step = 1e-7;
        for (lat, lon) in [(0.1 + 0.012, -0.2), (0.15, -0.3 + 0.011), (0.197, -0.104)] {
            let (_, d_lat, d_lon) = tiles.height_and_slopes(lat, lon, &base);
            let fd_lat = (height(lat + step, lon) - height(lat - step, lon)) / (2.0 * step);
            let fd_lon = (height(lat, lon + step) - height(lat, lon - step)) / (2.0 * step);
            assert!(
                (d_lat - fd_lat).abs() < 1e-3 * fd_lat.abs().max(1.0),
                "{d_lat} {fd_lat}"
            );
            assert!(
                (d_lon - fd_lon).abs() < 1e-3 * fd_lon.abs().max(1.0),
                "{d_lon} {fd_lon}"
            );
        }
        let tilted = || (7.0, 0.5, -0.25);
        assert_eq!(tiles.height_and_slopes(0.05, -0.2, &tilted), tilted());
        assert!(!tiles.covers(0.05, -0.2) && tiles.covers(0.15, -0.2));
    }
}
