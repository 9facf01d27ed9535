//! What a campaign gets from the facility camera's own calibration lab,
//! with stated uncertainties: not the truth. Each product's error is drawn
//! from the seed within the declared uncertainty of `[lab]` (k = 2, i.e. the
//! error's standard deviation is half of it):
//!
//! * `intrinsics.toml`: the intrinsics file `calibrate.camera.intrinsics`
//!   reads (OpenCV's K and k1, k2, p1, p2, k3, pixel centres at integers),
//!   fx, fy, cx, cy and k1 off by their draws, the uncertainties in comments;
//! * `camera_flat.tif` (+ `camera_flat.toml`): vignetting × PRNU measured
//!   with per-pixel noise and a low-order error (tilt and bowl);
//! * `responsivity.toml`: DN/s per W m⁻² sr⁻¹ of camera-effective radiance
//!   at the camera's entrance, averaged over a central region.
//!
//! Camera-effective radiance at the camera's entrance (after the
//! collimator) is L_eff = τ ∫ S R dλ · ∫_band E☉ dλ / ∫_band E☉ R dλ with R =
//! QE · T · λ / (h c) over the camera's band (src/calibration/mismatch.rs):
//! the radiance of a Sun-shaped spectrum giving the same electrons. The
//! responsivity is gain · ⟨A_pupil Ω cos θ · g⟩_region · ∫ E☉ R / ∫ E☉: the
//! small-signal slope (below the non-linearity), direct light only (the
//! veiling-glare pedestal is extra).

use std::path::{Path, PathBuf};

use super::noise::Rng;
use super::SimFacility;
use crate::error::{Error, Result};
use crate::facility::lut::FlatField;

/// Random stream of the lab's errors.
const LAB_STREAM: u64 = 4;
/// Random stream of the lab flat's per-pixel noise.
const LAB_FLAT_STREAM: u64 = 5;
/// Side of the central region of the responsivity, px.
const REGION_SIDE: usize = 16;

/// The files written.
#[derive(Debug, Clone)]
pub struct LabFiles {
    pub intrinsics: PathBuf,
    pub camera_flat: PathBuf,
    pub camera_flat_uncertainty: PathBuf,
    pub responsivity: PathBuf,
}

impl SimFacility {
    /// Writes the camera's lab products into `dir` (created).
    pub fn write_lab_camera_files(&self, dir: &Path) -> Result<LabFiles> {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        let mut rng = Rng::new(self.model.cfg.seed, LAB_STREAM, 0);
        let files = LabFiles {
            intrinsics: dir.join("intrinsics.toml"),
            camera_flat: dir.join("camera_flat.tif"),
            camera_flat_uncertainty: dir.join("camera_flat.toml"),
            responsivity: dir.join("responsivity.toml"),
        };
        self.write_lab_intrinsics(&files.intrinsics, &mut rng)?;
        self.write_lab_flat(&files.camera_flat, &files.camera_flat_uncertainty, &mut rng)?;
        self.write_lab_responsivity(&files.responsivity, &mut rng)?;
        Ok(files)
    }

    fn write_lab_intrinsics(&self, path: &Path, rng: &mut Rng) -> Result<()> {
        let c = &self.model.cfg.camera;
        let lab = &self.model.cfg.lab;
        let focal = lab.focal_k2_percent / 100.0 / 2.0;
        let pp = lab.principal_point_k2_px / 2.0;
        let fx = c.fx * (1.0 + focal * rng.normal());
        let fy = c.fy * (1.0 + focal * rng.normal());
        let cx = c.cx - 0.5 + pp * rng.normal();
        let cy = c.cy - 0.5 + pp * rng.normal();
        let k1 = c.k1 + lab.k1_k2 / 2.0 * rng.normal();
        let text = format!(
            "# Facility camera intrinsics from its calibration lab (simulated): OpenCV\n\
             # model, cx, cy with pixel centres at integers.\n\
             # Uncertainty (k = 2): fx, fy {} %; cx, cy {} px; k1 {}; k2, p1, p2 exact.\n\
             width = {}\nheight = {}\n\
             camera_matrix = [[{fx:?}, 0.0, {cx:?}],\n                 [0.0, {fy:?}, {cy:?}],\n                 [0.0, 0.0, 1.0]]\n\
             distortion = [{k1:?}, {:?}, {:?}, {:?}, 0.0]\n",
            lab.focal_k2_percent,
            lab.principal_point_k2_px,
            lab.k1_k2,
            c.resolution[0],
            c.resolution[1],
            c.k2,
            c.p1,
            c.p2
        );
        std::fs::write(path, text).map_err(|e| Error::io(path, e))
    }

