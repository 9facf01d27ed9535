//! Labels through a lens (`labels::compute_through`): each pixel centre's
//! ray is OpenCV's Brown–Conrady distortion inverted (written here, Newton
//! with a numerical Jacobian), and depth, normals and the body mask are
//! the ray–sphere intersection written here; the disk's centre, limb and
//! box are OpenCV's projection of the limb circle (written here); the body
//! mask's edge is the rendered image's limb; the stars' label positions
//! are OpenCV's projection of their catalogue directions.

mod common;

use std::path::PathBuf;

use glam::DVec3;
use optistim::scene::Scene;

const FX: f64 = 300.0;
const CX_CV: f64 = 127.5;
const CY_CV: f64 = 119.5;
const DIST: [f64; 5] = [-0.21, 0.06, 1.5e-3, -8e-4, -0.01];
const W: usize = 256;
const H: usize = 240;
/// The body: radius [m], at this camera-frame direction and range [m].
const RADIUS: f64 = 90.0;
const RANGE: f64 = 1000.0;
const AT: (f64, f64) = (0.22, -0.15);

/// OpenCV's distortion of normalised coordinates.
fn opencv_distort(x: f64, y: f64) -> (f64, f64) {
    let [k1, k2, p1, p2, k3] = DIST;
    let r2 = x * x + y * y;
    let radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
    (
        x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
        y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
    )
}

/// OpenCV's pixel of camera-frame direction d, this crate's convention
/// (centres at +0.5).
fn opencv_pixel(d: DVec3) -> [f64; 2] {
    let (xd, yd) = opencv_distort(d.x / d.z, d.y / d.z);
    [FX * xd + CX_CV + 0.5, FX * yd + CY_CV + 0.5]
}

/// The unit ray of OpenCV pixel (i, j) (this crate's pixel centre): the
/// distortion inverted by Newton with a central-difference Jacobian.
fn opencv_ray(i: usize, j: usize) -> DVec3 {
    let (xd, yd) = ((i as f64 - CX_CV) / FX, (j as f64 - CY_CV) / FX);
    let (mut x, mut y) = (xd, yd);
    for _ in 0..100 {
        let (fx, fy) = opencv_distort(x, y);
        let (ex, ey) = (fx - xd, fy - yd);
        if ex.abs().max(ey.abs()) < 1e-14 {
            break;
        }
        let h = 1e-6;
        let (ax, ay) = opencv_distort(x + h, y);
        let (bx, by) = opencv_distort(x - h, y);
        let (cx, cy) = opencv_distort(x, y + h);
        let (dx, dy) = opencv_distort(x, y - h);
        let (j11, j21, j12, j22) = (
            (ax - bx) / (2.0 * h),
            (ay - by) / (2.0 * h),
            (cx - dx) / (2.0 * h),
            (cy - dy) / (2.0 * h),
        );
        let det = j11 * j22 - j12 * j21;
        x -= (j22 * ex - j12 * ey) / det;
        y -= (-j21 * ex + j11 * ey) / det;
    }
    DVec3::new(x, y, 1.0).normalize()
}

/// Distance along the unit ray from the origin to the sphere, if it hits.
fn hit(dir: DVec3, centre: DVec3) -> Option<f64> {
    let b = dir.dot(centre);
    let disc = b * b - (centre.length_squared() - RADIUS * RADIUS);
    (disc >= 0.0).then(|| b - disc.sqrt())
}

fn body_centre() -> DVec3 {
    DVec3::new(AT.0, AT.1, 1.0).normalize() * RANGE
}

/// A directory with the lens file and a scene (camera frame = world
/// frame, the Sun behind the camera) with `extra` appended.
fn scene(name: &str, extra: &str) -> (PathBuf, Scene) {
    let dir = std::env::temp_dir().join(format!(
        "optistim-labels-lens-{name}-{}",
        std::process::id()
    ));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(
        dir.join("intrinsics.toml"),
        format!(
            "width = {W}\nheight = {H}\ncamera_matrix = [[{FX}, 0.0, {CX_CV}], [0.0, {FX}, {CY_CV}], [0.0, 0.0, 1.0]]\ndistortion = {DIST:?}\n"
        ),
    )
    .unwrap();
    let c = body_centre();
    let sun = c - c.normalize() * 1.495_978_707e11;
    let text = format!(
        "[camera]\nresolution = [{W}, {H}]\npixel_pitch = 10e-6\nfocal_length = {f}\nf_number = 4.0\nexposure = 1e-3\nfull_well = 1e12\nbits = 16\nband = [500e-9, 700e-9]\ndistortion = \"intrinsics.toml\"\n\n[sun]\nspectrum = \"blackbody\"\ntemperature = 5772.0\nirradiance_1au = 1361.0\n\n[body]\nradius = {RADIUS}\nreflectance = {{ model = \"lambert\", albedo = 0.3 }}\n\n[state]\ncamera_position = [0.0, 0.0, 0.0]\ncamera_attitude = [1.0, 0.0, 0.0, 0.0]\nbody_position = [{}, {}, {}]\nsun_position = [{}, {}, {}]\n{extra}",
        c.x,
        c.y,
        c.z,
        sun.x,
        sun.y,
        sun.z,
        f = FX * 10e-6,
    );
    std::fs::write(dir.join("scene.toml"), &text).unwrap();
    let scene = Scene::from_file(&dir.join("scene.toml")).expect("scene");
    (dir, scene)
}

