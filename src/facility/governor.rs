//! The frame-time governor of `optistim run`: a ladder of render
//! fidelities (rungs), a cost model per rung measured before the first
//! frame over the trajectory's range of apparent sizes and corrected
//! online from the frames just rendered, and per frame the finest rung
//! whose predicted time fits the frame's slot. Each rung's error against
//! a converged render is measured in the same pre-flight, so every frame can
//! log the error of the rung it was rendered at.
//!
//! This module is the decision logic only; the pre-flight renders live in
//! the driver (`driver::fidelity`).

use std::collections::VecDeque;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::fidelity;
use crate::render::RenderSettings;

/// Safety factor on a predicted render time: a rung is chosen only if its
/// prediction × this fits the time available.
pub const SAFETY: f64 = 1.2;
/// Frames over which the measured/predicted ratio (the machine's load) is
/// taken.
const LOAD_WINDOW: usize = 30;
/// The quantile of the recent ratios used as the load factor: a frame
/// must fit even when the machine is as slow as in most recent frames.
const LOAD_QUANTILE: f64 = 0.9;
/// One fidelity step: blocks of `block`² screen pixels rendered with
/// `settings`.
#[derive(Clone, Debug)]
pub struct Rung {
    pub label: String,
    pub block: usize,
    pub settings: RenderSettings,
}

/// The ladder from the configured fidelity down: the scene's settings at
/// the configured block; the same with the looser interior tolerance;
/// then one albedo-map sample per cap instead of k×k; then blocks of 2,
/// 3, … × the configured block up to `max_block` (the steps the
/// benchmarks show to buy the most time per unit of error).
pub fn ladder(base: &RenderSettings, block: usize, max_block: usize) -> Vec<Rung> {
    let block = block.max(1);
    let steps = fidelity::coarser_steps(base, "configured");
    let coarsest = steps.last().map(|s| s.settings.clone()).unwrap_or_default();
    let mut rungs: Vec<Rung> = steps
        .into_iter()
        .map(|s| Rung {
            label: format!("block {block}, {}", s.label),
            block,
            settings: s.settings,
        })
        .collect();
    for m in 2.. {
        let b = block * m;
        if b > max_block {
            break;
        }
        rungs.push(Rung {
            label: format!("block {b}"),
            block: b,
            settings: coarsest.clone(),
        });
    }
    rungs
}

/// [`ladder`] for a body with relief (`[body] shadows`): after the
/// configured block's rungs, the same again without the relief
/// (`[render] relief = false`: no cast shadows, no displacement; on the
/// bundled Moon a relief frame costs about 4 times a plain one,
/// BENCHMARKS.md), and the coarser blocks without it. The frame log names
/// the rung, and its `shadows` record says `render.relief = false`.
pub fn ladder_with_relief(base: &RenderSettings, block: usize, max_block: usize) -> Vec<Rung> {
    let mut rungs = ladder(base, block, max_block);
    let configured = rungs.iter().take_while(|r| r.block == block.max(1)).count();
    let plain: Vec<Rung> = rungs
        .iter_mut()
        .enumerate()
        .filter_map(|(i, r)| {
            let mut p = r.clone();
            p.settings.relief = false;
            p.label = format!("{}, no relief", r.label);
            if i >= configured {
                *r = p;
                None
            } else {
                Some(p)
            }
        })
        .collect();
    rungs.splice(configured..configured, plain);
    rungs
}

/// One pre-flight measurement of a rung at an apparent size.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Sample {
    /// Apparent disk area, screen px².
    pub area_px: f64,
    /// Render time, s (the faster of the repeats).
    pub seconds: f64,
    /// 99th percentile of |rung / converged − 1| over the disk's pixels.
    pub pixel_error: f64,
    /// |Σ rung / Σ converged − 1| over the screen: the disk-flux error.
    pub flux_error: f64,
}

