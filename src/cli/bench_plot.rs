//! `optistim bench --plot`: the speed-against-error figure of a bench
//! sweep (log-log, one curve per setting family, the targets of
//! BENCHMARKS.md drawn as lines).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use optistim::figures::{log_x_panels, LogXPanels, Panel, Series};
use plotters::style::RGBColor;

use super::bench::BenchRow;

/// Pixel size of the figure.
pub(super) const BENCH_FIGURE_SIZE: (u32, u32) = (1400, 620);
/// Target: render time per frame [ms] (BENCHMARKS.md, issue 2).
pub const TARGET_MS: f64 = 10.0;
/// Target: total-flux error [%] (1e-4).
pub const TARGET_FLUX_PERCENT: f64 = 1e-2;
/// Target: per-pixel error p99 [%].
pub const TARGET_PIXEL_P99_PERCENT: f64 = 0.5;
/// Colour of the target lines.
const TARGET_GREY: RGBColor = RGBColor(90, 90, 90);

/// The settings of one bench row, as the figure groups them.
#[derive(Clone, Copy, PartialEq)]
struct Setting {
    phase: f64,
    interior: &'static str,
    density: f64,
    samples: usize,
    spacing: usize,
    tolerance: f64,
}

impl Setting {
    fn of(r: &BenchRow) -> Setting {
        Setting {
            phase: r.phase_deg,
            interior: match r.interior {
                optistim::render::Interior::Pixels => "pixels",
                optistim::render::Interior::Caps => "caps",
            },
            density: r.caps_per_pixel,
            samples: r.texture_samples,
            spacing: r.node_spacing,
            tolerance: r.pixel_tolerance,
        }
    }
}

/// A swept setting: its name and value in a row.
struct Axis {
    name: &'static str,
    value: fn(&Setting) -> f64,
    label: fn(&Setting) -> String,
    /// The value alone, beside a point on a curve along this axis.
    short: fn(&Setting) -> String,
}

const AXES: [Axis; 6] = [
    Axis {
        name: "caps per pixel",
        value: |s| s.density,
        label: |s| format!("{} caps/px", s.density),
        short: |s| format!("{}", s.density),
    },
    Axis {
        name: "node spacing",
        value: |s| s.spacing as f64,
        label: |s| format!("nodes {} px", s.spacing),
        short: |s| format!("{} px", s.spacing),
    },
    Axis {
        name: "pixel tolerance",
        value: |s| s.tolerance,
        label: |s| format!("tol. {:.0e}", s.tolerance),
        short: |s| format!("{:.0e}", s.tolerance),
    },
    Axis {
        name: "map samples",
        value: |s| s.samples as f64,
        label: |s| format!("map {0}×{0}", s.samples),
        short: |s| format!("{0}×{0}", s.samples),
    },
    Axis {
        name: "phase",
        value: |s| s.phase,
        label: |s| format!("{:.0}°", s.phase),
        short: |s| format!("{:.0}°", s.phase),
    },
    Axis {
        name: "interior",
        value: |s| if s.interior == "pixels" { 0.0 } else { 1.0 },
        label: |s| format!("interior {}", s.interior),
        short: |s| s.interior.to_string(),
    },
];

/// Whether `axis` takes more than one value over `settings`.
fn varies(axis: &Axis, settings: &[Setting]) -> bool {
    settings
        .iter()
        .any(|s| (axis.value)(s) != (axis.value)(&settings[0]))
}

/// Where `--plot` writes: the path itself when it ends in `.png`, else
/// `bench.png` in that directory (created).
pub fn figure_path(plot: &Path) -> Result<PathBuf> {
    let is_png = plot
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("png"));
    let (dir, path) = if is_png {
        let dir = plot.parent().unwrap_or(Path::new("")).to_path_buf();
        (dir, plot.to_path_buf())
    } else {
        (plot.to_path_buf(), plot.join("bench.png"))
    };
    if !dir.as_os_str().is_empty() {
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    Ok(path)
}

