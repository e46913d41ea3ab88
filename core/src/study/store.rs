//! Stored interface solutions of a study and nearest-neighbour queries in parameter space
//! (docs/method.md 4: only interface fields are stored, never substructure interiors).
//!
//! [`SolutionStore`] is the seam: [`MemoryStore`] here (one process), the coordinator's sled
//! database in the service; both find neighbours with the same [`PointIndex`] (a kd-tree from
//! `kiddo`).

use crate::point::DesignPoint;
use std::collections::BTreeMap;
use std::num::NonZeroUsize;
use std::sync::Arc;

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use serde::{Deserialize, Serialize};

use crate::contact::ContactActivity;
use crate::field::InterfaceSolution;

use super::space::ParameterSpace;

/// Identifies a stored solution within its store.
pub type SolutionId = u64;

/// The most parameters a [`MemoryStore`] indexes: the kd-tree's dimension is a compile-time
/// constant, so coordinates are padded with zeros up to it.
pub const MAX_DIMENSION: usize = 8;

/// One stored interface solution and what it was computed for.
#[derive(Debug, Clone)]
pub struct StoredSolution {
    /// the design point (every parameter of the scene)
    pub point: DesignPoint,
    /// final error indicator of the dynamic stage
    pub eta: f64,
    /// the tolerance it was asked to reach
    pub tolerance: f64,
    pub converged: bool,
    /// LATIN iterations of the solve that produced it (static + dynamic)
    pub iterations: usize,
    /// final value of every QoI
    pub qoi: BTreeMap<String, f64>,
    /// the interface fields; shared, since a stored solution is read many times and never changed
    pub solution: Arc<InterfaceSolution>,
    /// the stored solution its solve started from (the first of a blend), or none (cold)
    pub parent: Option<SolutionId>,
    /// the version of the solver that computed it
    pub solver_version: String,
    /// what each frictional interface's contact did while it slid, so that a point this
    /// solution answers carries the evidence of the solve that made it
    pub contact: Vec<ContactActivity>,
}

impl StoredSolution {
    /// A description and its fields.
    pub fn from_info(info: SolutionInfo, solution: Arc<InterfaceSolution>) -> Self {
        StoredSolution {
            point: info.point,
            eta: info.eta,
            tolerance: info.tolerance,
            converged: info.converged,
            iterations: info.iterations,
            qoi: info.qoi,
            solution,
            parent: info.parent,
            solver_version: info.solver_version,
            contact: info.contact,
        }
    }

    /// Its description, without the fields.
    pub fn info(&self, id: SolutionId) -> SolutionInfo {
        SolutionInfo {
            id,
            point: self.point.clone(),
            eta: self.eta,
            tolerance: self.tolerance,
            converged: self.converged,
            iterations: self.iterations,
            parent: self.parent,
            qoi: self.qoi.clone(),
            solver_version: self.solver_version.clone(),
            contact: self.contact.clone(),
        }
    }
}

/// A stored solution's description without its fields (what listings and reports carry).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SolutionInfo {
    pub id: SolutionId,
    pub point: DesignPoint,
    pub eta: f64,
    pub tolerance: f64,
    pub converged: bool,
    pub iterations: usize,
    pub parent: Option<SolutionId>,
    #[serde(default)]
    pub qoi: BTreeMap<String, f64>,
    #[serde(default)]
    pub solver_version: String,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub contact: Vec<ContactActivity>,
}

/// Errors of a solution store.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("the scene has {count} parameters; the solution store indexes at most {max}")]
    TooManyParameters { count: usize, max: usize },
    #[error("point {point}: parameter '{name}' is not in the store's parameter space")]
    UnknownParameter { point: String, name: String },
    #[error("point {point}: parameter '{name}' = {value} is not a finite number")]
    NotFinite { point: String, name: String, value: f64 },
    #[error("no stored solution with id {0}")]
    UnknownId(SolutionId),
    #[error("nearest-neighbour index: {0}")]
    Index(String),
    /// for stores backed by a database
    #[error("solution store backend: {0}")]
    Backend(String),
}

