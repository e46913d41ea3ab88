//! The pure part of a refinement ladder (docs/verification.md 11): the scene of one level (time
//! steps or box elements multiplied), and what the finals of a ladder say of a QoI — observed
//! order, Richardson's extrapolation, remaining error. The worker's `refine` command runs a
//! ladder on one point; the coordinator's discretisation audit runs one on a few points of a
//! study. One place for each rule.

use serde::{Deserialize, Serialize};

use crate::scene::Scene;

/// What a ladder refines.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Refinement {
    /// the time step: `steps` x factor
    Time,
    /// the mesh of every box body: `elements` x factor along each axis
    Mesh,
}

#[derive(Debug, thiserror::Error)]
pub enum RefineError {
    #[error(
        "refinement factors must be 2 or more of them, the first 1, each a constant multiple of the one before (1,2,4): got {0:?}"
    )]
    Factors(Vec<usize>),
    #[error("body '{0}' is read from a mesh file: only box bodies (size and elements) can be refined in h")]
    MeshBody(String),
    #[error("the refined scene cannot be written as TOML: {0}")]
    Write(String),
    #[error("{steps} steps x {factor} is more than the {max} steps a refinement may take")]
    TooFine { steps: usize, factor: usize, max: usize },
}

/// The most time steps (or elements along an axis) a level may take: a guard on what a typo in
/// the factors would allocate.
pub const MAX_REFINED: usize = 200_000;

/// Checks a ladder's factors: the first 1, a constant ratio of at least 2.
pub fn check_factors(factors: &[usize]) -> Result<usize, RefineError> {
    let bad = || RefineError::Factors(factors.to_vec());
    if factors.len() < 2 || factors[0] != 1 || factors[1] < 2 {
        return Err(bad());
    }
    let ratio = factors[1];
    if factors.windows(2).any(|w| w[1] != w[0].saturating_mul(ratio)) {
        return Err(bad());
    }
    Ok(ratio)
}

/// The scene of one level: time steps or box elements multiplied by `factor`.
pub fn refined_scene(scene: &Scene, refinement: Refinement, factor: usize) -> Result<Scene, RefineError> {
    let mut s = scene.clone();
    let too_fine = |n: usize| RefineError::TooFine { steps: n, factor, max: MAX_REFINED };
    match refinement {
        Refinement::Time => {
            s.time.steps =
                s.time.steps.checked_mul(factor).filter(|&n| n <= MAX_REFINED).ok_or(too_fine(s.time.steps))?;
        }
        Refinement::Mesh => {
            for b in &mut s.bodies {
                let Some(elements) = b.elements.as_mut() else { return Err(RefineError::MeshBody(b.name.clone())) };
                for e in elements.iter_mut() {
                    *e = e.checked_mul(factor).filter(|&n| n <= MAX_REFINED).ok_or(too_fine(*e))?;
                }
            }
        }
    }
    Ok(s)
}

/// The scene text of one level: [`refined_scene`] written back as TOML (comments and layout
/// are lost; the content hash of the text read back, meshes attached, is the refined scene's).
/// What a coordinator stores and leases for a refined study.
pub fn refined_scene_text(scene: &Scene, refinement: Refinement, factor: usize) -> Result<String, RefineError> {
    let refined = refined_scene(scene, refinement, factor)?;
    let text = toml::to_string(&refined).map_err(|e| RefineError::Write(e.to_string()))?;
    let what = match refinement {
        Refinement::Time => format!("time steps x {factor}"),
        Refinement::Mesh => format!("box elements x {factor} along each axis"),
    };
    Ok(format!("# refined by glissade (discretisation audit): {what}\n{text}"))
}

/// What a change between levels below which the iterations, not the step, are measured, is
/// relative to the iteration tolerance: five times it (the tolerance bounds a history's L2 error,
/// not its final value's).
pub const NOISE_PER_TOLERANCE: f64 = 5.0;

