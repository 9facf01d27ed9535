//! Geometric calibration of the screen seen through the collimator: dot
//! patterns at known screen positions are shown and imaged by the facility
//! camera, the dots detected to sub-pixel accuracy and identified, turned
//! into camera-frame directions with the camera's intrinsics
//! ([`CameraIntrinsics`]), and a smooth
//! map screen (u, v) → (tan_x, tan_y) fitted to them; the result is the
//! `calibration.geometry` CSV that `run` reads
//! ([`GeometryCalibration`](crate::facility::geometry::GeometryCalibration)),
//! a JSON report and a residual plot. Method and accuracy: docs/GEOMETRIC.md.
//!
//! | file | owns |
//! |---|---|
//! | [`patterns`] | the dot grid, the anchor dots, drawing them into frames |
//! | [`dots`] | detection and sub-pixel centroids in a camera frame |
//! | [`matching`] | which detection is which grid dot |
//! | [`fit`] | the model (homography + radial distortion + correction) and its robust fit |
//! | [`output`] | the geometry CSV, the JSON report, the quiver plot |

pub mod dots;
pub mod fit;
pub mod matching;
pub mod output;
pub mod patterns;

use std::path::{Path, PathBuf};

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::facility::display::Display;
use crate::instruments::intrinsics::CameraIntrinsics;
use crate::instruments::{Camera, CameraFrame, CaptureRequest};
use dots::{Blob, Signal};
use fit::{apply_homography, normalise, Fit, FitSettings};
use matching::AnchorSighting;
use patterns::{DotGrid, DotShape};

/// `[calibrate.geometric]`: the dot patterns, the camera settings and the
/// fit. Every key has a default.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct GeometricConfig {
    /// Distance between neighbouring dots, screen pixels (8–1024).
    #[serde(default = "default_spacing")]
    pub spacing_px: usize,
    /// Dot radius: the Gaussian's σ or the disc's radius, screen pixels
    /// (0.5 up to spacing/8 for Gaussians, spacing/4 for discs, so dots
    /// never touch).
    #[serde(default = "default_radius")]
    pub radius_px: f64,
    /// `"gaussian"` or `"disc"`.
    #[serde(default = "default_shape")]
    pub shape: DotShape,
    /// Peak drive level of the dots (1 to 2^bits − 1).
    #[serde(default = "default_level")]
    pub level: u32,
    /// Drive bits of the frames, 8 or 10 (as `drive.bits`).
    #[serde(default = "default_bits")]
    pub bits: u32,
    /// Camera exposure, s (0 < exposure ≤ 100).
    #[serde(default = "default_exposure")]
    pub exposure: f64,
    /// Wait after showing a pattern before capturing it, s (0–60): the
    /// display's latency and the panel's response (the simulated facility
    /// needs none).
    #[serde(default = "default_settle")]
    pub settle: f64,
    /// Camera intrinsics file (docs/INSTRUMENTS.md; OpenCV K and
    /// distortion). Absent: the caller passes the intrinsics
    /// ([`calibrate_geometric_with`]; the CLI takes
    /// `calibrate.camera.intrinsics`).
    #[serde(default)]
    pub intrinsics: Option<PathBuf>,
    /// Match radius as a fraction of the predicted distance between
    /// neighbouring dots (0.05–0.5).
    #[serde(default = "default_gate")]
    pub gate: f64,
    /// Most predict–match–fit rounds over the whole grid (1–50), after
    /// those that grow the matched region from the anchors; stops earlier
    /// once the matches no longer change.
    #[serde(default = "default_iterations")]
    pub iterations: usize,
    /// Outlier rejection: residuals beyond this many per-axis RMS (2–10).
    #[serde(default = "default_clip")]
    pub clip_sigma: f64,
    /// Total degree of the Legendre correction fitted to the parametric
    /// model's residuals (0: none; at most 6).
    #[serde(default = "default_correction")]
    pub correction_degree: usize,
    /// Fewest matched dots accepted for a fit (at least 12).
    #[serde(default = "default_min_dots")]
    pub min_dots: usize,
    /// Spacing of the written lattice, screen pixels (4–256); the edges of
    /// the screen are always nodes.
    #[serde(default = "default_lattice")]
    pub lattice_px: usize,
    /// The geometry CSV, relative to the output directory unless absolute.
    #[serde(default = "default_output")]
    pub output: PathBuf,
}

