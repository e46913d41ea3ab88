//! One design point solved to an asked accuracy (`--accuracy`, docs/accuracy.md, "Ask for an
//! accuracy"), as a pure rule: [`next_step`] reads the levels solved so far and says which level
//! to solve next, or gives the report. The solver's `solve_to_accuracy` drives it with solves in
//! one process; the coordinator drives it with leases, one level at a time. Either way: the
//! iteration tolerance set from the accuracy; for box bodies a staircase of levels, dt and h
//! halved in turn, read every second level along its diagonal (dt and h halved together: the
//! step's and the mesh's errors in one estimate) and answered there when that estimate is within
//! the accuracy; where the diagonal cannot go on, each ladder climbs as far as it needs, read from
//! its own halvings' changes; otherwise the time step halved on the scene's mesh.
//! A ladder stops where it says its error is within its share.
//! The answer is the finest level solved; per QoI its estimated error, split into the
//! discretisation's (the diagonal's, or the time step's and the mesh's) and the iterations'. When the changes between levels do not fall within the largest factor
//! allowed, the report says the accuracy was not reached, with the ladder as evidence.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::point::DesignPoint;
use crate::refine::{Accuracy, FinestError, RefineError, Refinement, finest_error, refined_scene};
use crate::scene::Scene;
use crate::study::space::ParameterSpace;

/// The ratio between levels: dt / 2, h / 2.
pub const RATIO: usize = 2;

/// A QoI smaller than this fraction of the largest QoI of its unit is measured against that
/// largest instead of itself: a stuck slip of 1e-21 m beside displacements of 1e-5 m is zero,
/// not a value whose rounding could never settle.
pub const ZERO_SHARE: f64 = 1e-6;

/// The levels a ladder needs before it may stop: three, so that an order is observed. Two can
/// agree by chance: the chattering block of docs/verification.md moves 0.4 % from dt to dt / 2
/// under gamma = 0.6, then 9 % at dt / 4.
pub const MIN_LEVELS: usize = 3;

/// The Newmark gamma a solve to accuracy takes for a scene with contact or friction that does not
/// set its own: a little numerical dissipation. Measured (docs/accuracy.md, "The time scheme"):
/// under the trapezoidal rule the bar impact stops converging at dt / 4 (eta stuck at 3e-4, the
/// impact's force oscillating between iterations); at 0.55 it converges in 35-306 iterations from
/// dt to dt / 10, its wall force 2-6 x closer to d'Alembert's, and a chattering block drifts less.
/// The first order it costs is measured by the ladders like any other error.
pub const CONTACT_GAMMA: f64 = 0.55;

/// The scene a solve to accuracy solves: the given one, with [`CONTACT_GAMMA`] where it has a
/// contact or friction interface and no `newmark_gamma` of its own.
pub fn accuracy_scene(scene: &Scene) -> Scene {
    let mut s = scene.clone();
    if s.has_contact() && s.time.newmark_gamma.is_none() {
        s.time.newmark_gamma = Some(CONTACT_GAMMA);
    }
    s
}

/// The scene solved at a level: [`accuracy_scene`] with dt / `time_factor` and h / `mesh_factor`.
pub fn scene_at(scene: &Scene, time_factor: usize, mesh_factor: usize) -> Result<Scene, RefineError> {
    let timed = refined_scene(&accuracy_scene(scene), Refinement::Time, time_factor)?;
    refined_scene(&timed, Refinement::Mesh, mesh_factor)
}

/// [`scene_at`]'s text: what a coordinator stores and leases for a level (comments and layout
/// are lost; the content hash of the text read back, meshes attached, is the level's scene's).
pub fn scene_text_at(scene: &Scene, time_factor: usize, mesh_factor: usize) -> Result<String, RefineError> {
    let at = scene_at(scene, time_factor, mesh_factor)?;
    let text = toml::to_string(&at).map_err(|e| RefineError::Write(e.to_string()))?;
    Ok(format!("# written by glissade (a study to an accuracy): dt / {time_factor}, h / {mesh_factor}\n{text}"))
}

/// How far a solve to accuracy may refine.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AccuracyLimits {
    /// the finest time step allowed: dt / this (a power of 2)
    pub max_time_factor: usize,
    /// the finest mesh allowed: h / this along each axis (1: the mesh is not refined)
    pub max_mesh_factor: usize,
}

/// A limit that is not a power of 2 from 1 to 1024.
#[derive(Debug, thiserror::Error)]
#[error("{flag} {value}: give a power of 2 from 1 to 1024")]
pub struct LimitError {
    pub flag: &'static str,
    pub value: usize,
}

impl AccuracyLimits {
    /// The limits `--max-dt-factor` and `--max-h-factor` ask for, checked.
    pub fn new(max_time_factor: usize, max_mesh_factor: usize) -> Result<Self, LimitError> {
        for (flag, value) in [("--max-dt-factor", max_time_factor), ("--max-h-factor", max_mesh_factor)] {
            if !(value.is_power_of_two() && value <= 1024) {
                return Err(LimitError { flag, value });
            }
        }
        Ok(AccuracyLimits { max_time_factor, max_mesh_factor })
    }

    /// [`AccuracyLimits::new`] where the mesh's limit may be left to [`AccuracyLimits::for_scene`].
    pub fn asked(max_time_factor: usize, max_mesh_factor: Option<usize>, scene: &Scene) -> Result<Self, LimitError> {
        Self::new(max_time_factor, max_mesh_factor.unwrap_or(Self::for_scene(scene).max_mesh_factor))
    }
}

impl AccuracyLimits {
    /// The limits a solve of `scene` takes where it is not given any: dt / 16, and a mesh whose
    /// element count grows at most 64-fold (h / 16 in 1D, h / 8 in 2D, h / 4 in 3D), or further,
    /// to h / 16, while the finest mesh keeps within [`SMALL_MESH_ELEMENTS`]; so that the
    /// diagonal (dt and h halved together) can take a third and a fourth level where one costs
    /// little: a copper bar of our own reaches 5 % at dt / 16, h / 16 in 0.5 s, and
    /// sliding-block-2d 1 % at dt / 8, h / 8 in 28 s; both stop short at h / 4.
    pub fn for_scene(scene: &Scene) -> Self {
        let d = scene.dimension as u32;
        let mut max_mesh_factor = match d {
            1 => 16,
            2 => 8,
            _ => 4,
        };
        // (saturating: a scene's counts are bounded where it is read, not here)
        let elements = scene
            .bodies
            .iter()
            .filter_map(|b| b.elements.as_ref())
            .map(|e| e.iter().fold(1usize, |n, &m| n.saturating_mul(m)))
            .fold(0usize, usize::saturating_add);
        while max_mesh_factor < MAX_DEFAULT_MESH_FACTOR
            && elements.saturating_mul((max_mesh_factor * RATIO).pow(d)) <= SMALL_MESH_ELEMENTS
        {
            max_mesh_factor *= RATIO;
        }
        AccuracyLimits { max_time_factor: DEFAULT_MAX_TIME_FACTOR, max_mesh_factor }
    }
}

/// A mesh of this many elements or fewer, refined, costs little enough that the default limit on
/// h goes past the dimension's 64-fold growth (a 2D block of 4 x 4 elements to h / 16: 4,096; a
/// 2D mesh of 16,384 quads and dt / 16 is minutes).
pub const SMALL_MESH_ELEMENTS: usize = 16_384;
/// The finest mesh a default limit allows: h / 16.
pub const MAX_DEFAULT_MESH_FACTOR: usize = 16;

/// The finest time step a solve to accuracy takes where it is not given a limit: dt / 16.
pub const DEFAULT_MAX_TIME_FACTOR: usize = 16;

