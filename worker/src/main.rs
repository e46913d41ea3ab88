//! `glissade-worker`: runs LATIN solves of scenes (and, later, MPI worker pools).

use glissade_core::text::one_line;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result, anyhow, bail};
use clap::{Args, Parser, Subcommand};
use serde::Serialize;

use glissade_core::io::solution_file;
use glissade_core::point::DesignPoint;
use glissade_core::scene::{Scale, Scene, Tolerance};
use glissade_solver::accuracy::{AccuracyLimits, AccuracyReport, solve_to_accuracy};
use glissade_solver::comm::Communicator;
use glissade_solver::profile::{Profile, Profiled};
use glissade_solver::run::{SolveRequest, SolveSummary, solve_scene_on};
use glissade_worker::io::fields;
use glissade_worker::mpi_comm::Mpi;

mod fields_cmd;
mod study_cli;

#[derive(Parser)]
#[command(
    name = "glissade-worker",
    version,
    about = "LATIN solver for transient dynamics of elastic assemblies with contact and friction",
    after_help = "Examples:\n  glissade-worker solve scenes/bar-impact-1d.toml --json\n  glissade-worker solve --help   # flags, warm starts, field output"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

const SOLVE_EXAMPLES: &str = "\
Examples:
  glissade-worker solve scenes/bar-impact-1d.toml
  glissade-worker solve scenes/bar-impact-1d.toml --set v0=2 --json
  glissade-worker solve scenes/bar-impact-1d.toml --save v1.sol
  glissade-worker solve scenes/bar-impact-1d.toml --set v0=1.1 --init v1.sol
  glissade-worker solve scenes/bar-impact-1d.toml --fields out.h5   # then open out.xdmf in ParaView

  glissade-worker solve scenes/sliding-block-2d.toml --accuracy 0.02   # dt, h and tol chosen

Exit status: 0 converged, 1 error (one line on stderr), 2 not converged within the iteration limit,
3 (--accuracy) every level converged but the accuracy was not reached (the report says why).
Progress: RUST_LOG=glissade_worker=info (per solve) or glissade_solver=debug (per LATIN iteration).";

#[derive(Subcommand)]
enum Command {
    /// Solve one design point of a scene.
    #[command(after_help = SOLVE_EXAMPLES)]
    Solve(SolveArgs),
    /// Serve a glissade coordinator: lease design points, solve them, send the solutions back.
    #[command(after_help = POOL_EXAMPLES)]
    Pool(PoolArgs),
    /// Measure one design point's discretisation error: solve it with dt, dt/2, dt/4 (and h, h/2).
    #[command(after_help = REFINE_EXAMPLES)]
    Refine(RefineArgs),
    /// Solve a parametric study (a grid of design points) in this process, with warm starts.
    #[command(after_help = study_cli::STUDY_EXAMPLES)]
    Study(study_cli::StudyArgs),
    /// The fields of one design point of a coordinator's study as HDF5 + XDMF (ParaView),
    /// re-solved here from the study's nearest stored solution (what `glissade fields` runs).
    Fields(FieldsCommand),
}

#[derive(Args)]
struct FieldsCommand {
    #[command(flatten)]
    fields: glissade_cli::fields::FieldsArgs,
    #[command(flatten)]
    server: glissade_cli::fields::ServerArgs,
}

/// `glissade-worker fields`: a user-service client, then the re-solve (fields_cmd.rs).
fn fields(args: FieldsCommand) -> Result<Exit> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the tokio runtime")?;
    runtime.block_on(async {
        let mut client = glissade_cli::connect::user(&args.server.server()?).await?;
        fields_cmd::fields(&mut client, args.fields).await
    })?;
    Ok(Exit::Done)
}

const POOL_EXAMPLES: &str = "\
Examples:
  glissade-worker pool --coordinator http://coordinator:50051
  glissade-worker pool --coordinator http://10.0.0.5:50051 --pool-id node17 --idle-exit 600
  mpiexec.mpich -n 16 glissade-worker pool --coordinator http://coordinator:50051

Under mpiexec the ranks form one pool: rank 0 talks to the coordinator and all ranks solve each
point together (the substructures are shared out among them).

Runs until SIGTERM or Ctrl-C: a pool waiting for work stops at once, a pool solving finishes and
delivers its point first. Reconnects by itself (with back-off) when the coordinator goes away.
Logs to stderr (RUST_LOG=glissade_worker=debug for more).";

const REFINE_EXAMPLES: &str = "\
Examples:
  glissade-worker refine scenes/three-blocks-tiny.toml --tol 1e-6
  glissade-worker refine scenes/sliding-block-2d.toml --set f=0.2 --dt 1,2,4,8 --h 1,2 --json
  glissade-worker refine scenes/sliding-block-2d.toml --accuracy 0.02   # only the levels it needs

Each level is solved cold, at the same design point and tolerance; per QoI it prints the final
value at every level, the order observed over the last three levels, Richardson's extrapolation
and the estimated error of the scene's own step (and of the finest). 'erratic' means the changes
switch sign or fall at an order outside [0.5, 4]: something moves with the step (a contact
event, a slip onset) and the estimate is the last change. Use a tolerance well below the
discretisation error (1e-6). With --accuracy the ladders climb only as far as the accuracy needs,
at the tolerance it sets (the levels of `solve --accuracy`; --json prints its report). Exit
status: 0, 2 when a level did not converge, 3 (--accuracy) when the accuracy was not reached.";

