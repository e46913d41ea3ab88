//! Speed against accuracy (docs/accuracy.md and docs/accuracy.png): the QoI error of the
//! three-blocks scene at several meshes and tolerances against the finest mesh at the tightest
//! tolerance, versus wall time and iterations, from cold and warm-started.
//!
//! ```sh
//! cargo run --release -p glissade-solver --example accuracy -- \
//!     --scene scenes/three-blocks-tiny.toml --scene scenes/three-blocks-small.toml \
//!     --scene scenes/three-blocks-medium.toml --tol 1e-2 --tol 1e-3 --tol 2e-4 --tol 1e-5 \
//!     --cache bench/accuracy --out docs
//! ```
//!
//! Per mesh and tolerance: the design point P solved cold, and P warm-started from the converged
//! solution of its neighbour Q at the same tolerance (the situation of every point but the first
//! in a study; the warm solve reuses Q's factorisation, as in a study). Each solve is cached in
//! CACHE/MESH-TOL-KIND.json, so an interrupted run resumes; delete the cache to redo it. The
//! reference is the last --scene (the finest) at the smallest --tol, cold.

use glissade_core::point::DesignPoint;
use std::path::{Path, PathBuf};

use clap::Parser;
use plotters::coord::Shift;
use plotters::prelude::*;
use serde::{Deserialize, Serialize};

use glissade_core::scene::{Scene, Tolerance};
use glissade_core::study::order::LexicographicAscending;
use glissade_core::study::space::ParameterSpace;
use glissade_core::study::store::MemoryStore;
use glissade_core::study::strategy::InitStrategy;
use glissade_core::study::{StudyOptions, run_study};
use glissade_solver::run::PointSolver;

#[derive(Parser)]
struct Args {
    /// scene files, coarsest first (the last is the reference mesh)
    #[arg(long = "scene")]
    scenes: Vec<PathBuf>,
    /// tolerances (the smallest is the reference tolerance)
    #[arg(long = "tol")]
    tols: Vec<f64>,
    /// the QoI compared
    #[arg(long, default_value = "slip_A")]
    qoi: String,
    /// the design point P, NAME=VALUE,...
    #[arg(long, default_value = "f1=0.11,f2=0.10")]
    point: String,
    /// its neighbour Q, which P is warm-started from
    #[arg(long, default_value = "f1=0.10,f2=0.10")]
    neighbour: String,
    #[arg(long)]
    cache: PathBuf,
    /// where accuracy.md and accuracy.png are written
    #[arg(long)]
    out: PathBuf,
    /// solves not to run, as MESH-TOL-KIND (e.g. three-blocks-medium-1e-5-warm): listed in
    /// accuracy.md as not measured
    #[arg(long = "skip")]
    skip: Vec<String>,
    /// a line on where and when it was measured, copied into accuracy.md
    #[arg(long, default_value = "")]
    note: String,
}

/// One solve of P.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct Sample {
    mesh: String,
    dofs_label: String,
    tol: f64,
    warm: bool,
    converged: bool,
    iterations: usize,
    static_iterations: usize,
    wall_seconds: f64,
    qoi: f64,
}

fn parse_point(s: &str) -> DesignPoint {
    DesignPoint::from_pairs(s.split(',').map(|kv| {
        let (k, v) = kv.split_once('=').expect("NAME=VALUE");
        (k.trim().to_string(), v.trim().parse::<f64>().expect("number"))
    }))
    .expect("a design point")
}

fn sample_name(scene_path: &Path, tol: f64, warm: bool) -> String {
    let mesh = scene_path.file_stem().unwrap().to_string_lossy().into_owned();
    format!("{mesh}-{tol:e}-{}", if warm { "warm" } else { "cold" })
}

