//! PNG pictures of studies (plotters): response surfaces and convergence histories.
//!
//! Pure drawing: the caller gathers the numbers (from the coordinator or a file) and this module only turns
//! them into a picture, so that it is tested without a server.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::coord::Shift;
use plotters::data::float::pretty_print_float;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// A named axis: parameter or QoI, with its unit when the scene gives one.
#[derive(Debug, Clone, PartialEq)]
pub struct Axis {
    pub name: String,
    pub unit: Option<String>,
}

impl Axis {
    pub fn new(name: impl Into<String>, unit: Option<String>) -> Self {
        Self { name: name.into(), unit }
    }

    /// "name [unit]": the usual convention for axis labels; an empty unit counts as none.
    pub fn label(&self) -> String {
        match self.unit.as_deref() {
            Some(unit) if !unit.is_empty() => format!("{} [{unit}]", self.name),
            _ => self.name.clone(),
        }
    }
}

/// A response surface: QoI values over one or two swept parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct Surface {
    pub parameters: Vec<Axis>,
    pub qoi: Axis,
    /// (parameter values in `parameters` order, QoI value)
    pub points: Vec<(Vec<f64>, f64)>,
    pub title: String,
}

/// eta per iteration of one design point.
#[derive(Debug, Clone, PartialEq)]
pub struct ConvergenceSeries {
    pub label: String,
    pub history: Vec<f64>,
}

#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    #[error("nothing to plot: no points")]
    NoPoints,
    #[error("a surface needs at least one swept parameter")]
    NoParameters,
    #[error(
        "a picture shows a surface over 1 or 2 parameters but this one varies {0}: fix the others with --fix NAME=VALUE"
    )]
    TooManyParameters(usize),
    #[error("a point has {got} parameter values where the surface has {expected} parameters")]
    DimensionMismatch { expected: usize, got: usize },
    #[error("a parameter or QoI value is not finite (NaN or infinite)")]
    NonFinite,
    #[error(
        "picture size {0}x{1} out of range: from {min_w}x{min_h} to {max_w}x{max_h} pixels",
        min_w = MIN_SIZE.0,
        min_h = MIN_SIZE.1,
        max_w = MAX_SIZE.0,
        max_h = MAX_SIZE.1
    )]
    Size(u32, u32),
    #[error("{}: pictures are written as PNG, give a file name ending in .png", .0.display())]
    NotPng(PathBuf),
    #[error("drawing failed: {0}")]
    Draw(String),
}

impl<E: std::error::Error + Send + Sync> From<DrawingAreaErrorKind<E>> for PlotError {
    fn from(e: DrawingAreaErrorKind<E>) -> Self {
        PlotError::Draw(e.to_string())
    }
}

/// Below this the fixed-size label areas and colour bar leave no room for the plot itself.
pub const MIN_SIZE: (u32, u32) = (320, 240);
/// Beyond this the bitmap (3 bytes a pixel, held in memory) gets unreasonable, and its byte count overflows
/// plotters' u32 arithmetic long before memory runs out.
pub const MAX_SIZE: (u32, u32) = (10_000, 10_000);

/// Interior contour levels of a colour map: enough to read the shape, few enough to stay legible.
const CONTOUR_LEVELS: usize = 9;
/// Raster subcells per axis of a colour map: finer than the eye needs at usual picture sizes.
const RASTER: usize = 200;
/// Nodes per axis of the regular grid on which scattered data are contoured.
const RESAMPLE: usize = 61;
/// The convergence legend would hide the curves beyond this many series.
const MAX_LEGEND: usize = 12;
const MARGIN: u32 = 15;
const X_LABEL_AREA: u32 = 50;
const Y_LABEL_AREA: u32 = 85;
const BAR_WIDTH: u32 = 140;
const FONT: &str = "sans-serif";

/// Colour of a 1-parameter curve.
const CURVE: RGBColor = RGBColor(31, 119, 180);
/// tab10: distinct colours for convergence histories, cycled.
const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];
/// Viridis at 9 evenly spaced stops: perceptually ordered and readable in grey and by colour-blind readers.
const VIRIDIS: [(f64, f64, f64); 9] = [
    (68.0, 1.0, 84.0),
    (72.0, 40.0, 120.0),
    (62.0, 73.0, 137.0),
    (49.0, 104.0, 142.0),
    (38.0, 130.0, 142.0),
    (31.0, 158.0, 137.0),
    (53.0, 183.0, 121.0),
    (109.0, 205.0, 89.0),
    (253.0, 231.0, 37.0),
];

type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;

/// Draws a response surface: a curve over one parameter, a colour map with contours over two.
pub fn surface_png(path: &Path, surface: &Surface, size: (u32, u32)) -> Result<(), PlotError> {
    let dims = surface.parameters.len();
    if dims > 2 {
        return Err(PlotError::TooManyParameters(dims));
    }
    if dims == 0 {
        return Err(PlotError::NoParameters);
    }
    if surface.points.is_empty() {
        return Err(PlotError::NoPoints);
    }
    for (params, qoi) in &surface.points {
        if params.len() != dims {
            return Err(PlotError::DimensionMismatch { expected: dims, got: params.len() });
        }
        if !qoi.is_finite() || params.iter().any(|v| !v.is_finite()) {
            return Err(PlotError::NonFinite);
        }
    }
    check_target(path, size)?;
    register_bundled_font()?;
    let root = BitMapBackend::new(path, size).into_drawing_area();
    root.fill(&WHITE)?;
    if dims == 1 {
        draw_curve(&root, surface)?
    } else {
        draw_map(&root, surface)?
    }
    root.present()?;
    Ok(())
}