/// Where converged interface solutions are kept, queried by distance in parameter space
/// ([`ParameterSpace::normalised_distance`]).
pub trait SolutionStore {
    /// Stores a solution; returns its id.
    fn insert(&mut self, solution: StoredSolution) -> Result<SolutionId, StoreError>;
    /// Up to `k` stored solutions nearest `point`, as (normalised distance, id), nearest first
    /// (ties in id order).
    fn nearest(&self, point: &DesignPoint, k: usize) -> Result<Vec<(f64, SolutionId)>, StoreError>;
    /// A stored solution (its fields are shared, not copied).
    fn get(&self, id: SolutionId) -> Result<StoredSolution, StoreError>;
    /// A stored solution's description, without reading its fields.
    fn info(&self, id: SolutionId) -> Result<SolutionInfo, StoreError>;
    /// Number of stored solutions.
    fn len(&self) -> usize;
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Stored solutions' descriptions indexed by a kd-tree over their normalised coordinates: the
/// nearest-neighbour half of a store, without the fields (the coordinator keeps those in its
/// database, [`MemoryStore`] beside the index).
///
/// The tree is kiddo's immutable one, rebuilt by the first query after inserts (O(n log n),
/// negligible next to a solve; n inserts in a row, as a coordinator loading its database does,
/// build it once): its soft buckets accept any number of points sharing a coordinate, which the
/// grids of a study and the zero padding produce (kiddo's mutable tree refuses to split such
/// buckets).
pub struct PointIndex {
    space: ParameterSpace,
    infos: Vec<SolutionInfo>,
    coordinates: Vec<[f64; MAX_DIMENSION]>,
    /// None until a query needs it after an insert.
    tree: std::sync::Mutex<Option<ImmutableKdTree<f64, MAX_DIMENSION>>>,
}

impl PointIndex {
    /// An empty index over `space`; refuses a space of more than [`MAX_DIMENSION`] parameters.
    pub fn new(space: ParameterSpace) -> Result<Self, StoreError> {
        if space.dimension() > MAX_DIMENSION {
            return Err(StoreError::TooManyParameters { count: space.dimension(), max: MAX_DIMENSION });
        }
        Ok(Self { space, infos: Vec::new(), coordinates: Vec::new(), tree: Default::default() })
    }

    pub fn space(&self) -> &ParameterSpace {
        &self.space
    }

    /// Indexes a solution's description; its id (the next one) replaces `info.id`.
    pub fn insert(&mut self, mut info: SolutionInfo) -> Result<SolutionId, StoreError> {
        let c = self.coordinates_of(&info.point)?;
        info.id = self.infos.len() as SolutionId;
        self.coordinates.push(c);
        self.infos.push(info);
        *self.tree.get_mut().unwrap_or_else(std::sync::PoisonError::into_inner) = None;
        Ok((self.infos.len() - 1) as SolutionId)
    }

    /// Replaces the description of an indexed solution at the same point.
    pub fn update(&mut self, id: SolutionId, mut info: SolutionInfo) -> Result<(), StoreError> {
        let slot = self.infos.get_mut(id as usize).ok_or(StoreError::UnknownId(id))?;
        info.id = id;
        *slot = info;
        Ok(())
    }

    /// Up to `k` indexed solutions nearest `point`, as (normalised distance, id), nearest first
    /// (ties in id order).
    pub fn nearest(&self, point: &DesignPoint, k: usize) -> Result<Vec<(f64, SolutionId)>, StoreError> {
        let query = self.coordinates_of(point)?;
        let Some(k) = NonZeroUsize::new(k.min(self.infos.len())) else { return Ok(Vec::new()) };
        let mut tree = self.tree.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if tree.is_none() {
            let built =
                ImmutableKdTree::new_from_slice(&self.coordinates).map_err(|e| StoreError::Index(e.to_string()))?;
            *tree = Some(built);
        }
        let tree = tree.as_ref().expect("built above");
        let mut found: Vec<(f64, SolutionId)> = tree
            .query(&query)
            .nearest_n::<SquaredEuclidean<f64>>(k)
            .execute()
            .into_iter()
            .map(|r| (r.distance.max(0.0).sqrt(), r.item as SolutionId))
            .collect();
        found.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        Ok(found)
    }

    pub fn info(&self, id: SolutionId) -> Result<SolutionInfo, StoreError> {
        self.infos.get(id as usize).cloned().ok_or(StoreError::UnknownId(id))
    }

    /// Every indexed solution's description, in id order.
    pub fn infos(&self) -> &[SolutionInfo] {
        &self.infos
    }

    pub fn len(&self) -> usize {
        self.infos.len()
    }

    pub fn is_empty(&self) -> bool {
        self.infos.is_empty()
    }

    fn coordinates_of(&self, point: &DesignPoint) -> Result<[f64; MAX_DIMENSION], StoreError> {
        for (name, value) in point.iter() {
            if self.space.range(name).is_none() {
                return Err(StoreError::UnknownParameter { point: point.to_string(), name: name.into() });
            }
            if !value.is_finite() {
                return Err(StoreError::NotFinite { point: point.to_string(), name: name.into(), value });
            }
        }
        let mut c = [0.0; MAX_DIMENSION];
        for (ci, v) in c.iter_mut().zip(self.space.normalised_coordinates(point)) {
            *ci = v;
        }
        Ok(c)
    }
}

/// Solutions in memory: a [`PointIndex`] and the fields beside it (one process: the
/// `glissade-worker study` command).
pub struct MemoryStore {
    index: PointIndex,
    fields: Vec<Arc<InterfaceSolution>>,
}

impl MemoryStore {
    /// An empty store over `space`; refuses a space of more than [`MAX_DIMENSION`] parameters.
    pub fn new(space: ParameterSpace) -> Result<Self, StoreError> {
        Ok(Self { index: PointIndex::new(space)?, fields: Vec::new() })
    }

