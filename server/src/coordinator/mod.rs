//! The domain layer of the coordinator: studies, design points and their leases, stored
//! solutions; every rule of dispatch and durability. No gRPC here: the services (`user.rs`,
//! `pool.rs`) validate messages, call these methods and map [`CoordError`] to a status.
//!
//! State lives in memory (one mutex) and is written through to the [`Store`] in one atomic,
//! durable batch per change that matters (submission, lease, completion, failure, expiry), before
//! the change is visible to anyone: a SIGKILL at any instant loses nothing that was answered.
//! Heartbeats only move deadlines forward in memory; after a restart every lease gets a fresh
//! deadline, so pools have one lease period to come back.

use glissade_core::text::one_line;
pub use glissade_proto::now_unix_ms;
use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};

use glissade_core::io::solution_file::{self, SolutionFileError, SolutionMeta};
use glissade_core::point::DesignPoint;
use glissade_core::scene::{Scene, mesh_digest};
use glissade_proto::{PointId, StudyId};
use tokio::sync::{Notify, broadcast};

use glissade_core::study::order::OrderKind;
use glissade_core::study::strategy::InitStrategy;

use crate::records::{
    self, AdaptiveSpec, EtaHistory, NEXT_STUDY_KEY, PointRecord, PointResult, PointState, QoiMap, SolutionKey,
    SolutionOrigin, SolutionRecord, StudyRecord, decode, encode, point_key, study_key,
};
use crate::store::{Batch, Store, Tree};
use glissade_core::study::adaptive::{QoiReadings, TargetOutcome};

mod discretisation;
mod held_out;
mod submit;
mod surface;
mod tables;
mod to_accuracy;
mod transitions;
mod types;
use crate::study::{PointStart, StudyPlan, WarmStart};
use tables::{Leases, Pools, Solutions};
use transitions::{Transition, apply};
pub use types::*;

struct StudyEntry {
    record: StudyRecord,
    points: Vec<PointRecord>,
    plan: StudyPlan,
    /// The study's scene, parsed once where the study entered (its submission, or the reopening
    /// of the database), without its mesh bytes: the study list, the checks of its points, its
    /// QoIs' readings and its surfaces read it, none builds a mesh body.
    scene: Arc<Scene>,
}

impl StudyEntry {
    fn progress(&self) -> Progress {
        let mut p = Progress { total: self.points.len() as u32, ..Progress::default() };
        // an adaptive study's points not chosen yet are pending too
        if let Some(a) = self.record.adaptive.as_ref().filter(|_| !self.record.cancelled) {
            let unchosen = a.unchosen(p.total);
            p.total += unchosen;
            p.pending += unchosen;
        }
        for point in &self.points {
            match point.state {
                PointState::Pending => p.pending += 1,
                PointState::Leased { .. } => p.leased += 1,
                PointState::Done => p.done += 1,
                PointState::Failed => p.failed += 1,
                PointState::Cancelled => p.cancelled += 1,
            }
            if point.state == PointState::Done {
                p.iterations += point.result.as_ref().map_or(0, |r| r.iterations);
            }
        }
        p
    }

    fn state(&self) -> StudyState {
        let p = self.progress();
        if self.record.cancelled {
            StudyState::Cancelled
        } else if p.pending + p.leased > 0 {
            StudyState::Active
        } else if p.failed > 0 {
            StudyState::Failed
        } else {
            StudyState::Done
        }
    }

    /// Every scene parameter at point `i`: the scene's defaults overridden by the point's values.
    fn full_parameters(&self, i: usize) -> DesignPoint {
        self.plan.full(&self.points[i])
    }

    /// The stored solution of the point of this study finished last (for `previous`).
    fn previous(&self) -> Option<SolutionKey> {
        let (i, _) = self
            .points
            .iter()
            .enumerate()
            .filter(|(_, p)| p.state == PointState::Done)
            .max_by_key(|(_, p)| p.finished_seq)?;
        Some(SolutionKey::new(&self.record.scene_hash, &self.full_parameters(i)))
    }
}

/// The studies, with a version each that changes whenever the study may have changed: every
/// mutable access goes through [`Studies::get_mut`] or [`Studies::insert`], so a rendering kept
/// under its versions ([`StudyVersion`]) cannot be stale. Reads go through the map itself
/// (`Deref`); code that only reads should not take `get_mut`, or the study's page is built again.
#[derive(Default)]
struct Studies {
    map: BTreeMap<StudyId, StudyEntry>,
    versions: HashMap<StudyId, u64>,
    clock: u64,
}

impl std::ops::Deref for Studies {
    type Target = BTreeMap<StudyId, StudyEntry>;
    fn deref(&self) -> &Self::Target {
        &self.map
    }
}

impl Studies {
    fn tick(&mut self, id: StudyId) {
        self.clock += 1;
        self.versions.insert(id, self.clock);
    }

    fn get_mut(&mut self, id: &StudyId) -> Option<&mut StudyEntry> {
        if self.map.contains_key(id) {
            self.tick(*id);
        }
        self.map.get_mut(id)
    }

    fn insert(&mut self, id: StudyId, entry: StudyEntry) {
        self.tick(id);
        self.map.insert(id, entry);
    }

    /// The versions a study's view reads (its own and its audits'), or None while a point of it
    /// is `leased`: its view then shows the solves' last reports, which change without it.
    fn version(&self, id: StudyId, leased: bool) -> Option<StudyVersion> {
        let entry = self.map.get(&id)?;
        debug_assert_eq!(leased, entry.points.iter().any(|p| matches!(p.state, PointState::Leased { .. })));
        if leased {
            return None;
        }
        let of = |id: StudyId| (id.0, self.versions.get(&id).copied().unwrap_or(0));
        let mut read = vec![of(id)];
        read.extend(entry.record.dependents(|d| self.map.get(&d).map(|e| &e.record)).into_iter().map(|(d, _)| of(d)));
        Some(StudyVersion(read))
    }
}

#[derive(Default)]
struct State {
    studies: Studies,
    solutions: Solutions,
    leases: Leases,
    pools: Pools,
    /// Surface audits whose predictions a lease call is making (outside the lock).
    predicting: std::collections::HashSet<StudyId>,
    next_study: u64,
    next_finish_seq: u64,
}

/// The coordinator: shared by every gRPC handler.
pub struct Coordinator {
    store: Arc<dyn Store>,
    config: Config,
    state: Mutex<State>,
    events: broadcast::Sender<Event>,
    /// Woken when points may have become available to pools.
    work: Notify,
    /// True once the server is stopping: long polls and event streams end.
    stopping: tokio::sync::watch::Sender<bool>,
    /// Leases lost since this process started (a counter for /metrics).
    leases_expired: AtomicU64,
}

impl Coordinator {
    /// Loads every study, point and solution record from `store`, rebuilds the nearest-neighbour
    /// indexes, and gives every lease found a fresh deadline (its pool may be reconnecting).
    pub fn open(store: Arc<dyn Store>, config: Config) -> Result<Self, CoordError> {
        let mut state = State::default();
        let counter = |key: &[u8]| -> Result<u64, CoordError> {
            Ok(store.get(Tree::Meta, key)?.as_deref().and_then(records::decode_u64).unwrap_or(1))
        };
        state.next_study = counter(NEXT_STUDY_KEY)?;

        let mut in_key_order = Vec::new();
        for (key, value) in store.scan_prefix(Tree::Solutions, b"")? {
            let record: SolutionRecord = decode("solutions", &key, &value)?;
            let key = SolutionKey::new(&record.scene_hash, &record.parameters);
            in_key_order.push(key.clone());
            state.solutions.load(key, record);
        }
        let deadline = now_unix_ms() + config.lease.as_millis() as i64;
        let mut batch = Batch::new();
        for (key, value) in store.scan_prefix(Tree::Studies, b"")? {
            let record: StudyRecord = decode("studies", &key, &value)?;
            let scene = Scene::parse(&record.scene).map_err(|e| records::DecodeError {
                tree: "studies",
                key: record.id.to_string(),
                message: format!("stored scene no longer parses: {e}"),
            })?;
            let mut points = Vec::new();
            for (pkey, pvalue) in store.scan_prefix(Tree::Points, &study_key(record.id))? {
                let mut point: PointRecord = decode("points", &pkey, &pvalue)?;
                if let PointState::Leased { lease_id, deadline_unix_ms, .. } = &mut point.state {
                    *deadline_unix_ms = (*deadline_unix_ms).max(deadline);
                    state.leases.grant(*lease_id, point.study, point.id);
                    batch.put(Tree::Points, pkey.clone(), encode(&point));
                }
                // (its record keeps the history: read back when shown)
                if let Some(r) = point.result.as_mut() {
                    r.eta_history.leave_stored();
                }
                if let Some(seq) = point.finished_seq {
                    state.next_finish_seq = state.next_finish_seq.max(seq + 1);
                }
                points.push(point);
            }
            let plan = StudyPlan::new(&scene, &record, &points).map_err(|e| records::DecodeError {
                tree: "studies",
                key: record.id.to_string(),
                message: format!("stored study: {e}"),
            })?;
            if let Err(e) = state.solutions.index_scene(&record.scene_hash, plan.space(), &store) {
                tracing::warn!(study = %record.id, error = %e, "no warm starts for this scene");
            }
            state.studies.insert(record.id, StudyEntry { record, points, plan, scene: Arc::new(scene) });
        }
        store.commit(batch)?;
        // The nearest-neighbour indexes, rebuilt from the records (the fields stay on disk).
        state.solutions.index_loaded(&in_key_order)?;
        tracing::info!(
            studies = state.studies.len(),
            solutions = state.solutions.len(),
            leases = state.leases.len(),
            bytes = store.size_on_disk()?,
            "loaded the database"
        );
        let (events, _) = broadcast::channel(4096);
        let (stopping, _) = tokio::sync::watch::channel(false);
        Ok(Self {
            store,
            config,
            state: Mutex::new(state),
            events,
            work: Notify::new(),
            stopping,
            leases_expired: AtomicU64::new(0),
        })
    }

