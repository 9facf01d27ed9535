//! Exact labels of a rendered frame, from the analytic scene (pinhole camera,
//! spherical body, Sun, optional occulter) without a second render: per-pixel
//! masks, depth, normals and body-fixed latitude/longitude by one ray per
//! pixel centre, and the body's projected disk (centre, limb ellipse, radius,
//! limb points, bounding box) and the poses in closed form. [`files`] writes
//! them (TIFF, `labels.json`, COCO); docs/DATASETS.md documents the formats.
//! Through a lens ([`compute_through`]) the rays are the lens's undistorted
//! pixel directions and the disk is distorted ([`lens`]).
//!
//! The body is the reference sphere of radius `body.radius`: a displacement
//! map moves the rendered limb by its heights, the labels do not.

pub mod files;
pub mod geometry;
pub mod lens;

use glam::{DQuat, DVec3};
use rayon::prelude::*;
use serde::Serialize;

use crate::scene::{Pinhole, State};
pub use geometry::{limb_ellipse, ray_sphere, Ellipse};

/// Schema name and version written into every `labels.json`.
pub const SCHEMA: &str = "optistim-labels/1";

/// Limb points listed per frame (evenly spaced around the limb circle).
pub const LIMB_POINTS: usize = 64;

/// Per-pixel label images, row-major, `width × height`; values outside the
/// body are 0 (the body mask tells them apart).
#[derive(Clone, Debug, PartialEq)]
pub struct LabelImages {
    /// Image width [px].
    pub width: usize,
    /// Image height [px].
    pub height: usize,
    /// 1 where the pixel centre's ray hits the body.
    pub body: Vec<u8>,
    /// 1 where the hit point faces the Sun's centre (cos incidence > 0).
    pub lit: Vec<u8>,
    /// 1 where the hit point faces the Sun but the occulter hides the Sun's
    /// centre from it (always 0 without an occulter).
    pub shadow: Vec<u8>,
    /// Range from the camera centre to the hit point along the ray [m].
    pub depth: Vec<f32>,
    /// Outward unit surface normal, world frame, interleaved x, y, z.
    pub normals: Vec<f32>,
    /// Body-fixed (selenographic for the Moon) latitude [rad].
    pub latitude: Vec<f32>,
    /// Body-fixed east longitude in (−π, π] [rad].
    pub longitude: Vec<f32>,
}

/// A pose: position [m] and the rotation of the object's vectors into the
/// world frame (scalar-first quaternion).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Pose {
    /// Position, world frame [m].
    pub position: [f64; 3],
    /// Attitude [w, x, y, z].
    pub attitude: [f64; 4],
}

impl Pose {
    fn new(position: DVec3, attitude: DQuat) -> Pose {
        Pose {
            position: position.to_array(),
            attitude: [attitude.w, attitude.x, attitude.y, attitude.z],
        }
    }
}

/// The poses of camera, body and Sun (the Sun's attitude is the identity).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Poses {
    /// Camera (x right, y down, z boresight).
    pub camera: Pose,
    /// Body (+z north pole, +x longitude 0).
    pub body: Pose,
    /// Sun.
    pub sun: Pose,
}

/// The body's projected disk, in continuous pixel coordinates
/// (docs/CONVENTIONS.md: the centre of pixel (0, 0) is (0.5, 0.5)).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Disk {
    /// Projection of the body's centre [px]; None when it is behind the
    /// camera.
    pub projected_centre: Option<[f64; 2]>,
    /// The limb's image: an ellipse when the whole limb is in front of
    /// the camera.
    pub limb_ellipse: Option<Ellipse>,
    /// Apparent angular radius asin(R / range) [rad].
    pub apparent_radius_rad: f64,
    /// fx · tan(apparent radius) [px]: the disk's radius at the principal
    /// point.
    pub apparent_radius_px: f64,
    /// Range from the camera to the body's centre [m].
    pub range_m: f64,
    /// Limb points in front of the camera [px] (may lie outside the image).
    pub limb_points: Vec<[f64; 2]>,
    /// Bounding box of the body in the image, COCO order [x, y, w, h]
    /// [px]: the limb ellipse's box clipped to the image, else the body
    /// mask's pixels; None when the body is not in the image.
    pub bbox: Option<[f64; 4]>,
}

