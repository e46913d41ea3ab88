//! The parameter space of a study (docs/method.md 4): the scene's named parameters with their ranges,
//! the normalised distance between design points, and the grids a study sweeps
//! (`f1=0.10:0.20:11`, lists `f1=0.1,0.15,0.2`, Latin hypercube samples `f1=lhs:20:7`).

use crate::text::{MAX_NAME_CHARS, excerpt};
use std::collections::BTreeMap;

use rand::Rng;
use rand::SeedableRng;
use rand::seq::SliceRandom;
use serde::{Deserialize, Serialize};

use crate::point::DesignPoint;
use crate::point::ParameterError;
use crate::scene::Scene;

/// One named parameter of the space.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ParameterRange {
    pub name: String,
    pub default: f64,
    /// the scene's `min`, else its default
    pub min: f64,
    /// the scene's `max`, else its default
    pub max: f64,
    /// false when the scene gives no `min`/`max` (the range is then the default alone)
    pub declared: bool,
}

impl ParameterRange {
    /// The length distances are divided by: `max - min`, or 1 for a zero-width range (the raw
    /// difference then counts, so that distinct values never look identical).
    pub fn scale(&self) -> f64 {
        let w = self.max - self.min;
        if w > 0.0 { w } else { 1.0 }
    }
}

/// A range that starts above zero and reaches this many times its start is scaled by its
/// logarithm ([`Axis`]).
pub const LOG_SPAN: f64 = 10.0;

/// How a parameter's values map to the unit box that response surfaces and adaptive designs
/// work in: `(x - lo) / (hi - lo)`, or, over a range that starts above zero and spans
/// [`LOG_SPAN`] or more, `ln(x / lo) / ln(hi / lo)`. Over such a range a response changes most at
/// its low end (a friction coefficient over 0.02..0.4: the slips' direction turns within 0.02 of
/// the lowest friction), where a linear scale leaves its coarsest cells: measured on the box kept
/// aside for issue 46, the largest errors 2-4 x smaller (docs/surrogate.md, "Ranges over a
/// decade"). Warm starts keep the parameter's own scale ([`ParameterRange::scale`]): they
/// extrapolate interface fields, which follow the parameter itself (a bar's fields are
/// proportional to its impact velocity).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Axis {
    lo: f64,
    hi: f64,
    /// `hi - lo`, or `ln(hi / lo)` on a logarithmic axis; 1 for a zero-width range
    width: f64,
    logarithmic: bool,
}

impl Axis {
    /// The axis of `lo..hi`: logarithmic when `lo > 0` and `hi >= LOG_SPAN * lo`. A zero-width
    /// range is linear of width 1 (distinct values never look identical).
    pub fn new(lo: f64, hi: f64) -> Self {
        if lo > 0.0 && hi >= LOG_SPAN * lo && hi.is_finite() {
            // (logarithms apart, not of the ratio: 1e300 / 5e-324 overflows)
            Self { lo, hi, width: hi.ln() - lo.ln(), logarithmic: true }
        } else {
            Self { lo, hi, width: if hi > lo { hi - lo } else { 1.0 }, logarithmic: false }
        }
    }

    /// The axis of a scene's range.
    pub fn of(range: &ParameterRange) -> Self {
        Self::new(range.min, range.max)
    }

    pub fn is_logarithmic(&self) -> bool {
        self.logarithmic
    }

    /// `x`'s coordinate: 0 at `lo`, 1 at `hi`, increasing. Below `lo` a logarithmic axis goes on
    /// along its tangent at `lo`, so that a value at or below zero (outside the range, where a
    /// surface widened to its points may be asked) still has a finite coordinate.
    pub fn unit(&self, x: f64) -> f64 {
        match self.logarithmic {
            false => (x - self.lo) / self.width,
            true if x >= self.lo => (x.ln() - self.lo.ln()) / self.width,
            true => (x - self.lo) / (self.lo * self.width),
        }
    }

    /// The value at coordinate `u` ([`Self::unit`]'s inverse); within `lo..=hi` for `u` in
    /// `[0, 1]`, the ends exact.
    pub fn value(&self, u: f64) -> f64 {
        if u == 1.0 && self.hi > self.lo {
            return self.hi;
        }
        let x = match self.logarithmic {
            false => self.lo + u * self.width,
            true if u >= 0.0 => (self.lo.ln() + u * self.width).exp(),
            true => self.lo + u * self.lo * self.width,
        };
        if (0.0..=1.0).contains(&u) && self.hi > self.lo { x.clamp(self.lo, self.hi) } else { x }
    }
}

