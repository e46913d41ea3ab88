//! The multiparametric strategy (docs/method.md 4): a study solves many design points of one scene,
//! each started from converged interface fields of other points.
//!
//! - [`space`]: parameters, ranges, normalised distances, grids (`f1=0.10:0.20:11`, lists, Latin
//!   hypercubes);
//! - [`store`]: the [`SolutionStore`](store::SolutionStore) seam and its in-memory kd-tree store;
//! - [`strategy`]: where a point's iterations start (cold, previous, nearest, blend);
//! - [`order`]: which point next, given what is done and in flight;
//! - [`engine`]: the rules of every study (what the store answers, where a point starts, what a
//!   failed solve becomes), applied here and by the coordinator;
//! - [`run_study`]: a whole study, serially (the `glissade-worker study` command), over the
//!   [`SolvePoint`] seam.

pub mod adaptive;
pub mod engine;
pub mod holdout;
pub mod order;
pub mod space;
pub mod store;
pub mod strategy;
pub mod surrogate;

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::field::InterfaceSolution;
use crate::scene::{Scale, Scene, Tolerance};

use crate::point::DesignPoint;
use engine::{SOLVER_VERSION, Start, StudyEngine, solve_or_retry_cold};
use order::OrderingPolicy;
use space::SpaceError;
use store::{SolutionId, SolutionStore, StoreError, StoredSolution};
use strategy::{InitSource, InitStrategy};

/// Two points closer than this (normalised distance) are the same point.
pub const SAME_POINT: f64 = 1e-12;

/// Errors that stop a whole study (a design point that fails is recorded, not an error).
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    #[error(transparent)]
    Space(#[from] SpaceError),
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("ordering policy chose point {index} of {pending} pending")]
    Policy { index: usize, pending: usize },
}

/// How a study solves its points.
#[derive(Debug, Clone, Copy)]
pub struct StudyOptions {
    pub strategy: InitStrategy,
    /// error-indicator tolerance (None: the scene's)
    pub tolerance: Option<Tolerance>,
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
    /// the dynamic iterations' work in sweeps of the whole interval, where time windows made it
    /// less than their number (absent: one sweep each)
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dynamic_sweeps: Option<f64>,
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
    /// what each frictional interface's contact did while it slid (a reused point: that of the
    /// solve that made its stored solution)
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub contact: Vec<crate::contact::ContactActivity>,
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
    /// how many points each mean is over (0 in summaries written before they were kept)
    #[serde(default)]
    pub cold_points: usize,
    #[serde(default)]
    pub warm_points: usize,
}

impl StudySummary {
    /// How warm starts compared with cold ones in work, worded both ways.
    pub fn warm_against_cold(&self) -> Option<String> {
        Some(warm_against_cold(
            WorkMean { work: self.cold_mean_work?, points: self.cold_points },
            WorkMean { work: self.warm_mean_work?, points: self.warm_points },
        ))
    }
}

/// The mean work of a set of points (`points` 0: not known).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorkMean {
    pub work: f64,
    pub points: usize,
}

/// Below this many cold points, a study's cold mean is said to be a rough yardstick: cold solves
/// of one scene differ by 2x from point to point (three-blocks-small: 163 or 320 work).
const FEW_COLD_POINTS: usize = 3;

/// "warm starts cost 2.1x less work than cold ones" or, when they did not pay, "... 1.3x more",
/// with the counts behind the means.
pub fn warm_against_cold(cold: WorkMean, warm: WorkMean) -> String {
    let (c, w) = (cold.work, warm.work);
    let (factor, how) = if w <= c { (c / w.max(1e-12), "less") } else { (w / c.max(1e-12), "MORE") };
    let mut s = format!("warm starts cost {factor:.1}x {how} work than cold ones ({w:.1} against {c:.1} per point");
    if cold.points > 0 && warm.points > 0 {
        s += &format!("; {} warm, {} cold", warm.points, cold.points);
        if cold.points < FEW_COLD_POINTS {
            s += ": so few cold points make a rough yardstick";
        }
    }
    s + ")"
}

