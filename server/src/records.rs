//! What the coordinator keeps in its trees (`store.rs`): the keys' byte layout and the records
//! (JSON: self-describing, readable with any sled dump, and checked by the schema version).
//!
//! | tree              | key                                   | value                      |
//! |-------------------|---------------------------------------|----------------------------|
//! | `scenes`          | scene content hash (64 hex chars)     | scene TOML text            |
//! | `studies`         | study id, u64 big-endian              | [`StudyRecord`]            |
//! | `points`          | study id ++ point id, u64 BE each     | [`PointRecord`]            |
//! | `solutions`       | [`SolutionKey`] bytes                 | [`SolutionRecord`]         |
//! | `solution_fields` | [`SolutionKey`] bytes                 | solution file, zstd        |
//! | `meta`            | `next-study-id`, `next-lease-id`      | u64 big-endian             |
//!
//! Big-endian ids make sled's key order the numeric order, so scans come sorted.

use std::collections::{BTreeMap, HashSet};
use std::sync::{Arc, LazyLock, Mutex, PoisonError};

use glissade_core::contact::ContactActivity;
use glissade_core::point::DesignPoint;
use glissade_core::study::adaptive::{AdaptiveDesign, TargetOutcome};
use glissade_core::study::order::OrderKind;
use glissade_core::study::strategy::InitStrategy;
use glissade_proto::{PointId, StudyId};
use serde::{Deserialize, Serialize};

pub use crate::qoi_map::QoiMap;

/// `meta` key of the next study id to hand out.
pub const NEXT_STUDY_KEY: &[u8] = b"next-study-id";

/// Key of a study.
pub fn study_key(study: StudyId) -> [u8; 8] {
    study.0.to_be_bytes()
}

/// Key of a point: its study's key first, so a prefix scan gives a study's points in order.
pub fn point_key(study: StudyId, point: PointId) -> [u8; 16] {
    let mut key = [0; 16];
    key[..8].copy_from_slice(&study.0.to_be_bytes());
    key[8..].copy_from_slice(&point.0.to_be_bytes());
    key
}

/// Reads a big-endian u64 counter value.
pub fn decode_u64(bytes: &[u8]) -> Option<u64> {
    bytes.try_into().ok().map(u64::from_be_bytes)
}

/// Identity of a stored solution: the scene's content hash and every parameter's value.
///
/// Bytes in the store: the 64 hex characters of the hash, then per parameter in name order its
/// name's length (u16 BE), its name, and its value's IEEE bits (u64 BE; -0 stored as +0). The
/// hash first lets a prefix scan list a scene's solutions. In memory the hash is [`shared`]: the
/// coordinator holds a key for every stored solution (64 bytes each, issue 48).
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct SolutionKey {
    scene: Arc<str>,
    /// the bytes after the hash's
    point: Box<[u8]>,
}

impl SolutionKey {
    /// The key of `scene_hash` at `parameters`.
    pub fn new(scene_hash: &str, parameters: &DesignPoint) -> Self {
        let mut bytes = Vec::new();
        for (name, value) in parameters.iter() {
            let len = u16::try_from(name.len()).expect("parameter names are validated to be short");
            bytes.extend_from_slice(&len.to_be_bytes());
            bytes.extend_from_slice(name.as_bytes());
            let value = if value == 0.0 { 0.0 } else { value };
            bytes.extend_from_slice(&value.to_bits().to_be_bytes());
        }
        // (at its length: a vector keeps up to twice it)
        Self { scene: shared(scene_hash), point: bytes.into_boxed_slice() }
    }

    /// The key's bytes in the store.
    pub fn to_bytes(&self) -> Vec<u8> {
        [self.scene.as_bytes(), &self.point].concat()
    }

    /// The bytes after the hash (the parameters'), if the key is of `scene_hash`'s scene.
    pub fn point_bytes(&self, scene_hash: &str) -> Option<&[u8]> {
        (*self.scene == *scene_hash).then_some(&self.point)
    }
}

