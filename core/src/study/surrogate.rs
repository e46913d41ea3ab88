//! A response surface with error bars: a Gaussian process fitted to a QoI's stored values over
//! the swept parameters, which predicts a value and its standard deviation anywhere in the range.
//!
//! Inputs are each parameter scaled to [0, 1] over its range (the same scaling as the distances
//! of the warm starts), over a constant mean. The kernel is Matérn 3/2 with one length per
//! parameter, `k(x, x') = s^2 (1 + sqrt(3) r) exp(-sqrt(3) r)`, `r^2 = sum_d (x_d - x'_d)^2 / l_d^2`:
//! rougher than the squared exponential, which the stick / slip edges of friction QoIs make
//! overconfident (measured, with the likelihood choosing among kernels too: docs/surrogate.md).
//! The lengths and a nugget (noise variance relative to `s^2`, from 1e-10: the stored values carry
//! the solver's own error) are chosen by maximum likelihood on a grid, the lengths then refined
//! one by one; the signal variance and the mean are in closed form for each choice (profile
//! likelihood).
//!
//! The points are not exact: each QoI is within about 3 x its tolerance of the QoI's largest
//! |value| ([`POINT_ERROR_PER_TOLERANCE`]), and that error is an offset shared by neighbouring
//! points (tiny's middle_ux at 2e-4: -0.41 % of its spread at every point of an 11 x 11 grid, with
//! a scatter of 0.03 %), not noise that averaging removes. A nugget would average it away; the
//! prediction inherits sum_i w_i e_i instead (w the weights of the mean), bounded by
//! sum_i |w_i| e_i, which is added to the standard deviation ([`Surrogate::with_point_errors`];
//! docs/surrogate.md, "Error bars of grid studies").
//!
//! Cost: O(n^3) per likelihood evaluation, about 80 of them, on at most [`SEARCH_POINTS`] points,
//! then one on all; fits are refused above [`MAX_POINTS`] points before anything is allocated.

use super::space::{Axis, ParameterSpace};
use crate::point::DesignPoint;

/// The most points a surface is fitted to (an n x n matrix: 32 MB at this size).
pub const MAX_POINTS: usize = 2000;
/// Above this many points the likelihood's search runs on a spread-out subset of this size and
/// the surface is then fitted to all of them with what it chose (docs/surrogate.md, "Pictures
/// of the surface").
pub const SEARCH_POINTS: usize = 500;
/// The most parameters a surface is fitted over.
pub const MAX_DIMENSION: usize = 8;
/// The shortest length scale (in units of a parameter's range): shorter ones let the likelihood
/// explain a few points as unrelated spikes, a surface no study has the points to resolve.
const MIN_LENGTH: f64 = 0.1;
/// Nugget: the noise variance added to the diagonal, relative to the signal variance (lengths
/// whose matrix does not factorise with it are skipped by the search).
const NUGGETS: [f64; 5] = [1e-10, 1e-7, 1e-5, 1e-4, 1e-3];
/// A point's QoI error per unit of its tolerance, relative to the QoI's largest |value| over the
/// fitted points: measured within about 3 x (docs/surrogate.md, "Adaptive to a target"; tiny's
/// middle_ux at 2e-4 off by 3.5 x, slips by less).
pub const POINT_ERROR_PER_TOLERANCE: f64 = 3.0;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SurrogateError {
    #[error("a surface needs at least 2 points, got {0}")]
    TooFewPoints(usize),
    #[error("{count} points: a surface is fitted to at most {max}")]
    TooManyPoints { count: usize, max: usize },
    #[error("{count} parameters: a surface is fitted over 1 to {max}")]
    Dimension { count: usize, max: usize },
    #[error("point {index} has {found} coordinates, the surface {expected}")]
    Coordinates { index: usize, found: usize, expected: usize },
    #[error("point {index}: a value or coordinate is not a finite number")]
    NotFinite { index: usize },
    #[error("two points at the same place (points {0} and {1}) with different values")]
    Conflict(usize, usize),
    #[error("{tolerances} tolerances for {rows} points: give one per point, or none")]
    Tolerances { tolerances: usize, rows: usize },
    #[error("`{0}` is not a parameter of the scene")]
    UnknownParameter(String),
    #[error("give a value of `{0}` (a parameter of the surface)")]
    MissingParameter(String),
    #[error(
        "`{name}` = {value:?} is outside the box the surface covers, [{lo:?}, {hi:?}]: it predicts between its points, not beyond"
    )]
    OutsideBox { name: String, value: f64, lo: f64, hi: f64 },
}

/// A fitted Gaussian process.
#[derive(Debug, Clone)]
pub struct Surrogate {
    points: Vec<Vec<f64>>,
    values: Vec<f64>,
    lengths: Vec<f64>,
    /// noise variance relative to the signal variance
    nugget: f64,
    signal_variance: f64,
    mean: f64,
    /// Cholesky factor L of the kernel matrix (row-major, lower triangle).
    factor: Vec<f64>,
    /// K^-1 (y - mean).
    alpha: Vec<f64>,
    /// each fitted point's own error, in the values' units (empty: exact points)
    errors: Vec<f64>,
    /// K^-1 1 / (1' K^-1 1), the mean's weights (with `errors` only)
    mean_weights: Vec<f64>,
}

/// A prediction: the mean and its standard deviation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Prediction {
    pub mean: f64,
    pub std: f64,
}

impl Prediction {
    /// The band of 2 standard deviations about the mean, within the bound the physics sets: a
    /// norm (`non_negative`) is never below zero, so neither is its band.
    pub fn band(&self, non_negative: bool) -> (f64, f64) {
        let (low, high) = (self.mean - 2.0 * self.std, self.mean + 2.0 * self.std);
        if non_negative { (low.max(0.0), high.max(0.0)) } else { (low, high) }
    }
}

impl Surrogate {
    /// Fits `values` at `points` (each with the same number of coordinates, scaled to [0, 1]).
    pub fn fit(points: &[Vec<f64>], values: &[f64]) -> Result<Self, SurrogateError> {
        Self::fit_searching(points, values, SEARCH_POINTS)
    }

    /// [`Self::fit`], the likelihood searched on at most `search` of the points.
    fn fit_searching(points: &[Vec<f64>], values: &[f64], search: usize) -> Result<Self, SurrogateError> {
        let n = points.len();
        if n != values.len() || n < 2 {
            return Err(SurrogateError::TooFewPoints(n.min(values.len())));
        }
        if n > MAX_POINTS {
            return Err(SurrogateError::TooManyPoints { count: n, max: MAX_POINTS });
        }
        let dim = points[0].len();
        if dim == 0 || dim > MAX_DIMENSION {
            return Err(SurrogateError::Dimension { count: dim, max: MAX_DIMENSION });
        }
        for (index, (p, v)) in points.iter().zip(values).enumerate() {
            if p.len() != dim {
                return Err(SurrogateError::Coordinates { index, found: p.len(), expected: dim });
            }
            if !v.is_finite() || p.iter().any(|x| !x.is_finite()) {
                return Err(SurrogateError::NotFinite { index });
            }
        }
        for i in 0..n {
            for j in 0..i {
                if points[i] == points[j] && values[i] != values[j] {
                    return Err(SurrogateError::Conflict(j, i));
                }
            }
        }
        // The likelihood's search on a spread-out subset of a large study's points (each of its
        // ~80 evaluations is a factorisation: 2000 points took minutes), then one on all of them.
        let (lengths, nugget) = if n > search {
            let subset = super::space::farthest_first(points, search);
            let sub_points: Vec<Vec<f64>> = subset.iter().map(|&i| points[i].clone()).collect();
            let sub_values: Vec<f64> = subset.iter().map(|&i| values[i]).collect();
            most_likely(&sub_points, &sub_values)
        } else {
            most_likely(points, values)
        };
        // (the subset's nugget may be too small for the closer points of the whole set)
        Ok(NUGGETS
            .iter()
            .filter(|&&g| g >= nugget)
            .find_map(|&g| Self::with_lengths(points, values, lengths.clone(), g))
            .or_else(|| Self::with_lengths(points, values, lengths, NUGGETS[NUGGETS.len() - 1] * 10.0))
            .expect("a nugget of 1e-2 factorises a Matérn correlation matrix"))
    }

