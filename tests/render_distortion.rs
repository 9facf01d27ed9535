//! `camera.distortion` in the render: a small Lambert sphere at zero phase
//! placed at a grid of field positions lands, in the distorted image, where
//! OpenCV's Brown–Conrady formula (written here) puts its centre (within
//! 0.05 px), and its disk-integrated irradiance through the lens is the
//! pinhole render's within 0.2 % and the Lambert sphere's closed form
//! (2/3 · A · E☉ · (R/D)², geometric albedo 2A/3) within 0.5 % (the
//! pinhole render of a 2.4 px spot is itself 0.3 % off it at the corner):
//! the resampling moves light, it makes or loses none.

mod common;

use std::path::{Path, PathBuf};

use optistim::scene::Scene;

const AU: f64 = 1.495_978_707e11;
const ALBEDO: f64 = 0.3;
/// Focal length [px] and principal point (OpenCV's convention).
const FX: f64 = 300.0;
const CX_CV: f64 = 127.5;
const CY_CV: f64 = 119.5;
/// k1, k2, p1, p2, k3.
const DIST: [f64; 5] = [-0.21, 0.06, 1.5e-3, -8e-4, -0.01];
/// Sample points per pixel and axis: the grid's spots are 2.4 px across,
/// where the default 4 leaves the sampling up to 0.3 % of a spot's
/// irradiance and 8 up to 0.09 % (measured over this grid).
const SUPERSAMPLE: usize = 8;
/// Body radius [m] and range [m]: 2.4 px across at FX.
const RADIUS: f64 = 4.0;
const RANGE: f64 = 1000.0;

/// OpenCV's projection (cv::projectPoints), written here: the pixel of
/// camera-frame direction (x, y, 1), with pixel centres at integers.
fn opencv_pixel(x: f64, y: f64, d: [f64; 5]) -> (f64, f64) {
    let [k1, k2, p1, p2, k3] = d;
    let r2 = x * x + y * y;
    let radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
    let xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
    let yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
    (FX * xd + CX_CV, FX * yd + CY_CV)
}

