//! The `glissade` CLI against a real coordinator and pool: submit, watch, show, surfaces, predictions, fields, adaptive studies, the demo.

use crate::common::*;

#[test]
fn cli_demo_runs_a_study_and_draws_its_pictures() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let out_dir = dir.path().join("demo");
    let out = glissade(None, &["demo", "--grid", "3", "--out", out_dir.to_str().expect("utf-8")]);
    assert!(out.status.success(), "demo failed:\n{}\n{}", text(&out.stdout), text(&out.stderr));
    let stdout = text(&out.stdout);
    // plain progress lines without a terminal (the study's 9 points, its audit's 2, its
    // discretisation audit's 2), the summary, the surface table, the measured accuracy and time
    // step's error, and which dominates
    // the study's points, its audit's, its dt / 2 level's and those held out of its surface (a
    // quarter of 9 at most); with a pool a core the held-out points may end before the demo
    // watches them ("study 4 done ... watched 0.0 s": their lines are then not printed, their
    // summary below is)
    let lines = stdout.matches("done (f1=").count();
    assert!(lines == 9 + 2 + 2 + 2 || (lines == 9 + 2 + 2 && stdout.contains("watched 0.0 s")), "{lines}: {stdout}");
    assert!(
        stdout.contains("surface accuracy (errors relative to each QoI's spread): 2 of 2 held-out points (seed ")
            && stdout.contains(") solved cold at 2e-6"),
        "{stdout}"
    );
    assert!(stdout.contains("measured accuracy: 2 of 2 points re-solved cold at 2e-6"), "{stdout}");
    assert!(stdout.contains("time step's error: 2 of 2 points re-solved at dt / 2 (study 3; "), "{stdout}");
    // which error dominates, QoI by QoI (not the largest of one QoI against another's)
    let verdicts: Vec<&str> =
        stdout.lines().filter(|l| l.contains(" error (") && l.contains(" dominates the ")).collect();
    assert_eq!(verdicts.len(), 3, "{stdout}");
    for q in ["middle_ux: ", "slip_A: ", "slip_B: "] {
        assert!(verdicts.iter().any(|l| l.starts_with(q)), "{q}: {stdout}");
    }
    assert_eq!(stdout.matches("study 1 done").count(), 1, "said once: {stdout}");
    assert!(stdout.contains("study 1 done: 9/9 done"), "{stdout}");
    assert!(stdout.contains("x less work than cold ones"), "{stdout}");
    assert!(stdout.lines().any(|l| l.split_whitespace().take(2).eq(["f1", "f2"])), "{stdout}");
    assert_eq!(png_size(&out_dir.join("slip_A.png")), (1200, 560));
    assert_eq!(png_size(&out_dir.join("convergence.png")), (900, 600));
    let csv = std::fs::read_to_string(out_dir.join("surface.csv"))?;
    assert_eq!(csv.lines().next(), Some("f1,f2,middle_ux,slip_A,slip_B,iterations,eta,state"));
    assert_eq!(csv.lines().filter(|l| l.ends_with(",done")).count(), 9, "{csv}");
    // then sliding-block-2d asked for 5 %: the level its pilot chose, confirmed one level finer,
    // and per QoI the estimate read where dt and h were halved together
    assert!(stdout.contains("asked for an accuracy instead of a tolerance: sliding-block-2d"), "{stdout}");
    assert!(stdout.contains("  level     REACHED at dt / "), "{stdout}");
    assert!(stdout.contains("CONFIRMED: every difference within half the accuracy"), "{stdout}");
    for q in ["friction_force", "normal_force", "slip_centre"] {
        let line = stdout.lines().find(|l| l.trim_start().starts_with(&format!("{q}: "))).expect(q);
        assert!(line.contains("(dt and h together ") && !line.contains("ABOVE"), "{line}");
    }
    Ok(())
}

