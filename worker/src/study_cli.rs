//! `glissade-worker study`: a whole parametric study in one process (the CLI edge of
//! `glissade_core::study`).

use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Args;

use glissade_core::point::DesignPoint;
use glissade_core::refine::Accuracy;
use glissade_core::scene::{Scale, Tolerance};
use glissade_core::study::order::OrderKind;
use glissade_core::study::space::{DEFAULT_MAX_POINTS, GridAxis, ParameterSpace, design_points};
use glissade_core::study::store::MemoryStore;
use glissade_core::study::strategy::StrategyKind;
use glissade_core::study::{PointRecord, StudyOptions, StudyResult, run_study};
use glissade_solver::accuracy::{
    AccuracyLimits, AccuracyReport, HeldOutCheck, check_held_out, level_after_above, solve_to_accuracy, spread_order,
    study_level,
};
use glissade_solver::comm::Serial;
use glissade_solver::run::{PointSolver, SolveRequest};

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
    /// Neighbours combined by --strategy blend or linear (default: 3)
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
    /// Solve the study to this accuracy: pilot points solved to it choose dt, h and the
    /// tolerance, held-out points re-solved one level finer confirm it (docs/accuracy.md, "A
    /// study to an accuracy")
    #[arg(long, value_name = "A", conflicts_with = "tol")]
    accuracy: Option<f64>,
    /// With --accuracy: how many pilot points (the box's centre, then its corners)
    #[arg(long, value_name = "N", default_value_t = 3, requires = "accuracy")]
    pilots: usize,
    /// With --accuracy: how many held-out points to re-solve one level finer
    #[arg(long, value_name = "N", default_value_t = glissade_core::accuracy::DEFAULT_HELD_OUT, requires = "accuracy")]
    held_out: usize,
    /// With --accuracy: the finest time step a pilot may take, dt / N (a power of 2)
    #[arg(long, value_name = "N", default_value_t = glissade_core::accuracy::DEFAULT_MAX_TIME_FACTOR, requires = "accuracy")]
    max_dt_factor: usize,
    /// With --accuracy: the finest mesh a pilot may take, h / N (a power of 2; 1: kept)
    /// (default: 16 in 1D, 8 in 2D, 4 in 3D: the element count grows at most 64-fold; up to 16
    /// while the finest mesh keeps within 16,384 elements)
    #[arg(long, value_name = "N", requires = "accuracy")]
    max_h_factor: Option<usize>,
}

/// `study --accuracy`: what the pilots chose and what the held-out points said.
#[derive(serde::Serialize)]
struct StudyAccuracy {
    accuracy: f64,
    tolerance: f64,
    /// the study's level: dt / time_factor, h / mesh_factor
    time_factor: usize,
    mesh_factor: usize,
    pilots: Vec<Pilot>,
    held_out: Vec<HeldOutCheck>,
    /// every pilot reached the accuracy and every held-out point confirmed it
    confirmed: bool,
    /// why not, in one sentence
    why_not: Option<String>,
    /// the levels (dt / k, h / m) a held-out check found ABOVE, in order: after each the grid was
    /// solved again one level finer
    above: Vec<(usize, usize)>,
    /// pilots', study's (every level's) and held-out points' work (sweeps) and wall time
    work: AccuracyWork,
}

#[derive(serde::Serialize)]
struct Pilot {
    point: DesignPoint,
    report: AccuracyReport,
}

#[derive(serde::Serialize, Default)]
struct AccuracyWork {
    pilots: f64,
    study: f64,
    held_out: f64,
    wall_seconds: f64,
}

#[derive(serde::Serialize)]
struct StudyOutput<'a> {
    #[serde(flatten)]
    result: Option<&'a StudyResult>,
    accuracy: &'a StudyAccuracy,
}