#[derive(Args)]
struct RefineArgs {
    #[command(flatten)]
    point: PointArgs,
    /// Time-step ladder: the scene's steps times each factor
    #[arg(long, value_name = "1,2,4", value_delimiter = ',', default_value = "1,2,4", conflicts_with = "accuracy")]
    dt: Vec<usize>,
    /// Mesh ladder (box bodies): the scene's elements times each factor along every axis
    #[arg(long, value_name = "1,2", value_delimiter = ',', conflicts_with = "accuracy")]
    h: Vec<usize>,
    /// Print one JSON object instead of the tables
    #[arg(long)]
    json: bool,
    // --accuracy: the ladders climbed only as far as the accuracy needs, at the tolerance it
    // sets (the levels and the choice of `solve --accuracy`), printed as ladders
    #[command(flatten)]
    accuracy: AccuracyArgs,
}

/// The refinement ladders of one design point, on this process.
fn refine(args: RefineArgs) -> Result<Exit> {
    use glissade_solver::refine::{Refinement, check_factors, refined_scene, run_ladder};
    let (scene, request) = args.point.read()?;
    if let Some(a) = args.accuracy.accuracy {
        return refine_to_accuracy(&args, scene, &request, a);
    }
    let mut ladders = vec![(Refinement::Time, args.dt.clone())];
    if !args.h.is_empty() {
        ladders.push((Refinement::Mesh, args.h.clone()));
    }
    // every ladder's factors and scenes checked before the first solve
    for (refinement, factors) in &ladders {
        check_factors(factors)?;
        for &factor in factors {
            refined_scene(&scene, *refinement, factor)?;
        }
    }
    let comm = glissade_solver::comm::Serial;
    let mut results = Vec::new();
    for (refinement, factors) in ladders {
        let what = match refinement {
            Refinement::Time => "dt",
            Refinement::Mesh => "h",
        };
        let json = args.json;
        let ladder = run_ladder(&comm, &scene, &request, refinement, &factors, |l| {
            if !json {
                eprintln!(
                    "  {what} / {}: {} steps, {} after {} iterations, {:.2} s",
                    l.factor,
                    l.steps,
                    if l.converged { "converged" } else { "NOT converged" },
                    l.iterations,
                    l.wall_seconds
                );
            }
        })?;
        if !json {
            println!(
                "{} ladder ({what} / {}):",
                args.point.scene.display(),
                factors.iter().map(|f| f.to_string()).collect::<Vec<_>>().join(", ")
            );
            for q in &ladder.qois {
                let finals: Vec<String> = q.finals.iter().map(|v| format!("{v:.6e}")).collect();
                let order = q.observed_order.map_or("-".to_string(), |p| format!("{p:.2}"));
                let extrapolated = q.extrapolated.map_or("-".to_string(), |x| format!("{x:.6e}"));
                println!(
                    "  {:<20} {}  order {order}  extrapolated {extrapolated}  error at {what}: {:.2} %, at {what} / {}: {:.2} %{}",
                    q.name,
                    finals.join("  "),
                    100.0 * q.error_first,
                    factors[factors.len() - 1],
                    100.0 * q.error_finest,
                    if q.erratic {
                        "  ERRATIC (an event moves with the step)"
                    } else if q.below_tolerance {
                        "  (changes within the iteration tolerance)"
                    } else {
                        ""
                    }
                );
            }
        }
        results.push(ladder);
    }
    let converged = results.iter().all(|l| l.levels.iter().all(|v| v.converged));
    if args.json {
        println!("{}", serde_json::to_string(&results)?);
    }
    if !converged {
        eprintln!("error: not converged: a level ran out of iterations; its estimates are not to be trusted");
    }
    Ok(Exit::from(converged))
}

/// `refine --accuracy`: the levels `solve --accuracy` takes, printed as ladders, then the choice.
fn refine_to_accuracy(args: &RefineArgs, scene: Scene, request: &SolveRequest, accuracy: f64) -> Result<Exit> {
    let path = &args.point.scene;
    let (_, _, report) =
        solve_accurately(&glissade_solver::comm::Serial, scene, request, accuracy, &args.accuracy, path)?;
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        print_accuracy_ladders(path, &report);
        print_accuracy(&report);
    }
    let converged = report.levels.iter().all(|l| l.converged);
    if let Some(why) = &report.why_not {
        eprintln!("error: accuracy not reached: {why}");
    }
    Ok(match (converged, report.reached) {
        (false, _) => Exit::NotConverged,
        (true, false) => Exit::AccuracyNotReached,
        (true, true) => Exit::Done,
    })
}

