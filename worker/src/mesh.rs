//! Unstructured multilinear meshes with tagged faces, and the structured box generator.
//!
//! The solver only sees [`Mesh`] (nodes, elements in tensor order, named face sets) and an element
//! partition into substructures, so Gmsh meshes can replace the boxes without touching it.

use std::collections::BTreeMap;

use crate::element::{face_local_nodes, nodes_per_element};

/// Axis names used in face tags and vector components.
pub const AXES: [char; 3] = ['x', 'y', 'z'];

/// A face of an element: the reference face normal to `axis` on `side` (0: xi = -1, 1: xi = +1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub struct Face {
    pub element: usize,
    pub axis: u8,
    pub side: u8,
}

/// A mesh of one body.
#[derive(Debug, Clone)]
pub struct Mesh<const D: usize> {
    pub nodes: Vec<[f64; D]>,
    /// element connectivity, `2^D` nodes per element in tensor order
    pub connectivity: Vec<usize>,
    /// named face sets (`x-`, `x+`, ... for boxes; physical groups for Gmsh meshes)
    pub face_sets: BTreeMap<String, Vec<Face>>,
}

impl<const D: usize> Mesh<D> {
    pub fn n_elements(&self) -> usize {
        self.connectivity.len() / nodes_per_element(D)
    }

    pub fn element(&self, e: usize) -> &[usize] {
        let nn = nodes_per_element(D);
        &self.connectivity[e * nn..(e + 1) * nn]
    }

    /// Body node numbers of a face, in the face's own tensor order.
    pub fn face_nodes(&self, f: Face) -> Vec<usize> {
        let el = self.element(f.element);
        face_local_nodes(D, f.axis as usize, f.side as usize).into_iter().map(|a| el[a]).collect()
    }

    /// Centroid of an element.
    pub fn centroid(&self, e: usize) -> [f64; D] {
        let el = self.element(e);
        let mut c = [0.0; D];
        for &n in el {
            for d in 0..D {
                c[d] += self.nodes[n][d] / el.len() as f64;
            }
        }
        c
    }

    /// A structured box `origin + [0, size]` with `counts[d]` elements along axis `d`; face sets
    /// `x-`, `x+`, `y-`, ... name its sides.
    pub fn structured_box(origin: [f64; D], size: [f64; D], counts: [usize; D]) -> Self {
        let np: Vec<usize> = counts.iter().map(|c| c + 1).collect();
        let node_id = |idx: &[usize; D]| {
            let mut id = 0;
            for d in (0..D).rev() {
                id = id * np[d] + idx[d];
            }
            id
        };
        let n_nodes: usize = np.iter().product();
        let mut nodes = vec![[0.0; D]; n_nodes];
        for (id, node) in nodes.iter_mut().enumerate() {
            let mut r = id;
            for d in 0..D {
                let i = r % np[d];
                r /= np[d];
                node[d] = origin[d] + size[d] * i as f64 / counts[d] as f64;
            }
        }
        let n_el: usize = counts.iter().product();
        let nn = nodes_per_element(D);
        let mut connectivity = Vec::with_capacity(n_el * nn);
        let mut face_sets: BTreeMap<String, Vec<Face>> = BTreeMap::new();
        for e in 0..n_el {
            let mut eidx = [0usize; D];
            let mut r = e;
            for d in 0..D {
                eidx[d] = r % counts[d];
                r /= counts[d];
            }
            for a in 0..nn {
                let mut idx = eidx;
                for (d, v) in idx.iter_mut().enumerate() {
                    *v += (a >> d) & 1;
                }
                connectivity.push(node_id(&idx));
            }
            for d in 0..D {
                for (side, at_side) in [(0u8, eidx[d] == 0), (1u8, eidx[d] + 1 == counts[d])] {
                    if at_side {
                        let name = format!("{}{}", AXES[d], if side == 0 { '-' } else { '+' });
                        face_sets.entry(name).or_default().push(Face { element: e, axis: d as u8, side });
                    }
                }
            }
        }
        Self { nodes, connectivity, face_sets }
    }

    /// Partition of a structured box's elements into `parts[d]` blocks along each axis
    /// (element -> substructure index, lexicographic in the block indices).
    pub fn box_partition(counts: [usize; D], parts: [usize; D]) -> Vec<usize> {
        let n_el: usize = counts.iter().product();
        (0..n_el)
            .map(|e| {
                let mut r = e;
                let mut id = 0;
                let mut stride = 1;
                for d in 0..D {
                    let i = r % counts[d];
                    r /= counts[d];
                    id += stride * (i * parts[d] / counts[d]);
                    stride *= parts[d];
                }
                id
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_counts_and_faces() {
        let m = Mesh::<3>::structured_box([0.0; 3], [1.0, 2.0, 3.0], [2, 3, 4]);
        assert_eq!(m.nodes.len(), 3 * 4 * 5);
        assert_eq!(m.n_elements(), 24);
        assert_eq!(m.face_sets["x-"].len(), 12);
        assert_eq!(m.face_sets["z+"].len(), 6);
        for f in &m.face_sets["z+"] {
            assert!(m.face_nodes(*f).iter().all(|&n| (m.nodes[n][2] - 3.0).abs() < 1e-15));
        }
        let p = Mesh::<3>::box_partition([2, 3, 4], [1, 1, 2]);
        assert_eq!(p.iter().filter(|&&s| s == 0).count(), 12);
        assert_eq!(*p.iter().max().unwrap(), 1);
    }

    #[test]
    fn bar_mesh() {
        let m = Mesh::<1>::structured_box([0.0], [1.0], [4]);
        assert_eq!(m.nodes.len(), 5);
        assert_eq!(m.face_nodes(m.face_sets["x+"][0]), vec![4]);
        assert_eq!(Mesh::<1>::box_partition([4], [2]), vec![0, 0, 1, 1]);
    }
}
