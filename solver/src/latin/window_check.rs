//! Two windowings (docs/method.md, "Two windowings"). A solve in time windows accepts each
//! window on its own estimate, given the state the windows before it ended in; what no window
//! sees is how an error left at its end grows through the later ones (an undamped wave, a
//! contact that opens and closes; measured: a wall's normal force 8 % off a tight solve while
//! every window's estimate was below 2e-5). So the solve is iterated on from its answer in
//! windows of another length, ten times tighter, and the two answers compared: their distance is
//! about the looser one's error and bounds the tighter one's. The other windowing's windows span
//! the first's ends, where such errors sit, and carry what their iterations change to the later
//! windows. Where the distance exceeds the tolerance, a tighter pair is solved; a solve whose
//! windowings still part after [`CHECK_ROUNDS`] pairs did not meet its tolerance, and says so.
//! (A pass used to start again from where the solve started: the same verdicts on issue 30's
//! cases for 1.1-2 x the work, docs/notebook/2026-11-29.md, "The windowed check goes on".)

use super::*;
use glissade_core::scene::MIN_TOLERANCE;
use std::collections::BTreeMap;

/// Pairs the check compares at most: the solve with a pass `TIGHTER` times its tolerance; where
/// they part, a pair at a tolerance chosen from the distance measured.
pub const CHECK_ROUNDS: usize = 3;
/// The tighter member of a pair is iterated to this times the looser one's tolerance.
pub const TIGHTER: f64 = 0.1;
/// Where the whole-interval check's first pair parted, the next pair's tighter member is
/// iterated to this times the looser one's tolerance: the looser member is already ten times
/// tighter than asked, a third of it bounds its error as well (the distance is about two thirds
/// of the looser member's error, the tighter member's about half the distance), for about half
/// the iterations a tenth takes on a slow tail.
pub const TIGHTER_AFTER_PARTING: f64 = 1.0 / 3.0;
/// Where a pair parts, the next one's looser member is aimed at this share of the tolerance.
pub const AIM: f64 = 0.3;
/// Where a pass does not converge at a tolerance (its iterations stall short of it, the floor),
/// no looser member of a later pair is aimed within this factor above it.
pub const FLOOR_STEP: f64 = 3.0;

/// What the check of a windowed solve found.
#[derive(Debug, Clone, Default, Serialize)]
pub struct WindowCheck {
    /// steps per window of the solve and of the other windowing ([0, 0]: a whole-interval
    /// solve iterated on, [`Tightening`])
    pub windows: [usize; 2],
    /// passes over the interval the check iterated
    pub passes: usize,
    /// the check's own work, included in the solve's: its passes' iterations and sweeps, or for
    /// a whole-interval solve the iterations after its first answer
    pub iterations: usize,
    pub sweeps: f64,
    /// the distance between the two windowings' last answers: the largest over the QoIs,
    /// relative L2 over the history as the stopping test measures it
    pub discrepancy: f64,
    /// the QoI it was found on
    pub qoi: String,
    /// every QoI's distance in the last pair (where the worst parted, the others may agree)
    pub distances: BTreeMap<String, f64>,
    /// the tolerance the answer returned was iterated to: the last pair's tighter member, or
    /// where a pass did not converge, the last pass that did
    pub iteration_tolerance: f64,
    /// the loosest tolerance a pass did not converge at (its iterations stalled short of it),
    /// where one did not: each such pass was tried again, looser
    #[serde(skip_serializing_if = "Option::is_none")]
    pub floor: Option<f64>,
    /// where the last two answers part on the worst QoI, when they part by more than the
    /// tolerance
    #[serde(skip_serializing_if = "Option::is_none")]
    pub parting: Option<Parting>,
    pub outcome: CheckOutcome,
}

/// How two answers part on one QoI over time: the difference of their histories relative to the
/// QoI's size so far, as its running largest value, first reaches 1e-3 of its final largest at
/// `from` and a tenth of it at `to` (100 x more). Between the two it grew e-fold every `efold`
/// seconds: the rate at which the motion amplifies a perturbation (docs/verification.md, "A
/// slide that amplifies perturbations"). `efold` is none where the difference jumped by 100 x
/// within a step or two (an impact that one answer has and the other not); `growth` is what that
/// rate makes of a difference at `from` by the end of the interval.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Parting {
    pub qoi: String,
    pub from: f64,
    pub to: f64,
    pub efold: Option<f64>,
    pub growth: Option<f64>,
}