    pub fn config(&self) -> &Config {
        &self.config
    }

    /// Why the database can no longer write, if it cannot (a full disk).
    pub fn store_failure(&self) -> Option<String> {
        self.store.write_failure()
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        // A panic in another handler leaves the state as consistent as its last commit.
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Waits until work may be available (a submission, a requeue, a retry).
    pub fn work_notified(&self) -> tokio::sync::futures::Notified<'_> {
        self.work.notified()
    }

    /// Tells long polls and event streams to end (the server is stopping).
    pub fn stop(&self) {
        self.stopping.send_replace(true);
    }

    /// Resolves once [`Coordinator::stop`] was called.
    pub fn stopped(&self) -> impl Future<Output = ()> + Send + 'static {
        let mut receiver = self.stopping.subscribe();
        async move {
            let _ = receiver.wait_for(|&stopping| stopping).await;
        }
    }

    /// Announces a change; `point` as it was stored (its eta history held).
    fn emit(&self, kind: EventKind, entry: &StudyEntry, point: Option<PointRecord>) {
        self.send_event(kind, entry, point, None);
    }

    fn send_event(&self, kind: EventKind, entry: &StudyEntry, point: Option<PointRecord>, solving: Option<(u64, f64)>) {
        let _ = self.events.send(Event {
            kind,
            study: entry.record.id,
            point,
            progress: entry.progress(),
            state: entry.state(),
            replay: false,
            unix_ms: now_unix_ms(),
            solving,
        });
    }

    /// Emits `STUDY_ENDED` if `entry` just stopped being active.
    fn emit_if_ended(&self, entry: &StudyEntry, was: StudyState) {
        let now = entry.state();
        if was == StudyState::Active && now != StudyState::Active {
            self.emit(EventKind::StudyEnded, entry, None);
        }
    }

    /// The one path by which points change: the points after their transitions (each with the
    /// event it announces, if any), the study record if it changed, and `batch`'s other writes
    /// are committed together; then the study in memory takes them; then they are announced
    /// (and the study's end, if this ended it).
    fn commit(
        &self,
        entry: &mut StudyEntry,
        changes: Vec<(PointRecord, Option<EventKind>)>,
        record: Option<StudyRecord>,
        mut batch: Batch,
    ) -> Result<(), CoordError> {
        let was = entry.state();
        if let Some(record) = &record {
            batch.put(Tree::Studies, study_key(record.id), encode(record));
        }
        // when each point ended (the study's finish time and wall time come from them)
        let now = now_unix_ms();
        let mut changes = changes;
        for (p, _) in &mut changes {
            let ended = matches!(p.state, PointState::Done | PointState::Failed | PointState::Cancelled);
            p.finished_unix_ms = ended.then(|| p.finished_unix_ms.unwrap_or(now));
            // a point written again keeps its result's history (a failed point retried)
            self.with_history(p)?;
        }
        for (p, _) in &changes {
            batch.put(Tree::Points, point_key(p.study, p.id), encode(p));
        }
        self.store.commit(batch)?;
        if let Some(record) = record {
            entry.record = record;
        }
        for (mut p, kind) in changes {
            let i = p.id.0 as usize;
            // memory keeps the history's length; its event carries the values, as stored
            let history = p.result.as_mut().and_then(|r| r.eta_history.leave_stored());
            let Some(kind) = kind else {
                entry.points[i] = p;
                continue;
            };
            entry.points[i] = p.clone();
            if let (Some(r), Some(values)) = (p.result.as_mut(), history) {
                r.eta_history = EtaHistory::Held(values);
            }
            self.emit(kind, entry, Some(p));
        }
        self.emit_if_ended(entry, was);
        Ok(())
    }

    /// The eta history in the stored record of point `id` of `study` (none if it holds none).
    fn stored_history(&self, study: StudyId, id: PointId) -> Result<Box<[f64]>, CoordError> {
        let key = point_key(study, id);
        match self.store.get(Tree::Points, &key)? {
            Some(bytes) => Ok(records::decode_eta_history(&key, &bytes)?),
            None => Ok(Box::default()),
        }
    }

    /// Gives `point` (about to be written) its result's eta history, read back from its stored
    /// record where memory holds the length only; under the lock, so the record is the one
    /// memory describes.
    fn with_history(&self, point: &mut PointRecord) -> Result<(), CoordError> {
        let Some(EtaHistory::Stored(n)) = point.result.as_ref().map(|r| &r.eta_history) else { return Ok(()) };
        let n = *n as usize;
        let values = self.stored_history(point.study, point.id)?;
        if values.len() != n {
            return Err(records::DecodeError {
                tree: "points",
                key: point_key(point.study, point.id).iter().map(|b| format!("{b:02x}")).collect(),
                message: format!("an eta history of {} values where {n} were written", values.len()),
            }
            .into());
        }
        if let Some(r) = point.result.as_mut() {
            r.eta_history = EtaHistory::Held(values);
        }
        Ok(())
    }

    /// Reads back from the store the eta histories that `points` (a view's, read under the
    /// lock) hold the length of only: one read a point, outside the lock (the study's page is
    /// built once a version of the study). A point solved again since its view was read shows
    /// the history stored now.
    pub fn read_histories<'a>(&self, points: impl IntoIterator<Item = &'a mut PointRecord>) -> Result<(), CoordError> {
        for p in points {
            if let Some(r) = p.result.as_mut().filter(|r| matches!(r.eta_history, EtaHistory::Stored(_))) {
                r.eta_history = EtaHistory::Held(self.stored_history(p.study, p.id)?);
            }
        }
        Ok(())
    }

    /// The study's view with its points and their eta histories (GetStudy's, the study page's).
    pub fn study_with_histories(&self, id: StudyId) -> Result<StudyView, CoordError> {
        let mut view = self.study(id, true)?;
        self.read_histories(&mut view.points)?;
        Ok(view)
    }

    // ---- users ----

    fn view(state: &State, entry: &StudyEntry, with_points: bool) -> StudyView {
        let studies = &state.studies;
        let solving = entry
            .points
            .iter()
            .filter_map(|p| match p.state {
                PointState::Leased { lease_id, .. } => Some((p.id, state.leases.progress(lease_id)?)),
                _ => None,
            })
            .collect();
        let state = entry.state();
        let r = &entry.record;
        let kind = match (r.audit_of, &r.adaptive, r.listed) {
            (Some(_), ..) => "audit",
            _ if r.pilot_of.is_some() => "pilots",
            (_, Some(_), _) => "adaptive",
            (_, _, true) => "list",
            _ => "grid",
        };
        StudyView {
            solving,
            kind,
            scene_title: entry.scene.title.clone().unwrap_or_default(),
            scene: entry.scene.clone(),
            finished_unix_ms: (state != StudyState::Active)
                .then(|| entry.points.iter().filter_map(|p| p.finished_unix_ms).max())
                .flatten(),
            record: entry.record.clone(),
            state,
            progress: entry.progress(),
            points: if with_points { entry.points.clone() } else { Vec::new() },
            accuracy: entry.record.audit.and_then(|a| studies.get(&a)).map(|audit| accuracy(entry, audit)),
            discretisation: (!entry.record.refined_by.is_empty()).then(|| {
                let levels: Vec<&StudyEntry> = entry.record.refined_by.iter().filter_map(|l| studies.get(l)).collect();
                discretisation::measure(entry, &levels)
            }),
            surface_accuracy: entry
                .record
                .surface_audit
                .and_then(|a| studies.get(&a))
                .map(|a| held_out::measure(entry, a)),
            held_out_check: entry
                .record
                .to_accuracy
                .as_ref()
                .and_then(|t| t.held_out)
                .and_then(|c| studies.get(&c))
                .map(|c| to_accuracy::held_out_check(entry, c)),
            audits: entry
                .record
                .dependents(|id| studies.get(&id).map(|e| &e.record))
                .into_iter()
                .filter_map(|(id, what)| {
                    let a = studies.get(&id)?;
                    Some(AuditView {
                        study: id,
                        what,
                        state: a.state(),
                        progress: a.progress(),
                        why_cancelled: a
                            .points
                            .iter()
                            .find(|p| p.state == PointState::Cancelled && p.error.is_some())
                            .and_then(|p| p.error.clone()),
                    })
                })
                .collect(),
        }
    }

    /// What a rendering of the study's view may be kept under: the same version, the same view
    /// (None while the view changes without a version: a point is being solved).
    pub fn study_version(&self, id: StudyId) -> Result<Option<StudyVersion>, CoordError> {
        let state = self.lock();
        if !state.studies.contains_key(&id) {
            return Err(CoordError::UnknownStudy(id));
        }
        // the leases held (a few per pool), not the study's points (up to millions)
        let leased = state.leases.any_of(id);
        Ok(state.studies.version(id, leased))
    }

    pub fn study(&self, id: StudyId, with_points: bool) -> Result<StudyView, CoordError> {
        let state = self.lock();
        let entry = state.studies.get(&id).ok_or(CoordError::UnknownStudy(id))?;
        Ok(Self::view(&state, entry, with_points))
    }

    /// The study's view with its leased points only (what an open page polls): the points done
    /// are not copied.
    pub fn study_running(&self, id: StudyId) -> Result<StudyView, CoordError> {
        let state = self.lock();
        let entry = state.studies.get(&id).ok_or(CoordError::UnknownStudy(id))?;
        let mut view = Self::view(&state, entry, false);
        view.points = entry.points.iter().filter(|p| matches!(p.state, PointState::Leased { .. })).cloned().collect();
        Ok(view)
    }

    /// The mean work of the study's points solved cold and warm (converged, answered ones aside;
    /// None where there are none), read in place.
    pub fn mean_work(&self, id: StudyId) -> [Option<f64>; 2] {
        let state = self.lock();
        let mut sums = [(0.0, 0usize); 2];
        for r in state.studies.get(&id).into_iter().flat_map(|e| &e.points).filter_map(|p| p.result.as_ref()) {
            if !r.answered && r.converged {
                let s = &mut sums[usize::from(r.started_from.is_some())];
                *s = (s.0 + r.work, s.1 + 1);
            }
        }
        sums.map(|(w, n)| (n > 0).then(|| w / n as f64))
    }

    /// Every study (the lists are paged: [`Self::studies_page`]).
    #[cfg(test)]
    pub fn studies(&self) -> Vec<StudyView> {
        let state = self.lock();
        state.studies.values().map(|e| Self::view(&state, e, false)).collect()
    }

    /// One page of the studies in id order: at most `limit` after `after`, and whether more
    /// follow (only the page's views are built).
    pub fn studies_page(&self, after: StudyId, limit: usize) -> (Vec<StudyView>, bool) {
        let state = self.lock();
        let mut rest = state.studies.range((std::ops::Bound::Excluded(after), std::ops::Bound::Unbounded));
        let page: Vec<StudyView> = rest.by_ref().take(limit).map(|(_, e)| Self::view(&state, e, false)).collect();
        (page, rest.next().is_some())
    }

    /// The events replaying a study's state, and a subscription for what follows (taken under
    /// the same lock, so nothing falls between them).
    pub fn watch(&self, id: StudyId) -> Result<(Vec<Event>, broadcast::Receiver<Event>), CoordError> {
        let state = self.lock();
        let entry = state.studies.get(&id).ok_or(CoordError::UnknownStudy(id))?;
        let receiver = self.events.subscribe();
        let (progress, study_state, unix_ms) = (entry.progress(), entry.state(), now_unix_ms());
        let event = |kind, point: Option<&PointRecord>| Event {
            kind,
            study: id,
            point: point.cloned(),
            progress,
            state: study_state,
            replay: true,
            unix_ms,
            solving: None,
        };
        let mut replay = vec![event(EventKind::Snapshot, None)];
        for p in &entry.points {
            let kind = match p.state {
                PointState::Leased { .. } => EventKind::Started,
                PointState::Done => EventKind::Finished,
                PointState::Failed => EventKind::Failed,
                PointState::Pending | PointState::Cancelled => continue,
            };
            replay.push(event(kind, Some(p)));
        }
        if study_state != StudyState::Active {
            replay.push(event(EventKind::StudyEnded, None));
        }
        drop(state);
        self.read_histories(replay.iter_mut().filter_map(|e| e.point.as_mut()))?;
        Ok((replay, receiver))
    }

    pub fn cancel(&self, id: StudyId) -> Result<StudyView, CoordError> {
        let mut state = self.lock();
        let entry = state.studies.get_mut(&id).ok_or(CoordError::UnknownStudy(id))?;
        let was = entry.state();
        if was != StudyState::Active {
            return Err(CoordError::Precondition(format!(
                "study {id} is {} already: nothing to cancel",
                state_word(was)
            )));
        }
        let mut record = entry.record.clone();
        record.cancelled = true;
        // leased points are cancelled when their pools give them back or their leases expire
        let changes = entry
            .points
            .iter()
            .filter(|p| p.state == PointState::Pending)
            .map(|p| Ok((apply(p, Transition::Cancel)?, None)))
            .collect::<Result<_, CoordError>>()?;
        self.commit(entry, changes, Some(record), Batch::new())?;
        tracing::info!(study = %id, "study cancelled");
        let audits: Vec<StudyId> = entry
            .record
            .audit
            .into_iter()
            .chain(entry.record.refined_by.clone())
            .chain(entry.record.surface_audit)
            .chain(entry.record.to_accuracy.iter().flat_map(|t| t.levels.iter().map(|l| l.2).chain(t.held_out)))
            .collect();
        // its audits (and its pilots' levels) have nothing left to measure
        for audit in audits {
            if state.studies.get(&audit).is_some_and(|a| a.state() == StudyState::Active) {
                drop(state);
                self.cancel(audit)?;
                state = self.lock();
            }
        }
        let entry = state.studies.get(&id).expect("cancelled above");
        Ok(Self::view(&state, entry, false))
    }

    /// Requeues the study's failed points, except those whose scene is invalid at their
    /// parameters (core::check, the pool's check before solving): they would fail again. Returns
    /// the number requeued, the number kept and why (the first kept point's reason).
    pub fn retry_failed(&self, id: StudyId) -> Result<(u32, (u32, String), StudyView), CoordError> {
        let mut state = self.lock();
        let entry = state.studies.get_mut(&id).ok_or(CoordError::UnknownStudy(id))?;
        if entry.record.cancelled {
            return Err(CoordError::Precondition(format!("study {id} is cancelled: its points are not retried")));
        }
        // (stored meshes are attached to a lease, not here: only the per-point check runs)
        let scene = Arc::clone(&entry.scene);
        let bad_input = |i: usize| -> Option<String> {
            let values = scene.parameter_values(&entry.full_parameters(i));
            values
                .and_then(|v| scene.check_point(&v))
                .err()
                .map(|e| format!("point {i}: {}: retrying cannot help", one_line(&e.to_string())))
        };
        let mut kept = (0, String::new());
        let mut changes = Vec::new();
        for (i, p) in entry.points.iter().enumerate().filter(|(_, p)| p.state == PointState::Failed) {
            if let Some(why) = bad_input(i) {
                if kept.0 == 0 {
                    kept.1 = why;
                }
                kept.0 += 1;
                continue;
            }
            changes.push((apply(p, Transition::Retry)?, None));
        }
        let requeued = changes.len() as u32;
        self.commit(entry, changes, None, Batch::new())?;
        if requeued > 0 {
            tracing::info!(study = %id, requeued, "failed points requeued");
            self.emit(EventKind::Snapshot, entry, None);
        }
        let view = Self::view(&state, &state.studies[&id], false);
        drop(state);
        self.work.notify_waiters();
        Ok((requeued, kept, view))
    }

    // ---- pools ----

    pub fn register_pool(&self, id: String, info: PoolInfo) {
        tracing::info!(pool = %id, ranks = info.ranks, host = %info.host, version = %info.solver_version, "pool registered");
        let mut state = self.lock();
        state.pools.register(id, info);
    }

    /// Counts of studies, points, leases and pools now; walks every point under the lock, so
    /// it is for a scrape every few seconds, not a hot path.
    pub fn gauges(&self) -> Gauges {
        let mut g = Gauges {
            studies: StudyState::ALL.iter().map(|&s| (state_word(s), 0)).collect(),
            points: POINT_STATE_WORDS.iter().map(|&w| (w, 0)).collect(),
            leases_expired: self.leases_expired.load(Ordering::Relaxed),
            ..Gauges::default()
        };
        let state = self.lock();
        for entry in state.studies.values() {
            *g.studies.entry(state_word(entry.state())).or_default() += 1;
            g.pending += u64::from(entry.progress().pending);
            for point in &entry.points {
                *g.points.entry(point_state_word(&point.state)).or_default() += 1;
            }
        }
        g.leases = state.leases.len() as u64;
        g.pools_connected = state.pools.connected(self.config.lease) as u64;
        g
    }

    /// Bytes of the database on disk.
    pub fn store_bytes(&self) -> Result<u64, CoordError> {
        Ok(self.store.size_on_disk()?)
    }

    /// Leases the next point to `pool`, if any is pending. Points that a stored solution answers
    /// (same scene and solver version, converged at this tolerance or a tighter one: the
    /// solver's stopping test bounds every QoI's error by its tolerance) are marked done on the way.
    pub fn lease(&self, pool: &str) -> Result<Option<LeaseGrant>, CoordError> {
        self.expire_leases()?;
        self.predict_held_out()?;
        let mut state = self.lock();
        self.advance_to_accuracy(&mut state)?;
        let version = state.pools.solver_version(pool)?.to_owned();
        state.pools.seen(pool);
        // audits when nothing else is pending: they measure, they answer no one
        let mut ids: Vec<StudyId> = state.studies.keys().copied().collect();
        ids.sort_by_key(|id| (state.studies[id].record.audit_of.is_some(), *id));
        for id in ids {
            loop {
                let State { studies, solutions, .. } = &mut *state;
                // an audit waits for its study's end, solves one point at a time, and stops at its cap
                let audit_budget = match studies[&id].record.audit_of {
                    None => None,
                    Some(of) => match audit_budget(studies.get(&of), &studies[&id]) {
                        None => break,
                        // a discretisation level waits as an audit does, but the iteration
                        // audit's work cap is not its: a level cut short measures nothing, so it
                        // stops before a point that would pass the levels' cap
                        // (discretisation::level_over_cap; its bounds: MAX_REFINE_POINTS,
                        // MAX_REFINE_LEVELS)
                        Some(_) if studies[&id].record.refines.is_some() => {
                            let (study, level) = (&studies[&of], &studies[&id]);
                            let levels = studies
                                .values()
                                .filter(|e| e.record.audit_of == Some(of) && e.record.refines.is_some());
                            if let Some(why) = discretisation::level_over_cap(study, level, levels) {
                                let entry = studies.get_mut(&id).expect("id listed above");
                                self.stop_audit(entry, why)?;
                                break;
                            }
                            None
                        }
                        // (nor the held-out check of a study to an accuracy: cut short, it
                        // confirms nothing)
                        Some(_) if studies[&id].record.confirms.is_some() => None,
                        Some(budget) => Some(budget),
                    },
                };
                // (read first, changed only where it changes: a study changed is a new version
                // of its page, Studies)
                if waits(&studies[&id]) {
                    break;
                }
                self.choose_adaptive_point(studies, id)?;
                // (the cheap test first: the policy copies every point)
                let entry = &studies[&id];
                if entry.record.cancelled || !entry.points.iter().any(|p| p.state == PointState::Pending) {
                    break;
                }
                let entry = studies.get_mut(&id).expect("id listed above");
                let Some(i) = entry.plan.next(&entry.points) else { break };
                let start = entry.plan.start(
                    &entry.record,
                    &entry.points[i],
                    solutions.scene(&entry.record.scene_hash),
                    entry.previous().as_ref(),
                    &version,
                );
                let init = match start {
                    // a good enough stored solution is the answer (within any audit's cap: it costs nothing)
                    PointStart::Answer(key) => {
                        let answer = solutions.indexed(&key);
                        self.answer(&mut state, id, i, &answer)?;
                        continue;
                    }
                    PointStart::Solve(_) if audit_budget.is_some_and(|b| b.remaining() < 1.0) => {
                        let budget = audit_budget.expect("tested");
                        self.stop_audit(entry, spent_reason(&budget))?;
                        break;
                    }
                    PointStart::Solve(init) => init,
                };
                let lease_id = state.leases.new_id();
                let deadline = now_unix_ms() + self.config.lease.as_millis() as i64;
                let entry = state.studies.get_mut(&id).expect("id listed above");
                let max_iterations = match audit_budget {
                    Some(budget) => entry.record.max_iterations.min(budget.remaining() as u32),
                    None => entry.record.max_iterations,
                };
                let lease = Transition::Lease {
                    pool: pool.to_owned(),
                    lease_id,
                    deadline_unix_ms: deadline,
                    init: init.as_ref().map(|w| Box::new(w.origin.clone())),
                    cap: (max_iterations < entry.record.max_iterations).then_some(max_iterations),
                };
                let point = apply(&entry.points[i], lease)?;
                let grant = LeaseGrant {
                    lease_id,
                    study: id,
                    point: point.id,
                    parameters: point.parameters.clone(),
                    scene_text: entry.record.scene.clone(),
                    scene_hash: entry.record.scene_hash.clone(),
                    tolerance: entry.record.tolerance,
                    max_iterations,
                    deadline_unix_ms: deadline,
                    init,
                    meshes: entry.record.meshes.clone(),
                };
                self.commit(entry, vec![(point, Some(EventKind::Started))], None, Batch::new())?;
                tracing::info!(study = %id, point = i, pool, lease_id, "leased");
                state.leases.grant(lease_id, id, PointId(i as u64));
                return Ok(Some(grant));
            }
        }
        Ok(None)
    }

    /// Makes the predictions of the surface audits whose study has ended: each study's surface,
    /// fitted to its points, at its held-out points, recorded before any of them is leased. The
    /// fits run outside the lock, one caller per audit. An audit whose study's surface predicts
    /// nothing (too few points done) has its points cancelled with the reason.
    fn predict_held_out(&self) -> Result<(), CoordError> {
        let jobs: Vec<held_out::Job> = {
            let mut state = self.lock();
            let State { studies, predicting, .. } = &mut *state;
            let ready: Vec<held_out::Job> = studies
                .values()
                .filter(|a| a.record.held_out.as_ref().is_some_and(|h| h.predicted.is_none()))
                .filter(|a| !a.record.cancelled && !predicting.contains(&a.record.id))
                .filter_map(|a| {
                    let study = studies.get(&a.record.audit_of?)?;
                    (study.state() != StudyState::Active).then(|| held_out::job(study, a))
                })
                .collect();
            predicting.extend(ready.iter().map(|j| j.audit));
            ready
        };
        let mut result = Ok(());
        for job in jobs {
            let predicted = held_out::predict(&job);
            let mut state = self.lock();
            state.predicting.remove(&job.audit);
            let Some(entry) = state.studies.get_mut(&job.audit) else { continue };
            if result.is_err() || entry.record.held_out.as_ref().is_none_or(|h| h.predicted.is_some()) {
                continue;
            }
            let why = (!held_out::predicts_anything(&predicted)).then(|| {
                let reasons: Vec<String> = predicted
                    .refused
                    .iter()
                    .map(|(q, e)| if q.is_empty() { e.clone() } else { format!("{q}: {e}") })
                    .collect();
                format!("not solved: the study's surface predicts nothing here ({})", reasons.join("; "))
            });
            let changes = entry
                .points
                .iter()
                .filter(|p| why.is_some() && p.state == PointState::Pending)
                .map(|p| {
                    let mut cancelled = apply(p, Transition::Cancel)?;
                    cancelled.error = why.clone();
                    Ok((cancelled, None))
                })
                .collect::<Result<Vec<_>, CoordError>>()?;
            let mut record = entry.record.clone();
            tracing::info!(study = %job.audit, fitted = predicted.fitted, "surface audit: predictions made");
            let drawn = record.held_out.take().unwrap_or_default();
            record.held_out = Some(records::HeldOut { predicted: Some(predicted), ..drawn });
            result = self.commit(entry, changes, Some(record), Batch::new());
        }
        result
    }

    /// Cancels the pending points of an audit whose cost cap is spent, saying so on each.
    fn stop_audit(&self, entry: &mut StudyEntry, reason: String) -> Result<(), CoordError> {
        let changes = entry
            .points
            .iter()
            .filter(|p| p.state == PointState::Pending)
            .map(|p| {
                let mut cancelled = apply(p, Transition::Cancel)?;
                cancelled.error = Some(reason.clone());
                Ok((cancelled, None))
            })
            .collect::<Result<Vec<_>, CoordError>>()?;
        if !changes.is_empty() {
            tracing::info!(study = %entry.record.id, points = changes.len(), %reason, "audit stopped at its cost cap");
            self.commit(entry, changes, None, Batch::new())?;
        }
        Ok(())
    }

    /// An adaptive study with no point pending takes its next step ([`adaptive_choice`]); the
    /// study is changed only where the step changes it.
    fn choose_adaptive_point(&self, studies: &mut Studies, id: StudyId) -> Result<(), CoordError> {
        let entry = &studies[&id];
        if entry.record.adaptive.is_none()
            || entry.record.cancelled
            || entry.points.iter().any(|p| p.state == PointState::Pending)
        {
            return Ok(());
        }
        match adaptive_choice(entry)? {
            AdaptiveChoice::None => Ok(()),
            choice => self.apply_adaptive_choice(studies.get_mut(&id).expect("listed"), choice),
        }
    }

    /// Makes what [`adaptive_choice`] decided: the outcome recorded, the next point added, or
    /// the choice ended at the points it has.
    fn apply_adaptive_choice(&self, entry: &mut StudyEntry, choice: AdaptiveChoice) -> Result<(), CoordError> {
        match choice {
            AdaptiveChoice::None => Ok(()),
            AdaptiveChoice::End(spec) => self.end_adaptive_choice(entry, spec),
            AdaptiveChoice::Outcome(record) => self.commit(entry, Vec::new(), Some(*record), Batch::new()),
            AdaptiveChoice::Point(next) => {
                let point = PointRecord::pending(entry.record.id, PointId(entry.points.len() as u64), next);
                let mut batch = Batch::new();
                batch.put(Tree::Points, point_key(point.study, point.id), encode(&point));
                self.store.commit(batch)?;
                tracing::info!(study = %entry.record.id, point = point.id.0, at = %point.parameters, "adaptive point chosen");
                entry.points.push(point);
                Ok(())
            }
        }
    }

    /// Ends an adaptive study's choice at the points it has chosen (their number becomes its
    /// budget).
    fn end_adaptive_choice(&self, entry: &mut StudyEntry, spec: AdaptiveSpec) -> Result<(), CoordError> {
        let mut record = entry.record.clone();
        record.adaptive = Some(AdaptiveSpec { budget: entry.points.len() as u32, ..spec });
        let mut batch = Batch::new();
        batch.put(Tree::Studies, study_key(record.id), encode(&record));
        self.store.commit(batch)?;
        entry.record = record;
        Ok(())
    }

    /// Marks done every pending point of study `id` that a stored solution answers as it is, for
    /// a pool of this coordinator's solver version (the one its pools run).
    fn answer_stored(&self, state: &mut State, id: StudyId) -> Result<(), CoordError> {
        let entry = &state.studies[&id];
        let solutions = state.solutions.scene(&entry.record.scene_hash);
        let answers: Vec<(usize, SolutionKey)> = entry
            .points
            .iter()
            .enumerate()
            .filter(|(_, p)| p.state == PointState::Pending)
            .filter_map(|(i, p)| Some((i, entry.plan.answer(p, solutions, &self.config.solver_version)?)))
            .collect();
        for (i, key) in answers {
            let answer = state.solutions.indexed(&key);
            self.answer(state, id, i, &answer)?;
        }
        Ok(())
    }

    /// Marks point `i` of study `id` done from the stored solution `answer` (0 iterations).
    fn answer(&self, state: &mut State, id: StudyId, i: usize, answer: &SolutionRecord) -> Result<(), CoordError> {
        let seq = state.next_finish_seq;
        let entry = state.studies.get_mut(&id).expect("caller checked");
        let result = PointResult {
            pool: String::new(),
            converged: true,
            iterations: 0,
            error_indicator: answer.error_indicator,
            qoi: answer.qoi.clone(),
            wall_seconds: 0.0,
            started_from: Some(Box::new(answer.origin())),
            answered: true,
            eta_history: EtaHistory::default(),
            work: 0.0,
            contact: answer.contact.clone(),
            qoi_largest: answer.qoi_largest.clone(),
        };
        let point = apply(&entry.points[i], Transition::Answer { result, finished_seq: seq })?;
        self.commit(entry, vec![(point, Some(EventKind::Finished))], None, Batch::new())?;
        tracing::info!(study = %id, point = i, "answered from a stored solution");
        state.next_finish_seq = seq + 1;
        Ok(())
    }

    /// A stored mesh file by its SHA-256 (hex), checked against it.
    pub fn mesh_bytes(&self, sha256: &str) -> Result<Vec<u8>, CoordError> {
        let stored =
            self.store.get(Tree::Meshes, sha256.as_bytes())?.ok_or_else(|| CoordError::UnknownMesh(sha256.into()))?;
        let bytes =
            records::decode_fields(&stored).map_err(|e| CoordError::Corrupt(format!("stored mesh {sha256}: {e}")))?;
        if mesh_digest(&bytes) != sha256 {
            return Err(CoordError::Corrupt(format!("stored mesh {sha256}: its bytes do not match the digest")));
        }
        Ok(bytes)
    }

    /// The warm start's solution file bytes.
    pub fn warm_start_bytes(&self, warm: &WarmStart) -> Result<Vec<u8>, CoordError> {
        warm.bytes().map_err(|e| CoordError::Corrupt(format!("warm start from {}: {e}", warm.origin.parameters)))
    }

    /// Finds the point a pool's request names, and checks the pool holds it under `lease_id`
    /// (an expired lease is lost: its point may already be solved elsewhere).
    fn held<'a>(
        state: &'a mut State,
        pool: &str,
        lease_id: u64,
        study: StudyId,
        point: PointId,
    ) -> Result<(&'a mut StudyEntry, usize), CoordError> {
        let entry = state.studies.get_mut(&study).ok_or(CoordError::UnknownStudy(study))?;
        let i = usize::try_from(point.0)
            .ok()
            .filter(|&i| i < entry.points.len())
            .ok_or(CoordError::UnknownPoint { study, point })?;
        let p = &entry.points[i];
        let holds = match &p.state {
            PointState::Leased { pool: holder, lease_id: l, .. } => holder == pool && *l == lease_id,
            _ => false,
        };
        if !holds {
            let now = match &p.state {
                // never the lease id: whoever knows it may speak for the lease
                PointState::Leased { pool: holder, .. } if holder == pool => "it is held under another lease".into(),
                PointState::Leased { pool: holder, .. } => format!("it is leased to pool `{holder}`"),
                other => format!("it is {}", point_state_word(other)),
            };
            return Err(CoordError::Precondition(format!(
                "pool `{pool}` does not hold point {point} of study {study} under the lease given: {now}"
            )));
        }
        Ok((entry, i))
    }

    /// Checks, before the chunks are read, that a completion may be accepted at all.
    pub fn check_held(&self, pool: &str, lease_id: u64, study: StudyId, point: PointId) -> Result<(), CoordError> {
        let mut state = self.lock();
        Self::held(&mut state, pool, lease_id, study, point).map(drop)
    }

    /// Stores a solved point: the solution (if better than the one stored at its parameters),
    /// and the point as DONE, or FAILED when not converged (retryable, its last iterate kept).
    pub fn complete(&self, c: Completion, file: Vec<u8>) -> Result<PointRecord, CoordError> {
        let started = std::time::Instant::now();
        let (meta, solution) = solution_file::read_from(&file[..]).map_err(|e| match e {
            SolutionFileError::Checksum => CoordError::Corrupt(format!("solution of point {}: {e}", c.point)),
            e => CoordError::invalid_worded("solution", format_args!("solution of point {}: {e}", c.point)),
        })?;
        let (study_hash, full) = {
            let state = self.lock();
            let entry = state.studies.get(&c.study).ok_or(CoordError::UnknownStudy(c.study))?;
            let i = c.point.0 as usize;
            if i >= entry.points.len() {
                return Err(CoordError::UnknownPoint { study: c.study, point: c.point });
            }
            (entry.record.scene_hash.clone(), entry.full_parameters(i))
        };
        check_meta(&meta, &c, &study_hash, &full)?;
        let checked = started.elapsed();
        // Compress outside the lock: it is the costly part.
        let compressed = records::encode_fields(&file)
            .map_err(|e| CoordError::invalid_worded("solution", format_args!("compressing: {e}")))?;
        let compressed_at = started.elapsed();

        let mut state = self.lock();
        let seq = state.next_finish_seq;
        let current_version = self.config.solver_version.clone();
        let key = SolutionKey::new(&study_hash, &full);
        let old = state.solutions.get(&key).cloned();
        let (entry, i) = Self::held(&mut state, &c.pool, c.lease_id, c.study, c.point)?;
        let started_from = if c.started_cold { None } else { leased_from(&entry.points[i]) };
        let sizes = (file.len() as u64, compressed.len() as u64);
        let (record, result) =
            completion_records(&c, &meta, &study_hash, &full, started_from, sizes, entry.record.tolerance);
        let converged = result.converged;
        let tolerance = entry.record.tolerance;
        let point = apply(&entry.points[i], Transition::Complete { result, finished_seq: seq, tolerance })?;
        // a study with a target: judged with this point, in the same commit (so its outcome is
        // known when it ends)
        let judged =
            entry.record.adaptive.as_ref().filter(|a| a.target.is_some() && a.outcome.is_none()).and_then(|a| {
                let mut points = entry.points.clone();
                points[i] = point.clone();
                let (outcome, _) = adaptive_step(entry, &points, false);
                let mut record = entry.record.clone();
                record.adaptive = Some(AdaptiveSpec { outcome: Some(outcome?), ..a.clone() });
                Some(record)
            });
        let mut batch = Batch::new();
        let keep = old.as_ref().is_none_or(|old| record.replaces(old, &current_version));
        if keep {
            let bytes = key.to_bytes();
            batch.put(Tree::Solutions, bytes.clone(), encode(&record));
            batch.put(Tree::SolutionFields, bytes, compressed);
        }
        // (a point cut short by its audit's cap is cancelled, as the cap's other points are)
        let kind = match point.state {
            PointState::Done => Some(EventKind::Finished),
            PointState::Cancelled => None,
            _ => Some(EventKind::Failed),
        };
        self.commit(entry, vec![(point.clone(), kind)], judged, batch)?;
        tracing::debug!(
            check_ms = checked.as_secs_f64() * 1e3,
            compress_ms = (compressed_at - checked).as_secs_f64() * 1e3,
            commit_ms = (started.elapsed() - compressed_at).as_secs_f64() * 1e3,
            "completion costs"
        );
        tracing::info!(
            study = %c.study,
            point = i,
            pool = %c.pool,
            iterations = c.iterations,
            converged,
            file_bytes = file.len(),
            stored_bytes = if keep { record.stored_bytes } else { 0 },
            "completed"
        );
        if converged {
            state.next_finish_seq = seq + 1;
        }
        state.leases.end(c.lease_id);
        if keep {
            state.solutions.insert(key, record, file, solution)?;
        }
        Ok(point)
    }

    /// Removes every solution `pool` sent, from the database, the indexes and their decoded
    /// copies: a pool token can store a forged answer, which later studies would be served
    /// (issue 48). The points it solved keep their results (what they were answered); no later
    /// point starts from one of its solutions or is answered by one. Returns how many.
    pub fn purge_pool(&self, pool: &str) -> Result<usize, CoordError> {
        let mut state = self.lock();
        let keys = state.solutions.of_pool(pool);
        if keys.is_empty() {
            return Ok(0);
        }
        let mut batch = Batch::new();
        for key in &keys {
            let bytes = key.to_bytes();
            batch.delete(Tree::Solutions, bytes.clone()).delete(Tree::SolutionFields, bytes);
        }
        self.store.commit(batch)?;
        state.solutions.remove(&keys, &self.store)?;
        tracing::warn!(pool, purged = keys.len(), "purged the solutions of a pool");
        Ok(keys.len())
    }

    /// Records a solver failure: the point is FAILED with the error (retryable).
    pub fn fail(&self, f: Failure) -> Result<PointRecord, CoordError> {
        let mut state = self.lock();
        let (entry, i) = Self::held(&mut state, &f.pool, f.lease_id, f.study, f.point)?;
        let result = PointResult {
            pool: f.pool.clone(),
            converged: false,
            iterations: f.iterations,
            error_indicator: f.error_indicator.unwrap_or(f64::MAX),
            qoi: QoiMap::default(),
            wall_seconds: 0.0,
            started_from: leased_from(&entry.points[i]),
            answered: false,
            eta_history: EtaHistory::default(),
            work: 0.0,
            contact: Vec::new(),
            qoi_largest: QoiMap::default(),
        };
        // a pool's message, bounded and printable before it is stored, logged or shown
        let error = one_line(&f.error);
        let point = apply(&entry.points[i], Transition::Fail { result, error: error.clone() })?;
        self.commit(entry, vec![(point.clone(), Some(EventKind::Failed))], None, Batch::new())?;
        tracing::warn!(study = %f.study, point = i, pool = %f.pool, error = %error, "point failed");
        state.leases.end(f.lease_id);
        Ok(point)
    }

    /// A pool gives a point back unsolved: pending again, the attempt not counted.
    pub fn release(
        &self,
        pool: &str,
        lease_id: u64,
        study: StudyId,
        point: PointId,
    ) -> Result<PointRecord, CoordError> {
        let mut state = self.lock();
        let (entry, i) = Self::held(&mut state, pool, lease_id, study, point)?;
        let mut p = apply(&entry.points[i], Transition::Release { study_cancelled: entry.record.cancelled })?;
        // (answered with the result it keeps, its history too)
        self.with_history(&mut p)?;
        self.commit(entry, vec![(p.clone(), Some(EventKind::Requeued))], None, Batch::new())?;
        tracing::info!(study = %study, point = i, pool, "released");
        state.leases.end(lease_id);
        drop(state);
        self.work.notify_waiters();
        Ok(p)
    }

    /// Extends the pool's leases and forwards the progress it reports for them, (lease,
    /// iterations, eta), to the studies' watchers. For each lease: its new deadline and whether
    /// its solve should stop (its study was cancelled), or None when it is no longer the pool's.
    pub fn heartbeat(&self, pool: &str, lease_ids: &[u64], progress: &[(u64, u64, f64)]) -> Vec<Option<(i64, bool)>> {
        let mut state = self.lock();
        // only registered pools: the ids seen stay as many as the pools
        state.pools.seen(pool);
        let deadline = now_unix_ms() + self.config.lease.as_millis() as i64;
        let State { studies, leases, .. } = &mut *state;
        let deadlines: Vec<Option<(i64, bool)>> = lease_ids
            .iter()
            .map(|lease_id| {
                let lease = leases.get(*lease_id)?;
                let (study, point) = (lease.study, lease.point);
                let entry = studies.get_mut(&study)?;
                let cancelled = entry.record.cancelled;
                let p = entry.points.get_mut(point.0 as usize)?;
                match &mut p.state {
                    PointState::Leased { pool: holder, lease_id: l, deadline_unix_ms, .. }
                        if holder == pool && l == lease_id =>
                    {
                        *deadline_unix_ms = deadline;
                        Some((deadline, cancelled))
                    }
                    _ => None,
                }
            })
            .collect();
        // Progress only for the leases just found to be this pool's.
        let held = |id: u64| lease_ids.iter().zip(&deadlines).any(|(&l, d)| l == id && d.is_some());
        for &(lease_id, iterations, eta) in progress.iter().filter(|p| p.2.is_finite() && held(p.0)) {
            // a heartbeat that finds the solve where the last one left it tells watchers nothing
            if !leases.report(lease_id, iterations, eta) {
                continue;
            }
            let Some(&tables::Lease { study, point, .. }) = leases.get(lease_id) else { continue };
            let entry = &studies[&study];
            // (a point solved again after a retry shows its last result, its history with it)
            let mut shown = entry.points[point.0 as usize].clone();
            if let Err(e) = self.with_history(&mut shown) {
                tracing::error!(%study, %point, error = %e, "an eta history could not be read back");
                if let Some(r) = shown.result.as_mut() {
                    r.eta_history = EtaHistory::default();
                }
            }
            self.send_event(EventKind::Progress, entry, Some(shown), Some((iterations, eta)));
        }
        deadlines
    }

    /// Requeues (or fails, after `max_attempts`) every point whose lease deadline passed, and
    /// fails every point leased for longer than the per-point budget.
    pub fn expire_leases(&self) -> Result<usize, CoordError> {
        let now = now_unix_ms();
        let mut state = self.lock();
        let State { studies, leases, .. } = &mut *state;
        let mut expired = 0;
        let ids: Vec<StudyId> = studies.keys().copied().collect();
        for id in ids {
            // (read, and changed only where a lease expired: Studies' versions)
            let entry = &studies[&id];
            let mut changes = Vec::new();
            let mut lost = Vec::new();
            for (i, p) in entry.points.iter().enumerate() {
                let PointState::Leased { pool, lease_id, deadline_unix_ms, .. } = &p.state else { continue };
                let over_budget = leases.held_for(*lease_id) > self.config.point_budget;
                if *deadline_unix_ms > now && !over_budget {
                    continue;
                }
                let last = match leases.progress(*lease_id) {
                    Some((iterations, eta)) => format!("last heard solving at iteration {iterations}, eta {eta:.2e}"),
                    None => "it never reported progress: the pool may have died building the model (memory?)".into(),
                };
                let expire = if over_budget && !entry.record.cancelled {
                    Transition::OverBudget { seconds: self.config.point_budget.as_secs_f64(), last }
                } else {
                    Transition::Expire {
                        study_cancelled: entry.record.cancelled,
                        max_attempts: self.config.max_attempts,
                        last,
                    }
                };
                let q = apply(p, expire)?;
                tracing::warn!(study = %p.study, point = i, pool = %pool, lease_id, over_budget, "lease expired");
                let kind = if q.state == PointState::Failed { EventKind::Failed } else { EventKind::Requeued };
                changes.push((q, Some(kind)));
                lost.push(*lease_id);
            }
            if changes.is_empty() {
                continue;
            }
            expired += changes.len();
            self.commit(studies.get_mut(&id).expect("listed above"), changes, None, Batch::new())?;
            for lease_id in lost {
                leases.end(lease_id);
            }
        }
        drop(state);
        if expired > 0 {
            self.leases_expired.fetch_add(expired as u64, Ordering::Relaxed);
            self.work.notify_waiters();
        }
        Ok(expired)
    }

    /// Makes everything durable (at shutdown).
    pub fn flush(&self) -> Result<(), CoordError> {
        Ok(self.store.flush()?)
    }
}

