//! The coordinator's read-only web page and JSON API, served on its gRPC port (HTTP/1.1 beside
//! HTTP/2): the studies, each study with its progress and running points (updated while it runs),
//! its measured accuracy, a response surface per QoI drawn on the server as SVG (a colour map with
//! contour lines over two parameters, a curve over one; the value under the pointer; axes named
//! with the scene's units), its points, and downloads. Nothing is fetched from elsewhere.
//!
//! Every string a user gave (labels, parameter, QoI and unit names) reaches the page through
//! maud, which escapes by construction; the page's script and style are files of this server
//! (`/static/...`), and a Content-Security-Policy forbids any other, inline ones included.
//!
//! When the coordinator has tokens, every request needs the user token: `Authorization: Bearer
//! TOKEN`, or for a browser the HttpOnly cookie that the form at `/login` sets. A token never goes
//! in a URL (histories and logs keep URLs): `?token=` is refused.
//!
//! JSON: `/api/studies`, `/api/studies/ID` (with points, and the running points with the
//! iterations and eta their pools last reported), `/api/studies/ID/surface` (every QoI of every
//! point); CSV: `/api/studies/ID/surface.csv`; Prometheus text: `/metrics` (metrics.rs). Any
//! other path is 404.

use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;

use axum::extract::{Form, Path, Query, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Redirect, Response};
use axum::routing::get;
use glissade_proto::auth::Token;
use glissade_proto::{ParameterVector, StudyId};
use maud::{DOCTYPE, Markup, html};
use serde_json::json;

use crate::auth::Tokens;
use crate::coordinator::{
    AUDIT_WORK_FRACTION, CoordError, Coordinator, StudyState, StudyView, SurfaceSource, point_state_word, state_word,
};
use crate::metrics::{self, Metrics};
use crate::records::{PointRecord, PointState};
use glissade_core::study::shown;
use glissade_core::text::{parameter, same_parameter, utc_minute, wall_time};

#[derive(Clone)]
struct Web {
    coordinator: Arc<Coordinator>,
    metrics: Arc<Metrics>,
    token: Option<Token>,
    /// the login cookie is `Secure` (sent over https only) when the coordinator serves TLS
    secure_cookie: bool,
}

/// The cookie that carries the user token (hex-encoded: any printable token fits a cookie).
const COOKIE: &str = "glissade_token";

/// No script, style, image, frame or form target but this server's own: an injected inline
/// script would not run even if a string escaped the templates.
const CSP: &str = "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self'; connect-src 'self'; \
                   form-action 'self'; frame-ancestors 'none'; base-uri 'none'";

/// The routes of the page and the API; every answer carries [`CSP`], and any other path is 404.
pub fn router(
    coordinator: Arc<Coordinator>,
    metrics: Arc<Metrics>,
    tokens: Option<&Tokens>,
    secure_cookie: bool,
) -> axum::Router {
    let web = Web { coordinator, metrics, token: tokens.map(|t| t.user.clone()), secure_cookie };
    axum::Router::new()
        .route("/", get(index))
        .route("/login", get(login_form).post(login))
        .route("/static/study.js", get(|| async { ([(header::CONTENT_TYPE, "text/javascript")], STUDY_JS) }))
        .route("/static/style.css", get(|| async { ([(header::CONTENT_TYPE, "text/css")], STYLE) }))
        .route("/studies/{id}", get(study_page))
        .route("/api/studies", get(api_studies))
        .route("/api/studies/{id}", get(api_study))
        .route("/api/studies/{id}/surface", get(api_surface))
        .route("/api/studies/{id}/surface.csv", get(api_surface_csv))
        .route("/metrics", get(metrics_text))
        .route_layer(axum::middleware::from_fn(metrics::keep_route))
        .with_state(web)
        .layer(axum::middleware::map_response(|mut r: Response| async move {
            let h = r.headers_mut();
            h.insert(header::CONTENT_SECURITY_POLICY, HeaderValue::from_static(CSP));
            h.insert(header::X_CONTENT_TYPE_OPTIONS, HeaderValue::from_static("nosniff"));
            r
        }))
}

