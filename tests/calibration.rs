//! The calibration routines against a fake facility written here: a screen
//! with a known analytic level → radiance curve (and optionally a known
//! smooth non-uniformity), a noise-free camera and meter. References are the
//! test's own closed forms, never the routines' output.

use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use optistim::calibration::checkpoint::{fingerprint, Checkpoint};
use optistim::calibration::config::{calibrate_table, CalibrateConfig};
use optistim::calibration::dark::DarkBank;
use optistim::calibration::flat::{self, FlatSetup, POINTS_13};
use optistim::calibration::radiometric::{self, Outputs, Setup};
use optistim::calibration::responsivity::CameraResponsivity;
use optistim::calibration::verify::{self, AbsoluteCamera, VerifySetup};
use optistim::calibration::Instruments;
use optistim::facility::display::Display;
use optistim::facility::geometry::GeometryCalibration;
use optistim::facility::lut::{decode_grey, DisplayLut, FlatField};
use optistim::instruments::{Camera, CameraFrame, CaptureRequest, Shutter, SpotMeter, SpotReading};
use optistim::{Error, Result};

const SCREEN: (usize, usize) = (32, 24);
const CAM: (usize, usize) = (64, 48);
/// Camera DN per (W m⁻² sr⁻¹ · s).
const K: f64 = 1e7;
/// The meter's true mismatch factor: it reads L_eff / F.
const F: f64 = 1.7;

/// The screen's true camera-effective radiance: gamma 2.2 on a shifted
/// base, smooth on [0, 255] (so the interpolation bound below is finite).
fn curve(d: f64) -> f64 {
    1e-3 + 0.6 * ((d + 16.0) / 271.0).powf(2.2)
}

struct Shared {
    frame: Vec<u32>,
    curve: fn(f64) -> f64,
    screen_on: bool,
    ambient: f64,
    /// Screen non-uniformity g(u, v) (u, v in screen px) and the camera's
    /// view: camera pixel → screen (u, v).
    gain: fn(f64, f64) -> f64,
    captures: usize,
    fail_at: Option<usize>,
    stuck_level: Option<u32>,
}

type State = Arc<Mutex<Shared>>;

fn uniform(_: f64, _: f64) -> f64 {
    1.0
}

fn facility(curve: fn(f64) -> f64) -> State {
    Arc::new(Mutex::new(Shared {
        frame: vec![0; SCREEN.0 * SCREEN.1],
        curve,
        screen_on: true,
        ambient: 0.0,
        gain: uniform,
        captures: 0,
        fail_at: None,
        stuck_level: None,
    }))
}

struct FakeScreen(State);
impl Display for FakeScreen {
    fn present(&mut self, frame: &[u32]) -> Result<Instant> {
        self.0.lock().unwrap().frame = frame.to_vec();
        Ok(Instant::now())
    }
    fn is_open(&self) -> bool {
        true
    }
    fn size(&self) -> (usize, usize) {
        SCREEN
    }
}

/// Camera pixel (centre) → screen position: the camera sees the screen
/// scaled by 0.5 with no distortion.
fn cam_to_screen(i: usize, j: usize) -> (f64, f64) {
    ((i as f64 + 0.5) * 0.5, (j as f64 + 0.5) * 0.5)
}

/// The camera's direction of a pixel position (no distortion, 1000 px
/// focal length, principal point at the centre).
fn cam_direction(x: f64, y: f64) -> (f64, f64) {
    ((x - 32.0) / 1000.0, (y - 24.0) / 1000.0)
}

/// The camera's own flat: 5 % vignetting toward the left and right edges
/// and ±1 % pixel response non-uniformity (a fixed hash pattern).
fn camera_flat(i: usize, j: usize) -> f64 {
    let x = (i as f64 + 0.5 - 32.0) / 32.0;
    let h = ((i * 7919 + j * 104_729) % 1000) as f64 / 500.0 - 1.0;
    (1.0 - 0.05 * x * x) * (1.0 + 0.01 * h)
}

