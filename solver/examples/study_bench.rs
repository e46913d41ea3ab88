//! Benchmark of the multiparametric strategies (docs/performance.md, "Multiparametric study"):
//! runs the same study with several (strategy, order, tolerance) settings, one after the other in
//! this process, and compares their iterations, wall time and QoI accuracy.
//!
//! ```sh
//! cargo run --release -p glissade-solver --example study_bench -- scenes/three-blocks-small.toml \
//!     --grid f1=0.10:0.20:11 --grid f2=0.10:0.20:11 \
//!     --run cold:asc:2e-4 --run previous:asc:2e-4 --run previous:desc:2e-4 \
//!     --run nearest:greedy:2e-4 --run blend:greedy:2e-4 --run nearest:greedy:2e-5 \
//!     --reference-grid f1=0.10:0.19:4 --reference-grid f2=0.10:0.19:4 --reference-tol 1e-7 \
//!     --out bench/small
//! ```
//!
//! Each run is written to OUT/STRATEGY-ORDER-TOL.json as soon as it ends (a run already there is
//! read back, not solved again: delete it to redo it); OUT/summary.md is the table of every run
//! in OUT. Accuracy: on the points of the reference grid (solved cold at the reference
//! tolerance, OUT/reference.json), the largest |q - q_ref| over those points divided by the
//! largest |q_ref|, per QoI.

use glissade_core::point::DesignPoint;
use std::path::{Path, PathBuf};

use clap::Parser;

use glissade_core::scene::{Scene, Tolerance};
use glissade_core::study::order::OrderKind;
use glissade_core::study::space::{GridAxis, ParameterSpace, design_points};
use glissade_core::study::store::MemoryStore;
use glissade_core::study::strategy::InitStrategy;
use glissade_core::study::{StudyOptions, StudyResult, run_study};
use glissade_solver::run::PointSolver;

#[derive(Parser)]
struct Args {
    scene: PathBuf,
    #[arg(long = "grid")]
    grid: Vec<String>,
    /// STRATEGY:ORDER:TOL, e.g. nearest:greedy:2e-4 (blend uses --k neighbours)
    #[arg(long = "run")]
    run: Vec<String>,
    #[arg(long, default_value_t = 2)]
    k: usize,
    #[arg(long = "reference-grid")]
    reference_grid: Vec<String>,
    #[arg(long = "reference-tol", default_value_t = 1e-7)]
    reference_tol: f64,
    #[arg(long, default_value_t = 2000)]
    max_iter: usize,
    #[arg(long)]
    out: PathBuf,
}

fn points(scene: &Scene, specs: &[String]) -> Vec<DesignPoint> {
    let space = ParameterSpace::from_scene(scene);
    let axes: Vec<GridAxis> =
        specs.iter().map(|s| GridAxis::parse(s, &space).unwrap_or_else(|e| panic!("{e}"))).collect();
    design_points(&axes, usize::MAX).unwrap_or_else(|e| panic!("{e}"))
}

fn run(
    scene: &Scene,
    pts: &[DesignPoint],
    strategy: InitStrategy,
    order: OrderKind,
    tol: f64,
    max_iter: usize,
    path: &Path,
) -> StudyResult {
    if let Ok(text) = std::fs::read_to_string(path)
        && let Ok(r) = serde_json::from_str::<StudyResult>(&text)
    {
        eprintln!("{}: already there", path.display());
        return r;
    }
    let space = ParameterSpace::from_scene(scene);
    let mut store = MemoryStore::new(space.clone()).expect("store");
    let mut policy = order.policy(&space);
    let tolerance = Tolerance::new("tolerance", tol).expect("a tolerance");
    let options = StudyOptions { strategy, tolerance: Some(tolerance), max_iterations: Some(max_iter), scale: None };
    let label = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let mut progress = |r: &glissade_core::study::PointRecord, done: usize, total: usize| {
        if done == 1 || done.is_multiple_of(10) || done == total {
            eprintln!("{label}: [{done}/{total}] {} {} it., {:.2} s", r.point, r.iterations, r.wall_seconds);
        }
    };
    let result =
        run_study(scene, pts, &options, policy.as_mut(), &mut store, &mut PointSolver::default(), &mut progress)
            .expect("study");
    std::fs::write(path, serde_json::to_string(&result).expect("json")).expect("write run");
    result
}

