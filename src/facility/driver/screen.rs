//! What the camera sees on the screen: the screen-space renderer of the
//! facility loop ([`ScreenModel`]), the screen as a pinhole behind the
//! collimator, and the parts of the camera's band one frame renders.

use glam::DQuat;

use crate::facility::config::FacilityConfig;
use crate::facility::dither::Roi;
use crate::facility::geometry::{GeometryCalibration, PreWarp};
use crate::radiometry::lime::{Lime, LimeBand};
use crate::radiometry::reflectance::Reflectance;
use crate::radiometry::spectrum::band_integrals;
use crate::render::detector::{band_model, lime_camera_band, lunar_geometry};
use crate::render::field::{field_check, FieldCheck};
use crate::render::{BandModel, RenderSettings, Renderer};
use crate::scene::{Pinhole, Scene, State};

/// The static part of the screen-space renderer: what the camera sees on
/// the screen. Either the screen pinhole turned by `alignment.rotation`, or,
/// with a geometric calibration, an ideal pinhole grid pre-warped onto the
/// screen.
pub struct ScreenModel {
    renderer: Renderer,
    /// Screen pixels per rendered pixel along each axis (`screen.render_block`,
    /// or a governor rung's).
    block: usize,
    /// The renderer's settings: the scene's, or a governor rung's.
    settings: RenderSettings,
    solid_angle: Vec<f32>,
    /// What one frame renders: one band, or `drive.sub_bands` parts of the
    /// camera's band for a spectral body.
    bands: Vec<ScreenBand>,
    /// Σ over sub-bands of weight × flux, over the ROI (sub-bands > 1).
    accumulated: Vec<f64>,
    pub(super) screen: (usize, usize),
    rotation: f64,
    warp: Option<PreWarp>,
    /// Radiance over the rendered ROI, when it is not the screen's: the
    /// ideal grid of the pre-warp, or a grid of blocks.
    ideal_target: Vec<f32>,
    pub(super) roi_target: Vec<f32>,
    /// LIME's band in the flight camera's response, for a body marked
    /// `lime_reference`.
    lime: Option<LimeBand>,
    /// Camera-effective disk irradiance of the last render, over all caps
    /// [W m⁻²].
    effective_all_caps: f64,
    /// The last render's cast-shadow decision (its first band's).
    shadows: Option<crate::render::relief::ShadowDecision>,
    /// The screen ROI of the last render.
    last_roi: Option<Roi>,
}

/// One render of a frame: the body's model in a part of the camera's band,
/// and the weight that turns its flux per unit irradiance into
/// camera-effective radiance.
struct ScreenBand {
    model: Reflectance,
    albedo: Option<f64>,
    map_scale: f64,
    /// Band solar irradiance at 1 au × this part's share of the camera's
    /// electrons [W m⁻²].
    weight: f64,
}

/// The renders of one frame. A spectrally flat body, or `sub_bands` 1: one
/// render at the camera's electron-weighted wavelength (exact for a
/// reflectance linear across the band). Otherwise `sub_bands` equal parts,
/// each at its own centroid, weighted by its share of the electrons: the
/// camera-effective radiance L_eff = E_band Σ_k (e_k / e) f_k.
fn screen_bands(scene: &Scene, sub_bands: usize) -> Vec<ScreenBand> {
    let cam = &scene.camera;
    let whole = band_integrals(
        &scene.sun,
        &cam.quantum_efficiency,
        &cam.transmission,
        cam.band,
        1,
    );
    let e_band = whole[0].irradiance_1au;
    let band = |wavelength: f64, weight: f64| {
        let model = scene.body.reflectance.at_wavelength(wavelength);
        let b = band_model(&scene.body, &model, wavelength);
        let (albedo, map_scale) = (b.albedo, b.map_scale);
        ScreenBand {
            model,
            albedo,
            map_scale,
            weight,
        }
    };
    if scene.body.is_spectrally_flat() || sub_bands <= 1 {
        return vec![band(response_weighted_wavelength(scene), e_band)];
    }
    let parts = band_integrals(
        &scene.sun,
        &cam.quantum_efficiency,
        &cam.transmission,
        cam.band,
        sub_bands,
    );
    let electrons: f64 = parts.iter().map(|p| p.electron_rate_1au).sum();
    if electrons <= 0.0 {
        return vec![band(response_weighted_wavelength(scene), e_band)];
    }
    parts
        .iter()
        .filter(|p| p.electron_rate_1au > 0.0)
        .map(|p| band(p.centroid, e_band * p.electron_rate_1au / electrons))
        .collect()
}

