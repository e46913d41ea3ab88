//! An honest user's study beside hostile clients (issue 48's goal): points dispatched per second
//! and the Health check's latency, quiet and under attack, in one run.
//!
//!   load-bench SERVER_BIN SCENE.toml HOSTILE READERS POOLS GRID... [-- SERVER_ARGS...]
//!   load-bench target/release/glissade-server scenes/three-blocks-tiny.toml 1000 8 4 f1=0.1:0.2:40 f2=0.1:0.2:25
//!
//! It starts SERVER_BIN with tokens on loopback in a temporary directory, has POOLS fake pools
//! (src/synthetic.rs: an instant "solver", so that the coordinator's own work is measured) solve a
//! first study of the grid (the one the readers then read; its page is loaded once, which draws
//! its pictures), then three more studies of the same grid, cold, one at a time: quiet, under
//! attack, quiet again. The attack:
//! - HOSTILE connections without a token, from 127.0.0.2-9, each kept open for as long as the
//!   coordinator allows and opened again when closed: half send HTTP/2's preface and a PING every
//!   second, half a login body a byte every 2 s;
//! - READERS clients with the user token, each from its own address (127.0.0.10 on), each
//!   fetching in turn the first study's whole JSON, its page and the list of studies, as fast as
//!   they are answered, taking gzip as a browser does; a 429 (the coordinator's
//!   `--web-reads-per-second`) is counted and the reader asks again at once, ignoring
//!   `Retry-After` as a hostile one would (with `LOAD_BENCH_RETRY_AFTER=1`, it waits as told, as
//!   a browser or a client library does).
//!
//! The attack runs on a runtime (threads) of its own, the honest study's pools and the checker
//! on the bench's main one, as they would on different hosts; all share the machine's cores
//! with the coordinator.
//!
//! Meanwhile a checker opens a new connection every 100 ms and asks Health with the user token
//! (what a CLI call or a pool's first call does). Prints one JSON object: per phase the points per
//! second, Health's latency (p50, p99, the worst, and the checks that failed), the attack's
//! connections and reads; the throughput under attack relative to the mean of the quiet phases;
//! the coordinator's resident memory before and after.

use std::process::{Child, ExitCode, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use glissade_core::scene::Scene;
use glissade_e2e::bench::{self, percentile};
use glissade_e2e::synthetic::{self, Error};
use glissade_proto::auth::{Token, WithToken};
use glissade_proto::v1;
use glissade_proto::v1::health_client::HealthClient;
use glissade_proto::v1::user_client::UserClient;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

struct Args {
    server: String,
    scene_text: String,
    hostile: usize,
    readers: usize,
    pools: usize,
    grid: Vec<String>,
    /// given to the server after its own arguments (after `--`)
    server_args: Vec<String>,
}

const USER_TOKEN: &str = "load-bench-user-token-0123456789abcdef";
const POOL_TOKEN: &str = "load-bench-pool-token-0123456789abcdef";

fn parse_args() -> Result<Args, Error> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    let (a, server_args) = match a.iter().position(|x| x == "--") {
        Some(at) => (a[..at].to_vec(), a[at + 1..].to_vec()),
        None => (a, Vec::new()),
    };
    if a.len() < 6 {
        return Err("usage: load-bench SERVER_BIN SCENE.toml HOSTILE READERS POOLS GRID... [-- SERVER_ARGS...]".into());
    }
    Ok(Args {
        server: a[0].clone(),
        scene_text: std::fs::read_to_string(&a[1]).map_err(|e| format!("{}: {e}", a[1]))?,
        hostile: a[2].parse()?,
        readers: a[3].parse()?,
        pools: a[4].parse()?,
        grid: a[5..].to_vec(),
        server_args,
    })
}

