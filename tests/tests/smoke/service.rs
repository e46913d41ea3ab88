//! The coordinator with real pools over gRPC: studies solved once each like direct solves, refusals, the Python client, progress, memory limits.

use crate::common::*;

#[test]
fn server_and_client_talk_and_fail_cleanly() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let data = dir.path().join("db");
    let log = dir.path().join("server.log");
    let (mut server, addr) = start_server(&data, &log);
    assert!(addr.ip().is_loopback() && addr.port() != 0, "{addr}");

    let glissade = workspace_bin("glissade");
    let url = format!("http://{addr}");
    let out = run_with_timeout(command(&glissade).args(["--server", &url, "health", "--json"]), LIMIT);
    assert!(out.status.success(), "health failed: {}", text(&out.stderr));
    let reply: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    assert_eq!(reply["status"], "SERVING", "{reply}");
    assert_eq!(reply["version"], env!("CARGO_PKG_VERSION"), "{reply}");
    // the standard health service too, for the whole server and each service, unknown names refused
    let rt = runtime();
    for (service, status) in [("", Ok(1)), ("glissade.v1.User", Ok(1)), ("glissade.v1.Pool", Ok(1)), ("x.Y", Err(()))] {
        assert_eq!(rt.block_on(standard_health(&url, service)), status, "{service:?}");
    }
    drop(rt);

    // Nothing listens on port 1: one readable line and exit code 1, no panic, no Debug dump.
    let out = run_with_timeout(command(&glissade).args(["--server", "http://127.0.0.1:1", "health"]), LIMIT);
    assert_eq!(out.status.code(), Some(1), "stderr: {}", text(&out.stderr));
    assert!(out.stdout.is_empty(), "stdout: {}", text(&out.stdout));
    let stderr = text(&out.stderr);
    assert_eq!(stderr, "error: cannot reach glissade server at http://127.0.0.1:1: connection refused\n");

    // A second server on the same data directory must refuse (sled's lock is per process).
    let out = run_with_timeout(
        command(&workspace_bin("glissade-server")).args(["--listen", "127.0.0.1:0", "--data"]).arg(&data),
        LIMIT,
    );
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "stderr: {stderr}");
    assert!(stderr.lines().last().unwrap_or_default().contains("in use by another process"), "stderr: {stderr}");

    // SIGTERM: the server must stop by itself, successfully, having flushed its database.
    let kill = run_with_timeout(Command::new("kill").args(["-TERM", &server.0.id().to_string()]), LIMIT);
    assert!(kill.status.success(), "kill: {}", text(&kill.stderr));
    let status = wait_with_timeout(&mut server.0, LIMIT).expect("server did not stop on SIGTERM");
    let server_log = std::fs::read_to_string(&log)?;
    assert!(status.success(), "server exited with {status}; log:\n{server_log}");
    assert!(server_log.contains("SIGTERM"), "log:\n{server_log}");

    // The database it left behind is readable and carries a schema version; a different version
    // must make the next server refuse to start, with one clear line.
    {
        let db = sled::open(&data)?;
        assert_eq!(db.get("meta/schema-version")?.as_deref(), Some(&b"2"[..]));
        db.insert("meta/schema-version", "999")?;
        db.flush()?;
    }
    let out = run_with_timeout(
        command(&workspace_bin("glissade-server")).args(["--listen", "127.0.0.1:0", "--data"]).arg(&data),
        LIMIT,
    );
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "stderr: {stderr}");
    assert!(out.stdout.is_empty(), "must not announce a port: {}", text(&out.stdout));
    let last = stderr.lines().last().unwrap_or_default();
    assert!(
        last.starts_with("error: opening the database: ") && last.contains("schema version 999"),
        "stderr: {stderr}"
    );
    Ok(())
}

#[test]
fn every_binary_answers_help_and_version() {
    let mut stdout = std::collections::HashMap::new();
    for name in ["glissade-server", "glissade", "glissade-worker"] {
        let bin = workspace_bin(name);
        for flag in ["--help", "--version"] {
            let out = run_with_timeout(command(&bin).arg(flag), LIMIT);
            assert!(out.status.success(), "`{name} {flag}` exited with {}: {}", out.status, text(&out.stderr));
            stdout.insert((name, flag), text(&out.stdout));
        }
    }
    // Our own binaries' texts; glissade-worker's belong to the solver and are only run above.
    for name in ["glissade-server", "glissade"] {
        let version = format!("{name} {}\n", env!("CARGO_PKG_VERSION"));
        assert_eq!(stdout[&(name, "--version")], version);
        assert!(stdout[&(name, "--help")].contains("Usage:"), "{name} --help");
    }
    assert!(stdout[&("glissade", "--help")].contains("Examples:"));
    assert!(stdout[&("glissade-server", "--help")].contains("--listen <ADDR>"));
}

