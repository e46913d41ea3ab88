//! The LATIN mixed domain-decomposition solver (docs/method.md 3): linear stage (substructures),
//! relaxation, local stage (interfaces), error indicator — iterated over the whole time interval.

mod along;
pub mod distribution;
pub mod linear_stage;
pub mod local_stage;
pub mod macro_problem;
mod record;
pub mod relaxation;
pub mod stopping;
mod window_check;
mod windows;

use std::ops::Range;
use std::time::Instant;

use serde::Serialize;

use crate::comm::Communicator;
use crate::model::{Model, QoiTarget};
use crate::sparse::SparseError;
use glissade_core::scene::Scale;

use crate::newmark::NewmarkState;
use crate::search_direction::SearchDirection;
use along::AlongSolves;
use distribution::Distribution;
use glissade_core::field::{InterfaceField, InterfaceSolution, SideField, StageSolution};
use linear_stage::{Stage, SubstructureOperators};
use local_stage::{GapRule, NodeInput, NodeMemory, apply_law};
use macro_problem::{MacroError, MacroProblem};
use record::{BodyQois, QoiValues};
use relaxation::Relaxation;
use stopping::{ErrorEstimator, UnitScales};
use window_check::Tightening;
pub use window_check::{CheckOutcome, Parting, WindowCheck};

/// Tolerance of each time window relative to the asked one (docs/method.md, "Time windows").
pub const WINDOW_TOLERANCE_RATIO: f64 = 0.1;

/// A time window whose eta has converged but whose QoI estimate has not after
/// `STALL_ITERATIONS` plus `STALL_PER_STEP` per step iterations is accepted for now
/// (docs/method.md, "Time windows"): a QoI that barely moves yet (a slip of 1e-7 m before
/// sliding starts) is held to its share of the tolerance against that small prefix of its
/// history and can stall there. The windows' errors are judged together against the whole
/// histories once the last window has converged; if they do not fit, the first stalled window is
/// iterated again from where it stopped.
pub const STALL_ITERATIONS: usize = 100;
pub const STALL_PER_STEP: usize = 4;

/// Aspect ratio of the elements along an interface from which a diagnosis names it: at 10 the
/// range of stiffnesses one search direction must span is about 100 x wider than for cubes.
pub const FLAT_ELEMENTS: f64 = 10.0;

/// Tolerance of the static prestress stage relative to the asked one: the prestress is the
/// dynamics' initial state, and its error comes out of them amplified (a wall's normal force
/// 4,000 x the static stage's eta: docs/performance.md, "The prestress's error"), while a static
/// iteration costs one step.
pub const STATIC_TOLERANCE_RATIO: f64 = 1e-7;
/// Below this the static stage's eta stalls on round-off: no tighter than it.
pub const STATIC_TOLERANCE_FLOOR: f64 = 1e-12;
/// The static stage may iterate this many times the iteration limit (no more times than there
/// are steps): its iterations sweep one step, and tight it can take thousands (elements of
/// aspect ratio 100 at a floor: 3,012 to 2e-9, docs/performance.md "The prestress's error").
pub const STATIC_ITERATIONS_FACTOR: usize = 10;

/// The static stage's tolerance for a solve asked to `tolerance` (one rule: the solve's and its
/// report's).
pub fn static_tolerance(tolerance: f64) -> f64 {
    (tolerance * STATIC_TOLERANCE_RATIO).max(STATIC_TOLERANCE_FLOOR)
}

