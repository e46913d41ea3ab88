//! The coordinator's read-only web page and JSON API, served on its gRPC port (HTTP/1.1 beside
//! HTTP/2): the studies, each study with its progress and running points (updated while it runs),
//! its measured accuracy, a response surface per QoI drawn on the server as SVG (a colour map with
//! contour lines over two parameters, a curve over one; the value under the pointer; axes named
//! with the scene's units), its points, and downloads. Nothing is fetched from elsewhere: the
//! page's only script is inline and asks this server's `/api/studies/ID` for progress.
//!
//! When the coordinator has tokens, every request needs the user token: `Authorization: Bearer
//! TOKEN`, or `?token=TOKEN` for a browser.
//!
//! JSON: `/api/studies`, `/api/studies/ID` (with points, and the running points with the
//! iterations and eta their pools last reported), `/api/studies/ID/surface` (every QoI of every
//! point); CSV: `/api/studies/ID/surface.csv`.

use std::collections::{BTreeMap, HashMap};
use std::fmt::Write as _;
use std::sync::Arc;

use axum::extract::{Path, Query, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{Html, IntoResponse, Response};
use axum::routing::get;
use glissade_proto::auth::Token;
use glissade_proto::{ParameterVector, StudyId};
use serde_json::json;

use crate::auth::Tokens;
use crate::coordinator::{CoordError, Coordinator, StudyState, StudyView, SurfaceSource, point_state_word, state_word};
use crate::records::{PointRecord, PointState};

#[derive(Clone)]
struct Web {
    coordinator: Arc<Coordinator>,
    token: Option<Token>,
}

/// The routes of the page and the API.
pub fn router(coordinator: Arc<Coordinator>, tokens: Option<&Tokens>) -> axum::Router {
    let web = Web { coordinator, token: tokens.map(|t| t.user.clone()) };
    axum::Router::new()
        .route("/", get(index))
        .route("/studies/{id}", get(study_page))
        .route("/api/studies", get(api_studies))
        .route("/api/studies/{id}", get(api_study))
        .route("/api/studies/{id}/surface", get(api_surface))
        .route("/api/studies/{id}/surface.csv", get(api_surface_csv))
        .with_state(web)
}

type Params = Query<HashMap<String, String>>;

/// Why a request gets no page: a status and one line of text.
struct Refusal(StatusCode, String);

impl IntoResponse for Refusal {
    fn into_response(self) -> Response {
        (self.0, [(header::CONTENT_TYPE, "text/plain; charset=utf-8")], format!("{}\n", self.1)).into_response()
    }
}

fn refuse(status: StatusCode, message: &str) -> Refusal {
    Refusal(status, message.to_owned())
}

/// The user token, when the coordinator asks for one.
fn check(web: &Web, headers: &HeaderMap, params: &HashMap<String, String>) -> Result<(), Refusal> {
    let Some(token) = &web.token else { return Ok(()) };
    let presented = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.strip_prefix("Bearer "))
        .or(params.get("token").map(String::as_str));
    match presented {
        Some(p) if token.matches(p) => Ok(()),
        Some(_) => Err(refuse(StatusCode::UNAUTHORIZED, "wrong user token")),
        None => Err(refuse(
            StatusCode::UNAUTHORIZED,
            "this coordinator needs the user token (?token=... or Authorization: Bearer ...)",
        )),
    }
}

fn failed(e: CoordError) -> Refusal {
    match e {
        CoordError::UnknownStudy(_) => refuse(StatusCode::NOT_FOUND, &e.to_string()),
        e => refuse(StatusCode::INTERNAL_SERVER_ERROR, &glissade_core::text::one_line(&e.to_string())),
    }
}

/// The study's id from the path, then the study.
fn study(web: &Web, id: &str, points: bool) -> Result<StudyView, Refusal> {
    let id: u64 = id
        .parse()
        .map_err(|_| refuse(StatusCode::NOT_FOUND, &format!("no study `{}`", glissade_core::text::excerpt(id, 40))))?;
    web.coordinator.study(StudyId(id), points).map_err(failed)
}

