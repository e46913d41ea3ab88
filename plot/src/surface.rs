//! A response surface: over two parameters a colour map of the mean with labelled contours
//! beside a colour map of the standard deviation, each with its colour bar; over one the mean with
//! a band of 2 standard deviations. The design points on top, the axes over the whole box.

use plotters::coord::Shift;
use plotters::coord::ranged1d::ValueFormatter;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use std::cell::RefCell;

use crate::bitmap::{Bitmap, Embedded, MARKER_RADIUS, PLACEHOLDER};
use crate::colour::{bar_position, on_bar};
use crate::grid::{Grid, Segment, chains};
use crate::ticks::Ticks;
use crate::{Axis, CAPTION_TEXT, DESC, FONT, PlotError, TICK, TITLE, draw_legend, min_max, pad_degenerate};

/// A surface sampled on a regular grid over its box.
#[derive(Debug, Clone, PartialEq)]
pub struct Field {
    /// Node coordinates along each parameter, increasing; the first and last are the box's ends.
    pub axes: Vec<Vec<f64>>,
    /// Mean and standard deviation at the nodes, the first axis running fastest.
    pub mean: Vec<f64>,
    pub std: Vec<f64>,
    /// The QoI cannot be negative (a slip's norm): its band stops at zero, as `--at`'s does.
    pub non_negative: bool,
}

impl Field {
    /// `predict` (parameter values -> mean, standard deviation) at `nodes` evenly spaced values
    /// per parameter over `bounds`, the ends exactly (a box that refuses beyond takes them).
    pub fn sample<E>(
        bounds: &[(f64, f64)],
        nodes: usize,
        mut predict: impl FnMut(&[f64]) -> Result<(f64, f64), E>,
    ) -> Result<Field, E> {
        let nodes = nodes.max(2);
        let axes: Vec<Vec<f64>> = bounds
            .iter()
            .map(|&(lo, hi)| {
                (0..nodes)
                    .map(|k| if k + 1 == nodes { hi } else { lo + (hi - lo) * k as f64 / (nodes - 1) as f64 })
                    .collect()
            })
            .collect();
        let count: usize = axes.iter().map(Vec::len).product();
        let (mut mean, mut std) = (Vec::with_capacity(count), Vec::with_capacity(count));
        let mut x = vec![0.0; axes.len()];
        for flat in 0..count {
            let mut rest = flat;
            for (d, axis) in axes.iter().enumerate() {
                x[d] = axis[rest % axis.len()];
                rest /= axis.len();
            }
            let (m, s) = predict(&x)?;
            mean.push(m);
            std.push(s);
        }
        Ok(Field { axes, mean, std, non_negative: false })
    }

    fn bounds(&self) -> Vec<(f64, f64)> {
        self.axes.iter().map(|a| (a[0], a[a.len() - 1])).collect()
    }

    /// The values of a field over two parameters as a grid.
    fn grid(&self, values: &[f64]) -> Grid {
        Grid { xs: self.axes[0].clone(), ys: self.axes[1].clone(), z: values.to_vec() }
    }

    fn check(&self, dims: usize) -> Result<(), PlotError> {
        let wrong = |why: String| Err(PlotError::Field(why));
        if self.axes.len() != dims {
            return wrong(format!("{} axes for {dims} parameters", self.axes.len()));
        }
        if self
            .axes
            .iter()
            .any(|a| a.len() < 2 || a.windows(2).any(|w| w[1].partial_cmp(&w[0]) != Some(std::cmp::Ordering::Greater)))
        {
            return wrong("an axis has fewer than 2 nodes or does not increase".into());
        }
        let count: usize = self.axes.iter().map(Vec::len).product();
        if self.mean.len() != count || self.std.len() != count {
            return wrong(format!("{} nodes, {} means, {} deviations", count, self.mean.len(), self.std.len()));
        }
        if self.axes.iter().flatten().chain(&self.mean).chain(&self.std).any(|v| !v.is_finite()) {
            return Err(PlotError::NonFinite);
        }
        Ok(())
    }
}

/// A picture of a QoI over one or two parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct Surface {
    pub parameters: Vec<Axis>,
    pub qoi: Axis,
    pub title: String,
    /// The design points with a value: the parameters' values (in `parameters` order) and the QoI's.
    pub points: Vec<(Vec<f64>, f64)>,
    /// The fitted surface sampled over its box, or why there is none (then the points alone are
    /// drawn, with the reason).
    pub field: Result<Field, String>,
}

