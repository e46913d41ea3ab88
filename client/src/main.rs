//! `glissade`: the command-line client of the glissade coordinator: submit design grids, watch
//! them run, read and plot response surfaces, fetch fields, or run everything locally (`demo`).

mod demo;
mod fields;

use glissade_cli::{out, outln};
use glissade_core::text::one_line;
use glissade_proto::now_unix_ms;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};
use clap::{Parser, Subcommand};
use glissade_cli::names::{describe_parameters, order_name, point_state_name, strategy_name, study_state_name};
use glissade_cli::progress::WatchState;
use glissade_cli::surface::{Predictions, SurfaceTable, parse_fixed};
use glissade_core::scene::Scene;
use glissade_core::scene::check_tolerance;
use glissade_core::study::order::OrderKind;
use glissade_core::study::strategy::StrategyKind;
use glissade_plot::study::Picture;
use glissade_plot::{self as plot, ConvergenceSeries};
use glissade_proto::auth::{Token, WithToken};
use glissade_proto::v1::health_client::HealthClient;
use glissade_proto::v1::user_client::UserClient;
use glissade_proto::v1::{self, HealthRequest};
use tonic::service::interceptor::InterceptedService;
use tonic::transport::Channel;
use tonic::{Code, Status};
use tracing_subscriber::EnvFilter;

/// How long to wait for the coordinator to accept a connection before giving up.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(5);

