//! The MPI communicator: the solver's [`Communicator`] seam over MPI ranks (rsmpi); the serial
//! one and the trait live in `glissade_solver::comm`.

use glissade_solver::comm::Communicator;
use mpi::collective::SystemOperation;
use mpi::point_to_point::{Destination, Source};
use mpi::topology::{Communicator as _, SimpleCommunicator};
use mpi::traits::{CommunicatorCollectives, Root};

/// MPI ranks of a communicator (usually the world).
pub struct Mpi {
    pub world: SimpleCommunicator,
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
            self.world.all_reduce_into(&send[..], values, SystemOperation::sum());
        }
    }
    fn send(&self, to: usize, values: &[f64]) {
        self.world.process_at_rank(to as i32).send(values);
    }
    fn receive(&self, from: usize) -> Vec<f64> {
        self.world.process_at_rank(from as i32).receive_vec::<f64>().0
    }
    fn broadcast_bytes(&self, bytes: &mut Vec<u8>) {
        if self.size() == 1 {
            return;
        }
        let root = self.world.process_at_rank(0);
        let mut len = [bytes.len() as u64];
        root.broadcast_into(&mut len[..]);
        bytes.resize(len[0] as usize, 0);
        root.broadcast_into(&mut bytes[..]);
    }
}
