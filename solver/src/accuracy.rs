//! One design point solved to an asked accuracy (`--accuracy`, docs/accuracy.md, "Ask for an
//! accuracy"): the iteration tolerance set from the accuracy, the time step halved until the
//! time ladder says the step's error is within its share, then, for box bodies, the mesh
//! halved at that step until the mesh ladder says the same of h. The answer is the finest level
//! solved; per QoI its estimated error, split into time step, mesh and iterations. When the
//! changes between levels do not fall within the largest factor allowed, the answer is the
//! finest level and the report says the accuracy was not reached, with the ladder as evidence.

use std::collections::BTreeMap;

use glissade_core::point::DesignPoint;
use glissade_core::refine::{Accuracy, FinestError, Refinement, finest_error, refined_scene};
use glissade_core::scene::{LawSpec, Scene, Tolerance};
use glissade_core::study::space::ParameterSpace;
use serde::Serialize;

use crate::comm::Communicator;
use crate::refine::RefineError;
use crate::run::{SolveOutcome, SolveRequest, solve_scene_on};

/// The ratio between levels: dt / 2, h / 2.
pub const RATIO: usize = 2;

/// A QoI smaller than this fraction of the largest QoI of its unit is measured against that
/// largest instead of itself: a stuck slip of 1e-21 m beside displacements of 1e-5 m is zero,
/// not a value whose rounding could never settle.
pub const ZERO_SHARE: f64 = 1e-6;

/// The levels a ladder needs before it may stop: three, so that an order is observed. Two can
/// agree by chance: the chattering block of docs/verification.md moves 0.4 % from dt to dt / 2
/// under gamma = 0.6, then 9 % at dt / 4.
pub const MIN_LEVELS: usize = 3;

/// The Newmark gamma a solve to accuracy takes for a scene with contact or friction that does not
/// set its own: a little numerical dissipation. Measured (docs/accuracy.md, "The time scheme"):
/// under the trapezoidal rule the bar impact stops converging at dt / 4 (eta stuck at 3e-4, the
/// impact's force oscillating between iterations); at 0.55 it converges in 35-306 iterations from
/// dt to dt / 10, its wall force 2-6 x closer to d'Alembert's, and a chattering block drifts less.
/// The first order it costs is measured by the ladders like any other error.
pub const CONTACT_GAMMA: f64 = 0.55;

/// The scene a solve to accuracy solves: the given one, with [`CONTACT_GAMMA`] where it has a
/// contact or friction interface and no `newmark_gamma` of its own.
pub fn accuracy_scene(scene: &Scene) -> Scene {
    let mut s = scene.clone();
    let contact = s.interfaces.iter().any(|i| matches!(i.law, LawSpec::Contact | LawSpec::Friction));
    if contact && s.time.newmark_gamma.is_none() {
        s.time.newmark_gamma = Some(CONTACT_GAMMA);
    }
    s
}

/// How far a solve to accuracy may refine.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct AccuracyLimits {
    /// the finest time step allowed: dt / this (a power of 2)
    pub max_time_factor: usize,
    /// the finest mesh allowed: h / this along each axis (1: the mesh is not refined)
    pub max_mesh_factor: usize,
}

/// A limit that is not a power of 2 from 1 to 1024.
#[derive(Debug, thiserror::Error)]
#[error("{flag} {value}: give a power of 2 from 1 to 1024")]
pub struct LimitError {
    pub flag: &'static str,
    pub value: usize,
}

impl AccuracyLimits {
    /// The limits `--max-dt-factor` and `--max-h-factor` ask for, checked.
    pub fn new(max_time_factor: usize, max_mesh_factor: usize) -> Result<Self, LimitError> {
        for (flag, value) in [("--max-dt-factor", max_time_factor), ("--max-h-factor", max_mesh_factor)] {
            if !(value.is_power_of_two() && value <= 1024) {
                return Err(LimitError { flag, value });
            }
        }
        Ok(AccuracyLimits { max_time_factor, max_mesh_factor })
    }
}

/// The scene solved at a level: [`accuracy_scene`] with dt / `time_factor` and h / `mesh_factor`.
pub fn scene_at(scene: &Scene, time_factor: usize, mesh_factor: usize) -> Result<Scene, RefineError> {
    let timed = refined_scene(&accuracy_scene(scene), Refinement::Time, time_factor)?;
    Ok(refined_scene(&timed, Refinement::Mesh, mesh_factor)?)
}

impl Default for AccuracyLimits {
    fn default() -> Self {
        AccuracyLimits { max_time_factor: 16, max_mesh_factor: 4 }
    }
}

