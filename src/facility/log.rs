//! Frame log: one JSON line per presented frame, written through to disk
//! before the next frame, and the end-of-run summary.
//!
//! # File policy
//!
//! The log is opened with `O_APPEND | O_CREAT`: an existing log is never
//! truncated, a new run is appended after it. Every record carries the
//! `run` id (wall-clock start of the run, Unix nanoseconds) so runs in one
//! file can be told apart. Each record is written with one `write_all`, then
//! flushed and `sync_data`'d, so a crash or power cut loses at most the frame
//! in flight (whose line may be incomplete; [`read_records`] ignores an
//! unterminated last line).
//!
//! # Times
//!
//! All `t_*` fields are seconds since the run start ([`FrameLog::since_start`]);
//! `state_t` is the state's own time.
//!
//! # Summary
//!
//! [`FrameLog::summary`]: frames, missed deadlines, dropped states and the
//! state-received → presented latency p50/p99/max (nearest-rank
//! percentiles from a fixed-memory [`LatencyHistogram`]), written as pretty JSON by [`FrameLog::write_summary`]
//! (atomically: temp file + rename; the summary is derived data and may
//! replace an older regular file, never a symlink, device or directory).
//!
//! # Torn records
//!
//! A record cut short (disk full, power loss) leaves the file without a
//! final newline; the next run's [`FrameLog::open`] starts a new line
//! first and warns, so its first record is not glued onto the torn one.

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::acceptance::Verdict;
use crate::error::{Error, Result};
use crate::facility::governor::{FrameFidelity, GovernorSummary};

/// One frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct FrameRecord {
    /// Run id (set by [`FrameLog::write`]).
    #[serde(default)]
    pub run: String,
    /// Frame id.
    pub frame: u64,
    /// Time of the rendered state, s; NaN for a safe frame (no state),
    /// written as JSON `null`.
    #[serde(deserialize_with = "f64_or_nan")]
    pub state_t: f64,
    /// State received (closed loop; replay: the render start), s since run
    /// start. `None` for a safe frame, which shows no state.
    pub t_state_received: Option<f64>,
    /// Render start.
    pub t_render_start: f64,
    /// Render end.
    pub t_render_end: f64,
    /// Radiance → drive-level conversion end.
    pub t_convert_end: f64,
    /// Presented (display server has the image).
    pub t_presented: f64,
    /// Sync command handed to the port (`None`: the port refused it, e.g.
    /// device gone or queue full).
    pub t_sync_sent: Option<f64>,
    /// Acknowledgement received.
    pub t_ack: Option<f64>,
    /// Presentation deadline, s since run start.
    pub deadline: f64,
    /// `t_presented > deadline` (set by [`FrameLog::write`]).
    pub missed: bool,
    /// Clipped pixels (white + black).
    pub clipped: u64,
    /// Pixels whose screen radiance would exceed the LUT's top level.
    #[serde(default)]
    pub clipped_white: u64,
    /// Pixels whose screen radiance would be below the black level (level
    /// 0), sky excepted.
    #[serde(default)]
    pub clipped_black: u64,
    /// Flux the white level moves (shown − target over the white-clipped
    /// pixels, camera side), as a fraction of the frame's target disk
    /// flux: ≤ 0.
    #[serde(default)]
    pub clip_flux_white: f64,
    /// The same for the black level: ≥ 0 (dim pixels shown at black).
    #[serde(default)]
    pub clip_flux_black: f64,
    /// Peak target radiance, W m⁻² sr⁻¹.
    pub peak_radiance: f64,
    /// Facility scale factor k.
    pub k: f64,
    /// SHA-256 of the LUT file.
    pub lut_sha256: String,
    /// SHA-256 of the flat-field file (if any).
    pub calibration_sha256: Option<String>,
    /// SHA-256 of the geometric calibration file (if any).
    #[serde(default)]
    pub geometry_sha256: Option<String>,
    /// The safe (black) frame was shown: no current state.
    #[serde(default)]
    pub safe_frame: bool,
    /// The state put the body entirely out of the field: nothing of it
    /// was shown.
    #[serde(default)]
    pub out_of_field: bool,
    /// For a body marked `lime_reference`: the frame's camera-effective
    /// disk irradiance over LIME's at the same geometry (the render's
    /// radiometric error against the real Moon, in the flight camera's
    /// electrons); absent otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub render_over_lime: Option<f64>,
    /// The frame's radiometric uncertainty (k = 2, %): the display LUT's
    /// per-level budget weighted by the flux each pixel asks of the screen
    /// ([`crate::facility::frame_uncertainty`]); absent for a LUT without
    /// its `uncertainty_k2_percent` column or a frame with nothing lit.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radiometric_u_k2_percent: Option<f64>,
    /// The frame-time governor's rung and its predicted error (absent with
    /// `timing.governor = "off"`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fidelity: Option<FrameFidelity>,
    /// Whether the frame applied the relief's cast shadows, and why (a
    /// body with `[body] shadows`; absent otherwise or with nothing in
    /// the field).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shadows: Option<ShadowRecord>,
}