/// The one copy of `text` that every record read or made with it shares: a scene's hash is in
/// each of its solutions' records and origins, 64 bytes apiece before (docs/performance.md,
/// "Memory per design point"). A text no record holds any more is forgotten as the set doubles.
pub fn shared(text: &str) -> Arc<str> {
    struct Texts {
        set: HashSet<Arc<str>>,
        /// the size at which the unheld texts are dropped next
        prune_at: usize,
    }
    static TEXTS: LazyLock<Mutex<Texts>> = LazyLock::new(|| Mutex::new(Texts { set: HashSet::new(), prune_at: 64 }));
    let mut texts = TEXTS.lock().unwrap_or_else(PoisonError::into_inner);
    if let Some(t) = texts.set.get(text) {
        return t.clone();
    }
    if texts.set.len() >= texts.prune_at {
        texts.set.retain(|t| Arc::strong_count(t) > 1);
        texts.prune_at = (2 * texts.set.len()).max(64);
    }
    let t: Arc<str> = Arc::from(text);
    texts.set.insert(t.clone());
    t
}

/// (De)serialises a [`shared`] text as the plain string it replaced.
mod shared_text {
    use std::sync::Arc;

    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(text: &Arc<str>, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(text)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(deserializer: D) -> Result<Arc<str>, D::Error> {
        Ok(super::shared(&std::borrow::Cow::<str>::deserialize(deserializer)?))
    }
}

/// Reads a vector kept for good at its length: serde grows one by doubling as it reads (a
/// contact report held 320 bytes for its 80).
fn shrunk<'de, D: serde::Deserializer<'de>, T: Deserialize<'de>>(deserializer: D) -> Result<Vec<T>, D::Error> {
    let mut v = Vec::deserialize(deserializer)?;
    v.shrink_to_fit();
    Ok(v)
}

/// A study as submitted.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StudyRecord {
    pub id: StudyId,
    pub label: String,
    pub scene_hash: String,
    /// The scene's own text: defaults and solver settings may differ between texts of one hash.
    pub scene: String,
    /// Names of the swept parameters, sorted.
    pub parameters: Vec<String>,
    pub tolerance: f64,
    pub max_iterations: u32,
    /// How its points' iterations start (the study library's strategies).
    pub strategy: InitStrategy,
    /// Which pending point is handed out next (the study library's policies).
    pub order: OrderKind,
    pub created_unix_ms: i64,
    pub cancelled: bool,
    /// The study this one audits (re-solves some of its points cold at a tighter tolerance, or,
    /// with `refines`, on a refined scene): leased when nothing else is pending.
    #[serde(default)]
    pub audit_of: Option<StudyId>,
    /// The study auditing this one.
    #[serde(default)]
    pub audit: Option<StudyId>,
    /// An adaptive study: its box and budget (its points are chosen as pools ask for work).
    #[serde(default)]
    pub adaptive: Option<AdaptiveSpec>,
    /// The scene's mesh files (their bytes in the `meshes` tree, by digest).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub meshes: Vec<MeshRef>,
    /// Submitted as an explicit list of points, not a grid.
    #[serde(default)]
    pub listed: bool,
    /// The studies of its discretisation audit, one per refined level, finest last.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub refined_by: Vec<StudyId>,
    /// The study this one refines: some of its points re-solved on a refined scene (its own
    /// `scene`, written by core::refine) at the same tolerance.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub refines: Option<Refines>,
    /// The study holding points out of this one's response surface (its surface audit).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub surface_audit: Option<StudyId>,
    /// A surface audit: its points are held out of `audit_of`'s response surface; what that
    /// surface predicted at them, before they were solved.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub held_out: Option<HeldOut>,
    /// A study to an accuracy: its pilots' ladders and the level chosen.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub to_accuracy: Option<ToAccuracy>,
    /// A level of the pilots of this study (a study to an accuracy): its scene is that level's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pilot_of: Option<StudyId>,
    /// The held-out check of this study to an accuracy: some of its points re-solved cold one
    /// level finer (dt / 2 and h / 2 of the level chosen).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub confirms: Option<StudyId>,
}

