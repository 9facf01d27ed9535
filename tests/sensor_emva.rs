//! The EMVA 1288 sensor chain (`src/sensor`): the photon-transfer analysis
//! of tests/common/ptc.rs (EMVA 1288 §6: temporal variance from the difference of two
//! frames, gain from the mean–variance slope, dark current from the dark
//! signal's growth with exposure, read noise from the dark variance less
//! the quantisation noise 1/12 DN²) over flat fields rendered by the
//! renderer recovers the configured gain, read noise and dark current; the
//! full well and the ADC's bit depth cap the DN where they should; the
//! seed fixes the frame.

mod common;

use std::path::Path;

use optistim::scene::Scene;
use optistim::sensor::Sensor;

use common::ptc::{pair_stats, Pair, PhotonTransfer};

/// Configured truth.
const GAIN: f64 = 0.25;
const READ_NOISE: f64 = 8.0;
const DARK_CURRENT: f64 = 200.0;
const FULL_WELL: f64 = 20_000.0;
const OFFSET: f64 = 100.0;

/// A 128 × 128 camera 1000 m above a Lambert sphere of radius 1000 m,
/// looking at the sub-solar point with a 2° field: a flat field (the
/// radiance varies by < 0.1 % across it).
fn flat_scene(bits: u32, seed: u64, extra: &str) -> Scene {
    Scene::from_toml(&flat_text(bits, seed, extra), Path::new("flat.toml")).expect("flat scene")
}

fn flat_text(bits: u32, seed: u64, extra: &str) -> String {
    format!(
        r#"
[camera]
resolution = [128, 128]
pixel_pitch = 10e-6
fov_deg = 2.0
f_number = 8.0
exposure = 1e-3
full_well = {FULL_WELL:e}
bits = {bits}
gain = {GAIN}
band = [450e-9, 820e-9]

[camera.sensor]
seed = {seed}
dark_current = {DARK_CURRENT}
read_noise = {READ_NOISE}
prnu = 0.01
dsnu = 3.0
offset = {OFFSET}
{extra}

[sun]
spectrum = "blackbody"
temperature = 5772.0
irradiance_1au = 1361.0

[body]
radius = 1000.0
reflectance = {{ model = "lambert", albedo = 0.3 }}

[state]
camera_position = [2000.0, 0.0, 0.0]
camera_attitude = {q:?}
sun_position = [1.496e11, 0.0, 0.0]
"#,
        q = common::look_at(glam::DVec3::new(2000.0, 0.0, 0.0), glam::DVec3::ZERO)
    )
}

fn sensor_of(scene: &Scene) -> Sensor {
    let pin = &scene.camera.pinhole;
    Sensor::new(
        scene.camera.sensor.expect("sensor configured"),
        scene.camera.readout(),
        pin.width,
        pin.height,
    )
}

fn as_f64(dn: &[u16]) -> Vec<f64> {
    dn.iter().map(|&v| v as f64).collect()
}

/// The pair of frames numbered `frame` and `frame + 1`.
fn frame_pair(sensor: &Sensor, rate: &[f32], t: f64, frame: u64) -> (f64, f64) {
    let a = as_f64(&sensor.expose(rate, t, frame).dn);
    let b = as_f64(&sensor.expose(rate, t, frame + 1).dn);
    pair_stats(&a, &b)
}

#[test]
fn photon_transfer_recovers_gain_read_noise_and_dark_current() {
    let scene = flat_scene(16, 7, "");
    let images = common::render(&scene);
    let rate = &images.electron_rate;
    let max_rate = rate.iter().copied().fold(0.0f32, f32::max) as f64;
    let min_rate = rate.iter().copied().fold(f32::INFINITY, f32::min) as f64;
    assert!(
        min_rate > 0.995 * max_rate,
        "not flat: {min_rate} .. {max_rate}"
    );
    let sensor = sensor_of(&scene);
    let dark = vec![0.0f32; rate.len()];
    // Each pair its own frames: lit 0.., dark at the lit exposures 50..,
    // the dark ramp 100.., the read-noise pair 200.
    let ptc = PhotonTransfer::measure(FULL_WELL, max_rate, |which, t| {
        let k = |n: usize| 2 * n as u64;
        match which {
            Pair::Light(n) => frame_pair(&sensor, rate, t, k(n)),
            Pair::DarkAtLight(n) => frame_pair(&sensor, &dark, t, 50 + k(n)),
            Pair::DarkRamp(n) => frame_pair(&sensor, &dark, t, 100 + k(n)),
            Pair::ReadNoise => frame_pair(&sensor, &dark, t, 200),
        }
    });
    ptc.assert_recovers(GAIN, READ_NOISE, DARK_CURRENT, 0.02);
}

