//! `glissade demo`: the whole service on this machine with nothing to set up. It starts a
//! coordinator (`glissade-server`) on a temporary database and a pool a core (`glissade-worker pool`)
//! as processes, as a deployment runs them, and the CLI's own commands submit a study of the
//! shipped `three-blocks` `tiny` scene, watch it, print its response surface and draw its
//! pictures; then a study of the shipped `sliding-block-2d` asked for an accuracy, whose time step
//! and mesh the service chooses.

use glissade_cli::outln;
use glissade_core::scene::check_tolerance;
use std::future::Future;
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use glissade_proto::v1;
use tokio::io::AsyncBufReadExt;
use tokio::process::{Child, Command};

use crate::{
    ConvergenceArgs, Outcome, Server, SurfaceArgs, accuracy_line, convergence, discretisation_line, get_study, refused,
    sibling, surface, surface_accuracy_line, to_accuracy_lines, user, watch,
};

/// The scene of the demo, compiled in so that the binary alone is enough.
const SCENE: &str = include_str!("../../scenes/three-blocks-tiny.toml");

/// The scene of the demo's last study, asked for an accuracy: its bodies are generated boxes, so
/// the service may refine its mesh as well as its time step.
const ACCURACY_SCENE: &str = include_str!("../../scenes/sliding-block-2d.toml");

/// What the last study asks: every QoI within 5 % of its scale. The pilot answers at dt / 4, h / 4
/// in five levels (3 s in a release build), the study solves at dt / 2, h, its held-out point
/// one level finer (docs/accuracy.md, "A study to an accuracy").
const ACCURACY: f64 = 0.05;

/// How long the coordinator may take to say where it listens.
const START_TIMEOUT: Duration = Duration::from_secs(30);

#[derive(Debug, clap::Args)]
pub struct DemoArgs {
    /// Values of each friction coefficient (f1, f2 from 0.1 to 0.2): an N x N grid.
    #[arg(long, value_name = "N", default_value_t = 5, value_parser = clap::value_parser!(u32).range(2..=41))]
    grid: u32,
    /// Tolerance on the error indicator (default: the scene's, 2e-4).
    #[arg(long, value_name = "T")]
    tol: Option<f64>,
    /// Pools of one rank each that solve the points side by side (default: one a core, at most 4).
    #[arg(long, value_name = "P", value_parser = clap::value_parser!(u32).range(1..=16))]
    pools: Option<u32>,
    /// Directory for the pictures and the CSV (created if missing).
    #[arg(long, value_name = "DIR", default_value = "glissade-demo")]
    out: PathBuf,
}

pub async fn demo(args: DemoArgs) -> Result<Outcome> {
    if let Some(t) = args.tol {
        check_tolerance("--tol", t)?;
    }
    let (server_bin, worker_bin) = (sibling::find("glissade-server")?, sibling::find("glissade-worker")?);
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let data = tempfile::tempdir().context("creating a temporary directory")?;

    let (mut coordinator, addr) = start_coordinator(&server_bin, &data.path().join("db")).await?;
    let url = format!("http://{addr}");
    outln!("coordinator on {url} (database in {}, removed at the end)", data.path().display());
    let mut pools = Vec::new();
    for k in 1..=args.pools.unwrap_or_else(default_pools) {
        let mut pool = own_environment(Command::new(&worker_bin));
        pool.args(["pool", "--coordinator", &url, "--pool-id", &format!("demo-pool-{k}"), "--spool"])
            .arg(data.path().join(format!("spool-{k}")))
            .stdin(Stdio::null())
            .kill_on_drop(true);
        pools.push(pool.spawn().with_context(|| format!("starting pool {k} ({})", worker_bin.display()))?);
    }
    match pools.len() {
        1 => outln!("one pool of one rank"),
        n => outln!("{n} pools of one rank each"),
    }

    let outcome = tokio::select! {
        outcome = run_study(&url, &args) => outcome,
        ended = coordinator.wait() => Err(ended_early("the coordinator", ended)),
        ended = any_ended(&mut pools) => Err(ended_early("a pool", ended)),
    };
    // the study has ended (or failed): the processes have nothing left to keep
    for pool in &mut pools {
        let _ = pool.kill().await;
    }
    let _ = coordinator.kill().await;
    outcome
}

/// One pool a core, at most four: each solves a point on one rank, so the study's points run side
/// by side as they do under a deployment's pools.
fn default_pools() -> u32 {
    std::thread::available_parallelism().map_or(1, |n| n.get().min(4) as u32)
}

