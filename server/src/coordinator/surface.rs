//! Reading what the coordinator stores: response surfaces over a study or a scene, and stored
//! solutions' files and fields.

use glissade_core::point::DesignPoint;
use glissade_core::study::surrogate::{Prediction, QoiSurface};

use super::*;

/// The predictions of a surface's QoIs at `at`: a Gaussian process per QoI over the rows that
/// have it, a norm's from its components where the rows carry them (docs/surrogate.md).
fn predict(
    scene: &Scene,
    names: &[String],
    qoi: &[String],
    rows: &[SurfaceRow],
    at: &[DesignPoint],
) -> Result<Vec<PointPrediction>, CoordError> {
    let rows: Vec<&SurfaceRow> = rows.iter().filter(|r| names.iter().all(|n| r.parameters.get(n).is_some())).collect();
    let points: Vec<(Vec<f64>, &BTreeMap<String, f64>)> =
        rows.iter().map(|r| (names.iter().filter_map(|n| r.parameters.get(n)).collect(), &r.qoi)).collect();
    let tolerances: Vec<f64> = rows.iter().map(|r| r.tolerance).collect();
    let mut surfaces = Vec::with_capacity(qoi.len());
    for q in qoi {
        let surface = QoiSurface::of_scene(scene, names, &points, &tolerances, q)
            .map_err(|e| CoordError::Precondition(format!("the surface of {q} cannot predict: {e}")))?;
        surfaces.push(surface);
    }
    at.iter()
        .enumerate()
        .map(|(i, point)| {
            if let Some(name) = point.names().find(|k| !names.iter().any(|n| n == k)) {
                return Err(CoordError::invalid(
                    format!("predict_at[{i}]"),
                    format_args!("`{name}` is not a parameter of these points ({})", names.join(", ")),
                ));
            }
            let predicted = surfaces
                .iter()
                .zip(qoi)
                .map(|(s, q)| {
                    let band = |p: Prediction| p.band(scene.qoi_is_norm(q));
                    s.predict_within(point).map(|p| QoiPredicted { prediction: p, fitted: s.len(), band: band(p) })
                })
                .collect::<Result<Vec<_>, _>>()
                .map_err(|e| CoordError::invalid(format!("predict_at[{i}]"), e))?;
            Ok(PointPrediction { at: point.clone(), qoi: predicted })
        })
        .collect()
}

/// Every fixed parameter is one of the points' (`names`).
fn check_fixed(fixed: &DesignPoint, names: &[String]) -> Result<(), CoordError> {
    match fixed.names().find(|name| !names.iter().any(|n| n == name)) {
        Some(name) => Err(CoordError::invalid_worded(
            "fixed",
            format_args!(
                "fixed parameter `{name}` is not a parameter of these points (they have: {})",
                names.join(", ")
            ),
        )),
        None => Ok(()),
    }
}

impl Coordinator {
    pub fn surface(
        &self,
        source: SurfaceSource,
        fixed: &DesignPoint,
        qoi: &[String],
        predict_at: &[DesignPoint],
    ) -> Result<Surface, CoordError> {
        let state = self.lock();
        // the scene: its ranges scale the parameters of a prediction, it names the units
        let study_scene = match &source {
            SurfaceSource::Study(id) => state.studies.get(id).map(|e| Arc::clone(&e.scene)),
            SurfaceSource::Scene(_) => None,
        };
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
                            qoi: r.map(|r| r.qoi.clone().into()).unwrap_or_default(),
                            iterations: r.map_or(0, |r| r.iterations),
                            error_indicator: r.map_or(0.0, |r| r.error_indicator),
                            converged: r.is_some_and(|r| r.converged),
                            state: p.state.clone(),
                            tolerance: entry.record.tolerance,
                        }
                    })
                    .collect::<Vec<_>>();
                (entry.record.scene_hash.clone(), rows)
            }
            SurfaceSource::Scene(hash) => {
                let rows = state
                    .solutions
                    .of_scene(hash)
                    .map(|s| SurfaceRow {
                        parameters: s.parameters.clone(),
                        qoi: s.qoi.clone().into(),
                        iterations: s.iterations,
                        error_indicator: s.error_indicator,
                        converged: s.converged,
                        state: if s.converged { PointState::Done } else { PointState::Failed },
                        tolerance: s.tolerance,
                    })
                    .collect::<Vec<_>>();
                if rows.is_empty() && self.store.get(Tree::Scenes, hash.as_bytes())?.is_none() {
                    return Err(CoordError::invalid_worded(
                        "scene_hash",
                        format_args!("no scene with hash `{hash}` was ever submitted"),
                    ));
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
        if !rows.is_empty() {
            check_fixed(fixed, &names)?;
        }
        rows.retain(|r| {
            fixed
                .iter()
                .all(|(name, v)| r.parameters.get(name).is_some_and(|x| glissade_core::text::same_parameter(x, v)))
        });
        let mut qoi_names: Vec<String> = rows.iter().flat_map(|r| r.qoi.keys().cloned()).collect();
        qoi_names.sort();
        qoi_names.dedup();
        // a norm is predicted from its components, which the QoIs asked for may leave out
        let predicted_from = (!predict_at.is_empty()).then(|| rows.clone());
        if !qoi.is_empty() {
            for q in qoi {
                if !qoi_names.contains(q) && !rows.iter().all(|r| r.qoi.is_empty()) {
                    return Err(CoordError::invalid_worded(
                        "qoi",
                        format_args!("no QoI `{q}` in these results (they have: {})", qoi_names.join(", ")),
                    ));
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
        let scene = match study_scene {
            Some(scene) => Some(scene),
            None => self.stored_scene(&scene_hash)?,
        };
        let predictions = match predicted_from {
            Some(predicted_from) => {
                let scene = scene
                    .as_ref()
                    .ok_or_else(|| CoordError::Corrupt(format!("scene {scene_hash} is missing from the database")))?;
                predict(scene, &names, &qoi_names, &predicted_from, predict_at)?
            }
            None => Vec::new(),
        };
        let units = scene
            .map(|scene| {
                names.iter().chain(&qoi_names).filter_map(|n| Some((n.clone(), scene.unit(n)?.to_owned()))).collect()
            })
            .unwrap_or_default();
        Ok(Surface { scene_hash, parameters: names, qoi: qoi_names, rows, predictions, units })
    }

    /// The scene stored under `hash`, parsed, or None where the database has none.
    fn stored_scene(&self, hash: &str) -> Result<Option<Arc<Scene>>, CoordError> {
        let Some(bytes) = self.store.get(Tree::Scenes, hash.as_bytes())? else { return Ok(None) };
        let scene = Scene::parse(&String::from_utf8_lossy(&bytes))
            .map_err(|e| CoordError::Corrupt(format!("stored scene: {e}")))?;
        Ok(Some(Arc::new(scene)))
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
            .get(Tree::SolutionFields, &key.to_bytes())?
            .ok_or_else(|| CoordError::UnknownSolution(describe()))?;
        records::decode_fields(&compressed)
            .map_err(|e| CoordError::Corrupt(format!("stored solution {} does not decompress: {e}", describe())))
    }
}