/// Largest |q - q_ref| / max |q_ref| over the reference points, per QoI.
fn accuracy(result: &StudyResult, reference: &StudyResult, space: &ParameterSpace) -> Vec<(String, f64)> {
    let names: Vec<String> = reference.records[0].qoi.keys().cloned().collect();
    names
        .into_iter()
        .map(|name| {
            let scale = reference.records.iter().map(|r| r.qoi[&name].abs()).fold(0.0, f64::max);
            let worst = reference
                .records
                .iter()
                .filter_map(|r| {
                    let m = result.records.iter().find(|m| space.normalised_distance(&m.point, &r.point) < 1e-9)?;
                    Some((m.qoi.get(&name)? - r.qoi[&name]).abs())
                })
                .fold(0.0, f64::max);
            (name, if scale > 0.0 { worst / scale } else { worst })
        })
        .collect()
}

fn main() {
    let args = Args::parse();
    // read with its mesh files (mesh bodies), hashed as the service hashes it
    let scene = Scene::read(&args.scene).expect("scene");
    let space = ParameterSpace::from_scene(&scene);
    std::fs::create_dir_all(&args.out).expect("out dir");
    let pts = points(&scene, &args.grid);
    let reference = (!args.reference_grid.is_empty()).then(|| {
        let rp = points(&scene, &args.reference_grid);
        run(
            &scene,
            &rp,
            InitStrategy::Cold,
            OrderKind::Asc,
            args.reference_tol,
            10 * args.max_iter,
            &args.out.join("reference.json"),
        )
    });
    for spec in &args.run {
        let (strategy, order, tol, name) = parse_run(spec, args.k);
        run(&scene, &pts, strategy, order, tol, args.max_iter, &args.out.join(format!("{name}.json")));
    }

    // The table of every run in OUT.
    let mut runs: Vec<(String, StudyResult)> = std::fs::read_dir(&args.out)
        .expect("out dir")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "json") && p.file_stem().is_some_and(|s| s != "reference"))
        .filter_map(|p| {
            let r: StudyResult = serde_json::from_str(&std::fs::read_to_string(&p).ok()?).ok()?;
            Some((p.file_stem()?.to_string_lossy().into_owned(), r))
        })
        .collect();
    runs.sort_by(|a, b| a.0.cmp(&b.0));
    let steps = scene.time.steps;
    let cold = runs
        .iter()
        .filter(|(_, r)| r.strategy == InitStrategy::Cold)
        .map(|(_, r)| (r.tolerance, work(r, steps), r.summary.wall_seconds))
        .collect::<Vec<_>>();
    let mut md = String::new();
    md += &format!("Scene `{}`, {} points.\n\n", args.scene.display(), pts.len());
    let qoi_names: Vec<String> = reference.as_ref().map_or(vec![], |r| r.records[0].qoi.keys().cloned().collect());
    md += "| run | tol | converged | work | dynamic iterations | static iterations | first point (work) | wall s | gain (work) | gain (wall) |";
    for q in &qoi_names {
        md += &format!(" error {q} |");
    }
    md += "\n|---|---|---|---|---|---|---|---|---|---|";
    md += &"---|".repeat(qoi_names.len());
    md += "\n";
    for (name, r) in &runs {
        let s = &r.summary;
        // gains against the cold run at the same tolerance, else the loosest cold run
        let c = cold.iter().find(|c| c.0 == r.tolerance).or(cold.iter().max_by(|a, b| a.0.total_cmp(&b.0)));
        let gain = |x: f64, y: f64| if y > 0.0 { format!("{:.2}", x / y) } else { "-".into() };
        let first = r.records.first().map_or(0.0, |p| p.work(steps));
        md += &format!(
            "| {name} | {:.0e} | {}/{} | {:.0} | {} | {} | {:.0} | {:.1} | {} | {} |",
            r.tolerance,
            s.converged,
            s.points,
            work(r, steps),
            dynamic(r),
            s.total_iterations - dynamic(r),
            first,
            s.wall_seconds,
            c.map_or("-".into(), |c| gain(c.1, work(r, steps))),
            c.map_or("-".into(), |c| gain(c.2, s.wall_seconds)),
        );
        if let Some(reference) = &reference {
            for (_, e) in accuracy(r, reference, &space) {
                md += &format!(" {e:.1e} |");
            }
        }
        md += "\n";
    }
    md += &format!(
        "\nWork: dynamic iterations + static iterations / {steps} (a dynamic iteration sweeps every step, a \
         static one a single step).\n"
    );
    if let Some(reference) = &reference {
        md += &format!(
            "\nErrors: largest |q - q_ref| over the {} reference points divided by the largest |q_ref|; \
             reference: cold solves at tolerance {:.0e}.\n",
            reference.records.len(),
            reference.tolerance
        );
    }
    md += &shapes(&runs);
    std::fs::write(args.out.join("summary.md"), &md).expect("summary");
    print!("{md}");
}

