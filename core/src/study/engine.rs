//! The study engine: the rules every study follows, whether it runs in one process
//! ([`run_study`](super::run_study), `glissade-worker study`) or on the coordinator, which leases
//! its points to worker pools. One place decides
//!
//! - what a stored solution answers: one of this very point, converged at this tolerance or a
//!   tighter one, by the same solver version (the stopping test vouches for its QoIs at its
//!   tolerance; another version may not reach the same answer);
//! - where a point's iterations start: a stored solution of this very point that is not good
//!   enough is continued from, otherwise the study's [`InitStrategy`];
//! - what a failed solve becomes: a warm-started solve that fails is solved again from cold
//!   ([`solve_or_retry_cold`]), whoever runs it.

use crate::point::DesignPoint;
use std::collections::BTreeSet;

use crate::field::InterfaceSolution;
use crate::scene::{Scene, Tolerance};

use super::space::ParameterSpace;
use super::store::{SolutionId, SolutionInfo, SolutionStore, StoreError};
use super::strategy::{InitSource, InitStrategy, Initialisation, initialise, interface_law_parameters};
use super::{SAME_POINT, StartKind};

/// The version of the solver this build runs (every crate of the workspace shares it).
pub const SOLVER_VERSION: &str = env!("CARGO_PKG_VERSION");

/// How a design point begins.
#[derive(Debug, Clone)]
pub enum Start {
    /// A stored solution answers the point: nothing to solve.
    Answer(SolutionInfo),
    /// Solve the point from `init` (cold when it holds no fields).
    Solve { init: Initialisation, kind: StartKind },
}

/// The rules of one study: its scene's parameter space, its strategy and its tolerance (checked
/// here, once).
#[derive(Debug, Clone)]
pub struct StudyEngine {
    space: ParameterSpace,
    law_parameters: BTreeSet<String>,
    strategy: InitStrategy,
    tolerance: f64,
}

impl StudyEngine {
    /// The engine of a study of `scene` by `strategy` at `tolerance` (None: the scene's).
    pub fn new(scene: &Scene, strategy: InitStrategy, tolerance: Option<Tolerance>) -> Self {
        Self {
            space: ParameterSpace::from_scene(scene),
            law_parameters: interface_law_parameters(scene),
            strategy,
            tolerance: Tolerance::or_scene(tolerance, scene),
        }
    }

    pub fn space(&self) -> &ParameterSpace {
        &self.space
    }

    pub fn strategy(&self) -> InitStrategy {
        self.strategy
    }

    pub fn tolerance(&self) -> f64 {
        self.tolerance
    }

    /// The stored solution that answers `point` as it is (converged at this study's tolerance or
    /// a tighter one, by `solver_version`), if any: what [`Self::start`] answers with, without
    /// preparing a warm start. A `Cold` study is never answered.
    pub fn answer(
        &self,
        store: &dyn SolutionStore,
        point: &DesignPoint,
        solver_version: &str,
    ) -> Result<Option<SolutionInfo>, StoreError> {
        if self.strategy == InitStrategy::Cold {
            return Ok(None);
        }
        self.stored_answer(store, point, solver_version)
    }

    /// The stored solution that answers `point` as it is, whatever the strategy: for a study
    /// whose solves start cold but whose stored points need no solve (a discretisation audit's
    /// level: a stored solution of its refined scene at the point is the level's measurement).
    pub fn stored_answer(
        &self,
        store: &dyn SolutionStore,
        point: &DesignPoint,
        solver_version: &str,
    ) -> Result<Option<SolutionInfo>, StoreError> {
        Ok(self.same_point(store, point, solver_version)?.0)
    }

