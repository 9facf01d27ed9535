//! Exact labels against references written here: depth and normals from a
//! ray–sphere intersection by closest approach, the limb ellipse's centre
//! and axes from the tangent angles of an off-axis sphere, lit and shadow
//! masks from their definitions, lat/lon back to the normals, the COCO
//! run-length encoding back to the mask, and `render --labels` on disk.

use std::process::Command;

use glam::{DQuat, DVec3};
use optistim::labels::{self, files};
use optistim::scene::{Occulter, Pinhole, State};

const R: f64 = 1737.4e3;

fn camera(n: usize, f: f64) -> Pinhole {
    Pinhole {
        width: n,
        height: n,
        fx: f,
        fy: f,
        cx: n as f64 / 2.0,
        cy: n as f64 / 2.0,
    }
}

fn state(camera_position: DVec3, camera_attitude: DQuat, sun: DVec3) -> State {
    State {
        body_position: DVec3::new(1.0e3, -2.0e3, 5.0e2),
        body_attitude: DQuat::from_rotation_z(0.7) * DQuat::from_rotation_x(0.3),
        camera_position,
        camera_attitude,
        sun_position: sun,
        occulter: None,
    }
}

/// Unit ray through pixel (i, j)'s centre, world frame, from the pinhole
/// model written out: ((u − cx)/fx, (v − cy)/fy, 1) normalised.
fn ray(cam: &Pinhole, q: DQuat, i: usize, j: usize) -> DVec3 {
    let x = (i as f64 + 0.5 - cam.cx) / cam.fx;
    let y = (j as f64 + 0.5 - cam.cy) / cam.fy;
    q * DVec3::new(x, y, 1.0).normalize()
}

/// Hit distance by closest approach: t = tca − √(R² − d²).
fn closest_approach(o: DVec3, d: DVec3, c: DVec3, r: f64) -> Option<(f64, f64)> {
    let tca = (c - o).dot(d);
    let d2 = (c - o).length_squared() - tca * tca;
    (d2 <= r * r && tca > 0.0).then(|| (tca - (r * r - d2).sqrt(), d2.sqrt()))
}

/// A camera 5 radii out, looking back at the body a little off-axis and
/// rolled, the Sun at 60° phase.
fn oblique() -> (Pinhole, State) {
    let cam = camera(96, 120.0);
    let pos = DVec3::new(3.0, 4.0, 1.0).normalize() * 5.0 * R;
    let look = DQuat::from_rotation_arc(DVec3::Z, -pos.normalize());
    let attitude = look * DQuat::from_rotation_z(0.4) * DQuat::from_rotation_y(0.05);
    let sun = DQuat::from_rotation_z(1.05) * pos.normalize() * 1.5e11;
    (cam, state(pos, attitude, sun))
}

#[test]
fn depth_and_normals_match_closest_approach() {
    let (cam, st) = oblique();
    let l = labels::compute(&cam, &st, R, None);
    let im = &l.images;
    let mut hits = 0;
    for j in 0..cam.height {
        for i in 0..cam.width {
            let k = j * cam.width + i;
            let d = ray(&cam, st.camera_attitude, i, j);
            match closest_approach(st.camera_position, d, st.body_position, R) {
                Some((t, miss)) => {
                    // A ray grazing within 1e-6 R may fall either side.
                    if R - miss < 1e-6 * R {
                        continue;
                    }
                    assert_eq!(im.body[k], 1, "pixel ({i}, {j}) should hit");
                    let depth = im.depth[k] as f64;
                    assert!((depth - t).abs() < 1e-6 * t, "depth {depth} vs {t}");
                    let n = (st.camera_position + t * d - st.body_position) / R;
                    let got = DVec3::from_array([0, 1, 2].map(|c| im.normals[3 * k + c] as f64));
                    assert!((got - n).length() < 1e-5, "normal {got} vs {n}");
                    hits += 1;
                }
                None => {
                    assert_eq!(im.body[k], 0, "pixel ({i}, {j}) should miss");
                    assert_eq!(im.depth[k], 0.0);
                }
            }
        }
    }
    assert!(hits > 1000, "only {hits} body pixels");
    assert_eq!(
        l.frame.pixel_counts.body as usize,
        im.body.iter().filter(|&&b| b == 1).count()
    );
}