fn study_json(v: &StudyView) -> serde_json::Value {
    let p = v.progress;
    let r = &v.record;
    json!({
        "study_id": r.id.0,
        "label": r.label,
        "state": state_word(v.state),
        "tolerance": r.tolerance,
        "parameters": r.parameters,
        "strategy": r.strategy.name(),
        "audit_of": r.audit_of.map(|s| s.0),
        "progress": {"total": p.total, "pending": p.pending, "leased": p.leased, "done": p.done,
                     "failed": p.failed, "cancelled": p.cancelled, "iterations": p.iterations},
        "accuracy": v.accuracy.as_ref().map(|a| json!({
            "audit_study_id": a.audit_study.0, "tolerance": a.tolerance, "audited": a.audited, "planned": a.planned,
            "qoi": a.qoi.iter().map(|(q, (l, m))| (q.clone(), json!({"largest": l, "mean": m}))).collect::<serde_json::Map<_, _>>(),
        })),
        "points": v.points.iter().map(point_json).collect::<Vec<_>>(),
        "running": v.points.iter().filter_map(|p| match &p.state {
            PointState::Leased { pool, .. } => {
                let solving = v.solving.get(&p.id);
                Some(json!({
                    "point_id": p.id.0, "parameters": BTreeMap::from(p.parameters.clone()), "pool": pool,
                    "iterations": solving.map(|s| s.0), "eta": solving.map(|s| s.1),
                }))
            }
            _ => None,
        }).collect::<Vec<_>>(),
    })
}

fn point_json(p: &PointRecord) -> serde_json::Value {
    let r = p.result.as_ref();
    json!({
        "point_id": p.id.0,
        "parameters": BTreeMap::from(p.parameters.clone()),
        "state": point_state_word(&p.state),
        "iterations": r.map(|r| r.iterations),
        "error_indicator": r.map(|r| r.error_indicator),
        "work": r.map(|r| r.work),
        "started_from": r.and_then(|r| r.started_from.as_ref()).map(|o| BTreeMap::from(o.parameters.clone())),
        "qoi": r.map(|r| r.qoi.clone()).unwrap_or_default(),
    })
}

async fn api_studies(State(web): State<Web>, headers: HeaderMap, Query(q): Params) -> Response {
    if let Err(r) = check(&web, &headers, &q) {
        return r.into_response();
    }
    let list: Vec<serde_json::Value> = web.coordinator.studies().iter().map(study_json).collect();
    axum::Json(list).into_response()
}

async fn api_study(State(web): State<Web>, Path(id): Path<String>, headers: HeaderMap, Query(q): Params) -> Response {
    if let Err(r) = check(&web, &headers, &q) {
        return r.into_response();
    }
    match study(&web, &id, true) {
        Ok(v) => axum::Json(study_json(&v)).into_response(),
        Err(r) => r.into_response(),
    }
}

async fn api_surface(State(web): State<Web>, Path(id): Path<String>, headers: HeaderMap, Query(q): Params) -> Response {
    if let Err(r) = check(&web, &headers, &q) {
        return r.into_response();
    }
    match surface(&web, &id) {
        Ok(s) => axum::Json(json!({
            "parameters": s.parameters,
            "qoi": s.qoi,
            "points": s.rows.iter().map(|r| json!({
                "parameters": BTreeMap::from(r.parameters.clone()), "qoi": r.qoi, "state": point_state_word(&r.state),
            })).collect::<Vec<_>>(),
        }))
        .into_response(),
        Err(r) => r.into_response(),
    }
}

async fn api_surface_csv(
    State(web): State<Web>,
    Path(id): Path<String>,
    headers: HeaderMap,
    Query(q): Params,
) -> Response {
    if let Err(r) = check(&web, &headers, &q) {
        return r.into_response();
    }
    let s = match surface(&web, &id) {
        Ok(s) => s,
        Err(r) => return r.into_response(),
    };
    let mut out = s.parameters.iter().chain(&s.qoi).cloned().collect::<Vec<_>>().join(",") + ",state\n";
    for r in &s.rows {
        let mut fields: Vec<String> =
            s.parameters.iter().map(|n| r.parameters.get(n).map_or(String::new(), |v| v.to_string())).collect();
        fields.extend(s.qoi.iter().map(|q| r.qoi.get(q).map_or(String::new(), |v| format!("{v:e}"))));
        fields.push(point_state_word(&r.state).to_owned());
        out += &(fields.join(",") + "\n");
    }
    ([(header::CONTENT_TYPE, "text/csv; charset=utf-8")], out).into_response()
}