/// Command-line client of glissade, a parametric-study service for transient dynamics with
/// contact and friction.
#[derive(Debug, Parser)]
#[command(
    version,
    after_help = "Examples:\n  \
      glissade demo                                  # everything on this machine, in a minute\n  \
      glissade submit scenes/three-blocks-tiny.toml --grid f1=0.1:0.2:11 --grid f2=0.1:0.2:11 --watch\n  \
      glissade watch 1\n  \
      glissade studies\n  \
      glissade surface 1 --qoi slip_A --png slip_A.png\n  \
      glissade surface 1 --qoi slip_A --fix f2=0.15 --csv slice.csv\n  \
      glissade convergence 1 --png convergence.png\n  \
      glissade fields 1 --point f1=0.12,f2=0.15 --out point.h5   # open point.xdmf in ParaView\n  \
      GLISSADE_SERVER=http://coordinator:50051 glissade health\n\n\
      Logs go to stderr; set RUST_LOG=debug for details."
)]
struct Cli {
    /// URL of the glissade coordinator (glissade-server).
    #[arg(long, global = true, env = "GLISSADE_SERVER", value_name = "URL", default_value = "http://127.0.0.1:50051")]
    server: String,
    /// File holding the user token of a coordinator that asks for one (else GLISSADE_TOKEN,
    /// else the file GLISSADE_TOKEN_FILE names).
    #[arg(long, global = true, value_name = "FILE")]
    token_file: Option<PathBuf>,
    /// PEM certificate of the authority that signed an https:// coordinator's certificate
    /// (else GLISSADE_CA_CERT, else the system's roots).
    #[arg(long, global = true, value_name = "FILE")]
    ca_cert: Option<PathBuf>,
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
    /// Submit a parametric study of a scene; prints the study id (--watch: then follows it).
    #[command(after_help = "Examples:\n  \
        glissade submit scenes/three-blocks-small.toml --grid f1=0.10:0.20:11 --grid f2=0.10:0.20:11 --watch\n  \
        glissade submit scene.toml --grid f1=0.1,0.15,0.2 --grid v0=lhs:20:7 --tol 1e-4 --strategy linear --k 8\n  \
        glissade submit scene.toml --grid f1=0.1:0.2:5 --json | jq .study_id")]
    Submit(SubmitArgs),
    /// Follow a study until it ends: points done / running / pending, iterations cold vs warm,
    /// ETA; a summary at the end. Without a terminal, one plain line per event.
    Watch {
        /// The study id (from `glissade submit`).
        study: u64,
    },
    /// List the studies with their state and progress.
    Studies {
        /// Print one JSON object instead of a table.
        #[arg(long)]
        json: bool,
    },
    /// Show a study: its state, progress and (with --points) every design point.
    Show {
        /// The study id.
        study: u64,
        /// List every design point with its parameters, iterations, eta and QoIs.
        #[arg(long)]
        points: bool,
        /// Print one JSON object instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Stop handing out a study's points (points being solved still finish and are kept).
    Cancel {
        /// The study id.
        study: u64,
    },
    /// Put a study's failed points back in the queue.
    Retry {
        /// The study id.
        study: u64,
    },
    /// The response surface of a study: a table, CSV, JSON, or a PNG (a colour map with contour
    /// lines over two parameters, a curve over one).
    #[command(after_help = "Examples:\n  \
        glissade surface 3                                   # every QoI of every point, a table\n  \
        glissade surface 3 --qoi slip_A --png slip_A.png     # colour map over the two swept parameters\n  \
        glissade surface 3 --qoi slip_A --fix f2=0.15 --png slice.png --csv slice.csv   # a curve over f1\n  \
        glissade surface 3 --all-solutions --json            # every stored solution of the scene")]
    Surface(SurfaceArgs),
    /// The error indicator against the iterations of every point of a study (PNG or JSON).
    #[command(after_help = "Examples:\n  \
        glissade convergence 3 --png convergence.png\n  \
        glissade convergence 3 --json | jq '.points[0].eta_history | length'")]
    Convergence(ConvergenceArgs),
    /// The displacement and velocity fields of one design point as HDF5 + XDMF (ParaView):
    /// re-solved here from the nearest stored solution of the study (a few iterations).
    #[command(after_help = "Examples:\n  \
        glissade fields 3 --point f1=0.15,f2=0.15 --out p.h5          # a point of the study: 1 iteration a stage\n  \
        glissade fields 3 --point f1=0.123,f2=0.187 --out q.h5        # any point: from its nearest neighbour\n\n\
        Then open p.xdmf in ParaView (displacement and velocity at every time step).")]
    Fields(fields::FieldsArgs),
    /// Run a small study of the three-blocks scene on this machine, with no set-up: an embedded
    /// coordinator on a temporary database, one local pool, progress, the response surface and
    /// its pictures.
    #[command(after_help = "Examples:\n  \
        glissade demo\n  \
        glissade demo --grid 9 --out /tmp/demo     # 81 points")]
    Demo(demo::DemoArgs),
}

#[derive(Debug, clap::Args)]
#[command(group(clap::ArgGroup::new("adaptive_kind").args(["adaptive", "surface_accuracy"]).multiple(true)))]
struct SubmitArgs {
    /// Scene file (TOML); its text is sent to the coordinator.
    scene: PathBuf,
    /// A swept parameter, NAME=START:STOP:COUNT, NAME=V1,V2,... or NAME=lhs:N:SEED (repeatable;
    /// the study is the product of the grids).
    #[arg(long, value_name = "NAME=SPEC", required_unless_present_any = ["adaptive", "range"], conflicts_with = "adaptive_kind")]
    grid: Vec<String>,
    /// An adaptive study of N points instead of a grid: the first spread over the --range box,
    /// then each where the response surface is least sure (docs/surrogate.md)
    #[arg(long, value_name = "N", requires = "range")]
    adaptive: Option<u32>,
    /// The box of an adaptive study, NAME=LOW:HIGH (repeatable, one per swept parameter)
    #[arg(long, value_name = "NAME=LOW:HIGH", requires = "adaptive_kind")]
    range: Vec<String>,
    /// An adaptive study over the --range box that adds points until the cross-validated mean
    /// error of every QoI's surface is within this share of the QoI's spread (0.02: 2 %), or its
    /// budget (--adaptive N; default 100) is spent, and says which (`glissade show`); its points
    /// are solved to --tol, default this / 30 (docs/surrogate.md, "Adaptive to a target")
    #[arg(long, value_name = "SHARE", requires = "range")]
    surface_accuracy: Option<f64>,
    /// Tolerance on the error indicator (default: the scene's).
    #[arg(long, value_name = "T")]
    tol: Option<f64>,
    /// Iteration limit per point (default: the scene's).
    #[arg(long, value_name = "N")]
    max_iter: Option<u32>,
    /// Where each point's iterations start (default: linear, a fit of the solved neighbours).
    #[arg(long, value_enum)]
    strategy: Option<StrategyKind>,
    /// Neighbours a blend (or a linear fit) combines (default: 3 for blend, 8 for linear).
    #[arg(long, value_name = "K", default_value_t = 0, hide_default_value = true)]
    k: u32,
    /// Which pending point goes to the next free pool.
    #[arg(long, value_enum, default_value = "greedy")]
    order: OrderKind,
    /// Free text shown with the study.
    #[arg(long, default_value = "")]
    label: String,
    /// Points re-solved cold at 1/100 of the tolerance when pools are idle, to measure the
    /// accuracy the study got (`glissade show`); default: 10 % of the points, at least 2; 0: none
    #[arg(long, value_name = "N")]
    audit: Option<u32>,
    /// Points re-solved cold with the time step halved when pools are idle, to measure the
    /// discretisation error beside the iterations' (`glissade show`); default: 2; 0: none; at
    /// most 8
    #[arg(long, value_name = "N")]
    refine: Option<u32>,
    /// Levels of that discretisation audit, the study's own included: 2 (dt / 2, order 2
    /// assumed) or 3 (dt / 2 and dt / 4, order observed)
    #[arg(long, value_name = "2|3", default_value_t = 2)]
    refine_levels: u32,
    /// Those points also re-solved cold on the mesh refined once (box bodies: elements x 2 along
    /// each axis; about 2^dim x a point or more): the mesh's error beside the time step's
    #[arg(long)]
    refine_mesh: bool,
    /// Points held out of the study's response surface (random in its box), solved cold at 1/100
    /// of the tolerance when pools are idle, against the surface's predictions made before: how
    /// good the surface is between the points (`glissade show`); default: 5 % of the points, at
    /// least 5, at most a quarter; 0: none
    #[arg(long, value_name = "N")]
    surface_audit: Option<u32>,
    /// Follow the study until it ends (as `glissade watch`).
    #[arg(long)]
    watch: bool,
    /// Print one JSON object instead of the study id (not with --watch: its lines are for people).
    #[arg(long, conflicts_with = "watch")]
    json: bool,
}

#[derive(Debug, clap::Args)]
struct SurfaceArgs {
    /// The study id.
    study: u64,
    /// The quantity of interest (default: every QoI in the table; required for --png).
    #[arg(long, value_name = "NAME")]
    qoi: Option<String>,
    /// Keep only the points where a swept parameter has this value (repeatable): a slice.
    #[arg(long, value_name = "NAME=VALUE")]
    fix: Vec<String>,
    /// Every stored solution of the study's scene (any study), not only this study's points.
    #[arg(long)]
    all_solutions: bool,
    /// Write the surface as CSV to FILE ("-": stdout).
    #[arg(long, value_name = "FILE")]
    csv: Option<PathBuf>,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    json: bool,
    /// Draw the surface to a PNG file.
    #[arg(long, value_name = "FILE")]
    png: Option<PathBuf>,
    /// Picture size, WIDTHxHEIGHT in pixels (two panels side by side: the mean and its standard
    /// deviation).
    #[arg(long, value_name = "WxH", default_value = "1200x560", value_parser = parse_size)]
    size: (u32, u32),
    /// Predict the QoIs at this point, with a standard deviation (repeatable): a Gaussian process
    /// fitted to the surface's points, e.g. --at f1=0.137,f2=0.151
    #[arg(long, value_name = "NAME=VALUE,...")]
    at: Vec<String>,
}

#[derive(Debug, clap::Args)]
struct ConvergenceArgs {
    /// The study id.
    study: u64,
    /// Draw eta against the iterations of every point to a PNG file.
    #[arg(long, value_name = "FILE")]
    png: Option<PathBuf>,
    /// Print every point's history as JSON.
    #[arg(long)]
    json: bool,
    /// Picture size, WIDTHxHEIGHT in pixels.
    #[arg(long, value_name = "WxH", default_value = "900x600", value_parser = parse_size)]
    size: (u32, u32),
}

/// `900x700` -> (900, 700), within what a PNG viewer shows.
fn parse_size(text: &str) -> Result<(u32, u32), String> {
    let bad = || format!("`{text}`: expected WIDTHxHEIGHT in pixels, e.g. 900x700");
    let (w, h) = text.split_once(['x', 'X']).ok_or_else(bad)?;
    let (w, h): (u32, u32) = (w.trim().parse().map_err(|_| bad())?, h.trim().parse().map_err(|_| bad())?);
    let (min, max) = (plot::MIN_SIZE, plot::MAX_SIZE);
    if !(min.0..=max.0).contains(&w) || !(min.1..=max.1).contains(&h) {
        return Err(format!("`{text}`: from {}x{} to {}x{} pixels", min.0, min.1, max.0, max.1));
    }
    Ok((w, h))
}

/// Exit status of a command that ran: success, or "ran, but the study did not succeed".
enum Outcome {
    Success,
    StudyFailed,
}

/// A parser error as every other error: one line on stderr, exit status 1 (clap's own is 2); its
/// usage without the options every command takes (`--server <URL>` read as required there).
fn argument_error(e: &clap::Error) -> String {
    let text = e.render().to_string();
    let usage = |line: &str| {
        ["--server <URL>", "--token-file <FILE>", "--ca-cert <FILE>"]
            .iter()
            .fold(line.to_owned(), |l, option| l.replace(&format!(" {option}"), ""))
    };
    let lines: Vec<String> =
        text.lines().map(|l| if l.trim_start().starts_with("Usage:") { usage(l) } else { l.to_owned() }).collect();
    one_line(&lines.join("\n"))
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        // --help and --version: on stdout, success
        Err(e) if !e.use_stderr() => {
            let _ = e.print();
            return ExitCode::SUCCESS;
        }
        // no command at all: the help, as a failure
        Err(e) if e.kind() == clap::error::ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand => {
            let _ = e.print();
            return ExitCode::FAILURE;
        }
        Err(e) => {
            eprintln!("{}", argument_error(&e));
            return ExitCode::FAILURE;
        }
    };
    tracing_subscriber::fmt()
        .with_env_filter(EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("warn")))
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .init();
    let result = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the tokio runtime")
        .and_then(|rt| rt.block_on(run(cli)));
    match result {
        Ok(Outcome::Success) => ExitCode::SUCCESS,
        Ok(Outcome::StudyFailed) => ExitCode::from(2),
        Err(e) => {
            // A CLI user wants one readable line, not a Debug dump or a backtrace.
            let message = format!("{e:#}");
            eprintln!("error: {}", one_line(&message));
            ExitCode::FAILURE
        }
    }
}

