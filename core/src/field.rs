//! Interface unknowns over the whole time interval (docs/method.md 3).

use serde::{Deserialize, Serialize};

/// Force and velocity histories on one side of an interface. Index `(step * nodes + node) * D + c`;
/// in the static stage there is one step and "velocity" holds displacements.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SideField {
    /// F: traction exerted by the interface on this side (Pa)
    pub force: Vec<f64>,
    /// W: velocity of this side (m/s), or displacement (m) in the static stage
    pub velocity: Vec<f64>,
}

impl SideField {
    pub fn zeros(len: usize) -> Self {
        Self { force: vec![0.0; len], velocity: vec![0.0; len] }
    }

    /// self <- mu * self + (1 - mu) * old: the relaxation of docs/method.md 3, in place on the
    /// new field
    pub fn relax_from(&mut self, old: &SideField, mu: f64) {
        for (a, b) in self.force.iter_mut().zip(&old.force) {
            *a = mu * *a + (1.0 - mu) * b;
        }
        for (a, b) in self.velocity.iter_mut().zip(&old.velocity) {
            *a = mu * *a + (1.0 - mu) * b;
        }
    }
}

/// The LATIN unknowns of one interface: `s` (linear stage, admissible for the substructures) and
/// `hat` (local stage, satisfying the interface law), one entry per side.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InterfaceField {
    pub s: Vec<SideField>,
    pub hat: Vec<SideField>,
}

impl InterfaceField {
    pub fn zeros(sides: usize, len: usize) -> Self {
        Self { s: vec![SideField::zeros(len); sides], hat: vec![SideField::zeros(len); sides] }
    }

    pub fn len(&self) -> usize {
        self.s[0].force.len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// The interface solution of one stage (static or dynamic): every interface's fields.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageSolution {
    pub interfaces: Vec<InterfaceField>,
}

/// A whole interface solution: what is stored, warm-started from and exchanged (never
/// substructure interiors, docs/method.md 4).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InterfaceSolution {
    pub static_stage: Option<StageSolution>,
    pub dynamic: StageSolution,
}
