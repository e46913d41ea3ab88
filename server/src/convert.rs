//! The edge between generated proto messages and the domain: every incoming message is
//! validated here (`TryFrom`, errors as [`Invalid`]), every domain error becomes a status here
//! ([`status`]), so each rule and each status code lives in one place.

use std::collections::BTreeMap;

use glissade_core::contact::{ContactActivity, MAX_CONTACT_REPORTS};
use glissade_core::point::DesignPoint;
use glissade_core::scene::{MAX_MESH_BYTES, MAX_MESH_FILES, Tolerance};
use glissade_core::text::one_line;
use glissade_proto::v1;
use glissade_proto::{PointId, StudyId};
use tonic::{Code, Status};

use crate::coordinator::{
    Completion, CoordError, Discretisation, Event, EventKind, Failure, HeldOutCheck, MeshUpload, PoolInfo, Progress,
    SolutionSelector, StudyState, StudyView, Submission, Surface, SurfaceSource,
};
use glissade_core::study::order::OrderKind;
use glissade_core::study::strategy::{InitStrategy, StrategyKind};

use crate::records::{PointRecord, PointState, SolutionOrigin};
use crate::store::StoreError;

/// Largest scene text accepted (scenes are a few kilobytes; a mesh file would be another story).
pub const MAX_SCENE_BYTES: usize = 1 << 20;
/// The largest SubmitStudy message the coordinator decodes: the mesh files' bound
/// ([`MAX_MESH_BYTES`]) and 4 MiB (gRPC's default, for the scene, grid and points). Every other
/// message keeps gRPC's 4 MiB.
pub const MAX_SUBMISSION_BYTES: usize = MAX_MESH_BYTES as usize + (4 << 20);

/// An invalid message: becomes INVALID_ARGUMENT with this text.
#[derive(Debug)]
pub struct Invalid(pub String);

impl From<Invalid> for Status {
    fn from(e: Invalid) -> Self {
        Status::invalid_argument(one_line(&e.0))
    }
}

/// The status of a domain error: the one place where codes are chosen.
pub fn status(e: CoordError) -> Status {
    let code = match &e {
        CoordError::Invalid(_) => Code::InvalidArgument,
        CoordError::UnknownStudy(_)
        | CoordError::UnknownPoint { .. }
        | CoordError::UnknownPool(_)
        | CoordError::UnknownSolution(_)
        | CoordError::UnknownMesh(_) => Code::NotFound,
        CoordError::Precondition(_) => Code::FailedPrecondition,
        CoordError::Corrupt(_) => Code::DataLoss,
        CoordError::Exhausted(_) => Code::ResourceExhausted,
        CoordError::Store(StoreError::Full { .. }) => {
            tracing::error!(error = %e, "storage full");
            Code::ResourceExhausted
        }
        CoordError::Store(_) | CoordError::Decode(_) | CoordError::Index(_) => {
            tracing::error!(error = %e, "storage error");
            Code::Internal
        }
    };
    let unknown_pool = matches!(e, CoordError::UnknownPool(_));
    // bounded: a message that echoes a huge input must not outgrow the metadata limit
    let mut status = Status::new(code, one_line(&e.to_string()));
    if unknown_pool {
        status
            .metadata_mut()
            .insert(glissade_proto::auth::REGISTER_AGAIN, tonic::metadata::MetadataValue::from_static("1"));
    }
    status
}

impl From<CoordError> for Status {
    fn from(e: CoordError) -> Self {
        status(e)
    }
}

/// A design point from a request: core's one check (`DesignPoint`'s `TryFrom`), named by `what`.
fn parameters(what: &str, values: BTreeMap<String, f64>) -> Result<DesignPoint, Invalid> {
    DesignPoint::try_from(values).map_err(|e| Invalid(format!("{what}: {e}")))
}

/// Neighbours a blend or a linear fit may combine.
pub const MAX_NEIGHBOURS: u32 = 8;

/// The request's strategy; unspecified: core's default. `blend_neighbours` 0: the strategy's
/// default number of neighbours.
fn strategy(value: i32, blend_neighbours: u32) -> Result<InitStrategy, Invalid> {
    let kind = match v1::InitStrategy::try_from(value) {
        Ok(v1::InitStrategy::Unspecified) => StrategyKind::DEFAULT,
        Ok(v1::InitStrategy::Nearest) => StrategyKind::Nearest,
        Ok(v1::InitStrategy::Cold) => StrategyKind::Cold,
        Ok(v1::InitStrategy::Previous) => StrategyKind::Previous,
        Ok(v1::InitStrategy::Blend) => StrategyKind::Blend,
        Ok(v1::InitStrategy::Linear) => StrategyKind::Linear,
        Err(_) => return Err(Invalid(format!("strategy: unknown value {value}"))),
    };
    if blend_neighbours > MAX_NEIGHBOURS {
        return Err(Invalid(format!("blend_neighbours {blend_neighbours}: at most {MAX_NEIGHBOURS}")));
    }
    let k = if blend_neighbours == 0 { StrategyKind::DEFAULT_NEIGHBOURS } else { blend_neighbours as usize };
    Ok(kind.with_neighbours(k))
}

