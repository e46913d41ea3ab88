//! A pool with a FAKE, INSTANT "solver": it leases points from a real coordinator and completes
//! each at once with a small synthetic solution file of the right scene and point (one interface
//! node: about 5 kB) and the QoIs and eta history its caller makes up, so every rule of the
//! coordinator runs as for real solutions. For the service's benchmark (src/bin/service-bench.rs)
//! and for tests of what a large study looks like (its page's weight) without solving it.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Instant;

use glissade_core::field::{InterfaceField, InterfaceSolution, StageSolution};
use glissade_core::io::solution_file::{self, SolutionMeta};
use glissade_core::point::DesignPoint;
use glissade_core::scene::Scene;
use glissade_proto::auth::{Token, WithToken};
use glissade_proto::v1::pool_client::PoolClient;
use glissade_proto::v1::{self, complete_point_message, lease_message};

pub type Error = Box<dyn std::error::Error + Send + Sync>;

/// What a point "solved" to: its QoIs and its eta after each iteration.
pub struct Answer {
    pub qoi: BTreeMap<String, f64>,
    pub history: Vec<f64>,
}

/// Makes up a leased point's answer from its parameters.
pub type Answering = Arc<dyn Fn(&BTreeMap<String, f64>) -> Answer + Send + Sync>;

/// Latencies of one pool (milliseconds): leases, completions; and when it completed its last point.
pub type PoolRun = (Vec<f64>, Vec<f64>, Option<Instant>);

/// A converged solution file of `scene` at the lease's point with one interface node.
pub fn solution(scene: &Scene, hash: &str, lease: &v1::Lease, answer: &Answer) -> Result<Vec<u8>, Error> {
    let point = DesignPoint::try_from(lease.parameters.clone())?;
    let parameters = scene.parameter_values(&point)?;
    let len = scene.time.steps * scene.dimension;
    let solution = InterfaceSolution {
        static_stage: None,
        dynamic: StageSolution { interfaces: vec![InterfaceField::zeros(2, len)] },
    };
    let meta = SolutionMeta {
        solver_version: env!("CARGO_PKG_VERSION").into(),
        scene_hash: hash.into(),
        dimension: scene.dimension,
        time_steps: scene.time.steps,
        parameters,
        converged: true,
        error_indicator: lease.tolerance / 2.0,
        iterations: answer.history.len().max(1),
        tolerance: lease.tolerance,
        qoi: answer.qoi.clone(),
    };
    let mut bytes = Vec::new();
    solution_file::write_to(&mut bytes, &solution, &meta)?;
    Ok(bytes)
}

/// One pool: lease, complete at once, until no work is left (a lease that waits 300 ms for nothing).
/// `token`: the pool token of a coordinator that asks for one.
pub async fn pool(
    url: String,
    token: Option<String>,
    id: String,
    scene: Scene,
    answering: Answering,
) -> Result<PoolRun, Error> {
    let hash = scene.content_hash();
    let token = token.map(|t| Token::parse(&t, "the pool token")).transpose()?;
    let channel = tonic::transport::Endpoint::from_shared(url)?.connect().await?;
    let mut pool = PoolClient::with_interceptor(channel, WithToken::new(token.as_ref()));
    pool.register_pool(v1::RegisterPoolRequest {
        pool_id: id.clone(),
        ranks: 1,
        host: "synthetic".into(),
        solver_version: env!("CARGO_PKG_VERSION").into(),
    })
    .await?;
    let (mut lease_ms, mut complete_ms, mut last) = (Vec::new(), Vec::new(), None);
    loop {
        let t = Instant::now();
        let mut stream =
            pool.lease_point(v1::LeasePointRequest { pool_id: id.clone(), wait_ms: 300 }).await?.into_inner();
        let lease = match stream.message().await? {
            Some(v1::LeaseMessage { body: Some(lease_message::Body::Lease(l)) }) => l,
            _ => return Ok((lease_ms, complete_ms, last)),
        };
        while stream.message().await?.is_some() {}
        lease_ms.push(t.elapsed().as_secs_f64() * 1e3);
        let answer = answering(&lease.parameters.clone().into_iter().collect());
        let bytes = solution(&scene, &hash, &lease, &answer)?;
        let t = Instant::now();
        let header = v1::CompletePointHeader {
            pool_id: id.clone(),
            lease_id: lease.lease_id,
            study_id: lease.study_id,
            point_id: lease.point_id,
            converged: true,
            iterations: answer.history.len().max(1) as u64,
            error_indicator: lease.tolerance / 2.0,
            qoi: answer.qoi.clone(),
            wall_seconds: 0.0,
            solution_bytes: bytes.len() as u64,
            eta_history: answer.history.clone(),
            work: answer.history.len().max(1) as f64,
            started_cold: false,
            contact: Vec::new(),
            qoi_largest: Default::default(),
        };
        let mut messages = vec![v1::CompletePointMessage { body: Some(complete_point_message::Body::Header(header)) }];
        messages.extend(
            glissade_proto::chunks(&bytes)
                .map(|c| v1::CompletePointMessage { body: Some(complete_point_message::Body::Chunk(c)) }),
        );
        pool.complete_point(tokio_stream::iter(messages)).await?;
        complete_ms.push(t.elapsed().as_secs_f64() * 1e3);
        last = Some(Instant::now());
    }
}
