//! Compressed sparse row matrices assembled from triplets, and their sparse Cholesky factors.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::linalg::cholesky::{LltRef, SymbolicCholesky, SymmetricOrdering, factorize_symbolic_cholesky};
use faer::sparse::{SparseColMat, Triplet};
use faer::{Conj, MatMut, Par, Side};

/// Errors of sparse assembly and factorisation.
#[derive(Debug, thiserror::Error)]
pub enum SparseError {
    #[error("sparse matrix construction failed: {0}")]
    Creation(String),
    #[error("operator is not positive definite (is a body free to move without any support or interface?): {0}")]
    NotPositiveDefinite(String),
}

/// METIS's nested dissection of the graph of a symmetric matrix given by its lower triangle's
/// triplets: (perm, iperm), or None where METIS fails.
fn nested_dissection(m: usize, lower: &[Triplet<usize, usize, f64>]) -> Option<(Vec<usize>, Vec<usize>)> {
    let mut neighbours: Vec<Vec<i32>> = vec![Vec::new(); m];
    for t in lower {
        if t.row != t.col {
            neighbours[t.row].push(i32::try_from(t.col).ok()?);
            neighbours[t.col].push(i32::try_from(t.row).ok()?);
        }
    }
    let mut xadj = Vec::with_capacity(m + 1);
    xadj.push(0i32);
    let mut adjncy = Vec::new();
    for mut n in neighbours {
        n.sort_unstable();
        n.dedup();
        adjncy.extend(n);
        xadj.push(i32::try_from(adjncy.len()).ok()?);
    }
    let mut nvtxs = i32::try_from(m).ok()?;
    let (mut perm, mut iperm) = (vec![0i32; m], vec![0i32; m]);
    // SAFETY: xadj has nvtxs + 1 entries and adjncy xadj[nvtxs]; perm and iperm hold nvtxs;
    // null weights and options are METIS's defaults
    let status = unsafe {
        metis_sys::METIS_NodeND(
            &mut nvtxs,
            xadj.as_mut_ptr(),
            adjncy.as_mut_ptr(),
            std::ptr::null_mut(),
            std::ptr::null_mut(),
            perm.as_mut_ptr(),
            iperm.as_mut_ptr(),
        )
    };
    (status == metis_sys::rstatus_et_METIS_OK)
        .then(|| (perm.into_iter().map(|p| p as usize).collect(), iperm.into_iter().map(|p| p as usize).collect()))
}

/// Threads that factorisations and solves (sparse and the dense macro problem's) may use, for
/// the whole process: 1 runs them on the calling thread. faer's default is a pool of as many
/// threads as the machine has cores in every process; MPI ranks, one a core, are glissade's
/// parallelism, and 16 ranks each with a pool of 16 oversubscribe a 16-core node
/// (docs/performance.md, "Where a rank's time goes"). Called once at a binary's start.
pub fn set_solver_threads(threads: usize) {
    faer::set_global_parallelism(match threads {
        0 | 1 => Par::Seq,
        n => Par::rayon(n),
    });
}

/// A square sparse matrix in CSR form; used for matrix-vector products (mass, stiffness).
#[derive(Debug, Clone, Default)]
pub struct CsrMatrix {
    pub n: usize,
    pub row_ptr: Vec<usize>,
    pub col: Vec<usize>,
    pub val: Vec<f64>,
}

impl CsrMatrix {
    /// Assembles an `n x n` matrix from (row, col, value) triplets, summing duplicates.
    pub fn from_triplets(n: usize, mut t: Vec<(usize, usize, f64)>) -> Self {
        t.sort_unstable_by_key(|&(r, c, _)| (r, c));
        let mut row_ptr = vec![0usize; n + 1];
        let mut col = Vec::with_capacity(t.len());
        let mut val: Vec<f64> = Vec::with_capacity(t.len());
        let mut last: Option<(usize, usize)> = None;
        for (r, c, v) in t {
            if last == Some((r, c)) {
                *val.last_mut().expect("a previous entry exists") += v;
            } else {
                col.push(c);
                val.push(v);
                row_ptr[r + 1] += 1;
                last = Some((r, c));
            }
        }
        for i in 0..n {
            row_ptr[i + 1] += row_ptr[i];
        }
        Self { n, row_ptr, col, val }
    }

    /// The diagonal entry of row `i` (0 where the row stores none).
    pub fn diagonal(&self, i: usize) -> f64 {
        let row = self.row_ptr[i]..self.row_ptr[i + 1];
        self.col[row.clone()].iter().position(|&c| c == i).map_or(0.0, |k| self.val[row.start + k])
    }

    /// y += alpha * A x
    pub fn mul_add(&self, alpha: f64, x: &[f64], y: &mut [f64]) {
        for (i, yi) in y.iter_mut().enumerate().take(self.n) {
            let mut s = 0.0;
            for p in self.row_ptr[i]..self.row_ptr[i + 1] {
                s += self.val[p] * x[self.col[p]];
            }
            *yi += alpha * s;
        }
    }

