//! The coordinator's side of the study library (`glissade_core::study`): grids expanded by its
//! parser, points ordered by its policies, warm starts chosen by its strategies — over the
//! solutions of the sled database, which [`SceneSolutions`] presents as a
//! [`SolutionStore`].
//!
//! The index is the library's kd-tree ([`PointIndex`]) over the solutions' descriptions; the
//! fields stay in sled and are read (zstd, then the solution file format) when a strategy asks
//! for them.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, PoisonError};

use glissade_core::field::InterfaceSolution;
use glissade_core::io::solution_file::{self, SolutionMeta};
use glissade_core::point::DesignPoint;
use glissade_core::scene::{Scene, SceneError, Tolerance, invalid};
use glissade_core::study::StartKind;
use glissade_core::study::engine::{Start, StudyEngine};
use glissade_core::study::order::OrderingPolicy;
use glissade_core::study::space::ParameterSpace;
use glissade_core::study::store::{PointIndex, SolutionId, SolutionInfo, SolutionStore, StoreError, StoredSolution};
use glissade_core::study::strategy::Initialisation;

use crate::records::{PointRecord, PointState, SolutionKey, SolutionOrigin, SolutionRecord, StudyRecord};
use crate::store::{Store, Tree};

/// The ordering of one study and its engine (the rules of reuse, warm starts and failures that
/// the local study follows too).
pub struct StudyPlan {
    pub engine: StudyEngine,
    policy: Box<dyn OrderingPolicy>,
    /// Stored points are answered though the study's solves start cold (a discretisation
    /// audit's level, a level of a study's pilots: its cold solves measure the step, a stored
    /// solve of its scene does too).
    answers_stored: bool,
}

/// How a leased point begins.
pub enum PointStart {
    /// A stored solution answers it: its key.
    Answer(SolutionKey),
    /// Solve it, from this warm start (None: cold).
    Solve(Option<WarmStart>),
}

impl StudyPlan {
    /// Fails only on a stored tolerance out of range (a record is input too: a sled written by
    /// another version).
    pub fn new(scene: &Scene, record: &StudyRecord, points: &[PointRecord]) -> Result<Self, SceneError> {
        let tolerance = Tolerance::new("the study's tolerance", record.tolerance)?;
        let engine = StudyEngine::new(scene, record.strategy, Some(tolerance));
        for p in points {
            engine.space().complete(&p.parameters).map_err(|e| invalid("the study's points", e.to_string()))?;
        }
        let answers_stored = record.refines.is_some() || record.pilot_of.is_some();
        Ok(Self { policy: record.order.policy(engine.space()), engine, answers_stored })
    }

    pub fn space(&self) -> &ParameterSpace {
        self.engine.space()
    }

    /// Every parameter at `point`: the scene's defaults overridden by its swept values. Made
    /// when asked rather than kept (a point's parameters were held twice, 140 bytes a point:
    /// docs/performance.md, "Memory per design point"); every point's parameters were checked
    /// against the space where it entered the study (here, or as it was added).
    pub fn full(&self, point: &PointRecord) -> DesignPoint {
        self.space().complete(&point.parameters).expect("a point's parameters are checked where it enters its study")
    }

    /// The point to lease next among the pending ones, by the study's ordering policy (which sees
    /// the points done and those in flight on every pool).
    pub fn next(&mut self, points: &[PointRecord]) -> Option<usize> {
        let mut pending = (Vec::new(), Vec::new());
        let (mut done, mut in_flight) = (Vec::new(), Vec::new());
        for (i, p) in points.iter().enumerate() {
            match p.state {
                PointState::Pending => {
                    pending.0.push(i);
                    pending.1.push(self.full(p));
                }
                PointState::Leased { .. } => in_flight.push(self.full(p)),
                PointState::Done | PointState::Failed => done.push(self.full(p)),
                PointState::Cancelled => {}
            }
        }
        let choice = self.policy.next(&pending.1, &done, &in_flight)?;
        pending.0.get(choice).copied()
    }