/// The scheme's order where two levels cannot tell (Newmark average acceleration; linear
/// elements' displacements).
pub const ASSUMED_ORDER: f64 = 2.0;

/// What the ladder's finals say of one QoI.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    pub order: Option<f64>,
    pub extrapolated: Option<f64>,
    pub error_first: f64,
    pub error_finest: f64,
    pub erratic: bool,
    pub below_tolerance: bool,
}

/// Order, extrapolation and error estimates of one QoI's finals over levels of ratio `ratio`; a
/// last change within `noise` (relative: five times the iteration tolerance, which bounds a history's L2 error, not its final value's) is the iterations', not
/// the step's: the finest level's error is then said to be below it, the first's to be its
/// distance to the finest.
pub fn richardson(finals: &[f64], ratio: usize, noise: f64) -> Estimate {
    richardson_relative_to(finals, ratio, noise, finals.iter().fold(0.0f64, |s, x| s.max(x.abs())))
}

/// [`richardson`] with the errors relative to `scale` instead of the largest |final|.
pub fn richardson_relative_to(finals: &[f64], ratio: usize, noise: f64, scale: f64) -> Estimate {
    let r = ratio as f64;
    let k = finals.len() - 1;
    let rel = |x: f64| if scale > 0.0 { x / scale } else { 0.0 };
    let last = finals[k] - finals[k - 1];
    if rel(last.abs()) <= noise {
        return Estimate {
            order: None,
            extrapolated: None,
            error_first: rel((finals[0] - finals[k]).abs()).max(noise),
            error_finest: noise,
            erratic: false,
            below_tolerance: true,
        };
    }
    let (order, erratic) = if k >= 2 {
        let before = finals[k - 1] - finals[k - 2];
        if last == 0.0 && before == 0.0 {
            (None, false)
        } else if last == 0.0 || before == 0.0 || last * before < 0.0 {
            (None, true)
        } else {
            let p = (before / last).abs().ln() / r.ln();
            if (0.5..=4.0).contains(&p) { (Some(p), false) } else { (None, true) }
        }
    } else {
        (None, false)
    };
    if erratic {
        // no extrapolation: the last change is the finest level's error at best
        return Estimate {
            order: None,
            extrapolated: None,
            error_first: rel((finals[0] - finals[k]).abs() + last.abs()),
            error_finest: rel(last.abs()),
            erratic: true,
            below_tolerance: false,
        };
    }
    let p = order.unwrap_or(ASSUMED_ORDER);
    let extrapolated = finals[k] + last / (r.powf(p) - 1.0);
    Estimate {
        order,
        extrapolated: Some(extrapolated),
        error_first: rel((finals[0] - extrapolated).abs()),
        error_finest: rel((finals[k] - extrapolated).abs()),
        erratic: false,
        below_tolerance: false,
    }
}

/// The accuracy a user asks for (`--accuracy`): every QoI's final value within this fraction of
/// the QoI's scale (the largest magnitude its history reaches) of the value the scene would
/// give with dt, h and the iteration error all going to zero (docs/accuracy.md, "Ask for an
/// accuracy").
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Accuracy(f64);

/// The range an accuracy may be asked in: tighter than 1e-6 is below what the iterations resolve
/// in double precision on the shipped scenes; looser than 0.5 is no answer.
pub const ACCURACY_RANGE: (f64, f64) = (1e-6, 0.5);

/// The share of the asked accuracy left to the iterations; the rest goes to the discretisation.
pub const ITERATION_SHARE: f64 = 0.1;

/// The time step's share of what is left when the mesh is refined too (then the mesh has the
/// same); without a mesh ladder the time step has all of it.
pub const TIME_SHARE_WITH_MESH: f64 = 0.5;

