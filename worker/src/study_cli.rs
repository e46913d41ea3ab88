//! `glissade-worker study`: a whole parametric study in one process (the CLI edge of
//! `glissade_core::study`).

use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Args;

use glissade_core::scene::{Scale, Tolerance};
use glissade_core::study::order::OrderKind;
use glissade_core::study::space::{DEFAULT_MAX_POINTS, GridAxis, ParameterSpace, design_points};
use glissade_core::study::store::MemoryStore;
use glissade_core::study::strategy::StrategyKind;
use glissade_core::study::{PointRecord, StudyOptions, StudyResult, run_study};
use glissade_solver::run::PointSolver;

pub const STUDY_EXAMPLES: &str = "\
Examples:
  glissade-worker study scenes/three-blocks-tiny.toml --grid f1=0.10:0.20:11 --grid f2=0.10:0.20:11
  glissade-worker study scenes/three-blocks-small.toml --grid f1=0.1,0.15,0.2 --grid f2=0.1 --strategy previous --order desc
  glissade-worker study scenes/three-blocks-tiny.toml --grid f1=lhs:20:7 --grid f2=lhs:20:7 --strategy blend --out study-out

Grids: NAME=START:STOP:COUNT (COUNT evenly spaced values), NAME=V1,V2,... (a list), or
NAME=lhs:N:SEED[:LO:HI] (an N-point Latin hypercube over the scene's range or [LO, HI]; parameters
with the same N:SEED form one joint hypercube). Several --grid give the cartesian product;
parameters not swept stay at their defaults.
Strategies: cold (zero fields, the paper's direct computation), previous (the last converged
point, the paper's sweep), nearest (nearest converged point in normalised parameter distance),
blend (the --k nearest combined with inverse-distance weights when only friction parameters
differ, else nearest), linear (the --k nearest combined to reproduce a linear variation:
interpolation or extrapolation, same rule). Orders: asc, desc (lexicographic sweeps), greedy (the pending point nearest
to those done). A point already solved to the tolerance is answered with 0 iterations.
Progress: one line per point on stderr. Exit status: 0 all converged, 1 error, 2 some point not
converged or failed.";

#[derive(Args)]
pub struct StudyArgs {
    /// Scene file (TOML, see docs/scenes.md)
    scene: PathBuf,
    /// Parameter sweep NAME=SPEC (repeatable; see below)
    #[arg(long = "grid", value_name = "NAME=SPEC")]
    grid: Vec<String>,
    /// Where each point's iterations start (default: linear, a fit of the solved neighbours)
    #[arg(long, value_enum)]
    strategy: Option<StrategyKind>,
    /// Neighbours combined by --strategy blend or linear (default: 3 for blend, 8 for linear)
    #[arg(long, value_name = "K")]
    k: Option<usize>,
    /// Order of the points
    #[arg(long, value_enum, default_value = "greedy")]
    order: OrderKind,
    /// Error-indicator tolerance (default: the scene's, else 2e-4)
    #[arg(long, value_name = "T")]
    tol: Option<f64>,
    /// Iteration limit per stage (default: the scene's, else 1000)
    #[arg(long, value_name = "N")]
    max_iter: Option<usize>,
    /// Single-scale or multiscale (macro problem) iterations
    #[arg(long, value_enum)]
    scale: Option<Scale>,
    /// Write DIR/results.csv and DIR/results.json (the directory is created)
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// Print the whole result as one JSON object instead of the summary
    #[arg(long)]
    json: bool,
    /// Refuse a grid of more design points than this
    #[arg(long, value_name = "N", default_value_t = DEFAULT_MAX_POINTS)]
    max_points: usize,
}

/// Runs the study; Ok(false) when some point did not converge.
pub fn study(args: StudyArgs) -> Result<bool> {
    let path = &args.scene;
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read scene {}", path.display()))?;
    let scene = super::parse_scene(&text, path)?;
    let space = ParameterSpace::from_scene(&scene);
    let axes = args.grid.iter().map(|g| GridAxis::parse(g, &space)).collect::<Result<Vec<_>, _>>()?;
    let points = design_points(&axes, args.max_points)?;
    let tolerance = args.tol.map(|t| Tolerance::new("--tol", t)).transpose()?;
    let kind = args.strategy.unwrap_or(StrategyKind::DEFAULT);
    let k = args.k.unwrap_or_else(|| kind.default_neighbours());
    if k == 0 {
        bail!("--k 0: blend needs at least 1 neighbour");
    }
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("--out {}: cannot create the directory", dir.display()))?;
    }
    let strategy = kind.with_neighbours(k);
    let order = args.order;
    let options = StudyOptions { strategy, tolerance, max_iterations: args.max_iter, scale: args.scale };
    let mut store = MemoryStore::new(space.clone())?;
    let mut policy = order.policy(&space);
    let swept: Vec<String> = axes.iter().map(|a| a.name.clone()).collect();
    let mut progress = |r: &PointRecord, done: usize, total: usize| {
        let values: Vec<String> =
            swept.iter().map(|n| format!("{n}={}", r.point.get(n).map_or("?".into(), |v| v.to_string()))).collect();
        let outcome = match (&r.error, r.converged) {
            (Some(e), _) => format!("FAILED: {e}"),
            (None, true) => format!("{} iterations, eta {:.2e}", r.iterations, r.eta.unwrap_or(f64::NAN)),
            (None, false) => {
                format!("NOT converged after {} iterations, eta {:.2e}", r.iterations, r.eta.unwrap_or(f64::NAN))
            }
        };
        let _ = writeln!(
            std::io::stderr(),
            "[{done}/{total}] {}: {outcome}, {:.2} s, from {}",
            values.join(" "),
            r.wall_seconds,
            r.started_from()
        );
        for w in r.contact.iter().filter_map(|c| c.warning()) {
            let _ = writeln!(std::io::stderr(), "warning: {}: {w}", values.join(" "));
        }
    };
    let result =
        run_study(&scene, &points, &options, policy.as_mut(), &mut store, &mut PointSolver::default(), &mut progress)?;

    if let Some(dir) = &args.out {
        write_atomically(&dir.join("results.csv"), result.to_csv().as_bytes())?;
        write_atomically(&dir.join("results.json"), serde_json::to_string_pretty(&result)?.as_bytes())?;
    }
    let s = &result.summary;
    if args.json {
        println!("{}", serde_json::to_string(&result)?);
    } else {
        println!(
            "{}: {} points ({} converged, {} reused, {} not converged, {} failed), strategy {}, order {}, tolerance {:.1e}",
            path.display(),
            s.points,
            s.converged,
            s.reused,
            s.not_converged,
            s.failed,
            strategy.name(),
            order.name(),
            result.tolerance
        );
        println!(
            "  iterations: {} in all; first point {}, later points {:.1} on average",
            s.total_iterations, s.first_iterations, s.mean_later_iterations
        );
        println!("  work: {:.1} (dynamic iterations + static iterations / time steps)", s.work);
        if let Some(line) = s.warm_against_cold() {
            println!("  {line}");
        }
        println!("  wall time: {:.2} s", s.wall_seconds);
        let ill_posed = result.records.iter().filter(|r| r.contact.iter().any(|c| c.ill_posed)).count();
        if ill_posed > 0 {
            // docs/verification.md 4d: no tolerance bounds how far these answers move under refinement
            println!(
                "  warning: {ill_posed} of {} points slide ill-posed (on a rigid wall above friction 1; stderr names them)",
                s.points
            );
        }
        if let Some(dir) = &args.out {
            println!("  results: {}, {}", dir.join("results.csv").display(), dir.join("results.json").display());
        }
    }
    Ok(all_converged(&result))
}

fn all_converged(result: &StudyResult) -> bool {
    result.summary.not_converged == 0 && result.summary.failed == 0
}

/// A whole file or none (temporary file synced, then renamed: `io::write_atomically`).
fn write_atomically(path: &std::path::Path, bytes: &[u8]) -> Result<()> {
    glissade_core::io::write_atomically(path, |w| w.write_all(bytes))
        .with_context(|| format!("cannot write {}", path.display()))
}
