//! Small reusable PNG figures for reports: curves with an optional log axis
//! and a residual panel, curves over a histogram with marker lines, a
//! heatmap with a colour bar, and a quiver (arrow) plot. Built on `plotters`' bitmap backend with the bundled DejaVu Sans
//! (data/fonts/), so no system font library is needed.
//!
//! Every figure has a title and axis labels with units (the caller gives
//! them); colour always comes with a colour bar or a legend.

use std::path::Path;
use std::sync::Once;

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::error::{Error, Result};

/// DejaVu Sans, registered as plotters' `sans-serif` on first use.
static FONT: &[u8] = include_bytes!("../data/fonts/DejaVuSans.ttf");
static FONT_ONCE: Once = Once::new();

const FONT_NAME: &str = "sans-serif";

fn ensure_font() {
    FONT_ONCE.call_once(|| {
        // The bundled file is a valid TTF; failure would only mean no text.
        let _ = plotters::style::register_font(FONT_NAME, FontStyle::Normal, FONT);
    });
}

/// Series colours, in order (colour-blind friendly, Okabe–Ito).
pub const PALETTE: [RGBColor; 6] = [
    RGBColor(0, 114, 178),
    RGBColor(213, 94, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(230, 159, 0),
    RGBColor(86, 180, 233),
];

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mark {
    /// Connected line.
    Line,
    /// Filled circles.
    Points,
    /// Filled circles joined by a line.
    LinePoints,
}

/// One named series of `(x, y)` points.
#[derive(Debug, Clone)]
pub struct Series {
    pub label: String,
    pub points: Vec<(f64, f64)>,
    pub mark: Mark,
    /// Colour; `None`: the next colour of [`PALETTE`].
    pub colour: Option<RGBColor>,
    /// A label beside each point (empty: none), in the series' colour.
    pub point_labels: Vec<String>,
}

impl Series {
    pub fn line(label: impl Into<String>, points: Vec<(f64, f64)>) -> Series {
        Series {
            label: label.into(),
            points,
            mark: Mark::Line,
            colour: None,
            point_labels: Vec::new(),
        }
    }

    pub fn points(label: impl Into<String>, points: Vec<(f64, f64)>) -> Series {
        Series {
            label: label.into(),
            points,
            mark: Mark::Points,
            colour: None,
            point_labels: Vec::new(),
        }
    }

    /// Points joined by a line, in the order given.
    pub fn line_points(label: impl Into<String>, points: Vec<(f64, f64)>) -> Series {
        Series {
            label: label.into(),
            points,
            mark: Mark::LinePoints,
            colour: None,
            point_labels: Vec::new(),
        }
    }

    /// The same series with `labels` beside its points, in order.
    pub fn with_point_labels(self, labels: Vec<String>) -> Series {
        Series {
            point_labels: labels,
            ..self
        }
    }

    /// The same series drawn in `colour`.
    pub fn with_colour(self, colour: RGBColor) -> Series {
        Series {
            colour: Some(colour),
            ..self
        }
    }
}

/// A panel of series sharing axes.
#[derive(Debug, Clone)]
pub struct Panel {
    pub y_label: String,
    /// Logarithmic y axis (non-positive values are left out).
    pub log_y: bool,
    pub series: Vec<Series>,
}

/// A curve figure: a main panel and an optional residual panel below it,
/// sharing the x axis.
#[derive(Debug, Clone)]
pub struct CurveFigure {
    pub title: String,
    pub x_label: String,
    pub main: Panel,
    pub residuals: Option<Panel>,
    /// Pixels.
    pub size: (u32, u32),
}

fn draw_err(path: &Path) -> impl Fn(String) -> Error + '_ {
    move |e| Error::Other(format!("{}: cannot draw figure: {e}", path.display()))
}

/// A line series' key in the legend: a short stroke in its style.
fn line_key(style: ShapeStyle) -> impl Fn((i32, i32)) -> PathElement<(i32, i32)> {
    move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], style)
}

/// Draws the legend of the chart's labelled series at `position`: the
/// figures' one look (14 px labels in a white, black-bordered box).
fn draw_legend<'a, DB, CT>(
    chart: &mut ChartContext<'a, DB, CT>,
    position: SeriesLabelPosition,
) -> std::result::Result<(), String>
where
    DB: DrawingBackend + 'a,
    CT: CoordTranslate,
{
    chart
        .configure_series_labels()
        .label_font((FONT_NAME, 14))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(position)
        .draw()
        .map_err(|e| e.to_string())
}

fn finite_points(s: &Series, log_y: bool) -> Vec<(f64, f64)> {
    s.points
        .iter()
        .copied()
        .filter(|&p| finite_points_keep(p, log_y))
        .collect()
}

/// Whether point `p` can be drawn (finite, and y > 0 on a log axis).
fn finite_points_keep((x, y): (f64, f64), log_y: bool) -> bool {
    x.is_finite() && y.is_finite() && (!log_y || y > 0.0)
}

/// `(min, max)` of `values`, widened when empty or degenerate.
fn span(values: impl Iterator<Item = f64>, log: bool) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !(lo.is_finite() && hi.is_finite()) {
        return if log { (0.1, 10.0) } else { (-1.0, 1.0) };
    }
    if log {
        if hi <= lo * 1.0001 {
            return (lo / 2.0, hi * 2.0);
        }
        let r = (hi / lo).powf(0.05);
        (lo / r, hi * r)
    } else {
        let pad = if hi > lo {
            0.05 * (hi - lo)
        } else {
            0.5 * lo.abs().max(1.0)
        };
        (lo - pad, hi + pad)
    }
}

/// Tick label of `v` on a linear axis spanning `span`: as many decimals
/// as the ticks (about a tenth of the span) need.
fn tick(v: f64, span: f64) -> String {
    let d = if span.is_finite() && span > 0.0 {
        (-(span / 10.0).log10()).ceil().clamp(0.0, 6.0) as usize
    } else {
        2
    };
    let t = format!("{v:.d$}");
    // No "-0".
    if t.trim_start_matches('-')
        .chars()
        .all(|c| c == '0' || c == '.')
    {
        t.trim_start_matches('-').to_string()
    } else {
        t
    }
}

