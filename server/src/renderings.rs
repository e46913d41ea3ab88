//! A study's heavy answers (its JSON with every point, its page), kept between reads: a finished
//! study of 100,000 points is 17.5 MB of JSON, and rebuilding it for every reader copied its
//! records under the coordinator's lock each time. An answer is kept under the study's version
//! ([`StudyVersion`]: its own and its audits', changed by every mutable access to them), so a
//! kept answer is the one a rebuild would give; a study with a point being solved has no version
//! and is built each time. Readers of the same version wait for one build instead of making
//! their own. Bounded in bytes, the least recently read dropped first.

use std::sync::{Arc, Mutex, OnceLock, PoisonError};

use axum::body::Bytes;
use axum::http::StatusCode;
use glissade_proto::StudyId;

use crate::coordinator::StudyVersion;
use crate::kept::Kept;

/// What the kept answers of all studies may take.
pub const MAX_BYTES: usize = 128 << 20;

/// An answer: its content type and body, and the body gzipped once a reader asks for it (a
/// study's JSON compresses about 10 x: what greedy readers cost is sending it).
#[derive(Debug)]
pub struct Answer {
    pub content_type: &'static str,
    pub body: Bytes,
    gzipped: OnceLock<Bytes>,
}

impl Answer {
    pub fn new(content_type: &'static str, body: Bytes) -> Rendered {
        Arc::new(Answer { content_type, body, gzipped: OnceLock::new() })
    }

    /// The body gzipped (the first call compresses, at the fastest level).
    pub fn gzipped(&self) -> &Bytes {
        self.gzipped.get_or_init(|| {
            use std::io::Write;
            let mut out = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
            // (writing to a Vec cannot fail)
            let _ = out.write_all(&self.body);
            Bytes::from(out.finish().unwrap_or_default())
        })
    }
}

/// An answer as kept and shared.
pub type Rendered = Arc<Answer>;

/// An answer that could not be built: its status and why (not kept; its waiters get it too).
pub type NotRendered = (StatusCode, String);

/// Which study and which answer of it (the JSON, the page with its query).
type Slot = (StudyId, String);

struct Entry {
    version: StudyVersion,
    answer: Arc<OnceLock<Result<Rendered, NotRendered>>>,
}

struct Inner {
    entries: Kept<Slot, Entry>,
    builds: u64,
}

pub struct Renderings {
    inner: Mutex<Inner>,
}

impl Default for Renderings {
    fn default() -> Self {
        Renderings::new(MAX_BYTES)
    }
}