/// Draws eta against the iteration for each series, on a log scale since eta falls by decades.
///
/// Non-positive and non-finite values have no place on a log scale and are skipped, and so is a tolerance
/// that is not positive and finite.
pub fn convergence_png(
    path: &Path,
    series: &[ConvergenceSeries],
    tolerance: Option<f64>,
    title: &str,
    size: (u32, u32),
) -> Result<(), PlotError> {
    let lines: Vec<Vec<(u32, f64)>> = series
        .iter()
        .map(|s| {
            s.history
                .iter()
                .enumerate()
                .filter(|(_, eta)| eta.is_finite() && **eta > 0.0)
                .map(|(k, &eta)| (k as u32 + 1, eta))
                .collect()
        })
        .collect();
    let last = lines.iter().filter_map(|l| l.last()).map(|p| p.0).max().ok_or(PlotError::NoPoints)?;
    let tolerance = tolerance.filter(|t| t.is_finite() && *t > 0.0);
    let etas = lines.iter().flatten().map(|p| p.1).chain(tolerance);
    let (lo, hi) = min_max(etas).ok_or(PlotError::NoPoints)?;
    // a factor of 2 of head room in log scale; a decade each way when there is a single value
    let (lo, hi) = if hi > lo { (lo / 2.0, hi * 2.0) } else { (lo / 10.0, hi * 10.0) };
    let x_end = last.max(2);
    check_target(path, size)?;
    register_bundled_font()?;
    let root = BitMapBackend::new(path, size).into_drawing_area();
    root.fill(&WHITE)?;
    let mut builder = ChartBuilder::on(&root);
    if !title.is_empty() {
        builder.caption(title, (FONT, 22));
    }
    let mut chart = builder
        .margin(MARGIN)
        .x_label_area_size(X_LABEL_AREA)
        .y_label_area_size(Y_LABEL_AREA)
        .build_cartesian_2d(1u32..x_end, (lo..hi).log_scale().with_key_points(log_ticks(lo, hi)))?;
    chart
        .configure_mesh()
        .x_desc("iteration")
        .y_desc("eta (error indicator)")
        .y_label_formatter(&|v| pretty_print_float(*v, true))
        .label_style((FONT, 14))
        .axis_desc_style((FONT, 16))
        .draw()?;
    if let Some(tol) = tolerance {
        let style = BLACK.mix(0.7).stroke_width(1);
        chart.draw_series(DashedLineSeries::new([(1, tol), (x_end, tol)], 8, 5, style))?;
        let label = (FONT, 14).into_font().color(&BLACK).pos(Pos::new(HPos::Right, VPos::Bottom));
        chart.draw_series(std::iter::once(Text::new("tolerance", (x_end, tol), label)))?;
    }
    let legend = series.len() <= MAX_LEGEND;
    // many thin lines stay readable where many thick ones merge into a band
    let width = if legend { 2 } else { 1 };
    for (k, (s, line)) in series.iter().zip(&lines).enumerate() {
        let colour = PALETTE[k % PALETTE.len()];
        let anno = chart.draw_series(LineSeries::new(line.iter().copied(), colour.stroke_width(width)))?;
        if legend && !line.is_empty() {
            anno.label(s.label.as_str())
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], colour.stroke_width(2)));
        }
        // a line through one point is invisible
        if line.len() == 1 {
            chart.draw_series(line.iter().map(|&p| Circle::new(p, 3, colour.filled())))?;
        }
    }
    if legend {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.3))
            .label_font((FONT, 13))
            .draw()?;
    }
    root.present()?;
    Ok(())
}

/// Fails before anything is drawn, so that a bad path or size leaves no file behind.
fn check_target(path: &Path, size: (u32, u32)) -> Result<(), PlotError> {
    // the backend picks the image format from the extension
    if !path.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")) {
        return Err(PlotError::NotPng(path.to_path_buf()));
    }
    if !(MIN_SIZE.0..=MAX_SIZE.0).contains(&size.0) || !(MIN_SIZE.1..=MAX_SIZE.1).contains(&size.1) {
        return Err(PlotError::Size(size.0, size.1));
    }
    Ok(())
}

/// With ab_glyph plotters knows no system fonts: text needs a font registered under the family it names.
fn register_bundled_font() -> Result<(), PlotError> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font(FONT, FontStyle::Normal, include_bytes!("../../assets/DejaVuSans.ttf")).is_ok()
    });
    if ok { Ok(()) } else { Err(PlotError::Draw("the bundled font DejaVuSans.ttf was rejected".into())) }
}

