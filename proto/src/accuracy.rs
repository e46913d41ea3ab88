//! A pilot's report of a study to an accuracy (`glissade_core::accuracy::AccuracyReport`) on the
//! wire: out only (the coordinator reads its pilots' ladders itself).

use glissade_core::accuracy::{AccuracyLevel, AccuracyReport, LadderError, QoiAccuracy};
use glissade_core::refine::Refinement;

use crate::v1;

/// A count as the wire carries it (a factor, a step count: far below the bound).
fn count(n: usize) -> u32 {
    u32::try_from(n).unwrap_or(u32::MAX)
}

/// `time` or `mesh`, as core's serde writes it.
pub fn refinement(r: Refinement) -> &'static str {
    match r {
        Refinement::Time => "time",
        Refinement::Mesh => "mesh",
    }
}

impl From<&LadderError> for v1::LadderError {
    fn from(l: &LadderError) -> Self {
        Self {
            finals: l.finals.clone(),
            estimate: l.error.estimate,
            order: l.error.order,
            erratic: l.error.erratic,
            below_noise: l.error.below_noise,
        }
    }
}

impl From<&QoiAccuracy> for v1::QoiLadders {
    fn from(q: &QoiAccuracy) -> Self {
        Self {
            name: q.name.clone(),
            value: q.value,
            scale: q.scale,
            time: Some((&q.time).into()),
            mesh: q.mesh.as_ref().map(Into::into),
            joint: q.joint.as_ref().map(Into::into),
            iteration: q.iteration,
            total: q.total,
            within: q.within,
        }
    }
}

impl From<&AccuracyLevel> for v1::AccuracyLevel {
    fn from(l: &AccuracyLevel) -> Self {
        Self {
            refinement: refinement(l.refinement).to_owned(),
            time_factor: count(l.time_factor),
            mesh_factor: count(l.mesh_factor),
            steps: count(l.steps),
            dofs: l.dofs as u64,
            converged: l.converged,
            iterations: l.iterations as u64,
            work: l.work,
            wall_seconds: l.wall_seconds,
            finals: l.finals.clone(),
        }
    }
}

impl From<&AccuracyReport> for v1::AccuracyReport {
    fn from(r: &AccuracyReport) -> Self {
        Self {
            accuracy: r.accuracy,
            tolerance: r.tolerance,
            newmark_gamma: r.newmark_gamma,
            time_factor: count(r.time_factor),
            mesh_factor: count(r.mesh_factor),
            steps: count(r.steps),
            mesh_refined: r.mesh_refined,
            max_time_factor: count(r.limits.max_time_factor),
            max_mesh_factor: count(r.limits.max_mesh_factor),
            reached: r.reached,
            why_not: r.why_not.clone().unwrap_or_default(),
            levels: r.levels.iter().map(Into::into).collect(),
            qoi: r.qois.iter().map(Into::into).collect(),
            work: r.work,
            wall_seconds: r.wall_seconds,
            cheapest: r.cheapest.map(|c| v1::CheapestLevel {
                time_factor: count(c.time_factor),
                mesh_factor: count(c.mesh_factor),
                bound: c.bound,
            }),
        }
    }
}
