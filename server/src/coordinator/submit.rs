//! A submission's way in: every check made before the coordinator's lock ([`Admitted`]), then
//! under it the study's records and its audits' written in one batch and entered in the state.

use glissade_core::point::DesignPoint;
use glissade_core::scene::{MeshFileError, Scene, SceneError, Tolerance, mesh_digest};
use glissade_core::study::adaptive::{AdaptiveDesign, DesignError, TARGET_BUDGET, check_target, point_tolerance};
use glissade_core::study::space::{ParameterSpace, submission_points};
use glissade_core::study::strategy::InitStrategy;
use glissade_core::text::one_line;
use glissade_proto::{PointId, StudyId};

use super::discretisation::{self, Level};
use super::{
    CoordError, Coordinator, EventKind, State, StudyEntry, Submission, cold_audit_record, default_audit_points,
    default_surface_audit_points, held_out, now_unix_ms,
};
use crate::records::{
    self, AdaptiveSpec, MeshRef, NEXT_STUDY_KEY, PointRecord, StudyRecord, encode, point_key, study_key,
};
use crate::store::{Batch, Tree};
use crate::study::{SceneSolutions, StudyPlan};

/// A study's swept parameter names, its points (none yet for an adaptive study) and its
/// adaptive spec.
type Design = (Vec<String>, Vec<DesignPoint>, Option<AdaptiveSpec>);

/// A submission that passed every check: what [`Coordinator::submit`] stores.
struct Admitted {
    /// parsed, its meshes attached
    scene: Scene,
    scene_hash: String,
    tolerance: f64,
    max_iterations: u32,
    names: Vec<String>,
    points: Vec<DesignPoint>,
    adaptive: Option<AdaptiveSpec>,
    /// (digest, compressed bytes) of the meshes not stored yet
    new_meshes: Vec<(String, Vec<u8>)>,
    /// The points its audits re-solve some of: its own, or an adaptive study's initial points
    /// (known at submit: core::study::adaptive::AdaptiveDesign::initial_points).
    audited: Vec<DesignPoint>,
    audit_points: usize,
    /// points of each refined level
    refine_points: usize,
    refined: Vec<Level>,
    held_out_points: usize,
    /// a study to an accuracy: its pilots (its tolerance is the accuracy's)
    to_accuracy: Option<records::ToAccuracy>,
}

impl Coordinator {
    /// Stores a study and queues its points.
    pub fn submit(&self, mut submission: Submission) -> Result<(StudyId, u32, String), CoordError> {
        let mut admitted = self.admit(&mut submission)?;
        let mut state = self.lock();
        self.check_room(&state, &admitted)?;
        let studies = admitted.records(submission, StudyId(state.next_study), now_unix_ms());
        let next = studies.last().expect("the study itself").0.id.0 + 1;
        self.store_studies(&admitted, &studies, next)?;
        state.next_study = next;
        let id = studies[0].0.id;
        // an adaptive study's points are chosen as it runs: its budget
        let n = studies[0].0.adaptive.as_ref().map_or(studies[0].1.len() as u32, |a| a.budget);
        for (record, points) in studies {
            self.enter_study(&mut state, &admitted, record, points)?;
        }
        drop(state);
        self.work.notify_waiters();
        Ok((id, n, admitted.scene_hash))
    }