struct FakeCamera(State);
impl Camera for FakeCamera {
    fn capture(&mut self, r: &CaptureRequest) -> Result<CameraFrame> {
        let mut s = self.0.lock().unwrap();
        s.captures += 1;
        if Some(s.captures) == s.fail_at {
            return Err(Error::Other(format!("injected fault at `{}`", r.pattern)));
        }
        let mut data = vec![0f32; CAM.0 * CAM.1];
        for j in 0..CAM.1 {
            for i in 0..CAM.0 {
                let (u, v) = cam_to_screen(i, j);
                let level = decode_grey(s.frame[(v as usize) * SCREEN.0 + u as usize], 8);
                let light = r.shutter == Shutter::Open;
                let l = if s.screen_on && light {
                    (s.curve)(level as f64) * (s.gain)(u, v)
                } else {
                    0.0
                };
                let (tx, ty) = cam_direction(i as f64 + 0.5, j as f64 + 0.5);
                let cos4 = 1.0 / (1.0 + tx * tx + ty * ty).powi(2);
                let ambient = if light { s.ambient } else { 0.0 };
                let e = (l + ambient) * K * r.exposure_s * cos4 * camera_flat(i, j);
                let mut dn = e.min(65535.0);
                if light && s.stuck_level == Some(level) {
                    dn = 65535.0;
                }
                data[j * CAM.0 + i] = dn as f32;
            }
        }
        Ok(CameraFrame {
            width: CAM.0,
            height: CAM.1,
            data,
            exposure_s: r.exposure_s,
            saturation_dn: 65535.0,
        })
    }
    fn describe(&self) -> String {
        "fake camera".into()
    }
}

struct FakeMeter(State);
impl SpotMeter for FakeMeter {
    fn measure(&mut self) -> Result<SpotReading> {
        // Its spot: screen pixels u 8..24, v 8..16 (whole dither tiles).
        let s = self.0.lock().unwrap();
        let mut sum = 0.0;
        for v in 8..16 {
            for u in 8..24 {
                let level = decode_grey(s.frame[v * SCREEN.0 + u], 8) as f64;
                if s.screen_on {
                    sum += (s.curve)(level) * (s.gain)(u as f64 + 0.5, v as f64 + 0.5);
                }
            }
        }
        let l = sum / 128.0;
        Ok(SpotReading {
            value: (l + s.ambient) / F,
            spectrum: None,
        })
    }
    fn describe(&self) -> String {
        "fake meter".into()
    }
}

const CONFIG: &str = r#"
[calibrate]
levels = 17
repeats = 2
settle = 0.0
region = [0.25, 0.34, 0.5, 0.3333]
mismatch_factor = 1.7
ambient = "AMBIENT"

[calibrate.camera]
kind = "sim"
exposure = 0.01
saturation_dn = 65535
resolution = [64, 48]
dark = "shutter"
"#;

fn config(ambient: &str) -> (String, CalibrateConfig) {
    let text = CONFIG.replace("AMBIENT", ambient);
    let cfg = CalibrateConfig::parse(&text, "test.toml", 8).unwrap();
    (text, cfg)
}

/// Runs the radiometric routine on `state`; returns the report and the LUT
/// path.
fn calibrate(
    state: &State,
    text: &str,
    cfg: &CalibrateConfig,
    dir: &Path,
    resume: bool,
) -> Result<radiometric::Report> {
    let fp = fingerprint(
        &calibrate_table(text, Path::new("t")).unwrap(),
        radiometric::ROUTINE,
        SCREEN,
        8,
    );
    let mut ckpt = Checkpoint::open(&dir.join("radiometric.jsonl"), &fp, "radiometric", resume)?;
    let (mut screen, mut camera, mut meter) = (
        FakeScreen(state.clone()),
        FakeCamera(state.clone()),
        FakeMeter(state.clone()),
    );
    let power_state = state.clone();
    let mut power = move |on: bool| -> Result<()> {
        power_state.lock().unwrap().screen_on = on;
        Ok(())
    };
    let mut wait = |_s: f64| {};
    let mut darks = DarkBank::shutter(2);
    let mut inst = Instruments {
        display: &mut screen,
        camera: &mut camera,
        meter: Some(&mut meter),
        darks: &mut darks,
        wait: &mut wait,
    };
    let mut setup = Setup {
        cfg,
        bits: 8,
        spectral: None,
        meter_response: None,
        screen_spectrum: None,
        spectroradiometer: None,
        screen_power: Some(&mut power),
        source: "test".into(),
    };
    let report = radiometric::run(&mut inst, &mut setup, &mut ckpt)?;
    radiometric::write(&report, &setup, &Outputs::in_dir(dir))?;
    Ok(report)
}

