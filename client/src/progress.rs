//! What `glissade watch` knows about a study while it runs, built from the coordinator's event
//! stream alone, and how it says it: a status line (terminal) or one line per event (pipes).

use std::collections::{BTreeMap, HashMap};
use std::time::Duration;

use glissade_core::study::{WorkMean, warm_against_cold};
use glissade_proto::v1;

use crate::names::{describe_parameters, point_state_name, study_state_name};

/// Mean work of a set of points: dynamic iterations + static iterations / time steps (a
/// dynamic iteration sweeps every step, a static one a single step).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct WorkStats {
    pub points: u32,
    pub work: f64,
}

impl WorkStats {
    fn add(&mut self, p: &v1::PointStatus) {
        self.points += 1;
        // records written before work was reported count their iterations
        self.work += if p.work > 0.0 { p.work } else { p.iterations as f64 };
    }

    pub fn mean(&self) -> Option<f64> {
        (self.points > 0).then(|| self.work / self.points as f64)
    }

    fn describe(&self) -> String {
        match self.mean() {
            Some(m) => format!("{m:.1} ({} pt)", self.points),
            None => "-".into(),
        }
    }
}

/// A point a pool holds now, and since when (Unix ms).
#[derive(Debug, Clone, PartialEq)]
pub struct Running {
    pub parameters: String,
    pub pool: String,
    pub since_unix_ms: i64,
    /// Last progress a pool reported: (iterations, eta).
    pub progress: Option<(u64, Option<f64>)>,
}

/// The state of a study as its events tell it.
#[derive(Debug, Clone, Default)]
pub struct WatchState {
    pub study_id: u64,
    pub progress: v1::StudyProgress,
    pub state: i32,
    pub running: BTreeMap<u64, Running>,
    /// Points started from zero fields.
    pub cold: WorkStats,
    /// Points started from a stored solution.
    pub warm: WorkStats,
    /// Points answered by a stored solution without iterations.
    pub answered: u32,
    /// Finished points seen live (not replayed): the rate behind the ETA.
    pub finished_live: u32,
    failures: HashMap<u64, String>,
    /// The last snapshot's line: a study to an accuracy is snapshotted as each pilot level moves,
    /// its own counts unchanged, and a log wants that line once.
    last_snapshot: Option<String>,
}

impl WatchState {
    pub fn new(study_id: u64) -> Self {
        Self { study_id, ..Self::default() }
    }

    /// Takes one event into account; returns the line a non-terminal display prints for it
    /// (None for replayed events, which only rebuild the state).
    pub fn apply(&mut self, event: &v1::StudyEvent) -> Option<String> {
        if let Some(p) = event.progress {
            self.progress = p;
        }
        self.state = event.state;
        let kind = v1::EventKind::try_from(event.kind).unwrap_or(v1::EventKind::Unspecified);
        let point = event.point.as_ref();
        let id = point.map_or(0, |p| p.point_id);
        let what = point.map(|p| describe_parameters(&p.parameters)).unwrap_or_default();
        let line = match (kind, point) {
            (v1::EventKind::Snapshot, _) => {
                let line = format!("study {}: {}", self.study_id, self.counts());
                if self.last_snapshot.as_ref() == Some(&line) {
                    return None;
                }
                self.last_snapshot = Some(line.clone());
                Some(line)
            }
            (v1::EventKind::PointStarted, Some(p)) => {
                self.running.insert(
                    id,
                    Running {
                        parameters: what.clone(),
                        pool: p.pool_id.clone(),
                        since_unix_ms: event.unix_ms,
                        progress: None,
                    },
                );
                // The origin holds every scene parameter; the swept ones say which neighbour it is.
                let from = match &p.started_from {
                    Some(f) => {
                        let swept = f.parameters.iter().filter(|(k, _)| p.parameters.contains_key(*k));
                        format!(", warm from {}", describe_parameters(&swept.map(|(k, v)| (k.clone(), *v)).collect()))
                    }
                    None => String::new(),
                };
                Some(format!("point {id} started on {} ({what}{from})", p.pool_id))
            }
            (v1::EventKind::PointProgress, Some(p)) => {
                if let Some(r) = self.running.get_mut(&id) {
                    r.progress = Some((p.iterations, p.error_indicator));
                }
                // Progress is for the live display: a line per heartbeat would drown a log.
                return None;
            }
            (v1::EventKind::PointFinished, Some(p)) => {
                self.running.remove(&id);
                if p.answered {
                    self.answered += 1;
                } else if p.started_from.is_some() {
                    self.warm.add(p);
                } else {
                    self.cold.add(p);
                }
                if !event.replay {
                    self.finished_live += 1;
                }
                let how = if p.answered {
                    "answered from a stored solution".to_owned()
                } else {
                    let start = if p.started_from.is_some() { "warm" } else { "cold" };
                    format!(
                        "{} iterations, work {:.1} ({start}), eta {}, {:.2} s",
                        p.iterations,
                        p.work,
                        glissade_core::text::eta_of(p.error_indicator),
                        p.wall_seconds
                    )
                };
                Some(format!("point {id} done ({what}): {how}; {}", self.counts()))
            }
            (v1::EventKind::PointFailed, Some(p)) => {
                self.running.remove(&id);
                self.failures.insert(id, p.error.clone());
                Some(format!("point {id} FAILED ({what}): {}; {}", p.error, self.counts()))
            }
            (v1::EventKind::PointRequeued, Some(p)) => {
                self.running.remove(&id);
                let why = if p.error.is_empty() { "lease lost".to_owned() } else { p.error.clone() };
                Some(format!("point {id} back to pending ({what}): {why}"))
            }
            // (the summary that follows says how it ended: once, not twice)
            _ => None,
        };
        if event.replay { None } else { line }
    }

