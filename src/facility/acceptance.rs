//! Run acceptance: the facility file's `[acceptance]` table, and the
//! verdict of a run (`pass`, `degraded`, `fail`) drawn from its summary,
//! with one sentence per reason (each with its count) and the hints an
//! operator can act on.
//!
//! | rule | verdict |
//! |---|---|
//! | more sync lines not sent than `max_sync_not_sent` (default 0) | fail |
//! | a safe (black) frame in a replay | fail |
//! | closed loop: no state received at all | fail |
//! | closed loop: safe frames after the first state > `max_safe_fraction` of those frames (default 1 %) | fail |
//! | missed deadlines > `missed_fail` of the frames (default 5 %) | fail |
//! | missed deadlines > `missed_degraded` (default 0.5 %) | degraded |
//! | a frame's clipped flux (white or black level) > `max_clip_flux` of its disk flux (default 0.1 %) | degraded |
//! | a frame with the body out of the field, unless `allow_empty_frames` | fail |
//! | governed frames whose rung's predicted pixel error exceeds `timing.governor_max_pixel_error` | degraded |
//! | stopped before its planned frames (Ctrl-C, SIGTERM, window closed) | fail |
//! | no frame shown | fail |

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::log::Summary;
use crate::error::{Error, Result};

/// A run's verdict, from best to worst.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Verdict {
    /// Every rule met.
    #[default]
    Pass,
    /// Usable, with a known loss (late frames, clipped flux).
    Degraded,
    /// Not usable as a campaign's data.
    Fail,
}

impl Verdict {
    /// `pass`, `degraded` or `fail`.
    pub fn as_str(self) -> &'static str {
        match self {
            Verdict::Pass => "pass",
            Verdict::Degraded => "degraded",
            Verdict::Fail => "fail",
        }
    }
}

/// `[acceptance]`: what a run must meet (see the module docs).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AcceptanceConfig {
    /// Sync lines that may go unsent before the run fails.
    pub max_sync_not_sent: u64,
    /// Closed loop: largest fraction of the frames after the first state
    /// that may be safe frames.
    pub max_safe_fraction: f64,
    /// Fraction of missed deadlines above which the run is degraded.
    pub missed_degraded: f64,
    /// Fraction of missed deadlines above which the run fails.
    pub missed_fail: f64,
    /// Largest clipped flux of a frame (white or black level), as a
    /// fraction of its target disk flux, before the run is degraded.
    pub max_clip_flux: f64,
    /// Frames with the body entirely out of the field are allowed (the
    /// replay's states are not checked before the first frame).
    pub allow_empty_frames: bool,
}

impl Default for AcceptanceConfig {
    fn default() -> Self {
        AcceptanceConfig {
            max_sync_not_sent: 0,
            max_safe_fraction: 0.01,
            missed_degraded: 0.005,
            missed_fail: 0.05,
            max_clip_flux: 1e-3,
            allow_empty_frames: false,
        }
    }
}

fn fraction(key: &str, v: f64) -> Result<()> {
    if v.is_finite() && (0.0..=1.0).contains(&v) {
        Ok(())
    } else {
        Err(Error::invalid(
            format!("acceptance.{key}"),
            format!("must be a fraction in [0, 1], found {v}"),
        ))
    }
}

impl AcceptanceConfig {
    /// Every fraction finite and in [0, 1], and `missed_degraded` ≤
    /// `missed_fail`; errors name the key.
    pub fn validate(&self) -> Result<()> {
        fraction("max_safe_fraction", self.max_safe_fraction)?;
        fraction("missed_degraded", self.missed_degraded)?;
        fraction("missed_fail", self.missed_fail)?;
        fraction("max_clip_flux", self.max_clip_flux)?;
        if self.missed_degraded > self.missed_fail {
            return Err(Error::invalid(
                "acceptance.missed_degraded",
                format!(
                    "must not exceed acceptance.missed_fail ({} > {})",
                    self.missed_degraded, self.missed_fail
                ),
            ));
        }
        Ok(())
    }
}

/// What the hints need besides the summary.
pub struct RunContext<'a> {
    /// One screen refresh [s].
    pub refresh_s: f64,
    /// `timing.refreshes_per_frame` of the run.
    pub refreshes_per_frame: u32,
    /// `screen.render_block` of the run.
    pub render_block: usize,
    /// The frame log.
    pub log: &'a Path,
}

