//! The real-time loop of `optistim run`: states in, screen-space render,
//! drive levels, present, sync, log.
//!
//! Two threads share the work. The *render* thread takes the newest state,
//! renders the body's radiance on the screen's pixel grid as seen through the
//! collimator (the screen is a pinhole of focal length f_collimator and the
//! screen's pixel pitch, or, with a geometric calibration, an ideal grid
//! pre-warped onto the screen; see [`ScreenModel`]), converts it into drive
//! levels inside the body's region of interest and draws the frame-id
//! block. The calling thread *presents* the frame at its slot, sends the
//! sync line, waits for the acknowledgement if asked, and writes the log
//! record. Two frame buffers
//! circulate between them, so frame k+1 is rendered while frame k is on
//! screen, and nothing is allocated per frame.
//!
//! Late latching: the render thread does not take a state as soon as a
//! buffer is free, which would make every frame a slot old when shown. It
//! waits until the next slot minus its budget, the largest render,
//! conversion and present time of the last [`BUDGET_WINDOW`] frames plus a
//! margin, then takes the newest state.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{channel, sync_channel, Receiver, Sender, SyncSender};
use std::sync::Arc;
use std::time::{Duration, Instant};

use glam::DQuat;

use super::config::FacilityConfig;
use super::display::Display;
use super::dither::{ConvertSettings, Converter, Roi, ThresholdMatrix};
use super::frame_id::FrameIdCode;
use super::geometry::{GeometryCalibration, PreWarp};
use super::log::{FrameLog, FrameRecord, Summary};
use super::lut::{DisplayLut, FlatField};
use super::serial::{CommandTemplate, FrameCommand, SendOutcome, SyncPort};
use super::throttle::Throttle;
use super::trajectory::{State as TrajectoryState, Trajectory};
use super::udp::UdpStateReceiver;
use crate::error::{Error, Result};
use crate::radiometry::reflectance::Reflectance;
use crate::radiometry::spectrum::band_integrals;
use crate::render::detector::band_model;
use crate::render::{BandModel, Renderer};
use crate::scene::{Pinhole, Scene, State};

/// Where states come from.
pub enum StateSource {
    /// Replay a trajectory, one state per frame.
    Replay(Trajectory),
    /// Closed loop: one state per datagram from `sender`, newest wins.
    Udp {
        /// Address to bind.
        bind: SocketAddr,
        /// Only datagrams from this address are accepted.
        sender: SocketAddr,
    },
}

/// Everything `run` needs besides the backends.
pub struct RunPlan {
    /// Facility configuration.
    pub config: FacilityConfig,
    /// The scene (body, Sun, flight camera).
    pub scene: Scene,
    /// State source.
    pub source: StateSource,
    /// Stop after this many frames (replay: at most the trajectory's).
    pub frames: Option<u64>,
    /// Frame log (JSON lines, appended).
    pub log: PathBuf,
    /// Run summary (JSON).
    pub summary: PathBuf,
}

/// What the render thread hands to the presenter.
struct Job {
    buffer: Vec<u32>,
    frame: u64,
    state_t: f64,
    state_received: Option<Instant>,
    render_start: Instant,
    render_end: Instant,
    convert_end: Instant,
    clipped: u64,
    peak: f64,
    safe: bool,
}

/// The static part of the screen-space renderer: what the camera sees on
/// the screen. Either the screen pinhole turned by `alignment.rotation`, or,
/// with a geometric calibration, an ideal pinhole grid pre-warped onto the
/// screen.
pub struct ScreenModel {
    renderer: Renderer,
    /// Screen pixels per rendered pixel along each axis (`screen.render_block`).
    block: usize,
    solid_angle: Vec<f32>,
    /// What one frame renders: one band, or `drive.sub_bands` parts of the
    /// camera's band for a spectral body.
    bands: Vec<ScreenBand>,
    /// Σ over sub-bands of weight × flux, over the ROI (sub-bands > 1).
    accumulated: Vec<f64>,
    screen: (usize, usize),
    rotation: f64,
    warp: Option<PreWarp>,
    /// Radiance over the rendered ROI, when it is not the screen's: the
    /// ideal grid of the pre-warp, or a grid of blocks.
    ideal_target: Vec<f32>,
    roi_target: Vec<f32>,
}

/// One render of a frame: the body's model in a part of the camera's band,
/// and the weight that turns its flux per unit irradiance into
/// camera-effective radiance.
struct ScreenBand {
    model: Reflectance,
    albedo: Option<f64>,
    map_scale: f64,
    /// Band solar irradiance at 1 au × this part's share of the camera's
    /// electrons [W m⁻²].
    weight: f64,
}

