//! Linear stage: each substructure's dynamics (Newmark, velocity form: `crate::newmark`) or
//! statics, driven by the local-stage fields through the search direction E- (docs/method.md 3).
//!
//! A = (2/dt) M + (dt/2) K + N^T M_Gamma k N (or K + N^T M_Gamma k N in the static stage) is
//! factorised once per substructure. Each step is split so that the macro problem can sit between
//! the two micro problems: `predict` (micro problem 1), then optionally `correct` (micro problem 2,
//! a combination of precomputed responses to the macro basis), then `finish`.

use crate::model::{Interface, InterfaceSide, Model, PrescribedDof, Substructure};
use crate::newmark::{NewmarkState, step_operator};
use crate::search_direction::SearchDirection;
use crate::sparse::{FactorisedOperator, SparseError};
use glissade_core::scene::History;

use glissade_core::field::InterfaceField;

/// Which problem the linear stage solves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// prestress: K u = f(0) + interface, W holds displacements, one step
    Static,
    /// Newmark over the time interval
    Dynamic,
}

impl Stage {
    pub fn k(self, side: &InterfaceSide) -> SearchDirection {
        match self {
            Stage::Static => side.k_static,
            Stage::Dynamic => side.k_dynamic,
        }
    }

    /// What the static part from node to node ([`InterfaceSide::k_along`]) is multiplied by:
    /// 1 statically, beta dt / gamma (dt/2 for the trapezoidal rule) in the dynamic stage (where
    /// W is a velocity: within one step a side opposes that times its stiffness to it).
    pub fn along_factor<const D: usize>(self, model: &Model<D>) -> f64 {
        match self {
            Stage::Static => 1.0,
            Stage::Dynamic => model.newmark.new_velocity_weight(model.dt),
        }
    }

    pub fn steps<const D: usize>(self, model: &Model<D>) -> usize {
        match self {
            Stage::Static => 1,
            Stage::Dynamic => model.steps,
        }
    }

    /// Iterations the stage may run: the model's limit, the static stage's
    /// [`super::STATIC_ITERATIONS_FACTOR`] times more (no more times than there are steps: an
    /// iteration of it sweeps one).
    pub fn iteration_limit<const D: usize>(self, model: &Model<D>) -> usize {
        let limit = model.settings.max_iterations;
        match self {
            Stage::Static => limit.saturating_mul(super::STATIC_ITERATIONS_FACTOR.min(model.steps).max(1)),
            Stage::Dynamic => limit,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Stage::Static => "static",
            Stage::Dynamic => "dynamic",
        }
    }
}

/// The operators of one substructure, factorised once, and its work vectors.
pub struct SubstructureOperators {
    dynamic: FactorisedOperator,
    statics: Option<FactorisedOperator>,
    state: NewmarkState,
    /// v_{n+1} (dynamic) or u (static) being computed
    pub x: Vec<f64>,
    rhs: Vec<f64>,
}

/// Interface contribution N^T M_Gamma k N: a D x D block per interface node (its normal and
/// tangential values), as triplets.
fn interface_blocks<const D: usize>(
    sub: &Substructure<D>,
    interfaces: &[Interface<D>],
    stage: Stage,
    along_factor: f64,
) -> Vec<(usize, usize, f64)> {
    let mut t = Vec::new();
    for &(i, side) in &sub.sides {
        let itf = &interfaces[i];
        let s = &itf.sides[side];
        let k = stage.k(s);
        for (j, &node) in s.nodes.iter().enumerate() {
            for a in 0..D {
                for b in 0..D {
                    let v = itf.area[j] * k.entry(&itf.normal[j], a, b);
                    if v != 0.0 {
                        t.push((node * D + a, node * D + b, v));
                    }
                }
            }
        }
        for &(j, l, v) in &s.k_along {
            for c in 0..D {
                t.push((s.nodes[j] * D + c, s.nodes[l] * D + c, along_factor * v));
            }
        }
    }
    t
}

/// y += factor L v over a side's nodes (its [`InterfaceSide::k_along`]): v and y hold D
/// components a node, `at` is the first node's offset in v (a step's), y's starts at zero.
pub fn add_along<const D: usize>(side: &InterfaceSide, factor: f64, v: &[f64], at: usize, y: &mut [f64]) {
    for &(j, l, w) in &side.k_along {
        for c in 0..D {
            y[j * D + c] += factor * w * v[at + l * D + c];
        }
    }
}