/// One solve of the ladders.
#[derive(Debug, Clone, Serialize)]
pub struct AccuracyLevel {
    pub refinement: Refinement,
    /// dt / time_factor, h / mesh_factor
    pub time_factor: usize,
    pub mesh_factor: usize,
    pub steps: usize,
    pub dofs: usize,
    pub converged: bool,
    pub iterations: usize,
    /// sweeps of the whole interval, the self-check included
    pub work: f64,
    pub wall_seconds: f64,
}

/// What one ladder says of one QoI.
#[derive(Debug, Clone, Serialize)]
pub struct LadderError {
    /// the final value at each level of the ladder
    pub finals: Vec<f64>,
    /// (the estimate: the larger of the ladder's and `at_answer`)
    #[serde(flatten)]
    pub error: FinestError,
    /// the time ladder only, when the mesh was refined: the step's error estimated again on the
    /// answer's mesh, from one solve at twice the step
    #[serde(skip_serializing_if = "Option::is_none")]
    pub at_answer: Option<f64>,
}

/// One QoI of the answer.
#[derive(Debug, Clone, Serialize)]
pub struct QoiAccuracy {
    pub name: String,
    /// the finest level's final value
    pub value: f64,
    /// what the errors are relative to: the largest magnitude of the QoI's history at the finest
    /// level (no less than [`ZERO_SHARE`] of the largest QoI of the same unit)
    pub scale: f64,
    pub time: LadderError,
    /// `None` when the mesh was not refined
    pub mesh: Option<LadderError>,
    /// the iterations' share: [`glissade_core::refine::NOISE_PER_TOLERANCE`] x the tolerance
    pub iteration: f64,
    /// time + mesh + iteration, relative to `scale`
    pub total: f64,
    pub within: bool,
}

/// The answer to an accuracy: the discretisation chosen, its ladders and each QoI's error.
#[derive(Debug, Clone, Serialize)]
pub struct AccuracyReport {
    pub accuracy: f64,
    /// the iteration tolerance the accuracy set
    pub tolerance: f64,
    /// the time scheme's gamma (0.5: the trapezoidal rule; [`CONTACT_GAMMA`] where chosen)
    pub newmark_gamma: f64,
    /// the answer's level: dt / time_factor, h / mesh_factor
    pub time_factor: usize,
    pub mesh_factor: usize,
    pub steps: usize,
    /// whether the mesh was refined (box bodies only, and `max_mesh_factor` 2 or more); when
    /// not, the mesh's error is in no estimate and the accuracy is not said to be reached
    pub mesh_refined: bool,
    pub limits: AccuracyLimits,
    /// every QoI within the accuracy
    pub reached: bool,
    /// why not, in one sentence; `None` when reached
    pub why_not: Option<String>,
    pub levels: Vec<AccuracyLevel>,
    pub qois: Vec<QoiAccuracy>,
    /// work and wall time of every level together
    pub work: f64,
    pub wall_seconds: f64,
}

/// A ladder climbed until its finest level's error is within the share, or it may go no finer.
struct Climb {
    finals: Vec<BTreeMap<String, f64>>,
    errors: BTreeMap<String, FinestError>,
    /// the finest level's factor and its solve
    factor: usize,
    last: SolveOutcome,
    /// why it stopped short of the share: a level not converged, the factor limit
    stopped: Option<String>,
}

