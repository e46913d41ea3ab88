//! The glissade-worker binary, run as users run it: P MPI ranks against one process, exit
//! codes and messages of `solve`, `refine` and `study`. The numerics it runs are verified in
//! glissade-solver's tests (solver/tests/verification.rs).

#[path = "../../solver/tests/fixtures/mod.rs"]
mod fixtures;

use std::process::Command;

fn scene_path(name: &str) -> String {
    format!("{}/../scenes/{name}", env!("CARGO_MANIFEST_DIR"))
}

/// Runs `mpiexec ARGS` (each rank a real process) with a time limit, so a hang fails the test.
fn mpiexec(args: &[&str]) -> std::process::Output {
    mpiexec_with(&[], args)
}

/// `mpiexec ARGS` with the environment variables `env` set for every rank.
fn mpiexec_with(env: &[(&str, &str)], args: &[&str]) -> std::process::Output {
    std::process::Command::new("timeout")
        .arg("120")
        .arg("mpiexec.mpich")
        .args(args)
        .envs(env.iter().copied())
        .output()
        .expect("mpiexec runs (deploy/install-deps.sh installs MPICH)")
}

fn worker_bin() -> &'static str {
    env!("CARGO_BIN_EXE_glissade-worker")
}

/// P = 1, 2, 3 ranks give bitwise identical results: same iterations, same QoIs, and the same
/// saved interface solution byte for byte (every reduction has one or two contributions per
/// entry, so the order of the sum does not matter). Three ranks wait yielding their core
/// (`GLISSADE_MPI_YIELD=1`, what a node with fewer cores than ranks does by itself: mpi_comm.rs),
/// two as the node decides (spinning on two cores or more): both ways give the same bits.
#[test]
fn mpi_ranks_give_bitwise_identical_solutions() {
    let dir = tempfile::tempdir().unwrap();
    let whole = scene_path("three-blocks-tiny.toml");
    // in time windows too: only the window's steps move between ranks (latin/distribution.rs)
    let windowed = dir.path().join("windowed.toml");
    let text = std::fs::read_to_string(&whole).unwrap();
    assert!(!text.contains("[solver]"), "the shipped scene sets no solver options");
    std::fs::write(&windowed, format!("{text}\n[solver]\ntime_window = 10\n")).unwrap();
    let windowed = windowed.to_str().unwrap().to_owned();
    // and a whole-interval solve checked by iterating on (its tightening decides on QoIs that
    // every rank holds after their reduction)
    let checked = dir.path().join("checked.toml");
    std::fs::write(&checked, format!("{text}\n[solver]\nwhole_interval_check = true\n")).unwrap();
    let checked = checked.to_str().unwrap().to_owned();
    // and a regularised friction law, whose nodes carry their memory from window to window on
    // the rank that owns their interface
    let regularised = dir.path().join("regularised.toml");
    let pc = "\nprakash_clifton = { length = 3e-5, velocity = 1.0 }";
    let text_pc = text
        .replace("friction = \"f1\"", &format!("friction = \"f1\"{pc}"))
        .replace("friction = \"f2\"", &format!("friction = \"f2\"{pc}"));
    assert_eq!(text_pc.matches("prakash_clifton").count(), 2);
    std::fs::write(&regularised, format!("{text_pc}\n[solver]\ntime_window = 10\n")).unwrap();
    let regularised = regularised.to_str().unwrap().to_owned();
    // and a 3D block cut in 4 on a friction floor: the nodes the cuts share on the floor follow
    // the law together, their pieces owned by one rank whatever rank holds their substructures
    let shared = dir.path().join("shared.toml");
    let block = std::fs::read_to_string(scene_path("sliding-block-3d.toml")).unwrap();
    assert!(block.contains("substructures = [2, 1, 1]") && !block.contains("joint_wall_nodes"));
    std::fs::write(&shared, block.replace("substructures = [2, 1, 1]", "substructures = [4, 1, 1]")).unwrap();
    let shared = shared.to_str().unwrap().to_owned();
    // and cuts along flat elements, whose local stage solves one system over each cut on the
    // rank that owns it (the search direction from node to node)
    let flat = dir.path().join("flat.toml");
    let block = std::fs::read_to_string(scene_path("sliding-block-2d.toml")).unwrap();
    assert!(["elements = [8, 4]", "substructures = [2, 1]", "steps = 100"].iter().all(|k| block.contains(k)));
    assert!(!block.contains("[solver]"));
    // (elements 0.25 mm along the cuts, 5 mm deep; 20 steps, unchecked: 3 ranks spin on 2 cores)
    let block = block
        .replace("elements = [8, 4]", "elements = [4, 40]")
        .replace("substructures = [2, 1]", "substructures = [4, 1]")
        .replace("steps = 100", "steps = 20");
    std::fs::write(&flat, format!("{block}\n[solver]\nwhole_interval_check = false\n")).unwrap();
    let flat = flat.to_str().unwrap().to_owned();
    for (scene, scale) in [
        (&whole, "single"),
        (&whole, "multi"),
        (&windowed, "single"),
        (&checked, "multi"),
        (&regularised, "single"),
        (&shared, "single"),
        (&flat, "multi"),
    ] {
        let mut reference: Option<(serde_json::Value, Vec<u8>)> = None;
        for np in ["1", "2", "3"] {
            let save = dir.path().join(format!("{scale}-{}-{np}.sol", scene.len()));
            let env: &[(&str, &str)] = if np == "3" { &[("GLISSADE_MPI_YIELD", "1")] } else { &[] };
            let out = mpiexec_with(
                env,
                &[
                    "-n",
                    np,
                    worker_bin(),
                    "solve",
                    scene,
                    "--scale",
                    scale,
                    "--tol",
                    // (a loose tolerance keeps the 21 runs short: the identity holds at any)
                    "1e-2",
                    "--json",
                    "--save",
                    save.to_str().unwrap(),
                ],
            );
            assert!(out.status.success(), "P = {np}: {}", String::from_utf8_lossy(&out.stderr));
            let stdout = String::from_utf8(out.stdout).unwrap();
            assert_eq!(stdout.lines().count(), 1, "only rank 0 prints: {stdout}");
            let json: serde_json::Value = serde_json::from_str(&stdout).unwrap();
            let bytes = std::fs::read(&save).unwrap();
            match &reference {
                None => reference = Some((json, bytes)),
                Some((j, b)) => {
                    assert_eq!(j["iterations"], json["iterations"], "{scale} P = {np}");
                    assert_eq!(j["error_indicator"], json["error_indicator"], "{scale} P = {np}");
                    assert_eq!(j["qoi"], json["qoi"], "{scale} P = {np}");
                    assert_eq!(j["window_check"], json["window_check"], "{scale} P = {np}");
                    assert!(*b == bytes, "{scale} P = {np}: saved solution differs from P = 1");
                }
            }
        }
    }
}

