//! `glissade-worker solve`: warm starts from saved solutions, solution files, field output, bad input.

use crate::common::*;

#[test]
fn worker_warm_start_from_a_saved_solution_converges_within_two_windows() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let scene = bar_scene();
    let cold = converged_json(&worker_solve(dir.path(), &[scene.as_os_str(), os("--json"), os("--save"), os("s.bin")]));
    assert_eq!(cold["initialised_from"], serde_json::Value::Null, "{cold}");
    assert_eq!(cold["saved_to"], "s.bin", "{cold}");
    assert!(cold["iterations"].as_u64().unwrap() > 10, "a cold start should need iterations: {cold}");
    // every QoI with its unit (a 1D bar: velocities, and the wall's force per cross-section)
    let units = serde_json::json!({"free_end_velocity": "m/s", "tip_velocity": "m/s", "wall_force": "Pa"});
    assert_eq!(cold["units"], units);
    // times as decimals: 3 x 2e-7 is 6e-7, not 6.000000000000001e-7
    assert_eq!(cold["qoi"]["tip_velocity"]["times"][3].as_f64(), Some(6e-7), "{cold}");
    let bytes = std::fs::read(dir.path().join("s.bin"))?;
    assert_eq!(&bytes[..8], b"GLISSOL\0");

    let warm = converged_json(&worker_solve(dir.path(), &[scene.as_os_str(), os("--json"), os("--init"), os("s.bin")]));
    assert_eq!(warm["initialised_from"], "s.bin", "{warm}");
    assert_eq!(warm["scene_hash"], cold["scene_hash"]);
    // the stopping test measures the contraction over two windows of iterations before it trusts
    // a small change; the bar (400 steps, a contact) is iterated in time windows, so its work is
    // counted in sweeps of the interval (measured: 4.0 warm, 22.0 cold in windows of one step)
    let sweeps = warm["dynamic_sweeps"].as_f64().unwrap();
    let windows = 2.0 * glissade_solver::latin::stopping::WINDOW as f64 + 2.0;
    assert!(sweeps <= windows, "warm start from the converged solution took {sweeps} sweeps");
    assert!(sweeps * 4.0 <= cold["dynamic_sweeps"].as_f64().unwrap(), "{sweeps} sweeps warm: {cold}");

    // Both runs satisfy the same tolerance, so their QoIs agree to about its size: allow 10x the
    // tolerance, relative to each QoI's largest magnitude over time (a final value may be 0).
    let tol = cold["tolerance"].as_f64().unwrap();
    let qoi = cold["qoi"].as_object().unwrap();
    assert!(!qoi.is_empty());
    for (name, q) in qoi {
        let scale = q["values"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap().abs()).fold(0.0, f64::max);
        let (a, b) = (q["final"].as_f64().unwrap(), warm["qoi"][name]["final"].as_f64().unwrap());
        assert!((a - b).abs() <= 10.0 * tol * scale, "{name}: cold {a}, warm {b} (scale {scale}, tolerance {tol})");
    }

    // Not converged within the limit: exit 2, and the last iterate is still saved, marked so.
    let out = worker_solve(
        dir.path(),
        &[scene.as_os_str(), os("--json"), os("--max-iter"), os("3"), os("--save"), os("partial.bin")],
    );
    assert_eq!(out.status.code(), Some(2), "stderr: {}", text(&out.stderr));
    let partial: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    assert_eq!(partial["converged"], false, "{partial}");
    let bytes = std::fs::read(dir.path().join("partial.bin"))?;
    let header_len = u64::from_le_bytes(bytes[12..20].try_into()?) as usize;
    let header: serde_json::Value = serde_json::from_slice(&bytes[20..20 + header_len])?;
    assert_eq!(header["converged"], false, "{header}");
    assert_eq!(header["error_indicator"], partial["error_indicator"], "{header}");
    Ok(())
}

#[test]
fn worker_refuses_a_solution_of_another_scene() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let original = std::fs::read_to_string(bar_scene())?;
    let modified = original.replace("elements = [100]", "elements = [50]");
    assert_ne!(modified, original, "the scene no longer has `elements = [100]`");
    std::fs::write(dir.path().join("coarse.toml"), modified)?;
    let out = worker_solve(dir.path(), &[os("coarse.toml"), os("--save"), os("coarse.bin")]);
    assert_eq!(out.status.code(), Some(0), "stderr: {}", text(&out.stderr));

    let out = worker_solve(dir.path(), &[bar_scene().as_os_str(), os("--json"), os("--init"), os("coarse.bin")]);
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "stderr: {stderr}");
    assert!(out.stdout.is_empty(), "stdout: {}", text(&out.stdout));
    assert_eq!(stderr.lines().count(), 1, "one line expected: {stderr}");
    assert!(stderr.starts_with("error: --init coarse.bin: ") && stderr.contains("scene hash"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");

    // not a solution file at all
    let out = worker_solve(dir.path(), &[bar_scene().as_os_str(), os("--init"), os("coarse.toml")]);
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "stderr: {stderr}");
    assert!(stderr.contains("not a glissade solution file"), "{stderr}");
    Ok(())
}