    /// Entry-wise linear combination `a*self + b*other` (same dimension, any patterns).
    pub fn combine(&self, a: f64, other: &CsrMatrix, b: f64) -> CsrMatrix {
        let mut t = Vec::with_capacity(self.val.len() + other.val.len());
        for (m, s) in [(self, a), (other, b)] {
            for i in 0..m.n {
                for p in m.row_ptr[i]..m.row_ptr[i + 1] {
                    t.push((i, m.col[p], s * m.val[p]));
                }
            }
        }
        CsrMatrix::from_triplets(self.n, t)
    }

    /// This matrix plus the sum of the triplets (row, column, value).
    pub fn add_triplets(&self, t: Vec<(usize, usize, f64)>) -> CsrMatrix {
        let extra = CsrMatrix::from_triplets(self.n, t);
        self.combine(1.0, &extra, 1.0)
    }
}

/// A symmetric positive definite operator restricted to its free unknowns, factorised once.
///
/// Fixed unknowns (Dirichlet conditions) are eliminated: `solve` takes a full-length right-hand
/// side and full-length values of the fixed unknowns and returns the full solution.
pub struct FactorisedOperator {
    full: CsrMatrix,
    free: Vec<usize>,
    /// position of each full unknown among the free ones, `usize::MAX` when fixed
    free_index: Vec<usize>,
    /// the Cholesky factor L L^T of the free block: its pattern and its values
    symbolic: SymbolicCholesky<usize>,
    values: Vec<f64>,
    par: Par,
    work: Vec<f64>,
    /// faer's workspace of a solve, allocated once (faer's `Solve` allocates it at every call:
    /// a substructure's size per step and iteration)
    solve_stack: MemBuffer,
}

impl FactorisedOperator {
    pub fn new(a: CsrMatrix, fixed: &[bool]) -> Result<Self, SparseError> {
        let n = a.n;
        let free: Vec<usize> = (0..n).filter(|&i| !fixed[i]).collect();
        let mut free_index = vec![usize::MAX; n];
        for (k, &i) in free.iter().enumerate() {
            free_index[i] = k;
        }
        let mut trip = Vec::with_capacity(a.val.len());
        for i in 0..n {
            let fi = free_index[i];
            if fi == usize::MAX {
                continue;
            }
            for p in a.row_ptr[i]..a.row_ptr[i + 1] {
                let fj = free_index[a.col[p]];
                if fj != usize::MAX && fj <= fi {
                    trip.push(Triplet::new(fi, fj, a.val[p]));
                }
            }
        }
        let m = free.len();
        let mat = SparseColMat::<usize, f64>::try_new_from_triplets(m, m, &trip)
            .map_err(|e| SparseError::Creation(format!("{e:?}")))?;
        // what faer's `sp_cholesky(Side::Lower)` does, keeping the parts a solve needs
        let par = faer::get_global_parallelism();
        // The factor a solve streams through memory at every step: of faer's minimum degree and
        // METIS's nested dissection, the ordering that fills it less (dissection: about a
        // quarter less on the paper's 3D blocks; docs/performance.md, "The factors' ordering").
        let symbolic = |ordering| {
            factorize_symbolic_cholesky(mat.symbolic(), Side::Lower, ordering, Default::default())
                .map_err(|e| SparseError::Creation(format!("{e:?}")))
        };
        let mut chosen = symbolic(SymmetricOrdering::Amd)?;
        if let Some((perm, iperm)) = nested_dissection(m, &trip) {
            let nd = symbolic(SymmetricOrdering::Custom(faer::perm::PermRef::new_checked(&perm, &iperm, m)))?;
            if nd.len_val() < chosen.len_val() {
                chosen = nd;
            }
        }
        let symbolic = chosen;
        let mut values = vec![0.0; symbolic.len_val()];
        let scratch = MemBuffer::try_new(symbolic.factorize_numeric_llt_scratch::<f64>(par, Default::default()))
            .map_err(|e| SparseError::Creation(format!("{e:?}")))?;
        symbolic
            .factorize_numeric_llt(
                &mut values,
                mat.as_ref(),
                Side::Lower,
                Default::default(),
                par,
                MemStack::new(&mut { scratch }),
                Default::default(),
            )
            .map_err(|e| SparseError::NotPositiveDefinite(format!("{e:?}")))?;
        let solve_stack = MemBuffer::new(symbolic.solve_in_place_scratch::<f64>(1, par));
        Ok(Self { full: a, free, free_index, symbolic, values, par, work: vec![0.0; m], solve_stack })
    }

    pub fn n(&self) -> usize {
        self.full.n
    }

    /// Values stored in the Cholesky factor: what a solve reads twice (forward and back), the
    /// measure of its cost where memory, not arithmetic, is the limit.
    pub fn factor_len(&self) -> usize {
        self.values.len()
    }