/// A directory holding the intrinsics file of coefficients `d`.
fn lens_dir(name: &str, d: [f64; 5]) -> PathBuf {
    let dir =
        std::env::temp_dir().join(format!("optistim-distortion-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let text = format!(
        "width = 256\nheight = 240\ncamera_matrix = [[{FX}, 0.0, {CX_CV}], [0.0, {FX}, {CY_CV}], [0.0, 0.0, 1.0]]\ndistortion = {d:?}\n"
    );
    std::fs::write(dir.join("intrinsics.toml"), text).unwrap();
    dir
}

/// The scene with the body's centre along camera-frame direction
/// (x, y, 1), the camera at the origin with the identity attitude (the
/// camera frame is the world frame) and the Sun behind it.
fn scene(dir: &Path, x: f64, y: f64, supersample: usize) -> Scene {
    Scene::from_toml(&scene_text(x, y, supersample), &dir.join("scene.toml")).expect("scene")
}

/// The text of [`scene`], its lens file `intrinsics.toml` beside it.
fn scene_text(x: f64, y: f64, supersample: usize) -> String {
    let body = glam::DVec3::new(x, y, 1.0).normalize() * RANGE;
    let sun = body + (-body).normalize() * AU;
    format!(
        r#"
[camera]
resolution = [256, 240]
pixel_pitch = 10e-6
focal_length = {f}
f_number = 4.0
exposure = 1e-3
full_well = 1e12
bits = 16
band = [500e-9, 700e-9]
distortion = "intrinsics.toml"
distortion_supersample = {supersample}

[sun]
spectrum = "blackbody"
temperature = 5772.0
irradiance_1au = 1361.0

[body]
radius = {RADIUS}
reflectance = {{ model = "lambert", albedo = {ALBEDO} }}

[state]
camera_position = [0.0, 0.0, 0.0]
camera_attitude = [1.0, 0.0, 0.0, 0.0]
body_position = [{bx}, {by}, {bz}]
sun_position = [{sx}, {sy}, {sz}]
"#,
        f = FX * 10e-6,
        bx = body.x,
        by = body.y,
        bz = body.z,
        sx = sun.x,
        sy = sun.y,
        sz = sun.z,
    )
}

/// Electron-weighted centroid, this crate's pixel coordinates (centres at
/// +0.5).
fn centroid(e: &[f32], width: usize) -> (f64, f64) {
    let (mut s, mut sx, mut sy) = (0.0, 0.0, 0.0);
    for (k, &v) in e.iter().enumerate() {
        let v = v as f64;
        s += v;
        sx += v * ((k % width) as f64 + 0.5);
        sy += v * ((k / width) as f64 + 0.5);
    }
    (sx / s, sy / s)
}

#[test]
fn a_grid_of_spots_lands_on_opencvs_formula_and_keeps_its_irradiance() {
    let dir = lens_dir("grid", DIST);
    let mut worst: f64 = 0.0;
    for y in [-0.3, 0.0, 0.3] {
        for x in [-0.33, 0.0, 0.33] {
            let scene = scene(&dir, x, y, SUPERSAMPLE);
            assert!(
                scene.camera.render_pinhole().width > 256,
                "barrel: wider ideal grid"
            );
            let images = common::render(&scene);
            let (u, v) = centroid(&images.electrons, 256);
            let (u_cv, v_cv) = opencv_pixel(x, y, DIST);
            let err = (u - (u_cv + 0.5)).hypot(v - (v_cv + 0.5));
            worst = worst.max(err);
            assert!(
                err < 0.05,
                "({x}, {y}): centroid ({u:.3}, {v:.3}), OpenCV ({:.3}, {:.3})",
                u_cv + 0.5,
                v_cv + 0.5
            );
            // Disk irradiance: the closed form with the band's solar
            // irradiance at the body's distance from the Sun (1 au), for
            // the render through the lens and without it.
            let mut plain = scene.clone();
            plain.camera.distortion = None;
            let without = common::render(&plain).summary.irradiance_at_pupil_w_m2;
            let s = &images.summary;
            let closed = 2.0 / 3.0 * ALBEDO * s.band_irradiance_1au_w_m2 * (RADIUS / RANGE).powi(2);
            let (lensed, bare) = (s.irradiance_at_pupil_w_m2 / closed, without / closed);
            eprintln!(
                "({x}, {y}): centroid error {err:.4} px; irradiance / closed form: lens {lensed:.5}, pinhole {bare:.5}"
            );
            assert!(
                (lensed / bare - 1.0).abs() < 2e-3,
                "({x}, {y}): {lensed} vs {bare}"
            );
            assert!((lensed - 1.0).abs() < 5e-3, "({x}, {y}): {lensed}");
        }
    }
    eprintln!("worst centroid error {worst:.4} px");
}

/// Without coefficients the lens is the identity: the same total electrons
/// and centroid as the pinhole camera with the same K (the resampling
/// smooths the body's edge, so pixels are not compared one by one).
#[test]
fn zero_coefficients_give_the_pinhole_image() {
    let dir = lens_dir("zero", [0.0; 5]);
    let lensed = scene(&dir, 0.2, -0.1, 4);
    let mut plain = lensed.clone();
    plain.camera.distortion = None;
    let (a, b) = (common::render(&lensed), common::render(&plain));
    let total = |e: &[f32]| e.iter().map(|&v| v as f64).sum::<f64>();
    assert!((total(&a.electrons) / total(&b.electrons) - 1.0).abs() < 1e-3);
    let (ca, cb) = (centroid(&a.electrons, 256), centroid(&b.electrons, 256));
    assert!((ca.0 - cb.0).hypot(ca.1 - cb.1) < 0.02, "{ca:?} {cb:?}");
}

#[test]
fn a_lens_file_that_disagrees_with_the_camera_is_a_one_line_error() {
    let dir = lens_dir("bad", DIST);
    let text = std::fs::read_to_string(dir.join("intrinsics.toml")).unwrap();
    std::fs::write(
        dir.join("intrinsics.toml"),
        text.replace("height = 240", "height = 250"),
    )
    .unwrap();
    let body = "[body]\nradius = 4.0\nreflectance = { model = \"lambert\", albedo = 0.3 }\n";
    let toml = format!(
        "[camera]\nresolution = [256, 240]\npixel_pitch = 10e-6\nfocal_length = 3e-3\nf_number = 4.0\nexposure = 1e-3\nfull_well = 1e12\nbits = 16\nband = [500e-9, 700e-9]\ndistortion = \"intrinsics.toml\"\n\n[sun]\nspectrum = \"blackbody\"\ntemperature = 5772.0\n\n{body}\n[state]\ncamera_position = [0.0, 0.0, 0.0]\ncamera_attitude = [1.0, 0.0, 0.0, 0.0]\nbody_position = [0.0, 0.0, 1000.0]\nsun_position = [0.0, 0.0, -1.5e11]\n"
    );
    let e = Scene::from_toml(&toml, &dir.join("scene.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("camera.distortion") && !e.contains('\n'), "{e}");
    assert!(e.contains("256×250"), "{e}");
}

/// The lens's ideal grid and tables count in the memory bound, checked
/// before anything is allocated: a 6000 × 6000 camera passes alone
/// (1.6 GiB of images) but not with a lens (about 4.6 GiB).
#[test]
fn a_lens_beyond_the_memory_bound_is_refused_up_front() {
    let dir = lens_dir("huge", DIST);
    std::fs::write(
        dir.join("intrinsics.toml"),
        "width = 6000\nheight = 6000\ncamera_matrix = [[7000.0, 0.0, 2999.5], [0.0, 7000.0, 2999.5], [0.0, 0.0, 1.0]]\ndistortion = [-0.1, 0.0, 0.0, 0.0, 0.0]\n",
    )
    .unwrap();
    let text = scene_text(0.0, 0.0, 4)
        .replace("resolution = [256, 240]", "resolution = [6000, 6000]")
        .replace("focal_length = 0.003", "focal_length = 0.07");
    let e = Scene::from_toml(&text, &dir.join("scene.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("camera.distortion") && e.contains("GiB"), "{e}");
    let plain = text
        .replace("distortion = \"intrinsics.toml\"\n", "")
        .replace("distortion_supersample = 4\n", "");
    Scene::from_toml(&plain, &dir.join("scene.toml")).expect("the camera alone fits");
}

/// A star seen through the lens lands where OpenCV's formula puts its
/// direction (within 0.05 px): the stars are drawn on the distorted
/// pixels, as the body's image is resampled onto them. The camera frame is
/// the world frame here, so the star's RA/Dec is its camera direction.
#[test]
fn a_star_through_the_lens_lands_on_opencvs_formula() {
    let dir = lens_dir("star", DIST);
    for (x, y) in [(0.3, -0.22), (-0.31, 0.25), (0.05, 0.28)] {
        let d = glam::DVec3::new(x, y, 1.0).normalize();
        let (ra, dec) = (
            d.y.atan2(d.x).to_degrees().rem_euclid(360.0),
            d.z.asin().to_degrees(),
        );
        let catalogue = dir.join("stars.csv");
        std::fs::write(
            &catalogue,
            format!("ra_deg,dec_deg,pm_ra_mas_per_yr,pm_dec_mas_per_yr,v_mag,b_v\n{ra},{dec},0,0,2.0,0.6\n"),
        )
        .unwrap();
        let text = scene_text(0.0, 0.0, 4).replace(
            "distortion_supersample = 4\n",
            "distortion_supersample = 4\npsf = { model = \"gaussian\", sigma_px = 0.8 }\n",
        ) + &format!("\n[stars]\ncatalogue = \"{}\"\n", catalogue.display());
        let scene = Scene::from_toml(&text, &dir.join("scene.toml")).expect("scene");
        let images = common::render(&scene);
        let (u_cv, v_cv) = opencv_pixel(x, y, DIST);
        // The star's own window (the body sits at the centre, far away).
        let (i0, j0) = (u_cv.round() as usize - 6, v_cv.round() as usize - 6);
        let mut window = vec![0.0f32; 256 * 240];
        for j in j0..j0 + 13 {
            for i in i0..i0 + 13 {
                window[j * 256 + i] = images.electrons[j * 256 + i];
            }
        }
        let (u, v) = centroid(&window, 256);
        let err = (u - (u_cv + 0.5)).hypot(v - (v_cv + 0.5));
        println!("star at ({x}, {y}): ({u:.4}, {v:.4}) vs OpenCV ({u_cv:.4}, {v_cv:.4}) + 0.5: {err:.4} px");
        assert!(err < 0.05, "star off by {err} px");
    }
}