/// What a picture shows, in numbers: for tests, and for the web page's layer of points.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Drawn {
    /// The range of each axis (the box).
    pub axes: Vec<(f64, f64)>,
    /// The mean's colour bar (a map over two parameters).
    pub colour_range: Option<(f64, f64)>,
    /// The standard deviation's colour bar.
    pub std_range: Option<(f64, f64)>,
    /// Each contour level with its segments (parameter coordinates).
    pub contours: Vec<(f64, Vec<Segment>)>,
    /// The pixel where each point is drawn (on the mean's panel), in `Surface::points` order.
    pub markers: Vec<(i32, i32)>,
}

/// How a colour map is painted.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Raster<'a> {
    /// 200 x 200 rectangles, bilinear between the nodes: free in a bitmap.
    Fine,
    /// Each map a small PNG that the SVG embeds and the browser smooths (issue 47: a rectangle per
    /// cell weighed a megabyte a page and looked pixelated), collected here in drawing order; a
    /// placeholder rectangle marks its place.
    Embedded(&'a RefCell<Embedded>),
}

/// Ticks of a colour bar, whose interior ones are the mean's contour levels: enough to read the
/// shape, few enough to label.
const BAR_TICKS: usize = 7;
const FINE: usize = 200;
/// Screen pixels per pixel of an embedded map: the browser's smoothing hides the difference.
const EMBEDDED_PIXEL: i32 = 2;
const MARGIN: u32 = 12;
const X_LABEL_AREA: u32 = 48;
const Y_LABEL_AREA: u32 = 78;
const BAR_WIDTH: u32 = 96;
const CAPTION: u32 = 28;
/// Colour of a curve and its band.
const CURVE: RGBColor = RGBColor(31, 119, 180);

impl Surface {
    /// The checks before anything is drawn (a PNG left half-written is worse than none).
    pub(crate) fn check(&self) -> Result<(), PlotError> {
        let dims = self.parameters.len();
        if dims > 2 {
            return Err(PlotError::TooManyParameters(dims));
        }
        if dims == 0 {
            return Err(PlotError::NoParameters);
        }
        if self.points.is_empty() {
            return Err(PlotError::NoPoints);
        }
        for (params, qoi) in &self.points {
            if params.len() != dims {
                return Err(PlotError::DimensionMismatch { expected: dims, got: params.len() });
            }
            if !qoi.is_finite() || params.iter().any(|v| !v.is_finite()) {
                return Err(PlotError::NonFinite);
            }
        }
        if let Ok(field) = &self.field {
            field.check(dims)?;
        }
        Ok(())
    }

    /// The box: the sampled surface's, else the points' (with room when they do not spread).
    fn bounds(&self) -> Vec<(f64, f64)> {
        match &self.field {
            Ok(field) => field.bounds(),
            // room around the points, so that those at the ends show whole
            Err(_) => (0..self.parameters.len())
                .map(|d| {
                    let (lo, hi) = pad_degenerate(min_max(self.points.iter().map(|p| p.0[d])).unwrap_or((0.0, 0.0)));
                    (lo - 0.05 * (hi - lo), hi + 0.05 * (hi - lo))
                })
                .collect(),
        }
    }
}

type Area<DB> = DrawingArea<DB, Shift>;

pub(crate) fn draw<DB: DrawingBackend>(root: &Area<DB>, surface: &Surface, raster: Raster) -> Result<Drawn, PlotError>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let area = if surface.title.is_empty() { root.clone() } else { root.titled(&surface.title, (FONT, TITLE))? };
    let bounds = surface.bounds();
    let mut drawn = Drawn { axes: bounds.clone(), ..Drawn::default() };
    let (area, note) = match &surface.field {
        Ok(_) => (area, None),
        Err(why) => {
            let (_, h) = area.dim_in_pixel();
            let (top, bottom) = area.split_vertically(h.saturating_sub(24));
            (top, Some((bottom, format!("no surface: {why}; the points alone"))))
        }
    };
    if surface.parameters.len() == 1 {
        drawn.markers = draw_curve(&area, surface, bounds[0])?;
    } else {
        let panel = Panel { surface, boxes: (bounds[0], bounds[1]), raster };
        let unit = surface.qoi.unit.as_deref();
        match &surface.field {
            Ok(field) => {
                let (mean, std) = (field.grid(&field.mean), field.grid(&field.std));
                let colour_range = min_max(field.mean.iter().copied()).ok_or(PlotError::NoPoints)?;
                let std_range = min_max(field.std.iter().copied()).ok_or(PlotError::NoPoints)?;
                let (w, _) = area.dim_in_pixel();
                let (left, right) = area.split_horizontally(w / 2);
                let name = &surface.qoi.name;
                let (contours, markers) =
                    panel.map(&left, &format!("mean of {name}"), unit, Paint::Grid(&mean, colour_range), true)?;
                panel.map(
                    &right,
                    &format!("standard deviation of {name}"),
                    unit,
                    Paint::Grid(&std, std_range),
                    false,
                )?;
                drawn.colour_range = Some(colour_range);
                drawn.std_range = Some(std_range);
                drawn.contours = contours;
                drawn.markers = markers;
            }
            Err(_) => {
                let range = min_max(surface.points.iter().map(|p| p.1)).ok_or(PlotError::NoPoints)?;
                let (_, markers) = panel.map(&area, &surface.qoi.name, unit, Paint::Points(range), false)?;
                drawn.colour_range = Some(range);
                drawn.markers = markers;
            }
        }
    }
    if let Some((bottom, note)) = note {
        let style = (FONT, DESC).into_font().color(&BLACK).pos(Pos::new(HPos::Left, VPos::Center));
        bottom.draw(&Text::new(note, (MARGIN as i32, 12), style))?;
    }
    Ok(drawn)
}