    /// The process with given length scales (signal variance and mean in closed form); None if
    /// the kernel matrix does not factorise.
    fn with_lengths(points: &[Vec<f64>], values: &[f64], lengths: Vec<f64>, nugget: f64) -> Option<Self> {
        let n = points.len();
        let factor = cholesky(&correlation(points, &lengths, nugget), n)?;
        // the mean: generalised least squares, 1' K^-1 y / 1' K^-1 1
        let ones = solve(&factor, n, &vec![1.0; n]);
        let kinv_y = solve(&factor, n, values);
        let mean = kinv_y.iter().sum::<f64>() / ones.iter().sum::<f64>();
        let centred: Vec<f64> = values.iter().map(|v| v - mean).collect();
        let alpha = solve(&factor, n, &centred);
        let signal_variance = (centred.iter().zip(&alpha).map(|(c, a)| c * a).sum::<f64>() / n as f64).max(0.0);
        Some(Self {
            points: points.to_vec(),
            values: values.to_vec(),
            lengths,
            nugget,
            signal_variance,
            mean,
            factor,
            alpha,
            errors: Vec::new(),
            mean_weights: Vec::new(),
        })
    }

    /// The same process with each fitted point's own error (`errors[i]` >= 0, in the values'
    /// units, as the points): a prediction's standard deviation then includes what the points'
    /// errors can make of its mean, sum_i |w_i| errors[i] (w the weights of the mean: the errors
    /// taken as one offset of the worst sign, not as noise that averages out), in quadrature
    /// with the process's.
    pub fn with_point_errors(mut self, errors: Vec<f64>) -> Result<Self, SurrogateError> {
        if errors.len() != self.points.len() {
            return Err(SurrogateError::Tolerances { tolerances: errors.len(), rows: self.points.len() });
        }
        if let Some(index) = errors.iter().position(|e| !e.is_finite() || *e < 0.0) {
            return Err(SurrogateError::NotFinite { index });
        }
        if errors.iter().all(|e| *e == 0.0) {
            return Ok(self);
        }
        let n = self.points.len();
        let ones = solve(&self.factor, n, &vec![1.0; n]);
        let total: f64 = ones.iter().sum();
        self.mean_weights = ones.iter().map(|o| o / total).collect();
        self.errors = errors;
        Ok(self)
    }

    /// The length scale of each parameter (in units of its range).
    pub fn lengths(&self) -> &[f64] {
        &self.lengths
    }

    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Leave-one-out cross-validation, in closed form: for each fitted point, the prediction of
    /// the process fitted to the others with the same lengths and nugget (the mean re-estimated
    /// without it). With Q = K^-1 - K^-1 1 1' K^-1 / (1' K^-1 1), the residual of point i is
    /// (Q y)_i / Q_ii, its variance s^2 / Q_ii (Dubrule 1983), which costs one factorisation
    /// rather than n refits.
    pub fn leave_one_out(&self) -> Vec<Prediction> {
        let n = self.points.len();
        let ones = solve(&self.factor, n, &vec![1.0; n]);
        let total: f64 = ones.iter().sum();
        (0..n)
            .map(|i| {
                let mut unit = vec![0.0; n];
                unit[i] = 1.0;
                // (K^-1)_ii = |L^-1 e_i|^2
                let inverse_ii: f64 = forward(&self.factor, n, &unit).iter().map(|v| v * v).sum();
                let q_ii = (inverse_ii - ones[i] * ones[i] / total).max(f64::MIN_POSITIVE);
                // alpha = K^-1 (y - mean) = Q y, the mean being the generalised least squares one
                let residual = self.alpha[i] / q_ii;
                // (the variance with the signal variance of the whole fit)
                Prediction { mean: self.values[i] - residual, std: (self.signal_variance / q_ii).sqrt() }
            })
            .collect()
    }

    /// The mean and standard deviation at `x` (scaled coordinates, as the fitted points).
    pub fn predict(&self, x: &[f64]) -> Prediction {
        let n = self.points.len();
        let k: Vec<f64> = self.points.iter().map(|p| kernel(p, x, &self.lengths)).collect();
        let mean = self.mean + k.iter().zip(&self.alpha).map(|(a, b)| a * b).sum::<f64>();
        // var = s^2 (1 + nugget - k' K^-1 k), with v = L^-1 k
        let v = forward(&self.factor, n, &k);
        let reduction = v.iter().map(|x| x * x).sum::<f64>();
        let variance = self.signal_variance * (1.0 + self.nugget - reduction).max(0.0);
        let inherited = if self.errors.is_empty() {
            0.0
        } else {
            // the mean's weights: w = K^-1 k + u (1 - 1' K^-1 k), u = K^-1 1 / (1' K^-1 1);
            // K^-1 k = L'^-1 v, v = L^-1 k of the variance
            let kinv_k = backward(&self.factor, n, v);
            let share = 1.0 - kinv_k.iter().sum::<f64>();
            kinv_k.iter().zip(&self.mean_weights).zip(&self.errors).map(|((w, u), e)| (w + u * share).abs() * e).sum()
        };
        Prediction { mean, std: (variance + inherited * inherited).sqrt() }
    }
}

/// A QoI's surface over named parameters in their own units: each scaled to [0, 1] over its
/// range in the scene ([`ParameterSpace`]) before the process sees it.
#[derive(Debug, Clone)]
pub struct ResponseSurface {
    names: Vec<String>,
    /// each parameter's map to the unit box ([`Axis`], of the scene's range)
    axes: Vec<Axis>,
    /// (lowest, highest) of each parameter where the surface predicts
    bounds: Vec<(f64, f64)>,
    process: Surrogate,
    /// the QoI is a norm: its mean is never predicted below zero ([`Self::non_negative`])
    non_negative: bool,
}

impl ResponseSurface {
    /// Fits `samples` (each: the values of `names`, in that order, and the QoI's value).
    pub fn fit(space: &ParameterSpace, names: &[String], samples: &[(Vec<f64>, f64)]) -> Result<Self, SurrogateError> {
        if samples.len() > MAX_POINTS {
            return Err(SurrogateError::TooManyPoints { count: samples.len(), max: MAX_POINTS });
        }
        let axes = names
            .iter()
            .map(|name| space.range(name).map(Axis::of).ok_or_else(|| SurrogateError::UnknownParameter(name.clone())))
            .collect::<Result<Vec<_>, _>>()?;
        let points: Vec<Vec<f64>> = samples.iter().map(|(x, _)| unit(&axes, x)).collect();
        let values: Vec<f64> = samples.iter().map(|(_, v)| *v).collect();
        let process = Surrogate::fit(&points, &values)?;
        // the box: the scene's range, widened to the points (a parameter without a range in
        // the scene has only its default)
        let bounds = names
            .iter()
            .enumerate()
            .map(|(k, name)| {
                let range = space.range(name).expect("checked above");
                samples.iter().fold((range.min, range.max), |(lo, hi), (x, _)| (lo.min(x[k]), hi.max(x[k])))
            })
            .collect();
        Ok(Self { names: names.to_vec(), axes, bounds, process, non_negative: false })
    }

    /// The surface of a QoI that cannot be negative (a slip's norm): a mean below zero, which the
    /// process gives beside a region that sticks (a slip at -4.5e-8 m was read), is predicted as
    /// zero; the standard deviation stays the process's.
    pub fn non_negative(mut self) -> Self {
        self.non_negative = true;
        self
    }

    /// The surface with each sample's own error (the samples' order; see
    /// [`Surrogate::with_point_errors`]).
    pub fn with_point_errors(mut self, errors: Vec<f64>) -> Result<Self, SurrogateError> {
        self.process = self.process.with_point_errors(errors)?;
        Ok(self)
    }

    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// The process's length scale of each parameter (in units of its [`Axis`] over the scene's range).
    pub fn lengths(&self) -> &[f64] {
        self.process.lengths()
    }

