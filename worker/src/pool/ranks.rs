//! A pool of P > 1 MPI ranks: rank 0 talks to the coordinator (through [`super::run_pool`] with
//! [`RootSolver`]) and sends every design point to the other ranks, which wait in
//! [`follow_root`]; then all ranks solve the point together over the communicator seam, and rank
//! 0's outcome (which holds the whole interface solution) is what the coordinator receives.
//!
//! Jobs travel point to point with their own tag, and a waiting rank probes for them with a pause
//! between probes: a rank blocked in a collective would spin a core for as long as the pool is
//! idle.
//!
//! A job carries its scene's key; the scene's text and mesh files travel only with the first job
//! of a scene (rank 0 knows what the others hold: they get every job it sends), and each rank
//! parses a scene once and keeps it, one at a time: a study's points share one scene.

use std::time::Duration;

use mpi::point_to_point::{Destination, Source};
use mpi::topology::Communicator as _;

use super::{PointJob, PoolSolver, SceneKey};
use crate::mpi_comm::Mpi;
use glissade_core::io::solution_file;
use glissade_core::point::DesignPoint;
use glissade_core::scene::{Scale, Scene, Tolerance};
use glissade_proto::v1::{MeshFile, ParameterVector, RankJob, RankMessage, RankScene, rank_message};
use glissade_solver::comm::Communicator;
use glissade_solver::run::{PointSolver, RunError, SolveOutcome, SolveRequest};

/// MPI tag of the job messages, apart from the solver's own messages.
const JOB_TAG: i32 = 7001;
/// Pause between two probes of a waiting rank.
const PROBE_PAUSE: Duration = Duration::from_millis(5);

/// What rank 0 sends to the other ranks.
#[derive(Debug)]
enum Message {
    /// `scene`: the scene of `scene_key`, only when the ranks do not hold it yet
    Job {
        scene_key: SceneKey,
        scene: Option<SceneFiles>,
        request: SolveRequest,
        init_bytes: Vec<u8>,
    },
    Stop,
}

/// A scene as ranks 1..P receive it: its text and its mesh files (name, bytes), parsed and
/// attached again there.
#[derive(Debug, Clone, PartialEq)]
struct SceneFiles {
    text: String,
    meshes: Vec<(String, Vec<u8>)>,
}

/// Rank 0's record of the scene ranks 1..P hold: the last one sent.
#[derive(Debug, Default)]
struct SentScene(Option<SceneKey>);

