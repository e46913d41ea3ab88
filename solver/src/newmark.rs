//! Newmark average acceleration (beta = 1/4, gamma = 1/2) in velocity form (docs/method.md 3):
//! [(2/dt) M + (dt/2) K] v_{n+1} = f_{n+1} + M ((2/dt) v_n + a_n) - K (u_n + (dt/2) v_n).
//! Shared by the LATIN linear stage and the monolithic reference, so both integrate alike.

use crate::sparse::CsrMatrix;

/// State (u, v, a) of a discretised body and a scratch vector.
#[derive(Debug, Clone)]
pub struct NewmarkState {
    pub u: Vec<f64>,
    pub v: Vec<f64>,
    pub a: Vec<f64>,
    tmp: Vec<f64>,
}

impl NewmarkState {
    pub fn new(n: usize) -> Self {
        Self { u: vec![0.0; n], v: vec![0.0; n], a: vec![0.0; n], tmp: vec![0.0; n] }
    }

    /// rhs += M ((2/dt) v_n + a_n) - K (u_n + (dt/2) v_n)
    pub fn add_history(&mut self, mass: &CsrMatrix, stiffness: &CsrMatrix, dt: f64, rhs: &mut [f64]) {
        for i in 0..self.tmp.len() {
            self.tmp[i] = 2.0 / dt * self.v[i] + self.a[i];
        }
        mass.mul_add(1.0, &self.tmp, rhs);
        for i in 0..self.tmp.len() {
            self.tmp[i] = self.u[i] + 0.5 * dt * self.v[i];
        }
        stiffness.mul_add(-1.0, &self.tmp, rhs);
    }

    /// Advances to v_{n+1} = `v_new`: trapezoidal displacement, Newmark acceleration.
    pub fn advance(&mut self, v_new: &[f64], dt: f64) {
        for i in 0..v_new.len() {
            let a_new = 2.0 / dt * (v_new[i] - self.v[i]) - self.a[i];
            self.u[i] += 0.5 * dt * (self.v[i] + v_new[i]);
            self.v[i] = v_new[i];
            self.a[i] = a_new;
        }
    }
}

/// The Newmark step operator (2/dt) M + (dt/2) K.
pub fn step_operator(mass: &CsrMatrix, stiffness: &CsrMatrix, dt: f64) -> CsrMatrix {
    mass.combine(2.0 / dt, stiffness, dt / 2.0)
}
