//! The multiparametric strategy (docs/method.md 4): a study solves many design points of one scene,
//! each started from converged interface fields of other points.
//!
//! - [`space`]: parameters, ranges, normalised distances, grids (`f1=0.10:0.20:11`, lists, Latin
//!   hypercubes);
//! - [`store`]: the [`SolutionStore`](store::SolutionStore) seam and its in-memory kd-tree store;
//! - [`strategy`]: where a point's iterations start (cold, previous, nearest, blend);
//! - [`order`]: which point next, given what is done and in flight;
//! - [`run_study`]: a whole study, serially (the `glissade-worker study` command), with
//!   tolerance-aware reuse of stored solutions.

pub mod order;
pub mod space;
pub mod store;
pub mod strategy;

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::comm::Serial;
use crate::run::{PointSolver, SolveRequest};
use crate::scene::{Scale, Scene};

use order::OrderingPolicy;
use space::{DesignPoint, ParameterSpace, SpaceError};
use store::{SolutionId, SolutionStore, StoreError, StoredSolution};
use strategy::{InitSource, InitStrategy, Initialisation, initialise, interface_law_parameters};

/// Two points closer than this (normalised distance) are the same point.
pub const SAME_POINT: f64 = 1e-12;

/// Errors that stop a whole study (a design point that fails is recorded, not an error).
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    #[error(transparent)]
    Space(#[from] SpaceError),
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("--tol: must be a positive number, got {0}")]
    Tolerance(f64),
    #[error("ordering policy chose point {index} of {pending} pending")]
    Policy { index: usize, pending: usize },
}

/// How a study solves its points.
#[derive(Debug, Clone, Copy)]
pub struct StudyOptions {
    pub strategy: InitStrategy,
    /// error-indicator tolerance (None: the scene's)
    pub tolerance: Option<f64>,
    /// LATIN iterations per stage (None: the scene's)
    pub max_iterations: Option<usize>,
    pub scale: Option<Scale>,
}

impl Default for StudyOptions {
    fn default() -> Self {
        Self { strategy: InitStrategy::Nearest, tolerance: None, max_iterations: None, scale: None }
    }
}

/// How a point's iterations started.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum StartKind {
    /// from zero fields
    Cold,
    /// not solved: a stored solution of this very point already met the tolerance
    Reused,
    /// from a stored solution of this very point with eta above the tolerance
    Continued,
    Previous,
    Nearest,
    Blend,
    Linear,
}

/// How a point ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PointStatus {
    Converged,
    /// the iteration limit was hit
    NotConverged,
    /// answered from the store with 0 iterations
    Reused,
    /// the solve stopped with an error (see `error`)
    Failed,
}

/// The record of one design point of a study.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PointRecord {
    /// position in the study's list of points
    pub index: usize,
    /// position in the order the points were solved
    pub sequence: usize,
    /// every parameter of the scene
    pub point: DesignPoint,
    pub status: PointStatus,
    pub converged: bool,
    /// LATIN iterations, static + dynamic (0 when reused)
    pub iterations: usize,
    pub static_iterations: usize,
    /// final error indicator of the dynamic stage (null when failed)
    pub eta: Option<f64>,
    pub tolerance: f64,
    pub wall_seconds: f64,
    /// final value of every QoI (empty when failed)
    pub qoi: BTreeMap<String, f64>,
    pub start: StartKind,
    /// the stored solutions the start came from (with weights for a blend)
    pub sources: Vec<InitSource>,
    /// true when a warm-started solve failed and the point was solved again from cold
    pub retried_cold: bool,
    /// id of this point's solution in the store (converged points only)
    pub stored_as: Option<SolutionId>,
    pub error: Option<String>,
}

impl PointRecord {
    /// `cold`, `nearest #4 d=0.1000`, `blend #4:0.62 #7:0.38`, ...
    pub fn started_from(&self) -> String {
        let name = match self.start {
            StartKind::Cold if self.retried_cold => return "cold (the warm start failed)".into(),
            StartKind::Cold => return "cold".into(),
            StartKind::Reused => "reused",
            StartKind::Continued => "continued",
            StartKind::Previous => "previous",
            StartKind::Nearest => "nearest",
            StartKind::Blend => "blend",
            StartKind::Linear => "linear",
        };
        let sources: Vec<String> = if matches!(self.start, StartKind::Blend | StartKind::Linear) {
            self.sources.iter().map(|s| format!("#{}:{:.2}", s.id, s.weight)).collect()
        } else {
            self.sources.iter().map(|s| format!("#{} d={:.4}", s.id, s.distance)).collect()
        };
        format!("{name} {}", sources.join(" "))
    }
}