    /// Stored solutions of this very point: the most accurate of those that answer it, and the
    /// most accurate of the others to continue from (the index gives same-point solutions in no
    /// particular order).
    fn same_point(
        &self,
        store: &dyn SolutionStore,
        point: &DesignPoint,
        solver_version: &str,
    ) -> Result<(Option<SolutionInfo>, Option<SolutionInfo>), StoreError> {
        let mut answer: Option<SolutionInfo> = None;
        let mut same: Option<SolutionInfo> = None;
        for (d, id) in store.nearest(point, 8)? {
            if d > SAME_POINT {
                break;
            }
            let info = store.info(id)?;
            let best = if info.converged && info.tolerance <= self.tolerance && info.solver_version == solver_version {
                &mut answer
            } else {
                &mut same
            };
            if best.as_ref().is_none_or(|b| info.tolerance < b.tolerance) {
                *best = Some(info);
            }
        }
        Ok((answer, same))
    }

    /// How `point` (every parameter of the scene) begins, given the solutions in `store` (this
    /// scene's), the solution of the point finished last (`previous`), and the version of the
    /// solver that would solve it. A `Cold` study never reads the store.
    pub fn start(
        &self,
        store: &dyn SolutionStore,
        point: &DesignPoint,
        previous: Option<SolutionId>,
        solver_version: &str,
    ) -> Result<Start, StoreError> {
        if self.strategy == InitStrategy::Cold {
            return Ok(Start::Solve { init: Initialisation::cold(), kind: StartKind::Cold });
        }
        let (answer, same) = self.same_point(store, point, solver_version)?;
        if let Some(info) = answer {
            return Ok(Start::Answer(info));
        }
        if let Some(info) = same {
            let solution = store.get(info.id)?.solution;
            let source = InitSource { id: info.id, point: info.point, distance: 0.0, weight: 1.0 };
            let init = Initialisation { solution: Some(solution), sources: vec![source], used: self.strategy };
            return Ok(Start::Solve { init, kind: StartKind::Continued });
        }
        let init = initialise(store, &self.space, &self.law_parameters, point, previous, self.strategy)?;
        let kind = match init.used {
            InitStrategy::Cold => StartKind::Cold,
            InitStrategy::Previous => StartKind::Previous,
            InitStrategy::Nearest => StartKind::Nearest,
            InitStrategy::Blend { .. } => StartKind::Blend,
            InitStrategy::Linear { .. } => StartKind::Linear,
        };
        Ok(Start::Solve { init, kind })
    }
}

