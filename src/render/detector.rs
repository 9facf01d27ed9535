//! The detector chain of the paper's Eq. 2: collected flux → radiance
//! (W m⁻² sr⁻¹), electrons and quantised DN, with band integration,
//! exposure, full well, bits, gain and saturation counting.
//!
//! The radiance image is scene radiance: the mean over each pixel's exact
//! solid angle, with no optical falloff. The electron and DN images include
//! the camera's own cos⁴ falloff (exact pixel solid angle × the pupil's
//! projected area).

use std::time::Instant;

use serde::Serialize;

use super::{line_of_sight, BandModel, RenderStats, Renderer};
use crate::error::{Error, Result};
use crate::radiometry::lime::{Lime, LimeBand, LimeComparison, LunarGeometry};
use crate::radiometry::reflectance::Reflectance;
use crate::radiometry::spectrum::{
    band_integrals, electron_response, response_integral, BandIntegral,
};
use crate::scene::{Body, Scene, State};
use crate::sensor::{Sensor, SensorParams};

/// Images and figures of one rendered scene.
#[derive(Clone, Debug)]
pub struct SceneImages {
    /// Band-integrated radiance [W m⁻² sr⁻¹], row-major.
    pub radiance: Vec<f32>,
    /// Camera-effective radiance [W m⁻² sr⁻¹] (docs/SCENE.md): the band
    /// radiance of a solar-spectrum source giving the camera the same
    /// electron rate; equal to `radiance` for a spectrally flat body.
    pub radiance_effective: Vec<f32>,
    /// Electrons collected over the exposure, clipped at the full well.
    pub electrons: Vec<f32>,
    /// Mean electron rate per pixel [e⁻/s] (pupil and cos⁴ included, no
    /// clipping): what the sensor chain and `optistim expose` start from.
    pub electron_rate: Vec<f32>,
    /// Quantised DN: the ideal detector's, or the sensor chain's when the
    /// camera has `[camera.sensor]`.
    pub dn: Vec<u16>,
    /// Scalar results.
    pub summary: Summary,
}

/// Scalar results of a render (`summary.json`).
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    /// Phase angle at the body centre [deg].
    pub phase_angle_deg: f64,
    /// Σ L Ω cosθ over the image: the body's irradiance at the camera on a
    /// plane normal to the line of sight to its centre [W m⁻²].
    pub irradiance_at_pupil_w_m2: f64,
    /// Same, summed over all caps including those outside the image
    /// [W m⁻²].
    pub irradiance_all_caps_w_m2: f64,
    /// The camera-effective irradiance (below) over all caps, including
    /// those outside the image [W m⁻²].
    pub effective_irradiance_all_caps_w_m2: f64,
    /// Σ L_eff Ω cos θ over the image with the camera-effective radiance:
    /// the in-band irradiance of a solar-spectrum source giving the camera
    /// the same electron rate [W m⁻²].
    pub effective_irradiance_at_pupil_w_m2: f64,
    /// ∫ E(λ) R(λ) dλ / ∫ R(λ) dλ over the band, R = QE T λ/(hc): the
    /// response-weighted mean spectral irradiance at the pupil [W m⁻² nm⁻¹].
    pub response_weighted_irradiance_w_m2_nm: f64,
    /// Total electrons in the image.
    pub total_electrons: f64,
    /// Largest DN.
    pub max_dn: u32,
    /// Pixels at the full well or the largest DN.
    pub saturated_pixels: u64,
    /// Surface caps integrated.
    pub samples: u64,
    /// Wall-clock time of the render [ms].
    pub render_ms: f64,
    /// Wall-clock time of the PSF's convolution (and its kernel, the first
    /// time a process uses it) [ms], when the camera has one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub psf_ms: Option<f64>,
    /// Wall-clock time of the distortion's resampling (and its tables,
    /// the first time a process uses the lens) [ms], when the camera has
    /// one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub distortion_ms: Option<f64>,
    /// Sub-bands the band was split into.
    pub sub_bands: usize,
    /// Solar irradiance in band at 1 au [W m⁻²].
    pub band_irradiance_1au_w_m2: f64,
    /// Apparent angular radius of the body [deg].
    pub apparent_radius_deg: f64,
    /// Apparent radius [px] (at the principal point scale).
    pub apparent_radius_px: f64,
    /// The sensor chain's frame, when the camera has `[camera.sensor]`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sensor: Option<SensorSummary>,
    /// For a body marked `lime_reference`: LIME's disk irradiance over the
    /// band and the render's over it (`irradiance_all_caps_w_m2`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lime: Option<LimeComparison>,
    /// With a per-pixel error target: the settings the planner chose,
    /// their measured error and why ([`crate::planner`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub plan: Option<crate::fidelity::Plan>,
    /// For a body with `shadows`: whether the relief's cast shadows were
    /// applied and why ([`super::relief::decide_for_frame`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub relief_shadows: Option<super::relief::ShadowDecision>,
    /// With `[stars]`: the catalogue, epoch and the stars drawn.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stars: Option<crate::stars::StarSummary>,
}

