//! The shipped Moon (`configs/bodies/moon.toml`) against LIME at 2–150°
//! phase, waxing and waning, at the six LIME bands: prints a Markdown table
//! of render/LIME − 1 and draws `docs/moon_lime_residuals.png`.
//!
//! `cargo run --release --example moon_lime_residuals`
//!
//! With `--libration`, it prints instead how much each libration changes
//! the disk reflectance in LIME and in the model (675 and 1020 nm, 30–90°).
//!
//! Beyond 90° both the fit and LIME are extrapolations; the table and the
//! figure show the disagreement there rather than hiding it.

use std::path::Path;

use glam::{DMat3, DQuat, DVec3};
use optistim::radiometry::lime::{Lime, LunarGeometry};
use optistim::radiometry::spectrum::AU;
use optistim::render::detector::{render_scene, PixelGeometry};
use optistim::render::Renderer;
use optistim::scene::Scene;
use plotters::prelude::*;

const BANDS: [f64; 6] = [440.0, 500.0, 675.0, 870.0, 1020.0, 1640.0];
const D0: f64 = 384_400e3;
const OMEGA: f64 = 6.4177e-5;
const PHASES: [f64; 16] = [
    2.0, 3.0, 5.0, 7.5, 10.0, 15.0, 20.0, 30.0, 45.0, 60.0, 75.0, 90.0, 105.0, 120.0, 135.0, 150.0,
];

/// A view of the Moon: the observer at selenographic (lat, lon) [deg],
/// 384 400 km from the centre, the Sun at 1 au at (sun_lat [deg],
/// sun_lon [rad]).
#[derive(Clone, Copy)]
struct View {
    lat: f64,
    lon: f64,
    sun_lat: f64,
    sun_lon: f64,
}

fn unit(lat_deg: f64, lon_rad: f64) -> DVec3 {
    let lat = lat_deg.to_radians();
    DVec3::new(
        lat.cos() * lon_rad.cos(),
        lat.cos() * lon_rad.sin(),
        lat.sin(),
    )
}

impl View {
    /// Observer on the equator at longitude 0, the Sun on the equator.
    fn equatorial(sun_lon: f64) -> Self {
        View {
            lat: 0.0,
            lon: 0.0,
            sun_lat: 0.0,
            sun_lon,
        }
    }

    /// The Sun placed for phase `g_deg` (waxing: east of the observer);
    /// None where the libration makes it impossible.
    fn at_phase(g_deg: f64, waxing: bool, (lat, lon, sun_lat): (f64, f64, f64)) -> Option<Self> {
        let (t, b) = (lat.to_radians(), sun_lat.to_radians());
        let cos_d = (g_deg.to_radians().cos() - t.sin() * b.sin()) / (t.cos() * b.cos());
        let sign = if waxing { 1.0 } else { -1.0 };
        (cos_d.abs() <= 1.0).then(|| View {
            lat,
            lon,
            sun_lat,
            sun_lon: lon.to_radians() + sign * cos_d.acos(),
        })
    }

    fn observer(&self) -> DVec3 {
        unit(self.lat, self.lon.to_radians()) * D0
    }

    fn sun(&self) -> DVec3 {
        unit(self.sun_lat, self.sun_lon) * AU
    }

    /// LIME's disk reflectance in band k (the library's LIME,
    /// `src/radiometry/lime.rs`).
    fn lime(&self, k: usize) -> f64 {
        let geo = LunarGeometry::from_moon_fixed(self.observer(), self.sun())
            .expect("the observer and the Sun are away from the Moon");
        Lime::embedded().band_reflectance(k, &geo)
    }