fn surface(web: &Web, id: &str) -> Result<crate::coordinator::Surface, Refusal> {
    let v = study(web, id, false)?;
    web.coordinator.surface(SurfaceSource::Study(v.record.id), &ParameterVector::default(), &[], &[]).map_err(failed)
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

const STYLE: &str = "body{font-family:sans-serif;margin:2em;color:#222}table{border-collapse:collapse}\
td,th{padding:2px 8px;border-bottom:1px solid #ddd;text-align:right}th{cursor:pointer}\
.surface{display:inline-block;margin:0 2em 2em 0}.cell:hover{stroke:#000}";

fn page(title: &str, body: &str) -> Html<String> {
    Html(format!(
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>{t}</title><style>{STYLE}</style></head>\
         <body><h1>{t}</h1>{body}</body></html>",
        t = escape(title)
    ))
}

fn with_token(path: &str, q: &HashMap<String, String>) -> String {
    match q.get("token") {
        Some(t) => format!("{path}?token={}", escape(t)),
        None => path.to_owned(),
    }
}

async fn index(State(web): State<Web>, headers: HeaderMap, Query(q): Params) -> Response {
    if let Err(r) = check(&web, &headers, &q) {
        return r.into_response();
    }
    let mut rows = String::new();
    for v in web.coordinator.studies() {
        let p = v.progress;
        // mean work of the points solved cold and warm (answered ones aside)
        let full = web.coordinator.study(v.record.id, true).map(|f| f.points).unwrap_or_default();
        let mean = |warm: bool| {
            let w: Vec<f64> = full
                .iter()
                .filter_map(|p| p.result.as_ref())
                .filter(|r| !r.answered && r.converged && r.started_from.is_some() == warm)
                .map(|r| r.work)
                .collect();
            if w.is_empty() { "-".to_owned() } else { format!("{:.1}", w.iter().sum::<f64>() / w.len() as f64) }
        };
        let _ = write!(
            rows,
            "<tr><td><a href=\"{}\">{}</a></td><td>{}</td><td>{}</td><td>{} / {}</td><td>{}</td><td>{}</td><td>{:.1e}</td><td>{}</td><td>{}</td></tr>",
            with_token(&format!("/studies/{}", v.record.id.0), &q),
            v.record.id.0,
            escape(&v.record.label),
            state_word(v.state),
            p.done,
            p.total,
            p.leased,
            p.pending,
            v.record.tolerance,
            mean(false),
            mean(true)
        );
    }
    let body = format!(
        "<table id=\"studies\"><tr><th>study</th><th>label</th><th>state</th><th>done</th><th>running</th><th>pending</th><th>tolerance</th><th>work cold</th><th>work warm</th></tr>{rows}</table>\
         <p>work: dynamic iterations + static iterations / time steps, mean per point solved</p>\
         <p>JSON: <a href=\"{}\">/api/studies</a></p>",
        with_token("/api/studies", &q)
    );
    page("glissade studies", &body).into_response()
}

/// A colour on a blue-to-yellow scale for `t` in [0, 1].
fn colour(t: f64) -> String {
    let t = if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.0 };
    format!("hsl({:.0},70%,{:.0}%)", 240.0 - 180.0 * t, 35.0 + 30.0 * t)
}

/// `name (unit)`, or the name alone when the scene gives it no unit.
fn named(name: &str, units: &BTreeMap<String, String>) -> String {
    match units.get(name) {
        Some(u) => format!("{name} ({u})"),
        None => name.to_owned(),
    }
}

