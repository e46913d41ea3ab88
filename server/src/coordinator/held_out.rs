//! A study's surface audit: points held out of its response surface (random in its box, never
//! its design's), whose surface predictions are made from the study's points once it has ended,
//! and recorded, before the points are solved cold at the iteration audit's tighter tolerance; the
//! solves then measure the surface where users read it, between the points (docs/surrogate.md,
//! "Surface audit"). Leased as the iteration audit's points are: behind every user study, one at
//! a time, within its own cap of [`super::AUDIT_WORK_FRACTION`] of the study's work.

use std::collections::BTreeMap;

use glissade_core::point::DesignPoint;
use glissade_core::scene::Scene;
use glissade_core::study::holdout::{self, held_out_points};
use glissade_core::study::surrogate::{Prediction, QoiSurface};

use super::{StudyEntry, SurfaceAccuracy, audit_cost, now_unix_ms};
use crate::records::{AdaptiveSpec, PointState, Predicted, QoiMap};

/// `n` points held out of a study of swept `names` over `design` (or, adaptive, over its
/// ranges): uniform in the study's box (each parameter from its lowest to its highest value),
/// none at a design point, seeded by `seed` (the audit's record keeps it: the same seed, the same
/// points).
pub(super) fn points(
    names: &[String],
    design: &[DesignPoint],
    adaptive: Option<&AdaptiveSpec>,
    n: usize,
    seed: u64,
) -> Vec<DesignPoint> {
    let coordinates = |p: &DesignPoint| -> Vec<f64> { names.iter().map(|k| p.get(k).unwrap_or(0.0)).collect() };
    let design: Vec<Vec<f64>> = design.iter().map(coordinates).collect();
    let ranges: Vec<(f64, f64)> = match adaptive {
        Some(a) => names
            .iter()
            .map(|k| a.ranges.iter().find(|(n, ..)| n == k).map_or((0.0, 0.0), |(_, lo, hi)| (*lo, *hi)))
            .collect(),
        None => (0..names.len())
            .map(|d| design.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| (lo.min(x[d]), hi.max(x[d]))))
            .collect(),
    };
    if design.is_empty() && adaptive.is_none() {
        return Vec::new();
    }
    held_out_points(&ranges, &design, n, seed)
        .into_iter()
        // (coordinates inside the swept ranges, of the study's names: always a design point)
        .filter_map(|x| DesignPoint::from_pairs(names.iter().cloned().zip(x)).ok())
        .collect()
}

/// A surface's prediction of each QoI at a point: (mean, standard deviation).
type QoiPredictions = BTreeMap<String, (f64, f64)>;

/// What predicting a surface audit's points needs, copied out of the coordinator's state (the
/// fits run outside its lock: each is O(n^3) in the study's points).
pub(super) struct Job {
    pub audit: glissade_proto::StudyId,
    scene: std::sync::Arc<Scene>,
    names: Vec<String>,
    /// the study's done points: coordinates and QoIs
    rows: Vec<(Vec<f64>, BTreeMap<String, f64>)>,
    /// the tolerance they were solved to
    tolerance: f64,
    at: Vec<DesignPoint>,
}

pub(super) fn job(study: &StudyEntry, audit: &StudyEntry) -> Job {
    let names = study.record.parameters.clone();
    let rows = study
        .points
        .iter()
        .filter(|p| p.state == PointState::Done)
        .filter_map(|p| {
            let x: Option<Vec<f64>> = names.iter().map(|n| p.parameters.get(n)).collect();
            Some((x?, p.result.as_ref()?.qoi.clone().into()))
        })
        .collect();
    let at = audit.points.iter().map(|p| p.parameters.clone()).collect();
    let tolerance = study.record.tolerance;
    Job { audit: audit.record.id, scene: std::sync::Arc::clone(&study.scene), names, rows, tolerance, at }
}

