//! An independent reference for contact and friction against a rigid wall: the undecomposed mesh
//! integrated by central differences with a lumped (row-sum) mass, and each wall node's contact
//! and Coulomb friction enforced by an impulse at the end of its step (the explicit codes'
//! forward-increment Lagrange multiplier: the node is put back on the wall, and its tangential
//! velocity stopped, or slowed by f times the normal impulse, or under a Prakash-Clifton law by f
//! times the impulse that follows it). Another time scheme, another mass
//! and another contact enforcement than the LATIN solver's: what the two share is the mesh and
//! the continuous problem (docs/verification.md 4d).
//!
//! Conditionally stable: `substeps` per model step must make the inner step shorter than
//! 2 / omega_max, checked before integrating.

use glissade_core::contact::PrakashClifton;

use crate::latin::linear_stage::prescribed_velocities;
use crate::model::{InterfaceLaw, Model, QoiTarget};
use crate::monolithic::{Assembly, MonolithicError};

#[derive(Debug, thiserror::Error)]
pub enum ExplicitError {
    #[error(transparent)]
    Assembly(#[from] MonolithicError),
    #[error("explicit reference: a static stage is needed (loads at t = 0); ramp the loads from zero instead")]
    Prestressed,
    #[error(
        "explicit reference unstable: inner step {dt:.3e} s above the critical {critical:.3e} s; take more substeps"
    )]
    Unstable { dt: f64, critical: f64 },
    #[error("explicit reference: a lumped mass is not positive at dof {0}")]
    Mass(usize),
}

/// Displacement and velocity of every global dof at the model's steps 0..=N.
#[derive(Debug, Clone)]
pub struct ExplicitHistory {
    pub displacement: Vec<Vec<f64>>,
    pub velocity: Vec<Vec<f64>>,
    /// global dof of each substructure-local dof: `[substructure][local dof]`
    pub dof_map: Vec<Vec<usize>>,
    /// the inner time step and the critical one
    pub dt: f64,
    pub critical_dt: f64,
}

/// A wall node: global dofs, normal from the body towards the wall, initial gap, friction, and
/// under a Prakash-Clifton law the normal impulse (per unit mass) its friction follows and its
/// last slip rate.
struct WallNode<const D: usize> {
    dofs: [usize; D],
    normal: [f64; D],
    gap0: f64,
    friction: f64,
    regularisation: Option<PrakashClifton>,
    followed: Option<f64>,
    slip_rate: f64,
}

/// Largest eigenvalue of M^-1 K (lumped M), by power iteration from a rough vector.
fn omega_max_squared(a: &Assembly, lumped: &[f64]) -> f64 {
    let n = a.n;
    let mut x: Vec<f64> = (0..n).map(|i| if a.fixed[i] { 0.0 } else { 1.0 + ((i * 7919) % 13) as f64 }).collect();
    let mut lambda = 0.0;
    for _ in 0..500 {
        let mut y = vec![0.0; n];
        a.stiffness.mul_add(1.0, &x, &mut y);
        for i in 0..n {
            y[i] = if a.fixed[i] { 0.0 } else { y[i] / lumped[i] };
        }
        let norm = y.iter().map(|v| v * v).sum::<f64>().sqrt();
        let xnorm = x.iter().map(|v| v * v).sum::<f64>().sqrt();
        if norm == 0.0 || xnorm == 0.0 {
            return 0.0;
        }
        let next = norm / xnorm;
        x = y.iter().map(|v| v / norm).collect();
        if (next - lambda).abs() <= 1e-6 * next {
            return next;
        }
        lambda = next;
    }
    lambda
}