/// Tick label of `v` on a log axis.
fn tick_log(v: f64) -> String {
    if !(v > 0.0) || !(1e-3..1e5).contains(&v) {
        return format!("{v:.0e}");
    }
    let d = (-v.log10().floor()).clamp(0.0, 3.0) as usize;
    format!("{v:.d$}")
}

/// Tick label of `v` on a log axis spanning `decades`: powers of ten
/// only, and 2 and 5 × them when the axis spans under three decades;
/// the other minor ticks keep their grid line but no label, so labels
/// never crowd where a decade's ticks close up.
fn tick_log_sparse(v: f64, decades: f64) -> String {
    if !(v > 0.0) {
        return String::new();
    }
    let mantissa = v / 10f64.powf(v.log10().floor());
    let near = |m: f64| (mantissa - m).abs() < 1e-6 * m || (mantissa - 10.0 * m).abs() < 1e-5 * m;
    if near(1.0) || (decades < 3.0 && (near(2.0) || near(5.0))) {
        tick_log(v)
    } else {
        String::new()
    }
}

/// Draws one panel on `area`. A macro, because plotters' linear and log
/// charts are different types with the same drawing calls.
macro_rules! draw_panel {
    ($area:expr, $caption:expr, $x:expr, $y:expr, $x_label:expr, $panel:expr, $err:expr, $xf:expr, $yf:expr) => {
        draw_panel!(
            $area,
            $caption,
            $x,
            $y,
            $x_label,
            $panel,
            $err,
            $xf,
            $yf,
            SeriesLabelPosition::UpperLeft
        )
    };
    ($area:expr, $caption:expr, $x:expr, $y:expr, $x_label:expr, $panel:expr, $err:expr, $xf:expr, $yf:expr, $legend:expr) => {{
        let mut builder = ChartBuilder::on($area);
        if let Some(c) = $caption {
            builder.caption(c, (FONT_NAME, 22));
        }
        let mut chart = builder
            .margin(12)
            .x_label_area_size(42)
            .y_label_area_size(80)
            .build_cartesian_2d($x, $y)
            .map_err(|e| $err(e.to_string()))?;
        chart
            .configure_mesh()
            .x_desc($x_label)
            .y_desc($panel.y_label.as_str())
            .x_label_formatter($xf)
            .y_label_formatter($yf)
            .label_style((FONT_NAME, 14))
            .axis_desc_style((FONT_NAME, 16))
            .draw()
            .map_err(|e| $err(e.to_string()))?;
        let mut labelled = false;
        for (i, s) in $panel.series.iter().enumerate() {
            let colour = s.colour.unwrap_or(PALETTE[i % PALETTE.len()]);
            let pts = finite_points(s, $panel.log_y);
            let anno = match s.mark {
                Mark::Line => chart.draw_series(LineSeries::new(pts, colour.stroke_width(2))),
                Mark::Points => chart.draw_series(
                    pts.into_iter()
                        .map(move |p| Circle::new(p, 3, colour.filled())),
                ),
                Mark::LinePoints => {
                    chart
                        .draw_series(LineSeries::new(pts.clone(), colour.stroke_width(2)))
                        .map_err(|e| $err(e.to_string()))?;
                    chart.draw_series(
                        pts.into_iter()
                            .map(move |p| Circle::new(p, 4, colour.filled())),
                    )
                }
            }
            .map_err(|e| $err(e.to_string()))?;
            if !s.label.is_empty() {
                labelled = true;
                anno.label(s.label.as_str())
                    .legend(line_key(colour.stroke_width(3)));
            }
            if !s.point_labels.is_empty() {
                let font = (FONT_NAME, 13).into_font().color(&colour);
                // Above the points for even series, below for odd: two
                // curves at one height keep their labels apart.
                let dy = if i % 2 == 0 { -17 } else { 5 };
                let labelled_points = s
                    .points
                    .iter()
                    .zip(&s.point_labels)
                    .filter(|(p, _)| finite_points_keep(**p, $panel.log_y));
                chart
                    .draw_series(labelled_points.map(|(&p, l)| {
                        EmptyElement::at(p) + Text::new(l.clone(), (5, dy), font.clone())
                    }))
                    .map_err(|e| $err(e.to_string()))?;
            }
        }
        if labelled {
            draw_legend(&mut chart, $legend).map_err(|e| $err(e))?;
        }
    }};
}

fn panel_on(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    caption: Option<&str>,
    x: (f64, f64),
    x_label: &str,
    panel: &Panel,
    path: &Path,
) -> Result<()> {
    let err = draw_err(path);
    let ys = panel
        .series
        .iter()
        .flat_map(|s| finite_points(s, panel.log_y))
        .map(|p| p.1);
    let (y0, y1) = span(ys, panel.log_y);
    let xf = |v: &f64| tick(*v, x.1 - x.0);
    if panel.log_y {
        let yf = |v: &f64| tick_log(*v);
        draw_panel!(
            area,
            caption,
            x.0..x.1,
            (y0..y1).log_scale(),
            x_label,
            panel,
            err,
            &xf,
            &yf
        );
    } else {
        let yf = |v: &f64| tick(*v, y1 - y0);
        draw_panel!(
            area,
            caption,
            x.0..x.1,
            y0..y1,
            x_label,
            panel,
            err,
            &xf,
            &yf
        );
    }
    Ok(())
}

/// The linear axis range of the finite x of `series`' points.
fn x_span<'a>(series: impl Iterator<Item = &'a Series>) -> (f64, f64) {
    let xs = series.flat_map(|s| s.points.iter().map(|p| p.0).filter(|x| x.is_finite()));
    span(xs, false)
}