impl Parting {
    /// The parting of the QoI `qoi` between the histories `a` and `b` at steps 0, dt, 2 dt, ...;
    /// none where they are equal.
    pub fn of(qoi: &str, a: &[f64], b: &[f64], dt: f64) -> Option<Parting> {
        // the difference relative to the QoI's size so far, so that a QoI that only starts
        // (a slip from zero at the onset of sliding) is not taken for a difference that grows;
        // that size no less than 1e-3 of the QoI's largest (a stuck slip of 1e-22 m is no size)
        let floor = 1e-3 * a.iter().chain(b).fold(0.0f64, |m, v| m.max(v.abs()));
        let (mut size, mut apart, mut largest) = (floor, 0.0f64, 0.0f64);
        let running: Vec<f64> = a
            .iter()
            .zip(b)
            .map(|(x, y)| {
                size = size.max(x.abs()).max(y.abs());
                apart = apart.max((x - y).abs());
                if size > 0.0 {
                    largest = largest.max(apart / size);
                }
                largest
            })
            .collect();
        if !(largest > 0.0 && largest.is_finite()) {
            return None;
        }
        let first = |share: f64| running.iter().position(|d| *d >= share * largest).expect("the largest is reached");
        let (i, j) = (first(1e-3), first(0.1));
        let efold = (j >= i + 3).then(|| (j - i) as f64 * dt / (running[j] / running[i]).ln());
        let growth = efold.map(|e| ((running.len() - 1 - i) as f64 * dt / e).exp());
        Some(Parting { qoi: qoi.to_string(), from: i as f64 * dt, to: j as f64 * dt, efold, growth })
    }

    /// The evidence, in words.
    pub fn evidence(&self) -> String {
        match (self.efold, self.growth) {
            (Some(e), Some(g)) => format!(
                "they part from t = {:.2e} s, their difference growing e-fold every {e:.1e} s: the motion amplifies \
                 a difference there (an iteration error, or a change in the data) about {g:.0e} x by the end, and \
                 '{}' is pinned only by iterations as much tighter than the tolerance \
                 (docs/verification.md, \"A slide that amplifies perturbations\"); where a contact chatters as \
                 it slides below friction 1, a Prakash-Clifton regularisation of its friction (docs/scenes.md) damps it",
                self.from, self.qoi
            ),
            _ => format!("they part at t = {:.2e} s, at once (an impact in one answer and not in the other)", self.to),
        }
    }
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum CheckOutcome {
    /// the windowings agreed within the tolerance
    Agreed,
    /// they still parted after the last round
    #[default]
    Parted,
    /// a pass did not converge within the iteration limit (the stage's diagnosis is its)
    PassNotConverged,
    /// the whole-interval check's tighter pass would be below [`MIN_TOLERANCE`]: not run, the
    /// answer not checked
    BelowFloor,
}

impl WindowCheck {
    /// Why the check failed, and what to change; `pass` is the diagnosis of a pass that did not
    /// converge.
    pub fn diagnosis(&self, tolerance: f64, pass: &str) -> String {
        if self.outcome == CheckOutcome::BelowFloor {
            return format!(
                "not checked: the whole-interval check iterates on to a tenth of the tolerance, and {tolerance:.0e} \
                 is the smallest a solve may ask ({MIN_TOLERANCE:.0e}); the answer met the stopping test, unchecked; \
                 ask {:.0e} or above for a checked answer, or solver.whole_interval_check = false to take it unchecked",
                MIN_TOLERANCE / TIGHTER
            );
        }
        if self.outcome == CheckOutcome::PassNotConverged {
            let measured = if self.passes > 0 && !self.qoi.is_empty() {
                format!(
                    "{}, the answers parted by {:.2e} on '{}'{}, and ",
                    self.how(),
                    self.discrepancy,
                    self.qoi,
                    self.growth()
                )
            } else {
                String::new()
            };
            return format!(
                "checking the {} solve: {measured}a pass to {:.1e} did not converge ({pass}); a looser tolerance, \
                 or solver.window_check = false to take the first answer unchecked",
                if self.whole_interval() { "whole-interval" } else { "windowed" },
                self.floor.unwrap_or(self.iteration_tolerance)
            );
        }
        let agreeing: Vec<String> =
            self.distances.iter().filter(|(_, d)| **d <= tolerance).map(|(q, d)| format!("'{q}' {d:.1e}")).collect();
        let others = if agreeing.is_empty() { String::new() } else { format!("; within it: {}", agreeing.join(", ")) };
        format!(
            "sensitive: {}, the last two answers part by {:.2e} on '{}' \
             (the tighter iterated to {:.1e}, the tolerance {tolerance:.1e}{others}){}: this QoI moves with the iteration \
             error far more than the tolerance allows, as the forces of a contact that lifts off and lands do; \
             a looser tolerance, leaving this QoI out (a slip is often determined where a contact force is \
             not), or solver.window_check = false to take the first answer, off by about that much",
            self.how(),
            self.discrepancy,
            self.qoi,
            self.iteration_tolerance,
            self.growth()
        )
    }

