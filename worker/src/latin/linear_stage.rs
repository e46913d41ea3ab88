//! Linear stage: each substructure's dynamics (Newmark average acceleration, velocity form) or
//! statics, driven by the local-stage fields through the search direction E- (METHOD.md 3).
//!
//! A = (2/dt) M + (dt/2) K + N^T M_Gamma k N is factorised once per substructure; a sweep over the
//! time steps is then one sparse solve and two sparse products per step.

use crate::model::{Interface, Model, PrescribedDof, Substructure};
use crate::newmark::{NewmarkState, step_operator};
use crate::scene::History;
use crate::sparse::{FactorisedOperator, SparseError};

use super::field::InterfaceField;

/// Which problem a sweep solves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// prestress: K u = f(0) + interface, W holds displacements, one step
    Static,
    /// Newmark over the time interval
    Dynamic,
}

impl Stage {
    pub fn k(self, side: &crate::model::InterfaceSide) -> f64 {
        match self {
            Stage::Static => side.k_static,
            Stage::Dynamic => side.k_dynamic,
        }
    }
}

/// The operators of one substructure, factorised once, and its work vectors.
pub struct SubstructureOperators {
    dynamic: FactorisedOperator,
    statics: Option<FactorisedOperator>,
    state: NewmarkState,
    x: Vec<f64>,
    rhs: Vec<f64>,
}

/// Interface contribution N^T M_Gamma k N: a diagonal over the interface dofs.
fn interface_diagonal<const D: usize>(sub: &Substructure<D>, interfaces: &[Interface<D>], stage: Stage) -> Vec<f64> {
    let mut d = vec![0.0; sub.n_dofs()];
    for &(i, side) in &sub.sides {
        let itf = &interfaces[i];
        let s = &itf.sides[side];
        for (j, &node) in s.nodes.iter().enumerate() {
            for c in 0..D {
                d[node * D + c] += itf.area[j] * stage.k(s);
            }
        }
    }
    d
}

impl SubstructureOperators {
    pub fn new<const D: usize>(model: &Model<D>, s: usize, with_static: bool) -> Result<Self, SparseError> {
        let sub = &model.substructures[s];
        let dt = model.dt;
        let a = step_operator(&sub.mass, &sub.stiffness, dt).add_diagonal(&interface_diagonal(
            sub,
            &model.interfaces,
            Stage::Dynamic,
        ));
        let dynamic = FactorisedOperator::new(a, &sub.fixed)?;
        let statics = if with_static {
            let a = sub.stiffness.add_diagonal(&interface_diagonal(sub, &model.interfaces, Stage::Static));
            Some(FactorisedOperator::new(a, &sub.fixed)?)
        } else {
            None
        };
        let n = sub.n_dofs();
        Ok(Self { dynamic, statics, state: NewmarkState::new(n), x: vec![0.0; n], rhs: vec![0.0; n] })
    }

    /// Adds N^T M_Gamma (F^ + k W^) of step `step` to `rhs`.
    fn add_interface_load<const D: usize>(
        rhs: &mut [f64],
        sub: &Substructure<D>,
        interfaces: &[Interface<D>],
        fields: &[InterfaceField],
        stage: Stage,
        step: usize,
    ) {
        for &(i, side) in &sub.sides {
            let itf = &interfaces[i];
            let s = &itf.sides[side];
            let k = stage.k(s);
            let hat = &fields[i].hat[side];
            let m = s.nodes.len();
            for (j, &node) in s.nodes.iter().enumerate() {
                for c in 0..D {
                    let idx = (step * m + j) * D + c;
                    rhs[node * D + c] += itf.area[j] * (hat.force[idx] + k * hat.velocity[idx]);
                }
            }
        }
    }

    /// Extracts W = N x and F = F^ + k (W^ - W) on this substructure's sides at `step`.
    fn extract_interface<const D: usize>(
        x: &[f64],
        sub: &Substructure<D>,
        interfaces: &[Interface<D>],
        fields: &mut [InterfaceField],
        stage: Stage,
        step: usize,
    ) {
        for &(i, side) in &sub.sides {
            let s = &interfaces[i].sides[side];
            let k = stage.k(s);
            let m = s.nodes.len();
            let f = &mut fields[i];
            let (hat, lin) = (&f.hat[side], &mut f.s[side]);
            for (j, &node) in s.nodes.iter().enumerate() {
                for c in 0..D {
                    let idx = (step * m + j) * D + c;
                    let w = x[node * D + c];
                    lin.velocity[idx] = w;
                    lin.force[idx] = hat.force[idx] + k * (hat.velocity[idx] - w);
                }
            }
        }
    }

    /// Static sweep: solves K u = f(0) + interface with the prescribed displacements; writes the
    /// sides' `s` fields (W = displacement) and returns u.
    pub fn static_sweep<const D: usize>(
        &mut self,
        model: &Model<D>,
        s: usize,
        fields: &mut [InterfaceField],
    ) -> Vec<f64> {
        let sub = &model.substructures[s];
        let op = self.statics.as_mut().expect("static operator factorised when the stage is needed");
        sub.external_force(&model.histories, 0.0, &mut self.rhs);
        Self::add_interface_load(&mut self.rhs, sub, &model.interfaces, fields, Stage::Static, 0);
        self.x.fill(0.0);
        let mut nonzero = false;
        for p in &sub.prescribed {
            self.x[p.dof] = p.static_displacement;
            nonzero |= p.static_displacement != 0.0;
        }
        op.solve(&self.rhs, &mut self.x, nonzero);
        Self::extract_interface(&self.x, sub, &model.interfaces, fields, Stage::Static, 0);
        self.x.clone()
    }

    /// Dynamic sweep over all steps from the initial displacement `u0`; writes the sides' `s`
    /// fields and calls `record(step, u, v)` after each step (step 0 is the initial state).
    pub fn dynamic_sweep<const D: usize>(
        &mut self,
        model: &Model<D>,
        s: usize,
        u0: Option<&[f64]>,
        fields: &mut [InterfaceField],
        mut record: Option<&mut dyn FnMut(usize, &[f64], &[f64])>,
    ) {
        let sub = &model.substructures[s];
        let dt = model.dt;
        let st = &mut self.state;
        match u0 {
            Some(u0) => st.u.copy_from_slice(u0),
            None => st.u.fill(0.0),
        }
        for (i, v) in st.v.iter_mut().enumerate() {
            *v = sub.initial_velocity[i % D];
        }
        for p in &sub.prescribed {
            st.v[p.dof] = p.velocity * model.histories[p.history].at(0.0);
        }
        // the initial state is a static equilibrium (METHOD.md 3, prestress): a0 = 0
        st.a.fill(0.0);
        if let Some(r) = record.as_mut() {
            r(0, &st.u, &st.v);
        }
        for step in 0..model.steps {
            let t = (step + 1) as f64 * dt;
            sub.external_force(&model.histories, t, &mut self.rhs);
            Self::add_interface_load(&mut self.rhs, sub, &model.interfaces, fields, Stage::Dynamic, step);
            st.add_history(&sub.mass, &sub.stiffness, dt, &mut self.rhs);
            let nonzero = prescribed_velocities(&sub.prescribed, &model.histories, t, &mut self.x);
            self.dynamic.solve(&self.rhs, &mut self.x, nonzero);
            st.advance(&self.x, dt);
            Self::extract_interface(&self.x, sub, &model.interfaces, fields, Stage::Dynamic, step);
            if let Some(r) = record.as_mut() {
                r(step + 1, &st.u, &st.v);
            }
        }
    }
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