fn draw_curve(root: &Area, surface: &Surface) -> Result<(), PlotError> {
    let mut points: Vec<(f64, f64)> = surface.points.iter().map(|(p, q)| (p[0], *q)).collect();
    points.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (x0, x1) = with_margin(min_max(points.iter().map(|p| p.0)).ok_or(PlotError::NoPoints)?, 0.03);
    let (y0, y1) = with_margin(min_max(points.iter().map(|p| p.1)).ok_or(PlotError::NoPoints)?, 0.06);
    let mut builder = ChartBuilder::on(root);
    if !surface.title.is_empty() {
        builder.caption(&surface.title, (FONT, 22));
    }
    let mut chart = builder
        .margin(MARGIN)
        .x_label_area_size(X_LABEL_AREA)
        .y_label_area_size(Y_LABEL_AREA)
        .build_cartesian_2d(x0..x1, y0..y1)?;
    let (x_span, y_span) = (x1 - x0, y1 - y0);
    chart
        .configure_mesh()
        .x_desc(surface.parameters[0].label())
        .y_desc(surface.qoi.label())
        .x_label_formatter(&|v| tick_label(*v, x_span))
        .y_label_formatter(&|v| tick_label(*v, y_span))
        .label_style((FONT, 14))
        .axis_desc_style((FONT, 16))
        .draw()?;
    chart.draw_series(LineSeries::new(points.iter().copied(), CURVE.stroke_width(2)))?;
    chart.draw_series(points.iter().map(|&p| Circle::new(p, 4, CURVE.filled())))?;
    Ok(())
}

fn draw_map(root: &Area, surface: &Surface) -> Result<(), PlotError> {
    let points: Vec<(f64, f64, f64)> = surface.points.iter().map(|(p, q)| (p[0], p[1], *q)).collect();
    let (x0, x1) = pad_degenerate(min_max(points.iter().map(|p| p.0)).ok_or(PlotError::NoPoints)?);
    let (y0, y1) = pad_degenerate(min_max(points.iter().map(|p| p.1)).ok_or(PlotError::NoPoints)?);
    let (z0, z1) = min_max(points.iter().map(|p| p.2)).ok_or(PlotError::NoPoints)?;
    let field = match Grid::from_points(&points) {
        Some(grid) => Field::Grid(grid),
        None => Field::Scattered(Idw::new(&points, (x1 - x0, y1 - y0))),
    };
    let resampled;
    let contour_grid = match &field {
        Field::Grid(grid) => grid,
        Field::Scattered(idw) => {
            resampled = Grid::sample(|x, y| idw.value(x, y), (x0, x1), (y0, y1), RESAMPLE);
            &resampled
        }
    };
    let levels = contour_levels(z0, z1, CONTOUR_LEVELS);
    let colour = |z: f64| viridis(if z1 > z0 { (z - z0) / (z1 - z0) } else { 0.5 });

    let area = if surface.title.is_empty() { root.clone() } else { root.titled(&surface.title, (FONT, 22))? };
    let (main, bar) = area.split_horizontally(area.dim_in_pixel().0.saturating_sub(BAR_WIDTH));

    let mut chart = ChartBuilder::on(&main)
        .margin(MARGIN)
        .x_label_area_size(X_LABEL_AREA)
        .y_label_area_size(Y_LABEL_AREA)
        .build_cartesian_2d(x0..x1, y0..y1)?;
    let (x_span, y_span) = (x1 - x0, y1 - y0);
    chart
        .configure_mesh()
        .disable_mesh()
        .x_labels(7)
        .x_desc(surface.parameters[0].label())
        .y_desc(surface.parameters[1].label())
        .x_label_formatter(&|v| tick_label(*v, x_span))
        .y_label_formatter(&|v| tick_label(*v, y_span))
        .label_style((FONT, 14))
        .axis_desc_style((FONT, 16))
        .draw()?;
    // subcell edges from one formula, so that neighbours share them exactly and leave no gap
    let x_at = |i: usize| x0 + x_span * i as f64 / RASTER as f64;
    let y_at = |j: usize| y0 + y_span * j as f64 / RASTER as f64;
    chart.draw_series((0..RASTER).flat_map(|j| (0..RASTER).map(move |i| (i, j))).map(|(i, j)| {
        let (xa, xb, ya, yb) = (x_at(i), x_at(i + 1), y_at(j), y_at(j + 1));
        Rectangle::new([(xa, ya), (xb, yb)], colour(field.value(0.5 * (xa + xb), 0.5 * (ya + yb))).filled())
    }))?;
    let line = BLACK.mix(0.6).stroke_width(1);
    for &level in &levels {
        chart.draw_series(contour_grid.contour(level).into_iter().map(|[a, b]| PathElement::new([a, b], line)))?;
    }
    chart.draw_series(points.iter().map(|p| Circle::new((p.0, p.1), 3, WHITE.filled())))?;
    chart.draw_series(points.iter().map(|p| Circle::new((p.0, p.1), 3, BLACK.stroke_width(1))))?;

    // colour bar, its plot aligned with the map's
    let (b0, b1) = pad_degenerate((z0, z1));
    let mut bar_chart = ChartBuilder::on(&bar)
        .margin_top(MARGIN)
        .margin_bottom(MARGIN + X_LABEL_AREA)
        .margin_left(5)
        .margin_right(5)
        .right_y_label_area_size(BAR_WIDTH - 40)
        .build_cartesian_2d(0.0..1.0, b0..b1)?;
    let b_span = b1 - b0;
    bar_chart
        .configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .y_desc(surface.qoi.label())
        .y_label_formatter(&|v| tick_label(*v, b_span))
        .label_style((FONT, 14))
        .axis_desc_style((FONT, 16))
        .draw()?;
    const STRIPS: usize = 256;
    let z_at = |k: usize| b0 + b_span * k as f64 / STRIPS as f64;
    bar_chart.draw_series((0..STRIPS).map(|k| {
        let (za, zb) = (z_at(k), z_at(k + 1));
        Rectangle::new([(0.0, za), (1.0, zb)], colour(0.5 * (za + zb)).filled())
    }))?;
    bar_chart.draw_series(levels.iter().map(|&l| PathElement::new([(0.0, l), (1.0, l)], line)))?;
    Ok(())
}