/// Writes a curve figure (main panel, optional residual panel) as PNG.
pub fn curve_figure(path: impl AsRef<Path>, fig: &CurveFigure) -> Result<()> {
    let path = path.as_ref();
    ensure_font();
    draw_png(path, fig.size, |root| {
        let residuals = fig.residuals.iter().flat_map(|p| p.series.iter());
        let x = x_span(fig.main.series.iter().chain(residuals));
        match &fig.residuals {
            Some(res) => {
                let (top, bottom) = root.split_vertically(fig.size.1 * 65 / 100);
                panel_on(&top, Some(&fig.title), x, &fig.x_label, &fig.main, path)?;
                panel_on(&bottom, None, x, &fig.x_label, res, path)?;
            }
            None => panel_on(root, Some(&fig.title), x, &fig.x_label, &fig.main, path)?,
        }
        Ok(())
    })
}

/// Panels side by side, each with a logarithmic x axis (shared range) and
/// its own y axis (logarithmic where the panel says so): e.g. time against
/// several error measures.
#[derive(Debug, Clone)]
pub struct LogXPanels {
    pub title: String,
    pub x_label: String,
    pub panels: Vec<Panel>,
    /// Pixels.
    pub size: (u32, u32),
}

/// Fraction of the data's y range added above it in [`log_x_panels`]: the
/// legend's band.
const LEGEND_HEADROOM: f64 = 0.5;

/// Fraction of the x axis's log span added right of the data when points
/// carry labels.
const POINT_LABEL_ROOM: f64 = 0.15;

/// Writes side-by-side log-x panels as PNG.
pub fn log_x_panels(path: impl AsRef<Path>, fig: &LogXPanels) -> Result<()> {
    let path = path.as_ref();
    let err = draw_err(path);
    let xs = fig
        .panels
        .iter()
        .flat_map(|p| p.series.iter())
        .flat_map(|s| s.points.iter().map(|p| p.0))
        .filter(|x| x.is_finite() && *x > 0.0);
    let (x0, x1) = span(xs, true);
    // plotters labels a log axis from its first power of ten up: make sure
    // there is one.
    let x = if floor_decade(x1) < x0 {
        (floor_decade(x0), x1)
    } else {
        (x0, x1)
    };
    // Room right of the last point for its label.
    let labelled = fig
        .panels
        .iter()
        .flat_map(|p| p.series.iter())
        .any(|s| !s.point_labels.is_empty());
    let x = if labelled {
        (x.0, x.1 * (x.1 / x.0).powf(POINT_LABEL_ROOM))
    } else {
        x
    };
    draw_png(path, fig.size, |root| {
        let body = root
            .titled(&fig.title, (FONT_NAME, 22))
            .map_err(|e| err(e.to_string()))?;
        let areas = body.split_evenly((1, fig.panels.len().max(1)));
        for (area, panel) in areas.iter().zip(&fig.panels) {
            log_x_panel_on(area, x, &fig.x_label, panel, path)?;
        }
        Ok(())
    })
}

/// The power of ten at or below `v` (> 0), less a hair so that plotters'
/// own rounding of its logarithm keeps it on the axis.
fn floor_decade(v: f64) -> f64 {
    10f64.powf(v.log10().floor()) * (1.0 - 1e-9)
}

fn log_x_panel_on(
    area: &Area,
    x: (f64, f64),
    x_label: &str,
    panel: &Panel,
    path: &Path,
) -> Result<()> {
    let err = draw_err(path);
    // Non-positive x cannot sit on a log axis.
    let positive_x = Panel {
        series: panel
            .series
            .iter()
            .map(|s| Series {
                points: s.points.iter().copied().filter(|p| p.0 > 0.0).collect(),
                ..s.clone()
            })
            .collect(),
        ..panel.clone()
    };
    let panel = &positive_x;
    let ys = panel
        .series
        .iter()
        .flat_map(|s| finite_points(s, panel.log_y))
        .map(|p| p.1);
    let (y0, y1) = span(ys, panel.log_y);
    // The axis starts at a power of ten (see `log_x_panels`): the headroom
    // below is a share of the whole axis, not of the data's span.
    let y0 = if panel.log_y { floor_decade(y0) } else { y0 };
    // Headroom above the data (a third of the panel) for the legend, so it
    // never covers a point.
    let y1 = if panel.log_y {
        y1 * (y1 / y0).powf(LEGEND_HEADROOM)
    } else {
        y1 + LEGEND_HEADROOM * (y1 - y0)
    };
    let x_decades = (x.1 / x.0).log10();
    let xf = |v: &f64| tick_log_sparse(*v, x_decades);
    let none: Option<&str> = None;
    let legend = SeriesLabelPosition::UpperRight;
    if panel.log_y {
        let y_decades = (y1 / y0).log10();
        let yf = |v: &f64| tick_log_sparse(*v, y_decades);
        draw_panel!(
            area,
            none,
            (x.0..x.1).log_scale(),
            (y0..y1).log_scale(),
            x_label,
            panel,
            err,
            &xf,
            &yf,
            legend
        );
    } else {
        let yf = |v: &f64| tick(*v, y1 - y0);
        draw_panel!(
            area,
            none,
            (x.0..x.1).log_scale(),
            y0..y1,
            x_label,
            panel,
            err,
            &xf,
            &yf,
            legend
        );
    }
    Ok(())
}

/// A histogram of `values` in `bins` equal bins over their range, with
/// labelled vertical marker lines (e.g. percentiles).
#[derive(Debug, Clone)]
pub struct Histogram {
    pub x_label: String,
    pub y_label: String,
    pub values: Vec<f64>,
    pub bins: usize,
    /// `(label, x)` drawn as vertical lines in the palette's colours.
    pub markers: Vec<(String, f64)>,
}

/// Bin counts of the finite `values` over `[lo, hi]` (the top edge
/// belongs to the last bin).
pub fn bin_counts(values: &[f64], lo: f64, hi: f64, bins: usize) -> Vec<u64> {
    let bins = bins.max(1);
    let mut counts = vec![0u64; bins];
    let width = (hi - lo) / bins as f64;
    for &v in values
        .iter()
        .filter(|v| v.is_finite() && **v >= lo && **v <= hi)
    {
        let k = if width > 0.0 {
            ((v - lo) / width) as usize
        } else {
            0
        };
        counts[k.min(bins - 1)] += 1;
    }
    counts
}