fn default_spacing() -> usize {
    64
}
fn default_radius() -> f64 {
    4.0
}
fn default_shape() -> DotShape {
    DotShape::Gaussian
}
fn default_level() -> u32 {
    255
}
fn default_bits() -> u32 {
    8
}
fn default_exposure() -> f64 {
    0.01
}
fn default_settle() -> f64 {
    0.1
}
fn default_gate() -> f64 {
    0.3
}
fn default_iterations() -> usize {
    5
}
fn default_clip() -> f64 {
    3.5
}
fn default_correction() -> usize {
    3
}
fn default_min_dots() -> usize {
    20
}
fn default_lattice() -> usize {
    32
}
fn default_output() -> PathBuf {
    PathBuf::from("geometry.csv")
}

impl GeometricConfig {
    /// The defaults with this intrinsics file.
    pub fn with_intrinsics(intrinsics: impl Into<PathBuf>) -> GeometricConfig {
        GeometricConfig {
            intrinsics: Some(intrinsics.into()),
            ..GeometricConfig::default()
        }
    }
}

impl Default for GeometricConfig {
    fn default() -> GeometricConfig {
        GeometricConfig {
            spacing_px: default_spacing(),
            radius_px: default_radius(),
            shape: default_shape(),
            level: default_level(),
            bits: default_bits(),
            exposure: default_exposure(),
            settle: default_settle(),
            intrinsics: None,
            gate: default_gate(),
            iterations: default_iterations(),
            clip_sigma: default_clip(),
            correction_degree: default_correction(),
            min_dots: default_min_dots(),
            lattice_px: default_lattice(),
            output: default_output(),
        }
    }
}

impl GeometricConfig {
    /// Makes a relative `intrinsics` path relative to `dir` (the directory
    /// of the TOML file it came from).
    pub fn resolve_paths(&mut self, dir: &Path) {
        if let Some(p) = &mut self.intrinsics {
            if p.is_relative() {
                *p = dir.join(&*p);
            }
        }
    }

    /// Range checks; errors name the key (`calibrate.geometric.<key>`).
    pub fn validate(&self) -> Result<()> {
        let bad =
            |key: &str, msg: String| Err(Error::invalid(format!("calibrate.geometric.{key}"), msg));
        if !(8..=1024).contains(&self.spacing_px) {
            return bad(
                "spacing_px",
                format!("{} is outside 8–1024", self.spacing_px),
            );
        }
        let max_radius = self.spacing_px as f64
            / match self.shape {
                DotShape::Gaussian => 8.0,
                DotShape::Disc => 4.0,
            };
        if !(self.radius_px >= 0.5 && self.radius_px <= max_radius) {
            return bad(
                "radius_px",
                format!(
                    "{} is outside 0.5–{max_radius} (dots must not touch)",
                    self.radius_px
                ),
            );
        }
        if !(self.bits == 8 || self.bits == 10) {
            return bad("bits", format!("{} is neither 8 nor 10", self.bits));
        }
        if !(1..(1u32 << self.bits)).contains(&self.level) {
            return bad(
                "level",
                format!("{} is outside 1–{}", self.level, (1u32 << self.bits) - 1),
            );
        }
        if !(self.exposure > 0.0 && self.exposure <= 100.0) {
            return bad(
                "exposure",
                format!("{} s is outside (0, 100]", self.exposure),
            );
        }
        if !(self.settle >= 0.0 && self.settle <= 60.0) {
            return bad("settle", format!("{} s is outside 0–60", self.settle));
        }
        if !(self.gate >= 0.05 && self.gate <= 0.5) {
            return bad("gate", format!("{} is outside 0.05–0.5", self.gate));
        }
        if !(1..=50).contains(&self.iterations) {
            return bad("iterations", format!("{} is outside 1–50", self.iterations));
        }
        if !(self.clip_sigma >= 2.0 && self.clip_sigma <= 10.0) {
            return bad("clip_sigma", format!("{} is outside 2–10", self.clip_sigma));
        }
        if self.correction_degree > 6 {
            return bad(
                "correction_degree",
                format!("{} is above 6", self.correction_degree),
            );
        }
        if self.min_dots < 12 {
            return bad("min_dots", format!("{} is below 12", self.min_dots));
        }
        if !(4..=256).contains(&self.lattice_px) {
            return bad(
                "lattice_px",
                format!("{} is outside 4–256", self.lattice_px),
            );
        }
        if self.output.as_os_str().is_empty() {
            return bad("output", "empty path".into());
        }
        Ok(())
    }

