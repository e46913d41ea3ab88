//! The coordinator's persistent store.
//!
//! The rest of the server sees only [`Store`], so sled (whose 1.0 is still alpha) can be swapped
//! for another embedded engine without touching the service code.

use std::path::{Path, PathBuf};

/// Version of the on-disk layout; bump it whenever keys or value encodings change.
pub const SCHEMA_VERSION: u32 = 1;

/// Key under which the layout version is stored (a reserved prefix keeps it apart from data keys).
const SCHEMA_KEY: &[u8] = b"meta/schema-version";

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

/// Minimal key-value interface the coordinator needs.
pub trait Store: Send + Sync {
    /// The value stored under `key`, if any.
    fn get(&self, key: &[u8]) -> Result<Option<Vec<u8>>, StoreError>;
    /// Stores `value` under `key`, replacing any previous value.
    fn put(&self, key: &[u8], value: &[u8]) -> Result<(), StoreError>;
    /// Makes every earlier write durable.
    fn flush(&self) -> Result<(), StoreError>;
}

/// [`Store`] backed by a sled database directory.
pub struct SledStore {
    db: sled::Db,
    path: PathBuf,
}

impl SledStore {
    /// Opens (creating if needed) the database in `dir` and checks its schema version.
    ///
    /// A new database gets [`SCHEMA_VERSION`]; an existing one with another version is refused.
    pub fn open(dir: &Path) -> Result<Self, StoreError> {
        let path = dir.to_path_buf();
        let db = sled::open(dir).map_err(|source| match source {
            // sled 0.34 reports a held file lock only as text ("could not acquire lock on ...").
            sled::Error::Io(ref io) if io.to_string().starts_with("could not acquire lock") => {
                StoreError::Locked { path: path.clone() }
            }
            source => StoreError::Engine { path: path.clone(), source },
        })?;
        let store = Self { db, path };
        match store.get(SCHEMA_KEY)? {
            None => {
                store.put(SCHEMA_KEY, SCHEMA_VERSION.to_string().as_bytes())?;
                store.flush()?;
                tracing::info!(path = %store.path.display(), SCHEMA_VERSION, "created database");
            }
            Some(found) if found == SCHEMA_VERSION.to_string().as_bytes() => {
                tracing::info!(path = %store.path.display(), SCHEMA_VERSION, "opened database");
            }
            Some(found) => {
                return Err(StoreError::SchemaMismatch {
                    path: store.path,
                    found: String::from_utf8_lossy(&found).into_owned(),
                    expected: SCHEMA_VERSION,
                });
            }
        }
        Ok(store)
    }

    fn engine_error(&self, source: sled::Error) -> StoreError {
        StoreError::Engine { path: self.path.clone(), source }
    }
}

impl Store for SledStore {
    fn get(&self, key: &[u8]) -> Result<Option<Vec<u8>>, StoreError> {
        self.db.get(key).map(|v| v.map(|ivec| ivec.to_vec())).map_err(|e| self.engine_error(e))
    }

    fn put(&self, key: &[u8], value: &[u8]) -> Result<(), StoreError> {
        self.db.insert(key, value).map(drop).map_err(|e| self.engine_error(e))
    }

    fn flush(&self) -> Result<(), StoreError> {
        self.db.flush().map(drop).map_err(|e| self.engine_error(e))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn new_database_gets_schema_version_and_reopens() {
        let dir = tempfile::tempdir().unwrap();
        {
            let store = SledStore::open(dir.path()).unwrap();
            assert_eq!(store.get(SCHEMA_KEY).unwrap().as_deref(), Some(&b"1"[..]));
            store.put(b"k", b"v").unwrap();
            store.flush().unwrap();
        }
        let store = SledStore::open(dir.path()).unwrap();
        assert_eq!(store.get(b"k").unwrap().as_deref(), Some(&b"v"[..]));
    }

    #[test]
    fn other_schema_version_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        {
            let store = SledStore::open(dir.path()).unwrap();
            store.put(SCHEMA_KEY, b"999").unwrap();
            store.flush().unwrap();
        }
        let err = SledStore::open(dir.path()).err().expect("must refuse");
        assert!(
            matches!(&err, StoreError::SchemaMismatch { found, expected: SCHEMA_VERSION, .. } if found == "999"),
            "{err}"
        );
        assert!(err.to_string().contains("schema version 999"), "{err}");
    }
}