#[test]
fn service_two_pools_solve_each_point_once_like_direct_solves() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let (server_log, pool_logs) = (dir.path().join("server.log"), [dir.path().join("a.log"), dir.path().join("b.log")]);
    let (mut server, addr) = start_server_with(&dir.path().join("db"), &server_log, "127.0.0.1:0", &[]);
    let url = format!("http://{addr}");
    let mut pools = [start_pool(&url, "pool-a", &pool_logs[0]), start_pool(&url, "pool-b", &pool_logs[1])];
    let glissade = workspace_bin("glissade");
    let scene_path = shipped_scene("three-blocks-tiny.toml");
    let logs = || {
        let [a, b] = &pool_logs;
        format!("server:\n{}\npool-a:\n{}\npool-b:\n{}", log_of(&server_log), log_of(a), log_of(b))
    };

    // A cold study (so that each point is exactly a direct solve), submitted with the CLI; no
    // held-out points (the stored solutions are counted below; surface_audit.rs tests them).
    let out = run_with_timeout(
        command(&glissade).args(["--server", &url, "submit"]).arg(&scene_path).args([
            "--grid",
            "f1=0.1:0.2:3",
            "--grid",
            "f2=0.1:0.2:3",
            "--tol",
            &STUDY_TOL.to_string(),
            "--strategy",
            "cold",
            "--surface-audit",
            "0",
            "--json",
        ]),
        LIMIT,
    );
    assert!(out.status.success(), "submit: {}", text(&out.stderr));
    let submitted: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    assert_eq!(submitted["points"], 9, "{submitted}");
    let first = submitted["study_id"].as_u64().expect("study_id");
    let scene_hash = submitted["scene_hash"].as_str().expect("scene_hash").to_owned();

    let rt = runtime();
    let (events, first_study) = rt.block_on(async {
        let mut client = user(&url).await?;
        let events = watch(&mut client, first, |_| true).await?;
        anyhow::Ok((events, study(&mut client, first).await?))
    })?;
    // Every point finished exactly once, on one of the two pools, with one lease.
    let mut finished: Vec<u64> =
        events.iter().filter(|e| kind(e) == v1::EventKind::PointFinished && !e.replay).map(point_id).collect();
    finished.sort();
    assert_eq!(finished, (0..9).collect::<Vec<_>>(), "{}", logs());
    assert_eq!(first_study.state, v1::StudyState::Done as i32);
    for p in &first_study.points {
        assert_eq!(p.state, v1::PointState::Done as i32, "{p:?}");
        assert_eq!(p.attempts, 1, "{p:?}");
        assert!(["pool-a", "pool-b"].contains(&p.pool_id.as_str()), "{p:?}");
        assert!(
            p.error_indicator.is_some_and(|e| e <= STUDY_TOL) && p.iterations > 0 && p.started_from.is_none(),
            "{p:?}"
        );
    }
    // each pool registered once, as one pool of two ranks
    assert_eq!(log_of(&server_log).matches("pool registered").count(), 2, "{}", logs());
    assert_eq!(log_of(&server_log).matches("ranks=2").count(), 2, "{}", logs());
    // the CLI shows it
    let out =
        run_with_timeout(command(&glissade).args(["--server", &url, "show", &first.to_string(), "--json"]), LIMIT);
    assert!(out.status.success(), "show: {}", text(&out.stderr));
    let shown: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    assert_eq!(
        (&shown["state"], &shown["progress"]["done"], &shown["strategy"]),
        (&"STUDY_STATE_DONE".into(), &9.into(), &"INIT_STRATEGY_COLD".into())
    );

    // The same points solved directly on one process: the same iterations and QoIs (the pools'
    // two ranks compute bit for bit what one process does; 1e-12 leaves room for the decimal
    // round trip of the direct solve's JSON).
    for p in &first_study.points {
        let direct = direct_solve(&p.parameters, STUDY_TOL);
        assert_eq!(direct["iterations"].as_u64(), Some(p.iterations), "{p:?}");
        assert_qois_agree(p, &direct, 1e-12);
    }

    // A second study of the same scene starts from the first one's solutions: fewer iterations.
    let second_study = rt.block_on(async {
        let mut client = user(&url).await?;
        // from the nearest solution alone (not the default linear fit of several), so that a
        // direct `solve --init` from the recorded source reproduces a point below
        let request = v1::SubmitStudyRequest {
            strategy: v1::InitStrategy::Nearest.into(),
            ..grid_request(&["f1=0.125:0.175:2", "f2=0.125:0.175:2"], STUDY_TOL)
        };
        let reply = client.submit_study(request).await?.into_inner();
        assert_eq!(reply.scene_hash, scene_hash);
        watch(&mut client, reply.study_id, |_| true).await?;
        study(&mut client, reply.study_id).await
    })?;
    // work: dynamic iterations + static iterations / steps, as the pools report it
    let mean = |s: &v1::Study| s.points.iter().map(|p| p.work).sum::<f64>() / s.points.len() as f64;
    // (from the first study's solutions or its audit's: the audit re-solved two of its points
    // cold at 1/100 of the tolerance, and stored them)
    let audit = first_study.accuracy.as_ref().expect("an audit by default").audit_study_id;
    for p in &second_study.points {
        assert_eq!(p.state, v1::PointState::Done as i32, "{p:?}");
        let from = p.started_from.as_ref().map(|f| f.study_id);
        assert!(from == Some(first) || from == Some(audit), "{p:?}");
    }
    // Warm starts from neighbours stop on the same QoI error estimate as cold ones and cost
    // less work.
    assert!(first_study.points.iter().all(|p| p.work > 0.0 && p.work <= p.iterations as f64));
    assert!(
        mean(&second_study) < 0.8 * mean(&first_study),
        "second study: {} iterations per point, the first (cold) {}",
        mean(&second_study),
        mean(&first_study)
    );

    // The first study's audit: 2 of its 9 points (10 %, at least 2) re-solved cold at 1/100 of
    // its tolerance; the accuracy it reports is what a direct comparison gives.
    let (audited, measured) = rt.block_on(async {
        let mut client = user(&url).await?;
        watch(&mut client, audit, |_| true).await?;
        anyhow::Ok((study(&mut client, audit).await?, study(&mut client, first).await?))
    })?;
    assert_eq!((audited.audit_of, audited.points.len(), audited.tolerance), (first, 2, STUDY_TOL / 100.0));
    let accuracy = measured.accuracy.expect("measured");
    assert_eq!((accuracy.audited, accuracy.planned), (2, 2), "{accuracy:?}");
    for (q, reported) in &accuracy.qoi {
        let pairs: Vec<(f64, f64)> = audited
            .points
            .iter()
            .map(|a| {
                let p = measured.points.iter().find(|p| p.parameters == a.parameters).expect("an audited point");
                (p.qoi[q], a.qoi[q])
            })
            .collect();
        let scale = pairs.iter().map(|(_, a)| a.abs()).fold(0.0f64, f64::max);
        let errors: Vec<f64> = pairs.iter().map(|(p, a)| (p - a).abs() / scale).collect();
        let largest = errors.iter().cloned().fold(0.0f64, f64::max);
        assert_eq!(reported.largest, largest, "{q}");
        assert!((reported.mean - errors.iter().sum::<f64>() / 2.0).abs() <= 1e-15, "{q}");
        // and the study kept its word: within 10 x its tolerance
        assert!(largest <= 10.0 * STUDY_TOL, "{q}: {largest:e}");
    }

    // A warm-started point solved directly from the same stored solution gives the same result:
    // the pool runs exactly the solve of `glissade-worker solve --init`.
    use v1::fetch_solution_request::Solution;
    let warm = &second_study.points[0];
    let from = warm.started_from.clone().expect("checked above");
    let key = v1::SolutionKey { scene_hash: from.scene_hash.clone(), parameters: from.parameters.clone() };
    let init = rt.block_on(async { fetch(&mut user(&url).await?, Solution::Key(key)).await })?;
    std::fs::write(dir.path().join("init.bin"), init)?;
    let mut args: Vec<std::ffi::OsString> =
        vec![scene_path.clone().into(), "--json".into(), "--tol".into(), STUDY_TOL.to_string().into()];
    args.extend(["--init".into(), dir.path().join("init.bin").into()]);
    for (k, v) in &warm.parameters {
        args.extend(["--set".into(), format!("{k}={v}").into()]);
    }
    let args: Vec<&std::ffi::OsStr> = args.iter().map(|a| a.as_os_str()).collect();
    let same = converged_json(&worker_solve(dir.path(), &args));
    assert_eq!(same["iterations"].as_u64(), Some(warm.iterations), "{warm:?}\n{same}");
    assert_qois_agree(warm, &same, 1e-12);

    // Response surfaces: over a study, a slice of it, every solution of the scene.
    rt.block_on(async {
        use v1::query_surface_request::Source;
        let mut client = user(&url).await?;
        let q = |source, fixed: &[(&str, f64)]| v1::QuerySurfaceRequest {
            source: Some(source),
            fixed: fixed.iter().map(|&(k, v)| (k.to_owned(), v)).collect(),
            ..Default::default()
        };
        let s = client.query_surface(q(Source::StudyId(first), &[])).await?.into_inner();
        assert_eq!(s.points.len(), 9);
        // Predictions with error bars (docs/surrogate.md): at a stored point the surface gives
        // its value back, between points it is less sure.
        let at = |f1: f64, f2: f64| v1::ParameterPoint { parameters: [("f1".into(), f1), ("f2".into(), f2)].into() };
        let mut ask = q(Source::StudyId(first), &[]);
        ask.predict_at = vec![at(0.15, 0.15), at(0.125, 0.175)];
        let p = client.query_surface(ask).await?.into_inner();
        assert_eq!(p.predictions.len(), 2);
        let slips: Vec<f64> = s.points.iter().map(|x| x.qoi["slip_A"]).collect();
        let spread = slips.iter().cloned().fold(f64::MIN, f64::max) - slips.iter().cloned().fold(f64::MAX, f64::min);
        let stored = s.points.iter().find(|x| x.parameters["f1"] == 0.15 && x.parameters["f2"] == 0.15).unwrap();
        let (on, between) = (&p.predictions[0].qoi["slip_A"], &p.predictions[1].qoi["slip_A"]);
        assert!((on.mean - stored.qoi["slip_A"]).abs() <= 1e-3 * spread, "{on:?} against {stored:?}");
        assert!(on.std < between.std && on.fitted_points == 9, "{on:?} {between:?}");
        let mut wrong = q(Source::StudyId(first), &[]);
        wrong.predict_at = vec![v1::ParameterPoint { parameters: [("f9".into(), 0.1)].into() }];
        let refused = client.query_surface(wrong).await.expect_err("f9 is not a parameter");
        assert_eq!(refused.code(), Code::InvalidArgument, "{refused:?}");
        assert_eq!(s.parameters, ["f1", "f2"]);
        assert_eq!(s.qoi, ["middle_ux", "slip_A", "slip_B"]);
        let slice = client.query_surface(q(Source::StudyId(first), &[("f1", 0.1)])).await?.into_inner();
        assert_eq!(slice.points.len(), 3);
        assert!(slice.points.iter().all(|p| p.parameters["f1"] == 0.1 && p.converged));
        let all = client.query_surface(q(Source::SceneHash(scene_hash.clone()), &[("f2", 0.125)])).await?.into_inner();
        assert_eq!(all.points.len(), 2, "{all:?}");
        let all = client.query_surface(q(Source::SceneHash(scene_hash.clone()), &[])).await?.into_inner();
        assert_eq!(all.points.len(), 13);

        // The stored solution of a point: a whole solution file of this scene and point.
        let bytes = fetch(&mut client, Solution::Point(v1::PointKey { study_id: first, point_id: 4 })).await?;
        let (meta, _) = glissade_core::io::solution_file::read_from(&bytes[..])?;
        assert_eq!(meta.scene_hash, scene_hash);
        assert_eq!((meta.parameters.get("f1"), meta.parameters.get("f2")), (Some(0.15), Some(0.15)));
        assert!(meta.converged);
        anyhow::Ok(())
    })?;

    // Idle pools stop at once on SIGTERM, successfully; so does the coordinator.
    drop(rt);
    for pool in &mut pools {
        let status = terminate(&mut pool.0);
        assert!(status.success(), "pool exited with {status}:\n{}", logs());
    }
    let status = terminate(&mut server.0);
    assert!(status.success(), "server exited with {status}:\n{}", logs());
    Ok(())
}

