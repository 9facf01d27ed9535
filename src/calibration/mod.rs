//! Screen calibration (`optistim calibrate`): the routines that measure the
//! facility's screen through its camera and spot meter and write the files
//! `optistim run` reads — the display LUT (radiometric), the flat field
//! and the geometry — and check them (verify). It comes after [`facility`](crate::facility) on the data
//! flow: it drives the screen through the
//! [`Display`](crate::facility::display::Display) trait and measures
//! through the [`instruments`](crate::instruments) traits only, so the real
//! facility and the simulated one run the same code.
//!
//! | module | owns |
//! |---|---|
//! | [`config`] | the `[calibrate]` section of the facility file |
//! | [`budget`] | the LUT's uncertainty budget (per level, k = 2) |
//! | [`checkpoint`] | the crash-safe JSONL log of measurements, `--resume` |
//! | [`dark`] | dark frames per exposure (bias + dark current), cached for a campaign |
//! | [`mismatch`] | camera-effective radiance and the spectral mismatch factor F |
//! | [`mismatch_levels`] | F per drive level from spectra measured at several levels, its interpolation and bound |
//! | [`radiometric`] | drive level → camera-effective radiance: the LUT CSV, report and plot |
//! | [`geometric`] | dot patterns → the geometry CSV (screen pixel → camera direction) |
//! | [`focal`] | the collimator focal length the geometry implies near the axis |
//! | [`flat`] | the per-pixel flat-field gain TIFF and its uniformity |
//! | [`responsivity`] | the camera's absolute responsivity file (verify's independent scale) |
//! | [`verify`] | target radiances through the real conversion path, achieved/target, drift |
//!
//! The quantity and the methods are described in docs/CALIBRATION.md.

pub mod budget;
pub mod checkpoint;
pub mod config;
pub mod dark;
pub mod flat;
pub mod focal;
pub mod geometric;
pub mod mismatch;
pub mod mismatch_levels;
pub mod radiometric;
pub mod responsivity;
pub mod verify;

use std::time::Duration;

use crate::error::{Error, Result};
use crate::facility::display::Display;
use crate::facility::lut::encode_grey;
use crate::instruments::{Camera, CameraFrame, CaptureRequest, SpotMeter, SpotReading};

/// The instruments of a campaign, behind their traits.
pub struct Instruments<'a> {
    pub display: &'a mut dyn Display,
    pub camera: &'a mut dyn Camera,
    pub meter: Option<&'a mut dyn SpotMeter>,
    /// The campaign's dark frames, per exposure.
    pub darks: &'a mut dark::DarkBank,
    /// Waits `seconds` after showing a patch. Real campaigns sleep; tests
    /// and the simulated facility pass a virtual clock.
    pub wait: &'a mut dyn FnMut(f64),
}

/// Real waiting (for real instruments).
pub fn sleep(seconds: f64) {
    if seconds > 0.0 && seconds.is_finite() {
        std::thread::sleep(Duration::from_secs_f64(seconds));
    }
}

/// Shows a uniform patch of drive `level` over the whole screen.
pub fn show_level(display: &mut dyn Display, level: u32, bits: u32) -> Result<()> {
    let (w, h) = display.size();
    let frame = vec![encode_grey(level, bits); w * h];
    display.present(&frame)?;
    Ok(())
}

/// A rectangle of camera pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Rect {
    pub x: usize,
    pub y: usize,
    pub w: usize,
    pub h: usize,
}

/// `w×h at (x, y)`, as written in reports and file headers.
impl std::fmt::Display for Rect {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}×{} at ({}, {})", self.w, self.h, self.x, self.y)
    }
}

impl Rect {
    /// The rectangle of fractional `[x, y, w, h]` in a `width × height`
    /// frame (at least one pixel).
    pub fn from_fractions(f: [f64; 4], width: usize, height: usize) -> Rect {
        let x = ((f[0] * width as f64).floor() as usize).min(width.saturating_sub(1));
        let y = ((f[1] * height as f64).floor() as usize).min(height.saturating_sub(1));
        // `max(1)`: an empty frame gives a 1-pixel rect that
        // `region_stats` then refuses, instead of a panic here.
        let w = ((f[2] * width as f64).round() as usize).clamp(1, (width - x).max(1));
        let h = ((f[3] * height as f64).round() as usize).clamp(1, (height - y).max(1));
        Rect { x, y, w, h }
    }
}