/// Errors of a LATIN solve.
#[derive(Debug, thiserror::Error)]
pub enum SolverError {
    #[error("substructure {substructure}: {source}")]
    Factorisation { substructure: usize, source: SparseError },
    #[error(
        "{stage} stage, iteration {iteration}: error indicator is {eta} (the iterations diverged; try a smaller k0_factor or time step)"
    )]
    NonFinite { stage: &'static str, iteration: usize, eta: f64 },
    #[error(
        "{stage} stage, iteration {iteration}: quantity of interest '{qoi}' is not finite (the iterations diverged; try a k0_factor or tangential_factor nearer 1)"
    )]
    NonFiniteQoi { stage: &'static str, iteration: usize, qoi: String },
    #[error("interface '{interface}': its system from node to node: {source}")]
    AlongSystem { interface: String, source: SparseError },
    #[error("cannot distribute the model: {0}")]
    Distribution(String),
    #[error("initial solution does not fit this model: {0}")]
    IncompatibleInit(String),
    #[error("{stage} stage: {source}")]
    Macro { stage: &'static str, source: MacroError },
    /// [`SolveProgress::stop`] was called: the point's study was cancelled, its lease lost, or
    /// its pool stopping now.
    #[error("{stage} stage, iteration {iteration}: stopped on request")]
    Stopped { stage: &'static str, iteration: usize },
}

/// Iteration record of one stage.
#[derive(Debug, Clone, Default, Serialize)]
pub struct StageReport {
    pub iterations: usize,
    pub converged: bool,
    pub error_indicator: f64,
    /// estimated relative error of the worst QoI history when the stage stopped (dynamic
    /// stage; the static stage reports eta here)
    pub error_estimate: f64,
    /// eta after each iteration
    pub history: Vec<f64>,
    /// every QoI's history after each iteration, `[iteration][qoi][step]`, when
    /// [`SolveOptions::trace_qois`] asks for it
    #[serde(skip)]
    pub qoi_trace: Vec<Vec<Vec<f64>>>,
    /// the interface with the largest share of eta at the last iteration
    pub worst_interface: Option<String>,
    /// its elements' aspect ratio ([`crate::model::Interface::element_aspect`])
    #[serde(skip_serializing_if = "Option::is_none")]
    pub worst_interface_aspect: Option<f64>,
    /// the relaxation coefficient at the last iteration (lowered where the iterates oscillated)
    pub relaxation: f64,
    /// the work of the iterations in sweeps of the whole interval: `iterations`, or less with
    /// time windows (an iteration sweeps its window only)
    pub sweeps: f64,
    /// time windows iterated (1: the whole interval at once)
    pub windows: usize,
    /// windows accepted after stalling on a small QoI ([`STALL_ITERATIONS`]), and of those
    /// the ones the whole histories did not clear, iterated again
    pub windows_stalled: usize,
    pub windows_redone: usize,
    /// the same solve iterated again in other time windows and compared (dynamic stage in
    /// windows, unless the scene turns it off): `iterations` and `sweeps` include its passes
    pub window_check: Option<WindowCheck>,
    /// where a stage in time windows stopped before the end: the window's steps `[from, to)` of
    /// the interval's `of` (the steps after it were never iterated: their fields, and the QoIs,
    /// follow the starting guess)
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stopped_in: Option<StoppedIn>,
    /// per QoI, the norm of its whole history its error is measured against (floored as the
    /// stopping test floors it) when the stage stopped
    #[serde(skip)]
    scales: Vec<f64>,
    /// set by [`LatinSolver::iterate_window`]: eta converged, the QoI estimate stalled
    #[serde(skip)]
    stalled: bool,
}

impl StageReport {
    /// Adds the report of the next time window (or of one iterated again: `again`), whose
    /// iterations each swept `share` of the interval: iterations and eta's history go on, the
    /// estimate is the worst window's until the last, when [`LatinSolver::iterate`] replaces it
    /// with the windows' errors summed.
    fn append(&mut self, next: StageReport, share: f64, again: bool) {
        self.sweeps += next.iterations as f64 * share;
        if again {
            self.windows_redone += 1;
        } else {
            self.windows += 1;
        }
        self.iterations += next.iterations;
        self.history.extend(next.history);
        self.qoi_trace.extend(next.qoi_trace);
        self.error_indicator = next.error_indicator;
        self.error_estimate = self.error_estimate.max(next.error_estimate);
        self.converged = next.converged;
        self.worst_interface = next.worst_interface;
        self.worst_interface_aspect = next.worst_interface_aspect;
        self.relaxation = next.relaxation;
    }

    /// How the iterations went, for a stage that did not converge: the mode and what to change.
    pub fn diagnosis(&self, tolerance: f64) -> String {
        match &self.window_check {
            Some(check) if matches!(check.outcome, CheckOutcome::Parted | CheckOutcome::BelowFloor) => {
                check.diagnosis(tolerance, "")
            }
            Some(check) if check.outcome == CheckOutcome::PassNotConverged => {
                check.diagnosis(tolerance, &self.iterations_diagnosis(check.iteration_tolerance))
            }
            _ => self.iterations_diagnosis(tolerance),
        }
    }

    /// How the last iterations went (the history's end): the mode and what to change.
    fn iterations_diagnosis(&self, tolerance: f64) -> String {
        let h = &self.history;
        if h.is_empty() {
            return "no iteration ran".into();
        }
        let window = (h.len() / 5).clamp(1, 100);
        let mean = |s: &[f64]| s.iter().sum::<f64>() / s.len().max(1) as f64;
        let last = mean(&h[h.len().saturating_sub(window)..]);
        let before = mean(&h[h.len().saturating_sub(2 * window)..h.len().saturating_sub(window)]);
        let best = h.iter().copied().fold(f64::INFINITY, f64::min);
        // iterations over time windows sweep less than the interval each
        let windows = if self.sweeps < self.iterations as f64 {
            "another solver.time_window (twice or half this one)"
        } else {
            "time windows (solver.time_window = 1)"
        };
        let place =
            self.worst_interface.as_ref().map_or(String::new(), |i| format!(", largest residual on interface '{i}'"));
        // elements far from cubes widen the range of stiffnesses beyond what one k fits
        let flat = match self.worst_interface_aspect {
            Some(a) if a >= FLAT_ELEMENTS => format!(
                " (its elements are {a:.0} x longer one way than the other: cut them closer to cubes; \
                 docs/performance.md, \"Flat elements along an interface\")"
            ),
            _ => String::new(),
        };
        let advice = if last > 2.0 * best.max(f64::MIN_POSITIVE) && last > before {
            format!(
                "growing: eta {last:.2e} over the last {window} iterations, {best:.2e} at best; lower solver.relaxation (0.5) \
                 or change solver.k0_factor (0.5 or 2)"
            )
        } else if self.relaxation > 0.0 && self.relaxation < 0.5 {
            format!(
                "oscillating: the QoIs went back and forth between iterations, the relaxation was lowered to {:.2}; \
                 try the other solver.scale (single or multi) or another solver.k0_factor",
                self.relaxation
            )
        } else if last > 0.8 * before {
            format!(
                "stalled: eta {before:.2e} -> {last:.2e} over the last {window} iterations; try the other solver.scale \
                 (single or multi), solver.k0_factor (0.5 or 2), {windows} or a coarser time step"
            )
        } else {
            // geometric rate over the last window: iterations still needed to reach the tolerance
            let rate = (last / before).powf(1.0 / window as f64);
            let more = ((tolerance / h.last().copied().unwrap_or(last)).ln() / rate.ln()).ceil().max(0.0);
            format!(
                "still converging (eta x {rate:.4} per iteration): about {more} more iterations; raise --max-iter, \
                 or try {windows}"
            )
        };
        // a windowed stage that stopped early has no answer after that window
        let stopped = self.stopped_in.map_or(String::new(), |w| {
            format!(
                "; it stopped in the time window of steps {}..{} of {}: the steps after {} were never iterated, \
                 their histories follow the starting guess and are no answer",
                w.from, w.to, w.of, w.to
            )
        });
        format!("{advice}{place}{flat}{stopped}")
    }
}

/// The time window a stage stopped in ([`StageReport::stopped_in`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct StoppedIn {
    pub from: usize,
    pub to: usize,
    pub of: usize,
}

/// A quantity of interest as a time series over t_0 .. t_N.
#[derive(Debug, Clone, Serialize)]
pub struct QoiSeries {
    pub name: String,
    pub times: Vec<f64>,
    pub values: Vec<f64>,
}

/// Displacements and velocities of every substructure node at every step (for field output and
/// comparison with the monolithic reference): `[substructure][step][dof]`.
#[derive(Debug, Clone, Default)]
pub struct FieldHistory {
    pub displacement: Vec<Vec<Vec<f64>>>,
    pub velocity: Vec<Vec<Vec<f64>>>,
}

/// Wall-clock split of a solve, in seconds.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Timings {
    pub factorisation: f64,
    /// linear stages, including their macro problems and the transfer of side fields
    pub linear_stage: f64,
    /// local stages, including the error-indicator reduction and the return of the fields
    pub local_stage: f64,
    pub post_processing: f64,
    /// macro problems (right-hand side reduction and solve), part of `linear_stage`
    pub macro_problem: f64,
    /// interface-field exchanges and reductions (including waits on other ranks), part of the
    /// linear and local stages
    pub communication: f64,
}

