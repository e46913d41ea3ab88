//! `glissade show`: one study in words (or JSON): its state, its audits' figures and its points.

use anyhow::Result;
use glissade_cli::names::{describe_parameters, order_name, point_state_name, strategy_name, study_state_name};
use glissade_cli::outln;
use glissade_core::contact::ContactActivity;
use glissade_core::scene::Scene;
use glissade_core::text::percent;
use glissade_proto::v1;

use crate::{Server, get_study, user};

pub(crate) async fn show(server: &Server, study: u64, points: bool, json: bool) -> Result<()> {
    if json {
        // the study as GetStudy returned it, in the proto's JSON: as the web API serves it
        let s = get_study(&mut user(server).await?, "show", study, points, false).await?;
        outln!("{}", glissade_proto::json::to_string(&s));
        return Ok(());
    }
    // the points always: the work line and the failures come from them (the scene: the QoIs' units)
    let s = get_study(&mut user(server).await?, "show", study, true, true).await?;
    describe(&s);
    let p = s.progress.unwrap_or_default();
    outln!(
        "  progress  {} done, {} failed, {} running, {} pending{}; {} iterations in all",
        p.done,
        p.failed,
        p.leased,
        p.pending,
        if p.cancelled > 0 { format!(", {} cancelled", p.cancelled) } else { String::new() },
        p.iterations
    );
    work(&s);
    contact_warnings(&s);
    if !points {
        // why a point failed, without asking for every point
        for point in s.points.iter().filter(|x| x.state == v1::PointState::Failed as i32) {
            outln!("  failed    #{} {}: {}", point.point_id, describe_parameters(&point.parameters), point.error);
        }
        return Ok(());
    }
    point_lines(&s);
    Ok(())
}

/// `, its audits running (1 of 4 ended)` after a study's own state while an audit or a pilots'
/// level is active: a study whose points have ended is not finished with until they are.
pub(crate) fn audits_running(s: &v1::Study) -> String {
    let active = s.audits.iter().filter(|a| a.state == v1::StudyState::Active as i32).count();
    if active == 0 {
        return String::new();
    }
    let what = if s.audits.iter().all(|a| a.what == "pilot level") { "pilots' levels" } else { "audits" };
    format!(", its {what} running ({} of {} ended)", s.audits.len() - active, s.audits.len())
}

/// One line per audit of a study (its pilots' levels in one line): what, its id, its state and
/// progress, and why points were cancelled unsolved.
pub(crate) fn audit_lines(s: &v1::Study) -> Vec<String> {
    let mut lines = Vec::new();
    for a in s.audits.iter().filter(|a| a.what != "pilot level") {
        let p = a.progress.unwrap_or_default();
        let mut line = format!(
            "  audit     {} (study {}): {}, {} of {} re-solved",
            a.what,
            a.study_id,
            study_state_name(a.state),
            p.done,
            p.total
        );
        if p.failed > 0 {
            line.push_str(&format!(", {} failed", p.failed));
        }
        if p.cancelled > 0 {
            line.push_str(&format!(", {} cancelled: {}", p.cancelled, a.why_cancelled));
        }
        lines.push(line);
    }
    let levels: Vec<&v1::StudyAudit> = s.audits.iter().filter(|a| a.what == "pilot level").collect();
    if !levels.is_empty() {
        let ended = levels.iter().filter(|a| a.state != v1::StudyState::Active as i32).count();
        lines.push(format!(
            "  levels    {} pilots' levels (studies {}), {ended} ended",
            levels.len(),
            levels.iter().map(|a| a.study_id.to_string()).collect::<Vec<_>>().join(", ")
        ));
    }
    lines
}

