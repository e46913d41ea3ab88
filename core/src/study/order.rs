//! Ordering policies: which pending design point to solve next, given what is done and what is
//! in flight. A policy, not a precomputed list, so that several pools can ask concurrently (each
//! asks when it becomes free; the points the others are solving count as in flight).

use crate::point::DesignPoint;
use std::cmp::Ordering;

use serde::{Deserialize, Serialize};

use super::space::ParameterSpace;

/// Chooses the next point of a study.
pub trait OrderingPolicy: Send {
    /// Index into `pending` of the point to solve next, or None when `pending` is empty.
    /// `done` are the points already solved (converged or not), `in_flight` those being solved.
    fn next(&mut self, pending: &[DesignPoint], done: &[DesignPoint], in_flight: &[DesignPoint]) -> Option<usize>;
}

/// The ordering policies a study can be asked for by name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum OrderKind {
    /// lexicographic ascending (the paper's ascending sweep)
    Asc,
    /// lexicographic descending (the paper's descending sweep)
    Desc,
    /// pending point nearest to the done and in-flight points
    Greedy,
}

impl OrderKind {
    pub fn name(&self) -> &'static str {
        match self {
            Self::Asc => "asc",
            Self::Desc => "desc",
            Self::Greedy => "greedy",
        }
    }

    /// The policy of this kind over `space`.
    pub fn policy(&self, space: &ParameterSpace) -> Box<dyn OrderingPolicy> {
        match self {
            Self::Asc => Box::new(LexicographicAscending),
            Self::Desc => Box::new(LexicographicDescending),
            Self::Greedy => Box::new(Greedy::new(space.clone())),
        }
    }
}

/// Compares points by their values in parameter-name order (the first name varies slowest).
pub fn lexicographic(a: &DesignPoint, b: &DesignPoint) -> Ordering {
    for ((ka, va), (kb, vb)) in a.iter().zip(b.iter()) {
        let o = ka.cmp(kb).then(va.total_cmp(&vb));
        if o != Ordering::Equal {
            return o;
        }
    }
    a.len().cmp(&b.len())
}

/// Smallest pending point first: with parameters f1, f2 the sweep runs f2 up at f1 = its lowest
/// value, then at the next f1, ... (the paper's ascending sweep).
#[derive(Debug, Clone, Copy, Default)]
pub struct LexicographicAscending;

impl OrderingPolicy for LexicographicAscending {
    fn next(&mut self, pending: &[DesignPoint], _: &[DesignPoint], _: &[DesignPoint]) -> Option<usize> {
        (0..pending.len()).min_by(|&i, &j| lexicographic(&pending[i], &pending[j]).then(i.cmp(&j)))
    }
}

/// Largest pending point first (the paper's descending sweep).
#[derive(Debug, Clone, Copy, Default)]
pub struct LexicographicDescending;

impl OrderingPolicy for LexicographicDescending {
    fn next(&mut self, pending: &[DesignPoint], _: &[DesignPoint], _: &[DesignPoint]) -> Option<usize> {
        (0..pending.len()).min_by(|&i, &j| lexicographic(&pending[j], &pending[i]).then(i.cmp(&j)))
    }
}

/// Squared distances within this share of each other are the same distance (rounding).
const TIE: f64 = 1e-9;

/// The pending point nearest (normalised distance) to the set of done and in-flight points, so
/// every solve can warm-start from a close neighbour; ties (within rounding, [`TIE`]) go to the
/// lexicographically smaller point; the first, the lexicographically smallest pending point (for
/// friction studies: the most slip, from which the sweep moves towards stick, the cheaper
/// direction in the paper). Cost per call O(|pending| x |done + in flight|): a second for about
/// 10^4 x 10^4 points.
#[derive(Debug, Clone)]
pub struct Greedy {
    space: ParameterSpace,
}

impl Greedy {
    pub fn new(space: ParameterSpace) -> Self {
        Self { space }
    }
}

