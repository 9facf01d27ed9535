//! `optistim bench --images DIR`: each setting's image and the reference are
//! written as radiance per unit solar irradiance at 1 au, and each phase's
//! geometry as JSON, so another renderer (tools/mitsuba_moon.py) can render
//! the same scene. Checked against closed forms computed here: the phase
//! angle from the written geometry, and the disk-integrated irradiance of a
//! uniform Lambert sphere from the images against a quadrature over the
//! sphere's surface written here (the camera at finite distance).

use std::f64::consts::PI;
use std::path::Path;
use std::process::Command;

const AU: f64 = 1.495_978_707e11;
const RHO: f64 = 0.15;
const RADIUS: f64 = 1737.4e3;

/// The Lambert benchmark Moon at 192×192 px without its map (ρ uniform).
fn small_scene(dir: &Path) -> std::path::PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("configs/moon_bench_lambert.toml")).unwrap();
    let data = root.join("data");
    let text: String = text
        .replace("[1024, 1024]", "[192, 192]")
        .replace("../data", data.to_str().unwrap())
        .lines()
        .filter(|l| !l.starts_with("albedo_map"))
        .map(|l| format!("{l}\n"))
        .collect();
    assert!(text.contains("[192, 192]") && text.contains("model = \"lambert\", albedo = 0.15"));
    let path = dir.join("scene.toml");
    std::fs::write(&path, text).unwrap();
    path
}

fn read_tiff(path: &Path) -> Vec<f32> {
    let file = std::fs::File::open(path).unwrap();
    let mut dec = tiff::decoder::Decoder::new(std::io::BufReader::new(file)).unwrap();
    match dec.read_image().unwrap() {
        tiff::decoder::DecodingResult::F32(v) => v,
        _ => panic!("{}: not f32", path.display()),
    }
}

fn vec3(v: &serde_json::Value) -> [f64; 3] {
    let a: Vec<f64> = v
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    [a[0], a[1], a[2]]
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn norm(a: [f64; 3]) -> f64 {
    (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
}

/// Σ L Ω cos θ over the image, with Ω = cos³θ / (fx fy) (the pinhole's
/// pixel solid angle, to second order in the pixel size).
fn irradiance(img: &[f32], st: &serde_json::Value) -> f64 {
    let (w, h) = (
        st["width"].as_u64().unwrap() as usize,
        st["height"].as_u64().unwrap() as usize,
    );
    let f = |k: &str| st[k].as_f64().unwrap();
    let (fx, fy, cx, cy) = (f("fx"), f("fy"), f("cx"), f("cy"));
    let mut e = 0.0;
    for j in 0..h {
        for i in 0..w {
            let (x, y) = ((i as f64 + 0.5 - cx) / fx, (j as f64 + 0.5 - cy) / fy);
            let cos = 1.0 / (1.0 + x * x + y * y).sqrt();
            e += img[j * w + i] as f64 * cos.powi(4) / (fx * fy);
        }
    }
    e
}

/// The Lambert sphere's irradiance at the camera, on the plane normal to
/// the line of sight to the body centre, per unit solar irradiance at 1 au:
/// ∫ (ρ/π) μ0 E_sun cos e cos θ / r² dA over the lit and visible surface,
/// by the midpoint rule in (colatitude, longitude).
fn surface_irradiance(body: [f64; 3], cam: [f64; 3], sun: [f64; 3]) -> f64 {
    let (nt, np) = (2000, 4000);
    let axis = sub(body, cam);
    let axis_len = norm(axis);
    let mut e = 0.0;
    for i in 0..nt {
        let t = (i as f64 + 0.5) * PI / nt as f64;
        for j in 0..np {
            let p = (j as f64 + 0.5) * 2.0 * PI / np as f64;
            let n = [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()];
            let x = [0, 1, 2].map(|k| body[k] + RADIUS * n[k]);
            let to_sun = sub(sun, x);
            let ds = norm(to_sun);
            let mu0 = (0..3).map(|k| n[k] * to_sun[k]).sum::<f64>() / ds;
            let to_cam = sub(cam, x);
            let r = norm(to_cam);
            let mu = (0..3).map(|k| n[k] * to_cam[k]).sum::<f64>() / r;
            if mu0 <= 0.0 || mu <= 0.0 {
                continue;
            }
            let cos_axis = -(0..3).map(|k| to_cam[k] * axis[k]).sum::<f64>() / (r * axis_len);
            let da = RADIUS * RADIUS * t.sin() * (PI / nt as f64) * (2.0 * PI / np as f64);
            e += RHO / PI * mu0 * (AU / ds).powi(2) * mu * cos_axis / (r * r) * da;
        }
    }
    e
}

#[test]
fn bench_images_hold_the_lambert_sphere_irradiance_and_the_phase() {
    let dir = tempfile::tempdir().unwrap();
    let scene = small_scene(dir.path());
    let out = dir.path().join("images");
    let res = Command::new(env!("CARGO_BIN_EXE_optistim"))
        .arg("bench")
        .arg("--scene")
        .arg(&scene)
        .args(["--phases", "60", "--densities", "1", "--repeats", "1"])
        .args(["--interior", "pixels", "--json"])
        .arg(dir.path().join("bench.json"))
        .arg("--images")
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        res.status.success(),
        "{}",
        String::from_utf8_lossy(&res.stderr)
    );

    let st: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("phase60_state.json")).unwrap())
            .unwrap();
    let body = vec3(&st["body_position"]);
    let to_cam = sub(vec3(&st["camera_position"]), body);
    let to_sun = sub(vec3(&st["sun_position"]), body);
    let dot: f64 = (0..3).map(|k| to_cam[k] * to_sun[k]).sum();
    let phase = (dot / (norm(to_cam) * norm(to_sun))).acos().to_degrees();
    assert!((phase - 60.0).abs() < 1e-9, "phase {phase}");

    let sun_at = vec3(&st["sun_position"]);
    let cam_at = vec3(&st["camera_position"]);
    let want = surface_irradiance(body, cam_at, sun_at);
    let rows: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("bench.json")).unwrap())
            .unwrap();
    let name = rows[0]["image"].as_str().unwrap();
    assert_eq!(name, "phase60_row0.tiff");
    for file in ["phase60_ref.tiff", name] {
        let img = read_tiff(&out.join(file));
        assert_eq!(img.len(), 192 * 192);
        let e = irradiance(&img, &st);
        assert!(
            (e / want - 1.0).abs() < 2e-3,
            "{file}: E {e:e} against {want:e}"
        );
        // Radiance, not flux: the brightest pixel is ρ μ0 / π at most.
        let peak = img.iter().cloned().fold(0.0f32, f32::max) as f64;
        assert!(
            peak <= RHO / PI * 1.001 && peak > 0.5 * RHO / PI,
            "{file}: peak {peak}"
        );
    }
}
