//! The projected disk through a lens: the body's centre and limb points
//! distorted by the lens's Brown–Conrady model, and the box of the
//! distorted limb. The limb's image is no longer an ellipse, so
//! `limb_ellipse` is None.

use glam::DVec3;

use super::{clip_box_to, geometry, mask_bbox, Disk, LIMB_POINTS};
use crate::optics::distortion::Lens;
use crate::scene::State;

/// Limb points whose distorted box is the bounding box: the box of a
/// curve sampled every 2π/n misses at most r(1 − cos(π/n)), 3·10⁻⁵ px for
/// a 100 px radius.
const BOX_POINTS: usize = 4096;

/// The disk of a sphere of `radius` in `state` through `lens`; `mask` is
/// the body mask, whose box stands in when part of the limb is behind the
/// camera or beyond the lens's field.
pub fn disk(lens: &Lens, state: &State, radius: f64, mask: &[u8]) -> Disk {
    let centre_cam =
        state.camera_attitude.inverse() * (state.body_position - state.camera_position);
    let range = centre_cam.length();
    let rho = (radius / range).asin();
    let (w, h) = (lens.intrinsics.width, lens.intrinsics.height);
    let project = |p: DVec3| lens.project(p).map(|(u, v)| [u, v]);
    let dense: Option<Vec<[f64; 2]>> = (centre_cam.z > radius)
        .then(|| {
            geometry::limb_circle(centre_cam, radius, BOX_POINTS)
                .into_iter()
                .map(project)
                .collect()
        })
        .flatten();
    let bbox = dense
        .and_then(|points| {
            let b = points
                .iter()
                .fold([f64::MAX, f64::MAX, f64::MIN, f64::MIN], |b, p| {
                    [
                        b[0].min(p[0]),
                        b[1].min(p[1]),
                        b[2].max(p[0]),
                        b[3].max(p[1]),
                    ]
                });
            clip_box_to(b, w, h)
        })
        .or_else(|| mask_bbox(mask, w));
    Disk {
        projected_centre: project(centre_cam),
        limb_ellipse: None,
        apparent_radius_rad: rho,
        apparent_radius_px: lens.pinhole().fx * rho.tan(),
        range_m: range,
        limb_points: geometry::limb_circle(centre_cam, radius, LIMB_POINTS)
            .into_iter()
            .filter_map(project)
            .collect(),
        bbox,
    }
}