/// The interpolant behind a colour map.
enum Field {
    Grid(Grid),
    Scattered(Idw),
}

impl Field {
    fn value(&self, x: f64, y: f64) -> f64 {
        match self {
            Field::Grid(grid) => grid.value(x, y),
            Field::Scattered(idw) => idw.value(x, y),
        }
    }
}

/// Values on the nodes of a rectangular (not necessarily uniform) grid.
#[derive(Debug, Clone)]
struct Grid {
    xs: Vec<f64>,
    ys: Vec<f64>,
    /// z[j * xs.len() + i] at (xs[i], ys[j])
    z: Vec<f64>,
}

impl Grid {
    /// The grid the points lie on when they are exactly the Cartesian product of their distinct coordinates
    /// (in any order), each once; `None` otherwise.
    fn from_points(points: &[(f64, f64, f64)]) -> Option<Grid> {
        let xs = distinct(points.iter().map(|p| p.0));
        let ys = distinct(points.iter().map(|p| p.1));
        if xs.len() * ys.len() != points.len() {
            return None;
        }
        let mut z = vec![None; points.len()];
        for &(x, y, v) in points {
            let cell = &mut z[nearest(&ys, y) * xs.len() + nearest(&xs, x)];
            if cell.is_some() {
                return None;
            }
            *cell = Some(v);
        }
        let z = z.into_iter().collect::<Option<Vec<f64>>>()?;
        Some(Grid { xs, ys, z })
    }

    /// Samples `f` on a uniform n x n grid over the given ranges.
    fn sample(f: impl Fn(f64, f64) -> f64, (x0, x1): (f64, f64), (y0, y1): (f64, f64), n: usize) -> Grid {
        let axis = |a: f64, b: f64| (0..n).map(|k| a + (b - a) * k as f64 / (n - 1) as f64).collect::<Vec<_>>();
        let (xs, ys) = (axis(x0, x1), axis(y0, y1));
        let f = &f;
        let z = ys.iter().flat_map(|&y| xs.iter().map(move |&x| f(x, y))).collect();
        Grid { xs, ys, z }
    }

    fn at(&self, i: usize, j: usize) -> f64 {
        self.z[j * self.xs.len() + i]
    }

    /// Bilinear in the cell holding (x, y); clamped to the grid outside it, constant along an axis with a
    /// single value.
    fn value(&self, x: f64, y: f64) -> f64 {
        let (i0, i1, tx) = locate(&self.xs, x);
        let (j0, j1, ty) = locate(&self.ys, y);
        (1.0 - tx) * (1.0 - ty) * self.at(i0, j0)
            + tx * (1.0 - ty) * self.at(i1, j0)
            + (1.0 - tx) * ty * self.at(i0, j1)
            + tx * ty * self.at(i1, j1)
    }

    /// Marching squares: the segments of the level line, linear along each cell edge.
    fn contour(&self, level: f64) -> Vec<[(f64, f64); 2]> {
        let mut segments = Vec::new();
        for j in 0..self.ys.len().saturating_sub(1) {
            for i in 0..self.xs.len().saturating_sub(1) {
                // corners counter-clockwise, so that edge e runs from corner e to corner e + 1
                let corners = [(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)];
                let p = corners.map(|(a, b)| (self.xs[a], self.ys[b]));
                let v = corners.map(|(a, b)| self.at(a, b));
                let above = v.map(|z| z >= level);
                let mut cross = [None; 4];
                for e in 0..4 {
                    let f = (e + 1) % 4;
                    if above[e] != above[f] {
                        let t = (level - v[e]) / (v[f] - v[e]);
                        cross[e] = Some((p[e].0 + t * (p[f].0 - p[e].0), p[e].1 + t * (p[f].1 - p[e].1)));
                    }
                }
                let edges: Vec<usize> = (0..4).filter(|&e| cross[e].is_some()).collect();
                match edges[..] {
                    [a, b] => segments.extend(pair(&cross, a, b)),
                    [_, _, _, _] => {
                        // saddle: the mean of the corners tells whether corners 0 and 2 are connected, which
                        // isolates corners 1 and 3; corner k lies between edges k - 1 and k
                        let connected = (v.iter().sum::<f64>() / 4.0 >= level) == above[0];
                        let pairs = if connected { [(0, 1), (2, 3)] } else { [(3, 0), (1, 2)] };
                        segments.extend(pairs.into_iter().filter_map(|(a, b)| pair(&cross, a, b)));
                    }
                    _ => {}
                }
            }
        }
        segments
    }
}

/// The segment between the crossings on edges a and b, unless it has shrunk to a point (a corner on the
/// level).
fn pair(cross: &[Option<(f64, f64)>; 4], a: usize, b: usize) -> Option<[(f64, f64); 2]> {
    match (cross[a], cross[b]) {
        (Some(p), Some(q)) if p != q => Some([p, q]),
        _ => None,
    }
}

/// Inverse-distance weighting (power 2), with distances in units of each parameter's range so that
/// parameters of different scales weigh alike.
struct Idw {
    points: Vec<(f64, f64, f64)>,
    scale: (f64, f64),
}

impl Idw {
    fn new(points: &[(f64, f64, f64)], scale: (f64, f64)) -> Idw {
        Idw { points: points.to_vec(), scale }
    }

