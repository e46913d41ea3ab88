//! The CalculiX validation script (`tools/calculix/compare.py`, docs/verification.md 12): its
//! deck writer checked without CalculiX on a scene of our own. Running ccx itself stays outside
//! the suite (CalculiX is optional; the script says so and exits 3 without it).

use crate::common::*;

/// Two boxes of our own (a steel base, 2 x 2 x 2 hexahedra; an aluminium slider on it, 2 x 2 x 3,
/// its modulus a parameter), frictional contact with f a parameter, the slider pressed down and
/// pushed sideways by a ramped pressure. Glissade accepts it as it is.
const SCENE: &str = r#"
dimension = 3
[time]
duration = 1e-4
steps = 40
[parameters]
f = { default = 0.2, min = 0.1, max = 0.4 }
E_top = { default = 70e9 }
push = { default = 2e-5 }
[materials.steel]
E = 210e9
nu = 0.3
rho = 7850
[materials.alu]
E = "E_top"
nu = 0.33
rho = 2700
[[bodies]]
name = "base"
material = "steel"
size = [0.01, 0.01, 0.01]
elements = [2, 2, 2]
[[bodies]]
name = "slider"
material = "alu"
origin = [0.0, 0.0, 0.01]
size = [0.01, 0.01, 0.006]
elements = [2, 2, 3]
[[interfaces]]
name = "joint"
a = "base.z+"
b = "slider.z-"
law = "friction"
friction = "f"
[[boundary]]
face = "base.z-"
clamped = true
[[boundary]]
face = "slider.z+"
displacement = { z = "-push" }
[[loads]]
face = "slider.x-"
pressure = 3e7
history = [[0, 0], [5e-5, 1]]
[[qoi]]
name = "slip"
kind = "slip"
interface = "joint"
point = [0.005, 0.005, 0.01]
component = "x"
[[qoi]]
name = "top_ux"
kind = "displacement"
body = "slider"
point = [0.005, 0.005, 0.016]
component = "x"
"#;

fn script() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../tools/calculix/compare.py")
}

/// The lines after the first line that starts with `keyword` in `deck`.
fn after<'a>(deck: &'a str, keyword: &str, n: usize) -> Vec<&'a str> {
    let mut lines = deck.lines().skip_while(|l| !l.starts_with(keyword));
    assert!(lines.next().is_some(), "no {keyword} in the deck");
    lines.take(n).collect()
}

#[test]
fn calculix_deck_is_the_scene_at_its_design_point() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let scene = dir.path().join("slider.toml");
    std::fs::write(&scene, SCENE)?;
    // glissade takes the scene (conforming faces, the QoI points on nodes)
    let solved = worker_solve(dir.path(), &[scene.as_os_str(), os("--set"), os("f=0.3"), os("--json")]);
    converged_json(&solved);

    let deck = dir.path().join("slider.inp");
    let out = run_with_timeout(
        Command::new("/usr/bin/python3")
            .arg(script())
            .arg("deck")
            .arg(&scene)
            .args([
                "--set",
                "f=0.3",
                "--set",
                "E_top=72e9",
                "--dt",
                "1e-6",
                "--kn",
                "2e15",
                "--kt",
                "4e13",
                "--alpha",
                "-0.1",
                "--summary",
                "-o",
            ])
            .arg(&deck),
        LIMIT.min(Duration::from_secs(30)),
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    // 3 x 3 x 3 + 3 x 3 x 4 nodes, 8 + 12 hexahedra; the QoI nodes: the base's and the slider's
    // nodes at the interface's centre (node 23 = 1 + 1 + 3 (1 + 3 x 2); 27 + 1 + 1 + 3), and the
    // slider's at its top's centre
    assert_eq!(summary["nodes"], 63, "{summary}");
    assert_eq!(summary["elements"], 20, "{summary}");
    assert_eq!(summary["qoi_nodes"]["slip"], serde_json::json!([23, 32]), "{summary}");
    assert_eq!(summary["qoi_nodes"]["top_ux"], serde_json::json!([59]), "{summary}");
    let deck = std::fs::read_to_string(&deck)?;
    let node = |id: usize| deck.lines().find(|l| l.starts_with(&format!("{id}, "))).expect("node").to_owned();
    assert_eq!(node(23), "23, 5.000000000000e-03, 5.000000000000e-03, 1.000000000000e-02");
    assert_eq!(node(59), "59, 5.000000000000e-03, 5.000000000000e-03, 1.600000000000e-02");
    assert_eq!(deck.matches("*ELEMENT, TYPE=C3D8").count(), 2);
    // the materials at the design point (E_top set), the friction f = 0.3, the penalties asked
    assert_eq!(after(&deck, "*MATERIAL, NAME=M_alu", 2), ["*ELASTIC", "7.200000000000e+10, 3.300000000000e-01"]);
    assert_eq!(after(&deck, "*MATERIAL, NAME=M_steel", 4)[3], "7.850000000000e+03");
    assert_eq!(after(&deck, "*SURFACE BEHAVIOR, PRESSURE-OVERCLOSURE=LINEAR", 1), ["2.000000000000e+15"]);
    assert_eq!(after(&deck, "*FRICTION", 1), ["3.000000000000e-01, 4.000000000000e+13"]);
    assert_eq!(deck.matches("TYPE=SURFACE TO SURFACE").count(), 1);
    // the prestress in the static step, the pressure's history in the dynamic one, increments
    // capped at dt = 1 us over T = 0.1 ms, the alpha asked
    assert!(deck.contains("N_slider_zp, 3, 3, -2.000000000000e-05"), "{deck}");
    assert_eq!(
        after(&deck, "*AMPLITUDE, NAME=A_load0", 2),
        ["0.000000000000e+00, 0.000000000000e+00", "5.000000000000e-05, 1.000000000000e+00"]
    );
    assert_eq!(
        after(&deck, "*DYNAMIC, ALPHA=-0.1", 1),
        ["1.000000000000e-06, 1.000000000000e-04, 1.000000000000e-10, 1.000000000000e-06"]
    );
    assert_eq!(after(&deck, "*DLOAD, AMPLITUDE=A_load0", 1), ["E_load0, P6, 3.000000000000e+07"]);
    // the loaded face: the slider's elements at x- (i = 0 of its 2 x 2 x 3, numbered 9..20)
    assert_eq!(after(&deck, "*ELSET, ELSET=E_load0", 1), ["9, 11, 13, 15, 17, 19"]);

    // what it cannot write is refused, by name
    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, SCENE.replace("law = \"friction\"", "law = \"perfect\""))?;
    let out = run_with_timeout(
        Command::new("/usr/bin/python3").arg(script()).arg("deck").arg(&bad).args(["-o", "/dev/null"]),
        Duration::from_secs(30),
    );
    assert_eq!(out.status.code(), Some(1));
    assert!(text(&out.stderr).contains("interfaces[0].law = 'perfect'"), "{}", text(&out.stderr));
    Ok(())
}