/// What the sensor chain did (`summary.json`, `sensor`).
#[derive(Clone, Debug, Serialize)]
pub struct SensorSummary {
    /// The sensor's parameters.
    pub params: SensorParams,
    /// Frame index of the noise draw.
    pub frame: u64,
    /// Wall-clock time of the chain (the frame, and the maps the first
    /// time a process uses the camera) [ms].
    pub sensor_ms: f64,
}

/// Pixel solid angles and off-axis cosines of one camera, computed once.
pub struct PixelGeometry {
    /// Exact solid angle per pixel [sr].
    pub solid_angle: Vec<f32>,
}

impl PixelGeometry {
    /// Tables for a renderer's grid.
    pub fn new(renderer: &Renderer) -> Self {
        Self {
            solid_angle: renderer.camera().solid_angle_table(),
        }
    }
}

/// Split the band for the reflectance: once when spectrally flat (the
/// paper's saving), else in sub-bands of about 10 nm unless configured.
pub fn plan_bands(scene: &Scene) -> Vec<BandIntegral> {
    let cam = &scene.camera;
    let n = if scene.body.is_spectrally_flat() {
        1
    } else {
        scene
            .render
            .sub_bands
            .unwrap_or(((cam.band[1] - cam.band[0]) / 10e-9).ceil().max(1.0) as usize)
    };
    band_integrals(
        &scene.sun,
        &cam.quantum_efficiency,
        &cam.transmission,
        cam.band,
        n,
    )
}

/// What the sub-band at `wavelength` changes: `model` is the body's model
/// evaluated there. The albedo is w(λ) (spectral Hapke) or the model's,
/// times the albedo spectrum s(λ); a map is multiplied by s(λ), and by w(λ)
/// when w is a table (the map is then a relative pattern).
pub fn band_model<'a>(body: &Body, model: &'a Reflectance, wavelength: f64) -> BandModel<'a> {
    if body.is_spectrally_flat() {
        return BandModel::default();
    }
    let s = body.albedo_factor(wavelength);
    let w = body.reflectance.albedo_at(wavelength);
    let relative_map = body.reflectance.has_spectral_albedo();
    BandModel {
        model: Some(model),
        albedo: Some(w * s),
        map_scale: if relative_map { w * s } else { s },
    }
}