/// Errors of the parameter space and of grid specifications; each names the offending spec.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SpaceError {
    #[error("--grid {spec}: expected NAME=SPEC (START:STOP:COUNT, V1,V2,..., or lhs:N:SEED[:LO:HI])")]
    Malformed { spec: String },
    #[error("--grid {spec}: no parameter '{name}' in the scene (declared: {declared})")]
    UnknownParameter { spec: String, name: String, declared: String },
    #[error("--grid {spec}: '{value}' is not a finite number")]
    NotANumber { spec: String, value: String },
    #[error("--grid {spec}: {message}")]
    Invalid { spec: String, message: String },
    #[error("--grid {spec}: parameter '{name}' is swept twice")]
    Duplicate { spec: String, name: String },
    #[error("the study has no design points (give at least one --grid NAME=SPEC)")]
    EmptyGrid,
    #[error(
        "the grid gives {count} design points, more than the {max} accepted (give fewer values or split the study)"
    )]
    TooManyPoints { count: String, max: usize },
    #[error("point {point}: parameter '{name}' is not in the scene")]
    PointUnknownParameter { point: String, name: String },
    #[error(transparent)]
    Point(#[from] ParameterError),
}

/// The named parameters of a scene with their ranges, in name order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ParameterSpace {
    parameters: Vec<ParameterRange>,
}

impl ParameterSpace {
    /// Every `[parameters]` entry of the scene; a parameter without `min`/`max` gets the
    /// zero-width range of its default.
    pub fn from_scene(scene: &Scene) -> Self {
        let parameters = scene
            .parameters
            .iter()
            .map(|(name, p)| {
                let declared = p.min.is_some() && p.max.is_some();
                let min = p.min.unwrap_or(p.default);
                let max = p.max.unwrap_or(p.default).max(min);
                ParameterRange { name: name.clone(), default: p.default, min, max, declared }
            })
            .collect();
        Self { parameters }
    }

    /// A space from explicit ranges (tests, and services that know no scene).
    pub fn new(mut parameters: Vec<ParameterRange>) -> Self {
        parameters.sort_by(|a, b| a.name.cmp(&b.name));
        Self { parameters }
    }

    pub fn parameters(&self) -> &[ParameterRange] {
        &self.parameters
    }

    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.parameters.iter().map(|p| p.name.as_str())
    }

    /// Number of parameters (the dimension of the space).
    pub fn dimension(&self) -> usize {
        self.parameters.len()
    }

    pub fn range(&self, name: &str) -> Option<&ParameterRange> {
        self.parameters.iter().find(|p| p.name == name)
    }

    /// The point with every parameter at its default.
    pub fn defaults(&self) -> DesignPoint {
        DesignPoint::from_pairs(self.parameters.iter().map(|p| (p.name.as_str(), p.default)))
            .expect("a space's parameters are a parsed scene's: plain names, finite defaults, at most MAX_PARAMETERS")
    }

    /// `point` with every parameter it lacks at its default; refuses names not in the space.
    pub fn complete(&self, point: &DesignPoint) -> Result<DesignPoint, SpaceError> {
        if let Some(name) = point.names().find(|name| self.range(name).is_none()) {
            return Err(SpaceError::PointUnknownParameter { point: point.to_string(), name: name.into() });
        }
        Ok(self.defaults().overlaid(point)?)
    }

    /// Coordinates of a point in the unit-scaled space: (value - min) / scale per parameter, in
    /// name order; a parameter the point lacks is at its default.
    pub fn normalised_coordinates(&self, point: &DesignPoint) -> Vec<f64> {
        self.parameters.iter().map(|p| (point.get(&p.name).unwrap_or(p.default) - p.min) / p.scale()).collect()
    }

    /// Euclidean distance with each parameter's difference divided by its range (a zero-width
    /// range counts as 1); parameters a point lacks are at their defaults.
    pub fn normalised_distance(&self, a: &DesignPoint, b: &DesignPoint) -> f64 {
        self.parameters
            .iter()
            .map(|p| {
                let d = (a.get(&p.name).unwrap_or(p.default) - b.get(&p.name).unwrap_or(p.default)) / p.scale();
                d * d
            })
            .sum::<f64>()
            .sqrt()
    }
}

/// How one parameter is swept.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum AxisValues {
    /// explicit values `V1,V2,...`
    Values(Vec<f64>),
    /// `START:STOP:COUNT`, evenly spaced; expanded only once the study's size is accepted
    Range { start: f64, stop: f64, count: usize },
    /// a Latin hypercube of `samples` points drawn with `seed`; parameters with the same
    /// (samples, seed) form one joint hypercube
    Lhs { samples: usize, seed: u64, low: f64, high: f64 },
}

