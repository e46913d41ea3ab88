//! The two METIS calls glissade makes, on the system's libmetis: a k-way partition of a mesh's
//! dual graph into substructures, and the nested dissection that orders a substructure's factor.
//! The index type and the options' places come from the `metis.h` the library was built with
//! (build.rs), so that another METIS release or a 64-bit build links as well.

use std::os::raw::c_int;

include!(concat!(env!("OUT_DIR"), "/metis_h.rs"));

const METIS_OK: c_int = 1;
const METIS_ERROR_INPUT: c_int = -2;
const METIS_ERROR_MEMORY: c_int = -3;

#[link(name = "metis")]
unsafe extern "C" {
    fn METIS_SetDefaultOptions(options: *mut Idx) -> c_int;
    fn METIS_PartGraphKway(
        nvtxs: *mut Idx,
        ncon: *mut Idx,
        xadj: *mut Idx,
        adjncy: *mut Idx,
        vwgt: *mut Idx,
        vsize: *mut Idx,
        adjwgt: *mut Idx,
        nparts: *mut Idx,
        tpwgts: *mut std::ffi::c_void,
        ubvec: *mut std::ffi::c_void,
        options: *mut Idx,
        edgecut: *mut Idx,
        part: *mut Idx,
    ) -> c_int;
    fn METIS_NodeND(
        nvtxs: *mut Idx,
        xadj: *mut Idx,
        adjncy: *mut Idx,
        vwgt: *mut Idx,
        options: *mut Idx,
        perm: *mut Idx,
        iperm: *mut Idx,
    ) -> c_int;
}

/// Why METIS gave no answer.
#[derive(Debug, thiserror::Error)]
pub enum MetisError {
    #[error("the graph is too large for METIS's {bits}-bit indices")]
    TooLarge { bits: u32 },
    #[error("METIS refused its input")]
    Input,
    #[error("METIS ran out of memory")]
    Memory,
    #[error("METIS failed (status {0})")]
    Failed(c_int),
}

/// An undirected graph in METIS's compressed form: the neighbours of vertex v are
/// `adjncy[xadj[v]..xadj[v + 1]]`, each edge listed from both ends.
#[derive(Debug, Clone)]
pub struct Graph {
    xadj: Vec<Idx>,
    adjncy: Vec<Idx>,
}

fn idx(v: usize) -> Result<Idx, MetisError> {
    Idx::try_from(v).map_err(|_| MetisError::TooLarge { bits: Idx::BITS })
}

fn status(s: c_int) -> Result<(), MetisError> {
    match s {
        METIS_OK => Ok(()),
        METIS_ERROR_INPUT => Err(MetisError::Input),
        METIS_ERROR_MEMORY => Err(MetisError::Memory),
        s => Err(MetisError::Failed(s)),
    }
}

/// METIS's answers are indices below the vertex count (non-negative).
fn to_usize(v: Vec<Idx>) -> Vec<usize> {
    v.into_iter().map(|i| usize::try_from(i).unwrap_or(usize::MAX)).collect()
}

impl Graph {
    /// From each vertex's neighbours (symmetric, no vertex its own neighbour).
    pub fn new(neighbours: &[Vec<usize>]) -> Result<Self, MetisError> {
        let mut xadj = Vec::with_capacity(neighbours.len() + 1);
        xadj.push(0);
        let mut adjncy = Vec::new();
        for adj in neighbours {
            for &v in adj {
                adjncy.push(idx(v)?);
            }
            xadj.push(idx(adjncy.len())?);
        }
        Ok(Self { xadj, adjncy })
    }

    fn vertices(&self) -> usize {
        self.xadj.len() - 1
    }

    /// The k-way partition into `parts` (vertex -> part), METIS asked for contiguous parts with
    /// a fixed seed (deterministic); its default imbalance (3 %).
    pub fn part_kway(&self, parts: usize) -> Result<Vec<usize>, MetisError> {
        let n = self.vertices();
        if parts <= 1 || n == 0 {
            return Ok(vec![0; n]);
        }
        let (mut xadj, mut adjncy) = (self.xadj.clone(), self.adjncy.clone());
        let (mut nvtxs, mut ncon, mut nparts, mut edgecut) = (idx(n)?, 1, idx(parts)?, 0);
        let mut options = [0 as Idx; NOPTIONS];
        let mut part = vec![0 as Idx; n];
        // SAFETY: options holds METIS_NOPTIONS; xadj has nvtxs + 1 entries and adjncy
        // xadj[nvtxs]; part holds nvtxs; the null weights are METIS's defaults
        unsafe {
            status(METIS_SetDefaultOptions(options.as_mut_ptr()))?;
            options[OPTION_CONTIG] = 1;
            options[OPTION_SEED] = 0;
            status(METIS_PartGraphKway(
                &mut nvtxs,
                &mut ncon,
                xadj.as_mut_ptr(),
                adjncy.as_mut_ptr(),
                std::ptr::null_mut(),
                std::ptr::null_mut(),
                std::ptr::null_mut(),
                &mut nparts,
                std::ptr::null_mut(),
                std::ptr::null_mut(),
                options.as_mut_ptr(),
                &mut edgecut,
                part.as_mut_ptr(),
            ))?;
        }
        Ok(to_usize(part))
    }

    /// The nested dissection ordering with METIS's default options: (perm, iperm).
    pub fn nested_dissection(&self) -> Result<(Vec<usize>, Vec<usize>), MetisError> {
        let n = self.vertices();
        let (mut xadj, mut adjncy) = (self.xadj.clone(), self.adjncy.clone());
        let mut nvtxs = idx(n)?;
        let (mut perm, mut iperm) = (vec![0 as Idx; n], vec![0 as Idx; n]);
        // SAFETY: as in part_kway; perm and iperm hold nvtxs; null options are the defaults
        status(unsafe {
            METIS_NodeND(
                &mut nvtxs,
                xadj.as_mut_ptr(),
                adjncy.as_mut_ptr(),
                std::ptr::null_mut(),
                std::ptr::null_mut(),
                perm.as_mut_ptr(),
                iperm.as_mut_ptr(),
            )
        })?;
        Ok((to_usize(perm), to_usize(iperm)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A path of n vertices.
    fn path(n: usize) -> Vec<Vec<usize>> {
        (0..n).map(|v| [v.checked_sub(1), (v + 1 < n).then_some(v + 1)].into_iter().flatten().collect()).collect()
    }

    #[test]
    fn a_path_cut_in_two_is_two_runs() {
        let part = Graph::new(&path(40)).unwrap().part_kway(2).unwrap();
        // contiguous halves: one change of part along the path, balanced within METIS's 3 %
        assert_eq!(part.windows(2).filter(|w| w[0] != w[1]).count(), 1, "{part:?}");
        let first = part.iter().filter(|&&p| p == part[0]).count();
        assert!((19..=21).contains(&first), "{part:?}");
        assert_eq!(Graph::new(&path(40)).unwrap().part_kway(2).unwrap(), part, "deterministic");
    }

    #[test]
    fn nested_dissection_is_a_permutation_and_its_inverse() {
        let (perm, iperm) = Graph::new(&path(31)).unwrap().nested_dissection().unwrap();
        let mut seen = [false; 31];
        for (i, &p) in perm.iter().enumerate() {
            assert!(!seen[p]);
            seen[p] = true;
            assert_eq!(iperm[p], i);
        }
    }

    #[test]
    fn a_neighbour_past_the_index_width_is_refused_before_metis() {
        assert!(matches!(Graph::new(&[vec![usize::MAX], vec![0]]), Err(MetisError::TooLarge { .. })));
    }
}