/// What colours a map: a sampled grid, or (no surface) the points themselves.
enum Paint<'a> {
    Grid(&'a Grid, (f64, f64)),
    Points((f64, f64)),
}

impl Paint<'_> {
    fn range(&self) -> (f64, f64) {
        match self {
            Paint::Grid(_, r) | Paint::Points(r) => *r,
        }
    }
}

struct Panel<'a> {
    surface: &'a Surface,
    boxes: ((f64, f64), (f64, f64)),
    raster: Raster<'a>,
}

/// A chart's axis labels, in the one style of every picture: 14 px, the axis's power of ten in
/// its description.
fn axes_labels<'a, DB: DrawingBackend + 'a, X, Y>(
    chart: &mut ChartContext<'a, DB, Cartesian2d<X, Y>>,
    (x, x_desc): (&Ticks, String),
    (y, y_desc): (&Ticks, String),
) -> Result<(), PlotError>
where
    X: Ranged<ValueType = f64> + ValueFormatter<f64>,
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
    DB::ErrorType: 'static,
{
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .x_label_formatter(&|v| x.label(*v))
        .y_label_formatter(&|v| y.label(*v))
        .label_style((FONT, TICK))
        .axis_desc_style((FONT, DESC))
        .draw()?;
    Ok(())
}