/// Characters of a grid spec that an error message repeats.
const MAX_SPEC_ECHO: usize = 120;

/// One `--grid NAME=SPEC`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GridAxis {
    pub name: String,
    pub values: AxisValues,
    /// the text it was parsed from, for messages
    pub spec: String,
}

/// Rounds to 12 significant digits so `0.1:0.2:11` gives 0.11, not 0.11000000000000001.
fn tidy(v: f64) -> f64 {
    if v == 0.0 || !v.is_finite() {
        return v;
    }
    format!("{v:.11e}").parse().unwrap_or(v)
}

fn number(spec: &str, s: &str) -> Result<f64, SpaceError> {
    let v: f64 = s.trim().parse().map_err(|_| SpaceError::NotANumber { spec: spec.into(), value: s.trim().into() })?;
    if !v.is_finite() {
        return Err(SpaceError::NotANumber { spec: spec.into(), value: s.trim().into() });
    }
    Ok(v)
}

fn integer(spec: &str, what: &str, s: &str) -> Result<u64, SpaceError> {
    s.trim().parse().map_err(|_| SpaceError::Invalid {
        spec: spec.into(),
        message: format!("{what} '{}' is not an integer", s.trim()),
    })
}

impl GridAxis {
    /// Parses `NAME=START:STOP:COUNT` (COUNT >= 1 evenly spaced values, START <= STOP; COUNT 1
    /// gives START), `NAME=V1,V2,...` (a single value is a list of one) or
    /// `NAME=lhs:N:SEED[:LO:HI]` (a Latin hypercube over [LO, HI], by default the parameter's
    /// range in `space`), checking the name against `space`.
    pub fn parse(spec: &str, space: &ParameterSpace) -> Result<Self, SpaceError> {
        let full = spec;
        // errors echo the spec: a bounded excerpt of it, whatever a client sent
        let spec = &excerpt(full, MAX_SPEC_ECHO);
        let malformed = || SpaceError::Malformed { spec: spec.into() };
        let invalid = |message: String| SpaceError::Invalid { spec: spec.into(), message };
        let (name, rhs) = full.split_once('=').ok_or_else(malformed)?;
        let (name, rhs) = (name.trim(), rhs.trim());
        if name.is_empty() || rhs.is_empty() {
            return Err(malformed());
        }
        let Some(range) = space.range(name) else {
            return Err(SpaceError::UnknownParameter {
                spec: spec.into(),
                name: excerpt(name, MAX_NAME_CHARS),
                declared: space.names().collect::<Vec<_>>().join(", "),
            });
        };
        let values = if let Some(lhs) = rhs.strip_prefix("lhs:") {
            let parts: Vec<&str> = lhs.split(':').collect();
            if parts.len() != 2 && parts.len() != 4 {
                return Err(malformed());
            }
            let samples = integer(spec, "sample count", parts[0])? as usize;
            if samples == 0 {
                return Err(invalid("a Latin hypercube needs at least 1 sample".into()));
            }
            let seed = integer(spec, "seed", parts[1])?;
            let (low, high) = if parts.len() == 4 {
                (number(spec, parts[2])?, number(spec, parts[3])?)
            } else {
                if !range.declared {
                    return Err(invalid(format!(
                        "parameter '{name}' has no min/max in the scene: give the range, lhs:N:SEED:LO:HI"
                    )));
                }
                (range.min, range.max)
            };
            if low > high {
                return Err(invalid(format!("range [{low}, {high}] is empty (LO > HI)")));
            }
            AxisValues::Lhs { samples, seed, low, high }
        } else if rhs.contains(':') {
            let parts: Vec<&str> = rhs.split(':').collect();
            if parts.len() != 3 {
                return Err(malformed());
            }
            let (start, stop) = (number(spec, parts[0])?, number(spec, parts[1])?);
            let count = integer(spec, "count", parts[2])? as usize;
            if count == 0 {
                return Err(invalid("COUNT must be at least 1".into()));
            }
            if start > stop {
                return Err(invalid(format!("START {start} is above STOP {stop}")));
            }
            AxisValues::Range { start, stop, count }
        } else {
            let values = rhs.split(',').map(|s| number(spec, s)).collect::<Result<Vec<_>, _>>()?;
            AxisValues::Values(values)
        };
        Ok(Self { name: name.into(), values, spec: spec.into() })
    }
}

impl AxisValues {
    /// How many values this axis contributes (a hypercube's samples once per group).
    fn count(&self) -> usize {
        match self {
            AxisValues::Values(v) => v.len(),
            AxisValues::Range { count, .. } => *count,
            AxisValues::Lhs { samples, .. } => *samples,
        }
    }