/// The camera's electron-weighted mean wavelength over its band [m]: where
/// a single render stands for a spectral body.
fn response_weighted_wavelength(scene: &Scene) -> f64 {
    let cam = &scene.camera;
    let parts = band_integrals(
        &scene.sun,
        &cam.quantum_efficiency,
        &cam.transmission,
        cam.band,
        32,
    );
    let total: f64 = parts.iter().map(|b| b.electron_rate_1au).sum();
    if total > 0.0 {
        parts
            .iter()
            .map(|b| b.centroid * b.electron_rate_1au)
            .sum::<f64>()
            / total
    } else {
        0.5 * (cam.band[0] + cam.band[1])
    }
}

/// The screen as a pinhole camera behind the collimator.
pub fn screen_pinhole(config: &FacilityConfig) -> Pinhole {
    let [w, h] = config.screen.resolution;
    let f = config.collimator.focal_length / config.screen.pixel_pitch;
    Pinhole {
        width: w,
        height: h,
        fx: f,
        fy: f,
        cx: w as f64 / 2.0 + config.alignment.offset_px[0],
        cy: h as f64 / 2.0 + config.alignment.offset_px[1],
    }
}

/// The grid the renderer draws on without a geometric calibration: the
/// screen pinhole with `screen.render_block`² screen pixels per pixel.
/// Rendered pixel (I, J) covers screen pixels [bI, bI + b) × [bJ, bJ + b).
pub fn block_pinhole(config: &FacilityConfig) -> Pinhole {
    block_grid(config, config.screen.render_block)
}

/// The screen pinhole with `b`² screen pixels per rendered pixel.
fn block_grid(config: &FacilityConfig, b: usize) -> Pinhole {
    let screen = screen_pinhole(config);
    let b = b.max(1);
    let s = 1.0 / b as f64;
    Pinhole {
        width: screen.width.div_ceil(b),
        height: screen.height.div_ceil(b),
        fx: screen.fx * s,
        fy: screen.fy * s,
        cx: screen.cx * s,
        cy: screen.cy * s,
    }
}

impl ScreenModel {
    /// Builds the model of `config`'s screen for `scene`; `geometry` (the
    /// loaded `calibration.geometry`) replaces the screen pinhole and the
    /// alignment.
    pub fn new(
        config: &FacilityConfig,
        scene: &Scene,
        geometry: Option<&GeometryCalibration>,
    ) -> Self {
        let block = config.screen.render_block.max(1);
        Self::with_fidelity(config, scene, geometry, block, scene.render.clone())
    }

    /// The model rendering blocks of `block`² screen pixels with
    /// `settings` (a frame-time governor's rung).
    pub fn with_fidelity(
        config: &FacilityConfig,
        scene: &Scene,
        geometry: Option<&GeometryCalibration>,
        block: usize,
        settings: RenderSettings,
    ) -> Self {
        let block = block.max(1);
        let warp = geometry.map(|g| {
            let warp = PreWarp::with_block(g, block);
            let nominal = config.collimator.focal_length / config.screen.pixel_pitch;
            let f = warp.ideal_pinhole().fx * block as f64;
            if (f / nominal - 1.0).abs() > 0.05 {
                tracing::warn!(
                    file = %g.path().display(),
                    scale_px = f,
                    nominal_px = nominal,
                    "geometry file's scale differs from collimator.focal_length / screen.pixel_pitch by more than 5 %"
                );
            }
            warp
        });
        let pin = match &warp {
            Some(w) => w.ideal_pinhole().clone(),
            None => block_grid(config, block),
        };
        let camera_fx = scene.camera.pinhole.fx.min(scene.camera.pinhole.fy);
        if block > 1 && pin.fx < camera_fx {
            tracing::warn!(
                render_block = block,
                block_urad = 1e6 / pin.fx,
                camera_pixel_urad = 1e6 / camera_fx,
                "the camera's pixels are smaller than a render block: it resolves the blocks"
            );
        }
        let renderer = Renderer::new(pin.clone());
        let solid_angle = pin.solid_angle_table();
        // Build the albedo map's summed-area table and levels now, not in frame 0.
        if let Some(map) = &scene.body.albedo_map {
            map.box_average(0.0, 0.0, 1.0, 1.0);
            map.sample_stretched(0.0, 0.0, 4.0);
        }
        ScreenModel {
            renderer,
            block,
            settings,
            solid_angle,
            bands: screen_bands(scene, config.drive.sub_bands),
            accumulated: Vec::new(),
            screen: config.screen_size(),
            rotation: if warp.is_some() {
                0.0
            } else {
                config.alignment.rotation
            },
            warp,
            ideal_target: Vec::new(),
            roi_target: Vec::new(),
            lime: scene
                .body
                .lime_reference
                .then(|| lime_camera_band(scene))
                .flatten(),
            effective_all_caps: 0.0,
            shadows: None,
            last_roi: None,
        }
    }

