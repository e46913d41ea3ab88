//! The `glissade.v1.Pool` service: what `glissade-worker pool` calls. Thin, like `user.rs`; the
//! stream handling (long-polled leases, chunked solutions) is the only logic of its own here.

use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use glissade_proto::v1::pool_server::Pool;
use glissade_proto::v1::{self, LeaseMessage, complete_point_message::Body as CompleteBody, lease_message::Body};
use glissade_proto::{Assembler, PointId, StudyId};
use tokio_stream::{Stream, StreamExt};
use tonic::{Request, Response, Status, Streaming};

use crate::convert::{self, Invalid, Registration};
use crate::coordinator::{Completion, Coordinator, Failure, now_unix_ms};
use crate::metrics::Metrics;
use crate::user::blocking;

/// Longest a LeasePoint call waits for work before answering NoWork.
const MAX_WAIT: Duration = Duration::from_secs(30);

pub struct PoolService {
    pub coordinator: Arc<Coordinator>,
    /// For ids assigned to pools that bring none.
    pub next_pool: AtomicU64,
    /// Each delivered solve goes into the solve histograms.
    pub metrics: Arc<Metrics>,
}

impl PoolService {
    pub fn new(coordinator: Arc<Coordinator>, metrics: Arc<Metrics>) -> Self {
        Self { coordinator, next_pool: AtomicU64::new(1), metrics }
    }
}

#[tonic::async_trait]
impl Pool for PoolService {
    async fn register_pool(
        &self,
        request: Request<v1::RegisterPoolRequest>,
    ) -> Result<Response<v1::RegisterPoolReply>, Status> {
        let Registration { id, info } = Registration::try_from(request.into_inner())?;
        // Unique across restarts too: the start time in the id.
        let id = id
            .unwrap_or_else(|| format!("pool-{:x}-{}", now_unix_ms(), self.next_pool.fetch_add(1, Ordering::Relaxed)));
        self.coordinator.register_pool(id.clone(), info);
        let lease_ms = self.coordinator.config().lease.as_millis() as u64;
        // A quarter of the lease keeps it alive through a missed beat; at most 2 s, because the
        // beats also carry the solve's progress to watchers.
        let heartbeat_ms = (lease_ms / 4).clamp(50, 2000);
        Ok(Response::new(v1::RegisterPoolReply { pool_id: id, lease_ms, heartbeat_ms }))
    }

    type LeasePointStream = Pin<Box<dyn Stream<Item = Result<LeaseMessage, Status>> + Send>>;

    async fn lease_point(
        &self,
        request: Request<v1::LeasePointRequest>,
    ) -> Result<Response<Self::LeasePointStream>, Status> {
        let r = request.into_inner();
        let pool = convert::pool_id(&r.pool_id)?;
        let wait = Duration::from_millis(r.wait_ms).min(MAX_WAIT);
        let until = tokio::time::Instant::now() + wait;
        let c = &self.coordinator;
        let grant = loop {
            // Enabled before looking, so a submission between the look and the wait still wakes us.
            let notified = c.work_notified();
            tokio::pin!(notified);
            notified.as_mut().enable();
            let (c2, p2) = (c.clone(), pool.clone());
            if let Some(grant) = blocking(move || c2.lease(&p2)).await? {
                break grant;
            }
            if tokio::time::Instant::now() >= until {
                let no_work = LeaseMessage { body: Some(Body::NoWork(v1::NoWork {})) };
                return Ok(Response::new(Box::pin(tokio_stream::once(Ok(no_work)))));
            }
            // Leases of stopped pools expire while we wait: look again at least every lease/4.
            let tick = (c.config().lease / 4).max(Duration::from_millis(20));
            tokio::select! {
                _ = &mut notified => {}
                _ = tokio::time::sleep_until(until) => {}
                _ = tokio::time::sleep(tick) => {}
                _ = c.stopped() => return Err(Status::unavailable("the coordinator is stopping; retry later")),
            }
        };
        let bytes = match &grant.init {
            Some(warm) => {
                let (c2, warm) = (c.clone(), warm.clone());
                match blocking(move || c2.warm_start_bytes(&warm)).await {
                    Ok(b) => b,
                    Err(status) => {
                        // Give the point back rather than let the pool solve it from a wrong state.
                        let (c2, p2) = (c.clone(), pool.clone());
                        let (lease, study, point) = (grant.lease_id, grant.study, grant.point);
                        let _ = blocking(move || c2.release(&p2, lease, study, point)).await;
                        return Err(status);
                    }
                }
            }
            None => Vec::new(),
        };
        let lease = v1::Lease {
            lease_id: grant.lease_id,
            study_id: grant.study.0,
            point_id: grant.point.0,
            parameters: grant.parameters.into(),
            scene: grant.scene_text,
            scene_hash: grant.scene_hash,
            tolerance: grant.tolerance,
            max_iterations: grant.max_iterations,
            deadline_unix_ms: grant.deadline_unix_ms,
            init_from: grant.init.as_ref().map(|w| convert::origin(&w.origin)),
            init_bytes: bytes.len() as u64,
            meshes: grant
                .meshes
                .into_iter()
                .map(|m| v1::MeshRef { file: m.file, sha256: m.sha256, bytes: m.bytes })
                .collect(),
        };
        let mut messages = vec![Ok(LeaseMessage { body: Some(Body::Lease(lease)) })];
        messages.extend(glissade_proto::chunks(&bytes).map(|c| Ok(LeaseMessage { body: Some(Body::InitChunk(c)) })));
        Ok(Response::new(Box::pin(tokio_stream::iter(messages))))
    }

