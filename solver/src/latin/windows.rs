//! A stage's iterations in time windows (docs/method.md, "Time windows"): each window iterated
//! until its estimate is within its share of the tolerance, the next one started from its
//! converged end; a whole interval is one window. One LATIN iteration is `iterate_window`'s loop.

use super::*;

impl<'m, const D: usize> LatinSolver<'m, D> {
    /// LATIN iterations of one stage until the error indicator is below the tolerance: over the
    /// whole time interval at once (the paper's way), or window after window when the scene asks
    /// for time windows (docs/method.md, "Time windows").
    pub(super) fn iterate(
        &mut self,
        begin: &StageStart,
        fields: &mut [InterfaceField],
        timings: &mut Timings,
        options: &SolveOptions,
    ) -> Result<StageReport, SolverError> {
        let m = self.model;
        let StageStart { stage, tolerance, gaps: (gap_start, vn_start), u0, start, .. } = *begin;
        let steps = stage.steps(m);
        let length = match begin.window {
            0 => steps,
            w => w.min(steps),
        };
        let mut window = Window {
            steps: 0..length,
            states: None,
            memory: self.initial_memory(stage, gap_start, vn_start),
            body: BodyQois::new(m),
        };
        let mut report = StageReport::default();
        let mut it = Iterations::new(m, fields, timings, options);
        // a warm start's histories, which each later window's start follows
        let initial = (start == Start::Warm && length < steps).then(|| fields.to_vec());
        // Each window's error is carried to the end of the interval and adds to the later
        // windows' (a slip is a sum): the QoI estimate's tolerance is shared out between the
        // windows (a share by the square root of their number let the brass block's histories
        // at dt / 10 end 1.3 x the tolerance off); eta, a guard, is held to a tenth of it (its
        // share too kept the 3D block's first window from converging at 1e-5):
        // docs/performance.md, "Time windows".
        let windows = steps.div_ceil(length);
        let window_tolerance = if windows > 1 {
            let share = WINDOW_TOLERANCE_RATIO * tolerance;
            (share, share / windows as f64)
        } else {
            (tolerance, tolerance)
        };
        // each accepted window's QoI errors (absolute: estimate x the norm it was measured
        // against); together they may spend share.0 of each QoI's whole history
        let mut spent: Vec<Vec<f64>> = Vec::new();
        // windows accepted after stalling, and where their errors sit in `spent`
        let mut stalled: Vec<(Window, usize)> = Vec::new();
        // once a stalled window is iterated again: every QoI measured against at least its
        // whole history's norm
        let mut floors: Option<Vec<f64>> = None;
        loop {
            let stall_at = (window.steps.end < steps && floors.is_none() && !m.qois.is_empty())
                .then(|| STALL_ITERATIONS + STALL_PER_STEP * window.steps.len());
            let earlier: Vec<f64> = (0..m.qois.len()).map(|q| spent.iter().map(|e| e[q]).sum()).collect();
            let rule = WindowRule {
                tolerance: window_tolerance.0,
                estimate_tolerance: window_tolerance.1,
                stall_at,
                floors: floors.as_deref(),
                // the last window sees the whole histories: it may spend what the others left
                budget: (windows > 1 && window.steps.end == steps && !m.qois.is_empty())
                    .then_some((window_tolerance.0, earlier.as_slice())),
                // the solve's own windowing, when it is the whole interval (a windowed solve's
                // check iterates in another windowing and checks itself: window_check.rs)
                tighten: stage == Stage::Dynamic
                    && windows == 1
                    && begin.window == m.settings.time_window
                    && m.settings.whole_interval_check
                    && !m.qois.is_empty(),
            };
            let end = self.iterate_window(begin, rule, &window, fields, &mut it)?;
            let mut part = end.report;
            tracing::debug!(steps = ?window.steps, part.iterations, part.stalled, part.error_estimate, "window ended");
            if part.stalled {
                // accepted for now: judged with the whole histories below
                stalled.push((window.clone(), spent.len()));
                part.converged = true;
                part.error_estimate = 0.0;
                report.windows_stalled += 1;
            }
            spent.push(end.errors.iter().zip(&end.scales).map(|(e, s)| e * s).collect());
            report.scales = end.scales.clone();
            let check = part.window_check.take();
            report.append(part, window.steps.len() as f64 / steps as f64, floors.is_some() && stalled.is_empty());
            report.window_check = report.window_check.take().or(check);
            if report.converged && window.steps.end == steps && windows > 1 && !m.qois.is_empty() {
                // The whole histories are known: the windows' errors together must fit
                // share.0 of each. If they do not, the first stalled window is iterated again
                // from where it stopped, and the windows after it from their converged fields.
                let total: Vec<f64> = (0..m.qois.len()).map(|q| spent.iter().map(|e| e[q]).sum()).collect();
                let fits = total.iter().zip(&end.scales).all(|(e, s)| *e <= window_tolerance.0 * s);
                if !fits && !stalled.is_empty() {
                    let (again, at) = stalled.swap_remove(0);
                    window = again;
                    spent.truncate(at);
                    stalled.clear();
                    floors = Some(end.scales.clone());
                    continue;
                }
                // (each window met its share of a prefix no larger than the whole history, so
                // this holds but for the norms' floors; what is reported is the sum)
                report.error_estimate = total.iter().zip(&end.scales).map(|(e, s)| e / s).fold(0.0, f64::max);
                report.converged = report.error_estimate <= tolerance;
            }
            if !report.converged || window.steps.end == steps {
                if !report.converged && window.steps.end < steps {
                    report.stopped_in = Some(StoppedIn { from: window.steps.start, to: window.steps.end, of: steps });
                }
                return Ok(report);
            }
            let t = Instant::now();
            let ended = window.steps.end;
            let next = ended..(ended + length).min(steps);
            window = self.next_window(stage, fields, u0, &window, end.memory, next.clone());
            // (a window iterated again starts the next from its converged fields, not moved ones)
            if floors.is_none() && (initial.is_some() || start == Start::Cold) {
                start_window(fields, initial.as_deref(), steps, ended, next.end);
            }
            it.timings.linear_stage += t.elapsed().as_secs_f64();
        }
    }

