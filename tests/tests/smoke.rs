//! End-to-end smoke tests: real processes, real files, no mocks.
//!
//! The single integration-test file of this crate (each file links the whole stack, so more
//! files would multiply link time). Binaries of other packages come from `cargo build --workspace`.

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use glissade_e2e::{ChildToken, child_token, no_children, run_with_timeout, wait_with_timeout, workspace_bin};

/// Generous: the 2-core CI machine may be busy compiling beside us.
const LIMIT: Duration = Duration::from_secs(60);

/// A command with the ambient settings that would change the binaries' output removed.
fn command(program: &Path) -> Command {
    let mut cmd = Command::new(program);
    cmd.env_remove("RUST_LOG")
        .env_remove("GLISSADE_SERVER")
        .env_remove("GLISSADE_TOKEN")
        .env_remove("GLISSADE_TOKEN_FILE");
    // a pool that has to spool uses this run's directory, not the user's ~/.glissade/spool
    cmd.env("GLISSADE_SPOOL", std::env::temp_dir().join(format!("glissade-e2e-spool-{}", std::process::id())));
    cmd
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

#[test]
fn mpiexec_runs_two_ranks_and_all_reduces() {
    let bin = env!("CARGO_BIN_EXE_mpi-allreduce");
    let out = run_with_timeout(Command::new("mpiexec.mpich").args(["-n", "2", bin]), LIMIT);
    assert!(out.status.success(), "mpiexec failed ({}):\n{}", out.status, text(&out.stderr));
    assert_eq!(text(&out.stdout).trim(), "size=2 sum=3");
}

#[test]
fn hdf5_round_trip_of_a_2d_dataset_and_attribute() -> anyhow::Result<()> {
    let _locks_files = no_children();
    let dir = tempfile::tempdir()?;
    let path = dir.path().join("fields.h5");
    // Thirds are not exactly representable in decimal, so a lossy path (text, f32) would show.
    let (rows, cols) = (3, 4);
    let data: Vec<f64> = (0..rows * cols).map(|i| f64::from(i as u32) / 3.0).collect();
    let time = 0.1_f64 + 0.2;
    {
        let file = hdf5::File::create(&path)?;
        let ds = file.new_dataset::<f64>().shape((rows, cols)).create("displacement")?;
        ds.write_raw(&data[..])?;
        ds.new_attr::<f64>().create("time")?.write_scalar(&time)?;
    }
    let file = hdf5::File::open(&path)?;
    let ds = file.dataset("displacement")?;
    assert_eq!(ds.shape(), vec![rows, cols]);
    let back: Vec<f64> = ds.read_raw()?;
    assert_eq!(
        back.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
        data.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
    );
    assert_eq!(ds.attr("time")?.read_scalar::<f64>()?.to_bits(), time.to_bits());
    Ok(())
}

#[test]
fn sled_survives_flush_drop_and_reopen() -> anyhow::Result<()> {
    let _locks_files = no_children();
    let dir = tempfile::tempdir()?;
    {
        let db = sled::open(dir.path())?;
        for i in 0_u32..100 {
            db.insert(i.to_be_bytes(), format!("value {i}").as_bytes())?;
        }
        db.flush()?;
    }
    let db = sled::open(dir.path())?;
    assert_eq!(db.len(), 100);
    for i in 0_u32..100 {
        let v = db.get(i.to_be_bytes())?.expect("key written before reopen");
        assert_eq!(&*v, format!("value {i}").as_bytes());
    }
    Ok(())
}

/// Kills the server if a test panics before stopping it, so no process outlives the test.
struct ServerGuard(Child, ChildToken);

impl Drop for ServerGuard {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Starts `glissade-server` on a free port and returns it with the address from its stdout line.
fn start_server(data: &Path, log: &Path) -> (ServerGuard, SocketAddr) {
    start_server_with(data, log, "127.0.0.1:0", &[])
}

/// Starts `glissade-server` listening on `listen` with extra arguments.
fn start_server_with(data: &Path, log: &Path, listen: &str, args: &[&str]) -> (ServerGuard, SocketAddr) {
    let token = child_token();
    let child = command(&workspace_bin("glissade-server"))
        .args(["--listen", listen, "--data"])
        .arg(data)
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(File::create(log).expect("create server log"))
        .spawn()
        .expect("start glissade-server");
    let mut guard = ServerGuard(child, token);
    let stdout = guard.0.stdout.take().expect("piped stdout");
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let mut line = String::new();
        let _ = BufReader::new(stdout).read_line(&mut line);
        let _ = tx.send(line);
    });
    let line = rx.recv_timeout(LIMIT).unwrap_or_else(|_| {
        panic!(
            "glissade-server printed no line within {LIMIT:?}; log:\n{}",
            std::fs::read_to_string(log).unwrap_or_default()
        )
    });
    let addr = line.trim_end().strip_prefix("listening on ").and_then(|a| a.parse().ok()).unwrap_or_else(|| {
        panic!(
            "expected `listening on 127.0.0.1:PORT`, got {line:?}; log:\n{}",
            std::fs::read_to_string(log).unwrap_or_default()
        )
    });
    (guard, addr)
}

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

// ---- glissade-worker solve: warm starts, solution files, field output, bad input ----

/// The shipped 1D impact scene: a bar at v0 = 1 m/s hits a wall; 400 steps, 4 substructures,
/// 101 nodes of which 3 are duplicated at the substructure interfaces (104 in field output).
fn bar_scene() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/bar-impact-1d.toml")
}
const BAR_STEPS: usize = 400;
const BAR_FIELD_NODES: usize = 104;

/// Runs `glissade-worker solve ARGS` in `dir`.
fn worker_solve(dir: &Path, args: &[&std::ffi::OsStr]) -> std::process::Output {
    run_with_timeout(command(&workspace_bin("glissade-worker")).current_dir(dir).arg("solve").args(args), LIMIT)
}