/// The surface of each QoI of the study's points (as `glissade surface` fits it: norms never
/// below zero, from their components where the points carry them), predicted at the held-out
/// points.
pub(super) fn predict(job: &Job) -> Predicted {
    let mut refused = BTreeMap::new();
    let mut at = vec![BTreeMap::new(); job.at.len()];
    let scene: &Scene = &job.scene;
    let qois: std::collections::BTreeSet<&String> = job.rows.iter().flat_map(|(_, q)| q.keys()).collect();
    let points: Vec<(Vec<f64>, &BTreeMap<String, f64>)> = job.rows.iter().map(|(x, q)| (x.clone(), q)).collect();
    let tolerances = vec![job.tolerance; points.len()];
    for q in qois {
        let surface = match QoiSurface::of_scene(scene, &job.names, &points, &tolerances, q) {
            Ok(s) => s,
            Err(e) => {
                refused.insert(q.clone(), e.to_string());
                continue;
            }
        };
        for (point, values) in job.at.iter().zip(&mut at) {
            match surface.predict(point) {
                Ok(p) => {
                    values.insert(q.clone(), (p.mean, p.std));
                }
                Err(e) => {
                    refused.insert(q.clone(), e.to_string());
                }
            }
        }
    }
    if job.rows.is_empty() {
        refused.insert(String::new(), "the study has no point done".into());
    } else if job.rows.iter().all(|(_, q)| q.is_empty()) {
        refused.insert(String::new(), "the study's points have no QoI".into());
    }
    Predicted { fitted: job.rows.len() as u32, at, refused, unix_ms: now_unix_ms() }
}

/// Whether `predicted` holds anything to compare a solve with.
pub(super) fn predicts_anything(predicted: &Predicted) -> bool {
    predicted.at.iter().any(|q| !q.is_empty())
}

/// What the audit measured so far: per QoI, over its points solved that have a prediction, the
/// errors relative to the QoI's spread over the study's values and the held-out ones.
pub(super) fn measure(study: &StudyEntry, audit: &StudyEntry) -> SurfaceAccuracy {
    let budget = audit_cost(study, audit);
    let predicted = audit.record.held_out.as_ref().and_then(|h| h.predicted.as_ref());
    // (prediction per QoI, solved QoIs) at each held-out point solved
    let pairs: Vec<(&QoiPredictions, &QoiMap)> = match predicted {
        None => Vec::new(),
        Some(predicted) => audit
            .points
            .iter()
            .filter(|p| p.state == PointState::Done)
            .filter_map(|p| Some((predicted.at.get(p.id.0 as usize)?, &p.result.as_ref()?.qoi)))
            .collect(),
    };
    let mut qoi = BTreeMap::new();
    let names: std::collections::BTreeSet<&String> = pairs.iter().flat_map(|(p, _)| p.keys()).collect();
    for name in names {
        let both: Vec<(Prediction, f64)> = pairs
            .iter()
            .filter_map(|(p, v)| {
                let (mean, std) = *p.get(name)?;
                Some((Prediction { mean, std }, *v.get(name)?))
            })
            .collect();
        let study_values = study.points.iter().filter(|p| p.state == PointState::Done);
        let spread = holdout::spread(
            study_values.filter_map(|p| p.result.as_ref()?.qoi.get(name).copied()).chain(both.iter().map(|(_, v)| *v)),
        );
        qoi.insert(name.clone(), holdout::surface_errors(&both, spread));
    }
    SurfaceAccuracy {
        audit_study: audit.record.id,
        tolerance: audit.record.tolerance,
        validated: pairs.len() as u32,
        planned: audit.points.len() as u32,
        fitted: predicted.map_or(0, |p| p.fitted),
        seed: audit.record.held_out.as_ref().map_or(study.record.id.0, |h| h.seed_of(study.record.id)),
        qoi,
        refused: predicted.map(|p| p.refused.clone()).unwrap_or_default(),
        work: budget.map_or(0.0, |b| b.spent),
        work_cap: budget.map_or(0.0, |b| b.cap),
    }
}
