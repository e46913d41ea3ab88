//! Helpers for the end-to-end tests: finding the workspace's binaries and running them with a
//! time limit, so a hung child fails a test instead of hanging CI.

pub mod bench;
pub mod synthetic;
use std::io::Read;
use std::path::PathBuf;
use std::process::{Child, Command, ExitStatus, Output, Stdio};
use std::sync::{Condvar, Mutex, PoisonError};
use std::thread;
use std::time::{Duration, Instant};

/// A child process inherits the test process's open files: until it execs, and for files opened
/// without close-on-exec (HDF5 opens its files so) until it exits. A child spawned by one test
/// while another test holds a file lock in-process (HDF5, sled) thus keeps that lock, and the
/// other test's reopening fails with EWOULDBLOCK. So tests that lock files in-process run while
/// no child runs ([`no_children`]), and every spawn holds a [`ChildToken`] while its child lives.
struct Gate {
    children: usize,
    exclusive: bool,
}

static GATE: Mutex<Gate> = Mutex::new(Gate { children: 0, exclusive: false });
static GATE_CHANGED: Condvar = Condvar::new();

/// Held while a child process of a test runs (see [`no_children`]).
pub struct ChildToken(());

impl Drop for ChildToken {
    fn drop(&mut self) {
        GATE.lock().unwrap_or_else(PoisonError::into_inner).children -= 1;
        GATE_CHANGED.notify_all();
    }
}

/// Take before spawning a child process yourself ([`run_with_timeout`] does), and keep it until
/// the child is reaped. Tokens may nest; they wait only while a [`NoChildren`] is held.
pub fn child_token() -> ChildToken {
    let mut gate = GATE.lock().unwrap_or_else(PoisonError::into_inner);
    while gate.exclusive {
        gate = GATE_CHANGED.wait(gate).unwrap_or_else(PoisonError::into_inner);
    }
    gate.children += 1;
    ChildToken(())
}

/// Held by a test that locks files in-process: no child process runs meanwhile.
pub struct NoChildren(());

impl Drop for NoChildren {
    fn drop(&mut self) {
        GATE.lock().unwrap_or_else(PoisonError::into_inner).exclusive = false;
        GATE_CHANGED.notify_all();
    }
}

/// Waits until no child process of any test runs, and keeps new ones from starting until dropped.
/// Do not spawn while holding it (that would wait for itself).
pub fn no_children() -> NoChildren {
    let mut gate = GATE.lock().unwrap_or_else(PoisonError::into_inner);
    while gate.exclusive || gate.children > 0 {
        gate = GATE_CHANGED.wait(gate).unwrap_or_else(PoisonError::into_inner);
    }
    gate.exclusive = true;
    NoChildren(())
}

/// Path of binary `name` built by this workspace, e.g. `glissade-server`.
///
/// Binaries of *other* packages are not built for this crate's tests by Cargo, so they are looked
/// up beside the test executable: `target/<profile>/deps/smoke-HASH` -> `target/<profile>/NAME`.
///
/// # Panics
/// When the binary is missing, with a message saying to run `cargo build --workspace` first.
pub fn workspace_bin(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("cannot locate the running test executable");
    let deps = exe.parent().expect("test executable has no parent directory");
    // Integration tests live in `<profile>/deps`; tolerate being run from `<profile>` directly.
    let profile_dir = if deps.file_name().is_some_and(|n| n == "deps") {
        deps.parent().expect("`deps` has no parent directory")
    } else {
        deps
    };
    let path = profile_dir.join(format!("{name}{}", std::env::consts::EXE_SUFFIX));
    assert!(
        path.is_file(),
        "binary `{name}` not found at {}: run `cargo build --workspace` first \
         (cargo builds other packages' binaries only on request)",
        path.display()
    );
    path
}

/// Runs `cmd` to completion with stdin closed, capturing stdout and stderr.
///
/// # Panics
/// When it cannot start, or runs longer than `limit` (the child is killed first).
pub fn run_with_timeout(cmd: &mut Command, limit: Duration) -> Output {
    let _running = child_token();
    let described = format!("{cmd:?}");
    let mut child = cmd
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start {described}: {e}"));
    // Drain the pipes on threads so a chatty child cannot block on a full pipe.
    let stdout = drain(child.stdout.take());
    let stderr = drain(child.stderr.take());
    let status = wait_with_timeout(&mut child, limit)
        .unwrap_or_else(|| panic!("{described} did not finish within {limit:?}; killed it"));
    Output {
        status,
        stdout: stdout.join().expect("stdout reader panicked"),
        stderr: stderr.join().expect("stderr reader panicked"),
    }
}

/// Waits for `child` up to `limit`; on timeout kills and reaps it and returns `None`.
pub fn wait_with_timeout(child: &mut Child, limit: Duration) -> Option<ExitStatus> {
    let deadline = Instant::now() + limit;
    loop {
        match child.try_wait() {
            Ok(Some(status)) => return Some(status),
            Ok(None) if Instant::now() < deadline => thread::sleep(Duration::from_millis(20)),
            Ok(None) | Err(_) => {
                let _ = child.kill();
                let _ = child.wait();
                return None;
            }
        }
    }
}

fn drain<R: Read + Send + 'static>(pipe: Option<R>) -> thread::JoinHandle<Vec<u8>> {
    thread::spawn(move || {
        let mut buf = Vec::new();
        if let Some(mut pipe) = pipe {
            let _ = pipe.read_to_end(&mut buf);
        }
        buf
    })
}
