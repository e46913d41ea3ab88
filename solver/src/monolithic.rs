//! The monolithic reference: the undecomposed mesh assembled once and integrated with the same
//! Newmark scheme. Perfect interfaces and boundary conditions only. It is the oracle of the tests
//! and the "direct" baseline of the benchmarks.

use crate::latin::linear_stage::prescribed_velocities;
use crate::model::{InterfaceLaw, Model, PrescribedDof};
use crate::newmark::{NewmarkState, step_operator};
use crate::sparse::{CsrMatrix, FactorisedOperator, SparseError};

#[derive(Debug, thiserror::Error)]
pub enum MonolithicError {
    #[error(
        "the monolithic reference handles perfect interfaces (and, explicit, contact with a wall) only; interface '{0}' is another"
    )]
    NotPerfect(String),
    #[error(transparent)]
    Sparse(#[from] SparseError),
}

/// Displacement and velocity of every global dof at steps 0..=N.
#[derive(Debug, Clone)]
pub struct MonolithicHistory {
    pub displacement: Vec<Vec<f64>>,
    pub velocity: Vec<Vec<f64>>,
    /// global dof of each substructure-local dof: `[substructure][local dof]`
    pub dof_map: Vec<Vec<usize>>,
    /// wall-clock seconds of the factorisation and of the time sweep
    pub factorisation_seconds: f64,
    pub sweep_seconds: f64,
}

fn find(parent: &mut [usize], mut i: usize) -> usize {
    while parent[i] != i {
        parent[i] = parent[parent[i]];
        i = parent[i];
    }
    i
}

/// The undecomposed problem: substructure nodes joined by perfect interfaces merged, operators
/// summed. Shared by the Newmark reference here and the explicit one (`explicit`).
pub struct Assembly {
    /// global dofs
    pub n: usize,
    /// global dof of each substructure-local dof: `[substructure][local dof]`
    pub dof_map: Vec<Vec<usize>>,
    pub stiffness: CsrMatrix,
    pub mass: CsrMatrix,
    pub fixed: Vec<bool>,
    pub prescribed: Vec<PrescribedDof>,
    /// initial velocity of every dof
    pub v0: Vec<f64>,
    /// interfaces with a rigid wall (one side), by index into `Model::interfaces`
    pub walls: Vec<usize>,
    scratch: Vec<Vec<f64>>,
}

impl Assembly {
    /// Merges the perfect interfaces; a wall interface is kept in `walls` when `walls_allowed`,
    /// any other interface is refused.
    pub fn new<const D: usize>(m: &Model<D>, walls_allowed: bool) -> Result<Self, MonolithicError> {
        // Merge substructure nodes joined by perfect interfaces (union-find over all local nodes).
        let offsets: Vec<usize> = m
            .substructures
            .iter()
            .scan(0, |acc, s| {
                let o = *acc;
                *acc += s.nodes.len();
                Some(o)
            })
            .collect();
        let total: usize = m.substructures.iter().map(|s| s.nodes.len()).sum();
        let mut parent: Vec<usize> = (0..total).collect();
        let mut walls = Vec::new();
        for (i, itf) in m.interfaces.iter().enumerate() {
            let wall = itf.sides.len() == 1 && matches!(itf.law, InterfaceLaw::Contact | InterfaceLaw::Friction { .. });
            if wall && walls_allowed {
                walls.push(i);
                continue;
            }
            if itf.law != InterfaceLaw::Perfect || itf.sides.len() != 2 {
                return Err(MonolithicError::NotPerfect(itf.name.clone()));
            }
            let (a, b) = (&itf.sides[0], &itf.sides[1]);
            for (&na, &nb) in a.nodes.iter().zip(&b.nodes) {
                let ra = find(&mut parent, offsets[a.substructure] + na);
                let rb = find(&mut parent, offsets[b.substructure] + nb);
                parent[ra.max(rb)] = ra.min(rb);
            }
        }
        let mut global_node = vec![usize::MAX; total];
        let mut n_nodes = 0;
        for i in 0..total {
            let r = find(&mut parent, i);
            if global_node[r] == usize::MAX {
                global_node[r] = n_nodes;
                n_nodes += 1;
            }
            global_node[i] = global_node[r];
        }
        let n = n_nodes * D;
        let dof_map: Vec<Vec<usize>> = m
            .substructures
            .iter()
            .enumerate()
            .map(|(s, sub)| (0..sub.n_dofs()).map(|l| global_node[offsets[s] + l / D] * D + l % D).collect())
            .collect();

        // Assemble by summing the substructure operators (they are the element sums).
        let (mut kt, mut mt) = (Vec::new(), Vec::new());
        let mut fixed = vec![false; n];
        let mut prescribed: Vec<PrescribedDof> = Vec::new();
        let mut v0 = vec![0.0; n];
        for (s, sub) in m.substructures.iter().enumerate() {
            let map = &dof_map[s];
            for (mat, out) in [(&sub.stiffness, &mut kt), (&sub.mass, &mut mt)] {
                for i in 0..mat.n {
                    for p in mat.row_ptr[i]..mat.row_ptr[i + 1] {
                        out.push((map[i], map[mat.col[p]], mat.val[p]));
                    }
                }
            }
            for p in &sub.prescribed {
                let g = map[p.dof];
                if !fixed[g] {
                    fixed[g] = true;
                    prescribed.push(PrescribedDof { dof: g, ..p.clone() });
                }
            }
            for (l, &g) in map.iter().enumerate() {
                v0[g] = sub.initial_velocity[l % D];
            }
        }
        let scratch = m.substructures.iter().map(|s| vec![0.0; s.n_dofs()]).collect();
        Ok(Self {
            n,
            dof_map,
            stiffness: CsrMatrix::from_triplets(n, kt),
            mass: CsrMatrix::from_triplets(n, mt),
            fixed,
            prescribed,
            v0,
            walls,
            scratch,
        })
    }

