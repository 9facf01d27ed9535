//! Pinhole camera geometry: projection of camera-frame points to pixels, the
//! direction and exact solid angle of every pixel.
//!
//! Camera frame as in OpenCV: x right, y down, z along the boresight. Pixel
//! (0, 0) is the top-left pixel; pixel (i, j) covers the continuous pixel
//! coordinates [i, i+1) × [j, j+1), so its centre is at (i + 0.5, j + 0.5).

use glam::DVec3;

use crate::error::{Error, Result};

/// Pinhole projection with square or rectangular pixels.
#[derive(Clone, Debug, PartialEq)]
pub struct Pinhole {
    /// Image width [px].
    pub width: usize,
    /// Image height [px].
    pub height: usize,
    /// Focal length in pixels along x (focal length / pixel pitch).
    pub fx: f64,
    /// Focal length in pixels along y.
    pub fy: f64,
    /// Principal point, continuous pixel coordinates [px].
    pub cx: f64,
    /// Principal point, continuous pixel coordinates [px].
    pub cy: f64,
}

impl Pinhole {
    /// Continuous pixel coordinates of a camera-frame point in front of the
    /// camera (z > 0).
    #[inline]
    pub fn project(&self, p: DVec3) -> (f64, f64) {
        let inv_z = 1.0 / p.z;
        (
            self.fx * p.x * inv_z + self.cx,
            self.fy * p.y * inv_z + self.cy,
        )
    }

    /// Normalised image-plane coordinates (x/z, y/z) of a continuous pixel
    /// position.
    #[inline]
    pub fn normalised(&self, u: f64, v: f64) -> (f64, f64) {
        ((u - self.cx) / self.fx, (v - self.cy) / self.fy)
    }

    /// Unit direction (camera frame) through the centre of pixel (i, j).
    pub fn pixel_direction(&self, i: usize, j: usize) -> DVec3 {
        let (x, y) = self.normalised(i as f64 + 0.5, j as f64 + 0.5);
        DVec3::new(x, y, 1.0).normalize()
    }

    /// Exact solid angle of pixel (i, j) [sr]: the integral of
    /// dx dy / (1 + x² + y²)^{3/2} over the pixel's rectangle on the z = 1
    /// plane, in closed form.
    pub fn pixel_solid_angle(&self, i: usize, j: usize) -> f64 {
        let (x0, y0) = self.normalised(i as f64, j as f64);
        let (x1, y1) = self.normalised(i as f64 + 1.0, j as f64 + 1.0);
        rectangle_solid_angle(x0, x1, y0, y1)
    }

    /// Solid angles of all pixels, row-major, as f32.
    pub fn solid_angle_table(&self) -> Vec<f32> {
        use rayon::prelude::*;
        let mut table = vec![0.0f32; self.width * self.height];
        table
            .par_chunks_mut(self.width)
            .enumerate()
            .for_each(|(j, row)| {
                for (i, v) in row.iter_mut().enumerate() {
                    *v = self.pixel_solid_angle(i, j) as f32;
                }
            });
        table
    }
}

/// Solid angle of the rectangle [x0, x1] × [y0, y1] on the plane z = 1 seen
/// from the origin [sr].
pub fn rectangle_solid_angle(x0: f64, x1: f64, y0: f64, y1: f64) -> f64 {
    let f = |x: f64, y: f64| (x * y / (1.0 + x * x + y * y).sqrt()).atan();
    f(x1, y1) - f(x0, y1) - f(x1, y0) + f(x0, y0)
}

/// A point spread function.
#[derive(Debug, Clone, PartialEq)]
pub enum Psf {
    /// Circular Gaussian of standard deviation `sigma_px` pixels.
    Gaussian { sigma_px: f64 },
    /// Diffraction of a circular aperture of f-number `f_number` at
    /// wavelength `wavelength_m`, on pixels of pitch `pitch_m`.
    Airy {
        f_number: f64,
        wavelength_m: f64,
        pitch_m: f64,
    },
}

impl Psf {
    /// Range-checks the parameters (`key` names them in errors).
    pub fn validate(&self, key: &str) -> Result<()> {
        let ok = |v: f64, lo: f64, hi: f64| v.is_finite() && v > lo && v <= hi;
        match *self {
            Psf::Gaussian { sigma_px } if !ok(sigma_px, 0.0, 32.0) => Err(Error::invalid(
                key,
                format!("sigma_px {sigma_px} is not in (0, 32] px"),
            )),
            Psf::Airy {
                f_number,
                wavelength_m,
                pitch_m,
            } if !(ok(f_number, 0.0, 1e3)
                && ok(wavelength_m, 1e-8, 1e-4)
                && ok(pitch_m, 1e-7, 1e-3)) =>
            {
                Err(Error::invalid(
                    key,
                    format!(
                        "f_number {f_number}, wavelength {wavelength_m} m, pitch {pitch_m} m: \
                         need f-number in (0, 1000], wavelength in (10 nm, 100 µm], pitch in (0.1 µm, 1 mm]"
                    ),
                ))
            }
            _ => Ok(()),
        }
    }

    /// The fraction of a point source's power within radius `r_px` of its
    /// centre (the continuous PSF, closed form).
    pub fn encircled_energy(&self, r_px: f64) -> f64 {
        match *self {
            Psf::Gaussian { sigma_px } => 1.0 - (-0.5 * (r_px / sigma_px).powi(2)).exp(),
            Psf::Airy { .. } => {
                let x = std::f64::consts::PI * r_px / self.airy_scale_px();
                1.0 - libm::j0(x).powi(2) - libm::j1(x).powi(2)
            }
        }
    }

    /// λN in pixels: the Airy pattern's radial unit.
    pub fn airy_scale_px(&self) -> f64 {
        match *self {
            Psf::Airy {
                f_number,
                wavelength_m,
                pitch_m,
            } => wavelength_m * f_number / pitch_m,
            Psf::Gaussian { .. } => f64::NAN,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solid_angles_tile_the_field() {
        // The pixels of a 90° x 90° field must add up to the solid angle of
        // the square pyramid, 2π/3 (a cube face seen from its centre).
        let cam = Pinhole {
            width: 64,
            height: 64,
            fx: 32.0,
            fy: 32.0,
            cx: 32.0,
            cy: 32.0,
        };
        let total: f64 = cam.solid_angle_table().iter().map(|&v| v as f64).sum();
        assert!((total - 2.0 * std::f64::consts::PI / 3.0).abs() < 1e-5);
    }

    #[test]
    fn pixel_centres_project_to_half_integers() {
        let cam = Pinhole {
            width: 10,
            height: 8,
            fx: 100.0,
            fy: 100.0,
            cx: 5.0,
            cy: 4.0,
        };
        let d = cam.pixel_direction(0, 0);
        let (u, v) = cam.project(d);
        assert!((u - 0.5).abs() < 1e-12 && (v - 0.5).abs() < 1e-12);
        // +x right, +y down
        assert!(d.x < 0.0 && d.y < 0.0);
    }
}