/// Whether a study leases nothing yet: a study to an accuracy waits for its pilots' level, and
/// held-out points are solved only once the surface has predicted them.
fn waits(entry: &StudyEntry) -> bool {
    entry.record.to_accuracy.as_ref().is_some_and(|t| t.chosen.is_none())
        || entry.record.held_out.as_ref().is_some_and(|h| h.predicted.is_none())
}

/// What an adaptive study that has no point pending does next (decided without changing it, so
/// that a study with nothing to do is not a new version of itself).
enum AdaptiveChoice {
    /// nothing: its outcome is known, or its budget is spent
    None,
    /// end the choice at the points it has (the work budget is spent, or no room is left)
    End(AdaptiveSpec),
    /// record the target's outcome (no point is chosen after)
    Outcome(Box<StudyRecord>),
    /// add this point (its swept values, checked against the study's space)
    Point(DesignPoint),
}

/// The next point of an adaptive study that has none pending, if its budget allows: where the
/// response surface is least sure (core::study::adaptive). A box with no room left ends the study
/// at the points it has. A study with a target first judges it (recorded once decided: no point
/// is chosen after).
fn adaptive_choice(entry: &StudyEntry) -> Result<AdaptiveChoice, CoordError> {
    let Some(spec) = entry.record.adaptive.clone() else { return Ok(AdaptiveChoice::None) };
    let work_spent = spec.work_spent(&entry.points);
    if work_spent && spec.target.is_none() && entry.points.len() < spec.budget as usize {
        // the points chosen are the study's (those in flight finish); a study with a target
        // says so in its outcome instead
        tracing::info!(study = %entry.record.id, points = entry.points.len(), "adaptive study: its work budget is spent");
        return Ok(AdaptiveChoice::End(spec));
    }
    let spent = entry.points.len() >= spec.budget as usize || work_spent;
    if spec.outcome.is_some() || (spent && spec.target.is_none()) {
        return Ok(AdaptiveChoice::None);
    }
    let (outcome, next) = adaptive_step(entry, &entry.points, !spent);
    if let Some(outcome) = outcome {
        let mut record = entry.record.clone();
        record.adaptive = Some(AdaptiveSpec { outcome: Some(outcome), ..spec });
        return Ok(AdaptiveChoice::Outcome(Box::new(record)));
    }
    if spent {
        return Ok(AdaptiveChoice::None);
    }
    Ok(match next {
        Some(next) => {
            // (a point the plan cannot complete is refused before anything is stored)
            entry.plan.space().complete(&next).map_err(|e| CoordError::invalid_worded("ranges", e))?;
            AdaptiveChoice::Point(next)
        }
        None => {
            tracing::warn!(study = %entry.record.id, points = entry.points.len(), "adaptive study: no room left in the box");
            AdaptiveChoice::End(spec)
        }
    })
}

