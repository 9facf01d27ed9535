//! Shared helpers of the integration tests: scenes built from TOML text and
//! independent references (solid angles, phase laws) written here, not taken
//! from the renderer.
#![allow(dead_code)]

use std::path::Path;

use glam::{DMat3, DQuat, DVec3};
use optistim::radiometry::ScatteringGeometry;
use optistim::render::detector::{render_scene, PixelGeometry, SceneImages};
use optistim::render::Renderer;
use optistim::scene::Scene;

pub const AU: f64 = 149_597_870_700.0;

/// The test scenes' Sun: a 5772 K blackbody giving 1361 W/m² at 1 au.
const SUN: &str = r#"[sun]
spectrum = "blackbody"
temperature = 5772.0
irradiance_1au = 1361.0
"#;

/// Scalar-first quaternion of a camera at `pos` looking at `target`.
pub fn look_at(pos: DVec3, target: DVec3) -> [f64; 4] {
    let z = (target - pos).normalize();
    let hint = if z.cross(DVec3::Z).length() > 1e-6 {
        DVec3::Z
    } else {
        DVec3::X
    };
    let x = z.cross(hint).normalize();
    let y = z.cross(x);
    let q = DQuat::from_mat3(&DMat3::from_cols(x, y, z)).normalize();
    [q.w, q.x, q.y, q.z]
}

/// Parameters of a test scene: body of radius `radius` at the origin, Sun
/// along +x at `sun_au`, camera at `range` in the direction at phase `alpha`.
pub struct Setup {
    pub reflectance: String,
    pub radius: f64,
    pub range: f64,
    pub alpha_deg: f64,
    pub resolution: [usize; 2],
    /// Focal length in pixels.
    pub f_px: f64,
    pub geometry: &'static str,
    pub sun_au: f64,
    /// Extra rotation of the boresight away from the body [deg] about the
    /// camera's y axis.
    pub off_axis_deg: f64,
    pub extra_body: String,
    pub extra_render: String,
}

impl Setup {
    /// Body filling `diameter_px` pixels at `range` = `range_radii` radii.
    pub fn new(reflectance: &str, alpha_deg: f64, range_radii: f64, diameter_px: f64) -> Self {
        let radius = 1000.0;
        let range = range_radii * radius;
        let ang = (radius / range).asin();
        let res = (diameter_px * 1.3).ceil() as usize + 8;
        Setup {
            reflectance: reflectance.into(),
            radius,
            range,
            alpha_deg,
            resolution: [res, res],
            f_px: diameter_px / 2.0 / ang.tan(),
            geometry: "exact",
            sun_au: 1.0,
            off_axis_deg: 0.0,
            extra_body: String::new(),
            extra_render: String::new(),
        }
    }

    pub fn camera_position(&self) -> DVec3 {
        let a = self.alpha_deg.to_radians();
        DVec3::new(a.cos(), a.sin(), 0.0) * self.range
    }

    pub fn sun_position(&self) -> DVec3 {
        DVec3::X * self.sun_au * AU
    }

    pub fn toml(&self) -> String {
        let cam = self.camera_position();
        let mut q = look_at(cam, DVec3::ZERO);
        if self.off_axis_deg != 0.0 {
            let base = DQuat::from_xyzw(q[1], q[2], q[3], q[0]);
            let rot = base * DQuat::from_rotation_y(self.off_axis_deg.to_radians());
            q = [rot.w, rot.x, rot.y, rot.z];
        }
        let sun = self.sun_position();
        let pitch = 10e-6;
        format!(
            r#"
[camera]
resolution = [{w}, {h}]
pixel_pitch = {pitch:e}
focal_length = {f:e}
f_number = 2.5
exposure = 1e-3
full_well = 1e30
bits = 12
band = [450e-9, 820e-9]

{SUN}
[body]
radius = {r:e}
reflectance = {refl}
{extra_body}

[state]
camera_position = [{cx:e}, {cy:e}, {cz:e}]
camera_attitude = [{q0:e}, {q1:e}, {q2:e}, {q3:e}]
sun_position = [{sx:e}, {sy:e}, {sz:e}]

[render]
geometry = "{geom}"
{extra_render}
"#,
            w = self.resolution[0],
            h = self.resolution[1],
            f = self.f_px * pitch,
            r = self.radius,
            refl = self.reflectance,
            extra_body = self.extra_body,
            cx = cam.x,
            cy = cam.y,
            cz = cam.z,
            q0 = q[0],
            q1 = q[1],
            q2 = q[2],
            q3 = q[3],
            sx = sun.x,
            sy = sun.y,
            sz = sun.z,
            geom = self.geometry,
            extra_render = self.extra_render,
        )
    }