async fn run(cli: Cli) -> Result<Outcome> {
    let token = Token::for_client(cli.token_file.as_deref())?;
    let server = &Server { url: cli.server, token, ca_cert: cli.ca_cert };
    let done = |r: Result<()>| r.map(|()| Outcome::Success);
    match cli.command {
        Command::Health { json } => done(health(server, json).await),
        Command::Submit(args) => submit(server, args).await,
        Command::Watch { study } => {
            let mut client = user(server).await?;
            watch(&mut client, study).await
        }
        Command::Studies { json } => done(studies(server, json).await),
        Command::Show { study, points, json } => done(show(server, study, points, json).await),
        Command::Cancel { study } => done(cancel(server, study).await),
        Command::Retry { study } => done(retry(server, study).await),
        Command::Surface(args) => done(surface(server, args).await),
        Command::Convergence(args) => done(convergence(server, args).await),
        Command::Fields(args) => done(fields::fields(&mut user(server).await?, args).await),
        Command::Demo(args) => demo::demo(args).await,
    }
}

/// One line for a refused call: what was asked, the server's reason, the status code.
fn refused(what: &str, status: tonic::Status) -> anyhow::Error {
    anyhow!("{what}: {} ({:?})", one_line(status.message()), status.code())
}

/// The coordinator a command talks to: its URL and the user token (if it needs one).
pub struct Server {
    pub url: String,
    pub token: Option<Token>,
    /// CA certificate of an `https://` coordinator (else GLISSADE_CA_CERT, else system roots).
    pub ca_cert: Option<PathBuf>,
}

impl std::fmt::Display for Server {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.url)
    }
}

/// A user-service client that presents the token with every call.
pub type User = UserClient<InterceptedService<Channel, WithToken>>;

async fn user(server: &Server) -> Result<User> {
    Ok(UserClient::with_interceptor(connect(server).await?, WithToken::new(server.token.as_ref())))
}

/// The study with its points and (when asked) its scene text; errors start with `command ID`.
async fn get_study(client: &mut User, command: &str, id: u64, points: bool, scene: bool) -> Result<v1::Study> {
    Ok(client
        .get_study(v1::GetStudyRequest { study_id: id, points, scene })
        .await
        .map_err(|s| refused(&format!("{command} {id}"), s))?
        .into_inner())
}

/// Reads a scene file and the mesh files it names (next to it), as `glissade-worker solve` does.
fn read_scene(path: &Path) -> Result<(String, Scene)> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read scene {}", path.display()))?;
    let mut scene = Scene::parse(&text).with_context(|| format!("scene {}", path.display()))?;
    scene.attach_meshes(path.parent().unwrap_or(Path::new(""))).with_context(|| format!("scene {}", path.display()))?;
    Ok((text, scene))
}

async fn submit(server: &Server, args: SubmitArgs) -> Result<Outcome> {
    if let Some(t) = args.tol {
        check_tolerance("--tol", t)?;
    }
    // checked as the coordinator will, before connecting
    let (scene, parsed) = read_scene(&args.scene)?;
    if args.adaptive.is_some() || args.surface_accuracy.is_some() {
        let space = glissade_core::study::space::ParameterSpace::from_scene(&parsed);
        let budget = args.adaptive.map_or(glissade_core::study::adaptive::TARGET_BUDGET, |n| n as usize);
        glissade_core::study::adaptive::AdaptiveDesign::parse(
            &args.range,
            budget,
            args.surface_accuracy,
            &space,
            glissade_core::study::space::DEFAULT_MAX_POINTS,
        )
        .map_err(|e| anyhow!("--range / --adaptive / --surface-accuracy: {e}"))?;
    } else {
        glissade_core::study::space::check_grid(&parsed, &args.grid).map_err(|e| anyhow!("--grid: {e}"))?;
    }
    // the mesh files travel with the scene, each with its digest (the coordinator checks both)
    let meshes = parsed
        .meshes
        .iter()
        .map(|(file, bytes)| v1::MeshFile {
            file: file.clone(),
            data: bytes.to_vec(),
            sha256: parsed.mesh_digests[file].clone(),
        })
        .collect();
    let request = v1::SubmitStudyRequest {
        scene,
        meshes,
        ranges: args.range,
        adaptive_points: args.adaptive.unwrap_or(0),
        grid: args.grid,
        points: Vec::new(),
        tolerance: args.tol,
        // none named: the coordinator's default (core's StrategyKind::DEFAULT)
        strategy: match args.strategy {
            None => v1::InitStrategy::Unspecified,
            Some(StrategyKind::Cold) => v1::InitStrategy::Cold,
            Some(StrategyKind::Previous) => v1::InitStrategy::Previous,
            Some(StrategyKind::Nearest) => v1::InitStrategy::Nearest,
            Some(StrategyKind::Blend) => v1::InitStrategy::Blend,
            Some(StrategyKind::Linear) => v1::InitStrategy::Linear,
        }
        .into(),
        order: match args.order {
            OrderKind::Asc => v1::PointOrder::Ascending,
            OrderKind::Desc => v1::PointOrder::Descending,
            OrderKind::Greedy => v1::PointOrder::Greedy,
        }
        .into(),
        max_iterations: args.max_iter,
        label: args.label,
        blend_neighbours: args.k,
        audit_points: args.audit,
        refine_points: args.refine,
        refine_levels: args.refine_levels,
        refine_mesh: args.refine_mesh,
        surface_audit_points: args.surface_audit,
        surface_accuracy: args.surface_accuracy,
    };
    let mut client = user(server).await?;
    let reply = client
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
        outln!("{value}");
    } else if args.watch {
        outln!("study {} submitted: {} points", reply.study_id, reply.points);
    } else {
        outln!("{}", reply.study_id);
    }
    if args.watch { watch(&mut client, reply.study_id).await } else { Ok(Outcome::Success) }
}