    /// The global external forces at time t.
    pub fn external<const D: usize>(&mut self, m: &Model<D>, t: f64, out: &mut [f64]) {
        out.fill(0.0);
        for (s, sub) in m.substructures.iter().enumerate() {
            sub.external_force(&m.histories, t, &mut self.scratch[s]);
            for (l, &g) in self.dof_map[s].iter().enumerate() {
                out[g] += self.scratch[s][l];
            }
        }
    }
}

/// Assembles and integrates the undecomposed problem.
pub fn solve<const D: usize>(m: &Model<D>) -> Result<MonolithicHistory, MonolithicError> {
    let mut a = Assembly::new(m, false)?;
    let n = a.n;
    let start = std::time::Instant::now();
    let mut step_op = FactorisedOperator::new(step_operator(m.newmark, &a.mass, &a.stiffness, m.dt), &a.fixed)?;
    let mut state = NewmarkState::new(n);
    let mut rhs = vec![0.0; n];
    if m.needs_static_stage() {
        let mut static_op = FactorisedOperator::new(a.stiffness.clone(), &a.fixed)?;
        a.external(m, 0.0, &mut rhs);
        for p in &a.prescribed {
            state.u[p.dof] = p.static_displacement;
        }
        static_op.solve(&rhs, &mut state.u, true);
    }
    let factorisation_seconds = start.elapsed().as_secs_f64();
    let start = std::time::Instant::now();
    state.v.copy_from_slice(&a.v0);
    for p in &a.prescribed {
        state.v[p.dof] = p.velocity * m.histories[p.history].at(0.0);
    }
    let mut displacement = vec![state.u.clone()];
    let mut velocity = vec![state.v.clone()];
    let mut x = vec![0.0; n];
    for step in 0..m.steps {
        let t = (step + 1) as f64 * m.dt;
        a.external(m, t, &mut rhs);
        state.add_history(m.newmark, &a.mass, &a.stiffness, m.dt, &mut rhs);
        let nonzero = prescribed_velocities(&a.prescribed, &m.histories, t, &mut x);
        step_op.solve(&rhs, &mut x, nonzero);
        state.advance(m.newmark, &x, m.dt);
        displacement.push(state.u.clone());
        velocity.push(state.v.clone());
    }
    Ok(MonolithicHistory {
        displacement,
        velocity,
        dof_map: a.dof_map,
        factorisation_seconds,
        sweep_seconds: start.elapsed().as_secs_f64(),
    })
}