    pub fn scene(&self) -> Scene {
        Scene::from_toml(&self.toml(), Path::new("test-scene.toml")).expect("valid test scene")
    }
}

/// Render through the whole chain.
pub fn render(scene: &Scene) -> SceneImages {
    let mut renderer = Renderer::new(scene.camera.render_pinhole().clone());
    let pixels = PixelGeometry::new(&renderer);
    render_scene(scene, &mut renderer, &pixels).expect("render")
}

/// Solid angle of a pixel, from an independent 2-D Gauss–Legendre
/// quadrature of dx dy / (1 + x² + y²)^{3/2} (not the renderer's closed form).
pub fn pixel_solid_angle(x0: f64, x1: f64, y0: f64, y1: f64) -> f64 {
    const N: [f64; 3] = [-0.774_596_669_241_483_4, 0.0, 0.774_596_669_241_483_4];
    const W: [f64; 3] = [5.0 / 9.0, 8.0 / 9.0, 5.0 / 9.0];
    let (hx, hy) = (0.5 * (x1 - x0), 0.5 * (y1 - y0));
    let (mx, my) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let mut s = 0.0;
    for (a, wa) in N.iter().zip(W) {
        for (b, wb) in N.iter().zip(W) {
            let x = mx + hx * a;
            let y = my + hy * b;
            s += wa * wb / (1.0 + x * x + y * y).powf(1.5);
        }
    }
    s * hx * hy
}

/// E = Σ L Ω cosθ over the image, θ from the line of sight to the body
/// centre, with the test's own solid angles.
pub fn irradiance_from_image(scene: &Scene, radiance: &[f32]) -> f64 {
    let pin = &scene.camera.pinhole;
    let st = &scene.state;
    let los = (st.camera_attitude.inverse() * (st.body_position - st.camera_position)).normalize();
    let mut e = 0.0;
    for j in 0..pin.height {
        for i in 0..pin.width {
            let l = radiance[j * pin.width + i] as f64;
            if l == 0.0 {
                continue;
            }
            let x0 = (i as f64 - pin.cx) / pin.fx;
            let x1 = (i as f64 + 1.0 - pin.cx) / pin.fx;
            let y0 = (j as f64 - pin.cy) / pin.fy;
            let y1 = (j as f64 + 1.0 - pin.cy) / pin.fy;
            let dir = DVec3::new(0.5 * (x0 + x1), 0.5 * (y0 + y1), 1.0).normalize();
            e += l * pixel_solid_angle(x0, x1, y0, y1) * dir.dot(los);
        }
    }
    e
}

/// Solar irradiance in band at the body [W m⁻²].
pub fn sun_at_body(scene: &Scene, images: &SceneImages) -> f64 {
    let d = (scene.state.sun_position - scene.state.body_position).length();
    images.summary.band_irradiance_1au_w_m2 * (AU / d).powi(2)
}

/// The paper's AMIE image (phase 105°, 30 ms).
pub const IMG1: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/data/amie/AMI_EE3_040819_00208_00030.IMG"
);
/// The eclipse AMIE image (phase 9°, 10 ms).
pub const IMG2: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/data/amie/AMI_EE3_041028_00101_00010.IMG"
);

/// The facility tests' display: drive level l (0–255) gives
/// `TEST_LUT_MAX` (l/255)^2.2 + `TEST_LUT_BLACK` W m⁻² sr⁻¹, written here
/// independently of the library's LUT code.
/// The flight scene of the facility tests: a Lambert Moon (ρ 0.15) at the
/// origin, body frame = world frame, seen by a 64 px, 6° camera at
/// `camera` looking along +z, lit from `sun` (positions in m).
#[allow(dead_code)]
pub fn facility_scene_toml(camera: DVec3, sun: DVec3) -> String {
    format!(
        r#"
[camera]
resolution = [64, 64]
pixel_pitch = 10e-6
fov_deg = 6.0
f_number = 2.5
exposure = 2.0e-5
full_well = 1.0e5
bits = 12
band = [450e-9, 820e-9]

{SUN}
[body]
radius = 1737.4e3
reflectance = {{ model = "lambert", albedo = 0.15 }}

[state]
body_position = [0.0, 0.0, 0.0]
body_attitude = [1.0, 0.0, 0.0, 0.0]
camera_position = [{:e}, {:e}, {:e}]
camera_attitude = [1.0, 0.0, 0.0, 0.0]
sun_position = [{:e}, {:e}, {:e}]
"#,
        camera.x, camera.y, camera.z, sun.x, sun.y, sun.z
    )
}

