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
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use glissade_core::io::solution_file::{self, SolutionFileError, SolutionMeta};
use glissade_core::scene::Scene;
use glissade_proto::{ParameterVector, PointId, StudyId};
use tokio::sync::{Notify, broadcast};

use glissade_core::study::engine::StudyEngine;
use glissade_core::study::order::OrderKind;
use glissade_core::study::space::ParameterSpace;
use glissade_core::study::strategy::InitStrategy;

use crate::records::{
    self, NEXT_STUDY_KEY, PointRecord, PointResult, PointState, SolutionKey, SolutionOrigin, SolutionRecord,
    StudyRecord, decode, encode, point_key, study_key,
};
use crate::store::{Batch, Store, StoreError, Tree};
use crate::study::{PointStart, SceneSolutions, StudyPlan, WarmStart};

/// Settings of the coordinator's rules.
#[derive(Debug, Clone)]
pub struct Config {
    /// How long a lease lasts without a heartbeat.
    pub lease: Duration,
    /// Leases granted to a point before an expiry marks it failed (retryable).
    pub max_attempts: u32,
    /// Largest solution file accepted from a pool.
    pub max_solution_bytes: u64,
    /// Most design points in one study (counted from the grid before any is built).
    pub max_points: usize,
    /// Largest estimated memory of one solve of a submitted scene ([`Scene::size`]).
    pub max_scene_bytes: u64,
    /// The solver version the coordinator was built with (the pools' normally).
    pub solver_version: String,
}

/// Errors of the domain layer; each names the object concerned. `convert::status` maps each variant
/// to one gRPC status code.
#[derive(Debug, thiserror::Error)]
pub enum CoordError {
    /// A request that can never succeed as sent (INVALID_ARGUMENT).
    #[error("{0}")]
    Invalid(String),
    #[error("no study {0}")]
    UnknownStudy(StudyId),
    #[error("study {study} has no point {point}")]
    UnknownPoint { study: StudyId, point: PointId },
    #[error("pool `{0}` is not registered (register again)")]
    UnknownPool(String),
    #[error("no stored solution {0}")]
    UnknownSolution(String),
    /// A valid request the current state forbids (FAILED_PRECONDITION).
    #[error("{0}")]
    Precondition(String),
    /// Bytes that do not match their checksum (DATA_LOSS).
    #[error("{0}")]
    Corrupt(String),
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("damaged database: {0}")]
    Decode(#[from] records::DecodeError),
    #[error("solution index: {0}")]
    Index(#[from] glissade_core::study::store::StoreError),
}

/// Counts of a study's points by state.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Progress {
    pub total: u32,
    pub pending: u32,
    pub leased: u32,
    pub done: u32,
    pub failed: u32,
    pub cancelled: u32,
    pub iterations: u64,
}

/// A study's overall state, derived from its points.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StudyState {
    Active,
    Done,
    Failed,
    Cancelled,
}

/// What a progress event reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EventKind {
    Started,
    Finished,
    Failed,
    Requeued,
    StudyEnded,
    Snapshot,
    /// A pool's report of a point it is solving (iterations, eta so far); never stored.
    Progress,
}

/// A change of a study, as broadcast to watchers.
#[derive(Debug, Clone)]
pub struct Event {
    pub kind: EventKind,
    pub study: StudyId,
    pub point: Option<PointRecord>,
    pub progress: Progress,
    pub state: StudyState,
    pub replay: bool,
    pub unix_ms: i64,
    /// Iterations and eta so far of the point being solved (Progress events).
    pub solving: Option<(u64, f64)>,
}

/// A study as GetStudy shows it.
#[derive(Debug, Clone)]
pub struct StudyView {
    pub record: StudyRecord,
    pub state: StudyState,
    pub progress: Progress,
    pub points: Vec<PointRecord>,
}

/// A submission, validated by the service layer's conversions.
#[derive(Debug, Clone)]
pub struct Submission {
    pub scene_text: String,
    pub grid: Vec<String>,
    pub points: Vec<ParameterVector>,
    pub tolerance: Option<f64>,
    pub max_iterations: Option<u32>,
    pub strategy: InitStrategy,
    pub order: OrderKind,
    pub label: String,
}

/// A point handed to a pool.
#[derive(Debug, Clone)]
pub struct LeaseGrant {
    pub lease_id: u64,
    pub study: StudyId,
    pub point: PointId,
    pub parameters: ParameterVector,
    pub scene_text: String,
    pub scene_hash: String,
    pub tolerance: f64,
    pub max_iterations: u32,
    pub deadline_unix_ms: i64,
    /// The warm start, if any.
    pub init: Option<WarmStart>,
}

/// What a pool reports with a solved point (the solution file's bytes come apart).
#[derive(Debug, Clone)]
pub struct Completion {
    pub pool: String,
    pub lease_id: u64,
    pub study: StudyId,
    pub point: PointId,
    pub converged: bool,
    pub iterations: u64,
    pub error_indicator: f64,
    pub qoi: BTreeMap<String, f64>,
    pub wall_seconds: f64,
    pub eta_history: Vec<f64>,
    pub work: f64,
    /// solved from cold in spite of the lease's warm start
    pub started_cold: bool,
}

/// A pool's failure report.
#[derive(Debug, Clone)]
pub struct Failure {
    pub pool: String,
    pub lease_id: u64,
    pub study: StudyId,
    pub point: PointId,
    pub error: String,
    pub error_indicator: Option<f64>,
    pub iterations: u64,
}

/// A registered pool.
#[derive(Debug, Clone)]
pub struct PoolInfo {
    pub ranks: u32,
    pub host: String,
    pub solver_version: String,
}

/// One row of a response surface.
#[derive(Debug, Clone)]
pub struct SurfaceRow {
    pub parameters: ParameterVector,
    pub qoi: BTreeMap<String, f64>,
    pub iterations: u64,
    pub error_indicator: f64,
    pub converged: bool,
    /// Point state for a study source; Done/Failed for a stored solution.
    pub state: PointState,
}

/// A response surface.
#[derive(Debug, Clone)]
pub struct Surface {
    pub scene_hash: String,
    pub parameters: Vec<String>,
    pub qoi: Vec<String>,
    pub rows: Vec<SurfaceRow>,
}

/// Which points or solutions a surface covers.
#[derive(Debug, Clone)]
pub enum SurfaceSource {
    Study(StudyId),
    Scene(String),
}

/// Which stored solution to fetch.
#[derive(Debug, Clone)]
pub enum SolutionSelector {
    Point(StudyId, PointId),
    Key(String, ParameterVector),
}

