//! glissade-worker: the LATIN solver (pure computation) and its edges.
//!
//! Layout: `element`, `mesh`, `gmsh`, `sparse`, `newmark` (discretisation); `model` (the
//! decomposed problem of one design point, from a `glissade_core::scene::Scene`); `latin` (the
//! iterative solver), with `comm` (the communicator seam: serial or MPI); `monolithic` and
//! `explicit` (independent references); `run` (one solve, for the CLI and the pools), `refine`
//! (a point on a ladder of time steps and meshes), `io` (solution files, field output) and
//! `pool` (a worker pool of the coordinator) at the edge. The scene, the solution store and the
//! study engine (parameter space, warm starts, ordering) live in `glissade_core`.

pub mod comm;
pub mod contact_activity;
pub mod element;
pub mod explicit;
pub mod gmsh;
pub mod io;
pub mod latin;
pub mod mesh;
pub mod model;
pub mod monolithic;
pub mod newmark;
pub mod pool;
pub mod refine;
pub mod run;
pub mod search_direction;
pub mod sparse;