fn os(s: &str) -> &std::ffi::OsStr {
    s.as_ref()
}

/// The `--json` object of a run that must have converged.
fn converged_json(out: &std::process::Output) -> serde_json::Value {
    assert_eq!(out.status.code(), Some(0), "stderr: {}", text(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("stdout is not JSON ({e}): {}", text(&out.stdout)));
    assert_eq!(v["converged"], true, "{v}");
    v
}

#[test]
fn worker_warm_start_from_a_saved_solution_converges_within_two_windows() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let scene = bar_scene();
    let cold = converged_json(&worker_solve(dir.path(), &[scene.as_os_str(), os("--json"), os("--save"), os("s.bin")]));
    assert_eq!(cold["initialised_from"], serde_json::Value::Null, "{cold}");
    assert_eq!(cold["saved_to"], "s.bin", "{cold}");
    assert!(cold["iterations"].as_u64().unwrap() > 10, "a cold start should need iterations: {cold}");
    let bytes = std::fs::read(dir.path().join("s.bin"))?;
    assert_eq!(&bytes[..8], b"GLISSOL\0");

    let warm = converged_json(&worker_solve(dir.path(), &[scene.as_os_str(), os("--json"), os("--init"), os("s.bin")]));
    assert_eq!(warm["initialised_from"], "s.bin", "{warm}");
    assert_eq!(warm["scene_hash"], cold["scene_hash"]);
    let iterations = warm["iterations"].as_u64().unwrap();
    // the stopping test measures the contraction over two windows before it trusts a small change
    let windows = 2 * glissade_worker::latin::stopping::WINDOW as u64 + 2;
    assert!(iterations <= windows, "warm start from the converged solution took {iterations} iterations");

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

// ---- the service: coordinator, worker pools and studies over gRPC ----

use glissade_proto::v1;
use glissade_proto::v1::pool_client::PoolClient;
use glissade_proto::v1::user_client::UserClient;
use tonic::Code;
use tonic::transport::Channel;

/// The shipped tiny three-blocks scene: f1, f2 in [0.1, 0.2]; a cold solve takes well under a
/// second in a debug build.
fn tiny_scene() -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/three-blocks-tiny.toml");
    std::fs::read_to_string(path).expect("read scenes/three-blocks-tiny.toml")
}

/// Tolerance of the service studies where results are only checked for what they are.
const STUDY_TOL: f64 = 1e-3;

/// Starts a pool of two MPI ranks, `mpiexec -n 2 glissade-worker pool`, against `url`, logging to
/// `log`. Killing mpiexec (SIGKILL) ends its ranks too; SIGTERM reaches all of them.
fn start_pool(url: &str, id: &str, log: &Path) -> ServerGuard {
    let token = child_token();
    let child = command(Path::new("mpiexec.mpich"))
        .args(["-n", "2"])
        .arg(workspace_bin("glissade-worker"))
        .args(["pool", "--coordinator", url, "--pool-id", id])
        .env("RUST_LOG", "glissade_worker::pool=debug")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(File::create(log).expect("create pool log"))
        .spawn()
        .expect("start glissade-worker pool");
    ServerGuard(child, token)
}

/// Sends SIGTERM to a child and waits for it to exit.
fn terminate(child: &mut Child) -> std::process::ExitStatus {
    let kill = run_with_timeout(Command::new("kill").args(["-TERM", &child.id().to_string()]), LIMIT);
    assert!(kill.status.success(), "kill: {}", text(&kill.stderr));
    wait_with_timeout(child, LIMIT).expect("did not stop within the limit after SIGTERM")
}

/// grpc.health.v1 Check of `service`: the status number (1 SERVING, 2 NOT_SERVING), or Err when
/// the call fails.
async fn standard_health(url: &str, service: &str) -> Result<i32, ()> {
    use tonic_health::pb::{HealthCheckRequest, health_client::HealthClient};
    let channel =
        tonic::transport::Endpoint::from_shared(url.to_owned()).map_err(drop)?.connect().await.map_err(drop)?;
    let mut client = HealthClient::new(channel);
    let reply = client.check(HealthCheckRequest { service: service.into() }).await.map_err(drop)?;
    Ok(reply.into_inner().status)
}

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread().enable_all().build().expect("tokio runtime")
}

async fn user(url: &str) -> anyhow::Result<UserClient<Channel>> {
    Ok(UserClient::connect(url.to_owned()).await?)
}

fn grid_request(grid: &[&str], tolerance: f64) -> v1::SubmitStudyRequest {
    v1::SubmitStudyRequest {
        scene: tiny_scene(),
        grid: grid.iter().map(|g| g.to_string()).collect(),
        tolerance: Some(tolerance),
        ..Default::default()
    }
}

fn kind(e: &v1::StudyEvent) -> v1::EventKind {
    v1::EventKind::try_from(e.kind).unwrap_or(v1::EventKind::Unspecified)
}

fn point_id(e: &v1::StudyEvent) -> u64 {
    e.point.as_ref().map_or(u64::MAX, |p| p.point_id)
}

/// Watches study `id` until it ends, passing each event to `on_event` (which may stop the watch
/// early by returning false); returns the events seen.
async fn watch(
    client: &mut UserClient<Channel>,
    id: u64,
    mut on_event: impl FnMut(&v1::StudyEvent) -> bool,
) -> anyhow::Result<Vec<v1::StudyEvent>> {
    let mut stream = client.watch_study(v1::WatchStudyRequest { study_id: id }).await?.into_inner();
    let mut events = Vec::new();
    loop {
        let next = tokio::time::timeout(LIMIT, stream.message()).await;
        let event = next.map_err(|_| anyhow::anyhow!("no event within {LIMIT:?}; so far: {events:?}"))??;
        let Some(event) = event else { anyhow::bail!("the watch stream ended before the study did: {events:?}") };
        let go_on = on_event(&event);
        let ended = kind(&event) == v1::EventKind::StudyEnded;
        events.push(event);
        if ended || !go_on {
            return Ok(events);
        }
    }
}

