//! Stored interface solutions (`--save`, `--init`): the binary format of `docs/solution-format.md`.
//!
//! ```text
//! offset  size  content
//! 0       8     magic b"GLISSOL\0"
//! 8       4     format version, u32 little-endian (FORMAT_VERSION)
//! 12      8     header length H in bytes, u64 little-endian
//! 20      H     header: UTF-8 JSON object, padded with spaces so the arrays start at a multiple of 8
//! 20+H    ...   the arrays, f64 little-endian, in the order of `layout` (see below); nothing after
//! ```
//! Array order: for each stage (`static` if present, then `dynamic`), for each interface, the `s`
//! sides then the `hat` sides, and for each side its force array then its velocity array — every
//! array `len` values long (`len` per interface in the header's layout).

use std::fs::File;
use std::io::{BufReader, Read, Write};
use std::path::Path;

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::field::{InterfaceField, InterfaceSolution, SideField, StageSolution};
use crate::point::DesignPoint;
use crate::scene::Scene;

/// The first 8 bytes of every solution file.
pub const MAGIC: [u8; 8] = *b"GLISSOL\0";
/// The format version this code writes and reads.
pub const FORMAT_VERSION: u32 = 1;
/// Headers are small (a few hundred bytes per interface); a larger length means a damaged file.
const MAX_HEADER_BYTES: u64 = 64 << 20;
/// magic + version + header length
const PREAMBLE_BYTES: usize = 8 + 4 + 8;

/// Errors of reading or writing a solution file.
#[derive(Debug, thiserror::Error)]
pub enum SolutionFileError {
    #[error("not a glissade solution file (bad magic bytes)")]
    BadMagic,
    #[error("solution file format version {found} is not supported (this build reads {supported})")]
    UnsupportedVersion { found: u32, supported: u32 },
    #[error("solution file is truncated: {0}")]
    Truncated(String),
    #[error("solution file has {0} unexpected bytes after its last array")]
    TrailingBytes(u64),
    #[error("solution file header: {0}")]
    Header(String),
    #[error("solution file is corrupt: the arrays' SHA-256 does not match the header's")]
    Checksum,
    #[error("solution does not fit its layout: {0}")]
    Layout(String),
    #[error(transparent)]
    Io(#[from] std::io::Error),
}

/// What a stored solution was computed for and how the computation ended.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SolutionMeta {
    /// `CARGO_PKG_VERSION` of the solver that wrote the file
    pub solver_version: String,
    /// [`Scene::content_hash`] of the scene solved
    pub scene_hash: String,
    pub dimension: usize,
    pub time_steps: usize,
    /// the design point
    pub parameters: DesignPoint,
    /// false when the iteration limit was hit: the file then holds the last iterate
    pub converged: bool,
    /// final error indicator of the dynamic stage
    pub error_indicator: f64,
    /// total LATIN iterations (static + dynamic)
    pub iterations: usize,
    pub tolerance: f64,
    /// every QoI's final value, as the solve reported it (what a completion's header must
    /// repeat; empty in files written before 0.2.0)
    #[serde(default)]
    pub qoi: std::collections::BTreeMap<String, f64>,
}

/// Why a stored solution cannot warm-start a solve of a scene.
#[derive(Debug, thiserror::Error)]
pub enum InitMismatch {
    #[error("the solution is of dimension {found}, this scene of dimension {expected}")]
    Dimension { found: usize, expected: usize },
    #[error("the solution has {found} time steps, this scene {expected}")]
    TimeSteps { found: usize, expected: usize },
    #[error(
        "the solution was computed for scene hash {found}, this scene is {expected} (a warm start needs the same scene; only parameter values and [solver] settings may differ)"
    )]
    SceneHash { found: String, expected: String },
}

impl SolutionMeta {
    /// Checks that a solution of this metadata may initialise a solve of `scene`.
    pub fn check_fits(&self, scene: &Scene) -> Result<(), InitMismatch> {
        if self.dimension != scene.dimension {
            return Err(InitMismatch::Dimension { found: self.dimension, expected: scene.dimension });
        }
        if self.time_steps != scene.time.steps {
            return Err(InitMismatch::TimeSteps { found: self.time_steps, expected: scene.time.steps });
        }
        let expected = scene.content_hash();
        if self.scene_hash != expected {
            return Err(InitMismatch::SceneHash { found: self.scene_hash.clone(), expected });
        }
        Ok(())
    }
}

