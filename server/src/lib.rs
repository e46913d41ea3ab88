//! The glissade coordinator as a library: [`serve`] runs the gRPC service (User, Pool, Health,
//! reflection) over a sled database until a shutdown future resolves. `glissade-server` is a thin
//! binary around it, which `glissade demo` runs on a temporary directory.

pub mod auth;
mod conn;
mod convert;
mod coordinator;
mod figures;
mod health;
#[cfg(test)]
mod heap;
mod kept;
mod low_priority;
mod metrics;
mod pool;
mod qoi_map;
mod read_budget;
mod records;
mod renderings;
mod store;
mod study;
mod user;
mod web;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result};
use coordinator::{Config, Coordinator};
pub use glissade_core::study::space::DEFAULT_MAX_POINTS;
use glissade_proto::v1::health_server::HealthServer;
use glissade_proto::v1::pool_server::PoolServer;
use glissade_proto::v1::user_server::UserServer;
use store::SledStore;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::Server;

/// How long a stopping coordinator waits for open connections to finish their calls.
const SHUTDOWN_GRACE: Duration = Duration::from_secs(5);

/// What a coordinator needs to start.
#[derive(Debug, Clone)]
pub struct ServerOptions {
    /// Directory of the database (created if missing).
    pub data: PathBuf,
    /// How long a pool holds a design point without a heartbeat.
    pub lease: Duration,
    /// Leases granted to one point before a lost lease marks it failed.
    pub max_attempts: u32,
    /// Largest solution file a pool may send.
    pub max_solution_bytes: u64,
    /// Most design points in one study.
    pub max_points: usize,
    /// Largest estimated memory of one solve of a submitted scene, bytes.
    pub max_scene_bytes: u64,
    /// Most points pending over all studies.
    pub max_pending: usize,
    /// Longest a point may stay leased.
    pub point_budget: Duration,
    /// A connection silent for this long is closed.
    pub idle: Duration,
    /// Most connections open at once.
    pub max_connections: usize,
    /// Most connections open at once from one client address.
    pub max_connections_per_client: usize,
    /// Where there are tokens, how long a connection may stay open without presenting one
    /// (conn.rs: it is closed then, and may be displaced by a newer connection before).
    pub probation: Duration,
    /// The user and pool tokens; None: no authentication, which is allowed on loopback only
    /// unless `open` says otherwise.
    pub tokens: Option<auth::Tokens>,
    /// Serve without tokens on a non-loopback address (a network where every host is trusted).
    pub open: bool,
    /// PEM certificate chain and private key: serve TLS (clients use https:// URLs).
    pub tls: Option<(Vec<u8>, Vec<u8>)>,
    /// Web requests (page, JSON API, /metrics) a second from one client address, on average;
    /// more get 429 (read_budget.rs).
    pub web_reads_per_second: f64,
}

/// Default of `--web-reads-per-second`: a person's browser makes a request or two a second.
pub const DEFAULT_WEB_READS_PER_SECOND: f64 = read_budget::DEFAULT_RATE;

/// Default of `--max-scene-mib`: 64 GiB, the memory of a large compute node (the paper's
/// bolted joint, 450,000 dofs, is estimated at about 4.5 GB).
pub const DEFAULT_MAX_SCENE_MIB: u64 = 64 << 10;

/// Default of `--max-pending`: five studies of the default `--max-points`, the probe's 1.3 GB
/// (a pending point costs the coordinator a few kB: docs/performance.md).
pub const DEFAULT_MAX_PENDING: usize = 5 * DEFAULT_MAX_POINTS;

/// Default of `--max-connections`: below the usual file limit of 1024, with room for the
/// database's files.
pub const DEFAULT_MAX_CONNECTIONS: usize = 768;

/// Default of `--max-connections-per-client`: a quarter of the connections, so that one host
/// (slow bodies, pinging sockets) cannot hold them all; a site whose pools reach the coordinator
/// through one NAT address raises it.
pub const DEFAULT_MAX_CONNECTIONS_PER_CLIENT: usize = DEFAULT_MAX_CONNECTIONS / 4;