    /// The dot grid of a `screen`.
    pub fn grid(&self, screen: (usize, usize)) -> DotGrid {
        DotGrid::new(
            screen,
            self.spacing_px,
            self.radius_px,
            self.shape,
            self.level,
            self.bits,
        )
    }
}

/// The frames of one geometric calibration.
#[derive(Debug, Clone)]
pub struct Captures {
    /// The black screen.
    pub dark: CameraFrame,
    /// The full dot grid.
    pub grid: CameraFrame,
    /// Each anchor dot alone: its grid index and its frame.
    pub anchors: Vec<(usize, CameraFrame)>,
}

/// Name of the pattern of anchor `k` (the camera request and errors use it).
pub fn anchor_pattern(k: usize) -> String {
    format!("geometric_anchor_{k}")
}

/// Pattern name of the black frame.
pub const DARK_PATTERN: &str = "geometric_dark";
/// Pattern name of the full grid.
pub const GRID_PATTERN: &str = "geometric_grid";

/// A dot used in the fit (or rejected by it).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DotResidual {
    /// Screen position of the dot, pixels.
    pub u_px: f64,
    pub v_px: f64,
    /// Measured centroid, camera pixels.
    pub x_px: f64,
    pub y_px: f64,
    /// Measured minus modelled position in the camera, pixels.
    pub dx_px: f64,
    pub dy_px: f64,
    /// Angle between the measured and modelled directions, arcsec.
    pub arcsec: f64,
    /// Kept by the outlier rejection.
    pub used: bool,
}

/// What the detection, identification and fit found.
#[derive(Debug, Clone)]
pub struct Solution {
    pub fit: Fit,
    pub dots: Vec<DotResidual>,
    /// Dots in the grid.
    pub dots_shown: usize,
    /// Blobs found in the grid frame, and those rejected by size or shape.
    pub blobs_detected: usize,
    pub blobs_rejected: usize,
    /// Anchors identified, of those shown.
    pub anchors_identified: usize,
    pub anchors_shown: usize,
    /// Predict–match–fit rounds run.
    pub iterations: usize,
}

impl Solution {
    fn used(&self) -> impl Iterator<Item = &DotResidual> {
        self.dots.iter().filter(|d| d.used)
    }

    /// RMS and max of the used dots' residuals, camera pixels.
    pub fn residual_px(&self) -> (f64, f64) {
        rms_max(self.used().map(|d| d.dx_px.hypot(d.dy_px)))
    }

    /// RMS and max of the used dots' residuals, arcseconds.
    pub fn residual_arcsec(&self) -> (f64, f64) {
        rms_max(self.used().map(|d| d.arcsec))
    }
}

fn rms_max(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut n, mut ss, mut max) = (0usize, 0.0, 0.0f64);
    for v in values {
        n += 1;
        ss += v * v;
        max = max.max(v);
    }
    ((ss / n.max(1) as f64).sqrt(), max)
}

/// Angle between the directions (t, 1) and (m, 1), arcseconds.
fn angle_arcsec(t: [f64; 2], m: [f64; 2]) -> f64 {
    let a = [t[0], t[1], 1.0];
    let b = [m[0], m[1], 1.0];
    let cross = [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ];
    let dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let sin = (cross[0].powi(2) + cross[1].powi(2) + cross[2].powi(2)).sqrt();
    sin.atan2(dot).to_degrees() * 3600.0
}

/// Dark-subtracted signal of `frame`, checked against the dark's size.
fn signal_of(frame: &CameraFrame, dark: &CameraFrame, pattern: &str) -> Result<Vec<f32>> {
    if (frame.width, frame.height) != (dark.width, dark.height)
        || frame.data.len() != frame.width * frame.height
        || dark.data.len() != dark.width * dark.height
    {
        return Err(Error::invalid(
            "camera frame",
            format!(
                "pattern {pattern}: {}×{} frame with {} values, the dark frame is {}×{}",
                frame.width,
                frame.height,
                frame.data.len(),
                dark.width,
                dark.height
            ),
        ));
    }
    Ok(frame
        .data
        .iter()
        .zip(&dark.data)
        .map(|(a, b)| a - b)
        .collect())
}