/// The renders of one frame. A spectrally flat body, or `sub_bands` 1: one
/// render at the camera's electron-weighted wavelength (exact for a
/// reflectance linear across the band). Otherwise `sub_bands` equal parts,
/// each at its own centroid, weighted by its share of the electrons: the
/// camera-effective radiance L_eff = E_band Σ_k (e_k / e) f_k.
fn screen_bands(scene: &Scene, sub_bands: usize) -> Vec<ScreenBand> {
    let cam = &scene.camera;
    let whole = band_integrals(
        &scene.sun,
        &cam.quantum_efficiency,
        &cam.transmission,
        cam.band,
        1,
    );
    let e_band = whole[0].irradiance_1au;
    let band = |wavelength: f64, weight: f64| {
        let model = scene.body.reflectance.at_wavelength(wavelength);
        let b = band_model(&scene.body, &model, wavelength);
        let (albedo, map_scale) = (b.albedo, b.map_scale);
        ScreenBand {
            model,
            albedo,
            map_scale,
            weight,
        }
    };
    if scene.body.is_spectrally_flat() || sub_bands <= 1 {
        return vec![band(response_weighted_wavelength(scene), e_band)];
    }
    let parts = band_integrals(
        &scene.sun,
        &cam.quantum_efficiency,
        &cam.transmission,
        cam.band,
        sub_bands,
    );
    let electrons: f64 = parts.iter().map(|p| p.electron_rate_1au).sum();
    if electrons <= 0.0 {
        return vec![band(response_weighted_wavelength(scene), e_band)];
    }
    parts
        .iter()
        .filter(|p| p.electron_rate_1au > 0.0)
        .map(|p| band(p.centroid, e_band * p.electron_rate_1au / electrons))
        .collect()
}

/// The camera's electron-weighted mean wavelength over its band [m]: where
/// a single render stands for a spectral body.
fn response_weighted_wavelength(scene: &Scene) -> f64 {
    let cam = &scene.camera;
    let parts = band_integrals(
        &scene.sun,
        &cam.quantum_efficiency,
        &cam.transmission,
        cam.band,
        32,
    );
    let total: f64 = parts.iter().map(|b| b.electron_rate_1au).sum();
    if total > 0.0 {
        parts
            .iter()
            .map(|b| b.centroid * b.electron_rate_1au)
            .sum::<f64>()
            / total
    } else {
        0.5 * (cam.band[0] + cam.band[1])
    }
}

/// The screen as a pinhole camera behind the collimator.
pub fn screen_pinhole(config: &FacilityConfig) -> Pinhole {
    let [w, h] = config.screen.resolution;
    let f = config.collimator.focal_length / config.screen.pixel_pitch;
    Pinhole {
        width: w,
        height: h,
        fx: f,
        fy: f,
        cx: w as f64 / 2.0 + config.alignment.offset_px[0],
        cy: h as f64 / 2.0 + config.alignment.offset_px[1],
    }
}

/// The grid the renderer draws on without a geometric calibration: the
/// screen pinhole with `screen.render_block`² screen pixels per pixel.
/// Rendered pixel (I, J) covers screen pixels [bI, bI + b) × [bJ, bJ + b).
pub fn block_pinhole(config: &FacilityConfig) -> Pinhole {
    let screen = screen_pinhole(config);
    let b = config.screen.render_block.max(1);
    let s = 1.0 / b as f64;
    Pinhole {
        width: screen.width.div_ceil(b),
        height: screen.height.div_ceil(b),
        fx: screen.fx * s,
        fy: screen.fy * s,
        cx: screen.cx * s,
        cy: screen.cy * s,
    }
}

/// Frames over which the late-latching budget is taken.
pub const BUDGET_WINDOW: usize = 60;
/// Safety margin added to the late-latching budget.
const BUDGET_MARGIN: Duration = Duration::from_millis(2);

/// Shared by the two threads for late latching: the next free slot with
/// the frame that will take it, and the recent present times.
struct Pacer {
    /// Next slot and the id of the frame to be presented in it (None:
    /// nothing presented yet).
    next: std::sync::Mutex<Option<(Instant, u64)>>,
    /// Largest present duration seen recently, ns.
    present_ns: std::sync::atomic::AtomicU64,
}