    /// (lowest, highest) of each parameter, in [`Self::names`] order: the box where
    /// [`Self::predict_within`] answers.
    pub fn bounds(&self) -> &[(f64, f64)] {
        &self.bounds
    }

    /// Points it was fitted to.
    pub fn len(&self) -> usize {
        self.process.len()
    }

    pub fn is_empty(&self) -> bool {
        self.process.is_empty()
    }

    /// [`Surrogate::leave_one_out`] at each fitted point, in the order of the samples (a norm's
    /// mean never below zero).
    pub fn leave_one_out(&self) -> Vec<Prediction> {
        let mut at = self.process.leave_one_out();
        if self.non_negative {
            at.iter_mut().for_each(|p| p.mean = p.mean.max(0.0));
        }
        at
    }

    /// The prediction at `point` for someone who asked for it: refused outside the box of the
    /// scene's ranges and the fitted points, where the mean is a guess (and at 1e300 was NaN).
    pub fn predict_within(&self, point: &DesignPoint) -> Result<Prediction, SurrogateError> {
        for (name, &(lo, hi)) in self.names.iter().zip(&self.bounds) {
            if let Some(v) = point.get(name).filter(|v| !(lo..=hi).contains(v)) {
                return Err(SurrogateError::OutsideBox { name: name.clone(), value: v, lo, hi });
            }
        }
        self.predict(point)
    }

    /// Values of [`Self::names`] (in that order) as the process sees them.
    fn scale(&self, x: &[f64]) -> Vec<f64> {
        unit(&self.axes, x)
    }

    /// `point`'s coordinates as the process sees them (each parameter on its [`Axis`]).
    fn scaled(&self, point: &DesignPoint) -> Result<Vec<f64>, SurrogateError> {
        self.names
            .iter()
            .zip(&self.axes)
            .map(|(name, axis)| {
                let v = point.get(name).ok_or_else(|| SurrogateError::MissingParameter(name.clone()))?;
                if v.is_finite() { Ok(axis.unit(v)) } else { Err(SurrogateError::NotFinite { index: 0 }) }
            })
            .collect()
    }

    /// The prediction at `point`, which must give every parameter of the surface.
    pub fn predict(&self, point: &DesignPoint) -> Result<Prediction, SurrogateError> {
        let x = self.scaled(point)?;
        let mut p = self.process.predict(&x);
        if self.non_negative {
            p.mean = p.mean.max(0.0);
        }
        Ok(p)
    }
}

/// `x` (one value per axis) in the unit box.
fn unit(axes: &[Axis], x: &[f64]) -> Vec<f64> {
    x.iter().zip(axes).map(|(v, a)| a.unit(*v)).collect()
}

/// The surface a QoI is read from: its own process, or, for a norm whose signed components the
/// points carry too, the norm of the components' processes. Through the place where a norm
/// passes through zero (a slip sliding back: its components change sign) the components are
/// smooth and the norm has a kink no stationary process bends to: measured on tiny's wide box,
/// 2.1-2.4 x smaller largest errors, error bars still calibrated (docs/surrogate.md, "Surfaces
/// that know contact"). A norm is exactly zero where every neighbouring point stuck ([`Sticks`]).
#[derive(Debug, Clone)]
pub struct QoiSurface {
    reading: Reading,
    /// a norm some of whose points stuck: where it reads exactly zero
    sticks: Option<Sticks>,
}

/// How a QoI's surface reads its values.
#[derive(Debug, Clone)]
pub enum Reading {
    Direct(Box<ResponseSurface>),
    Components(Vec<ResponseSurface>),
}

/// A value at most this share of the largest |value| of its QoI is a stick: a slip that stuck is
/// 1e-35 to 1e-21 m where slips are 1e-6 to 1e-4 m (tiny's wide box at 1e-6), so round-off, not
/// a slip a study resolves.
pub const STICK_SHARE: f64 = 1e-9;

/// Where a norm stuck: its fitted points (scaled as the surfaces scale them) and whether each
/// stuck. A prediction whose 2 d nearest points (d parameters) all stuck is exactly zero: the
/// physics gives zero there, where a process through zeros gives a few 1e-8 of the largest slip
/// (and a band below zero). Beside the edge, where a neighbour slides, the process reads.
#[derive(Debug, Clone)]
struct Sticks {
    points: Vec<(Vec<f64>, bool)>,
    neighbours: usize,
}

impl Sticks {
    /// None when no point stuck, or every point did (the process of zeros is zero already).
    fn of(points: &[Vec<f64>], values: &[f64]) -> Option<Self> {
        let stuck = stuck(values);
        if !stuck.iter().any(|s| *s) {
            return None;
        }
        let neighbours = (2 * points.first().map_or(1, Vec::len)).min(points.len());
        Some(Self { points: points.iter().cloned().zip(stuck).collect(), neighbours })
    }

    /// Whether the nearest points to `x` all stuck (`skip`: a point left out, for leave-one-out).
    fn holds_at(&self, x: &[f64], skip: Option<usize>) -> bool {
        let mut near: Vec<(f64, bool)> = self
            .points
            .iter()
            .enumerate()
            .filter(|(i, _)| Some(*i) != skip)
            .map(|(_, (p, s))| (p.iter().zip(x).map(|(a, b)| (a - b).powi(2)).sum::<f64>(), *s))
            .collect();
        let k = self.neighbours.min(near.len());
        if k == 0 {
            return false;
        }
        near.select_nth_unstable_by(k - 1, |a, b| a.0.total_cmp(&b.0));
        near[..k].iter().all(|(_, s)| *s)
    }
}

/// Whether each of a norm's `values` stuck ([`STICK_SHARE`] of the largest |value| or less).
fn stuck(values: &[f64]) -> Vec<bool> {
    let largest = values.iter().map(|v| v.abs()).fold(0.0, f64::max);
    values.iter().map(|v| v.abs() <= STICK_SHARE * largest).collect()
}

/// A prediction where the norm stuck: exactly zero, with the process's standard deviation (a
/// neighbour that stuck does not rule out a slip between points).
fn stuck_at(p: Prediction) -> Prediction {
    Prediction { mean: 0.0, std: p.std }
}

impl QoiSurface {
    /// The surface of `qoi` as the scene defines it: never below zero for a norm, from its
    /// components where the scene reports them. The one fit behind `glissade surface --at`, the
    /// surface audit and the pictures. `tolerances`: as [`Self::fit`].
    pub fn of_scene(
        scene: &crate::scene::Scene,
        names: &[String],
        rows: &[(Vec<f64>, &std::collections::BTreeMap<String, f64>)],
        tolerances: &[f64],
        qoi: &str,
    ) -> Result<Self, SurrogateError> {
        let space = ParameterSpace::from_scene(scene);
        Self::fit(&space, names, rows, tolerances, qoi, scene.qoi_is_norm(qoi), &scene.components_of(qoi))
    }