    fn expand(&self) -> Vec<f64> {
        match *self {
            AxisValues::Values(ref v) => v.clone(),
            AxisValues::Range { start, count: 1, .. } => vec![start],
            AxisValues::Range { start, stop, count } => {
                (0..count)
                    .map(|i| {
                        if i + 1 == count { stop } else { tidy(start + (stop - start) * i as f64 / (count - 1) as f64) }
                    })
                    .collect()
            }
            AxisValues::Lhs { .. } => unreachable!("hypercubes are drawn per group"),
        }
    }
}

/// Most design points a study may have by default (the coordinator's `--max-points` and the
/// local study command use it; docs/performance.md has the bytes each point costs).
pub const DEFAULT_MAX_POINTS: usize = 100_000;

/// The factors of the cartesian product: each plain axis alone, each (samples, seed) hypercube
/// group once; checks that no parameter is swept twice.
fn factors(axes: &[GridAxis]) -> Result<Vec<Vec<&GridAxis>>, SpaceError> {
    if axes.is_empty() {
        return Err(SpaceError::EmptyGrid);
    }
    let mut out: Vec<Vec<&GridAxis>> = Vec::new();
    for (i, a) in axes.iter().enumerate() {
        if axes[..i].iter().any(|b| b.name == a.name) {
            return Err(SpaceError::Duplicate { spec: a.spec.clone(), name: a.name.clone() });
        }
        let group = match a.values {
            AxisValues::Lhs { samples, seed, .. } => out.iter_mut().find(
                |f| matches!(f[0].values, AxisValues::Lhs { samples: n, seed: s, .. } if n == samples && s == seed),
            ),
            _ => None,
        };
        match group {
            Some(f) => f.push(a),
            None => out.push(vec![a]),
        }
    }
    Ok(out)
}

/// Indices of `coords` in a spread-out order, at most `n`: the one nearest their centre first,
/// then each time the one farthest (Euclidean) from all those already taken, the last of equals.
/// O(len x n): each point's distance to the order is kept as it grows.
pub fn farthest_first(coords: &[Vec<f64>], n: usize) -> Vec<usize> {
    if coords.is_empty() {
        return Vec::new();
    }
    let dim = coords[0].len();
    let centre: Vec<f64> = (0..dim).map(|d| coords.iter().map(|c| c[d]).sum::<f64>() / coords.len() as f64).collect();
    let distance = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>().sqrt();
    let first = (0..coords.len())
        .min_by(|&a, &b| distance(&coords[a], &centre).total_cmp(&distance(&coords[b], &centre)))
        .unwrap_or(0);
    let mut order = vec![first];
    // distance of each point to the order; None once taken
    let mut nearest: Vec<Option<f64>> = coords.iter().map(|c| Some(distance(c, &coords[first]))).collect();
    nearest[first] = None;
    while order.len() < n.min(coords.len()) {
        let mut farthest: Option<(usize, f64)> = None;
        for (i, d) in nearest.iter().enumerate() {
            if let Some(d) = *d
                && farthest.is_none_or(|(_, f)| d.total_cmp(&f).is_ge())
            {
                farthest = Some((i, d));
            }
        }
        let Some((next, _)) = farthest else { break };
        order.push(next);
        nearest[next] = None;
        for (i, d) in nearest.iter_mut().enumerate() {
            if let Some(d) = d {
                *d = d.min(distance(&coords[i], &coords[next]));
            }
        }
    }
    order
}

/// The number of design points the axes give, computed from the specs alone (nothing is
/// allocated), or None when it does not fit in a usize.
pub fn point_count(axes: &[GridAxis]) -> Result<Option<usize>, SpaceError> {
    Ok(count_of(&factors(axes)?))
}

fn count_of(factors: &[Vec<&GridAxis>]) -> Option<usize> {
    factors.iter().try_fold(1usize, |n, f| n.checked_mul(f[0].values.count()))
}