    /// The parting's evidence after "; ", or nothing.
    fn growth(&self) -> String {
        self.parting.as_ref().map_or(String::new(), |p| format!("; {}", p.evidence()))
    }

    /// The check iterated a whole-interval solve on rather than another windowing.
    pub fn whole_interval(&self) -> bool {
        self.windows == [0, 0]
    }

    /// What the two answers compared are.
    pub fn how(&self) -> String {
        if self.whole_interval() {
            "iterated on over the whole interval, 10 x tighter each time".to_string()
        } else {
            format!("iterated in windows of {} and of {} steps", self.windows[0], self.windows[1])
        }
    }
}

impl<const D: usize> LatinSolver<'_, D> {
    /// Checks a windowed solve converged to `tolerance` (module docs). Every pass goes on from
    /// the fields the last one left, its prestress converged again as much tighter as the pass
    /// is; `prestress` and `fields` end as the last pass's, `report` counts the passes' work and
    /// carries the check.
    pub(super) fn check_windows(
        &mut self,
        tolerance: f64,
        report: &mut StageReport,
        prestress: &mut Option<Prestress>,
        fields: &mut [InterfaceField],
        timings: &mut Timings,
        options: &SolveOptions,
    ) -> Result<(), SolverError> {
        let first = self.model.settings.time_window;
        let windows = [first, first + first.div_ceil(2)];
        let quiet = SolveOptions { record_fields: false, trace_qois: false, ..options.clone() };
        // the answer to return should a later pass stop part-way: the solve's own, at first
        let kept = Some(Kept { fields: fields.to_vec(), prestress: prestress.clone(), tolerance });
        let check = WindowCheck { windows, ..Default::default() };
        let mut pass = Pass { prestress, fields, check, kept };
        let mut run = PassRun { scales: report.scales.clone(), report, timings, quiet: &quiet };
        // the looser member of the pair and its iteration tolerance: first the solve itself
        let mut looser = self.answer(&pass, &quiet);
        let mut loose = tolerance;
        // where the last pair's tighter member was iterated to, while a fresh looser one is wanted
        let mut fresh_below = None;
        // the looser member was iterated in the first windowing (else in the second, as the
        // tighter member of the last pair)
        let mut first_windowing = true;
        for _ in 0..CHECK_ROUNDS {
            if let Some(tight) = fresh_below.take() {
                // a fresh looser member (the last tighter one was predicted too far off)
                let Some((answer, at)) = self.pass_to(&mut pass, windows[0], loose, tight, &mut run)? else {
                    break;
                };
                (looser, loose, first_windowing) = (answer, at, true);
            }
            // (no tighter than a scene may ask: below it the iterations stall on round-off; there
            // the two windowings are compared at the same tolerance, but one windowing never with
            // itself)
            let aim = (loose * TIGHTER).max(MIN_TOLERANCE);
            if aim >= loose && !first_windowing {
                break;
            }
            let Some((answer, tight)) = self.pass_to(&mut pass, windows[1], aim, loose, &mut run)? else {
                break;
            };
            let check = &mut pass.check;
            check.iteration_tolerance = tight;
            check.distances = distances(&looser, &answer, &run.scales);
            (check.discrepancy, check.qoi) = worst(&check.distances);
            check.parting = (check.discrepancy > tolerance)
                .then(|| {
                    let q = looser.iter().position(|q| q.name == check.qoi)?;
                    Parting::of(&check.qoi, &looser[q].values, &answer[q].values, self.model.dt)
                })
                .flatten();
            tracing::info!(
                loose,
                tight,
                discrepancy = check.discrepancy,
                qoi = check.qoi,
                "window check: a pair compared"
            );
            // the looser member's error is about the distance, the tighter's is less: the
            // distance bounds the answer returned, the tighter one
            run.report.error_estimate = check.discrepancy;
            if check.discrepancy <= tolerance {
                check.outcome = CheckOutcome::Agreed;
                break;
            }
            // The error grows about as the iteration tolerance (measured in docs/performance.md,
            // "Two windowings"): the next pair's looser member at the tolerance whose error is
            // predicted at AIM of the asked one, above the floor; the tighter member just
            // iterated when it is predicted there already.
            let floor = check.floor.map_or(MIN_TOLERANCE, |floor| floor * FLOOR_STEP);
            let wanted = (loose * AIM * tolerance / check.discrepancy).max(loose * 1e-4).max(floor);
            if wanted < tight {
                fresh_below = Some(tight);
                loose = wanted;
            } else {
                (looser, loose, first_windowing) = (answer, tight, false);
            }
        }
        // A pass that did not converge stopped in some window, the later ones never iterated
        // (the 3D block's QoIs then ended at their values of t = 1.2e-4 s): the answer returned
        // is the last pass that converged, the tolerance it was iterated to with it.
        if pass.check.outcome == CheckOutcome::PassNotConverged
            && let Some(kept) = pass.kept.take()
        {
            pass.fields.clone_from_slice(&kept.fields);
            *pass.prestress = kept.prestress;
            pass.check.iteration_tolerance = kept.tolerance;
        }
        let report = run.report;
        report.converged &= pass.check.outcome == CheckOutcome::Agreed;
        report.window_check = Some(pass.check);
        Ok(())
    }

