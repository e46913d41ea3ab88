//! Pool mode (`glissade-worker pool --coordinator URL`): pulls design points from a glissade
//! coordinator, solves them, sends the interface solutions back.
//!
//! Two halves, so that MPI stays on the main thread: [`run_pool`] runs the conversation with the
//! coordinator (register, lease with the warm start, heartbeats, complete or fail, reconnect with
//! back-off) on a small tokio runtime, and hands each point to a [`PoolSolver`] on the calling
//! thread — one call per point. A one-process pool uses [`SerialPoolSolver`]; a pool of P > 1 MPI
//! ranks uses [`ranks::RootSolver`] on rank 0, which sends each [`PointJob`] to the other ranks
//! (waiting in [`ranks::follow_root`]) and solves it with them; only rank 0 talks to the
//! coordinator.
//!
//! The last lease's scene is kept, parsed and checked, for the next ([`scenes::SceneCache`]):
//! a study's points share one scene, parsed and its mesh files fetched once per pool.
//!
//! SIGTERM or SIGINT: a pool waiting for work stops at once; a pool solving finishes the point,
//! delivers it, then stops (a point it holds but has not started is released). A second signal
//! stops the solve at its next iteration, gives the point back and stops; a pool still busy 5 s
//! later exits. A solve also stops at its next iteration when the coordinator's heartbeat answer
//! says its lease is lost or its study cancelled.

use glissade_core::text::one_line;
use glissade_proto::auth::{Token, WithToken};
use std::sync::Arc;
use std::sync::mpsc as std_mpsc;
use std::time::{Duration, Instant};
use tonic::service::interceptor::InterceptedService;

use anyhow::{Context, Result, anyhow, bail};
use glissade_proto::Assembler;
use glissade_proto::v1::pool_client::PoolClient;
use glissade_proto::v1::{self, lease_message};
use tokio::sync::{oneshot, watch};
use tonic::transport::Channel;
use tonic::{Code, Status};

use glissade_core::field::InterfaceSolution;
use glissade_core::io::solution_file::{self, SolutionMeta};
use glissade_core::point::DesignPoint;
use glissade_core::scene::{MAX_MESH_FILE_BYTES, MAX_MESH_FILES, Scene, Tolerance, check_max_iterations};
use glissade_core::study::engine::solve_or_retry_cold;
use glissade_solver::comm::Serial;
use glissade_solver::run::{PointSolver, RunError, SolveOutcome, SolveRequest};

pub mod delivery;
#[cfg(feature = "mpi")]
pub mod ranks;
pub mod scenes;

use delivery::{Delivery, Spool};
use scenes::{LeasedScene, PreparedScene, SceneCache, SceneKey};

/// Largest warm-start solution accepted from the coordinator (a paper-size scene's is ~100 MB).
const MAX_INIT_BYTES: u64 = 4 << 30;

/// How a pool reaches its coordinator and waits.
#[derive(Debug, Clone)]
pub struct PoolOptions {
    /// `http://host:port` of glissade-server.
    pub coordinator: String,
    /// Stable id of this pool (logs, leases); None: the coordinator assigns one.
    pub pool_id: Option<String>,
    /// MPI ranks of the pool.
    pub ranks: u32,
    /// Host name of rank 0.
    pub host: String,
    /// How long one LeasePoint call waits for work.
    pub wait: Duration,
    /// First and largest pause between reconnection attempts (doubling in between).
    pub backoff: (Duration, Duration),
    /// Stop after this long without work (None: never).
    pub idle_exit: Option<Duration>,
    /// The pool token of a coordinator that asks for one.
    pub token: Option<Token>,
    /// CA certificate of an `https://` coordinator (else GLISSADE_CA_CERT, else system roots).
    pub ca_cert: Option<std::path::PathBuf>,
    /// Where a stopping pool leaves results it could not deliver (delivered at the next start).
    pub spool: Option<Spool>,
    /// How long a stopping pool keeps trying to deliver before it spools and exits.
    pub stop_grace: Duration,
    /// Memory a solve may take, bytes (None: what the system says is available when a point
    /// arrives). A point whose scene needs more fails with the reason instead of killing the pool.
    pub memory_budget: Option<u64>,
    /// Stop when this turns true (a pool embedded in another program, e.g. `glissade demo`);
    /// None: on SIGTERM or SIGINT, with handlers installed by [`run_pool`].
    pub stop: Option<watch::Receiver<bool>>,
}

