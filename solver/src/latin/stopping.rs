//! The stopping test: an estimate of how far each QoI history still is from the converged one
//! (docs/method.md, "Relaxation, error indicator, stopping test").
//!
//! eta measures the gap between the two LATIN spaces over every interface and step; it says
//! little about one velocity or one slip (measured: velocity histories 40x eta, slips at 2e-4
//! still 5-500x off). So the test follows what users read. A LATIN iteration with settled
//! interface statuses is a linear contraction: each QoI's change between iterations shrinks by
//! a factor rho, and the error left is the sum of the changes to come, d rho / (1 - rho). The
//! change d is the largest of the last `WINDOW` iterations (an oscillating QoI pauses at its
//! turning points; a window longer than its half-period still sees it move) and rho compares
//! it with the largest of the window before, or the last half window with the one before it
//! when that is slower (a slow mode under a transient that dies fast).

pub use crate::model::QoiUnit;

/// Iterations per window; rho is measured over two windows.
pub const WINDOW: usize = 10;
/// Slowest contraction the estimate trusts: beyond it (or before two windows exist, or while
/// the changes grow) the remaining error is taken as RHO_MAX / (1 - RHO_MAX) = 99 times the
/// change, which only a QoI that has hardly moved for every recent iteration passes.
pub const RHO_MAX: f64 = 0.99;
/// A QoI's history norm is floored at this share of the largest norm among the QoIs of the same
/// unit and of the interface fields' scale of that unit ([`UnitScales`]): a slip that sticks
/// (1e-22 m) is measured against the displacements beside it, not against its own noise.
pub const NORM_FLOOR: f64 = glissade_core::study::QOI_FLOOR;

/// What the interface fields say a QoI history of each unit is worth, as an L2 norm over the
/// steps: the area-weighted RMS of the local-stage velocities, of the tractions times the mean
/// area of an interface side, and for lengths the larger of velocity x duration and the RMS of
/// the static (prestress) displacements held over the interval.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct UnitScales {
    pub length: f64,
    pub velocity: f64,
    pub force: f64,
}

impl UnitScales {
    /// From reduced sums: [sum a |W|^2, sum a |F|^2, sum a |U_static|^2, total area, sides].
    pub fn from_sums(sums: &[f64], steps: usize, dt: f64) -> Self {
        let area = sums[3];
        if area <= 0.0 {
            return Self::default();
        }
        let velocity = (sums[0] / area).sqrt();
        let statics = (sums[2] / area * (steps + 1) as f64).sqrt();
        Self {
            length: (velocity * steps as f64 * dt).max(statics),
            velocity,
            force: (sums[1] / area).sqrt() * area / sums[4],
        }
    }

    pub fn of(&self, unit: QoiUnit) -> f64 {
        match unit {
            QoiUnit::Length => self.length,
            QoiUnit::Velocity => self.velocity,
            QoiUnit::Force => self.force,
        }
    }
}

/// The QoI histories of a window's iterates agree before its first step (the fields there do
/// not change while it is iterated): each history's norm continues the sum of squares over those
/// steps, taken once, and its change is measured from `from` on. The sums run in the same order
/// as over the whole history, so the results are the same to the bit; over the whole interval
/// `from` is 0.
#[derive(Debug, Clone, Default)]
pub(super) struct WindowNorms {
    from: usize,
    /// per QoI, the sum of squares of its values before `from` (taken at the first update)
    before: Option<Vec<f64>>,
}

impl WindowNorms {
    pub(super) fn from_step(from: usize) -> Self {
        Self { from, before: None }
    }