impl StudyRecord {
    /// The studies that hang under this one, each with what it is in a user's words: its
    /// audits (iteration, time step, mesh, surface, held-out check) and its pilots' levels.
    /// `child` reads a named study's record (a level's refinement is its own).
    pub fn dependents<'a>(&self, child: impl Fn(StudyId) -> Option<&'a StudyRecord>) -> Vec<(StudyId, &'static str)> {
        let mut out: Vec<(StudyId, &'static str)> = self.audit.iter().map(|&a| (a, "iteration")).collect();
        for &level in &self.refined_by {
            let mesh = child(level)
                .and_then(|r| r.refines.as_ref())
                .is_some_and(|r| r.refinement == glissade_core::refine::Refinement::Mesh);
            out.push((level, if mesh { "mesh" } else { "time step" }));
        }
        out.extend(self.surface_audit.map(|a| (a, "surface")));
        if let Some(t) = &self.to_accuracy {
            out.extend(t.levels.iter().map(|&(_, _, id)| (id, "pilot level")));
            out.extend(t.above.iter().map(|a| (a.check, "held-out check")));
            out.extend(t.held_out.map(|c| (c, "held-out check")));
        }
        out
    }
}

/// A study to an accuracy (core::accuracy, docs/accuracy.md): its pilot points climb the
/// ladders of levels one lease at a time, each level a study of its own (`pilot_of`), refined
/// from the study's scene as submitted (its `scene` until the level is chosen); once every pilot
/// is done the study takes the finest of the pilots' cheapest levels within it, and its points
/// are solved there.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ToAccuracy {
    pub accuracy: f64,
    pub limits: glissade_core::accuracy::AccuracyLimits,
    /// The study's points that are its pilots.
    pub pilots: Vec<u64>,
    /// Per pilot, the levels its ladder asked for, in order: (refinement, dt / k, h / m).
    pub asked: Vec<Vec<(glissade_core::refine::Refinement, usize, usize)>>,
    /// The studies of the levels, as opened: (dt / k, h / m, study).
    pub levels: Vec<(usize, usize, StudyId)>,
    /// Per pilot, its report once its ladder is read to the end.
    pub reports: Vec<Option<glissade_core::accuracy::AccuracyReport>>,
    /// Once every pilot is done: the level (dt / k, h / m) the study is solved at.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub chosen: Option<(usize, usize)>,
    /// The study's points re-solved one level finer once it has ended (the spread order's next
    /// after the pilots: between them).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub held_out_points: Vec<u64>,
    /// The study of that check (opened with the level).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub held_out: Option<StudyId>,
    /// Why no level was chosen (a pilot did not reach the accuracy): the points are cancelled.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub why_not: Option<String>,
    /// The levels a held-out check found ABOVE, in order: after each the study moved one level
    /// finer (its points solved again there) and opened a new check.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub above: Vec<Above>,
}

/// A level of a study to an accuracy that its held-out check found ABOVE.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Above {
    pub time_factor: usize,
    pub mesh_factor: usize,
    /// the check that said so
    pub check: StudyId,
}

impl ToAccuracy {
    /// The pilots' ladders are all read.
    pub fn decided(&self) -> bool {
        self.chosen.is_some() || self.why_not.is_some()
    }

    /// Per QoI over the pilots done: the estimate of the pilot whose total is largest (its parts
    /// with it), within the accuracy only if every pilot's is.
    pub fn largest_estimates(&self) -> BTreeMap<String, QoiEstimate> {
        let mut qoi: BTreeMap<String, QoiEstimate> = BTreeMap::new();
        for q in self.reports.iter().flatten().flat_map(|r| &r.qois) {
            let this = QoiEstimate {
                total: q.total,
                time: q.time.error.estimate,
                mesh: q.mesh.as_ref().map(|m| m.error.estimate),
                joint: q.joint.as_ref().map(|j| j.error.estimate),
                iteration: q.iteration,
                within: q.within,
            };
            let kept = qoi.entry(q.name.clone()).or_insert(this);
            let within = kept.within && this.within;
            if this.total > kept.total {
                *kept = this;
            }
            kept.within = within;
        }
        qoi
    }
}

