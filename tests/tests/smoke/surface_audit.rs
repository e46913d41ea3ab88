//! A study's surface audit on a real coordinator with a real pool: its held-out points solved
//! cold at 1/100 of the tolerance, and what the study reports (the API, `glissade show`, the web
//! page) is the error of the study's response surface (QuerySurface's predictions, `glissade
//! surface --at`) at those points.

use crate::common::*;

#[test]
fn a_surface_audit_reports_the_error_of_the_surface_at_held_out_solves() -> anyhow::Result<()> {
    const TOL: f64 = 1e-3;
    let dir = tempfile::tempdir()?;
    let (server_log, pool_log) = (dir.path().join("server.log"), dir.path().join("pool.log"));
    let (_server, addr) = start_server(&dir.path().join("db"), &server_log);
    let url = format!("http://{addr}");
    let mut pool = start_single_pool(&url, "pool", &pool_log);
    let rt = runtime();
    let (measured, held, predictions) = rt.block_on(async {
        let mut client = user(&url).await?;
        let request = v1::SubmitStudyRequest {
            audit_points: Some(0),
            refine_points: Some(0),
            // (two: each costs about 2 of the study's cold points, within the cap of half its 16)
            surface_audit_points: Some(2),
            ..grid_request(&["f1=0.1:0.2:4", "f2=0.1:0.2:4"], TOL)
        };
        let id = client.submit_study(request).await?.into_inner().study_id;
        watch(&mut client, id, |_| true).await?;
        let audit = study(&mut client, id).await?.surface_accuracy.expect("a surface audit").audit_study_id;
        watch(&mut client, audit, |_| true).await?;
        let held = study(&mut client, audit).await?;
        // the study's surface, as users read it, at the held-out points
        let request = v1::QuerySurfaceRequest {
            source: Some(v1::query_surface_request::Source::StudyId(id)),
            predict_at: held.points.iter().map(|p| v1::ParameterPoint { parameters: p.parameters.clone() }).collect(),
            ..Default::default()
        };
        let predictions = client.query_surface(request).await?.into_inner().predictions;
        anyhow::Ok((study(&mut client, id).await?, held, predictions))
    })?;
    let logs = || format!("server:\n{}\npool:\n{}", log_of(&server_log), log_of(&pool_log));
    let s = measured.surface_accuracy.clone().expect("measured");
    assert_eq!((s.validated, s.planned, s.fitted), (2, 2, 16), "{s:?}\n{}", logs());
    assert!(held.held_out && held.audit_of == measured.study_id, "{held:?}");
    assert!((held.tolerance - TOL / 100.0).abs() < 1e-15);
    let design: Vec<(f64, f64)> = measured.points.iter().map(|p| (p.parameters["f1"], p.parameters["f2"])).collect();
    for p in &held.points {
        assert_eq!(p.state, v1::PointState::Done as i32, "{p:?}\n{}", logs());
        assert!(
            p.started_from.is_none() && p.error_indicator.is_some_and(|e| e <= TOL / 100.0),
            "cold, at the audit's tolerance: {p:?}"
        );
        let (f1, f2) = (p.parameters["f1"], p.parameters["f2"]);
        assert!((0.1..=0.2).contains(&f1) && (0.1..=0.2).contains(&f2), "{p:?}");
        assert!(!design.contains(&(f1, f2)), "{p:?} is a design point");
    }
    // the reported errors, from the surface's predictions and the held-out solves
    assert_eq!(s.qoi.len(), 3, "{s:?}");
    for (name, reported) in &s.qoi {
        let values = measured.points.iter().chain(&held.points).map(|p| p.qoi[name]);
        let spread = values.clone().fold(f64::MIN, f64::max) - values.fold(f64::MAX, f64::min);
        let errors: Vec<(f64, f64)> = held
            .points
            .iter()
            .zip(&predictions)
            .map(|(p, at)| ((at.qoi[name].mean - p.qoi[name]).abs(), at.qoi[name].std))
            .collect();
        let largest = errors.iter().fold(0.0f64, |m, (e, _)| m.max(*e)) / spread;
        let mean = errors.iter().map(|(e, _)| e).sum::<f64>() / 2.0 / spread;
        let within = errors.iter().filter(|(e, sd)| *e <= 2.0 * sd).count() as f64 / 2.0;
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * a.abs().max(b.abs()).max(1e-300);
        assert!(close(reported.largest, largest) && close(reported.mean, mean), "{name}: {reported:?} {errors:?}");
        assert_eq!((reported.within_2sd, reported.points), (within, 2), "{name}");
    }
    assert!(s.work > 0.0 && s.work <= s.work_cap, "{s:?}");

    // `glissade show`, the web page and its JSON carry it
    let out = glissade(Some(&url), &["show", &measured.study_id.to_string()]);
    assert!(out.status.success(), "show: {}", text(&out.stderr));
    let shown = text(&out.stdout);
    let line = format!("  surface   2 of 2 held-out points (seed {}) solved cold at 1e-5", s.seed);
    assert!(shown.contains(&line), "{shown}");
    assert!(shown.contains("against the surface of 16 points: middle_ux largest"), "{shown}");
    let out = glissade(Some(&url), &["show", &held.study_id.to_string()]);
    assert!(text(&out.stdout).contains("points held out of its surface"), "{}", text(&out.stdout));
    let (status, _, page) = http_get(&addr, &format!("/studies/{}", measured.study_id));
    assert_eq!(status, 200);
    assert!(page.contains("id=\"surface-accuracy\"") && page.contains("2 of 2 held-out points"), "{page}");
    let (_, _, json) = http_get(&addr, &format!("/api/studies/{}", measured.study_id));
    let json: serde_json::Value = serde_json::from_str(&json)?;
    let slip = &json["surface_accuracy"]["qoi"]["slip_A"];
    assert_eq!(slip["largest"].as_f64(), Some(s.qoi["slip_A"].largest), "{json}");
    // (a 64-bit integer: a string in the proto's JSON)
    assert_eq!(json["surface_accuracy"]["seed"], s.seed.to_string(), "{json}");
    assert_one_rendering(&addr, &url, measured.study_id)?;
    assert!(terminate(&mut pool.0).success());
    Ok(())
}

