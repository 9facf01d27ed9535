//! The validation pipeline of the reference paper on SMART-1 AMIE flight
//! images (`optistim validate amie`, `docs/VALIDATION.md`):
//!
//! 1. load the image and rebuild its scene from the label ([`super::amie`]);
//! 2. build an optistim [`Scene`] (AMIE camera and detector chain, the Moon
//!    with the chosen reflection model and the LROC albedo map, and during a
//!    lunar eclipse the Earth as an occulter) and render it with
//!    [`render_scene`];
//! 3. the render in DN as floats before quantisation: electrons × gain
//!    (1/280 DN per e⁻), not clipped (see [`RENDER_FULL_WELL_E`]);
//! 4. align the render to the real image by NCC ([`super::align`]), in two
//!    passes over a window around the disk: ±[`MAX_SHIFT_PX`] against a
//!    provisional background-free image (disk widened by [`DISK_MARGIN_PX`]),
//!    then, with the background fitted around the aligned disk, ±[`REFINE_PX`]
//!    about that; the render is shifted (bilinear), the real image is never
//!    resampled;
//! 5. background removal of the real image ([`super::background`], the
//!    one AMIE tuning), then the noise floor: pixels below
//!    [`NOISE_FLOOR_SIGMA`] × the sky's robust σ are set to 0;
//! 6. total-signal ratio real/render over the disk plus
//!    [`SIGNAL_MARGIN_PX`] (sky excluded: its clipped noise would bias it);
//! 7. SSIM with the 10-bit range L = 1023 of the background-free real image
//!    against the render scaled to the same total signal (AMIE has no
//!    absolute calibration), and also against the unscaled render.
//!
//! Everything tuned is a constant of this module, used unchanged for every
//! image and model.

use std::path::{Path, PathBuf};

use glam::{DQuat, DVec3};
use serde::Serialize;

use super::align::{ncc_align, shift_bilinear, Alignment};
use super::amie::{self, AmieObservation, GeometryCheck, EARTH_RADIUS_M, MOON_RADIUS_M};
use super::background::{remove_background, BackgroundModel, BackgroundParams, Disk};
use super::ephem::{self, Utc};
use super::figure;
use super::raster::Raster;
use super::relief_signal::{relief_signal, HighPassSignal, ReliefSignal};
use super::ssim::{ssim, SsimResult, AMIE_DATA_RANGE};
use crate::error::{Error, Result};
use crate::radiometry::reflectance::ReflectanceConfig;
use crate::radiometry::spectrum::{Response, SolarSpectrum, Table};
use crate::render::detector::{render_scene, PixelGeometry, Summary};
use crate::render::{RenderSettings, Renderer};
use crate::scene::{
    Body, Camera, EquirectMap, Occulter, Pinhole, Relief, Scene, ShadowsSpec, State,
};

/// Lower and upper wavelength of the assumed AMIE response [m].
pub const BAND_M: [f64; 2] = [400e-9, 1000e-9];
/// Range the LROC WAC colour mosaic is stretched to, as the model's albedo
/// parameter (Oren–Nayar and Lambert "albedo"). The paper's value.
pub const ALBEDO_RANGE: (f64, f64) = (0.16, 0.40);
/// AMIE saturation [e⁻]: 1023 DN × 280 e⁻/DN (the ADC saturates first).
pub const FULL_WELL_E: f64 = 286_440.0;
/// Full well given to the renderer: effectively none. AMIE has no absolute
/// calibration and the render's absolute level is uncertain by a factor of
/// a few (assumed response, albedo scale), so clipping it at the AMIE
/// saturation would cut the render and not the real image; the render is
/// compared unclipped and the pixels above [`FULL_WELL_E`] are counted
/// ([`ValidationReport::render_pixels_above_saturation`]).
pub const RENDER_FULL_WELL_E: f64 = 1e15;
/// The Earth's shadow is enlarged by its atmosphere by ~2 % (Chauvenet's
/// classical 1/50; Danjon's 1/85 of the parallax is similar): modelled by an
/// occulter of radius 1.02 × the equatorial radius.
pub const EARTH_SHADOW_ENLARGEMENT: f64 = 1.02;
/// Half-width of the NCC search [px]: the label pose is good to ~10 px.
pub const MAX_SHIFT_PX: usize = 30;
/// Noise floor: after the background subtraction, real pixels below this
/// many robust σ of the sky are set to 0 (the paper's "removal of background
/// noise", which the model does not contain). 3σ keeps < 0.2 % of pure-noise
/// pixels.
pub const NOISE_FLOOR_SIGMA: f64 = 3.0;
/// Half-width of the second, refining NCC search about the first [px].
pub const REFINE_PX: usize = 3;
/// Margin added to the predicted disk for the provisional background fit [px].
pub const DISK_MARGIN_PX: f64 = 12.0;
/// Pixels within this distance outside the aligned limb count in the total
/// signal (the optics spread the limb over a few pixels) [px].
pub const SIGNAL_MARGIN_PX: f64 = 4.0;