/// `solve --profile` on two real ranks: each rank's compute, wait, transfer and exchange add up
/// to the solve's own wall time (measured apart, in the solver's run) within 5 %; the stage
/// timers of the solver agree with it; what one rank sent the other received, byte for byte;
/// both saw the same collectives, one of them once a time step; and profiling changes nothing
/// in the answer.
#[test]
fn mpi_profile_adds_up_on_two_ranks() {
    let scene = scene_path("three-blocks-tiny.toml");
    let run = |profile: bool| {
        let mut args = vec!["-n", "2", worker_bin(), "solve", &scene, "--scale", "multi", "--tol", "1e-2", "--json"];
        if profile {
            args.push("--profile");
        }
        let out = mpiexec(&args);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        serde_json::from_slice::<serde_json::Value>(&out.stdout).expect("one JSON object")
    };
    let plain = run(false);
    let json = run(true);
    assert!(plain.get("profile").is_none(), "no profile unless asked");
    for key in ["iterations", "error_indicator", "qoi"] {
        assert_eq!(plain[key], json[key], "--profile changed {key}");
    }
    let p = &json["profile"];
    let ranks = p["ranks"].as_array().expect("a profile per rank");
    assert_eq!(ranks.len(), 2);
    let f = |r: &serde_json::Value, k: &str| r[k].as_f64().unwrap_or_else(|| panic!("{k} in {r}"));
    let wall = json["wall_seconds"].as_f64().unwrap();
    let t = &json["timings"];
    let stages: f64 = ["factorisation", "linear_stage", "local_stage", "post_processing"].iter().map(|k| f(t, k)).sum();
    for r in ranks {
        let sum = f(r, "compute") + f(r, "wait") + f(r, "transfer") + f(r, "exchange");
        assert!((sum - wall).abs() <= 0.05 * wall, "rank {r}: the terms add to {sum} s, the solve took {wall} s");
        for k in ["compute", "wait", "transfer", "exchange"] {
            assert!(f(r, k) >= 0.0, "{k} < 0: {r}");
        }
    }
    // rank 0's stage timers (factorisation, stages, post-processing) cover its wall time but
    // the model's build; its communication timer is part of what the profile counts
    assert!(stages <= wall && stages >= 0.5 * wall, "stages {stages} s of {wall} s");
    let r0 = &ranks[0];
    assert!(f(t, "communication") <= f(r0, "wait") + f(r0, "transfer") + f(r0, "exchange") + 1e-3);
    assert_eq!(ranks[0]["messages_sent"], ranks[1]["messages_received"]);
    assert_eq!(ranks[0]["bytes_sent"], ranks[1]["bytes_received"]);
    assert_eq!(ranks[1]["messages_sent"], ranks[0]["messages_received"]);
    assert_eq!(ranks[1]["bytes_sent"], ranks[0]["bytes_received"]);
    assert!(ranks[0]["messages_sent"].as_u64().unwrap() > 0);
    assert_eq!(ranks[0]["collectives"], ranks[1]["collectives"]);
    let last: u64 = ranks.iter().map(|r| r["last_to_arrive"].as_u64().unwrap()).sum();
    assert_eq!(last, ranks[0]["collectives"].as_u64().unwrap(), "one rank arrives last at each");
    // the macro right-hand side: one reduction a time step of every dynamic iteration
    let steps = json["time_steps"].as_u64().unwrap();
    let dynamic = json["iterations"].as_u64().unwrap() - json["static_stage"]["iterations"].as_u64().unwrap_or(0);
    let groups = p["collectives"].as_array().unwrap();
    assert!(groups.iter().any(|g| g["calls"].as_u64().unwrap() >= steps * dynamic), "a reduction a step: {groups:?}");
}

