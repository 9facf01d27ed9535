//! `[stars]` in the render. Every reference is computed here, apart from
//! the code under test: a star's electrons from Bessell's V zero point, a
//! Planck curve at Ballesteros' temperature and a brute-force band integral;
//! the catalogue's pixel positions from its own parse of the bundled CSV,
//! linear proper motion and a pinhole projection; the attitude from an
//! independent plate solver (the `tetra3` crate) given only the centroids
//! found in the image; the occultation from the body's disk.

mod common;
use std::path::Path;

use glam::{DMat3, DQuat, DVec3};
use optistim::render::detector::SceneImages;
use optistim::scene::Scene;
use proptest::prelude::*;

const MOON_RADIUS: f64 = 1_737_400.0;
const PITCH: f64 = 10e-6;
const F_NUMBER: f64 = 2.5;

// Physical constants (CODATA 2018, exact SI values).
const H: f64 = 6.626_070_15e-34;
const C: f64 = 299_792_458.0;
const K_B: f64 = 1.380_649e-23;

/// Camera-to-world rotation of a camera looking along `dir`, rolled by
/// `roll_deg` about its boresight.
fn attitude(dir: DVec3, roll_deg: f64) -> DQuat {
    let z = dir.normalize();
    let x = z.cross(DVec3::Z).normalize();
    let y = z.cross(x);
    let q = DQuat::from_mat3(&DMat3::from_cols(x, y, z)).normalize();
    q * DQuat::from_rotation_z(roll_deg.to_radians())
}

fn radec(ra_deg: f64, dec_deg: f64) -> DVec3 {
    let (ra, dec) = (ra_deg.to_radians(), dec_deg.to_radians());
    DVec3::new(dec.cos() * ra.cos(), dec.cos() * ra.sin(), dec.sin())
}

/// A square camera at the origin (unless `camera` is given), a Moon-sized
/// body at `body`, 12-bit detector, QE from a table, transmission 0.9.
struct Shot {
    size: usize,
    f_px: f64,
    q: DQuat,
    body: DVec3,
    camera: DVec3,
    sun: DVec3,
    stars: String,
    psf: &'static str,
    exposure: f64,
}

impl Shot {
    fn toml(&self, dir: &Path) -> String {
        let qe = dir.join("qe.csv");
        std::fs::write(
            &qe,
            "wavelength_nm,qe\n400,0.30\n550,0.70\n700,0.50\n900,0.10\n",
        )
        .unwrap();
        let v = |p: DVec3| format!("[{:e}, {:e}, {:e}]", p.x, p.y, p.z);
        let q = self.q;
        format!(
            r#"
[camera]
resolution = [{n}, {n}]
pixel_pitch = {PITCH:e}
focal_length = {f:e}
f_number = {F_NUMBER}
exposure = {exposure:e}
full_well = 1e30
bits = 16
band = [450e-9, 820e-9]
quantum_efficiency = "{qe}"
transmission = 0.9
psf = {psf}

[sun]
spectrum = "blackbody"
temperature = 5772.0
irradiance_1au = 1361.0

[body]
radius = {MOON_RADIUS:e}
reflectance = {{ model = "lambert", albedo = 0.12 }}

[state]
body_position = {body}
camera_position = {camera}
camera_attitude = [{w:e}, {x:e}, {y:e}, {z:e}]
sun_position = {sun}

{stars}
"#,
            n = self.size,
            f = self.f_px * PITCH,
            exposure = self.exposure,
            qe = qe.display(),
            psf = self.psf,
            body = v(self.body),
            camera = v(self.camera),
            sun = v(self.sun),
            w = q.w,
            x = q.x,
            y = q.y,
            z = q.z,
            stars = self.stars,
        )
    }

    fn scene(&self, dir: &Path) -> Scene {
        Scene::from_toml(&self.toml(dir), &dir.join("scene.toml")).expect("valid scene")
    }
}

/// A shot along `dir` with the body far behind the camera.
fn sky_shot(dir: DVec3, roll_deg: f64, size: usize, f_px: f64, stars: &str) -> Shot {
    Shot {
        size,
        f_px,
        q: attitude(dir, roll_deg),
        body: -dir * 4e8,
        camera: DVec3::ZERO,
        sun: DVec3::new(0.0, 1.5e11, 0.0),
        stars: stars.into(),
        psf: "{ model = \"gaussian\", sigma_px = 1.0 }",
        exposure: 1.0,
    }
}

