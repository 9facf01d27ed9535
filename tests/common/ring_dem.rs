//! A DEM constant in longitude (a ring ridge around the pole) and what a
//! camera over the pole sees of it, computed here from the DEM's rows:
//! the relief tests' shared reference (limb, far limb, hidden terrain).

use std::f64::consts::{FRAC_PI_2, PI};

/// DEM rows (latitude) and columns of the ring ridge.
pub const ROWS: usize = 720;
pub const COLS: usize = 8;

/// Ridge height profile of latitude: a Gaussian ring of height `h` [m]
/// and width `sigma` [rad] around latitude `crest` [rad].
pub fn ridge(lat: f64, h: f64, crest: f64, sigma: f64) -> f64 {
    h * (-0.5 * ((lat - crest) / sigma).powi(2)).exp()
}

/// Latitude [rad] of DEM row centre j.
pub fn row_lat(j: usize) -> f64 {
    FRAC_PI_2 - (j as f64 + 0.5) * PI / ROWS as f64
}

/// The DEM's height at latitude `lat`: linear between row centres, held
/// beyond the first and last (a bilinear read of a DEM constant in
/// longitude).
pub fn dem_height(rows: &[f64], lat: f64) -> f64 {
    let y = ((FRAC_PI_2 - lat) / PI * ROWS as f64 - 0.5).clamp(0.0, (ROWS - 1) as f64);
    let j = (y.floor() as usize).min(ROWS - 2);
    let t = y - j as f64;
    rows[j] * (1.0 - t) + rows[j + 1] * t
}

/// Angle [rad] off the line of sight of the silhouette of the body of
/// radius `radius` raised by `rows`, seen from distance `d` over its north
/// pole: the largest atan(ρ / (d − z)) over `steps` + 1 latitudes from
/// `lats.0` to `lats.1` [rad], and the latitude where it is reached.
pub fn silhouette(rows: &[f64], radius: f64, d: f64, lats: (f64, f64), steps: usize) -> (f64, f64) {
    let (mut best, mut at) = (0.0f64, 0.0);
    for k in 0..=steps {
        let lat = lats.0 + (k as f64 / steps as f64) * (lats.1 - lats.0);
        let r = radius + dem_height(rows, lat);
        let a = (r * lat.cos()).atan2(d - r * lat.sin());
        if a > best {
            (best, at) = (a, lat);
        }
    }
    (best, at)
}

/// Distance [px] from the principal point to the end of the lit disk along
/// row `row`, toward `sign` (±1): pixels past the outermost one at least
/// 98 % of `full` count their share of `full` (an area-law body is
/// uniformly bright, so a pixel's radiance is its covered share).
pub fn edge_px(radiance: &[f32], width: usize, row: usize, cx: f64, sign: i64, full: f64) -> f64 {
    let col = |k: i64| (cx.floor() as i64 + sign * k) as usize;
    let share = |k: i64| (radiance[row * width + col(k)] as f64 / full).min(1.0);
    let last = (0..(width as i64 / 2 - 1))
        .filter(|&k| share(k) >= 0.98)
        .max()
        .unwrap();
    let partial: f64 = (last + 1..(width as i64 / 2 - 1)).map(share).sum();
    // The central pixel's far edge is |cx − floor cx ± ...| from cx.
    let far_edge_of_last = if sign > 0 {
        (cx.floor() + last as f64 + 1.0) - cx
    } else {
        cx - (cx.floor() - last as f64)
    };
    far_edge_of_last + partial
}

/// Writes the DEM of `rows` (one height [m] per latitude row, constant in
/// longitude over [`COLS`] columns) to `path` as a float TIFF.
pub fn write_ring_dem(path: &std::path::Path, rows: &[f64]) {
    let data: Vec<f32> = rows
        .iter()
        .flat_map(|&v| std::iter::repeat_n(v as f32, COLS))
        .collect();
    optistim::render::output::write_f32_tiff(path, COLS, ROWS, &data).unwrap();
}

/// A scene's `[state]` header with the body attitude that turns its north
/// pole toward the camera at `camera` (body-centred, world frame).
pub fn pole_toward(camera: glam::DVec3) -> String {
    let q = glam::DQuat::from_rotation_arc(glam::DVec3::Z, camera.normalize());
    format!(
        "[state]\nbody_attitude = [{:e}, {:e}, {:e}, {:e}]",
        q.w, q.x, q.y, q.z
    )
}
