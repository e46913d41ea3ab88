//! Dispatch throughput of the coordinator, with a FAKE, INSTANT "solver": a benchmark of the
//! service alone (lease, warm-start transfer, completion, database commits), not of any solve.
//!
//! K fake pools (tasks of this process, each with its own connection: src/synthetic.rs) lease
//! the points of one study and complete each at once with a small synthetic solution file of the
//! right scene and point (one interface node: about 5 kB), so every rule of the coordinator runs
//! as for real solutions. Prints one JSON object: points per second and latency percentiles, then what the
//! web page's requests cost on the study solved (its page, its JSON whole, the progress an open page polls,
//! the list of studies): bytes and the median of 5 fetches.
//!
//!   service-bench [--no-web] URL SCENE.toml POOLS STRATEGY ORDER GRID...
//!   service-bench http://127.0.0.1:50051 scenes/three-blocks-tiny.toml 4 nearest asc \
//!       f1=0.1:0.2:50 f2=0.1:0.2:40
//!
//! STRATEGY: cold | previous | nearest | blend; ORDER: asc | desc | greedy. `--no-web`: no web
//! request (the coordinator's memory is then what the study left).

use std::process::ExitCode;
use std::time::Instant;

use std::sync::Arc;

use glissade_core::scene::Scene;
use glissade_e2e::bench::{self, percentile};
use glissade_e2e::synthetic::{self, Error};
use glissade_proto::v1;
use glissade_proto::v1::user_client::UserClient;

struct Args {
    web: bool,
    url: String,
    scene_text: String,
    pools: usize,
    strategy: v1::InitStrategy,
    order: v1::PointOrder,
    grid: Vec<String>,
}

fn parse_args() -> Result<Args, Error> {
    let mut a: Vec<String> = std::env::args().skip(1).collect();
    let web = a.first().is_none_or(|f| f != "--no-web");
    if !web {
        a.remove(0);
    }
    if a.len() < 6 {
        return Err("usage: service-bench [--no-web] URL SCENE.toml POOLS STRATEGY ORDER GRID...".into());
    }
    let strategy = match a[3].as_str() {
        "cold" => v1::InitStrategy::Cold,
        "previous" => v1::InitStrategy::Previous,
        "nearest" => v1::InitStrategy::Nearest,
        "blend" => v1::InitStrategy::Blend,
        s => return Err(format!("unknown strategy {s}").into()),
    };
    let order = match a[4].as_str() {
        "asc" => v1::PointOrder::Ascending,
        "desc" => v1::PointOrder::Descending,
        "greedy" => v1::PointOrder::Greedy,
        s => return Err(format!("unknown order {s}").into()),
    };
    Ok(Args {
        web,
        url: a[0].clone(),
        scene_text: std::fs::read_to_string(&a[1]).map_err(|e| format!("{}: {e}", a[1]))?,
        pools: a[2].parse()?,
        strategy,
        order,
        grid: a[5..].to_vec(),
    })
}

/// Bytes and the median wall time (ms) of 5 GETs of `path` from the coordinator's web page.
fn web_cost(url: &str, path: &str) -> Result<serde_json::Value, Error> {
    use std::io::{Read, Write};
    let addr = url.trim_start_matches("http://");
    let mut ms = Vec::new();
    let mut bytes = 0;
    for _ in 0..5 {
        let started = Instant::now();
        let mut stream = std::net::TcpStream::connect(addr)?;
        write!(stream, "GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n")?;
        let mut answer = Vec::new();
        stream.read_to_end(&mut answer)?;
        ms.push(started.elapsed().as_secs_f64() * 1e3);
        let head = answer.windows(4).position(|w| w == b"\r\n\r\n").map_or(0, |i| i + 4);
        if !answer.starts_with(b"HTTP/1.1 200") {
            return Err(format!("GET {path}: {}", String::from_utf8_lossy(&answer[..head.min(answer.len())])).into());
        }
        bytes = answer.len() - head;
    }
    Ok(serde_json::json!({"bytes": bytes, "ms_p50": percentile(&mut ms, 0.5)}))
}

async fn run(args: Args) -> Result<serde_json::Value, Error> {
    let scene = Scene::parse(&args.scene_text)?;
    let mut user = UserClient::connect(args.url.clone()).await?;
    let start = Instant::now();
    let reply = user
        .submit_study(v1::SubmitStudyRequest {
            scene: args.scene_text.clone(),
            grid: args.grid.clone(),
            tolerance: Some(1e-3),
            strategy: args.strategy.into(),
            order: args.order.into(),
            // the study's own dispatch alone: its audits would lease other scenes' points
            audit_points: Some(0),
            refine_points: Some(0),
            surface_audit_points: Some(0),
            ..Default::default()
        })
        .await?
        .into_inner();
    let submitted = start.elapsed();
    // every point the same answer: the dispatch is measured, not the surfaces
    let answering: synthetic::Answering =
        Arc::new(|_| synthetic::Answer { qoi: [("q".to_string(), 1.0)].into(), history: Vec::new() });
    let tasks: Vec<_> = (0..args.pools)
        .map(|i| {
            tokio::spawn(synthetic::pool(
                args.url.clone(),
                None,
                format!("bench-{i}"),
                scene.clone(),
                answering.clone(),
            ))
        })
        .collect();
    let (mut lease_ms, mut complete_ms, mut last) = (Vec::new(), Vec::new(), start);
    for t in tasks {
        let (l, c, end) = t.await??;
        lease_ms.extend(l);
        complete_ms.extend(c);
        last = last.max(end.unwrap_or(start));
    }
    // The final NoWork waits are not dispatch time: the clock stops at the last completion.
    let study = user
        .get_study(v1::GetStudyRequest { study_id: reply.study_id, points: false, ..Default::default() })
        .await?
        .into_inner();
    let done = study.progress.map_or(0, |p| p.done);
    let elapsed = last - start;
    let id = reply.study_id;
    let web = if args.web {
        serde_json::json!({
            "study_json": web_cost(&args.url, &format!("/api/studies/{id}"))?,
            "study_page": web_cost(&args.url, &format!("/studies/{id}"))?,
            "progress_json": web_cost(&args.url, &format!("/api/studies/{id}/progress"))?,
            "studies_page": web_cost(&args.url, "/")?,
        })
    } else {
        serde_json::Value::Null
    };
    Ok(serde_json::json!({
        "points": reply.points,
        "done": done,
        "pools": args.pools,
        "strategy": args.strategy.as_str_name(),
        "order": args.order.as_str_name(),
        "submit_seconds": submitted.as_secs_f64(),
        "seconds": elapsed.as_secs_f64(),
        "points_per_second": done as f64 / elapsed.as_secs_f64(),
        "lease_ms": {"p50": percentile(&mut lease_ms, 0.5), "p99": percentile(&mut lease_ms, 0.99)},
        "complete_ms": {"p50": percentile(&mut complete_ms, 0.5), "p99": percentile(&mut complete_ms, 0.99)},
        "web": web,
    }))
}

fn main() -> ExitCode {
    let result = parse_args()
        .and_then(|args| tokio::runtime::Builder::new_multi_thread().enable_all().build()?.block_on(run(args)));
    bench::report(result)
}