impl Pacer {
    /// The slot frame `frame` will be shown in if the frames before it are
    /// on time: frames are presented in order, one per slot.
    fn slot_of(&self, frame: u64, period: Duration) -> Option<Instant> {
        let (slot, next_frame) = (*self.next.lock().ok()?)?;
        let ahead = frame.saturating_sub(next_frame).min(1 << 20) as u32;
        Some(slot + period * ahead)
    }

    fn set_next(&self, slot: Instant, frame: u64) {
        if let Ok(mut next) = self.next.lock() {
            *next = Some((slot, frame));
        }
    }
}

/// Recent per-frame work times of the render thread.
struct Budget {
    recent: std::collections::VecDeque<Duration>,
}

impl Budget {
    fn record(&mut self, d: Duration) {
        if self.recent.len() == BUDGET_WINDOW {
            self.recent.pop_front();
        }
        self.recent.push_back(d);
    }

    /// Time to reserve before a slot: the slowest recent frame, the
    /// slowest recent present, and the margin.
    fn reserve(&self, present: Duration) -> Option<Duration> {
        let work = self.recent.iter().max()?;
        Some(*work + present + BUDGET_MARGIN)
    }
}

/// Scene state of a trajectory state: the body pose defaults to the
/// scene file's.
fn scene_state(s: &TrajectoryState, base: &State) -> State {
    State {
        body_position: s.body_position.unwrap_or(base.body_position),
        body_attitude: s.body_attitude.unwrap_or(base.body_attitude),
        camera_position: s.camera_position,
        camera_attitude: s.camera_attitude,
        sun_position: s.sun_position,
        occulter: base.occulter,
    }
}

impl ScreenModel {
    /// Builds the model of `config`'s screen for `scene`; `geometry` (the
    /// loaded `calibration.geometry`) replaces the screen pinhole and the
    /// alignment.
    pub fn new(
        config: &FacilityConfig,
        scene: &Scene,
        geometry: Option<&GeometryCalibration>,
    ) -> Self {
        let block = config.screen.render_block.max(1);
        let warp = geometry.map(|g| {
            let warp = PreWarp::with_block(g, block);
            let nominal = config.collimator.focal_length / config.screen.pixel_pitch;
            let f = warp.ideal_pinhole().fx * block as f64;
            if (f / nominal - 1.0).abs() > 0.05 {
                tracing::warn!(
                    file = %g.path().display(),
                    scale_px = f,
                    nominal_px = nominal,
                    "geometry file's scale differs from collimator.focal_length / screen.pixel_pitch by more than 5 %"
                );
            }
            warp
        });
        let pin = match &warp {
            Some(w) => w.ideal_pinhole().clone(),
            None => block_pinhole(config),
        };
        let camera_fx = scene.camera.pinhole.fx.min(scene.camera.pinhole.fy);
        if block > 1 && pin.fx < camera_fx {
            tracing::warn!(
                render_block = block,
                block_urad = 1e6 / pin.fx,
                camera_pixel_urad = 1e6 / camera_fx,
                "the camera's pixels are smaller than a render block: it resolves the blocks"
            );
        }
        let renderer = Renderer::new(pin.clone());
        let solid_angle = pin.solid_angle_table();
        // Build the albedo map's summed-area table and levels now, not in frame 0.
        if let Some(map) = &scene.body.albedo_map {
            map.box_average(0.0, 0.0, 1.0, 1.0);
            map.sample_stretched(0.0, 0.0, 4.0);
        }
        ScreenModel {
            renderer,
            block,
            solid_angle,
            bands: screen_bands(scene, config.drive.sub_bands),
            accumulated: Vec::new(),
            screen: config.screen_size(),
            rotation: if warp.is_some() {
                0.0
            } else {
                config.alignment.rotation
            },
            warp,
            ideal_target: Vec::new(),
            roi_target: Vec::new(),
        }
    }

    /// The grid the renderer draws on: the screen pinhole, or the ideal
    /// grid of the pre-warp.
    pub fn render_grid(&self) -> &Pinhole {
        self.renderer.camera()
    }