/// What the study is, how it was asked, and what its audits measured.
fn describe(s: &v1::Study) {
    let p = s.progress.unwrap_or_default();
    outln!(
        "study {}{}: {}{}",
        s.study_id,
        if s.label.is_empty() { String::new() } else { format!(" ({})", s.label) },
        study_state_name(s.state),
        audits_running(s)
    );
    outln!(
        "  scene     {}{}",
        if s.scene_title.is_empty() { String::new() } else { format!("{}, ", s.scene_title) },
        s.scene_hash
    );
    outln!(
        "  kind      {}, submitted {}{}",
        s.kind,
        glissade_core::text::utc_minute(s.created_unix_ms),
        if s.finished_unix_ms > 0 {
            format!(
                ", finished {} (wall time {})",
                glissade_core::text::utc_minute(s.finished_unix_ms),
                glissade_core::text::wall_time((s.finished_unix_ms - s.created_unix_ms) as f64 / 1e3)
            )
        } else {
            String::new()
        }
    );
    outln!(
        "  sweep     {} ({} points), strategy {}, order {}",
        s.parameters.join(", "),
        p.total,
        strategy_name(s.strategy),
        order_name(s.order)
    );
    outln!("  tolerance {:.1e}, at most {} iterations", s.tolerance, s.max_iterations);
    if s.refines != 0 {
        let what = if s.refines_mesh { "the mesh h" } else { "the time step" };
        outln!("  refines   study {} (its points re-solved with {what} / {})", s.refines, s.refine_factor);
    } else if s.held_out {
        outln!(
            "  audits    study {} (points held out of its surface, solved cold at this tighter tolerance)",
            s.audit_of
        );
    } else if s.audit_of != 0 {
        outln!("  audits    study {} (its points re-solved cold at this tighter tolerance)", s.audit_of);
    }
    if s.pilot_of != 0 {
        outln!("  pilots    of study {} (one level of its pilots' ladders)", s.pilot_of);
    }
    for line in audit_lines(s) {
        outln!("{line}");
    }
    if let Some(t) = &s.to_accuracy {
        for line in to_accuracy_lines(t) {
            outln!("{line}");
        }
    }
    if let Some(t) = &s.target {
        outln!("  target    {}", target_line(t, s.surface_accuracy.as_ref()));
    }
    if let Some(a) = &s.accuracy {
        outln!("  accuracy  {}", accuracy_line(a));
    }
    if let Some(a) = &s.surface_accuracy {
        outln!("  surface   {}", surface_accuracy_line(a));
    }
    if let Some(d) = &s.discretisation {
        outln!("  dt error  {}", discretisation_line(d));
        if let Some(mesh) = mesh_line(d) {
            outln!("  h error   {mesh}");
        }
        for verdict in &s.verdicts {
            outln!("  verdict   {verdict}");
        }
    }
}

/// Cold against warm in work (dynamic iterations + static iterations / steps).
fn work(s: &v1::Study) {
    let mean = |warm: bool| {
        let w: Vec<f64> = s
            .points
            .iter()
            .filter(|x| x.state == v1::PointState::Done as i32 && !x.answered && x.started_from.is_some() == warm)
            .map(|x| x.work)
            .collect();
        (!w.is_empty())
            .then(|| glissade_core::study::WorkMean { work: w.iter().sum::<f64>() / w.len() as f64, points: w.len() })
    };
    let answered = s.points.iter().filter(|x| x.answered).count();
    let work = match (mean(false), mean(true)) {
        (Some(cold), Some(warm)) => Some(glissade_core::study::warm_against_cold(cold, warm)),
        (Some(m), None) | (None, Some(m)) => Some(format!(
            "{:.1} per point, every point solved {} ({} points)",
            m.work,
            if mean(false).is_some() { "cold" } else { "warm" },
            m.points
        )),
        (None, None) => None,
    };
    match work {
        Some(work) => outln!(
            "  work      {work}{} (work: dynamic iterations + static iterations / time steps)",
            if answered > 0 { format!("; {answered} answered from stored solutions") } else { String::new() }
        ),
        None if answered > 0 => outln!("  work      none: {answered} points answered from stored solutions"),
        None => {}
    }
}

/// The points whose sliding is ill-posed, then those whose slide chatters (docs/verification.md
/// 4d): no tolerance bounds how far their answers move as the mesh and the time step are
/// refined, and a user reading the surface should know which they are.
fn contact_warnings(s: &v1::Study) {
    flagged_points(s, "slide ill-posed", ContactActivity::warning);
    flagged_points(s, "chatter while they slide", ContactActivity::chatter_warning);
}