#[test]
fn latitude_longitude_rebuild_the_normals_in_the_body_frame() {
    let (cam, st) = oblique();
    let l = labels::compute(&cam, &st, R, None);
    let im = &l.images;
    for k in (0..im.body.len()).filter(|&k| im.body[k] == 1) {
        let (lat, lon) = (im.latitude[k] as f64, im.longitude[k] as f64);
        let body = DVec3::new(lat.cos() * lon.cos(), lat.cos() * lon.sin(), lat.sin());
        let n = DVec3::from_array([0, 1, 2].map(|c| im.normals[3 * k + c] as f64));
        assert!((st.body_attitude * body - n).length() < 1e-5);
        assert!(lon > -std::f64::consts::PI - 1e-6 && lon <= std::f64::consts::PI + 1e-6);
    }
}

#[test]
fn sub_camera_point_is_east_longitude() {
    // Identity body attitude, camera on the body-fixed +y axis (longitude
    // +90°, equator), looking at the centre: the centre pixel sees lon 90°.
    let cam = camera(33, 40.0);
    let pos = DVec3::new(0.0, 4.0 * R, 0.0);
    let mut st = state(
        pos,
        DQuat::from_rotation_arc(DVec3::Z, -DVec3::Y),
        DVec3::X * 1.5e11,
    );
    st.body_position = DVec3::ZERO;
    st.body_attitude = DQuat::IDENTITY;
    let l = labels::compute(&cam, &st, R, None);
    let k = 16 * 33 + 16;
    assert!((l.images.longitude[k] as f64 - std::f64::consts::FRAC_PI_2).abs() < 1e-6);
    assert!((l.images.latitude[k] as f64).abs() < 1e-6);
}

#[test]
fn limb_ellipse_of_an_off_axis_sphere_matches_its_tangent_angles() {
    // Sphere centre at angle β off the boresight in the x–z plane, angular
    // radius ρ: its image spans tan(β ± ρ) along x, so the ellipse's centre
    // is f(tan(β+ρ) + tan(β−ρ))/2 and its semi-major axis f(tan(β+ρ) −
    // tan(β−ρ))/2; the semi-minor axis is f sin ρ / √(cos²β − sin²ρ).
    let cam = camera(512, 300.0);
    for &(beta_deg, dist) in &[(0.0f64, 6.0), (20.0, 6.0), (35.0, 3.0), (-25.0, 10.0)] {
        let beta = beta_deg.to_radians();
        let centre = DVec3::new(beta.sin(), 0.0, beta.cos()) * dist * R;
        let mut st = state(DVec3::ZERO, DQuat::IDENTITY, DVec3::X * 1.5e11);
        st.body_position = centre;
        let l = labels::compute(&cam, &st, R, None);
        let rho = (1.0 / dist).asin();
        let (tp, tm) = ((beta + rho).tan(), (beta - rho).tan());
        let e = l.frame.disk.limb_ellipse.expect("an ellipse");
        let f = cam.fx;
        assert!((e.centre[0] - (cam.cx + f * (tp + tm) / 2.0)).abs() < 1e-9 * f);
        assert!((e.centre[1] - cam.cy).abs() < 1e-9 * f);
        assert!((e.semi_axes[0] - f * (tp - tm) / 2.0).abs() < 1e-9 * f);
        let minor = f * rho.sin() / (beta.cos().powi(2) - rho.sin().powi(2)).sqrt();
        assert!((e.semi_axes[1] - minor).abs() < 1e-9 * f, "{beta_deg}");
        if beta_deg != 0.0 {
            assert!(e.angle_rad.abs() < 1e-9, "major axis along x");
        }
        let pc = l.frame.disk.projected_centre.unwrap();
        assert!((pc[0] - (cam.cx + f * beta.tan())).abs() < 1e-9 * f);
        assert!((l.frame.disk.apparent_radius_rad - rho).abs() < 1e-12);
        // Every limb point lies on the ellipse.
        for p in &l.frame.disk.limb_points {
            let (dx, dy) = (p[0] - e.centre[0], p[1] - e.centre[1]);
            let q = (dx / e.semi_axes[0]).powi(2) + (dy / e.semi_axes[1]).powi(2);
            assert!((q - 1.0).abs() < 1e-9, "limb point off the ellipse: {q}");
        }
    }
}

