//! A study's discretisation audit: a few of its points re-solved cold on refined scenes (the
//! time step halved, and quartered with 3 levels; on request the box bodies' mesh refined once
//! too; core::refine writes the scenes), at the study's tolerance, when the pools have nothing
//! else to do. Per QoI the finals of the levels, the study's own first, give Richardson's
//! estimate of the error of the time step and of the mesh (core::refine::richardson, the rule
//! the worker's `refine` command uses), beside the iteration audit's measure of the tolerance's
//! (docs/verification.md 11).

use std::collections::{BTreeMap, BTreeSet};

use glissade_core::point::DesignPoint;
use glissade_core::refine::{NOISE_PER_TOLERANCE, Refinement, refined_scene_text, richardson};
use glissade_core::scene::Scene;
use glissade_core::text::one_line;
use glissade_proto::StudyId;

use super::{
    CoordError, Discretisation, MAX_REFINE_LEVELS, MAX_REFINE_POINTS, MeshError, MeshLevel, QoiDiscretisation,
    StudyEntry,
};
use super::{DEFAULT_REFINE_POINTS, Submission};
use crate::records::{PointResult, PointState, QoiMap, Refines, StudyRecord};

/// The time step's divisor between two levels.
const RATIO: u32 = 2;

/// One refined level of a submission's audit: what it refines and by how much, its scene text
/// and hash, and the scene (meshes attached).
pub(super) struct Level {
    pub refinement: Refinement,
    pub factor: u32,
    pub text: String,
    pub hash: String,
    pub scene: Scene,
}

/// The audit a submission asks for: its points (how many) and refined levels. An explicit
/// request that cannot be met (too many points or levels, a refined scene over the coordinator's
/// size bound or step limit) is refused; the default audit is dropped instead, silently for the
/// user (logged), so that a scene near the bound is not refused for what no one asked.
pub(super) fn plan(
    submission: &Submission,
    scene: &Scene,
    points: usize,
    max_scene_bytes: u64,
) -> Result<(usize, Vec<Level>), CoordError> {
    let levels = match submission.refine_levels {
        0 => 2,
        n if (2..=MAX_REFINE_LEVELS).contains(&n) => n,
        n => {
            return Err(CoordError::invalid_worded(
                "refine_levels",
                format!(
                    "refine_levels {n}: 2 (the time step halved) or {MAX_REFINE_LEVELS} (halved and quartered), the study's own level included"
                ),
            ));
        }
    };
    let asked = match submission.refine_points {
        None => DEFAULT_REFINE_POINTS,
        Some(n) if n > MAX_REFINE_POINTS => {
            return Err(CoordError::invalid_worded(
                "refine_points",
                format!(
                    "refine_points {n}: at most {MAX_REFINE_POINTS} (each costs {} of the study's points)",
                    (1..levels).map(|k| RATIO.pow(k)).sum::<u32>()
                ),
            ));
        }
        Some(n) => n,
    };
    let n = (asked as usize).min(points);
    if n == 0 {
        return Ok((0, Vec::new()));
    }
    let mut refined = Vec::new();
    for k in 1..levels {
        let factor = RATIO.pow(k);
        match level(scene, Refinement::Time, factor, max_scene_bytes) {
            Ok(l) => refined.push(l),
            Err(e) if submission.refine_points.is_none() && !submission.refine_mesh => {
                tracing::info!(error = %e, "no discretisation audit for this study");
                return Ok((0, Vec::new()));
            }
            Err(e) => return Err(CoordError::invalid("refine_points", e)),
        }
    }
    // the mesh, asked for explicitly (a level costs about 2^dim x a point, and more): refused
    // with the reason when it cannot be
    if submission.refine_mesh {
        refined.push(
            level(scene, Refinement::Mesh, RATIO, max_scene_bytes)
                .map_err(|e| CoordError::invalid("refine_mesh", e))?,
        );
    }
    Ok((n, refined))
}

/// The scene of one level, within the bounds every submitted scene obeys.
fn level(scene: &Scene, refinement: Refinement, factor: u32, max_scene_bytes: u64) -> Result<Level, String> {
    let dt = describe(refinement, factor);
    let text = refined_scene_text(scene, refinement, factor as usize).map_err(|e| format!("{dt}: {e}"))?;
    let mut refined = Scene::parse(&text).map_err(|e| format!("{dt}: {}", one_line(&e.to_string())))?;
    refined
        .attach_mesh_bytes(scene.meshes.iter().map(|(f, b)| (f.clone(), b.clone())))
        .map_err(|e| format!("{dt}: {e}"))?;
    let size = refined.size().map_err(|e| format!("{dt}: {}", one_line(&e.to_string())))?;
    if size.bytes() > max_scene_bytes {
        return Err(format!(
            "{dt} ({} steps) would need about {} MiB, more than the {} MiB accepted (glissade-server --max-scene-mib): ask for fewer levels, or none",
            size.steps,
            size.bytes() >> 20,
            max_scene_bytes >> 20
        ));
    }
    Ok(Level { refinement, factor, hash: refined.content_hash(), text, scene: refined })
}

