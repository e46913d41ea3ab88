//! The macro problem of the multiscale LATIN (docs/method.md 3, "Multiscale").
//!
//! Each two-sided interface carries a small macro basis (rigid motions and linear fields,
//! orthonormal for M_Gamma). At every step, between the two micro problems, the macro
//! admissibility Pi^M (F_E + F_E') = 0 is enforced on every interface through one macro
//! multiplier W~ per interface, solving (sum_E L_E) W~ = -sum_E Pi^M F1_E. The homogenised
//! operators L_E come from each substructure's responses q to the macro basis, computed once.

use faer::linalg::solvers::Solve;
use faer::{Mat, MatMut, Side};

use crate::comm::Communicator;
use crate::model::{Interface, Model};

use super::linear_stage::{Stage, SubstructureOperators, add_along, along_traction, node_vector};
use glissade_core::field::InterfaceField;

/// Relative M_Gamma-norm below which a candidate macro field is dependent on the previous ones.
const DEPENDENCE_TOLERANCE: f64 = 1e-8;

/// Macro basis of one interface: fields of length `nodes * D`, orthonormal for M_Gamma.
/// Candidates: D translations, rotations about the principal axes, linear in-plane extensions
/// and shear; Gram-Schmidt drops those a given interface cannot carry (e.g. on a single node).
/// A planar 3D interface keeps 9 fields, a straight 2D one 4, a 1D point 1.
pub fn interface_basis<const D: usize>(itf: &Interface<D>) -> Vec<Vec<f64>> {
    let n = itf.n_nodes();
    let total: f64 = itf.area.iter().sum();
    let mut centre = [0.0; D];
    for j in 0..n {
        for d in 0..D {
            centre[d] += itf.area[j] * itf.coords[j][d] / total;
        }
    }
    let rel = |j: usize| -> [f64; D] {
        let mut r = [0.0; D];
        for d in 0..D {
            r[d] = itf.coords[j][d] - centre[d];
        }
        r
    };
    let mut candidates: Vec<Vec<f64>> = Vec::new();
    // translations
    for d in 0..D {
        candidates.push((0..n * D).map(|k| if k % D == d { 1.0 } else { 0.0 }).collect());
    }
    // rotations: omega x r for each axis (3D), or the in-plane rotation (2D)
    if D == 3 {
        for axis in 0..3 {
            let mut f = vec![0.0; n * D];
            for j in 0..n {
                let r = rel(j);
                let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
                f[j * D + b] = r[a];
                f[j * D + a] = -r[b];
            }
            candidates.push(f);
        }
    } else if D == 2 {
        let mut f = vec![0.0; n * D];
        for j in 0..n {
            let r = rel(j);
            f[j * D] = -r[1];
            f[j * D + 1] = r[0];
        }
        candidates.push(f);
    }
    // symmetric linear fields sym(t_a (x) t_b) r over tangent-plane directions: extensions, shear
    let nrm = itf.normal[0];
    let tangents: Vec<[f64; D]> = (0..D)
        .map(|d| {
            let mut t = [0.0; D];
            t[d] = 1.0;
            let dn: f64 = (0..D).map(|c| t[c] * nrm[c]).sum();
            for c in 0..D {
                t[c] -= dn * nrm[c];
            }
            t
        })
        .collect();
    for a in 0..D {
        for b in a..D {
            let mut f = vec![0.0; n * D];
            for j in 0..n {
                let r = rel(j);
                let ra: f64 = (0..D).map(|c| r[c] * tangents[a][c]).sum();
                let rb: f64 = (0..D).map(|c| r[c] * tangents[b][c]).sum();
                for c in 0..D {
                    f[j * D + c] = rb * tangents[a][c] + ra * tangents[b][c];
                }
            }
            candidates.push(f);
        }
    }
    let inner = |x: &[f64], y: &[f64]| -> f64 { (0..n * D).map(|k| itf.area[k / D] * x[k] * y[k]).sum() };
    let mut basis: Vec<Vec<f64>> = Vec::new();
    for mut f in candidates {
        let norm0 = inner(&f, &f).sqrt();
        if norm0 == 0.0 {
            continue;
        }
        // modified Gram-Schmidt, twice for stability
        for _ in 0..2 {
            for e in &basis {
                let p = inner(&f, e);
                for k in 0..f.len() {
                    f[k] -= p * e[k];
                }
            }
        }
        let norm = inner(&f, &f).sqrt();
        if norm > DEPENDENCE_TOLERANCE * norm0 {
            for v in f.iter_mut() {
                *v /= norm;
            }
            basis.push(f);
        }
    }
    basis
}

/// One macro basis field of one interface side, as seen by a substructure, and the
/// substructure's response q = A^-1 N^T M_Gamma k e to it.
struct Column {
    interface: usize,
    side: usize,
    mode: usize,
    dof: usize,
    response: Vec<f64>,
}

