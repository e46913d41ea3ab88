//! Bodies meshed by Gmsh: one physical volume of an MSH 4.1 file (ASCII or binary) as a
//! [`Mesh`], its faces named by the physical surfaces that cover them.
//!
//! `mshio` parses the file; `$PhysicalNames` (ASCII even in binary files, and not read by
//! mshio) is read here. A body takes the nodes of its own elements only, so nodes shared with
//! other volumes are split per body and the bodies meet through declared interfaces.

use std::collections::{BTreeMap, HashMap, HashSet};

use mshio::{ElementType, MshFile};

use crate::element::ElementKind;
use crate::mesh::{Face, Mesh};

#[derive(Debug, thiserror::Error)]
pub enum GmshError {
    #[error("{0}")]
    Read(String),
    #[error("not a readable MSH 4.1 file: {0}")]
    Parse(String),
    #[error("no physical volume '{volume}' in the file (physical volumes: {available})")]
    NoVolume { volume: String, available: String },
    #[error(
        "volume '{volume}': element type {element_type}; only 4-node tetrahedra and 8-node hexahedra are supported"
    )]
    UnsupportedElement { volume: String, element_type: String },
    #[error("volume '{volume}' mixes tetrahedra and hexahedra; mesh it with one kind")]
    MixedElements { volume: String },
    #[error(
        "physical surface '{surface}': element type {element_type}; only 3-node triangles and 4-node quadrangles are supported"
    )]
    UnsupportedFace { surface: String, element_type: String },
    #[error("volume '{volume}' has no elements")]
    Empty { volume: String },
    #[error("element {element} refers to node {node}, which the file does not define")]
    MissingNode { element: u64, node: u64 },
}

/// Gmsh's hexahedron node order (counter-clockwise bottom, then top) to tensor order.
const HEX_TENSOR_FROM_GMSH: [usize; 8] = [0, 1, 3, 2, 4, 5, 7, 6];