    /// Whether the body of `scene` can be on the screen in `state` (the
    /// render grid, turned as [`render`](Self::render) turns it).
    pub fn field_check(&self, scene: &Scene, state: &State) -> FieldCheck {
        let mut st = *state;
        st.camera_attitude = state.camera_attitude * DQuat::from_rotation_z(self.rotation);
        field_check(self.renderer.camera(), &st, scene.body.radius)
    }

    /// The grid the renderer draws on: the screen pinhole, or the ideal
    /// grid of the pre-warp.
    pub fn render_grid(&self) -> &Pinhole {
        self.renderer.camera()
    }

    /// Renders the scene radiance [W m⁻² sr⁻¹] seen by the camera in
    /// `state` onto the screen; returns the screen ROI ([`target`](Self::target)
    /// holds its radiance, row-major) or None when nothing is visible.
    pub fn render(&mut self, scene: &Scene, state: &State) -> Option<Roi> {
        self.last_roi = self.render_roi(scene, state);
        self.last_roi
    }

    /// The screen ROI of the last [`render`](Self::render).
    pub fn last_roi(&self) -> Option<Roi> {
        self.last_roi
    }

    fn render_roi(&mut self, scene: &Scene, state: &State) -> Option<Roi> {
        let mut st = *state;
        // The screen's x axis is turned by `rotation` in the camera frame.
        st.camera_attitude = state.camera_attitude * DQuat::from_rotation_z(self.rotation);
        let r = self.render_bands(scene, &st);
        let w = self.renderer.camera().width;
        let out = if self.warp.is_some() || self.block > 1 {
            &mut self.ideal_target
        } else {
            &mut self.roi_target
        };
        out.clear();
        if let [one] = self.bands.as_slice() {
            let flux = self.renderer.flux();
            for row in r.y0..r.y1 {
                let k = row * w;
                out.extend(
                    flux[k + r.x0..k + r.x1]
                        .iter()
                        .zip(&self.solid_angle[k + r.x0..k + r.x1])
                        .map(|(&f, &o)| (one.weight * f as f64 / o as f64) as f32),
                );
            }
        } else {
            let mut acc = self.accumulated.iter();
            for row in r.y0..r.y1 {
                let k = row * w;
                out.extend(
                    self.solid_angle[k + r.x0..k + r.x1]
                        .iter()
                        .zip(acc.by_ref())
                        .map(|(&o, &f)| (f / o as f64) as f32),
                );
            }
        }
        let ideal = Roi::new(r.x0, r.y0, r.width(), r.height());
        match &mut self.warp {
            // Always called, so the previous frame's ideal radiance is cleared.
            Some(warp) => warp.apply(ideal, &self.ideal_target, &mut self.roi_target),
            None if r.is_empty() => None,
            None if self.block == 1 => Some(ideal),
            None => Some(expand_blocks(
                ideal,
                &self.ideal_target,
                self.block,
                self.screen,
                &mut self.roi_target,
            )),
        }
    }