/// The record of an audit of `study` that re-solves points cold at [`AUDIT_TOLERANCE_RATIO`] of
/// its tolerance (the iteration audit, the surface audit).
/// One step of an adaptive study over `points` (its points, with the latest change): the
/// surfaces of the done ones fitted once, for the target's outcome if it is decided (reached,
/// or the budget spent with nothing in flight) and, if `choose`, the next point.
fn adaptive_step(
    entry: &StudyEntry,
    points: &[PointRecord],
    choose: bool,
) -> (Option<TargetOutcome>, Option<DesignPoint>) {
    let Some(spec) = entry.record.adaptive.as_ref() else { return (None, None) };
    let design = spec.design();
    let done: Vec<Option<BTreeMap<String, f64>>> = points
        .iter()
        .map(|p| (p.state == PointState::Done).then(|| p.result.as_ref().map(|r| r.qoi.clone().into())).flatten())
        .collect();
    let chosen: Vec<(DesignPoint, Option<&BTreeMap<String, f64>>)> =
        points.iter().zip(&done).map(|(p, d)| (p.parameters.clone(), d.as_ref())).collect();
    // (what each done point's contacts did: a force of one that chatters is no surface)
    let contacts = points.iter().filter(|p| p.state == PointState::Done).filter_map(|p| p.result.as_ref());
    let readings = QoiReadings::of(&entry.scene).with_contacts(contacts.map(|r| r.contact.as_slice()));
    let surfaces = design.surfaces(entry.plan.space(), &readings, &chosen);
    let in_flight = points.iter().any(|p| matches!(p.state, PointState::Pending | PointState::Leased { .. }));
    let spent = (points.len() >= spec.budget as usize || spec.work_spent(points)) && !in_flight;
    let outcome = if spec.outcome.is_none() { design.outcome(&surfaces, spent) } else { None };
    let next = (choose && outcome.is_none()).then(|| design.next(&chosen, &surfaces)).flatten();
    if let Some(o) = &outcome {
        tracing::info!(study = %entry.record.id, reached = o.reached, points = o.validation.points, "adaptive study: target judged");
    }
    (outcome, next)
}