/// What the pre-flight measured of one rung, and the cost model fitted to
/// it: seconds = intercept + slope × area.
#[derive(Clone, Debug)]
pub struct RungProfile {
    pub rung: Rung,
    samples: Vec<Sample>,
    intercept: f64,
    slope: f64,
}

impl RungProfile {
    /// Fits the cost model to `samples` (least squares, both coefficients
    /// kept non-negative).
    pub fn new(rung: Rung, mut samples: Vec<Sample>) -> RungProfile {
        samples.retain(|s| s.area_px.is_finite() && s.seconds.is_finite());
        samples.sort_by(|a, b| a.area_px.total_cmp(&b.area_px));
        let (intercept, slope) = fit_line(&samples);
        RungProfile {
            rung,
            samples,
            intercept,
            slope,
        }
    }

    /// Predicted render time at `area_px`, s, on the machine as measured.
    pub fn predict_seconds(&self, area_px: f64) -> f64 {
        self.intercept + self.slope * area_px.max(0.0)
    }

    /// Predicted (pixel, flux) error at `area_px`: interpolated in
    /// ln(area) between the samples, held at the ends.
    pub fn predict_error(&self, area_px: f64) -> (f64, f64) {
        let s = &self.samples;
        let Some(first) = s.first() else {
            return (0.0, 0.0);
        };
        if s.len() == 1 || area_px <= first.area_px {
            return (first.pixel_error, first.flux_error);
        }
        let last = s[s.len() - 1];
        if area_px >= last.area_px {
            return (last.pixel_error, last.flux_error);
        }
        let i = s.partition_point(|x| x.area_px <= area_px).max(1);
        let (a, b) = (s[i - 1], s[i]);
        let span = (b.area_px / a.area_px).ln();
        let w = if span > 0.0 {
            (area_px / a.area_px).ln() / span
        } else {
            0.0
        };
        (
            a.pixel_error + w * (b.pixel_error - a.pixel_error),
            a.flux_error + w * (b.flux_error - a.flux_error),
        )
    }

    /// The samples, by increasing area.
    pub fn samples(&self) -> &[Sample] {
        &self.samples
    }
}

/// Least-squares line y = a + b x through (area, seconds) with a, b ≥ 0.
fn fit_line(samples: &[Sample]) -> (f64, f64) {
    let n = samples.len() as f64;
    if samples.is_empty() {
        return (0.0, 0.0);
    }
    let mean_t = samples.iter().map(|s| s.seconds).sum::<f64>() / n;
    let mean_x = samples.iter().map(|s| s.area_px).sum::<f64>() / n;
    let sxx: f64 = samples.iter().map(|s| (s.area_px - mean_x).powi(2)).sum();
    let sxt: f64 = samples
        .iter()
        .map(|s| (s.area_px - mean_x) * (s.seconds - mean_t))
        .sum();
    let b = if sxx > 0.0 { sxt / sxx } else { 0.0 };
    let a = mean_t - b * mean_x;
    if b < 0.0 {
        (mean_t.max(0.0), 0.0)
    } else if a < 0.0 {
        let sx2: f64 = samples.iter().map(|s| s.area_px * s.area_px).sum();
        let st: f64 = samples.iter().map(|s| s.area_px * s.seconds).sum();
        (0.0, if sx2 > 0.0 { (st / sx2).max(0.0) } else { 0.0 })
    } else {
        (a, b)
    }
}

/// How rungs are chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Per frame, the finest rung that fits.
    Auto,
    /// Always this rung (reproducible runs).
    Fixed(usize),
}

/// One frame's decision.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Choice {
    pub rung: usize,
    /// The chosen rung's predicted render time with the load factor and
    /// the safety factor.
    pub predicted: Duration,
    /// False when not even the coarsest rung was predicted to fit.
    pub fits: bool,
    /// Predicted per-pixel error (p99) and disk-flux error against a
    /// converged render.
    pub pixel_error: f64,
    pub flux_error: f64,
    /// The rung's predicted pixel error is beyond the configured floor.
    pub degraded: bool,
}