/// A frame's cast-shadow decision ([`crate::render::relief::ShadowDecision`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShadowRecord {
    /// Whether the horizon map was applied.
    pub applied: bool,
    /// Why: `mode = always`, `mode = never`, `auto: reaches the error
    /// target`, `render.relief = false`, …
    pub reason: String,
    /// Longest visible shadow on the image [px].
    pub shadow_px: f64,
    /// Lowest Sun elevation over the visible lit disk [deg].
    pub min_sun_elevation_deg: f64,
    /// Whether terrain hidden from the camera by nearer relief was
    /// dropped (with the shadows and the displacement).
    #[serde(default)]
    pub hidden_applied: bool,
    /// Interior pixels a shadow's edge crosses, refined over their
    /// preimage (0 with `[render] shadow_edges = false`).
    #[serde(default)]
    pub edge_pixels: usize,
    /// The per-pixel error target `auto` compared with, and the estimated
    /// largest changes of a pixel by the shadows, the slopes and the limb
    /// (`render::relief_effect`).
    #[serde(default)]
    pub target: f64,
    #[serde(default)]
    pub shadow_effect: f64,
    #[serde(default)]
    pub shading_effect: f64,
    #[serde(default)]
    pub limb_effect: f64,
    /// Whether the DEM moved the limb and tilted the normals.
    #[serde(default)]
    pub displaced: bool,
}

impl From<crate::render::relief::ShadowDecision> for ShadowRecord {
    fn from(d: crate::render::relief::ShadowDecision) -> Self {
        ShadowRecord {
            applied: d.applied,
            reason: d.reason.to_string(),
            shadow_px: d.shadow_px,
            min_sun_elevation_deg: d.min_sun_elevation_deg,
            hidden_applied: d.hidden_applied,
            edge_pixels: d.edge_pixels,
            target: d.target,
            shadow_effect: d.shadow_effect,
            shading_effect: d.shading_effect,
            limb_effect: d.limb_effect,
            displaced: d.displaced,
        }
    }
}

/// A number, or `null` (how serde_json writes a non-finite `f64`) read
/// back as NaN.
fn f64_or_nan<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// Latency statistics, s.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
pub struct LatencyStats {
    /// Samples.
    pub count: u64,
    /// Median (nearest rank).
    pub p50: Option<f64>,
    /// 99th percentile (nearest rank).
    pub p99: Option<f64>,
    /// Maximum.
    pub max: Option<f64>,
}

impl LatencyStats {
    /// Nearest-rank statistics of `samples` (NaNs ignored).
    pub fn from_samples(samples: &[f64]) -> LatencyStats {
        let mut v: Vec<f64> = samples.iter().copied().filter(|x| !x.is_nan()).collect();
        v.sort_by(f64::total_cmp);
        let rank = |p: f64| -> Option<f64> {
            if v.is_empty() {
                return None;
            }
            let idx = ((p / 100.0) * v.len() as f64).ceil() as usize;
            Some(v[idx.clamp(1, v.len()) - 1])
        };
        LatencyStats {
            count: v.len() as u64,
            p50: rank(50.0),
            p99: rank(99.0),
            max: v.last().copied(),
        }
    }
}

