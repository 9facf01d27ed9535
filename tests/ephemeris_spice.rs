//! The SPICE epoch path (anise reading DE421 and the lunar BPC) against
//! CSPICE: `tests/data/spice_reference.csv` was written by
//! `tools/spice_reference.py` with spiceypy from the same kernels, so the
//! reference shares the data but none of the code.
//!
//! Needs the kernels of `tools/fetch_kernels.sh` (in `data/kernels`, or
//! the directory in `OPTISTIM_KERNELS`): without them the tests print a
//! notice and pass, unless `OPTISTIM_REQUIRE_KERNELS=1` (CI), where they fail.

use std::path::PathBuf;

mod common;

use glam::{DMat3, DVec3};
use optistim::ephemeris::{self, parse_epoch, Ephemeris, Spice};

fn kernel_dir() -> PathBuf {
    std::env::var_os("OPTISTIM_KERNELS")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/kernels"))
}

/// The kernels, or None (with a notice) when they are absent and not required.
fn spice() -> Option<Spice> {
    let dir = kernel_dir();
    let present = ephemeris::KERNEL_FILES
        .iter()
        .all(|f| dir.join(f).is_file());
    if !present {
        if std::env::var("OPTISTIM_REQUIRE_KERNELS").as_deref() == Ok("1") {
            panic!(
                "OPTISTIM_REQUIRE_KERNELS=1 but the kernels are not in {} (run tools/fetch_kernels.sh)",
                dir.display()
            );
        }
        eprintln!(
            "NOTICE: SPICE kernels not in {}: test skipped (run tools/fetch_kernels.sh)",
            dir.display()
        );
        return None;
    }
    Some(Spice::from_dir(&dir).expect("kernels load"))
}

struct Row {
    epoch: String,
    et_s: f64,
    moon_wrt_earth_km: DVec3,
    sun_wrt_moon_km: DVec3,
    pa_to_j2000: DMat3,
    me_to_j2000: DMat3,
}

fn matrix(v: &[f64]) -> DMat3 {
    DMat3::from_cols_array(&[v[0], v[3], v[6], v[1], v[4], v[7], v[2], v[5], v[8]])
}

fn reference() -> Vec<Row> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/spice_reference.csv");
    let text = std::fs::read_to_string(path).unwrap();
    let rows: Vec<Row> = text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with("epoch"))
        .map(|l| {
            let cells: Vec<&str> = l.split(',').collect();
            let v: Vec<f64> = cells[1..].iter().map(|c| c.parse().unwrap()).collect();
            assert_eq!(v.len(), 25, "{l}");
            Row {
                epoch: cells[0].to_string(),
                et_s: v[0],
                moon_wrt_earth_km: DVec3::new(v[1], v[2], v[3]),
                sun_wrt_moon_km: DVec3::new(v[4], v[5], v[6]),
                pa_to_j2000: matrix(&v[7..16]),
                me_to_j2000: matrix(&v[16..25]),
            }
        })
        .collect();
    assert!(rows.len() >= 10);
    rows
}

/// Angle of the rotation taking `a` to `b`, degrees (stable for tiny angles).
fn rotation_angle_deg(a: DMat3, b: DMat3) -> f64 {
    let d = a.transpose() * b;
    let skew = DVec3::new(
        d.y_axis.z - d.z_axis.y,
        d.z_axis.x - d.x_axis.z,
        d.x_axis.y - d.y_axis.x,
    );
    (skew.length() / 2.0).asin().to_degrees()
}