/// The traction of the part from node to node at each node, M_Gamma^-1 factor L v (v: D
/// components a node, one step).
pub fn along_traction<const D: usize>(side: &InterfaceSide, factor: f64, v: &[f64], area: &[f64]) -> Vec<f64> {
    let mut y = vec![0.0; v.len()];
    add_along::<D>(side, factor, v, 0, &mut y);
    for (q, y) in y.iter_mut().enumerate() {
        *y /= area[q / D];
    }
    y
}

impl SubstructureOperators {
    pub fn new<const D: usize>(model: &Model<D>, s: usize, with_static: bool) -> Result<Self, SparseError> {
        let sub = &model.substructures[s];
        let a = step_operator(model.newmark, &sub.mass, &sub.stiffness, model.dt).add_triplets(interface_blocks(
            sub,
            &model.interfaces,
            Stage::Dynamic,
            Stage::Dynamic.along_factor(model),
        ));
        let dynamic = FactorisedOperator::new(a, &sub.fixed)?;
        let statics = if with_static {
            let a = sub.stiffness.add_triplets(interface_blocks(sub, &model.interfaces, Stage::Static, 1.0));
            Some(FactorisedOperator::new(a, &sub.fixed)?)
        } else {
            None
        };
        let n = sub.n_dofs();
        Ok(Self { dynamic, statics, state: NewmarkState::new(n), x: vec![0.0; n], rhs: vec![0.0; n] })
    }

    /// Values in the dynamic operator's factor ([`FactorisedOperator::factor_len`]).
    pub fn dynamic_factor_len(&self) -> usize {
        self.dynamic.factor_len()
    }

    fn operator(&mut self, stage: Stage) -> &mut FactorisedOperator {
        match stage {
            Stage::Static => self.statics.as_mut().expect("static operator factorised when the stage is needed"),
            Stage::Dynamic => &mut self.dynamic,
        }
    }

    /// Solves A q = rhs with zero prescribed values and no history (macro basis responses).
    pub fn solve_homogeneous(&mut self, stage: Stage, rhs: &[f64]) -> Vec<f64> {
        let mut q = vec![0.0; rhs.len()];
        self.operator(stage).solve(rhs, &mut q, false);
        q
    }

    /// Sets the initial state of a stage: u0 (the prestressed state or zero), v0, a0 = 0.
    pub fn start<const D: usize>(&mut self, model: &Model<D>, s: usize, stage: Stage, u0: Option<&[f64]>) {
        let sub = &model.substructures[s];
        let st = &mut self.state;
        match (stage, u0) {
            (Stage::Dynamic, Some(u0)) => st.u.copy_from_slice(u0),
            _ => st.u.fill(0.0),
        }
        for (i, v) in st.v.iter_mut().enumerate() {
            *v = if stage == Stage::Dynamic { sub.initial_velocity[i % D] } else { 0.0 };
        }
        if stage == Stage::Dynamic {
            for p in &sub.prescribed {
                st.v[p.dof] = p.velocity * model.histories[p.history].at(0.0);
            }
        }
        // the initial state is a static equilibrium (docs/method.md 3, prestress): a0 = 0
        st.a.fill(0.0);
    }

    /// The Newmark state, to start a later time window from (docs/method.md, "Time windows").
    pub fn save(&self) -> NewmarkState {
        self.state.clone()
    }

    /// Starts from a state saved by [`Self::save`] instead of the initial one.
    pub fn restore(&mut self, state: &NewmarkState) {
        self.state.clone_from(state);
    }

    /// Current (u, v) of the substructure.
    pub fn state(&self) -> (&[f64], &[f64]) {
        (&self.state.u, &self.state.v)
    }