/// The design points of a study: the cartesian product of the axes, in lexicographic order of
/// the axes as given (the first axis varies slowest). Parameters with `lhs` specs of the same
/// (N, SEED) form one joint N-point Latin hypercube, which is one factor of the product. Points
/// hold the swept parameters only ([`ParameterSpace::complete`] adds the defaults). A grid of
/// more than `max_points` points is refused before any is built.
pub fn design_points(axes: &[GridAxis], max_points: usize) -> Result<Vec<DesignPoint>, SpaceError> {
    let factors = factors(axes)?;
    match count_of(&factors) {
        Some(n) if n <= max_points => {}
        n => {
            let count = n.map_or_else(|| "more than 2^64".to_string(), |n| n.to_string());
            return Err(SpaceError::TooManyPoints { count, max: max_points });
        }
    }
    let mut points = vec![DesignPoint::new()];
    for factor in factors {
        let partial: Vec<DesignPoint> = match factor[0].values {
            AxisValues::Lhs { samples, seed, .. } => latin_hypercube(&factor, samples, seed)?,
            ref values => values
                .expand()
                .into_iter()
                .map(|v| DesignPoint::from_pairs([(factor[0].name.clone(), v)]))
                .collect::<Result<_, _>>()?,
        };
        let mut next = Vec::with_capacity(points.len() * partial.len());
        for p in &points {
            for q in &partial {
                next.push(p.clone().overlaid(q)?);
            }
        }
        points = next;
    }
    if points.is_empty() || points.iter().all(DesignPoint::is_empty) {
        return Err(SpaceError::EmptyGrid);
    }
    Ok(points)
}

/// A Latin hypercube: each parameter's range cut into `samples` equal strata, one sample drawn
/// uniformly in each stratum, the strata permuted independently per parameter (ChaCha8 seeded
/// with `seed`, so the same spec gives the same points on every machine).
fn latin_hypercube(members: &[&GridAxis], samples: usize, seed: u64) -> Result<Vec<DesignPoint>, ParameterError> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut points = vec![DesignPoint::new(); samples];
    for a in members {
        let AxisValues::Lhs { low, high, .. } = a.values else { continue };
        let mut strata: Vec<usize> = (0..samples).collect();
        strata.shuffle(&mut rng);
        for (p, s) in points.iter_mut().zip(strata) {
            let u: f64 = rng.random();
            p.insert(a.name.clone(), tidy(low + (high - low) * (s as f64 + u) / samples as f64))?;
        }
    }
    Ok(points)
}

/// Why the design points of a submission ([`submission_points`], [`check_grid`]) are refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PointsError {
    /// An explicit list longer than the study may be.
    #[error("{count} points, more than the {max} accepted")]
    TooManyListed { count: usize, max: usize },
    /// A grid spec, the grid's size, or a point's parameter the scene does not have.
    #[error(transparent)]
    Space(#[from] SpaceError),
    #[error("empty study: the grid or point list gives no design point")]
    Empty,
    /// Point `index` (`point`, shown) leaves out some of the `swept` parameters.
    #[error("point {index} ({point}) does not give every swept parameter ({})", swept.join(", "))]
    Incomplete { index: usize, point: String, swept: Vec<String> },
    #[error("point {index}: {name} = {value} is outside the scene's range [{min}, {max}]")]
    OutsideScene { index: usize, name: String, value: f64, min: f64, max: f64 },
    #[error("the grid gives more than 2^64 design points")]
    Uncountable,
}

/// The design points of a study submission: a grid (`NAME=SPEC` axes, Cartesian product) or an
/// explicit list, each checked against the scene's parameters and their declared ranges, at most
/// `max_points` of them (counted before any is built). Returns the swept names (sorted) and the
/// points (swept parameters only). The coordinator's SubmitStudy and the CLI's checks use it.
pub fn submission_points(
    scene: &Scene,
    grid: &[String],
    points: &[DesignPoint],
    max_points: usize,
) -> Result<(Vec<String>, Vec<DesignPoint>), PointsError> {
    let space = ParameterSpace::from_scene(scene);
    let design: Vec<DesignPoint> = if grid.is_empty() {
        if points.len() > max_points {
            return Err(PointsError::TooManyListed { count: points.len(), max: max_points });
        }
        points.to_vec()
    } else {
        let axes = grid.iter().map(|spec| GridAxis::parse(spec, &space)).collect::<Result<Vec<_>, _>>()?;
        design_points(&axes, max_points)?
    };
    if design.is_empty() {
        return Err(PointsError::Empty);
    }
    let mut names: Vec<String> = design.iter().flat_map(|p| p.iter().map(|(k, _)| k.to_owned())).collect();
    names.sort();
    names.dedup();
    for (i, p) in design.iter().enumerate() {
        space.complete(p)?;
        if p.len() != names.len() {
            return Err(PointsError::Incomplete { index: i, point: p.to_string(), swept: names });
        }
        for (name, value) in p.iter() {
            let range = space.range(name).expect("complete() checked the name");
            if range.declared && !(range.min..=range.max).contains(&value) {
                let (name, min, max) = (name.to_owned(), range.min, range.max);
                return Err(PointsError::OutsideScene { index: i, name, value, min, max });
            }
        }
    }
    Ok((names, design))
}