/// One solve of the ladders.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AccuracyLevel {
    pub refinement: Refinement,
    /// dt / time_factor, h / mesh_factor
    pub time_factor: usize,
    pub mesh_factor: usize,
    pub steps: usize,
    /// 0 where the solve did not say (a pool's lease)
    pub dofs: usize,
    pub converged: bool,
    pub iterations: usize,
    /// sweeps of the whole interval, the self-check included
    pub work: f64,
    pub wall_seconds: f64,
    /// in a report, each QoI's final value at this level (a ladder's `finals` are rebuilt from
    /// the changes of its own halvings: these are what was solved); empty where the level is
    /// read by the rule ([`LevelSolved`] carries its finals)
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub finals: BTreeMap<String, f64>,
}

/// A level solved, as the rule reads it: the level, and per QoI its final value and the largest
/// magnitude its history reached.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LevelSolved {
    pub level: AccuracyLevel,
    pub finals: BTreeMap<String, f64>,
    pub largest: BTreeMap<String, f64>,
}

/// What one ladder says of one QoI.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LadderError {
    /// the final value at each level of the ladder
    pub finals: Vec<f64>,
    #[serde(flatten)]
    pub error: FinestError,
}

/// One QoI of the answer.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct QoiAccuracy {
    pub name: String,
    /// the finest level's final value
    pub value: f64,
    /// what the errors are relative to: the largest magnitude of the QoI's history at the finest
    /// level (no less than [`ZERO_SHARE`] of the largest QoI of the same unit)
    pub scale: f64,
    pub time: LadderError,
    /// `None` when the mesh was not refined
    pub mesh: Option<LadderError>,
    /// dt and h halved together (dt, h; dt / 2, h / 2; ...: c dt / h kept), when the answer was
    /// read there: the step's and the mesh's errors in one estimate, where they need not add
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub joint: Option<LadderError>,
    /// the iterations' share: [`crate::refine::NOISE_PER_TOLERANCE`] x the tolerance
    pub iteration: f64,
    /// joint + iteration where the answer was read on the diagonal, else time + mesh +
    /// iteration; relative to `scale`
    pub total: f64,
    pub within: bool,
}

/// The answer to an accuracy: the discretisation chosen, its ladders and each QoI's error.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AccuracyReport {
    pub accuracy: f64,
    /// the iteration tolerance the accuracy set
    pub tolerance: f64,
    /// the time scheme's gamma (0.5: the trapezoidal rule; [`CONTACT_GAMMA`] where chosen)
    pub newmark_gamma: f64,
    /// the answer's level: dt / time_factor, h / mesh_factor
    pub time_factor: usize,
    pub mesh_factor: usize,
    pub steps: usize,
    /// whether the mesh was refined (box bodies only, and `max_mesh_factor` 2 or more); when
    /// not, the mesh's error is in no estimate and the accuracy is not said to be reached
    pub mesh_refined: bool,
    pub limits: AccuracyLimits,
    /// every QoI within the accuracy
    pub reached: bool,
    /// why not, in one sentence; `None` when reached
    pub why_not: Option<String>,
    pub levels: Vec<AccuracyLevel>,
    pub qois: Vec<QoiAccuracy>,
    /// work and wall time of every level together
    pub work: f64,
    pub wall_seconds: f64,
    /// when reached: the cheapest level solved whose error is bounded within the accuracy (the
    /// answer's when none is cheaper); a study solves its points there
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cheapest: Option<CheapestLevel>,
}

/// A level solved on the way whose error is bounded within the accuracy without assuming an
/// order: per QoI, its measured distance to the answer plus the answer's estimated total.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CheapestLevel {
    pub time_factor: usize,
    pub mesh_factor: usize,
    /// the largest bound over the QoIs, relative to each QoI's scale
    pub bound: f64,
}

impl AccuracyReport {
    /// The level a study takes from this pilot: the cheapest within the accuracy, else the
    /// answer's.
    pub fn study_candidate(&self) -> (usize, usize) {
        self.cheapest.map_or((self.time_factor, self.mesh_factor), |c| (c.time_factor, c.mesh_factor))
    }
}

/// What to do next: solve a level, or read the report.
#[derive(Debug, Clone, PartialEq)]
pub enum Step {
    Solve { refinement: Refinement, time_factor: usize, mesh_factor: usize },
    Done(Box<AccuracyReport>),
}

/// A ladder climbed as far as its levels go.
struct Climb {
    finals: Vec<BTreeMap<String, f64>>,
    errors: BTreeMap<String, FinestError>,
    /// the finest level
    last: LevelSolved,
    /// why it stopped short of the share: a level not converged, the factor limit
    stopped: Option<String>,
}

/// One ladder's rule: what it refines, how far, and the share of the accuracy its finest level
/// must be within.
struct Ladder<'a> {
    refinement: Refinement,
    max_factor: usize,
    share: f64,
    noise: f64,
    scene: &'a Scene,
}

impl Ladder<'_> {
    fn what(&self) -> &'static str {
        match self.refinement {
            Refinement::Time => "dt",
            Refinement::Mesh => "h",
        }
    }

    fn factor(&self, l: &LevelSolved) -> usize {
        match self.refinement {
            Refinement::Time => l.level.time_factor,
            Refinement::Mesh => l.level.mesh_factor,
        }
    }

    /// The level (dt / k, h / m) with this ladder's factor set to `f`.
    fn at(&self, (k, m): (usize, usize), f: usize) -> (usize, usize) {
        match self.refinement {
            Refinement::Time => (f, m),
            Refinement::Mesh => (k, f),
        }
    }

    /// Whether `l` refined this ladder's factor from `before`.
    fn refined(&self, before: &LevelSolved, l: &LevelSolved) -> bool {
        self.factor(l) != self.factor(before)
    }

    /// Reads `solved` (factors 1, 2, 4, ... of this ladder, in order): the ladder as it stands
    /// when every QoI's finest error is within the share, a level did not converge or the next
    /// factor passes the limit or cannot be built (`build`); else the next factor to solve.
    fn climb(&self, solved: &[&LevelSolved], build: impl Fn(usize) -> Result<(), RefineError>) -> Result<Climb, usize> {
        let Some(&last) = solved.last() else { return Err(1) };
        let finals: Vec<BTreeMap<String, f64>> = solved.iter().map(|l| l.finals.clone()).collect();
        let factor = self.factor(last);
        let what = self.what();
        let errors = self.errors(&finals, last);
        let climb = |stopped: Option<String>| Climb {
            finals: finals.clone(),
            errors: errors.clone(),
            last: last.clone(),
            stopped,
        };
        if !last.level.converged {
            return Ok(climb(Some(format!("the solve at {what} / {factor} did not converge: the ladder stops there"))));
        }
        if finals.len() >= MIN_LEVELS && errors.values().all(|e| e.estimate <= self.share) {
            return Ok(climb(None));
        }
        let next = factor * RATIO;
        if next > self.max_factor {
            return Ok(climb((finals.len() < MIN_LEVELS).then(|| {
                format!(
                    "the {what} ladder needs {MIN_LEVELS} levels ({what} / {}) and may go to {what} / {} only",
                    RATIO.pow(MIN_LEVELS as u32 - 1),
                    self.max_factor
                )
            })));
        }
        match build(next) {
            Ok(()) => Err(next),
            Err(e) => Ok(climb(Some(format!("the {what} ladder stops at {what} / {factor}: {e}")))),
        }
    }

    /// This ladder read off a staircase's path: its changes (the levels that refined its
    /// factor, each against the level before it) summed back from the path's last level, which
    /// is the ladder's finest. `at_answer`: levels at the answer's other factor with this
    /// ladder's halved, quartered, ...; the changes nearest the answer are the ones measured
    /// between them instead.
    fn rebuilt(&self, path: &[&LevelSolved], at_answer: &[&LevelSolved]) -> Climb {
        let last = *path.last().expect("a path has its first level");
        let value = |l: &LevelSolved, n: &str| l.finals.get(n).copied().unwrap_or(f64::NAN);
        let mut changes: Vec<(&LevelSolved, &LevelSolved)> =
            path.windows(2).rev().filter(|w| self.refined(w[0], w[1])).map(|w| (w[0], w[1])).collect();
        let measured = std::iter::once(last).chain(at_answer.iter().copied());
        for (change, (fine, coarse)) in changes.iter_mut().zip(measured.clone().zip(measured.skip(1))) {
            *change = (coarse, fine);
        }
        let mut finals = vec![last.finals.clone()];
        for (coarse, fine) in changes {
            let later = finals.last().expect("the finest level");
            let earlier = later.iter().map(|(n, v)| (n.clone(), v - (value(fine, n) - value(coarse, n)))).collect();
            finals.push(earlier);
        }
        finals.reverse();
        let errors = self.errors(&finals, last);
        Climb { finals, errors, last: last.clone(), stopped: None }
    }

    /// Whether the ladder needs another level: fewer than [`MIN_LEVELS`], or a QoI's finest
    /// error above the share.
    fn needs(&self, c: &Climb) -> bool {
        c.finals.len() < MIN_LEVELS || c.errors.values().any(|e| e.estimate > self.share)
    }

    fn errors(&self, finals: &[BTreeMap<String, f64>], last: &LevelSolved) -> BTreeMap<String, FinestError> {
        finest_errors(self.scene, self.noise, finals, last)
    }
}

