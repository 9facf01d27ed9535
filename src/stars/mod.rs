//! Stars in the camera's frame (`[stars]` of a scene): which catalogue,
//! down to which magnitude, at which epoch; where each star lands on the
//! detector, whether a body hides it, and its electron rate spread
//! through the PSF ([`render`]), which the detector stage adds to the
//! body's before the sensor chain.

pub mod catalogue;
pub mod photometry;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::optics::psf::{point_stamp, Stamp};
use crate::scene::Scene;
pub use catalogue::{Catalogue, Star};

/// The bundled catalogue's magnitude limit (and the default `mag_limit`).
pub const BUNDLED_MAG_LIMIT: f64 = 7.5;
/// Epoch of a user catalogue's positions unless `catalogue_epoch` says.
pub const DEFAULT_CATALOGUE_EPOCH: f64 = 2000.0;

/// `[stars]` of a scene file.
#[derive(Deserialize, Clone, Debug)]
#[serde(deny_unknown_fields)]
pub struct StarsFile {
    /// `"bundled"` or the path of a CSV catalogue.
    catalogue: String,
    /// Faintest V drawn.
    mag_limit: Option<f64>,
    /// Julian year of a user catalogue's positions (default 2000.0).
    catalogue_epoch: Option<f64>,
    /// Epoch of the render (ISO text) when the scene has no `state.epoch`.
    epoch: Option<String>,
    /// The camera's velocity [m/s] in the world (barycentric ICRS) frame:
    /// stellar aberration. None: none.
    observer_velocity: Option<[f64; 3]>,
}

/// The stars of a scene.
#[derive(Clone, Debug)]
pub struct StarField {
    pub catalogue: Arc<Catalogue>,
    /// `bundled` or the file's path, for the summary.
    pub name: String,
    /// Faintest V drawn.
    pub mag_limit: f64,
    /// Julian year the stars are moved to by their proper motion.
    pub epoch_year: f64,
    /// The camera's velocity over c (stellar aberration), if given.
    pub beta: Option<DVec3>,
}

impl StarField {
    /// From the `[stars]` table; `base` anchors a relative catalogue path,
    /// `state_epoch` is the scene's `state.epoch` text, if any.
    pub fn from_file(file: &StarsFile, base: &Path, state_epoch: Option<&str>) -> Result<Self> {
        let mag_limit = file.mag_limit.unwrap_or(BUNDLED_MAG_LIMIT);
        let (lo, hi) = catalogue::V_RANGE;
        if !(mag_limit.is_finite() && (lo..=hi).contains(&mag_limit)) {
            return Err(Error::invalid(
                "stars.mag_limit",
                format!("must be within [{lo}, {hi}], got {mag_limit}"),
            ));
        }
        let epoch_year = match (&file.epoch, state_epoch) {
            (Some(_), Some(_)) => {
                return Err(Error::invalid(
                    "stars.epoch",
                    "not allowed with `state.epoch` (the stars use that)",
                ))
            }
            (Some(text), None) => {
                catalogue::julian_year(crate::ephemeris::parse_epoch(text, "stars.epoch")?)
            }
            (None, Some(text)) => {
                catalogue::julian_year(crate::ephemeris::parse_epoch(text, "state.epoch")?)
            }
            (None, None) => 2000.0,
        };
        let (catalogue, name) = if file.catalogue == "bundled" {
            if file.catalogue_epoch.is_some() {
                return Err(Error::invalid(
                    "stars.catalogue_epoch",
                    "only for a catalogue file (the bundled one is at J1991.25)",
                ));
            }
            (Catalogue::bundled(), "bundled".to_string())
        } else {
            let epoch = file.catalogue_epoch.unwrap_or(DEFAULT_CATALOGUE_EPOCH);
            if !(epoch.is_finite() && (1000.0..=3000.0).contains(&epoch)) {
                return Err(Error::invalid(
                    "stars.catalogue_epoch",
                    format!("must be a Julian year within [1000, 3000], got {epoch}"),
                ));
            }
            let path = resolve(base, &file.catalogue);
            let cat = Catalogue::from_file(&path, epoch).map_err(|e| match e {
                Error::Parse { path, message } => {
                    Error::parse(path, format!("stars.catalogue: {message}"))
                }
                other => Error::invalid("stars.catalogue", other.to_string()),
            })?;
            (Arc::new(cat), path.display().to_string())
        };
        Ok(StarField {
            catalogue,
            name,
            mag_limit,
            epoch_year,
            beta: file.observer_velocity.map(velocity_over_c).transpose()?,
        })
    }
}

