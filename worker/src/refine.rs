//! The discretisation error of one design point: the point solved on a ladder of time steps
//! (dt, dt / 2, dt / 4, ...) or, for box bodies, of meshes (h, h / 2, ...), and per QoI the
//! change between levels, the observed order and Richardson's extrapolation
//! (docs/verification.md 11). The iteration error is the tolerance's business; this is the rest
//! of the error a user reads.

use std::collections::BTreeMap;

use glissade_core::scene::Scene;
use serde::Serialize;

use crate::comm::Communicator;
use crate::run::{RunError, SolveRequest, solve_scene_on};

/// What a ladder refines.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Refinement {
    /// the time step: `steps` x factor
    Time,
    /// the mesh of every box body: `elements` x factor along each axis
    Mesh,
}

#[derive(Debug, thiserror::Error)]
pub enum RefineError {
    #[error(
        "refinement factors must be 2 or more of them, the first 1, each a constant multiple of the one before (1,2,4): got {0:?}"
    )]
    Factors(Vec<usize>),
    #[error("body '{0}' is read from a mesh file: only box bodies (size and elements) can be refined in h")]
    MeshBody(String),
    #[error("{steps} steps x {factor} is more than the {max} steps a refinement may take")]
    TooFine { steps: usize, factor: usize, max: usize },
    #[error(transparent)]
    Run(#[from] RunError),
}

/// The most time steps (or elements along an axis) a level may take: a guard on what a typo in
/// the factors would allocate.
pub const MAX_REFINED: usize = 200_000;

/// Checks a ladder's factors: the first 1, a constant ratio of at least 2.
pub fn check_factors(factors: &[usize]) -> Result<usize, RefineError> {
    let bad = || RefineError::Factors(factors.to_vec());
    if factors.len() < 2 || factors[0] != 1 || factors[1] < 2 {
        return Err(bad());
    }
    let ratio = factors[1];
    if factors.windows(2).any(|w| w[1] != w[0].saturating_mul(ratio)) {
        return Err(bad());
    }
    Ok(ratio)
}

/// The scene of one level: time steps or box elements multiplied by `factor`.
pub fn refined_scene(scene: &Scene, refinement: Refinement, factor: usize) -> Result<Scene, RefineError> {
    let mut s = scene.clone();
    let too_fine = |n: usize| RefineError::TooFine { steps: n, factor, max: MAX_REFINED };
    match refinement {
        Refinement::Time => {
            s.time.steps =
                s.time.steps.checked_mul(factor).filter(|&n| n <= MAX_REFINED).ok_or(too_fine(s.time.steps))?;
        }
        Refinement::Mesh => {
            for b in &mut s.bodies {
                let Some(elements) = b.elements.as_mut() else { return Err(RefineError::MeshBody(b.name.clone())) };
                for e in elements.iter_mut() {
                    *e = e.checked_mul(factor).filter(|&n| n <= MAX_REFINED).ok_or(too_fine(*e))?;
                }
            }
        }
    }
    Ok(s)
}

/// One level of a ladder.
#[derive(Debug, Clone, Serialize)]
pub struct Level {
    pub factor: usize,
    pub steps: usize,
    pub converged: bool,
    pub iterations: usize,
    pub tolerance: f64,
    pub wall_seconds: f64,
    /// each QoI's final value
    pub finals: BTreeMap<String, f64>,
}