#[test]
fn positions_and_orientation_match_cspice() {
    let Some(spice) = spice() else { return };
    let (mut worst_moon_m, mut worst_sun_m, mut worst_pa, mut worst_me) =
        (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for r in reference() {
        // At CSPICE's own TDB instant: this compares the ephemerides alone.
        let t = anise::prelude::Epoch::from_et_seconds(r.et_s);
        let moon = spice.moon_from_earth(t).unwrap();
        let sun = spice.sun_from_moon(t).unwrap();
        let moon_err = (moon - r.moon_wrt_earth_km * 1e3).length();
        let sun_err = (sun - r.sun_wrt_moon_km * 1e3).length();
        let pa = rotation_angle_deg(spice.moon_pa_to_j2000(t).unwrap(), r.pa_to_j2000);
        let me = rotation_angle_deg(spice.moon_to_j2000(t).unwrap(), r.me_to_j2000);
        eprintln!(
            "{}: Moon {moon_err:.2e} m, Sun {sun_err:.2e} m, PA {pa:.1e} deg, ME {me:.1e} deg",
            r.epoch
        );
        worst_moon_m = worst_moon_m.max(moon_err);
        worst_sun_m = worst_sun_m.max(sun_err);
        worst_pa = worst_pa.max(pa);
        worst_me = worst_me.max(me);
    }
    // The brief's bounds are 1 km and 1e-3 deg; the same kernels read by two
    // codes should agree to round-off, so hold them to metres and µdeg.
    assert!(worst_moon_m < 1.0, "Moon position off by {worst_moon_m} m");
    assert!(worst_sun_m < 1.0, "Sun position off by {worst_sun_m} m");
    assert!(worst_pa < 1e-6, "MOON_PA orientation off by {worst_pa} deg");
    assert!(worst_me < 1e-6, "MOON_ME orientation off by {worst_me} deg");
}

#[test]
fn epoch_text_gives_cspice_ephemeris_time() {
    for r in reference() {
        let t = parse_epoch(&r.epoch, "epoch").unwrap();
        let dt = t.to_et_seconds() - r.et_s;
        // Before 1972 SPICE takes TAI − UTC = 9 s, hifitime 0 s: a
        // documented 9 s offset (module doc of `optistim::ephemeris`).
        let year: i32 = r.epoch[..4].parse().unwrap();
        let utc = !r.epoch.ends_with("TDB");
        // naif0011.tls predates the 2017-01-01 leap second hifitime has.
        let expected = match year {
            _ if !utc => 0.0,
            ..1972 => -9.0,
            2017.. => 1.0,
            _ => 0.0,
        };
        assert!(
            (dt - expected).abs() < 1e-3,
            "{}: ET differs from CSPICE by {dt} s",
            r.epoch
        );
    }
}

#[test]
fn me_offset_matches_the_frame_kernel() {
    // CSPICE's MOON_ME and MOON_PA rotations give the constant offset.
    for r in reference() {
        let me_to_pa = r.pa_to_j2000.transpose() * r.me_to_j2000;
        let d = rotation_angle_deg(ephemeris::moon_me_to_pa(), me_to_pa);
        assert!(d < 1e-9, "{}: {d} deg", r.epoch);
    }
}

#[test]
fn epochs_outside_the_kernels_are_named_errors() {
    let Some(spice) = spice() else { return };
    let t = parse_epoch("2060-01-01T00:00:00", "state.epoch").unwrap();
    let e = spice.moon_from_earth(t).unwrap_err().to_string();
    assert!(e.contains("coverage"), "{e}");
    let e = spice.moon_to_j2000(t).unwrap_err().to_string();
    assert!(e.contains("coverage"), "{e}");
}

#[test]
fn bad_kernel_files_are_named_errors() {
    let dir = tempfile::tempdir().unwrap();
    let text = dir.path().join("naif.tls");
    std::fs::write(&text, "KPL/LSK\n\\begindata\n").unwrap();
    let e = Spice::load(std::slice::from_ref(&text))
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("naif.tls") && e.contains("text kernel"), "{e}");
    let Some(_) = spice() else { return };
    // A real kernel cut short: an error naming the file, never a panic.
    let whole = std::fs::read(kernel_dir().join("moon_pa_de421_1900-2050.bpc")).unwrap();
    for len in [8usize, 1024, 1500, 4096, whole.len() / 2] {
        let cut = dir.path().join(format!("cut{len}.bpc"));
        std::fs::write(&cut, &whole[..len]).unwrap();
        let r = Spice::load(std::slice::from_ref(&cut))
            .and_then(|s| s.moon_pa_to_j2000(parse_epoch("2004-08-19T00:00:00", "t").unwrap()));
        let e = r
            .expect_err("a truncated kernel must not give a rotation")
            .to_string();
        assert!(
            e.contains(&format!("cut{len}")) || e.contains("frame"),
            "{e}"
        );
    }
}

// ------------------------------------------------------------ scene files

