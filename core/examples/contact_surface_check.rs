//! Surfaces that know contact: leads for a slip norm's response surface (zero where the interface
//! sticks, a kink at the stick / slip edge), measured against a dense reference grid.
//!
//! Reads a study's results over a grid of two swept parameters (`glissade-worker study --json` or
//! `--out`'s results.json: a `StudyResult`), fits each lead to designs drawn from it (sub-grids and
//! random subsets), and judges each on every reference point outside the design, with the
//! measure of the coordinator's surface audit (core::study::holdout: largest and mean error
//! relative to the QoI's spread over the reference, share within 2 standard deviations).
//!
//! Leads (for the norms; other QoIs get the plain surface):
//! - `gp`: the surface of `glissade surface` (Gaussian process, mean clamped at 0);
//! - `classify`: stick / slip classified first (the Gaussian process of +1 slip / -1 stick, its
//!   sign), the slip fitted to the slipping points alone; exactly 0 where classified stick; the
//!   standard deviation that of the mixture (slip with the classifier's probability);
//! - `latent`: one smooth latent fitted across the edge, the surface its positive part: the slip
//!   where it slips, and where it sticks minus a distance to the slipping points (times the
//!   slip's typical slope away from the sticking ones);
//! - `components`: where the results hold the norm's signed components (QoIs `{name}_x`, `_y`,
//!   `_z` with `component`), the norm of their surfaces.
//!
//! cargo run --release -p glissade-core --example contact_surface_check -- SCENE RESULTS.json P1 P2

use glissade_core::point::DesignPoint;
use glissade_core::scene::Scene;
use glissade_core::study::StudyResult;
use glissade_core::study::holdout::{SurfaceErrors, spread, surface_errors};
use glissade_core::study::space::{Axis, ParameterSpace};
use glissade_core::study::surrogate::{Prediction, ResponseSurface};
use rand::SeedableRng;
use rand::seq::index::sample;

/// A value below this fraction of the largest |value| of the design is a stick (round-off: the
/// reference's sticks are 1e-35 to 1e-21 against slips of 1e-6 to 1e-4).
const STICK: f64 = 1e-9;

type Sample = (Vec<f64>, f64);
/// A lead's surface: the prediction at a point (the swept parameters' values).
type Predictor = Box<dyn Fn(&[f64]) -> Prediction>;