    /// The values of `v` that may change between iterates (from `from` on).
    pub(super) fn changing<'v>(&self, v: &'v [f64]) -> &'v [f64] {
        &v[self.from.min(v.len())..]
    }

    /// The L2 norm of each of `series`, in `out`.
    pub(super) fn norms(&mut self, series: &[Vec<f64>], out: &mut Vec<f64>) {
        let from = self.from;
        let before = self.before.get_or_insert_with(|| {
            series.iter().map(|v| v[..from.min(v.len())].iter().fold(-0.0, |a, x| a + x * x)).collect()
        });
        out.clear();
        out.extend(
            series
                .iter()
                .zip(before.iter())
                .map(|(v, &b)| v[from.min(v.len())..].iter().fold(b, |a, x| a + x * x).sqrt()),
        );
    }

    /// Copies `series` into `to`: only from `from` on where `to` holds the same histories' rows.
    pub(super) fn copy(&self, to: &mut Option<Vec<Vec<f64>>>, series: &[Vec<f64>]) {
        match to {
            Some(rows) if rows.len() == series.len() && rows.iter().zip(series).all(|(r, s)| r.len() == s.len()) => {
                for (r, s) in rows.iter_mut().zip(series) {
                    let from = self.from.min(s.len());
                    r[from..].copy_from_slice(self.changing(s));
                }
            }
            _ => super::copy_rows(to.get_or_insert_with(Vec::new), series),
        }
    }
}

/// Follows the QoI histories of successive iterates and estimates their remaining error.
#[derive(Debug, Clone)]
pub struct ErrorEstimator {
    units: Vec<QoiUnit>,
    previous: Option<Vec<Vec<f64>>>,
    /// relative change of each QoI (or eta, when there is none) at each iteration so far
    changes: Vec<Vec<f64>>,
    /// per QoI, a norm below which its history is not measured (empty: none)
    floors: Vec<f64>,
    /// per QoI, the norm its last change was measured against
    scales: Vec<f64>,
    /// the histories' norms, and where they may change (a window's first step)
    window: WindowNorms,
    norms: Vec<f64>,
}

impl ErrorEstimator {
    /// An estimator of QoIs with these units; with none, it follows eta's sequence instead.
    pub fn new(units: Vec<QoiUnit>) -> Self {
        Self {
            units,
            previous: None,
            changes: Vec::new(),
            floors: Vec::new(),
            scales: Vec::new(),
            window: WindowNorms::default(),
            norms: Vec::new(),
        }
    }

    /// The same, for a window whose histories change from value `from` on only.
    pub fn from_step(mut self, from: usize) -> Self {
        self.window = WindowNorms::from_step(from);
        self
    }

    /// The same, measuring each QoI against at least `floors[q]` (a time window redone with the
    /// whole interval's norms, docs/method.md "Time windows").
    pub fn with_floors(mut self, floors: Vec<f64>) -> Self {
        self.floors = floors;
        self
    }

    /// Per QoI, the norm its error is relative to at the last update (empty without QoIs).
    pub fn scales(&self) -> &[f64] {
        &self.scales
    }

    /// Takes the iterate's QoI histories (`[qoi][step]`) and eta; returns the estimated relative
    /// L2 error (over time, relative to the history's norm) of the worst QoI.
    pub fn update(&mut self, series: &[Vec<f64>], scales: &UnitScales, eta: f64) -> f64 {
        if self.units.is_empty() {
            // Nothing to follow but eta, itself a distance between iterates.
            self.changes.push(vec![eta]);
            return self.estimate();
        }
        let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
        self.window.norms(series, &mut self.norms);
        let norms = &self.norms;
        let largest = |unit: QoiUnit| {
            norms.iter().zip(&self.units).filter(|(_, u)| **u == unit).map(|(n, _)| *n).fold(scales.of(unit), f64::max)
        };
        let floors = &self.floors;
        self.scales = norms
            .iter()
            .zip(&self.units)
            .enumerate()
            .map(|(q, (&n, &unit))| n.max(NORM_FLOOR * largest(unit)).max(floors.get(q).copied().unwrap_or(0.0)))
            .collect();
        if let Some(prev) = &self.previous {
            let window = &self.window;
            let change = series
                .iter()
                .zip(prev)
                .zip(self.scales.iter_mut())
                .map(|((now, before), scale)| {
                    let (changed, was) = (window.changing(now), window.changing(before));
                    let diff = changed.iter().zip(was).map(|(a, b)| (a - b) * (a - b)).sum::<f64>().sqrt();
                    if *scale == 0.0 {
                        // everything of this unit just fell to zero: measure against before
                        *scale = norm(before);
                    }
                    if diff == 0.0 { 0.0 } else { diff / *scale }
                })
                .collect();
            self.changes.push(change);
        }
        self.window.copy(&mut self.previous, series);
        self.estimate()
    }

