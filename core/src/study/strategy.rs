//! Initialisation strategies (docs/method.md 4): where the LATIN iterations of a design point start.
//!
//! - `Cold`: zero interface fields (the paper's "direct" computation); the store is not read.
//! - `Previous`: the last solution stored in this sweep (the paper's multiparametric strategy).
//! - `Nearest`: the stored solution nearest in normalised parameter distance.
//! - `Blend { k }`: the k nearest combined with inverse-distance weights w_i ∝ 1 / d_i^2
//!   (summing to 1).
//! - `Linear { k }`: the k nearest combined with the weights (summing to 1) that reproduce a
//!   field varying linearly in the parameters, the nearest weighted most (minimum of
//!   Σ d_i^2 w_i^2): interpolation inside the neighbours, linear extrapolation outside them (in a
//!   sweep, 2 s(p-1) - s(p-2)). Same admissibility rule and fallback as `Blend`; weights summing
//!   in absolute value to more than [`MAX_LINEAR_AMPLIFICATION`] fall back to `Nearest`. A combination with weights summing to 1 of interface fields that are
//!   admissible for the same substructures and loads (space A_d) is admissible too: A_d is affine
//!   in the interface fields when only the interface laws differ. So only neighbours that agree
//!   with the point on every parameter other than interface-law parameters
//!   ([`interface_law_parameters`]) are blended; with fewer than 2 of them, `Blend` falls back
//!   to `Nearest`. The blended local-stage fields need not satisfy the new interface law: the
//!   first local stage projects them.

use crate::point::DesignPoint;
use std::collections::BTreeSet;
use std::sync::Arc;

use serde::{Deserialize, Serialize};

use crate::field::{InterfaceSolution, SideField, StageSolution};
use crate::scene::Scene;

use super::space::ParameterSpace;
use super::store::{SolutionId, SolutionStore, StoreError};

/// Where the iterations of a design point start.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum InitStrategy {
    Cold,
    Previous,
    Nearest,
    Blend { k: usize },
    Linear { k: usize },
}

impl InitStrategy {
    pub fn name(&self) -> &'static str {
        match self {
            Self::Cold => "cold",
            Self::Previous => "previous",
            Self::Nearest => "nearest",
            Self::Blend { .. } => "blend",
            Self::Linear { .. } => "linear",
        }
    }

    pub fn kind(&self) -> StrategyKind {
        match self {
            Self::Cold => StrategyKind::Cold,
            Self::Previous => StrategyKind::Previous,
            Self::Nearest => StrategyKind::Nearest,
            Self::Blend { .. } => StrategyKind::Blend,
            Self::Linear { .. } => StrategyKind::Linear,
        }
    }
}

/// A strategy by name, before the number of neighbours a blend combines is known (what a
/// command line or a request names).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum StrategyKind {
    Cold,
    Previous,
    Nearest,
    Blend,
    Linear,
}

impl StrategyKind {
    /// The strategy a study uses when it names none: the cheapest measured at honoured tolerance
    /// with the check on (docs/performance.md, "Gain at equal accuracy": tiny 11 x 11 at 2e-4,
    /// 9,801 work with 3 neighbours against 13,692 for `Nearest`; on bolted-joint-tiny 5 x 5
    /// `Nearest` was 5 % cheaper).
    pub const DEFAULT: StrategyKind = StrategyKind::Linear;

    /// Neighbours `Blend` and `Linear` combine when a study does not say: three, for both. A blend
    /// is best with a few (docs/performance.md); a linear fit through three neighbours is a plane
    /// through them (on a grid, q(i-1, j) + q(i, j-1) - q(i-1, j-1)), where more neighbours
    /// smear their fields into a least-squares plane: three-blocks-tiny 11 x 11 at 2e-4, checked,
    /// 9,801 work with 3 against 13,343 with 8 (cold 20,059), and on a box across a stick / slip
    /// edge 11,163 against 16,214 (docs/performance.md, "Gain at equal accuracy").
    pub const DEFAULT_NEIGHBOURS: usize = 3;