/// Bound on |PCHIP − f| at every integer level for the measured levels
/// `x`, from the test's own analysis: cubic Hermite with exact slopes errs
/// by ≤ h⁴/384·max|f⁗|; a slope error δ adds ≤ (4/27)·h·δ per end; PCHIP's
/// interior slope lies between the adjacent secants (δ ≤ max|f''|·max h),
/// its three-point end slope has δ ≤ max|f''|·(2h₀ + h₁).
fn pchip_bound(x: &[f64], d: f64) -> f64 {
    // For this curve |f''| increases and |f⁗| decreases with d.
    let a = 0.6 / 271f64.powf(2.2);
    let f2 = |d: f64| a * 2.2 * 1.2 * (d + 16.0).powf(0.2);
    let f4 = |d: f64| a * 2.2 * 1.2 * 0.2 * 0.8 * (d + 16.0).powf(-1.8);
    let n = x.len();
    let i = x.partition_point(|&v| v <= d).clamp(1, n - 1) - 1;
    let h = |k: usize| x[k + 1] - x[k];
    let m2 = f2(x[(i + 2).min(n - 1)]);
    let delta = |k: usize| {
        if k == 0 {
            m2 * (2.0 * h(0) + h(1))
        } else if k == n - 1 {
            m2 * (2.0 * h(n - 2) + h(n - 3))
        } else {
            m2 * h(k - 1).max(h(k))
        }
    };
    let hi = h(i);
    hi.powi(4) / 384.0 * f4(x[i]) + 4.0 / 27.0 * hi * (delta(i) + delta(i + 1))
}

