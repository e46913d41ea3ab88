//! Library half of the `glissade` CLI: what the binary draws, formats and counts, apart from its
//! conversation with the coordinator (so that it is testable without a server).

pub mod connect;
pub mod fields;
pub mod names;
pub mod output;
pub mod progress;
pub mod surface;