/// Everything `labels.json` holds besides the file names.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FrameLabels {
    /// Image width [px].
    pub width: usize,
    /// Image height [px].
    pub height: usize,
    /// Epoch text of the scene, if it has one.
    pub epoch: Option<String>,
    /// Poses of camera, body and Sun.
    pub poses: Poses,
    /// Body radius [m].
    pub body_radius_m: f64,
    /// Phase angle at the body centre [rad].
    pub phase_angle_rad: f64,
    /// The projected disk.
    pub disk: Disk,
    /// Pixels in the body, lit and shadow masks.
    pub pixel_counts: PixelCounts,
    /// The catalogue stars whose direction falls in the image (`[stars]`;
    /// [`add_stars`]), drawn or hidden by the body.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub stars: Vec<crate::stars::ProjectedStar>,
}

/// Adds to `labels` the stars of `scene` (if it has `[stars]`) whose
/// direction falls in the image: catalogue id, position [px], V, electron
/// rate and whether the body hides them; the same projection the render
/// draws them with.
pub fn add_stars(labels: &mut Labels, scene: &crate::scene::Scene) {
    if let Some(field) = &scene.stars {
        labels.frame.stars = crate::stars::project(field, scene, 0.0);
    }
}

/// Counts of set pixels per mask.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct PixelCounts {
    /// Body mask.
    pub body: u64,
    /// Lit mask.
    pub lit: u64,
    /// Shadow mask.
    pub shadow: u64,
}

/// Labels of one frame: images and the record.
#[derive(Clone, Debug, PartialEq)]
pub struct Labels {
    /// Per-pixel images.
    pub images: LabelImages,
    /// Scalars, poses and the disk.
    pub frame: FrameLabels,
}

/// Computes the labels of the frame `camera` sees of a sphere of `radius`
/// in `state`.
pub fn compute(camera: &Pinhole, state: &State, radius: f64, epoch: Option<String>) -> Labels {
    let images = pixel_labels(camera.width, camera.height, state, radius, |i, j| {
        Some(camera.pixel_direction(i, j))
    });
    let disk = disk(camera, state, radius, &images.body);
    frame_labels(images, disk, state, radius, epoch)
}

/// Computes the labels of the frame a camera with `lens` sees: each
/// pixel centre's ray is the direction the lens undistorts it to (the
/// render's own, [`crate::optics::distortion::Resampler`]), and the disk's
/// centre, limb points and box are distorted through the lens
/// ([`lens::disk`]).
pub fn compute_through(
    lens: &crate::optics::distortion::Lens,
    state: &State,
    radius: f64,
    epoch: Option<String>,
) -> crate::error::Result<Labels> {
    let tables = lens.resampler()?;
    let (w, h) = (lens.intrinsics.width, lens.intrinsics.height);
    let images = pixel_labels(w, h, state, radius, |i, j| {
        let d = tables.direction[j * w + i];
        (d != DVec3::ZERO).then_some(d)
    });
    let disk = lens::disk(lens, state, radius, &images.body);
    Ok(frame_labels(images, disk, state, radius, epoch))
}

/// The labels of the scene's camera, through its lens if it has one.
pub fn compute_for(
    camera: &crate::scene::Camera,
    state: &State,
    radius: f64,
    epoch: Option<String>,
) -> crate::error::Result<Labels> {
    match &camera.distortion {
        Some(lens) => compute_through(lens, state, radius, epoch),
        None => Ok(compute(&camera.pinhole, state, radius, epoch)),
    }
}

/// The record of a frame around its images and disk.
fn frame_labels(
    images: LabelImages,
    disk: Disk,
    state: &State,
    radius: f64,
    epoch: Option<String>,
) -> Labels {
    let count = |m: &[u8]| m.iter().map(|&v| v as u64).sum();
    let pixel_counts = PixelCounts {
        body: count(&images.body),
        lit: count(&images.lit),
        shadow: count(&images.shadow),
    };
    let to_sun = state.sun_position - state.body_position;
    let to_cam = state.camera_position - state.body_position;
    let frame = FrameLabels {
        width: images.width,
        height: images.height,
        epoch,
        poses: Poses {
            camera: Pose::new(state.camera_position, state.camera_attitude),
            body: Pose::new(state.body_position, state.body_attitude),
            sun: Pose::new(state.sun_position, DQuat::IDENTITY),
        },
        body_radius_m: radius,
        phase_angle_rad: to_sun.angle_between(to_cam),
        disk,
        pixel_counts,
        stars: Vec::new(),
    };
    Labels { images, frame }
}