    /// The worst QoI's estimated remaining error from the changes so far: each change of the
    /// last window decayed to today at the measured rate (the envelope of an oscillation, the
    /// change itself for a monotone contraction), times rho / (1 - rho).
    fn estimate(&self) -> f64 {
        self.errors().into_iter().fold(if self.changes.is_empty() { f64::INFINITY } else { 0.0 }, f64::max)
    }

    /// Each QoI's estimated remaining error relative to its norm ([`Self::scales`]), or eta's
    /// when there is no QoI; empty before the first change.
    pub fn errors(&self) -> Vec<f64> {
        let k = self.changes.len();
        let Some(last) = self.changes.last() else { return Vec::new() };
        let window_max = |q: usize, from: usize, to: usize| -> f64 {
            self.changes[from..to].iter().map(|c| c[q]).fold(0.0, f64::max)
        };
        (0..last.len())
            .map(|q| {
                let recent = window_max(q, k.saturating_sub(WINDOW), k);
                if recent == 0.0 {
                    return 0.0;
                }
                let rho = if k >= 2 * WINDOW {
                    let before = window_max(q, k - 2 * WINDOW, k - WINDOW);
                    let long = (recent / before).powf(1.0 / WINDOW as f64);
                    // A slow mode under a transient that dies fast (a warm start's first
                    // iterations): the two windows measure the transient's rate, the last two
                    // half windows the slow mode's. The slower one rules.
                    let half = WINDOW / 2;
                    let latest = window_max(q, k - half, k) / window_max(q, k - WINDOW, k - half);
                    let short = latest.powf(1.0 / half as f64);
                    long.max(short).min(RHO_MAX)
                } else {
                    RHO_MAX
                };
                let now = (0..WINDOW.min(k))
                    .map(|age| self.changes[k - 1 - age][q] * rho.powi(age as i32))
                    .fold(0.0, f64::max);
                now * rho / (1.0 - rho)
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A QoI converging geometrically towards `limit`: the estimate must bound the true error
    /// within a small factor once two windows exist.
    #[test]
    fn geometric_convergence_is_estimated_within_a_factor_two() {
        for rho in [0.5, 0.9, 0.97] {
            let limit = [1.0, 2.0, -1.0];
            let mut e = ErrorEstimator::new(vec![QoiUnit::Length]);
            for k in 0..200 {
                let x: Vec<f64> = limit.iter().map(|l| l + 0.3 * rho_pow(rho, k)).collect();
                let est = e.update(std::slice::from_ref(&x), &UnitScales::default(), 1.0);
                let truth = 0.3 * rho_pow(rho, k) * 3f64.sqrt() / x.iter().map(|v| v * v).sum::<f64>().sqrt();
                if k >= 2 * WINDOW && truth > 1e-12 {
                    assert!(
                        est >= 0.9 * truth && est <= 2.0 * truth,
                        "rho {rho}, k {k}: estimate {est}, error {truth}"
                    );
                }
            }
        }
    }

    /// A slow mode, small at first, under a transient that dies fast (what a warm start sees):
    /// the estimate follows the slow mode's rate once the transient is gone, instead of the
    /// average rate of two windows that span both (which under-estimated the error 15 x here).
    #[test]
    fn a_slow_mode_under_a_fast_transient_is_not_missed() {
        let mut e = ErrorEstimator::new(vec![QoiUnit::Length]);
        let (fast, slow) = (0.5f64, 0.97f64);
        let value = |k: usize| 1.0 + rho_pow(fast, k) + 1e-3 * rho_pow(slow, k);
        for k in 0..60 {
            let est = e.update(&[vec![value(k)]], &UnitScales::default(), 1.0);
            // the error left: the distance to the limit 1
            let truth = (value(k) - 1.0) / value(k);
            // from k = 30 the last two half windows see the slow mode alone (the two windows'
            // rate alone stays below the error until k = 40)
            if k >= 30 {
                assert!(est >= 0.5 * truth, "k {k}: estimate {est} under the error {truth}");
            }
        }
    }

    fn rho_pow(rho: f64, k: usize) -> f64 {
        rho.powi(k as i32)
    }

    /// An oscillation whose amplitude decays slowly is not taken as converged at a turning
    /// point: the window still holds the motion.
    #[test]
    fn a_slow_oscillation_is_not_converged_at_its_turning_points() {
        let mut e = ErrorEstimator::new(vec![QoiUnit::Length]);
        let mut smallest: f64 = f64::INFINITY;
        for k in 0..100 {
            let amplitude = 0.1 * 0.995f64.powi(k);
            let x = 1.0 + amplitude * (k as f64 * 0.3).cos();
            smallest = smallest.min(e.update(&[vec![x]], &UnitScales::default(), 1.0));
        }
        assert!(smallest > 0.1, "estimate fell to {smallest} while the QoI swings by 5 %");
    }

    /// A QoI that is zero (a stuck slip) is measured against the other lengths, not against its
    /// own vanishing norm; a QoI of another unit does not give it a floor.
    #[test]
    fn a_vanishing_qoi_is_floored_by_its_unit() {
        let mut e = ErrorEstimator::new(vec![QoiUnit::Length, QoiUnit::Length, QoiUnit::Velocity]);
        let mut last = f64::INFINITY;
        for k in 0..40 {
            let noise = 1e-24 * (k % 2) as f64;
            last = e.update(&[vec![noise], vec![1e-3; 4], vec![5.0; 4]], &UnitScales::default(), 1.0);
        }
        assert!(last < 1e-15, "a stuck slip's noise is negligible against 1e-3 m: {last}");
        let mut alone = ErrorEstimator::new(vec![QoiUnit::Length, QoiUnit::Velocity]);
        for k in 0..40 {
            last = alone.update(&[vec![1e-24 * (k % 2) as f64], vec![5.0]], &UnitScales::default(), 1.0);
        }
        assert!(last > 1.0, "with no other length, the noise is all there is: {last}");
        // ... unless the interface fields give lengths a scale
        let mut scaled = ErrorEstimator::new(vec![QoiUnit::Length]);
        let scales = UnitScales { length: 1e-5, ..UnitScales::default() };
        for k in 0..40 {
            last = scaled.update(&[vec![1e-24 * (k % 2) as f64]], &scales, 1.0);
        }
        assert!(last < 1e-12, "noise against the fields' lengths: {last}");
    }

    /// A window's estimate, which sums only the values from its first step on (those before it do
    /// not change while it is iterated), is that of the whole histories to the bit; its norms too.
    #[test]
    fn a_windows_estimate_is_that_of_the_whole_histories() {
        let from = 30;
        let iterate = |k: usize| -> Vec<Vec<f64>> {
            (0..2)
                .map(|q| {
                    (0..80)
                        .map(|n| {
                            let settled = (n as f64 * 0.21 + q as f64).sin() * 1e-3;
                            if n < from { settled } else { settled * (1.0 + 0.3 * 0.8f64.powi(k as i32)) }
                        })
                        .collect()
                })
                .collect()
        };
        let units = vec![QoiUnit::Length, QoiUnit::Velocity];
        let (mut whole, mut window) = (ErrorEstimator::new(units.clone()), ErrorEstimator::new(units).from_step(from));
        for k in 0..40 {
            let series = iterate(k);
            let (a, b) = (
                whole.update(&series, &UnitScales::default(), 1.0),
                window.update(&series, &UnitScales::default(), 1.0),
            );
            assert_eq!(a.to_bits(), b.to_bits(), "iteration {k}: {a} against {b}");
            assert_eq!(whole.scales(), window.scales());
        }
        let series = iterate(0);
        let mut norms = Vec::new();
        WindowNorms::from_step(from).norms(&series, &mut norms);
        let full: Vec<f64> = series.iter().map(|v| v.iter().map(|x| x * x).sum::<f64>().sqrt()).collect();
        assert_eq!(norms, full);
    }

    #[test]
    fn without_qois_eta_is_followed() {
        let mut e = ErrorEstimator::new(Vec::new());
        let mut est = 0.0;
        for k in 0..40 {
            est = e.update(&[], &UnitScales::default(), 0.8f64.powi(k));
        }
        let eta = 0.8f64.powi(39);
        assert!(est > eta && est < 5.0 * eta, "estimate {est}, eta {eta}");
    }
}