fn histogram_on(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    h: &Histogram,
    path: &Path,
) -> Result<()> {
    let err = draw_err(path);
    let finite = h.values.iter().copied().filter(|v| v.is_finite());
    let marks = h.markers.iter().map(|m| m.1).filter(|v| v.is_finite());
    let (lo, hi) = span(finite.chain(marks), false);
    let bins = h.bins.clamp(1, 10_000);
    let counts = bin_counts(&h.values, lo, hi, bins);
    let top = counts.iter().copied().max().unwrap_or(0).max(1) as f64 * 1.1;
    let mut chart = ChartBuilder::on(area)
        .margin(12)
        .x_label_area_size(42)
        .y_label_area_size(80)
        .build_cartesian_2d(lo..hi, 0.0..top)
        .map_err(|e| err(e.to_string()))?;
    chart
        .configure_mesh()
        .x_desc(h.x_label.as_str())
        .y_desc(h.y_label.as_str())
        .x_label_formatter(&|v| tick(*v, hi - lo))
        .y_label_formatter(&|v| tick(*v, top))
        .label_style((FONT_NAME, 14))
        .axis_desc_style((FONT_NAME, 16))
        .draw()
        .map_err(|e| err(e.to_string()))?;
    let width = (hi - lo) / bins as f64;
    chart
        .draw_series(
            counts
                .iter()
                .enumerate()
                .filter(|c| *c.1 > 0)
                .map(|(k, &c)| {
                    let x0 = lo + k as f64 * width;
                    Rectangle::new(
                        [(x0, 0.0), (x0 + width, c as f64)],
                        RGBColor(150, 150, 150).filled(),
                    )
                }),
        )
        .map_err(|e| err(e.to_string()))?;
    for (i, (label, x)) in h.markers.iter().enumerate() {
        if !x.is_finite() {
            continue;
        }
        let colour = PALETTE[i % PALETTE.len()];
        chart
            .draw_series(LineSeries::new(
                vec![(*x, 0.0), (*x, top)],
                colour.stroke_width(2),
            ))
            .map_err(|e| err(e.to_string()))?
            .label(label.as_str())
            .legend(line_key(colour.stroke_width(3)));
    }
    if !h.markers.is_empty() {
        draw_legend(&mut chart, SeriesLabelPosition::UpperRight).map_err(&err)?;
    }
    Ok(())
}

/// A curve panel (with the title) above a histogram panel.
#[derive(Debug, Clone)]
pub struct CurveAndHistogram {
    pub title: String,
    pub x_label: String,
    pub main: Panel,
    pub histogram: Histogram,
    /// Pixels.
    pub size: (u32, u32),
}

/// Writes a curve panel over a histogram as PNG.
pub fn curve_and_histogram(path: impl AsRef<Path>, fig: &CurveAndHistogram) -> Result<()> {
    let path = path.as_ref();
    ensure_font();
    draw_png(path, fig.size, |root| {
        let x = x_span(fig.main.series.iter());
        let (top, bottom) = root.split_vertically(fig.size.1 * 58 / 100);
        panel_on(&top, Some(&fig.title), x, &fig.x_label, &fig.main, path)?;
        histogram_on(&bottom, &fig.histogram, path)?;
        Ok(())
    })
}