/// The verdict's findings as they are collected.
#[derive(Default)]
struct Findings {
    verdict: Verdict,
    reasons: Vec<String>,
    hints: Vec<String>,
}

impl Findings {
    fn add(&mut self, verdict: Verdict, reason: String) {
        self.verdict = self.verdict.max(verdict);
        self.reasons.push(reason);
    }
}

fn percent(n: u64, of: u64) -> f64 {
    100.0 * n as f64 / of.max(1) as f64
}

/// Sets `s.verdict`, `s.reasons` and `s.hints` from the rest of `s`.
pub fn judge(s: &mut Summary, a: &AcceptanceConfig, ctx: &RunContext) {
    let mut f = Findings::default();
    if s.frames == 0 {
        f.add(Verdict::Fail, "no frame was shown".into());
    }
    if let Some(planned) = s.frames_planned.filter(|&n| s.frames < n) {
        f.add(
            Verdict::Fail,
            format!("interrupted after {} of {planned} planned frames", s.frames),
        );
    }
    sync_rule(s, a, &mut f);
    safe_rule(s, a, &mut f);
    missed_rule(s, a, ctx, &mut f);
    clip_rule(s, a, &mut f);
    empty_rule(s, a, &mut f);
    governor_rule(s, &mut f);
    s.verdict = f.verdict;
    s.reasons = f.reasons;
    s.hints = f.hints;
}

/// Frames the governor rendered below the fidelity floor are degraded:
/// shown, counted and named, never silently.
fn governor_rule(s: &Summary, f: &mut Findings) {
    let Some(g) = &s.governor else { return };
    if g.degraded_frames > 0 {
        let worst = g
            .rungs
            .iter()
            .filter(|r| r.frames > 0)
            .map(|r| r.max_pixel_error)
            .fold(0.0, f64::max);
        f.add(
            Verdict::Degraded,
            format!(
                "{} of {} frames were rendered at a governor rung whose predicted per-pixel error exceeds timing.governor_max_pixel_error (worst p99 {:.1} %)",
                g.degraded_frames,
                s.frames,
                100.0 * worst
            ),
        );
        f.hints.push(
            "timing.refreshes_per_frame = 2 gives each frame twice the time (a finer rung)".into(),
        );
    }
    if g.unfit_frames > 0 {
        f.hints.push(format!(
            "{} frames were predicted not to fit their slot even at the coarsest rung",
            g.unfit_frames
        ));
    }
}

fn sync_rule(s: &Summary, a: &AcceptanceConfig, f: &mut Findings) {
    if s.sync_not_sent > a.max_sync_not_sent {
        f.add(
            Verdict::Fail,
            format!(
                "{} of {} sync lines were not sent: the camera was not triggered for those frames",
                s.sync_not_sent, s.frames
            ),
        );
        f.hints.push(
            "check the serial device (--serial, sync.port); `--serial none` runs without sync on purpose"
                .into(),
        );
    }
}

fn safe_rule(s: &Summary, a: &AcceptanceConfig, f: &mut Findings) {
    if s.safe_frames == 0 {
        return;
    }
    if !s.closed_loop {
        f.add(
            Verdict::Fail,
            format!(
                "{} of {} frames were the safe (black) frame",
                s.safe_frames, s.frames
            ),
        );
        return;
    }
    if s.safe_frames >= s.frames {
        f.add(
            Verdict::Fail,
            format!(
                "no state was received: all {} frames were the safe (black) frame",
                s.frames
            ),
        );
        f.hints.push(
            "is the sender running, sending to the --listen address from the --sender address?"
                .into(),
        );
        return;
    }
    let after = s.frames - s.safe_frames_waiting;
    let safe = s.safe_frames - s.safe_frames_waiting;
    if safe as f64 > a.max_safe_fraction * after as f64 {
        f.add(
            Verdict::Fail,
            format!(
                "{safe} of the {after} frames after the first state were the safe (black) frame \
                 ({:.2} %, acceptance.max_safe_fraction {} %)",
                percent(safe, after),
                100.0 * a.max_safe_fraction
            ),
        );
        f.hints.push(
            "states arrived late or stopped: compare the sender's rate with timing.state_timeout"
                .into(),
        );
    }
    if s.safe_frames_waiting > 0 {
        f.hints.push(format!(
            "{} safe frames before the first state are not counted (start the sender first to avoid them)",
            s.safe_frames_waiting
        ));
    }
}