impl OrderingPolicy for Greedy {
    fn next(&mut self, pending: &[DesignPoint], done: &[DesignPoint], in_flight: &[DesignPoint]) -> Option<usize> {
        if done.is_empty() && in_flight.is_empty() {
            return LexicographicAscending.next(pending, done, in_flight);
        }
        // O(|pending| x |done + in flight|) per call, on coordinates computed once per call
        let refs: Vec<Vec<f64>> = done.iter().chain(in_flight).map(|q| self.space.normalised_coordinates(q)).collect();
        let nearest: Vec<f64> = pending
            .iter()
            .map(|p| {
                let c = self.space.normalised_coordinates(p);
                refs.iter()
                    .map(|r| r.iter().zip(&c).map(|(a, b)| (a - b) * (a - b)).sum::<f64>())
                    .fold(f64::INFINITY, f64::min)
            })
            .collect();
        // ties within rounding: a grid's values (0.1 + 0.01 k) are not exact, and their rounding
        // alone used to decide between points a step away, so the sweep went in blocks
        let least = nearest.iter().copied().fold(f64::INFINITY, f64::min);
        let tied = |d: f64| d <= least + TIE * least.max(f64::MIN_POSITIVE);
        (0..pending.len())
            .filter(|&i| tied(nearest[i]))
            .min_by(|&i, &j| lexicographic(&pending[i], &pending[j]).then(i.cmp(&j)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::study::space::friction_box;

    fn grid() -> (ParameterSpace, Vec<DesignPoint>) {
        let space = friction_box(0.0, 1.0);
        let mut pts = Vec::new();
        for i in 0..3 {
            for j in 0..3 {
                pts.push(DesignPoint::from_pairs([("f1", i as f64 / 2.0), ("f2", j as f64 / 2.0)]).unwrap());
            }
        }
        (space, pts)
    }

    /// Drives a policy like a serial study: returns the order the points are taken in.
    fn sweep(policy: &mut dyn OrderingPolicy, mut pending: Vec<DesignPoint>) -> Vec<DesignPoint> {
        let mut done = Vec::new();
        while let Some(i) = policy.next(&pending, &done, &[]) {
            done.push(pending.remove(i));
        }
        done
    }

    #[test]
    fn lexicographic_sweeps() {
        let (_, pts) = grid();
        let mut shuffled = pts.clone();
        shuffled.reverse();
        shuffled.swap(2, 5);
        assert_eq!(sweep(&mut LexicographicAscending, shuffled.clone()), pts);
        let mut rev = pts.clone();
        rev.reverse();
        assert_eq!(sweep(&mut LexicographicDescending, shuffled), rev);
    }

    #[test]
    fn greedy_always_steps_to_a_neighbour() {
        let (space, pts) = grid();
        let order = sweep(&mut Greedy::new(space.clone()), pts.clone());
        assert_eq!(order[0], pts[0]);
        for (k, p) in order.iter().enumerate().skip(1) {
            let d = order[..k].iter().map(|q| space.normalised_distance(p, q)).fold(f64::INFINITY, f64::min);
            assert!((d - 0.5).abs() < 1e-12, "step {k} to {p} is {d} from the done set");
        }
    }

    /// On a grid whose values are rounded (0.1 + 0.01 k), the points a step away are tied and
    /// the sweep goes row by row, as the lexicographic one; it went in blocks of three rows when
    /// the values' rounding broke the ties (the paper's grid: 9,801 work against 9,351).
    #[test]
    fn greedy_breaks_ties_of_rounded_grids_lexicographically() {
        let space = friction_box(0.1, 0.2);
        let value = |k: usize| 0.1 + k as f64 * (0.2 - 0.1) / 10.0;
        let pts: Vec<DesignPoint> = (0..11)
            .flat_map(|i| (0..11).map(move |j| (i, j)))
            .map(|(i, j)| DesignPoint::from_pairs([("f1", value(i)), ("f2", value(j))]).unwrap())
            .collect();
        // (the rounding is there: not every step has the same length)
        let steps: Vec<f64> = (1..11).map(|k| value(k) - value(k - 1)).collect();
        assert!(steps.iter().any(|s| *s != steps[0]), "{steps:?}");
        let mut shuffled = pts.clone();
        shuffled.reverse();
        assert_eq!(sweep(&mut Greedy::new(space), shuffled), pts);
    }

    #[test]
    fn greedy_counts_in_flight_points() {
        let (space, pts) = grid();
        let mut g = Greedy::new(space);
        // a far corner in flight elsewhere: its neighbour is as near as the done point's
        let done = [pts[0].clone()];
        let in_flight = [pts[8].clone()];
        let pending: Vec<DesignPoint> = vec![pts[7].clone(), pts[4].clone()];
        assert_eq!(g.next(&pending, &done, &in_flight), Some(0));
        assert_eq!(g.next(&[], &done, &in_flight), None);
    }
}
