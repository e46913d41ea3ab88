//! The coordinator's persistent store: named trees of byte keys and values, written in atomic,
//! durable batches.
//!
//! The rest of the server sees only [`Store`], so sled (whose 1.0 is still alpha) can be swapped
//! for another embedded engine (LMDB, SQLite) without touching the service code: the seam is
//! get / scan / commit-a-batch, which every such engine offers. What the keys and values mean is
//! `records.rs`'s business.

use std::path::{Path, PathBuf};

/// Version of the on-disk layout; bump it whenever keys or value encodings change.
///
/// 1: only this version key (the service stored nothing yet). 2: the trees of [`Tree`].
pub const SCHEMA_VERSION: u32 = 2;

/// Key of the layout version, in sled's default tree: where version 1 put it and where any
/// glissade-server looks first, so an older binary opening a newer database sees a version it
/// does not know and refuses, instead of taking the database for a new one.
const SCHEMA_KEY: &[u8] = b"meta/schema-version";

/// The trees of the database (sled trees; tables elsewhere).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Tree {
    /// Scene content hash (hex) -> scene TOML text.
    Scenes,
    /// Study id (u64 big-endian) -> study record.
    Studies,
    /// Study id ++ point id (u64 big-endian each) -> point record.
    Points,
    /// Solution key (scene hash ++ parameter vector) -> solution metadata.
    Solutions,
    /// Solution key -> zstd-compressed solution file; apart from the metadata so that loading
    /// the index at start reads kilobytes, not the fields.
    SolutionFields,
    /// SHA-256 (hex) of a mesh file -> the file, zstd-compressed: content-addressed, so studies
    /// of one mesh store it once.
    Meshes,
    /// Counters (next study id, next lease id).
    Meta,
}

impl Tree {
    /// Every tree, in a fixed order.
    pub const ALL: [Tree; 7] =
        [Tree::Scenes, Tree::Studies, Tree::Points, Tree::Solutions, Tree::SolutionFields, Tree::Meshes, Tree::Meta];

    /// Name of the tree on disk.
    pub fn name(self) -> &'static str {
        match self {
            Tree::Scenes => "scenes",
            Tree::Studies => "studies",
            Tree::Points => "points",
            Tree::Solutions => "solutions",
            Tree::SolutionFields => "solution_fields",
            Tree::Meshes => "meshes",
            Tree::Meta => "meta",
        }
    }

    fn index(self) -> usize {
        Self::ALL.iter().position(|&t| t == self).expect("every tree is in ALL")
    }
}

/// Writes applied together or not at all.
#[derive(Debug, Default)]
pub struct Batch {
    /// (tree, key, the value to store or None to remove the key)
    ops: Vec<(Tree, Vec<u8>, Option<Vec<u8>>)>,
}

impl Batch {
    /// An empty batch.
    pub fn new() -> Self {
        Self::default()
    }

    /// Stores `value` under `key` in `tree`, replacing any previous value.
    pub fn put(&mut self, tree: Tree, key: impl Into<Vec<u8>>, value: impl Into<Vec<u8>>) -> &mut Self {
        self.ops.push((tree, key.into(), Some(value.into())));
        self
    }

    /// Removes `key` from `tree` (nothing if it is absent).
    pub fn delete(&mut self, tree: Tree, key: impl Into<Vec<u8>>) -> &mut Self {
        self.ops.push((tree, key.into(), None));
        self
    }

    /// True when there is nothing to write.
    pub fn is_empty(&self) -> bool {
        self.ops.is_empty()
    }
}

/// Errors of the store; each names the database directory involved.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// Another process (most likely another glissade-server) holds the database's lock.
    #[error("database at {path} is in use by another process (another glissade-server?)")]
    Locked {
        /// The database directory.
        path: PathBuf,
    },
    /// The engine could not open, read or write the database.
    #[error("database at {path}")]
    Engine {
        /// The database directory.
        path: PathBuf,
        /// The engine's own error.
        #[source]
        source: sled::Error,
    },
    /// The disk under the database is full: nothing more can be written until space is freed
    /// (and, sled's write error being sticky, the coordinator restarted).
    #[error("database at {path}: the disk is full (no space left on the device)")]
    Full {
        /// The database directory.
        path: PathBuf,
    },
    /// The database was written by a different layout version; reading it would misinterpret data.
    #[error(
        "database at {path} has schema version {found}, this glissade-server expects {expected}; \
         use a matching glissade-server or a fresh --data directory"
    )]
    SchemaMismatch {
        /// The database directory.
        path: PathBuf,
        /// Version found on disk.
        found: String,
        /// Version this binary writes.
        expected: u32,
    },
}

/// A key and its value.
pub type Entry = (Vec<u8>, Vec<u8>);