/// One QoI's estimated error at a level, relative to its scale, and its parts.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct QoiEstimate {
    pub total: f64,
    pub time: f64,
    /// None: the mesh was not refined (its error in no estimate)
    pub mesh: Option<f64>,
    /// dt and h halved together, where the answer was read there: the total is this and the
    /// iterations', the time step's and the mesh's apart are not added
    pub joint: Option<f64>,
    pub iteration: f64,
    pub within: bool,
}

/// How a surface audit's points were drawn, and what its study predicted at them (None until
/// that study has ended).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct HeldOut {
    /// The seed of their draw (`held_out::points`), random at submission, so that every study,
    /// a resubmitted one too, is judged on points of its own; None in records written before
    /// 2026-11-26, drawn with the study's id.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub predicted: Option<Predicted>,
}

impl HeldOut {
    /// The seed its points were drawn with, the study's id for the records that do not say.
    pub fn seed_of(&self, study: StudyId) -> u64 {
        self.seed.unwrap_or(study.0)
    }
}

/// A surface's predictions at the held-out points, made from the study's points alone.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Predicted {
    /// Points the surface was fitted to.
    pub fitted: u32,
    /// Per held-out point (in point id order), per QoI: the mean and standard deviation.
    pub at: Vec<BTreeMap<String, (f64, f64)>>,
    /// QoIs whose surface could not be fitted, and why.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub refused: BTreeMap<String, String>,
    pub unix_ms: i64,
}

/// What a discretisation audit level refines, and by how much.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Refines {
    pub study: StudyId,
    pub refinement: glissade_core::refine::Refinement,
    pub factor: u32,
}

/// A mesh file of a study's scene: its name in the scene, SHA-256 (hex) and size.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct MeshRef {
    pub file: String,
    pub sha256: String,
    pub bytes: u64,
}

/// The box and budget of an adaptive study.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AdaptiveSpec {
    /// (name, low, high) per swept parameter, sorted by name.
    pub ranges: Vec<(String, f64, f64)>,
    pub budget: u32,
    /// Stop before the budget once every QoI's surface is this good (a share of its spread).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target: Option<f64>,
    /// How a study with a target ended (None while it runs): no point is chosen after it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub outcome: Option<TargetOutcome>,
    /// No point is chosen once the points' work reaches this (dynamic iterations + static
    /// iterations / steps, summed over the points solved).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub work_budget: Option<f64>,
}

impl AdaptiveSpec {
    /// Points still to be chosen: none once the target's outcome is decided.
    pub fn unchosen(&self, chosen: u32) -> u32 {
        if self.outcome.is_some() { 0 } else { self.budget.saturating_sub(chosen) }
    }

    /// Whether another point would take the points' work past the work budget: the work so
    /// far, and the mean work of a solved point for each point in flight and the next one.
    pub fn work_spent(&self, points: &[PointRecord]) -> bool {
        self.work_budget.is_some_and(|budget| {
            let solved = points.iter().filter(|p| p.result.is_some()).count();
            let in_flight =
                points.iter().filter(|p| matches!(p.state, PointState::Pending | PointState::Leased { .. })).count();
            let work = work_of(points);
            let mean = if solved > 0 { work / solved as f64 } else { 0.0 };
            work + mean * (in_flight + 1) as f64 > budget
        })
    }

    pub fn design(&self) -> AdaptiveDesign {
        AdaptiveDesign { ranges: self.ranges.clone(), budget: self.budget as usize, target: self.target }
    }
}

/// The work of the points solved so far (dynamic iterations + static iterations / steps).
pub fn work_of(points: &[PointRecord]) -> f64 {
    points.iter().filter_map(|p| p.result.as_ref()).map(|r| r.work).sum()
}

