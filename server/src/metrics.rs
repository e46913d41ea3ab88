//! `/metrics`: the coordinator in the Prometheus text format (0.0.4), for an operator's
//! Prometheus. Studies, points, the pending queue, leases and pools are counted from the
//! coordinator's state when scraped; solves and requests are counted as they happen.
//!
//! Every label takes its values from a fixed set, so the series stay as many as the code's
//! names: gRPC methods are the ones this server serves (read from the descriptor sets) or
//! `other`, HTTP routes are the router's templates (`/studies/{id}`, not the id) or `other`,
//! statuses are gRPC's 17 codes and HTTP's three-digit statuses.

use std::collections::HashSet;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};

use axum::body::{Body, Bytes};
use axum::extract::{MatchedPath, Request, State};
use axum::http::HeaderMap;
use axum::middleware::Next;
use axum::response::Response;
use http_body::{Frame, SizeHint};
use prometheus_client::collector::Collector;
use prometheus_client::encoding::{DescriptorEncoder, EncodeLabelSet, EncodeMetric};
use prometheus_client::metrics::counter::{ConstCounter, Counter};
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::ConstGauge;
use prometheus_client::metrics::histogram::{Histogram, exponential_buckets};
use prometheus_client::registry::{Registry, Unit};
use prost::Message;

use crate::coordinator::Coordinator;
use crate::records::PointRecord;

/// The `Content-Type` of [`Metrics::render`]'s text.
pub const CONTENT_TYPE: &str = prometheus_client::encoding::prometheus_text::CONTENT_TYPE;

/// The label value of a gRPC method this server does not serve, or of a page it does not have.
const OTHER: &str = "other";

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct GrpcLabels {
    /// `/package.Service/Method`, or [`OTHER`]
    method: String,
    /// the gRPC status code's canonical name (`OK`, `NOT_FOUND`, ...)
    code: &'static str,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct HttpLabels {
    /// the route's template, or [`OTHER`]
    route: String,
    status: u16,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct StartLabels {
    /// `warm` (from a stored solution) or `cold`: warm starts take fewer iterations
    start: &'static str,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct StateLabels {
    state: &'static str,
}

type Histograms = Family<StartLabels, Histogram, fn() -> Histogram>;

/// The coordinator's metrics: one per server, shared by the request layer, the pool service
/// (solves) and the `/metrics` page.
#[derive(Debug)]
pub struct Metrics {
    registry: Registry,
    grpc: Family<GrpcLabels, Counter>,
    http: Family<HttpLabels, Counter>,
    solve_seconds: Histograms,
    solve_iterations: Histograms,
    /// every `/package.Service/Method` this server answers
    grpc_methods: HashSet<String>,
}

impl Metrics {
    pub fn new(coordinator: Arc<Coordinator>) -> Self {
        let mut registry = Registry::with_prefix("glissade");
        let grpc = Family::<GrpcLabels, Counter>::default();
        registry.register("grpc_requests", "gRPC calls answered, by method and status code", grpc.clone());
        let http = Family::<HttpLabels, Counter>::default();
        registry.register(
            "http_requests",
            "HTTP requests (web page, JSON API, /metrics) by route and status",
            http.clone(),
        );
        // 10 ms to 12 h, and 1 to 8192 iterations: a point of `tiny` to the paper's bolted joint
        let solve_seconds: Histograms =
            Family::new_with_constructor(|| Histogram::new(exponential_buckets(0.01, 4.0, 12)));
        registry.register_with_unit(
            "solve_wall",
            "Wall time of each solve a pool delivered (converged or not), cold and warm starts apart",
            Unit::Seconds,
            solve_seconds.clone(),
        );
        let solve_iterations: Histograms =
            Family::new_with_constructor(|| Histogram::new(exponential_buckets(1.0, 2.0, 14)));
        registry.register(
            "solve_iterations",
            "LATIN iterations of each solve a pool delivered, cold and warm starts apart",
            solve_iterations.clone(),
        );
        registry.register_collector(Box::new(Now(coordinator)));
        let grpc_methods = grpc_methods(&[
            glissade_proto::FILE_DESCRIPTOR_SET,
            tonic_health::pb::FILE_DESCRIPTOR_SET,
            tonic_reflection::pb::v1::FILE_DESCRIPTOR_SET,
            tonic_reflection::pb::v1alpha::FILE_DESCRIPTOR_SET,
        ]);
        Self { registry, grpc, http, solve_seconds, solve_iterations, grpc_methods }
    }

    /// Counts a point a pool delivered; an answered point (from a stored solution) was not solved.
    pub fn solved(&self, point: &PointRecord) {
        let Some(result) = point.result.as_ref().filter(|r| !r.answered) else { return };
        let labels = StartLabels { start: if result.started_from.is_some() { "warm" } else { "cold" } };
        self.solve_seconds.get_or_create(&labels).observe(result.wall_seconds);
        self.solve_iterations.get_or_create(&labels).observe(result.iterations as f64);
    }

    /// Every metric, in the Prometheus text format. Counts the coordinator's state under its
    /// lock and reads the database's size: call it off the async threads.
    pub fn render(&self) -> String {
        let mut text = String::new();
        // writing to a String fails only if an encoder does, which ours do not
        if let Err(e) = prometheus_client::encoding::prometheus_text::encode(&mut text, &self.registry) {
            tracing::error!(error = %e, "encoding the metrics");
        }
        text
    }

    fn grpc_method(&self, path: &str) -> String {
        if self.grpc_methods.contains(path) { path.to_owned() } else { OTHER.to_owned() }
    }

    fn grpc_request(&self, method: String, code: tonic::Code) {
        self.grpc.get_or_create(&GrpcLabels { method, code: code_name(code) }).inc();
    }
}

/// `/package.Service/Method` of every method in the encoded descriptor sets.
fn grpc_methods(sets: &[&[u8]]) -> HashSet<String> {
    let mut methods = HashSet::new();
    for set in sets {
        // the sets are compiled in: one that does not decode is a build error, found by the tests
        let Ok(set) = prost_types::FileDescriptorSet::decode(*set) else {
            tracing::error!("a compiled-in descriptor set does not decode: its methods count as other");
            continue;
        };
        for file in &set.file {
            for service in &file.service {
                for method in &service.method {
                    methods.insert(format!("/{}.{}/{}", file.package(), service.name(), method.name()));
                }
            }
        }
    }
    methods
}

/// The canonical name of a gRPC status code (as in grpc's documentation and other servers' metrics).
fn code_name(code: tonic::Code) -> &'static str {
    use tonic::Code::*;
    match code {
        Ok => "OK",
        Cancelled => "CANCELLED",
        Unknown => "UNKNOWN",
        InvalidArgument => "INVALID_ARGUMENT",
        DeadlineExceeded => "DEADLINE_EXCEEDED",
        NotFound => "NOT_FOUND",
        AlreadyExists => "ALREADY_EXISTS",
        PermissionDenied => "PERMISSION_DENIED",
        ResourceExhausted => "RESOURCE_EXHAUSTED",
        FailedPrecondition => "FAILED_PRECONDITION",
        Aborted => "ABORTED",
        OutOfRange => "OUT_OF_RANGE",
        Unimplemented => "UNIMPLEMENTED",
        Internal => "INTERNAL",
        Unavailable => "UNAVAILABLE",
        DataLoss => "DATA_LOSS",
        Unauthenticated => "UNAUTHENTICATED",
    }
}