impl PoolOptions {
    /// Defaults for `coordinator`: coordinator-assigned id, one rank, 10 s polls, back-off
    /// 0.2 s to 5 s, never idle out.
    pub fn new(coordinator: impl Into<String>) -> Self {
        Self {
            coordinator: coordinator.into(),
            pool_id: None,
            ranks: 1,
            host: host_name(),
            wait: Duration::from_secs(10),
            backoff: (Duration::from_millis(200), Duration::from_secs(5)),
            idle_exit: None,
            memory_budget: None,
            token: None,
            ca_cert: None,
            spool: delivery::default_spool_dir().map(|dir| Spool { dir }),
            stop_grace: Duration::from_secs(10),
            stop: None,
        }
    }
}

/// Host name of this machine, for the coordinator's logs.
pub fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|s| s.trim().to_owned())
        .ok()
        .filter(|s| !s.is_empty())
        .or_else(|| std::env::var("HOSTNAME").ok())
        .unwrap_or_else(|| "unknown".into())
}

/// One design point to solve, with what a wrapper needs to send it to other ranks: the scene's
/// key and text and the warm start's file bytes beside their parsed forms.
#[derive(Debug, Clone)]
pub struct PointJob {
    /// shared with the pool's kept scene and the jobs of its other points
    pub scene: Arc<PreparedScene>,
    /// The lease's design point, the tolerance and the iteration limit.
    pub request: SolveRequest,
    /// The warm start as a solution file (empty: cold start).
    pub init_bytes: Vec<u8>,
    pub init: Option<InterfaceSolution>,
    /// The lease's warm start did not fit the scene and was dropped.
    pub warm_start_dropped: bool,
}

impl PointJob {
    /// The same point from cold.
    fn cold(&self) -> PointJob {
        let mut request = self.request.clone();
        request.init_parameters = None;
        PointJob {
            scene: self.scene.clone(),
            request,
            init_bytes: Vec::new(),
            init: None,
            warm_start_dropped: self.warm_start_dropped,
        }
    }
}

/// The solve of one design point. Called on the thread that called [`run_pool`].
pub trait PoolSolver {
    fn solve(&mut self, job: &PointJob) -> Result<SolveOutcome, RunError>;
}

/// A pool of one process: the solver's [`PointSolver`], which keeps the factorised operators
/// from one point to the next while only friction coefficients change.
#[derive(Default)]
pub struct SerialPoolSolver {
    solver: PointSolver,
}

impl PoolSolver for SerialPoolSolver {
    fn solve(&mut self, job: &PointJob) -> Result<SolveOutcome, RunError> {
        self.solver.solve(&Serial, &job.scene.scene, &job.request, job.init.as_ref())
    }
}

/// A job for the solving thread, and where its outcome (or why there is none) goes, with whether
/// it was solved from cold in spite of a warm start.
type Work = (PointJob, oneshot::Sender<Result<(SolveOutcome, bool), String>>);

/// Runs the pool until SIGTERM/SIGINT (or `idle_exit`): the coordinator conversation on a
/// background runtime, every solve on this thread through `solver`.
pub fn run_pool(options: PoolOptions, solver: &mut dyn PoolSolver) -> Result<()> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .context("starting the tokio runtime")?;
    let stop_rx = match options.stop.clone() {
        Some(stop) => stop,
        None => {
            let (stop_tx, stop_rx) = watch::channel(false);
            // Handlers first: a SIGTERM from now on must not kill the pool mid-delivery.
            runtime.block_on(install_signal_handlers(stop_tx))?;
            stop_rx
        }
    };
    let (work_tx, work_rx) = std_mpsc::channel::<Work>();
    let talker = runtime.spawn(converse(options, work_tx, stop_rx));
    // Ends when the conversation drops its sender.
    for (job, reply) in work_rx {
        // A panicking solve fails its point (FailPoint) instead of taking the pool down with it.
        let mut attempt =
            |job: &PointJob| match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| solver.solve(job))) {
                Ok(result) => result.map_err(|e| e.to_string()),
                Err(panic) => {
                    let what = panic
                        .downcast_ref::<&str>()
                        .map(|s| s.to_string())
                        .or_else(|| panic.downcast_ref::<String>().cloned());
                    Err(format!("the solver panicked: {}", what.unwrap_or_else(|| "(no message)".into())))
                }
            };
        // the study engine's rule: a failed warm start is solved again from cold (not a stopped one)
        let stopped = || job.request.progress.as_ref().is_some_and(|p| p.stop_asked());
        let mut unless_stopped =
            |job: &PointJob| if stopped() { Err("stopped on request".to_owned()) } else { attempt(job) };
        let cold = job.cold();
        let (outcome, retried) =
            solve_or_retry_cold(job.init.as_ref(), |init| unless_stopped(if init.is_some() { &job } else { &cold }));
        let _ = reply.send(outcome.map(|o| (o, retried || job.warm_start_dropped)));
    }
    runtime.block_on(talker).context("pool task panicked")?
}