impl Panel<'_> {
    /// A colour map over the box with its caption and colour bar, the contours at the bar's
    /// interior ticks (`contoured`) and the points; returns the contours drawn and the points' pixels.
    #[allow(clippy::type_complexity)]
    fn map<DB: DrawingBackend>(
        &self,
        area: &Area<DB>,
        caption: &str,
        unit: Option<&str>,
        paint: Paint,
        contoured: bool,
    ) -> Result<(Vec<(f64, Vec<Segment>)>, Vec<(i32, i32)>), PlotError>
    where
        DB::ErrorType: 'static,
    {
        let ((x0, x1), (y0, y1)) = (pad_degenerate(self.boxes.0), pad_degenerate(self.boxes.1));
        let range = paint.range();
        let bar_ticks = Ticks::new(range.0, range.1, BAR_TICKS);
        let (w, _) = area.dim_in_pixel();
        let (head, body) = area.split_vertically(CAPTION);
        let style = (FONT, CAPTION_TEXT).into_font().color(&BLACK).pos(Pos::new(HPos::Center, VPos::Center));
        let caption = bar_ticks.described(caption, unit);
        head.draw(&Text::new(caption, ((w.saturating_sub(BAR_WIDTH) / 2) as i32, CAPTION as i32 / 2), style))?;
        let (main, bar) = body.split_horizontally(w.saturating_sub(BAR_WIDTH));
        let (xt, yt) = (Ticks::new(x0, x1, 6), Ticks::new(y0, y1, 6));
        let (x_span, y_span) = (x1 - x0, y1 - y0);
        let mut chart = ChartBuilder::on(&main)
            .margin(MARGIN)
            .x_label_area_size(X_LABEL_AREA)
            .y_label_area_size(Y_LABEL_AREA)
            .build_cartesian_2d(xt.axis(x0, x1), yt.axis(y0, y1))?;
        let [px, py] = &self.surface.parameters[..] else { return Err(PlotError::NoParameters) };
        axes_labels(
            &mut chart,
            (&xt, xt.described(&px.name, px.unit.as_deref())),
            (&yt, yt.described(&py.name, py.unit.as_deref())),
        )?;
        let mut contours = Vec::new();
        if let Paint::Grid(grid, _) = &paint {
            self.paint(&mut chart, grid, range)?;
            let levels: Vec<f64> =
                bar_ticks.values.iter().copied().filter(|&l| contoured && l > range.0 && l < range.1).collect();
            let line = BLACK.mix(0.7).stroke_width(1);
            for (k, &level) in levels.iter().enumerate() {
                let segments = grid.contour(level);
                let tol = 1e-9 * x_span.max(y_span);
                chart.draw_series(chains(&segments, tol).into_iter().map(|c| PathElement::new(c, line)))?;
                // labelled away from the box's edges (where a label would run into the axes or
                // the colour bar), neighbouring levels on different pieces, so that close labels
                // do not overlap
                let middle = |[a, b]: &Segment| (0.5 * (a.0 + b.0), 0.5 * (a.1 + b.1));
                let inner =
                    |(x, y): (f64, f64)| (x - x0).min(x1 - x) >= 0.1 * x_span && (y - y0).min(y1 - y) >= 0.08 * y_span;
                let mut places: Vec<(f64, f64)> = segments.iter().map(middle).filter(|p| inner(*p)).collect();
                if places.is_empty() {
                    places = segments.iter().map(middle).collect();
                }
                if !places.is_empty() {
                    let at = places[(places.len() / 2 + 3 * k) % places.len()];
                    let style = (FONT, TICK).into_font().color(&BLACK).pos(Pos::new(HPos::Center, VPos::Center));
                    chart.draw_series(std::iter::once(Text::new(bar_ticks.label(level), at, style)))?;
                }
                contours.push((level, segments));
            }
        }
        let markers: Vec<(i32, i32)> =
            self.surface.points.iter().map(|p| chart.backend_coord(&(p.0[0], p.0[1]))).collect();
        match (&paint, self.raster) {
            // an SVG's markers over a map: one path of them all (bitmap.rs)
            (Paint::Grid(..), Raster::Embedded(embedded)) => embedded.borrow_mut().markers.extend(&markers),
            _ => {
                let fill = |v: f64| match paint {
                    Paint::Points(r) => on_bar(v, r),
                    Paint::Grid(..) => WHITE,
                };
                let radius = if matches!(paint, Paint::Points(_)) { 6 } else { MARKER_RADIUS as u32 };
                let at = |p: &(Vec<f64>, f64)| (p.0[0], p.0[1]);
                chart
                    .draw_series(self.surface.points.iter().map(|p| Circle::new(at(p), radius, fill(p.1).filled())))?;
                chart.draw_series(
                    self.surface.points.iter().map(|p| Circle::new(at(p), radius, BLACK.stroke_width(1))),
                )?;
            }
        }
        let levels: Vec<f64> = contours.iter().map(|c| c.0).collect();
        colour_bar(&bar, &bar_ticks, range, &levels, self.raster)?;
        Ok((contours, markers))
    }

    /// The map's colours over the box: bilinear between the grid's nodes.
    fn paint<DB: DrawingBackend, X, Y>(
        &self,
        chart: &mut ChartContext<DB, Cartesian2d<X, Y>>,
        grid: &Grid,
        range: (f64, f64),
    ) -> Result<(), PlotError>
    where
        X: Ranged<ValueType = f64>,
        Y: Ranged<ValueType = f64>,
        DB::ErrorType: 'static,
    {
        let ((x0, x1), (y0, y1)) = (pad_degenerate(self.boxes.0), pad_degenerate(self.boxes.1));
        let (x_span, y_span) = (x1 - x0, y1 - y0);
        match self.raster {
            Raster::Fine => {
                // rectangle edges from one formula, so that neighbours share them exactly and leave no gap
                let x_at = |i: usize| x0 + x_span * i as f64 / FINE as f64;
                let y_at = |j: usize| y0 + y_span * j as f64 / FINE as f64;
                chart.draw_series((0..FINE).flat_map(|j| (0..FINE).map(move |i| (i, j))).map(|(i, j)| {
                    let (xa, xb, ya, yb) = (x_at(i), x_at(i + 1), y_at(j), y_at(j + 1));
                    let z = grid.value(0.5 * (xa + xb), 0.5 * (ya + yb));
                    Rectangle::new([(xa, ya), (xb, yb)], on_bar(z, range).filled())
                }))?;
            }
            Raster::Embedded(bitmaps) => {
                let ((left, top), (right, bottom)) = (chart.backend_coord(&(x0, y1)), chart.backend_coord(&(x1, y0)));
                let (w, h) = ((right - left) / EMBEDDED_PIXEL, (bottom - top) / EMBEDDED_PIXEL);
                // each pixel the colour at its centre; rows from the top, as an image's
                bitmaps.borrow_mut().bitmaps.push(Bitmap::paint(w.max(1) as u32, h.max(1) as u32, |u, v| {
                    bar_position(grid.value(x0 + u * x_span, y1 - v * y_span), range)
                }));
                chart.draw_series(std::iter::once(Rectangle::new([(x0, y0), (x1, y1)], PLACEHOLDER.filled())))?;
            }
        }
        Ok(())
    }
}

