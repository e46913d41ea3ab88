//! What a frictional contact did while it slid, read from a converged solution, and the one
//! case where the solver knows its answer cannot converge under refinement: an elastic body
//! sliding on a rigid wall with a friction coefficient above 1 (docs/verification.md 4d).

use std::collections::BTreeMap;

pub use glissade_core::contact::{ContactActivity, ILL_POSED_FRICTION};
use glissade_core::field::{InterfaceField, StageSolution};

use crate::model::{Interface, InterfaceLaw};

/// A node counts as closed when its compressive traction exceeds this share of the interface's
/// largest: below it, a grazing node's round-off would count as landings.
const CLOSED_SHARE: f64 = 1e-6;

/// A node slides when its tangential relative velocity exceeds this share of the interface's
/// largest, and its tangential traction is at the friction limit (within [`AT_LIMIT`]).
const SLIDING_SHARE: f64 = 1e-3;

/// The share of f times the pressure a tangential traction reaches when the node slides: a node
/// that sticks stays below it, whatever round-off moves it by (a block that sticks at f = 6 was
/// called sliding, and ill-posed, on its velocities alone: issue 45).
const AT_LIMIT: f64 = 0.99;

/// The contact slides when the nodes that slide carry at least this share of its normal force: a
/// block that sticks may slip at an edge where the pressure falls to nothing (the copper block of
/// `sliding_above_friction_one_is_reported_ill_posed` at f = 6 does), and that is not the sliding
/// the evidence and the ill-posedness are about.
const SLIDING_FORCE_SHARE: f64 = 0.5;

/// The contact activity of every frictional interface of a dynamic solution (levels 0..=steps),
/// one entry per interface name in the model's order.
pub fn contact_activity<const D: usize>(
    interfaces: &[Interface<D>],
    dynamic: &StageSolution,
    dt: f64,
) -> Vec<ContactActivity> {
    // the pieces of each frictional interface (cut by the substructures), by name in the
    // model's order
    let mut named: Vec<Vec<Cut<D>>> = Vec::new();
    for (itf, field) in interfaces.iter().zip(&dynamic.interfaces) {
        if !matches!(itf.law, InterfaceLaw::Friction { .. }) {
            continue;
        }
        let piece = (itf, Piece::read(itf, field));
        match named.iter_mut().find(|pieces| pieces[0].0.name == itf.name) {
            Some(pieces) => pieces.push(piece),
            None => named.push(vec![piece]),
        }
    }
    named.iter().map(|pieces| activity(pieces, dt)).collect()
}

/// One interface's activity from its pieces; a node two pieces share (at a cut between
/// substructures) is one node, its landings counted once.
fn activity<const D: usize>(pieces: &[Cut<D>], dt: f64) -> ContactActivity {
    let itf = pieces[0].0;
    let InterfaceLaw::Friction { coefficient: friction, .. } = itf.law else { unreachable!("frictional pieces only") };
    let first_slip = first_slip(pieces);
    // landings of each node in contact, by its position
    let mut nodes: BTreeMap<[u64; D], usize> = BTreeMap::new();
    let mut total = vec![0.0; pieces.iter().map(|(_, p)| p.levels).max().unwrap_or(0)];
    for (piece_of, piece) in pieces {
        for j in piece.contact_nodes() {
            let at = std::array::from_fn(|c| piece_of.coords[j][c].to_bits());
            let landings = first_slip.map_or(0, |f| piece.landings_of(j, f));
            let count = nodes.entry(at).or_default();
            *count = (*count).max(landings);
        }
        for (t, p) in total.iter_mut().zip(piece.normal_force()) {
            *t += p;
        }
    }
    let mut a = ContactActivity {
        interface: itf.name.clone(),
        friction,
        rigid_wall: itf.sides.len() == 1,
        contact_nodes: nodes.len(),
        first_slip_time: first_slip.map(|s| s as f64 * dt),
        landings_while_sliding: nodes.values().sum(),
        peak_normal_force_ratio: 0.0,
        ill_posed: false,
    };
    if let Some(first) = first_slip {
        // the total normal force over the sliding phase: its peak against its mean
        let phase = &total[first.min(total.len())..];
        let mean = phase.iter().sum::<f64>() / phase.len().max(1) as f64;
        let peak = phase.iter().cloned().fold(0.0, f64::max);
        a.peak_normal_force_ratio = if mean > 0.0 { peak / mean } else { 0.0 };
        // (regularised too: at f = 1.5 the regularised block still chatters, docs/verification.md 4e)
        a.ill_posed = a.rigid_wall && a.friction > ILL_POSED_FRICTION;
    }
    a
}