    /// The stored solution that answers `point` as it is for a pool of `solver_version`, if
    /// any (what [`Self::start`] would answer with, without preparing a warm start). A damaged
    /// store answers nothing: the point is then leased as usual.
    pub fn answer(
        &self,
        point: &PointRecord,
        solutions: Option<&SceneSolutions>,
        solver_version: &str,
    ) -> Option<SolutionKey> {
        let solutions = solutions?;
        let full = self.full(point);
        let info = if self.answers_stored {
            self.engine.stored_answer(solutions, &full, solver_version)
        } else {
            self.engine.answer(solutions, &full, solver_version)
        };
        solutions.key_of(info.ok()??.id)
    }

    /// How `point` begins on a pool of `solver_version`, by the study engine, from `solutions`
    /// (this scene's; None: the scene has no index, so its studies are cold); `previous` is the
    /// solution of the study's point finished last. A store failure (a damaged stored solution)
    /// gives a cold start rather than no start.
    pub fn start(
        &self,
        study: &StudyRecord,
        point: &PointRecord,
        solutions: Option<&SceneSolutions>,
        previous: Option<&SolutionKey>,
        solver_version: &str,
    ) -> PointStart {
        let Some(solutions) = solutions else { return PointStart::Solve(None) };
        if self.answers_stored
            && let Some(key) = self.answer(point, Some(solutions), solver_version)
        {
            return PointStart::Answer(key);
        }
        let (i, point) = (point.id.0, &self.full(point));
        let previous = previous.and_then(|k| solutions.id_of(k));
        match self.engine.start(solutions, point, previous, solver_version) {
            Ok(Start::Answer(info)) => match solutions.key_of(info.id) {
                Some(key) => PointStart::Answer(key),
                None => PointStart::Solve(None),
            },
            Ok(Start::Solve { init, kind }) => PointStart::Solve(solutions.warm_start(init, kind)),
            Err(e) => {
                tracing::error!(study = %study.id, point = i, error = %e, "warm start failed; starting cold");
                PointStart::Solve(None)
            }
        }
    }
}

/// A chosen warm start: where it came from and its fields, ready to stream.
#[derive(Debug, Clone)]
pub struct WarmStart {
    /// The (nearest) stored solution it came from.
    pub origin: SolutionOrigin,
    pub file: WarmFile,
}

/// The warm start's solution file.
#[derive(Debug, Clone)]
pub enum WarmFile {
    /// A stored solution as is: its file bytes.
    Stored(Arc<Vec<u8>>),
    /// A blend: the combined fields, and the header to write them with.
    Blended(Arc<InterfaceSolution>, Box<SolutionMeta>),
}

impl WarmStart {
    /// The bytes to stream.
    pub fn bytes(&self) -> Result<Vec<u8>, solution_file::SolutionFileError> {
        match &self.file {
            WarmFile::Stored(bytes) => Ok(bytes.as_ref().clone()),
            WarmFile::Blended(solution, meta) => {
                let mut out = Vec::new();
                solution_file::write_to(&mut out, solution, meta)?;
                Ok(out)
            }
        }
    }
}

/// Solutions kept decoded (enough for a blend of up to 8 neighbours).
const RECENT: usize = 8;

/// A solution read back from the database.
struct Loaded {
    id: SolutionId,
    bytes: Arc<Vec<u8>>,
    solution: Arc<InterfaceSolution>,
}

/// The converged solutions of one scene: the library's kd-tree over their design points, their
/// records, and the database their fields are read from.
pub struct SceneSolutions {
    /// Neighbours: each solution's coordinates (and point); the descriptions the engine reads
    /// are made from `records` when asked, not kept twice (the index's own copy of a record's
    /// QoIs, version and contact report took 380 bytes a bare point, 480 a real one:
    /// docs/performance.md, "Memory per design point"), and the fields stay in the database.
    index: PointIndex,
    scene_hash: String,
    /// Keyed by a key's parameter bytes: the scene hash before them is this index's own.
    ids: HashMap<Box<[u8]>, SolutionId>,
    /// (shared with the coordinator's map of every stored solution: one copy of each)
    records: Vec<Arc<SolutionRecord>>,
    store: Arc<dyn Store>,
    /// The solutions read last, newest last: a strategy reads the ones it picks twice (to check
    /// them, to use them).
    recent: Mutex<Vec<Arc<Loaded>>>,
}