/// A colour bar from `range`'s low end to its high end, ticked as `ticks` says, its levels
/// marked; its plot aligned with the map's (the same margins). Its scale and unit are in the
/// panel's caption, so that nothing is written beside it, where the next panel's labels begin.
fn colour_bar<DB: DrawingBackend>(
    bar: &Area<DB>,
    ticks: &Ticks,
    range: (f64, f64),
    levels: &[f64],
    raster: Raster,
) -> Result<(), PlotError>
where
    DB::ErrorType: 'static,
{
    let (b0, b1) = pad_degenerate(range);
    let mut chart = ChartBuilder::on(bar)
        .margin_top(MARGIN)
        .margin_bottom(MARGIN + X_LABEL_AREA)
        .margin_left(4)
        .margin_right(4)
        .right_y_label_area_size(BAR_WIDTH - 36)
        .build_cartesian_2d(0.0..1.0, ticks.axis(b0, b1))?;
    let span = b1 - b0;
    match raster {
        Raster::Fine => {
            const STRIPS: usize = 256;
            let z_at = |k: usize| b0 + span * k as f64 / STRIPS as f64;
            chart.draw_series((0..STRIPS).map(|k| {
                let (za, zb) = (z_at(k), z_at(k + 1));
                Rectangle::new([(0.0, za), (1.0, zb)], on_bar(0.5 * (za + zb), range).filled())
            }))?;
        }
        Raster::Embedded(bitmaps) => {
            bitmaps.borrow_mut().bitmaps.push(Bitmap::paint(1, 128, |_, v| bar_position(b1 - v * span, range)));
            chart.draw_series(std::iter::once(Rectangle::new([(0.0, b0), (1.0, b1)], PLACEHOLDER.filled())))?;
        }
    }
    // the ticks after the colours, which would hide their marks; the labels clear of the marks
    chart
        .configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .y_label_formatter(&|v| ticks.label(*v))
        .label_style((FONT, TICK))
        .set_tick_mark_size(LabelAreaPosition::Right, 6)
        .draw()?;
    let line = BLACK.mix(0.7).stroke_width(1);
    chart.draw_series(levels.iter().map(|&l| PathElement::new([(0.0, l), (1.0, l)], line)))?;
    Ok(())
}

/// The mean with a band of 2 standard deviations over the box (or, without a surface, the
/// points joined), the points on top; returns the points' pixels. A norm's band stops at zero.
fn draw_curve<DB: DrawingBackend>(
    area: &Area<DB>,
    surface: &Surface,
    (x0, x1): (f64, f64),
) -> Result<Vec<(i32, i32)>, PlotError>
where
    DB::ErrorType: 'static,
{
    let (x0, x1) = pad_degenerate((x0, x1));
    let band = |f: &Field| -> Vec<(f64, f64, f64)> {
        let floor = if f.non_negative { 0.0 } else { f64::NEG_INFINITY };
        let at = f.axes[0].iter().zip(f.mean.iter().zip(&f.std));
        at.map(|(&x, (m, s))| (x, (m - 2.0 * s).max(floor), m + 2.0 * s)).collect()
    };
    let values = surface.points.iter().map(|p| p.1);
    let (y0, y1) = match &surface.field {
        Ok(f) => min_max(values.chain(band(f).into_iter().flat_map(|(_, lo, hi)| [lo, hi]))),
        Err(_) => min_max(values),
    }
    .ok_or(PlotError::NoPoints)?;
    let (y0, y1) = pad_degenerate((y0, y1));
    let (y0, y1) = (y0 - 0.05 * (y1 - y0), y1 + 0.05 * (y1 - y0));
    let (xt, yt) = (Ticks::new(x0, x1, 8), Ticks::new(y0, y1, 7));
    let mut chart = ChartBuilder::on(area)
        .margin(MARGIN)
        .x_label_area_size(X_LABEL_AREA)
        .y_label_area_size(Y_LABEL_AREA)
        .build_cartesian_2d(xt.axis(x0, x1), yt.axis(y0, y1))?;
    let (px, qoi) = (&surface.parameters[0], &surface.qoi);
    axes_labels(
        &mut chart,
        (&xt, xt.described(&px.name, px.unit.as_deref())),
        (&yt, yt.described(&qoi.name, qoi.unit.as_deref())),
    )?;
    match &surface.field {
        Ok(f) => {
            let band = band(f);
            let outline: Vec<(f64, f64)> =
                band.iter().map(|b| (b.0, b.2)).chain(band.iter().rev().map(|b| (b.0, b.1))).collect();
            chart
                .draw_series(std::iter::once(Polygon::new(outline, CURVE.mix(0.2).filled())))?
                .label("mean ± 2 sd")
                .legend(|(x, y)| Rectangle::new([(x, y - 5), (x + 20, y + 5)], CURVE.mix(0.2).filled()));
            let xs = &f.axes[0];
            chart
                .draw_series(LineSeries::new(xs.iter().copied().zip(f.mean.iter().copied()), CURVE.stroke_width(2)))?
                .label("mean")
                .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], CURVE.stroke_width(2)));
        }
        Err(_) => {
            let mut sorted: Vec<(f64, f64)> = surface.points.iter().map(|(p, q)| (p[0], *q)).collect();
            sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
            chart.draw_series(LineSeries::new(sorted, CURVE.stroke_width(1)))?;
        }
    }
    chart
        .draw_series(surface.points.iter().map(|p| Circle::new((p.0[0], p.1), 4, BLACK.filled())))?
        .label("design points")
        .legend(|(x, y)| Circle::new((x + 10, y), 4, BLACK.filled()));
    draw_legend(&mut chart)?;
    Ok(surface.points.iter().map(|p| chart.backend_coord(&(p.0[0], p.1))).collect())
}