    /// The window of steps `next`, which starts where `window` ends: the substructures' states
    /// from a sweep over the converged fields (what the post-processing sweep will find), the
    /// nodes' `memory` from its last local stage.
    pub(super) fn next_window(
        &mut self,
        stage: Stage,
        fields: &mut [InterfaceField],
        u0: &[Option<Vec<f64>>],
        window: &Window,
        memory: Vec<Vec<NodeMemory>>,
        next: Range<usize>,
    ) -> Window {
        // The sweep writes the window's `s` values: they are kept and put back (a copy of every
        // field for each window cost O(steps) a window, most of a solve in windows of one step).
        let at = Self::window_values(self.model, &window.steps);
        let kept: Vec<Vec<[Vec<f64>; 2]>> = fields
            .iter()
            .zip(&at)
            .map(|(f, at)| {
                let part = |v: &[f64]| v.get(at.clone()).map_or_else(Vec::new, <[f64]>::to_vec);
                f.s.iter().map(|side| [part(&side.force), part(&side.velocity)]).collect()
            })
            .collect();
        let mut body = window.body.clone();
        let mut record = |s: usize, step: usize, u: &[f64], v: &[f64]| body.record(s, step, u, v);
        let range = window.steps.clone();
        self.linear_stage(stage, fields, u0, Some(&mut record), range, window.states.as_deref());
        for ((f, at), kept) in fields.iter_mut().zip(&at).zip(kept) {
            for (side, [force, velocity]) in f.s.iter_mut().zip(kept).filter(|(_, [force, _])| !force.is_empty()) {
                side.force[at.clone()].copy_from_slice(&force);
                side.velocity[at.clone()].copy_from_slice(&velocity);
            }
        }
        let states = self.ops.iter().map(|o| o.as_ref().map(SubstructureOperators::save)).collect();
        Window { steps: next, states: Some(states), memory, body }
    }