async fn install_signal_handlers(stop: watch::Sender<bool>) -> Result<()> {
    use tokio::signal::unix::{SignalKind, signal};
    let mut term = signal(SignalKind::terminate()).context("installing the SIGTERM handler")?;
    let mut int = signal(SignalKind::interrupt()).context("installing the SIGINT handler")?;
    tokio::spawn(async move {
        tokio::select! {
            _ = term.recv() => tracing::info!("SIGTERM: stopping after the current point"),
            _ = int.recv() => tracing::info!("SIGINT: stopping after the current point"),
        }
        let _ = stop.send(true);
        // A second signal: no more waiting for the coordinator (the result is spooled).
        tokio::select! {
            _ = term.recv() => {}
            _ = int.recv() => {}
        }
        tracing::warn!("second signal: stopping now");
        URGENT.store(true, std::sync::atomic::Ordering::Relaxed);
        let _ = stop.send(true);
        // The solve stops at its next iteration and the result is spooled; a pool still busy
        // after this (a long factorisation, an unreachable coordinator) exits anyway.
        tokio::time::sleep(URGENT_EXIT).await;
        tracing::error!(after = ?URGENT_EXIT, "second signal: still busy, exiting");
        std::process::exit(1);
    });
    Ok(())
}

/// A solved (or failed) point waiting to be delivered, kept across reconnections.
pub struct Report {
    pub lease: v1::Lease,
    /// The scene solved, the outcome and whether it was solved from cold in spite of a warm
    /// start; or why there is no outcome (one line).
    pub outcome: Result<(Arc<PreparedScene>, SolveOutcome, bool), String>,
}

/// Why the conversation with the coordinator broke off.
enum Break {
    /// Transport down or coordinator restarting: reconnect with back-off.
    Reconnect(String),
    /// Stop requested (and nothing left to deliver), or idle too long.
    Stop,
}

/// A pool-service client that presents the pool token with every call.
pub type Pool = PoolClient<InterceptedService<Channel, WithToken>>;

struct Session {
    client: Pool,
    pool_id: String,
    heartbeat: Duration,
}

/// Where the conversation sends jobs, and the scene it keeps for them, across leases and
/// reconnections.
struct Solving {
    work: std_mpsc::Sender<Work>,
    scenes: SceneCache,
}

async fn converse(options: PoolOptions, work: std_mpsc::Sender<Work>, mut stop: watch::Receiver<bool>) -> Result<()> {
    let mut pool_id = options.pool_id.clone();
    let mut solving = Solving { work, scenes: SceneCache::default() };
    let mut pending: Option<Delivery> = None;
    let mut backoff = options.backoff.0;
    let mut idle_since = Instant::now();
    // When a stop was asked with a result still to deliver: from then on the grace runs.
    let mut stopping_since: Option<Instant> = None;
    loop {
        if *stop.borrow() {
            if pending.is_none() {
                return Ok(());
            }
            let since = *stopping_since.get_or_insert_with(Instant::now);
            if since.elapsed() >= options.stop_grace || URGENT.load(std::sync::atomic::Ordering::Relaxed) {
                return spool_and_stop(&options, pending.take().expect("checked above"));
            }
        }
        // Pauses end early on a stop, and never outlast the grace of a stopping pool.
        let pause = |wanted: Duration| match stopping_since {
            Some(since) => wanted.min(options.stop_grace.saturating_sub(since.elapsed())),
            None => wanted,
        };
        let mut session = match connect(&options, pool_id.as_deref()).await {
            Ok(s) => s,
            // A token the coordinator refuses will not get better by retrying.
            Err(e) if e.downcast_ref::<Refused>().is_some() => return Err(e),
            Err(e) => {
                tracing::warn!(coordinator = %options.coordinator, error = %format!("{e:#}"), retry_in = ?backoff, "cannot reach the coordinator");
                tokio::select! {
                    _ = tokio::time::sleep(pause(backoff)) => {}
                    _ = stop.changed() => {}
                }
                backoff = (backoff * 2).min(options.backoff.1);
                continue;
            }
        };
        if pool_id.as_deref() != Some(&session.pool_id) {
            tracing::info!(pool = %session.pool_id, coordinator = %options.coordinator, "registered");
        }
        pool_id = Some(session.pool_id.clone());
        deliver_spooled(&options, &mut session.client).await;
        let mut progressed = false;
        match serve(&options, session, &mut solving, &mut stop, &mut pending, &mut idle_since, &mut progressed).await {
            Break::Stop => return Ok(()),
            Break::Reconnect(why) => {
                // A coordinator that answers but cannot take the result (a full disk) must not
                // be asked again every 200 ms: back off until something goes through.
                let wait = if progressed { options.backoff.0 } else { backoff };
                tracing::warn!(reason = %why, retry_in = ?wait, "lost the coordinator; reconnecting");
                tokio::select! {
                    _ = tokio::time::sleep(pause(wait)) => {}
                    _ = stop.changed() => {}
                }
                backoff = if progressed { options.backoff.0 } else { (backoff * 2).min(options.backoff.1) };
            }
        }
    }
}

