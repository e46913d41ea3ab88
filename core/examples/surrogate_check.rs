//! How good are the response surface's means and error bars on real solves?
//!
//! Reads a study's results (`glissade-worker study --json` or `study_bench`'s reference file:
//! a `StudyResult`) over a grid, fits the Gaussian process of `core::study::surrogate` to a
//! subset of its points (a coarse sub-grid, and random subsets of the same size), and compares
//! its predictions with the held-out points: the largest error relative to the QoI's spread, and
//! the share of held-out points whose error is within 2 standard deviations (calibration).
//!
//! cargo run --release -p glissade-core --example surrogate_check -- SCENE RESULTS.json

use std::collections::BTreeSet;

use glissade_core::scene::Scene;
use glissade_core::study::StudyResult;
use glissade_core::study::space::ParameterSpace;
use glissade_core::study::surrogate::ResponseSurface;
use rand::SeedableRng;
use rand::seq::index::sample;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [scene, results] = &args[..] else {
        eprintln!("usage: surrogate_check SCENE RESULTS.json");
        std::process::exit(1);
    };
    let scene = Scene::parse(&std::fs::read_to_string(scene).expect("read the scene")).expect("a scene");
    let result: StudyResult =
        serde_json::from_str(&std::fs::read_to_string(results).expect("read the results")).expect("a study result");
    let space = ParameterSpace::from_scene(&scene);
    let names = vec!["f1".to_owned(), "f2".to_owned()];
    let records = result.by_index();
    let xs: Vec<Vec<f64>> =
        records.iter().map(|r| names.iter().map(|n| r.point.get(n).expect("swept")).collect()).collect();
    let qois: Vec<String> = records[0].qoi.keys().cloned().collect();
    // the coarse sub-grid: 5 of the 11 values per parameter
    let levels = |i: usize| -> BTreeSet<u64> {
        let mut v: Vec<u64> = xs.iter().map(|x| (x[i] * 1e9).round() as u64).collect();
        v.sort();
        v.dedup();
        [0, 3, 5, 7, 10].iter().filter_map(|&k| v.get(k).copied()).collect()
    };
    let (l1, l2) = (levels(0), levels(1));
    let grid: Vec<usize> = (0..xs.len())
        .filter(|&i| l1.contains(&((xs[i][0] * 1e9).round() as u64)) && l2.contains(&((xs[i][1] * 1e9).round() as u64)))
        .collect();
    println!("{} points, {} QoIs; training designs of {} points", xs.len(), qois.len(), grid.len());
    println!("| design | QoI | largest error / spread | held-out within 2 sd |");
    println!("|---|---|---|---|");
    let mut designs = vec![("5 x 5 sub-grid".to_owned(), grid.clone())];
    for seed in 1..=3u64 {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        designs.push((format!("random subset (seed {seed})"), sample(&mut rng, xs.len(), grid.len()).into_vec()));
    }
    for (name, train) in designs {
        for q in &qois {
            let values: Vec<f64> = records.iter().map(|r| r.qoi[q]).collect();
            let spread =
                values.iter().cloned().fold(f64::MIN, f64::max) - values.iter().cloned().fold(f64::MAX, f64::min);
            let samples: Vec<(Vec<f64>, f64)> = train.iter().map(|&i| (xs[i].clone(), values[i])).collect();
            let surface = ResponseSurface::fit(&space, &names, &samples).expect("fit");
            let (mut worst, mut within, mut held) = (0.0f64, 0, 0);
            for i in (0..xs.len()).filter(|i| !train.contains(i)) {
                let p = surface.predict(&records[i].point).expect("predict");
                let error = (p.mean - values[i]).abs();
                worst = worst.max(error / spread);
                within += usize::from(error <= 2.0 * p.std);
                held += 1;
            }
            println!("| {name} | {q} | {worst:.2e} | {:.0} % ({within}/{held}) |", 100.0 * within as f64 / held as f64);
        }
    }
}
