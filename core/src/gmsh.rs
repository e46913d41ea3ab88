//! MSH 4.1 files (Gmsh, ASCII or binary) read into the volumes that scenes name: the one reading
//! that the solver (which builds a body's mesh from it) and the coordinator (which sizes a
//! submitted scene from it) share.
//!
//! The reader takes the sections a volume needs (`$MeshFormat`, `$PhysicalNames`, `$Entities`,
//! `$Nodes`, `$Elements`) and steps over the others. A file may come from a client that is not
//! ours: nothing is allocated from a count the file announces (each item is read before it is
//! stored, so memory follows the file's length), and every failure is an error naming the byte
//! and the section. A volume takes the nodes of its own elements only, so nodes shared with other
//! volumes are split per body and the bodies meet through declared interfaces.

use std::collections::{HashMap, HashSet};

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

/// Gmsh's element types 1-31 (their short names and node counts): a block of any of them is
/// read, whether or not a volume uses it, since its length depends on the count.
const ELEMENT_TYPES: [(&str, usize); 31] = [
    ("Lin2", 2),
    ("Tri3", 3),
    ("Qua4", 4),
    ("Tet4", 4),
    ("Hex8", 8),
    ("Pri6", 6),
    ("Pyr5", 5),
    ("Lin3", 3),
    ("Tri6", 6),
    ("Qua9", 9),
    ("Tet10", 10),
    ("Hex27", 27),
    ("Pri18", 18),
    ("Pyr14", 14),
    ("Pnt", 1),
    ("Qua8", 8),
    ("Hex20", 20),
    ("Pri15", 15),
    ("Pyr13", 13),
    ("Tri9", 9),
    ("Tri10", 10),
    ("Tri12", 12),
    ("Tri15", 15),
    ("Tri15i", 15),
    ("Tri21", 21),
    ("Lin4", 4),
    ("Lin5", 5),
    ("Lin6", 6),
    ("Tet20", 20),
    ("Tet35", 35),
    ("Tet56", 56),
];
const TRI3: i32 = 2;
const QUA4: i32 = 3;
const TET4: i32 = 4;
const HEX8: i32 = 5;

/// Gmsh's element type `element_type`: its short name and node count, if it is one of 1-31.
fn element_type(element_type: i32) -> Option<(&'static str, usize)> {
    let index = usize::try_from(element_type).ok()?.checked_sub(1)?;
    ELEMENT_TYPES.get(index).copied()
}

/// "Tet10 (Gmsh type 11)": an element type as errors name it.
fn element_type_name(element_type: i32) -> String {
    let name = self::element_type(element_type).map_or("?", |t| t.0);
    format!("{name} (Gmsh type {element_type})")
}

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

/// One block of `$Elements`: elements of one type on one entity.
struct ElementBlock {
    entity_dim: i32,
    entity_tag: i32,
    element_type: i32,
    /// the elements' tags
    tags: Vec<u64>,
    /// their node tags, `per` an element
    nodes: Vec<u64>,
    per: usize,
}

impl ElementBlock {
    fn elements(&self) -> impl Iterator<Item = (u64, &[u64])> {
        self.tags.iter().copied().zip(self.nodes.chunks(self.per))
    }
}

/// A parsed MSH 4.1 file: the sections a volume is read from.
pub struct Msh {
    /// `$PhysicalNames`: (dimension, tag, name)
    names: Vec<(i32, i32, String)>,
    /// `$Entities`: the physical tags of each (dimension, entity tag)
    physical: HashMap<(i32, i32), Vec<i32>>,
    /// `$Nodes`: (tag, coordinates), in file order
    nodes: Vec<(u64, [f64; 3])>,
    elements: Vec<ElementBlock>,
    /// which of `$Entities`, `$Nodes`, `$Elements` the file has
    sections: [bool; 3],
}

