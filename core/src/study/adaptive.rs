//! Adaptive studies: the next design point is chosen from what is known so far, not from a grid.
//!
//! A study of `budget` points over a box of parameter ranges first spreads `initial` points
//! (each the candidate farthest from every point already chosen: a maximin design), then hands out
//! the candidate where the response surface ([`QoiSurface`]: a norm from its components where the
//! scene reports them) is least sure: the largest standard deviation over the QoIs, each relative
//! to the spread of its values. Candidates are a fixed quasi-random (Halton) set over the box,
//! and, once the surface chooses, the box's 2^d corners ([`corners`]: no Halton point reaches
//! them, and a QoI steepest towards a corner is wrong there most); those closer than
//! [`MIN_SEPARATION`] to a point already chosen (done, running or pending) are skipped, so pools
//! asking at the same time get different points.
//!
//! With a target (`--surface-accuracy`), the study stops before its budget once the surfaces'
//! cross-validated error ([`Surfaces::cross_validate`]: leave-one-out, the measure of the surface
//! audit) is within the target for every QoI (docs/surrogate.md, "Adaptive to a target").

use crate::point::DesignPoint;
use std::collections::BTreeMap;

use super::holdout::{self, SurfaceErrors};
use super::space::{Axis, ParameterSpace};
use super::surrogate::QoiSurface;
use crate::contact::ContactActivity;
use crate::scene::{MIN_TOLERANCE, QoiKind, Scene};

/// Candidates scored per choice.
const CANDIDATES: usize = 1024;
/// Closest a new point may be to a chosen one, in units of the box's sides (scaled coordinates).
pub const MIN_SEPARATION: f64 = 0.02;
/// The largest error in the box per unit of the largest score (standard deviation x local
/// calibration, relative to the spread) over the candidates ([`Surfaces::box_largest`]).
pub const BOX_LARGEST_PER_SCORE: f64 = 3.0;
/// The budget of a study with a target and no budget given.
pub const TARGET_BUDGET: usize = 100;
/// A point's tolerance per unit of the target ([`point_tolerance`]): measured, a point's QoIs
/// are within about 3 x the tolerance of the largest |QoI|, and a QoI may vary over the box by
/// only a tenth of its largest value (tiny's middle_ux: 13-17 % on the paper's box), so this keeps
/// the points' own error near a tenth of the target for such a QoI too. Tighter points cost little
/// (tiny's 121 cold points: 1.22 x the work at 1e-6 as at 2e-4), looser ones show in the surface
/// (middle_ux from 121 points at 2e-4 against 3.3e-5: 1.7 x the mean error, 59 % within 2 sd
/// against 85 %; docs/surrogate.md, "Why 121 points left 4-5 %").
pub const TOLERANCE_PER_TARGET: f64 = 1.0 / 300.0;
/// A surface accuracy target: a share of each QoI's spread, in (0, 1].
pub fn check_target(target: f64) -> Result<f64, TargetError> {
    if target.is_finite() && target > 0.0 && target <= 1.0 { Ok(target) } else { Err(TargetError { target }) }
}

/// A surface accuracy target out of (0, 1] ([`check_target`]).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error(
    "surface accuracy {target}: give the error aimed at as a share of each QoI's spread, above 0 and at most 1 (0.02: 2 %)"
)]
pub struct TargetError {
    pub target: f64,
}

/// Why [`AdaptiveDesign::parse`] refuses a design.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DesignError {
    #[error("a surface accuracy target needs the box of an adaptive study: give ranges NAME=LOW:HIGH")]
    TargetWithoutRanges,
    #[error("an adaptive study needs at least one range NAME=LOW:HIGH")]
    NoRanges,
    #[error(transparent)]
    Target(#[from] TargetError),
    #[error("adaptive budget {budget}: give 2 to {max} points")]
    Budget { budget: usize, max: usize },
    /// One `NAME=LOW:HIGH` range (`spec`: an excerpt of it) and what is wrong with it.
    #[error("range `{spec}`: {problem}")]
    Range { spec: String, problem: RangeProblem },
    #[error("{count} ranges: an adaptive study sweeps at most {max}")]
    TooManyRanges { count: usize, max: usize },
}

/// What is wrong with one range of an adaptive design ([`DesignError::Range`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RangeProblem {
    #[error("expected NAME=LOW:HIGH")]
    Syntax,
    #[error("LOW and HIGH must be numbers")]
    NotNumbers,
    /// `declared`: the scene's parameters, listed.
    #[error("`{name}` is not a parameter of the scene ({declared})")]
    UnknownParameter { name: String, declared: String },
    #[error("LOW must be below HIGH")]
    Empty,
    #[error("outside the scene's range [{min}, {max}]")]
    OutsideScene { min: f64, max: f64 },
    #[error("`{name}` given twice")]
    Twice { name: String },
}

/// The tolerance the points of a study aiming at `target` are solved to: target x
/// [`TOLERANCE_PER_TARGET`] (at most 3.3e-3, for a target of 1), at least MIN_TOLERANCE. It assumes every
/// QoI varies over the box by at least a tenth of its largest |value|; one that varies by a
/// smaller share r needs 10 r x this (give `--tol`).
pub fn point_tolerance(target: f64) -> f64 {
    (target * TOLERANCE_PER_TARGET).max(MIN_TOLERANCE)
}

/// How each QoI's surface is read: a norm (a slip without a component) never below zero, and
/// from its signed components where the scene reports them; the components themselves are read
/// through their norm, neither scored nor judged on their own (a component that stays near zero
/// over the box has a spread of rounding errors).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct QoiReadings {
    /// norm -> its components (empty: none reported)
    norms: BTreeMap<String, Vec<String>>,
    /// force QoI -> its interface
    forces: BTreeMap<String, String>,
    /// interface -> how many of the done points it chattered at ([`ContactActivity::chatters`]),
    /// and the done points
    chatter: (BTreeMap<String, usize>, usize),
}

/// The share of the done points at which an interface chatters from which its forces are set
/// aside (at least [`CHATTER_POINTS`] of them): a force read at the last step of a contact that
/// lifts off and lands while it slides is a snapshot of that ringing, not a function of the
/// parameters. Measured on sliding-block-2d over f 0.05..0.6 x push 2..30 MPa (21 x 21 points
/// at 1e-6): the floor chatters at 65 of them (15 %), and there the final normal force jumps
/// from 0 to 640 kN/m between neighbours; the slip beside it stays smooth
/// (docs/notebook/2026-11-29.md, "Forces set aside where the contact chatters").
pub const CHATTER_SHARE: f64 = 0.1;
/// The fewest chattering points that set a force aside.
pub const CHATTER_POINTS: usize = 3;

