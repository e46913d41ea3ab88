//! Adaptive points against a grid and a Latin hypercube at the same budget: how well does the
//! response surface fitted to each design predict the QoIs over the whole grid of a reference?
//!
//! Every design's points are solved cold at the reference's tolerance (so the comparison is of
//! the designs, not of solver errors); the 5 x 5 sub-grid takes its values from the reference.
//! For each design and QoI: the largest error of the surface's mean over the reference grid
//! (relative to the QoI's spread) and the share of reference points whose error is within 2
//! standard deviations (calibration).
//!
//! cargo run --release -p glissade-solver --example adaptive_check -- SCENE REFERENCE.json [BUDGET]

use glissade_core::point::DesignPoint;
use std::collections::BTreeMap;

use glissade_core::scene::Scene;
use glissade_core::study::adaptive::{AdaptiveDesign, QoiReadings};
use glissade_core::study::space::{GridAxis, ParameterSpace, design_points};
use glissade_core::study::surrogate::ResponseSurface;
use glissade_core::study::{PointRequest, SolvePoint, StudyResult};
use glissade_solver::run::PointSolver;

/// A design point and its QoIs.
type Solved = (DesignPoint, BTreeMap<String, f64>);

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (scene_path, reference_path) = (&args[0], &args[1]);
    let budget: usize = args.get(2).map_or(25, |b| b.parse().expect("BUDGET: a number"));
    let scene = Scene::read(std::path::Path::new(scene_path)).expect("a scene");
    let reference: StudyResult =
        serde_json::from_str(&std::fs::read_to_string(reference_path).expect("read the reference")).expect("a result");
    let space = ParameterSpace::from_scene(&scene);
    let names = vec!["f1".to_owned(), "f2".to_owned()];
    let truth = reference.by_index();
    let qois: Vec<String> = truth[0].qoi.keys().cloned().collect();
    let mut solver = PointSolver::default();
    let mut solve = |p: &DesignPoint| -> BTreeMap<String, f64> {
        let full = space.complete(p).expect("a point of the scene");
        let request = PointRequest {
            point: &full,
            tolerance: reference.tolerance,
            max_iterations: Some(20_000),
            scale: None,
            init_point: None,
        };
        SolvePoint::solve(&mut solver, &scene, &request, None).expect("a solve").qoi
    };

    let mut designs: Vec<(String, Vec<Solved>)> = Vec::new();
    // the 5 x 5 sub-grid of the reference (values 0, 3, 5, 7, 10 of 11 per parameter)
    let keep = [0usize, 3, 5, 7, 10];
    let grid: Vec<Solved> = truth
        .iter()
        .filter(|r| {
            names.iter().all(|n| {
                let k = ((r.point.get(n).unwrap() - 0.1) / 0.01).round() as usize;
                keep.contains(&k)
            })
        })
        .map(|r| (r.point.clone(), r.qoi.clone()))
        .collect();
    designs.push((format!("{} x {} grid", keep.len(), keep.len()), grid));
    // a Latin hypercube of the budget (the study grids' `lhs:N:SEED`)
    let axes: Vec<GridAxis> = names
        .iter()
        .map(|n| GridAxis::parse(&format!("{n}=lhs:{budget}:7:0.1:0.2"), &space).expect("an lhs axis"))
        .collect();
    let lhs = design_points(&axes, 100_000).expect("lhs points");
    eprintln!("solving the Latin hypercube ({} points)", lhs.len());
    designs.push(("Latin hypercube".into(), lhs.iter().map(|p| (p.clone(), solve(p))).collect()));
    // adaptive: each point where the surface is least sure
    let design =
        AdaptiveDesign { ranges: vec![("f1".into(), 0.1, 0.2), ("f2".into(), 0.1, 0.2)], budget, target: None };
    let readings = QoiReadings::of(&scene);
    let mut adaptive: Vec<Solved> = Vec::new();
    while adaptive.len() < budget {
        let chosen: Vec<(DesignPoint, Option<&BTreeMap<String, f64>>)> =
            adaptive.iter().map(|(p, q)| (p.clone(), Some(q))).collect();
        let Some(next) = design.next(&chosen, &design.surfaces(&space, &readings, &chosen)) else { break };
        eprintln!("adaptive point {}: {next}", adaptive.len() + 1);
        let q = solve(&next);
        adaptive.push((next, q));
    }
    designs.push(("adaptive".into(), adaptive));

    println!("| design ({budget} points) | QoI | largest error / spread | within 2 sd |");
    println!("|---|---|---|---|");
    for (name, points) in &designs {
        for q in &qois {
            let samples: Vec<(Vec<f64>, f64)> =
                points.iter().map(|(p, v)| (names.iter().map(|n| p.get(n).unwrap()).collect(), v[q])).collect();
            let surface = ResponseSurface::fit(&space, &names, &samples).expect("a surface");
            let values: Vec<f64> = truth.iter().map(|r| r.qoi[q]).collect();
            let spread =
                values.iter().cloned().fold(f64::MIN, f64::max) - values.iter().cloned().fold(f64::MAX, f64::min);
            let (mut worst, mut within) = (0.0f64, 0);
            for (r, v) in truth.iter().zip(&values) {
                let p = surface.predict(&r.point).expect("a prediction");
                let error = (p.mean - v).abs();
                worst = worst.max(error / spread);
                within += usize::from(error <= 2.0 * p.std);
            }
            println!(
                "| {name} | {q} | {worst:.3} | {:.0} % ({within}/{}) |",
                100.0 * within as f64 / truth.len() as f64,
                truth.len()
            );
        }
    }
}