/// Paths and switches of one validation run. [`ValidationOptions::new`]
/// gives the documented configuration; nothing in it is per-image.
#[derive(Debug, Clone, Serialize)]
pub struct ValidationOptions {
    /// Albedo map (equirectangular); `None`: uniform model albedo.
    pub albedo_map: Option<PathBuf>,
    /// Range the map is stretched to.
    pub albedo_range: (f64, f64),
    /// Solar spectrum CSV (nm, W m⁻² nm⁻¹).
    pub solar_spectrum: PathBuf,
    /// Assumed QE × transmission CSV (nm, e⁻/photon).
    pub response: PathBuf,
    /// Add the Earth as an occulter when the Moon is near its shadow.
    pub earth_shadow: bool,
    /// Caps per pixel along each axis (`None`: renderer default).
    pub caps_per_pixel: Option<f64>,
    /// Directory of SPICE kernels (`tools/fetch_kernels.sh`): Sun and Moon
    /// attitude from them instead of the analytic ephemerides.
    pub kernels: Option<PathBuf>,
    /// Relief from a DEM (`[body] shadows`, applied in every frame):
    /// cast shadows, and with `displace` the limb and the normals too.
    pub relief: Option<ShadowsSpec>,
    /// A Gaussian PSF of this standard deviation [px] on the render (AMIE
    /// publishes none; `None`: no PSF).
    pub psf_sigma_px: Option<f64>,
}

impl ValidationOptions {
    /// The documented configuration, with data files under `data_dir`
    /// (the repository's `data/`).
    pub fn new(data_dir: impl AsRef<Path>) -> Self {
        let d = data_dir.as_ref();
        Self {
            albedo_map: Some(d.join("maps/lroc_color_poles_2k.tif")),
            albedo_range: ALBEDO_RANGE,
            solar_spectrum: d.join("solar/astm_e490_am0.csv"),
            response: d.join("amie/qe_assumed.csv"),
            earth_shadow: true,
            caps_per_pixel: None,
            kernels: None,
            relief: None,
            psf_sigma_px: None,
        }
    }
}

/// A reflection model as used here: its scene-file table and its source.
#[derive(Debug, Clone, Serialize)]
pub struct ModelChoice {
    pub name: String,
    /// TOML inline table given to [`ReflectanceConfig`].
    pub config_toml: String,
    /// Where the parameters come from.
    pub source: String,
}

/// The models `optistim validate amie --model` knows, with their fixed
/// parameters.
pub fn model_choice(model: &str) -> Result<ModelChoice> {
    let (toml, source) = match model {
        "oren_nayar" => (
            r#"{ model = "oren_nayar", albedo = 0.15, roughness = 0.3 }"#,
            "reference paper: Oren-Nayar (1994), albedo 0.15, roughness 0.3",
        ),
        "lambert" => (r#"{ model = "lambert", albedo = 0.15 }"#, "Lambert, albedo 0.15 (as the paper's Oren-Nayar)"),
        "lommel_seeliger" => (
            r#"{ model = "lommel_seeliger", albedo = 0.15 }"#,
            "Lommel-Seeliger, albedo 0.15",
        ),
        "hapke" => (
            HAPKE_TOML,
            "Hapke (2012 IMSA) with the disk-integrated lunar parameters of Helfenstein & Veverka (1987, Icarus 72, 342): \
             w = 0.21, single-lobe Henyey-Greenstein g = -0.29, theta_bar = 20 deg, SHOE B_S0 = 2.01, h_S = 0.07; \
             no CBOE, no porosity correction (K = 1)",
        ),
        "moon" => (
            "",
            "the bundled Moon anchored to LIME (configs/bodies/moon.toml, docs/MOON.md): its own map and spectral parameters",
        ),
        other => {
            return Err(Error::invalid(
                "validate.model",
                format!("unknown model `{other}` (oren_nayar, hapke, lambert, lommel_seeliger, moon)"),
            ))
        }
    };
    Ok(ModelChoice {
        name: model.to_string(),
        config_toml: toml.to_string(),
        source: source.to_string(),
    })
}

/// Hapke parameters (see [`model_choice`]).
const HAPKE_TOML: &str = r#"{ model = "hapke", w = 0.21, b = 0.29, c = 1.0, theta_bar = 0.3490658503988659, h_s = 0.07, b_s0 = 2.01, porosity_k = 1.0 }"#;

fn reflectance_config(choice: &ModelChoice) -> Result<ReflectanceConfig> {
    #[derive(serde::Deserialize)]
    struct Wrap {
        r: ReflectanceConfig,
    }
    let w: Wrap = toml::from_str(&format!("r = {}", choice.config_toml))
        .map_err(|e| Error::invalid("validate.model", format!("{}: {e}", choice.name)))?;
    Ok(w.r)
}

/// The Earth's shadow as used for one image.
#[derive(Debug, Clone, Serialize)]
pub struct EclipseReport {
    /// Earth centre relative to the Moon, J2000 [m].
    pub earth_position_m: [f64; 3],
    /// How the Earth's position was obtained.
    pub earth_position_source: String,
    /// Occulter radius [m] (equatorial radius × enlargement).
    pub occulter_radius_m: f64,
    pub enlargement: f64,
    /// Distance of the Moon's centre from the shadow axis [km].
    pub axis_distance_km: f64,
    /// Umbra and penumbra radii at the Moon [km] (with the enlargement).
    pub umbra_radius_km: f64,
    pub penumbra_radius_km: f64,
}

/// SSIM means.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct SsimScores {
    pub mssim: f64,
    pub luminance: f64,
    pub contrast: f64,
    pub structure: f64,
}