/// A level in words: `the time step / 2`, `the mesh h / 2`.
fn describe(refinement: Refinement, factor: u32) -> String {
    match refinement {
        Refinement::Time => format!("the time step / {factor}"),
        Refinement::Mesh => format!("the mesh h / {factor}"),
    }
}

/// `n` of `points` spread over the list: the first and the last, and evenly between (the
/// iteration audit's choice too).
pub(super) fn spread(points: &[DesignPoint], n: usize) -> Vec<DesignPoint> {
    (0..n).map(|k| points[if n == 1 { 0 } else { k * (points.len() - 1) / (n - 1) }].clone()).collect()
}

/// The record of a level's study, refining `study`.
pub(super) fn record(study: &StudyRecord, id: StudyId, level: &Level) -> StudyRecord {
    StudyRecord {
        id,
        label: format!("discretisation audit of study {}: {}", study.id, describe(level.refinement, level.factor)),
        scene_hash: level.hash.clone(),
        scene: level.text.clone(),
        // more steps may take more iterations: the limit grows with them, within every solve's
        max_iterations: study
            .max_iterations
            .saturating_mul(level.factor)
            .min(glissade_core::scene::MAX_ITERATIONS as u32),
        strategy: glissade_core::study::strategy::InitStrategy::Cold,
        order: glissade_core::study::order::OrderKind::Asc,
        // an audit: leased when nothing else is pending
        audit_of: Some(study.id),
        audit: None,
        adaptive: None,
        refined_by: Vec::new(),
        refines: Some(Refines { study: study.id, refinement: level.refinement, factor: level.factor }),
        ..study.clone()
    }
}

/// What the levels measured of `study`: per QoI, over the points done at every time level and
/// in the study, the change from the study's value to the first refined level's, and
/// Richardson's estimate of the study's error (core::refine::richardson), relative to the
/// largest |final value| of the QoI over those points and levels; the same for the mesh level
/// with its own points, where there is one.
pub(super) fn measure(study: &StudyEntry, levels: &[&StudyEntry]) -> Discretisation {
    let refinement = |e: &StudyEntry| e.record.refines.map(|r| (r.refinement, r.factor));
    // time levels finest last, as they were written
    let all_time: Vec<&StudyEntry> =
        levels.iter().copied().filter(|l| refinement(l).is_none_or(|(r, _)| r == Refinement::Time)).collect();
    // the ladders of the levels that solved something: a level cut by the levels' cost cap
    // before its first point does not empty those of the levels before it
    let solved = |l: &&StudyEntry| l.points.iter().any(|p| p.state == PointState::Done);
    let time: Vec<&StudyEntry> = all_time.iter().copied().take_while(solved).collect();
    let mesh = levels.iter().copied().find(|l| refinement(l).is_some_and(|(r, _)| r == Refinement::Mesh));
    let noise = NOISE_PER_TOLERANCE * study.record.tolerance;
    let (time_ladders, planned) = ladders(study, &time);
    let mesh_ladders = mesh.map(|m| ladders(study, &[m]).0);
    let names: BTreeSet<&str> =
        time_ladders.iter().chain(mesh_ladders.iter().flatten()).flat_map(|l| l[0].keys()).collect();
    let mut qoi = BTreeMap::new();
    for name in names {
        let t = estimate(&time_ladders, name, noise);
        let mut orders = t.orders;
        // the mean over the points that observed one (not erratic, not within the noise)
        orders.retain(|o| o.is_finite());
        qoi.insert(
            name.to_owned(),
            QoiDiscretisation {
                change: t.change,
                error: t.error,
                order: (!orders.is_empty()).then(|| orders.iter().sum::<f64>() / orders.len() as f64),
                order_assumed: time.len() < 2,
                erratic: t.erratic,
                below_tolerance: t.below_tolerance,
                mesh: mesh_ladders.as_ref().map(|l| {
                    let m = estimate(l, name, noise);
                    MeshError { change: m.change, error: m.error, below_tolerance: m.below_tolerance }
                }),
            },
        );
    }
    Discretisation {
        // every level, solved or not (the API lists them to follow)
        levels: all_time.iter().map(|l| (l.record.id, refinement(l).map_or(0, |(_, f)| f))).collect(),
        audited: time_ladders.len() as u32,
        planned: planned as u32,
        work_seconds: time.iter().map(|l| seconds(l)).sum(),
        study_seconds: seconds(study),
        qoi,
        mesh: mesh.map(|m| MeshLevel {
            study: m.record.id,
            factor: refinement(m).map_or(0, |(_, f)| f),
            audited: mesh_ladders.as_ref().map_or(0, |l| l.len() as u32),
            work_seconds: seconds(m),
        }),
    }
}