/// The assembled, factorised macro problem of one stage.
pub struct MacroProblem {
    /// first macro dof of each interface; `None` for one-sided (wall) interfaces
    offset: Vec<Option<usize>>,
    basis: Vec<Vec<Vec<f64>>>,
    n: usize,
    llt: Option<faer::linalg::solvers::Llt<f64>>,
    columns: Vec<Vec<Column>>,
    /// right-hand side, then solution W~, of the current step
    pub rhs: Vec<f64>,
    /// F1 at the nodes of one interface side (work vector of `add_residual`)
    f1: Vec<f64>,
}

/// Errors of the macro problem.
#[derive(Debug, thiserror::Error)]
#[error("macro operator is not positive definite: {0}")]
pub struct MacroError(String);

impl MacroProblem {
    /// Builds the homogenised operators from each substructure's responses to the macro basis and
    /// factorises their sum (dense Cholesky: a few hundred macro dofs).
    pub fn new<const D: usize>(
        model: &Model<D>,
        ops: &mut [Option<SubstructureOperators>],
        stage: Stage,
        comm: &dyn Communicator,
    ) -> Result<Self, MacroError> {
        let mut offset = Vec::with_capacity(model.interfaces.len());
        let mut basis = Vec::with_capacity(model.interfaces.len());
        let mut n = 0;
        for itf in &model.interfaces {
            if itf.sides.len() == 2 {
                let b = interface_basis(itf);
                offset.push(Some(n));
                n += b.len();
                basis.push(b);
            } else {
                offset.push(None);
                basis.push(Vec::new());
            }
        }
        // column-major n x n; each entry gets at most two contributions (the two sides of an
        // interface), so the sum over ranks is exact in any order
        let mut operator = vec![0.0; n * n];
        let mut columns = Vec::with_capacity(model.substructures.len());
        for (s, sub) in model.substructures.iter().enumerate() {
            let mut cols: Vec<Column> = Vec::new();
            let Some(op) = ops[s].as_mut() else {
                columns.push(cols);
                continue;
            };
            for &(i, side) in &sub.sides {
                let Some(off) = offset[i] else { continue };
                let itf = &model.interfaces[i];
                let sd = &itf.sides[side];
                let k = stage.k(sd);
                for (mode, e) in basis[i].iter().enumerate() {
                    let mut rhs = vec![0.0; sub.n_dofs()];
                    let mut le = vec![0.0; e.len()];
                    add_along::<D>(sd, stage.along_factor(model), e, 0, &mut le);
                    for (j, &node) in sd.nodes.iter().enumerate() {
                        let ke = k.apply(&itf.normal[j], &node_vector(&e[j * D..(j + 1) * D]));
                        for c in 0..D {
                            rhs[node * D + c] = itf.area[j] * ke[c] + le[j * D + c];
                        }
                    }
                    let response = op.solve_homogeneous(stage, &rhs);
                    cols.push(Column { interface: i, side, mode, dof: off + mode, response });
                }
            }
            // L_E[c', c] = <e_c', k' (e_c - N_c' q_c)>, e_c counted on its own interface side
            // only (k e_c there is what loaded q_c); with k = k' I this is k (delta_cc' - <e_c', N q_c>)
            for c in &cols {
                for cp in &cols {
                    let itf = &model.interfaces[cp.interface];
                    let sd = &itf.sides[cp.side];
                    let k = stage.k(sd);
                    let e = &basis[cp.interface][cp.mode];
                    let own = (c.interface, c.side) == (cp.interface, cp.side);
                    let ec = &basis[c.interface][c.mode];
                    let mut sum = 0.0;
                    let jumps: Vec<f64> = (0..e.len())
                        .map(|q| if own { ec[q] } else { 0.0 } - c.response[sd.nodes[q / D] * D + q % D])
                        .collect();
                    for (j, jump) in jumps.chunks(D).enumerate() {
                        let kj = k.apply(&itf.normal[j], &node_vector(jump));
                        for d in 0..D {
                            sum += itf.area[j] * e[j * D + d] * kj[d];
                        }
                    }
                    if !sd.k_along.is_empty() {
                        let mut lj = vec![0.0; e.len()];
                        add_along::<D>(sd, stage.along_factor(model), &jumps, 0, &mut lj);
                        sum += e.iter().zip(&lj).map(|(a, b)| a * b).sum::<f64>();
                    }
                    operator[c.dof * n + cp.dof] += sum;
                }
            }
            columns.push(cols);
        }
        comm.sum_in_place(&mut operator);
        // symmetrise away round-off before Cholesky
        let operator = Mat::<f64>::from_fn(n, n, |i, j| 0.5 * (operator[j * n + i] + operator[i * n + j]));
        let llt = if n > 0 { Some(operator.llt(Side::Lower).map_err(|e| MacroError(format!("{e:?}")))?) } else { None };
        Ok(Self { offset, basis, n, llt, columns, rhs: vec![0.0; n], f1: Vec::new() })
    }

    pub fn n_dofs(&self) -> usize {
        self.n
    }

