//! A study to an accuracy (`SubmitStudyRequest.accuracy`, docs/accuracy.md): its pilot points
//! climb core::accuracy's ladders as `glissade-worker solve --accuracy` does, one level at a
//! time, each level a study of its own (`pilot_of`) whose points pools lease as any other; the
//! rule ([`next_step`]) reads the levels done and says which to open next. Once every pilot is
//! done the study takes the finest of its pilots' cheapest levels within it (its scene becomes
//! that level's) and its points are solved there, the pilots' own answered by their stored solutions; when a
//! pilot did not reach the accuracy no level is chosen and the study is cancelled with why.

use std::sync::Arc;

use glissade_core::accuracy::{
    AccuracyLevel, AccuracyLimits, DEFAULT_HELD_OUT, DEFAULT_PILOTS, LevelSolved, MAX_PILOTS, RATIO, Step,
    level_after_above, next_step, scene_text_at, spread_order, study_level,
};
use glissade_core::point::DesignPoint;
use glissade_core::refine::{Accuracy, Refinement};
use glissade_core::scene::Scene;
use glissade_core::study::space::ParameterSpace;
use glissade_core::text::one_line;
use glissade_proto::{PointId, StudyId};

use super::submit::plan_refused;
use super::transitions::{Transition, apply};
use super::{CoordError, Coordinator, State, StudyEntry, Submission, now_unix_ms};
use crate::records::{
    NEXT_STUDY_KEY, PointRecord, PointResult, PointState, StudyRecord, ToAccuracy, encode, point_key, study_key,
};
use crate::store::{Batch, Tree};
use crate::study::StudyPlan;

/// What a submission to an accuracy is, checked: its record's part (pilots chosen among
/// `points`), or None when it asks for none. Refused with the reason when the study asks for
/// what an accuracy sets (a tolerance), for an adaptive design, the refine options, or when its
/// scene reads a mesh file (its mesh cannot be refined: its error would be in no estimate).
pub(super) fn admit(
    submission: &Submission,
    scene: &Scene,
    points: &[DesignPoint],
) -> Result<Option<(ToAccuracy, Accuracy)>, CoordError> {
    let Some(asked) = submission.accuracy else {
        if submission.accuracy_pilots.is_some() {
            return Err(CoordError::invalid("accuracy_pilots", "pilots are for a study to an accuracy"));
        }
        return Ok(None);
    };
    let accuracy = Accuracy::new("accuracy", asked).map_err(|e| CoordError::invalid_worded("accuracy", e))?;
    let refused = |what: &str| {
        Err(CoordError::invalid("accuracy", format_args!("{what}: an accuracy chooses the tolerance, dt and h itself")))
    };
    if submission.tolerance.is_some() {
        return refused("not with a tolerance");
    }
    if submission.adaptive.is_some() || submission.surface_accuracy.is_some() {
        return refused("not with an adaptive study (give a grid or points)");
    }
    // (0 and 2 are every client's default levels)
    if submission.refine_points.is_some_and(|n| n > 0) || submission.refine_levels > 2 || submission.refine_mesh {
        return refused("not with a discretisation audit");
    }
    if submission.audit_points.is_some_and(|n| n > 0) || submission.surface_audit_points.is_some_and(|n| n > 0) {
        return Err(CoordError::invalid(
            "accuracy",
            "a study to an accuracy has no iteration or surface audit yet (they would run at the scene as given, not at the level its pilots choose)",
        ));
    }
    if !scene.mesh_digests.is_empty() {
        return Err(CoordError::invalid(
            "accuracy",
            "the scene reads a mesh file, which cannot be refined: its mesh error would be in no estimate (give box bodies, or solve at a tolerance)",
        ));
    }
    let n = match submission.accuracy_pilots {
        None => DEFAULT_PILOTS,
        Some(n) if (1..=MAX_PILOTS as u32).contains(&n) => n as usize,
        Some(n) => {
            return Err(CoordError::invalid_worded(
                "accuracy_pilots",
                format_args!("accuracy_pilots {n}: from 1 to {MAX_PILOTS}"),
            ));
        }
    };
    // the pilots span the box; the held-out points lie between them
    let order = spread_order(points, &ParameterSpace::from_scene(scene), n + DEFAULT_HELD_OUT);
    let pilots: Vec<u64> = order.iter().take(n).map(|&i| i as u64).collect();
    let held_out_points: Vec<u64> = order.iter().skip(n).map(|&i| i as u64).collect();
    let spec = ToAccuracy {
        accuracy: asked,
        limits: AccuracyLimits::for_scene(scene),
        asked: vec![Vec::new(); pilots.len()],
        reports: vec![None; pilots.len()],
        pilots,
        levels: Vec::new(),
        held_out_points,
        held_out: None,
        chosen: None,
        why_not: None,
        above: Vec::new(),
    };
    Ok(Some((spec, accuracy)))
}

