//! The simulated facility: a seeded physics model of the screen, the
//! collimator, the facility camera and the spot meter, for rehearsing a
//! calibration campaign and `optistim run` without hardware, and for the
//! tests that close the loop calibrate → run → compare with `render`.
//!
//! It owns the *truth* (configured in `configs/simfacility.toml`, see
//! `docs/SIMFACILITY.md`) and implements the same seams as the hardware:
//! [`Display`] ([`SimScreen`]), [`Camera`] ([`SimCamera`]) and
//! [`SpotMeter`] ([`SimMeter`], also served over a pseudo-terminal by
//! [`pty`]; [`SimSpectroradiometer`] on the same spot). All handles share one state (the frames shown and a virtual
//! clock) behind a mutex: a `present` advances the clock by one refresh, a
//! capture by its exposure, a meter reading by its integration time, never
//! by sleeping.
//!
//! | module | owns |
//! |---|---|
//! | [`config`] | the TOML file and its range checks |
//! | [`screen`] | spectra, the black leak, warm-up; the per-level integrals |
//! | [`panel`] | the colour channels: primaries, tone curves, crosstalk |
//! | [`spatial`] | the screen's non-uniformity: falloff, gradient, mura, the black leak's pattern |
//! | [`clock`] | the clock file that carries virtual time across commands |
//! | [`lab`] | the camera's lab products (intrinsics, flat, responsivity) with their errors |
//! | [`optics`] | camera intrinsics and distortion, collimator and misalignment |
//! | [`camera`] | the camera's optics tables and captures, read out by the one detector model ([`crate::sensor`]) |
//! | [`noise`] | counter-based random numbers (the sensor's) |
//! | [`pty`] | the spot meter served over a pseudo-terminal in a real meter's line protocol |

pub mod camera;
pub mod clock;
pub mod config;
pub mod instruments;
pub mod lab;
pub mod noise;
pub mod optics;
pub mod panel;
pub mod pty;
pub mod screen;
pub mod spatial;

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Instant;

use crate::error::{Error, Result};
use crate::facility::display::Display;
use crate::facility::lut::{decode_grey, FlatField};
use crate::instruments::{CameraFrame, CaptureRequest, Shutter, SpotMeter, SpotReading};

use camera::{CameraModel, WindowFrame};
pub use config::SimFacilityConfig;
use noise::Rng;
use optics::Collimator;
use screen::{CameraResponse, MeterResponse, ScreenPhysics};

/// Random stream of meter readings.
const METER_STREAM: u64 = 2;
/// Random streams of spectroradiometer bins start here (+ reading index).
const SPECTRUM_STREAM: u64 = 1 << 48;

/// The immutable part: the truth and its precomputed tables.
struct Model {
    cfg: SimFacilityConfig,
    screen: ScreenPhysics,
    collimator: Collimator,
    camera: CameraModel,
    /// Screen pixel indices inside the meter's spot.
    spot: Vec<usize>,
    /// ∫_band E☉ dλ / ∫_band E☉ R dλ: L_eff per electron rate.
    effective_per_rate: f64,
}

/// A frame on the screen from `start` (virtual s) until the next one.
struct Shown {
    start: f64,
    levels: Arc<Vec<u16>>,
}

/// The mutable part: the clock, recent frames, counters.
struct State {
    now: f64,
    frames: VecDeque<Shown>,
    presented: u64,
    captures: u64,
    readings: u64,
}

/// The simulated facility. Cloning gives another handle on the same state.
#[derive(Clone)]
pub struct SimFacility {
    model: Arc<Model>,
    state: Arc<Mutex<State>>,
}

impl SimFacility {
    /// Reads a configuration file and builds the facility.
    pub fn load(path: impl AsRef<Path>) -> Result<SimFacility> {
        SimFacility::new(SimFacilityConfig::load(path)?)
    }