#[test]
fn service_refuses_bad_input_precisely_and_keeps_what_it_stored() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let log = dir.path().join("server.log");
    let (_server, addr) = start_server_with(&dir.path().join("db"), &log, "127.0.0.1:0", &["--lease-seconds", "30"]);
    let url = format!("http://{addr}");
    let rt = runtime();
    let mut client = rt.block_on(user(&url))?;
    let expect = |result: Result<tonic::Response<v1::SubmitStudyReply>, tonic::Status>, code: Code, needle: &str| {
        let status = result.expect_err("must be refused");
        assert_eq!(status.code(), code, "{status:?}");
        assert!(status.message().contains(needle), "expected `{needle}` in: {}", status.message());
    };

    // Submissions: malformed scene, empty grid, NaN, out of range, unknown parameter.
    let mut bad = grid_request(&["f1=0.1:0.2:3"], STUDY_TOL);
    bad.scene = tiny_scene().replace("dimension = 3", "dimension = [3");
    expect(rt.block_on(client.submit_study(bad)), Code::InvalidArgument, "scene");
    expect(rt.block_on(client.submit_study(grid_request(&[], STUDY_TOL))), Code::InvalidArgument, "empty study");
    let mut nan = grid_request(&[], STUDY_TOL);
    nan.points = vec![v1::ParameterVector { values: [("f1".to_string(), f64::NAN)].into() }];
    expect(rt.block_on(client.submit_study(nan)), Code::InvalidArgument, "not finite");
    expect(
        rt.block_on(client.submit_study(grid_request(&["f1=0.1,0.5"], STUDY_TOL))),
        Code::InvalidArgument,
        "outside the scene's range",
    );
    expect(
        rt.block_on(client.submit_study(grid_request(&["mu=0.1:0.2:3"], STUDY_TOL))),
        Code::InvalidArgument,
        "no parameter 'mu'",
    );
    expect(rt.block_on(client.submit_study(grid_request(&["f1=0.1"], -1.0))), Code::InvalidArgument, "tolerance");
    // Hostile sizes: counted and refused before anything is built; the coordinator stays up.
    for grid in
        [&["f1=0.1:0.2:1000000000000"][..], &["f1=lhs:1000000000000:1"], &["f1=0.1:0.2:100000", "f2=0.1:0.2:100000"]]
    {
        expect(rt.block_on(client.submit_study(grid_request(grid, STUDY_TOL))), Code::InvalidArgument, "design points");
    }
    let mut poison = grid_request(&["f1=0.1"], STUDY_TOL);
    poison.scene = tiny_scene().replacen("elements = [2, 2, 4]", "elements = [200, 200, 250]", 1);
    expect(rt.block_on(client.submit_study(poison)), Code::InvalidArgument, "--max-scene-mib");
    // A 10 kB name is echoed as a bounded excerpt: INVALID_ARGUMENT, not RESOURCE_EXHAUSTED.
    let long = format!("{}=0.1", "n".repeat(10_000));
    expect(
        rt.block_on(client.submit_study(grid_request(&[&long], STUDY_TOL))),
        Code::InvalidArgument,
        "more characters",
    );
    // Unknown study ids.
    for status in [
        rt.block_on(client.get_study(v1::GetStudyRequest { study_id: 42, points: false, ..Default::default() }))
            .map(drop)
            .expect_err("get"),
        rt.block_on(client.watch_study(v1::WatchStudyRequest { study_id: 42 })).map(drop).expect_err("watch"),
        rt.block_on(client.cancel_study(v1::CancelStudyRequest { study_id: 42 })).map(drop).expect_err("cancel"),
    ] {
        assert_eq!((status.code(), status.message()), (Code::NotFound, "no study 42"));
    }
    // The CLI says it in one line.
    let out = run_with_timeout(command(&workspace_bin("glissade")).args(["--server", &url, "show", "42"]), LIMIT);
    assert_eq!(out.status.code(), Some(1));
    assert_eq!(text(&out.stderr), "error: show 42: no study 42 (NotFound)\n");
    // A reader that goes away before the output comes (`| head`): a quiet exit, no panic.
    let piped =
        format!("set -o pipefail; '{}' --server {url} studies --json | true", workspace_bin("glissade").display());
    let out = run_with_timeout(Command::new("bash").args(["-c", &piped]), LIMIT);
    assert!(out.status.success() && out.stderr.is_empty(), "{:?}: {}", out.status, text(&out.stderr));

    // A study of two points: one completed properly first, whose stored solution must survive.
    let id = rt.block_on(client.submit_study(grid_request(&["f1=0.1,0.2"], STUDY_TOL)))?.into_inner().study_id;
    let solve_to_file = |lease: &v1::Lease, scene: &Path| -> Vec<u8> {
        let file = dir.path().join(format!("p{}.bin", lease.point_id));
        let mut args: Vec<std::ffi::OsString> =
            vec![scene.into(), "--tol".into(), STUDY_TOL.to_string().into(), "--save".into(), file.clone().into()];
        for (k, v) in &lease.parameters {
            args.push("--set".into());
            args.push(format!("{k}={v}").into());
        }
        let out = run_with_timeout(command(&workspace_bin("glissade-worker")).arg("solve").args(&args), LIMIT);
        assert!(out.status.success(), "{}", text(&out.stderr));
        std::fs::read(&file).expect("saved solution")
    };
    let scene_file = dir.path().join("tiny.toml");
    std::fs::write(&scene_file, tiny_scene())?;
    let (mut pool, lease) = rt.block_on(fake_pool(&url, "tester"))?;
    let good = solve_to_file(&lease, &scene_file);
    let reply = rt.block_on(complete(&mut pool, &lease, "tester", &good, &good, good.len()))?;
    assert_eq!(reply.point.expect("point").state, v1::PointState::Done as i32);
    let fetch = |client: &mut UserClient<Channel>, point: u64| -> anyhow::Result<Vec<u8>> {
        rt.block_on(async {
            let request = v1::FetchSolutionRequest {
                solution: Some(v1::fetch_solution_request::Solution::Point(v1::PointKey {
                    study_id: id,
                    point_id: point,
                })),
            };
            let mut stream = client.fetch_solution(request).await?.into_inner();
            let mut bytes = Vec::new();
            while let Some(c) = stream.message().await? {
                bytes.extend_from_slice(&c.data);
            }
            anyhow::Ok(bytes)
        })
    };
    let stored = fetch(&mut client, lease.point_id)?;
    assert_eq!(stored, good, "the coordinator serves the bytes the pool sent");

    // Completing that point again (no longer held), and completing under another pool's name.
    let status =
        rt.block_on(complete(&mut pool, &lease, "tester", &good, &good, good.len())).expect_err("done already");
    assert_eq!(status.code(), Code::FailedPrecondition, "{status:?}");
    assert!(status.message().contains("it is done"), "{}", status.message());

    // The second point: leased; then truncated, corrupt and foreign solutions are refused.
    let (mut pool, lease2) = rt.block_on(fake_pool(&url, "tester"))?;
    let good2 = solve_to_file(&lease2, &scene_file);
    let status =
        rt.block_on(complete(&mut pool, &lease2, "intruder", &good2, &good2, good2.len())).expect_err("not held");
    assert_eq!(status.code(), Code::FailedPrecondition, "{status:?}");
    assert!(status.message().contains("leased to pool `tester`"), "{}", status.message());
    let status = rt
        .block_on(complete(&mut pool, &lease2, "tester", &good2, &good2[..good2.len() / 2], good2.len()))
        .expect_err("truncated");
    assert_eq!(status.code(), Code::InvalidArgument, "{status:?}");
    assert!(status.message().contains("truncated"), "{}", status.message());
    let mut corrupt = good2.clone();
    let last = corrupt.len() - 3;
    corrupt[last] ^= 0x40;
    let status =
        rt.block_on(complete(&mut pool, &lease2, "tester", &good2, &corrupt, corrupt.len())).expect_err("corrupt");
    assert_eq!(status.code(), Code::DataLoss, "{status:?}");
    let bar = shipped_scene("bar-impact-1d.toml");
    let foreign = {
        let file = dir.path().join("bar.bin");
        let out = run_with_timeout(
            command(&workspace_bin("glissade-worker")).arg("solve").arg(&bar).arg("--save").arg(&file),
            LIMIT,
        );
        assert!(out.status.success(), "{}", text(&out.stderr));
        std::fs::read(&file)?
    };
    let status =
        rt.block_on(complete(&mut pool, &lease2, "tester", &foreign, &foreign, foreign.len())).expect_err("foreign");
    assert_eq!(status.code(), Code::InvalidArgument, "{status:?}");
    assert!(status.message().contains("solution is for scene"), "{}", status.message());
    let status =
        rt.block_on(complete(&mut pool, &lease2, "tester", &good, &good, good.len())).expect_err("other point");
    assert_eq!(status.code(), Code::InvalidArgument, "{status:?}");
    assert!(status.message().contains("solution is for parameters"), "{}", status.message());

    // Nothing stored was harmed, and the point held is still held: the right solution completes it.
    assert_eq!(fetch(&mut client, lease.point_id)?, good);
    let s = rt.block_on(study(&mut client, id))?;
    assert_eq!(s.points[lease2.point_id as usize].state, v1::PointState::Leased as i32, "{s:?}");
    let reply = rt.block_on(complete(&mut pool, &lease2, "tester", &good2, &good2, good2.len()))?;
    assert_eq!(reply.point.expect("point").state, v1::PointState::Done as i32);
    let s = rt.block_on(study(&mut client, id))?;
    assert_eq!(s.state, v1::StudyState::Done as i32, "{s:?}");
    assert_eq!(fetch(&mut client, lease2.point_id)?, good2);
    Ok(())
}

