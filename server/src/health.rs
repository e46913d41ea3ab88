//! The `glissade.v1.Health` service: tells clients the coordinator is up and which version it is.

use glissade_proto::v1::health_server::Health;
use glissade_proto::v1::{HealthReply, HealthRequest};
use tonic::{Request, Response, Status};

/// Status string the proto documents for a coordinator that accepts work.
pub const SERVING: &str = "SERVING";

/// Stateless: if the process answers at all, it is serving.
#[derive(Debug, Default)]
pub struct HealthService;

#[tonic::async_trait]
impl Health for HealthService {
    async fn check(&self, _request: Request<HealthRequest>) -> Result<Response<HealthReply>, Status> {
        Ok(Response::new(HealthReply { status: SERVING.to_owned(), version: env!("CARGO_PKG_VERSION").to_owned() }))
    }
}