/// How long a pool given a second signal may take to stop before it exits.
const URGENT_EXIT: Duration = Duration::from_secs(5);

/// Set by a second SIGTERM or SIGINT: stop now, spooling what is not delivered.
static URGENT: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// A stopping pool's last act when the coordinator cannot be reached: keep the result.
fn spool_and_stop(options: &PoolOptions, delivery: Delivery) -> Result<()> {
    let (study, point) = delivery.point();
    let Some(spool) = &options.spool else {
        bail!(
            "stopping with the result of study {study} point {point} undelivered and no --spool directory: it is lost"
        );
    };
    let path = spool.save(&delivery)?;
    tracing::warn!(study, point, file = %path.display(), "coordinator unreachable: result spooled for the next start of a pool");
    Ok(())
}

/// Sends what an earlier run of a pool spooled; a result the coordinator refuses for good (its
/// lease was lost meanwhile and the point went elsewhere) is dropped, a transient error keeps
/// it for the next connection.
async fn deliver_spooled(options: &PoolOptions, client: &mut Pool) {
    let Some(spool) = &options.spool else { return };
    for (path, delivery) in spool.pending() {
        let (study, point) = delivery.point();
        match delivery.send(client).await {
            Ok(state) => {
                tracing::info!(study, point, state = ?state, "delivered a spooled result");
                Spool::remove(&path);
            }
            Err(status) if is_transient(&status) => return,
            Err(status) => {
                tracing::warn!(study, point, code = ?status.code(), error = status.message(), "the coordinator refused a spooled result; dropping it");
                Spool::remove(&path);
            }
        }
    }
}

async fn connect(options: &PoolOptions, pool_id: Option<&str>) -> Result<Session> {
    let endpoint = glissade_proto::auth::endpoint(&options.coordinator, options.ca_cert.as_deref())?
        .connect_timeout(Duration::from_secs(5))
        .tcp_keepalive(Some(Duration::from_secs(30)));
    let channel = glissade_proto::auth::connect(endpoint).await.context("connecting")?;
    let mut client = PoolClient::with_interceptor(channel, WithToken::new(options.token.as_ref()));
    let reply = client
        .register_pool(v1::RegisterPoolRequest {
            pool_id: pool_id.unwrap_or_default().to_owned(),
            ranks: options.ranks,
            host: options.host.clone(),
            solver_version: env!("CARGO_PKG_VERSION").to_owned(),
        })
        .await
        .map_err(|s| match s.code() {
            Code::Unauthenticated | Code::PermissionDenied => anyhow::Error::new(Refused(one_line(s.message()))),
            _ => anyhow!("registering: {}", s.message()),
        })?
        .into_inner();
    Ok(Session { client, pool_id: reply.pool_id, heartbeat: Duration::from_millis(reply.heartbeat_ms.max(20)) })
}

/// The coordinator refused this pool's credentials.
#[derive(Debug, thiserror::Error)]
#[error(
    "the coordinator refused this pool: {0} (give the pool token: --token-file, GLISSADE_TOKEN or GLISSADE_TOKEN_FILE)"
)]
struct Refused(String);

/// Transport failures and a restarting coordinator are worth a reconnect; anything else is an
/// answer about the request itself.
fn is_transient(status: &Status) -> bool {
    // RESOURCE_EXHAUSTED: the coordinator's disk is full; it restarts once space is freed
    matches!(
        status.code(),
        Code::Unavailable | Code::Unknown | Code::Cancelled | Code::DeadlineExceeded | Code::ResourceExhausted
    ) || status.metadata().contains_key(glissade_proto::auth::REGISTER_AGAIN)
}