impl SceneSolutions {
    /// An empty index over `space` (the scene's parameters and ranges).
    pub fn new(scene_hash: String, space: ParameterSpace, store: Arc<dyn Store>) -> Result<Self, StoreError> {
        Ok(Self {
            index: PointIndex::new(space)?,
            scene_hash,
            ids: HashMap::new(),
            records: Vec::new(),
            store,
            recent: Mutex::new(Vec::new()),
        })
    }

    /// The parameters and ranges its index is over.
    pub fn space(&self) -> &ParameterSpace {
        self.index.space()
    }

    /// Makes a stored solution (already committed to the database) findable; a better solution
    /// at a key already indexed only replaces the record.
    pub fn index(&mut self, key: SolutionKey, record: &Arc<SolutionRecord>) -> Result<(), StoreError> {
        let Some(point) = key.point_bytes(&self.scene_hash) else {
            return Err(StoreError::Backend(format!("solution at {} is of another scene", record.parameters)));
        };
        if let Some(&id) = self.ids.get(point) {
            // what the engine reads to decide on reuse must be the better solution's (read from
            // `records`; the index's point and coordinates are the same)
            self.records[id as usize] = record.clone();
            self.recent.lock().unwrap_or_else(PoisonError::into_inner).retain(|l| l.id != id);
            return Ok(());
        }
        // the index needs the point alone: the rest of the description is `info`'s to make
        let id = self.index.insert(bare_info(0, record))?;
        self.ids.insert(point.into(), id);
        self.records.push(record.clone());
        Ok(())
    }

    /// What the engine reads of solution `id`: its record's description.
    fn info_of(&self, id: SolutionId) -> Result<SolutionInfo, StoreError> {
        let record = self.records.get(id as usize).ok_or(StoreError::UnknownId(id))?;
        Ok(SolutionInfo {
            qoi: record.qoi.clone().into(),
            solver_version: record.solver_version.clone(),
            contact: record.contact.clone(),
            ..bare_info(id, record)
        })
    }

    /// Keeps a solution just indexed decoded: the next point's warm start is likely it.
    pub fn remember(&self, key: &SolutionKey, bytes: Vec<u8>, solution: InterfaceSolution) {
        let Some(id) = self.id_of(key) else { return };
        let loaded = Arc::new(Loaded { id, bytes: Arc::new(bytes), solution: Arc::new(solution) });
        let mut recent = self.recent.lock().unwrap_or_else(PoisonError::into_inner);
        recent.retain(|l| l.id != id);
        if recent.len() == RECENT {
            recent.remove(0);
        }
        recent.push(loaded);
    }

    /// The key of solution `id` (made from its record: the index keeps no second copy).
    fn key_of(&self, id: SolutionId) -> Option<SolutionKey> {
        let record = self.records.get(id as usize)?;
        Some(SolutionKey::new(&record.scene_hash, &record.parameters))
    }

    pub fn id_of(&self, key: &SolutionKey) -> Option<SolutionId> {
        self.ids.get(key.point_bytes(&self.scene_hash)?).copied()
    }

    fn load(&self, id: SolutionId) -> Result<Arc<Loaded>, StoreError> {
        if let Some(l) = self.recent.lock().unwrap_or_else(PoisonError::into_inner).iter().find(|l| l.id == id) {
            return Ok(l.clone());
        }
        let key = self.key_of(id).ok_or(StoreError::UnknownId(id))?;
        let compressed = self
            .store
            .get(Tree::SolutionFields, &key.to_bytes())
            .map_err(|e| StoreError::Backend(e.to_string()))?
            .ok_or_else(|| StoreError::Backend(format!("solution {id}: fields missing from the database")))?;
        let bytes = crate::records::decode_fields(&compressed)
            .map_err(|e| StoreError::Backend(format!("solution {id}: fields do not decompress: {e}")))?;
        let (_, solution) =
            solution_file::read_from(&bytes[..]).map_err(|e| StoreError::Backend(format!("solution {id}: {e}")))?;
        let loaded = Arc::new(Loaded { id, bytes: Arc::new(bytes), solution: Arc::new(solution) });
        let mut recent = self.recent.lock().unwrap_or_else(PoisonError::into_inner);
        if recent.len() == RECENT {
            recent.remove(0);
        }
        recent.push(loaded.clone());
        Ok(loaded)
    }