/// What the ladder says of one QoI.
#[derive(Debug, Clone, Serialize)]
pub struct QoiRefinement {
    pub name: String,
    /// final value per level
    pub finals: Vec<f64>,
    /// relative L2 difference of the history between each level and the one before, at the
    /// coarser level's times
    pub history_change: Vec<f64>,
    /// p in |q_k - q_{k-1}| ~ C (h_k)^p from the last three levels; `None` from two (then the
    /// scheme's order, 2, is assumed) or when erratic
    pub observed_order: Option<f64>,
    /// Richardson's extrapolation of the final value to a zero step, `None` when erratic
    pub extrapolated: Option<f64>,
    /// estimated error of the first (the scene's own) and of the finest level's final value,
    /// relative to the largest |final| of the ladder
    pub error_first: f64,
    pub error_finest: f64,
    /// the changes between levels switch sign or fall at an order outside [0.5, 4]: something
    /// (a contact event, a slip onset) moves with the step; the estimates are then the last
    /// change, not an extrapolation
    pub erratic: bool,
    /// the last change between levels within five times the iteration tolerance: the finest step's
    /// error is below what the iterations resolve
    pub below_tolerance: bool,
}

/// A whole ladder.
#[derive(Debug, Clone, Serialize)]
pub struct Ladder {
    pub refinement: Refinement,
    pub ratio: usize,
    pub levels: Vec<Level>,
    pub qois: Vec<QoiRefinement>,
}

/// The scheme's order where two levels cannot tell (Newmark average acceleration; linear
/// elements' displacements).
const ASSUMED_ORDER: f64 = 2.0;

/// What the ladder's finals say of one QoI.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    pub order: Option<f64>,
    pub extrapolated: Option<f64>,
    pub error_first: f64,
    pub error_finest: f64,
    pub erratic: bool,
    pub below_tolerance: bool,
}

/// Order, extrapolation and error estimates of one QoI's finals over levels of ratio `ratio`; a
/// last change within `noise` (relative: five times the iteration tolerance, which bounds a history's L2 error, not its final value's) is the iterations', not
/// the step's: the finest level's error is then said to be below it, the first's to be its
/// distance to the finest.
pub fn richardson(finals: &[f64], ratio: usize, noise: f64) -> Estimate {
    let r = ratio as f64;
    let k = finals.len() - 1;
    let scale = finals.iter().fold(0.0f64, |s, x| s.max(x.abs()));
    let rel = |x: f64| if scale > 0.0 { x / scale } else { 0.0 };
    let last = finals[k] - finals[k - 1];
    if rel(last.abs()) <= noise {
        return Estimate {
            order: None,
            extrapolated: None,
            error_first: rel((finals[0] - finals[k]).abs()).max(noise),
            error_finest: noise,
            erratic: false,
            below_tolerance: true,
        };
    }
    let (order, erratic) = if k >= 2 {
        let before = finals[k - 1] - finals[k - 2];
        if last == 0.0 && before == 0.0 {
            (None, false)
        } else if last == 0.0 || before == 0.0 || last * before < 0.0 {
            (None, true)
        } else {
            let p = (before / last).abs().ln() / r.ln();
            if (0.5..=4.0).contains(&p) { (Some(p), false) } else { (None, true) }
        }
    } else {
        (None, false)
    };
    if erratic {
        // no extrapolation: the last change is the finest level's error at best
        return Estimate {
            order: None,
            extrapolated: None,
            error_first: rel((finals[0] - finals[k]).abs() + last.abs()),
            error_finest: rel(last.abs()),
            erratic: true,
            below_tolerance: false,
        };
    }
    let p = order.unwrap_or(ASSUMED_ORDER);
    let extrapolated = finals[k] + last / (r.powf(p) - 1.0);
    Estimate {
        order,
        extrapolated: Some(extrapolated),
        error_first: rel((finals[0] - extrapolated).abs()),
        error_finest: rel((finals[k] - extrapolated).abs()),
        erratic: false,
        below_tolerance: false,
    }
}