#[test]
fn lut_reproduces_a_known_curve_within_the_pchip_bound_and_loads_in_run() {
    let dir = tempfile::tempdir().unwrap();
    let (text, cfg) = config("none");
    let state = facility(curve);
    let report = calibrate(&state, &text, &cfg, dir.path(), false).unwrap();
    let lut = DisplayLut::load(dir.path().join("lut.csv"), 8).unwrap();
    let x: Vec<f64> = report.levels.iter().map(|l| l.level as f64).collect();
    assert_eq!(x.len(), 17);
    for l in &report.levels {
        let truth = curve(l.level as f64);
        assert!(
            (lut.radiance(l.level as f64) / truth - 1.0).abs() < 1e-6,
            "level {}: {} vs {truth}",
            l.level,
            lut.radiance(l.level as f64)
        );
    }
    for d in 0..=255 {
        let d = d as f64;
        let err = (lut.radiance(d) - curve(d)).abs();
        let bound = pchip_bound(&x, d);
        assert!(
            err <= bound,
            "level {d}: error {err:e} above the bound {bound:e}"
        );
    }
    let text = std::fs::read_to_string(dir.path().join("lut.csv")).unwrap();
    assert!(
        text.contains("# quantity: camera-effective radiance"),
        "{text}"
    );
    assert!(text.contains("repeats: 2"), "{text}");
    assert!((report.mismatch_factor.unwrap() - F).abs() < 1e-12);
    assert!(report.drift_percent.abs() < 1e-9);
    assert!(dir.path().join("radiometric.png").exists());
    let json: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("radiometric_report.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(json["levels"].as_array().unwrap().len(), 17);
    if let Some(keep) = std::env::var_os("OPTISTIM_KEEP_FIGURES") {
        std::fs::copy(
            dir.path().join("radiometric.png"),
            Path::new(&keep).join("radiometric.png"),
        )
        .unwrap();
    }
}

#[test]
fn ambient_light_is_measured_with_the_screen_off_and_subtracted() {
    let dir = tempfile::tempdir().unwrap();
    let (text, cfg) = config("prompt");
    let state = facility(curve);
    state.lock().unwrap().ambient = 0.004;
    let report = calibrate(&state, &text, &cfg, dir.path(), false).unwrap();
    assert!(state.lock().unwrap().screen_on, "screen left off");
    let amb = report.ambient_radiance.unwrap();
    assert!((amb / 0.004 - 1.0).abs() < 1e-6, "ambient {amb}");
    for l in &report.levels {
        let truth = curve(l.level as f64);
        assert!((l.radiance / truth - 1.0).abs() < 1e-6, "level {}", l.level);
    }
}

/// A screen whose level 143 is darker than level 100 (a broken LUT in the
/// monitor): refused, naming both levels.
#[test]
fn non_monotone_response_is_refused_naming_the_levels() {
    fn dip(d: f64) -> f64 {
        if (d - 143.0).abs() < 0.5 {
            0.5 * curve(100.0)
        } else {
            curve(d)
        }
    }
    let dir = tempfile::tempdir().unwrap();
    let (text, mut cfg) = config("none");
    cfg.levels = 9; // ladder 0 4 16 36 64 100 143 195 255
    let e = calibrate(&facility(dip), &text, &cfg, dir.path(), false)
        .unwrap_err()
        .to_string();
    assert!(e.contains("not monotone"), "{e}");
    assert!(e.contains("level 143") && e.contains("level 100"), "{e}");
}

#[test]
fn a_saturated_patch_is_an_error_naming_pattern_and_level() {
    let dir = tempfile::tempdir().unwrap();
    let (text, cfg) = config("none");
    let state = facility(curve);
    state.lock().unwrap().stuck_level = Some(64);
    let e = calibrate(&state, &text, &cfg, dir.path(), false)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("level_0064_r") && e.contains("drive level 64"),
        "{e}"
    );
    assert!(e.contains("saturated"), "{e}");
}

/// A campaign killed halfway (the camera fails on its 20th capture)
/// resumes from the checkpoint, takes only the missing patterns, and ends
/// with the same LUT as an uninterrupted campaign.
#[test]
fn a_campaign_killed_halfway_resumes_to_the_same_result() {
    let (text, cfg) = config("none");
    let clean_dir = tempfile::tempdir().unwrap();
    let clean_state = facility(curve);
    calibrate(&clean_state, &text, &cfg, clean_dir.path(), false).unwrap();
    let clean_captures = clean_state.lock().unwrap().captures;

    let dir = tempfile::tempdir().unwrap();
    let state = facility(curve);
    state.lock().unwrap().fail_at = Some(20);
    let e = calibrate(&state, &text, &cfg, dir.path(), false).unwrap_err();
    assert!(e.to_string().contains("injected fault"), "{e}");
    // Without --resume the checkpoint is protected.
    let again = facility(curve);
    assert!(calibrate(&again, &text, &cfg, dir.path(), false).is_err());
    let resumed = facility(curve);
    calibrate(&resumed, &text, &cfg, dir.path(), true).unwrap();
    let taken = resumed.lock().unwrap().captures;
    assert!(
        taken < clean_captures,
        "{taken} captures on resume, {clean_captures} clean"
    );
    let strip = |p: &Path| {
        std::fs::read_to_string(p)
            .unwrap()
            .lines()
            .filter(|l| !l.starts_with("# date"))
            .map(String::from)
            .collect::<Vec<_>>()
    };
    // The same LUT: identical text but for the last digit a JSON round
    // trip of the checkpointed values may change.
    let (a, b) = (
        strip(&clean_dir.path().join("lut.csv")),
        strip(&dir.path().join("lut.csv")),
    );
    assert_eq!(a.len(), b.len());
    for (la, lb) in a.iter().zip(&b) {
        match (la.split_once(','), lb.split_once(',')) {
            (Some((xa, ya)), Some((xb, yb))) if !la.starts_with('#') && xa != "drive_level" => {
                assert_eq!(xa, xb);
                let first = |s: &str| s.split(',').next().unwrap().parse::<f64>().unwrap();
                let (ya, yb): (f64, f64) = (first(ya), first(yb));
                assert!((ya / yb - 1.0).abs() < 1e-12, "{la} vs {lb}");
            }
            _ => assert_eq!(la, lb),
        }
    }
    // A different campaign's checkpoint is refused.
    let (text2, mut cfg2) = config("none");
    cfg2.levels = 9;
    let text2 = text2.replace("levels = 17", "levels = 9");
    let e = calibrate(&facility(curve), &text2, &cfg2, dir.path(), true).unwrap_err();
    assert!(e.to_string().contains("different campaign"), "{e}");
}