impl From<&SsimResult> for SsimScores {
    fn from(r: &SsimResult) -> Self {
        Self {
            mssim: r.mssim,
            luminance: r.luminance,
            contrast: r.contrast,
            structure: r.structure,
        }
    }
}

/// Means of the SSIM maps over the map pixels whose window centre lies
/// within `margin` px outside the disk: the Moon only, without the sky that
/// dominates the full-image means (most of all on image 00101_00010, where
/// the Moon is 29 px in radius).
pub fn disk_scores(r: &SsimResult, disk: &Disk, margin: f64) -> SsimScores {
    let (mut n, mut acc) = (0usize, [0.0f64; 4]);
    for j in 0..r.map.height {
        for i in 0..r.map.width {
            let (x, y) = ((i + r.offset) as f64 + 0.5, (j + r.offset) as f64 + 0.5);
            if disk.limb_distance(x, y) <= margin {
                n += 1;
                acc[0] += r.map.get(i, j) as f64;
                acc[1] += r.luminance_map.get(i, j) as f64;
                acc[2] += r.contrast_map.get(i, j) as f64;
                acc[3] += r.structure_map.get(i, j) as f64;
            }
        }
    }
    let m = |v: f64| if n > 0 { v / n as f64 } else { f64::NAN };
    SsimScores {
        mssim: m(acc[0]),
        luminance: m(acc[1]),
        contrast: m(acc[2]),
        structure: m(acc[3]),
    }
}

/// Camera as rendered.
#[derive(Debug, Clone, Serialize)]
pub struct CameraReport {
    pub resolution: [usize; 2],
    pub focal_length_m: f64,
    pub pixel_pitch_m: f64,
    pub f_number: f64,
    pub exposure_s: f64,
    pub gain_dn_per_e: f64,
    pub full_well_e: f64,
    pub bits: u32,
    pub band_nm: [f64; 2],
    pub response: String,
}

/// Everything one validation produced (`report.json`).
#[derive(Debug, Clone, Serialize)]
pub struct ValidationReport {
    pub product_id: String,
    pub image: String,
    pub start_time_utc: String,
    pub model: ModelChoice,
    pub options: ValidationOptions,
    pub camera: CameraReport,
    /// Phase angle: label (at the boresight point), derived at the same
    /// point, derived at the Moon centre, and |derived − label| [deg].
    pub phase_label_deg: f64,
    pub phase_derived_deg: f64,
    pub phase_at_centre_deg: f64,
    pub phase_error_deg: f64,
    pub geometry: GeometryCheck,
    pub eclipse: Option<EclipseReport>,
    pub render: Summary,
    /// Render pixels at or above the AMIE saturation (1023 DN) before the
    /// scaling to the real total signal (the render is not clipped).
    pub render_pixels_above_saturation: usize,
    /// "what the render is compared as" in words.
    pub render_product: String,
    pub background_method: String,
    pub background_params: BackgroundParams,
    pub background: BackgroundModel,
    /// Predicted disk (from the label pose) and disk after alignment.
    pub predicted_disk: Disk,
    pub aligned_disk: Disk,
    /// Shift of the real image content relative to the render [px].
    pub alignment: Alignment,
    pub shift_px: f64,
    /// Σ real DN and Σ render DN over the aligned disk + margin.
    pub real_total_dn: f64,
    pub render_total_dn: f64,
    /// real / render: the absolute-level check (AMIE has no absolute
    /// calibration; depends on the assumed response and albedo scale).
    pub total_signal_ratio: f64,
    pub ssim_data_range: f64,
    /// SSIM against the render scaled by `total_signal_ratio` (headline).
    pub ssim: SsimScores,
    /// SSIM against the unscaled render (its luminance term is the
    /// absolute-level comparison).
    pub ssim_unnormalised: SsimScores,
    /// SSIM (render scaled) against the background-subtracted real image
    /// without the noise floor (sky noise left in, clipped at 0).
    pub ssim_without_noise_floor: SsimScores,
    /// The headline SSIM's means over the Moon's disk (+ [`SIGNAL_MARGIN_PX`]) only.
    pub ssim_disk: SsimScores,
    /// Real pixels below this were set to 0 [DN].
    pub noise_floor_dn: f64,
    /// With `relief`: the relief's change to the render against the
    /// residual of a render without it ([`relief_signal`]).
    pub relief_signal: Option<ReliefSignal>,
}