/// What the coordinator needs from a storage engine.
pub trait Store: Send + Sync {
    /// The value under `key` in `tree`, if any.
    fn get(&self, tree: Tree, key: &[u8]) -> Result<Option<Vec<u8>>, StoreError>;
    /// Every `(key, value)` of `tree` whose key starts with `prefix`, in key order.
    fn scan_prefix(&self, tree: Tree, prefix: &[u8]) -> Result<Vec<Entry>, StoreError>;
    /// Applies every write of `batch` atomically, and durably: on disk when this returns, so a
    /// SIGKILL right after loses nothing.
    fn commit(&self, batch: Batch) -> Result<(), StoreError>;
    /// Makes every earlier write durable (commits already are; this is for shutdown).
    fn flush(&self) -> Result<(), StoreError>;
    /// Bytes the database occupies on disk.
    fn size_on_disk(&self) -> Result<u64, StoreError>;
    /// Why the store can no longer write (the first write error), if it cannot.
    fn write_failure(&self) -> Option<String> {
        None
    }
}

/// sled's page cache (its default is 1 GiB): the coordinator keeps every record it serves in its
/// own memory, and solution files are read once per warm start, so the cache mostly holds what
/// was just written (docs/performance.md, "Memory per design point").
const CACHE_BYTES: u64 = 64 << 20;

/// [`Store`] backed by a sled database directory.
pub struct SledStore {
    /// The first write error: sled keeps failing after one, until it is reopened.
    failure: std::sync::Mutex<Option<String>>,
    db: sled::Db,
    /// Open trees, indexed like [`Tree::ALL`].
    trees: Vec<sled::Tree>,
    path: PathBuf,
}

impl SledStore {
    /// Opens (creating if needed) the database in `dir` and checks its schema version.
    ///
    /// A new database gets [`SCHEMA_VERSION`]; a version-1 one (which held nothing but its
    /// version) is migrated; any other version is refused.
    pub fn open(dir: &Path) -> Result<Self, StoreError> {
        let path = dir.to_path_buf();
        let db = sled::Config::new().path(dir).cache_capacity(CACHE_BYTES).open().map_err(|source| match source {
            // sled 0.34 reports a held file lock only as text ("could not acquire lock on ...").
            sled::Error::Io(ref io) if io.to_string().starts_with("could not acquire lock") => {
                StoreError::Locked { path: path.clone() }
            }
            source => StoreError::Engine { path: path.clone(), source },
        })?;
        let engine = |source| StoreError::Engine { path: path.clone(), source };
        let found = db.get(SCHEMA_KEY).map_err(engine)?;
        // Check before opening trees: opening one creates it, which would change an old database.
        let expected = SCHEMA_VERSION.to_string();
        match found.as_deref() {
            None => {
                let has_trees = db.tree_names().iter().any(|n| &n[..] != b"__sled__default");
                if !db.is_empty() || has_trees {
                    return Err(StoreError::SchemaMismatch { path, found: "(none)".into(), expected: SCHEMA_VERSION });
                }
                db.insert(SCHEMA_KEY, expected.as_bytes()).map_err(engine)?;
                tracing::info!(path = %path.display(), SCHEMA_VERSION, "created database");
            }
            Some(b"1") if db.len() == 1 && db.tree_names().len() == 1 => {
                db.insert(SCHEMA_KEY, expected.as_bytes()).map_err(engine)?;
                tracing::info!(path = %path.display(), SCHEMA_VERSION, "migrated an empty version-1 database");
            }
            Some(v) if v == expected.as_bytes() => {
                tracing::info!(path = %path.display(), SCHEMA_VERSION, "opened database");
            }
            Some(v) => {
                return Err(StoreError::SchemaMismatch {
                    path,
                    found: String::from_utf8_lossy(v).into_owned(),
                    expected: SCHEMA_VERSION,
                });
            }
        }
        let trees = Tree::ALL.iter().map(|t| db.open_tree(t.name())).collect::<Result<Vec<_>, _>>().map_err(engine)?;
        db.flush().map_err(engine)?;
        Ok(Self { failure: Default::default(), db, trees, path })
    }

    fn tree(&self, tree: Tree) -> &sled::Tree {
        &self.trees[tree.index()]
    }

    fn engine_error(&self, source: sled::Error) -> StoreError {
        match source {
            sled::Error::Io(ref io)
                if io.raw_os_error() == Some(28) || io.kind() == std::io::ErrorKind::StorageFull =>
            {
                StoreError::Full { path: self.path.clone() }
            }
            source => StoreError::Engine { path: self.path.clone(), source },
        }
    }

    /// A write error, remembered as the store's failure (the first one is the cause).
    fn write_error(&self, source: sled::Error) -> StoreError {
        let e = self.engine_error(source);
        let mut failure = self.failure.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        failure.get_or_insert_with(|| match std::error::Error::source(&e) {
            Some(cause) => format!("{e}: {cause}"),
            None => e.to_string(),
        });
        e
    }
}