/// One ray per pixel centre against the sphere: pixel (i, j) looks along
/// camera-frame `direction(i, j)` (None: it sees nothing).
fn pixel_labels(
    w: usize,
    h: usize,
    state: &State,
    radius: f64,
    direction: impl Fn(usize, usize) -> Option<DVec3> + Sync,
) -> LabelImages {
    let mut images = LabelImages {
        width: w,
        height: h,
        body: vec![0; w * h],
        lit: vec![0; w * h],
        shadow: vec![0; w * h],
        depth: vec![0.0; w * h],
        normals: vec![0.0; 3 * w * h],
        latitude: vec![0.0; w * h],
        longitude: vec![0.0; w * h],
    };
    let to_body = state.body_attitude.inverse();
    let rows = images
        .body
        .par_chunks_mut(w)
        .zip(images.lit.par_chunks_mut(w))
        .zip(images.shadow.par_chunks_mut(w))
        .zip(images.depth.par_chunks_mut(w))
        .zip(images.normals.par_chunks_mut(3 * w))
        .zip(images.latitude.par_chunks_mut(w))
        .zip(images.longitude.par_chunks_mut(w));
    rows.enumerate().for_each(
        |(j, ((((((body, lit), shadow), depth), normals), lat), lon))| {
            for i in 0..w {
                let Some(d) = direction(i, j) else {
                    continue;
                };
                let dir = state.camera_attitude * d;
                let Some(t) = ray_sphere(state.camera_position, dir, state.body_position, radius)
                else {
                    continue;
                };
                let p = state.camera_position + t * dir;
                let n = (p - state.body_position) / radius;
                let to_sun = state.sun_position - p;
                body[i] = 1;
                depth[i] = t as f32;
                normals[3 * i..3 * i + 3].copy_from_slice(&n.as_vec3().to_array());
                if n.dot(to_sun) > 0.0 {
                    lit[i] = 1;
                    shadow[i] = u8::from(occulted(state, p, to_sun));
                }
                let nb = to_body * n;
                lat[i] = nb.z.clamp(-1.0, 1.0).asin() as f32;
                lon[i] = nb.y.atan2(nb.x) as f32;
            }
        },
    );
    images
}

/// Whether the occulter hides the Sun's centre from the point `p`.
fn occulted(state: &State, p: DVec3, to_sun: DVec3) -> bool {
    let Some(o) = state.occulter else {
        return false;
    };
    let range = to_sun.length();
    ray_sphere(p, to_sun / range, o.position, o.radius).is_some_and(|t| t < range)
}

/// The projected disk in closed form.
fn disk(camera: &Pinhole, state: &State, radius: f64, mask: &[u8]) -> Disk {
    let centre_cam =
        state.camera_attitude.inverse() * (state.body_position - state.camera_position);
    let range = centre_cam.length();
    let rho = (radius / range).asin();
    let ellipse = limb_ellipse(camera, centre_cam, radius);
    let bbox = ellipse
        .as_ref()
        .and_then(|e| clip_box(e.bbox(), camera))
        .or_else(|| mask_bbox(mask, camera.width));
    Disk {
        projected_centre: (centre_cam.z > 0.0).then(|| {
            let (u, v) = camera.project(centre_cam);
            [u, v]
        }),
        limb_ellipse: ellipse,
        apparent_radius_rad: rho,
        apparent_radius_px: camera.fx * rho.tan(),
        range_m: range,
        limb_points: geometry::limb_points(camera, centre_cam, radius, LIMB_POINTS),
        bbox,
    }
}

/// A box [x0, y0, x1, y1] clipped to the image, as [x, y, w, h]; None when
/// nothing of it is inside.
fn clip_box(b: [f64; 4], camera: &Pinhole) -> Option<[f64; 4]> {
    clip_box_to(b, camera.width, camera.height)
}

/// A box [x0, y0, x1, y1] clipped to a `w × h` image, as [x, y, w, h];
/// None when nothing of it is inside.
fn clip_box_to(b: [f64; 4], w: usize, h: usize) -> Option<[f64; 4]> {
    let x0 = b[0].max(0.0);
    let y0 = b[1].max(0.0);
    let x1 = b[2].min(w as f64);
    let y1 = b[3].min(h as f64);
    (x1 > x0 && y1 > y0).then_some([x0, y0, x1 - x0, y1 - y0])
}

/// The box of the set pixels of `mask` (row width `w`) as [x, y, w, h].
fn mask_bbox(mask: &[u8], w: usize) -> Option<[f64; 4]> {
    let mut b: Option<[usize; 4]> = None;
    for (k, _) in mask.iter().enumerate().filter(|(_, &m)| m != 0) {
        let (i, j) = (k % w, k / w);
        let r = b.get_or_insert([i, j, i, j]);
        *r = [r[0].min(i), r[1].min(j), r[2].max(i), r[3].max(j)];
    }
    b.map(|[x0, y0, x1, y1]| {
        [
            x0 as f64,
            y0 as f64,
            (x1 + 1 - x0) as f64,
            (y1 + 1 - y0) as f64,
        ]
    })
}
