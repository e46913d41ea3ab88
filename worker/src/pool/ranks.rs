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
use glissade_core::scene::{Scale, Scene};
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

// Byte layout: a tag byte (0 stop, 1 job); a job then holds the scene text, the `--set` pairs,
// the tolerance and iteration limit (floats as their bits: every rank must solve the same
// numbers), the scale, whether fields are recorded, the warm start's parameters, and the
// warm-start file bytes up to the end. `encode` takes the request apart field by field, so a new
// field of `SolveRequest` does not compile until it travels too.

fn encode(message: &Message) -> Vec<u8> {
    let mut out = Vec::new();
    match message {
        Message::Stop => out.push(0),
        Message::Job { scene_text, meshes, request, init_bytes } => {
            // progress is counted on each rank for itself
            let SolveRequest { set, tolerance, max_iterations, scale, record_fields, progress: _, init_parameters } =
                request;
            out.push(1);
            put_bytes(&mut out, scene_text.as_bytes());
            out.extend((meshes.len() as u64).to_le_bytes());
            for (file, bytes) in meshes {
                put_bytes(&mut out, file.as_bytes());
                put_bytes(&mut out, bytes);
            }
            put_pairs(&mut out, set.iter().map(|(k, v)| (k.as_str(), *v)));
            put_option(&mut out, tolerance.map(f64::to_bits));
            put_option(&mut out, max_iterations.map(|n| n as u64));
            out.push(match scale {
                None => 0,
                Some(Scale::Single) => 1,
                Some(Scale::Multi) => 2,
            });
            out.push(u8::from(*record_fields));
            // every rank must stop at the same tolerance, which depends on where the init is from
            match init_parameters {
                None => out.push(0),
                Some(values) => {
                    out.push(1);
                    put_pairs(&mut out, values.iter().map(|(k, v)| (k.as_str(), *v)));
                }
            }
            out.extend_from_slice(init_bytes);
        }
    }
    out
}

fn decode(bytes: &[u8]) -> Result<Message, RanksError> {
    let mut reader = Reader(bytes);
    match reader.take(1)?[0] {
        0 => Ok(Message::Stop),
        1 => {
            let scene_text = reader.string()?;
            let count = reader.u64()? as usize;
            let mut meshes = Vec::with_capacity(count.min(glissade_core::scene::MAX_MESH_FILES));
            for _ in 0..count {
                let file = reader.string()?;
                let n = reader.u64()? as usize;
                meshes.push((file, reader.take(n)?.to_vec()));
            }
            let set = reader.pairs()?;
            let tolerance = reader.option()?.map(f64::from_bits);
            let max_iterations = reader.option()?.map(|n| n as usize);
            let scale = match reader.take(1)?[0] {
                0 => None,
                1 => Some(Scale::Single),
                2 => Some(Scale::Multi),
                _ => return Err(RanksError::Malformed("bad scale")),
            };
            let record_fields = match reader.take(1)?[0] {
                0 => false,
                1 => true,
                _ => return Err(RanksError::Malformed("bad flag")),
            };
            let init_parameters = match reader.take(1)?[0] {
                0 => None,
                1 => Some(reader.pairs()?.into_iter().collect()),
                _ => return Err(RanksError::Malformed("bad option flag")),
            };
            let request =
                SolveRequest { set, tolerance, max_iterations, scale, record_fields, progress: None, init_parameters };
            Ok(Message::Job { scene_text, meshes, request, init_bytes: reader.0.to_vec() })
        }
        _ => Err(RanksError::Malformed("unknown message kind")),
    }
}

fn put_bytes(out: &mut Vec<u8>, bytes: &[u8]) {
    out.extend((bytes.len() as u64).to_le_bytes());
    out.extend_from_slice(bytes);
}

/// A count, then (name, f64 bits) pairs.
fn put_pairs<'a>(out: &mut Vec<u8>, pairs: impl ExactSizeIterator<Item = (&'a str, f64)>) {
    out.extend((pairs.len() as u64).to_le_bytes());
    for (name, value) in pairs {
        put_bytes(out, name.as_bytes());
        out.extend(value.to_bits().to_le_bytes());
    }
}

fn put_option(out: &mut Vec<u8>, value: Option<u64>) {
    match value {
        None => out.push(0),
        Some(v) => {
            out.push(1);
            out.extend(v.to_le_bytes());
        }
    }
}

struct Reader<'a>(&'a [u8]);

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], RanksError> {
        if self.0.len() < n {
            return Err(RanksError::Malformed("truncated"));
        }
        let (head, rest) = self.0.split_at(n);
        self.0 = rest;
        Ok(head)
    }
    fn u64(&mut self) -> Result<u64, RanksError> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().expect("8 bytes")))
    }
    fn string(&mut self) -> Result<String, RanksError> {
        let n = self.u64()? as usize;
        String::from_utf8(self.take(n)?.to_vec()).map_err(|_| RanksError::Malformed("text is not UTF-8"))
    }
    fn pairs(&mut self) -> Result<Vec<(String, f64)>, RanksError> {
        let n = self.u64()? as usize;
        let mut pairs = Vec::with_capacity(n.min(1024));
        for _ in 0..n {
            pairs.push((self.string()?, f64::from_bits(self.u64()?)));
        }
        Ok(pairs)
    }

    fn option(&mut self) -> Result<Option<u64>, RanksError> {
        match self.take(1)?[0] {
            0 => Ok(None),
            1 => Ok(Some(self.u64()?)),
            _ => Err(RanksError::Malformed("bad option flag")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_job_survives_encoding_bit_for_bit() {
        // every field of the request set to something other than its default
        let request = SolveRequest {
            set: vec![("f1".into(), 0.1 + 0.2), ("prestress".into(), -1e-300)],
            tolerance: Some(2e-4),
            max_iterations: Some(77),
            scale: Some(Scale::Multi),
            record_fields: true,
            progress: Some(Default::default()),
            init_parameters: Some([("f1".to_owned(), 0.1), ("f2".to_owned(), 1.0 / 3.0)].into()),
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
        assert_eq!(request.set[0].1.to_bits(), (0.1f64 + 0.2).to_bits());
        assert_eq!(request.set[1], ("prestress".into(), -1e-300));
        assert_eq!((request.tolerance, request.max_iterations), (Some(2e-4), Some(77)));
        assert_eq!((request.scale, request.record_fields), (Some(Scale::Multi), true));
        // a progress counter is each rank's own
        assert!(request.progress.is_none());
        assert_eq!(request.init_parameters.unwrap()["f2"].to_bits(), (1.0f64 / 3.0).to_bits());
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
