//! The `glissade.v1.User` service: thin — converts (`convert.rs`), calls the coordinator off the
//! async threads (its commits wait for the disk), converts back.

use std::pin::Pin;
use std::sync::Arc;

use glissade_proto::StudyId;
use glissade_proto::v1::user_server::User;
use glissade_proto::v1::{self, SolutionChunk, StudyEvent};
use tokio::sync::{broadcast, mpsc};
use tokio_stream::Stream;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status};

use crate::convert::{self, SurfaceQuery};
use crate::coordinator::{CoordError, Coordinator, EventKind, SolutionSelector, Submission};

/// Studies in a page of ListStudies when the request does not say, and the most it may ask.
const LIST_PAGE: usize = 200;
const LIST_PAGE_MAX: usize = 1000;

/// The studies a ListStudies page holds for the `limit` asked.
fn page_limit(asked: u32) -> usize {
    match asked {
        0 => LIST_PAGE,
        n => (n as usize).min(LIST_PAGE_MAX),
    }
}

type Streamed<T> = Pin<Box<dyn Stream<Item = Result<T, Status>> + Send>>;

/// Runs a coordinator call on tokio's blocking pool.
pub async fn blocking<T: Send + 'static>(
    f: impl FnOnce() -> Result<T, CoordError> + Send + 'static,
) -> Result<T, Status> {
    match tokio::task::spawn_blocking(f).await {
        Ok(result) => result.map_err(convert::status),
        Err(e) => {
            tracing::error!(error = %e, "coordinator call panicked");
            Err(Status::internal("coordinator call failed; see the coordinator's log"))
        }
    }
}

pub struct UserService {
    pub coordinator: Arc<Coordinator>,
}

#[tonic::async_trait]
impl User for UserService {
    async fn submit_study(
        &self,
        request: Request<v1::SubmitStudyRequest>,
    ) -> Result<Response<v1::SubmitStudyReply>, Status> {
        let submission = Submission::try_from(request.into_inner())?;
        let c = self.coordinator.clone();
        let (id, points, scene_hash) = blocking(move || c.submit(submission)).await?;
        Ok(Response::new(v1::SubmitStudyReply { study_id: id.0, points, scene_hash }))
    }

    type WatchStudyStream = Streamed<StudyEvent>;

    async fn watch_study(
        &self,
        request: Request<v1::WatchStudyRequest>,
    ) -> Result<Response<Self::WatchStudyStream>, Status> {
        let id = StudyId(request.into_inner().study_id);
        // (the replay's eta histories are read from the store)
        let c = self.coordinator.clone();
        let (replay, receiver) = blocking(move || c.watch(id)).await?;
        let (tx, rx) = mpsc::channel(256);
        let coordinator = self.coordinator.clone();
        tokio::spawn(forward_events(coordinator, id, replay, receiver, tx));
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }

    async fn get_study(&self, request: Request<v1::GetStudyRequest>) -> Result<Response<v1::Study>, Status> {
        let r = request.into_inner();
        let (id, c) = (StudyId(r.study_id), self.coordinator.clone());
        // (its points' eta histories are read from the store)
        let view = match (r.points, r.without_eta_histories) {
            (true, false) => blocking(move || c.study_with_histories(id)).await?,
            (true, true) => blocking(move || c.study(id, true)).await?,
            (false, _) => c.study(id, false)?,
        };
        let mut study = convert::study(&view);
        if r.scene {
            study.scene = view.record.scene.clone();
        }
        Ok(Response::new(study))
    }

    async fn list_studies(
        &self,
        request: Request<v1::ListStudiesRequest>,
    ) -> Result<Response<v1::ListStudiesReply>, Status> {
        let r = request.into_inner();
        // a page, not the whole list: thousands of studies with long labels would pass a
        // client's message limit (issue 48)
        let (page, more) = self.coordinator.studies_page(StudyId(r.after), page_limit(r.limit));
        let next_after = if more { page.last().map_or(0, |v| v.record.id.0) } else { 0 };
        Ok(Response::new(v1::ListStudiesReply { studies: page.iter().map(convert::study).collect(), next_after }))
    }