impl PointRecord {
    /// Sweeps of the whole interval: dynamic iterations (or their windows' share) + static
    /// iterations / steps.
    pub fn work(&self, steps: usize) -> f64 {
        let dynamic = self.dynamic_sweeps.unwrap_or((self.iterations - self.static_iterations) as f64);
        dynamic + self.static_iterations as f64 / steps.max(1) as f64
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
        let works = |warm: bool| -> Vec<f64> {
            records
                .iter()
                .filter(|r| r.status != PointStatus::Reused && r.status != PointStatus::Failed)
                .filter(|r| (r.start != StartKind::Cold) == warm && r.start != StartKind::Continued)
                .map(|r| r.work(steps))
                .collect()
        };
        let (cold_works, warm_works) = (works(false), works(true));
        let mean = |w: &[f64]| (!w.is_empty()).then(|| w.iter().sum::<f64>() / w.len() as f64);
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
            cold_mean_work: mean(&cold_works),
            warm_mean_work: mean(&warm_works),
            cold_points: cold_works.len(),
            warm_points: warm_works.len(),
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
        let fixed = ["status", "converged", "iterations", "static_iterations", "eta", "tolerance", "wall_seconds"];
        let last = ["started_from", "source_ids", "source_distance", "error"];
        let header: Vec<String> = ["index", "sequence"]
            .iter()
            .map(|s| s.to_string())
            .chain(self.parameters.iter().cloned())
            .chain(fixed.iter().map(|s| s.to_string()))
            .chain(qoi_names.iter().cloned())
            .chain(last.iter().map(|s| s.to_string()))
            .collect();
        let rows = self.by_index().into_iter().map(|r| {
            let status = serde_json::to_value(r.status).ok().and_then(|v| v.as_str().map(String::from));
            let ids: Vec<String> = r.sources.iter().map(|s| s.id.to_string()).collect();
            let distance =
                r.sources.iter().map(|s| s.distance).fold(None, |m: Option<f64>, d| Some(m.map_or(d, |m| m.min(d))));
            [r.index.to_string(), r.sequence.to_string()]
                .into_iter()
                .chain(self.parameters.iter().map(|p| r.point.get(p).map_or(String::new(), |v| v.to_string())))
                .chain([
                    status.unwrap_or_default(),
                    r.converged.to_string(),
                    r.iterations.to_string(),
                    r.static_iterations.to_string(),
                    r.eta.map_or(String::new(), |e| format!("{e:.6e}")),
                    r.tolerance.to_string(),
                    format!("{:.6}", r.wall_seconds),
                ])
                .chain(qoi_names.iter().map(|q| r.qoi.get(q).map_or(String::new(), |v| format!("{v:.10e}"))))
                .chain([
                    r.started_from(),
                    ids.join(" "),
                    distance.map_or(String::new(), |d| format!("{d:.6}")),
                    r.error.clone().unwrap_or_default(),
                ])
                .collect::<Vec<String>>()
        });
        crate::text::csv_table(std::iter::once(header).chain(rows))
    }
}

/// What a study asks of the solver for one point.
#[derive(Debug, Clone)]
pub struct PointRequest<'a> {
    /// every parameter of the scene
    pub point: &'a DesignPoint,
    pub tolerance: f64,
    /// LATIN iterations per stage (None: the scene's)
    pub max_iterations: Option<usize>,
    pub scale: Option<Scale>,
    /// The design point the warm start converged at. A continued solve of this very point stops
    /// at the tolerance, one started from another point at `warm_tolerance_ratio` times it
    /// (docs/scenes.md); None for a blend, which comes from no single point.
    pub init_point: Option<&'a DesignPoint>,
}

