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

use super::{line_of_sight, RenderStats, Renderer};
use crate::error::{Error, Result};
use crate::radiometry::spectrum::{band_integrals, BandIntegral};
use crate::scene::Scene;

/// Images and figures of one rendered scene.
#[derive(Clone, Debug)]
pub struct SceneImages {
    /// Band-integrated radiance [W m⁻² sr⁻¹], row-major.
    pub radiance: Vec<f32>,
    /// Electrons collected over the exposure, clipped at the full well.
    pub electrons: Vec<f32>,
    /// Quantised DN.
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
    /// Sub-bands the band was split into.
    pub sub_bands: usize,
    /// Solar irradiance in band at 1 au [W m⁻²].
    pub band_irradiance_1au_w_m2: f64,
    /// Apparent angular radius of the body [deg].
    pub apparent_radius_deg: f64,
    /// Apparent radius [px] (at the principal point scale).
    pub apparent_radius_px: f64,
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
    let n = if scene.body.reflectance.is_spectrally_flat() {
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

/// Render a scene through the whole chain.
pub fn render_scene(
    scene: &Scene,
    renderer: &mut Renderer,
    pixels: &PixelGeometry,
) -> Result<SceneImages> {
    let start = Instant::now();
    let cam = &scene.camera;
    let pin = &cam.pinhole;
    if renderer.camera() != pin {
        return Err(Error::Other(
            "renderer grid differs from the scene camera".into(),
        ));
    }
    let n = pin.width * pin.height;
    let bands = plan_bands(scene);
    if bands.len() > 1 && scene.body.albedo_map.is_some() {
        return Err(Error::invalid(
            "body.albedo_map",
            "cannot be combined with a spectral reflectance",
        ));
    }
    let mut radiance = vec![0.0f32; n];
    let mut electron_rate = vec![0.0f32; n];
    let mut stats = RenderStats::default();
    let mut all_caps = 0.0;
    for band in &bands {
        let albedo = (bands.len() > 1).then(|| scene.body.reflectance.albedo_at(band.centroid));
        stats = renderer.render_flux(&scene.body, &scene.state, &scene.render, albedo);
        all_caps += stats.total_flux * band.irradiance_1au;
        let flux = renderer.flux();
        let roi = stats.roi;
        for row in roi.y0..roi.y1 {
            for i in row * pin.width + roi.x0..row * pin.width + roi.x1 {
                let f = flux[i] as f64;
                radiance[i] += (band.irradiance_1au * f / pixels.solid_angle[i] as f64) as f32;
                electron_rate[i] += (band.electron_rate_1au * f) as f32;
            }
        }
    }
    let render_ms = start.elapsed().as_secs_f64() * 1e3;

    // Electrons (with the pupil's projected area: cos⁴ with the exact Ω),
    // saturation and quantisation.
    let pupil = cam.pupil_area();
    let max_dn = cam.max_dn();
    let los = line_of_sight(&scene.state);
    let mut electrons = vec![0.0f32; n];
    let mut dn = vec![0u16; n];
    let mut total_electrons = 0.0;
    let mut saturated = 0u64;
    let mut peak_dn = 0u32;
    let mut irradiance = 0.0;
    for j in 0..pin.height {
        for i in 0..pin.width {
            let k = j * pin.width + i;
            if radiance[k] == 0.0 {
                continue;
            }
            let dir = pin.pixel_direction(i, j);
            irradiance += radiance[k] as f64 * pixels.solid_angle[k] as f64 * dir.dot(los);
            let mut e = cam.exposure * pupil * dir.z * electron_rate[k] as f64;
            if e >= cam.full_well {
                e = cam.full_well;
            }
            let level = (e * cam.gain).round().min(max_dn);
            if e >= cam.full_well || level >= max_dn {
                saturated += 1;
            }
            electrons[k] = e as f32;
            total_electrons += e;
            dn[k] = level.min(u16::MAX as f64) as u16;
            peak_dn = peak_dn.max(level as u32);
        }
    }
    let range = (scene.state.camera_position - scene.state.body_position).length();
    let apparent = (scene.body.radius / range).asin();
    Ok(SceneImages {
        radiance,
        electrons,
        dn,
        summary: Summary {
            phase_angle_deg: stats.phase_angle.to_degrees(),
            irradiance_at_pupil_w_m2: irradiance,
            irradiance_all_caps_w_m2: all_caps,
            total_electrons,
            max_dn: peak_dn,
            saturated_pixels: saturated,
            samples: stats.caps,
            render_ms,
            sub_bands: bands.len(),
            band_irradiance_1au_w_m2: bands.iter().map(|b| b.irradiance_1au).sum(),
            apparent_radius_deg: apparent.to_degrees(),
            apparent_radius_px: apparent.tan() * pin.fx,
        },
    })
}
