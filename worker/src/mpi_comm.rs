//! The MPI communicator: the solver's [`Communicator`] seam over MPI ranks (rsmpi); the serial
//! one and the trait live in `glissade_solver::comm`.

use glissade_solver::comm::Communicator;
use mpi::collective::SystemOperation;
use mpi::datatype::Equivalence;
use mpi::point_to_point::{Destination, MatchedReceiveVec, Source};
use mpi::request::{Request, Scope};
use mpi::topology::{Communicator as _, SimpleCommunicator};
use mpi::traits::{CommunicatorCollectives, Root};

/// MPI ranks of a communicator (usually the world).
pub struct Mpi {
    pub world: SimpleCommunicator,
    /// more ranks on this node than it has cores: a rank that waits gives its core away
    /// ([`Mpi::new`])
    yielding: bool,
}

/// Environment variable that decides whether a rank's waits yield its core: `1` yes (a node
/// shared with other jobs or pools), `0` no (they spin, MPICH's way); unset, yes where the node
/// holds more of the job's ranks than cores ([`Mpi::new`]).
pub const YIELD_ENV: &str = "GLISSADE_MPI_YIELD";

/// A value of [`YIELD_ENV`] other than `0` or `1`.
#[derive(Debug, thiserror::Error)]
#[error("{YIELD_ENV}={0:?}: give 1 (a waiting rank yields its core) or 0 (it spins)")]
pub struct BadYieldSetting(String);

impl Mpi {
    /// The ranks of `world`. Where a node holds more ranks than cores ([`node_cores`]: a test of
    /// three ranks on a 2-core machine), MPICH's ranks spin while they wait and a collective waits for the
    /// scheduler to give the rank that is not running a time slice: three-blocks-tiny
    /// multiscale took 48.5 s on 3 ranks against 0.4 s on 2. There each wait polls and yields
    /// the core instead (the same operations, so the same sums to the bit: 0.9 s); with a core
    /// each, the blocking calls as they are. [`YIELD_ENV`] decides instead where it is set.
    pub fn new(world: SimpleCommunicator) -> Result<Self, BadYieldSetting> {
        // (collectives first: every rank takes part, whatever its setting says)
        let node = world.split_shared(world.rank());
        let on_node = node.size() as usize;
        let cores = node_cores(&node);
        let asked = match std::env::var(YIELD_ENV) {
            Ok(v) if v == "1" => Some(true),
            Ok(v) if v == "0" => Some(false),
            Ok(v) => return Err(BadYieldSetting(v)),
            Err(_) => None,
        };
        let yielding = asked.unwrap_or(on_node > cores);
        if yielding {
            tracing::debug!(ranks = on_node, cores, "a waiting rank yields its core");
        }
        Ok(Self { world, yielding })
    }

    /// Rank 0's `buf` into every rank's.
    fn broadcast_into<T: Equivalence>(&self, buf: &mut [T]) {
        let root = self.world.process_at_rank(0);
        if self.yielding {
            mpi::request::scope(|scope| wait_yielding(root.immediate_broadcast_into(scope, buf)));
        } else {
            root.broadcast_into(buf);
        }
    }
}

/// Words of a CPU mask: 1,024 CPUs, glibc's `CPU_SETSIZE`.
const MASK_WORDS: usize = 16;

/// The cores the ranks of one node may run on: the union of their affinity masks (ranks that
/// Slurm binds to a core each see one core each, the node as many as it has ranks), no more than
/// a quota that holds a rank below its own mask (a container's `cpu.max`, which
/// `available_parallelism` reads).
fn node_cores(node: &SimpleCommunicator) -> usize {
    let mut mask = [0u64; MASK_WORDS];
    let allowed = std::thread::available_parallelism().map_or(1, usize::from);
    // SAFETY: a zeroed cpu_set_t is an empty set; sched_getaffinity writes at most its size.
    let own = unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        if libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set) == 0 {
            for cpu in 0..MASK_WORDS * 64 {
                if libc::CPU_ISSET(cpu, &set) {
                    mask[cpu / 64] |= 1 << (cpu % 64);
                }
            }
        }
        mask.iter().map(|w| w.count_ones() as usize).sum::<usize>()
    };
    if own == 0 {
        // no mask to read: the cores this rank may use, by whatever else std reads
        mask[0] = if allowed >= 64 { u64::MAX } else { (1u64 << allowed) - 1 };
    }
    let mut union = [0u64; MASK_WORDS];
    node.all_reduce_into(&mask[..], &mut union[..], SystemOperation::bitwise_or());
    let quota = [if allowed < own { allowed as u64 } else { u64::MAX }];
    let mut cap = [0u64];
    node.all_reduce_into(&quota[..], &mut cap[..], SystemOperation::min());
    let cores = union.iter().map(|w| w.count_ones() as u64).sum::<u64>().min(cap[0]);
    cores.max(1) as usize
}

/// Polls `request` until it completes, yielding the core between polls.
fn wait_yielding<'a, D: ?Sized, S: Scope<'a>>(mut request: Request<'a, D, S>) {
    loop {
        match request.test() {
            Ok(_) => return,
            Err(pending) => {
                request = pending;
                std::thread::yield_now();
            }
        }
    }
}

impl Communicator for Mpi {
    fn rank(&self) -> usize {
        self.world.rank() as usize
    }
    fn size(&self) -> usize {
        self.world.size() as usize
    }
    fn sum_in_place(&self, values: &mut [f64]) {
        if self.size() > 1 && !values.is_empty() {
            let send = values.to_vec();
            if self.yielding {
                mpi::request::scope(|scope| {
                    wait_yielding(self.world.immediate_all_reduce_into(
                        scope,
                        &send[..],
                        values,
                        SystemOperation::sum(),
                    ));
                });
            } else {
                self.world.all_reduce_into(&send[..], values, SystemOperation::sum());
            }
        }
    }
    fn send(&self, to: usize, values: &[f64]) {
        let process = self.world.process_at_rank(to as i32);
        if self.yielding {
            mpi::request::scope(|scope| wait_yielding(process.immediate_send(scope, values)));
        } else {
            process.send(values);
        }
    }
    fn receive(&self, from: usize) -> Vec<f64> {
        let process = self.world.process_at_rank(from as i32);
        if self.yielding {
            loop {
                if let Some(message) = process.immediate_matched_probe() {
                    return message.matched_receive_vec::<f64>().0;
                }
                std::thread::yield_now();
            }
        }
        process.receive_vec::<f64>().0
    }
    fn broadcast_bytes(&self, bytes: &mut Vec<u8>) {
        if self.size() == 1 {
            return;
        }
        let mut len = [bytes.len() as u64];
        self.broadcast_into(&mut len[..]);
        bytes.resize(len[0] as usize, 0);
        self.broadcast_into(&mut bytes[..]);
    }
}