/// Totals of a study.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StudySummary {
    pub points: usize,
    pub converged: usize,
    pub not_converged: usize,
    pub failed: usize,
    pub reused: usize,
    pub total_iterations: usize,
    /// iterations of the first point solved
    pub first_iterations: usize,
    /// mean iterations of the other points
    pub mean_later_iterations: f64,
    /// sum of the points' wall times
    pub wall_seconds: f64,
    /// work of the study: dynamic iterations + static iterations / steps (a dynamic iteration
    /// sweeps every time step, a static one a single step)
    #[serde(default)]
    pub work: f64,
    /// mean work of the points solved from cold, and of those warm-started from other points
    #[serde(default)]
    pub cold_mean_work: Option<f64>,
    #[serde(default)]
    pub warm_mean_work: Option<f64>,
}

impl StudySummary {
    /// How warm starts compared with cold ones in work, worded both ways.
    pub fn warm_against_cold(&self) -> Option<String> {
        Some(warm_against_cold(self.cold_mean_work?, self.warm_mean_work?))
    }
}

/// "warm starts cost 2.1x less work than cold ones" or, when they did not pay, "... 1.3x more".
pub fn warm_against_cold(cold: f64, warm: f64) -> String {
    if warm <= cold {
        format!(
            "warm starts cost {:.1}x less work than cold ones ({warm:.1} against {cold:.1} per point)",
            cold / warm.max(1e-12)
        )
    } else {
        format!(
            "warm starts cost {:.1}x MORE work than cold ones ({warm:.1} against {cold:.1} per point)",
            warm / cold.max(1e-12)
        )
    }
}

impl PointRecord {
    /// Dynamic iterations + static iterations / steps.
    pub fn work(&self, steps: usize) -> f64 {
        (self.iterations - self.static_iterations) as f64 + self.static_iterations as f64 / steps.max(1) as f64
    }
}

/// The result of a study: one record per point, in the order solved.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StudyResult {
    pub scene_hash: String,
    pub strategy: InitStrategy,
    pub tolerance: f64,
    pub parameters: Vec<String>,
    pub summary: StudySummary,
    pub records: Vec<PointRecord>,
}

impl StudyResult {
    fn summarise(records: &[PointRecord], steps: usize) -> StudySummary {
        let count = |s: PointStatus| records.iter().filter(|r| r.status == s).count();
        let mean_work = |warm: bool| {
            let w: Vec<f64> = records
                .iter()
                .filter(|r| r.status != PointStatus::Reused && r.status != PointStatus::Failed)
                .filter(|r| (r.start != StartKind::Cold) == warm && r.start != StartKind::Continued)
                .map(|r| r.work(steps))
                .collect();
            (!w.is_empty()).then(|| w.iter().sum::<f64>() / w.len() as f64)
        };
        let total: usize = records.iter().map(|r| r.iterations).sum();
        let first = records.first().map_or(0, |r| r.iterations);
        StudySummary {
            points: records.len(),
            converged: count(PointStatus::Converged) + count(PointStatus::Reused),
            not_converged: count(PointStatus::NotConverged),
            failed: count(PointStatus::Failed),
            reused: count(PointStatus::Reused),
            total_iterations: total,
            first_iterations: first,
            mean_later_iterations: if records.len() > 1 {
                (total - first) as f64 / (records.len() - 1) as f64
            } else {
                0.0
            },
            wall_seconds: records.iter().map(|r| r.wall_seconds).sum(),
            work: records.iter().map(|r| r.work(steps)).sum(),
            cold_mean_work: mean_work(false),
            warm_mean_work: mean_work(true),
        }
    }

    /// The records in the study's list order (by `index`).
    pub fn by_index(&self) -> Vec<&PointRecord> {
        let mut v: Vec<&PointRecord> = self.records.iter().collect();
        v.sort_by_key(|r| r.index);
        v
    }