/// The ladders of an accuracy's report as `refine` prints its own: per QoI the final value at
/// each level, the order observed and the finest level's error relative to the QoI's scale.
fn print_accuracy_ladders(path: &Path, a: &AccuracyReport) {
    use glissade_solver::accuracy::LadderError;
    let factors = |n: usize| (0..n).map(|i| (1usize << i).to_string()).collect::<Vec<_>>().join(", ");
    let row = |name: &str, l: &LadderError, finest: String| {
        let finals: Vec<String> = l.finals.iter().map(|v| format!("{v:.6e}")).collect();
        let order = l.error.order.map_or("-".to_string(), |p| format!("{p:.2}"));
        let error = if l.error.estimate.is_finite() { format!("{:.2e}", l.error.estimate) } else { "unknown".into() };
        let tag = if l.error.erratic {
            "  ERRATIC (an event moves with the step)"
        } else if l.error.below_noise {
            "  (changes within the iteration tolerance)"
        } else {
            ""
        };
        println!("  {name:<20} {}  order {order}  error at {finest}: {error}{tag}", finals.join("  "));
    };
    let Some(first) = a.qois.first() else { return };
    // a staircase's ladders are its changes carried to the answer's other factor
    let carried = if first.mesh.is_some() {
        format!("carried to the answer's mesh h / {}", a.mesh_factor)
    } else {
        "on the scene's mesh".to_string()
    };
    println!(
        "{} dt ladder (dt / {}) {carried}, errors relative to each QoI's scale:",
        path.display(),
        factors(first.time.finals.len())
    );
    let time_finest = format!("dt / {}", 1usize << (first.time.finals.len() - 1));
    for q in &a.qois {
        row(&q.name, &q.time, time_finest.clone());
    }
    if let Some(m) = &first.mesh {
        println!(
            "{} h ladder (h / {}) carried to the answer's step dt / {}:",
            path.display(),
            factors(m.finals.len()),
            a.time_factor
        );
        let finest = format!("h / {}", 1usize << (m.finals.len() - 1));
        for q in &a.qois {
            if let Some(m) = &q.mesh {
                row(&q.name, m, finest.clone());
            }
        }
        let solved: Vec<String> = a.levels.iter().map(|l| format!("({}, {})", l.time_factor, l.mesh_factor)).collect();
        println!(
            "  solved (dt / k, h / m), dt and h halved in turn: {}; each ladder's changes are those of its own halvings",
            solved.join(" ")
        );
    }
    if let Some(j) = &first.joint {
        println!(
            "{} dt and h halved together ((dt / k, h / k), k = {}): the answer's total is this and the iterations'",
            path.display(),
            factors(j.finals.len())
        );
        let finest = format!("dt / {0}, h / {0}", 1usize << (j.finals.len() - 1));
        for q in &a.qois {
            if let Some(j) = &q.joint {
                row(&q.name, j, finest.clone());
            }
        }
    }
}

#[derive(Args)]
struct PoolArgs {
    /// URL of the coordinator (glissade-server)
    #[arg(long, env = "GLISSADE_SERVER", value_name = "URL")]
    coordinator: String,
    /// Id of this pool in the coordinator's records (default: assigned by the coordinator)
    #[arg(long, value_name = "ID")]
    pool_id: Option<String>,
    /// Stop after this many seconds without work (default: never)
    #[arg(long, value_name = "SECONDS")]
    idle_exit: Option<f64>,
    /// Memory one solve may take, MiB; a point whose scene needs more (estimated from its text)
    /// fails with that reason (default: the memory available when the point arrives)
    #[arg(long, value_name = "MIB", env = "GLISSADE_POOL_MEMORY_MIB")]
    memory_mib: Option<u64>,
    /// File holding the pool token of a coordinator that asks for one (else GLISSADE_TOKEN,
    /// else the file GLISSADE_TOKEN_FILE names)
    #[arg(long, value_name = "FILE")]
    token_file: Option<std::path::PathBuf>,
    /// Where results that could not be delivered before a stop are kept, and delivered from at
    /// the next start (default: $GLISSADE_SPOOL, else ~/.glissade/spool)
    #[arg(long, value_name = "DIR")]
    spool: Option<std::path::PathBuf>,
    /// PEM certificate of the authority that signed an https:// coordinator's certificate
    /// (else GLISSADE_CA_CERT, else the system's roots)
    #[arg(long, value_name = "FILE")]
    ca_cert: Option<std::path::PathBuf>,
    /// After SIGTERM or SIGINT, how long to keep trying to deliver a result to an unreachable
    /// coordinator before spooling it and exiting (a second signal: at once)
    #[arg(long, value_name = "SECONDS", default_value_t = 10.0)]
    stop_grace: f64,
}

/// Pool mode: one process, or P MPI ranks of which rank 0 talks to the coordinator.
fn pool(args: PoolArgs) -> Result<bool> {
    use glissade_worker::pool::ranks::{RootSolver, follow_root};
    use glissade_worker::pool::{PoolOptions, SerialPoolSolver, run_pool};
    let mut options = PoolOptions::new(args.coordinator);
    options.pool_id = args.pool_id;
    options.memory_budget = args.memory_mib.map(|m| m.saturating_mul(1 << 20));
    options.token = glissade_proto::auth::Token::for_client(args.token_file.as_deref())?;
    options.ca_cert = args.ca_cert;
    if let Some(dir) = args.spool {
        options.spool = Some(glissade_worker::pool::delivery::Spool { dir });
    }
    if !(args.stop_grace.is_finite() && args.stop_grace >= 0.0) {
        bail!("--stop-grace {}: give a number of seconds", args.stop_grace);
    }
    options.stop_grace = std::time::Duration::from_secs_f64(args.stop_grace);
    if let Some(s) = args.idle_exit {
        if !(s.is_finite() && s >= 0.0) {
            bail!("--idle-exit {s}: give a number of seconds");
        }
        options.idle_exit = Some(std::time::Duration::from_secs_f64(s));
    }
    let Some(universe) = mpi::initialize() else { bail!("MPI could not be initialised") };
    let comm = Mpi::new(universe.world())?;
    check_launcher(comm.size())?;
    if comm.size() == 1 {
        run_pool(options, &mut SerialPoolSolver::default())?;
        return Ok(true);
    }
    // A rank that panics mid-point would leave the others in a collective: the whole pool ends,
    // its lease expires and the coordinator hands the point out again (up to its attempt limit).
    abort_all_ranks_on_panic();
    if comm.rank() > 0 {
        follow_root(&comm).inspect_err(|_| mpi::traits::Communicator::abort(&comm.world, 1))?;
        return Ok(true);
    }
    options.ranks = comm.size() as u32;
    let mut root = RootSolver::new(&comm);
    let result = run_pool(options, &mut root);
    // Whatever ended the pool, the other ranks are waiting for a job: tell them to stop.
    root.stop();
    result.map(|()| true)
}

