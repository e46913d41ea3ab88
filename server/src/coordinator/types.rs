//! What the coordinator's callers give and get: its settings, errors, events, views of studies,
//! and the requests and grants of the lease protocol.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Duration;

use glissade_core::contact::ContactActivity;
use glissade_core::point::DesignPoint;
use glissade_core::scene::Tolerance;
use glissade_core::study::holdout::SurfaceErrors;
use glissade_core::study::order::OrderKind;
use glissade_core::study::strategy::InitStrategy;
use glissade_core::study::surrogate::Prediction;
use glissade_proto::{PointId, StudyId};

use crate::records::{self, PointRecord, PointState, StudyRecord};
use crate::store::StoreError;

use super::WarmStart;
use super::transitions;

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
    /// Most points pending over all studies (a submission that would pass it is refused).
    pub max_pending: usize,
    /// Longest a point may stay leased (from its lease, whatever its heartbeats): then it fails.
    pub point_budget: Duration,
}

/// Errors of the domain layer; each names the object concerned. `convert::status` maps each variant
/// to one gRPC status code.
#[derive(Debug, thiserror::Error)]
pub enum CoordError {
    /// A request that can never succeed as sent (INVALID_ARGUMENT): the field at fault and why.
    #[error("{0}")]
    Invalid(InvalidRequest),
    #[error("no study {0}")]
    UnknownStudy(StudyId),
    #[error("study {study} has no point {point}")]
    UnknownPoint { study: StudyId, point: PointId },
    #[error("pool `{0}` is not registered (register again)")]
    UnknownPool(String),
    #[error("no stored solution {0}")]
    UnknownSolution(String),
    #[error("no stored mesh file of SHA-256 {0}")]
    UnknownMesh(String),
    /// A valid request the current state forbids (FAILED_PRECONDITION).
    #[error("{0}")]
    Precondition(String),
    /// A limit of the coordinator reached; may succeed later (RESOURCE_EXHAUSTED).
    #[error("{0}")]
    Exhausted(String),
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

impl CoordError {
    /// An invalid request whose message is `field: reason` (`refine_mesh: the mesh h / 2 ...`).
    pub fn invalid(field: impl Into<String>, reason: impl std::fmt::Display) -> Self {
        CoordError::Invalid(InvalidRequest::new(field, reason))
    }

    /// An invalid request whose message names its field in its own words and is read as given
    /// (`refine_levels 4: ...`, `no scene with hash ...`).
    pub fn invalid_worded(field: impl Into<String>, message: impl std::fmt::Display) -> Self {
        CoordError::Invalid(InvalidRequest::worded(field, message))
    }
}

/// Why a request can never succeed as sent: the request field at fault, named as the API names
/// it (`scene`, `meshes`, `work_budget`, `refine_mesh`, `predict_at[3]`, `accuracy_pilots`,
/// `strategy`, `solution`, ...), and the reason, in words for its user. Its message (Display,
/// and the INVALID_ARGUMENT status's) is `field: reason`, or the reason alone where that names
/// the field its own way.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct InvalidRequest {
    pub field: String,
    pub reason: String,
    /// The message is `reason` alone (which names the field in its own words).
    pub worded: bool,
}

impl InvalidRequest {
    /// The message `field: reason`.
    pub fn new(field: impl Into<String>, reason: impl std::fmt::Display) -> Self {
        Self { field: field.into(), reason: reason.to_string(), worded: false }
    }

    /// The message `message`, which names `field` its own way.
    pub fn worded(field: impl Into<String>, message: impl std::fmt::Display) -> Self {
        Self { field: field.into(), reason: message.to_string(), worded: true }
    }
}

impl std::fmt::Display for InvalidRequest {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.worded { f.write_str(&self.reason) } else { write!(f, "{}: {}", self.field, self.reason) }
    }
}

impl std::error::Error for InvalidRequest {}

