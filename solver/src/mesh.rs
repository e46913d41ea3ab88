//! Unstructured meshes of linear elements with tagged faces, and the structured box generator.
//!
//! The solver only sees [`Mesh`] (nodes, elements of one [`ElementKind`], named face sets) and
//! an element partition into substructures, so Gmsh meshes (crate::gmsh) replace the boxes
//! without touching it.

use std::collections::{BTreeMap, HashMap};

use crate::element::{ElementKind, nodes_per_element};

/// Axis names used in face tags and vector components.
pub const AXES: [char; 3] = ['x', 'y', 'z'];

/// A face of an element: its local face `local` ([`ElementKind::face_local_nodes`]); for
/// tensor elements `2 axis + side`, the reference face normal to `axis` on `side`
/// (0: xi = -1, 1: xi = +1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub struct Face {
    pub element: usize,
    pub local: u8,
}

impl Face {
    /// The face of a tensor element normal to `axis` on `side`.
    pub fn tensor(element: usize, axis: usize, side: usize) -> Self {
        Face { element, local: (2 * axis + side) as u8 }
    }
}

/// A mesh of one body.
#[derive(Debug, Clone)]
pub struct Mesh<const D: usize> {
    pub nodes: Vec<[f64; D]>,
    pub kind: ElementKind,
    /// element connectivity, [`ElementKind::nodes`] per element (tensor order for tensor elements)
    pub connectivity: Vec<usize>,
    /// named face sets (`x-`, `x+`, ... for boxes; physical groups for Gmsh meshes)
    pub face_sets: BTreeMap<String, Vec<Face>>,
}

impl<const D: usize> Mesh<D> {
    pub fn n_elements(&self) -> usize {
        self.connectivity.len() / self.kind.nodes(D)
    }

    pub fn element(&self, e: usize) -> &[usize] {
        let nn = self.kind.nodes(D);
        &self.connectivity[e * nn..(e + 1) * nn]
    }

    /// Every face of element `e`.
    pub fn faces_of(&self, e: usize) -> impl Iterator<Item = Face> {
        (0..self.kind.faces(D)).map(move |local| Face { element: e, local: local as u8 })
    }

    /// Body node numbers of a face, in the face's own order.
    pub fn face_nodes(&self, f: Face) -> Vec<usize> {
        let el = self.element(f.element);
        self.kind.face_local_nodes(D, f.local as usize).into_iter().map(|a| el[a]).collect()
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
                for (side, at_side) in [(0, eidx[d] == 0), (1, eidx[d] + 1 == counts[d])] {
                    if at_side {
                        let name = format!("{}{}", AXES[d], if side == 0 { '-' } else { '+' });
                        face_sets.entry(name).or_default().push(Face::tensor(e, d, side));
                    }
                }
            }
        }
        Self { nodes, kind: ElementKind::Tensor, connectivity, face_sets }
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

/// Why [`Mesh::graph_partition`] found no partition.
#[derive(Debug, thiserror::Error)]
pub enum PartitionError {
    #[error("{elements} elements are too many for METIS's 32-bit indices")]
    TooMany { elements: usize },
    #[error("METIS refused the graph: {0}")]
    Graph(#[source] metis::NewGraphError),
    #[error("METIS failed: {0}")]
    Metis(#[source] metis::Error),
    #[error("METIS left substructure {part} of {parts} empty: ask for fewer")]
    EmptyPart { part: usize, parts: usize },
    #[error("substructure {part} is not contiguous (element {element}): is the volume in one piece?")]
    NotContiguous { part: usize, element: usize },
}

impl<const D: usize> Mesh<D> {
    /// Partition of the elements into `parts` substructures (element -> part) by METIS k-way on
    /// the dual graph (elements joined by a face): parts balanced (METIS's default 3 %
    /// imbalance) and contiguous, checked here; deterministic (fixed seed).
    pub fn graph_partition(&self, parts: usize) -> Result<Vec<usize>, PartitionError> {
        let n = self.n_elements();
        if parts <= 1 {
            return Ok(vec![0; n]);
        }
        let neighbours = self.dual_graph();
        let idx = |v: usize| metis::Idx::try_from(v).map_err(|_| PartitionError::TooMany { elements: n });
        let mut xadj = vec![0];
        let mut adjncy = Vec::new();
        for adj in &neighbours {
            for &e in adj {
                adjncy.push(idx(e)?);
            }
            xadj.push(idx(adjncy.len())?);
        }
        let mut part = vec![0; n];
        metis::Graph::new(1, idx(parts)?, &xadj, &adjncy)
            .map_err(PartitionError::Graph)?
            .set_option(metis::option::Contig(true))
            .set_option(metis::option::Seed(0))
            .part_kway(&mut part)
            .map_err(PartitionError::Metis)?;
        let part: Vec<usize> = part.into_iter().map(|p| p as usize).collect();
        // every part present and connected (a disconnected volume cannot be cut contiguously)
        let mut reached = vec![false; n];
        for p in 0..parts {
            let Some(seed) = (0..n).find(|&e| part[e] == p) else {
                return Err(PartitionError::EmptyPart { part: p, parts });
            };
            let mut stack = vec![seed];
            reached[seed] = true;
            while let Some(e) = stack.pop() {
                for &f in &neighbours[e] {
                    if part[f] == p && !reached[f] {
                        reached[f] = true;
                        stack.push(f);
                    }
                }
            }
        }
        if let Some(e) = reached.iter().position(|r| !r) {
            return Err(PartitionError::NotContiguous { part: part[e], element: e });
        }
        Ok(part)
    }

    /// Elements sharing a face with each element, in increasing order.
    fn dual_graph(&self) -> Vec<Vec<usize>> {
        let mut by_face: HashMap<Vec<usize>, usize> = HashMap::new();
        let mut neighbours = vec![Vec::new(); self.n_elements()];
        for e in 0..self.n_elements() {
            for f in self.faces_of(e) {
                let mut key = self.face_nodes(f);
                key.sort_unstable();
                if let Some(other) = by_face.insert(key, e) {
                    neighbours[e].push(other);
                    neighbours[other].push(e);
                }
            }
        }
        for adj in neighbours.iter_mut() {
            adj.sort_unstable();
        }
        neighbours
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
    fn graph_partition_is_balanced_and_contiguous() {
        let m = Mesh::<3>::structured_box([0.0; 3], [1.0; 3], [6, 4, 2]);
        let p = m.graph_partition(4).unwrap();
        for s in 0..4 {
            let n = p.iter().filter(|&&q| q == s).count();
            assert!((11..=13).contains(&n), "part {s} has {n} of 48 elements");
        }
        assert_eq!(p, m.graph_partition(4).unwrap(), "deterministic");
        assert!(m.graph_partition(1).unwrap().iter().all(|&q| q == 0));
    }

    #[test]
    fn bar_mesh() {
        let m = Mesh::<1>::structured_box([0.0], [1.0], [4]);
        assert_eq!(m.nodes.len(), 5);
        assert_eq!(m.face_nodes(m.face_sets["x+"][0]), vec![4]);
        assert_eq!(Mesh::<1>::box_partition([4], [2]), vec![0, 0, 1, 1]);
    }
}
