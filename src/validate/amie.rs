//! SMART-1 AMIE: the camera model and the full scene geometry of one image,
//! rebuilt from its PDS3 label alone (no SPICE kernels):
//!
//! - camera position: `-SC_TARGET_POSITION_VECTOR` (km, J2000; the label's
//!   spacecraft→Moon vector), in a world frame = J2000 axes, Moon at origin;
//! - camera attitude: a Wahba fit of the camera rays of the boresight and of
//!   the four corner pixels to the label's `RIGHT_ASCENSION`/`DECLINATION`
//!   and `RETICLE_POINT_RA`/`RETICLE_POINT_DECLINATION` (this fixes the roll
//!   and the handedness of the pixel grid);
//! - Sun: analytic geocentric Sun minus analytic geocentric Moon
//!   ([`super::ephem`]);
//! - Moon orientation: IAU 2009 rotation model ([`super::ephem`]).
//!
//! ## Image orientation (checked on both images, see `tests/validate_amie.rs`)
//! The label's four corner coordinates are, in order, the corners at
//! (first line, first sample), (first line, last sample), (last line, last
//! sample), (last line, first sample). With the stored lines taken top to
//! bottom and samples left to right, i.e. **without any row flip**, the
//! corner directions project onto the corner pixels to < 1 px (the RA/Dec are
//! rounded to 0.01° ≈ 1.9 px). Flipping rows (or columns) mirrors the grid
//! and the corner fit fails by ~500 px. The image content agrees: the lit
//! limb of image 00208_00030 lies toward the projected Sun and its fitted
//! limb circle is within a few pixels of the projected Moon centre. So
//! [`ROWS_FLIPPED`] is `false`: the stored array already is in the camera
//! convention below.
//!
//! ## Camera convention
//! OpenCV camera frame: x right, y down, z along the boresight. Pixel (0, 0)
//! is the top-left pixel; its centre is at (0.5, 0.5); the principal point is
//! the detector centre (256, 256) (instrument kernel `CCD_CENTER` 256.5 in
//! 1-based pixel indices). Pinhole, no distortion (none is published).

#![allow(clippy::needless_range_loop)] // small fixed-size matrix code reads better with indices

use std::path::Path;

use glam::{DMat3, DQuat, DVec3};

use super::ephem::{self, Utc};
use super::pds3::{self, Label};
use super::raster::Raster;
use crate::ephemeris::{self, Ephemeris};
use crate::error::{Error, Result};

/// Whether the stored AMIE lines must be reversed to get the camera
/// convention (row 0 at the top). Determined from the label corners and the
/// image content: they are not.
pub const ROWS_FLIPPED: bool = false;

/// Mean lunar radius, m (IAU).
pub const MOON_RADIUS_M: f64 = 1_737_400.0;
/// Earth equatorial radius, m.
pub const EARTH_RADIUS_M: f64 = 6_378_137.0;
/// Solar radius, m (IAU 2015 nominal).
pub const SUN_RADIUS_M: f64 = 695_700_000.0;

/// AMIE camera (unfiltered "NONE" quadrant) and detector chain.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct AmieCamera {
    /// 154.7 mm (instrument kernel `INS-238110_FOCAL_LENGTH`).
    pub focal_length_m: f64,
    /// 14 µm (`INS-238110_PIXEL_SIZE`).
    pub pixel_pitch_m: f64,
    /// f/10 (`INS-238110_F/RATIO`).
    pub f_number: f64,
    /// (columns, rows) = (512, 512).
    pub resolution: (u32, u32),
    /// Principal point in pixel coordinates (x right, y down), (256, 256).
    pub principal_point_px: (f64, f64),
    /// Exposure from the label's `EXPOSURE_DURATION`, s.
    pub exposure_s: f64,
    /// Gain from the label's `GAIN_NUMBER`, e-/DN (280).
    pub gain_e_per_dn: f64,
    /// ADC bits (10).
    pub bits: u32,
    /// Saturation, e- (about 300 000; 1023 DN × 280 e-/DN = 286 440 e-).
    pub full_well_e: f64,
}