fn order(value: i32) -> Result<OrderKind, Invalid> {
    Ok(match v1::PointOrder::try_from(value) {
        Ok(v1::PointOrder::Unspecified | v1::PointOrder::Greedy) => OrderKind::Greedy,
        Ok(v1::PointOrder::Ascending) => OrderKind::Asc,
        Ok(v1::PointOrder::Descending) => OrderKind::Desc,
        Err(_) => return Err(Invalid(format!("order: unknown value {value}"))),
    })
}

impl TryFrom<v1::SubmitStudyRequest> for Submission {
    type Error = Invalid;

    fn try_from(m: v1::SubmitStudyRequest) -> Result<Self, Invalid> {
        if m.scene.trim().is_empty() {
            return Err(Invalid("scene: empty (give the scene file's TOML text)".into()));
        }
        if m.scene.len() > MAX_SCENE_BYTES {
            return Err(Invalid(format!("scene: {} bytes, more than the {MAX_SCENE_BYTES} accepted", m.scene.len())));
        }
        if let Some(t) = m.surface_accuracy {
            glissade_core::study::adaptive::check_target(t).map_err(|e| Invalid(format!("surface_accuracy: {e}")))?;
            if m.ranges.is_empty() {
                return Err(Invalid(
                    "surface_accuracy: a target is for an adaptive study: give its ranges (NAME=LOW:HIGH)".into(),
                ));
            }
        }
        let adaptive = match (m.ranges.is_empty(), m.adaptive_points) {
            (true, 0) => None,
            // a target with no budget: the default budget (the coordinator's)
            (false, 0) if m.surface_accuracy.is_none() => {
                return Err(Invalid("ranges: give adaptive_points too (the study's number of points)".into()));
            }
            (true, _) => return Err(Invalid("adaptive_points: give the ranges (NAME=LOW:HIGH) too".into())),
            (false, n) => {
                if m.ranges.len() > 64 || m.ranges.iter().any(|r| r.len() > 256) {
                    return Err(Invalid("ranges: at most 64, of at most 256 bytes each".into()));
                }
                if !m.grid.is_empty() || !m.points.is_empty() {
                    return Err(Invalid("an adaptive study takes ranges, not a grid or points".into()));
                }
                Some((m.ranges, n))
            }
        };
        if m.grid.is_empty() && m.points.is_empty() && adaptive.is_none() {
            return Err(Invalid("empty study: give a grid (`NAME=SPEC`) or a list of points".into()));
        }
        if !m.grid.is_empty() && !m.points.is_empty() {
            return Err(Invalid("give either a grid or a list of points, not both".into()));
        }
        let points = m
            .points
            .into_iter()
            .enumerate()
            .map(|(i, p)| parameters(&format!("points[{i}]"), p.values))
            .collect::<Result<Vec<_>, _>>()?;
        let tolerance =
            m.tolerance.map(|t| Tolerance::new("tolerance", t)).transpose().map_err(|e| Invalid(e.to_string()))?;
        if let Some(n) = m.max_iterations {
            glissade_core::scene::check_max_iterations("max_iterations", n.into())
                .map_err(|e| Invalid(e.to_string()))?;
        }
        if m.label.len() > 1024 {
            return Err(Invalid("label: longer than 1024 bytes".into()));
        }
        if !glissade_core::text::is_plain_text(&m.label) {
            return Err(Invalid(format!(
                "label `{}`: control or direction characters (escapes, carriage returns, overrides) are not allowed",
                glissade_core::text::printable(&m.label)
            )));
        }
        if m.meshes.len() > MAX_MESH_FILES {
            return Err(Invalid(format!("meshes: {} files, more than the {MAX_MESH_FILES} allowed", m.meshes.len())));
        }
        if let Some(f) = m.meshes.iter().find(|f| f.file.len() > 1024 || f.sha256.len() > 64) {
            return Err(Invalid(format!(
                "meshes: a file name of {} bytes or a digest of {} (at most 1024 and 64)",
                f.file.len(),
                f.sha256.len()
            )));
        }
        Ok(Submission {
            scene_text: m.scene,
            grid: m.grid,
            points,
            tolerance,
            max_iterations: m.max_iterations,
            strategy: strategy(m.strategy, m.blend_neighbours)?,
            order: order(m.order)?,
            label: m.label,
            audit_points: m.audit_points,
            refine_points: m.refine_points,
            refine_levels: m.refine_levels,
            refine_mesh: m.refine_mesh,
            adaptive,
            surface_audit_points: m.surface_audit_points,
            surface_accuracy: m.surface_accuracy,
            work_budget: m.work_budget,
            accuracy: m.accuracy,
            accuracy_pilots: m.accuracy_pilots,
            meshes: m.meshes.into_iter().map(|f| MeshUpload { file: f.file, data: f.data, sha256: f.sha256 }).collect(),
        })
    }
}

