//! The web page in a real browser: headless Chromium (installed by deploy/install-deps.sh) loads
//! a study's page from the coordinator, runs its script, and the test reads the DOM it drew.

use crate::common::*;

/// The page's DOM after its scripts ran (3 s of the browser's virtual time).
fn rendered(url: &str) -> String {
    let out = run_with_timeout(
        Command::new("chromium").args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--virtual-time-budget=3000",
            "--dump-dom",
            url,
        ]),
        LIMIT,
    );
    assert!(out.status.success(), "chromium: {}", text(&out.stderr));
    text(&out.stdout)
}

#[test]
fn a_browser_draws_the_study_page_and_follows_its_progress() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let (server_log, pool_log) = (dir.path().join("server.log"), dir.path().join("pool.log"));
    let (_server, addr) = start_server(&dir.path().join("db"), &server_log);
    let url = format!("http://{addr}");
    let rt = runtime();
    let id = rt.block_on(async {
        let mut client = user(&url).await?;
        let mut request = grid_request(&["f1=0.1:0.2:3", "f2=0.1:0.2:3"], STUDY_TOL);
        request.label = "browser test".into();
        anyhow::Ok(client.submit_study(request).await?.into_inner().study_id)
    })?;
    let page = format!("{url}/studies/{id}");

    // One point held by a pool that reported its solve's progress; the others wait. The page's
    // script polls the progress and lists the running point (the server draws no row of it).
    let (mut fake, lease) = rt.block_on(fake_pool(&url, "fake"))?;
    rt.block_on(report_progress(&mut fake, "fake", &lease, 7, 3.2e-2))?;
    let waiting = rendered(&page);
    assert!(waiting.contains("<h1>study 1: browser test</h1>"), "{waiting}");
    assert!(waiting.contains("active: 0 of 9 done, 1 running"), "{waiting}");
    let polled =
        waiting.split("data-polled=\"").nth(1).and_then(|s| s.split('"').next()).and_then(|n| n.parse::<u32>().ok());
    assert!(polled.is_some_and(|n| n >= 1), "the script polled the API: {waiting}");
    let row = format!("<tr><td>{}</td>", lease.point_id);
    let running =
        waiting.split("<table id=\"running\">").nth(1).and_then(|t| t.split("</table>").next()).unwrap_or_default();
    assert!(running.contains(&row) && running.contains("<td>fake</td><td>7</td><td>3.20e-2</td></tr>"), "{waiting}");
    rt.block_on(fake.release_point(v1::ReleasePointRequest {
        pool_id: "fake".into(),
        lease_id: lease.lease_id,
        study_id: lease.study_id,
        point_id: lease.point_id,
    }))?;

    // A pool solves it; the same page then draws three response surfaces (mean and standard
    // deviation) with their 9 points, and the table.
    let mut pool = start_pool(&url, "browser-pool", &pool_log);
    rt.block_on(async { watch(&mut user(&url).await?, id, |_| true).await })?;
    let done = rendered(&page);
    assert!(done.contains("done: 9 of 9 done"), "{done}");
    assert_eq!(done.matches("class=\"point\"").count(), 27, "{done}");
    assert_eq!(done.matches("<svg class=\"surface\"").count(), 3, "{done}");
    assert!(done.contains("<table id=\"points\">"), "{done}");
    // two panels, each caption with the unit and the scale of its colour bar's labels
    assert!(done.contains("mean of slip_A [× 1e-5 m]") && done.contains("standard deviation of slip_A [×"), "{done}");

    // A picture a person can open: target/study-page.png.
    let shot = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/study-page.png");
    let out = run_with_timeout(
        Command::new("chromium").args(["--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars"]).args([
            format!("--screenshot={}", shot.display()),
            "--window-size=1280,900".into(),
            "--virtual-time-budget=2000".into(),
            page,
        ]),
        LIMIT,
    );
    assert!(out.status.success(), "chromium: {}", text(&out.stderr));
    assert_eq!(png_size(&shot), (1280, 900));
    assert!(terminate(&mut pool.0).success());
    Ok(())
}

/// Strings a user controls, each of which would run script if written into the page as HTML
/// (each sets its own mark on the body, which the test looks for).
const HOSTILE_PARAMETER: &str = r#"<img src=x onerror="document.body.dataset.p1=1">"#;
const HOSTILE_QOI: &str = r#"<svg onload="document.body.dataset.p2=1">"#;
const HOSTILE_UNIT: &str = r#"</title><img src=x onerror="document.body.dataset.p3=1">"#;
const HOSTILE_LABEL: &str = r#"</script><script>document.body.dataset.p4=1</script>"#;