    /// Builds the facility: loads the spectra, integrates them per level,
    /// tabulates the camera's geometry. The screen shows black (level 0)
    /// from power-on, virtual time 0.
    pub fn new(cfg: SimFacilityConfig) -> Result<SimFacility> {
        cfg.validate()?;
        let response = CameraResponse::from_config(&cfg.camera)?;
        let meter = MeterResponse::from_config(&cfg.meter)?;
        let screen = ScreenPhysics::new(&cfg.screen, &response, &meter, cfg.seed)?;
        let collimator = Collimator::from_config(&cfg.screen, &cfg.collimator);
        check_folds(&collimator, cfg.screen.resolution)?;
        let camera = CameraModel::new(&cfg.camera, &collimator, cfg.seed)?;
        let spot = spot_pixels(&cfg);
        let [w, h] = cfg.screen.resolution;
        let state = State {
            now: 0.0,
            frames: VecDeque::from([Shown {
                start: 0.0,
                levels: Arc::new(vec![0; w * h]),
            }]),
            presented: 0,
            captures: 0,
            readings: 0,
        };
        Ok(SimFacility {
            model: Arc::new(Model {
                cfg,
                screen,
                collimator,
                camera,
                spot,
                effective_per_rate: response.effective_per_rate,
            }),
            state: Arc::new(Mutex::new(state)),
        })
    }

    fn state(&self) -> MutexGuard<'_, State> {
        // A panic elsewhere cannot leave the state half-updated: recover it.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The configuration: the truth, for tests only (a campaign gets the
    /// lab products of [`Self::write_lab_camera_files`] instead).
    pub fn config(&self) -> &SimFacilityConfig {
        &self.model.cfg
    }

    /// The screen's per-level tables and factors.
    pub fn screen(&self) -> &ScreenPhysics {
        &self.model.screen
    }

    /// Virtual time since power-on, s.
    pub fn now(&self) -> f64 {
        self.state().now
    }

    /// Sets virtual time since power-on (a clock file's value), s; a
    /// value that is not finite and ≥ 0 is refused.
    pub fn set_now(&self, seconds: f64) -> Result<()> {
        if !(seconds.is_finite() && seconds >= 0.0) {
            return Err(Error::invalid(
                "seconds_since_power_on",
                format!("{seconds} is not a finite number ≥ 0"),
            ));
        }
        let mut st = self.state();
        st.now = seconds;
        // What was shown last stays up from the new time on.
        if let Some(last) = st.frames.pop_back() {
            st.frames.clear();
            st.frames.push_back(Shown {
                start: seconds,
                levels: last.levels,
            });
        }
        Ok(())
    }

    /// Lets virtual time pass (a settle time, a pause).
    pub fn advance(&self, seconds: f64) {
        if seconds.is_finite() && seconds > 0.0 {
            self.state().now += seconds;
        }
    }

    /// A [`Display`] handle on the screen.
    pub fn display(&self) -> SimScreen {
        SimScreen {
            facility: self.clone(),
        }
    }

    /// A [`Camera`](crate::instruments::Camera) handle.
    pub fn camera(&self) -> SimCamera {
        SimCamera {
            facility: self.clone(),
        }
    }

    /// A [`SpotMeter`] handle.
    pub fn meter(&self) -> SimMeter {
        SimMeter {
            facility: self.clone(),
        }
    }

    /// A spectroradiometer on the meter's spot: every reading carries the
    /// spectrum (380–780 nm, 5 nm) with the meter's wavelength-scale error
    /// and per-bin noise, whatever `meter.spectrometer` says.
    pub fn spectroradiometer(&self) -> SimSpectroradiometer {
        SimSpectroradiometer {
            facility: self.clone(),
        }
    }

    /// True camera-effective radiance (W m⁻² sr⁻¹, at the screen, before
    /// the collimator) of drive `level` at screen position (u, v), now
    /// (warm-up and drift included).
    /// The channels and the black leak each carry their own pattern.
    pub fn true_camera_effective_radiance(&self, level: usize, screen_xy: (f64, f64)) -> f64 {
        let s = &self.model.screen;
        let (u, v) = screen_xy;
        s.camera_effective_split
            .at(level, s.pattern.main(u, v), s.pattern.leak(u, v))
            * s.warmup(self.now())
    }