impl AmieCamera {
    /// Focal length in pixels (11 050).
    pub fn focal_px(&self) -> f64 {
        self.focal_length_m / self.pixel_pitch_m
    }

    /// Unit ray in the camera frame through pixel coordinates (u, v)
    /// (pixel centres at +0.5).
    pub fn pixel_to_ray(&self, u: f64, v: f64) -> DVec3 {
        let f = self.focal_px();
        DVec3::new(
            (u - self.principal_point_px.0) / f,
            (v - self.principal_point_px.1) / f,
            1.0,
        )
        .normalize()
    }

    /// Pixel coordinates of a camera-frame point, `None` behind the camera.
    pub fn project_camera(&self, p: DVec3) -> Option<[f64; 2]> {
        if p.z <= 0.0 {
            return None;
        }
        let f = self.focal_px();
        Some([
            self.principal_point_px.0 + f * p.x / p.z,
            self.principal_point_px.1 + f * p.y / p.z,
        ])
    }

    /// Pixel coordinates of the centres of the four corner pixels, in the
    /// order of the label's corner coordinates (see the module doc).
    pub fn corner_pixels(&self) -> [[f64; 2]; 4] {
        let (w, h) = (self.resolution.0 as f64, self.resolution.1 as f64);
        [
            [0.5, 0.5],
            [w - 0.5, 0.5],
            [w - 0.5, h - 0.5],
            [0.5, h - 0.5],
        ]
    }
}

/// Pose of camera, body and Sun, world frame = J2000 axes, Moon at origin.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct AmieState {
    /// Camera position, m.
    pub camera_position: [f64; 3],
    /// Scalar-first quaternion [w, x, y, z] rotating camera-frame vectors
    /// (x right, y down, z boresight) into J2000.
    pub camera_attitude: [f64; 4],
    /// Scalar-first quaternion [w, x, y, z] rotating Moon body-fixed
    /// (IAU_MOON) vectors into J2000.
    pub body_attitude: [f64; 4],
    /// Sun position, m.
    pub sun_position: [f64; 3],
}

/// The label values the geometry is built from or checked against, in the
/// label's own units.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LabelGeometry {
    pub product_id: String,
    /// `START_TIME` (UTC).
    pub start_time: String,
    /// `SC_TARGET_POSITION_VECTOR`: spacecraft→Moon centre, km, J2000.
    pub sc_target_position_km: [f64; 3],
    pub target_center_distance_km: f64,
    /// `SOLAR_DISTANCE`: Moon–Sun distance, km.
    pub solar_distance_km: f64,
    pub phase_angle_deg: f64,
    pub incidence_angle_deg: f64,
    pub emission_angle_deg: f64,
    pub sub_solar_lat_lon_deg: (f64, f64),
    /// `CENTER_LATITUDE`/`CENTER_LONGITUDE`: surface point on the boresight.
    pub center_lat_lon_deg: (f64, f64),
    pub boresight_ra_dec_deg: (f64, f64),
    pub corner_ra_dec_deg: [(f64, f64); 4],
    /// `SMART1:AMIE_SC_EFRF_VECTOR`: spacecraft position in the Earth-fixed
    /// frame, km (optional; used only as a cross-check of the Moon ephemeris).
    pub sc_efrf_km: Option<[f64; 3]>,
}

/// Everything the renderer needs to image one AMIE frame.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct AmieScene {
    pub camera: AmieCamera,
    pub state: AmieState,
    /// Epoch (TT Julian date) the state refers to.
    pub jd_tt: f64,
    /// RMS of the attitude fit over boresight + 4 corners, px.
    pub attitude_fit_rms_px: f64,
    pub label: LabelGeometry,
}

/// One AMIE product: its scene and its image.
#[derive(Debug, Clone)]
pub struct AmieObservation {
    pub scene: AmieScene,
    /// DN (raw / 64), rows in the camera convention (row 0 at the top).
    pub image: Raster,
}

