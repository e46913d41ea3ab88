//! The load-balance term of the scaling model (docs/performance.md, "A model of the time per
//! iteration"): each substructure's cost in an iteration, measured, and what it makes of the
//! ranks' loads under the distribution the solver uses (contiguous blocks balanced by dofs,
//! `latin::distribution`) and under contiguous blocks balanced by the measured cost instead.
//!
//! cargo run --release -p glissade-solver --example substructure_cost -- scenes/three-blocks-paper.toml [SOLVES]
//!
//! A substructure's cost is the time of one solve with its factorised dynamic operator (the two
//! solves a step of the linear stage and the post-processing's are such solves), the median of
//! SOLVES (default 20), the fastest of them. The imbalance is the largest rank's load over the mean: at each of the 50
//! synchronisations of an iteration every rank waits for the most loaded one.

use std::time::Instant;

use glissade_core::point::DesignPoint;
use glissade_core::scene::Scene;
use glissade_solver::latin::distribution::{Distribution, contiguous_blocks as blocks};
use glissade_solver::latin::linear_stage::{Stage, SubstructureOperators};
use glissade_solver::model::Model;

/// Contiguous blocks with the least largest load (bisection on that load, greedy filling).
fn best_blocks(weights: &[f64], ranks: usize) -> Vec<usize> {
    let fill = |cap: f64| -> Option<Vec<usize>> {
        let (mut rank, mut load, mut out) = (0, 0.0, Vec::with_capacity(weights.len()));
        for (s, &w) in weights.iter().enumerate() {
            // a new block when this one is full, or when the rest need a rank each
            if (load + w > cap || weights.len() - s <= ranks - 1 - rank) && load > 0.0 && rank + 1 < ranks {
                rank += 1;
                load = 0.0;
            }
            load += w;
            if load > cap {
                return None;
            }
            out.push(rank);
        }
        Some(out)
    };
    let (mut lo, mut hi) = (weights.iter().cloned().fold(0.0, f64::max), weights.iter().sum::<f64>());
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if fill(mid).is_some() { hi = mid } else { lo = mid }
    }
    fill(hi).expect("the whole load fits one block")
}

/// Each substructure, heaviest first, to the least loaded rank (not contiguous: neighbours may
/// land apart, more exchanges).
fn greedy(weights: &[f64], ranks: usize) -> Vec<usize> {
    let mut order: Vec<usize> = (0..weights.len()).collect();
    order.sort_by(|&a, &b| weights[b].total_cmp(&weights[a]));
    let (mut load, mut rank) = (vec![0.0f64; ranks], vec![0; weights.len()]);
    for s in order {
        let r = (0..ranks).min_by(|&a, &b| load[a].total_cmp(&load[b])).expect("ranks > 0");
        load[r] += weights[s];
        rank[s] = r;
    }
    rank
}

fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let cov: f64 = a.iter().zip(b).map(|(x, y)| (x - ma) * (y - mb)).sum();
    let va: f64 = a.iter().map(|x| (x - ma).powi(2)).sum();
    let vb: f64 = b.iter().map(|y| (y - mb).powi(2)).sum();
    cov / (va * vb).sqrt()
}

/// Largest rank load over the mean.
fn imbalance(cost: &[f64], rank: &[usize], ranks: usize) -> f64 {
    let mut load = vec![0.0; ranks];
    for (c, &r) in cost.iter().zip(rank) {
        load[r] += c;
    }
    let mean = load.iter().sum::<f64>() / ranks as f64;
    load.iter().cloned().fold(0.0, f64::max) / mean
}

fn run<const D: usize>(scene: &Scene, solves: usize) {
    let values = scene.parameter_values(&DesignPoint::new()).expect("parameters");
    let model = Model::<D>::build(scene, &values).expect("model");
    let n = model.substructures.len();
    let mut cost = Vec::with_capacity(n);
    let mut factor = Vec::with_capacity(n);
    for s in 0..n {
        let mut ops = SubstructureOperators::new(&model, s, false).expect("factorisation");
        factor.push(ops.dynamic_factor_len() as f64);
        let dofs = model.substructures[s].n_dofs();
        let rhs: Vec<f64> = (0..dofs).map(|i| ((i * 7919) % 101) as f64 - 50.0).collect();
        let mut times: Vec<f64> = (0..solves)
            .map(|_| {
                let t = Instant::now();
                std::hint::black_box(ops.solve_homogeneous(Stage::Dynamic, &rhs));
                t.elapsed().as_secs_f64()
            })
            .collect();
        times.sort_by(f64::total_cmp);
        // the fastest: the machine's noise only ever adds
        cost.push(times[0]);
    }
    let dofs: Vec<f64> = model.substructures.iter().map(|s| s.n_dofs() as f64).collect();
    let total: f64 = cost.iter().sum();
    let (lo, hi) = cost.iter().fold((f64::MAX, 0.0f64), |(a, b), &c| (a.min(c), b.max(c)));
    println!(
        "{n} substructures, {} dofs; a solve of each: {:.2} to {:.2} ms, {:.1} ms in all (one rank's step)",
        dofs.iter().sum::<f64>(),
        1e3 * lo,
        1e3 * hi,
        1e3 * total
    );
    println!("each substructure in order: time of a solve (us) / values in its factor (thousands):");
    let per: Vec<String> = cost.iter().zip(&factor).map(|(c, f)| format!("{:.0}/{:.0}", 1e6 * c, f / 1e3)).collect();
    println!("  {}", per.join(" "));
    let r = correlation(&cost, &factor);
    println!(
        "correlation of the solve's time with the factor's size {r:.3}, with the dofs {:.3}",
        correlation(&cost, &dofs)
    );
    println!(
        "| ranks | imbalance: blocks by dofs (the solver's) | by cost, midpoint rule | by cost, best blocks | by cost, any ranks (greedy) | by factor size, best blocks | bound: largest substructure / mean |"
    );
    println!("|---|---|---|---|---|---|---|");
    for ranks in [2, 4, 8, 16, 24, 32, 48] {
        if ranks > n {
            break;
        }
        let by_dofs = Distribution::new(&model, 0, ranks).expect("distribution").substructure_rank;
        println!(
            "| {ranks} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} |",
            imbalance(&cost, &by_dofs, ranks),
            imbalance(&cost, &blocks(&cost, ranks), ranks),
            imbalance(&cost, &best_blocks(&cost, ranks), ranks),
            imbalance(&cost, &greedy(&cost, ranks), ranks),
            imbalance(&cost, &best_blocks(&factor, ranks), ranks),
            (hi / (total / ranks as f64)).max(1.0)
        );
    }
}

fn main() {
    let mut args = std::env::args().skip(1);
    let path = args.next().unwrap_or_else(|| "scenes/three-blocks-paper.toml".into());
    let solves: usize = args.next().map_or(20, |s| s.parse().expect("SOLVES is a number"));
    let scene = Scene::read(std::path::Path::new(&path)).expect("scene");
    match scene.dimension {
        1 => run::<1>(&scene, solves),
        2 => run::<2>(&scene, solves),
        _ => run::<3>(&scene, solves),
    }
}