/// The `grpc-status` of a header or trailer map, if it has one.
fn grpc_status(headers: &HeaderMap) -> Option<tonic::Code> {
    let value = headers.get("grpc-status")?.to_str().ok()?.parse::<i32>().ok()?;
    Some(tonic::Code::from(value))
}

/// The gauges counted from the coordinator at each scrape.
struct Now(Arc<Coordinator>);

impl std::fmt::Debug for Now {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("the coordinator's gauges")
    }
}

impl Collector for Now {
    fn encode(&self, mut encoder: DescriptorEncoder) -> Result<(), std::fmt::Error> {
        let g = self.0.gauges();
        for (name, help, by_state) in
            [("studies", "Studies by state", &g.studies), ("points", "Design points by state", &g.points)]
        {
            let gauge = ConstGauge::new(0i64);
            let mut family = encoder.encode_descriptor(name, help, None, gauge.metric_type())?;
            for (&state, &n) in by_state {
                ConstGauge::new(n as i64).encode(family.encode_family(&StateLabels { state })?)?;
            }
        }
        let gauges = [
            ("queue_pending_points", "Points waiting for a pool, as --max-pending counts them", g.pending),
            ("leases_held", "Points leased to pools now", g.leases),
            ("pools_connected", "Pools heard from within one lease period", g.pools_connected),
        ];
        for (name, help, n) in gauges {
            let gauge = ConstGauge::new(n as i64);
            gauge.encode(encoder.encode_descriptor(name, help, None, gauge.metric_type())?)?;
        }
        let expired = ConstCounter::new(g.leases_expired);
        expired.encode(encoder.encode_descriptor(
            "leases_expired",
            "Leases lost (no heartbeat within the lease, or over the per-point budget) since the coordinator started",
            None,
            expired.metric_type(),
        )?)?;
        // a database that cannot say its size leaves the metric out rather than report 0
        match self.0.store_bytes() {
            Ok(bytes) => {
                let gauge = ConstGauge::new(bytes as i64);
                gauge.encode(encoder.encode_descriptor(
                    "store_size",
                    "Size of the database on disk",
                    Some(&Unit::Bytes),
                    gauge.metric_type(),
                )?)?;
            }
            Err(e) => tracing::warn!(error = %e, "reading the database's size for /metrics"),
        }
        Ok(())
    }
}