/// The SVG of one QoI over the done points: a colour map of cells over two parameters with
/// labelled contour lines, a curve over one. Each cell or dot carries its value (the tooltip
/// under the pointer). `units` (the scene's, by name) label the axes.
pub fn surface_svg(
    parameters: &[String],
    qoi: &str,
    points: &[(Vec<f64>, f64)],
    units: &BTreeMap<String, String>,
) -> String {
    let (w, h, m) = (420.0, 320.0, 40.0);
    let mut svg = format!(
        "<svg class=\"surface\" data-qoi=\"{q}\" width=\"{w}\" height=\"{h}\" xmlns=\"http://www.w3.org/2000/svg\"><text x=\"{m}\" y=\"16\">{t}</text>",
        q = escape(qoi),
        t = escape(&named(qoi, units))
    );
    if points.is_empty() {
        return svg + "<text x=\"40\" y=\"60\">no point done yet</text></svg>";
    }
    let range = |k: usize| {
        let lo = points.iter().map(|p| p.0[k]).fold(f64::INFINITY, f64::min);
        let hi = points.iter().map(|p| p.0[k]).fold(f64::NEG_INFINITY, f64::max);
        (lo, if hi > lo { hi } else { lo + 1.0 })
    };
    let (vlo, vhi) = {
        let lo = points.iter().map(|p| p.1).fold(f64::INFINITY, f64::min);
        let hi = points.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max);
        (lo, if hi > lo { hi } else { lo + 1.0 })
    };
    let label = |x: &[f64]| parameters.iter().zip(x).map(|(n, v)| format!("{n}={v}")).collect::<Vec<_>>().join(" ");
    if parameters.len() >= 2 {
        let ((x0, x1), (y0, y1)) = (range(0), range(1));
        let distinct = |k: usize| {
            let mut v: Vec<f64> = points.iter().map(|p| p.0[k]).collect();
            v.sort_by(f64::total_cmp);
            v.dedup();
            v
        };
        let (xs, ys) = (distinct(0), distinct(1));
        let (cw, ch) = ((w - 2.0 * m) / xs.len() as f64, (h - 2.0 * m) / ys.len() as f64);
        // the top left corner of a cell
        let px = |x: f64| m + (x - x0) / (x1 - x0) * (w - 2.0 * m - cw);
        let py = |y: f64| h - m - ch - (y - y0) / (y1 - y0) * (h - 2.0 * m - ch);
        for (x, v) in points {
            let _ = write!(
                svg,
                "<rect class=\"cell\" x=\"{:.1}\" y=\"{:.1}\" width=\"{cw:.1}\" height=\"{ch:.1}\" fill=\"{}\" data-value=\"{v:e}\"><title>{} {qoi} = {v:.4e}</title></rect>",
                px(x[0]),
                py(x[1]),
                colour((v - vlo) / (vhi - vlo)),
                label(x),
                qoi = escape(qoi)
            );
        }
        // contours through the cells' centres, at 4 levels evenly between the extremes
        let mut grid = vec![None; xs.len() * ys.len()];
        for (x, v) in points {
            let (i, j) = (xs.partition_point(|a| *a < x[0]), ys.partition_point(|b| *b < x[1]));
            grid[j * xs.len() + i] = Some(*v);
        }
        let centre = |i: usize, j: usize| (px(xs[i]) + cw / 2.0, py(ys[j]) + ch / 2.0);
        for k in 1..=4 {
            let level = vlo + (vhi - vlo) * k as f64 / 5.0;
            let segments = contour(&grid, xs.len(), level, centre);
            if segments.is_empty() {
                continue;
            }
            // neighbouring levels labelled on different segments: close lines' labels do not overlap
            let ((ax, ay), (bx, by)) = segments[(segments.len() / 2 + k) % segments.len()];
            let d: String =
                segments.iter().map(|((ax, ay), (bx, by))| format!("M{ax:.1} {ay:.1}L{bx:.1} {by:.1}")).collect();
            let _ = write!(
                svg,
                "<path class=\"contour\" data-level=\"{level:e}\" d=\"{d}\" fill=\"none\" stroke=\"#000\" stroke-width=\"0.8\" pointer-events=\"none\"/>\
                 <text class=\"contour-label\" x=\"{:.1}\" y=\"{:.1}\" font-size=\"10\" stroke=\"#fff\" stroke-width=\"2\" paint-order=\"stroke\" pointer-events=\"none\">{level:.2e}</text>",
                (ax + bx) / 2.0,
                (ay + by) / 2.0
            );
        }
        let _ = write!(
            svg,
            "<text x=\"{m}\" y=\"{}\">{} →</text><text x=\"4\" y=\"{}\">↑ {}</text>",
            h - 8.0,
            escape(&named(&parameters[0], units)),
            m - 4.0,
            escape(&named(&parameters[1], units))
        );
    } else {
        let (x0, x1) = range(0);
        let mut sorted: Vec<&(Vec<f64>, f64)> = points.iter().collect();
        sorted.sort_by(|a, b| a.0[0].total_cmp(&b.0[0]));
        let xy = |x: f64, v: f64| {
            (m + (x - x0) / (x1 - x0) * (w - 2.0 * m), h - m - (v - vlo) / (vhi - vlo) * (h - 2.0 * m))
        };
        let line: Vec<String> = sorted
            .iter()
            .map(|(x, v)| {
                let (px, py) = xy(x[0], *v);
                format!("{px:.1},{py:.1}")
            })
            .collect();
        let _ = write!(svg, "<polyline fill=\"none\" stroke=\"#36c\" points=\"{}\"/>", line.join(" "));
        for (x, v) in sorted {
            let (px, py) = xy(x[0], *v);
            let _ = write!(
                svg,
                "<circle class=\"cell\" cx=\"{px:.1}\" cy=\"{py:.1}\" r=\"4\" fill=\"#36c\" data-value=\"{v:e}\"><title>{} {qoi} = {v:.4e}</title></circle>",
                label(x),
                qoi = escape(qoi)
            );
        }
        if let Some(p) = parameters.first() {
            let _ = write!(svg, "<text x=\"{m}\" y=\"{}\">{} →</text>", h - 8.0, escape(&named(p, units)));
        }
    }
    let _ = write!(svg, "<text x=\"{}\" y=\"16\">{vlo:.3e} … {vhi:.3e}</text></svg>", w - 200.0);
    svg
}