#[test]
fn python_example_client_submits_a_grid_and_reads_the_surface() -> anyhow::Result<()> {
    let Some(python) = python_with_glissade() else {
        eprintln!(
            "SKIPPED python_example_client_submits_a_grid_and_reads_the_surface: PyPI is unreachable, so the glissade package cannot be installed"
        );
        return Ok(());
    };
    let dir = tempfile::tempdir()?;
    let (_server, addr) = start_server(&dir.path().join("db"), &dir.path().join("server.log"));
    let _pool = start_pool(&format!("http://{addr}"), "py-pool", &dir.path().join("pool.log"));
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("../client/examples/submit_and_surface.py");
    let scene = shipped_scene("three-blocks-tiny.toml");
    let run = |grid: &[&str]| {
        let mut cmd = Command::new(&python);
        cmd.arg(&example).args(["--server", &addr.to_string(), "--tol", "1e-3", "--json"]).arg(&scene);
        for g in grid {
            cmd.args(["--grid", g]);
        }
        run_with_timeout(&mut cmd, LIMIT)
    };
    let out = run(&["f1=0.1,0.2", "f2=0.1,0.2"]);
    assert_eq!(out.status.code(), Some(0), "stderr: {}", text(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    assert_eq!(v["state"], "STUDY_STATE_DONE", "{v}");
    assert_eq!(v["parameters"], serde_json::json!(["f1", "f2"]), "{v}");
    assert_eq!(v["qoi"], serde_json::json!(["middle_ux", "slip_A", "slip_B"]), "{v}");
    let points = v["points"].as_array().expect("points");
    assert_eq!(points.len(), 4, "{v}");
    for p in points {
        assert_eq!(p["converged"], true, "{p}");
        assert!(p["error_indicator"].as_f64().is_some_and(|e| e <= 1e-3), "{p}");
        assert!(p["qoi"]["slip_A"].as_f64().is_some_and(f64::is_finite), "{p}");
    }
    assert!(text(&out.stderr).contains("done 4/4"), "progress lines expected: {}", text(&out.stderr));
    // no --strategy: the coordinator's default, as for the CLI (issue 25: the example said nearest)
    let submitted = runtime().block_on(async { study(&mut user(&format!("http://{addr}")).await?, 1).await })?;
    assert_eq!(submitted.strategy, glissade_proto::v1::InitStrategy::Linear as i32);

    // Server reflection lists the services (what `grpcurl list` shows).
    let list = format!(
        "import grpc\nfrom grpc_reflection.v1alpha.proto_reflection_descriptor_database import \
         ProtoReflectionDescriptorDatabase as D\nprint(' '.join(sorted(D(grpc.insecure_channel('{addr}')).get_services())))"
    );
    let out = run_with_timeout(Command::new(&python).args(["-c", &list]), LIMIT);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let services = text(&out.stdout);
    for s in ["glissade.v1.Health", "glissade.v1.Pool", "glissade.v1.User"] {
        assert!(services.split_whitespace().any(|x| x == s), "{s} not in {services}");
    }

    // A refused request: one line and exit status 1.
    let out = run(&["f1=0.1,0.5"]);
    assert_eq!(out.status.code(), Some(1), "stdout: {}", text(&out.stdout));
    assert_eq!(
        text(&out.stderr),
        "error: point 1: f1 = 0.5 is outside the scene's range [0.1, 0.2] (INVALID_ARGUMENT)\n"
    );
    Ok(())
}

#[test]
fn service_forwards_solve_progress_to_watchers() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let logs = [dir.path().join("server.log"), dir.path().join("pool.log")];
    // short leases: heartbeats (a quarter of the lease) come every 125 ms during a ~0.6 s solve
    let (_server, addr) =
        start_server_with(&dir.path().join("db"), &logs[0], "127.0.0.1:0", &["--lease-seconds", "0.5"]);
    let url = format!("http://{addr}");
    let _pool = start_pool(&url, "p", &logs[1]);
    let rt = runtime();
    let mut client = rt.block_on(user(&url))?;
    let id = rt.block_on(client.submit_study(grid_request(&["f1=0.1"], 1e-6)))?.into_inner().study_id;
    let events = rt.block_on(watch(&mut client, id, |_| true))?;
    let progress: Vec<&v1::PointStatus> = events
        .iter()
        .filter(|e| kind(e) == v1::EventKind::PointProgress)
        .map(|e| e.point.as_ref().expect("a progress event names its point"))
        .collect();
    let done = rt.block_on(study(&mut client, id))?.points.remove(0);
    assert_eq!(done.state, v1::PointState::Done as i32);
    assert!(!progress.is_empty(), "no progress event during a {} s solve:\n{}", done.wall_seconds, log_of(&logs[1]));
    let mut last = 0;
    for p in &progress {
        // iterations so far, increasing, below the final count; eta not yet converged
        assert_eq!(p.state, v1::PointState::Leased as i32, "{p:?}");
        assert!(p.iterations > last && p.iterations <= done.iterations, "{p:?} vs {} in all", done.iterations);
        assert!(p.error_indicator.is_some_and(|e| e > 0.0 && e.is_finite()), "{p:?}");
        last = p.iterations;
    }
    Ok(())
}

#[test]
fn the_study_json_shows_the_running_points_with_their_iterations_and_eta() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let (_server, addr) = start_server(&dir.path().join("db"), &dir.path().join("server.log"));
    let url = format!("http://{addr}");
    let rt = runtime();
    let id = rt.block_on(async {
        anyhow::Ok(
            user(&url).await?.submit_study(grid_request(&["f1=0.1,0.2"], STUDY_TOL)).await?.into_inner().study_id,
        )
    })?;
    let api = format!("/api/studies/{id}");
    // the study's JSON (the proto's) read back as the message; its leased points, as they are
    // now, and the same in what an open page polls
    let running = |path: &str| -> anyhow::Result<Vec<v1::PointStatus>> {
        let study: v1::Study = serde_json::from_str(&http_get(&addr, path).2)?;
        Ok(study.points.into_iter().filter(|p| p.state == v1::PointState::Leased as i32).collect())
    };
    let progress = format!("{api}/progress");
    // a pool holds a point but has not reported yet: running, without iterations
    let (mut pool, lease) = rt.block_on(fake_pool(&url, "tester"))?;
    let r = running(&api)?;
    assert_eq!(r.len(), 1, "{r:?}");
    assert_eq!((r[0].point_id, r[0].pool_id.as_str()), (lease.point_id, "tester"), "{r:?}");
    assert_eq!((r[0].iterations, r[0].error_indicator), (0, None), "{r:?}");
    assert_eq!(running(&progress)?, r);
    // its heartbeats report the solve's progress: the latest is what the JSON says
    for (iterations, eta) in [(3, 0.5), (7, 3.2e-2)] {
        rt.block_on(report_progress(&mut pool, "tester", &lease, iterations, eta))?;
    }
    let r = running(&api)?;
    assert_eq!((r[0].iterations, r[0].error_indicator), (7, Some(3.2e-2)), "{r:?}");
    assert_eq!(r[0].parameters.get("f1"), lease.parameters.get("f1"), "{r:?}");
    assert_eq!(running(&progress)?, r);
    // given back, it runs no more
    rt.block_on(pool.release_point(v1::ReleasePointRequest {
        pool_id: "tester".into(),
        lease_id: lease.lease_id,
        study_id: lease.study_id,
        point_id: lease.point_id,
    }))?;
    assert!(running(&api)?.is_empty() && running(&progress)?.is_empty());
    Ok(())
}