    async fn heartbeat(&self, request: Request<v1::HeartbeatRequest>) -> Result<Response<v1::HeartbeatReply>, Status> {
        let r = request.into_inner();
        let pool = convert::pool_id(&r.pool_id)?;
        let progress: Vec<(u64, u64, f64)> =
            r.progress.iter().map(|p| (p.lease_id, p.iterations, p.error_indicator)).collect();
        let deadlines = self.coordinator.heartbeat(&pool, &r.lease_ids, &progress);
        let leases = r
            .lease_ids
            .iter()
            .zip(deadlines)
            .map(|(&lease_id, d)| v1::LeaseStatus {
                lease_id,
                valid: d.is_some(),
                deadline_unix_ms: d.map_or(0, |d| d.0),
                stop: d.is_some_and(|d| d.1),
            })
            .collect();
        Ok(Response::new(v1::HeartbeatReply { leases }))
    }

    async fn complete_point(
        &self,
        request: Request<Streaming<v1::CompletePointMessage>>,
    ) -> Result<Response<v1::CompletePointReply>, Status> {
        let mut stream = request.into_inner();
        let header = match stream.next().await {
            Some(Ok(v1::CompletePointMessage { body: Some(CompleteBody::Header(h)) })) => h,
            Some(Ok(_)) => return Err(Invalid("the first message of CompletePoint must be the header".into()).into()),
            Some(Err(status)) => return Err(status),
            None => {
                return Err(Invalid("CompletePoint stream is empty: send the header, then the solution".into()).into());
            }
        };
        let announced = header.solution_bytes;
        let completion = Completion::try_from(header)?;
        // Refuse before reading megabytes for a point the pool does not hold.
        self.coordinator.check_held(&completion.pool, completion.lease_id, completion.study, completion.point)?;
        let limit = self.coordinator.config().max_solution_bytes;
        let mut assembler = Assembler::new(announced, limit).map_err(|e| Invalid(e.to_string()))?;
        while let Some(message) = stream.next().await {
            match message? {
                v1::CompletePointMessage { body: Some(CompleteBody::Chunk(chunk)) } => {
                    assembler.push(chunk).map_err(|e| Invalid(e.to_string()))?;
                }
                _ => return Err(Invalid("CompletePoint: only solution chunks may follow the header".into()).into()),
            }
        }
        let bytes = assembler.finish().map_err(|e| Invalid(e.to_string()))?;
        let c = self.coordinator.clone();
        let point = blocking(move || c.complete(completion, bytes)).await?;
        self.metrics.solved(&point);
        Ok(Response::new(v1::CompletePointReply { point: Some(convert::point(&point)) }))
    }

    async fn fail_point(&self, request: Request<v1::FailPointRequest>) -> Result<Response<v1::PointStatus>, Status> {
        let failure = Failure::try_from(request.into_inner())?;
        let c = self.coordinator.clone();
        let point = blocking(move || c.fail(failure)).await?;
        Ok(Response::new(convert::point(&point)))
    }

    async fn release_point(
        &self,
        request: Request<v1::ReleasePointRequest>,
    ) -> Result<Response<v1::PointStatus>, Status> {
        let r = request.into_inner();
        let pool = convert::pool_id(&r.pool_id)?;
        let c = self.coordinator.clone();
        let (lease, study, point) = (r.lease_id, StudyId(r.study_id), PointId(r.point_id));
        let point = blocking(move || c.release(&pool, lease, study, point)).await?;
        Ok(Response::new(convert::point(&point)))
    }

    type FetchMeshStream = Pin<Box<dyn Stream<Item = Result<v1::SolutionChunk, Status>> + Send>>;

    async fn fetch_mesh(
        &self,
        request: Request<v1::FetchMeshRequest>,
    ) -> Result<Response<Self::FetchMeshStream>, Status> {
        let sha256 = request.into_inner().sha256;
        if sha256.len() != 64 || !sha256.bytes().all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b)) {
            return Err(Invalid("sha256: 64 lowercase hex digits".into()).into());
        }
        let c = self.coordinator.clone();
        let bytes = blocking(move || c.mesh_bytes(&sha256)).await?;
        let chunks: Vec<_> = glissade_proto::chunks(&bytes).map(Ok).collect();
        Ok(Response::new(Box::pin(tokio_stream::iter(chunks))))
    }
}