impl From<transitions::IllegalTransition> for CoordError {
    fn from(e: transitions::IllegalTransition) -> Self {
        CoordError::Precondition(e.to_string())
    }
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

impl StudyState {
    pub const ALL: [StudyState; 4] = [StudyState::Active, StudyState::Done, StudyState::Failed, StudyState::Cancelled];
}

/// What the coordinator holds at one instant, for `/metrics` (counted when scraped).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Gauges {
    /// Studies by state word (every state present, 0 included).
    pub studies: BTreeMap<&'static str, u64>,
    /// Design points by state word (every state present, 0 included).
    pub points: BTreeMap<&'static str, u64>,
    /// Points pending, as `max_pending` counts them (an adaptive study's unchosen points too).
    pub pending: u64,
    /// Points leased to pools now.
    pub leases: u64,
    /// Leases lost (deadline or per-point budget passed) since this process started.
    pub leases_expired: u64,
    /// Pools heard from (registration, lease call or heartbeat) within one lease period.
    pub pools_connected: u64,
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
/// The version of a study's view (its own and its audits' records and points): two readings
/// with the same version read the same view.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct StudyVersion(pub(crate) Vec<(u64, u64)>);

#[derive(Debug, Clone)]
pub struct StudyView {
    pub record: StudyRecord,
    pub state: StudyState,
    pub progress: Progress,
    /// (their eta histories' lengths only: `Coordinator::study_with_histories` reads the values)
    pub points: Vec<PointRecord>,
    pub accuracy: Option<Accuracy>,
    /// What its discretisation audit measured (None: it has none).
    pub discretisation: Option<Discretisation>,
    /// What its surface audit measured of its response surface (None: it has none).
    pub surface_accuracy: Option<SurfaceAccuracy>,
    /// A study to an accuracy: what its held-out points said one level finer (None: no check).
    pub held_out_check: Option<HeldOutCheck>,
    /// Iterations and eta its pool last reported, per leased point that reported (not stored).
    pub solving: BTreeMap<PointId, (u64, f64)>,
    /// `grid`, `list`, `adaptive` or `audit`.
    pub kind: &'static str,
    /// The scene's `title` (empty: none).
    pub scene_title: String,
    /// Its scene, parsed once where the study entered (without its mesh bytes): the web page
    /// reads its units from it rather than parsing the text again.
    pub scene: Arc<glissade_core::scene::Scene>,
    /// When its last point ended, once it has ended (Unix ms).
    pub finished_unix_ms: Option<i64>,
    /// The studies under it (its audits, its pilots' levels), in the order it opened them.
    pub audits: Vec<AuditView>,
}

impl StudyView {
    /// Which error dominates each QoI, one sentence a QoI (core::accuracy::verdict): the
    /// iterations' error its audit measured beside the time step's and the mesh's its
    /// discretisation audit estimated, each said with how it was estimated. The API, the web
    /// page, `show` and the demo give these.
    pub fn verdicts(&self) -> Vec<String> {
        use glissade_core::accuracy::{ErrorPart, verdict};
        let Some(d) = &self.discretisation else { return Vec::new() };
        d.qoi
            .iter()
            .filter_map(|(name, e)| {
                let mut parts: Vec<ErrorPart> = (self.accuracy.as_ref())
                    .and_then(|a| a.qoi.get(name))
                    .map(|&(largest, _)| ErrorPart::iterations(largest))
                    .into_iter()
                    .collect();
                parts.push(ErrorPart::time_step(e.error, e.order, e.order_assumed, e.erratic > 0));
                parts.extend(e.mesh.map(|m| ErrorPart::mesh(m.error)));
                verdict(name, &parts)
            })
            .collect()
    }
}

/// A study under another (an audit or a pilots' level), as its parent shows it.
#[derive(Debug, Clone, PartialEq)]
pub struct AuditView {
    pub study: StudyId,
    /// `iteration`, `time step`, `mesh`, `surface`, `held-out check` or `pilot level`
    pub what: &'static str,
    pub state: StudyState,
    pub progress: Progress,
    /// why its points were cancelled unsolved (its cost cap, no prediction, ...), if some were
    pub why_cancelled: Option<String>,
}

/// The held-out check of a study to an accuracy: some of its points re-solved cold one level
/// finer (dt / 2, h / 2 of its level), per QoI the largest |study - finer| over the points done
/// in both, relative to the QoI's scale in the finer solve (core::accuracy::scales).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct HeldOutCheck {
    pub study: StudyId,
    /// the finer level: dt / time_factor, h / mesh_factor
    pub time_factor: usize,
    pub mesh_factor: usize,
    pub planned: u32,
    /// re-solved and converged, and their study point done
    pub done: u32,
    /// re-solves that did not converge or failed
    pub failed: u32,
    pub difference: BTreeMap<String, f64>,
    /// every point done, none failed, every difference within half the accuracy
    /// (core::accuracy::held_out_confirms); None while it runs
    pub confirmed: Option<bool>,
}