#[test]
fn a_pool_fails_a_point_too_big_for_its_memory_with_the_reason_and_lives_on() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let (_server, addr) = start_server(&dir.path().join("db"), &dir.path().join("server.log"));
    let url = format!("http://{addr}");
    // One rank with a budget of 1 MiB: the tiny scene is estimated at several MiB.
    let token = child_token();
    let pool = command(&workspace_bin("glissade-worker"))
        .args(["pool", "--coordinator", &url, "--pool-id", "small", "--memory-mib", "1"])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(File::create(dir.path().join("pool.log"))?)
        .spawn()?;
    let mut pool = ServerGuard(pool, token);
    let rt = runtime();
    let mut client = rt.block_on(user(&url))?;
    let id = rt.block_on(client.submit_study(grid_request(&["f1=0.1,0.2"], STUDY_TOL)))?.into_inner().study_id;
    rt.block_on(watch(&mut client, id, |_| true))?;
    let s = rt.block_on(study(&mut client, id))?;
    assert_eq!(s.state, v1::StudyState::Failed as i32, "{s:?}");
    for p in &s.points {
        assert_eq!(p.state, v1::PointState::Failed as i32, "{p:?}");
        assert!(p.error.contains("MiB this pool has") && p.error.contains("dofs"), "{}", p.error);
    }
    // the pool did not die over it
    assert!(pool.0.try_wait()?.is_none(), "the pool exited: {}", log_of(&dir.path().join("pool.log")));
    Ok(())
}

