//! Round ticks and one label format per axis (issue 47: an axis read 0.01, 0.001 and 1e-4 side by
//! side): steps of 1, 2 or 5 times a power of ten, every label of an axis with the same decimals,
//! and an axis whose values are far from 1 (slips in micrometres, forces in kilonewtons) labelled
//! by mantissas, its power of ten said once beside it.

use plotters::coord::ranged1d::{DefaultFormatting, KeyPointHint, Ranged};
use plotters::coord::types::RangedCoordf64;

/// The ticks of one axis and how its labels are written.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Ticks {
    /// Round values within the range, increasing.
    pub values: Vec<f64>,
    /// Every label's decimals (of the mantissa when `exponent` is not 0).
    decimals: usize,
    /// The axis's power of ten: labels are value / 10^exponent.
    exponent: i32,
    step: f64,
}

/// Below 10^-2 or from 10^4 up an axis is labelled by mantissas.
const PLAIN: std::ops::Range<f64> = 1e-2..1e4;

impl Ticks {
    /// The finest round step that puts at most `max` ticks within [lo, hi] (a range without width
    /// gets its one value).
    pub fn new(lo: f64, hi: f64, max: usize) -> Ticks {
        let (lo, hi) = (lo.min(hi), lo.max(hi));
        let largest = lo.abs().max(hi.abs());
        let exponent = if largest == 0.0 || PLAIN.contains(&largest) { 0 } else { largest.log10().floor() as i32 };
        if hi <= lo || !lo.is_finite() || !hi.is_finite() {
            return Ticks { values: vec![lo], decimals: 0, exponent, step: 0.0 };
        }
        let max = max.max(2) as f64;
        // the multiples of s within the range, one that rounding puts a hair outside included
        let first = |s: f64| (lo / s - 1e-9).ceil();
        let last = |s: f64| (hi / s + 1e-9).floor();
        let mut k = (hi - lo).log10().floor() as i32 - 2;
        let (step, k) = loop {
            let found = [1.0, 2.0, 5.0].into_iter().map(|m| m * pow10(k)).find(|&s| last(s) - first(s) < max);
            match found {
                Some(step) => break (step, k),
                None => k += 1,
            }
        };
        let values = (first(step) as i64..=last(step) as i64).map(|n| (n as f64 * step).clamp(lo, hi)).collect();
        Ticks { values, decimals: (exponent - k).max(0) as usize, exponent, step }
    }

    /// The label of `v`: its mantissa with the axis's decimals; 0 for what is zero but for rounding.
    pub fn label(&self, v: f64) -> String {
        if v.abs() <= 1e-9 * self.step || v == 0.0 {
            return "0".into();
        }
        let m = v / pow10(self.exponent);
        format!("{m:.*}", self.decimals)
    }

    /// "× 1e-5" when the labels are mantissas, to be said once beside the axis.
    pub fn scale(&self) -> Option<String> {
        (self.exponent != 0).then(|| format!("× 1e{}", self.exponent))
    }

    /// `label` with its unit and, where the labels are mantissas, their scale: "slip_A [× 1e-5 m]".
    pub fn described(&self, name: &str, unit: Option<&str>) -> String {
        let unit = unit.filter(|u| !u.is_empty());
        match (self.scale(), unit) {
            (None, None) => name.to_owned(),
            (None, Some(u)) => format!("{name} [{u}]"),
            (Some(s), None) => format!("{name} [{s}]"),
            (Some(s), Some(u)) => format!("{name} [{s} {u}]"),
        }
    }
}

/// A linear axis from lo to hi with these ticks (plotters' `with_key_points` would lose the
/// formatter that `configure_mesh` asks of its axes).
#[derive(Clone)]
pub(crate) struct Ticked {
    linear: RangedCoordf64,
    ticks: Vec<f64>,
}

impl Ticks {
    /// The axis over [lo, hi] that these ticks label.
    pub fn axis(&self, lo: f64, hi: f64) -> Ticked {
        Ticked { linear: (lo..hi).into(), ticks: self.values.clone() }
    }
}

impl Ranged for Ticked {
    type FormatOption = DefaultFormatting;
    type ValueType = f64;

    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        self.linear.map(value, limit)
    }

    fn key_points<Hint: KeyPointHint>(&self, hint: Hint) -> Vec<f64> {
        let every = self.ticks.len().div_ceil(hint.max_num_points().max(1)).max(1);
        self.ticks.iter().copied().step_by(every).collect()
    }

    fn range(&self) -> std::ops::Range<f64> {
        self.linear.range()
    }
}

/// 10^k, by a division below 1 (10^-k rounds once where powi(-k) rounds twice).
fn pow10(k: i32) -> f64 {
    if k < 0 { 1.0 / 10f64.powi(-k) } else { 10f64.powi(k) }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn labels(t: &Ticks) -> Vec<String> {
        t.values.iter().map(|&v| t.label(v)).collect()
    }

    #[test]
    fn ticks_are_round_and_every_label_of_an_axis_has_the_same_decimals() {
        let t = Ticks::new(0.0, 1.0, 6);
        assert_eq!(labels(&t), ["0", "0.2", "0.4", "0.6", "0.8", "1.0"]);
        assert_eq!(t.scale(), None);
        // a friction box: 0.05 .. 0.3
        assert_eq!(labels(&Ticks::new(0.05, 0.3, 6)), ["0.05", "0.10", "0.15", "0.20", "0.25", "0.30"]);
        assert_eq!(labels(&Ticks::new(-3.0, 17.0, 6)), ["0", "5", "10", "15"]);
        assert_eq!(labels(&Ticks::new(-12.0, 3.0, 6)), ["-10", "-5", "0"]);
    }

    #[test]
    fn far_from_one_an_axis_is_labelled_by_mantissas_and_its_power_of_ten() {
        // slips in metres: 0 .. 2.6e-5
        let t = Ticks::new(0.0, 2.6e-5, 7);
        assert_eq!(labels(&t), ["0", "0.5", "1.0", "1.5", "2.0", "2.5"]);
        assert_eq!(t.scale().as_deref(), Some("× 1e-5"));
        assert_eq!(t.described("slip_A", Some("m")), "slip_A [× 1e-5 m]");
        // pressures: 2e7 .. 1e8
        let p = Ticks::new(2e7, 1e8, 6);
        assert_eq!(labels(&p), ["0.2", "0.4", "0.6", "0.8", "1.0"]);
        assert_eq!(p.described("pressure", Some("Pa")), "pressure [× 1e8 Pa]");
        assert_eq!(Ticks::new(0.1, 0.2, 6).described("f1", None), "f1");
        // a range without width: its value
        assert_eq!(Ticks::new(3.0, 3.0, 6).values, [3.0]);
        // a tick at zero but for rounding reads 0
        assert_eq!(Ticks::new(-1e-5, 1e-5, 5).label(1e-21), "0");
    }

    #[test]
    fn never_more_than_asked() {
        for (lo, hi) in [(0.0, 1.0), (0.013, 0.97), (-7.3e-6, 2.2e-5), (1.0, 1.0 + 1e-9), (2e7, 1.3e8)] {
            for max in 2..10 {
                let t = Ticks::new(lo, hi, max);
                assert!(
                    t.values.len() <= max && t.values.len() >= if max >= 5 { 2 } else { 1 },
                    "{lo} {hi} {max}: {:?}",
                    t.values
                );
                assert!(t.values.iter().all(|v| (lo - 1e-12 * hi.abs()..=hi + 1e-12 * hi.abs()).contains(v)));
            }
        }
    }
}