/// The tower layer (as axum middleware) around every route, gRPC and HTTP: counts each request
/// once its status is known. A gRPC status comes in the trailers, after the last message of a
/// stream; one that ends without them (the client went away) counts as CANCELLED.
pub async fn count_requests(State(metrics): State<Arc<Metrics>>, request: Request, next: Next) -> Response {
    if !crate::web::is_grpc(request.headers()) {
        let response = next.run(request).await;
        let route = response.extensions().get::<MatchedPath>().map_or(OTHER, MatchedPath::as_str).to_owned();
        metrics.http.get_or_create(&HttpLabels { route, status: response.status().as_u16() }).inc();
        return response;
    }
    let method = metrics.grpc_method(request.uri().path());
    let response = next.run(request).await;
    // refusals and errors are trailers-only: the status is in the headers
    if let Some(code) = grpc_status(response.headers()) {
        metrics.grpc_request(method, code);
        return response;
    }
    response.map(|inner| Body::new(Tallied { inner, tally: Some(Tally { metrics, method }) }))
}

/// Keeps the matched route's template on the response, for [`count_requests`] outside the
/// router (axum puts it on the request only). A `route_layer`: unmatched paths have none.
pub async fn keep_route(request: Request, next: Next) -> Response {
    let route = request.extensions().get::<MatchedPath>().cloned();
    let mut response = next.run(request).await;
    if let Some(route) = route {
        response.extensions_mut().insert(route);
    }
    response
}

/// A gRPC call still to count.
struct Tally {
    metrics: Arc<Metrics>,
    method: String,
}

/// A gRPC response body that counts its call when its trailers pass (or when it is dropped
/// without them).
struct Tallied {
    inner: Body,
    tally: Option<Tally>,
}

impl Tallied {
    fn count(&mut self, code: tonic::Code) {
        if let Some(Tally { metrics, method }) = self.tally.take() {
            metrics.grpc_request(method, code);
        }
    }
}

impl http_body::Body for Tallied {
    type Data = Bytes;
    type Error = axum::Error;

    fn poll_frame(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Result<Frame<Bytes>, axum::Error>>> {
        let polled = Pin::new(&mut self.inner).poll_frame(cx);
        match &polled {
            Poll::Ready(Some(Ok(frame))) => {
                if let Some(trailers) = frame.trailers_ref() {
                    self.count(grpc_status(trailers).unwrap_or(tonic::Code::Unknown));
                }
            }
            Poll::Ready(Some(Err(_))) => self.count(tonic::Code::Internal),
            // a gRPC body always ends with trailers: without them the status is unknown
            Poll::Ready(None) => self.count(tonic::Code::Unknown),
            Poll::Pending => {}
        }
        polled
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> SizeHint {
        self.inner.size_hint()
    }
}

impl Drop for Tallied {
    fn drop(&mut self) {
        self.count(tonic::Code::Cancelled);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_method_set_is_every_served_method_and_nothing_else() {
        let m = grpc_methods(&[
            glissade_proto::FILE_DESCRIPTOR_SET,
            tonic_health::pb::FILE_DESCRIPTOR_SET,
            tonic_reflection::pb::v1::FILE_DESCRIPTOR_SET,
            tonic_reflection::pb::v1alpha::FILE_DESCRIPTOR_SET,
        ]);
        for served in [
            "/glissade.v1.User/SubmitStudy",
            "/glissade.v1.Pool/LeasePoint",
            "/glissade.v1.Health/Check",
            "/grpc.health.v1.Health/Check",
            "/grpc.health.v1.Health/Watch",
            "/grpc.reflection.v1.ServerReflection/ServerReflectionInfo",
            "/grpc.reflection.v1alpha.ServerReflection/ServerReflectionInfo",
        ] {
            assert!(m.contains(served), "{served} missing from {m:?}");
        }
        assert!(!m.contains("/glissade.v1.User/NoSuchMethod"));
        // a handful of services with a handful of methods each: bounded by the proto files
        assert!(m.len() < 64, "{} methods", m.len());
    }

    #[test]
    fn every_status_code_has_its_canonical_name() {
        let names: HashSet<&str> = (0..=16).map(|c| code_name(tonic::Code::from(c))).collect();
        assert_eq!(names.len(), 17);
        assert_eq!(code_name(tonic::Code::from(99)), "UNKNOWN");
        assert_eq!(code_name(tonic::Code::Unauthenticated), "UNAUTHENTICATED");
    }
}
