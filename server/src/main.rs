//! `glissade-server`: the coordinator of parametric studies (gRPC service + solution database).

mod convert;
mod coordinator;
mod health;
mod pool;
mod records;
mod store;
mod study;
mod user;

use std::io::IsTerminal;
use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result};
use clap::Parser;
use coordinator::{Config, Coordinator};
use glissade_proto::v1::health_server::HealthServer;
use glissade_proto::v1::pool_server::PoolServer;
use glissade_proto::v1::user_server::UserServer;
use store::SledStore;
use tonic::transport::Server;
use tonic::transport::server::TcpIncoming;
use tracing_subscriber::EnvFilter;

/// Coordinator of glissade parametric studies: serves the gRPC API (services glissade.v1.User,
/// glissade.v1.Pool, glissade.v1.Health, and server reflection) and keeps studies and solutions
/// in a database in DIR.
///
/// Prints exactly one line `listening on ADDR:PORT` on stdout once it accepts connections
/// (useful with `--listen 127.0.0.1:0`); logs go to stderr (filter with RUST_LOG, default info).
/// Stops cleanly on SIGTERM or Ctrl-C. Every option can also be set by its environment variable
/// (deploy/coordinator.env is an example for systemd's EnvironmentFile).
#[derive(Debug, Parser)]
#[command(version)]
struct Args {
    /// Directory of the database (created if missing).
    #[arg(long, value_name = "DIR", env = "GLISSADE_DATA")]
    data: PathBuf,
    /// Address to listen on; port 0 picks a free port.
    #[arg(long, value_name = "ADDR", default_value = "127.0.0.1:50051", env = "GLISSADE_LISTEN")]
    listen: SocketAddr,
    /// How long a pool holds a design point without a heartbeat before it goes to another pool.
    #[arg(long, value_name = "SECONDS", default_value_t = 60.0, env = "GLISSADE_LEASE_SECONDS")]
    lease_seconds: f64,
    /// Leases granted to one point before a lost lease marks it failed (RetryFailed requeues it).
    #[arg(long, value_name = "N", default_value_t = 3, env = "GLISSADE_MAX_ATTEMPTS")]
    max_attempts: u32,
    /// Largest solution file a pool may send, MiB.
    #[arg(long, value_name = "MIB", default_value_t = 4096, env = "GLISSADE_MAX_SOLUTION_MIB")]
    max_solution_mib: u64,
}

/// How long a stopping coordinator waits for open connections to finish their calls.
const SHUTDOWN_GRACE: Duration = Duration::from_secs(5);

fn main() -> ExitCode {
    let args = Args::parse();
    tracing_subscriber::fmt()
        .with_env_filter(EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("info")))
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .init();
    let result =
        tokio::runtime::Runtime::new().context("starting the tokio runtime").and_then(|rt| rt.block_on(run(args)));
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // One line with the context chain; no Debug dump or backtrace for an operator to parse.
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

async fn run(args: Args) -> Result<()> {
    std::fs::create_dir_all(&args.data).with_context(|| format!("creating data directory {}", args.data.display()))?;
    if !(args.lease_seconds.is_finite() && args.lease_seconds >= 0.05) {
        anyhow::bail!("--lease-seconds {}: give at least 0.05", args.lease_seconds);
    }
    if args.max_attempts == 0 {
        anyhow::bail!("--max-attempts 0: give at least 1");
    }
    let store = SledStore::open(&args.data).context("opening the database")?;
    let config = Config {
        lease: Duration::from_secs_f64(args.lease_seconds),
        max_attempts: args.max_attempts,
        max_solution_bytes: args.max_solution_mib.saturating_mul(1 << 20),
        solver_version: env!("CARGO_PKG_VERSION").to_owned(),
    };
    let coordinator = Arc::new(Coordinator::open(Arc::new(store), config).context("loading the database")?);
    // Both reflection versions: grpcurl asks v1 first, older tools (grpcio-reflection) v1alpha.
    let reflection = || {
        tonic_reflection::server::Builder::configure()
            .register_encoded_file_descriptor_set(glissade_proto::FILE_DESCRIPTOR_SET)
    };
    let reflection_v1 = reflection().build_v1().context("building the reflection service")?;
    let reflection_v1alpha = reflection().build_v1alpha().context("building the reflection service")?;

    // Bind before announcing, so the printed port is already accepting connections.
    let listener =
        tokio::net::TcpListener::bind(args.listen).await.with_context(|| format!("binding {}", args.listen))?;
    let addr = listener.local_addr().context("reading the bound address")?;
    // Install the handlers before announcing the port: a SIGTERM right after it must not kill us
    // with the default action and skip the database flush.
    let shutdown = shutdown_signal()?;
    {
        let mut out = std::io::stdout().lock();
        writeln!(out, "listening on {addr}").context("writing to stdout")?;
        out.flush().context("flushing stdout")?;
    }
    tracing::info!(%addr, version = env!("CARGO_PKG_VERSION"), "serving");

    // Leases of pools that stopped answering expire even while no pool asks for work.
    let expiry = {
        let c = coordinator.clone();
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
    };

    let (stopping_tx, stopping_rx) = tokio::sync::oneshot::channel();
    let serve = Server::builder()
        .add_service(HealthServer::new(health::HealthService))
        .add_service(UserServer::new(user::UserService { coordinator: coordinator.clone() }))
        .add_service(PoolServer::new(pool::PoolService::new(coordinator.clone())))
        .add_service(reflection_v1)
        .add_service(reflection_v1alpha)
        // No Nagle: a lease is several small messages, and delayed ACKs would add 40 ms to each.
        .serve_with_incoming_shutdown(TcpIncoming::from(listener).with_nodelay(Some(true)), {
            let c = coordinator.clone();
            async move {
                shutdown.await;
                // End long polls and event streams, or the graceful shutdown would wait for them.
                c.stop();
                let _ = stopping_tx.send(());
            }
        });
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

    coordinator.flush().context("flushing the database at shutdown")?;
    tracing::info!("stopped");
    Ok(())
}

/// Installs SIGTERM (what service managers and `kill` send) and SIGINT (Ctrl-C) handlers now,
/// and returns a future that resolves on the first of them.
fn shutdown_signal() -> Result<impl Future<Output = ()>> {
    use tokio::signal::unix::{SignalKind, signal};
    let mut term = signal(SignalKind::terminate()).context("installing the SIGTERM handler")?;
    let mut int = signal(SignalKind::interrupt()).context("installing the SIGINT handler")?;
    Ok(async move {
        tokio::select! {
            _ = term.recv() => tracing::info!("SIGTERM received, shutting down"),
            _ = int.recv() => tracing::info!("SIGINT received, shutting down"),
        }
    })
}