    /// Every check of a submission, made before the lock: its scene with its meshes, its
    /// numbers, its points and its audits. Takes the mesh uploads out of `submission`.
    fn admit(&self, submission: &mut Submission) -> Result<Admitted, CoordError> {
        let scene = self.admit_scene(submission)?;
        let scene_hash = scene.content_hash();
        // an adaptive study with a target solves its points to the tolerance the target needs,
        // unless told (core::study::adaptive::point_tolerance)
        if submission.work_budget.is_some() && submission.adaptive.is_none() {
            return Err(CoordError::invalid(
                "work_budget",
                "a work budget is for an adaptive study: give its ranges (NAME=LOW:HIGH)",
            ));
        }
        if let Some(target) = submission.surface_accuracy {
            check_target(target).map_err(|e| CoordError::invalid_worded("surface_accuracy", e))?;
            if submission.adaptive.is_none() {
                return Err(CoordError::invalid(
                    "surface_accuracy",
                    "a target is for an adaptive study: give its ranges (NAME=LOW:HIGH)",
                ));
            }
        }
        // (a submission's own tolerance was checked as it entered: convert.rs)
        let derived = match (submission.tolerance, submission.surface_accuracy) {
            (None, Some(target)) => Some(
                Tolerance::new("surface_accuracy", point_tolerance(target))
                    .map_err(|e| CoordError::invalid_worded("surface_accuracy", e))?,
            ),
            _ => None,
        };
        let (names, points, adaptive) = self.design(submission, &scene)?;
        let to_accuracy = super::to_accuracy::admit(submission, &scene, &points)?;
        let derived = match &to_accuracy {
            Some((_, accuracy)) => Some(
                Tolerance::new("accuracy", accuracy.tolerance())
                    .map_err(|e| CoordError::invalid_worded("accuracy", e))?,
            ),
            None => derived,
        };
        let tolerance = Tolerance::or_scene(submission.tolerance.or(derived), &scene);
        let max_iterations = match submission.max_iterations {
            Some(n) => glissade_core::scene::check_max_iterations("max_iterations", n.into())
                .map_err(|e| CoordError::invalid_worded("max_iterations", e))? as u32,
            // (the scene's was checked as it parsed)
            None => scene.solver.max_iterations as u32,
        };
        if submission.strategy != InitStrategy::Cold {
            // The index refuses scenes of too many parameters: say so now, not at the first lease.
            SceneSolutions::new(scene_hash.clone(), ParameterSpace::from_scene(&scene), self.store.clone()).map_err(
                |e| {
                    CoordError::invalid_worded("strategy", format_args!("strategy {}: {e}", submission.strategy.name()))
                },
            )?;
        }
        let new_meshes = self.new_meshes(&scene)?;
        // A study to an accuracy solves at the level its pilots choose, which the audits, written
        // now from the scene as given, would not be at: it has none.
        // an adaptive study is audited on its initial points (issue 47: it had no iteration and no
        // time-step audit)
        let audited = match &adaptive {
            Some(spec) => spec.design().initial_points(),
            None => points.clone(),
        };
        let (audit_points, refine_points, refined, held_out_points) = if to_accuracy.is_some() {
            (0, 0, Vec::new(), 0)
        } else {
            self.audits(submission, &scene, audited.len(), adaptive.as_ref())?
        };
        Ok(Admitted {
            scene,
            scene_hash,
            tolerance,
            max_iterations,
            names,
            points,
            adaptive,
            new_meshes,
            audited,
            audit_points,
            refine_points,
            refined,
            held_out_points,
            to_accuracy: to_accuracy.map(|(spec, _)| spec),
        })
    }

    /// The points of a study's audits: iteration (its points re-solved tighter), discretisation
    /// (its refined scenes written and checked now) and surface (points held out of it).
    fn audits(
        &self,
        submission: &Submission,
        scene: &Scene,
        n: usize,
        adaptive: Option<&AdaptiveSpec>,
    ) -> Result<(usize, usize, Vec<Level>, usize), CoordError> {
        let audit_points = match submission.audit_points {
            None => default_audit_points(n),
            Some(asked) => (asked as usize).min(n),
        };
        // the discretisation audit: its refined scenes written and checked now
        let (refine_points, refined) = discretisation::plan(submission, scene, n, self.config.max_scene_bytes)?;
        // the surface audit: points held out of the study's response surface
        let study_points = adaptive.map_or(n, |a| a.budget as usize);
        let held_out_points = match submission.surface_audit_points {
            None => default_surface_audit_points(study_points),
            Some(0) => 0,
            Some(_) if study_points > glissade_core::study::surrogate::MAX_POINTS => {
                return Err(CoordError::invalid(
                    "surface_audit_points",
                    format_args!(
                        "a response surface is fitted to at most {} points, this study has {study_points}",
                        glissade_core::study::surrogate::MAX_POINTS
                    ),
                ));
            }
            Some(n) => (n as usize).min(study_points),
        };
        Ok((audit_points, refine_points, refined, held_out_points))
    }