/// Where a point is in its life.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "state", rename_all = "lowercase")]
pub enum PointState {
    Pending,
    /// Held by `pool` until `deadline_unix_ms` (wall clock, so that it survives a restart).
    Leased {
        pool: String,
        lease_id: u64,
        deadline_unix_ms: i64,
        /// The stored solution its warm start came from.
        init: Option<Box<SolutionOrigin>>,
        /// An audit's lease: the iterations left of its cost cap, where fewer than the study's
        /// limit (a solve stopped there was cut short by the cap, not by the solver)
        #[serde(default, skip_serializing_if = "Option::is_none")]
        cap: Option<u32>,
    },
    Done,
    Failed,
    Cancelled,
}

/// A reference to a stored solution, as recorded in a point ("started from") or a solution
/// ("parent").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SolutionOrigin {
    #[serde(with = "shared_text")]
    pub scene_hash: Arc<str>,
    /// Every parameter of the solution.
    pub parameters: DesignPoint,
    pub study: Option<StudyId>,
    pub point: Option<PointId>,
}

/// What a solve of a point gave (converged or not).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PointResult {
    pub pool: String,
    pub converged: bool,
    pub iterations: u64,
    pub error_indicator: f64,
    pub qoi: QoiMap,
    pub wall_seconds: f64,
    pub started_from: Option<Box<SolutionOrigin>>,
    /// Answered from a stored solution without iterations.
    pub answered: bool,
    /// eta after each dynamic-stage iteration (absent in records written before it existed);
    /// in the coordinator's memory its length only (the points tree keeps the values).
    #[serde(default)]
    pub eta_history: EtaHistory,
    /// Dynamic iterations + static iterations / steps (0 in records written before it existed).
    #[serde(default)]
    pub work: f64,
    /// What each frictional interface's contact did while it slid (none in records written
    /// before it existed).
    #[serde(default, skip_serializing_if = "Vec::is_empty", deserialize_with = "shrunk")]
    pub contact: Vec<ContactActivity>,
    /// The largest magnitude of each QoI's history (none from older pools and records).
    #[serde(default, skip_serializing_if = "QoiMap::is_empty")]
    pub qoi_largest: QoiMap,
}

/// A point's eta history: 800 bytes of a real point's 2.9 kB in the coordinator's memory, where
/// only its page and GetStudy read it (issue 48). A point record holds the values while it is
/// written or shown ([`EtaHistory::Held`]), and once in memory their number only
/// ([`EtaHistory::Stored`]): its stored record (JSON, as before) keeps them, and a reader reads
/// them back from there.
#[derive(Debug, Clone, PartialEq)]
pub enum EtaHistory {
    Held(Box<[f64]>),
    /// In the point's stored record only: this many values (never 0: an empty history is held).
    Stored(u32),
}

impl Default for EtaHistory {
    fn default() -> Self {
        EtaHistory::Held(Box::default())
    }
}

impl From<Vec<f64>> for EtaHistory {
    fn from(values: Vec<f64>) -> Self {
        EtaHistory::Held(values.into_boxed_slice())
    }
}

impl EtaHistory {
    /// How many values (eta after each dynamic-stage iteration).
    pub fn len(&self) -> usize {
        match self {
            EtaHistory::Held(values) => values.len(),
            EtaHistory::Stored(n) => *n as usize,
        }
    }

    /// The values, once held: a history left in the store reads as none (its readers take
    /// [`Self::Held`] ones: `Coordinator::read_histories`).
    pub fn values(&self) -> &[f64] {
        match self {
            EtaHistory::Held(values) => values,
            EtaHistory::Stored(_) => {
                if cfg!(debug_assertions) {
                    panic!("an eta history shown without being read from the store");
                }
                &[]
            }
        }
    }

    /// The values where they are held, None where they were left in the store: a view read
    /// without its histories (GetStudy's `without_eta_histories`, the JSON API) shows none.
    pub fn held(&self) -> Option<&[f64]> {
        match self {
            EtaHistory::Held(values) => Some(values),
            EtaHistory::Stored(_) => None,
        }
    }