    /// A pass to `tolerance`; where it does not converge there (its iterations stall short of
    /// it: the floor), once more at the geometric mean of that and `ceiling`, the tolerance of
    /// the member it is compared with (so never the same answer). The answer and the tolerance
    /// it was iterated to, or `None` when neither converged: the check is over, the report says
    /// so.
    fn pass_to(
        &mut self,
        pass: &mut Pass,
        window: usize,
        tolerance: f64,
        ceiling: f64,
        run: &mut PassRun,
    ) -> Result<Option<(Vec<QoiSeries>, f64)>, SolverError> {
        let retry = (tolerance * ceiling).sqrt();
        let mut estimate = 0.0;
        for at in [tolerance, retry].into_iter().take(if retry > tolerance { 2 } else { 1 }) {
            match self.check_pass(pass, window, at, run)? {
                Ok(answer) => return Ok(Some((answer, at))),
                Err(e) => estimate = e,
            }
            pass.check.floor = Some(pass.check.floor.map_or(at, |floor| floor.max(at)));
            pass.check.iteration_tolerance = at;
        }
        // what the check measured before stays the estimate of the answer returned
        run.report.converged = false;
        run.report.error_estimate = estimate.max(pass.check.discrepancy);
        pass.check.outcome = CheckOutcome::PassNotConverged;
        Ok(None)
    }

    /// The QoIs of the fields a pass left.
    fn answer(&mut self, pass: &Pass, quiet: &SolveOptions) -> Vec<QoiSeries> {
        let none = vec![None; self.model.substructures.len()];
        let (u0, statics) = pass.prestress.as_ref().map_or((&none, None), |p| (&p.u0, Some(&p.solution)));
        self.post_process(pass.fields, u0, statics, quiet).0
    }