fn write_catalogue(dir: &Path, rows: &[(f64, f64, f64, f64)]) -> String {
    let mut text = String::from("ra_deg,dec_deg,pm_ra_mas_per_yr,pm_dec_mas_per_yr,v_mag,b_v\n");
    for (ra, dec, v, bv) in rows {
        text += &format!("{ra},{dec},0,0,{v},{bv}\n");
    }
    let path = dir.join("stars.csv");
    std::fs::write(&path, text).unwrap();
    format!(
        "[stars]\ncatalogue = \"{}\"\nmag_limit = 12.0\n",
        path.display()
    )
}

/// QE of the test's table (linear between its rows, as documented).
fn qe(nm: f64) -> f64 {
    let t = [(400.0, 0.30), (550.0, 0.70), (700.0, 0.50), (900.0, 0.10)];
    let k = t.windows(2).find(|w| nm >= w[0].0 && nm <= w[1].0).unwrap();
    let f = (nm - k[0].0) / (k[1].0 - k[0].0);
    k[0].1 + f * (k[1].1 - k[0].1)
}

/// The electrons per second a star of `v`, `bv` on the boresight gives,
/// by a midpoint rule at 0.01 nm: A ∫ F_λ QE T λ/(hc) dλ, F_λ = Bessell's
/// V = 0 flux (363.1e-11 erg cm⁻² s⁻¹ Å⁻¹ at 545 nm) × 10^(−0.4 V) ×
/// B_λ(T)/B_545(T), T from Ballesteros' formula.
fn expected_rate(v: f64, bv: f64, focal_length: f64) -> f64 {
    let f0 = 363.1e-11 * 1e-7 / 1e-4 / 1e-10; // erg/cm²/s/Å → W/m²/m
    let t = 4600.0 * (1.0 / (0.92 * bv + 1.7) + 1.0 / (0.92 * bv + 0.62));
    let planck = |l: f64| 2.0 * H * C * C / l.powi(5) / ((H * C / (l * K_B * t)).exp() - 1.0);
    let scale = f0 * 10f64.powf(-0.4 * v) / planck(545e-9);
    let step = 0.01e-9;
    let n = ((820e-9f64 - 450e-9) / step).round() as usize;
    let photons: f64 = (0..n)
        .map(|k| {
            let l = 450e-9 + (k as f64 + 0.5) * step;
            scale * planck(l) * l / (H * C) * qe(l * 1e9) * 0.9 * step
        })
        .sum();
    let diameter = focal_length / F_NUMBER;
    photons * std::f64::consts::PI * diameter * diameter / 4.0
}

fn render(scene: &Scene) -> SceneImages {
    common::render(scene)
}

#[test]
fn a_star_gives_its_electrons_within_one_percent() {
    let dir = tempfile::tempdir().unwrap();
    for (v, bv) in [(3.0, 0.65), (6.5, -0.2), (1.0, 1.6)] {
        let stars = write_catalogue(dir.path(), &[(30.0, 20.0, v, bv)]);
        let shot = sky_shot(radec(30.0, 20.0), 0.0, 64, 4000.0, &stars);
        let images = render(&shot.scene(dir.path()));
        let got: f64 = images.electrons.iter().map(|&e| e as f64).sum();
        let want = expected_rate(v, bv, 4000.0 * PITCH) * shot.exposure;
        println!(
            "V {v}, B-V {bv}: {got:.6e} e- vs {want:.6e} e- ({:+.4} %)",
            100.0 * (got / want - 1.0)
        );
        assert!((got / want - 1.0).abs() < 0.01, "{got} vs {want}");
        let summary = images.summary.stars.as_ref().unwrap();
        assert_eq!((summary.in_field, summary.occulted), (1, 0));
    }
}

/// Intensity-weighted centroid [px, centres at +0.5] of a `width`-wide image.
fn centroid_of(image: &[f32], width: usize) -> (f64, f64) {
    let (mut sum, mut su, mut sv) = (0.0, 0.0, 0.0);
    for (k, &x) in image.iter().enumerate() {
        let x = x as f64;
        sum += x;
        su += x * ((k % width) as f64 + 0.5);
        sv += x * ((k / width) as f64 + 0.5);
    }
    (su / sum, sv / sum)
}