/// One connection's worth of pool work: deliver what is pending, lease, solve, repeat.
///
/// A solved point is delivered before the next one is leased, never in the background: the
/// next point's warm start may be the solution just delivered (the nearest, for a single pool),
/// and a start from an older one costs more iterations than the delivery costs time.
async fn serve(
    options: &PoolOptions,
    mut session: Session,
    solving: &mut Solving,
    stop: &mut watch::Receiver<bool>,
    pending: &mut Option<Delivery>,
    idle_since: &mut Instant,
    progressed: &mut bool,
) -> Break {
    // When the last solve ended: the pool's time between solves is the service's cost.
    let mut last_solved: Option<Instant> = None;
    loop {
        if let Some(delivery) = pending.take() {
            if let Err(reconnect) = deliver(&mut session, delivery, pending, progressed).await {
                return reconnect;
            }
            *idle_since = Instant::now();
        }
        if *stop.borrow() {
            return Break::Stop;
        }
        if options.idle_exit.is_some_and(|limit| idle_since.elapsed() >= limit) {
            tracing::info!(idle = ?idle_since.elapsed(), "no work for too long: stopping");
            return Break::Stop;
        }
        // Poll no longer than the idle limit leaves, so that the limit is kept.
        let wait = options
            .idle_exit
            .map_or(options.wait, |limit| options.wait.min(limit.saturating_sub(idle_since.elapsed())));
        let request = v1::LeasePointRequest { pool_id: session.pool_id.clone(), wait_ms: wait.as_millis() as u64 };
        let asked = Instant::now();
        let leased = tokio::select! {
            r = receive_lease(&mut session.client, request, &solving.scenes) => r,
            _ = stop.changed() => return Break::Stop,
        };
        let (lease, init_bytes, scene) = match leased {
            Ok(Some(l)) => {
                *progressed = true;
                l
            }
            Ok(None) => {
                *progressed = true;
                last_solved = None;
                continue;
            }
            Err(status) if is_transient(&status) => return Break::Reconnect(status.message().to_owned()),
            Err(status) => {
                // A lease stream we could not use: the lease expires and the point goes elsewhere.
                tracing::error!(code = ?status.code(), error = status.message(), "leasing failed");
                tokio::time::sleep(options.backoff.0).await;
                continue;
            }
        };
        *idle_since = Instant::now();
        // Timings of the coordinator's share of a point (docs/performance.md, Service).
        tracing::info!(
            study = lease.study_id,
            point = lease.point_id,
            lease = lease.lease_id,
            init_bytes = lease.init_bytes,
            lease_ms = asked.elapsed().as_secs_f64() * 1e3,
            "leased"
        );
        if *stop.borrow() {
            release(&mut session, &lease).await;
            return Break::Stop;
        }
        let memory = options.memory_budget.or_else(available_memory);
        let job = match prepare(&lease, scene, init_bytes, memory, &mut solving.scenes) {
            Ok(job) => job,
            Err(e) => {
                *pending =
                    Some(Delivery::new(&session.pool_id, Report { lease, outcome: Err(one_line(&format!("{e:#}"))) }));
                continue;
            }
        };
        let scene = job.scene.clone();
        let progress = job.request.progress.clone();
        let (reply_tx, mut reply_rx) = oneshot::channel();
        let solve_started = Instant::now();
        if solving.work.send((job, reply_tx)).is_err() {
            return Break::Stop;
        }
        let Some(outcome) = solved(&mut session, lease.lease_id, progress.as_ref(), &mut reply_rx, stop).await else {
            return Break::Stop;
        };
        if progress.as_ref().is_some_and(|p| p.stop_asked()) {
            // Not the point's fault: given back (a cancelled study's point becomes cancelled; a
            // lost lease's release is refused, and its point is already elsewhere).
            tracing::info!(study = lease.study_id, point = lease.point_id, "solve stopped");
            release(&mut session, &lease).await;
            last_solved = Some(Instant::now());
            continue;
        }
        // What the pool spent between two solves: delivering the last point, leasing this one
        // with its warm start (docs/performance.md, Service).
        let gap = solve_started - last_solved.unwrap_or(asked).min(solve_started);
        last_solved = Some(Instant::now());
        tracing::info!(
            study = lease.study_id,
            point = lease.point_id,
            seconds = solve_started.elapsed().as_secs_f64(),
            gap_ms = gap.as_secs_f64() * 1e3,
            "solved"
        );
        let outcome = outcome.map(|(o, started_cold)| (scene, o, started_cold)).map_err(|e| one_line(&e));
        *pending = Some(Delivery::new(&session.pool_id, Report { lease, outcome }));
    }
}

/// Delivers a solved point: Err (reconnect) when the coordinator is away, the delivery kept
/// `pending` for the next connection; a refusal is logged, the result dropped.
async fn deliver(
    session: &mut Session,
    delivery: Delivery,
    pending: &mut Option<Delivery>,
    progressed: &mut bool,
) -> Result<(), Break> {
    let (study, point) = delivery.point();
    let started = Instant::now();
    match delivery.send(&mut session.client).await {
        Ok(state) => {
            *progressed = true;
            let deliver_ms = started.elapsed().as_secs_f64() * 1e3;
            tracing::info!(study, point, state = ?state, deliver_ms, "delivered");
        }
        Err(status) if is_transient(&status) => {
            *pending = Some(delivery);
            return Err(Break::Reconnect(status.message().to_owned()));
        }
        Err(status) => {
            tracing::error!(study, point, code = ?status.code(), error = status.message(), "the coordinator refused the result");
        }
    }
    Ok(())
}