/// What the solver returns to a study for one point.
#[derive(Debug, Clone)]
pub struct PointSolved {
    pub converged: bool,
    /// static + dynamic
    pub iterations: usize,
    pub static_iterations: usize,
    /// the dynamic iterations in sweeps of the whole interval (their number without time windows)
    pub dynamic_sweeps: f64,
    /// final error indicator of the dynamic stage
    pub eta: f64,
    /// final value of every QoI
    pub qoi: BTreeMap<String, f64>,
    pub solution: InterfaceSolution,
    /// what each frictional interface's contact did while it slid
    pub contact: Vec<crate::contact::ContactActivity>,
}

/// The seam between a study and the solver (the worker's solver, which keeps factorised operators
/// from one point to the next).
pub trait SolvePoint {
    fn solve(
        &mut self,
        scene: &Scene,
        request: &PointRequest,
        init: Option<&InterfaceSolution>,
    ) -> Result<PointSolved, SolvePointError>;
}

/// Why [`SolvePoint::solve`] gave no outcome for a point. Its message is the point record's
/// `error`; the solver's own error is kept whole, with its sources.
#[derive(Debug, thiserror::Error)]
pub enum SolvePointError {
    /// The study's tolerance is not one a solve accepts.
    #[error(transparent)]
    Tolerance(crate::scene::SceneError),
    /// The solve failed (the solver's error: its scene, its numerics).
    #[error(transparent)]
    Solver(Box<dyn std::error::Error + Send + Sync>),
}

impl SolvePointError {
    /// The solver's own error, kept whole.
    pub fn solver(e: impl std::error::Error + Send + Sync + 'static) -> Self {
        Self::Solver(Box::new(e))
    }
}

/// Runs a study of `points` of `scene` serially: asks `order` for the next point, lets the
/// [`StudyEngine`] say how it begins from the solutions in `store` (which must hold solutions of
/// this scene only, i.e. of the same [`Scene::content_hash`]), solves it with `solver`, stores it
/// if it converged, and reports each record to `progress` (with the number of points done and
/// the total).
pub fn run_study(
    scene: &Scene,
    points: &[DesignPoint],
    options: &StudyOptions,
    order: &mut dyn OrderingPolicy,
    store: &mut dyn SolutionStore,
    solver: &mut dyn SolvePoint,
    progress: &mut dyn FnMut(&PointRecord, usize, usize),
) -> Result<StudyResult, StudyError> {
    let engine = StudyEngine::new(scene, options.strategy, options.tolerance);
    if points.is_empty() {
        return Err(SpaceError::EmptyGrid.into());
    }
    let space = engine.space();
    // the pending points and their positions in `points`, removed from both together
    let mut pending: Vec<DesignPoint> = points.iter().map(|p| space.complete(p)).collect::<Result<_, SpaceError>>()?;
    let mut pending_index: Vec<usize> = (0..pending.len()).collect();
    let total = pending.len();
    let mut done: Vec<DesignPoint> = Vec::new();
    let mut records: Vec<PointRecord> = Vec::new();
    let mut previous: Option<SolutionId> = None;
    while !pending.is_empty() {
        let Some(choice) = order.next(&pending, &done, &[]) else { break };
        if choice >= pending.len() {
            return Err(StudyError::Policy { index: choice, pending: pending.len() });
        }
        let (index, point) = (pending_index.remove(choice), pending.remove(choice));
        let record = solve_point(solver, scene, &engine, &point, index, records.len(), options, store, &mut previous)?;
        done.push(point);
        progress(&record, records.len() + 1, total);
        records.push(record);
    }
    Ok(StudyResult {
        scene_hash: scene.content_hash(),
        strategy: options.strategy,
        tolerance: engine.tolerance(),
        parameters: space.names().map(String::from).collect(),
        summary: StudyResult::summarise(&records, scene.time.steps),
        records,
    })
}