    /// LATIN iterations of one stage over one time window (or the whole interval) until the
    /// error indicator is below the tolerance; returns the report and the nodes' memory at
    /// the window's end.
    /// The tolerances: eta's and the QoI estimate's.
    pub(super) fn iterate_window(
        &mut self,
        begin: &StageStart,
        rule: WindowRule,
        window: &Window,
        fields: &mut [InterfaceField],
        it: &mut Iterations,
    ) -> Result<WindowEnd, SolverError> {
        let m = self.model;
        let StageStart { stage, u0, statics, .. } = *begin;
        let WindowRule { mut tolerance, mut estimate_tolerance, stall_at, floors, budget, tighten } = rule;
        let mut tightening = tighten.then(|| Tightening::new(tolerance, m.dt));
        let progress = it.options.progress.as_deref();
        let mut report = StageReport::default();
        let stage_name = stage.name();
        let (mut estimator, mut relaxation) = Self::followers(m, window, floors, it);
        // the interface with the largest share of eta at the last iteration
        let mut worst = None;
        // the QoIs are followed up to the window's end (later steps are not computed yet)
        let known = window.steps.end + 1;
        let at = Self::window_values(m, &window.steps);
        let mut limit = stage.iteration_limit(m);
        for iteration in 1.. {
            if iteration > limit {
                break;
            }
            let t = Instant::now();
            it.keep_previous(fields, &at);
            // (the linear stage records all the window's values at each iteration)
            if iteration == 1 {
                it.body.copy_from(&window.body);
            }
            let body = &mut it.body;
            let mut record = |s: usize, step: usize, u: &[f64], v: &[f64]| body.record(s, step, u, v);
            let dynamic = stage == Stage::Dynamic;
            self.linear_stage(
                stage,
                fields,
                u0,
                dynamic.then_some(&mut record as StepRecorder),
                window.steps.clone(),
                window.states.as_deref(),
            );
            // relaxation (mu = 1 at the first iteration)
            if iteration > 1 {
                self.relax(fields, &it.previous, relaxation.mu(), &at);
            }
            let c = Instant::now();
            self.dist.send_sides_to_owners(self.comm, m, fields, window.steps.clone());
            it.timings.communication += c.elapsed().as_secs_f64();
            it.timings.linear_stage += t.elapsed().as_secs_f64();
            let t = Instant::now();
            self.local_stage(stage, fields, window.steps.clone(), &window.memory, &mut it.memory);
            let partial = &mut it.partial;
            let stop = progress.is_some_and(SolveProgress::stop_asked);
            self.eta_parts(stage, fields, window.steps.clone(), stop, partial);
            let c = Instant::now();
            self.comm.sum_in_place(partial);
            if partial.pop().is_some_and(|stop| stop > 0.0) {
                return Err(SolverError::Stopped { stage: stage_name, iteration });
            }
            let eta = error_indicator_from_parts(partial);
            worst = (0..m.interfaces.len()).max_by(|&a, &b| partial[2 * a].total_cmp(&partial[2 * b]));
            self.dist.send_hats_to_sides(self.comm, m, fields, window.steps.clone());
            it.timings.communication += c.elapsed().as_secs_f64();
            it.timings.local_stage += t.elapsed().as_secs_f64();
            report.iterations = iteration;
            report.error_indicator = eta;
            report.history.push(eta);
            // The static stage is one step, converged far tighter than asked; the dynamic stage
            // stops on the QoIs' estimated error (stopping.rs).
            report.error_estimate = if dynamic {
                let scales = self.qoi_values(fields, statics, &it.body, &window.steps, &mut it.qois);
                let series = &mut it.qois.values;
                // a non-finite QoI would pass the estimate's comparisons (NaN changes): refuse it
                // (a non-finite eta is reported below, as such)
                if eta.is_finite()
                    && let Some(q) = first_non_finite(series, &it.qois.computed)
                {
                    let qoi = m.qois[q].name.clone();
                    return Err(SolverError::NonFiniteQoi { stage: stage_name, iteration, qoi });
                }
                series.iter_mut().for_each(|v| v.truncate(known));
                let estimate = estimator.update(series, &scales, eta);
                relaxation.update(series, &scales);
                if it.options.trace_qois {
                    report.qoi_trace.push(series.clone());
                }
                estimate
            } else {
                eta
            };
            if let Some(p) = progress {
                p.record(eta);
            }
            tracing::debug!(stage = stage_name, iteration, eta, estimate = report.error_estimate, "LATIN iteration");
            if !eta.is_finite() {
                return Err(SolverError::NonFinite { stage: stage_name, iteration, eta });
            }
            if eta <= tolerance && (report.error_estimate <= estimate_tolerance || within_budget(budget, &estimator)) {
                if let Some(t) = tightening.as_mut() {
                    if let Some(next) = t.reached(iteration, tolerance, &it.qois.values, &m.qois, estimator.scales()) {
                        // on, a tenth tighter; the first time, with iterations to spare
                        limit = if t.check.passes == 1 { iteration + stage.iteration_limit(m) } else { limit };
                        (tolerance, estimate_tolerance) = (next, estimate_tolerance * next / tolerance);
                        continue;
                    }
                    report.error_estimate = t.check.discrepancy;
                }
                report.converged = tightening.as_ref().is_none_or(|t| t.check.outcome == CheckOutcome::Agreed);
                break;
            }
            if stall_at.is_some_and(|at| iteration >= at) && eta <= tolerance {
                report.stalled = true;
                break;
            }
        }
        report.relaxation = relaxation.mu();
        Ok(self.window_end(report, worst, tightening, &estimator, it))
    }