/// The order assumed where only two levels are known: first, not the scheme's second, because
/// the contact scenes' slips converge at orders 0.7-1.3 (docs/scenes.md); the second order of a
/// smooth QoI is then only used once three levels observe it.
pub const TWO_LEVEL_ORDER: f64 = 1.0;

#[derive(Debug, thiserror::Error)]
#[error("{flag} {value}: give an accuracy between {min:e} and {max} (a fraction of each QoI's scale: 0.05 is 5 %)", min = ACCURACY_RANGE.0, max = ACCURACY_RANGE.1)]
pub struct AccuracyError {
    pub flag: String,
    pub value: f64,
}

impl Accuracy {
    pub fn new(flag: &str, value: f64) -> Result<Self, AccuracyError> {
        if value.is_finite() && (ACCURACY_RANGE.0..=ACCURACY_RANGE.1).contains(&value) {
            Ok(Accuracy(value))
        } else {
            Err(AccuracyError { flag: flag.to_string(), value })
        }
    }

    pub fn get(self) -> f64 {
        self.0
    }

    /// The iteration tolerance that keeps the iterations' share of a final value
    /// ([`NOISE_PER_TOLERANCE`] times the tolerance) within [`ITERATION_SHARE`] of the accuracy:
    /// 1e-3 for 5 %, 2e-4 (the default) for 1 %.
    pub fn tolerance(self) -> f64 {
        self.iteration_error() / NOISE_PER_TOLERANCE
    }

    /// What the iterations may add to a final value's error.
    pub fn iteration_error(self) -> f64 {
        ITERATION_SHARE * self.0
    }

    /// What the time step (or the mesh) may add: the rest, split in two when both are refined.
    pub fn discretisation_share(self, with_mesh: bool) -> f64 {
        let rest = (1.0 - ITERATION_SHARE) * self.0;
        if with_mesh { TIME_SHARE_WITH_MESH * rest } else { rest }
    }
}

/// The estimated error of a ladder's finest level, relative to `scale`, and how it was reached.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FinestError {
    pub estimate: f64,
    /// the order the last three levels show, `None` from two levels or when erratic
    pub order: Option<f64>,
    /// the changes switch sign or fall at an order outside [0.5, 4]: the estimate is the larger
    /// of the last two changes, or where they fall steadily but slower than order 0.5, the
    /// sum of the changes still to come at that rate
    pub erratic: bool,
    /// the last change within the iterations' noise: the estimate is the noise
    pub below_noise: bool,
}

/// The slowest order Richardson extrapolates at ([`richardson_relative_to`]'s range starts there).
const SLOWEST_ORDER: f64 = 0.5;