/// Whether a request is a gRPC call (the rest is HTTP for the page, the API and /metrics).
pub fn is_grpc(headers: &HeaderMap) -> bool {
    headers.get(header::CONTENT_TYPE).is_some_and(|v| v.as_bytes().starts_with(b"application/grpc"))
}

/// What a path the gRPC services and the web page do not know answers (tonic's default is a
/// gRPC UNIMPLEMENTED inside HTTP 200): 404 for a browser or curl, UNIMPLEMENTED for gRPC.
pub async fn not_found(request: axum::extract::Request) -> Response {
    if is_grpc(request.headers()) {
        return tonic::Status::unimplemented(format!("no gRPC method {}", request.uri().path())).into_http();
    }
    refuse(StatusCode::NOT_FOUND, "no such page (try /)").into_response()
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

/// The value of cookie `name` in the request's `Cookie` headers.
fn cookie<'h>(headers: &'h HeaderMap, name: &str) -> Option<&'h str> {
    headers
        .get_all(header::COOKIE)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(';'))
        .find_map(|pair| pair.trim().strip_prefix(name)?.strip_prefix('='))
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn unhex(text: &str) -> Option<String> {
    let bytes: Option<Vec<u8>> =
        (0..text.len()).step_by(2).map(|i| text.get(i..i + 2).and_then(|b| u8::from_str_radix(b, 16).ok())).collect();
    String::from_utf8(bytes?).ok()
}

/// The user token, when the coordinator asks for one: from `Authorization: Bearer` or the login
/// cookie. A token in the URL is refused whether or not it is right.
fn check(web: &Web, headers: &HeaderMap, params: &HashMap<String, String>) -> Result<(), Refusal> {
    if params.contains_key("token") {
        return Err(refuse(
            StatusCode::BAD_REQUEST,
            "a token does not go in a URL (browsers and proxies keep URLs): log in at /login, or send Authorization: Bearer ...",
        ));
    }
    let Some(token) = &web.token else { return Ok(()) };
    let bearer = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.strip_prefix("Bearer "))
        .map(str::to_owned);
    match bearer.or_else(|| cookie(headers, COOKIE).and_then(unhex)) {
        Some(p) if token.matches(&p) => Ok(()),
        Some(_) => Err(refuse(StatusCode::UNAUTHORIZED, "wrong user token (log in again at /login)")),
        None => Err(refuse(
            StatusCode::UNAUTHORIZED,
            "this coordinator needs the user token: log in at /login, or send Authorization: Bearer ...",
        )),
    }
}

/// A page's refusal: the login form when the token is missing or wrong, else the text.
fn page_refusal(r: Refusal) -> Response {
    if r.0 == StatusCode::UNAUTHORIZED {
        return (r.0, login_page(Some(&r.1))).into_response();
    }
    r.into_response()
}

