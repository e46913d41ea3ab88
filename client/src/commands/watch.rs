//! `glissade watch`: follows a study to its end, reconnecting when the coordinator goes away.

use std::io::IsTerminal;
use std::time::{Duration, Instant};

use anyhow::Result;
use glissade_cli::outln;
use glissade_cli::progress::WatchState;
use glissade_core::text::one_line;
use glissade_proto::now_unix_ms;
use glissade_proto::v1;
use tonic::{Code, Status};

use crate::{Outcome, User, refused};

/// Follows a study to its end: an indicatif bar on a terminal, plain lines otherwise; then the
/// summary. StudyFailed when it ended with failed or cancelled points.
pub(crate) async fn watch(client: &mut User, id: u64) -> Result<Outcome> {
    let mut stream = client
        .watch_study(v1::WatchStudyRequest { study_id: id })
        .await
        .map_err(|s| refused(&format!("watch {id}"), s))?
        .into_inner();
    let started = Instant::now();
    let mut state = WatchState::new(id);
    let bar = std::io::stderr().is_terminal().then(|| {
        let bar = indicatif::ProgressBar::new(0);
        bar.set_style(
            indicatif::ProgressStyle::with_template("{spinner} study {prefix} [{bar:30}] {pos}/{len}  {msg}")
                .map(|s| s.progress_chars("=> "))
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        bar.set_prefix(id.to_string());
        bar.enable_steady_tick(Duration::from_millis(200));
        bar
    });
    let say = |text: &str| match &bar {
        Some(bar) => bar.println(text),
        None => eprintln!("{text}"),
    };
    loop {
        let event = match stream.message().await {
            Ok(Some(e)) => e,
            // The coordinator went away (restart, crash, network): the study's events are
            // durable, so a new watch starts from a snapshot. Reconnect with back-off.
            broken @ (Ok(None) | Err(_)) => {
                if let Err(s) = &broken
                    && !is_transient(s)
                {
                    if let Some(bar) = &bar {
                        bar.abandon();
                    }
                    return Err(refused(&format!("watch {id}: the stream broke off"), s.clone()));
                }
                let why = broken.err().map_or("the stream ended".to_owned(), |s| one_line(s.message()));
                say(&format!("watch {id}: lost the coordinator ({why}); reconnecting"));
                stream = reconnect_watch(client, id, &say).await?;
                continue;
            }
        };
        let line = state.apply(&event);
        match &bar {
            Some(bar) => {
                let (position, total) = state.position();
                bar.set_length(total);
                bar.set_position(position);
                let eta = state.eta(started.elapsed()).map_or(String::new(), |d| format!(", ETA {}", clock(d)));
                bar.set_message(format!("{}; {}{eta}\n  {}", state.counts(), state.iterations(), {
                    let running = state.running_line(now_unix_ms());
                    if running.is_empty() { "-".to_owned() } else { format!("running: {running}") }
                }));
            }
            None => {
                if let Some(line) = line {
                    let eta = state.eta(started.elapsed()).map_or(String::new(), |d| format!(" (ETA {})", clock(d)));
                    outln!("{line}{eta}");
                }
            }
        }
        // (not at the snapshot of a finished study: its points' replay comes after it)
        if state.ended() && event.kind == v1::EventKind::StudyEnded as i32 {
            break;
        }
    }
    if let Some(bar) = &bar {
        bar.finish_and_clear();
    }
    outln!("{}", state.summary(started.elapsed()));
    // its points have ended; its audits may not have (a look, not a wait: they answer no one)
    if let Ok(s) = client.get_study(v1::GetStudyRequest { study_id: id, ..Default::default() }).await {
        let running = crate::commands::show::audits_running(&s.into_inner());
        if !running.is_empty() {
            outln!("study {id}{running}: `glissade show {id}` follows them");
        }
    }
    Ok(if state.state == v1::StudyState::Done as i32 { Outcome::Success } else { Outcome::StudyFailed })
}

/// Statuses after which a watch reconnects: the coordinator or the network went away, not a
/// refusal of this request.
pub(crate) fn is_transient(s: &Status) -> bool {
    matches!(s.code(), Code::Unavailable | Code::Unknown | Code::Cancelled | Code::Aborted)
}

/// A new watch of study `id`, retried with back-off (0.2 s doubling to 5 s) for as long as the
/// coordinator is unreachable; a refusal (the study is gone) ends it.
pub(crate) async fn reconnect_watch(
    client: &mut User,
    id: u64,
    say: &impl Fn(&str),
) -> Result<tonic::Streaming<v1::StudyEvent>> {
    let mut pause = Duration::from_millis(200);
    let mut attempts = 0u32;
    loop {
        tokio::time::sleep(pause).await;
        attempts += 1;
        match client.watch_study(v1::WatchStudyRequest { study_id: id }).await {
            Ok(r) => {
                say(&format!("watch {id}: reconnected after {attempts} attempt(s)"));
                return Ok(r.into_inner());
            }
            Err(s) if is_transient(&s) => {
                if attempts.is_multiple_of(10) {
                    say(&format!(
                        "watch {id}: still no coordinator after {attempts} attempts ({})",
                        one_line(s.message())
                    ));
                }
                pause = (pause * 2).min(Duration::from_secs(5));
            }
            Err(s) => return Err(refused(&format!("watch {id}"), s)),
        }
    }
}

pub(crate) fn clock(d: Duration) -> String {
    let s = d.as_secs();
    if s >= 3600 { format!("{}h{:02}m", s / 3600, s % 3600 / 60) } else { format!("{}m{:02}s", s / 60, s % 60) }
}