/// The screen's known smooth non-uniformity (normalised coordinates).
fn nonuniform(u: f64, v: f64) -> f64 {
    let (s, t) = (
        2.0 * u / SCREEN.0 as f64 - 1.0,
        2.0 * v / SCREEN.1 as f64 - 1.0,
    );
    1.0 + 0.03 * s - 0.02 * t * t + 0.01 * s * t
}

/// The geometry file of the fake view: screen (u, v) is seen at camera
/// pixel (2u, 2v), so tan = ((2u − 32)/1000, (2v − 24)/1000).
fn geometry(dir: &Path) -> GeometryCalibration {
    let mut text = String::from("u_px,v_px,tan_x,tan_y\n");
    for v in (0..=24).step_by(4) {
        for u in (0..=32).step_by(4) {
            let (tx, ty) = cam_direction(2.0 * u as f64, 2.0 * v as f64);
            text.push_str(&format!("{u},{v},{tx:?},{ty:?}\n"));
        }
    }
    let p = dir.join("geometry.csv");
    std::fs::write(&p, text).unwrap();
    GeometryCalibration::load(&p, SCREEN).unwrap()
}

fn run_flat(
    state: &State,
    cfg: &CalibrateConfig,
    dir: &Path,
    with_camera_flat: bool,
) -> (Vec<f32>, flat::FlatReport) {
    let g = geometry(dir);
    let cam_flat: Vec<f32> = (0..CAM.0 * CAM.1)
        .map(|k| camera_flat(k % CAM.0, k / CAM.0) as f32)
        .collect();
    let dirf = |x: f64, y: f64| cam_direction(x, y);
    let setup = FlatSetup {
        cfg,
        bits: 8,
        screen: SCREEN,
        pixel_direction: &dirf,
        geometry: &g,
        camera_flat: with_camera_flat.then_some(cam_flat),
    };
    let name = if with_camera_flat {
        "flat.jsonl"
    } else {
        "flat_nocam.jsonl"
    };
    let mut ckpt = Checkpoint::open(&dir.join(name), "fp", "flat", false).unwrap();
    let (mut screen, mut camera) = (FakeScreen(state.clone()), FakeCamera(state.clone()));
    let mut wait = |_s: f64| {};
    let mut darks = DarkBank::shutter(2);
    let mut inst = Instruments {
        display: &mut screen,
        camera: &mut camera,
        meter: None,
        darks: &mut darks,
        wait: &mut wait,
    };
    flat::run(&mut inst, &setup, &mut ckpt).unwrap()
}