impl QoiReadings {
    pub fn of(scene: &Scene) -> Self {
        let norms = scene
            .qoi
            .iter()
            .filter(|q| scene.qoi_is_norm(&q.name))
            .map(|q| (q.name.clone(), scene.components_of(&q.name).into_iter().map(String::from).collect()))
            .collect();
        let forces = scene
            .qoi
            .iter()
            .filter(|q| q.kind == QoiKind::Force)
            .filter_map(|q| Some((q.name.clone(), q.interface.clone()?)))
            .collect();
        Self { norms, forces, chatter: (BTreeMap::new(), 0) }
    }

    /// The same, with what the contacts did at the done points (each point's reports).
    pub fn with_contacts<'a>(mut self, done: impl IntoIterator<Item = &'a [ContactActivity]>) -> Self {
        let (counts, points) = &mut self.chatter;
        for reports in done {
            *points += 1;
            for r in reports.iter().filter(|r| r.chatters()) {
                *counts.entry(r.interface.clone()).or_insert(0) += 1;
            }
        }
        self
    }

    /// Why `qoi` is no surface over this box, if it is not: a force of an interface that
    /// chatters at [`CHATTER_SHARE`] of the done points or more.
    fn set_aside(&self, qoi: &str) -> Option<String> {
        let interface = self.forces.get(qoi)?;
        let (counts, points) = &self.chatter;
        let chattering = counts.get(interface).copied().unwrap_or(0);
        (chattering >= CHATTER_POINTS && chattering as f64 >= CHATTER_SHARE * *points as f64).then(|| {
            format!(
                "set aside: interface '{interface}' chatters (lifts off and lands while it slides) at {chattering} of \
                 {points} points, and a force read at the last step of a chattering contact is a snapshot of its \
                 ringing, not a surface; read a slip, or damp the chatter with `prakash_clifton` (docs/scenes.md)"
            )
        })
    }

    fn is_component(&self, qoi: &str) -> bool {
        self.norms.values().any(|c| c.iter().any(|c| c == qoi))
    }
}

/// The surfaces of an adaptive study's done points, one per QoI read on its own.
#[derive(Debug, Clone, Default)]
pub struct Surfaces {
    /// the design's box: (name, low, high) per swept parameter
    ranges: Vec<(String, f64, f64)>,
    /// (QoI, its surface, its spread over the done points, its values there in the fitted order)
    fitted: Vec<(String, QoiSurface, f64, Vec<f64>)>,
    /// per fitted QoI, its fitted points (the swept parameters' values), in the fitted order
    at: Vec<Vec<Vec<f64>>>,
    /// per fitted QoI, at each fitted point but the box's corners: |leave-one-out residual| and
    /// its standard deviation, how wrong the surface is there for how unsure
    misfit: Vec<Vec<(Vec<f64>, f64, f64)>>,
    /// QoIs whose surface could not be fitted, and why
    pub refused: BTreeMap<String, String>,
    /// those of `refused` set aside as no surface at all ([`QoiReadings::set_aside`])
    pub set_aside: std::collections::BTreeSet<String>,
    /// done points the surfaces were fitted to
    pub points: usize,
}

/// The cross-validated error of each QoI's surface, relative to its spread over the done points.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CrossValidation {
    /// done points the surfaces were fitted to
    pub points: usize,
    pub qoi: BTreeMap<String, SurfaceErrors>,
    /// QoIs whose surface could not be fitted, and why
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub refused: BTreeMap<String, String>,
    /// those of `refused` set aside as no surface at all: the study stops when the others are
    /// within its target, and says NOT REACHED
    #[serde(default, skip_serializing_if = "std::collections::BTreeSet::is_empty")]
    pub set_aside: std::collections::BTreeSet<String>,
}

impl CrossValidation {
    /// Some QoIs were refused, and every one of them was set aside as no surface.
    pub fn only_set_aside(&self) -> bool {
        !self.set_aside.is_empty() && self.refused.keys().all(|q| self.set_aside.contains(q))
    }
}

/// How a study with a target ended, and the errors it was judged on.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TargetOutcome {
    /// Every QoI's cross-validated error within the target; false: the budget was spent first.
    pub reached: bool,
    pub validation: CrossValidation,
}

impl Surfaces {
    /// Leave-one-out over the done points ([`QoiSurface::leave_one_out`]), measured as the
    /// surface audit measures its held-out points ([`holdout::surface_errors`]), and the largest
    /// error in the box as the surface estimates it ([`Self::box_largest`]): what a target is
    /// judged on.
    pub fn cross_validate(&self) -> CrossValidation {
        let candidates = with_corners(candidates(self.ranges.len()));
        let qoi = self
            .fitted
            .iter()
            .enumerate()
            .map(|(k, (q, surface, spread, values))| {
                // (a corner that is a design point is left out: the surface is exact there, and
                // its leave-one-out residual measures an extrapolation the surface never makes)
                let pairs: Vec<_> = surface
                    .leave_one_out()
                    .into_iter()
                    .zip(values.iter().copied())
                    .zip(&self.at[k])
                    .filter(|(_, x)| !self.is_corner(x))
                    .map(|(pair, _)| pair)
                    .collect();
                let mut errors = holdout::surface_errors(&pairs, *spread);
                errors.box_largest = Some(self.box_largest(k, &candidates).max(errors.largest));
                (q.clone(), errors)
            })
            .collect();
        CrossValidation { points: self.points, qoi, refused: self.refused.clone(), set_aside: self.set_aside.clone() }
    }

    /// How wrong fitted QoI `k`'s surface may be at `c` (scaled coordinates), relative to its
    /// spread: its standard deviation times how wrong it is near `c` for how unsure it says it
    /// is ([`Self::calibration`]). The design goes where this is largest.
    fn score(&self, k: usize, c: &[f64]) -> f64 {
        let (_, s, spread, _) = &self.fitted[k];
        let x: Vec<f64> = axes(&self.ranges).iter().zip(c).map(|(axis, u)| axis.value(*u)).collect();
        let p = DesignPoint::from_pairs(self.ranges.iter().zip(&x).map(|((n, ..), v)| (n.as_str(), *v)))
            .expect("a point of ranges `parse` checked: the scene's parameters, finite bounds");
        s.predict(&p).map_or(0.0, |v| v.std / spread * self.calibration(&self.misfit[k], &x))
    }

    /// The largest error of fitted QoI `k`'s surface anywhere in the box, as it estimates it:
    /// [`BOX_LARGEST_PER_SCORE`] x the largest [`Self::score`] over the candidates and the box's
    /// corners (the leave-one-out errors are at the points, where the surface was forced
    /// through; the largest error of a surface is between them, where the design has not been,
    /// or beyond them, at a corner).
    fn box_largest(&self, k: usize, candidates: &[Vec<f64>]) -> f64 {
        BOX_LARGEST_PER_SCORE * candidates.iter().map(|c| self.score(k, c)).fold(0.0, f64::max)
    }

    pub fn is_empty(&self) -> bool {
        self.fitted.is_empty()
    }

