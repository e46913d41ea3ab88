//! Adaptive studies: the next design point is chosen from what is known so far, not from a grid.
//!
//! A study of `budget` points over a box of parameter ranges first spreads `initial` points
//! (each the candidate farthest from every point already chosen: a maximin design), then hands out
//! the candidate where the response surface ([`ResponseSurface`]) is least sure: the largest
//! standard deviation over the QoIs, each relative to the spread of its values. Candidates are a
//! fixed quasi-random (Halton) set over the box; those closer than [`MIN_SEPARATION`] to a point
//! already chosen (done, running or pending) are skipped, so pools asking at the same time get
//! different points.

use std::collections::BTreeMap;

use super::space::{DesignPoint, ParameterSpace};
use super::surrogate::ResponseSurface;

/// Candidates scored per choice.
const CANDIDATES: usize = 1024;
/// Closest a new point may be to a chosen one, in units of the box's sides (scaled coordinates).
pub const MIN_SEPARATION: f64 = 0.02;

/// An adaptive study's box and budget.
#[derive(Debug, Clone, PartialEq)]
pub struct AdaptiveDesign {
    /// (name, low, high) per swept parameter, sorted by name.
    pub ranges: Vec<(String, f64, f64)>,
    pub budget: usize,
}

impl AdaptiveDesign {
    /// The design of `NAME=LOW:HIGH` ranges (parameters of `space`, inside their declared
    /// ranges) and a budget of at least 2 points and at most `max_points`.
    pub fn parse(specs: &[String], budget: usize, space: &ParameterSpace, max_points: usize) -> Result<Self, String> {
        if specs.is_empty() {
            return Err("an adaptive study needs at least one range NAME=LOW:HIGH".into());
        }
        if !(2..=max_points).contains(&budget) {
            return Err(format!("adaptive budget {budget}: give 2 to {max_points} points"));
        }
        let mut ranges: Vec<(String, f64, f64)> = Vec::new();
        for spec in specs {
            let shown = crate::text::excerpt(spec, 80);
            let (name, bounds) =
                spec.split_once('=').ok_or_else(|| format!("range `{shown}`: expected NAME=LOW:HIGH"))?;
            let (lo, hi) = bounds.split_once(':').ok_or_else(|| format!("range `{shown}`: expected NAME=LOW:HIGH"))?;
            let number = |s: &str| s.trim().parse::<f64>().ok().filter(|v| v.is_finite());
            let (Some(lo), Some(hi)) = (number(lo), number(hi)) else {
                return Err(format!("range `{shown}`: LOW and HIGH must be numbers"));
            };
            let name = name.trim();
            let declared = space.range(name).ok_or_else(|| {
                format!(
                    "range `{shown}`: `{name}` is not a parameter of the scene ({})",
                    space.names().collect::<Vec<_>>().join(", ")
                )
            })?;
            if lo >= hi {
                return Err(format!("range `{shown}`: LOW must be below HIGH"));
            }
            if declared.declared && (lo < declared.min || hi > declared.max) {
                return Err(format!("range `{shown}`: outside the scene's range [{}, {}]", declared.min, declared.max));
            }
            if ranges.iter().any(|(n, ..)| n == name) {
                return Err(format!("range `{shown}`: `{name}` given twice"));
            }
            ranges.push((name.to_owned(), lo, hi));
        }
        if ranges.len() > super::surrogate::MAX_DIMENSION {
            return Err(format!(
                "{} ranges: an adaptive study sweeps at most {}",
                ranges.len(),
                super::surrogate::MAX_DIMENSION
            ));
        }
        ranges.sort_by(|a, b| a.0.cmp(&b.0));
        Ok(Self { ranges, budget })
    }

    /// Points spread before the surface chooses: 2 per parameter plus one, within the budget.
    pub fn initial(&self) -> usize {
        (2 * self.ranges.len() + 1).min(self.budget)
    }

