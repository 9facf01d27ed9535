//! The simulated facility: a seeded physics model of the screen, the
//! collimator, the facility camera and the spot meter, for rehearsing a
//! calibration campaign and `optistim run` without hardware, and for the
//! tests that close the loop calibrate → run → compare with `render`.
//!
//! It owns the *truth* (configured in `configs/simfacility.toml`, see
//! `docs/SIMFACILITY.md`) and implements the same seams as the hardware:
//! [`Display`] ([`SimScreen`]), [`Camera`] ([`SimCamera`]) and
//! [`SpotMeter`] ([`SimMeter`], also served over a pseudo-terminal by
//! [`pty`]). All handles share one state (the frames shown and a virtual
//! clock) behind a mutex: a `present` advances the clock by one refresh, a
//! capture by its exposure, a meter reading by its integration time, never
//! by sleeping.
//!
//! | module | owns |
//! |---|---|
//! | [`config`] | the TOML file and its range checks |
//! | [`screen`] | spectra, level → radiance curve, non-uniformity, warm-up; the per-level integrals |
//! | [`optics`] | camera intrinsics and distortion, collimator and misalignment |
//! | [`camera`] | the camera's tables and detector chain |
//! | [`noise`] | counter-based random numbers |
//! | [`pty`] | the spot meter served over a pseudo-terminal in a real meter's line protocol |

pub mod camera;
pub mod config;
pub mod noise;
pub mod optics;
pub mod pty;
pub mod screen;

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

/// The immutable part: the truth and its precomputed tables.
struct Model {
    cfg: SimFacilityConfig,
    screen: ScreenPhysics,
    collimator: Collimator,
    camera: CameraModel,
    /// Screen pixel indices inside the meter's spot.
    spot: Vec<usize>,
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
        let screen = ScreenPhysics::new(&cfg.screen, &response, &meter)?;
        let collimator = Collimator::from_config(&cfg.screen, &cfg.collimator);
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
            }),
            state: Arc::new(Mutex::new(state)),
        })
    }

    fn state(&self) -> MutexGuard<'_, State> {
        // A panic elsewhere cannot leave the state half-updated: recover it.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The configuration.
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

    /// True camera-effective radiance (W m⁻² sr⁻¹, at the screen, before
    /// the collimator) of drive `level` at screen position (u, v), now
    /// (warm-up and drift included).
    pub fn true_camera_effective_radiance(&self, level: usize, screen_xy: (f64, f64)) -> f64 {
        let s = &self.model.screen;
        let level = level.min(s.camera_effective.len() - 1);
        s.camera_effective[level] * s.uniformity(screen_xy.0, screen_xy.1) * s.warmup(self.now())
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
    /// renderer also applies), row-major.
    pub fn camera_flat(&self) -> Vec<f32> {
        self.model.camera.flat().to_vec()
    }

    /// Writes the camera's own flat as a Gray32Float TIFF of the camera's
    /// size.
    pub fn write_camera_flat(&self, path: impl AsRef<Path>) -> Result<()> {
        let (w, h) = self.model.camera.size();
        FlatField::from_gains(w, h, self.camera_flat())?.save(path)
    }

    /// Writes the camera's intrinsics file (TOML `fx, fy, cx, cy, k1, k2,
    /// p1, p2, k3` with `cx, cy` in OpenCV's convention, pixel centres at
    /// integers, as OpenCV's calibration writes them: the project's
    /// principal point − 0.5), what a campaign gets from the camera's own
    /// calibration.
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
        let level = level.min(s.meter.len() - 1);
        s.meter[level] * self.spot_uniformity() * s.warmup(self.now())
    }

    fn spot_uniformity(&self) -> f64 {
        let w = self.model.cfg.screen.resolution[0];
        let s = &self.model.screen;
        let sum: f64 = self
            .model
            .spot
            .iter()
            .map(|&p| s.uniformity((p % w) as f64 + 0.5, (p / w) as f64 + 0.5))
            .sum();
        sum / self.model.spot.len().max(1) as f64
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
            saturation_dn: m.cfg.camera.max_dn() as f32,
        })
    }

    /// A dark frame (shutter closed: bias, dark current and noise only) of
    /// `exposure` s ending now, without moving the clock.
    pub fn capture_dark(&self, exposure: f64) -> Result<CameraFrame> {
        self.capture_window(exposure, false)
    }

    /// One meter reading over [now − integration, now].
    fn read_meter(&self) -> SpotReading {
        let m = &self.model;
        let w = m.cfg.screen.resolution[0];
        let (frames, index) = {
            let mut st = self.state();
            st.now += m.cfg.meter.integration_time;
            let now = st.now;
            let frames = self.window(&st, now - m.cfg.meter.integration_time, now);
            st.readings += 1;
            (frames, st.readings - 1)
        };
        // Weight of every level over the spot and the exposure.
        let mut weights = vec![0.0; m.screen.meter.len()];
        let n = m.spot.len().max(1) as f64;
        for (levels, share, warmup) in &frames {
            for &p in &m.spot {
                let u = m
                    .screen
                    .uniformity((p % w) as f64 + 0.5, (p / w) as f64 + 0.5);
                weights[levels[p] as usize] += share * warmup * u / n;
            }
        }
        let clean: f64 = weights
            .iter()
            .zip(&m.screen.meter)
            .map(|(a, b)| a * b)
            .sum();
        let mut rng = Rng::new(m.cfg.seed, METER_STREAM, index);
        let factor = 1.0 + m.cfg.meter.noise * rng.normal();
        let spectrum = m.cfg.meter.spectrometer.then(|| {
            let mut total: Vec<(f64, f64)> = m.screen.meter_spectrum(0);
            total.iter_mut().for_each(|p| p.1 = 0.0);
            for (level, &wt) in weights.iter().enumerate().filter(|(_, w)| **w > 0.0) {
                for (t, (_, v)) in total.iter_mut().zip(m.screen.meter_spectrum(level)) {
                    t.1 += wt * v * factor;
                }
            }
            total
        });
        SpotReading {
            value: clean * factor,
            spectrum,
        }
    }
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