/// Held-out points of a surface audit of a 121-point study (5 %, at least 5: 7).
const AUDIT: usize = 7;
/// Draws of them, to see the audit's spread.
const DRAWS: u64 = 40;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [scene, results, p1, p2] = &args[..] else {
        eprintln!("usage: contact_surface_check SCENE RESULTS.json PARAMETER1 PARAMETER2");
        std::process::exit(1);
    };
    let scene = Scene::parse(&std::fs::read_to_string(scene).expect("read the scene")).expect("a scene");
    let result: StudyResult =
        serde_json::from_str(&std::fs::read_to_string(results).expect("read the results")).expect("a study result");
    let space = ParameterSpace::from_scene(&scene);
    let names = vec![p1.clone(), p2.clone()];
    let records = result.by_index();
    let xs: Vec<Vec<f64>> =
        records.iter().map(|r| names.iter().map(|n| r.point.get(n).expect("swept")).collect()).collect();
    let qois: Vec<String> = records[0].qoi.keys().cloned().collect();
    // the grid's levels per parameter
    let levels = |d: usize| -> Vec<f64> {
        let mut v: Vec<f64> = xs.iter().map(|x| x[d]).collect();
        v.sort_by(f64::total_cmp);
        v.dedup();
        v
    };
    let (l1, l2) = (levels(0), levels(1));
    let sub_grid = |k: usize| -> Vec<usize> {
        // k levels evenly among the grid's, both ends included
        let keep = |l: &[f64], x: f64| {
            let i = l.iter().position(|&v| v == x).expect("a level");
            (0..k).any(|j| ((j * (l.len() - 1)) as f64 / (k - 1) as f64).round() as usize == i)
        };
        (0..xs.len()).filter(|&i| keep(&l1, xs[i][0]) && keep(&l2, xs[i][1])).collect()
    };
    let mut designs: Vec<(String, Vec<usize>)> = Vec::new();
    for k in [11, 6] {
        let g = sub_grid(k);
        designs.push((format!("{k} x {k} sub-grid ({} points)", g.len()), g));
    }
    for seed in 1..=2u64 {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        designs.push((format!("random 50, seed {seed}"), sample(&mut rng, xs.len(), 50).into_vec()));
    }
    println!(
        "{} reference points; errors / the QoI's spread over the reference, at the points outside each design",
        xs.len()
    );
    println!(
        "| design | QoI | lead | largest | mean | within 2 sd | audit of {AUDIT}: mean / true mean, median [min, max] of {DRAWS} draws, share within x2 |"
    );
    println!("|---|---|---|---|---|---|---|");
    for (design, train) in &designs {
        let test: Vec<usize> = (0..xs.len()).filter(|i| !train.contains(i)).collect();
        for q in &qois {
            // a norm's signed components (`{q}_x`, ...: QoIs with `component`) serve its leads
            let component_of = |c: &String| ["_x", "_y", "_z"].iter().any(|s| c.strip_suffix(s) == Some(q.as_str()));
            let components: Vec<&String> = qois.iter().filter(|c| component_of(c)).collect();
            if qois.iter().any(|n| ["_x", "_y", "_z"].iter().any(|s| q.strip_suffix(s) == Some(n.as_str()))) {
                continue;
            }
            let values: Vec<f64> = records.iter().map(|r| r.qoi[q]).collect();
            let scale = spread(values.iter().copied());
            let samples: Vec<Sample> = train.iter().map(|&i| (xs[i].clone(), values[i])).collect();
            let mut leads: Vec<(&str, Predictor)> = if scene.qoi_is_norm(q) {
                vec![
                    ("gp", plain(&space, &names, &samples, true)),
                    ("classify", classify(&space, &names, &samples)),
                    ("latent", latent(&space, &names, &samples)),
                ]
            } else {
                vec![("gp", plain(&space, &names, &samples, false))]
            };
            if !components.is_empty() {
                let each: Vec<Vec<Sample>> = components
                    .iter()
                    .map(|c| train.iter().map(|&i| (xs[i].clone(), records[i].qoi[*c])).collect())
                    .collect();
                leads.push(("components", norm_of_components(&space, &names, &each)));
            }
            for (lead, predict) in leads {
                let pairs: Vec<(Prediction, f64)> = test.iter().map(|&i| (predict(&xs[i]), values[i])).collect();
                let SurfaceErrors { largest, mean, within_2sd, .. } = surface_errors(&pairs, scale);
                // what a surface audit of `AUDIT` held-out points would have said of the mean
                // error: its ratio to the whole reference's, over draws of that many test points
                let mut ratios: Vec<f64> = (0..DRAWS)
                    .map(|seed| {
                        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1000 + seed);
                        let drawn: Vec<(Prediction, f64)> =
                            sample(&mut rng, pairs.len(), AUDIT).iter().map(|k| pairs[k]).collect();
                        surface_errors(&drawn, scale).mean / mean.max(f64::MIN_POSITIVE)
                    })
                    .collect();
                ratios.sort_by(f64::total_cmp);
                let within2 = ratios.iter().filter(|r| (0.5..=2.0).contains(*r)).count();
                println!(
                    "| {design} | {q} | {lead} | {largest:.3} | {mean:.4} | {:.0} % | {:.2} [{:.2}, {:.2}], {} % |",
                    within_2sd * 100.0,
                    ratios[DRAWS as usize / 2],
                    ratios[0],
                    ratios[DRAWS as usize - 1],
                    within2 * 100 / DRAWS as usize
                );
            }
        }
    }
}

fn at(names: &[String], x: &[f64]) -> DesignPoint {
    DesignPoint::from_pairs(names.iter().cloned().zip(x.iter().copied())).expect("the swept names at finite values")
}

fn fit(space: &ParameterSpace, names: &[String], samples: &[Sample]) -> ResponseSurface {
    ResponseSurface::fit(space, names, samples).expect("a surface")
}

fn plain(space: &ParameterSpace, names: &[String], samples: &[Sample], norm: bool) -> Predictor {
    let s = fit(space, names, samples);
    let s = if norm { s.non_negative() } else { s };
    let names = names.to_vec();
    Box::new(move |x| s.predict(&at(&names, x)).expect("a prediction"))
}

fn sticks(samples: &[Sample]) -> Vec<bool> {
    let largest = samples.iter().fold(0.0f64, |m, (_, v)| m.max(v.abs()));
    samples.iter().map(|(_, v)| v.abs() <= STICK * largest).collect()
}