const SCENE_HEAD: &str = r#"[camera]
resolution = [64, 48]
pixel_pitch = 13.3e-6
fov_deg = 6.0
f_number = 2.5
exposure = 2.0e-5
full_well = 1.0e5
bits = 12
band = [450e-9, 820e-9]

[sun]
spectrum = "blackbody"
temperature = 5772.0

[body]
radius = 1737.4e3
reflectance = { model = "lambert", albedo = 0.12 }
"#;

/// A scene at `epoch` with the fetched kernels; `extra_state` lines go in `[state]`.
fn epoch_scene(epoch: &str, extra_state: &str) -> String {
    let k = kernel_dir();
    let quoted = |s: &str| toml::Value::String(s.to_string()).to_string();
    let kernels: Vec<String> = ephemeris::KERNEL_FILES
        .iter()
        .map(|f| quoted(&k.join(f).to_string_lossy()))
        .collect();
    format!(
        "{SCENE_HEAD}\n[state]\nepoch = {}\ncamera_position = [0.0, 0.0, -8.0e7]\n\
         camera_attitude = [1.0, 0.0, 0.0, 0.0]\n{extra_state}\n\
         [ephemeris]\nkernels = [{}]\n",
        quoted(epoch),
        kernels.join(", "),
    )
}

#[test]
fn scene_epoch_gives_the_cspice_sun_and_moon_attitude() {
    let Some(_) = spice() else { return };
    let path = std::path::Path::new("epoch_scene.toml");
    for r in reference().iter().filter(|r| r.epoch.starts_with("2004")) {
        let text = epoch_scene(&r.epoch, "");
        let scene = optistim::scene::Scene::from_toml(&text, path).unwrap();
        let st = scene.state;
        assert_eq!(st.body_position, DVec3::ZERO);
        let sun_err = (st.sun_position - r.sun_wrt_moon_km * 1e3).length();
        assert!(sun_err < 1.0, "{}: Sun off by {sun_err} m", r.epoch);
        let body = DMat3::from_quat(st.body_attitude);
        let d = rotation_angle_deg(body, r.me_to_j2000);
        assert!(d < 1e-6, "{}: body attitude off by {d} deg", r.epoch);
    }
}

#[test]
fn scene_epoch_errors_name_the_file_and_key() {
    let Some(_) = spice() else { return };
    let path = std::path::Path::new("epoch_scene.toml");
    let cases = [
        (epoch_scene("2060-01-01T00:00:00", ""), "state.epoch"),
        (epoch_scene("2004-13-01T00:00:00", ""), "state.epoch"),
        (epoch_scene("JD 2451545.0 TDB", ""), "state.epoch"),
        (
            epoch_scene("2004-08-19T00:00:00", "sun_position = [1e11, 0.0, 0.0]"),
            "state.sun_position",
        ),
        (
            epoch_scene("2004-08-19T00:00:00", "")
                .replace("camera_position = [0.0, 0.0, -8.0e7]\n", ""),
            "state.camera_position",
        ),
        (
            epoch_scene("2004-08-19T00:00:00", "")
                .replace("[ephemeris]", "[ephemeris]\nobserver = { spk_id = -238 }"),
            "state.camera_position",
        ),
        (
            epoch_scene("2004-08-19T00:00:00", "")
                .split("[ephemeris]")
                .next()
                .unwrap()
                .to_string(),
            "ephemeris",
        ),
    ];
    for (text, key) in cases {
        let e = optistim::scene::Scene::from_toml(&text, path)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("epoch_scene.toml:"), "{e}");
        assert!(e.contains(key), "expected `{key}` in: {e}");
        assert!(!e.contains('\n'), "not one line: {e}");
    }
}

#[test]
fn scene_observer_from_an_spk_is_the_bodys_position() {
    let Some(spice) = spice() else { return };
    // The Earth (399) as the "spacecraft": camera = Earth relative to the Moon.
    let r = &reference()[2];
    let text = epoch_scene(&r.epoch, "")
        .replace("camera_position = [0.0, 0.0, -8.0e7]\n", "")
        .replace("[ephemeris]", "[ephemeris]\nobserver = { spk_id = 399 }");
    let scene = optistim::scene::Scene::from_toml(&text, std::path::Path::new("s.toml")).unwrap();
    let t = parse_epoch(&r.epoch, "t").unwrap();
    let expected = -spice.moon_from_earth(t).unwrap();
    assert!((scene.state.camera_position - expected).length() < 1e-3);
    // And independently of anise: CSPICE's Moon wrt Earth (the epoch is
    // after 1972 and before 2017, so the time scales agree to < 1 ms).
    let err = (scene.state.camera_position + r.moon_wrt_earth_km * 1e3).length();
    assert!(err < 5.0, "camera off by {err} m");
}