/// The governor: the profiles, the mode, the floor and the recent load.
pub struct Governor {
    profiles: Vec<RungProfile>,
    mode: Mode,
    /// Largest predicted per-pixel error a frame may have before it counts
    /// as degraded.
    max_pixel_error: f64,
    ratios: VecDeque<f64>,
}

impl Governor {
    /// A governor over `profiles` (finest first).
    pub fn new(profiles: Vec<RungProfile>, mode: Mode, max_pixel_error: f64) -> Governor {
        Governor {
            profiles,
            mode,
            max_pixel_error,
            ratios: VecDeque::with_capacity(LOAD_WINDOW),
        }
    }

    /// The rungs' profiles, finest first.
    pub fn profiles(&self) -> &[RungProfile] {
        &self.profiles
    }

    /// The largest apparent area the pre-flight profiled, px².
    pub fn largest_profiled_area(&self) -> f64 {
        self.profiles
            .iter()
            .filter_map(|p| p.samples.last())
            .map(|s| s.area_px)
            .fold(0.0, f64::max)
    }

    /// Measured over predicted render time in recent frames (their
    /// [`LOAD_QUANTILE`]); 1 before any frame.
    pub fn load_factor(&self) -> f64 {
        if self.ratios.is_empty() {
            return 1.0;
        }
        // On the stack: this runs every frame.
        let mut buf = [0.0f64; LOAD_WINDOW];
        let r = &mut buf[..self.ratios.len()];
        r.iter_mut().zip(&self.ratios).for_each(|(a, &b)| *a = b);
        r.sort_unstable_by(f64::total_cmp);
        let k = ((r.len() - 1) as f64 * LOAD_QUANTILE).round() as usize;
        r[k].max(0.25)
    }

    /// The rung for a frame whose body covers `area_px` screen px², with
    /// `available` for its render.
    pub fn choose(&self, area_px: f64, available: Duration) -> Choice {
        let load = self.load_factor() * SAFETY;
        let predicted = |i: usize| {
            Duration::from_secs_f64(
                (self.profiles[i].predict_seconds(area_px) * load).clamp(0.0, 3600.0),
            )
        };
        let last = self.profiles.len() - 1;
        let (rung, fits) = match self.mode {
            Mode::Fixed(i) => {
                let i = i.min(last);
                (i, predicted(i) <= available)
            }
            Mode::Auto => match (0..=last).find(|&i| predicted(i) <= available) {
                Some(i) => (i, true),
                None => (last, false),
            },
        };
        let (pixel_error, flux_error) = self.profiles[rung].predict_error(area_px);
        Choice {
            rung,
            predicted: predicted(rung),
            fits,
            pixel_error,
            flux_error,
            degraded: pixel_error > self.max_pixel_error,
        }
    }

    /// A frame at `rung` and `area_px` took `took` to render: updates the
    /// load factor.
    pub fn record(&mut self, rung: usize, area_px: f64, took: Duration) {
        let Some(p) = self.profiles.get(rung) else {
            return;
        };
        let predicted = p.predict_seconds(area_px);
        if predicted > 0.0 {
            if self.ratios.len() == LOAD_WINDOW {
                self.ratios.pop_front();
            }
            self.ratios.push_back(took.as_secs_f64() / predicted);
        }
    }
}

/// What the governor chose for one frame, as logged.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FrameFidelity {
    /// The rung (0: the configured fidelity).
    pub rung: usize,
    /// Its predicted render time with the load and safety factors, s.
    pub predicted_render_s: f64,
    /// Predicted per-pixel error (p99) and disk-flux error against a
    /// converged render.
    pub predicted_pixel_error: f64,
    pub predicted_flux_error: f64,
    /// Not even the coarsest rung was predicted to fit the slot.
    pub unfit: bool,
    /// The rung's predicted pixel error is beyond
    /// `timing.governor_max_pixel_error`.
    pub degraded: bool,
}

