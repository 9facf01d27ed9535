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
//!
//! The render (`camera.distortion`, a [`Lens`]) draws the ideal image on a
//! pinhole grid with the camera's K extended to cover the distorted field,
//! then resamples it with a [`Resampler`]: the same sampling, with each
//! pixel's corners undistorted once per process and its sample points
//! interpolated bilinearly between them, tabulated as a sparse linear map
//! ([`super::lens_table`]). The interpolation moves a point by at most
//! 1/8 of the map's second derivative over a pixel, ≈ (3/4)·|k1|·r/fx px
//! at normalised radius r: 2·10⁻⁴ px at the corners of
//! tests/render_distortion.rs's lens (k1 = −0.21, r = 0.45, fx = 300 px),
//! 5·10⁻⁶ px for configs/bench_lens_intrinsics.toml.

use std::sync::Arc;

use glam::{DVec2, DVec3};
use rayon::prelude::*;

use super::lens_table::{undistort_grid, WeightTable};
use crate::error::{Error, Result};
use crate::instruments::intrinsics::CameraIntrinsics;
use crate::memo::Memo;
use crate::scene::camera::Pinhole;

/// Largest supersampling per axis.
pub const MAX_SUPERSAMPLE: usize = 16;
/// Pixels the ideal grid keeps beyond the distorted field on each side
/// (the bilinear lookup's neighbours, rounding).
const MARGIN_PX: f64 = 2.0;
/// The ideal grid may be at most this many times the image, per axis.
pub const MAX_GROWTH: f64 = 2.0;

/// A camera's lens distortion as the render applies it.
#[derive(Clone, Debug, PartialEq)]
pub struct Lens {
    /// The distorted camera: K and the Brown–Conrady coefficients.
    pub intrinsics: CameraIntrinsics,
    /// The ideal pinhole grid the renderer draws on: the camera's K
    /// extended to cover the distorted field.
    pub ideal: Pinhole,
    /// Sample points per pixel and axis of the resampling.
    pub supersample: usize,
}

impl Lens {
    /// The lens of `intrinsics`, resampled at `supersample`² points per
    /// pixel; errors if the distortion does not invert over the image or
    /// needs an ideal grid over [`MAX_GROWTH`] times the image.
    pub fn new(intrinsics: CameraIntrinsics, supersample: usize) -> Result<Lens> {
        intrinsics.validate()?;
        if !(1..=MAX_SUPERSAMPLE).contains(&supersample) {
            return Err(Error::invalid(
                "camera.distortion_supersample",
                format!("{supersample} is not in 1 … {MAX_SUPERSAMPLE}"),
            ));
        }
        let ideal = covering_pinhole(&intrinsics)?;
        Ok(Lens {
            intrinsics,
            ideal,
            supersample,
        })
    }

    /// The camera's own pinhole: K without the distortion, with this
    /// crate's pixel centres (OpenCV's cx → cx + 0.5).
    pub fn pinhole(&self) -> Pinhole {
        let (m, k) = (&self.intrinsics.camera_matrix, &self.intrinsics);
        Pinhole {
            width: k.width,
            height: k.height,
            fx: m[0][0],
            fy: m[1][1],
            cx: m[0][2] + 0.5,
            cy: m[1][2] + 0.5,
        }
    }

    /// The pixel (centres at +0.5) where the camera sees camera-frame
    /// direction `d` through the lens (OpenCV's distortion); None behind
    /// the camera or beyond the field the ideal grid covers, where the
    /// polynomial is not the lens (it can fold back into the image).
    pub fn project(&self, d: DVec3) -> Option<(f64, f64)> {
        if !(d.z > 0.0) {
            return None;
        }
        let (x, y) = self.ideal.project(d);
        let inside = (0.0..=self.ideal.width as f64).contains(&x)
            && (0.0..=self.ideal.height as f64).contains(&y);
        inside
            .then(|| self.intrinsics.direction_to_pixel(d))
            .flatten()
    }

    /// The lens's resampling tables, built once per process for the two
    /// most recent lenses.
    pub fn resampler(&self) -> Result<Arc<Resampler>> {
        static TABLES: Memo<Lens, Resampler> = Memo::new(2);
        TABLES.get_or_build(self.clone(), || Resampler::new(self))
    }
}

