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
//!
//! - [`screen`]: what the camera sees on the screen ([`ScreenModel`]);
//! - `render_thread`: the render thread;
//! - `present`: the presenting thread;
//! - here: [`run`], which loads the calibration, times the scene, starts
//!   the render thread, presents, and writes the run summary.

pub mod fidelity;
mod present;
mod render_thread;
pub mod screen;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{channel, sync_channel};
use std::sync::Arc;
use std::time::{Duration, Instant};

use present::{Presenter, Slots, Stamps, SyncLine};
pub use render_thread::BUDGET_WINDOW;
use render_thread::{scene_state, Pacer, RenderThread, Source};
pub use screen::{block_pinhole, screen_pinhole, ScreenModel};

use super::acceptance::{self, RunContext};
use super::config::{FacilityConfig, GovernorMode};
use super::display::Display;
use super::dither::{ConvertSettings, Converter, ThresholdMatrix};
use super::frame_id::FrameIdCode;
use super::geometry::GeometryCalibration;
use super::governor::{Governor, Mode, RungProfile};
use super::log::{write_summary, FrameLog, Summary};
use super::lut::{DisplayLut, FlatField};
use super::serial::{CommandTemplate, SyncPort};
use super::throttle::Throttle;
use super::trajectory::Trajectory;
use super::udp::UdpStateReceiver;
use crate::error::{Error, Result};
use crate::scene::{Scene, State};

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

/// The calibration a run drives the screen with, loaded before anything
/// is shown (a bad file stops the run there).
struct Calibration {
    converter: Converter,
    geometry: Option<GeometryCalibration>,
    stamps: Stamps,
}

impl Calibration {
    fn load(config: &FacilityConfig) -> Result<Calibration> {
        let (w, h) = config.screen_size();
        let lut = DisplayLut::load(&config.calibration.lut, config.drive.bits)?;
        let lut_sha256 = lut.sha256().to_string();
        let flat = match &config.calibration.flat_field {
            Some(p) => Some(FlatField::load(p, (w, h))?),
            None => None,
        };
        let geometry = match &config.calibration.geometry {
            Some(p) => Some(GeometryCalibration::load(p, (w, h))?),
            None => None,
        };
        let stamps = Stamps {
            k: config.drive.k()?,
            lut_sha256,
            flat_sha256: flat.as_ref().map(|f| f.sha256().to_string()),
            geometry_sha256: geometry.as_ref().map(|g| g.sha256().to_string()),
        };
        let converter = Converter::new(
            lut,
            flat,
            ThresholdMatrix::for_kind(config.drive.dither, config.drive.seed)?,
            ConvertSettings {
                transmission: config.collimator.transmission,
                scale_k: stamps.k,
                temporal: config.drive.temporal,
                seed: config.drive.seed,
                block: 8,
            },
            (w, h),
        )?;
        Ok(Calibration {
            converter,
            geometry,
            stamps,
        })
    }
}

/// The state the pre-flight renders (the first replayed, or the scene's
/// own), the render thread's source and the frames to show.
fn open_source(
    source: StateSource,
    frames: Option<u64>,
    scene_state_default: &State,
) -> Result<(State, Source, Option<u64>)> {
    Ok(match source {
        StateSource::Replay(t) => {
            let first = t.states.first().map_or(*scene_state_default, |s| {
                scene_state(s, scene_state_default)
            });
            let n = t.len() as u64;
            let source = Source::Replay {
                states: t.states,
                next: 0,
            };
            (first, source, Some(frames.map_or(n, |f| f.min(n))))
        }
        StateSource::Udp { bind, sender } => {
            let rx = UdpStateReceiver::bind(bind, sender)?;
            (*scene_state_default, Source::Udp(Box::new(rx)), frames)
        }
    })
}

/// Every state of a replay has the body in the screen's field: one that
/// would show nothing stops the run before the first frame.
fn check_states_in_field(model: &ScreenModel, scene: &Scene, t: &Trajectory) -> Result<()> {
    for (row, s) in t.states.iter().enumerate() {
        let check = model.field_check(scene, &scene_state(s, &scene.state));
        if !check.in_field {
            return Err(Error::invalid(
                "trajectory",
                format!(
                    "state {row} (t = {} s): {} (acceptance.allow_empty_frames = true shows such states black)",
                    s.t,
                    check.describe()
                ),
            ));
        }
    }
    Ok(())
}