/// The flat field recovers a known smooth non-uniformity, normalised to
/// mean 1 over the screen area of the radiometric region, after removing
/// the camera's own vignetting and PRNU with its flat; the TIFF loads as
/// `calibration.flat_field`.
#[test]
fn flat_field_recovers_a_known_non_uniformity() {
    let dir = tempfile::tempdir().unwrap();
    let (_, cfg) = config("none");
    let state = facility(curve);
    state.lock().unwrap().gain = nonuniform;
    let (gains, report) = run_flat(&state, &cfg, dir.path(), true);
    // Reference: mean of g over the screen positions of the region's
    // camera pixel centres (camera x 16..48, y 16..32).
    let (mut sum, mut n) = (0.0, 0.0);
    for j in 16..32 {
        for i in 16..48 {
            sum += nonuniform((i as f64 + 0.5) / 2.0, (j as f64 + 0.5) / 2.0);
            n += 1.0;
        }
    }
    let norm = sum / n;
    // The camera pixels used: all but the outermost ring (they may see
    // the bezel), i.e. screen centres 0.75 … 31.25 × 0.75 … 23.25.
    let seen = [0.75, 0.75, 31.25, 23.25];
    for (a, b) in report.seen.iter().zip(seen) {
        assert!((a - b).abs() < 1e-6, "{:?}", report.seen);
    }
    let mut worst = 0.0f64;
    for (k, g) in gains.iter().enumerate() {
        let (u, v) = ((k % SCREEN.0) as f64 + 0.5, (k / SCREEN.0) as f64 + 0.5);
        if u >= seen[0] && u <= seen[2] && v >= seen[1] && v <= seen[3] {
            worst = worst.max((*g as f64 / (nonuniform(u, v) / norm) - 1.0).abs());
        }
    }
    assert!(worst < 3e-4, "worst relative gain error {worst:e}");
    let p = dir.path().join("flat.tif");
    flat::write_tiff(&p, &gains, SCREEN).unwrap();
    let ff = FlatField::load(&p, SCREEN).unwrap();
    assert_eq!(ff.size(), SCREEN);
    // The 13-point figure at the documented points of the seen area.
    let g13: Vec<f64> = POINTS_13
        .iter()
        .map(|&(a, b)| nonuniform(0.75 + 30.5 * a, 0.75 + 22.5 * b))
        .collect();
    let max = g13.iter().cloned().fold(0.0, f64::max);
    let min = g13.iter().cloned().fold(f64::INFINITY, f64::min);
    let expect = 100.0 * (1.0 - min / max);
    assert!(
        (report.nonuniformity_13_percent - expect).abs() < 0.02,
        "{} vs {expect}",
        report.nonuniformity_13_percent
    );
    let png = dir.path().join("flat.png");
    flat::write_report(&report, &gains, SCREEN, &dir.path().join("flat.json"), &png).unwrap();
    if let Some(keep) = std::env::var_os("OPTISTIM_KEEP_FIGURES") {
        std::fs::copy(&png, Path::new(&keep).join("flat.png")).unwrap();
    }
    // Without the camera's own flat its vignetting is taken for the
    // screen's: the map is wrong by about the 5 % vignetting.
    let (bad, _) = run_flat(&state, &cfg, dir.path(), false);
    let mut worst_bad = 0.0f64;
    for (k, g) in bad.iter().enumerate() {
        let (u, v) = ((k % SCREEN.0) as f64 + 0.5, (k / SCREEN.0) as f64 + 0.5);
        worst_bad = worst_bad.max((*g as f64 / (nonuniform(u, v) / norm) - 1.0).abs());
    }
    assert!(worst_bad > 0.02, "{worst_bad}");
}