    /// Whether the study is no longer active (its event stream is over).
    pub fn ended(&self) -> bool {
        self.state != v1::StudyState::Active as i32 && self.state != v1::StudyState::Unspecified as i32
    }

    /// Points finished (done or failed) and the total: the progress bar's position and length.
    pub fn position(&self) -> (u64, u64) {
        let p = &self.progress;
        ((p.done + p.failed + p.cancelled) as u64, p.total as u64)
    }

    /// `4/9 done, 1 failed, 2 running, 2 pending`.
    pub fn counts(&self) -> String {
        let p = &self.progress;
        let mut s = format!("{}/{} done", p.done, p.total);
        if p.failed > 0 {
            s += &format!(", {} failed", p.failed);
        }
        if p.cancelled > 0 {
            s += &format!(", {} cancelled", p.cancelled);
        }
        s + &format!(", {} running, {} pending", p.leased, p.pending)
    }

    /// Mean work cold vs warm so far.
    pub fn iterations(&self) -> String {
        let mut s = format!("mean work cold {} warm {}", self.cold.describe(), self.warm.describe());
        if self.answered > 0 {
            s += &format!(", {} answered", self.answered);
        }
        s
    }

    /// Remaining time from the rate of points finished while watching (None before the first).
    pub fn eta(&self, watched: Duration) -> Option<Duration> {
        let (finished, total) = self.position();
        if self.finished_live == 0 || finished >= total {
            return None;
        }
        let per_point = watched.as_secs_f64() / self.finished_live as f64;
        Some(Duration::from_secs_f64(per_point * (total - finished) as f64))
    }

    /// The running points with their pools and iterations so far, one short line.
    pub fn running_line(&self, now_unix_ms: i64) -> String {
        self.running
            .iter()
            .map(|(id, r)| {
                let seconds = (now_unix_ms - r.since_unix_ms).max(0) as f64 / 1e3;
                let progress = match r.progress {
                    Some((it, Some(eta))) => format!(" it {it} eta {eta:.1e}"),
                    Some((it, None)) => format!(" it {it}"),
                    None => String::new(),
                };
                format!("#{id} [{}] {} {seconds:.0}s{progress}", r.pool, r.parameters)
            })
            .collect::<Vec<_>>()
            .join("; ")
    }

