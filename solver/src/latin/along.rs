//! The local stage of a perfect interface whose search direction has a part from node to node
//! ([`crate::model::InterfaceSide::k_along`]): k_i + g_i M_Gamma^-1 L_i on side i. The law is
//! the perfect interface's (docs/method.md 3, "Local stage"), W^1 = W^2 + s n and
//! F^1 + F^2 = 0, but the directions couple the nodes, so W^ solves one system over the
//! interface at each step, factorised once per stage:
//! (M_Gamma (k_1 + k_2) + g_1 L_1 + g_2 L_2) W^ = M_Gamma (k_1 W_1 + k_2 (W_2 + s n) - F_1 - F_2)
//! + g_1 L_1 W_1 + g_2 L_2 (W_2 + s n), one component at a time (k is isotropic there).

use std::ops::Range;
use std::sync::Mutex;

use glissade_core::field::InterfaceField;

use super::distribution::Distribution;
use super::linear_stage::{Stage, add_along};
use crate::model::{InterfaceLaw, Model};
use crate::sparse::{CsrMatrix, FactorisedOperator, SparseError};

/// Per interface, the factorised systems of its static and dynamic stages (`None` where the
/// directions are scalars or another rank owns the interface).
pub struct AlongSolves {
    systems: Vec<Option<[Mutex<FactorisedOperator>; 2]>>,
}

fn stage_index(stage: Stage) -> usize {
    match stage {
        Stage::Static => 0,
        Stage::Dynamic => 1,
    }
}

impl AlongSolves {
    /// Fails with the interface whose system is not positive definite.
    pub fn new<const D: usize>(model: &Model<D>, dist: &Distribution) -> Result<Self, (usize, SparseError)> {
        let mut systems = Vec::with_capacity(model.interfaces.len());
        for (i, itf) in model.interfaces.iter().enumerate() {
            if !dist.owns_interface(i) || itf.sides.len() != 2 || itf.sides.iter().all(|s| s.k_along.is_empty()) {
                systems.push(None);
                continue;
            }
            let n = itf.n_nodes();
            let system = |stage: Stage| -> Result<Mutex<FactorisedOperator>, SparseError> {
                let factor = stage.along_factor(model);
                let mut t: Vec<(usize, usize, f64)> = (0..n)
                    .map(|j| (j, j, itf.area[j] * itf.sides.iter().map(|s| stage.k(s).normal).sum::<f64>()))
                    .collect();
                for s in &itf.sides {
                    t.extend(s.k_along.iter().map(|&(j, l, v)| (j, l, factor * v)));
                }
                Ok(Mutex::new(FactorisedOperator::new(CsrMatrix::from_triplets(n, t), &vec![false; n])?))
            };
            let both = system(Stage::Static).and_then(|a| Ok([a, system(Stage::Dynamic)?]));
            systems.push(Some(both.map_err(|e| (i, e))?));
        }
        Ok(Self { systems })
    }

    /// Applies the perfect law at the steps `steps` of interface `i` if its directions couple
    /// its nodes; says whether it did.
    pub fn local_stage<const D: usize>(
        &self,
        model: &Model<D>,
        stage: Stage,
        i: usize,
        f: &mut InterfaceField,
        steps: Range<usize>,
    ) -> bool {
        let Some(systems) = self.systems.get(i).and_then(Option::as_ref) else { return false };
        let itf = &model.interfaces[i];
        let shortening = match (stage, itf.law) {
            (Stage::Static, InterfaceLaw::Prestress { shortening }) => shortening,
            (_, InterfaceLaw::Perfect | InterfaceLaw::Prestress { .. }) => 0.0,
            _ => return false,
        };
        let mut system = systems[stage_index(stage)].lock().expect("an interface system is used by one thread");
        let (n, factor) = (itf.n_nodes(), stage.along_factor(model));
        let (s1, s2) = (&itf.sides[0], &itf.sides[1]);
        let (k1, k2) = (stage.k(s1).normal, stage.k(s2).normal);
        let (mut rhs, mut x) = (vec![0.0; n], vec![0.0; n]);
        // (buffers of one step, D components a node, allocated once)
        let (mut w2, mut coupled, mut change, mut l_change) =
            (vec![0.0; n * D], vec![0.0; n * D], vec![0.0; n * D], vec![0.0; n * D]);
        let shift = |q: usize| shortening * itf.normal[q / D][q % D];
        for step in steps {
            let r = step * n * D..(step + 1) * n * D;
            let (w1, f1, f2) = (&f.s[0].velocity[r.clone()], &f.s[0].force[r.clone()], &f.s[1].force[r.clone()]);
            for (q, w) in w2.iter_mut().enumerate() {
                *w = f.s[1].velocity[r.start + q] + shift(q);
            }
            coupled.fill(0.0);
            add_along::<D>(s1, factor, w1, 0, &mut coupled);
            add_along::<D>(s2, factor, &w2, 0, &mut coupled);
            let (hat1, hat2) = f.hat.split_at_mut(1);
            let (hat1, hat2) = (&mut hat1[0], &mut hat2[0]);
            let what = &mut hat1.velocity[r.clone()];
            for c in 0..D {
                for j in 0..n {
                    let q = j * D + c;
                    rhs[j] = itf.area[j] * (k1 * w1[q] + k2 * w2[q] - f1[q] - f2[q]) + coupled[q];
                }
                system.solve(&rhs, &mut x, false);
                for j in 0..n {
                    what[j * D + c] = x[j];
                }
            }
            // F^1 = F1 + (k_1 + g_1 M^-1 L_1) (W^ - W1), F^2 = -F^1, W^2 = W^1 - s n
            for q in 0..n * D {
                change[q] = what[q] - w1[q];
            }
            l_change.fill(0.0);
            add_along::<D>(s1, factor, &change, 0, &mut l_change);
            for q in 0..n * D {
                let f1h = f1[q] + k1 * change[q] + l_change[q] / itf.area[q / D];
                hat2.velocity[r.start + q] = what[q] - shift(q);
                hat1.force[r.start + q] = f1h;
                hat2.force[r.start + q] = -f1h;
            }
        }
        true
    }
}