type Vertex = (f64, f64);

/// Marching squares: the segments of the line where the value is `level`, over a grid of `nx`
/// columns (row-major, None where no point is done) whose node (i, j) is drawn at `at(i, j)`.
/// Each square's crossings are linear along its edges; a saddle is split by the square's mean.
fn contour(grid: &[Option<f64>], nx: usize, level: f64, at: impl Fn(usize, usize) -> Vertex) -> Vec<(Vertex, Vertex)> {
    let mut segments = Vec::new();
    let ny = grid.len().checked_div(nx).unwrap_or(0);
    for j in 0..ny.saturating_sub(1) {
        for i in 0..nx - 1 {
            // the square's corners in turn around it; edge k joins corner k to corner k + 1
            let nodes = [(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)];
            let Some(v) = nodes.iter().map(|&(a, b)| grid[b * nx + a]).collect::<Option<Vec<f64>>>() else { continue };
            let above = |x: f64| x >= level;
            let crossings: Vec<Vertex> = (0..4)
                .filter(|&k| above(v[k]) != above(v[(k + 1) % 4]))
                .map(|k| {
                    let (a, b) = (at(nodes[k].0, nodes[k].1), at(nodes[(k + 1) % 4].0, nodes[(k + 1) % 4].1));
                    let t = (level - v[k]) / (v[(k + 1) % 4] - v[k]);
                    (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1))
                })
                .collect();
            match crossings[..] {
                [p, q] => segments.push((p, q)),
                // a saddle: if the middle is on corner 0's side, corners 1 and 3 are cut off
                [p0, p1, p2, p3] if above(v.iter().sum::<f64>() / 4.0) == above(v[0]) => {
                    segments.extend([(p0, p1), (p2, p3)])
                }
                [p0, p1, p2, p3] => segments.extend([(p3, p0), (p1, p2)]),
                _ => {}
            }
        }
    }
    segments
}

/// Eta against the iterations of every point solved (log scale), as the paper's Figures 7 and 8.
pub fn convergence_svg(histories: &[Vec<f64>]) -> String {
    let (w, h, m) = (420.0, 320.0, 40.0);
    let mut svg = format!(
        "<svg class=\"convergence\" width=\"{w}\" height=\"{h}\" xmlns=\"http://www.w3.org/2000/svg\"><text x=\"{m}\" y=\"16\">eta against iterations</text>"
    );
    let values = histories.iter().flatten().filter(|v| **v > 0.0 && v.is_finite());
    let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v.log10()), b.max(v.log10())));
    let longest = histories.iter().map(Vec::len).max().unwrap_or(0);
    if longest < 2 || lo >= hi {
        return svg + "<text x=\"40\" y=\"60\">no history yet</text></svg>";
    }
    for history in histories.iter().filter(|h| h.len() >= 2) {
        let line: Vec<String> = history
            .iter()
            .enumerate()
            .filter(|(_, v)| **v > 0.0 && v.is_finite())
            .map(|(k, v)| {
                let x = m + k as f64 / (longest - 1) as f64 * (w - 2.0 * m);
                let y = h - m - (v.log10() - lo) / (hi - lo) * (h - 2.0 * m);
                format!("{x:.1},{y:.1}")
            })
            .collect();
        let _ = write!(
            svg,
            "<polyline class=\"history\" fill=\"none\" stroke=\"#36c\" stroke-opacity=\"0.5\" points=\"{}\"/>",
            line.join(" ")
        );
    }
    let _ = write!(
        svg,
        "<text x=\"{m}\" y=\"{}\">iterations (0 … {}) →</text><text x=\"{}\" y=\"16\">1e{lo:.0} … 1e{hi:.0}</text></svg>",
        h - 8.0,
        longest - 1,
        w - 140.0
    );
    svg
}