/// Nearest-rank percentiles of a stream of latencies [s] in fixed memory,
/// so a run of any length keeps a steady footprint: log-spaced bins 1e-3
/// wide (relative) from 1 µs to 10⁴ s, each with its count and its largest
/// sample. A percentile is the largest sample of the bin holding its rank:
/// an observed value within 1e-3 (relative) of the exact nearest rank, and
/// exactly it when that bin holds one distinct value. The table (370 kB)
/// is written whole when created, so its pages are resident from the
/// start rather than faulted in as new latencies appear.
#[derive(Debug, Clone)]
pub struct LatencyHistogram {
    /// Per bin: samples, and the largest (−∞ while empty).
    bins: Vec<(u32, f64)>,
    count: u64,
}

impl LatencyHistogram {
    const FLOOR: f64 = 1e-6;
    /// ln of a bin's upper-to-lower edge ratio.
    const LN_WIDTH: f64 = 1e-3;
    /// Bin 0 (≤ 1 µs, negative) plus ln(10⁴ s / 1 µs) / 1e-3 bins.
    const BINS: usize = 1 + 23_026;

    /// An empty histogram.
    pub fn new() -> Self {
        Self {
            bins: vec![(0, f64::NEG_INFINITY); Self::BINS],
            count: 0,
        }
    }

    fn bin(v: f64) -> usize {
        if v > Self::FLOOR {
            (1 + ((v / Self::FLOOR).ln() / Self::LN_WIDTH) as usize).min(Self::BINS - 1)
        } else {
            0
        }
    }

    /// Adds one sample (NaN ignored).
    pub fn add(&mut self, v: f64) {
        if v.is_nan() {
            return;
        }
        let (count, largest) = &mut self.bins[Self::bin(v)];
        *largest = largest.max(v);
        *count = count.saturating_add(1);
        self.count += 1;
    }

    /// Nearest-rank p-th percentile (see the type's doc), None when empty.
    pub fn percentile(&self, p: f64) -> Option<f64> {
        if self.count == 0 {
            return None;
        }
        let rank = ((p / 100.0) * self.count as f64).ceil().max(1.0) as u64;
        let mut seen = 0u64;
        for &(c, largest) in &self.bins {
            seen += u64::from(c);
            if c > 0 && seen >= rank {
                return Some(largest);
            }
        }
        self.max()
    }

    /// Largest sample.
    pub fn max(&self) -> Option<f64> {
        self.bins.iter().rev().find(|b| b.0 > 0).map(|b| b.1)
    }

    /// p50, p99 and max.
    pub fn stats(&self) -> LatencyStats {
        LatencyStats {
            count: self.count,
            p50: self.percentile(50.0),
            p99: self.percentile(99.0),
            max: self.max(),
        }
    }
}

impl Default for LatencyHistogram {
    fn default() -> Self {
        Self::new()
    }
}

