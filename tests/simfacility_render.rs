//! The simulated camera agrees with `render` on the same camera: `run`
//! drives the simulated screen through a LUT of the screen's *true*
//! camera-effective radiance (no calibration involved), the simulated
//! camera (the scene's camera: same intrinsics, band, pupil) images it at
//! the facility exposure, and its signal is compared with `render`'s at
//! the flight exposure. This checks the radiometric convention end to end
//! (L_eff of an LCD spectrum, τ, k, the etendue) and the geometry of an
//! ideal collimator; the closed loop with calibrated files is the
//! calibration's test.

use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Instant;

use optistim::facility::config::FacilityConfig;
use optistim::facility::display::Display;
use optistim::facility::driver::{self, RunPlan, StateSource};
use optistim::facility::serial::SimSync;
use optistim::facility::trajectory::Trajectory;
use optistim::render::detector::{render_scene, PixelGeometry};
use optistim::render::Renderer;
use optistim::scene::Scene;
use optistim::simfacility::{SimFacility, SimScreen};

mod common;
use common::simfacility::{lcd_white_spectrum, SimToml};

/// Moon radius 1737.4 km at 2.78e8 m, camera f = 4000 px: 25 px radius.
const RANGE: f64 = 2.78e8;
const SUN: [f64; 3] = [7.48e10, 0.0, -1.29557e11];
const TAU: f64 = 0.85;

fn scene_toml() -> String {
    format!(
        r#"
[camera]
resolution = [96, 96]
pixel_pitch = 10e-6
focal_length = 0.04
f_number = 2.5
exposure = 2.0e-5
full_well = 1.0e9
bits = 16
gain = 0.05
band = [450e-9, 820e-9]

[sun]
spectrum = "blackbody"
temperature = 5772.0
irradiance_1au = 1361.0

[body]
radius = 1737.4e3
reflectance = {{ model = "lambert", albedo = 0.15 }}

[state]
camera_position = [0.0, 0.0, {cz:e}]
camera_attitude = [1.0, 0.0, 0.0, 0.0]
sun_position = [{:e}, {:e}, {:e}]
"#,
        SUN[0],
        SUN[1],
        SUN[2],
        cz = -RANGE
    )
}

/// The screen (320×240, 0.1 mm) behind a 0.8 m collimator: 8000 px focal
/// length, two screen pixels per camera pixel.
fn facility_toml() -> String {
    format!(
        r#"
[scenario]
scene = "scene.toml"
trajectory = "trajectory.csv"
[screen]
resolution = [320, 240]
pixel_pitch = 1.0e-4
refresh_hz = 60.0
[collimator]
focal_length = 0.8
transmission = {TAU}
[calibration]
lut = "lut.csv"
[drive]
flight_exposure = 2.0e-5
facility_exposure = 2.0e-3
dither = "bayer"
temporal = false
seed = 1
bits = 8
[frame_id]
enabled = false
[timing]
state_timeout = 5.0
"#
    )
}

/// The same screen and camera as physics: an LCD spectrum (not the Sun's),
/// no noise, no non-uniformity, an ideal aligned collimator.
fn sim_facility() -> SimFacility {
    let spectrum = format!("spectrum = \"{}\"", lcd_white_spectrum().display());
    SimToml::quiet()
        .seed(3)
        .with(
            "screen",
            "resolution = [320, 240]\nmax_radiance = 1.0\nblack_level = 0.0005",
        )
        .with("screen", &spectrum)
        .with(
            "collimator",
            &format!("focal_length = 0.8\ntransmission = {TAU}"),
        )
        .with(
            "camera",
            "resolution = [96, 96]\ncx = 48.0\ncy = 48.0\nfocal_length = 0.04\nf_number = 2.5\n\
             exposure = 2.0e-3\nsupersample = 4",
        )
        .with(
            "meter",
            "spot_center_px = [160.0, 120.0]\nspot_radius_px = 10.0",
        )
        .facility()
}

/// A display that captures what the simulated camera sees after each
/// present (the facility exposure, within the frame's refresh).
struct Capturing {
    screen: SimScreen,
    facility: SimFacility,
    shots: Vec<Vec<f32>>,
}

impl Display for Capturing {
    fn present(&mut self, frame: &[u32]) -> optistim::Result<Instant> {
        let at = self.screen.present(frame)?;
        self.shots.push(self.facility.capture_last(2.0e-3)?.data);
        Ok(at)
    }
    fn is_open(&self) -> bool {
        true
    }
    fn size(&self) -> (usize, usize) {
        self.screen.size()
    }
}