fn solve(args: &Args, scene_path: &Path, tol: f64, warm: bool) -> Sample {
    let mesh = scene_path.file_stem().unwrap().to_string_lossy().into_owned();
    let cache = args.cache.join(format!("{}.json", sample_name(scene_path, tol, warm)));
    if let Ok(s) =
        std::fs::read_to_string(&cache).map_err(|_| ()).and_then(|t| serde_json::from_str(&t).map_err(|_| ()))
    {
        return s;
    }
    let scene = Scene::read(scene_path).expect("scene");
    let space = ParameterSpace::from_scene(&scene);
    let (p, q) = (parse_point(&args.point), parse_point(&args.neighbour));
    let mut store = MemoryStore::new(space).expect("store");
    let (points, strategy) =
        if warm { (vec![q, p.clone()], InitStrategy::Nearest) } else { (vec![p.clone()], InitStrategy::Cold) };
    let tolerance = Tolerance::new("tolerance", tol).expect("a tolerance");
    let options = StudyOptions { strategy, tolerance: Some(tolerance), max_iterations: Some(5000), scale: None };
    // P sorts after Q (checked below), so the ascending order solves Q first
    let result = run_study(
        &scene,
        &points,
        &options,
        &mut LexicographicAscending,
        &mut store,
        &mut PointSolver::default(),
        &mut |_, _, _| {},
    )
    .expect("study");
    let r = result.records.last().expect("a record");
    assert!(r.point.get("f1") == p.get("f1") && r.point.get("f2") == p.get("f2"), "P must be solved last");
    let body = scene.bodies[0].elements.as_deref().expect("the accuracy scenes are boxes");
    let sample = Sample {
        mesh,
        dofs_label: format!("{}x{}x{} per block", body[0], body.get(1).unwrap_or(&1), body.get(2).unwrap_or(&1)),
        tol,
        warm,
        converged: r.converged,
        iterations: r.iterations,
        static_iterations: r.static_iterations,
        wall_seconds: r.wall_seconds,
        qoi: r.qoi[&args.qoi],
    };
    eprintln!("{sample:?}");
    std::fs::write(&cache, serde_json::to_string(&sample).expect("json")).expect("cache");
    sample
}

fn main() {
    let args = Args::parse();
    assert!(!args.scenes.is_empty() && !args.tols.is_empty(), "give --scene and --tol");
    std::fs::create_dir_all(&args.cache).expect("cache dir");
    std::fs::create_dir_all(&args.out).expect("out dir");
    let mut tols = args.tols.clone();
    tols.sort_by(|a, b| b.total_cmp(a));
    let tightest = *tols.last().unwrap();
    // the reference first: it is the most expensive, and everything is measured against it
    let reference = solve(&args, args.scenes.last().unwrap(), tightest, false);
    let mut samples = Vec::new();
    for scene in &args.scenes {
        for &tol in &tols {
            for warm in [false, true] {
                if !args.skip.contains(&sample_name(scene, tol, warm)) {
                    samples.push(solve(&args, scene, tol, warm));
                }
            }
        }
    }
    let error = |s: &Sample| (s.qoi - reference.qoi).abs() / reference.qoi.abs();
    plot(&args, &samples, &error);
    write_markdown(&args, &samples, &reference, &error, &tols);
}

const COLOURS: [RGBColor; 4] =
    [RGBColor(31, 119, 180), RGBColor(214, 39, 40), RGBColor(44, 160, 44), RGBColor(148, 103, 189)];

fn plot(args: &Args, samples: &[Sample], error: &dyn Fn(&Sample) -> f64) {
    plotters::style::register_font("sans-serif", FontStyle::Normal, include_bytes!("../../assets/DejaVuSans.ttf"))
        .map_err(|_| ())
        .expect("bundled font");
    const SIZE: (u32, u32) = (1400, 600);
    let mut rgb = vec![0; SIZE.0 as usize * SIZE.1 as usize * 3];
    draw(&BitMapBackend::with_buffer(&mut rgb, SIZE).into_drawing_area(), args, samples, error);
    // glissade-plot's encoder rather than plotters' file output, which would build the `image` crate
    let bytes = glissade_plot::rgb_png(&rgb, SIZE).expect("encode png");
    let path = args.out.join("accuracy.png");
    std::fs::write(&path, bytes).unwrap_or_else(|e| panic!("writing {}: {e}", path.display()));
}