/// A response-surface query.
pub struct SurfaceQuery {
    pub source: SurfaceSource,
    pub fixed: DesignPoint,
    pub qoi: Vec<String>,
    pub predict_at: Vec<DesignPoint>,
}

/// The most points one QuerySurface predicts at.
pub const MAX_PREDICTIONS: usize = 10_000;

impl TryFrom<v1::QuerySurfaceRequest> for SurfaceQuery {
    type Error = Invalid;

    fn try_from(m: v1::QuerySurfaceRequest) -> Result<Self, Invalid> {
        let source = match m.source {
            Some(v1::query_surface_request::Source::StudyId(id)) => SurfaceSource::Study(StudyId(id)),
            Some(v1::query_surface_request::Source::SceneHash(h)) => SurfaceSource::Scene(scene_hash(&h)?),
            None => return Err(Invalid("give a study_id or a scene_hash".into())),
        };
        if m.predict_at.len() > MAX_PREDICTIONS {
            return Err(Invalid(format!(
                "predict_at: {} points, more than the {MAX_PREDICTIONS} accepted",
                m.predict_at.len()
            )));
        }
        let predict_at = m
            .predict_at
            .into_iter()
            .enumerate()
            .map(|(i, p)| parameters(&format!("predict_at[{i}]"), p.parameters))
            .collect::<Result<_, _>>()?;
        Ok(Self { source, fixed: parameters("fixed", m.fixed)?, qoi: m.qoi, predict_at })
    }
}

fn scene_hash(h: &str) -> Result<String, Invalid> {
    if h.len() == 64 && h.bytes().all(|b| b.is_ascii_hexdigit()) {
        Ok(h.to_ascii_lowercase())
    } else {
        Err(Invalid(format!("scene_hash `{}`: expected 64 hexadecimal digits", h.escape_debug())))
    }
}

impl TryFrom<v1::FetchSolutionRequest> for SolutionSelector {
    type Error = Invalid;

    fn try_from(m: v1::FetchSolutionRequest) -> Result<Self, Invalid> {
        match m.solution {
            Some(v1::fetch_solution_request::Solution::Point(p)) => {
                Ok(SolutionSelector::Point(StudyId(p.study_id), PointId(p.point_id)))
            }
            Some(v1::fetch_solution_request::Solution::Key(k)) => {
                Ok(SolutionSelector::Key(scene_hash(&k.scene_hash)?, parameters("key.parameters", k.parameters)?))
            }
            None => Err(Invalid("give a point (study_id, point_id) or a key (scene_hash, parameters)".into())),
        }
    }
}

/// A pool id: what logs, leases and errors name, so kept printable.
pub fn pool_id(id: &str) -> Result<String, Invalid> {
    let ok = !id.is_empty()
        && id.len() <= 64
        && id.bytes().all(|b| b.is_ascii_alphanumeric() || matches!(b, b'-' | b'_' | b'.'));
    if ok {
        Ok(id.to_owned())
    } else {
        Err(Invalid(format!("pool_id `{}`: use 1 to 64 letters, digits, `-`, `_` or `.`", id.escape_debug())))
    }
}

/// A pool's registration: its id (None: to be assigned) and description.
pub struct Registration {
    pub id: Option<String>,
    pub info: PoolInfo,
}

impl TryFrom<v1::RegisterPoolRequest> for Registration {
    type Error = Invalid;

    fn try_from(m: v1::RegisterPoolRequest) -> Result<Self, Invalid> {
        let id = if m.pool_id.is_empty() { None } else { Some(pool_id(&m.pool_id)?) };
        if m.ranks == 0 {
            return Err(Invalid("ranks must be at least 1".into()));
        }
        if m.solver_version.is_empty() || m.solver_version.len() > 64 {
            return Err(Invalid("solver_version: give the pool's `glissade-worker --version`".into()));
        }
        let host: String = m.host.chars().filter(|c| !c.is_control()).take(256).collect();
        Ok(Self { id, info: PoolInfo { ranks: m.ranks, host, solver_version: m.solver_version } })
    }
}

impl TryFrom<v1::CompletePointHeader> for Completion {
    type Error = Invalid;

