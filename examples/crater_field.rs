//! Synthetic crater-field DEM tile for close-range scenes (issue 26 item 3).
//!
//! Craters follow a power-law cumulative size-frequency distribution
//! N(>D) ∝ D^−b between `--d-min` and `--d-max` (default b = 2, the slope
//! of a saturated small-crater population), placed uniformly over the tile
//! (seeded: the same arguments give the same file). Each is a simple
//! crater: a paraboloid bowl of depth 0.2 D below a raised rim of height
//! 0.036 D (Pike 1977), the rim's ejecta falling off as (r / R)^−3 outside;
//! profiles add, largest first. Heights are metres above the body's sphere:
//! with `--base` (a float GeoTIFF DEM, km with `--base-scale 1000`) the
//! field sits on that DEM's bilinear surface, so the tile blends into it.
//!
//! Writes a float TIFF of heights [m] (`scale = 1.0`) and prints the
//! `[[body.dem_tiles]]` entry with its limits. Run:
//!
//! ```text
//! cargo run --release --example crater_field -- --out data/tiles/crater_field_s85.tif \
//!     --lat -85.5 --lon 0.0 --cells 256 --cell-m 40 --seed 26 \
//!     --base data/maps/ldem_4.tif --base-scale 1000
//! ```
//! (`tools/crater_field.sh` runs exactly that.)

use std::path::PathBuf;

use optistim::render::output::write_f32_tiff;
use optistim::scene::EquirectMap;

/// Depth over diameter of a simple crater.
const DEPTH_RATIO: f64 = 0.2;
/// Rim height over diameter (Pike 1977, simple craters).
const RIM_RATIO: f64 = 0.036;
/// Radii beyond which a crater's ejecta is dropped (0.036 D / 4³ < 0.1 % D).
const EJECTA_REACH: f64 = 4.0;

struct Args {
    out: PathBuf,
    lat: f64,
    lon: f64,
    cells: usize,
    cell_m: f64,
    radius_m: f64,
    seed: u64,
    count: usize,
    b: f64,
    d_min: f64,
    d_max: f64,
    base: Option<PathBuf>,
    base_scale: f64,
}

fn parse() -> Result<Args, String> {
    let mut a = Args {
        out: PathBuf::from("crater_field.tif"),
        lat: -85.5,
        lon: 0.0,
        cells: 256,
        cell_m: 40.0,
        radius_m: 1737.4e3,
        seed: 26,
        count: 1000,
        b: 2.0,
        d_min: 80.0,
        d_max: 2500.0,
        base: None,
        base_scale: 1.0,
    };
    let argv: Vec<String> = std::env::args().skip(1).collect();
    for pair in argv.chunks(2) {
        let [k, v] = pair else {
            return Err(format!("{} needs a value", pair[0]));
        };
        let num = |v: &str| v.parse::<f64>().map_err(|e| format!("{k}: {e}"));
        match k.as_str() {
            "--out" => a.out = v.into(),
            "--lat" => a.lat = num(v)?,
            "--lon" => a.lon = num(v)?,
            "--cells" => a.cells = num(v)? as usize,
            "--cell-m" => a.cell_m = num(v)?,
            "--radius-m" => a.radius_m = num(v)?,
            "--seed" => a.seed = num(v)? as u64,
            "--count" => a.count = num(v)? as usize,
            "--b" => a.b = num(v)?,
            "--d-min" => a.d_min = num(v)?,
            "--d-max" => a.d_max = num(v)?,
            "--base" => a.base = Some(v.into()),
            "--base-scale" => a.base_scale = num(v)?,
            _ => return Err(format!("unknown option {k}")),
        }
    }
    let ok = a.lat.abs() < 89.0
        && a.lon.abs() <= 180.0
        && (8..=4096).contains(&a.cells)
        && a.cell_m > 0.0
        && a.radius_m > 0.0
        && a.b > 0.0
        && 0.0 < a.d_min
        && a.d_min < a.d_max
        && a.count <= 1_000_000;
    if !ok {
        return Err("need |lat| < 89, |lon| ≤ 180, 8 ≤ cells ≤ 4096, cell-m, radius-m, b > 0, 0 < d-min < d-max, count ≤ 1e6".into());
    }
    Ok(a)
}

/// SplitMix64: a small seeded generator, so the tile is reproducible
/// without a dependency.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// A diameter from N(>D) ∝ D^−b truncated to [d_min, d_max]: the inverse
/// of the normalised cumulative distribution.
fn diameter(u: f64, b: f64, d_min: f64, d_max: f64) -> f64 {
    let tail = (d_min / d_max).powf(b);
    d_min * (1.0 - u * (1.0 - tail)).powf(-1.0 / b)
}

/// Height [m] of a simple crater of diameter `d` at distance `r` [m] from
/// its centre.
fn profile(d: f64, r: f64) -> f64 {
    let radius = 0.5 * d;
    let rim = RIM_RATIO * d;
    let depth = DEPTH_RATIO * d;
    if r <= radius {
        rim - depth * (1.0 - (r / radius).powi(2))
    } else {
        rim * (radius / r).powi(3)
    }
}

