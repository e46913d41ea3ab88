//! End-to-end smoke tests: real processes, real files, no mocks.
//!
//! The single integration-test binary of this crate (each binary links the whole stack, so more
//! would multiply link time), in one module per topic. Binaries of other packages come from
//! `cargo build --workspace`.

mod architecture;
mod browser;
mod calculix;
mod cli;
mod common;
mod discretisation;
mod engine;
mod first_use;
mod limits;
mod meshes;
mod metrics;
mod python;
mod resilience;
mod security;
mod service;
mod slurm;
mod surface_audit;
mod to_accuracy;
mod toolchain;
mod worker_cli;
