//! The scene of a pool's last lease, kept for the next one: a study's points share one scene,
//! which a pool parses, checks and fetches the mesh files of once, not at every point (issue 50).
//! One scene is kept, so that a pool's memory holds one.

use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use glissade_core::scene::{MeshFileError, Scene, SceneSize, mesh_digest};
use glissade_proto::v1;

/// Identity of a scene as a pool solves it: SHA-256 (hex) of its text and its mesh files'
/// digests. Not the content hash, which leaves out the `[solver]` section and the parameters'
/// ranges: two scenes of one content hash may solve differently or accept other points.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SceneKey(String);

impl SceneKey {
    /// The key of scene text `text` with the mesh files (name, SHA-256 hex) it names.
    pub fn new<'a>(text: &str, meshes: impl IntoIterator<Item = (&'a str, &'a str)>) -> Self {
        use sha2::{Digest, Sha256};
        // the order in which a lease lists the files is not the scene's
        let mut meshes: Vec<(&str, &str)> = meshes.into_iter().collect();
        meshes.sort_unstable();
        let mut hasher = Sha256::new();
        hasher.update(b"glissade-pool-scene-key-v1\n");
        // each part behind its length: no two inputs run together into one
        for part in std::iter::once(text).chain(meshes.iter().flat_map(|&(file, digest)| [file, digest])) {
            hasher.update((part.len() as u64).to_le_bytes());
            hasher.update(part.as_bytes());
        }
        Self(hasher.finalize().iter().map(|b| format!("{b:02x}")).collect())
    }

    /// The key of a lease's scene, its mesh files by the digests the lease announces.
    pub fn of_lease(lease: &v1::Lease) -> Self {
        Self::new(&lease.scene, lease.meshes.iter().map(|m| (m.file.as_str(), m.sha256.as_str())))
    }

    pub fn as_str(&self) -> &str {
        &self.0
    }
}

impl std::fmt::Display for SceneKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

/// A string that is not a scene key (64 lowercase hex digits).
#[derive(Debug, thiserror::Error)]
#[error("not a scene key: {0:?}")]
pub struct NotASceneKey(String);

impl TryFrom<String> for SceneKey {
    type Error = NotASceneKey;

    fn try_from(s: String) -> Result<Self, NotASceneKey> {
        if s.len() == 64 && s.bytes().all(|b| matches!(b, b'0'..=b'9' | b'a'..=b'f')) {
            Ok(Self(s))
        } else {
            Err(NotASceneKey(s))
        }
    }
}

/// A lease's scene parsed, its mesh files attached, and what depends on the scene alone checked
/// and measured; what depends on the design point is checked at every lease (`prepare`).
#[derive(Debug)]
pub struct PreparedScene {
    pub key: SceneKey,
    pub text: String,
    pub scene: Scene,
    /// its content hash: the lease's `scene_hash`
    pub hash: String,
    /// what solving it takes: measured once (the mesh files parsed), held against the memory
    /// a pool has at each lease
    pub size: SceneSize,
}

impl PreparedScene {
    /// The scene of `lease` (of key `key`) with its mesh files `meshes` (name, bytes), checked
    /// against the digests the lease announces and the hash it says.
    fn new(lease: &v1::Lease, key: SceneKey, meshes: Vec<(String, Vec<u8>)>) -> Result<Self> {
        let mut scene = Scene::parse(&lease.scene).context("scene")?;
        if meshes.len() != lease.meshes.len() {
            bail!("the lease names {} mesh files, {} were fetched", lease.meshes.len(), meshes.len());
        }
        for ((file, bytes), announced) in meshes.iter().zip(&lease.meshes) {
            let actual = mesh_digest(bytes);
            if actual != announced.sha256 {
                bail!(MeshFileError::DigestMismatch { file: file.clone(), expected: announced.sha256.clone(), actual });
            }
        }
        scene.attach_mesh_bytes(meshes).context("meshes")?;
        let hash = scene.content_hash();
        if hash != lease.scene_hash {
            bail!("the lease's scene has hash {hash}, the lease says {}", lease.scene_hash);
        }
        // the coordinator's checks at submit (core::check), again: a scene from an older
        // coordinator, or one whose rules changed since
        scene.check_meshes().context("scene")?;
        let size = scene.size().context("scene")?;
        Ok(Self { key, text: lease.scene.clone(), scene, hash, size })
    }
}