/// One warning line for the points one of whose contacts `warning` flags, and the first's words.
fn flagged_points(s: &v1::Study, what: &str, warning: fn(&ContactActivity) -> Option<String>) {
    let flagged: Vec<(&v1::PointStatus, String)> = s
        .points
        .iter()
        .filter_map(|p| {
            let w = p.contact.iter().find_map(|c| warning(&ContactActivity::try_from(c.clone()).ok()?))?;
            Some((p, w))
        })
        .collect();
    let Some((_, first)) = flagged.first() else { return };
    const LISTED: usize = 10;
    let listed: Vec<String> = flagged
        .iter()
        .take(LISTED)
        .map(|(p, _)| format!("#{} {}", p.point_id, describe_parameters(&p.parameters)))
        .collect();
    let more = if flagged.len() > LISTED { format!(" and {} more", flagged.len() - LISTED) } else { String::new() };
    outln!("  warning   {} of {} points {what}: {}{more}", flagged.len(), s.points.len(), listed.join(", "));
    outln!("            the first: {first}");
}

/// One line a point: its parameters, state, iterations, eta, QoIs and where it started from
/// (and a line for each contact that landed while it slid, or slid ill-posed).
fn point_lines(s: &v1::Study) {
    // QoIs below what the solves resolve read 0 (`--json` keeps them)
    let scene = Scene::parse(&s.scene).ok();
    let resolution = glissade_core::study::resolutions(s.tolerance, s.points.iter().map(|p| &p.qoi), |q| {
        Some(scene.as_ref()?.unit(q)?.to_owned())
    });
    let digits = glissade_core::text::qoi_digits(s.tolerance);
    for point in &s.points {
        let qoi: Vec<String> = point
            .qoi
            .iter()
            .map(|(k, &v)| {
                let unit = scene.as_ref().and_then(|s| s.unit(k)).map(|u| format!(" {u}")).unwrap_or_default();
                format!("{k}={}{unit}", glissade_core::text::qoi_value(v, digits, resolution[k]))
            })
            .collect();
        let from = match &point.started_from {
            _ if point.answered => "answered from a stored solution".to_owned(),
            Some(f) => format!("from {}", describe_parameters(&f.parameters)),
            None if point.state == v1::PointState::Done as i32 => "cold".to_owned(),
            None => String::new(),
        };
        outln!(
            "  #{:<4} {:<28} {:<9} {:>5} it  work {:>6.1}  eta {}  {}  {}{}",
            point.point_id,
            describe_parameters(&point.parameters),
            point_state_name(point.state),
            point.iterations,
            point.work,
            glissade_core::text::eta_of(point.error_indicator),
            qoi.join(" "),
            from,
            if point.error.is_empty() { String::new() } else { format!("  [{}]", point.error) }
        );
        let contact = point.contact.iter().filter_map(|c| ContactActivity::try_from(c.clone()).ok());
        for c in contact.filter(|c| c.landings_while_sliding > 0 || c.ill_posed) {
            let flag = if c.ill_posed {
                " (ILL-POSED: on a rigid wall above friction 1)"
            } else if c.chatters() {
                " (CHATTERS: the answer moves with the time step)"
            } else {
                ""
            };
            outln!("        {}{flag}", c.evidence());
        }
    }
}

/// `2 of 2 points re-solved cold at 1e-5 (study 2): slip_A largest 0.0310 % mean 0.0120 %, ...
/// (of each QoI's largest |value|)`
pub(crate) fn accuracy_line(a: &v1::StudyAccuracy) -> String {
    let errors: Vec<String> =
        a.qoi.iter().map(|(q, e)| format!("{q} largest {} mean {}", percent(e.largest), percent(e.mean))).collect();
    let errors = of_largest_value(errors);
    let cost = if a.work_cap > 0.0 {
        format!("; it cost {:.0} work of its cap {:.0}", a.work, a.work_cap)
    } else {
        String::new()
    };
    format!(
        "{} of {} points re-solved cold at {:.0e} (study {}){}{}{cost}",
        a.audited,
        a.planned,
        a.tolerance,
        a.audit_study_id,
        if errors.is_empty() { "" } else { ": " },
        errors.join(", ")
    )
}