impl Msh {
    /// Parses the file's bytes.
    pub fn parse(bytes: &[u8]) -> Result<Self, GmshError> {
        let mut msh = Msh {
            names: Vec::new(),
            physical: HashMap::new(),
            nodes: Vec::new(),
            elements: Vec::new(),
            sections: [false; 3],
        };
        let mut at = Cursor { bytes, at: 0, format: None, section: "" };
        loop {
            at.skip_space();
            if at.at == bytes.len() {
                break;
            }
            let header = at.line()?;
            let name = header.strip_prefix('$').filter(|n| !n.is_empty() && !n.starts_with("End"));
            let name = name.ok_or_else(|| at.error(format!("'{}' where a section starts", clip(header))))?;
            at.section = name;
            match name {
                "MeshFormat" => at.mesh_format()?,
                "PhysicalNames" => msh.names = at.physical_names()?,
                "Entities" => (msh.physical, msh.sections[0]) = (at.entities()?, true),
                "Nodes" => (msh.nodes, msh.sections[1]) = (at.nodes()?, true),
                "Elements" => (msh.elements, msh.sections[2]) = (at.elements()?, true),
                _ => {
                    at.skip_section(name)?;
                    continue;
                }
            }
            at.end_of_section(name)?;
        }
        Ok(msh)
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
        for (present, section) in self.sections.iter().zip(["$Entities", "$Nodes", "$Elements"]) {
            if !present {
                return Err(GmshError::Parse(format!("no {section} section")));
            }
        }
        let entities_of = |dim: i32, tag: i32| -> HashSet<i32> {
            self.physical.iter().filter(|((d, _), p)| *d == dim && p.contains(&tag)).map(|((_, t), _)| *t).collect()
        };

        // The volume's elements (Gmsh node tags), of one kind.
        let volume_entities = entities_of(3, volume_tag);
        let mut hexahedra = None;
        let mut cells: Vec<(u64, &[u64])> = Vec::new();
        for block in self.elements.iter().filter(|b| b.entity_dim == 3 && volume_entities.contains(&b.entity_tag)) {
            let block_hex = match block.element_type {
                TET4 => false,
                HEX8 => true,
                other => {
                    return Err(GmshError::UnsupportedElement {
                        volume: volume.into(),
                        element_type: element_type_name(other),
                    });
                }
            };
            if hexahedra.is_some_and(|h| h != block_hex) {
                return Err(GmshError::MixedElements { volume: volume.into() });
            }
            hexahedra = Some(block_hex);
            cells.extend(block.elements());
        }
        let hexahedra = hexahedra.ok_or_else(|| GmshError::Empty { volume: volume.into() })?;

        // The volume's own nodes: those of its elements, numbered in increasing tag order.
        let mut tags: Vec<u64> = cells.iter().flat_map(|(_, n)| n.iter().copied()).collect();
        tags.sort_unstable();
        tags.dedup();
        let local: HashMap<u64, usize> = tags.iter().enumerate().map(|(l, &t)| (t, l)).collect();
        let mut coords: Vec<Option<[f64; 3]>> = vec![None; tags.len()];
        for (t, x) in &self.nodes {
            if let Some(&l) = local.get(t) {
                coords[l] = Some(*x);
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
            let entity_tags = entities_of(*dim, *tag);
            let mut faces = Vec::new();
            for block in self.elements.iter().filter(|b| b.entity_dim == *dim && entity_tags.contains(&b.entity_tag)) {
                if !matches!(block.element_type, TRI3 | QUA4) {
                    return Err(GmshError::UnsupportedFace {
                        surface: name.clone(),
                        element_type: element_type_name(block.element_type),
                    });
                }
                faces.extend(block.elements().filter_map(|(_, e)| e.iter().map(|n| local.get(n).copied()).collect()));
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

/// At most 40 characters of a file's text, for an error.
fn clip(text: &str) -> String {
    crate::text::one_line(&text.chars().take(40).collect::<String>())
}

/// Binary or ASCII, and the size of a `size_t` (4 or 8 bytes).
#[derive(Clone, Copy)]
struct Format {
    binary: bool,
    size_t: usize,
}

/// A position in the file, and how its values are written.
struct Cursor<'a> {
    bytes: &'a [u8],
    at: usize,
    /// from `$MeshFormat`; None before it
    format: Option<Format>,
    section: &'a str,
}

impl<'a> Cursor<'a> {
    fn error(&self, what: String) -> GmshError {
        GmshError::Parse(format!("at byte {}: ${}: {what}", self.at, self.section))
    }

    fn skip_space(&mut self) {
        while self.bytes.get(self.at).is_some_and(u8::is_ascii_whitespace) {
            self.at += 1;
        }
    }

    /// The rest of the line, without its end; the cursor after the line's end.
    fn line(&mut self) -> Result<&'a str, GmshError> {
        let rest = &self.bytes[self.at..];
        let end = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
        let line = std::str::from_utf8(&rest[..end]).map_err(|_| self.error("a line that is not text".into()))?;
        self.at += (end + 1).min(rest.len());
        Ok(line.trim())
    }

    /// The next whitespace-separated word (ASCII values).
    fn word(&mut self, what: &str) -> Result<&'a str, GmshError> {
        self.skip_space();
        let rest = &self.bytes[self.at..];
        let end = rest.iter().position(u8::is_ascii_whitespace).unwrap_or(rest.len());
        if end == 0 {
            return Err(self.error(format!("the file ends before {what}")));
        }
        let word = std::str::from_utf8(&rest[..end]).map_err(|_| self.error(format!("{what} is not text")))?;
        self.at += end;
        Ok(word)
    }

    /// The next `n` bytes (binary values).
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], GmshError> {
        let taken =
            self.bytes.get(self.at..self.at + n).ok_or_else(|| self.error(format!("the file ends before {what}")))?;
        self.at += n;
        Ok(taken)
    }

    fn format(&self) -> Result<Format, GmshError> {
        self.format.ok_or_else(|| self.error("no $MeshFormat before this section".into()))
    }

    fn parse<T: std::str::FromStr>(&mut self, what: &str) -> Result<T, GmshError> {
        let word = self.word(what)?;
        word.parse().map_err(|_| self.error(format!("{what} '{}' is not a number of its kind", clip(word))))
    }

    /// An `int`.
    fn int(&mut self, what: &str) -> Result<i32, GmshError> {
        if self.format()?.binary {
            let b = self.take(4, what)?;
            Ok(i32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        } else {
            self.parse(what)
        }
    }

    /// A `size_t`.
    fn size(&mut self, what: &str) -> Result<u64, GmshError> {
        let format = self.format()?;
        if format.binary {
            let b = self.take(format.size_t, what)?;
            let mut full = [0u8; 8];
            full[..b.len()].copy_from_slice(b);
            Ok(u64::from_le_bytes(full))
        } else {
            self.parse(what)
        }
    }

    /// A `double`.
    fn real(&mut self, what: &str) -> Result<f64, GmshError> {
        if self.format()?.binary {
            let b = self.take(8, what)?;
            Ok(f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]))
        } else {
            self.parse(what)
        }
    }

