//! Scene files (TOML): what a user declares, parsed and validated. See `docs/scenes.md`.
//!
//! Any number may instead be the name of a declared parameter; [`Model::build`](crate::model::Model::build) substitutes the
//! design point's values and checks every physical constraint, naming the offending key.

use crate::point::{DesignPoint, MAX_PARAMETERS};
use crate::text::{MAX_NAME_CHARS, excerpt, is_plain_name, is_plain_text, one_line};
use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// Errors of scene parsing and validation; each names the offending key.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error("cannot parse scene: {0}")]
    Parse(String),
    #[error("{key}: {message}")]
    Invalid { key: String, message: String },
    #[error("{key}: parameter '{name}' is used but not declared in [parameters]")]
    UndeclaredParameter { key: String, name: String },
    #[error("--set {name}: no parameter of that name in the scene (declared: {declared})")]
    UnknownParameter { name: String, declared: String },
}

/// A TOML error in one line, its position first ("line 3, column 7: ..."): toml's own rendering
/// spans several lines with the offending source quoted, which a log or an RPC status garbles.
fn toml_error_line(e: &toml::de::Error, text: &str) -> String {
    let at = e.span().map(|span| {
        // (a span that does not fall on a character's start is taken back to one: no panic)
        let end = (0..=span.start.min(text.len())).rev().find(|&i| text.is_char_boundary(i)).unwrap_or(0);
        let before = &text[..end];
        let line = before.matches('\n').count() + 1;
        let column = before[before.rfind('\n').map_or(0, |i| i + 1)..].chars().count() + 1;
        format!("line {line}, column {column}: ")
    });
    format!("{}{}", at.unwrap_or_default(), one_line(e.message()))
}

pub fn invalid(key: impl Into<String>, message: impl Into<String>) -> SceneError {
    SceneError::Invalid { key: key.into(), message: message.into() }
}

/// The tightest tolerance accepted. eta is relative and computed in double precision: a
/// tighter one is never reached, and a solve asked for it would hold its pool until the
/// iteration limit (README, Service: limits).
pub const MIN_TOLERANCE: f64 = 1e-10;
/// The loosest: eta is relative, and 1 is no accuracy at all.
pub const MAX_TOLERANCE: f64 = 1.0;
/// The most LATIN iterations a stage of a solve may be given (the shipped scenes converge in at
/// most a few thousand).
pub const MAX_ITERATIONS: usize = 100_000;

/// The one rule for an error-indicator tolerance, wherever it comes from (a scene's
/// `solver.tolerance`, `--tol`, a submission): a number in [[`MIN_TOLERANCE`],
/// [`MAX_TOLERANCE`]]. `key` names the source.
pub fn check_tolerance(key: &str, tolerance: f64) -> Result<f64, SceneError> {
    if (MIN_TOLERANCE..=MAX_TOLERANCE).contains(&tolerance) {
        Ok(tolerance)
    } else {
        Err(invalid(key, format!("must be a number from {MIN_TOLERANCE:e} to {MAX_TOLERANCE}, got {tolerance:e}")))
    }
}

/// An error-indicator tolerance that passed [`check_tolerance`]: checked once, where it enters
/// (a submission, `--tol`, a stored study), and trusted from then on.
#[derive(Debug, Clone, Copy, PartialEq, PartialOrd)]
pub struct Tolerance(f64);

impl Tolerance {
    /// `tolerance` if [`check_tolerance`] accepts it; `key` names where it came from.
    pub fn new(key: &str, tolerance: f64) -> Result<Self, SceneError> {
        check_tolerance(key, tolerance).map(Self)
    }

    /// `asked`, or else the scene's own (checked as the scene parsed).
    pub fn or_scene(asked: Option<Tolerance>, scene: &Scene) -> f64 {
        asked.map_or(scene.solver.tolerance, Tolerance::get)
    }

    pub fn get(self) -> f64 {
        self.0
    }
}

/// The one rule for an iteration limit (a scene's `solver.max_iterations`, `--max-iter`, a
/// submission): 1 to [`MAX_ITERATIONS`].
pub fn check_max_iterations(key: &str, n: u64) -> Result<usize, SceneError> {
    match usize::try_from(n) {
        Ok(n) if (1..=MAX_ITERATIONS).contains(&n) => Ok(n),
        _ => Err(invalid(key, format!("must be from 1 to {MAX_ITERATIONS}, got {n}"))),
    }
}

/// A number, or the name of a parameter standing for one.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Scalar {
    Number(f64),
    Parameter(String),
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParameterSpec {
    pub default: f64,
    pub min: Option<f64>,
    pub max: Option<f64>,
    pub unit: Option<String>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimeSpec {
    pub duration: Scalar,
    pub steps: usize,
    /// the mass matrix of the elements (docs/scenes.md, `[time]`)
    #[serde(default)]
    pub mass: MassMatrix,
    /// Newmark's gamma (docs/scenes.md, `[time]`): absent or 1/2, the trapezoidal rule; above,
    /// a scheme that damps the highest frequencies. Left out of the serialised form when absent,
    /// so that the scene hash stays what it was before the option.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub newmark_gamma: Option<f64>,
}

/// How the elements' mass is discretised.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum MassMatrix {
    /// the integral of the shape functions' products: exact kinetic energy of the element
    #[default]
    Consistent,
    /// each row's sum on the diagonal: every node an independent mass, so that a node that hits
    /// a wall stops alone (docs/verification.md 4d)
    Lumped,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
#[allow(non_snake_case)]
pub struct MaterialSpec {
    pub E: Scalar,
    #[serde(default = "zero")]
    pub nu: Scalar,
    pub rho: Scalar,
}

fn zero() -> Scalar {
    Scalar::Number(0.0)
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BodySpec {
    pub name: String,
    pub material: String,
    #[serde(default)]
    pub origin: Option<Vec<Scalar>>,
    /// a box: its extents and element counts (exactly one of a box or `mesh`)
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub size: Option<Vec<Scalar>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub elements: Option<Vec<usize>>,
    /// a volume of a Gmsh mesh file
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh: Option<MeshSpec>,
    #[serde(default)]
    pub substructures: Option<Substructures>,
    #[serde(default)]
    pub initial_velocity: Option<Vec<Scalar>>,
}

/// A body meshed by Gmsh: a physical volume of an MSH 4.1 file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshSpec {
    /// path of the `.msh` file, relative to the scene file
    pub file: String,
    /// name of the physical volume (Gmsh `Physical Volume("name")`)
    pub volume: String,
}

/// How a body is cut into substructures: blocks per axis (boxes) or a count of graph parts
/// (mesh bodies).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Substructures {
    PerAxis(Vec<usize>),
    Count(usize),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LawSpec {
    Perfect,
    Contact,
    Friction,
    /// glued with a prescribed normal shortening (a bolt's prestress)
    Prestress,
}

/// Where a parameter changes only an interface law (no operator): [`Scene::interface_law_parameters`].
const LAW_ONLY_PATHS: [&str; 3] =
    ["interfaces.[].friction", "interfaces.[].prakash_clifton.length", "interfaces.[].prakash_clifton.velocity"];

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InterfaceSpec {
    pub name: String,
    /// `body.face` of side 1 (the interface normal points out of it)
    pub a: String,
    /// `body.face` of side 2, or `wall` for a fixed rigid obstacle
    pub b: String,
    pub law: LawSpec,
    pub friction: Option<Scalar>,
    /// initial normal gap to a wall (m)
    pub gap: Option<Scalar>,
    /// normal shortening of law `prestress` (m): n.(u_b - u_a) = -prestress, reached in the
    /// static stage and held in the dynamics (absent from the hash when absent)
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub prestress: Option<Scalar>,
    /// law `friction` only: the friction follows the normal force with a lag (the Prakash-Clifton
    /// regularisation, docs/method.md 3, "Local stage") instead of at once (absent from the hash when absent)
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub prakash_clifton: Option<PrakashCliftonSpec>,
}

/// The Prakash-Clifton law's two numbers: the friction strength relaxes towards f times the
/// normal force at the rate (|slip rate| + `velocity`) / `length`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PrakashCliftonSpec {
    /// slip over which the strength follows a change of the normal force (m)
    pub length: Scalar,
    /// reference velocity (m/s): at rest the lag is `length / velocity`
    pub velocity: Scalar,
}