    /// Rendered disk reflectance at `nm` (1 nm band), LIME's normalisation.
    fn render(&self, root: &Path, nm: f64) -> anyhow::Result<f64> {
        let (obs, sun) = (self.observer(), self.sun());
        let z = (-obs).normalize();
        let x = DVec3::Z.cross(z).normalize();
        let q = DQuat::from_mat3(&DMat3::from_cols(x, z.cross(x), z));
        let text = format!(
            r#"[camera]
resolution = [128, 128]
pixel_pitch = 1e-5
fov_deg = 0.66
f_number = 4.0
exposure = 1e-3
full_well = 1e12
bits = 16
band = [{lo}e-9, {hi}e-9]
[sun]
spectrum = "../data/solar/astm_e490_am0.csv"
[body]
file = "bodies/moon.toml"
[state]
camera_position = [{}, {}, {}]
camera_attitude = [{}, {}, {}, {}]
sun_position = [{}, {}, {}]
"#,
            obs.x,
            obs.y,
            obs.z,
            q.w,
            q.x,
            q.y,
            q.z,
            sun.x,
            sun.y,
            sun.z,
            lo = nm - 0.5,
            hi = nm + 0.5,
        );
        let scene = Scene::from_toml(&text, &root.join("configs/residuals.toml"))?;
        let mut renderer = Renderer::new(scene.camera.pinhole.clone());
        let pixels = PixelGeometry::new(&renderer);
        let s = render_scene(&scene, &mut renderer, &pixels)?.summary;
        Ok(
            s.irradiance_all_caps_w_m2 * std::f64::consts::PI
                / (OMEGA * s.band_irradiance_1au_w_m2),
        )
    }
}

/// Observer (lat, lon) and sub-solar latitude [deg]: the corners and edge
/// middles of the range of the librations (as `tests/moon_lime.rs`).
const LIBRATIONS: [(f64, f64, f64); 8] = [
    (6.5, -7.5, 1.5),
    (-6.5, 7.5, -1.5),
    (6.5, 7.5, 1.5),
    (-6.5, -7.5, -1.5),
    (6.5, 0.0, 1.5),
    (-6.5, 0.0, -1.5),
    (0.0, 7.5, 0.0),
    (0.0, -7.5, 0.0),
];

/// `--libration`: how much each libration changes the disk reflectance,
/// in LIME (its c-terms and the shift of Φ) and in the model (the map
/// seen from elsewhere), ln(A_librated / A_unlibrated) in per cent, at
/// 30–90° phase.
fn libration_response(root: &Path) -> anyhow::Result<()> {
    let bands = [2usize, 4];
    print!("| phase (°) | | observer (lat, lon) |");
    for k in bands {
        print!(" {:.0} nm LIME / model / difference |", BANDS[k]);
    }
    println!("\n|---|---|---|{}", "---|".repeat(bands.len()));
    for g in [30.0, 45.0, 60.0, 75.0, 90.0] {
        for waxing in [true, false] {
            let base =
                View::at_phase(g, waxing, (0.0, 0.0, 0.0)).expect("any phase without libration");
            let base_values: Vec<(f64, f64)> = bands
                .iter()
                .map(|&k| Ok((base.lime(k), base.render(root, BANDS[k])?)))
                .collect::<anyhow::Result<_>>()?;
            for lib in LIBRATIONS {
                let Some(view) = View::at_phase(g, waxing, lib) else {
                    continue;
                };
                let side = if waxing { "waxing" } else { "waning" };
                print!("| {g} | {side} | ({}, {}) |", lib.0, lib.1);
                for (&k, (lime0, model0)) in bands.iter().zip(&base_values) {
                    let lime = 100.0 * (view.lime(k) / lime0).ln();
                    let model = 100.0 * (view.render(root, BANDS[k])? / model0).ln();
                    print!(" {lime:+.2} / {model:+.2} / {:+.2} |", model - lime);
                }
                println!();
            }
        }
    }
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    if std::env::args().any(|a| a == "--libration") {
        return libration_response(root);
    }
    // residuals[band][phase] = (waxing, waning), per cent.
    let mut residuals = vec![Vec::new(); BANDS.len()];
    for (k, &nm) in BANDS.iter().enumerate() {
        for &g in &PHASES {
            let mut pair = [0.0; 2];
            for (i, sign) in [1.0, -1.0].iter().enumerate() {
                let view = View::equatorial(sign * g.to_radians());
                pair[i] = 100.0 * (view.render(root, nm)? / view.lime(k) - 1.0);
            }
            residuals[k].push(pair);
        }
    }
    print!("| phase (°) |");
    for nm in BANDS {
        print!(" {nm:.0} nm wax / wane |");
    }
    println!("\n|---|{}", "---|".repeat(BANDS.len()));
    for (j, g) in PHASES.iter().enumerate() {
        print!("| {g} |");
        for r in &residuals {
            print!(" {:+.2} / {:+.2} |", r[j][0], r[j][1]);
        }
        println!();
    }
    plot(&root.join("docs/moon_lime_residuals.png"), &residuals)?;
    Ok(())
}