/// Reads an AMIE `.IMG` file: label, geometry and image.
pub fn load(path: impl AsRef<Path>) -> Result<AmieObservation> {
    let img = pds3::read_image(path.as_ref())?;
    let scene = scene_from_label(&img.label)?;
    let (w, h) = scene.camera.resolution;
    if img.scaled.width != w as usize || img.scaled.height != h as usize {
        return Err(Error::parse(
            path.as_ref(),
            format!(
                "AMIE image is {}x{}, expected {w}x{h}",
                img.scaled.width, img.scaled.height
            ),
        ));
    }
    let image = if ROWS_FLIPPED {
        img.scaled.flipped_rows()
    } else {
        img.scaled
    };
    Ok(AmieObservation { scene, image })
}

fn label_geometry(label: &Label) -> Result<LabelGeometry> {
    let r = &label.root;
    let ra_seq = r.f64_array::<4>("RETICLE_POINT_RA")?;
    let dec_seq = r.f64_array::<4>("RETICLE_POINT_DECLINATION")?;
    let efrf = match r.find("SMART1:AMIE_SC_EFRF_VECTOR") {
        Some(_) => Some(r.f64_array::<3>("SMART1:AMIE_SC_EFRF_VECTOR")?),
        None => None,
    };
    Ok(LabelGeometry {
        product_id: r.string("PRODUCT_ID")?,
        start_time: r.string("START_TIME")?,
        sc_target_position_km: r.f64_array("SC_TARGET_POSITION_VECTOR")?,
        target_center_distance_km: r.f64_in("TARGET_CENTER_DISTANCE", "KM")?,
        solar_distance_km: r.f64_in("SOLAR_DISTANCE", "KM")?,
        phase_angle_deg: r.f64_in("PHASE_ANGLE", "DEG")?,
        incidence_angle_deg: r.f64_in("INCIDENCE_ANGLE", "DEG")?,
        emission_angle_deg: r.f64_in("EMISSION_ANGLE", "DEG")?,
        sub_solar_lat_lon_deg: (
            r.f64_in("SUB_SOLAR_LATITUDE", "DEG")?,
            r.f64_in("SUB_SOLAR_LONGITUDE", "DEG")?,
        ),
        center_lat_lon_deg: (
            r.f64_in("CENTER_LATITUDE", "DEG")?,
            r.f64_in("CENTER_LONGITUDE", "DEG")?,
        ),
        boresight_ra_dec_deg: (
            r.f64_in("RIGHT_ASCENSION", "DEG")?,
            r.f64_in("DECLINATION", "DEG")?,
        ),
        corner_ra_dec_deg: std::array::from_fn(|i| (ra_seq[i], dec_seq[i])),
        sc_efrf_km: efrf,
    })
}

/// Exposure time in seconds from a `<MS>`, `<S>` or `<SEC>` quantity.
fn exposure_s(label: &Label) -> Result<f64> {
    let (v, unit) = label.root.f64_with_unit("EXPOSURE_DURATION")?;
    let scale = match unit.as_deref().map(|u| u.to_ascii_uppercase()) {
        Some(u) if u == "MS" => 1e-3,
        Some(u) if u == "S" || u == "SEC" || u == "SECONDS" => 1.0,
        other => {
            return Err(Error::parse(
                label.path(),
                format!(
                    "`EXPOSURE_DURATION`: unit {}, expected <MS> or <S>",
                    other.map_or("missing".to_string(), |u| format!("<{u}>"))
                ),
            ))
        }
    };
    if v.is_nan() || v <= 0.0 {
        return Err(Error::parse(
            label.path(),
            format!("`EXPOSURE_DURATION`: {v} is not positive"),
        ));
    }
    Ok(v * scale)
}

