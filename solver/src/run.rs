//! One solve of a scene at a design point: the library call behind `glissade-worker solve`, and
//! what the study logic and the worker pool call. Dispatches on the scene's dimension.

use std::collections::BTreeMap;
use std::time::Instant;

use serde::Serialize;

use crate::comm::Communicator;
use crate::contact_activity::{ContactActivity, contact_activity};
use crate::latin::{
    CheckOutcome, FieldHistory, LatinSolver, Operators, SolveOptions, SolverError, StageReport, Timings, WindowCheck,
};
use crate::model::Model;
use glissade_core::field::InterfaceSolution;
use glissade_core::point::DesignPoint;
use glissade_core::scene::{Scale, Scene, SceneError, SolverSpec, Tolerance};
use glissade_core::study::{PointRequest, PointSolved, SolvePoint, SolvePointError};

#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error(transparent)]
    Scene(#[from] SceneError),
    #[error(transparent)]
    Solver(#[from] SolverError),
}

/// What to solve and how.
#[derive(Debug, Clone, Default)]
pub struct SolveRequest {
    /// The design point: the parameters it sets (`--set NAME=VALUE`); the others keep the
    /// scene's defaults.
    pub point: DesignPoint,
    /// (None: the scene's)
    pub tolerance: Option<Tolerance>,
    pub max_iterations: Option<usize>,
    pub scale: Option<Scale>,
    pub record_fields: bool,
    /// Counts the iterations while they run (for progress reports).
    pub progress: Option<std::sync::Arc<crate::latin::SolveProgress>>,
    /// Every parameter's value at the design point the warm start converged at, when known:
    /// a restart of this very point converges to the tolerance as asked, one from another
    /// point to `warm_tolerance_ratio` times it (docs/scenes.md).
    pub init_parameters: Option<DesignPoint>,
}

/// A QoI time series and its final value.
#[derive(Debug, Clone, Serialize)]
pub struct QoiJson {
    #[serde(rename = "final")]
    pub final_value: f64,
    pub times: Vec<f64>,
    pub values: Vec<f64>,
}

/// The machine-readable result of a solve (`--json`).
#[derive(Debug, Clone, Serialize)]
pub struct SolveSummary {
    pub converged: bool,
    /// total LATIN iterations (static + dynamic stages)
    pub iterations: usize,
    /// final error indicator of the dynamic stage
    pub error_indicator: f64,
    /// the dynamic stage's final estimate of the worst QoI's relative error (stopping.rs)
    pub error_estimate: f64,
    /// eta per iteration of the dynamic stage
    pub history: Vec<f64>,
    /// the dynamic iterations' work in sweeps of the whole interval (less than their number
    /// with time windows: an iteration sweeps its window)
    pub dynamic_sweeps: f64,
    /// time windows the dynamic stage iterated (1: the whole interval at once)
    pub dynamic_windows: usize,
    /// steps per time window (`solver.time_window`; 0: the whole interval)
    pub time_window: usize,
    /// windows accepted after stalling on a QoI still small, and of those the ones iterated
    /// again once the whole histories were known (docs/method.md, "Time windows")
    pub dynamic_windows_stalled: usize,
    pub dynamic_windows_redone: usize,
    /// a windowed solve iterated again in other windows and compared (docs/method.md, "Two
    /// windowings"); its passes are counted in `iterations` and `dynamic_sweeps`
    pub window_check: Option<WindowCheck>,
    pub static_stage: Option<StageReport>,
    /// where the dynamic stage left off and how it went (`StageReport::diagnosis`), when it did
    /// not converge
    pub dynamic_diagnosis: Option<String>,
    pub tolerance: f64,
    pub wall_seconds: f64,
    pub dofs: usize,
    pub substructures: usize,
    pub interfaces: usize,
    pub time_steps: usize,
    pub parameters: DesignPoint,
    pub qoi: BTreeMap<String, QoiJson>,
    /// what each frictional interface's contact did while it slid, and whether that sliding is
    /// ill-posed (`contact_activity`, docs/verification.md 4d); rank 0's only
    pub contact: Vec<ContactActivity>,
    pub timings: Timings,
}

impl SolveSummary {
    /// Sweeps of the whole interval: dynamic iterations (each sweeps every step, or its time
    /// window's) + static iterations / time steps (a static one sweeps a single step).
    pub fn work(&self) -> f64 {
        let statics = self.static_stage.as_ref().map_or(0, |s| s.iterations);
        self.dynamic_sweeps + statics as f64 / self.time_steps.max(1) as f64
    }

    /// Why the solve did not converge, naming the stage that fell short and what it was held
    /// to; `None` when it converged.
    pub fn shortfall(&self) -> Option<String> {
        if self.converged {
            return None;
        }
        if let Some(st) = self.static_stage.as_ref().filter(|s| !s.converged) {
            let tol = crate::latin::static_tolerance(self.tolerance);
            return Some(format!(
                "the static stage did not converge: eta = {:.3e} > {:.1e} (the tolerance x {}, no tighter than {:.0e}) after {} iterations; {}",
                st.error_indicator,
                tol,
                crate::latin::STATIC_TOLERANCE_RATIO,
                crate::latin::STATIC_TOLERANCE_FLOOR,
                st.iterations,
                st.diagnosis(tol)
            ));
        }
        Some(format!(
            "the dynamic stage did not converge: eta = {:.3e}, estimated QoI error {:.3e}, tolerance {:.1e}, after {} iterations; {}",
            self.error_indicator,
            self.error_estimate,
            self.tolerance,
            self.history.len(),
            self.dynamic_diagnosis.as_deref().unwrap_or("")
        ))
    }
}

/// Node coordinates and connectivity of every substructure, for field output.
#[derive(Debug, Clone)]
pub struct SubstructureMesh {
    pub dimension: usize,
    pub kind: crate::element::ElementKind,
    /// coordinates padded to 3 components
    pub coords: Vec<[f64; 3]>,
    pub connectivity: Vec<usize>,
    /// its body's material, for the stress the field output derives
    pub material: crate::element::Material,
}

/// Fields of a solve, for `--fields`.
#[derive(Debug, Clone)]
pub struct FieldOutput {
    pub meshes: Vec<SubstructureMesh>,
    pub times: Vec<f64>,
    pub history: FieldHistory,
    /// what happened on each interface (wall interfaces included)
    pub interfaces: Vec<InterfaceOutput>,
}

/// An interface's nodes and, at every time (`[step][node]`, steps + 1 of them), what happened
/// there: from its converged fields, as its QoIs are.
#[derive(Debug, Clone)]
pub struct InterfaceOutput {
    pub name: String,
    /// coordinates padded to 3 components
    pub coords: Vec<[f64; 3]>,
    /// the normal traction pressing the sides together (Pa; negative: pulling them apart, as a
    /// glued interface may)
    pub pressure: Vec<Vec<f64>>,
    /// the normal gap (m): the initial one, plus the sides' normal separation since (the
    /// prestress's, then the dynamics')
    pub gap: Vec<Vec<f64>>,
    /// the tangential relative displacement accumulated during the dynamics (m; side b's less
    /// side a's), 3 components a node: the slip QoIs' at their nodes
    pub slip: Vec<Vec<[f64; 3]>>,
}

/// [`InterfaceOutput`] of every interface of `model` from the solution's fields.
fn interface_output<const D: usize>(model: &Model<D>, solution: &InterfaceSolution) -> Vec<InterfaceOutput> {
    let pad = |p: &[f64; D]| -> [f64; 3] { std::array::from_fn(|c| if c < D { p[c] } else { 0.0 }) };
    model
        .interfaces
        .iter()
        .enumerate()
        .map(|(i, itf)| {
            let (n, f) = (itf.n_nodes(), &solution.dynamic.interfaces[i]);
            let normal = |j: usize, v: &[f64], at: usize| -> f64 {
                (0..D).map(|c| v[(at * n + j) * D + c] * itf.normal[j][c]).sum()
            };
            // the prestress's normal separation and traction, where there is one
            let statics = solution.static_stage.as_ref().map(|st| &st.interfaces[i]);
            let static_jump: Vec<f64> = (0..n)
                .map(|j| {
                    statics.map_or(0.0, |s| {
                        s.hat.get(1).map_or(0.0, |b| normal(j, &b.velocity, 0)) - normal(j, &s.hat[0].velocity, 0)
                    })
                })
                .collect();
            let relative: Vec<Vec<[f64; D]>> =
                (0..n).map(|j| crate::latin::relative_displacement(model, f, i, j)).collect();
            let steps = model.steps + 1;
            let pressure = (0..steps)
                .map(|k| {
                    (0..n)
                        .map(|j| match k {
                            0 => statics.map_or(0.0, |s| -normal(j, &s.hat[0].force, 0)),
                            _ => -normal(j, &f.hat[0].force, k - 1),
                        })
                        .collect()
                })
                .collect();
            let along = |r: &[f64; D], j: usize| -> f64 { (0..D).map(|c| r[c] * itf.normal[j][c]).sum() };
            let gap = (0..steps)
                .map(|k| (0..n).map(|j| itf.gap0[j] + static_jump[j] + along(&relative[j][k], j)).collect())
                .collect();
            let slip = (0..steps)
                .map(|k| {
                    (0..n)
                        .map(|j| {
                            let (r, rn) = (&relative[j][k], along(&relative[j][k], j));
                            std::array::from_fn(|c| if c < D { r[c] - rn * itf.normal[j][c] } else { 0.0 })
                        })
                        .collect()
                })
                .collect();
            InterfaceOutput {
                name: itf.name.clone(),
                coords: itf.coords.iter().map(pad).collect(),
                pressure,
                gap,
                slip,
            }
        })
        .collect()
}

pub struct SolveOutcome {
    pub summary: SolveSummary,
    pub solution: InterfaceSolution,
    pub fields: Option<FieldOutput>,
}

/// Solves `scene` at the design point `request.point`, optionally warm-started, on one
/// process.
pub fn solve_scene(
    scene: &Scene,
    request: &SolveRequest,
    init: Option<&InterfaceSolution>,
) -> Result<SolveOutcome, RunError> {
    solve_scene_on(&crate::comm::Serial, scene, request, init)
}

/// The same solve spread over the ranks of `comm`; every rank calls it with the same arguments.
/// Rank 0's outcome holds the whole solution, QoIs and fields; other ranks' outcomes hold the
/// same summary and QoIs.
pub fn solve_scene_on(
    comm: &dyn Communicator,
    scene: &Scene,
    request: &SolveRequest,
    init: Option<&InterfaceSolution>,
) -> Result<SolveOutcome, RunError> {
    PointSolver::default().solve(comm, scene, request, init)
}

/// Solves design point after design point, keeping the factorised operators of the last model
/// while only interface-law parameters change (friction coefficients: docs/method.md 4), as a worker
/// pool or a study does. Any other change (scene, other parameters, scale) refactorises.
#[derive(Default)]
pub struct PointSolver {
    cache: Option<CachedModel>,
}

/// The last model built, of the scene's dimension.
enum CachedModel {
    One(Cached<1>),
    Two(Cached<2>),
    Three(Cached<3>),
}

impl CachedModel {
    fn one(self) -> Option<Cached<1>> {
        if let Self::One(c) = self { Some(c) } else { None }
    }
    fn two(self) -> Option<Cached<2>> {
        if let Self::Two(c) = self { Some(c) } else { None }
    }
    fn three(self) -> Option<Cached<3>> {
        if let Self::Three(c) = self { Some(c) } else { None }
    }
}

/// A built model and its factorised operators, with what they were built for.
struct Cached<const D: usize> {
    key: OperatorKey,
    model: Model<D>,
    operators: Operators,
}

impl PointSolver {
    pub fn solve(
        &mut self,
        comm: &dyn Communicator,
        scene: &Scene,
        request: &SolveRequest,
        init: Option<&InterfaceSolution>,
    ) -> Result<SolveOutcome, RunError> {
        use CachedModel::{One, Three, Two};
        // a model of another dimension is dropped, as one of another key
        let cache = self.cache.take();
        let (outcome, cached) = match scene.dimension {
            1 => solve_dim(comm, scene, request, init, cache.and_then(CachedModel::one)).map(|(o, c)| (o, One(c)))?,
            2 => solve_dim(comm, scene, request, init, cache.and_then(CachedModel::two)).map(|(o, c)| (o, Two(c)))?,
            _ => {
                solve_dim(comm, scene, request, init, cache.and_then(CachedModel::three)).map(|(o, c)| (o, Three(c)))?
            }
        };
        self.cache = Some(cached);
        Ok(outcome)
    }
}

/// A study's points solved on this process (`glissade-worker study`), operators kept between them.
impl SolvePoint for PointSolver {
    fn solve(
        &mut self,
        scene: &Scene,
        request: &PointRequest,
        init: Option<&InterfaceSolution>,
    ) -> Result<PointSolved, SolvePointError> {
        let request = SolveRequest {
            point: request.point.clone(),
            tolerance: Some(
                Tolerance::new("the study's tolerance", request.tolerance).map_err(SolvePointError::Tolerance)?,
            ),
            max_iterations: request.max_iterations,
            scale: request.scale,
            record_fields: false,
            progress: None,
            init_parameters: request.init_point.and_then(|p| scene.parameter_values(p).ok()),
        };
        let o =
            PointSolver::solve(self, &crate::comm::Serial, scene, &request, init).map_err(SolvePointError::solver)?;
        let s = o.summary;
        Ok(PointSolved {
            converged: s.converged,
            iterations: s.iterations,
            static_iterations: s.static_stage.as_ref().map_or(0, |st| st.iterations),
            dynamic_sweeps: s.dynamic_sweeps,
            eta: s.error_indicator,
            qoi: s.qoi.iter().map(|(k, q)| (k.clone(), q.final_value)).collect(),
            contact: s.contact.clone(),
            solution: o.solution,
        })
    }
}

/// What the operators and the cached model depend on: the scene (its hash leaves out the
/// `[solver]` section, whose k0_factor is in the operators and whose other settings are in the
/// model: so the section too), the parameters other than interface laws (their bits: -0 is not
/// 0 here), the scale.
#[derive(PartialEq)]
struct OperatorKey {
    scene: String,
    solver: SolverSpec,
    others: Vec<(String, u64)>,
    scale: Option<Scale>,
}

impl OperatorKey {
    fn new(scene: &Scene, values: &DesignPoint, scale: Option<Scale>) -> Self {
        let law = scene.interface_law_parameters();
        let others =
            values.iter().filter(|(k, _)| !law.contains(*k)).map(|(k, v)| (k.to_owned(), v.to_bits())).collect();
        Self { scene: scene.content_hash(), solver: scene.solver.clone(), others, scale }
    }
}

fn apply_request<const D: usize>(model: &mut Model<D>, scene: &Scene, request: &SolveRequest) -> Result<(), RunError> {
    model.settings.tolerance = scene.solver.tolerance;
    model.settings.max_iterations = scene.solver.max_iterations;
    if let Some(t) = request.tolerance {
        model.settings.tolerance = t.get();
    }
    if let Some(n) = request.max_iterations {
        model.settings.max_iterations = glissade_core::scene::check_max_iterations("--max-iter", n as u64)?;
    }
    if let Some(s) = request.scale {
        model.settings.scale = s;
    }
    Ok(())
}

/// Why the dynamic stage did not converge and what to change: the stage's diagnosis, led by the
/// advice on the time step where iterations fell short: the time scheme's where the solve's own
/// did (the impacts that measured it stalled there; a check's pass that stalls on a sliding block
/// of flat elements does so under gamma 0.55 too), a step far below the mesh's transit time's
/// where any did. Not where the check found an answer that moves with the iteration error: that
/// is the motion's, not the scheme's.
fn dynamic_diagnosis<const D: usize>(model: &Model<D>, stage: &StageReport) -> String {
    let diagnosis = stage.diagnosis(model.settings.tolerance);
    let outcome = stage.window_check.as_ref().map(|c| c.outcome);
    if matches!(outcome, Some(CheckOutcome::Parted | CheckOutcome::BelowFloor)) {
        return diagnosis;
    }
    let scheme = model.scheme_advice().filter(|_| outcome.is_none());
    let advice: Vec<String> = [scheme, model.short_step_advice()].into_iter().flatten().collect();
    if advice.is_empty() {
        return diagnosis;
    }
    format!("{}; {diagnosis}", advice.join("; "))
}

fn solve_dim<const D: usize>(
    comm: &dyn Communicator,
    scene: &Scene,
    request: &SolveRequest,
    init: Option<&InterfaceSolution>,
    cache: Option<Cached<D>>,
) -> Result<(SolveOutcome, Cached<D>), RunError> {
    let start = Instant::now();
    let values = scene.parameter_values(&request.point)?;
    let key = OperatorKey::new(scene, &values, request.scale);
    let (mut model, operators) = match cache.filter(|c| c.key == key) {
        Some(c) => {
            let Cached { mut model, operators, .. } = c;
            model.update_interface_laws(scene, &values)?;
            (model, Some(operators))
        }
        None => (Model::<D>::build(scene, &values)?, None),
    };
    apply_request(&mut model, scene, request)?;
    let mut solver = match operators {
        Some(ops) => LatinSolver::with_operators(&model, comm, ops),
        None => LatinSolver::new(&model, comm)?,
    };
    let options = SolveOptions {
        record_fields: request.record_fields,
        progress: request.progress.clone(),
        init_at_this_point: request.init_parameters.as_ref() == Some(&values),
        trace_qois: false,
    };
    let report = solver.solve(init, &options);
    let operators = solver.into_operators();
    let report = report?;
    let qoi = report
        .qoi
        .iter()
        .map(|q| {
            (
                q.name.clone(),
                QoiJson {
                    final_value: *q.values.last().unwrap_or(&0.0),
                    times: q.times.clone(),
                    values: q.values.clone(),
                },
            )
        })
        .collect();
    let fields = report.fields.clone().map(|history| FieldOutput {
        meshes: model
            .substructures
            .iter()
            .map(|s| SubstructureMesh {
                dimension: D,
                kind: s.kind,
                coords: s
                    .coords
                    .iter()
                    .map(|p| {
                        let mut q = [0.0; 3];
                        q[..D].copy_from_slice(p);
                        q
                    })
                    .collect(),
                connectivity: s.connectivity.clone(),
                material: s.material,
            })
            .collect(),
        times: (0..=model.steps).map(|n| glissade_core::text::decimal(n as f64 * model.dt)).collect(),
        history,
        // (the interfaces' fields are gathered on rank 0, which writes the field file)
        interfaces: if comm.rank() == 0 { interface_output(&model, &report.solution) } else { Vec::new() },
    });
    let summary = SolveSummary {
        converged: report.converged(),
        iterations: report.iterations(),
        error_indicator: report.dynamic.error_indicator,
        error_estimate: report.dynamic.error_estimate,
        history: report.dynamic.history.clone(),
        dynamic_sweeps: report.dynamic.sweeps,
        dynamic_windows: report.dynamic.windows,
        time_window: model.settings.time_window,
        dynamic_windows_stalled: report.dynamic.windows_stalled,
        dynamic_windows_redone: report.dynamic.windows_redone,
        window_check: report.dynamic.window_check.clone(),
        dynamic_diagnosis: (!report.dynamic.converged).then(|| dynamic_diagnosis(&model, &report.dynamic)),
        static_stage: report.static_stage.clone(),
        tolerance: model.settings.tolerance,
        wall_seconds: start.elapsed().as_secs_f64(),
        dofs: model.n_dofs(),
        substructures: model.substructures.len(),
        interfaces: model.interfaces.len(),
        time_steps: model.steps,
        parameters: values,
        qoi,
        contact: if comm.rank() == 0 {
            contact_activity(&model.interfaces, &report.solution.dynamic, model.dt)
        } else {
            Vec::new()
        },
        timings: report.timings.clone(),
    };
    Ok((SolveOutcome { summary, solution: report.solution, fields }, Cached { key, model, operators }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::latin::WindowCheck;

    /// The time scheme's advice leads where the solve's own iterations fell short, not where a
    /// check's pass did (measured on a sliding titanium block of flat elements whose pass stalls
    /// under gamma 0.55 as under the trapezoidal rule: docs/notebook/2026-11-29.md, "Refine dt
    /// and h together"); a parted check is the motion's, and gets neither.
    #[test]
    fn the_time_schemes_advice_leads_only_where_the_solves_own_iterations_stalled() {
        let scene = Scene::parse(
            "dimension = 1\n[time]\nduration = 1e-5\nsteps = 10\n[materials.m]\nE = 1e11\nrho = 5000\n\
             [[bodies]]\nname = \"bar\"\nmaterial = \"m\"\nsize = [0.05]\nelements = [5]\ninitial_velocity = [1.0]\n\
             [[interfaces]]\nname = \"wall\"\na = \"bar.x+\"\nb = \"wall\"\nlaw = \"contact\"\n",
        )
        .unwrap();
        let model = Model::<1>::build(&scene, &scene.parameter_values(&Default::default()).unwrap()).unwrap();
        let mut stalled = StageReport::default();
        stalled.iterations = 3;
        stalled.history = vec![1e-2, 9e-3, 8e-3];
        assert!(dynamic_diagnosis(&model, &stalled).starts_with("first try a little numerical dissipation"));
        let check = |outcome| {
            let mut s = stalled.clone();
            s.window_check = Some(WindowCheck { outcome, ..Default::default() });
            s
        };
        for outcome in [CheckOutcome::PassNotConverged, CheckOutcome::Parted, CheckOutcome::BelowFloor] {
            let why = dynamic_diagnosis(&model, &check(outcome));
            assert!(!why.contains("newmark_gamma"), "{outcome:?}: {why}");
        }
    }
}