    fn value(&self, x: f64, y: f64) -> f64 {
        let (mut num, mut den) = (0.0, 0.0);
        let (mut exact, mut exact_count) = (0.0, 0usize);
        for &(px, py, z) in &self.points {
            let (dx, dy) = ((x - px) / self.scale.0, (y - py) / self.scale.1);
            let d2 = dx * dx + dy * dy;
            if d2 < 1e-24 {
                exact += z;
                exact_count += 1;
            } else {
                num += z / d2;
                den += 1.0 / d2;
            }
        }
        if exact_count > 0 { exact / exact_count as f64 } else { num / den }
    }
}

/// (i, i + 1, t) with x = (1 - t) xs[i] + t xs[i + 1], t clamped to [0, 1].
fn locate(xs: &[f64], x: f64) -> (usize, usize, f64) {
    if xs.len() < 2 {
        return (0, 0, 0.0);
    }
    let i = xs.partition_point(|&a| a <= x).saturating_sub(1).min(xs.len() - 2);
    let t = ((x - xs[i]) / (xs[i + 1] - xs[i])).clamp(0.0, 1.0);
    (i, i + 1, t)
}

/// Sorted distinct values, merging those that differ by rounding only (values computed by a sweep).
fn distinct(values: impl Iterator<Item = f64>) -> Vec<f64> {
    let mut values: Vec<f64> = values.collect();
    values.sort_by(f64::total_cmp);
    let scale = match (values.first(), values.last()) {
        (Some(&lo), Some(&hi)) => (hi - lo).max(hi.abs()).max(lo.abs()),
        _ => 0.0,
    };
    let mut out: Vec<f64> = Vec::new();
    for v in values {
        if out.last().is_none_or(|&last| v - last > 1e-9 * scale) {
            out.push(v);
        }
    }
    out
}

/// Index of the value of `sorted` nearest to `x`.
fn nearest(sorted: &[f64], x: f64) -> usize {
    let k = sorted.partition_point(|&a| a < x);
    match (k.checked_sub(1), sorted.get(k)) {
        (Some(below), Some(&above)) if x - sorted[below] < above - x => below,
        (Some(below), None) => below,
        _ => k,
    }
}

fn min_max(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    values.fold(None, |acc, v| match acc {
        None => Some((v, v)),
        Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
    })
}

/// A range with some width, so that plotters can map it: a single value gets ±10 % of itself, or ±1 at zero.
fn pad_degenerate((lo, hi): (f64, f64)) -> (f64, f64) {
    if hi > lo {
        return (lo, hi);
    }
    let d = if lo != 0.0 { 0.1 * lo.abs() } else { 1.0 };
    (lo - d, hi + d)
}

/// Room around the data so that markers at the ends are not cut by the axes.
fn with_margin(range: (f64, f64), fraction: f64) -> (f64, f64) {
    let (lo, hi) = pad_degenerate(range);
    let d = fraction * (hi - lo);
    (lo - d, hi + d)
}

/// Evenly spaced levels strictly between lo and hi (none when the values are constant).
fn contour_levels(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    if hi <= lo {
        return Vec::new();
    }
    (1..=n).map(|k| lo + (hi - lo) * k as f64 / (n + 1) as f64).collect()
}

/// A tick label short enough for the label area at any scale (slips are micrometres, forces kilonewtons);
/// a tick that is zero but for rounding reads 0.
fn tick_label(v: f64, span: f64) -> String {
    if v.abs() < 1e-9 * span { "0".into() } else { pretty_print_float(v, true) }
}

/// Ticks of a log axis at round values: plotters' own ticks overlap and repeat on ranges of a decade or two.
fn log_ticks(lo: f64, hi: f64) -> Vec<f64> {
    let (first, last) = (lo.log10().floor() as i32, hi.log10().ceil() as i32);
    let ticks = |mantissas: &[f64]| -> Vec<f64> {
        (first..=last)
            // 1 / 10^-e rounds once where 10^e with e < 0 would round twice
            .map(|e| if e < 0 { 1.0 / 10f64.powi(-e) } else { 10f64.powi(e) })
            .flat_map(|decade| mantissas.iter().map(move |m| m * decade))
            .filter(|v| (lo..=hi).contains(v))
            .collect()
    };
    let decades = ticks(&[1.0]);
    if decades.len() >= 3 {
        // at most about 8 labels, every few decades over a wide range
        let step = decades.len().div_ceil(8);
        return decades.into_iter().step_by(step).collect();
    }
    let ticks_125 = ticks(&[1.0, 2.0, 5.0]);
    if ticks_125.len() >= 3 { ticks_125 } else { ticks(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]) }
}

/// Viridis at t in [0, 1], linear between the stops.
fn viridis(t: f64) -> RGBColor {
    let t = if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.0 };
    let s = t * (VIRIDIS.len() - 1) as f64;
    let k = (s.floor() as usize).min(VIRIDIS.len() - 2);
    let f = s - k as f64;
    let (a, b) = (VIRIDIS[k], VIRIDIS[k + 1]);
    let mix = |p: f64, q: f64| (p + f * (q - p)).round() as u8;
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

#[cfg(test)]
mod tests {
    //! Set GLISSADE_KEEP_PLOTS=1 to keep the pictures (the directory is printed) and look at them.

    use super::*;

    const PNG_SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', 0x0D, 0x0A, 0x1A, 0x0A];

    /// A directory of its own per test, removed at the end (also when the test fails).
    struct Scratch(PathBuf);