    /// What follows a window's QoIs from iteration to iteration: the stopping test's estimator and
    /// the relaxation. The QoIs' values before the window's first step do not change while it is
    /// iterated: both sum from there on, and the fields' sums outside it are taken once.
    fn followers(
        m: &Model<D>,
        window: &Window,
        floors: Option<&[f64]>,
        it: &mut Iterations,
    ) -> (ErrorEstimator, Relaxation) {
        let units = || m.qois.iter().map(|q| q.target.unit()).collect::<Vec<_>>();
        it.qois.new_window();
        (
            ErrorEstimator::new(units())
                .with_floors(floors.map(<[f64]>::to_vec).unwrap_or_default())
                .from_step(window.steps.start),
            Relaxation::new(m.settings.relaxation, units()).from_step(window.steps.start),
        )
    }

    /// Each interface's values of the window's steps: what an iteration changes.
    pub(super) fn window_values(m: &Model<D>, steps: &Range<usize>) -> Vec<Range<usize>> {
        m.interfaces.iter().map(|itf| steps.start * itf.n_nodes() * D..steps.end * itf.n_nodes() * D).collect()
    }

    /// Relaxes the new fields toward the last iteration's (`previous`) by `mu` at the window's
    /// values `at`, on the sides this rank computed.
    pub(super) fn relax(
        &self,
        fields: &mut [InterfaceField],
        previous: &[Vec<SideField>],
        mu: f64,
        at: &[Range<usize>],
    ) {
        for (i, (f, p)) in fields.iter_mut().zip(previous).enumerate() {
            for (k, (side, old)) in f.s.iter_mut().zip(p).enumerate() {
                if self.dist.owns_substructure(self.model.interfaces[i].sides[k].substructure) {
                    side.relax_from(old, mu, at[i].clone());
                }
            }
        }
    }

    /// A window's report completed (the interface with the largest share of eta, `worst`, and
    /// the check's outcome), with the nodes' memory and the QoIs' errors it ends with.
    pub(super) fn window_end(
        &self,
        mut report: StageReport,
        worst: Option<usize>,
        tightening: Option<Tightening>,
        estimator: &ErrorEstimator,
        it: &Iterations,
    ) -> WindowEnd {
        let m = self.model;
        report.worst_interface = worst.map(|i| m.interfaces[i].name.clone());
        // geometry for the diagnosis, which only a window that did not converge needs
        if !report.converged {
            report.worst_interface_aspect = worst.and_then(|i| m.interfaces[i].element_aspect(&m.substructures));
        }
        if let Some(t) = tightening {
            report.window_check = t.end(&mut report);
        }
        WindowEnd { report, memory: it.memory.clone(), errors: estimator.errors(), scales: estimator.scales().to_vec() }
    }
}

/// A time window of a stage: its steps, and at its first one the substructures' states (`None`:
/// the stage's initial state) and the nodes' memory; the body QoIs recorded before it.
#[derive(Clone)]
pub(super) struct Window {
    pub(super) steps: Range<usize>,
    pub(super) states: Option<Vec<Option<NewmarkState>>>,
    pub(super) memory: Vec<Vec<NodeMemory>>,
    pub(super) body: BodyQois,
}

/// A stage's iterations in progress: what the solve asks, its clock, and the buffers every
/// iteration works in, allocated once per stage so that an iteration allocates nothing of the
/// interval's size (issue 26; docs/performance.md, "An iteration that does not allocate").
pub(super) struct Iterations<'r> {
    pub(super) options: &'r SolveOptions,
    pub(super) timings: &'r mut Timings,
    /// `s` as the last iteration left it, the relaxation's old values (each iteration copies
    /// only its window's steps)
    pub(super) previous: Vec<Vec<SideField>>,
    /// the body QoIs: the window's, then those this iteration's linear stage records
    pub(super) body: BodyQois,
    /// per interface, the nodes' memory after the last local stage
    pub(super) memory: Vec<Vec<NodeMemory>>,
    /// per interface eta's numerator and denominator, then the stop flag: one reduction
    pub(super) partial: Vec<f64>,
    /// every QoI's history ([`LatinSolver::qoi_values`])
    pub(super) qois: QoiValues,
}

impl<'r> Iterations<'r> {
    /// Copies `fields`' `s` at the window's values `at` (per interface) into `previous`: it holds
    /// every value once, and a copy of the whole interval per iteration would cost O(steps) in
    /// a window's loop.
    pub(super) fn keep_previous(&mut self, fields: &[InterfaceField], at: &[Range<usize>]) {
        for ((f, p), at) in fields.iter().zip(self.previous.iter_mut()).zip(at) {
            for (side, old) in f.s.iter().zip(p.iter_mut()).filter(|(side, _)| !side.force.is_empty()) {
                old.force[at.clone()].copy_from_slice(&side.force[at.clone()]);
                old.velocity[at.clone()].copy_from_slice(&side.velocity[at.clone()]);
            }
        }
    }