/// Everything a solve produces.
#[derive(Debug, Clone)]
pub struct SolveReport {
    pub static_stage: Option<StageReport>,
    pub dynamic: StageReport,
    pub solution: InterfaceSolution,
    pub qoi: Vec<QoiSeries>,
    pub fields: Option<FieldHistory>,
    pub timings: Timings,
}

impl SolveReport {
    pub fn converged(&self) -> bool {
        self.dynamic.converged && self.static_stage.as_ref().is_none_or(|s| s.converged)
    }

    pub fn iterations(&self) -> usize {
        self.dynamic.iterations + self.static_stage.as_ref().map_or(0, |s| s.iterations)
    }
}

/// What a solve is asked for beyond the model.
#[derive(Debug, Clone, Default)]
pub struct SolveOptions {
    /// record every node's displacement and velocity at every step
    pub record_fields: bool,
    /// where to count the iterations while they run (read by another thread)
    pub progress: Option<std::sync::Arc<SolveProgress>>,
    /// the warm start is a solution of this very design point (not a neighbour's): its
    /// dynamic stage converges to the tolerance, not to `warm_tolerance_ratio` times it
    pub init_at_this_point: bool,
    /// keep every QoI's history after each dynamic iteration (`StageReport::qoi_trace`)
    pub trace_qois: bool,
}

/// Iterations of a running solve (static and dynamic stages) and the last eta, readable from
/// another thread: a worker pool's heartbeats report them to the coordinator's watchers.
#[derive(Debug, Default)]
pub struct SolveProgress {
    iterations: std::sync::atomic::AtomicU64,
    eta_bits: std::sync::atomic::AtomicU64,
    stop: std::sync::atomic::AtomicBool,
}

impl SolveProgress {
    fn record(&self, eta: f64) {
        use std::sync::atomic::Ordering::Relaxed;
        self.eta_bits.store(eta.to_bits(), Relaxed);
        self.iterations.fetch_add(1, Relaxed);
    }

    /// (iterations so far, last eta); eta is 0 before the first iteration.
    pub fn get(&self) -> (u64, f64) {
        use std::sync::atomic::Ordering::Relaxed;
        (self.iterations.load(Relaxed), f64::from_bits(self.eta_bits.load(Relaxed)))
    }

    /// Asks the solve to stop at the end of its current iteration ([`SolverError::Stopped`]).
    pub fn stop(&self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
    }

    pub fn stop_asked(&self) -> bool {
        self.stop.load(std::sync::atomic::Ordering::Relaxed)
    }
}

/// A LATIN solver over one model: the substructure operators are factorised once in `new` and
/// reused by every `solve` (a warm-started design point does not refactorise).
pub struct LatinSolver<'m, const D: usize> {
    model: &'m Model<D>,
    comm: &'m dyn Communicator,
    dist: Distribution,
    /// operators of this rank's substructures (`None` elsewhere)
    ops: Vec<Option<SubstructureOperators>>,
    /// macro problems of the static and dynamic stages (multiscale only)
    macro_static: Option<MacroProblem>,
    macro_dynamic: Option<MacroProblem>,
    factorisation_seconds: f64,
    /// seconds in macro solves since the last `solve` started
    macro_seconds: f64,
    /// per interface and node, whether the node is a copy of one a wall interface holds twice
    /// (`shared_wall_stage` applies their law; empty when there is none)
    shared_wall: Vec<Vec<bool>>,
    /// the local stage of perfect interfaces whose directions couple their nodes
    along: AlongSolves,
}

/// The factorised operators of a model (substructure operators, macro problems) and where they
/// live: taken out of a solver with [`LatinSolver::into_operators`] and given to the next one with
/// [`LatinSolver::with_operators`], for design points that differ only in interface laws.
pub struct Operators {
    dist: Distribution,
    ops: Vec<Option<SubstructureOperators>>,
    macro_static: Option<MacroProblem>,
    macro_dynamic: Option<MacroProblem>,
    along: AlongSolves,
}

/// Called after each step of a linear stage with (substructure, step, u, v); step 0 is the
/// initial state.
pub type StepRecorder<'a> = &'a mut dyn FnMut(usize, usize, &[f64], &[f64]);

impl<'m, const D: usize> LatinSolver<'m, D> {
    /// A solver on one process.
    pub fn serial(model: &'m Model<D>) -> Result<Self, SolverError> {
        Self::new(model, &crate::comm::Serial)
    }

    /// A solver whose substructures and interfaces are spread over the ranks of `comm`; every
    /// rank calls it with the same model.
    pub fn new(model: &'m Model<D>, comm: &'m dyn Communicator) -> Result<Self, SolverError> {
        let start = Instant::now();
        let with_static = model.needs_static_stage();
        let dist = Distribution::new(model, comm.rank(), comm.size()).map_err(SolverError::Distribution)?;
        let mut ops = (0..model.substructures.len())
            .map(|s| {
                if !dist.owns_substructure(s) {
                    return Ok(None);
                }
                SubstructureOperators::new(model, s, with_static)
                    .map(Some)
                    .map_err(|source| SolverError::Factorisation { substructure: s, source })
            })
            .collect::<Result<Vec<_>, _>>()?;
        let build = |ops: &mut [Option<SubstructureOperators>], stage: Stage| {
            MacroProblem::new(model, ops, stage, comm)
                .map_err(|source| SolverError::Macro { stage: stage.name(), source })
        };
        // The static stage is multiscale at either scale: one step, so its macro problem costs
        // little, and without it the iterations alone carry the assembly's global deformation
        // from substructure to substructure (a cantilever plate cut 16 x 2: 2139 static
        // iterations single-scale, 20 multiscale; docs/performance.md, "Locking, and the static
        // search direction").
        let macro_static = if with_static { Some(build(&mut ops, Stage::Static)?) } else { None };
        let macro_dynamic =
            if model.settings.scale == Scale::Multi { Some(build(&mut ops, Stage::Dynamic)?) } else { None };
        let along = AlongSolves::new(model, &dist)
            .map_err(|(i, source)| SolverError::AlongSystem { interface: model.interfaces[i].name.clone(), source })?;
        let operators = Operators { dist, ops, macro_static, macro_dynamic, along };
        Ok(Self {
            factorisation_seconds: start.elapsed().as_secs_f64(),
            ..Self::with_operators(model, comm, operators)
        })
    }