/// Every QoI's finest error on a ladder of `finals` whose finest level is `last` (infinite from a
/// single level: nothing is known yet).
fn finest_errors(
    scene: &Scene,
    noise: f64,
    finals: &[BTreeMap<String, f64>],
    last: &LevelSolved,
) -> BTreeMap<String, FinestError> {
    let scales = scales(scene, last);
    finals[0]
        .keys()
        .map(|name| {
            let f: Vec<f64> = finals.iter().map(|l| l.get(name).copied().unwrap_or(f64::NAN)).collect();
            let e = if f.len() < 2 {
                FinestError { estimate: f64::INFINITY, order: None, erratic: false, below_noise: false }
            } else {
                finest_error(&f, RATIO, noise, scales[name])
            };
            (name.clone(), e)
        })
        .collect()
}

/// Whether every QoI's last changes (over the last four levels, or three) keep one sign, those
/// within the iterations' noise aside. Three levels observe an order once: a tip velocity under
/// the trapezoidal rule, refined in dt and h together, moves -9.9 %, +8.3 %, -1.1 %, -0.6 %,
/// -0.8 %, -0.8 %: Richardson on its first falling three said 0.4 % where a solve four times
/// finer is 0.7 % away and still moving.
fn steady(scene: &Scene, noise: f64, finals: &[BTreeMap<String, f64>], last: &LevelSolved) -> bool {
    let scales = scales(scene, last);
    let recent = &finals[finals.len().saturating_sub(MIN_LEVELS + 1)..];
    scales.iter().all(|(name, &scale)| {
        let value = |l: &BTreeMap<String, f64>| l.get(name).copied().unwrap_or(f64::NAN);
        let signs: Vec<bool> = recent
            .windows(2)
            .map(|w| value(&w[1]) - value(&w[0]))
            .filter(|c| !(scale > 0.0 && c.abs() / scale <= noise))
            .map(|c| c > 0.0)
            .collect();
        signs.windows(2).all(|s| s[0] == s[1])
    })
}

/// The diagonal: the levels solved at dt, h; dt / 2, h / 2; dt / 4, h / 4; ... from the first, as
/// far as they were solved and converged.
fn diagonal(solved: &[LevelSolved]) -> Vec<&LevelSolved> {
    let mut levels = Vec::new();
    let mut f = 1;
    while let Some(l) = solved.iter().find(|l| (l.level.time_factor, l.level.mesh_factor) == (f, f)) {
        if !l.level.converged {
            break;
        }
        levels.push(l);
        f *= RATIO;
    }
    levels
}

/// Each QoI's scale: the largest magnitude of its history, no less than [`ZERO_SHARE`] of the
/// largest of the QoIs of the same unit.
pub fn scales(scene: &Scene, solved: &LevelSolved) -> BTreeMap<String, f64> {
    let unit = |name: &str| scene.qoi.iter().find(|q| q.name == name).map_or("", |q| q.kind.unit(scene.dimension));
    let own = &solved.largest;
    solved
        .finals
        .keys()
        .map(|name| {
            let s = own.get(name).copied().unwrap_or(0.0);
            let largest = own.iter().filter(|(n, _)| unit(n) == unit(name)).fold(0.0f64, |m, (_, &v)| m.max(v));
            (name.clone(), s.max(ZERO_SHARE * largest))
        })
        .collect()
}

/// The next step of a solve of `scene` (as given: [`accuracy_scene`] is applied here) to
/// `accuracy` within `limits`, from the levels solved so far, in the order they were solved.
pub fn next_step(scene: &Scene, accuracy: Accuracy, limits: AccuracyLimits, solved: &[LevelSolved]) -> Step {
    let scene = &accuracy_scene(scene);
    let mesh_refined = limits.max_mesh_factor >= RATIO && refined_scene(scene, Refinement::Mesh, RATIO).is_ok();
    let share = accuracy.discretisation_share(mesh_refined);
    let noise = accuracy.iteration_error();
    let solve = |refinement, time_factor, mesh_factor| Step::Solve { refinement, time_factor, mesh_factor };
    let time_ladder = Ladder { refinement: Refinement::Time, max_factor: limits.max_time_factor, share, noise, scene };
    let answered = |time, mesh, joint| {
        Step::Done(Box::new(report(scene, accuracy, limits, solved, Answered { time, mesh, joint, mesh_refined })))
    };
    if !mesh_refined {
        let on_scene_mesh: Vec<&LevelSolved> = solved.iter().filter(|l| l.level.mesh_factor == 1).collect();
        return match time_ladder.climb(&on_scene_mesh, |f| scene_at(scene, f, 1).map(drop)) {
            Ok(time) => answered(time, None, None),
            Err(next) => solve(Refinement::Time, next, 1),
        };
    }
    let mesh_ladder = Ladder { refinement: Refinement::Mesh, max_factor: limits.max_mesh_factor, share, noise, scene };
    staircase(scene, solved, [&time_ladder, &mesh_ladder], answered)
}

