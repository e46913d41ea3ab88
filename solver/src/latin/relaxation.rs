//! Relaxation of the linear stage's fields, s = mu s_new + (1 - mu) s_old (docs/method.md 3),
//! with mu lowered when the iterates oscillate.
//!
//! Where the interface law switches a node between stick and slip from one iteration to the next
//! (a high friction coefficient), the raw iteration can settle into a two-cycle: every QoI moves
//! back and forth by the same amount and eta stands still (a contraction factor of -1). With
//! mu = 0.8 the cycle survives; lowering mu damps it (mu = 0.5 takes a factor -1 to 0).

use super::stopping::{NORM_FLOOR, QoiUnit, UnitScales, WindowNorms};

/// mu is multiplied by this when the iterates oscillate...
const DECREASE: f64 = 0.75;
/// ...but not below this
const FLOOR: f64 = 0.3;
/// successive QoI changes pointing this much against each other (cosine) count as a flip
const FLIP_COSINE: f64 = -0.5;
/// flips in a row that lower mu
const FLIPS: usize = 3;

/// The relaxation coefficient of the dynamic stage and what it follows.
#[derive(Debug, Clone)]
pub struct Relaxation {
    mu: f64,
    units: Vec<QoiUnit>,
    previous: Option<Vec<Vec<f64>>>,
    last_change: Option<Vec<f64>>,
    /// this update's change (a buffer, swapped into `last_change`)
    change: Vec<f64>,
    flips: usize,
    /// the histories' norms, and where they may change (a window's first step)
    window: WindowNorms,
    norms: Vec<f64>,
}

impl Relaxation {
    pub fn new(mu: f64, units: Vec<QoiUnit>) -> Self {
        Self {
            mu,
            units,
            previous: None,
            last_change: None,
            change: Vec::new(),
            flips: 0,
            window: WindowNorms::default(),
            norms: Vec::new(),
        }
    }

    /// The same, for a window whose histories change from value `from` on only (the changes
    /// before it are zeros, which add nothing to the cosine).
    pub fn from_step(mut self, from: usize) -> Self {
        self.window = WindowNorms::from_step(from);
        self
    }

    /// The coefficient for the next relaxation.
    pub fn mu(&self) -> f64 {
        self.mu
    }

    /// Takes the iterate's QoI histories (`[qoi][step]`): when their changes between iterations
    /// flip direction `FLIPS` times in a row, mu is lowered.
    pub fn update(&mut self, series: &[Vec<f64>], scales: &UnitScales) {
        let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
        let c = &mut self.change;
        c.clear();
        let norms = &mut self.norms;
        let changed = self.previous.as_ref().is_some_and(|prev| {
            self.window.norms(series, norms);
            for (((now, before), unit), n) in series.iter().zip(prev).zip(&self.units).zip(norms.iter()) {
                // each QoI relative to its norm, a near-zero one to a floor of its unit's scale
                let scale = n.max(NORM_FLOOR * scales.of(*unit));
                if scale > 0.0 {
                    let (now, before) = (self.window.changing(now), self.window.changing(before));
                    c.extend(now.iter().zip(before).map(|(a, b)| (a - b) / scale));
                }
            }
            true
        });
        if let (true, Some(last)) = (changed, &self.last_change) {
            let c = &self.change;
            let (nc, nl) = (norm(c), norm(last));
            let cosine = if nc > 0.0 && nl > 0.0 {
                c.iter().zip(last).map(|(a, b)| a * b).sum::<f64>() / (nc * nl)
            } else {
                0.0
            };
            self.flips = if cosine < FLIP_COSINE { self.flips + 1 } else { 0 };
            if self.flips >= FLIPS && self.mu > FLOOR {
                self.mu = (self.mu * DECREASE).max(FLOOR);
                self.flips = 0;
                tracing::debug!(mu = self.mu, "iterates oscillate: relaxation lowered");
            }
        }
        if changed {
            std::mem::swap(self.last_change.get_or_insert_with(Vec::new), &mut self.change);
        } else {
            self.last_change = None;
        }
        self.window.copy(&mut self.previous, series);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scales() -> UnitScales {
        UnitScales { length: 1.0, velocity: 1.0, force: 1.0 }
    }

    #[test]
    fn a_two_cycle_lowers_mu_and_a_monotone_approach_does_not() {
        let mut r = Relaxation::new(0.8, vec![QoiUnit::Length]);
        for i in 0..20 {
            let x = 1.0 + if i % 2 == 0 { 0.1 } else { -0.1 };
            r.update(&[vec![0.0, x]], &scales());
        }
        assert!(r.mu() < 0.8 * DECREASE + 1e-12, "mu {}", r.mu());
        assert!(r.mu() >= FLOOR);

        let mut r = Relaxation::new(0.8, vec![QoiUnit::Length]);
        for i in 0..20 {
            r.update(&[vec![0.0, 1.0 + 0.5f64.powi(i)]], &scales());
        }
        assert_eq!(r.mu(), 0.8);
    }
}