/// Statistics of a frame region after dark subtraction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RegionStats {
    /// Mean DN (dark subtracted).
    pub mean: f64,
    /// Standard deviation of the pixels, DN.
    pub std: f64,
    /// Largest raw DN in the region.
    pub max_raw: f64,
    /// Pixels of the whole frame at or above saturation.
    pub saturated: usize,
    /// Pixels of the region at exactly `max_raw` (a plateau means clipping,
    /// e.g. at a full well below the configured saturation).
    pub at_max: usize,
    pub pixels: usize,
}

/// Mean and scatter of `rect` in `frame`, `dark` (DN, same size) subtracted.
pub fn region_stats(frame: &CameraFrame, dark: Option<&[f32]>, rect: Rect) -> Result<RegionStats> {
    if frame.width * frame.height != frame.data.len()
        || rect.x + rect.w > frame.width
        || rect.y + rect.h > frame.height
    {
        return Err(Error::Other(format!(
            "camera frame {}×{} does not hold the region {}+{}×{}+{}",
            frame.width, frame.height, rect.w, rect.x, rect.h, rect.y
        )));
    }
    if let Some(d) = dark {
        if d.len() != frame.data.len() {
            return Err(Error::Other(format!(
                "dark frame has {} pixels, the camera frame {}",
                d.len(),
                frame.data.len()
            )));
        }
    }
    let saturated = frame
        .data
        .iter()
        .filter(|&&v| v >= frame.saturation_dn)
        .count();
    let (mut s, mut s2, mut max_raw) = (0.0, 0.0, f64::NEG_INFINITY);
    for y in rect.y..rect.y + rect.h {
        for x in rect.x..rect.x + rect.w {
            let i = y * frame.width + x;
            let raw = frame.data[i] as f64;
            max_raw = max_raw.max(raw);
            let v = raw - dark.map_or(0.0, |d| d[i] as f64);
            s += v;
            s2 += v * v;
        }
    }
    let mut at_max = 0;
    for y in rect.y..rect.y + rect.h {
        let row = &frame.data[y * frame.width + rect.x..y * frame.width + rect.x + rect.w];
        at_max += row.iter().filter(|&&v| v as f64 == max_raw).count();
    }
    let n = (rect.w * rect.h) as f64;
    let mean = s / n;
    let std = (s2 / n - mean * mean).max(0.0).sqrt();
    if !mean.is_finite() {
        return Err(Error::Other("camera frame holds non-finite values".into()));
    }
    Ok(RegionStats {
        mean,
        std,
        max_raw,
        saturated,
        at_max,
        pixels: rect.w * rect.h,
    })
}

/// A frame taken with an exposure chosen so that the region's brightest
/// pixel sits near `fill` of saturation, from the ladder `base × 2^k`
/// within `[min, max]` (so darks are taken once per exposure and reused):
/// starting at `base`, halved while anything in the region saturates
/// (reaches `saturation_dn`, or more than 1 % of the region sits at one
/// bright value: clipped below it), lengthened by powers of 2 (up to the
/// longest ladder exposure) while the region is below a quarter of the aim.
/// The accepted frame is dark-corrected at its own exposure.
pub struct AutoExposure {
    pub fill: f64,
    /// The ladder's base exposure (`calibrate.camera.exposure`), s.
    pub base: f64,
    pub min: f64,
    pub max: f64,
}

/// One exposure-ranged capture.
pub struct Ranged {
    pub frame: CameraFrame,
    /// Region statistics, dark subtracted.
    pub stats: RegionStats,
    /// The dark subtracted (mean DN per pixel at the frame's exposure).
    pub dark: Option<std::sync::Arc<Vec<f32>>>,
}

/// Most halvings below the base exposure the ladder holds.
const LADDER_DOWN: i32 = 20;

impl AutoExposure {
    /// The ranging of `cfg`: base `calibrate.camera.exposure`, at most
    /// `max_exposure`.
    pub fn of(cfg: &config::CalibrateConfig) -> AutoExposure {
        AutoExposure {
            fill: cfg.target_fill,
            base: cfg.camera.exposure,
            min: 1e-6_f64.min(cfg.camera.exposure),
            max: cfg.max_exposure,
        }
    }

    /// Every exposure of the ladder, shortest first.
    pub fn ladder(&self) -> Vec<f64> {
        (-LADDER_DOWN..=30)
            .map(|k| self.base * 2f64.powi(k))
            .filter(|&t| t >= self.min * (1.0 - 1e-9) && t <= self.max * (1.0 + 1e-9))
            .collect()
    }

    /// The longest ladder exposure.
    pub fn longest(&self) -> f64 {
        self.ladder().last().copied().unwrap_or(self.base)
    }