impl ServerOptions {
    /// The defaults of `glissade-server` for a database in `data`.
    pub fn new(data: impl Into<PathBuf>) -> Self {
        Self {
            data: data.into(),
            lease: Duration::from_secs(60),
            max_attempts: 3,
            max_solution_bytes: 4 << 30,
            max_points: DEFAULT_MAX_POINTS,
            max_scene_bytes: DEFAULT_MAX_SCENE_MIB << 20,
            max_pending: DEFAULT_MAX_PENDING,
            point_budget: Duration::from_secs(86400),
            idle: Duration::from_secs(60),
            max_connections: DEFAULT_MAX_CONNECTIONS,
            max_connections_per_client: DEFAULT_MAX_CONNECTIONS_PER_CLIENT,
            probation: Duration::from_secs(10),
            tokens: None,
            open: false,
            tls: None,
            web_reads_per_second: DEFAULT_WEB_READS_PER_SECOND,
        }
    }
}

/// Opens the database and binds `listen`; returns the bound address (port 0 picks one) and the
/// future that serves until `shutdown` resolves, then flushes the database.
pub async fn bind(
    options: ServerOptions,
    listen: SocketAddr,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<(SocketAddr, impl Future<Output = Result<()>>)> {
    check_options(&options, listen)?;
    let store = SledStore::open(&options.data).context("opening the database")?;
    let config = Config {
        lease: options.lease,
        max_attempts: options.max_attempts,
        max_solution_bytes: options.max_solution_bytes,
        max_points: options.max_points,
        max_scene_bytes: options.max_scene_bytes,
        max_pending: options.max_pending,
        point_budget: options.point_budget,
        solver_version: env!("CARGO_PKG_VERSION").to_owned(),
    };
    let coordinator = Arc::new(Coordinator::open(Arc::new(store), config).context("loading the database")?);
    let metrics = Arc::new(metrics::Metrics::new(coordinator.clone()));
    // Both reflection versions: grpcurl asks v1 first, older tools (grpcio-reflection) v1alpha.
    let reflection = || {
        tonic_reflection::server::Builder::configure()
            .register_encoded_file_descriptor_set(glissade_proto::FILE_DESCRIPTOR_SET)
    };
    let heavy = Arc::new(low_priority::LowPriority::for_this_machine().context("starting the web's threads")?);
    let budget = Arc::new(read_budget::ReadBudget::new(options.web_reads_per_second));
    let reflection_v1 = reflection().build_v1().context("building the reflection service")?;
    let reflection_v1alpha = reflection().build_v1alpha().context("building the reflection service")?;
    let listener = tokio::net::TcpListener::bind(listen).await.with_context(|| format!("binding {listen}"))?;
    let addr = listener.local_addr().context("reading the bound address")?;

    // The standard grpc.health.v1 service beside glissade.v1.Health (which also says why and
    // which version): the whole server ("") and each of our services, NOT_SERVING once the
    // database cannot write.
    let (health_reporter, standard_health) = tonic_health::server::health_reporter();
    for service in STANDARD_HEALTH_NAMES {
        health_reporter.set_service_status(service, tonic_health::ServingStatus::Serving).await;
    }
    let tokens = options.tokens.clone();
    let tls = options.tls.is_some();
    let limits = conn::Limits {
        max_connections: options.max_connections,
        max_per_client: options.max_connections_per_client,
        idle: options.idle,
        probation: options.tokens.is_some().then_some(options.probation),
    };
    let idle = options.idle;
    // Pings keep a live HTTP/2 client's connection busy (conn.rs closes a silent one); one that
    // leaves a ping unanswered for the idle time is gone.
    let mut builder = Server::builder().http2_keepalive_interval(Some(idle / 4)).http2_keepalive_timeout(Some(idle));
    if let Some((cert, key)) = &options.tls {
        let identity = tonic::transport::Identity::from_pem(cert, key);
        builder = builder
            .tls_config(tonic::transport::ServerTlsConfig::new().identity(identity))
            .context("TLS certificate and key")?;
    }
    let serve = async move {
        let expiry = spawn_lease_expiry(coordinator.clone());
        let (stopping_tx, stopping_rx) = tokio::sync::oneshot::channel();
        let standard =
            tonic::service::Routes::new(standard_health).add_service(reflection_v1).add_service(reflection_v1alpha);
        let routes = routes(standard, &coordinator, &metrics, tokens.as_ref(), tls, heavy, budget);
        let serve = builder.accept_http1(true).add_routes(routes).serve_with_incoming_shutdown(
            conn::Incoming::new(listener, limits),
            {
                let c = coordinator.clone();
                async move {
                    tokio::select! {
                        () = shutdown => {}
                        () = store_failed(c.clone(), health_reporter) => {}
                    }
                    // End long polls and event streams, or the graceful shutdown would wait for them.
                    c.stop();
                    let _ = stopping_tx.send(());
                }
            },
        );
        tokio::pin!(serve);
        tokio::select! {
            served = &mut serve => served.context("serving gRPC")?,
            // A client that never reads the goaway (a stalled process) must not keep us up.
            _ = async {
                let _ = stopping_rx.await;
                tokio::time::sleep(SHUTDOWN_GRACE).await;
            } => tracing::warn!(grace = ?SHUTDOWN_GRACE, "connections still open after the grace period: closing"),
        }
        expiry.abort();
        if let Some(cause) = coordinator.store_failure() {
            // sled's write errors are sticky: only a new process writes again. Every answer
            // given was committed first, so nothing is lost; pools keep their results. The
            // database is not dropped: sled's drop would retry its failed flush for ever.
            std::mem::forget(coordinator.clone());
            anyhow::bail!(
                "the database cannot write ({cause}): stopped so that the service manager restarts the coordinator once space is freed"
            );
        }
        coordinator.flush().context("flushing the database at shutdown")?;
        tracing::info!("stopped");
        Ok(())
    };
    Ok((addr, serve))
}

/// The options `bind` refuses, before anything is opened (the data directory is created).
fn check_options(options: &ServerOptions, listen: SocketAddr) -> Result<()> {
    std::fs::create_dir_all(&options.data)
        .with_context(|| format!("creating data directory {}", options.data.display()))?;
    if options.lease < Duration::from_millis(50) {
        anyhow::bail!("lease of {:?}: give at least 0.05 s", options.lease);
    }
    if options.max_attempts == 0 {
        anyhow::bail!("max attempts 0: give at least 1");
    }
    for (name, value) in [
        ("--max-points", options.max_points),
        ("--max-pending", options.max_pending),
        ("--max-connections", options.max_connections),
        ("--max-connections-per-client", options.max_connections_per_client),
    ] {
        if value == 0 {
            anyhow::bail!("{name} 0: give at least 1");
        }
    }
    let rate = options.web_reads_per_second;
    if !(rate.is_finite() && (0.1..=1e6).contains(&rate)) {
        anyhow::bail!("--web-reads-per-second {rate}: give 0.1 to 1e6");
    }
    if options.tokens.is_none() && !listen.ip().is_loopback() && !options.open {
        anyhow::bail!(
            "listening on {listen} without tokens would let anyone who reaches it submit, cancel or falsify results: give --user-token-file and --pool-token-file (README, Service), listen on 127.0.0.1, or pass --open on a network where every host is trusted"
        );
    }
    Ok(())
}

/// Leases of pools that stopped answering expire even while no pool asks for work.
fn spawn_lease_expiry(c: Arc<Coordinator>) -> tokio::task::JoinHandle<()> {
    let tick = (c.config().lease / 4).clamp(Duration::from_millis(20), Duration::from_secs(1));
    tokio::spawn(async move {
        loop {
            tokio::time::sleep(tick).await;
            let c = c.clone();
            match tokio::task::spawn_blocking(move || c.expire_leases()).await {
                Ok(Ok(_)) => {}
                Ok(Err(e)) => tracing::error!(error = %e, "expiring leases"),
                Err(e) => tracing::error!(error = %e, "expiring leases panicked"),
            }
        }
    })
}

/// Every route of the port: the standard services already in `routes` (health, reflection), our
/// gRPC services (each behind its token), then the web page and its JSON API over HTTP/1.1,
/// every request counted for /metrics.
fn routes(
    mut routes: tonic::service::Routes,
    coordinator: &Arc<Coordinator>,
    metrics: &Arc<metrics::Metrics>,
    tokens: Option<&auth::Tokens>,
    tls: bool,
    heavy: Arc<low_priority::LowPriority>,
    budget: Arc<read_budget::ReadBudget>,
) -> tonic::service::Routes {
    routes = routes
        .add_service(HealthServer::new(health::HealthService { coordinator: coordinator.clone() }))
        .add_service(InterceptedService::new(
            // SubmitStudy carries the scene's mesh files: raised from gRPC's 4 MiB to their
            // bound and 4 MiB (the token is checked on the headers, before the body is read)
            UserServer::new(user::UserService { coordinator: coordinator.clone() })
                .max_decoding_message_size(convert::MAX_SUBMISSION_BYTES),
            auth::RequireToken::users(tokens),
        ))
        .add_service(InterceptedService::new(
            // a pool's messages are a chunk of at most 1 MiB plus a small header: a bigger one is
            // refused as it is decoded, not after
            PoolServer::new(pool::PoolService::new(coordinator.clone(), metrics.clone()))
                .max_decoding_message_size(glissade_proto::CHUNK_BYTES + (64 << 10)),
            auth::RequireToken::pools(tokens),
        ));
    // the web page and its JSON API on the same port, over HTTP/1.1
    // (tonic's own fallback answers any path with a gRPC status in HTTP 200: ours says 404)
    let grpc =
        std::mem::take(routes.axum_router_mut()).fallback(web::not_found).layer(axum::middleware::from_fn(grpc_only));
    // every request, gRPC or HTTP, counted by method and status for /metrics
    *routes.axum_router_mut() = grpc
        .merge(web::router(coordinator.clone(), metrics.clone(), tokens, tls, heavy, budget))
        .layer(axum::middleware::from_fn_with_state(metrics.clone(), metrics::count_requests))
        .layer(axum::middleware::from_fn_with_state(tokens.cloned(), trust_tokens));
    routes
}

/// A request that presents a valid token (either role's, as `Authorization: Bearer`, which is
/// gRPC's metadata too, or as the page's login cookie) takes its connection off probation
/// (conn.rs). Whether the token may call what it asks is each service's check, after this.
async fn trust_tokens(
    axum::extract::State(tokens): axum::extract::State<Option<auth::Tokens>>,
    request: axum::extract::Request,
    next: axum::middleware::Next,
) -> axum::response::Response {
    if let (Some(tokens), Some(conn)) = (&tokens, conn::conn_of(request.extensions()))
        && !conn.trust.granted()
        && web::presented(request.headers()).is_some_and(|p| tokens.user.matches(&p) || tokens.pool.matches(&p))
    {
        conn.trust.grant();
        tracing::debug!(peer = ?conn.tcp.remote_addr(), "a token presented: the connection leaves its probation");
    }
    next.run(request).await
}

/// The gRPC routes answer gRPC requests only: anything else (a browser's GET of a method's path)
/// gets the web page's 404, not a gRPC status inside HTTP 200.
///
/// And tonic answers a request whose body is not the method's protobuf message with INTERNAL
/// (its codec's rule, for either side); a server that receives one was sent bad input:
/// INVALID_ARGUMENT. (Such an answer is trailers-only: the status is in the headers.)
async fn grpc_only(request: axum::extract::Request, next: axum::middleware::Next) -> axum::response::Response {
    if !web::is_grpc(request.headers()) {
        return web::not_found(request).await;
    }
    let mut response = next.run(request).await;
    let headers = response.headers_mut();
    let undecodable = headers.get("grpc-status").is_some_and(|s| s == "13")
        && headers
            .get("grpc-message")
            .is_some_and(|m| m.as_bytes().starts_with(b"failed%20to%20decode%20Protobuf%20message"));
    if undecodable {
        headers.insert("grpc-status", axum::http::HeaderValue::from_static("3"));
    }
    response
}

/// How long a coordinator whose database cannot write keeps answering (Health NOT_SERVING,
/// RESOURCE_EXHAUSTED) before it stops to be restarted.
const STORE_FAILURE_GRACE: Duration = Duration::from_secs(3);

/// The names the standard health service answers for: the whole server, then each service.
const STANDARD_HEALTH_NAMES: [&str; 3] = ["", "glissade.v1.User", "glissade.v1.Pool"];

/// Resolves once the database has failed to write, after [`STORE_FAILURE_GRACE`] (during which
/// the standard health service says NOT_SERVING).
async fn store_failed(coordinator: Arc<Coordinator>, health: tonic_health::server::HealthReporter) {
    loop {
        if let Some(cause) = coordinator.store_failure() {
            tracing::error!(cause, grace = ?STORE_FAILURE_GRACE, "the database cannot write: stopping");
            for service in STANDARD_HEALTH_NAMES {
                health.set_service_status(service, tonic_health::ServingStatus::NotServing).await;
            }
            tokio::time::sleep(STORE_FAILURE_GRACE).await;
            return;
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}