/// The two panels: error against wall time and against iterations.
fn draw(root: &DrawingArea<BitMapBackend<'_>, Shift>, args: &Args, samples: &[Sample], error: &dyn Fn(&Sample) -> f64) {
    root.fill(&WHITE).expect("draw");
    let panels = root.split_evenly((1, 2));
    // the reference itself (error 0) is left out of the plot
    let samples: Vec<&Sample> = samples.iter().filter(|s| error(s) > 0.0).collect();
    let floor = samples.iter().map(|s| error(s)).fold(f64::INFINITY, f64::min) / 2.0;
    let err = |s: &Sample| error(s);
    let meshes: Vec<String> = {
        let mut m: Vec<String> = Vec::new();
        for s in &samples {
            if !m.contains(&s.mesh) {
                m.push(s.mesh.clone());
            }
        }
        m
    };
    for (panel, (xlabel, xval)) in panels.iter().zip([
        (
            "wall time of the solve of P (s)",
            Box::new(|s: &Sample| s.wall_seconds.max(1e-3)) as Box<dyn Fn(&Sample) -> f64>,
        ),
        ("LATIN iterations of P (static + dynamic)", Box::new(|s: &Sample| s.iterations.max(1) as f64)),
    ]) {
        let xs: Vec<f64> = samples.iter().map(|s| xval(s)).collect();
        let (xmin, xmax) = (xs.iter().cloned().fold(f64::INFINITY, f64::min), xs.iter().cloned().fold(0.0, f64::max));
        let ymax = samples.iter().map(|s| err(s)).fold(0.0, f64::max).max(1e-2) * 2.0;
        let mut chart = ChartBuilder::on(panel)
            .caption(
                format!("{} error vs {}", args.qoi, xlabel.split(" (").next().unwrap_or(xlabel)),
                ("sans-serif", 22),
            )
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(70)
            .build_cartesian_2d((xmin / 1.5..xmax * 1.5).log_scale(), (floor..ymax).log_scale())
            .expect("chart");
        chart
            .configure_mesh()
            .x_desc(xlabel)
            .x_label_formatter(&|v| if *v >= 1.0 { format!("{v:.0}") } else { format!("{v}") })
            .y_label_formatter(&|v| format!("{v:.0e}"))
            .y_desc(format!("relative error of {}", args.qoi))
            .label_style(("sans-serif", 15))
            .axis_desc_style(("sans-serif", 16))
            .draw()
            .expect("mesh");
        // the 1 % line
        chart
            .draw_series(LineSeries::new([(xmin / 1.5, 1e-2), (xmax * 1.5, 1e-2)], BLACK.mix(0.4).stroke_width(1)))
            .expect("draw")
            .label("1 % error")
            .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], BLACK.mix(0.4)));
        for (mi, mesh) in meshes.iter().enumerate() {
            let colour = COLOURS[mi % COLOURS.len()];
            for warm in [false, true] {
                let mut pts: Vec<(f64, f64, f64)> = samples
                    .iter()
                    .filter(|s| &s.mesh == mesh && s.warm == warm)
                    .map(|s| (xval(s), err(s), s.tol))
                    .collect();
                pts.sort_by(|a, b| b.2.total_cmp(&a.2));
                let style = colour.stroke_width(2);
                let line: Vec<(f64, f64)> = pts.iter().map(|p| (p.0, p.1)).collect();
                let label = format!("{mesh}, {}", if warm { "warm start" } else { "cold" });
                if warm {
                    chart
                        .draw_series(DashedLineSeries::new(line.clone(), 8, 5, style))
                        .expect("draw")
                        .label(label)
                        .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], colour.stroke_width(2)));
                    chart
                        .draw_series(line.iter().map(|&(x, y)| TriangleMarker::new((x, y), 6, colour.filled())))
                        .expect("draw");
                } else {
                    chart
                        .draw_series(LineSeries::new(line.clone(), style))
                        .expect("draw")
                        .label(label)
                        .legend(move |(x, y)| Circle::new((x + 10, y), 4, colour.filled()));
                    chart
                        .draw_series(line.iter().map(|&(x, y)| Circle::new((x, y), 4, colour.filled())))
                        .expect("draw");
                }
                // tolerance labels beside the cold points
                if !warm {
                    chart
                        .draw_series(pts.iter().map(|p| {
                            Text::new(format!("{:.0e}", p.2), (p.0 * 1.08, p.1 * 1.25), ("sans-serif", 12).into_font())
                        }))
                        .expect("draw");
                }
            }
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.3))
            .label_font(("sans-serif", 14))
            .position(SeriesLabelPosition::LowerLeft)
            .draw()
            .expect("legend");
    }
    root.present().expect("draw");
}

