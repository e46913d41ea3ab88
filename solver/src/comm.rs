//! The communicator seam: the only way the solver core talks across processes.
//!
//! The numerics call these few operations; [`Serial`] makes a one-process run the P = 1 case of
//! the same code, `glissade_worker::mpi_comm::Mpi` runs it over MPI ranks (rsmpi). Every sum
//! the solver reduces has at most one non-zero contribution per entry, or two (the two sides of
//! an interface), so results do not depend on the reduction order: P = 1, 2, 3, ... give
//! bitwise identical iterates.

use std::collections::BTreeMap;

/// What the solver needs from a group of processes.
pub trait Communicator {
    fn rank(&self) -> usize;
    fn size(&self) -> usize;
    /// Element-wise sum over all ranks, in place on every rank.
    fn sum_in_place(&self, values: &mut [f64]);
    fn send(&self, to: usize, values: &[f64]);
    fn receive(&self, from: usize) -> Vec<f64>;
    /// Broadcasts rank 0's bytes to every rank.
    fn broadcast_bytes(&self, bytes: &mut Vec<u8>);
}

/// One process: every operation is the identity.
#[derive(Debug, Default, Clone, Copy)]
pub struct Serial;

impl Communicator for Serial {
    fn rank(&self) -> usize {
        0
    }
    fn size(&self) -> usize {
        1
    }
    fn sum_in_place(&self, _values: &mut [f64]) {}
    fn send(&self, to: usize, _values: &[f64]) {
        panic!("serial communicator has no rank {to} to send to");
    }
    fn receive(&self, from: usize) -> Vec<f64> {
        panic!("serial communicator has no rank {from} to receive from");
    }
    fn broadcast_bytes(&self, _bytes: &mut Vec<u8>) {}
}

/// Exchanges one message with each neighbour rank (the neighbour relation must be symmetric:
/// both sides list each other, possibly with an empty message). Pairs are served in increasing
/// neighbour order, the lower rank sending first, which cannot deadlock.
pub fn exchange(comm: &dyn Communicator, outgoing: BTreeMap<usize, Vec<f64>>) -> BTreeMap<usize, Vec<f64>> {
    let me = comm.rank();
    let mut incoming = BTreeMap::new();
    for (&q, message) in &outgoing {
        if me < q {
            comm.send(q, message);
            incoming.insert(q, comm.receive(q));
        } else {
            incoming.insert(q, comm.receive(q));
            comm.send(q, message);
        }
    }
    incoming
}
