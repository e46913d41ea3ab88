//! One design point solved to an asked accuracy (`--accuracy`, docs/accuracy.md, "Ask for an
//! accuracy"): the iteration tolerance set from the accuracy, then the levels that
//! `glissade_core::accuracy::next_step` asks for (for box bodies, dt and h halved in turn) solved
//! one after the other until each ladder says its error is within its share. The answer is the
//! finest level solved; per QoI its estimated error, split into time step, mesh and iterations. When the
//! changes between levels do not fall within the largest factor allowed, the answer is the
//! finest level and the report says the accuracy was not reached, with the ladder as evidence.

use std::collections::BTreeMap;

use glissade_core::point::DesignPoint;
use glissade_core::refine::{Accuracy, Refinement};
use glissade_core::scene::{Scene, Tolerance};
use serde::Serialize;

pub use glissade_core::accuracy::{
    AccuracyLevel, AccuracyLimits, AccuracyReport, CONTACT_GAMMA, CheapestLevel, LadderError, LevelSolved, LimitError,
    MIN_LEVELS, QoiAccuracy, RATIO, Step, ZERO_SHARE, accuracy_scene, level_after_above, next_step, scene_at,
    spread_order, study_level,
};

use crate::comm::Communicator;
use crate::refine::RefineError;
use crate::run::{SolveOutcome, SolveRequest, solve_scene_on};

/// Solves `request`'s design point of `scene` to `accuracy` (module doc): the levels
/// [`next_step`] asks for, one after the other. `on_level` sees every level as it is solved,
/// for progress. Returns the report and the answer's solve (the finest level).
pub fn solve_to_accuracy(
    comm: &dyn Communicator,
    scene: &Scene,
    request: &SolveRequest,
    accuracy: Accuracy,
    limits: AccuracyLimits,
    mut on_level: impl FnMut(&AccuracyLevel),
) -> Result<(AccuracyReport, SolveOutcome), RefineError> {
    let request = SolveRequest {
        tolerance: Some(
            Tolerance::new("the accuracy's tolerance", accuracy.tolerance()).map_err(crate::run::RunError::from)?,
        ),
        init_parameters: None,
        ..request.clone()
    };
    let mut solved = Vec::new();
    // the finest solve so far on both axes: the answer (the check at dt x 2 on the answer's
    // mesh is coarser in time, so it never replaces it)
    let mut answer: Option<SolveOutcome> = None;
    loop {
        match next_step(scene, accuracy, limits, &solved) {
            Step::Solve { refinement, time_factor, mesh_factor } => {
                let s = scene_at(scene, time_factor, mesh_factor)?;
                let outcome = solve_scene_on(comm, &s, &request, None)?;
                let level = level_solved(refinement, &outcome, time_factor, mesh_factor);
                on_level(&level.level);
                solved.push(level);
                let finer = answer.as_ref().is_none_or(|a| {
                    let at = |o: &SolveOutcome| (o.summary.time_steps, o.summary.dofs);
                    at(&outcome).0 >= at(a).0 && at(&outcome).1 >= at(a).1
                });
                if finer {
                    answer = Some(outcome);
                }
            }
            Step::Done(report) => {
                let answer = answer.expect("a report follows at least one solve");
                return Ok((*report, answer));
            }
        }
    }
}

/// A solve as the rule reads it.
pub fn level_solved(refinement: Refinement, o: &SolveOutcome, time_factor: usize, mesh_factor: usize) -> LevelSolved {
    let s = &o.summary;
    LevelSolved {
        level: AccuracyLevel {
            refinement,
            time_factor,
            mesh_factor,
            steps: s.time_steps,
            dofs: s.dofs,
            converged: s.converged,
            iterations: s.iterations,
            work: s.work(),
            wall_seconds: s.wall_seconds,
            finals: Default::default(),
        },
        finals: s.qoi.iter().map(|(k, q)| (k.clone(), q.final_value)).collect(),
        largest: s.qoi.iter().map(|(k, q)| (k.clone(), q.values.iter().fold(0.0f64, |m, v| m.max(v.abs())))).collect(),
    }
}

/// One QoI of a held-out point: the study's answer against the same point one level finer.
#[derive(Debug, Clone, Serialize)]
pub struct HeldOutQoi {
    pub name: String,
    pub study: f64,
    pub finer: f64,
    /// the finer solve's scale of this QoI (as [`QoiAccuracy::scale`])
    pub scale: f64,
    /// |study - finer| / scale: at first order, the study's discretisation error
    pub difference: f64,
    pub within: bool,
}

/// A held-out point re-solved one level finer (dt / 2, and h / 2 when the study refined the
/// mesh), cold, at the study's tolerance.
#[derive(Debug, Clone, Serialize)]
pub struct HeldOutCheck {
    pub point: DesignPoint,
    pub time_factor: usize,
    pub mesh_factor: usize,
    pub converged: bool,
    pub qois: Vec<HeldOutQoi>,
    /// converged, and every QoI within the accuracy
    pub within: bool,
    pub work: f64,
    pub wall_seconds: f64,
}

/// Re-solves `point` of `scene` one level finer than the study's (`time_factor`, `mesh_factor`)
/// and compares its finals with the study's answer there.
#[allow(clippy::too_many_arguments)]
pub fn check_held_out(
    comm: &dyn Communicator,
    scene: &Scene,
    point: &DesignPoint,
    study: &BTreeMap<String, f64>,
    (time_factor, mesh_factor): (usize, usize),
    refine_mesh: bool,
    accuracy: Accuracy,
) -> Result<HeldOutCheck, RefineError> {
    let scene = &accuracy_scene(scene);
    let finer_mesh = if refine_mesh { mesh_factor * RATIO } else { mesh_factor };
    let finer = scene_at(scene, time_factor * RATIO, finer_mesh)?;
    let request = SolveRequest {
        point: point.clone(),
        tolerance: Some(
            Tolerance::new("the accuracy's tolerance", accuracy.tolerance()).map_err(crate::run::RunError::from)?,
        ),
        ..SolveRequest::default()
    };
    let outcome = solve_scene_on(comm, &finer, &request, None)?;
    let scales = glissade_core::accuracy::scales(scene, &level_solved(Refinement::Time, &outcome, 1, 1));
    let qois: Vec<HeldOutQoi> = outcome
        .summary
        .qoi
        .iter()
        .filter_map(|(name, q)| {
            let s = *study.get(name)?;
            let scale = scales[name];
            let difference = if scale > 0.0 { (s - q.final_value).abs() / scale } else { 0.0 };
            Some(HeldOutQoi {
                name: name.clone(),
                study: s,
                finer: q.final_value,
                scale,
                difference,
                within: glissade_core::accuracy::held_out_confirms(difference, accuracy.get()),
            })
        })
        .collect();
    let converged = outcome.summary.converged;
    Ok(HeldOutCheck {
        point: point.clone(),
        time_factor: time_factor * RATIO,
        mesh_factor: finer_mesh,
        converged,
        within: converged && qois.iter().all(|q| q.within),
        qois,
        work: outcome.summary.work(),
        wall_seconds: outcome.summary.wall_seconds,
    })
}
