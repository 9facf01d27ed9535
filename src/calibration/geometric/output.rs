//! What the geometric calibration writes: the geometry CSV (the lattice
//! `run` reads, with a provenance header), the JSON report and the residual
//! quiver plot.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use super::patterns::DotGrid;
use super::{GeometricConfig, GeometricReport, Solution};
use crate::error::{Error, Result};
use crate::facility::geometry::GeometryCalibration;
use crate::figures::{quiver, Arrow, Quiver};

/// Nodes `0, step, 2 step, …` and always `size`.
pub fn lattice_axis(size: usize, step: usize) -> Vec<usize> {
    let mut xs: Vec<usize> = (0..size).step_by(step).collect();
    xs.push(size);
    xs
}

/// The geometry CSV text of a solution.
pub fn geometry_csv(
    solution: &Solution,
    grid: &DotGrid,
    cfg: &GeometricConfig,
    camera: &str,
    date: &str,
) -> String {
    let (w, h) = grid.screen;
    let (rms, max) = solution.residual_px();
    let (rms_as, max_as) = solution.residual_arcsec();
    let used = solution.dots.iter().filter(|d| d.used).count();
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# optistim geometric calibration: screen pixel -> camera direction (tan_x, tan_y) at zero attitude"
    );
    let _ = writeln!(s, "# date: {date}");
    let _ = writeln!(s, "# software: optistim {}", env!("CARGO_PKG_VERSION"));
    let _ = writeln!(s, "# camera: {}", camera.replace('\n', " "));
    if let Some(p) = &cfg.intrinsics {
        let _ = writeln!(s, "# intrinsics: {}", p.display());
    }
    let _ = writeln!(
        s,
        "# screen: {w}x{h}; dots every {} px ({:?}, radius {} px, level {}); {} shown",
        cfg.spacing_px, grid.shape, cfg.radius_px, cfg.level, solution.dots_shown
    );
    let _ = writeln!(
        s,
        "# dots: {} identified, {used} used, {} rejected as outliers; anchors {} of {}",
        solution.dots.len(),
        solution.dots.len() - used,
        solution.anchors_identified,
        solution.anchors_shown
    );
    let _ = writeln!(
        s,
        "# residual: RMS {rms:.4} camera px ({rms_as:.3} arcsec), max {max:.4} camera px ({max_as:.3} arcsec)"
    );
    let _ = writeln!(
        s,
        "# model: homography + radial distortion about a fitted centre, Legendre correction of degree {}; lattice every {} px",
        cfg.correction_degree, cfg.lattice_px
    );
    s.push_str("u_px,v_px,tan_x,tan_y\n");
    for v in lattice_axis(h, cfg.lattice_px) {
        for u in lattice_axis(w, cfg.lattice_px) {
            let t = solution.fit.model.direction(u as f64, v as f64);
            let _ = writeln!(s, "{u},{v},{:e},{:e}", t[0], t[1]);
        }
    }
    s
}

/// Writes the geometry CSV (checked by loading it back as `run` does), the
/// JSON report and the quiver plot.
pub fn write_all(
    solution: &Solution,
    grid: &DotGrid,
    cfg: &GeometricConfig,
    camera: &str,
    out_dir: &Path,
) -> Result<GeometricReport> {
    let date = crate::utc::now();
    let csv_path = out_dir.join(&cfg.output);
    let text = geometry_csv(solution, grid, cfg, camera, &date);
    std::fs::write(&csv_path, &text).map_err(|e| Error::io(&csv_path, e))?;
    GeometryCalibration::load(&csv_path, grid.screen).map_err(|e| {
        Error::Other(format!(
            "the fitted geometry is not a valid calibration (the fit extrapolates badly \
             beyond the dots the camera saw?): {e}"
        ))
    })?;
    let (rms_px, max_px) = solution.residual_px();
    let (rms_arcsec, max_arcsec) = solution.residual_arcsec();
    let used = solution.dots.iter().filter(|d| d.used).count();
    let report = GeometricReport {
        date_utc: date,
        software: format!("optistim {}", env!("CARGO_PKG_VERSION")),
        camera: camera.to_string(),
        intrinsics: cfg.intrinsics.clone(),
        screen: [grid.screen.0, grid.screen.1],
        config: cfg.clone(),
        geometry_csv: csv_path,
        report_json: out_dir.join("geometric_report.json"),
        quiver_png: Some(out_dir.join("geometric_residuals.png")),
        dots_shown: solution.dots_shown,
        blobs_detected: solution.blobs_detected,
        blobs_rejected: solution.blobs_rejected,
        dots_matched: solution.dots.len(),
        dots_used: used,
        dots_rejected: solution.dots.len() - used,
        anchors_identified: solution.anchors_identified,
        anchors_shown: solution.anchors_shown,
        iterations: solution.iterations,
        rms_px,
        max_px,
        rms_arcsec,
        max_arcsec,
        radial_k1_k2: solution.fit.model.radial_coefficients(),
        model: solution.fit.model.clone(),
        dots: solution.dots.clone(),
    };
    write_json(&report.report_json, &report)?;
    if let Some(png) = &report.quiver_png {
        quiver_plot(&report, png)?;
    }
    Ok(report)
}

fn write_json(path: &PathBuf, report: &GeometricReport) -> Result<()> {
    let text = serde_json::to_string_pretty(report)
        .map_err(|e| Error::Other(format!("{}: {e}", path.display())))?;
    std::fs::write(path, text).map_err(|e| Error::io(path, e))
}

/// The residual of each used dot as an arrow at its screen position,
/// magnified so the largest is about one dot spacing long; the key arrow
/// is a round number of camera pixels. Rejected dots are not drawn (the
/// JSON report lists them).
fn quiver_plot(report: &GeometricReport, path: &Path) -> Result<()> {
    let arrows: Vec<Arrow> = report
        .dots
        .iter()
        .filter(|d| d.used)
        .map(|d| Arrow {
            x: d.u_px,
            y: d.v_px,
            dx: d.dx_px,
            dy: d.dy_px,
        })
        .collect();
    let largest = report.max_px.max(1e-6);
    let key = round_125(largest);
    let scale = report.config.spacing_px as f64 / largest;
    let [w, h] = report.screen;
    let height = (900.0 * h as f64 / w as f64).round().clamp(300.0, 1200.0) as u32 + 120;
    quiver(
        path,
        &Quiver {
            title: format!(
                "Residuals: RMS {:.4}, max {:.4} camera px",
                report.rms_px, report.max_px
            ),
            x_label: "screen u (px)".into(),
            y_label: "screen v (px)".into(),
            extent: ((0.0, w as f64), (0.0, h as f64)),
            arrows: &arrows,
            scale,
            key: (key, format!("{key} camera px")),
            size: (1000, height),
        },
    )
}

/// The largest of 1, 2, 5 × 10ⁿ not above `x`.
fn round_125(x: f64) -> f64 {
    let p = 10f64.powf(x.log10().floor());
    [5.0, 2.0, 1.0]
        .into_iter()
        .map(|m| m * p)
        .find(|&v| v <= x)
        .unwrap_or(p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lattice_spans_the_screen() {
        assert_eq!(lattice_axis(100, 32), vec![0, 32, 64, 96, 100]);
        assert_eq!(lattice_axis(64, 32), vec![0, 32, 64]);
    }

    #[test]
    fn key_lengths_are_round() {
        assert_eq!(round_125(0.0077), 0.005);
        assert_eq!(round_125(0.25), 0.2);
        assert_eq!(round_125(1.0), 1.0);
        assert_eq!(round_125(9.9), 5.0);
    }
}