    /// The strategy, `Blend` and `Linear` combining `k` neighbours.
    pub fn with_neighbours(self, k: usize) -> InitStrategy {
        match self {
            Self::Cold => InitStrategy::Cold,
            Self::Previous => InitStrategy::Previous,
            Self::Nearest => InitStrategy::Nearest,
            Self::Blend => InitStrategy::Blend { k },
            Self::Linear => InitStrategy::Linear { k },
        }
    }
}

/// Inverse-distance weights use this power of the distance (Shepard's usual choice).
pub const BLEND_POWER: i32 = 2;
/// Two values of a parameter closer than this (relative to its range) are the same.
pub const SAME_VALUE: f64 = 1e-12;
/// `Linear` falls back to `Nearest` when Σ |w_i| exceeds this: far extrapolation amplifies the
/// neighbours' own errors.
pub const MAX_LINEAR_AMPLIFICATION: f64 = 4.0;

/// One stored solution an initialisation came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InitSource {
    pub id: SolutionId,
    pub point: DesignPoint,
    /// normalised distance to the point being solved
    pub distance: f64,
    /// weight in a blend (1 for a single source)
    pub weight: f64,
}

/// An initialisation: the fields to start from (None: cold) and where they came from.
#[derive(Debug, Clone)]
pub struct Initialisation {
    pub solution: Option<Arc<InterfaceSolution>>,
    /// empty for a cold start
    pub sources: Vec<InitSource>,
    /// what was actually done (`Blend` may fall back to `Nearest`, anything to `Cold` when the
    /// store is empty)
    pub used: InitStrategy,
}

impl Initialisation {
    pub fn cold() -> Self {
        Self { solution: None, sources: Vec::new(), used: InitStrategy::Cold }
    }
}

/// Parameters used only as `interfaces[].friction` in the scene: a change of them changes the
/// interface laws alone, not the substructures, loads or time discretisation. A parameter also
/// used anywhere else (a material, a load, a gap, the search direction, ...) is not one. The same
/// set decides when `run::PointSolver` keeps its factorisations ([`Scene::interface_law_parameters`]).
pub fn interface_law_parameters(scene: &Scene) -> BTreeSet<String> {
    scene.interface_law_parameters()
}

/// True when `a` and `b` agree on every parameter of `space` outside `law_parameters`.
fn differ_only_in(space: &ParameterSpace, a: &DesignPoint, b: &DesignPoint, law_parameters: &BTreeSet<String>) -> bool {
    space.parameters().iter().filter(|p| !law_parameters.contains(&p.name)).all(|p| {
        let (x, y) = (a.get(&p.name).unwrap_or(p.default), b.get(&p.name).unwrap_or(p.default));
        (x - y).abs() <= SAME_VALUE * p.scale()
    })
}