    /// One pass of the check: the prestress converged again for `tolerance` (from its last
    /// solution: it costs a step per iteration), then the dynamic stage from the fields the last
    /// pass left, in windows of `window` steps; its QoIs, or its error estimate when it did not
    /// converge (the report keeps the pass's history, for its diagnosis).
    fn check_pass(
        &mut self,
        pass: &mut Pass,
        window: usize,
        tolerance: f64,
        run: &mut PassRun,
    ) -> Result<Result<Vec<QoiSeries>, f64>, SolverError> {
        let PassRun { report, scales, timings, quiet } = run;
        // A pass goes on from the fields the last one left (docs/method.md, "Two windowings"):
        // a continuation in the other windowing, as the whole-interval check iterates on.
        if let Some(before) = pass.prestress.take() {
            let old = before.solution.clone();
            let mut again = self.iterate_prestress(before.solution, tolerance, false, timings, quiet)?;
            again.report.iterations += before.report.iterations;
            again.report.sweeps += before.report.sweeps;
            let converged = again.report.converged;
            // the dynamic fields hold the static forces at every step: they move by its change
            add_static_change(pass.fields, &again.solution, Some(&old));
            *pass.prestress = Some(again);
            if !converged {
                return Ok(Err(report.error_estimate));
            }
        }
        let outcome = self.dynamic_stage(
            pass.prestress.as_ref(),
            (tolerance, window, Start::Continued),
            pass.fields,
            timings,
            quiet,
        )?;
        tracing::info!(
            window,
            tolerance,
            iterations = outcome.iterations,
            sweeps = outcome.sweeps,
            converged = outcome.converged,
            stalled = outcome.windows_stalled,
            "window check: a pass"
        );
        let check = &mut pass.check;
        check.passes += 1;
        check.iterations += outcome.iterations;
        check.sweeps += outcome.sweeps;
        for (s, p) in scales.iter_mut().zip(&outcome.scales) {
            *s = s.max(*p);
        }
        report.iterations += outcome.iterations;
        report.sweeps += outcome.sweeps;
        report.history.extend(&outcome.history);
        report.error_indicator = outcome.error_indicator;
        report.worst_interface = outcome.worst_interface.clone();
        report.worst_interface_aspect = outcome.worst_interface_aspect;
        report.relaxation = outcome.relaxation;
        report.windows_stalled += outcome.windows_stalled;
        report.windows_redone += outcome.windows_redone;
        if !outcome.converged {
            return Ok(Err(outcome.error_estimate));
        }
        pass.kept = Some(Kept { fields: pass.fields.to_vec(), prestress: pass.prestress.clone(), tolerance });
        Ok(Ok(self.answer(pass, quiet)))
    }
}

/// What the check's passes go on from and leave: the prestress and dynamic fields of the last
/// pass, and the check's record.
struct Pass<'b> {
    prestress: &'b mut Option<Prestress>,
    fields: &'b mut [InterfaceField],
    check: WindowCheck,
    /// the last pass that converged (at first the solve itself)
    kept: Option<Kept>,
}

/// A converged pass's fields and prestress, and the tolerance it was iterated to.
struct Kept {
    fields: Vec<InterfaceField>,
    prestress: Option<Prestress>,
    tolerance: f64,
}

/// What the passes add their work to, the QoIs' scales they measure with, and how they run.
struct PassRun<'r> {
    report: &'r mut StageReport,
    scales: Vec<f64>,
    timings: &'r mut Timings,
    quiet: &'r SolveOptions,
}

/// The largest of the QoIs' distances ([`distances`]), and the QoI it is on.
fn worst(distances: &BTreeMap<String, f64>) -> (f64, String) {
    distances.iter().fold((0.0, String::new()), |best, (name, d)| if *d > best.0 { (*d, name.clone()) } else { best })
}

/// Each QoI's distance between two answers, relative to the larger of its norm in `scales` (the
/// stopping test's, floored) and its own.
fn distances(a: &[QoiSeries], b: &[QoiSeries], scales: &[f64]) -> BTreeMap<String, f64> {
    distances_of(a.iter().zip(b).map(|(x, y)| (x.name.as_str(), &x.values[..], &y.values[..])), scales)
}

/// [`distances`] of (name, one answer's history, the other's), QoI by QoI.
fn distances_of<'a>(
    pairs: impl Iterator<Item = (&'a str, &'a [f64], &'a [f64])>,
    scales: &[f64],
) -> BTreeMap<String, f64> {
    let norm = |v: &mut dyn Iterator<Item = f64>| v.map(|x| x * x).sum::<f64>().sqrt();
    pairs
        .enumerate()
        .map(|(q, (name, x, y))| {
            let diff = norm(&mut x.iter().zip(y).map(|(p, r)| p - r));
            let scale = scales.get(q).copied().unwrap_or(0.0).max(norm(&mut x.iter().copied()));
            (name.to_string(), if diff == 0.0 { 0.0 } else { diff / scale })
        })
        .collect()
}

