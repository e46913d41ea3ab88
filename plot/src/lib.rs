//! glissade's pictures, drawn once by plotters for two backends: PNG files for the CLI
//! (`glissade surface --png`, `glissade convergence --png`, the demo) and SVG text that the web
//! page inlines. One colour map ([`colour::viridis`]), one contour routine ([`grid::Grid::contour`])
//! and one convergence plot serve both.
//!
//! A response surface is pictured as the surface, not as its points: the Gaussian process that
//! answers `glissade surface --at` ([`glissade_core::study::surrogate::QoiSurface`]), sampled on a
//! regular grid over the box where it answers ([`study::picture`]). Over two parameters: a
//! colour map of the mean with labelled contours and a second panel of the standard deviation,
//! each with its colour bar, the design points on top; over one: the mean with a band of 2
//! standard deviations and the points.
//!
//! Text (parameter, QoI and unit names, which users choose) reaches an SVG through plotters'
//! SVG backend, which escapes `<`, `>`, `&` and quotes in text and attributes (a test pins it).

mod bitmap;
pub mod colour;
mod convergence;
pub mod grid;
pub mod study;
mod surface;
mod ticks;

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::coord::Shift;
use plotters::prelude::*;

pub use convergence::ConvergenceSeries;
pub use surface::{Drawn, Field, Surface};

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
    #[error("the sampled surface does not match its axes: {0}")]
    Field(String),
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
    #[error("writing {}", .path.display())]
    Write {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

impl<E: std::error::Error + Send + Sync> From<DrawingAreaErrorKind<E>> for PlotError {
    fn from(e: DrawingAreaErrorKind<E>) -> Self {
        PlotError::Draw(e.to_string())
    }
}

/// Below this the fixed-size label areas and colour bars of two panels leave no room for the maps.
pub const MIN_SIZE: (u32, u32) = (480, 320);
/// Beyond this the bitmap (3 bytes a pixel, held in memory) gets unreasonable, and its byte count overflows
/// plotters' u32 arithmetic long before memory runs out.
pub const MAX_SIZE: (u32, u32) = (10_000, 10_000);

/// The font family every text names; registered from the bundled DejaVu Sans.
pub(crate) const FONT: &str = "sans-serif";

/// Text sizes, in plotters' units: its SVG backend writes a size s as s / 1.24 px, so that 16
/// reads 12.9 px in a browser at 100 % (issue 47: tick labels of 14 read 11.3 px). The browser
/// test of the study page checks every text at 12 px at least.
pub(crate) const TICK: u32 = 16;
/// Axis descriptions, legends and notes.
pub(crate) const DESC: u32 = 18;
/// A panel's caption.
pub(crate) const CAPTION_TEXT: u32 = 20;
/// A picture's title.
pub(crate) const TITLE: u32 = 24;

/// The series' legend of a chart, in the one style every picture uses.
pub(crate) fn draw_legend<'a, DB: DrawingBackend + 'a, CT: plotters::coord::CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
) -> Result<(), PlotError> {
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.3))
        .label_font((FONT, DESC))
        .draw()?;
    Ok(())
}

/// Draws a response surface into a PNG file.
pub fn surface_png(path: &Path, surface: &Surface, size: (u32, u32)) -> Result<Drawn, PlotError> {
    surface.check()?;
    check_target(path, size)?;
    register_bundled_font()?;
    png_file(path, size, |root| surface::draw(root, surface, surface::Raster::Fine))
}

/// An SVG document (`<svg ...>...</svg>`) and what was drawn where.
#[derive(Debug, Clone)]
pub struct Svg {
    pub text: String,
    pub drawn: Drawn,
}

/// Draws a response surface as SVG text, the same layout as the PNG: each colour map an embedded
/// PNG of a pixel per 2 of the screen's, which the browser smooths, and each map's points one path.
pub fn surface_svg(surface: &Surface, size: (u32, u32)) -> Result<Svg, PlotError> {
    surface.check()?;
    check_size(size)?;
    register_bundled_font()?;
    let mut text = String::new();
    let embedded = std::cell::RefCell::new(bitmap::Embedded::default());
    let drawn = {
        let root = SVGBackend::with_string(&mut text, size).into_drawing_area();
        let drawn = surface::draw(&root, surface, surface::Raster::Embedded(&embedded))?;
        root.present()?;
        drawn
    };
    Ok(Svg { text: bitmap::embed(&text, &embedded.into_inner())?, drawn })
}

/// Draws eta against the iteration for each series into a PNG file (log scale; the tolerance
/// as a dashed line).
pub fn convergence_png(
    path: &Path,
    series: &[ConvergenceSeries],
    tolerance: Option<f64>,
    title: &str,
    size: (u32, u32),
) -> Result<(), PlotError> {
    let lines = convergence::lines(series, usize::MAX)?;
    check_target(path, size)?;
    register_bundled_font()?;
    png_file(path, size, |root| convergence::draw(root, series, &lines, tolerance, title))
}

/// As [`convergence_png`], as SVG text, the histories drawn through at most this many points
/// together (each through 24 to 120 of its own): many histories merge into a band anyway.
const SVG_HISTORY_POINTS: usize = 2400;