/// End-of-run summary.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct Summary {
    /// Run id.
    pub run: String,
    /// The run's verdict ([`acceptance`](super::acceptance)).
    #[serde(default)]
    pub verdict: Verdict,
    /// Why it is not `pass`: one sentence per reason, with its count.
    #[serde(default)]
    pub reasons: Vec<String>,
    /// What the operator can do about the reasons (and other findings).
    #[serde(default)]
    pub hints: Vec<String>,
    /// Stopped before its planned frames (a signal, the window closed).
    #[serde(default)]
    pub interrupted: bool,
    /// Frames the run was to show (the replay's, or `--frames`); None for
    /// an open-ended closed loop.
    #[serde(default)]
    pub frames_planned: Option<u64>,
    /// Frames logged.
    pub frames: u64,
    /// Frames presented after their deadline.
    pub missed_deadlines: u64,
    /// States dropped (stale, malformed, superseded, …) as reported.
    pub dropped_states: u64,
    /// State received → presented.
    pub latency_state_to_present: LatencyStats,
    /// Median render time [s] of the pre-flight renders done before the
    /// first frame (see `driver::run`); None when none was done.
    #[serde(default)]
    pub preflight_render: Option<f64>,
    /// Render start → conversion end of each frame (the render thread's
    /// work), s.
    #[serde(default)]
    pub frame_work: LatencyStats,
    /// States came over UDP (closed loop).
    #[serde(default)]
    pub closed_loop: bool,
    /// Frames that showed the safe (black) frame: no current state.
    #[serde(default)]
    pub safe_frames: u64,
    /// Of those, the frames before the first state arrived.
    #[serde(default)]
    pub safe_frames_waiting: u64,
    /// Frames whose state put the body entirely out of the field.
    #[serde(default)]
    pub out_of_field_frames: u64,
    /// The first of them and why (`frame 12: the body is entirely out of
    /// the field: …`).
    #[serde(default)]
    pub first_out_of_field: Option<String>,
    /// Frames whose sync line was not sent (device gone, writer behind,
    /// error).
    #[serde(default)]
    pub sync_not_sent: u64,
    /// Datagrams the kernel dropped from the closed loop's UDP receive
    /// buffer (Linux: /proc/net/udp); None in open loop or where the OS
    /// does not tell.
    #[serde(default)]
    pub udp_kernel_drops: Option<u64>,
    /// Smallest and largest `render_over_lime` of the run's frames; None
    /// when no frame had one.
    #[serde(default)]
    pub render_over_lime_range: Option<[f64; 2]>,
    /// Largest `radiometric_u_k2_percent` of the run's frames (k = 2, %);
    /// None when no frame had one.
    #[serde(default)]
    pub radiometric_u_k2_percent_max: Option<f64>,
    /// Frames per governor rung and their predicted errors (absent with
    /// `timing.governor = "off"`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub governor: Option<GovernorSummary>,
    /// The white level's clipping over the run.
    #[serde(default)]
    pub clip_white: ClipSummary,
    /// The black level's clipping over the run.
    #[serde(default)]
    pub clip_black: ClipSummary,
}

/// One clipping level (white or black) over a run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
pub struct ClipSummary {
    /// Frames with a pixel clipped at this level.
    pub frames: u64,
    /// Most pixels clipped in one frame.
    pub pixels_max: u64,
    /// Largest |moved flux| of a frame, as a fraction of its disk flux.
    pub flux_max: f64,
    /// The frame of `flux_max`.
    pub flux_max_frame: Option<u64>,
}

impl ClipSummary {
    fn add(&mut self, frame: u64, pixels: u64, flux: f64) {
        if pixels == 0 {
            return;
        }
        self.frames += 1;
        self.pixels_max = self.pixels_max.max(pixels);
        if flux.abs() > self.flux_max || self.flux_max_frame.is_none() {
            self.flux_max = flux.abs();
            self.flux_max_frame = Some(frame);
        }
    }
}

/// True when `file` is non-empty and its last byte is not a newline.
fn ends_torn(file: &mut File) -> std::io::Result<bool> {
    use std::io::{Read, Seek, SeekFrom};
    if file.metadata()?.len() == 0 {
        return Ok(false);
    }
    file.seek(SeekFrom::End(-1))?;
    let mut last = [0u8; 1];
    file.read_exact(&mut last)?;
    Ok(last[0] != b'\n')
}

/// Append-only, write-through frame log.
#[derive(Debug)]
pub struct FrameLog {
    path: PathBuf,
    file: File,
    run_start: Instant,
    run: String,
    frames: u64,
    missed: u64,
    dropped_states: u64,
    latencies: LatencyHistogram,
    work: LatencyHistogram,
    preflight_render: Option<f64>,
    safe_frames: u64,
    safe_waiting: u64,
    sync_not_sent: u64,
    udp_kernel_drops: Option<u64>,
    lime_range: Option<[f64; 2]>,
    u_max: Option<f64>,
    governor: Option<GovernorSummary>,
    clip_white: ClipSummary,
    clip_black: ClipSummary,
    out_of_field: u64,
    first_out_of_field: Option<String>,
}

