//! Anderson acceleration of the LATIN fixed point (docs/method.md, "Acceleration").
//!
//! One LATIN iteration maps the linear-stage fields `s` it starts from to the relaxed fields of
//! the next linear stage: `g = G(x)`. Near convergence that map contracts slowly (0.95-0.97 per
//! iteration on the three-blocks scenes) but almost linearly, so the last `depth` differences of
//! `x` and `g` predict where it goes: the next start is `g - dG gamma`, gamma minimising the
//! residual `|f - dF gamma|` with f = g - x, in the norm of the error indicator
//! (a |F|^2 / k + a k |W|^2). Every start is an affine combination of linear-stage solutions,
//! so it stays admissible for the substructures.
//!
//! The dot products are summed per interface on the interface's owner and then in interface
//! order, like eta, so a solve gives the same result on any number of ranks.

use std::collections::VecDeque;

use crate::comm::Communicator;
use crate::model::Model;

use super::distribution::Distribution;
use super::field::{InterfaceField, SideField};
use super::linear_stage::Stage;

/// Residual growth that discards the history: the contact or friction statuses changed and the
/// differences stored no longer describe the map.
const RESTART_GROWTH: f64 = 2.0;

pub struct Anderson {
    depth: usize,
    /// weight of each entry of the flattened owned fields, and the interface it belongs to
    weights: Vec<f64>,
    /// [start, end) of each interface in the flattened vector (empty when not owned)
    ranges: Vec<(usize, usize)>,
    last: Option<(Vec<f64>, Vec<f64>)>,
    last_norm: f64,
    d_f: VecDeque<Vec<f64>>,
    d_g: VecDeque<Vec<f64>>,
    /// iterations whose start was extrapolated (for the reports)
    pub accelerated: usize,
    pub restarts: usize,
}

impl Anderson {
    pub fn new<const D: usize>(m: &Model<D>, dist: &Distribution, stage: Stage, depth: usize) -> Self {
        let steps = stage.steps(m);
        let mut weights = Vec::new();
        let mut ranges = Vec::with_capacity(m.interfaces.len());
        for (i, itf) in m.interfaces.iter().enumerate() {
            let start = weights.len();
            if dist.owns_interface(i) {
                let n = itf.n_nodes();
                for side in &itf.sides {
                    let k = stage.k(side);
                    let per_entry = |idx: usize| itf.area[(idx / D) % n];
                    weights.extend((0..steps * n * D).map(|idx| per_entry(idx) / k));
                    weights.extend((0..steps * n * D).map(|idx| per_entry(idx) * k));
                }
            }
            ranges.push((start, weights.len()));
        }
        Self {
            depth,
            weights,
            ranges,
            last: None,
            last_norm: f64::INFINITY,
            d_f: VecDeque::new(),
            d_g: VecDeque::new(),
            accelerated: 0,
            restarts: 0,
        }
    }

    fn flatten(&self, fields: &[InterfaceField], previous: Option<&[Vec<SideField>]>) -> Vec<f64> {
        let mut out = Vec::with_capacity(self.weights.len());
        for (i, &(a, b)) in self.ranges.iter().enumerate() {
            if a == b {
                continue;
            }
            let sides = match previous {
                Some(p) => &p[i][..],
                None => &fields[i].s[..],
            };
            for side in sides {
                out.extend_from_slice(&side.force);
                out.extend_from_slice(&side.velocity);
            }
        }
        out
    }

    /// `previous[i]`: the fields the iteration started from (x); `fields[i].s`: the relaxed
    /// linear-stage result (g), replaced by the extrapolated start of the next iteration.
    pub fn step(
        &mut self,
        comm: &dyn Communicator,
        fields: &mut [InterfaceField],
        previous: &[Vec<SideField>],
    ) {
        if self.depth == 0 {
            return;
        }
        let x = self.flatten(fields, Some(previous));
        let g = self.flatten(fields, None);
        let f: Vec<f64> = g.iter().zip(&x).map(|(g, x)| g - x).collect();
        let norm = self.dot_all(comm, &[&f], &f)[0].sqrt();
        if let Some((f_old, g_old)) = self.last.take() {
            if norm > RESTART_GROWTH * self.last_norm {
                self.d_f.clear();
                self.d_g.clear();
                self.restarts += 1;
            } else {
                self.d_f.push_back(f.iter().zip(&f_old).map(|(a, b)| a - b).collect());
                self.d_g.push_back(g.iter().zip(&g_old).map(|(a, b)| a - b).collect());
                if self.d_f.len() > self.depth {
                    self.d_f.pop_front();
                    self.d_g.pop_front();
                }
            }
        }
        self.last_norm = norm;
        let columns = self.d_f.len();
        if columns > 0 {
            // normal equations of the small least-squares problem, one reduction for all of them
            let cols: Vec<&Vec<f64>> = self.d_f.iter().collect();
            let mut partial = self.partials(&cols, &f);
            comm.sum_in_place(&mut partial);
            let products = self.sum_blocks(&partial, columns * (columns + 1));
            let a: Vec<f64> = products[..columns * columns].to_vec();
            let b = &products[columns * columns..];
            match solve_regularised(&a, b, columns) {
                Some(gamma) => {
                    let mut next = g.clone();
                    for (c, dg) in self.d_g.iter().enumerate() {
                        for (n, d) in next.iter_mut().zip(dg) {
                            *n -= gamma[c] * d;
                        }
                    }
                    self.unflatten(fields, &next);
                    self.accelerated += 1;
                }
                None => {
                    self.d_f.clear();
                    self.d_g.clear();
                    self.restarts += 1;
                }
            }
        }
        self.last = Some((f, g));
    }

