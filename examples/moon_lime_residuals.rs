//! The shipped Moon (`configs/bodies/moon.toml`) against LIME at 2–150°
//! phase, waxing and waning, at the six LIME bands: prints a Markdown table
//! of render/LIME − 1 and draws `docs/moon_lime_residuals.png`.
//!
//! `cargo run --release --example moon_lime_residuals`
//!
//! Beyond 90° both the fit and LIME are extrapolations; the table and the
//! figure show the disagreement there rather than hiding it.

use std::path::Path;

use glam::{DMat3, DQuat, DVec3};
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

/// LIME's ln A for band k (see data/lime/README.md).
fn lime(coefs: &[(String, Vec<f64>)], k: usize, g_deg: f64, sun_lon: f64) -> f64 {
    let c = |n: &str| coefs.iter().find(|r| r.0 == n).map_or(0.0, |r| r.1[k]);
    let g = g_deg.to_radians();
    (c("a0")
        + c("a1") * g
        + c("a2") * g * g
        + c("a3") * g.powi(3)
        + c("b1") * sun_lon
        + c("b2") * sun_lon.powi(3)
        + c("b3") * sun_lon.powi(5)
        + c("d1") * (-g_deg / c("p1")).exp()
        + c("d2") * (-g_deg / c("p2")).exp()
        + c("d3") * ((g_deg - c("p3")) / c("p4")).cos())
    .exp()
}

/// Rendered disk reflectance at `nm` (1 nm band), observer at selenographic
/// (0, 0), Sun on the equator at longitude `sun_lon`.
fn render(root: &Path, nm: f64, sun_lon: f64) -> anyhow::Result<f64> {
    let obs = DVec3::X * D0;
    let sun = DVec3::new(sun_lon.cos(), sun_lon.sin(), 0.0) * AU;
    let z = -DVec3::X;
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
camera_position = [{}, 0.0, 0.0]
camera_attitude = [{}, {}, {}, {}]
sun_position = [{}, {}, 0.0]
"#,
        obs.x,
        q.w,
        q.x,
        q.y,
        q.z,
        sun.x,
        sun.y,
        lo = nm - 0.5,
        hi = nm + 0.5,
    );
    let scene = Scene::from_toml(&text, &root.join("configs/residuals.toml"))?;
    let mut renderer = Renderer::new(scene.camera.pinhole.clone());
    let pixels = PixelGeometry::new(&renderer);
    let s = render_scene(&scene, &mut renderer, &pixels)?.summary;
    Ok(s.irradiance_all_caps_w_m2 * std::f64::consts::PI / (OMEGA * s.band_irradiance_1au_w_m2))
}

fn main() -> anyhow::Result<()> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("data/lime/lime_coefficients_20251010_v01.csv"))?;
    let coefs: Vec<(String, Vec<f64>)> = text
        .lines()
        .skip(1)
        .map(|l| {
            let mut f = l.split(',');
            let name = f.next().unwrap_or_default().to_string();
            (name, f.filter_map(|x| x.parse().ok()).collect())
        })
        .collect();
    // residuals[band][phase] = (waxing, waning), per cent.
    let mut residuals = vec![Vec::new(); BANDS.len()];
    for (k, &nm) in BANDS.iter().enumerate() {
        for &g in &PHASES {
            let mut pair = [0.0; 2];
            for (i, sign) in [1.0, -1.0].iter().enumerate() {
                let sun_lon = sign * g.to_radians();
                let model = render(root, nm, sun_lon)?;
                pair[i] = 100.0 * (model / lime(&coefs, k, g, sun_lon) - 1.0);
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