impl FrameLog {
    /// Opens (creating or appending to) `path`; `run_start` is time zero.
    pub fn open(path: impl AsRef<Path>, run_start: Instant) -> Result<FrameLog> {
        let path = path.as_ref();
        crate::outfile::check_appendable(path)?;
        let mut file = OpenOptions::new()
            .create(true)
            .append(true)
            .read(true)
            .open(path)
            .map_err(|e| Error::io(path, e))?;
        if ends_torn(&mut file).map_err(|e| Error::io(path, e))? {
            tracing::warn!(
                "{}: the last record is torn (no final newline); starting a new line",
                path.display()
            );
            file.write_all(b"\n").map_err(|e| Error::io(path, e))?;
        }
        let run = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos().to_string())
            .unwrap_or_default();
        Ok(FrameLog {
            path: path.to_path_buf(),
            file,
            run_start,
            run,
            frames: 0,
            missed: 0,
            dropped_states: 0,
            latencies: LatencyHistogram::new(),
            work: LatencyHistogram::new(),
            preflight_render: None,
            safe_frames: 0,
            safe_waiting: 0,
            sync_not_sent: 0,
            udp_kernel_drops: None,
            lime_range: None,
            u_max: None,
            governor: None,
            clip_white: ClipSummary::default(),
            clip_black: ClipSummary::default(),
            out_of_field: 0,
            first_out_of_field: None,
        })
    }

    /// The log file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// This run's id.
    pub fn run(&self) -> &str {
        &self.run
    }

    /// Seconds from the run start to `t` (negative if before).
    pub fn since_start(&self, t: Instant) -> f64 {
        match t.checked_duration_since(self.run_start) {
            Some(d) => d.as_secs_f64(),
            None => -(self.run_start - t).as_secs_f64(),
        }
    }

    /// Missed deadlines so far.
    pub fn missed(&self) -> u64 {
        self.missed
    }

    /// Appends one record (setting `run` and `missed`) and syncs it to disk.
    pub fn write(&mut self, mut rec: FrameRecord) -> Result<()> {
        rec.run.clone_from(&self.run);
        rec.missed = rec.t_presented > rec.deadline;
        let mut line = serde_json::to_string(&rec)
            .map_err(|e| Error::Other(format!("frame record not serialisable: {e}")))?;
        line.push('\n');
        let io = |e| Error::io(&self.path, e);
        self.file.write_all(line.as_bytes()).map_err(io)?;
        self.file.flush().map_err(io)?;
        self.file.sync_data().map_err(io)?;
        self.frames += 1;
        self.missed += u64::from(rec.missed);
        self.safe_frames += u64::from(rec.safe_frame);
        if rec.safe_frame && self.safe_waiting + 1 == self.frames {
            self.safe_waiting += 1;
        }
        self.work.add(rec.t_convert_end - rec.t_render_start);
        self.clip_white
            .add(rec.frame, rec.clipped_white, rec.clip_flux_white);
        self.clip_black
            .add(rec.frame, rec.clipped_black, rec.clip_flux_black);
        if let Some(r) = rec.render_over_lime {
            let [lo, hi] = self.lime_range.get_or_insert([r, r]);
            *lo = lo.min(r);
            *hi = hi.max(r);
        }
        if let Some(u) = rec.radiometric_u_k2_percent {
            self.u_max = Some(self.u_max.map_or(u, |m: f64| m.max(u)));
        }
        if let Some(r) = rec.t_state_received {
            self.latencies.add(rec.t_presented - r);
        }
        if let (Some(g), Some(f)) = (&mut self.governor, &rec.fidelity) {
            g.add(f);
        }
        Ok(())
    }

    /// The run is governed over rungs labelled `labels`: the summary
    /// tallies its frames per rung.
    pub fn set_governor_rungs(&mut self, labels: Vec<String>) {
        self.governor = Some(GovernorSummary::new(labels));
    }

    /// Counts a frame whose state put the body out of the field; `why`
    /// names the geometry (kept for the first).
    pub fn note_out_of_field(&mut self, frame: u64, why: &str) {
        self.out_of_field += 1;
        self.first_out_of_field
            .get_or_insert_with(|| format!("frame {frame}: {why}"));
    }

    /// Records the pre-flight render time [s] for the summary.
    pub fn set_preflight_render(&mut self, seconds: f64) {
        self.preflight_render = Some(seconds);
    }

    /// Counts one frame whose sync line was not sent.
    pub fn add_sync_not_sent(&mut self) {
        self.sync_not_sent += 1;
    }

    /// Records the kernel's drop count of the closed loop's UDP socket.
    pub fn set_udp_kernel_drops(&mut self, n: u64) {
        self.udp_kernel_drops = Some(n);
    }

    /// Counts states dropped before rendering.
    pub fn add_dropped_states(&mut self, n: u64) {
        self.dropped_states += n;
    }

    /// Summary of the records written by this `FrameLog`.
    pub fn summary(&self) -> Summary {
        Summary {
            run: self.run.clone(),
            frames: self.frames,
            missed_deadlines: self.missed,
            dropped_states: self.dropped_states,
            latency_state_to_present: self.latencies.stats(),
            frame_work: self.work.stats(),
            preflight_render: self.preflight_render,
            safe_frames: self.safe_frames,
            safe_frames_waiting: self.safe_waiting,
            sync_not_sent: self.sync_not_sent,
            udp_kernel_drops: self.udp_kernel_drops,
            render_over_lime_range: self.lime_range,
            radiometric_u_k2_percent_max: self.u_max,
            governor: self.governor.clone(),
            clip_white: self.clip_white,
            clip_black: self.clip_black,
            out_of_field_frames: self.out_of_field,
            first_out_of_field: self.first_out_of_field.clone(),
            ..Default::default()
        }
    }

    /// Writes the summary as pretty JSON to `path` (atomically) and returns it.
    pub fn write_summary(&self, path: impl AsRef<Path>) -> Result<Summary> {
        let s = self.summary();
        write_summary(path.as_ref(), &s)?;
        Ok(s)
    }
}