fn labels_of(scene: &Scene) -> optistim::labels::Labels {
    optistim::labels::compute_for(&scene.camera, &scene.state, scene.body.radius, None)
        .expect("labels")
}

#[test]
fn depth_normals_and_mask_are_the_rays_of_opencvs_inverse() {
    let (_, scene) = scene("depth", "");
    let l = labels_of(&scene);
    let im = &l.images;
    assert_eq!((im.width, im.height), (W, H));
    let c = body_centre();
    let (mut hits, mut grazing) = (0, 0);
    for j in 0..H {
        for i in 0..W {
            let k = j * W + i;
            let ray = opencv_ray(i, j);
            match hit(ray, c) {
                Some(t) => {
                    // A ray grazing within 10⁻⁹ of the limb may go either way.
                    let n = (ray * t - c) / RADIUS;
                    if n.dot(ray).abs() < 1e-9 {
                        grazing += 1;
                        continue;
                    }
                    assert_eq!(im.body[k], 1, "pixel ({i}, {j})");
                    hits += 1;
                    let depth = im.depth[k] as f64;
                    assert!((depth / t - 1.0).abs() < 1e-6, "({i}, {j}): {depth} vs {t}");
                    let got = DVec3::new(
                        im.normals[3 * k] as f64,
                        im.normals[3 * k + 1] as f64,
                        im.normals[3 * k + 2] as f64,
                    );
                    assert!((got - n).length() < 1e-5, "({i}, {j}): {got} vs {n}");
                }
                None => assert_eq!(im.body[k], 0, "pixel ({i}, {j})"),
            }
        }
    }
    // The disk is asin(R / range) · fx ≈ 27 px in radius: π · 27² ≈ 2300 px.
    assert!(hits > 2_000, "{hits} pixels on the body");
    assert!(grazing < 5, "{grazing}");
    assert_eq!(l.frame.pixel_counts.body as usize, hits + grazing);
}

/// The disk: its centre is OpenCV's pixel of the body's centre, its limb
/// points lie on OpenCV's image of the limb circle, its box is the
/// distorted limb's (the limb circle sampled densely here), and no limb
/// ellipse is claimed.
#[test]
fn the_disk_is_the_distorted_limb() {
    let (_, scene) = scene("disk", "");
    let disk = labels_of(&scene).frame.disk;
    let c = body_centre();
    let centre = disk.projected_centre.expect("centre");
    let want = opencv_pixel(c);
    assert!((centre[0] - want[0]).hypot(centre[1] - want[1]) < 1e-6);
    assert!(disk.limb_ellipse.is_none());
    // The limb circle: tangent points of the cone from the camera.
    let d2 = c.length_squared();
    let centre_circle = c * (1.0 - RADIUS * RADIUS / d2);
    let r_circle = RADIUS * (d2 - RADIUS * RADIUS).sqrt() / d2.sqrt();
    let e1 = c.cross(DVec3::X).normalize();
    let e2 = c.normalize().cross(e1);
    let mut limb = Vec::new();
    for k in 0..20_000 {
        let t = std::f64::consts::TAU * k as f64 / 20_000.0;
        limb.push(opencv_pixel(
            centre_circle + r_circle * (t.cos() * e1 + t.sin() * e2),
        ));
    }
    assert_eq!(disk.limb_points.len(), optistim::labels::LIMB_POINTS);
    for p in &disk.limb_points {
        let nearest = limb
            .iter()
            .map(|q| (p[0] - q[0]).hypot(p[1] - q[1]))
            .fold(f64::MAX, f64::min);
        assert!(
            nearest < 0.01,
            "limb point {p:?} is {nearest} px off the limb"
        );
    }
    let (x0, x1) = limb
        .iter()
        .fold((f64::MAX, f64::MIN), |a, p| (a.0.min(p[0]), a.1.max(p[0])));
    let (y0, y1) = limb
        .iter()
        .fold((f64::MAX, f64::MIN), |a, p| (a.0.min(p[1]), a.1.max(p[1])));
    assert!(x1 < W as f64 && y0 > 0.0, "the disk is inside the image");
    let b = disk.bbox.expect("box");
    let want = [x0, y0, x1 - x0, y1 - y0];
    for (got, want) in b.iter().zip(want) {
        assert!((got - want).abs() < 1e-3, "box {b:?} vs {want:?}");
    }
}