    /// The direction (x/z, y/z) in the camera frame at zero attitude under
    /// which the camera sees screen point (u, v): what a geometry file
    /// holds.
    pub fn true_geometry(&self, u_px: f64, v_px: f64) -> (f64, f64) {
        self.model.collimator.screen_to_tan(u_px, v_px)
    }

    /// Continuous camera pixel position where screen point (u, v) is imaged.
    pub fn true_camera_pixel(&self, u_px: f64, v_px: f64) -> (f64, f64) {
        let (x, y) = self.true_geometry(u_px, v_px);
        self.model.camera.optics.project(x, y)
    }

    /// The camera's own flat (vignetting × PRNU, without the cos⁴ law the
    /// renderer also applies), row-major: the truth, for tests only (a
    /// campaign's is [`Self::write_lab_camera_files`]' measured one).
    pub fn camera_flat(&self) -> Vec<f32> {
        self.model.camera.flat()
    }

    /// Writes the camera's true own flat as a Gray32Float TIFF of the
    /// camera's size (the truth, for tests only).
    pub fn write_camera_flat(&self, path: impl AsRef<Path>) -> Result<()> {
        let (w, h) = self.model.camera.size();
        FlatField::from_gains(w, h, self.camera_flat())?.save(path)
    }

    /// Writes the camera's intrinsics file (TOML `fx, fy, cx, cy, k1, k2,
    /// p1, p2, k3` with `cx, cy` in OpenCV's convention, pixel centres at
    /// integers, as OpenCV's calibration writes them: the project's
    /// principal point − 0.5): the truth, for tests only (a campaign's is
    /// [`Self::write_lab_camera_files`]').
    pub fn write_camera_intrinsics(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let c = &self.model.cfg.camera;
        let text = format!(
            "# Intrinsics of the simulated facility camera (OpenCV model; cx, cy with\n\
             # pixel centres at integers, as OpenCV writes them).\n\
             fx = {:?}\nfy = {:?}\ncx = {:?}\ncy = {:?}\n\
             k1 = {:?}\nk2 = {:?}\np1 = {:?}\np2 = {:?}\nk3 = 0.0\n",
            c.fx,
            c.fy,
            c.cx - 0.5,
            c.cy - 0.5,
            c.k1,
            c.k2,
            c.p1,
            c.p2
        );
        std::fs::write(path, text).map_err(|e| Error::io(path, e))
    }

    /// Noise-free meter reading of a uniform screen at `level`, now.
    pub fn true_meter_reading(&self, level: usize) -> f64 {
        let s = &self.model.screen;
        let (main, leak) = self.spot_uniformity();
        s.meter_split.at(level, main, leak) * s.warmup(self.now())
    }

    /// Mean U_main and U_leak over the meter's spot.
    fn spot_uniformity(&self) -> (f64, f64) {
        let p = &self.model.screen.pattern;
        let n = self.model.spot.len().max(1) as f64;
        let (main, leak) = self.model.spot.iter().fold((0.0, 0.0), |(m, l), &k| {
            (m + p.main_map[k] as f64, l + p.leak_map[k] as f64)
        });
        (main / n, leak / n)
    }

    /// Stores a presented frame at the current time, then advances the
    /// clock by one refresh.
    fn present_levels(&self, levels: Vec<u16>) {
        let history = self.model.cfg.screen.history_frames;
        let refresh = 1.0 / self.model.cfg.screen.refresh_hz;
        let mut st = self.state();
        let now = st.now;
        st.frames.push_back(Shown {
            start: now,
            levels: Arc::new(levels),
        });
        while st.frames.len() > history {
            st.frames.pop_front();
        }
        st.now += refresh;
        st.presented += 1;
    }