    /// A solver reusing operators factorised for a model with the same substructures, loads and
    /// search directions (only interface laws may differ); no factorisation is repeated.
    pub fn with_operators(model: &'m Model<D>, comm: &'m dyn Communicator, operators: Operators) -> Self {
        let Operators { dist, ops, macro_static, macro_dynamic, along } = operators;
        Self {
            model,
            comm,
            dist,
            ops,
            macro_static,
            macro_dynamic,
            factorisation_seconds: 0.0,
            macro_seconds: 0.0,
            shared_wall: shared_wall_mask(model),
            along,
        }
    }

    /// Gives the factorised operators back, for the next design point.
    pub fn into_operators(self) -> Operators {
        Operators {
            dist: self.dist,
            ops: self.ops,
            macro_static: self.macro_static,
            macro_dynamic: self.macro_dynamic,
            along: self.along,
        }
    }

    /// One linear stage over the whole time interval: at every step micro problem 1 in each
    /// substructure, then (multiscale) the macro problem and micro problem 2, then the interface
    /// fields `s` and the substructure states.
    ///
    /// `steps` is the whole interval or a time window; `states` (a later window) the
    /// substructures' states at its first step, instead of the stage's initial state.
    fn linear_stage(
        &mut self,
        stage: Stage,
        fields: &mut [InterfaceField],
        u0: &[Option<Vec<f64>>],
        mut record: Option<StepRecorder>,
        steps: Range<usize>,
        states: Option<&[Option<NewmarkState>]>,
    ) {
        let m = self.model;
        let ops = &mut self.ops;
        let mut macro_problem = match stage {
            Stage::Static => self.macro_static.as_mut(),
            Stage::Dynamic => self.macro_dynamic.as_mut(),
        };
        for (s, op) in ops.iter_mut().enumerate().filter_map(|(s, o)| o.as_mut().map(|o| (s, o))) {
            match states.and_then(|st| st[s].as_ref()) {
                Some(state) => op.restore(state),
                None => op.start(m, s, stage, u0[s].as_deref()),
            }
            if let Some(r) = record.as_mut() {
                let (u, v) = op.state();
                r(s, steps.start, u, v);
            }
        }
        for step in steps {
            if let Some(mp) = macro_problem.as_mut() {
                mp.rhs.fill(0.0);
            }
            for (s, op) in ops.iter_mut().enumerate().filter_map(|(s, o)| o.as_mut().map(|o| (s, o))) {
                op.predict(m, s, stage, step, fields);
                if let Some(mp) = macro_problem.as_mut() {
                    mp.add_residual(m, s, stage, step, fields, &op.x);
                }
            }
            if let Some(mp) = macro_problem.as_mut() {
                let t = Instant::now();
                mp.solve(self.comm);
                self.macro_seconds += t.elapsed().as_secs_f64();
            }
            let mp = macro_problem.as_deref();
            let macro_field =
                |i: usize, _side: usize, j: usize, c: usize| mp.map_or(0.0, |mp| mp.field_value(D, i, j, c));
            for (s, op) in ops.iter_mut().enumerate().filter_map(|(s, o)| o.as_mut().map(|o| (s, o))) {
                if let Some(mp) = mp {
                    mp.correct(s, &mut op.x);
                }
                op.finish(m, s, stage, step, fields, &macro_field);
                if let Some(r) = record.as_mut() {
                    let (u, v) = op.state();
                    r(s, step + 1, u, v);
                }
            }
        }
    }

    /// Zero fields for the interfaces this rank holds (rank 0 holds all, to gather results).
    fn zero_stage(&self, steps: usize) -> StageSolution {
        let m = self.model;
        StageSolution {
            interfaces: (0..m.interfaces.len())
                .map(|i| {
                    let itf = &m.interfaces[i];
                    let held = self.dist.rank == 0 || self.dist.holds_interface(m, i);
                    InterfaceField::zeros(itf.sides.len(), if held { steps * itf.n_nodes() * D } else { 0 })
                })
                .collect(),
        }
    }

    fn check_init(&self, stage: &StageSolution, steps: usize, what: &str) -> Result<(), SolverError> {
        let m = self.model;
        if stage.interfaces.len() != m.interfaces.len() {
            return Err(SolverError::IncompatibleInit(format!(
                "{what}: {} interfaces, the model has {}",
                stage.interfaces.len(),
                m.interfaces.len()
            )));
        }
        for (f, itf) in stage.interfaces.iter().zip(&m.interfaces) {
            let len = steps * itf.n_nodes() * D;
            let ok = f.s.len() == itf.sides.len()
                && f.hat.len() == itf.sides.len()
                && f.s.iter().chain(&f.hat).all(|sf| sf.force.len() == len && sf.velocity.len() == len);
            if !ok {
                return Err(SolverError::IncompatibleInit(format!("{what}: interface '{}' has other sizes", itf.name)));
            }
        }
        Ok(())
    }