/// The coordinator, stopped when dropped.
struct Server(Child);

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn start_server(bin: &str, extra: &[String], dir: &std::path::Path) -> Result<(Server, String), Error> {
    use std::io::BufRead;
    std::fs::write(dir.join("user.token"), USER_TOKEN)?;
    std::fs::write(dir.join("pool.token"), POOL_TOKEN)?;
    let mut child = std::process::Command::new(bin)
        .args(["--listen", "127.0.0.1:0", "--data"])
        .arg(dir.join("db"))
        .arg("--user-token-file")
        .arg(dir.join("user.token"))
        .arg("--pool-token-file")
        .arg(dir.join("pool.token"))
        .args(["--max-points", "1000000", "--max-pending", "1000000"])
        .args(extra)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(std::fs::File::create(dir.join("server.log"))?)
        .spawn()
        .map_err(|e| format!("{bin}: {e}"))?;
    let stdout = child.stdout.take().ok_or("no stdout")?;
    let server = Server(child);
    let mut line = String::new();
    std::io::BufReader::new(stdout).read_line(&mut line)?;
    let addr = line.trim_end().strip_prefix("listening on ").ok_or_else(|| format!("the server said {line:?}"))?;
    Ok((server, format!("http://{addr}")))
}

/// The coordinator's resident memory, MiB.
fn rss_mib(server: &Server) -> f64 {
    let status = std::fs::read_to_string(format!("/proc/{}/status", server.0.id())).unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

fn token() -> Token {
    Token::parse(USER_TOKEN, "the bench's token").expect("a valid token")
}

/// Submits a study of the grid and has the pools solve it; its id and points per second.
async fn solve_study(url: &str, args: &Args, scene: &Scene) -> Result<(u64, f64), Error> {
    let channel = tonic::transport::Endpoint::from_shared(url.to_owned())?.connect().await?;
    let mut user = UserClient::with_interceptor(channel, WithToken::new(Some(&token())));
    let start = Instant::now();
    let reply = user
        .submit_study(v1::SubmitStudyRequest {
            scene: args.scene_text.clone(),
            grid: args.grid.clone(),
            tolerance: Some(1e-3),
            strategy: v1::InitStrategy::Cold.into(),
            order: v1::PointOrder::Ascending.into(),
            audit_points: Some(0),
            refine_points: Some(0),
            surface_audit_points: Some(0),
            ..Default::default()
        })
        .await?
        .into_inner();
    let answering: synthetic::Answering = Arc::new(|p| synthetic::Answer {
        qoi: [("q".to_string(), p.values().sum::<f64>())].into(),
        history: Vec::new(),
    });
    let tasks: Vec<_> = (0..args.pools)
        .map(|i| {
            tokio::spawn(synthetic::pool(
                url.to_owned(),
                Some(POOL_TOKEN.to_owned()),
                format!("bench-{i}"),
                scene.clone(),
                answering.clone(),
            ))
        })
        .collect();
    let mut last = start;
    for t in tasks {
        let (_, _, end) = t.await??;
        last = last.max(end.unwrap_or(start));
    }
    Ok((reply.study_id, f64::from(reply.points) / (last - start).as_secs_f64()))
}

/// Health asked every 100 ms on a new connection until `stop`: latencies (ms) and failures.
async fn check_health(url: String, stop: Arc<AtomicBool>) -> (Vec<f64>, u64) {
    let (mut ms, mut failed) = (Vec::new(), 0);
    while !stop.load(Ordering::Relaxed) {
        let started = Instant::now();
        let asked = async {
            let channel = tonic::transport::Endpoint::from_shared(url.clone())?
                .connect_timeout(Duration::from_secs(5))
                .connect()
                .await?;
            HealthClient::with_interceptor(channel, WithToken::new(Some(&token()))).check(v1::HealthRequest {}).await?;
            Ok::<_, Error>(())
        };
        match tokio::time::timeout(Duration::from_secs(5), asked).await {
            Ok(Ok(())) => ms.push(started.elapsed().as_secs_f64() * 1e3),
            _ => failed += 1,
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    (ms, failed)
}

/// What the attack did: connections opened (each closed by the coordinator but the last) and
/// bytes the readers read.
#[derive(Default)]
struct Attack {
    connections: AtomicU64,
    reads: AtomicU64,
    read_bytes: AtomicU64,
    read_failures: AtomicU64,
    /// answered 429: over the address's budget of web requests
    refused: AtomicU64,
}

/// One hostile client without a token: open, send, reopen when closed, until `stop`.
async fn hostile(addr: std::net::SocketAddr, k: usize, attack: Arc<Attack>, stop: Arc<AtomicBool>) {
    const PREFACE: &[u8] = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n\x00\x00\x00\x04\x00\x00\x00\x00\x00";
    const PING: &[u8] = b"\x00\x00\x08\x06\x00\x00\x00\x00\x00pingping";
    let source: std::net::SocketAddr = ([127, 0, 0, 2 + (k % 8) as u8], 0).into();
    while !stop.load(Ordering::Relaxed) {
        let connected = async {
            let socket = tokio::net::TcpSocket::new_v4()?;
            socket.bind(source)?;
            socket.connect(addr).await
        };
        let Ok(stream) = connected.await else {
            tokio::time::sleep(Duration::from_millis(200)).await;
            continue;
        };
        attack.connections.fetch_add(1, Ordering::Relaxed);
        let (mut read, mut write) = stream.into_split();
        // read (and drop) whatever comes back, so that the socket's buffers never fill
        let reader = tokio::spawn(async move {
            let mut sink = [0u8; 4096];
            while matches!(read.read(&mut sink).await, Ok(n) if n > 0) {}
        });
        let (first, next, every): (Vec<u8>, &[u8], u64) = if k.is_multiple_of(2) {
            (PREFACE.to_vec(), PING, 1000)
        } else {
            let head = "POST /login HTTP/1.1\r\nHost: x\r\nContent-Type: application/x-www-form-urlencoded\r\nContent-Length: 100000\r\n\r\n";
            (head.as_bytes().to_vec(), b"t", 2000)
        };
        let mut sent = write.write_all(&first).await;
        while sent.is_ok() && !reader.is_finished() && !stop.load(Ordering::Relaxed) {
            tokio::time::sleep(Duration::from_millis(every)).await;
            sent = write.write_all(next).await;
        }
        reader.abort();
    }
}

/// GET `path` from the address `from` with the user token: the whole answer.
async fn get(from: std::net::IpAddr, addr: std::net::SocketAddr, path: &str) -> std::io::Result<Vec<u8>> {
    let socket = tokio::net::TcpSocket::new_v4()?;
    socket.bind((from, 0).into())?;
    let mut s = socket.connect(addr).await?;
    let head = format!(
        "GET {path} HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer {USER_TOKEN}\r\nAccept-Encoding: gzip\r\n\
         Connection: close\r\n\r\n"
    );
    s.write_all(head.as_bytes()).await?;
    let mut answer = Vec::new();
    s.read_to_end(&mut answer).await?;
    Ok(answer)
}

/// How long a 429 said to wait, where the bench is asked to honour it.
fn retry_after(answer: &[u8]) -> Option<Duration> {
    if std::env::var_os("LOAD_BENCH_RETRY_AFTER").is_none_or(|v| v != "1") {
        return None;
    }
    let head = String::from_utf8_lossy(&answer[..answer.len().min(4096)]).to_ascii_lowercase();
    let seconds = head.lines().find_map(|l| l.strip_prefix("retry-after:"))?.trim().parse().ok()?;
    Some(Duration::from_secs(seconds))
}

/// One heavy reader with the user token: the first study's JSON, its page, the list, in turn.
async fn reader(k: usize, addr: std::net::SocketAddr, study: u64, attack: Arc<Attack>, stop: Arc<AtomicBool>) {
    let from = std::net::IpAddr::from([127, 0, 0, 10 + (k % 240) as u8]);
    let paths = [format!("/api/studies/{study}"), format!("/studies/{study}"), "/".to_owned()];
    let mut i = 0;
    while !stop.load(Ordering::Relaxed) {
        let path = &paths[i % paths.len()];
        i += 1;
        match tokio::time::timeout(Duration::from_secs(60), get(from, addr, path)).await {
            Ok(Ok(a)) if a.starts_with(b"HTTP/1.1 200") => {
                attack.reads.fetch_add(1, Ordering::Relaxed);
                attack.read_bytes.fetch_add(a.len() as u64, Ordering::Relaxed);
            }
            Ok(Ok(a)) if a.starts_with(b"HTTP/1.1 429") => {
                attack.refused.fetch_add(1, Ordering::Relaxed);
                if let Some(wait) = retry_after(&a) {
                    tokio::time::sleep(wait).await;
                }
            }
            _ => {
                attack.read_failures.fetch_add(1, Ordering::Relaxed);
                tokio::time::sleep(Duration::from_millis(200)).await;
            }
        }
    }
}

/// One of the measured studies, with Health checked beside it.
async fn phase(url: &str, args: &Args, scene: &Scene) -> Result<serde_json::Value, Error> {
    let stop = Arc::new(AtomicBool::new(false));
    let checker = tokio::spawn(check_health(url.to_owned(), stop.clone()));
    let (_, points_per_second) = solve_study(url, args, scene).await?;
    stop.store(true, Ordering::Relaxed);
    let (mut ms, failed) = checker.await?;
    Ok(serde_json::json!({
        "points_per_second": points_per_second,
        "health_ms": {
            "p50": percentile(&mut ms, 0.5),
            "p99": percentile(&mut ms, 0.99),
            "max": percentile(&mut ms, 1.0),
            "checks": ms.len(),
            "failed": failed,
        },
    }))
}

async fn run(args: Args) -> Result<serde_json::Value, Error> {
    let scene = Scene::parse(&args.scene_text)?;
    let dir = std::env::temp_dir().join(format!("load-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let (server, url) = start_server(&args.server, &args.server_args, &dir)?;
    let addr: std::net::SocketAddr = url.trim_start_matches("http://").parse()?;
    let (first, _) = solve_study(&url, &args, &scene).await?;
    // its page once, quiet: the pictures drawn and kept, as for a study someone has looked at
    let drawn = Instant::now();
    let page = get([127, 0, 0, 1].into(), addr, &format!("/studies/{first}")).await?;
    if !page.starts_with(b"HTTP/1.1 200") {
        return Err(format!("the first study's page: {}", String::from_utf8_lossy(&page[..page.len().min(200)])).into());
    }
    let first_page_seconds = drawn.elapsed().as_secs_f64();
    let rss_before = rss_mib(&server);

    let quiet = phase(&url, &args, &scene).await?;
    let attack = Arc::new(Attack::default());
    let stop = Arc::new(AtomicBool::new(false));
    // the attack on threads of its own, as it would be on hosts of its own: on the honest side's
    // runtime its thousand tasks queued the pools' and the checker's behind them
    let attackers = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build()?;
    let mut tasks: Vec<_> =
        (0..args.hostile).map(|k| attackers.spawn(hostile(addr, k, attack.clone(), stop.clone()))).collect();
    tasks.extend((0..args.readers).map(|k| attackers.spawn(reader(k, addr, first, attack.clone(), stop.clone()))));
    // the attack in place (every slot taken) before the honest study starts
    tokio::time::sleep(Duration::from_secs(3)).await;
    let attacked = phase(&url, &args, &scene).await;
    stop.store(true, Ordering::Relaxed);
    for t in tasks {
        t.abort();
    }
    attackers.shutdown_background();
    let attacked = attacked?;
    let quiet_again = phase(&url, &args, &scene).await?;
    let rss_after = rss_mib(&server);
    drop(server);
    let _ = std::fs::remove_dir_all(&dir);

    let rate = |v: &serde_json::Value| v["points_per_second"].as_f64().unwrap_or(f64::NAN);
    let relative = rate(&attacked) / ((rate(&quiet) + rate(&quiet_again)) / 2.0);
    Ok(serde_json::json!({
        "grid": args.grid,
        "pools": args.pools,
        "hostile": args.hostile,
        "readers": args.readers,
        "server_args": args.server_args,
        "quiet": quiet,
        "attacked": attacked,
        "quiet_again": quiet_again,
        "attacked_throughput_relative": relative,
        "attack": {
            "connections_opened": attack.connections.load(Ordering::Relaxed),
            "reads": attack.reads.load(Ordering::Relaxed),
            "read_mib": attack.read_bytes.load(Ordering::Relaxed) as f64 / (1u64 << 20) as f64,
            "read_failures": attack.read_failures.load(Ordering::Relaxed),
            "refused": attack.refused.load(Ordering::Relaxed),
        },
        "first_page_seconds": first_page_seconds,
        "rss_mib": {"after_first_study": rss_before, "end": rss_after},
    }))
}

fn main() -> ExitCode {
    let result = parse_args()
        .and_then(|args| tokio::runtime::Builder::new_multi_thread().enable_all().build()?.block_on(run(args)));
    bench::report(result)
}