/// Checks a grid against its scene as a submission is checked, and returns the swept parameters
/// and the number of design points (the CLI refuses a bad grid before it connects). The points
/// are counted from the specs; a grid above [`DEFAULT_MAX_POINTS`] is not expanded here (the
/// coordinator's own `--max-points` decides).
pub fn check_grid(scene: &Scene, grid: &[String]) -> Result<(Vec<String>, usize), PointsError> {
    let space = ParameterSpace::from_scene(scene);
    let axes = grid.iter().map(|spec| GridAxis::parse(spec, &space)).collect::<Result<Vec<_>, _>>()?;
    match point_count(&axes)? {
        Some(n) if n > DEFAULT_MAX_POINTS => {
            let mut names: Vec<String> = axes.into_iter().map(|a| a.name).collect();
            names.sort();
            Ok((names, n))
        }
        None => Err(PointsError::Uncountable),
        Some(_) => submission_points(scene, grid, &[], DEFAULT_MAX_POINTS).map(|(names, points)| (names, points.len())),
    }
}

/// Why a slice of a study holds no point, for people: `no point has f2 = 0.13 (f2 takes 0.1,
/// 0.15, 0.2)` for the first fixed parameter whose value no point has (by
/// [`crate::text::same_parameter`]), else that the values are never found together.
pub fn slice_miss<'a>(fixed: &[(String, f64)], points: impl IntoIterator<Item = &'a BTreeMap<String, f64>>) -> String {
    use crate::text::{parameter, same_parameter};
    let points: Vec<&BTreeMap<String, f64>> = points.into_iter().collect();
    for (name, value) in fixed {
        let mut values: Vec<f64> = points.iter().filter_map(|p| p.get(name).copied()).collect();
        if values.iter().any(|&v| same_parameter(v, *value)) {
            continue;
        }
        values.sort_by(f64::total_cmp);
        values.dedup();
        const SHOWN: usize = 20;
        let mut list: Vec<String> = values.iter().take(SHOWN).map(|&v| parameter(v)).collect();
        if values.len() > SHOWN {
            list.push(format!("... ({} more)", values.len() - SHOWN));
        }
        let takes =
            if list.is_empty() { "no point has it".to_owned() } else { format!("{name} takes {}", list.join(", ")) };
        return format!("no point has {name} = {} ({takes})", parameter(*value));
    }
    let all = fixed.iter().map(|(n, v)| format!("{n} = {}", parameter(*v))).collect::<Vec<_>>().join(" and ");
    format!("no point has {all} together")
}