/// Plausible blobs of a pattern's frame (all blobs when `typical_area` is
/// None, which the grid frame sets), with the count found and rejected.
/// Saturated dots are an error naming the pattern.
fn dots_of(
    frame: &CameraFrame,
    dark: &CameraFrame,
    pattern: &str,
    typical_area: Option<f64>,
) -> Result<(Vec<Blob>, usize, usize, f64)> {
    let data = signal_of(frame, dark, pattern)?;
    let signal = Signal {
        width: frame.width,
        height: frame.height,
        data: &data,
    };
    let blobs = dots::detect(&signal, &frame.data, frame.saturation_dn)
        .map_err(|e| Error::Other(format!("pattern {pattern}: {e}")))?;
    let found = blobs.len();
    let typical = typical_area.unwrap_or_else(|| dots::typical_area(&blobs));
    let (kept, rejected) = dots::plausible(blobs, typical);
    let saturated: usize = kept.iter().map(|b| b.saturated).sum();
    if saturated > 0 {
        return Err(Error::Other(format!(
            "pattern {pattern}: {saturated} saturated camera pixels in the dots \
             (lower calibrate.geometric.exposure or level)"
        )));
    }
    Ok((kept, found, rejected, typical))
}

/// The frames must have the size the intrinsics were measured at.
fn check_camera_size(captures: &Captures, intrinsics: &CameraIntrinsics) -> Result<()> {
    let f = &captures.dark;
    if (f.width, f.height) != (intrinsics.width, intrinsics.height) {
        return Err(Error::invalid(
            "camera frame",
            format!(
                "pattern {DARK_PATTERN}: {}×{} frame, the intrinsics are for a {}×{} camera",
                f.width, f.height, intrinsics.width, intrinsics.height
            ),
        ));
    }
    Ok(())
}

/// Detects, identifies and fits: the calibration from its frames alone.
pub fn solve(
    grid: &DotGrid,
    captures: &Captures,
    intrinsics: &CameraIntrinsics,
    cfg: &GeometricConfig,
) -> Result<Solution> {
    check_camera_size(captures, intrinsics)?;
    let direction = |p: [f64; 2]| {
        intrinsics
            .pixel_to_direction(p[0], p[1])
            .map(|d| [d.x / d.z, d.y / d.z])
    };
    let (blobs, found, rejected, typical) =
        dots_of(&captures.grid, &captures.dark, GRID_PATTERN, None)?;
    // Directions of the grid detections (blobs where the intrinsics do not
    // invert are outside the calibrated field and dropped).
    let seen: Vec<([f64; 2], [f64; 2])> = blobs
        .iter()
        .filter_map(|b| direction(b.centre).map(|t| (b.centre, t)))
        .collect();
    let tans: Vec<[f64; 2]> = seen.iter().map(|s| s.1).collect();
    let sightings = anchor_sightings(captures, typical, &direction)?;
    let h = matching::anchor_homography(grid, &sightings, captures.anchors.len(), cfg.gate)?;
    let screen = grid.screen;
    let first_guess = Box::new(move |u, v| apply_homography(&h, normalise(screen, u, v)));
    let settings = FitSettings {
        clip_sigma: cfg.clip_sigma,
        // 0.001 camera px.
        floor: 1e-3 / intrinsics.camera_matrix[0][0].max(intrinsics.camera_matrix[1][1]),
        correction_degree: cfg.correction_degree,
    };
    let too_few = |pairs: usize| {
        Error::Other(format!(
            "geometric calibration: too few dots: {pairs} of {} identified, min_dots = {} \
             ({found} blobs found, {rejected} rejected by size or shape): check the \
             camera's view of the screen, its focus and exposure",
            grid.centres.len(),
            cfg.min_dots
        ))
    };
    let (fit, pairs, iterations) =
        match_and_fit(grid, &tans, first_guess, cfg, &settings, too_few)?;
    let dots = residuals(grid, &seen, &fit, &pairs, intrinsics);
    Ok(Solution {
        fit,
        dots,
        dots_shown: grid.centres.len(),
        blobs_detected: found,
        blobs_rejected: rejected,
        anchors_identified: sightings.len(),
        anchors_shown: captures.anchors.len(),
        iterations,
    })
}