/// The solve's outcome, heartbeating lease `lease_id` while the point is solved on the main
/// thread (None: the solving thread is gone). The solve stops at its next iteration when the
/// coordinator says so (the study cancelled, the lease lost or past its budget) or at a second
/// signal.
async fn solved<T>(
    session: &mut Session,
    lease_id: u64,
    progress: Option<&std::sync::Arc<glissade_solver::latin::SolveProgress>>,
    reply: &mut oneshot::Receiver<T>,
    stop: &mut watch::Receiver<bool>,
) -> Option<T> {
    let mut ticker = tokio::time::interval(session.heartbeat);
    ticker.tick().await;
    let stop_solve = || {
        if let Some(p) = progress {
            p.stop();
        }
    };
    loop {
        tokio::select! {
            r = &mut *reply => return r.ok(),
            _ = ticker.tick() => {
                let solving = progress.map(|p| p.get()).filter(|&(iterations, _)| iterations > 0);
                if !heartbeat(session, lease_id, solving).await {
                    stop_solve();
                }
            }
            Ok(()) = stop.changed() => {
                if URGENT.load(std::sync::atomic::Ordering::Relaxed) {
                    stop_solve();
                }
            }
        }
    }
}

/// A lease, its warm start's bytes and its scene.
type Leased = (v1::Lease, Vec<u8>, LeasedScene);

/// LeasePoint: the lease, then the warm start's chunks; then, unless its scene is the one kept
/// in `scenes`, each mesh file the lease names (FetchMesh). None when there was no work.
async fn receive_lease(
    client: &mut Pool,
    request: v1::LeasePointRequest,
    scenes: &SceneCache,
) -> Result<Option<Leased>, Status> {
    let mut stream = client.lease_point(request).await?.into_inner();
    let lease = match stream.message().await? {
        Some(v1::LeaseMessage { body: Some(lease_message::Body::Lease(lease)) }) => lease,
        Some(v1::LeaseMessage { body: Some(lease_message::Body::NoWork(_)) }) | None => return Ok(None),
        Some(_) => return Err(Status::internal("LeasePoint: expected a lease first")),
    };
    let mut assembler =
        Assembler::new(lease.init_bytes, MAX_INIT_BYTES).map_err(|e| Status::internal(format!("warm start: {e}")))?;
    while let Some(message) = stream.message().await? {
        match message.body {
            Some(lease_message::Body::InitChunk(chunk)) => {
                assembler.push(chunk).map_err(|e| Status::internal(format!("warm start: {e}")))?
            }
            _ => return Err(Status::internal("LeasePoint: only warm-start chunks may follow the lease")),
        }
    }
    let bytes = assembler.finish().map_err(|e| Status::internal(format!("warm start: {e}")))?;
    let key = SceneKey::of_lease(&lease);
    if let Some(kept) = scenes.get(&key, &lease.scene_hash) {
        return Ok(Some((lease, bytes, LeasedScene::Kept(kept))));
    }
    if lease.meshes.len() > MAX_MESH_FILES {
        return Err(Status::internal(format!(
            "the lease names {} mesh files, more than {MAX_MESH_FILES}",
            lease.meshes.len()
        )));
    }
    let mut meshes = Vec::with_capacity(lease.meshes.len());
    for mesh in &lease.meshes {
        let what = |e: &dyn std::fmt::Display| Status::internal(format!("mesh file '{}': {e}", mesh.file));
        let mut stream = client.fetch_mesh(v1::FetchMeshRequest { sha256: mesh.sha256.clone() }).await?.into_inner();
        let mut assembler = Assembler::new(mesh.bytes, MAX_MESH_FILE_BYTES).map_err(|e| what(&e))?;
        while let Some(chunk) = stream.message().await? {
            assembler.push(chunk).map_err(|e| what(&e))?;
        }
        meshes.push((mesh.file.clone(), assembler.finish().map_err(|e| what(&e))?));
    }
    Ok(Some((lease, bytes, LeasedScene::New { key, meshes })))
}

/// Bytes the system can give a new process now (`MemAvailable` of /proc/meminfo), if known.
pub fn available_memory() -> Option<u64> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = info.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib.saturating_mul(1024))
}

/// What a lease asks of the solver, converted and checked once, at the pool's edge: the swept
/// parameters (names and finite values: the domain type), the tolerance and the iteration limit.
#[derive(Debug, Clone, PartialEq)]
struct Asked {
    parameters: DesignPoint,
    tolerance: Tolerance,
    max_iterations: usize,
}

impl TryFrom<&v1::Lease> for Asked {
    type Error = anyhow::Error;