/// Tests' box: f1 and f2 over [min, max], each defaulting to min.
#[cfg(test)]
pub(crate) fn friction_box(min: f64, max: f64) -> ParameterSpace {
    ParameterSpace::new(
        ["f1", "f2"]
            .iter()
            .map(|n| ParameterRange { name: n.to_string(), default: min, min, max, declared: true })
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_range_over_a_decade_above_zero_is_logarithmic_and_its_map_inverts() {
        let log = Axis::new(0.02, 0.4);
        assert!(log.is_logarithmic());
        assert_eq!((log.unit(0.02), log.value(0.0), log.value(1.0)), (0.0, 0.02, 0.4));
        assert!((log.unit(0.4) - 1.0).abs() < 1e-15);
        // equal ratios, equal steps: the geometric middle is the middle
        assert!((log.unit((0.02f64 * 0.4).sqrt()) - 0.5).abs() < 1e-12);
        for u in [0.0, 0.1, 0.37, 0.5, 0.99, 1.0, 1.3] {
            assert!((log.unit(log.value(u)) - u).abs() < 1e-12, "{u}");
        }
        for u in (0..=100).map(|i| i as f64 / 100.0) {
            assert!((0.02..=0.4).contains(&log.value(u)), "{u}: {}", log.value(u));
        }
        // below the range it goes on along its tangent: finite, increasing, inverted, through zero
        let below = [-1.0, -0.01, 0.0, 0.01, 0.019, 0.02, 0.021];
        let units: Vec<f64> = below.iter().map(|x| log.unit(*x)).collect();
        assert!(units.windows(2).all(|w| w[0] < w[1]) && units.iter().all(|u| u.is_finite()), "{units:?}");
        for (x, u) in below.iter().zip(&units) {
            assert!((log.value(*u) - x).abs() < 1e-12, "{x}");
        }
        // linear: from zero, under a decade, zero width (which counts the raw difference)
        for (lo, hi) in [(0.0, 5e-4), (0.1, 0.2), (0.05, 0.49), (-1.0, 10.0)] {
            let a = Axis::new(lo, hi);
            assert!(!a.is_logarithmic(), "{lo}..{hi}");
            assert!((a.unit((lo + hi) / 2.0) - 0.5).abs() < 1e-12);
        }
        let point = Axis::new(3.0, 3.0);
        assert!(!point.is_logarithmic());
        assert_eq!((point.unit(4.0), point.value(-2.0)), (1.0, 1.0));
        assert!(Axis::new(0.1, 1.0).is_logarithmic() && !Axis::new(0.1, 0.999).is_logarithmic());
        // the extremes of a scene's finite ranges: every coordinate finite, the map inverts
        let wide = Axis::new(5e-324, 1e308);
        for x in [5e-324, 1e-300, 1.0, 1e300, 1e308] {
            let u = wide.unit(x);
            assert!(u.is_finite() && (0.0..=1.0).contains(&u), "{x}: {u}");
            assert!((wide.value(u) / x - 1.0).abs() < 1e-9 || x == 5e-324, "{x}: {}", wide.value(u));
        }
    }

    #[test]
    fn a_slice_without_points_says_which_values_there_are() {
        let points: Vec<BTreeMap<String, f64>> = [(0.1, 0.1), (0.1, 0.15), (0.2, 0.2)]
            .iter()
            .map(|&(a, b)| [("f1".to_owned(), a), ("f2".to_owned(), b)].into())
            .collect();
        let miss = |fixed: &[(&str, f64)]| {
            let fixed: Vec<(String, f64)> = fixed.iter().map(|(n, v)| (n.to_string(), *v)).collect();
            slice_miss(&fixed, &points)
        };
        assert_eq!(miss(&[("f2", 0.13)]), "no point has f2 = 0.13 (f2 takes 0.1, 0.15, 0.2)");
        assert_eq!(miss(&[("f1", 0.1), ("f2", 0.2)]), "no point has f1 = 0.1 and f2 = 0.2 together");
    }

    fn space() -> ParameterSpace {
        ParameterSpace::new(vec![
            ParameterRange { name: "f1".into(), default: 0.1, min: 0.1, max: 0.2, declared: true },
            ParameterRange { name: "f2".into(), default: 0.1, min: 0.1, max: 0.2, declared: true },
            ParameterRange { name: "p".into(), default: 5.0, min: 5.0, max: 5.0, declared: false },
        ])
    }

    #[test]
    fn range_spec_gives_evenly_spaced_tidy_values() {
        let a = GridAxis::parse("f1=0.10:0.20:11", &space()).unwrap();
        let v: Vec<f64> = design_points(&[a], 11).unwrap().iter().map(|p| p.get("f1").unwrap()).collect();
        assert_eq!(v.len(), 11);
        assert_eq!(v[1], 0.11);
        assert_eq!(v[3], 0.13);
        assert_eq!(v[10], 0.2);
        let a = GridAxis::parse("f1=0.15:0.2:1", &space()).unwrap();
        assert_eq!(a.values.expand(), vec![0.15]);
        let a = GridAxis::parse("f2=0.1, 0.15,0.2", &space()).unwrap();
        assert_eq!(a.values, AxisValues::Values(vec![0.1, 0.15, 0.2]));
    }

    #[test]
    fn bad_specs_are_named() {
        let s = space();
        for (spec, needle) in [
            ("f1=0.2:0.1:0", "COUNT"),
            ("f1=0.2:0.1:3", "above STOP"),
            ("f1=0.1:nan:3", "not a finite number"),
            ("f1=NaN", "not a finite number"),
            ("f1=inf", "not a finite number"),
            ("f1=0.1:0.2", "expected NAME=SPEC"),
            ("f1", "expected NAME=SPEC"),
            ("f1=", "expected NAME=SPEC"),
            ("g=0.1", "no parameter 'g'"),
            ("f1=0.1,,0.2", "not a finite number"),
            ("f1=lhs:0:1", "at least 1 sample"),
            ("f1=lhs:x:1", "not an integer"),
            ("p=lhs:4:1", "no min/max"),
            ("f1=lhs:4:1:0.3:0.2", "LO > HI"),
        ] {
            let err = GridAxis::parse(spec, &s).unwrap_err().to_string();
            assert!(err.contains(spec) && err.contains(needle), "{spec}: {err}");
        }
    }

    #[test]
    fn product_is_lexicographic_and_empty_grids_are_refused() {
        let s = space();
        let axes = vec![GridAxis::parse("f1=0.1,0.2", &s).unwrap(), GridAxis::parse("f2=0.1:0.2:3", &s).unwrap()];
        let pts = design_points(&axes, DEFAULT_MAX_POINTS).unwrap();
        assert_eq!(pts.len(), 6);
        assert_eq!(pts[0], DesignPoint::from_pairs([("f1", 0.1), ("f2", 0.1)]).unwrap());
        assert_eq!(pts[1], DesignPoint::from_pairs([("f1", 0.1), ("f2", 0.15)]).unwrap());
        assert_eq!(pts[5], DesignPoint::from_pairs([("f1", 0.2), ("f2", 0.2)]).unwrap());
        assert_eq!(design_points(&[], DEFAULT_MAX_POINTS).unwrap_err(), SpaceError::EmptyGrid);
        let dup = vec![axes[0].clone(), axes[0].clone()];
        assert!(matches!(design_points(&dup, DEFAULT_MAX_POINTS), Err(SpaceError::Duplicate { .. })));
    }

    #[test]
    fn errors_echo_a_bounded_excerpt_of_the_spec() {
        let name = "n".repeat(10_000);
        let err = GridAxis::parse(&format!("{name}=0.1:0.2:3"), &space()).unwrap_err().to_string();
        assert!(err.len() < 600 && err.contains("more characters"), "{} bytes: {err}", err.len());
    }

    #[test]
    fn huge_grids_are_counted_and_refused_before_anything_is_built() {
        let s = space();
        let parse = |spec: &str| GridAxis::parse(spec, &s).unwrap();
        // 10^12 points, and a product that overflows 64 bits: parsing allocates nothing
        let huge = vec![parse("f1=0.1:0.2:1000000000000")];
        assert_eq!(point_count(&huge).unwrap(), Some(1_000_000_000_000));
        let err = design_points(&huge, DEFAULT_MAX_POINTS).unwrap_err().to_string();
        assert!(err.contains("1000000000000 design points") && err.contains("100000 accepted"), "{err}");
        let overflow = vec![parse("f1=0.1:0.2:10000000000"), parse("f2=lhs:10000000000:1")];
        assert_eq!(point_count(&overflow).unwrap(), None);
        assert!(design_points(&overflow, usize::MAX).unwrap_err().to_string().contains("more than 2^64"));
        // a hypercube group counts once; the cap is inclusive
        let joint = vec![parse("f1=lhs:50:3"), parse("f2=lhs:50:3")];
        assert_eq!(point_count(&joint).unwrap(), Some(50));
        assert_eq!(design_points(&joint, 50).unwrap().len(), 50);
        assert!(matches!(design_points(&joint, 49), Err(SpaceError::TooManyPoints { .. })));
    }

    #[test]
    fn latin_hypercube_hits_every_stratum_once_and_is_reproducible() {
        let s = space();
        let axes = vec![GridAxis::parse("f1=lhs:10:7", &s).unwrap(), GridAxis::parse("f2=lhs:10:7", &s).unwrap()];
        let pts = design_points(&axes, DEFAULT_MAX_POINTS).unwrap();
        assert_eq!(pts.len(), 10, "one joint hypercube, not a product");
        for name in ["f1", "f2"] {
            let mut strata: Vec<usize> =
                pts.iter().map(|p| ((p.get(name).unwrap() - 0.1) / 0.01).floor() as usize).collect();
            strata.sort();
            assert_eq!(strata, (0..10).collect::<Vec<_>>(), "{name}");
        }
        assert_eq!(pts, design_points(&axes, DEFAULT_MAX_POINTS).unwrap());
        let other = vec![GridAxis::parse("f1=lhs:10:8", &s).unwrap(), axes[1].clone()];
        assert_eq!(design_points(&other, DEFAULT_MAX_POINTS).unwrap().len(), 100, "different seeds: two factors");
    }

    #[test]
    fn distance_is_normalised_by_range_and_zero_width_counts_as_one() {
        let s = space();
        let a = DesignPoint::from_pairs([("f1", 0.1), ("f2", 0.1)]).unwrap();
        let b = DesignPoint::from_pairs([("f1", 0.2), ("f2", 0.2)]).unwrap();
        assert!((s.normalised_distance(&a, &b) - 2f64.sqrt()).abs() < 1e-12);
        let c = DesignPoint::from_pairs([("f1", 0.1), ("f2", 0.1), ("p", 7.0)]).unwrap();
        assert!((s.normalised_distance(&a, &c) - 2.0).abs() < 1e-12, "p defaults to 5, width 1");
        assert_eq!(s.normalised_distance(&a, &s.complete(&a).unwrap()), 0.0);
        assert!(s.complete(&DesignPoint::from_pairs([("q", 1.0)]).unwrap()).is_err());
        assert!(DesignPoint::from_pairs([("f1", f64::NAN)]).is_err(), "a point is finite before a space sees it");
    }
}
