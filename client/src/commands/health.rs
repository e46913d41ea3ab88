//! `glissade health`: is the coordinator up, and which version.

use anyhow::{Result, anyhow, bail};
use glissade_cli::outln;
use glissade_proto::v1::HealthRequest;
use glissade_proto::v1::health_client::HealthClient;

use crate::{Server, connect};

pub(crate) async fn health(server: &Server, json: bool) -> Result<()> {
    let channel = connect(server).await?;
    let reply = HealthClient::new(channel)
        .check(HealthRequest {})
        .await
        .map_err(|status| anyhow!("health check at {server} failed: {} ({:?})", status.message(), status.code()))?
        .into_inner();
    if json {
        let value = serde_json::json!({
            "server": server.url,
            "status": reply.status,
            "version": reply.version,
            "detail": reply.detail,
        });
        outln!("{value}");
    } else {
        outln!("status:  {}", reply.status);
        outln!("version: {}", reply.version);
    }
    if reply.status != "SERVING" {
        bail!("the coordinator at {server} is not serving: {}", reply.detail);
    }
    Ok(())
}