/// Follows a study to its end: an indicatif bar on a terminal, plain lines otherwise; then the
/// summary. StudyFailed when it ended with failed or cancelled points.
async fn watch(client: &mut User, id: u64) -> Result<Outcome> {
    let mut stream = client
        .watch_study(v1::WatchStudyRequest { study_id: id })
        .await
        .map_err(|s| refused(&format!("watch {id}"), s))?
        .into_inner();
    let started = Instant::now();
    let mut state = WatchState::new(id);
    let bar = std::io::stderr().is_terminal().then(|| {
        let bar = indicatif::ProgressBar::new(0);
        bar.set_style(
            indicatif::ProgressStyle::with_template("{spinner} study {prefix} [{bar:30}] {pos}/{len}  {msg}")
                .map(|s| s.progress_chars("=> "))
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        bar.set_prefix(id.to_string());
        bar.enable_steady_tick(Duration::from_millis(200));
        bar
    });
    let say = |text: &str| match &bar {
        Some(bar) => bar.println(text),
        None => eprintln!("{text}"),
    };
    loop {
        let event = match stream.message().await {
            Ok(Some(e)) => e,
            // The coordinator went away (restart, crash, network): the study's events are
            // durable, so a new watch starts from a snapshot. Reconnect with back-off.
            broken @ (Ok(None) | Err(_)) => {
                if let Err(s) = &broken
                    && !is_transient(s)
                {
                    if let Some(bar) = &bar {
                        bar.abandon();
                    }
                    return Err(refused(&format!("watch {id}: the stream broke off"), s.clone()));
                }
                let why = broken.err().map_or("the stream ended".to_owned(), |s| one_line(s.message()));
                say(&format!("watch {id}: lost the coordinator ({why}); reconnecting"));
                stream = reconnect_watch(client, id, &say).await?;
                continue;
            }
        };
        let line = state.apply(&event);
        match &bar {
            Some(bar) => {
                let (position, total) = state.position();
                bar.set_length(total);
                bar.set_position(position);
                let eta = state.eta(started.elapsed()).map_or(String::new(), |d| format!(", ETA {}", clock(d)));
                bar.set_message(format!("{}; {}{eta}\n  {}", state.counts(), state.iterations(), {
                    let running = state.running_line(now_unix_ms());
                    if running.is_empty() { "-".to_owned() } else { format!("running: {running}") }
                }));
            }
            None => {
                if let Some(line) = line {
                    let eta = state.eta(started.elapsed()).map_or(String::new(), |d| format!(" (ETA {})", clock(d)));
                    outln!("{line}{eta}");
                }
            }
        }
        // (not at the snapshot of a finished study: its points' replay comes after it)
        if state.ended() && event.kind == v1::EventKind::StudyEnded as i32 {
            break;
        }
    }
    if let Some(bar) = &bar {
        bar.finish_and_clear();
    }
    outln!("{}", state.summary(started.elapsed()));
    Ok(if state.state == v1::StudyState::Done as i32 { Outcome::Success } else { Outcome::StudyFailed })
}

/// Statuses after which a watch reconnects: the coordinator or the network went away, not a
/// refusal of this request.
fn is_transient(s: &Status) -> bool {
    matches!(s.code(), Code::Unavailable | Code::Unknown | Code::Cancelled | Code::Aborted)
}

/// A new watch of study `id`, retried with back-off (0.2 s doubling to 5 s) for as long as the
/// coordinator is unreachable; a refusal (the study is gone) ends it.
async fn reconnect_watch(client: &mut User, id: u64, say: &impl Fn(&str)) -> Result<tonic::Streaming<v1::StudyEvent>> {
    let mut pause = Duration::from_millis(200);
    let mut attempts = 0u32;
    loop {
        tokio::time::sleep(pause).await;
        attempts += 1;
        match client.watch_study(v1::WatchStudyRequest { study_id: id }).await {
            Ok(r) => {
                say(&format!("watch {id}: reconnected after {attempts} attempt(s)"));
                return Ok(r.into_inner());
            }
            Err(s) if is_transient(&s) => {
                if attempts.is_multiple_of(10) {
                    say(&format!(
                        "watch {id}: still no coordinator after {attempts} attempts ({})",
                        one_line(s.message())
                    ));
                }
                pause = (pause * 2).min(Duration::from_secs(5));
            }
            Err(s) => return Err(refused(&format!("watch {id}"), s)),
        }
    }
}

fn clock(d: Duration) -> String {
    let s = d.as_secs();
    if s >= 3600 { format!("{}h{:02}m", s / 3600, s % 3600 / 60) } else { format!("{}m{:02}s", s / 60, s % 60) }
}

async fn studies(server: &Server, json: bool) -> Result<()> {
    let list = user(server)
        .await?
        .list_studies(v1::ListStudiesRequest {})
        .await
        .map_err(|s| refused("list studies", s))?
        .into_inner()
        .studies;
    if json {
        outln!("{}", serde_json::Value::Array(list.iter().map(study_json).collect()));
        return Ok(());
    }
    if list.is_empty() {
        outln!("no studies yet (glissade submit SCENE --grid ...)");
        return Ok(());
    }
    outln!(
        "{:>5}  {:<8}  {:<9}  {:>11}  {:<9}  {:<14}  {:>8}  {:<20}  {:>8}  scene / label",
        "id",
        "kind",
        "state",
        "done/total",
        "strategy",
        "parameters",
        "tol",
        "submitted",
        "wall"
    );
    for s in &list {
        let p = s.progress.unwrap_or_default();
        let wall = if s.finished_unix_ms > 0 {
            glissade_core::text::wall_time((s.finished_unix_ms - s.created_unix_ms) as f64 / 1e3)
        } else {
            "-".to_owned()
        };
        let title =
            [s.scene_title.as_str(), s.label.as_str()].iter().filter(|t| !t.is_empty()).cloned().collect::<Vec<_>>();
        outln!(
            "{:>5}  {:<8}  {:<9}  {:>11}  {:<9}  {:<14}  {:>8.1e}  {:<20}  {:>8}  {}",
            s.study_id,
            s.kind,
            study_state_name(s.state),
            format!("{}/{}", p.done, p.total),
            strategy_name(s.strategy),
            s.parameters.join(","),
            s.tolerance,
            glissade_core::text::utc_minute(s.created_unix_ms),
            wall,
            title.join(" / ")
        );
    }
    Ok(())
}

/// `2 of 2 points re-solved cold at 1e-5 (study 2): slip_A largest 3.1e-4 mean 1.2e-4, ...`
fn accuracy_line(a: &v1::StudyAccuracy) -> String {
    let errors: Vec<String> =
        a.qoi.iter().map(|(q, e)| format!("{q} largest {:.1e} mean {:.1e}", e.largest, e.mean)).collect();
    let cost = if a.work_cap > 0.0 {
        format!("; it cost {:.0} work of its cap {:.0}", a.work, a.work_cap)
    } else {
        String::new()
    };
    format!(
        "{} of {} points re-solved cold at {:.0e} (study {}){}{}{cost}",
        a.audited,
        a.planned,
        a.tolerance,
        a.audit_study_id,
        if errors.is_empty() { "" } else { ": " },
        errors.join(", ")
    )
}

/// `7 of 7 held-out points solved cold at 2e-6 (study 4) against the surface of 121 points:
/// slip_A largest 1.3e-1 mean 5.0e-3 within 2 sd 86 %, ...`; errors relative to each QoI's spread.
fn surface_accuracy_line(a: &v1::StudySurfaceAccuracy) -> String {
    let mut parts: Vec<String> = a
        .qoi
        .iter()
        .map(|(q, e)| {
            format!("{q} largest {:.1e} mean {:.1e} within 2 sd {:.0} %", e.largest, e.mean, e.within_2sd * 100.0)
        })
        .collect();
    parts.extend(
        a.refused
            .iter()
            .map(|(q, why)| format!("{} not predicted: {why}", if q.is_empty() { "the surface" } else { q })),
    );
    let cost = if a.work_cap > 0.0 {
        format!("; it cost {:.0} work of its cap {:.0}", a.work, a.work_cap)
    } else {
        String::new()
    };
    format!(
        "{} of {} held-out points solved cold at {:.0e} (study {}) against the surface of {} points{}{}{cost}",
        a.validated,
        a.planned,
        a.tolerance,
        a.audit_study_id,
        a.fitted,
        if parts.is_empty() { "" } else { ": " },
        parts.join(", ")
    )
}

/// `surface accuracy 2.0e-2 (mean error / spread, cross-validated): reached at 34 points of
/// 100: slip_A mean 1.2e-2 largest 8.1e-2, ...`, then what the held-out points measured against
/// the target where they did.
fn target_line(t: &v1::StudyTarget, held: Option<&v1::StudySurfaceAccuracy>) -> String {
    let errors: Vec<String> = t
        .qoi
        .iter()
        .map(|(q, e)| {
            let above = if e.mean > t.surface_accuracy { " (ABOVE)" } else { "" };
            format!("{q} mean {:.1e}{above} largest {:.1e}", e.mean, e.largest)
        })
        .chain(t.refused.iter().map(|(q, why)| format!("{q} not fitted: {why}")))
        .collect();
    let verdict = match t.outcome.as_str() {
        "reached" => format!("REACHED at {} points (budget {})", t.points, t.budget),
        "budget" => format!("NOT REACHED: the budget of {} points was spent; at {} points", t.budget, t.points),
        _ => format!("not decided yet (budget {})", t.budget),
    };
    let mut line = format!(
        "surface accuracy {:.1e} (mean error / spread, cross-validated): {verdict}{}{}",
        t.surface_accuracy,
        if errors.is_empty() { "" } else { ": " },
        errors.join(", ")
    );
    if let Some(h) = held.filter(|h| h.validated > 0) {
        let above: Vec<String> = h
            .qoi
            .iter()
            .filter(|(_, e)| e.mean > t.surface_accuracy)
            .map(|(q, e)| format!("{q} {:.1e}", e.mean))
            .collect();
        line.push_str(&if above.is_empty() {
            format!("; the {} held-out points confirm it (every mean within the target)", h.validated)
        } else {
            format!("; the {} held-out points measure means ABOVE the target: {}", h.validated, above.join(", "))
        });
    }
    line
}

/// `2 of 2 points re-solved at dt / 2 (study 3; 4.1 s, 0.8 x the study's 5.0 s): slip_A change
/// 3.2e-2 error ~4.3e-2 (order 2 assumed), ...`
fn discretisation_line(d: &v1::StudyDiscretisation) -> String {
    let errors: Vec<String> = d
        .qoi
        .iter()
        .map(|(q, e)| {
            let how = if e.erratic > 0 {
                format!(" (ERRATIC at {} point(s): an event moves with the step; no extrapolation)", e.erratic)
            } else if e.below_tolerance {
                " (below the iterations' noise)".to_string()
            } else if e.order_assumed {
                " (order 2 assumed)".to_string()
            } else {
                format!(" (observed order {:.2})", e.order)
            };
            format!("{q} change {:.1e} error ~{:.1e}{how}", e.change, e.error)
        })
        .collect();
    let levels: Vec<String> = d.factors.iter().map(|f| format!("dt / {f}")).collect();
    let studies: Vec<String> = d.level_study_ids.iter().map(|s| s.to_string()).collect();
    format!(
        "{} of {} points re-solved at {} (study {}; {:.1} s, {:.2} x the study's {:.1} s){}{}",
        d.audited,
        d.planned,
        levels.join(" and "),
        studies.join(", "),
        d.work_seconds,
        if d.study_seconds > 0.0 { d.work_seconds / d.study_seconds } else { 0.0 },
        d.study_seconds,
        if errors.is_empty() { "" } else { ": " },
        errors.join(", ")
    )
}

/// The mesh level's line: per QoI the change at h / 2 and the estimated error (None: no mesh
/// level).
fn mesh_line(d: &v1::StudyDiscretisation) -> Option<String> {
    (d.mesh_study_id != 0).then_some(())?;
    let errors: Vec<String> = d
        .qoi
        .iter()
        .filter_map(|(q, e)| {
            let how = if e.mesh_below_tolerance { " (below the iterations' noise)" } else { " (order 2 assumed)" };
            Some(format!("{q} change {:.1e} error ~{:.1e}{how}", e.mesh_change?, e.mesh_error?))
        })
        .collect();
    Some(format!(
        "{} of {} points re-solved cold at h / {} (study {}; {:.1} s, {:.2} x the study's {:.1} s){}{}",
        d.mesh_audited,
        d.planned,
        d.mesh_factor,
        d.mesh_study_id,
        d.mesh_work_seconds,
        if d.study_seconds > 0.0 { d.mesh_work_seconds / d.study_seconds } else { 0.0 },
        d.study_seconds,
        if errors.is_empty() { "" } else { ": " },
        errors.join(", ")
    ))
}

/// Which of the errors dominates, by the largest over the QoIs of each (None until the
/// iterations' and the time step's measured something; the mesh's where it did).
fn dominant(a: &v1::StudyAccuracy, d: &v1::StudyDiscretisation) -> Option<String> {
    let largest = |v: &mut dyn Iterator<Item = f64>| v.fold(None, |m: Option<f64>, x| Some(m.map_or(x, |m| m.max(x))));
    let mut errors = vec![
        ("the iterations'", largest(&mut a.qoi.values().map(|e| e.largest))?),
        ("the time step's", largest(&mut d.qoi.values().map(|e| e.error))?),
    ];
    if let Some(mesh) = largest(&mut d.qoi.values().filter_map(|e| e.mesh_error)) {
        errors.push(("the mesh's", mesh));
    }
    errors.sort_by(|x, y| y.1.total_cmp(&x.1));
    let others: Vec<String> = errors[1..].iter().map(|(who, e)| format!("{who} ({e:.1e})")).collect();
    Some(format!("{} error (~{:.1e}) dominates {}", errors[0].0, errors[0].1, others.join(" and ")))
}

fn study_json(s: &v1::Study) -> serde_json::Value {
    let p = s.progress.unwrap_or_default();
    serde_json::json!({
        "study_id": s.study_id,
        "label": s.label,
        "scene_hash": s.scene_hash,
        "state": study_state_name(s.state),
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
        "finished_unix_ms": (s.finished_unix_ms > 0).then_some(s.finished_unix_ms),
        "kind": s.kind,
        "scene_title": s.scene_title,
        "audit_of": (s.audit_of != 0).then_some(s.audit_of),
        "accuracy": s.accuracy.as_ref().map(|a| serde_json::json!({
            "audit_study_id": a.audit_study_id,
            "tolerance": a.tolerance,
            "audited": a.audited,
            "planned": a.planned,
            "work": a.work,
            "work_cap": a.work_cap,
            "qoi": a.qoi.iter().map(|(q, e)| (q.clone(), serde_json::json!({"largest": e.largest, "mean": e.mean})))
                .collect::<serde_json::Map<_, _>>(),
        })),
        "refines": (s.refines != 0).then(|| serde_json::json!({"study_id": s.refines, "factor": s.refine_factor})),
        "held_out": s.held_out,
        "target": s.target.as_ref().map(|t| serde_json::json!({
            "surface_accuracy": t.surface_accuracy,
            "budget": t.budget,
            "outcome": (!t.outcome.is_empty()).then_some(&t.outcome),
            "points": t.points,
            "refused": t.refused,
            "qoi": t.qoi.iter().map(|(q, e)| (q.clone(), serde_json::json!({
                "largest": e.largest, "mean": e.mean, "within_2sd": e.within_2sd, "points": e.points,
            }))).collect::<serde_json::Map<_, _>>(),
        })),
        "surface_accuracy": s.surface_accuracy.as_ref().map(|a| serde_json::json!({
            "audit_study_id": a.audit_study_id,
            "tolerance": a.tolerance,
            "validated": a.validated,
            "planned": a.planned,
            "fitted": a.fitted,
            "work": a.work,
            "work_cap": a.work_cap,
            "refused": a.refused,
            "qoi": a.qoi.iter().map(|(q, e)| (q.clone(), serde_json::json!({
                "largest": e.largest, "mean": e.mean, "within_2sd": e.within_2sd, "points": e.points,
            }))).collect::<serde_json::Map<_, _>>(),
        })),
        "discretisation": s.discretisation.as_ref().map(|d| serde_json::json!({
            "level_study_ids": d.level_study_ids,
            "factors": d.factors,
            "audited": d.audited,
            "planned": d.planned,
            "work_seconds": d.work_seconds,
            "study_seconds": d.study_seconds,
            "qoi": d.qoi.iter().map(|(q, e)| (q.clone(), serde_json::json!({
                "change": e.change, "error": e.error, "order": (e.order > 0.0).then_some(e.order),
                "order_assumed": e.order_assumed, "erratic": e.erratic, "below_tolerance": e.below_tolerance,
                "mesh": e.mesh_change.map(|change| serde_json::json!({
                    "change": change, "error": e.mesh_error, "below_tolerance": e.mesh_below_tolerance,
                })),
            }))).collect::<serde_json::Map<_, _>>(),
            "mesh": (d.mesh_study_id != 0).then(|| serde_json::json!({
                "study_id": d.mesh_study_id, "factor": d.mesh_factor, "audited": d.mesh_audited,
                "work_seconds": d.mesh_work_seconds,
            })),
        })),
    })
}

async fn cancel(server: &Server, id: u64) -> Result<()> {
    let s = user(server)
        .await?
        .cancel_study(v1::CancelStudyRequest { study_id: id })
        .await
        .map_err(|s| refused(&format!("cancel {id}"), s))?
        .into_inner();
    let p = s.progress.unwrap_or_default();
    outln!(
        "study {id} {}: {} done, {} cancelled, {} still running",
        study_state_name(s.state),
        p.done,
        p.cancelled,
        p.leased
    );
    Ok(())
}

async fn retry(server: &Server, id: u64) -> Result<()> {
    let r = user(server)
        .await?
        .retry_failed(v1::RetryFailedRequest { study_id: id })
        .await
        .map_err(|s| refused(&format!("retry {id}"), s))?
        .into_inner();
    outln!("study {id}: {} failed points back in the queue", r.requeued);
    if r.kept > 0 {
        outln!("{} failed points kept: their failure can only repeat ({})", r.kept, r.kept_because);
    }
    Ok(())
}

/// Writes `text` to `path`, or to stdout for "-".
fn write_output(path: &Path, text: &str) -> Result<()> {
    if path == Path::new("-") {
        out!("{text}");
        return Ok(());
    }
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}

async fn surface(server: &Server, args: SurfaceArgs) -> Result<()> {
    let mut client = user(server).await?;
    // the scene's text for the units (the picture's axes; QoIs of one unit set their resolution)
    let study = get_study(&mut client, "surface", args.study, false, true).await?;
    let fixed = args
        .fix
        .iter()
        .map(|f| parse_fixed(f, &study.parameters))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| anyhow!(e))?;
    let source = if args.all_solutions {
        v1::query_surface_request::Source::SceneHash(study.scene_hash.clone())
    } else {
        v1::query_surface_request::Source::StudyId(study.study_id)
    };
    let swept = &study.parameters;
    let predict_at = args
        .at
        .iter()
        .map(|spec| {
            Ok(v1::ParameterPoint { parameters: fields::parse_point("--at", spec, swept)?.into_iter().collect() })
        })
        .collect::<Result<Vec<_>>>()?;
    let reply = client
        .query_surface(v1::QuerySurfaceRequest {
            source: Some(source),
            fixed: fixed.iter().cloned().collect(),
            qoi: vec![],
            predict_at,
        })
        .await
        .map_err(|s| refused(&format!("surface {}", args.study), s))?
        .into_inner();
    if reply.points.is_empty() && !fixed.is_empty() {
        // no point in the slice: say which values there are, not that the QoI is unknown
        let all = get_study(&mut client, "surface", args.study, true, false).await?;
        let points: Vec<&std::collections::BTreeMap<String, f64>> = all.points.iter().map(|p| &p.parameters).collect();
        bail!("--fix: {}", glissade_core::study::space::slice_miss(&fixed, points));
    }
    let scene = Scene::parse(&study.scene).ok();
    let unit = |q: &str| Some(scene.as_ref()?.unit(q)?.to_owned());
    let mut table = SurfaceTable::new(&reply, args.qoi.as_deref())?.resolved(&reply, study.tolerance, unit);
    if args.all_solutions {
        // Every parameter comes back; keep the study's swept ones as columns.
        table = table.restricted_to(&study.parameters);
    }
    if let Some(path) = &args.csv {
        write_output(path, &table.to_csv())?;
    }
    if let Some(path) = &args.png {
        let Some(qoi) = &args.qoi else {
            bail!("--png: say which QoI to draw with --qoi (one of {})", reply.qoi.join(", "))
        };
        let fixed_text = fixed.iter().map(|(n, v)| format!("{n}={v}")).collect::<Vec<_>>().join(", ");
        let title = format!(
            "study {}: {qoi}{}",
            args.study,
            if fixed_text.is_empty() { String::new() } else { format!(" at {fixed_text}") }
        );
        // the surface of `--at`, fitted here to the same points
        let rows: Vec<plot::study::Row> = reply.points.iter().map(|p| (&p.parameters, &p.qoi)).collect();
        let picture = Picture {
            scene: scene.as_ref(),
            names: &reply.parameters,
            swept: &study.parameters,
            fixed: &fixed,
            qoi,
            resolution: table.resolution[0],
            title,
        };
        let surface = picture.surface(&rows);
        plot::surface_png(path, &surface, args.size).with_context(|| format!("--png {}", path.display()))?;
        eprintln!("wrote {} ({}x{})", path.display(), args.size.0, args.size.1);
    }
    if !args.at.is_empty() {
        let predictions = Predictions::new(&reply, &table);
        if args.json {
            outln!("{}", predictions.to_json());
        } else {
            out!("{}", predictions.to_text());
        }
        return Ok(());
    }
    if args.json {
        outln!("{}", table.to_json());
    } else if args.csv.is_none() && args.png.is_none() {
        out!("{}", table.to_text());
    }
    Ok(())
}