/// A validation with its images (for the figure).
pub struct ValidationRun {
    pub report: ValidationReport,
    /// Background-free real image [DN].
    pub real: Raster,
    /// Aligned render scaled to the real total signal [DN].
    pub render: Raster,
    pub ssim: SsimResult,
}

/// The numbers printed on `comparison.png`.
fn figure_notes(r: &ValidationReport) -> Vec<String> {
    let scores = |s: &SsimScores| {
        format!(
            "{:.4} (luminance {:.4}, contrast {:.4}, structure {:.4})",
            s.mssim, s.luminance, s.contrast, s.structure
        )
    };
    let mut notes = vec![
        format!("SSIM full frame: {}", scores(&r.ssim)),
        format!("SSIM over the disk: {}", scores(&r.ssim_disk)),
        format!(
            "shift render → real: ({:+.2}, {:+.2}) px, |shift| {:.2} px; disk centre ({:.1}, {:.1}) px, radius {:.1} px",
            r.alignment.dx, r.alignment.dy, r.shift_px, r.aligned_disk.cx, r.aligned_disk.cy, r.aligned_disk.radius
        ),
        format!(
            "real / render total signal: {:.4} (render scaled by it); noise floor {:.1} DN",
            r.total_signal_ratio, r.noise_floor_dn
        ),
        format!(
            "phase: {:.2}° derived, {:.2}° in the label ({:.2}° at the disk centre)",
            r.phase_derived_deg, r.phase_label_deg, r.phase_at_centre_deg
        ),
    ];
    if let Some(s) = &r.relief_signal {
        // The high-passed numbers stay in report.json and the command's
        // output: the figure's foot holds seven lines.
        notes.push(relief_note(s));
    }
    notes
}

/// One line on the relief's change against the residual without it.
pub fn relief_note(s: &ReliefSignal) -> String {
    format!(
        "relief vs residual without it ({} px ≥ {} px inside the limb): correlation {:.3}, gain {:.3}, residual {:+.1} %",
        s.pixels,
        s.inset_px,
        s.correlation,
        s.gain,
        100.0 * s.residual_change
    )
}

/// Two lines on the same after the high-pass: the statistics per blur,
/// and the best shift of the narrowest.
pub fn relief_high_pass_notes(s: &ReliefSignal) -> [String; 2] {
    let join = |f: &dyn Fn(&HighPassSignal) -> String| {
        s.high_pass.iter().map(f).collect::<Vec<_>>().join(" / ")
    };
    let first = format!(
        "high-passed (σ {} px): correlation {}, gain {}, residual {} %",
        join(&|h| format!("{}", h.sigma_px)),
        join(&|h| format!("{:.3}", h.correlation)),
        join(&|h| format!("{:.3}", h.gain)),
        join(&|h| format!("{:+.1}", 100.0 * h.residual_change)),
    );
    let second = match s.high_pass.first() {
        Some(h) => format!(
            "high-passed (σ {} px), best at the relief shifted by ({}, {}) px: correlation {:.3}",
            h.sigma_px, h.best_shift_px[0], h.best_shift_px[1], h.best_shift_correlation
        ),
        None => "high-passed: no pixels".to_string(),
    };
    [first, second]
}

/// Runs the pipeline on one AMIE image; see the module doc.
pub fn validate_amie(
    img_path: impl AsRef<Path>,
    model: &str,
    options: &ValidationOptions,
) -> Result<ValidationReport> {
    run(img_path, model, options).map(|r| r.report)
}