/// Perceptually ordered colour map (viridis control points, linear
/// between them) for `t` in [0, 1].
pub fn viridis(t: f64) -> RGBColor {
    const STOPS: [(u8, u8, u8); 6] = [
        (68, 1, 84),
        (65, 68, 135),
        (42, 120, 142),
        (34, 168, 132),
        (122, 209, 81),
        (253, 231, 37),
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let f = t * (STOPS.len() - 1) as f64;
    let i = (f as usize).min(STOPS.len() - 2);
    let w = f - i as f64;
    let mix = |a: u8, b: u8| (a as f64 * (1.0 - w) + b as f64 * w).round() as u8;
    let (a, b) = (STOPS[i], STOPS[i + 1]);
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

/// A scalar map to draw as a heatmap.
#[derive(Debug, Clone)]
pub struct Heatmap<'a> {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    /// Colour-bar label with the unit.
    pub value_label: String,
    /// Map size in its own pixels (row-major, top row first).
    pub width: usize,
    pub height: usize,
    pub values: &'a [f64],
    /// Image size, pixels.
    pub size: (u32, u32),
}

/// Block-averages a `width`×`height` raster to at most `max_cells` cells
/// along each axis (non-finite values left out; an empty cell is NaN).
/// Returns the cells per row and the block size.
fn block_mean(
    width: usize,
    height: usize,
    values: &[f64],
    max_cells: usize,
) -> (usize, usize, Vec<f64>) {
    let step = width.max(height).div_ceil(max_cells.max(1)).max(1);
    let (nw, nh) = (width.div_ceil(step), height.div_ceil(step));
    let mut out = vec![0.0; nw * nh];
    for (j, row) in out.chunks_mut(nw.max(1)).enumerate() {
        for (i, cell) in row.iter_mut().enumerate() {
            let (mut sum, mut n) = (0.0, 0usize);
            for y in j * step..((j + 1) * step).min(height) {
                for x in i * step..((i + 1) * step).min(width) {
                    let v = values[y * width + x];
                    if v.is_finite() {
                        sum += v;
                        n += 1;
                    }
                }
            }
            *cell = if n > 0 { sum / n as f64 } else { f64::NAN };
        }
    }
    (nw, step, out)
}

fn downsample(h: &Heatmap, max_cells: usize) -> (usize, usize, Vec<f64>) {
    block_mean(h.width, h.height, h.values, max_cells)
}

/// Writes a heatmap with a colour bar as PNG. The y axis runs down (image
/// rows), as on the screen.
pub fn heatmap(path: impl AsRef<Path>, h: &Heatmap) -> Result<()> {
    let path = path.as_ref();
    ensure_font();
    let err = draw_err(path);
    if h.width == 0 || h.height == 0 || h.values.len() != h.width * h.height {
        return Err(err(format!(
            "{} values for a {}×{} map",
            h.values.len(),
            h.width,
            h.height
        )));
    }
    let (nw, step, cells) = downsample(h, 240);
    let (vmin, vmax) = span(cells.iter().copied().filter(|v| v.is_finite()), false);
    let norm = |v: f64| (v - vmin) / (vmax - vmin);
    draw_png(path, h.size, |root| {
        let (main, bar) = root.split_horizontally(h.size.0 * 80 / 100);
        let main = main
            .titled(&h.title, (FONT_NAME, 22))
            .map_err(|e| err(e.to_string()))?;
        let (w, hh) = (h.width as f64, h.height as f64);
        let builder = |xr: f64, yr: f64| {
            ChartBuilder::on(&main)
                .margin(12)
                .x_label_area_size(42)
                .y_label_area_size(70)
                .build_cartesian_2d(0.0..xr, -yr..0.0)
        };
        // A map is drawn at its own aspect ratio: the axis of the longer
        // side (in plot pixels per map pixel) is extended, left blank.
        let (pw, ph) = builder(w, hh)
            .map_err(|e| err(e.to_string()))?
            .plotting_area()
            .dim_in_pixel();
        let per_px = (w / pw.max(1) as f64).max(hh / ph.max(1) as f64);
        let mut chart =
            builder(per_px * pw as f64, per_px * ph as f64).map_err(|e| err(e.to_string()))?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc(h.x_label.as_str())
            .y_desc(h.y_label.as_str())
            .y_label_formatter(&|y| format!("{:.0}", 0.0 - y))
            .label_style((FONT_NAME, 14))
            .axis_desc_style((FONT_NAME, 16))
            .draw()
            .map_err(|e| err(e.to_string()))?;
        let s = step as f64;
        chart
            .draw_series(cells.iter().enumerate().map(|(k, &v)| {
                let (i, j) = ((k % nw) as f64, (k / nw) as f64);
                let colour = if v.is_finite() {
                    viridis(norm(v))
                } else {
                    WHITE
                };
                Rectangle::new(
                    [
                        (i * s, -j * s),
                        (((i + 1.0) * s).min(w), -((j + 1.0) * s).min(hh)),
                    ],
                    colour.filled(),
                )
            }))
            .map_err(|e| err(e.to_string()))?;
        colour_bar(&bar, (vmin, vmax), ColourMap::Viridis, &h.value_label, path)?;
        Ok(())
    })
}

fn colour_bar(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    (vmin, vmax): (f64, f64),
    map: ColourMap,
    label: &str,
    path: &Path,
) -> Result<()> {
    let err = draw_err(path);
    let mut chart = ChartBuilder::on(area)
        .margin_top(44)
        .margin_bottom(54)
        .margin_left(8)
        .margin_right(24)
        .right_y_label_area_size(80)
        .build_cartesian_2d(0.0..1.0, vmin..vmax)
        .map_err(|e| err(e.to_string()))?;
    chart
        .configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .y_desc(label)
        .y_label_formatter(&|v| tick(*v, vmax - vmin))
        .label_style((FONT_NAME, 13))
        .axis_desc_style((FONT_NAME, 15))
        .draw()
        .map_err(|e| err(e.to_string()))?;
    let n = 200;
    chart
        .draw_series((0..n).map(|k| {
            let a = vmin + (vmax - vmin) * k as f64 / n as f64;
            let b = vmin + (vmax - vmin) * (k + 1) as f64 / n as f64;
            Rectangle::new(
                [(0.0, a), (1.0, b)],
                map.colour((k as f64 + 0.5) / n as f64).filled(),
            )
        }))
        .map_err(|e| err(e.to_string()))?;
    Ok(())
}

/// Colour maps for values scaled to [0, 1].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ColourMap {
    /// Perceptually ordered, for magnitudes ([`viridis`]).
    Viridis,
    /// Black (0) to white (1), for images.
    Grey,
    /// Blue (0) – white (½) – red (1), for signed differences.
    Diverging,
}

impl ColourMap {
    /// The colour of `t` (clamped to [0, 1]; NaN: the low end).
    pub fn colour(self, t: f64) -> RGBColor {
        let t = if t.is_finite() {
            t.clamp(0.0, 1.0)
        } else {
            0.0
        };
        let lerp = |a: (u8, u8, u8), b: (u8, u8, u8), w: f64| {
            let m = |x: u8, y: u8| (x as f64 * (1.0 - w) + y as f64 * w).round() as u8;
            RGBColor(m(a.0, b.0), m(a.1, b.1), m(a.2, b.2))
        };
        match self {
            ColourMap::Viridis => viridis(t),
            ColourMap::Grey => lerp((0, 0, 0), (255, 255, 255), t),
            ColourMap::Diverging if t < 0.5 => lerp((33, 102, 172), (255, 255, 255), 2.0 * t),
            ColourMap::Diverging => lerp((255, 255, 255), (178, 24, 43), 2.0 * t - 1.0),
        }
    }
}

/// A drawing area of a figure being built.
pub type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;

/// Draws a figure of `size` pixels with `draw` on a white canvas and
/// writes it to `path` as PNG, through `image` (so plotters needs no image
/// encoder of its own, and the build one `image` version).
pub fn draw_png(
    path: &Path,
    size: (u32, u32),
    draw: impl FnOnce(&Area) -> Result<()>,
) -> Result<()> {
    ensure_font();
    let err = draw_err(path);
    let mut buf = vec![255u8; size.0 as usize * size.1 as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, size).into_drawing_area();
        draw(&root)?;
        root.present().map_err(|e| err(e.to_string()))?;
    }
    let img = image::RgbImage::from_raw(size.0, size.1, buf)
        .ok_or_else(|| err("canvas size mismatch".into()))?;
    img.save_with_format(path, image::ImageFormat::Png)
        .map_err(|e| Error::Other(format!("{}: cannot write figure: {e}", path.display())))
}