    /// The frames up during [t0, t1], with their share and warm-up factor.
    /// Before the oldest kept frame, the oldest is taken to have been up.
    fn window(&self, st: &State, t0: f64, t1: f64) -> Vec<(Arc<Vec<u16>>, f64, f64)> {
        let span = (t1 - t0).max(0.0);
        let n = st.frames.len();
        let mut out = Vec::new();
        for (k, f) in st.frames.iter().enumerate() {
            let start = if k == 0 { f64::NEG_INFINITY } else { f.start };
            let end = if k + 1 < n {
                st.frames[k + 1].start
            } else {
                f64::INFINITY
            };
            let (a, b) = (start.max(t0), end.min(t1));
            if span == 0.0 {
                if k + 1 == n {
                    let w = self.model.screen.warmup(t1);
                    out.push((f.levels.clone(), 1.0, w));
                }
            } else if b > a {
                let w = self.model.screen.warmup(0.5 * (a + b));
                out.push((f.levels.clone(), (b - a) / span, w));
            }
        }
        out
    }

    /// A camera frame of what the screen showed during [now − exposure,
    /// now], without moving the clock.
    pub fn capture_last(&self, exposure: f64) -> Result<CameraFrame> {
        self.capture_window(exposure, true)
    }

    /// A frame over [now − exposure, now]: of the screen (`light`) or dark.
    fn capture_window(&self, exposure: f64, light: bool) -> Result<CameraFrame> {
        if !(exposure.is_finite() && exposure > 0.0 && exposure <= 3600.0) {
            return Err(Error::invalid(
                "exposure",
                format!("{exposure} s is not in (0, 3600]"),
            ));
        }
        let (frames, index) = {
            let mut st = self.state();
            let now = st.now;
            let frames = if light {
                self.window(&st, now - exposure, now)
            } else {
                Vec::new()
            };
            st.captures += 1;
            (frames, st.captures - 1)
        };
        let window: Vec<WindowFrame> = frames
            .iter()
            .map(|(levels, weight, warmup)| WindowFrame {
                levels,
                weight: *weight,
                warmup: *warmup,
            })
            .collect();
        let m = &self.model;
        let data = m.camera.capture(
            &m.screen,
            m.cfg.collimator.transmission,
            &window,
            exposure,
            m.cfg.seed,
            index,
        );
        let (width, height) = m.camera.size();
        Ok(CameraFrame {
            width,
            height,
            data,
            exposure_s: exposure,
            saturation_dn: m.cfg.camera.saturation_dn() as f32,
        })
    }

    /// A dark frame (shutter closed: bias, dark current and noise only) of
    /// `exposure` s ending now, without moving the clock.
    pub fn capture_dark(&self, exposure: f64) -> Result<CameraFrame> {
        self.capture_window(exposure, false)
    }

    /// One meter reading over [now − integration, now].
    fn read_meter(&self) -> SpotReading {
        self.read_spot(self.model.cfg.meter.spectrometer)
    }

    /// One reading of the meter's spot over [now − integration, now], with
    /// the spectrum when `spectrum` (a spectroradiometer).
    fn read_spot(&self, spectrum: bool) -> SpotReading {
        let m = &self.model;
        let (frames, index) = {
            let mut st = self.state();
            st.now += m.cfg.meter.integration_time;
            let now = st.now;
            let frames = self.window(&st, now - m.cfg.meter.integration_time, now);
            st.readings += 1;
            (frames, st.readings - 1)
        };
        // Weight of every level's channels, and of the leak, over the spot
        // and the exposure.
        let mut weights = vec![0.0; m.screen.meter.len()];
        let mut leak_weight = 0.0;
        let n = m.spot.len().max(1) as f64;
        let pattern = &m.screen.pattern;
        for (levels, share, warmup) in &frames {
            for &p in &m.spot {
                weights[levels[p] as usize] += share * warmup * pattern.main_map[p] as f64 / n;
                leak_weight += share * warmup * pattern.leak_map[p] as f64 / n;
            }
        }
        let split = &m.screen.meter_split;
        let clean: f64 = weights
            .iter()
            .zip(&split.main)
            .map(|(a, b)| a * b)
            .sum::<f64>()
            + leak_weight * split.leak;
        let mut rng = Rng::new(m.cfg.seed, METER_STREAM, index);
        let factor = 1.0 + m.cfg.meter.noise * rng.normal();
        let spectrum = spectrum.then(|| self.meter_spectrum(&weights, leak_weight, factor, index));
        SpotReading {
            value: clean * factor,
            spectrum,
        }
    }