/// Reads physical volume `volume` of the MSH 4.1 file `bytes`.
pub fn parse_volume(bytes: &[u8], volume: &str) -> Result<Mesh<3>, GmshError> {
    let names = physical_names(bytes)?;
    // mshio can panic on inconsistent headers (e.g. a node count of 0 with tags): an error here
    let parsed = std::panic::catch_unwind(|| mshio::parse_msh_bytes(bytes))
        .map_err(|_| GmshError::Parse("the parser failed on an inconsistent section".into()))?;
    let msh: MshFile<u64, i32, f64> = parsed.map_err(|e| {
        // mshio's Display dumps the rest of the file: name the position and the contexts only
        let trace = e.filtered_backtrace();
        let at = trace.first().map_or(0, |(rest, _)| bytes.len() - rest.len());
        let what: Vec<String> = trace.iter().rev().map(|(_, k)| k.to_string()).collect();
        GmshError::Parse(format!("at byte {at}: {}", what.join(": ")))
    })?;
    let physical = |dim: i32, name: &str| names.iter().find(|(d, _, n)| *d == dim && n == name).map(|(_, t, _)| *t);
    let volume_tag = physical(3, volume).ok_or_else(|| GmshError::NoVolume {
        volume: volume.into(),
        available: names
            .iter()
            .filter(|(d, ..)| *d == 3)
            .map(|(.., n)| format!("'{n}'"))
            .collect::<Vec<_>>()
            .join(", "),
    })?;
    let data = &msh.data;
    let no_section = |s: &str| GmshError::Parse(format!("no {s} section"));
    let entities = data.entities.as_ref().ok_or_else(|| no_section("$Entities"))?;
    let elements = data.elements.as_ref().ok_or_else(|| no_section("$Elements"))?;
    let nodes = data.nodes.as_ref().ok_or_else(|| no_section("$Nodes"))?;

    // The volume's elements (Gmsh node tags), of one kind.
    let volume_entities: HashSet<i32> =
        entities.volumes.iter().filter(|v| v.physical_tags.contains(&volume_tag)).map(|v| v.tag).collect();
    let mut kind = None;
    let mut cells: Vec<(u64, Vec<u64>)> = Vec::new();
    for block in elements.element_blocks.iter().filter(|b| b.entity_dim == 3 && volume_entities.contains(&b.entity_tag))
    {
        let block_kind = match block.element_type {
            ElementType::Tet4 => ElementKind::Simplex,
            ElementType::Hex8 => ElementKind::Tensor,
            other => {
                return Err(GmshError::UnsupportedElement {
                    volume: volume.into(),
                    element_type: format!("{other:?} (Gmsh type {})", other as u8),
                });
            }
        };
        if kind.is_some_and(|k| k != block_kind) {
            return Err(GmshError::MixedElements { volume: volume.into() });
        }
        kind = Some(block_kind);
        cells.extend(block.elements.iter().map(|e| (e.element_tag, e.nodes.clone())));
    }
    let kind = kind.ok_or_else(|| GmshError::Empty { volume: volume.into() })?;

    // The body's own nodes: those of its elements, numbered in increasing tag order.
    let mut tags: Vec<u64> = cells.iter().flat_map(|(_, n)| n.iter().copied()).collect();
    tags.sort_unstable();
    tags.dedup();
    let local: HashMap<u64, usize> = tags.iter().enumerate().map(|(l, &t)| (t, l)).collect();
    let mut coords: Vec<Option<[f64; 3]>> = vec![None; tags.len()];
    // mshio keeps a block's tags only when the file's tags are sparse; otherwise they run on
    // from the smallest tag in block order
    let mut next_tag = nodes.min_node_tag;
    for block in &nodes.node_blocks {
        let mut block_tags = vec![0; block.nodes.len()];
        match &block.node_tags {
            Some(map) => {
                for (&t, &i) in map {
                    if let Some(slot) = block_tags.get_mut(i) {
                        *slot = t;
                    }
                }
            }
            None => {
                for t in block_tags.iter_mut() {
                    *t = next_tag;
                    next_tag += 1;
                }
            }
        }
        for (t, n) in block_tags.iter().zip(&block.nodes) {
            if let Some(&l) = local.get(t) {
                coords[l] = Some([n.x, n.y, n.z]);
            }
        }
    }
    let mut connectivity = Vec::with_capacity(cells.len() * kind.nodes(3));
    for (tag, cell) in &cells {
        for (a, &n) in cell.iter().enumerate() {
            if coords[local[&n]].is_none() {
                return Err(GmshError::MissingNode { element: *tag, node: n });
            }
            let from = if kind == ElementKind::Tensor { cell[HEX_TENSOR_FROM_GMSH[a]] } else { n };
            connectivity.push(local[&from]);
        }
    }
    let mut mesh = Mesh {
        nodes: coords.into_iter().map(|c| c.expect("checked above")).collect(),
        kind,
        connectivity,
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
    for (dim, tag, name) in names.iter().filter(|(d, ..)| *d == 2) {
        let surfaces: HashSet<i32> =
            entities.surfaces.iter().filter(|s| s.physical_tags.contains(tag)).map(|s| s.tag).collect();
        let mut faces = Vec::new();
        for block in elements.element_blocks.iter().filter(|b| b.entity_dim == *dim && surfaces.contains(&b.entity_tag))
        {
            if !matches!(block.element_type, ElementType::Tri3 | ElementType::Qua4) {
                return Err(GmshError::UnsupportedFace {
                    surface: name.clone(),
                    element_type: format!("{:?} (Gmsh type {})", block.element_type, block.element_type as u8),
                });
            }
            for e in &block.elements {
                let key: Option<Vec<usize>> = e.nodes.iter().map(|n| local.get(n).copied()).collect();
                let Some(mut key) = key else { continue };
                key.sort_unstable();
                if let Some(Some(f)) = boundary.get(&key) {
                    faces.push(*f);
                }
            }
        }
        if !faces.is_empty() {
            faces.sort_unstable();
            mesh.face_sets.insert(name.clone(), faces);
        }
    }
    Ok(mesh)
}

/// The `$PhysicalNames` section: (dimension, tag, name) of each physical group.
fn physical_names(bytes: &[u8]) -> Result<Vec<(i32, i32, String)>, GmshError> {
    const START: &[u8] = b"$PhysicalNames";
    const END: &[u8] = b"$EndPhysicalNames";
    let find = |hay: &[u8], needle: &[u8]| hay.windows(needle.len()).position(|w| w == needle);
    let Some(start) = find(bytes, START) else { return Ok(Vec::new()) };
    let rest = &bytes[start + START.len()..];
    let bad = |m: String| GmshError::Parse(format!("$PhysicalNames: {m}"));
    let end = find(rest, END).ok_or_else(|| bad("no $EndPhysicalNames".into()))?;
    let text = std::str::from_utf8(&rest[..end]).map_err(|_| bad("not text".into()))?;
    let mut lines = text.lines().map(str::trim).filter(|l| !l.is_empty());
    let count: usize = lines.next().and_then(|l| l.parse().ok()).ok_or_else(|| bad("no count".into()))?;
    let mut names = Vec::new();
    for line in lines {
        let mut fields = line.splitn(3, char::is_whitespace);
        let mut int = || fields.next().and_then(|f| f.parse::<i32>().ok());
        let (Some(dim), Some(tag)) = (int(), int()) else {
            return Err(bad(format!("line '{line}' is not `dimension tag \"name\"`")));
        };
        let name = fields.next().unwrap_or("").trim().trim_matches('"');
        names.push((dim, tag, name.to_string()));
    }
    if names.len() != count {
        return Err(bad(format!("{count} names announced, {} given", names.len())));
    }
    Ok(names)
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