/// Lines of text from the top-left of `area`, `font_px` high.
pub fn text_block(area: &Area, lines: &[String], font_px: u32, path: &Path) -> Result<()> {
    ensure_font();
    let step = (font_px as f64 * 1.35) as i32;
    for (k, line) in lines.iter().enumerate() {
        area.draw(&Text::new(
            line.as_str(),
            (10, 6 + k as i32 * step),
            (FONT_NAME, font_px).into_font().color(&BLACK),
        ))
        .map_err(|e| draw_err(path)(e.to_string()))?;
    }
    Ok(())
}

/// A raster drawn in image coordinates (y down, pixel `(c, r)` covering
/// `[c, c+1] × [r, r+1]` from `origin`), with a colour bar.
#[derive(Debug, Clone)]
pub struct ImagePanel<'a> {
    pub title: String,
    /// Colour-bar label with the unit.
    pub value_label: String,
    /// Image coordinates of the raster's top-left corner, px.
    pub origin: (f64, f64),
    pub width: usize,
    pub height: usize,
    /// Row-major, top row first; NaN drawn light grey.
    pub values: &'a [f64],
    /// Values at the ends of the colour map.
    pub range: (f64, f64),
    pub map: ColourMap,
    /// A circle `(cx, cy, radius)` outlined over the image, in image
    /// coordinates (e.g. a disk's limb).
    pub circle: Option<(f64, f64, f64)>,
}

/// Outline of a circle in image coordinates, as chart points (y negated).
fn circle_path((cx, cy, r): (f64, f64, f64)) -> Vec<(f64, f64)> {
    (0..=180)
        .map(|k| {
            let a = k as f64 * std::f64::consts::TAU / 180.0;
            (cx + r * a.cos(), -(cy + r * a.sin()))
        })
        .collect()
}

/// Margins that keep a `w`×`h` data box square-pixelled in `area`.
fn square_margins(area: &Area, w: f64, h: f64) -> (u32, u32) {
    let (aw, ah) = area.dim_in_pixel();
    let (pw, ph) = (aw as f64 - 70.0 - 16.0, ah as f64 - 40.0 - 34.0 - 16.0);
    if pw <= 0.0 || ph <= 0.0 || w <= 0.0 || h <= 0.0 {
        return (8, 8);
    }
    if pw / ph > w / h {
        (8 + ((pw - ph * w / h) / 2.0) as u32, 8)
    } else {
        (8, 8 + ((ph - pw * h / w) / 2.0) as u32)
    }
}

/// Draws an [`ImagePanel`] on `area` (its right 20 % holds the colour bar).
pub fn image_panel(area: &Area, p: &ImagePanel, path: &Path) -> Result<()> {
    let err = draw_err(path);
    if p.width == 0 || p.height == 0 || p.values.len() != p.width * p.height {
        return Err(err(format!(
            "{} values for a {}×{} panel",
            p.values.len(),
            p.width,
            p.height
        )));
    }
    let (lo, hi) = if p.range.1 > p.range.0 {
        p.range
    } else {
        (p.range.0, p.range.0 + 1.0)
    };
    let (aw, _) = area.dim_in_pixel();
    let (main, bar) = area.split_horizontally(aw * 80 / 100);
    let (w, h) = (p.width as f64, p.height as f64);
    let (x0, y0) = p.origin;
    let (mx, my) = square_margins(&main, w, h);
    let mut chart = ChartBuilder::on(&main)
        .caption(&p.title, (FONT_NAME, 18))
        .margin_left(mx)
        .margin_right(mx)
        .margin_top(my)
        .margin_bottom(my)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(x0..x0 + w, -(y0 + h)..-y0)
        .map_err(|e| err(e.to_string()))?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc("x (px)")
        .y_desc("y (px)")
        .x_label_formatter(&|x| format!("{x:.0}"))
        .y_label_formatter(&|y| format!("{:.0}", 0.0 - y))
        .label_style((FONT_NAME, 13))
        .axis_desc_style((FONT_NAME, 14))
        .draw()
        .map_err(|e| err(e.to_string()))?;
    let (nw, step, cells) = block_mean(p.width, p.height, p.values, 300);
    let s = step as f64;
    chart
        .draw_series(cells.iter().enumerate().map(|(k, &v)| {
            let (i, j) = ((k % nw) as f64, (k / nw) as f64);
            let colour = if v.is_finite() {
                p.map.colour((v - lo) / (hi - lo))
            } else {
                RGBColor(210, 210, 210)
            };
            Rectangle::new(
                [
                    (x0 + i * s, -(y0 + j * s)),
                    (x0 + ((i + 1.0) * s).min(w), -(y0 + ((j + 1.0) * s).min(h))),
                ],
                colour.filled(),
            )
        }))
        .map_err(|e| err(e.to_string()))?;
    if let Some(c) = p
        .circle
        .filter(|c| c.0.is_finite() && c.1.is_finite() && c.2 > 0.0)
    {
        chart
            .draw_series(std::iter::once(PathElement::new(
                circle_path(c),
                PALETTE[4].stroke_width(1),
            )))
            .map_err(|e| err(e.to_string()))?;
    }
    colour_bar(&bar, (lo, hi), p.map, &p.value_label, path)
}

/// One arrow of a quiver plot: from `(x, y)` along `(dx, dy)` (data
/// units of the arrow, scaled by [`Quiver::scale`] for drawing).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Arrow {
    pub x: f64,
    pub y: f64,
    pub dx: f64,
    pub dy: f64,
}

/// A quiver plot over an image-like area (y down).
#[derive(Debug, Clone)]
pub struct Quiver<'a> {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    /// `[x0, x1] × [y0, y1]` of the plotted area, y down.
    pub extent: ((f64, f64), (f64, f64)),
    pub arrows: &'a [Arrow],
    /// Drawing length per arrow unit (e.g. screen px per camera px of
    /// residual).
    pub scale: f64,
    /// Length of the key arrow in arrow units, and its label
    /// (e.g. `0.1 camera px`).
    pub key: (f64, String),
    pub size: (u32, u32),
}