    /// A count of items of `values` values each, which the rest of the file must be able to
    /// hold (a value takes 2 bytes at least in text, 4 in binary) before anything is allocated
    /// for them: a parsed mesh then takes at most a few times its file.
    fn bounded_count(&mut self, values: usize, what: &str) -> Result<usize, GmshError> {
        let count = self.size(what)?;
        let least = values * if self.format()?.binary { 4 } else { 2 };
        let room = (self.bytes.len() - self.at) / least;
        match usize::try_from(count) {
            Ok(n) if n <= room => Ok(n),
            _ => Err(self.error(format!("{what} {count} is more than the rest of the file holds"))),
        }
    }

    fn mesh_format(&mut self) -> Result<(), GmshError> {
        let version = self.word("the version")?;
        if version != "4.1" {
            return Err(self.error(format!("version '{}': only MSH 4.1 is read (Gmsh: -format msh41)", clip(version))));
        }
        let binary = match self.word("the file type")? {
            "0" => false,
            "1" => true,
            other => return Err(self.error(format!("file type '{}' (0 or 1)", clip(other)))),
        };
        let size_t = match self.word("the data size")? {
            "4" => 4,
            "8" => 8,
            other => return Err(self.error(format!("data size '{}' (4 or 8)", clip(other)))),
        };
        self.line()?;
        self.format = Some(Format { binary, size_t });
        if binary && self.int("the byte order's mark")? != 1 {
            return Err(self.error("a big-endian file (only little-endian binary files are read)".into()));
        }
        Ok(())
    }