/// A submission, validated by the service layer's conversions.
#[derive(Debug, Clone)]
pub struct Submission {
    pub scene_text: String,
    pub grid: Vec<String>,
    pub points: Vec<DesignPoint>,
    pub tolerance: Option<Tolerance>,
    pub max_iterations: Option<u32>,
    pub strategy: InitStrategy,
    pub order: OrderKind,
    pub label: String,
    /// Points re-solved by the audit (None: [`default_audit_points`]; 0: no audit).
    pub audit_points: Option<u32>,
    /// Points re-solved with the time step halved (None: [`DEFAULT_REFINE_POINTS`]; 0: none).
    pub refine_points: Option<u32>,
    /// Levels of that discretisation audit, the study's own included (0: 2).
    pub refine_levels: u32,
    /// The discretisation audit's points also re-solved on the mesh refined once (box bodies'
    /// elements x 2 along each axis, the study's time step), cold.
    pub refine_mesh: bool,
    /// An adaptive study instead of `grid` / `points`: `NAME=LOW:HIGH` ranges and the budget.
    pub adaptive: Option<(Vec<String>, u32)>,
    /// An adaptive study's target: stop once every QoI's estimated largest error in the box is
    /// within this share of its spread (its budget: `adaptive`'s, or
    /// [`glissade_core::study::adaptive::TARGET_BUDGET`] where that is 0).
    pub surface_accuracy: Option<f64>,
    /// An adaptive study chooses no point once its points' work reaches this.
    pub work_budget: Option<f64>,
    /// Points held out of the study's response surface (None: [`default_surface_audit_points`];
    /// 0: none).
    pub surface_audit_points: Option<u32>,
    /// Solve the study to this accuracy: pilots choose dt, h and the tolerance first.
    pub accuracy: Option<f64>,
    /// With `accuracy`: how many pilots (None: [`glissade_core::accuracy::DEFAULT_PILOTS`]).
    pub accuracy_pilots: Option<u32>,
    /// The mesh files the scene names.
    pub meshes: Vec<MeshUpload>,
}

/// A mesh file carried by a submission.
#[derive(Debug, Clone)]
pub struct MeshUpload {
    /// the scene's `file`
    pub file: String,
    pub data: Vec<u8>,
    /// SHA-256 (hex) the sender announced; empty: not checked
    pub sha256: String,
}

/// The audit's tolerance, relative to the study's.
pub const AUDIT_TOLERANCE_RATIO: f64 = 0.01;
/// The audit's iteration limit, relative to the study's (a tighter tolerance takes longer).
pub const AUDIT_ITERATION_FACTOR: u32 = 4;

/// An audit's cost cap: this fraction of its study's work (dynamic iterations + static
/// iterations / steps), so that measuring a study never costs more than half of solving it.
pub const AUDIT_WORK_FRACTION: f64 = 0.5;