#[cfg(test)]
mod tests {
    //! Set GLISSADE_KEEP_PLOTS=1 to keep the PNGs (the directory is printed) and look at them.

    use super::*;
    use crate::tests::texts;
    use crate::{surface_png, surface_svg};
    use std::path::{Path, PathBuf};

    /// `f` sampled over [0, 1] x [0, 2] with a standard deviation growing away from (0.5, 1),
    /// and two points well inside the box.
    fn surface(f: impl Fn(f64, f64) -> f64) -> Surface {
        let field = Field::sample(&[(0.0, 1.0), (0.0, 2.0)], 21, |x| {
            Ok::<_, ()>((f(x[0], x[1]), 0.1 * ((x[0] - 0.5).powi(2) + (x[1] - 1.0).powi(2))))
        })
        .unwrap();
        Surface {
            parameters: vec![Axis::new("f1", None), Axis::new("v0", Some("m/s".into()))],
            qoi: Axis::new("slip_A", Some("m".into())),
            title: "slip_A over f1, v0".into(),
            points: vec![(vec![0.3, 0.6], f(0.3, 0.6)), (vec![0.6, 1.1], f(0.6, 1.1))],
            field: Ok(field),
        }
    }

    /// The numbers among the SVG's texts.
    fn numbers(svg: &str) -> Vec<f64> {
        texts(svg).iter().filter_map(|t| t.parse().ok()).collect()
    }

    #[test]
    fn the_axes_cover_the_box_not_the_points() {
        let s = surface(|a, b| a + b);
        let svg = surface_svg(&s, (1000, 420)).unwrap();
        if std::env::var_os("GLISSADE_DUMP_SVG").is_some() {
            std::fs::write("/tmp/dump.svg", &svg.text).unwrap();
        }
        let ticks = numbers(&svg.text);
        // the ends of both axes are labelled, although the points lie within [0.3, 0.6] x [0.6, 1.1]
        for end in [0.0, 1.0, 2.0] {
            assert!(ticks.contains(&end), "tick {end} in {ticks:?}");
        }
        assert_eq!(svg.drawn.axes, vec![(0.0, 1.0), (0.0, 2.0)]);
        for text in ["f1", "v0 [m/s]", "mean of slip_A [m]", "standard deviation of slip_A [m]"] {
            assert!(texts(&svg.text).iter().any(|t| t == text), "`{text}` in {:?}", texts(&svg.text));
        }
    }

    #[test]
    fn the_colour_bars_span_the_sampled_surface() {
        let s = surface(|a, b| (3.0 * a).cos() * b);
        let svg = surface_svg(&s, (1000, 420)).unwrap();
        let field = s.field.as_ref().unwrap();
        assert_eq!(svg.drawn.colour_range, min_max(field.mean.iter().copied()));
        assert_eq!(svg.drawn.std_range, min_max(field.std.iter().copied()));
        let (lo, hi) = svg.drawn.colour_range.unwrap();
        assert!(lo < -1.9 && hi > 1.9, "the surface's range, not the two points' ({lo}, {hi})");
        // each map and each bar an embedded image, in place of its placeholder
        assert_eq!(svg.text.matches("<image").count(), 4);
        assert!(!svg.text.contains("#010203"));
    }