    /// The submission's scene parsed, with its mesh files (each as announced, exactly those
    /// named, bounded: core's one rule) and within the coordinator's size.
    fn admit_scene(&self, submission: &mut Submission) -> Result<Scene, CoordError> {
        let mut scene =
            Scene::parse(&submission.scene_text).map_err(|e| CoordError::invalid("scene", one_line(&e.to_string())))?;
        for m in &submission.meshes {
            let actual = mesh_digest(&m.data);
            if !m.sha256.is_empty() && m.sha256 != actual {
                let e = MeshFileError::DigestMismatch { file: m.file.clone(), expected: m.sha256.clone(), actual };
                return Err(CoordError::invalid("meshes", one_line(&e.to_string())));
            }
        }
        let uploads = std::mem::take(&mut submission.meshes);
        scene
            .attach_mesh_bytes(uploads.into_iter().map(|m| (m.file, m.data)))
            .map_err(|e| CoordError::invalid("meshes", one_line(&e.to_string())))?;
        let size = scene.size().map_err(|e| CoordError::invalid("scene", one_line(&e.to_string())))?;
        if size.bytes() > self.config.max_scene_bytes {
            return Err(CoordError::invalid(
                "scene",
                format_args!(
                    "a solve would need about {} MiB ({} dofs, {} steps, estimated from the text and meshes), more than the {} MiB accepted (glissade-server --max-scene-mib)",
                    size.bytes() >> 20,
                    size.dofs,
                    size.steps,
                    self.config.max_scene_bytes >> 20
                ),
            ));
        }
        // What a pool checks before it solves, checked now (core::check): its message, at once.
        scene.check_meshes().map_err(scene_refused)?;
        Ok(scene)
    }

    /// The study's swept names and points (none yet for an adaptive study, whose spec comes
    /// back instead), each point checked as a pool will check it.
    fn design(&self, submission: &Submission, scene: &Scene) -> Result<Design, CoordError> {
        // the field of the points: a grid, else a list
        let listed = if submission.grid.is_empty() { "points" } else { "grid" };
        let (names, points, adaptive) = match &submission.adaptive {
            None => {
                let (names, points) =
                    submission_points(scene, &submission.grid, &submission.points, self.config.max_points)
                        .map_err(|e| CoordError::invalid_worded(listed, e))?;
                (names, points, None)
            }
            Some(_) if !submission.grid.is_empty() || !submission.points.is_empty() => {
                return Err(CoordError::invalid_worded(listed, "an adaptive study takes ranges, not a grid or points"));
            }
            Some((ranges, budget)) => {
                let space = ParameterSpace::from_scene(scene);
                let target = submission.surface_accuracy;
                let budget = match (*budget, target) {
                    (0, Some(_)) => TARGET_BUDGET.min(self.config.max_points) as u32,
                    (n, _) => n,
                };
                let design = AdaptiveDesign::parse(ranges, budget as usize, target, &space, self.config.max_points)
                    .map_err(design_refused)?;
                let names = design.ranges.iter().map(|(n, ..)| n.clone()).collect();
                let work_budget = submission.work_budget;
                if let Some(w) = work_budget.filter(|w| !(w.is_finite() && *w > 0.0)) {
                    return Err(CoordError::invalid(
                        "work_budget",
                        format_args!("{w}: must be a finite number above 0"),
                    ));
                }
                let spec = AdaptiveSpec { ranges: design.ranges, budget, target, outcome: None, work_budget };
                (names, Vec::new(), Some(spec))
            }
        };
        for (i, point) in points.iter().enumerate() {
            check_point(scene, point).map_err(|e| {
                CoordError::invalid_worded(
                    "scene",
                    format_args!("scene at point {i} ({point}): {}", one_line(&e.to_string())),
                )
            })?;
        }
        if let Some(a) = &adaptive {
            // an adaptive study's points are not known yet: every corner of its box
            for corner in 0..1usize << a.ranges.len().min(12) {
                let at = a
                    .ranges
                    .iter()
                    .enumerate()
                    .map(|(k, (n, lo, hi))| (n, if (corner >> k) & 1 == 1 { *hi } else { *lo }));
                let at = DesignPoint::from_pairs(at).map_err(|e| CoordError::invalid_worded("ranges", e))?;
                check_point(scene, &at).map_err(scene_refused)?;
            }
        }
        Ok((names, points, adaptive))
    }

    /// The scene's mesh files not stored yet, compressed. Content-addressed: a mesh already
    /// stored (another study's) is not stored again (two submissions racing store the same bytes
    /// twice under one key: harmless). Compressed before the lock: it is the costly part.
    fn new_meshes(&self, scene: &Scene) -> Result<Vec<(String, Vec<u8>)>, CoordError> {
        let mut new_meshes = Vec::new();
        for (file, digest) in &scene.mesh_digests {
            if self.store.get(Tree::Meshes, digest.as_bytes())?.is_none() {
                let compressed = records::encode_fields(&scene.meshes[file])
                    .map_err(|e| CoordError::invalid_worded("meshes", format_args!("compressing mesh {file}: {e}")))?;
                new_meshes.push((digest.clone(), compressed));
            }
        }
        Ok(new_meshes)
    }