async fn study(client: &mut UserClient<Channel>, id: u64) -> anyhow::Result<v1::Study> {
    Ok(client.get_study(v1::GetStudyRequest { study_id: id, points: true, scene: false }).await?.into_inner())
}

/// The `--json` summary of a direct `glissade-worker solve` of the tiny scene at a point.
fn direct_solve(parameters: &std::collections::BTreeMap<String, f64>, tol: f64) -> serde_json::Value {
    let dir = tempfile::tempdir().expect("tempdir");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/three-blocks-tiny.toml");
    let mut args = vec![scene.into_os_string(), "--json".into(), "--tol".into(), tol.to_string().into()];
    for (k, v) in parameters {
        args.push("--set".into());
        args.push(format!("{k}={v}").into());
    }
    let args: Vec<&std::ffi::OsStr> = args.iter().map(|a| a.as_os_str()).collect();
    converged_json(&worker_solve(dir.path(), &args))
}

fn log_of(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_default()
}

/// Fetches a stored solution file through FetchSolution.
async fn fetch(
    client: &mut UserClient<Channel>,
    which: v1::fetch_solution_request::Solution,
) -> anyhow::Result<Vec<u8>> {
    let mut stream = client.fetch_solution(v1::FetchSolutionRequest { solution: Some(which) }).await?.into_inner();
    let mut bytes = Vec::new();
    while let Some(chunk) = stream.message().await? {
        assert_eq!(chunk.offset as usize, bytes.len(), "chunks in order");
        assert!(chunk.data.len() <= glissade_proto::CHUNK_BYTES);
        bytes.extend_from_slice(&chunk.data);
    }
    Ok(bytes)
}

/// QoIs of a service point and of a direct solve: within `tol` x the QoI's magnitude.
fn assert_qois_agree(point: &v1::PointStatus, direct: &serde_json::Value, tol: f64) {
    assert!(!point.qoi.is_empty(), "{point:?}");
    for (name, value) in &point.qoi {
        let expected = direct["qoi"][name]["final"].as_f64().expect("QoI in the direct solve");
        let scale = direct["qoi"][name]["values"]
            .as_array()
            .map_or(0.0, |v| v.iter().map(|x| x.as_f64().unwrap_or(0.0).abs()).fold(0.0, f64::max));
        assert!(
            (value - expected).abs() <= tol * scale,
            "point {:?} {name}: service {value}, direct {expected}",
            point.parameters
        );
    }
}