/// Writes `summary` as pretty JSON to `path` (atomically).
pub fn write_summary(path: &Path, summary: &Summary) -> Result<()> {
    let text = serde_json::to_string_pretty(summary)
        .map_err(|e| Error::Other(format!("summary not serialisable: {e}")))?;
    crate::outfile::write_atomic(path, (text + "\n").as_bytes())
}

/// Reads a frame log. An unterminated last line (crash mid-write) is
/// ignored, and so is a torn record that a later run closed with a newline
/// (a `{` line that does not end in `}`); any other bad line is an error
/// naming the line.
pub fn read_records(path: impl AsRef<Path>) -> Result<Vec<FrameRecord>> {
    let path = path.as_ref();
    let text = crate::infile::read_text_bounded(path, crate::infile::DATA_LIMIT)?;
    let complete = match text.rfind('\n') {
        Some(i) => &text[..=i],
        None => "",
    };
    complete
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty() && !is_torn(l))
        .map(|(i, l)| {
            serde_json::from_str(l).map_err(|e| Error::parse(path, format!("line {}: {e}", i + 1)))
        })
        .collect()
}

/// A record cut short: begun as an object but not closed.
fn is_torn(line: &str) -> bool {
    let l = line.trim();
    l.starts_with('{') && !l.ends_with('}')
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(frame: u64, recv: Option<f64>, presented: f64, deadline: f64) -> FrameRecord {
        FrameRecord {
            frame,
            state_t: frame as f64 * 0.1,
            t_state_received: recv,
            t_render_start: presented - 0.01,
            t_render_end: presented - 0.005,
            t_convert_end: presented - 0.002,
            t_presented: presented,
            t_sync_sent: Some(presented + 0.0001),
            t_ack: None,
            deadline,
            clipped: frame * 3,
            peak_radiance: 12.5,
            k: 0.25,
            lut_sha256: "ab".repeat(32),
            calibration_sha256: None,
            ..Default::default()
        }
    }

    #[test]
    fn nearest_rank_percentiles() {
        // 1 … 100 ms: nearest rank p50 = 50 ms, p99 = 99 ms.
        let v: Vec<f64> = (1..=100).rev().map(|i| i as f64 * 1e-3).collect();
        let s = LatencyStats::from_samples(&v);
        assert_eq!(s.count, 100);
        assert_eq!(s.p50, Some(0.050));
        assert_eq!(s.p99, Some(0.099));
        assert_eq!(s.max, Some(0.100));
        let one = LatencyStats::from_samples(&[0.2]);
        assert_eq!(
            (one.p50, one.p99, one.max),
            (Some(0.2), Some(0.2), Some(0.2))
        );
        assert_eq!(LatencyStats::from_samples(&[]).p50, None);
    }

    /// The fixed-memory histogram against exact nearest ranks of the same
    /// samples: within its 1e-3 bin width, an observed sample, and exact
    /// for well-separated values.
    #[test]
    fn histogram_percentiles_match_exact_nearest_ranks() {
        let mut h = LatencyHistogram::new();
        let v: Vec<f64> = (1..=100).rev().map(|i| i as f64 * 1e-3).collect();
        v.iter().for_each(|&x| h.add(x));
        assert_eq!(h.stats(), LatencyStats::from_samples(&v));
        // A dense, skewed stream: 1e-3 relative, and always a sample.
        let mut h = LatencyHistogram::new();
        let mut v = Vec::new();
        let mut x = 0.3f64;
        for _ in 0..20_000 {
            x = (x * 3.9 * (1.0 - x)).clamp(1e-9, 1.0 - 1e-9); // logistic map
            let sample = 0.012 + 0.02 * x * x * x;
            v.push(sample);
            h.add(sample);
        }
        h.add(f64::NAN);
        let exact = LatencyStats::from_samples(&v);
        let got = h.stats();
        assert_eq!((got.count, got.max), (exact.count, exact.max));
        for (a, b) in [(got.p50, exact.p50), (got.p99, exact.p99)] {
            let (a, b) = (a.unwrap(), b.unwrap());
            assert!((a - b).abs() <= 1e-3 * b, "{a} vs {b}");
            assert!(v.contains(&a), "{a} is not a sample");
        }
        assert_eq!(LatencyHistogram::new().stats().p50, None);
    }

    #[test]
    fn records_summary_and_append_only() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("frames.jsonl");
        std::fs::write(&p, "{\"old\":true}\n").unwrap();
        let start = Instant::now();
        let mut log = FrameLog::open(&p, start).unwrap();
        assert!(log.since_start(start + std::time::Duration::from_millis(1500)) - 1.5 < 1e-9);
        log.write(rec(0, Some(0.0), 0.020, 0.030)).unwrap();
        log.write(rec(1, Some(0.1), 0.150, 0.130)).unwrap(); // missed
        log.write(rec(2, None, 0.210, 0.230)).unwrap();
        log.add_dropped_states(4);
        let text = std::fs::read_to_string(&p).unwrap();
        assert!(
            text.starts_with("{\"old\":true}\n"),
            "existing content kept"
        );
        let lines: Vec<&str> = text.lines().skip(1).collect();
        assert_eq!(lines.len(), 3);
        let r1: FrameRecord = serde_json::from_str(lines[1]).unwrap();
        assert!(r1.missed && r1.run == log.run() && r1.frame == 1);
        let s = log.write_summary(dir.path().join("summary.json")).unwrap();
        assert_eq!((s.frames, s.missed_deadlines, s.dropped_states), (3, 1, 4));
        let l = s.latency_state_to_present;
        assert_eq!(l.count, 2);
        assert!((l.max.unwrap() - 0.05).abs() < 1e-12);
        assert!((l.p50.unwrap() - 0.02).abs() < 1e-12);
        let back: Summary = serde_json::from_str(
            &std::fs::read_to_string(dir.path().join("summary.json")).unwrap(),
        )
        .unwrap();
        assert_eq!(back, s);
    }

    #[test]
    fn safe_frame_without_state_time_reads_back() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("f.jsonl");
        let mut log = FrameLog::open(&p, Instant::now()).unwrap();
        log.write(FrameRecord {
            state_t: f64::NAN,
            safe_frame: true,
            ..rec(0, None, 1.0, 2.0)
        })
        .unwrap();
        let r = read_records(&p).unwrap();
        assert!(r[0].state_t.is_nan() && r[0].safe_frame);
    }

    #[test]
    fn reader_ignores_torn_last_line_but_reports_bad_lines() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("f.jsonl");
        let good = serde_json::to_string(&rec(7, None, 1.0, 2.0)).unwrap();
        std::fs::write(&p, format!("{good}\n{}", &good[..good.len() / 2])).unwrap();
        let r = read_records(&p).unwrap();
        assert_eq!(r.len(), 1);
        assert_eq!(r[0].frame, 7);
        std::fs::write(&p, format!("{good}\nnot json\n")).unwrap();
        let e = read_records(&p).unwrap_err().to_string();
        assert!(e.contains("f.jsonl") && e.contains("line 2"), "{e}");
    }
}