impl Store for SledStore {
    fn get(&self, tree: Tree, key: &[u8]) -> Result<Option<Vec<u8>>, StoreError> {
        self.tree(tree).get(key).map(|v| v.map(|ivec| ivec.to_vec())).map_err(|e| self.engine_error(e))
    }

    fn scan_prefix(&self, tree: Tree, prefix: &[u8]) -> Result<Vec<Entry>, StoreError> {
        self.tree(tree)
            .scan_prefix(prefix)
            .map(|kv| kv.map(|(k, v)| (k.to_vec(), v.to_vec())))
            .collect::<Result<_, _>>()
            .map_err(|e| self.engine_error(e))
    }

    fn commit(&self, batch: Batch) -> Result<(), StoreError> {
        if batch.is_empty() {
            return Ok(());
        }
        // One transaction over the trees the batch touches.
        let mut involved: Vec<Tree> = Vec::new();
        for (tree, _, _) in &batch.ops {
            if !involved.contains(tree) {
                involved.push(*tree);
            }
        }
        let handles: Vec<&sled::Tree> = involved.iter().map(|&t| self.tree(t)).collect();
        use sled::Transactional;
        handles[..]
            .transaction(|views| {
                for (tree, key, value) in &batch.ops {
                    let view = &views[involved.iter().position(|t| t == tree).expect("tree listed above")];
                    match value {
                        Some(value) => drop(view.insert(key.as_slice(), value.as_slice())?),
                        None => drop(view.remove(key.as_slice())?),
                    }
                }
                Ok(())
            })
            .map_err(|e: sled::transaction::TransactionError<()>| match e {
                sled::transaction::TransactionError::Storage(source) => self.write_error(source),
                sled::transaction::TransactionError::Abort(()) => {
                    unreachable!("the transaction closure never aborts")
                }
            })?;
        self.flush()
    }

    fn flush(&self) -> Result<(), StoreError> {
        self.db.flush().map(drop).map_err(|e| self.write_error(e))
    }

    fn size_on_disk(&self) -> Result<u64, StoreError> {
        self.db.size_on_disk().map_err(|e| self.engine_error(e))
    }

    fn write_failure(&self) -> Option<String> {
        self.failure.lock().unwrap_or_else(std::sync::PoisonError::into_inner).clone()
    }
}

/// [`Store`] in memory, for tests: a second engine behind the seam, so that the contract
/// suite below checks what the coordinator relies on rather than what sled happens to do.
#[cfg(test)]
#[derive(Default)]
pub struct InMemoryStore {
    trees: std::sync::Mutex<std::collections::HashMap<Tree, MemoryTree>>,
}

#[cfg(test)]
type MemoryTree = std::collections::BTreeMap<Vec<u8>, Vec<u8>>;

#[cfg(test)]
impl Store for InMemoryStore {
    fn get(&self, tree: Tree, key: &[u8]) -> Result<Option<Vec<u8>>, StoreError> {
        Ok(self.trees.lock().unwrap().get(&tree).and_then(|t| t.get(key).cloned()))
    }

    fn scan_prefix(&self, tree: Tree, prefix: &[u8]) -> Result<Vec<Entry>, StoreError> {
        let trees = self.trees.lock().unwrap();
        let Some(t) = trees.get(&tree) else { return Ok(Vec::new()) };
        Ok(t.range(prefix.to_vec()..)
            .take_while(|(k, _)| k.starts_with(prefix))
            .map(|(k, v)| (k.clone(), v.clone()))
            .collect())
    }

    fn commit(&self, batch: Batch) -> Result<(), StoreError> {
        let mut trees = self.trees.lock().unwrap();
        for (tree, key, value) in batch.ops {
            let tree = trees.entry(tree).or_default();
            match value {
                Some(value) => drop(tree.insert(key, value)),
                None => drop(tree.remove(&key)),
            }
        }
        Ok(())
    }

    fn flush(&self) -> Result<(), StoreError> {
        Ok(())
    }

    fn size_on_disk(&self) -> Result<u64, StoreError> {
        Ok(0)
    }
}

/// Opens the sled database at `dir` for a test that has just dropped another handle on it:
/// sled lets go of its file lock when its flusher thread ends, which a loaded machine can delay
/// past the drop (failed in CI: `Locked`), so wait for it, a few seconds at most.
#[cfg(test)]
pub(crate) fn open_when_unlocked(dir: &Path) -> SledStore {
    reopen(dir).unwrap()
}

