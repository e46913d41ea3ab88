//! A design's response surface against a dense reference, offline: why is it wrong where it is?
//!
//! Fits every QoI's surface exactly as `glissade surface --at` does (`QoiSurface::of_scene`:
//! norms from their components where the scene reports them, never below zero) to the points of
//! DESIGN.json, and judges it at every point of REFERENCE.json off the design (both `StudyResult`s:
//! `glissade-worker study --out`'s results.json), with the surface audit's measure
//! (core::study::holdout: errors relative to the QoI's spread over the reference). Per QoI it
//! prints the largest and mean error, the share within 2 sd, where the largest error is, the
//! fitted lengths, and the design's own estimate of its mean error (leave-one-out, as a target
//! study judges itself) beside the truth's.
//!
//! Two designs at the same points solved at two tolerances tell the points' noise from the
//! surface's shape: docs/surrogate.md, "Why 121 points left 4-5 %".
//!
//! cargo run --release -p glissade-core --example surface_design_check -- SCENE DESIGN.json REFERENCE.json

use std::collections::BTreeMap;

use glissade_core::point::DesignPoint;
use glissade_core::scene::Scene;
use glissade_core::study::StudyResult;
use glissade_core::study::holdout::{spread, surface_errors};
use glissade_core::study::surrogate::{Prediction, QoiSurface, Reading};

