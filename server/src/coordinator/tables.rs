//! The coordinator's tables other than its studies: the leases held now, the pools that
//! registered, the stored solutions with their warm-start indexes. Each is one map of one record
//! type, changed only through its methods, so the rows that belong together (a lease's point,
//! since when it is held and what its pool last reported; a solution's record and its place in
//! its scene's index) cannot part. They live in [`super::State`] under the coordinator's one
//! mutex: a lease, a completion or an expiry changes a study's points and a lease in one step.

use std::collections::{BTreeSet, HashMap};
use std::sync::Arc;
use std::time::{Duration, Instant};

use glissade_core::field::InterfaceSolution;
use glissade_core::study::space::ParameterSpace;
use glissade_core::study::store::StoreError;
use glissade_proto::{PointId, StudyId};

use super::{CoordError, PoolInfo};
use crate::records::{SolutionKey, SolutionRecord};
use crate::store::Store;
use crate::study::SceneSolutions;

/// A lease held now: the point it holds, since when (the per-point budget runs from it), and the
/// last progress its pool reported (what is known of a point whose pool then vanished).
pub(super) struct Lease {
    pub study: StudyId,
    pub point: PointId,
    pub since: Instant,
    pub progress: Option<(u64, f64)>,
}

/// Lease id -> [`Lease`]. A point's record says which lease holds it; this says what the lease
/// is doing.
#[derive(Default)]
pub(super) struct Leases(HashMap<u64, Lease>);

impl Leases {
    /// A lease id nobody can guess (64 random bits from the OS-seeded generator), unused and not
    /// 0 (the wire's "no lease"): a lease id is what lets a pool complete, fail or release a point.
    pub fn new_id(&self) -> u64 {
        loop {
            let id: u64 = rand::random();
            if id != 0 && !self.0.contains_key(&id) {
                return id;
            }
        }
    }

    /// Lease `id` holds `point` of `study` from now.
    pub fn grant(&mut self, id: u64, study: StudyId, point: PointId) {
        self.0.insert(id, Lease { study, point, since: Instant::now(), progress: None });
    }

    /// The lease ends (completed, failed, released or expired).
    pub fn end(&mut self, id: u64) {
        self.0.remove(&id);
    }

    pub fn get(&self, id: u64) -> Option<&Lease> {
        self.0.get(&id)
    }

    /// Records a progress report; false when it says what the last one said (the same iteration).
    pub fn report(&mut self, id: u64, iterations: u64, eta: f64) -> bool {
        let Some(lease) = self.0.get_mut(&id) else { return false };
        let before = lease.progress.replace((iterations, eta));
        before.is_none_or(|(i, _)| i != iterations)
    }

    /// The last progress lease `id` reported.
    pub fn progress(&self, id: u64) -> Option<(u64, f64)> {
        self.0.get(&id)?.progress
    }

    /// How long lease `id` has been held (zero for a lease not held).
    pub fn held_for(&self, id: u64) -> Duration {
        self.0.get(&id).map(|l| l.since.elapsed()).unwrap_or_default()
    }

    /// Whether a lease holds a point of `study` (the leases are a few per pool, a study's points
    /// up to millions).
    pub fn any_of(&self, study: StudyId) -> bool {
        self.0.values().any(|l| l.study == study)
    }

    pub fn len(&self) -> usize {
        self.0.len()
    }
}

/// A registered pool and when it last called (registration, lease call, heartbeat).
struct Pool {
    info: PoolInfo,
    seen: Instant,
}

/// Pool id -> [`Pool`]: only registered pools, so the ids kept stay as many as the pools.
#[derive(Default)]
pub(super) struct Pools(HashMap<String, Pool>);

impl Pools {
    pub fn register(&mut self, id: String, info: PoolInfo) {
        self.0.insert(id, Pool { info, seen: Instant::now() });
    }

    /// Pool `id` called now; false when it never registered.
    pub fn seen(&mut self, id: &str) -> bool {
        self.0.get_mut(id).map(|p| p.seen = Instant::now()).is_some()
    }

    /// The solver version pool `id` registered with.
    pub fn solver_version(&self, id: &str) -> Result<&str, CoordError> {
        Ok(&self.0.get(id).ok_or_else(|| CoordError::UnknownPool(id.to_owned()))?.info.solver_version)
    }

    /// How many pools called within `within` (connected, for /metrics).
    pub fn connected(&self, within: Duration) -> usize {
        self.0.values().filter(|p| p.seen.elapsed() <= within).count()
    }
}

/// Every stored solution's record, keyed as in the database, and each scene's nearest-neighbour
/// index over its converged ones (the records shared, one copy of each; the fields stay on disk).
#[derive(Default)]
pub(super) struct Solutions {
    records: HashMap<SolutionKey, Arc<SolutionRecord>>,
    by_scene: HashMap<String, SceneSolutions>,
}

impl Solutions {
    pub fn get(&self, key: &SolutionKey) -> Option<&Arc<SolutionRecord>> {
        self.records.get(key)
    }

    /// The stored record that a key found in a scene's index has.
    pub fn indexed(&self, key: &SolutionKey) -> Arc<SolutionRecord> {
        self.records.get(key).expect("indexed solutions have records").clone()
    }

