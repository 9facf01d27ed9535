//! The geometric calibration end to end on a screen and camera simulated
//! here, with this file's own forward model (collimator distortion, screen
//! offset, rotation and tilt, camera intrinsics with OpenCV distortion, a
//! Gaussian camera blur): the geometry file it writes must give the true
//! directions to 0.05 camera px, also with missing and spurious dots; too
//! few dots must be a clear error.

use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use optistim::calibration::geometric::{calibrate_geometric, GeometricConfig, GRID_PATTERN};
use optistim::facility::display::Display;
use optistim::facility::geometry::GeometryCalibration;
use optistim::instruments::{Camera, CameraFrame, CaptureRequest};

mod common;

const SCREEN: (usize, usize) = (960, 640);
const CAMERA: (usize, usize) = (1024, 768);
/// Collimator focal length in screen pixels (tan = offset / F).
const F_COLL: f64 = 4000.0;

/// The camera's intrinsics, OpenCV convention (pixel centres at integers).
struct Cam {
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    k1: f64,
    k2: f64,
    p1: f64,
    p2: f64,
}

const CAM: Cam = Cam {
    fx: 0.9 * F_COLL,
    fy: 0.9 * F_COLL * 1.001,
    cx: 515.3,
    cy: 380.6,
    k1: -0.35,
    k2: 0.8,
    p1: 4e-4,
    p2: -2e-4,
};

/// The truth: where the camera sees screen point (u, v), as (tan_x,
/// tan_y). The collimator's barrel distortion acts on the screen-plane
/// position about its axis (offset from the screen centre), then the
/// screen's tilt and rotation relative to the camera make a projective
/// map of those directions.
fn truth(u: f64, v: f64) -> [f64; 2] {
    let (ax, ay) = (SCREEN.0 as f64 / 2.0 + 6.5, SCREEN.1 as f64 / 2.0 - 4.25);
    let (x, y) = ((u - ax) / F_COLL, (v - ay) / F_COLL);
    let r2 = x * x + y * y;
    let g = 1.0 - 2.5 * r2 + 40.0 * r2 * r2;
    let (x, y) = (x * g, y * g);
    let rot: f64 = 0.012;
    let (c, s) = (rot.cos(), rot.sin());
    let (x, y) = (c * x - s * y, s * x + c * y);
    let den = 1.0 + 0.15 * x - 0.1 * y;
    [(x + 1e-3) / den, (y - 5e-4) / den]
}

/// OpenCV projection, written out: direction → camera pixel in the
/// project's convention (centres at +0.5).
fn project(t: [f64; 2]) -> [f64; 2] {
    let (x, y) = (t[0], t[1]);
    let r2 = x * x + y * y;
    let rad = 1.0 + CAM.k1 * r2 + CAM.k2 * r2 * r2;
    let xd = x * rad + 2.0 * CAM.p1 * x * y + CAM.p2 * (r2 + 2.0 * x * x);
    let yd = y * rad + CAM.p1 * (r2 + 2.0 * y * y) + 2.0 * CAM.p2 * x * y;
    [CAM.fx * xd + CAM.cx + 0.5, CAM.fy * yd + CAM.cy + 0.5]
}

fn write_intrinsics(dir: &Path) -> std::path::PathBuf {
    let p = dir.join("intrinsics.toml");
    std::fs::write(
        &p,
        intrinsics_toml(
            CAMERA,
            [CAM.fx, CAM.fy, CAM.cx, CAM.cy],
            [CAM.k1, CAM.k2, CAM.p1, CAM.p2],
        ),
    )
    .unwrap();
    p
}

/// An intrinsics file (docs/INSTRUMENTS.md), K in OpenCV's convention.
fn intrinsics_toml(size: (usize, usize), k: [f64; 4], d: [f64; 4]) -> String {
    format!(
        "width = {}\nheight = {}\ncamera_matrix = [[{}, 0.0, {}], [0.0, {}, {}], [0.0, 0.0, 1.0]]\n\
         distortion = [{}, {}, {}, {}, 0.0]\n",
        size.0, size.1, k[0], k[2], k[1], k[3], d[0], d[1], d[2], d[3]
    )
}

/// What the screen shows, shared by the display and camera handles.
#[derive(Default)]
struct Shared {
    frame: Vec<u32>,
}

struct TestDisplay(Arc<Mutex<Shared>>);