/// The anchors seen: in each anchor frame, one clear dot (the brightest,
/// at least twice the next), as a camera direction; frames without one
/// are not trusted.
fn anchor_sightings(
    captures: &Captures,
    typical: f64,
    direction: &dyn Fn([f64; 2]) -> Option<[f64; 2]>,
) -> Result<Vec<AnchorSighting>> {
    let mut sightings = Vec::new();
    for (k, (dot, frame)) in captures.anchors.iter().enumerate() {
        let pattern = anchor_pattern(k);
        let (mut b, _, _, _) = dots_of(frame, &captures.dark, &pattern, Some(typical))?;
        b.sort_by(|x, y| y.flux.total_cmp(&x.flux));
        let clear = match b.as_slice() {
            [] => None,
            [one] => Some(one),
            [first, second, ..] => (second.flux < 0.5 * first.flux).then_some(first),
        };
        if let Some(t) = clear.and_then(|blob| direction(blob.centre)) {
            sightings.push(AnchorSighting { dot: *dot, tan: t });
        }
    }
    Ok(sightings)
}

/// A fit, its (dot, detection) pairs and the rounds it took.
type Rounds = (Fit, Vec<(usize, usize)>, usize);

/// Predict, match and fit in rounds over a growing region: a disc about
/// the central anchor, twice the anchors' extent at first, doubling each
/// round until it holds every dot; then up to `iterations` rounds until
/// the matches are stable. Fewer than `min_dots` pairs with every dot in
/// the region is the error `too_few` makes of their count.
fn match_and_fit(
    grid: &DotGrid,
    tans: &[[f64; 2]],
    first_guess: Box<dyn Fn(f64, f64) -> [f64; 2]>,
    cfg: &GeometricConfig,
    settings: &FitSettings,
    too_few: impl Fn(usize) -> Error,
) -> Result<Rounds> {
    let mut predict = first_guess;
    let centre = grid.centres[grid.anchors()[grid.anchors().len() / 2]];
    let dist = |c: &[f64; 2]| (c[0] - centre[0]).hypot(c[1] - centre[1]);
    let full = grid.centres.iter().map(dist).fold(0.0, f64::max);
    let mut radius = 2.0 * grid.spacing * grid.anchor_step() as f64 * std::f64::consts::SQRT_2;
    let mut previous: Option<Vec<Option<usize>>> = None;
    let mut result = None;
    let (mut rounds, mut covered_rounds) = (0, 0);
    while covered_rounds < cfg.iterations {
        rounds += 1;
        let covered = radius >= full;
        let active: Vec<bool> = grid.centres.iter().map(|c| dist(c) <= radius).collect();
        radius *= 2.0;
        let matches = matching::match_dots(grid, &predict, tans, cfg.gate, &active);
        let pairs: Vec<(usize, usize)> = matches
            .iter()
            .enumerate()
            .filter_map(|(dot, m)| m.map(|k| (dot, k)))
            .collect();
        if pairs.len() < cfg.min_dots {
            if !covered {
                continue;
            }
            return Err(too_few(pairs.len()));
        }
        let uv: Vec<[f64; 2]> = pairs.iter().map(|&(d, _)| grid.centres[d]).collect();
        let tan: Vec<[f64; 2]> = pairs.iter().map(|&(_, k)| tans[k]).collect();
        let f = fit::fit(grid.screen, &uv, &tan, settings)?;
        let model = f.model.clone();
        predict = Box::new(move |u, v| model.direction(u, v));
        let stable = covered && previous.as_ref() == Some(&matches);
        previous = covered.then_some(matches);
        result = Some((f, pairs));
        if covered {
            covered_rounds += 1;
        }
        if stable {
            break;
        }
    }
    let (fit, pairs) = result.expect("at least one round");
    Ok((fit, pairs, rounds))
}

/// Each identified dot against the fitted model: where the camera saw it
/// and where the model puts it, in camera pixels and arcseconds.
fn residuals(
    grid: &DotGrid,
    seen: &[([f64; 2], [f64; 2])],
    fit: &Fit,
    pairs: &[(usize, usize)],
    intrinsics: &CameraIntrinsics,
) -> Vec<DotResidual> {
    pairs
        .iter()
        .enumerate()
        .map(|(i, &(dot, k))| {
            let [u, v] = grid.centres[dot];
            let (pixel, t) = seen[k];
            let m = fit.model.direction(u, v);
            let p = intrinsics
                .direction_to_pixel(DVec3::new(m[0], m[1], 1.0))
                .map_or([f64::NAN; 2], |p| [p.0, p.1]);
            DotResidual {
                u_px: u,
                v_px: v,
                x_px: pixel[0],
                y_px: pixel[1],
                dx_px: pixel[0] - p[0],
                dy_px: pixel[1] - p[1],
                arcsec: angle_arcsec(t, m),
                used: fit.inlier[i],
            }
        })
        .collect()
}

