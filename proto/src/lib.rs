//! The gRPC contract of glissade (generated) and the small domain types both ends share.

pub mod accuracy;
pub mod auth;
pub mod chunks;
pub mod contact;
pub mod domain;
pub mod json;

pub use chunks::{Assembler, CHUNK_BYTES, ChunkError, chunks};
pub use domain::{IdParseError, PointId, StudyId, now_unix_ms};
use glissade_core::point::{DesignPoint, ParameterError};

/// Generated code of package `glissade.v1`: the API (`glissade.proto`) and the message rank 0
/// of a pool sends its other ranks (`ranks.proto`).
pub mod v1 {
    tonic::include_proto!("glissade.v1");
    // their serde: proto3's JSON mapping (build.rs; json.rs says how it reads)
    include!(concat!(env!("OUT_DIR"), "/glissade.v1.serde.rs"));
}

/// The encoded protobuf descriptors of `glissade.v1`, for server reflection.
pub const FILE_DESCRIPTOR_SET: &[u8] = tonic::include_file_descriptor_set!("glissade_descriptor");

/// A design point from the wire: checked here, once (core's rule), and trusted after.
impl TryFrom<v1::ParameterVector> for DesignPoint {
    type Error = ParameterError;

    fn try_from(message: v1::ParameterVector) -> Result<Self, Self::Error> {
        Self::try_from(message.values)
    }
}

impl From<DesignPoint> for v1::ParameterVector {
    fn from(point: DesignPoint) -> Self {
        Self { values: point.into() }
    }
}