fn arrow_lines(x: f64, y: f64, dx: f64, dy: f64) -> [Vec<(f64, f64)>; 3] {
    let (ex, ey) = (x + dx, y + dy);
    let len = dx.hypot(dy);
    let head = 0.3 * len;
    let (ux, uy) = if len > 0.0 {
        (dx / len, dy / len)
    } else {
        (0.0, 0.0)
    };
    let side = |s: f64| {
        let (c, sn) = (0.45_f64.cos(), s * 0.45_f64.sin());
        let (rx, ry) = (ux * c - uy * sn, ux * sn + uy * c);
        vec![(ex, -ey), (ex - head * rx, -(ey - head * ry))]
    };
    [vec![(x, -y), (ex, -ey)], side(1.0), side(-1.0)]
}

/// Writes a quiver plot as PNG, with a key arrow below the title.
pub fn quiver(path: impl AsRef<Path>, q: &Quiver) -> Result<()> {
    let path = path.as_ref();
    ensure_font();
    let err = draw_err(path);
    let ((x0, x1), (y0, y1)) = q.extent;
    if !(x1 > x0 && y1 > y0 && q.scale.is_finite() && q.scale > 0.0) {
        return Err(err("empty extent or non-positive scale".into()));
    }
    draw_png(path, q.size, |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(&q.title, (FONT_NAME, 22))
            .margin(12)
            .margin_top(44)
            .x_label_area_size(42)
            .y_label_area_size(70)
            .build_cartesian_2d(x0..x1, -y1..-y0)
            .map_err(|e| err(e.to_string()))?;
        chart
            .configure_mesh()
            .x_desc(q.x_label.as_str())
            .y_desc(q.y_label.as_str())
            .y_label_formatter(&|y| format!("{:.0}", 0.0 - y))
            .label_style((FONT_NAME, 14))
            .axis_desc_style((FONT_NAME, 16))
            .draw()
            .map_err(|e| err(e.to_string()))?;
        let colour = PALETTE[0];
        for a in q
            .arrows
            .iter()
            .filter(|a| [a.x, a.y, a.dx, a.dy].iter().all(|v| v.is_finite()))
        {
            let lines = arrow_lines(a.x, a.y, a.dx * q.scale, a.dy * q.scale);
            chart
                .draw_series(
                    lines
                        .into_iter()
                        .map(|l| PathElement::new(l, colour.stroke_width(1))),
                )
                .map_err(|e| err(e.to_string()))?;
        }
        // Key: an arrow of the key length in the top margin, above the plot,
        // so it never hides an arrow.
        let area = chart.plotting_area();
        let (pw, _) = area.dim_in_pixel();
        let (bx, by) = area.get_base_pixel();
        let klen = (q.key.0 * q.scale * pw as f64 / (x1 - x0)).round();
        let key_colour = PALETTE[1];
        let (kx, ky) = (bx as f64 + 10.0, by as f64 - 14.0);
        for l in arrow_lines(kx, ky, klen, 0.0) {
            let px: Vec<(i32, i32)> = l.iter().map(|&(x, y)| (x as i32, -y as i32)).collect();
            root.draw(&PathElement::new(px, key_colour.stroke_width(2)))
                .map_err(|e| err(e.to_string()))?;
        }
        root.draw(&Text::new(
            format!("key: {}", q.key.1),
            ((kx + klen + 10.0) as i32, (ky - 8.0) as i32),
            (FONT_NAME, 14).into_font().color(&key_colour),
        ))
        .map_err(|e| err(e.to_string()))?;
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_ticks_label_decades_and_two_five_on_short_axes_only() {
        for (v, decades, expected) in [
            (10.0, 5.0, "10"),
            (100.0, 5.0, "100"),
            (1e-4, 5.0, "1e-4"),
            (20.0, 5.0, ""),
            (20.0, 2.0, "20"),
            (50.0, 2.0, "50"),
            (500.0, 2.9, "500"),
            (30.0, 2.0, ""),
            (90.0, 1.0, ""),
            (0.0, 1.0, ""),
        ] {
            assert_eq!(tick_log_sparse(v, decades), expected, "{v} over {decades}");
        }
    }

    #[test]
    fn viridis_ends_and_clamps() {
        assert_eq!(viridis(0.0), RGBColor(68, 1, 84));
        assert_eq!(viridis(1.0), RGBColor(253, 231, 37));
        assert_eq!(viridis(-3.0), viridis(0.0));
        assert_eq!(viridis(f64::NAN), viridis(0.0));
    }

    /// Each figure kind writes a PNG of the requested size whose pixels are
    /// not all white (something was drawn).
    #[test]
    fn figures_write_pngs_of_the_requested_size() {
        let dir = tempfile::tempdir().unwrap();
        // OPTISTIM_KEEP_FIGURES=DIR keeps the figures for looking at them.
        let keep = std::env::var_os("OPTISTIM_KEEP_FIGURES");
        let check = |p: &Path, size: (u32, u32)| {
            if let Some(k) = &keep {
                std::fs::copy(p, Path::new(k).join(p.file_name().unwrap())).unwrap();
            }
            let img = image::open(p).unwrap().to_rgb8();
            assert_eq!((img.width(), img.height()), size);
            let dark = img
                .pixels()
                .filter(|p| p.0.iter().all(|&c| c < 100))
                .count();
            assert!(dark > 500, "{}: only {dark} dark pixels", p.display());
        };
        let pts: Vec<(f64, f64)> = (0..=32)
            .map(|k| (k as f64 * 8.0, 1e-3 + (k as f64 / 32.0).powf(2.2)))
            .collect();
        let fig = CurveFigure {
            title: "curve".into(),
            x_label: "drive level".into(),
            main: Panel {
                y_label: "radiance (W m⁻² sr⁻¹)".into(),
                log_y: true,
                series: vec![
                    Series::line("fit", pts.clone()),
                    Series::points("measured", pts.clone()),
                ],
            },
            residuals: Some(Panel {
                y_label: "residual (%)".into(),
                log_y: false,
                series: vec![Series::points(
                    "",
                    pts.iter().map(|p| (p.0, p.1.sin())).collect(),
                )],
            }),
            size: (800, 600),
        };
        let p = dir.path().join("c.png");
        curve_figure(&p, &fig).unwrap();
        check(&p, (800, 600));
        let values: Vec<f64> = (0..50 * 30).map(|k| (k % 50) as f64 / 50.0).collect();
        let p = dir.path().join("h.png");
        heatmap(
            &p,
            &Heatmap {
                title: "map".into(),
                x_label: "u (px)".into(),
                y_label: "v (px)".into(),
                value_label: "gain".into(),
                width: 50,
                height: 30,
                values: &values,
                size: (700, 420),
            },
        )
        .unwrap();
        check(&p, (700, 420));
        let arrows: Vec<Arrow> = (0..25)
            .map(|k| Arrow {
                x: (k % 5) as f64 * 20.0 + 10.0,
                y: (k / 5) as f64 * 20.0 + 10.0,
                dx: 0.1,
                dy: -0.05,
            })
            .collect();
        let p = dir.path().join("q.png");
        quiver(
            &p,
            &Quiver {
                title: "residuals".into(),
                x_label: "u (px)".into(),
                y_label: "v (px)".into(),
                extent: ((0.0, 100.0), (0.0, 100.0)),
                arrows: &arrows,
                scale: 100.0,
                key: (0.1, "0.1 px".into()),
                size: (600, 600),
            },
        )
        .unwrap();
        check(&p, (600, 600));
        let bad = Heatmap {
            width: 3,
            height: 3,
            values: &values[..4],
            ..heatmap_like()
        };
        assert!(heatmap(dir.path().join("bad.png"), &bad).is_err());
    }

    fn heatmap_like() -> Heatmap<'static> {
        Heatmap {
            title: String::new(),
            x_label: String::new(),
            y_label: String::new(),
            value_label: String::new(),
            width: 0,
            height: 0,
            values: &[],
            size: (100, 100),
        }
    }
}