    fn try_from(m: v1::CompletePointHeader) -> Result<Self, Invalid> {
        if !m.error_indicator.is_finite() {
            return Err(Invalid(format!("error_indicator is not finite: {}", m.error_indicator)));
        }
        // Divergence is reported with FailPoint; a completed history is finite like eta.
        if let Some(x) = m.eta_history.iter().find(|x| !x.is_finite()) {
            return Err(Invalid(format!("eta_history holds a non-finite value: {x}")));
        }
        if !(m.work.is_finite() && m.work >= 0.0 && m.work <= m.iterations as f64) {
            return Err(Invalid(format!("work must be in 0..=iterations, got {}", m.work)));
        }
        if m.contact.len() > MAX_CONTACT_REPORTS {
            return Err(Invalid(format!("contact: at most {MAX_CONTACT_REPORTS} interfaces, got {}", m.contact.len())));
        }
        let contact = m
            .contact
            .into_iter()
            .map(ContactActivity::try_from)
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| Invalid(e.to_string()))?;
        // (bounded by the QoIs the solution file names, which check_meta holds to the header's)
        if let Some((name, x)) =
            m.qoi_largest.iter().find(|(n, x)| !(x.is_finite() && **x >= 0.0 && m.qoi.contains_key(*n)))
        {
            return Err(Invalid(format!(
                "qoi_largest: '{}' = {x}: a QoI of `qoi`, finite and 0 or more",
                one_line(name)
            )));
        }
        Ok(Completion {
            pool: pool_id(&m.pool_id)?,
            lease_id: m.lease_id,
            study: StudyId(m.study_id),
            point: PointId(m.point_id),
            converged: m.converged,
            iterations: m.iterations,
            error_indicator: m.error_indicator,
            qoi: m.qoi,
            wall_seconds: m.wall_seconds,
            eta_history: m.eta_history,
            work: m.work,
            started_cold: m.started_cold,
            contact,
            qoi_largest: m.qoi_largest,
        })
    }
}

impl TryFrom<v1::FailPointRequest> for Failure {
    type Error = Invalid;

    fn try_from(m: v1::FailPointRequest) -> Result<Self, Invalid> {
        let error = m.error.trim();
        if error.is_empty() {
            return Err(Invalid("error: say what went wrong".into()));
        }
        // Stored and shown: one line, bounded.
        let error: String = error.lines().collect::<Vec<_>>().join(" ").chars().take(4096).collect();
        if m.error_indicator.is_some_and(|e| !e.is_finite()) {
            // A diverged solve: keep the fact in words, not a NaN in the record.
            return Ok(Failure {
                pool: pool_id(&m.pool_id)?,
                lease_id: m.lease_id,
                study: StudyId(m.study_id),
                point: PointId(m.point_id),
                error: format!("{error} (eta not finite)"),
                error_indicator: None,
                iterations: m.iterations,
            });
        }
        Ok(Failure {
            pool: pool_id(&m.pool_id)?,
            lease_id: m.lease_id,
            study: StudyId(m.study_id),
            point: PointId(m.point_id),
            error,
            error_indicator: m.error_indicator,
            iterations: m.iterations,
        })
    }
}

// ---- domain -> proto ----

pub fn study_state(s: StudyState) -> v1::StudyState {
    match s {
        StudyState::Active => v1::StudyState::Active,
        StudyState::Done => v1::StudyState::Done,
        StudyState::Failed => v1::StudyState::Failed,
        StudyState::Cancelled => v1::StudyState::Cancelled,
    }
}

pub fn point_state(s: &PointState) -> v1::PointState {
    match s {
        PointState::Pending => v1::PointState::Pending,
        PointState::Leased { .. } => v1::PointState::Leased,
        PointState::Done => v1::PointState::Done,
        PointState::Failed => v1::PointState::Failed,
        PointState::Cancelled => v1::PointState::Cancelled,
    }
}

pub fn progress(p: Progress) -> v1::StudyProgress {
    v1::StudyProgress {
        total: p.total,
        pending: p.pending,
        leased: p.leased,
        done: p.done,
        failed: p.failed,
        cancelled: p.cancelled,
        iterations: p.iterations,
    }
}

pub fn origin(o: &SolutionOrigin) -> v1::SolutionRef {
    v1::SolutionRef {
        scene_hash: o.scene_hash.to_string(),
        parameters: o.parameters.clone().into(),
        study_id: o.study.map_or(0, |s| s.0),
        point_id: o.point.map_or(0, |p| p.0),
    }
}

pub fn point(p: &PointRecord) -> v1::PointStatus {
    let r = p.result.as_deref();
    let (pool, deadline, leased_from) = match &p.state {
        PointState::Leased { pool, deadline_unix_ms, init, .. } => (pool.clone(), *deadline_unix_ms, init.as_deref()),
        _ => (r.map(|r| r.pool.clone()).unwrap_or_default(), 0, None),
    };
    let started_from = r.and_then(|r| r.started_from.as_deref()).or(leased_from);
    v1::PointStatus {
        study_id: p.study.0,
        point_id: p.id.0,
        parameters: p.parameters.clone().into(),
        state: point_state(&p.state).into(),
        attempts: p.attempts,
        pool_id: pool,
        iterations: r.map_or(0, |r| r.iterations),
        error_indicator: r.and_then(|r| glissade_core::text::measured_eta(r.error_indicator)),
        qoi: r.map(|r| r.qoi.clone().into()).unwrap_or_default(),
        started_from: started_from.map(origin),
        answered: r.is_some_and(|r| r.answered),
        wall_seconds: r.map_or(0.0, |r| r.wall_seconds),
        error: p.error.clone().unwrap_or_default(),
        lease_deadline_unix_ms: deadline,
        // (a view read without its histories has them in the store: none shown)
        eta_history: r.and_then(|r| r.eta_history.held()).map(<[f64]>::to_vec).unwrap_or_default(),
        work: r.map_or(0.0, |r| r.work),
        contact: r.map(|r| r.contact.iter().map(Into::into).collect()).unwrap_or_default(),
    }
}