/// What a study's discretisation levels may cost together: this many times its own points' wall
/// time, or [`LEVELS_WALL_FLOOR`] seconds (5 minutes), whichever is more (issue 47: levels had no cap and
/// cost 1.65 x and 2.56 x a 3 x 3 grid's solves; the floor keeps small studies measured).
pub const LEVELS_WALL_FRACTION: f64 = 2.0;
pub const LEVELS_WALL_FLOOR: f64 = 300.0;

/// Why `level` (a refined level of `study`) leases no further point: with its next re-solve,
/// whose wall time is its done points' mean (else the study's, times what the level multiplies),
/// the levels of `study` would pass their cap. A level cut short measures nothing past the
/// points every level solved, so it stops before, not in the middle of a solve.
pub(super) fn level_over_cap<'a>(
    study: &StudyEntry,
    level: &StudyEntry,
    levels: impl Iterator<Item = &'a StudyEntry>,
) -> Option<String> {
    let solved = |e: &StudyEntry| e.points.iter().filter(|p| p.result.is_some()).count();
    let cap = (LEVELS_WALL_FRACTION * seconds(study)).max(LEVELS_WALL_FLOOR);
    let spent: f64 = levels.map(seconds).sum();
    let next = match solved(level) {
        0 => {
            let per_point = seconds(study) / solved(study).max(1) as f64;
            let times = level.record.refines.as_ref().map_or(1.0, |r| match r.refinement {
                Refinement::Time => r.factor as f64,
                Refinement::Mesh => (r.factor as f64).powi(study.scene.dimension as i32),
            });
            per_point * times
        }
        n => seconds(level) / n as f64,
    };
    (spent + next > cap).then(|| {
        format!(
            "not re-solved: the discretisation levels' cost cap ({cap:.0} s: {LEVELS_WALL_FRACTION} x the study's {:.0} s of solves, \
             at least {LEVELS_WALL_FLOOR:.0} s) would be passed ({spent:.0} s spent, about {next:.0} s more a point)",
            seconds(study)
        )
    })
}

/// Wall seconds of a study's solved points.
fn seconds(e: &StudyEntry) -> f64 {
    e.points.iter().filter_map(|p| p.result.as_ref()).map(|r| r.wall_seconds).sum()
}

/// One point's QoIs, level by level, the study's own first.
type Ladder<'a> = Vec<&'a QoiMap>;

/// The QoIs of each point of the first level that is done at every level, level by level, the
/// study's own first; and how many points the levels plan.
fn ladders<'a>(study: &'a StudyEntry, levels: &[&'a StudyEntry]) -> (Vec<Ladder<'a>>, usize) {
    fn result<'a>(e: &'a StudyEntry, at: &DesignPoint) -> Option<&'a PointResult> {
        let p = e.points.iter().find(|p| p.state == PointState::Done && &p.parameters == at)?;
        p.result.as_deref()
    }
    let Some(first) = levels.first() else { return (Vec::new(), 0) };
    let ladders = first
        .points
        .iter()
        .filter_map(|p| {
            std::iter::once(study)
                .chain(levels.iter().copied())
                .map(|e| result(e, &p.parameters).map(|r| &r.qoi))
                .collect::<Option<Vec<_>>>()
        })
        .collect();
    (ladders, first.points.len())
}

/// What ladders of levels of ratio 2 say of one QoI, relative to its largest |final| over them.
struct Measured {
    change: f64,
    error: f64,
    /// per point the observed order (NaN: none)
    orders: Vec<f64>,
    erratic: u32,
    below_tolerance: bool,
}

fn estimate(ladders: &[Ladder<'_>], name: &str, noise: f64) -> Measured {
    let finals: Vec<Vec<f64>> =
        ladders.iter().filter_map(|l| l.iter().map(|q| q.get(name).copied()).collect()).collect();
    let largest = |v: &[f64]| v.iter().fold(0.0f64, |s, x| s.max(x.abs()));
    let scale = finals.iter().map(|f| largest(f)).fold(0.0f64, f64::max);
    let scale = if scale > 0.0 { scale } else { 1.0 };
    let mut m = Measured { change: 0.0, error: 0.0, orders: Vec::new(), erratic: 0, below_tolerance: true };
    for f in &finals {
        // the iterations' noise is relative to the QoI's scale, not to this point's: a QoI
        // near zero here (a slip that sticks, 1e-21) is noise at every level, not erratic
        let e = richardson(f, RATIO as usize, noise * scale / largest(f).max(f64::MIN_POSITIVE));
        m.change = m.change.max((f[1] - f[0]).abs() / scale);
        // richardson's errors are relative to this point's largest final: to the QoI's
        m.error = m.error.max(e.error_first * largest(f) / scale);
        m.erratic += e.erratic as u32;
        m.below_tolerance &= e.below_tolerance;
        m.orders.push(e.order.unwrap_or(f64::NAN));
    }
    m
}
