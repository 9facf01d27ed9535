//! Albedo tiles in a render: a Lambert sphere (albedo 0.3) under a tile of
//! albedo 0.6 is exactly twice as bright where the tile covers a pixel's
//! surface point wholly, unchanged away from it, in between only in the
//! seam; a tile of the model's own albedo changes the image only by the
//! node lattice it switches off.

mod common;
use common::*;

use std::path::Path;

use glam::DVec3;
use optistim::render::output::write_f32_tiff;
use optistim::scene::Scene;

/// Tile limits [deg] and its blend band [deg] (4 cells of 30°/64).
const LAT: [f64; 2] = [-10.0, 20.0];
const LON: [f64; 2] = [10.0, 40.0];
const BAND_DEG: f64 = 4.0 * 30.0 / 64.0;

fn scene(tile: &Path, albedo: f64) -> Scene {
    let mut s = Setup::new("{ model = \"lambert\", albedo = 0.3 }", 30.0, 10.0, 200.0);
    if albedo > 0.0 {
        s.extra_body = format!(
            "albedo_tiles = [{{ path = \"{}\", lat_min = {}, lat_max = {}, lon_min = {}, lon_max = {}, min = {albedo}, max = {albedo} }}]",
            tile.display(),
            LAT[0],
            LAT[1],
            LON[0],
            LON[1]
        );
    }
    s.scene()
}

/// Latitude/longitude [deg] where the ray through pixel (i, j) meets the
/// sphere (body at the origin, body frame = world), if it does.
fn surface_point(scene: &Scene, i: usize, j: usize) -> Option<(f64, f64)> {
    let st = &scene.state;
    let d = st.camera_attitude * scene.camera.pinhole.pixel_direction(i, j);
    let o = st.camera_position - st.body_position;
    let r = scene.body.radius;
    let b = o.dot(d);
    let disc = b * b - (o.length_squared() - r * r);
    if disc <= 0.0 {
        return None;
    }
    let p: DVec3 = o + d * (-b - disc.sqrt());
    let p = p / r;
    Some((p.z.asin().to_degrees(), p.y.atan2(p.x).to_degrees()))
}

#[test]
fn an_albedo_tile_scales_the_pixels_it_covers() {
    let dir = tempfile::tempdir().unwrap();
    let tile = dir.path().join("albedo.tiff");
    write_f32_tiff(&tile, 64, 64, &vec![1.0f32; 64 * 64]).unwrap();
    let bright = render(&scene(&tile, 0.6));
    let same = render(&scene(&tile, 0.3));
    let none = render(&scene(&tile, 0.0));
    let sc = scene(&tile, 0.6);
    let [w, h] = [sc.camera.pinhole.width, sc.camera.pinhole.height];
    // A pixel spans about 0.6° of arc at the centre of the disk: 2° of
    // margin around the band (inside) and the edge (outside).
    let margin = 2.0;
    let (mut inside, mut outside, mut seam) = (0, 0, 0);
    let mut worst_lattice = 0.0f64;
    for j in 0..h {
        for i in 0..w {
            let k = j * w + i;
            let (a, b) = (bright.radiance[k] as f64, same.radiance[k] as f64);
            if b <= 0.0 {
                continue;
            }
            let ratio = a / b;
            assert!(
                (1.0 - 1e-6..=2.0 + 1e-6).contains(&ratio),
                "({i}, {j}): {ratio}"
            );
            let Some((lat, lon)) = surface_point(&sc, i, j) else {
                continue;
            };
            let depth = (lat - LAT[0])
                .min(LAT[1] - lat)
                .min(lon - LON[0])
                .min(LON[1] - lon);
            if depth > BAND_DEG + margin {
                assert!((ratio - 2.0).abs() < 1e-5, "inside ({i}, {j}): {ratio}");
                inside += 1;
            } else if depth < -margin {
                assert!((ratio - 1.0).abs() < 1e-5, "outside ({i}, {j}): {ratio}");
                outside += 1;
            } else {
                seam += 1;
            }
            let c = none.radiance[k] as f64;
            worst_lattice = worst_lattice.max((b - c).abs() / c.max(1e-30));
        }
    }
    println!("inside {inside}, outside {outside}, seam {seam} pixels; tile of the model's albedo vs none: worst {worst_lattice:.2e} relative");
    assert!(inside > 500 && outside > 5000, "{inside} {outside}");
    // The lattice's interpolation is held to the render's pixel tolerance.
    assert!(worst_lattice < 1e-3, "{worst_lattice}");
}