/// A process that OpenMPI's launcher started as one of several ranks, but that MPICH (which this
/// binary links) sees alone: every rank would solve the whole problem by itself. Debian switches
/// `mpiexec` to OpenMPI when a package pulls it in (ParaView does).
fn check_launcher(world_size: usize) -> Result<()> {
    let openmpi_ranks = std::env::var("OMPI_COMM_WORLD_SIZE").ok().and_then(|n| n.parse::<usize>().ok());
    if let Some(n) = openmpi_ranks.filter(|&n| n > 1 && world_size == 1) {
        bail!(
            "started by OpenMPI's mpiexec as one of {n} ranks, but glissade-worker is built on MPICH and would run alone: launch it with mpiexec.mpich (or srun)"
        );
    }
    Ok(())
}

/// Ends every rank of the job when one panics (MPI_Abort from the panic hook).
fn abort_all_ranks_on_panic() {
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        default_hook(info);
        // SAFETY: MPI is initialised (the universe lives until main returns); MPI_Abort on the
        // world ends every rank of the job.
        unsafe {
            mpi::ffi::MPI_Abort(mpi::ffi::RSMPI_COMM_WORLD, 101);
        }
    }));
}

/// A design point of a scene and the iterations' settings (`solve`, `refine`).
#[derive(Args)]
struct PointArgs {
    /// Scene file (TOML, see docs/scenes.md)
    scene: PathBuf,
    /// Parameter value, NAME=VALUE (repeatable)
    #[arg(long = "set", value_name = "NAME=VALUE")]
    set: Vec<String>,
    /// Error-indicator tolerance (default: the scene's, else 2e-4)
    #[arg(long, value_name = "T")]
    tol: Option<f64>,
    /// Iteration limit (default: the scene's, else 1000)
    #[arg(long, value_name = "N")]
    max_iter: Option<usize>,
}

impl PointArgs {
    /// The scene, read and parsed, and the request of its design point.
    fn read(&self) -> Result<(Scene, SolveRequest)> {
        let text = std::fs::read_to_string(&self.scene)
            .with_context(|| format!("cannot read scene {}", self.scene.display()))?;
        let scene = parse_scene(&text, &self.scene)?;
        let request = SolveRequest {
            point: parse_point(&self.set)?,
            tolerance: self.tol.map(|t| Tolerance::new("--tol", t)).transpose()?,
            max_iterations: self.max_iter,
            ..SolveRequest::default()
        };
        Ok((scene, request))
    }
}

#[derive(Args)]
struct SolveArgs {
    #[command(flatten)]
    point: PointArgs,
    /// Single-scale or multiscale (macro problem) iterations
    #[arg(long, value_enum)]
    scale: Option<Scale>,
    /// Start the iterations from a stored interface solution of the same scene (any design point)
    #[arg(long, value_name = "SOLUTION", conflicts_with = "accuracy")]
    init: Option<PathBuf>,
    /// Store the final interface solution (docs/solution-format.md), also when not converged
    #[arg(long, value_name = "SOLUTION")]
    save: Option<PathBuf>,
    /// Write the fields to OUT.h5 for ParaView: every node's displacement and velocity and every
    /// element's stress (OUT.xdmf), the interfaces' contact pressure, gap and slip
    /// (OUT-interfaces.xdmf), at every time step
    #[arg(long, value_name = "OUT.h5")]
    fields: Option<PathBuf>,
    /// Print one JSON object instead of the human summary
    #[arg(long)]
    json: bool,
    /// Time every rank's compute, waits at collectives, transfers and exchanges, and print the
    /// split (`profile` in the JSON; docs/performance.md, "Where a rank's time goes")
    #[arg(long, conflicts_with = "accuracy")]
    profile: bool,
    #[command(flatten)]
    accuracy: AccuracyArgs,
}

/// `--accuracy` on `solve` and `refine`: the rule of docs/accuracy.md chooses dt, h and the
/// tolerance.
#[derive(Args)]
struct AccuracyArgs {
    /// Solve to this accuracy: every QoI's final value within A of its scale (the largest
    /// magnitude of its history), dt, h (box bodies) and the tolerance chosen for it
    /// (docs/accuracy.md, "Ask for an accuracy")
    #[arg(long, value_name = "A", conflicts_with = "tol")]
    accuracy: Option<f64>,
    /// With --accuracy: the finest time step it may take, dt / N (a power of 2)
    #[arg(long, value_name = "N", default_value_t = glissade_core::accuracy::DEFAULT_MAX_TIME_FACTOR, requires = "accuracy")]
    max_dt_factor: usize,
    /// With --accuracy: the finest mesh it may take, h / N along each axis (a power of 2; 1: the
    /// mesh is kept)
    /// (default: 16 in 1D, 8 in 2D, 4 in 3D: the element count grows at most 64-fold; up to 16
    /// while the finest mesh keeps within 16,384 elements)
    #[arg(long, value_name = "N", requires = "accuracy")]
    max_h_factor: Option<usize>,
}