    fn try_from(lease: &v1::Lease) -> Result<Self> {
        Ok(Self {
            parameters: DesignPoint::try_from(lease.parameters.clone()).context("the lease's parameters")?,
            tolerance: Tolerance::new("the lease's tolerance", lease.tolerance)?,
            max_iterations: check_max_iterations("the lease's max_iterations", lease.max_iterations.into())?,
        })
    }
}

impl Asked {
    /// The solver's request at the lease's point.
    fn request(&self, init_parameters: Option<DesignPoint>) -> SolveRequest {
        SolveRequest {
            point: self.parameters.clone(),
            tolerance: Some(self.tolerance),
            max_iterations: Some(self.max_iterations),
            scale: None,
            record_fields: false,
            progress: Some(Default::default()),
            init_parameters,
        }
    }
}

/// The job of a lease: its scene, the kept one or parsed and kept in `scenes`, with the checks of
/// the scene alone; then at every lease the point's checks, the scene's size against `memory`
/// (bytes), the request built, the warm start read and checked.
fn prepare(
    lease: &v1::Lease,
    scene: LeasedScene,
    init_bytes: Vec<u8>,
    memory: Option<u64>,
    scenes: &mut SceneCache,
) -> Result<PointJob> {
    let prepared = scenes.scene_of(lease, scene)?;
    let scene = &prepared.scene;
    // the coordinator's checks at submit (core::check), again: a scene from an older
    // coordinator, or one whose rules changed since
    let asked = Asked::try_from(lease)?;
    let request = asked.request(None);
    scene.parameter_values(&request.point).and_then(|values| scene.check_point(&values)).context("scene")?;
    let size = prepared.size;
    if let Some(memory) = memory
        && size.bytes() > memory
    {
        bail!(
            "the scene needs about {} MiB ({} dofs, estimated), more than the {} MiB this pool has",
            size.bytes() >> 20,
            size.dofs,
            memory >> 20
        );
    }
    let mut init_parameters = None;
    let mut warm_start_dropped = false;
    let init = if init_bytes.is_empty() {
        None
    } else {
        // A warm start that does not fit is not worth failing the point over: start cold.
        match solution_file::read_from(&init_bytes[..]).map_err(anyhow::Error::from).and_then(|(meta, solution)| {
            meta.check_fits(scene)?;
            Ok((meta, solution))
        }) {
            Ok((meta, solution)) => {
                init_parameters = Some(meta.parameters);
                Some(solution)
            }
            Err(e) => {
                tracing::warn!(error = %e, "warm start unusable; starting cold");
                warm_start_dropped = true;
                None
            }
        }
    };
    let request = SolveRequest { init_parameters, ..request };
    let init_bytes = if init.is_some() { init_bytes } else { Vec::new() };
    Ok(PointJob { scene: prepared, request, init_bytes, init, warm_start_dropped })
}

/// Extends the lease, reporting how far its solve got: (iterations, eta). False when the solve
/// should stop: the coordinator says the lease is no longer ours, or asks to stop it.
async fn heartbeat(session: &mut Session, lease_id: u64, solving: Option<(u64, f64)>) -> bool {
    let request = v1::HeartbeatRequest {
        pool_id: session.pool_id.clone(),
        lease_ids: vec![lease_id],
        progress: solving
            .map(|(iterations, error_indicator)| v1::SolveProgress { lease_id, iterations, error_indicator })
            .into_iter()
            .collect(),
    };
    match session.client.heartbeat(request).await {
        Ok(reply) => {
            let mut go_on = true;
            for lease in reply.into_inner().leases {
                if !lease.valid {
                    tracing::warn!(lease = lease.lease_id, "the coordinator says this lease is no longer ours");
                } else if lease.stop {
                    tracing::info!(lease = lease.lease_id, "the coordinator asks to stop this solve (study cancelled)");
                }
                go_on &= lease.valid && !lease.stop;
            }
            go_on
        }
        // The coordinator may be restarting; the result is kept and delivered after reconnecting.
        Err(status) => {
            tracing::debug!(error = status.message(), "heartbeat failed");
            true
        }
    }
}

async fn release(session: &mut Session, lease: &v1::Lease) {
    let request = v1::ReleasePointRequest {
        pool_id: session.pool_id.clone(),
        lease_id: lease.lease_id,
        study_id: lease.study_id,
        point_id: lease.point_id,
    };
    match session.client.release_point(request).await {
        Ok(_) => tracing::info!(study = lease.study_id, point = lease.point_id, "released"),
        Err(status) => tracing::warn!(error = status.message(), "release failed; the lease will expire"),
    }
}

