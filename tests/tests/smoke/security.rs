//! Tokens and TLS: who may do what, and strangers get nothing.

use crate::common::*;

#[test]
fn tokens_separate_users_from_pools_and_strangers_get_nothing() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let tokens = Tokens::write(dir.path())?;
    let (user_token, pool_token, user_file) = (&tokens.user, &tokens.pool, &tokens.user_file);

    // Without tokens a coordinator refuses to listen beyond loopback.
    let out = run_with_timeout(
        command(&workspace_bin("glissade-server")).args(["--listen", "0.0.0.0:0", "--data"]).arg(dir.path().join("x")),
        LIMIT,
    );
    assert_eq!(out.status.code(), Some(1));
    assert!(text(&out.stderr).contains("without tokens"), "{}", text(&out.stderr));

    let (_server, addr) =
        start_server_with(&dir.path().join("db"), &dir.path().join("server.log"), "127.0.0.1:0", &tokens.server_args());
    let url = format!("http://{addr}");
    let rt = runtime();
    let with = |token: &str| {
        let value: tonic::metadata::MetadataValue<_> = format!("Bearer {token}").parse().expect("ascii");
        move |mut r: tonic::Request<()>| {
            r.metadata_mut().insert("authorization", value.clone());
            Ok(r)
        }
    };
    let channel = rt.block_on(tonic::transport::Endpoint::from_shared(url.clone())?.connect())?;

    // A stranger, and a pool posing as a user: refused before anything is read.
    let mut stranger = UserClient::new(channel.clone());
    let s = rt.block_on(stranger.submit_study(grid_request(&["f1=0.1"], STUDY_TOL))).expect_err("no token");
    assert_eq!(s.code(), Code::Unauthenticated, "{s:?}");
    let mut posing = UserClient::with_interceptor(channel.clone(), with(pool_token));
    let s = rt.block_on(posing.list_studies(v1::ListStudiesRequest::default())).expect_err("pool token");
    assert_eq!(s.code(), Code::PermissionDenied, "{s:?}");
    // ...and a user posing as a pool cannot lease or complete.
    let mut fake = PoolClient::with_interceptor(channel.clone(), with(user_token));
    let s = rt
        .block_on(fake.register_pool(v1::RegisterPoolRequest { pool_id: "fake".into(), ..Default::default() }))
        .expect_err("user token");
    assert_eq!(s.code(), Code::PermissionDenied, "{s:?}");
    let mut wrong = PoolClient::with_interceptor(channel.clone(), with(&"w".repeat(40)));
    let s = rt.block_on(wrong.lease_point(v1::LeasePointRequest::default())).map(drop).expect_err("wrong");
    assert_eq!(s.code(), Code::Unauthenticated, "{s:?}");
    // The web page obeys the tokens: nothing without the user token, the page with it.
    assert_eq!(http_get(&addr, "/api/studies").0, 401);
    let bearer = |t: &str| format!("GET /api/studies HTTP/1.1\r\nAuthorization: Bearer {t}\r\n");
    assert_eq!(http_request(&addr, &bearer(pool_token), "").0, 401);
    assert_eq!(http_request(&addr, &bearer(user_token), "").0, 200);
    // A token never goes in a URL (histories and logs keep them), not even the right one.
    let (status, _, body) = http_get(&addr, &format!("/?token={user_token}"));
    assert_eq!(status, 400, "{body}");
    assert!(body.contains("log in at /login"), "{body}");
    // A browser without the cookie gets the login form; the form sets an HttpOnly cookie.
    let (status, _, body) = http_get(&addr, "/");
    assert!(status == 401 && body.contains("<form method=\"post\" action=\"/login\">"), "{status} {body}");
    let form = "POST /login HTTP/1.1\r\nContent-Type: application/x-www-form-urlencoded\r\n";
    let (status, _, body) = http_request(&addr, form, &format!("token={}", "w".repeat(40)));
    assert!(status == 401 && body.contains("wrong user token"), "{status} {body}");
    let (status, head, _) = http_request(&addr, form, &format!("token={user_token}"));
    assert_eq!(status, 303, "{head}");
    let cookie = head
        .lines()
        .find_map(|l| l.strip_prefix("set-cookie: ").or_else(|| l.strip_prefix("Set-Cookie: ")))
        .unwrap_or_default();
    assert!(cookie.contains("HttpOnly") && cookie.contains("SameSite=Strict"), "{head}");
    assert!(!cookie.contains(user_token.as_str()), "the cookie does not show the token as is: {cookie}");
    let with_cookie = format!("GET / HTTP/1.1\r\nCookie: {}\r\n", cookie.split(';').next().unwrap_or_default());
    let (status, _, body) = http_request(&addr, &with_cookie, "");
    assert!(status == 200 && body.contains("glissade studies"), "{status} {body}");
    // Health stays open for monitoring, ours and the standard one.
    let out = glissade(Some(&url), &["health"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert_eq!(rt.block_on(standard_health(&url, "")), Ok(1));

    // The CLI with the user token submits; a pool with the user token is refused and says so.
    let scene = dir.path().join("tiny.toml");
    std::fs::write(&scene, tiny_scene())?;
    let token_arg = user_file.to_str().unwrap();
    let out = glissade(
        Some(&url),
        &["--token-file", token_arg, "submit", scene.to_str().unwrap(), "--grid", "f1=0.1,0.2", "--tol", "1e-3"],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let out = glissade(Some(&url), &["studies"]);
    assert_eq!(out.status.code(), Some(1));
    assert!(text(&out.stderr).contains("needs a user token"), "{}", text(&out.stderr));
    let out = run_with_timeout(
        command(&workspace_bin("glissade-worker")).args(["pool", "--coordinator", &url, "--token-file", token_arg]),
        LIMIT,
    );
    assert_eq!(out.status.code(), Some(1));
    assert!(text(&out.stderr).contains("refused this pool"), "{}", text(&out.stderr));

    // A pool with its token (from the environment) solves the study.
    let pool_log = dir.path().join("pool.log");
    let _pool = start_single_pool_with_token(&url, pool_token, &["--idle-exit", "3"], &pool_log);
    let mut user = UserClient::with_interceptor(channel, with(user_token));
    rt.block_on(async {
        let mut stream = user.watch_study(v1::WatchStudyRequest { study_id: 1 }).await?.into_inner();
        while let Some(e) = tokio::time::timeout(LIMIT, stream.message()).await?? {
            if kind(&e) == v1::EventKind::StudyEnded {
                break;
            }
        }
        anyhow::Ok(())
    })?;
    let s = rt
        .block_on(user.get_study(v1::GetStudyRequest { study_id: 1, points: true, ..Default::default() }))?
        .into_inner();
    assert_eq!(s.state, v1::StudyState::Done as i32, "{s:?}\n{}", log_of(&pool_log));
    Ok(())
}

#[test]
fn tls_serves_https_clients_that_trust_its_authority_and_no_one_else() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let d = dir.path().display();
    // A test CA and a certificate for localhost / 127.0.0.1 signed by it.
    let script = format!(
        "set -e; cd {d}
         openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -keyout ca.key -out ca.pem -days 1 -subj '/CN=glissade test CA' 2>/dev/null
         openssl req -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -keyout server.key -out server.csr -subj '/CN=localhost' 2>/dev/null
         printf 'subjectAltName=DNS:localhost,IP:127.0.0.1\\n' > san.ext
         openssl x509 -req -in server.csr -CA ca.pem -CAkey ca.key -CAcreateserial -out server.pem -days 1 -extfile san.ext 2>/dev/null"
    );
    let out = run_with_timeout(Command::new("bash").args(["-c", &script]), LIMIT);
    assert!(out.status.success(), "openssl: {}", text(&out.stderr));
    let path = |f: &str| dir.path().join(f).display().to_string();
    let tls = ["--tls-cert", &path("server.pem"), "--tls-key", &path("server.key")];
    let (_server, addr) =
        start_server_with(&dir.path().join("db"), &dir.path().join("server.log"), "127.0.0.1:0", &tls);
    let https = format!("https://localhost:{}", addr.port());

    // The CLI and a pool that trust the CA: a study goes through.
    let out = glissade(Some(&https), &["--ca-cert", &path("ca.pem"), "health"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let scene = dir.path().join("tiny.toml");
    std::fs::write(&scene, tiny_scene())?;
    let out = glissade(
        Some(&https),
        &["--ca-cert", &path("ca.pem"), "submit", scene.to_str().unwrap(), "--grid", "f1=0.1", "--tol", "1e-3"],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let out = run_with_timeout(
        command(&workspace_bin("glissade-worker"))
            .args(["pool", "--coordinator", &https, "--idle-exit", "2"])
            .env("GLISSADE_CA_CERT", path("ca.pem")),
        LIMIT,
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let out = glissade(Some(&https), &["--ca-cert", &path("ca.pem"), "show", "1", "--json"]);
    assert!(text(&out.stdout).contains("\"STUDY_STATE_DONE\""), "{}{}", text(&out.stdout), text(&out.stderr));

    // Without the CA (the system's roots do not know it), and in clear text: nothing.
    let out = glissade(Some(&https), &["health"]);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out.stdout));
    let out = glissade(Some(&format!("http://127.0.0.1:{}", addr.port())), &["health"]);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out.stdout));
    Ok(())
}

/// A pool token can store a forged answer, which later studies are then served (issue 48): each
/// stored solution keeps the pool that sent it, and `glissade purge-pool` removes that pool's
/// solutions. Here a "forger" solves a study with a made-up QoI; a second study of the same
/// points is answered from those solutions; once purged, a third is solved again, by an honest
/// pool, and keeps the honest values. An id no pool could have is refused and purges nothing.
#[test]
fn a_pools_solutions_can_be_purged_and_no_later_point_is_answered_from_them() -> anyhow::Result<()> {
    use glissade_e2e::synthetic;
    let dir = tempfile::tempdir()?;
    let (_server, addr) = start_server_with(&dir.path().join("db"), &dir.path().join("server.log"), "127.0.0.1:0", &[]);
    let url = format!("http://{addr}");
    let scene = glissade_core::scene::Scene::parse(&tiny_scene())?;
    let answer = |value: f64| -> synthetic::Answering {
        std::sync::Arc::new(move |_| synthetic::Answer {
            qoi: ["middle_ux", "slip_A", "slip_B"].map(|q| (q.to_owned(), value)).into(),
            history: Vec::new(),
        })
    };
    let rt = runtime();
    // a study of two points, solved by `pool`; its points' middle_ux, and whether each was answered
    let study = |pool: &'static str, value: f64| -> anyhow::Result<Vec<(f64, bool)>> {
        rt.block_on(async {
            let mut request = grid_request(&["f1=0.1,0.2"], STUDY_TOL);
            (request.audit_points, request.refine_points) = (Some(0), Some(0));
            let id = user(&url).await?.submit_study(request).await?.into_inner().study_id;
            synthetic::pool(url.clone(), None, pool.into(), scene.clone(), answer(value))
                .await
                .map_err(|e| anyhow::anyhow!("{e}"))?;
            let request = v1::GetStudyRequest { study_id: id, points: true, ..Default::default() };
            let points = user(&url).await?.get_study(request).await?.into_inner().points;
            Ok(points.iter().map(|p| (p.qoi["middle_ux"], p.answered)).collect())
        })
    };
    assert_eq!(study("forger", 42.0)?, [(42.0, false); 2]);
    // the forged answers are served to a later study of the same points
    assert_eq!(study("honest", 1.0)?, [(42.0, true); 2]);
    let out = glissade(Some(&url), &["purge-pool", "forger"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert_eq!(text(&out.stdout), "purged 2 stored solutions of pool forger\n");
    assert_eq!(study("honest", 1.0)?, [(1.0, false); 2], "a purged solution answered a point");
    let out = glissade(Some(&url), &["purge-pool", "forger"]);
    assert_eq!(text(&out.stdout), "purged 0 stored solutions of pool forger\n");
    // an id no pool can register is refused with what it takes, and harms nothing: the honest
    // pool's solutions still answer
    for bad in [String::new(), "p".repeat(257)] {
        let out = glissade(Some(&url), &["purge-pool", &bad]);
        assert!(!out.status.success(), "purge-pool {:?}: {}", bad.len(), text(&out.stdout));
        assert!(text(&out.stderr).contains("1 to 256 bytes"), "{}", text(&out.stderr));
    }
    assert_eq!(study("honest", 1.0)?, [(1.0, true); 2], "the honest solutions are kept");
    Ok(())
}