/// How a command ended, for the exit status.
enum Exit {
    Done,
    NotConverged,
    /// `--accuracy`: every level converged, the accuracy was not reached
    AccuracyNotReached,
}

impl From<bool> for Exit {
    fn from(converged: bool) -> Self {
        if converged { Exit::Done } else { Exit::NotConverged }
    }
}

/// Field files written by `--fields`.
#[derive(Serialize)]
struct FieldFiles {
    h5: String,
    xdmf: String,
}

/// `--json` output: the solve summary and what this command read and wrote.
#[derive(Serialize)]
struct Output<'a> {
    #[serde(flatten)]
    summary: &'a SolveSummary,
    scene_hash: String,
    /// the `--init` solution file, or null
    initialised_from: Option<String>,
    /// the `--save` solution file, or null
    saved_to: Option<String>,
    fields: Option<FieldFiles>,
    /// each QoI's unit (SI, by the scene's dimension: docs/scenes.md)
    units: BTreeMap<String, &'a str>,
    /// `--profile`: each rank's time split, or absent
    #[serde(skip_serializing_if = "Option::is_none")]
    profile: Option<Profile>,
    /// `--accuracy`: the discretisation chosen, its ladders and each QoI's error; the summary
    /// above is the chosen level's
    #[serde(skip_serializing_if = "Option::is_none")]
    accuracy: Option<AccuracyReport>,
    /// what a user must know beside the answer: each contact that slides ill-posed or chatters
    /// (`ContactActivity::any_warning`), also on stderr
    warnings: Vec<String>,
}

/// The design point of `--set NAME=VALUE`s (a name set twice takes its last value).
fn parse_point(sets: &[String]) -> Result<DesignPoint> {
    let mut point = DesignPoint::new();
    for s in sets {
        let (name, value) = s.split_once('=').with_context(|| format!("--set {s}: expected NAME=VALUE"))?;
        let v: f64 = value.trim().parse().with_context(|| format!("--set {s}: '{value}' is not a number"))?;
        if !v.is_finite() {
            bail!("--set {s}: value must be a finite number");
        }
        point.insert(name.trim(), v).with_context(|| format!("--set {s}"))?;
    }
    Ok(point)
}

/// Parses a scene (its mesh files next to it); TOML errors become one line with their position.
fn parse_scene(text: &str, path: &Path) -> Result<Scene> {
    let mut scene = parse_scene_text(text, path)?;
    scene
        .attach_meshes(path.parent().unwrap_or(Path::new("")))
        .map_err(|e| anyhow!("scene {}: {e}", path.display()))?;
    Ok(scene)
}

fn parse_scene_text(text: &str, path: &Path) -> Result<Scene> {
    Scene::parse(text).map_err(|e| anyhow!("scene {}: {e}", path.display()))
}

/// Refuses before a long solve to write where it could not (missing directory, clashing names).
fn check_output(flag: &str, path: &Path) -> Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    if !dir.is_dir() {
        bail!("{flag} {}: directory {} does not exist", path.display(), dir.display());
    }
    if path.is_dir() {
        bail!("{flag} {}: is a directory", path.display());
    }
    Ok(())
}

