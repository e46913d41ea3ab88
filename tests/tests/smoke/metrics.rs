//! `/metrics` on a real coordinator with tokens and a real pool: scraped before, during and
//! after a small study, its text parsed as Prometheus would, and its numbers held against what
//! the study did.

use std::collections::BTreeMap;

use crate::common::*;

/// One scrape: each sample line's `name{labels}` and value.
struct Scrape(BTreeMap<String, f64>);

impl Scrape {
    fn parse(text: &str) -> Self {
        let samples = text
            .lines()
            .filter(|l| !l.is_empty() && !l.starts_with('#'))
            .map(|l| {
                let (series, value) = l.rsplit_once(' ').unwrap_or_else(|| panic!("not a sample: {l:?}"));
                (series.to_owned(), value.parse().unwrap_or_else(|_| panic!("not a number: {l:?}")))
            })
            .collect();
        Self(samples)
    }

    /// The value of `series` (0 if absent: a counter not yet incremented has no line).
    fn get(&self, series: &str) -> f64 {
        self.0.get(series).copied().unwrap_or(0.0)
    }

    /// The sum of the series named `name` whose labels contain every one of `labels`.
    fn sum(&self, name: &str, labels: &[&str]) -> f64 {
        self.0
            .iter()
            .filter(|(s, _)| s.split('{').next() == Some(name) && labels.iter().all(|l| s.contains(l)))
            .map(|(_, v)| v)
            .sum()
    }
}

#[test]
fn metrics_follow_a_study_behind_the_user_token() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let tokens = Tokens::write(dir.path())?;
    let (user_token, pool_token) = (&tokens.user, &tokens.pool);
    let (server_log, pool_log) = (dir.path().join("server.log"), dir.path().join("pool.log"));
    let (_server, addr) = start_server_with(&dir.path().join("db"), &server_log, "127.0.0.1:0", &tokens.server_args());
    let url = format!("http://{addr}");
    let logs = || format!("server:\n{}\npool:\n{}", log_of(&server_log), log_of(&pool_log));

    // Prometheus without the token, or with the pool's, gets nothing.
    let (status, _, body) = http_get(&addr, "/metrics");
    assert_eq!(status, 401, "{body}");
    let scrape_with =
        |token: &str| http_request(&addr, &format!("GET /metrics HTTP/1.1\r\nAuthorization: Bearer {token}\r\n"), "");
    assert_eq!(scrape_with(pool_token).0, 401);
    let scrape = || {
        let (status, head, body) = scrape_with(user_token);
        assert_eq!(status, 200, "{head}\n{body}\n{}", logs());
        assert!(head.to_ascii_lowercase().contains("content-type: text/plain; version=0.0.4"), "{head}");
        Scrape::parse(&body)
    };
    let before = scrape();
    assert_eq!(before.sum("glissade_studies", &[]), 0.0);
    assert_eq!(before.get("glissade_pools_connected"), 0.0);
    assert!(before.get("glissade_store_size_bytes") > 0.0, "an open database has files");
    // the two refusals above were counted, by route and status (a scrape is counted once answered)
    assert_eq!(before.get(r#"glissade_http_requests_total{route="/metrics",status="401"}"#), 2.0);

    // During: the study is submitted before any pool exists, so its points wait in the queue.
    let rt = runtime();
    let channel = rt.block_on(tonic::transport::Endpoint::from_shared(url.clone())?.connect())?;
    let bearer: tonic::metadata::MetadataValue<_> = format!("Bearer {user_token}").parse()?;
    let mut client = UserClient::with_interceptor(channel, move |mut r: tonic::Request<()>| {
        r.metadata_mut().insert("authorization", bearer.clone());
        Ok(r)
    });
    let request = v1::SubmitStudyRequest {
        audit_points: Some(0),
        refine_points: Some(0),
        ..grid_request(&["f1=0.1:0.2:2", "f2=0.1:0.2:2"], 1e-2)
    };
    let id = rt.block_on(client.submit_study(request))?.into_inner().study_id;
    let during = scrape();
    assert_eq!(during.get(r#"glissade_studies{state="active"}"#), 1.0);
    assert_eq!(during.get(r#"glissade_points{state="pending"}"#), 4.0);
    assert_eq!(during.get("glissade_queue_pending_points"), 4.0);
    assert_eq!(during.get(r#"glissade_grpc_requests_total{method="/glissade.v1.User/SubmitStudy",code="OK"}"#), 1.0);

    let _pool = start_single_pool_with_token(&url, pool_token, &["--pool-id", "metrics"], &pool_log);
    rt.block_on(async {
        let mut stream = client.watch_study(v1::WatchStudyRequest { study_id: id }).await?.into_inner();
        while let Some(e) = tokio::time::timeout(LIMIT, stream.message()).await?? {
            if kind(&e) == v1::EventKind::StudyEnded {
                break;
            }
        }
        anyhow::Ok(())
    })?;

    // After: every point solved once, each solve in the histograms, the pool's calls counted.
    // (The study ends as the last completion commits; its call is counted as its answer goes out.)
    let completed = r#"glissade_grpc_requests_total{method="/glissade.v1.Pool/CompletePoint",code="OK"}"#;
    let waited = std::time::Instant::now();
    let after = loop {
        let s = scrape();
        if s.get(completed) >= 4.0 || waited.elapsed() > LIMIT {
            break s;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    assert_eq!(after.get(r#"glissade_studies{state="done"}"#), 1.0, "{}", logs());
    assert_eq!(after.get(r#"glissade_points{state="done"}"#), 4.0);
    assert_eq!(after.get("glissade_queue_pending_points"), 0.0);
    assert_eq!(after.get("glissade_leases_held"), 0.0);
    assert_eq!(after.get("glissade_leases_expired_total"), 0.0);
    assert_eq!(after.get("glissade_pools_connected"), 1.0);
    let solves = after.sum("glissade_solve_wall_seconds_count", &[]);
    assert_eq!(solves, 4.0, "one observation per point solved");
    assert_eq!(after.sum("glissade_solve_iterations_count", &[]), 4.0);
    // the first point starts cold (nothing is stored yet), the others from its solution
    assert!(after.get(r#"glissade_solve_wall_seconds_count{start="cold"}"#) >= 1.0);
    assert!(after.sum("glissade_solve_iterations_sum", &[]) >= 4.0);
    assert!(after.sum("glissade_solve_wall_seconds_sum", &[]) > 0.0);
    // the +Inf bucket of each histogram holds every observation
    assert_eq!(after.sum("glissade_solve_wall_seconds_bucket", &[r#"le="+Inf""#]), 4.0);
    assert_eq!(after.get(completed), 4.0);
    assert_eq!(after.get(r#"glissade_grpc_requests_total{method="/glissade.v1.Pool/RegisterPool",code="OK"}"#), 1.0);
    assert!(after.get(r#"glissade_http_requests_total{route="/metrics",status="200"}"#) >= 2.0);
    assert!(after.get("glissade_store_size_bytes") >= before.get("glissade_store_size_bytes"));

    // Unknown paths and methods count as `other`, whatever they are called: the series stay bounded.
    for path in ["/no/such/page", "/another/one"] {
        assert_eq!(http_get(&addr, path).0, 404);
    }
    let last = scrape();
    assert_eq!(last.get(r#"glissade_http_requests_total{route="other",status="404"}"#), 2.0);
    assert!(!last.0.keys().any(|s| s.contains("/no/such/page")));
    assert!(
        last.get(r#"glissade_http_requests_total{route="/metrics",status="200"}"#)
            > after.get(r#"glissade_http_requests_total{route="/metrics",status="200"}"#)
    );
    Ok(())
}