/// As [`convergence_png`], as SVG text.
pub fn convergence_svg(
    series: &[ConvergenceSeries],
    tolerance: Option<f64>,
    title: &str,
    size: (u32, u32),
) -> Result<String, PlotError> {
    let lines = convergence::lines(series, (SVG_HISTORY_POINTS / series.len().max(1)).clamp(24, 120))?;
    check_size(size)?;
    register_bundled_font()?;
    let mut text = String::new();
    {
        let root = SVGBackend::with_string(&mut text, size).into_drawing_area();
        convergence::draw(&root, series, &lines, tolerance, title)?;
        root.present()?;
    }
    Ok(text)
}

/// Draws into an RGB buffer, then writes it to `path` as PNG: plotters' own file output would
/// build the `image` crate for this one call. The file is created only once the drawing succeeded.
fn png_file<T>(
    path: &Path,
    (w, h): (u32, u32),
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> Result<T, PlotError>,
) -> Result<T, PlotError> {
    // sizes are checked (at most 10_000 x 10_000): no overflow
    let mut rgb = vec![0; w as usize * h as usize * 3];
    let drawn = {
        let root = BitMapBackend::with_buffer(&mut rgb, (w, h)).into_drawing_area();
        let drawn = draw(&root)?;
        root.present()?;
        drawn
    };
    let bytes = rgb_png(&rgb, (w, h))?;
    std::fs::write(path, bytes).map_err(|source| PlotError::Write { path: path.to_path_buf(), source })?;
    Ok(drawn)
}

/// `rgb` (rows from the top, 3 bytes a pixel) encoded as a PNG file's bytes, with the settings
/// plotters' encoder (the `image` crate) used: the same files as before, half the size of png's
/// default settings.
pub fn rgb_png(rgb: &[u8], (w, h): (u32, u32)) -> Result<Vec<u8>, PlotError> {
    let mut bytes = Vec::new();
    let mut encoder = png::Encoder::new(&mut bytes, w, h);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.set_compression(png::Compression::Fast);
    encoder.set_filter(png::FilterType::Sub);
    encoder.set_adaptive_filter(png::AdaptiveFilterType::Adaptive);
    let encoded = encoder.write_header().and_then(|mut writer| {
        writer.write_image_data(rgb)?;
        writer.finish()
    });
    encoded.map_err(|e| PlotError::Draw(format!("PNG encoding: {e}")))?;
    Ok(bytes)
}

/// Fails before anything is drawn, so that a bad path or size leaves no file behind.
fn check_target(path: &Path, size: (u32, u32)) -> Result<(), PlotError> {
    // the file is PNG whatever its name: refuse a name that says otherwise
    if !path.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")) {
        return Err(PlotError::NotPng(path.to_path_buf()));
    }
    check_size(size)
}

fn check_size(size: (u32, u32)) -> Result<(), PlotError> {
    if !(MIN_SIZE.0..=MAX_SIZE.0).contains(&size.0) || !(MIN_SIZE.1..=MAX_SIZE.1).contains(&size.1) {
        return Err(PlotError::Size(size.0, size.1));
    }
    Ok(())
}

/// With ab_glyph plotters knows no system fonts: text needs a font registered under the family it
/// names (the SVG backend measures text with it too).
fn register_bundled_font() -> Result<(), PlotError> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font(FONT, FontStyle::Normal, include_bytes!("../../assets/DejaVuSans.ttf")).is_ok()
    });
    if ok { Ok(()) } else { Err(PlotError::Draw("the bundled font DejaVuSans.ttf was rejected".into())) }
}

/// Smallest and largest of `values` (None when there are none).
pub(crate) fn min_max(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    values.fold(None, |acc, v| match acc {
        None => Some((v, v)),
        Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
    })
}

/// A range with some width, so that plotters can map it: a single value gets ±10 % of itself, or ±1 at zero.
pub(crate) fn pad_degenerate((lo, hi): (f64, f64)) -> (f64, f64) {
    if hi > lo {
        return (lo, hi);
    }
    let d = if lo != 0.0 { 0.1 * lo.abs() } else { 1.0 };
    (lo - d, hi + d)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The contents of an SVG's `<text>` elements, trimmed (plotters writes them on lines of their own).
    pub(crate) fn texts(svg: &str) -> Vec<String> {
        svg.split("<text")
            .skip(1)
            .filter_map(|t| Some(t.split_once('>')?.1.split("</text>").next()?.trim().to_owned()))
            .collect()
    }

    #[test]
    fn axis_label_has_the_unit_in_brackets() {
        assert_eq!(Axis::new("slip_A", Some("m".into())).label(), "slip_A [m]");
        assert_eq!(Axis::new("f1", None).label(), "f1");
        assert_eq!(Axis::new("f1", Some(String::new())).label(), "f1");
    }

    #[test]
    fn ranges_and_labels() {
        assert_eq!(pad_degenerate((0.0, 0.0)), (-1.0, 1.0));
        assert_eq!(pad_degenerate((2.0, 2.0)), (1.8, 2.2));
        assert_eq!(min_max([3.0, -1.0, 2.0].into_iter()), Some((-1.0, 3.0)));
        assert_eq!(min_max(std::iter::empty()), None);
    }
}