    /// Solves the model, starting from `init` (a converged neighbour's interface solution) or
    /// from zero interface fields (the paper's "direct" start).
    pub fn solve(
        &mut self,
        init: Option<&InterfaceSolution>,
        options: &SolveOptions,
    ) -> Result<SolveReport, SolverError> {
        let m = self.model;
        let mut timings = Timings { factorisation: self.factorisation_seconds, ..Default::default() };
        self.macro_seconds = 0.0;
        let from = init.and_then(|i| i.static_stage.as_ref());
        let mut prestress = self.prestress(from, m.settings.tolerance, init.is_none(), &mut timings, options)?;
        let mut dynamic = self.dynamic_start(init, prestress.as_ref())?;
        // A warm start begins near in eta but not as near in the solution: it converges tighter
        // (warm_tolerance_ratio, docs/scenes.md; measured in docs/performance.md).
        let from_neighbour = init.is_some() && !options.init_at_this_point;
        let ratio = if from_neighbour { m.settings.warm_tolerance_ratio } else { 1.0 };
        let tolerance = m.settings.tolerance * ratio;
        let checked = m.settings.window_check && m.settings.time_window > 0 && !m.qois.is_empty();
        let mut report = self.dynamic_stage(
            prestress.as_ref(),
            (tolerance, m.settings.time_window, if init.is_none() { Start::Cold } else { Start::Warm }),
            &mut dynamic.interfaces,
            &mut timings,
            options,
        )?;
        if checked && report.converged && report.windows > 1 {
            self.check_windows(tolerance, &mut report, &mut prestress, &mut dynamic.interfaces, &mut timings, options)?;
        }
        let (static_report, static_solution, u0) = match prestress {
            Some(p) => (Some(p.report), Some(p.solution), p.u0),
            None => (None, None, vec![None; m.substructures.len()]),
        };

        // Post-processing sweep on the converged local-stage fields.
        let t = Instant::now();
        let (qoi, fields) = self.post_process(&dynamic.interfaces, &u0, static_solution.as_ref(), options);
        self.dist.gather_interfaces(self.comm, &mut dynamic.interfaces);
        let mut static_solution = static_solution;
        if let Some(st) = static_solution.as_mut() {
            self.dist.gather_interfaces(self.comm, &mut st.interfaces);
        }
        timings.post_processing += t.elapsed().as_secs_f64();
        timings.macro_problem = self.macro_seconds;
        Ok(SolveReport {
            static_stage: static_report,
            dynamic: report,
            solution: InterfaceSolution { static_stage: static_solution, dynamic },
            qoi,
            fields,
            timings,
        })
    }

    /// The static prestress stage, where the model needs one, from `from` (a solution's static
    /// stage) or zero fields, to [`static_tolerance`]: its report, solution
    /// and the displacements it leaves each substructure in (the dynamics' initial state).
    fn prestress(
        &mut self,
        from: Option<&StageSolution>,
        tolerance: f64,
        cold: bool,
        timings: &mut Timings,
        options: &SolveOptions,
    ) -> Result<Option<Prestress>, SolverError> {
        if !self.model.needs_static_stage() {
            return Ok(None);
        }
        let st = match from {
            Some(s) => {
                self.check_init(s, 1, "static stage")?;
                s.clone()
            }
            None => self.zero_stage(1),
        };
        self.iterate_prestress(st, tolerance, cold, timings, options).map(Some)
    }

    /// [`Self::prestress`] from `st` (this rank's fields: the interfaces it owns).
    fn iterate_prestress(
        &mut self,
        mut st: StageSolution,
        tolerance: f64,
        cold: bool,
        timings: &mut Timings,
        options: &SolveOptions,
    ) -> Result<Prestress, SolverError> {
        let m = self.model;
        let start: Vec<Vec<f64>> = m.interfaces.iter().map(|itf| itf.gap0.clone()).collect();
        let mut u0: Vec<Option<Vec<f64>>> = vec![None; m.substructures.len()];
        // The static stage's error is carried by every step of the dynamics, and its
        // iterations cost one step each: it is converged far tighter ([`static_tolerance`]).
        let begin = StageStart {
            stage: Stage::Static,
            tolerance: static_tolerance(tolerance),
            gaps: (&start, &[]),
            u0: &u0,
            statics: None,
            start: if cold { Start::Cold } else { Start::Warm },
            window: 0,
        };
        let report = self.iterate(&begin, &mut st.interfaces, timings, options)?;
        // the initial state of the dynamics: displacements of the converged static solution
        let t = Instant::now();
        let mut scratch = st.interfaces.clone();
        let mut record = |s: usize, step: usize, u: &[f64], _: &[f64]| {
            if step == 1 {
                u0[s] = Some(u.to_vec());
            }
        };
        let none = vec![None; m.substructures.len()];
        self.linear_stage(Stage::Static, &mut scratch, &none, Some(&mut record), 0..1, None);
        timings.post_processing += t.elapsed().as_secs_f64();
        Ok(Prestress { report, solution: st, u0 })
    }

    /// The dynamic stage's fields to start from: `init`'s, or zero; moved by the prestress.
    fn dynamic_start(
        &self,
        init: Option<&InterfaceSolution>,
        prestress: Option<&Prestress>,
    ) -> Result<StageSolution, SolverError> {
        let m = self.model;
        let mut dynamic = match init {
            Some(i) => {
                self.check_init(&i.dynamic, m.steps, "dynamic stage")?;
                i.dynamic.clone()
            }
            None => self.zero_stage(m.steps),
        };
        if let Some(st) = prestress.map(|p| &p.solution) {
            // A cold start holds the prestressed interface forces over the whole interval
            // (velocities zero): the state the assembly is in before loading. A warm start's
            // fields hold its source's static forces at every step: they move by the change of
            // the static stage's (a change of preload otherwise takes hundreds of iterations to
            // cross the interval: bolted joint, prestress 0.028 -> 0.030 mm, 251 -> 57 dynamic
            // iterations at 2e-4, docs/performance.md "Bolted joint").
            match init {
                None => add_static_change(&mut dynamic.interfaces, st, None),
                Some(i) => {
                    if let Some(old) = &i.static_stage {
                        add_static_change(&mut dynamic.interfaces, st, Some(old));
                    }
                }
            }
        }
        Ok(dynamic)
    }

    /// The dynamic stage's iterations from `fields` after `prestress`, to `tolerance` in
    /// windows of `window` steps (0: the whole interval), the fields holding `start`.
    fn dynamic_stage(
        &mut self,
        prestress: Option<&Prestress>,
        (tolerance, window, start): (f64, usize, Start),
        fields: &mut [InterfaceField],
        timings: &mut Timings,
        options: &SolveOptions,
    ) -> Result<StageReport, SolverError> {
        let m = self.model;
        let statics = prestress.map(|p| &p.solution);
        let none = vec![None; m.substructures.len()];
        let u0 = prestress.map_or(&none, |p| &p.u0);
        let (gap_start, vn_start) = self.dynamic_initial_gaps(statics);
        let begin =
            StageStart { stage: Stage::Dynamic, tolerance, gaps: (&gap_start, &vn_start), u0, statics, start, window };
        self.iterate(&begin, fields, timings, options)
    }