#[test]
fn a_study_of_hostile_names_renders_inert_in_a_browser() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let (server_log, pool_log) = (dir.path().join("server.log"), dir.path().join("pool.log"));
    let (_server, addr) = start_server(&dir.path().join("db"), &server_log);
    let url = format!("http://{addr}");
    // the tiny scene, its f1 and slip_A renamed and f1 given a unit (TOML literal strings: the
    // double quotes stay)
    let scene = tiny_scene()
        .replace(
            "f1 = { default = 0.1, min = 0.1, max = 0.2 }",
            &format!("'{HOSTILE_PARAMETER}' = {{ default = 0.1, min = 0.1, max = 0.2, unit = '{HOSTILE_UNIT}' }}"),
        )
        .replace("friction = \"f1\"", &format!("friction = '{HOSTILE_PARAMETER}'"))
        .replace("name = \"slip_A\"", &format!("name = '{HOSTILE_QOI}'"));
    assert!(scene.contains(HOSTILE_UNIT) && scene.contains(HOSTILE_QOI), "the scene changed: {scene}");
    let rt = runtime();
    let id = rt.block_on(async {
        let request = v1::SubmitStudyRequest {
            scene,
            // a list, not a grid: the grid's syntax has no room for `=` in a name
            points: [0.1, 0.2]
                .iter()
                .map(|&v| v1::ParameterVector { values: [(HOSTILE_PARAMETER.to_owned(), v)].into() })
                .collect(),
            tolerance: Some(STUDY_TOL),
            label: HOSTILE_LABEL.into(),
            audit_points: Some(0),
            refine_points: Some(0),
            ..Default::default()
        };
        anyhow::Ok(user(&url).await?.submit_study(request).await?.into_inner().study_id)
    })?;
    let mut pool = start_pool(&url, "hostile-pool", &pool_log);
    rt.block_on(async { watch(&mut user(&url).await?, id, |_| true).await })?;
    assert!(terminate(&mut pool.0).success());

    for path in ["/".to_owned(), format!("/studies/{id}")] {
        let dom = rendered(&format!("{url}{path}"));
        assert!(!dom.contains("data-p"), "a hostile string ran as script on {path}: {dom}");
        // shown as text, as given
        assert!(dom.contains("&lt;/script&gt;&lt;script&gt;document.body.dataset.p4=1"), "{path}: {dom}");
        if path != "/" {
            assert!(dom.contains("done: 2 of 2 done"), "{dom}\n{}", log_of(&pool_log));
            assert!(dom.contains("&lt;img src=x onerror=\"document.body.dataset.p1=1\"&gt;=0.1"), "{dom}");
            assert!(dom.contains("&lt;svg onload=\"document.body.dataset.p2=1\"&gt;"), "{dom}");
            assert!(dom.contains("&lt;/title&gt;&lt;img src=x"), "{dom}");
        }
    }
    // Even a string that escaped the templates could not run: no inline script is allowed.
    let (status, head, _) = http_request(&addr, &format!("GET /studies/{id} HTTP/1.1\r\n"), "");
    assert_eq!(status, 200);
    let csp =
        head.lines().find_map(|l| l.to_ascii_lowercase().strip_prefix("content-security-policy:").map(str::to_owned));
    assert!(csp.as_deref().is_some_and(|p| p.contains("script-src 'self'") && !p.contains("unsafe-inline")), "{head}");
    Ok(())
}

/// Made-up answers of the tiny scene over f1, f2 in [0.1, 0.2]: a smooth displacement, a slip
/// that sticks over part of the box, a wavy one; and eta over 150-210 iterations down to below
/// the tolerance, with the wiggles of a real history.
fn tiny_answer(p: &std::collections::BTreeMap<String, f64>) -> glissade_e2e::synthetic::Answer {
    let (f1, f2) = (p["f1"], p["f2"]);
    let qoi = [
        ("middle_ux", 4e-5 + 1e-5 * (f1 - 0.1) / 0.1 - 0.5e-5 * ((f2 - 0.15) / 0.05).powi(2)),
        ("slip_A", (3e-5 * (f1 - 0.13) / 0.07 + 1e-5 * (f2 - 0.1) / 0.1).max(0.0)),
        ("slip_B", 2e-6 * (1.0 + (20.0 * f1).sin() * f2 * 5.0)),
    ]
    .map(|(n, v)| (n.to_owned(), v))
    .into();
    let n = 150 + (f1 * 1000.0 + f2 * 300.0) as usize % 60;
    let rate = (STUDY_TOL * 0.9 / 0.5f64).ln() / n as f64;
    let history = (0..n).map(|k| 0.5 * (rate * k as f64).exp() * (1.0 + 0.3 * (k as f64).sin())).collect();
    glissade_e2e::synthetic::Answer { qoi, history }
}