    /// The surface of `qoi` over `rows` (each: the values of `names`, in that order, and the
    /// point's QoIs): from its `components` (names of QoIs) where every row that has the norm has
    /// them all, else its own, never below zero if `norm`, and exactly zero where a norm's
    /// neighbouring points all stuck. `tolerances`: one per row, the
    /// tolerance its QoIs were solved to, whose error each surface's standard deviation carries
    /// ([`POINT_ERROR_PER_TOLERANCE`] x it x the largest |value| of the surface's QoI); empty:
    /// the points are taken as exact.
    pub fn fit(
        space: &ParameterSpace,
        names: &[String],
        rows: &[(Vec<f64>, &std::collections::BTreeMap<String, f64>)],
        tolerances: &[f64],
        qoi: &str,
        norm: bool,
        components: &[&str],
    ) -> Result<Self, SurrogateError> {
        if !tolerances.is_empty() && tolerances.len() != rows.len() {
            return Err(SurrogateError::Tolerances { tolerances: tolerances.len(), rows: rows.len() });
        }
        let tolerance = |i: usize| tolerances.get(i).copied().unwrap_or(0.0);
        // (the components at the rows that have the norm: every surface fits the same points)
        let samples = |q: &str| -> (Vec<(Vec<f64>, f64)>, Vec<f64>) {
            rows.iter()
                .enumerate()
                .filter(|(_, (_, v))| v.contains_key(qoi))
                .filter_map(|(i, (x, v))| Some(((x.clone(), *v.get(q)?), tolerance(i))))
                .unzip()
        };
        // `fitted` (the QoI's samples, or a slip's latent) with the errors of `own`'s values
        let fit_to = |fitted: &[Sample], own: &[Sample], tolerances: &[f64]| {
            let largest = own.iter().map(|(_, v)| v.abs()).fold(0.0, f64::max);
            let errors = tolerances.iter().map(|t| POINT_ERROR_PER_TOLERANCE * t * largest).collect();
            ResponseSurface::fit(space, names, fitted)?.with_point_errors(errors)
        };
        let fit = |q: &str| -> Result<ResponseSurface, SurrogateError> {
            let (samples, tolerances) = samples(q);
            fit_to(&samples, &samples, &tolerances)
        };
        let complete = !components.is_empty()
            && rows
                .iter()
                .filter(|(_, v)| v.contains_key(qoi))
                .all(|(_, v)| components.iter().all(|c| v.contains_key(*c)));
        // (a norm read through a latent margin is zero where the margin is below zero; read
        // through its zeros, where its nearest points all stuck)
        let (own, tolerances) = samples(qoi);
        let (reading, latent) = if norm && complete {
            (Reading::Components(components.iter().map(|c| fit(c)).collect::<Result<_, _>>()?), false)
        } else if norm {
            let latent = latent_slip(space, names, &own)?;
            let surface = fit_to(latent.as_deref().unwrap_or(&own), &own, &tolerances)?;
            (Reading::Direct(Box::new(surface.non_negative())), latent.is_some())
        } else {
            (Reading::Direct(Box::new(fit_to(&own, &own, &tolerances)?)), false)
        };
        let mut surface = Self { reading, sticks: None };
        if norm && !latent {
            let values: Vec<f64> = own.iter().map(|(_, v)| *v).collect();
            let first = surface.first().expect("a fitted surface");
            surface.sticks = Sticks::of(first.process.points.as_slice(), &values);
        }
        Ok(surface)
    }

    /// How it reads its values.
    pub fn reading(&self) -> &Reading {
        &self.reading
    }

    /// Whether it is read from a norm's components.
    pub fn from_components(&self) -> bool {
        matches!(self.reading, Reading::Components(_))
    }

    /// Points it was fitted to.
    pub fn len(&self) -> usize {
        self.first().map_or(0, |s| s.len())
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn first(&self) -> Option<&ResponseSurface> {
        match &self.reading {
            Reading::Direct(s) => Some(s),
            Reading::Components(parts) => parts.first(),
        }
    }

    /// The leave-one-out prediction at each fitted point: the rows that have the QoI, in their
    /// order. Of components: the norm of their leave-one-out means, as [`Self::predict`]; zero
    /// where the point's nearest others all stuck.
    pub fn leave_one_out(&self) -> Vec<Prediction> {
        let mut at = match &self.reading {
            Reading::Direct(s) => s.leave_one_out(),
            Reading::Components(parts) => {
                let each: Vec<Vec<Prediction>> = parts.iter().map(|s| s.leave_one_out()).collect();
                (0..self.len())
                    .map(|i| {
                        let mean = each.iter().map(|c| c[i].mean.powi(2)).sum::<f64>().sqrt();
                        let std = each.iter().map(|c| c[i].std.powi(2)).sum::<f64>().sqrt();
                        Prediction { mean, std }
                    })
                    .collect()
            }
        };
        if let Some(sticks) = &self.sticks {
            for (i, p) in at.iter_mut().enumerate() {
                if sticks.holds_at(&sticks.points[i].0, Some(i)) {
                    *p = stuck_at(*p);
                }
            }
        }
        at
    }

    /// The parameters it is a surface over.
    pub fn names(&self) -> &[String] {
        self.first().map_or(&[], |s| s.names())
    }

    /// The box where [`Self::predict_within`] answers (of components: the union of theirs).
    pub fn bounds(&self) -> Vec<(f64, f64)> {
        match &self.reading {
            Reading::Direct(s) => s.bounds().to_vec(),
            Reading::Components(parts) => {
                let mut parts = parts.iter().map(|s| s.bounds());
                let first = parts.next().map(<[_]>::to_vec).unwrap_or_default();
                parts.fold(first, |acc, b| acc.iter().zip(b).map(|(a, b)| (a.0.min(b.0), a.1.max(b.1))).collect())
            }
        }
    }

    /// As [`ResponseSurface::predict_within`]: refused outside the box.
    pub fn predict_within(&self, point: &DesignPoint) -> Result<Prediction, SurrogateError> {
        self.combine(point, ResponseSurface::predict_within)
    }

    /// As [`ResponseSurface::predict`]. Of components: the norm of their means, and the root of
    /// the sum of their variances, the rms of the vector's error, which bounds the norm's
    /// (|norm(a) - norm(b)| <= norm(a - b)). Zero where the nearest points all stuck.
    pub fn predict(&self, point: &DesignPoint) -> Result<Prediction, SurrogateError> {
        self.combine(point, ResponseSurface::predict)
    }

    fn combine(
        &self,
        point: &DesignPoint,
        predict: fn(&ResponseSurface, &DesignPoint) -> Result<Prediction, SurrogateError>,
    ) -> Result<Prediction, SurrogateError> {
        let p = match &self.reading {
            Reading::Direct(s) => predict(s, point)?,
            Reading::Components(parts) => {
                let (mut squares, mut variances) = (0.0, 0.0);
                for s in parts {
                    let p = predict(s, point)?;
                    squares += p.mean * p.mean;
                    variances += p.std * p.std;
                }
                Prediction { mean: squares.sqrt(), std: variances.sqrt() }
            }
        };
        match (&self.sticks, self.first()) {
            (Some(sticks), Some(s)) if sticks.holds_at(&s.scaled(point)?, None) => Ok(stuck_at(p)),
            _ => Ok(p),
        }
    }
}

/// A sample: a point's parameters (in the surface's order) and its value.
type Sample = (Vec<f64>, f64);

/// A slip norm's samples with its stuck points' zeros replaced by a latent below zero: the slip
/// is the positive part of a smooth margin, which goes on below zero where it sticks. Fitted
/// through the zeros, a process bends the edge's kink into a bump above zero on the stuck side
/// (a 7 x 7 grid over a curved edge: largest error 4.4 % of the spread through the zeros, 0.8 %
/// through the latent; 45 adaptive points: 4.2 % against 0.23 %); through the latent it
/// has no kink to bend, and its positive part puts the edge back. Each stuck point's latent is
/// what the process of the sliding points predicts there, kept below zero: the mean of that
/// prediction's normal law truncated at zero (Tobit). None without a stuck point or with fewer
/// than 3 sliding ones.
fn latent_slip(
    space: &ParameterSpace,
    names: &[String],
    samples: &[(Vec<f64>, f64)],
) -> Result<Option<Vec<Sample>>, SurrogateError> {
    let values: Vec<f64> = samples.iter().map(|(_, v)| *v).collect();
    let stuck = stuck(&values);
    let sliding: Vec<Sample> =
        samples.iter().zip(&stuck).filter(|(_, s)| !**s).map(|(sample, _)| sample.clone()).collect();
    if sliding.len() < 3 || sliding.len() == samples.len() {
        return Ok(None);
    }
    let margin = ResponseSurface::fit(space, names, &sliding)?;
    let latent = samples
        .iter()
        .zip(&stuck)
        .map(|((x, v), s)| {
            (x.clone(), if *s { truncated_below_zero(margin.process.predict(&margin.scale(x))) } else { *v })
        })
        .collect::<Vec<_>>();
    Ok(Some(latent))
}

/// The mean of N(p.mean, p.std^2) truncated to (-inf, 0]: m - s phi(a) / Phi(a), a = -m / s.
fn truncated_below_zero(p: Prediction) -> f64 {
    if p.std <= 0.0 || !p.std.is_finite() {
        return p.mean.min(0.0);
    }
    let a = -p.mean / p.std;
    let density = (-0.5 * a * a).exp() / (2.0 * std::f64::consts::PI).sqrt();
    let below = 0.5 * erfc(-a / std::f64::consts::SQRT_2);
    if below < 1e-300 {
        // far above zero: the truncated law sits at zero
        return 0.0;
    }
    (p.mean - p.std * density / below).min(0.0)
}

/// The complementary error function (Numerical Recipes' erfcc, relative error below 1.2e-7).
fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let r = t
        * (-z * z - 1.26551223
            + t * (1.00002368
                + t * (0.37409196
                    + t * (0.09678418
                        + t * (-0.18628806
                            + t * (0.27886807
                                + t * (-1.13520398 + t * (1.48851587 + t * (-0.82215223 + t * 0.17087277)))))))))
            .exp();
    if x >= 0.0 { r } else { 2.0 - r }
}