/// A study to an accuracy: what was asked, what the pilots chose (or why nothing), and per QoI
/// the largest estimate over the pilots with its parts, as fractions of the QoI's scale.
pub(crate) fn to_accuracy_lines(t: &v1::StudyToAccuracy) -> Vec<String> {
    let mut lines = vec![format!(
        "  accuracy  asked {} of each QoI's scale (the largest magnitude of its history): tolerance {:.1e}, Newmark gamma {}",
        percent(t.accuracy),
        t.tolerance,
        if t.newmark_gamma > 0.0 { format!("{}", t.newmark_gamma) } else { "(pilots running)".into() }
    )];
    let levels = t.level_study_ids.iter().map(|id| id.to_string()).collect::<Vec<_>>().join(", ");
    let pilots = format!(
        "{} of {} pilots done (points {}; levels in studies {}), work {:.1}, {:.1} s",
        t.pilots_done,
        t.pilot_points.len(),
        t.pilot_points.iter().map(|p| p.to_string()).collect::<Vec<_>>().join(", "),
        if levels.is_empty() { "none yet".into() } else { levels },
        t.pilot_work,
        t.pilot_wall_seconds
    );
    lines.push(format!("  pilots    {pilots}"));
    if t.chosen {
        lines.push(format!(
            "  level     REACHED at dt / {}, h / {}: the study's points are solved there",
            t.time_factor, t.mesh_factor
        ));
    } else if !t.why_not.is_empty() {
        lines.push(format!("  level     NOT REACHED: {}", t.why_not));
    }
    for ((k, m), check) in t.above_time_factors.iter().zip(&t.above_mesh_factors).zip(&t.above_check_ids) {
        lines.push(format!(
            "  refined   ABOVE at dt / {k}, h / {m} (held-out check, study {check}): the points were solved again one level finer"
        ));
    }
    if t.held_out_study_id != 0 {
        let verdict = match t.confirmed {
            Some(true) => "CONFIRMED: every difference within half the accuracy".to_string(),
            Some(false) if t.held_out_failed > 0 => format!("NOT CONFIRMED: {} re-solves failed", t.held_out_failed),
            Some(false) => "ABOVE: a difference passes the accuracy".to_string(),
            None => "running once the study has ended".to_string(),
        };
        let differences: Vec<String> =
            t.held_out_difference.iter().map(|(name, d)| format!("{name} {}", percent(*d))).collect();
        lines.push(format!(
            "  held-out  {} of {} points re-solved at dt / {}, h / {} (study {}){}: {verdict}",
            t.held_out_done,
            t.held_out_planned,
            t.held_out_time_factor,
            t.held_out_mesh_factor,
            t.held_out_study_id,
            if differences.is_empty() {
                String::new()
            } else {
                format!(", largest difference {}", differences.join(", "))
            }
        ));
    }
    for (name, q) in &t.qoi {
        let mesh = if q.mesh >= 0.0 { percent(q.mesh) } else { "not estimated".into() };
        let parts = match q.joint {
            Some(j) => format!(
                "dt and h together {}, iterations {}; apart: time step {}, mesh {mesh}",
                percent(j),
                percent(q.iteration),
                percent(q.time)
            ),
            None => format!("time step {}, mesh {mesh}, iterations {}", percent(q.time), percent(q.iteration)),
        };
        lines.push(format!(
            "            {name}: {} ({parts}){}",
            percent(q.total),
            if q.within { "" } else { " ABOVE" }
        ));
    }
    lines
}