/// Builds the scene of an AMIE label.
pub fn scene_from_label(label: &Label) -> Result<AmieScene> {
    let geo = label_geometry(label)?;
    let camera = AmieCamera {
        focal_length_m: 0.1547,
        pixel_pitch_m: 14e-6,
        f_number: 10.0,
        resolution: (512, 512),
        principal_point_px: (256.0, 256.0),
        exposure_s: exposure_s(label)?,
        gain_e_per_dn: label.root.f64_in("GAIN_NUMBER", "E/DN")?,
        bits: 10,
        full_well_e: 300_000.0,
    };
    let utc = Utc::parse(&geo.start_time)
        .map_err(|e| Error::parse(label.path(), format!("`START_TIME`: {e}")))?;
    let jd_tt = utc.jd_tt();

    let sc_to_moon_m = DVec3::from_array(geo.sc_target_position_km) * 1e3;
    let camera_position = -sc_to_moon_m;

    let (q_cam, _) = fit_attitude(&camera, &geo, camera.corner_pixels());
    let body = DQuat::from_mat3(&ephem::moon_body_to_j2000(jd_tt)).normalize();
    // Sun: analytic direction (≤ 0.003° from DE421 on both images), and the
    // label's Moon–Sun distance (within 5 km of DE421), since the
    // low-accuracy solar radius is only good to ~1e-4 (up to 9000 km).
    let sun_analytic = ephem::sun_from_moon_j2000(jd_tt);
    let sun = if geo.solar_distance_km > 0.0 {
        sun_analytic.normalize() * geo.solar_distance_km * 1e3
    } else {
        sun_analytic
    };

    let state = AmieState {
        camera_position: camera_position.to_array(),
        camera_attitude: quat_wxyz(q_cam),
        body_attitude: quat_wxyz(body),
        sun_position: sun.to_array(),
    };
    let mut scene = AmieScene {
        camera,
        state,
        jd_tt,
        attitude_fit_rms_px: 0.0,
        label: geo,
    };
    let res = scene.pointing_residuals_px();
    scene.attitude_fit_rms_px = (res.iter().map(|r| r * r).sum::<f64>() / res.len() as f64).sqrt();
    Ok(scene)
}

/// Fits the camera→J2000 rotation to the label's boresight and corner
/// directions, assuming label corner `k` is seen at pixel `corner_pixels[k]`
/// (the camera convention uses [`AmieCamera::corner_pixels`]; other
/// assignments, e.g. a row-flipped grid, can be tried to test the
/// orientation). Returns the rotation and the reprojection errors (px) of
/// boresight and corners.
pub fn fit_attitude(
    camera: &AmieCamera,
    geo: &LabelGeometry,
    corner_pixels: [[f64; 2]; 4],
) -> (DQuat, [f64; 5]) {
    let pp = [camera.principal_point_px.0, camera.principal_point_px.1];
    let mut pixels = vec![pp];
    let mut sky = vec![ephem::radec_to_unit(
        geo.boresight_ra_dec_deg.0,
        geo.boresight_ra_dec_deg.1,
    )];
    for (px, (ra, dec)) in corner_pixels.iter().zip(geo.corner_ra_dec_deg) {
        pixels.push(*px);
        sky.push(ephem::radec_to_unit(ra, dec));
    }
    let rays: Vec<DVec3> = pixels
        .iter()
        .map(|p| camera.pixel_to_ray(p[0], p[1]))
        .collect();
    let q = wahba_quaternion(&rays, &sky);
    let mut res = [f64::INFINITY; 5];
    for (i, (px, d)) in pixels.iter().zip(&sky).enumerate() {
        if let Some(p) = camera.project_camera(q.inverse() * *d) {
            res[i] = (p[0] - px[0]).hypot(p[1] - px[1]);
        }
    }
    (q, res)
}

/// [w, x, y, z] of a glam quaternion.
pub fn quat_wxyz(q: DQuat) -> [f64; 4] {
    [q.w, q.x, q.y, q.z]
}

/// glam quaternion from [w, x, y, z].
pub fn quat_from_wxyz(q: [f64; 4]) -> DQuat {
    DQuat::from_xyzw(q[1], q[2], q[3], q[0])
}