    /// `$PhysicalNames` (text even in binary files).
    fn physical_names(&mut self) -> Result<Vec<(i32, i32, String)>, GmshError> {
        let count: u64 = self.parse("the count of names")?;
        self.line()?;
        let mut names = Vec::new();
        for _ in 0..count {
            self.skip_space();
            let line = self.line()?;
            let mut fields = line.splitn(3, char::is_whitespace);
            let mut int = || fields.next().and_then(|f| f.parse::<i32>().ok());
            let (Some(dim), Some(tag)) = (int(), int()) else {
                return Err(self.error(format!("line '{}' is not `dimension tag \"name\"`", clip(line))));
            };
            let name = fields.next().unwrap_or("").trim().trim_matches('"');
            names.push((dim, tag, name.to_string()));
        }
        Ok(names)
    }

    /// `$Entities`: each entity's physical tags (its place and bounds are read and left).
    fn entities(&mut self) -> Result<HashMap<(i32, i32), Vec<i32>>, GmshError> {
        let mut counts = [0u64; 4];
        for (dim, c) in counts.iter_mut().enumerate() {
            *c = self.size(&format!("the count of entities of dimension {dim}"))?;
        }
        let mut physical = HashMap::new();
        for (dim, &count) in (0i32..).zip(&counts) {
            for _ in 0..count {
                let tag = self.int("an entity's tag")?;
                for _ in 0..if dim == 0 { 3 } else { 6 } {
                    self.real("an entity's bounds")?;
                }
                let mut tags = Vec::new();
                for _ in 0..self.size("a count of physical tags")? {
                    tags.push(self.int("a physical tag")?);
                }
                if dim > 0 {
                    for _ in 0..self.size("a count of bounding entities")? {
                        self.int("a bounding entity")?;
                    }
                }
                physical.insert((dim, tag), tags);
            }
        }
        Ok(physical)
    }

    /// The count of blocks that opens `$Nodes` and `$Elements` (of `item`s), past the three
    /// sizes after it: the count of items, their smallest and largest tags (not needed here).
    fn blocks(&mut self, item: &str) -> Result<u64, GmshError> {
        let blocks = self.size(&format!("the count of {item} blocks"))?;
        self.size(&format!("the count of {item}s"))?;
        self.size(&format!("the smallest {item} tag"))?;
        self.size(&format!("the largest {item} tag"))?;
        Ok(blocks)
    }

    /// `$Nodes`: every node's tag and coordinates.
    fn nodes(&mut self) -> Result<Vec<(u64, [f64; 3])>, GmshError> {
        let blocks = self.blocks("node")?;
        let mut nodes = Vec::new();
        for _ in 0..blocks {
            let dim = self.int("a node block's entity dimension")?;
            self.int("a node block's entity tag")?;
            let parametric = self.int("a node block's parametric flag")? != 0;
            let count = self.bounded_count(4, "a node block's count")?;
            nodes.reserve(count);
            let first = nodes.len();
            for _ in 0..count {
                nodes.push((self.size("a node tag")?, [0.0; 3]));
            }
            for node in &mut nodes[first..] {
                for x in &mut node.1 {
                    *x = self.real("a coordinate")?;
                }
                for _ in 0..if parametric { dim.clamp(0, 3) } else { 0 } {
                    self.real("a parametric coordinate")?;
                }
            }
        }
        Ok(nodes)
    }

    /// `$Elements`: every block, of any of Gmsh's types 1-31.
    fn elements(&mut self) -> Result<Vec<ElementBlock>, GmshError> {
        let mut blocks = Vec::new();
        for _ in 0..self.blocks("element")? {
            let entity_dim = self.int("an element block's entity dimension")?;
            let entity_tag = self.int("an element block's entity tag")?;
            let element_type = self.int("an element block's type")?;
            let per = self::element_type(element_type).map(|t| t.1);
            let per = per.ok_or_else(|| self.error(format!("element type {element_type} (this reader knows 1-31)")))?;
            let count = self.bounded_count(1 + per, "an element block's count")?;
            let (tags, nodes) = (Vec::with_capacity(count), Vec::with_capacity(count * per));
            let mut block = ElementBlock { entity_dim, entity_tag, element_type, tags, nodes, per };
            for _ in 0..count {
                block.tags.push(self.size("an element tag")?);
                for _ in 0..per {
                    block.nodes.push(self.size("an element's node")?);
                }
            }
            blocks.push(block);
        }
        Ok(blocks)
    }