/// `7 of 7 held-out points (seed 1234) solved cold at 2e-6 (study 4) against the surface of 121 points:
/// slip_A largest 1.3e-1 mean 5.0e-3 within 2 sd 86 %, ...`; errors relative to each QoI's spread.
pub(crate) fn surface_accuracy_line(a: &v1::StudySurfaceAccuracy) -> String {
    let mut parts: Vec<String> = a
        .qoi
        .iter()
        .map(|(q, e)| {
            format!(
                "{q} largest {} mean {} of its spread, within 2 sd at {:.0} % of the points",
                percent(e.largest),
                percent(e.mean),
                e.within_2sd * 100.0
            )
        })
        .collect();
    parts.extend(
        a.refused
            .iter()
            .map(|(q, why)| format!("{} not predicted: {why}", if q.is_empty() { "the surface" } else { q })),
    );
    let cost = if a.work_cap > 0.0 {
        format!("; it cost {:.0} work of its cap {:.0}", a.work, a.work_cap)
    } else {
        String::new()
    };
    format!(
        "{} of {} held-out points (seed {}) solved cold at {:.0e} (study {}) against the surface of {} points{}{}{cost}",
        a.validated,
        a.planned,
        a.seed,
        a.tolerance,
        a.audit_study_id,
        a.fitted,
        if parts.is_empty() { "" } else { ": " },
        parts.join(", ")
    )
}

/// `surface accuracy 2.0e-2 (largest error / spread anywhere in the box, as the surface
/// estimates it): REACHED at 34 points (budget 100): slip_A largest in the box 1.9e-2 (at the
/// points 8.1e-3, mean 1.2e-3), ...`, then what the held-out points measured against the target
/// where they did.
pub(crate) fn target_line(t: &v1::StudyTarget, held: Option<&v1::StudySurfaceAccuracy>) -> String {
    let errors: Vec<String> = t
        .qoi
        .iter()
        .map(|(q, e)| {
            // (0: a coordinator that did not estimate it: the largest at the points)
            let judged = if e.box_largest > 0.0 { e.box_largest } else { e.largest };
            let above = if judged > t.surface_accuracy { " (ABOVE)" } else { "" };
            format!(
                "{q} largest in the box {}{above} (at the points {}, mean {})",
                percent(judged),
                percent(e.largest),
                percent(e.mean)
            )
        })
        .chain(t.refused.iter().map(|(q, why)| format!("{q} not fitted: {why}")))
        .collect();
    let budget = if t.work_budget > 0.0 {
        format!("{} points or work {:.0}", t.budget, t.work_budget)
    } else {
        t.budget.to_string()
    };
    let verdict = match t.outcome.as_str() {
        "reached" => format!("REACHED at {} points (budget {budget})", t.points),
        // a work budget stopped it where its points are fewer than their budget
        "budget" if t.work_budget > 0.0 && t.points < t.budget => format!(
            "NOT REACHED: the work budget of {:.0} was spent (work {:.0}); at {} points",
            t.work_budget, t.work, t.points
        ),
        "budget" => format!("NOT REACHED: the budget of {} points was spent; at {} points", t.budget, t.points),
        "set_aside" => format!(
            "NOT REACHED: {} set aside as no surface (below); the others within it at {} points (budget {budget})",
            t.refused.keys().cloned().collect::<Vec<_>>().join(", "),
            t.points
        ),
        _ => format!("not decided yet (budget {budget})"),
    };
    let mut line = format!(
        "surface accuracy {} (the largest error anywhere in the box, as the surface estimates it, of each QoI's spread): {verdict}{}{}",
        percent(t.surface_accuracy),
        if errors.is_empty() { "" } else { ": " },
        errors.join(", ")
    );
    if let Some(h) = held.filter(|h| h.validated > 0) {
        let above: Vec<String> = h
            .qoi
            .iter()
            .filter(|(_, e)| e.largest > t.surface_accuracy)
            .map(|(q, e)| format!("{q} {}", percent(e.largest)))
            .collect();
        line.push_str(&if above.is_empty() {
            format!("; the {} held-out points confirm it (every error within the target)", h.validated)
        } else {
            format!("; the {} held-out points measure errors ABOVE the target: {}", h.validated, above.join(", "))
        });
    }
    line
}