/// Earth relative to the Moon, J2000 [m], from the label: the spacecraft's
/// Earth-fixed vector rotated to J2000 plus the spacecraft→Moon vector gives
/// the geocentric Moon to ~30 km (the analytic Moon is good to ~900 km,
/// i.e. 15 px of the shadow edge on image 00101_00010). Falls back to the
/// analytic ephemeris when the label has no Earth-fixed vector.
pub fn earth_from_moon(obs: &AmieObservation) -> Result<(DVec3, String)> {
    let l = &obs.scene.label;
    match l.sc_efrf_km {
        Some(efrf) => {
            let utc = Utc::parse(&l.start_time)
                .map_err(|e| Error::invalid("START_TIME", e.to_string()))?;
            let sc_geo = ephem::earth_fixed_to_j2000(utc.jd_utc(), obs.scene.jd_tt)
                * DVec3::from_array(efrf)
                * 1e3;
            let moon_geo = sc_geo + DVec3::from_array(l.sc_target_position_km) * 1e3;
            Ok((
                -moon_geo,
                "label: precession(IAU 1976) x GMST x SMART1:AMIE_SC_EFRF_VECTOR + SC_TARGET_POSITION_VECTOR".into(),
            ))
        }
        None => Ok((
            -ephem::moon_geocentric_j2000(obs.scene.jd_tt),
            "analytic Moon ephemeris (Astronomical Almanac low precision)".into(),
        )),
    }
}

/// `spice_earth`: the Earth relative to the Moon from the kernels, used
/// instead of the label's when given.
fn eclipse(obs: &AmieObservation, spice_earth: Option<DVec3>) -> Result<Option<EclipseReport>> {
    let (earth, source) = match spice_earth {
        Some(e) => (e, "SPICE kernels (DE421)".to_string()),
        None => earth_from_moon(obs)?,
    };
    let sun = obs.scene.sun_position();
    // Shadow axis: from the Earth away from the Sun.
    let axis = (earth - sun).normalize();
    let moon_rel = -earth;
    let along = moon_rel.dot(axis);
    if along <= 0.0 {
        return Ok(None);
    }
    let r_occ = EARTH_RADIUS_M * EARTH_SHADOW_ENLARGEMENT;
    let d_sun = (earth - sun).length();
    let axis_dist = (moon_rel - axis * along).length();
    let umbra = r_occ - along * (amie::SUN_RADIUS_M - r_occ) / d_sun;
    let penumbra = r_occ + along * (amie::SUN_RADIUS_M + r_occ) / d_sun;
    if axis_dist > penumbra + MOON_RADIUS_M {
        return Ok(None);
    }
    Ok(Some(EclipseReport {
        earth_position_m: earth.to_array(),
        earth_position_source: source,
        occulter_radius_m: r_occ,
        enlargement: EARTH_SHADOW_ENLARGEMENT,
        axis_distance_km: axis_dist / 1e3,
        umbra_radius_km: umbra / 1e3,
        penumbra_radius_km: penumbra / 1e3,
    }))
}

/// The optistim scene of an AMIE observation.
pub fn build_scene(
    obs: &AmieObservation,
    choice: &ModelChoice,
    options: &ValidationOptions,
    eclipse: Option<&EclipseReport>,
) -> Result<Scene> {
    let c = &obs.scene.camera;
    let (w, h) = (c.resolution.0 as usize, c.resolution.1 as usize);
    let f_px = c.focal_px();
    let response = Table::from_csv(&options.response)?;
    let camera = Camera {
        pinhole: Pinhole {
            width: w,
            height: h,
            fx: f_px,
            fy: f_px,
            cx: c.principal_point_px.0,
            cy: c.principal_point_px.1,
        },
        pixel_pitch: c.pixel_pitch_m,
        focal_length: c.focal_length_m,
        f_number: c.f_number,
        exposure: c.exposure_s,
        full_well: RENDER_FULL_WELL_E,
        bits: c.bits,
        gain: 1.0 / c.gain_e_per_dn,
        band: BAND_M,
        quantum_efficiency: Response::Table(response),
        transmission: Response::Constant(1.0),
        sensor: None,
        psf: options
            .psf_sigma_px
            .map(|sigma_px| crate::scene::camera::Psf::Gaussian { sigma_px }),
        distortion: None,
        sensor_frame: 0,
    };
    let sun = SolarSpectrum::from_csv(&options.solar_spectrum, Some(1361.0))?;
    let body = if choice.name == "moon" {
        // The body file sits in configs/bodies/ next to data/.
        let data = options.solar_spectrum.parent().and_then(Path::parent);
        let path = data
            .unwrap_or(Path::new("data"))
            .join("../configs/bodies/moon.toml");
        Body::from_file(&path)?
    } else {
        let albedo_map = match &options.albedo_map {
            Some(p) => {
                let mut m = EquirectMap::load(p)?;
                m.stretch(options.albedo_range.0, options.albedo_range.1);
                Some(m)
            }
            None => None,
        };
        Body {
            radius: MOON_RADIUS_M,
            reflectance: reflectance_config(choice)?.build()?,
            albedo_map,
            albedo_spectrum: None,
            relief: Relief::default(),
            parameter_maps: Vec::new(),
            lime_reference: false,
        }
    };
    let mut body = body;
    if let Some(spec) = &options.relief {
        let relief = Relief::from_dem(spec, Path::new("."), body.radius)?;
        body.relief.shadows = relief.shadows;
        if relief.height.is_some() {
            body.relief.height = relief.height;
            body.relief.height_bound = relief.height_bound;
        }
    }
    let s = &obs.scene;
    let q = |v: [f64; 4]| DQuat::from_xyzw(v[1], v[2], v[3], v[0]).normalize();
    let state = State {
        body_position: DVec3::ZERO,
        body_attitude: q(s.state.body_attitude),
        camera_position: s.camera_position(),
        camera_attitude: q(s.state.camera_attitude),
        sun_position: s.sun_position(),
        occulter: eclipse.map(|e| Occulter {
            position: DVec3::from_array(e.earth_position_m),
            radius: e.occulter_radius_m,
        }),
    };
    if let Some(psf) = &camera.psf {
        psf.validate("validate.psf_sigma_px")?;
    }
    let render = RenderSettings {
        caps_per_pixel: options.caps_per_pixel,
        ..RenderSettings::default()
    };
    render.check()?;
    Ok(Scene {
        camera,
        sun,
        body,
        state,
        render,
        stars: None,
    })
}

