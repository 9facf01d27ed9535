//! The closed loop on the simulated facility, honest: starting from
//! nothing, `optistim calibrate geometric`, `radiometric`, `flat` and
//! `verify` (the CLI, as users run them) measure the small simulated
//! facility of tests/data/closed_loop/ into a temp dir; `optistim run
//! --display sim-facility` plays a Moon scene on the result (one state
//! repeated, the camera integrating eight temporally dithered frames); the
//! simulated camera's frame is compared with the library renderer's image
//! of the same state on the same pixel grid (the facility camera is the
//! scene's flight camera, distortion-free because `render`'s pinhole has no
//! distortion model).
//!
//! What the calibration is given is what a real campaign has: the camera's
//! lab products (`optistim sim-lab`: intrinsics, own flat and absolute
//! responsivity, each off by an error drawn within its declared
//! uncertainty), the nominal white spectrum of the panel (the simulated
//! panel's grey levels are three channels with their own tone curves and a
//! bluer black leak), or with `OPTISTIM_F_PER_LEVEL=1` instead a
//! spectroradiometer on the meter's spot, its wavelength scale 0.3 nm off,
//! measuring the spectrum at several levels for F per level (see
//! [`f_per_level`]), darks it takes itself (`dark = "shutter"`), and one
//! simulated clock across all its commands (`--sim-clock`), started an hour
//! after power-on as a campaign's procedure asks (docs/CALIBRATION.md). The
//! simulator models bias, dark current, row noise, a camera
//! non-linearity, veiling glare, mura, decentring and thin-prism
//! distortion, none of which the calibration fits exactly. Only the
//! comparison below reads the simulator's truth.
//!
//! Common quantity: electrons at the flight exposure. `run` drives
//! τ·L_eff = k·L with k = flight / facility exposure, so the facility
//! camera's electrons, the inverse non-linearity of (DN − bias)/gain less
//! dark current × t, divided by the camera's own flat (vignetting × PRNU,
//! which `render` does not model), equal `render`'s electrons.
//! Thresholds (the figures README.md quotes, over seeds 1–10): disk signal
//! within what the run claims, the k = 2 uncertainty of the disk flux it
//! quotes (its summary's `radiometric_u_k2_percent_max`, from the LUT's
//! budget), that claim itself at most 1 % (what README.md tells a user
//! this facility achieves), p95 of the per-pixel error within 2 % over every disk
//! pixel whose target is above the screen's black level and which the limb
//! does not cross (those judge the limb's position), centroid and lit
//! limb within 0.02 camera px, and the campaign's own verify passes.
//! Negatives (one seed each): each omission a reviewer named (no darks,
//! the screen spectrum 2 nm off, a cold calibration shown on a warm
//! screen, the focal length +0.25 %, the principal point +0.5 px, a wrong
//! LUT) must be caught by verify or by the closed loop.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use optistim::render::detector::{render_scene, PixelGeometry};
use optistim::render::Renderer;
use optistim::scene::Scene;
use optistim::simfacility::SimFacility;

const W: usize = 128;
const DATA: &str = "tests/data/closed_loop";
/// The campaign starts this long after the screen's power-on (s).
const WARM: f64 = 3600.0;
/// k = flight / facility exposure of the facility file.
const K: f64 = 6.66667e-4 / 0.133333;
const TAU: f64 = 0.85;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn data(name: &str) -> PathBuf {
    root().join(DATA).join(name)
}

/// Whether the honest campaign measures F per level with a simulated
/// spectroradiometer (`OPTISTIM_F_PER_LEVEL=1`) instead of taking the
/// white's F from the nominal spectrum. Not yet the default: with the
/// greys' F bias removed, seed 9's verify misses its camera threshold
/// (1.67 % against 1.65 %): its lab responsivity is drawn −1.39 % (1.9σ of
/// the declared 1.5 % k = 2), which the bias used to offset
/// (docs/CALIBRATION.md, "The closed loop").
fn f_per_level() -> bool {
    std::env::var_os("OPTISTIM_F_PER_LEVEL").is_some_and(|v| v == "1")
}

/// What a campaign is given, varied by the negative tests.
#[derive(Clone)]
struct Given {
    /// `calibrate.camera.dark`.
    dark: &'static str,
    /// `calibrate.screen_spectrum`, when there is no spectroradiometer.
    spectrum: PathBuf,
    /// `[calibrate.spectroradiometer]`: the spectrum measured per level
    /// instead of the file.
    spectroradiometer: bool,
    /// The camera intrinsics the geometric and flat routines use.
    intrinsics: PathBuf,
}

/// The calibration files a run uses.
struct Files {
    lut: PathBuf,
    flat: Option<PathBuf>,
    geometry: Option<PathBuf>,
}

/// One campaign on the simulated facility with simulator seed `seed`: its
/// own directory, facility truth file, lab products and clock.
struct Campaign {
    tmp: tempfile::TempDir,
}

impl Campaign {
    /// Writes the seeded truth file (paths made absolute), the clock an
    /// hour after power-on, and the camera's lab products.
    fn new(seed: u64) -> Campaign {
        let tmp = tempfile::tempdir().unwrap();
        let text = std::fs::read_to_string(data("simfacility.toml")).unwrap();
        let text = text
            .replace("seed = 7", &format!("seed = {seed}"))
            .replace("\"../../../data/", &format!("\"{}/data/", root().display()))
            .replace(
                "\"../../../configs/",
                &format!("\"{}/configs/", root().display()),
            );
        assert!(text.contains(&format!("seed = {seed}")));
        std::fs::write(tmp.path().join("sim.toml"), text).unwrap();
        let c = Campaign { tmp };
        c.set_clock(WARM);
        let lab = c.path("lab").display().to_string();
        c.optistim(&["sim-lab", "--sim-facility", &c.sim(), "--out", &lab]);
        for scene in ["moon.toml", "moon_lime.toml"] {
            c.write_scene(scene);
        }
        c
    }