/// The initialisation of `point` by `strategy`.
///
/// `previous` is the solution stored last in this sweep (for `Previous`); only converged stored
/// solutions are used. Any strategy gives a cold start when nothing usable is stored.
pub fn initialise(
    store: &dyn SolutionStore,
    space: &ParameterSpace,
    law_parameters: &BTreeSet<String>,
    point: &DesignPoint,
    previous: Option<SolutionId>,
    strategy: InitStrategy,
) -> Result<Initialisation, StoreError> {
    let single = |id: SolutionId, used: InitStrategy| -> Result<Initialisation, StoreError> {
        let s = store.get(id)?;
        Ok(Initialisation {
            sources: vec![InitSource {
                id,
                distance: space.normalised_distance(point, &s.point),
                point: s.point,
                weight: 1.0,
            }],
            solution: Some(s.solution),
            used,
        })
    };
    match strategy {
        InitStrategy::Cold => Ok(Initialisation::cold()),
        InitStrategy::Previous => match previous {
            Some(id) => single(id, InitStrategy::Previous),
            None => Ok(Initialisation::cold()),
        },
        InitStrategy::Nearest => match nearest_converged(store, point, 1)?.first() {
            Some(&(_, id)) => single(id, InitStrategy::Nearest),
            None => Ok(Initialisation::cold()),
        },
        InitStrategy::Blend { k } | InitStrategy::Linear { k } => {
            let near = nearest_converged(store, point, k.max(1))?;
            let Some(&(_, first)) = near.first() else {
                return Ok(Initialisation::cold());
            };
            let mut members = Vec::new();
            for &(d, id) in &near {
                let s = store.get(id)?;
                if differ_only_in(space, point, &s.point, law_parameters) {
                    members.push((d, id, s));
                }
            }
            // an exact match needs no blending; fewer than 2 admissible neighbours: nearest
            if members.len() < 2 || members[0].0 == 0.0 {
                return single(first, InitStrategy::Nearest);
            }
            let weights: Vec<f64> = if let InitStrategy::Linear { .. } = strategy {
                let points: Vec<(&DesignPoint, f64)> = members.iter().map(|(d, _, s)| (&s.point, *d)).collect();
                match linear_weights(space, point, &points) {
                    Some(w) if w.iter().map(|x| x.abs()).sum::<f64>() <= MAX_LINEAR_AMPLIFICATION => w,
                    _ => return single(first, InitStrategy::Nearest),
                }
            } else {
                let raw: Vec<f64> = members.iter().map(|(d, _, _)| d.powi(-BLEND_POWER)).collect();
                let total: f64 = raw.iter().sum();
                raw.iter().map(|w| w / total).collect()
            };
            let parts: Vec<(&InterfaceSolution, f64)> =
                members.iter().zip(&weights).map(|((_, _, s), &w)| (s.solution.as_ref(), w)).collect();
            let Some(solution) = combine(&parts) else {
                return single(first, InitStrategy::Nearest);
            };
            Ok(Initialisation {
                solution: Some(Arc::new(solution)),
                sources: members
                    .into_iter()
                    .zip(weights)
                    .map(|((d, id, s), w)| InitSource { id, point: s.point, distance: d, weight: w })
                    .collect(),
                used: strategy,
            })
        }
    }
}

/// Weights w (Σ w_i = 1, Σ w_i (y_i - x) = 0 in the normalised coordinates that vary) of least
/// Σ d_i^2 w_i^2: w = D^-1 A^T (A D^-1 A^T)^-1 b with A = [1; y_i - x], b = [1; 0], D = diag(d_i^2).
/// Directions the neighbours do not span are left out of the constraints (least squares there).
fn linear_weights(space: &ParameterSpace, x: &DesignPoint, neighbours: &[(&DesignPoint, f64)]) -> Option<Vec<f64>> {
    let cx = space.normalised_coordinates(x);
    let cy: Vec<Vec<f64>> = neighbours.iter().map(|(p, _)| space.normalised_coordinates(p)).collect();
    // the coordinates in which some neighbour differs from x
    let dims: Vec<usize> = (0..cx.len()).filter(|&j| cy.iter().any(|y| (y[j] - cx[j]).abs() > SAME_VALUE)).collect();
    let n = dims.len() + 1;
    let rows: Vec<Vec<f64>> = std::iter::once(vec![1.0; neighbours.len()])
        .chain(dims.iter().map(|&j| cy.iter().map(|y| y[j] - cx[j]).collect()))
        .collect();
    let dinv: Vec<f64> = neighbours.iter().map(|(_, d)| 1.0 / (d * d)).collect();
    let mut m = vec![vec![0.0; n]; n];
    for a in 0..n {
        for b in 0..n {
            m[a][b] = (0..neighbours.len()).map(|i| rows[a][i] * dinv[i] * rows[b][i]).sum();
        }
    }
    // a small ridge keeps collinear neighbours (a 1D sweep in a 2D space) solvable
    let ridge = 1e-12 * (0..n).map(|a| m[a][a]).sum::<f64>();
    for (a, row) in m.iter_mut().enumerate() {
        row[a] += ridge;
    }
    let mut rhs = vec![0.0; n];
    rhs[0] = 1.0;
    let lambda = solve_small(m, rhs)?;
    let w: Vec<f64> =
        (0..neighbours.len()).map(|i| dinv[i] * (0..n).map(|a| rows[a][i] * lambda[a]).sum::<f64>()).collect();
    let total: f64 = w.iter().sum();
    (total.is_finite() && total.abs() > 1e-12).then(|| w.iter().map(|x| x / total).collect())
}

