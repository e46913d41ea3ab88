//! The readers of untrusted bytes, as a fuzzer would drive them, at a bounded cost in the suite
//! (proptest: a few hundred cases each, well under a second): a scene's text, an MSH mesh file,
//! a solution file; and the response surface, fitted to whatever values a study's points hold. Arbitrary bytes, and valid inputs with bytes replaced and cut short (those
//! get past the first check, into the parsers' depths). Each must answer Ok or an error: no
//! panic, and no allocation from a size the input claims (the decoders bound sizes before they
//! allocate; a claimed size of 2^60 would abort the process here).
//!
//! A longer run: `PROPTEST_CASES=100000 cargo test -p glissade-core --test fuzz --release`.
//! Failing inputs are saved by proptest under `core/tests/fuzz.proptest-regressions` (commit
//! that file: it is the corpus, replayed first on every run).

use glissade_core::field::{InterfaceField, InterfaceSolution, SideField, StageSolution};
use glissade_core::gmsh::Msh;
use glissade_core::io::solution_file::{self, SolutionMeta};
use glissade_core::point::DesignPoint;
use glissade_core::scene::Scene;
use glissade_core::study::surrogate::Surrogate;
use proptest::prelude::*;
use proptest::strategy::ValueTree;

const TINY: &str = include_str!("../../scenes/three-blocks-tiny.toml");

/// Two hexahedra in two physical volumes, MSH 4.1 ASCII (solver/src/gmsh.rs's test mesh).
const TWO_HEXES: &str = "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n\
$PhysicalNames\n3\n2 1 \"left_end\"\n3 2 \"left\"\n3 3 \"right\"\n$EndPhysicalNames\n\
$Entities\n0 0 1 2\n1 0 0 0 0 1 1 1 1 1 0\n\
1 0 0 0 1 1 1 1 2 0\n2 1 0 0 2 1 1 1 3 0\n$EndEntities\n\
$Nodes\n1 12 1 12\n3 1 0 12\n1\n2\n3\n4\n5\n6\n7\n8\n9\n10\n11\n12\n\
0 0 0\n1 0 0\n1 1 0\n0 1 0\n0 0 1\n1 0 1\n1 1 1\n0 1 1\n2 0 0\n2 1 0\n2 0 1\n2 1 1\n$EndNodes\n\
$Elements\n3 3 1 3\n2 1 3 1\n1 1 4 8 5\n3 1 5 1\n2 1 2 3 4 5 6 7 8\n3 2 5 1\n3 2 9 10 3 6 11 12 7\n$EndElements\n";

/// A bar in two physical volumes, as Gmsh writes it in binary (the solver's test mesh).
const BAR_TET_BINARY: &[u8] = include_bytes!("../../solver/tests/data/bar-tet-bin.msh");

/// Characters that matter to TOML and to numbers: replacing bytes with these keeps the text
/// near enough to a scene to reach its validation.
const SIGNIFICANT: &[u8] = b"[]{}=\"'.,:-+e0123456789 \n#nainf";

/// `base` with each (position, byte) replaced (positions taken modulo its length), then cut to
/// `keep` (a fraction of its length).
fn mutate(base: &[u8], edits: &[(usize, u8)], keep: f64) -> Vec<u8> {
    let mut bytes = base.to_vec();
    for &(at, b) in edits {
        let n = bytes.len();
        bytes[at % n] = b;
    }
    bytes.truncate(((bytes.len() as f64) * keep).ceil() as usize);
    bytes
}

fn significant_edits() -> impl Strategy<Value = Vec<(usize, u8)>> {
    prop::collection::vec((any::<usize>(), prop::sample::select(SIGNIFICANT)), 1..8)
}

/// A scene's whole path at submit: parse, size, the checks of every point and mesh.
fn submit_path(text: &str) {
    let Ok(scene) = Scene::parse(text) else { return };
    let _ = scene.size();
    let _ = scene.check_meshes();
    if let Ok(values) = scene.parameter_values(&DesignPoint::new()) {
        let _ = scene.check_point(&values);
    }
}

/// A small solution file: every field non-empty, a static stage.
fn solution_bytes() -> Vec<u8> {
    let side = |len: usize| SideField { force: vec![1.5; len], velocity: vec![-2.5; len] };
    let field = |len: usize| InterfaceField { s: vec![side(len), side(len)], hat: vec![side(len), side(len)] };
    let solution = InterfaceSolution {
        static_stage: Some(StageSolution { interfaces: vec![field(6)] }),
        dynamic: StageSolution { interfaces: vec![field(30)] },
    };
    let meta = SolutionMeta {
        solver_version: "0.3.0".into(),
        scene_hash: "ab".repeat(32),
        dimension: 2,
        time_steps: 5,
        parameters: DesignPoint::from_pairs([("f1", 0.3)]).unwrap(),
        converged: true,
        error_indicator: 1e-4,
        iterations: 17,
        tolerance: 2e-4,
        qoi: Default::default(),
    };
    let mut bytes = Vec::new();
    solution_file::write_to(&mut bytes, &solution, &meta).expect("writing to memory");
    bytes
}