/// The levels of a staircase, from dt, h: each one halves dt or h of the one before, in turn
/// while both ladders need levels, so that c dt / h stays within a factor 2 of the scene's. A
/// step refined far below the mesh's transit time (dt alone, the mesh kept) makes a contact's
/// iterations grow about as h / (c dt), and both halved together keep them flat
/// (docs/accuracy.md, "Refine dt and h together"). Each ladder reads its own changes: under
/// errors that add (a k^-p + b m^-q) the change from dt / k to dt / 2k is the same on every
/// mesh, so the changes rebuild each ladder at the answer's other factor.
///
/// The staircase passes the diagonal (dt / k, h / k) every second level. There the diagonal's
/// own changes estimate the step's and the mesh's errors together, where they need not add (a
/// wave's depend on c dt / h; a ladder in h at a step far below the coarse meshes' transit time
/// reads their dispersion, not the answer's error): when that estimate puts every QoI within the
/// two shares together, the answer is read there. While it does not and the diagonal can go on
/// within the limits, dt and h are halved in turn whatever each ladder says alone; where it
/// cannot, each ladder climbs as far as it needs.
fn staircase(
    scene: &Scene,
    solved: &[LevelSolved],
    [time, mesh]: [&Ladder<'_>; 2],
    answered: impl Fn(Climb, Option<Climb>, Option<Climb>) -> Step,
) -> Step {
    let solve = |refinement, (time_factor, mesh_factor)| Step::Solve { refinement, time_factor, mesh_factor };
    // the path: from dt, h, each level solved that halves one factor of the path's last
    let mut path: Vec<&LevelSolved> = Vec::new();
    for l in solved {
        let at = (l.level.time_factor, l.level.mesh_factor);
        let next = match path.last() {
            None => at == (1, 1),
            Some(p) => {
                let (k, m) = (p.level.time_factor, p.level.mesh_factor);
                at == (k * RATIO, m) || at == (k, m * RATIO)
            }
        };
        if next {
            path.push(l);
        }
    }
    let Some(&last) = path.last() else { return solve(Refinement::Time, (1, 1)) };
    let (k, m) = (last.level.time_factor, last.level.mesh_factor);
    // Each ladder's changes nearest the answer measured at the answer's other factor where those
    // levels were solved (the answer's level with this ladder's factor halved, quartered): the
    // errors need not add (a wave's depend on c dt / h), and the staircase measured them at
    // coarser levels of the other ladder. `missing`: the first such level not solved yet.
    let at_answer = |ladder: &Ladder<'_>| {
        let levels = 1 + path.windows(2).filter(|w| ladder.refined(w[0], w[1])).count();
        let mut found = Vec::new();
        for halvings in 1..levels.min(MIN_LEVELS) {
            let at = ladder.at((k, m), ladder.factor(last) / RATIO.pow(halvings as u32));
            match solved.iter().find(|l| (l.level.time_factor, l.level.mesh_factor) == at) {
                None => return (found, Some(at)),
                Some(l) if l.level.converged => found.push(l),
                // (a level that did not converge leaves the staircase's changes in its place)
                Some(_) => break,
            }
        }
        (found, None)
    };
    let mut missing = [None, None];
    let mut climbs = [0, 1].map(|i| {
        let ladder = [time, mesh][i];
        let (found, first_missing) = at_answer(ladder);
        missing[i] = first_missing;
        ladder.rebuilt(&path, &found)
    });
    if !last.level.converged {
        let what = if last.level.refinement == Refinement::Mesh { 1 } else { 0 };
        climbs[what].stopped = Some(format!(
            "the solve at dt / {k}, h / {m} did not converge: the {} ladder stops there",
            [time, mesh][what].what()
        ));
        let [t, h] = climbs;
        return answered(t, Some(h), None);
    }
    let (joint, diagonal_open) = read_diagonal(scene, solved, last, [time, mesh]);
    if let Some(joint) = joint {
        let [t, h] = climbs;
        return answered(t, Some(h), Some(joint));
    }
    // which ladders still need a level, and which of them can take one
    let next_of = |ladder: &Ladder<'_>| ladder.at((k, m), ladder.factor(last) * RATIO);
    let mut open = Vec::new();
    for (i, ladder) in [time, mesh].into_iter().enumerate() {
        if !ladder.needs(&climbs[i]) {
            continue;
        }
        let (nk, nm) = next_of(ladder);
        let factor = ladder.factor(last) * RATIO;
        let what = ladder.what();
        if factor > ladder.max_factor {
            if climbs[i].finals.len() < MIN_LEVELS {
                climbs[i].stopped = Some(format!(
                    "the {what} ladder needs {MIN_LEVELS} levels ({what} / {}) and may go to {what} / {} only",
                    RATIO.pow(MIN_LEVELS as u32 - 1),
                    ladder.max_factor
                ));
            }
        } else if let Err(e) = scene_at(scene, nk, nm) {
            climbs[i].stopped = Some(format!("the {what} ladder stops at {what} / {}: {e}", factor / RATIO));
        } else {
            open.push(i);
        }
    }
    // in turn: the other ladder than the last level's, when it is open
    let took = match path.len() {
        1 => None,
        n => Some(if time.refined(path[n - 2], path[n - 1]) { 0 } else { 1 }),
    };
    if diagonal_open {
        let i = if k == m { 0 } else { 1 };
        return solve([time, mesh][i].refinement, next_of([time, mesh][i]));
    }
    if let Some(&i) = open.iter().find(|&&i| Some(i) != took).or(open.first()) {
        return solve([time, mesh][i].refinement, next_of([time, mesh][i]));
    }
    // Neither ladder needs a level: the other ladder than the last level's is measured at the
    // answer where it was not yet (up to two more solves), and the rule is read again with it
    // (a ladder that then needs a level goes on climbing).
    if let Some(other) = took.map(|t| 1 - t)
        && let Some(at) = missing[other]
    {
        return solve([time, mesh][other].refinement, at);
    }
    let [t, h] = climbs;
    answered(t, Some(h), None)
}