    /// The streamable form of an initialisation.
    fn warm_start(&self, init: Initialisation, kind: StartKind) -> Option<WarmStart> {
        let solution = init.solution?;
        let first = init.sources.first()?;
        let record = self.records.get(first.id as usize)?;
        let origin = record.origin();
        if init.sources.len() == 1 {
            // The stored solution as is: send its bytes, no re-encoding.
            let loaded = self.load(first.id).ok()?;
            return Some(WarmStart { origin, file: WarmFile::Stored(loaded.bytes.clone()) });
        }
        debug_assert!(matches!(kind, StartKind::Blend | StartKind::Linear), "several sources make a blend");
        let meta = SolutionMeta {
            solver_version: record.solver_version.clone(),
            scene_hash: self.scene_hash.clone(),
            dimension: 0,
            time_steps: 0,
            // The nearest source's point, as for any start from another point: the pool then
            // stops at `warm_tolerance_ratio` times the tolerance, as the engine asks of every
            // start that is not a continuation of this very point.
            parameters: first.point.clone(),
            converged: false,
            error_indicator: record.error_indicator,
            iterations: 0,
            tolerance: record.tolerance,
            // a blend is a starting point, not a solve: it reports no QoIs
            qoi: Default::default(),
        };
        // Dimension and steps: those of the stored file the blend was made from.
        let loaded = self.load(first.id).ok()?;
        let (stored_meta, _) = solution_file::read_from(&loaded.bytes[..]).ok()?;
        let meta = SolutionMeta { dimension: stored_meta.dimension, time_steps: stored_meta.time_steps, ..meta };
        Some(WarmStart { origin, file: WarmFile::Blended(solution, Box::new(meta)) })
    }
}

impl SolutionStore for SceneSolutions {
    /// Indexes a solution whose fields the coordinator has committed under the key of this
    /// scene and the solution's point (the coordinator calls [`SceneSolutions::index`] itself,
    /// with the record it committed).
    fn insert(&mut self, solution: StoredSolution) -> Result<SolutionId, StoreError> {
        let parameters = &solution.point;
        let key = SolutionKey::new(&self.scene_hash, parameters);
        let stored = key.to_bytes();
        let bytes = self
            .store
            .get(Tree::Solutions, &stored)
            .map_err(|e| StoreError::Backend(e.to_string()))?
            .ok_or_else(|| StoreError::Backend(format!("no solution record at {parameters} in the database")))?;
        let record: SolutionRecord =
            crate::records::decode("solutions", &stored, &bytes).map_err(|e| StoreError::Backend(e.to_string()))?;
        self.index(key.clone(), &Arc::new(record))?;
        self.id_of(&key).ok_or_else(|| StoreError::Backend(format!("solution at {parameters} is of another scene")))
    }

    fn nearest(&self, point: &DesignPoint, k: usize) -> Result<Vec<(f64, SolutionId)>, StoreError> {
        self.index.nearest(point, k)
    }

    fn get(&self, id: SolutionId) -> Result<StoredSolution, StoreError> {
        let info = self.info_of(id)?;
        Ok(StoredSolution::from_info(info, self.load(id)?.solution.clone()))
    }

    fn info(&self, id: SolutionId) -> Result<SolutionInfo, StoreError> {
        self.info_of(id)
    }

    fn len(&self) -> usize {
        self.index.len()
    }
}

/// What the warm-start index keeps of a solution: its point and how it converged; the QoIs,
/// version and contact report stay in the record (`info_of` adds them when asked).
fn bare_info(id: SolutionId, record: &SolutionRecord) -> SolutionInfo {
    SolutionInfo {
        id,
        point: record.parameters.clone(),
        eta: record.error_indicator,
        tolerance: record.tolerance,
        converged: record.converged,
        iterations: record.iterations as usize,
        parent: None,
        qoi: Default::default(),
        solver_version: String::new(),
        contact: Vec::new(),
    }
}