/// Sizes of one interface's arrays in one stage.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct InterfaceLayout {
    /// 1 (boundary or wall interface) or 2
    pub sides: usize,
    /// values per array: steps * interface nodes * dimension (1 step in the static stage)
    pub len: usize,
}

/// Sizes of every array, in file order.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Layout {
    #[serde(rename = "static")]
    pub static_stage: Option<Vec<InterfaceLayout>>,
    pub dynamic: Vec<InterfaceLayout>,
}

/// The JSON header: format version, metadata, layout, and a checksum of the arrays.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct Header {
    format_version: u32,
    #[serde(flatten)]
    meta: SolutionMeta,
    layout: Layout,
    /// hex SHA-256 of the array bytes as stored
    arrays_sha256: String,
}

impl Layout {
    fn of(solution: &InterfaceSolution) -> Result<Self, SolutionFileError> {
        let stage = |st: &StageSolution, name: &str| -> Result<Vec<InterfaceLayout>, _> {
            st.interfaces
                .iter()
                .enumerate()
                .map(|(i, f)| {
                    let sides = f.s.len();
                    let len = f.s.first().map_or(0, |s| s.force.len());
                    let consistent = sides > 0
                        && f.hat.len() == sides
                        && f.s.iter().chain(&f.hat).all(|sf| sf.force.len() == len && sf.velocity.len() == len);
                    if consistent {
                        Ok(InterfaceLayout { sides, len })
                    } else {
                        Err(SolutionFileError::Layout(format!(
                            "{name} stage, interface {i}: sides or array lengths differ"
                        )))
                    }
                })
                .collect()
        };
        Ok(Self {
            static_stage: solution.static_stage.as_ref().map(|s| stage(s, "static")).transpose()?,
            dynamic: stage(&solution.dynamic, "dynamic")?,
        })
    }

    fn stages(&self) -> impl Iterator<Item = &Vec<InterfaceLayout>> {
        self.static_stage.iter().chain(std::iter::once(&self.dynamic))
    }

    /// Total number of f64 values, or None on overflow.
    fn values(&self) -> Option<u64> {
        let mut total: u64 = 0;
        for itf in self.stages().flatten() {
            // 2 (s, hat) x sides x 2 (force, velocity) arrays
            let n = (itf.sides as u64).checked_mul(4)?.checked_mul(itf.len as u64)?;
            total = total.checked_add(n)?;
        }
        Some(total)
    }

    fn check(&self, meta: &SolutionMeta) -> Result<(), SolutionFileError> {
        let d = meta.dimension;
        if !(1..=3).contains(&d) {
            return Err(SolutionFileError::Header(format!("dimension {d} is not 1, 2 or 3")));
        }
        let check_stage = |st: &[InterfaceLayout], name: &str, steps: usize| {
            for (i, itf) in st.iter().enumerate() {
                if !(1..=2).contains(&itf.sides) {
                    return Err(SolutionFileError::Header(format!("{name} stage, interface {i}: {} sides", itf.sides)));
                }
                let per_node = steps.checked_mul(d).filter(|&n| n > 0);
                if !per_node.is_some_and(|n| itf.len.is_multiple_of(n)) {
                    return Err(SolutionFileError::Header(format!(
                        "{name} stage, interface {i}: array length {} is not a multiple of steps ({steps}) x dimension ({d})",
                        itf.len
                    )));
                }
            }
            Ok(())
        };
        if let Some(st) = &self.static_stage {
            check_stage(st, "static", 1)?;
            if st.len() != self.dynamic.len() {
                return Err(SolutionFileError::Header(format!(
                    "{} static interfaces but {} dynamic ones",
                    st.len(),
                    self.dynamic.len()
                )));
            }
        }
        check_stage(&self.dynamic, "dynamic", meta.time_steps)?;
        self.values().map(|_| ()).ok_or_else(|| SolutionFileError::Header("array sizes overflow a 64-bit count".into()))
    }
}