    /// The lab flat: truth × (1 + noise N_k) × (1 + a_x n_x + a_y n_y +
    /// a_b (n_x² + n_y² − 2/3)), n relative to the image centre (−1 … 1).
    fn write_lab_flat(&self, tif: &Path, toml: &Path, rng: &mut Rng) -> Result<()> {
        let c = &self.model.cfg.camera;
        let lab = &self.model.cfg.lab;
        let [w, h] = c.resolution;
        let s = lab.flat_low_order_k2 / 2.0;
        let (ax, ay, ab) = (s * rng.normal(), s * rng.normal(), s * rng.normal());
        let seed = self.model.cfg.seed;
        let gains: Vec<f32> = self
            .model
            .camera
            .flat()
            .iter()
            .enumerate()
            .map(|(k, &g)| {
                let nx = ((k % w) as f64 + 0.5) / (0.5 * w as f64) - 1.0;
                let ny = ((k / w) as f64 + 0.5) / (0.5 * h as f64) - 1.0;
                let low = 1.0 + ax * nx + ay * ny + ab * (nx * nx + ny * ny - 2.0 / 3.0);
                let noise =
                    1.0 + lab.flat_pixel_noise * Rng::new(seed, LAB_FLAT_STREAM, k as u64).normal();
                (g as f64 * low * noise) as f32
            })
            .collect();
        FlatField::from_gains(w, h, gains)?.save(tif)?;
        let text = format!(
            "# Uncertainty of {} (the camera's own flat, vignetting x PRNU, from its lab).\n\
             pixel_noise_rms = {:?}        # relative, per pixel\n\
             low_order_k2 = {:?}           # relative, k = 2: tilt and bowl across the image\n",
            tif.file_name().unwrap_or_default().to_string_lossy(),
            lab.flat_pixel_noise,
            lab.flat_low_order_k2
        );
        std::fs::write(toml, text).map_err(|e| Error::io(toml, e))
    }

    /// The true responsivity (DN/s per W m⁻² sr⁻¹ of camera-effective
    /// radiance at the camera's entrance) averaged over the central
    /// region `[x0, y0, w, h]`: for tests only.
    pub fn true_responsivity(&self) -> (f64, [usize; 4]) {
        let m = &self.model;
        let [w, h] = m.cfg.camera.resolution;
        let (rw, rh) = (REGION_SIDE.min(w), REGION_SIDE.min(h));
        let (x0, y0) = ((w - rw) / 2, (h - rh) / 2);
        let flat = m.camera.flat();
        let mut sum = 0.0;
        for y in y0..y0 + rh {
            for x in x0..x0 + rw {
                let k = y * w + x;
                sum += m.camera.etendue()[k] * flat[k] as f64;
            }
        }
        let mean = sum / (rw * rh) as f64;
        (
            m.cfg.camera.gain * mean / m.effective_per_rate,
            [x0, y0, rw, rh],
        )
    }

    fn write_lab_responsivity(&self, path: &Path, rng: &mut Rng) -> Result<()> {
        let lab = &self.model.cfg.lab;
        let (truth, [x0, y0, rw, rh]) = self.true_responsivity();
        let r = truth * (1.0 + lab.responsivity_k2_percent / 100.0 / 2.0 * rng.normal());
        let text = format!(
            "# Absolute responsivity of the facility camera from its lab (simulated):\n\
             # DN/s per W m-2 sr-1 of camera-effective radiance at the camera's entrance\n\
             # (after the collimator; docs/SIMFACILITY.md), the mean over region_px\n\
             # (x0, y0, width, height; pixel (x, y) covers [x, x+1) x [y, y+1)),\n\
             # small-signal (below the non-linearity), direct light (no veiling glare),\n\
             # with the camera's own flat in it.\n\
             responsivity_dn_per_s_per_w_m2_sr = {r:?}\n\
             uncertainty_k2_percent = {:?}\n\
             region_px = [{x0}, {y0}, {rw}, {rh}]\n",
            lab.responsivity_k2_percent
        );
        std::fs::write(path, text).map_err(|e| Error::io(path, e))
    }
}