/// The first step at which the interface slides: its sliding nodes carry [`SLIDING_FORCE_SHARE`]
/// of its normal force or more.
fn first_slip<const D: usize>(pieces: &[Cut<D>]) -> Option<usize> {
    let levels = pieces.iter().map(|(_, p)| p.levels).min().unwrap_or(0);
    (0..levels).find(|&s| {
        let sliding: f64 = pieces.iter().map(|(_, p)| p.sliding_force(s)).sum();
        let total: f64 = pieces.iter().map(|(_, p)| p.normal_force_at(s)).sum();
        sliding > 0.0 && sliding >= SLIDING_FORCE_SHARE * total
    })
}

/// A piece of an interface and its histories.
type Cut<'a, const D: usize> = (&'a Interface<D>, Piece<'a>);

/// One interface's histories, node by node: the compressive traction on side 1 (its normal
/// points towards side 2) and the norm of the tangential relative velocity.
struct Piece<'a> {
    n: usize,
    levels: usize,
    area: &'a [f64],
    pressure: Vec<f64>,
    sliding: Vec<f64>,
    /// whether the tangential traction is at f times the pressure
    at_limit: Vec<bool>,
    closed_at: f64,
    sliding_at: f64,
}

impl<'a> Piece<'a> {
    fn read<const D: usize>(itf: &'a Interface<D>, field: &InterfaceField) -> Self {
        let n = itf.n_nodes();
        let levels = if n == 0 { 0 } else { field.hat[0].force.len() / (n * D) };
        let at = |v: &[f64], step: usize, j: usize| -> [f64; D] { std::array::from_fn(|c| v[(step * n + j) * D + c]) };
        let dot = |a: &[f64; D], b: &[f64; D]| (0..D).map(|c| a[c] * b[c]).sum::<f64>();
        let friction = match itf.law {
            InterfaceLaw::Friction { coefficient, .. } => coefficient,
            _ => 0.0,
        };
        let mut pressure = vec![0.0; levels * n];
        let mut sliding = vec![0.0; levels * n];
        let mut at_limit = vec![false; levels * n];
        for step in 0..levels {
            for j in 0..n {
                let normal = &itf.normal[j];
                pressure[step * n + j] = -dot(&at(&field.hat[0].force, step, j), normal);
                let w1 = at(&field.hat[0].velocity, step, j);
                let w2 = field.hat.get(1).map_or([0.0; D], |h| at(&h.velocity, step, j));
                let rel: [f64; D] = std::array::from_fn(|c| w2[c] - w1[c]);
                let rn = dot(&rel, normal);
                let t: [f64; D] = std::array::from_fn(|c| rel[c] - rn * normal[c]);
                sliding[step * n + j] = dot(&t, &t).sqrt();
                let force = at(&field.hat[0].force, step, j);
                let fnorm = dot(&force, normal);
                let ft: [f64; D] = std::array::from_fn(|c| force[c] - fnorm * normal[c]);
                let p = pressure[step * n + j];
                at_limit[step * n + j] = p > 0.0 && dot(&ft, &ft).sqrt() >= AT_LIMIT * friction * p;
            }
        }
        let closed_at = CLOSED_SHARE * pressure.iter().cloned().fold(0.0, f64::max);
        let sliding_at = SLIDING_SHARE * sliding.iter().cloned().fold(0.0, f64::max);
        Self { n, levels, area: &itf.area, pressure, sliding, at_limit, closed_at, sliding_at }
    }

    fn closed(&self, step: usize, j: usize) -> bool {
        self.closed_at > 0.0 && self.pressure[step * self.n + j] > self.closed_at
    }

    /// Whether node `j` slides at step `s`: in contact, moving along the wall, its traction at
    /// the friction limit.
    fn slides(&self, s: usize, j: usize) -> bool {
        self.sliding_at > 0.0
            && self.closed(s, j)
            && self.sliding[s * self.n + j] > self.sliding_at
            && self.at_limit[s * self.n + j]
    }

    /// The normal force the sliding nodes carry at step `s`.
    fn sliding_force(&self, s: usize) -> f64 {
        (0..self.n).filter(|&j| self.slides(s, j)).map(|j| self.area[j] * self.pressure[s * self.n + j]).sum()
    }