/// A whole-interval solve checked by iterating on (docs/method.md, "Two tolerances"). The
/// stopping test reads the error from the rate at which the QoIs still change, which a contact
/// that lifts off and lands while it slides fools by 30 x and more; iterated on to a tenth of
/// the tolerance, the same sequence of iterates shows how far its answer at the tolerance was:
/// where the two part by more than the tolerance, on again, [`CHECK_ROUNDS`] pairs at most. The
/// cost is the iterations from the tolerance to a tenth of it; no windowing to iterate again.
pub(super) struct Tightening {
    asked: f64,
    /// the time step, where the QoI histories' steps are
    dt: f64,
    /// the pairs have ended the check (else the iterations ran out on the way)
    over: bool,
    /// the iterations the first answer took: the check's are those after it
    first_answer: Option<usize>,
    looser: Option<Vec<Vec<f64>>>,
    pub(super) check: WindowCheck,
}

impl Tightening {
    pub(super) fn new(asked: f64, dt: f64) -> Self {
        Self {
            asked,
            dt,
            over: false,
            first_answer: None,
            looser: None,
            check: WindowCheck { iteration_tolerance: asked, ..Default::default() },
        }
    }

    /// The iterations reached `tolerance` at `iteration` with the QoIs `current`: the tolerance
    /// to iterate on to, or `None` when the check is over (`check.outcome` says how; `passes`
    /// counts the tightenings, kept by the caller).
    pub(super) fn reached(
        &mut self,
        iteration: usize,
        tolerance: f64,
        current: &[Vec<f64>],
        qois: &[crate::model::Qoi],
        scales: &[f64],
    ) -> Option<f64> {
        self.first_answer.get_or_insert(iteration);
        tracing::debug!(iteration, tolerance, "whole-interval check: a tolerance reached");
        if let Some(looser) = &self.looser {
            let pairs = qois.iter().zip(looser).zip(current).map(|((q, a), b)| (q.name.as_str(), &a[..], &b[..]));
            self.check.distances = distances_of(pairs, scales);
            (self.check.discrepancy, self.check.qoi) = worst(&self.check.distances);
            tracing::info!(
                iteration,
                tolerance,
                discrepancy = self.check.discrepancy,
                qoi = self.check.qoi,
                "whole-interval check: a pair compared"
            );
            if self.check.discrepancy <= self.asked {
                self.check.outcome = CheckOutcome::Agreed;
                self.check.parting = None;
                self.over = true;
                return None;
            }
            self.check.parting = qois
                .iter()
                .position(|q| q.name == self.check.qoi)
                .and_then(|q| Parting::of(&self.check.qoi, &looser[q], &current[q], self.dt));
        }
        // (no tighter than a scene may ask: below it the iterations stall on round-off)
        let factor = if self.looser.is_some() { TIGHTER_AFTER_PARTING } else { TIGHTER };
        let next = (tolerance * factor).max(MIN_TOLERANCE);
        if self.looser.is_none() && next >= tolerance {
            // asked at the floor: no tighter pass to compare with (it used to read as "still
            // converging: about 0 more iterations")
            self.check.outcome = CheckOutcome::BelowFloor;
            self.over = true;
            return None;
        }
        if self.check.passes >= CHECK_ROUNDS || next >= tolerance {
            self.check.outcome = CheckOutcome::Parted;
            self.over = true;
            return None;
        }
        self.looser = Some(current.to_vec());
        self.check.iteration_tolerance = next;
        self.check.passes += 1;
        Some(next)
    }