/// Times the scene before the first frame and says whether it fits a slot.
fn preflight_report(
    model: &mut ScreenModel,
    scene: &Scene,
    state: &State,
    slots: Slots,
    config: &FacilityConfig,
) -> Duration {
    let render_time = preflight(model, scene, state);
    let needed = refreshes_needed(render_time, slots.refresh);
    let (render_ms, slot_ms) = (
        render_time.as_secs_f64() * 1e3,
        slots.period.as_secs_f64() * 1e3,
    );
    if needed > config.timing.refreshes_per_frame {
        tracing::warn!(
            render_ms,
            slot_ms,
            "the scene renders in about a slot or more: expect missed deadlines; \
             timing.refreshes_per_frame = {needed} would leave a quarter of margin"
        );
    } else {
        tracing::info!(render_ms, slot_ms, "pre-flight render");
    }
    render_time
}

/// The screen models a run renders with, and its governor.
struct Fidelity {
    /// One per rung, finest first (one without a governor).
    models: Vec<ScreenModel>,
    governor: Option<Governor>,
    /// The pre-flight's render time of the first state at full fidelity.
    preflight_render: Duration,
}

impl Fidelity {
    /// Without a governor: the configured model, timed on the first state.
    /// With one: every rung profiled over the run's apparent sizes.
    fn prepare(
        config: &FacilityConfig,
        scene: &Scene,
        geometry: Option<&GeometryCalibration>,
        source: &Source,
        first_state: &State,
        slots: Slots,
    ) -> Result<Fidelity> {
        let mode = match config.timing.governor {
            GovernorMode::Off => {
                let mut model = ScreenModel::new(config, scene, geometry);
                let t = preflight_report(&mut model, scene, first_state, slots, config);
                return Ok(Fidelity {
                    models: vec![model],
                    governor: None,
                    preflight_render: t,
                });
            }
            GovernorMode::Auto => Mode::Auto,
            GovernorMode::Fixed => Mode::Fixed(config.timing.governor_rung),
        };
        let f_px = screen_pinhole(config).fx;
        let (rungs, mut models) = fidelity::rung_models(config, scene, geometry);
        if let Mode::Fixed(i) = mode {
            if i >= rungs.len() {
                return Err(Error::invalid(
                    "timing.governor_rung",
                    format!(
                        "rung {i} does not exist: the ladder has {} ({})",
                        rungs.len(),
                        rungs
                            .iter()
                            .map(|r| r.label.as_str())
                            .collect::<Vec<_>>()
                            .join("; ")
                    ),
                ));
            }
        }
        let samples = match source {
            Source::Replay { states, .. } => {
                let states: Vec<State> = states
                    .iter()
                    .map(|s| scene_state(s, &scene.state))
                    .collect();
                fidelity::sample_states(&states, scene, f_px)
            }
            Source::Udp(_) => fidelity::scaled_states(first_state),
        };
        let samples = if samples.is_empty() {
            fidelity::scaled_states(first_state)
        } else {
            samples
        };
        let mut reference = fidelity::reference_model(config, scene, geometry);
        let profiles = fidelity::profile(rungs, &mut models, &mut reference, scene, &samples, f_px);
        report_profiles(&profiles, slots);
        let first = fidelity::apparent_area(scene, first_state, f_px);
        let preflight_render =
            Duration::from_secs_f64(profiles[0].predict_seconds(first).clamp(0.0, 3600.0));
        let governor = Governor::new(profiles, mode, config.timing.governor_max_pixel_error);
        Ok(Fidelity {
            models,
            governor: Some(governor),
            preflight_render,
        })
    }
}

/// Logs each rung's measured times and errors, and warns when even the
/// coarsest does not fit a slot at the largest size profiled.
fn report_profiles(profiles: &[RungProfile], slots: Slots) {
    for (i, p) in profiles.iter().enumerate() {
        let s = p.samples();
        let (small, large) = (s[0], s[s.len() - 1]);
        tracing::info!(
            rung = i,
            label = %p.rung.label,
            area_px = format!("{:.0}..{:.0}", small.area_px, large.area_px),
            render_ms = format!("{:.1}..{:.1}", small.seconds * 1e3, large.seconds * 1e3),
            pixel_error_p99 = format!("{:.1e}..{:.1e}", small.pixel_error, large.pixel_error),
            flux_error = format!("{:.1e}..{:.1e}", small.flux_error, large.flux_error),
            "governor rung"
        );
    }
    let coarsest = &profiles[profiles.len() - 1];
    let largest = coarsest.samples().last().map_or(0.0, |s| s.area_px);
    let t = coarsest.predict_seconds(largest) * crate::facility::governor::SAFETY;
    if t > slots.period.as_secs_f64() {
        tracing::warn!(
            coarsest_ms = t * 1e3,
            slot_ms = slots.period.as_secs_f64() * 1e3,
            "even the coarsest rung does not fit a slot at the largest size: expect late frames; \
             raise timing.refreshes_per_frame or timing.governor_max_block"
        );
    }
}

