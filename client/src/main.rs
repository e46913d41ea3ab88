//! `glissade`: command-line client of the glissade coordinator.

use std::io::IsTerminal;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Context, Result, anyhow};
use clap::{Parser, Subcommand, ValueEnum};
use glissade_proto::v1::health_client::HealthClient;
use glissade_proto::v1::user_client::UserClient;
use glissade_proto::v1::{self, HealthRequest};
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
      glissade submit scenes/three-blocks-tiny.toml --grid f1=0.1:0.2:3 --grid f2=0.1:0.2:3\n  \
      glissade show 1 --points\n  \
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
    /// Submit a parametric study of a scene; prints the study id.
    Submit(SubmitArgs),
    /// Show a study: its state, progress and (with --points) every design point.
    Show {
        /// The study id (from `glissade submit`).
        study: u64,
        /// List every design point with its parameters, iterations, eta and QoIs.
        #[arg(long)]
        points: bool,
        /// Print one JSON object instead of text.
        #[arg(long)]
        json: bool,
    },
}

#[derive(Debug, clap::Args)]
struct SubmitArgs {
    /// Scene file (TOML); its text is sent to the coordinator.
    scene: std::path::PathBuf,
    /// A swept parameter, NAME=START:STOP:COUNT, NAME=V1,V2,... or NAME=lhs:N:SEED (repeatable;
    /// the study is the product of the grids).
    #[arg(long, value_name = "NAME=SPEC", required = true)]
    grid: Vec<String>,
    /// Tolerance on the error indicator (default: the scene's).
    #[arg(long, value_name = "T")]
    tol: Option<f64>,
    /// Iteration limit per point (default: the scene's).
    #[arg(long, value_name = "N")]
    max_iter: Option<u32>,
    /// Where each point's iterations start.
    #[arg(long, value_enum, default_value = "nearest")]
    strategy: StrategyArg,
    /// Neighbours a blend (or a linear extrapolation) combines.
    #[arg(long, value_name = "K", default_value_t = 3)]
    k: u32,
    /// Which pending point goes to the next free pool.
    #[arg(long, value_enum, default_value = "greedy")]
    order: OrderArg,
    /// Free text shown with the study.
    #[arg(long, default_value = "")]
    label: String,
    /// Print one JSON object instead of the study id.
    #[arg(long)]
    json: bool,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum StrategyArg {
    Cold,
    Previous,
    Nearest,
    Blend,
    Linear,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum OrderArg {
    Asc,
    Desc,
    Greedy,
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
        Command::Submit(args) => submit(&cli.server, args).await,
        Command::Show { study, points, json } => show(&cli.server, study, points, json).await,
    }
}

/// One line for a refused call: what was asked, the server's reason, the status code.
fn refused(what: &str, status: tonic::Status) -> anyhow::Error {
    let message = status.message().lines().map(str::trim).collect::<Vec<_>>().join(" ");
    anyhow!("{what}: {message} ({:?})", status.code())
}

async fn submit(server: &str, args: SubmitArgs) -> Result<()> {
    let scene =
        std::fs::read_to_string(&args.scene).with_context(|| format!("cannot read scene {}", args.scene.display()))?;
    let request = v1::SubmitStudyRequest {
        scene,
        grid: args.grid,
        points: Vec::new(),
        tolerance: args.tol,
        strategy: match args.strategy {
            StrategyArg::Cold => v1::InitStrategy::Cold,
            StrategyArg::Previous => v1::InitStrategy::Previous,
            StrategyArg::Nearest => v1::InitStrategy::Nearest,
            StrategyArg::Blend => v1::InitStrategy::Blend,
            StrategyArg::Linear => v1::InitStrategy::Linear,
        }
        .into(),
        order: match args.order {
            OrderArg::Asc => v1::PointOrder::Ascending,
            OrderArg::Desc => v1::PointOrder::Descending,
            OrderArg::Greedy => v1::PointOrder::Greedy,
        }
        .into(),
        max_iterations: args.max_iter,
        label: args.label,
        blend_neighbours: args.k,
    };
    let channel = connect(server).await?;
    let reply = UserClient::new(channel)
        .submit_study(request)
        .await
        .map_err(|s| refused(&format!("submit {}", args.scene.display()), s))?
        .into_inner();
    if args.json {
        let value = serde_json::json!({
            "study_id": reply.study_id,
            "points": reply.points,
            "scene_hash": reply.scene_hash,
        });
        println!("{value}");
    } else {
        println!("{}", reply.study_id);
    }
    Ok(())
}

fn state_name(state: i32) -> &'static str {
    match v1::StudyState::try_from(state) {
        Ok(v1::StudyState::Active) => "active",
        Ok(v1::StudyState::Done) => "done",
        Ok(v1::StudyState::Failed) => "failed",
        Ok(v1::StudyState::Cancelled) => "cancelled",
        _ => "unknown",
    }
}