/// Render a scene through the whole chain.
pub fn render_scene(
    scene: &Scene,
    renderer: &mut Renderer,
    pixels: &PixelGeometry,
) -> Result<SceneImages> {
    let start = Instant::now();
    let cam = &scene.camera;
    let pin = &cam.pinhole;
    let grid = cam.render_pinhole();
    if renderer.camera() != grid {
        return Err(Error::Other(
            "renderer grid differs from the scene camera's render grid".into(),
        ));
    }
    let bands = plan_bands(scene);
    let mut spectral = render_bands(scene, renderer, pixels, &bands);
    let render_ms = start.elapsed().as_secs_f64() * 1e3;
    let psf_start = Instant::now();
    if let Some(psf) = &cam.psf {
        let kernel = crate::optics::psf::shared_kernel(psf)?;
        spectral.blur(&kernel, grid.width, grid.height, &pixels.solid_angle);
    }
    let psf_ms = cam
        .psf
        .as_ref()
        .map(|_| psf_start.elapsed().as_secs_f64() * 1e3);
    let distortion_start = Instant::now();
    let lens = cam.distortion.as_ref().map(|l| l.resampler()).transpose()?;
    let output = match &lens {
        Some(lens) => {
            spectral.distort(lens, &pixels.solid_angle);
            OutputPixels {
                solid_angle: &lens.solid_angle,
                direction: Some(&lens.direction),
            }
        }
        None => OutputPixels {
            solid_angle: &pixels.solid_angle,
            direction: None,
        },
    };
    let distortion_ms = lens
        .as_ref()
        .map(|_| distortion_start.elapsed().as_secs_f64() * 1e3);
    let band_irradiance: f64 = bands.iter().map(|b| b.irradiance_1au).sum();
    let band_electrons: f64 = bands.iter().map(|b| b.electron_rate_1au).sum();
    // L_eff = (∫ L R dλ) ∫E☉ / ∫E☉R; ∫ L R dλ = electron rate / Ω.
    let to_effective = if band_electrons > 0.0 {
        band_irradiance / band_electrons
    } else {
        0.0
    };
    let stars = match &scene.stars {
        Some(field) => Some(crate::stars::render(field, scene)?),
        None => None,
    };
    let star_rate = stars.as_ref().map(|s| s.electron_rate.as_slice());
    let mut d = detect(scene, &output, &spectral, to_effective, star_rate);
    let sensor = cam.sensor.map(|params| apply_sensor(scene, params, &mut d));
    let effective_all_caps = spectral.all_caps_electrons * to_effective;
    let range = (scene.state.camera_position - scene.state.body_position).length();
    let apparent = (scene.body.radius / range).asin();
    let response = response_integral(&cam.quantum_efficiency, &cam.transmission, cam.band);
    let response_weighted = if response > 0.0 {
        d.weighted / response * 1e-9
    } else {
        0.0
    };
    let images = SceneImages {
        radiance: spectral.radiance,
        radiance_effective: d.radiance_effective,
        electrons: d.electrons,
        electron_rate: d.electron_rate,
        dn: d.dn,
        summary: Summary {
            phase_angle_deg: spectral.stats.phase_angle.to_degrees(),
            irradiance_at_pupil_w_m2: d.irradiance,
            irradiance_all_caps_w_m2: spectral.all_caps,
            effective_irradiance_all_caps_w_m2: effective_all_caps,
            effective_irradiance_at_pupil_w_m2: d.effective_irradiance,
            response_weighted_irradiance_w_m2_nm: response_weighted,
            total_electrons: d.total_electrons,
            max_dn: d.peak_dn,
            saturated_pixels: d.saturated,
            samples: spectral.stats.caps,
            render_ms,
            psf_ms,
            distortion_ms,
            sub_bands: bands.len(),
            band_irradiance_1au_w_m2: band_irradiance,
            apparent_radius_deg: apparent.to_degrees(),
            apparent_radius_px: apparent.tan() * pin.fx,
            sensor,
            lime: lime_comparison(scene, spectral.all_caps, effective_all_caps),
            plan: None,
            relief_shadows: spectral.stats.shadows,
            stars: stars.map(|s| s.summary),
        },
    };
    images.check_finite()?;
    Ok(images)
}

/// The render summed over the sub-bands.
struct Spectral {
    /// Radiance [W m⁻² sr⁻¹].
    radiance: Vec<f32>,
    /// Electron rate per unit pupil area and exposure [e⁻ s⁻¹ m⁻²].
    electron_rate: Vec<f32>,
    /// Σ over every cap (also outside the image) [W m⁻²].
    all_caps: f64,
    /// The same in electrons [e⁻ s⁻¹ m⁻²].
    all_caps_electrons: f64,
    /// The last sub-band's statistics (phase, caps).
    stats: RenderStats,
    /// L Ω per unit electron rate when one band makes both images
    /// (E☉ / rate☉ of the band), else None.
    radiance_per_rate: Option<f32>,
    /// [x0, x1, y0, y1): both images are 0 outside it (the union of the
    /// bands' regions of interest, grown by the PSF; it may reach past
    /// the frame, which clips it).
    lit: [usize; 4],
}

