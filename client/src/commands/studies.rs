//! `glissade studies`, `cancel` and `retry`: the list of studies, and what a user changes of one.

use anyhow::Result;
use glissade_cli::names::{strategy_name, study_state_name};
use glissade_cli::outln;
use glissade_proto::v1;

use crate::{Server, refused, user};

pub(crate) async fn studies(server: &Server, json: bool, all: bool) -> Result<()> {
    // page by page: the whole list at once could pass the message limit
    let mut client = user(server).await?;
    let (mut list, mut after) = (Vec::new(), 0);
    loop {
        let page = client
            .list_studies(v1::ListStudiesRequest { after, limit: 0 })
            .await
            .map_err(|s| refused("list studies", s))?
            .into_inner();
        list.extend(page.studies);
        if page.next_after == 0 || page.next_after <= after {
            break;
        }
        after = page.next_after;
    }
    // the audits and pilots' levels are counted on their study's row unless asked for
    let under = |s: &v1::Study| s.audit_of != 0 || s.pilot_of != 0;
    if !all {
        list.retain(|s| !under(s));
    }
    if json {
        // ListStudies' studies in the proto's JSON, as the web API's /api/studies serves them
        outln!("{}", glissade_proto::json::to_string(&list));
        return Ok(());
    }
    if list.is_empty() {
        outln!("no studies yet (glissade submit SCENE --grid ...)");
        return Ok(());
    }
    outln!(
        "{:>5}  {:<8}  {:<9}  {:>11}  {:<14}  {:<9}  {:<14}  {:>8}  {:<20}  {:>8}  scene / label",
        "id",
        "kind",
        "state",
        "done/total",
        "audits",
        "strategy",
        "parameters",
        "tol",
        "submitted",
        "wall"
    );
    for s in &list {
        let p = s.progress.unwrap_or_default();
        let wall = if s.finished_unix_ms > 0 {
            glissade_core::text::wall_time((s.finished_unix_ms - s.created_unix_ms) as f64 / 1e3)
        } else {
            "-".to_owned()
        };
        let title =
            [s.scene_title.as_str(), s.label.as_str()].iter().filter(|t| !t.is_empty()).cloned().collect::<Vec<_>>();
        outln!(
            "{:>5}  {:<8}  {:<9}  {:>11}  {:<14}  {:<9}  {:<14}  {:>8.1e}  {:<20}  {:>8}  {}",
            s.study_id,
            s.kind,
            study_state_name(s.state),
            format!("{}/{}", p.done, p.total),
            audits_cell(s),
            strategy_name(s.strategy),
            s.parameters.join(","),
            s.tolerance,
            glissade_core::text::utc_minute(s.created_unix_ms),
            wall,
            title.join(" / ")
        );
    }
    Ok(())
}

/// A study's audits and pilots' levels in a cell of the list (as the web page's).
fn audits_cell(s: &v1::Study) -> String {
    let active = s.audits.iter().filter(|a| a.state == v1::StudyState::Active as i32).count();
    glissade_core::text::audits_cell(s.audits.len(), active)
}

pub(crate) async fn cancel(server: &Server, id: u64) -> Result<()> {
    let s = user(server)
        .await?
        .cancel_study(v1::CancelStudyRequest { study_id: id })
        .await
        .map_err(|s| refused(&format!("cancel {id}"), s))?
        .into_inner();
    let p = s.progress.unwrap_or_default();
    outln!(
        "study {id} {}: {} done, {} cancelled, {} still running",
        study_state_name(s.state),
        p.done,
        p.cancelled,
        p.leased
    );
    Ok(())
}

pub(crate) async fn purge_pool(server: &Server, pool: &str) -> Result<()> {
    let r = user(server)
        .await?
        .purge_pool(v1::PurgePoolRequest { pool_id: pool.to_owned() })
        .await
        .map_err(|s| refused(&format!("purge-pool {pool}"), s))?
        .into_inner();
    outln!("purged {} stored solutions of pool {pool}", r.purged);
    Ok(())
}

pub(crate) async fn retry(server: &Server, id: u64) -> Result<()> {
    let r = user(server)
        .await?
        .retry_failed(v1::RetryFailedRequest { study_id: id })
        .await
        .map_err(|s| refused(&format!("retry {id}"), s))?
        .into_inner();
    outln!("study {id}: {} failed points back in the queue", r.requeued);
    if r.kept > 0 {
        outln!("{} failed points kept: their failure can only repeat ({})", r.kept, r.kept_because);
    }
    Ok(())
}