/// The sensor a render loop shares (`Sensor::shared`, built once per
/// process) reads out byte for byte the frames of one built afresh, with
/// smear and blooming on and a quarter of the frame over the full well.
#[test]
fn a_shared_sensor_gives_the_frames_of_a_fresh_one() {
    let scene = flat_scene(12, 5, "transfer_time = 1e-4\nblooming = true");
    let rate: Vec<f32> = common::render(&scene)
        .electron_rate
        .iter()
        .enumerate()
        .map(|(k, &r)| if k % 4 == 0 { 3.0 * r } else { r })
        .collect();
    let max_rate = rate.iter().copied().fold(0.0f32, f32::max) as f64;
    let t = 0.5 * FULL_WELL / max_rate;
    let pin = &scene.camera.pinhole;
    let params = scene.camera.sensor.expect("sensor");
    let shared = Sensor::shared(params, scene.camera.readout(), pin.width, pin.height);
    let again = Sensor::shared(params, scene.camera.readout(), pin.width, pin.height);
    assert!(std::sync::Arc::ptr_eq(&shared, &again), "built twice");
    let fresh = sensor_of(&scene);
    assert_eq!(shared.prnu_map(), fresh.prnu_map());
    assert_eq!(shared.dsnu_map(), fresh.dsnu_map());
    for frame in [0, 1, 77] {
        let (a, b) = (
            shared.expose(&rate, t, frame),
            fresh.expose(&rate, t, frame),
        );
        assert!(a.saturated > 0, "no pixel over the full well");
        assert_eq!(a.dn, b.dn, "frame {frame}");
        assert_eq!(a.saturated, b.saturated);
    }
}

#[test]
fn render_writes_frame_zero_of_the_sensor() {
    let scene = flat_scene(16, 3, "");
    let images = common::render(&scene);
    let frame = sensor_of(&scene).expose(&images.electron_rate, scene.camera.exposure, 0);
    assert_eq!(images.dn, frame.dn);
    assert!(images.summary.sensor.is_some());
}

/// `camera.sensor_frame` (a dataset item's noise seed) picks the frame
/// the render draws: the sensor's own frame of that index.
#[test]
fn render_draws_the_cameras_sensor_frame() {
    let mut scene = flat_scene(16, 3, "");
    // An exposure at 30 % of the full well, where the noise shows.
    let rate = common::render(&scene).electron_rate[0] as f64;
    scene.camera.exposure = 0.3 * FULL_WELL / rate;
    scene.camera.sensor_frame = 12_345;
    let images = common::render(&scene);
    let t = scene.camera.exposure;
    let frame = sensor_of(&scene).expose(&images.electron_rate, t, 12_345);
    assert!(images.dn == frame.dn, "the render draws frame 12345");
    let zero = sensor_of(&scene).expose(&images.electron_rate, t, 0);
    let differing = images
        .dn
        .iter()
        .zip(&zero.dn)
        .filter(|(a, b)| a != b)
        .count();
    assert!(
        differing > images.dn.len() / 2,
        "{differing} pixels differ from frame 0"
    );
}

#[test]
fn saturation_sits_at_the_full_well_and_the_bit_depth() {
    // 16 bits: the full well saturates first, at round(offset + K · FW).
    let scene = flat_scene(16, 5, "");
    let images = common::render(&scene);
    let max_rate = images.electron_rate.iter().copied().fold(0.0f32, f32::max) as f64;
    let sensor = sensor_of(&scene);
    let t_over = 3.0 * FULL_WELL / max_rate;
    let frame = sensor.expose(&images.electron_rate, t_over, 0);
    let level = (OFFSET + GAIN * FULL_WELL).round() as u16;
    assert!(frame.dn.iter().all(|&v| v == level), "full well at {level}");
    assert_eq!(frame.saturated as usize, frame.dn.len());
    // Just below the full well, nothing saturates.
    let below = sensor.expose(&images.electron_rate, 0.8 * FULL_WELL / max_rate, 0);
    assert_eq!(below.saturated, 0);
    assert!(below.dn.iter().all(|&v| v < level));

    // 12 bits: K · FW + offset = 5100 DN exceeds 4095, so the ADC limits.
    let scene = flat_scene(12, 5, "");
    let sensor = sensor_of(&scene);
    let max_dn = (1u16 << 12) - 1;
    let frame = sensor.expose(&images.electron_rate, t_over, 0);
    assert!(frame.dn.iter().all(|&v| v == max_dn));
    // At 90 % of the full well (4600 DN expected) some pixels clip at
    // 4095 and none exceed it.
    let frame = sensor.expose(&images.electron_rate, 0.9 * FULL_WELL / max_rate, 0);
    assert!(frame.dn.iter().all(|&v| v <= max_dn));
    assert!(frame.dn.contains(&max_dn));
    assert_eq!(
        frame.saturated as usize,
        frame.dn.iter().filter(|&&v| v == max_dn).count()
    );
}