    /// Every user's pending points together (there is one user token) stay bounded.
    fn check_room(&self, state: &State, admitted: &Admitted) -> Result<(), CoordError> {
        let pending: usize = state.studies.values().map(|e| e.progress().pending as usize).sum();
        let adding = admitted.adding();
        if pending + adding > self.config.max_pending {
            return Err(CoordError::Exhausted(format!(
                "this study would add {adding} points to the {pending} pending, more than the {} the coordinator holds (glissade-server --max-pending): wait for studies to finish, or cancel some",
                self.config.max_pending
            )));
        }
        Ok(())
    }

    /// One batch: the scenes and meshes not stored yet, every study with its points, the next id.
    fn store_studies(
        &self,
        admitted: &Admitted,
        studies: &[(StudyRecord, Vec<PointRecord>)],
        next: u64,
    ) -> Result<(), CoordError> {
        let mut batch = Batch::new();
        let record = &studies[0].0;
        if self.store.get(Tree::Scenes, admitted.scene_hash.as_bytes())?.is_none() {
            batch.put(Tree::Scenes, admitted.scene_hash.as_bytes(), record.scene.as_bytes());
        }
        for level in &admitted.refined {
            if self.store.get(Tree::Scenes, level.hash.as_bytes())?.is_none() {
                batch.put(Tree::Scenes, level.hash.as_bytes(), level.text.as_bytes());
            }
        }
        for (digest, compressed) in &admitted.new_meshes {
            batch.put(Tree::Meshes, digest.as_bytes(), compressed.clone());
        }
        for (r, ps) in studies {
            batch.put(Tree::Studies, study_key(r.id), encode(r));
            for p in ps {
                batch.put(Tree::Points, point_key(r.id, p.id), encode(p));
            }
        }
        batch.put(Tree::Meta, NEXT_STUDY_KEY, next.to_be_bytes());
        self.store.commit(batch)?;
        Ok(())
    }

    /// The warm-start index of a scene, if it has none yet (none for a scene of too many
    /// parameters: its studies are cold, checked at submit).
    pub(super) fn index_scene(&self, state: &mut State, hash: &str, space: &ParameterSpace) {
        // (an error here is a scene its studies solve cold)
        let _ = state.solutions.index_scene(hash, space, &self.store);
    }

    /// A stored study in the coordinator's state, with its plan and its scene's index.
    fn enter_study(
        &self,
        state: &mut State,
        admitted: &Admitted,
        record: StudyRecord,
        points: Vec<PointRecord>,
    ) -> Result<(), CoordError> {
        // (a discretisation audit's level has its own, refined scene)
        let scene = admitted.refined.iter().find(|l| l.hash == record.scene_hash).map_or(&admitted.scene, |l| &l.scene);
        let plan = StudyPlan::new(scene, &record, &points).map_err(plan_refused)?;
        self.index_scene(state, &record.scene_hash, plan.space());
        // (the parsed scene kept without its mesh bytes, as a reopened database has it)
        let mut kept = scene.clone();
        kept.meshes.clear();
        let entry = StudyEntry { record, points, plan, scene: std::sync::Arc::new(kept) };
        tracing::info!(study = %entry.record.id, points = entry.points.len(), scene = %admitted.scene_hash, audit_of = ?entry.record.audit_of, "study submitted");
        self.emit(EventKind::Snapshot, &entry, None);
        let id = entry.record.id;
        state.studies.insert(id, entry);
        // stored answers need no pool: a busy pool must not hold them up
        self.answer_stored(state, id)
    }
}

impl Admitted {
    /// Points the study adds to the pending ones, its audits' included.
    fn adding(&self) -> usize {
        self.points.len()
            + self.audit_points
            + self.refine_points * self.refined.len()
            + self.held_out_points
            + self.adaptive.as_ref().map_or(0, |a| a.budget as usize)
    }

