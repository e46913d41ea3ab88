//! `glissade-server`: the coordinator of parametric studies (gRPC service + solution database).

use std::io::IsTerminal;
use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Context, Result};
use clap::Parser;
use glissade_proto::auth::Token;
use glissade_server::ServerOptions;
use glissade_server::auth::Tokens;
use tracing_subscriber::filter::{LevelFilter, Targets};
use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::util::SubscriberInitExt;

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
    /// Most design points in one study; a bigger grid is refused before it is built. Each point
    /// costs the coordinator about 6 kB of memory and 0.5 kB on disk (docs/performance.md).
    #[arg(long, value_name = "N", default_value_t = glissade_server::DEFAULT_MAX_POINTS, env = "GLISSADE_MAX_POINTS")]
    max_points: usize,
    /// Most design points pending over all studies (and per user token: there is one); a
    /// submission that would pass it is refused. Cancelling a study frees its share.
    #[arg(long, value_name = "N", default_value_t = glissade_server::DEFAULT_MAX_PENDING, env = "GLISSADE_MAX_PENDING")]
    max_pending: usize,
    /// Longest a point may be held by pools, counted from its lease whatever the heartbeats
    /// say; then it fails (retry requeues it) and its pool is told to stop.
    #[arg(long, value_name = "SECONDS", default_value_t = 86400.0, env = "GLISSADE_POINT_SECONDS")]
    point_seconds: f64,
    /// A connection that sends nothing for this long is closed (HTTP/2 clients answer the
    /// keepalive pings sent every quarter of it, so open streams and long polls stay up).
    #[arg(long, value_name = "SECONDS", default_value_t = 60.0, env = "GLISSADE_IDLE_SECONDS")]
    idle_seconds: f64,
    /// Web requests (the page, the JSON API, /metrics; not its static files) a second from one
    /// client address, on average, two seconds' worth at once: more get 429 with Retry-After,
    /// so a client reading as fast as it is answered cannot take the cores the studies need.
    /// gRPC calls are not counted.
    #[arg(long, value_name = "N", default_value_t = glissade_server::DEFAULT_WEB_READS_PER_SECOND, env = "GLISSADE_WEB_READS_PER_SECOND")]
    web_reads_per_second: f64,
    /// Where there are tokens: a connection that has not presented a valid one within this long
    /// is closed, and at the connection limit a new connection displaces the oldest such
    /// connection (strangers cannot hold the slots that clients with a token need).
    #[arg(long, value_name = "SECONDS", default_value_t = 10.0, env = "GLISSADE_PROBATION_SECONDS")]
    probation_seconds: f64,
    /// Most connections open at once; more are closed as they arrive. Keep it below the
    /// process's file limit (`ulimit -n`).
    #[arg(long, value_name = "N", default_value_t = glissade_server::DEFAULT_MAX_CONNECTIONS, env = "GLISSADE_MAX_CONNECTIONS")]
    max_connections: usize,
    /// Most connections open at once from one client address (a host that holds its share has
    /// its next connections closed as they arrive); raise it where many pools reach the
    /// coordinator through one NAT address
    #[arg(long, value_name = "N", default_value_t = glissade_server::DEFAULT_MAX_CONNECTIONS_PER_CLIENT, env = "GLISSADE_MAX_CONNECTIONS_PER_CLIENT")]
    max_connections_per_client: usize,
    /// Largest estimated memory of one solve of a submitted scene, MiB (estimated from the
    /// scene's text: dofs and interface size; docs/performance.md, "Memory per design point, and of one solve").
    #[arg(long, value_name = "MIB", default_value_t = glissade_server::DEFAULT_MAX_SCENE_MIB, env = "GLISSADE_MAX_SCENE_MIB")]
    max_scene_mib: u64,
    /// File holding the token users present (submit, watch, cancel, query); with
    /// --pool-token-file. Without tokens the coordinator listens on loopback only.
    #[arg(long, value_name = "FILE", env = "GLISSADE_USER_TOKEN_FILE", requires = "pool_token_file")]
    user_token_file: Option<PathBuf>,
    /// File holding the token pools present (lease, heartbeat, complete, fail).
    #[arg(long, value_name = "FILE", env = "GLISSADE_POOL_TOKEN_FILE", requires = "user_token_file")]
    pool_token_file: Option<PathBuf>,
    /// Serve without tokens on a non-loopback address: only where every host that can reach
    /// the port is trusted.
    #[arg(long, env = "GLISSADE_OPEN")]
    open: bool,
    /// PEM certificate (chain) to serve TLS with; clients then use https:// URLs.
    #[arg(long, value_name = "FILE", env = "GLISSADE_TLS_CERT", requires = "tls_key")]
    tls_cert: Option<PathBuf>,
    /// PEM private key of --tls-cert.
    #[arg(long, value_name = "FILE", env = "GLISSADE_TLS_KEY", requires = "tls_cert")]
    tls_key: Option<PathBuf>,
}