struct StudyEntry {
    record: StudyRecord,
    points: Vec<PointRecord>,
    plan: StudyPlan,
}

impl StudyEntry {
    fn progress(&self) -> Progress {
        let mut p = Progress { total: self.points.len() as u32, ..Progress::default() };
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
    fn full_parameters(&self, i: usize) -> ParameterVector {
        crate::study::parameter_vector(&self.plan.full[i])
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

#[derive(Default)]
struct State {
    studies: BTreeMap<StudyId, StudyEntry>,
    /// Metadata of every stored solution.
    solutions: HashMap<SolutionKey, SolutionRecord>,
    /// Nearest-neighbour index of the converged solutions, per scene hash.
    by_scene: HashMap<String, SceneSolutions>,
    /// Lease id -> the point holding it.
    leases: HashMap<u64, (StudyId, PointId)>,
    /// Lease id -> the last progress its pool reported (iterations, eta): what is known of a
    /// point whose pool then vanished.
    lease_progress: HashMap<u64, (u64, f64)>,
    pools: HashMap<String, PoolInfo>,
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
            state.solutions.insert(key, record);
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
                    state.leases.insert(*lease_id, (point.study, point.id));
                    batch.put(Tree::Points, pkey.clone(), encode(&point));
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
            if !state.by_scene.contains_key(&record.scene_hash) {
                match SceneSolutions::new(record.scene_hash.clone(), plan.space().clone(), store.clone()) {
                    Ok(index) => drop(state.by_scene.insert(record.scene_hash.clone(), index)),
                    Err(e) => tracing::warn!(study = %record.id, error = %e, "no warm starts for this scene"),
                }
            }
            state.studies.insert(record.id, StudyEntry { record, points, plan });
        }
        store.commit(batch)?;
        // The nearest-neighbour indexes, rebuilt from the records (the fields stay on disk).
        let State { solutions, by_scene, .. } = &mut state;
        for key in in_key_order {
            let record = &solutions[&key];
            if let (true, Some(index)) = (record.converged, by_scene.get_mut(&record.scene_hash)) {
                index.index(key, record)?;
            }
        }
        tracing::info!(
            studies = state.studies.len(),
            solutions = state.solutions.len(),
            leases = state.leases.len(),
            bytes = store.size_on_disk()?,
            "loaded the database"
        );
        let (events, _) = broadcast::channel(4096);
        let (stopping, _) = tokio::sync::watch::channel(false);
        Ok(Self { store, config, state: Mutex::new(state), events, work: Notify::new(), stopping })
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

    fn emit(&self, kind: EventKind, entry: &StudyEntry, point: Option<&PointRecord>) {
        self.send_event(kind, entry, point, None);
    }

    fn send_event(
        &self,
        kind: EventKind,
        entry: &StudyEntry,
        point: Option<&PointRecord>,
        solving: Option<(u64, f64)>,
    ) {
        let _ = self.events.send(Event {
            kind,
            study: entry.record.id,
            point: point.cloned(),
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

    // ---- users ----

    /// Stores a study and queues its points.
    pub fn submit(&self, submission: Submission) -> Result<(StudyId, u32, String), CoordError> {
        let scene = Scene::parse(&submission.scene_text)
            .map_err(|e| CoordError::Invalid(format!("scene: {}", one_line(&e.to_string()))))?;
        let size = scene.size();
        if size.bytes() > self.config.max_scene_bytes {
            return Err(CoordError::Invalid(format!(
                "scene: a solve would need about {} MiB ({} dofs, {} steps, estimated from the text), more than the {} MiB accepted (glissade-server --max-scene-mib)",
                size.bytes() >> 20,
                size.dofs,
                size.steps,
                self.config.max_scene_bytes >> 20
            )));
        }
        let scene_hash = scene.content_hash();
        // the tolerance's one check
        let tolerance = StudyEngine::new(&scene, submission.strategy, submission.tolerance)
            .map_err(|e| CoordError::Invalid(e.to_string()))?
            .tolerance();
        let max_iterations = match submission.max_iterations {
            Some(0) => return Err(CoordError::Invalid("max_iterations must be at least 1".into())),
            Some(n) => n,
            None => u32::try_from(scene.solver.max_iterations).unwrap_or(u32::MAX),
        };
        let (names, points) =
            crate::study::expand(&scene, &submission.grid, &submission.points, self.config.max_points)
                .map_err(CoordError::Invalid)?;
        if submission.strategy != InitStrategy::Cold {
            // The index refuses scenes of too many parameters: say so now, not at the first lease.
            SceneSolutions::new(scene_hash.clone(), ParameterSpace::from_scene(&scene), self.store.clone())
                .map_err(|e| CoordError::Invalid(format!("strategy {}: {e}", submission.strategy.name())))?;
        }
        let created = now_unix_ms();

        let mut state = self.lock();
        let id = StudyId(state.next_study);
        let record = StudyRecord {
            id,
            label: submission.label,
            scene_hash: scene_hash.clone(),
            scene: submission.scene_text,
            parameters: names,
            tolerance,
            max_iterations,
            strategy: submission.strategy,
            order: submission.order,
            created_unix_ms: created,
            cancelled: false,
        };
        let points: Vec<PointRecord> = points
            .into_iter()
            .enumerate()
            .map(|(i, parameters)| PointRecord {
                study: id,
                id: PointId(i as u64),
                parameters,
                state: PointState::Pending,
                attempts: 0,
                result: None,
                error: None,
                finished_seq: None,
            })
            .collect();
        let mut batch = Batch::new();
        if self.store.get(Tree::Scenes, scene_hash.as_bytes())?.is_none() {
            batch.put(Tree::Scenes, scene_hash.as_bytes(), record.scene.as_bytes());
        }
        batch.put(Tree::Studies, study_key(id), encode(&record));
        for p in &points {
            batch.put(Tree::Points, point_key(id, p.id), encode(p));
        }
        batch.put(Tree::Meta, NEXT_STUDY_KEY, (id.0 + 1).to_be_bytes());
        self.store.commit(batch)?;
        state.next_study = id.0 + 1;
        let n = points.len() as u32;
        let plan = StudyPlan::new(&scene, &record, &points).map_err(|e| CoordError::Invalid(e.to_string()))?;
        if !state.by_scene.contains_key(&scene_hash) {
            // None for a scene of too many parameters: its studies are cold (checked above).
            if let Ok(index) = SceneSolutions::new(scene_hash.clone(), plan.space().clone(), self.store.clone()) {
                state.by_scene.insert(scene_hash.clone(), index);
            }
        }
        let entry = StudyEntry { record, points, plan };
        tracing::info!(study = %id, points = n, scene = %scene_hash, "study submitted");
        self.emit(EventKind::Snapshot, &entry, None);
        state.studies.insert(id, entry);
        drop(state);
        self.work.notify_waiters();
        Ok((id, n, scene_hash))
    }

    fn view(entry: &StudyEntry, with_points: bool) -> StudyView {
        StudyView {
            record: entry.record.clone(),
            state: entry.state(),
            progress: entry.progress(),
            points: if with_points { entry.points.clone() } else { Vec::new() },
        }
    }

    pub fn study(&self, id: StudyId, with_points: bool) -> Result<StudyView, CoordError> {
        let state = self.lock();
        let entry = state.studies.get(&id).ok_or(CoordError::UnknownStudy(id))?;
        Ok(Self::view(entry, with_points))
    }

    pub fn studies(&self) -> Vec<StudyView> {
        self.lock().studies.values().map(|e| Self::view(e, false)).collect()
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
        let mut batch = Batch::new();
        batch.put(Tree::Studies, study_key(id), encode(&record));
        let mut points = entry.points.clone();
        for p in points.iter_mut().filter(|p| p.state == PointState::Pending) {
            p.state = PointState::Cancelled;
            batch.put(Tree::Points, point_key(id, p.id), encode(p));
        }
        self.store.commit(batch)?;
        entry.record = record;
        entry.points = points;
        tracing::info!(study = %id, "study cancelled");
        self.emit_if_ended(entry, was);
        Ok(Self::view(entry, false))
    }

    pub fn retry_failed(&self, id: StudyId) -> Result<(u32, StudyView), CoordError> {
        let mut state = self.lock();
        let entry = state.studies.get_mut(&id).ok_or(CoordError::UnknownStudy(id))?;
        if entry.record.cancelled {
            return Err(CoordError::Precondition(format!("study {id} is cancelled: its points are not retried")));
        }
        let mut points = entry.points.clone();
        let mut batch = Batch::new();
        let mut requeued = 0;
        for p in points.iter_mut().filter(|p| p.state == PointState::Failed) {
            p.state = PointState::Pending;
            p.attempts = 0;
            batch.put(Tree::Points, point_key(id, p.id), encode(p));
            requeued += 1;
        }
        self.store.commit(batch)?;
        entry.points = points;
        if requeued > 0 {
            tracing::info!(study = %id, requeued, "failed points requeued");
            self.emit(EventKind::Snapshot, entry, None);
        }
        let view = Self::view(entry, false);
        drop(state);
        self.work.notify_waiters();
        Ok((requeued, view))
    }

    pub fn surface(
        &self,
        source: SurfaceSource,
        fixed: &ParameterVector,
        qoi: &[String],
    ) -> Result<Surface, CoordError> {
        let state = self.lock();
        let (scene_hash, mut rows) = match &source {
            SurfaceSource::Study(id) => {
                let entry = state.studies.get(id).ok_or(CoordError::UnknownStudy(*id))?;
                let rows = entry
                    .points
                    .iter()
                    .map(|p| {
                        let r = p.result.as_ref();
                        SurfaceRow {
                            parameters: p.parameters.clone(),
                            qoi: r.map(|r| r.qoi.clone()).unwrap_or_default(),
                            iterations: r.map_or(0, |r| r.iterations),
                            error_indicator: r.map_or(0.0, |r| r.error_indicator),
                            converged: r.is_some_and(|r| r.converged),
                            state: p.state.clone(),
                        }
                    })
                    .collect::<Vec<_>>();
                (entry.record.scene_hash.clone(), rows)
            }
            SurfaceSource::Scene(hash) => {
                let rows = state
                    .solutions
                    .values()
                    .filter(|s| &s.scene_hash == hash)
                    .map(|s| SurfaceRow {
                        parameters: s.parameters.clone(),
                        qoi: s.qoi.clone(),
                        iterations: s.iterations,
                        error_indicator: s.error_indicator,
                        converged: s.converged,
                        state: if s.converged { PointState::Done } else { PointState::Failed },
                    })
                    .collect::<Vec<_>>();
                if rows.is_empty() && self.store.get(Tree::Scenes, hash.as_bytes())?.is_none() {
                    return Err(CoordError::Invalid(format!("no scene with hash `{hash}` was ever submitted")));
                }
                (hash.clone(), rows)
            }
        };
        drop(state);
        let names: Vec<String> = {
            let mut n: Vec<String> = rows.iter().flat_map(|r| r.parameters.iter().map(|(k, _)| k.to_owned())).collect();
            n.sort();
            n.dedup();
            n
        };
        for (name, _) in fixed.iter() {
            if !names.iter().any(|n| n == name) && !rows.is_empty() {
                return Err(CoordError::Invalid(format!(
                    "fixed parameter `{name}` is not a parameter of these points (they have: {})",
                    names.join(", ")
                )));
            }
        }
        rows.retain(|r| {
            fixed
                .iter()
                .all(|(name, v)| r.parameters.get(name).is_some_and(|x| (x - v).abs() <= 1e-9 * v.abs().max(1e-300)))
        });
        let mut qoi_names: Vec<String> = rows.iter().flat_map(|r| r.qoi.keys().cloned()).collect();
        qoi_names.sort();
        qoi_names.dedup();
        if !qoi.is_empty() {
            for q in qoi {
                if !qoi_names.contains(q) && !rows.iter().all(|r| r.qoi.is_empty()) {
                    return Err(CoordError::Invalid(format!(
                        "no QoI `{q}` in these results (they have: {})",
                        qoi_names.join(", ")
                    )));
                }
            }
            for r in &mut rows {
                r.qoi.retain(|k, _| qoi.contains(k));
            }
            qoi_names.retain(|k| qoi.contains(k));
        }
        rows.sort_by(|a, b| {
            let key = |r: &SurfaceRow| r.parameters.iter().map(|(_, v)| v).collect::<Vec<_>>();
            key(a).partial_cmp(&key(b)).unwrap_or(std::cmp::Ordering::Equal)
        });
        Ok(Surface { scene_hash, parameters: names, qoi: qoi_names, rows })
    }

    /// The bytes of a stored solution file.
    pub fn solution_bytes(&self, selector: &SolutionSelector) -> Result<Vec<u8>, CoordError> {
        let key = match selector {
            SolutionSelector::Point(study, point) => {
                let state = self.lock();
                let entry = state.studies.get(study).ok_or(CoordError::UnknownStudy(*study))?;
                let i = entry
                    .points
                    .iter()
                    .position(|p| p.id == *point)
                    .ok_or(CoordError::UnknownPoint { study: *study, point: *point })?;
                if entry.points[i].result.is_none() {
                    return Err(CoordError::Precondition(format!(
                        "point {point} of study {study} has no solution yet ({})",
                        point_state_word(&entry.points[i].state)
                    )));
                }
                SolutionKey::new(&entry.record.scene_hash, &entry.full_parameters(i))
            }
            SolutionSelector::Key(hash, parameters) => SolutionKey::new(hash, parameters),
        };
        self.fields(&key, selector)
    }

    fn fields(&self, key: &SolutionKey, what: &SolutionSelector) -> Result<Vec<u8>, CoordError> {
        let describe = || match what {
            SolutionSelector::Point(s, p) => format!("for point {p} of study {s}"),
            SolutionSelector::Key(h, p) => format!("of scene {h} at {p}"),
        };
        let compressed = self
            .store
            .get(Tree::SolutionFields, key.as_bytes())?
            .ok_or_else(|| CoordError::UnknownSolution(describe()))?;
        records::decode_fields(&compressed)
            .map_err(|e| CoordError::Corrupt(format!("stored solution {} does not decompress: {e}", describe())))
    }

    // ---- pools ----

    pub fn register_pool(&self, id: String, info: PoolInfo) {
        tracing::info!(pool = %id, ranks = info.ranks, host = %info.host, version = %info.solver_version, "pool registered");
        self.lock().pools.insert(id, info);
    }

    /// Leases the next point to `pool`, if any is pending. Points that a stored solution answers
    /// (same scene and solver version, converged at this tolerance or a tighter one: the
    /// solver's stopping test bounds every QoI's error by its tolerance) are marked done on the way.
    pub fn lease(&self, pool: &str) -> Result<Option<LeaseGrant>, CoordError> {
        self.expire_leases()?;
        let mut state = self.lock();
        let version =
            state.pools.get(pool).ok_or_else(|| CoordError::UnknownPool(pool.to_owned()))?.solver_version.clone();
        let ids: Vec<StudyId> = state.studies.keys().copied().collect();
        for id in ids {
            loop {
                let State { studies, solutions, by_scene, .. } = &mut *state;
                let entry = studies.get_mut(&id).expect("id listed above");
                // (the cheap test first: the policy copies every point)
                if entry.record.cancelled || !entry.points.iter().any(|p| p.state == PointState::Pending) {
                    break;
                }
                let Some(i) = entry.plan.next(&entry.points) else { break };
                let start = entry.plan.start(
                    &entry.record,
                    i,
                    by_scene.get(&entry.record.scene_hash),
                    entry.previous().as_ref(),
                    &version,
                );
                let init = match start {
                    // a good enough stored solution is the answer
                    PointStart::Answer(key) => {
                        let answer = solutions.get(&key).expect("indexed solutions have records").clone();
                        self.answer(&mut state, id, i, &answer)?;
                        continue;
                    }
                    PointStart::Solve(init) => init,
                };
                let lease_id = new_lease_id(&state.leases);
                let deadline = now_unix_ms() + self.config.lease.as_millis() as i64;
                let entry = state.studies.get_mut(&id).expect("id listed above");
                let mut point = entry.points[i].clone();
                point.state = PointState::Leased {
                    pool: pool.to_owned(),
                    lease_id,
                    deadline_unix_ms: deadline,
                    init: init.as_ref().map(|w| w.origin.clone()),
                };
                point.attempts += 1;
                let mut batch = Batch::new();
                batch.put(Tree::Points, point_key(id, point.id), encode(&point));
                self.store.commit(batch)?;
                let grant = LeaseGrant {
                    lease_id,
                    study: id,
                    point: point.id,
                    parameters: point.parameters.clone(),
                    scene_text: entry.record.scene.clone(),
                    scene_hash: entry.record.scene_hash.clone(),
                    tolerance: entry.record.tolerance,
                    max_iterations: entry.record.max_iterations,
                    deadline_unix_ms: deadline,
                    init,
                };
                entry.points[i] = point;
                tracing::info!(study = %id, point = i, pool, lease_id, "leased");
                self.emit(EventKind::Started, entry, Some(&entry.points[i]));
                state.leases.insert(lease_id, (id, PointId(i as u64)));
                return Ok(Some(grant));
            }
        }
        Ok(None)
    }

    /// Marks point `i` of study `id` done from the stored solution `answer` (0 iterations).
    fn answer(&self, state: &mut State, id: StudyId, i: usize, answer: &SolutionRecord) -> Result<(), CoordError> {
        let seq = state.next_finish_seq;
        let entry = state.studies.get_mut(&id).expect("caller checked");
        let was = entry.state();
        let mut point = entry.points[i].clone();
        point.state = PointState::Done;
        point.error = None;
        point.finished_seq = Some(seq);
        point.result = Some(PointResult {
            pool: String::new(),
            converged: true,
            iterations: 0,
            error_indicator: answer.error_indicator,
            qoi: answer.qoi.clone(),
            wall_seconds: 0.0,
            started_from: Some(answer.origin()),
            answered: true,
            eta_history: Vec::new(),
            work: 0.0,
        });
        let mut batch = Batch::new();
        batch.put(Tree::Points, point_key(id, point.id), encode(&point));
        self.store.commit(batch)?;
        entry.points[i] = point;
        tracing::info!(study = %id, point = i, "answered from a stored solution");
        self.emit(EventKind::Finished, entry, Some(&entry.points[i]));
        self.emit_if_ended(entry, was);
        state.next_finish_seq = seq + 1;
        Ok(())
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
            e => CoordError::Invalid(format!("solution of point {}: {e}", c.point)),
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
        let compressed = records::encode_fields(&file).map_err(|e| CoordError::Invalid(format!("compressing: {e}")))?;
        let compressed_at = started.elapsed();

        let mut state = self.lock();
        let seq = state.next_finish_seq;
        let current_version = self.config.solver_version.clone();
        let key = SolutionKey::new(&study_hash, &full);
        let old = state.solutions.get(&key).cloned();
        let (entry, i) = Self::held(&mut state, &c.pool, c.lease_id, c.study, c.point)?;
        let was = entry.state();
        let started_from = if c.started_cold { None } else { leased_from(&entry.points[i]) };
        let record = SolutionRecord {
            scene_hash: study_hash.clone(),
            parameters: full.clone(),
            solver_version: meta.solver_version.clone(),
            converged: meta.converged,
            // the pool's exact value (the file's JSON header may differ in the last bit)
            error_indicator: c.error_indicator,
            tolerance: meta.tolerance,
            iterations: meta.iterations as u64,
            wall_seconds: c.wall_seconds,
            qoi: c.qoi.clone(),
            parent: started_from.clone(),
            study: Some(c.study),
            point: Some(c.point),
            stored_unix_ms: now_unix_ms(),
            file_bytes: file.len() as u64,
            stored_bytes: compressed.len() as u64,
        };
        let mut point = entry.points[i].clone();
        let converged = meta.converged && c.error_indicator <= entry.record.tolerance;
        point.result = Some(PointResult {
            pool: c.pool.clone(),
            converged,
            iterations: c.iterations,
            error_indicator: c.error_indicator,
            qoi: c.qoi.clone(),
            wall_seconds: c.wall_seconds,
            started_from,
            answered: false,
            eta_history: c.eta_history.clone(),
            work: c.work,
        });
        if converged {
            point.state = PointState::Done;
            point.error = None;
            point.finished_seq = Some(seq);
        } else {
            point.state = PointState::Failed;
            point.error = Some(format!(
                "not converged: eta = {:.3e} > tolerance {:.1e} after {} iterations",
                c.error_indicator, entry.record.tolerance, c.iterations
            ));
        }
        let mut batch = Batch::new();
        batch.put(Tree::Points, point_key(c.study, c.point), encode(&point));
        let keep = old.as_ref().is_none_or(|old| record.replaces(old, &current_version));
        if keep {
            batch.put(Tree::Solutions, key.as_bytes(), encode(&record));
            batch.put(Tree::SolutionFields, key.as_bytes(), compressed);
        }
        self.store.commit(batch)?;
        tracing::debug!(
            check_ms = checked.as_secs_f64() * 1e3,
            compress_ms = (compressed_at - checked).as_secs_f64() * 1e3,
            commit_ms = (started.elapsed() - compressed_at).as_secs_f64() * 1e3,
            "completion costs"
        );
        let (entry, i) = Self::held(&mut state, &c.pool, c.lease_id, c.study, c.point)?;
        entry.points[i] = point.clone();
        let kind = if converged { EventKind::Finished } else { EventKind::Failed };
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
        self.emit(kind, entry, Some(&point));
        self.emit_if_ended(entry, was);
        if converged {
            state.next_finish_seq = seq + 1;
        }
        state.leases.remove(&c.lease_id);
        state.lease_progress.remove(&c.lease_id);
        if keep {
            let index = state.by_scene.get_mut(&record.scene_hash).filter(|_| record.converged);
            if let Some(index) = index {
                // The next point's warm start is likely this one: keep it decoded.
                index.index(key.clone(), &record)?;
                index.remember(&key, file, solution);
            }
            state.solutions.insert(key, record);
        }
        Ok(point)
    }

    /// Records a solver failure: the point is FAILED with the error (retryable).
    pub fn fail(&self, f: Failure) -> Result<PointRecord, CoordError> {
        let mut state = self.lock();
        let (entry, i) = Self::held(&mut state, &f.pool, f.lease_id, f.study, f.point)?;
        let was = entry.state();
        let mut point = entry.points[i].clone();
        point.state = PointState::Failed;
        point.error = Some(f.error.clone());
        point.result = Some(PointResult {
            pool: f.pool.clone(),
            converged: false,
            iterations: f.iterations,
            error_indicator: f.error_indicator.unwrap_or(f64::MAX),
            qoi: BTreeMap::new(),
            wall_seconds: 0.0,
            started_from: leased_from(&entry.points[i]),
            answered: false,
            eta_history: Vec::new(),
            work: 0.0,
        });
        let mut batch = Batch::new();
        batch.put(Tree::Points, point_key(f.study, f.point), encode(&point));
        self.store.commit(batch)?;
        entry.points[i] = point.clone();
        tracing::warn!(study = %f.study, point = i, pool = %f.pool, error = %f.error, "point failed");
        self.emit(EventKind::Failed, entry, Some(&point));
        self.emit_if_ended(entry, was);
        state.leases.remove(&f.lease_id);
        state.lease_progress.remove(&f.lease_id);
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
        let mut p = entry.points[i].clone();
        p.state = if entry.record.cancelled { PointState::Cancelled } else { PointState::Pending };
        p.attempts = p.attempts.saturating_sub(1);
        let was = entry.state();
        let mut batch = Batch::new();
        batch.put(Tree::Points, point_key(study, point), encode(&p));
        self.store.commit(batch)?;
        entry.points[i] = p.clone();
        tracing::info!(study = %study, point = i, pool, "released");
        self.emit(EventKind::Requeued, entry, Some(&p));
        self.emit_if_ended(entry, was);
        state.leases.remove(&lease_id);
        state.lease_progress.remove(&lease_id);
        drop(state);
        self.work.notify_waiters();
        Ok(p)
    }

    /// Extends the pool's valid leases; returns for each its new deadline, or None if no longer
    /// the pool's.
    /// Extends the pool's leases (None for a lease no longer its own) and forwards the progress
    /// it reports for them, (lease, iterations, eta), to the studies' watchers.
    pub fn heartbeat(&self, pool: &str, lease_ids: &[u64], progress: &[(u64, u64, f64)]) -> Vec<Option<i64>> {
        let mut state = self.lock();
        let deadline = now_unix_ms() + self.config.lease.as_millis() as i64;
        let State { studies, leases, lease_progress, .. } = &mut *state;
        let deadlines: Vec<Option<i64>> = lease_ids
            .iter()
            .map(|lease_id| {
                let (study, point) = leases.get(lease_id)?;
                let p = studies.get_mut(study)?.points.get_mut(point.0 as usize)?;
                match &mut p.state {
                    PointState::Leased { pool: holder, lease_id: l, deadline_unix_ms, .. }
                        if holder == pool && l == lease_id =>
                    {
                        *deadline_unix_ms = deadline;
                        Some(deadline)
                    }
                    _ => None,
                }
            })
            .collect();
        // Progress only for the leases just found to be this pool's.
        let held = |id: u64| lease_ids.iter().zip(&deadlines).any(|(&l, d)| l == id && d.is_some());
        for &(lease_id, iterations, eta) in progress.iter().filter(|p| p.2.is_finite() && held(p.0)) {
            lease_progress.insert(lease_id, (iterations, eta));
            let (study, point) = leases[&lease_id];
            let entry = &studies[&study];
            self.send_event(EventKind::Progress, entry, Some(&entry.points[point.0 as usize]), Some((iterations, eta)));
        }
        deadlines
    }

    /// Requeues (or fails, after `max_attempts`) every point whose lease deadline passed.
    pub fn expire_leases(&self) -> Result<usize, CoordError> {
        let now = now_unix_ms();
        let mut state = self.lock();
        let State { studies, leases, lease_progress, .. } = &mut *state;
        let mut expired = 0;
        for entry in studies.values_mut() {
            let was = entry.state();
            let mut batch = Batch::new();
            let mut changed = Vec::new();
            for (i, p) in entry.points.iter().enumerate() {
                let PointState::Leased { pool, lease_id, deadline_unix_ms, .. } = &p.state else { continue };
                if *deadline_unix_ms > now {
                    continue;
                }
                let mut q = p.clone();
                let last = match lease_progress.get(lease_id) {
                    Some((iterations, eta)) => format!("last heard solving at iteration {iterations}, eta {eta:.2e}"),
                    None => "it never reported progress: the pool may have died building the model (memory?)".into(),
                };
                if entry.record.cancelled {
                    q.state = PointState::Cancelled;
                } else if p.attempts >= self.config.max_attempts {
                    q.state = PointState::Failed;
                    q.error = Some(format!(
                        "lease expired {} times (last held by pool `{pool}`): the pools solving it stopped answering; {last}",
                        p.attempts
                    ));
                } else {
                    q.state = PointState::Pending;
                    q.error = Some(format!("a lease of pool `{pool}` expired; {last}"));
                }
                tracing::warn!(study = %p.study, point = i, pool = %pool, lease_id, "lease expired");
                batch.put(Tree::Points, point_key(p.study, p.id), encode(&q));
                changed.push((i, q, *lease_id));
            }
            if changed.is_empty() {
                continue;
            }
            self.store.commit(batch)?;
            for (i, q, lease_id) in changed {
                leases.remove(&lease_id);
                lease_progress.remove(&lease_id);
                let kind = if q.state == PointState::Failed { EventKind::Failed } else { EventKind::Requeued };
                entry.points[i] = q;
                self.emit(kind, entry, Some(&entry.points[i]));
                expired += 1;
            }
            self.emit_if_ended(entry, was);
        }
        drop(state);
        if expired > 0 {
            self.work.notify_waiters();
        }
        Ok(expired)
    }

    /// Makes everything durable (at shutdown).
    pub fn flush(&self) -> Result<(), CoordError> {
        Ok(self.store.flush()?)
    }
}

/// The solution a leased point's warm start came from.
fn leased_from(point: &PointRecord) -> Option<SolutionOrigin> {
    match &point.state {
        PointState::Leased { init, .. } => init.clone(),
        _ => None,
    }
}

/// Checks that a solution file is the one announced, for the point held.
fn check_meta(meta: &SolutionMeta, c: &Completion, scene_hash: &str, full: &ParameterVector) -> Result<(), CoordError> {
    let point = format!("point {} of study {}", c.point, c.study);
    if meta.scene_hash != scene_hash {
        return Err(CoordError::Invalid(format!(
            "solution is for scene {}, {point} is of scene {scene_hash}",
            meta.scene_hash
        )));
    }
    let parameters = ParameterVector::try_from(meta.parameters.clone())
        .map_err(|e| CoordError::Invalid(format!("solution for {point}: {e}")))?;
    let same_point = parameters.len() == full.len()
        && full.iter().all(|(name, v)| parameters.get(name).is_some_and(|w| same_number(v, w)));
    if !same_point {
        return Err(CoordError::Invalid(format!("solution is for parameters {parameters}, {point} is at {full}")));
    }
    // The QoIs a study reports are the header's: they must be the solve's own, bit for bit.
    let same_qoi = meta.qoi.len() == c.qoi.len()
        && meta.qoi.iter().all(|(name, v)| c.qoi.get(name).is_some_and(|w| w.to_bits() == v.to_bits()));
    if !same_qoi {
        return Err(CoordError::Invalid(format!(
            "the QoIs of the header for {point} are not those of its solution file ({})",
            if meta.qoi.is_empty() {
                "which has none: written by a solver before 0.2.0?".to_string()
            } else {
                format!("{:?}", meta.qoi)
            }
        )));
    }
    if meta.converged != c.converged || meta.iterations as u64 != c.iterations {
        return Err(CoordError::Invalid(format!(
            "solution for {point} says converged = {} after {} iterations, the header {} after {}",
            meta.converged, meta.iterations, c.converged, c.iterations
        )));
    }
    if !same_number(meta.error_indicator, c.error_indicator) {
        return Err(CoordError::Invalid(format!(
            "solution for {point} has eta = {:e}, the header {:e}",
            meta.error_indicator, c.error_indicator
        )));
    }
    if let Some((name, v)) = c.qoi.iter().find(|(_, v)| !v.is_finite()) {
        return Err(CoordError::Invalid(format!("QoI `{name}` of {point} is not finite: {v}")));
    }
    if !(c.wall_seconds.is_finite() && c.wall_seconds >= 0.0) {
        return Err(CoordError::Invalid(format!("wall_seconds of {point} is {}", c.wall_seconds)));
    }
    Ok(())
}

/// Equal but for the last bits: the solution file's header is JSON, and serde_json's default
/// float parsing is not exactly round-trip (it may move the last bit).
/// A lease id nobody can guess (64 random bits from the OS-seeded generator), unused and not 0:
/// a lease id is what lets a pool complete, fail or release a point.
fn new_lease_id(leases: &HashMap<u64, (StudyId, PointId)>) -> u64 {
    loop {
        let id: u64 = rand::random();
        if id != 0 && !leases.contains_key(&id) {
            return id;
        }
    }
}

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
mod tests {
    use super::*;
    use crate::store::SledStore;
    use glissade_core::field::{InterfaceField, InterfaceSolution, StageSolution};

    const TINY: &str = include_str!("../../scenes/three-blocks-tiny.toml");
    const VERSION: &str = env!("CARGO_PKG_VERSION");

    fn open(dir: &std::path::Path, lease_ms: u64, max_attempts: u32) -> Coordinator {
        let store = Arc::new(SledStore::open(dir).unwrap());
        let config = Config {
            lease: Duration::from_millis(lease_ms),
            max_attempts,
            max_solution_bytes: 1 << 30,
            max_points: glissade_core::study::space::DEFAULT_MAX_POINTS,
            max_scene_bytes: crate::DEFAULT_MAX_SCENE_MIB << 20,
            solver_version: VERSION.into(),
        };
        Coordinator::open(store, config).unwrap()
    }

    fn submit(c: &Coordinator, grid: &[&str], tolerance: f64, strategy: InitStrategy) -> StudyId {
        let submission = Submission {
            scene_text: TINY.into(),
            grid: grid.iter().map(|s| s.to_string()).collect(),
            points: vec![],
            tolerance: Some(tolerance),
            max_iterations: None,
            strategy,
            order: OrderKind::Asc,
            label: String::new(),
        };
        c.submit(submission).unwrap().0
    }

    fn refused(c: &Coordinator, scene: &str, grid: &[&str]) -> String {
        let submission = Submission {
            scene_text: scene.into(),
            grid: grid.iter().map(|s| s.to_string()).collect(),
            points: vec![],
            tolerance: None,
            max_iterations: None,
            strategy: InitStrategy::Nearest,
            order: OrderKind::Asc,
            label: String::new(),
        };
        match c.submit(submission) {
            Err(CoordError::Invalid(message)) => message,
            other => panic!("{grid:?} must be refused as invalid, got {:?}", other.map(|r| r.1)),
        }
    }

    #[test]
    fn a_header_whose_qois_are_not_its_files_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let c = open(dir.path(), 60_000, 3);
        submit(&c, &["f1=0.1"], 1e-3, InitStrategy::Cold);
        pool(&c, "p", VERSION);
        let grant = c.lease("p").unwrap().unwrap();
        let (mut forged, bytes) = solution_file(&grant, 5e-4, true);
        forged.qoi.insert("slip_A".into(), 999.0);
        let message = match c.complete(forged, bytes.clone()) {
            Err(CoordError::Invalid(m)) => m,
            other => panic!("must be refused: {:?}", other.map(|p| p.state)),
        };
        assert!(message.contains("not those of its solution file"), "{message}");
        // the point is still held, and the true header completes it
        let (honest, bytes) = solution_file(&grant, 5e-4, true);
        assert_eq!(c.complete(honest, bytes).unwrap().state, PointState::Done);
    }

    #[test]
    fn huge_grids_and_scenes_are_refused_before_anything_is_allocated() {
        let dir = tempfile::tempdir().unwrap();
        let c = open(dir.path(), 60_000, 3);
        let started = std::time::Instant::now();
        for grid in [
            &["f1=0.1:0.2:1000000000000"][..],
            &["f1=lhs:1000000000000:1"],
            &["f1=0.1:0.2:100000", "f2=0.1:0.2:100000"],
            &["f1=0.1:0.2:1000", "f2=0.1:0.2:1000"],
            &["f1=0.1:0.2:18446744073709551615", "f2=0.1:0.2:3"],
        ] {
            let message = refused(&c, TINY, grid);
            assert!(message.contains("design points, more than the 100000 accepted"), "{message}");
        }
        // 10^7 elements in a kilobyte of text
        let poison = TINY.replacen("elements = [2, 2, 4]", "elements = [200, 200, 250]", 1);
        let message = refused(&c, &poison, &["f1=0.1"]);
        assert!(message.contains("MiB") && message.contains("--max-scene-mib"), "{message}");
        assert!(started.elapsed() < Duration::from_secs(2), "refusals must not build anything");
        // nothing was stored, and a proper study still goes through
        assert!(c.studies().is_empty());
        submit(&c, &["f1=0.1:0.2:3"], 1e-3, InitStrategy::Nearest);
        // a 10 kB name comes back as a bounded excerpt
        let name = "n".repeat(10_000);
        let message = refused(&c, TINY, &[&format!("{name}=0.1")]);
        assert!(message.len() < 1000, "{} bytes", message.len());
    }

    /// A solution file of the tiny scene at `grant`'s point, with the outcome given.
    fn solution_file(grant: &LeaseGrant, eta: f64, converged: bool) -> (Completion, Vec<u8>) {
        let scene = Scene::parse(&grant.scene_text).unwrap();
        let mut full = BTreeMap::new();
        for (name, p) in &scene.parameters {
            full.insert(name.clone(), grant.parameters.get(name).unwrap_or(p.default));
        }
        let len = scene.time.steps * 3 * 4;
        let mut field = InterfaceField::zeros(2, len);
        field.s[0].force[0] = grant.point.0 as f64 + 1.0;
        let solution = InterfaceSolution { static_stage: None, dynamic: StageSolution { interfaces: vec![field] } };
        let meta = SolutionMeta {
            solver_version: VERSION.into(),
            scene_hash: grant.scene_hash.clone(),
            dimension: 3,
            time_steps: scene.time.steps,
            parameters: full,
            converged,
            error_indicator: eta,
            iterations: 10,
            tolerance: grant.tolerance,
            qoi: [("slip_A".to_string(), 1e-6)].into(),
        };
        let mut bytes = Vec::new();
        solution_file::write_to(&mut bytes, &solution, &meta).unwrap();
        let completion = Completion {
            pool: "p".into(),
            lease_id: grant.lease_id,
            study: grant.study,
            point: grant.point,
            converged,
            iterations: 10,
            error_indicator: eta,
            qoi: [("slip_A".to_string(), 1e-6)].into(),
            wall_seconds: 0.5,
            eta_history: vec![1.0, eta],
            work: 8.0,
            started_cold: false,
        };
        (completion, bytes)
    }

    fn pool(c: &Coordinator, id: &str, version: &str) {
        c.register_pool(id.into(), PoolInfo { ranks: 1, host: "h".into(), solver_version: version.into() });
    }

    fn state_of(c: &Coordinator, study: StudyId, point: u64) -> PointRecord {
        c.study(study, true).unwrap().points[point as usize].clone()
    }

    #[test]
    fn a_stored_solution_answers_only_its_solver_version_within_the_tolerance() {
        let dir = tempfile::tempdir().unwrap();
        let c = open(dir.path(), 60_000, 3);
        pool(&c, "p", VERSION);
        let a = submit(&c, &["f1=0.15"], 1e-3, InitStrategy::Nearest);
        let grant = c.lease("p").unwrap().unwrap();
        assert!(grant.init.is_none(), "nothing stored yet: cold");
        let (done, bytes) = solution_file(&grant, 5e-4, true);
        assert_eq!(c.complete(done, bytes.clone()).unwrap().state, PointState::Done);
        assert_eq!(c.solution_bytes(&SolutionSelector::Point(a, PointId(0))).unwrap(), bytes);

        // same point, same version, looser tolerance: answered at once
        let b = submit(&c, &["f1=0.15"], 1e-3, InitStrategy::Nearest);
        assert!(c.lease("p").unwrap().is_none(), "the answer leaves nothing to lease");
        let answered = state_of(&c, b, 0);
        assert_eq!(answered.state, PointState::Done);
        let r = answered.result.unwrap();
        assert!(r.answered && r.iterations == 0 && r.error_indicator == 5e-4, "{r:?}");
        assert_eq!(r.started_from.unwrap().study, Some(a));
        // a tighter tolerance continues from it
        let tight = submit(&c, &["f1=0.15"], 1e-4, InitStrategy::Nearest);
        let grant = c.lease("p").unwrap().unwrap();
        assert_eq!((grant.study, grant.init.as_ref().map(|w| w.origin.study)), (tight, Some(Some(a))));
        // the cold strategy never reads the store
        c.release("p", grant.lease_id, grant.study, grant.point).unwrap();
        c.cancel(tight).unwrap();
        let cold = submit(&c, &["f1=0.15"], 1e-3, InitStrategy::Cold);
        let grant = c.lease("p").unwrap().unwrap();
        assert_eq!((grant.study, grant.init.is_none()), (cold, true));
        c.release("p", grant.lease_id, grant.study, grant.point).unwrap();
        c.cancel(cold).unwrap();
        // another solver version gets it as a warm start only
        pool(&c, "old", "0.0.1");
        let other = submit(&c, &["f1=0.15"], 1e-3, InitStrategy::Nearest);
        let grant = c.lease("old").unwrap().unwrap();
        assert_eq!(grant.study, other);
        let Some(WarmStart { file: crate::study::WarmFile::Stored(sent), .. }) = &grant.init else {
            panic!("a stored warm start expected: {:?}", grant.init)
        };
        assert_eq!(sent.as_slice(), bytes.as_slice(), "the stored file's bytes as they came");
    }

    #[test]
    fn lost_leases_requeue_then_fail_and_retry_requeues() {
        let dir = tempfile::tempdir().unwrap();
        let c = open(dir.path(), 50, 2);
        pool(&c, "p", VERSION);
        let id = submit(&c, &["f1=0.15"], 1e-3, InitStrategy::Nearest);
        let first = c.lease("p").unwrap().unwrap();
        std::thread::sleep(Duration::from_millis(80));
        assert_eq!(c.expire_leases().unwrap(), 1);
        let p = state_of(&c, id, 0);
        assert_eq!((&p.state, p.attempts), (&PointState::Pending, 1));
        assert!(p.error.as_deref().unwrap().contains("expired"), "{p:?}");
        // the old lease is no longer the pool's: heartbeats say so, completion is refused
        assert_eq!(c.heartbeat("p", &[first.lease_id], &[]), vec![None]);
        let (late, bytes) = solution_file(&first, 5e-4, true);
        assert!(matches!(c.complete(late, bytes), Err(CoordError::Precondition(_))));

        let second = c.lease("p").unwrap().unwrap();
        assert!(c.heartbeat("p", &[second.lease_id], &[])[0].is_some());
        std::thread::sleep(Duration::from_millis(80));
        c.expire_leases().unwrap();
        let p = state_of(&c, id, 0);
        assert_eq!((&p.state, p.attempts), (&PointState::Failed, 2));
        assert!(p.error.as_deref().unwrap().contains("lease expired 2 times"), "{p:?}");
        assert_eq!(c.study(id, false).unwrap().state, StudyState::Failed);
        assert!(c.lease("p").unwrap().is_none());

        let (requeued, view) = c.retry_failed(id).unwrap();
        assert_eq!((requeued, view.state), (1, StudyState::Active));
        let p = state_of(&c, id, 0);
        assert_eq!((p.state, p.attempts), (PointState::Pending, 0));
        // a released point is pending again without an attempt counted
        let g = c.lease("p").unwrap().unwrap();
        c.release("p", g.lease_id, g.study, g.point).unwrap();
        assert_eq!(state_of(&c, id, 0).attempts, 0);
    }

    #[test]
    fn everything_committed_survives_a_reopen_and_leases_get_a_fresh_deadline() {
        let dir = tempfile::tempdir().unwrap();
        let (id, held) = {
            let c = open(dir.path(), 60_000, 3);
            pool(&c, "p", VERSION);
            let id = submit(&c, &["f1=0.1,0.15,0.2"], 1e-3, InitStrategy::Nearest);
            let g = c.lease("p").unwrap().unwrap();
            let (done, bytes) = solution_file(&g, 5e-4, true);
            c.complete(done, bytes).unwrap();
            let g = c.lease("p").unwrap().unwrap();
            let (not_converged, bytes) = solution_file(&g, 3e-3, false);
            let p = c.complete(not_converged, bytes).unwrap();
            assert_eq!(p.state, PointState::Failed);
            assert!(p.error.as_deref().unwrap().starts_with("not converged: eta = 3.000e-3"), "{p:?}");
            (id, c.lease("p").unwrap().unwrap())
        };
        let c = open(dir.path(), 60_000, 3);
        let v = c.study(id, true).unwrap();
        let states: Vec<_> = v.points.iter().map(|p| point_state_word(&p.state)).collect();
        assert_eq!(states, ["done", "failed", "leased"]);
        let PointState::Leased { deadline_unix_ms, lease_id, .. } = &v.points[2].state else { unreachable!() };
        assert_eq!(*lease_id, held.lease_id);
        assert!(*deadline_unix_ms >= now_unix_ms() + 59_000, "a fresh deadline after the restart");
        // the non-converged point kept its last eta; the pool holding point 2 may still complete it
        assert_eq!(v.points[1].result.as_ref().unwrap().error_indicator, 3e-3);
        let (done, bytes) = solution_file(&held, 5e-4, true);
        assert_eq!(c.complete(done, bytes).unwrap().state, PointState::Done);
        // the index was rebuilt: a retried point warm-starts from the nearest converged solution
        pool(&c, "p", VERSION);
        c.retry_failed(id).unwrap();
        let g = c.lease("p").unwrap().unwrap();
        assert_eq!(g.point, PointId(1));
        let from = g.init.expect("a warm start").origin;
        assert!(from.point == Some(PointId(0)) || from.point == Some(PointId(2)), "{from:?}");
        // study ids continue where they were; lease ids are random, never reused
        assert_ne!(g.lease_id, held.lease_id);
        assert_eq!(submit(&c, &["f1=0.1"], 1e-3, InitStrategy::Cold), StudyId(id.0 + 1));
    }
}