fn missed_rule(s: &Summary, a: &AcceptanceConfig, ctx: &RunContext, f: &mut Findings) {
    if s.missed_deadlines == 0 {
        return;
    }
    let fraction = s.missed_deadlines as f64 / s.frames.max(1) as f64;
    let sentence = |bound: &str, v: f64| {
        format!(
            "{} of {} frames missed their deadline ({:.1} %, acceptance.{bound} {} %)",
            s.missed_deadlines,
            s.frames,
            100.0 * fraction,
            100.0 * v
        )
    };
    if fraction > a.missed_fail {
        f.add(Verdict::Fail, sentence("missed_fail", a.missed_fail));
    } else if fraction > a.missed_degraded {
        f.add(
            Verdict::Degraded,
            sentence("missed_degraded", a.missed_degraded),
        );
    }
    let mut hint = String::new();
    if let Some(p99) = s.frame_work.p99.filter(|v| v.is_finite() && *v > 0.0) {
        let refresh = std::time::Duration::from_secs_f64(ctx.refresh_s);
        let needed =
            super::driver::refreshes_needed(std::time::Duration::from_secs_f64(p99), refresh);
        if needed > ctx.refreshes_per_frame {
            hint = format!(
                "timing.refreshes_per_frame = {needed} would give the slowest 1 % of frames \
                 (render + conversion {:.1} ms) a quarter of margin; ",
                p99 * 1e3
            );
        }
    }
    if ctx.render_block < 2 {
        hint.push_str("screen.render_block = 2 about halves the render time; ");
    }
    f.hints.push(format!(
        "{hint}`optistim plot-log {} --run {}` shows when the deadlines were missed",
        ctx.log.display(),
        s.run
    ));
}

fn clip_rule(s: &Summary, a: &AcceptanceConfig, f: &mut Findings) {
    let levels = [
        (
            &s.clip_white,
            "white level (the LUT's top)",
            "it took away",
            "a longer drive.facility_exposure (smaller k) or a clearer optical path (higher τ) \
             lowers the screen radiance the scene needs",
        ),
        (
            &s.clip_black,
            "black level (drive level 0)",
            "it added",
            "the black level sets the dimmest radiance the screen can show (black × τ / k at the camera): \
             an ND filter in front of the screen (lower τ) or a shorter drive.facility_exposure (larger k) \
             runs the screen brighter, above its black",
        ),
    ];
    for (clip, level, moved, hint) in levels {
        let Some(frame) = clip.flux_max_frame else {
            continue;
        };
        if clip.flux_max > a.max_clip_flux {
            f.add(
                Verdict::Degraded,
                format!(
                    "{} frames clipped at the screen's {level}; {moved} up to {:.3} % of a frame's disk flux \
                     (frame {frame}, up to {} pixels a frame; acceptance.max_clip_flux {} %)",
                    clip.frames,
                    100.0 * clip.flux_max,
                    clip.pixels_max,
                    100.0 * a.max_clip_flux
                ),
            );
            f.hints.push(hint.into());
        }
    }
}