#[test]
fn mask_centroid_and_area_agree_with_the_ellipse() {
    // Brute force: the mean of the body pixels' centres is the ellipse's
    // centre and their count its area, to the pixel grid's resolution.
    let (cam, st) = oblique();
    let l = labels::compute(&cam, &st, R, None);
    let e = l.frame.disk.limb_ellipse.unwrap();
    let (mut sx, mut sy, mut n) = (0.0, 0.0, 0.0);
    for (k, _) in l.images.body.iter().enumerate().filter(|(_, &b)| b == 1) {
        sx += (k % cam.width) as f64 + 0.5;
        sy += (k / cam.width) as f64 + 0.5;
        n += 1.0;
    }
    assert!((sx / n - e.centre[0]).abs() < 0.05 && (sy / n - e.centre[1]).abs() < 0.05);
    let area = std::f64::consts::PI * e.semi_axes[0] * e.semi_axes[1];
    assert!((n - area).abs() < 0.01 * area, "{n} pixels vs area {area}");
    // The box holds every body pixel's centre.
    let b = l.frame.disk.bbox.unwrap();
    for (k, _) in l.images.body.iter().enumerate().filter(|(_, &v)| v == 1) {
        let (u, v) = ((k % cam.width) as f64 + 0.5, (k / cam.width) as f64 + 0.5);
        assert!(u >= b[0] && u <= b[0] + b[2] && v >= b[1] && v <= b[1] + b[3]);
    }
}

#[test]
fn lit_and_shadow_masks_follow_their_definitions() {
    let (cam, mut st) = oblique();
    // An occulter of half the body's radius a tenth of the way to the Sun,
    // on the line through a point off the body's centre: a partial shadow.
    let to_sun = (st.sun_position - st.body_position).normalize();
    let side = to_sun.any_orthonormal_vector();
    st.occulter = Some(Occulter {
        position: st.body_position + to_sun * 20.0 * R + side * 0.6 * R,
        radius: 0.5 * R,
    });
    let l = labels::compute(&cam, &st, R, None);
    let o = st.occulter.unwrap();
    let (mut lit, mut shadow) = (0, 0);
    for j in 0..cam.height {
        for i in 0..cam.width {
            let k = j * cam.width + i;
            let d = ray(&cam, st.camera_attitude, i, j);
            let Some((t, miss)) = closest_approach(st.camera_position, d, st.body_position, R)
            else {
                continue;
            };
            let p = st.camera_position + t * d;
            let n = (p - st.body_position) / R;
            let s = st.sun_position - p;
            let cos_i = n.dot(s.normalize());
            if R - miss < 1e-6 * R || cos_i.abs() < 1e-6 {
                continue;
            }
            assert_eq!(l.images.lit[k], u8::from(cos_i > 0.0), "lit at ({i}, {j})");
            // Shadow: the segment p → Sun passes within the occulter.
            let along = (o.position - p).dot(s.normalize());
            let dist = ((o.position - p) - along * s.normalize()).length();
            if (dist - o.radius).abs() < 1e-6 * R {
                continue;
            }
            let hidden = cos_i > 0.0 && along > 0.0 && dist < o.radius;
            assert_eq!(l.images.shadow[k], u8::from(hidden), "shadow at ({i}, {j})");
            lit += usize::from(cos_i > 0.0);
            shadow += usize::from(hidden);
        }
    }
    assert!(
        lit > 500 && shadow > 50 && shadow < lit,
        "lit {lit}, shadow {shadow}"
    );
}

#[test]
fn coco_run_lengths_decode_to_the_mask() {
    let (cam, st) = oblique();
    let l = labels::compute(&cam, &st, R, None);
    let counts = files::rle(&l.images);
    assert_eq!(counts.iter().sum::<u64>() as usize, cam.width * cam.height);
    let mut decoded = vec![0u8; cam.width * cam.height];
    let mut pos = 0usize;
    for (r, &c) in counts.iter().enumerate() {
        for p in pos..pos + c as usize {
            // Column-major: position p is row p % h, column p / h.
            decoded[(p % cam.height) * cam.width + p / cam.height] = (r % 2) as u8;
        }
        pos += c as usize;
    }
    assert_eq!(decoded, l.images.body);
}

