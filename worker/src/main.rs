//! `glissade-worker`: runs LATIN solves of scenes (and, later, MPI worker pools).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand, ValueEnum};

use glissade_worker::run::{SolveRequest, solve_scene};
use glissade_worker::scene::{Scale, Scene};

#[derive(Parser)]
#[command(
    name = "glissade-worker",
    version,
    about = "LATIN solver for transient dynamics of elastic assemblies with contact and friction"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Clone, Copy, ValueEnum)]
enum ScaleArg {
    Single,
    Multi,
}

#[derive(Subcommand)]
enum Command {
    /// Solve one design point of a scene.
    #[command(
        after_help = "Examples:\n  glissade-worker solve scenes/bar-impact-1d.toml\n  glissade-worker solve scenes/three-blocks-tiny.toml --set f1=0.12 --json"
    )]
    Solve {
        /// Scene file (TOML, see docs/scenes.md)
        scene: PathBuf,
        /// Parameter value, NAME=VALUE (repeatable)
        #[arg(long = "set", value_name = "NAME=VALUE")]
        set: Vec<String>,
        /// Error-indicator tolerance (default: the scene's, else 2e-4)
        #[arg(long)]
        tol: Option<f64>,
        /// Iteration limit (default: the scene's, else 1000)
        #[arg(long)]
        max_iter: Option<usize>,
        /// Single-scale or multiscale (macro problem) iterations
        #[arg(long, value_enum)]
        scale: Option<ScaleArg>,
        /// Print one JSON object instead of the human summary
        #[arg(long)]
        json: bool,
    },
}

fn parse_set(s: &str) -> Result<(String, f64)> {
    let (name, value) = s
        .split_once('=')
        .with_context(|| format!("--set {s}: expected NAME=VALUE"))?;
    let v: f64 = value
        .trim()
        .parse()
        .with_context(|| format!("--set {s}: '{value}' is not a number"))?;
    if !v.is_finite() {
        bail!("--set {s}: value must be a finite number");
    }
    Ok((name.trim().to_string(), v))
}

fn solve(
    scene_path: PathBuf,
    set: Vec<String>,
    tol: Option<f64>,
    max_iter: Option<usize>,
    scale: Option<ScaleArg>,
    json: bool,
) -> Result<bool> {
    let text = std::fs::read_to_string(&scene_path)
        .with_context(|| format!("cannot read scene {}", scene_path.display()))?;
    let scene = Scene::parse(&text).with_context(|| format!("scene {}", scene_path.display()))?;
    let request = SolveRequest {
        set: set.iter().map(|s| parse_set(s)).collect::<Result<_>>()?,
        tolerance: tol,
        max_iterations: max_iter,
        scale: scale.map(|s| match s {
            ScaleArg::Single => Scale::Single,
            ScaleArg::Multi => Scale::Multi,
        }),
        record_fields: false,
    };
    let outcome = solve_scene(&scene, &request, None)
        .with_context(|| format!("scene {}", scene_path.display()))?;
    let s = &outcome.summary;
    if json {
        println!("{}", serde_json::to_string(s)?);
    } else {
        println!(
            "{}: {} after {} iterations, eta = {:.3e} (tolerance {:.1e}), {} dofs in {} substructures, {:.2} s",
            scene_path.display(),
            if s.converged {
                "converged"
            } else {
                "NOT converged"
            },
            s.iterations,
            s.error_indicator,
            s.tolerance,
            s.dofs,
            s.substructures,
            s.wall_seconds
        );
        for (name, q) in &s.qoi {
            println!("  {name:<24} final = {:.6e}", q.final_value);
        }
    }
    if !s.converged {
        eprintln!(
            "error: not converged: eta = {:.3e} > tolerance {:.1e} after {} iterations",
            s.error_indicator, s.tolerance, s.iterations
        );
    }
    Ok(s.converged)
}

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "warn".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Solve {
            scene,
            set,
            tol,
            max_iter,
            scale,
            json,
        } => solve(scene, set, tol, max_iter, scale, json),
    };
    match result {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::from(2),
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