/// The ideal grid of `lens`: its K (same focal lengths), grown or shrunk
/// to the undistorted image of the frame's edge plus [`MARGIN_PX`]. The
/// distortion maps the frame's edge to the field's edge (it is invertible
/// over the frame, or `pixel_to_direction` fails and this errs).
fn covering_pinhole(lens: &CameraIntrinsics) -> Result<Pinhole> {
    let m = &lens.camera_matrix;
    let (fx, fy, cx, cy) = (m[0][0], m[1][1], m[0][2] + 0.5, m[1][2] + 0.5);
    let (w, h) = (lens.width, lens.height);
    let edge = (0..=w)
        .flat_map(|u| [(u, 0), (u, h)])
        .chain((0..=h).flat_map(|v| [(0, v), (w, v)]));
    let (mut u0, mut u1, mut v0, mut v1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for (u, v) in edge {
        let d = lens.pixel_to_direction(u as f64, v as f64).ok_or_else(|| {
            Error::invalid(
                "camera.distortion",
                format!("the distortion does not invert at the image's edge, pixel ({u}, {v})"),
            )
        })?;
        let (x, y) = (fx * d.x / d.z + cx, fy * d.y / d.z + cy);
        (u0, u1, v0, v1) = (u0.min(x), u1.max(x), v0.min(y), v1.max(y));
    }
    let (x0, y0) = ((u0 - MARGIN_PX).floor(), (v0 - MARGIN_PX).floor());
    let (width, height) = ((u1 + MARGIN_PX).ceil() - x0, (v1 + MARGIN_PX).ceil() - y0);
    if !(width <= MAX_GROWTH * w as f64 && height <= MAX_GROWTH * h as f64) {
        return Err(Error::invalid(
            "camera.distortion",
            format!(
                "the undistorted field needs a {width}×{height} px grid, over {MAX_GROWTH}× the {w}×{h} image: the distortion is too strong for this renderer"
            ),
        ));
    }
    Ok(Pinhole {
        width: width as usize,
        height: height as usize,
        fx,
        fy,
        cx: cx - x0,
        cy: cy - y0,
    })
}

/// What resampling through one lens needs, per output pixel.
pub struct Resampler {
    /// The resampling as a sparse linear map from the ideal grid's
    /// images to the camera's.
    pub table: WeightTable,
    /// Each pixel's solid angle [sr] ([`pixel_solid_angles`]).
    pub solid_angle: Vec<f32>,
    /// Each pixel centre's unit direction in the camera frame (zero where
    /// it does not undistort).
    pub direction: Vec<DVec3>,
}

/// Where each pixel corner of `lens` lies in its ideal image (continuous
/// pixel coordinates), `(width + 1) × (height + 1)`, and its direction;
/// None where it does not undistort.
fn ideal_corners(lens: &Lens) -> Vec<Option<(DVec2, (f64, f64))>> {
    let k = &lens.intrinsics;
    let p = &lens.ideal;
    undistort_grid(k, k.width + 1, k.height + 1, 0.0)
        .into_par_iter()
        .map(|m| m.map(|m| (m, (p.fx * m.x + p.cx, p.fy * m.y + p.cy))))
        .collect()
}

impl Resampler {
    fn new(lens: &Lens) -> Result<Resampler> {
        let k = &lens.intrinsics;
        let (w, h) = (k.width, k.height);
        let corners = ideal_corners(lens);
        let at: Vec<Option<(f64, f64)>> = corners.iter().map(|c| c.map(|c| c.1)).collect();
        let ideal = (lens.ideal.width, lens.ideal.height);
        let table = WeightTable::new(at, (w, h), ideal, lens.supersample)?;
        let corner_dirs: Vec<Option<DVec3>> = corners
            .iter()
            .map(|c| c.map(|(m, _)| m.extend(1.0).normalize()))
            .collect();
        let direction = undistort_grid(k, w, h, 0.5)
            .into_par_iter()
            .map(|m| m.map_or(DVec3::ZERO, |m| m.extend(1.0).normalize()))
            .collect();
        let solid_angle = quad_solid_angles(&corner_dirs, w, h)
            .iter()
            .map(|&o| o as f32)
            .collect();
        Ok(Resampler {
            table,
            solid_angle,
            direction,
        })
    }

    /// The distorted camera's radiance image from the ideal grid's
    /// `ideal` (radiance, row-major), as [`resample_radiance`]; pixels
    /// whose terms all lie beyond the ideal image's non-zero box stay 0
    /// without summing.
    pub fn resample(&self, ideal: &[f32]) -> Vec<f32> {
        let [out] = self.resample_all([ideal]);
        out
    }

    /// [`Resampler::resample`] of `N` images on the same ideal grid in one
    /// pass (the terms are shared).
    pub fn resample_all<const N: usize>(&self, images: [&[f32]; N]) -> [Vec<f32>; N] {
        self.table.apply(images)
    }
}

/// The resampling [`Resampler`] tabulates, done directly: each pixel's
/// corners placed in `lens`'s ideal grid, its `n²` sample points
/// interpolated between them and each read bilinearly from `ideal`. The
/// reference the table is tested against.
pub fn resample_direct(lens: &Lens, ideal: &[f32]) -> Vec<f32> {
    let (w, h, n) = (
        lens.intrinsics.width,
        lens.intrinsics.height,
        lens.supersample,
    );
    let corners = ideal_corners(lens);
    let inv = 1.0 / n as f64;
    let mut out = vec![0.0f32; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let c = |dx: usize, dy: usize| corners[(y + dy) * (w + 1) + x + dx].map(|c| c.1);
            let (Some(a), Some(b), Some(cc), Some(d)) = (c(0, 0), c(1, 0), c(0, 1), c(1, 1)) else {
                continue;
            };
            let mut sum = 0.0;
            for sy in 0..n {
                let t = (sy as f64 + 0.5) * inv;
                for sx in 0..n {
                    let s = (sx as f64 + 0.5) * inv;
                    let lerp = |p: f64, q: f64, r: f64, z: f64| {
                        (1.0 - t) * ((1.0 - s) * p + s * q) + t * ((1.0 - s) * r + s * z)
                    };
                    let at = (lerp(a.0, b.0, cc.0, d.0), lerp(a.1, b.1, cc.1, d.1));
                    sum += bilinear(ideal, &lens.ideal, at);
                }
            }
            *o = (sum * inv * inv) as f32;
        }
    });
    out
}

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
    quad_solid_angles(&corners, w, lens.height)
}