/// The error of the finest of `finals` (levels of ratio `ratio`), on the safe side of
/// [`richardson_relative_to`]: from two levels the order is [`TWO_LEVEL_ORDER`]; when erratic the
/// error is no smaller than either of the last two changes. Changes of one sign that fall slower
/// than order 0.5 (each more than 0.71 of the one before) leave more to come than either: the
/// estimate is their geometric tail, last / (ratio^p - 1), which meets Richardson's at p = 0.5
/// (a mid-bar displacement behind a wave front, refined in dt and h together, falls at p ~ 0.4
/// and lies 4 % from d'Alembert's where its last change is 2 %). Changes of one sign that do not
/// fall are not converging yet: the estimate is the whole distance moved from the first level,
/// no less than the last two changes together.
pub fn finest_error(finals: &[f64], ratio: usize, noise: f64, scale: f64) -> FinestError {
    let e = richardson_relative_to(finals, ratio, noise, scale);
    let k = finals.len() - 1;
    let rel = |x: f64| if scale > 0.0 { x.abs() / scale } else { 0.0 };
    let last = rel(finals[k] - finals[k - 1]);
    let estimate = if e.below_tolerance {
        e.error_finest
    } else if k == 1 {
        last / ((ratio as f64).powf(TWO_LEVEL_ORDER) - 1.0)
    } else if e.erratic {
        let before = finals[k - 1] - finals[k - 2];
        let p = (before / (finals[k] - finals[k - 1])).ln() / (ratio as f64).ln();
        if p > 0.0 && p < SLOWEST_ORDER {
            last / ((ratio as f64).powf(p) - 1.0)
        } else if p <= 0.0 {
            // one sign, not falling: not converging yet; it may move as far again
            rel(finals[k] - finals[0]).max(last + rel(before))
        } else {
            last.max(rel(before))
        }
    } else {
        e.error_finest
    };
    FinestError { estimate, order: e.order, erratic: e.erratic, below_noise: e.below_tolerance }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn richardson_recovers_a_second_order_sequence() {
        // q(h) = 1 + 0.3 h^2 at h = 1, 1/2, 1/4
        let finals: Vec<f64> = [1.0, 0.5, 0.25].iter().map(|h: &f64| 1.0 + 0.3 * h * h).collect();
        let e = richardson(&finals, 2, 1e-9);
        assert!(!e.erratic && !e.below_tolerance);
        assert!((e.order.unwrap() - 2.0).abs() < 1e-12, "{e:?}");
        assert!((e.extrapolated.unwrap() - 1.0).abs() < 1e-12);
        assert!((e.error_first - 0.3 / 1.3).abs() < 1e-12 && (e.error_finest - 0.3 / 16.0 / 1.3).abs() < 1e-12);
    }

    #[test]
    fn a_change_of_sign_is_erratic_unless_within_the_tolerance() {
        let e = richardson(&[1.0, 1.2, 1.1], 2, 1e-6);
        assert!(e.erratic && e.order.is_none() && e.extrapolated.is_none());
        assert!((e.error_finest - 0.1 / 1.2).abs() < 1e-12);
        let e = richardson(&[1.0, 1.0 + 1e-5, 1.0 - 1e-5], 2, 4e-4);
        assert!(!e.erratic && e.below_tolerance && e.error_finest == 4e-4, "{e:?}");
    }

    #[test]
    fn factors_are_checked() {
        assert_eq!(check_factors(&[1, 2, 4]).unwrap(), 2);
        assert_eq!(check_factors(&[1, 3]).unwrap(), 3);
        for bad in [vec![1], vec![2, 4], vec![1, 2, 3], vec![1, 1], vec![]] {
            assert!(check_factors(&bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn a_refined_text_reads_back_as_the_refined_scene() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes");
        let mut read = 0;
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_none_or(|e| e != "toml") {
                continue;
            }
            // (a mesh generated by a script may be absent: both sides then hash without it)
            let mut scene = Scene::parse(&std::fs::read_to_string(&path).unwrap()).unwrap();
            let meshes = scene.attach_meshes(&dir).is_ok();
            let text = refined_scene_text(&scene, Refinement::Time, 2).unwrap();
            let mut back = Scene::parse(&text).unwrap_or_else(|e| panic!("{}: {e}\n{text}", path.display()));
            if meshes {
                back.attach_meshes(&dir).unwrap();
            }
            let refined = refined_scene(&scene, Refinement::Time, 2).unwrap();
            assert_eq!(back.time.steps, 2 * scene.time.steps);
            assert_eq!(back.content_hash(), refined.content_hash(), "{}", path.display());
            assert_ne!(back.content_hash(), scene.content_hash());
            // what the hash leaves out survives too
            assert_eq!(back.solver.tolerance, scene.solver.tolerance);
            assert_eq!(back.parameters.len(), scene.parameters.len());
            for (name, p) in &scene.parameters {
                let q = &back.parameters[name];
                assert_eq!((q.default, q.min, q.max, &q.unit), (p.default, p.min, p.max, &p.unit), "{name}");
            }
            read += 1;
        }
        assert!(read >= 10, "{read} scenes");
    }

    #[test]
    fn the_finest_error_is_on_the_safe_side() {
        // two levels: first order assumed, whatever the true order (here 2: the estimate is 3 x)
        let q = |h: f64| 1.0 + 0.3 * h * h;
        let two = finest_error(&[q(1.0), q(0.5)], 2, 1e-9, 1.0);
        assert!((two.estimate - (q(1.0) - q(0.5))).abs() < 1e-12 && two.order.is_none(), "{two:?}");
        // three levels observe the order and extrapolate: the exact error of the finest
        let three = finest_error(&[q(1.0), q(0.5), q(0.25)], 2, 1e-9, 1.0);
        assert!((three.estimate - 0.3 / 16.0).abs() < 1e-12 && (three.order.unwrap() - 2.0).abs() < 1e-9);
        // relative to the scale given, not to the finals
        let scaled = finest_error(&[q(1.0), q(0.5), q(0.25)], 2, 1e-9, 10.0);
        assert!((scaled.estimate - 0.3 / 160.0).abs() < 1e-12);
        // erratic: the larger of the last two changes
        let e = finest_error(&[1.0, 1.2, 1.1], 2, 1e-6, 1.0);
        assert!(e.erratic && (e.estimate - 0.2).abs() < 1e-12, "{e:?}");
        // growing changes are erratic too (order below 0.5), and not converging: the distance
        // moved from the first level
        let g = finest_error(&[1.0, 1.01, 1.1], 2, 1e-6, 1.0);
        assert!(g.erratic && (g.estimate - 0.1).abs() < 1e-12, "{g:?}");
        let g = finest_error(&[1.3, 1.0, 1.01, 1.1], 2, 1e-6, 1.0);
        assert!(g.erratic && (g.estimate - 0.2).abs() < 1e-12, "{g:?}");
        let g = finest_error(&[1.08, 1.0, 1.01, 1.1], 2, 1e-6, 1.0);
        assert!(g.erratic && (g.estimate - 0.1).abs() < 1e-12, "the last two changes: {g:?}");
        // changes of one sign falling slower than order 0.5: the rest of their fall, more than
        // either change (here q = 1 + 0.3 h^0.25, the error of the finest 0.3 x 0.25^0.25)
        let q = |h: f64| 1.0 + 0.3 * h.powf(0.25);
        let s = finest_error(&[q(1.0), q(0.5), q(0.25)], 2, 1e-6, 1.0);
        assert!(s.erratic && (s.estimate - 0.3 * 0.25f64.powf(0.25)).abs() < 1e-12, "{s:?}");
        assert!(s.estimate > 4.0 * (q(0.5) - q(0.25)), "{s:?}");
        // within the noise: the noise; a QoI that is zero at every level: the noise too
        let n = finest_error(&[1.0, 1.0 + 1e-7], 2, 1e-4, 1.0);
        assert!(n.below_noise && n.estimate == 1e-4);
        assert_eq!(finest_error(&[0.0, 0.0, 0.0], 2, 1e-4, 0.0).estimate, 1e-4);
    }

    #[test]
    fn an_accuracy_sets_the_tolerance_and_the_shares() {
        let a = Accuracy::new("--accuracy", 0.05).unwrap();
        assert!((a.tolerance() - 1e-3).abs() < 1e-15);
        assert!((Accuracy::new("--accuracy", 0.01).unwrap().tolerance() - 2e-4).abs() < 1e-15);
        // the parts add up to the whole
        let total = a.iteration_error() + 2.0 * a.discretisation_share(true);
        assert!((total - 0.05).abs() < 1e-15);
        assert!((a.iteration_error() + a.discretisation_share(false) - 0.05).abs() < 1e-15);
        for bad in [0.0, -0.1, 0.6, 1e-7, f64::NAN, f64::INFINITY] {
            let e = Accuracy::new("--accuracy", bad).unwrap_err().to_string();
            assert!(e.contains("--accuracy") && e.contains("0.05 is 5 %"), "{e}");
        }
    }
}