/// One solve; under `mpiexec.mpich -n P` every rank runs it and rank 0 writes the files and prints.
fn solve(args: SolveArgs, comm: &dyn Communicator) -> Result<Exit> {
    let scene_path = &args.point.scene;
    let (scene, mut request) = args.point.read()?;
    request.scale = args.scale;
    request.record_fields = args.fields.is_some();
    if let Some(p) = &args.save {
        check_output("--save", p)?;
    }
    if let Some(p) = &args.fields {
        check_output("--fields", p)?;
        if fields::xdmf_path(p) == *p {
            bail!("--fields {}: give the HDF5 file (e.g. out.h5); the .xdmf file is written beside it", p.display());
        }
    }

    let init = match &args.init {
        Some(p) => {
            let (meta, solution) = solution_file::read(p).with_context(|| format!("--init {}", p.display()))?;
            meta.check_fits(&scene).with_context(|| format!("--init {}", p.display()))?;
            tracing::info!(
                solution = %p.display(),
                converged = meta.converged,
                parameters = ?meta.parameters,
                "warm start"
            );
            request.init_parameters = Some(meta.parameters);
            Some(solution)
        }
        None => None,
    };

    tracing::info!(scene = %scene_path.display(), hash = %scene.content_hash(), "solving");
    let profiled = args.profile.then(|| Profiled::new(comm));
    let (scene, outcome, accuracy) = match args.accuracy.accuracy {
        Some(a) => {
            let (scene, outcome, report) = solve_accurately(comm, scene, &request, a, &args.accuracy, scene_path)?;
            (scene, outcome, Some(report))
        }
        None => {
            let outcome = solve_scene_on(
                profiled.as_ref().map_or(comm, |p| p as &dyn Communicator),
                &scene,
                &request,
                init.as_ref(),
            )
            .with_context(|| format!("scene {}", scene_path.display()))?;
            (scene, outcome, None)
        }
    };
    let scene_hash = scene.content_hash();
    let profile = profiled.and_then(Profiled::finish);
    let s = &outcome.summary;
    tracing::info!(
        converged = s.converged,
        iterations = s.iterations,
        eta = s.error_indicator,
        seconds = s.wall_seconds,
        "solved"
    );

    let exit = match &accuracy {
        Some(a) if s.converged && !a.reached => Exit::AccuracyNotReached,
        _ => Exit::from(s.converged),
    };
    if comm.rank() != 0 {
        return Ok(exit);
    }
    let why_not = accuracy.as_ref().and_then(|a| a.why_not.clone());
    // Files first: the summary is printed only once everything asked for is written.
    if let Some(p) = &args.save {
        let meta = glissade_worker::pool::solution_meta(&scene, &outcome);
        solution_file::write(p, &outcome.solution, &meta).with_context(|| format!("--save {}", p.display()))?;
    }
    let field_files = match (&args.fields, &outcome.fields) {
        (Some(p), Some(f)) => {
            let xdmf = fields::write(p, f, &scene_hash).with_context(|| format!("--fields {}", p.display()))?;
            Some(FieldFiles { h5: p.display().to_string(), xdmf: xdmf.display().to_string() })
        }
        (Some(p), None) => bail!("--fields {}: the solver returned no fields", p.display()),
        _ => None,
    };

    if args.json {
        let out = Output {
            summary: s,
            scene_hash,
            initialised_from: args.init.as_ref().map(|p| p.display().to_string()),
            saved_to: args.save.as_ref().map(|p| p.display().to_string()),
            fields: field_files,
            units: s.qoi.keys().filter_map(|q| Some((q.clone(), scene.unit(q)?))).collect(),
            profile,
            accuracy,
            warnings: s.contact.iter().filter_map(|c| c.any_warning()).collect(),
        };
        println!("{}", serde_json::to_string(&out)?);
    } else {
        print_human(&args, &scene, s, field_files.as_ref(), profile.as_ref(), accuracy.as_ref());
    }
    for w in s.contact.iter().filter_map(|c| c.any_warning()) {
        eprintln!("warning: {w}");
    }
    if let Some(why) = s.shortfall() {
        eprintln!("error: not converged: {why}");
    }
    if let Some(why) = why_not {
        eprintln!("error: accuracy not reached: {why}");
    }
    Ok(exit)
}

/// `solve` without `--json`: the summary, each QoI with its unit, the files written, the profile
/// and the accuracy's ladders where asked.
fn print_human(
    args: &SolveArgs,
    scene: &Scene,
    s: &SolveSummary,
    field_files: Option<&FieldFiles>,
    profile: Option<&Profile>,
    accuracy: Option<&AccuracyReport>,
) {
    print_solve(&args.point.scene, s);
    print_contact_evidence(scene, &s.contact);
    if let Some(p) = &args.init {
        println!("  initialised from {}", p.display());
    }
    for (name, q) in &s.qoi {
        println!("  {name:<24} final = {:.6e} {}", q.final_value, scene.unit(name).unwrap_or(""));
    }
    if let Some(p) = &args.save {
        println!("  interface solution saved to {}", p.display());
    }
    if let Some(f) = field_files {
        println!("  fields written to {} (open {} in ParaView)", f.h5, f.xdmf);
    }
    if let Some(p) = profile {
        print_profile(p);
    }
    if let Some(a) = accuracy {
        print_accuracy(a);
    }
}

/// The human summary of a solve: its outcome, its windows and its self-check.
fn print_solve(scene_path: &Path, s: &SolveSummary) {
    println!(
        "{}: {} after {} iterations, eta = {:.3e} (tolerance {:.1e}), {} dofs in {} substructures, {:.2} s",
        scene_path.display(),
        if s.converged { "converged" } else { "NOT converged" },
        s.iterations,
        s.error_indicator,
        s.tolerance,
        s.dofs,
        s.substructures,
        s.wall_seconds
    );
    if s.dynamic_windows > 1 {
        // an iteration of a time window sweeps the window only: the work is in sweeps
        println!(
            "  time windows: {} of {} steps, the dynamic work {:.1} sweeps of the interval",
            s.dynamic_windows, s.time_window, s.dynamic_sweeps
        );
        if s.dynamic_windows_stalled > 0 {
            println!(
                "  {} window(s) stalled on a QoI still small and were accepted against the whole histories; {} iterated again",
                s.dynamic_windows_stalled, s.dynamic_windows_redone
            );
        }
    }
    if let Some(c) = s.window_check.as_ref().filter(|c| c.outcome == glissade_solver::latin::CheckOutcome::BelowFloor) {
        println!(
            "  not checked: a pass ten times tighter than {:.0e} would be below the smallest tolerance",
            c.iteration_tolerance
        );
    } else if let Some(c) = &s.window_check {
        // the solve's own estimate cannot see an error that grows from window to window
        println!(
            "  checked {}: {} passes, {:.1} sweeps; the answers {} by {:.2e} on '{}' \
             (the answer returned iterated to {:.1e})",
            if c.whole_interval() {
                "by iterating on, 10 x tighter".to_string()
            } else {
                format!("in windows of {} and {} steps", c.windows[0], c.windows[1])
            },
            c.passes,
            c.sweeps,
            if c.outcome == glissade_solver::latin::CheckOutcome::Agreed { "agree" } else { "part" },
            c.discrepancy,
            c.qoi,
            c.iteration_tolerance
        );
        if let Some(floor) = c.floor {
            println!(
                "  a pass did not converge at {floor:.1e} (its iterations stall short of it) and was tried again looser"
            );
        }
        if let Some(p) = &c.parting {
            println!("  {}", p.evidence());
        }
    }
}