/// Solves `request`'s design point of `scene` to `accuracy` (module doc), `scene` as
/// [`accuracy_scene`] has it. `on_level` sees every level as it is solved, for progress.
pub fn solve_to_accuracy(
    comm: &dyn Communicator,
    scene: &Scene,
    request: &SolveRequest,
    accuracy: Accuracy,
    limits: AccuracyLimits,
    mut on_level: impl FnMut(&AccuracyLevel),
) -> Result<(AccuracyReport, SolveOutcome), RefineError> {
    let scene = &accuracy_scene(scene);
    let tolerance = accuracy.tolerance();
    let request = SolveRequest {
        tolerance: Some(Tolerance::new("the accuracy's tolerance", tolerance).map_err(crate::run::RunError::from)?),
        init_parameters: None,
        ..request.clone()
    };
    let mesh_refined = limits.max_mesh_factor >= RATIO && refined_scene(scene, Refinement::Mesh, RATIO).is_ok();
    let share = accuracy.discretisation_share(mesh_refined);
    let noise = accuracy.iteration_error();
    let mut levels = Vec::new();
    let mut record = |refinement, outcome: &SolveOutcome, time_factor, mesh_factor| {
        let l = describe(refinement, outcome, time_factor, mesh_factor);
        on_level(&l);
        levels.push(l);
    };

    let climb_time = Ladder { refinement: Refinement::Time, max_factor: limits.max_time_factor, share, noise };
    let time = climb_time.climb(comm, scene, &request, None, &mut |o, f| record(Refinement::Time, o, f, 1))?;
    let Climb { finals: time_finals, errors: time_errors, factor: time_factor, last, stopped: time_stopped } = time;
    let (mesh, answer, mesh_factor) = if mesh_refined && time_stopped.is_none() {
        let base = refined_scene(scene, Refinement::Time, time_factor)?;
        let climb_mesh = Ladder { refinement: Refinement::Mesh, max_factor: limits.max_mesh_factor, share, noise };
        let m = climb_mesh
            .climb(comm, &base, &request, Some(last), &mut |o, f| record(Refinement::Mesh, o, time_factor, f))?;
        let Climb { finals, errors, factor, last, stopped } = m;
        (Some((finals, errors, stopped)), last, factor)
    } else {
        (None, last, 1)
    };

    // The time ladder ran on the scene's mesh; a finer mesh carries higher frequencies that the
    // step may resolve worse. One more solve, at dt x 2 on the answer's mesh, checks the step's
    // error where the answer is.
    let time_at_answer = if mesh_factor > 1 && time_factor >= RATIO {
        let s = scene_at(scene, time_factor / RATIO, mesh_factor)?;
        let coarser = solve_scene_on(comm, &s, &request, None)?;
        record(Refinement::Time, &coarser, time_factor / RATIO, mesh_factor);
        coarser.summary.converged.then(|| finals_of(&coarser))
    } else {
        None
    };

    let scales = scales(scene, &answer);
    let qois: Vec<QoiAccuracy> = answer
        .summary
        .qoi
        .iter()
        .map(|(name, q)| {
            let ladder = |finals: &[BTreeMap<String, f64>], errors: &BTreeMap<String, FinestError>| LadderError {
                finals: finals.iter().map(|f| f[name]).collect(),
                error: errors[name],
                at_answer: None,
            };
            let mut time = ladder(&time_finals, &time_errors);
            // at the answer's mesh: the change from dt x 2, at the order the ladder observed (else
            // the first)
            time.at_answer = time_at_answer.as_ref().map(|coarser| {
                let order = time.error.order.unwrap_or(glissade_core::refine::TWO_LEVEL_ORDER);
                let change =
                    if scales[name] > 0.0 { (q.final_value - coarser[name]).abs() / scales[name] } else { 0.0 };
                change / ((RATIO as f64).powf(order) - 1.0)
            });
            if let Some(e) = time.at_answer {
                time.error.estimate = time.error.estimate.max(e);
            }
            let mesh = mesh.as_ref().map(|(f, e, _)| ladder(f, e));
            let total = time.error.estimate + mesh.as_ref().map_or(0.0, |m| m.error.estimate) + noise;
            QoiAccuracy {
                name: name.clone(),
                value: q.final_value,
                scale: scales[name],
                time,
                mesh,
                iteration: noise,
                total,
                within: total <= accuracy.get() * (1.0 + 1e-12),
            }
        })
        .collect();
    let mesh_ran = mesh.is_some();
    let mut reasons: Vec<String> = time_stopped.into_iter().chain(mesh.and_then(|(_, _, s)| s)).collect();
    // (an infinite estimate comes from a ladder that stopped at one level: its reason says why)
    let finite_above = qois.iter().filter(|q| !q.within && q.total.is_finite());
    if let Some(q) = finite_above.max_by(|a, b| a.total.total_cmp(&b.total)) {
        reasons.push(format!(
            "'{}' is estimated {:.1e} off, above the accuracy {:.1e} (its parts: time step {:.1e}, mesh {}, iterations {:.1e})",
            q.name,
            q.total,
            accuracy.get(),
            q.time.error.estimate,
            q.mesh.as_ref().map_or("not estimated".to_string(), |m| format!("{:.1e}", m.error.estimate)),
            q.iteration
        ));
    }
    if !mesh_refined {
        reasons.push(if refined_scene(scene, Refinement::Mesh, RATIO).is_ok() {
            format!("the mesh was kept (its largest factor is {}): its error is in no estimate", limits.max_mesh_factor)
        } else {
            "the mesh is read from a file and cannot be refined: its error is in no estimate".to_string()
        });
    }
    let why_not = (!reasons.is_empty()).then(|| reasons.join("; "));
    let report = AccuracyReport {
        newmark_gamma: scene.time.newmark_gamma.unwrap_or(0.5),
        accuracy: accuracy.get(),
        tolerance,
        time_factor,
        mesh_factor,
        steps: answer.summary.time_steps,
        mesh_refined: mesh_ran,
        limits,
        reached: why_not.is_none(),
        why_not,
        work: levels.iter().map(|l| l.work).sum(),
        wall_seconds: levels.iter().map(|l| l.wall_seconds).sum(),
        levels,
        qois,
    };
    Ok((report, answer))
}