/// A study to an accuracy as the API gives it.
fn to_accuracy(t: &crate::records::ToAccuracy, tolerance: f64, check: Option<&HeldOutCheck>) -> v1::StudyToAccuracy {
    let reports: Vec<&glissade_core::accuracy::AccuracyReport> = t.reports.iter().flatten().collect();
    let qoi = t
        .largest_estimates()
        .into_iter()
        .map(|(name, e)| {
            let q = v1::QoiToAccuracy {
                total: e.total,
                time: e.time,
                mesh: e.mesh.unwrap_or(-1.0),
                joint: e.joint,
                iteration: e.iteration,
                within: e.within,
            };
            (name, q)
        })
        .collect();
    v1::StudyToAccuracy {
        max_time_factor: t.limits.max_time_factor as u32,
        max_mesh_factor: t.limits.max_mesh_factor as u32,
        level_time_factors: t.levels.iter().map(|l| l.0 as u32).collect(),
        level_mesh_factors: t.levels.iter().map(|l| l.1 as u32).collect(),
        held_out_points: t.held_out_points.clone(),
        pilots: pilots(t),
        above_time_factors: t.above.iter().map(|a| a.time_factor as u32).collect(),
        above_mesh_factors: t.above.iter().map(|a| a.mesh_factor as u32).collect(),
        above_check_ids: t.above.iter().map(|a| a.check.0).collect(),
        accuracy: t.accuracy,
        tolerance,
        pilot_points: t.pilots.clone(),
        pilots_done: reports.len() as u32,
        chosen: t.chosen.is_some(),
        time_factor: t.chosen.map_or(0, |(k, _)| k as u32),
        mesh_factor: t.chosen.map_or(0, |(_, m)| m as u32),
        reached: t.chosen.is_some(),
        why_not: t.why_not.clone().unwrap_or_default(),
        qoi,
        level_study_ids: t.levels.iter().map(|l| l.2.0).collect(),
        pilot_work: reports.iter().map(|r| r.work).sum(),
        pilot_wall_seconds: reports.iter().map(|r| r.wall_seconds).sum(),
        newmark_gamma: reports.first().map_or(0.0, |r| r.newmark_gamma),
        held_out_study_id: check.map_or(0, |c| c.study.0),
        held_out_time_factor: check.map_or(0, |c| c.time_factor as u32),
        held_out_mesh_factor: check.map_or(0, |c| c.mesh_factor as u32),
        held_out_planned: check.map_or(0, |c| c.planned),
        held_out_done: check.map_or(0, |c| c.done),
        held_out_failed: check.map_or(0, |c| c.failed),
        held_out_difference: check.map(|c| c.difference.clone().into_iter().collect()).unwrap_or_default(),
        confirmed: check.and_then(|c| c.confirmed),
    }
}

/// Each pilot of a study to an accuracy: the levels its ladders asked for, and its report.
fn pilots(t: &crate::records::ToAccuracy) -> Vec<v1::PilotLadders> {
    t.pilots
        .iter()
        .enumerate()
        .map(|(i, &point_id)| v1::PilotLadders {
            point_id,
            asked: (t.asked.get(i).into_iter().flatten())
                .map(|&(refinement, k, m)| v1::LevelAsked {
                    refinement: glissade_proto::accuracy::refinement(refinement).to_owned(),
                    time_factor: k as u32,
                    mesh_factor: m as u32,
                })
                .collect(),
            report: t.reports.get(i).and_then(Option::as_ref).map(Into::into),
        })
        .collect()
}

/// The unit of each parameter of the scene that declares one and of each QoI.
fn units(scene: &glissade_core::scene::Scene) -> BTreeMap<String, String> {
    let names = scene.parameters.keys().chain(scene.qoi.iter().map(|q| &q.name));
    names.filter_map(|n| Some((n.clone(), scene.unit(n)?.to_owned()))).collect()
}