impl Display for TestDisplay {
    fn present(&mut self, frame: &[u32]) -> optistim::Result<Instant> {
        assert_eq!(frame.len(), SCREEN.0 * SCREEN.1);
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

/// Images the screen: every lit screen pixel's level, times a gain, is
/// splatted bilinearly at the camera pixel its centre projects to, then
/// blurred by a Gaussian of σ = 0.8 px; a dark offset is added.
struct TestCamera {
    screen: Arc<Mutex<Shared>>,
    /// Screen cells (48 × 48 px) whose light never reaches the camera.
    dropped: fn(usize, usize) -> bool,
    /// Extra blobs `(x, y, σ, peak)` in the frames of these patterns.
    spurious: Vec<(&'static str, [f64; 4])>,
    /// Camera focal-length factor (1: as CAM; larger sees less screen).
    zoom: f64,
    /// DN at which a pixel saturates.
    saturation: f32,
}

impl TestCamera {
    fn new(screen: Arc<Mutex<Shared>>) -> TestCamera {
        TestCamera {
            screen,
            dropped: |_, _| false,
            spurious: Vec::new(),
            zoom: 1.0,
            saturation: 1e9,
        }
    }
}

fn splat(img: &mut [f64], p: [f64; 2], value: f64) {
    let (w, h) = CAMERA;
    let (x, y) = (p[0] - 0.5, p[1] - 0.5);
    let (i, j) = (x.floor(), y.floor());
    if i < 0.0 || j < 0.0 || i + 1.0 >= w as f64 || j + 1.0 >= h as f64 {
        return;
    }
    let (fx, fy) = (x - i, y - j);
    let k = j as usize * w + i as usize;
    img[k] += value * (1.0 - fx) * (1.0 - fy);
    img[k + 1] += value * fx * (1.0 - fy);
    img[k + w] += value * (1.0 - fx) * fy;
    img[k + w + 1] += value * fx * fy;
}

fn blur(img: &[f64]) -> Vec<f64> {
    let (w, h) = CAMERA;
    let k: Vec<f64> = (-3i32..=3)
        .map(|d| (-0.5 * (d as f64 / 0.8).powi(2)).exp())
        .collect();
    let sum: f64 = k.iter().sum();
    let pass = |src: &[f64], dx: usize, dy: usize| {
        let mut out = vec![0.0; w * h];
        for y in 3..h - 3 {
            for x in 3..w - 3 {
                let mut s = 0.0;
                for (t, kv) in k.iter().enumerate() {
                    let o = t as isize - 3;
                    let (xx, yy) = (x as isize + o * dx as isize, y as isize + o * dy as isize);
                    s += kv * src[yy as usize * w + xx as usize];
                }
                out[y * w + x] = s / sum;
            }
        }
        out
    };
    pass(&pass(img, 1, 0), 0, 1)
}

impl Camera for TestCamera {
    fn capture(&mut self, request: &CaptureRequest) -> optistim::Result<CameraFrame> {
        let frame = self.screen.lock().unwrap().frame.clone();
        let (w, h) = CAMERA;
        let mut img = vec![0.0f64; w * h];
        for v in 0..SCREEN.1 {
            for u in 0..SCREEN.0 {
                let level = (frame[v * SCREEN.0 + u] >> 8) & 0xff;
                if level == 0 || (self.dropped)(u / 48, v / 48) {
                    continue;
                }
                let t = truth(u as f64 + 0.5, v as f64 + 0.5);
                let t = [t[0] * self.zoom, t[1] * self.zoom];
                splat(&mut img, project(t), level as f64 * 20.0);
            }
        }
        for (pattern, [x, y, s, peak]) in &self.spurious {
            if *pattern == request.pattern {
                for j in 0..h {
                    for i in 0..w {
                        let r2 = (i as f64 + 0.5 - x).powi(2) + (j as f64 + 0.5 - y).powi(2);
                        img[j * w + i] += peak * (-0.5 * r2 / (s * s)).exp();
                    }
                }
            }
        }
        let img = blur(&img);
        Ok(CameraFrame {
            width: w,
            height: h,
            data: img.iter().map(|&v| (v + 100.0) as f32).collect(),
            exposure_s: request.exposure_s,
            saturation_dn: self.saturation,
        })
    }
    fn describe(&self) -> String {
        "test camera (tests/calibration_geometric.rs)".into()
    }
}

fn config(dir: &Path) -> GeometricConfig {
    let mut cfg = GeometricConfig::with_intrinsics(write_intrinsics(dir));
    cfg.spacing_px = 48;
    cfg.radius_px = 3.0;
    cfg.settle = 0.0;
    cfg
}

/// Error of the written geometry against the truth, camera px (RMS, max),
/// over the screen region the dots cover, and max over the whole screen.
fn geometry_error(csv: &Path) -> (f64, f64, f64) {
    let g = GeometryCalibration::load(csv, SCREEN).unwrap();
    let (mut ss, mut n, mut max_in, mut max_all) = (0.0, 0usize, 0.0f64, 0.0f64);
    for j in 0..=64 {
        for i in 0..=96 {
            let (u, v) = (i as f64 * 10.0, j as f64 * 10.0);
            let (a, b) = (g.direction(u, v), truth(u, v));
            let e = (a[0] - b[0]).hypot(a[1] - b[1]) * CAM.fx;
            max_all = max_all.max(e);
            if (24.0..=936.0).contains(&u) && (32.0..=608.0).contains(&v) {
                ss += e * e;
                n += 1;
                max_in = max_in.max(e);
            }
        }
    }
    ((ss / n as f64).sqrt(), max_in, max_all)
}

#[test]
fn recovers_the_true_geometry() {
    let dir = tempfile::tempdir().unwrap();
    let shared = Arc::new(Mutex::new(Shared::default()));
    let mut display = TestDisplay(shared.clone());
    let mut camera = TestCamera::new(shared);
    let cfg = config(dir.path());
    let report = calibrate_geometric(&mut display, &mut camera, &cfg, dir.path()).unwrap();
    let (rms, max_in, max_all) = geometry_error(&report.geometry_csv);
    eprintln!(
        "noise-free: geometry error RMS {rms:.4} px, max {max_in:.4} px over the dots, {max_all:.4} px over the screen; \
         fit residual RMS {:.4} px ({:.3} arcsec), {} of {} dots used",
        report.rms_px, report.rms_arcsec, report.dots_used, report.dots_shown
    );
    assert!(rms < 0.05, "geometry RMS error {rms} camera px");
    assert!(max_in < 0.15, "geometry max error {max_in} camera px");
    assert_eq!(report.dots_shown, 20 * 13);
    assert_eq!(report.dots_matched, report.dots_shown);
    assert_eq!(report.anchors_identified, 9);
    assert!(report.rms_px < 0.05);
    // Arcsec and px agree through the camera's scale (1 px = 206265/fx arcsec).
    let scale = 206_264.8 / CAM.fx;
    assert!((report.rms_arcsec / report.rms_px / scale - 1.0).abs() < 0.1);
    // The report is on disk and says the same.
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report.report_json).unwrap()).unwrap();
    assert_eq!(json["dots_used"], report.dots_used);
    let csv = std::fs::read_to_string(&report.geometry_csv).unwrap();
    assert!(csv.starts_with("# optistim geometric calibration"));
    assert!(csv.contains("# camera: test camera"));
    // The lattice: every 32 px and the edges.
    assert!(csv.contains("\n960,640,"), "the screen corner is a node");
    assert!(csv.contains("\n32,0,"));
}

#[test]
fn missing_and_spurious_dots() {
    let dir = tempfile::tempdir().unwrap();
    let shared = Arc::new(Mutex::new(Shared::default()));
    let mut display = TestDisplay(shared.clone());
    let mut camera = TestCamera::new(shared);
    // About 10 % of the dots never reach the camera (a fixed hash of
    // their cell), and one of them is an anchor.
    camera.dropped = |i, j| (i * 7 + j * 13) % 10 == 3;
    // Five spurious blobs in the grid frame: three dot-like ones between
    // dots, a large glow where a dot is missing (over dots, it would swallow
    // them) and a small bright speck; and a dot-like blob as bright as a
    // dot in the first anchor's frame (ambiguous: skipped).
    let at = |u: f64, v: f64| project(truth(u, v));
    let (a, b, c) = (at(48.0, 56.0), at(480.0, 320.0), at(720.0, 536.0));
    let (glow, speck) = (at(120.0, 176.0), at(696.0, 104.0));
    camera.spurious = vec![
        (GRID_PATTERN, [a[0], a[1], 2.8, 5000.0]),
        (GRID_PATTERN, [b[0], b[1], 2.8, 5000.0]),
        (GRID_PATTERN, [c[0], c[1], 2.8, 3000.0]),
        (GRID_PATTERN, [glow[0], glow[1], 10.0, 800.0]),
        (GRID_PATTERN, [speck[0], speck[1], 0.5, 3000.0]),
        ("geometric_anchor_0", [900.0, 700.0, 2.8, 5000.0]),
    ];
    let cfg = config(dir.path());
    let report = calibrate_geometric(&mut display, &mut camera, &cfg, dir.path()).unwrap();
    let (rms, max_in, _) = geometry_error(&report.geometry_csv);
    let missing = (0..13)
        .flat_map(|j| (0..20).map(move |i| (i, j)))
        .filter(|&(i, j)| (i * 7 + j * 13) % 10 == 3)
        .count();
    eprintln!(
        "{missing} dots missing, 5 spurious blobs: geometry error RMS {rms:.4} px, max {max_in:.4} px; \
         {} matched, {} used, anchors {} of 9",
        report.dots_matched, report.dots_used, report.anchors_identified
    );
    assert!(missing >= 20, "{missing}");
    assert_eq!(
        report.dots_matched,
        260 - missing,
        "every present dot, nothing spurious"
    );
    // Every matched dot is where the truth puts it: correctly identified.
    for d in &report.dots {
        let p = project(truth(d.u_px, d.v_px));
        assert!((p[0] - d.x_px).hypot(p[1] - d.y_px) < 0.1, "{d:?}");
    }
    assert!(report.anchors_identified <= 8);
    assert!(rms < 0.05, "geometry RMS error {rms} camera px");
    assert!(max_in < 0.15, "geometry max error {max_in} camera px");
}

#[test]
fn too_few_dots_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let shared = Arc::new(Mutex::new(Shared::default()));
    let mut display = TestDisplay(shared.clone());
    // The camera sees the central ~70 % of the screen: every anchor but
    // only about half of the dots.
    let mut camera = TestCamera::new(shared.clone());
    camera.zoom = 1.6;
    let mut cfg = config(dir.path());
    cfg.min_dots = 200;
    let e = calibrate_geometric(&mut display, &mut camera, &cfg, dir.path())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("too few dots")
            && e.contains("of 260 identified")
            && e.contains("min_dots = 200"),
        "{e}"
    );
    // A camera that sees nothing: no anchors.
    camera.dropped = |_, _| true;
    let e = calibrate_geometric(&mut display, &mut camera, &cfg, dir.path())
        .unwrap_err()
        .to_string();
    assert!(e.contains("only 0 of 9 anchor dots"), "{e}");
}