/// The solution file header of a solve's outcome (what `solve --save` writes too).
pub fn solution_meta(scene: &Scene, outcome: &SolveOutcome) -> SolutionMeta {
    let s = &outcome.summary;
    SolutionMeta {
        solver_version: env!("CARGO_PKG_VERSION").into(),
        scene_hash: scene.content_hash(),
        dimension: scene.dimension,
        time_steps: s.time_steps,
        parameters: s.parameters.clone(),
        converged: s.converged,
        error_indicator: s.error_indicator,
        iterations: s.iterations,
        tolerance: s.tolerance,
        qoi: s.qoi.iter().map(|(k, q)| (k.clone(), q.final_value)).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::scenes::testing::{fetched, lease as scene_lease};
    use super::*;

    fn lease(parameters: &[(&str, f64)], tolerance: f64, max_iterations: u32) -> v1::Lease {
        v1::Lease {
            parameters: parameters.iter().map(|&(k, v)| (k.to_owned(), v)).collect(),
            tolerance,
            max_iterations,
            ..Default::default()
        }
    }

    #[test]
    fn a_lease_is_checked_at_the_edge_and_its_numbers_reach_the_solver_bit_for_bit() {
        let asked = Asked::try_from(&lease(&[("f2", 0.1 + 0.2), ("f1", -1e-300)], 2e-4, 77)).unwrap();
        let request = asked.request(None);
        // name order, every bit kept
        let set: Vec<(&str, u64)> = request.point.iter().map(|(k, v)| (k, v.to_bits())).collect();
        assert_eq!(set, [("f1", (-1e-300f64).to_bits()), ("f2", (0.1f64 + 0.2).to_bits())]);
        assert_eq!((request.tolerance.map(|t| t.get()), request.max_iterations), (Some(2e-4), Some(77)));
        for (bad, needle) in [
            (lease(&[("f1", f64::NAN)], 2e-4, 77), "not finite"),
            (lease(&[(" ", 0.1)], 2e-4, 77), "printable characters"),
            (lease(&[("f1", 0.1)], 0.0, 77), "tolerance"),
            (lease(&[("f1", 0.1)], 1e-30, 77), "tolerance"),
            (lease(&[("f1", 0.1)], 2e-4, 0), "max_iterations"),
        ] {
            let e = format!("{:#}", Asked::try_from(&bad).unwrap_err());
            assert!(e.contains(needle), "{e}");
        }
    }

    #[test]
    fn a_lease_of_the_kept_scene_is_not_parsed_again_and_its_point_is_still_checked() {
        let (joint, meshes) = scene_lease("bolted-joint-tiny.toml");
        let mut scenes = SceneCache::default();
        let first = prepare(&joint, fetched(&joint, &meshes), Vec::new(), None, &mut scenes).unwrap();
        // what receive_lease finds for the next lease of the scene, which fetches no mesh file
        let kept = |lease: &v1::Lease, scenes: &SceneCache| {
            LeasedScene::Kept(scenes.get(&SceneKey::of_lease(lease), &lease.scene_hash).expect("the kept scene"))
        };
        let mut second = joint.clone();
        second.parameters.insert("f".into(), 0.35);
        let job = prepare(&second, kept(&second, &scenes), Vec::new(), None, &mut scenes).unwrap();
        assert!(Arc::ptr_eq(&job.scene, &first.scene));
        assert_eq!((scenes.parsed(), job.request.point.get("f")), (1, Some(0.35)));
        // the point's checks and the memory's run at every lease
        for (parameters, memory, needle) in [
            (vec![("f", -0.5)], None, "must be >= 0"),
            (vec![("g", 0.3)], None, "g"),
            (vec![], Some(1 << 20), "more than the 1 MiB this pool has"),
        ] {
            let mut bad = joint.clone();
            bad.parameters = parameters.into_iter().map(|(k, v)| (k.to_owned(), v)).collect();
            let e = prepare(&bad, kept(&bad, &scenes), Vec::new(), memory, &mut scenes).unwrap_err();
            assert!(format!("{e:#}").contains(needle), "{e:#}");
        }
        assert_eq!(scenes.parsed(), 1);
        // another scene is parsed anew and kept in the first one's place
        let (blocks, none) = scene_lease("three-blocks-tiny.toml");
        assert!(scenes.get(&SceneKey::of_lease(&blocks), &blocks.scene_hash).is_none());
        let job = prepare(&blocks, fetched(&blocks, &none), Vec::new(), None, &mut scenes).unwrap();
        assert!(!Arc::ptr_eq(&job.scene, &first.scene));
        assert_eq!((scenes.parsed(), job.scene.text.as_str()), (2, blocks.scene.as_str()));
        assert!(scenes.get(&SceneKey::of_lease(&joint), &joint.scene_hash).is_none());
    }
}