    /// Leaves the values to the store, keeping their number; returns them (none if empty or
    /// stored already).
    pub fn leave_stored(&mut self) -> Option<Box<[f64]>> {
        let n = match self {
            EtaHistory::Held(values) if !values.is_empty() => u32::try_from(values.len()).ok()?,
            _ => return None,
        };
        match std::mem::replace(self, EtaHistory::Stored(n)) {
            EtaHistory::Held(values) => Some(values),
            EtaHistory::Stored(_) => None,
        }
    }
}

impl Serialize for EtaHistory {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        match self {
            EtaHistory::Held(values) => values.serialize(serializer),
            // written without its values, a record would lose them for good
            EtaHistory::Stored(_) => Err(serde::ser::Error::custom("an eta history written before it was read back")),
        }
    }
}

impl<'de> Deserialize<'de> for EtaHistory {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        // (a boxed slice: at its length, where a vector would keep serde's doubled capacity)
        Box::<[f64]>::deserialize(deserializer).map(EtaHistory::Held)
    }
}

/// The eta history in a point's stored record (none when it holds no result), read without
/// the rest of the record.
pub fn decode_eta_history(key: &[u8], bytes: &[u8]) -> Result<Box<[f64]>, DecodeError> {
    #[derive(Deserialize)]
    struct Point {
        result: Option<Solved>,
    }
    #[derive(Deserialize)]
    struct Solved {
        #[serde(default)]
        eta_history: Box<[f64]>,
    }
    let point: Point = decode("points", key, bytes)?;
    Ok(point.result.map(|r| r.eta_history).unwrap_or_default())
}

/// One design point of a study.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PointRecord {
    pub study: StudyId,
    pub id: PointId,
    /// The swept parameters only.
    pub parameters: DesignPoint,
    #[serde(flatten)]
    pub state: PointState,
    /// Leases granted since submission or the last RetryFailed.
    pub attempts: u32,
    /// The last solve's result (also for a non-converged FAILED point).
    pub result: Option<Box<PointResult>>,
    /// Why the point failed, or why its last attempt did.
    pub error: Option<String>,
    /// Completion order among all points (for the `previous` strategy); None until done.
    pub finished_seq: Option<u64>,
    /// When it last became done, failed or cancelled (Unix ms; None before, and in records
    /// written before it existed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub finished_unix_ms: Option<i64>,
}

impl PointRecord {
    /// Point `id` of `study` at `parameters` (the swept ones), pending, never leased.
    pub fn pending(study: StudyId, id: PointId, parameters: DesignPoint) -> Self {
        PointRecord {
            study,
            id,
            parameters,
            state: PointState::Pending,
            attempts: 0,
            result: None,
            error: None,
            finished_seq: None,
            finished_unix_ms: None,
        }
    }
}

/// Metadata of a stored solution; its fields are in `solution_fields` under the same key.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SolutionRecord {
    #[serde(with = "shared_text")]
    pub scene_hash: Arc<str>,
    /// Every parameter of the scene at this solution.
    pub parameters: DesignPoint,
    /// Version of the solver that computed it: it answers a request only of the same version.
    pub solver_version: String,
    pub converged: bool,
    pub error_indicator: f64,
    pub tolerance: f64,
    pub iterations: u64,
    pub wall_seconds: f64,
    pub qoi: QoiMap,
    /// The solution its iterations started from.
    pub parent: Option<Box<SolutionOrigin>>,
    /// The study point whose solve stored it.
    pub study: Option<StudyId>,
    pub point: Option<PointId>,
    pub stored_unix_ms: i64,
    /// Size of the solution file, and of its zstd compression as stored.
    pub file_bytes: u64,
    pub stored_bytes: u64,
    /// What each frictional interface's contact did while it slid: a point this solution
    /// answers carries it (none in records written before it existed).
    #[serde(default, skip_serializing_if = "Vec::is_empty", deserialize_with = "shrunk")]
    pub contact: Vec<ContactActivity>,
    /// The largest magnitude of each QoI's history (none from older pools and records).
    #[serde(default, skip_serializing_if = "QoiMap::is_empty")]
    pub qoi_largest: QoiMap,
    /// The pool that sent it, as it registered (empty in records written before it existed):
    /// an operator can purge one pool's answers (`glissade purge-pool`).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub pool: String,
}