/// A study as GetStudy returns it, and the web API and `show --json` write it
/// (glissade_proto::json): its leased points with what their pools last reported.
pub fn study(v: &StudyView) -> v1::Study {
    let r = &v.record;
    v1::Study {
        units: units(&v.scene),
        verdicts: v.verdicts(),
        to_accuracy: r.to_accuracy.as_ref().map(|t| to_accuracy(t, r.tolerance, v.held_out_check.as_ref())),
        pilot_of: r.pilot_of.map_or(0, |s| s.0),
        audits: v
            .audits
            .iter()
            .map(|a| v1::StudyAudit {
                study_id: a.study.0,
                what: a.what.to_owned(),
                state: study_state(a.state).into(),
                progress: Some(progress(a.progress)),
                why_cancelled: a.why_cancelled.clone().unwrap_or_default(),
            })
            .collect(),
        study_id: r.id.0,
        label: r.label.clone(),
        scene_hash: r.scene_hash.clone(),
        state: study_state(v.state).into(),
        strategy: match r.strategy {
            InitStrategy::Cold => v1::InitStrategy::Cold,
            InitStrategy::Previous => v1::InitStrategy::Previous,
            InitStrategy::Nearest => v1::InitStrategy::Nearest,
            InitStrategy::Blend { .. } => v1::InitStrategy::Blend,
            InitStrategy::Linear { .. } => v1::InitStrategy::Linear,
        }
        .into(),
        order: match r.order {
            OrderKind::Asc => v1::PointOrder::Ascending,
            OrderKind::Desc => v1::PointOrder::Descending,
            OrderKind::Greedy => v1::PointOrder::Greedy,
        }
        .into(),
        blend_neighbours: match r.strategy {
            InitStrategy::Blend { k } | InitStrategy::Linear { k } => k as u32,
            _ => 0,
        },
        tolerance: r.tolerance,
        max_iterations: r.max_iterations,
        progress: Some(progress(v.progress)),
        parameters: r.parameters.clone(),
        created_unix_ms: r.created_unix_ms,
        points: v
            .points
            .iter()
            .map(|p| {
                let mut status = point(p);
                if let Some(&(iterations, eta)) = v.solving.get(&p.id) {
                    (status.iterations, status.error_indicator) = (iterations, Some(eta));
                }
                status
            })
            .collect(),
        scene: String::new(),
        accuracy: v.accuracy.as_ref().map(|a| v1::StudyAccuracy {
            audit_study_id: a.audit_study.0,
            tolerance: a.tolerance,
            audited: a.audited,
            planned: a.planned,
            qoi: a.qoi.iter().map(|(q, &(largest, mean))| (q.clone(), v1::QoiAccuracy { largest, mean })).collect(),
            work: a.work,
            work_cap: a.work_cap,
        }),
        audit_of: r.audit_of.map_or(0, |s| s.0),
        kind: v.kind.to_owned(),
        scene_title: v.scene_title.clone(),
        finished_unix_ms: v.finished_unix_ms.unwrap_or(0),
        discretisation: v.discretisation.as_ref().map(discretisation),
        refines: r.refines.map_or(0, |x| x.study.0),
        refine_factor: r.refines.map_or(0, |x| x.factor),
        refines_mesh: r.refines.is_some_and(|x| x.refinement == glissade_core::refine::Refinement::Mesh),
        surface_accuracy: v.surface_accuracy.as_ref().map(|a| v1::StudySurfaceAccuracy {
            audit_study_id: a.audit_study.0,
            tolerance: a.tolerance,
            validated: a.validated,
            planned: a.planned,
            fitted: a.fitted,
            qoi: surface_errors(&a.qoi),
            refused: a.refused.clone().into_iter().collect(),
            work: a.work,
            work_cap: a.work_cap,
            seed: a.seed,
        }),
        held_out: r.held_out.is_some(),
        target: r.adaptive.as_ref().and_then(|a| {
            let outcome = a.outcome.as_ref();
            Some(v1::StudyTarget {
                surface_accuracy: a.target?,
                budget: a.budget,
                outcome: outcome.map_or("", target_outcome).into(),
                points: outcome.map_or(0, |o| o.validation.points as u32),
                qoi: outcome.map(|o| surface_errors(&o.validation.qoi)).unwrap_or_default(),
                refused: outcome.map(|o| o.validation.refused.clone().into_iter().collect()).unwrap_or_default(),
                work_budget: a.work_budget.unwrap_or(0.0),
                work: crate::records::work_of(&v.points),
            })
        }),
    }
}

