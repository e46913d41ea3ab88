//! glissade-solver: the LATIN solver, pure computation (no MPI, HDF5 or network).
//!
//! Layout: `element`, `mesh`, `gmsh`, `sparse`, `newmark` (discretisation); `search_direction`
//! and `model` (the decomposed problem of one design point, from a
//! `glissade_core::scene::Scene`); `latin` (the iterative solver), with `comm` (the communicator
//! seam: [`comm::Serial`] here, MPI in glissade-worker); `monolithic` and `explicit`
//! (independent references); `run` (one solve, for the CLI and the pools) and `refine` (a point
//! on a ladder of time steps and meshes). The scene, the solution store and the study engine live
//! in `glissade_core`; MPI, field output and the worker pool in `glissade_worker`.

pub mod accuracy;
pub mod comm;
pub mod contact_activity;
pub mod element;
pub mod explicit;
pub mod gmsh;
pub mod latin;
pub mod mesh;
pub mod model;
pub mod monolithic;
pub mod newmark;
pub mod profile;
pub mod refine;
pub mod run;
pub mod search_direction;
pub mod sparse;