/// Richardson extrapolation over the meshes at the tightest tolerance (cold): q(h) = q0 + C h^p with
/// h = 1 / (elements along x), p solved from the three finest meshes.
fn mesh_convergence(args: &Args, samples: &[Sample], tol: f64) -> String {
    let mut rows: Vec<(f64, f64, String)> = samples
        .iter()
        .filter(|s| !s.warm && s.tol == tol)
        .filter_map(|s| {
            let n: f64 = s.dofs_label.split('x').next()?.parse().ok()?;
            Some((1.0 / n, s.qoi, s.mesh.clone()))
        })
        .collect();
    rows.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut md = format!("## Mesh convergence\n\n{} at tolerance {tol:.0e}, cold:\n\n", args.qoi);
    for (h, q, mesh) in &rows {
        md += &format!("- `{mesh}` (h = 1/{:.0} of the block width): {q:.6e}\n", 1.0 / h);
    }
    if rows.len() >= 3 {
        let [(h1, q1, _), (h2, q2, _), (h3, q3, _)] =
            [&rows[rows.len() - 3], &rows[rows.len() - 2], &rows[rows.len() - 1]];
        let target = (q1 - q2) / (q2 - q3);
        let ratio = |p: f64| (h1.powf(p) - h2.powf(p)) / (h2.powf(p) - h3.powf(p));
        if target > 0.0 && target.is_finite() {
            // the ratio grows with p: bisection
            let (mut lo, mut hi) = (0.05, 8.0);
            if (ratio(lo) - target) * (ratio(hi) - target) < 0.0 {
                for _ in 0..100 {
                    let mid = 0.5 * (lo + hi);
                    if (ratio(mid) - target) * (ratio(lo) - target) > 0.0 { lo = mid } else { hi = mid }
                }
                let p = 0.5 * (lo + hi);
                let c = (q2 - q3) / (h2.powf(p) - h3.powf(p));
                let q0 = q3 - c * h3.powf(p);
                md += &format!(
                    "\nRichardson extrapolation from the three: observed order p = {p:.2}, extrapolated value {q0:.4e}; \
                     estimated discretisation error of each mesh: {}. So the errors of the table (against the finest \
                     mesh) leave out about {:.0} % of discretisation error of the finest mesh itself.\n\n",
                    rows.iter()
                        .map(|(h, _, m)| format!("`{m}` {:.1} %", 100.0 * (c * h.powf(p)).abs() / q0.abs()))
                        .collect::<Vec<_>>()
                        .join(", "),
                    100.0 * (c * h3.powf(p)).abs() / q0.abs()
                );
                return md;
            }
        }
        md += "\nThe three finest meshes do not converge monotonically: no extrapolation.\n\n";
    }
    md
}