/// A rank that fails makes the whole job exit non-zero with the error on stderr, never a hang:
/// rank 1 gets a malformed scene (MPMD launch) while rank 0 starts solving a good one.
#[test]
fn mpi_failing_rank_stops_the_job() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, "dimension = 3\nbogus = 1\n").unwrap();
    let good = scene_path("three-blocks-tiny.toml");
    let out = mpiexec(&[
        "-n",
        "1",
        worker_bin(),
        "solve",
        &good,
        ":",
        "-n",
        "1",
        worker_bin(),
        "solve",
        bad.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_ne!(out.status.code(), Some(124), "the job hung");
    assert!(!out.status.success());
    assert!(stderr.contains("rank 1") && stderr.contains("bogus"), "{stderr}");
    // more ranks than substructures: every rank refuses, clearly
    let out = mpiexec(&["-n", "3", worker_bin(), "solve", &scene_path("sliding-block-2d.toml")]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && stderr.contains("at most 2 ranks"), "{stderr}");
}

/// `--fields` under P = 2 ranks gathers every substructure's history and every interface's
/// fields on rank 0: the written fields (the interfaces' pressure and slip too) equal the P = 1
/// ones value for value.
#[test]
fn mpi_fields_are_gathered_on_rank_zero() {
    let dir = tempfile::tempdir().unwrap();
    let scene = scene_path("three-blocks-tiny.toml");
    let read = |np: &str| -> [Vec<f64>; 4] {
        let h5 = dir.path().join(format!("p{np}.h5"));
        let out =
            mpiexec(&["-n", np, worker_bin(), "solve", &scene, "--tol", "1e-3", "--fields", h5.to_str().unwrap()]);
        assert!(out.status.success(), "P = {np}: {}", String::from_utf8_lossy(&out.stderr));
        let file = hdf5::File::open(&h5).unwrap();
        ["displacement/000050", "velocity/000025", "contact_pressure/000030", "slip/000050"]
            .map(|d| file.dataset(&format!("fields/{d}")).unwrap().read_raw().unwrap())
    };
    let one = read("1");
    let two = read("2");
    assert!(one[0].iter().any(|x| *x != 0.0) && one[2].iter().any(|x| *x != 0.0));
    assert_eq!(one, two);
}

/// A solve that runs out of iterations says which stage fell short and what it was held to (a
/// static stage stopped short used to be reported with the dynamic stage's eta, below the
/// tolerance), and exits with status 2. The static stage may iterate ten times the limit (its
/// iterations sweep one step): the sliding block with elements of aspect ratio 100 at its floor
/// needs 471 to reach 2e-11 and falls short at 5 x 10.
#[test]
fn a_solve_out_of_iterations_names_the_stage_that_fell_short() {
    let dir = tempfile::tempdir().unwrap();
    let flat = dir.path().join("flat.toml");
    std::fs::write(&flat, fixtures::SLIDING_BLOCK_2D.replace("elements = [8, 4]", "elements = [2, 100]")).unwrap();
    let flat = flat.to_string_lossy().into_owned();
    let tiny = scene_path("three-blocks-tiny.toml");
    for (scene, limit, stage, held_to) in [
        (&flat, "5", "static stage", "2.0e-11 (the tolerance x 0.0000001, no tighter than 1e-12) after 50 iterations"),
        (&tiny, "100", "dynamic stage", "tolerance 2.0e-4"),
    ] {
        let out = std::process::Command::new(worker_bin())
            .args(["solve", scene, "--max-iter", limit])
            .output()
            .expect("the worker runs");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "limit {limit}: {err}");
        let line = err.lines().last().unwrap_or_default();
        assert!(
            line.starts_with(&format!("error: not converged: the {stage} did not converge")),
            "limit {limit}: {line}"
        );
        assert!(line.contains(held_to), "limit {limit}: {line}");
    }
}

/// `refine` refuses a ladder it cannot extrapolate, and h on a mesh body, before any solve.
#[test]
fn refine_refuses_bad_ladders_at_once() {
    let scene = scene_path("bar-impact-1d.toml");
    for (args, says) in [
        (vec!["--dt", "1,3,4"], "refinement factors must be"),
        (vec!["--dt", "2,4"], "refinement factors must be"),
        (vec!["--dt", "1,2", "--h", "1"], "refinement factors must be"),
        (vec!["--dt", "1,100000000"], "more than the 200000 steps"),
    ] {
        let out = std::process::Command::new(worker_bin())
            .args(["refine", &scene])
            .args(&args)
            .output()
            .expect("the worker runs");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {err}");
        assert!(err.contains(says), "{args:?}: {err}");
    }
    let out = std::process::Command::new(worker_bin())
        .args(["refine", &scene_path("bolted-joint-tiny.toml"), "--dt", "1,2", "--h", "1,2"])
        .output()
        .expect("the worker runs");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("read from a mesh file"), "{err}");
}