/// What [`calibrate_geometric`] did and measured (also its JSON report).
#[derive(Debug, Clone, Serialize)]
pub struct GeometricReport {
    pub date_utc: String,
    pub software: String,
    pub camera: String,
    /// The intrinsics file (None: passed by the caller).
    pub intrinsics: Option<PathBuf>,
    pub screen: [usize; 2],
    pub config: GeometricConfig,
    /// Files written.
    pub geometry_csv: PathBuf,
    pub report_json: PathBuf,
    /// The residual quiver plot.
    pub quiver_png: Option<PathBuf>,
    pub dots_shown: usize,
    pub blobs_detected: usize,
    pub blobs_rejected: usize,
    pub dots_matched: usize,
    pub dots_used: usize,
    /// Matched dots rejected as outliers by the fit.
    pub dots_rejected: usize,
    pub anchors_identified: usize,
    pub anchors_shown: usize,
    pub iterations: usize,
    pub rms_px: f64,
    pub max_px: f64,
    pub rms_arcsec: f64,
    pub max_arcsec: f64,
    pub model: fit::ScreenModel,
    /// Radial distortion of the model in plain tangent units.
    pub radial_k1_k2: [f64; 2],
    pub dots: Vec<DotResidual>,
}

/// Shows `frame`, waits `settle`, and captures `pattern`.
fn capture(
    display: &mut dyn Display,
    camera: &mut dyn Camera,
    frame: &[u32],
    pattern: &str,
    cfg: &GeometricConfig,
) -> Result<CameraFrame> {
    display
        .present(frame)
        .map_err(|e| Error::Other(format!("pattern {pattern}: display: {e}")))?;
    if cfg.settle > 0.0 {
        std::thread::sleep(std::time::Duration::from_secs_f64(cfg.settle));
    }
    camera.capture(&CaptureRequest {
        pattern: pattern.to_string(),
        exposure_s: cfg.exposure,
        shutter: Default::default(),
    })
}

/// Runs the geometric calibration with the intrinsics file of
/// `cfg.intrinsics` (see [`calibrate_geometric_with`]).
pub fn calibrate_geometric(
    display: &mut dyn Display,
    camera: &mut dyn Camera,
    cfg: &GeometricConfig,
    out_dir: &Path,
) -> Result<GeometricReport> {
    let path = cfg.intrinsics.as_ref().ok_or_else(|| {
        Error::invalid(
            "calibrate.geometric.intrinsics",
            "missing: the camera's intrinsics file turns dot centroids into directions",
        )
    })?;
    let intrinsics = CameraIntrinsics::load(path)?;
    calibrate_geometric_with(display, camera, &intrinsics, cfg, out_dir)
}

/// Runs the geometric calibration: shows the black screen, the dot grid
/// and each anchor dot, captures each, solves, and writes the geometry CSV,
/// `geometric_report.json` and `geometric_residuals.png` into `out_dir`.
/// The screen is left black.
pub fn calibrate_geometric_with(
    display: &mut dyn Display,
    camera: &mut dyn Camera,
    intrinsics: &CameraIntrinsics,
    cfg: &GeometricConfig,
    out_dir: &Path,
) -> Result<GeometricReport> {
    cfg.validate()?;
    intrinsics.validate()?;
    let screen = display.size();
    let grid = cfg.grid(screen);
    let black = grid.draw(std::iter::empty());
    let dark = capture(display, camera, &black, DARK_PATTERN, cfg)?;
    let all = capture(
        display,
        camera,
        &grid.draw(0..grid.centres.len()),
        GRID_PATTERN,
        cfg,
    )?;
    let mut anchors = Vec::new();
    for (k, dot) in grid.anchors().into_iter().enumerate() {
        let frame = capture(display, camera, &grid.draw([dot]), &anchor_pattern(k), cfg)?;
        anchors.push((dot, frame));
    }
    display.present(&black)?;
    let captures = Captures {
        dark,
        grid: all,
        anchors,
    };
    let solution = solve(&grid, &captures, intrinsics, cfg)?;
    std::fs::create_dir_all(out_dir).map_err(|e| Error::io(out_dir, e))?;
    output::write_all(&solution, &grid, cfg, &camera.describe(), out_dir)
}
