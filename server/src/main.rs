//! `glissade-server`: the coordinator of parametric studies (gRPC service + solution database).

mod health;
mod store;

use std::io::IsTerminal;
use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Parser;
use glissade_proto::v1::health_server::HealthServer;
use store::{SledStore, Store};
use tonic::transport::Server;
use tonic::transport::server::TcpIncoming;
use tracing_subscriber::EnvFilter;

/// Coordinator of glissade parametric studies: serves the gRPC API and keeps results in DIR.
///
/// Prints exactly one line `listening on ADDR:PORT` on stdout once it accepts connections
/// (useful with `--listen 127.0.0.1:0`); logs go to stderr (filter with RUST_LOG, default info).
/// Stops cleanly on SIGTERM or Ctrl-C.
#[derive(Debug, Parser)]
#[command(version)]
struct Args {
    /// Directory of the database (created if missing).
    #[arg(long, value_name = "DIR")]
    data: PathBuf,
    /// Address to listen on; port 0 picks a free port.
    #[arg(long, value_name = "ADDR", default_value = "127.0.0.1:50051")]
    listen: SocketAddr,
}

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
    let store = SledStore::open(&args.data).context("opening the database")?;

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

    Server::builder()
        .add_service(HealthServer::new(health::HealthService))
        .serve_with_incoming_shutdown(TcpIncoming::from(listener), shutdown)
        .await
        .context("serving gRPC")?;

    store.flush().context("flushing the database at shutdown")?;
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