    /// The next point to solve, given the points chosen so far (`chosen`, with their QoIs where
    /// they are done); None when every candidate is too close to a chosen point.
    pub fn next(
        &self,
        space: &ParameterSpace,
        chosen: &[(DesignPoint, Option<&BTreeMap<String, f64>>)],
    ) -> Option<DesignPoint> {
        let dim = self.ranges.len();
        let scaled = |p: &DesignPoint| -> Vec<f64> {
            self.ranges
                .iter()
                .map(|(n, lo, hi)| (p.get(n).unwrap_or(*lo) - lo) / (hi - lo).max(f64::MIN_POSITIVE))
                .collect()
        };
        let taken: Vec<Vec<f64>> = chosen.iter().map(|(p, _)| scaled(p)).collect();
        let distance = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>().sqrt();
        let nearest = |c: &[f64]| taken.iter().map(|t| distance(c, t)).fold(f64::INFINITY, f64::min);
        let candidates: Vec<Vec<f64>> =
            (1..=CANDIDATES).map(|i| (0..dim).map(|d| halton(i, PRIMES[d % PRIMES.len()])).collect()).collect();
        let free: Vec<&Vec<f64>> = candidates.iter().filter(|c| nearest(c) >= MIN_SEPARATION).collect();
        let point = |c: &[f64]| {
            DesignPoint::from_pairs(self.ranges.iter().zip(c).map(|((n, lo, hi), x)| (n.clone(), lo + x * (hi - lo))))
        };
        // the surfaces of the QoIs, from the done points
        let done: Vec<(&DesignPoint, &BTreeMap<String, f64>)> =
            chosen.iter().filter_map(|(p, q)| Some((p, (*q)?))).collect();
        let names: Vec<String> = self.ranges.iter().map(|(n, ..)| n.clone()).collect();
        let mut surfaces = Vec::new();
        if chosen.len() >= self.initial() && done.len() >= 2 {
            let qois: std::collections::BTreeSet<&String> = done.iter().flat_map(|(_, q)| q.keys()).collect();
            for q in qois {
                let samples: Vec<(Vec<f64>, f64)> = done
                    .iter()
                    .filter_map(|(p, v)| {
                        Some((names.iter().map(|n| p.get(n).unwrap_or(f64::NAN)).collect(), *v.get(q)?))
                    })
                    .collect();
                let values: Vec<f64> = samples.iter().map(|(_, v)| *v).collect();
                let spread =
                    values.iter().cloned().fold(f64::MIN, f64::max) - values.iter().cloned().fold(f64::MAX, f64::min);
                if let Ok(s) = ResponseSurface::fit(space, &names, &samples) {
                    surfaces.push((s, if spread > 0.0 { spread } else { 1.0 }));
                }
            }
        }
        let score = |c: &[f64]| -> f64 {
            if surfaces.is_empty() {
                // the initial, space-filling points: farthest from every chosen one
                return nearest(c);
            }
            let p = point(c);
            surfaces.iter().filter_map(|(s, spread)| s.predict(&p).ok().map(|v| v.std / spread)).fold(0.0, f64::max)
        };
        let best = free.into_iter().map(|c| (score(c), c)).max_by(|a, b| a.0.total_cmp(&b.0))?;
        Some(point(best.1))
    }
}

const PRIMES: [usize; 8] = [2, 3, 5, 7, 11, 13, 17, 19];

/// The `i`-th element of the van der Corput sequence in base `b` (a coordinate of Halton's).
fn halton(mut i: usize, b: usize) -> f64 {
    let (mut f, mut r) = (1.0, 0.0);
    while i > 0 {
        f /= b as f64;
        r += f * (i % b) as f64;
        i /= b;
    }
    r
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::study::space::ParameterRange;

    fn space() -> ParameterSpace {
        let range =
            |name: &str| ParameterRange { name: name.into(), default: 0.15, min: 0.1, max: 0.2, declared: true };
        ParameterSpace::new(vec![range("f1"), range("f2")])
    }

    fn design(budget: usize) -> AdaptiveDesign {
        AdaptiveDesign { ranges: vec![("f1".into(), 0.1, 0.2), ("f2".into(), 0.1, 0.2)], budget }
    }

    #[test]
    fn it_spreads_the_first_points_then_goes_where_the_surface_is_least_sure() {
        let (d, space) = (design(20), space());
        // space-filling: each new point far from the chosen ones, inside the box
        let mut chosen: Vec<DesignPoint> = Vec::new();
        for _ in 0..d.initial() {
            let with: Vec<(DesignPoint, Option<&BTreeMap<String, f64>>)> =
                chosen.iter().map(|p| (p.clone(), None)).collect();
            let p = d.next(&space, &with).unwrap();
            for (_, v) in p.iter() {
                assert!((0.1..=0.2).contains(&v), "{p}");
            }
            assert!(chosen.iter().all(|c| space.normalised_distance(c, &p) > 0.3), "{p} too close to {chosen:?}");
            chosen.push(p);
        }
        // a surface that bends only near f1 = 0.2: the next points go there
        let qoi = |p: &DesignPoint| -> BTreeMap<String, f64> {
            let x = (p.get("f1").unwrap() - 0.1) / 0.1;
            [("slip".to_string(), (12.0 * (x - 0.8).max(0.0)).powi(2))].into()
        };
        let values: Vec<BTreeMap<String, f64>> = chosen.iter().map(qoi).collect();
        let with: Vec<(DesignPoint, Option<&BTreeMap<String, f64>>)> =
            chosen.iter().cloned().zip(values.iter().map(Some)).collect();
        let next = d.next(&space, &with).unwrap();
        assert!(chosen.iter().all(|c| space.normalised_distance(c, &next) >= MIN_SEPARATION));
        let nearest_done = chosen.iter().map(|c| space.normalised_distance(c, &next)).fold(f64::INFINITY, f64::min);
        assert!(nearest_done > 0.1, "the least sure place is away from the points: {next} ({nearest_done})");
    }

    #[test]
    fn points_asked_for_at_the_same_time_differ_and_a_full_box_gives_none() {
        let (d, space) = (design(4), space());
        let a = d.next(&space, &[]).unwrap();
        let b = d.next(&space, &[(a.clone(), None)]).unwrap();
        assert!(space.normalised_distance(&a, &b) > MIN_SEPARATION);
        // every candidate taken: nothing left to give
        let all: Vec<(DesignPoint, Option<&BTreeMap<String, f64>>)> = (1..=CANDIDATES)
            .map(|i| {
                let (x, y) = (halton(i, 2), halton(i, 3));
                (DesignPoint::from_pairs([("f1", 0.1 + 0.1 * x), ("f2", 0.1 + 0.1 * y)]), None)
            })
            .collect();
        assert_eq!(d.next(&space, &all), None);
    }
}