/// A windowed solve says so, with its work in sweeps of the interval (its iterations each sweep
/// a window of one step only, so their count alone would overstate the work 200 times here), and
/// says how its check against another windowing went.
#[test]
fn the_cli_reports_a_windowed_solves_work_in_sweeps() {
    let out = std::process::Command::new(worker_bin())
        .args(["solve", &scene_path("three-blocks-tiny-200.toml"), "--tol", "1e-2"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}{}", String::from_utf8_lossy(&out.stderr));
    let line = text.lines().find(|l| l.contains("time windows:")).unwrap_or_else(|| panic!("no windows line: {text}"));
    assert!(line.contains("200 of 1 steps") && line.contains("sweeps of the interval"), "{line}");
    let sweeps: f64 = line.split("work ").nth(1).and_then(|r| r.split(' ').next()).unwrap().parse().unwrap();
    let iterations: f64 = text.split("after ").nth(1).and_then(|r| r.split(' ').next()).unwrap().parse().unwrap();
    assert!(sweeps > 0.0 && sweeps < iterations / 100.0, "{sweeps} sweeps for {iterations} iterations");
    // and that it was checked against another windowing, whose work the sweeps include
    let check =
        text.lines().find(|l| l.contains("checked in windows of")).unwrap_or_else(|| panic!("no check: {text}"));
    assert!(check.contains("1 and 2 steps") && check.contains("the answers agree by"), "{check}");
}

/// A magnesium block of our own pushed along a rigid floor at f = 0.4: its contact lands while it
/// slides (119 times), and the solve's text names the regularisation that damps that chatter;
/// regularised, the block converges, does not land, and the line is not printed.
#[test]
fn the_cli_names_the_regularisation_where_a_contact_chatters() {
    const MAGNESIUM_BLOCK: &str = r#"
dimension = 2
[time]
duration = 5e-4
steps = 250
[parameters]
f = { default = 0.4, min = 0.0, max = 1.0 }
[materials.mg]
E = 45e9
nu = 0.35
rho = 1740
[[bodies]]
name = "block"
material = "mg"
size = [0.02, 0.01]
elements = [8, 4]
substructures = [2, 1]
[[interfaces]]
name = "floor"
a = "block.y-"
b = "wall"
law = "friction"
friction = "f"
[[loads]]
face = "block.y+"
pressure = 4e6
[[loads]]
face = "block.x-"
traction = [7e6, 0]
history = [[0, 0], [5e-4, 1]]
[[qoi]]
name = "slip"
kind = "slip"
interface = "floor"
point = [0.01, 0]
"#;
    let dir = tempfile::tempdir().unwrap();
    let run = |name: &str, text: &str| {
        let path = dir.path().join(name);
        std::fs::write(&path, text).unwrap();
        let (code, stdout, _) = worker(&["solve", path.to_str().unwrap()]);
        (code == 0, stdout)
    };
    let (_, coulomb) = run("coulomb.toml", MAGNESIUM_BLOCK);
    let hint = "`prakash_clifton` on interface 'floor' damps the chatter";
    assert!(coulomb.contains("lifted off and landed") && coulomb.contains(hint), "{coulomb}");
    let regularised = MAGNESIUM_BLOCK
        .replace("friction = \"f\"", "friction = \"f\"\nprakash_clifton = { length = 3e-5, velocity = 1.0 }");
    let (converged, text) = run("regularised.toml", &regularised);
    assert!(converged && !text.contains("lifted off and landed") && !text.contains(hint), "{text}");
}

/// `refine --accuracy` climbs the levels `solve --accuracy` climbs, on a bar of our own
/// (aluminium, 0.3 m, 6 elements in 2 substructures, 20 steps, its tip's velocity read too): the
/// same levels, the same choice and values, printed as ladders; every QoI within the accuracy of a
/// solve two levels finer in dt and h at 1e-8; `--dt`, `--h` and `--tol` are refused beside it.
/// The tip's velocity (trapezoidal rule, no contact) moves about 0.35 % at each halving of dt and
/// h together from dt / 4, h / 4 on: 5 % is reached, 2 % is not claimed.
#[test]
fn refine_to_an_accuracy_prints_the_ladders_solve_climbs() {
    let dir = tempfile::tempdir().unwrap();
    let bar = |steps: u64, elements: u64| {
        let scene = PRESSED_STEEL_BAR
            .replace("E = \"E\"\nrho = 7800", "E = 70e9\nrho = 2700")
            .replace("size = [0.2]", "size = [0.3]")
            .replace("elements = [10]", &format!("elements = [{elements}]"))
            .replace("steps = 15", &format!("steps = {steps}"))
            .replace("duration = 1.5e-4", "duration = 2e-4")
            .replace("point = [0.2]", "point = [0.3]")
            .replace("point = [0.04]", "point = [0.1]")
            + "[[qoi]]\nname = \"tip_vx\"\nkind = \"velocity\"\nbody = \"bar\"\npoint = [0.3]\ncomponent = \"x\"\n";
        assert!(scene.contains("70e9") && scene.contains("[0.3]") && scene.contains("[0.1]"), "{scene}");
        let path = dir.path().join(format!("al-bar-{steps}-{elements}.toml"));
        std::fs::write(&path, scene).unwrap();
        path.to_str().unwrap().to_owned()
    };
    let scene = bar(20, 6);
    let accuracy = 5e-2;
    let (code, refined, stderr) = worker(&["refine", &scene, "--set", "p=3e7", "--accuracy", "5e-2", "--json"]);
    assert_eq!(code, 0, "{stderr}");
    let refined: serde_json::Value = serde_json::from_str(&refined).unwrap();
    let (code, solved, stderr) = worker(&["solve", &scene, "--set", "p=3e7", "--accuracy", "5e-2", "--json"]);
    assert_eq!(code, 0, "{stderr}");
    let solved: serde_json::Value = serde_json::from_str(&solved).unwrap();
    let solved = &solved["accuracy"];
    let levels = |r: &serde_json::Value| -> Vec<(u64, u64, bool)> {
        r["levels"]
            .as_array()
            .unwrap()
            .iter()
            .map(|l| (l["time_factor"].as_u64().unwrap(), l["mesh_factor"].as_u64().unwrap(), l["converged"] == true))
            .collect()
    };
    assert_eq!(levels(&refined), levels(solved));
    assert!(levels(&refined).len() >= 5, "three steps and two meshes at least: {:?}", levels(&refined));
    for key in ["reached", "time_factor", "mesh_factor", "tolerance", "qois"] {
        assert_eq!(refined[key], solved[key], "{key}");
    }

    // the answer against a solve two levels finer in both, far tighter
    let (tf, mf) = (refined["time_factor"].as_u64().unwrap(), refined["mesh_factor"].as_u64().unwrap());
    let (code, reference, stderr) =
        worker(&["solve", &bar(20 * tf * 4, 6 * mf * 4), "--set", "p=3e7", "--tol", "1e-8", "--json"]);
    assert_eq!(code, 0, "{stderr}");
    let reference: serde_json::Value = serde_json::from_str(&reference).unwrap();
    let qois = refined["qois"].as_array().unwrap();
    assert_eq!(qois.len(), 3);
    for q in qois {
        let name = q["name"].as_str().unwrap();
        let truth = reference["qoi"][name]["final"].as_f64().unwrap();
        let off = (q["value"].as_f64().unwrap() - truth).abs() / q["scale"].as_f64().unwrap();
        assert!(off <= accuracy && off <= q["total"].as_f64().unwrap(), "{name}: {off} off, estimated {}", q["total"]);
    }

    let (code, table, stderr) = worker(&["refine", &scene, "--set", "p=3e7", "--accuracy", "5e-2"]);
    assert_eq!(code, 0, "{stderr}");
    assert!(table.contains("dt ladder (dt / 1, 2, 4") && table.contains("h ladder (h / 1, 2"), "{table}");
    assert!(table.contains("dt and h halved together ((dt / k, h / k), k = 1, 2, 4"), "{table}");
    assert!(table.contains(&format!("REACHED at dt / {tf}, h / {mf}")), "{table}");
    for q in qois {
        let name = q["name"].as_str().unwrap();
        for ladder in ["time", "mesh", "joint"] {
            let l = &q[ladder];
            let finals: Vec<String> =
                l["finals"].as_array().unwrap().iter().map(|v| format!("{:.6e}", v.as_f64().unwrap())).collect();
            let line = table
                .lines()
                .find(|line| line.trim_start().starts_with(&format!("{name} ")) && line.contains(&finals.join("  ")))
                .unwrap_or_else(|| panic!("{name}'s {ladder} ladder {finals:?}: {table}"));
            assert!(line.contains(&format!("{:.2e}", l["estimate"].as_f64().unwrap())), "{line}");
        }
    }
    for (args, says) in [
        (vec!["--accuracy", "0.01", "--dt", "1,2"], "cannot be used with"),
        (vec!["--accuracy", "0.01", "--h", "1,2"], "cannot be used with"),
        (vec!["--accuracy", "0.01", "--tol", "1e-6"], "cannot be used with"),
        (vec!["--max-dt-factor", "4"], "--accuracy"),
        (vec!["--accuracy", "2"], "give an accuracy between"),
    ] {
        let (code, _, stderr) = worker(&[&["refine", &scene][..], &args].concat());
        assert!(code == 1 || code == 2, "{args:?}: {code} {stderr}");
        assert!(stderr.contains(says) && !stderr.contains("converged after"), "{args:?}: {stderr}");
    }

    // at 2 % the tip's velocity, still moving, is not claimed (exit status 3)
    let (code, _, stderr) = worker(&["solve", &scene, "--set", "p=3e7", "--accuracy", "2e-2"]);
    assert_eq!(code, 3, "{stderr}");
    assert!(stderr.contains("accuracy not reached: 'tip_vx' is estimated"), "{stderr}");
}

/// An aluminium bar of our own flying at 1 m/s onto a rigid wall across a gap `g`: the pilot at
/// the centre of the box never reaches the wall (free flight, the same at every level), the
/// corner g = 0 strikes it at once.
const FLYING_AL_BAR: &str = r#"
dimension = 1
[time]
duration = 4e-5
steps = 40
[parameters]
g = { default = 1e-5, min = 0.0, max = 1e-4, unit = "m" }
[materials.al]
E = 70e9
rho = 2700
[[bodies]]
name = "bar"
material = "al"
size = [0.05]
elements = [10]
substructures = [2]
initial_velocity = [1.0]
[[interfaces]]
name = "impact"
a = "bar.x+"
b = "wall"
law = "contact"
gap = "g"
[[qoi]]
name = "tip_ux"
kind = "displacement"
body = "bar"
point = [0.05]
component = "x"
"#;

/// `study --accuracy` whose held-out check says ABOVE solves its grid again one level finer: the
/// free-flying pilot bounds the scene's own level, the struck corner moves 5.2 % one level finer,
/// then 3.1 % (above half the accuracy: this corner converges at order 0.7), then 2.0 %: the
/// check confirms at dt / 4, h / 4, and the struck point is within the accuracy of a solve two
/// levels finer at 1e-8. At 2 % it climbs to the limits and says NOT CONFIRMED.
#[test]
fn a_study_whose_held_out_check_says_above_is_solved_again_one_level_finer() {
    let dir = tempfile::tempdir().unwrap();
    let bar = dir.path().join("flying.toml");
    std::fs::write(&bar, FLYING_AL_BAR).unwrap();
    let bar = bar.to_str().unwrap();
    let study = |accuracy: &str| {
        let (code, stdout, stderr) = worker(&[
            "study",
            bar,
            "--grid",
            "g=0:1e-4:5",
            "--accuracy",
            accuracy,
            "--pilots",
            "1",
            "--held-out",
            "2",
            "--json",
        ]);
        (code, serde_json::from_str::<serde_json::Value>(&stdout).unwrap(), stderr)
    };
    let (code, out, stderr) = study("0.05");
    assert_eq!(code, 0, "{stderr}");
    let a = &out["accuracy"];
    assert_eq!(a["above"], serde_json::json!([[1, 1], [2, 2]]), "{a}");
    assert_eq!(
        (a["time_factor"].as_u64(), a["mesh_factor"].as_u64(), &a["confirmed"]),
        (Some(4), Some(4), &serde_json::json!(true))
    );
    assert!(stderr.contains("[above]") && stderr.contains("ABOVE") && stderr.contains("confirms"), "{stderr}");
    // the struck corner: the study's value is the grid's at dt / 4, h / 4, its difference the check's
    let struck = a["held_out"].as_array().unwrap().iter().find(|c| c["point"]["g"] == 0.0).expect("g = 0 held out");
    assert_eq!((struck["time_factor"].as_u64(), struck["mesh_factor"].as_u64()), (Some(8), Some(8)));
    let q = &struck["qois"][0];
    let (mine, finer, scale) =
        (q["study"].as_f64().unwrap(), q["finer"].as_f64().unwrap(), q["scale"].as_f64().unwrap());
    assert!(((mine - finer).abs() / scale - q["difference"].as_f64().unwrap()).abs() < 1e-12, "{q}");
    let record = out["records"].as_array().unwrap().iter().find(|r| r["point"]["g"] == 0.0).unwrap();
    assert_eq!(record["qoi"]["tip_ux"].as_f64(), Some(mine));
    // against a solve two levels finer (dt / 16, h / 16) at 1e-8
    let reference = dir.path().join("reference.toml");
    std::fs::write(
        &reference,
        FLYING_AL_BAR
            .replace("steps = 40", "steps = 640\nnewmark_gamma = 0.55")
            .replace("elements = [10]", "elements = [160]"),
    )
    .unwrap();
    let (code, r, stderr) = worker(&["solve", reference.to_str().unwrap(), "--set", "g=0", "--tol", "1e-8", "--json"]);
    assert_eq!(code, 0, "{stderr}");
    let r: serde_json::Value = serde_json::from_str(&r).unwrap();
    let truth = r["qoi"]["tip_ux"]["final"].as_f64().unwrap();
    let truth_scale =
        r["qoi"]["tip_ux"]["values"].as_array().unwrap().iter().fold(0.0f64, |m, v| m.max(v.as_f64().unwrap().abs()));
    assert!((mine - truth).abs() / truth_scale <= 0.05, "{mine} against {truth} (scale {truth_scale})");

    let (code, out, stderr) = study("0.02");
    assert_eq!(code, 3, "{stderr}");
    let a = &out["accuracy"];
    // (h / 16 is the 1D limit: the check at dt / 32, h / 32 would pass it)
    assert_eq!(
        (&a["above"], &a["confirmed"]),
        (&serde_json::json!([[1, 1], [2, 2], [4, 4], [8, 8]]), &serde_json::json!(false)),
        "{a}"
    );
    assert!(stderr.contains("accuracy not confirmed: at the held-out point g=0"), "{stderr}");
}

// ---------------------------------------------------------------------------------------------
// The study command.

fn worker(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_glissade-worker"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("glissade-worker runs");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into(),
        String::from_utf8_lossy(&out.stderr).into(),
    )
}