    impl Scratch {
        fn new(name: &str) -> Scratch {
            let dir = std::env::temp_dir().join(format!("glissade-plot-{}-{name}", std::process::id()));
            std::fs::create_dir_all(&dir).expect("scratch directory");
            Scratch(dir)
        }

        fn file(&self, name: &str) -> PathBuf {
            self.0.join(name)
        }
    }

    impl Drop for Scratch {
        fn drop(&mut self) {
            if std::env::var_os("GLISSADE_KEEP_PLOTS").is_some() {
                eprintln!("pictures kept in {}", self.0.display());
            } else {
                let _ = std::fs::remove_dir_all(&self.0);
            }
        }
    }

    fn assert_png(path: &Path, (w, h): (u32, u32)) {
        let bytes = std::fs::read(path).expect("the picture was written");
        assert!(bytes.len() > 24, "too short for a PNG: {} bytes", bytes.len());
        assert_eq!(bytes[..8], PNG_SIGNATURE, "PNG signature");
        assert_eq!(&bytes[12..16], b"IHDR");
        let be = |r: std::ops::Range<usize>| u32::from_be_bytes(bytes[r].try_into().unwrap());
        assert_eq!((be(16..20), be(20..24)), (w, h), "IHDR width and height");
    }

    fn axis(name: &str, unit: Option<&str>) -> Axis {
        Axis::new(name, unit.map(str::to_string))
    }

    fn surface2(points: Vec<(Vec<f64>, f64)>) -> Surface {
        Surface {
            parameters: vec![axis("f1", None), axis("f2", None)],
            qoi: axis("slip_A", Some("m")),
            points,
            title: "slip_A over f1, f2".into(),
        }
    }

    /// The Cartesian product of xs and ys, in an order that is not the grid's.
    fn grid_points(xs: &[f64], ys: &[f64], f: impl Fn(f64, f64) -> f64) -> Vec<(Vec<f64>, f64)> {
        let mut points: Vec<(Vec<f64>, f64)> =
            xs.iter().flat_map(|&x| ys.iter().map(move |&y| (x, y))).map(|(x, y)| (vec![x, y], f(x, y))).collect();
        points.reverse();
        points.rotate_left(1);
        points
    }

    #[test]
    fn axis_label_has_the_unit_in_brackets() {
        assert_eq!(axis("slip_A", Some("m")).label(), "slip_A [m]");
        assert_eq!(axis("f1", None).label(), "f1");
        assert_eq!(axis("f1", Some("")).label(), "f1");
    }

    #[test]
    fn curve_over_one_parameter() {
        let scratch = Scratch::new("curve");
        let path = scratch.file("curve.png");
        let surface = Surface {
            parameters: vec![axis("f1", None)],
            qoi: axis("slip_A", Some("m")),
            // unsorted on purpose, with micrometre values
            points: [0.3, 0.1, 0.2, 0.05, 0.25].iter().map(|&f: &f64| (vec![f], 1e-6 * (1.0 - f).powi(2))).collect(),
            title: "slip_A over f1".into(),
        };
        surface_png(&path, &surface, (800, 600)).unwrap();
        assert_png(&path, (800, 600));
    }

    #[test]
    fn map_over_a_full_grid() {
        let scratch = Scratch::new("grid");
        let path = scratch.file("grid.png");
        let (xs, ys) = ([0.05, 0.1, 0.15, 0.2, 0.3], [0.1, 0.2, 0.4]);
        let surface = surface2(grid_points(&xs, &ys, |x, y| (x - 0.15).powi(2) + 0.5 * x * y - y * y));
        surface_png(&path, &surface, (900, 640)).unwrap();
        assert_png(&path, (900, 640));
    }

    #[test]
    fn map_over_scattered_points() {
        let scratch = Scratch::new("scattered");
        let path = scratch.file("scattered.png");
        let points: Vec<(Vec<f64>, f64)> = [(0.1, 10.0), (0.3, 12.0), (0.25, 30.0), (0.15, 25.0), (0.2, 18.0)]
            .iter()
            .map(|&(x, y): &(f64, f64)| (vec![x, y], (x * 10.0).sin() + y / 30.0))
            .collect();
        let mut surface = surface2(points);
        surface.parameters[1] = axis("v0", Some("m/s"));
        surface_png(&path, &surface, (700, 500)).unwrap();
        assert_png(&path, (700, 500));
        // a grid with a point missing is scattered too
        let mut points = grid_points(&[0.1, 0.2, 0.3], &[1.0, 2.0], |x, y| x * y);
        points.pop();
        let path = scratch.file("incomplete-grid.png");
        surface_png(&path, &surface2(points), (700, 500)).unwrap();
        assert_png(&path, (700, 500));
    }

    #[test]
    fn map_of_a_single_point() {
        let scratch = Scratch::new("single");
        let path = scratch.file("single.png");
        surface_png(&path, &surface2(vec![(vec![0.1, 0.0], 2.5e-6)]), (640, 480)).unwrap();
        assert_png(&path, (640, 480));
    }

    #[test]
    fn map_of_a_constant() {
        let scratch = Scratch::new("constant");
        let path = scratch.file("constant.png");
        surface_png(&path, &surface2(grid_points(&[0.1, 0.2], &[0.3, 0.4, 0.5], |_, _| 0.0)), (640, 480)).unwrap();
        assert_png(&path, (640, 480));
        // a line of points: a grid one node wide
        let path = scratch.file("line.png");
        surface_png(&path, &surface2(grid_points(&[0.1, 0.2, 0.3], &[0.5], |x, _| x)), (640, 480)).unwrap();
        assert_png(&path, (640, 480));
    }