impl SentScene {
    /// The message of `job`, its scene's text and mesh files in it only when they are not the
    /// ones sent last (which the ranks then hold).
    fn job(&mut self, job: &PointJob) -> Message {
        let prepared = &job.scene;
        let scene = (self.0.as_ref() != Some(&prepared.key)).then(|| SceneFiles {
            text: prepared.text.clone(),
            meshes: prepared.scene.meshes.iter().map(|(f, b)| (f.clone(), b.to_vec())).collect(),
        });
        self.0 = Some(prepared.key.clone());
        Message::Job {
            scene_key: prepared.key.clone(),
            scene,
            request: job.request.clone(),
            init_bytes: job.init_bytes.clone(),
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum RanksError {
    #[error("job message from rank 0 is malformed: {0}")]
    Malformed(&'static str),
    #[error("job message from rank 0 is for scene {0}, which this rank was not sent")]
    UnknownScene(SceneKey),
    #[error("job message from rank 0 does not decode: {0}")]
    Decode(#[from] prost::DecodeError),
    #[error("job message from rank 0: {0}")]
    Scene(#[from] glissade_core::scene::SceneError),
    #[error("job message from rank 0: {0}")]
    Meshes(#[from] glissade_core::scene::MeshFileError),
    #[error("job message from rank 0: warm start: {0}")]
    WarmStart(#[from] solution_file::SolutionFileError),
}

/// Rank 0's solver: sends each job to ranks 1..P, then solves with them. Call [`RootSolver::stop`]
/// when the pool ends, or the other ranks wait for ever.
pub struct RootSolver<'a> {
    comm: &'a Mpi,
    solver: PointSolver,
    sent: SentScene,
}

impl<'a> RootSolver<'a> {
    pub fn new(comm: &'a Mpi) -> Self {
        Self { comm, solver: PointSolver::default(), sent: SentScene::default() }
    }

    fn send_to_all(&self, message: &Message) {
        let bytes = encode(message);
        tracing::debug!(bytes = bytes.len(), ranks = self.comm.size() - 1, "job message sent");
        for rank in 1..self.comm.size() {
            self.comm.world.process_at_rank(rank as i32).send_with_tag(&bytes[..], JOB_TAG);
        }
    }

    /// Tells ranks 1..P that the pool is over.
    pub fn stop(self) {
        self.send_to_all(&Message::Stop);
    }
}

impl PoolSolver for RootSolver<'_> {
    fn solve(&mut self, job: &PointJob) -> Result<SolveOutcome, RunError> {
        let message = self.sent.job(job);
        self.send_to_all(&message);
        self.solver.solve(self.comm, &job.scene.scene, &job.request, job.init.as_ref())
    }
}

/// Ranks 1..P of a pool: solve every job rank 0 sends, until it says stop. SIGTERM and SIGINT
/// are ignored here: rank 0 decides when the pool ends (after delivering its point), and a rank
/// that left early would stall the others in a collective.
pub fn follow_root(comm: &Mpi) -> Result<(), RanksError> {
    ignore_termination_signals();
    let mut solver = PointSolver::default();
    let root = comm.world.process_at_rank(0);
    // the scene of the last job, parsed, under its key
    let mut held: Option<(SceneKey, Scene)> = None;
    loop {
        while root.immediate_probe_with_tag(JOB_TAG).is_none() {
            std::thread::sleep(PROBE_PAUSE);
        }
        let (bytes, _) = root.receive_vec_with_tag::<u8>(JOB_TAG);
        match decode(&bytes)? {
            Message::Stop => return Ok(()),
            Message::Job { scene_key, scene, request, init_bytes } => {
                let scene = hold(&mut held, scene_key, scene)?;
                let init =
                    if init_bytes.is_empty() { None } else { Some(solution_file::read_from(&init_bytes[..])?.1) };
                // Rank 0 reports the outcome; an error here is the same error as rank 0's (same
                // inputs, same reductions), so there is nothing more to do with it.
                if let Err(e) = solver.solve(comm, scene, &request, init.as_ref()) {
                    tracing::debug!(rank = comm.rank(), error = %e, "point failed");
                }
            }
        }
    }
}

/// The scene of a job for `key`: `sent`, parsed and kept in `held`, or the one `held` already.
fn hold(held: &mut Option<(SceneKey, Scene)>, key: SceneKey, sent: Option<SceneFiles>) -> Result<&Scene, RanksError> {
    if let Some(SceneFiles { text, meshes }) = sent {
        // one scene in memory, not two, while the next is parsed
        *held = None;
        let mut scene = Scene::parse(&text)?;
        scene.attach_mesh_bytes(meshes)?;
        tracing::debug!(key = %key, "parsed the job's scene");
        *held = Some((key.clone(), scene));
    }
    match held {
        Some((kept, scene)) if *kept == key => Ok(scene),
        _ => Err(RanksError::UnknownScene(key)),
    }
}

fn ignore_termination_signals() {
    // SAFETY: setting the disposition of two signals to SIG_IGN has no other effect.
    unsafe {
        libc::signal(libc::SIGTERM, libc::SIG_IGN);
        libc::signal(libc::SIGINT, libc::SIG_IGN);
    }
}

// The job message on the wire: `RankMessage` of proto/proto/ranks.proto, so the framing, the
// bounds checks of a truncated message and the float bits (fixed64: every rank must solve the
// same numbers) are protobuf's, and the design point is the API's `ParameterVector`, converted
// by the proto crate's impls. `encode` takes the request apart field by field, so a new field
// of `SolveRequest` does not compile until it travels too.

fn encode(message: &Message) -> Vec<u8> {
    use prost::Message as _;
    let kind = match message {
        Message::Stop => rank_message::Kind::Stop(true),
        Message::Job { scene_key, scene, request, init_bytes } => {
            // progress is counted on each rank for itself
            let SolveRequest { point, tolerance, max_iterations, scale, record_fields, progress: _, init_parameters } =
                request;
            rank_message::Kind::Job(RankJob {
                scene_key: scene_key.as_str().to_owned(),
                scene: scene.as_ref().map(|SceneFiles { text, meshes }| RankScene {
                    text: text.clone(),
                    meshes: meshes
                        .iter()
                        .map(|(file, bytes)| MeshFile {
                            file: file.clone(),
                            data: bytes.clone(),
                            sha256: String::new(),
                        })
                        .collect(),
                }),
                point: Some(point.clone().into()),
                tolerance: tolerance.map(Tolerance::get),
                max_iterations: max_iterations.map(|n| n as u64),
                scale: match scale {
                    None => 0,
                    Some(Scale::Single) => 1,
                    Some(Scale::Multi) => 2,
                },
                record_fields: *record_fields,
                init_parameters: init_parameters.clone().map(ParameterVector::from),
                init_bytes: init_bytes.clone(),
            })
        }
    };
    RankMessage { kind: Some(kind) }.encode_to_vec()
}

fn decode(bytes: &[u8]) -> Result<Message, RanksError> {
    use prost::Message as _;
    let job = match RankMessage::decode(bytes)?.kind {
        Some(rank_message::Kind::Job(job)) => job,
        Some(rank_message::Kind::Stop(true)) => return Ok(Message::Stop),
        Some(rank_message::Kind::Stop(false)) | None => return Err(RanksError::Malformed("neither a job nor a stop")),
    };
    if job.scene.as_ref().is_some_and(|s| s.meshes.len() > glissade_core::scene::MAX_MESH_FILES) {
        return Err(RanksError::Malformed("too many mesh files"));
    }
    let scene_key = SceneKey::try_from(job.scene_key).map_err(|_| RanksError::Malformed("bad scene key"))?;
    // (rank 0 sent design points: a failure here is a damaged message)
    let point = |p: ParameterVector| DesignPoint::try_from(p).map_err(|_| RanksError::Malformed("bad design point"));
    let tolerance = match job.tolerance.map(|t| Tolerance::new("the job's tolerance", t)) {
        None => None,
        Some(Ok(t)) => Some(t),
        Some(Err(_)) => return Err(RanksError::Malformed("tolerance out of range")),
    };
    let scale = match job.scale {
        0 => None,
        1 => Some(Scale::Single),
        2 => Some(Scale::Multi),
        _ => return Err(RanksError::Malformed("bad scale")),
    };
    let max_iterations = match job.max_iterations.map(usize::try_from) {
        None => None,
        Some(Ok(n)) => Some(n),
        Some(Err(_)) => return Err(RanksError::Malformed("iteration limit out of range")),
    };
    let request = SolveRequest {
        point: point(job.point.ok_or(RanksError::Malformed("no design point"))?)?,
        tolerance,
        max_iterations,
        scale,
        record_fields: job.record_fields,
        progress: None,
        init_parameters: job.init_parameters.map(point).transpose()?,
    };
    Ok(Message::Job {
        scene_key,
        scene: job
            .scene
            .map(|s| SceneFiles { text: s.text, meshes: s.meshes.into_iter().map(|m| (m.file, m.data)).collect() }),
        request,
        init_bytes: job.init_bytes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pool::scenes::PreparedScene;
    use crate::pool::scenes::testing::prepared;
    use std::sync::Arc;

    fn key(text: &str) -> SceneKey {
        SceneKey::new(text, [])
    }

    #[test]
    fn a_job_survives_encoding_bit_for_bit() {
        // every field of the request set to something other than its default
        let request = SolveRequest {
            point: DesignPoint::from_pairs([("f1", 0.1 + 0.2), ("prestress", -1e-300)]).unwrap(),
            tolerance: Some(Tolerance::new("tol", 2e-4).unwrap()),
            max_iterations: Some(77),
            scale: Some(Scale::Multi),
            record_fields: true,
            progress: Some(Default::default()),
            init_parameters: Some(DesignPoint::from_pairs([("f1", 0.1), ("f2", 1.0 / 3.0)]).unwrap()),
        };
        let files = SceneFiles {
            text: "dimension = 2\n".into(),
            meshes: vec![("a.msh".to_string(), vec![1, 2, 3]), ("b.msh".to_string(), vec![])],
        };
        let message =
            Message::Job { scene_key: key("a"), scene: Some(files.clone()), request, init_bytes: vec![9, 8, 7] };
        let Message::Job { scene_key, scene, request, init_bytes } = decode(&encode(&message)).unwrap() else {
            panic!("not a job")
        };
        assert_eq!((scene_key, scene), (key("a"), Some(files)));
        assert_eq!(request.point.get("f1").unwrap().to_bits(), (0.1f64 + 0.2).to_bits());
        assert_eq!(request.point.get("prestress").unwrap().to_bits(), (-1e-300f64).to_bits());
        assert_eq!(request.point.len(), 2);
        assert_eq!((request.tolerance.map(Tolerance::get), request.max_iterations), (Some(2e-4), Some(77)));
        assert_eq!((request.scale, request.record_fields), (Some(Scale::Multi), true));
        // a progress counter is each rank's own
        assert!(request.progress.is_none());
        assert_eq!(request.init_parameters.unwrap().get("f2").unwrap().to_bits(), (1.0f64 / 3.0).to_bits());
        for scale in [None, Some(Scale::Single)] {
            let message = Message::Job {
                scene_key: key("b"),
                scene: None,
                request: SolveRequest { scale, ..SolveRequest::default() },
                init_bytes: Vec::new(),
            };
            let Message::Job { request, .. } = decode(&encode(&message)).unwrap() else { panic!("not a job") };
            assert_eq!((request.scale, request.record_fields, request.init_parameters), (scale, false, None));
        }
        assert_eq!(init_bytes, vec![9, 8, 7]);
        assert!(matches!(decode(&encode(&Message::Stop)).unwrap(), Message::Stop));
    }

    #[test]
    fn a_job_without_its_scene_carries_the_key_alone_and_an_empty_scene_is_still_a_scene() {
        let job = |scene| Message::Job {
            scene_key: key("a"),
            scene,
            request: SolveRequest::default(),
            init_bytes: Vec::new(),
        };
        let Message::Job { scene_key, scene, .. } = decode(&encode(&job(None))).unwrap() else { panic!("not a job") };
        assert_eq!((scene_key, scene), (key("a"), None));
        // present but empty is not absent
        let empty = SceneFiles { text: String::new(), meshes: Vec::new() };
        let Message::Job { scene, .. } = decode(&encode(&job(Some(empty.clone())))).unwrap() else {
            panic!("not a job")
        };
        assert_eq!(scene, Some(empty));
        // a job names its scene by a key, or it is damaged
        use prost::Message as _;
        let mut bad = RankMessage::decode(&encode(&job(None))[..]).unwrap();
        if let Some(rank_message::Kind::Job(j)) = &mut bad.kind {
            j.scene_key = "not a key".into();
        }
        assert!(matches!(decode(&bad.encode_to_vec()), Err(RanksError::Malformed("bad scene key"))));
    }

    #[test]
    fn rank_0_sends_a_scene_and_its_meshes_with_its_first_job_only() {
        let joint = prepared("bolted-joint-tiny.toml");
        let blocks = prepared("three-blocks-tiny.toml");
        let job = |scene: &Arc<PreparedScene>| PointJob {
            scene: scene.clone(),
            request: SolveRequest::default(),
            init_bytes: vec![1],
            init: None,
            warm_start_dropped: false,
        };
        let mut sent = SentScene::default();
        let sizes: Vec<(bool, usize)> = [&joint, &joint, &joint, &blocks, &blocks, &joint]
            .into_iter()
            .map(|scene| {
                let message = sent.job(&job(scene));
                let bytes = encode(&message).len();
                let Message::Job { scene_key, scene: files, init_bytes, .. } = message else { panic!("not a job") };
                assert_eq!((&scene_key, init_bytes), (&scene.key, vec![1]));
                if let Some(files) = &files {
                    assert_eq!(files.text, scene.text);
                    let meshes: Vec<(&str, &[u8])> =
                        scene.scene.meshes.iter().map(|(f, b)| (f.as_str(), &b[..])).collect();
                    assert_eq!(files.meshes.iter().map(|(f, b)| (f.as_str(), &b[..])).collect::<Vec<_>>(), meshes);
                }
                (files.is_some(), bytes)
            })
            .collect();
        let carried: Vec<bool> = sizes.iter().map(|&(c, _)| c).collect();
        assert_eq!(carried, [true, false, false, true, false, true]);
        // the joint's mesh file is 151 kB; its later jobs carry tens of bytes
        assert!(sizes[0].1 > 150_000 && sizes[1].1 < 200, "{sizes:?}");
        eprintln!("bytes per job to each rank, bolted-joint-tiny: first {}, then {}", sizes[0].1, sizes[1].1);
    }

    #[test]
    fn a_rank_parses_a_scene_once_and_refuses_a_job_of_a_scene_it_was_not_sent() {
        let joint = prepared("bolted-joint-tiny.toml");
        let files = SceneFiles {
            text: joint.text.clone(),
            meshes: joint.scene.meshes.iter().map(|(f, b)| (f.clone(), b.to_vec())).collect(),
        };
        let mut held = None;
        assert!(matches!(hold(&mut held, key("a"), None), Err(RanksError::UnknownScene(_))));
        let parsed: *const Scene = hold(&mut held, joint.key.clone(), Some(files)).unwrap();
        let again: *const Scene = hold(&mut held, joint.key.clone(), None).unwrap();
        assert_eq!(parsed, again);
        assert_eq!(held.as_ref().unwrap().1.content_hash(), joint.hash);
        assert!(matches!(hold(&mut held, key("a"), None), Err(RanksError::UnknownScene(k)) if k == key("a")));
        // a scene that does not parse is not held, and neither is the last one
        let bad = SceneFiles { text: "dimension = 9".into(), meshes: Vec::new() };
        assert!(matches!(hold(&mut held, key("b"), Some(bad)), Err(RanksError::Scene(_))));
        assert!(held.is_none());
    }

    #[test]
    fn a_truncated_job_is_an_error_not_a_panic() {
        let bytes = encode(&Message::Job {
            scene_key: key("a"),
            scene: Some(SceneFiles { text: "x".repeat(40), meshes: vec![("m".into(), vec![0; 5])] }),
            request: SolveRequest::default(),
            init_bytes: Vec::new(),
        });
        for cut in 0..bytes.len() {
            assert!(decode(&bytes[..cut]).is_err(), "cut at {cut}");
        }
        assert!(decode(&[5]).is_err());
    }
}
