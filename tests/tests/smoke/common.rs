//! What the end-to-end tests share: the binaries, servers and pools they start, the clients they
//! talk with, the scenes they solve.

pub use std::fs::File;
pub use std::io::{BufRead, BufReader};
pub use std::net::SocketAddr;
pub use std::path::Path;
pub use std::process::{Child, Command, Stdio};
pub use std::sync::mpsc;
pub use std::time::Duration;

pub use glissade_e2e::{ChildToken, child_token, no_children, run_with_timeout, wait_with_timeout, workspace_bin};

/// Generous: the 2-core CI machine may be busy compiling beside us.
pub const LIMIT: Duration = Duration::from_secs(60);

/// A command with the ambient settings that would change the binaries' output removed.
pub fn command(program: &Path) -> Command {
    let mut cmd = Command::new(program);
    cmd.env_remove("RUST_LOG")
        .env_remove("GLISSADE_SERVER")
        .env_remove("GLISSADE_TOKEN")
        .env_remove("GLISSADE_TOKEN_FILE");
    // a pool that has to spool uses this run's directory, not the user's ~/.glissade/spool
    cmd.env("GLISSADE_SPOOL", std::env::temp_dir().join(format!("glissade-e2e-spool-{}", std::process::id())));
    cmd
}

pub fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// Kills the server if a test panics before stopping it, so no process outlives the test.
pub struct ServerGuard(pub Child, pub ChildToken);