fn write_markdown(args: &Args, samples: &[Sample], reference: &Sample, error: &dyn Fn(&Sample) -> f64, tols: &[f64]) {
    // accuracy.md's hand-written part (above the marker: `--accuracy`) is kept
    let path = args.out.join("accuracy.md");
    let kept = std::fs::read_to_string(&path).ok().and_then(|t| t.find(MARKER).map(|i| t[..i].to_string()));
    let mut md = kept.unwrap_or_default();
    md += MARKER;
    md += " (see the command below); do not edit by hand below this line -->\n\n";
    md += "# Speed against accuracy, chosen by hand\n\n";
    md += &format!(
        "The QoI `{}` (slip at point A, interface 1, at the final time) of the three-blocks scene at the design point \
         P = ({}), solved at three meshes and {} tolerances, against the reference: the finest mesh ({}) at the \
         tightest tolerance ({:.0e}), {} = {:.6e} m. Each point is solved twice: **cold** (zero initial fields, \
         including the factorisation) and **warm** (started from the converged solution of its neighbour \
         Q = ({}) at the same tolerance, reusing Q's factorisation — what every point after the first costs in a \
         study).\n\n",
        args.qoi,
        args.point,
        tols.len(),
        reference.mesh,
        reference.tol,
        args.qoi,
        reference.qoi,
        args.neighbour
    );
    if !args.note.is_empty() {
        md += &format!("{}\n\n", args.note);
    }
    md += "Iteration counts are exact; wall times are those of a shared 2-core machine, release build, one \
           process per run, and rows may come from different runs (each solve is cached).\n\n";
    md += "![error against wall time and iterations](accuracy.png)\n\n";
    md += &mesh_convergence(args, samples, reference.tol);
    md += "## How to choose\n\n";
    for target in [0.10, 0.05, 0.01, 0.001] {
        let best = |warm: bool| {
            samples
                .iter()
                .filter(|s| s.warm == warm && s.converged && error(s) <= target)
                .min_by(|a, b| a.wall_seconds.total_cmp(&b.wall_seconds))
        };
        let describe = |s: Option<&Sample>| match s {
            Some(s) => format!(
                "mesh `{}` ({}) at tolerance {:.0e}: error {:.2} %, {} iterations, {:.2} s",
                s.mesh,
                s.dofs_label,
                s.tol,
                100.0 * error(s),
                s.iterations,
                s.wall_seconds
            ),
            None => "none of the measured settings".into(),
        };
        md += &format!(
            "- **{} % error on {}**: cold, the cheapest is {}; in a study (warm start), {}.\n",
            100.0 * target,
            args.qoi,
            describe(best(false)),
            describe(best(true))
        );
    }
    // the ratio these runs used: the scene's (1 by default: a warm start stops at the tolerance)
    let ratio = Scene::read(&args.scenes[0]).map_or(1.0, |s| s.solver.warm_tolerance_ratio);
    let tighter = if ratio < 1.0 { ", so at one tolerance it is more accurate than a cold solve" } else { "" };
    md += &format!(
        "\nThese errors are against the finest mesh at the tightest tolerance, not against the exact solution: \
         the finest mesh's own discretisation error (mesh convergence, above) comes on top. A warm start \
         from a neighbour stops at `warm_tolerance_ratio` ({ratio} in these runs, docs/scenes.md) times the \
         tolerance{tighter}: read the warm rows for what a study gives (docs/performance.md, Warm starts at \
         equal accuracy).\n\n"
    );
    md += "## Measurements\n\n";
    md += &format!(
        "| mesh | tolerance | start | converged | iterations (static + dynamic) | wall s | {} | relative error |\n",
        args.qoi
    );
    md += "|---|---|---|---|---|---|---|---|\n";
    for s in samples {
        md += &format!(
            "| {} ({}) | {:.0e} | {} | {} | {} ({} + {}) | {:.3} | {:.6e} | {:.2e} |\n",
            s.mesh,
            s.dofs_label,
            s.tol,
            if s.warm { "warm" } else { "cold" },
            s.converged,
            s.iterations,
            s.static_iterations,
            s.iterations - s.static_iterations,
            s.wall_seconds,
            s.qoi,
            error(s)
        );
    }
    if !args.skip.is_empty() {
        md += &format!("\nNot measured (to keep the benchmark's cost bounded): {}.\n", args.skip.join(", "));
    }
    md += "\n## Command\n\n```sh\ncargo run --release -p glissade-solver --example accuracy --";
    for s in &args.scenes {
        md += &format!(" \\\n    --scene {}", s.display());
    }
    for t in tols {
        md += &format!(" --tol {t:e}");
    }
    for k in &args.skip {
        md += &format!(" \\\n    --skip {k}");
    }
    md += &format!(
        " \\\n    --qoi {} --point {} --neighbour {} --cache {} --out {}\n```\n",
        args.qoi,
        args.point,
        args.neighbour,
        args.cache.display(),
        args.out.display()
    );
    std::fs::write(path, md).expect("write accuracy.md");
}

/// Where the generated part of accuracy.md begins.
const MARKER: &str = "<!-- generated by: cargo run --release -p glissade-solver --example accuracy";