    /// The scene `name` of tests/data/closed_loop/ with the flight camera
    /// the user knows: the lab's intrinsics (mean focal length, principal
    /// point moved to pixel centres at +0.5), paths made absolute.
    fn write_scene(&self, name: &str) {
        let (f, cx, cy) = lab_intrinsics(&self.path("lab/intrinsics.toml"));
        let text = std::fs::read_to_string(data(name)).unwrap();
        let text = text
            .replace("\"../../../data/", &format!("\"{}/data/", root().display()))
            .replace(
                "\"../../../configs/",
                &format!("\"{}/configs/", root().display()),
            )
            .replace(
                "focal_length = 0.04\n",
                &format!(
                    "focal_length = {:e}\nprincipal_point = [{cx}, {cy}]\n",
                    f * 10e-6
                ),
            );
        assert!(
            text.contains("principal_point"),
            "{name}: no focal_length line"
        );
        std::fs::write(self.path(name), text).unwrap();
    }

    fn path(&self, name: &str) -> PathBuf {
        self.tmp.path().join(name)
    }

    fn sim(&self) -> String {
        self.path("sim.toml").display().to_string()
    }

    /// Sets the simulated clock (s since the screen's power-on).
    fn set_clock(&self, seconds: f64) {
        let text = format!(
            "{{\"format\": \"optistim-simclock-1\", \"seconds_since_power_on\": {seconds}}}"
        );
        std::fs::write(self.path("clock.json"), text).unwrap();
    }

    /// The simulator's truth, for the comparison only.
    fn truth(&self) -> SimFacility {
        SimFacility::load(self.sim()).unwrap()
    }

    /// What an honest campaign is given.
    fn honest(&self) -> Given {
        Given {
            dark: "shutter",
            spectrum: root().join("data/display/lcd_white_apple_studio_display.csv"),
            spectroradiometer: f_per_level(),
            intrinsics: self.path("lab/intrinsics.toml"),
        }
    }

    /// Runs the optistim binary (on the simulated facility and clock).
    fn optistim_output(&self, args: &[&str]) -> Output {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_optistim"));
        cmd.current_dir(root()).args(args);
        if args[0] != "sim-lab" {
            let clock = self.path("clock.json");
            cmd.args(["--sim-facility", &self.sim(), "--sim-clock"])
                .arg(clock);
        }
        cmd.output().unwrap()
    }