#[test]
fn service_two_pools_solve_each_point_once_like_direct_solves() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let (server_log, pool_logs) = (dir.path().join("server.log"), [dir.path().join("a.log"), dir.path().join("b.log")]);
    let (mut server, addr) = start_server_with(&dir.path().join("db"), &server_log, "127.0.0.1:0", &[]);
    let url = format!("http://{addr}");
    let mut pools = [start_pool(&url, "pool-a", &pool_logs[0]), start_pool(&url, "pool-b", &pool_logs[1])];
    let glissade = workspace_bin("glissade");
    let scene_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/three-blocks-tiny.toml");
    let logs = || {
        let [a, b] = &pool_logs;
        format!("server:\n{}\npool-a:\n{}\npool-b:\n{}", log_of(&server_log), log_of(a), log_of(b))
    };

    // A cold study (so that each point is exactly a direct solve), submitted with the CLI.
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
        assert!(p.error_indicator <= STUDY_TOL && p.iterations > 0 && p.started_from.is_none(), "{p:?}");
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
        (&"done".into(), &9.into(), &"cold".into())
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
        let reply =
            client.submit_study(grid_request(&["f1=0.125:0.175:2", "f2=0.125:0.175:2"], STUDY_TOL)).await?.into_inner();
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
        assert_eq!((meta.parameters["f1"], meta.parameters["f2"]), (0.15, 0.15));
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
fn service_survives_a_killed_pool_and_a_killed_coordinator() -> anyhow::Result<()> {
    const TOL: f64 = 1e-4; // long enough solves (about a second cold) to be killed in the middle
    let dir = tempfile::tempdir()?;
    let data = dir.path().join("db");
    let logs = ["server1.log", "server2.log", "a.log", "b.log"].map(|n| dir.path().join(n));
    let all_logs = || logs.iter().map(|l| format!("{}:\n{}", l.display(), log_of(l))).collect::<Vec<_>>().join("\n");
    let lease = ["--lease-seconds", "1.5", "--max-attempts", "5"];
    let (mut server, addr) = start_server_with(&data, &logs[0], "127.0.0.1:0", &lease);
    let url = format!("http://{addr}");
    let mut pool_a = start_pool(&url, "pool-a", &logs[2]);
    let rt = runtime();

    let mut client = rt.block_on(user(&url))?;
    let id =
        rt.block_on(client.submit_study(grid_request(&["f1=0.1:0.2:3", "f2=0.1:0.2:3"], TOL)))?.into_inner().study_id;
    // The CLI watches the whole study, through the coordinator's restart below.
    let cli_out = dir.path().join("watch.out");
    let cli_err = dir.path().join("watch.err");
    let mut cli_watch = command(&workspace_bin("glissade"))
        .args(["--server", &url, "watch", &id.to_string()])
        .stdin(Stdio::null())
        .stdout(File::create(&cli_out)?)
        .stderr(File::create(&cli_err)?)
        .spawn()?;
    // Kill pool A with SIGKILL as soon as it starts its first point.
    let started = rt.block_on(watch(&mut client, id, |e| kind(e) != v1::EventKind::PointStarted))?;
    pool_a.0.kill()?;
    let _ = pool_a.0.wait();
    let killed = point_id(started.last().expect("an event"));
    assert_eq!(started.last().and_then(|e| e.point.as_ref()).map(|p| p.pool_id.as_str()), Some("pool-a"));

    // Pool B takes over; the lost point comes back when its lease expires.
    let _pool_b = start_pool(&url, "pool-b", &logs[3]);
    let mut finished_before = std::collections::BTreeSet::new();
    let mut requeued = false;
    rt.block_on(watch(&mut client, id, |e| {
        match kind(e) {
            v1::EventKind::PointRequeued if point_id(e) == killed && !e.replay => requeued = true,
            v1::EventKind::PointFinished if !e.replay => {
                assert!(finished_before.insert(point_id(e)), "point {} finished twice", point_id(e));
            }
            _ => {}
        }
        !(requeued && finished_before.len() >= 3)
    }))?;
    assert!(requeued, "the killed pool's point was never requeued:\n{}", all_logs());

    // Kill the coordinator mid-study and restart it on the same data and address.
    let done_before: Vec<u64> = rt
        .block_on(study(&mut client, id))?
        .points
        .iter()
        .filter(|p| p.state == v1::PointState::Done as i32)
        .map(|p| p.point_id)
        .collect();
    assert!(done_before.len() < 9, "the study ended before the coordinator could be killed");
    server.0.kill()?;
    let _ = server.0.wait();
    drop(server);
    let (_server, _) = start_server_with(&data, &logs[1], &addr.to_string(), &lease);
    let mut client = rt.block_on(user(&url))?;
    let mut finished_after = std::collections::BTreeSet::new();
    let mut replayed_done = std::collections::BTreeSet::new();
    rt.block_on(watch(&mut client, id, |e| {
        if kind(e) == v1::EventKind::PointFinished {
            let set = if e.replay { &mut replayed_done } else { &mut finished_after };
            assert!(set.insert(point_id(e)), "point {} finished twice", point_id(e));
        }
        true
    }))?;
    let after = rt.block_on(study(&mut client, id))?;

    // Nothing lost: what was done before the kill is still done; nothing done twice.
    for p in &done_before {
        assert!(replayed_done.contains(p), "point {p} was done before the kill, not after:\n{}", all_logs());
    }
    assert!(finished_after.is_disjoint(&replayed_done), "{finished_after:?} {replayed_done:?}");
    assert!(finished_after.is_disjoint(&finished_before), "{finished_after:?} {finished_before:?}");
    let all: std::collections::BTreeSet<u64> = replayed_done.union(&finished_after).copied().collect();
    assert_eq!(all, (0..9).collect(), "\n{}", all_logs());
    assert_eq!(after.state, v1::StudyState::Done as i32, "{after:?}");
    let lost = &after.points[killed as usize];
    assert!(lost.attempts >= 2, "the killed pool's point was leased {} times: {lost:?}", lost.attempts);
    assert!(after.points.iter().all(|p| p.state == v1::PointState::Done as i32 && p.error_indicator <= TOL));
    // one stored solution per point: no duplicate
    let surface = rt.block_on(client.query_surface(v1::QuerySurfaceRequest {
        source: Some(v1::query_surface_request::Source::SceneHash(after.scene_hash.clone())),
        ..Default::default()
    }))?;
    assert_eq!(surface.into_inner().points.len(), 9);
    // pool B reconnected by itself
    assert!(log_of(&logs[3]).contains("reconnecting") || log_of(&logs[3]).contains("cannot reach"), "{}", all_logs());
    // and so did `glissade watch`, which saw the study to its end
    let status = wait_with_timeout(&mut cli_watch, LIMIT).expect("glissade watch did not end with the study");
    let (out, err) = (log_of(&cli_out), log_of(&cli_err));
    assert!(status.success(), "glissade watch: {status:?}\n{out}\n{err}");
    assert!(err.contains("reconnecting") && err.contains("reconnected"), "{err}");
    assert!(out.contains("9/9 done"), "{out}");
    Ok(())
}

/// A pool client in the test: registers, leases a point of the tiny scene.
async fn fake_pool(url: &str, id: &str) -> anyhow::Result<(PoolClient<Channel>, v1::Lease)> {
    let mut pool = PoolClient::connect(url.to_owned()).await?;
    pool.register_pool(v1::RegisterPoolRequest {
        pool_id: id.into(),
        ranks: 1,
        host: "test".into(),
        solver_version: env!("CARGO_PKG_VERSION").into(),
    })
    .await?;
    let mut stream = pool.lease_point(v1::LeasePointRequest { pool_id: id.into(), wait_ms: 5000 }).await?.into_inner();
    let Some(v1::LeaseMessage { body: Some(v1::lease_message::Body::Lease(lease)) }) = stream.message().await? else {
        anyhow::bail!("no lease");
    };
    while stream.message().await?.is_some() {}
    Ok((pool, lease))
}