/// A lease's scene as received: the kept one, or another with its mesh files fetched.
#[derive(Debug)]
pub enum LeasedScene {
    Kept(Arc<PreparedScene>),
    New { key: SceneKey, meshes: Vec<(String, Vec<u8>)> },
}

/// The last scene prepared, for the leases that follow it.
#[derive(Debug, Default)]
pub struct SceneCache {
    kept: Option<Arc<PreparedScene>>,
    /// scenes parsed so far: the log says it, once per scene rather than once per point
    parsed: u64,
}

impl SceneCache {
    /// The kept scene if it is the one of `key` with content hash `hash`.
    pub fn get(&self, key: &SceneKey, hash: &str) -> Option<Arc<PreparedScene>> {
        self.kept.as_ref().filter(|kept| kept.key == *key && kept.hash == hash).cloned()
    }

    /// The scene of a lease, the kept one or `lease`'s parsed and kept in its place.
    pub fn scene_of(&mut self, lease: &v1::Lease, scene: LeasedScene) -> Result<Arc<PreparedScene>> {
        let (key, meshes) = match scene {
            LeasedScene::Kept(kept) => return Ok(kept),
            LeasedScene::New { key, meshes } => (key, meshes),
        };
        // one scene in memory, not two, while the next is parsed
        self.kept = None;
        self.parsed += 1;
        let started = Instant::now();
        let prepared = Arc::new(PreparedScene::new(lease, key, meshes)?);
        tracing::info!(
            scene = %prepared.hash,
            parsed = self.parsed,
            ms = started.elapsed().as_secs_f64() * 1e3,
            "scene parsed and kept"
        );
        self.kept = Some(prepared.clone());
        Ok(prepared)
    }

    /// Scenes parsed so far.
    pub fn parsed(&self) -> u64 {
        self.parsed
    }
}

/// Leases of the shipped scenes, for the pool's tests.
#[cfg(test)]
pub(crate) mod testing {
    use super::*;

    /// A lease of `name` (scenes/) at its parameters' defaults, with its mesh files (name,
    /// bytes) as a pool fetches them.
    pub fn lease(name: &str) -> (v1::Lease, Vec<(String, Vec<u8>)>) {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes").join(name);
        let scene = Scene::read(&path).unwrap();
        let meshes: Vec<(String, Vec<u8>)> = scene.meshes.iter().map(|(f, b)| (f.clone(), b.to_vec())).collect();
        let lease = v1::Lease {
            scene: std::fs::read_to_string(&path).unwrap(),
            scene_hash: scene.content_hash(),
            meshes: meshes
                .iter()
                .map(|(file, b)| v1::MeshRef { file: file.clone(), sha256: mesh_digest(b), bytes: b.len() as u64 })
                .collect(),
            tolerance: 1e-3,
            max_iterations: 100,
            ..Default::default()
        };
        (lease, meshes)
    }

    /// The scene of `lease` as a pool receives it when it keeps another.
    pub fn fetched(lease: &v1::Lease, meshes: &[(String, Vec<u8>)]) -> LeasedScene {
        LeasedScene::New { key: SceneKey::of_lease(lease), meshes: meshes.to_vec() }
    }

    /// `name`'s scene prepared as a pool does (for the ranks' tests, which need MPI).
    #[cfg(feature = "mpi")]
    pub fn prepared(name: &str) -> Arc<PreparedScene> {
        let (lease, meshes) = lease(name);
        SceneCache::default().scene_of(&lease, fetched(&lease, &meshes)).unwrap()
    }
}

#[cfg(test)]
mod tests {
    use super::testing::{fetched, lease};
    use super::*;