/// A level's study before it is stored: its record, points and scene.
struct NewLevel {
    record: StudyRecord,
    points: Vec<PointRecord>,
    scene: Scene,
}

impl Coordinator {
    /// Moves every study to an accuracy whose level is not chosen yet as far as its pilots'
    /// levels done allow: the levels each pilot needs next opened (or its point added to an open
    /// one), the reports of the pilots done kept, the level chosen once all are.
    pub(super) fn advance_to_accuracy(&self, state: &mut State) -> Result<(), CoordError> {
        let ids: Vec<StudyId> = state
            .studies
            .values()
            .filter(|e| !e.record.cancelled && e.record.to_accuracy.as_ref().is_some_and(|t| !t.decided()))
            .map(|e| e.record.id)
            .collect();
        for id in ids {
            self.advance(state, id)?;
        }
        // a study whose held-out check ended ABOVE moves one level finer, where the limits allow
        let above: Vec<StudyId> = state
            .studies
            .values()
            .filter(|e| {
                // the cheap tests first: this runs at every lease
                let Some(t) = e.record.to_accuracy.as_ref().filter(|_| !e.record.cancelled) else { return false };
                if t.chosen.and_then(|level| level_after_above(level, true, t.limits)).is_none() {
                    return false;
                }
                let Some(check) = t.held_out.and_then(|c| state.studies.get(&c)) else { return false };
                if check.state() == super::StudyState::Active || e.state() == super::StudyState::Active {
                    return false;
                }
                let c = held_out_check(e, check);
                c.confirmed == Some(false) && c.failed == 0
            })
            .map(|e| e.record.id)
            .collect();
        for id in above {
            self.refine_after_above(state, id)?;
        }
        Ok(())
    }

    /// The study's held-out check said ABOVE: its points are solved again one level finer (the
    /// check's own level: its points are answered by the check's solves) and a new check opens
    /// one level finer still.
    fn refine_after_above(&self, state: &mut State, id: StudyId) -> Result<(), CoordError> {
        let mut spec = state.studies[&id].record.to_accuracy.clone().expect("listed by the caller");
        let (Some(chosen), Some(check)) = (spec.chosen, spec.held_out) else { return Ok(()) };
        // (the check refines both: take_level opens it at dt / 2k, h / 2m)
        let Some(next) = level_after_above(chosen, true, spec.limits) else { return Ok(()) };
        // the scene as submitted, as the pilots' first level (dt, h) holds it: levels are
        // written from it
        let base = spec.levels.iter().find(|l| (l.0, l.1) == (1, 1)).and_then(|l| state.studies.get(&l.2));
        let Some(base) = base.map(|l| l.scene.clone()) else { return Ok(()) };
        tracing::warn!(study = %id, time_factor = chosen.0, mesh_factor = chosen.1, "held-out check ABOVE: the study moves one level finer");
        spec.above.push(crate::records::Above { time_factor: chosen.0, mesh_factor: chosen.1, check });
        let entry = state.studies.get_mut(&id).expect("listed by the caller");
        let reopened = entry
            .points
            .iter()
            .filter(|p| matches!(p.state, PointState::Done | PointState::Failed))
            .map(|p| Ok((apply(p, Transition::Reopen)?, None)))
            .collect::<Result<Vec<_>, CoordError>>()?;
        self.commit(entry, reopened, None, Batch::new())?;
        self.take_level(state, id, spec, &base, next)
    }