impl Drop for ServerGuard {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Starts `glissade-server` on a free port and returns it with the address from its stdout line.
pub fn start_server(data: &Path, log: &Path) -> (ServerGuard, SocketAddr) {
    start_server_with(data, log, "127.0.0.1:0", &[])
}

/// Starts `glissade-server` listening on `listen` with extra arguments.
pub fn start_server_with(data: &Path, log: &Path, listen: &str, args: &[&str]) -> (ServerGuard, SocketAddr) {
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

// ---- glissade-worker solve: warm starts, solution files, field output, bad input ----

/// The path of a scene the repository ships (scenes/FILE): the tests solve what users get.
pub fn shipped_scene(file: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes").join(file)
}

/// The shipped 1D impact scene: a bar at v0 = 1 m/s hits a wall; 400 steps, 4 substructures,
/// 101 nodes of which 3 are duplicated at the substructure interfaces (104 in field output).
pub fn bar_scene() -> std::path::PathBuf {
    shipped_scene("bar-impact-1d.toml")
}
pub const BAR_STEPS: usize = 400;
pub const BAR_FIELD_NODES: usize = 104;

/// Runs `glissade-worker solve ARGS` in `dir`.
pub fn worker_solve(dir: &Path, args: &[&std::ffi::OsStr]) -> std::process::Output {
    run_with_timeout(command(&workspace_bin("glissade-worker")).current_dir(dir).arg("solve").args(args), LIMIT)
}

pub fn os(s: &str) -> &std::ffi::OsStr {
    s.as_ref()
}

/// The `--json` object of a run that must have converged.
pub fn converged_json(out: &std::process::Output) -> serde_json::Value {
    assert_eq!(out.status.code(), Some(0), "stderr: {}", text(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("stdout is not JSON ({e}): {}", text(&out.stdout)));
    assert_eq!(v["converged"], true, "{v}");
    v
}

// ---- the service: coordinator, worker pools and studies over gRPC ----

pub use glissade_proto::v1;
pub use glissade_proto::v1::pool_client::PoolClient;
pub use glissade_proto::v1::user_client::UserClient;
pub use tonic::Code;
pub use tonic::transport::Channel;

/// The shipped tiny three-blocks scene: f1, f2 in [0.1, 0.2]; a cold solve takes well under a
/// second in a debug build.
pub fn tiny_scene() -> String {
    let path = shipped_scene("three-blocks-tiny.toml");
    std::fs::read_to_string(path).expect("read scenes/three-blocks-tiny.toml")
}

/// Tolerance of the service studies where results are only checked for what they are.
pub const STUDY_TOL: f64 = 1e-3;

/// Starts a pool of two MPI ranks, `mpiexec -n 2 glissade-worker pool`, against `url`, logging to
/// `log`. Killing mpiexec (SIGKILL) ends its ranks too; SIGTERM reaches all of them. Its ranks
/// yield their core while they wait (`GLISSADE_MPI_YIELD=1`): they share the machine's cores
/// with the coordinator, another pool and the tests beside them.
pub fn start_pool(url: &str, id: &str, log: &Path) -> ServerGuard {
    let mut cmd = command(Path::new("mpiexec.mpich"));
    cmd.env("GLISSADE_MPI_YIELD", "1").args(["-n", "2"]).arg(workspace_bin("glissade-worker"));
    spawn_pool(cmd, url, id, log)
}

/// Starts a pool of one process (signals reach it directly), as `start_pool` otherwise.
pub fn start_single_pool(url: &str, id: &str, log: &Path) -> ServerGuard {
    spawn_pool(command(&workspace_bin("glissade-worker")), url, id, log)
}

/// Starts a pool of one process that presents `token` (`GLISSADE_TOKEN`), with `args` after
/// `pool --coordinator URL`.
pub fn start_single_pool_with_token(url: &str, token: &str, args: &[&str], log: &Path) -> ServerGuard {
    let mut cmd = command(&workspace_bin("glissade-worker"));
    cmd.env("GLISSADE_TOKEN", token);
    spawn(cmd, url, args, log)
}

fn spawn_pool(cmd: Command, url: &str, id: &str, log: &Path) -> ServerGuard {
    spawn(cmd, url, &["--pool-id", id], log)
}

fn spawn(mut cmd: Command, url: &str, args: &[&str], log: &Path) -> ServerGuard {
    let token = child_token();
    let child = cmd
        .args(["pool", "--coordinator", url])
        .args(args)
        .env("RUST_LOG", "glissade_worker::pool=debug")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(File::create(log).expect("create pool log"))
        .spawn()
        .expect("start glissade-worker pool");
    ServerGuard(child, token)
}

/// A coordinator's two tokens and the files under a test's directory that hold them.
pub struct Tokens {
    pub user: String,
    pub pool: String,
    pub user_file: std::path::PathBuf,
    pub pool_file: std::path::PathBuf,
}

impl Tokens {
    /// Writes them, the user token with a newline (as `openssl rand -hex 32 > file` leaves it).
    pub fn write(dir: &Path) -> std::io::Result<Self> {
        let t = Self {
            user: "u".repeat(40),
            pool: "p".repeat(40),
            user_file: dir.join("user.token"),
            pool_file: dir.join("pool.token"),
        };
        std::fs::write(&t.user_file, format!("{}\n", t.user))?;
        std::fs::write(&t.pool_file, &t.pool)?;
        Ok(t)
    }

    /// The coordinator's arguments that name the files.
    pub fn server_args(&self) -> [&str; 4] {
        fn path(p: &Path) -> &str {
            p.to_str().expect("a UTF-8 temporary path")
        }
        ["--user-token-file", path(&self.user_file), "--pool-token-file", path(&self.pool_file)]
    }
}

/// Sends SIGTERM to a child and waits for it to exit.
pub fn terminate(child: &mut Child) -> std::process::ExitStatus {
    let kill = run_with_timeout(Command::new("kill").args(["-TERM", &child.id().to_string()]), LIMIT);
    assert!(kill.status.success(), "kill: {}", text(&kill.stderr));
    wait_with_timeout(child, LIMIT).expect("did not stop within the limit after SIGTERM")
}

/// grpc.health.v1 Check of `service`: the status number (1 SERVING, 2 NOT_SERVING), or Err when
/// the call fails.
pub async fn standard_health(url: &str, service: &str) -> Result<i32, ()> {
    use tonic_health::pb::{HealthCheckRequest, health_client::HealthClient};
    let channel =
        tonic::transport::Endpoint::from_shared(url.to_owned()).map_err(drop)?.connect().await.map_err(drop)?;
    let mut client = HealthClient::new(channel);
    let reply = client.check(HealthCheckRequest { service: service.into() }).await.map_err(drop)?;
    Ok(reply.into_inner().status)
}

pub fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread().enable_all().build().expect("tokio runtime")
}

pub async fn user(url: &str) -> anyhow::Result<UserClient<Channel>> {
    Ok(UserClient::connect(url.to_owned()).await?)
}

pub fn grid_request(grid: &[&str], tolerance: f64) -> v1::SubmitStudyRequest {
    v1::SubmitStudyRequest {
        scene: tiny_scene(),
        grid: grid.iter().map(|g| g.to_string()).collect(),
        tolerance: Some(tolerance),
        // no held-out points unless a test asks: they add stored solutions after the study ends
        surface_audit_points: Some(0),
        ..Default::default()
    }
}

pub fn kind(e: &v1::StudyEvent) -> v1::EventKind {
    v1::EventKind::try_from(e.kind).unwrap_or(v1::EventKind::Unspecified)
}

pub fn point_id(e: &v1::StudyEvent) -> u64 {
    e.point.as_ref().map_or(u64::MAX, |p| p.point_id)
}

/// Watches study `id` until it ends, passing each event to `on_event` (which may stop the watch
/// early by returning false); returns the events seen.
pub async fn watch(
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

pub async fn study(client: &mut UserClient<Channel>, id: u64) -> anyhow::Result<v1::Study> {
    Ok(client.get_study(v1::GetStudyRequest { study_id: id, points: true, ..Default::default() }).await?.into_inner())
}

/// The `--json` summary of a direct `glissade-worker solve` of the tiny scene at a point.
pub fn direct_solve(parameters: &std::collections::BTreeMap<String, f64>, tol: f64) -> serde_json::Value {
    let dir = tempfile::tempdir().expect("tempdir");
    let scene = shipped_scene("three-blocks-tiny.toml");
    let mut args = vec![scene.into_os_string(), "--json".into(), "--tol".into(), tol.to_string().into()];
    for (k, v) in parameters {
        args.push("--set".into());
        args.push(format!("{k}={v}").into());
    }
    let args: Vec<&std::ffi::OsStr> = args.iter().map(|a| a.as_os_str()).collect();
    converged_json(&worker_solve(dir.path(), &args))
}

pub fn log_of(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_default()
}

/// Fetches a stored solution file through FetchSolution.
pub async fn fetch(
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
pub fn assert_qois_agree(point: &v1::PointStatus, direct: &serde_json::Value, tol: f64) {
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

/// A pool client in the test: registers, leases a point of the tiny scene.
pub async fn fake_pool(url: &str, id: &str) -> anyhow::Result<(PoolClient<Channel>, v1::Lease)> {
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

/// A heartbeat of pool `pool_id` for `lease`, reporting `iterations` so far and `eta`.
pub async fn report_progress(
    pool: &mut PoolClient<Channel>,
    pool_id: &str,
    lease: &v1::Lease,
    iterations: u64,
    eta: f64,
) -> anyhow::Result<()> {
    let progress = v1::SolveProgress { lease_id: lease.lease_id, iterations, error_indicator: eta };
    let request =
        v1::HeartbeatRequest { pool_id: pool_id.into(), lease_ids: vec![lease.lease_id], progress: vec![progress] };
    let reply = pool.heartbeat(request).await?.into_inner();
    anyhow::ensure!(reply.leases.iter().all(|l| l.valid), "lease lost: {reply:?}");
    Ok(())
}

/// CompletePoint: a header with the outcome of the solution file `valid` announcing `announced`
/// bytes, then the chunks of `bytes` (`valid` itself, or a damaged or foreign file).
pub async fn complete(
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

/// A Python virtual environment under target/ with the glissade package (client/python, its
/// stubs generated from the .proto as it installs; numpy and pandas with it) and
/// grpcio-reflection, made once and reinstalled when the package or the .proto change; None
/// when PyPI cannot be reached (the caller skips, saying so). Tests in parallel share one.
pub fn python_with_glissade() -> Option<std::path::PathBuf> {
    static VENV: std::sync::OnceLock<Option<std::path::PathBuf>> = std::sync::OnceLock::new();
    VENV.get_or_init(make_python_venv).clone()
}

fn make_python_venv() -> Option<std::path::PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let package = root.join("client/python");
    let venv = Path::new(env!("CARGO_TARGET_TMPDIR")).join("python-glissade");
    let python = venv.join("bin/python");
    // what the installed package was built from: its sources and the .proto
    let mut sources =
        vec![root.join("proto/proto/glissade.proto"), package.join("pyproject.toml"), package.join("setup.py")];
    for dir in [package.join("glissade"), package.join("glissade/proto")] {
        let mut files: Vec<_> = std::fs::read_dir(&dir)
            .expect("client/python/glissade")
            .map(|e| e.expect("dir entry").path())
            .filter(|p| p.extension().is_some_and(|e| e == "py") && !p.to_string_lossy().contains("_pb2"))
            .collect();
        files.sort();
        sources.extend(files);
    }
    let mut hasher = std::hash::DefaultHasher::new();
    for path in &sources {
        std::hash::Hash::hash(&std::fs::read(path).expect("package source"), &mut hasher);
    }
    let fingerprint = format!("{:016x}", std::hash::Hasher::finish(&hasher));
    let marker = venv.join("glissade-source");
    let check = "import glissade, pandas, numpy, grpc_reflection";
    let ready = |python: &Path| {
        python.is_file()
            && std::fs::read_to_string(&marker).is_ok_and(|m| m == fingerprint)
            && run_with_timeout(Command::new(python).args(["-c", check]), LIMIT).status.success()
    };
    if ready(&python) {
        return Some(python);
    }
    if !python.is_file() {
        let out = run_with_timeout(Command::new("python3").args(["-m", "venv"]).arg(&venv), LIMIT);
        assert!(out.status.success(), "python3 -m venv failed (run deploy/install-deps.sh): {}", text(&out.stderr));
    }
    let out = run_with_timeout(
        Command::new(venv.join("bin/pip"))
            .args(["install", "--quiet", "--disable-pip-version-check", "grpcio-reflection"])
            .arg(&package),
        Duration::from_secs(600),
    );
    if !out.status.success() {
        let reach = "import urllib.request; urllib.request.urlopen('https://pypi.org/simple/grpcio/', timeout=15)";
        if !run_with_timeout(Command::new("python3").args(["-c", reach]), LIMIT).status.success() {
            return None;
        }
        panic!("pip install ./client/python grpcio-reflection failed although PyPI answers:\n{}", text(&out.stderr));
    }
    std::fs::write(&marker, &fingerprint).expect("write the venv's marker");
    assert!(ready(&python), "the glissade package installed but not importable");
    Some(python)
}

// ---------------------------------------------------------------------------------------------
// The CLI (`glissade`) against a real coordinator and pool
// ---------------------------------------------------------------------------------------------

/// Width and height of a PNG file from its IHDR chunk (after checking the signature).
pub fn png_size(path: &Path) -> (u32, u32) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert!(bytes.len() > 24 && bytes.starts_with(b"\x89PNG\r\n\x1a\n") && &bytes[12..16] == b"IHDR", "not a PNG");
    let be = |i: usize| u32::from_be_bytes(bytes[i..i + 4].try_into().expect("4 bytes"));
    (be(16), be(20))
}

/// Runs `glissade` with `args` against `url` (None: no --server), without a terminal.
pub fn glissade(url: Option<&str>, args: &[&str]) -> std::process::Output {
    let mut cmd = command(&workspace_bin("glissade"));
    if let Some(url) = url {
        cmd.args(["--server", url]);
    }
    run_with_timeout(cmd.args(args), LIMIT)
}

/// The one rendering of a study (issue 50): `/api/studies/ID` serves the proto's JSON
/// (glissade_proto::json) of exactly the study GetStudy returns with its points, `glissade show
/// ID --points --json` prints the same, and it reads back as that message. Read while the study
/// stays as it is (GetStudy the same before and after: its audits may still be running). Returns
/// the study.
pub fn assert_one_rendering(addr: &SocketAddr, url: &str, id: u64) -> anyhow::Result<v1::Study> {
    let get_study = || {
        let request = v1::GetStudyRequest { study_id: id, points: true, scene: false, without_eta_histories: true };
        runtime().block_on(async { anyhow::Ok(user(url).await?.get_study(request).await?.into_inner()) })
    };
    let started = std::time::Instant::now();
    loop {
        let got = get_study()?;
        let (status, kind, api) = http_get(addr, &format!("/api/studies/{id}"));
        assert_eq!((status, kind.as_str()), (200, "application/json"), "{api}");
        let out = glissade(Some(url), &["show", &id.to_string(), "--points", "--json"]);
        assert!(out.status.success(), "show: {}", text(&out.stderr));
        if get_study()? != got {
            assert!(started.elapsed() < LIMIT, "study {id} never stayed as it was for a read");
            std::thread::sleep(Duration::from_millis(200));
            continue;
        }
        let expected = serde_json::to_value(&got)?;
        let api: serde_json::Value = serde_json::from_str(&api)?;
        assert_eq!(api, expected, "the API's JSON is GetStudy's study");
        let shown: serde_json::Value = serde_json::from_slice(&out.stdout)?;
        assert_eq!(shown, expected, "`show --json` prints GetStudy's study");
        assert_eq!(serde_json::from_value::<v1::Study>(api)?, got, "the JSON reads back as the message");
        return Ok(got);
    }
}

/// A refused command: non-zero exit, exactly one line on stderr that starts with `error:` and
/// names `needle`, nothing on stdout.
pub fn assert_one_line_error(out: &std::process::Output, needle: &str) {
    let err = text(&out.stderr);
    assert!(!out.status.success(), "expected a failure, got success; stdout: {}", text(&out.stdout));
    assert!(
        err.starts_with("error: ") && err.ends_with('\n') && err.lines().count() == 1,
        "one line expected: {err:?}"
    );
    assert!(err.contains(needle), "expected `{needle}` in {err:?}");
    assert!(out.stdout.is_empty(), "stdout: {}", text(&out.stdout));
}

/// A tmpfs of `mib` MiB mounted at `dir`, unmounted on drop; None where this process may not
/// mount (not root, or a container without CAP_SYS_ADMIN).
pub struct SmallDisk(pub std::path::PathBuf);

impl SmallDisk {
    pub fn mount(dir: &Path, mib: u32) -> Option<Self> {
        std::fs::create_dir_all(dir).ok()?;
        // (through run_with_timeout: its token keeps the spawn away from tests that lock files)
        let size = format!("size={mib}m");
        let out = run_with_timeout(Command::new("mount").args(["-t", "tmpfs", "-o", &size, "tmpfs"]).arg(dir), LIMIT);
        out.status.success().then(|| Self(dir.to_path_buf()))
    }

    /// Fills the disk with a file `filler`.
    pub fn fill(&self) {
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

pub fn tiny_path() -> String {
    shipped_scene("three-blocks-tiny.toml").display().to_string()
}

/// An HTTP/1.1 request on `addr`, `head` its request line and headers (each line ending in
/// CRLF) and `body` sent after them: (status, the response's head, body).
pub fn http_request(addr: &SocketAddr, head: &str, body: &str) -> (u16, String, String) {
    use std::io::{Read, Write};
    let mut stream = std::net::TcpStream::connect(addr).expect("connect");
    stream.set_read_timeout(Some(LIMIT)).expect("timeout");
    write!(stream, "{head}Host: {addr}\r\nConnection: close\r\nContent-Length: {}\r\n\r\n{body}", body.len())
        .expect("request");
    let mut raw = Vec::new();
    stream.read_to_end(&mut raw).expect("response");
    let raw = String::from_utf8_lossy(&raw).into_owned();
    let (head, body) = raw.split_once("\r\n\r\n").unwrap_or((&raw, ""));
    let status = head.split_whitespace().nth(1).and_then(|s| s.parse().ok()).unwrap_or(0);
    (status, head.to_owned(), body.to_owned())
}

/// An HTTP/1.1 GET of `path` on `addr`: (status, content type, body).
pub fn http_get(addr: &SocketAddr, path: &str) -> (u16, String, String) {
    use std::io::{Read, Write};
    let mut stream = std::net::TcpStream::connect(addr).expect("connect");
    stream.set_read_timeout(Some(LIMIT)).expect("timeout");
    write!(stream, "GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n").expect("request");
    let mut raw = Vec::new();
    stream.read_to_end(&mut raw).expect("response");
    let raw = String::from_utf8_lossy(&raw).into_owned();
    let (head, body) = raw.split_once("\r\n\r\n").unwrap_or((&raw, ""));
    let status = head.split_whitespace().nth(1).and_then(|s| s.parse().ok()).unwrap_or(0);
    let content_type = head
        .lines()
        .find_map(|l| l.to_ascii_lowercase().strip_prefix("content-type:").map(|v| v.trim().to_owned()))
        .unwrap_or_default();
    // chunked bodies: good enough to search in (the chunk sizes stay in as lines)
    (status, content_type, body.to_owned())
}