/// The frame's sync line as the config and the scene give it.
fn sync_line(config: &FacilityConfig, scene: &Scene) -> Result<SyncLine> {
    let exposure = config
        .drive
        .facility_exposure
        .unwrap_or(scene.camera.exposure);
    Ok(SyncLine {
        template: CommandTemplate::parse(&config.sync.template)?,
        exposure_us: (exposure * 1e6).round() as u64,
        ack_timeout: config
            .sync
            .ack
            .then(|| Duration::from_secs_f64(config.sync.ack_timeout)),
    })
}

fn frame_id_code(config: &FacilityConfig) -> Result<FrameIdCode> {
    let fid = &config.frame_id;
    FrameIdCode::new(
        fid.enabled,
        fid.corner,
        fid.bits,
        fid.cell_px,
        config.drive.bits,
        config.screen_size(),
    )
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
        let (dw, dh) = display.size();
        return Err(Error::invalid(
            "screen.resolution",
            format!("{w}×{h} in the config but the display is {dw}×{dh}"),
        ));
    }
    let Calibration {
        converter,
        geometry,
        stamps,
    } = Calibration::load(config)?;
    let frame_id = frame_id_code(config)?;
    let line = sync_line(config, &scene)?;
    let closed_loop = matches!(plan.source, StateSource::Udp { .. });
    if let (StateSource::Replay(t), false) = (&plan.source, config.acceptance.allow_empty_frames) {
        let model = ScreenModel::new(config, &scene, geometry.as_ref());
        check_states_in_field(&model, &scene, t)?;
    }
    let (first_state, source, frames) = open_source(plan.source, plan.frames, &scene.state)?;
    tracing::info!(
        k = stamps.k,
        screen = format!("{w}x{h}"),
        "facility scale k (flight radiance × k = screen radiance before τ and flat field)"
    );
    let refresh = Duration::from_secs_f64(1.0 / config.screen.refresh_hz);
    let slots = Slots {
        refresh,
        period: refresh * config.timing.refreshes_per_frame,
    };
    let Fidelity {
        models,
        governor,
        preflight_render,
    } = Fidelity::prepare(
        config,
        &scene,
        geometry.as_ref(),
        &source,
        &first_state,
        slots,
    )?;
    let mut log = FrameLog::open(&plan.log, Instant::now())?;
    log.set_preflight_render(preflight_render.as_secs_f64());
    if let Some(g) = &governor {
        log.set_governor_rungs(g.profiles().iter().map(|p| p.rung.label.clone()).collect());
    }
    // Two frame buffers circulate: one on screen, one being rendered.
    let (free_tx, free_rx) = channel();
    let (ready_tx, ready_rx) = sync_channel(1);
    for _ in 0..2 {
        free_tx
            .send(crate::resident_vec(converter.black_pixel(), w * h))
            .ok();
    }
    let dropped = Arc::new(AtomicU64::new(0));
    let pacer = config.timing.late_latch.then(|| Arc::new(Pacer::default()));
    let thread = RenderThread {
        scene,
        models,
        governor,
        f_px: screen_pinhole(config).fx,
        converter,
        frame_id,
        source,
        frames,
        state_timeout: Duration::from_secs_f64(config.timing.state_timeout),
        stop: stop.clone(),
        free: free_rx,
        ready: ready_tx,
        dropped: dropped.clone(),
        pacer: pacer.clone(),
        period: slots.period,
    };
    let worker = std::thread::Builder::new()
        .name("optistim-render".into())
        .spawn(move || thread.run())
        .map_err(|e| Error::Other(format!("cannot start the render thread: {e}")))?;

    let progress = match frames {
        Some(n) => crate::progress::bar(n, "run"),
        None => crate::progress::counter("run"),
    };
    let mut presenter = Presenter {
        display,
        sync,
        line,
        stamps,
        slots,
        pacer,
        log,
        unsent: Throttle::default(),
    };
    let result = presenter.run(&ready_rx, &free_tx, &stop, &progress);
    progress.finish_and_clear();
    stop.store(true, Ordering::Relaxed);
    drop(ready_rx);
    drop(free_tx);
    let worker_result = worker
        .join()
        .map_err(|_| Error::Other("render thread panicked".into()))?;
    let mut log = presenter.log;
    log.add_dropped_states(dropped.load(Ordering::Relaxed));
    if let Ok(Some(n)) = worker_result {
        log.set_udp_kernel_drops(n);
    }
    let mut summary = log.summary();
    summary.frames_planned = frames;
    summary.interrupted = frames.is_some_and(|n| summary.frames < n);
    summary.closed_loop = closed_loop;
    acceptance::judge(
        &mut summary,
        &config.acceptance,
        &RunContext {
            refresh_s: refresh.as_secs_f64(),
            refreshes_per_frame: config.timing.refreshes_per_frame,
            render_block: config.screen.render_block,
            log: &plan.log,
        },
    );
    write_summary(&plan.summary, &summary)?;
    result?;
    worker_result?;
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;

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