#[test]
fn the_observers_velocity_moves_a_star_by_the_aberration_angle() {
    // 30 km/s along the camera's x axis, the star on the boresight (90°
    // from the velocity): classically tan θ' = sin θ / (γ (cos θ + β)),
    // so the star moves toward +x by tan δ = γ β, f γ β pixels.
    let dir = tempfile::tempdir().unwrap();
    let (f_px, speed) = (4000.0, 3e4);
    let shot = sky_shot(radec(30.0, 20.0), 0.0, 64, f_px, "");
    let x_axis = shot.q * DVec3::X;
    let catalogue = write_catalogue(dir.path(), &[(30.0, 20.0, 4.0, 0.6)]);
    let v = x_axis * speed;
    let centroid = |stars: String| {
        let mut s = sky_shot(radec(30.0, 20.0), 0.0, 64, f_px, &stars);
        s.q = shot.q;
        centroid_of(&render(&s.scene(dir.path())).electrons, 64)
    };
    let still = centroid(catalogue.clone());
    let moving = centroid(format!(
        "{catalogue}observer_velocity = [{:e}, {:e}, {:e}]\n",
        v.x, v.y, v.z
    ));
    let beta = speed / C;
    let gamma = 1.0 / (1.0 - beta * beta).sqrt();
    let want = f_px * gamma * beta;
    println!(
        "aberration: {:.5} px (closed form {want:.5} px)",
        moving.0 - still.0
    );
    assert!(
        (still.0 - 32.0).abs() < 1e-3 && (still.1 - 32.0).abs() < 1e-3,
        "{still:?}"
    );
    assert!((moving.0 - still.0 - want).abs() < 2e-3, "{moving:?}");
    assert!((moving.1 - still.1).abs() < 1e-3);
}

/// A star with a parallax seen by a narrow-angle camera 1 AU from the
/// Sun: it lands where the star's position at 1 AU / p, seen from the
/// camera, projects (computed here), 2 px from where it lands without it.
#[test]
fn a_nearby_star_moves_by_its_parallax() {
    const AU: f64 = 1.495_978_707e11;
    let dir = tempfile::tempdir().unwrap();
    let (f_px, parallax_mas) = (1e6, 500.0);
    let shot = sky_shot(radec(30.0, 20.0), 0.0, 64, f_px, "");
    let write = |parallax: Option<f64>| {
        let (head, cell) = match parallax {
            Some(p) => (",parallax_mas", format!(",{p}")),
            None => ("", String::new()),
        };
        let path = dir.path().join("near.csv");
        std::fs::write(
            &path,
            format!("ra_deg,dec_deg,pm_ra_mas_per_yr,pm_dec_mas_per_yr,v_mag,b_v{head}\n30,20,0,0,4,0.6{cell}\n"),
        )
        .unwrap();
        format!("[stars]\ncatalogue = \"{}\"\n", path.display())
    };
    let centroid = |stars: String| {
        let mut s = sky_shot(radec(30.0, 20.0), 0.0, 64, f_px, &stars);
        s.q = shot.q;
        centroid_of(&render(&s.scene(dir.path())).electrons, 64)
    };
    let far = centroid(write(None));
    let near = centroid(write(Some(parallax_mas)));
    // The star at distance AU / p [rad]; the camera at the origin, the Sun
    // at `shot.sun`: the star's position relative to the camera.
    let distance = AU / (parallax_mas / 3.6e6).to_radians();
    let seen = (radec(30.0, 20.0) * distance + shot.sun).normalize();
    let c = shot.q.inverse() * seen;
    let want = (f_px * c.x / c.z + 32.0, f_px * c.y / c.z + 32.0);
    let shift = (near.0 - far.0).hypot(near.1 - far.1);
    println!(
        "parallax: {shift:.4} px; at ({:.4}, {:.4}), expected ({:.4}, {:.4})",
        near.0, near.1, want.0, want.1
    );
    assert!(shift > 1.5, "{shift} px: the parallax was not applied");
    assert!(
        (near.0 - want.0).abs() < 2e-3 && (near.1 - want.1).abs() < 2e-3,
        "{near:?} vs {want:?}"
    );
}

/// The bundled catalogue as read here (not by the library): HIP, RA, Dec
/// [deg] moved by linear proper motion to `year`, V.
fn bundled_at(year: f64) -> Vec<(i64, f64, f64, f64)> {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("data/stars/hipparcos_v7.5.csv"),
    )
    .unwrap();
    let t = year - 1991.25;
    text.lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with("id"))
        .map(|l| {
            let c: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            let dec = c[2] + c[4] * t / 3.6e6;
            let ra = c[1] + c[3] * t / 3.6e6 / c[2].to_radians().cos();
            (c[0] as i64, ra, dec, c[5])
        })
        .collect()
}