    /// Micro problem 1 of step `step`: x = A^-1 [f + N^T M_Gamma (F^ + k W^) + history].
    pub fn predict<const D: usize>(
        &mut self,
        model: &Model<D>,
        s: usize,
        stage: Stage,
        step: usize,
        fields: &[InterfaceField],
    ) {
        let sub = &model.substructures[s];
        let t = match stage {
            Stage::Static => 0.0,
            Stage::Dynamic => (step + 1) as f64 * model.dt,
        };
        sub.external_force(&model.histories, t, &mut self.rhs);
        for &(i, side) in &sub.sides {
            let itf = &model.interfaces[i];
            let sd = &itf.sides[side];
            let k = stage.k(sd);
            let hat = &fields[i].hat[side];
            let m = sd.nodes.len();
            for (j, &node) in sd.nodes.iter().enumerate() {
                let at = (step * m + j) * D;
                let kw = k.apply(&itf.normal[j], &node_vector(&hat.velocity[at..at + D]));
                for c in 0..D {
                    self.rhs[node * D + c] += itf.area[j] * (hat.force[at + c] + kw[c]);
                }
            }
            if !sd.k_along.is_empty() {
                let mut lw = vec![0.0; m * D];
                add_along::<D>(sd, stage.along_factor(model), &hat.velocity, step * m * D, &mut lw);
                for (j, &node) in sd.nodes.iter().enumerate() {
                    for c in 0..D {
                        self.rhs[node * D + c] += lw[j * D + c];
                    }
                }
            }
        }
        let nonzero = match stage {
            Stage::Static => {
                self.x.fill(0.0);
                let mut nonzero = false;
                for p in &sub.prescribed {
                    self.x[p.dof] = p.static_displacement;
                    nonzero |= p.static_displacement != 0.0;
                }
                nonzero
            }
            Stage::Dynamic => {
                self.state.add_history(model.newmark, &sub.mass, &sub.stiffness, model.dt, &mut self.rhs);
                prescribed_velocities(&sub.prescribed, &model.histories, t, &mut self.x)
            }
        };
        let rhs = std::mem::take(&mut self.rhs);
        let mut x = std::mem::take(&mut self.x);
        self.operator(stage).solve(&rhs, &mut x, nonzero);
        self.rhs = rhs;
        self.x = x;
    }

    /// Writes W = N x and F = F^ + k (W^ - W + W~) on this substructure's sides at `step`, where
    /// W~ is the macro correction field of each side (zero in single-scale), then advances the
    /// Newmark state.
    pub fn finish<const D: usize>(
        &mut self,
        model: &Model<D>,
        s: usize,
        stage: Stage,
        step: usize,
        fields: &mut [InterfaceField],
        macro_field: &dyn Fn(usize, usize, usize, usize) -> f64,
    ) {
        let sub = &model.substructures[s];
        for &(i, side) in &sub.sides {
            let itf = &model.interfaces[i];
            let sd = &itf.sides[side];
            let k = stage.k(sd);
            let m = sd.nodes.len();
            let f = &mut fields[i];
            let (hat, lin) = (&f.hat[side], &mut f.s[side]);
            for (j, &node) in sd.nodes.iter().enumerate() {
                let at = (step * m + j) * D;
                let jump: [f64; D] =
                    std::array::from_fn(|c| hat.velocity[at + c] - self.x[node * D + c] + macro_field(i, side, j, c));
                let kj = k.apply(&itf.normal[j], &jump);
                for c in 0..D {
                    lin.velocity[at + c] = self.x[node * D + c];
                    lin.force[at + c] = hat.force[at + c] + kj[c];
                }
            }
            if !sd.k_along.is_empty() {
                let jumps: Vec<f64> = (0..m * D)
                    .map(|k| {
                        hat.velocity[step * m * D + k] - self.x[sd.nodes[k / D] * D + k % D]
                            + macro_field(i, side, k / D, k % D)
                    })
                    .collect();
                let traction = along_traction::<D>(sd, stage.along_factor(model), &jumps, &itf.area);
                for (f, t) in lin.force[step * m * D..(step + 1) * m * D].iter_mut().zip(traction) {
                    *f += t;
                }
            }
        }
        match stage {
            Stage::Static => self.state.u.copy_from_slice(&self.x),
            Stage::Dynamic => self.state.advance(model.newmark, &self.x, model.dt),
        }
    }
}

/// The D components of one node, copied out of a field.
pub fn node_vector<const D: usize>(v: &[f64]) -> [f64; D] {
    std::array::from_fn(|c| v[c])
}

/// Zeroes `x` and writes the prescribed velocities at time t; says whether any is non-zero.
pub fn prescribed_velocities(prescribed: &[PrescribedDof], histories: &[History], t: f64, x: &mut [f64]) -> bool {
    x.fill(0.0);
    let mut nonzero = false;
    for p in prescribed {
        let v = p.velocity * histories[p.history].at(t);
        x[p.dof] = v;
        nonzero |= v != 0.0;
    }
    nonzero
}
