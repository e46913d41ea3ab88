//! glissade-worker: the LATIN solver core (pure computation) and its edges.
//!
//! Layout: `element`, `mesh`, `sparse` (discretisation); `scene` and `model` (what is solved);
//! `latin` (the iterative solver) and `monolithic` (the reference); `io` (solution files,
//! field output) and `run` (one solve, for the CLI and the workers) at the edge; `study` (the
//! multiparametric strategy: parameter space, solution store, warm starts, ordering) above `run`.

pub mod comm;
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
pub mod sparse;