    #[test]
    fn convergence_with_tolerance() {
        let scratch = Scratch::new("convergence");
        let path = scratch.file("convergence.png");
        let series: Vec<ConvergenceSeries> = (0..4)
            .map(|k| ConvergenceSeries {
                label: format!("f1=0.{k}"),
                history: (0..30 + 5 * k).map(|i| 0.5 * (-(i as f64) / (3.0 + k as f64)).exp()).collect(),
            })
            .chain([
                ConvergenceSeries { label: "empty".into(), history: vec![] },
                ConvergenceSeries { label: "odd".into(), history: vec![0.0, f64::NAN, -1.0, 0.3, f64::INFINITY, 0.01] },
                ConvergenceSeries { label: "one".into(), history: vec![1e-3] },
            ])
            .collect();
        convergence_png(&path, &series, Some(1e-4), "convergence", (800, 500)).unwrap();
        assert_png(&path, (800, 500));
        // no legend beyond MAX_LEGEND series, a single iteration, an unusable tolerance
        let many: Vec<ConvergenceSeries> =
            (0..20).map(|k| ConvergenceSeries { label: format!("p{k}"), history: vec![1.0 + k as f64] }).collect();
        let path = scratch.file("many.png");
        convergence_png(&path, &many, Some(-1.0), "", (640, 480)).unwrap();
        assert_png(&path, (640, 480));
    }

    #[test]
    fn errors() {
        let scratch = Scratch::new("errors");
        let path = scratch.file("error.png");
        assert!(matches!(surface_png(&path, &surface2(vec![]), (640, 480)), Err(PlotError::NoPoints)));
        let mut three = surface2(vec![(vec![1.0, 2.0, 3.0], 1.0)]);
        three.parameters.push(axis("v0", None));
        let err = surface_png(&path, &three, (640, 480)).unwrap_err();
        assert!(matches!(err, PlotError::TooManyParameters(3)), "{err:?}");
        assert!(err.to_string().contains("--fix"), "{err}");
        let nan = surface2(vec![(vec![1.0, 2.0], 1.0), (vec![1.0, 3.0], f64::NAN)]);
        assert!(matches!(surface_png(&path, &nan, (640, 480)), Err(PlotError::NonFinite)));
        let inf = surface2(vec![(vec![f64::INFINITY, 2.0], 1.0)]);
        assert!(matches!(surface_png(&path, &inf, (640, 480)), Err(PlotError::NonFinite)));
        let short = surface2(vec![(vec![1.0], 1.0)]);
        assert!(matches!(
            surface_png(&path, &short, (640, 480)),
            Err(PlotError::DimensionMismatch { expected: 2, got: 1 })
        ));
        let one = surface2(vec![(vec![1.0, 2.0], 1.0)]);
        assert!(matches!(surface_png(&scratch.file("x.jpg"), &one, (640, 480)), Err(PlotError::NotPng(_))));
        assert!(matches!(surface_png(&path, &one, (100, 480)), Err(PlotError::Size(100, 480))));
        assert!(matches!(surface_png(&path, &one, (70_000, 70_000)), Err(PlotError::Size(..))));
        let nowhere = scratch.file("missing-directory").join("x.png");
        let err = surface_png(&nowhere, &one, (640, 480)).unwrap_err();
        assert!(matches!(err, PlotError::Draw(_)), "{err:?}");
        let empty = [ConvergenceSeries { label: "a".into(), history: vec![] }];
        assert!(matches!(convergence_png(&path, &empty, Some(1e-3), "t", (640, 480)), Err(PlotError::NoPoints)));
        let negative = [ConvergenceSeries { label: "a".into(), history: vec![0.0, -1.0, f64::NAN] }];
        assert!(matches!(convergence_png(&path, &negative, None, "t", (640, 480)), Err(PlotError::NoPoints)));
        assert!(matches!(convergence_png(&path, &[], None, "t", (640, 480)), Err(PlotError::NoPoints)));
        assert!(!path.exists(), "no file is written on error");
    }

    #[test]
    fn bilinear_is_exact_for_bilinear_functions() {
        let f = |x: f64, y: f64| x + y;
        let g = |x: f64, y: f64| 2.0 - 3.0 * x + 0.5 * y + 4.0 * x * y;
        let (xs, ys) = ([0.0, 0.5, 1.0], [0.0, 0.25, 1.0]);
        for h in [&f as &dyn Fn(f64, f64) -> f64, &g] {
            let points: Vec<(f64, f64, f64)> =
                grid_points(&xs, &ys, h).into_iter().map(|(p, z)| (p[0], p[1], z)).collect();
            let grid = Grid::from_points(&points).expect("a full grid");
            assert_eq!((grid.xs.len(), grid.ys.len()), (3, 3));
            for i in 0..2 {
                for j in 0..2 {
                    let (x, y) = (0.5 * (xs[i] + xs[i + 1]), 0.5 * (ys[j] + ys[j + 1]));
                    assert!((grid.value(x, y) - h(x, y)).abs() < 1e-12, "cell centre ({x}, {y})");
                }
            }
            for &(x, y) in &[(0.0, 0.0), (1.0, 1.0), (0.3, 0.9), (0.77, 0.1), (0.5, 0.25)] {
                assert!((grid.value(x, y) - h(x, y)).abs() < 1e-12, "({x}, {y})");
            }
        }
    }