#[test]
fn the_seed_fixes_the_noise() {
    let scene = flat_scene(16, 11, "");
    let images = common::render(&scene);
    let rate = &images.electron_rate;
    let t = 0.3 * FULL_WELL / rate[0] as f64;
    let a = sensor_of(&scene).expose(rate, t, 0).dn;
    let b = sensor_of(&flat_scene(16, 11, "")).expose(rate, t, 0).dn;
    assert_eq!(a, b, "same seed, same frame");
    let other = sensor_of(&flat_scene(16, 12, "")).expose(rate, t, 0).dn;
    let differing = a.iter().zip(&other).filter(|(x, y)| x != y).count();
    // Shot noise alone is ~ 1.2 DN rms here: nearly every pixel differs.
    assert!(differing > a.len() * 9 / 10, "{differing} of {}", a.len());
    let next = sensor_of(&scene).expose(rate, t, 1).dn;
    assert_ne!(a, next, "another frame, other noise");
}

#[test]
fn blooming_conserves_charge_in_a_render() {
    // A spot over the full well in one column: with blooming the column's
    // mean DN (offset removed) equals the unclipped charge while the
    // column has room; without, it is clipped.
    let scene = flat_scene(16, 2, "blooming = true");
    let sensor = sensor_of(&scene);
    let (w, h) = (128, 128);
    let mut rate = vec![0.0f32; w * h];
    // 5.2 full wells in 1 s whatever the pixel's PRNU: 5 pixels fill.
    let spot = 5.2 * FULL_WELL;
    rate[64 * w + 10] = (spot / sensor.prnu_map()[64 * w + 10] as f64) as f32;
    let t = 1.0;
    // One frame's column difference has σ ≈ 420 e⁻ (the spot's own shot
    // noise, 316 e⁻, and two columns of dark shot and read noise, 187 e⁻
    // each): 1 % of the spot is 2.4 σ there, 6.7 σ over the mean of 8.
    let frames = 8;
    let got = (0..frames)
        .map(|f| {
            let frame = sensor.expose(&rate, t, f);
            let column = |i: usize| {
                (0..h)
                    .map(|j| frame.dn[j * w + i] as f64 - OFFSET)
                    .sum::<f64>()
            };
            (column(10) - column(11)) / GAIN
        })
        .sum::<f64>()
        / frames as f64;
    assert!((got / spot - 1.0).abs() < 0.01, "{got} e- for {spot}");
    let frame = sensor.expose(&rate, t, 0);
    // The spill is symmetric about the spot: 5 full pixels in a row
    // (full: within 4 read-noise σ of the full well), rows 62 to 66.
    let near_full = OFFSET + GAIN * (FULL_WELL - 4.0 * READ_NOISE);
    let full: Vec<usize> = (0..h)
        .filter(|&j| frame.dn[j * w + 10] as f64 >= near_full)
        .collect();
    assert_eq!(full, vec![62, 63, 64, 65, 66]);
}

#[test]
fn bad_sensor_keys_are_one_line_errors_naming_the_key() {
    let good = flat_text(16, 1, "");
    for (from, to, key) in [
        (
            "read_noise = 8",
            "read_noise = -1",
            "camera.sensor.read_noise",
        ),
        ("prnu = 0.01", "prnu = 1.5", "camera.sensor.prnu"),
        ("offset = 100", "offset = 70000", "camera.sensor.offset"),
        (
            "dark_current = 200",
            "dark_current = nan",
            "camera.sensor.dark_current",
        ),
        (
            "dsnu = 3.0",
            "dsnu = 3.0\ntransfer_time = inf",
            "camera.sensor.transfer_time",
        ),
        ("dsnu = 3.0", "dsnu = 3.0\nsmear = 1", "smear"),
        (
            "dsnu = 3.0",
            "dsnu = 3.0\nnonlinearity = 0.6",
            "camera.sensor.nonlinearity",
        ),
        (
            "dsnu = 3.0",
            "dsnu = 3.0\nrow_noise = -2",
            "camera.sensor.row_noise",
        ),
        ("dsnu = 3.0", "dsnu = 3.0\nshot_noise = 1", "shot_noise"),
    ] {
        assert!(good.contains(from), "{from}");
        let text = good.replace(from, to);
        let err = Scene::from_toml(&text, Path::new("flat.toml"))
            .expect_err(to)
            .to_string();
        assert!(
            err.contains(key) && err.contains("flat.toml"),
            "{to}: {err}"
        );
        assert!(!err.contains('\n'), "{err}");
    }
}

/// The facility camera's effects are `[camera.sensor]` keys too: they
/// reach the sensor's parameters, and are off when absent.
#[test]
fn non_linearity_row_noise_and_shot_noise_keys_reach_the_sensor() {
    let off = flat_scene(16, 1, "").camera.sensor.expect("sensor");
    assert_eq!(
        (off.nonlinearity, off.row_noise, off.shot_noise),
        (0.0, 0.0, true)
    );
    let on = flat_scene(
        16,
        1,
        "nonlinearity = 0.02\nrow_noise = 3.5\nshot_noise = false",
    )
    .camera
    .sensor
    .expect("sensor");
    assert_eq!(
        (on.nonlinearity, on.row_noise, on.shot_noise),
        (0.02, 3.5, false)
    );
}