async fn study_page(State(web): State<Web>, Path(id): Path<String>, headers: HeaderMap, Query(q): Params) -> Response {
    if let Err(r) = check(&web, &headers, &q) {
        return r.into_response();
    }
    let v = match study(&web, &id, true) {
        Ok(v) => v,
        Err(r) => return r.into_response(),
    };
    let s = match surface(&web, &id) {
        Ok(s) => s,
        Err(r) => return r.into_response(),
    };
    let r = &v.record;
    let p = v.progress;
    // the units the scene gives its parameters and QoIs (it parsed when the study was submitted)
    let scene = glissade_core::scene::Scene::parse(&r.scene).ok();
    let units: BTreeMap<String, String> = r
        .parameters
        .iter()
        .chain(&s.qoi)
        .filter_map(|n| Some((n.clone(), scene.as_ref()?.unit(n)?.to_owned())))
        .collect();
    let mut body = format!(
        "<p id=\"progress\" data-state=\"{}\">{}: {} of {} done, {} running, {} pending, {} failed</p>\
         <p>tolerance {:.1e}, strategy {}, parameters {}</p>",
        state_word(v.state),
        state_word(v.state),
        p.done,
        p.total,
        p.leased,
        p.pending,
        p.failed,
        r.tolerance,
        r.strategy.name(),
        escape(&r.parameters.join(", "))
    );
    if let Some(a) = &v.accuracy {
        let errors: Vec<String> =
            a.qoi.iter().map(|(q, (l, m))| format!("{} largest {l:.1e} mean {m:.1e}", escape(q))).collect();
        let _ = write!(
            body,
            "<p id=\"accuracy\">measured accuracy: {} of {} points re-solved cold at {:.0e}: {}</p>",
            a.audited,
            a.planned,
            a.tolerance,
            errors.join(", ")
        );
    }
    // a slice: `?fix=NAME=VALUE` keeps the points at that value and draws the others' curve
    let fixed =
        q.get("fix").and_then(|f| f.split_once('=')).and_then(|(n, v)| Some((n.to_owned(), v.parse::<f64>().ok()?)));
    let free: Vec<String> =
        s.parameters.iter().filter(|n| fixed.as_ref().is_none_or(|(f, _)| f != *n)).cloned().collect();
    if let Some((name, value)) = &fixed {
        let _ = write!(
            body,
            "<p id=\"slice\">slice at {} = {value} (<a href=\"{}\">whole surface</a>)</p>",
            escape(name),
            with_token(&format!("/studies/{}", r.id.0), &q)
        );
    } else if let Some(last) = s.parameters.last().filter(|_| s.parameters.len() >= 2) {
        let first = s.rows.iter().find_map(|row| row.parameters.get(last));
        if let Some(v) = first {
            let mut link = with_token(&format!("/studies/{}", r.id.0), &q);
            link += if link.contains('?') { "&" } else { "?" };
            let _ = write!(
                body,
                "<p>slices: <a id=\"slice-link\" href=\"{link}fix={}={v}\">{} = {v}</a></p>",
                escape(last),
                escape(last)
            );
        }
    }
    for qoi in &s.qoi {
        let points: Vec<(Vec<f64>, f64)> = s
            .rows
            .iter()
            .filter(|row| {
                fixed.as_ref().is_none_or(|(n, v)| {
                    row.parameters.get(n).is_some_and(|x| (x - v).abs() <= 1e-9 * v.abs().max(1e-300))
                })
            })
            .filter_map(|row| {
                let x: Option<Vec<f64>> = free.iter().map(|n| row.parameters.get(n)).collect();
                Some((x?, *row.qoi.get(qoi)?))
            })
            .collect();
        body += &surface_svg(&free, qoi, &points, &units);
    }
    // the running points: the script fills this table from the JSON while the study runs
    if v.state == StudyState::Active {
        body += "<table id=\"running\"><caption>running points</caption><tr><th>point</th>";
        for n in &r.parameters {
            let _ = write!(body, "<th>{}</th>", escape(&named(n, &units)));
        }
        body += "<th>pool</th><th>iterations</th><th>eta</th></tr></table>";
    }
    let histories: Vec<Vec<f64>> =
        v.points.iter().filter_map(|p| p.result.as_ref().map(|r| r.eta_history.clone())).collect();
    body += &convergence_svg(&histories);
    let _ = write!(
        body,
        "<p>download: <a href=\"{}\">surface.csv</a>, <a href=\"{}\">study JSON</a></p>",
        with_token(&format!("/api/studies/{}/surface.csv", r.id.0), &q),
        with_token(&format!("/api/studies/{}", r.id.0), &q)
    );
    body += "<table id=\"points\"><tr><th>point</th>";
    for n in &r.parameters {
        let _ = write!(body, "<th>{}</th>", escape(&named(n, &units)));
    }
    body += "<th>state</th><th>iterations</th><th>eta</th>";
    for qoi in &s.qoi {
        let _ = write!(body, "<th>{}</th>", escape(&named(qoi, &units)));
    }
    body += "</tr>";
    for point in &v.points {
        let res = point.result.as_ref();
        let _ = write!(body, "<tr><td>{}</td>", point.id.0);
        for n in &r.parameters {
            let _ = write!(body, "<td>{}</td>", point.parameters.get(n).map_or(String::new(), |x| x.to_string()));
        }
        let _ = write!(
            body,
            "<td>{}</td><td>{}</td><td>{}</td>",
            point_state_word(&point.state),
            res.map_or(String::new(), |r| r.iterations.to_string()),
            res.map_or(String::new(), |r| format!("{:.2e}", r.error_indicator))
        );
        for qoi in &s.qoi {
            let _ = write!(
                body,
                "<td>{}</td>",
                res.and_then(|r| r.qoi.get(qoi)).map_or(String::new(), |x| format!("{x:.4e}"))
            );
        }
        body += "</tr>";
    }
    body += "</table>";
    // progress without reloading while the study runs; a sortable points table
    let _ = write!(
        body,
        "<script>\
         const api = {api:?};\
         async function poll() {{\
           const p = document.getElementById('progress');\
           if (p.dataset.state !== 'active') return;\
           try {{ const s = await (await fetch(api)).json(); const g = s.progress;\
             p.textContent = s.state + ': ' + g.done + ' of ' + g.total + ' done, ' + g.leased + ' running, ' + g.pending + ' pending, ' + g.failed + ' failed';\
             const t = document.getElementById('running');\
             if (t) {{ [...t.rows].slice(1).forEach(r => r.remove());\
               s.running.forEach(r => {{ const row = t.insertRow();\
                 [r.point_id, ...s.parameters.map(n => r.parameters[n]), r.pool, r.iterations ?? '', r.eta == null ? '' : r.eta.toExponential(2)]\
                   .forEach(x => row.insertCell().textContent = x); }}); }}\
             if (s.state !== 'active') location.reload(); else p.dataset.polled = (Number(p.dataset.polled || 0) + 1).toString();\
           }} catch (e) {{}}\
           setTimeout(poll, 1000);\
         }}\
         poll();\
         document.querySelectorAll('#points th').forEach((th, k) => th.onclick = () => {{\
           const t = document.getElementById('points'); const rows = [...t.rows].slice(1);\
           const key = r => {{ const x = r.cells[k].textContent; const n = parseFloat(x); return isNaN(n) ? x : n; }};\
           rows.sort((a, b) => key(a) < key(b) ? -1 : key(a) > key(b) ? 1 : 0).forEach(r => t.appendChild(r));\
         }});\
         </script>",
        api = with_token(&format!("/api/studies/{}", r.id.0), &q)
    );
    let title = if r.label.is_empty() { format!("study {}", r.id.0) } else { format!("study {}: {}", r.id.0, r.label) };
    page(&title, &body).into_response()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_11_by_11_study_draws_121_cells_and_one_parameter_a_curve() {
        let names = vec!["f1".to_owned(), "f2".to_owned()];
        let none = BTreeMap::new();
        let mut points = Vec::new();
        for i in 0..11 {
            for j in 0..11 {
                let (a, b) = (0.1 + 0.01 * i as f64, 0.1 + 0.01 * j as f64);
                points.push((vec![a, b], a * b));
            }
        }
        let svg = surface_svg(&names, "slip_A", &points, &none);
        assert_eq!(svg.matches("class=\"cell\"").count(), 121);
        assert!(svg.contains("<title>f1=0.1 f2=0.1 slip_A = 1.0000e-2</title>"), "the value under the pointer");
        // every cell inside the picture
        for part in svg.split("<rect class=\"cell\" x=\"").skip(1) {
            let x: f64 = part.split('"').next().unwrap().parse().unwrap();
            assert!((0.0..420.0).contains(&x), "{x}");
        }
        let curve = surface_svg(
            &names[..1],
            "slip_A",
            &points[..11].iter().map(|(x, v)| (vec![x[1]], *v)).collect::<Vec<_>>(),
            &none,
        );
        assert!(curve.contains("<polyline") && curve.matches("<circle class=\"cell\"").count() == 11);
        assert!(surface_svg(&names, "q", &[], &none).contains("no point done yet"));
        // names are escaped
        assert!(surface_svg(&names, "<b>", &points, &none).contains("&lt;b&gt;"));
    }

    /// The numbers of attribute `name` in every element of class `class`.
    fn attributes(svg: &str, class: &str, name: &str) -> Vec<String> {
        svg.split(&format!("class=\"{class}\""))
            .skip(1)
            .filter_map(|e| e.split(&format!(" {name}=\"")).nth(1)?.split('"').next().map(str::to_owned))
            .collect()
    }

    #[test]
    fn contour_lines_lie_where_the_surface_takes_their_level() {
        let names = vec!["a".to_owned(), "b".to_owned()];
        // v = a over an 11 x 11 grid: every contour is straight across, at its level's column
        let grid: Vec<(Vec<f64>, f64)> =
            (0..121).map(|k| (vec![0.1 * (k % 11) as f64, 0.1 * (k / 11) as f64], 0.1 * (k % 11) as f64)).collect();
        let svg = surface_svg(&names, "v", &grid, &BTreeMap::new());
        let levels = attributes(&svg, "contour", "data-level");
        assert_eq!(levels.len(), 4, "{svg}");
        assert_eq!(attributes(&svg, "contour-label", "x").len(), 4, "each labelled");
        // the centres of the columns where v = 0 and v = 1 (the first and last cells)
        let xs: Vec<f64> = attributes(&svg, "cell", "x").iter().map(|x| x.parse().unwrap()).collect();
        let cw: f64 = attributes(&svg, "cell", "width")[0].parse().unwrap();
        let (c0, c1) = (xs[0] + cw / 2.0, xs[10] + cw / 2.0);
        for (level, d) in levels.iter().zip(attributes(&svg, "contour", "d")) {
            let level: f64 = level.parse().unwrap();
            let vertices: Vec<(f64, f64)> = d
                .split(['M', 'L'])
                .filter(|p| !p.is_empty())
                .map(|p| p.split_once(' ').map(|(x, y)| (x.parse().unwrap(), y.parse().unwrap())).unwrap())
                .collect();
            assert_eq!(vertices.len(), 2 * 10, "a segment per row of squares: {d}");
            for (x, y) in vertices {
                assert!((x - (c0 + level * (c1 - c0))).abs() <= 0.06, "level {level}: x = {x}");
                assert!((40.0..280.0).contains(&y), "{y}");
            }
        }
        // a saddle, v = (a - 0.5)(b - 0.5): lines, none outside the picture
        let saddle: Vec<(Vec<f64>, f64)> = grid.iter().map(|(x, _)| (x.clone(), (x[0] - 0.5) * (x[1] - 0.5))).collect();
        let svg = surface_svg(&names, "v", &saddle, &BTreeMap::new());
        assert_eq!(attributes(&svg, "contour", "d").len(), 4, "{svg}");
        // a constant surface has no contour
        let flat: Vec<(Vec<f64>, f64)> = grid.iter().map(|(x, _)| (x.clone(), 2.0)).collect();
        assert!(!surface_svg(&names, "v", &flat, &BTreeMap::new()).contains("contour"));
    }

    #[test]
    fn the_axes_carry_the_scenes_names_and_units() {
        let names = vec!["pressure".to_owned(), "f1".to_owned()];
        let units = BTreeMap::from([("pressure".to_owned(), "Pa".to_owned()), ("slip_A".to_owned(), "m".to_owned())]);
        let points = vec![(vec![1e7, 0.1], 1e-5), (vec![2e7, 0.2], 2e-5)];
        let svg = surface_svg(&names, "slip_A", &points, &units);
        assert!(svg.contains(">slip_A (m)</text>"), "the title: {svg}");
        assert!(svg.contains(">pressure (Pa) →</text>"), "the x axis: {svg}");
        assert!(svg.contains(">↑ f1</text>"), "no unit, the name alone: {svg}");
        let curve = surface_svg(&names[..1], "slip_A", &[(vec![1e7], 1e-5), (vec![2e7], 2e-5)], &units);
        assert!(curve.contains(">pressure (Pa) →</text>") && curve.contains(">slip_A (m)</text>"), "{curve}");
    }

    #[test]
    fn the_convergence_plot_draws_a_line_per_point() {
        let histories = vec![vec![1.0, 0.1, 0.01], vec![0.5, 0.05], vec![]];
        let svg = convergence_svg(&histories);
        assert_eq!(svg.matches("class=\"history\"").count(), 2);
        assert!(convergence_svg(&[]).contains("no history yet"));
    }
}