/// Solid angles of the `w × h` pixels whose corner directions are
/// `corners` ((w + 1) × (h + 1)): two spherical triangles each, 0 where a
/// corner is missing.
fn quad_solid_angles(corners: &[Option<DVec3>], w: usize, h: usize) -> Vec<f64> {
    (0..w * h)
        .into_par_iter()
        .map(|k| {
            let (x, y) = (k % w, k / w);
            let c = |dx: usize, dy: usize| corners[(y + dy) * (w + 1) + x + dx];
            match (c(0, 0), c(1, 0), c(1, 1), c(0, 1)) {
                (Some(a), Some(b), Some(cc), Some(d)) => {
                    // atan2(n₁, d₁) + atan2(n₂, d₂) in one atan2 (each
                    // triangle's half-angle is in [0, π/2)).
                    let (n1, d1) = triangle_tangent(a, b, cc);
                    let (n2, d2) = triangle_tangent(a, cc, d);
                    2.0 * (n1 * d2 + n2 * d1).atan2(d1 * d2 - n1 * n2)
                }
                _ => 0.0,
            }
        })
        .collect()
}

/// The spherical triangle of unit vectors a, b, c: its solid angle is
/// 2 atan2(num, den) of the returned (num, den) (Van Oosterom and
/// Strackee).
fn triangle_tangent(a: DVec3, b: DVec3, c: DVec3) -> (f64, f64) {
    let num = a.dot(b.cross(c)).abs();
    let den = 1.0 + a.dot(b) + b.dot(c) + c.dot(a);
    (num, den)
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

    /// The cached resampling (corners undistorted once, sample points
    /// interpolated between them) agrees with the exact one (every sample
    /// point undistorted) on a smooth image: points move by under
    /// (3/4)·|k1|·r/fx ≈ 7·10⁻⁴ px here, the image's gradient is under
    /// 1/7 + 1/5 per px, so values agree within 2.5·10⁻⁴.
    #[test]
    fn cached_resampling_matches_the_exact_one() {
        let k = CameraIntrinsics {
            width: 64,
            height: 48,
            camera_matrix: [[100.0, 0.0, 31.5], [0.0, 100.0, 23.5], [0.0, 0.0, 1.0]],
            distortion: [-0.3, 0.05, 1e-3, -1e-3, 0.0],
        };
        let lens = Lens::new(k.clone(), 3).unwrap();
        let p = &lens.ideal;
        assert!(p.width > 64 && p.height > 48, "barrel: a wider ideal grid");
        let img: Vec<f32> = (0..p.width * p.height)
            .map(|i| {
                let (x, y) = ((i % p.width) as f64, (i / p.width) as f64);
                (2.0 + (x / 7.0).sin() * (y / 5.0).cos()) as f32
            })
            .collect();
        let fast = lens.resampler().unwrap().resample(&img);
        let exact = resample_radiance(&img, p, &k, 3).unwrap();
        let worst = fast
            .iter()
            .zip(&exact)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(worst < 2.5e-4, "{worst}");
    }

    /// The weight table gives the direct resampling's image within f32
    /// rounding (its weights are f32, its sums f32: under 10⁻⁶ of the
    /// image's scale), on a smooth image filling the ideal grid and on a
    /// small blob, where the table skips every tile outside the blob's box.
    #[test]
    fn the_weight_table_equals_the_direct_resampling() {
        let k = CameraIntrinsics {
            width: 70,
            height: 45,
            camera_matrix: [[90.0, 0.0, 34.2], [0.0, 95.0, 22.8], [0.0, 0.0, 1.0]],
            distortion: [-0.3, 0.08, 2e-3, -1.5e-3, -0.01],
        };
        for n in [1, 3, 4] {
            let lens = Lens::new(k.clone(), n).unwrap();
            let p = &lens.ideal;
            let smooth: Vec<f32> = (0..p.width * p.height)
                .map(|i| {
                    let (x, y) = ((i % p.width) as f64, (i / p.width) as f64);
                    (2.0 + (x / 7.0).sin() * (y / 5.0).cos()) as f32
                })
                .collect();
            let mut blob = vec![0.0f32; p.width * p.height];
            for y in 30..36 {
                for x in 50..57 {
                    blob[y * p.width + x] = (1.0 + x as f32 * 0.1) * (y as f32 - 29.0);
                }
            }
            let resampler = Resampler::new(&lens).unwrap();
            let [a, b] = resampler.resample_all([&smooth, &blob]);
            for (table, img, scale) in [(a, &smooth, 3.0f32), (b, &blob, 40.0)] {
                let direct = resample_direct(&lens, img);
                let worst = table
                    .iter()
                    .zip(&direct)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0f32, f32::max);
                assert!(worst <= 1e-6 * scale, "n = {n}: {worst}");
                assert!(direct.iter().any(|&v| v != 0.0));
            }
            let mean = resampler.table.len() as f64 / (70.0 * 45.0);
            assert!((1.0..=9.0).contains(&mean), "{mean} terms per pixel");
        }
    }

    /// The fast undistortion (analytic Jacobian, warm starts) finds the
    /// same directions as the calibration's own Newton solve.
    #[test]
    fn the_grid_undistortion_matches_pixel_to_direction() {
        let k = CameraIntrinsics {
            width: 40,
            height: 30,
            camera_matrix: [[60.0, 0.0, 19.5], [0.0, 62.0, 14.5], [0.0, 0.0, 1.0]],
            distortion: [-0.25, 0.05, 1e-3, -2e-3, 0.01],
        };
        let grid = super::super::lens_table::undistort_grid(&k, 40, 30, 0.5);
        for (i, m) in grid.iter().enumerate() {
            let (u, v) = ((i % 40) as f64 + 0.5, (i / 40) as f64 + 0.5);
            let d = m.unwrap().extend(1.0).normalize();
            let e = k.pixel_to_direction(u, v).unwrap();
            assert!((d - e).length() < 1e-11, "({u}, {v})");
        }
    }

    /// Beyond the field the barrel polynomial folds back: x = 1.75 maps
    /// to 1.75 · (1 − 0.3 · 1.75²) = 0.142, inside the image, but the lens
    /// does not see it there; inside the field `project` is OpenCV's.
    #[test]
    fn project_refuses_the_folded_polynomial_beyond_the_field() {
        let k = CameraIntrinsics {
            width: 64,
            height: 48,
            camera_matrix: [[100.0, 0.0, 31.5], [0.0, 100.0, 23.5], [0.0, 0.0, 1.0]],
            distortion: [-0.3, 0.0, 0.0, 0.0, 0.0],
        };
        let lens = Lens::new(k.clone(), 2).unwrap();
        let far = DVec3::new(1.75, 0.0, 1.0);
        let (u, _) = k.direction_to_pixel(far).unwrap();
        assert!((u - (31.5 + 100.0 * 1.75 * (1.0 - 0.3 * 1.75 * 1.75) + 0.5)).abs() < 1e-9);
        assert!(
            u > 0.0 && u < 64.0,
            "the polynomial folds into the image: {u}"
        );
        assert_eq!(lens.project(far), None);
        let near = DVec3::new(0.2, -0.1, 1.0);
        assert_eq!(lens.project(near), k.direction_to_pixel(near));
        assert_eq!(lens.project(DVec3::new(0.0, 0.0, -1.0)), None);
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
