//! Eta against the iterations of every design point, on a log scale (the paper's Figures 7 and
//! 8), with the study's tolerance as a dashed line.

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::{DESC, FONT, PlotError, TICK, TITLE, draw_legend, min_max};

/// eta per iteration of one design point.
#[derive(Debug, Clone, PartialEq)]
pub struct ConvergenceSeries {
    pub label: String,
    pub history: Vec<f64>,
}

/// The convergence legend would hide the curves beyond this many series.
const MAX_LEGEND: usize = 12;
const MARGIN: u32 = 15;
const X_LABEL_AREA: u32 = 50;
const Y_LABEL_AREA: u32 = 85;

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

/// The (iteration, eta) points of each series that a log scale can show (non-positive and
/// non-finite values have no place there), at most `most` of them a series (evenly spaced, the
/// first and the last kept: an SVG of 121 histories of 200 iterations weighed 200 kB);
/// `NoPoints` when no series has one.
pub(crate) fn lines(series: &[ConvergenceSeries], most: usize) -> Result<Vec<Vec<(u32, f64)>>, PlotError> {
    let lines: Vec<Vec<(u32, f64)>> = series
        .iter()
        .map(|s| {
            let all: Vec<(u32, f64)> = s
                .history
                .iter()
                .enumerate()
                .filter(|(_, eta)| eta.is_finite() && **eta > 0.0)
                .map(|(k, &eta)| (k as u32 + 1, eta))
                .collect();
            thinned(all, most.max(2))
        })
        .collect();
    if lines.iter().all(Vec::is_empty) {
        return Err(PlotError::NoPoints);
    }
    Ok(lines)
}

fn thinned(all: Vec<(u32, f64)>, most: usize) -> Vec<(u32, f64)> {
    if all.len() <= most {
        return all;
    }
    let last = all.len() - 1;
    (0..most).map(|k| all[(k * last).div_ceil(most - 1)]).collect()
}

/// A tolerance that is not positive and finite is not drawn.
pub(crate) fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    series: &[ConvergenceSeries],
    lines: &[Vec<(u32, f64)>],
    tolerance: Option<f64>,
    title: &str,
) -> Result<(), PlotError>
where
    DB::ErrorType: 'static,
{
    let last = lines.iter().filter_map(|l| l.last()).map(|p| p.0).max().ok_or(PlotError::NoPoints)?;
    let tolerance = tolerance.filter(|t| t.is_finite() && *t > 0.0);
    let (lo, hi) = min_max(lines.iter().flatten().map(|p| p.1).chain(tolerance)).ok_or(PlotError::NoPoints)?;
    // a factor of 2 of head room in log scale; a decade each way when there is a single value
    let (lo, hi) = if hi > lo { (lo / 2.0, hi * 2.0) } else { (lo / 10.0, hi * 10.0) };
    let x_end = last.max(2);
    root.fill(&WHITE)?;
    let mut builder = ChartBuilder::on(root);
    if !title.is_empty() {
        builder.caption(title, (FONT, TITLE));
    }
    let mut chart = builder
        .margin(MARGIN)
        .x_label_area_size(X_LABEL_AREA)
        .y_label_area_size(Y_LABEL_AREA)
        .build_cartesian_2d(1u32..x_end, (lo..hi).log_scale().with_key_points(log_ticks(lo, hi)))?;
    chart
        .configure_mesh()
        .x_desc("dynamic iteration")
        .y_desc("eta (error indicator)")
        .y_label_formatter(&|v| format!("{v:.0e}"))
        .label_style((FONT, TICK))
        .axis_desc_style((FONT, DESC))
        .draw()?;
    if let Some(tol) = tolerance {
        let style = BLACK.mix(0.7).stroke_width(1);
        chart.draw_series(DashedLineSeries::new([(1, tol), (x_end, tol)], 8, 5, style))?;
        // at the left end, where the curves are high above it and the legend is not
        let label = (FONT, DESC).into_font().color(&BLACK).pos(Pos::new(HPos::Left, VPos::Bottom));
        chart.draw_series(std::iter::once(Text::new("tolerance", (1, tol), label)))?;
    }
    let legend = series.len() <= MAX_LEGEND;
    // many thin lines stay readable where many thick ones merge into a band
    let width = if legend { 2 } else { 1 };
    for (k, (s, line)) in series.iter().zip(lines).enumerate() {
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
        draw_legend(&mut chart)?;
    }
    Ok(())
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_ticks_are_round() {
        assert_eq!(log_ticks(0.5, 40.0), [0.5, 1.0, 2.0, 5.0, 10.0, 20.0]);
        assert_eq!(log_ticks(1.5e-3, 0.4), [2e-3, 5e-3, 1e-2, 2e-2, 5e-2, 0.1, 0.2]);
        assert_eq!(log_ticks(5e-6, 2.0).len(), 6);
        let wide = log_ticks(1e-16, 10.0);
        assert!((3..=8).contains(&wide.len()) && wide[0] == 1e-16, "{wide:?}");
        assert_eq!(log_ticks(1.5, 2.5), [2.0]);
    }

    #[test]
    fn the_svg_draws_the_tolerance_line() {
        let series = [ConvergenceSeries { label: "a".into(), history: vec![1.0, 0.1, 0.01, 1e-3] }];
        let svg = crate::convergence_svg(&series, Some(2e-3), "t", (640, 400)).unwrap();
        assert!(crate::tests::texts(&svg).contains(&"tolerance".to_owned()), "{svg}");
        let without = crate::convergence_svg(&series, None, "t", (640, 400)).unwrap();
        assert!(!crate::tests::texts(&without).contains(&"tolerance".to_owned()));
        assert!(matches!(crate::convergence_svg(&[], None, "t", (640, 400)), Err(PlotError::NoPoints)));
    }

    #[test]
    fn a_long_history_is_thinned_to_its_first_last_and_evenly_spaced_points() {
        let all: Vec<(u32, f64)> = (1..=200).map(|k| (k, 1.0 / k as f64)).collect();
        let few = thinned(all.clone(), 5);
        assert_eq!(few.iter().map(|p| p.0).collect::<Vec<_>>(), [1, 51, 101, 151, 200]);
        assert_eq!(thinned(all[..4].to_vec(), 5), all[..4]);
    }
}