mod properties {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig { cases: 64, .. ProptestConfig::default() })]

        /// Any epoch text: a state or an error naming `state.epoch`, never a panic.
        #[test]
        fn epoch_key_is_ok_or_a_named_error(
            epoch in prop_oneof![
                "[0-9]{4}-[0-9]{2}-[0-9]{2}T[0-9]{2}:[0-9]{2}:[0-9]{2}(\\.[0-9]{1,12})?( UTC| TDB| TAI| XYZ)?",
                "\\PC{0,40}",
            ]
        ) {
            let parsed = parse_epoch(&epoch, "state.epoch");
            if let Err(e) = &parsed {
                prop_assert!(e.to_string().contains("state.epoch"), "{}", e);
            }
            if spice().is_none() {
                return Ok(());
            }
            let text = epoch_scene(&epoch, "");
            if let Err(e) = optistim::scene::Scene::from_toml(&text, std::path::Path::new("p.toml")) {
                let m = e.to_string();
                prop_assert!(m.starts_with("p.toml:") && !m.contains('\n'), "{}", m);
            }
        }
    }
}

// ------------------------------------------------------------ AMIE images

#[test]
fn amie_geometry_from_spice_matches_the_labels() {
    use optistim::validate::{amie, ephem::Analytic};
    let Some(spice) = spice() else { return };
    for p in [common::IMG1, common::IMG2] {
        let analytic = amie::load(p).unwrap().scene;
        let s = amie::with_ephemeris(&analytic, &spice).unwrap();
        let c = s.geometry_check();
        let d = amie::ephemeris_difference(&analytic, &Analytic, &spice).unwrap();
        eprintln!(
            "{}: SPICE sub-solar {:.4} deg from label, solar distance {:.2} km from label; \
             analytic - SPICE {d:?}",
            s.label.product_id,
            c.sub_solar_error_deg,
            c.solar_distance_km - s.label.solar_distance_km,
        );
        // The labels were made with SPICE from a DE4xx ephemeris: distance to
        // a few km, sub-solar point to the label's 0.01 deg rounding plus the
        // labels' lunar frame (IAU_MOON, ~0.005 deg from ME).
        assert!((c.solar_distance_km - s.label.solar_distance_km).abs() < 5.0);
        assert!(c.sub_solar_error_deg < 0.02, "{}", c.sub_solar_error_deg);
        // The analytic theories' documented accuracy (validate::ephem doc):
        // Moon ~2000 km, Sun direction from the Moon < 0.003 deg + Moon
        // error, IAU 2009 frame ~150 m on the surface (0.005 deg) from ME.
        assert!(d.moon_position_km < 2500.0, "{d:?}");
        assert!(d.sun_direction_deg < 0.01, "{d:?}");
        assert!(d.moon_orientation_deg < 0.01, "{d:?}");
    }
}

// ------------------------------------------------------------ trajectories

#[test]
fn epoch_trajectory_takes_sun_and_moon_from_the_kernels() {
    use optistim::facility::epoch_trajectory;
    let Some(spice) = spice() else { return };
    let refs = reference();
    let (a, b) = (&refs[2], &refs[3]); // the two 2004 epochs (UTC)
    let text = format!(
        "# two states\ncam_qw,cam_qx,cam_qy,cam_qz,epoch,cam_x_km,cam_y_km,cam_z_km\n\
         1,0,0,0,{},1000,-2000,300000\n\n0,1,0,0,{},-5e4,0,0\n",
        a.epoch.trim_end_matches(" UTC"),
        b.epoch
    );
    let path = std::path::Path::new("traj.csv");
    assert!(epoch_trajectory::is_epoch_header(&text));
    let traj = epoch_trajectory::parse(&text, path, &spice).unwrap();
    assert_eq!(traj.states.len(), 2);
    for (s, r) in traj.states.iter().zip([a, b]) {
        let sun_err = (s.sun_position - r.sun_wrt_moon_km * 1e3).length();
        assert!(sun_err < 1.0, "Sun off by {sun_err} m");
        let d = rotation_angle_deg(DMat3::from_quat(s.body_attitude.unwrap()), r.me_to_j2000);
        assert!(d < 1e-6, "{d} deg");
        assert_eq!(s.body_position, Some(DVec3::ZERO));
    }
    let s0 = &traj.states[0];
    assert_eq!(s0.t, 0.0);
    assert_eq!(s0.camera_position, DVec3::new(1e6, -2e6, 3e8));
    // t: TDB seconds between the epochs, as CSPICE's str2et gives them.
    let dt = traj.states[1].t - (b.et_s - a.et_s);
    assert!(dt.abs() < 1e-3, "{dt}");
    assert!((traj.states[1].camera_attitude.x - 1.0).abs() < 1e-12);
}