    /// Past `$End<name>` (a section this reader does not need).
    fn skip_section(&mut self, name: &str) -> Result<(), GmshError> {
        let end = format!("$End{name}");
        let rest = &self.bytes[self.at..];
        let found = rest.windows(end.len()).position(|w| w == end.as_bytes());
        let found = found.ok_or_else(|| self.error(format!("no {}", clip(&end))))?;
        self.at += found + end.len();
        Ok(())
    }

    /// `$End<name>` after a section's values.
    fn end_of_section(&mut self, name: &str) -> Result<(), GmshError> {
        self.skip_space();
        let end = self.line()?;
        if end.strip_prefix("$End") != Some(name) {
            return Err(self.error(format!("'{}' where $End{name} was expected", clip(end))));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One tetrahedron in volume "body" with a named face, in the file's text form; its second
    /// node block is parametric (u, v after x, y, z) and a section this reader does not need
    /// comes first.
    const TET: &str = "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n\
$Comments\nanything, even $Nodes\n$EndComments\n\
$PhysicalNames\n2\n2 7 \"base\"\n3 9 \"body\"\n$EndPhysicalNames\n\
$Entities\n0 0 1 1\n3 0 0 0 1 1 0 1 7 0\n5 0 0 0 1 1 1 1 9 1 3\n$EndEntities\n\
$Nodes\n2 4 1 4\n3 5 0 1\n4\n0 0 1\n2 3 1 3\n1\n2\n3\n0 0 0 0 0\n1 0 0 1 0\n0 1 0 0 1\n$EndNodes\n\
$Elements\n2 2 1 2\n2 3 2 1\n7 1 3 2\n3 5 4 1\n8 1 2 3 4\n$EndElements\n";

    #[test]
    fn a_volume_its_faces_and_parametric_nodes() {
        let v = Msh::parse(TET.as_bytes()).unwrap().volume("body").unwrap();
        assert!(!v.hexahedra);
        assert_eq!(v.nodes, vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
        assert_eq!(v.connectivity, vec![0, 1, 2, 3]);
        assert_eq!(v.surfaces, vec![("base".to_string(), vec![vec![0, 2, 1]])]);
    }

    #[test]
    fn bad_files_give_errors_that_name_the_place() {
        let parse = |text: &str| Msh::parse(text.as_bytes()).err().map(|e| e.to_string()).unwrap_or_default();
        // a count beyond what the rest of the file can hold is refused before it allocates
        let e = parse(&TET.replace("$Nodes\n2 4 1 4\n3 5 0 1\n", "$Nodes\n2 4 1 4\n3 5 0 99999999999999\n"));
        assert!(
            e.contains("$Nodes: a node block's count 99999999999999 is more than the rest of the file holds"),
            "{e}"
        );
        let e = parse(&TET.replace("3 5 4 1\n", "3 5 4 18446744073709551615\n"));
        assert!(e.contains("$Elements: an element block's count 18446744073709551615 is more"), "{e}");
        let e = parse(&TET.replace("4.1 0 8", "2.2 0 8"));
        assert!(e.starts_with("not a readable MSH 4.1 file: at byte"), "{e}");
        assert!(e.ends_with("$MeshFormat: version '2.2': only MSH 4.1 is read (Gmsh: -format msh41)"), "{e}");
        let e = parse(&TET.replace("3 5 4 1\n", "3 5 99 1\n"));
        assert!(e.ends_with("$Elements: element type 99 (this reader knows 1-31)"), "{e}");
        let e = parse(&TET.replace("3 5 4 1\n", "3 5 -2147483648 1\n"));
        assert!(e.ends_with("$Elements: element type -2147483648 (this reader knows 1-31)"), "{e}");
        let e = parse(&TET.replace("8 1 2 3 4\n$EndElements", "8 1 2 3\n$EndElements"));
        assert!(e.contains("$Elements: an element's node '$EndElements' is not a number"), "{e}");
        let e = parse(&TET.replace("$EndNodes", "$EndNode"));
        assert!(e.contains("'$EndNode' where $EndNodes was expected"), "{e}");
        let e = parse(&TET.replace("$Comments\n", "$Comments\n$EndComment\n").replace("$EndComments\n", ""));
        assert!(e.contains("$Comments: no $EndComments"), "{e}");
        let e = parse(&TET[..TET.find("$Nodes\n2").unwrap() + 10]);
        assert!(e.ends_with("$Nodes: the file ends before the smallest node tag"), "{e}");
        // the volume's element of a type the solver does not take, and a node that is missing
        let msh = Msh::parse(TET.replace("3 5 4 1\n8 1 2 3 4", "3 5 11 1\n8 1 2 3 4 1 2 3 4 1 2").as_bytes()).unwrap();
        let e = msh.volume("body").unwrap_err().to_string();
        assert!(e.starts_with("volume 'body': element type Tet10 (Gmsh type 11)"), "{e}");
        let msh = Msh::parse(TET.replace("8 1 2 3 4", "8 1 2 3 5").as_bytes()).unwrap();
        assert_eq!(
            msh.volume("body").unwrap_err().to_string(),
            "element 8 refers to node 5, which the file does not define"
        );
        let msh = Msh::parse(TET.replace("$Entities", "$Entitie").replace("$EndEntities", "$EndEntitie").as_bytes());
        assert_eq!(
            msh.unwrap().volume("body").unwrap_err().to_string(),
            "not a readable MSH 4.1 file: no $Entities section"
        );
    }

    /// The binary form of a file reads as its text form does (a binary file written here from
    /// the text's values, little-endian, 8-byte counts).
    #[test]
    fn binary_reads_as_text() {
        let mut b: Vec<u8> = b"$MeshFormat\n4.1 1 8\n".to_vec();
        b.extend(1i32.to_le_bytes());
        b.extend(b"\n$EndMeshFormat\n$PhysicalNames\n2\n2 7 \"base\"\n3 9 \"body\"\n$EndPhysicalNames\n$Entities\n");
        let size = |b: &mut Vec<u8>, v: u64| b.extend(v.to_le_bytes());
        let int = |b: &mut Vec<u8>, v: i32| b.extend(v.to_le_bytes());
        let real = |b: &mut Vec<u8>, v: f64| b.extend(v.to_le_bytes());
        for c in [0, 0, 1, 1] {
            size(&mut b, c);
        }
        for (tag, phys, bounds) in [(3, 7, vec![]), (5, 9, vec![3])] {
            int(&mut b, tag);
            (0..6).for_each(|_| real(&mut b, 0.0));
            size(&mut b, 1);
            int(&mut b, phys);
            size(&mut b, bounds.len() as u64);
            bounds.iter().for_each(|&t| int(&mut b, t));
        }
        b.extend(b"\n$EndEntities\n$Nodes\n");
        [1, 4, 1, 4].into_iter().for_each(|v| size(&mut b, v));
        [3, 5, 0].into_iter().for_each(|v| int(&mut b, v));
        size(&mut b, 4);
        (1..=4).for_each(|t| size(&mut b, t));
        for x in [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]] {
            x.into_iter().for_each(|v| real(&mut b, v));
        }
        b.extend(b"\n$EndNodes\n$Elements\n");
        [2, 2, 1, 2].into_iter().for_each(|v| size(&mut b, v));
        for (dim, entity, kind, element) in [(2, 3, 2, vec![7, 1, 3, 2]), (3, 5, 4, vec![8, 1, 2, 3, 4])] {
            [dim, entity, kind].into_iter().for_each(|v| int(&mut b, v));
            size(&mut b, 1);
            element.into_iter().for_each(|v| size(&mut b, v));
        }
        b.extend(b"\n$EndElements\n");
        let binary = Msh::parse(&b).unwrap().volume("body").unwrap();
        let text = Msh::parse(TET.as_bytes()).unwrap().volume("body").unwrap();
        assert_eq!(
            (binary.nodes, binary.connectivity, binary.surfaces),
            (text.nodes, text.connectivity, text.surfaces)
        );
        // a big-endian file's mark
        let mut big = b.clone();
        big[20..24].copy_from_slice(&1i32.to_be_bytes());
        let e = Msh::parse(&big).err().map(|e| e.to_string()).unwrap_or_default();
        assert!(e.ends_with("$MeshFormat: a big-endian file (only little-endian binary files are read)"), "{e}");
    }
}
