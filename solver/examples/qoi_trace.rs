//! Every QoI's true error iteration by iteration, for cold and warm starts: the data behind the
//! stopping test (docs/performance.md, "Tolerance = accuracy").
//!
//! Solves P at a tight tolerance (the reference), then P cold and P warm-started from Q with QoI
//! histories traced, and prints per iteration: eta and each QoI's relative L2 error over time
//! against the reference (relative to the reference history's norm), as CSV.
//!
//!   cargo run --release -p glissade-solver --example qoi_trace -- SCENE "f1=0.15,f2=0.1" "f1=0.125,f2=0.1" [K0_FACTOR]

use glissade_core::point::DesignPoint;
use glissade_core::scene::Scene;
use glissade_solver::latin::{LatinSolver, SolveOptions, SolveReport};
use glissade_solver::model::Model;

fn parse_point(s: &str) -> Vec<(String, f64)> {
    s.split(',')
        .filter(|p| !p.is_empty())
        .map(|p| {
            let (k, v) = p.split_once('=').expect("NAME=VALUE");
            (k.trim().to_string(), v.trim().parse().expect("a number"))
        })
        .collect()
}

fn run<const D: usize>(scene: &Scene, p: &[(String, f64)], q: Option<&[(String, f64)]>, k0: Option<f64>) {
    let build = |set: &[(String, f64)], tol: f64, max: usize| {
        let point = DesignPoint::from_pairs(set.iter().map(|(k, v)| (k.as_str(), *v))).expect("a design point");
        let values = scene.parameter_values(&point).expect("parameters");
        let mut m = Model::<D>::build(scene, &values).expect("model");
        m.settings.tolerance = tol;
        m.settings.max_iterations = max;
        if let Some(k) = k0 {
            for sub in m.interfaces.iter_mut().flat_map(|i| i.sides.iter_mut()) {
                sub.k_dynamic = sub.k_dynamic.scaled(k);
            }
        }
        m
    };
    let solve = |m: &Model<D>, init: Option<&glissade_core::field::InterfaceSolution>, trace: bool| -> SolveReport {
        let mut solver = LatinSolver::serial(m).expect("factorisation");
        solver.solve(init, &SolveOptions { trace_qois: trace, ..SolveOptions::default() }).expect("solve")
    };
    let mp = build(p, 1e-10, 20000);
    let reference = solve(&mp, None, false);
    eprintln!(
        "reference: {} dynamic iterations, eta {:.2e}",
        reference.dynamic.iterations, reference.dynamic.error_indicator
    );
    let names: Vec<&str> = reference.qoi.iter().map(|q| q.name.as_str()).collect();
    let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
    let mut runs = vec![("cold", build(p, 1e-7, 3000), None)];
    if let Some(q) = q {
        let mq = build(q, 1e-5, 3000);
        let neighbour = solve(&mq, None, false).solution;
        runs.push(("warm", build(p, 1e-7, 3000), Some(neighbour)));
    }
    println!("start,iteration,eta,{}", names.join(","));
    let mut dump = serde_json::Map::new();
    dump.insert("reference".into(), reference.qoi.iter().map(|q| q.values.clone()).collect::<Vec<_>>().into());
    for (label, m, init) in &runs {
        let r = solve(m, init.as_ref(), true);
        dump.insert(label.to_string(), serde_json::json!({"eta": r.dynamic.history, "qoi": r.dynamic.qoi_trace}));
        for (k, (eta, qois)) in r.dynamic.history.iter().zip(&r.dynamic.qoi_trace).enumerate() {
            let errors: Vec<String> = qois
                .iter()
                .zip(&reference.qoi)
                .map(|(v, refq)| {
                    let d: Vec<f64> = v.iter().zip(&refq.values).map(|(a, b)| a - b).collect();
                    format!("{:.3e}", norm(&d) / norm(&refq.values).max(1e-300))
                })
                .collect();
            println!("{label},{},{eta:.3e},{}", k + 1, errors.join(","));
        }
    }
    // The stopping test itself: each start at several tolerances, true error of every QoI.
    for (label, m, init) in &runs {
        for tol in [1e-3, 2e-4, 1e-5] {
            let mut m = m.clone();
            m.settings.tolerance = tol;
            m.settings.warm_tolerance_ratio = 1.0;
            let r = solve(&m, init.as_ref(), false);
            let errors: Vec<String> = r
                .qoi
                .iter()
                .zip(&reference.qoi)
                .map(|(q, refq)| {
                    let d: Vec<f64> = q.values.iter().zip(&refq.values).map(|(a, b)| a - b).collect();
                    format!("{} {:.2}", q.name, norm(&d) / norm(&refq.values).max(1e-300) / tol)
                })
                .collect();
            eprintln!(
                "{label} tol {tol:.0e}: {} dynamic it. (+{} static), estimate {:.2e}, error/tol: {}",
                r.dynamic.iterations,
                r.static_stage.as_ref().map_or(0, |s| s.iterations),
                r.dynamic.error_estimate,
                errors.join(", ")
            );
        }
    }
    if let Ok(path) = std::env::var("QOI_TRACE_JSON") {
        std::fs::write(path, serde_json::Value::Object(dump).to_string()).expect("write the trace");
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        eprintln!("usage: qoi_trace SCENE P [Q] [K0_FACTOR]");
        std::process::exit(1);
    }
    let scene = Scene::read(std::path::Path::new(&args[1])).expect("scene");
    let p = parse_point(&args[2]);
    let q = args.get(3).filter(|s| !s.is_empty()).map(|s| parse_point(s));
    let k0 = args.get(4).map(|s| s.parse().expect("a number"));
    match scene.dimension {
        1 => run::<1>(&scene, &p, q.as_deref(), k0),
        2 => run::<2>(&scene, &p, q.as_deref(), k0),
        _ => run::<3>(&scene, &p, q.as_deref(), k0),
    }
}
