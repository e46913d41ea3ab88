//! The discretisation error of one design point: the point solved on a ladder of time steps
//! (dt, dt / 2, dt / 4, ...) or, for box bodies, of meshes (h, h / 2, ...), and per QoI the
//! change between levels, the observed order and Richardson's extrapolation
//! (docs/verification.md 11). The iteration error is the tolerance's business; this is the rest
//! of the error a user reads.

use std::collections::BTreeMap;

pub use glissade_core::refine::{
    ASSUMED_ORDER, Estimate, MAX_REFINED, NOISE_PER_TOLERANCE, Refinement, check_factors, refined_scene, richardson,
};
use glissade_core::scene::Scene;
use serde::Serialize;

use crate::comm::Communicator;
use crate::run::{RunError, SolveRequest, solve_scene_on};

/// Why a ladder did not run: its factors or scenes (core), or a level's solve.
#[derive(Debug, thiserror::Error)]
pub enum RefineError {
    #[error(transparent)]
    Scene(#[from] glissade_core::refine::RefineError),
    #[error(transparent)]
    Run(#[from] RunError),
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
            let e = richardson(&finals, ratio, NOISE_PER_TOLERANCE * tolerance);
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