    /// Solves `A x = rhs` for the free unknowns, with `x` holding the fixed values on entry.
    /// `fixed_nonzero` says whether any fixed value is non-zero (saves a product otherwise).
    pub fn solve(&mut self, rhs: &[f64], x: &mut [f64], fixed_nonzero: bool) {
        for (k, &i) in self.free.iter().enumerate() {
            self.work[k] = rhs[i];
        }
        if fixed_nonzero {
            // move the known columns to the right-hand side: rhs_f -= A_fp x_p
            for (k, &i) in self.free.iter().enumerate() {
                let mut s = 0.0;
                for p in self.full.row_ptr[i]..self.full.row_ptr[i + 1] {
                    let j = self.full.col[p];
                    if self.free_index[j] == usize::MAX {
                        s += self.full.val[p] * x[j];
                    }
                }
                self.work[k] -= s;
            }
        }
        let m = self.work.len();
        LltRef::new(&self.symbolic, &self.values).solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(&mut self.work, m, 1),
            self.par,
            MemStack::new(&mut self.solve_stack),
        );
        for (k, &i) in self.free.iter().enumerate() {
            x[i] = self.work[k];
        }
    }

    /// The full (unrestricted) operator.
    pub fn matrix(&self) -> &CsrMatrix {
        &self.full
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A chain of n unknowns: `diagonal` on the diagonal, -1 beside it.
    fn chain(n: usize, diagonal: f64) -> CsrMatrix {
        let mut t = vec![];
        for i in 0..n {
            t.push((i, i, diagonal));
            if i + 1 < n {
                t.push((i, i + 1, -1.0));
                t.push((i + 1, i, -1.0));
            }
        }
        CsrMatrix::from_triplets(n, t)
    }

    #[test]
    fn solves_spd_system_with_fixed_unknown() {
        // 1D Laplacian on 4 unknowns, the last fixed to 2.0: exact solution is linear.
        let a = chain(4, 2.0);
        let mut op = FactorisedOperator::new(a, &[false, false, false, true]).unwrap();
        let mut x = vec![0.0, 0.0, 0.0, 2.0];
        // rhs chosen so that x = [0.5, 1.0, 1.5, 2.0] solves rows 0..3 (row 0: 2*0.5-1 = 0)
        op.solve(&[0.0, 0.0, 0.0, 0.0], &mut x, true);
        // rows: 2x0-x1=0, -x0+2x1-x2=0, -x1+2x2-2=0 -> x = [0.5,1,1.5]
        for (xi, ei) in x.iter().zip([0.5, 1.0, 1.5, 2.0]) {
            assert!((xi - ei).abs() < 1e-14, "{x:?}");
        }
    }

    /// A 3D grid of n^3 nodes, the 7-point Laplacian plus a mass-like diagonal (SPD).
    fn grid_3d(n: usize) -> CsrMatrix {
        let id = |i: usize, j: usize, k: usize| (i * n + j) * n + k;
        let mut t = vec![];
        for i in 0..n {
            for j in 0..n {
                for k in 0..n {
                    let a = id(i, j, k);
                    t.push((a, a, 6.1));
                    for (di, dj, dk) in [(1, 0, 0), (0, 1, 0), (0, 0, 1)] {
                        if i + di < n && j + dj < n && k + dk < n {
                            let b = id(i + di, j + dj, k + dk);
                            t.push((a, b, -1.0));
                            t.push((b, a, -1.0));
                        }
                    }
                }
            }
        }
        CsrMatrix::from_triplets(n * n * n, t)
    }

    /// faer's minimum-degree factor's size for the same matrix (no fixed unknowns).
    fn amd_factor_len(a: &CsrMatrix) -> usize {
        let mut trip = vec![];
        for i in 0..a.n {
            for p in a.row_ptr[i]..a.row_ptr[i + 1] {
                if a.col[p] <= i {
                    trip.push(Triplet::new(i, a.col[p], a.val[p]));
                }
            }
        }
        let mat = SparseColMat::<usize, f64>::try_new_from_triplets(a.n, a.n, &trip).unwrap();
        factorize_symbolic_cholesky(mat.symbolic(), Side::Lower, SymmetricOrdering::Amd, Default::default())
            .unwrap()
            .len_val()
    }

    #[test]
    fn the_factor_takes_the_ordering_that_fills_it_less() {
        // a 3D grid: nested dissection fills less than minimum degree, and the answer holds
        let a = grid_3d(14);
        let amd = amd_factor_len(&a);
        let mut op = FactorisedOperator::new(a.clone(), &vec![false; a.n]).unwrap();
        assert!((op.factor_len() as f64) < 0.9 * amd as f64, "{} against minimum degree's {amd}", op.factor_len());
        let exact: Vec<f64> = (0..a.n).map(|i| ((i * 37) % 11) as f64 - 5.0).collect();
        let mut rhs = vec![0.0; a.n];
        a.mul_add(1.0, &exact, &mut rhs);
        let mut x = vec![0.0; a.n];
        op.solve(&rhs, &mut x, false);
        let err = x.iter().zip(&exact).map(|(x, e)| (x - e).abs()).fold(0.0, f64::max);
        assert!(err < 1e-12, "largest error {err:e}");
        // a chain: neither ordering fills it; the factor is no larger than minimum degree's
        let a = chain(200, 2.5);
        let op = FactorisedOperator::new(a.clone(), &vec![false; a.n]).unwrap();
        assert!(op.factor_len() <= amd_factor_len(&a));
    }
}