fn read(path: &str) -> StudyResult {
    serde_json::from_str(&std::fs::read_to_string(path).expect("read a results.json")).expect("a study result")
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [scene, design, reference] = &args[..] else {
        eprintln!("usage: surface_design_check SCENE DESIGN.json REFERENCE.json");
        std::process::exit(1);
    };
    let scene = Scene::parse(&std::fs::read_to_string(scene).expect("read the scene")).expect("a scene");
    let (design, reference) = (read(design), read(reference));
    // the swept parameters: those that vary over the design
    let names: Vec<String> = design
        .parameters
        .iter()
        .filter(|n| design.records.iter().any(|r| r.point.get(n) != design.records[0].point.get(n)))
        .cloned()
        .collect();
    let coordinates = |p: &DesignPoint| -> Vec<f64> { names.iter().map(|n| p.get(n).expect("swept")).collect() };
    let rows: Vec<(Vec<f64>, &BTreeMap<String, f64>)> =
        design.records.iter().filter(|r| r.converged).map(|r| (coordinates(&r.point), &r.qoi)).collect();
    // each point's tolerance, whose error the surface carries as the service's does
    let tolerances: Vec<f64> = design.records.iter().filter(|r| r.converged).map(|r| r.tolerance).collect();
    let off: Vec<_> = reference
        .records
        .iter()
        .filter(|r| r.converged)
        .filter(|r| {
            let x = coordinates(&r.point);
            !rows.iter().any(|(d, _)| d.iter().zip(&x).all(|(a, b)| (a - b).abs() <= 1e-9 * a.abs().max(1.0)))
        })
        .collect();
    println!(
        "{} design points (tol {:e}), judged at {} reference points off them (tol {:e}); errors / the QoI's spread over the design and the reference",
        rows.len(),
        design.tolerance,
        off.len(),
        reference.tolerance
    );
    println!(
        "| QoI | largest | mean | within 2 sd | largest at | leave-one-out mean (/ truth's) | its largest | lengths |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    // a norm's components are judged through it
    let components: Vec<&str> = scene.qoi.iter().flat_map(|d| scene.components_of(&d.name)).collect();
    let qois: Vec<String> =
        scene.qoi.iter().map(|d| d.name.clone()).filter(|q| !components.contains(&q.as_str())).collect();
    for q in &qois {
        let surface = QoiSurface::of_scene(&scene, &names, &rows, &tolerances, q).expect("a surface");
        // the QoI's spread over the box: the design's values and the reference's (the audit's)
        let scale = spread(
            rows.iter()
                .map(|(_, v)| v[q.as_str()])
                .chain(reference.records.iter().filter_map(|r| r.qoi.get(q).copied())),
        );
        let pairs: Vec<(Prediction, f64)> =
            off.iter().map(|r| (surface.predict(&r.point).expect("a prediction"), r.qoi[q])).collect();
        let truth = surface_errors(&pairs, scale);
        let worst = pairs
            .iter()
            .zip(&off)
            .max_by(|a, b| (a.0.0.mean - a.0.1).abs().total_cmp(&(b.0.0.mean - b.0.1).abs()))
            .map(|(_, r)| coordinates(&r.point))
            .expect("a reference point");
        // the design's own estimate, on its own spread (as a target study's)
        let own: Vec<f64> = rows.iter().map(|(_, v)| v[q.as_str()]).collect();
        let loo: Vec<(Prediction, f64)> = surface.leave_one_out().into_iter().zip(own.iter().copied()).collect();
        let cv = surface_errors(&loo, spread(own.iter().copied()));
        let lengths = match surface.reading() {
            Reading::Direct(s) => format!("{:.2?}", s.lengths()),
            Reading::Components(parts) => {
                parts.iter().map(|s| format!("{:.2?}", s.lengths())).collect::<Vec<_>>().join(" ")
            }
        };
        print_leads(&scene, &names, &rows, q, &off, scale);
        print_audits(&pairs, scale, truth.mean);
        println!(
            "| {q} | {:.4} | {:.5} | {:.0} % | {:.4?} | {:.5} ({:.2}) | {:.4} | {lengths} |",
            truth.largest,
            truth.mean,
            100.0 * truth.within_2sd,
            worst,
            cv.mean,
            cv.mean / truth.mean,
            cv.largest
        );
    }
}

/// Leads measured beside the product's surface (one line each: largest, mean, within 2 sd).
fn print_leads(
    scene: &Scene,
    names: &[String],
    rows: &[(Vec<f64>, &BTreeMap<String, f64>)],
    q: &str,
    off: &[&glissade_core::study::PointRecord],
    scale: f64,
) {
    let space = glissade_core::study::space::ParameterSpace::from_scene(scene);
    let judge = |lead: &str, predict: &dyn Fn(&DesignPoint) -> Prediction| {
        let pairs: Vec<(Prediction, f64)> = off.iter().map(|r| (predict(&r.point), r.qoi[q])).collect();
        let e = surface_errors(&pairs, scale);
        println!("|   {q} {lead} | {:.4} | {:.5} | {:.0} % |", e.largest, e.mean, 100.0 * e.within_2sd);
    };
    // the surface before 2026-11-26's: the points taken as exact (their error not carried)
    let exact = QoiSurface::of_scene(scene, names, rows, &[], q).expect("a surface");
    judge("points taken as exact", &|p| exact.predict(p).expect("a prediction"));
    if scene.qoi_is_norm(q) {
        let samples: Vec<(Vec<f64>, f64)> = rows.iter().map(|(x, v)| (x.clone(), v[q].max(0.0).sqrt())).collect();
        let root = glissade_core::study::surrogate::ResponseSurface::fit(&space, names, &samples).expect("a surface");
        judge("sqrt", &|p| {
            let at = root.predict(p).expect("a prediction");
            let m = at.mean.max(0.0);
            Prediction { mean: m * m, std: ((2.0 * m * at.std).powi(2) + 2.0 * at.std.powi(4)).sqrt() }
        });
    }
}

/// What a surface audit of n held-out points (drawn from the reference's) estimates of the mean
/// error, against the truth (the whole reference's): the share of draws within a factor 2, for
/// the held-out points' own mean error and for the error bars' mean scaled by the held-out
/// points' calibration (sqrt(2 / pi) x rms(error / sd) x the mean sd over the reference).
fn print_audits(pairs: &[(Prediction, f64)], scale: f64, truth: f64) {
    use rand::SeedableRng;
    use rand::seq::index::sample;
    const DRAWS: u64 = 400;
    let mean_sd = pairs.iter().map(|(p, _)| p.std).sum::<f64>() / pairs.len() as f64;
    for n in [5, 7, 10, 15, 30] {
        let (mut plain, mut scaled) = (Vec::new(), Vec::new());
        for seed in 0..DRAWS {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            let drawn: Vec<(Prediction, f64)> = sample(&mut rng, pairs.len(), n).iter().map(|k| pairs[k]).collect();
            plain.push(surface_errors(&drawn, scale).mean / truth);
            let c =
                (drawn.iter().map(|(p, v)| ((p.mean - v) / p.std.max(1e-300)).powi(2)).sum::<f64>() / n as f64).sqrt();
            scaled.push((2.0 / std::f64::consts::PI).sqrt() * c * mean_sd / scale / truth);
        }
        let summary = |r: &mut Vec<f64>| {
            r.sort_by(f64::total_cmp);
            let within = r.iter().filter(|x| (0.5..=2.0).contains(*x)).count();
            format!("median {:.2}, {} % within x2", r[r.len() / 2], within * 100 / r.len())
        };
        println!(
            "|   audit of {n}: held-out mean {}; error bars scaled {} |",
            summary(&mut plain),
            summary(&mut scaled)
        );
    }
}