    /// Whether `x` (the swept parameters' values) is a corner of the box.
    fn is_corner(&self, x: &[f64]) -> bool {
        self.ranges.iter().zip(x).all(|((_, lo, hi), v)| {
            let at = (hi - lo).abs() * 1e-9;
            (v - lo).abs() <= at || (v - hi).abs() <= at
        })
    }

    /// The QoIs scored and judged, and whether each is read from its components.
    pub fn qois(&self) -> impl Iterator<Item = (&str, bool)> {
        self.fitted.iter().map(|(q, s, ..)| (q.as_str(), s.from_components()))
    }
}

/// An adaptive study's box and budget.
#[derive(Debug, Clone, PartialEq)]
pub struct AdaptiveDesign {
    /// (name, low, high) per swept parameter, sorted by name.
    pub ranges: Vec<(String, f64, f64)>,
    pub budget: usize,
    /// Stop once the cross-validated mean error is within this share of every QoI's spread.
    pub target: Option<f64>,
}

impl AdaptiveDesign {
    /// The design of `NAME=LOW:HIGH` ranges (parameters of `space`, inside their declared
    /// ranges) and a budget of at least 2 points and at most `max_points`.
    /// A `target` ([`check_target`]) stops it earlier, when its surfaces are good enough.
    pub fn parse(
        specs: &[String],
        budget: usize,
        target: Option<f64>,
        space: &ParameterSpace,
        max_points: usize,
    ) -> Result<Self, DesignError> {
        if specs.is_empty() {
            return Err(if target.is_some() { DesignError::TargetWithoutRanges } else { DesignError::NoRanges });
        }
        let target = target.map(check_target).transpose()?;
        if !(2..=max_points).contains(&budget) {
            return Err(DesignError::Budget { budget, max: max_points });
        }
        let mut ranges: Vec<(String, f64, f64)> = Vec::new();
        for spec in specs {
            let refused = |problem| DesignError::Range { spec: crate::text::excerpt(spec, 80), problem };
            let (name, bounds) = spec.split_once('=').ok_or_else(|| refused(RangeProblem::Syntax))?;
            let (lo, hi) = bounds.split_once(':').ok_or_else(|| refused(RangeProblem::Syntax))?;
            let number = |s: &str| s.trim().parse::<f64>().ok().filter(|v| v.is_finite());
            let (Some(lo), Some(hi)) = (number(lo), number(hi)) else {
                return Err(refused(RangeProblem::NotNumbers));
            };
            let name = name.trim();
            let declared = space.range(name).ok_or_else(|| {
                let declared = space.names().collect::<Vec<_>>().join(", ");
                refused(RangeProblem::UnknownParameter { name: name.to_owned(), declared })
            })?;
            if lo >= hi {
                return Err(refused(RangeProblem::Empty));
            }
            if declared.declared && (lo < declared.min || hi > declared.max) {
                return Err(refused(RangeProblem::OutsideScene { min: declared.min, max: declared.max }));
            }
            if ranges.iter().any(|(n, ..)| n == name) {
                return Err(refused(RangeProblem::Twice { name: name.to_owned() }));
            }
            ranges.push((name.to_owned(), lo, hi));
        }
        if ranges.len() > super::surrogate::MAX_DIMENSION {
            return Err(DesignError::TooManyRanges { count: ranges.len(), max: super::surrogate::MAX_DIMENSION });
        }
        ranges.sort_by(|a, b| a.0.cmp(&b.0));
        Ok(Self { ranges, budget, target })
    }

    /// Points spread before the surface chooses: 2 per parameter plus one, within the budget.
    pub fn initial(&self) -> usize {
        (2 * self.ranges.len() + 1).min(self.budget)
    }

    /// The initial points, as [`Self::next`] chooses them one after another before any surface
    /// is fitted (the surfaces wait for them all): known at submit, so that a study's audits can
    /// re-solve some of them.
    pub fn initial_points(&self) -> Vec<DesignPoint> {
        let mut chosen: Vec<(DesignPoint, Option<&BTreeMap<String, f64>>)> = Vec::new();
        while chosen.len() < self.initial() {
            let Some(p) = self.next(&chosen, &Surfaces::default()) else { break };
            chosen.push((p, None));
        }
        chosen.into_iter().map(|(p, _)| p).collect()
    }

    /// Done points needed before the target is judged: twice the initial design (a surface of
    /// fewer points can be flat by chance, every point sticking: its error would read zero).
    pub fn validated_after(&self) -> usize {
        2 * (2 * self.ranges.len() + 1)
    }

    /// Whether `cv` meets the target: enough points, every QoI fitted, each one's mean error
    /// within the target. False without a target.
    pub fn target_reached(&self, cv: &CrossValidation) -> bool {
        cv.refused.is_empty() && self.fitted_within(cv)
    }

    /// Whether every QoI fitted is within the target, with enough points: the study stops there
    /// (REACHED when no QoI was refused; with QoIs set aside, NOT REACHED, and they say why).
    fn fitted_within(&self, cv: &CrossValidation) -> bool {
        self.target.is_some_and(|t| {
            cv.points >= self.validated_after()
                && !cv.qoi.is_empty()
                && cv.qoi.values().all(|e| e.box_largest.unwrap_or(e.largest) <= t)
        })
    }

    /// The outcome of a study with a target, once decided: reached; or every QoI fitted within
    /// the target and the others set aside (not reached: they are no surface, and more points
    /// would not make them one); or `spent` (its budget chosen and nothing left to solve) with
    /// the error it got. None without a target.
    pub fn outcome(&self, surfaces: &Surfaces, spent: bool) -> Option<TargetOutcome> {
        self.target?;
        let validation = surfaces.cross_validate();
        let reached = self.target_reached(&validation);
        let settled = validation.only_set_aside() && self.fitted_within(&validation);
        (reached || settled || spent).then_some(TargetOutcome { reached, validation })
    }