/// `solve --accuracy` and `refine --accuracy`: the ladders (progress on stderr), and the scene of
/// the level answered.
fn solve_accurately(
    comm: &dyn Communicator,
    scene: Scene,
    request: &SolveRequest,
    accuracy: f64,
    args: &AccuracyArgs,
    scene_path: &Path,
) -> Result<(Scene, glissade_solver::run::SolveOutcome, AccuracyReport)> {
    let accuracy = glissade_core::refine::Accuracy::new("--accuracy", accuracy)?;
    let limits = AccuracyLimits::asked(args.max_dt_factor, args.max_h_factor, &scene)?;
    let root = comm.rank() == 0;
    if root {
        eprintln!(
            "solving to accuracy {:.1e}: tolerance {:.1e}, dt down to dt / {}, h down to h / {}",
            accuracy.get(),
            accuracy.tolerance(),
            limits.max_time_factor,
            limits.max_mesh_factor
        );
    }
    let (report, outcome) = solve_to_accuracy(comm, &scene, request, accuracy, limits, |l| {
        if root {
            eprintln!(
                "  dt / {}, h / {}: {} steps, {} dofs, {} after {} iterations ({:.1} sweeps), {:.2} s",
                l.time_factor,
                l.mesh_factor,
                l.steps,
                l.dofs,
                if l.converged { "converged" } else { "NOT converged" },
                l.iterations,
                l.work,
                l.wall_seconds
            );
        }
    })
    .with_context(|| format!("scene {}", scene_path.display()))?;
    let answered = glissade_solver::accuracy::scene_at(&scene, report.time_factor, report.mesh_factor)?;
    Ok((answered, outcome, report))
}

/// `solve --accuracy`: the level chosen and each QoI's error with its parts.
fn print_accuracy(a: &AccuracyReport) {
    println!(
        "  accuracy {:.1e} asked: {} at dt / {}{} ({} steps, Newmark gamma {}), tolerance {:.1e}; {} levels solved, {:.1} sweeps, {:.2} s in all",
        a.accuracy,
        if a.reached { "REACHED" } else { "NOT REACHED" },
        a.time_factor,
        if a.mesh_refined { format!(", h / {}", a.mesh_factor) } else { " (mesh kept)".to_string() },
        a.steps,
        a.newmark_gamma,
        a.tolerance,
        a.levels.len(),
        a.work,
        a.wall_seconds
    );
    if let Some(c) = a.cheapest.filter(|c| (c.time_factor, c.mesh_factor) != (a.time_factor, a.mesh_factor)) {
        println!(
            "    a study would solve its points at dt / {}, h / {}: the cheapest level solved within the accuracy \
             (bound {:.1e}: its distance to the answer plus the answer's total)",
            c.time_factor, c.mesh_factor, c.bound
        );
    }
    println!("    errors relative to each QoI's scale (the largest magnitude of its history):");
    println!(
        "    {:<20} {:>14} {:>10} {:>9} {:>9} {:>9} {:>9} {:>9}",
        "QoI", "value", "scale", "time", "mesh", "dt+h", "iter.", "total"
    );
    for q in &a.qois {
        let mark = |e: &glissade_solver::accuracy::LadderError| {
            if !e.error.estimate.is_finite() {
                return "unknown".to_string();
            }
            if e.error.below_noise {
                return format!("<{:.1e}", e.error.estimate);
            }
            let tag = if e.error.erratic {
                "!"
            } else if e.error.order.is_some() {
                ""
            } else {
                "~"
            };
            format!("{:.1e}{tag}", e.error.estimate)
        };
        println!(
            "    {:<20} {:>14.6e} {:>10.3e} {:>9} {:>9} {:>9} {:>9.1e} {:>9.1e}{}",
            q.name,
            q.value,
            q.scale,
            mark(&q.time),
            q.mesh.as_ref().map_or("-".to_string(), mark),
            q.joint.as_ref().map_or("-".to_string(), mark),
            q.iteration,
            q.total,
            if q.within {
                ""
            } else if q.total.is_finite() {
                "  ABOVE"
            } else {
                "  UNKNOWN"
            }
        );
    }
    if a.qois.iter().any(|q| q.joint.is_some()) {
        println!(
            "    read where dt and h were halved together (dt, h; dt / 2, h / 2; ...: c dt / h kept): total = dt+h + iter.; \
             time and mesh are the ladders apart, shown, not added"
        );
    }
    println!(
        "    (< the last change within the iterations' noise; ! the changes do not fall steadily: the larger of the last two; ~ from two levels, first order assumed)"
    );
}