/// The lengths and nugget of the largest likelihood: a log grid of lengths common to all
/// parameters for each nugget, then each length refined in turn.
fn most_likely(points: &[Vec<f64>], values: &[f64]) -> (Vec<f64>, f64) {
    let dim = points[0].len();
    let grid: Vec<f64> = (0..12).map(|i| MIN_LENGTH * 2f64.powf(i as f64 * 0.5)).collect();
    let mut best: Option<(f64, Vec<f64>, f64)> = None;
    for &nugget in &NUGGETS {
        for &l in &grid {
            let lengths = vec![l; dim];
            if let Some(ll) = log_likelihood(points, values, &lengths, nugget)
                && best.as_ref().is_none_or(|(b, ..)| ll > *b)
            {
                best = Some((ll, lengths, nugget));
            }
        }
    }
    let (mut best_ll, mut lengths, nugget) = best.unwrap_or((f64::NEG_INFINITY, vec![0.3; dim], NUGGETS[4]));
    for _sweep in 0..2 {
        for d in 0..dim {
            for factor in [0.35, 0.5, 0.7, 1.4, 2.0, 2.8] {
                let mut trial = lengths.clone();
                trial[d] = (trial[d] * factor).clamp(MIN_LENGTH, 20.0);
                if let Some(ll) = log_likelihood(points, values, &trial, nugget)
                    && ll > best_ll
                {
                    best_ll = ll;
                    lengths = trial;
                }
            }
        }
    }
    (lengths, nugget)
}

/// Matérn 3/2 correlation of two scaled points: rougher than the squared exponential, whose
/// error bars the stick / slip edges of friction QoIs make overconfident (docs/surrogate.md).
fn kernel(a: &[f64], b: &[f64], lengths: &[f64]) -> f64 {
    let r2: f64 = a.iter().zip(b).zip(lengths).map(|((x, y), l)| ((x - y) / l).powi(2)).sum();
    let r = (3.0 * r2).sqrt();
    (1.0 + r) * (-r).exp()
}

/// The correlation matrix (unit signal variance) with the nugget on its diagonal.
fn correlation(points: &[Vec<f64>], lengths: &[f64], nugget: f64) -> Vec<f64> {
    let n = points.len();
    let mut k = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..=i {
            let v = kernel(&points[i], &points[j], lengths);
            k[i * n + j] = v;
            k[j * n + i] = v;
        }
        k[i * n + i] += nugget;
    }
    k
}

/// Profile log likelihood of the lengths (signal variance and mean at their optimum), up to a
/// constant; None when the matrix does not factorise.
fn log_likelihood(points: &[Vec<f64>], values: &[f64], lengths: &[f64], nugget: f64) -> Option<f64> {
    let n = points.len();
    let factor = cholesky(&correlation(points, lengths, nugget), n)?;
    let ones = solve(&factor, n, &vec![1.0; n]);
    let mean = solve(&factor, n, values).iter().sum::<f64>() / ones.iter().sum::<f64>();
    let centred: Vec<f64> = values.iter().map(|v| v - mean).collect();
    let quad = centred.iter().zip(solve(&factor, n, &centred)).map(|(c, a)| c * a).sum::<f64>();
    let log_det: f64 = (0..n).map(|i| factor[i * n + i].ln()).sum::<f64>() * 2.0;
    // all values equal: any lengths explain them; prefer long ones (a flat surface)
    if quad <= 0.0 {
        return Some(lengths.iter().map(|l| l.ln()).sum());
    }
    Some(-0.5 * n as f64 * (quad / n as f64).ln() - 0.5 * log_det)
}

/// Lower Cholesky factor of the symmetric n x n matrix `a`; None if it is not positive definite.
fn cholesky(a: &[f64], n: usize) -> Option<Vec<f64>> {
    let mut l = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..=i {
            let s = dot(&l[i * n..i * n + j], &l[j * n..j * n + j]);
            if i == j {
                let d = a[i * n + i] - s;
                if d.is_nan() || d <= 0.0 {
                    return None;
                }
                l[i * n + i] = d.sqrt();
            } else {
                l[i * n + j] = (a[i * n + j] - s) / l[j * n + j];
            }
        }
    }
    Some(l)
}

/// L^-1 b.
fn forward(l: &[f64], n: usize, b: &[f64]) -> Vec<f64> {
    let mut y = vec![0.0; n];
    for i in 0..n {
        let s = dot(&l[i * n..i * n + i], &y[..i]);
        y[i] = (b[i] - s) / l[i * n + i];
    }
    y
}

/// L'^-1 y, by rows of L (contiguous): once x_k is known, its share leaves every earlier entry.
fn backward(l: &[f64], n: usize, mut x: Vec<f64>) -> Vec<f64> {
    for k in (0..n).rev() {
        x[k] /= l[k * n + k];
        let xk = x[k];
        for (xi, lki) in x[..k].iter_mut().zip(&l[k * n..k * n + k]) {
            *xi -= lki * xk;
        }
    }
    x
}

/// a . b, in four interleaved sums (the compiler keeps one sum in order, which it cannot
/// vectorise): the factorisations and solves of a large surface are these dot products.
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut sums = [0.0; 4];
    let (a4, b4) = (a.chunks_exact(4), b.chunks_exact(4));
    let tail: f64 = a4.remainder().iter().zip(b4.remainder()).map(|(x, y)| x * y).sum();
    for (x, y) in a4.zip(b4) {
        for k in 0..4 {
            sums[k] += x[k] * y[k];
        }
    }
    (sums[0] + sums[1]) + (sums[2] + sums[3]) + tail
}