async fn convergence(server: &Server, args: ConvergenceArgs) -> Result<()> {
    if args.png.is_none() && !args.json {
        bail!("say where the histories go: --png FILE and/or --json");
    }
    let mut client = user(server).await?;
    let study = get_study(&mut client, "convergence", args.study, true, false).await?;
    let series: Vec<ConvergenceSeries> = study
        .points
        .iter()
        .filter(|p| !p.eta_history.is_empty())
        .map(|p| ConvergenceSeries {
            label: format!("#{} {}", p.point_id, describe_parameters(&p.parameters)),
            history: p.eta_history.clone(),
        })
        .collect();
    if let Some(path) = &args.png {
        if series.is_empty() {
            bail!(
                "study {}: no point has iterated yet (or every point was answered from a stored solution)",
                args.study
            );
        }
        let title = format!("study {}: error indicator of the dynamic stage", args.study);
        plot::convergence_png(path, &series, Some(study.tolerance), &title, args.size)
            .with_context(|| format!("--png {}", path.display()))?;
        eprintln!("wrote {} ({} points, {}x{})", path.display(), series.len(), args.size.0, args.size.1);
    }
    if args.json {
        let points: Vec<serde_json::Value> = study
            .points
            .iter()
            .map(|p| {
                serde_json::json!({
                    "point_id": p.point_id,
                    "parameters": p.parameters,
                    "state": point_state_name(p.state),
                    "started_from": p.started_from.as_ref().map(|f| &f.parameters),
                    "eta_history": p.eta_history,
                })
            })
            .collect();
        outln!("{}", serde_json::json!({ "study_id": study.study_id, "tolerance": study.tolerance, "points": points }));
    }
    Ok(())
}