impl From<Choice> for FrameFidelity {
    fn from(c: Choice) -> FrameFidelity {
        FrameFidelity {
            rung: c.rung,
            predicted_render_s: c.predicted.as_secs_f64(),
            predicted_pixel_error: c.pixel_error,
            predicted_flux_error: c.flux_error,
            unfit: !c.fits,
            degraded: c.degraded,
        }
    }
}

/// The governor's part of a run summary.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GovernorSummary {
    /// Frames per rung with their largest predicted errors.
    pub rungs: Vec<RungTally>,
    /// Frames whose rung's predicted pixel error exceeded the floor.
    pub degraded_frames: u64,
    /// Frames that did not fit their slot even at the coarsest rung.
    pub unfit_frames: u64,
}

impl GovernorSummary {
    /// An empty tally over rungs labelled `labels`.
    pub fn new(labels: Vec<String>) -> GovernorSummary {
        GovernorSummary {
            rungs: labels
                .into_iter()
                .enumerate()
                .map(|(rung, label)| RungTally {
                    rung,
                    label,
                    ..RungTally::default()
                })
                .collect(),
            degraded_frames: 0,
            unfit_frames: 0,
        }
    }

    /// Counts one frame.
    pub fn add(&mut self, f: &FrameFidelity) {
        if let Some(t) = self.rungs.get_mut(f.rung) {
            t.frames += 1;
            t.max_pixel_error = t.max_pixel_error.max(f.predicted_pixel_error);
            t.max_flux_error = t.max_flux_error.max(f.predicted_flux_error);
        }
        self.degraded_frames += u64::from(f.degraded);
        self.unfit_frames += u64::from(f.unfit);
    }
}