/// CompletePoint: a header with the outcome of the solution file `valid` announcing `announced`
/// bytes, then the chunks of `bytes` (`valid` itself, or a damaged or foreign file).
async fn complete(
    pool: &mut PoolClient<Channel>,
    lease: &v1::Lease,
    pool_id: &str,
    valid: &[u8],
    bytes: &[u8],
    announced: usize,
) -> Result<v1::CompletePointReply, tonic::Status> {
    let (meta, _) = glissade_core::io::solution_file::read_from(valid).expect("a valid solution file");
    let header = v1::CompletePointHeader {
        pool_id: pool_id.into(),
        lease_id: lease.lease_id,
        study_id: lease.study_id,
        point_id: lease.point_id,
        converged: meta.converged,
        iterations: meta.iterations as u64,
        error_indicator: meta.error_indicator,
        qoi: meta.qoi.clone(),
        wall_seconds: 0.1,
        solution_bytes: announced as u64,
        eta_history: Vec::new(),
        work: 1.0,
        ..Default::default()
    };
    let mut messages = vec![v1::CompletePointMessage { body: Some(v1::complete_point_message::Body::Header(header)) }];
    messages.extend(
        glissade_proto::chunks(bytes)
            .map(|mut c| {
                c.total_bytes = announced as u64;
                c
            })
            .map(|c| v1::CompletePointMessage { body: Some(v1::complete_point_message::Body::Chunk(c)) }),
    );
    Ok(pool.complete_point(tokio_stream::iter(messages)).await?.into_inner())
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
        rt.block_on(client.get_study(v1::GetStudyRequest { study_id: 42, points: false, scene: false }))
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
    let bar = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/bar-impact-1d.toml");
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

/// A Python virtual environment with grpcio, grpcio-tools and grpcio-reflection under target/,
/// made once; None when PyPI cannot be reached (the caller skips, saying so).
fn python_with_grpc() -> Option<std::path::PathBuf> {
    let venv = Path::new(env!("CARGO_TARGET_TMPDIR")).join("python-grpc");
    let python = venv.join("bin/python");
    let ready = |python: &Path| {
        python.is_file()
            && run_with_timeout(Command::new(python).args(["-c", "import grpc, grpc_tools, grpc_reflection"]), LIMIT)
                .status
                .success()
    };
    if ready(&python) {
        return Some(python);
    }
    let out = run_with_timeout(Command::new("python3").args(["-m", "venv"]).arg(&venv), LIMIT);
    assert!(out.status.success(), "python3 -m venv failed (run deploy/install-deps.sh): {}", text(&out.stderr));
    let pip = venv.join("bin/pip");
    let out = run_with_timeout(
        Command::new(&pip).args([
            "install",
            "--quiet",
            "--disable-pip-version-check",
            "grpcio",
            "grpcio-tools",
            "grpcio-reflection",
        ]),
        Duration::from_secs(600),
    );
    if !out.status.success() {
        let reach = "import urllib.request; urllib.request.urlopen('https://pypi.org/simple/grpcio/', timeout=15)";
        if !run_with_timeout(Command::new("python3").args(["-c", reach]), LIMIT).status.success() {
            return None;
        }
        panic!(
            "pip install grpcio grpcio-tools grpcio-reflection failed although PyPI answers:\n{}",
            text(&out.stderr)
        );
    }
    assert!(ready(&python), "grpcio installed but not importable");
    Some(python)
}

#[test]
fn python_example_client_submits_a_grid_and_reads_the_surface() -> anyhow::Result<()> {
    let Some(python) = python_with_grpc() else {
        eprintln!(
            "SKIPPED python_example_client_submits_a_grid_and_reads_the_surface: PyPI is unreachable, so grpcio cannot be installed"
        );
        return Ok(());
    };
    let dir = tempfile::tempdir()?;
    let (_server, addr) = start_server(&dir.path().join("db"), &dir.path().join("server.log"));
    let _pool = start_pool(&format!("http://{addr}"), "py-pool", &dir.path().join("pool.log"));
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("../client/examples/submit_and_surface.py");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/three-blocks-tiny.toml");
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

// ---------------------------------------------------------------------------------------------
// The CLI (`glissade`) against a real coordinator and pool
// ---------------------------------------------------------------------------------------------

/// Width and height of a PNG file from its IHDR chunk (after checking the signature).
fn png_size(path: &Path) -> (u32, u32) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert!(bytes.len() > 24 && bytes.starts_with(b"\x89PNG\r\n\x1a\n") && &bytes[12..16] == b"IHDR", "not a PNG");
    let be = |i: usize| u32::from_be_bytes(bytes[i..i + 4].try_into().expect("4 bytes"));
    (be(16), be(20))
}

/// Runs `glissade` with `args` against `url` (None: no --server), without a terminal.
fn glissade(url: Option<&str>, args: &[&str]) -> std::process::Output {
    let mut cmd = command(&workspace_bin("glissade"));
    if let Some(url) = url {
        cmd.args(["--server", url]);
    }
    run_with_timeout(cmd.args(args), LIMIT)
}

/// A refused command: non-zero exit, exactly one line on stderr that starts with `error:` and
/// names `needle`, nothing on stdout.
fn assert_one_line_error(out: &std::process::Output, needle: &str) {
    let err = text(&out.stderr);
    assert!(!out.status.success(), "expected a failure, got success; stdout: {}", text(&out.stdout));
    assert!(
        err.starts_with("error: ") && err.ends_with('\n') && err.lines().count() == 1,
        "one line expected: {err:?}"
    );
    assert!(err.contains(needle), "expected `{needle}` in {err:?}");
    assert!(out.stdout.is_empty(), "stdout: {}", text(&out.stdout));
}

#[test]
fn cli_demo_runs_a_study_and_draws_its_pictures() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let out_dir = dir.path().join("demo");
    let out = glissade(None, &["demo", "--grid", "3", "--out", out_dir.to_str().expect("utf-8")]);
    assert!(out.status.success(), "demo failed:\n{}\n{}", text(&out.stdout), text(&out.stderr));
    let stdout = text(&out.stdout);
    // plain progress lines without a terminal, the summary, the surface table
    assert_eq!(stdout.matches("done (f1=").count(), 9, "{stdout}");
    assert!(stdout.contains("study 1 done: 9/9 done"), "{stdout}");
    assert!(stdout.contains("x less work than cold ones"), "{stdout}");
    assert!(stdout.lines().any(|l| l.split_whitespace().take(2).eq(["f1", "f2"])), "{stdout}");
    assert_eq!(png_size(&out_dir.join("slip_A.png")), (900, 700));
    assert_eq!(png_size(&out_dir.join("convergence.png")), (900, 600));
    let csv = std::fs::read_to_string(out_dir.join("surface.csv"))?;
    assert_eq!(csv.lines().next(), Some("f1,f2,middle_ux,slip_A,slip_B,iterations,eta,state"));
    assert_eq!(csv.lines().filter(|l| l.ends_with(",done")).count(), 9, "{csv}");
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
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/three-blocks-tiny.toml");
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

    // pictures of the stated size: a colour map, a curve (one free parameter), the convergence
    for (args, size) in [
        (vec!["surface", "1", "--qoi", "slip_A", "--png", &path("map.png"), "--size", "640x480"], (640, 480)),
        (vec!["surface", "1", "--qoi", "slip_B", "--fix", "f1=0.1", "--png", &path("curve.png")], (900, 700)),
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
        assert_eq!(last, point.error_indicator, "the history ends at the point's eta");
    }

    // studies / show / cancel
    let out = glissade(Some(&url), &["studies", "--json"]);
    let list: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    assert_eq!(list[0]["state"], "done", "{list}");
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
    let id = serde_json::from_slice::<serde_json::Value>(&out.stdout)?["study_id"].to_string();
    let out = glissade(Some(&url), &["watch", &id]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let out = glissade(Some(&url), &["show", &id, "--points", "--json"]);
    let shown: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    assert_eq!((&shown["state"], &shown["progress"]["done"]), (&"done".into(), &6.into()), "{shown}");
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
        assert!(p.error_indicator > 0.0 && p.error_indicator.is_finite(), "{p:?}");
        last = p.iterations;
    }
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

#[test]
fn tokens_separate_users_from_pools_and_strangers_get_nothing() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let (user_token, pool_token) = ("u".repeat(40), "p".repeat(40));
    let (user_file, pool_file) = (dir.path().join("user.token"), dir.path().join("pool.token"));
    std::fs::write(&user_file, format!("{user_token}\n"))?;
    std::fs::write(&pool_file, &pool_token)?;

    // Without tokens a coordinator refuses to listen beyond loopback.
    let out = run_with_timeout(
        command(&workspace_bin("glissade-server")).args(["--listen", "0.0.0.0:0", "--data"]).arg(dir.path().join("x")),
        LIMIT,
    );
    assert_eq!(out.status.code(), Some(1));
    assert!(text(&out.stderr).contains("without tokens"), "{}", text(&out.stderr));

    let files = ["--user-token-file", user_file.to_str().unwrap(), "--pool-token-file", pool_file.to_str().unwrap()];
    let (_server, addr) =
        start_server_with(&dir.path().join("db"), &dir.path().join("server.log"), "127.0.0.1:0", &files);
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
    let mut posing = UserClient::with_interceptor(channel.clone(), with(&pool_token));
    let s = rt.block_on(posing.list_studies(v1::ListStudiesRequest {})).expect_err("pool token");
    assert_eq!(s.code(), Code::PermissionDenied, "{s:?}");
    // ...and a user posing as a pool cannot lease or complete.
    let mut fake = PoolClient::with_interceptor(channel.clone(), with(&user_token));
    let s = rt
        .block_on(fake.register_pool(v1::RegisterPoolRequest { pool_id: "fake".into(), ..Default::default() }))
        .expect_err("user token");
    assert_eq!(s.code(), Code::PermissionDenied, "{s:?}");
    let mut wrong = PoolClient::with_interceptor(channel.clone(), with(&"w".repeat(40)));
    let s = rt.block_on(wrong.lease_point(v1::LeasePointRequest::default())).map(drop).expect_err("wrong");
    assert_eq!(s.code(), Code::Unauthenticated, "{s:?}");
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
    let token = child_token();
    let pool = command(&workspace_bin("glissade-worker"))
        .args(["pool", "--coordinator", &url, "--idle-exit", "3"])
        .env("GLISSADE_TOKEN", &pool_token)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(File::create(&pool_log)?)
        .spawn()?;
    let _pool = ServerGuard(pool, token);
    let mut user = UserClient::with_interceptor(channel, with(&user_token));
    rt.block_on(async {
        let mut stream = user.watch_study(v1::WatchStudyRequest { study_id: 1 }).await?.into_inner();
        while let Some(e) = tokio::time::timeout(LIMIT, stream.message()).await?? {
            if kind(&e) == v1::EventKind::StudyEnded {
                break;
            }
        }
        anyhow::Ok(())
    })?;
    let s = rt.block_on(user.get_study(v1::GetStudyRequest { study_id: 1, points: true, scene: false }))?.into_inner();
    assert_eq!(s.state, v1::StudyState::Done as i32, "{s:?}\n{}", log_of(&pool_log));
    Ok(())
}

