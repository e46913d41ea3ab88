//! `glissade demo`: the whole service on this machine with nothing to set up. A coordinator runs
//! in this process on a temporary database, one pool solves on a thread of it, and the CLI's own
//! commands submit a study of the shipped `three-blocks` `tiny` scene, watch it, print its
//! response surface and draw its pictures.

use glissade_cli::outln;
use glissade_core::scene::check_tolerance;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use glissade_proto::v1;
use glissade_server::ServerOptions;
use glissade_worker::pool::{PoolOptions, SerialPoolSolver, run_pool};

use crate::{
    ConvergenceArgs, Outcome, Server, SurfaceArgs, accuracy_line, convergence, discretisation_line, get_study, refused,
    surface, surface_accuracy_line, user, watch,
};

/// The scene of the demo, compiled in so that the binary alone is enough.
const SCENE: &str = include_str!("../../scenes/three-blocks-tiny.toml");

#[derive(Debug, clap::Args)]
pub struct DemoArgs {
    /// Values of each friction coefficient (f1, f2 from 0.1 to 0.2): an N x N grid.
    #[arg(long, value_name = "N", default_value_t = 5, value_parser = clap::value_parser!(u32).range(2..=41))]
    grid: u32,
    /// Tolerance on the error indicator (default: the scene's, 2e-4).
    #[arg(long, value_name = "T")]
    tol: Option<f64>,
    /// Directory for the pictures and the CSV (created if missing).
    #[arg(long, value_name = "DIR", default_value = "glissade-demo")]
    out: PathBuf,
}

pub async fn demo(args: DemoArgs) -> Result<Outcome> {
    if let Some(t) = args.tol {
        check_tolerance("--tol", t)?;
    }
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let data = tempfile::tempdir().context("creating a temporary database directory")?;

    let (stop_server, server_stopped) = tokio::sync::oneshot::channel::<()>();
    let (addr, serving) = glissade_server::bind(
        ServerOptions::new(data.path().join("db")),
        "127.0.0.1:0".parse().expect("literal address"),
        async {
            let _ = server_stopped.await;
        },
    )
    .await
    .context("starting the embedded coordinator")?;
    let server = tokio::spawn(serving);
    let url = format!("http://{addr}");
    outln!("coordinator on {url} (database in {}, removed at the end)", data.path().display());

    // One pool, on a thread of its own: the solver runs there, the pool's gRPC on its runtime.
    let (stop_pool, pool_stop) = tokio::sync::watch::channel(false);
    let mut options = PoolOptions::new(url.clone());
    options.pool_id = Some("demo-pool".into());
    options.wait = Duration::from_millis(500);
    options.stop = Some(pool_stop);
    let pool = std::thread::Builder::new()
        .name("demo-pool".into())
        .spawn(move || run_pool(options, &mut SerialPoolSolver::default()))
        .context("starting the pool thread")?;

    let outcome = run_study(&url, &args).await;

    let _ = stop_pool.send(true);
    let pool_result = tokio::task::spawn_blocking(move || pool.join()).await;
    let _ = stop_server.send(());
    let served = server.await;
    let outcome = outcome?;
    match pool_result {
        Ok(Ok(Ok(()))) => {}
        Ok(Ok(Err(e))) => return Err(e.context("the demo pool")),
        _ => bail!("the demo pool panicked"),
    }
    served.context("the embedded coordinator panicked")?.context("the embedded coordinator")?;
    Ok(outcome)
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
    Ok(outcome)
}