fn point_json(p: &v1::PointStatus) -> serde_json::Value {
    serde_json::json!({
        "point_id": p.point_id,
        "parameters": p.parameters,
        "state": point_state_name(p.state),
        "attempts": p.attempts,
        "pool_id": p.pool_id,
        "iterations": p.iterations,
        "work": p.work,
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

async fn show(server: &Server, study: u64, points: bool, json: bool) -> Result<()> {
    // the points always: the work line and the failures come from them (the scene: the QoIs' units)
    let s = get_study(&mut user(server).await?, "show", study, true, true).await?;
    let p = s.progress.unwrap_or_default();
    if json {
        let mut value = study_json(&s);
        if points {
            value["points"] = s.points.iter().map(point_json).collect();
        }
        outln!("{value}");
        return Ok(());
    }
    outln!(
        "study {}{}: {}",
        s.study_id,
        if s.label.is_empty() { String::new() } else { format!(" ({})", s.label) },
        study_state_name(s.state)
    );
    outln!(
        "  scene     {}{}",
        if s.scene_title.is_empty() { String::new() } else { format!("{}, ", s.scene_title) },
        s.scene_hash
    );
    outln!(
        "  kind      {}, submitted {}{}",
        s.kind,
        glissade_core::text::utc_minute(s.created_unix_ms),
        if s.finished_unix_ms > 0 {
            format!(
                ", finished {} (wall time {})",
                glissade_core::text::utc_minute(s.finished_unix_ms),
                glissade_core::text::wall_time((s.finished_unix_ms - s.created_unix_ms) as f64 / 1e3)
            )
        } else {
            String::new()
        }
    );
    outln!(
        "  sweep     {} ({} points), strategy {}, order {}",
        s.parameters.join(", "),
        p.total,
        strategy_name(s.strategy),
        order_name(s.order)
    );
    outln!("  tolerance {:.1e}, at most {} iterations", s.tolerance, s.max_iterations);
    if s.refines != 0 {
        let what = if s.refines_mesh { "the mesh h" } else { "the time step" };
        outln!("  refines   study {} (its points re-solved with {what} / {})", s.refines, s.refine_factor);
    } else if s.held_out {
        outln!(
            "  audits    study {} (points held out of its surface, solved cold at this tighter tolerance)",
            s.audit_of
        );
    } else if s.audit_of != 0 {
        outln!("  audits    study {} (its points re-solved cold at this tighter tolerance)", s.audit_of);
    }
    if let Some(t) = &s.target {
        outln!("  target    {}", target_line(t, s.surface_accuracy.as_ref()));
    }
    if let Some(a) = &s.accuracy {
        outln!("  accuracy  {}", accuracy_line(a));
    }
    if let Some(a) = &s.surface_accuracy {
        outln!("  surface   {}", surface_accuracy_line(a));
    }
    if let Some(d) = &s.discretisation {
        outln!("  dt error  {}", discretisation_line(d));
        if let Some(mesh) = mesh_line(d) {
            outln!("  h error   {mesh}");
        }
        if let Some(verdict) = s.accuracy.as_ref().and_then(|a| dominant(a, d)) {
            outln!("            {verdict}");
        }
    }
    outln!(
        "  progress  {} done, {} failed, {} running, {} pending{}; {} iterations in all",
        p.done,
        p.failed,
        p.leased,
        p.pending,
        if p.cancelled > 0 { format!(", {} cancelled", p.cancelled) } else { String::new() },
        p.iterations
    );
    // cold against warm in work (dynamic iterations + static iterations / steps)
    let mean = |warm: bool| {
        let w: Vec<f64> = s
            .points
            .iter()
            .filter(|x| x.state == v1::PointState::Done as i32 && !x.answered && x.started_from.is_some() == warm)
            .map(|x| x.work)
            .collect();
        (!w.is_empty())
            .then(|| glissade_core::study::WorkMean { work: w.iter().sum::<f64>() / w.len() as f64, points: w.len() })
    };
    let answered = s.points.iter().filter(|x| x.answered).count();
    let work = match (mean(false), mean(true)) {
        (Some(cold), Some(warm)) => Some(glissade_core::study::warm_against_cold(cold, warm)),
        (Some(m), None) | (None, Some(m)) => Some(format!(
            "{:.1} per point, every point solved {} ({} points)",
            m.work,
            if mean(false).is_some() { "cold" } else { "warm" },
            m.points
        )),
        (None, None) => None,
    };
    match work {
        Some(work) => outln!(
            "  work      {work}{} (work: dynamic iterations + static iterations / time steps)",
            if answered > 0 { format!("; {answered} answered from stored solutions") } else { String::new() }
        ),
        None if answered > 0 => outln!("  work      none: {answered} points answered from stored solutions"),
        None => {}
    }
    if !points {
        // why a point failed, without asking for every point
        for point in s.points.iter().filter(|x| x.state == v1::PointState::Failed as i32) {
            outln!("  failed    #{} {}: {}", point.point_id, describe_parameters(&point.parameters), point.error);
        }
        return Ok(());
    }
    // QoIs below what the solves resolve read 0 (`--json` keeps them)
    let scene = Scene::parse(&s.scene).ok();
    let resolution = glissade_core::study::resolutions(s.tolerance, s.points.iter().map(|p| &p.qoi), |q| {
        Some(scene.as_ref()?.unit(q)?.to_owned())
    });
    for point in &s.points {
        let qoi: Vec<String> = point
            .qoi
            .iter()
            .map(|(k, &v)| format!("{k}={:.6e}", glissade_core::study::shown(v, resolution[k])))
            .collect();
        let from = match &point.started_from {
            _ if point.answered => "answered from a stored solution".to_owned(),
            Some(f) => format!("from {}", describe_parameters(&f.parameters)),
            None if point.state == v1::PointState::Done as i32 => "cold".to_owned(),
            None => String::new(),
        };
        outln!(
            "  #{:<4} {:<28} {:<9} {:>5} it  work {:>6.1}  eta {:.2e}  {}  {}{}",
            point.point_id,
            describe_parameters(&point.parameters),
            point_state_name(point.state),
            point.iterations,
            point.work,
            point.error_indicator,
            qoi.join(" "),
            from,
            if point.error.is_empty() { String::new() } else { format!("  [{}]", point.error) }
        );
    }
    Ok(())
}

async fn health(server: &Server, json: bool) -> Result<()> {
    let channel = connect(server).await?;
    let reply = HealthClient::new(channel)
        .check(HealthRequest {})
        .await
        .map_err(|status| anyhow!("health check at {server} failed: {} ({:?})", status.message(), status.code()))?
        .into_inner();
    if json {
        let value = serde_json::json!({
            "server": server.url,
            "status": reply.status,
            "version": reply.version,
            "detail": reply.detail,
        });
        outln!("{value}");
    } else {
        outln!("status:  {}", reply.status);
        outln!("version: {}", reply.version);
    }
    if reply.status != "SERVING" {
        bail!("the coordinator at {server} is not serving: {}", reply.detail);
    }
    Ok(())
}

/// Connects to `server`, turning transport errors into one line that says what went wrong.
async fn connect(server: &Server) -> Result<Channel> {
    let endpoint =
        glissade_proto::auth::endpoint(&server.url, server.ca_cert.as_deref())?.connect_timeout(CONNECT_TIMEOUT);
    tracing::debug!(server = %server, "connecting");
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