/// An audit's work: its cap and what it spent.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AuditBudget {
    pub cap: f64,
    pub spent: f64,
}

impl AuditBudget {
    pub fn remaining(&self) -> f64 {
        (self.cap - self.spent).max(0.0)
    }
}

/// Points a study's audit re-solves unless told: 10 %, at least 2 (at most all).
pub fn default_audit_points(points: usize) -> usize {
    points.div_ceil(10).max(2).min(points)
}

/// Points held out of a study's response surface unless told: [`SURFACE_AUDIT_POINTS`], at most
/// a quarter of its points (its own solves stay the bulk of the work: a study of fewer than 4 has
/// none); none for a study of more points than a surface is fitted to.
pub fn default_surface_audit_points(points: usize) -> usize {
    if points > glissade_core::study::surrogate::MAX_POINTS {
        return 0;
    }
    SURFACE_AUDIT_POINTS.min(points / 4)
}

/// Held-out points of a surface audit: the mean of that many errors is within a factor 2 of
/// the mean over the whole box in 77-100 % of draws on tiny's two boxes, against 47-94 % for 7
/// (the errors are heavy-tailed; docs/surrogate.md, "How many held-out points"). A mean's
/// precision depends on how many, not on the study's size: a fixed count.
pub const SURFACE_AUDIT_POINTS: usize = 15;

/// Points a study's discretisation audit re-solves unless told (at most the study's).
pub const DEFAULT_REFINE_POINTS: u32 = 2;
/// The most points a discretisation audit may re-solve: each costs 2 (or 2 + 4) of the study's.
pub const MAX_REFINE_POINTS: u32 = 8;
/// The most levels of a discretisation audit, the study's own included (dt, dt / 2, dt / 4).
pub const MAX_REFINE_LEVELS: u32 = 3;

/// What a study's discretisation audit measured (docs/verification.md 11).
#[derive(Debug, Clone, PartialEq)]
pub struct Discretisation {
    /// The refined studies, finest last, and their time-step divisors.
    pub levels: Vec<(StudyId, u32)>,
    /// Points solved at every level so far, of `planned`.
    pub audited: u32,
    pub planned: u32,
    /// Wall seconds of the refined solves done, and of the study's own points done.
    pub work_seconds: f64,
    pub study_seconds: f64,
    pub qoi: BTreeMap<String, QoiDiscretisation>,
    /// The mesh level, where one was asked for.
    pub mesh: Option<MeshLevel>,
}

/// The discretisation audit's mesh level: its points re-solved cold with the box bodies'
/// elements x `factor` along each axis, at the study's time step.
#[derive(Debug, Clone, PartialEq)]
pub struct MeshLevel {
    pub study: StudyId,
    pub factor: u32,
    /// Points solved on it (and by the study) so far, of the audit's `planned`.
    pub audited: u32,
    /// Wall seconds of its solves done.
    pub work_seconds: f64,
}

/// One QoI's discretisation error over the audited points, relative to the largest |final
/// value| of the QoI over the points and levels compared.
#[derive(Debug, Clone, PartialEq)]
pub struct QoiDiscretisation {
    /// largest |q(dt / 2) - q(dt)|
    pub change: f64,
    /// largest estimated error of the study's values (core::refine::richardson's `error_first`)
    pub error: f64,
    /// observed order, mean over the points that observed one (None: 2 levels, or none did)
    pub order: Option<f64>,
    /// 2 levels: the scheme's order was assumed
    pub order_assumed: bool,
    /// points whose changes are erratic
    pub erratic: u32,
    /// every point's last change within the iterations' noise
    pub below_tolerance: bool,
    /// The mesh's part, with a mesh level: the same measures for h / 2 (order 2 assumed).
    pub mesh: Option<MeshError>,
}

/// One QoI's change and estimated error with the mesh refined once (two levels: the order 2 of
/// linear elements' displacements assumed), relative as [`QoiDiscretisation`]'s.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshError {
    /// largest |q(h / 2) - q(h)|
    pub change: f64,
    /// largest |q(h) - Richardson's extrapolation| (4/3 of the change)
    pub error: f64,
    /// every point's change within the iterations' noise
    pub below_tolerance: bool,
}