    /// The study's record with its pending points, then its audits' (ids from `id` on, in this
    /// order: the iteration audit, the refined levels, the surface audit).
    fn records(&mut self, submission: Submission, id: StudyId, created: i64) -> Vec<(StudyRecord, Vec<PointRecord>)> {
        let audit_id = (self.audit_points > 0).then_some(StudyId(id.0 + 1));
        let refined_ids: Vec<StudyId> =
            (0..self.refined.len() as u64).map(|k| StudyId(id.0 + 1 + audit_id.is_some() as u64 + k)).collect();
        let mut record = StudyRecord {
            id,
            label: submission.label,
            scene_hash: self.scene_hash.clone(),
            scene: submission.scene_text,
            parameters: self.names.clone(),
            tolerance: self.tolerance,
            max_iterations: self.max_iterations,
            strategy: submission.strategy,
            order: submission.order,
            created_unix_ms: created,
            cancelled: false,
            audit_of: None,
            audit: audit_id,
            adaptive: self.adaptive.clone(),
            listed: !submission.points.is_empty(),
            meshes: self
                .scene
                .meshes
                .iter()
                .map(|(file, bytes)| MeshRef {
                    file: file.clone(),
                    sha256: self.scene.mesh_digests[file].clone(),
                    bytes: bytes.len() as u64,
                })
                .collect(),
            refined_by: if self.refine_points > 0 { refined_ids.clone() } else { Vec::new() },
            refines: None,
            // set below, once the audits' records are written from this one
            surface_audit: None,
            held_out: None,
            to_accuracy: self.to_accuracy.take(),
            pilot_of: None,
            confirms: None,
        };
        // The audit: points spread over the list, re-solved cold at a tighter tolerance.
        let audit = audit_id.map(|audit_id| {
            let chosen = discretisation::spread(&self.audited, self.audit_points);
            (cold_audit_record(&record, audit_id, format!("audit of study {id}")), pending(audit_id, chosen))
        });
        let refined_studies: Vec<(StudyRecord, Vec<PointRecord>)> = self
            .refined
            .iter()
            .zip(&refined_ids)
            .take(if self.refine_points > 0 { self.refined.len() } else { 0 })
            .map(|(level, &rid)| {
                (
                    discretisation::record(&record, rid, level),
                    pending(rid, discretisation::spread(&self.audited, self.refine_points)),
                )
            })
            .collect();
        // The surface audit: points held out of the study's surface, solved as the audit's are.
        let surface_audit = (self.held_out_points > 0)
            .then(|| {
                let sid = StudyId(id.0 + 1 + audit_id.is_some() as u64 + refined_studies.len() as u64);
                // a seed of its own (not the study's id, 1 in every fresh database): a study
                // submitted again is judged on other points; the record keeps it
                let seed: u64 = rand::random();
                let held = held_out::points(
                    &record.parameters,
                    &self.points,
                    record.adaptive.as_ref(),
                    self.held_out_points,
                    seed,
                )
                .into_iter()
                // (the design's points passed this check; its box's may not everywhere)
                .filter(|p| check_point(&self.scene, p).is_ok())
                .collect();
                let mut audit = cold_audit_record(&record, sid, format!("surface audit of study {id}"));
                audit.held_out = Some(records::HeldOut { seed: Some(seed), predicted: None });
                (audit, pending(sid, held))
            })
            // (a box the design fills, a point with no swept parameter: nothing to hold out)
            .filter(|(_, held)| !held.is_empty());
        record.surface_audit = surface_audit.as_ref().map(|(r, _)| r.id);
        let mut studies = vec![(record, pending(id, std::mem::take(&mut self.points)))];
        studies.extend(audit);
        studies.extend(refined_studies);
        studies.extend(surface_audit);
        studies
    }
}

/// A study's points, pending.
fn pending(study: StudyId, points: Vec<DesignPoint>) -> Vec<PointRecord> {
    points
        .into_iter()
        .enumerate()
        .map(|(i, parameters)| PointRecord::pending(study, PointId(i as u64), parameters))
        .collect()
}

/// What a pool checks before it solves a point (core::check), checked at submit.
fn check_point(scene: &Scene, point: &DesignPoint) -> Result<(), SceneError> {
    scene.check_point(&scene.parameter_values(point)?)
}

/// A scene the checks refuse: its message, on one line.
fn scene_refused(e: SceneError) -> CoordError {
    CoordError::invalid("scene", one_line(&e.to_string()))
}

/// An adaptive design refused: the field at fault (the target, the budget, else the ranges) and
/// core's message.
fn design_refused(e: DesignError) -> CoordError {
    let field = match &e {
        DesignError::Target(_) => "surface_accuracy",
        DesignError::Budget { .. } => "adaptive_points",
        _ => "ranges",
    };
    CoordError::invalid_worded(field, e)
}

/// A study's plan refused: core's check of its tolerance and its points (both checked as they
/// entered: only a stored record of another version fails it), named by the key of the check.
pub(super) fn plan_refused(e: SceneError) -> CoordError {
    let field = match &e {
        SceneError::Invalid { key, .. } if key.ends_with("points") => "points",
        _ => "tolerance",
    };
    CoordError::invalid_worded(field, e)
}