/// Every array of the solution in file order.
fn arrays(solution: &InterfaceSolution) -> impl Iterator<Item = &[f64]> {
    solution
        .static_stage
        .iter()
        .chain(std::iter::once(&solution.dynamic))
        .flat_map(|st| &st.interfaces)
        .flat_map(|f| f.s.iter().chain(&f.hat))
        .flat_map(|side| [side.force.as_slice(), side.velocity.as_slice()])
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Writes `solution` with `meta` to `w` (see the module documentation for the layout).
pub fn write_to<W: Write>(
    mut w: W,
    solution: &InterfaceSolution,
    meta: &SolutionMeta,
) -> Result<(), SolutionFileError> {
    let layout = Layout::of(solution)?;
    // JSON has no NaN or infinity: such a header would write but not read back (a design
    // point's values are finite by construction)
    if !(meta.error_indicator.is_finite() && meta.tolerance.is_finite()) {
        return Err(SolutionFileError::Header("error indicator and tolerance must be finite numbers".into()));
    }
    let mut hasher = Sha256::new();
    for a in arrays(solution) {
        for v in a {
            hasher.update(v.to_le_bytes());
        }
    }
    let header =
        Header { format_version: FORMAT_VERSION, meta: meta.clone(), layout, arrays_sha256: hex(&hasher.finalize()) };
    let mut json = serde_json::to_vec(&header).map_err(|e| SolutionFileError::Header(e.to_string()))?;
    while !(PREAMBLE_BYTES + json.len()).is_multiple_of(8) {
        json.push(b' ');
    }
    w.write_all(&MAGIC)?;
    w.write_all(&FORMAT_VERSION.to_le_bytes())?;
    w.write_all(&(json.len() as u64).to_le_bytes())?;
    w.write_all(&json)?;
    for a in arrays(solution) {
        for v in a {
            w.write_all(&v.to_le_bytes())?;
        }
    }
    w.flush()?;
    Ok(())
}

/// Writes a solution file atomically (temporary file in the same directory, then rename).
pub fn write(path: &Path, solution: &InterfaceSolution, meta: &SolutionMeta) -> Result<(), SolutionFileError> {
    super::write_atomically(path, |w| write_to(w, solution, meta))
}

/// Reads exactly `buf.len()` bytes, or says what was being read when the data ended.
fn read_exact_or_truncated<R: Read>(r: &mut R, buf: &mut [u8], what: &str) -> Result<(), SolutionFileError> {
    r.read_exact(buf).map_err(|e| match e.kind() {
        std::io::ErrorKind::UnexpectedEof => SolutionFileError::Truncated(format!("the file ends inside the {what}")),
        _ => SolutionFileError::Io(e),
    })
}

/// Reads a solution file from `r`, checking magic, version, header, sizes and checksum.
pub fn read_from<R: Read>(mut r: R) -> Result<(SolutionMeta, InterfaceSolution), SolutionFileError> {
    // magic: a short file whose bytes start like the magic is truncated, anything else is foreign
    let mut magic = Vec::with_capacity(MAGIC.len());
    (&mut r).take(MAGIC.len() as u64).read_to_end(&mut magic)?;
    if magic[..] != MAGIC[..magic.len()] {
        return Err(SolutionFileError::BadMagic);
    }
    if magic.len() < MAGIC.len() {
        return Err(SolutionFileError::Truncated("the file ends inside the magic bytes".into()));
    }
    let mut word = [0u8; 4];
    read_exact_or_truncated(&mut r, &mut word, "format version")?;
    let version = u32::from_le_bytes(word);
    if version != FORMAT_VERSION {
        return Err(SolutionFileError::UnsupportedVersion { found: version, supported: FORMAT_VERSION });
    }
    let mut dword = [0u8; 8];
    read_exact_or_truncated(&mut r, &mut dword, "header length")?;
    let header_len = u64::from_le_bytes(dword);
    if header_len > MAX_HEADER_BYTES {
        return Err(SolutionFileError::Header(format!("length {header_len} bytes is implausible (damaged file?)")));
    }
    let mut json = vec![0u8; header_len as usize];
    read_exact_or_truncated(&mut r, &mut json, "header")?;
    let header: Header = serde_json::from_slice(&json).map_err(|e| SolutionFileError::Header(e.to_string()))?;
    if header.format_version != version {
        return Err(SolutionFileError::Header(format!(
            "format_version {} differs from the preamble's {version}",
            header.format_version
        )));
    }
    header.layout.check(&header.meta)?;
    let values = header.layout.values().unwrap_or(u64::MAX);
    let bytes_expected = values
        .checked_mul(8)
        .ok_or_else(|| SolutionFileError::Header("array sizes overflow a 64-bit byte count".into()))?;
    // `take` + `read_to_end` grows the buffer with the data actually present, so a damaged
    // header cannot make us allocate more than the file holds.
    let mut data = Vec::new();
    (&mut r).take(bytes_expected).read_to_end(&mut data)?;
    if (data.len() as u64) < bytes_expected {
        return Err(SolutionFileError::Truncated(format!(
            "the arrays need {bytes_expected} bytes, the file holds {}",
            data.len()
        )));
    }
    let trailing = std::io::copy(&mut r, &mut std::io::sink())?;
    if trailing > 0 {
        return Err(SolutionFileError::TrailingBytes(trailing));
    }
    if hex(&Sha256::digest(&data)) != header.arrays_sha256 {
        return Err(SolutionFileError::Checksum);
    }
    let mut chunks = data.chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().expect("chunks of 8 bytes")));
    let mut take = |len: usize| -> Vec<f64> { chunks.by_ref().take(len).collect() };
    let mut stage = |layout: &[InterfaceLayout]| StageSolution {
        interfaces: layout
            .iter()
            .map(|itf| {
                let mut side = || SideField { force: take(itf.len), velocity: take(itf.len) };
                let s = (0..itf.sides).map(|_| side()).collect();
                let hat = (0..itf.sides).map(|_| side()).collect();
                InterfaceField { s, hat }
            })
            .collect(),
    };
    let static_stage = header.layout.static_stage.as_deref().map(&mut stage);
    let dynamic = stage(&header.layout.dynamic);
    Ok((header.meta, InterfaceSolution { static_stage, dynamic }))
}