/// [`SledStore::open`] once sled's lock is free ([`open_when_unlocked`]): any other outcome.
#[cfg(test)]
pub(crate) fn reopen(dir: &Path) -> Result<SledStore, StoreError> {
    for _ in 0..100 {
        match SledStore::open(dir) {
            Err(StoreError::Locked { .. }) => std::thread::sleep(std::time::Duration::from_millis(50)),
            other => return other,
        }
    }
    SledStore::open(dir)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What the coordinator relies on from any engine.
    fn contract(store: &dyn Store) {
        assert_eq!(store.get(Tree::Studies, b"a").unwrap(), None);
        assert!(store.scan_prefix(Tree::Points, b"").unwrap().is_empty());
        store.commit(Batch::new()).unwrap();
        // one batch over several trees, visible at once; trees do not share keys
        let mut batch = Batch::new();
        batch
            .put(Tree::Points, b"s1/p2".to_vec(), b"two".to_vec())
            .put(Tree::Points, b"s1/p1".to_vec(), b"one".to_vec())
            .put(Tree::Points, b"s2/p1".to_vec(), b"other".to_vec())
            .put(Tree::Studies, b"s1".to_vec(), b"study".to_vec());
        store.commit(batch).unwrap();
        assert_eq!(store.get(Tree::Studies, b"s1").unwrap().as_deref(), Some(&b"study"[..]));
        assert_eq!(store.get(Tree::Scenes, b"s1").unwrap(), None);
        // a prefix scan: only that prefix, in key order
        let scan = store.scan_prefix(Tree::Points, b"s1/").unwrap();
        assert_eq!(scan, vec![(b"s1/p1".to_vec(), b"one".to_vec()), (b"s1/p2".to_vec(), b"two".to_vec())]);
        assert_eq!(store.scan_prefix(Tree::Points, b"").unwrap().len(), 3);
        // the last write of a key wins, also within one batch
        let mut batch = Batch::new();
        batch.put(Tree::Points, b"s1/p1".to_vec(), b"x".to_vec()).put(Tree::Points, b"s1/p1".to_vec(), b"uno".to_vec());
        store.commit(batch).unwrap();
        assert_eq!(store.get(Tree::Points, b"s1/p1").unwrap().as_deref(), Some(&b"uno"[..]));
        store.flush().unwrap();
        store.size_on_disk().unwrap();
        assert_eq!(store.write_failure(), None);
    }

    #[test]
    fn every_engine_keeps_the_store_contract() {
        let dir = tempfile::tempdir().unwrap();
        contract(&open_when_unlocked(dir.path()));
        contract(&InMemoryStore::default());
    }

    #[test]
    fn new_database_gets_schema_version_and_reopens() {
        let dir = tempfile::tempdir().unwrap();
        {
            let store = open_when_unlocked(dir.path());
            assert_eq!(store.db.get(SCHEMA_KEY).unwrap().as_deref(), Some(&b"2"[..]));
            let mut batch = Batch::new();
            batch.put(Tree::Studies, b"k".to_vec(), b"v".to_vec()).put(Tree::Points, b"k1".to_vec(), b"w".to_vec());
            store.commit(batch).unwrap();
        }
        let store = open_when_unlocked(dir.path());
        assert_eq!(store.get(Tree::Studies, b"k").unwrap().as_deref(), Some(&b"v"[..]));
        assert_eq!(store.get(Tree::Points, b"k").unwrap(), None);
        assert_eq!(store.scan_prefix(Tree::Points, b"k").unwrap(), vec![(b"k1".to_vec(), b"w".to_vec())]);
        assert!(store.size_on_disk().unwrap() > 0);
    }

    #[test]
    fn other_schema_version_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        {
            let store = open_when_unlocked(dir.path());
            store.db.insert(SCHEMA_KEY, b"999").unwrap();
            store.flush().unwrap();
        }
        let err = reopen(dir.path()).err().expect("must refuse");
        assert!(
            matches!(&err, StoreError::SchemaMismatch { found, expected: SCHEMA_VERSION, .. } if found == "999"),
            "{err}"
        );
        assert!(err.to_string().contains("schema version 999"), "{err}");
    }

    #[test]
    fn empty_version_1_database_is_migrated_and_a_versionless_one_refused() {
        let dir = tempfile::tempdir().unwrap();
        {
            let db = sled::open(dir.path()).unwrap();
            db.insert(SCHEMA_KEY, b"1").unwrap();
            db.flush().unwrap();
        }
        let store = open_when_unlocked(dir.path());
        assert_eq!(store.db.get(SCHEMA_KEY).unwrap().as_deref(), Some(&b"2"[..]));
        drop(store);

        let dir = tempfile::tempdir().unwrap();
        {
            let db = sled::open(dir.path()).unwrap();
            db.open_tree("studies").unwrap().insert(b"1", b"x").unwrap();
            db.flush().unwrap();
        }
        let err = reopen(dir.path()).err().expect("must refuse data without a version");
        assert!(matches!(&err, StoreError::SchemaMismatch { found, .. } if found == "(none)"), "{err}");
    }
}