/// `STRATEGY:ORDER:TOL` (`--run`): the strategy, the order, the tolerance and the run's name.
fn parse_run(spec: &str, k: usize) -> (InitStrategy, OrderKind, f64, String) {
    let parts: Vec<&str> = spec.split(':').collect();
    assert_eq!(parts.len(), 3, "--run {spec}: STRATEGY:ORDER:TOL");
    let strategy = match parts[0] {
        "cold" => InitStrategy::Cold,
        "previous" => InitStrategy::Previous,
        "nearest" => InitStrategy::Nearest,
        "blend" => InitStrategy::Blend { k },
        "linear" => InitStrategy::Linear { k },
        s => panic!("unknown strategy {s}"),
    };
    let order = match parts[1] {
        "asc" => OrderKind::Asc,
        "desc" => OrderKind::Desc,
        "greedy" => OrderKind::Greedy,
        o => panic!("unknown order {o}"),
    };
    let tol: f64 = parts[2].parse().expect("tolerance");
    let neighbours = if parts[0] == "blend" || parts[0] == "linear" { k.to_string() } else { String::new() };
    (strategy, order, tol, format!("{}{neighbours}-{}-{}", parts[0], parts[1], parts[2]))
}

/// The shape of each run: the first points solved (the paper's table is the first row of the
/// ascending sweep) and the cost of points where an interface sticks (a slip QoI is zero).
fn shapes(runs: &[(String, StudyResult)]) -> String {
    let mut md = String::new();
    md += "\n| run | dynamic iterations of the first 11 points solved | warm points, some slip = 0: mean dynamic iterations | warm points, every slip > 0 |\n|---|---|---|---|\n";
    for (name, r) in runs {
        let first: Vec<String> =
            r.records.iter().take(11).map(|p| (p.iterations - p.static_iterations).to_string()).collect();
        let sticks =
            |p: &glissade_core::study::PointRecord| p.qoi.iter().any(|(k, v)| k.starts_with("slip") && v.abs() < 1e-15);
        let mean = |stick: bool| {
            let v: Vec<usize> = r
                .records
                .iter()
                .skip(1)
                .filter(|p| sticks(p) == stick)
                .map(|p| p.iterations - p.static_iterations)
                .collect();
            if v.is_empty() {
                "-".to_string()
            } else {
                format!("{:.1} ({} points)", v.iter().sum::<usize>() as f64 / v.len() as f64, v.len())
            }
        };
        md += &format!("| {name} | {} | {} | {} |\n", first.join(", "), mean(true), mean(false));
    }
    md
}

/// Work of a study: dynamic iterations + static iterations / steps ([`PointRecord::work`]).
///
/// [`PointRecord::work`]: glissade_core::study::PointRecord::work
fn work(r: &StudyResult, steps: usize) -> f64 {
    r.records.iter().map(|p| p.work(steps)).sum()
}

/// Iterations of the dynamic stage alone.
fn dynamic(r: &StudyResult) -> usize {
    r.records.iter().map(|p| p.iterations - p.static_iterations).sum()
}