/// The body mask's edge is the rendered limb: at zero phase the disk is
/// lit to its edge, so every pixel 2 px inside the mask's edge is bright
/// and every pixel 2 px outside it is dark (the resampling spreads the
/// edge over the pixel's footprint and the bilinear lookup).
#[test]
fn the_mask_edge_is_the_rendered_limb() {
    let (_, scene) = scene("edge", "");
    let l = labels_of(&scene);
    let images = common::render(&scene);
    let m = &l.images.body;
    let within = |i: usize, j: usize, value: u8| {
        (j.saturating_sub(2)..(j + 3).min(H))
            .all(|y| (i.saturating_sub(2)..(i + 3).min(W)).all(|x| m[y * W + x] == value))
    };
    let (mut inside, mut outside) = (0, 0);
    for j in 0..H {
        for i in 0..W {
            let r = images.radiance[j * W + i];
            if within(i, j, 1) {
                assert!(r > 0.0, "({i}, {j}) inside the mask is dark");
                inside += 1;
            } else if within(i, j, 0) {
                assert_eq!(r, 0.0, "({i}, {j}) outside the mask is lit");
                outside += 1;
            }
        }
    }
    // A disk of about 27 px radius in a 256 × 240 frame.
    assert!(inside > 1_500 && outside > 50_000, "{inside} {outside}");
}

/// The stars in labels.json sit where OpenCV's formula puts their
/// catalogue directions (the camera frame is the world frame: RA/Dec is
/// the camera direction).
#[test]
fn star_labels_are_the_lens_projected_catalogue() {
    let dirs = [(0.3, -0.22), (-0.31, 0.25), (0.05, 0.28), (-0.2, -0.3)];
    let mut csv = String::from("ra_deg,dec_deg,pm_ra_mas_per_yr,pm_dec_mas_per_yr,v_mag,b_v\n");
    for (x, y) in dirs {
        let d = DVec3::new(x, y, 1.0).normalize();
        let ra = d.y.atan2(d.x).to_degrees().rem_euclid(360.0);
        csv += &format!("{ra},{},0,0,3.0,0.6\n", d.z.asin().to_degrees());
    }
    let dir = std::env::temp_dir().join(format!("optistim-labels-lens-cat-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let catalogue = dir.join("stars.csv");
    std::fs::write(&catalogue, csv).unwrap();
    let (_, scene) = scene(
        "stars",
        &format!("\n[stars]\ncatalogue = \"{}\"\n", catalogue.display()),
    );
    let mut l = labels_of(&scene);
    optistim::labels::add_stars(&mut l, &scene);
    assert_eq!(l.frame.stars.len(), dirs.len());
    for (x, y) in dirs {
        let want = opencv_pixel(DVec3::new(x, y, 1.0));
        let got = l
            .frame
            .stars
            .iter()
            .map(|s| (s.u - want[0]).hypot(s.v - want[1]))
            .fold(f64::MAX, f64::min);
        assert!(
            got < 1e-6,
            "star ({x}, {y}) is {got} px from OpenCV's {want:?}"
        );
    }
}

/// `optistim render --labels` through a lens writes the labels, and a
/// dataset spec with a lens accepts them.
#[test]
fn render_and_dataset_labels_through_a_lens() {
    let (dir, _) = scene("cli", "");
    let out = dir.join("render-out");
    let run = std::process::Command::new(env!("CARGO_BIN_EXE_optistim"))
        .args(["render", "--overwrite", "--labels", "--out"])
        .arg(&out)
        .arg(dir.join("scene.toml"))
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("labels.json")).unwrap()).unwrap();
    let centre = &json["disk"]["projected_centre"];
    let want = opencv_pixel(body_centre());
    assert!(
        (centre[0].as_f64().unwrap() - want[0]).abs() < 1e-6,
        "{centre}"
    );
    let spec = "[dataset]\nscene = \"scene.toml\"\ncount = 2\nseed = 1\nout = \"out\"\noutputs = [\"image\", \"labels\"]\n\n[poses]\ndistance = [900.0, 1100.0]\nphase_deg = [0.0, 30.0]\n";
    optistim::dataset::Spec::from_toml(spec, &dir.join("spec.toml"), None)
        .expect("labels with a lens");
}