/// Box (x0, y0, x1, y1) around the predicted disk with room for the
/// search: only this part enters the NCC (the rest is sky).
fn crop_window(disk: &Disk, w: usize, h: usize) -> (usize, usize, usize, usize) {
    let half = disk.radius + DISK_MARGIN_PX + MAX_SHIFT_PX as f64;
    let clamp = |v: f64, hi: usize| (v.max(0.0) as usize).min(hi);
    (
        clamp(disk.cx - half, w),
        clamp(disk.cy - half, h),
        clamp(disk.cx + half, w),
        clamp(disk.cy + half, h),
    )
}

fn crop(img: &Raster, (x0, y0, x1, y1): (usize, usize, usize, usize), shift: (i32, i32)) -> Raster {
    // `out(x, y) = img(x − sx, y − sy)` inside the window, 0 outside the image.
    Raster::from_fn(x1 - x0, y1 - y0, |c, r| {
        let (x, y) = (
            (x0 + c) as i64 - shift.0 as i64,
            (y0 + r) as i64 - shift.1 as i64,
        );
        if x < 0 || y < 0 || x >= img.width as i64 || y >= img.height as i64 {
            0.0
        } else {
            img.get(x as usize, y as usize)
        }
    })
}

/// NCC shift of `real` relative to `render` within `window`, searched
/// ±`max_shift` px about the integer shift `about`.
fn align_in(
    render: &Raster,
    real: &Raster,
    window: (usize, usize, usize, usize),
    about: (i32, i32),
    max_shift: usize,
) -> Result<Alignment> {
    let a = ncc_align(
        &crop(render, window, about),
        &crop(real, window, (0, 0)),
        max_shift,
    )?;
    Ok(Alignment {
        dx: a.dx + about.0 as f64,
        dy: a.dy + about.1 as f64,
        integer_shift: (a.integer_shift.0 + about.0, a.integer_shift.1 + about.1),
        ..a
    })
}

fn sum_within(img: &Raster, disk: &Disk, margin: f64) -> f64 {
    let mut s = 0.0;
    for r in 0..img.height {
        for c in 0..img.width {
            if disk.limb_distance(c as f64 + 0.5, r as f64 + 0.5) <= margin {
                s += img.get(c, r) as f64;
            }
        }
    }
    s
}