impl SolutionRecord {
    /// Whether this (new) solution should replace `old` under the same key: converged beats
    /// not converged, the current solver version beats another, then the tighter tolerance (the
    /// accuracy its stopping test vouches for), then the smaller eta.
    pub fn replaces(&self, old: &SolutionRecord, current_version: &str) -> bool {
        if self.converged != old.converged {
            return self.converged;
        }
        let (new_current, old_current) =
            (self.solver_version == current_version, old.solver_version == current_version);
        if new_current != old_current {
            return new_current;
        }
        if self.tolerance != old.tolerance {
            return self.tolerance < old.tolerance;
        }
        self.error_indicator <= old.error_indicator
    }

    /// This solution as an origin reference.
    pub fn origin(&self) -> SolutionOrigin {
        SolutionOrigin {
            scene_hash: self.scene_hash.clone(),
            parameters: self.parameters.clone(),
            study: self.study,
            point: self.point,
        }
    }
}

/// zstd level of stored fields. On a three-blocks-small solution file (2.4 MB of f64 fields),
/// measured with `zstd -b1 -e3`: level 1 at 450 MB/s to 68 % of the size, level 2 at 410 MB/s
/// to 58 %, level 3 at 250 MB/s to 55 %; level 2 keeps a completion's cost low for 5 % more disk.
const ZSTD_LEVEL: i32 = 2;

/// Compresses a solution file for the `solution_fields` tree.
pub fn encode_fields(file: &[u8]) -> std::io::Result<Vec<u8>> {
    zstd::encode_all(file, ZSTD_LEVEL)
}

/// The solution file stored in `solution_fields`.
pub fn decode_fields(stored: &[u8]) -> std::io::Result<Vec<u8>> {
    zstd::decode_all(stored)
}

/// JSON encoding of a record (records hold only finite numbers: the coordinator checks them).
pub fn encode<T: Serialize>(record: &T) -> Vec<u8> {
    serde_json::to_vec(record).expect("records serialise to JSON")
}

/// A record that does not decode: the database is damaged or of another layout.
#[derive(Debug, thiserror::Error)]
#[error("{tree} record {key}: {message}")]
pub struct DecodeError {
    pub tree: &'static str,
    pub key: String,
    pub message: String,
}