    /// Gap and relative normal velocity at t_0, per interface node.
    fn dynamic_initial_gaps(&self, statics: Option<&StageSolution>) -> (Vec<Vec<f64>>, Vec<Vec<f64>>) {
        let m = self.model;
        let mut gaps = Vec::new();
        let mut vns = Vec::new();
        for (i, itf) in m.interfaces.iter().enumerate() {
            let n = itf.n_nodes();
            let mut g = itf.gap0.clone();
            let mut vn = vec![0.0; n];
            for j in 0..n {
                let nrm = &itf.normal[j];
                let side_vel = |k: usize| -> [f64; D] {
                    itf.sides.get(k).map_or([0.0; D], |s| m.substructures[s.substructure].initial_velocity)
                };
                let (v1, v2) = (side_vel(0), side_vel(1));
                vn[j] = (0..D).map(|c| nrm[c] * (v2[c] - v1[c])).sum();
                if let (Some(st), true) = (statics, self.dist.owns_interface(i)) {
                    let hat = &st.interfaces[i].hat;
                    for c in 0..D {
                        let u1 = hat[0].velocity[j * D + c];
                        let u2 = hat.get(1).map_or(0.0, |h| h.velocity[j * D + c]);
                        g[j] += nrm[c] * (u2 - u1);
                    }
                }
            }
            gaps.push(g);
            vns.push(vn);
        }
        (gaps, vns)
    }

    /// eta's numerator and denominator on every interface this rank owns (zeros elsewhere), then
    /// the stop flag: a stop asked of any rank, summed with the errors so that all stop together.
    fn eta_parts(
        &self,
        stage: Stage,
        fields: &[InterfaceField],
        steps: Range<usize>,
        stop: bool,
        parts: &mut Vec<f64>,
    ) {
        let m = self.model;
        parts.clear();
        parts.resize(2 * m.interfaces.len() + 1, 0.0);
        for i in (0..m.interfaces.len()).filter(|&i| self.dist.owns_interface(i)) {
            let (num, den) = interface_error(m, stage, i, &fields[i], steps.clone());
            parts[2 * i] = num;
            parts[2 * i + 1] = den;
        }
        parts[2 * m.interfaces.len()] = if stop { 1.0 } else { 0.0 };
    }

    /// Local stage over every interface and node, at the steps `steps`, from the nodes' `memory`
    /// at the first of them ([`Self::initial_memory`] at t_0); leaves the memory after the last
    /// in `out` (empty for interfaces another rank owns).
    fn local_stage(
        &self,
        stage: Stage,
        fields: &mut [InterfaceField],
        steps: Range<usize>,
        memory: &[Vec<NodeMemory>],
        out: &mut [Vec<NodeMemory>],
    ) {
        let m = self.model;
        let rule = GapRule {
            weight: match stage {
                Stage::Static => 1.0,
                Stage::Dynamic => m.newmark.new_velocity_weight(m.dt),
            },
            dt: m.dt,
            carry: m.newmark.old_velocity_weight(m.dt),
        };
        for (i, itf) in m.interfaces.iter().enumerate() {
            out[i].clear();
            if !self.dist.owns_interface(i) {
                continue;
            }
            let n = itf.n_nodes();
            let h1 = stage.k(&itf.sides[0]).inverse();
            // a rigid wall takes no velocity change: zero compliance
            let h2 = itf.sides.get(1).map_or(SearchDirection::isotropic(0.0), |s| stage.k(s).inverse());
            let f = &mut fields[i];
            let node_memory = &mut out[i];
            node_memory.extend_from_slice(&memory[i]);
            if self.along.local_stage(m, stage, i, f, steps.clone()) {
                continue;
            }
            let law = match stage {
                Stage::Static => itf.law,
                Stage::Dynamic => itf.law.in_dynamics(),
            };
            for step in steps.clone() {
                for (j, memory) in node_memory.iter_mut().enumerate() {
                    // (the copies of a node a wall interface holds twice: their law below, at once)
                    if self.shared_wall.get(i).is_some_and(|s| s[j]) {
                        continue;
                    }
                    let at = |v: &[f64]| -> [f64; D] {
                        let mut out = [0.0; D];
                        out.copy_from_slice(&v[(step * n + j) * D..(step * n + j + 1) * D]);
                        out
                    };
                    let (w2, f2) = match f.s.get(1) {
                        Some(s2) => (at(&s2.velocity), at(&s2.force)),
                        None => ([0.0; D], [0.0; D]),
                    };
                    let input = NodeInput {
                        w1: at(&f.s[0].velocity),
                        f1: at(&f.s[0].force),
                        w2,
                        f2,
                        h1,
                        h2,
                        normal: itf.normal[j],
                    };
                    let out = apply_law(law, &input, rule, memory);
                    let r = (step * n + j) * D..(step * n + j + 1) * D;
                    f.hat[0].velocity[r.clone()].copy_from_slice(&out.w1);
                    f.hat[0].force[r.clone()].copy_from_slice(&out.f1);
                    if let Some(h) = f.hat.get_mut(1) {
                        h.velocity[r.clone()].copy_from_slice(&out.w2);
                        h.force[r].copy_from_slice(&out.f2);
                    }
                }
            }
        }
        self.shared_wall_stage(stage, fields, steps, rule, out);
    }