#[test]
fn epoch_trajectory_errors_name_file_line_and_column() {
    use optistim::facility::epoch_trajectory;
    let Some(spice) = spice() else { return };
    let head = "epoch,cam_x_km,cam_y_km,cam_z_km,cam_qw,cam_qx,cam_qy,cam_qz\n";
    let ok = "2004-08-19T00:00:00,0,0,-1e5,1,0,0,0\n";
    let cases = [
        (
            format!("{head}{ok}2004-08-18T00:00:00,0,0,-1e5,1,0,0,0\n"),
            "line 3: column `epoch`",
        ),
        (
            format!("{head}2060-01-01T00:00:00,0,0,-1e5,1,0,0,0\n"),
            "line 2: column `epoch`",
        ),
        (
            format!("{head}2004-08-19,0,0,-1e5,1,0,0,0\n"),
            "line 2: column `epoch`",
        ),
        (
            format!("{head}{ok}2004-08-20T00:00:00,0,x,-1e5,1,0,0,0\n"),
            "line 3: column `cam_y_km`",
        ),
        (
            format!("{head}2004-08-19T00:00:00,0,0,-1e5,0,0,0,0\n"),
            "line 2: column `cam_qw`",
        ),
        (
            format!("{head}2004-08-19T00:00:00,0,0\n"),
            "line 2: expected 8 fields",
        ),
        (
            "epoch,cam_x_km\n".to_string(),
            "line 1: missing required column `cam_y_km`",
        ),
        (
            format!("{},sun_x\n", head.trim_end()),
            "line 1: unknown column `sun_x`",
        ),
        (head.to_string(), "no states"),
    ];
    for (text, want) in cases {
        let e = epoch_trajectory::parse(&text, std::path::Path::new("traj.csv"), &spice)
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("traj.csv: ") && e.contains(want),
            "expected `{want}` in: {e}"
        );
        assert!(!e.contains('\n'), "{e}");
    }
}

mod trajectory_properties {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig { cases: 128, .. ProptestConfig::default() })]

        /// Any rows under a valid header: a trajectory or an error naming
        /// the file, never a panic.
        #[test]
        fn epoch_rows_are_ok_or_named_errors(
            rows in proptest::collection::vec(
                prop_oneof![
                    "20[0-4][0-9]-[01][0-9]-[0-3][0-9]T[0-2][0-9]:[0-5][0-9]:[0-5][0-9](,-?[0-9e.]{1,6}){7}",
                    "[-0-9a-zT:., e]{0,60}",
                ],
                0..4,
            )
        ) {
            use optistim::facility::epoch_trajectory;
            let Some(spice) = spice() else { return Ok(()) };
            let text = format!(
                "epoch,cam_x_km,cam_y_km,cam_z_km,cam_qw,cam_qx,cam_qy,cam_qz\n{}\n",
                rows.join("\n")
            );
            if let Err(e) = epoch_trajectory::parse(&text, std::path::Path::new("p.csv"), &spice) {
                let m = e.to_string();
                prop_assert!(m.starts_with("p.csv: ") && !m.contains('\n'), "{}", m);
            }
        }
    }
}

