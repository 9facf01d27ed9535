//! Lens distortion applied to an ideal pinhole image: the Brown–Conrady
//! model of OpenCV, with the same file and numbers as the geometric
//! calibration's camera intrinsics
//! ([`CameraIntrinsics`](crate::instruments::intrinsics::CameraIntrinsics)).
//!
//! Each pixel of the distorted camera looks, through the lens, along the
//! directions its area undistorts to; radiance is conserved along a ray, so
//! the pixel's radiance is the mean of the ideal image's radiance over
//! `n × n` points of the pixel, each undistorted (Newton) and projected
//! into the ideal image (bilinear between its pixel centres). What a pixel
//! collects is that radiance times its own solid angle, which
//! [`pixel_solid_angles`] gives.

use glam::DVec3;
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::instruments::intrinsics::CameraIntrinsics;
use crate::scene::camera::Pinhole;

/// Largest supersampling per axis.
pub const MAX_SUPERSAMPLE: usize = 16;

/// The distorted camera's radiance image from the ideal `pinhole` image
/// `ideal` (radiance, row-major): `lens.width × lens.height` values. Points
/// whose direction falls outside the ideal image or does not undistort
/// count as 0 (dark sky): give an ideal image that covers the lens's field.
pub fn resample_radiance(
    ideal: &[f32],
    pinhole: &Pinhole,
    lens: &CameraIntrinsics,
    supersample: usize,
) -> Result<Vec<f32>> {
    if ideal.len() != pinhole.width * pinhole.height {
        return Err(Error::invalid(
            "camera.distortion",
            format!(
                "{} values for a {}×{} ideal image",
                ideal.len(),
                pinhole.width,
                pinhole.height
            ),
        ));
    }
    if !(1..=MAX_SUPERSAMPLE).contains(&supersample) {
        return Err(Error::invalid(
            "camera.distortion_supersample",
            format!("{supersample} is not in 1 … {MAX_SUPERSAMPLE}"),
        ));
    }
    lens.validate()?;
    let (w, n) = (lens.width, supersample);
    let mut out = vec![0.0f32; w * lens.height];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let mut sum = 0.0;
            for sy in 0..n {
                for sx in 0..n {
                    let u = x as f64 + (sx as f64 + 0.5) / n as f64;
                    let v = y as f64 + (sy as f64 + 0.5) / n as f64;
                    if let Some(d) = lens.pixel_to_direction(u, v) {
                        sum += bilinear(ideal, pinhole, pinhole.project(d));
                    }
                }
            }
            *o = (sum / (n * n) as f64) as f32;
        }
    });
    Ok(out)
}

/// The ideal image's radiance at continuous pixel coordinates (centres at
/// +0.5), bilinear between centres; 0 outside the image.
fn bilinear(img: &[f32], p: &Pinhole, (u, v): (f64, f64)) -> f64 {
    let (fx, fy) = (u - 0.5, v - 0.5);
    let (x0, y0) = (fx.floor(), fy.floor());
    let (tx, ty) = (fx - x0, fy - y0);
    let at = |x: f64, y: f64| {
        if x < 0.0 || y < 0.0 || x >= p.width as f64 || y >= p.height as f64 {
            0.0
        } else {
            img[y as usize * p.width + x as usize] as f64
        }
    };
    (1.0 - ty) * ((1.0 - tx) * at(x0, y0) + tx * at(x0 + 1.0, y0))
        + ty * ((1.0 - tx) * at(x0, y0 + 1.0) + tx * at(x0 + 1.0, y0 + 1.0))
}

/// Each distorted pixel's solid angle, sr: its four corners undistorted
/// into directions, the quadrilateral split into two spherical triangles
/// (0 where a corner does not undistort).
pub fn pixel_solid_angles(lens: &CameraIntrinsics) -> Vec<f64> {
    let w = lens.width;
    let corners: Vec<Option<DVec3>> = (0..(w + 1) * (lens.height + 1))
        .into_par_iter()
        .map(|k| lens.pixel_to_direction((k % (w + 1)) as f64, (k / (w + 1)) as f64))
        .collect();
    (0..w * lens.height)
        .into_par_iter()
        .map(|k| {
            let (x, y) = (k % w, k / w);
            let c = |dx: usize, dy: usize| corners[(y + dy) * (w + 1) + x + dx];
            match (c(0, 0), c(1, 0), c(1, 1), c(0, 1)) {
                (Some(a), Some(b), Some(cc), Some(d)) => {
                    spherical_triangle(a, b, cc) + spherical_triangle(a, cc, d)
                }
                _ => 0.0,
            }
        })
        .collect()
}

/// Solid angle of the spherical triangle of unit vectors a, b, c (Van
/// Oosterom and Strackee).
fn spherical_triangle(a: DVec3, b: DVec3, c: DVec3) -> f64 {
    let num = a.dot(b.cross(c)).abs();
    let den = 1.0 + a.dot(b) + b.dot(c) + c.dot(a);
    2.0 * num.atan2(den)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lens(k1: f64) -> CameraIntrinsics {
        CameraIntrinsics {
            width: 64,
            height: 48,
            camera_matrix: [[500.0, 0.0, 31.5], [0.0, 500.0, 23.5], [0.0, 0.0, 1.0]],
            distortion: [k1, 0.0, 0.0, 0.0, 0.0],
        }
    }

    /// Without distortion the same pinhole gives the same image back (a
    /// uniform one exactly, away from the edges).
    #[test]
    fn no_distortion_is_the_identity_on_a_uniform_field() {
        let p = Pinhole {
            width: 64,
            height: 48,
            fx: 500.0,
            fy: 500.0,
            cx: 32.0,
            cy: 24.0,
        };
        let img = vec![2.5f32; 64 * 48];
        let out = resample_radiance(&img, &p, &lens(0.0), 2).unwrap();
        for y in 1..47 {
            for x in 1..63 {
                assert!((out[y * 64 + x] - 2.5).abs() < 1e-6);
            }
        }
    }

    /// The pixels' solid angles add up to the field's: the frame's corners'
    /// directions bound it, and without distortion each pixel's is the
    /// pinhole's exact rectangle.
    #[test]
    fn solid_angles_without_distortion_match_the_rectangle_formula() {
        let om = pixel_solid_angles(&lens(0.0));
        let rect = crate::scene::camera::rectangle_solid_angle;
        let f = 500.0;
        let (x, y) = (10usize, 7usize);
        let exact = rect(
            (x as f64 - 32.0) / f,
            (x as f64 + 1.0 - 32.0) / f,
            (y as f64 - 24.0) / f,
            (y as f64 + 1.0 - 24.0) / f,
        );
        assert!((om[y * 64 + x] / exact - 1.0).abs() < 1e-9);
    }
}