/// Orion's belt, a 15° field, rolled by 23°, at 2025.0.
const FIELD_SIZE: usize = 1024;
const FIELD_F_PX: f64 = 3889.0;
const FIELD_YEAR: f64 = 2025.0;

fn orion_shot() -> Shot {
    let stars = "[stars]\ncatalogue = \"bundled\"\nepoch = \"2024-12-31T18:00:00 TT\"\n";
    sky_shot(radec(84.0, -1.0), 23.0, FIELD_SIZE, FIELD_F_PX, stars)
}

/// Continuous pixel position of a catalogue direction.
fn project(q: DQuat, ra: f64, dec: f64) -> Option<(f64, f64)> {
    let c = q.inverse() * radec(ra, dec);
    let half = FIELD_SIZE as f64 / 2.0;
    (c.z > 0.0).then(|| (FIELD_F_PX * c.x / c.z + half, FIELD_F_PX * c.y / c.z + half))
}

#[test]
fn star_centroids_sit_on_the_catalogues_projection() {
    let dir = tempfile::tempdir().unwrap();
    let shot = orion_shot();
    let images = render(&shot.scene(dir.path()));
    let stars: Vec<(f64, f64)> = bundled_at(FIELD_YEAR)
        .iter()
        .filter_map(|&(_, ra, dec, _)| project(shot.q, ra, dec))
        .collect();
    let n = FIELD_SIZE as f64;
    let (mut checked, mut worst) = (0, 0.0f64);
    for &(u, v) in &stars {
        let isolated = stars
            .iter()
            .filter(|&&(a, b)| (a - u).hypot(b - v) < 12.0)
            .count()
            == 1;
        if !(isolated && u > 8.0 && v > 8.0 && u < n - 8.0 && v < n - 8.0) {
            continue;
        }
        // Centroid of the 11 × 11 pixels around the star's pixel.
        let (i0, j0) = (u.floor() as usize, v.floor() as usize);
        let (mut s, mut su, mut sv) = (0.0, 0.0, 0.0);
        for j in j0 - 5..=j0 + 5 {
            for i in i0 - 5..=i0 + 5 {
                let e = images.electrons[j * FIELD_SIZE + i] as f64;
                s += e;
                su += e * (i as f64 + 0.5);
                sv += e * (j as f64 + 0.5);
            }
        }
        let err = (su / s - u).hypot(sv / s - v);
        worst = worst.max(err);
        checked += 1;
    }
    println!("{checked} isolated stars, worst centroid offset {worst:.4} px");
    assert!(checked >= 50, "only {checked} stars checked");
    assert!(worst < 0.05, "{worst} px");
}

/// Stars found in an image: 8-connected pixels above `threshold`,
/// with their intensity-weighted centroids and sums.
fn detect(image: &[f32], size: usize, threshold: f32) -> Vec<(f64, f64, f64)> {
    let mut seen = vec![false; image.len()];
    let mut found = Vec::new();
    for start in 0..image.len() {
        if seen[start] || image[start] <= threshold {
            continue;
        }
        let (mut stack, mut s, mut su, mut sv) = (vec![start], 0.0, 0.0, 0.0);
        seen[start] = true;
        while let Some(k) = stack.pop() {
            let (i, j) = ((k % size) as i64, (k / size) as i64);
            let e = image[k] as f64;
            s += e;
            su += e * (i as f64 + 0.5);
            sv += e * (j as f64 + 0.5);
            for (di, dj) in [
                (-1, -1),
                (0, -1),
                (1, -1),
                (-1, 0),
                (1, 0),
                (-1, 1),
                (0, 1),
                (1, 1),
            ] {
                let (a, b) = (i + di, j + dj);
                if a < 0 || b < 0 || a >= size as i64 || b >= size as i64 {
                    continue;
                }
                let n = b as usize * size + a as usize;
                if !seen[n] && image[n] > threshold {
                    seen[n] = true;
                    stack.push(n);
                }
            }
        }
        found.push((su / s, sv / s, s));
    }
    found
}

