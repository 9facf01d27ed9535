//! The render thread of the facility loop: waits for a free frame buffer
//! and for its late-latching moment, takes the newest state, renders the
//! screen radiance, converts it into drive levels, draws the frame id and
//! hands the frame ([`Job`]) to the presenting thread.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, SyncSender};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use super::screen::ScreenModel;
use crate::error::Result;
use crate::facility::dither::{ConvertStats, Converter, Roi};
use crate::facility::frame_id::FrameIdCode;
use crate::facility::frame_uncertainty::UncertaintyTable;
use crate::facility::governor::{FrameFidelity, Governor};
use crate::facility::throttle::Throttle;
use crate::facility::trajectory::State as TrajectoryState;
use crate::facility::udp::UdpStateReceiver;
use crate::scene::{Scene, State};

/// Frames over which the late-latching budget is taken.
pub const BUDGET_WINDOW: usize = 60;
/// Safety margin added to the late-latching budget.
const BUDGET_MARGIN: Duration = Duration::from_millis(2);

/// What the render thread hands to the presenter.
pub(super) struct Job {
    pub buffer: Vec<u32>,
    pub frame: u64,
    pub state_t: f64,
    pub state_received: Option<Instant>,
    pub render_start: Instant,
    pub render_end: Instant,
    pub convert_end: Instant,
    /// The conversion's counts and clipped flux.
    pub stats: ConvertStats,
    pub safe: bool,
    /// The render's error against LIME (a `lime_reference` body).
    pub render_over_lime: Option<f64>,
    /// The frame's radiometric uncertainty from the LUT's budget (k = 2, %).
    pub radiometric_u_k2_percent: Option<f64>,
    /// The governor's rung and predicted error, when it governs.
    pub fidelity: Option<FrameFidelity>,
    /// The state put the body entirely out of the field: why.
    pub out_of_field: Option<String>,
    /// The render's cast-shadow decision (a body with shadows).
    pub shadows: Option<crate::render::relief::ShadowDecision>,
}

/// Shared by the two threads for late latching: the next free slot with
/// the frame that will take it, and the recent present times.
#[derive(Default)]
pub(super) struct Pacer {
    /// Next slot and the id of the frame to be presented in it (None:
    /// nothing presented yet).
    next: Mutex<Option<(Instant, u64)>>,
    /// Largest present duration seen recently, ns.
    present_ns: AtomicU64,
}

impl Pacer {
    /// The slot frame `frame` will be shown in if the frames before it are
    /// on time: frames are presented in order, one per slot.
    fn slot_of(&self, frame: u64, period: Duration) -> Option<Instant> {
        let (slot, next_frame) = (*self.next.lock().ok()?)?;
        let ahead = frame.saturating_sub(next_frame).min(1 << 20) as u32;
        Some(slot + period * ahead)
    }

    /// The last present took `took`. The recorded present time decays
    /// slowly, so one slow present keeps the budget up for a while but not
    /// forever.
    pub fn record_present(&self, took: Duration) {
        let took = took.as_nanos() as u64;
        let old = self.present_ns.load(Ordering::Relaxed);
        self.present_ns.store(
            took.max(old - old / BUDGET_WINDOW as u64),
            Ordering::Relaxed,
        );
    }

    /// Frame `frame` is the next to be presented, at `slot`.
    pub fn set_next(&self, slot: Instant, frame: u64) {
        if let Ok(mut next) = self.next.lock() {
            *next = Some((slot, frame));
        }
    }

    fn present_time(&self) -> Duration {
        Duration::from_nanos(self.present_ns.load(Ordering::Relaxed))
    }
}

/// Recent per-frame work times of the render thread.
#[derive(Default)]
struct Budget {
    recent: std::collections::VecDeque<Duration>,
    /// Recent conversion (and frame-id) times.
    convert: std::collections::VecDeque<Duration>,
}

impl Budget {
    fn record(&mut self, work: Duration, convert: Duration) {
        if self.recent.len() == BUDGET_WINDOW {
            self.recent.pop_front();
            self.convert.pop_front();
        }
        self.recent.push_back(work);
        self.convert.push_back(convert);
    }

