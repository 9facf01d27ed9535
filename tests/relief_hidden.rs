//! Terrain hidden from the camera by nearer relief adds no light: a ring
//! ridge seen at a slant, the pixels whose ray (marched through the DEM's
//! height field here) first meets the ridge's near face and, past it, the
//! lit terrain behind, carry one surface's radiance, not both.

mod common;
use common::ring_dem::*;
use common::*;

use glam::{DQuat, DVec3};

/// Whether body-frame point `p` is inside the relief over the sphere of
/// `radius`.
fn inside(rows: &[f64], radius: f64, p: DVec3) -> bool {
    let lat = p.z.atan2(p.x.hypot(p.y));
    p.length() <= radius + dem_height(rows, lat)
}

/// Distances along the ray `o + t d` where it enters, leaves and enters
/// the relief again (steps of 0.1 m from `t0` to `t1`).
fn crossings(rows: &[f64], radius: f64, o: DVec3, d: DVec3, t0: f64, t1: f64) -> Vec<f64> {
    let mut out = Vec::new();
    let mut was = false;
    let mut t = t0;
    while t < t1 && out.len() < 3 {
        let now = inside(rows, radius, o + d * t);
        if now != was {
            out.push(t);
            was = now;
        }
        t += 0.1;
    }
    out
}

/// Whether the Sun (body-frame unit vector `sun`) lights the surface
/// point `p`: a march of 1 km toward it stays outside the relief.
fn sunlit(rows: &[f64], radius: f64, p: DVec3, sun: DVec3) -> bool {
    (1..4000).all(|k| !inside(rows, radius, p + sun * (0.5 + k as f64 * 0.25)))
}

/// A Gaussian ring ridge 100 m high (σ = 1.5°) at latitude 45° on a
/// 1000 m area-law body seen from 4 radii over its pole, 300 px across,
/// the Sun 30° off the camera on the same side: the camera sees the
/// ridge's outer side at about 30° elevation, so a band behind it is
/// hidden yet sunlit. Along the central row on the Sun's side, every pixel
/// the test's march finds covered twice (near face, then hidden lit
/// terrain) stays at the uniform radiance of one surface (the centre's),
/// and pixels whose first surface is sunlit keep it, neither darker nor
/// brighter by 5 % (the grazing pixel just past the crest, where the
/// terrain behind meets the ridge's image, held 1.41 before caps were cut
/// at occlusion edges): with the far limb's wider cap layout (the default)
/// and without it.
#[test]
fn terrain_behind_a_ridge_adds_no_light() {
    for far_limb in [None, Some(false)] {
        hidden_terrain_adds_no_light(far_limb);
    }
}

fn hidden_terrain_adds_no_light(far_limb: Option<bool>) {
    let dir = tempfile::tempdir().unwrap();
    let mut setup = Setup::new("{ model = \"area\", albedo = 0.3 }", 30.0, 4.0, 300.0);
    let (radius, range) = (setup.radius, setup.range);
    let (h, crest, sigma) = (100.0, 45f64.to_radians(), 1.5f64.to_radians());
    let rows: Vec<f64> = (0..ROWS)
        .map(|j| ridge(row_lat(j), h, crest, sigma))
        .collect();
    let dem = dir.path().join("ring.tiff");
    write_ring_dem(&dem, &rows);

    let cam = setup.camera_position();
    let body_attitude = pole_toward(cam);
    let far_limb = far_limb.map_or(String::new(), |f| format!("far_limb = {f}, "));
    let layout = if far_limb.is_empty() {
        "default layout"
    } else {
        &far_limb
    };
    setup.extra_body = format!(
        "shadows = {{ dem = \"{}\", scale = 1.0, mode = \"always\", displace = true, {far_limb}cache_dir = \"{}\" }}",
        dem.display(),
        dir.path().display()
    );
    let toml = setup.toml().replacen("[state]", &body_attitude, 1);
    let scene = optistim::scene::Scene::from_toml(&toml, std::path::Path::new("t.toml")).unwrap();
    let images = render(&scene);
    let decision = images.summary.relief_shadows.expect("shadows decided");
    assert!(
        decision.applied && decision.displaced && decision.hidden_applied,
        "{decision:?}"
    );

    // Camera axes as `look_at` builds them; rays in the body frame.
    let z = -cam.normalize();
    let x_cam = z.cross(DVec3::Z).normalize();
    let y_cam = z.cross(x_cam);
    // The same rotation as pole_toward's.
    let to_body = DQuat::from_rotation_arc(DVec3::Z, cam.normalize()).inverse();
    let sun = to_body * setup.sun_position().normalize();
    let origin = to_body * cam;
    let sign: i64 = if x_cam.dot(setup.sun_position()) > 0.0 {
        1
    } else {
        -1
    };
    let pin = &scene.camera.pinhole;
    let row = pin.cy.floor() as usize;
    let img = &images.radiance;
    let full = img[row * pin.width + pin.cx.floor() as usize] as f64;
    assert!(full > 0.0);

    // Per pixel of the row from the centre out on the Sun's side: (twice
    // covered with the far surface sunlit, first surface sunlit).
    let (t0, t1) = (range - radius - 2.0 * h, range);
    let class: Vec<(bool, bool)> = (0..(pin.width as i64 / 2 - 2))
        .map(|k| {
            let col = (pin.cx.floor() as i64 + sign * k) as f64 + 0.5;
            let v = DVec3::new(
                (col - pin.cx) / pin.fx,
                (row as f64 + 0.5 - pin.cy) / pin.fy,
                1.0,
            );
            let d = to_body * (x_cam * v.x + y_cam * v.y + z * v.z).normalize();
            let c = crossings(&rows, radius, origin, d, t0, t1);
            let first_lit = !c.is_empty() && sunlit(&rows, radius, origin + d * c[0], sun);
            let twice = c.len() == 3 && sunlit(&rows, radius, origin + d * c[2], sun);
            (twice, first_lit)
        })
        .collect();
    let col = |k: usize| (pin.cx.floor() as i64 + sign * k as i64) as usize;
    let (mut twice, mut lit, mut worst_high, mut worst_lit) = (0, 0, 0.0f64, 0.0f64);
    for k in 2..class.len() - 2 {
        let ratio = img[row * pin.width + col(k)] as f64 / full;
        let near = &class[k - 2..=k + 2];
        if near.iter().all(|c| c.0) {
            twice += 1;
            worst_high = worst_high.max(ratio - 1.0);
            eprintln!("pixel {k}: twice covered, radiance / full = {ratio:.4}");
        }
        if near.iter().all(|c| c.1) {
            lit += 1;
            worst_lit = worst_lit.max((1.0 - ratio).abs());
        }
    }
    eprintln!("{layout}: {twice} twice-covered pixels, worst excess {worst_high:e}; {lit} lit, worst |1 - ratio| {worst_lit:e}");
    assert!(twice >= 3, "the march finds {twice} twice-covered pixels");
    assert!(
        worst_high < 0.05,
        "hidden terrain adds {worst_high} of the radiance"
    );
    assert!(
        lit > 50 && worst_lit < 0.05,
        "{layout}: {lit} lit pixels, one off by {worst_lit}"
    );
}