/// The standard normal distribution function (Abramowitz & Stegun 7.1.26, error below 1.5e-7).
fn phi(z: f64) -> f64 {
    let x = z.abs() / std::f64::consts::SQRT_2;
    let t = 1.0 / (1.0 + 0.327_591_1 * x);
    let poly =
        t * (0.254_829_592 + t * (-0.284_496_736 + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
    let erf = 1.0 - poly * (-x * x).exp();
    if z >= 0.0 { 0.5 * (1.0 + erf) } else { 0.5 * (1.0 - erf) }
}

fn classify(space: &ParameterSpace, names: &[String], samples: &[Sample]) -> Predictor {
    let stick = sticks(samples);
    let labels: Vec<Sample> =
        samples.iter().zip(&stick).map(|((x, _), s)| (x.clone(), if *s { -1.0 } else { 1.0 })).collect();
    let slipping: Vec<Sample> = samples.iter().zip(&stick).filter(|(_, s)| !**s).map(|(p, _)| p.clone()).collect();
    if slipping.len() < 2 || slipping.len() == samples.len() {
        return plain(space, names, samples, true);
    }
    let classifier = fit(space, names, &labels);
    let slip = fit(space, names, &slipping).non_negative();
    let names = names.to_vec();
    Box::new(move |x| {
        let p = at(&names, x);
        let c = classifier.predict(&p).expect("a prediction");
        let s = slip.predict(&p).expect("a prediction");
        let chance = phi(c.mean / c.std.max(1e-12));
        // the root mean square deviation from the mean told, under the mixture
        if c.mean < 0.0 {
            Prediction { mean: 0.0, std: (chance * (s.std.powi(2) + s.mean.powi(2))).sqrt() }
        } else {
            Prediction { mean: s.mean, std: (chance * s.std.powi(2) + (1.0 - chance) * s.mean.powi(2)).sqrt() }
        }
    })
}

/// The norm of the signed components' surfaces (each smooth where the norm has a V: a component
/// through zero); its standard deviation that of the vector's error, sqrt(sum of the variances),
/// which bounds the norm's (|norm(a) - norm(b)| <= norm(a - b)).
fn norm_of_components(space: &ParameterSpace, names: &[String], each: &[Vec<Sample>]) -> Predictor {
    let surfaces: Vec<Predictor> = each.iter().map(|samples| plain(space, names, samples, false)).collect();
    Box::new(move |x| {
        let parts: Vec<Prediction> = surfaces.iter().map(|s| s(x)).collect();
        Prediction {
            mean: parts.iter().map(|p| p.mean * p.mean).sum::<f64>().sqrt(),
            std: parts.iter().map(|p| p.std * p.std).sum::<f64>().sqrt(),
        }
    })
}

fn latent(space: &ParameterSpace, names: &[String], samples: &[Sample]) -> Predictor {
    let stick = sticks(samples);
    if stick.iter().all(|s| *s) || !stick.iter().any(|s| *s) {
        return plain(space, names, samples, true);
    }
    // distances in the scene's scaling of the parameters (the surface's)
    let axes: Vec<Axis> = names.iter().map(|n| Axis::of(space.range(n).expect("a parameter"))).collect();
    let distance = |a: &[f64], b: &[f64]| -> f64 {
        a.iter().zip(b).zip(&axes).map(|((x, y), axis)| (axis.unit(*x) - axis.unit(*y)).powi(2)).sum::<f64>().sqrt()
    };
    let nearest = |x: &[f64], sticking: bool| -> f64 {
        samples
            .iter()
            .zip(&stick)
            .filter(|(_, s)| **s == sticking)
            .map(|((y, _), _)| distance(x, y))
            .fold(f64::INFINITY, f64::min)
    };
    // the slip's typical slope away from the sticking points: the median of value / distance
    let mut slopes: Vec<f64> =
        samples.iter().zip(&stick).filter(|(_, s)| !**s).map(|((x, v), _)| v / nearest(x, true)).collect();
    slopes.sort_by(f64::total_cmp);
    let slope = slopes[slopes.len() / 2];
    let values: Vec<Sample> = samples
        .iter()
        .zip(&stick)
        .map(|((x, v), s)| (x.clone(), if *s { -slope * nearest(x, false) } else { *v }))
        .collect();
    plain(space, names, &values, true)
}