/// Rotation `q` minimising `Σ |b_i − q a_i|²` (Wahba's problem, equal
/// weights), by Davenport's q-method: the eigenvector of the largest
/// eigenvalue of the 4×4 matrix K, found with Jacobi rotations.
pub fn wahba_quaternion(a: &[DVec3], b: &[DVec3]) -> DQuat {
    let mut bm = [[0.0f64; 3]; 3];
    for (ai, bi) in a.iter().zip(b) {
        let (ai, bi) = (ai.normalize(), bi.normalize());
        let (av, bv) = (ai.to_array(), bi.to_array());
        for r in 0..3 {
            for c in 0..3 {
                bm[r][c] += bv[r] * av[c];
            }
        }
    }
    let s = [
        [2.0 * bm[0][0], bm[0][1] + bm[1][0], bm[0][2] + bm[2][0]],
        [bm[1][0] + bm[0][1], 2.0 * bm[1][1], bm[1][2] + bm[2][1]],
        [bm[2][0] + bm[0][2], bm[2][1] + bm[1][2], 2.0 * bm[2][2]],
    ];
    let tr = bm[0][0] + bm[1][1] + bm[2][2];
    let z = [
        bm[1][2] - bm[2][1],
        bm[2][0] - bm[0][2],
        bm[0][1] - bm[1][0],
    ];
    // K for q = [x, y, z, w] (vector first), for vectors b = R(q) a.
    let mut k = [[0.0f64; 4]; 4];
    for r in 0..3 {
        for c in 0..3 {
            k[r][c] = s[r][c] - if r == c { tr } else { 0.0 };
        }
        k[r][3] = z[r];
        k[3][r] = z[r];
    }
    k[3][3] = tr;
    let (vals, vecs) = jacobi_eigen4(k);
    let best = (0..4)
        .max_by(|&i, &j| vals[i].total_cmp(&vals[j]))
        .expect("4 eigenvalues");
    // With this sign convention the eigenvector is the conjugate-sense
    // quaternion; verify on the data and pick the rotation that maps a -> b.
    let q =
        DQuat::from_xyzw(vecs[0][best], vecs[1][best], vecs[2][best], vecs[3][best]).normalize();
    let err = |q: DQuat| {
        a.iter()
            .zip(b)
            .map(|(ai, bi)| (q * ai.normalize() - bi.normalize()).length_squared())
            .sum::<f64>()
    };
    if err(q) <= err(q.conjugate()) {
        q
    } else {
        q.conjugate()
    }
}