    #[test]
    fn contours_lie_where_the_surface_takes_their_level_and_reach_the_box() {
        // v = a: every level line is straight across the box at a = level, from b = 0 to b = 2
        let svg = surface_svg(&surface(|a, _| a), (1000, 420)).unwrap();
        // at the colour bar's round interior ticks, each labelled as the bar labels it
        let bar = Ticks::new(0.0, 1.0, BAR_TICKS);
        let levels: Vec<f64> = svg.drawn.contours.iter().map(|c| c.0).collect();
        assert_eq!(levels, bar.values[1..bar.values.len() - 1], "{:?}", bar.values);
        for (level, segments) in &svg.drawn.contours {
            assert!(!segments.is_empty(), "level {level}");
            for p in segments.iter().flatten() {
                assert!((p.0 - level).abs() < 1e-12, "level {level}: {p:?}");
            }
            let (lo, hi) = min_max(segments.iter().flatten().map(|p| p.1)).unwrap();
            assert_eq!((lo, hi), (0.0, 2.0), "level {level} from edge to edge");
            // labelled
            let label = bar.label(*level);
            assert!(texts(&svg.text).contains(&label), "{label}");
        }
        // a constant surface has none
        assert!(surface_svg(&surface(|_, _| 2.0), (1000, 420)).unwrap().drawn.contours.iter().all(|c| c.1.is_empty()));
    }

    #[test]
    fn the_points_are_drawn_on_the_mean_panel() {
        let svg = surface_svg(&surface(|a, b| a * b), (1000, 420)).unwrap();
        assert_eq!(svg.drawn.markers.len(), 2);
        let [(x0, y0), (x1, y1)] = [svg.drawn.markers[0], svg.drawn.markers[1]];
        assert!(x0 < x1 && y0 > y1, "the second point right of and above the first");
        assert!(x1 < 500, "on the left panel: {x1}");
    }

    #[test]
    fn hostile_names_are_escaped_in_the_svg() {
        let mut s = surface(|a, b| a + b);
        s.qoi = Axis::new("<script>alert(1)</script>", Some("\"&'".into()));
        s.parameters[0] = Axis::new("<img src=x onerror=alert(2)>", None);
        s.title = "</svg><script>alert(3)</script>".into();
        let svg = surface_svg(&s, (1000, 420)).unwrap().text;
        assert!(!svg.contains("<script") && !svg.contains("<img") && !svg.contains("</svg><"), "{svg}");
        assert!(svg.contains("&lt;script&gt;alert(1)&lt;/script&gt;"));
        assert!(svg.contains("&quot;&amp;&apos;"));
        assert!(!svg.contains("style="), "no inline style: the page's CSP forbids it");
    }

    #[test]
    fn one_parameter_draws_the_mean_with_its_band() {
        let field = Field::sample(&[(0.0, 1.0)], 51, |x| Ok::<_, ()>((x[0] * x[0], 0.05))).unwrap();
        let s = Surface {
            parameters: vec![Axis::new("f1", None)],
            qoi: Axis::new("slip_A", Some("m".into())),
            title: String::new(),
            points: vec![(vec![0.2], 0.04), (vec![0.5], 0.25)],
            field: Ok(field),
        };
        let svg = surface_svg(&s, (800, 500)).unwrap();
        assert!(texts(&svg.text).iter().any(|t| t == "mean ± 2 sd"), "{:?}", texts(&svg.text));
        assert!(svg.text.contains("<polygon"), "the band");
        assert!(numbers(&svg.text).contains(&1.0), "the box's end");
        assert_eq!(svg.drawn.markers.len(), 2);
    }

