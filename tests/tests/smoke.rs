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
    cmd.env_remove("RUST_LOG").env_remove("GLISSADE_SERVER");
    cmd
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

#[test]
fn mpiexec_runs_two_ranks_and_all_reduces() {
    let bin = env!("CARGO_BIN_EXE_mpi-allreduce");
    let out = run_with_timeout(Command::new("mpiexec").args(["-n", "2", bin]), LIMIT);
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
    let token = child_token();
    let child = command(&workspace_bin("glissade-server"))
        .args(["--listen", "127.0.0.1:0", "--data"])
        .arg(data)
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
        assert_eq!(db.get("meta/schema-version")?.as_deref(), Some(&b"1"[..]));
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
fn worker_warm_start_from_a_saved_solution_converges_at_once() -> anyhow::Result<()> {
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
    assert!(iterations <= 2, "warm start from the converged solution took {iterations} iterations");

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
    Ok(())
}