/// `2 of 2 points re-solved at dt / 2 (study 3; 4.1 s, 0.8 x the study's 5.0 s): slip_A change
/// 3.2e-2 error ~4.3e-2 (order 2 assumed), ...`
pub(crate) fn discretisation_line(d: &v1::StudyDiscretisation) -> String {
    let errors: Vec<String> = d
        .qoi
        .iter()
        .map(|(q, e)| {
            let how = if e.erratic > 0 {
                format!(" (ERRATIC at {} point(s): an event moves with the step; no extrapolation)", e.erratic)
            } else if e.below_tolerance {
                " (below the iterations' noise)".to_string()
            } else if e.order_assumed {
                " (order 2 assumed)".to_string()
            } else {
                format!(" (observed order {:.2})", e.order)
            };
            format!("{q} change {} error ~{}{how}", percent(e.change), percent(e.error))
        })
        .collect();
    let errors = of_largest_value(errors);
    let levels: Vec<String> = d.factors.iter().map(|f| format!("dt / {f}")).collect();
    let studies: Vec<String> = d.level_study_ids.iter().map(|s| s.to_string()).collect();
    format!(
        "{} of {} points re-solved at {} (study {}; {:.1} s, {:.2} x the study's {:.1} s){}{}",
        d.audited,
        d.planned,
        levels.join(" and "),
        studies.join(", "),
        d.work_seconds,
        if d.study_seconds > 0.0 { d.work_seconds / d.study_seconds } else { 0.0 },
        d.study_seconds,
        if errors.is_empty() { "" } else { ": " },
        errors.join(", ")
    )
}

/// Errors relative to each QoI's largest |value|, said once after the last.
fn of_largest_value(mut errors: Vec<String>) -> Vec<String> {
    if let Some(last) = errors.last_mut() {
        last.push_str(" (of each QoI's largest |value|)");
    }
    errors
}

