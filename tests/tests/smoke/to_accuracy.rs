//! A study to an accuracy on a real coordinator with a real pool: its pilots climb the ladders
//! one lease at a time, and the level the study takes, the tolerance and every pilot's answer
//! are those of `glissade-worker solve --accuracy` at the same points.

use crate::common::*;

/// A titanium bar of our own (no shipped scene): clamped, pushed at its free end by a pressure
/// that ramps in smoothly and holds; the pressure is the swept parameter.
const PUSHED_TI_BAR: &str = r#"
dimension = 1
[time]
duration = 1.5e-4
steps = 16
[parameters]
p = { default = 4e7, min = 1e7, max = 8e7, unit = "Pa" }
[materials.ti]
E = 110e9
rho = 4500
[[bodies]]
name = "bar"
material = "ti"
size = [0.2]
elements = [8]
substructures = [2]
[[boundary]]
face = "bar.x-"
clamped = true
[[loads]]
face = "bar.x+"
pressure = "p"
history = [[0, 0], [2.5e-5, 0.146], [5e-5, 0.5], [7.5e-5, 0.854], [1e-4, 1], [1.5e-4, 1]]
[[qoi]]
name = "tip_ux"
kind = "displacement"
body = "bar"
point = [0.2]
component = "x"
[[qoi]]
name = "tip_vx"
kind = "velocity"
body = "bar"
point = [0.2]
component = "x"
"#;

const ACCURACY: f64 = 0.05;