fn empty_rule(s: &Summary, a: &AcceptanceConfig, f: &mut Findings) {
    if s.out_of_field_frames == 0 || a.allow_empty_frames {
        return;
    }
    f.add(
        Verdict::Fail,
        format!(
            "{} of {} frames showed nothing: the state put the body out of the field ({})",
            s.out_of_field_frames,
            s.frames,
            s.first_out_of_field.as_deref().unwrap_or("")
        ),
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ctx() -> RunContext<'static> {
        RunContext {
            refresh_s: 1.0 / 60.0,
            refreshes_per_frame: 1,
            render_block: 1,
            log: Path::new("out/f.jsonl"),
        }
    }

    fn summary(frames: u64) -> Summary {
        Summary {
            run: "7".into(),
            frames,
            frames_planned: Some(frames),
            ..Default::default()
        }
    }

    fn judged(mut s: Summary) -> Summary {
        judge(&mut s, &AcceptanceConfig::default(), &ctx());
        s
    }

    #[test]
    fn a_clean_run_passes() {
        let s = judged(summary(300));
        assert_eq!((s.verdict, s.reasons.len()), (Verdict::Pass, 0));
    }

    /// 0.5 % and 5 % of 1000 frames are 5 and 50: strictly above degrades
    /// or fails.
    #[test]
    fn missed_deadlines_degrade_then_fail_at_the_bounds() {
        for (missed, verdict) in [
            (5, Verdict::Pass),
            (6, Verdict::Degraded),
            (50, Verdict::Degraded),
            (51, Verdict::Fail),
        ] {
            let s = judged(Summary {
                missed_deadlines: missed,
                frame_work: crate::facility::log::LatencyStats {
                    p99: Some(0.030),
                    ..Default::default()
                },
                ..summary(1000)
            });
            assert_eq!(s.verdict, verdict, "{missed}: {:?}", s.reasons);
            let hints = s.hints.join(" ");
            // 1.25 × 30 ms = 37.5 ms: three 16.7 ms refreshes.
            assert!(
                hints.contains("refreshes_per_frame = 3")
                    && hints.contains("render_block = 2")
                    && hints.contains("plot-log out/f.jsonl --run 7"),
                "{hints}"
            );
            if verdict != Verdict::Pass {
                assert!(s.reasons[0].starts_with(&format!("{missed} of 1000 frames")));
            }
        }
    }

    #[test]
    fn sync_safe_and_interrupted_runs_fail() {
        let s = judged(Summary {
            sync_not_sent: 1,
            ..summary(120)
        });
        assert_eq!(s.verdict, Verdict::Fail);
        assert!(
            s.reasons[0].starts_with("1 of 120 sync lines"),
            "{:?}",
            s.reasons
        );

        let s = judged(Summary {
            safe_frames: 1,
            ..summary(120)
        });
        assert_eq!(s.verdict, Verdict::Fail, "any safe frame in a replay");

        // Closed loop: 10 frames waiting for the first state are not
        // counted; 1 of the other 100 is 1 %: allowed; 2 is not.
        let udp = |safe| Summary {
            closed_loop: true,
            safe_frames: safe,
            safe_frames_waiting: 10,
            ..summary(110)
        };
        assert_eq!(judged(udp(11)).verdict, Verdict::Pass);
        let s = judged(udp(12));
        assert_eq!(s.verdict, Verdict::Fail);
        assert!(
            s.reasons[0].starts_with("2 of the 100 frames"),
            "{:?}",
            s.reasons
        );
        let s = judged(Summary {
            closed_loop: true,
            safe_frames: 100,
            safe_frames_waiting: 100,
            ..summary(100)
        });
        assert_eq!(s.verdict, Verdict::Fail);
        assert!(
            s.reasons[0].contains("no state was received"),
            "{:?}",
            s.reasons
        );

        let s = judged(Summary {
            frames_planned: Some(300),
            ..summary(125)
        });
        assert_eq!(s.verdict, Verdict::Fail);
        assert_eq!(s.reasons, ["interrupted after 125 of 300 planned frames"]);
        // An open-ended closed loop ends by a signal: not interrupted.
        let s = judged(Summary {
            frames_planned: None,
            closed_loop: true,
            ..summary(125)
        });
        assert_eq!(s.verdict, Verdict::Pass);
    }

    #[test]
    fn frames_out_of_the_field_fail_unless_allowed() {
        let s = judged(Summary {
            out_of_field_frames: 3,
            first_out_of_field: Some("frame 4: the body is entirely out of the field".into()),
            ..summary(50)
        });
        assert_eq!(s.verdict, Verdict::Fail);
        assert_eq!(
            s.reasons,
            [
                "3 of 50 frames showed nothing: the state put the body out of the field \
              (frame 4: the body is entirely out of the field)"
            ]
        );
        let mut s = Summary {
            out_of_field_frames: 3,
            ..summary(50)
        };
        let allow = AcceptanceConfig {
            allow_empty_frames: true,
            ..Default::default()
        };
        judge(&mut s, &allow, &ctx());
        assert_eq!(s.verdict, Verdict::Pass);
    }

    #[test]
    fn thresholds_are_range_checked_by_name() {
        let parse = |t: &str| toml::from_str::<AcceptanceConfig>(t).unwrap();
        for (text, key) in [
            ("missed_fail = nan", "acceptance.missed_fail"),
            ("max_safe_fraction = 1.5", "acceptance.max_safe_fraction"),
            ("max_clip_flux = -1e-3", "acceptance.max_clip_flux"),
            (
                "missed_degraded = 0.1\nmissed_fail = 0.05",
                "acceptance.missed_degraded",
            ),
        ] {
            let e = parse(text).validate().unwrap_err().to_string();
            assert!(e.contains(key) && !e.contains('\n'), "{text}: {e}");
        }
        parse("missed_fail = 1.0").validate().unwrap();
    }
}