    /// The surfaces of the done points among `chosen` (none before the initial points are chosen
    /// and 2 are done: the initial points fill the box first).
    pub fn surfaces(
        &self,
        space: &ParameterSpace,
        readings: &QoiReadings,
        chosen: &[(DesignPoint, Option<&BTreeMap<String, f64>>)],
    ) -> Surfaces {
        let names: Vec<String> = self.ranges.iter().map(|(n, ..)| n.clone()).collect();
        let rows: Vec<(Vec<f64>, &BTreeMap<String, f64>)> = chosen
            .iter()
            .filter_map(|(p, q)| Some((names.iter().map(|n| p.get(n).unwrap_or(f64::NAN)).collect(), (*q)?)))
            .collect();
        let mut surfaces = Surfaces { ranges: self.ranges.clone(), points: rows.len(), ..Surfaces::default() };
        if chosen.len() < self.initial() || rows.len() < 2 {
            return surfaces;
        }
        let qois: std::collections::BTreeSet<&String> = rows.iter().flat_map(|(_, q)| q.keys()).collect();
        for q in qois.into_iter().filter(|q| !readings.is_component(q)) {
            if let Some(why) = readings.set_aside(q) {
                surfaces.set_aside.insert(q.clone());
                surfaces.refused.insert(q.clone(), why);
                continue;
            }
            let components: Vec<&str> =
                readings.norms.get(q.as_str()).map(|c| c.iter().map(String::as_str).collect()).unwrap_or_default();
            let norm = readings.norms.contains_key(q.as_str());
            // (the points taken as exact: a new point has the same error as the others, so the
            // points' own error, which the surface of `--at` carries, says nothing of where to go)
            match QoiSurface::fit(space, &names, &rows, &[], q, norm, &components) {
                Ok(s) => {
                    let at: Vec<&Vec<f64>> =
                        rows.iter().filter(|(_, v)| v.contains_key(q.as_str())).map(|(x, _)| x).collect();
                    let values: Vec<f64> = rows.iter().filter_map(|(_, v)| v.get(q.as_str()).copied()).collect();
                    // (a corner's residual is an extrapolation's: it says nothing of the
                    // surface near the corner once the corner is a point)
                    let misfit = s
                        .leave_one_out()
                        .iter()
                        .zip(&values)
                        .zip(&at)
                        .filter(|(_, x)| !surfaces.is_corner(x))
                        .map(|((p, v), x)| ((*x).clone(), (p.mean - v).abs(), p.std))
                        .collect();
                    surfaces.misfit.push(misfit);
                    surfaces.at.push(at.into_iter().cloned().collect());
                    surfaces.fitted.push((q.clone(), s, holdout::spread(values.iter().copied()), values));
                }
                Err(e) => {
                    surfaces.refused.insert(q.clone(), e.to_string());
                }
            }
        }
        surfaces
    }

    /// The next point to solve, given the points chosen so far (`chosen`, with their QoIs where
    /// they are done) and the `surfaces` of the done ones; None when every candidate is too
    /// close to a chosen point.
    pub fn next(
        &self,
        chosen: &[(DesignPoint, Option<&BTreeMap<String, f64>>)],
        surfaces: &Surfaces,
    ) -> Option<DesignPoint> {
        let axes = axes(&self.ranges);
        let scaled = |p: &DesignPoint| -> Vec<f64> {
            self.ranges.iter().zip(&axes).map(|((n, lo, _), axis)| axis.unit(p.get(n).unwrap_or(*lo))).collect()
        };
        let taken: Vec<Vec<f64>> = chosen.iter().map(|(p, _)| scaled(p)).collect();
        let distance = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>().sqrt();
        let nearest = |c: &[f64]| taken.iter().map(|t| distance(c, t)).fold(f64::INFINITY, f64::min);
        // (the initial points among the Halton points only: the corners, farthest from any
        // point, would be the maximin start's first choices, and 2^d points on the box's
        // corners fit the surface's length scales worse than as many spread inside)
        let candidates = if surfaces.is_empty() {
            candidates(self.ranges.len())
        } else {
            with_corners(candidates(self.ranges.len()))
        };
        let free: Vec<&Vec<f64>> = candidates.iter().filter(|c| nearest(c) >= MIN_SEPARATION).collect();
        let score = |c: &[f64]| -> f64 {
            if surfaces.is_empty() {
                // the initial, space-filling points: farthest from every chosen one
                return nearest(c);
            }
            (0..surfaces.fitted.len()).map(|k| surfaces.score(k, c)).fold(0.0, f64::max)
        };
        let best = free.into_iter().map(|c| (score(c), c)).max_by(|a, b| a.0.total_cmp(&b.0))?;
        Some(
            DesignPoint::from_pairs(
                self.ranges.iter().zip(&axes).zip(best.1).map(|(((n, ..), axis), u)| (n.as_str(), axis.value(*u))),
            )
            .expect("a point of ranges `parse` checked: the scene's parameters, finite bounds"),
        )
    }
}

/// Each range's map to [0, 1] ([`Axis`]: logarithmic over a decade or more).
fn axes(ranges: &[(String, f64, f64)]) -> Vec<Axis> {
    ranges.iter().map(|(_, lo, hi)| Axis::new(*lo, *hi)).collect()
}

/// The candidates of a box of `dim` parameters, scaled to [0, 1]: the first [`CANDIDATES`]
/// points of the Halton sequence.
fn candidates(dim: usize) -> Vec<Vec<f64>> {
    (1..=CANDIDATES).map(|i| (0..dim).map(|d| halton(i, PRIMES[d % PRIMES.len()])).collect()).collect()
}

/// The 2^`dim` corners of the box, scaled to [0, 1]. No Halton point reaches them (the nearest
/// of the 1,024 is 0.02-0.03 of the sides away), and a QoI steepest towards a corner is wrong
/// there most: on tiny's prestress x pressure box slip_A's largest error, 6.5 % of its spread
/// where 2 % was asked, sat at a corner, estimated 2.7 % (docs/surrogate.md, "Boxes of our
/// own"). A corner's own standard deviation, an extrapolation's, says little of its error
/// (measured on the synthetic laws of the tests: |error| / score at a corner median 1.75, one
/// in ten above 5), so the corners are not scored apart: they are points the surface may ask
/// for like any candidate, and once solved the surface is exact there.
fn corners(dim: usize) -> Vec<Vec<f64>> {
    (0..1usize << dim).map(|m| (0..dim).map(|d| ((m >> d) & 1) as f64).collect()).collect()
}

/// `candidates` and the box's corners.
fn with_corners(mut candidates: Vec<Vec<f64>>) -> Vec<Vec<f64>> {
    candidates.extend(corners(candidates.first().map_or(0, Vec::len)));
    candidates
}

impl Surfaces {
    /// How wrong the surface is near `x` for how unsure it says it is: over the 2 d nearest
    /// fitted points (d parameters), the sum of their leave-one-out |residuals| over the sum of
    /// their standard deviations (1 where both are 0). The standard deviation alone is the same
    /// wherever the points are as far apart (a stationary kernel); times this, the points go
    /// where the surface is wrong: on tiny's paper box, 10 more points along the low-friction
    /// edge brought every QoI's largest error from 1.9-3.0 % to 0.9-1.8 % of its spread
    /// (docs/surrogate.md, "Why 121 points left 4-5 %").
    fn calibration(&self, misfit: &[(Vec<f64>, f64, f64)], x: &[f64]) -> f64 {
        let axes = axes(&self.ranges);
        let distance = |y: &[f64]| -> f64 {
            axes.iter().zip(x.iter().zip(y)).map(|(axis, (a, b))| (axis.unit(*a) - axis.unit(*b)).powi(2)).sum::<f64>()
        };
        let mut near: Vec<(f64, f64, f64)> = misfit.iter().map(|(y, r, s)| (distance(y), *r, *s)).collect();
        near.sort_by(|a, b| a.0.total_cmp(&b.0));
        let k = (2 * self.ranges.len()).min(near.len());
        let (residuals, deviations) = near[..k].iter().fold((0.0, 0.0), |(r, s), n| (r + n.1, s + n.2));
        if deviations > 0.0 { residuals / deviations } else { 1.0 }
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
        AdaptiveDesign { ranges: vec![("f1".into(), 0.1, 0.2), ("f2".into(), 0.1, 0.2)], budget, target: None }
    }