    #[test]
    fn contours_of_a_plane_lie_on_the_level_line() {
        let xs = [0.0, 0.5, 1.0];
        let points: Vec<(f64, f64, f64)> =
            grid_points(&xs, &xs, |x, y| x + y).into_iter().map(|(p, z)| (p[0], p[1], z)).collect();
        let grid = Grid::from_points(&points).unwrap();
        // level 1.0 passes through grid nodes; 0.75 and 1.6 cut edges inside
        for level in [1.0, 0.75, 1.6] {
            let segments = grid.contour(level);
            assert!(!segments.is_empty(), "level {level}");
            for [a, b] in &segments {
                for p in [a, b] {
                    assert!((p.0 + p.1 - level).abs() < 1e-12, "level {level}: {p:?}");
                }
            }
            // the whole chord of the unit square, each piece once
            let length: f64 = segments.iter().map(|[a, b]| ((a.0 - b.0).powi(2) + (a.1 - b.1).powi(2)).sqrt()).sum();
            let chord = std::f64::consts::SQRT_2 * if level <= 1.0 { level } else { 2.0 - level };
            assert!((length - chord).abs() < 1e-12, "level {level}: length {length}, expected {chord}");
        }
        assert!(grid.contour(-1.0).is_empty() && grid.contour(3.0).is_empty());
    }

    #[test]
    fn saddle_gives_two_segments() {
        // f = (x - 0.5)(y - 0.5) on the unit square: a saddle in the single cell
        let grid = Grid { xs: vec![0.0, 1.0], ys: vec![0.0, 1.0], z: vec![0.25, -0.25, -0.25, 0.25] };
        for level in [0.1, -0.1, 0.0] {
            assert_eq!(grid.contour(level).len(), 2, "level {level}");
        }
    }

    #[test]
    fn grid_detection() {
        let points: Vec<(f64, f64, f64)> = grid_points(&[0.1, 0.2, 0.30000000000000004], &[1.0, 2.0], |x, y| x * y)
            .into_iter()
            .map(|(p, z)| (p[0], p[1], z))
            .collect();
        let grid = Grid::from_points(&points).expect("a grid in any order");
        assert_eq!(grid.xs.len(), 3);
        // a sweep's rounding does not break the grid
        let mut rounded = points.clone();
        rounded[0].0 += 1e-15;
        assert!(Grid::from_points(&rounded).is_some());
        let mut missing = points.clone();
        missing.pop();
        assert!(Grid::from_points(&missing).is_none());
        let mut duplicate = points.clone();
        duplicate[1] = duplicate[0];
        assert!(Grid::from_points(&duplicate).is_none());
    }

    #[test]
    fn idw_passes_through_the_points_and_stays_within_their_range() {
        let points = [(0.0, 0.0, 0.0), (1.0, 100.0, 2.0), (0.2, 70.0, 5.0)];
        let idw = Idw::new(&points, (1.0, 100.0));
        for &(x, y, z) in &points {
            assert_eq!(idw.value(x, y), z);
        }
        let two = Idw::new(&points[..2], (1.0, 100.0));
        assert!((two.value(0.5, 50.0) - 1.0).abs() < 1e-12, "midway between two points, scaled by range");
        for &(x, y) in &[(0.5, 50.0), (0.9, 10.0), (0.1, 99.0)] {
            let v = idw.value(x, y);
            assert!((0.0..=5.0).contains(&v), "{v}");
        }
    }

    #[test]
    fn viridis_runs_dark_to_light() {
        assert_eq!(viridis(0.0), RGBColor(68, 1, 84));
        assert_eq!(viridis(1.0), RGBColor(253, 231, 37));
        assert_eq!(viridis(0.5), RGBColor(38, 130, 142));
        assert_eq!(viridis(f64::NAN), viridis(0.0));
        let luminance = |c: RGBColor| 0.2126 * c.0 as f64 + 0.7152 * c.1 as f64 + 0.0722 * c.2 as f64;
        let steps: Vec<f64> = (0..=50).map(|k| luminance(viridis(k as f64 / 50.0))).collect();
        assert!(steps.windows(2).all(|w| w[1] > w[0]), "luminance increases");
    }

    #[test]
    fn levels_and_ranges() {
        assert!(contour_levels(1.0, 1.0, 9).is_empty());
        let levels = contour_levels(0.0, 1.0, 9);
        assert_eq!(levels.len(), 9);
        assert!((levels[0] - 0.1).abs() < 1e-15 && (levels[8] - 0.9).abs() < 1e-15);
        assert_eq!(pad_degenerate((0.0, 0.0)), (-1.0, 1.0));
        assert_eq!(pad_degenerate((2.0, 2.0)), (1.8, 2.2));
        assert_eq!(tick_label(1e-20, 1.0), "0");
        assert_eq!(log_ticks(0.5, 40.0), [0.5, 1.0, 2.0, 5.0, 10.0, 20.0]);
        assert_eq!(log_ticks(1.5e-3, 0.4), [2e-3, 5e-3, 1e-2, 2e-2, 5e-2, 0.1, 0.2]);
        assert_eq!(log_ticks(5e-6, 2.0).len(), 6);
        let wide = log_ticks(1e-16, 10.0);
        assert!((3..=8).contains(&wide.len()) && wide[0] == 1e-16, "{wide:?}");
        assert_eq!(log_ticks(1.5, 2.5), [2.0]);
    }
}