/// A band between two curves over x, shaded, on a log y axis, with
/// optional horizontal reference lines: e.g. the exposures between a noise
/// floor and saturation along a trajectory.
#[derive(Debug, Clone)]
pub struct ShadedBand {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    /// (x, lower, upper); the band is shaded where lower < upper.
    pub rows: Vec<(f64, f64, f64)>,
    pub lower_label: String,
    pub upper_label: String,
    pub band_label: String,
    /// Labelled horizontal lines (y, label).
    pub lines: Vec<(f64, String)>,
    /// Pixels.
    pub size: (u32, u32),
}

/// Writes a [`ShadedBand`] figure as PNG. A single row is drawn as a band
/// one unit wide around its x.
pub fn shaded_band(path: impl AsRef<Path>, fig: &ShadedBand) -> Result<()> {
    let path = path.as_ref();
    let err = draw_err(path);
    let rows: Vec<(f64, f64, f64)> = if fig.rows.len() == 1 {
        let (x, lo, hi) = fig.rows[0];
        vec![(x - 0.5, lo, hi), (x + 0.5, lo, hi)]
    } else {
        fig.rows.clone()
    };
    let ok = |v: f64| v.is_finite() && v > 0.0;
    let ys = rows
        .iter()
        .flat_map(|r| [r.1, r.2])
        .chain(fig.lines.iter().map(|l| l.0))
        .filter(|&v| ok(v));
    let (y0, y1) = span(ys, true);
    // Headroom for the legend above the data.
    let (y0, y1) = (floor_decade(y0), y1 * (y1 / y0).powf(LEGEND_HEADROOM));
    let (x0, x1) = span(rows.iter().map(|r| r.0), false);
    draw_png(path, fig.size, |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(&fig.title, (FONT_NAME, 22))
            .margin(12)
            .x_label_area_size(42)
            .y_label_area_size(80)
            .build_cartesian_2d(x0..x1, (y0..y1).log_scale())
            .map_err(|e| err(e.to_string()))?;
        chart
            .configure_mesh()
            .x_desc(fig.x_label.as_str())
            .y_desc(fig.y_label.as_str())
            .x_label_formatter(&|v: &f64| tick(*v, x1 - x0))
            .y_label_formatter(&|v: &f64| tick_log(*v))
            .label_style((FONT_NAME, 14))
            .axis_desc_style((FONT_NAME, 16))
            .draw()
            .map_err(|e| err(e.to_string()))?;
        let open: Vec<(f64, f64, f64)> = rows
            .iter()
            .copied()
            .filter(|r| ok(r.1) && ok(r.2))
            .map(|(x, lo, hi)| (x, lo, hi.max(lo)))
            .collect();
        let mut polygon: Vec<(f64, f64)> = open.iter().map(|r| (r.0, r.1)).collect();
        polygon.extend(open.iter().rev().map(|r| (r.0, r.2)));
        let shade = PALETTE[2].mix(0.3);
        chart
            .draw_series(std::iter::once(Polygon::new(polygon, shade.filled())))
            .map_err(|e| err(e.to_string()))?
            .label(fig.band_label.as_str())
            .legend(move |(x, y)| Rectangle::new([(x, y - 6), (x + 18, y + 6)], shade.filled()));
        for (label, colour, pick) in [
            (&fig.lower_label, PALETTE[0], 1usize),
            (&fig.upper_label, PALETTE[1], 2usize),
        ] {
            let pts: Vec<(f64, f64)> = rows
                .iter()
                .map(|r| (r.0, if pick == 1 { r.1 } else { r.2 }))
                .filter(|p| ok(p.1))
                .collect();
            chart
                .draw_series(LineSeries::new(pts, colour.stroke_width(2)))
                .map_err(|e| err(e.to_string()))?
                .label(label.as_str())
                .legend(line_key(colour.stroke_width(3)));
        }
        for (y, label) in fig.lines.iter().filter(|l| ok(l.0)) {
            chart
                .draw_series(DashedLineSeries::new(
                    vec![(x0, *y), (x1, *y)],
                    8,
                    5,
                    BLACK.stroke_width(2),
                ))
                .map_err(|e| err(e.to_string()))?
                .label(label.as_str())
                .legend(line_key(BLACK.stroke_width(2)));
        }
        draw_legend(&mut chart, SeriesLabelPosition::UpperRight).map_err(&err)?;
        Ok(())
    })
}