/// The mesh level's line: per QoI the change at h / 2 and the estimated error (None: no mesh
/// level).
pub(crate) fn mesh_line(d: &v1::StudyDiscretisation) -> Option<String> {
    (d.mesh_study_id != 0).then_some(())?;
    let errors: Vec<String> = d
        .qoi
        .iter()
        .filter_map(|(q, e)| {
            let how = if e.mesh_below_tolerance { " (below the iterations' noise)" } else { " (order 2 assumed)" };
            Some(format!("{q} change {} error ~{}{how}", percent(e.mesh_change?), percent(e.mesh_error?)))
        })
        .collect();
    let errors = of_largest_value(errors);
    Some(format!(
        "{} of {} points re-solved cold at h / {} (study {}; {:.1} s, {:.2} x the study's {:.1} s){}{}",
        d.mesh_audited,
        d.planned,
        d.mesh_factor,
        d.mesh_study_id,
        d.mesh_work_seconds,
        if d.study_seconds > 0.0 { d.mesh_work_seconds / d.study_seconds } else { 0.0 },
        d.study_seconds,
        if errors.is_empty() { "" } else { ": " },
        errors.join(", ")
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A target's verdict names what stopped it: the points' budget, or the work budget when
    /// its points are fewer than their budget.
    #[test]
    fn a_target_line_names_the_budget_that_was_spent() {
        let target = |points: u32, work_budget: f64| v1::StudyTarget {
            surface_accuracy: 1e-3,
            budget: 60,
            outcome: "budget".into(),
            points,
            work_budget,
            work: 96.0,
            ..Default::default()
        };
        let line = target_line(&target(12, 100.0), None);
        assert!(line.contains("NOT REACHED: the work budget of 100 was spent (work 96); at 12 points"), "{line}");
        let line = target_line(&target(60, 0.0), None);
        assert!(line.contains("NOT REACHED: the budget of 60 points was spent; at 60 points"), "{line}");
        let line = target_line(&v1::StudyTarget { outcome: String::new(), ..target(0, 100.0) }, None);
        assert!(line.contains("not decided yet (budget 60 points or work 100)"), "{line}");
        // stopped with a force set aside: NOT REACHED, the others within, the reason beside
        let set_aside = v1::StudyTarget {
            outcome: "set_aside".into(),
            refused: [("normal_force".to_owned(), "set aside: interface 'floor' chatters".to_owned())].into(),
            ..target(31, 0.0)
        };
        let line = target_line(&set_aside, None);
        assert!(
            line.contains(
                "NOT REACHED: normal_force set aside as no surface (below); the others within it at 31 points"
            ) && line.contains("normal_force not fitted: set aside: interface 'floor' chatters"),
            "{line}"
        );
    }

    /// A study whose points have ended says that its audits still run, and each audit's line
    /// says what it is, how far it got and why points were cancelled; pilots' levels in one line.
    /// A level found ABOVE is named with its check, in `show`'s lines.
    #[test]
    fn a_level_found_above_is_named() {
        let t = v1::StudyToAccuracy {
            chosen: true,
            time_factor: 8,
            mesh_factor: 4,
            above_time_factors: vec![4],
            above_mesh_factors: vec![2],
            above_check_ids: vec![9],
            ..Default::default()
        };
        let lines = to_accuracy_lines(&t);
        assert!(lines.contains(&"  refined   ABOVE at dt / 4, h / 2 (held-out check, study 9): the points were solved again one level finer".to_string()), "{lines:?}");
    }

    /// A QoI read where dt and h were halved together says so: its total is that estimate and
    /// the iterations', the ladders apart shown beside, not added.
    #[test]
    fn an_estimate_read_on_the_diagonal_says_so() {
        let q = |joint: Option<f64>| v1::QoiToAccuracy {
            total: 0.0155,
            time: 0.0224,
            mesh: 0.013,
            joint,
            iteration: 0.005,
            within: true,
        };
        let t = v1::StudyToAccuracy {
            accuracy: 0.05,
            qoi: [("friction_force".to_owned(), q(Some(0.0105))), ("slip".to_owned(), q(None))].into(),
            ..Default::default()
        };
        let lines = to_accuracy_lines(&t);
        let line = |name: &str| lines.iter().find(|l| l.trim_start().starts_with(name)).cloned().unwrap_or_default();
        assert_eq!(
            line("friction_force").trim_start(),
            "friction_force: 1.55 % (dt and h together 1.05 %, iterations 0.500 %; apart: time step 2.24 %, mesh 1.30 %)"
        );
        assert_eq!(line("slip").trim_start(), "slip: 1.55 % (time step 2.24 %, mesh 1.30 %, iterations 0.500 %)");
        // in JSON, a QoI not read on the diagonal has no `joint`
        let json = glissade_proto::json::to_value(&t);
        assert_eq!(json["qoi"]["friction_force"]["joint"], serde_json::json!(0.0105));
        assert!(json["qoi"]["slip"].get("joint").is_none(), "{json}");
    }

    #[test]
    fn a_study_says_its_audits_are_running() {
        let audit = |id: u64, what: &str, state: v1::StudyState, done: u32, cancelled: u32, why: &str| v1::StudyAudit {
            study_id: id,
            what: what.into(),
            state: state.into(),
            progress: Some(v1::StudyProgress { total: 2, done, cancelled, ..Default::default() }),
            why_cancelled: why.into(),
        };
        let mut s = v1::Study {
            state: v1::StudyState::Done.into(),
            audits: vec![
                audit(2, "iteration", v1::StudyState::Done, 1, 1, "not re-solved: the audit spent its cost cap"),
                audit(3, "time step", v1::StudyState::Active, 0, 0, ""),
            ],
            ..Default::default()
        };
        assert_eq!(audits_running(&s), ", its audits running (1 of 2 ended)");
        let lines = audit_lines(&s);
        assert_eq!(
            lines,
            vec![
                "  audit     iteration (study 2): done, 1 of 2 re-solved, 1 cancelled: not re-solved: the audit spent its cost cap",
                "  audit     time step (study 3): active, 0 of 2 re-solved",
            ]
        );
        s.audits = vec![
            audit(4, "pilot level", v1::StudyState::Done, 2, 0, ""),
            audit(5, "pilot level", v1::StudyState::Active, 0, 0, ""),
        ];
        assert_eq!(audits_running(&s), ", its pilots' levels running (1 of 2 ended)");
        assert_eq!(audit_lines(&s), vec!["  levels    2 pilots' levels (studies 4, 5), 1 ended"]);
        s.audits.clear();
        assert_eq!((audits_running(&s), audit_lines(&s).len()), (String::new(), 0));
    }
}