fn main() {
    let a = match parse() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("crater_field: {e}");
            std::process::exit(2);
        }
    };
    let n = a.cells;
    // Square ground cells at the centre latitude.
    let dlat = a.cell_m / a.radius_m;
    let dlon = dlat / a.lat.to_radians().cos();
    let half = 0.5 * n as f64;
    let lat0 = a.lat.to_radians() - half * dlat;
    let lat1 = a.lat.to_radians() + half * dlat;
    let lon0 = a.lon.to_radians() - half * dlon;
    let lon1 = a.lon.to_radians() + half * dlon;
    let base = a.base.as_ref().map(|p| {
        let mut m = EquirectMap::load(p).unwrap_or_else(|e| {
            eprintln!("crater_field: --base: {e}");
            std::process::exit(2);
        });
        m.scale(a.base_scale);
        m
    });
    let mut rng = Rng(a.seed);
    // Craters anywhere over the tile (centres in cells), largest first.
    let mut craters: Vec<(f64, f64, f64)> = (0..a.count)
        .map(|_| {
            let d = diameter(rng.next(), a.b, a.d_min, a.d_max);
            (rng.next() * n as f64, rng.next() * n as f64, d)
        })
        .collect();
    craters.sort_by(|p, q| q.2.total_cmp(&p.2));
    let mut heights = vec![0.0f64; n * n];
    for &(cx, cy, d) in &craters {
        let reach = EJECTA_REACH * 0.5 * d / a.cell_m;
        let (x0, x1) = (
            (cx - reach).floor().max(0.0),
            (cx + reach).ceil().min(n as f64),
        );
        let (y0, y1) = (
            (cy - reach).floor().max(0.0),
            (cy + reach).ceil().min(n as f64),
        );
        for row in y0 as usize..y1 as usize {
            for col in x0 as usize..x1 as usize {
                let dx = (col as f64 + 0.5 - cx) * a.cell_m;
                let dy = (row as f64 + 0.5 - cy) * a.cell_m;
                heights[row * n + col] += profile(d, dx.hypot(dy));
            }
        }
    }
    let mut data = vec![0.0f32; n * n];
    for row in 0..n {
        let lat = lat1 - (row as f64 + 0.5) * dlat;
        for col in 0..n {
            let lon = lon0 + (col as f64 + 0.5) * dlon;
            let ground = base.as_ref().map_or(0.0, |m| m.sample(lat, lon));
            data[row * n + col] = (ground + heights[row * n + col]) as f32;
        }
    }
    if let Some(dir) = a.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).expect("create the output directory");
    }
    write_f32_tiff(&a.out, n, n, &data).expect("write the tile");
    let (lo, hi) = data
        .iter()
        .fold((f32::MAX, f32::MIN), |(l, h), &v| (l.min(v), h.max(v)));
    let area_km2 = (n as f64 * a.cell_m / 1e3).powi(2);
    println!(
        "# {} craters, N(>D) ∝ D^-{} for D in [{}, {}] m (N(>{} m) = {:.1} per km²), seed {}; heights {lo:.1} … {hi:.1} m",
        a.count,
        a.b,
        a.d_min,
        a.d_max,
        a.d_min,
        a.count as f64 / area_km2,
        a.seed
    );
    println!(
        "# {n} × {n} cells of {} m, centred on ({}°, {}°)",
        a.cell_m, a.lat, a.lon
    );
    println!(
        "dem_tiles = [{{ path = \"{}\", lat_min = {:.9}, lat_max = {:.9}, lon_min = {:.9}, lon_max = {:.9}, scale = 1.0 }}]",
        a.out.display(),
        lat0.to_degrees(),
        lat1.to_degrees(),
        lon0.to_degrees(),
        lon1.to_degrees()
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The sampled diameters follow N(>D) ∝ D^−b: the share above D
    /// against ((D/d_min)^−b − t)/(1 − t), t = (d_min/d_max)^b.
    #[test]
    fn diameters_follow_the_power_law() {
        let (b, lo, hi) = (2.0, 60.0, 2500.0);
        let mut rng = Rng(7);
        let n = 200_000;
        let ds: Vec<f64> = (0..n).map(|_| diameter(rng.next(), b, lo, hi)).collect();
        let t = (lo / hi).powf(b);
        for d in [80.0, 150.0, 400.0, 1000.0] {
            let share = ds.iter().filter(|&&x| x > d).count() as f64 / n as f64;
            let want = ((d / lo).powf(-b) - t) / (1.0 - t);
            assert!(
                (share - want).abs() < 4.0 * (want / n as f64).sqrt() + 1e-4,
                "{d}: {share} vs {want}"
            );
        }
        assert!(ds.iter().all(|&x| (lo..=hi).contains(&x)));
    }

    /// A crater's floor is 0.2 D below its rim crest, which stands 0.036 D
    /// above the plain; continuous at the rim.
    #[test]
    fn the_profile_has_its_stated_depth_and_rim() {
        let d = 1000.0;
        assert!((profile(d, 500.0) - profile(d, 0.0) - 200.0).abs() < 1e-9);
        assert!((profile(d, 500.0) - 36.0).abs() < 1e-9);
        assert!((profile(d, 500.0 + 1e-9) - profile(d, 500.0 - 1e-9)).abs() < 1e-6);
    }
}