/// Each contact that lifted off and landed while it slid, and below friction 1, where its
/// interface is not regularised, the law that damps its chatter.
fn print_contact_evidence(scene: &Scene, contact: &[glissade_solver::contact_activity::ContactActivity]) {
    for c in contact.iter().filter(|c| c.landings_while_sliding > 0) {
        println!("  {}", c.evidence());
        let regularised = scene.interfaces.iter().any(|i| i.name == c.interface && i.prakash_clifton.is_some());
        if !regularised && c.friction <= glissade_solver::contact_activity::ILL_POSED_FRICTION {
            println!(
                "  (a contact that lands while it slides moves the answer with dt; `prakash_clifton` on interface '{}' \
                 damps the chatter: docs/scenes.md)",
                c.interface
            );
        }
    }
}

/// Threads each process's factorisations and solves may use (default 1: the ranks are the
/// parallelism).
const SOLVER_THREADS_VAR: &str = "GLISSADE_SOLVER_THREADS";

/// `solve --profile`: each rank's wall time split, then the collectives by kind and size.
fn print_profile(p: &Profile) {
    println!(
        "  profile (s): imbalance {:.2} (largest compute / mean), jitter {:.3} s (the slowest rank changing between synchronisations)",
        p.imbalance, p.jitter
    );
    println!("    rank     wall  compute     wait transfer exchange  last-in  messages     bytes");
    for r in &p.ranks {
        println!(
            "    {:>4} {:>8.3} {:>8.3} {:>8.3} {:>8.3} {:>8.3} {:>8} {:>9} {:>9}",
            r.rank,
            r.wall,
            r.compute,
            r.wait,
            r.transfer,
            r.exchange,
            r.last_to_arrive,
            r.messages_sent + r.messages_received,
            r.bytes_sent + r.bytes_received
        );
    }
    for g in &p.collectives {
        println!(
            "    {} of {} {}: {} calls, transfer {:.3} s, wait {:.3} s over the ranks, slowest rank's excess compute {:.3} s",
            g.kind,
            g.len,
            if g.kind == "sum" { "values" } else { "bytes" },
            g.calls,
            g.transfer,
            g.wait,
            g.slowest_excess
        );
    }
}

fn main() -> ExitCode {
    use tracing_subscriber::filter::{LevelFilter, Targets};
    use tracing_subscriber::layer::SubscriberExt;
    use tracing_subscriber::util::SubscriberInitExt;
    // RUST_LOG as `target=level` directives (a filter without regular expressions to build)
    let filter = std::env::var("RUST_LOG").ok().and_then(|v| v.parse::<Targets>().ok()).unwrap_or_else(|| {
        Targets::new().with_default(LevelFilter::WARN).with_target("glissade_worker::pool", LevelFilter::INFO)
    });
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .finish()
        .with(filter)
        .init();
    let cli = Cli::parse();
    // one thread a rank unless asked (glissade_solver::sparse::set_solver_threads says why)
    let threads = match std::env::var(SOLVER_THREADS_VAR).ok().map(|v| v.trim().parse::<usize>()) {
        None => 1,
        Some(Ok(n)) if (1..=1024).contains(&n) => n,
        Some(_) => {
            eprintln!("error: {SOLVER_THREADS_VAR}: give a number of threads from 1 to 1024");
            return ExitCode::FAILURE;
        }
    };
    glissade_solver::sparse::set_solver_threads(threads);
    let result = match cli.command {
        Command::Solve(args) => {
            // Without mpiexec this is a one-rank world (MPI singleton).
            let Some(universe) = mpi::initialize() else {
                eprintln!("error: MPI could not be initialised");
                return ExitCode::FAILURE;
            };
            let comm = match Mpi::new(universe.world()) {
                Ok(comm) => comm,
                Err(e) => {
                    eprintln!("error: {e}");
                    return ExitCode::FAILURE;
                }
            };
            if let Err(e) = check_launcher(comm.size()) {
                eprintln!("error: {e}");
                return ExitCode::FAILURE;
            }
            if comm.size() > 1 {
                abort_all_ranks_on_panic();
            }
            let result = solve(args, &comm);
            if let (Err(e), true) = (&result, comm.size() > 1) {
                // A failing rank must not leave the others waiting in a collective: abort all.
                eprintln!("error: rank {}: {}", comm.rank(), one_line(&format!("{e:#}")));
                // mpiexec forwards our stderr asynchronously and MPI_Abort kills the job at once:
                // without a pause the one line that says what went wrong is sometimes lost.
                std::thread::sleep(std::time::Duration::from_millis(300));
                mpi::traits::Communicator::abort(&comm.world, 1);
            }
            if comm.size() > 1 {
                // Every rank meets here before MPI_Finalize: rank 0 writes and prints after the
                // others have returned, and on a 16-core node multi-rank solves printed their
                // answer and then never ended, rank 0 busy while the others waited in
                // MPI_Finalize (docs/notebook/2026-11-28.md). With the barrier every run of a
                // third node ended by itself (docs/notebook/2026-11-30.md).
                mpi::traits::CommunicatorCollectives::barrier(&comm.world);
            }
            result
        }
        Command::Pool(args) => pool(args).map(Exit::from),
        Command::Refine(args) => refine(args),
        Command::Study(args) => study_cli::study(args),
        Command::Fields(args) => fields(args),
    };
    match result {
        Ok(Exit::Done) => ExitCode::SUCCESS,
        Ok(Exit::NotConverged) => ExitCode::from(2),
        Ok(Exit::AccuracyNotReached) => ExitCode::from(3),
        Err(e) => {
            eprintln!("error: {}", one_line(&format!("{e:#}")));
            ExitCode::FAILURE
        }
    }
}
