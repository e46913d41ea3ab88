//! Bodies meshed by Gmsh: one physical volume of an MSH 4.1 file (read by
//! [`glissade_core::gmsh`]) as a [`Mesh`], its faces named by the physical surfaces that cover
//! them.

use std::collections::{BTreeMap, HashMap};

pub use glissade_core::gmsh::GmshError;
use glissade_core::gmsh::Msh;

use crate::element::ElementKind;
use crate::mesh::{Face, Mesh};

/// Reads physical volume `volume` of the MSH 4.1 file `bytes`.
pub fn parse_volume(bytes: &[u8], volume: &str) -> Result<Mesh<3>, GmshError> {
    let v = Msh::parse(bytes)?.volume(volume)?;
    let mut mesh = Mesh {
        nodes: v.nodes,
        kind: if v.hexahedra { ElementKind::Tensor } else { ElementKind::Simplex },
        connectivity: v.connectivity,
        face_sets: BTreeMap::new(),
    };
    // Faces: the body's boundary faces, keyed by their sorted node numbers; a physical surface
    // names those of its triangles / quadrangles that are faces of this body.
    let mut boundary: HashMap<Vec<usize>, Option<Face>> = HashMap::new();
    for e in 0..mesh.n_elements() {
        for f in mesh.faces_of(e) {
            let mut key = mesh.face_nodes(f);
            key.sort_unstable();
            // a face met twice is inside the body
            boundary.entry(key).and_modify(|seen| *seen = None).or_insert(Some(f));
        }
    }
    for (name, surface) in v.surfaces {
        let mut faces: Vec<Face> = surface
            .into_iter()
            .filter_map(|mut key| {
                key.sort_unstable();
                boundary.get(&key).copied().flatten()
            })
            .collect();
        if !faces.is_empty() {
            faces.sort_unstable();
            mesh.face_sets.insert(name, faces);
        }
    }
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two hexahedra side by side along x, the left one in volume "left" with Gmsh's node order.
    const TWO_HEXES: &str = "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n\
$PhysicalNames\n3\n2 1 \"left_end\"\n3 2 \"left\"\n3 3 \"right\"\n$EndPhysicalNames\n\
$Entities\n0 0 1 2\n1 0 0 0 0 1 1 1 1 1 0\n\
1 0 0 0 1 1 1 1 2 0\n2 1 0 0 2 1 1 1 3 0\n$EndEntities\n\
$Nodes\n1 12 1 12\n3 1 0 12\n1\n2\n3\n4\n5\n6\n7\n8\n9\n10\n11\n12\n\
0 0 0\n1 0 0\n1 1 0\n0 1 0\n0 0 1\n1 0 1\n1 1 1\n0 1 1\n2 0 0\n2 1 0\n2 0 1\n2 1 1\n$EndNodes\n\
$Elements\n3 3 1 3\n2 1 3 1\n1 1 4 8 5\n3 1 5 1\n2 1 2 3 4 5 6 7 8\n3 2 5 1\n3 2 9 10 3 6 11 12 7\n$EndElements\n";

    #[test]
    fn hexahedra_in_tensor_order_with_named_faces() {
        let m = parse_volume(TWO_HEXES.as_bytes(), "left").unwrap();
        assert_eq!((m.kind, m.n_elements(), m.nodes.len()), (ElementKind::Tensor, 1, 8));
        // tensor order: local a at (a & 1, a >> 1 & 1, a >> 2 & 1)
        for (a, &n) in m.element(0).iter().enumerate() {
            let expect = [(a & 1) as f64, (a >> 1 & 1) as f64, (a >> 2 & 1) as f64];
            assert_eq!(m.nodes[n], expect, "local node {a}");
        }
        assert_eq!(m.face_sets["left_end"], vec![Face::tensor(0, 0, 0)]);
        // the right body has its own copies of the shared nodes, and no left_end face
        let r = parse_volume(TWO_HEXES.as_bytes(), "right").unwrap();
        assert_eq!(r.nodes.len(), 8);
        assert!(r.face_sets.is_empty());
    }

    #[test]
    fn precise_errors() {
        let e = parse_volume(TWO_HEXES.as_bytes(), "middle").unwrap_err().to_string();
        assert_eq!(e, "no physical volume 'middle' in the file (physical volumes: 'left', 'right')");
        // a 6-node prism (Gmsh type 6) in the right volume
        let prism = TWO_HEXES.replace("3 2 5 1\n3 2 9 10 3 6 11 12 7\n", "3 2 6 1\n3 2 9 10 6 11 12\n");
        let e = parse_volume(prism.as_bytes(), "right").unwrap_err().to_string();
        assert!(e.starts_with("volume 'right': element type Pri6 (Gmsh type 6)"), "{e}");
        let e = parse_volume(b"$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 2\n", "v").unwrap_err();
        assert!(e.to_string().starts_with("not a readable MSH 4.1 file"), "{e}");
        // counts announced by a hostile header allocate nothing: the parse fails on the data
        let huge = TWO_HEXES.replace("$Nodes\n1 12 1 12\n3 1 0 12\n", "$Nodes\n1 12 1 12\n3 1 0 999999999999\n");
        let e = parse_volume(huge.as_bytes(), "left").unwrap_err();
        assert!(e.to_string().starts_with("not a readable MSH 4.1 file"), "{e}");
        let huge = TWO_HEXES.replace("$Elements\n3 3 1 3\n", "$Elements\n999999999999 3 1 3\n");
        let e = parse_volume(huge.as_bytes(), "left").unwrap_err();
        assert!(e.to_string().starts_with("not a readable MSH 4.1 file"), "{e}");
        let missing = TWO_HEXES.replace("1 1 4 8 5\n", "1 1 4 8 99\n");
        assert!(parse_volume(missing.as_bytes(), "left").is_ok(), "a surface of unknown nodes names no face");
        let missing = TWO_HEXES.replace("2 1 2 3 4 5 6 7 8\n", "2 1 2 3 4 5 6 7 99\n");
        let e = parse_volume(missing.as_bytes(), "left").unwrap_err().to_string();
        assert_eq!(e, "element 2 refers to node 99, which the file does not define");
    }
}