/// `--surface-accuracy` through the real CLI, coordinator and pool: a target that a few points
/// reach stops the study there and says so; one they cannot reach spends the budget and says
/// that. The outcome is checked against the cross-validation of the points the pool solved,
/// recomputed here from the API's values (core's leave-one-out, the measure the coordinator
/// judges with): reached at the first count of points where every QoI's estimated largest error
/// in the box is within the target, not one point later.
#[test]
fn a_target_stops_an_adaptive_study_once_its_surfaces_are_within_it() -> anyhow::Result<()> {
    use glissade_core::point::DesignPoint;
    use glissade_core::study::adaptive::{AdaptiveDesign, QoiReadings};
    use glissade_core::study::space::ParameterSpace;
    let dir = tempfile::tempdir()?;
    let (server_log, pool_log) = (dir.path().join("server.log"), dir.path().join("pool.log"));
    let (_server, addr) = start_server(&dir.path().join("db"), &server_log);
    let url = format!("http://{addr}");
    let mut pool = start_single_pool(&url, "pool", &pool_log);
    let logs = || format!("server:\n{}\npool:\n{}", log_of(&server_log), log_of(&pool_log));
    let scene_path = shipped_scene("three-blocks-tiny.toml");
    let scene_text = std::fs::read_to_string(&scene_path)?;
    let scene = glissade_core::scene::Scene::parse(&scene_text)?;
    let space = ParameterSpace::from_scene(&scene);
    let ranges = ["f1=0.1:0.2".to_owned(), "f2=0.1:0.2".to_owned()];
    // (target, budget, extra arguments): a loose target at its own tolerance (target / 300), and
    // one that 10 points cannot reach, at a given tolerance
    let runs: [(f64, usize, &[&str]); 2] = [(0.25, 16, &[]), (1e-3, 10, &["--tol", "1e-3"])];
    let mut outcomes = Vec::new();
    for (target, budget, extra) in runs {
        let (t, b) = (target.to_string(), budget.to_string());
        let mut args =
            vec!["submit", scene_path.to_str().expect("utf-8"), "--range", &ranges[0], "--range", &ranges[1]];
        args.extend(["--surface-accuracy", &t, "--adaptive", &b, "--audit", "0", "--refine", "0", "--json"]);
        args.extend(extra);
        let out = glissade(Some(&url), &args);
        assert!(out.status.success(), "{}\n{}", text(&out.stderr), logs());
        let id = serde_json::from_slice::<serde_json::Value>(&out.stdout)?["study_id"].as_u64().expect("an id");
        let (s, audit) = runtime().block_on(async {
            let mut client = user(&url).await?;
            watch(&mut client, id, |_| true).await?;
            let audit = study(&mut client, id).await?.surface_accuracy.expect("a surface audit").audit_study_id;
            watch(&mut client, audit, |_| true).await?;
            anyhow::Ok((study(&mut client, id).await?, study(&mut client, audit).await?))
        })?;
        let reported = s.target.clone().expect("a target");
        assert_eq!((reported.surface_accuracy, reported.budget as usize), (target, budget), "{reported:?}");
        let tolerance = if extra.is_empty() { target / 300.0 } else { 1e-3 };
        assert!((s.tolerance - tolerance).abs() <= 1e-12 * tolerance, "{} against {tolerance}", s.tolerance);
        // the cross-validation after each point the pool solved (one pool: in the order chosen)
        let mut done: Vec<&v1::PointStatus> =
            s.points.iter().filter(|p| p.state == v1::PointState::Done as i32).collect();
        done.sort_by_key(|p| p.point_id);
        let design = AdaptiveDesign::parse(&ranges, budget, Some(target), &space, 1000).map_err(anyhow::Error::msg)?;
        let points: Vec<(DesignPoint, std::collections::BTreeMap<String, f64>)> = done
            .iter()
            .map(|p| (DesignPoint::try_from(p.parameters.clone()).unwrap(), p.qoi.clone().into_iter().collect()))
            .collect();
        let validation = |k: usize| {
            let chosen: Vec<_> = points[..k].iter().map(|(p, q)| (p.clone(), Some(q))).collect();
            design.surfaces(&space, &QoiReadings::of(&scene), &chosen).cross_validate()
        };
        let first_within = (design.validated_after()..=done.len()).find(|&k| design.target_reached(&validation(k)));
        let n = done.len();
        match reported.outcome.as_str() {
            "reached" => assert_eq!(first_within, Some(n), "reached at the first point within, no point after"),
            "budget" => assert_eq!((first_within, n), (None, budget), "never within, every point of the budget"),
            other => panic!("outcome {other:?}: {reported:?}\n{}", logs()),
        }
        assert_eq!(reported.points as usize, n);
        let expected = validation(n);
        assert_eq!(reported.qoi.len(), expected.qoi.len(), "{reported:?}");
        for (q, e) in &expected.qoi {
            let r = &reported.qoi[q];
            assert!((r.mean - e.mean).abs() <= 1e-9 * e.mean.max(1e-300), "{q}: {r:?} against {e:?}");
            assert!((r.largest - e.largest).abs() <= 1e-9 * e.largest.max(1e-300), "{q}: {r:?} against {e:?}");
            let b = e.box_largest.expect("an estimate over the box");
            assert!((r.box_largest - b).abs() <= 1e-9 * b.max(1e-300), "{q}: {r:?} against {e:?}");
        }
        // its held-out points were leased after it (within their cost cap: a study this cheap
        // affords few of them cold at 1/100 of its tolerance), and `show`, the web page and the
        // API say the same
        assert!(audit.held_out && audit.audit_of == id, "{audit:?}");
        let shown = text(&glissade(Some(&url), &["show", &id.to_string()]).stdout);
        let verdict = match reported.outcome.as_str() {
            "reached" => format!("REACHED at {n} points (budget {budget})"),
            _ => format!("NOT REACHED: the budget of {budget} points was spent; at {n} points"),
        };
        assert!(shown.contains(&verdict), "{shown}");
        let (_, _, page) = http_get(&addr, &format!("/studies/{id}"));
        assert!(page.contains("id=\"target\""), "{page}");
        let (_, _, json) = http_get(&addr, &format!("/api/studies/{id}"));
        let json: serde_json::Value = serde_json::from_str(&json)?;
        assert_eq!(json["target"]["outcome"], reported.outcome.as_str(), "{json}");
        // the estimate the target was judged on, in /api and in `show --json`
        let shown_json: serde_json::Value =
            serde_json::from_slice(&glissade(Some(&url), &["show", &id.to_string(), "--json"]).stdout)?;
        for (q, r) in &reported.qoi {
            assert_eq!(json["target"]["qoi"][q]["box_largest"], r.box_largest, "{json}");
            assert_eq!(shown_json["target"]["qoi"][q]["box_largest"], r.box_largest, "{shown_json}");
        }
        outcomes.push(reported.outcome);
    }
    // each run ends its own way: a test of both
    assert_eq!(outcomes, ["reached", "budget"], "{}", logs());
    assert!(terminate(&mut pool.0).success());
    Ok(())
}