#[test]
fn bad_inputs_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let shared = Arc::new(Mutex::new(Shared::default()));
    let mut display = TestDisplay(shared.clone());
    let mut camera = TestCamera::new(shared);
    let mut cfg = config(dir.path());
    // No intrinsics.
    let mut none = cfg.clone();
    none.intrinsics = None;
    let e = calibrate_geometric(&mut display, &mut camera, &none, dir.path()).unwrap_err();
    assert!(
        e.to_string().contains("calibrate.geometric.intrinsics"),
        "{e}"
    );
    // Intrinsics of another camera.
    let other = dir.path().join("other.toml");
    std::fs::write(
        &other,
        intrinsics_toml((640, 480), [500.0, 500.0, 320.0, 240.0], [0.0; 4]),
    )
    .unwrap();
    let mut wrong = cfg.clone();
    wrong.intrinsics = Some(other);
    let e = calibrate_geometric(&mut display, &mut camera, &wrong, dir.path()).unwrap_err();
    assert!(
        e.to_string()
            .contains("intrinsics are for a 640×480 camera"),
        "{e}"
    );
    // Saturated dots name the pattern.
    camera.saturation = 2000.0;
    let e = calibrate_geometric(&mut display, &mut camera, &cfg, dir.path()).unwrap_err();
    assert!(
        e.to_string().contains("pattern geometric_grid") && e.to_string().contains("saturated"),
        "{e}"
    );
    // A bad configuration value is refused before anything is shown.
    camera.saturation = 1e9;
    cfg.gate = 0.0;
    let e = calibrate_geometric(&mut display, &mut camera, &cfg, dir.path()).unwrap_err();
    assert!(e.to_string().contains("calibrate.geometric.gate"), "{e}");
}

