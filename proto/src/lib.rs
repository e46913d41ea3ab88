//! The gRPC contract of glissade (generated) and the small domain types both ends share.

pub mod domain;

pub use domain::{IdParseError, ParameterError, ParameterVector, PointId, StudyId};

/// Generated code of package `glissade.v1`.
pub mod v1 {
    tonic::include_proto!("glissade.v1");
}