    /// The slowest recent conversion.
    fn convert_time(&self) -> Duration {
        self.convert.iter().max().copied().unwrap_or_default()
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
pub(super) fn scene_state(s: &TrajectoryState, base: &State) -> State {
    State {
        body_position: s.body_position.unwrap_or(base.body_position),
        body_attitude: s.body_attitude.unwrap_or(base.body_attitude),
        camera_position: s.camera_position,
        camera_attitude: s.camera_attitude,
        sun_position: s.sun_position,
        occulter: base.occulter,
    }
}

/// Frame source used by the render thread.
pub(super) enum Source {
    Replay {
        states: Vec<TrajectoryState>,
        next: usize,
    },
    Udp(Box<UdpStateReceiver>),
}

/// The region last drawn into each frame buffer (by its address), so that
/// clearing a reused buffer costs that region only.
#[derive(Default)]
struct DrawnRegions(Vec<(usize, Option<Roi>)>);

impl DrawnRegions {
    /// Blackens what `buffer` showed last time; returns its entry.
    fn clear(&mut self, buffer: &mut [u32], width: usize, black: u32) -> usize {
        let key = buffer.as_ptr() as usize;
        let entry = match self.0.iter().position(|(k, _)| *k == key) {
            Some(i) => i,
            None => {
                self.0.push((key, None));
                self.0.len() - 1
            }
        };
        if let Some(old) = self.0[entry].1.take() {
            for row in old.y..old.y + old.height {
                buffer[row * width + old.x..][..old.width].fill(black);
            }
        }
        entry
    }

    fn remember(&mut self, entry: usize, roi: Option<Roi>) {
        self.0[entry].1 = roi;
    }
}

/// Everything the render thread owns.
pub(super) struct RenderThread {
    pub scene: Scene,
    /// One screen model per fidelity rung (one without a governor).
    pub models: Vec<ScreenModel>,
    /// The frame-time governor, when `timing.governor` is on.
    pub governor: Option<Governor>,
    /// Screen pixels per unit tangent (the apparent size the governor
    /// predicts from).
    pub f_px: f64,
    pub converter: Converter,
    pub frame_id: FrameIdCode,
    pub source: Source,
    /// Stop after this many frames.
    pub frames: Option<u64>,
    /// A closed-loop state older than this is not shown (the safe frame is).
    pub state_timeout: Duration,
    pub stop: Arc<AtomicBool>,
    /// Buffers the presenter has finished with.
    pub free: Receiver<Vec<u32>>,
    /// Frames ready to present.
    pub ready: SyncSender<Job>,
    /// Datagrams dropped so far (closed loop).
    pub dropped: Arc<AtomicU64>,
    /// Late latching, when on.
    pub pacer: Option<Arc<Pacer>>,
    /// A frame's slot.
    pub period: Duration,
}

impl RenderThread {
    /// Renders frames until the frames are done, the source ends, `stop`
    /// is set or the presenter is gone. Returns the datagrams the kernel
    /// dropped from the UDP socket's receive buffer, where the OS tells
    /// (closed loop on Linux).
    pub fn run(mut self) -> Result<Option<u64>> {
        let black = self.converter.black_pixel();
        let uncertainty = UncertaintyTable::new(self.converter.lut());
        let mut no_state = Throttle::default();
        let mut budget = Budget::default();
        let mut last = None;
        let mut drawn = DrawnRegions::default();
        let mut warned_peak = false;
        let mut frame = 0u64;
        // The body's apparent area in the last state shown (the governor
        // chooses before the newest state is taken, for its freshness).
        let mut area = f64::NAN;
        while !self.stop.load(Ordering::Relaxed) && self.frames.is_none_or(|n| frame < n) {
            let Ok(mut buffer) = self.free.recv() else {
                break;
            };
            let choice = self.choose_rung(frame, &budget, area);
            let reserve = choice.map(|c| c.predicted + budget.convert_time());
            self.wait_for_latch(frame, &budget, reserve);
            let render_start = Instant::now();
            let Some((state, received)) = self.next_state(&mut last) else {
                break;
            };
            let rung = choice.map_or(0, |c| c.rung);
            let entry = drawn.clear(&mut buffer, self.models[rung].screen.0, black);
            self.converter.forget_previous_roi();
            let shown = state.as_ref().map(|s| scene_state(s, &self.scene.state));
            let out_of_field = shown
                .map(|st| self.models[rung].field_check(&self.scene, &st))
                .filter(|c| !c.in_field)
                .map(|c| c.describe());
            let roi = shown.and_then(|st| self.models[rung].render(&self.scene, &st));
            let render_end = Instant::now();
            let shadows = roi.and(self.models[rung].shadows());
            // Nothing of the body shown: nothing to compare with LIME.
            let render_over_lime = shown
                .filter(|_| out_of_field.is_none())
                .and_then(|st| self.models[rung].render_over_lime(&st));
            let fidelity =
                self.account(choice, shown.as_ref(), &mut area, render_end - render_start);
            let stats = self.convert(rung, roi, frame, &mut buffer, &mut warned_peak)?;
            let radiometric_u_k2_percent = uncertainty
                .as_ref()
                .zip(roi)
                .and_then(|(u, r)| u.frame(&self.models[rung].roi_target, r.width, self.factor()));
            drawn.remember(entry, roi);
            if state.is_none() {
                if let Some(more) = no_state.hit(Instant::now()) {
                    tracing::warn!(
                        frame,
                        more,
                        "no current state: showing the safe (black) frame"
                    );
                }
            }
            self.frame_id.encode(&mut buffer, frame)?;
            let convert_end = Instant::now();
            budget.record(convert_end - render_start, convert_end - render_end);
            let job = Job {
                buffer,
                frame,
                state_t: state.as_ref().map_or(f64::NAN, |s| s.t),
                state_received: received,
                render_start,
                render_end,
                convert_end,
                stats,
                safe: state.is_none(),
                render_over_lime,
                radiometric_u_k2_percent,
                fidelity,
                out_of_field,
                shadows,
            };
            if self.ready.send(job).is_err() {
                break;
            }
            frame += 1;
        }
        Ok(match &self.source {
            Source::Udp(rx) => rx.kernel_drops(),
            Source::Replay { .. } => None,
        })
    }

    /// The governor's rung for `frame`: the finest whose predicted render
    /// fits the time to its slot (at most one slot), less the conversion,
    /// the present and the margin. None without a governor.
    fn choose_rung(
        &self,
        frame: u64,
        budget: &Budget,
        area: f64,
    ) -> Option<crate::facility::governor::Choice> {
        let governor = self.governor.as_ref()?;
        let present = self
            .pacer
            .as_ref()
            .map_or(Duration::ZERO, |p| p.present_time());
        let overhead = budget.convert_time() + present + BUDGET_MARGIN;
        let mut available = self.period.saturating_sub(overhead);
        if let Some(slot) = self
            .pacer
            .as_ref()
            .and_then(|p| p.slot_of(frame, self.period))
        {
            let until = slot.saturating_duration_since(Instant::now());
            available = available.min(until.saturating_sub(overhead));
        }
        // Before the first state: the largest size the pre-flight saw.
        let area = if area.is_finite() {
            area
        } else {
            governor.largest_profiled_area()
        };
        Some(governor.choose(area, available))
    }

    /// Feeds the frame's render time back to the governor and returns what
    /// the frame logs: its rung with the error predicted at its own size.
    fn account(
        &mut self,
        choice: Option<crate::facility::governor::Choice>,
        shown: Option<&State>,
        area: &mut f64,
        took: Duration,
    ) -> Option<FrameFidelity> {
        let (governor, choice) = (self.governor.as_mut()?, choice?);
        let Some(state) = shown else {
            return Some(choice.into());
        };
        *area = super::fidelity::apparent_area(&self.scene, state, self.f_px);
        governor.record(choice.rung, *area, took);
        let (pixel, flux) = governor.profiles()[choice.rung].predict_error(*area);
        Some(FrameFidelity {
            predicted_pixel_error: pixel,
            predicted_flux_error: flux,
            ..choice.into()
        })
    }

    /// Late latching: sleeps until the slot frame `frame` will take, minus
    /// the governor's predicted work (`reserve`) or, without one, the
    /// budget of recent frames.
    fn wait_for_latch(&self, frame: u64, budget: &Budget, reserve: Option<Duration>) {
        let Some(pacer) = &self.pacer else { return };
        // The slot this frame will be shown in, counted from the next free
        // slot past the frames still queued before it.
        let target = pacer.slot_of(frame, self.period);
        let reserve = match reserve {
            Some(r) => Some(r + pacer.present_time() + BUDGET_MARGIN),
            None => budget.reserve(pacer.present_time()),
        };
        let Some(start) = target
            .zip(reserve)
            .and_then(|(slot, reserve)| slot.checked_sub(reserve))
        else {
            return;
        };
        while !self.stop.load(Ordering::Relaxed) {
            let now = Instant::now();
            if now >= start {
                break;
            }
            std::thread::sleep((start - now).min(Duration::from_millis(50)));
        }
    }

    /// The state to show and when it was received; None when a replay has
    /// run out. A closed-loop state older than `state_timeout`, or none
    /// yet, gives `(None, ..)`: the safe frame.
    #[allow(clippy::type_complexity)]
    fn next_state(
        &mut self,
        last: &mut Option<(TrajectoryState, Instant)>,
    ) -> Option<(Option<TrajectoryState>, Option<Instant>)> {
        match &mut self.source {
            Source::Replay { states, next } => {
                let state = *states.get(*next)?;
                *next += 1;
                Some((Some(state), None))
            }
            Source::Udp(rx) => {
                if let Some(newest) = rx.latest() {
                    *last = Some(newest);
                }
                self.dropped.store(rx.stats().dropped(), Ordering::Relaxed);
                Some(match last {
                    Some((s, at)) if at.elapsed() <= self.state_timeout => (Some(*s), Some(*at)),
                    _ => (None, last.as_ref().map(|l| l.1)),
                })
            }
        }
    }

    /// Screen radiance per unit target radiance: k ÷ τ.
    fn factor(&self) -> f64 {
        let s = self.converter.settings();
        s.scale_k / s.transmission
    }

    /// Drive levels of the rendered region into `buffer`; returns the
    /// conversion's counts (warning once when the screen cannot show the
    /// peak).
    fn convert(
        &mut self,
        rung: usize,
        roi: Option<Roi>,
        frame: u64,
        buffer: &mut [u32],
        warned_peak: &mut bool,
    ) -> Result<ConvertStats> {
        let Some(r) = roi else {
            return Ok(ConvertStats::default());
        };
        let stats = self
            .converter
            .convert(&self.models[rung].roi_target, r, frame, buffer)?;
        if stats.clipped_high > 0 && !*warned_peak {
            *warned_peak = true;
            tracing::warn!(
                frame,
                peak_radiance = stats.peak_target,
                pixels = stats.clipped_high,
                "scene peak exceeds what the screen can show at this k; clipped"
            );
        }
        Ok(stats)
    }
}