    /// [`optistim_output`](Self::optistim_output); panics with its stderr
    /// on failure.
    fn optistim(&self, args: &[&str]) -> String {
        let out = self.optistim_output(args);
        assert!(
            out.status.success(),
            "optistim {args:?} failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).into_owned()
    }

    /// The facility file: the screen and collimator *as designed* (aligned,
    /// ideal), k = 0.005, the `[calibrate]` campaign with what it is
    /// `given`, and the calibration `files`.
    fn facility(&self, given: &Given, files: &Files) -> String {
        let opt = |key: &str, p: &Option<PathBuf>| match p {
            Some(p) => format!("{key} = \"{}\"\n", p.display()),
            None => String::new(),
        };
        let spectrum = match given.spectroradiometer {
            true => "[calibrate.spectroradiometer]\nkind = \"sim\"\n".to_string(),
            false => format!("screen_spectrum = \"{}\"\n", given.spectrum.display()),
        };
        format!(
            r#"
[scenario]
scene = "{scene}"
trajectory = "{traj}"
[screen]
resolution = [600, 450]
pixel_pitch = 6.66667e-5
refresh_hz = 60.0
[collimator]
focal_length = 0.8
transmission = {TAU}
[calibration]
lut = "{lut}"
{flat}{geometry}
[drive]
flight_exposure = 6.66667e-4
facility_exposure = 0.133333
dither = "bayer"
temporal = true
seed = 1
bits = 8
[frame_id]
enabled = false
[sync]
template = "FRAME {{id}} {{t}} {{exposure_us}}\n"
ack = false
[timing]
state_timeout = 5.0
[acceptance]
# The simulated camera's captures take longer than a slot in wall time;
# its clock is virtual, so the frames it sees are on time regardless.
missed_degraded = 1.0
missed_fail = 1.0
[calibrate]
levels = 33
repeats = 2
seed = 1
settle = 0.5
region = [0.4, 0.4, 0.2, 0.2]
target_fill = 0.6
max_exposure = 1.0
ambient = "none"
screen_spectrum_uncertainty_nm = 1.0
{spectrum}[calibrate.flat]
levels = [128, 255]
degree = 4
camera_flat = "{camera_flat}"
[calibrate.verify]
dark = "shutter"
[calibrate.geometric]
intrinsics = "{intrinsics}"
spacing_px = 36
radius_px = 4.5
exposure = 0.0333
[calibrate.meter]
kind = "sim"
spectral_response = "{meter}"
[calibrate.camera]
kind = "sim"
exposure = 0.0333
saturation_dn = 65535
resolution = [128, 128]
dark = "{dark}"
intrinsics = "{intrinsics}"
responsivity = "{responsivity}"
"#,
            scene = self.path("moon.toml").display(),
            traj = data("trajectory.csv").display(),
            lut = files.lut.display(),
            flat = opt("flat_field", &files.flat),
            geometry = opt("geometry", &files.geometry),
            spectrum = spectrum,
            intrinsics = given.intrinsics.display(),
            meter = root().join("configs/meter_flat_380_780.csv").display(),
            camera_flat = self.path("lab/camera_flat.tif").display(),
            responsivity = self.path("lab/responsivity.toml").display(),
            dark = given.dark,
        )
    }

    fn write_facility(&self, name: &str, text: String) -> String {
        let path = self.path(name);
        std::fs::write(&path, text).unwrap();
        path.display().to_string()
    }

    /// Calibrates geometry, LUT and flat field into `cal_<tag>` with what
    /// it is `given`.
    fn calibrate(&self, tag: &str, given: &Given) -> Files {
        let cal = self.path(&format!("cal_{tag}"));
        let out = cal.display().to_string();
        let files = Files {
            lut: cal.join("lut.csv"),
            flat: Some(cal.join("flat_field.tif")),
            geometry: Some(cal.join("geometry.csv")),
        };
        // Before any calibration the facility file needs some LUT: the
        // repository's synthetic example (unused by the geometric routine).
        let none = Files {
            lut: root().join("calib/example_lut.csv"),
            flat: None,
            geometry: None,
        };
        let f = self.write_facility(&format!("{tag}_0.toml"), self.facility(given, &none));
        for routine in ["geometric", "radiometric"] {
            self.optistim(&["calibrate", routine, &f, "--out", &out]);
        }
        let partial = Files {
            lut: files.lut.clone(),
            flat: None,
            geometry: files.geometry.clone(),
        };
        let f = self.write_facility(&format!("{tag}_1.toml"), self.facility(given, &partial));
        self.optistim(&["calibrate", "flat", &f, "--out", &out]);
        files
    }

    /// `calibrate verify` of `files` (a campaign's directory `cal_<tag>`):
    /// whether it passed, and its report.
    fn verify(&self, tag: &str, given: &Given, files: &Files) -> (bool, serde_json::Value) {
        let cal = self.path(&format!("cal_{tag}"));
        let f = self.write_facility(&format!("{tag}_verify.toml"), self.facility(given, files));
        let out = self.optistim_output(&[
            "calibrate",
            "verify",
            &f,
            "--out",
            &cal.display().to_string(),
        ]);
        let report = std::fs::read_to_string(cal.join("verify_report.json")).unwrap_or_else(|_| {
            panic!(
                "verify wrote no report: {}",
                String::from_utf8_lossy(&out.stderr)
            )
        });
        (out.status.success(), serde_json::from_str(&report).unwrap())
    }

    /// `run` with `files`: the mean of the camera's frames after presents
    /// 16, 24, 32 and 40 (each integrating the eight presents before it),
    /// in flight electrons. Four frames, not one, so that the camera's own
    /// noise (a measurement's, not the facility's) does not set the
    /// per-pixel figure. With the run's own quoted uncertainty.
    fn run_and_capture(&self, tag: &str, facility: String) -> Capture {
        let f = self.write_facility(&format!("{tag}.toml"), facility);
        let caps = self.path(&format!("cap_{tag}"));
        let (log, summary) = (
            self.path(&format!("{tag}.jsonl")),
            self.path(&format!("{tag}.json")),
        );
        self.optistim(&[
            "run",
            &f,
            "--frames",
            "41",
            "--display",
            "sim-facility",
            "--capture-every",
            "8",
            "--captures",
            &caps.display().to_string(),
            "--log",
            &log.display().to_string(),
            "--summary",
            &summary.display().to_string(),
        ]);
        let mut mean = vec![0.0; W * W];
        let frames = [16, 24, 32, 40];
        for n in frames {
            let img = image::open(caps.join(format!("frame_{n:06}.png"))).unwrap();
            let dn = img.as_luma16().expect("16-bit grey").clone().into_raw();
            assert_eq!(dn.len(), W * W);
            for (m, &d) in mean.iter_mut().zip(&dn) {
                *m += d as f64 / frames.len() as f64;
            }
        }
        let summary: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&summary).unwrap()).unwrap();
        Capture {
            electrons: self.electrons(&mean),
            u_k2: summary["radiometric_u_k2_percent_max"]
                .as_f64()
                .map(|u| u / 100.0),
        }
    }

    /// Flight electrons of a capture, from the simulator's truth: bias,
    /// gain, the non-linearity inverted, dark current, the camera's own
    /// flat.
    fn electrons(&self, dn: &[f64]) -> Vec<f64> {
        let sim = self.truth();
        let c = &sim.config().camera;
        let dark_e = c.dark_current * c.exposure;
        let (beta, well) = (c.nonlinearity, c.full_well);
        // m = e (1 − β e / FW) ⇒ e = FW (1 − √(1 − 4 β m / FW)) / (2 β).
        let linear = |m: f64| {
            if beta > 0.0 {
                well * (1.0 - (1.0 - 4.0 * beta * m / well).max(0.0).sqrt()) / (2.0 * beta)
            } else {
                m
            }
        };
        let flat = sim.camera_flat();
        dn.iter()
            .zip(&flat)
            .map(|(&d, &g)| (linear((d - c.bias_dn) / c.gain) - dark_e) / g as f64)
            .collect()
    }

    /// Electrons per unit of the scene's camera-effective radiance at the
    /// flight camera: the threshold below which a target is under the
    /// screen's black level, from the truth.
    fn black_level_electrons(&self, reference: &Reference) -> f64 {
        let sim = self.truth();
        let black = sim.true_camera_effective_radiance(0, (300.0, 225.0));
        // The screen shows L_eff × k / τ; below the black level it cannot.
        reference.electrons_per_radiance * black * TAU / K
    }
}

/// The renderer's image of a scene, electrons at the flight exposure.
struct Reference {
    electrons: Vec<f64>,
    /// Electrons per W m⁻² sr⁻¹ of camera-effective radiance (the image's
    /// own ratio, constant but for the camera's cos⁴ over this small field).
    electrons_per_radiance: f64,
}