#[test]
fn config_bad_values_are_named() {
    let base = "intrinsics = \"i.toml\"\n";
    let cfg: GeometricConfig = toml::from_str(base).unwrap();
    cfg.validate().unwrap();
    for (extra, key) in [
        ("spacing_px = 4", "spacing_px"),
        ("radius_px = 20.0", "radius_px"),
        ("radius_px = nan", "radius_px"),
        ("level = 256", "level"),
        ("level = 0", "level"),
        ("bits = 12", "bits"),
        ("exposure = 0.0", "exposure"),
        ("exposure = inf", "exposure"),
        ("settle = -1.0", "settle"),
        ("gate = 0.9", "gate"),
        ("iterations = 0", "iterations"),
        ("clip_sigma = 1.0", "clip_sigma"),
        ("correction_degree = 9", "correction_degree"),
        ("min_dots = 3", "min_dots"),
        ("lattice_px = 2", "lattice_px"),
    ] {
        let cfg: GeometricConfig = toml::from_str(&format!("{base}{extra}\n")).unwrap();
        let e = cfg.validate().unwrap_err().to_string();
        assert!(
            e.contains(&format!("calibrate.geometric.{key}")),
            "{extra}: {e}"
        );
    }
    let e = toml::from_str::<GeometricConfig>(&format!("{base}spacing = 3\n")).unwrap_err();
    assert!(e.to_string().contains("spacing"), "{e}");
}