/// What a study's discretisation audit measured.
fn discretisation(d: &Discretisation) -> v1::StudyDiscretisation {
    v1::StudyDiscretisation {
        level_study_ids: d.levels.iter().map(|(s, _)| s.0).collect(),
        factors: d.levels.iter().map(|&(_, f)| f).collect(),
        audited: d.audited,
        planned: d.planned,
        work_seconds: d.work_seconds,
        study_seconds: d.study_seconds,
        qoi: d
            .qoi
            .iter()
            .map(|(name, q)| {
                (
                    name.clone(),
                    v1::QoiDiscretisation {
                        change: q.change,
                        error: q.error,
                        order: q.order.unwrap_or(0.0),
                        order_assumed: q.order_assumed,
                        erratic: q.erratic,
                        below_tolerance: q.below_tolerance,
                        mesh_change: q.mesh.map(|m| m.change),
                        mesh_error: q.mesh.map(|m| m.error),
                        mesh_below_tolerance: q.mesh.is_some_and(|m| m.below_tolerance),
                    },
                )
            })
            .collect(),
        mesh_study_id: d.mesh.as_ref().map_or(0, |m| m.study.0),
        mesh_factor: d.mesh.as_ref().map_or(0, |m| m.factor),
        mesh_audited: d.mesh.as_ref().map_or(0, |m| m.audited),
        mesh_work_seconds: d.mesh.as_ref().map_or(0.0, |m| m.work_seconds),
    }
}

/// How a study with a target ended, as `StudyTarget.outcome` says it.
pub(crate) fn target_outcome(o: &glissade_core::study::adaptive::TargetOutcome) -> &'static str {
    if o.reached {
        "reached"
    } else if o.validation.only_set_aside() {
        "set_aside"
    } else {
        "budget"
    }
}

/// Per QoI errors of a surface (held-out or cross-validated), relative to its spread.
fn surface_errors(
    qoi: &BTreeMap<String, glissade_core::study::holdout::SurfaceErrors>,
) -> BTreeMap<String, v1::QoiSurfaceAccuracy> {
    qoi.iter()
        .map(|(q, e)| {
            let points = e.count as u32;
            let box_largest = e.box_largest.unwrap_or(0.0);
            (
                q.clone(),
                v1::QoiSurfaceAccuracy {
                    largest: e.largest,
                    mean: e.mean,
                    within_2sd: e.within_2sd,
                    points,
                    box_largest,
                },
            )
        })
        .collect()
}

pub fn event(e: &Event) -> v1::StudyEvent {
    let kind = match e.kind {
        EventKind::Started => v1::EventKind::PointStarted,
        EventKind::Finished => v1::EventKind::PointFinished,
        EventKind::Failed => v1::EventKind::PointFailed,
        EventKind::Requeued => v1::EventKind::PointRequeued,
        EventKind::StudyEnded => v1::EventKind::StudyEnded,
        EventKind::Snapshot => v1::EventKind::Snapshot,
        EventKind::Progress => v1::EventKind::PointProgress,
    };
    let mut status = e.point.as_ref().map(point);
    if let (Some(s), Some((iterations, eta))) = (status.as_mut(), e.solving) {
        s.iterations = iterations;
        s.error_indicator = Some(eta);
    }
    v1::StudyEvent {
        kind: kind.into(),
        study_id: e.study.0,
        point: status,
        progress: Some(progress(e.progress)),
        state: study_state(e.state).into(),
        replay: e.replay,
        unix_ms: e.unix_ms,
    }
}