/// Runs the pipeline and keeps the images.
pub fn run(
    img_path: impl AsRef<Path>,
    model: &str,
    options: &ValidationOptions,
) -> Result<ValidationRun> {
    let path = img_path.as_ref();
    let mut obs = amie::load(path)?;
    let mut spice_earth = None;
    if let Some(dir) = &options.kernels {
        let spice = crate::ephemeris::Spice::from_dir(dir)?;
        obs.scene = amie::with_ephemeris(&obs.scene, &spice)?;
        let t = amie::epoch(&obs.scene)?;
        spice_earth = Some(spice.position(crate::ephemeris::EARTH, crate::ephemeris::MOON, t)?);
    }
    let choice = model_choice(model)?;
    let ecl = if options.earth_shadow {
        eclipse(&obs, spice_earth)?
    } else {
        None
    };
    let r = render_observation(&obs, &choice, options, ecl.as_ref())?;
    let m = match_to_image(&obs, &r.dn)?;
    let shifted = shift_bilinear(&r.dn, m.align.dx, m.align.dy, 0.0);

    let real = &m.real;
    let real_total = sum_within(real, &m.aligned_disk, SIGNAL_MARGIN_PX);
    let render_total = sum_within(&shifted, &m.aligned_disk, SIGNAL_MARGIN_PX);
    if render_total <= 0.0 {
        return Err(Error::Other(
            "the render is black over the Moon's disk".into(),
        ));
    }
    let ratio = real_total / render_total;
    let scaled = Raster::new(
        shifted.width,
        shifted.height,
        shifted.data.iter().map(|&v| v * ratio as f32).collect(),
    )?;
    let s_norm = ssim(real, &scaled, AMIE_DATA_RANGE)?;
    let s_raw = ssim(real, &shifted, AMIE_DATA_RANGE)?;
    let s_no_floor = ssim(&m.subtracted, &scaled, AMIE_DATA_RANGE)?;
    let relief_signal = match options.relief {
        Some(_) => flat_comparison(&obs, &choice, options, ecl.as_ref(), &m, &scaled)?,
        None => None,
    };

    let scene = &r.scene;
    let pin = &scene.camera.pinhole;
    let geometry = obs.scene.geometry_check();
    let phase_derived = geometry
        .phase_at_boresight_deg
        .unwrap_or(geometry.phase_at_centre_deg);
    let report = ValidationReport {
        product_id: obs.scene.label.product_id.clone(),
        image: path.display().to_string(),
        start_time_utc: obs.scene.label.start_time.clone(),
        model: choice,
        options: options.clone(),
        camera: CameraReport {
            resolution: [pin.width, pin.height],
            focal_length_m: scene.camera.focal_length,
            pixel_pitch_m: scene.camera.pixel_pitch,
            f_number: scene.camera.f_number,
            exposure_s: scene.camera.exposure,
            gain_dn_per_e: scene.camera.gain,
            full_well_e: scene.camera.full_well,
            bits: scene.camera.bits,
            band_nm: [BAND_M[0] * 1e9, BAND_M[1] * 1e9],
            response: format!("{} (assumed) x transmission 1", options.response.display()),
        },
        phase_label_deg: obs.scene.label.phase_angle_deg,
        phase_derived_deg: phase_derived,
        phase_at_centre_deg: geometry.phase_at_centre_deg,
        phase_error_deg: (phase_derived - obs.scene.label.phase_angle_deg).abs(),
        geometry,
        eclipse: ecl,
        render: r.images.summary.clone(),
        render_pixels_above_saturation: r.above_saturation,
        render_product: "float DN before quantisation and without saturation: electrons x gain (1/280 DN per e-)".into(),
        background_method: "background::remove_background with BackgroundParams::amie() (kappa-sigma-clipped quadratic sky + limb halo rings), \
                            fitted around the NCC-aligned disk; then pixels below 3 sky sigma set to 0 (noise floor)"
            .into(),
        background_params: m.params,
        background: m.background,
        predicted_disk: m.predicted,
        aligned_disk: m.aligned_disk,
        alignment: m.align,
        shift_px: m.align.dx.hypot(m.align.dy),
        real_total_dn: real_total,
        render_total_dn: render_total,
        total_signal_ratio: ratio,
        ssim_data_range: AMIE_DATA_RANGE,
        ssim: SsimScores::from(&s_norm),
        ssim_unnormalised: SsimScores::from(&s_raw),
        ssim_without_noise_floor: SsimScores::from(&s_no_floor),
        noise_floor_dn: m.floor as f64,
        ssim_disk: disk_scores(&s_norm, &m.aligned_disk, SIGNAL_MARGIN_PX),
        relief_signal,
    };
    Ok(ValidationRun {
        report,
        real: m.real,
        render: scaled,
        ssim: s_norm,
    })
}

/// [`relief_signal`] of the relief render `scaled` (aligned and scaled by
/// `m`) against a render of the same observation without relief, aligned
/// by the same shift and scaled to the same real total.
fn flat_comparison(
    obs: &AmieObservation,
    choice: &ModelChoice,
    options: &ValidationOptions,
    ecl: Option<&EclipseReport>,
    m: &Matched,
    scaled: &Raster,
) -> Result<Option<ReliefSignal>> {
    let flat = ValidationOptions {
        relief: None,
        ..options.clone()
    };
    let r = render_observation(obs, choice, &flat, ecl)?;
    let shifted = shift_bilinear(&r.dn, m.align.dx, m.align.dy, 0.0);
    let total = sum_within(&shifted, &m.aligned_disk, SIGNAL_MARGIN_PX);
    if total <= 0.0 {
        return Ok(None);
    }
    let k = (sum_within(&m.real, &m.aligned_disk, SIGNAL_MARGIN_PX) / total) as f32;
    let without = Raster::new(
        shifted.width,
        shifted.height,
        shifted.data.iter().map(|&v| v * k).collect(),
    )?;
    Ok(relief_signal(&m.real, scaled, &without, &m.aligned_disk))
}