/// A tmpfs of `mib` MiB mounted at `dir`, unmounted on drop; None where this process may not
/// mount (not root, or a container without CAP_SYS_ADMIN).
struct SmallDisk(std::path::PathBuf);

impl SmallDisk {
    fn mount(dir: &Path, mib: u32) -> Option<Self> {
        std::fs::create_dir_all(dir).ok()?;
        // (through run_with_timeout: its token keeps the spawn away from tests that lock files)
        let size = format!("size={mib}m");
        let out = run_with_timeout(Command::new("mount").args(["-t", "tmpfs", "-o", &size, "tmpfs"]).arg(dir), LIMIT);
        out.status.success().then(|| Self(dir.to_path_buf()))
    }

    /// Fills the disk with a file `filler`.
    fn fill(&self) {
        let mut f = File::create(self.0.join("filler")).expect("filler");
        let block = vec![0u8; 1 << 16];
        while std::io::Write::write_all(&mut f, &block).is_ok() {}
    }
}

impl Drop for SmallDisk {
    fn drop(&mut self) {
        let _ = run_with_timeout(Command::new("umount").arg("-l").arg(&self.0), LIMIT);
    }
}

#[test]
fn a_full_disk_is_named_and_the_coordinator_recovers_after_a_restart() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let Some(disk) = SmallDisk::mount(&dir.path().join("fs"), 16) else {
        eprintln!("skipped: cannot mount a tmpfs here (needs root, as on the CI machine)");
        return Ok(());
    };
    let data = disk.0.join("db");
    let log = dir.path().join("server.log");
    let (mut server, addr) = start_server_with(&data, &log, "127.0.0.1:0", &["--lease-seconds", "60"]);
    let url = format!("http://{addr}");
    let rt = runtime();
    let mut client = rt.block_on(user(&url))?;
    let id = rt.block_on(client.submit_study(grid_request(&["f1=0.1:0.2:4"], STUDY_TOL)))?.into_inner().study_id;

    // A pool holds a point and its solution when the disk fills up.
    let (mut pool, lease) = rt.block_on(fake_pool(&url, "tester"))?;
    let file = dir.path().join("p.bin");
    let mut args = vec!["solve".to_string(), tiny_path(), "--tol".into(), STUDY_TOL.to_string(), "--save".into()];
    args.push(file.display().to_string());
    for (k, v) in &lease.parameters {
        args.extend(["--set".to_string(), format!("{k}={v}")]);
    }
    let out = run_with_timeout(command(&workspace_bin("glissade-worker")).args(&args), LIMIT);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let solution = std::fs::read(&file)?;
    disk.fill();
    let status =
        rt.block_on(complete(&mut pool, &lease, "tester", &solution, &solution, solution.len())).expect_err("full");
    assert_eq!(status.code(), Code::ResourceExhausted, "{status:?}");
    assert!(status.message().contains("disk is full"), "{}", status.message());
    let health = glissade(Some(&url), &["health", "--json"]);
    assert_eq!(health.status.code(), Some(1));
    assert!(text(&health.stdout).contains("NOT_SERVING"), "{}", text(&health.stdout));
    // the standard health service follows within its 200 ms watch (the grace is 3 s)
    let not_serving = (0..20).any(|_| {
        std::thread::sleep(Duration::from_millis(50));
        rt.block_on(standard_health(&url, "")) == Ok(2)
    });
    assert!(not_serving, "grpc.health.v1 did not say NOT_SERVING");
    // It stops by itself, saying why, for its service manager to restart it.
    let status = wait_with_timeout(&mut server.0, LIMIT)
        .unwrap_or_else(|| panic!("the coordinator did not stop:\n{}", log_of(&log)));
    assert_eq!(status.code(), Some(1));
    assert!(log_of(&log).contains("restarts the coordinator once space is freed"), "{}", log_of(&log));

    // Space freed, restarted on the same data: the held point completes, a real pool does the rest.
    std::fs::remove_file(disk.0.join("filler"))?;
    let (_server, _) = start_server_with(&data, &dir.path().join("server2.log"), &addr.to_string(), &[]);
    // (the old connection broke with the coordinator: retry as a pool does)
    let mut reply = Err(tonic::Status::unavailable("not tried"));
    for _ in 0..50 {
        reply = rt.block_on(complete(&mut pool, &lease, "tester", &solution, &solution, solution.len()));
        match &reply {
            Err(s) if matches!(s.code(), Code::Unknown | Code::Unavailable) => {
                std::thread::sleep(Duration::from_millis(100))
            }
            _ => break,
        }
    }
    assert_eq!(reply?.point.expect("point").state, v1::PointState::Done as i32);
    let out = run_with_timeout(
        command(&workspace_bin("glissade-worker")).args(["pool", "--coordinator", &url, "--idle-exit", "2"]),
        LIMIT,
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let mut client = rt.block_on(user(&url))?;
    let s = rt.block_on(study(&mut client, id))?;
    assert_eq!(s.state, v1::StudyState::Done as i32, "{s:?}");
    assert!(s.points.iter().all(|p| p.attempts == 1), "each point leased once: {s:?}");
    Ok(())
}