/// The check a browser runs on a page's pictures at 100 %: every text at least 12 px, inside
/// its picture, and clear of every other text of it (issue 47: colour-bar titles ran into the
/// next panel's axis label). It writes what it finds on the body.
const LEGIBILITY: &str = r#"<script>
const found = [];
for (const svg of document.querySelectorAll('svg.surface, svg.convergence')) {
  const box = svg.getBoundingClientRect();
  const texts = [...svg.querySelectorAll('text')].filter(t => t.textContent.trim())
    .map(t => ({ s: t.textContent.trim(), r: t.getBoundingClientRect(), px: parseFloat(getComputedStyle(t).fontSize) }));
  for (const t of texts) {
    if (t.px < 12) found.push(`small: ${t.s} (${t.px} px)`);
    if (t.r.left < box.left - 1 || t.r.right > box.right + 1 || t.r.top < box.top - 1 || t.r.bottom > box.bottom + 1)
      found.push(`outside its picture: ${t.s}`);
  }
  for (let i = 0; i < texts.length; i++) for (let j = i + 1; j < texts.length; j++) {
    const [a, b] = [texts[i].r, texts[j].r];
    const w = Math.min(a.right, b.right) - Math.max(a.left, b.left), h = Math.min(a.bottom, b.bottom) - Math.max(a.top, b.top);
    if (w > 1 && h > 1) found.push(`overlap: "${texts[i].s}" and "${texts[j].s}"`);
  }
}
document.body.dataset.legibility = found.length ? found.join(' | ') : 'clear';
</script>"#;

/// Issue 47: a 121-point study's page weighed 1.03 MB (a rectangle per cell of each colour map,
/// a path per contour cell, every iteration of every history) and its labels ran into each
/// other. Solved by synthetic pools (instant, made-up answers: the page is measured, not the
/// solver), the page stays under 300 kB, and a browser finds every label of its pictures
/// legible at 100 %.
#[test]
fn a_121_point_study_page_is_light_and_its_labels_read_clear_in_a_browser() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let (_server, addr) = start_server(&dir.path().join("db"), &dir.path().join("server.log"));
    let url = format!("http://{addr}");
    let rt = runtime();
    let id = rt.block_on(async {
        let mut request = grid_request(&["f1=0.1:0.2:11", "f2=0.1:0.2:11"], STUDY_TOL);
        (request.audit_points, request.refine_points) = (Some(0), Some(0));
        let id = user(&url).await?.submit_study(request).await?.into_inner().study_id;
        let scene = glissade_core::scene::Scene::parse(&tiny_scene())?;
        let answering: glissade_e2e::synthetic::Answering = std::sync::Arc::new(tiny_answer);
        let pools: Vec<_> = (0..2)
            .map(|k| {
                tokio::spawn(glissade_e2e::synthetic::pool(
                    url.clone(),
                    None,
                    format!("s{k}"),
                    scene.clone(),
                    answering.clone(),
                ))
            })
            .collect();
        for p in pools {
            p.await?.map_err(|e| anyhow::anyhow!("{e}"))?;
        }
        anyhow::Ok(id)
    })?;
    let started = std::time::Instant::now();
    let (status, _, page) = http_get(&addr, &format!("/studies/{id}"));
    let took = started.elapsed();
    assert_eq!(status, 200, "{page}");
    assert!(page.contains("done: 121 of 121 done"), "{page}");
    assert_eq!(page.matches("<circle class=\"point\"").count(), 3 * 121);
    assert_eq!(page.matches("<image ").count(), 3 * 4, "each QoI's two maps and two bars, embedded PNGs");
    eprintln!("the 121-point study page: {} bytes, {:.0} ms (debug build)", page.len(), took.as_secs_f64() * 1e3);
    if let Some(keep) = std::env::var_os("GLISSADE_KEEP_PAGE") {
        std::fs::write(keep, &page)?;
    }
    assert!(page.len() < 300_000, "{} bytes", page.len());

    // the page's pictures as the browser draws them, the check in place of the page's script
    let local = dir.path().join("page.html");
    std::fs::write(&local, page.replace("<script src=\"/static/study.js\"></script>", LEGIBILITY))?;
    let dom = rendered(&format!("file://{}", local.display()));
    let verdict = dom.split("data-legibility=\"").nth(1).and_then(|t| t.split('"').next()).unwrap_or("not run");
    assert_eq!(verdict, "clear");
    Ok(())
}