/// A rank's way of waiting is set by `GLISSADE_MPI_YIELD` as 1 or 0; anything else is refused
/// before any work, in one line that names the variable.
#[test]
fn a_bad_yield_setting_is_refused_in_one_line() {
    let out = Command::new(worker_bin())
        .args(["solve", &scene_path("three-blocks-tiny.toml")])
        .env("GLISSADE_MPI_YIELD", "sometimes")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(out.stdout.is_empty());
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
    assert!(stderr.contains("GLISSADE_MPI_YIELD=\"sometimes\"") && stderr.contains("give 1"), "{stderr}");
}

#[test]
fn study_command_refuses_bad_input_in_one_line() {
    let tiny = "../scenes/three-blocks-tiny.toml";
    for (args, needle) in [
        (vec!["study", tiny], "no design points"),
        (vec!["study", tiny, "--grid", "f1=0.2:0.1:0"], "f1=0.2:0.1:0"),
        (vec!["study", tiny, "--grid", "f1=0.2:0.1:3"], "above STOP"),
        (vec!["study", tiny, "--grid", "mu=0.1"], "no parameter 'mu'"),
        (vec!["study", tiny, "--grid", "f1=NaN"], "not a finite number"),
        (vec!["study", tiny, "--grid", "f1=0.1", "--tol", "0"], "--tol"),
        (vec!["study", "no-such-scene.toml", "--grid", "f1=0.1"], "no-such-scene.toml"),
    ] {
        let (code, stdout, stderr) = worker(&args);
        assert_eq!(code, 1, "{args:?}: {stderr}");
        assert!(stdout.is_empty(), "{args:?}: {stdout}");
        assert_eq!(stderr.trim().lines().count(), 1, "{args:?}: {stderr}");
        assert!(stderr.starts_with("error: ") && stderr.contains(needle), "{args:?}: {stderr}");
    }
}