/// Solves the design point of `request` at every level of the ladder, cold, and estimates.
pub fn run_ladder(
    comm: &dyn Communicator,
    scene: &Scene,
    request: &SolveRequest,
    refinement: Refinement,
    factors: &[usize],
    mut on_level: impl FnMut(&Level),
) -> Result<Ladder, RefineError> {
    let ratio = check_factors(factors)?;
    let mut levels = Vec::with_capacity(factors.len());
    let mut histories: Vec<BTreeMap<String, Vec<f64>>> = Vec::with_capacity(factors.len());
    for &factor in factors {
        let s = refined_scene(scene, refinement, factor)?;
        let outcome = solve_scene_on(comm, &s, request, None)?;
        let summary = outcome.summary;
        let level = Level {
            factor,
            steps: summary.time_steps,
            converged: summary.converged,
            iterations: summary.iterations,
            tolerance: summary.tolerance,
            wall_seconds: summary.wall_seconds,
            finals: summary.qoi.iter().map(|(k, q)| (k.clone(), q.final_value)).collect(),
        };
        on_level(&level);
        levels.push(level);
        histories.push(summary.qoi.into_iter().map(|(k, q)| (k, q.values)).collect());
    }
    let time_ratio = if refinement == Refinement::Time { ratio } else { 1 };
    let tolerance = levels.iter().map(|l| l.tolerance).fold(0.0, f64::max);
    let qois = histories[0]
        .keys()
        .map(|name| {
            let finals: Vec<f64> = levels.iter().map(|l| l.finals[name]).collect();
            let history_change = histories
                .windows(2)
                .map(|w| {
                    let (coarse, fine) = (&w[0][name], &w[1][name]);
                    let (mut num, mut den) = (0.0, 0.0);
                    for (i, c) in coarse.iter().enumerate() {
                        let f = fine.get(i * time_ratio).copied().unwrap_or(f64::NAN);
                        num += (c - f).powi(2);
                        den += f * f;
                    }
                    if den > 0.0 { (num / den).sqrt() } else { 0.0 }
                })
                .collect();
            let e = richardson(&finals, ratio, 5.0 * tolerance);
            QoiRefinement {
                name: name.clone(),
                finals,
                history_change,
                observed_order: e.order,
                extrapolated: e.extrapolated,
                error_first: e.error_first,
                error_finest: e.error_finest,
                erratic: e.erratic,
                below_tolerance: e.below_tolerance,
            }
        })
        .collect();
    Ok(Ladder { refinement, ratio, levels, qois })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn richardson_recovers_a_second_order_sequence() {
        // q(h) = 1 + 0.3 h^2 at h = 1, 1/2, 1/4
        let finals: Vec<f64> = [1.0, 0.5, 0.25].iter().map(|h: &f64| 1.0 + 0.3 * h * h).collect();
        let e = richardson(&finals, 2, 1e-9);
        assert!(!e.erratic && !e.below_tolerance);
        assert!((e.order.unwrap() - 2.0).abs() < 1e-12, "{e:?}");
        assert!((e.extrapolated.unwrap() - 1.0).abs() < 1e-12);
        assert!((e.error_first - 0.3 / 1.3).abs() < 1e-12 && (e.error_finest - 0.3 / 16.0 / 1.3).abs() < 1e-12);
    }

    #[test]
    fn a_change_of_sign_is_erratic_unless_within_the_tolerance() {
        let e = richardson(&[1.0, 1.2, 1.1], 2, 1e-6);
        assert!(e.erratic && e.order.is_none() && e.extrapolated.is_none());
        assert!((e.error_finest - 0.1 / 1.2).abs() < 1e-12);
        let e = richardson(&[1.0, 1.0 + 1e-5, 1.0 - 1e-5], 2, 4e-4);
        assert!(!e.erratic && e.below_tolerance && e.error_finest == 4e-4, "{e:?}");
    }

    #[test]
    fn factors_are_checked() {
        assert_eq!(check_factors(&[1, 2, 4]).unwrap(), 2);
        assert_eq!(check_factors(&[1, 3]).unwrap(), 3);
        for bad in [vec![1], vec![2, 4], vec![1, 2, 3], vec![1, 1], vec![]] {
            assert!(check_factors(&bad).is_err(), "{bad:?}");
        }
    }
}