/// Piecewise-linear factor `[[t, value], ...]`, constant beyond its ends.
pub type HistorySpec = Vec<[Scalar; 2]>;

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoundarySpec {
    pub face: String,
    #[serde(default)]
    pub clamped: bool,
    /// components reached in the static prestress stage and held during the dynamics
    pub displacement: Option<BTreeMap<String, Scalar>>,
    /// prescribed velocity components during the dynamics (times `history`)
    pub velocity: Option<BTreeMap<String, Scalar>>,
    pub history: Option<HistorySpec>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoadSpec {
    pub face: String,
    /// pressure (positive pushes into the body)
    pub pressure: Option<Scalar>,
    /// traction vector
    pub traction: Option<Vec<Scalar>>,
    pub history: Option<HistorySpec>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum QoiKind {
    /// relative tangential displacement at an interface point: its norm, or with `component`
    /// its signed component along an axis
    Slip,
    /// displacement component of a body point
    Displacement,
    /// velocity component of a body point
    Velocity,
    /// resultant force component on side 1 of an interface
    Force,
}

impl QoiKind {
    /// The SI unit of the value, by the scene's dimension (docs/scenes.md, Conventions: forces
    /// are per unit cross-section in 1D, per metre of thickness in 2D).
    pub fn unit(self, dimension: usize) -> &'static str {
        match (self, dimension) {
            (QoiKind::Slip | QoiKind::Displacement, _) => "m",
            (QoiKind::Velocity, _) => "m/s",
            (QoiKind::Force, 1) => "Pa",
            (QoiKind::Force, 2) => "N/m",
            (QoiKind::Force, _) => "N",
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QoiSpec {
    pub name: String,
    pub kind: QoiKind,
    pub interface: Option<String>,
    pub body: Option<String>,
    pub point: Option<Vec<Scalar>>,
    pub component: Option<String>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Scale {
    #[default]
    Single,
    Multi,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SolverSpec {
    #[serde(default = "default_tolerance")]
    pub tolerance: f64,
    #[serde(default = "default_max_iterations")]
    pub max_iterations: usize,
    /// multiplies the default search direction k0 = sqrt(rho E) of each side
    #[serde(default = "one")]
    pub k0_factor: Scalar,
    /// tangential / normal search direction on contact and friction interfaces
    #[serde(default = "default_tangential_factor")]
    pub tangential_factor: f64,
    #[serde(default = "default_relaxation")]
    pub relaxation: f64,
    /// absent: chosen ([`Scene::scale`]); left out of the serialised form when absent (the
    /// hash writes the old default, see [`Scene::content_hash`])
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scale: Option<Scale>,
    /// a warm-started solve stops at `tolerance` times this (see docs/scenes.md)
    #[serde(default = "default_warm_tolerance_ratio")]
    pub warm_tolerance_ratio: f64,
    /// steps per time window of the dynamic stage; 0: the whole interval at once; absent:
    /// chosen from the scene ([`Scene::window_steps`], docs/method.md "Time windows"). Left out of the serialised form when absent, so that the scene hash
    /// (which serialises the default solver section) stays what it was before time windows.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time_window: Option<usize>,
    /// a solve in time windows is iterated again in other windows and the two answers compared
    /// (docs/method.md, "Two windowings"); absent: true. Left out of the serialised form when
    /// absent, as `time_window`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub window_check: Option<bool>,
    /// a whole-interval solve iterates on to a tenth of its tolerance and compares the two
    /// answers (docs/method.md, "Two tolerances"); absent: false. Left out of the serialised
    /// form when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub whole_interval_check: Option<bool>,
    /// a node where substructures of a body meet a wall interface follows the law on its total
    /// force, one velocity for all its copies (docs/method.md 3, "Local stage"); absent: true in
    /// 3D, false in 1D and 2D (docs/performance.md, "Nodes two substructures share on a wall").
    /// Left out of the serialised form when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub joint_wall_nodes: Option<bool>,
}

/// Without `time_window`, a scene with a contact or friction interface and more than this many
/// steps is iterated in windows of [`AUTO_TIME_WINDOW`] steps, any other whole (docs/method.md,
/// "Time windows"): a sliding history, or an impact's front, settles a fraction of a step per
/// whole-interval iteration, so those iterations grow with the steps while a window's do not (a
/// bar's impact: 198 sweeps whole and 22.0 in windows of one step at 400 steps, not converged
/// whole at 1600; of windows of 1, 2, 4 and 10 steps, one took the fewest sweeps on every impact
/// and sliding block measured but 8 of issue 30's 34 cases, and the fewest on those 34 together);
/// on perfect interfaces alone the whole interval's do not grow (a pulled bar: 71 iterations at
/// 1600 and 6400 steps) and short windows cost more; up to 100 steps the whole interval keeps the
/// paper's way and its figures.
pub const AUTO_WINDOW_ABOVE_STEPS: usize = 100;
pub const AUTO_TIME_WINDOW: usize = 1;
/// Without `solver.scale`, a scene with a body cut into more substructures than this is solved
/// multiscale ([`Scene::scale`]).
pub const MULTISCALE_ABOVE_SUBSTRUCTURES: usize = 2;

fn default_tolerance() -> f64 {
    2e-4
}
fn default_max_iterations() -> usize {
    1000
}
fn default_tangential_factor() -> f64 {
    TANGENTIAL_FACTOR
}
/// The default [`SolverSpec::tangential_factor`] (measured in docs/performance.md, "Search
/// direction").
pub const TANGENTIAL_FACTOR: f64 = 2.0;
fn default_relaxation() -> f64 {
    0.8
}
fn default_warm_tolerance_ratio() -> f64 {
    1.0
}
fn one() -> Scalar {
    Scalar::Number(1.0)
}

impl Default for SolverSpec {
    fn default() -> Self {
        Self {
            tolerance: default_tolerance(),
            max_iterations: default_max_iterations(),
            k0_factor: one(),
            tangential_factor: default_tangential_factor(),
            relaxation: default_relaxation(),
            scale: None,
            warm_tolerance_ratio: default_warm_tolerance_ratio(),
            time_window: None,
            window_check: None,
            whole_interval_check: None,
            joint_wall_nodes: None,
        }
    }
}

/// The size of a scene's problem, estimated from its text ([`Scene::size`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SceneSize {
    /// degrees of freedom of all substructures (nodes on cuts counted once per side)
    pub dofs: u64,
    /// nodes on interfaces, counting each side
    pub interface_nodes: u64,
    pub steps: u64,
    pub dimension: u64,
}

impl SceneSize {
    /// Bytes per degree of freedom: operators and their factors, measured at 6-8 kB on 3D boxes
    /// of 375-2187-dof substructures (docs/performance.md, "Memory per design point, and of one solve").
    pub const BYTES_PER_DOF: u64 = 10_000;
    /// Bytes per interface node, step and dimension: F and W of both stages' copies.
    pub const BYTES_PER_INTERFACE_VALUE: u64 = 100;

    /// Estimated peak memory of one solve (an upper bound for the scenes measured).
    pub fn bytes(&self) -> u64 {
        self.dofs.saturating_mul(Self::BYTES_PER_DOF).saturating_add(
            self.interface_nodes
                .saturating_mul(self.steps)
                .saturating_mul(self.dimension)
                .saturating_mul(Self::BYTES_PER_INTERFACE_VALUE),
        )
    }
}

/// A parsed scene file.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    pub dimension: usize,
    pub title: Option<String>,
    pub time: TimeSpec,
    #[serde(default)]
    pub parameters: BTreeMap<String, ParameterSpec>,
    pub materials: BTreeMap<String, MaterialSpec>,
    pub bodies: Vec<BodySpec>,
    #[serde(default)]
    pub interfaces: Vec<InterfaceSpec>,
    #[serde(default)]
    pub boundary: Vec<BoundarySpec>,
    #[serde(default)]
    pub loads: Vec<LoadSpec>,
    #[serde(default)]
    pub qoi: Vec<QoiSpec>,
    #[serde(default)]
    pub solver: SolverSpec,
    /// The mesh files' bytes by their `file` in the scene ([`Scene::attach_mesh_bytes`]): read
    /// next to the scene file by [`Scene::read`], or carried by a submission; a scene without
    /// them (text alone) cannot build its mesh bodies
    #[serde(skip)]
    pub meshes: BTreeMap<String, std::sync::Arc<[u8]>>,
    /// SHA-256 (hex) of each mesh file by its `file` in the scene: the content hash covers the
    /// meshes, not only their names
    #[serde(skip)]
    pub mesh_digests: BTreeMap<String, String>,
}

/// The largest mesh file read (bytes): parsed, a mesh takes a few times its file, so this keeps
/// a hostile or mistaken file well under a gigabyte; 128 MiB of binary MSH is ~2 M tetrahedra.
pub const MAX_MESH_FILE_BYTES: u64 = 128 << 20;
/// The most mesh files a scene may name.
pub const MAX_MESH_FILES: usize = 16;
/// The most bytes of mesh files a scene may have in all: one file's bound, so that a
/// submission carrying them is bounded by it too.
pub const MAX_MESH_BYTES: u64 = MAX_MESH_FILE_BYTES;

/// Errors of a scene's mesh files: what a submission or a pool is told.
#[derive(Debug, thiserror::Error)]
pub enum MeshFileError {
    #[error("mesh file '{0}' is named by the scene but was not given")]
    Missing(String),
    #[error("mesh file '{0}' was given but the scene names no such file")]
    Unexpected(String),
    #[error("mesh file '{0}' was given twice")]
    Duplicate(String),
    #[error("mesh file '{file}': {bytes} bytes, more than the {MAX_MESH_FILE_BYTES} allowed")]
    TooLarge { file: String, bytes: u64 },
    #[error("mesh files: {bytes} bytes in all, more than the {MAX_MESH_BYTES} allowed")]
    TotalTooLarge { bytes: u64 },
    #[error("{count} mesh files, more than the {MAX_MESH_FILES} allowed")]
    TooMany { count: usize },
    #[error("mesh file '{file}': its bytes have SHA-256 {actual}, {expected} was announced")]
    DigestMismatch { file: String, expected: String, actual: String },
}

/// Hex SHA-256 of a mesh file: its name in the scene hash and in a coordinator's store.
pub fn mesh_digest(bytes: &[u8]) -> String {
    use sha2::{Digest, Sha256};
    Sha256::digest(bytes).iter().map(|b| format!("{b:02x}")).collect()
}

/// Why a mesh file could not be read ([`read_mesh_file`]).
#[derive(Debug, thiserror::Error)]
pub enum MeshReadError {
    #[error("cannot open {path}: {source}")]
    Open { path: std::path::PathBuf, source: std::io::Error },
    #[error("cannot read {path}: {source}")]
    Read { path: std::path::PathBuf, source: std::io::Error },
    #[error("{path} is {len} bytes, more than the {max} allowed", max = MAX_MESH_FILE_BYTES)]
    TooLarge { path: std::path::PathBuf, len: u64 },
    #[error("{path} grew past {max} bytes while read", max = MAX_MESH_FILE_BYTES)]
    Grew { path: std::path::PathBuf },
}

/// Reads a mesh file named by a scene, its size bounded before it is read.
pub fn read_mesh_file(path: &std::path::Path) -> Result<Vec<u8>, MeshReadError> {
    use std::io::Read;
    let path_buf = || path.to_path_buf();
    let file = std::fs::File::open(path).map_err(|source| MeshReadError::Open { path: path_buf(), source })?;
    let len = file.metadata().map_err(|source| MeshReadError::Read { path: path_buf(), source })?.len();
    if len > MAX_MESH_FILE_BYTES {
        return Err(MeshReadError::TooLarge { path: path_buf(), len });
    }
    let mut bytes = Vec::with_capacity(len as usize);
    // take() holds the bound even if the file grows while it is read
    file.take(MAX_MESH_FILE_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(|source| MeshReadError::Read { path: path_buf(), source })?;
    if bytes.len() as u64 > MAX_MESH_FILE_BYTES {
        return Err(MeshReadError::Grew { path: path_buf() });
    }
    Ok(bytes)
}

/// Most quantities of interest a scene may declare: each is a history in every point's record and
/// a surface on the study's page (1000 of them made a 326 MB page, issue 48); the shipped scenes
/// declare at most 4.
pub const MAX_QOIS: usize = 64;

/// Most bodies, interfaces, materials, loads or boundary conditions a scene may declare, each
/// (issue 48: a limit on every count a user sets; within the 1 MiB a scene may weigh, about
/// 10,000 fit, each read and checked at every submit and by every pool). The shipped scenes
/// declare at most 8 of any.
pub const MAX_PARTS: usize = 1000;

impl Scene {
    /// Parses TOML text; a TOML error is one line with its line and column.
    pub fn parse(text: &str) -> Result<Self, SceneError> {
        let scene: Scene = toml::from_str(text).map_err(|e| SceneError::Parse(toml_error_line(&e, text)))?;
        if !(1..=3).contains(&scene.dimension) {
            return Err(invalid("dimension", format!("must be 1, 2 or 3, got {}", scene.dimension)));
        }
        scene.check_names()?;
        if scene.parameters.len() > MAX_PARAMETERS {
            let n = scene.parameters.len();
            return Err(invalid("parameters", format!("{n} parameters, more than the {MAX_PARAMETERS} accepted")));
        }
        if scene.qoi.len() > MAX_QOIS {
            let n = scene.qoi.len();
            return Err(invalid("qoi", format!("{n} quantities of interest, more than the {MAX_QOIS} accepted")));
        }
        let parts = [
            ("bodies", scene.bodies.len()),
            ("interfaces", scene.interfaces.len()),
            ("materials", scene.materials.len()),
            ("loads", scene.loads.len()),
            ("boundary", scene.boundary.len()),
        ];
        if let Some((key, n)) = parts.into_iter().find(|&(_, n)| n > MAX_PARTS) {
            return Err(invalid(key, format!("{n} entries, more than the {MAX_PARTS} accepted")));
        }
        for q in &scene.qoi {
            if q.point.iter().flatten().any(|c| matches!(c, Scalar::Number(x) if !x.is_finite())) {
                return Err(invalid(format!("qoi.{}.point", q.name), "coordinates must be finite numbers"));
            }
        }
        check_tolerance("solver.tolerance", scene.solver.tolerance)?;
        check_max_iterations("solver.max_iterations", scene.solver.max_iterations as u64)?;
        for (name, p) in &scene.parameters {
            let key = format!("parameters.{name}");
            if !p.default.is_finite() {
                return Err(invalid(key, "default must be a finite number"));
            }
            if let (Some(lo), Some(hi)) = (p.min, p.max)
                && !(lo.is_finite() && hi.is_finite() && lo <= hi)
            {
                return Err(invalid(key, format!("range [{lo}, {hi}] is not a finite interval")));
            }
            if p.min.is_some_and(|lo| p.default < lo) || p.max.is_some_and(|hi| p.default > hi) {
                return Err(invalid(key, format!("default {} lies outside its own range", p.default)));
            }
        }
        Ok(scene)
    }

    /// Whether a QoI is a norm, never negative: a slip without a component.
    pub fn qoi_is_norm(&self, name: &str) -> bool {
        self.qoi.iter().any(|q| q.name == name && q.kind == QoiKind::Slip && q.component.is_none())
    }

    /// The signed components of a norm QoI that the scene also reports (slips with a
    /// `component` at the same interface and point), in the scene's order; empty for any other.
    pub fn components_of(&self, name: &str) -> Vec<&str> {
        let Some(norm) = self.qoi.iter().find(|q| q.name == name && q.kind == QoiKind::Slip && q.component.is_none())
        else {
            return Vec::new();
        };
        // (axis, name): one QoI per axis (two of one axis are the same number)
        let mut found: Vec<(&str, &str)> = Vec::new();
        for q in &self.qoi {
            if let Some(axis) = q.component.as_deref()
                && q.kind == QoiKind::Slip
                && q.interface == norm.interface
                && q.point == norm.point
                && !found.iter().any(|(a, _)| *a == axis)
            {
                found.push((axis, &q.name));
            }
        }
        found.into_iter().map(|(_, name)| name).collect()
    }

    /// The unit of a parameter (as declared; None if it has none) or of a QoI (from its kind).
    pub fn unit(&self, name: &str) -> Option<&str> {
        match self.parameters.get(name) {
            Some(p) => p.unit.as_deref(),
            None => self.qoi.iter().find(|q| q.name == name).map(|q| q.kind.unit(self.dimension)),
        }
    }

    /// Reads and parses a scene file; its mesh files are read next to it and hashed.
    pub fn read(path: &std::path::Path) -> Result<Self, SceneError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| invalid("scene", format!("cannot read {}: {e}", path.display())))?;
        let mut scene = Self::parse(&text)?;
        scene.attach_meshes(path.parent().unwrap_or(std::path::Path::new("")))?;
        Ok(scene)
    }

    /// The mesh files the scene's bodies name (each once).
    pub fn mesh_files(&self) -> std::collections::BTreeSet<&str> {
        self.bodies.iter().filter_map(|b| b.mesh.as_ref()).map(|m| m.file.as_str()).collect()
    }

    /// Reads the mesh files from `directory` (the scene file's) and attaches them.
    pub fn attach_meshes(&mut self, directory: &std::path::Path) -> Result<(), SceneError> {
        let mut files = BTreeMap::new();
        for (bi, b) in self.bodies.iter().enumerate() {
            if let Some(m) = &b.mesh
                && !files.contains_key(&m.file)
            {
                let bytes = read_mesh_file(&directory.join(&m.file))
                    .map_err(|e| invalid(format!("bodies[{bi}].mesh.file"), e.to_string()))?;
                files.insert(m.file.clone(), bytes);
            }
        }
        self.attach_mesh_bytes(files).map_err(|e| invalid("meshes", e.to_string()))
    }

    /// Attaches the mesh files' bytes by their `file` in the scene and hashes them: exactly the
    /// files the scene names, within [`MAX_MESH_FILES`], [`MAX_MESH_FILE_BYTES`] each and
    /// [`MAX_MESH_BYTES`] in all. The one path of every scene with meshes (read from disk or
    /// submitted), so both hash the same.
    pub fn attach_mesh_bytes<B: AsRef<[u8]> + Into<std::sync::Arc<[u8]>>>(
        &mut self,
        files: impl IntoIterator<Item = (String, B)>,
    ) -> Result<(), MeshFileError> {
        let mut meshes = BTreeMap::new();
        let mut total = 0u64;
        for (file, bytes) in files {
            if meshes.len() == MAX_MESH_FILES {
                return Err(MeshFileError::TooMany { count: MAX_MESH_FILES + 1 });
            }
            if meshes.contains_key(&file) {
                return Err(MeshFileError::Duplicate(file));
            }
            // measured before the bytes are moved (or copied) into the scene
            let len = bytes.as_ref().len() as u64;
            if len > MAX_MESH_FILE_BYTES {
                return Err(MeshFileError::TooLarge { file, bytes: len });
            }
            total += len;
            if total > MAX_MESH_BYTES {
                return Err(MeshFileError::TotalTooLarge { bytes: total });
            }
            meshes.insert(file, bytes.into());
        }
        let named = self.mesh_files();
        if let Some(file) = named.iter().find(|f| !meshes.contains_key(**f)) {
            return Err(MeshFileError::Missing(file.to_string()));
        }
        if let Some(file) = meshes.keys().find(|f| !named.contains(f.as_str())) {
            return Err(MeshFileError::Unexpected(file.clone()));
        }
        self.mesh_digests = meshes.iter().map(|(f, b)| (f.clone(), mesh_digest(b))).collect();
        self.meshes = meshes;
        Ok(())
    }

    /// What solving this scene will take, from its text and its mesh files (nothing is built):
    /// the work of refusing a scene too big for a coordinator or a pool before it allocates.
    /// Fails only on a mesh body whose file is not attached or does not read as its volume.
    pub fn size(&self) -> Result<SceneSize, SceneError> {
        let nodes = |e: &[usize]| e.iter().fold(1u64, |n, &k| n.saturating_mul(k as u64 + 1));
        let dim = self.dimension as u64;
        let mut dofs = 0u64;
        let mut interface_nodes = 0u64;
        // Mesh bodies: each file parsed once; a volume's nodes and those of its named surfaces.
        let mut parsed = BTreeMap::new();
        for file in self.mesh_files() {
            let bytes = self
                .meshes
                .get(file)
                .ok_or_else(|| invalid("meshes", MeshFileError::Missing(file.to_string()).to_string()))?;
            let msh = crate::gmsh::Msh::parse(bytes).map_err(|e| invalid("meshes", format!("{file}: {e}")))?;
            parsed.insert(file, msh);
        }
        let mut mesh_faces: BTreeMap<&str, BTreeMap<String, u64>> = BTreeMap::new();
        for (bi, b) in self.bodies.iter().enumerate() {
            let Some(m) = &b.mesh else { continue };
            let volume = parsed[m.file.as_str()]
                .volume(&m.volume)
                .map_err(|e| invalid(format!("bodies[{bi}].mesh"), format!("{}: {e}", m.file)))?;
            let n = volume.nodes.len() as u64;
            dofs = dofs.saturating_add(n.saturating_mul(dim));
            // METIS cuts, not known before partitioning: k compact parts of a body of n nodes
            // are cut by about 3 (k^(1/3) - 1) planes of n^(2/3) nodes, each held by both sides
            // (the joint's dofs within 3 % on the tiny and the paper-size mesh, docs/performance.md)
            let parts = match &b.substructures {
                Some(Substructures::Count(p)) => *p as f64,
                _ => 1.0,
            };
            let cut = (3.0 * (parts.cbrt() - 1.0) * (n as f64).powf(2.0 / 3.0)).ceil() as u64;
            interface_nodes = interface_nodes.saturating_add(cut.saturating_mul(2));
            dofs = dofs.saturating_add(cut.saturating_mul(dim));
            let faces = volume.surfaces.iter().map(|(name, faces)| {
                let mut distinct: Vec<usize> = faces.iter().flatten().copied().collect();
                distinct.sort_unstable();
                distinct.dedup();
                (name.clone(), distinct.len() as u64)
            });
            mesh_faces.insert(b.name.as_str(), faces.collect());
        }
        for b in &self.bodies {
            let Some(elements) = &b.elements else { continue };
            dofs = dofs.saturating_add(nodes(elements).saturating_mul(dim));
            // substructure cuts: a plane of nodes per cut, held by both sides
            let subs = match &b.substructures {
                Some(Substructures::PerAxis(p)) => p.clone(),
                _ => Vec::new(),
            };
            for (axis, &s) in subs.iter().enumerate().filter(|&(a, _)| a < elements.len()) {
                let mut face = elements.clone();
                face.remove(axis);
                let cut = nodes(&face).saturating_mul(s.saturating_sub(1) as u64);
                interface_nodes = interface_nodes.saturating_add(cut);
                dofs = dofs.saturating_add(cut.saturating_mul(dim));
            }
        }
        for itf in &self.interfaces {
            for side in [&itf.a, &itf.b] {
                let Some((body, face)) = side.split_once('.') else { continue };
                if let Some(&count) = mesh_faces.get(body).and_then(|faces| faces.get(face)) {
                    interface_nodes = interface_nodes.saturating_add(count);
                    continue;
                }
                let Some(elements) = self.bodies.iter().find(|b| b.name == body).and_then(|b| b.elements.as_ref())
                else {
                    continue;
                };
                let Some(axis) = face.chars().next().and_then(|c| "xyz".find(c)) else { continue };
                if axis < elements.len() {
                    let mut f = elements.clone();
                    f.remove(axis);
                    interface_nodes = interface_nodes.saturating_add(nodes(&f));
                }
            }
        }
        Ok(SceneSize { dofs, interface_nodes, steps: self.time.steps as u64, dimension: dim })
    }

    /// Names are short and printable: they key records, label plots and come back in messages.
    fn check_names(&self) -> Result<(), SceneError> {
        let names = self
            .parameters
            .keys()
            .map(|n| ("parameters", n))
            .chain(self.materials.keys().map(|n| ("materials", n)))
            .chain(self.bodies.iter().map(|b| ("bodies", &b.name)))
            .chain(self.interfaces.iter().map(|i| ("interfaces", &i.name)))
            .chain(self.qoi.iter().map(|q| ("qoi", &q.name)));
        for (table, name) in names {
            if !is_plain_name(name) {
                return Err(invalid(
                    table,
                    format!(
                        "name `{}` must be 1 to {MAX_NAME_CHARS} printable characters",
                        excerpt(&name.escape_debug().to_string(), MAX_NAME_CHARS)
                    ),
                ));
            }
        }
        // the title and the units are printed by every client: nothing that acts on a terminal
        let texts = self.title.iter().map(|t| ("title".to_string(), t)).chain(
            self.parameters.iter().filter_map(|(n, p)| Some((format!("parameters.{n}.unit"), p.unit.as_ref()?))),
        );
        for (key, text) in texts {
            if !is_plain_text(text) {
                return Err(invalid(
                    key,
                    format!(
                        "`{}` holds control or direction characters (escapes, carriage returns, overrides)",
                        excerpt(&text.escape_debug().to_string(), MAX_NAME_CHARS)
                    ),
                ));
            }
        }
        Ok(())
    }

    /// Parameters used only in interface laws (`interfaces[*].friction`, `.prakash_clifton`):
    /// changing them changes no substructure operator, only the local stage, so a solve can
    /// keep its factorisations and warm starts may blend solutions. A parameter also used
    /// anywhere else (or never used) is not in the set.
    pub fn interface_law_parameters(&self) -> std::collections::BTreeSet<String> {
        fn walk(v: &serde_json::Value, path: &mut Vec<String>, uses: &mut BTreeMap<String, Vec<String>>) {
            match v {
                serde_json::Value::String(s) => {
                    let name = s.strip_prefix('-').unwrap_or(s);
                    uses.entry(name.to_string()).or_default().push(path.join("."));
                }
                serde_json::Value::Array(a) => {
                    for x in a {
                        path.push("[]".into());
                        walk(x, path, uses);
                        path.pop();
                    }
                }
                serde_json::Value::Object(o) => {
                    for (k, x) in o {
                        path.push(k.clone());
                        walk(x, path, uses);
                        path.pop();
                    }
                }
                _ => {}
            }
        }
        let mut body = self.clone();
        body.parameters.clear();
        let value = serde_json::to_value(&body).expect("a scene serialises");
        let mut uses = BTreeMap::new();
        walk(&value, &mut Vec::new(), &mut uses);
        self.parameters
            .keys()
            .filter(|name| {
                uses.get(*name).is_some_and(|paths| paths.iter().all(|p| LAW_ONLY_PATHS.contains(&p.as_str())))
            })
            .cloned()
            .collect()
    }

    /// Identity of the mechanical problem: hex SHA-256 of the scene serialised canonically
    /// (serde_json, maps sorted) without what does not change the solution of a design point —
    /// the `[solver]` section, the title, and the parameters' defaults, ranges and units (their
    /// names stay). A stored interface solution may warm-start a solve only of a scene with the
    /// same hash (docs/method.md 4).
    pub fn content_hash(&self) -> String {
        use sha2::{Digest, Sha256};
        let mut canonical = self.clone();
        canonical.title = None;
        // the solver section as it serialised before its keys became optional (the hash of
        // every stored solution; `shipped_scene_hashes_do_not_move`)
        canonical.solver = SolverSpec { scale: Some(Scale::Single), ..SolverSpec::default() };
        for p in canonical.parameters.values_mut() {
            *p = ParameterSpec { default: 0.0, min: None, max: None, unit: None };
        }
        // a tag, so that a change of this canonical form can be told from a change of the scene
        let mut hasher = Sha256::new();
        hasher.update(b"glissade-scene-hash-v1\n");
        // Serialising plain data (no maps with non-string keys) cannot fail.
        let json = serde_json::to_vec(&canonical).expect("scene serialises to JSON");
        hasher.update(&json);
        // Mesh bodies: the files' contents and the partitioner that cuts them (a box's text
        // says it all, so box scenes keep their hash).
        if self.bodies.iter().any(|b| b.mesh.is_some()) {
            hasher.update(b"\npartition: metis-5 k-way, contiguous, seed 0\n");
            for (file, digest) in &self.mesh_digests {
                hasher.update(format!("{file}: {digest}\n").as_bytes());
            }
        }
        hasher.finalize().iter().map(|b| format!("{b:02x}")).collect()
    }

    /// Whether an interface has a contact or friction law (a unilateral one).
    pub fn has_contact(&self) -> bool {
        self.interfaces.iter().any(|i| matches!(i.law, LawSpec::Contact | LawSpec::Friction))
    }

    /// Steps per time window of the dynamic stage (0: the whole interval): `solver.time_window`,
    /// or chosen ([`AUTO_WINDOW_ABOVE_STEPS`]).
    pub fn window_steps(&self) -> usize {
        self.solver.time_window.unwrap_or(if self.has_contact() && self.time.steps > AUTO_WINDOW_ABOVE_STEPS {
            AUTO_TIME_WINDOW
        } else {
            0
        })
    }

    /// Whether a whole-interval solve iterates on to check its answer: `solver.whole_interval_check`,
    /// or where the scene has a contact or friction interface (a contact that lifts off and lands
    /// fools the stopping test's rate 2-4 x and more; on perfect interfaces the rate holds:
    /// docs/method.md 3, "Two tolerances").
    pub fn whole_interval_check(&self) -> bool {
        self.solver.whole_interval_check.unwrap_or_else(|| self.has_contact())
    }

    /// The dynamic stage's scale: `solver.scale`, or multiscale where the solver chooses time
    /// windows ([`Scene::window_steps`]) or where a body is cut into more than
    /// [`MULTISCALE_ABOVE_SUBSTRUCTURES`] substructures, single scale elsewhere. In windows of 10
    /// steps the macro problem cost nothing on the sliding blocks measured and took one element
    /// per substructure from 278 to 63 sweeps (docs/performance.md, "The default window: one
    /// step"). Where a body is cut into a chain or a grid of substructures, single
    /// scale carries equilibrium one substructure an iteration: cold solves at 2e-4 with their
    /// check took 1.3-3.1 x the sweeps of the macro problem's (docs/performance.md, "The
    /// default scale"); a body in one or two pieces converges the same either way, and single
    /// scale's iteration costs less.
    pub fn scale(&self) -> Scale {
        let chosen_windows = self.solver.time_window.is_none() && self.window_steps() > 0;
        self.solver.scale.unwrap_or(
            if chosen_windows || self.most_substructures_in_a_body() > MULTISCALE_ABOVE_SUBSTRUCTURES {
                Scale::Multi
            } else {
                Scale::Single
            },
        )
    }

    /// The most substructures any body is cut into (1 for a body not cut).
    pub fn most_substructures_in_a_body(&self) -> usize {
        let count = |s: &Substructures| match s {
            Substructures::PerAxis(p) => p.iter().fold(1usize, |a, &n| a.saturating_mul(n)),
            Substructures::Count(n) => *n,
        };
        self.bodies.iter().filter_map(|b| b.substructures.as_ref().map(count)).max().unwrap_or(1).max(1)
    }

    /// Every parameter's value at `point`: the defaults, overridden by `point`'s values; refuses
    /// a name the scene does not declare.
    pub fn parameter_values(&self, point: &DesignPoint) -> Result<DesignPoint, SceneError> {
        if let Some(name) = point.names().find(|name| !self.parameters.contains_key(*name)) {
            return Err(SceneError::UnknownParameter {
                name: name.to_owned(),
                declared: self.parameters.keys().cloned().collect::<Vec<_>>().join(", "),
            });
        }
        let defaults = DesignPoint::from_pairs(self.parameters.iter().map(|(k, p)| (k.as_str(), p.default)));
        defaults.and_then(|d| d.overlaid(point)).map_err(|e| invalid("parameters", e.to_string()))
    }
}

/// Substitutes parameter values into scalars, naming the key on failure.
pub struct Resolver<'a> {
    pub values: &'a DesignPoint,
}

impl Resolver<'_> {
    pub fn get(&self, key: &str, s: &Scalar) -> Result<f64, SceneError> {
        let v = match s {
            Scalar::Number(v) => *v,
            Scalar::Parameter(spec) => {
                // "-name" stands for the negated parameter (e.g. a prestress pushing down)
                let (sign, name) = match spec.strip_prefix('-') {
                    Some(n) => (-1.0, n),
                    None => (1.0, spec.as_str()),
                };
                sign * self
                    .values
                    .get(name)
                    .ok_or_else(|| SceneError::UndeclaredParameter { key: key.to_string(), name: name.to_string() })?
            }
        };
        if !v.is_finite() {
            return Err(invalid(key, format!("{v} is not a finite number")));
        }
        Ok(v)
    }

    pub fn vector<const D: usize>(&self, key: &str, v: &[Scalar]) -> Result<[f64; D], SceneError> {
        if v.len() != D {
            return Err(invalid(key, format!("expected {D} components (dimension {D}), got {}", v.len())));
        }
        let mut out = [0.0; D];
        for (i, s) in v.iter().enumerate() {
            out[i] = self.get(&format!("{key}[{i}]"), s)?;
        }
        Ok(out)
    }

    pub fn history(&self, key: &str, h: &Option<HistorySpec>) -> Result<History, SceneError> {
        let Some(h) = h else {
            return Ok(History::constant());
        };
        if h.is_empty() {
            return Err(invalid(key, "history needs at least one [time, value] pair"));
        }
        let mut points = Vec::with_capacity(h.len());
        for (i, [t, v]) in h.iter().enumerate() {
            let t = self.get(&format!("{key}[{i}][0]"), t)?;
            let v = self.get(&format!("{key}[{i}][1]"), v)?;
            if let Some(&(tp, _)) = points.last()
                && t < tp
            {
                return Err(invalid(format!("{key}[{i}]"), "times must not decrease"));
            }
            points.push((t, v));
        }
        Ok(History { points })
    }
}

/// A piecewise-linear time history, constant beyond its first and last points.
#[derive(Debug, Clone, PartialEq)]
pub struct History {
    pub points: Vec<(f64, f64)>,
}

impl History {
    pub fn constant() -> Self {
        Self { points: vec![(0.0, 1.0)] }
    }

    pub fn at(&self, t: f64) -> f64 {
        let p = &self.points;
        if t <= p[0].0 {
            return p[0].1;
        }
        for w in p.windows(2) {
            let ((t0, v0), (t1, v1)) = (w[0], w[1]);
            if t <= t1 {
                return if t1 > t0 { v0 + (v1 - v0) * (t - t0) / (t1 - t0) } else { v1 };
            }
        }
        p[p.len() - 1].1
    }
}

/// Component index of an axis name (`x`, `y`, `z`) in dimension `dim`.
pub fn component_index(key: &str, name: &str, dim: usize) -> Result<usize, SceneError> {
    let i = match name {
        "x" => 0,
        "y" => 1,
        "z" => 2,
        _ => {
            return Err(invalid(key, format!("unknown component '{name}' (use x, y or z)")));
        }
    };
    if i >= dim {
        return Err(invalid(key, format!("component '{name}' does not exist in dimension {dim}")));
    }
    Ok(i)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interface_law_parameters_are_friction_only() {
        let text = include_str!("../../scenes/three-blocks-tiny.toml");
        let scene = Scene::parse(text).unwrap();
        let law: Vec<String> = scene.interface_law_parameters().into_iter().collect();
        assert_eq!(law, vec!["f1".to_string(), "f2".to_string()]);
        // a friction parameter also used as a load is no longer law-only
        let scene = Scene::parse(&text.replace("pressure = \"pressure\"", "pressure = \"f1\"")).unwrap();
        assert_eq!(scene.interface_law_parameters().into_iter().collect::<Vec<_>>(), vec!["f2".to_string()]);
    }

    #[test]
    fn units_are_the_parameters_own_and_follow_from_a_qois_kind() {
        let scene = Scene::parse(include_str!("../../scenes/three-blocks-tiny.toml")).unwrap();
        let units: Vec<Option<&str>> =
            ["pressure", "f1", "slip_A", "middle_ux", "nothing"].iter().map(|n| scene.unit(n)).collect();
        assert_eq!(units, [Some("Pa"), None, Some("m"), Some("m"), None]);
        assert_eq!(QoiKind::Velocity.unit(3), "m/s");
        let forces: Vec<&str> = (1..=3).map(|d| QoiKind::Force.unit(d)).collect();
        assert_eq!(forces, ["Pa", "N/m", "N"]);
    }

    #[test]
    fn history_interpolates_and_holds() {
        let h = History { points: vec![(0.0, 0.0), (1.0, 2.0), (2.0, 0.0)] };
        assert_eq!(h.at(-1.0), 0.0);
        assert_eq!(h.at(0.5), 1.0);
        assert_eq!(h.at(1.5), 1.0);
        assert_eq!(h.at(5.0), 0.0);
    }

    #[test]
    fn a_toml_error_is_one_line_with_its_position() {
        // line 3; the column counts characters, not bytes ("é" is two)
        let err = Scene::parse("dimension = 1\n# é\nname = \"é\" x\n").unwrap_err().to_string();
        assert!(err.starts_with("cannot parse scene: line 3, column 12: "), "{err}");
        assert!(!err.contains('\n'), "{err}");
    }

    #[test]
    fn unknown_key_is_named() {
        let err = Scene::parse("dimension = 1\nbogus = 3\n").unwrap_err().to_string();
        assert!(err.contains("bogus"), "{err}");
    }

    const HASHED: &str = r#"
dimension = 1
title = "bar"
[time]
duration = 1e-4
steps = 10
[parameters]
v0 = { default = 1.0, min = 0.1, max = 10.0, unit = "m/s" }
[materials.steel]
E = 200e9
rho = 7800
[[bodies]]
name = "bar"
material = "steel"
size = [0.1]
elements = [10]
initial_velocity = ["v0"]
"#;

    /// A mesh file over the bound is refused from its length, before a byte is read.
    #[test]
    fn mesh_files_are_bounded_before_reading() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("big.msh");
        // sparse: no disk used
        std::fs::File::create(&path).unwrap().set_len(MAX_MESH_FILE_BYTES + 1).unwrap();
        let err = read_mesh_file(&path).unwrap_err();
        assert!(matches!(err, MeshReadError::TooLarge { len, .. } if len == MAX_MESH_FILE_BYTES + 1), "{err:?}");
        let err = err.to_string();
        assert!(
            err.ends_with(&format!(
                "is {} bytes, more than the {MAX_MESH_FILE_BYTES} allowed",
                MAX_MESH_FILE_BYTES + 1
            )),
            "{err}"
        );
        std::fs::write(&path, b"$MeshFormat").unwrap();
        assert_eq!(read_mesh_file(&path).unwrap(), b"$MeshFormat");
    }

    /// Stored solutions are found by the scene hash: it must not move when the solver section
    /// gains a key. These are the hashes from before `time_window` existed (which moved them
    /// once, by serialising its default; it is left out now when absent), and an explicit
    /// `time_window` does not move them either.
    #[test]
    fn shipped_scene_hashes_do_not_move() {
        for (file, hash) in [
            ("three-blocks-tiny.toml", "00a52ca1cc6a32e6db17843501d8072dbac98331b6ad883af6657d5be8e1829a"),
            ("bar-impact-1d.toml", "8c0a3ed5779c2172d01364e855c3ae2d2e967e9a175a11045792bd0154ef469e"),
            ("sliding-block-3d.toml", "31f3c20e41d336759f724ee17e438941411f454c0898c32dff7967a2109a6cbb"),
        ] {
            let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes").join(file);
            assert_eq!(Scene::read(&path).unwrap().content_hash(), hash, "{file}");
            let text = std::fs::read_to_string(&path).unwrap();
            let windowed = if text.contains("[solver]") {
                text.replace("[solver]", "[solver]\ntime_window = 7")
            } else {
                format!("{text}\n[solver]\ntime_window = 7\n")
            };
            assert_eq!(Scene::parse(&windowed).unwrap().content_hash(), hash, "{file} with windows");
        }
    }

    /// Counts and values that every pool would refuse are refused at parse, where the
    /// coordinator reads a submission: more QoIs than [`MAX_QOIS`], a QoI point that is not
    /// finite (TOML has `nan` and `inf`), a parameter's default outside its own range.
    #[test]
    fn counts_and_values_every_pool_would_refuse_are_refused_at_parse() {
        let many: String = (0..=MAX_QOIS)
            .map(|i| format!("[[qoi]]\nname = \"q{i}\"\nkind = \"displacement\"\nbody = \"bar\"\npoint = [0.5]\ncomponent = \"x\"\n"))
            .collect();
        let err = Scene::parse(&format!("{HASHED}\n{many}")).unwrap_err().to_string();
        assert!(err.contains("qoi") && err.contains(&MAX_QOIS.to_string()), "{err}");
        // and every other list a user fills: here loads
        let loads: String =
            (0..=MAX_PARTS).map(|_| "[[loads]]\nface = \"bar.x-\"\npressure = 1.0\nhistory = [[0.0, 1.0]]\n").collect();
        let err = Scene::parse(&format!("{HASHED}\n{loads}")).unwrap_err().to_string();
        assert!(err.starts_with("loads: 1001 entries, more than the 1000 accepted"), "{err}");
        for bad in ["nan", "inf", "-inf"] {
            let text =
                format!("{HASHED}\n[[qoi]]\nname = \"q\"\nkind = \"displacement\"\nbody = \"bar\"\npoint = [{bad}]\n");
            let err = Scene::parse(&text).unwrap_err().to_string();
            assert!(err.contains("qoi.q.point") && err.contains("finite"), "{bad}: {err}");
        }
        let text = HASHED.replacen("default = 1.0, min = 0.1", "default = 20.0, min = 0.1", 1);
        assert_ne!(text, HASHED);
        let err = Scene::parse(&text).unwrap_err().to_string();
        assert!(err.contains("parameters.v0") && err.contains("outside its own range"), "{err}");
        assert!(Scene::parse(HASHED).is_ok());
    }

    /// A title or a unit that would act on a terminal (an escape, a carriage return, a direction
    /// override) is refused naming its key; accents and other scripts are text.
    #[test]
    fn titles_and_units_that_would_act_on_a_terminal_are_refused() {
        for (from, to, key) in [
            ("title = \"bar\"", "title = \"bar\\u001b]0;owned\\u0007\"", "title"),
            ("title = \"bar\"", "title = \"bar\\rforged\"", "title"),
            ("unit = \"m/s\"", "unit = \"m/s\\u202e\"", "parameters.v0.unit"),
        ] {
            let text = HASHED.replacen(from, to, 1);
            assert_ne!(text, HASHED);
            let err = Scene::parse(&text).unwrap_err().to_string();
            assert!(err.contains(key) && err.contains("control or direction"), "{to}: {err}");
        }
        assert!(Scene::parse(&HASHED.replacen("title = \"bar\"", "title = \"barre d'acier, 応力\"", 1)).is_ok());
    }

    #[test]
    fn content_hash_ignores_solver_settings_and_parameter_defaults() {
        let base = Scene::parse(HASHED).unwrap().content_hash();
        assert_eq!(base.len(), 64);
        assert!(base.chars().all(|c| c.is_ascii_hexdigit()));
        let same = [
            format!("{HASHED}[solver]\ntolerance = 1e-6\nmax_iterations = 5\n"),
            HASHED.replace("default = 1.0, min = 0.1", "default = 2.0, min = 0.5"),
            HASHED.replace("title = \"bar\"", "title = \"other\""),
            // an integer and a float of the same value are the same number
            HASHED.replace("rho = 7800", "rho = 7800.0"),
        ];
        for text in &same {
            assert_eq!(Scene::parse(text).unwrap().content_hash(), base, "{text}");
        }
        let different = [
            HASHED.replace("elements = [10]", "elements = [50]"),
            HASHED.replace("rho = 7800", "rho = 7801"),
            HASHED.replace("steps = 10", "steps = 11"),
            HASHED.replace("v0 = {", "w0 = {").replace("[\"v0\"]", "[\"w0\"]"),
        ];
        for text in &different {
            assert_ne!(Scene::parse(text).unwrap().content_hash(), base, "{text}");
        }
    }

    #[test]
    fn names_are_bounded_and_sizes_estimated_from_the_text() {
        let tiny = include_str!("../../scenes/three-blocks-tiny.toml");
        let long = "q".repeat(MAX_NAME_CHARS + 1);
        let err = Scene::parse(&tiny.replace("name = \"slip_A\"", &format!("name = \"{long}\""))).unwrap_err();
        assert!(err.to_string().contains("printable characters"), "{err}");
        // tiny: 3 blocks of 3 x 3 x 5 nodes, each cut once along z (9 nodes a side), two
        // interfaces of 9 + 9 nodes
        let size = Scene::parse(tiny).unwrap().size().unwrap();
        assert_eq!(size.dofs, 3 * (45 + 9) * 3);
        assert_eq!(size.interface_nodes, 3 * 9 + 2 * 18);
        assert!(size.bytes() < 100 << 20);
        let poison = tiny.replacen("elements = [2, 2, 4]", "elements = [200, 200, 250]", 1);
        assert!(Scene::parse(&poison).unwrap().size().unwrap().bytes() > 100 << 30);
        let overflow = tiny.replacen("elements = [2, 2, 4]", "elements = [9223372036854775807, 2, 4]", 1);
        assert_eq!(Scene::parse(&overflow).unwrap().size().unwrap().bytes(), u64::MAX);
    }

    /// A scene read from disk and the same text given its mesh bytes (a submission) hash the
    /// same; the files must be exactly those named; the size counts the mesh's nodes.
    #[test]
    fn mesh_bytes_attach_hash_and_size_like_a_read_scene() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes");
        let read = Scene::read(&dir.join("bolted-joint-tiny.toml")).unwrap();
        let text = std::fs::read_to_string(dir.join("bolted-joint-tiny.toml")).unwrap();
        let bytes = std::fs::read(dir.join("bolted-joint-tiny.msh")).unwrap();
        let mut sent = Scene::parse(&text).unwrap();
        let bare_hash = sent.content_hash();
        sent.attach_mesh_bytes([("bolted-joint-tiny.msh".to_string(), bytes.clone())]).unwrap();
        assert_eq!(sent.content_hash(), read.content_hash());
        assert_ne!(bare_hash, read.content_hash(), "the meshes' digests are in the hash");
        let mut other = bytes.clone();
        other.extend_from_slice(b"\n");
        let mut changed = Scene::parse(&text).unwrap();
        changed.attach_mesh_bytes([("bolted-joint-tiny.msh".to_string(), other)]).unwrap();
        assert_ne!(changed.content_hash(), read.content_hash(), "a changed mesh changes the hash");

        let mut s = Scene::parse(&text).unwrap();
        let none: [(String, Vec<u8>); 0] = [];
        let e = s.attach_mesh_bytes(none).unwrap_err().to_string();
        assert_eq!(e, "mesh file 'bolted-joint-tiny.msh' is named by the scene but was not given");
        let e = s
            .attach_mesh_bytes([("bolted-joint-tiny.msh".to_string(), bytes.clone()), ("x.msh".into(), vec![])])
            .unwrap_err()
            .to_string();
        assert_eq!(e, "mesh file 'x.msh' was given but the scene names no such file");
        let many = (0..=MAX_MESH_FILES).map(|i| (format!("{i}.msh"), Vec::new()));
        assert!(matches!(s.attach_mesh_bytes(many), Err(MeshFileError::TooMany { .. })));
        assert!(s.meshes.is_empty() && s.mesh_digests.is_empty(), "a refused set attaches nothing");
        let e = s.size().unwrap_err().to_string();
        assert!(e.contains("not given"), "{e}");

        // 3,204 dofs built (docs/scenes.md); the estimate counts the nodes of each volume and
        // guesses the METIS cuts: 3,291 (the paper-size mesh: 546,006 for 534,945 built)
        let size = read.size().unwrap();
        assert!((3_204..=3_400).contains(&size.dofs), "{size:?}");
        assert!(size.interface_nodes > 200, "{size:?}");
    }

    #[test]
    fn undeclared_parameter_is_named() {
        let values = DesignPoint::new();
        let r = Resolver { values: &values };
        let err = r.get("interfaces[0].friction", &Scalar::Parameter("f9".into())).unwrap_err().to_string();
        assert!(err.contains("f9") && err.contains("interfaces[0].friction"), "{err}");
    }
}