pub const TEST_LUT_MAX: f64 = 0.5;
/// Black level of the test display [W m⁻² sr⁻¹].
pub const TEST_LUT_BLACK: f64 = 5.0e-4;
/// Gamma of the test display.
pub const TEST_LUT_GAMMA: f64 = 2.2;

/// Radiance of drive level `level` of the test display.
pub fn test_lut_radiance(level: u32) -> f64 {
    TEST_LUT_MAX * (level as f64 / 255.0).powf(TEST_LUT_GAMMA) + TEST_LUT_BLACK
}

/// The test display's LUT file (`calibration.lut`).
pub fn test_lut_csv() -> String {
    let mut s = String::from("# gamma 2.2 test LUT\ndrive_level,radiance_w_m2_sr\n");
    for l in 0..=255u32 {
        s.push_str(&format!("{l},{}\n", test_lut_radiance(l)));
    }
    s
}

/// SHA-256 of `bytes` in lower-case hex, as the frame log records file
/// hashes (computed here with the sha2 crate).
pub fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::{Digest, Sha256};
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// E at the camera from a sphere at the origin (body frame = world frame),
/// written independently of the renderer: ∫ r(n) F(p) μ/|c−p|² cos θ dS
/// over the visible cap, F(p) the band irradiance at p, r the radiance
/// factor at the surface normal n. `n_gauss`-point Gauss–Legendre in the
/// angle from the sub-camera point (split where rings cross the
/// terminator), `n_az` midpoints in azimuth.
pub fn visible_cap_irradiance(
    radius: f64,
    camera: DVec3,
    sun: DVec3,
    f_1au: f64,
    (n_gauss, n_az): (usize, usize),
    radiance_factor: impl Fn(DVec3, &ScatteringGeometry) -> f64,
) -> f64 {
    let d = camera.length();
    let axis = camera / d;
    let e1 = axis.any_orthonormal_vector();
    let e2 = axis.cross(e1);
    let psi_max = (radius / d).acos();
    let n = n_gauss;
    let mut nodes = Vec::new();
    for k in 1..=n {
        let mut x = (std::f64::consts::PI * (k as f64 - 0.25) / (n as f64 + 0.5)).cos();
        for _ in 0..100 {
            let (mut p0, mut p1) = (1.0, x);
            for m in 2..=n {
                let p2 = ((2 * m - 1) as f64 * x * p1 - (m - 1) as f64 * p0) / m as f64;
                p0 = p1;
                p1 = p2;
            }
            let dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
            let dx = p1 / dp;
            x -= dx;
            if dx.abs() < 1e-16 {
                nodes.push((x, 2.0 / ((1.0 - x * x) * dp * dp)));
                break;
            }
        }
    }
    let alpha = axis.dot(sun.normalize()).clamp(-1.0, 1.0).acos();
    let kink = (alpha - std::f64::consts::PI / 2.0).abs();
    let pieces = if kink > 0.0 && kink < psi_max {
        vec![(0.0, kink), (kink, psi_max)]
    } else {
        vec![(0.0, psi_max)]
    };
    let mut total = 0.0;
    for (a, b) in pieces {
        for &(x, w) in &nodes {
            let psi = a + 0.5 * (b - a) * (x + 1.0);
            let (sp, cp) = psi.sin_cos();
            let mut ring = 0.0;
            for k in 0..n_az {
                let beta = (k as f64 + 0.5) * 2.0 * std::f64::consts::PI / n_az as f64;
                let nrm = axis * cp + (e1 * beta.cos() + e2 * beta.sin()) * sp;
                let p = nrm * radius;
                let (to_sun, to_cam) = (sun - p, camera - p);
                let (ds, dc) = (to_sun.length(), to_cam.length());
                let (l, v) = (to_sun / ds, to_cam / dc);
                let g = ScatteringGeometry {
                    mu0: nrm.dot(l),
                    mu: nrm.dot(v),
                    cos_g: l.dot(v),
                };
                if g.mu0 <= 0.0 || g.mu <= 0.0 {
                    continue;
                }
                let f = f_1au * (AU / ds).powi(2);
                let cos_theta = (-to_cam / dc).dot(-axis);
                ring += radiance_factor(nrm, &g) * f * g.mu / (dc * dc) * cos_theta;
            }
            total += w * 0.5 * (b - a) * ring * 2.0 * std::f64::consts::PI / n_az as f64 * sp;
        }
    }
    total * radius * radius
}