proptest! {
    // 256 cases each unless PROPTEST_CASES says otherwise
    #![proptest_config(ProptestConfig::default())]

    #[test]
    fn scene_text_arbitrary(bytes in prop::collection::vec(any::<u8>(), 0..2048)) {
        submit_path(&String::from_utf8_lossy(&bytes));
    }

    #[test]
    fn scene_text_mutated(edits in significant_edits(), keep in 0.0..=1.0f64) {
        submit_path(&String::from_utf8_lossy(&mutate(TINY.as_bytes(), &edits, keep)));
    }

    #[test]
    fn msh_arbitrary(bytes in prop::collection::vec(any::<u8>(), 0..2048)) {
        if let Ok(msh) = Msh::parse(&bytes) {
            let _ = msh.volume("left");
        }
    }

    #[test]
    fn msh_mutated(edits in significant_edits(), keep in 0.0..=1.0f64) {
        let bytes = mutate(TWO_HEXES.as_bytes(), &edits, keep);
        if let Ok(msh) = Msh::parse(&bytes) {
            let _ = msh.volume("left");
            let _ = msh.volume("right");
        }
    }

    /// A binary file written by Gmsh with any bytes replaced: its counts and tags become any
    /// 4- or 8-byte values.
    #[test]
    fn msh_binary_mutated(edits in prop::collection::vec((any::<usize>(), any::<u8>()), 1..8), keep in 0.0..=1.0f64) {
        let bytes = mutate(BAR_TET_BINARY, &edits, keep);
        if let Ok(msh) = Msh::parse(&bytes) {
            let _ = msh.volume("lower");
            let _ = msh.volume("upper");
        }
    }

    /// Any points a study may hold (repeated places, one value everywhere, values from 1e-30
    /// to 1e30 in size and either sign): the surface fits or says why not, and where it fits,
    /// its predictions anywhere in the box and its cross-validation are finite.
    #[test]
    fn surface_of_any_points(
        dim in 1usize..4,
        rows in prop::collection::vec(
            (prop::collection::vec(prop_oneof![Just(0.0), Just(1.0), Just(0.5), 0.0..=1.0f64], 3),
             prop_oneof![Just(0.0), -1e30..1e30f64, -1e-30..1e-30f64, -1.0..1.0f64]),
            2..30,
        ),
        at in prop::collection::vec(0.0..=1.0f64, 3),
    ) {
        let points: Vec<Vec<f64>> = rows.iter().map(|(x, _)| x[..dim].to_vec()).collect();
        let values: Vec<f64> = rows.iter().map(|(_, v)| *v).collect();
        if let Ok(s) = Surrogate::fit(&points, &values) {
            let p = s.predict(&at[..dim]);
            prop_assert!(p.mean.is_finite() && p.std.is_finite() && p.std >= 0.0, "{p:?}");
            for p in s.leave_one_out() {
                prop_assert!(p.mean.is_finite() && p.std.is_finite(), "leave-one-out {p:?}");
            }
        }
    }

    #[test]
    fn solution_arbitrary(bytes in prop::collection::vec(any::<u8>(), 0..4096)) {
        let _ = solution_file::read_from(&bytes[..]);
    }

    /// Any byte replaced, including the sizes and counts in the header: an error, not an
    /// allocation of what they claim.
    #[test]
    fn solution_mutated(edits in prop::collection::vec((any::<usize>(), any::<u8>()), 1..8), keep in 0.0..=1.0f64) {
        let bytes = mutate(&solution_bytes(), &edits, keep);
        let _ = solution_file::read_from(&bytes[..]);
    }
}

/// The mutations reach past the first check: some mutated scenes still parse and some fail
/// only in the checks, so the properties above test more than the TOML reader.
#[test]
fn mutations_reach_the_checks() {
    let mut runner = proptest::test_runner::TestRunner::deterministic();
    let (mut parsed, mut refused_by_checks) = (0, 0);
    for _ in 0..300 {
        let edits = significant_edits().new_tree(&mut runner).expect("a value").current();
        let text = String::from_utf8_lossy(&mutate(TINY.as_bytes(), &edits, 1.0)).into_owned();
        if let Ok(scene) = Scene::parse(&text) {
            parsed += 1;
            let checked = scene.parameter_values(&DesignPoint::new()).and_then(|v| scene.check_point(&v));
            refused_by_checks += usize::from(checked.is_err());
        }
    }
    assert!(parsed >= 10 && refused_by_checks >= 1, "{parsed} parsed, {refused_by_checks} refused by the checks");
}
