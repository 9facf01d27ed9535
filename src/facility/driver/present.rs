//! The presenting side of the facility loop: shows each rendered frame at
//! its slot, sends its sync line (and waits for the acknowledgement if
//! asked), writes its log record and hands the buffer back.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, Sender};
use std::sync::Arc;
use std::time::{Duration, Instant};

use super::render_thread::{Job, Pacer};
use crate::error::Result;
use crate::facility::display::Display;
use crate::facility::log::{FrameLog, FrameRecord};
use crate::facility::serial::{CommandTemplate, FrameCommand, SendOutcome, SyncPort};
use crate::facility::throttle::Throttle;

/// What every frame's log record names: the facility scale and the
/// calibration files in use.
pub(super) struct Stamps {
    pub k: f64,
    pub lut_sha256: String,
    pub flat_sha256: Option<String>,
    pub geometry_sha256: Option<String>,
}

/// The sync line of each frame.
pub(super) struct SyncLine {
    pub template: CommandTemplate,
    /// Exposure the line announces [µs].
    pub exposure_us: u64,
    /// How long to wait for an acknowledgement; None: none is expected.
    pub ack_timeout: Option<Duration>,
}

/// Slots: a frame's slot is `period` (whole refreshes) long, and the
/// frame must be up by the end of the slot's first refresh.
#[derive(Clone, Copy)]
pub(super) struct Slots {
    pub refresh: Duration,
    pub period: Duration,
}

/// The presenting thread's backends and per-run state.
pub(super) struct Presenter<'a, D, S: ?Sized> {
    pub display: &'a mut D,
    pub sync: &'a mut S,
    pub line: SyncLine,
    pub stamps: Stamps,
    pub slots: Slots,
    pub pacer: Option<Arc<Pacer>>,
    pub log: FrameLog,
    /// Rate limit of the "sync line not sent" warnings.
    pub unsent: Throttle,
}

impl<D: Display, S: SyncPort + ?Sized> Presenter<'_, D, S> {
    /// Presents the frames of `ready` until it disconnects, the display
    /// closes or `stop` is set, returning each buffer through `free`.
    ///
    /// Slots form a fixed grid of frame periods from the first frame. A
    /// frame must be presented before the end of its slot's first refresh;
    /// one that is not has left the previous frame on screen for an extra
    /// refresh (a missed deadline), and the next frame takes the first slot
    /// that has not yet ended.
    pub fn run(
        &mut self,
        ready: &Receiver<Job>,
        free: &Sender<Vec<u32>>,
        stop: &AtomicBool,
        progress: &indicatif::ProgressBar,
    ) -> Result<()> {
        let mut schedule: Option<Instant> = None;
        while !stop.load(Ordering::Relaxed) {
            let job = match ready.recv_timeout(Duration::from_millis(200)) {
                Ok(job) => job,
                Err(RecvTimeoutError::Timeout) if self.display.is_open() => continue,
                Err(_) => break,
            };
            if !self.display.is_open() {
                break;
            }
            let slot = *schedule.get_or_insert_with(Instant::now);
            let presented = self.present(&job, slot)?;
            progress.inc(1);
            progress.set_message(format!("missed {}", self.log.missed()));
            schedule = Some(self.next_slot(slot, presented, job.frame));
            // The render thread may already have finished (frame limit, end
            // of the trajectory) with its last frame still queued in
            // `ready`: keep presenting until it is drained and disconnected.
            let _ = free.send(job.buffer);
        }
        Ok(())
    }

    /// Shows `job` at `slot`, sends its sync line and logs it; returns when
    /// it was presented.
    fn present(&mut self, job: &Job, slot: Instant) -> Result<Instant> {
        let now = Instant::now();
        if slot > now {
            std::thread::sleep(slot - now);
        }
        let present_start = Instant::now();
        let presented = self.display.present(&job.buffer)?;
        if let Some(p) = &self.pacer {
            p.record_present(presented.saturating_duration_since(present_start));
        }
        let (sync_sent, ack) = self.send_sync(job);
        let record = self.record(job, slot + self.slots.refresh, presented, sync_sent, ack);
        if let Some(why) = &job.out_of_field {
            self.log.note_out_of_field(job.frame, why);
        }
        self.log.write(record)?;
        Ok(presented)
    }

    /// The first slot that has not ended when `presented`, after `slot`;
    /// the pacer learns that frame `frame` + 1 takes it.
    fn next_slot(&self, slot: Instant, presented: Instant, frame: u64) -> Instant {
        let period = self.slots.period;
        let periods =
            presented.saturating_duration_since(slot).as_nanos() / period.as_nanos().max(1);
        let next = slot + period * (periods.min(1 << 20) as u32 + 1);
        if let Some(p) = &self.pacer {
            p.set_next(next, frame + 1);
        }
        next
    }

    /// Sends the frame's sync line; returns when it was handed to the port
    /// and when it was acknowledged.
    fn send_sync(&mut self, job: &Job) -> (Option<Instant>, Option<Instant>) {
        let line = self.line.template.render(&FrameCommand {
            id: job.frame,
            t: if job.state_t.is_finite() {
                job.state_t
            } else {
                -1.0
            },
            exposure_us: self.line.exposure_us,
        });
        let warning = match self.sync.send(&line) {
            Ok(SendOutcome::Queued) => {
                let sent = Instant::now();
                let ack = self.line.ack_timeout.and_then(|timeout| {
                    matches!(self.sync.wait_ack(timeout), Ok(Some(_))).then(Instant::now)
                });
                return (Some(sent), ack);
            }
            Ok(SendOutcome::Disabled) => return (None, None),
            Ok(other) => format!("sync line not sent: {other:?}"),
            Err(e) => format!("sync failed: {e}"),
        };
        self.log.add_sync_not_sent();
        if let Some(more) = self.unsent.hit(Instant::now()) {
            tracing::warn!(frame = job.frame, more, "{warning}");
        }
        (None, None)
    }

    /// The log record of a presented frame.
    fn record(
        &self,
        job: &Job,
        deadline: Instant,
        presented: Instant,
        sync_sent: Option<Instant>,
        ack: Option<Instant>,
    ) -> FrameRecord {
        let at = |t: Instant| self.log.since_start(t);
        FrameRecord {
            run: String::new(),
            frame: job.frame,
            state_t: job.state_t,
            // A safe frame shows no state: no receive time, no latency.
            t_state_received: (!job.safe)
                .then(|| at(job.state_received.unwrap_or(job.render_start))),
            t_render_start: at(job.render_start),
            t_render_end: at(job.render_end),
            t_convert_end: at(job.convert_end),
            t_presented: at(presented),
            t_sync_sent: sync_sent.map(at),
            t_ack: ack.map(at),
            deadline: at(deadline),
            missed: false,
            clipped: job.stats.clipped(),
            clipped_white: job.stats.clipped_high,
            clipped_black: job.stats.clipped_low,
            clip_flux_white: job.stats.white_flux_fraction(),
            clip_flux_black: job.stats.black_flux_fraction(),
            peak_radiance: job.stats.peak_target,
            k: self.stamps.k,
            lut_sha256: self.stamps.lut_sha256.clone(),
            calibration_sha256: self.stamps.flat_sha256.clone(),
            geometry_sha256: self.stamps.geometry_sha256.clone(),
            safe_frame: job.safe,
            out_of_field: job.out_of_field.is_some(),
            render_over_lime: job.render_over_lime,
            radiometric_u_k2_percent: job.radiometric_u_k2_percent,
            fidelity: job.fidelity,
            shadows: job.shadows.map(Into::into),
        }
    }
}