impl Spectral {
    /// The optics' PSF: the pinhole image's power spread over the pixels
    /// (the light that leaves the frame is lost). The electron rate is a
    /// power per pixel and is convolved as it is; the radiance is the
    /// convolved power L Ω over each pixel's solid angle `omega`. With one
    /// band the two are the same image (L Ω = rate · E☉ / rate☉, the
    /// band's `radiance_per_rate`), so it is convolved once. The pixels'
    /// cos⁴ changes little over a kernel, so blurring before the detector
    /// equals blurring its electrons.
    fn blur(
        &mut self,
        kernel: &crate::optics::psf::Kernel,
        width: usize,
        height: usize,
        omega: &[f32],
    ) {
        let lit = self.lit;
        let rate_box = kernel.convolve_in_place_within(&mut self.electron_rate, width, height, lit);
        let power_image;
        let (power, scale, area) = match self.radiance_per_rate {
            Some(ratio) => (&self.electron_rate, ratio, rate_box),
            None => {
                let mut power: Vec<f32> = self
                    .radiance
                    .iter()
                    .zip(omega)
                    .map(|(l, o)| l * o)
                    .collect();
                let area = kernel.convolve_in_place_within(&mut power, width, height, lit);
                power_image = power;
                (&power_image, 1.0, area)
            }
        };
        // The radiance is written over in place: its old light (inside
        // `lit`) cleared, then the convolution's box filled.
        let [x0, x1, y0, y1] = lit;
        let x1 = x1.min(width);
        for y in y0..y1.min(height) {
            self.radiance[y * width + x0.min(x1)..y * width + x1].fill(0.0);
        }
        if let Some([x0, x1, y0, y1]) = area {
            for y in y0..y1 {
                let span = y * width + x0..y * width + x1;
                for ((l, &p), &o) in self.radiance[span.clone()]
                    .iter_mut()
                    .zip(&power[span.clone()])
                    .zip(&omega[span])
                {
                    *l = p * scale / o;
                }
            }
        }
        self.lit = union_box(rate_box, area);
    }

    /// The lens: the ideal grid's images resampled onto the camera's
    /// pixels. Radiance is conserved along rays, so it resamples as it
    /// is; the electron rate is a radiance times the pixel's solid angle,
    /// so it resamples divided by the ideal pixel's (`ideal_omega`) and
    /// is multiplied by the camera pixel's.
    fn distort(&mut self, lens: &crate::optics::distortion::Resampler, ideal_omega: &[f32]) {
        let per_sr: Vec<f32> = self
            .electron_rate
            .iter()
            .zip(ideal_omega)
            .map(|(&r, &o)| r / o)
            .collect();
        let [radiance, per_sr] = lens.resample_all([&self.radiance, &per_sr]);
        self.radiance = radiance;
        self.electron_rate = per_sr
            .iter()
            .zip(&lens.solid_angle)
            .map(|(&r, &o)| r * o)
            .collect();
        // Light may now be anywhere in the camera's frame.
        self.lit = [0, usize::MAX, 0, usize::MAX];
    }
}

/// The smallest box [x0, x1, y0, y1) holding both (an empty box for none).
fn union_box(a: Option<[usize; 4]>, b: Option<[usize; 4]>) -> [usize; 4] {
    match (a, b) {
        (Some(a), Some(b)) => [
            a[0].min(b[0]),
            a[1].max(b[1]),
            a[2].min(b[2]),
            a[3].max(b[3]),
        ],
        (Some(a), None) | (None, Some(a)) => a,
        (None, None) => [0, 0, 0, 0],
    }
}

/// The camera's pixels the detector reads out: their solid angles and,
/// through a lens, their centres' directions (else the pinhole's).
struct OutputPixels<'a> {
    solid_angle: &'a [f32],
    direction: Option<&'a [glam::DVec3]>,
}

/// Renders each sub-band at its own model and sums radiance and electron
/// rate over the bands.
fn render_bands(
    scene: &Scene,
    renderer: &mut Renderer,
    pixels: &PixelGeometry,
    bands: &[BandIntegral],
) -> Spectral {
    let grid = renderer.camera().clone();
    let n = grid.width * grid.height;
    let mut out = Spectral {
        radiance: vec![0.0f32; n],
        electron_rate: vec![0.0f32; n],
        all_caps: 0.0,
        all_caps_electrons: 0.0,
        stats: RenderStats::default(),
        radiance_per_rate: match bands {
            [band] if band.electron_rate_1au > 0.0 => {
                Some((band.irradiance_1au / band.electron_rate_1au) as f32)
            }
            _ => None,
        },
        lit: [0, 0, 0, 0],
    };
    if bands.len() > 1 {
        renderer.begin_sub_bands();
    }
    for band in bands {
        let model = scene.body.reflectance.at_wavelength(band.centroid);
        let band_model = band_model(&scene.body, &model, band.centroid);
        out.stats =
            renderer.render_flux_band(&scene.body, &scene.state, &scene.render, &band_model);
        out.all_caps += out.stats.total_flux * band.irradiance_1au;
        out.all_caps_electrons += out.stats.total_flux * band.electron_rate_1au;
        let flux = renderer.flux();
        let roi = out.stats.roi;
        let roi_box = (!roi.is_empty()).then_some([roi.x0, roi.x1, roi.y0, roi.y1]);
        out.lit = union_box((out.lit != [0; 4]).then_some(out.lit), roi_box);
        for row in roi.y0..roi.y1 {
            let span = row * grid.width + roi.x0..row * grid.width + roi.x1;
            let pixels = flux[span.clone()]
                .iter()
                .zip(&pixels.solid_angle[span.clone()])
                .zip(&mut out.radiance[span.clone()])
                .zip(&mut out.electron_rate[span]);
            for (((&f, &omega), radiance), rate) in pixels {
                let f = f as f64;
                *radiance += (band.irradiance_1au * f / omega as f64) as f32;
                *rate += (band.electron_rate_1au * f) as f32;
            }
        }
    }
    renderer.end_sub_bands();
    out
}