/// Eigenvalues and eigenvectors (columns) of a symmetric 4×4 matrix.
fn jacobi_eigen4(mut a: [[f64; 4]; 4]) -> ([f64; 4], [[f64; 4]; 4]) {
    let mut v = [[0.0f64; 4]; 4];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for _sweep in 0..100 {
        let off: f64 = (0..4)
            .flat_map(|p| (0..4).filter(move |&q| q != p).map(move |q| (p, q)))
            .map(|(p, q)| a[p][q] * a[p][q])
            .sum();
        if off < 1e-30 {
            break;
        }
        for p in 0..3 {
            for q in p + 1..4 {
                if a[p][q].abs() < 1e-300 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..4 {
                    let (akp, akq) = (a[k][p], a[k][q]);
                    a[k][p] = c * akp - s * akq;
                    a[k][q] = s * akp + c * akq;
                }
                for k in 0..4 {
                    let (apk, aqk) = (a[p][k], a[q][k]);
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
                for row in v.iter_mut() {
                    let (vp, vq) = (row[p], row[q]);
                    row[p] = c * vp - s * vq;
                    row[q] = s * vp + c * vq;
                }
            }
        }
    }
    ([a[0][0], a[1][1], a[2][2], a[3][3]], v)
}

/// Result of [`AmieScene::geometry_check`]: derived values next to the
/// label's, degrees unless stated.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct GeometryCheck {
    /// Sun–Moon centre–camera angle.
    pub phase_at_centre_deg: f64,
    /// Phase angle at the surface point on the fitted boresight (`None` if
    /// the boresight misses the Moon). The label's angles refer to that point.
    pub phase_at_boresight_deg: Option<f64>,
    pub incidence_at_boresight_deg: Option<f64>,
    pub emission_at_boresight_deg: Option<f64>,
    pub boresight_lat_lon_deg: Option<(f64, f64)>,
    pub sub_solar_lat_lon_deg: (f64, f64),
    pub sub_spacecraft_lat_lon_deg: (f64, f64),
    /// Great-circle distance between derived and label sub-solar points.
    pub sub_solar_error_deg: f64,
    /// Reprojection error of boresight and the four corners, px.
    pub pointing_residuals_px: [f64; 5],
    /// Derived |Sun − Moon|, km.
    pub solar_distance_km: f64,
    /// |Moon from analytic ephemeris − Moon from the label's Earth-fixed
    /// spacecraft vector rotated by GMST + spacecraft→Moon vector|, km.
    pub moon_position_vs_efrf_km: Option<f64>,
    /// Distance of the Moon's centre from the Earth's shadow axis and the
    /// geometric umbra radius there, km (`None` when the Moon is on the
    /// Sun's side of the Earth): the Moon is (partly) in the umbra when the
    /// first is below the second plus the lunar radius.
    pub earth_shadow: Option<(f64, f64)>,
    /// Pixel distance between the principal point and the projection of the
    /// label's `CENTER_LATITUDE`/`CENTER_LONGITUDE` surface point (which the
    /// label computed on its boresight).
    pub label_center_point_offset_px: Option<f64>,
}

impl AmieScene {
    /// Camera → J2000 rotation.
    pub fn camera_to_world(&self) -> DQuat {
        quat_from_wxyz(self.state.camera_attitude)
    }

    /// Moon body-fixed → J2000 rotation.
    pub fn body_to_world(&self) -> DQuat {
        quat_from_wxyz(self.state.body_attitude)
    }

    pub fn camera_position(&self) -> DVec3 {
        DVec3::from_array(self.state.camera_position)
    }

    pub fn sun_position(&self) -> DVec3 {
        DVec3::from_array(self.state.sun_position)
    }

    /// Pixel coordinates of a world point (m), `None` behind the camera.
    pub fn project_point(&self, p: DVec3) -> Option<[f64; 2]> {
        self.camera
            .project_camera(self.camera_to_world().inverse() * (p - self.camera_position()))
    }

    /// Pixel coordinates of a J2000 direction (e.g. a star), `None` behind.
    pub fn project_direction(&self, d: DVec3) -> Option<[f64; 2]> {
        self.camera
            .project_camera(self.camera_to_world().inverse() * d)
    }

    /// Apparent Moon disk: centre (px) and radius (px) of the limb circle
    /// (small-angle: the limb is a circle of angular radius asin(R/d) about
    /// the centre direction; exact to < 0.01 px at these distances).
    pub fn moon_disk_px(&self) -> Option<([f64; 2], f64)> {
        let c = self.project_point(DVec3::ZERO)?;
        let d = self.camera_position().length();
        let ang = (MOON_RADIUS_M / d).asin();
        Some((c, self.camera.focal_px() * ang.tan()))
    }

    /// Unit vector in the image plane (x right, y down) from the Moon centre
    /// toward the sub-solar side, i.e. where the lit limb is.
    pub fn sun_direction_in_image(&self) -> Option<[f64; 2]> {
        let c = self.project_point(DVec3::ZERO)?;
        let s = self.project_point(self.sun_position().normalize() * MOON_RADIUS_M * 0.01)?;
        let (dx, dy) = (s[0] - c[0], s[1] - c[1]);
        let n = dx.hypot(dy);
        Some([dx / n, dy / n])
    }