#[test]
fn sim_camera_through_a_true_lut_matches_render() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path();
    std::fs::write(p.join("scene.toml"), scene_toml()).unwrap();
    std::fs::write(
        p.join("trajectory.csv"),
        format!(
            "t,cam_x,cam_y,cam_z,cam_qw,cam_qx,cam_qy,cam_qz,sun_x,sun_y,sun_z\n0,0,0,{:e},1,0,0,0,{:e},{:e},{:e}\n",
            -RANGE, SUN[0], SUN[1], SUN[2]
        ),
    )
    .unwrap();
    std::fs::write(p.join("facility.toml"), facility_toml()).unwrap();
    let facility = sim_facility();
    // The LUT of the screen's true camera-effective radiance at its centre.
    let mut lut = String::from("drive_level,radiance_w_m2_sr\n");
    for level in 0..256 {
        let l = facility.true_camera_effective_radiance(level, (160.0, 120.0));
        lut.push_str(&format!("{level},{l:e}\n"));
    }
    std::fs::write(p.join("lut.csv"), lut).unwrap();

    let config = FacilityConfig::load(p.join("facility.toml")).unwrap();
    let scene = Scene::from_file(&config.scenario.scene).unwrap();
    let plan = RunPlan {
        source: StateSource::Replay(Trajectory::load(p.join("trajectory.csv")).unwrap()),
        config,
        scene: scene.clone(),
        frames: Some(1),
        log: p.join("frames.jsonl"),
        summary: p.join("summary.json"),
    };
    let mut display = Capturing {
        screen: facility.display(),
        facility: facility.clone(),
        shots: Vec::new(),
    };
    driver::run(
        plan,
        &mut display,
        &mut SimSync::with_history(4),
        Arc::new(AtomicBool::new(false)),
    )
    .unwrap();
    let moon = display.shots[0].clone();
    // The sky: the screen's black level, imaged alone.
    let mut screen = facility.display();
    screen.present(&vec![0; 320 * 240]).expect("black frame");
    let black = facility.capture_last(2.0e-3).unwrap().data;

    let mut renderer = Renderer::new(scene.camera.pinhole.clone());
    let pixels = PixelGeometry::new(&renderer);
    let images = render_scene(&scene, &mut renderer, &pixels).unwrap();
    let reference: Vec<f64> = images.electrons.iter().map(|&e| e as f64 * 0.05).collect();
    let sim: Vec<f64> = moon
        .iter()
        .zip(&black)
        .map(|(&m, &b)| (m - b) as f64)
        .collect();

    let total = |v: &[f64]| v.iter().sum::<f64>();
    let centroid = |v: &[f64]| {
        let t = total(v);
        let x = v
            .iter()
            .enumerate()
            .map(|(k, a)| a * ((k % 96) as f64 + 0.5))
            .sum::<f64>();
        let y = v
            .iter()
            .enumerate()
            .map(|(k, a)| a * ((k / 96) as f64 + 0.5))
            .sum::<f64>();
        (x / t, y / t)
    };
    let (ts, tr) = (total(&sim), total(&reference));
    let (cs, cr) = (centroid(&sim), centroid(&reference));
    let peak = reference.iter().cloned().fold(0.0, f64::max);
    let mut errors: Vec<f64> = sim
        .iter()
        .zip(&reference)
        .filter(|(_, &r)| r > 0.1 * peak)
        .map(|(s, r)| (s / r - 1.0).abs())
        .collect();
    errors.sort_by(f64::total_cmp);
    let p95 = errors[errors.len() * 95 / 100];
    eprintln!(
        "disk signal sim/render {:.5}, centroid sim ({:.4}, {:.4}) render ({:.4}, {:.4}), per-pixel p95 {:.4} over {} pixels",
        ts / tr,
        cs.0,
        cs.1,
        cr.0,
        cr.1,
        p95,
        errors.len()
    );
    assert!(
        (ts / tr - 1.0).abs() < 0.005,
        "disk signal ratio {}",
        ts / tr
    );
    assert!(
        (cs.0 - cr.0).abs() < 0.05 && (cs.1 - cr.1).abs() < 0.05,
        "centroids {cs:?} vs {cr:?}"
    );
    assert!(p95 < 0.03, "per-pixel p95 {p95}");
}
