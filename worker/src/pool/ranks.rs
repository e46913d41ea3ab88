//! A pool of P > 1 MPI ranks: rank 0 talks to the coordinator (through [`super::run_pool`] with
//! [`RootSolver`]) and sends every design point to the other ranks, which wait in
//! [`follow_root`]; then all ranks solve the point together over the communicator seam, and rank
//! 0's outcome (which holds the whole interface solution) is what the coordinator receives.
//!
//! Jobs travel point to point with their own tag, and a waiting rank probes for them with a pause
//! between probes: a rank blocked in a collective would spin a core for as long as the pool is
//! idle.

use std::time::Duration;

use mpi::point_to_point::{Destination, Source};
use mpi::topology::Communicator as _;

use super::{PointJob, PoolSolver};
use crate::mpi_comm::Mpi;
use glissade_core::io::solution_file;
use glissade_core::point::DesignPoint;
use glissade_core::scene::{Scale, Scene, Tolerance};
use glissade_proto::v1::{MeshFile, ParameterVector, RankJob, RankMessage, rank_message};
use glissade_solver::comm::Communicator;
use glissade_solver::run::{PointSolver, RunError, SolveOutcome, SolveRequest};

/// MPI tag of the job messages, apart from the solver's own messages.
const JOB_TAG: i32 = 7001;
/// Pause between two probes of a waiting rank.
const PROBE_PAUSE: Duration = Duration::from_millis(5);

/// What rank 0 sends to the other ranks.
#[derive(Debug)]
enum Message {
    /// `meshes`: the scene's mesh files (name, bytes), attached again on each rank
    Job {
        scene_text: String,
        meshes: Vec<(String, Vec<u8>)>,
        request: SolveRequest,
        init_bytes: Vec<u8>,
    },
    Stop,
}

#[derive(Debug, thiserror::Error)]
pub enum RanksError {
    #[error("job message from rank 0 is malformed: {0}")]
    Malformed(&'static str),
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
}

impl<'a> RootSolver<'a> {
    pub fn new(comm: &'a Mpi) -> Self {
        Self { comm, solver: PointSolver::default() }
    }

    fn send_to_all(&self, message: &Message) {
        let bytes = encode(message);
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
        self.send_to_all(&Message::Job {
            scene_text: job.scene_text.clone(),
            meshes: job.scene.meshes.iter().map(|(f, b)| (f.clone(), b.to_vec())).collect(),
            request: job.request.clone(),
            init_bytes: job.init_bytes.clone(),
        });
        self.solver.solve(self.comm, &job.scene, &job.request, job.init.as_ref())
    }
}

/// Ranks 1..P of a pool: solve every job rank 0 sends, until it says stop. SIGTERM and SIGINT
/// are ignored here: rank 0 decides when the pool ends (after delivering its point), and a rank
/// that left early would stall the others in a collective.
pub fn follow_root(comm: &Mpi) -> Result<(), RanksError> {
    ignore_termination_signals();
    let mut solver = PointSolver::default();
    let root = comm.world.process_at_rank(0);
    loop {
        while root.immediate_probe_with_tag(JOB_TAG).is_none() {
            std::thread::sleep(PROBE_PAUSE);
        }
        let (bytes, _) = root.receive_vec_with_tag::<u8>(JOB_TAG);
        match decode(&bytes)? {
            Message::Stop => return Ok(()),
            Message::Job { scene_text, meshes, request, init_bytes } => {
                let mut scene = Scene::parse(&scene_text)?;
                scene.attach_mesh_bytes(meshes)?;
                let init =
                    if init_bytes.is_empty() { None } else { Some(solution_file::read_from(&init_bytes[..])?.1) };
                // Rank 0 reports the outcome; an error here is the same error as rank 0's (same
                // inputs, same reductions), so there is nothing more to do with it.
                if let Err(e) = solver.solve(comm, &scene, &request, init.as_ref()) {
                    tracing::debug!(rank = comm.rank(), error = %e, "point failed");
                }
            }
        }
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
        Message::Job { scene_text, meshes, request, init_bytes } => {
            // progress is counted on each rank for itself
            let SolveRequest { point, tolerance, max_iterations, scale, record_fields, progress: _, init_parameters } =
                request;
            rank_message::Kind::Job(RankJob {
                scene_text: scene_text.clone(),
                meshes: meshes
                    .iter()
                    .map(|(file, bytes)| MeshFile { file: file.clone(), data: bytes.clone(), sha256: String::new() })
                    .collect(),
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
    if job.meshes.len() > glissade_core::scene::MAX_MESH_FILES {
        return Err(RanksError::Malformed("too many mesh files"));
    }
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
        scene_text: job.scene_text,
        meshes: job.meshes.into_iter().map(|m| (m.file, m.data)).collect(),
        request,
        init_bytes: job.init_bytes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

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
        let meshes = vec![("a.msh".to_string(), vec![1, 2, 3]), ("b.msh".to_string(), vec![])];
        let message = Message::Job {
            scene_text: "dimension = 2\n".into(),
            meshes: meshes.clone(),
            request,
            init_bytes: vec![9, 8, 7],
        };
        let Message::Job { scene_text, meshes: decoded, request, init_bytes } = decode(&encode(&message)).unwrap()
        else {
            panic!("not a job")
        };
        assert_eq!(scene_text, "dimension = 2\n");
        assert_eq!(decoded, meshes);
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
                scene_text: String::new(),
                meshes: Vec::new(),
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
    fn a_truncated_job_is_an_error_not_a_panic() {
        let bytes = encode(&Message::Job {
            scene_text: "x".repeat(40),
            meshes: vec![("m".into(), vec![0; 5])],
            request: SolveRequest::default(),
            init_bytes: Vec::new(),
        });
        for cut in 0..bytes.len() {
            assert!(decode(&bytes[..cut]).is_err(), "cut at {cut}");
        }
        assert!(decode(&[5]).is_err());
    }
}
