//! Smallest real MPI program: proves rsmpi links against the system MPI and `mpiexec` runs it.
//!
//! Every rank contributes `rank + 1`; rank 0 prints `size=N sum=S` (S = N(N+1)/2).

use std::process::ExitCode;

use mpi::collective::SystemOperation;
use mpi::traits::*;

fn main() -> ExitCode {
    let Some(universe) = mpi::initialize() else {
        eprintln!("error: MPI was already initialised in this process");
        return ExitCode::FAILURE;
    };
    let world = universe.world();
    let rank = world.rank();
    let mut sum = 0_i64;
    world.all_reduce_into(&(i64::from(rank) + 1), &mut sum, SystemOperation::sum());
    if rank == 0 {
        println!("size={} sum={sum}", world.size());
    }
    ExitCode::SUCCESS
}
