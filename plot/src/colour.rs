//! The one colour map of every picture.

use plotters::style::RGBColor;

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

/// Viridis at t in [0, 1], linear between the stops (t outside is clamped, NaN is the bottom).
pub fn viridis(t: f64) -> RGBColor {
    let t = if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.0 };
    let s = t * (VIRIDIS.len() - 1) as f64;
    let k = (s.floor() as usize).min(VIRIDIS.len() - 2);
    let f = s - k as f64;
    let (a, b) = (VIRIDIS[k], VIRIDIS[k + 1]);
    let mix = |p: f64, q: f64| (p + f * (q - p)).round() as u8;
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

/// The colour of `z` on a bar from `lo` to `hi` (the middle when the bar has no width).
pub fn on_bar(z: f64, range: (f64, f64)) -> RGBColor {
    viridis(bar_position(z, range))
}

/// Where `z` lies on a bar from `lo` to `hi`, 0 to 1 (0.5 when the bar has no width): the
/// viridis parameter of [`on_bar`], and the level of an embedded map's pixel.
pub fn bar_position(z: f64, (lo, hi): (f64, f64)) -> f64 {
    if hi > lo { (z - lo) / (hi - lo) } else { 0.5 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn viridis_runs_dark_to_light() {
        assert_eq!(viridis(0.0), RGBColor(68, 1, 84));
        assert_eq!(viridis(1.0), RGBColor(253, 231, 37));
        assert_eq!(viridis(0.5), RGBColor(38, 130, 142));
        assert_eq!(viridis(f64::NAN), viridis(0.0));
        let luminance = |c: RGBColor| 0.2126 * c.0 as f64 + 0.7152 * c.1 as f64 + 0.0722 * c.2 as f64;
        let steps: Vec<f64> = (0..=50).map(|k| luminance(viridis(k as f64 / 50.0))).collect();
        assert!(steps.windows(2).all(|w| w[1] > w[0]), "luminance increases");
        assert_eq!(on_bar(3.0, (1.0, 3.0)), viridis(1.0));
        assert_eq!(on_bar(7.0, (2.0, 2.0)), viridis(0.5));
    }
}