impl Renderings {
    pub fn new(max_bytes: usize) -> Self {
        Renderings { inner: Mutex::new(Inner { entries: Kept::new(max_bytes), builds: 0 }) }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        // a panic while holding it leaves a consistent map (no build runs under it)
        self.inner.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The answer `what` of `study` at `version`: the kept one, or `build`'s, kept (a second
    /// reader of the same version waits for the first's build). Without a version (the study
    /// changes as it is read) it is built and not kept; neither is a refusal.
    pub fn get_or_build(
        &self,
        study: StudyId,
        what: &str,
        version: Option<StudyVersion>,
        build: impl FnOnce() -> Result<Rendered, NotRendered>,
    ) -> Result<Rendered, NotRendered> {
        let Some(version) = version else { return build() };
        let slot = (study, what.to_owned());
        let answer = {
            let mut inner = self.lock();
            match inner.entries.read(&slot, |e| e.version == version) {
                Some(e) => e.answer.clone(),
                None => {
                    let answer = Arc::new(OnceLock::new());
                    inner.entries.insert(slot.clone(), Entry { version, answer: answer.clone() }, 0);
                    answer
                }
            }
        };
        let built = answer
            .get_or_init(|| {
                self.lock().builds += 1;
                build()
            })
            .clone();
        let this = |e: &Entry| Arc::ptr_eq(&e.answer, &answer);
        match &built {
            Ok(kept) => self.lock().entries.count(&slot, this, kept.body.len()),
            // not kept: the next reader builds again
            Err(_) => self.lock().entries.remove_if(&slot, this),
        }
        built
    }

    /// The answer `what` of `study` kept at `version`, if any (for answers built in stages,
    /// which [`Renderings::put`] keeps).
    pub fn get(&self, study: StudyId, what: &str, version: &StudyVersion) -> Option<Rendered> {
        let mut inner = self.lock();
        let entry = inner.entries.read(&(study, what.to_owned()), |e| &e.version == version)?;
        entry.answer.get()?.clone().ok()
    }

    /// Keeps an answer built at `version` (replacing that slot's older one).
    pub fn put(&self, study: StudyId, what: &str, version: StudyVersion, answer: Rendered) {
        let bytes = answer.body.len();
        let entry = Entry { version, answer: Arc::new(OnceLock::from(Ok(answer))) };
        let mut inner = self.lock();
        inner.builds += 1;
        inner.entries.insert((study, what.to_owned()), entry, bytes);
    }

    /// How many answers were built (kept or not, versioned ones only) and the bytes kept.
    #[cfg(test)]
    pub fn stats(&self) -> (u64, usize) {
        let inner = self.lock();
        (inner.builds, inner.entries.bytes())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn version(v: u64) -> Option<StudyVersion> {
        Some(StudyVersion(vec![(1, v)]))
    }

    fn body(text: &str, bytes: usize) -> Result<Rendered, NotRendered> {
        Ok(Answer::new("text/plain", Bytes::from(text.repeat(bytes))))
    }

    #[test]
    fn readers_of_one_version_wait_for_one_build() {
        let kept = Renderings::default();
        let started = std::sync::Barrier::new(4);
        std::thread::scope(|s| {
            for _ in 0..4 {
                s.spawn(|| {
                    started.wait();
                    let got = kept.get_or_build(StudyId(1), "json", version(7), || {
                        std::thread::sleep(std::time::Duration::from_millis(50));
                        body("a", 10)
                    });
                    assert_eq!(got.unwrap().body, "a".repeat(10));
                });
            }
        });
        assert_eq!(kept.stats(), (1, 10));
        // a new version is built again and replaces the old; no version is built and not kept
        kept.get_or_build(StudyId(1), "json", version(8), || body("b", 20)).unwrap();
        assert_eq!(kept.stats(), (2, 20));
        kept.get_or_build(StudyId(1), "json", None, || body("c", 30)).unwrap();
        kept.get_or_build(StudyId(1), "json", None, || body("c", 30)).unwrap();
        assert_eq!(kept.stats(), (2, 20));
        assert_eq!(kept.get(StudyId(1), "json", &version(8).unwrap()).unwrap().body, "b".repeat(20));
        assert!(kept.get(StudyId(1), "json", &version(7).unwrap()).is_none());
    }

    #[test]
    fn a_refusal_is_not_kept_and_the_bound_drops_the_least_recently_read() {
        let kept = Renderings::new(100);
        let refused = kept.get_or_build(StudyId(1), "json", version(1), || Err((StatusCode::NOT_FOUND, "gone".into())));
        assert_eq!(refused.unwrap_err().0, StatusCode::NOT_FOUND);
        kept.get_or_build(StudyId(1), "json", version(1), || body("a", 40)).unwrap();
        assert_eq!(kept.stats(), (2, 40), "built again after the refusal");
        kept.put(StudyId(2), "page", version(1).unwrap(), body("b", 40).unwrap());
        // gzipped once, and gunzipped back to the body
        let b = kept.get(StudyId(2), "page", &version(1).unwrap()).unwrap();
        assert!(std::ptr::eq(b.gzipped(), b.gzipped()));
        let mut back = String::new();
        std::io::Read::read_to_string(&mut flate2::read::GzDecoder::new(&b.gzipped()[..]), &mut back).unwrap();
        assert_eq!(back, "b".repeat(40));
        // read 1, then add a third: 2 (read least recently) goes
        assert!(kept.get(StudyId(1), "json", &version(1).unwrap()).is_some());
        kept.get_or_build(StudyId(3), "json", version(1), || body("c", 40)).unwrap();
        assert_eq!(kept.stats().1, 80);
        assert!(kept.get(StudyId(2), "page", &version(1).unwrap()).is_none());
        assert!(kept.get(StudyId(1), "json", &version(1).unwrap()).is_some());
        // an answer larger than the bound is served, not kept
        let large = kept.get_or_build(StudyId(4), "json", version(1), || body("d", 200)).unwrap();
        assert_eq!(large.body.len(), 200);
        assert_eq!(kept.stats().1, 80);
    }
}