/// Runs the study (to an accuracy: its pilots first, its held-out points last).
pub fn study(args: StudyArgs) -> Result<super::Exit> {
    let path = &args.scene;
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read scene {}", path.display()))?;
    let given = super::parse_scene(&text, path)?;
    let space = ParameterSpace::from_scene(&given);
    let axes = args.grid.iter().map(|g| GridAxis::parse(g, &space)).collect::<Result<Vec<_>, _>>()?;
    let points = design_points(&axes, args.max_points)?;
    let mut tolerance = args.tol.map(|t| Tolerance::new("--tol", t)).transpose()?;
    let mut accuracy = match args.accuracy {
        Some(a) => Some(pilots(&args, &given, &points, &space, Accuracy::new("--accuracy", a)?)?),
        None => None,
    };
    if let Some(a) = accuracy.as_ref().filter(|a| a.why_not.is_some()) {
        // a pilot could not reach the accuracy: no level is picked, the grid is not solved
        return finish_without_study(&args, a);
    }
    let mut scene = match &accuracy {
        Some(a) => {
            tolerance = Some(Tolerance::new("the accuracy's tolerance", a.tolerance)?);
            glissade_solver::accuracy::scene_at(&given, a.time_factor, a.mesh_factor)?
        }
        None => given.clone(),
    };
    let kind = args.strategy.unwrap_or(StrategyKind::DEFAULT);
    let k = args.k.unwrap_or(StrategyKind::DEFAULT_NEIGHBOURS);
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
        for w in r.contact.iter().filter_map(|c| c.any_warning()) {
            let _ = writeln!(std::io::stderr(), "warning: {}: {w}", values.join(" "));
        }
    };
    // (a store of its own per level: a warm start never mixes levels)
    let mut run = |scene: &glissade_core::scene::Scene| -> Result<StudyResult> {
        let mut store = MemoryStore::new(space.clone())?;
        let mut policy = order.policy(&space);
        Ok(run_study(
            scene,
            &points,
            &options,
            policy.as_mut(),
            &mut store,
            &mut PointSolver::default(),
            &mut progress,
        )?)
    };
    let mut result = run(&scene)?;

    if let Some(a) = accuracy.as_mut() {
        held_out(&args, &given, &points, &space, &result, a)?;
        // ABOVE: the grid solved again at the check's level, and checked one level finer
        let limits = AccuracyLimits::asked(args.max_dt_factor, args.max_h_factor, &given)?;
        let refine_mesh = a.pilots.iter().any(|p| p.report.mesh_refined);
        while let Some((k, m)) =
            above(a).then(|| level_after_above((a.time_factor, a.mesh_factor), refine_mesh, limits)).flatten()
        {
            eprintln!(
                "[above] the held-out check passes the accuracy at dt / {}, h / {}: the grid is solved again at dt / {k}, h / {m}",
                a.time_factor, a.mesh_factor
            );
            a.above.push((a.time_factor, a.mesh_factor));
            (a.time_factor, a.mesh_factor) = (k, m);
            (a.held_out, a.confirmed, a.why_not) = (Vec::new(), true, None);
            scene = glissade_solver::accuracy::scene_at(&given, k, m)?;
            result = run(&scene)?;
            held_out(&args, &given, &points, &space, &result, a)?;
        }
    }
    if let Some(dir) = &args.out {
        write_atomically(&dir.join("results.csv"), result.to_csv().as_bytes())?;
        write_atomically(&dir.join("results.json"), serde_json::to_string_pretty(&result)?.as_bytes())?;
    }
    if args.json {
        match &accuracy {
            Some(a) => println!("{}", serde_json::to_string(&StudyOutput { result: Some(&result), accuracy: a })?),
            None => println!("{}", serde_json::to_string(&result)?),
        }
    } else {
        print_summary(path, &result, (strategy.name(), order.name()), args.out.as_deref());
        if let Some(a) = &accuracy {
            print_study_accuracy(a);
        }
    }
    Ok(match &accuracy {
        _ if !all_converged(&result) => super::Exit::NotConverged,
        Some(a) if !a.confirmed => {
            eprintln!("error: accuracy not confirmed: {}", a.why_not.as_deref().unwrap_or(""));
            super::Exit::AccuracyNotReached
        }
        _ => super::Exit::Done,
    })
}