    /// Adds -Pi^M F1 of substructure `s` at `step` to the macro right-hand side, where
    /// F1 = F^ + k (W^ - N x) follows from micro problem 1's solution x.
    pub fn add_residual<const D: usize>(
        &mut self,
        model: &Model<D>,
        s: usize,
        stage: Stage,
        step: usize,
        fields: &[InterfaceField],
        x: &[f64],
    ) {
        let sub = &model.substructures[s];
        for &(i, side) in &sub.sides {
            let Some(off) = self.offset[i] else { continue };
            let itf = &model.interfaces[i];
            let sd = &itf.sides[side];
            let k = stage.k(sd);
            let hat = &fields[i].hat[side];
            let m = sd.nodes.len();
            // F1 = F^ + k (W^ - N x) at every node of the side, then its projections
            self.f1.clear();
            for (j, &node) in sd.nodes.iter().enumerate() {
                let at = (step * m + j) * D;
                let jump: [f64; D] = std::array::from_fn(|c| hat.velocity[at + c] - x[node * D + c]);
                let kj = k.apply(&itf.normal[j], &jump);
                self.f1.extend((0..D).map(|c| hat.force[at + c] + kj[c]));
            }
            if !sd.k_along.is_empty() {
                let jumps: Vec<f64> =
                    (0..m * D).map(|q| hat.velocity[step * m * D + q] - x[sd.nodes[q / D] * D + q % D]).collect();
                let traction = along_traction::<D>(sd, stage.along_factor(model), &jumps, &itf.area);
                for (f, t) in self.f1.iter_mut().zip(traction) {
                    *f += t;
                }
            }
            for (mode, e) in self.basis[i].iter().enumerate() {
                let mut proj = 0.0;
                for (j, f) in self.f1.chunks(D).enumerate() {
                    for c in 0..D {
                        proj += itf.area[j] * e[j * D + c] * f[c];
                    }
                }
                self.rhs[off + mode] -= proj;
            }
        }
    }

    /// Solves for W~ in place of the right-hand side.
    pub fn solve(&mut self, comm: &dyn Communicator) {
        comm.sum_in_place(&mut self.rhs);
        if let Some(llt) = &self.llt {
            let n = self.n;
            llt.solve_in_place(MatMut::from_column_major_slice_mut(&mut self.rhs, n, 1));
        }
    }

    /// Micro problem 2: x += sum_c q_c W~_c over the substructure's macro columns.
    pub fn correct(&self, s: usize, x: &mut [f64]) {
        for c in &self.columns[s] {
            let w = self.rhs[c.dof];
            if w != 0.0 {
                for (xi, qi) in x.iter_mut().zip(&c.response) {
                    *xi += w * qi;
                }
            }
        }
    }

    /// Value of the macro field W~ of interface `i` at node `j`, component `c` (D components).
    pub fn field_value(&self, dim: usize, i: usize, j: usize, c: usize) -> f64 {
        match self.offset[i] {
            Some(off) => self.basis[i].iter().enumerate().map(|(mode, e)| self.rhs[off + mode] * e[j * dim + c]).sum(),
            None => 0.0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{InterfaceLaw, InterfaceSide};
    use crate::search_direction::SearchDirection;

    fn square_interface(nx: usize) -> Interface<3> {
        let mut coords = vec![];
        let mut area = vec![];
        for i in 0..=nx {
            for j in 0..=nx {
                coords.push([i as f64 / nx as f64, j as f64 / nx as f64, 0.5]);
                let w = |k: usize| if k == 0 || k == nx { 0.5 } else { 1.0 };
                area.push(w(i) * w(j) / (nx * nx) as f64);
            }
        }
        let n = coords.len();
        let iso = SearchDirection::isotropic(1.0);
        let side = InterfaceSide {
            substructure: 0,
            nodes: (0..n).collect(),
            k_dynamic: iso,
            k_static: iso,
            k_along: Vec::new(),
        };
        Interface {
            name: "t".into(),
            law: InterfaceLaw::Perfect,
            sides: vec![side.clone(), side],
            area,
            normal: vec![[0.0, 0.0, 1.0]; n],
            coords,
            gap0: vec![0.0; n],
        }
    }

    #[test]
    fn planar_3d_interface_has_nine_orthonormal_fields() {
        let itf = square_interface(4);
        let b = interface_basis(&itf);
        assert_eq!(b.len(), 9);
        for (p, x) in b.iter().enumerate() {
            for (q, y) in b.iter().enumerate() {
                let dot: f64 = (0..x.len()).map(|k| itf.area[k / 3] * x[k] * y[k]).sum();
                assert!((dot - if p == q { 1.0 } else { 0.0 }).abs() < 1e-12, "<e{p}, e{q}> = {dot}");
            }
        }
    }

    #[test]
    fn single_node_interface_keeps_translations_only() {
        let mut itf = square_interface(1);
        itf.coords.truncate(1);
        itf.area.truncate(1);
        itf.normal.truncate(1);
        assert_eq!(interface_basis(&itf).len(), 3);
    }
}