/// One curve per family (rows equal in every swept setting but the curve
/// parameter: the first of caps per pixel, node spacing, pixel tolerance,
/// map samples that takes several values), as `(label, rows)` with the
/// rows in sweep order.
fn families(rows: &[BenchRow]) -> (Option<&'static Axis>, Vec<Family<'_>>) {
    let settings: Vec<Setting> = rows.iter().map(Setting::of).collect();
    let along = AXES[..4].iter().position(|a| varies(a, &settings));
    let keyed: Vec<&Axis> = AXES
        .iter()
        .enumerate()
        .filter(|(i, a)| Some(*i) != along && varies(a, &settings))
        .map(|(_, a)| a)
        .collect();
    let mut out: Vec<(Vec<f64>, String, Vec<&BenchRow>)> = Vec::new();
    for (row, s) in rows.iter().zip(&settings) {
        let key: Vec<f64> = keyed.iter().map(|a| (a.value)(s)).collect();
        match out.iter_mut().find(|f| f.0 == key) {
            Some(f) => f.2.push(row),
            None => {
                let label = keyed.iter().map(|a| (a.label)(s)).collect::<Vec<_>>();
                let label = if label.is_empty() {
                    "as swept".to_string()
                } else {
                    label.join(", ")
                };
                out.push((key, label, vec![row]));
            }
        }
    }
    let families = out.into_iter().map(|(_, l, r)| (l, r)).collect();
    (along.map(|i| &AXES[i]), families)
}

/// A curve's label and its rows.
type Family<'a> = (String, Vec<&'a BenchRow>);

/// A horizontal target line over `x` and a vertical one over `y`.
fn target_lines(x: (f64, f64), y: (f64, f64), y_target: f64, y_label: &str) -> [Series; 2] {
    [
        Series::line(
            format!("target ≤ {y_target} % ({y_label})"),
            vec![(x.0, y_target), (x.1, y_target)],
        )
        .with_colour(RGBColor(0, 0, 0)),
        Series::line(
            format!("target ≤ {TARGET_MS} ms per frame"),
            vec![(TARGET_MS, y.0), (TARGET_MS, y.1)],
        )
        .with_colour(TARGET_GREY),
    ]
}

/// One panel: error measure `error` [%] against the median time.
fn panel(
    fams: &[Family],
    along: Option<&Axis>,
    y_label: &str,
    error: fn(&BenchRow) -> f64,
    target: f64,
) -> Panel {
    let all = fams.iter().flat_map(|f| f.1.iter());
    let (mut x0, mut x1) = (TARGET_MS, TARGET_MS);
    let (mut y0, mut y1) = (target, target);
    for r in all.filter(|r| error(r) > 0.0 && r.median_ms > 0.0) {
        x0 = x0.min(r.median_ms);
        x1 = x1.max(r.median_ms);
        y0 = y0.min(error(r));
        y1 = y1.max(error(r));
    }
    let mut series: Vec<Series> = fams
        .iter()
        .map(|(label, rows)| {
            let pts = rows.iter().map(|r| (r.median_ms, error(r))).collect();
            let labels = rows.iter().map(|r| point_label(r, along)).collect();
            Series::line_points(label.clone(), pts).with_point_labels(labels)
        })
        .collect();
    series.extend(target_lines((x0, x1), (y0, y1), target, y_label));
    Panel {
        y_label: format!("{y_label} (%)"),
        log_y: true,
        series,
    }
}

/// What a point is: its value along the curve's axis, else the planner's
/// step that chose it, else nothing (the legend says it).
fn point_label(row: &BenchRow, along: Option<&Axis>) -> String {
    match (along, &row.planned) {
        (Some(axis), _) => (axis.short)(&Setting::of(row)),
        (None, Some(plan)) => plan.label.clone(),
        (None, None) => String::new(),
    }
}

/// Writes the figure of `rows` (one bench sweep) to `path`.
pub(super) fn write_bench_figure(path: &Path, rows: &[BenchRow], what: &str) -> Result<()> {
    let (along, fams) = families(rows);
    let title_along = along.map_or(String::new(), |a| {
        format!("; along each curve: {} (labelled)", a.name)
    });
    let fig = LogXPanels {
        title: format!("Render time against error: {what}{title_along}"),
        x_label: "render time per frame, median (ms)".into(),
        panels: vec![
            panel(
                &fams,
                along,
                "total-flux error",
                |r| 100.0 * r.flux_error,
                TARGET_FLUX_PERCENT,
            ),
            panel(
                &fams,
                along,
                "per-pixel error p99",
                |r| 100.0 * r.pixel_error_p99,
                TARGET_PIXEL_P99_PERCENT,
            ),
        ],
        size: BENCH_FIGURE_SIZE,
    };
    log_x_panels(path, &fig)?;
    Ok(())
}
