//! The life of a design point as pure functions: [`apply`] takes a point as it is and a
//! [`Transition`], and returns the point as it becomes, or refuses a transition its state does
//! not allow. No database, no lock, no clock: the coordinator decides what happened, these
//! functions decide what it does to the point, and [`Coordinator::commit`](super::Coordinator)
//! makes it durable, then visible, then announced.
//!
//! ```text
//!   PENDING --lease--> LEASED --complete (converged)--> DONE
//!      |                 |  \--complete (not converged), fail--> FAILED --retry--> PENDING
//!      |                 |--complete (not converged, an audit's cap spent)--> CANCELLED
//!      |                 |--release, expire--> PENDING (CANCELLED if the study is)
//!      |                 \--expire (max attempts), past the per-point budget--> FAILED
//!      |--answer (a stored solution)--> DONE --reopen (its study moved to a finer level)--> PENDING
//!      \--cancel--> CANCELLED
//! ```

use crate::records::{PointRecord, PointResult, PointState, SolutionOrigin};

use super::point_state_word;

/// What happens to a point.
#[derive(Debug, Clone)]
pub enum Transition {
    /// PENDING -> LEASED to `pool`; counts an attempt. `cap`: an audit's iterations left.
    Lease { pool: String, lease_id: u64, deadline_unix_ms: i64, init: Option<Box<SolutionOrigin>>, cap: Option<u32> },
    /// PENDING -> DONE: a stored solution answers it.
    Answer { result: PointResult, finished_seq: u64 },
    /// LEASED -> DONE when `result.converged`, else FAILED (retryable, the result kept), with
    /// the study's `tolerance` in the error; CANCELLED when an audit's lease spent its cap.
    Complete { result: PointResult, finished_seq: u64, tolerance: f64 },
    /// LEASED -> FAILED: the solver reported `error`.
    Fail { result: PointResult, error: String },
    /// LEASED -> PENDING (CANCELLED when the study is): given back unsolved, the attempt not
    /// counted.
    Release { study_cancelled: bool },
    /// LEASED past its deadline -> PENDING, FAILED once `max_attempts` leases were granted,
    /// CANCELLED when the study is; `last` says what was last heard of the solve.
    Expire { study_cancelled: bool, max_attempts: u32, last: String },
    /// LEASED for longer than the per-point budget of `seconds` -> FAILED (retryable).
    OverBudget { seconds: f64, last: String },
    /// PENDING -> CANCELLED.
    Cancel,
    /// FAILED -> PENDING, attempts counted afresh.
    Retry,
    /// DONE or FAILED -> PENDING, its result dropped: its study moved to a finer level (a study
    /// to an accuracy whose held-out check said ABOVE).
    Reopen,
}

impl Transition {
    fn verb(&self) -> &'static str {
        match self {
            Transition::Lease { .. } => "be leased",
            Transition::Answer { .. } => "be answered from a stored solution",
            Transition::Complete { .. } => "be completed",
            Transition::Fail { .. } => "be failed",
            Transition::Release { .. } => "be released",
            Transition::Expire { .. } => "expire",
            Transition::OverBudget { .. } => "run past its budget",
            Transition::Cancel => "be cancelled",
            Transition::Retry => "be retried",
            Transition::Reopen => "be reopened",
        }
    }
}

/// A transition the point's state does not allow.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("point {point} of study {study} is {state}: it cannot {verb}")]
pub struct IllegalTransition {
    pub study: u64,
    pub point: u64,
    pub state: &'static str,
    pub verb: &'static str,
}

