//! The coordinator's study list against the number of studies it holds: submits N one-point
//! studies of a scene (their audits are one-point studies too), then times M ListStudies calls.
//! Prints one JSON object: the studies listed and the call's latency percentiles.
//!
//!   list-bench URL SCENE.toml N M
//!   list-bench http://127.0.0.1:50051 scenes/three-blocks-tiny.toml 200 50
//!
//! A point of each study has its own f1, so that no study answers another's from the store.

use std::process::ExitCode;
use std::time::Instant;

use glissade_proto::v1;
use glissade_proto::v1::user_client::UserClient;

type Error = Box<dyn std::error::Error + Send + Sync>;

async fn run(url: String, scene: String, n: usize, m: usize) -> Result<serde_json::Value, Error> {
    let mut user = UserClient::connect(url).await?;
    for i in 0..n {
        let f1 = 0.1 + 0.1 * i as f64 / n as f64;
        user.submit_study(v1::SubmitStudyRequest {
            scene: scene.clone(),
            grid: vec![format!("f1={f1}")],
            ..Default::default()
        })
        .await?;
    }
    let mut ms = Vec::with_capacity(m);
    let mut listed = 0;
    for _ in 0..m {
        let start = Instant::now();
        listed = user.list_studies(v1::ListStudiesRequest::default()).await?.into_inner().studies.len();
        ms.push(start.elapsed().as_secs_f64() * 1e3);
    }
    ms.sort_by(f64::total_cmp);
    let at = |q: f64| ms[((ms.len() - 1) as f64 * q).round() as usize];
    Ok(serde_json::json!({"studies": listed, "calls": m, "list_ms": {"p50": at(0.5), "p90": at(0.9), "min": ms[0]}}))
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [url, scene, n, m] = args.as_slice() else {
        eprintln!("usage: list-bench URL SCENE.toml N M");
        return ExitCode::from(2);
    };
    let parsed = (std::fs::read_to_string(scene), n.parse::<usize>(), m.parse::<usize>());
    let (Ok(scene), Ok(n), Ok(m @ 1..)) = parsed else {
        eprintln!("list-bench: a readable scene, a number of studies and at least one call");
        return ExitCode::from(2);
    };
    let runtime = tokio::runtime::Runtime::new().expect("a tokio runtime");
    match runtime.block_on(run(url.clone(), scene, n, m)) {
        Ok(json) => {
            println!("{json}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("list-bench: {e}");
            ExitCode::FAILURE
        }
    }
}