    /// The check's record for the stage's report once its iterations ended (none if they never
    /// reached the asked tolerance): where the limit ran out on the way to a tighter one, that
    /// pass did not converge.
    pub(super) fn end(mut self, report: &mut StageReport) -> Option<WindowCheck> {
        if self.check.passes == 0 && self.check.outcome != CheckOutcome::BelowFloor {
            return None;
        }
        if !self.over {
            self.check.outcome = CheckOutcome::PassNotConverged;
            report.error_estimate = report.error_estimate.max(self.check.discrepancy);
        }
        // the check's own cost, as a windowed check counts its passes: the iterations after
        // the first answer
        self.check.iterations = report.iterations - self.first_answer.unwrap_or(report.iterations);
        self.check.sweeps = self.check.iterations as f64;
        Some(self.check)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn series(name: &str, values: &[f64]) -> QoiSeries {
        QoiSeries { name: name.into(), times: (0..values.len()).map(|n| n as f64).collect(), values: values.to_vec() }
    }

    /// The whole-interval check's pairs: the first answer against one iterated on to a tenth of
    /// the tolerance; where they part, the next pair's tighter member a third of its looser one
    /// (already a tenth of the asked tolerance); the answers agreeing end the check.
    #[test]
    fn a_parted_pair_is_followed_by_one_a_third_tighter() {
        use crate::model::{Qoi, QoiTarget};
        let qois = [Qoi { name: "slip".into(), target: QoiTarget::Slip { interface: 0, node: 0, component: None } }];
        let answer = |value: f64| vec![vec![1.0, value]];
        let scales = [0.0];
        let mut t = Tightening::new(2e-4, 1e-6);
        assert_eq!(t.reached(50, 2e-4, &answer(1.0), &qois, &scales), Some(2e-5));
        // 1e-3 apart (relative to the history's norm, about 1.4): parted, on to a third
        let next = t.reached(90, 2e-5, &answer(1.0 + 1.4e-3), &qois, &scales).expect("on again");
        assert!((next - 2e-5 / 3.0).abs() < 1e-18, "{next}");
        assert!(t.check.discrepancy > 2e-4 && t.check.passes == 2, "{:?}", t.check);
        // 1e-5 apart: agreed, the check is over with the tighter answer
        assert_eq!(t.reached(120, next, &answer(1.0 + 1.4e-3 + 1.4e-5), &qois, &scales), None);
        assert_eq!(t.check.outcome, CheckOutcome::Agreed);
        assert_eq!((t.check.passes, t.check.iteration_tolerance), (2, next));
    }

    /// The distance is the worst QoI's, relative to its norm or, for a QoI near zero, to its
    /// floored scale (a stuck slip of 1e-22 m is not compared with itself).
    #[test]
    fn the_discrepancy_is_the_worst_qoi_relative_to_its_floored_norm() {
        let a = [series("slip", &[0.0, 1e-22, 2e-22]), series("force", &[3.0, 4.0, 0.0])];
        let b = [series("slip", &[0.0, 3e-22, 2e-22]), series("force", &[3.0, 4.0, 0.5])];
        let (d, q) = worst(&distances(&a, &b, &[1e-6, 5.0]));
        assert_eq!(q, "force");
        assert!((d - 0.1).abs() < 1e-12, "{d}");
        let (d, q) = worst(&distances(&a, &a, &[1e-6, 5.0]));
        assert_eq!((d, q.as_str()), (0.0, ""));
    }

    /// A difference that grows e-fold every 5 steps from step 40 (below 1e-12 before) is found
    /// there, at that rate, and what the rate makes of it by the end; one that jumps has no
    /// rate; equal answers do not part.
    #[test]
    fn a_parting_is_found_where_the_difference_grows_and_at_its_rate() {
        let dt = 2e-6;
        let a: Vec<f64> = (0..=100).map(|n| (n as f64 * 0.3).sin()).collect();
        let grown: Vec<f64> = (0..=100)
            .map(|n| if n < 40 { 1e-13 * (n as f64).cos() } else { 1e-9 * ((n - 40) as f64 / 5.0).exp() })
            .collect();
        let b: Vec<f64> = a.iter().zip(&grown).map(|(x, d)| x + d).collect();
        let p = Parting::of("force", &a, &b, dt).expect("they part");
        let efold = p.efold.expect("a rate");
        assert!((efold / (5.0 * dt) - 1.0).abs() < 0.05, "{p:?}");
        // the largest is 1e-9 e^12 at the end; 1e-3 of it is 6.9 e-folds (34.5 steps) before,
        // a tenth of it 2.3 (11.5 steps) before
        assert!((p.from / dt - 65.5).abs() < 1.0 && (p.to / dt - 88.5).abs() < 1.0, "{p:?}");
        let growth = p.growth.expect("a growth");
        assert!((growth.ln() - (100.0 * dt - p.from) / efold).abs() < 1e-9, "{p:?}");
        assert!(p.evidence().contains("e-fold every 1.0e-5 s"), "{}", p.evidence());

        let mut jump = a.clone();
        jump[70] += 0.5;
        let p = Parting::of("force", &a, &jump, dt).expect("they part");
        assert_eq!((p.efold, p.growth, p.to), (None, None, 70.0 * dt));
        assert!(p.evidence().contains("at once"), "{}", p.evidence());
        assert_eq!(Parting::of("force", &a, &a, dt), None);
    }
}
