//! glissade-worker: the solver's edges: the MPI communicator (`mpi_comm`, feature `mpi`), field
//! output (`io`) and a worker pool of the coordinator (`pool`). The solver itself is
//! `glissade_solver`; the scene, the solution store and the study engine live in `glissade_core`.

pub mod io;
#[cfg(feature = "mpi")]
pub mod mpi_comm;
pub mod pool;