    /// Renders the scene radiance [W m⁻² sr⁻¹] seen by the camera in
    /// `state` onto the screen; returns the screen ROI ([`target`](Self::target)
    /// holds its radiance, row-major) or None when nothing is visible.
    pub fn render(&mut self, scene: &Scene, state: &State) -> Option<Roi> {
        let mut st = *state;
        // The screen's x axis is turned by `rotation` in the camera frame.
        st.camera_attitude = state.camera_attitude * DQuat::from_rotation_z(self.rotation);
        let r = self.render_bands(scene, &st);
        let w = self.renderer.camera().width;
        let out = if self.warp.is_some() || self.block > 1 {
            &mut self.ideal_target
        } else {
            &mut self.roi_target
        };
        out.clear();
        if let [one] = self.bands.as_slice() {
            let flux = self.renderer.flux();
            for row in r.y0..r.y1 {
                let k = row * w;
                out.extend(
                    flux[k + r.x0..k + r.x1]
                        .iter()
                        .zip(&self.solid_angle[k + r.x0..k + r.x1])
                        .map(|(&f, &o)| (one.weight * f as f64 / o as f64) as f32),
                );
            }
        } else {
            let mut acc = self.accumulated.iter();
            for row in r.y0..r.y1 {
                let k = row * w;
                out.extend(
                    self.solid_angle[k + r.x0..k + r.x1]
                        .iter()
                        .zip(acc.by_ref())
                        .map(|(&o, &f)| (f / o as f64) as f32),
                );
            }
        }
        let ideal = Roi::new(r.x0, r.y0, r.width(), r.height());
        match &mut self.warp {
            // Always called, so the previous frame's ideal radiance is cleared.
            Some(warp) => warp.apply(ideal, &self.ideal_target, &mut self.roi_target),
            None if r.is_empty() => None,
            None if self.block == 1 => Some(ideal),
            None => Some(expand_blocks(
                ideal,
                &self.ideal_target,
                self.block,
                self.screen,
                &mut self.roi_target,
            )),
        }
    }

    /// Renders every band of the frame; with several, sums weight × flux
    /// over the ROI into `accumulated`. Returns the ROI (on the render grid).
    fn render_bands(&mut self, scene: &Scene, st: &State) -> crate::render::caps::Rect {
        let w = self.renderer.camera().width;
        let mut roi = None;
        self.accumulated.clear();
        for (i, b) in self.bands.iter().enumerate() {
            let band = BandModel {
                model: Some(&b.model),
                albedo: b.albedo,
                map_scale: b.map_scale,
            };
            let stats = self
                .renderer
                .render_flux_band(&scene.body, st, &scene.render, &band);
            let r = *roi.get_or_insert(stats.roi);
            if self.bands.len() == 1 {
                break;
            }
            let flux = self.renderer.flux();
            let rows = (r.y0..r.y1).flat_map(|row| &flux[row * w + r.x0..row * w + r.x1]);
            if i == 0 {
                self.accumulated.extend(rows.map(|&f| b.weight * f as f64));
            } else {
                for (a, &f) in self.accumulated.iter_mut().zip(rows) {
                    *a += b.weight * f as f64;
                }
            }
        }
        roi.expect("at least one band")
    }

    /// Screen radiance of the last [`render`](Self::render), row-major over
    /// its ROI.
    pub fn target(&self) -> &[f32] {
        &self.roi_target
    }
}

/// Spreads the radiance of rendered blocks (row-major over `blocks`, a
/// region of the block grid) over their screen pixels into `out`
/// (row-major over the returned screen region, clipped to the screen):
/// every pixel of a block shows the block's mean radiance, so each block
/// sends the flux that was integrated over it.
fn expand_blocks(
    blocks: Roi,
    radiance: &[f32],
    block: usize,
    screen: (usize, usize),
    out: &mut Vec<f32>,
) -> Roi {
    let x0 = blocks.x * block;
    let y0 = blocks.y * block;
    let x1 = ((blocks.x + blocks.width) * block).min(screen.0);
    let y1 = ((blocks.y + blocks.height) * block).min(screen.1);
    let roi = Roi::new(x0, y0, x1.saturating_sub(x0), y1.saturating_sub(y0));
    out.clear();
    out.reserve(roi.area());
    for y in y0..y1 {
        let src = &radiance[(y / block - blocks.y) * blocks.width..][..blocks.width];
        out.extend((x0..x1).map(|x| src[x / block - blocks.x]));
    }
    roi
}

/// Frame source used by the render thread.
enum Source {
    Replay {
        states: Vec<TrajectoryState>,
        next: usize,
    },
    Udp(Box<UdpStateReceiver>),
}