    /// Captures `pattern` (drive `level`, for errors) with auto-ranging
    /// and dark-corrects the accepted frame from `darks`.
    pub fn capture(
        &self,
        camera: &mut dyn Camera,
        darks: &mut dark::DarkBank,
        pattern: &str,
        level: u32,
        rect: Rect,
    ) -> Result<Ranged> {
        let ladder = self.ladder();
        let mut k = ladder
            .iter()
            .position(|&t| (t - self.base).abs() <= 1e-9 * self.base)
            .unwrap_or(ladder.len() - 1);
        for attempt in 0..48 {
            let request = CaptureRequest::light(
                if attempt == 0 {
                    pattern.to_string()
                } else {
                    format!("{pattern}_x{attempt}")
                },
                ladder[k],
            );
            let frame = camera.capture(&request)?;
            let stats = region_stats(&frame, None, rect)?;
            let sat = frame.saturation_dn as f64;
            // More than 1 % of the region at one bright value is a clipped
            // plateau (a full well below `saturation_dn`), not a signal.
            let plateau = stats.max_raw > 0.25 * sat && stats.at_max > (stats.pixels / 100).max(3);
            if stats.max_raw >= sat || plateau {
                if k == 0 {
                    return Err(Error::Other(format!(
                        "pattern `{pattern}` (drive level {level}): camera saturated in the \
                         measured region ({} pixels of the frame at ≥ {sat} DN) even at the \
                         shortest exposure {} s",
                        stats.saturated, ladder[0]
                    )));
                }
                k -= 1;
                continue;
            }
            let aim = self.fill * sat;
            let peak = stats.max_raw.max(1.0);
            if peak < aim / 4.0 && k + 1 < ladder.len() {
                // Lengthen toward the aim in one step (a power of 2, ≤ 64).
                let steps = ((aim / peak).min(64.0).log2().floor() as usize).max(1);
                k = (k + steps).min(ladder.len() - 1);
                continue;
            }
            let dark = darks.dark_for(camera, &frame)?;
            let stats = region_stats(&frame, dark.as_deref().map(|d| d.as_slice()), rect)?;
            return Ok(Ranged { frame, stats, dark });
        }
        Err(Error::Other(format!(
            "pattern `{pattern}` (drive level {level}): exposure auto-ranging did not settle"
        )))
    }
}

/// Reads the meter if there is one; errors name the pattern and level.
pub fn read_meter(
    meter: &mut Option<&mut dyn SpotMeter>,
    pattern: &str,
    level: u32,
) -> Result<Option<SpotReading>> {
    match meter {
        None => Ok(None),
        Some(m) => m
            .measure()
            .map(Some)
            .map_err(|e| Error::Other(format!("pattern `{pattern}` (drive level {level}): {e}"))),
    }
}

/// Deterministic permutation of `items` (Fisher–Yates driven by
/// SplitMix64 from `seed`): the measurement order of a campaign.
pub fn shuffle<T>(items: &mut [T], seed: u64) {
    let mut state = seed;
    let mut next = || {
        state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    };
    for i in (1..items.len()).rev() {
        let j = (next() % (i as u64 + 1)) as usize;
        items.swap(i, j);
    }
}

/// A progress bar on stderr (level, ETA, last reading), hidden when
/// stderr is not a terminal.
pub fn progress(total: u64, what: &str) -> indicatif::ProgressBar {
    crate::progress::bar(total, what)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shuffle_is_a_seeded_permutation() {
        let mut a: Vec<u32> = (0..50).collect();
        let mut b = a.clone();
        shuffle(&mut a, 7);
        shuffle(&mut b, 7);
        assert_eq!(a, b);
        assert_ne!(a, (0..50).collect::<Vec<_>>());
        let mut s = a.clone();
        s.sort();
        assert_eq!(s, (0..50).collect::<Vec<_>>());
    }

    #[test]
    fn region_stats_against_hand_values() {
        let frame = CameraFrame {
            width: 4,
            height: 3,
            data: vec![
                1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0, 4095.0,
            ],
            exposure_s: 1.0,
            saturation_dn: 4095.0,
        };
        let dark = vec![1.0f32; 12];
        let r = Rect {
            x: 1,
            y: 1,
            w: 2,
            h: 2,
        };
        let s = region_stats(&frame, Some(&dark), r).unwrap();
        // Pixels 6, 7, 10, 11 minus 1: mean 7.5, population std 2.0616.
        assert!((s.mean - 7.5).abs() < 1e-12);
        assert!((s.std - (4.25f64).sqrt()).abs() < 1e-12);
        assert_eq!(s.saturated, 1);
        assert_eq!(s.max_raw, 11.0);
        assert!(region_stats(
            &frame,
            None,
            Rect {
                x: 3,
                y: 0,
                w: 2,
                h: 1
            }
        )
        .is_err());
    }
}