    /// The law at the nodes a wall interface holds twice or more ([`Model::shared_wall_nodes`]),
    /// on each node's total force, one velocity for all its copies (c: area a_c, direction k_c):
    /// the copies make one node of area A = sum a_c, direction K = sum a_c k_c / A, force
    /// F = sum a_c F_c / A and velocity W = K^-1 sum a_c k_c W_c / A, since F^ - F = K (W^ - W)
    /// is then the sum of the copies' F^_c - F_c = k_c (W^ - W_c). The law gives F^ and W^ there;
    /// each copy takes W^ and F^_c (so that sum a_c F^_c = A F^): the copies are tied as a
    /// perfect interface ties them (the model drops the node from those). The first copy's
    /// memory is the node's, copied to the others.
    fn shared_wall_stage(
        &self,
        stage: Stage,
        fields: &mut [InterfaceField],
        steps: Range<usize>,
        rule: GapRule,
        out: &mut [Vec<NodeMemory>],
    ) {
        let m = self.model;
        for group in m.shared_wall_nodes.iter().filter(|g| self.dist.owns_interface(g[0].0)) {
            let (i0, j0) = group[0];
            let law = match stage {
                Stage::Static => m.interfaces[i0].law,
                Stage::Dynamic => m.interfaces[i0].law.in_dynamics(),
            };
            let area: f64 = group.iter().map(|&(i, j)| m.interfaces[i].area[j]).sum();
            let mut normal = [0.0; D];
            for &(i, j) in group {
                let itf = &m.interfaces[i];
                (0..D).for_each(|c| normal[c] += itf.area[j] * itf.normal[j][c]);
            }
            let length = normal.iter().map(|x| x * x).sum::<f64>().sqrt();
            if length > 0.0 {
                normal.iter_mut().for_each(|x| *x /= length);
            } else {
                // (copies facing opposite ways, an edge folded flat: the first copy's)
                normal = m.interfaces[i0].normal[j0];
            }
            let k = |i: usize| stage.k(&m.interfaces[i].sides[0]);
            let share = |i: usize, j: usize| m.interfaces[i].area[j] / area;
            let node = SearchDirection {
                normal: group.iter().map(|&(i, j)| share(i, j) * k(i).normal).sum(),
                tangential: group.iter().map(|&(i, j)| share(i, j) * k(i).tangential).sum(),
            };
            let mut memory = out[i0][j0];
            for step in steps.clone() {
                let at = |i: usize, j: usize| (step * m.interfaces[i].n_nodes() + j) * D;
                let (mut force, mut kw) = ([0.0; D], [0.0; D]);
                for &(i, j) in group {
                    let (s, a) = (&fields[i].s[0], share(i, j));
                    let w: [f64; D] = std::array::from_fn(|c| s.velocity[at(i, j) + c]);
                    let kw_c = k(i).apply(&normal, &w);
                    for c in 0..D {
                        force[c] += a * s.force[at(i, j) + c];
                        kw[c] += a * kw_c[c];
                    }
                }
                let input = NodeInput {
                    w1: node.inverse().apply(&normal, &kw),
                    f1: force,
                    w2: [0.0; D],
                    f2: [0.0; D],
                    h1: node.inverse(),
                    h2: SearchDirection::isotropic(0.0),
                    normal,
                };
                let hat = apply_law(law, &input, rule, &mut memory);
                for &(i, j) in group {
                    let f = &mut fields[i];
                    let r = at(i, j)..at(i, j) + D;
                    let w: [f64; D] = std::array::from_fn(|c| f.s[0].velocity[r.start + c]);
                    let dk = k(i).apply(&normal, &std::array::from_fn(|c| hat.w1[c] - w[c]));
                    let force: [f64; D] = std::array::from_fn(|c| f.s[0].force[r.start + c] + dk[c]);
                    f.hat[0].velocity[r.clone()].copy_from_slice(&hat.w1);
                    f.hat[0].force[r].copy_from_slice(&force);
                }
            }
            for &(i, j) in group {
                out[i][j] = memory;
            }
        }
    }

    /// Every interface node's memory at t_0 of a stage: the gap, and in dynamics the gap carried
    /// a step on at the initial normal velocity (half a step for the trapezoidal rule).
    fn initial_memory(&self, stage: Stage, gap_start: &[Vec<f64>], vn_start: &[Vec<f64>]) -> Vec<Vec<NodeMemory>> {
        let carry = self.model.newmark.old_velocity_weight(self.model.dt);
        gap_start
            .iter()
            .enumerate()
            .map(|(i, g)| match stage {
                Stage::Static => g.iter().map(|&g| NodeMemory::new(g)).collect(),
                Stage::Dynamic => g.iter().zip(&vn_start[i]).map(|(g, vn)| NodeMemory::new(g + carry * vn)).collect(),
            })
            .collect()
    }
}

/// The static prestress stage's outcome: its report, its solution, and the displacements it
/// leaves each substructure in (the dynamics' initial state).
#[derive(Clone)]
struct Prestress {
    report: StageReport,
    solution: StageSolution,
    u0: Vec<Option<Vec<f64>>>,
}

/// What a stage starts from, and the tolerance it is held to.
#[derive(Clone, Copy)]
struct StageStart<'a> {
    stage: Stage,
    tolerance: f64,
    /// the gap and the relative normal velocity at t_0 of every interface node
    gaps: (&'a [Vec<f64>], &'a [Vec<f64>]),
    /// each substructure's initial displacements (the prestressed state), where there are
    u0: &'a [Option<Vec<f64>>],
    /// the static stage's solution (the force QoIs' values at t_0)
    statics: Option<&'a StageSolution>,
    /// what the fields hold at the start: where a later time window starts
    start: Start,
    /// steps per time window (0: the whole interval at once)
    window: usize,
}

/// What a stage's fields hold when its iterations start, which decides where a later time
/// window starts (the windows before it converged; its own steps still hold the start's values).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Start {
    /// zero fields: the window starts from the last converged step, held
    Cold,
    /// another solution's histories (a neighbour's, or one saved): the window starts from the
    /// last converged step moved as that solution moves over the window (from the solution's
    /// own values the window started 1.12 x the work of a cold start, in windows of one step)
    Warm,
    /// an answer being iterated on (a check's pass): the window starts from its values
    Continued,
}

/// Copies `from` into `to`, keeping `to`'s buffers where they are long enough.
pub(crate) fn copy_rows(to: &mut Vec<Vec<f64>>, from: &[Vec<f64>]) {
    to.resize_with(from.len(), Vec::new);
    for (t, f) in to.iter_mut().zip(from) {
        t.clear();
        t.extend_from_slice(f);
    }
}