fn cold_audit_record(study: &StudyRecord, id: StudyId, label: String) -> StudyRecord {
    StudyRecord {
        id,
        label,
        // within the bounds every solve obeys
        // (2e-4 x 0.01 reads 2e-6, not 2.0000000000000003e-6)
        tolerance: glissade_core::text::decimal(study.tolerance * AUDIT_TOLERANCE_RATIO)
            .max(glissade_core::scene::MIN_TOLERANCE),
        max_iterations: study
            .max_iterations
            .saturating_mul(AUDIT_ITERATION_FACTOR)
            .min(glissade_core::scene::MAX_ITERATIONS as u32),
        strategy: InitStrategy::Cold,
        order: OrderKind::Asc,
        audit_of: Some(study.id),
        audit: None,
        adaptive: None,
        refined_by: Vec::new(),
        refines: None,
        surface_audit: None,
        held_out: None,
        ..study.clone()
    }
}

/// Why an audit that spent its cost cap re-solves no more of its points.
fn spent_reason(budget: &AuditBudget) -> String {
    if budget.cap > 0.0 {
        format!(
            "not re-solved: the audit spent its cost cap ({:.0} work, {:.0} % of its study's)",
            budget.cap,
            AUDIT_WORK_FRACTION * 100.0
        )
    } else {
        // (a study answered from stored solutions: what measured them was their own audit)
        "not re-solved: its study cost no work (its points were answered from stored solutions), \
         so the audit's cost cap, a share of that work, is 0"
            .to_owned()
    }
}