/// Decodes a record of `tree` stored under `key`.
pub fn decode<T: for<'de> Deserialize<'de>>(tree: &'static str, key: &[u8], bytes: &[u8]) -> Result<T, DecodeError> {
    serde_json::from_slice(bytes).map_err(|e| DecodeError {
        tree,
        key: key.iter().map(|b| format!("{b:02x}")).collect(),
        message: e.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pv(pairs: &[(&str, f64)]) -> DesignPoint {
        DesignPoint::from_pairs(pairs.iter().map(|&(n, v)| (n, v))).unwrap()
    }

    #[test]
    fn solution_keys_are_prefixed_by_the_scene_and_exact_in_values() {
        let h = "ab".repeat(32);
        let a = SolutionKey::new(&h, &pv(&[("f1", 0.1), ("f2", 0.2)]));
        assert!(a.to_bytes().starts_with(h.as_bytes()));
        assert_eq!(a.point_bytes(&h), Some(&a.to_bytes()[64..]));
        assert_eq!(a.point_bytes(&"cd".repeat(32)), None);
        assert_eq!(a, SolutionKey::new(&h, &pv(&[("f2", 0.2), ("f1", 0.1)])));
        assert_ne!(a, SolutionKey::new(&h, &pv(&[("f1", 0.1), ("f2", 0.2 + 1e-16)])));
        assert_ne!(a, SolutionKey::new(&"cd".repeat(32), &pv(&[("f1", 0.1), ("f2", 0.2)])));
        // a name boundary cannot be shifted: ("ab", x) differs from ("a", ...) ("b", ...)
        assert_ne!(SolutionKey::new(&h, &pv(&[("ab", 1.0)])), SolutionKey::new(&h, &pv(&[("a", 1.0), ("b", 1.0)])));
        assert_eq!(SolutionKey::new(&h, &pv(&[("v", -0.0)])), SolutionKey::new(&h, &pv(&[("v", 0.0)])));
    }

    /// Records hold scene hashes shared, origins boxed and vectors at their length (issue 48):
    /// what they store is the JSON they stored before, read back equal.
    #[test]
    fn compact_records_store_the_json_they_stored_before() {
        let h = "cd".repeat(32);
        let origin = SolutionOrigin {
            scene_hash: shared(&h),
            parameters: pv(&[("f1", 0.1)]),
            study: Some(StudyId(1)),
            point: Some(PointId(2)),
        };
        let result = PointResult {
            pool: "p".into(),
            converged: true,
            iterations: 3,
            error_indicator: 1e-4,
            qoi: [("slip_A".to_owned(), 1.2e-6)].into(),
            wall_seconds: 0.5,
            started_from: Some(Box::new(origin.clone())),
            answered: false,
            eta_history: (0..100).map(|k| 0.9f64.powi(k)).collect::<Vec<_>>().into(),
            work: 3.0,
            contact: vec![],
            qoi_largest: QoiMap::default(),
        };
        let json = String::from_utf8(encode(&result)).unwrap();
        let hash = format!(r#""started_from":{{"scene_hash":"{h}","parameters":{{"f1":0.1}},"study":1,"point":2}}"#);
        assert!(json.contains(&hash), "{json}");
        let back: PointResult = decode("points", b"k", json.as_bytes()).unwrap();
        assert_eq!((&back, encode(&back)), (&result, json.into_bytes()));
        assert_eq!(back.eta_history.len(), 100);
        // a point's record: its history read alone; left to the store, it is not written again
        // without its values
        let mut point = PointRecord::pending(StudyId(1), PointId(2), pv(&[("f1", 0.1)]));
        point.result = Some(Box::new(back.clone()));
        let stored = encode(&point);
        assert_eq!(decode_eta_history(b"k", &stored).unwrap(), result.eta_history.values().into());
        let values = point.result.as_mut().unwrap().eta_history.leave_stored();
        assert_eq!(
            (values.map(|v| v.len()), &point.result.as_ref().unwrap().eta_history),
            (Some(100), &EtaHistory::Stored(100))
        );
        assert!(serde_json::to_vec(&point).is_err());
        assert!(
            decode_eta_history(b"k", &encode(&PointRecord::pending(StudyId(1), PointId(2), pv(&[]))))
                .unwrap()
                .is_empty()
        );
        // one copy of a hash however many records name it
        let back = back.started_from.unwrap();
        assert!(Arc::ptr_eq(&back.scene_hash, &origin.scene_hash));
        assert_eq!(serde_json::from_str::<SolutionOrigin>(&serde_json::to_string(&origin).unwrap()).unwrap(), origin);
    }

    #[test]
    fn point_keys_sort_by_study_then_point() {
        let keys = [point_key(StudyId(1), PointId(300)), point_key(StudyId(2), PointId(0))];
        assert!(keys[0] < keys[1]);
        assert!(point_key(StudyId(1), PointId(2)) < point_key(StudyId(1), PointId(256)));
        assert_eq!(&keys[1][..8], &study_key(StudyId(2)));
    }

    #[test]
    fn records_round_trip_and_damage_is_named() {
        let p = PointRecord {
            study: StudyId(3),
            id: PointId(4),
            parameters: pv(&[("f1", 0.15)]),
            state: PointState::Leased { pool: "p1".into(), lease_id: 9, deadline_unix_ms: 1234, init: None, cap: None },
            attempts: 1,
            result: None,
            error: None,
            finished_seq: None,
            finished_unix_ms: None,
        };
        let bytes = encode(&p);
        let back: PointRecord = decode("points", b"k", &bytes).unwrap();
        assert_eq!(back, p);
        let err = decode::<PointRecord>("points", &[1, 255], b"{").unwrap_err();
        assert!(err.to_string().starts_with("points record 01ff: "), "{err}");
    }
}
