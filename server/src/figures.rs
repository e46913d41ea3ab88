//! The web page's surface pictures, kept between loads: fitting a QoI's surface is O(points^3)
//! (0.9 s for 400 points, docs/surrogate.md), and a page reloads every second while its study
//! runs. A study's pictures are a function of its points' parameters and values, the slice shown
//! and the resolution of each QoI (the scene is the study's own), so they are kept under a hash
//! of exactly these: a point that lands changes the hash and the next load draws again, a load
//! with nothing new draws nothing. Bounded in bytes, the least recently used dropped first.

use std::collections::HashSet;
use std::hash::{DefaultHasher, Hash, Hasher};
use std::sync::{Arc, Mutex, PoisonError};

use glissade_proto::StudyId;

use crate::coordinator::Surface;
use crate::kept::Kept;

/// What the pictures of all studies may take (a picture is 0.3-0.5 MB of SVG, docs/surrogate.md).
pub const MAX_BYTES: usize = 64 << 20;

/// Which study and slice: each keeps only its latest pictures.
type Slot = (StudyId, Vec<(String, u64)>);

struct Entry {
    hash: u64,
    figures: Arc<Vec<String>>,
}

struct Inner {
    entries: Kept<Slot, Entry>,
    draws: u64,
    /// pictures being drawn (slot and content hash): a second load waits for them
    drawing: HashSet<(Slot, u64)>,
}

/// The pictures last drawn per study and slice.
pub struct FigureCache {
    inner: Mutex<Inner>,
}

impl Default for FigureCache {
    fn default() -> Self {
        FigureCache::new(MAX_BYTES)
    }
}

/// What a study's pictures depend on besides its scene: every point's parameters and QoI values
/// (not its state: a point leased draws the same as a point pending), the slice, the
/// resolutions.
pub fn content_hash(
    surface: &Surface,
    fixed: &[(String, f64)],
    resolution: &std::collections::BTreeMap<String, f64>,
) -> u64 {
    let mut h = DefaultHasher::new();
    surface.parameters.hash(&mut h);
    surface.qoi.hash(&mut h);
    for row in &surface.rows {
        for (n, v) in row.parameters.iter() {
            (n, v.to_bits()).hash(&mut h);
        }
        for (q, v) in &row.qoi {
            (q, v.to_bits()).hash(&mut h);
        }
        // the end of a row, so that values cannot shift from one row to the next
        u8::MAX.hash(&mut h);
    }
    for (n, v) in fixed {
        (n, v.to_bits()).hash(&mut h);
    }
    for (q, r) in resolution {
        (q, r.to_bits()).hash(&mut h);
    }
    h.finish()
}

impl FigureCache {
    pub fn new(max_bytes: usize) -> Self {
        FigureCache { inner: Mutex::new(Inner { entries: Kept::new(max_bytes), draws: 0, drawing: HashSet::new() }) }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        // a panic while holding it leaves a consistent map (every change is one statement)
        self.inner.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The pictures kept for `study` and `fixed` if they were drawn from content `hash`.
    pub fn get(&self, study: StudyId, fixed: &[(String, f64)], hash: u64) -> Option<Arc<Vec<String>>> {
        Some(self.lock().entries.read(&slot(study, fixed), |e| e.hash == hash)?.figures.clone())
    }

    /// Keeps pictures just drawn from content `hash` (replacing that study's and slice's older
    /// ones), the least recently read dropped until the whole fits the bound; pictures larger
    /// than the bound alone are not kept.
    pub fn put(&self, study: StudyId, fixed: &[(String, f64)], hash: u64, figures: Arc<Vec<String>>) {
        let bytes: usize = figures.iter().map(String::len).sum();
        let mut inner = self.lock();
        inner.draws += 1;
        inner.entries.insert(slot(study, fixed), Entry { hash, figures }, bytes);
    }

    /// Marks the pictures of `hash` as being drawn by the caller: false when another caller
    /// already draws them (wait for [`FigureCache::get`] to have them).
    pub fn begin(&self, study: StudyId, fixed: &[(String, f64)], hash: u64) -> bool {
        self.lock().drawing.insert((slot(study, fixed), hash))
    }

    /// The drawing [`FigureCache::begin`] marked has ended (kept by `put`, or failed).
    pub fn end(&self, study: StudyId, fixed: &[(String, f64)], hash: u64) {
        self.lock().drawing.remove(&(slot(study, fixed), hash));
    }

    /// Whether pictures of `hash` are being drawn.
    #[cfg(test)]
    pub fn drawing(&self, study: StudyId, fixed: &[(String, f64)], hash: u64) -> bool {
        self.lock().drawing.contains(&(slot(study, fixed), hash))
    }

    /// How many times pictures were drawn (kept or not) and the bytes kept.
    #[cfg(test)]
    pub fn stats(&self) -> (u64, usize) {
        let inner = self.lock();
        (inner.draws, inner.entries.bytes())
    }
}

fn slot(study: StudyId, fixed: &[(String, f64)]) -> Slot {
    (study, fixed.iter().map(|(n, v)| (n.clone(), v.to_bits())).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn figures(text: &str, bytes: usize) -> Arc<Vec<String>> {
        Arc::new(vec![text.repeat(bytes / text.len().max(1))])
    }

    #[test]
    fn pictures_are_kept_per_study_and_slice_until_their_content_changes() {
        let cache = FigureCache::new(1000);
        let (a, b) = (StudyId(1), StudyId(2));
        let slice = [("f2".to_owned(), 0.1)];
        assert!(cache.get(a, &[], 7).is_none());
        cache.put(a, &[], 7, figures("a", 100));
        cache.put(a, &slice, 7, figures("s", 100));
        cache.put(b, &[], 7, figures("b", 100));
        assert_eq!(cache.get(a, &[], 7).unwrap()[0], "a".repeat(100));
        assert_eq!(cache.get(a, &slice, 7).unwrap()[0], "s".repeat(100));
        // new content: the old pictures are no answer, and the new replace them
        assert!(cache.get(a, &[], 8).is_none());
        cache.put(a, &[], 8, figures("A", 100));
        assert!(cache.get(a, &[], 7).is_none());
        assert_eq!(cache.get(a, &[], 8).unwrap()[0], "A".repeat(100));
        assert_eq!(cache.stats(), (4, 300));
    }

    #[test]
    fn the_cache_stays_within_its_bound_dropping_the_least_recently_read() {
        let cache = FigureCache::new(1000);
        for k in 0..4 {
            cache.put(StudyId(k), &[], 0, figures("x", 300));
        }
        // 4 x 300 > 1000: the first put is gone
        assert_eq!(cache.stats().1, 900);
        assert!(cache.get(StudyId(0), &[], 0).is_none());
        // read 1, then add one more: 2 (read least recently) goes, 1 stays
        assert!(cache.get(StudyId(1), &[], 0).is_some());
        cache.put(StudyId(4), &[], 0, figures("x", 300));
        assert!(cache.get(StudyId(1), &[], 0).is_some());
        assert!(cache.get(StudyId(2), &[], 0).is_none());
        assert_eq!(cache.stats().1, 900);
        // a picture above the bound alone is drawn but not kept, and evicts nothing
        cache.put(StudyId(9), &[], 0, figures("x", 2000));
        assert!(cache.get(StudyId(9), &[], 0).is_none());
        assert_eq!(cache.stats().1, 900);
    }
}