    fn advance(&self, state: &mut State, id: StudyId) -> Result<(), CoordError> {
        let entry = &state.studies[&id];
        let mut spec = entry.record.to_accuracy.clone().expect("listed by the caller");
        let given = entry.scene.clone();
        let accuracy =
            Accuracy::new("accuracy", spec.accuracy).map_err(|e| CoordError::invalid_worded("accuracy", e))?;
        let mut changed = false;
        // (pilot, level) pairs to solve next
        let mut wanted: Vec<(usize, usize, usize)> = Vec::new();
        for p in 0..spec.pilots.len() {
            if spec.reports[p].is_some() {
                continue;
            }
            let at = &entry.points[spec.pilots[p] as usize].parameters;
            let mut solved = Vec::new();
            let mut waiting = false;
            for &(refinement, k, m) in &spec.asked[p] {
                let point = level_point(state, &spec, k, m, at);
                match point.map(|q| (&q.state, &q.result, &q.error)) {
                    Some((PointState::Done | PointState::Failed, Some(r), _)) => {
                        solved.push(level_solved(&given, refinement, k, m, r))
                    }
                    Some((PointState::Failed, None, error)) => {
                        spec.why_not = Some(format!(
                            "the pilot at {at}: its solve at dt / {k}, h / {m} failed ({}), so no level is chosen",
                            error.as_deref().unwrap_or("no reason given")
                        ));
                        break;
                    }
                    _ => {
                        waiting = true;
                        break;
                    }
                }
            }
            if spec.why_not.is_some() {
                break;
            }
            if waiting {
                continue;
            }
            changed = true;
            match next_step(&given, accuracy, spec.limits, &solved) {
                Step::Solve { refinement, time_factor, mesh_factor } => {
                    spec.asked[p].push((refinement, time_factor, mesh_factor));
                    wanted.push((p, time_factor, mesh_factor));
                }
                Step::Done(report) => spec.reports[p] = Some(*report),
            }
        }
        if let Some(r) = spec.reports.iter().flatten().find(|r| !r.reached) {
            let p = spec.reports.iter().position(|x| x.as_ref() == Some(r)).expect("found above");
            let at = &entry.points[spec.pilots[p] as usize].parameters;
            spec.why_not = Some(format!(
                "the pilot at {at} did not reach the accuracy, so no level is chosen: {}",
                r.why_not.as_deref().unwrap_or("")
            ));
        }
        if spec.why_not.is_some() {
            return self.refuse_level(state, id, spec);
        }
        if !changed {
            return Ok(());
        }
        if spec.reports.iter().all(Option::is_some) {
            return self.choose_level(state, id, spec, &given);
        }
        self.open_levels(state, id, spec, &given, wanted)
    }

    /// Adds each pilot's next level: a point of that level's study, opened if need be; the
    /// study's record with its ladders, in the same batch.
    fn open_levels(
        &self,
        state: &mut State,
        id: StudyId,
        mut spec: ToAccuracy,
        given: &Scene,
        wanted: Vec<(usize, usize, usize)>,
    ) -> Result<(), CoordError> {
        let mut batch = Batch::new();
        let mut opened: Vec<NewLevel> = Vec::new();
        let mut added: Vec<(StudyId, PointRecord)> = Vec::new();
        let study = state.studies[&id].record.clone();
        let mut next_id = state.next_study;
        for (p, k, m) in wanted {
            let at = state.studies[&id].points[spec.pilots[p] as usize].parameters.clone();
            let open = spec.levels.iter().find(|l| (l.0, l.1) == (k, m)).map(|l| l.2);
            match open {
                // opened in this pass: not in the state yet
                Some(sid) if opened.iter().any(|l| l.record.id == sid) => {
                    let level = opened.iter_mut().find(|l| l.record.id == sid).expect("found above");
                    let point = PointRecord::pending(sid, PointId(level.points.len() as u64), at);
                    batch.put(Tree::Points, point_key(sid, point.id), encode(&point));
                    level.points.push(point);
                }
                Some(sid) => {
                    let level = &state.studies[&sid];
                    let n = level.points.len() + added.iter().filter(|(s, ..)| *s == sid).count();
                    // (a point the plan cannot complete is refused before anything is stored)
                    level.plan.space().complete(&at).map_err(|e| CoordError::invalid_worded("points", e))?;
                    let point = PointRecord::pending(sid, PointId(n as u64), at);
                    batch.put(Tree::Points, point_key(sid, point.id), encode(&point));
                    added.push((sid, point));
                }
                None => {
                    let sid = StudyId(next_id);
                    next_id += 1;
                    let level = new_level(&study, sid, given, (k, m), vec![at], Role::Pilots)?;
                    self.put_level(&mut batch, &level)?;
                    spec.levels.push((k, m, sid));
                    tracing::info!(study = %id, level = %sid, time_factor = k, mesh_factor = m, "a level of the pilots opened");
                    opened.push(level);
                }
            }
        }
        batch.put(Tree::Meta, NEXT_STUDY_KEY, next_id.to_be_bytes());
        let mut record = study;
        record.to_accuracy = Some(spec);
        batch.put(Tree::Studies, study_key(id), encode(&record));
        self.store.commit(batch)?;
        state.next_study = next_id;
        let entry = state.studies.get_mut(&id).expect("advanced");
        entry.record = record;
        // its watchers hear of each step of its pilots (its own points wait)
        self.emit(super::EventKind::Snapshot, entry, None);
        for (sid, point) in added {
            let level = state.studies.get_mut(&sid).expect("an open level");
            level.points.push(point);
        }
        for level in opened {
            self.enter_level(state, level)?;
        }
        self.work.notify_waiters();
        Ok(())
    }