    pub fn space(&self) -> &ParameterSpace {
        self.index.space()
    }

    /// Every stored solution's description, in id order.
    pub fn infos(&self) -> Vec<SolutionInfo> {
        self.index.infos().to_vec()
    }
}

impl SolutionStore for MemoryStore {
    fn insert(&mut self, solution: StoredSolution) -> Result<SolutionId, StoreError> {
        let id = self.index.insert(solution.info(0))?;
        self.fields.push(solution.solution);
        Ok(id)
    }

    fn nearest(&self, point: &DesignPoint, k: usize) -> Result<Vec<(f64, SolutionId)>, StoreError> {
        self.index.nearest(point, k)
    }

    fn get(&self, id: SolutionId) -> Result<StoredSolution, StoreError> {
        let info = self.index.info(id)?;
        Ok(StoredSolution::from_info(info, self.fields[id as usize].clone()))
    }

    fn info(&self, id: SolutionId) -> Result<SolutionInfo, StoreError> {
        self.index.info(id)
    }

    fn len(&self) -> usize {
        self.index.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::field::StageSolution;
    use crate::study::space::ParameterRange;

    fn space(n: usize) -> ParameterSpace {
        ParameterSpace::new(
            (0..n)
                .map(|i| ParameterRange {
                    name: format!("p{i}"),
                    default: 0.0,
                    min: 0.0,
                    max: 1.0 + i as f64,
                    declared: true,
                })
                .collect(),
        )
    }

    fn stored(point: DesignPoint) -> StoredSolution {
        StoredSolution {
            point,
            eta: 1e-4,
            tolerance: 2e-4,
            converged: true,
            iterations: 1,
            qoi: BTreeMap::new(),
            solution: Arc::new(InterfaceSolution { static_stage: None, dynamic: StageSolution { interfaces: vec![] } }),
            parent: None,
            solver_version: "test".into(),
            contact: Vec::new(),
        }
    }

    /// The kd-tree's answers equal a brute-force scan, also for many points sharing coordinates
    /// (a 2-parameter grid of 400 points, padded to 8 dimensions).
    #[test]
    fn nearest_matches_brute_force_on_a_grid() {
        let sp = space(3);
        let mut store = MemoryStore::new(sp.clone()).unwrap();
        let mut points = Vec::new();
        for i in 0..20 {
            for j in 0..20 {
                let p = DesignPoint::from_pairs([("p0", i as f64 / 19.0), ("p1", 2.0 * j as f64 / 19.0)]).unwrap();
                points.push(p.clone());
                store.insert(stored(p)).unwrap();
            }
        }
        assert_eq!(store.len(), 400);
        for q in [
            DesignPoint::from_pairs([("p0", 0.33), ("p1", 1.01)]).unwrap(),
            DesignPoint::from_pairs([("p0", 1.5), ("p1", -1.0), ("p2", 2.0)]).unwrap(),
            points[37].clone(),
        ] {
            let got = store.nearest(&q, 5).unwrap();
            let mut brute: Vec<(f64, SolutionId)> =
                points.iter().enumerate().map(|(i, p)| (sp.normalised_distance(&q, p), i as SolutionId)).collect();
            brute.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            assert_eq!(got.len(), 5);
            for (g, b) in got.iter().zip(&brute) {
                assert!((g.0 - b.0).abs() < 1e-12, "{q}: {got:?} vs {:?}", &brute[..5]);
            }
        }
        assert_eq!(store.nearest(&points[37], 1).unwrap(), vec![(0.0, 37)]);
        assert_eq!(store.get(37).unwrap().point, points[37]);
        assert!(matches!(store.get(400), Err(StoreError::UnknownId(400))));
    }

    #[test]
    fn empty_store_and_bad_points() {
        let store = MemoryStore::new(space(2)).unwrap();
        assert!(store.nearest(&DesignPoint::new(), 3).unwrap().is_empty());
        assert!(store.nearest(&DesignPoint::from_pairs([("zz", 1.0)]).unwrap(), 1).is_err());
        assert!(DesignPoint::from_pairs([("p0", f64::NAN)]).is_err(), "a NaN never reaches the store");
        let err = MemoryStore::new(space(MAX_DIMENSION + 1)).err().unwrap().to_string();
        assert!(err.contains("at most 8"), "{err}");
    }
}