/// Mean focal length (px) and principal point (pixel centres at +0.5) of
/// an intrinsics file (OpenCV convention, centres at integers).
fn lab_intrinsics(path: &Path) -> (f64, f64, f64) {
    let k = optistim::instruments::intrinsics::CameraIntrinsics::load(path).unwrap();
    let m = k.camera_matrix;
    (0.5 * (m[0][0] + m[1][1]), m[0][2] + 0.5, m[1][2] + 0.5)
}

/// The renderer's image of scene file `path`.
fn reference_of(path: &Path) -> Reference {
    let scene = Scene::from_file(path).unwrap();
    let mut renderer = Renderer::new(scene.camera.pinhole.clone());
    let pixels = PixelGeometry::new(&renderer);
    let images = render_scene(&scene, &mut renderer, &pixels).unwrap();
    let (mut e, mut l) = (0.0, 0.0);
    for (&a, &b) in images.electrons.iter().zip(&images.radiance_effective) {
        e += a as f64;
        l += b as f64;
    }
    Reference {
        electrons: images.electrons.iter().map(|&e| e as f64).collect(),
        electrons_per_radiance: e / l,
    }
}

/// A run's camera frames in flight electrons, and the expanded uncertainty
/// (k = 2, a fraction) the run quotes for the disk flux it showed: the
/// summary's `radiometric_u_k2_percent_max` (None for a LUT without its
/// uncertainty column, as the simulator's true files).
struct Capture {
    electrons: Vec<f64>,
    u_k2: Option<f64>,
}

/// The disk-signal limit for a run whose LUT quotes no uncertainty (the
/// simulator's true files): the chain's own error (blur, noise, dithering,
/// the mura and glare no file corrects).
const DISK_LIMIT_UNQUOTED: f64 = 0.005;

/// The largest k = 2 uncertainty of the disk flux an honest campaign on
/// this facility may quote (README.md, "How well it works"; measured
/// 0.75–0.91 % over seeds 1–10, docs/CALIBRATION.md).
const U_K2_QUOTED: f64 = 0.01;

/// The comparison's numbers.
#[derive(Debug)]
struct Comparison {
    /// Σ sim / Σ render − 1 over the disk (render > 0, dilated by 3 px).
    disk_signal: f64,
    /// 95th percentile of |sim/render − 1| over the disk pixels whose
    /// target is above the screen's black level and which the limb does not
    /// cross ([`inside_silhouette`]).
    p95: f64,
    /// Centroid offset sim − render, camera px (x, y).
    centroid: (f64, f64),
    /// Lit-limb position offset sim − render along x, camera px.
    limb: f64,
    /// The run's own quoted k = 2 uncertainty of the disk flux (fraction).
    u_k2: Option<f64>,
}

impl Comparison {
    /// The disk signal's limit: what the run claims (its k = 2
    /// uncertainty), or [`DISK_LIMIT_UNQUOTED`] when it claims nothing.
    fn disk_limit(&self) -> f64 {
        self.u_k2.unwrap_or(DISK_LIMIT_UNQUOTED)
    }

    /// Within the thresholds README.md quotes: the disk signal within the
    /// run's own claim, the rest fixed.
    fn passes(&self) -> bool {
        self.disk_signal.abs() <= self.disk_limit()
            && self.p95 <= 0.02
            && self.centroid.0.abs() <= 0.02
            && self.centroid.1.abs() <= 0.02
            && self.limb.abs() <= 0.02
    }
}

/// One honest campaign: calibrate, verify, run; the comparison and verify's
/// verdict.
fn honest_loop(seed: u64) -> (Comparison, bool, serde_json::Value) {
    let c = Campaign::new(seed);
    let given = c.honest();
    let files = c.calibrate("main", &given);
    let (verified, report) = c.verify("main", &given, &files);
    let reference = reference_of(&c.path("moon.toml"));
    let floor = c.black_level_electrons(&reference);
    let sim = c.run_and_capture("main", c.facility(&given, &files));
    (compare(&sim, &reference.electrons, floor), verified, report)
}