/// Gaussian elimination with partial pivoting for the small systems of `linear_weights`.
fn solve_small(mut m: Vec<Vec<f64>>, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    for c in 0..n {
        let p = (c..n).max_by(|&i, &j| m[i][c].abs().total_cmp(&m[j][c].abs()))?;
        if m[p][c].abs() < 1e-300 {
            return None;
        }
        m.swap(c, p);
        b.swap(c, p);
        for r in c + 1..n {
            let f = m[r][c] / m[c][c];
            for k in c..n {
                m[r][k] -= f * m[c][k];
            }
            b[r] -= f * b[c];
        }
    }
    let mut x = vec![0.0; n];
    for r in (0..n).rev() {
        x[r] = (b[r] - (r + 1..n).map(|k| m[r][k] * x[k]).sum::<f64>()) / m[r][r];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// The `k` nearest stored solutions that converged (a store may also keep unconverged ones).
fn nearest_converged(
    store: &dyn SolutionStore,
    point: &DesignPoint,
    k: usize,
) -> Result<Vec<(f64, SolutionId)>, StoreError> {
    // Ask for a few more in case some did not converge; enough for the stores this code fills.
    let found = store.nearest(point, 2 * k + 2)?;
    let mut out = Vec::with_capacity(k);
    for (d, id) in found {
        if store.get(id)?.converged {
            out.push((d, id));
            if out.len() == k {
                break;
            }
        }
    }
    Ok(out)
}

/// Σ w_i s_i over every field of the solutions, or None when their layouts differ.
pub fn combine(parts: &[(&InterfaceSolution, f64)]) -> Option<InterfaceSolution> {
    let (first, _) = parts.first()?;
    let stage = |get: &dyn Fn(&InterfaceSolution) -> Option<&StageSolution>| -> Option<Option<StageSolution>> {
        let Some(base) = get(first) else {
            return parts.iter().all(|(s, _)| get(s).is_none()).then_some(None);
        };
        let mut out = base.clone();
        for (i, f) in out.interfaces.iter_mut().enumerate() {
            for (k, side) in f.s.iter_mut().chain(f.hat.iter_mut()).enumerate() {
                side.force.iter_mut().for_each(|x| *x = 0.0);
                side.velocity.iter_mut().for_each(|x| *x = 0.0);
                for (sol, w) in parts {
                    let other = get(sol)?.interfaces.get(i)?;
                    let n_s = other.s.len();
                    let src: &SideField = if k < n_s { other.s.get(k)? } else { other.hat.get(k - n_s)? };
                    if src.force.len() != side.force.len() || src.velocity.len() != side.velocity.len() {
                        return None;
                    }
                    side.force.iter_mut().zip(&src.force).for_each(|(a, b)| *a += w * b);
                    side.velocity.iter_mut().zip(&src.velocity).for_each(|(a, b)| *a += w * b);
                }
            }
        }
        Some(Some(out))
    };
    let static_stage = stage(&|s: &InterfaceSolution| s.static_stage.as_ref())?;
    let dynamic = stage(&|s: &InterfaceSolution| Some(&s.dynamic))??;
    if parts.iter().any(|(s, _)| s.dynamic.interfaces.len() != dynamic.interfaces.len()) {
        return None;
    }
    Some(InterfaceSolution { static_stage, dynamic })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::field::InterfaceField;

    const SCENE: &str = r#"
dimension = 1
[time]
duration = 1e-4
steps = 10
[parameters]
f = { default = 0.3 }
g = { default = 0.0 }
k = { default = 1.0 }
e = { default = 2e11 }
[materials.steel]
E = "e"
rho = 7800
[[bodies]]
name = "bar"
material = "steel"
size = [0.1]
elements = [10]
[[interfaces]]
name = "wall1"
a = "bar.x+"
b = "wall"
law = "friction"
friction = "f"
gap = "g"
[[interfaces]]
name = "wall2"
a = "bar.x-"
b = "wall"
law = "friction"
friction = "k"
[solver]
k0_factor = "k"
"#;

    #[test]
    fn interface_law_parameters_are_those_only_in_friction() {
        let scene = Scene::parse(SCENE).unwrap();
        // g is a gap, k also a search direction, e a material
        assert_eq!(interface_law_parameters(&scene), BTreeSet::from(["f".to_string()]));
    }

    fn solution(value: f64) -> InterfaceSolution {
        let mut f = InterfaceField::zeros(2, 3);
        f.s[1].force = vec![value; 3];
        f.hat[0].velocity = vec![2.0 * value; 3];
        InterfaceSolution { static_stage: None, dynamic: StageSolution { interfaces: vec![f] } }
    }

    #[test]
    fn linear_weights_extrapolate_a_sweep_and_interpolate_a_square() {
        use crate::study::space::friction_box;
        let space = friction_box(0.0, 1.0);
        let p = |a: f64, b: f64| DesignPoint::from_pairs([("f1", a), ("f2", b)]).unwrap();
        let x = p(0.3, 0.5);
        let (a, b) = (p(0.2, 0.5), p(0.1, 0.5));
        let w = linear_weights(&space, &x, &[(&a, 0.1), (&b, 0.2)]).unwrap();
        assert!((w[0] - 2.0).abs() < 1e-6 && (w[1] + 1.0).abs() < 1e-6, "{w:?}");
        // the centre of a square of 4 neighbours: equal weights
        let c = [p(0.2, 0.4), p(0.4, 0.4), p(0.2, 0.6), p(0.4, 0.6)];
        let d = 0.02f64.sqrt();
        let w = linear_weights(&space, &x, &c.iter().map(|q| (q, d)).collect::<Vec<_>>()).unwrap();
        assert!(w.iter().all(|w| (w - 0.25).abs() < 1e-9), "{w:?}");
        // any linear function is reproduced: here f1 + 3 f2 from 3 neighbours in a corner
        let n = [p(0.2, 0.5), p(0.3, 0.4), p(0.2, 0.4)];
        let nd: Vec<(&DesignPoint, f64)> = n.iter().map(|q| (q, space.normalised_distance(q, &x))).collect();
        let w = linear_weights(&space, &x, &nd).unwrap();
        let f = |q: &DesignPoint| q.get("f1").unwrap() + 3.0 * q.get("f2").unwrap();
        let value: f64 = n.iter().zip(&w).map(|(q, w)| w * f(q)).sum();
        assert!((value - f(&x)).abs() < 1e-6, "{w:?}");
    }

    #[test]
    fn combine_is_the_weighted_sum_and_refuses_other_layouts() {
        let (a, b) = (solution(1.0), solution(3.0));
        let c = combine(&[(&a, 0.25), (&b, 0.75)]).unwrap();
        assert_eq!(c.dynamic.interfaces[0].s[1].force, vec![2.5; 3]);
        assert_eq!(c.dynamic.interfaces[0].hat[0].velocity, vec![5.0; 3]);
        assert_eq!(c.dynamic.interfaces[0].s[0].force, vec![0.0; 3]);
        let mut other = solution(1.0);
        other.dynamic.interfaces[0] = InterfaceField::zeros(2, 4);
        assert!(combine(&[(&a, 0.5), (&other, 0.5)]).is_none());
    }
}