/// Per-rung frame counts and predicted errors of a run, for its summary.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RungTally {
    pub rung: usize,
    pub label: String,
    pub frames: u64,
    /// Largest predicted per-pixel (p99) and disk-flux error of its frames.
    pub max_pixel_error: f64,
    pub max_flux_error: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(area: f64, ms: f64, err: f64) -> Sample {
        Sample {
            area_px: area,
            seconds: ms * 1e-3,
            pixel_error: err,
            flux_error: err / 100.0,
        }
    }

    fn profiles() -> Vec<RungProfile> {
        let base = RenderSettings::default();
        let rungs: Vec<Rung> = ladder(&base, 1, 3)
            .into_iter()
            .filter(|r| r.settings.texture_samples == base.texture_samples || r.block > 1)
            .collect();
        // Costs 2 + area/1e4, 1.5 + area/2e4, 1 + area/4e4, 1 + area/9e4 ms.
        rungs
            .into_iter()
            .zip([
                (2.0, 1e4, 0.0),
                (1.5, 2e4, 1e-3),
                (1.0, 4e4, 0.05),
                (1.0, 9e4, 0.1),
            ])
            .map(|(r, (a, d, e))| {
                let s = [1e3, 1e4, 1e5, 4e5]
                    .iter()
                    .map(|&x| sample(x, a + x / d, e))
                    .collect();
                RungProfile::new(r, s)
            })
            .collect()
    }

    #[test]
    fn ladder_goes_from_the_configured_fidelity_to_coarser_blocks() {
        let base = RenderSettings::default();
        let l = ladder(&base, 1, 4);
        let blocks: Vec<usize> = l.iter().map(|r| r.block).collect();
        assert_eq!(blocks, [1, 1, 1, 2, 3, 4]);
        assert_eq!(l[0].settings, base);
        assert!(l[1].settings.pixel_tolerance > base.pixel_tolerance);
        assert_eq!(l[2].settings.texture_samples, 1);
        // A configured block of 2 with at most 4: blocks 2, 2, 2, 4.
        let l = ladder(&base, 2, 4);
        assert_eq!(l.iter().map(|r| r.block).collect::<Vec<_>>(), [2, 2, 2, 4]);
    }

    /// With relief: the configured block's rungs with it, then the same
    /// without, then the coarser blocks without.
    #[test]
    fn a_relief_ladder_drops_the_relief_before_the_blocks() {
        let base = RenderSettings::default();
        let plain = ladder(&base, 1, 3);
        let l = ladder_with_relief(&base, 1, 3);
        let blocks: Vec<usize> = l.iter().map(|r| r.block).collect();
        assert_eq!(blocks, [1, 1, 1, 1, 1, 1, 2, 3]);
        let relief: Vec<bool> = l.iter().map(|r| r.settings.relief).collect();
        assert_eq!(
            relief,
            [true, true, true, false, false, false, false, false]
        );
        for k in 0..3 {
            assert_eq!(l[k].settings, plain[k].settings);
            let mut off = plain[k].settings.clone();
            off.relief = false;
            assert_eq!(l[k + 3].settings, off);
            assert!(l[k + 3].label.ends_with("no relief"), "{}", l[k + 3].label);
        }
    }

    #[test]
    fn cost_model_recovers_a_line_and_stays_non_negative() {
        let p = &profiles()[0];
        // 2 ms + area / 1e4 ms, recovered exactly from exact samples.
        for area in [0.0, 5e3, 2e5] {
            let expected = (2.0 + area / 1e4) * 1e-3;
            assert!((p.predict_seconds(area) - expected).abs() < 1e-9);
        }
        // Decreasing times: a constant at their mean, never a negative slope.
        let r = ladder(&RenderSettings::default(), 1, 1).remove(0);
        let q = RungProfile::new(r, vec![sample(1e3, 5.0, 0.0), sample(1e5, 3.0, 0.0)]);
        assert!((q.predict_seconds(1e9) - 4e-3).abs() < 1e-12);
    }

    #[test]
    fn errors_interpolate_in_log_area_and_hold_at_the_ends() {
        let r = ladder(&RenderSettings::default(), 1, 1).remove(0);
        let p = RungProfile::new(r, vec![sample(1e2, 1.0, 0.01), sample(1e4, 1.0, 0.03)]);
        assert_eq!(p.predict_error(10.0).0, 0.01);
        assert_eq!(p.predict_error(1e6).0, 0.03);
        // Halfway in ln(area): 1e3.
        assert!((p.predict_error(1e3).0 - 0.02).abs() < 1e-12);
    }

    #[test]
    fn picks_the_finest_rung_that_fits_and_the_coarsest_when_none_does() {
        let g = Governor::new(profiles(), Mode::Auto, 0.06);
        let ms = |v: f64| Duration::from_secs_f64(v * 1e-3);
        // Area 1e5: predicted 12, 6.5, 3.5, 2.11 ms (× 1.2 safety).
        let c = g.choose(1e5, ms(16.0));
        assert_eq!((c.rung, c.fits, c.degraded), (0, true, false));
        let c = g.choose(1e5, ms(8.0));
        assert_eq!((c.rung, c.fits), (1, true));
        let c = g.choose(1e5, ms(3.0));
        assert_eq!((c.rung, c.fits, c.degraded), (3, true, true));
        let c = g.choose(1e5, ms(1.0));
        assert_eq!((c.rung, c.fits), (3, false));
        // A fixed rung is kept whatever the time.
        let f = Governor::new(profiles(), Mode::Fixed(2), 0.06);
        let c = f.choose(1e5, ms(1.0));
        assert_eq!((c.rung, c.fits), (2, false));
    }

    #[test]
    fn a_slower_machine_moves_the_choice_down() {
        let mut g = Governor::new(profiles(), Mode::Auto, 1.0);
        let ms = |v: f64| Duration::from_secs_f64(v * 1e-3);
        assert_eq!(g.choose(1e5, ms(16.0)).rung, 0);
        // Frames at rung 0 take twice their prediction (a busy machine).
        for _ in 0..10 {
            g.record(0, 1e5, ms(24.0));
        }
        assert!((g.load_factor() - 2.0).abs() < 1e-9);
        // 12 ms × 2 × 1.2 no longer fits 16 ms; 6.5 × 2.4 = 15.6 does.
        assert_eq!(g.choose(1e5, ms(16.0)).rung, 1);
    }
}