    /// The closing summary: counts, iterations cold vs warm, and every failure's reason.
    pub fn summary(&self, watched: Duration) -> String {
        let mut s = format!(
            "study {} {}: {}; {}; {} iterations in all; watched {:.1} s",
            self.study_id,
            study_state_name(self.state),
            self.counts(),
            self.iterations(),
            self.progress.iterations,
            watched.as_secs_f64()
        );
        if let (Some(c), Some(w)) = (self.cold.mean(), self.warm.mean()) {
            let mean = |work: f64, stats: &WorkStats| WorkMean { work, points: stats.points as usize };
            s += &format!(
                "\n{} (work: dynamic iterations + static iterations / time steps)",
                warm_against_cold(mean(c, &self.cold), mean(w, &self.warm))
            );
        }
        let mut failures: Vec<_> = self.failures.iter().collect();
        failures.sort();
        for (id, why) in failures {
            s += &format!("\npoint {id} {}: {why}", point_state_name(v1::PointState::Failed as i32));
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn progress(done: u32, leased: u32, pending: u32) -> Option<v1::StudyProgress> {
        Some(v1::StudyProgress { total: 3, done, leased, pending, ..Default::default() })
    }

    fn event(kind: v1::EventKind, point: Option<v1::PointStatus>, p: Option<v1::StudyProgress>) -> v1::StudyEvent {
        v1::StudyEvent {
            kind: kind.into(),
            study_id: 7,
            point,
            progress: p,
            state: v1::StudyState::Active.into(),
            replay: false,
            unix_ms: 1_000,
        }
    }

    fn point(id: u64, iterations: u64, warm: bool) -> v1::PointStatus {
        v1::PointStatus {
            point_id: id,
            parameters: [("f1".to_owned(), 0.1 * (id + 1) as f64)].into(),
            pool_id: "a".into(),
            iterations,
            work: iterations as f64 * 0.9,
            started_from: warm.then(v1::SolutionRef::default),
            ..Default::default()
        }
    }

    #[test]
    fn counts_iterations_cold_and_warm_and_estimates_the_rest() {
        let mut w = WatchState::new(7);
        w.apply(&event(v1::EventKind::Snapshot, None, progress(0, 0, 3)));
        let started = w.apply(&event(v1::EventKind::PointStarted, Some(point(0, 0, false)), progress(0, 1, 2)));
        assert_eq!(started.as_deref(), Some("point 0 started on a (f1=0.1)"));
        assert_eq!(w.running.len(), 1);
        w.apply(&event(v1::EventKind::PointFinished, Some(point(0, 100, false)), progress(1, 0, 2)));
        w.apply(&event(v1::EventKind::PointStarted, Some(point(1, 0, true)), progress(1, 1, 1)));
        let line = w.apply(&event(v1::EventKind::PointFinished, Some(point(1, 20, true)), progress(2, 0, 1)));
        assert!(line.unwrap().contains("20 iterations, work 18.0 (warm)"));
        assert_eq!((w.cold.mean(), w.warm.mean()), (Some(90.0), Some(18.0)));
        assert!(w.running.is_empty());
        assert_eq!(w.position(), (2, 3));
        // two points in 10 s: the last one in about 5 s
        assert_eq!(w.eta(Duration::from_secs(10)), Some(Duration::from_secs(5)));
        assert!(w.summary(Duration::from_secs(10)).contains("warm starts cost 5.0x less work than cold ones"));
        assert!(!w.ended());
        // warm points that cost more are said to
        w.apply(&event(v1::EventKind::PointFinished, Some(point(2, 400, true)), progress(3, 0, 0)));
        assert!(w.summary(Duration::from_secs(10)).contains("warm starts cost 2.1x MORE work than cold ones"));
    }

    #[test]
    fn a_snapshot_that_says_nothing_new_is_not_repeated() {
        let mut w = WatchState::new(7);
        let first = w.apply(&event(v1::EventKind::Snapshot, None, progress(0, 0, 3)));
        assert_eq!(first.as_deref(), Some("study 7: 0/3 done, 0 running, 3 pending"));
        assert_eq!(w.apply(&event(v1::EventKind::Snapshot, None, progress(0, 0, 3))), None);
        let moved = w.apply(&event(v1::EventKind::Snapshot, None, progress(1, 0, 2)));
        assert_eq!(moved.as_deref(), Some("study 7: 1/3 done, 0 running, 2 pending"));
    }

    #[test]
    fn replayed_events_rebuild_the_state_silently() {
        let mut w = WatchState::new(7);
        let mut e = event(v1::EventKind::PointFinished, Some(point(0, 50, false)), progress(1, 0, 2));
        e.replay = true;
        assert_eq!(w.apply(&e), None);
        assert_eq!(w.cold.mean(), Some(45.0));
        // replays do not count towards the rate of the ETA
        assert_eq!(w.eta(Duration::from_secs(10)), None);
        let mut end = event(v1::EventKind::StudyEnded, None, progress(3, 0, 0));
        end.state = v1::StudyState::Done.into();
        assert_eq!(w.apply(&end), None, "the summary says it");
        assert!(w.ended());
        assert!(w.summary(Duration::from_secs(1)).starts_with("study 7 done: 3/3 done, 0 running, 0 pending; "));
    }
}
