//! `glissade`: command-line client of the glissade coordinator.

use std::io::IsTerminal;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Context, Result, anyhow};
use clap::{Parser, Subcommand};
use glissade_proto::v1::HealthRequest;
use glissade_proto::v1::health_client::HealthClient;
use tonic::transport::{Channel, Endpoint};
use tracing_subscriber::EnvFilter;

/// How long to wait for the coordinator to accept a connection before giving up.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(5);

/// Command-line client of glissade, a parametric-study service for transient dynamics with
/// contact and friction.
#[derive(Debug, Parser)]
#[command(
    version,
    after_help = "Examples:\n  \
      glissade health\n  \
      glissade --server http://10.0.0.5:50051 health --json\n  \
      GLISSADE_SERVER=http://coordinator:50051 glissade health\n\n\
      Logs go to stderr; set RUST_LOG=debug for details."
)]
struct Cli {
    /// URL of the glissade coordinator (glissade-server).
    #[arg(long, global = true, env = "GLISSADE_SERVER", value_name = "URL", default_value = "http://127.0.0.1:50051")]
    server: String,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Check that the coordinator is up, and print its status and version.
    Health {
        /// Print one JSON object instead of text.
        #[arg(long)]
        json: bool,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    tracing_subscriber::fmt()
        .with_env_filter(EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("warn")))
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .init();
    let result = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("starting the tokio runtime")
        .and_then(|rt| rt.block_on(run(cli)));
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // A CLI user wants one readable line, not a Debug dump or a backtrace.
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

async fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Health { json } => health(&cli.server, json).await,
    }
}

async fn health(server: &str, json: bool) -> Result<()> {
    let channel = connect(server).await?;
    let reply = HealthClient::new(channel)
        .check(HealthRequest {})
        .await
        .map_err(|status| anyhow!("health check at {server} failed: {} ({:?})", status.message(), status.code()))?
        .into_inner();
    if json {
        let value = serde_json::json!({
            "server": server,
            "status": reply.status,
            "version": reply.version,
        });
        println!("{value}");
    } else {
        println!("status:  {}", reply.status);
        println!("version: {}", reply.version);
    }
    Ok(())
}

/// Connects to `server`, turning transport errors into one line that says what went wrong.
async fn connect(server: &str) -> Result<Channel> {
    let invalid = || anyhow!("invalid server URL `{server}` (expected e.g. http://host:50051)");
    let endpoint = Endpoint::from_shared(server.to_owned()).map_err(|_| invalid())?.connect_timeout(CONNECT_TIMEOUT);
    // `Endpoint` accepts relative URIs such as `localhost:50051`; catch them before connecting.
    let uri = endpoint.uri();
    if !matches!(uri.scheme_str(), Some("http" | "https")) || uri.host().is_none() {
        return Err(invalid());
    }
    tracing::debug!(server, "connecting");
    endpoint.connect().await.map_err(|e| {
        tracing::debug!(error = ?e, "connect failed");
        anyhow!("cannot reach glissade server at {server}: {}", root_cause(&e))
    })
}

/// The innermost cause of a transport error, in words (tonic's own message is only
/// "transport error"; the useful part, e.g. "connection refused", sits at the bottom).
fn root_cause(error: &(dyn std::error::Error + 'static)) -> String {
    let mut current = error;
    let mut io_error = current.downcast_ref::<std::io::Error>();
    while let Some(next) = current.source() {
        current = next;
        io_error = current.downcast_ref::<std::io::Error>().or(io_error);
    }
    if let Some(io) = io_error {
        return match io.kind() {
            std::io::ErrorKind::ConnectionRefused => "connection refused".to_owned(),
            std::io::ErrorKind::TimedOut => {
                format!("no answer within {}s", CONNECT_TIMEOUT.as_secs())
            }
            _ => io.to_string(),
        };
    }
    let text = current.to_string();
    // Timeouts surface as a bare "timed out" from tower/hyper without an io::Error.
    if text.contains("timed out") { format!("no answer within {}s", CONNECT_TIMEOUT.as_secs()) } else { text }
}