#[test]
fn study_command_writes_its_tables() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let (code, stdout, stderr) = worker(&[
        "study",
        "../scenes/three-blocks-tiny.toml",
        "--grid",
        "f1=0.15:0.2:2",
        "--grid",
        "f2=0.2",
        "--strategy",
        "previous",
        "--order",
        "desc",
        "--tol",
        "1e-3",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("2 points (2 converged") && stdout.contains("first point"), "{stdout}");
    assert_eq!(stderr.lines().filter(|l| l.starts_with("[")).count(), 2, "one progress line per point: {stderr}");
    let csv = std::fs::read_to_string(out.join("results.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), 3);
    assert!(lines[0].starts_with("index,sequence,f1,f2,pressure,prestress,status,converged,iterations"));
    // descending: f1 = 0.2 first (cold), then f1 = 0.15 from it
    assert!(lines[1].starts_with("0,1,0.15,0.2,") && lines[1].contains("previous #0"), "{csv}");
    assert!(lines[2].starts_with("1,0,0.2,0.2,") && lines[2].contains(",cold,"), "{csv}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("results.json")).unwrap()).unwrap();
    assert_eq!(json["summary"]["points"], 2);
    assert_eq!(json["records"][1]["sources"][0]["id"], 0);
}

// ---------------------------------------------------------------------------------------------
// `solve --accuracy`.

/// A steel block pushed along a rigid floor hard enough to chatter as it slides (10 MPa on
/// 24 x 12 mm, f = 0.4): under the Newmark gamma a solve to accuracy takes for contact (0.55) its
/// slip moves 4 % from 200 to 400 steps and 14 % to 800 (9-10 % each time under the trapezoidal
/// rule).
const CHATTERING_STEEL_BLOCK: &str = r#"
dimension = 2
[time]
duration = 4e-4
steps = 200
[parameters]
f = { default = 0.4, min = 0.0, max = 10.0 }
[materials.steel]
E = 210e9
nu = 0.28
rho = 7850
[[bodies]]
name = "block"
material = "steel"
size = [0.024, 0.012]
elements = [6, 3]
substructures = [2, 1]
[[interfaces]]
name = "floor"
a = "block.y-"
b = "wall"
law = "friction"
friction = "f"
[[loads]]
face = "block.y+"
pressure = 8e6
history = [[0, 0], [8e-5, 1]]
[[loads]]
face = "block.x-"
traction = [1e7, 0]
history = [[0, 0], [4e-4, 1]]
[[qoi]]
name = "slip"
kind = "slip"
interface = "floor"
point = [0.012, 0]
[[qoi]]
name = "corner_ux"
kind = "displacement"
body = "block"
point = [0.024, 0.012]
component = "x"
"#;

/// An accuracy the ladder cannot reach is said so: exit status 3, every level converged, the
/// QoI above it named with its parts, the answer the finest level's; its flags are checked
/// before any solve.
#[test]
fn an_accuracy_out_of_reach_is_reported_with_its_ladder() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("chatter.toml");
    std::fs::write(&path, CHATTERING_STEEL_BLOCK).unwrap();
    let scene = path.to_str().unwrap();
    let (code, stdout, stderr) =
        worker(&["solve", scene, "--accuracy", "0.02", "--max-dt-factor", "4", "--max-h-factor", "1", "--json"]);
    assert_eq!(code, 3, "{stderr}");
    assert_eq!(stderr.matches("converged after").count(), 3, "three levels, each converged: {stderr}");
    assert!(stderr.contains("accuracy not reached: '") && stderr.contains("the mesh was kept"), "{stderr}");
    let out: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let a = &out["accuracy"];
    assert_eq!(
        (a["reached"].as_bool(), a["time_factor"].as_u64(), a["mesh_factor"].as_u64()),
        (Some(false), Some(4), Some(1))
    );
    assert_eq!(out["time_steps"].as_u64(), Some(800), "the answer is the finest level's");
    assert!((a["tolerance"].as_f64().unwrap() - 4e-4).abs() < 1e-15 && out["tolerance"] == a["tolerance"]);
    assert_eq!(a["newmark_gamma"].as_f64(), Some(0.55), "a contact scene without a gamma of its own");
    for q in a["qois"].as_array().unwrap() {
        let name = q["name"].as_str().unwrap();
        assert_eq!(q["value"], out["qoi"][name]["final"], "{name}");
        assert_eq!(q["time"]["finals"].as_array().unwrap().len(), 3);
        assert!(q["total"].as_f64().unwrap() > 0.02 && q["within"] == false, "{q}");
    }
    // two levels observe no order: the table, and why it stops there
    let (code, stdout, stderr) =
        worker(&["solve", scene, "--accuracy", "0.1", "--max-dt-factor", "2", "--max-h-factor", "1"]);
    assert_eq!(code, 3, "{stderr}");
    assert!(stdout.contains("NOT REACHED at dt / 2 (mesh kept)") && stdout.contains("~"), "{stdout}");
    assert!(stderr.contains("the dt ladder needs 3 levels (dt / 4) and may go to dt / 2 only"), "{stderr}");
    for (args, says) in [
        (vec!["--accuracy", "0.7"], "give an accuracy between"),
        (vec!["--accuracy", "0"], "give an accuracy between"),
        (vec!["--accuracy", "0.1", "--max-dt-factor", "3"], "--max-dt-factor 3: give a power of 2"),
        (vec!["--accuracy", "0.1", "--tol", "1e-3"], "cannot be used with"),
        (vec!["--max-h-factor", "2"], "--accuracy"),
    ] {
        let (code, _, stderr) = worker(&[&["solve", scene][..], &args].concat());
        assert!(code == 1 || code == 2, "{args:?}: {code} {stderr}");
        assert!(stderr.contains(says) && !stderr.contains("converged after"), "{args:?}: {stderr}");
    }
}

/// A clamped steel bar of our own (0.2 m, 10 elements, 2 substructures) under an end pressure `p`
/// rising along a sampled 1 - cos over 80 us: no contact.
const PRESSED_STEEL_BAR: &str = r#"
dimension = 1
[time]
duration = 1.5e-4
steps = 15
[parameters]
p = { default = 4e7, min = 1e7, max = 1e8, unit = "Pa" }
E = { default = 200e9, min = 100e9, max = 300e9, unit = "Pa" }
[materials.steel]
E = "E"
rho = 7800
[[bodies]]
name = "bar"
material = "steel"
size = [0.2]
elements = [10]
substructures = [2]
[[boundary]]
face = "bar.x-"
clamped = true
[[loads]]
face = "bar.x+"
pressure = "p"
history = [[0, 0], [2e-5, 0.146], [4e-5, 0.5], [6e-5, 0.854], [8e-5, 1], [1.5e-4, 1]]
[[qoi]]
name = "tip_ux"
kind = "displacement"
body = "bar"
point = [0.2]
component = "x"
[[qoi]]
name = "quarter_ux"
kind = "displacement"
body = "bar"
point = [0.04]
component = "x"
"#;

/// `study --accuracy`: three pilots solved to the accuracy choose the level, the grid is solved
/// there at the accuracy's tolerance (a pilot's answer and the study's at the same point agree),
/// and the held-out points re-solved one level finer confirm it; a study whose pilot cannot reach
/// its accuracy picks no level and solves no point.
#[test]
fn a_study_to_an_accuracy_takes_its_level_from_pilots_and_confirms_it_on_held_out_points() {
    let dir = tempfile::tempdir().unwrap();
    let bar = dir.path().join("bar.toml");
    std::fs::write(&bar, PRESSED_STEEL_BAR).unwrap();
    let (code, stdout, stderr) =
        worker(&["study", bar.to_str().unwrap(), "--grid", "p=2e7:8e7:4", "--accuracy", "1e-2", "--json"]);
    assert_eq!(code, 0, "{stderr}");
    let out: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let a = &out["accuracy"];
    assert_eq!(a["confirmed"], true, "{a}");
    assert!((out["tolerance"].as_f64().unwrap() - 2e-4).abs() < 1e-15, "the accuracy's tolerance");
    let (tf, mf) = (a["time_factor"].as_u64().unwrap(), a["mesh_factor"].as_u64().unwrap());
    let pilots = a["pilots"].as_array().unwrap();
    assert_eq!(pilots.len(), 3);
    // the level: the finest of the pilots' cheapest levels within the accuracy, cheaper than the
    // levels the pilots answered at (their ladders had to climb past it to see it)
    let factor = |r: &serde_json::Value, key: &str| r[key].as_u64().unwrap();
    let cheapest: Vec<(u64, u64)> = pilots
        .iter()
        .map(|p| (factor(&p["report"]["cheapest"], "time_factor"), factor(&p["report"]["cheapest"], "mesh_factor")))
        .collect();
    // (where the held-out check says ABOVE there, the grid is solved again one level finer in
    // both: the pilots' dt and h together put dt / 2, h there, 9.6e-3 bounded, and the check
    // finds quarter_ux 8.4e-3 from dt / 4, h / 2, above half the accuracy)
    let above: Vec<(u64, u64)> =
        a["above"].as_array().unwrap().iter().map(|l| (l[0].as_u64().unwrap(), l[1].as_u64().unwrap())).collect();
    let first = above.first().copied().unwrap_or((tf, mf));
    assert_eq!(first, cheapest.iter().fold((1, 1), |(t, m), &(pt, pm)| (t.max(pt), m.max(pm))));
    if let Some(&(k, m)) = above.last() {
        assert_eq!((tf, mf), (2 * k, 2 * m), "{above:?}");
    }
    assert!(
        pilots.iter().all(|p| tf * mf < factor(&p["report"], "time_factor") * factor(&p["report"], "mesh_factor")),
        "dt / {tf}, h / {mf}: {pilots:?}"
    );
    // each pilot's point as the study solved it, within the accuracy of the pilot's finer answer
    let records = out["records"].as_array().unwrap();
    for p in pilots {
        let r = &p["report"];
        assert_eq!(r["reached"], true);
        let record = records.iter().find(|rec| rec["point"] == p["point"]).expect("a pilot is a point of the grid");
        for q in r["qois"].as_array().unwrap() {
            let (pilot, study) =
                (q["value"].as_f64().unwrap(), record["qoi"][q["name"].as_str().unwrap()].as_f64().unwrap());
            assert!((pilot - study).abs() <= 1e-2 * q["scale"].as_f64().unwrap(), "{q}: {pilot} against {study}");
        }
    }
    let held = a["held_out"].as_array().unwrap();
    assert_eq!(held.len(), 1, "four points, three pilots: one held out");
    for c in held {
        assert_eq!((c["time_factor"].as_u64(), c["within"].as_bool()), (Some(2 * tf), Some(true)), "{c}");
        assert!(pilots.iter().all(|p| p["point"] != c["point"]), "held out, not a pilot");
        for q in c["qois"].as_array().unwrap() {
            assert!(q["difference"].as_f64().unwrap() <= 1e-2, "{q}");
        }
    }
    assert!(stderr.contains("[pilot 3/3]") && stderr.contains("[held out]") && stderr.contains("confirms"), "{stderr}");

    let block = dir.path().join("chatter.toml");
    std::fs::write(&block, CHATTERING_STEEL_BLOCK).unwrap();
    let (code, stdout, stderr) = worker(&[
        "study",
        block.to_str().unwrap(),
        "--grid",
        "f=0.35,0.4",
        "--accuracy",
        "0.02",
        "--pilots",
        "1",
        "--max-dt-factor",
        "4",
        "--max-h-factor",
        "1",
        "--json",
    ]);
    assert_eq!(code, 3, "{stderr}");
    let out: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert!(out.get("records").is_none() && out["accuracy"]["confirmed"] == false, "{out}");
    assert!(stderr.contains("no level is chosen") && !stderr.contains("[1/2]"), "{stderr}");
}