/// Reads a solution file.
pub fn read(path: &Path) -> Result<(SolutionMeta, InterfaceSolution), SolutionFileError> {
    read_from(BufReader::new(File::open(path)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Values that a lossy path (text, f32) or a byte-order slip would change.
    fn sample() -> (SolutionMeta, InterfaceSolution) {
        let mut x = 0.0_f64;
        let mut next = |len: usize| -> Vec<f64> {
            (0..len)
                .map(|_| {
                    x += 1.0;
                    (x / 3.0).exp() * if (x as u64).is_multiple_of(2) { -1.0 } else { 1.0 }
                })
                .collect()
        };
        let mut field = |sides: usize, len: usize| InterfaceField {
            s: (0..sides).map(|_| SideField { force: next(len), velocity: next(len) }).collect(),
            hat: (0..sides).map(|_| SideField { force: next(len), velocity: next(len) }).collect(),
        };
        let (d, steps) = (2, 5);
        let solution = InterfaceSolution {
            static_stage: Some(StageSolution { interfaces: vec![field(2, 3 * d), field(1, 2 * d)] }),
            dynamic: StageSolution { interfaces: vec![field(2, steps * 3 * d), field(1, steps * 2 * d)] },
        };
        let meta = SolutionMeta {
            solver_version: env!("CARGO_PKG_VERSION").into(),
            scene_hash: "ab".repeat(32),
            dimension: d,
            time_steps: steps,
            parameters: DesignPoint::from_pairs([("f1", 0.3), ("v0", 1.0 / 7.0)]).unwrap(),
            converged: false,
            error_indicator: 3.3e-3,
            iterations: 17,
            tolerance: 2e-4,
            qoi: Default::default(),
        };
        (meta, solution)
    }

    fn bits(s: &InterfaceSolution) -> Vec<u64> {
        arrays(s).flatten().map(|v| v.to_bits()).collect()
    }

    #[test]
    fn round_trip_is_bitwise_exact() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.bin");
        let (meta, solution) = sample();
        write(&path, &solution, &meta).unwrap();
        let (meta2, solution2) = read(&path).unwrap();
        assert_eq!(meta2, meta);
        assert_eq!(bits(&solution2), bits(&solution));
        assert_eq!(solution2, solution);
        // nothing but the file itself is left in the directory
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);

        // the documented layout: preamble, padded header, then the arrays in order
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(&bytes[..8], b"GLISSOL\0");
        assert_eq!(u32::from_le_bytes(bytes[8..12].try_into().unwrap()), 1);
        let h = u64::from_le_bytes(bytes[12..20].try_into().unwrap()) as usize;
        assert_eq!((20 + h) % 8, 0);
        let first = solution.static_stage.as_ref().unwrap().interfaces[0].s[0].force[0];
        assert_eq!(f64::from_le_bytes(bytes[20 + h..28 + h].try_into().unwrap()).to_bits(), first.to_bits());
        let n_values: usize = arrays(&solution).map(|a| a.len()).sum();
        assert_eq!(bytes.len(), 20 + h + 8 * n_values);
        let header: serde_json::Value = serde_json::from_slice(&bytes[20..20 + h]).unwrap();
        assert_eq!(header["layout"]["dynamic"][0]["sides"], 2);
        assert_eq!(header["layout"]["dynamic"][1]["len"], 20);
        assert_eq!(header["scene_hash"], "ab".repeat(32));
    }

    #[test]
    fn round_trip_without_static_stage() {
        let (meta, mut solution) = sample();
        solution.static_stage = None;
        let mut buf = Vec::new();
        write_to(&mut buf, &solution, &meta).unwrap();
        let (_, back) = read_from(&buf[..]).unwrap();
        assert_eq!(back, solution);
    }

    #[test]
    fn truncated_damaged_and_foreign_files_are_refused() {
        let (meta, solution) = sample();
        let mut buf = Vec::new();
        write_to(&mut buf, &solution, &meta).unwrap();
        let h = u64::from_le_bytes(buf[12..20].try_into().unwrap()) as usize;
        for cut in [3, 8, 10, 15, 20, 20 + h / 2, 20 + h, 20 + h + 12, buf.len() - 1] {
            let err = read_from(&buf[..cut]).unwrap_err();
            assert!(matches!(err, SolutionFileError::Truncated(_)), "cut at {cut}: {err}");
        }
        let mut longer = buf.clone();
        longer.extend_from_slice(&[0; 5]);
        assert!(matches!(read_from(&longer[..]).unwrap_err(), SolutionFileError::TrailingBytes(5)));
        let mut flipped = buf.clone();
        let last = flipped.len() - 1;
        flipped[last] ^= 1;
        assert!(matches!(read_from(&flipped[..]).unwrap_err(), SolutionFileError::Checksum));
        let mut future = buf.clone();
        future[8..12].copy_from_slice(&2u32.to_le_bytes());
        assert!(matches!(
            read_from(&future[..]).unwrap_err(),
            SolutionFileError::UnsupportedVersion { found: 2, supported: 1 }
        ));
        assert!(matches!(read_from(&b"dimension = 1\n"[..]).unwrap_err(), SolutionFileError::BadMagic));
        assert!(matches!(read_from(&b""[..]).unwrap_err(), SolutionFileError::Truncated(_)));
        let mut bad_json = buf.clone();
        bad_json[20] = b'[';
        assert!(matches!(read_from(&bad_json[..]).unwrap_err(), SolutionFileError::Header(_)));
    }

    #[test]
    fn inconsistent_solution_is_not_written() {
        let (meta, mut solution) = sample();
        solution.dynamic.interfaces[1].hat[0].velocity.pop();
        let err = write_to(Vec::new(), &solution, &meta).unwrap_err();
        assert!(matches!(err, SolutionFileError::Layout(_)), "{err}");
    }
}