mod props {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]
        /// Any TOML text: a config or an error, never a panic; a config
        /// that validates has its values in range.
        #[test]
        fn config_parse_never_panics(
            spacing in -10i64..5000, radius in -5.0f64..600.0, level in -1i64..2000,
            gate in -1.0f64..2.0, iters in -1i64..100, junk in "[a-z_ =0-9.\"]{0,20}"
        ) {
            let text = format!(
                "intrinsics = \"i.toml\"\nspacing_px = {spacing}\nradius_px = {radius}\nlevel = {level}\ngate = {gate}\niterations = {iters}\n{junk}\n"
            );
            if let Ok(cfg) = toml::from_str::<GeometricConfig>(&text) {
                if cfg.validate().is_ok() {
                    prop_assert!((8..=1024).contains(&cfg.spacing_px));
                    prop_assert!(cfg.radius_px * 8.0 <= cfg.spacing_px as f64 + 1e-9);
                    prop_assert!(cfg.gate > 0.0 && cfg.gate <= 0.5);
                }
            }
        }
    }
}

/// End to end on the simulated facility (configs/simfacility.toml: its
/// collimator distortion and misalignment, the camera's intrinsics,
/// distortion, vignetting, PRNU and noise): the geometry recovered against
/// the facility's truth accessor, over the part of the screen the camera
/// sees.
#[test]
fn simulated_facility_end_to_end() {
    use optistim::simfacility::SimFacility;
    let sim = SimFacility::load(common::simfacility::bundled_path()).unwrap();
    let cam = sim.config().camera.clone();
    let dir = tempfile::tempdir().unwrap();
    // The intrinsics file a camera calibration would give (OpenCV's pixel
    // convention: centres at integers).
    let intrinsics = dir.path().join("intrinsics.toml");
    let [cw, ch] = cam.resolution;
    std::fs::write(
        &intrinsics,
        intrinsics_toml(
            (cw, ch),
            [cam.fx, cam.fy, cam.cx - 0.5, cam.cy - 0.5],
            [cam.k1, cam.k2, cam.p1, cam.p2],
        ),
    )
    .unwrap();
    let mut cfg = GeometricConfig::with_intrinsics(&intrinsics);
    cfg.exposure = cam.exposure;
    cfg.settle = 0.0;
    let (mut display, mut camera) = (sim.display(), sim.camera());
    let t0 = Instant::now();
    let report = calibrate_geometric(&mut display, &mut camera, &cfg, dir.path()).unwrap();
    let elapsed = t0.elapsed().as_secs_f64();
    let g = GeometryCalibration::load(&report.geometry_csv, (1920, 1080)).unwrap();
    let [w, h] = cam.resolution;
    let (mut ss, mut n, mut max) = (0.0, 0usize, 0.0f64);
    for j in 0..=135 {
        for i in 0..=240 {
            let (u, v) = (i as f64 * 8.0, j as f64 * 8.0);
            let (px, py) = sim.true_camera_pixel(u, v);
            if px < 40.0 || py < 40.0 || px > w as f64 - 40.0 || py > h as f64 - 40.0 {
                continue;
            }
            let t = sim.true_geometry(u, v);
            let d = g.direction(u, v);
            let e = (d[0] - t.0).hypot(d[1] - t.1) * cam.fx;
            ss += e * e;
            n += 1;
            max = max.max(e);
        }
    }
    let rms = (ss / n as f64).sqrt();
    let arcsec = 206_264.806 / cam.fx;
    eprintln!(
        "simulated facility: geometry error vs truth RMS {rms:.4} camera px ({:.3} arcsec), max {max:.4} px \
         ({:.3} arcsec) over {n} points the camera sees; fit residual RMS {:.4} px ({:.3} arcsec), max {:.4} px; \
         {} dots matched, {} used of {} shown; anchors {} of {}; {elapsed:.1} s",
        rms * arcsec,
        max * arcsec,
        report.rms_px,
        report.rms_arcsec,
        report.max_px,
        report.dots_matched,
        report.dots_used,
        report.dots_shown,
        report.anchors_identified,
        report.anchors_shown
    );
    assert!(n > 10_000, "{n} points in view");
    assert!(rms <= 0.05, "geometry RMS error {rms} camera px");
    assert!(report.dots_used > 200);
}