/// One point of a study: answered from the store, or started and solved (cold again if a warm
/// start fails), then stored if it converged.
#[allow(clippy::too_many_arguments)]
fn solve_point(
    solver: &mut dyn SolvePoint,
    scene: &Scene,
    engine: &StudyEngine,
    point: &DesignPoint,
    index: usize,
    sequence: usize,
    options: &StudyOptions,
    store: &mut dyn SolutionStore,
    previous: &mut Option<SolutionId>,
) -> Result<PointRecord, StudyError> {
    let start = Instant::now();
    let tolerance = engine.tolerance();
    let mut record = PointRecord {
        index,
        sequence,
        point: point.clone(),
        status: PointStatus::Failed,
        converged: false,
        iterations: 0,
        static_iterations: 0,
        dynamic_sweeps: None,
        eta: None,
        tolerance,
        wall_seconds: 0.0,
        qoi: BTreeMap::new(),
        start: StartKind::Cold,
        sources: Vec::new(),
        retried_cold: false,
        stored_as: None,
        error: None,
        contact: Vec::new(),
    };
    let (init, start_kind) = match engine.start(store, point, *previous, SOLVER_VERSION)? {
        Start::Answer(s) => {
            record.status = PointStatus::Reused;
            record.converged = true;
            record.eta = Some(s.eta);
            record.qoi = s.qoi.clone();
            record.start = StartKind::Reused;
            record.sources = vec![InitSource { id: s.id, point: s.point.clone(), distance: 0.0, weight: 1.0 }];
            record.stored_as = Some(s.id);
            record.contact = s.contact;
            record.wall_seconds = start.elapsed().as_secs_f64();
            *previous = Some(s.id);
            return Ok(record);
        }
        Start::Solve { init, kind } => (init, kind),
    };
    let init_point = match start_kind {
        StartKind::Blend | StartKind::Linear => None,
        _ => init.sources.first().map(|s| &s.point),
    };
    let request =
        PointRequest { point, tolerance, max_iterations: options.max_iterations, scale: options.scale, init_point };
    let (outcome, retried_cold) =
        solve_or_retry_cold(init.solution.as_deref(), |init| solver.solve(scene, &request, init));
    record.retried_cold = retried_cold;
    record.start = if retried_cold { StartKind::Cold } else { start_kind };
    record.sources = init.sources;
    match outcome {
        Err(e) => {
            record.error = Some(e.to_string());
        }
        Ok(o) => {
            record.converged = o.converged;
            record.status = if o.converged { PointStatus::Converged } else { PointStatus::NotConverged };
            record.iterations = o.iterations;
            record.static_iterations = o.static_iterations;
            let dynamic = (o.iterations - o.static_iterations) as f64;
            record.dynamic_sweeps = (o.dynamic_sweeps != dynamic).then_some(o.dynamic_sweeps);
            record.eta = Some(o.eta);
            record.qoi = o.qoi;
            record.contact = o.contact;
            if o.converged {
                let id = store.insert(StoredSolution {
                    point: point.clone(),
                    eta: o.eta,
                    tolerance,
                    converged: true,
                    iterations: o.iterations,
                    qoi: record.qoi.clone(),
                    solution: Arc::new(o.solution),
                    parent: if retried_cold { None } else { record.sources.first().map(|s| s.id) },
                    solver_version: SOLVER_VERSION.into(),
                    contact: record.contact.clone(),
                })?;
                record.stored_as = Some(id);
                *previous = Some(id);
            }
        }
    }
    record.wall_seconds = start.elapsed().as_secs_f64();
    Ok(record)
}

/// Share of the largest QoI of a unit below which the solver's stopping test measures a QoI of
/// that unit against that share, not against itself (`latin::stopping::NORM_FLOOR` in the worker).
pub const QOI_FLOOR: f64 = 1e-3;