/// One ladder's rule: what it refines, how far, and the share of the accuracy its finest level
/// must be within.
struct Ladder {
    refinement: Refinement,
    max_factor: usize,
    share: f64,
    noise: f64,
}

impl Ladder {
    /// Solves `scene` at factor 1 (or takes `first`, the solve at factor 1 already made), 2, 4,
    /// ... until every QoI's finest error is within the share, a level does not converge or the
    /// next factor passes the limit.
    fn climb(
        &self,
        comm: &dyn Communicator,
        scene: &Scene,
        request: &SolveRequest,
        first: Option<SolveOutcome>,
        on_level: &mut dyn FnMut(&SolveOutcome, usize),
    ) -> Result<Climb, RefineError> {
        let solve = |factor: usize| -> Result<SolveOutcome, RefineError> {
            let s = refined_scene(scene, self.refinement, factor)?;
            Ok(solve_scene_on(comm, &s, request, None)?)
        };
        let mut factor = 1;
        let mut last = match first {
            Some(o) => o,
            None => {
                let o = solve(1)?;
                on_level(&o, 1);
                o
            }
        };
        let mut finals = vec![finals_of(&last)];
        let what = match self.refinement {
            Refinement::Time => "dt",
            Refinement::Mesh => "h",
        };
        loop {
            if !last.summary.converged {
                let stopped = format!("the solve at {what} / {factor} did not converge: the ladder stops there");
                return Ok(Climb {
                    errors: self.errors(&finals, scene, &last),
                    finals,
                    factor,
                    last,
                    stopped: Some(stopped),
                });
            }
            let errors = self.errors(&finals, scene, &last);
            if finals.len() >= MIN_LEVELS && errors.values().all(|e| e.estimate <= self.share) {
                return Ok(Climb { finals, errors, factor, last, stopped: None });
            }
            let next = factor * RATIO;
            if next > self.max_factor {
                let stopped = (finals.len() < MIN_LEVELS).then(|| {
                    format!(
                        "the {what} ladder needs {MIN_LEVELS} levels ({what} / {}) and may go to {what} / {} only",
                        RATIO.pow(MIN_LEVELS as u32 - 1),
                        self.max_factor
                    )
                });
                return Ok(Climb { finals, errors, factor, last, stopped });
            }
            let outcome = match solve(next) {
                Ok(o) => o,
                Err(RefineError::Scene(e)) => {
                    let stopped = format!("the {what} ladder stops at {what} / {factor}: {e}");
                    return Ok(Climb { finals, errors, factor, last, stopped: Some(stopped) });
                }
                Err(e) => return Err(e),
            };
            on_level(&outcome, next);
            factor = next;
            finals.push(finals_of(&outcome));
            last = outcome;
        }
    }

    /// Every QoI's finest error (infinite from a single level: nothing is known yet).
    fn errors(
        &self,
        finals: &[BTreeMap<String, f64>],
        scene: &Scene,
        last: &SolveOutcome,
    ) -> BTreeMap<String, FinestError> {
        let scales = scales(scene, last);
        finals[0]
            .keys()
            .map(|name| {
                let f: Vec<f64> = finals.iter().map(|l| l[name]).collect();
                let e = if f.len() < 2 {
                    FinestError { estimate: f64::INFINITY, order: None, erratic: false, below_noise: false }
                } else {
                    finest_error(&f, RATIO, self.noise, scales[name])
                };
                (name.clone(), e)
            })
            .collect()
    }
}

fn finals_of(o: &SolveOutcome) -> BTreeMap<String, f64> {
    o.summary.qoi.iter().map(|(k, q)| (k.clone(), q.final_value)).collect()
}

