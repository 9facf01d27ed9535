//! A render tells the sensor where its light is (`Sensor::expose_lit`'s
//! box) so the rest of the rate image is not scanned, and the PSF where
//! its image is non-zero: the frames must be the ones a full scan gives.
//! Checked against `Sensor::expose`, which scans every row, on a frame
//! with a saturating blob, smear and blooming, and on `render_scene`'s own
//! frame (PSF and sensor on) against `expose` of the electron rate it
//! returns; the largest DN against a maximum taken here.

use optistim::render::detector::{render_scene, PixelGeometry};
use optistim::render::Renderer;
use optistim::scene::Scene;
use optistim::sensor::{Readout, Sensor, SensorParams};

const W: usize = 96;
const H: usize = 64;

fn sensor() -> Sensor {
    let params = SensorParams {
        seed: 7,
        dark_current: 40.0,
        read_noise: 5.0,
        prnu: 0.01,
        dsnu: 1.5,
        offset: 50.0,
        transfer_time: 1e-3,
        blooming: true,
        nonlinearity: 0.0,
        row_noise: 0.0,
        shot_noise: true,
    };
    let readout = Readout {
        full_well: 2e4,
        gain: 0.2,
        bits: 12,
    };
    Sensor::new(params, readout, W, H)
}

/// A lit block over columns 30..41 and rows 20..31, one pixel far over
/// the full well (it blooms): its box is [30, 41, 20, 31).
fn rate() -> Vec<f32> {
    let mut rate = vec![0.0f32; W * H];
    for y in 20..31 {
        for x in 30..41 {
            rate[y * W + x] = 1e3 * (1 + (x * 7 + y * 3) % 11) as f32;
        }
    }
    rate[25 * W + 35] = 1e8;
    rate
}

#[test]
fn a_box_holding_the_light_gives_the_full_scan_frame() {
    let (s, rate) = (sensor(), rate());
    let full = s.expose(&rate, 1.0, 3);
    let peak = *full.dn.iter().max().unwrap();
    assert!(full.saturated > 0, "the blob saturates");
    for lit in [[30, 41, 20, 31], [0, W, 0, H], [25, 200, 10, 500]] {
        let mut dn = vec![0u16; W * H];
        let counts = s.expose_lit(&rate, lit, 1.0, 3, &mut dn);
        assert!(dn == full.dn, "{lit:?}: frames differ");
        assert_eq!(counts.saturated, full.saturated, "{lit:?}");
        assert_eq!(counts.peak_dn, peak, "{lit:?}");
    }
    // A box that misses lit pixels reads them as dark: the box is what
    // is scanned.
    let mut dn = vec![0u16; W * H];
    s.expose_lit(&rate, [30, 41, 20, 25], 1.0, 3, &mut dn);
    assert!(dn != full.dn, "a box missing rows 25..31 changed nothing");
}

/// The benchmark scene with smear (every lit pixel is then in a smeared
/// column) and without (a lit pixel left out of the box would be drawn
/// as a dark one).
#[test]
fn a_render_with_psf_and_sensor_reads_out_as_a_full_scan_does() {
    let path = std::path::Path::new("configs/moon_bench_camera.toml");
    let scene = Scene::from_file(path).expect("scene");
    let mut unsmeared = scene.clone();
    if let Some(p) = unsmeared.camera.sensor.as_mut() {
        p.transfer_time = 0.0;
    }
    render_reads_out_as_a_full_scan(&scene);
    render_reads_out_as_a_full_scan(&unsmeared);
}

fn render_reads_out_as_a_full_scan(scene: &Scene) {
    let cam = &scene.camera;
    let mut renderer = Renderer::new(cam.render_pinhole().clone());
    let pixels = PixelGeometry::new(&renderer);
    let images = render_scene(scene, &mut renderer, &pixels).expect("render");
    let params = cam.sensor.expect("the scene has a sensor");
    let (w, h) = (cam.pinhole.width, cam.pinhole.height);
    let sensor = Sensor::new(params, cam.readout(), w, h);
    let full = sensor.expose(&images.electron_rate, cam.exposure, cam.sensor_frame);
    assert!(images.dn == full.dn, "the render's frame differs");
    assert_eq!(images.summary.saturated_pixels, full.saturated);
    let peak = full.dn.iter().copied().max().unwrap() as u32;
    assert_eq!(images.summary.max_dn, peak);
    // The blurred radiance holds light only where the blurred rate does,
    // and both hold the Moon's: at 90° phase half a disk 40 % of the
    // 1024 px frame wide, π (0.2 · 1024)² / 2 ≈ 66 k pixels.
    let lit = |v: &[f32]| v.iter().filter(|&&x| x != 0.0).count();
    let half_disk = std::f64::consts::PI * (0.2 * 1024.0f64).powi(2) / 2.0;
    assert!(lit(&images.electron_rate) as f64 > 0.9 * half_disk);
    for (l, r) in images.radiance.iter().zip(&images.electron_rate) {
        assert_eq!(*l == 0.0, *r == 0.0, "radiance {l} against rate {r}");
    }
}