    /// The nodes in contact at some level.
    fn contact_nodes(&self) -> impl Iterator<Item = usize> + '_ {
        (0..self.n).filter(|&j| (0..self.levels).any(|s| self.closed(s, j)))
    }

    /// Node `j`'s landings after `first`, if it had been in contact before: a node's first
    /// landing (an edge rolling onto the wall) is not a lift-off's end.
    fn landings_of(&self, j: usize, first: usize) -> usize {
        let landings = (first.max(1)..self.levels).filter(|&s| self.closed(s, j) && !self.closed(s - 1, j)).count();
        let was_closed = (0..first.max(1)).any(|s| self.closed(s, j));
        if was_closed { landings } else { landings.saturating_sub(1) }
    }

    /// The total normal force at level `s`.
    fn normal_force_at(&self, s: usize) -> f64 {
        (0..self.n).map(|j| self.area[j] * self.pressure[s * self.n + j].max(0.0)).sum()
    }

    /// The total normal force at each level.
    fn normal_force(&self) -> Vec<f64> {
        (0..self.levels).map(|s| self.normal_force_at(s)).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use num_complex::Complex64;

    /// The determinant of a plane-strain surface wave exp(k (i x + c t) - k alpha y), c in units
    /// of the shear wave speed, in an elastic half-space y > 0 sliding on a rigid plane with its
    /// contact held (u_y = 0) and Coulomb's law perturbed (sigma_xy = -f sigma_yy); `side` is
    /// the wave's direction against the sliding (docs/verification.md 4d). Re c > 0 grows.
    fn determinant(c: Complex64, friction: f64, nu: f64, side: f64) -> Complex64 {
        let kappa = (1.0 - 2.0 * nu) / (2.0 * (1.0 - nu));
        let x = c * c;
        let (ap, as_) = ((1.0 + kappa * x).sqrt(), (1.0 + x).sqrt());
        Complex64::i() * side * ap * x + friction * (2.0 + x - 2.0 * ap * as_)
    }

    /// Roots with Re c > 0 found by Newton's method from a grid of starts, both directions.
    fn growing_waves(friction: f64, nu: f64) -> Vec<Complex64> {
        let mut roots = Vec::new();
        for side in [1.0, -1.0] {
            for a in 1..=15 {
                for b in -12..=12 {
                    let mut c = Complex64::new(0.2 * a as f64, 0.25 * b as f64);
                    for _ in 0..100 {
                        let d = determinant(c, friction, nu, side);
                        let h = 1e-7;
                        let slope = (determinant(c + h, friction, nu, side) - d) / h;
                        let step = d / slope;
                        c -= step;
                        if !c.is_finite() || step.norm() < 1e-14 {
                            break;
                        }
                    }
                    if c.is_finite() && c.re > 1e-6 && determinant(c, friction, nu, side).norm() < 1e-10 {
                        roots.push(c);
                    }
                }
            }
        }
        roots
    }

    #[test]
    fn the_neutral_surface_wave_sits_at_friction_one_whatever_poisson() {
        // at c = i sqrt(2): alpha_s = i, 2 + x - 2 alpha_p alpha_s = -2 i alpha_p, and the
        // determinant is -2 i alpha_p (side + f): zero for f = 1 against the sliding
        let c = Complex64::new(0.0, 2f64.sqrt());
        for nu in [0.1, 0.25, 0.33, 0.45, 0.4999] {
            assert!(determinant(c, ILL_POSED_FRICTION, nu, -1.0).norm() < 1e-12, "nu {nu}");
            assert!(determinant(c, 0.9, nu, -1.0).norm() > 1e-2, "nu {nu}");
        }
    }

    #[test]
    fn surface_waves_grow_above_friction_one_and_not_below() {
        for nu in [0.2, 0.33, 0.45] {
            for f in [0.2, 0.5, 0.9, 0.99] {
                assert!(growing_waves(f, nu).is_empty(), "f {f}, nu {nu}: {:?}", growing_waves(f, nu));
            }
            let mut rate = 0.0;
            for f in [1.05, 1.5, 2.0] {
                let roots = growing_waves(f, nu);
                let fastest = roots.iter().map(|c| c.re).fold(0.0, f64::max);
                assert!(fastest > rate, "f {f}, nu {nu}: the growth rate rises with f: {roots:?}");
                rate = fastest;
            }
        }
    }
}