/// Each QoI's scale: the largest magnitude of its history, no less than [`ZERO_SHARE`] of the
/// largest of the QoIs of the same unit.
fn scales(scene: &Scene, o: &SolveOutcome) -> BTreeMap<String, f64> {
    let unit = |name: &str| scene.qoi.iter().find(|q| q.name == name).map_or("", |q| q.kind.unit(scene.dimension));
    let own: BTreeMap<&str, f64> =
        o.summary.qoi.iter().map(|(k, q)| (k.as_str(), q.values.iter().fold(0.0f64, |s, v| s.max(v.abs())))).collect();
    own.iter()
        .map(|(name, &s)| {
            let largest = own.iter().filter(|(n, _)| unit(n) == unit(name)).fold(0.0f64, |m, (_, &v)| m.max(v));
            (name.to_string(), s.max(ZERO_SHARE * largest))
        })
        .collect()
}

fn describe(refinement: Refinement, o: &SolveOutcome, time_factor: usize, mesh_factor: usize) -> AccuracyLevel {
    let s = &o.summary;
    AccuracyLevel {
        refinement,
        time_factor,
        mesh_factor,
        steps: s.time_steps,
        dofs: s.dofs,
        converged: s.converged,
        iterations: s.iterations,
        work: s.work(),
        wall_seconds: s.wall_seconds,
    }
}

/// Design points in a spread-out order: the one nearest the points' centre first, then each
/// time the one farthest (normalised distance) from all those already taken. A study to an
/// accuracy solves the first few as pilots and checks the next few as held-out points: the
/// pilots span the box (its centre, then its corners), the held-out points lie between them.
pub fn spread_order(points: &[DesignPoint], space: &ParameterSpace, n: usize) -> Vec<usize> {
    if points.is_empty() {
        return Vec::new();
    }
    let coords: Vec<Vec<f64>> = points.iter().map(|p| space.normalised_coordinates(p)).collect();
    let dim = coords[0].len();
    let centre: Vec<f64> = (0..dim).map(|d| coords.iter().map(|c| c[d]).sum::<f64>() / coords.len() as f64).collect();
    let distance = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>().sqrt();
    let first =
        (0..points.len()).min_by(|&a, &b| distance(&coords[a], &centre).total_cmp(&distance(&coords[b], &centre)));
    let mut order: Vec<usize> = first.into_iter().collect();
    while order.len() < n.min(points.len()) {
        let farthest = (0..points.len()).filter(|i| !order.contains(i)).max_by(|&a, &b| {
            let d = |i: usize| order.iter().map(|&o| distance(&coords[i], &coords[o])).fold(f64::INFINITY, f64::min);
            d(a).total_cmp(&d(b))
        });
        match farthest {
            Some(i) => order.push(i),
            None => break,
        }
    }
    order
}

/// The discretisation a study takes from its pilots: the finest any of them needed.
pub fn study_level(pilots: &[AccuracyReport]) -> (usize, usize) {
    let time = pilots.iter().map(|r| r.time_factor).max().unwrap_or(1);
    let mesh = pilots.iter().map(|r| r.mesh_factor).max().unwrap_or(1);
    (time, mesh)
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
    let scales = scales(scene, &outcome);
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
                within: difference <= accuracy.get(),
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

#[cfg(test)]
mod tests {
    use super::*;
    use glissade_core::study::space::{GridAxis, design_points};

    #[test]
    fn the_spread_order_starts_at_the_centre_then_takes_the_corners() {
        let scene = Scene::parse(
            "dimension = 1\n[time]\nduration = 1e-4\nsteps = 10\n[parameters]\na = { default = 0.5, min = 0.0, max = 1.0 }\nb = { default = 0.5, min = 0.0, max = 1.0 }\n[materials.m]\nE = 1e9\nrho = 1000\n[[bodies]]\nname = \"bar\"\nmaterial = \"m\"\nsize = [1.0]\nelements = [2]\n",
        )
        .unwrap();
        let space = ParameterSpace::from_scene(&scene);
        let axes = ["a=0:1:5", "b=0:1:5"].map(|g| GridAxis::parse(g, &space).unwrap());
        let points = design_points(&axes, 100).unwrap();
        let order = spread_order(&points, &space, 7);
        let at = |i: usize| (points[order[i]].get("a").unwrap(), points[order[i]].get("b").unwrap());
        assert_eq!(at(0), (0.5, 0.5), "the centre first");
        let corners: Vec<(f64, f64)> = (1..5).map(at).collect();
        for c in [(0.0, 0.0), (0.0, 1.0), (1.0, 0.0), (1.0, 1.0)] {
            assert!(corners.contains(&c), "{c:?} in {corners:?}");
        }
        // then edge midpoints, each far from every point taken
        assert_eq!(order.len(), 7);
        let mut unique = order.clone();
        unique.sort();
        unique.dedup();
        assert_eq!(unique.len(), 7);
        assert_eq!(spread_order(&points[..1], &space, 3), vec![0]);
    }
}