fn tiny_path() -> String {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/three-blocks-tiny.toml").display().to_string()
}

#[test]
fn a_pool_stopped_while_the_coordinator_is_down_spools_its_result_and_delivers_it_later() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let data = dir.path().join("db");
    let spool = dir.path().join("spool");
    let log = dir.path().join("server.log");
    let (mut server, addr) = start_server_with(&data, &log, "127.0.0.1:0", &["--lease-seconds", "6"]);
    let url = format!("http://{addr}");
    let rt = runtime();
    let mut client = rt.block_on(user(&url))?;
    // long enough (seconds: 4 x the steps, a tight tolerance) for the coordinator to die during
    // it, after the pool's first heartbeat (every 1.5 s with 6 s leases)
    let mut request = grid_request(&["f1=0.15"], 1e-7);
    request.scene = request.scene.replace("steps = 50", "steps = 200");
    let id = rt.block_on(client.submit_study(request))?.into_inner().study_id;
    let pool_log = dir.path().join("pool.log");
    let pool_args = ["pool", "--coordinator", &url, "--stop-grace", "2", "--spool", spool.to_str().unwrap()];
    let token = child_token();
    let pool = command(&workspace_bin("glissade-worker"))
        .args(pool_args)
        .env("RUST_LOG", "glissade_worker::pool=info")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(File::create(&pool_log)?)
        .spawn()?;
    let mut pool = ServerGuard(pool, token);
    // killed once the pool reports progress: it holds the lease and is solving
    rt.block_on(watch(&mut client, id, |e| kind(e) != v1::EventKind::PointProgress))?;
    server.0.kill()?;
    let _ = server.0.wait();
    drop(server);
    // SIGTERM while the coordinator is gone: the pool finishes its point, tries for the grace,
    // spools the result and exits (it used to retry for ever and ignore further signals).
    let started = std::time::Instant::now();
    let status = terminate(&mut pool.0);
    assert!(status.success(), "{status:?}\n{}", log_of(&pool_log));
    assert!(started.elapsed() < Duration::from_secs(30), "took {:?}", started.elapsed());
    let spooled: Vec<_> = std::fs::read_dir(&spool).map(|d| d.flatten().collect()).unwrap_or_default();
    assert_eq!(spooled.len(), 1, "{spooled:?}\n{}", log_of(&pool_log));

    // Coordinator back on the same data; the next pool delivers the spooled result first.
    let (_server, _) = start_server_with(&data, &dir.path().join("server2.log"), &addr.to_string(), &[]);
    let out = run_with_timeout(
        command(&workspace_bin("glissade-worker"))
            .args(["pool", "--coordinator", &url, "--idle-exit", "2", "--spool", spool.to_str().unwrap()])
            .env("RUST_LOG", "glissade_worker::pool=info"),
        LIMIT,
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(text(&out.stderr).contains("delivered a spooled result"), "{}", text(&out.stderr));
    assert_eq!(std::fs::read_dir(&spool)?.count(), 0);
    let mut client = rt.block_on(user(&url))?;
    let s = rt.block_on(study(&mut client, id))?;
    assert_eq!(s.state, v1::StudyState::Done as i32, "{s:?}");
    assert_eq!(s.points[0].attempts, 1, "solved once, delivered late: {s:?}");
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
    assert!(text(&out.stdout).contains("\"done\""), "{}{}", text(&out.stdout), text(&out.stderr));

    // Without the CA (the system's roots do not know it), and in clear text: nothing.
    let out = glissade(Some(&https), &["health"]);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out.stdout));
    let out = glissade(Some(&format!("http://127.0.0.1:{}", addr.port())), &["health"]);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out.stdout));
    Ok(())
}