    /// CSV: one row per point in list order; parameter and QoI columns by name.
    pub fn to_csv(&self) -> String {
        let qoi_names: Vec<String> = {
            let mut names: Vec<String> = self.records.iter().flat_map(|r| r.qoi.keys().cloned()).collect();
            names.sort();
            names.dedup();
            names
        };
        let mut out = String::from("index,sequence");
        for p in &self.parameters {
            out += &format!(",{p}");
        }
        out += ",status,converged,iterations,static_iterations,eta,tolerance,wall_seconds";
        for q in &qoi_names {
            out += &format!(",{q}");
        }
        out += ",started_from,source_ids,source_distance,error\n";
        for r in self.by_index() {
            out += &format!("{},{}", r.index, r.sequence);
            for p in &self.parameters {
                out += &format!(",{}", r.point.get(p).map_or(String::new(), |v| v.to_string()));
            }
            let status = serde_json::to_value(r.status).ok().and_then(|v| v.as_str().map(String::from));
            out += &format!(
                ",{},{},{},{},{},{},{:.6}",
                status.unwrap_or_default(),
                r.converged,
                r.iterations,
                r.static_iterations,
                r.eta.map_or(String::new(), |e| format!("{e:.6e}")),
                r.tolerance,
                r.wall_seconds
            );
            for q in &qoi_names {
                out += &format!(",{}", r.qoi.get(q).map_or(String::new(), |v| format!("{v:.10e}")));
            }
            let ids: Vec<String> = r.sources.iter().map(|s| s.id.to_string()).collect();
            let distance =
                r.sources.iter().map(|s| s.distance).fold(None, |m: Option<f64>, d| Some(m.map_or(d, |m| m.min(d))));
            out += &format!(
                ",{},{},{},{}\n",
                csv_field(&r.started_from()),
                ids.join(" "),
                distance.map_or(String::new(), |d| format!("{d:.6}")),
                csv_field(r.error.as_deref().unwrap_or(""))
            );
        }
        out
    }
}

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) { format!("\"{}\"", s.replace('"', "\"\"")) } else { s.to_string() }
}

/// Runs a study of `points` of `scene` serially: asks `order` for the next point, starts it
/// according to `options.strategy` from the solutions in `store` (which must hold solutions of
/// this scene only, i.e. of the same [`Scene::content_hash`]), solves it, stores it if it
/// converged, and reports each record to `progress` (with the number of points done and the
/// total).
///
/// Tolerance-aware reuse (every strategy but `Cold`, which never reads the store): a stored
/// solution of this very point converged at this tolerance or a tighter one answers at once with
/// 0 iterations (the stopping test vouches for its QoIs at its tolerance); one converged at a
/// looser tolerance is continued from instead of restarting.
pub fn run_study(
    scene: &Scene,
    points: &[DesignPoint],
    options: &StudyOptions,
    order: &mut dyn OrderingPolicy,
    store: &mut dyn SolutionStore,
    progress: &mut dyn FnMut(&PointRecord, usize, usize),
) -> Result<StudyResult, StudyError> {
    let tolerance = options.tolerance.unwrap_or(scene.solver.tolerance);
    if !(tolerance > 0.0 && tolerance.is_finite()) {
        return Err(StudyError::Tolerance(tolerance));
    }
    if points.is_empty() {
        return Err(SpaceError::EmptyGrid.into());
    }
    let space = ParameterSpace::from_scene(scene);
    let law_parameters = interface_law_parameters(scene);
    // the pending points and their positions in `points`, removed from both together
    let mut pending: Vec<DesignPoint> = points.iter().map(|p| space.complete(p)).collect::<Result<_, SpaceError>>()?;
    let mut pending_index: Vec<usize> = (0..pending.len()).collect();
    let total = pending.len();
    let mut done: Vec<DesignPoint> = Vec::new();
    let mut records: Vec<PointRecord> = Vec::new();
    let mut previous: Option<SolutionId> = None;
    // keeps the factorised operators while only interface-law parameters change
    let mut solver = PointSolver::default();
    while !pending.is_empty() {
        let Some(choice) = order.next(&pending, &done, &[]) else { break };
        if choice >= pending.len() {
            return Err(StudyError::Policy { index: choice, pending: pending.len() });
        }
        let (index, point) = (pending_index.remove(choice), pending.remove(choice));
        let record = solve_point(
            &mut solver,
            scene,
            &space,
            &law_parameters,
            &point,
            index,
            records.len(),
            options,
            tolerance,
            store,
            &mut previous,
        )?;
        done.push(point);
        progress(&record, records.len() + 1, total);
        records.push(record);
    }
    Ok(StudyResult {
        scene_hash: scene.content_hash(),
        strategy: options.strategy,
        tolerance,
        parameters: space.names().map(String::from).collect(),
        summary: StudyResult::summarise(&records, scene.time.steps),
        records,
    })
}

