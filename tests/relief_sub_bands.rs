//! The sub-bands of one frame share their lines of sight through the
//! relief (`render::sight_memo`): rendered with the memo, every band's
//! flux is the same, bit for bit, as rendered alone; a state change while
//! the memo is on is not read from it.

mod common;
use common::ring_dem::*;
use common::*;

use optistim::render::{BandModel, Renderer};
use optistim::scene::Scene;

/// The ring ridge of `tests/relief_hidden.rs` (100 m, σ = 1.5°, at 45°,
/// seen from over the pole), whose crest hides lit terrain: caps are cut
/// at its occlusion edge and many points march their line of sight.
fn ridge_scene(dir: &std::path::Path, range_radii: f64) -> Scene {
    let mut setup = Setup::new(
        "{ model = \"area\", albedo = 0.3 }",
        30.0,
        range_radii,
        200.0,
    );
    let (h, crest, sigma) = (100.0, 45f64.to_radians(), 1.5f64.to_radians());
    let rows: Vec<f64> = (0..ROWS)
        .map(|j| ridge(row_lat(j), h, crest, sigma))
        .collect();
    let dem = dir.join("ring.tiff");
    write_ring_dem(&dem, &rows);
    let body_attitude = pole_toward(setup.camera_position());
    setup.extra_body = format!(
        "shadows = {{ dem = \"{}\", scale = 1.0, mode = \"always\", displace = true, cache_dir = \"{}\" }}",
        dem.display(),
        dir.display()
    );
    let toml = setup.toml().replacen("[state]", &body_attitude, 1);
    Scene::from_toml(&toml, std::path::Path::new("t.toml")).unwrap()
}

/// Two bands of different albedo: each band's flux.
fn bands(renderer: &mut Renderer, scene: &Scene, shared: bool) -> Vec<Vec<f32>> {
    if shared {
        renderer.begin_sub_bands();
    }
    let out = [0.12, 0.31]
        .map(|albedo| {
            let band = BandModel {
                albedo: Some(albedo),
                ..BandModel::default()
            };
            let stats = renderer.render_flux_band(&scene.body, &scene.state, &scene.render, &band);
            assert!(stats.total_flux > 0.0);
            renderer.flux().to_vec()
        })
        .to_vec();
    if shared {
        let kept = renderer.sub_band_memo().kept();
        assert!(
            kept.0 > 100 && kept.1 > 10,
            "the memo kept {kept:?} (marches, leaves)"
        );
        renderer.end_sub_bands();
        assert_eq!(renderer.sub_band_memo().kept(), (0, 0));
    }
    out
}

#[test]
fn shared_sights_change_no_pixel() {
    let dir = tempfile::tempdir().unwrap();
    let scene = ridge_scene(dir.path(), 4.0);
    let mut renderer = Renderer::new(scene.camera.render_pinhole().clone());
    let alone = bands(&mut renderer, &scene, false);
    let shared = bands(&mut renderer, &scene, true);
    for (a, s) in alone.iter().zip(&shared) {
        assert!(a.iter().zip(s).all(|(x, y)| x.to_bits() == y.to_bits()));
    }
    // The bands differ (albedo), so the comparison sees each band.
    assert!(alone[0] != alone[1]);

    // The same body from 3.5 radii, rendered while the memo still holds
    // the 4-radii frame's answers: as rendered alone.
    let near = ridge_scene(dir.path(), 3.5);
    let band = BandModel::default();
    renderer.begin_sub_bands();
    renderer.render_flux_band(&scene.body, &scene.state, &scene.render, &band);
    renderer.render_flux_band(&scene.body, &near.state, &near.render, &band);
    let after = renderer.flux().to_vec();
    renderer.end_sub_bands();
    renderer.render_flux_band(&scene.body, &near.state, &near.render, &band);
    let fresh = renderer.flux();
    assert!(after.iter().any(|&v| v > 0.0));
    assert!(after
        .iter()
        .zip(fresh)
        .all(|(x, y)| x.to_bits() == y.to_bits()));
}