fn main() -> ExitCode {
    let args = Args::parse();
    // RUST_LOG as `target=level` directives (a filter without regular expressions to build)
    let filter = std::env::var("RUST_LOG")
        .ok()
        .and_then(|v| v.parse::<Targets>().ok())
        .unwrap_or_else(|| Targets::new().with_default(LevelFilter::INFO));
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .finish()
        .with(filter)
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
    if !(args.lease_seconds.is_finite() && args.lease_seconds >= 0.05) {
        anyhow::bail!("--lease-seconds {}: give at least 0.05", args.lease_seconds);
    }
    if args.max_attempts == 0 {
        anyhow::bail!("--max-attempts 0: give at least 1");
    }
    let seconds = |name: &str, value: f64, least: f64| {
        if value.is_finite() && value >= least && value <= 1e9 {
            Ok(Duration::from_secs_f64(value))
        } else {
            Err(anyhow::anyhow!("{name} {value}: give {least} to 1e9 seconds"))
        }
    };
    let options = ServerOptions {
        point_budget: seconds("--point-seconds", args.point_seconds, 1.0)?,
        idle: seconds("--idle-seconds", args.idle_seconds, 0.1)?,
        probation: seconds("--probation-seconds", args.probation_seconds, 0.1)?,
        max_connections: args.max_connections,
        web_reads_per_second: args.web_reads_per_second,
        max_connections_per_client: args.max_connections_per_client,
        max_pending: args.max_pending,
        data: args.data,
        lease: Duration::from_secs_f64(args.lease_seconds),
        max_attempts: args.max_attempts,
        max_solution_bytes: args.max_solution_mib.saturating_mul(1 << 20),
        max_points: args.max_points,
        max_scene_bytes: args.max_scene_mib.saturating_mul(1 << 20),
        tokens: match (&args.user_token_file, &args.pool_token_file) {
            (Some(u), Some(p)) => {
                let tokens = Tokens { user: Token::from_file(u)?, pool: Token::from_file(p)? };
                if tokens.user == tokens.pool {
                    anyhow::bail!("the user and pool tokens are the same: give each role its own");
                }
                Some(tokens)
            }
            _ => None,
        },
        open: args.open,
        tls: match (&args.tls_cert, &args.tls_key) {
            (Some(c), Some(k)) => Some((
                std::fs::read(c).with_context(|| format!("reading --tls-cert {}", c.display()))?,
                std::fs::read(k).with_context(|| format!("reading --tls-key {}", k.display()))?,
            )),
            _ => None,
        },
    };
    // Install the handlers before announcing the port: a SIGTERM right after it must not kill us
    // with the default action and skip the database flush.
    let shutdown = shutdown_signal()?;
    // Bound before announcing, so the printed port is already accepting connections.
    let scheme = if options.tls.is_some() { "https" } else { "http" };
    let (addr, serve) = glissade_server::bind(options, args.listen, shutdown).await?;
    {
        let mut out = std::io::stdout().lock();
        writeln!(out, "listening on {addr}").context("writing to stdout")?;
        out.flush().context("flushing stdout")?;
    }
    tracing::info!(%addr, version = env!("CARGO_PKG_VERSION"), "serving");
    // the web page, for people (stdout stays the one line above, for scripts)
    eprintln!("web page: {scheme}://{addr}/");
    serve.await
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