#[test]
fn a_plate_solver_recovers_the_cameras_attitude() {
    use tetra3::{Centroid, GenerateDatabaseConfig, SolveConfig, SolverDatabase, Star};
    let dir = tempfile::tempdir().unwrap();
    let shot = orion_shot();
    let images = render(&shot.scene(dir.path()));
    let peak = images.electrons.iter().cloned().fold(0.0f32, f32::max);
    let mut found = detect(&images.electrons, FIELD_SIZE, peak * 1e-4);
    found.sort_by(|a, b| b.2.total_cmp(&a.2));
    let half = FIELD_SIZE as f64 / 2.0;
    let centroids: Vec<Centroid> = found
        .iter()
        .map(|&(u, v, s)| Centroid {
            x: (u - half) as f32,
            y: (v - half) as f32,
            mass: Some(s as f32),
            cov: None,
        })
        .collect();
    let catalogue: Vec<Star> = bundled_at(FIELD_YEAR)
        .into_iter()
        .map(|(id, ra, dec, v)| Star {
            id,
            ra_rad: ra.to_radians() as f32,
            dec_rad: dec.to_radians() as f32,
            mag: v as f32,
        })
        .collect();
    let fov_deg = 2.0 * (half / FIELD_F_PX).atan().to_degrees();
    let db = SolverDatabase::generate_from_star_list(
        catalogue,
        &GenerateDatabaseConfig {
            max_fov_deg: fov_deg as f32 * 1.1,
            min_fov_deg: Some(fov_deg as f32 * 0.9),
            ..Default::default()
        },
        FIELD_YEAR,
    )
    .unwrap();
    let config = SolveConfig::new(
        fov_deg.to_radians() as f32,
        FIELD_SIZE as u32,
        FIELD_SIZE as u32,
    );
    let solution = db
        .solve_from_centroids(&centroids, &config)
        .expect("solved");
    let q = solution.qicrs2cam;
    let solved = DQuat::from_xyzw(q.x as f64, q.y as f64, q.z as f64, q.w as f64).inverse();
    // Boresight and roll errors of the solved camera-to-world rotation.
    let boresight = (shot.q * DVec3::Z).angle_between(solved * DVec3::Z);
    let roll = (shot.q * DVec3::X).angle_between(solved * DVec3::X);
    let arcsec = 180.0 * 3600.0 / std::f64::consts::PI;
    println!(
        "{} centroids, {} matched; boresight error {:.2}\", x-axis error {:.2}\"",
        centroids.len(),
        solution.num_matches,
        boresight * arcsec,
        roll * arcsec
    );
    // 0.05 px at the boresight (the position test's bound), and
    // 0.05 px over half the frame for the roll.
    let px = 1.0 / FIELD_F_PX;
    assert!(solution.num_matches >= 20);
    assert!(boresight < 0.05 * px, "{}\"", boresight * arcsec);
    assert!(roll < 0.05 * px + 0.05 / half, "{}\"", roll * arcsec);
}

#[test]
fn the_body_hides_the_stars_behind_its_disk() {
    let dir = tempfile::tempdir().unwrap();
    // The Moon 20 radii ahead (angular radius 2.87°), lit from behind
    // the camera; one star 0.5 angular radii from its centre, one 1.6.
    let to_body = radec(120.0, 10.0);
    let range = 20.0 * MOON_RADIUS;
    let radius_deg = (1.0f64 / 20.0).asin().to_degrees();
    let (behind, beside) = (
        (120.0, 10.0 + 0.5 * radius_deg),
        (120.0, 10.0 - 1.6 * radius_deg),
    );
    let stars = write_catalogue(
        dir.path(),
        &[
            (behind.0, behind.1, 2.0, 0.5),
            (beside.0, beside.1, 2.0, 0.5),
        ],
    );
    let mut shot = sky_shot(to_body, 0.0, 256, 1000.0, &stars);
    shot.body = to_body * range;
    shot.sun = -to_body * 1.5e11;
    let with = render(&shot.scene(dir.path()));
    shot.stars = String::new();
    let without = render(&shot.scene(dir.path()));
    let summary = with.summary.stars.as_ref().unwrap();
    assert_eq!((summary.in_field, summary.occulted), (2, 1));
    let diff: Vec<f64> = with
        .electrons
        .iter()
        .zip(&without.electrons)
        .map(|(&a, &b)| a as f64 - b as f64)
        .collect();
    let added: f64 = diff.iter().sum();
    let one_star = expected_rate(2.0, 0.5, 1000.0 * PITCH);
    // The visible star is 4.6° off the boresight: the pupil's cos θ.
    let pixel = |(ra, dec): (f64, f64)| {
        let c = shot.q.inverse() * radec(ra, dec);
        let (u, v) = (1000.0 * c.x / c.z + 128.0, 1000.0 * c.y / c.z + 128.0);
        (u as usize, v as usize, c.normalize().z)
    };
    let (_, _, cos_beside) = pixel(beside);
    println!(
        "added {added:.5e} e-, one star {:.5e} e-",
        one_star * cos_beside
    );
    assert!((added / (one_star * cos_beside) - 1.0).abs() < 0.01);
    let (i, j, _) = pixel(behind);
    let body = without.electrons[j * 256 + i] as f64;
    assert!(body > 0.0, "the hidden star's pixel is on the lit disk");
    assert!(
        diff[j * 256 + i].abs() <= 1e-6 * body,
        "{}",
        diff[j * 256 + i]
    );
}