    /// A spectroradiometer's reading: the spot's spectrum at the
    /// instrument's (shifted) wavelength scale, × the reading's `factor`
    /// and per-bin noise.
    fn meter_spectrum(
        &self,
        weights: &[f64],
        leak_weight: f64,
        factor: f64,
        index: u64,
    ) -> Vec<(f64, f64)> {
        let m = &self.model;
        let shift = m.cfg.meter.wavelength_error_nm;
        let mut total: Vec<(f64, f64)> = m
            .screen
            .meter_spectrum(0, shift)
            .iter()
            .map(|&(nm, _, leak)| (nm, leak_weight * leak))
            .collect();
        for (level, &wt) in weights.iter().enumerate().filter(|(_, w)| **w > 0.0) {
            for (t, (_, main, _)) in total.iter_mut().zip(m.screen.meter_spectrum(level, shift)) {
                t.1 += wt * main;
            }
        }
        let mut rng = Rng::new(m.cfg.seed, SPECTRUM_STREAM + index, 0);
        let noise = m.cfg.meter.spectrum_noise;
        for t in total.iter_mut() {
            t.1 *= factor * (1.0 + noise * rng.normal());
        }
        total
    }
}

/// The collimator's distortion must not fold over on the screen: its
/// Jacobian's determinant stays positive on a 17 × 17 grid including the
/// corners.
fn check_folds(c: &Collimator, [w, h]: [usize; 2]) -> Result<()> {
    for j in 0..=16 {
        for i in 0..=16 {
            let (u, v) = (w as f64 * i as f64 / 16.0, h as f64 * j as f64 / 16.0);
            let det = c.jacobian_det(u, v);
            if !(det > 0.05) {
                return Err(Error::invalid(
                    "collimator.thin_prism",
                    format!("the distortion (k1, k2, p1, p2, thin_prism) folds over at screen ({u}, {v})"),
                ));
            }
        }
    }
    Ok(())
}

/// Screen pixels whose centres lie in the meter's spot (at least the one
/// under its centre).
fn spot_pixels(cfg: &SimFacilityConfig) -> Vec<usize> {
    let [w, h] = cfg.screen.resolution;
    let [cx, cy] = cfg.meter.spot_center_px;
    let r = cfg.meter.spot_radius_px;
    let (x0, x1) = (
        (cx - r).floor().max(0.0) as usize,
        ((cx + r).ceil() as usize).min(w),
    );
    let (y0, y1) = (
        (cy - r).floor().max(0.0) as usize,
        ((cy + r).ceil() as usize).min(h),
    );
    let mut spot = Vec::new();
    for y in y0..y1 {
        for x in x0..x1 {
            if (x as f64 + 0.5 - cx).hypot(y as f64 + 0.5 - cy) <= r {
                spot.push(y * w + x);
            }
        }
    }
    if spot.is_empty() {
        spot.push((cy as usize).min(h - 1) * w + (cx as usize).min(w - 1));
    }
    spot
}

/// The simulated screen, as a [`Display`].
#[derive(Clone)]
pub struct SimScreen {
    facility: SimFacility,
}

impl Display for SimScreen {
    fn present(&mut self, frame: &[u32]) -> Result<Instant> {
        let (w, h) = self.size();
        if frame.len() != w * h {
            return Err(Error::invalid(
                "frame",
                format!("{} pixels for a {w}×{h} simulated screen", frame.len()),
            ));
        }
        let bits = self.facility.model.cfg.screen.bits;
        let levels = frame.iter().map(|&p| decode_grey(p, bits) as u16).collect();
        self.facility.present_levels(levels);
        Ok(Instant::now())
    }

    fn is_open(&self) -> bool {
        true
    }

    fn size(&self) -> (usize, usize) {
        let [w, h] = self.facility.model.cfg.screen.resolution;
        (w, h)
    }
}

/// The simulated facility camera.
#[derive(Clone)]
pub struct SimCamera {
    facility: SimFacility,
}