    #[test]
    fn without_a_surface_the_points_are_drawn_with_the_reason() {
        let mut s = surface(|a, b| a + b);
        s.field = Err("a surface needs at least 2 points, got 1".into());
        s.points.truncate(1);
        let svg = surface_svg(&s, (800, 500)).unwrap();
        assert!(svg.text.contains("no surface: a surface needs at least 2 points"), "{}", svg.text);
        assert_eq!(svg.drawn.std_range, None);
        assert_eq!(svg.drawn.markers.len(), 1);
    }

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
        const PNG_SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', 0x0D, 0x0A, 0x1A, 0x0A];
        let bytes = std::fs::read(path).expect("the picture was written");
        assert!(bytes.len() > 24, "too short for a PNG: {} bytes", bytes.len());
        assert_eq!(bytes[..8], PNG_SIGNATURE, "PNG signature");
        assert_eq!(&bytes[12..16], b"IHDR");
        let be = |r: std::ops::Range<usize>| u32::from_be_bytes(bytes[r].try_into().unwrap());
        assert_eq!((be(16..20), be(20..24)), (w, h), "IHDR width and height");
    }

    #[test]
    fn pngs_of_a_map_a_curve_and_points_alone() {
        let scratch = Scratch::new("surfaces");
        let map = scratch.file("map.png");
        let drawn = surface_png(&map, &surface(|a, b| (4.0 * a).sin() + b * b), (1200, 520)).unwrap();
        assert_png(&map, (1200, 520));
        assert!(drawn.std_range.is_some());
        let mut alone = surface(|a, b| a + b);
        alone.field = Err("too few points".into());
        let path = scratch.file("alone.png");
        surface_png(&path, &alone, (640, 480)).unwrap();
        assert_png(&path, (640, 480));
        alone.parameters.pop();
        alone.points.iter_mut().for_each(|p| p.0.pop().map(|_| ()).unwrap_or(()));
        let path = scratch.file("curve.png");
        surface_png(&path, &alone, (640, 480)).unwrap();
        assert_png(&path, (640, 480));
    }

    #[test]
    fn a_convergence_png_decodes_to_what_was_drawn() {
        let scratch = Scratch::new("convergence");
        let path = scratch.file("eta.PNG");
        let series = [crate::ConvergenceSeries { label: "a".into(), history: vec![1.0, 0.1, 0.01, 1e-3] }];
        crate::convergence_png(&path, &series, Some(2e-3), "t", (640, 400)).unwrap();
        let mut reader = png::Decoder::new(std::fs::File::open(&path).unwrap()).read_info().unwrap();
        let mut rgb = vec![0; reader.output_buffer_size()];
        let info = reader.next_frame(&mut rgb).unwrap();
        assert_eq!((info.width, info.height, info.color_type), (640, 400, png::ColorType::Rgb));
        assert_eq!(rgb[..3], [255, 255, 255], "a white background");
        assert!(rgb.chunks(3).any(|p| p != [255, 255, 255]), "something drawn on it");
    }

    #[test]
    fn errors() {
        let scratch = Scratch::new("errors");
        let path = scratch.file("error.png");
        let mut s = surface(|a, b| a + b);
        let size = (640, 480);
        s.points.clear();
        assert!(matches!(surface_png(&path, &s, size), Err(PlotError::NoPoints)));
        let mut three = surface(|a, b| a + b);
        three.parameters.push(Axis::new("v1", None));
        let err = surface_png(&path, &three, size).unwrap_err();
        assert!(matches!(err, PlotError::TooManyParameters(3)) && err.to_string().contains("--fix"), "{err}");
        let mut nan = surface(|a, b| a + b);
        nan.points[1].1 = f64::NAN;
        assert!(matches!(surface_png(&path, &nan, size), Err(PlotError::NonFinite)));
        let mut short = surface(|a, b| a + b);
        short.points[0].0.pop();
        assert!(matches!(surface_png(&path, &short, size), Err(PlotError::DimensionMismatch { expected: 2, got: 1 })));
        let mut torn = surface(|a, b| a + b);
        torn.field.as_mut().unwrap().std.pop();
        assert!(matches!(surface_png(&path, &torn, size), Err(PlotError::Field(_))));
        let mut inf = surface(|a, b| a + b);
        inf.field.as_mut().unwrap().mean[3] = f64::INFINITY;
        assert!(matches!(surface_png(&path, &inf, size), Err(PlotError::NonFinite)));
        let one = surface(|a, b| a + b);
        assert!(matches!(surface_png(&scratch.file("x.jpg"), &one, size), Err(PlotError::NotPng(_))));
        assert!(matches!(surface_png(&path, &one, (100, 480)), Err(PlotError::Size(100, 480))));
        assert!(matches!(surface_png(&path, &one, (70_000, 70_000)), Err(PlotError::Size(..))));
        let nowhere = scratch.file("missing-directory").join("x.png");
        let err = surface_png(&nowhere, &one, size).unwrap_err();
        assert!(matches!(&err, PlotError::Write { path, .. } if *path == nowhere), "{err:?}");
        assert_eq!(err.to_string(), format!("writing {}", nowhere.display()));
        assert!(!path.exists(), "no file is written on error");
    }

    #[test]
    fn sampling_takes_the_boxs_ends_exactly() {
        let f = Field::sample(&[(0.1, 0.3), (-1.0, 7.0)], 7, |x| Ok::<_, ()>((x[0], x[1]))).unwrap();
        assert_eq!(f.axes[0][6], 0.3);
        assert_eq!(f.axes[1][0], -1.0);
        assert_eq!(f.mean.len(), 49);
        // the first axis runs fastest
        assert_eq!((f.mean[1], f.std[1]), (f.axes[0][1], -1.0));
        assert_eq!(f.std[7], f.axes[1][1]);
        assert_eq!(Field::sample(&[(0.0, 1.0)], 5, |_| Err::<(f64, f64), _>("no")), Err("no"));
    }
}