    pub(super) fn new<const D: usize>(
        m: &Model<D>,
        fields: &[InterfaceField],
        timings: &'r mut Timings,
        options: &'r SolveOptions,
    ) -> Self {
        Self {
            options,
            timings,
            previous: fields.iter().map(|f| f.s.clone()).collect(),
            body: BodyQois::new(m),
            memory: vec![Vec::new(); m.interfaces.len()],
            partial: Vec::with_capacity(2 * m.interfaces.len() + 1),
            qois: QoiValues::default(),
        }
    }
}

/// When a time window's iterations stop: eta's and the QoI estimate's tolerances, the iteration
/// from which a window whose eta has converged is accepted as stalled ([`STALL_ITERATIONS`]),
/// and the norms each QoI is measured against at least.
pub(super) struct WindowRule<'a> {
    pub(super) tolerance: f64,
    pub(super) estimate_tolerance: f64,
    pub(super) stall_at: Option<usize>,
    pub(super) floors: Option<&'a [f64]>,
    /// for the last window: the share of each whole QoI history all windows may spend, and what
    /// the earlier ones spent (absolute)
    pub(super) budget: Option<(f64, &'a [f64])>,
    /// a whole-interval solve checked by iterating on (docs/method.md, "Two tolerances")
    pub(super) tighten: bool,
}

/// How a time window's iterations ended: the report, the nodes' memory at the window's end,
/// and each QoI's estimated error relative to the norm it was measured against.
pub(super) struct WindowEnd {
    pub(super) report: StageReport,
    pub(super) memory: Vec<Vec<NodeMemory>>,
    pub(super) errors: Vec<f64>,
    pub(super) scales: Vec<f64>,
}

/// The last window sees the whole histories: it may stop once every QoI's estimated error, with
/// what the earlier windows spent (absolute), fits `share` of the QoI's norm.
pub(super) fn within_budget(budget: Option<(f64, &[f64])>, estimator: &ErrorEstimator) -> bool {
    budget.is_some_and(|(share, earlier)| {
        let errors = estimator.errors();
        !errors.is_empty()
            && errors.iter().zip(estimator.scales()).zip(earlier).all(|((e, s), before)| e * s + before <= share * s)
    })
}

/// The first of `series` with a value in `values` that is not finite.
fn first_non_finite(series: &[Vec<f64>], values: &Range<usize>) -> Option<usize> {
    series.iter().position(|v| v[values.clone()].iter().any(|v| !v.is_finite()))
}

/// Fills steps `from..to` of every field with its values at step `from - 1`: the next window
/// begins from the state the last one converged to. With `initial` (a warm start's histories,
/// which those steps still hold) they are moved by what `initial` changes from step `from - 1`
/// to each, so the window moves as the other solution does; without it (a cold start) they are
/// held, rather than starting from zero forces.
pub(super) fn start_window(
    fields: &mut [InterfaceField],
    initial: Option<&[InterfaceField]>,
    steps: usize,
    from: usize,
    to: usize,
) {
    for (i, f) in fields.iter_mut().enumerate().filter(|(_, f)| !f.is_empty() && from > 0) {
        let per_step = f.len() / steps;
        let sides = initial.map(|g| g[i].s.iter().chain(g[i].hat.iter()));
        let mut sides = sides.into_iter().flatten();
        for side in f.s.iter_mut().chain(f.hat.iter_mut()) {
            let first = sides.next();
            for (k, v) in [&mut side.force, &mut side.velocity].into_iter().enumerate() {
                let (done, rest) = v.split_at_mut(from * per_step);
                let last = &done[(from - 1) * per_step..];
                let w = first.map(|g| if k == 0 { &g.force } else { &g.velocity });
                for (n, chunk) in rest[..(to - from) * per_step].chunks_mut(per_step).enumerate() {
                    match w {
                        None => chunk.copy_from_slice(last),
                        Some(w) => {
                            let was = &w[(from - 1) * per_step..from * per_step];
                            let guess = &w[(from + n) * per_step..(from + n + 1) * per_step];
                            for (((x, g), l), o) in chunk.iter_mut().zip(guess).zip(last).zip(was) {
                                *x = g + (l - o);
                            }
                        }
                    }
                }
            }
        }
    }
}