#[test]
fn cli_submits_watches_and_reads_surfaces_and_fields() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let logs = [dir.path().join("server.log"), dir.path().join("pool.log")];
    let all_logs = || logs.iter().map(|l| format!("{}:\n{}", l.display(), log_of(l))).collect::<Vec<_>>().join("\n");
    let (_server, addr) = start_server(&dir.path().join("db"), &logs[0]);
    let url = format!("http://{addr}");
    let _pool = start_pool(&url, "cli-pool", &logs[1]);
    let scene = shipped_scene("three-blocks-tiny.toml");
    let scene = scene.to_str().expect("utf-8");
    let path = |name: &str| dir.path().join(name).to_str().expect("utf-8").to_owned();

    // submit --watch: plain lines per event (no terminal here), then the summary
    let out = glissade(
        Some(&url),
        &["submit", scene, "--grid", "f1=0.1:0.2:3", "--grid", "f2=0.1:0.2:3", "--tol", "1e-3", "--watch"],
    );
    let stdout = text(&out.stdout);
    assert!(out.status.success(), "submit --watch: {stdout}\n{}\n{}", text(&out.stderr), all_logs());
    assert!(stdout.starts_with("study 1 submitted: 9 points\n"), "{stdout}");
    assert_eq!(stdout.matches(" started on cli-pool ").count(), 9, "{stdout}");
    assert_eq!(stdout.matches(" done (f1=").count(), 9, "{stdout}");
    assert!(stdout.contains("study 1 done: 9/9 done, 0 running, 0 pending; mean work cold"), "{stdout}");

    // watching a finished study replays it silently and prints the same summary
    let out = glissade(Some(&url), &["watch", "1"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(text(&out.stdout).contains("study 1 done: 9/9 done"), "{}", text(&out.stdout));

    // the stored results, straight from the API
    let rt = runtime();
    let stored = rt.block_on(async { study(&mut user(&url).await?, 1).await })?;
    let stored_slip = |f1: f64, f2: f64| {
        let p = stored.points.iter().find(|p| p.parameters["f1"] == f1 && p.parameters["f2"] == f2).expect("point");
        p.qoi["slip_A"]
    };

    // CSV and JSON give back exactly the stored QoIs
    let out = glissade(Some(&url), &["surface", "1", "--qoi", "slip_A", "--csv", &path("s.csv")]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let csv = std::fs::read_to_string(path("s.csv"))?;
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some("f1,f2,slip_A,iterations,eta,state"));
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 9);
    for r in &rows {
        let (f1, f2, slip): (f64, f64, f64) = (r[0].parse()?, r[1].parse()?, r[2].parse()?);
        assert_eq!(slip.to_bits(), stored_slip(f1, f2).to_bits(), "{r:?}");
    }
    let out = glissade(Some(&url), &["surface", "1", "--qoi", "slip_A", "--fix", "f2=0.15", "--json"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let json: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    let points = json["points"].as_array().expect("points");
    assert_eq!(points.len(), 3, "{json}");
    for p in points {
        let (f1, f2) = (p["parameters"]["f1"].as_f64().expect("f1"), p["parameters"]["f2"].as_f64().expect("f2"));
        assert_eq!(f2, 0.15);
        assert_eq!(p["qoi"]["slip_A"].as_f64(), Some(stored_slip(f1, f2)), "{p}");
    }
    // the table for people
    let out = glissade(Some(&url), &["surface", "1", "--qoi", "slip_A"]);
    assert_eq!(text(&out.stdout).lines().count(), 10, "{}", text(&out.stdout));
    // the web page on the same port as gRPC: the study with each QoI's response surface (its 9
    // points on top), its table, downloads, and the JSON API
    let (status, kind, page) = http_get(&addr, "/studies/1");
    assert_eq!((status, kind.as_str()), (200, "text/html; charset=utf-8"), "{page}");
    assert_eq!(page.matches("data-surface=\"true\"").count(), 3, "{page}");
    assert_eq!(page.matches("<circle class=\"point\"").count(), 9 * 3, "{page}");
    assert!(page.contains("<table id=\"points\">") && page.contains("measured accuracy"), "{page}");
    assert!(page.contains("<svg class=\"convergence\" data-series=\"9\""), "a convergence line per point: {page}");
    // labelled contour lines on the maps; the QoIs' units from the scene
    assert!(page.contains("mean of slip_A [× 1e-5 m]") && page.contains("mean of middle_ux [× 1e-5 m]"), "{page}");
    let contours: Vec<usize> =
        page.split("data-contours=\"").skip(1).filter_map(|t| t.split('"').next()?.parse().ok()).collect();
    assert!(contours.len() == 3 && contours.iter().all(|&n| n >= 3), "round levels on each map: {contours:?}");
    // a slice: the curves over f1 at f2 = 0.15, 3 points per QoI
    let (status, _, slice) = http_get(&addr, "/studies/1?fix=f2=0.15");
    assert_eq!(status, 200);
    assert_eq!(slice.matches("<circle class=\"point\"").count(), 3 * 3, "{slice}");
    assert!(http_get(&addr, "/").2.contains("work cold"));
    let (status, kind, csv) = http_get(&addr, "/api/studies/1/surface.csv");
    assert_eq!((status, kind.as_str()), (200, "text/csv; charset=utf-8"));
    assert!(csv.contains("f1,f2,middle_ux,slip_A,slip_B,state"), "{csv}");
    let (status, kind, list) = http_get(&addr, "/api/studies");
    assert_eq!((status, kind.as_str()), (200, "application/json"));
    // ListStudies' studies in the proto's JSON (64-bit integers as strings)
    let listed: Vec<v1::Study> = serde_json::from_str(&list)?;
    assert_eq!(listed.first().map(|s| s.study_id), Some(1), "{list}");
    assert!(list.contains("\"study_id\":\"1\""), "{list}");
    assert_eq!(http_get(&addr, "/studies/999").0, 404);
    assert_eq!(http_get(&addr, "/").0, 200);
    // what an open page polls: the study with its running points only, not every point
    let (status, _, progress) = http_get(&addr, "/api/studies/1/progress");
    assert_eq!(status, 200);
    let progress: serde_json::Value = serde_json::from_str(&progress)?;
    assert_eq!(
        (&progress["state"], &progress["progress"]["done"]),
        (&serde_json::json!("STUDY_STATE_DONE"), &serde_json::json!(9))
    );
    assert!(progress["points"].as_array().is_some_and(Vec::is_empty), "{progress}");
    // the one rendering: the API's JSON and `show --json` are GetStudy's study (its audits too)
    let study = assert_one_rendering(&addr, &url, 1)?;
    assert!(study.accuracy.is_some() && study.points.len() == 9, "{study:?}");
    assert_eq!(http_get(&addr, "/api/studies/999/progress").0, 404);
    assert_eq!(http_get(&addr, "/api/studies/x/progress").0, 404);
    // the list's mean work, read in place: cold and warm of study 1
    let index = http_get(&addr, "/").2;
    let row = index.split("<tr>").find(|r| r.contains("href=\"/studies/1\"")).expect("study 1's row");
    let cells: Vec<&str> = row.split("<td>").map(|c| c.split("</td>").next().unwrap_or("")).collect();
    assert!(cells.iter().rev().take(2).all(|c| c.parse::<f64>().is_ok_and(|w| w > 0.0)), "{row}");

    // predictions with error bars: a stored point gives its value back, less surely between
    let out = glissade(
        Some(&url),
        &["surface", "1", "--qoi", "slip_A", "--at", "f1=0.15,f2=0.15", "--at", "f1=0.125,f2=0.125", "--json"],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let json: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    let (on, between) = (&json["points"][0]["qoi"]["slip_A"], &json["points"][1]["qoi"]["slip_A"]);
    let mean = on["mean"].as_f64().expect("mean");
    assert!((mean - stored_slip(0.15, 0.15)).abs() <= 1e-3 * stored_slip(0.15, 0.15).abs().max(1e-12), "{json}");
    assert!(on["std"].as_f64() < between["std"].as_f64(), "{json}");
    let out = glissade(Some(&url), &["surface", "1", "--qoi", "slip_A", "--at", "f1=0.15,f2=0.15"]);
    assert!(text(&out.stdout).starts_with("f1=0.15 f2=0.15  slip_A = "), "{}", text(&out.stdout));
    assert_one_line_error(&glissade(Some(&url), &["surface", "1", "--at", "f1=0.15"]), "give every swept parameter");
    // outside the box: refused, not `NaN +- 0`
    assert_one_line_error(
        &glissade(Some(&url), &["surface", "1", "--qoi", "slip_A", "--at", "f1=1e300,f2=0.15"]),
        "`f1` = 1e300 is outside the box the surface covers, [0.1, 0.2]",
    );

    // pictures of the stated size: a colour map, a curve (one free parameter), the convergence
    for (args, size) in [
        (vec!["surface", "1", "--qoi", "slip_A", "--png", &path("map.png"), "--size", "640x480"], (640, 480)),
        (vec!["surface", "1", "--qoi", "slip_B", "--fix", "f1=0.1", "--png", &path("curve.png")], (1200, 560)),
        (vec!["convergence", "1", "--png", &path("conv.png"), "--size", "800x500"], (800, 500)),
    ] {
        let out = glissade(Some(&url), &args);
        assert!(out.status.success(), "{args:?}: {}", text(&out.stderr));
        assert_eq!(png_size(Path::new(args[args.iter().position(|a| *a == "--png").expect("png") + 1])), size);
    }
    let out = glissade(Some(&url), &["convergence", "1", "--json"]);
    let json: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    for p in json["points"].as_array().expect("points") {
        let history = p["eta_history"].as_array().expect("history");
        let last = history.last().and_then(|v| v.as_f64()).expect("a history");
        let point = &stored.points[p["point_id"].as_u64().expect("id") as usize];
        assert_eq!(Some(last), point.error_indicator, "the history ends at the point's eta");
    }

    // studies / show / cancel
    let out = glissade(Some(&url), &["studies", "--json"]);
    let list: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    assert_eq!(list[0]["state"], "STUDY_STATE_DONE", "{list}");
    let out = glissade(Some(&url), &["cancel", "1"]);
    assert_one_line_error(&out, "FailedPrecondition");

    // fields of a point between the grid's: re-solved from its nearest neighbour, read by h5py
    let out = glissade(Some(&url), &["fields", "1", "--point", "f1=0.12,f2=0.15", "--out", &path("p.h5"), "--json"]);
    assert!(out.status.success(), "fields: {}", text(&out.stderr));
    let fields: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    assert_eq!(fields["started_from"]["parameters"]["f1"], 0.1, "{fields}");
    assert!(Path::new(&path("p.xdmf")).is_file());
    let check = r#"
import sys, h5py, numpy as np
with h5py.File(sys.argv[1], "r") as f:
    x = f["mesh/coordinates"][...]
    top = f["mesh/topology"][...]
    t = f["time"][...]
    u0 = f["fields/displacement/000000"][...]
    u = f["fields/displacement/%06d" % (len(t) - 1)][...]
    assert x.shape[1] == 3 and top.shape[1] == 8 and u.shape == x.shape, (x.shape, top.shape, u.shape)
    assert len(t) == 51 and abs(t[-1] - 2e-4) < 1e-15, t[-1]
    # the prestress: the top face is pushed down by 0.1 mm before the dynamics start
    z_top = x[:, 2].max()
    on_top = np.isclose(x[:, 2], z_top)
    assert np.allclose(u0[on_top, 2], -1e-4, rtol=1e-9, atol=1e-15), u0[on_top, 2]
    print(x.shape[0], top.shape[0])
"#;
    let out = run_with_timeout(Command::new("/usr/bin/python3").args(["-c", check, &path("p.h5")]), LIMIT);
    assert!(out.status.success(), "h5py check (deploy/install-deps.sh installs python3-h5py): {}", text(&out.stderr));

    // bad input: one line and a non-zero exit each
    assert_one_line_error(&glissade(Some(&url), &["show", "999"]), "NotFound");
    assert_one_line_error(&glissade(Some(&url), &["surface", "1", "--qoi", "slip_C"]), "unknown QoI `slip_C`");
    assert_one_line_error(&glissade(Some(&url), &["surface", "1", "--fix", "f9=0.1"]), "not a swept parameter");
    assert_one_line_error(&glissade(Some(&url), &["submit", scene, "--grid", "f1=0.2:0.1:0"]), "--grid: ");
    assert_one_line_error(
        &glissade(Some(&url), &["fields", "1", "--point", "f1=0.1", "--out", &path("q.h5")]),
        "every swept parameter",
    );
    assert_one_line_error(
        &glissade(Some("http://127.0.0.1:9"), &["studies"]),
        "cannot reach glissade server at http://127.0.0.1:9",
    );
    assert_one_line_error(
        &glissade(Some(&url), &["submit", scene, "--range", "f1=0.2:0.1", "--adaptive", "5"]),
        "LOW must be below HIGH",
    );

    // an adaptive study: 6 distinct points inside the box, chosen as the pool asks, then done
    let out = glissade(
        Some(&url),
        &[
            "submit",
            scene,
            "--range",
            "f1=0.1:0.2",
            "--range",
            "f2=0.1:0.2",
            "--adaptive",
            "6",
            "--tol",
            "1e-3",
            "--json",
        ],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let submitted = serde_json::from_slice::<serde_json::Value>(&out.stdout)?;
    assert_eq!(submitted["points"], 6, "its budget, not the 0 chosen yet: {submitted}");
    let id = submitted["study_id"].to_string();
    let out = glissade(Some(&url), &["watch", &id]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    // its points print at 6 significant digits at most (0.197852, not 0.19785156250000002)
    let listed = text(&glissade(Some(&url), &["show", &id, "--points"]).stdout);
    let values: Vec<&str> =
        listed.split_whitespace().filter_map(|w| w.strip_prefix("f1=").or(w.strip_prefix("f2="))).collect();
    assert!(values.len() >= 12, "{listed}");
    assert!(values.iter().all(|v| v.trim_start_matches("0.").len() <= 6), "{listed}");
    let out = glissade(Some(&url), &["show", &id, "--points", "--json"]);
    let shown: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    assert_eq!((&shown["state"], &shown["progress"]["done"]), (&"STUDY_STATE_DONE".into(), &6.into()), "{shown}");
    // each QoI's unit, in the JSON and on each point's line
    assert_eq!(shown["units"]["slip_A"], "m", "{shown}");
    assert!(
        listed.contains(" slip_A=") && listed.lines().filter(|l| l.contains(" slip_A=")).all(|l| l.contains(" m ")),
        "{listed}"
    );
    let points = shown["points"].as_array().expect("points");
    let at: Vec<(f64, f64)> = points
        .iter()
        .map(|p| (p["parameters"]["f1"].as_f64().unwrap(), p["parameters"]["f2"].as_f64().unwrap()))
        .collect();
    for (i, &(f1, f2)) in at.iter().enumerate() {
        assert!((0.1..=0.2).contains(&f1) && (0.1..=0.2).contains(&f2), "{at:?}");
        assert!(!at[..i].contains(&(f1, f2)), "{at:?}");
    }
    Ok(())
}

/// `glissade demo | head -2`: the demo exits at the closed pipe without unwinding (as Unix tools
/// do), which skips its children's `kill_on_drop`; the kernel must end its coordinator and pools
/// with it (PR_SET_PDEATHSIG), or they run on, orphaned, on the user's machine.
#[test]
fn a_demo_whose_reader_goes_away_leaves_no_coordinator_behind() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let token = child_token();
    let child = command(&workspace_bin("glissade"))
        .args(["demo", "--grid", "2", "--out"])
        .arg(dir.path().join("demo"))
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()?;
    // killed and reaped should an assertion below fail first
    let mut demo = ServerGuard(child, token);
    let mut lines = BufReader::new(demo.0.stdout.take().expect("piped"));
    let mut first = String::new();
    lines.read_line(&mut first)?;
    // "coordinator on http://127.0.0.1:PORT (database in ...)"
    let addr: SocketAddr = first
        .strip_prefix("coordinator on http://")
        .and_then(|rest| rest.split_whitespace().next())
        .and_then(|a| a.parse().ok())
        .unwrap_or_else(|| panic!("no address in {first:?}"));
    assert!(std::net::TcpStream::connect(addr).is_ok(), "the coordinator listens while the demo runs");
    drop(lines);
    assert!(wait_with_timeout(&mut demo.0, LIMIT).is_some(), "the demo did not end when its reader went away");
    // its coordinator went with it: the port refuses (a SIGKILLed process's socket closes at once)
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    while std::net::TcpStream::connect(addr).is_ok() {
        assert!(std::time::Instant::now() < deadline, "the demo's coordinator on {addr} outlived it");
        std::thread::sleep(Duration::from_millis(50));
    }
    Ok(())
}
