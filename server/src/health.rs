//! The `glissade.v1.Health` service: tells clients whether the coordinator can take work (its
//! database can write) and which version it is.

use std::sync::Arc;

use glissade_proto::v1::health_server::Health;
use glissade_proto::v1::{HealthReply, HealthRequest};
use tonic::{Request, Response, Status};

use crate::coordinator::Coordinator;

/// Status string the proto documents for a coordinator that accepts work.
pub const SERVING: &str = "SERVING";
/// ... and for one whose database cannot write.
pub const NOT_SERVING: &str = "NOT_SERVING";

pub struct HealthService {
    pub coordinator: Arc<Coordinator>,
}

#[tonic::async_trait]
impl Health for HealthService {
    async fn check(&self, _request: Request<HealthRequest>) -> Result<Response<HealthReply>, Status> {
        let (status, detail) = match self.coordinator.store_failure() {
            None => (SERVING, String::new()),
            Some(cause) => (NOT_SERVING, cause),
        };
        Ok(Response::new(HealthReply {
            status: status.to_owned(),
            version: env!("CARGO_PKG_VERSION").to_owned(),
            detail,
        }))
    }
}