/// What an audit may still spend: [`AUDIT_WORK_FRACTION`] of its study's work, less what its
/// points cost so far. None while it must wait: its study still has points to solve, or one of
/// its own points is being solved (an audit solves one point at a time, each capped at what is
/// left).
fn audit_budget(study: Option<&StudyEntry>, audit: &StudyEntry) -> Option<AuditBudget> {
    if audit.points.iter().any(|p| matches!(p.state, PointState::Leased { .. })) {
        return None;
    }
    audit_cost(study?, audit)
}

/// An audit's cap and what it spent (None while its study still has points to solve: its work,
/// and so the cap, is not known yet).
fn audit_cost(study: &StudyEntry, audit: &StudyEntry) -> Option<AuditBudget> {
    if study.state() == StudyState::Active {
        return None;
    }
    let work = |e: &StudyEntry| e.points.iter().filter_map(|p| p.result.as_ref()).map(|r| r.work).sum::<f64>();
    Some(AuditBudget { cap: AUDIT_WORK_FRACTION * work(study), spent: work(audit) })
}

/// What `audit` (re-solves of some of `study`'s points) measured of `study`: per QoI, |study -
/// audit| over the points done in both, relative to the largest |audit value| of that QoI (the
/// measure of docs/performance.md).
fn accuracy(study: &StudyEntry, audit: &StudyEntry) -> Accuracy {
    let budget = audit_cost(study, audit);
    let done = |p: &PointRecord| p.state == PointState::Done;
    // (the study's QoIs, the audit's) at each point done in both
    let mut pairs = Vec::new();
    for a in audit.points.iter().filter(|p| done(p)) {
        let found = study.points.iter().find(|p| done(p) && p.parameters == a.parameters);
        if let (Some(p), Some(ar)) = (found, a.result.as_ref())
            && let Some(pr) = p.result.as_ref()
        {
            pairs.push((&pr.qoi, &ar.qoi));
        }
    }
    let mut qoi = BTreeMap::new();
    let names: std::collections::BTreeSet<&str> = pairs.iter().flat_map(|(_, a)| a.keys()).collect();
    for name in names {
        let both: Vec<(f64, f64)> = pairs.iter().filter_map(|(s, a)| Some((*s.get(name)?, *a.get(name)?))).collect();
        let scale = both.iter().map(|(_, a)| a.abs()).fold(0.0f64, f64::max);
        let scale = if scale > 0.0 { scale } else { 1.0 };
        let errors: Vec<f64> = both.iter().map(|(s, a)| (s - a).abs() / scale).collect();
        let largest = errors.iter().cloned().fold(0.0f64, f64::max);
        qoi.insert(name.to_owned(), (largest, errors.iter().sum::<f64>() / errors.len().max(1) as f64));
    }
    Accuracy {
        audit_study: audit.record.id,
        tolerance: audit.record.tolerance,
        audited: pairs.len() as u32,
        planned: audit.points.len() as u32,
        qoi,
        work: budget.map_or(0.0, |b| b.spent),
        work_cap: budget.map_or(0.0, |b| b.cap),
    }
}