// ------------------------------------------------------------ bad input

fn scene_error(stars: &str) -> String {
    let dir = tempfile::tempdir().unwrap();
    let shot = sky_shot(DVec3::X, 0.0, 16, 100.0, stars);
    let err = Scene::from_toml(&shot.toml(dir.path()), &dir.path().join("scene.toml"))
        .expect_err("must fail");
    err.to_string()
}

fn catalogue_error(text: &str) -> String {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cat.csv");
    std::fs::write(&path, text).unwrap();
    let shot = sky_shot(
        DVec3::X,
        0.0,
        16,
        100.0,
        &format!("[stars]\ncatalogue = \"{}\"\n", path.display()),
    );
    let err = Scene::from_toml(&shot.toml(dir.path()), &dir.path().join("scene.toml"))
        .expect_err("must fail")
        .to_string();
    assert!(
        err.contains("cat.csv") && err.contains("stars.catalogue"),
        "{err}"
    );
    assert!(!err.contains('\n'), "one line: {err}");
    err
}

const HEADER: &str = "ra_deg,dec_deg,pm_ra_mas_per_yr,pm_dec_mas_per_yr,v_mag,b_v\n";

#[test]
fn bad_catalogues_are_one_line_errors_naming_file_line_and_column() {
    let cases = [
        (
            format!("{HEADER}10,20,0,0,5,0.5\n11,21,0,0,5,0."),
            "truncated",
        ),
        (
            format!("{HEADER}10,20,0,0,5,0.5\n11,21,0\n"),
            "line 3: 3 cells",
        ),
        (format!("{HEADER}10,95,0,0,5,0.5\n"), "dec_deg 95"),
        (format!("{HEADER}10,20,0,0,5,9\n"), "b_v 9"),
        (format!("{HEADER}370,20,0,0,5,0.5\n"), "ra_deg 370"),
        (format!("{HEADER}10,20,1e9,0,5,0.5\n"), "pm_ra_mas_per_yr"),
        (format!("{HEADER}10,20,0,0,NaN,0.5\n"), "v_mag `NaN`"),
        (format!("{HEADER}10,20,0,0,x,0.5\n"), "v_mag `x`"),
        ("ra,dec\n1,2\n".to_string(), "header"),
        (HEADER.to_string(), "no stars"),
        (String::new(), "no header"),
        (format!("id,{HEADER}-3,10,20,0,0,5,0.5\n"), "id `-3`"),
    ];
    for (text, want) in cases {
        let err = catalogue_error(&text);
        assert!(err.contains(want), "`{want}` not in: {err}");
    }
    for (stars, want) in [
        (
            "[stars]\ncatalogue = \"bundled\"\nmag_limit = 99.0\n",
            "stars.mag_limit",
        ),
        (
            "[stars]\ncatalogue = \"bundled\"\ncatalogue_epoch = 2000.0\n",
            "stars.catalogue_epoch",
        ),
        (
            "[stars]\ncatalogue = \"bundled\"\nepoch = \"yesterday\"\n",
            "stars.epoch",
        ),
        (
            "[stars]\ncatalogue = \"bundled\"\nbrightness = 2\n",
            "brightness",
        ),
        ("[stars]\ncatalogue = \"missing.csv\"\n", "missing.csv"),
        (
            "[stars]\ncatalogue = \"bundled\"\nobserver_velocity = [1e9, 0, 0]\n",
            "stars.observer_velocity",
        ),
    ] {
        let err = scene_error(stars);
        assert!(
            err.contains(want) && !err.contains('\n'),
            "`{want}` not in: {err}"
        );
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Any valid rows read back as written; any line cut short of its
    /// newline is refused rather than read as a different star.
    #[test]
    fn valid_rows_read_back_and_cut_files_fail(
        rows in prop::collection::vec(
            (0.0..360.0f64, -90.0..90.0f64, -2e4..2e4f64, -2e4..2e4f64, -2.0..30.0f64, -0.5..5.0f64),
            1..20,
        ),
        cut in 1usize..40,
    ) {
        let mut text = HEADER.to_string();
        for r in &rows {
            text += &format!("{},{},{},{},{},{}\n", r.0, r.1, r.2, r.3, r.4, r.5);
        }
        let path = Path::new("prop.csv");
        let stars = optistim::stars::catalogue::parse(path, text.as_bytes()).unwrap();
        prop_assert_eq!(stars.len(), rows.len());
        let mas = std::f64::consts::PI / 180.0 / 3.6e6;
        for (s, r) in stars.iter().zip(&rows) {
            prop_assert!((s.ra - r.0.to_radians()).abs() < 1e-15);
            prop_assert!((s.dec - r.1.to_radians()).abs() < 1e-15);
            prop_assert!((s.pm_ra - r.2 * mas).abs() < 1e-18);
            prop_assert!((s.pm_dec - r.3 * mas).abs() < 1e-18);
            prop_assert_eq!((s.v_mag, s.b_v), (r.4, r.5));
        }
        let cut_at = text.len() - 1 - cut.min(text.len() - HEADER.len() - 1);
        if text[..cut_at].ends_with('\n') {
            return Ok(()); // a whole shorter file
        }
        let err = optistim::stars::catalogue::parse(path, &text.as_bytes()[..cut_at]);
        prop_assert!(err.is_err());
        let message = err.unwrap_err().to_string();
        prop_assert!(message.starts_with("prop.csv: line ") && !message.contains('\n'));
    }

    /// Arbitrary bytes never panic; an error is one line.
    #[test]
    fn arbitrary_bytes_are_an_error_or_stars(bytes in prop::collection::vec(any::<u8>(), 0..400)) {
        let mut text = HEADER.as_bytes().to_vec();
        text.extend(bytes);
        match optistim::stars::catalogue::parse(Path::new("x.csv"), &text) {
            Ok(stars) => prop_assert!(stars.iter().all(|s| s.v_mag.is_finite() && s.ra.is_finite())),
            Err(e) => prop_assert!(!e.to_string().contains('\n')),
        }
    }
}

/// `labels.json`'s star list: every bundled star to V 7.5 whose direction
/// falls in the image, with its HIP number and position, against the
/// catalogue read and projected here; none other.
#[test]
fn the_labels_list_the_stars_in_the_image() {
    let dir = tempfile::tempdir().unwrap();
    let shot = orion_shot();
    let scene = shot.scene(dir.path());
    let mut labels =
        optistim::labels::compute(&scene.camera.pinhole, &scene.state, scene.body.radius, None);
    optistim::labels::add_stars(&mut labels, &scene);
    let n = FIELD_SIZE as f64;
    let want: Vec<(i64, f64, f64)> = bundled_at(FIELD_YEAR)
        .iter()
        .filter(|s| s.3 <= 7.5)
        .filter_map(|&(id, ra, dec, _)| project(shot.q, ra, dec).map(|(u, v)| (id, u, v)))
        .filter(|&(_, u, v)| u > 0.0 && v > 0.0 && u < n && v < n)
        .collect();
    let got = &labels.frame.stars;
    let mut worst = 0.0f64;
    for &(id, u, v) in &want {
        let s = got
            .iter()
            .find(|s| s.id as i64 == id)
            .unwrap_or_else(|| panic!("HIP {id} at ({u:.1}, {v:.1}) not labelled"));
        worst = worst.max((s.u - u).hypot(s.v - v));
        assert!(!s.occulted && s.electron_rate > 0.0);
    }
    println!(
        "{} stars labelled, {} expected, worst position {worst:.2e} px",
        got.len(),
        want.len()
    );
    assert_eq!(got.len(), want.len());
    assert!(worst < 0.01, "{worst} px");
}