/// The first of the pools to stop (they are not expected to before the demo ends).
async fn any_ended(pools: &mut [Child]) -> std::io::Result<std::process::ExitStatus> {
    let mut waits: Vec<_> = pools.iter_mut().map(|pool| Box::pin(pool.wait())).collect();
    std::future::poll_fn(|cx| {
        waits
            .iter_mut()
            .find_map(|wait| match wait.as_mut().poll(cx) {
                std::task::Poll::Ready(ended) => Some(ended),
                std::task::Poll::Pending => None,
            })
            .map_or(std::task::Poll::Pending, std::task::Poll::Ready)
    })
    .await
}

/// A child of the demo with none of the user's GLISSADE_ settings (a token file, a data
/// directory, an address): the demo's coordinator and pools are its own. They say only what goes
/// wrong, unless RUST_LOG asks for more. They end with the demo however it ends: the kernel kills
/// each when the thread that started it exits (the demo runs on the main thread, under
/// `block_on`), so `glissade demo | head`, which exits at the closed pipe without unwinding and so
/// without `kill_on_drop`, leaves no coordinator or pool behind.
fn own_environment(mut command: Command) -> Command {
    for (key, _) in std::env::vars_os() {
        if key.to_string_lossy().starts_with("GLISSADE_") {
            command.env_remove(key);
        }
    }
    if std::env::var_os("RUST_LOG").is_none() {
        command.env("RUST_LOG", "warn");
    }
    // SAFETY: the closure runs in the child between fork and exec and calls only prctl, which
    // is async-signal-safe and changes the child's own state
    unsafe {
        command.pre_exec(|| {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) == -1 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    command
}

/// Starts `glissade-server` on a free loopback port over `db`, and reads where it listens.
async fn start_coordinator(bin: &Path, db: &Path) -> Result<(Child, String)> {
    let mut command = own_environment(Command::new(bin));
    command
        .args(["--listen", "127.0.0.1:0", "--data"])
        .arg(db)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .kill_on_drop(true);
    let mut child = command.spawn().with_context(|| format!("starting the coordinator ({})", bin.display()))?;
    let stdout = child.stdout.take().context("the coordinator's output")?;
    let mut lines = tokio::io::BufReader::new(stdout).lines();
    let listening = async {
        while let Some(line) = lines.next_line().await? {
            if let Some(addr) = line.strip_prefix("listening on ") {
                return Ok(Some(addr.trim().to_owned()));
            }
        }
        Ok::<_, std::io::Error>(None)
    };
    match tokio::time::timeout(START_TIMEOUT, listening).await {
        Ok(Ok(Some(addr))) => Ok((child, addr)),
        Ok(Ok(None)) => Err(ended_early("the coordinator", child.wait().await)),
        Ok(Err(e)) => Err(e).context("reading the coordinator's output"),
        Err(_) => bail!("the coordinator did not start within {} s", START_TIMEOUT.as_secs()),
    }
}

fn ended_early(who: &str, status: std::io::Result<std::process::ExitStatus>) -> anyhow::Error {
    match status {
        Ok(status) => anyhow::anyhow!("{who} stopped before the demo's end ({status}; its messages are above)"),
        Err(e) => anyhow::anyhow!("{who}: {e}"),
    }
}

async fn run_study(url: &str, args: &DemoArgs) -> Result<Outcome> {
    // the demo's own coordinator, on loopback: no token
    let server = &Server { url: url.to_owned(), token: None, ca_cert: None };
    let n = args.grid;
    let grid = vec![format!("f1=0.1:0.2:{n}"), format!("f2=0.1:0.2:{n}")];
    let mut client = user(server).await?;
    let reply = client
        .submit_study(v1::SubmitStudyRequest {
            scene: SCENE.to_owned(),
            grid: grid.clone(),
            tolerance: args.tol,
            label: "glissade demo".into(),
            ..Default::default()
        })
        .await
        .map_err(|s| refused("submitting the demo study", s))?
        .into_inner();
    let id = reply.study_id;
    outln!(
        "study {id}: three blocks (tiny), friction f1 x f2 on a {n} x {n} grid ({} points), \
         each point warm-started from a linear fit of its solved neighbours",
        reply.points
    );
    let outcome = watch(&mut client, id).await?;
    if !matches!(outcome, Outcome::Success) {
        return Ok(outcome);
    }
    let png = |name: &str| args.out.join(name);
    outln!("\nslip at A (centre of the upper interface) at the end of the load, m:");
    let surface_args = |qoi: Option<&str>, csv: Option<PathBuf>, png: Option<PathBuf>| SurfaceArgs {
        study: id,
        qoi: qoi.map(str::to_owned),
        fix: Vec::new(),
        all_solutions: false,
        csv,
        json: false,
        png,
        size: (1200, 560),
        at: Vec::new(),
    };
    surface(server, surface_args(Some("slip_A"), None, None)).await?;
    if n >= 2 {
        outln!("\nslip at A between the grid points, from the response surface (Gaussian process):");
        let at = vec!["f1=0.137,f2=0.151".to_owned(), "f1=0.2,f2=0.2".to_owned()];
        surface(server, SurfaceArgs { at, ..surface_args(Some("slip_A"), None, None) }).await?;
    }
    surface(server, surface_args(None, Some(png("surface.csv")), None)).await?;
    surface(server, surface_args(Some("slip_A"), None, Some(png("slip_A.png")))).await?;
    convergence(
        server,
        ConvergenceArgs { study: id, png: Some(png("convergence.png")), json: false, size: (900, 600) },
    )
    .await?;
    eprintln!("wrote {} (every QoI of every point)", png("surface.csv").display());
    // the accuracy the study got: its audit re-solves two of its points cold, far tighter
    let audit = get_study(&mut client, "demo", id, false, false).await?.accuracy.map(|a| a.audit_study_id);
    if let Some(audit) = audit {
        outln!("\nthe study's audit (study {audit}): points re-solved cold at 1/100 of the tolerance");
        watch(&mut client, audit).await?;
        if let Some(a) = get_study(&mut client, "demo", id, false, false).await?.accuracy {
            outln!("measured accuracy: {}", accuracy_line(&a));
        }
    }
    // and the time step's: two of its points re-solved with dt / 2
    let levels = get_study(&mut client, "demo", id, false, false).await?.discretisation.map(|d| d.level_study_ids);
    for level in levels.unwrap_or_default() {
        outln!("\nthe study's discretisation audit (study {level}): points re-solved cold with the time step halved");
        watch(&mut client, level).await?;
    }
    let s = get_study(&mut client, "demo", id, false, false).await?;
    if let Some(d) = &s.discretisation {
        outln!("time step's error: {}", discretisation_line(d));
        for verdict in &s.verdicts {
            outln!("{verdict}");
        }
    }
    // and the surface's between the points: points held out of it, predicted before they were
    // solved (docs/surrogate.md, "Surface audit")
    if let Some(held_out) = s.surface_accuracy.map(|a| a.audit_study_id).filter(|&a| a != 0) {
        outln!(
            "\nthe study's surface audit (study {held_out}): points held out of its response surface, solved cold at 1/100 of the tolerance"
        );
        watch(&mut client, held_out).await?;
        if let Some(a) = get_study(&mut client, "demo", id, false, false).await?.surface_accuracy {
            outln!("surface accuracy (errors relative to each QoI's spread): {}", surface_accuracy_line(&a));
        }
    }
    to_an_accuracy(&mut client).await
}

/// The same service asked for an accuracy instead of a tolerance: a pilot point climbs dt and h
/// until its ladders bound every QoI's error within it, the grid is solved at the cheapest level
/// that does, and a held-out point re-solved one level finer checks the choice.
async fn to_an_accuracy(client: &mut crate::User) -> Result<Outcome> {
    outln!(
        "\nasked for an accuracy instead of a tolerance: sliding-block-2d (a steel block pushed along a rigid floor), \
         friction f over 3 points, every QoI within {} % of its scale; the service chooses the time step, the mesh \
         and the tolerance",
        ACCURACY * 100.0
    );
    let reply = client
        .submit_study(v1::SubmitStudyRequest {
            scene: ACCURACY_SCENE.to_owned(),
            grid: vec!["f=0.2:0.4:3".to_owned()],
            accuracy: Some(ACCURACY),
            accuracy_pilots: Some(1),
            label: "glissade demo: to an accuracy".into(),
            ..Default::default()
        })
        .await
        .map_err(|s| refused("submitting the demo's study to an accuracy", s))?
        .into_inner();
    let id = reply.study_id;
    outln!("study {id}: its pilot's levels first, then its {} points at the level chosen", reply.points);
    let outcome = watch(client, id).await?;
    if !matches!(outcome, Outcome::Success) {
        return Ok(outcome);
    }
    let check = get_study(client, "demo", id, false, false).await?.to_accuracy.map_or(0, |t| t.held_out_study_id);
    if check != 0 {
        outln!("\nthe study's held-out check (study {check}): a point between the pilots re-solved one level finer");
        watch(client, check).await?;
    }
    if let Some(t) = get_study(client, "demo", id, false, false).await?.to_accuracy {
        for line in to_accuracy_lines(&t) {
            outln!("{line}");
        }
    }
    Ok(outcome)
}