impl crate::instruments::Camera for SimCamera {
    /// Exposes for `request.exposure_s` from now (the clock advances by
    /// it) and returns what the screen showed meanwhile.
    fn capture(&mut self, request: &CaptureRequest) -> Result<CameraFrame> {
        let t = request.exposure_s;
        if !(t.is_finite() && t > 0.0 && t <= 3600.0) {
            return Err(Error::invalid(
                "exposure",
                format!("pattern {}: {t} s is not in (0, 3600]", request.pattern),
            ));
        }
        self.facility.advance(t);
        match request.shutter {
            Shutter::Open => self.facility.capture_last(t),
            Shutter::Closed => self.facility.capture_dark(t),
        }
    }

    fn describe(&self) -> String {
        let c = &self.facility.model.cfg.camera;
        format!(
            "simulated facility camera {}x{} ({} bit, gain {} DN/e-, seed {})",
            c.resolution[0], c.resolution[1], c.bits, c.gain, self.facility.model.cfg.seed
        )
    }
}

/// The simulated spot meter.
#[derive(Clone)]
pub struct SimMeter {
    facility: SimFacility,
}

impl SpotMeter for SimMeter {
    fn measure(&mut self) -> Result<SpotReading> {
        Ok(self.facility.read_meter())
    }

    fn describe(&self) -> String {
        let m = &self.facility.model.cfg.meter;
        format!(
            "simulated spot meter ({}, spot {:?} r {} px, noise {})",
            m.response, m.spot_center_px, m.spot_radius_px, m.noise
        )
    }
}

/// The simulated spectroradiometer (the meter's spot, always with the
/// spectrum).
#[derive(Clone)]
pub struct SimSpectroradiometer {
    facility: SimFacility,
}

impl SpotMeter for SimSpectroradiometer {
    fn measure(&mut self) -> Result<SpotReading> {
        Ok(self.facility.read_spot(true))
    }

    fn describe(&self) -> String {
        let m = &self.facility.model.cfg.meter;
        format!(
            "simulated spectroradiometer (380-780 nm in 5 nm bins, spot {:?} r {} px)",
            m.spot_center_px, m.spot_radius_px
        )
    }
}

/// A [`Display`] for `optistim run`: shows frames on the simulated screen
/// and writes what the simulated camera captured (its configured exposure,
/// ending at the end of the frame's first refresh) as 16-bit PNG, every
/// `every`-th frame, into `dir` (`frame_000000.png`, …).
pub struct RecordingScreen {
    screen: SimScreen,
    dir: PathBuf,
    every: u64,
    shown: u64,
    /// Files written.
    pub written: Vec<PathBuf>,
}

impl RecordingScreen {
    /// Creates `dir`. `every` 0 is taken as 1.
    pub fn new(facility: &SimFacility, dir: impl Into<PathBuf>, every: u64) -> Result<Self> {
        let dir = dir.into();
        std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
        Ok(RecordingScreen {
            screen: facility.display(),
            dir,
            every: every.max(1),
            shown: 0,
            written: Vec::new(),
        })
    }
}

impl Display for RecordingScreen {
    fn present(&mut self, frame: &[u32]) -> Result<Instant> {
        let at = self.screen.present(frame)?;
        if self.shown.is_multiple_of(self.every) {
            let f = &self.screen.facility;
            let shot = f.capture_last(f.model.cfg.camera.exposure)?;
            let path = self.dir.join(format!("frame_{:06}.png", self.shown));
            write_png16(&shot, &path)?;
            self.written.push(path);
        }
        self.shown += 1;
        Ok(at)
    }

    fn is_open(&self) -> bool {
        true
    }

    fn size(&self) -> (usize, usize) {
        self.screen.size()
    }
}

/// Writes a camera frame as a 16-bit greyscale PNG (DN as is).
pub fn write_png16(frame: &CameraFrame, path: &Path) -> Result<()> {
    let data: Vec<u16> = frame
        .data
        .iter()
        .map(|&v| v.clamp(0.0, u16::MAX as f32) as u16)
        .collect();
    let img = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(
        frame.width as u32,
        frame.height as u32,
        data,
    )
    .ok_or_else(|| Error::invalid("frame", "size does not match its data"))?;
    img.save(path)
        .map_err(|e| Error::parse(path, format!("cannot write PNG: {e}")))
}
