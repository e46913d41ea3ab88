//! glissade-core: what the solver, the workers, the coordinator and the CLI share, without any of
//! their machinery (no MPI, HDF5, faer, tokio or tonic).
//!
//! - [`scene`]: what is solved (bodies, interfaces, loads, QoIs, declared parameters);
//! - [`contact`]: what a frictional contact did while it slid (evidence beside an answer);
//! - [`field`]: interface force and velocity fields, the solutions a study stores;
//! - [`io`]: the solution file format and atomic, durable file writes;
//! - [`point`]: a design point, the one checked form of a study's parameter values;
//! - [`refine`]: refinement ladders (dt / 2, h / 2): the refined scene and Richardson's estimate;
//! - [`study`]: the multiparametric strategy (design points, parameter space, solution store,
//!   warm starts, ordering) and the study engine that both the local study and the coordinator run;
//! - [`text`]: bounded, single-line text for messages that quote user input.

pub mod accuracy;
pub mod check;
pub mod contact;
pub mod field;
pub mod gmsh;
pub mod io;
pub mod point;
pub mod refine;
pub mod scene;
pub mod study;
pub mod text;