/// Fastest observer accepted [m/s] (1000× a spacecraft's speed).
pub const MAX_OBSERVER_SPEED: f64 = 1e7;
/// Speed of light [m/s].
const LIGHT_SPEED: f64 = 299_792_458.0;

/// `stars.observer_velocity` as β = v/c, range-checked.
fn velocity_over_c(v: [f64; 3]) -> Result<DVec3> {
    let v = DVec3::from_array(v);
    if !(v.is_finite() && v.length() <= MAX_OBSERVER_SPEED) {
        return Err(Error::invalid(
            "stars.observer_velocity",
            format!("need a finite velocity of at most {MAX_OBSERVER_SPEED:e} m/s, got {v}"),
        ));
    }
    Ok(v / LIGHT_SPEED)
}

/// The apparent direction of a star in direction `n` to an observer moving
/// at `beta` (special-relativistic aberration):
/// n' = (n + γβ + (γ − 1)(n·β̂)β̂) / (γ (1 + n·β)).
pub fn aberrate(n: DVec3, beta: DVec3) -> DVec3 {
    let b2 = beta.length_squared();
    if b2 == 0.0 {
        return n;
    }
    let gamma = 1.0 / (1.0 - b2).sqrt();
    let along = n.dot(beta) / b2;
    ((n + gamma * beta + (gamma - 1.0) * along * beta) / (gamma * (1.0 + n.dot(beta)))).normalize()
}

fn resolve(base: &Path, path: &str) -> PathBuf {
    let p = Path::new(path);
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        base.join(p)
    }
}

/// A catalogue star as the camera sees it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ProjectedStar {
    pub id: u64,
    /// Continuous pixel position of its direction [px].
    pub u: f64,
    pub v: f64,
    pub v_mag: f64,
    /// Electrons per second it gives the detector (all pixels together).
    pub electron_rate: f64,
    /// Behind the body (or the occulter) and not drawn.
    pub occulted: bool,
}

/// What the stars added (`summary.json`, `stars`).
#[derive(Clone, Debug, Serialize)]
pub struct StarSummary {
    pub catalogue: String,
    pub epoch_year: f64,
    pub mag_limit: f64,
    /// Stars brighter than the limit whose light can reach the frame.
    pub in_field: usize,
    /// Of those, hidden by the body or the occulter.
    pub occulted: usize,
    /// Σ electron rate of the drawn stars [e⁻/s] (before the frame's edge).
    pub electron_rate: f64,
    /// Wall-clock time of the stars' stage [ms].
    pub stars_ms: f64,
}

/// The stars' electron-rate image [e⁻/s per pixel] and its summary.
pub struct StarImage {
    pub electron_rate: Vec<f32>,
    pub stars: Vec<ProjectedStar>,
    pub summary: StarSummary,
}

/// Whether the ray from `origin` along unit `dir` meets the sphere.
fn ray_hits_sphere(origin: DVec3, dir: DVec3, centre: DVec3, radius: f64) -> bool {
    let d = centre - origin;
    let along = d.dot(dir);
    along > 0.0 && d.length_squared() - along * along < radius * radius
}