/// A brass block of our own pushed along a rigid floor hard enough to slide at f = 0.5 and at
/// f = 1.4: through a real pool and the coordinator, each point keeps what its contact did, and
/// `glissade show` warns of the one whose sliding is ill-posed (above friction 1 on a rigid
/// wall, docs/verification.md 4d), and of the other, whose slide chatters (39 landings on 5
/// nodes), with the evidence, where a user reads the study.
#[test]
fn a_study_says_which_points_slide_ill_posed() -> anyhow::Result<()> {
    const BRASS_BLOCK: &str = r#"
dimension = 2
[time]
duration = 2.4e-4
steps = 80
[parameters]
f = { default = 0.5, min = 0.0, max = 3.0 }
[materials.brass]
E = 100e9
nu = 0.34
rho = 8500
[[bodies]]
name = "block"
material = "brass"
size = [0.02, 0.01]
elements = [4, 2]
substructures = [2, 1]
[[interfaces]]
name = "floor"
a = "block.y-"
b = "wall"
law = "friction"
friction = "f"
[[loads]]
face = "block.y+"
pressure = 2.5e6
[[loads]]
face = "block.x-"
traction = [1.6e7, 0]
history = [[0, 0], [2.4e-4, 1]]
[[qoi]]
name = "slip"
kind = "slip"
interface = "floor"
point = [0.01, 0]
"#;
    let dir = tempfile::tempdir()?;
    let scene = dir.path().join("brass.toml");
    std::fs::write(&scene, BRASS_BLOCK)?;
    let (_server, addr) = start_server(&dir.path().join("db"), &dir.path().join("server.log"));
    let url = format!("http://{addr}");
    let _pool = start_single_pool(&url, "brass", &dir.path().join("pool.log"));
    let scene = scene.to_str().expect("a UTF-8 path");
    let out = glissade(
        Some(&url),
        &["submit", scene, "--grid", "f=0.5,1.4", "--strategy", "cold", "--surface-audit", "0", "--json"],
    );
    assert!(out.status.success(), "submit: {}", text(&out.stderr));
    let id = serde_json::from_slice::<serde_json::Value>(&out.stdout)?["study_id"].as_u64().expect("study_id");
    let done = runtime().block_on(async {
        let mut client = user(&url).await?;
        watch(&mut client, id, |_| true).await?;
        study(&mut client, id).await
    })?;
    let pool_log = || log_of(&dir.path().join("pool.log"));
    for p in &done.points {
        assert_eq!(p.state, v1::PointState::Done as i32, "{p:?}\n{}", pool_log());
        let [c] = &p.contact[..] else { panic!("one frictional interface: {p:?}") };
        let f = p.parameters["f"];
        assert_eq!((c.interface.as_str(), c.friction, c.rigid_wall), ("floor", f, true), "{c:?}");
        assert!(c.first_slip_time.is_some_and(|t| t > 0.0) && c.contact_nodes == 5, "it slides: {c:?}");
        assert_eq!(c.ill_posed, f > 1.0, "{c:?}");
    }
    let out = glissade(Some(&url), &["show", &id.to_string()]);
    let shown = text(&out.stdout);
    assert!(out.status.success(), "show: {}", text(&out.stderr));
    assert!(shown.contains("warning   1 of 2 points slide ill-posed: #1 f=1.4"), "{shown}");
    assert!(shown.contains("'floor' slides on a rigid wall at friction 1.4"), "{shown}");
    assert!(shown.contains("warning   1 of 2 points chatter while they slide: #0 f=0.5"), "{shown}");
    assert!(shown.contains("interface 'floor' chatters while it slides: its 5 contact nodes"), "{shown}");
    let out = glissade(Some(&url), &["show", &id.to_string(), "--points", "--json"]);
    let json: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    let flags: Vec<bool> =
        json["points"].as_array().expect("points").iter().map(|p| p["contact"][0]["ill_posed"] == true).collect();
    assert_eq!(flags, [false, true], "{json}");
    let chatters: Vec<bool> =
        json["points"].as_array().expect("points").iter().map(|p| p["contact"][0]["chatters"] == true).collect();
    assert_eq!(chatters, [true, true], "both land more than once a node: {json}");
    // and the web page, where the surface is read
    let (status, _, page) = http_get(&addr, &format!("/studies/{id}"));
    assert_eq!(status, 200, "{page}");
    assert!(page.contains("warning: 1 of 2 points slide ill-posed (#1)"), "{page}");
    assert!(page.contains("ill-posed: 'floor' slides on a rigid wall at friction 1.4"), "{page}");
    assert!(page.contains("warning: 1 of 2 points chatter while they slide (#0)"), "{page}");
    assert!(page.contains("chatters: 'floor' landed"), "{page}");
    let (status, _, api) = http_get(&addr, &format!("/api/studies/{id}"));
    assert_eq!(status, 200, "{api}");
    let api: serde_json::Value = serde_json::from_str(&api)?;
    let flagged: Vec<(bool, bool)> = api["points"]
        .as_array()
        .expect("points")
        .iter()
        .map(|p| (p["contact"][0]["chatters"] == true, p["contact"][0]["ill_posed"] == true))
        .collect();
    assert_eq!(flagged, [(true, false), (true, true)], "{api}");
    assert_one_rendering(&addr, &url, id)?;
    Ok(())
}