fn run_verify(
    state: &State,
    cfg: &CalibrateConfig,
    lut: DisplayLut,
    report: &radiometric::Report,
    dir: &Path,
) -> verify::VerifyReport {
    // The camera's lab responsivity: K DN/s per W m⁻² sr⁻¹ at the centre
    // (no collimator loss in this fake facility), declared to 0.5 %.
    let flat: Vec<f32> = (0..CAM.0 * CAM.1)
        .map(|k| camera_flat(k % CAM.0, k / CAM.0) as f32)
        .collect();
    let setup = VerifySetup {
        cfg,
        lut,
        flat: None,
        screen: SCREEN,
        camera_scale: report.scale,
        camera: AbsoluteCamera {
            responsivity: CameraResponsivity {
                responsivity_dn_per_s_per_w_m2_sr: K,
                uncertainty_k2_percent: 0.5,
            },
            transmission: 1.0,
            camera_flat: flat,
            pixel_direction: &cam_direction,
        },
        mismatch_factor: report.mismatch_factor,
        mismatch_by_level: None,
        spectral: None,
        meter_uncertainty_k2_percent: Some(1.0),
        lut_scale_k2_percent: Some(report.budget.scale_total()),
    };
    let mut ckpt = Checkpoint::open(&dir.join("verify.jsonl"), "fp", "verify", false).unwrap();
    let (mut screen, mut camera, mut meter) = (
        FakeScreen(state.clone()),
        FakeCamera(state.clone()),
        FakeMeter(state.clone()),
    );
    let mut wait = |_s: f64| {};
    let mut darks = DarkBank::shutter(2);
    let mut inst = Instruments {
        display: &mut screen,
        camera: &mut camera,
        meter: Some(&mut meter),
        darks: &mut darks,
        wait: &mut wait,
    };
    verify::run(&mut inst, &setup, &mut ckpt).unwrap()
}

/// Verify drives target radiances through the run's converter: with the
/// calibrated LUT the patches land within 1 % (the test's reference is the
/// fake screen's own curve, the targets are radiances); with a LUT 10 %
/// too bright every patch is ~9 % short and the verification fails.
#[test]
fn verify_passes_a_good_lut_and_fails_a_wrong_one() {
    let dir = tempfile::tempdir().unwrap();
    let (text, cfg) = config("none");
    let state = facility(curve);
    let report = calibrate(&state, &text, &cfg, dir.path(), false).unwrap();
    let lut = DisplayLut::load(dir.path().join("lut.csv"), 8).unwrap();
    let good = run_verify(&state, &cfg, lut.clone(), &report, &dir.path().join("good"));
    assert!(good.passed, "{}", verify::summary(&good));
    println!("{}", verify::summary(&good));
    // Noise-free: the spots read the fake screen through K exactly; what
    // is left is the LUT's interpolation between its 17 levels.
    assert!(good.max_error_percent < 0.1, "{}", verify::summary(&good));
    let png = dir.path().join("verify.png");
    verify::plot(&good, &png).unwrap();
    assert!(std::fs::metadata(&png).unwrap().len() > 10_000);
    if let Ok(keep) = std::env::var("OPTISTIM_KEEP_FIGURES") {
        std::fs::copy(&png, Path::new(&keep).join("verify_good.png")).unwrap();
    }
    // Drift levels 64 and 255 were measured; 128 is interpolated, so it
    // may differ by the PCHIP bound.
    let x: Vec<f64> = report.levels.iter().map(|l| l.level as f64).collect();
    for d in &good.drift {
        let allowed = 100.0 * pchip_bound(&x, d.level as f64) / curve(d.level as f64) + 1e-4;
        assert!(
            d.drift_percent.abs() <= allowed,
            "{}",
            verify::summary(&good)
        );
    }
    let levels: Vec<f64> = (0..=255).map(|d| d as f64).collect();
    let bright: Vec<f64> = levels.iter().map(|&d| 1.1 * lut.radiance(d)).collect();
    let wrong = DisplayLut::from_points(&levels, &bright, 8).unwrap();
    let bad = run_verify(&state, &cfg, wrong, &report, &dir.path().join("bad"));
    assert!(!bad.passed);
    if let Ok(keep) = std::env::var("OPTISTIM_KEEP_FIGURES") {
        verify::plot(&bad, &Path::new(&keep).join("verify_bad.png")).unwrap();
    }
    // 1/1.1 − 1 = −9.09 % at every spot and the meter.
    for p in &bad.patches {
        for e in p
            .spots
            .iter()
            .map(|s| s.error_percent)
            .chain(p.meter_error_percent)
        {
            assert!((e + 9.09).abs() < 0.5, "{}", verify::summary(&bad));
        }
    }
}