    /// Per-interface blocks of `[cols[r] . cols[c]]_{r,c}` then `[cols[r] . rhs]_r`.
    fn partials(&self, cols: &[&Vec<f64>], rhs: &[f64]) -> Vec<f64> {
        let m = cols.len();
        let block = m * (m + 1);
        let mut out = vec![0.0; block * self.ranges.len()];
        for (i, &(a, b)) in self.ranges.iter().enumerate() {
            if a == b {
                continue;
            }
            let w = &self.weights[a..b];
            let o = &mut out[i * block..(i + 1) * block];
            let dot = |u: &[f64], v: &[f64]| -> f64 { u.iter().zip(v).zip(w).map(|((u, v), w)| u * v * w).sum() };
            for r in 0..m {
                for c in r..m {
                    let v = dot(&cols[r][a..b], &cols[c][a..b]);
                    o[r * m + c] = v;
                    o[c * m + r] = v;
                }
                o[m * m + r] = dot(&cols[r][a..b], &rhs[a..b]);
            }
        }
        out
    }

    fn sum_blocks(&self, partial: &[f64], block: usize) -> Vec<f64> {
        let mut total = vec![0.0; block];
        for chunk in partial.chunks(block) {
            for (t, p) in total.iter_mut().zip(chunk) {
                *t += p;
            }
        }
        total
    }

    /// `[u . v for u in cols]`, reduced over ranks in interface order.
    fn dot_all(&self, comm: &dyn Communicator, cols: &[&[f64]], v: &[f64]) -> Vec<f64> {
        let m = cols.len();
        let mut partial = vec![0.0; m * self.ranges.len()];
        for (i, &(a, b)) in self.ranges.iter().enumerate() {
            let w = &self.weights[a..b];
            for (r, u) in cols.iter().enumerate() {
                partial[i * m + r] = u[a..b].iter().zip(&v[a..b]).zip(w).map(|((u, v), w)| u * v * w).sum();
            }
        }
        comm.sum_in_place(&mut partial);
        self.sum_blocks(&partial, m)
    }

    fn unflatten(&self, fields: &mut [InterfaceField], values: &[f64]) {
        for (i, &(a, b)) in self.ranges.iter().enumerate() {
            if a == b {
                continue;
            }
            let mut at = a;
            for side in fields[i].s.iter_mut() {
                let len = side.force.len();
                side.force.copy_from_slice(&values[at..at + len]);
                side.velocity.copy_from_slice(&values[at + len..at + 2 * len]);
                at += 2 * len;
            }
        }
    }
}

/// Solves (A + lambda I) x = b for a small symmetric positive semi-definite A by Gaussian
/// elimination with partial pivoting; lambda = 1e-10 x the largest diagonal entry keeps nearly
/// dependent columns from exploding. None when A is zero or the result is not finite.
fn solve_regularised(a: &[f64], b: &[f64], n: usize) -> Option<Vec<f64>> {
    let largest = (0..n).map(|i| a[i * n + i]).fold(0.0_f64, f64::max);
    if largest <= 0.0 || !largest.is_finite() {
        return None;
    }
    let mut m: Vec<f64> = a.to_vec();
    for i in 0..n {
        m[i * n + i] += 1e-10 * largest;
    }
    let mut x = b.to_vec();
    for col in 0..n {
        let pivot = (col..n).max_by(|&p, &q| m[p * n + col].abs().total_cmp(&m[q * n + col].abs()))?;
        if m[pivot * n + col] == 0.0 {
            return None;
        }
        if pivot != col {
            for c in 0..n {
                m.swap(pivot * n + c, col * n + c);
            }
            x.swap(pivot, col);
        }
        for r in col + 1..n {
            let factor = m[r * n + col] / m[col * n + col];
            for c in col..n {
                m[r * n + c] -= factor * m[col * n + c];
            }
            x[r] -= factor * x[col];
        }
    }
    for r in (0..n).rev() {
        let s: f64 = (r + 1..n).map(|c| m[r * n + c] * x[c]).sum();
        x[r] = (x[r] - s) / m[r * n + r];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_a_small_symmetric_system() {
        // [[4, 1], [1, 3]] x = [1, 2] -> x = [1/11, 7/11]
        let x = solve_regularised(&[4.0, 1.0, 1.0, 3.0], &[1.0, 2.0], 2).unwrap();
        assert!((x[0] - 1.0 / 11.0).abs() < 1e-9 && (x[1] - 7.0 / 11.0).abs() < 1e-9, "{x:?}");
        assert!(solve_regularised(&[0.0], &[1.0], 1).is_none());
    }
}