/// Solves from `init`; when that fails and `init` was a warm start, solves again from cold.
/// Returns the outcome and whether it comes from the cold retry.
pub fn solve_or_retry_cold<T, E: std::fmt::Display>(
    init: Option<&InterfaceSolution>,
    mut solve: impl FnMut(Option<&InterfaceSolution>) -> Result<T, E>,
) -> (Result<T, E>, bool) {
    let outcome = solve(init);
    match outcome {
        Err(e) if init.is_some() => {
            tracing::warn!(error = %e, "warm-started solve failed; solving from cold");
            (solve(None), true)
        }
        outcome => (outcome, false),
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;
    use std::sync::Arc;

    use super::*;
    use crate::field::StageSolution;
    use crate::study::store::{MemoryStore, StoredSolution};

    const SCENE: &str = include_str!("../../../scenes/three-blocks-tiny.toml");

    fn stored(point: &DesignPoint, tolerance: f64, converged: bool, version: &str) -> StoredSolution {
        StoredSolution {
            point: point.clone(),
            eta: tolerance / 2.0,
            tolerance,
            converged,
            iterations: 10,
            qoi: BTreeMap::new(),
            solution: Arc::new(InterfaceSolution {
                static_stage: None,
                dynamic: StageSolution { interfaces: Vec::new() },
            }),
            parent: None,
            solver_version: version.into(),
            contact: Vec::new(),
        }
    }

    #[test]
    fn a_stored_point_answers_only_at_this_tolerance_or_tighter_and_by_this_solver_version() {
        let scene = Scene::parse(SCENE).unwrap();
        let engine = StudyEngine::new(&scene, InitStrategy::Nearest, Some(tolerance(1e-4)));
        let point = engine.space().defaults();
        let mut store = MemoryStore::new(engine.space().clone()).unwrap();
        // nothing stored: cold
        assert!(matches!(
            engine.start(&store, &point, None, SOLVER_VERSION).unwrap(),
            Start::Solve { kind: StartKind::Cold, .. }
        ));
        // looser tolerance, or another version, or not converged: continued, not answered
        store.insert(stored(&point, 1e-3, true, SOLVER_VERSION)).unwrap();
        store.insert(stored(&point, 1e-5, true, "0.0.1")).unwrap();
        store.insert(stored(&point, 1e-6, false, SOLVER_VERSION)).unwrap();
        match engine.start(&store, &point, None, SOLVER_VERSION).unwrap() {
            // continued from the most accurate of them
            Start::Solve { kind: StartKind::Continued, init } => assert_eq!(init.sources[0].id, 2),
            other => panic!("expected a continued start, got {other:?}"),
        }
        // the old version's solution answers a pool of that version
        assert!(matches!(engine.start(&store, &point, None, "0.0.1").unwrap(), Start::Answer(i) if i.id == 1));
        // a tighter one of this version answers
        store.insert(stored(&point, 5e-5, true, SOLVER_VERSION)).unwrap();
        assert!(matches!(engine.start(&store, &point, None, SOLVER_VERSION).unwrap(), Start::Answer(i) if i.id == 3));
        // of several that answer, the most accurate, whatever the order they are stored in
        store.insert(stored(&point, 1e-4, true, SOLVER_VERSION)).unwrap();
        store.insert(stored(&point, 2e-5, true, SOLVER_VERSION)).unwrap();
        store.insert(stored(&point, 8e-5, true, SOLVER_VERSION)).unwrap();
        assert!(matches!(engine.start(&store, &point, None, SOLVER_VERSION).unwrap(), Start::Answer(i) if i.id == 5));
        // a cold study reads nothing
        let cold = StudyEngine::new(&scene, InitStrategy::Cold, Some(tolerance(1e-4)));
        assert!(matches!(
            cold.start(&store, &point, None, SOLVER_VERSION).unwrap(),
            Start::Solve { kind: StartKind::Cold, .. }
        ));
    }

    fn tolerance(t: f64) -> Tolerance {
        Tolerance::new("tolerance", t).unwrap()
    }

    #[test]
    fn a_tolerance_is_checked_where_it_enters_and_the_scene_s_stands_in_for_none() {
        let scene = Scene::parse(SCENE).unwrap();
        // beyond the floor and the ceiling too: 1e-30 and 5e-324 held a pool for ever (issue 28)
        for t in [0.0, -1e-3, f64::NAN, f64::INFINITY, 1e-30, 5e-324, 2.0] {
            let e = Tolerance::new("--tol", t).unwrap_err().to_string();
            assert!(e.starts_with("--tol: must be a number from 1e-10 to 1"), "{t}: {e}");
        }
        for t in [1e-10, 2e-4, 1.0] {
            assert_eq!(tolerance(t).get().to_bits(), t.to_bits());
        }
        assert_eq!(StudyEngine::new(&scene, InitStrategy::Nearest, None).tolerance(), scene.solver.tolerance);
        assert_eq!(StudyEngine::new(&scene, InitStrategy::Nearest, Some(tolerance(3e-5))).tolerance(), 3e-5);
    }

    #[test]
    fn only_a_failed_warm_start_is_retried_cold() {
        let warm = InterfaceSolution { static_stage: None, dynamic: StageSolution { interfaces: Vec::new() } };
        let mut calls = Vec::new();
        let (out, retried) = solve_or_retry_cold(Some(&warm), |init| {
            calls.push(init.is_some());
            if init.is_some() { Err("diverged") } else { Ok(1) }
        });
        assert_eq!((out, retried, calls), (Ok(1), true, vec![true, false]));
        let mut calls = 0;
        let (out, retried) = solve_or_retry_cold::<i32, _>(None, |_| {
            calls += 1;
            Err("diverged")
        });
        assert_eq!((out, retried, calls), (Err("diverged"), false, 1));
        let (out, retried) = solve_or_retry_cold::<_, &str>(Some(&warm), |_| Ok(2));
        assert_eq!((out, retried), (Ok(2), false));
    }
}