/// The diagonal read where the staircase's last level stands on it: its climb when every QoI's
/// estimate is within the two shares together and its changes are [`steady`]; and whether it can
/// take its next level (dt / 2d, h / 2d) from where the staircase stands, (d, d) or (2d, d).
fn read_diagonal(
    scene: &Scene,
    solved: &[LevelSolved],
    last: &LevelSolved,
    [time, mesh]: [&Ladder<'_>; 2],
) -> (Option<Climb>, bool) {
    let (k, m) = (last.level.time_factor, last.level.mesh_factor);
    let diagonal = diagonal(solved);
    let d = diagonal.last().map_or(0, |l| l.level.time_factor);
    if (k, m) == (d, d) && diagonal.len() >= MIN_LEVELS {
        let finals: Vec<BTreeMap<String, f64>> = diagonal.iter().map(|l| l.finals.clone()).collect();
        let errors = finest_errors(scene, time.noise, &finals, last);
        if errors.values().all(|e| e.estimate <= time.share + mesh.share) && steady(scene, time.noise, &finals, last) {
            return (Some(Climb { finals, errors, last: last.clone(), stopped: None }), false);
        }
    }
    let open = d > 0
        && ((k, m) == (d, d) || (k, m) == (d * RATIO, d))
        && d * RATIO <= time.max_factor.min(mesh.max_factor)
        && scene_at(scene, d * RATIO, d * RATIO).is_ok();
    (None, open)
}

/// The ladders read to the end.
struct Answered {
    time: Climb,
    mesh: Option<Climb>,
    /// the diagonal's, where the answer was read there
    joint: Option<Climb>,
    mesh_refined: bool,
}

fn report(
    scene: &Scene,
    accuracy: Accuracy,
    limits: AccuracyLimits,
    solved: &[LevelSolved],
    answered: Answered,
) -> AccuracyReport {
    let Answered { time: time_climb, mesh: mesh_climb, joint: joint_climb, mesh_refined } = answered;
    let noise = accuracy.iteration_error();
    let answer = mesh_climb.as_ref().map_or(&time_climb.last, |m| &m.last);
    let scales = scales(scene, answer);
    let ladder = |c: &Climb, name: &str| LadderError {
        finals: c.finals.iter().map(|f| f.get(name).copied().unwrap_or(f64::NAN)).collect(),
        error: c.errors[name],
    };
    let qois: Vec<QoiAccuracy> = answer
        .finals
        .iter()
        .map(|(name, &value)| {
            let time = ladder(&time_climb, name);
            let mesh = mesh_climb.as_ref().map(|m| ladder(m, name));
            let joint = joint_climb.as_ref().map(|j| ladder(j, name));
            let discretisation = match &joint {
                Some(j) => j.error.estimate,
                None => time.error.estimate + mesh.as_ref().map_or(0.0, |m| m.error.estimate),
            };
            let total = discretisation + noise;
            QoiAccuracy {
                name: name.clone(),
                value,
                scale: scales[name],
                time,
                mesh,
                joint,
                iteration: noise,
                total,
                within: total <= accuracy.get() * (1.0 + 1e-12),
            }
        })
        .collect();
    let mut reasons: Vec<String> =
        time_climb.stopped.iter().chain(mesh_climb.as_ref().and_then(|m| m.stopped.as_ref())).cloned().collect();
    // (an infinite estimate comes from a ladder that stopped at one level: its reason says why)
    let finite_above = qois.iter().filter(|q| !q.within && q.total.is_finite());
    if let Some(q) = finite_above.max_by(|a, b| a.total.total_cmp(&b.total)) {
        reasons.push(format!(
            "'{}' is estimated {:.1e} off, above the accuracy {:.1e} (its parts: time step {:.1e}, mesh {}, iterations {:.1e})",
            q.name,
            q.total,
            accuracy.get(),
            q.time.error.estimate,
            q.mesh.as_ref().map_or("not estimated".to_string(), |m| format!("{:.1e}", m.error.estimate)),
            q.iteration
        ));
    }
    if !mesh_refined {
        reasons.push(if refined_scene(scene, Refinement::Mesh, RATIO).is_ok() {
            format!("the mesh was kept (its largest factor is {}): its error is in no estimate", limits.max_mesh_factor)
        } else {
            "the mesh is read from a file and cannot be refined: its error is in no estimate".to_string()
        });
    }
    let why_not = (!reasons.is_empty()).then(|| reasons.join("; "));
    let cheapest = why_not.is_none().then(|| cheapest_level(scene, accuracy, solved, &qois)).flatten();
    let levels: Vec<AccuracyLevel> =
        solved.iter().map(|l| AccuracyLevel { finals: l.finals.clone(), ..l.level.clone() }).collect();
    AccuracyReport {
        newmark_gamma: scene.time.newmark_gamma.unwrap_or(0.5),
        accuracy: accuracy.get(),
        tolerance: accuracy.tolerance(),
        time_factor: answer.level.time_factor,
        mesh_factor: answer.level.mesh_factor,
        steps: answer.level.steps,
        mesh_refined: mesh_climb.is_some(),
        limits,
        reached: why_not.is_none(),
        why_not,
        work: levels.iter().map(|l| l.work).sum(),
        wall_seconds: levels.iter().map(|l| l.wall_seconds).sum(),
        levels,
        qois,
        cheapest,
    }
}

/// The cheapest converged level of `solved` whose every QoI is within `accuracy` by the bound
/// |level - answer| / scale + the answer's total: the triangle inequality, so no order is
/// assumed for the coarser level. Cost: the level's sweeps times steps x elements (dt / k and
/// h / m costing k m^dimension): a level whose step is far below its mesh's transit time (the
/// staircase's measurements at the answer) takes that many more iterations, and a study solves
/// every point there.
fn cheapest_level(
    scene: &Scene,
    accuracy: Accuracy,
    solved: &[LevelSolved],
    qois: &[QoiAccuracy],
) -> Option<CheapestLevel> {
    let cost = |l: &AccuracyLevel| {
        l.work.max(1.0) * l.time_factor as f64 * (l.mesh_factor as f64).powi(scene.dimension as i32)
    };
    solved
        .iter()
        .filter(|l| l.level.converged)
        .filter_map(|l| {
            let bound = qois.iter().try_fold(0.0f64, |largest, q| {
                let v = l.finals.get(&q.name)?;
                let b = if q.scale > 0.0 { (v - q.value).abs() / q.scale } else { 0.0 } + q.total;
                b.is_finite().then_some(largest.max(b))
            })?;
            (bound <= accuracy.get() * (1.0 + 1e-12)).then_some((l, bound))
        })
        .min_by(|(a, _), (b, _)| cost(&a.level).total_cmp(&cost(&b.level)))
        .map(|(l, bound)| CheapestLevel { time_factor: l.level.time_factor, mesh_factor: l.level.mesh_factor, bound })
}

/// Design points in a spread-out order: the one nearest the points' centre first, then each
/// time the one farthest (normalised distance) from all those already taken. A study to an
/// accuracy solves the first few as pilots and checks the next few as held-out points: the
/// pilots span the box (its centre, then its corners), the held-out points lie between them.
pub fn spread_order(points: &[DesignPoint], space: &ParameterSpace, n: usize) -> Vec<usize> {
    let coords: Vec<Vec<f64>> = points.iter().map(|p| space.normalised_coordinates(p)).collect();
    crate::study::space::farthest_first(&coords, n)
}

/// The pilots a study to an accuracy takes unless told.
pub const DEFAULT_PILOTS: usize = 3;

/// The held-out points a study to an accuracy re-solves one level finer to confirm it.
pub const DEFAULT_HELD_OUT: usize = 2;

/// The most pilots a study to an accuracy may ask for (each climbs its own ladders).
pub const MAX_PILOTS: usize = 16;

/// One part of a QoI's error as an audit measured it (relative to the QoI's scale).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ErrorPart {
    /// `the iterations'`, `the time step's`, `the mesh's`
    pub who: &'static str,
    pub estimate: f64,
    /// how it was estimated: `order 1.4 observed`, or why it may be larger (`order 2 assumed`,
    /// `erratic`); empty for a direct measure
    pub how: &'static str,
    pub order: Option<f64>,
}

impl ErrorPart {
    /// The iterations' error an audit measured (its largest over the points re-solved).
    pub fn iterations(largest: f64) -> Self {
        ErrorPart { who: "the iterations'", estimate: largest, how: "", order: None }
    }

    /// The time step's error a discretisation audit estimated: at the order it observed, or
    /// with the order assumed (two levels) or from erratic changes, when it may be larger.
    pub fn time_step(error: f64, order: Option<f64>, order_assumed: bool, erratic: bool) -> Self {
        let how = if erratic {
            "erratic"
        } else if order_assumed {
            "order 2 assumed"
        } else {
            ""
        };
        ErrorPart { who: "the time step's", estimate: error, how, order: order.filter(|_| !erratic) }
    }

    /// The mesh's error from one refinement (order 2 assumed).
    pub fn mesh(error: f64) -> Self {
        ErrorPart { who: "the mesh's", estimate: error, how: "order 2 assumed", order: None }
    }
}

/// Which error dominates one QoI, in one sentence shared by `glissade show`, the demo and the
/// web page: `middle_ux: the mesh's error (~25.0 %, order 2 assumed: may be larger) dominates
/// the time step's (~5.90 %, order 1.52 observed) and the iterations' (6.5e-3 %)`, each a share
/// of the QoI's largest |value|. Parts compare
/// QoI by QoI, never the largest of one QoI with the largest of another. None without two parts.
pub fn verdict(qoi: &str, parts: &[ErrorPart]) -> Option<String> {
    let mut parts: Vec<&ErrorPart> = parts.iter().filter(|p| p.estimate.is_finite()).collect();
    if parts.len() < 2 {
        return None;
    }
    parts.sort_by(|a, b| b.estimate.total_cmp(&a.estimate));
    let said = |p: &ErrorPart| {
        let how = match (p.order, p.how) {
            (Some(order), _) => format!(", order {order:.2} observed"),
            (None, "") => String::new(),
            (None, how) => format!(", {how}: may be larger"),
        };
        let approx = if p.how.is_empty() && p.order.is_none() { "" } else { "~" };
        format!("{approx}{}{how}", crate::text::percent(p.estimate))
    };
    let others: Vec<String> = parts[1..].iter().map(|p| format!("{} ({})", p.who, said(p))).collect();
    Some(format!("{qoi}: {} error ({}) dominates {}", parts[0].who, said(parts[0]), others.join(" and ")))
}