/// The detector's images and sums.
#[derive(Default)]
struct Detected {
    radiance_effective: Vec<f32>,
    electrons: Vec<f32>,
    electron_rate: Vec<f32>,
    dn: Vec<u16>,
    /// Σ L Ω cos θ [W m⁻²].
    irradiance: f64,
    /// Σ L_eff Ω cos θ [W m⁻²].
    effective_irradiance: f64,
    /// Σ electron rate × cos θ.
    weighted: f64,
    total_electrons: f64,
    saturated: u64,
    peak_dn: u32,
    /// [x0, x1, y0, y1): the pixels detected (lit by the body or a star);
    /// every other pixel's electron rate is 0.
    lit: [usize; 4],
}

/// Electrons (with the pupil's projected area: cos⁴ with the exact Ω),
/// plus the stars' electron rate if any, saturation and quantisation, and
/// the camera-effective radiance (of the body alone).
fn detect(
    scene: &Scene,
    pixels: &OutputPixels,
    spectral: &Spectral,
    to_effective: f64,
    stars: Option<&[f32]>,
) -> Detected {
    let cam = &scene.camera;
    let pin = &cam.pinhole;
    let n = pin.width * pin.height;
    let pupil = cam.pupil_area();
    let max_dn = cam.max_dn();
    let los = line_of_sight(&scene.state);
    let mut d = Detected {
        radiance_effective: vec![0.0f32; n],
        electrons: vec![0.0f32; n],
        electron_rate: vec![0.0f32; n],
        dn: vec![0u16; n],
        ..Default::default()
    };
    let (mut x0, mut x1, mut y0, mut y1) = (usize::MAX, 0, usize::MAX, 0);
    for j in 0..pin.height {
        for i in 0..pin.width {
            let k = j * pin.width + i;
            let star_rate = stars.map_or(0.0, |s| s[k] as f64);
            if spectral.radiance[k] == 0.0 && star_rate == 0.0 {
                continue;
            }
            (x0, x1) = (x0.min(i), x1.max(i + 1));
            (y0, y1) = (y0.min(j), j + 1);
            let dir = match pixels.direction {
                Some(d) => d[k],
                None => pin.pixel_direction(i, j),
            };
            let cos_los = dir.dot(los);
            let omega = pixels.solid_angle[k] as f64;
            let rate = spectral.electron_rate[k] as f64;
            d.irradiance += spectral.radiance[k] as f64 * omega * cos_los;
            let effective = rate * to_effective / omega;
            d.radiance_effective[k] = effective as f32;
            d.effective_irradiance += effective * omega * cos_los;
            d.weighted += rate * cos_los;
            let e_rate = pupil * dir.z * rate + star_rate;
            d.electron_rate[k] = e_rate as f32;
            let mut e = cam.exposure * e_rate;
            // Not `min`: a NaN must stay NaN for `check_finite` to see it.
            if e >= cam.full_well {
                e = cam.full_well;
            }
            let level = (e * cam.gain).round().min(max_dn);
            if e >= cam.full_well || level >= max_dn {
                d.saturated += 1;
            }
            d.electrons[k] = e as f32;
            d.total_electrons += e;
            d.dn[k] = level.min(u16::MAX as f64) as u16;
            d.peak_dn = d.peak_dn.max(level as u32);
        }
    }
    d.lit = if x0 < x1 { [x0, x1, y0, y1] } else { [0; 4] };
    d
}