    /// The warm-start index of scene `hash`, if it has one.
    pub fn scene(&self, hash: &str) -> Option<&SceneSolutions> {
        self.by_scene.get(hash)
    }

    /// Every stored solution of scene `hash`, converged or not.
    pub fn of_scene<'a>(&'a self, hash: &'a str) -> impl Iterator<Item = &'a Arc<SolutionRecord>> + 'a {
        self.records.values().filter(move |r| *r.scene_hash == *hash)
    }

    pub fn len(&self) -> usize {
        self.records.len()
    }

    /// Gives scene `hash` an index over `space` if it has none (none for a scene of too many
    /// parameters: its studies are cold, checked at submit). The error says why there is none.
    pub fn index_scene(
        &mut self,
        hash: &str,
        space: &ParameterSpace,
        store: &Arc<dyn Store>,
    ) -> Result<(), StoreError> {
        if !self.by_scene.contains_key(hash) {
            let index = SceneSolutions::new(hash.to_owned(), space.clone(), store.clone())?;
            self.by_scene.insert(hash.to_owned(), index);
        }
        Ok(())
    }

    /// Keeps a record read from the database (not indexed: [`Solutions::index_loaded`] indexes
    /// them once every scene's index exists).
    pub fn load(&mut self, key: SolutionKey, record: SolutionRecord) {
        self.records.insert(key, Arc::new(record));
    }

    /// Indexes the converged records loaded, in `order` (the database's key order, so that an
    /// index is the same whatever the map's order).
    pub fn index_loaded(&mut self, order: &[SolutionKey]) -> Result<(), StoreError> {
        for key in order {
            let record = &self.records[key];
            if let (true, Some(index)) = (record.converged, self.by_scene.get_mut(&*record.scene_hash)) {
                index.index(key.clone(), record)?;
            }
        }
        Ok(())
    }

    /// Keeps a solution just committed to the database: findable at once if it converged, its
    /// fields kept decoded (the next point's warm start is likely this one).
    pub fn insert(
        &mut self,
        key: SolutionKey,
        record: SolutionRecord,
        file: Vec<u8>,
        solution: InterfaceSolution,
    ) -> Result<(), StoreError> {
        let record = Arc::new(record);
        if let Some(index) = self.by_scene.get_mut(&*record.scene_hash).filter(|_| record.converged) {
            index.index(key.clone(), &record)?;
            index.remember(&key, file, solution);
        }
        self.records.insert(key, record);
        Ok(())
    }

    /// The keys of every solution `pool` sent.
    pub fn of_pool(&self, pool: &str) -> Vec<SolutionKey> {
        self.records.iter().filter(|(_, r)| r.pool == pool).map(|(k, _)| k.clone()).collect()
    }

    /// Forgets the solutions at `keys` (already deleted from the database) and builds their
    /// scenes' indexes again from what is left.
    pub fn remove(&mut self, keys: &[SolutionKey], store: &Arc<dyn Store>) -> Result<(), StoreError> {
        let scenes: BTreeSet<String> =
            keys.iter().filter_map(|k| self.records.remove(k)).map(|r| r.scene_hash.to_string()).collect();
        for hash in scenes {
            let Some(old) = self.by_scene.remove(&hash) else { continue };
            let mut index = SceneSolutions::new(hash.clone(), old.space().clone(), store.clone())?;
            for (key, record) in self.records.iter().filter(|(_, r)| *r.scene_hash == *hash && r.converged) {
                index.index(key.clone(), record)?;
            }
            self.by_scene.insert(hash, index);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lease_keeps_its_point_its_start_and_its_progress_together_and_ends_whole() {
        let mut leases = Leases::default();
        let id = leases.new_id();
        assert_ne!(id, 0);
        leases.grant(id, StudyId(3), PointId(7));
        assert!(leases.any_of(StudyId(3)) && !leases.any_of(StudyId(4)));
        assert_eq!(leases.progress(id), None);
        assert!(leases.report(id, 10, 1e-2), "a first report is news");
        assert!(!leases.report(id, 10, 5e-3), "the same iteration again is not");
        assert!(leases.report(id, 11, 4e-3));
        assert_eq!(leases.progress(id), Some((11, 4e-3)));
        assert!(!leases.report(id + 1, 1, 1.0), "a lease not held records nothing");
        leases.end(id);
        assert_eq!((leases.len(), leases.progress(id), leases.held_for(id)), (0, None, Duration::ZERO));
        assert!(leases.get(id).is_none());
    }

    #[test]
    fn only_registered_pools_are_seen_and_counted() {
        let mut pools = Pools::default();
        assert!(!pools.seen("ghost"));
        assert!(matches!(pools.solver_version("ghost"), Err(CoordError::UnknownPool(_))));
        pools.register("p".into(), PoolInfo { ranks: 2, host: "h".into(), solver_version: "v1".into() });
        assert!(pools.seen("p"));
        assert_eq!(pools.solver_version("p").expect("registered"), "v1");
        assert_eq!(pools.connected(Duration::from_secs(60)), 1);
        std::thread::sleep(Duration::from_millis(5));
        assert_eq!(pools.connected(Duration::from_millis(1)), 0, "not heard from within the lease");
    }
}