#[test]
fn the_epoch_example_scene_looks_at_the_moon() {
    let Some(_) = spice() else { return };
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("configs/moon_epoch.toml");
    let scene = optistim::scene::Scene::from_file(&path).unwrap();
    let st = scene.state;
    // The attitude in the file was computed with CSPICE (Moon wrt Earth,
    // naif0011: 1 s off after 2017, ~1 km of lunar motion, 1.5e-4 deg).
    let boresight = st.camera_attitude * DVec3::Z;
    let to_moon = (st.body_position - st.camera_position).normalize();
    let off = boresight.angle_between(to_moon).to_degrees();
    assert!(off < 1e-3, "boresight {off} deg from the Moon's centre");
    let range_km = (st.body_position - st.camera_position).length() / 1e3;
    assert!((range_km - 399_781.07).abs() < 2.0, "{range_km}");
}

/// LIME's geometry (`summary.json`, `lime`) from an epoch, against the
/// values published in the README of spicedmoon, the geometry library of
/// the LIME toolbox (CSPICE with DE421, `moon_pa_de421_1900-2050.bpc` and
/// the MOON_ME frame): at 2025-01-10 00:00:00 UTC an observer at
/// (4510, 3480, 4060) km from the Earth's centre in J2000 axes sees the
/// sub-observer point at 2.321035° E, −5.358904° N, the sub-solar point at
/// 0.9199491 rad E, −0.02542042 rad N, the phase 50.433894°, and the Sun
/// 147 349 561.9 km from the Moon. Its latitudes are planetographic on an
/// ellipsoid of radii 1738.1 and 1736.0 km (tan φ_g = tan φ_c / (1 − f)²);
/// ours are planetocentric, on the sphere (0.013° apart here, which moves
/// LIME by 1e-5). spicedmoon's `naif0011.tls` lacks the 2017 leap second,
/// so its epoch is 1 s earlier than ours: ~3e-4° here.
#[test]
fn lime_geometry_from_an_epoch_matches_published_values() {
    let Some(spice) = spice() else { return };
    let epoch = "2025-01-10T00:00:00";
    let t = parse_epoch(epoch, "epoch").unwrap();
    let moon = spice.moon_from_earth(t).unwrap();
    let camera = DVec3::new(4510.0, 3480.0, 4060.0) * 1e3 - moon;
    let text = epoch_scene(epoch, "")
        .replace(
            "camera_position = [0.0, 0.0, -8.0e7]",
            &format!(
                "camera_position = [{:.3}, {:.3}, {:.3}]",
                camera.x, camera.y, camera.z
            ),
        )
        .replace(
            "radius = 1737.4e3\n",
            "radius = 1737.4e3\nlime_reference = true\n",
        );
    let path = std::path::Path::new("epoch_scene.toml");
    let scene = optistim::scene::Scene::from_toml(&text, path).unwrap();
    let mut renderer = optistim::render::Renderer::new(scene.camera.pinhole.clone());
    let pixels = optistim::render::detector::PixelGeometry::new(&renderer);
    let summary = optistim::render::detector::render_scene(&scene, &mut renderer, &pixels)
        .unwrap()
        .summary;
    let g = summary
        .lime
        .expect("a lime_reference body reports LIME")
        .geometry;
    let flattening: f64 = (1738.1 - 1736.0) / 1738.1;
    let centric = |graphic_deg: f64| {
        (graphic_deg.to_radians().tan() * (1.0 - flattening).powi(2))
            .atan()
            .to_degrees()
    };
    let angles = [
        (
            "observer longitude",
            g.observer_selenographic_lon_deg,
            2.321034649559275,
        ),
        (
            "observer latitude",
            g.observer_selenographic_lat_deg,
            centric(-5.3589043558009095),
        ),
        (
            "Sun longitude",
            g.sun_selenographic_lon_deg,
            0.9199491298659819f64.to_degrees(),
        ),
        (
            "Sun latitude",
            g.sun_selenographic_lat_deg,
            centric((-0.02542042276583308f64).to_degrees()),
        ),
        ("phase", g.phase_deg, 50.433894317010626),
    ];
    for (what, got, published) in angles {
        eprintln!(
            "{what}: {got}° against {published}° ({:+.1e})",
            got - published
        );
        assert!(
            (got - published).abs() < 5e-4,
            "{what}: {got}° against {published}°"
        );
    }
    let sun_km = g.sun_distance_m / 1e3;
    assert!(
        (sun_km - 147_349_561.92).abs() < 50.0,
        "Sun–Moon {sun_km} km"
    );
}