/// Per QoI, the smallest value a study at `tolerance` resolves: tolerance x [`QOI_FLOOR`] x the
/// largest |value| of any QoI of the same unit over `points` (each point's QoIs; `unit` gives a
/// QoI's unit, None: its own). The stopping test bounds a QoI's error by tolerance x its own size
/// or that floor, whichever is larger, so a value below it (a slip that sticks, 1e-21 m next to
/// slips of 1e-5 m) is zero as far as the solve can tell.
pub fn resolutions<'a>(
    tolerance: f64,
    points: impl IntoIterator<Item = &'a BTreeMap<String, f64>>,
    unit: impl Fn(&str) -> Option<String>,
) -> BTreeMap<String, f64> {
    let points: Vec<&BTreeMap<String, f64>> = points.into_iter().collect();
    let unit_of = |q: &str| unit(q).unwrap_or_else(|| format!("qoi:{q}"));
    let mut largest: BTreeMap<String, f64> = BTreeMap::new();
    for (q, v) in points.iter().flat_map(|p| p.iter()) {
        let l = largest.entry(unit_of(q)).or_insert(0.0);
        if v.is_finite() {
            *l = l.max(v.abs());
        }
    }
    let names: std::collections::BTreeSet<&String> = points.iter().flat_map(|p| p.keys()).collect();
    names.into_iter().map(|q| (q.clone(), tolerance * QOI_FLOOR * largest[&unit_of(q)])).collect()
}

/// A QoI's value as tables, plots and ranges show it: 0 below its resolution ([`resolutions`]).
pub fn shown(value: f64, resolution: f64) -> f64 {
    if value.abs() < resolution { 0.0 } else { value }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A solver's error crosses the seam whole: the record's text is its message, and its
    /// sources are still there.
    #[test]
    fn a_solver_error_keeps_its_message_and_its_sources() {
        use std::error::Error;
        #[derive(Debug, thiserror::Error)]
        #[error("the solve failed: {0}")]
        struct Failed(#[source] std::io::Error);
        let e = SolvePointError::solver(Failed(std::io::Error::other("disk full")));
        assert_eq!(e.to_string(), "the solve failed: disk full");
        assert_eq!(e.source().map(|s| s.to_string()).as_deref(), Some("disk full"));
    }

    #[test]
    fn a_stuck_slip_below_the_resolution_shows_as_zero() {
        // issue 25: slips of 1.9e-21 and 1.2e-22 beside 2.2e-5, displacements of 6e-4, at 2e-4
        let points: Vec<BTreeMap<String, f64>> = [(1.915135e-21, 2.229e-5, 6e-4), (2.2e-5, 1.249e-22, 5e-4)]
            .iter()
            .map(|&(a, b, u)| {
                [("slip_A".into(), a), ("slip_B".into(), b), ("middle_ux".into(), u), ("n".into(), 3.0)].into()
            })
            .collect();
        let unit = |q: &str| (q != "n").then(|| "m".to_owned());
        let r = resolutions(2e-4, &points, unit);
        // tolerance x 1e-3 x the largest length, 6e-4; the count against its own size
        assert!((r["slip_A"] - 1.2e-10).abs() < 1e-22 && r["slip_B"] == r["slip_A"], "{r:?}");
        assert!((r["n"] - 6e-7).abs() < 1e-19, "{r:?}");
        assert_eq!((shown(1.915135e-21, r["slip_A"]), shown(2.229e-5, r["slip_B"])), (0.0, 2.229e-5));
        assert_eq!(shown(-1e-12, r["slip_A"]), 0.0);
    }

    /// The comparison says which way warm starts went, and how many points stand behind it.
    #[test]
    fn warm_against_cold_says_the_direction_and_the_counts() {
        let cold = |points| WorkMean { work: 317.9, points };
        let warm = |work, points| WorkMean { work, points };
        assert_eq!(
            warm_against_cold(cold(1), warm(133.2, 8)),
            "warm starts cost 2.4x less work than cold ones (133.2 against 317.9 per point; 8 warm, 1 cold: \
             so few cold points make a rough yardstick)"
        );
        assert_eq!(
            warm_against_cold(cold(5), warm(400.0, 8)),
            "warm starts cost 1.3x MORE work than cold ones (400.0 against 317.9 per point; 8 warm, 5 cold)"
        );
        // counts not known (summaries written before they were kept): the means alone
        assert_eq!(
            warm_against_cold(cold(0), warm(133.2, 0)),
            "warm starts cost 2.4x less work than cold ones (133.2 against 317.9 per point)"
        );
    }
}