    /// Unit vector in the image plane from the Moon centre away from the
    /// Earth's shadow axis: during a lunar eclipse the part of the disk still
    /// in sunlight lies on this side.
    pub fn anti_shadow_direction_in_image(&self) -> Option<[f64; 2]> {
        let moon_geo = ephem::moon_geocentric_j2000(self.jd_tt);
        let axis = -ephem::sun_geocentric_j2000(self.jd_tt).normalize();
        let off = (moon_geo - axis * moon_geo.dot(axis)).normalize();
        let c = self.project_point(DVec3::ZERO)?;
        let s = self.project_point(off * MOON_RADIUS_M * 0.01)?;
        let (dx, dy) = (s[0] - c[0], s[1] - c[1]);
        let n = dx.hypot(dy);
        Some([dx / n, dy / n])
    }

    /// Reprojection error (px) of the label's boresight and four corner
    /// directions against the principal point and the corner pixels.
    pub fn pointing_residuals_px(&self) -> [f64; 5] {
        let l = &self.label;
        let mut targets = vec![(
            l.boresight_ra_dec_deg,
            [
                self.camera.principal_point_px.0,
                self.camera.principal_point_px.1,
            ],
        )];
        for (rd, px) in l.corner_ra_dec_deg.iter().zip(self.camera.corner_pixels()) {
            targets.push((*rd, px));
        }
        let mut out = [f64::INFINITY; 5];
        for (i, ((ra, dec), px)) in targets.into_iter().enumerate() {
            if let Some(p) = self.project_direction(ephem::radec_to_unit(ra, dec)) {
                out[i] = (p[0] - px[0]).hypot(p[1] - px[1]);
            }
        }
        out
    }

    /// Derives the label's geometric quantities from this scene.
    pub fn geometry_check(&self) -> GeometryCheck {
        let cam = self.camera_position();
        let sun = self.sun_position();
        let body_inv = self.body_to_world().inverse();
        let angle = |a: DVec3, b: DVec3| a.angle_between(b).to_degrees();

        // Boresight intercept with the sphere.
        let dir = self.camera_to_world() * DVec3::Z;
        let b = cam.dot(dir);
        let disc = b * b - (cam.length_squared() - MOON_RADIUS_M * MOON_RADIUS_M);
        let hit = (disc >= 0.0).then(|| cam + dir * (-b - disc.sqrt()));
        let sub_solar = ephem::lat_lon_deg(body_inv * sun);
        let (la, lo) = (sub_solar.0.to_radians(), sub_solar.1.to_radians());
        let (lb, lob) = (
            self.label.sub_solar_lat_lon_deg.0.to_radians(),
            self.label.sub_solar_lat_lon_deg.1.to_radians(),
        );
        let cosd = la.sin() * lb.sin() + la.cos() * lb.cos() * (lo - lob).cos();

        let moon_vs_efrf = self.label.sc_efrf_km.map(|efrf| {
            let utc =
                Utc::parse(&self.label.start_time).expect("validated when the scene was built");
            let g = ephem::gmst_deg(utc.jd_utc()).to_radians();
            let sc_geo = DMat3::from_rotation_z(g) * DVec3::from_array(efrf) * 1e3;
            let moon_label = sc_geo + DVec3::from_array(self.label.sc_target_position_km) * 1e3;
            (moon_label - ephem::moon_geocentric_j2000(self.jd_tt)).length() / 1e3
        });

        // Earth's shadow: axis from the Earth's centre away from the Sun.
        let moon_geo = ephem::moon_geocentric_j2000(self.jd_tt);
        let sun_geo = ephem::sun_geocentric_j2000(self.jd_tt);
        let axis = -sun_geo.normalize();
        let along = moon_geo.dot(axis);
        let earth_shadow = (along > 0.0).then(|| {
            let axis_dist = (moon_geo - axis * along).length();
            let umbra = EARTH_RADIUS_M - along * (SUN_RADIUS_M - EARTH_RADIUS_M) / sun_geo.length();
            (axis_dist / 1e3, umbra / 1e3)
        });
        let (clat, clon) = (
            self.label.center_lat_lon_deg.0.to_radians(),
            self.label.center_lat_lon_deg.1.to_radians(),
        );
        let center_body = DVec3::new(clat.cos() * clon.cos(), clat.cos() * clon.sin(), clat.sin())
            * MOON_RADIUS_M;
        let pp = self.camera.principal_point_px;
        let center_offset = self
            .project_point(self.body_to_world() * center_body)
            .map(|p| (p[0] - pp.0).hypot(p[1] - pp.1));

        GeometryCheck {
            phase_at_centre_deg: angle(sun, cam),
            phase_at_boresight_deg: hit.map(|p| angle(sun - p, cam - p)),
            incidence_at_boresight_deg: hit.map(|p| angle(sun - p, p)),
            emission_at_boresight_deg: hit.map(|p| angle(cam - p, p)),
            boresight_lat_lon_deg: hit.map(|p| ephem::lat_lon_deg(body_inv * p)),
            sub_solar_lat_lon_deg: sub_solar,
            sub_spacecraft_lat_lon_deg: ephem::lat_lon_deg(body_inv * cam),
            sub_solar_error_deg: cosd.clamp(-1.0, 1.0).acos().to_degrees(),
            pointing_residuals_px: self.pointing_residuals_px(),
            solar_distance_km: sun.length() / 1e3,
            moon_position_vs_efrf_km: moon_vs_efrf,
            earth_shadow,
            label_center_point_offset_px: center_offset,
        }
    }
}

