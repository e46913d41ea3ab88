//! How a warm start's QoI and eta evolve iteration by iteration, against a tight reference: the
//! evidence behind `warm_tolerance_ratio` (docs/performance.md, "Warm starts at equal accuracy").
//! Solves the neighbour Q cold, the point P at eta <= 1e-7 (reference) and at 2e-4 cold, then P
//! warm-started from Q stopped after 2, 4, 6, ... iterations (each a fresh solve).
//!
//!   cargo run --release -p glissade-solver --example warm_trace -- SCENE Q_F1 Q_F2 P_F1 P_F2 QOI [MAX]
//!   cargo run --release -p glissade-solver --example warm_trace -- scenes/three-blocks-tiny.toml 0.125 0.1 0.15 0.1 slip_A

use glissade_core::point::DesignPoint;
use glissade_core::scene::{Scene, Tolerance};
use glissade_solver::run::{SolveRequest, solve_scene};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 7 {
        eprintln!("usage: warm_trace SCENE Q_F1 Q_F2 P_F1 P_F2 QOI [MAX_ITERATIONS]");
        std::process::exit(1);
    }
    let scene = Scene::read(std::path::Path::new(&args[1])).expect("scene");
    let number = |i: usize| -> f64 { args[i].parse().expect("a number") };
    let (q, p, qoi) = ((number(2), number(3)), (number(4), number(5)), args[6].as_str());
    let max: usize = args.get(7).map_or(160, |s| s.parse().expect("an iteration count"));
    let request = |(f1, f2): (f64, f64), tol: f64, max_iterations: Option<usize>| SolveRequest {
        point: DesignPoint::from_pairs([("f1", f1), ("f2", f2)]).expect("a design point"),
        tolerance: Some(Tolerance::new("tolerance", tol).expect("a tolerance")),
        max_iterations,
        ..SolveRequest::default()
    };
    let value = |o: &glissade_solver::run::SolveOutcome| o.summary.qoi[qoi].final_value;
    let neighbour = solve_scene(&scene, &request(q, 2e-4, None), None).expect("neighbour");
    let reference = value(&solve_scene(&scene, &request(p, 1e-7, None), None).expect("reference"));
    let cold = solve_scene(&scene, &request(p, 2e-4, None), None).expect("cold");
    let error = |v: f64| (v - reference).abs() / reference.abs();
    println!(
        "{qoi} at {p:?}: reference {reference:.6e}; cold at 2e-4 {:.6e} (error {:.2e}, {} iterations)",
        value(&cold),
        error(value(&cold)),
        cold.summary.iterations
    );
    println!("warm from {q:?}, stopped after k dynamic iterations:\n    k  eta        {qoi:<13}  rel. error");
    for k in (2..=max).step_by(2) {
        let Ok(o) = solve_scene(&scene, &request(p, 1e-12, Some(k)), Some(&neighbour.solution)) else { continue };
        println!(
            "{:5}  {:.3e}  {:.6e}  {:.2e}",
            o.summary.history.len(),
            o.summary.error_indicator,
            value(&o),
            error(value(&o))
        );
    }
}