/// The relative displacement of an interface node's sides (side b's less side a's; a wall does
/// not move) accumulated during the dynamics, integrated from the local-stage velocities as the
/// bodies' displacements are (Newmark's rule): steps + 1 values, the first 0.
pub(crate) fn relative_displacement<const D: usize>(
    m: &Model<D>,
    f: &InterfaceField,
    interface: usize,
    node: usize,
) -> Vec<[f64; D]> {
    relative_displacement_over(m, f, interface, node, 0..m.steps + 1, [0.0; D])
}

/// [`relative_displacement`]'s values `values` (indices from 0, the initial state), from
/// `before`, the value at `values.start - 1` (unused where `values` starts at 0): the same sums
/// in the same order, so a window's iterations may take the values before it once.
pub(crate) fn relative_displacement_over<const D: usize>(
    m: &Model<D>,
    f: &InterfaceField,
    interface: usize,
    node: usize,
    values: Range<usize>,
    before: [f64; D],
) -> Vec<[f64; D]> {
    let itf = &m.interfaces[interface];
    let n = itf.n_nodes();
    let velocity = |step: Option<usize>| -> [f64; D] {
        std::array::from_fn(|c| match step {
            Some(s) => {
                let idx = (s * n + node) * D + c;
                f.hat.get(1).map_or(0.0, |h| h.velocity[idx]) - f.hat[0].velocity[idx]
            }
            None => {
                let v =
                    |k: usize| itf.sides.get(k).map_or(0.0, |sd| m.substructures[sd.substructure].initial_velocity[c]);
                v(1) - v(0)
            }
        })
    };
    let mut rel = before;
    let mut out = Vec::with_capacity(values.len());
    // value j is the end of step j - 1, which starts from the end of step j - 2 (value 0, the
    // initial state, from the initial velocities)
    let mut prev = velocity(values.start.checked_sub(2));
    for value in values {
        if value == 0 {
            rel = [0.0; D];
            out.push(rel);
            continue;
        }
        let cur = velocity(Some(value - 1));
        for c in 0..D {
            rel[c] += m.newmark.displacement_increment(m.dt, prev[c], cur[c]);
        }
        out.push(rel);
        prev = cur;
    }
    out
}

/// The LATIN error indicator (docs/method.md 3), in parts: computed per interface by its owner
/// inside `iterate`, then [`error_indicator_from_parts`]:
/// eta^2 = sum a [|F - F^|^2 / k + k |W - W^|^2] / sum a [|F + F^|^2 / k + k |W + W^|^2]
/// over interface nodes, sides and steps.
///
/// This function: the numerator and denominator on one interface.
fn interface_error<const D: usize>(
    m: &Model<D>,
    stage: Stage,
    i: usize,
    f: &InterfaceField,
    steps: Range<usize>,
) -> (f64, f64) {
    let itf = &m.interfaces[i];
    let n = itf.n_nodes();
    let (mut num, mut den) = (0.0, 0.0);
    for (k, side) in itf.sides.iter().enumerate() {
        let kk = stage.k(side);
        let hh = kk.inverse();
        let (s, h) = (&f.s[k], &f.hat[k]);
        for at in (steps.start * n * D..steps.end * n * D).step_by(D) {
            let j = (at / D) % n;
            let (a, nrm) = (itf.area[j], &itf.normal[j]);
            let df: [f64; D] = std::array::from_fn(|c| s.force[at + c] - h.force[at + c]);
            let dw: [f64; D] = std::array::from_fn(|c| s.velocity[at + c] - h.velocity[at + c]);
            let sf: [f64; D] = std::array::from_fn(|c| s.force[at + c] + h.force[at + c]);
            let sw: [f64; D] = std::array::from_fn(|c| s.velocity[at + c] + h.velocity[at + c]);
            num += a * (hh.energy(nrm, &df) + kk.energy(nrm, &dw));
            den += a * (hh.energy(nrm, &sf) + kk.energy(nrm, &sw));
        }
    }
    (num, den)
}

/// Per interface and node, whether the node is in one of `model.shared_wall_nodes`' groups;
/// empty when there is none.
fn shared_wall_mask<const D: usize>(model: &Model<D>) -> Vec<Vec<bool>> {
    if model.shared_wall_nodes.is_empty() {
        return Vec::new();
    }
    let mut mask: Vec<Vec<bool>> = model.interfaces.iter().map(|itf| vec![false; itf.n_nodes()]).collect();
    for &(i, j) in model.shared_wall_nodes.iter().flatten() {
        mask[i][j] = true;
    }
    mask
}

/// eta from per-interface (numerator, denominator) pairs, summed in interface order so that the
/// result does not depend on how interfaces are spread over ranks.
fn error_indicator_from_parts(parts: &[f64]) -> f64 {
    let (num, den) = parts.chunks(2).fold((0.0, 0.0), |(a, b), p| (a + p[0], b + p[1]));
    if den == 0.0 {
        // nothing moves and nothing is loaded: the zero solution is exact
        return if num == 0.0 { 0.0 } else { f64::INFINITY };
    }
    (num / den).sqrt()
}

/// Adds `new - old` static interface forces (`old` none: zero) to every step of the dynamic
/// fields, on both LATIN spaces; interfaces with no static fields (or another size) are left.
fn add_static_change(dynamic: &mut [InterfaceField], new: &StageSolution, old: Option<&StageSolution>) {
    for (k, (f, n)) in dynamic.iter_mut().zip(&new.interfaces).enumerate() {
        let o = match old.map(|o| o.interfaces.get(k)) {
            Some(None) => continue,
            Some(Some(o)) => Some(o),
            None => None,
        };
        let per_step = n.len();
        if per_step == 0 || f.is_empty() || o.is_some_and(|o| o.len() != per_step) {
            continue;
        }
        for (space, (sides, new_sides)) in [(&mut f.s, &n.s), (&mut f.hat, &n.hat)].into_iter().enumerate() {
            for (side_index, (side, ns)) in sides.iter_mut().zip(new_sides).enumerate() {
                let os = o.map(|o| if space == 0 { &o.s[side_index] } else { &o.hat[side_index] });
                for chunk in side.force.chunks_mut(per_step) {
                    for (j, x) in chunk.iter_mut().enumerate() {
                        *x += ns.force[j] - os.map_or(0.0, |os| os.force[j]);
                    }
                }
            }
        }
    }
}