fn login_page(message: Option<&str>) -> Markup {
    page(
        "glissade: log in",
        html! {
            @if let Some(m) = message { p #message { (m) } }
            form method="post" action="/login" {
                label { "user token " input type="password" name="token" autocomplete="current-password"; }
                " " button type="submit" { "log in" }
            }
            p { "The token is kept in a cookie that scripts cannot read, for this browser session." }
        },
    )
}

async fn login_form() -> Markup {
    login_page(None)
}

#[derive(serde::Deserialize)]
struct Login {
    token: String,
}

/// The login form's answer: the cookie and a redirect to the studies, or the form again.
async fn login(State(web): State<Web>, Form(login): Form<Login>) -> Response {
    if web.token.as_ref().is_some_and(|t| !t.matches(&login.token)) {
        return (StatusCode::UNAUTHORIZED, login_page(Some("wrong user token"))).into_response();
    }
    let secure = if web.secure_cookie { "; Secure" } else { "" };
    let cookie = format!("{COOKIE}={}; HttpOnly; SameSite=Strict; Path=/{secure}", hex(login.token.as_bytes()));
    match HeaderValue::from_str(&cookie) {
        Ok(value) => ([(header::SET_COOKIE, value)], Redirect::to("/")).into_response(),
        Err(_) => refuse(StatusCode::BAD_REQUEST, "a token is printable characters").into_response(),
    }
}

/// `/metrics` for Prometheus, behind the user token as every page is (Prometheus sends it as
/// `Authorization: Bearer`: its scrape config's `authorization.credentials_file`).
async fn metrics_text(State(web): State<Web>, headers: HeaderMap, Query(params): Params) -> Response {
    if let Err(r) = check(&web, &headers, &params) {
        return r.into_response();
    }
    // counting walks every point under the coordinator's lock: off the async threads
    match tokio::task::spawn_blocking(move || web.metrics.render()).await {
        Ok(text) => ([(header::CONTENT_TYPE, metrics::CONTENT_TYPE)], text).into_response(),
        Err(e) => refuse(StatusCode::INTERNAL_SERVER_ERROR, &format!("rendering the metrics: {e}")).into_response(),
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
        "kind": v.kind,
        "scene_title": v.scene_title,
        "created_unix_ms": r.created_unix_ms,
        "finished_unix_ms": v.finished_unix_ms,
        "progress": {"total": p.total, "pending": p.pending, "leased": p.leased, "done": p.done,
                     "failed": p.failed, "cancelled": p.cancelled, "iterations": p.iterations},
        "accuracy": v.accuracy.as_ref().map(|a| json!({
            "audit_study_id": a.audit_study.0, "tolerance": a.tolerance, "audited": a.audited, "planned": a.planned,
            "work": a.work, "work_cap": a.work_cap,
            "qoi": a.qoi.iter().map(|(q, (l, m))| (q.clone(), json!({"largest": l, "mean": m}))).collect::<serde_json::Map<_, _>>(),
        })),
        "refines": r.refines.map(|x| json!({"study_id": x.study.0, "factor": x.factor, "refinement": x.refinement})),
        "held_out": r.held_out.is_some(),
        "surface_accuracy": v.surface_accuracy.as_ref().map(|a| json!({
            "audit_study_id": a.audit_study.0, "tolerance": a.tolerance, "validated": a.validated,
            "planned": a.planned, "fitted": a.fitted, "work": a.work, "work_cap": a.work_cap, "refused": a.refused,
            "qoi": a.qoi.iter().map(|(q, e)| (q.clone(), json!({
                "largest": e.largest, "mean": e.mean, "within_2sd": e.within_2sd, "points": e.count,
            }))).collect::<serde_json::Map<_, _>>(),
        })),
        "discretisation": v.discretisation.as_ref().map(|d| json!({
            "level_study_ids": d.levels.iter().map(|(s, _)| s.0).collect::<Vec<_>>(),
            "factors": d.levels.iter().map(|(_, f)| f).collect::<Vec<_>>(),
            "audited": d.audited, "planned": d.planned,
            "work_seconds": d.work_seconds, "study_seconds": d.study_seconds,
            "qoi": d.qoi.iter().map(|(q, e)| (q.clone(), json!({
                "change": e.change, "error": e.error, "order": e.order, "order_assumed": e.order_assumed,
                "erratic": e.erratic, "below_tolerance": e.below_tolerance,
                "mesh": e.mesh.map(|m| json!({"change": m.change, "error": m.error, "below_tolerance": m.below_tolerance})),
            }))).collect::<serde_json::Map<_, _>>(),
            "mesh": d.mesh.as_ref().map(|m| json!({
                "study_id": m.study.0, "factor": m.factor, "audited": m.audited, "work_seconds": m.work_seconds,
            })),
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

const STYLE: &str = "body{font-family:sans-serif;margin:2em;color:#222}table{border-collapse:collapse}\
td,th{padding:2px 8px;border-bottom:1px solid #ddd;text-align:right}th{cursor:pointer}\
.surface{display:inline-block;margin:0 2em 2em 0}.cell:hover{stroke:#000}";

/// The study page's script: progress without reloading while the study runs (from the JSON at
/// `data-api`, written with `textContent` only), and a sortable points table.
const STUDY_JS: &str = "\
async function poll() {
  const p = document.getElementById('progress');
  if (!p || p.dataset.state !== 'active') return;
  try {
    const s = await (await fetch(p.dataset.api)).json(); const g = s.progress;
    p.textContent = s.state + ': ' + g.done + ' of ' + g.total + ' done, ' + g.leased + ' running, ' + g.pending + ' pending, ' + g.failed + ' failed';
    const t = document.getElementById('running');
    if (t) {
      [...t.rows].slice(1).forEach(r => r.remove());
      s.running.forEach(r => { const row = t.insertRow();
        [r.point_id, ...s.parameters.map(n => r.parameters[n]), r.pool, r.iterations ?? '', r.eta == null ? '' : r.eta.toExponential(2)]
          .forEach(x => row.insertCell().textContent = x); });
    }
    if (s.state !== 'active') location.reload(); else p.dataset.polled = (Number(p.dataset.polled || 0) + 1).toString();
  } catch (e) {}
  setTimeout(poll, 1000);
}
poll();
document.querySelectorAll('#points th').forEach((th, k) => th.onclick = () => {
  const t = document.getElementById('points'); const rows = [...t.rows].slice(1);
  const key = r => { const x = r.cells[k].textContent; const n = parseFloat(x); return isNaN(n) ? x : n; };
  rows.sort((a, b) => key(a) < key(b) ? -1 : key(a) > key(b) ? 1 : 0).forEach(r => t.appendChild(r));
});
";

fn page(title: &str, body: Markup) -> Markup {
    html! {
        (DOCTYPE)
        html {
            head { meta charset="utf-8"; title { (title) } link rel="stylesheet" href="/static/style.css"; }
            body { h1 { (title) } (body) }
        }
    }
}

/// `path?fix=NAME=VALUE`, the query percent-encoded (a parameter's name may hold any character).
fn slice_link(path: &str, name: &str, value: f64) -> String {
    let query: String = form_urlencoded::Serializer::new(String::new())
        .append_pair("fix", &format!("{name}={}", parameter(value)))
        .finish();
    format!("{path}?{query}")
}

async fn index(State(web): State<Web>, headers: HeaderMap, Query(q): Params) -> Response {
    if let Err(r) = check(&web, &headers, &q) {
        return page_refusal(r);
    }
    let studies = web.coordinator.studies();
    // mean work of the points solved cold and warm (answered ones aside)
    let mean = |id: StudyId, warm: bool| {
        let full = web.coordinator.study(id, true).map(|f| f.points).unwrap_or_default();
        let w: Vec<f64> = full
            .iter()
            .filter_map(|p| p.result.as_ref())
            .filter(|r| !r.answered && r.converged && r.started_from.is_some() == warm)
            .map(|r| r.work)
            .collect();
        if w.is_empty() { "-".to_owned() } else { format!("{:.1}", w.iter().sum::<f64>() / w.len() as f64) }
    };
    let body = html! {
        table #studies {
            tr { th { "study" } th { "kind" } th { "scene" } th { "label" } th { "state" } th { "done" } th { "running" } th { "pending" }
                 th { "tolerance" } th { "submitted" } th { "finished" } th { "wall time" } th { "work cold" } th { "work warm" } }
            @for v in &studies {
                tr {
                    td { a href=(format!("/studies/{}", v.record.id.0)) { (v.record.id.0) } }
                    td { (v.kind) }
                    td { (v.scene_title) }
                    td { (v.record.label) }
                    td { (state_word(v.state)) }
                    td { (v.progress.done) " / " (v.progress.total) }
                    td { (v.progress.leased) }
                    td { (v.progress.pending) }
                    td { (format!("{:.1e}", v.record.tolerance)) }
                    td { (utc_minute(v.record.created_unix_ms)) }
                    td { (v.finished_unix_ms.map_or(String::new(), utc_minute)) }
                    td { (v.finished_unix_ms.map_or(String::new(), |f| wall_time((f - v.record.created_unix_ms) as f64 / 1e3))) }
                    td { (mean(v.record.id, false)) }
                    td { (mean(v.record.id, true)) }
                }
            }
        }
        p { "work: dynamic iterations + static iterations / time steps, mean per point solved" }
        p { "JSON: " a href="/api/studies" { "/api/studies" } }
    };
    page("glissade studies", body).into_response()
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

/// One decimal: SVG coordinates.
fn d1(x: f64) -> String {
    format!("{x:.1}")
}

/// The SVG of one QoI over the done points: a colour map of cells over two parameters with
/// labelled contour lines, a curve over one. Each cell or dot carries its value (the tooltip
/// under the pointer). `units` (the scene's, by name) label the axes.
pub fn surface_svg(
    parameters: &[String],
    qoi: &str,
    points: &[(Vec<f64>, f64)],
    units: &BTreeMap<String, String>,
) -> Markup {
    let (w, h, m) = (420.0, 320.0, 40.0);
    let inner = surface_content(parameters, qoi, points, units, (w, h, m));
    html! {
        svg class="surface" data-qoi=(qoi) width=(w) height=(h) xmlns="http://www.w3.org/2000/svg" {
            text x=(m) y="16" { (named(qoi, units)) }
            (inner)
        }
    }
}

fn surface_content(
    parameters: &[String],
    qoi: &str,
    points: &[(Vec<f64>, f64)],
    units: &BTreeMap<String, String>,
    (w, h, m): (f64, f64, f64),
) -> Markup {
    if points.is_empty() {
        return html! { text x="40" y="60" { "no point done yet" } };
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
    let label = |x: &[f64]| {
        parameters.iter().zip(x).map(|(n, v)| format!("{n}={}", parameter(*v))).collect::<Vec<_>>().join(" ")
    };
    let extremes = html! { text x=(w - 200.0) y="16" { (format!("{vlo:.3e} … {vhi:.3e}")) } };
    if parameters.len() < 2 {
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
        return html! {
            polyline fill="none" stroke="#36c" points=(line.join(" ")) {}
            @for (x, v) in &sorted {
                @let (px, py) = xy(x[0], *v);
                circle class="cell" cx=(d1(px)) cy=(d1(py)) r="4" fill="#36c" data-value=(format!("{v:e}")) {
                    title { (label(x)) " " (qoi) " = " (format!("{v:.4e}")) }
                }
            }
            @if let Some(p) = parameters.first() {
                text x=(m) y=(h - 8.0) { (named(p, units)) " →" }
            }
            (extremes)
        };
    }
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
    // contours through the cells' centres, at 4 levels evenly between the extremes
    let mut grid = vec![None; xs.len() * ys.len()];
    for (x, v) in points {
        let (i, j) = (xs.partition_point(|a| *a < x[0]), ys.partition_point(|b| *b < x[1]));
        grid[j * xs.len() + i] = Some(*v);
    }
    let centre = |i: usize, j: usize| (px(xs[i]) + cw / 2.0, py(ys[j]) + ch / 2.0);
    let contours: Vec<(usize, f64, Vec<Segment>)> = (1..=4)
        .map(|k| {
            let level = vlo + (vhi - vlo) * k as f64 / 5.0;
            (k, level, contour(&grid, xs.len(), level, centre))
        })
        .filter(|(_, _, segments)| !segments.is_empty())
        .collect();
    html! {
        @for (x, v) in points {
            rect class="cell" x=(d1(px(x[0]))) y=(d1(py(x[1]))) width=(d1(cw)) height=(d1(ch))
                fill=(colour((v - vlo) / (vhi - vlo))) data-value=(format!("{v:e}")) {
                title { (label(x)) " " (qoi) " = " (format!("{v:.4e}")) }
            }
        }
        @for (k, level, segments) in &contours {
            // neighbouring levels labelled on different segments: close lines' labels do not overlap
            @let ((ax, ay), (bx, by)) = segments[(segments.len() / 2 + k) % segments.len()];
            @let d: String = segments.iter().map(|((ax, ay), (bx, by))| format!("M{ax:.1} {ay:.1}L{bx:.1} {by:.1}")).collect();
            path class="contour" data-level=(format!("{level:e}")) d=(d) fill="none" stroke="#000" stroke-width="0.8" pointer-events="none" {}
            text class="contour-label" x=(d1((ax + bx) / 2.0)) y=(d1((ay + by) / 2.0)) font-size="10" stroke="#fff"
                stroke-width="2" paint-order="stroke" pointer-events="none" { (format!("{level:.2e}")) }
        }
        text x=(m) y=(h - 8.0) { (named(&parameters[0], units)) " →" }
        text x="4" y=(m - 4.0) { "↑ " (named(&parameters[1], units)) }
        (extremes)
    }
}

type Vertex = (f64, f64);
type Segment = (Vertex, Vertex);

/// Marching squares: the segments of the line where the value is `level`, over a grid of `nx`
/// columns (row-major, None where no point is done) whose node (i, j) is drawn at `at(i, j)`.
/// Each square's crossings are linear along its edges; a saddle is split by the square's mean.
fn contour(grid: &[Option<f64>], nx: usize, level: f64, at: impl Fn(usize, usize) -> Vertex) -> Vec<Segment> {
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
pub fn convergence_svg(histories: &[Vec<f64>]) -> Markup {
    let (w, h, m) = (420.0, 320.0, 40.0);
    let values = histories.iter().flatten().filter(|v| **v > 0.0 && v.is_finite());
    let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v.log10()), b.max(v.log10())));
    let longest = histories.iter().map(Vec::len).max().unwrap_or(0);
    let lines: Vec<String> = histories
        .iter()
        .filter(|h| h.len() >= 2)
        .map(|history| {
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
            line.join(" ")
        })
        .collect();
    html! {
        svg class="convergence" width=(w) height=(h) xmlns="http://www.w3.org/2000/svg" {
            text x=(m) y="16" { "eta against iterations" }
            @if longest < 2 || lo >= hi {
                text x="40" y="60" { "no history yet" }
            } @else {
                @for line in &lines {
                    polyline class="history" fill="none" stroke="#36c" stroke-opacity="0.5" points=(line) {}
                }
                text x=(m) y=(h - 8.0) { (format!("iterations (0 … {}) →", longest - 1)) }
                text x=(w - 140.0) y="16" { (format!("1e{lo:.0} … 1e{hi:.0}")) }
            }
        }
    }
}

async fn study_page(State(web): State<Web>, Path(id): Path<String>, headers: HeaderMap, Query(q): Params) -> Response {
    if let Err(r) = check(&web, &headers, &q) {
        return page_refusal(r);
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
    // what the solve resolves of each QoI: values below it show as 0 (the API keeps them)
    let resolution = glissade_core::study::resolutions(r.tolerance, s.rows.iter().map(|row| &row.qoi), |q| {
        scene.as_ref()?.unit(q).map(str::to_owned)
    });
    // a slice: `?fix=NAME=VALUE` keeps the points at that value and draws the others' curve
    let fixed =
        q.get("fix").and_then(|f| f.split_once('=')).and_then(|(n, v)| Some((n.to_owned(), v.parse::<f64>().ok()?)));
    let free: Vec<String> =
        s.parameters.iter().filter(|n| fixed.as_ref().is_none_or(|(f, _)| f != *n)).cloned().collect();
    let here = format!("/studies/{}", r.id.0);
    // the first value of the last parameter: a slice the page offers
    let offered = s
        .parameters
        .last()
        .filter(|_| s.parameters.len() >= 2 && fixed.is_none())
        .and_then(|last| Some((last, s.rows.iter().find_map(|row| row.parameters.get(last))?)));
    let surfaces: Vec<Markup> = s
        .qoi
        .iter()
        .map(|qoi| {
            let points: Vec<(Vec<f64>, f64)> = s
                .rows
                .iter()
                .filter(|row| {
                    fixed.as_ref().is_none_or(|(n, v)| row.parameters.get(n).is_some_and(|x| same_parameter(x, *v)))
                })
                .filter_map(|row| {
                    let x: Option<Vec<f64>> = free.iter().map(|n| row.parameters.get(n)).collect();
                    Some((x?, shown(*row.qoi.get(qoi)?, resolution[qoi])))
                })
                .collect();
            surface_svg(&free, qoi, &points, &units)
        })
        .collect();
    // a slice that holds no point says which values there are
    let slice_miss = fixed
        .as_ref()
        .filter(|(n, v)| !s.rows.iter().any(|row| row.parameters.get(n).is_some_and(|x| same_parameter(x, *v))))
        .map(|f| {
            let points: Vec<BTreeMap<String, f64>> =
                s.rows.iter().map(|row| BTreeMap::from(row.parameters.clone())).collect();
            glissade_core::study::space::slice_miss(std::slice::from_ref(f), &points)
        });
    let histories: Vec<Vec<f64>> =
        v.points.iter().filter_map(|p| p.result.as_ref().map(|r| r.eta_history.clone())).collect();
    let state = state_word(v.state);
    let body = html! {
        p #progress data-state=(state) data-api=(format!("/api/studies/{}", r.id.0)) {
            (format!("{state}: {} of {} done, {} running, {} pending, {} failed", p.done, p.total, p.leased, p.pending, p.failed))
        }
        p { (format!("tolerance {:.1e}, strategy {}, parameters ", r.tolerance, r.strategy.name())) (r.parameters.join(", ")) }
        @if let Some(a) = &v.accuracy {
            p #accuracy {
                (format!("measured accuracy: {} of {} points re-solved cold at {:.0e}: ", a.audited, a.planned, a.tolerance))
                @for (k, (q, (l, m))) in a.qoi.iter().enumerate() {
                    @if k > 0 { ", " }
                    (q) (format!(" largest {l:.1e} mean {m:.1e}"))
                }
                @if a.work_cap > 0.0 {
                    (format!("; it cost {:.0} work of its cap {:.0} ({:.0} % of the study's)", a.work, a.work_cap, AUDIT_WORK_FRACTION * 100.0))
                }
            }
        }
        @if let Some(a) = &v.surface_accuracy {
            p #surface-accuracy {
                (format!(
                    "surface between the points: {} of {} held-out points solved cold at {:.0e}, against the surface of {} points: ",
                    a.validated, a.planned, a.tolerance, a.fitted
                ))
                @for (k, (q, e)) in a.qoi.iter().enumerate() {
                    @if k > 0 { ", " }
                    (q) (format!(" largest {:.1e} mean {:.1e} of its spread, {:.0} % within 2 sd", e.largest, e.mean, e.within_2sd * 100.0))
                }
                @for (q, why) in &a.refused {
                    (format!("; {} not predicted: {why}", if q.is_empty() { "the surface" } else { q }))
                }
                @if a.work_cap > 0.0 {
                    (format!("; it cost {:.0} work of its cap {:.0}", a.work, a.work_cap))
                }
            }
        }
        @if let Some(d) = &v.discretisation {
            p #discretisation {
                (format!(
                    "discretisation error: {} of {} points re-solved at {} ({:.1} s of solves, {:.2} x the study's {:.1} s): ",
                    d.audited,
                    d.planned,
                    d.levels.iter().map(|(_, f)| format!("dt / {f}")).collect::<Vec<_>>().join(" and "),
                    d.work_seconds,
                    if d.study_seconds > 0.0 { d.work_seconds / d.study_seconds } else { 0.0 },
                    d.study_seconds
                ))
                @for (k, (q, e)) in d.qoi.iter().enumerate() {
                    @if k > 0 { ", " }
                    (q) (format!(" change {:.1e} error ~{:.1e}", e.change, e.error))
                    @if e.erratic > 0 {
                        strong { (format!(" (erratic at {} point(s): an event moves with the step; no extrapolation)", e.erratic)) }
                    } @else if e.below_tolerance {
                        " (below the iterations' noise)"
                    } @else if let Some(order) = e.order {
                        (format!(" (observed order {order:.2})"))
                    } @else {
                        " (order 2 assumed)"
                    }
                }
            }
            @if let Some(m) = &d.mesh {
                p #mesh-discretisation {
                    (format!(
                        "mesh error: {} of {} points re-solved cold at h / {} ({:.1} s of solves, {:.2} x the study's): ",
                        m.audited,
                        d.planned,
                        m.factor,
                        m.work_seconds,
                        if d.study_seconds > 0.0 { m.work_seconds / d.study_seconds } else { 0.0 },
                    ))
                    @for (k, (q, e)) in d.qoi.iter().filter_map(|(q, e)| Some((q, e.mesh?))).enumerate() {
                        @if k > 0 { ", " }
                        (q) (format!(" change {:.1e} error ~{:.1e}", e.change, e.error))
                        @if e.below_tolerance { " (below the iterations' noise)" } @else { " (order 2 assumed)" }
                    }
                }
            }
        }
        @if let Some((name, value)) = &fixed {
            p #slice { "slice at " (name) (format!(" = {} (", parameter(*value))) a href=(here) { "whole surface" } ")" }
        } @else if let Some((last, value)) = offered {
            p { "slices: " a #slice-link href=(slice_link(&here, last, value)) { (last) (format!(" = {}", parameter(value))) } }
        }
        @if let Some(miss) = &slice_miss {
            p #slice-miss { (miss) }
        } @else {
            @for svg in &surfaces { (svg) }
        }
        // the running points: the script fills this table from the JSON while the study runs
        @if v.state == StudyState::Active {
            table #running {
                caption { "running points" }
                tr { th { "point" } @for n in &r.parameters { th { (named(n, &units)) } } th { "pool" } th { "iterations" } th { "eta" } }
            }
        }
        (convergence_svg(&histories))
        p {
            "download: " a href=(format!("/api/studies/{}/surface.csv", r.id.0)) { "surface.csv" } ", "
            a href=(format!("/api/studies/{}", r.id.0)) { "study JSON" }
        }
        table #points {
            tr {
                th { "point" }
                @for n in &r.parameters { th { (named(n, &units)) } }
                th { "state" } th { "iterations" } th { "eta" }
                @for qoi in &s.qoi { th { (named(qoi, &units)) } }
                th { "note" }
            }
            @for point in &v.points {
                @let res = point.result.as_ref();
                tr {
                    td { (point.id.0) }
                    @for n in &r.parameters { td { @if let Some(x) = point.parameters.get(n) { (parameter(x)) } } }
                    td { (point_state_word(&point.state)) }
                    td { @if let Some(r) = res { (r.iterations) } }
                    td { @if let Some(r) = res { (format!("{:.2e}", r.error_indicator)) } }
                    @for qoi in &s.qoi {
                        td { @if let Some(x) = res.and_then(|r| r.qoi.get(qoi)) { (format!("{:.4e}", shown(*x, resolution[qoi]))) } }
                    }
                    // why it failed (or why its last attempt did)
                    td class="note" { @if let Some(e) = &point.error { (e) } }
                }
            }
        }
        script src="/static/study.js" {}
    };
    let title = if r.label.is_empty() { format!("study {}", r.id.0) } else { format!("study {}: {}", r.id.0, r.label) };
    page(&title, body).into_response()
}

#[cfg(test)]
mod tests {
    use super::*;

    // the pictures as text, to search in
    fn surface_svg(p: &[String], q: &str, points: &[(Vec<f64>, f64)], u: &BTreeMap<String, String>) -> String {
        super::surface_svg(p, q, points, u).into_string()
    }
    fn convergence_svg(histories: &[Vec<f64>]) -> String {
        super::convergence_svg(histories).into_string()
    }

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