#[test]
fn worker_writes_fields_as_hdf5_and_xdmf() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let out = worker_solve(dir.path(), &[bar_scene().as_os_str(), os("--json"), os("--fields"), os("out.h5")]);
    let v = converged_json(&out);
    assert_eq!(v["fields"]["h5"], "out.h5", "{v}");
    assert_eq!(v["fields"]["xdmf"], "out.xdmf", "{v}");
    let xdmf = std::fs::read_to_string(dir.path().join("out.xdmf"))?;
    assert_eq!(xdmf.matches("<Grid Name=\"step ").count(), BAR_STEPS + 1);
    assert!(xdmf.contains(r#"TopologyType="Polyline" NodesPerElement="2" NumberOfElements="100""#));

    let file = hdf5::File::open(dir.path().join("out.h5"))?;
    assert_eq!(file.dataset("mesh/coordinates")?.shape(), vec![BAR_FIELD_NODES, 3]);
    assert_eq!(file.dataset("mesh/topology")?.shape(), vec![100, 2]);
    let time: Vec<f64> = file.dataset("time")?.read_raw()?;
    assert_eq!(time.len(), BAR_STEPS + 1);
    assert!((time[BAR_STEPS] - 8e-5).abs() < 1e-18, "final time {}", time[BAR_STEPS]);
    for field in ["displacement", "velocity"] {
        let names = file.group(&format!("fields/{field}"))?.member_names()?;
        assert_eq!(names.len(), BAR_STEPS + 1, "{field}");
        for name in &names {
            let shape = file.dataset(&format!("fields/{field}/{name}"))?.shape();
            assert_eq!(shape, vec![BAR_FIELD_NODES, 3], "{field}/{name}");
        }
    }
    // the initial state: every node at rest in place, moving at v0 = 1 m/s along x
    let u0: Vec<f64> = file.dataset("fields/displacement/000000")?.read_raw()?;
    assert!(u0.iter().all(|&u| u == 0.0));
    let v0: Vec<f64> = file.dataset("fields/velocity/000000")?.read_raw()?;
    assert!(v0.chunks(3).all(|v| v == [1.0, 0.0, 0.0]), "{:?}", &v0[..6]);
    // each element's stress (issue 47: ParaView had displacements and velocities only): 10 us
    // after the impact (step 50) the wave has run 5.1 cm back from the wall at x = 0.1 m;
    // behind it the bar is compressed at rho c v0 (d'Alembert), ahead of it unstressed
    let coords: Vec<f64> = file.dataset("mesh/coordinates")?.read_raw()?;
    let topology: Vec<i64> = file.dataset("mesh/topology")?.read_raw()?;
    let centre = |e: usize| 0.5 * (coords[3 * topology[2 * e] as usize] + coords[3 * topology[2 * e + 1] as usize]);
    let stress: Vec<f64> = file.dataset("fields/stress/000050")?.read_raw()?;
    let von_mises: Vec<f64> = file.dataset("fields/von_mises/000050")?.read_raw()?;
    assert_eq!((stress.len(), von_mises.len()), (600, 100));
    let rho_c_v0 = (7800.0f64 * 200e9).sqrt();
    for e in 0..100 {
        let (x, xx) = (centre(e), stress[6 * e]);
        if x > 0.07 {
            assert!((xx + rho_c_v0).abs() < 0.1 * rho_c_v0, "behind the front, x = {x}: {xx:e}");
        } else if x < 0.03 {
            assert!(xx.abs() < 0.05 * rho_c_v0, "ahead of the front, x = {x}: {xx:e}");
        }
        assert!((von_mises[e] - xx.abs()).abs() <= 1e-9 * rho_c_v0, "uniaxial: von Mises = |xx|");
    }
    assert!(xdmf.contains(r#"Name="stress" AttributeType="Tensor6" Center="Cell""#));
    // the wall's contact (ParaView's OUT-interfaces.xdmf): pressed at rho c v0 while the bar rests
    // on it (the contact lasts 2 L / c
    // = 39.5 us), then open, the gap growing at v0 once the bar leaves at -v0 (step 300: 60 us)
    // (the wall's node among every interface's: the 3 perfect ones between the 4 substructures
    // carry the wave's traction, with no gap)
    let names: Vec<hdf5::types::VarLenUnicode> = file.dataset("interfaces/names")?.read_raw()?;
    let impact = names.iter().position(|n| n.as_str() == "impact").expect("the wall interface") as i64;
    let which: Vec<i64> = file.dataset("interfaces/interface")?.read_raw()?;
    let node = which.iter().position(|&i| i == impact).expect("its node");
    let at = |what: &str, step: &str| -> anyhow::Result<f64> {
        Ok(file.dataset(&format!("fields/{what}/{step}"))?.read_raw::<f64>()?[node])
    };
    let pressure = |step: &str| at("contact_pressure", step);
    let gap = |step: &str| at("gap", step);
    // (the trapezoidal rule's contact force alternates from step to step about its value, as the
    // wall_force QoI's does: 1.7e7 and 6.2e7 Pa; docs/verification.md: the mean of two steps)
    let pressed = 0.5 * (pressure("000050")? + pressure("000051")?);
    assert!((pressed - rho_c_v0).abs() < 0.05 * rho_c_v0, "{pressed:e}");
    // closed within the step's travel v0 dt (the first step's impact: the trapezoidal rule moves
    // the bar's end dt / 2 at v0 into the wall)
    assert!(gap("000050")?.abs() <= 8e-5 / 400.0 * 1.0, "closed: {:e}", gap("000050")?);
    let c = (200e9f64 / 7800.0).sqrt();
    let opened = 8e-5 * 300.0 / 400.0 - 2.0 * 0.1 / c;
    assert!(pressure("000300")?.abs() < 0.01 * rho_c_v0, "open: {:e}", pressure("000300")?);
    assert!((gap("000300")? - opened).abs() < 0.05 * opened, "gap {:e}, d'Alembert {opened:e}", gap("000300")?);
    assert!(dir.path().join("out-interfaces.xdmf").is_file());
    Ok(())
}

#[test]
fn worker_rejects_bad_input_with_one_line() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let scene = bar_scene();
    let text_of_scene = std::fs::read_to_string(&scene)?;
    std::fs::write(dir.path().join("bogus.toml"), format!("bogus = 1\n{text_of_scene}"))?;
    let cases: [(&[&std::ffi::OsStr], &str); 5] = [
        (&[scene.as_os_str(), os("--set"), os("nosuch=1")], "nosuch"),
        (&[scene.as_os_str(), os("--set"), os("v0=nan")], "v0=nan"),
        (&[os("bogus.toml")], "bogus"),
        (&[os("missing.toml")], "missing.toml"),
        (&[scene.as_os_str(), os("--init"), os("missing.bin")], "missing.bin"),
    ];
    for (args, named) in cases {
        let out = worker_solve(dir.path(), args);
        let stderr = text(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
        assert_eq!(stderr.lines().count(), 1, "{args:?}: one line expected: {stderr}");
        assert!(stderr.starts_with("error: ") && stderr.contains(named), "{args:?}: {stderr}");
        assert!(out.stdout.is_empty(), "{args:?}: {}", text(&out.stdout));
    }
    // Started by OpenMPI's launcher (as Debian's `mpiexec` becomes once ParaView is installed):
    // one line that names the launcher to use, not a solve per rank.
    let out = run_with_timeout(
        command(&workspace_bin("glissade-worker")).arg("solve").arg(&scene).env("OMPI_COMM_WORLD_SIZE", "2"),
        LIMIT,
    );
    let stderr = text(&out.stderr);
    assert_eq!((out.status.code(), stderr.lines().count()), (Some(1), 1), "{stderr}");
    assert!(stderr.contains("mpiexec.mpich"), "{stderr}");
    Ok(())
}

/// A contact scene asked at the smallest tolerance: its whole-interval check would need a pass
/// ten times tighter, which no solve may ask. The solve says that, not "still converging: about
/// 0 more iterations" (issue 48), and exits 2 with the check's outcome in the JSON.
#[test]
fn a_solve_asked_at_the_floor_says_its_answer_is_not_checked() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let scene = shipped_scene("three-blocks-tiny.toml");
    let out = worker_solve(dir.path(), &[scene.as_os_str(), os("--tol"), os("1e-10"), os("--json")]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    assert_eq!(v["converged"], false, "{v}");
    assert_eq!(v["window_check"]["outcome"], "below_floor", "{v}");
    let stderr = text(&out.stderr);
    assert!(stderr.contains("not checked") && stderr.contains("ask 1e-9 or above"), "{stderr}");
    assert!(!stderr.contains("about 0 more iterations"), "{stderr}");
    Ok(())
}