pub fn surface(s: Surface) -> v1::QuerySurfaceReply {
    // the coarsest tolerance of the points (a scene's stored solutions may have several)
    let tolerance = s.rows.iter().map(|r| r.tolerance).fold(0.0, f64::max);
    let resolutions =
        glissade_core::study::resolutions(tolerance, s.rows.iter().map(|r| &r.qoi), |q| s.units.get(q).cloned());
    v1::QuerySurfaceReply {
        resolutions: resolutions.into_iter().collect(),
        digits: glissade_core::text::qoi_digits(tolerance) as u32,
        units: s.units,
        scene_hash: s.scene_hash,
        parameters: s.parameters,
        qoi: s.qoi.clone(),
        points: s
            .rows
            .into_iter()
            .map(|r| v1::SurfacePoint {
                parameters: r.parameters.into(),
                qoi: r.qoi,
                iterations: r.iterations,
                error_indicator: r.error_indicator,
                converged: r.converged,
                state: point_state(&r.state).into(),
            })
            .collect(),
        predictions: s
            .predictions
            .into_iter()
            .map(|p| v1::SurfacePrediction {
                parameters: p.at.into(),
                qoi: s
                    .qoi
                    .iter()
                    .zip(p.qoi)
                    .map(|(q, p)| {
                        let (low, high) = p.band;
                        let (mean, std) = (p.prediction.mean, p.prediction.std);
                        let prediction = v1::QoiPrediction { mean, std, fitted_points: p.fitted as u32, low, high };
                        (q.clone(), prediction)
                    })
                    .collect(),
            })
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An invalid request's status says what its Display says: `field: reason`, or the reason
    /// alone where it names the field its own way.
    #[test]
    fn an_invalid_request_is_invalid_argument_with_its_message() {
        let e = CoordError::invalid("refine_mesh", "the mesh h / 2: a mesh file");
        assert_eq!(e.to_string(), "refine_mesh: the mesh h / 2: a mesh file");
        let s = status(e);
        assert_eq!((s.code(), s.message()), (Code::InvalidArgument, "refine_mesh: the mesh h / 2: a mesh file"));
        let e = CoordError::invalid_worded("refine_levels", "refine_levels 4: 2 or 3");
        assert!(matches!(&e, CoordError::Invalid(r) if r.field == "refine_levels"));
        assert_eq!(status(e).message(), "refine_levels 4: 2 or 3");
    }

    #[test]
    fn a_submission_without_a_strategy_gets_the_default_and_its_neighbours() {
        let unspecified = v1::InitStrategy::Unspecified as i32;
        assert_eq!(strategy(unspecified, 0).unwrap(), StrategyKind::DEFAULT.with_neighbours(3));
        assert_eq!(strategy(unspecified, 0).unwrap(), InitStrategy::Linear { k: 3 });
        assert_eq!(strategy(v1::InitStrategy::Blend as i32, 0).unwrap(), InitStrategy::Blend { k: 3 });
        assert_eq!(strategy(v1::InitStrategy::Linear as i32, 5).unwrap(), InitStrategy::Linear { k: 5 });
        assert_eq!(strategy(v1::InitStrategy::Nearest as i32, 0).unwrap(), InitStrategy::Nearest);
        assert!(strategy(v1::InitStrategy::Linear as i32, 9).unwrap_err().0.contains("at most 8"));
        assert!(strategy(99, 0).is_err());
    }

    /// A study's label is printed by every client and logged: one with an escape, a carriage
    /// return, NUL or a direction override is refused (saying which), before anything is kept.
    #[test]
    fn a_label_that_would_act_on_a_terminal_is_refused() {
        for label in ["a\u{1b}[2J", "ok\rforged", "nul\0", "\u{202e}txt.exe", "osc\u{9d}0;x\u{7}"] {
            let m = v1::SubmitStudyRequest {
                scene: "x".into(),
                grid: vec!["f=0.1".into()],
                label: label.into(),
                ..Default::default()
            };
            let err = Submission::try_from(m).unwrap_err().0;
            assert!(err.contains("label") && err.contains("control or direction"), "{label:?}: {err}");
            assert!(glissade_core::text::is_plain_text(&err), "the refusal itself prints safely: {err:?}");
        }
        let m =
            v1::SubmitStudyRequest { scene: "x".into(), label: "Ti-6Al-4V, 応力 sweep".into(), ..Default::default() };
        if let Err(e) = Submission::try_from(m) {
            assert!(!e.0.contains("label"), "a plain label passes: {}", e.0);
        }
    }

    /// A pool's contact reports are checked like the rest of its completion: a report no solver
    /// makes, or more of them than any scene has interfaces, is refused before it is kept.
    #[test]
    fn a_completion_with_a_contact_report_no_solver_makes_is_refused() {
        let report = v1::ContactActivity {
            interface: "floor".into(),
            friction: 1.2,
            rigid_wall: true,
            contact_nodes: 9,
            first_slip_time: Some(2e-4),
            landings_while_sliding: 4,
            peak_normal_force_ratio: 3.0,
            ill_posed: true,
            // (a pool's word for it is not kept: the coordinator recomputes it)
            chatters: false,
        };
        let header = |contact: Vec<v1::ContactActivity>| v1::CompletePointHeader {
            pool_id: "p".into(),
            iterations: 5,
            contact,
            ..Default::default()
        };
        let kept = Completion::try_from(header(vec![report.clone()])).expect("a report the solver makes");
        assert_eq!(kept.contact.len(), 1);
        assert!(kept.contact[0].ill_posed);
        let spoilt = v1::ContactActivity { peak_normal_force_ratio: f64::INFINITY, ..report.clone() };
        assert!(Completion::try_from(header(vec![spoilt])).unwrap_err().0.contains("finite"));
        let too_many = vec![report; MAX_CONTACT_REPORTS + 1];
        assert!(Completion::try_from(header(too_many)).unwrap_err().0.contains("at most"));
    }

    /// A QoI's largest magnitude (the accuracy's scale) is one of the header's QoIs, finite and
    /// not negative: anything else is refused with the name.
    #[test]
    fn a_qois_largest_magnitude_is_checked() {
        let header = |name: &str, largest: f64| v1::CompletePointHeader {
            pool_id: "p".into(),
            iterations: 5,
            qoi: [("u".to_string(), -2.0)].into(),
            qoi_largest: [(name.to_string(), largest)].into(),
            ..Default::default()
        };
        assert_eq!(Completion::try_from(header("u", 3.0)).unwrap().qoi_largest["u"], 3.0);
        for (name, bad) in [("u", f64::NAN), ("u", -1.0), ("u", f64::INFINITY), ("v", 1.0)] {
            let e = Completion::try_from(header(name, bad)).unwrap_err().0;
            assert!(e.contains("qoi_largest") && e.contains(&format!("'{name}'")), "{e}");
        }
    }
}