/// The render thread: waits for a free buffer, takes the newest state,
/// renders, converts, draws the frame id, and hands the frame over. Returns
/// the datagrams the kernel dropped from the UDP socket's receive buffer,
/// where the OS tells (closed loop on Linux).
#[allow(clippy::too_many_arguments)]
fn render_loop(
    scene: Scene,
    mut model: ScreenModel,
    mut converter: Converter,
    frame_id: FrameIdCode,
    mut source: Source,
    frames: Option<u64>,
    state_timeout: Duration,
    stop: Arc<AtomicBool>,
    free: Receiver<Vec<u32>>,
    ready: SyncSender<Job>,
    dropped: Arc<std::sync::atomic::AtomicU64>,
    pacer: Option<Arc<Pacer>>,
    period: Duration,
) -> Result<Option<u64>> {
    let black = converter.black_pixel();
    let mut no_state = Throttle::default();
    let mut budget = Budget {
        recent: std::collections::VecDeque::with_capacity(BUDGET_WINDOW),
    };
    let mut last: Option<(TrajectoryState, Instant)> = None;
    // ROI last drawn into each buffer, by buffer address.
    let mut drawn: Vec<(usize, Option<Roi>)> = Vec::new();
    let mut frame = 0u64;
    let mut warned_peak = false;
    while !stop.load(Ordering::Relaxed) {
        if frames.is_some_and(|n| frame >= n) {
            break;
        }
        let Ok(mut buffer) = free.recv() else { break };
        if let Some(p) = &pacer {
            let present = Duration::from_nanos(p.present_ns.load(Ordering::Relaxed));
            // The slot this frame will be shown in, counted from the next
            // free slot past the frames still queued before it.
            let target = p.slot_of(frame, period);
            if let (Some(slot), Some(reserve)) = (target, budget.reserve(present)) {
                if let Some(start) = slot.checked_sub(reserve) {
                    while !stop.load(Ordering::Relaxed) {
                        let now = Instant::now();
                        if now >= start {
                            break;
                        }
                        std::thread::sleep((start - now).min(Duration::from_millis(50)));
                    }
                }
            }
        }
        let render_start = Instant::now();
        let (state, received) = match &mut source {
            Source::Replay { states, next } => {
                if *next >= states.len() {
                    break;
                }
                *next += 1;
                (Some(states[*next - 1]), None)
            }
            Source::Udp(rx) => {
                if let Some((s, at)) = rx.latest() {
                    last = Some((s, at));
                }
                dropped.store(rx.stats().dropped(), Ordering::Relaxed);
                match &last {
                    Some((s, at)) if at.elapsed() <= state_timeout => (Some(*s), Some(*at)),
                    _ => (None, last.as_ref().map(|l| l.1)),
                }
            }
        };
        // Clear what this buffer showed last time (cost: that ROI only).
        let key = buffer.as_ptr() as usize;
        let slot = match drawn.iter().position(|(k, _)| *k == key) {
            Some(i) => i,
            None => {
                drawn.push((key, None));
                drawn.len() - 1
            }
        };
        if let Some(old) = drawn[slot].1.take() {
            let w = model.screen.0;
            for row in old.y..old.y + old.height {
                buffer[row * w + old.x..row * w + old.x + old.width].fill(black);
            }
        }
        converter.forget_previous_roi();
        let (state_t, safe) = match &state {
            Some(s) => (s.t, false),
            None => (f64::NAN, true),
        };
        let mut roi = None;
        if let Some(s) = &state {
            let st = scene_state(s, &scene.state);
            roi = model.render(&scene, &st);
        }
        let render_end = Instant::now();
        let mut clipped = 0;
        let mut peak = 0.0;
        if let Some(r) = roi {
            let stats = converter.convert(&model.roi_target, r, frame, &mut buffer)?;
            clipped = stats.clipped();
            peak = stats.peak_target;
            if stats.clipped_high > 0 && !warned_peak {
                warned_peak = true;
                tracing::warn!(
                    frame,
                    peak_radiance = peak,
                    pixels = stats.clipped_high,
                    "scene peak exceeds what the screen can show at this k; clipped"
                );
            }
        }
        drawn[slot].1 = roi;
        if safe {
            if let Some(more) = no_state.hit(Instant::now()) {
                tracing::warn!(
                    frame,
                    more,
                    "no current state: showing the safe (black) frame"
                );
            }
        }
        frame_id.encode(&mut buffer, frame)?;
        let convert_end = Instant::now();
        budget.record(convert_end - render_start);
        let job = Job {
            buffer,
            frame,
            state_t,
            state_received: received,
            render_start,
            render_end,
            convert_end,
            clipped,
            peak,
            safe,
        };
        if ready.send(job).is_err() {
            break;
        }
        frame += 1;
    }
    Ok(match &source {
        Source::Udp(rx) => rx.kernel_drops(),
        Source::Replay { .. } => None,
    })
}

