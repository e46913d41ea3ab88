//! One study engine: the same study locally and on the service.

use crate::common::*;

/// One study engine: the same studies run by `glissade-worker study` on one process and by the
/// coordinator with a pool of two ranks take the same starts, the same iterations and the same
/// QoIs, bit for bit (the coordinator's order and warm starts are the library's).
#[test]
fn a_study_runs_the_same_locally_and_on_the_service() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let (server_log, pool_log) = (dir.path().join("server.log"), dir.path().join("pool.log"));
    let (mut server, addr) = start_server_with(&dir.path().join("db"), &server_log, "127.0.0.1:0", &[]);
    let url = format!("http://{addr}");
    let mut pool = start_pool(&url, "pool-a", &pool_log);
    let logs = || format!("server:\n{}\npool:\n{}", log_of(&server_log), log_of(&pool_log));
    let grid = ["f1=0.1:0.2:3", "f2=0.1:0.2:3"];
    let rt = runtime();
    // The service's store spans studies of a scene, a local study's store is its own: warm first
    // (a cold study never reads the store), and the blend on a scene of its own (another material).
    let other = dir.path().join("other.toml");
    std::fs::write(&other, tiny_scene().replace("E = 150e9", "E = 140e9"))?;
    let tiny = std::path::PathBuf::from(tiny_path());
    for (strategy, scene) in
        [(v1::InitStrategy::Nearest, &tiny), (v1::InitStrategy::Cold, &tiny), (v1::InitStrategy::Blend, &other)]
    {
        let tol = STUDY_TOL;
        let service = rt.block_on(async {
            let mut client = user(&url).await?;
            let mut request = grid_request(&grid, tol);
            request.scene = std::fs::read_to_string(scene)?;
            request.strategy = strategy as i32;
            request.blend_neighbours = 3;
            let id = client.submit_study(request).await?.into_inner().study_id;
            watch(&mut client, id, |_| true).await?;
            study(&mut client, id).await
        })?;
        let name = match strategy {
            v1::InitStrategy::Cold => "cold",
            v1::InitStrategy::Blend => "blend",
            _ => "nearest",
        };
        let mut args =
            vec![scene.display().to_string(), "--tol".into(), tol.to_string(), "--strategy".into(), name.into()];
        args.extend(["--k".into(), "3".into()]);
        args.extend(["--json".into(), "--grid".into(), grid[0].into(), "--grid".into(), grid[1].into()]);
        let out = run_with_timeout(command(&workspace_bin("glissade-worker")).arg("study").args(&args), LIMIT);
        assert!(out.status.success(), "study: {}", text(&out.stderr));
        let local: serde_json::Value = serde_json::from_slice(&out.stdout)?;
        let records = local["records"].as_array().expect("records");
        assert_eq!((records.len(), service.points.len()), (9, 9));
        let mut warm = 0;
        for r in records {
            let p = &service.points[r["index"].as_u64().expect("index") as usize];
            assert_eq!(p.state, v1::PointState::Done as i32, "{p:?}\n{}", logs());
            assert_eq!(Some(p.iterations), r["iterations"].as_u64(), "{name}: {p:?}\n{r}");
            for (q, v) in &p.qoi {
                assert_eq!(Some(v.to_bits()), r["qoi"][q].as_f64().map(f64::to_bits), "{name} {q}: {p:?}\n{r}");
            }
            // the same start: cold, or from the stored solution of the same point
            // (the service names a blend's nearest source)
            let from = |k: &str| p.started_from.as_ref().map(|f| f.parameters[k]);
            let source = |k: &str| r["sources"].get(0).map(|s| s["point"][k].as_f64().expect("a number"));
            assert_eq!((from("f1"), from("f2")), (source("f1"), source("f2")), "{name}: {p:?}\n{r}");
            warm += usize::from(p.started_from.is_some());
        }
        assert_eq!(warm, if strategy == v1::InitStrategy::Cold { 0 } else { 8 }, "{name}");
    }
    drop(rt);
    assert!(terminate(&mut pool.0).success(), "{}", logs());
    assert!(terminate(&mut server.0).success(), "{}", logs());
    Ok(())
}