    async fn cancel_study(&self, request: Request<v1::CancelStudyRequest>) -> Result<Response<v1::Study>, Status> {
        let id = StudyId(request.into_inner().study_id);
        let c = self.coordinator.clone();
        let view = blocking(move || c.cancel(id)).await?;
        Ok(Response::new(convert::study(&view)))
    }

    async fn retry_failed(
        &self,
        request: Request<v1::RetryFailedRequest>,
    ) -> Result<Response<v1::RetryFailedReply>, Status> {
        let id = StudyId(request.into_inner().study_id);
        let c = self.coordinator.clone();
        let (requeued, (kept, kept_because), view) = blocking(move || c.retry_failed(id)).await?;
        Ok(Response::new(v1::RetryFailedReply { requeued, study: Some(convert::study(&view)), kept, kept_because }))
    }

    async fn purge_pool(&self, request: Request<v1::PurgePoolRequest>) -> Result<Response<v1::PurgePoolReply>, Status> {
        let pool = request.into_inner().pool_id;
        if pool.is_empty() || pool.len() > 256 {
            return Err(Status::invalid_argument("give the pool's id, as it registered (1 to 256 bytes)"));
        }
        let c = self.coordinator.clone();
        let purged = blocking(move || c.purge_pool(&pool)).await?;
        Ok(Response::new(v1::PurgePoolReply { purged: purged as u64 }))
    }

    async fn query_surface(
        &self,
        request: Request<v1::QuerySurfaceRequest>,
    ) -> Result<Response<v1::QuerySurfaceReply>, Status> {
        let q = SurfaceQuery::try_from(request.into_inner())?;
        let c = self.coordinator.clone();
        let surface = blocking(move || c.surface(q.source, &q.fixed, &q.qoi, &q.predict_at)).await?;
        Ok(Response::new(convert::surface(surface)))
    }

    type FetchSolutionStream = Streamed<SolutionChunk>;

    async fn fetch_solution(
        &self,
        request: Request<v1::FetchSolutionRequest>,
    ) -> Result<Response<Self::FetchSolutionStream>, Status> {
        let selector = SolutionSelector::try_from(request.into_inner())?;
        let c = self.coordinator.clone();
        let bytes = blocking(move || c.solution_bytes(&selector)).await?;
        let chunks: Vec<_> = glissade_proto::chunks(&bytes).map(Ok).collect();
        Ok(Response::new(Box::pin(tokio_stream::iter(chunks))))
    }
}

/// Sends the replay, then the study's live events, until the study ends or the client leaves.
/// A watcher too slow for the broadcast buffer gets a fresh replay instead of a silent gap.
async fn forward_events(
    coordinator: Arc<Coordinator>,
    id: StudyId,
    mut replay: Vec<crate::coordinator::Event>,
    mut receiver: broadcast::Receiver<crate::coordinator::Event>,
    tx: mpsc::Sender<Result<StudyEvent, Status>>,
) {
    loop {
        for event in replay.drain(..) {
            let ended = event.kind == EventKind::StudyEnded;
            if tx.send(Ok(convert::event(&event))).await.is_err() || ended {
                return;
            }
        }
        let received = tokio::select! {
            r = receiver.recv() => r,
            _ = coordinator.stopped() => {
                let _ = tx.send(Err(Status::unavailable("the coordinator is stopping; watch again later"))).await;
                return;
            }
        };
        match received {
            Ok(event) if event.study == id => {
                let ended = event.kind == EventKind::StudyEnded;
                if tx.send(Ok(convert::event(&event))).await.is_err() || ended {
                    return;
                }
            }
            Ok(_) => {}
            Err(broadcast::error::RecvError::Lagged(missed)) => {
                tracing::debug!(study = %id, missed, "watcher lagged; replaying");
                let c = coordinator.clone();
                match blocking(move || c.watch(id)).await {
                    Ok((again, fresh)) => {
                        replay = again;
                        receiver = fresh;
                    }
                    Err(status) => {
                        let _ = tx.send(Err(status)).await;
                        return;
                    }
                }
            }
            Err(broadcast::error::RecvError::Closed) => return,
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_page_holds_the_default_or_what_is_asked_up_to_the_most() {
        assert_eq!(super::page_limit(0), super::LIST_PAGE);
        assert_eq!(super::page_limit(7), 7);
        assert_eq!(super::page_limit(u32::MAX), super::LIST_PAGE_MAX);
    }
}