/// What a study's audit measured.
#[derive(Debug, Clone, PartialEq)]
pub struct Accuracy {
    pub audit_study: StudyId,
    pub tolerance: f64,
    /// Points compared so far, of `planned`.
    pub audited: u32,
    pub planned: u32,
    /// Per QoI: (largest, mean) of |study - audit| / largest |audit|.
    pub qoi: BTreeMap<String, (f64, f64)>,
    /// The audit's work so far and its cap (0 until its study has ended).
    pub work: f64,
    pub work_cap: f64,
}

/// What a study's surface audit measured: its response surface's predictions at held-out
/// points (made before they were solved) against their solves at the audit's tolerance.
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceAccuracy {
    pub audit_study: StudyId,
    pub tolerance: f64,
    /// Held-out points compared so far, of `planned`.
    pub validated: u32,
    pub planned: u32,
    /// Points the surface was fitted to (0 until the study has ended and it predicted).
    pub fitted: u32,
    /// The seed the held-out points were drawn with (records::HeldOut::seed).
    pub seed: u64,
    /// Per QoI: largest and mean |predicted - solved| / the QoI's spread, share within 2 sd.
    pub qoi: BTreeMap<String, SurfaceErrors>,
    /// QoIs whose surface could not be fitted, and why.
    pub refused: BTreeMap<String, String>,
    /// The audit's work so far and its cap (0 until its study has ended).
    pub work: f64,
    pub work_cap: f64,
}

/// A point handed to a pool.
#[derive(Debug, Clone)]
pub struct LeaseGrant {
    pub lease_id: u64,
    pub study: StudyId,
    pub point: PointId,
    pub parameters: DesignPoint,
    pub scene_text: String,
    pub scene_hash: String,
    pub tolerance: f64,
    pub max_iterations: u32,
    pub deadline_unix_ms: i64,
    /// The warm start, if any.
    pub init: Option<WarmStart>,
    /// The scene's mesh files (fetched by digest).
    pub meshes: Vec<crate::records::MeshRef>,
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
    pub contact: Vec<ContactActivity>,
    /// the largest magnitude of each QoI's history
    pub qoi_largest: BTreeMap<String, f64>,
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
    pub parameters: DesignPoint,
    pub qoi: BTreeMap<String, f64>,
    pub iterations: u64,
    pub error_indicator: f64,
    pub converged: bool,
    /// Point state for a study source; Done/Failed for a stored solution.
    pub state: PointState,
    /// The tolerance its QoIs were solved to (a study's points: the study's, an upper bound for
    /// those answered from tighter stored solutions), whose error the surface carries.
    pub tolerance: f64,
}

/// A response surface.
#[derive(Debug, Clone)]
pub struct Surface {
    pub scene_hash: String,
    pub parameters: Vec<String>,
    pub qoi: Vec<String>,
    pub rows: Vec<SurfaceRow>,
    /// One per point asked for.
    pub predictions: Vec<PointPrediction>,
    /// The unit of each parameter that declares one and of each QoI, where the scene is known.
    pub units: BTreeMap<String, String>,
}

/// The response surface's prediction at a point asked for.
#[derive(Debug, Clone)]
pub struct PointPrediction {
    pub at: DesignPoint,
    /// Per QoI (in the surface's `qoi` order).
    pub qoi: Vec<QoiPredicted>,
}

/// A QoI's prediction at a point.
#[derive(Debug, Clone, Copy)]
pub struct QoiPredicted {
    pub prediction: Prediction,
    /// points its surface was fitted to
    pub fitted: usize,
    /// its band of 2 standard deviations, within the physics' bound (a norm's at zero)
    pub band: (f64, f64),
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
    Key(String, DesignPoint),
}