    /// A level's writes: its scene (if not stored yet), its record and its points.
    fn put_level(&self, batch: &mut Batch, level: &NewLevel) -> Result<(), CoordError> {
        let r = &level.record;
        if self.store.get(Tree::Scenes, r.scene_hash.as_bytes())?.is_none() {
            batch.put(Tree::Scenes, r.scene_hash.as_bytes(), r.scene.as_bytes());
        }
        batch.put(Tree::Studies, study_key(r.id), encode(r));
        for q in &level.points {
            batch.put(Tree::Points, point_key(r.id, q.id), encode(q));
        }
        Ok(())
    }

    /// A level's study in the state, with its plan and its scene's index.
    fn enter_level(&self, state: &mut State, level: NewLevel) -> Result<(), CoordError> {
        let NewLevel { record, points, scene } = level;
        let plan = StudyPlan::new(&scene, &record, &points).map_err(plan_refused)?;
        self.index_scene(state, &record.scene_hash, plan.space());
        let id = record.id;
        state.studies.insert(id, StudyEntry { record, points, plan, scene: Arc::new(scene) });
        self.answer_stored(state, id)
    }

    /// Every pilot is done and reached the accuracy: the study's scene becomes the finest of the
    /// pilots' cheapest levels within it, and its points are solved there (the pilots' own answered by their stored
    /// solutions where the level is theirs).
    fn choose_level(&self, state: &mut State, id: StudyId, spec: ToAccuracy, given: &Scene) -> Result<(), CoordError> {
        let level = study_level(spec.reports.iter().flatten().map(|r| r.study_candidate()));
        self.take_level(state, id, spec, given, level)
    }

