//! The explicit reference (central differences, lumped mass, impulse contact with a wall:
//! `glissade_solver::explicit`) against the LATIN solve of the same scene, QoI by QoI.
//!
//! cargo run --release -p glissade-solver --example explicit_reference -- SCENE [SUBSTEPS] [NAME=VALUE]... [--explicit-only]

use anyhow::{Context, Result, bail};
use glissade_core::point::DesignPoint;
use glissade_core::scene::Scene;
use glissade_solver::explicit;
use glissade_solver::latin::{LatinSolver, SolveOptions};
use glissade_solver::model::Model;

fn run<const D: usize>(scene: &Scene, point: &DesignPoint, substeps: usize, explicit_only: bool) -> Result<()> {
    let values = scene.parameter_values(point)?;
    let m = Model::<D>::build(scene, &values)?;
    let t = std::time::Instant::now();
    let reference = explicit::solve(&m, substeps)?;
    let explicit_seconds = t.elapsed().as_secs_f64();
    if explicit_only {
        for q in &m.qois {
            if let Some(e) = reference.qoi(&m, &q.target) {
                println!("{:<20} explicit final {:.6e} ({explicit_seconds:.2} s)", q.name, e.last().unwrap_or(&0.0));
            }
        }
        return Ok(());
    }
    let t = std::time::Instant::now();
    let mut solver = LatinSolver::serial(&m)?;
    let r = solver.solve(None, &SolveOptions::default())?;
    println!(
        "dt {:.3e} s, {} steps; explicit: inner dt {:.3e} s (critical {:.3e}), {explicit_seconds:.2} s; \
         LATIN: {} iterations, converged {}, {:.2} s",
        m.dt,
        m.steps,
        reference.dt,
        reference.critical_dt,
        r.iterations(),
        r.converged(),
        t.elapsed().as_secs_f64()
    );
    for (q, series) in m.qois.iter().zip(&r.qoi) {
        let Some(e) = reference.qoi(&m, &q.target) else { continue };
        let (a, b) = (*series.values.last().unwrap_or(&0.0), *e.last().unwrap_or(&0.0));
        let scale = e.iter().fold(0.0f64, |s, x| s.max(x.abs()));
        let l2 = (series.values.iter().zip(&e).map(|(x, y)| (x - y).powi(2)).sum::<f64>()
            / e.iter().map(|y| y * y).sum::<f64>().max(f64::MIN_POSITIVE))
        .sqrt();
        if scale == 0.0 {
            println!("{:<20} LATIN final {a:.6e}  explicit 0 at every step", q.name);
            continue;
        }
        println!(
            "{:<20} LATIN final {a:.6e}  explicit {b:.6e}  difference {:+.3} % of the largest |explicit|, history L2 {:.3} %",
            q.name,
            100.0 * (a - b) / scale,
            100.0 * l2
        );
    }
    Ok(())
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(path) = args.first() else { bail!("usage: explicit_reference SCENE [SUBSTEPS] [NAME=VALUE]...") };
    let scene = Scene::read(std::path::Path::new(path)).with_context(|| format!("reading {path}"))?;
    let mut substeps = 10;
    let mut set = DesignPoint::new();
    let mut explicit_only = false;
    for a in &args[1..] {
        if a == "--explicit-only" {
            explicit_only = true;
            continue;
        }
        match a.split_once('=') {
            Some((k, v)) => set.insert(k, v.parse::<f64>().with_context(|| format!("value of {k}"))?)?,
            None => substeps = a.parse().with_context(|| format!("substeps '{a}'"))?,
        }
    }
    match scene.dimension {
        1 => run::<1>(&scene, &set, substeps, explicit_only),
        2 => run::<2>(&scene, &set, substeps, explicit_only),
        3 => run::<3>(&scene, &set, substeps, explicit_only),
        d => bail!("dimension {d}"),
    }
}