/// One point of a study: reuse, or initialise and solve (retrying from cold if a warm start
/// fails), then store it if it converged.
#[allow(clippy::too_many_arguments)]
fn solve_point(
    solver: &mut PointSolver,
    scene: &Scene,
    space: &ParameterSpace,
    law_parameters: &BTreeSet<String>,
    point: &DesignPoint,
    index: usize,
    sequence: usize,
    options: &StudyOptions,
    tolerance: f64,
    store: &mut dyn SolutionStore,
    previous: &mut Option<SolutionId>,
) -> Result<PointRecord, StudyError> {
    let start = Instant::now();
    let mut record = PointRecord {
        index,
        sequence,
        point: point.clone(),
        status: PointStatus::Failed,
        converged: false,
        iterations: 0,
        static_iterations: 0,
        eta: None,
        tolerance,
        wall_seconds: 0.0,
        qoi: BTreeMap::new(),
        start: StartKind::Cold,
        sources: Vec::new(),
        retried_cold: false,
        stored_as: None,
        error: None,
    };

    // Tolerance-aware reuse: a stored solution of this very point (the most accurate one).
    let mut init = Initialisation::cold();
    let mut start_kind = StartKind::Cold;
    if options.strategy != InitStrategy::Cold {
        let mut same: Option<(SolutionId, StoredSolution)> = None;
        for (d, id) in store.nearest(point, 8)? {
            if d > SAME_POINT {
                break;
            }
            let s = store.get(id)?;
            if same.as_ref().is_none_or(|(_, b)| s.tolerance < b.tolerance) {
                same = Some((id, s));
            }
        }
        if let Some((id, s)) = same {
            let source = InitSource { id, point: s.point.clone(), distance: 0.0, weight: 1.0 };
            if s.converged && s.tolerance <= tolerance {
                record.status = PointStatus::Reused;
                record.converged = true;
                record.eta = Some(s.eta);
                record.qoi = s.qoi.clone();
                record.start = StartKind::Reused;
                record.sources = vec![source];
                record.stored_as = Some(id);
                record.wall_seconds = start.elapsed().as_secs_f64();
                *previous = Some(id);
                return Ok(record);
            }
            init = Initialisation { solution: Some(s.solution), sources: vec![source], used: options.strategy };
            start_kind = StartKind::Continued;
        } else {
            init = initialise(store, space, law_parameters, point, *previous, options.strategy)?;
            start_kind = match init.used {
                InitStrategy::Cold => StartKind::Cold,
                InitStrategy::Previous => StartKind::Previous,
                InitStrategy::Nearest => StartKind::Nearest,
                InitStrategy::Blend { .. } => StartKind::Blend,
                InitStrategy::Linear { .. } => StartKind::Linear,
            };
        }
    }

    let request = SolveRequest {
        set: point.to_set(),
        tolerance: Some(tolerance),
        max_iterations: options.max_iterations,
        scale: options.scale,
        record_fields: false,
        progress: None,
        // a continued solve of this very point needs only the tolerance (see SolveRequest)
        init_parameters: if start_kind == StartKind::Continued {
            scene.parameter_values(&point.to_set()).ok()
        } else {
            None
        },
    };
    let mut outcome = solver.solve(&Serial, scene, &request, init.solution.as_deref());
    if outcome.is_err() && init.solution.is_some() {
        tracing::warn!(point = %point, error = %outcome.as_ref().err().map(|e| e.to_string()).unwrap_or_default(),
            "warm-started solve failed; solving from cold");
        record.retried_cold = true;
        outcome = solver.solve(&Serial, scene, &request, None);
    }
    record.start = if record.retried_cold { StartKind::Cold } else { start_kind };
    record.sources = init.sources;
    match outcome {
        Err(e) => {
            record.error = Some(e.to_string());
        }
        Ok(o) => {
            let s = &o.summary;
            record.converged = s.converged;
            record.status = if s.converged { PointStatus::Converged } else { PointStatus::NotConverged };
            record.iterations = s.iterations;
            record.static_iterations = s.static_stage.as_ref().map_or(0, |st| st.iterations);
            record.eta = Some(s.error_indicator);
            record.qoi = s.qoi.iter().map(|(k, q)| (k.clone(), q.final_value)).collect();
            if s.converged {
                let id = store.insert(StoredSolution {
                    point: point.clone(),
                    eta: s.error_indicator,
                    tolerance,
                    converged: true,
                    iterations: s.iterations,
                    qoi: record.qoi.clone(),
                    solution: Arc::new(o.solution),
                    parent: if record.retried_cold { None } else { record.sources.first().map(|s| s.id) },
                })?;
                record.stored_as = Some(id);
                *previous = Some(id);
            }
        }
    }
    record.wall_seconds = start.elapsed().as_secs_f64();
    Ok(record)
}