fn point_state_name(state: i32) -> &'static str {
    match v1::PointState::try_from(state) {
        Ok(v1::PointState::Pending) => "pending",
        Ok(v1::PointState::Leased) => "leased",
        Ok(v1::PointState::Done) => "done",
        Ok(v1::PointState::Failed) => "failed",
        Ok(v1::PointState::Cancelled) => "cancelled",
        _ => "unknown",
    }
}

fn strategy_name(strategy: i32) -> &'static str {
    match v1::InitStrategy::try_from(strategy) {
        Ok(v1::InitStrategy::Cold) => "cold",
        Ok(v1::InitStrategy::Previous) => "previous",
        Ok(v1::InitStrategy::Nearest) => "nearest",
        Ok(v1::InitStrategy::Blend) => "blend",
        Ok(v1::InitStrategy::Linear) => "linear",
        _ => "unknown",
    }
}

fn order_name(order: i32) -> &'static str {
    match v1::PointOrder::try_from(order) {
        Ok(v1::PointOrder::Ascending) => "asc",
        Ok(v1::PointOrder::Descending) => "desc",
        Ok(v1::PointOrder::Greedy) => "greedy",
        _ => "unknown",
    }
}

fn point_json(p: &v1::PointStatus) -> serde_json::Value {
    serde_json::json!({
        "point_id": p.point_id,
        "parameters": p.parameters,
        "state": point_state_name(p.state),
        "attempts": p.attempts,
        "pool_id": p.pool_id,
        "iterations": p.iterations,
        "error_indicator": p.error_indicator,
        "qoi": p.qoi,
        "answered": p.answered,
        "wall_seconds": p.wall_seconds,
        "started_from": p.started_from.as_ref().map(|s| serde_json::json!({
            "scene_hash": s.scene_hash,
            "parameters": s.parameters,
            "study_id": s.study_id,
            "point_id": s.point_id,
        })),
        "error": if p.error.is_empty() { None } else { Some(&p.error) },
    })
}

async fn show(server: &str, study: u64, points: bool, json: bool) -> Result<()> {
    let channel = connect(server).await?;
    let s = UserClient::new(channel)
        .get_study(v1::GetStudyRequest { study_id: study, points })
        .await
        .map_err(|status| refused(&format!("show {study}"), status))?
        .into_inner();
    let p = s.progress.unwrap_or_default();
    if json {
        let mut value = serde_json::json!({
            "study_id": s.study_id,
            "label": s.label,
            "scene_hash": s.scene_hash,
            "state": state_name(s.state),
            "strategy": strategy_name(s.strategy),
            "order": order_name(s.order),
            "tolerance": s.tolerance,
            "max_iterations": s.max_iterations,
            "parameters": s.parameters,
            "progress": {
                "total": p.total, "pending": p.pending, "leased": p.leased, "done": p.done,
                "failed": p.failed, "cancelled": p.cancelled, "iterations": p.iterations,
            },
            "created_unix_ms": s.created_unix_ms,
        });
        if points {
            value["points"] = s.points.iter().map(point_json).collect();
        }
        println!("{value}");
        return Ok(());
    }
    println!(
        "study {}{}: {}",
        s.study_id,
        if s.label.is_empty() { String::new() } else { format!(" ({})", s.label) },
        state_name(s.state)
    );
    println!("  scene     {}", s.scene_hash);
    println!(
        "  sweep     {} ({} points), strategy {}, order {}",
        s.parameters.join(", "),
        p.total,
        strategy_name(s.strategy),
        order_name(s.order)
    );
    println!("  tolerance {:.1e}, at most {} iterations", s.tolerance, s.max_iterations);
    println!(
        "  progress  {} done, {} failed, {} running, {} pending{}; {} iterations in all",
        p.done,
        p.failed,
        p.leased,
        p.pending,
        if p.cancelled > 0 { format!(", {} cancelled", p.cancelled) } else { String::new() },
        p.iterations
    );
    for point in &s.points {
        let params: Vec<String> = point.parameters.iter().map(|(k, v)| format!("{k}={v}")).collect();
        let qoi: Vec<String> = point.qoi.iter().map(|(k, v)| format!("{k}={v:.6e}")).collect();
        let from = match &point.started_from {
            _ if point.answered => "answered from a stored solution".to_owned(),
            Some(f) => {
                format!("from {}", f.parameters.iter().map(|(k, v)| format!("{k}={v}")).collect::<Vec<_>>().join(" "))
            }
            None if point.state == v1::PointState::Done as i32 => "cold".to_owned(),
            None => String::new(),
        };
        println!(
            "  #{:<4} {:<28} {:<9} {:>5} it  eta {:.2e}  {}  {}{}",
            point.point_id,
            params.join(" "),
            point_state_name(point.state),
            point.iterations,
            point.error_indicator,
            qoi.join(" "),
            from,
            if point.error.is_empty() { String::new() } else { format!("  [{}]", point.error) }
        );
    }
    Ok(())
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