    /// The study's scene becomes level (dt / k, h / m) of `given`, its pending points are solved
    /// there (answered where a stored solve of that level is), and its held-out check opens one
    /// level finer.
    fn take_level(
        &self,
        state: &mut State,
        id: StudyId,
        mut spec: ToAccuracy,
        given: &Scene,
        (k, m): (usize, usize),
    ) -> Result<(), CoordError> {
        let text = scene_text_at(given, k, m).map_err(|e| CoordError::invalid("accuracy", e))?;
        let scene = Scene::parse(&text).map_err(|e| {
            CoordError::invalid("accuracy", format_args!("the level's scene: {}", one_line(&e.to_string())))
        })?;
        spec.chosen = Some((k, m));
        let entry = &state.studies[&id];
        // the held-out check, one level finer, opened now (an audit: leased once the study ended)
        let mut batch = Batch::new();
        let check = if spec.held_out_points.is_empty() {
            None
        } else {
            let cid = StudyId(state.next_study);
            let at = spec.held_out_points.iter().map(|&i| entry.points[i as usize].parameters.clone()).collect();
            let finer = (k * RATIO, m * RATIO);
            match new_level(&entry.record, cid, given, finer, at, Role::HeldOut) {
                Ok(level) => {
                    spec.held_out = Some(cid);
                    self.put_level(&mut batch, &level)?;
                    batch.put(Tree::Meta, NEXT_STUDY_KEY, (cid.0 + 1).to_be_bytes());
                    Some(level)
                }
                // (a level past the refinement's bounds): the study is solved, unconfirmed
                Err(e) => {
                    tracing::warn!(study = %id, error = %e, "no held-out check");
                    None
                }
            }
        };
        let mut record = entry.record.clone();
        record.scene_hash = scene.content_hash();
        record.scene = text;
        record.to_accuracy = Some(spec);
        let plan = StudyPlan::new(&scene, &record, &entry.points).map_err(plan_refused)?;
        if self.store.get(Tree::Scenes, record.scene_hash.as_bytes())?.is_none() {
            batch.put(Tree::Scenes, record.scene_hash.as_bytes(), record.scene.as_bytes());
        }
        batch.put(Tree::Studies, study_key(id), encode(&record));
        self.store.commit(batch)?;
        if let Some(check) = check {
            state.next_study = check.record.id.0 + 1;
            self.enter_level(state, check)?;
        }
        tracing::info!(study = %id, time_factor = k, mesh_factor = m, "a study to an accuracy chose its level");
        self.index_scene(state, &record.scene_hash, plan.space());
        let entry = state.studies.get_mut(&id).expect("advanced");
        entry.record = record;
        entry.plan = plan;
        entry.scene = Arc::new(scene);
        self.emit(super::EventKind::Snapshot, entry, None);
        self.answer_stored(state, id)?;
        self.work.notify_waiters();
        Ok(())
    }

    /// No level: the study's pending points are cancelled with the reason, and the study with them.
    fn refuse_level(&self, state: &mut State, id: StudyId, spec: ToAccuracy) -> Result<(), CoordError> {
        let why = spec.why_not.clone().unwrap_or_default();
        tracing::warn!(study = %id, why = %why, "a study to an accuracy chose no level");
        let entry = state.studies.get_mut(&id).expect("advanced");
        let mut record = entry.record.clone();
        record.to_accuracy = Some(spec);
        record.cancelled = true;
        let changes = entry
            .points
            .iter()
            .filter(|p| p.state == PointState::Pending)
            .map(|p| {
                let mut cancelled = apply(p, Transition::Cancel)?;
                cancelled.error = Some(format!("not solved: {why}"));
                Ok((cancelled, None))
            })
            .collect::<Result<Vec<_>, CoordError>>()?;
        self.commit(entry, changes, Some(record), Batch::new())
    }
}

/// The point of the level (dt / k, h / m) at the pilot `at`, if that level has it.
fn level_point<'a>(
    state: &'a State,
    spec: &ToAccuracy,
    k: usize,
    m: usize,
    at: &DesignPoint,
) -> Option<&'a PointRecord> {
    let sid = spec.levels.iter().find(|l| (l.0, l.1) == (k, m))?.2;
    state.studies.get(&sid)?.points.iter().find(|p| &p.parameters == at)
}

/// A level's point as the rule reads it. Where the pool did not send the QoIs' largest
/// magnitudes (an older pool, a stored answer from before), the finals stand for them.
fn level_solved(given: &Scene, refinement: Refinement, k: usize, m: usize, r: &PointResult) -> LevelSolved {
    let largest = r.qoi.iter().map(|(n, v)| (n.to_owned(), r.qoi_largest.get(n).copied().unwrap_or(v.abs()))).collect();
    LevelSolved {
        level: AccuracyLevel {
            refinement,
            time_factor: k,
            mesh_factor: m,
            // (refining the time multiplies the steps; the mesh keeps them)
            steps: given.time.steps * k,
            dofs: 0,
            converged: r.converged,
            iterations: r.iterations as usize,
            work: r.work,
            wall_seconds: r.wall_seconds,
            finals: Default::default(),
        },
        finals: r.qoi.clone().into(),
        largest,
    }
}