/// Integrates the model with `substeps` central-difference steps per model step.
pub fn solve<const D: usize>(m: &Model<D>, substeps: usize) -> Result<ExplicitHistory, ExplicitError> {
    if m.needs_static_stage() {
        return Err(ExplicitError::Prestressed);
    }
    let mut a = Assembly::new(m, true)?;
    let n = a.n;
    let mut lumped = vec![0.0; n];
    for (i, l) in lumped.iter_mut().enumerate() {
        *l = (a.mass.row_ptr[i]..a.mass.row_ptr[i + 1]).map(|p| a.mass.val[p]).sum();
        if !a.fixed[i] && *l <= 0.0 {
            return Err(ExplicitError::Mass(i));
        }
    }
    let dt = m.dt / substeps.max(1) as f64;
    // 0.9 of the bound, for the power iteration's shortfall
    let critical_dt = 0.9 * 2.0 / omega_max_squared(&a, &lumped).sqrt();
    if dt > critical_dt {
        return Err(ExplicitError::Unstable { dt, critical: critical_dt });
    }
    let mut wall: Vec<WallNode<D>> = Vec::new();
    for &i in &a.walls {
        let itf = &m.interfaces[i];
        let (friction, regularisation) = match itf.law {
            InterfaceLaw::Friction { coefficient, regularisation } => (coefficient, regularisation),
            _ => (0.0, None),
        };
        let side = &itf.sides[0];
        for (j, &node) in side.nodes.iter().enumerate() {
            let dofs = std::array::from_fn(|c| a.dof_map[side.substructure][node * D + c]);
            let (normal, gap0) = (itf.normal[j], itf.gap0[j]);
            wall.push(WallNode { dofs, normal, gap0, friction, regularisation, followed: None, slip_rate: 0.0 });
        }
    }

    let mut u = vec![0.0; n];
    let mut v = a.v0.clone();
    let mut f = vec![0.0; n];
    let mut prescribed = vec![0.0; n];
    let mut t = 0.0;
    // acceleration at t: M^-1 (f - K u), zero on prescribed dofs
    let accel = |a: &mut Assembly, t: f64, u: &[f64], f: &mut Vec<f64>| {
        a.external(m, t, f);
        a.stiffness.mul_add(-1.0, u, f);
        for i in 0..n {
            f[i] = if a.fixed[i] { 0.0 } else { f[i] / lumped[i] };
        }
    };
    prescribed_velocities(&a.prescribed, &m.histories, 0.0, &mut prescribed);
    for p in &a.prescribed {
        v[p.dof] = prescribed[p.dof];
    }
    let mut displacement = vec![u.clone()];
    let mut velocity = vec![v.clone()];
    // v holds v_{n-1/2} after the first half step
    accel(&mut a, t, &u, &mut f);
    let mut half: Vec<f64> = (0..n).map(|i| v[i] + 0.5 * dt * f[i]).collect();
    for _ in 0..m.steps {
        for _ in 0..substeps.max(1) {
            let t_next = t + dt;
            prescribed_velocities(&a.prescribed, &m.histories, t + 0.5 * dt, &mut prescribed);
            for p in &a.prescribed {
                half[p.dof] = prescribed[p.dof];
            }
            // contact: the impulse that puts the node on the wall at t_next, friction bounded by it
            // (or, under a Prakash-Clifton law, by the impulse that follows it with a lag)
            for w in &mut wall {
                let un: f64 = (0..D).map(|c| w.normal[c] * u[w.dofs[c]]).sum();
                let vn: f64 = (0..D).map(|c| w.normal[c] * half[w.dofs[c]]).sum();
                let gap = w.gap0 - un - dt * vn;
                // normal velocity change (along -n, away from the wall), per unit mass
                let dvn = gap.min(0.0) / dt;
                let bound = match w.regularisation {
                    Some(law) => law.step(&mut w.followed, dvn.abs(), w.slip_rate, dt),
                    None => dvn.abs(),
                };
                let mut vt = [0.0; D];
                for c in 0..D {
                    vt[c] = half[w.dofs[c]] - vn * w.normal[c];
                }
                let vt_norm = vt.iter().map(|x| x * x).sum::<f64>().sqrt();
                w.slip_rate = vt_norm;
                if gap >= 0.0 {
                    continue;
                }
                let keep = if vt_norm <= w.friction * bound { 0.0 } else { 1.0 - w.friction * bound / vt_norm };
                w.slip_rate = keep * vt_norm;
                for c in 0..D {
                    let d = w.dofs[c];
                    if !a.fixed[d] {
                        half[d] = (vn + dvn) * w.normal[c] + keep * vt[c];
                    }
                }
            }
            for i in 0..n {
                u[i] += dt * half[i];
            }
            t = t_next;
            accel(&mut a, t, &u, &mut f);
            for i in 0..n {
                v[i] = half[i] + 0.5 * dt * f[i];
                half[i] += dt * f[i];
            }
        }
        prescribed_velocities(&a.prescribed, &m.histories, t, &mut prescribed);
        for p in &a.prescribed {
            v[p.dof] = prescribed[p.dof];
        }
        displacement.push(u.clone());
        velocity.push(v.clone());
    }
    Ok(ExplicitHistory { displacement, velocity, dof_map: a.dof_map, dt, critical_dt })
}

impl ExplicitHistory {
    /// The history of a slip (on a wall interface), displacement or velocity QoI; `None` for the
    /// QoIs this reference does not compute (interface forces, slips between two bodies).
    pub fn qoi<const D: usize>(&self, m: &Model<D>, target: &QoiTarget) -> Option<Vec<f64>> {
        match *target {
            QoiTarget::Displacement { substructure, dof } => {
                let g = self.dof_map[substructure][dof];
                Some(self.displacement.iter().map(|u| u[g]).collect())
            }
            QoiTarget::Velocity { substructure, dof } => {
                let g = self.dof_map[substructure][dof];
                Some(self.velocity.iter().map(|v| v[g]).collect())
            }
            QoiTarget::Slip { interface, node, component } => {
                let itf = &m.interfaces[interface];
                if itf.sides.len() != 1 {
                    return None;
                }
                let side = &itf.sides[0];
                let dofs: [usize; D] =
                    std::array::from_fn(|c| self.dof_map[side.substructure][side.nodes[node] * D + c]);
                let n = itf.normal[node];
                let u0 = &self.displacement[0];
                Some(
                    self.displacement
                        .iter()
                        .map(|u| {
                            // the wall's slip over the body: minus the body's tangential displacement
                            let d: [f64; D] = std::array::from_fn(|c| -(u[dofs[c]] - u0[dofs[c]]));
                            let dn: f64 = (0..D).map(|c| d[c] * n[c]).sum();
                            let t: [f64; D] = std::array::from_fn(|c| d[c] - dn * n[c]);
                            match component {
                                Some(c) => t[c],
                                None => t.iter().map(|x| x * x).sum::<f64>().sqrt(),
                            }
                        })
                        .collect(),
                )
            }
            QoiTarget::Force { .. } => None,
        }
    }
}
