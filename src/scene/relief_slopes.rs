//! The steepest slope of a DEM at each scale: what the per-frame relief
//! switch ([`crate::render::relief_effect`]) needs to bound how far the
//! DEM can tilt the mean normal of a pixel's footprint.
//!
//! At baseline b the slope is |h(p + b) − h(p)| / b between DEM cells b
//! apart along a row (the true east–west distance at that latitude) or a
//! column. A pixel whose footprint spans b sees the mean of the slopes
//! inside it, which is that difference over b; its largest value over the
//! DEM bounds the tilt of any footprint that size. Baselines are the DEM's
//! cell × 2^k; a footprint between two baselines takes the shorter one's
//! slope (slopes shrink with the baseline, so that is the larger).

use super::maps::EquirectMap;

/// Most cell pairs a baseline is scanned over: a larger map is scanned on
/// a strided subset of rows and columns (a DEM tile may hold 2^27 cells).
const MAX_PAIRS: usize = 1 << 21;

/// The steepest slope [rad] per baseline [m] of a DEM and its tiles.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SlopeScales {
    /// Per map: (baseline [m], steepest slope over it [rad]), baselines
    /// ascending by factors of 2 from the map's cell.
    pub maps: Vec<Vec<(f64, f64)>>,
}

impl SlopeScales {
    /// Slopes of `dem` (heights [m], equirectangular, row 0's northern
    /// edge at `lat_max`, cells of `cell_lat` × `cell_lon` [rad]) on a
    /// sphere of `radius` [m].
    pub fn of_map(
        dem: &EquirectMap,
        radius: f64,
        lat_max: f64,
        cell_lat: f64,
        cell_lon: f64,
    ) -> Self {
        let mut steps = Vec::new();
        let mut k = 1usize;
        while k < dem.height.min(dem.width) {
            let baseline = radius * cell_lat * k as f64;
            let slope = steepest_at(dem, radius, lat_max, (cell_lat, cell_lon), k);
            steps.push((baseline, slope.atan()));
            k *= 2;
        }
        SlopeScales { maps: vec![steps] }
    }

    /// Slopes of a global equirectangular DEM.
    pub fn of_global(dem: &EquirectMap, radius: f64) -> Self {
        let cell = std::f64::consts::PI / dem.height as f64;
        let cell_lon = std::f64::consts::TAU / dem.width as f64;
        Self::of_map(dem, radius, std::f64::consts::FRAC_PI_2, cell, cell_lon)
    }

    /// Both tables (a DEM tile's over the global DEM's).
    pub fn with(mut self, other: SlopeScales) -> SlopeScales {
        self.maps.extend(other.maps);
        self
    }

    /// The steepest mean slope [rad] of a footprint `footprint` [m]
    /// across, over every map: each map's longest baseline not longer than
    /// the footprint (or its cell's, below it: the bilinear surface's
    /// slope is its cell's). 0 without a map.
    pub fn at(&self, footprint: f64) -> f64 {
        self.maps
            .iter()
            .filter_map(|steps| {
                let first = steps.first()?;
                let shorter = steps.iter().take_while(|(b, _)| *b <= footprint).last();
                Some(shorter.unwrap_or(first).1)
            })
            .fold(0.0, f64::max)
    }
}

/// The steepest |Δh| / distance over cell pairs `k` apart along rows and
/// columns.
fn steepest_at(
    dem: &EquirectMap,
    radius: f64,
    lat_max: f64,
    (cell_lat, cell_lon): (f64, f64),
    k: usize,
) -> f64 {
    let (w, h) = (dem.width, dem.height);
    let stride = ((w * h) as f64 / MAX_PAIRS as f64).sqrt().ceil().max(1.0) as usize;
    let mut steepest = 0.0f64;
    for row in (0..h).step_by(stride) {
        let lat = lat_max - (row as f64 + 0.5) * cell_lat;
        let east = radius * cell_lon * lat.cos() * k as f64;
        let north = radius * cell_lat * k as f64;
        let line = &dem.data[row * w..(row + 1) * w];
        for col in (0..w).step_by(stride) {
            let z = line[col] as f64;
            if col + k < w && east > 0.0 {
                steepest = steepest.max((line[col + k] as f64 - z).abs() / east);
            }
            if row + k < h {
                steepest = steepest.max((dem.data[(row + k) * w + col] as f64 - z).abs() / north);
            }
        }
    }
    steepest
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A plane tilted in latitude, h = g · (distance north): every
    /// baseline reads atan g; a flat map reads 0.
    #[test]
    fn a_tilted_plane_reads_its_slope_at_every_baseline() {
        let (w, h, r) = (64, 32, 1.0e6);
        let cell = std::f64::consts::PI / h as f64;
        let g = 0.05;
        let data: Vec<f32> = (0..w * h)
            .map(|i| (-g * r * cell * (i / w) as f64) as f32)
            .collect();
        let s = SlopeScales::of_global(&EquirectMap::new(w, h, data), r);
        assert!(!s.maps[0].is_empty());
        for &(b, slope) in &s.maps[0] {
            assert!((slope - g.atan()).abs() < 1e-6, "baseline {b}: {slope}");
        }
        let flat = SlopeScales::of_global(&EquirectMap::new(w, h, vec![0.0; w * h]), r);
        assert!(flat.maps[0].iter().all(|&(_, s)| s == 0.0));
        assert_eq!(flat.at(1e3), 0.0);
    }

    /// One step of height d between two rows: baseline b reads atan(d / b)
    /// (the step lies within every baseline), and `at` takes the longest
    /// baseline at or below the footprint.
    #[test]
    fn a_step_reads_its_height_over_the_baseline() {
        let (w, h, r) = (64, 32, 1.0e6);
        let cell_m = r * std::f64::consts::PI / h as f64;
        let d = 500.0;
        let data: Vec<f32> = (0..w * h)
            .map(|i| if i / w < 16 { d as f32 } else { 0.0 })
            .collect();
        let s = SlopeScales::of_global(&EquirectMap::new(w, h, data), r);
        for &(b, slope) in &s.maps[0] {
            assert!((slope - (d / b).atan()).abs() < 1e-9, "baseline {b}");
        }
        assert!((s.at(3.0 * cell_m) - (d / (2.0 * cell_m)).atan()).abs() < 1e-9);
        assert!((s.at(0.1 * cell_m) - (d / cell_m).atan()).abs() < 1e-9);
    }
}