pub mod ptc;
pub mod ring_dem;
pub mod simfacility;

/// The machine, shared between the tests of one binary. Tests that judge
/// wall-clock time (pacing, latency, "does not block") take it exclusively,
/// so the other tests of the binary, which cargo runs in parallel, cannot
/// slow them on a two-core runner; every other test takes it shared.
pub mod machine {
    use std::sync::{RwLock, RwLockReadGuard, RwLockWriteGuard};

    static MACHINE: RwLock<()> = RwLock::new(());

    /// For a test whose assertions do not depend on elapsed time.
    pub fn shared() -> RwLockReadGuard<'static, ()> {
        MACHINE.read().unwrap_or_else(|e| e.into_inner())
    }

    /// For a test that asserts on elapsed time: no other test of the binary
    /// runs while it does.
    pub fn exclusive() -> RwLockWriteGuard<'static, ()> {
        MACHINE.write().unwrap_or_else(|e| e.into_inner())
    }
}

/// Every file under `dir`, relative path → bytes (output trees compared
/// byte for byte).
pub fn file_tree(dir: &Path) -> std::collections::BTreeMap<String, Vec<u8>> {
    let mut out = std::collections::BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p.strip_prefix(dir).unwrap().to_string_lossy().into_owned();
                out.insert(rel, std::fs::read(&p).unwrap());
            }
        }
    }
    out
}

/// The westmost x in (−a, a) where `f` turns positive (a shadow's edge
/// along a crater's axis), scanned in steps of `step` from −0.999 a, then
/// bisected 50 times.
pub fn first_crossing(f: impl Fn(f64) -> f64, a: f64, step: f64) -> f64 {
    let mut lo = -a * 0.999;
    assert!(f(lo) < 0.0, "shadowed at the west rim");
    while f(lo + step) < 0.0 {
        lo += step;
        assert!(lo < a, "no shadow");
    }
    let mut hi = lo + step;
    for _ in 0..50 {
        let mid = 0.5 * (lo + hi);
        if f(mid) < 0.0 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Every case (scene text, a key the error must name, a file it must
/// name) is refused by `load` with a one-line error.
pub fn assert_one_line_errors<'a, T>(
    cases: impl IntoIterator<Item = (String, &'a str, Option<&'a str>)>,
    load: impl Fn(&str) -> Result<T, String>,
) {
    for (text, needle, file) in cases {
        let e = match load(&text) {
            Ok(_) => panic!("accepted: {text}"),
            Err(e) => e,
        };
        assert!(!e.contains('\n'), "not one line: {e}");
        assert!(e.contains(needle), "{e} does not name {needle}");
        if let Some(f) = file {
            assert!(e.contains(f), "{e} does not name the file {f}");
        }
    }
}

/// Where the great circle from unit vector `p` toward unit tangent `dir`
/// leaves a circular crater of radius `a` [m] centred on unit vector
/// `centre`, on a sphere of radius `r` [m] (bisection to 80 halvings):
/// the rim point, scaled to `r`.
pub fn crater_exit(p: DVec3, dir: DVec3, centre: DVec3, a: f64, r: f64) -> DVec3 {
    let at = |g: f64| p * g.cos() + dir * g.sin();
    let (mut lo, mut hi) = (0.0, 2.0 * a / r);
    for _ in 0..80 {
        let mid = 0.5 * (lo + hi);
        if r * at(mid).dot(centre).clamp(-1.0, 1.0).acos() < a {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    at(0.5 * (lo + hi)) * r
}

/// |image / truth − 1| over the pixels whose truth is above 1 % of its
/// peak, sorted ascending.
pub fn sorted_relative_errors(image: &[f32], truth: &[f32]) -> Vec<f64> {
    let peak = truth.iter().copied().fold(0.0f32, f32::max) as f64;
    let mut e: Vec<f64> = (0..truth.len())
        .filter(|&k| truth[k] as f64 > 0.01 * peak)
        .map(|k| (image[k] as f64 / truth[k] as f64 - 1.0).abs())
        .collect();
    e.sort_by(f64::total_cmp);
    e
}

/// The nearest-rank `q` quantile of ascending `sorted` values.
pub fn nearest_rank(sorted: &[f64], q: f64) -> f64 {
    let rank = (q * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1]
}