#[test]
fn honest_campaigns_reproduce_the_render_over_ten_seeds() {
    let mut results = Vec::new();
    for seed in 1..=10 {
        let (cmp, verified, report) = honest_loop(seed);
        println!(
            "seed {seed:2}: disk {:+.3} % (quoted k = 2: {:.3} %), p95 {:.2} %, centroid ({:+.4}, {:+.4}) px, \
             limb {:+.4} px; verify {} (max |error| {:.2} %, {} patches beyond their uncertainty; \
             camera common mode {:+.3} % of ± {:.3} %, spread {:.3} %)",
            100.0 * cmp.disk_signal,
            100.0 * cmp.u_k2.unwrap_or(f64::NAN),
            100.0 * cmp.p95,
            cmp.centroid.0,
            cmp.centroid.1,
            cmp.limb,
            if verified { "PASS" } else { "FAIL" },
            report["max_error_percent"].as_f64().unwrap_or(f64::NAN),
            report["failures"].as_u64().unwrap_or(0),
            report["camera_common_mode"]["mean_percent"].as_f64().unwrap_or(f64::NAN),
            report["camera_common_mode"]["budget_k2_percent"].as_f64().unwrap_or(f64::NAN),
            report["camera_common_mode"]["max_spread_percent"].as_f64().unwrap_or(f64::NAN),
        );
        results.push((seed, cmp, verified));
    }
    let range = |f: &dyn Fn(&Comparison) -> f64| {
        let v: Vec<f64> = results.iter().map(|r| f(&r.1)).collect();
        (
            v.iter().cloned().fold(f64::INFINITY, f64::min),
            v.iter().cloned().fold(f64::NEG_INFINITY, f64::max),
        )
    };
    let d = range(&|c| 100.0 * c.disk_signal);
    let u = range(&|c| 100.0 * c.u_k2.unwrap_or(f64::NAN));
    let p = range(&|c| 100.0 * c.p95);
    let cx = range(&|c| c.centroid.0.abs().max(c.centroid.1.abs()));
    let l = range(&|c| c.limb.abs());
    let disks: Vec<f64> = results.iter().map(|r| 100.0 * r.1.disk_signal).collect();
    let n = disks.len() as f64;
    let mean = disks.iter().sum::<f64>() / n;
    let sd = (disks.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    println!(
        "seeds 1-10: disk {:+.3} .. {:+.3} % (mean {mean:+.3} %, sd {sd:.3} %), quoted k = 2 {:.3} .. {:.3} %, \
         p95 {:.2} .. {:.2} %, |centroid| <= {:.4} px, |limb| <= {:.4} px",
        d.0, d.1, u.0, u.1, p.0, p.1, cx.1, l.1
    );
    for (seed, cmp, verified) in &results {
        assert!(*verified, "seed {seed}: the campaign fails its own verify");
        let u = cmp.u_k2.expect("the calibrated LUT quotes its uncertainty");
        assert!(
            u <= U_K2_QUOTED,
            "seed {seed}: the run quotes {:.3} %, more than the {:.2} % README.md states",
            100.0 * u,
            100.0 * U_K2_QUOTED
        );
        assert!(cmp.passes(), "seed {seed}: {cmp:?}");
    }
}

/// The CLI path of F per level (seed 1): `[calibrate.spectroradiometer]
/// kind = "sim"` measures the spectrum at the default seven levels, the
/// report and the LUT header carry F per level, verify reads the meter
/// with it and passes, and the run's disk lies within its claim.
#[test]
fn a_campaign_with_a_spectroradiometer_applies_f_per_level_through_the_cli() {
    let c = Campaign::new(1);
    let given = Given {
        spectroradiometer: true,
        ..c.honest()
    };
    let files = c.calibrate("spectro", &given);
    let text = std::fs::read_to_string(c.path("cal_spectro/radiometric_report.json")).unwrap();
    let report: serde_json::Value = serde_json::from_str(&text).unwrap();
    let points = report["mismatch_by_level"].as_array().unwrap();
    let levels: Vec<u64> = points
        .iter()
        .map(|p| p["level"].as_u64().unwrap())
        .collect();
    assert_eq!(levels, [64, 96, 128, 159, 191, 223, 255]);
    let f: Vec<f64> = points
        .iter()
        .map(|p| p["factor"].as_f64().unwrap())
        .collect();
    // The simulated panel's greys are bluer: F rises with level.
    assert!(f.windows(2).all(|w| w[1] > w[0]), "{f:?}");
    assert_eq!(report["mismatch_factor"].as_f64(), Some(f[6]));
    let lut = std::fs::read_to_string(&files.lut).unwrap();
    assert!(
        lut.contains("F(level)") && lut.contains("255 0.79"),
        "{lut}"
    );
    let (verified, v) = c.verify("spectro", &given, &files);
    println!(
        "F per level {f:?}; verify {verified}, mean meter error {}",
        v["mean_meter_error_percent"]
    );
    assert!(verified);
    let reference = reference_of(&c.path("moon.toml"));
    let floor = c.black_level_electrons(&reference);
    let cmp = compare(
        &c.run_and_capture("spectro", c.facility(&given, &files)),
        &reference.electrons,
        floor,
    );
    println!("closed loop with F per level: {cmp:?}");
    assert!(cmp.u_k2.unwrap() <= U_K2_QUOTED && cmp.passes(), "{cmp:?}");
}

/// A copy of the white spectrum with its wavelengths moved by `nm`.
fn shifted_spectrum(c: &Campaign, nm: f64) -> PathBuf {
    let text = std::fs::read_to_string(c.honest().spectrum).unwrap();
    let mut out = String::new();
    for line in text.lines() {
        let mut f = line.splitn(2, ',');
        match (
            f.next().and_then(|w| w.trim().parse::<f64>().ok()),
            f.next(),
        ) {
            (Some(w), Some(rest)) => out.push_str(&format!("{},{rest}\n", w + nm)),
            _ => out.push_str(&format!("{line}\n")),
        }
    }
    let path = c.path("spectrum_shifted.csv");
    std::fs::write(&path, out).unwrap();
    path
}

/// The lab intrinsics with the focal lengths scaled by `scale` and the
/// principal point moved by `dx` px.
fn altered_intrinsics(c: &Campaign, scale: f64, dx: f64) -> PathBuf {
    let lab = c.path("lab/intrinsics.toml");
    let k = optistim::instruments::intrinsics::CameraIntrinsics::load(&lab).unwrap();
    let m = k.camera_matrix;
    let text = format!(
        "width = {}\nheight = {}\ncamera_matrix = [[{:?}, 0.0, {:?}], [0.0, {:?}, {:?}], [0.0, 0.0, 1.0]]\ndistortion = {:?}\n",
        k.width,
        k.height,
        m[0][0] * scale,
        m[0][2] + dx,
        m[1][1] * scale,
        m[1][2],
        k.distortion
    );
    let path = c.path(&format!("intrinsics_{scale}_{dx}.toml"));
    std::fs::write(&path, text).unwrap();
    path
}

/// How one omission fared: verify's verdict and the closed loop's numbers.
fn omission(c: &Campaign, tag: &str, given: &Given) -> (bool, Comparison) {
    let files = c.calibrate(tag, given);
    // Verify and run with what the calibration was given (verify needs the
    // same camera model and darks as the campaign).
    let (verified, report) = c.verify(tag, given, &files);
    let reference = reference_of(&c.path("moon.toml"));
    let floor = c.black_level_electrons(&reference);
    let cmp = compare(
        &c.run_and_capture(tag, c.facility(given, &files)),
        &reference.electrons,
        floor,
    );
    println!(
        "{tag}: verify {} (max |error| {:.2} %, {} patches beyond their uncertainty); closed loop {cmp:?}",
        if verified { "pass" } else { "FAIL" },
        report["max_error_percent"].as_f64().unwrap_or(f64::NAN),
        report["failures"].as_u64().unwrap_or(0),
    );
    (verified, cmp)
}

#[test]
fn each_omission_is_caught_by_verify_or_the_closed_loop() {
    let c = Campaign::new(3);
    let honest = c.honest();
    // No darks: the bias and dark current enter the LUT, most at the dark
    // levels; caught, or inside the LUT's own stated uncertainty there.
    let given = Given {
        dark: "none",
        ..honest.clone()
    };
    let (v, cmp) = omission(&c, "no_dark", &given);
    let uncovered = uncovered_levels(&c, &c.path("cal_no_dark/lut.csv"));
    println!("no_dark: levels whose LUT error exceeds its stated uncertainty: {uncovered:?}");
    assert!(
        !v || !cmp.passes() || uncovered.is_empty(),
        "no darks went unnoticed and outside the LUT's stated uncertainty at levels {uncovered:?}: {cmp:?}"
    );
    // A campaign without a spectroradiometer given a white spectrum 2 nm
    // off: the mismatch factor errs.
    let given = Given {
        spectrum: shifted_spectrum(&c, 2.0),
        spectroradiometer: false,
        ..honest.clone()
    };
    let (v, cmp) = omission(&c, "spectrum_2nm", &given);
    assert!(
        !v || !cmp.passes(),
        "a 2 nm spectrum error went unnoticed: {cmp:?}"
    );
    // Focal length +0.25 % and principal point +0.5 px in the intrinsics
    // the calibration uses (the scene keeps the lab's).
    let given = Given {
        intrinsics: altered_intrinsics(&c, 1.0025, 0.0),
        ..honest.clone()
    };
    let (v, cmp) = omission(&c, "focal", &given);
    assert!(
        !v || !cmp.passes(),
        "focal length +0.25 % went unnoticed: {cmp:?}"
    );
    let given = Given {
        intrinsics: altered_intrinsics(&c, 1.0, 0.5),
        ..honest.clone()
    };
    let (v, cmp) = omission(&c, "principal_point", &given);
    assert!(
        !v || !cmp.passes(),
        "principal point +0.5 px went unnoticed: {cmp:?}"
    );
    // A cold calibration (from power-on) shown on the screen an hour later.
    c.set_clock(0.0);
    let files = c.calibrate("cold", &honest);
    c.set_clock(WARM);
    let (verified, report) = c.verify("cold", &honest, &files);
    let reference = reference_of(&c.path("moon.toml"));
    let floor = c.black_level_electrons(&reference);
    let cmp = compare(
        &c.run_and_capture("cold", c.facility(&honest, &files)),
        &reference.electrons,
        floor,
    );
    println!(
        "cold calibration on a warm screen: verify {verified} {}; {cmp:?}",
        report["max_error_percent"]
    );
    assert!(
        !verified,
        "verify must see a cold calibration on a warm screen: {cmp:?}"
    );
    assert!(!cmp.passes());
    // A wrong LUT (the honest one × 1.03): verify alone must catch it.
    c.set_clock(WARM);
    let files = c.calibrate("honest", &honest);
    let wrong = c.path("cal_honest/lut_x1.03.csv");
    scale_lut(&files.lut, &wrong, 1.03);
    let files = Files {
        lut: wrong,
        ..files
    };
    let (verified, _) = c.verify("honest", &honest, &files);
    assert!(!verified, "verify must catch a LUT 3 % off");
}

/// The levels of the LUT at `path` whose error against the simulator's
/// truth (the warm screen at the calibration region's centre) exceeds the
/// LUT's own expanded uncertainty there: (level, error %, uncertainty %).
fn uncovered_levels(c: &Campaign, path: &Path) -> Vec<(u32, f64, f64)> {
    let sim = c.truth();
    sim.set_now(WARM).unwrap();
    let text = std::fs::read_to_string(path).unwrap();
    let mut out = Vec::new();
    for line in text
        .lines()
        .filter(|l| l.starts_with(|ch: char| ch.is_ascii_digit()))
    {
        let f: Vec<f64> = line.split(',').map(|v| v.trim().parse().unwrap()).collect();
        let truth = sim.true_camera_effective_radiance(f[0] as usize, (300.0, 225.0));
        let error = 100.0 * (f[1] / truth - 1.0);
        let u = f.get(2).copied().unwrap_or(0.0);
        if error.abs() > u {
            out.push((f[0] as u32, error, u));
        }
    }
    out
}

/// The LUT at `from` with every radiance × `factor`, written to `to`
/// (comment lines kept).
fn scale_lut(from: &Path, to: &Path, factor: f64) {
    let text = std::fs::read_to_string(from).unwrap();
    let mut out = String::new();
    for line in text.lines() {
        let fields: Vec<&str> = line.split(',').collect();
        match fields.get(1).and_then(|v| v.trim().parse::<f64>().ok()) {
            Some(l) if line.starts_with(|ch: char| ch.is_ascii_digit()) => {
                let mut f: Vec<String> = fields.iter().map(|s| s.to_string()).collect();
                f[1] = format!("{:e}", l * factor);
                out.push_str(&f.join(","));
                out.push('\n');
            }
            _ => out.push_str(&format!("{line}\n")),
        }
    }
    std::fs::write(to, out).unwrap();
}

#[test]
fn a_linear_lut_and_a_missing_geometry_fail_the_loop() {
    let c = Campaign::new(7);
    let honest = c.honest();
    let files = c.calibrate("main", &honest);
    let reference = reference_of(&c.path("moon.toml"));
    let floor = c.black_level_electrons(&reference);
    let linear = c.path("linear_lut.csv");
    linear_lut(&files.lut, &linear);
    let lin = Files {
        lut: linear,
        flat: files.flat.clone(),
        geometry: files.geometry.clone(),
    };
    let uncal_lut = compare(
        &c.run_and_capture("linear", c.facility(&honest, &lin)),
        &reference.electrons,
        floor,
    );
    println!("closed loop, linear LUT: {uncal_lut:?}");
    let nogeo = Files {
        lut: files.lut.clone(),
        flat: files.flat.clone(),
        geometry: None,
    };
    let no_geometry = compare(
        &c.run_and_capture("nogeo", c.facility(&honest, &nogeo)),
        &reference.electrons,
        floor,
    );
    println!("closed loop, no geometry file: {no_geometry:?}");
    assert!(
        uncal_lut.disk_signal.abs() > 0.05 && !uncal_lut.passes(),
        "a linear LUT should be caught: {uncal_lut:?}"
    );
    assert!(
        no_geometry.centroid.0.hypot(no_geometry.centroid.1) > 1.0 && !no_geometry.passes(),
        "a missing geometry file should be caught: {no_geometry:?}"
    );
}
/// Pixels within `r` px of a pixel where the render is positive.
fn disk_mask(reference: &[f64], r: i64) -> Vec<bool> {
    let mut mask = vec![false; W * W];
    for (k, _) in reference.iter().enumerate().filter(|(_, &e)| e > 0.0) {
        let (x, y) = ((k % W) as i64, (k / W) as i64);
        for dy in -r..=r {
            for dx in -r..=r {
                let (u, v) = (x + dx, y + dy);
                if (0..W as i64).contains(&u) && (0..W as i64).contains(&v) {
                    mask[v as usize * W + u as usize] = true;
                }
            }
        }
    }
    mask
}

/// Intensity-weighted centroid over the mask (pixel centres at +0.5).
fn centroid(img: &[f64], mask: &[bool]) -> (f64, f64) {
    let (mut s, mut sx, mut sy) = (0.0, 0.0, 0.0);
    for (k, (&a, _)) in img.iter().zip(mask).enumerate().filter(|(_, (_, &m))| m) {
        s += a;
        sx += a * ((k % W) as f64 + 0.5);
        sy += a * ((k / W) as f64 + 0.5);
    }
    (sx / s, sy / s)
}

/// The lit (+x, the Sun's side) limb: the mean, over the 11 rows around
/// `row`, of the x where the row's profile, scanned from the right, first
/// crosses half the row's maximum (linear interpolation between centres).
fn limb_x(img: &[f64], row: usize) -> f64 {
    let rows = row - 5..=row + 5;
    let n = rows.clone().count() as f64;
    rows.map(|y| {
        let line = &img[y * W..(y + 1) * W];
        let half = 0.5 * line.iter().cloned().fold(f64::MIN, f64::max);
        let x = (1..W)
            .rev()
            .find(|&x| line[x - 1] >= half && line[x] < half)
            .expect("a limb crossing");
        let (a, b) = (line[x - 1], line[x]);
        (x - 1) as f64 + 0.5 + (a - half) / (a - b)
    })
    .sum::<f64>()
        / n
}

/// The comparison of `sim` with `reference` over the disk; the per-pixel
/// error over pixels whose reference is above `floor` electrons (the
/// screen's black level).
fn compare(capture: &Capture, reference: &[f64], floor: f64) -> Comparison {
    let sim = &capture.electrons[..];
    let mask = disk_mask(reference, 3);
    let sum = |v: &[f64]| {
        v.iter()
            .zip(&mask)
            .filter(|(_, &m)| m)
            .map(|(a, _)| a)
            .sum::<f64>()
    };
    let inside = inside_silhouette(reference);
    let mut errors: Vec<f64> = sim
        .iter()
        .zip(reference)
        .zip(&inside)
        .filter(|((_, &r), &i)| i && r > floor)
        .map(|((s, r), _)| (s / r - 1.0).abs())
        .collect();
    errors.sort_by(f64::total_cmp);
    let (cs, cr) = (centroid(sim, &mask), centroid(reference, &mask));
    let row = cr.1 as usize;
    Comparison {
        disk_signal: sum(sim) / sum(reference) - 1.0,
        p95: errors[errors.len() * 95 / 100],
        centroid: (cs.0 - cr.0, cs.1 - cr.1),
        limb: limb_x(sim, row) - limb_x(reference, row),
        u_k2: capture.u_k2,
    }
}

/// Pixels whose 3 × 3 neighbourhood the body covers in `reference`: their
/// signal is the surface's radiance, not the fraction of the pixel the limb
/// covers. A pixel the limb crosses changes by its whole signal when the
/// limb moves by a pixel: its relative error measures the limb's position
/// (judged on its own, to 0.02 px), and a camera blur a third of a pixel
/// wide already moves such pixels by +100 % and more.
fn inside_silhouette(reference: &[f64]) -> Vec<bool> {
    let covered = |x: i64, y: i64| {
        (0..W as i64).contains(&x)
            && (0..W as i64).contains(&y)
            && reference[y as usize * W + x as usize] > 0.0
    };
    (0..W * W)
        .map(|i| {
            let (x, y) = ((i % W) as i64, (i / W) as i64);
            (-1..=1).all(|dy| (-1..=1).all(|dx| covered(x + dx, y + dy)))
        })
        .collect()
}

/// The calibrated LUT's levels replaced by a straight line between its
/// black and its maximum: what an uncalibrated facility assumes.
fn linear_lut(calibrated: &Path, out: &Path) {
    let text = std::fs::read_to_string(calibrated).unwrap();
    let rows: Vec<(f64, f64)> = text
        .lines()
        .filter(|l| l.starts_with(|c: char| c.is_ascii_digit()))
        .map(|l| {
            let mut f = l.split(',').map(|v| v.trim().parse::<f64>().unwrap());
            (f.next().unwrap(), f.next().unwrap())
        })
        .collect();
    assert!(
        rows.len() >= 17 && rows[rows.len() - 1].0 == 255.0,
        "{} rows",
        rows.len()
    );
    let (lo, hi) = (rows[0].1, rows[rows.len() - 1].1);
    let mut lut = String::from("drive_level,radiance_w_m2_sr\n");
    for level in 0..256 {
        lut.push_str(&format!(
            "{level},{:e}\n",
            lo + (hi - lo) * level as f64 / 255.0
        ));
    }
    std::fs::write(out, lut).unwrap();
}

impl Campaign {
    /// The simulated facility's true LUT (camera-effective radiance at the
    /// screen centre, with the warm screen of the campaign), flat field (its
    /// non-uniformity at full white relative to the centre) and geometry (a
    /// 30 px lattice of its true map): what a perfect calibration would
    /// write.
    fn truth_files(&self) -> Files {
        let sim = self.truth();
        sim.set_now(WARM).unwrap();
        let (w, h) = (600usize, 450usize);
        let centre = (0.5 * w as f64, 0.5 * h as f64);
        let mut lut = String::from("drive_level,radiance_w_m2_sr\n");
        for level in 0..256 {
            let l = sim.true_camera_effective_radiance(level, centre);
            lut.push_str(&format!("{level},{l:e}\n"));
        }
        let lut_path = self.path("true_lut.csv");
        std::fs::write(&lut_path, lut).unwrap();
        let u0 = sim.screen().uniformity(centre.0, centre.1);
        let gains: Vec<f32> = (0..w * h)
            .map(|k| {
                let (x, y) = ((k % w) as f64 + 0.5, (k / w) as f64 + 0.5);
                (sim.screen().uniformity(x, y) / u0) as f32
            })
            .collect();
        let flat_path = self.path("true_flat.tif");
        optistim::facility::lut::FlatField::from_gains(w, h, gains)
            .unwrap()
            .save(&flat_path)
            .unwrap();
        let mut geo = String::from("u_px,v_px,tan_x,tan_y\n");
        for v in (0..=h).step_by(30) {
            for u in (0..=w).step_by(30) {
                let (tx, ty) = sim.true_geometry(u as f64, v as f64);
                geo.push_str(&format!("{u},{v},{tx:e},{ty:e}\n"));
            }
        }
        let geo_path = self.path("true_geometry.csv");
        std::fs::write(&geo_path, geo).unwrap();
        Files {
            lut: lut_path,
            flat: Some(flat_path),
            geometry: Some(geo_path),
        }
    }
}

/// The simulator's true files separate the chain's own error (the camera's
/// blur and noise, dithering, the mura and glare no file corrects) from
/// the calibration's. The true geometry maps onto the true camera, so the
/// reference is the scene with the true camera.
#[test]
fn true_calibration_files_reproduce_the_render() {
    let c = Campaign::new(7);
    let files = c.truth_files();
    let reference = reference_of(&data("moon.toml"));
    let floor = c.black_level_electrons(&reference);
    let sim = c.run_and_capture("truth", c.facility(&c.honest(), &files));
    let truth = compare(&sim, &reference.electrons, floor);
    println!("closed loop, true files: {truth:?}");
    assert!(truth.passes(), "true files: {truth:?}");
}

/// The bundled Moon anchored to LIME is spectral: the facility renders it
/// in `drive.sub_bands` parts of the camera's band and `render` in 10 nm
/// sub-bands. With two parts the facility's camera-effective radiance
/// meets the render as the flat Moon does (one render at the
/// electron-weighted wavelength errs by ~0.9 % on this Moon: printed).
#[test]
fn spectral_moon_through_the_facility_matches_its_render() {
    let c = Campaign::new(7);
    let files = c.truth_files();
    let reference = reference_of(&data("moon_lime.toml"));
    let floor = c.black_level_electrons(&reference);
    let lime_scene = c.path("moon_lime.toml").display().to_string();
    let facility = |n: usize| {
        c.facility(&c.honest(), &files)
            .replace(&c.path("moon.toml").display().to_string(), &lime_scene)
            .replace(
                "bits = 8\n[frame_id]",
                &format!("bits = 8\nsub_bands = {n}\n[frame_id]"),
            )
    };
    assert!(facility(2).contains("sub_bands = 2") && facility(2).contains("moon_lime"));
    let one = compare(
        &c.run_and_capture("one", facility(1)),
        &reference.electrons,
        floor,
    );
    println!("spectral Moon, one render per frame: {one:?}");
    let two = compare(
        &c.run_and_capture("two", facility(2)),
        &reference.electrons,
        floor,
    );
    println!("spectral Moon, sub_bands = 2: {two:?}");
    assert!(two.passes(), "sub_bands = 2: {two:?}");
    assert!(two.disk_signal.abs() <= 0.005, "sub_bands = 2: {two:?}");
}