/// The study's summary in words: its points and their outcomes, the work, and the warnings of
/// points whose answers move under refinement whatever the tolerance (docs/verification.md 4d).
fn print_summary(
    path: &std::path::Path,
    result: &StudyResult,
    (strategy, order): (&str, &str),
    out: Option<&std::path::Path>,
) {
    let s = &result.summary;
    println!(
        "{}: {} points ({} converged, {} reused, {} not converged, {} failed), strategy {}, order {}, tolerance {:.1e}",
        path.display(),
        s.points,
        s.converged,
        s.reused,
        s.not_converged,
        s.failed,
        strategy,
        order,
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
    let chatter = result.records.iter().filter(|r| r.contact.iter().any(|c| c.chatter_warning().is_some())).count();
    if chatter > 0 {
        // docs/verification.md 4d: their answers move with the time step beyond the tolerance
        println!(
            "  warning: {chatter} of {} points chatter while they slide (their answers move with the time step; stderr names them)",
            s.points
        );
    }
    if let Some(dir) = out {
        println!("  results: {}, {}", dir.join("results.csv").display(), dir.join("results.json").display());
    }
}

/// The pilots of `study --accuracy`, each solved to the accuracy (progress on stderr), and the
/// level the study takes from them.
fn pilots(
    args: &StudyArgs,
    scene: &glissade_core::scene::Scene,
    points: &[DesignPoint],
    space: &ParameterSpace,
    accuracy: Accuracy,
) -> Result<StudyAccuracy> {
    let limits = AccuracyLimits::asked(args.max_dt_factor, args.max_h_factor, scene)?;
    if args.pilots == 0 || args.pilots > 16 || args.held_out > 16 {
        bail!("--pilots {} --held-out {}: from 1 to 16 pilots, at most 16 held-out points", args.pilots, args.held_out);
    }
    let chosen = spread_order(points, space, args.pilots);
    let mut pilots = Vec::new();
    for (k, &i) in chosen.iter().enumerate() {
        let point = space.complete(&points[i])?;
        let request = SolveRequest {
            point: point.clone(),
            max_iterations: args.max_iter,
            scale: args.scale,
            ..Default::default()
        };
        let (report, _) = solve_to_accuracy(&Serial, scene, &request, accuracy, limits, |_| {})?;
        eprintln!(
            "[pilot {}/{}] {}: {} at dt / {}, h / {} ({} levels, {:.2} s){}",
            k + 1,
            chosen.len(),
            points[i],
            if report.reached { "reached" } else { "NOT reached" },
            report.time_factor,
            report.mesh_factor,
            report.levels.len(),
            report.wall_seconds,
            report.why_not.as_ref().map_or(String::new(), |w| format!(": {w}"))
        );
        pilots.push(Pilot { point, report });
    }
    let (time_factor, mesh_factor) = study_level(pilots.iter().map(|p| p.report.study_candidate()));
    let why_not = pilots.iter().find(|p| !p.report.reached).map(|p| {
        format!(
            "the pilot {} did not reach the accuracy, so no level is chosen: {}",
            p.point,
            p.report.why_not.as_deref().unwrap_or("")
        )
    });
    let work = AccuracyWork {
        pilots: pilots.iter().map(|p| p.report.work).sum(),
        wall_seconds: pilots.iter().map(|p| p.report.wall_seconds).sum(),
        ..Default::default()
    };
    Ok(StudyAccuracy {
        accuracy: accuracy.get(),
        tolerance: accuracy.tolerance(),
        time_factor,
        mesh_factor,
        confirmed: why_not.is_none(),
        why_not,
        pilots,
        held_out: Vec::new(),
        above: Vec::new(),
        work,
    })
}

/// Every held-out point converged one level finer and one passes the accuracy there.
fn above(a: &StudyAccuracy) -> bool {
    !a.held_out.is_empty() && a.held_out.iter().all(|c| c.converged) && a.held_out.iter().any(|c| !c.within)
}

/// The held-out points of `study --accuracy`: the next points of the spread order after the
/// pilots, each re-solved one level finer against the study's answer.
fn held_out(
    args: &StudyArgs,
    scene: &glissade_core::scene::Scene,
    points: &[DesignPoint],
    space: &ParameterSpace,
    result: &StudyResult,
    a: &mut StudyAccuracy,
) -> Result<()> {
    let accuracy = Accuracy::new("--accuracy", a.accuracy)?;
    let refine_mesh = a.pilots.iter().any(|p| p.report.mesh_refined);
    a.work.study += result.summary.work;
    a.work.wall_seconds += result.summary.wall_seconds;
    for &i in spread_order(points, space, a.pilots.len() + args.held_out).iter().skip(a.pilots.len()) {
        // (a record's point carries every parameter, the grid's only those swept)
        let complete = space.complete(&points[i])?;
        let Some(record) = result.records.iter().find(|r| r.point == complete && r.converged) else {
            a.confirmed = false;
            a.why_not = Some(format!("the held-out point {} did not converge in the study", points[i]));
            continue;
        };
        let check = check_held_out(
            &Serial,
            scene,
            &complete,
            &record.qoi,
            (a.time_factor, a.mesh_factor),
            refine_mesh,
            accuracy,
        )?;
        let worst = check.qois.iter().max_by(|x, y| x.difference.total_cmp(&y.difference));
        eprintln!(
            "[held out] {} at dt / {}, h / {}: {}{}",
            points[i],
            check.time_factor,
            check.mesh_factor,
            if check.within { "confirms" } else { "ABOVE" },
            worst.map_or(String::new(), |q| format!(" (largest difference {:.1e} on '{}')", q.difference, q.name))
        );
        a.work.held_out += check.work;
        a.work.wall_seconds += check.wall_seconds;
        a.held_out.push(check);
    }
    if a.held_out.is_empty() && args.held_out > 0 && a.why_not.is_none() {
        eprintln!("[held out] none: every point of the grid was a pilot");
    }
    if let Some(c) = a.held_out.iter().find(|c| !c.within) {
        let worst = c.qois.iter().filter(|q| !q.within).max_by(|x, y| x.difference.total_cmp(&y.difference));
        a.why_not = Some(match worst {
            Some(q) => format!(
                "at the held-out point {}, '{}' moves by {:.1e} of its scale one level finer, above the accuracy {:.1e}",
                c.point, q.name, q.difference, a.accuracy
            ),
            None => format!("the held-out point {} did not converge one level finer", c.point),
        });
        a.confirmed = false;
    }
    Ok(())
}

/// `study --accuracy` whose pilots fell short: the pilots' evidence, no study.
fn finish_without_study(args: &StudyArgs, a: &StudyAccuracy) -> Result<super::Exit> {
    if args.json {
        println!("{}", serde_json::to_string(&StudyOutput { result: None, accuracy: a })?);
    } else {
        print_study_accuracy(a);
    }
    eprintln!("error: accuracy not reached: {}", a.why_not.as_deref().unwrap_or(""));
    Ok(super::Exit::AccuracyNotReached)
}

fn print_study_accuracy(a: &StudyAccuracy) {
    println!(
        "  accuracy {:.1e}: {} at dt / {}, h / {}, tolerance {:.1e}; {} pilots, {} held-out points",
        a.accuracy,
        if a.confirmed { "CONFIRMED" } else { "NOT CONFIRMED" },
        a.time_factor,
        a.mesh_factor,
        a.tolerance,
        a.pilots.len(),
        a.held_out.len()
    );
    for (k, m) in &a.above {
        println!(
            "  refined: ABOVE at dt / {k}, h / {m} (a held-out check passed the accuracy): the grid solved again one level finer"
        );
    }
    println!(
        "  work (sweeps): pilots {:.1}, study {:.1}, held-out {:.1}; {:.2} s in all",
        a.work.pilots, a.work.study, a.work.held_out, a.work.wall_seconds
    );
    for c in &a.held_out {
        let worst = c.qois.iter().max_by(|x, y| x.difference.total_cmp(&y.difference));
        if let Some(q) = worst {
            println!(
                "  held out {}: largest difference one level finer {:.1e} ('{}'){}",
                c.point,
                q.difference,
                q.name,
                if c.within { "" } else { "  ABOVE" }
            );
        }
    }
}

fn all_converged(result: &StudyResult) -> bool {
    result.summary.not_converged == 0 && result.summary.failed == 0
}

/// A whole file or none (temporary file synced, then renamed: `io::write_atomically`).
fn write_atomically(path: &std::path::Path, bytes: &[u8]) -> Result<()> {
    glissade_core::io::write_atomically(path, |w| w.write_all(bytes))
        .with_context(|| format!("cannot write {}", path.display()))
}