/// The point after `transition`, or why it cannot happen.
pub fn apply(point: &PointRecord, transition: Transition) -> Result<PointRecord, IllegalTransition> {
    let illegal = |t: &Transition| IllegalTransition {
        study: point.study.0,
        point: point.id.0,
        state: point_state_word(&point.state),
        verb: t.verb(),
    };
    let mut p = point.clone();
    match (&point.state, transition) {
        (PointState::Pending, Transition::Lease { pool, lease_id, deadline_unix_ms, init, cap }) => {
            p.state = PointState::Leased { pool, lease_id, deadline_unix_ms, init, cap };
            p.attempts += 1;
        }
        (PointState::Pending, Transition::Answer { result, finished_seq }) => {
            p.state = PointState::Done;
            p.error = None;
            p.finished_seq = Some(finished_seq);
            p.result = Some(Box::new(result));
        }
        (PointState::Leased { cap, .. }, Transition::Complete { result, finished_seq, tolerance }) => {
            if result.converged {
                p.state = PointState::Done;
                p.error = None;
                p.finished_seq = Some(finished_seq);
            } else if cap.is_some_and(|c| result.iterations >= u64::from(c)) {
                p.state = PointState::Cancelled;
                p.error = Some(format!(
                    "not re-solved: cut short after {} iterations, what was left of the audit's cost cap \
                     (eta = {:.3e}, tolerance {tolerance:.1e}); an audit measures, it answers no one",
                    result.iterations, result.error_indicator
                ));
            } else {
                p.state = PointState::Failed;
                p.error = Some(format!(
                    "not converged: eta = {:.3e} > tolerance {tolerance:.1e} after {} iterations",
                    result.error_indicator, result.iterations
                ));
            }
            p.result = Some(Box::new(result));
        }
        (PointState::Leased { .. }, Transition::Fail { result, error }) => {
            p.state = PointState::Failed;
            p.error = Some(error);
            p.result = Some(Box::new(result));
        }
        (PointState::Leased { .. }, Transition::Release { study_cancelled }) => {
            p.state = if study_cancelled { PointState::Cancelled } else { PointState::Pending };
            p.attempts = p.attempts.saturating_sub(1);
        }
        (PointState::Leased { pool, .. }, Transition::Expire { study_cancelled, max_attempts, last }) => {
            if study_cancelled {
                p.state = PointState::Cancelled;
            } else if p.attempts >= max_attempts {
                p.state = PointState::Failed;
                p.error = Some(format!(
                    "lease expired {} times (last held by pool `{pool}`): the pools solving it stopped answering; {last}",
                    p.attempts
                ));
            } else {
                p.state = PointState::Pending;
                p.error = Some(format!("a lease of pool `{pool}` expired; {last}"));
            }
        }
        (PointState::Leased { pool, .. }, Transition::OverBudget { seconds, last }) => {
            p.state = PointState::Failed;
            p.error = Some(format!(
                "held by pool `{pool}` for more than the {seconds} s a point may take (glissade-server --point-seconds); {last}"
            ));
        }
        (PointState::Pending, Transition::Cancel) => p.state = PointState::Cancelled,
        (PointState::Failed, Transition::Retry) => {
            p.state = PointState::Pending;
            p.attempts = 0;
        }
        (PointState::Done | PointState::Failed, Transition::Reopen) => {
            p.state = PointState::Pending;
            p.attempts = 0;
            p.result = None;
            p.error = None;
            p.finished_seq = None;
            p.finished_unix_ms = None;
        }
        (_, t) => return Err(illegal(&t)),
    }
    Ok(p)
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use glissade_core::point::DesignPoint;

    use glissade_proto::{PointId, StudyId};

    use super::*;

    fn point(state: PointState, attempts: u32) -> PointRecord {
        PointRecord {
            study: StudyId(3),
            id: PointId(7),
            parameters: DesignPoint::default(),
            state,
            attempts,
            result: None,
            error: None,
            finished_seq: None,
            finished_unix_ms: None,
        }
    }

    fn leased() -> PointState {
        PointState::Leased { pool: "a".into(), lease_id: 9, deadline_unix_ms: 100, init: None, cap: None }
    }

    fn result(converged: bool) -> PointResult {
        PointResult {
            pool: "a".into(),
            converged,
            iterations: 12,
            error_indicator: if converged { 1e-4 } else { 3e-3 },
            qoi: Default::default(),
            wall_seconds: 1.0,
            started_from: None,
            answered: false,
            eta_history: Default::default(),
            work: 12.0,
            contact: Vec::new(),
            qoi_largest: Default::default(),
        }
    }

    /// Every transition, each from every state: the legal ones give the documented state, the
    /// others are refused naming the state, and leave nothing half done (the input is untouched).
    #[test]
    fn every_transition_from_every_state() {
        let states = [
            ("pending", PointState::Pending),
            ("leased", leased()),
            ("done", PointState::Done),
            ("failed", PointState::Failed),
            ("cancelled", PointState::Cancelled),
        ];
        let transitions = || {
            [
                Transition::Lease { pool: "b".into(), lease_id: 5, deadline_unix_ms: 200, init: None, cap: None },
                Transition::Answer { result: result(true), finished_seq: 4 },
                Transition::Complete { result: result(true), finished_seq: 4, tolerance: 2e-4 },
                Transition::Complete { result: result(false), finished_seq: 4, tolerance: 2e-4 },
                Transition::Fail { result: result(false), error: "diverged".into() },
                Transition::Release { study_cancelled: false },
                Transition::Release { study_cancelled: true },
                Transition::Expire { study_cancelled: false, max_attempts: 3, last: "silence".into() },
                Transition::Expire { study_cancelled: false, max_attempts: 1, last: "silence".into() },
                Transition::Expire { study_cancelled: true, max_attempts: 3, last: "silence".into() },
                Transition::Cancel,
                Transition::Retry,
            ]
        };
        // (state, transition index) -> the state after, for the legal pairs
        let legal: BTreeMap<(&str, usize), &str> = [
            (("pending", 0), "leased"),
            (("pending", 1), "done"),
            (("leased", 2), "done"),
            (("leased", 3), "failed"),
            (("leased", 4), "failed"),
            (("leased", 5), "pending"),
            (("leased", 6), "cancelled"),
            (("leased", 7), "pending"),
            (("leased", 8), "failed"),
            (("leased", 9), "cancelled"),
            (("pending", 10), "cancelled"),
            (("failed", 11), "pending"),
        ]
        .into();
        for (name, state) in &states {
            for (k, t) in transitions().into_iter().enumerate() {
                let before = point(state.clone(), 1);
                let verb = t.verb();
                match (apply(&before, t), legal.get(&(*name, k))) {
                    (Ok(after), Some(&want)) => {
                        assert_eq!(point_state_word(&after.state), want, "{name} --{k}-->")
                    }
                    (Err(e), None) => {
                        assert_eq!(e.state, *name);
                        assert_eq!(e.to_string(), format!("point 7 of study 3 is {name}: it cannot {verb}"));
                    }
                    (got, want) => panic!("{name} --{k}-->: got {got:?}, want {want:?}"),
                }
                assert_eq!(before.state, *state, "the input is not changed");
            }
        }
    }

    #[test]
    fn attempts_count_leases_and_not_releases_and_restart_at_a_retry() {
        let lease = || Transition::Lease { pool: "a".into(), lease_id: 1, deadline_unix_ms: 0, init: None, cap: None };
        let p = apply(&point(PointState::Pending, 0), lease()).unwrap();
        assert_eq!(p.attempts, 1);
        let p = apply(&p, Transition::Release { study_cancelled: false }).unwrap();
        assert_eq!((p.state.clone(), p.attempts), (PointState::Pending, 0));
        let p =
            apply(&apply(&p, lease()).unwrap(), Transition::Fail { result: result(false), error: "x".into() }).unwrap();
        assert_eq!((p.error.as_deref(), p.attempts), (Some("x"), 1));
        let p = apply(&p, Transition::Retry).unwrap();
        assert_eq!((p.state, p.attempts), (PointState::Pending, 0));
    }

    #[test]
    fn completions_and_expiries_say_why_a_point_failed() {
        let done =
            apply(&point(leased(), 1), Transition::Complete { result: result(true), finished_seq: 8, tolerance: 2e-4 })
                .unwrap();
        assert_eq!((done.finished_seq, done.error), (Some(8), None));
        let failed = apply(
            &point(leased(), 1),
            Transition::Complete { result: result(false), finished_seq: 8, tolerance: 2e-4 },
        )
        .unwrap();
        assert_eq!(failed.finished_seq, None, "only a DONE point takes a place in the finishing order");
        assert_eq!(
            failed.error.as_deref(),
            Some("not converged: eta = 3.000e-3 > tolerance 2.0e-4 after 12 iterations")
        );
        assert!(failed.result.is_some(), "the last iterate's result is kept");
        let requeued = apply(
            &point(leased(), 2),
            Transition::Expire { study_cancelled: false, max_attempts: 3, last: "last heard at 40".into() },
        )
        .unwrap();
        assert_eq!(requeued.error.as_deref(), Some("a lease of pool `a` expired; last heard at 40"));
        let given_up = apply(
            &point(leased(), 3),
            Transition::Expire { study_cancelled: false, max_attempts: 3, last: "last heard at 40".into() },
        )
        .unwrap();
        assert_eq!(given_up.state, PointState::Failed);
        assert!(given_up.error.unwrap().starts_with("lease expired 3 times (last held by pool `a`)"));
    }
}