fn plot(path: &Path, residuals: &[Vec<[f64; 2]>]) -> anyhow::Result<()> {
    plotters::style::register_font(
        "sans-serif",
        FontStyle::Normal,
        include_bytes!("../data/fonts/DejaVuSans.ttf"),
    )
    .map_err(|_| anyhow::anyhow!("bundled font unreadable"))?;
    // Drawn into a buffer and saved through `image` (plotters' own encoder
    // is not built).
    let size = (1100u32, 650u32);
    let mut buf = vec![255u8; (size.0 * size.1 * 3) as usize];
    let root = BitMapBackend::with_buffer(&mut buf, size).into_drawing_area();
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Bundled Moon vs LIME: disk reflectance residual by phase and band",
            ("sans-serif", 24),
        )
        .margin(15)
        .x_label_area_size(50)
        .y_label_area_size(70)
        .build_cartesian_2d(-152.0f64..152.0, -40.0f64..40.0)?;
    chart
        .configure_mesh()
        .x_desc("signed phase angle (deg; + waxing, − waning)")
        .y_desc("render / LIME − 1 (%), clipped at ±40 %")
        .label_style(("sans-serif", 16))
        .draw()?;
    // The tolerance band and the fitted range.
    chart
        .draw_series(std::iter::once(Rectangle::new(
            [(-90.0, -2.0), (90.0, 2.0)],
            RGBColor(200, 230, 200).filled(),
        )))?
        .label("±2 % over the fitted range 2–90°")
        .legend(|(x, y)| {
            Rectangle::new(
                [(x, y - 5), (x + 18, y + 5)],
                RGBColor(200, 230, 200).filled(),
            )
        });
    let colours = [
        RGBColor(80, 0, 160),
        RGBColor(0, 90, 220),
        RGBColor(0, 150, 60),
        RGBColor(220, 120, 0),
        RGBColor(200, 0, 0),
        RGBColor(90, 40, 20),
    ];
    for ((r, nm), colour) in residuals.iter().zip(BANDS).zip(colours) {
        let mut pts: Vec<(f64, f64)> = PHASES
            .iter()
            .zip(r)
            .map(|(g, p)| (-g, p[1].clamp(-40.0, 40.0)))
            .collect();
        pts.reverse();
        pts.extend(
            PHASES
                .iter()
                .zip(r)
                .map(|(g, p)| (*g, p[0].clamp(-40.0, 40.0))),
        );
        chart
            .draw_series(LineSeries::new(pts.clone(), colour.stroke_width(2)))?
            .label(format!("{nm:.0} nm"))
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 18, y)], colour.stroke_width(2)));
        chart.draw_series(pts.iter().map(|&p| Circle::new(p, 3, colour.filled())))?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .label_font(("sans-serif", 15))
        .draw()?;
    root.present()?;
    drop(chart);
    drop(root);
    image::RgbImage::from_raw(size.0, size.1, buf)
        .ok_or_else(|| anyhow::anyhow!("canvas size mismatch"))?
        .save_with_format(path, image::ImageFormat::Png)?;
    Ok(())
}