/// What a level's study is for.
#[derive(Clone, Copy)]
enum Role {
    /// a level of the pilots' ladders: leased as soon as a pilot needs it
    Pilots,
    /// the held-out check one level finer than the study's: an audit, leased once it has ended
    HeldOut,
}

/// The study of level (dt / k, h / m) of `study`, for `role`, with its points at `at`.
fn new_level(
    study: &StudyRecord,
    id: StudyId,
    given: &Scene,
    (k, m): (usize, usize),
    at: Vec<DesignPoint>,
    role: Role,
) -> Result<NewLevel, CoordError> {
    let text = scene_text_at(given, k, m).map_err(|e| CoordError::invalid("accuracy", e))?;
    let scene = Scene::parse(&text).map_err(|e| {
        CoordError::invalid("accuracy", format_args!("the level's scene: {}", one_line(&e.to_string())))
    })?;
    let (label, pilot_of, confirms) = match role {
        Role::Pilots => (format!("pilots of study {}: dt / {k}, h / {m}", study.id), Some(study.id), None),
        Role::HeldOut => (format!("held-out check of study {}: dt / {k}, h / {m}", study.id), None, Some(study.id)),
    };
    let record = StudyRecord {
        id,
        label,
        scene_hash: scene.content_hash(),
        scene: text,
        // more steps may take more iterations: the limit grows with them, within every solve's
        max_iterations: study.max_iterations.saturating_mul(k as u32).min(glissade_core::scene::MAX_ITERATIONS as u32),
        strategy: glissade_core::study::strategy::InitStrategy::Cold,
        order: glissade_core::study::order::OrderKind::Asc,
        created_unix_ms: now_unix_ms(),
        cancelled: false,
        audit_of: confirms,
        audit: None,
        adaptive: None,
        listed: true,
        refined_by: Vec::new(),
        refines: None,
        surface_audit: None,
        held_out: None,
        to_accuracy: None,
        pilot_of,
        confirms,
        ..study.clone()
    };
    let points = at.into_iter().enumerate().map(|(i, p)| PointRecord::pending(id, PointId(i as u64), p)).collect();
    Ok(NewLevel { record, points, scene })
}

/// What the held-out check `check` of `study` says (types::HeldOutCheck).
pub(super) fn held_out_check(study: &StudyEntry, check: &StudyEntry) -> super::HeldOutCheck {
    let accuracy = study.record.to_accuracy.as_ref().map_or(0.0, |t| t.accuracy);
    let (k, m) = study.record.to_accuracy.as_ref().and_then(|t| t.chosen).unwrap_or((1, 1));
    let mut difference: std::collections::BTreeMap<String, f64> = Default::default();
    let (mut done, mut failed) = (0, 0);
    for p in &check.points {
        match (&p.state, &p.result) {
            (PointState::Done, Some(finer)) => {
                let own = study.points.iter().find(|q| q.parameters == p.parameters && q.state == PointState::Done);
                // (the check runs once the study ended: a point of its not done never will be)
                let Some(own) = own.and_then(|q| q.result.as_ref()) else {
                    failed += 1;
                    continue;
                };
                done += 1;
                let solved = level_solved(&study.scene, Refinement::Time, 1, 1, finer);
                let scales = glissade_core::accuracy::scales(&study.scene, &solved);
                for (name, &f) in &finer.qoi {
                    let Some(&s) = own.qoi.get(name) else { continue };
                    let d = if scales[name] > 0.0 { (s - f).abs() / scales[name] } else { 0.0 };
                    let kept = difference.entry(name.to_owned()).or_insert(0.0);
                    *kept = kept.max(d);
                }
            }
            (PointState::Failed | PointState::Cancelled, _) => failed += 1,
            _ => {}
        }
    }
    let planned = check.points.len() as u32;
    let ended = done + failed == planned;
    super::HeldOutCheck {
        study: check.record.id,
        time_factor: k * RATIO,
        mesh_factor: m * RATIO,
        planned,
        done,
        failed,
        confirmed: ended.then(|| {
            failed == 0 && difference.values().all(|&d| glissade_core::accuracy::held_out_confirms(d, accuracy))
        }),
        difference,
    }
}