#[test]
fn render_labels_writes_the_documented_files() {
    let dir = tempfile::tempdir().unwrap();
    let root = env!("CARGO_MANIFEST_DIR");
    let scene = std::fs::read_to_string(format!("{root}/configs/examples/moon_lambert.toml"))
        .unwrap()
        .replace("[512, 512]", "[64, 64]")
        .replace("../../data", &format!("{root}/data"));
    let path = dir.path().join("scene.toml");
    std::fs::write(&path, scene).unwrap();
    let out = dir.path().join("out");
    let status = Command::new(env!("CARGO_BIN_EXE_optistim"))
        .args(["render", path.to_str().unwrap(), "--labels", "--out"])
        .arg(&out)
        .env("OPTISTIM_LOG", "warn")
        .status()
        .unwrap();
    assert!(status.success());
    for f in files::all_files() {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("labels.json")).unwrap()).unwrap();
    assert_eq!(json["schema"], labels::SCHEMA);
    // Camera on −z at 6.636e7 m, boresight +z at the origin: the disk sits
    // at the image centre with radius f tan(asin(R/d)), f = 32/tan 3°.
    let c = &json["disk"]["projected_centre"];
    assert!((c[0].as_f64().unwrap() - 32.0).abs() < 1e-9);
    let f = 32.0 / 3f64.to_radians().tan();
    let r_px = f * (R / 6.636e7).asin().tan();
    let got = json["disk"]["apparent_radius_px"].as_f64().unwrap();
    assert!((got - r_px).abs() < 1e-9 * r_px, "{got} vs {r_px}");
    // The depth TIFF reads back as f32 with the centre pixel's range.
    let mut dec =
        tiff::decoder::Decoder::new(std::fs::File::open(out.join("depth.tiff")).unwrap()).unwrap();
    let tiff::decoder::DecodingResult::F32(depth) = dec.read_image().unwrap() else {
        panic!("depth.tiff is not f32");
    };
    let d = ray(&camera(64, f), DQuat::IDENTITY, 32, 32);
    let (t, _) = closest_approach(DVec3::new(0.0, 0.0, -6.636e7), d, DVec3::ZERO, R).unwrap();
    assert!((depth[32 * 64 + 32] as f64 - t).abs() < 1e-6 * t);
}

#[test]
fn a_body_behind_or_across_the_edge_gives_empty_or_clipped_labels() {
    let cam = camera(64, 80.0);
    // Behind the camera: no pixel, no disk, no box, no COCO annotation.
    let mut st = state(DVec3::ZERO, DQuat::IDENTITY, DVec3::X * 1.5e11);
    st.body_position = DVec3::new(0.0, 0.0, -5.0 * R);
    let l = labels::compute(&cam, &st, R, None);
    assert_eq!(l.frame.pixel_counts.body, 0);
    assert!(l.frame.disk.projected_centre.is_none() && l.frame.disk.limb_ellipse.is_none());
    assert!(l.frame.disk.bbox.is_none());
    let coco = files::coco(&[("x.png".into(), &l)]);
    assert_eq!(coco["annotations"].as_array().unwrap().len(), 0);
    // Centred on the right edge (u = 64): the box starts at the limb's
    // left tangent, f tan(β − ρ) + cx, and is clipped at the image edge.
    let beta = (32.0f64 / 80.0).atan();
    st.body_position = DVec3::new(beta.sin(), 0.0, beta.cos()) * 6.0 * R;
    let l = labels::compute(&cam, &st, R, None);
    let rho = (1.0f64 / 6.0).asin();
    let b = l.frame.disk.bbox.unwrap();
    assert!((b[0] - (32.0 + 80.0 * (beta - rho).tan())).abs() < 1e-9);
    assert!((b[0] + b[2] - 64.0).abs() < 1e-12);
    let pc = l.frame.disk.projected_centre.unwrap();
    assert!((pc[0] - 64.0).abs() < 1e-9);
}