/// Random SIGKILLs of the coordinator and of a two-rank pool during a cold study (a fixed seed,
/// so a failure can be replayed): every point ends done, solved as a direct solve would (bit for
/// bit: P-identical, cold), one stored solution each.
#[test]
fn chaos_random_kills_of_coordinator_and_pool_lose_nothing_and_change_nothing() -> anyhow::Result<()> {
    const TOL: f64 = 1e-4;
    let dir = tempfile::tempdir()?;
    let data = dir.path().join("db");
    let lease = ["--lease-seconds", "1", "--max-attempts", "20"];
    let server_log = |i: usize| dir.path().join(format!("server{i}.log"));
    let pool_log = |i: usize| dir.path().join(format!("pool{i}.log"));
    let (mut server, addr) = start_server_with(&data, &server_log(0), "127.0.0.1:0", &lease);
    let url = format!("http://{addr}");
    let mut pool = start_pool(&url, "chaos", &pool_log(0));
    let rt = runtime();
    let mut request = grid_request(&["f1=0.1:0.2:3", "f2=0.1:0.2:3"], TOL);
    request.strategy = v1::InitStrategy::Cold as i32;
    let id = rt
        .block_on(async { user(&url).await?.submit_study(request).await.map_err(anyhow::Error::from) })?
        .into_inner()
        .study_id;
    let mut seed: u64 = 0x05ee_d0fc_4a05;
    let mut next = || {
        seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        seed >> 33
    };
    let (mut servers, mut pools) = (1, 1);
    for _ in 0..6 {
        std::thread::sleep(Duration::from_millis(300 + next() % 1200));
        if next() % 2 == 0 {
            server.0.kill()?;
            let _ = server.0.wait();
            drop(server);
            server = start_server_with(&data, &server_log(servers), &addr.to_string(), &lease).0;
            servers += 1;
        } else {
            pool.0.kill()?;
            let _ = pool.0.wait();
            drop(pool);
            pool = start_pool(&url, "chaos", &pool_log(pools));
            pools += 1;
        }
    }
    let s = rt.block_on(async {
        let mut client = user(&url).await?;
        watch(&mut client, id, |_| true).await?;
        study(&mut client, id).await
    })?;
    let logs = || {
        (0..servers)
            .map(|i| log_of(&server_log(i)))
            .chain((0..pools).map(|i| log_of(&pool_log(i))))
            .collect::<Vec<_>>()
            .join("\n---\n")
    };
    assert_eq!(s.state, v1::StudyState::Done as i32, "{s:?}\n{}", logs());
    for p in &s.points {
        let direct = direct_solve(&p.parameters.clone().into_iter().collect(), TOL);
        for (name, value) in &p.qoi {
            let expected = direct["qoi"][name]["final"].as_f64().expect("QoI");
            assert_eq!(value.to_bits(), expected.to_bits(), "{name} at {:?}: {value} vs {expected}", p.parameters);
        }
    }
    let surface = rt.block_on(async {
        let request = v1::QuerySurfaceRequest {
            source: Some(v1::query_surface_request::Source::SceneHash(s.scene_hash.clone())),
            ..Default::default()
        };
        user(&url).await?.query_surface(request).await.map_err(anyhow::Error::from)
    })?;
    assert_eq!(surface.into_inner().points.len(), 9, "one stored solution per point");
    eprintln!("chaos: {} coordinator and {} pool restarts", servers - 1, pools - 1);
    Ok(())
}

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