/// The stars brighter than the limit whose light can reach the frame
/// (their pixel within `margin` px of it), with their electron rates.
pub fn project(field: &StarField, scene: &Scene, margin: f64) -> Vec<ProjectedStar> {
    let cam = &scene.camera;
    let pin = &cam.pinhole;
    let s = &scene.state;
    let to_camera = s.camera_attitude.inverse();
    let years = field.epoch_year - field.catalogue.epoch_year;
    // Parallax: the camera's position from the Sun (heliocentric).
    let observer = s.camera_position - s.sun_position;
    let pupil = cam.pupil_area();
    let (w, h) = (pin.width as f64, pin.height as f64);
    field
        .catalogue
        .stars
        .par_iter()
        .filter(|star| star.v_mag <= field.mag_limit)
        .filter_map(|star| {
            let world = star.direction_from(years, observer);
            // Aberration moves the body's image as much: it decides where
            // a star lands, not whether the body hides it.
            let apparent = field.beta.map_or(world, |b| aberrate(world, b));
            let c = to_camera * apparent;
            if c.z <= 0.0 {
                return None;
            }
            // Through the lens where the camera has one: the body's image
            // is resampled onto the distorted pixels, so the stars must be
            // too (none beyond the lens's field, where the polynomial folds).
            let (u, v) = match &cam.distortion {
                Some(lens) => lens.project(c)?,
                None => pin.project(c),
            };
            if !(u > -margin && u < w + margin && v > -margin && v < h + margin) {
                return None;
            }
            let hidden = |centre: DVec3, radius: f64| {
                ray_hits_sphere(s.camera_position, world, centre, radius)
            };
            let occulted = hidden(s.body_position, scene.body.radius)
                || s.occulter.is_some_and(|o| hidden(o.position, o.radius));
            let per_area = photometry::electron_rate_per_area(
                star.v_mag,
                star.b_v,
                &cam.quantum_efficiency,
                &cam.transmission,
                cam.band,
            );
            Some(ProjectedStar {
                id: star.id,
                u,
                v,
                v_mag: star.v_mag,
                // The pupil's area projected on the star's direction.
                electron_rate: per_area * pupil * c.normalize().z,
                occulted,
            })
        })
        .collect()
}

/// The stars' electron rates on the detector, through the camera's PSF
/// (each star integrated over the pixels at its own sub-pixel position;
/// without a PSF all its light falls in the pixel holding it).
pub fn render(field: &StarField, scene: &Scene) -> Result<StarImage> {
    let start = std::time::Instant::now();
    let pin = &scene.camera.pinhole;
    let psf = scene.camera.psf.as_ref();
    let margin = match psf {
        Some(p) => point_stamp(p, 0.5, 0.5)?.half as f64 + 1.0,
        None => 0.0,
    };
    let stars = project(field, scene, margin);
    let mut image = vec![0.0f32; pin.width * pin.height];
    let mut add = |i: isize, j: isize, rate: f64| {
        if i >= 0 && j >= 0 && (i as usize) < pin.width && (j as usize) < pin.height {
            image[j as usize * pin.width + i as usize] += rate as f32;
        }
    };
    let drawn: Vec<&ProjectedStar> = stars.iter().filter(|s| !s.occulted).collect();
    // Stamps in parallel (an Airy stamp is ~10⁵ Bessel evaluations).
    let stamps: Vec<Option<Stamp>> = drawn
        .par_iter()
        .map(|s| psf.map(|p| point_stamp(p, s.u, s.v)).transpose())
        .collect::<Result<_>>()?;
    for (star, stamp) in drawn.iter().zip(stamps) {
        match stamp {
            None => add(
                star.u.floor() as isize,
                star.v.floor() as isize,
                star.electron_rate,
            ),
            Some(stamp) => {
                let n = 2 * stamp.half + 1;
                for (k, w) in stamp.weights.iter().enumerate() {
                    let i = stamp.i0 + (k % n) as isize - stamp.half as isize;
                    let j = stamp.j0 + (k / n) as isize - stamp.half as isize;
                    add(i, j, star.electron_rate * w);
                }
            }
        }
    }
    let summary = StarSummary {
        catalogue: field.name.clone(),
        epoch_year: field.epoch_year,
        mag_limit: field.mag_limit,
        in_field: stars.len(),
        occulted: stars.len() - drawn.len(),
        electron_rate: drawn.iter().map(|s| s.electron_rate).sum(),
        stars_ms: start.elapsed().as_secs_f64() * 1e3,
    };
    Ok(StarImage {
        electron_rate: image,
        stars,
        summary,
    })
}
