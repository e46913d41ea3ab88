//! Measures a coarse-in-time start: the design point solved with steps / R first, its interface
//! fields carried to the scene's steps (each fine step takes the coarse step it falls in), then
//! the fine solve warm from them, against the fine solve cold (docs/performance.md, "Refinement
//! and the extremes").
//!
//! cargo run --release -p glissade-solver --example coarse_start -- SCENE R [NAME=VALUE]...

use anyhow::{Context, Result, bail};
use glissade_core::field::{InterfaceSolution, SideField, StageSolution};
use glissade_core::point::DesignPoint;
use glissade_core::scene::Scene;
use glissade_solver::latin::{LatinSolver, SolveOptions};
use glissade_solver::model::Model;

fn refine_side(coarse: &SideField, ratio: usize, steps: usize) -> SideField {
    let per_step = coarse.force.len() / (steps / ratio);
    let take = |v: &[f64]| -> Vec<f64> {
        (0..steps).flat_map(|j| v[(j / ratio) * per_step..(j / ratio + 1) * per_step].iter().copied()).collect()
    };
    SideField { force: take(&coarse.force), velocity: take(&coarse.velocity) }
}

fn run<const D: usize>(scene: &Scene, point: &DesignPoint, ratio: usize) -> Result<()> {
    let values = scene.parameter_values(point)?;
    let fine = Model::<D>::build(scene, &values)?;
    if fine.steps % ratio != 0 {
        bail!("{} steps are not a multiple of {ratio}", fine.steps);
    }
    let mut coarse_scene = scene.clone();
    coarse_scene.time.steps /= ratio;
    let coarse = Model::<D>::build(&coarse_scene, &values)?;
    let t = std::time::Instant::now();
    let cold = LatinSolver::serial(&fine)?.solve(None, &SolveOptions::default())?;
    let cold_seconds = t.elapsed().as_secs_f64();
    let t = std::time::Instant::now();
    let c = LatinSolver::serial(&coarse)?.solve(None, &SolveOptions::default())?;
    let init = InterfaceSolution {
        static_stage: c.solution.static_stage.clone(),
        dynamic: StageSolution {
            interfaces: c
                .solution
                .dynamic
                .interfaces
                .iter()
                .map(|f| glissade_core::field::InterfaceField {
                    s: f.s.iter().map(|s| refine_side(s, ratio, fine.steps)).collect(),
                    hat: f.hat.iter().map(|s| refine_side(s, ratio, fine.steps)).collect(),
                })
                .collect(),
        },
    };
    let warm = LatinSolver::serial(&fine)?.solve(Some(&init), &SolveOptions::default())?;
    let warm_seconds = t.elapsed().as_secs_f64();
    let work = |dynamic: usize, steps: usize| dynamic as f64 * steps as f64 / fine.steps as f64;
    println!(
        "cold: {} dynamic iterations, converged {}, {cold_seconds:.2} s; coarse (steps / {ratio}) {} + fine warm {} \
         (converged {}): work {:.0} fine sweeps, {warm_seconds:.2} s",
        cold.dynamic.iterations,
        cold.converged(),
        c.dynamic.iterations,
        warm.dynamic.iterations,
        warm.converged(),
        work(c.dynamic.iterations, coarse.steps) + warm.dynamic.iterations as f64
    );
    for (a, b) in cold.qoi.iter().zip(&warm.qoi) {
        println!(
            "  {:<20} cold {:.6e}  coarse start {:.6e}",
            a.name,
            a.values.last().unwrap(),
            b.values.last().unwrap()
        );
    }
    Ok(())
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (Some(path), Some(ratio)) = (args.first(), args.get(1)) else {
        bail!("usage: coarse_start SCENE R [NAME=VALUE]...")
    };
    let ratio: usize = ratio.parse().context("R")?;
    let scene = Scene::read(std::path::Path::new(path)).with_context(|| format!("reading {path}"))?;
    let set: Vec<(String, f64)> = args[2..]
        .iter()
        .map(|a| {
            let (k, v) = a.split_once('=').context("NAME=VALUE")?;
            Ok((k.to_string(), v.parse::<f64>()?))
        })
        .collect::<Result<_>>()?;
    let set = DesignPoint::from_pairs(set)?;
    match scene.dimension {
        1 => run::<1>(&scene, &set, ratio),
        2 => run::<2>(&scene, &set, ratio),
        3 => run::<3>(&scene, &set, ratio),
        d => bail!("dimension {d}"),
    }
}