/// How far two ephemerides put the Moon, the Sun and the Moon's axes at an
/// AMIE image's epoch.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct EphemerisDifference {
    /// |Δ geocentric Moon|, km.
    pub moon_position_km: f64,
    /// Angle between the selenocentric Sun directions, degrees.
    pub sun_direction_deg: f64,
    /// |Δ Moon–Sun distance|, km.
    pub sun_distance_km: f64,
    /// Angle of the rotation between the two Moon body frames, degrees.
    pub moon_orientation_deg: f64,
}

/// The label's `START_TIME` as an epoch (UTC).
pub fn epoch(scene: &AmieScene) -> Result<ephemeris::Epoch> {
    ephemeris::parse_epoch(&scene.label.start_time, "START_TIME")
}

/// `scene` with its Moon attitude and Sun from `eph` (the SPICE path: the
/// Sun exactly where the kernels put it, no label distance needed).
pub fn with_ephemeris(scene: &AmieScene, eph: &dyn Ephemeris) -> Result<AmieScene> {
    let t = epoch(scene)?;
    let mut out = scene.clone();
    let body = DQuat::from_mat3(&eph.moon_to_j2000(t)?).normalize();
    out.state.body_attitude = quat_wxyz(body);
    out.state.sun_position = eph.sun_from_moon(t)?.to_array();
    Ok(out)
}

/// Differences between ephemerides `a` and `b` at the scene's epoch.
pub fn ephemeris_difference(
    scene: &AmieScene,
    a: &dyn Ephemeris,
    b: &dyn Ephemeris,
) -> Result<EphemerisDifference> {
    let t = epoch(scene)?;
    let (sa, sb) = (a.sun_from_moon(t)?, b.sun_from_moon(t)?);
    let turn = a.moon_to_j2000(t)?.transpose() * b.moon_to_j2000(t)?;
    let cos = ((turn.x_axis.x + turn.y_axis.y + turn.z_axis.z - 1.0) / 2.0).clamp(-1.0, 1.0);
    Ok(EphemerisDifference {
        moon_position_km: (a.moon_from_earth(t)? - b.moon_from_earth(t)?).length() / 1e3,
        sun_direction_deg: sa.angle_between(sb).to_degrees(),
        sun_distance_km: (sa.length() - sb.length()).abs() / 1e3,
        moon_orientation_deg: cos.acos().to_degrees(),
    })
}
