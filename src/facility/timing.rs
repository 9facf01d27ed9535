//! Timing figure of a frame log (`optistim plot-log`): state → present
//! latency against the frame's presentation time, missed deadlines in red,
//! frames on time coloured by the governor's rung when it governed,
//! and the latency histogram with its nearest-rank p50 and p99 (the same
//! statistics as the run summary, [`LatencyStats::from_samples`]).

use std::path::Path;

use plotters::style::RGBColor;

use crate::error::{Error, Result};
use crate::facility::log::{FrameRecord, LatencyStats};
use crate::figures::{curve_and_histogram, CurveAndHistogram, Histogram, Panel, Series, PALETTE};

/// Pixel size of `timing.png`.
pub const TIMING_FIGURE_SIZE: (u32, u32) = (1100, 800);

/// Colour of missed deadlines.
pub const MISSED_RED: RGBColor = RGBColor(220, 0, 0);

/// What the figure shows of one run.
#[derive(Debug, Clone, PartialEq)]
pub struct RunTiming {
    pub run: String,
    pub frames: usize,
    pub missed: usize,
    pub safe_frames: usize,
    /// `(t_presented [s], latency [ms])` of frames on time / late.
    pub on_time: Vec<(f64, f64)>,
    /// The governor's rung of each frame on time, in `on_time`'s order
    /// (empty when the run was not governed).
    pub on_time_rungs: Vec<usize>,
    pub late: Vec<(f64, f64)>,
    /// Over all frames with a state, ms.
    pub latency_ms: LatencyStats,
}

/// State received → presented, ms; `None` for a safe frame (no state).
fn latency_ms(r: &FrameRecord) -> Option<f64> {
    let recv = r.t_state_received?;
    let l = (r.t_presented - recv) * 1e3;
    l.is_finite().then_some(l)
}

/// Run ids in the order they first appear in the log.
pub fn runs(records: &[FrameRecord]) -> Vec<String> {
    let mut ids: Vec<String> = Vec::new();
    for r in records {
        if !ids.contains(&r.run) {
            ids.push(r.run.clone());
        }
    }
    ids
}

impl RunTiming {
    /// The records of `run`.
    pub fn of_run(records: &[FrameRecord], run: &str) -> RunTiming {
        let mine: Vec<&FrameRecord> = records.iter().filter(|r| r.run == run).collect();
        let mut t = RunTiming {
            run: run.to_string(),
            frames: mine.len(),
            missed: mine.iter().filter(|r| r.missed).count(),
            safe_frames: mine.iter().filter(|r| r.safe_frame).count(),
            on_time: Vec::new(),
            on_time_rungs: Vec::new(),
            late: Vec::new(),
            latency_ms: LatencyStats::default(),
        };
        for r in &mine {
            if let Some(l) = latency_ms(r) {
                let p = (r.t_presented, l);
                if r.missed {
                    t.late.push(p)
                } else {
                    t.on_time.push(p);
                    if let Some(f) = r.fidelity {
                        t.on_time_rungs.push(f.rung);
                    }
                }
            }
        }
        let all: Vec<f64> = t.on_time.iter().chain(&t.late).map(|p| p.1).collect();
        t.latency_ms = LatencyStats::from_samples(&all);
        t
    }
}

/// Frames on time (one series per governor rung when governed), then the
/// missed ones in red.
fn latency_series(timing: &RunTiming) -> Vec<Series> {
    let mut series = Vec::new();
    if timing.on_time_rungs.len() == timing.on_time.len() && !timing.on_time_rungs.is_empty() {
        let top = timing.on_time_rungs.iter().copied().max().unwrap_or(0);
        for rung in 0..=top {
            let points: Vec<(f64, f64)> = timing
                .on_time
                .iter()
                .zip(&timing.on_time_rungs)
                .filter(|(_, &r)| r == rung)
                .map(|(p, _)| *p)
                .collect();
            if !points.is_empty() {
                let colour = PALETTE[rung % PALETTE.len()];
                let label = format!("on time, governor rung {rung}");
                series.push(Series::points(label, points).with_colour(colour));
            }
        }
    } else {
        series.push(Series::points("on time", timing.on_time.clone()));
    }
    series.push(Series::points("missed deadline", timing.late.clone()).with_colour(MISSED_RED));
    series
}

/// Writes the timing figure of `timing` to `path`.
pub fn write_timing_figure(path: &Path, timing: &RunTiming) -> Result<()> {
    if timing.on_time.is_empty() && timing.late.is_empty() {
        return Err(Error::invalid(
            path.display().to_string(),
            format!("run {}: no frame with a state to plot", timing.run),
        ));
    }
    let l = &timing.latency_ms;
    let fmt = |v: Option<f64>| v.map_or("–".into(), |v| format!("{v:.2} ms"));
    let title = format!(
        "Frame timing, run {}: {} frames, {} missed, {} safe",
        timing.run, timing.frames, timing.missed, timing.safe_frames
    );
    let values: Vec<f64> = timing
        .on_time
        .iter()
        .chain(&timing.late)
        .map(|p| p.1)
        .collect();
    let bins = (values.len() / 5).clamp(10, 80);
    let fig = CurveAndHistogram {
        title,
        x_label: "frame presented (s since run start)".into(),
        main: Panel {
            y_label: "state → present latency (ms)".into(),
            log_y: false,
            series: latency_series(timing),
        },
        histogram: Histogram {
            x_label: "state → present latency (ms)".into(),
            y_label: "frames".into(),
            values,
            bins,
            markers: vec![
                (format!("p50 {}", fmt(l.p50)), l.p50.unwrap_or(f64::NAN)),
                (format!("p99 {}", fmt(l.p99)), l.p99.unwrap_or(f64::NAN)),
            ],
        },
        size: TIMING_FIGURE_SIZE,
    };
    curve_and_histogram(path, &fig)
}