    /// Renders every band of the frame; with several, sums weight × flux
    /// over the ROI into `accumulated`. Returns the ROI (on the render grid).
    fn render_bands(&mut self, scene: &Scene, st: &State) -> crate::render::caps::Rect {
        let w = self.renderer.camera().width;
        let mut roi = None;
        self.accumulated.clear();
        self.effective_all_caps = 0.0;
        self.shadows = None;
        if self.bands.len() > 1 {
            self.renderer.begin_sub_bands();
        }
        for (i, b) in self.bands.iter().enumerate() {
            let band = BandModel {
                model: Some(&b.model),
                albedo: b.albedo,
                map_scale: b.map_scale,
            };
            let stats = self
                .renderer
                .render_flux_band(&scene.body, st, &self.settings, &band);
            let r = *roi.get_or_insert(stats.roi);
            self.shadows = self.shadows.or(stats.shadows);
            self.effective_all_caps += b.weight * stats.total_flux;
            if self.bands.len() == 1 {
                break;
            }
            let flux = self.renderer.flux();
            let rows = (r.y0..r.y1).flat_map(|row| &flux[row * w + r.x0..row * w + r.x1]);
            if i == 0 {
                self.accumulated.extend(rows.map(|&f| b.weight * f as f64));
            } else {
                for (a, &f) in self.accumulated.iter_mut().zip(rows) {
                    *a += b.weight * f as f64;
                }
            }
        }
        self.renderer.end_sub_bands();
        roi.expect("at least one band")
    }

    /// The last [`render`](Self::render)'s camera-effective disk irradiance
    /// over LIME's at `state` (the state it rendered), for a body marked
    /// `lime_reference`; None otherwise or where it is not finite.
    pub fn render_over_lime(&self, state: &State) -> Option<f64> {
        let band = self.lime.as_ref()?;
        let geometry = lunar_geometry(state)?;
        let lime = Lime::embedded().disk_irradiance(band, &geometry);
        let ratio = self.effective_all_caps / lime;
        (lime > 0.0 && ratio.is_finite()).then_some(ratio)
    }

    /// The last [`render`](Self::render)'s cast-shadow decision, for a body
    /// with `[body] shadows` (None otherwise, or when nothing was
    /// rendered).
    pub fn shadows(&self) -> Option<crate::render::relief::ShadowDecision> {
        self.shadows
    }

    /// Screen radiance of the last [`render`](Self::render), row-major over
    /// its ROI.
    pub fn target(&self) -> &[f32] {
        &self.roi_target
    }
}

/// Spreads the radiance of rendered blocks (row-major over `blocks`, a
/// region of the block grid) over their screen pixels into `out`
/// (row-major over the returned screen region, clipped to the screen):
/// every pixel of a block shows the block's mean radiance, so each block
/// sends the flux that was integrated over it.
fn expand_blocks(
    blocks: Roi,
    radiance: &[f32],
    block: usize,
    screen: (usize, usize),
    out: &mut Vec<f32>,
) -> Roi {
    let x0 = blocks.x * block;
    let y0 = blocks.y * block;
    let x1 = ((blocks.x + blocks.width) * block).min(screen.0);
    let y1 = ((blocks.y + blocks.height) * block).min(screen.1);
    let roi = Roi::new(x0, y0, x1.saturating_sub(x0), y1.saturating_sub(y0));
    out.clear();
    out.reserve(roi.area());
    for y in y0..y1 {
        let src = &radiance[(y / block - blocks.y) * blocks.width..][..blocks.width];
        out.extend((x0..x1).map(|x| src[x / block - blocks.x]));
    }
    roi
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Blocks at the screen's bottom-right corner, the last ones cut by
    /// the screen edge (a body partly off screen): every visible pixel
    /// shows its own block's value and none is written past the edge.
    #[test]
    fn blocks_expand_onto_their_pixels_and_stop_at_the_screen_edge() {
        let screen = (7, 5);
        // Block grid of a 7 × 5 screen with blocks of 3: 3 × 2 blocks;
        // the region is blocks (1..3) × (0..2), values 10 · row + column.
        let blocks = Roi::new(1, 0, 2, 2);
        let radiance = [0.0, 1.0, 10.0, 11.0];
        let mut out = Vec::new();
        let roi = expand_blocks(blocks, &radiance, 3, screen, &mut out);
        assert_eq!(roi, Roi::new(3, 0, 4, 5));
        assert_eq!(out.len(), roi.area());
        for (k, &v) in out.iter().enumerate() {
            let (x, y) = (roi.x + k % roi.width, roi.y + k / roi.width);
            let expected = 10.0 * (y / 3) as f32 + (x / 3 - 1) as f32;
            assert_eq!(v, expected, "pixel ({x}, {y})");
        }
    }
}