    #[test]
    fn a_scene_key_covers_the_text_and_the_mesh_digests_not_their_order() {
        let key = SceneKey::new("a", [("m.msh", "01"), ("n.msh", "02")]);
        assert_eq!(key, SceneKey::new("a", [("n.msh", "02"), ("m.msh", "01")]));
        for other in [
            SceneKey::new("b", [("m.msh", "01"), ("n.msh", "02")]),
            SceneKey::new("a", [("m.msh", "01"), ("n.msh", "03")]),
            SceneKey::new("a", [("m.msh", "01")]),
            // lengths keep the parts apart
            SceneKey::new("a", [("m.msh0", "1"), ("n.msh", "02")]),
        ] {
            assert_ne!(key, other);
        }
        assert_eq!(SceneKey::try_from(key.as_str().to_owned()).unwrap(), key);
        for bad in ["", "xyz", &"A".repeat(64), &"0".repeat(63)] {
            assert!(SceneKey::try_from(bad.to_owned()).is_err(), "{bad}");
        }
    }

    #[test]
    fn a_lease_of_the_kept_scene_gets_it_and_another_scene_or_hash_does_not() {
        let (joint, meshes) = lease("bolted-joint-tiny.toml");
        let mut cache = SceneCache::default();
        let key = SceneKey::of_lease(&joint);
        assert!(cache.get(&key, &joint.scene_hash).is_none());
        let kept = cache.scene_of(&joint, fetched(&joint, &meshes)).unwrap();
        assert_eq!(
            (kept.key.clone(), kept.hash.as_str(), kept.scene.meshes.len()),
            (key.clone(), joint.scene_hash.as_str(), 1)
        );
        assert!(Arc::ptr_eq(&cache.get(&key, &joint.scene_hash).unwrap(), &kept));
        // the same text under another content hash is not the kept scene
        assert!(cache.get(&key, "0").is_none());
        // another mesh file under the same text is another scene
        let mut other_mesh = joint.clone();
        other_mesh.meshes[0].sha256 = mesh_digest(b"another mesh");
        assert!(cache.get(&SceneKey::of_lease(&other_mesh), &joint.scene_hash).is_none());
        // a `[solver]` setting (the text ends in that section) leaves the content hash as it
        // is, not the key
        let mut windowed = joint.clone();
        windowed.scene.push_str("time_window = 5\n");
        assert!(cache.get(&SceneKey::of_lease(&windowed), &joint.scene_hash).is_none());
        let windowed = cache.scene_of(&windowed, fetched(&windowed, &meshes)).unwrap();
        assert_eq!((windowed.hash.as_str(), windowed.scene.solver.time_window), (joint.scene_hash.as_str(), Some(5)));
        // one scene kept: the last
        assert!(cache.get(&key, &joint.scene_hash).is_none());
        assert_eq!(cache.parsed(), 2);
    }

    #[test]
    fn a_lease_whose_meshes_or_hash_do_not_match_is_refused_and_nothing_is_kept() {
        let (joint, meshes) = lease("bolted-joint-tiny.toml");
        let mut cache = SceneCache::default();
        let mut wrong_hash = joint.clone();
        wrong_hash.scene_hash = "0".repeat(64);
        let e = cache.scene_of(&wrong_hash, fetched(&wrong_hash, &meshes)).unwrap_err();
        assert!(format!("{e:#}").contains("the lease says"), "{e:#}");
        let other = vec![(meshes[0].0.clone(), b"another mesh".to_vec())];
        let e = cache.scene_of(&joint, fetched(&joint, &other)).unwrap_err();
        assert!(format!("{e:#}").contains("SHA-256"), "{e:#}");
        let e = cache.scene_of(&joint, fetched(&joint, &[])).unwrap_err();
        assert!(format!("{e:#}").contains("1 mesh files, 0 were fetched"), "{e:#}");
        assert!(cache.get(&SceneKey::of_lease(&joint), &joint.scene_hash).is_none());
    }
}