/// The model's render of an AMIE observation, in float DN.
struct Rendered {
    scene: Scene,
    images: crate::render::detector::SceneImages,
    /// Electrons × gain: DN before quantisation and saturation.
    dn: Raster,
    /// Pixels of `dn` at or above the largest DN.
    above_saturation: usize,
}

fn render_observation(
    obs: &AmieObservation,
    choice: &ModelChoice,
    options: &ValidationOptions,
    ecl: Option<&EclipseReport>,
) -> Result<Rendered> {
    let scene = build_scene(obs, choice, options, ecl)?;
    let mut renderer = Renderer::new(scene.camera.render_pinhole().clone());
    let pixels = PixelGeometry::new(&renderer);
    let images = render_scene(&scene, &mut renderer, &pixels)?;
    let pin = &scene.camera.pinhole;
    let max_dn = scene.camera.max_dn() as f32;
    let gain = scene.camera.gain as f32;
    let dn = Raster::new(
        pin.width,
        pin.height,
        images.electrons.iter().map(|&e| e * gain).collect(),
    )?;
    let above_saturation = dn.data.iter().filter(|&&v| v >= max_dn).count();
    Ok(Rendered {
        scene,
        images,
        dn,
        above_saturation,
    })
}

/// The real image's background removed around the render's disk, and
/// where the render lands on it.
struct Matched {
    params: BackgroundParams,
    background: BackgroundModel,
    /// The image with the background removed.
    subtracted: Raster,
    /// The same with pixels below the noise floor set to 0.
    real: Raster,
    floor: f32,
    predicted: Disk,
    aligned_disk: Disk,
    align: Alignment,
}

/// Two passes: a provisional background with a widened predicted disk and
/// an alignment; then the background around the aligned disk and the
/// alignment again (±REFINE px about pass 1's integer shift).
fn match_to_image(obs: &AmieObservation, render: &Raster) -> Result<Matched> {
    let (centre, radius) = obs
        .scene
        .moon_disk_px()
        .ok_or_else(|| Error::Other("the Moon is behind the camera".into()))?;
    let predicted = Disk {
        cx: centre[0],
        cy: centre[1],
        radius,
    };
    let params = BackgroundParams::amie();
    let wide = Disk {
        radius: radius + DISK_MARGIN_PX,
        ..predicted
    };
    let (clean0, _) = remove_background(&obs.image, wide, &params)?;
    let window = crop_window(&predicted, render.width, render.height);
    let a0 = align_in(render, &clean0, window, (0, 0), MAX_SHIFT_PX)?;
    let disk1 = Disk {
        cx: predicted.cx + a0.dx,
        cy: predicted.cy + a0.dy,
        ..predicted
    };
    let (subtracted, background) = remove_background(&obs.image, disk1, &params)?;
    let floor = (NOISE_FLOOR_SIGMA * background.sky_sigma_dn) as f32;
    let real = Raster::new(
        subtracted.width,
        subtracted.height,
        subtracted
            .data
            .iter()
            .map(|&v| if v < floor { 0.0 } else { v })
            .collect(),
    )?;
    let align = align_in(render, &real, window, a0.integer_shift, REFINE_PX)?;
    let aligned_disk = Disk {
        cx: predicted.cx + align.dx,
        cy: predicted.cy + align.dy,
        ..predicted
    };
    Ok(Matched {
        params,
        background,
        subtracted,
        real,
        floor,
        predicted,
        aligned_disk,
        align,
    })
}

/// Writes `dir/comparison.png` (real, render, real − render and SSIM map
/// around the disk, with the numbers), `dir/profile.png` and
/// `dir/report.json`.
pub fn write_outputs(run: &ValidationRun, dir: impl AsRef<Path>) -> Result<()> {
    let dir = dir.as_ref();
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let r = &run.report;
    let cmp = figure::Comparison {
        real: &run.real,
        render: &run.render,
        ssim: &run.ssim,
        disk: r.aligned_disk,
        title: format!("{}, {}", r.product_id, r.model.name),
        notes: figure_notes(r),
    };
    figure::write_comparison_png(dir.join("comparison.png"), &cmp)?;
    figure::write_profile_png(dir.join("profile.png"), &cmp)?;
    let json =
        serde_json::to_string_pretty(&run.report).map_err(|e| Error::Other(e.to_string()))?;
    let p = dir.join("report.json");
    std::fs::write(&p, json).map_err(|e| Error::io(&p, e))
}