#[test]
fn a_study_to_an_accuracy_takes_the_level_its_pilots_chose_as_the_worker_does() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let scene_path = dir.path().join("ti-bar.toml");
    std::fs::write(&scene_path, PUSHED_TI_BAR)?;
    let (server_log, pool_log) = (dir.path().join("server.log"), dir.path().join("pool.log"));
    let (_server, addr) = start_server(&dir.path().join("db"), &server_log);
    let url = format!("http://{addr}");
    let mut pool = start_single_pool(&url, "pool", &pool_log);
    let rt = runtime();
    let logs = || format!("server:\n{}\npool:\n{}", log_of(&server_log), log_of(&pool_log));

    // refused: what an accuracy chooses itself
    let refused = rt.block_on(async {
        let mut client = user(&url).await?;
        let request = v1::SubmitStudyRequest {
            scene: PUSHED_TI_BAR.into(),
            grid: vec!["p=2e7:6e7:3".into()],
            accuracy: Some(ACCURACY),
            tolerance: Some(1e-4),
            ..Default::default()
        };
        anyhow::Ok(client.submit_study(request).await.expect_err("refused"))
    })?;
    assert_eq!(refused.code(), tonic::Code::InvalidArgument);
    assert!(refused.message().contains("accuracy: not with a tolerance"), "{}", refused.message());

    let out = glissade(
        Some(&url),
        &["submit", scene_path.to_str().unwrap(), "--grid", "p=2e7:6e7:3", "--accuracy", "0.05", "--pilots", "2"],
    );
    assert!(out.status.success(), "submit: {}", text(&out.stderr));
    let id: u64 = text(&out.stdout).trim().parse()?;
    let ran = rt.block_on(async {
        let mut client = user(&url).await?;
        watch(&mut client, id, |_| true).await?;
        // its held-out check, an audit, runs once the study has ended
        let check = study(&mut client, id).await?.to_accuracy.map_or(0, |t| t.held_out_study_id);
        anyhow::ensure!(check != 0, "no held-out check");
        watch(&mut client, check, |_| true).await?;
        let s = study(&mut client, id).await?;
        let mut levels = Vec::new();
        for level in &s.to_accuracy.as_ref().expect("to an accuracy").level_study_ids {
            levels.push(study(&mut client, *level).await?);
        }
        anyhow::Ok((s, levels))
    });
    let (s, levels) = ran.map_err(|e| anyhow::anyhow!("{e}\n{}", logs()))?;
    let t = s.to_accuracy.clone().expect("to an accuracy");
    assert!(t.chosen && t.reached && t.why_not.is_empty(), "{t:?}\n{}", logs());
    assert_eq!((t.pilot_points.len(), t.pilots_done), (2, 2), "{t:?}");
    assert_eq!(s.state, v1::StudyState::Done as i32, "{s:?}\n{}", logs());
    assert!((s.tolerance - ACCURACY / 50.0).abs() < 1e-15, "{}", s.tolerance);
    // every level a study of its own, pilots of this one, solved cold at the study's tolerance
    assert!(levels.len() >= 3, "three time levels at least: {levels:?}");
    for level in &levels {
        assert_eq!((level.pilot_of, level.kind.as_str()), (id, "pilots"));
        assert_eq!(level.tolerance, s.tolerance);
        assert!(level.points.iter().all(|p| p.state == v1::PointState::Done as i32), "{level:?}");
    }
    // the study's scene is its level's
    assert!(levels.iter().any(|l| l.scene_hash == s.scene_hash), "the chosen level is one of the pilots'");

    // each pilot, on the worker: the same ladders, the same level, the same answer
    let (mut time_factor, mut mesh_factor) = (1, 1);
    for &pilot in &t.pilot_points {
        let point = &s.points[pilot as usize];
        let p = point.parameters["p"];
        let out = run_with_timeout(
            command(&workspace_bin("glissade-worker")).arg("solve").arg(&scene_path).args([
                "--set",
                &format!("p={p}"),
                "--accuracy",
                &ACCURACY.to_string(),
                "--json",
            ]),
            LIMIT,
        );
        assert!(out.status.success(), "solve --accuracy: {}", text(&out.stderr));
        let json: serde_json::Value = serde_json::from_slice(&out.stdout)?;
        let report = &json["accuracy"];
        // the level a study takes from this pilot: the cheapest solved within the accuracy
        let cheapest = &report["cheapest"];
        let (k, m) = (cheapest["time_factor"].as_u64().unwrap(), cheapest["mesh_factor"].as_u64().unwrap());
        assert!(cheapest["bound"].as_f64().unwrap() <= ACCURACY, "{report}");
        time_factor = time_factor.max(k);
        mesh_factor = mesh_factor.max(m);
        for q in report["qois"].as_array().expect("qois") {
            let name = q["name"].as_str().unwrap();
            let (worker, service) = (q["total"].as_f64().unwrap(), t.qoi[name].total);
            // the study's largest estimate over its pilots is no smaller than this pilot's
            assert!(service >= worker * (1.0 - 1e-9), "{name}: service {service}, worker {worker}");
        }
        // the study's point at the pilot, at the chosen level: answered from the pilot's own
        // stored solve where its level is the study's
        if (k, m) == (t.time_factor as u64, t.mesh_factor as u64) {
            assert!(point.answered, "{point:?}");
            for q in report["qois"].as_array().unwrap() {
                let name = q["name"].as_str().unwrap();
                // the worker's final at (k, m), as its report lists each level it solved
                let worker = report["levels"]
                    .as_array()
                    .expect("levels")
                    .iter()
                    .find(|l| (l["time_factor"].as_u64(), l["mesh_factor"].as_u64()) == (Some(k), Some(m)))
                    .and_then(|l| l["finals"][name].as_f64())
                    .unwrap_or_else(|| panic!("the cheapest level ({k}, {m}) is one the worker solved: {report}"));
                let service = point.qoi[name];
                assert!(
                    (worker - service).abs() <= 1e-9 * worker.abs().max(1e-30),
                    "{name}: worker {worker}, service {service}"
                );
            }
        }
    }
    assert_eq!((t.time_factor as u64, t.mesh_factor as u64), (time_factor, mesh_factor), "{t:?}");
    for (name, q) in &t.qoi {
        assert!(q.within && q.total <= ACCURACY && q.mesh >= 0.0, "{name}: {q:?}");
    }

    // the promise, on the point no pilot solved: every QoI (the velocity too) within the accuracy
    // of a reference two levels finer in dt and in h, at a tolerance 1000 x tighter
    let other = s.points.iter().find(|p| !t.pilot_points.contains(&p.point_id)).expect("3 points, 2 pilots");
    let fine = PUSHED_TI_BAR
        .replace("steps = 16", &format!("steps = {}", 16 * 4 * t.time_factor))
        .replace("elements = [8]", &format!("elements = [{}]", 8 * 4 * t.mesh_factor));
    let fine_path = dir.path().join("ti-bar-fine.toml");
    std::fs::write(&fine_path, fine)?;
    let out = run_with_timeout(
        command(&workspace_bin("glissade-worker")).arg("solve").arg(&fine_path).args([
            "--set",
            &format!("p={}", other.parameters["p"]),
            "--tol",
            "1e-6",
            "--json",
        ]),
        LIMIT,
    );
    assert!(out.status.success(), "the reference: {}", text(&out.stderr));
    let reference: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    // that point is the held-out one: re-solved one level finer, the difference reported is the
    // study's against it, and it confirms the accuracy
    assert_eq!(t.held_out_planned, 1, "3 points, 2 pilots: {t:?}");
    assert_eq!((t.held_out_done, t.held_out_failed, t.confirmed), (1, 0, Some(true)), "{t:?}");
    assert_eq!((t.held_out_time_factor, t.held_out_mesh_factor), (2 * t.time_factor, 2 * t.mesh_factor));
    let check = rt.block_on(async { study(&mut user(&url).await?, t.held_out_study_id).await })?;
    assert_eq!(check.points[0].parameters, other.parameters);
    // the check's level solved here, cold at the accuracy's tolerance: the same answer, and the
    // scale the reported difference is relative to
    let finer = PUSHED_TI_BAR
        .replace("steps = 16", &format!("steps = {}", 16 * t.held_out_time_factor))
        .replace("elements = [8]", &format!("elements = [{}]", 8 * t.held_out_mesh_factor));
    let finer_path = dir.path().join("ti-bar-finer.toml");
    std::fs::write(&finer_path, finer)?;
    let out = run_with_timeout(
        command(&workspace_bin("glissade-worker")).arg("solve").arg(&finer_path).args([
            "--set",
            &format!("p={}", other.parameters["p"]),
            "--tol",
            &(ACCURACY / 50.0).to_string(),
            "--json",
        ]),
        LIMIT,
    );
    assert!(out.status.success(), "the check's level: {}", text(&out.stderr));
    let finer: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    for (name, q) in reference["qoi"].as_object().expect("qoi") {
        let values: Vec<f64> = q["values"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
        let scale = values.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let error = (other.qoi[name] - q["final"].as_f64().unwrap()).abs() / scale;
        eprintln!("{name}: {error:.2e} off the reference two levels finer (asked {ACCURACY})");
        assert!(error <= ACCURACY, "{name}: {error:.2e} off the reference two levels finer");
        let f = &finer["qoi"][name];
        let checked = check.points[0].qoi[name];
        assert!(
            (f["final"].as_f64().unwrap() - checked).abs() <= 1e-9 * checked.abs(),
            "{name}: {f} against {checked}"
        );
        let finer_scale = f["values"].as_array().unwrap().iter().fold(0.0f64, |m, v| m.max(v.as_f64().unwrap().abs()));
        let difference = (other.qoi[name] - checked).abs() / finer_scale;
        let reported = t.held_out_difference[name];
        assert!(
            (reported - difference).abs() <= 1e-9 * difference.max(1e-12),
            "{name}: {reported} against {difference}"
        );
    }

    // `glissade show` says what was chosen and why
    let out = glissade(Some(&url), &["show", &id.to_string()]);
    assert!(out.status.success(), "show: {}", text(&out.stderr));
    let shown = text(&out.stdout);
    let level = format!("  level     REACHED at dt / {}, h / {}", t.time_factor, t.mesh_factor);
    assert!(shown.contains("  accuracy  asked 5.00 % of each QoI's scale") && shown.contains(&level), "{shown}");
    assert!(shown.contains("  held-out  1 of 1 points re-solved at dt / ") && shown.contains("CONFIRMED"), "{shown}");
    let out = glissade(Some(&url), &["show", &id.to_string(), "--json"]);
    let json: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    assert_eq!(json["to_accuracy"]["time_factor"], serde_json::json!(t.time_factor), "{json}");
    // the web page says it in the same words
    let (status, _, page) = http_get(&addr, &format!("/studies/{id}"));
    assert_eq!(status, 200);
    let reached = format!("REACHED at dt / {}, h / {}", t.time_factor, t.mesh_factor);
    assert!(page.contains("id=\"to-accuracy\"") && page.contains(&reached), "{page}");
    assert!(page.contains("id=\"held-out-check\"") && page.contains("CONFIRMED"), "{page}");
    // the web API and `show --json` give GetStudy's study, each pilot's ladders and report in it
    let study = assert_one_rendering(&addr, &url, id)?;
    let a = study.to_accuracy.as_ref().expect("to an accuracy");
    assert!(a.chosen && (a.time_factor, a.mesh_factor) == (t.time_factor, t.mesh_factor), "{a:?}");
    assert_eq!(a.pilots.len(), 2, "{a:?}");
    for pilot in &a.pilots {
        let report = pilot.report.as_ref().expect("a pilot done has its report");
        assert!(!pilot.asked.is_empty() && !report.levels.is_empty() && !report.qoi.is_empty(), "{pilot:?}");
        assert!(report.qoi.iter().all(|q| q.time.as_ref().is_some_and(|l| l.finals.len() >= 2)), "{pilot:?}");
    }
    assert_eq!(a.level_study_ids.len(), a.level_time_factors.len(), "{a:?}");
    assert!(terminate(&mut pool.0).success());
    Ok(())
}