/// The share of the accuracy a held-out point's difference one level finer may reach. The study's
/// error there is the sum of its differences to each level finer, falling by r = 2^-p a level at
/// order p: the first difference / (1 - r), twice it at order 1 (the order a two-level estimate
/// assumes, [`crate::refine::TWO_LEVEL_ORDER`]), 1.33 x at order 2, 2.6 x at 0.7. A bar struck
/// across a gap converges at about 0.7: with the whole accuracy as the bar, its difference of
/// 3.1 % one level finer confirmed 5 % and it was 5.1 % from a solve two levels finer.
pub const HELD_OUT_SHARE: f64 = 0.5;

/// Whether a held-out point's `difference` one level finer (relative to the QoI's scale)
/// confirms `accuracy`.
pub fn held_out_confirms(difference: f64, accuracy: f64) -> bool {
    difference <= HELD_OUT_SHARE * accuracy * (1.0 + 1e-12)
}

/// The level a study to an accuracy moves to when its held-out check says ABOVE: the check's own,
/// one level finer (dt / 2k, and h / 2m where the check refined the mesh), where the limits
/// allow; None: it stays ABOVE.
pub fn level_after_above((k, m): (usize, usize), refine_mesh: bool, limits: AccuracyLimits) -> Option<(usize, usize)> {
    let (k, m) = (k * RATIO, if refine_mesh { m * RATIO } else { m });
    (k <= limits.max_time_factor && m <= limits.max_mesh_factor).then_some((k, m))
}

