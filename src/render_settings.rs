//! The renderer's settings (the `[render]` table of a scene file): how
//! finely the body is sampled, how the map is filtered, how interior
//! pixels are integrated. Their own home, read by the scene file
//! ([`crate::scene`]), the renderer ([`crate::render`]) and the facility's
//! frame-time governor, so that the scene does not depend on the renderer.

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// Default spacing [px] of the interior pixels' node lattice.
pub const DEFAULT_NODE_SPACING: usize = 4;
/// Default estimated quadrature error up to which an interior pixel keeps
/// one point.
pub const DEFAULT_PIXEL_TOLERANCE: f64 = 1e-4;

/// How finely the body is sampled (the `[render]` table of a scene file).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RenderSettings {
    /// Caps per pixel along each image axis. Omitted: [`DEFAULT_DENSITY`],
    /// chosen from the benchmark's error curve (see BENCHMARKS.md).
    pub caps_per_pixel: Option<f64>,
    /// Minimum number of caps across the lit, visible lune, whatever the
    /// apparent size: along θ over its whole range, along φ across its
    /// widest row (shorter rows pro rata of their arc). Keeps the total flux
    /// of unresolved bodies exact to the flux tolerance.
    pub min_caps: usize,
    /// `exact` (finite-distance geometry for every cap) or `distant` (the
    /// paper's far-field limit: one view and Sun direction for all caps).
    pub geometry: GeometryMode,
    /// Sub-bands for spectrally varying reflectance; omitted: automatic.
    pub sub_bands: Option<usize>,
    /// Albedo-map samples per cap along each axis (1–4): the map varies at
    /// pixel scale while the BRDF does not, so each cap's PF is split over
    /// k×k parts of its footprint by the map alone.
    pub texture_samples: usize,
    /// How a pixel's or cap's albedo is averaged over its map footprint:
    /// `exact` (the bilinear map's exact mean over the footprint
    /// parallelogram), `samples` (k×k samples, `texture_samples`) or
    /// `adaptive` (the samples, and the exact mean where their spread
    /// exceeds `map_tolerance`).
    pub map_filter: MapFilter,
    /// The adaptive filter's threshold: where the k×k samples' range
    /// (max − min) reaches this fraction of their mean, the footprint
    /// takes the exact mean. 0: always exact; above k² never (for a
    /// non-negative map). In [0, 100].
    pub map_tolerance: f64,
    /// `pixels` (default): pixels whose whole preimage is lit and visible
    /// are integrated per pixel ([`crate::render::interior`]), the rest by the lune's caps;
    /// `caps`: the lune's caps everywhere.
    pub interior: Interior,
    /// Spacing [px] of the lattice on which interior pixels evaluate their
    /// smooth factors (geometry, reflectance model, map footprint) and
    /// interpolate them (`interior::Lattice`); 1 evaluates every pixel.
    pub node_spacing: usize,
    /// Estimated relative error of an interior pixel's quadrature up to
    /// which it keeps one point (then 2×2, then 4×4 Gauss points). Only
    /// pixels near the limb reach it; default
    /// [`DEFAULT_PIXEL_TOLERANCE`].
    pub pixel_tolerance: f64,
    /// `optistim render` writes an empty image when the body is entirely
    /// out of the field ([`crate::render::field`]) instead of stopping with
    /// an error.
    pub allow_empty: bool,
    /// Interior pixels a cast shadow's edge crosses take the mean shadow
    /// factor over 4 × 4 points of the pixel ([`crate::render::shadow_edges`]);
    /// `false` keeps their centre's 0 or 1 (faster, aliased edges).
    pub shadow_edges: bool,
    /// Target per-pixel error (interior p99 against a converged render):
    /// `optistim render` and `bench` then choose the cheapest settings of
    /// the planner's ladder that meet it ([`crate::planner`]), in place of
    /// the map filter, samples and tolerance above. In (0, 1].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_pixel_error: Option<f64>,
    /// `false` renders the body without its relief (`[body] shadows`: no
    /// cast shadows, no displacement), whatever `shadows.mode` says: the
    /// governor's cheapest rungs (`facility::governor::ladder_with_relief`).
    #[serde(skip_serializing_if = "is_true")]
    pub relief: bool,
}

fn is_true(b: &bool) -> bool {
    *b
}

