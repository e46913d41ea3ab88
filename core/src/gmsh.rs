//! MSH 4.1 files (Gmsh, ASCII or binary) read into the volumes that scenes name: the one reading
//! that the solver (which builds a body's mesh from it) and the coordinator (which sizes a
//! submitted scene from it) share.
//!
//! `mshio` parses the file; `$PhysicalNames` (ASCII even in binary files, and not read by
//! mshio) is read here. A volume takes the nodes of its own elements only, so nodes shared with
//! other volumes are split per body and the bodies meet through declared interfaces.

use std::collections::{HashMap, HashSet};

use mshio::{ElementType, MshFile};

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

/// One physical volume of a file, with the body's own node numbering.
#[derive(Debug, Clone)]
pub struct Volume {
    /// hexahedra (8 nodes, tensor order) or else tetrahedra (4 nodes)
    pub hexahedra: bool,
    /// the volume's nodes, in increasing Gmsh tag order
    pub nodes: Vec<[f64; 3]>,
    pub connectivity: Vec<usize>,
    /// every physical surface: its triangles / quadrangles whose nodes all belong to the volume,
    /// as volume node numbers (whether each is a face of the volume is the caller's to check)
    pub surfaces: Vec<(String, Vec<Vec<usize>>)>,
}

/// A parsed MSH 4.1 file and its physical names.
pub struct Msh {
    names: Vec<(i32, i32, String)>,
    msh: MshFile<u64, i32, f64>,
}

impl Msh {
    /// Parses the file's bytes.
    pub fn parse(bytes: &[u8]) -> Result<Self, GmshError> {
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
        Ok(Self { names, msh })
    }

    /// Physical volume `volume`.
    pub fn volume(&self, volume: &str) -> Result<Volume, GmshError> {
        let names = &self.names;
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
        let data = &self.msh.data;
        let no_section = |s: &str| GmshError::Parse(format!("no {s} section"));
        let entities = data.entities.as_ref().ok_or_else(|| no_section("$Entities"))?;
        let elements = data.elements.as_ref().ok_or_else(|| no_section("$Elements"))?;
        let nodes = data.nodes.as_ref().ok_or_else(|| no_section("$Nodes"))?;

        // The volume's elements (Gmsh node tags), of one kind.
        let volume_entities: HashSet<i32> =
            entities.volumes.iter().filter(|v| v.physical_tags.contains(&volume_tag)).map(|v| v.tag).collect();
        let mut hexahedra = None;
        let mut cells: Vec<(u64, &[u64])> = Vec::new();
        for block in
            elements.element_blocks.iter().filter(|b| b.entity_dim == 3 && volume_entities.contains(&b.entity_tag))
        {
            let block_hex = match block.element_type {
                ElementType::Tet4 => false,
                ElementType::Hex8 => true,
                other => {
                    return Err(GmshError::UnsupportedElement {
                        volume: volume.into(),
                        element_type: format!("{other:?} (Gmsh type {})", other as u8),
                    });
                }
            };
            if hexahedra.is_some_and(|h| h != block_hex) {
                return Err(GmshError::MixedElements { volume: volume.into() });
            }
            hexahedra = Some(block_hex);
            cells.extend(block.elements.iter().map(|e| (e.element_tag, e.nodes.as_slice())));
        }
        let hexahedra = hexahedra.ok_or_else(|| GmshError::Empty { volume: volume.into() })?;

        // The volume's own nodes: those of its elements, numbered in increasing tag order.
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
        let per_cell = if hexahedra { 8 } else { 4 };
        let mut connectivity = Vec::with_capacity(cells.len() * per_cell);
        for (tag, cell) in &cells {
            for (a, &n) in cell.iter().enumerate() {
                if coords[local[&n]].is_none() {
                    return Err(GmshError::MissingNode { element: *tag, node: n });
                }
                let from = if hexahedra { cell[HEX_TENSOR_FROM_GMSH[a]] } else { n };
                connectivity.push(local[&from]);
            }
        }

        let mut surfaces = Vec::new();
        for (dim, tag, name) in names.iter().filter(|(d, ..)| *d == 2) {
            let entity_tags: HashSet<i32> =
                entities.surfaces.iter().filter(|s| s.physical_tags.contains(tag)).map(|s| s.tag).collect();
            let mut faces = Vec::new();
            for block in
                elements.element_blocks.iter().filter(|b| b.entity_dim == *dim && entity_tags.contains(&b.entity_tag))
            {
                if !matches!(block.element_type, ElementType::Tri3 | ElementType::Qua4) {
                    return Err(GmshError::UnsupportedFace {
                        surface: name.clone(),
                        element_type: format!("{:?} (Gmsh type {})", block.element_type, block.element_type as u8),
                    });
                }
                faces.extend(
                    block.elements.iter().filter_map(|e| e.nodes.iter().map(|n| local.get(n).copied()).collect()),
                );
            }
            surfaces.push((name.clone(), faces));
        }
        Ok(Volume {
            hexahedra,
            nodes: coords.into_iter().map(|c| c.expect("checked above")).collect(),
            connectivity,
            surfaces,
        })
    }
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