/// (L L')^-1 b.
fn solve(l: &[f64], n: usize, b: &[f64]) -> Vec<f64> {
    backward(l, n, forward(l, n, b))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use std::collections::BTreeMap;

    /// The tiny scene whose slip at A also reports its signed components, slip_A_x and _y.
    pub(crate) fn tiny_with_slip_a_components() -> crate::scene::Scene {
        let mut text = include_str!("../../../scenes/three-blocks-tiny.toml").to_owned();
        for axis in ["x", "y"] {
            text.push_str(&format!(
                "\n[[qoi]]\nname = \"slip_A_{axis}\"\nkind = \"slip\"\ninterface = \"interface1\"\npoint = [0.0075, 0.0075, 0.06]\ncomponent = \"{axis}\"\n"
            ));
        }
        crate::scene::Scene::parse(&text).unwrap()
    }

    fn grid(n: usize) -> Vec<Vec<f64>> {
        let mut points = Vec::new();
        for i in 0..n {
            for j in 0..n {
                points.push(vec![i as f64 / (n - 1) as f64, j as f64 / (n - 1) as f64]);
            }
        }
        points
    }

    fn analytic(x: &[f64]) -> f64 {
        (3.0 * x[0]).sin() + 0.5 * (2.0 * x[1]).cos() + x[0] * x[1]
    }

    /// Points solved to a tolerance are off by an offset their neighbours share (tiny's middle_ux
    /// at 2e-4: -0.41 % of its spread at every point of a grid, scatter 0.03 %): the error bars
    /// must carry it, where a process that takes the points as exact is sure of the wrong value.
    #[test]
    fn the_points_error_is_carried_as_an_offset_not_averaged_away() {
        let points = grid(9);
        let truth: Vec<f64> = points.iter().map(|p| analytic(p)).collect();
        let largest = truth.iter().map(|v| v.abs()).fold(0.0, f64::max);
        let error = POINT_ERROR_PER_TOLERANCE * 1e-2 * largest;
        // every point off by 80 % of its error bound, one sign, with a small scatter
        let values: Vec<f64> =
            truth.iter().enumerate().map(|(i, v)| v - 0.8 * error + 0.05 * error * (i % 3) as f64).collect();
        let exact = Surrogate::fit(&points, &values).unwrap();
        let carried = exact.clone().with_point_errors(vec![error; points.len()]).unwrap();
        let centres: Vec<Vec<f64>> =
            (0..8).flat_map(|i| (0..8).map(move |j| vec![(i as f64 + 0.5) / 8.0, (j as f64 + 0.5) / 8.0])).collect();
        let within = |s: &Surrogate| {
            centres.iter().filter(|c| (s.predict(c).mean - analytic(c)).abs() <= 2.0 * s.predict(c).std).count()
        };
        assert!(within(&exact) < centres.len() / 2, "exact points: {} of 64 within 2 sd", within(&exact));
        assert_eq!(within(&carried), centres.len(), "every centre within 2 sd once the points' error is carried");
        for c in &centres {
            let (a, b) = (exact.predict(c), carried.predict(c));
            assert_eq!(a.mean, b.mean, "the error bars change, not the mean");
            // the inherited term is at least the error (the weights sum to 1) and no wild multiple of it
            assert!(b.std >= error && b.std <= 2.0 * error + a.std, "{c:?}: {b:?}, error {error}, {a:?}");
        }
        // at a fitted point the prediction inherits that point's error
        let at = carried.predict(&points[40]);
        assert!((at.std - error).abs() < 0.02 * error, "{at:?} at a point of error {error}");
        // each point's own: looser points (x < 0.5) give wider bars than tighter ones
        let mixed: Vec<f64> = points.iter().map(|p| if p[0] < 0.5 { 10.0 * error } else { error }).collect();
        let mixed = exact.clone().with_point_errors(mixed).unwrap();
        let (loose, tight) = (mixed.predict(&[0.2, 0.5]).std, mixed.predict(&[0.8, 0.5]).std);
        assert!(loose > 5.0 * tight, "{loose} against {tight}");
        // one error per point, finite and not negative
        assert_eq!(
            exact.clone().with_point_errors(vec![error; 3]).err(),
            Some(SurrogateError::Tolerances { tolerances: 3, rows: 81 })
        );
        let mut bad = vec![error; 81];
        bad[7] = -1.0;
        assert_eq!(exact.clone().with_point_errors(bad).err(), Some(SurrogateError::NotFinite { index: 7 }));
    }

    #[test]
    fn it_passes_through_the_stored_points_and_is_unsure_away_from_them() {
        // a surface that bends within a grid cell, so that the process is unsure between points
        let points = grid(4);
        let values: Vec<f64> = points.iter().map(|p| (4.0 * p[0]).sin() * (3.0 * p[1]).cos()).collect();
        let s = Surrogate::fit(&points, &values).unwrap();
        let spread = values.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
            - values.iter().cloned().fold(f64::INFINITY, f64::min);
        // between points: unsure, more so farther from every point (and outside the range)
        let between = s.predict(&[1.0 / 6.0, 1.0 / 6.0]).std;
        let outside = s.predict(&[1.6, 1.6]).std;
        let far = s.predict(&[3.0, 3.0]).std;
        for (p, v) in points.iter().zip(&values) {
            let at = s.predict(p);
            assert!((at.mean - v).abs() < 1e-4 * spread, "{p:?}: {at:?} against {v}");
            assert!(at.std < 0.05 * between, "{p:?}: {at:?}, {between} between points");
        }
        assert!(outside > between && far >= outside, "{between} {outside} {far}");
    }

    /// Calibration: on an analytic function, the true value lies within 2 standard deviations at
    /// (at least) 90 % of an 11 x 11 grid, from 25 points of a Latin-hypercube-like design.
    #[test]
    fn its_error_bars_are_calibrated_on_an_analytic_function() {
        // 25 points: a 5 x 5 grid jittered deterministically inside its cells
        let mut points = Vec::new();
        for i in 0..5 {
            for j in 0..5 {
                let jitter = |k: usize| ((k * 7919 + i * 31 + j * 17) % 100) as f64 / 100.0;
                points.push(vec![(i as f64 + 0.2 + 0.6 * jitter(1)) / 5.0, (j as f64 + 0.2 + 0.6 * jitter(2)) / 5.0]);
            }
        }
        let values: Vec<f64> = points.iter().map(|p| analytic(p)).collect();
        let s = Surrogate::fit(&points, &values).unwrap();
        let (mut within, mut squares) = (0, 0.0f64);
        let test = grid(11);
        let truth: Vec<f64> = test.iter().map(|p| analytic(p)).collect();
        for (p, t) in test.iter().zip(&truth) {
            let at = s.predict(p);
            let error = (at.mean - t).abs();
            squares += error * error;
            within += usize::from(error <= 2.0 * at.std);
        }
        let share = within as f64 / test.len() as f64;
        let rms = (squares / test.len() as f64).sqrt();
        let mean = truth.iter().sum::<f64>() / truth.len() as f64;
        let spread = (truth.iter().map(|t| (t - mean).powi(2)).sum::<f64>() / truth.len() as f64).sqrt();
        assert!(share >= 0.9, "{within} of {} within 2 sd (rms error {rms:.2e})", test.len());
        // the mean itself is informative: a tenth of the function's own spread (measured 8 %; a
        // constant would be 100 %)
        assert!(rms < 0.1 * spread, "rms error {rms:.2e} against a spread of {spread:.2e}");
    }

    /// The closed form against what it stands for: n refits, each without one point, with the
    /// same lengths and nugget (its mean re-estimated), predicting at the point left out.
    /// A large study's surface, its likelihood searched on a spread-out subset, predicts as the
    /// one searched on every point: a 17 x 17 grid of the analytic function, searched on 60 of
    /// its points or all 289, against the function on 15 x 15 points between them.
    #[test]
    fn a_search_on_a_spread_out_subset_fits_as_well_as_on_every_point() {
        let points = grid(17);
        let values: Vec<f64> = points.iter().map(|p| analytic(p)).collect();
        let all = Surrogate::fit_searching(&points, &values, points.len()).unwrap();
        let subset = Surrogate::fit_searching(&points, &values, 60).unwrap();
        let test: Vec<Vec<f64>> = grid(15).into_iter().map(|p| p.iter().map(|x| 0.02 + 0.96 * x).collect()).collect();
        let rms = |s: &Surrogate| {
            (test.iter().map(|x| (s.predict(x).mean - analytic(x)).powi(2)).sum::<f64>() / test.len() as f64).sqrt()
        };
        let within = |s: &Surrogate| {
            test.iter().filter(|x| (s.predict(x).mean - analytic(x)).abs() <= 2.0 * s.predict(x).std).count() as f64
                / test.len() as f64
        };
        let spread = values.iter().cloned().fold(f64::MIN, f64::max) - values.iter().cloned().fold(f64::MAX, f64::min);
        assert!(rms(&all) < 1e-3 * spread, "the full search's fit: rms {:.2e} of a spread {spread:.2e}", rms(&all));
        assert!(
            rms(&subset) <= 1.5 * rms(&all),
            "subset {:.3e} against all {:.3e} (lengths {:?} against {:?})",
            rms(&subset),
            rms(&all),
            subset.lengths(),
            all.lengths()
        );
        assert!(within(&subset) >= 0.9, "within 2 sd: {}", within(&subset));
    }

    #[test]
    fn leave_one_out_equals_refitting_without_each_point() {
        let mut points = grid(4);
        points.push(vec![0.4, 0.55]);
        let values: Vec<f64> = points.iter().map(|p| analytic(p)).collect();
        let s = Surrogate::fit(&points, &values).unwrap();
        let loo = s.leave_one_out();
        assert_eq!(loo.len(), points.len());
        for i in 0..points.len() {
            let (mut others, mut rest) = (points.clone(), values.clone());
            others.remove(i);
            rest.remove(i);
            let refit = Surrogate::with_lengths(&others, &rest, s.lengths.clone(), s.nugget).unwrap();
            let direct = refit.predict(&points[i]).mean;
            assert!(
                (loo[i].mean - direct).abs() < 1e-9 * (1.0 + direct.abs()),
                "{i}: {} against {direct}",
                loo[i].mean
            );
            // it does leave the point out: a residual, not the interpolated value
            assert!((loo[i].mean - values[i]).abs() > 1e-6, "{i}: {loo:?}");
        }
    }

    #[test]
    fn one_parameter_and_flat_data_work() {
        let points: Vec<Vec<f64>> = (0..6).map(|i| vec![i as f64 / 5.0]).collect();
        let flat = Surrogate::fit(&points, &[2.5; 6]).unwrap();
        let at = flat.predict(&[0.33]);
        assert!((at.mean - 2.5).abs() < 1e-9 && at.std < 1e-6, "{at:?}");
        let line: Vec<f64> = points.iter().map(|p| 1.0 + 2.0 * p[0]).collect();
        let s = Surrogate::fit(&points, &line).unwrap();
        assert!((s.predict(&[0.5]).mean - 2.0).abs() < 1e-3);
    }

    /// A norm that sticks over half the range and grows over the other: the process alone
    /// undershoots zero beside the edge; the non-negative surface never does, and keeps the same
    /// mean where the process is positive.
    #[test]
    fn a_norm_is_never_predicted_below_zero() {
        let scene = crate::scene::Scene::parse(include_str!("../../../scenes/three-blocks-tiny.toml")).unwrap();
        let space = ParameterSpace::from_scene(&scene);
        let names = vec!["f1".to_owned()];
        let slip = |f: f64| (0.15 - f).max(0.0) * 1e-3;
        let samples: Vec<(Vec<f64>, f64)> = (0..6).map(|i| 0.1 + 0.02 * i as f64).map(|f| (vec![f], slip(f))).collect();
        let raw = ResponseSurface::fit(&space, &names, &samples).unwrap();
        let norm = raw.clone().non_negative();
        let at = |s: &ResponseSurface, f: f64| s.predict(&DesignPoint::from_pairs([("f1", f)]).unwrap()).unwrap();
        let grid: Vec<f64> = (0..=100).map(|i| 0.1 + 0.001 * i as f64).collect();
        let lowest = grid.iter().map(|&f| at(&raw, f).mean).fold(f64::INFINITY, f64::min);
        assert!(lowest < 0.0, "the process alone undershoots beside the edge: {lowest:e}");
        for &f in &grid {
            let (r, n) = (at(&raw, f), at(&norm, f));
            assert!(n.mean >= 0.0, "f1 = {f}: {n:?}");
            assert_eq!(n.mean, r.mean.max(0.0));
            assert_eq!(n.std, r.std);
        }
    }

    /// A norm reads exactly zero where its nearest points all stuck (between them too: the
    /// process through zeros gave a few 1e-3 of the largest slip there), never below zero, and
    /// beside the edge, where a neighbour slides, the process's value with zero within its error
    /// bars. Read directly and from components alike.
    #[test]
    fn a_stick_region_reads_exactly_zero_where_every_neighbour_sticks() {
        let scene = tiny_with_slip_a_components();
        let space = ParameterSpace::from_scene(&scene);
        let names = vec!["f1".to_owned(), "f2".to_owned()];
        // slips over the low-friction corner, stuck (0, or round-off) beyond a curved edge
        let margin = |a: f64, b: f64| 0.3 - a - b + 4.0 * (a - 0.15).powi(2);
        let slip = |a: f64, b: f64| margin(a, b).max(0.0) * 1e-3;
        let rows: Vec<(Vec<f64>, BTreeMap<String, f64>)> = (0..36)
            .map(|k| (0.1 + 0.02 * (k / 6) as f64, 0.1 + 0.02 * (k % 6) as f64))
            .map(|(a, b)| {
                let v = if margin(a, b) > 0.0 { slip(a, b) } else { 1e-30 * (a + b) };
                let q = [("slip_A", v), ("slip_A_x", 0.6 * v), ("slip_A_y", -0.8 * v)];
                (vec![a, b], q.iter().map(|(n, v)| (n.to_string(), *v)).collect())
            })
            .collect();
        let rows: Vec<(Vec<f64>, &BTreeMap<String, f64>)> = rows.iter().map(|(p, q)| (p.clone(), q)).collect();
        let largest = rows.iter().map(|(_, q)| q["slip_A"]).fold(0.0f64, f64::max);
        let stuck_at = |x: &[f64]| margin(x[0], x[1]) <= 0.0;
        for components in [vec![], scene.components_of("slip_A")] {
            let surface = QoiSurface::fit(&space, &names, &rows, &[], "slip_A", true, &components).unwrap();
            let (mut zeros, mut inside) = (0, 0);
            for i in 0..=50 {
                for j in 0..=50 {
                    let x = [0.1 + 0.002 * i as f64, 0.1 + 0.002 * j as f64];
                    let p = surface.predict(&DesignPoint::from_pairs([("f1", x[0]), ("f2", x[1])]).unwrap()).unwrap();
                    assert!(p.mean >= 0.0, "{x:?}: {p:?}");
                    // the 4 nearest design points (a cell's corners) all stuck: exactly zero
                    let mut near: Vec<(f64, &Vec<f64>)> =
                        rows.iter().map(|(y, _)| ((y[0] - x[0]).powi(2) + (y[1] - x[1]).powi(2), y)).collect();
                    near.sort_by(|a, b| a.0.total_cmp(&b.0));
                    if near[..4].iter().all(|(_, y)| stuck_at(y)) {
                        inside += 1;
                        assert_eq!(p.mean, 0.0, "{x:?} among stuck points: {p:?}");
                    }
                    zeros += usize::from(p.mean == 0.0);
                    if margin(x[0], x[1]) < -0.01 {
                        // half a design step past the edge (on it, the kink is the process's to miss)
                        assert!(p.mean <= 2.0 * p.std + 1e-12 * largest, "{x:?}: 0 outside 2 sd of {p:?}");
                    } else if near[..4].iter().all(|(_, y)| !stuck_at(y)) {
                        // away from the edge the slip is read, not zeroed
                        assert!(p.mean > 0.0, "{x:?}: {p:?} where it slides");
                    }
                }
            }
            assert!(inside > 400 && zeros >= inside, "{inside} points inside the stick region, {zeros} zeros");
            // leave-one-out: a stuck point among stuck ones is predicted as zero, exactly
            let loo = surface.leave_one_out();
            let deep = rows.iter().position(|(x, _)| x[0] > 0.17 && x[1] > 0.17).unwrap();
            assert_eq!(loo[deep].mean, 0.0, "{:?}", rows[deep].0);
        }
    }

    /// A slip through a curved stick / slip edge, read through a latent margin that goes on
    /// below zero where it sticks, against the process through its zeros: the kink no longer
    /// bends into a bump on the stuck side. The truncated normal's mean is the textbook one.
    #[test]
    fn a_slip_is_read_through_a_latent_margin_below_its_stuck_points() {
        let scene = crate::scene::Scene::parse(include_str!("../../../scenes/three-blocks-tiny.toml")).unwrap();
        let space = ParameterSpace::from_scene(&scene);
        let names = vec!["f1".to_owned(), "f2".to_owned()];
        let slip = |a: f64, b: f64| (0.3 - a - b + 40.0 * (a - 0.15).powi(2)).max(0.0) * 1e-3;
        let rows: Vec<(Vec<f64>, BTreeMap<String, f64>)> = (0..49)
            .map(|k| (0.1 + (k / 7) as f64 / 60.0, 0.1 + (k % 7) as f64 / 60.0))
            .map(|(a, b)| (vec![a, b], [("slip_A".to_string(), slip(a, b))].into()))
            .collect();
        let rows: Vec<(Vec<f64>, &BTreeMap<String, f64>)> = rows.iter().map(|(p, q)| (p.clone(), q)).collect();
        let latent = QoiSurface::fit(&space, &names, &rows, &[], "slip_A", true, &[]).unwrap();
        let samples: Vec<(Vec<f64>, f64)> = rows.iter().map(|(x, q)| (x.clone(), q["slip_A"])).collect();
        let zeros = ResponseSurface::fit(&space, &names, &samples).unwrap().non_negative();
        let (mut worst_latent, mut worst_zeros) = (0.0f64, 0.0f64);
        for i in 0..=50 {
            for j in 0..=50 {
                let (a, b) = (0.1 + 0.002 * i as f64, 0.1 + 0.002 * j as f64);
                let p = DesignPoint::from_pairs([("f1", a), ("f2", b)]).unwrap();
                let (l, z) = (latent.predict(&p).unwrap(), zeros.predict(&p).unwrap());
                assert!(l.mean >= 0.0, "({a}, {b}): {l:?}");
                worst_latent = worst_latent.max((l.mean - slip(a, b)).abs());
                worst_zeros = worst_zeros.max((z.mean - slip(a, b)).abs());
            }
        }
        let spread = slip(0.1, 0.1);
        eprintln!(
            "largest error: latent {:.4}, zeros {:.4} of the spread",
            worst_latent / spread,
            worst_zeros / spread
        );
        assert!(worst_latent < 0.5 * worst_zeros, "latent {worst_latent:e}, zeros {worst_zeros:e}");
        // E[g | g <= 0] for g ~ N(m, s^2): -s sqrt(2 / pi) at m = 0; m far below zero
        let t = |mean: f64, std: f64| truncated_below_zero(Prediction { mean, std });
        assert!((t(0.0, 1.0) + (2.0 / std::f64::consts::PI).sqrt()).abs() < 1e-6, "{}", t(0.0, 1.0));
        assert!((t(-10.0, 1.0) + 10.0).abs() < 1e-9 && t(50.0, 1.0) == 0.0 && t(-2.0, 0.0) == -2.0);
        // (far above zero, the law truncated below zero sits just below it: about -s^2 / m)
        assert!((t(5.0, 1.0) + 0.19).abs() < 0.01, "{}", t(5.0, 1.0));
        // erfc against tabulated values
        for (x, e) in
            [(0.0, 1.0), (0.5, 0.4795001222), (1.0, 0.1572992071), (-1.0, 1.8427007929), (3.0, 2.209049700e-5)]
        {
            assert!((erfc(x) - e).abs() < 1.2e-7 * e.max(1.0), "erfc({x}) = {} against {e}", erfc(x));
        }
    }

    /// A slip that slides back through zero: its norm has a V, its components are smooth. The
    /// norm of the components' surfaces follows the V; the norm's own surface rounds it off.
    #[test]
    fn a_norm_through_zero_is_read_from_its_components() {
        let scene = tiny_with_slip_a_components();
        assert_eq!(scene.components_of("slip_A"), ["slip_A_x", "slip_A_y"]);
        assert!(scene.components_of("slip_B").is_empty() && scene.components_of("slip_A_x").is_empty());
        let space = ParameterSpace::from_scene(&scene);
        let names = vec!["f1".to_owned()];
        let (x, y) = (|f: f64| (f - 0.137) * 1e-3, |f: f64| 2e-6 * (1.0 + f));
        let rows: Vec<(Vec<f64>, BTreeMap<String, f64>)> = (0..6)
            .map(|i| 0.1 + 0.02 * i as f64)
            .map(|f| {
                let q = [("slip_A", x(f).hypot(y(f))), ("slip_A_x", x(f)), ("slip_A_y", y(f))];
                (vec![f], q.iter().map(|(n, v)| (n.to_string(), *v)).collect())
            })
            .collect();
        let rows: Vec<(Vec<f64>, &BTreeMap<String, f64>)> = rows.iter().map(|(p, q)| (p.clone(), q)).collect();
        let components = scene.components_of("slip_A");
        let read = QoiSurface::fit(&space, &names, &rows, &[], "slip_A", true, &components).unwrap();
        let direct = QoiSurface::fit(&space, &names, &rows, &[], "slip_A", true, &[]).unwrap();
        assert!(read.from_components() && !direct.from_components());
        assert_eq!(read.len(), 6);
        let largest = |s: &QoiSurface| {
            (0..=100)
                .map(|i| 0.1 + 0.001 * i as f64)
                .map(|f| {
                    let p = s.predict(&DesignPoint::from_pairs([("f1", f)]).unwrap()).unwrap();
                    assert!(p.mean >= 0.0, "f1 = {f}: {p:?}");
                    (p.mean - x(f).hypot(y(f))).abs()
                })
                .fold(0.0f64, f64::max)
        };
        let (from_components, own) = (largest(&read), largest(&direct));
        assert!(from_components < own / 4.0, "components {from_components:e}, the norm's own {own:e}");
        // a row without a component: the norm's own surface
        let mut partial = rows.clone();
        let lacking: BTreeMap<String, f64> = [("slip_A".to_string(), 1e-6)].into();
        partial[0].1 = &lacking;
        assert!(
            !QoiSurface::fit(&space, &names, &partial, &[], "slip_A", true, &components).unwrap().from_components()
        );
    }

    /// `--at f1=1e300` answered `NaN +- 0`: a point outside the box is refused, naming it.
    #[test]
    fn a_prediction_outside_the_box_is_refused() {
        let scene = crate::scene::Scene::parse(include_str!("../../../scenes/three-blocks-tiny.toml")).unwrap();
        let space = ParameterSpace::from_scene(&scene);
        let names = vec!["f1".to_owned()];
        let samples: Vec<(Vec<f64>, f64)> = (0..5).map(|i| (vec![0.1 + 0.025 * i as f64], i as f64)).collect();
        let surface = ResponseSurface::fit(&space, &names, &samples).unwrap();
        let at = |v: f64| surface.predict_within(&DesignPoint::from_pairs([("f1", v)]).unwrap());
        assert!(at(0.2).unwrap().mean.is_finite() && at(0.1).unwrap().std.is_finite());
        for v in [1e300, 0.2 + 1e-9, -1.0] {
            match at(v) {
                Err(SurrogateError::OutsideBox { lo, hi, .. }) => assert_eq!((lo, hi), (0.1, 0.2)),
                other => panic!("{v}: {other:?}"),
            }
        }
    }

    #[test]
    fn bad_input_is_refused_before_anything_is_built() {
        assert_eq!(Surrogate::fit(&[vec![0.0]], &[1.0]).err(), Some(SurrogateError::TooFewPoints(1)));
        let many = vec![vec![0.0]; MAX_POINTS + 1];
        assert!(matches!(Surrogate::fit(&many, &vec![0.0; MAX_POINTS + 1]), Err(SurrogateError::TooManyPoints { .. })));
        assert!(matches!(
            Surrogate::fit(&[vec![0.0], vec![0.5, 1.0]], &[1.0, 2.0]),
            Err(SurrogateError::Coordinates { index: 1, .. })
        ));
        assert!(matches!(
            Surrogate::fit(&[vec![0.0], vec![0.5]], &[1.0, f64::NAN]),
            Err(SurrogateError::NotFinite { index: 1 })
        ));
        assert_eq!(Surrogate::fit(&[vec![0.5], vec![0.5]], &[1.0, 2.0]).err(), Some(SurrogateError::Conflict(0, 1)));
        // the same point twice with the same value is fine (a point stored by two studies)
        assert!(Surrogate::fit(&[vec![0.5], vec![0.5], vec![0.0]], &[1.0, 1.0, 0.0]).is_ok());
    }
}