    /// The next point with the surfaces of `chosen`, read as plain processes.
    fn next(
        d: &AdaptiveDesign,
        space: &ParameterSpace,
        chosen: &[(DesignPoint, Option<&BTreeMap<String, f64>>)],
    ) -> Option<DesignPoint> {
        d.next(chosen, &d.surfaces(space, &QoiReadings::default(), chosen))
    }

    #[test]
    fn it_spreads_the_first_points_then_goes_where_the_surface_is_least_sure() {
        let (d, space) = (design(20), space());
        // space-filling: each new point far from the chosen ones, inside the box
        let mut chosen: Vec<DesignPoint> = Vec::new();
        for _ in 0..d.initial() {
            let with: Vec<(DesignPoint, Option<&BTreeMap<String, f64>>)> =
                chosen.iter().map(|p| (p.clone(), None)).collect();
            let p = next(&d, &space, &with).unwrap();
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
        let next = next(&d, &space, &with).unwrap();
        assert!(chosen.iter().all(|c| space.normalised_distance(c, &next) >= MIN_SEPARATION));
        let nearest_done = chosen.iter().map(|c| space.normalised_distance(c, &next)).fold(f64::INFINITY, f64::min);
        assert!(nearest_done > 0.1, "the least sure place is away from the points: {next} ({nearest_done})");
    }

    /// The design of `budget` points of `law`, one at a time, each chosen with the surfaces of
    /// those before; `blind`: without the leave-one-out residuals (the standard deviation alone,
    /// as before they weighed it). Returns the points and the largest error of the final surface
    /// over a 41 x 41 grid, relative to the law's spread there.
    fn drive(law: &dyn Fn(f64, f64) -> f64, budget: usize, blind: bool) -> (Vec<DesignPoint>, f64) {
        let (d, space) = (design(budget), space());
        let qoi = |p: &DesignPoint| -> BTreeMap<String, f64> {
            [("q".to_string(), law(p.get("f1").unwrap(), p.get("f2").unwrap()))].into()
        };
        let mut chosen: Vec<(DesignPoint, BTreeMap<String, f64>)> = Vec::new();
        let surfaces_of = |chosen: &[(DesignPoint, BTreeMap<String, f64>)]| {
            let with: Vec<(DesignPoint, Option<&BTreeMap<String, f64>>)> =
                chosen.iter().map(|(p, q)| (p.clone(), Some(q))).collect();
            let mut s = d.surfaces(&space, &QoiReadings::default(), &with);
            if blind {
                s.misfit.iter_mut().flatten().for_each(|m| m.1 = m.2);
            }
            (with.iter().map(|(p, _)| (p.clone(), None)).collect::<Vec<_>>(), s)
        };
        while chosen.len() < budget {
            let (with, surfaces) = surfaces_of(&chosen);
            let p = d.next(&with, &surfaces).unwrap();
            let q = qoi(&p);
            chosen.push((p, q));
        }
        let (_, surfaces) = surfaces_of(&chosen);
        let largest = largest_over_grid(&surfaces.fitted[0].1, law, 40, |_, _| ());
        (chosen.into_iter().map(|(p, _)| p).collect(), largest)
    }

    /// The largest |error| of `surface` against `law` over an (n + 1) x (n + 1) grid of the
    /// box, relative to the law's spread there; `check` sees each prediction and its place.
    fn largest_over_grid(
        surface: &QoiSurface,
        law: &dyn Fn(f64, f64) -> f64,
        n: usize,
        check: impl Fn(&super::super::surrogate::Prediction, (f64, f64)),
    ) -> f64 {
        largest_over_box(surface, law, (0.1, 0.2), n, check)
    }

    /// [`largest_over_grid`] over the box `lo..hi` in both parameters, the grid evenly spaced in
    /// the parameters' own values (as a user reads the box).
    fn largest_over_box(
        surface: &QoiSurface,
        law: &dyn Fn(f64, f64) -> f64,
        (lo, hi): (f64, f64),
        n: usize,
        check: impl Fn(&super::super::surrogate::Prediction, (f64, f64)),
    ) -> f64 {
        let at = |i: usize| lo + (hi - lo) * i as f64 / n as f64;
        let grid: Vec<(f64, f64)> = (0..=n).flat_map(|i| (0..=n).map(move |j| (at(i), at(j)))).collect();
        let truth: Vec<f64> = grid.iter().map(|(a, b)| law(*a, *b)).collect();
        let spread = holdout::spread(truth.iter().copied());
        grid.iter()
            .zip(&truth)
            .map(|((a, b), t)| {
                let p = surface.predict(&DesignPoint::from_pairs([("f1", *a), ("f2", *b)]).unwrap()).unwrap();
                check(&p, (*a, *b));
                (p.mean - t).abs() / spread
            })
            .fold(0.0f64, f64::max)
    }

    /// A law that is steep along one edge of the box and gentle elsewhere (as tiny's QoIs at low
    /// friction): the standard deviation alone spreads the points evenly; weighed by how wrong
    /// the surface is near each candidate, they gather along that edge and the largest error
    /// falls.
    #[test]
    fn the_initial_points_are_known_before_any_is_solved() {
        // as a study chooses them, its first points done at once (the surfaces wait for all 5)
        let d = design(20);
        let initial = d.initial_points();
        assert_eq!(initial.len(), 5);
        let mut chosen: Vec<(DesignPoint, BTreeMap<String, f64>)> = Vec::new();
        for expected in &initial {
            let view: Vec<(DesignPoint, Option<&BTreeMap<String, f64>>)> =
                chosen.iter().map(|(p, q)| (p.clone(), Some(q))).collect();
            let surfaces = d.surfaces(&space(), &QoiReadings::default(), &view);
            let p = d.next(&view, &surfaces).unwrap();
            assert_eq!(&p, expected);
            chosen.push((p, [("q".to_owned(), 1.0)].into()));
        }
    }

    #[test]
    fn points_go_where_the_surface_is_wrong() {
        let law = |f1: f64, f2: f64| (-(f1 - 0.1) / 0.008).exp() + 0.2 * (f2 - 0.1) / 0.1;
        let ((weighed, weighed_error), (blind, blind_error)) = (drive(&law, 30, false), drive(&law, 30, true));
        let along_the_edge = |points: &[DesignPoint]| points.iter().filter(|p| p.get("f1").unwrap() < 0.12).count();
        let (a, b) = (along_the_edge(&weighed), along_the_edge(&blind));
        eprintln!("weighed: {a} of 30 along the edge, largest error {weighed_error:.4}; blind: {b}, {blind_error:.4}");
        // measured: 8 against 7 of 30 points at f1 < 0.12, largest error 0.0069 against 0.0268
        assert!(a >= b, "{a} against {b} points along the edge");
        assert!(weighed_error < 0.5 * blind_error, "{weighed_error} against {blind_error}");
    }

    #[test]
    fn points_asked_for_at_the_same_time_differ_and_a_full_box_gives_none() {
        let (d, space) = (design(4), space());
        let a = next(&d, &space, &[]).unwrap();
        let b = next(&d, &space, &[(a.clone(), None)]).unwrap();
        assert!(space.normalised_distance(&a, &b) > MIN_SEPARATION);
        // every candidate taken: nothing left to give
        let all: Vec<(DesignPoint, Option<&BTreeMap<String, f64>>)> = (1..=CANDIDATES)
            .map(|i| {
                let (x, y) = (halton(i, 2), halton(i, 3));
                (DesignPoint::from_pairs([("f1", 0.1 + 0.1 * x), ("f2", 0.1 + 0.1 * y)]).unwrap(), None)
            })
            .collect();
        assert_eq!(next(&d, &space, &all), None);
    }

    #[test]
    fn a_target_is_a_share_of_the_spread_and_sets_the_points_tolerance() {
        let space = space();
        let ranges = vec!["f1=0.1:0.2".to_string()];
        let parsed = AdaptiveDesign::parse(&ranges, 30, Some(0.02), &space, 1000).unwrap();
        assert_eq!(parsed.target, Some(0.02));
        for bad in [0.0, -0.01, 1.5, f64::NAN, f64::INFINITY] {
            let e = AdaptiveDesign::parse(&ranges, 30, Some(bad), &space, 1000).unwrap_err();
            assert!(matches!(e, DesignError::Target(TargetError { .. })), "{bad}: {e:?}");
            let e = e.to_string();
            assert!(e.contains("surface accuracy") && e.contains("at most 1"), "{bad}: {e}");
        }
        let e = AdaptiveDesign::parse(&[], 30, Some(0.02), &space, 1000).unwrap_err();
        assert_eq!(e, DesignError::TargetWithoutRanges);
        assert!(e.to_string().contains("target needs the box"), "{e}");
        // the tolerance follows the target, within the bounds
        assert!((point_tolerance(0.02) - 0.02 / 300.0).abs() < 1e-18);
        assert!(point_tolerance(0.002) < point_tolerance(0.02));
        assert_eq!(point_tolerance(1.0), 1.0 / 300.0);
        assert_eq!(point_tolerance(1e-12), MIN_TOLERANCE);
    }

    /// The target is judged on the cross-validated error: a smooth law reaches a loose target
    /// once enough points are done, never before `validated_after`, and a tight one is not.
    #[test]
    fn the_target_is_judged_on_the_cross_validated_error_of_every_qoi() {
        let space = space();
        let law = |p: &DesignPoint| -> BTreeMap<String, f64> {
            let (x, y) = ((p.get("f1").unwrap() - 0.1) / 0.1, (p.get("f2").unwrap() - 0.1) / 0.1);
            [("smooth".to_string(), x + 0.5 * y), ("bent".to_string(), (3.0 * x).sin() * (2.0 * y).cos())].into()
        };
        let mut d = design(40);
        d.target = Some(0.05);
        let (mut chosen, mut values): (Vec<DesignPoint>, Vec<BTreeMap<String, f64>>) = (Vec::new(), Vec::new());
        let mut reached_at = None;
        while chosen.len() < 40 {
            let with: Vec<_> = chosen.iter().cloned().zip(values.iter().map(Some)).collect();
            let surfaces = d.surfaces(&space, &QoiReadings::default(), &with);
            let cv = surfaces.cross_validate();
            if d.target_reached(&cv) {
                reached_at = Some((chosen.len(), cv));
                break;
            }
            if chosen.len() >= 5 && chosen.len() < d.validated_after() {
                assert!(!d.target_reached(&cv));
            }
            let p = d.next(&with, &surfaces).unwrap();
            values.push(law(&p));
            chosen.push(p);
        }
        let (n, cv) = reached_at.expect("a smooth law reaches 5 % within 40 points");
        assert!(n >= d.validated_after(), "{n}");
        assert_eq!(cv.qoi.keys().collect::<Vec<_>>(), ["bent", "smooth"]);
        // by hand: the leave-one-out errors are those of refits without each point; here the
        // plane, which any process fits, is far within it
        // (the box's corners among the points are not judged by their leave-one-out residual,
        // an extrapolation's)
        let lo_hi = |v: f64| (v - 0.1).abs() < 1e-12 || (v - 0.2).abs() < 1e-12;
        let corners = chosen.iter().filter(|p| lo_hi(p.get("f1").unwrap()) && lo_hi(p.get("f2").unwrap())).count();
        assert!(
            cv.qoi["smooth"].mean < 0.01
                && cv.qoi.values().all(|e| e.box_largest <= Some(0.05) && e.count == n - corners),
            "{cv:?}"
        );
        // the estimate over the box is at least the largest error at the points
        assert!(cv.qoi.values().all(|e| e.box_largest >= Some(e.largest)), "{cv:?}");
        // a target tighter than the errors reached is not met
        let tight = AdaptiveDesign { target: Some(cv.qoi["bent"].box_largest.unwrap() / 2.0), ..d.clone() };
        assert!(!tight.target_reached(&cv));
        assert!(!design(40).target_reached(&cv), "no target, never reached");
    }

    /// A force of an interface that chatters over part of the box is no surface there (its last
    /// step samples the contact's ringing): it is set aside with the evidence, the design follows
    /// the other QoIs only, and the study stops once they are within the target, NOT REACHED. A
    /// contact that chatters at fewer than a tenth of the points sets nothing aside.
    #[test]
    fn a_force_of_a_chattering_contact_is_set_aside_and_the_others_decide() {
        let space = space();
        let scene = Scene::parse(
            "dimension = 2\n[time]\nduration = 1e-4\nsteps = 10\n[parameters]\nf1 = { default = 0.1, min = 0.1, max = 0.2 }\n\
             f2 = { default = 0.1, min = 0.1, max = 0.2 }\n[materials.m]\nE = 1e9\nrho = 1000\n\
             [[bodies]]\nname = \"b\"\nmaterial = \"m\"\nsize = [1.0, 0.5]\nelements = [2, 1]\n\
             [[interfaces]]\nname = \"floor\"\na = \"b.y-\"\nb = \"wall\"\nlaw = \"friction\"\nfriction = \"f1\"\n\
             [[qoi]]\nname = \"force\"\nkind = \"force\"\ninterface = \"floor\"\ncomponent = \"y\"\n",
        )
        .unwrap();
        // where f1 + f2 > 0.3 the contact chatters and its last-step force is any value
        let chatters = |p: &DesignPoint| p.get("f1").unwrap() + p.get("f2").unwrap() > 0.3;
        let law = |p: &DesignPoint| -> BTreeMap<String, f64> {
            let (x, y) = ((p.get("f1").unwrap() - 0.1) / 0.1, (p.get("f2").unwrap() - 0.1) / 0.1);
            let ringing = ((x * 997.0 + y * 131.0).sin() * 4e4).fract();
            let force = if chatters(p) { 640.0 * ringing.abs() } else { 200.0 + 3.0 * x };
            [("smooth".to_string(), x + 0.5 * y), ("force".to_string(), force)].into()
        };
        let report = |p: &DesignPoint| ContactActivity {
            interface: "floor".into(),
            friction: 0.3,
            rigid_wall: true,
            contact_nodes: 9,
            first_slip_time: Some(1e-5),
            landings_while_sliding: if chatters(p) { 19 } else { 0 },
            peak_normal_force_ratio: 2.6,
            ill_posed: false,
        };
        let d = AdaptiveDesign { target: Some(0.05), ..design(60) };
        let (mut chosen, mut values, mut contacts) = (Vec::new(), Vec::new(), Vec::<Vec<ContactActivity>>::new());
        let outcome = loop {
            let with: Vec<_> = chosen.iter().cloned().zip(values.iter().map(Some)).collect();
            let readings = QoiReadings::of(&scene).with_contacts(contacts.iter().map(Vec::as_slice));
            let surfaces = d.surfaces(&space, &readings, &with);
            if let Some(o) = d.outcome(&surfaces, false) {
                break o;
            }
            let p = d.next(&with, &surfaces).expect("room in the box");
            values.push(law(&p));
            contacts.push(vec![report(&p)]);
            chosen.push(p);
            assert!(chosen.len() < 60, "the smooth QoI decides well before the budget");
        };
        let cv = &outcome.validation;
        assert!(!outcome.reached, "{cv:?}");
        assert_eq!(cv.set_aside.iter().collect::<Vec<_>>(), ["force"]);
        assert!(cv.refused["force"].starts_with("set aside: interface 'floor' chatters"), "{cv:?}");
        assert_eq!(cv.qoi.keys().collect::<Vec<_>>(), ["smooth"], "judged on the others");
        assert!(cv.qoi["smooth"].box_largest <= Some(0.05) && cv.points >= d.validated_after(), "{cv:?}");
        // the same box where it chatters nowhere: the force is a surface like any other
        let quiet: Vec<Vec<ContactActivity>> =
            chosen.iter().map(|p| vec![ContactActivity { landings_while_sliding: 0, ..report(p) }]).collect();
        let readings = QoiReadings::of(&scene).with_contacts(quiet.iter().map(Vec::as_slice));
        let with: Vec<_> = chosen.iter().cloned().zip(values.iter().map(Some)).collect();
        let cv = d.surfaces(&space, &readings, &with).cross_validate();
        assert!(cv.set_aside.is_empty() && cv.qoi.contains_key("force"), "{cv:?}");
        // chattering at 2 points of many: too few to set it aside
        let mut few = quiet.clone();
        for c in few.iter_mut().take(2) {
            c[0].landings_while_sliding = 19;
        }
        let readings = QoiReadings::of(&scene).with_contacts(few.iter().map(Vec::as_slice));
        assert!(d.surfaces(&space, &readings, &with).set_aside.is_empty());
    }

    /// The target's meaning: every point of the box within it. A slip with a curved stick /
    /// slip edge (a norm: zero beyond the edge, a kink on it) and a bent smooth QoI, to a target
    /// of 2 %: once the study says it is reached, the largest error of each surface over a
    /// 61 x 61 grid is within the target, and the study's own estimate of it within a factor
    /// 1.5 either way (measured: slip 0.54 % estimated 0.74 %, smooth 1.78 % estimated 1.60 %,
    /// at 39 points; the leave-one-out mean, which the target was judged on before, 0.09 % and
    /// 0.48 %).
    #[test]
    fn a_target_bounds_the_largest_error_over_the_box() {
        let space = space();
        let slip = |a: f64, b: f64| (0.3 - a - b + 40.0 * (a - 0.15).powi(2)).max(0.0);
        let bent = |a: f64, b: f64| ((a - 0.1) * 30.0).sin() * ((b - 0.1) * 20.0).cos();
        let d = AdaptiveDesign { target: Some(0.02), ..design(150) };
        let readings = QoiReadings { norms: [("slip".to_string(), vec![])].into(), ..QoiReadings::default() };
        let mut chosen: Vec<(DesignPoint, BTreeMap<String, f64>)> = Vec::new();
        let (surfaces, cv) = loop {
            let with: Vec<_> = chosen.iter().map(|(p, q)| (p.clone(), Some(q))).collect();
            let surfaces = d.surfaces(&space, &readings, &with);
            let cv = surfaces.cross_validate();
            if d.target_reached(&cv) {
                break (surfaces, cv);
            }
            assert!(chosen.len() < 100, "2 % not reached in 100 points: {cv:?}");
            let p = d.next(&with, &surfaces).unwrap();
            let (a, b) = (p.get("f1").unwrap(), p.get("f2").unwrap());
            chosen.push((p, [("slip".to_string(), slip(a, b)), ("bent".to_string(), bent(a, b))].into()));
        };
        for (k, (name, law)) in [("bent", &bent as &dyn Fn(f64, f64) -> f64), ("slip", &slip)].into_iter().enumerate() {
            assert_eq!(surfaces.fitted[k].0, name);
            let largest = largest_over_grid(&surfaces.fitted[k].1, law, 60, |at, place| {
                assert!(name != "slip" || at.mean >= 0.0, "{place:?}: {at:?}");
            });
            let estimate = cv.qoi[name].box_largest.unwrap();
            eprintln!("{name}: at {} points, largest {largest:.4}, estimated {estimate:.4}", chosen.len());
            assert!(largest <= 0.02, "{name}: largest error {largest} over the box, target 0.02");
            // never more than 1.5 x below the truth (the promise); above it, up to 2 x: on smooth
            // laws the estimate runs about 2 x high (median 1.9 over whole runs of the sine), and
            // this test's 1.5 x held before only because a corner error the estimate did not see
            // raised the truth (issue 46's goal of 1.5 x both ways is open)
            assert!(largest <= 1.5 * estimate && estimate <= 2.0 * largest, "{name}: {estimate} against {largest}");
        }
    }

    /// A QoI steepest towards a corner of the box (as slip_A on tiny's prestress x pressure box,
    /// largest where the prestress is least and the pressure most): no Halton candidate reaches
    /// the corner, and without the corners among the candidates the study said "reached 2 %"
    /// at 40 points with 8.6 % at the corner (0.1, 0.2), estimated 1.6 %. With them: reached at
    /// 38 points, the corners among them, largest 0.79 % over a 61 x 61 grid (corners
    /// included), estimated 1.57 %.
    #[test]
    fn a_qoi_steepest_towards_a_corner_is_judged_there_too() {
        let space = space();
        let law = |a: f64, b: f64| (0.2 + (b - 0.1) / 0.1) / (0.08 + (a - 0.1) / 0.1).powf(0.7);
        let d = AdaptiveDesign { target: Some(0.02), ..design(150) };
        let mut chosen: Vec<(DesignPoint, BTreeMap<String, f64>)> = Vec::new();
        let (surfaces, cv) = loop {
            let with: Vec<_> = chosen.iter().map(|(p, q)| (p.clone(), Some(q))).collect();
            let surfaces = d.surfaces(&space, &QoiReadings::default(), &with);
            let cv = surfaces.cross_validate();
            if d.target_reached(&cv) {
                break (surfaces, cv);
            }
            assert!(chosen.len() < 100, "2 % not reached in 100 points: {cv:?}");
            let p = d.next(&with, &surfaces).unwrap();
            let q = law(p.get("f1").unwrap(), p.get("f2").unwrap());
            chosen.push((p, [("q".to_string(), q)].into()));
        };
        let largest = largest_over_grid(&surfaces.fitted[0].1, &law, 60, |_, _| ());
        let estimate = cv.qoi["q"].box_largest.unwrap();
        eprintln!("at {} points, largest {largest:.4}, estimated {estimate:.4}", chosen.len());
        assert!(largest <= 0.02, "largest error {largest} over the box, target 0.02 (estimated {estimate})");
        assert!(largest <= 1.5 * estimate, "{estimate} against {largest}");
        let corner = DesignPoint::from_pairs([("f1", 0.1), ("f2", 0.2)]).unwrap();
        assert!(chosen.iter().any(|(p, _)| space.normalised_distance(p, &corner) < 1e-9), "the steep corner solved");
    }

    /// A study to `target` of `law` over `lo..hi` in both parameters (named f1, f2), budget
    /// 150: the points it took, the largest error of its surface over a 61 x 61 grid of the box
    /// ([`largest_over_box`]), and its estimate.
    fn to_target(law: &dyn Fn(f64, f64) -> f64, lo: f64, hi: f64, target: f64) -> (usize, f64, f64) {
        let range = |name: &str| ParameterRange { name: name.into(), default: lo, min: lo, max: hi, declared: true };
        let space = ParameterSpace::new(vec![range("f1"), range("f2")]);
        let ranges = vec![("f1".into(), lo, hi), ("f2".into(), lo, hi)];
        let d = AdaptiveDesign { ranges, budget: 150, target: Some(target) };
        let mut chosen: Vec<(DesignPoint, BTreeMap<String, f64>)> = Vec::new();
        let (surfaces, cv) = loop {
            let with: Vec<_> = chosen.iter().map(|(p, q)| (p.clone(), Some(q))).collect();
            let surfaces = d.surfaces(&space, &QoiReadings::default(), &with);
            let cv = surfaces.cross_validate();
            if d.target_reached(&cv) || chosen.len() == d.budget {
                break (surfaces, cv);
            }
            let p = d.next(&with, &surfaces).unwrap();
            let q = law(p.get("f1").unwrap(), p.get("f2").unwrap());
            chosen.push((p, [("q".to_string(), q)].into()));
        };
        let largest = largest_over_box(&surfaces.fitted[0].1, law, (lo, hi), 60, |_, _| ());
        (chosen.len(), largest, cv.qoi["q"].box_largest.unwrap())
    }

    /// A response that turns at the low end of a friction range spanning 20 x (as tiny's slips
    /// over 0.02..0.4, the box kept aside for issue 46): smooth in the logarithm of the friction,
    /// steep near 0.02 and flat near 0.4 in the friction itself. Over 0.02..0.4 the ranges are
    /// logarithmic ([`Axis`]); the same law over the shifted range 0..0.38 (which starts at zero:
    /// linear) is the same problem on a linear scale. Measured: the logarithmic design reached
    /// 2 % at 33 points, largest 0.73 % over the box (estimated 1.79 %); the linear one said
    /// "reached" at 135 points with 2.74 % (estimated 1.94 %).
    #[test]
    fn a_range_over_a_decade_is_sampled_on_its_logarithm() {
        let turning = |a: f64, b: f64| (2.0 * (a / 0.02).ln()).sin() * (1.0 + 0.3 * (b / 0.02).ln());
        let (log_points, log_largest, log_estimate) = to_target(&turning, 0.02, 0.4, 0.02);
        let shifted = |a: f64, b: f64| turning(a + 0.02, b + 0.02);
        let (linear_points, linear_largest, linear_estimate) = to_target(&shifted, 0.0, 0.38, 0.02);
        eprintln!(
            "logarithmic: {log_points} points, largest {log_largest:.4} estimated {log_estimate:.4}; \
             linear: {linear_points} points, largest {linear_largest:.4} estimated {linear_estimate:.4}"
        );
        assert!(log_largest <= 0.02, "largest error {log_largest} over the box, target 0.02 ({log_points} points)");
        assert!(log_largest <= 1.5 * log_estimate, "{log_estimate} against {log_largest}");
        assert!(2 * log_points <= linear_points, "{log_points} points on the logarithm, {linear_points} linear");
    }

    /// A norm whose components the scene reports is scored and judged through them; the
    /// components are not judged on their own.
    #[test]
    fn a_norm_is_read_from_its_components_and_they_are_not_judged_alone() {
        let scene = crate::study::surrogate::tests::tiny_with_slip_a_components();
        let readings = QoiReadings::of(&scene);
        let space = ParameterSpace::from_scene(&scene);
        let d = design(20);
        let chosen: Vec<DesignPoint> = (0..8)
            .map(|i| {
                DesignPoint::from_pairs([
                    ("f1", 0.1 + 0.0125 * i as f64),
                    ("f2", 0.1 + 0.1 * ((i * 3) % 8) as f64 / 7.0),
                ])
                .unwrap()
            })
            .collect();
        let values: Vec<BTreeMap<String, f64>> = chosen
            .iter()
            .map(|p| {
                let (x, y) = (p.get("f1").unwrap() - 0.137, 1e-9 * p.get("f2").unwrap());
                [("slip_A", x.hypot(y)), ("slip_A_x", x), ("slip_A_y", y), ("slip_B", x.abs() * 2.0)]
                    .iter()
                    .map(|(n, v)| (n.to_string(), *v))
                    .collect()
            })
            .collect();
        let with: Vec<_> = chosen.iter().cloned().zip(values.iter().map(Some)).collect();
        let surfaces = d.surfaces(&space, &readings, &with);
        assert_eq!(surfaces.qois().collect::<Vec<_>>(), [("slip_A", true), ("slip_B", false)]);
        assert_eq!(surfaces.cross_validate().qoi.keys().collect::<Vec<_>>(), ["slip_A", "slip_B"]);
        // without the scene's readings every QoI stands alone
        let plain = d.surfaces(&space, &QoiReadings::default(), &with);
        assert_eq!(plain.qois().count(), 4);
    }
}