/// What a completion stores: the solution's record (`sizes`: its file's bytes, as stored) and
/// the point's result, converged when the solve says so within the study's `tolerance`.
fn completion_records(
    c: &Completion,
    meta: &SolutionMeta,
    scene_hash: &str,
    full: &DesignPoint,
    started_from: Option<Box<SolutionOrigin>>,
    sizes: (u64, u64),
    tolerance: f64,
) -> (SolutionRecord, PointResult) {
    let record = SolutionRecord {
        scene_hash: records::shared(scene_hash),
        parameters: full.clone(),
        solver_version: meta.solver_version.clone(),
        converged: meta.converged,
        // the pool's exact value (the file's JSON header may differ in the last bit)
        error_indicator: c.error_indicator,
        tolerance: meta.tolerance,
        iterations: meta.iterations as u64,
        wall_seconds: c.wall_seconds,
        qoi: c.qoi.clone().into(),
        parent: started_from.clone(),
        study: Some(c.study),
        point: Some(c.point),
        stored_unix_ms: now_unix_ms(),
        file_bytes: sizes.0,
        stored_bytes: sizes.1,
        contact: c.contact.clone(),
        qoi_largest: c.qoi_largest.clone().into(),
        pool: c.pool.clone(),
    };
    let result = PointResult {
        pool: c.pool.clone(),
        converged: meta.converged && c.error_indicator <= tolerance,
        iterations: c.iterations,
        error_indicator: c.error_indicator,
        qoi: c.qoi.clone().into(),
        wall_seconds: c.wall_seconds,
        started_from,
        answered: false,
        eta_history: c.eta_history.clone().into(),
        work: c.work,
        contact: c.contact.clone(),
        qoi_largest: c.qoi_largest.clone().into(),
    };
    (record, result)
}