/// How the pixels inside the lit disk are integrated.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum Interior {
    /// One cap per pixel: the pixel's preimage.
    #[default]
    Pixels,
    /// The lune's caps, gridded exactly.
    Caps,
}

/// Default threshold of the adaptive map filter
/// ([`RenderSettings::map_tolerance`]), from the benchmark's curve.
pub const DEFAULT_MAP_TOLERANCE: f64 = 0.05;

/// Default caps per pixel along each axis.
pub const DEFAULT_DENSITY: f64 = 1.0;
/// Largest caps per pixel accepted (64² caps per pixel already converge).
pub const MAX_DENSITY: f64 = 64.0;

/// Whether `d` is an accepted caps-per-pixel value: finite, in (0, [`MAX_DENSITY`]].
pub fn density_in_range(d: f64) -> bool {
    d.is_finite() && d > 0.0 && d <= MAX_DENSITY
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            caps_per_pixel: None,
            min_caps: 128,
            geometry: GeometryMode::Exact,
            sub_bands: None,
            texture_samples: 2,
            map_filter: MapFilter::Samples,
            map_tolerance: DEFAULT_MAP_TOLERANCE,
            interior: Interior::Pixels,
            node_spacing: DEFAULT_NODE_SPACING,
            pixel_tolerance: DEFAULT_PIXEL_TOLERANCE,
            allow_empty: false,
            shadow_edges: true,
            max_pixel_error: None,
            relief: true,
        }
    }
}

impl RenderSettings {
    /// Reject out-of-range values, naming the key.
    pub fn check(&self) -> Result<()> {
        if let Some(d) = self.caps_per_pixel {
            if !density_in_range(d) {
                return Err(Error::invalid(
                    "render.caps_per_pixel",
                    format!("must be in (0, {MAX_DENSITY}], got {d}"),
                ));
            }
        }
        if self.min_caps == 0 || self.min_caps > 100_000 {
            return Err(Error::invalid("render.min_caps", "must be in 1..=100000"));
        }
        if !(1..=4).contains(&self.texture_samples) {
            return Err(Error::invalid("render.texture_samples", "must be in 1..=4"));
        }
        if !(self.map_tolerance >= 0.0 && self.map_tolerance <= 100.0) {
            return Err(Error::invalid(
                "render.map_tolerance",
                "must be in [0, 100]",
            ));
        }
        if !(1..=16).contains(&self.node_spacing) {
            return Err(Error::invalid("render.node_spacing", "must be in 1..=16"));
        }
        if !(self.pixel_tolerance >= 1e-6 && self.pixel_tolerance <= 1e-2) {
            return Err(Error::invalid(
                "render.pixel_tolerance",
                "must be in [1e-6, 1e-2]",
            ));
        }
        if let Some(e) = self.max_pixel_error {
            check_pixel_error_target("render.max_pixel_error", e)?;
        }
        if let Some(n) = self.sub_bands {
            if n == 0 || n > 1000 {
                return Err(Error::invalid("render.sub_bands", "must be in 1..=1000"));
            }
        }
        Ok(())
    }

    /// Caps per pixel in use.
    pub fn density(&self) -> f64 {
        self.caps_per_pixel.unwrap_or(DEFAULT_DENSITY)
    }
}

/// A per-pixel error target must be finite and in (0, 1]; `key` names the
/// key or flag it came from.
pub fn check_pixel_error_target(key: &str, target: f64) -> Result<()> {
    if !(target.is_finite() && target > 0.0 && target <= 1.0) {
        return Err(Error::invalid(
            key,
            format!("must be in (0, 1], not {target}"),
        ));
    }
    Ok(())
}

/// How the albedo map is averaged over a pixel's or cap's footprint.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum MapFilter {
    /// The exact mean of the map's bilinear interpolant over the footprint
    /// parallelogram ([`crate::scene::EquirectMap::parallelogram_mean`]);
    /// caps take it over each of their k×k parts.
    Exact,
    /// k×k bilinear samples or box averages (`texture_samples`).
    #[default]
    Samples,
    /// The k×k samples where their range is below `map_tolerance` of
    /// their mean, else the exact mean: the samples' spread estimates the
    /// detail the footprint holds.
    Adaptive,
}

/// Geometry of the cap integrals.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum GeometryMode {
    /// Each cap has its own view vector, Sun vector and distances; the
    /// visible cap shrinks at close range.
    Exact,
    /// The paper's distant-observer form (far-field limit).
    Distant,
}