/// Replaces the ideal detector's DN by the sensor chain's frame
/// `camera.sensor_frame`.
fn apply_sensor(scene: &Scene, params: SensorParams, d: &mut Detected) -> SensorSummary {
    let start = Instant::now();
    let cam = &scene.camera;
    let pin = &cam.pinhole;
    let sensor = Sensor::shared(params, cam.readout(), pin.width, pin.height);
    // The ideal detector's frame is written over: no new frame.
    d.dn.resize(d.electron_rate.len(), 0);
    let frame = sensor.expose_lit(
        &d.electron_rate,
        d.lit,
        cam.exposure,
        cam.sensor_frame,
        &mut d.dn,
    );
    d.saturated = frame.saturated;
    d.peak_dn = frame.peak_dn as u32;
    SensorSummary {
        params,
        frame: cam.sensor_frame,
        sensor_ms: start.elapsed().as_secs_f64() * 1e3,
    }
}

/// The render's disk irradiance against LIME, for a body that stands for
/// the Moon (`[body] lime_reference`); None otherwise or where LIME cannot
/// be evaluated (a band beyond its composite spectrum).
fn lime_comparison(
    scene: &Scene,
    all_caps: f64,
    effective_all_caps: f64,
) -> Option<LimeComparison> {
    if !scene.body.lime_reference {
        return None;
    }
    let s = &scene.state;
    let geometry = lunar_geometry(s)?;
    let lime = Lime::embedded();
    let band = lime.band(&scene.sun, scene.camera.band)?;
    let camera_band = lime_camera_band(scene);
    let camera = camera_band.as_ref().map(|b| (b, effective_all_caps));
    let mut comparison = lime.compare(&band, camera, geometry, all_caps)?;
    if s.occulter.is_some() {
        comparison
            .extrapolated
            .push("an occulter (eclipse) is in the scene; LIME has none".into());
    }
    Some(comparison)
}

/// LIME's geometry for `state`: the camera and the Sun in the body's
/// (Moon-fixed) frame.
pub fn lunar_geometry(state: &State) -> Option<LunarGeometry> {
    let to_body = state.body_attitude.inverse();
    LunarGeometry::from_moon_fixed(
        to_body * (state.camera_position - state.body_position),
        to_body * (state.sun_position - state.body_position),
    )
}

/// LIME's band as the scene's camera sees it (its QE × T electron
/// response), for camera-effective comparisons.
pub fn lime_camera_band(scene: &Scene) -> Option<LimeBand> {
    let cam = &scene.camera;
    Lime::embedded().camera_band(&scene.sun, cam.band, |l| {
        electron_response(&cam.quantum_efficiency, &cam.transmission, l)
    })
}

impl SceneImages {
    /// A render whose results are not all finite is an error, never a
    /// success with NaN: extreme but finite inputs can overflow a product.
    fn check_finite(&self) -> Result<()> {
        let s = &self.summary;
        let scalars = [
            ("irradiance_at_pupil_w_m2", s.irradiance_at_pupil_w_m2),
            ("irradiance_all_caps_w_m2", s.irradiance_all_caps_w_m2),
            (
                "effective_irradiance_all_caps_w_m2",
                s.effective_irradiance_all_caps_w_m2,
            ),
            (
                "effective_irradiance_at_pupil_w_m2",
                s.effective_irradiance_at_pupil_w_m2,
            ),
            (
                "response_weighted_irradiance_w_m2_nm",
                s.response_weighted_irradiance_w_m2_nm,
            ),
            ("total_electrons", s.total_electrons),
            ("band_irradiance_1au_w_m2", s.band_irradiance_1au_w_m2),
            ("apparent_radius_px", s.apparent_radius_px),
        ];
        let images = [
            ("radiance", &self.radiance),
            ("camera-effective radiance", &self.radiance_effective),
            ("electrons", &self.electrons),
            ("electron rate", &self.electron_rate),
        ];
        let bad = scalars
            .iter()
            .find(|(_, v)| !v.is_finite())
            .map(|(name, _)| *name)
            .or_else(|| {
                images
                    .iter()
                    .find(|(_, img)| img.iter().any(|v| !v.is_finite()))
                    .map(|(name, _)| *name)
            });
        match bad {
            Some(name) => Err(Error::Other(format!(
                "the render's {name} is not finite: the scene's values overflow (check the camera, Sun and body values)"
            ))),
            None => Ok(()),
        }
    }
}