/// The solution a leased point's warm start came from.
fn leased_from(point: &PointRecord) -> Option<Box<SolutionOrigin>> {
    match &point.state {
        PointState::Leased { init, .. } => init.clone(),
        _ => None,
    }
}

/// Checks that a solution file is the one announced, for the point held.
fn check_meta(meta: &SolutionMeta, c: &Completion, scene_hash: &str, full: &DesignPoint) -> Result<(), CoordError> {
    let point = format!("point {} of study {}", c.point, c.study);
    if meta.scene_hash != scene_hash {
        return Err(CoordError::invalid_worded(
            "solution",
            format_args!("solution is for scene {}, {point} is of scene {scene_hash}", meta.scene_hash),
        ));
    }
    let parameters = &meta.parameters;
    let same_point = parameters.len() == full.len()
        && full.iter().all(|(name, v)| parameters.get(name).is_some_and(|w| same_number(v, w)));
    if !same_point {
        return Err(CoordError::invalid_worded(
            "solution",
            format_args!("solution is for parameters {parameters}, {point} is at {full}"),
        ));
    }
    // The QoIs a study reports are the header's: they must be the solve's own, bit for bit.
    let same_qoi = meta.qoi.len() == c.qoi.len()
        && meta.qoi.iter().all(|(name, v)| c.qoi.get(name).is_some_and(|w| w.to_bits() == v.to_bits()));
    if !same_qoi {
        return Err(CoordError::invalid_worded(
            "qoi",
            format_args!(
                "the QoIs of the header for {point} are not those of its solution file ({})",
                if meta.qoi.is_empty() {
                    "which has none: written by a solver before 0.2.0?".to_string()
                } else {
                    format!("{:?}", meta.qoi)
                }
            ),
        ));
    }
    if meta.converged != c.converged || meta.iterations as u64 != c.iterations {
        return Err(CoordError::invalid_worded(
            if meta.converged != c.converged { "converged" } else { "iterations" },
            format_args!(
                "solution for {point} says converged = {} after {} iterations, the header {} after {}",
                meta.converged, meta.iterations, c.converged, c.iterations
            ),
        ));
    }
    if !same_number(meta.error_indicator, c.error_indicator) {
        return Err(CoordError::invalid_worded(
            "error_indicator",
            format_args!(
                "solution for {point} has eta = {:e}, the header {:e}",
                meta.error_indicator, c.error_indicator
            ),
        ));
    }
    if let Some((name, v)) = c.qoi.iter().find(|(_, v)| !v.is_finite()) {
        return Err(CoordError::invalid_worded("qoi", format_args!("QoI `{name}` of {point} is not finite: {v}")));
    }
    if !(c.wall_seconds.is_finite() && c.wall_seconds >= 0.0) {
        return Err(CoordError::invalid_worded(
            "wall_seconds",
            format_args!("wall_seconds of {point} is {}", c.wall_seconds),
        ));
    }
    Ok(())
}

/// Equal but for the last bits: the solution file's header is JSON, and serde_json's default
/// float parsing is not exactly round-trip (it may move the last bit).
fn same_number(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-12 * a.abs().max(b.abs())
}

pub fn state_word(s: StudyState) -> &'static str {
    match s {
        StudyState::Active => "active",
        StudyState::Done => "done",
        StudyState::Failed => "failed",
        StudyState::Cancelled => "cancelled",
    }
}

/// Every word of [`point_state_word`], in the order of a point's life.
pub const POINT_STATE_WORDS: [&str; 5] = ["pending", "leased", "done", "failed", "cancelled"];

pub fn point_state_word(s: &PointState) -> &'static str {
    match s {
        PointState::Pending => "pending",
        PointState::Leased { .. } => "leased",
        PointState::Done => "done",
        PointState::Failed => "failed",
        PointState::Cancelled => "cancelled",
    }
}

#[cfg(test)]
pub(crate) mod tests;