/// Renders made before the first frame: they build what the renderer makes
/// on first use (the map's longitude levels, summed-area tables, buffers),
/// so the first frames are not late for it, and they time the scene.
const PREFLIGHT_RENDERS: usize = 3;

/// Refreshes per frame that leave a render of `render` a quarter of margin
/// in its slot (at least 1).
pub fn refreshes_needed(render: Duration, refresh: Duration) -> u32 {
    let slots = 1.25 * render.as_secs_f64() / refresh.as_secs_f64();
    (slots.ceil() as u32).max(1)
}

/// Median time of [`PREFLIGHT_RENDERS`] renders of `state`.
fn preflight(model: &mut ScreenModel, scene: &Scene, state: &State) -> Duration {
    let mut times: Vec<Duration> = (0..PREFLIGHT_RENDERS)
        .map(|_| {
            let t = Instant::now();
            model.render(scene, state);
            t.elapsed()
        })
        .collect();
    times.sort();
    times[PREFLIGHT_RENDERS / 2]
}

/// Run the loop until the frames are done, the display closes or `stop`
/// is set. Returns the summary (also written to `plan.summary`).
pub fn run<D: Display, S: SyncPort + ?Sized>(
    plan: RunPlan,
    display: &mut D,
    sync: &mut S,
    stop: Arc<AtomicBool>,
) -> Result<Summary> {
    let config = &plan.config;
    let scene = plan.scene;
    let (w, h) = config.screen_size();
    if display.size() != (w, h) {
        return Err(Error::invalid(
            "screen.resolution",
            format!(
                "{w}×{h} in the config but the display is {}×{}",
                display.size().0,
                display.size().1
            ),
        ));
    }
    // Calibration first: a bad file stops the run before anything is shown.
    let lut = DisplayLut::load(&config.calibration.lut, config.drive.bits)?;
    let lut_sha = lut.sha256().to_string();
    let flat = match &config.calibration.flat_field {
        Some(p) => Some(FlatField::load(p, (w, h))?),
        None => None,
    };
    let flat_sha = flat.as_ref().map(|f| f.sha256().to_string());
    let geometry = match &config.calibration.geometry {
        Some(p) => Some(GeometryCalibration::load(p, (w, h))?),
        None => None,
    };
    let geometry_sha = geometry.as_ref().map(|g| g.sha256().to_string());
    let k = config.drive.k()?;
    let converter = Converter::new(
        lut,
        flat,
        ThresholdMatrix::for_kind(config.drive.dither, config.drive.seed)?,
        ConvertSettings {
            transmission: config.collimator.transmission,
            scale_k: k,
            temporal: config.drive.temporal,
            seed: config.drive.seed,
            block: 8,
        },
        (w, h),
    )?;
    let fid = &config.frame_id;
    let frame_id = FrameIdCode::new(
        fid.enabled,
        fid.corner,
        fid.bits,
        fid.cell_px,
        config.drive.bits,
        (w, h),
    )?;
    let template = CommandTemplate::parse(&config.sync.template)?;
    let exposure_us = (config
        .drive
        .facility_exposure
        .unwrap_or(scene.camera.exposure)
        * 1e6)
        .round() as u64;
    // The pre-flight renders the first state replayed, or the scene's own.
    let first_state = match &plan.source {
        StateSource::Replay(t) => t.states.first().map(|s| scene_state(s, &scene.state)),
        StateSource::Udp { .. } => None,
    }
    .unwrap_or(scene.state);
    let (source, frames) = match plan.source {
        StateSource::Replay(t) => {
            let n = t.len() as u64;
            (
                Source::Replay {
                    states: t.states,
                    next: 0,
                },
                Some(plan.frames.map_or(n, |f| f.min(n))),
            )
        }
        StateSource::Udp { bind, sender } => (
            Source::Udp(Box::new(UdpStateReceiver::bind(bind, sender)?)),
            plan.frames,
        ),
    };
    tracing::info!(
        k,
        screen = format!("{w}x{h}"),
        "facility scale k (flight radiance × k = screen radiance before τ and flat field)"
    );

    let mut model = ScreenModel::new(config, &scene, geometry.as_ref());
    // A frame's slot is `refreshes_per_frame` refreshes; it must be up by
    // the end of the slot's first refresh.
    let refresh = Duration::from_secs_f64(1.0 / config.screen.refresh_hz);
    let period = refresh * config.timing.refreshes_per_frame;
    let render_time = preflight(&mut model, &scene, &first_state);
    let needed = refreshes_needed(render_time, refresh);
    if needed > config.timing.refreshes_per_frame {
        tracing::warn!(
            render_ms = render_time.as_secs_f64() * 1e3,
            slot_ms = period.as_secs_f64() * 1e3,
            "the scene renders in about a slot or more: expect missed deadlines; \
             timing.refreshes_per_frame = {needed} would leave a quarter of margin"
        );
    } else {
        tracing::info!(
            render_ms = render_time.as_secs_f64() * 1e3,
            slot_ms = period.as_secs_f64() * 1e3,
            "pre-flight render"
        );
    }
    let run_start = Instant::now();
    let mut log = FrameLog::open(&plan.log, run_start)?;
    log.set_preflight_render(render_time.as_secs_f64());
    let state_timeout = Duration::from_secs_f64(config.timing.state_timeout);
    let (free_tx, free_rx): (Sender<Vec<u32>>, Receiver<Vec<u32>>) = channel();
    let (ready_tx, ready_rx) = sync_channel::<Job>(1);
    let black = converter.black_pixel();
    for _ in 0..2 {
        free_tx.send(crate::resident_vec(black, w * h)).ok();
    }
    let dropped = Arc::new(std::sync::atomic::AtomicU64::new(0));
    let render_stop = stop.clone();
    let render_dropped = dropped.clone();
    let pacer = config.timing.late_latch.then(|| {
        Arc::new(Pacer {
            next: std::sync::Mutex::new(None),
            present_ns: 0.into(),
        })
    });
    let render_pacer = pacer.clone();
    let worker = std::thread::Builder::new()
        .name("optistim-render".into())
        .spawn(move || {
            render_loop(
                scene,
                model,
                converter,
                frame_id,
                source,
                frames,
                state_timeout,
                render_stop,
                free_rx,
                ready_tx,
                render_dropped,
                render_pacer,
                period,
            )
        })
        .map_err(|e| Error::Other(format!("cannot start the render thread: {e}")))?;

    let ack_timeout = Duration::from_secs_f64(config.sync.ack_timeout);
    let progress = match frames {
        Some(n) => crate::progress::bar(n, "run"),
        None => crate::progress::counter("run"),
    };
    let mut schedule: Option<Instant> = None;
    let mut unsent = Throttle::default();
    let mut result = Ok(());
    while !stop.load(Ordering::Relaxed) {
        let job = match ready_rx.recv_timeout(Duration::from_millis(200)) {
            Ok(job) => job,
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                if !display.is_open() {
                    break;
                }
                continue;
            }
            Err(_) => break,
        };
        if !display.is_open() {
            break;
        }
        // Slots form a fixed grid of frame periods (refreshes_per_frame
        // refreshes) from the first frame. A frame must be presented before
        // the end of its slot's first refresh; one that is not has left the
        // previous frame on screen for an extra refresh (a missed deadline),
        // and the next frame takes the first slot that has not yet ended.
        let slot = *schedule.get_or_insert_with(Instant::now);
        let now = Instant::now();
        if slot > now {
            std::thread::sleep(slot - now);
        }
        let deadline = slot + refresh;
        let present_start = Instant::now();
        let presented = match display.present(&job.buffer) {
            Ok(t) => t,
            Err(e) => {
                result = Err(e);
                break;
            }
        };
        let line = template.render(&FrameCommand {
            id: job.frame,
            t: if job.state_t.is_finite() {
                job.state_t
            } else {
                -1.0
            },
            exposure_us,
        });
        let outcome = sync.send(&line);
        let mut sync_sent = None;
        let mut ack = None;
        match outcome {
            Ok(SendOutcome::Queued) => {
                sync_sent = Some(Instant::now());
                if config.sync.ack {
                    if let Ok(Some(_)) = sync.wait_ack(ack_timeout) {
                        ack = Some(Instant::now());
                    }
                }
            }
            Ok(other) => {
                log.add_sync_not_sent();
                if let Some(more) = unsent.hit(Instant::now()) {
                    tracing::warn!(frame = job.frame, more, "sync line not sent: {other:?}");
                }
            }
            Err(e) => {
                log.add_sync_not_sent();
                if let Some(more) = unsent.hit(Instant::now()) {
                    tracing::warn!(frame = job.frame, more, error = %e, "sync failed");
                }
            }
        }
        let record = FrameRecord {
            run: String::new(),
            frame: job.frame,
            state_t: job.state_t,
            // A safe frame shows no state: no receive time, no latency.
            t_state_received: (!job.safe)
                .then(|| log.since_start(job.state_received.unwrap_or(job.render_start))),
            t_render_start: log.since_start(job.render_start),
            t_render_end: log.since_start(job.render_end),
            t_convert_end: log.since_start(job.convert_end),
            t_presented: log.since_start(presented),
            t_sync_sent: sync_sent.map(|t| log.since_start(t)),
            t_ack: ack.map(|a| log.since_start(a)),
            deadline: log.since_start(deadline),
            missed: false,
            clipped: job.clipped,
            peak_radiance: job.peak,
            k,
            lut_sha256: lut_sha.clone(),
            calibration_sha256: flat_sha.clone(),
            geometry_sha256: geometry_sha.clone(),
            safe_frame: job.safe,
        };
        if let Err(e) = log.write(record) {
            result = Err(e);
            break;
        }
        progress.inc(1);
        progress.set_message(format!("missed {}", log.missed()));
        let periods =
            presented.saturating_duration_since(slot).as_nanos() / period.as_nanos().max(1);
        let next = slot + period * (periods.min(1 << 20) as u32 + 1);
        schedule = Some(next);
        if let Some(p) = &pacer {
            // Decay the recorded present time slowly, so one slow present
            // keeps the budget up for a while but not forever.
            let took = presented
                .saturating_duration_since(present_start)
                .as_nanos() as u64;
            let old = p.present_ns.load(Ordering::Relaxed);
            p.present_ns.store(
                took.max(old - old / BUDGET_WINDOW as u64),
                Ordering::Relaxed,
            );
            p.set_next(next, job.frame + 1);
        }
        // The render thread may already have finished (frame limit, end of
        // the trajectory) with its last frame still queued in `ready_rx`:
        // keep presenting until that channel is drained and disconnected.
        let _ = free_tx.send(job.buffer);
    }
    progress.finish_and_clear();
    stop.store(true, Ordering::Relaxed);
    drop(ready_rx);
    drop(free_tx);
    let worker_result = worker
        .join()
        .map_err(|_| Error::Other("render thread panicked".into()))?;
    log.add_dropped_states(dropped.load(Ordering::Relaxed));
    if let Ok(Some(n)) = worker_result {
        log.set_udp_kernel_drops(n);
    }
    let summary = log.write_summary(&plan.summary)?;
    result?;
    worker_result?;
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Blocks at the screen's bottom-right corner, the last ones cut by
    /// the screen edge (a body partly off screen): every visible pixel
    /// shows its own block's value and none is written past the edge.
    #[test]
    fn blocks_expand_onto_their_pixels_and_stop_at_the_screen_edge() {
        let screen = (7, 5);
        // Block grid of a 7 × 5 screen with blocks of 3: 3 × 2 blocks;
        // the region is blocks (1..3) × (0..2), values 10 · row + column.
        let blocks = Roi::new(1, 0, 2, 2);
        let radiance = [0.0, 1.0, 10.0, 11.0];
        let mut out = Vec::new();
        let roi = expand_blocks(blocks, &radiance, 3, screen, &mut out);
        assert_eq!(roi, Roi::new(3, 0, 4, 5));
        assert_eq!(out.len(), roi.area());
        for (k, &v) in out.iter().enumerate() {
            let (x, y) = (roi.x + k % roi.width, roi.y + k / roi.width);
            let expected = 10.0 * (y / 3) as f32 + (x / 3 - 1) as f32;
            assert_eq!(v, expected, "pixel ({x}, {y})");
        }
    }

    #[test]
    fn refreshes_needed_leaves_a_quarter_of_margin() {
        let refresh = Duration::from_secs_f64(1.0 / 60.0);
        let ms = |v: f64| Duration::from_secs_f64(v * 1e-3);
        // 1.25 × render against whole 16.67 ms refreshes.
        assert_eq!(refreshes_needed(ms(1.0), refresh), 1);
        assert_eq!(refreshes_needed(ms(13.0), refresh), 1); // 16.25 ms
        assert_eq!(refreshes_needed(ms(14.0), refresh), 2); // 17.5 ms
        assert_eq!(refreshes_needed(ms(30.0), refresh), 3); // 37.5 ms
        assert_eq!(refreshes_needed(ms(39.0), refresh), 3); // 48.75 ms
        assert_eq!(refreshes_needed(ms(41.0), refresh), 4);
        assert_eq!(refreshes_needed(Duration::ZERO, refresh), 1);
    }
}
