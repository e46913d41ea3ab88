//! What a new user hits (issue 25), through the real binaries: the figures `show`, `watch` and
//! `fields` print agree with the README, numbers read at the precision they carry, and wrong
//! arguments get one line that names the cause.

use crate::common::*;

/// Argument errors from the parser: one line, exit status 1 (as every other error), naming the
/// flag that is missing, and a usage that does not make `--server` look required.
#[test]
fn argument_errors_are_one_line_with_status_1_and_name_the_missing_flag() {
    let scene = tiny_path();
    // --range alone: the flag missing is --adaptive, not --grid
    let out = glissade(None, &["submit", &scene, "--range", "f1=0.1:0.2"]);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out.stderr));
    assert_one_line_error(&out, "--adaptive <N>");
    assert!(!text(&out.stderr).contains("--grid"), "{}", text(&out.stderr));
    // a server from the environment: its option is not printed as if it were required
    let mut cmd = command(&workspace_bin("glissade"));
    cmd.env("GLISSADE_SERVER", "http://127.0.0.1:1").args(["submit", &scene]);
    let out = run_with_timeout(&mut cmd, LIMIT);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out.stderr));
    assert_one_line_error(&out, "--grid <NAME=SPEC>");
    assert!(!text(&out.stderr).contains("--server"), "{}", text(&out.stderr));
    // help is not an error
    let out = glissade(None, &["submit", "--help"]);
    assert!(out.status.success() && text(&out.stdout).contains("Usage: glissade submit"));
}

#[test]
fn show_watch_fields_and_slices_say_what_the_readme_says() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let logs = [dir.path().join("server.log"), dir.path().join("pool.log")];
    let all_logs = || logs.iter().map(|l| format!("{}:\n{}", l.display(), log_of(l))).collect::<Vec<_>>().join("\n");
    let (_server, addr) = start_server(&dir.path().join("db"), &logs[0]);
    let url = format!("http://{addr}");
    let _pool = start_pool(&url, "first-pool", &logs[1]);
    let scene = tiny_path();
    let out = glissade(
        Some(&url),
        &["submit", &scene, "--grid", "f1=0.1:0.2:3", "--grid", "f2=0.1:0.2:3", "--tol", "1e-3", "--watch"],
    );
    assert!(out.status.success(), "{}\n{}\n{}", text(&out.stdout), text(&out.stderr), all_logs());

    // `show ID` has the cold/warm work line the README promises (not only with --points)
    let out = glissade(Some(&url), &["show", "1"]);
    let shown = text(&out.stdout);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(shown.contains("  work      warm starts cost"), "{shown}");
    // `watch` on a finished study: its summary has the means, not `-`
    let out = glissade(Some(&url), &["watch", "1"]);
    let watched = text(&out.stdout);
    assert!(watched.contains("study 1 done: 9/9 done") && !watched.contains("cold - warm -"), "{watched}");

    // `fields` at a stored point: 1 iteration of each stage (static, dynamic), as its help says
    let h5 = dir.path().join("p.h5");
    let out = glissade(
        Some(&url),
        &["fields", "1", "--point", "f1=0.15,f2=0.15", "--out", h5.to_str().expect("utf-8"), "--json"],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let fields: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    assert_eq!((&fields["dynamic_iterations"], &fields["iterations"]), (&1.into(), &2.into()), "{fields}");

    // a slip that sticks (f1 = 0.2: 1e-21 m beside 1e-5 m) reads 0 in the table, and keeps its
    // stored value in JSON
    let table = text(&glissade(Some(&url), &["surface", "1", "--qoi", "slip_A"]).stdout);
    let stuck: Vec<&str> = table.lines().filter(|l| l.trim_start().starts_with("0.2 ")).collect();
    assert_eq!(stuck.len(), 3, "{table}");
    assert!(stuck.iter().all(|l| l.split_whitespace().nth(2) == Some("0")), "{table}");
    let json: serde_json::Value =
        serde_json::from_slice(&glissade(Some(&url), &["surface", "1", "--qoi", "slip_A", "--json"]).stdout)?;
    let stored: Vec<f64> = json["points"]
        .as_array()
        .expect("points")
        .iter()
        .filter(|p| p["parameters"]["f1"] == 0.2)
        .map(|p| p["qoi"]["slip_A"].as_f64().expect("slip"))
        .collect();
    assert!(stored.iter().any(|&s| s != 0.0 && s.abs() < 1e-15), "{stored:?}");

    // a slice where no point is: the cause and the values there are, in the CLI and on the web
    assert_one_line_error(
        &glissade(Some(&url), &["surface", "1", "--qoi", "slip_A", "--fix", "f2=0.13"]),
        "no point has f2 = 0.13 (f2 takes 0.1, 0.15, 0.2)",
    );
    let (status, _, page) = http_get(&addr, "/studies/1?fix=f2=0.13");
    assert_eq!(status, 200);
    assert!(page.contains("no point has f2 = 0.13 (f2 takes 0.1, 0.15, 0.2)"), "{page}");
    assert!(!page.contains("no point done yet"), "{page}");

    // studies at a glance: kind, scene title, submitted, wall time; in the CLI and on the web
    let out = glissade(Some(&url), &["studies"]);
    let list = text(&out.stdout);
    let row = list.lines().find(|l| l.trim_start().starts_with("1 ")).expect("study 1 listed");
    assert!(row.contains(" grid ") && row.contains(" UTC") && row.contains("three blocks (tiny)"), "{list}");
    assert!(!row.split_whitespace().any(|w| w == "-"), "a wall time: {list}");
    // its audits under it: counted on its row, listed with --all, named by `show`
    assert!(!list.lines().any(|l| l.trim_start().starts_with("2 ")), "audits under their study: {list}");
    assert!(row.contains(" ended ") || row.contains(" running "), "{list}");
    let all = text(&glissade(Some(&url), &["studies", "--all"]).stdout);
    assert!(all.lines().any(|l| l.trim_start().starts_with("2 ") && l.contains(" audit ")), "{all}");
    let shown = text(&glissade(Some(&url), &["show", "1"]).stdout);
    assert!(shown.contains("  kind      grid, submitted ") && shown.contains("(wall time "), "{shown}");
    assert!(shown.contains("  audit     iteration (study 2): "), "{shown}");
    let (_, _, index) = http_get(&addr, "/");
    assert!(index.contains("<td>grid</td>") && index.contains("three blocks (tiny)"), "{index}");
    assert!(!index.contains("<td>audit</td>") && index.contains("<th>audits</th>"), "{index}");
    let (_, _, page) = http_get(&addr, "/studies/1");
    assert!(page.contains("id=\"audits\"") && page.contains("href=\"/studies/2\""), "{page}");
    // a failed point says why, in `show` and on the study page
    let out = glissade(
        Some(&url),
        &["submit", &scene, "--grid", "f1=0.12", "--max-iter", "2", "--audit", "0", "--refine", "0", "--watch"],
    );
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stderr));
    // (its id from `study N submitted`: audits and discretisation levels take ids too)
    let id: u64 = text(&out.stdout)
        .strip_prefix("study ")
        .and_then(|t| t.split_whitespace().next()?.parse().ok())
        .expect("study N submitted");
    let shown = text(&glissade(Some(&url), &["show", &id.to_string()]).stdout);
    assert!(shown.contains("  failed    #0 f1=0.12: not converged"), "{shown}");
    let (_, _, page) = http_get(&addr, &format!("/studies/{id}"));
    assert!(page.contains("<td class=\"note\">not converged"), "{page}");
    Ok(())
}