/// The discretisation a study takes from its pilots' levels ([`AccuracyReport::study_candidate`]):
/// the finest any of them needed.
pub fn study_level(pilots: impl IntoIterator<Item = (usize, usize)>) -> (usize, usize) {
    pilots.into_iter().fold((1, 1), |(t, m), (pt, pm)| (t.max(pt), m.max(pm)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::study::space::{GridAxis, design_points};

    #[test]
    fn the_spread_order_starts_at_the_centre_then_takes_the_corners() {
        let scene = Scene::parse(
            "dimension = 1\n[time]\nduration = 1e-4\nsteps = 10\n[parameters]\na = { default = 0.5, min = 0.0, max = 1.0 }\nb = { default = 0.5, min = 0.0, max = 1.0 }\n[materials.m]\nE = 1e9\nrho = 1000\n[[bodies]]\nname = \"bar\"\nmaterial = \"m\"\nsize = [1.0]\nelements = [2]\n",
        )
        .unwrap();
        let space = ParameterSpace::from_scene(&scene);
        let axes = ["a=0:1:5", "b=0:1:5"].map(|g| GridAxis::parse(g, &space).unwrap());
        let points = design_points(&axes, 100).unwrap();
        let order = spread_order(&points, &space, 7);
        let at = |i: usize| (points[order[i]].get("a").unwrap(), points[order[i]].get("b").unwrap());
        assert_eq!(at(0), (0.5, 0.5), "the centre first");
        let corners: Vec<(f64, f64)> = (1..5).map(at).collect();
        for c in [(0.0, 0.0), (0.0, 1.0), (1.0, 0.0), (1.0, 1.0)] {
            assert!(corners.contains(&c), "{c:?} in {corners:?}");
        }
        // then edge midpoints, each far from every point taken
        assert_eq!(order.len(), 7);
        let mut unique = order.clone();
        unique.sort();
        unique.dedup();
        assert_eq!(unique.len(), 7);
        assert_eq!(spread_order(&points[..1], &space, 3), vec![0]);
    }

    #[test]
    fn the_rule_climbs_a_staircase_halving_dt_and_h_in_turn() {
        // a 1D bar of boxes, no contact (gamma kept); a QoI of second order in dt and in h
        let scene = Scene::parse(
            "dimension = 1\n[time]\nduration = 1e-4\nsteps = 10\n[materials.m]\nE = 1e9\nrho = 1000\n[[bodies]]\nname = \"bar\"\nmaterial = \"m\"\nsize = [1.0]\nelements = [4]\n[[boundary]]\nface = \"bar.x-\"\nclamped = true\n[[qoi]]\nname = \"u\"\nkind = \"displacement\"\nbody = \"bar\"\npoint = [1.0]\ncomponent = \"x\"\n",
        )
        .unwrap();
        let q = |k: usize, m: usize| 1.0 + 0.2 / (k * k) as f64 + 0.05 / (m * m) as f64;
        let (asked, report) = climb(&scene, 0.01, q);
        use Refinement::{Mesh, Time};
        // dt and h halved in turn while both ladders need levels; the share of each is 0.45 %:
        // the mesh's error 0.05 / m^2 is 0.3 % at h / 4, the step's 0.2 / k^2 1.2 % at dt / 4 and
        // 0.3 % at dt / 8, so dt alone goes on from there; then h / 2 and h at the answer's step,
        // where the mesh's last two changes are measured again
        let expected = vec![
            (Time, 1, 1),
            (Time, 2, 1),
            (Mesh, 2, 2),
            (Time, 4, 2),
            (Mesh, 4, 4),
            (Time, 8, 4),
            (Mesh, 8, 2),
            (Mesh, 8, 1),
        ];
        assert_eq!(asked, expected);
        assert!(report.reached, "{:?}", report.why_not);
        assert_eq!((report.time_factor, report.mesh_factor, report.levels.len()), (8, 4, 8));
        let u = &report.qois[0];
        assert_eq!((u.value, u.scale), (q(8, 4), q(8, 4)));
        // each ladder rebuilt at the answer's other factor from its own changes: the values a
        // ladder on the answer's mesh (or at its step) would have solved
        let mesh = u.mesh.as_ref().unwrap();
        for (i, v) in u.time.finals.iter().enumerate() {
            assert!((v - q(1 << i, 4)).abs() < 1e-12, "{:?}", u.time.finals);
        }
        for (i, v) in mesh.finals.iter().enumerate() {
            assert!((v - q(8, 1 << i)).abs() < 1e-12, "{:?}", mesh.finals);
        }
        // Richardson at the observed order 2 is exact here: the errors 0.2 / 64 and 0.05 / 16
        assert!((u.time.error.estimate - 0.2 / 64.0 / u.scale).abs() < 1e-12, "{u:?}");
        assert!((mesh.error.estimate - 0.05 / 16.0 / u.scale).abs() < 1e-12, "{u:?}");
        assert!((u.total - (0.2 / 64.0 + 0.05 / 16.0) / u.scale - 1e-3).abs() < 1e-12, "{u:?}");
        // no level solved on the way is bounded within 1 %: dt / 4 on h / 4 is 0.94 % from the
        // answer, which is itself 0.73 % off
        assert_eq!(report.study_candidate(), (8, 4));
        // the levels' scenes: the text the coordinator leases reads back as the level
        let text = scene_text_at(&scene, 4, 2).unwrap();
        assert_eq!(Scene::parse(&text).unwrap().content_hash(), scene_at(&scene, 4, 2).unwrap().content_hash());

        // the mesh's error the larger: h alone goes on once the step is within its share, then
        // dt / 2 and dt at the answer's mesh measure the step's last changes there
        let (asked, report) = climb(&scene, 0.01, |k, m| 1.0 + 0.05 / (k * k) as f64 + 0.2 / (m * m) as f64);
        assert_eq!(
            asked,
            vec![(Time, 1, 1), (Time, 2, 1), (Mesh, 2, 2), (Time, 4, 2), (Mesh, 4, 4), (Time, 2, 4), (Time, 1, 4)]
        );
        assert!(!report.reached, "h / 8 is past the limit: {report:?}");
        let why = report.why_not.unwrap();
        assert!(why.starts_with("'u' is estimated 1.6e-2 off"), "{why}");

        // errors that do not add (a wave's depend on c dt / h): the mesh's change measured at
        // the answer's step, not the staircase's coarser one, sets its estimate
        let q = |k: usize, m: usize| 1.0 + 0.2 / (k * k) as f64 + 0.05 / (m * m) as f64 + 0.3 / (k * m) as f64;
        let (asked, report) = climb(&scene, 0.01, q);
        let (k, m) = (report.time_factor, report.mesh_factor);
        assert_eq!(asked[asked.len() - 2..], [(Mesh, k, m / 2), (Mesh, k, m / 4)], "{asked:?}");
        let mesh = report.qois[0].mesh.as_ref().unwrap();
        let n = mesh.finals.len();
        for (i, mm) in [m / 4, m / 2, m].into_iter().enumerate() {
            assert!((mesh.finals[n - 3 + i] - q(k, mm)).abs() < 1e-12, "{mesh:?}: the ladder at dt / {k}");
        }
        // the staircase measured it at the step where it halved h last
        let &(_, at, _) = asked.iter().rev().skip(1).find(|(r, _, mm)| *r == Mesh && *mm == m).expect("h halved");
        assert!(at < k, "{asked:?}");
        let staircase = (q(at, m) - q(at, m / 2)).abs();
        assert!((q(k, m) - q(k, m / 2)).abs() < 0.7 * staircase, "the check sees a smaller change: {asked:?}");

        // a level solved off the staircase (by an earlier rule: dt / 2, h / 2 after dt / 4, h) is
        // passed over, not read: the path goes on from dt / 4, h by halving h
        let q = |k: usize, m: usize| 1.0 + 0.2 / (k * k) as f64 + 0.05 / (m * m) as f64;
        let level = |refinement, k: usize, m: usize| solved_at(refinement, k, m, q(k, m));
        let accuracy = Accuracy::new("--accuracy", 0.01).unwrap();
        let earlier = [level(Time, 1, 1), level(Time, 2, 1), level(Time, 4, 1), level(Mesh, 2, 2)];
        let next = next_step(&scene, accuracy, AccuracyLimits::new(16, 4).unwrap(), &earlier);
        assert_eq!(next, Step::Solve { refinement: Mesh, time_factor: 4, mesh_factor: 2 });
    }

    /// The default limits: the dimension's 64-fold growth of the element count, further for a
    /// mesh that stays small, never past h / 16.
    #[test]
    fn the_default_mesh_limit_follows_the_dimension_and_the_mesh_size() {
        let scene = |dimension: usize, elements: &str| {
            let (size, box_elements) = match dimension {
                1 => ("[1.0]".to_string(), format!("[{elements}]")),
                2 => ("[1.0, 1.0]".to_string(), format!("[{elements}, {elements}]")),
                _ => ("[1.0, 1.0, 1.0]".to_string(), format!("[{elements}, {elements}, {elements}]")),
            };
            Scene::parse(&format!(
                "dimension = {dimension}\n[time]\nduration = 1e-4\nsteps = 10\n[materials.m]\nE = 1e9\nrho = 1000\n\
                 [[bodies]]\nname = \"b\"\nmaterial = \"m\"\nsize = {size}\nelements = {box_elements}\n"
            ))
            .unwrap()
        };
        let limit = |d: usize, n: &str| AccuracyLimits::for_scene(&scene(d, n)).max_mesh_factor;
        // 1D: h / 16 always; 2D: h / 8, h / 16 for a mesh of 32 x 32 or fewer (16,384 at h / 4 x 4)
        assert_eq!((limit(1, "25"), limit(1, "2000")), (16, 16));
        assert_eq!((limit(2, "4"), limit(2, "8"), limit(2, "9"), limit(2, "100")), (16, 16, 8, 8));
        // 3D: h / 4; h / 8 up to 3 x 3 x 3 elements (13,824 at h / 8), h / 16 for one (4,096)
        assert_eq!((limit(3, "1"), limit(3, "2"), limit(3, "3"), limit(3, "4")), (16, 8, 8, 4));
        assert_eq!(AccuracyLimits::for_scene(&scene(2, "4")).max_time_factor, 16);
    }

    #[test]
    fn the_diagonal_reads_the_step_and_the_mesh_together() {
        let scene = Scene::parse(
            "dimension = 1\n[time]\nduration = 1e-4\nsteps = 10\n[materials.m]\nE = 1e9\nrho = 1000\n[[bodies]]\nname = \"bar\"\nmaterial = \"m\"\nsize = [1.0]\nelements = [4]\n[[boundary]]\nface = \"bar.x-\"\nclamped = true\n[[qoi]]\nname = \"u\"\nkind = \"displacement\"\nbody = \"bar\"\npoint = [1.0]\ncomponent = \"x\"\n",
        )
        .unwrap();
        use Refinement::{Mesh, Time};
        // a wave's error: second order where dt and h fall together (c dt / h kept), and a
        // dispersion that does not fall where they part (here 0.2 x (1 - the smaller factor /
        // the larger)): the staircase's changes each cross c dt / h, the diagonal's do not
        let q = |k: usize, m: usize| {
            let parted = 1.0 - k.min(m) as f64 / k.max(m) as f64;
            1.0 + 0.3 / (k * m) as f64 + 0.2 * parted
        };
        let (asked, report) = climb(&scene, 0.05, q);
        assert_eq!(asked, vec![(Time, 1, 1), (Time, 2, 1), (Mesh, 2, 2), (Time, 4, 2), (Mesh, 4, 4)]);
        assert!(report.reached, "{:?}", report.why_not);
        assert_eq!((report.time_factor, report.mesh_factor), (4, 4));
        let u = &report.qois[0];
        let joint = u.joint.as_ref().expect("read on the diagonal");
        assert_eq!(joint.finals, vec![q(1, 1), q(2, 2), q(4, 4)]);
        // Richardson at the observed order 2 is exact: the error 0.3 / 16 at dt / 4, h / 4
        assert_eq!(joint.error.order.map(|p| (p - 2.0).abs() < 1e-9), Some(true), "{joint:?}");
        assert!((joint.error.estimate - 0.3 / 16.0 / u.scale).abs() < 1e-12, "{joint:?}");
        assert!((u.total - joint.error.estimate - 5e-3).abs() < 1e-12, "the iterations' share added: {u:?}");
        // the ladders apart, shown and not added, read the dispersion: their sum is above 5 %
        let apart = u.time.error.estimate + u.mesh.as_ref().unwrap().error.estimate;
        assert!(apart > 0.05 && u.total < 0.05, "{u:?}");

        // the same at 1 %: the diagonal says 1.8 %, and with h / 4 the finest allowed it cannot go
        // on: the staircase climbs as it would without it, and says why it stops
        let (asked, report) = climb(&scene, 0.01, q);
        assert_eq!(asked[..5], [(Time, 1, 1), (Time, 2, 1), (Mesh, 2, 2), (Time, 4, 2), (Mesh, 4, 4)]);
        assert!(!report.reached && report.qois[0].joint.is_none(), "{report:?}");
        // with h / 8 allowed, it goes on along the diagonal: dt / 8 on h / 4, then h / 8
        let limits = AccuracyLimits::new(16, 8).unwrap();
        let (asked, report) = climb_within(&scene, 0.01, limits, q);
        assert_eq!(asked[5..], [(Time, 8, 4), (Mesh, 8, 8)], "{asked:?}");
        assert!(report.reached && (report.time_factor, report.mesh_factor) == (8, 8), "{report:?}");
        let joint = report.qois[0].joint.as_ref().unwrap();
        assert!((joint.error.estimate - 0.3 / 64.0 / report.qois[0].scale).abs() < 1e-12, "{joint:?}");
    }

    /// A level solved at dt / k, h / m whose QoI `u` ended at `v`.
    fn solved_at(refinement: Refinement, k: usize, m: usize, v: f64) -> LevelSolved {
        LevelSolved {
            level: AccuracyLevel {
                refinement,
                time_factor: k,
                mesh_factor: m,
                steps: 10 * k,
                dofs: 0,
                converged: true,
                iterations: 1,
                work: 1.0,
                wall_seconds: 0.0,
                finals: BTreeMap::new(),
            },
            finals: [("u".to_string(), v)].into(),
            largest: [("u".to_string(), v)].into(),
        }
    }

    /// The rule run on a 1D bar whose QoI `u` is `q(k, m)` at dt / k, h / m.
    fn climb(
        scene: &Scene,
        accuracy: f64,
        q: impl Fn(usize, usize) -> f64,
    ) -> (Vec<(Refinement, usize, usize)>, AccuracyReport) {
        climb_within(scene, accuracy, AccuracyLimits::new(16, 4).unwrap(), q)
    }

    fn climb_within(
        scene: &Scene,
        accuracy: f64,
        limits: AccuracyLimits,
        q: impl Fn(usize, usize) -> f64,
    ) -> (Vec<(Refinement, usize, usize)>, AccuracyReport) {
        let accuracy = Accuracy::new("--accuracy", accuracy).unwrap();
        let mut solved: Vec<LevelSolved> = Vec::new();
        let mut asked = Vec::new();
        loop {
            match next_step(scene, accuracy, limits, &solved) {
                Step::Solve { refinement, time_factor, mesh_factor } => {
                    asked.push((refinement, time_factor, mesh_factor));
                    assert!(asked.len() < 20, "{asked:?}");
                    solved.push(solved_at(refinement, time_factor, mesh_factor, q(time_factor, mesh_factor)));
                }
                Step::Done(report) => return (asked, *report),
            }
        }
    }

    #[test]
    fn the_cheapest_level_counts_its_sweeps() {
        // two levels of the same steps x elements within the bound: the one that iterated less
        let scene = Scene::parse(
            "dimension = 2\n[time]\nduration = 1e-4\nsteps = 10\n[materials.m]\nE = 1e9\nrho = 1000\n[[bodies]]\nname = \"b\"\nmaterial = \"m\"\nsize = [1.0, 0.5]\nelements = [4, 2]\n",
        )
        .unwrap();
        let with_work = |k: usize, m: usize, work: f64| {
            let mut l = solved_at(Refinement::Time, k, m, 1.0);
            l.level.work = work;
            l
        };
        let answer = QoiAccuracy {
            name: "u".into(),
            value: 1.0,
            scale: 1.0,
            time: LadderError {
                finals: vec![1.0],
                error: FinestError { estimate: 0.0, order: None, erratic: false, below_noise: true },
            },
            mesh: None,
            joint: None,
            iteration: 1e-3,
            total: 1e-3,
            within: true,
        };
        let accuracy = Accuracy::new("--accuracy", 0.01).unwrap();
        let pick = |solved: &[LevelSolved]| {
            let c = cheapest_level(&scene, accuracy, solved, std::slice::from_ref(&answer)).unwrap();
            (c.time_factor, c.mesh_factor)
        };
        // dt / 4 on h costs 4 x 1^2 = 4 in steps x elements, as dt on h / 2
        assert_eq!(pick(&[with_work(4, 1, 400.0), with_work(1, 2, 30.0)]), (1, 2));
        assert_eq!(pick(&[with_work(4, 1, 30.0), with_work(1, 2, 400.0)]), (4, 1));
    }

    #[test]
    fn a_study_takes_the_cheapest_level_solved_whose_error_is_bounded_within_the_accuracy() {
        // a 2D block of boxes whose QoI barely moves with dt and h: three levels of each are
        // needed to see it, but the scene's own level is within 5 %
        let scene = Scene::parse(
            "dimension = 2\n[time]\nduration = 1e-4\nsteps = 10\n[materials.m]\nE = 1e9\nrho = 1000\n[[bodies]]\nname = \"b\"\nmaterial = \"m\"\nsize = [1.0, 0.5]\nelements = [4, 2]\n[[boundary]]\nface = \"b.x-\"\nclamped = true\n[[qoi]]\nname = \"u\"\nkind = \"displacement\"\nbody = \"b\"\npoint = [1.0, 0.5]\ncomponent = \"x\"\n",
        )
        .unwrap();
        let truth = 2.0;
        let q = |k: usize, m: usize| truth * (1.0 + 0.004 / (k * k) as f64 - 0.006 / (m * m) as f64);
        let (asked, report) = climb(&scene, 0.05, q);
        assert!(report.reached, "{:?}", report.why_not);
        assert_eq!((report.time_factor, report.mesh_factor), (4, 4), "{asked:?}");
        let cheapest = report.cheapest.expect("reached");
        assert_eq!(report.study_candidate(), (1, 1), "{report:?}");
        // the bound holds: the level's true error, relative to the answer's scale
        let u = &report.qois[0];
        let true_error = (q(1, 1) - truth).abs() / u.scale;
        assert!(true_error <= cheapest.bound && cheapest.bound <= 0.05, "{true_error} {cheapest:?}");
        // at 0.2 % the scene's level is not within the bound (0.19 % from the answer, 0.11 % its
        // total): a finer level is taken
        let (_, tight) = climb(&scene, 0.002, q);
        assert!(tight.reached, "{:?}", tight.why_not);
        let (k, m) = tight.study_candidate();
        assert!(
            k * m > 1 && (q(k, m) - truth).abs() / tight.qois[0].scale <= tight.cheapest.unwrap().bound,
            "{tight:?}"
        );
        // a report not reached offers no level
        let (_, out_of_reach) = climb(&scene, 1e-5, q);
        assert!(!out_of_reach.reached && out_of_reach.cheapest.is_none());
        // the verdict compares one QoI's parts, largest first, saying how each was estimated
        let v = verdict(
            "middle_ux",
            &[
                ErrorPart::iterations(6.5e-5),
                ErrorPart::time_step(5.9e-2, Some(1.52), false, false),
                ErrorPart::mesh(2.5e-1),
            ],
        );
        assert_eq!(
            v.as_deref(),
            Some(
                "middle_ux: the mesh's error (~25.0 %, order 2 assumed: may be larger) dominates the time step's (~5.90 %, order 1.52 observed) and the iterations' (6.5e-3 %)"
            )
        );
        assert_eq!(verdict("q", &[ErrorPart::iterations(1e-4)]), None, "one part compares with nothing");
        let erratic =
            verdict("slip", &[ErrorPart::iterations(1e-6), ErrorPart::time_step(0.3, Some(1.1), false, true)]);
        assert_eq!(
            erratic.as_deref(),
            Some("slip: the time step's error (~30.0 %, erratic: may be larger) dominates the iterations' (1.0e-4 %)")
        );
        // ABOVE moves a study one level finer in both, within the limits
        let limits = AccuracyLimits::new(16, 4).unwrap();
        assert_eq!(level_after_above((1, 1), true, limits), Some((2, 2)));
        assert_eq!(level_after_above((8, 2), true, limits), Some((16, 4)));
        assert_eq!(level_after_above((16, 1), true, limits), None, "dt / 32 is past the limit");
        assert_eq!(level_after_above((2, 4), true, limits), None, "h / 8 is past the limit");
        assert_eq!(level_after_above((2, 4), false, limits), Some((4, 4)), "the mesh kept");
    }
}
