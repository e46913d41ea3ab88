//! The coordinator's read-only web page and JSON API, served on its gRPC port (HTTP/1.1 beside
//! HTTP/2): the studies, each study with its progress and running points (updated while it runs),
//! its measured accuracy, a response surface per QoI drawn on the server as SVG (a colour map with
//! contour lines over two parameters, a curve over one; the value under the pointer; axes named
//! with the scene's units; kept between loads until a point lands, figures.rs), its points, and
//! downloads. Nothing is fetched from elsewhere.
//!
//! Every string a user gave (labels, parameter, QoI and unit names) reaches the page through
//! maud, which escapes by construction; the page's script and style are files of this server
//! (`/static/...`), and a Content-Security-Policy forbids any other, inline ones included.
//!
//! When the coordinator has tokens, every request needs the user token: `Authorization: Bearer
//! TOKEN`, or for a browser the HttpOnly cookie that the form at `/login` sets. A token never goes
//! in a URL (histories and logs keep URLs): `?token=` is refused.
//!
//! JSON: `/api/studies` (a page of ListStudies' studies), `/api/studies/ID` (the study GetStudy
//! returns with its points, the running ones with the iterations and eta their pools last
//! reported), `/api/studies/ID/progress` (the same with its running points only), each the
//! proto's JSON (glissade_proto::json: proto3's mapping, the one rendering of a study);
//! `/api/studies/ID/surface` (every QoI of every point); CSV: `/api/studies/ID/surface.csv`;
//! Prometheus text: `/metrics` (metrics.rs). Any other path is 404.

use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;

use axum::extract::{Form, Path, Query, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Redirect, Response};
use axum::routing::get;
use glissade_core::contact::ContactActivity;
use glissade_core::point::DesignPoint;
use glissade_proto::StudyId;
use glissade_proto::auth::Token;
use glissade_proto::v1;
use maud::{DOCTYPE, Markup, PreEscaped, html};
use serde_json::json;

use crate::auth::Tokens;
use crate::convert;
use crate::coordinator::{
    AUDIT_WORK_FRACTION, CoordError, Coordinator, StudyState, StudyView, Surface, SurfaceSource, point_state_word,
    state_word,
};
use crate::figures::{self, FigureCache};
use crate::low_priority::{LowPriority, NotBuilt};
use crate::metrics::{self, Metrics};
use crate::read_budget::{Admission, MAX_WAIT, REFUSAL_DELAY, ReadBudget};
use crate::renderings::{Answer, NotRendered, Rendered, Renderings};
use axum::body::Bytes;
use glissade_core::text::{parameter, percent, qoi_digits, qoi_value, same_parameter, utc_minute, wall_time};

#[derive(Clone)]
struct Web {
    coordinator: Arc<Coordinator>,
    metrics: Arc<Metrics>,
    token: Option<Token>,
    /// the login cookie is `Secure` (sent over https only) when the coordinator serves TLS
    secure_cookie: bool,
    /// the surfaces' pictures of the last loads
    figures: Arc<FigureCache>,
    /// where the heavy answers are built (low_priority.rs)
    heavy: Arc<LowPriority>,
    /// the studies' JSON and pages last built, kept under their versions
    renderings: Arc<Renderings>,
}

/// The cookie that carries the user token (hex-encoded: any printable token fits a cookie).
const COOKIE: &str = "glissade_token";

/// No script, style, image, frame or form target but this server's own (and the colour maps'
/// PNGs, embedded in their SVGs as data: images, which run nothing): an injected inline script
/// would not run even if a string escaped the templates.
const CSP: &str = "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data:; connect-src 'self'; \
                   form-action 'self'; frame-ancestors 'none'; base-uri 'none'";

/// The routes of the page and the API; every answer carries [`CSP`], and any other path is 404.
pub fn router(
    coordinator: Arc<Coordinator>,
    metrics: Arc<Metrics>,
    tokens: Option<&Tokens>,
    secure_cookie: bool,
    heavy: Arc<LowPriority>,
    budget: Arc<ReadBudget>,
) -> axum::Router {
    let token = tokens.map(|t| t.user.clone());
    let web =
        Web { coordinator, metrics, token, secure_cookie, figures: Arc::default(), heavy, renderings: Arc::default() };
    routes(web).route_layer(axum::middleware::from_fn_with_state(budget, within_budget))
}

/// Every request but the page's static files takes its turn from its address's budget
/// (read_budget.rs): at once, after a wait, or, past the longest wait, 429 with `Retry-After`
/// after a delay. A request without a connection (only in-process tests make one) is not counted.
async fn within_budget(
    State(budget): State<Arc<ReadBudget>>,
    request: axum::extract::Request,
    next: axum::middleware::Next,
) -> Response {
    let ip = crate::conn::conn_of(request.extensions()).and_then(|c| c.tcp.remote_addr()).map(|a| a.ip());
    let admission = match ip {
        Some(ip) if !request.uri().path().starts_with("/static/") => budget.take(ip, std::time::Instant::now()),
        _ => Admission::Now,
    };
    match admission {
        Admission::Now => {}
        Admission::After(wait) => tokio::time::sleep(wait).await,
        Admission::Refused { retry_after } => {
            tokio::time::sleep(REFUSAL_DELAY).await;
            let seconds = retry_after.as_secs_f64().ceil().max(1.0);
            let mut refused = refuse(
                StatusCode::TOO_MANY_REQUESTS,
                &format!(
                    "too many requests from this address: at most {} a second (the coordinator's \
                     --web-reads-per-second), and those of the next {} s are taken; try again in {seconds} s",
                    budget.rate(),
                    MAX_WAIT.as_secs()
                ),
            )
            .into_response();
            refused.headers_mut().insert(header::RETRY_AFTER, HeaderValue::from(seconds as u64));
            return refused;
        }
    }
    next.run(request).await
}

fn routes(web: Web) -> axum::Router {
    axum::Router::new()
        .route("/", get(index))
        .route("/login", get(login_form).post(login))
        .route("/static/study.js", get(|| async { ([(header::CONTENT_TYPE, "text/javascript")], STUDY_JS) }))
        .route("/static/style.css", get(|| async { ([(header::CONTENT_TYPE, "text/css")], STYLE) }))
        .route("/studies/{id}", get(study_page))
        .route("/api/studies", get(api_studies))
        .route("/api/studies/{id}", get(api_study))
        .route("/api/studies/{id}/progress", get(api_study_progress))
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

/// The token a request presents: `Authorization: Bearer` (gRPC's metadata as well), else the
/// login cookie.
pub fn presented(headers: &HeaderMap) -> Option<String> {
    let bearer = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.strip_prefix("Bearer "))
        .map(str::to_owned);
    bearer.or_else(|| cookie(headers, COOKIE).and_then(unhex))
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
    match presented(headers) {
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

/// Runs `build` on the web's low-priority threads: the answer, or why there is none (503 when
/// they are all busy and their queue is full).
async fn heavy(web: &Web, build: impl FnOnce() -> Response + Send + 'static) -> Response {
    web.heavy.run(build).await.unwrap_or_else(not_built)
}

fn not_built(e: NotBuilt) -> Response {
    not_built_refusal(e).into_response()
}

fn not_built_refusal(e: NotBuilt) -> Refusal {
    match e {
        NotBuilt::Busy => {
            refuse(StatusCode::SERVICE_UNAVAILABLE, "the coordinator is busy with other pages: try again in a moment")
        }
        NotBuilt::Failed => {
            refuse(StatusCode::INTERNAL_SERVER_ERROR, "this answer could not be built (the coordinator's log says why)")
        }
    }
}

/// A message's JSON (glissade_proto::json: the API's one rendering), serialised where it is
/// built.
fn message_response<M: serde::Serialize>(message: &M) -> Response {
    ([(header::CONTENT_TYPE, "application/json")], glissade_proto::json::to_vec(message)).into_response()
}

/// JSON, serialised where it is built (a large study's is megabytes).
fn json_response(value: &serde_json::Value) -> Response {
    match serde_json::to_vec(value) {
        Ok(bytes) => ([(header::CONTENT_TYPE, "application/json")], bytes).into_response(),
        Err(e) => refuse(StatusCode::INTERNAL_SERVER_ERROR, &format!("writing the JSON: {e}")).into_response(),
    }
}

fn failed(e: CoordError) -> Refusal {
    match e {
        CoordError::UnknownStudy(_) => refuse(StatusCode::NOT_FOUND, &e.to_string()),
        e => refuse(StatusCode::INTERNAL_SERVER_ERROR, &glissade_core::text::one_line(&e.to_string())),
    }
}

/// The study's id from the path.
fn study_id(id: &str) -> Result<StudyId, Refusal> {
    id.parse()
        .map(StudyId)
        .map_err(|_| refuse(StatusCode::NOT_FOUND, &format!("no study `{}`", glissade_core::text::excerpt(id, 40))))
}

/// The study's id from the path, then the study.
fn study(web: &Web, id: &str, points: bool) -> Result<StudyView, Refusal> {
    web.coordinator.study(study_id(id)?, points).map_err(failed)
}

/// What an open study page polls: the study as GetStudy returns it (its JSON,
/// glissade_proto::json) with its running points only, each with the iterations and eta its pool
/// last reported: not the points done (a whole study's JSON is megabytes on a large one).
async fn api_study_progress(
    State(web): State<Web>,
    Path(id): Path<String>,
    headers: HeaderMap,
    Query(q): Params,
) -> Response {
    if let Err(r) = check(&web, &headers, &q) {
        return r.into_response();
    }
    let id = match study_id(&id) {
        Ok(id) => id,
        Err(r) => return r.into_response(),
    };
    let coordinator = web.coordinator.clone();
    match tokio::task::spawn_blocking(move || coordinator.study_running(id)).await {
        Ok(Ok(v)) => message_response(&convert::study(&v)),
        Ok(Err(e)) => failed(e).into_response(),
        Err(_) => refuse(StatusCode::INTERNAL_SERVER_ERROR, "the progress could not be read").into_response(),
    }
}

async fn api_studies(State(web): State<Web>, headers: HeaderMap, Query(q): Params) -> Response {
    if let Err(r) = check(&web, &headers, &q) {
        return r.into_response();
    }
    let (after, limit) = match paging(&q) {
        Ok(p) => p,
        Err(r) => return r.into_response(),
    };
    // (the views and their JSON of a large database take a while)
    let coordinator = web.coordinator.clone();
    heavy(&web, move || {
        let (page, more) = coordinator.studies_page(after, limit);
        let studies: Vec<v1::Study> = page.iter().map(convert::study).collect();
        let mut response = message_response(&studies);
        let last = page.last().map(|v| v.record.id.0);
        if let Some(next) = next_page("/api/studies", last, more, limit)
            && let Ok(link) = HeaderValue::from_str(&format!("<{next}>; rel=\"next\""))
        {
            response.headers_mut().insert(header::LINK, link);
        }
        response
    })
    .await
}

/// Studies a list gives at most unless `?limit=` says otherwise (1 to [`MAX_PAGE_STUDIES`]): a
/// database of thousands of studies made each list megabytes built under the coordinator's lock
/// (issue 48).
const PAGE_STUDIES: usize = 200;
const MAX_PAGE_STUDIES: usize = 1000;

/// `?after=ID&limit=N`: the studies after `ID` in id order, at most `N`.
fn paging(q: &HashMap<String, String>) -> Result<(StudyId, usize), Refusal> {
    let after = match q.get("after") {
        None => 0,
        Some(a) => a.parse().map_err(|_| refuse(StatusCode::BAD_REQUEST, "after=ID takes a study id"))?,
    };
    let limit = match q.get("limit") {
        None => PAGE_STUDIES,
        Some(l) => l.parse().ok().filter(|n| (1..=MAX_PAGE_STUDIES).contains(n)).ok_or_else(|| {
            refuse(StatusCode::BAD_REQUEST, &format!("limit=N takes 1 to {MAX_PAGE_STUDIES} studies"))
        })?,
    };
    Ok((StudyId(after), limit))
}

/// The address of the page after one that ended at study `last`, when more follow.
fn next_page(path: &str, last: Option<u64>, more: bool, limit: usize) -> Option<String> {
    let last = last.filter(|_| more)?;
    Some(if limit == PAGE_STUDIES {
        format!("{path}?after={last}")
    } else {
        format!("{path}?after={last}&limit={limit}")
    })
}

async fn api_study(State(web): State<Web>, Path(id): Path<String>, headers: HeaderMap, Query(q): Params) -> Response {
    if let Err(r) = check(&web, &headers, &q) {
        return r.into_response();
    }
    // (a large study's points and their JSON take a while: kept while the study stays as it is)
    let w = web.clone();
    heavy(&web, move || {
        let (id, version) = match versioned(&w, &id) {
            Ok(v) => v,
            Err(r) => return r.into_response(),
        };
        let built = w.renderings.get_or_build(id, "json", version, || {
            // exactly GetStudy's study with its points, without their eta histories
            // (`without_eta_histories`: a hundred numbers a point, read from the store)
            let v = w.coordinator.study(id, true).map_err(|e| not_rendered(failed(e)))?;
            Ok(Answer::new("application/json", glissade_proto::json::to_vec(&convert::study(&v)).into()))
        });
        rendered(built, &headers)
    })
    .await
}

/// The study's id from the path, and its version (None while it changes as it is read).
fn versioned(web: &Web, id: &str) -> Result<(StudyId, Option<crate::coordinator::StudyVersion>), Refusal> {
    let id = study_id(id)?;
    Ok((id, web.coordinator.study_version(id).map_err(failed)?))
}

fn not_rendered(r: Refusal) -> NotRendered {
    (r.0, r.1)
}

/// An answer as the reader asked for it: gzipped when its `Accept-Encoding` takes gzip.
fn rendered(r: Result<Rendered, NotRendered>, headers: &HeaderMap) -> Response {
    let answer = match r {
        Ok(answer) => answer,
        Err((status, why)) => return Refusal(status, why).into_response(),
    };
    let gzip = headers
        .get_all(header::ACCEPT_ENCODING)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','))
        .any(|coding| coding.split(';').next().is_some_and(|c| c.trim().eq_ignore_ascii_case("gzip")));
    let vary = (header::VARY, HeaderValue::from_static("accept-encoding"));
    let content_type = (header::CONTENT_TYPE, HeaderValue::from_static(answer.content_type));
    if gzip {
        let encoding = (header::CONTENT_ENCODING, HeaderValue::from_static("gzip"));
        return ([content_type, encoding, vary], answer.gzipped().clone()).into_response();
    }
    ([content_type, vary], answer.body.clone()).into_response()
}

async fn api_surface(State(web): State<Web>, Path(id): Path<String>, headers: HeaderMap, Query(q): Params) -> Response {
    if let Err(r) = check(&web, &headers, &q) {
        return r.into_response();
    }
    let w = web.clone();
    heavy(&web, move || match surface(&w, &id) {
        Ok(s) => json_response(&json!({
            "parameters": s.parameters,
            "qoi": s.qoi,
            "points": s.rows.iter().map(|r| json!({
                "parameters": BTreeMap::from(r.parameters.clone()), "qoi": r.qoi, "state": point_state_word(&r.state),
            })).collect::<Vec<_>>(),
        })),
        Err(r) => r.into_response(),
    })
    .await
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
    let w = web.clone();
    heavy(&web, move || surface_csv(&w, &id)).await
}

fn surface_csv(web: &Web, id: &str) -> Response {
    let s = match surface(web, id) {
        Ok(s) => s,
        Err(r) => return r.into_response(),
    };
    let header: Vec<String> = s.parameters.iter().chain(&s.qoi).cloned().chain(["state".to_owned()]).collect();
    let rows = s.rows.iter().map(|r| {
        let mut fields: Vec<String> =
            s.parameters.iter().map(|n| r.parameters.get(n).map_or(String::new(), |v| v.to_string())).collect();
        fields.extend(s.qoi.iter().map(|q| r.qoi.get(q).map_or(String::new(), |v| format!("{v:e}"))));
        fields.push(point_state_word(&r.state).to_owned());
        fields
    });
    let out = glissade_core::text::csv_table(std::iter::once(header).chain(rows));
    ([(header::CONTENT_TYPE, "text/csv; charset=utf-8")], out).into_response()
}

fn surface(web: &Web, id: &str) -> Result<Surface, Refusal> {
    let v = study(web, id, false)?;
    web.coordinator.surface(SurfaceSource::Study(v.record.id), &DesignPoint::default(), &[], &[]).map_err(failed)
}

const STYLE: &str = "body{font-family:sans-serif;margin:2em;color:#222}table{border-collapse:collapse}\
td,th{padding:2px 8px;border-bottom:1px solid #ddd;text-align:right}th{cursor:pointer}\
.surface,.convergence{display:block;margin:0 0 2em 0}circle.point{fill:#000;fill-opacity:0}\
.point:hover{stroke:#000;stroke-width:2}";

/// The study page's script: progress without reloading while the study runs (from the study's
/// JSON at `data-api` + `/progress`: proto3's mapping, its points the running ones; written with
/// `textContent` only), and a sortable points table.
const STUDY_JS: &str = "\
async function poll() {
  const p = document.getElementById('progress');
  if (!p || p.dataset.state !== 'active') return;
  try {
    const s = await (await fetch(p.dataset.api + '/progress')).json(); const g = s.progress;
    const state = s.state.replace('STUDY_STATE_', '').toLowerCase();
    p.textContent = state + ': ' + g.done + ' of ' + g.total + ' done, ' + g.leased + ' running, ' + g.pending + ' pending, ' + g.failed + ' failed';
    const t = document.getElementById('running');
    if (t) {
      [...t.rows].slice(1).forEach(r => r.remove());
      // (iterations and eta 0: its pool has not reported yet)
      s.points.filter(r => r.state === 'POINT_STATE_LEASED').forEach(r => { const row = t.insertRow();
        [r.point_id, ...s.parameters.map(n => r.parameters[n]), r.pool_id, r.iterations === '0' ? '' : r.iterations,
         r.error_indicator ? r.error_indicator.toExponential(2) : '']
          .forEach(x => row.insertCell().textContent = x); });
    }
    if (state !== 'active') location.reload(); else p.dataset.polled = (Number(p.dataset.polled || 0) + 1).toString();
  } catch (e) {}
  // every second at first, then less often: a long study's open tab costs little
  setTimeout(poll, Math.min(5000, 1000 + 250 * Number(p.dataset.polled || 0)));
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
    let (after, limit) = match paging(&q) {
        Ok(p) => p,
        Err(r) => return page_refusal(r),
    };
    // (a large database takes a while under the coordinator's lock)
    let coordinator = web.coordinator.clone();
    heavy(&web, move || studies_html(&coordinator, after, limit)).await
}

/// A page of the studies (`limit` of them after `after`, in id order) but the audits and pilots'
/// levels, which are listed on their study's page and counted on its row.
fn studies_html(coordinator: &Coordinator, after: StudyId, limit: usize) -> Response {
    let (listed, more) = coordinator.studies_page(after, limit);
    let next = next_page("/", listed.last().map(|v| v.record.id.0), more, limit);
    let studies: Vec<StudyView> =
        listed.into_iter().filter(|v| v.record.audit_of.is_none() && v.record.pilot_of.is_none()).collect();
    let means: Vec<[Option<f64>; 2]> = studies.iter().map(|v| coordinator.mean_work(v.record.id)).collect();
    // mean work of the points solved cold and warm (answered ones aside)
    let mean = |k: usize, warm: bool| means[k][usize::from(warm)].map_or("-".to_owned(), |w| format!("{w:.1}"));
    let body = html! {
        table #studies {
            tr { th { "study" } th { "kind" } th { "scene" } th { "label" } th { "state" } th { "audits" } th { "done" } th { "running" } th { "pending" }
                 th { "tolerance" } th { "submitted" } th { "finished" } th { "wall time" } th { "work cold" } th { "work warm" } }
            @for (k, v) in studies.iter().enumerate() {
                tr {
                    td { a href=(format!("/studies/{}", v.record.id.0)) { (v.record.id.0) } }
                    td { (v.kind) }
                    td { (v.scene_title) }
                    td { (v.record.label) }
                    td { (state_word(v.state)) }
                    td { (audits_cell(v)) }
                    td { (v.progress.done) " / " (v.progress.total) }
                    td { (v.progress.leased) }
                    td { (v.progress.pending) }
                    td { (format!("{:.1e}", v.record.tolerance)) }
                    td { (utc_minute(v.record.created_unix_ms)) }
                    td { (v.finished_unix_ms.map_or(String::new(), utc_minute)) }
                    td { (v.finished_unix_ms.map_or(String::new(), |f| wall_time((f - v.record.created_unix_ms) as f64 / 1e3))) }
                    td { (mean(k, false)) }
                    td { (mean(k, true)) }
                }
            }
        }
        p { "work: dynamic iterations + static iterations / time steps, mean per point solved; audits and pilots' levels are listed on their study's page" }
        @if let Some(next) = &next {
            p #next-page { a href=(next) { "next page" } (format!(" ({limit} studies a page, audits and levels included)")) }
        }
        p { "JSON: " a href="/api/studies" { "/api/studies" } " (" (PAGE_STUDIES) " a page; the next in its Link header)" }
    };
    page("glissade studies", body).into_response()
}

/// `name (unit)`, or the name alone when the scene gives it no unit.
fn named(name: &str, units: &BTreeMap<String, String>) -> String {
    match units.get(name) {
        Some(u) => format!("{name} ({u})"),
        None => name.to_owned(),
    }
}

/// A response surface's picture on the page (glissade-plot's SVG, the one drawing of the CLI's
/// PNG too), with a transparent circle over each point that names its value under the pointer.
const SURFACE_SIZE: (u32, u32) = (960, 420);
const CONVERGENCE_SIZE: (u32, u32) = (720, 420);

/// The picture of one QoI: the surface that answers `glissade surface --at`, over the box where
/// it answers, or a line that says why there is none.
fn surface_figure(surface: &glissade_plot::Surface, digits: usize) -> Markup {
    let qoi = &surface.qoi.name;
    let (w, h) = SURFACE_SIZE;
    if surface.points.is_empty() {
        return html! {
            svg class="surface" data-qoi=(qoi) width=(w) height="60" xmlns="http://www.w3.org/2000/svg" {
                text x="10" y="30" { (surface.qoi.label()) ": no point done yet" }
            }
        };
    }
    let svg = match glissade_plot::surface_svg(surface, SURFACE_SIZE) {
        Ok(svg) => svg,
        Err(e) => return html! { p class="surface-error" { (surface.qoi.label()) ": " (e.to_string()) } },
    };
    let label = |x: &[f64]| {
        surface
            .parameters
            .iter()
            .zip(x)
            .map(|(a, v)| format!("{}={}", a.name, parameter(*v)))
            .collect::<Vec<_>>()
            .join(" ")
    };
    let levels = svg.drawn.contours.iter().filter(|(_, s)| !s.is_empty()).count();
    html! {
        svg class="surface" data-qoi=(qoi) data-count=(surface.points.len()) data-contours=(levels)
            data-surface=(surface.field.is_ok()) width=(w) height=(h) xmlns="http://www.w3.org/2000/svg" {
            // plotters escapes the text it writes (glissade-plot's tests pin it)
            (PreEscaped(svg.text))
            @for ((x, v), (px, py)) in surface.points.iter().zip(&svg.drawn.markers) {
                // transparent (style.css): the picture draws the point, this names its value
                circle class="point" cx=(px) cy=(py) r="6" {
                    title { (label(x)) " " (qoi) " = " (qoi_value(*v, digits, 0.0)) }
                }
            }
        }
    }
}

/// Eta against the iterations of every point solved (log scale), as the paper's Figures 7 and
/// 8, with the study's tolerance.
fn convergence_figure(series: &[glissade_plot::ConvergenceSeries], tolerance: f64) -> Markup {
    let (w, h) = CONVERGENCE_SIZE;
    match glissade_plot::convergence_svg(series, Some(tolerance), "eta against iterations", CONVERGENCE_SIZE) {
        Ok(text) => html! {
            svg class="convergence" data-series=(series.iter().filter(|s| !s.history.is_empty()).count())
                width=(w) height=(h) xmlns="http://www.w3.org/2000/svg" { (PreEscaped(text)) }
        },
        Err(_) => html! {
            svg class="convergence" data-series="0" width=(w) height="60" xmlns="http://www.w3.org/2000/svg" {
                text x="10" y="30" { "eta against iterations: no history yet" }
            }
        },
    }
}

/// The pictures of every QoI of a study (a slice of it when `fixed`), as SVG text. Fitting a
/// surface costs O(points^3): callers run this off the async threads.
fn surface_figures(
    s: &Surface,
    scene: Option<&glissade_core::scene::Scene>,
    fixed: &[(String, f64)],
    resolution: &BTreeMap<String, f64>,
) -> Vec<String> {
    let parameters: Vec<BTreeMap<String, f64>> = s.rows.iter().map(|r| BTreeMap::from(r.parameters.clone())).collect();
    let rows: Vec<glissade_plot::study::Row> = parameters.iter().zip(&s.rows).map(|(p, r)| (p, &r.qoi)).collect();
    s.qoi
        .iter()
        .map(|qoi| {
            let picture = glissade_plot::study::Picture {
                scene,
                names: &s.parameters,
                swept: &s.parameters,
                fixed,
                qoi,
                resolution: resolution.get(qoi).copied().unwrap_or(0.0),
                tolerance: s.rows.first().map_or(0.0, |r| r.tolerance),
                title: String::new(),
            };
            surface_figure(&picture.surface(&rows), qoi_digits(picture.tolerance)).into_string()
        })
        .collect()
}

/// The pictures of a study's surfaces: those of the last load when none of the points'
/// parameters and values changed since (figures.rs), else drawn again off the async threads.
async fn cached_figures(
    cache: &Arc<FigureCache>,
    heavy: &LowPriority,
    study: StudyId,
    s: &Arc<Surface>,
    scene: &Option<Arc<glissade_core::scene::Scene>>,
    fixed: &[(String, f64)],
    resolution: &BTreeMap<String, f64>,
) -> Result<Arc<Vec<String>>, Refusal> {
    let hash = figures::content_hash(s, fixed, resolution);
    loop {
        if let Some(kept) = cache.get(study, fixed, hash) {
            return Ok(kept);
        }
        if cache.begin(study, fixed, hash) {
            break;
        }
        // another load draws these very pictures: they will be kept
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }
    // The drawing keeps its pictures itself: a page that gives up (a browser's timeout, a
    // reload) does not throw minutes of drawing away, and the next load finds them.
    // The drawing ends (the next load may draw) when it is kept, and also if its job panicked or
    // was refused (the threads busy).
    struct Ends(Arc<FigureCache>, StudyId, Vec<(String, f64)>, u64);
    impl Drop for Ends {
        fn drop(&mut self) {
            self.0.end(self.1, &self.2, self.3);
        }
    }
    let ends = Ends(cache.clone(), study, fixed.to_vec(), hash);
    let (s, scene, resolution) = (s.clone(), scene.clone(), resolution.clone());
    heavy
        .run_to_end(move || {
            let Ends(cache, study, fixed, hash) = &ends;
            let drawn = Arc::new(surface_figures(&s, scene.as_deref(), fixed, &resolution));
            cache.put(*study, fixed, *hash, drawn.clone());
            drawn
        })
        .await
        .map_err(not_built_refusal)
}

/// The slice a page shows (`?fix=NAME=VALUE`), the values there are when it holds no point, and
/// the slice it offers when it shows the whole surface.
struct Slicing {
    fixed: Option<(String, f64)>,
    miss: Option<String>,
    offered: Option<(String, f64)>,
}

impl Slicing {
    fn of(s: &Surface, q: &HashMap<String, String>) -> Slicing {
        let fixed = q
            .get("fix")
            .and_then(|f| f.split_once('='))
            .and_then(|(n, v)| Some((n.to_owned(), v.parse::<f64>().ok()?)));
        let miss = fixed
            .as_ref()
            .filter(|(n, v)| !s.rows.iter().any(|row| row.parameters.get(n).is_some_and(|x| same_parameter(x, *v))))
            .map(|f| {
                let points: Vec<BTreeMap<String, f64>> =
                    s.rows.iter().map(|row| BTreeMap::from(row.parameters.clone())).collect();
                glissade_core::study::space::slice_miss(std::slice::from_ref(f), &points)
            });
        // the first value of the last parameter
        let offered = s
            .parameters
            .last()
            .filter(|_| s.parameters.len() >= 2 && fixed.is_none())
            .and_then(|last| Some((last.clone(), s.rows.iter().find_map(|row| row.parameters.get(last))?)));
        Slicing { fixed, miss, offered }
    }

    fn links(&self, here: &str) -> Markup {
        html! {
            @if let Some((name, value)) = &self.fixed {
                p #slice { "slice at " (name) (format!(" = {} (", parameter(*value))) a href=(here) { "whole surface" } ")" }
            } @else if let Some((last, value)) = &self.offered {
                p { "slices: " a #slice-link href=(slice_link(here, last, *value)) { (last) (format!(" = {}", parameter(*value))) } }
            }
        }
    }
}

async fn study_page(State(web): State<Web>, Path(id): Path<String>, headers: HeaderMap, Query(q): Params) -> Response {
    if let Err(r) = check(&web, &headers, &q) {
        return page_refusal(r);
    }
    // read and built on the low-priority threads, the pictures too; kept while the study stays
    // as it is (per slice)
    let what = format!("page {}", q.get("fix").map_or("", String::as_str));
    let w = web.clone();
    let key = what.clone();
    let asked = headers.clone();
    let read = web.heavy.run(move || -> Result<PageRead, Refusal> {
        let (study, version) = versioned(&w, &id)?;
        if let Some(kept) = version.as_ref().and_then(|v| w.renderings.get(study, &key, v)) {
            // (gzipped here, on this thread, when asked)
            return Ok(PageRead::Kept(rendered(Ok(kept), &asked)));
        }
        Ok(PageRead::Shown(study, version, Box::new(StudyShown::read(&w, &id, &q)?)))
    });
    let (study, version, shown) = match read.await {
        Ok(Ok(PageRead::Shown(study, version, shown))) => (study, version, shown),
        Ok(Ok(PageRead::Kept(kept))) => return kept,
        Ok(Err(r)) => return r.into_response(),
        Err(e) => return not_built(e),
    };
    let figures = match &shown.slicing.miss {
        Some(_) => Arc::default(),
        None => {
            let fixed: Vec<(String, f64)> = shown.slicing.fixed.iter().cloned().collect();
            match cached_figures(
                &web.figures,
                &web.heavy,
                shown.v.record.id,
                &shown.s,
                &shown.scene,
                &fixed,
                &shown.resolution,
            )
            .await
            {
                Ok(f) => f,
                Err(refusal) => return refusal.into_response(),
            }
        }
    };
    let w = web.clone();
    heavy(&web, move || {
        let html: Bytes = shown.page(&figures).into_string().into();
        let built = Answer::new("text/html; charset=utf-8", html);
        if let Some(version) = version {
            w.renderings.put(study, &what, version, built.clone());
        }
        rendered(Ok(built), &headers)
    })
    .await
}

/// A study's page kept at the study's version (the answer to send), or what to build it from.
enum PageRead {
    Kept(Response),
    Shown(StudyId, Option<crate::coordinator::StudyVersion>, Box<StudyShown>),
}

/// What a study's page shows but its pictures.
struct StudyShown {
    v: StudyView,
    s: Arc<Surface>,
    scene: Option<Arc<glissade_core::scene::Scene>>,
    /// the units the scene gives its parameters and QoIs
    units: BTreeMap<String, String>,
    /// what the solve resolves of each QoI: values below it show as 0 (the API keeps them)
    resolution: BTreeMap<String, f64>,
    slicing: Slicing,
}

impl StudyShown {
    fn read(web: &Web, id: &str, q: &HashMap<String, String>) -> Result<Self, Refusal> {
        // (the points' eta histories read back from the store for the convergence plot)
        let v = web.coordinator.study_with_histories(study_id(id)?).map_err(failed)?;
        let s = Arc::new(surface(web, id)?);
        let r = &v.record;
        // (parsed once, when the study entered)
        let scene = Some(v.scene.clone());
        let units: BTreeMap<String, String> = r
            .parameters
            .iter()
            .chain(&s.qoi)
            .filter_map(|n| Some((n.clone(), scene.as_ref()?.unit(n)?.to_owned())))
            .collect();
        let resolution = glissade_core::study::resolutions(r.tolerance, s.rows.iter().map(|row| &row.qoi), |q| {
            scene.as_ref()?.unit(q).map(str::to_owned)
        });
        let slicing = Slicing::of(&s, q);
        Ok(Self { v, s, scene, units, resolution, slicing })
    }

    fn page(&self, figures: &[String]) -> Markup {
        let StudyShown { v, s, units, resolution, slicing, .. } = self;
        let r = &v.record;
        let series: Vec<glissade_plot::ConvergenceSeries> = v
            .points
            .iter()
            .filter_map(|p| {
                let history = p.result.as_ref()?.eta_history.values().to_vec();
                Some(glissade_plot::ConvergenceSeries { label: format!("#{}", p.id.0), history })
            })
            .collect();
        let here = format!("/studies/{}", r.id.0);
        let state = state_word(v.state);
        let p = v.progress;
        let body = html! {
            p #progress data-state=(state) data-api=(format!("/api/studies/{}", r.id.0)) {
                (format!("{state}: {} of {} done, {} running, {} pending, {} failed", p.done, p.total, p.leased, p.pending, p.failed))
            }
            (audits_paragraph(v))
            p { (format!("tolerance {:.1e}, strategy {}, parameters ", r.tolerance, r.strategy.name())) (r.parameters.join(", ")) }
            // the pictures first, then how far to trust them (issue 47: the page opened on five
            // paragraphs of numbers)
            (slicing.links(&here))
            @if let Some(miss) = &slicing.miss {
                p #slice-miss { (miss) }
            } @else {
                @for svg in figures.iter() { (PreEscaped(svg)) }
            }
            h2 { "Accuracy" }
            (target_paragraph(v))
            (contact_paragraphs(v))
            (audit_paragraphs(v))
            // the running points: the script fills this table from the JSON while the study runs
            @if v.state == StudyState::Active {
                table #running {
                    caption { "running points" }
                    tr { th { "point" } @for n in &r.parameters { th { (named(n, units)) } } th { "pool" } th { "iterations" } th { "eta" } }
                }
            }
            (convergence_figure(&series, r.tolerance))
            (undrawn_iterations(v))
            p {
                "download: " a href=(format!("/api/studies/{}/surface.csv", r.id.0)) { "surface.csv" } ", "
                a href=(format!("/api/studies/{}", r.id.0)) { "study JSON" }
            }
            (points_table(v, &s.qoi, units, resolution))
            script src="/static/study.js" {}
        };
        let title =
            if r.label.is_empty() { format!("study {}", r.id.0) } else { format!("study {}: {}", r.id.0, r.label) };
        page(&title, body)
    }
}

/// What the convergence plot leaves out: the static stage's iterations (a prestressed scene's),
/// which the points' iteration counts include but which have no eta on the curves.
fn undrawn_iterations(v: &StudyView) -> Markup {
    let most = v
        .points
        .iter()
        .filter_map(|p| p.result.as_ref())
        .map(|r| r.iterations.saturating_sub(r.eta_history.len() as u64))
        .max()
        .unwrap_or(0);
    if most == 0 {
        return html! {};
    }
    html! {
        p #undrawn { (format!("The curves draw the dynamic stage: the iteration counts below also count up to {most} static iterations a point, before it.")) }
    }
}

/// The studies under this one (its audits, its pilots' levels), each linked with its state:
/// a study whose points have ended is not finished with while one of them runs.
fn audits_paragraph(v: &StudyView) -> Markup {
    if v.audits.is_empty() {
        return html! {};
    }
    let active = v.audits.iter().filter(|a| a.state == StudyState::Active).count();
    html! {
        p #audits data-running=(active) {
            @if active > 0 { strong { (format!("{active} of {} audits and levels still running", v.audits.len())) } ": " }
            @for (k, a) in v.audits.iter().enumerate() {
                @if k > 0 { "; " }
                (a.what) " " a href=(format!("/studies/{}", a.study.0)) { (format!("study {}", a.study.0)) }
                (format!(" {}, {} of {} done", state_word(a.state), a.progress.done, a.progress.total))
                @if let Some(why) = &a.why_cancelled { (format!(", {} cancelled: {why}", a.progress.cancelled)) }
            }
        }
    }
}

/// A study's audits in a cell of the list (as `glissade studies`).
fn audits_cell(v: &StudyView) -> String {
    glissade_core::text::audits_cell(v.audits.len(), v.audits.iter().filter(|a| a.state == StudyState::Active).count())
}

/// An adaptive study's surface accuracy target and what came of it.
fn target_paragraph(v: &StudyView) -> Markup {
    let Some((target, a)) = v.record.adaptive.as_ref().and_then(|a| Some((a.target?, a))) else { return html! {} };
    html! {
        p #target {
            (format!("surface accuracy target {} (the largest error anywhere in the box, as the surface estimates it, of each QoI's spread): ", percent(target)))
            @match &a.outcome {
                None => (format!("not decided yet (budget {} points)", a.budget)),
                Some(o) => {
                    @if o.reached { (format!("reached at {} points (budget {}): ", o.validation.points, a.budget)) }
                    @else if o.validation.only_set_aside() {
                        (format!("NOT reached: {} set aside as no surface (below); the others within it at {} points (budget {}): ",
                            o.validation.set_aside.iter().cloned().collect::<Vec<_>>().join(", "), o.validation.points, a.budget))
                    }
                    // (a work budget stopped it where its points are fewer than their budget: as
                    // `glissade show` reads the API's target)
                    @else if a.work_budget.is_some() && (o.validation.points as u32) < a.budget {
                        (format!("NOT reached: the work budget of {:.0} was spent (work {:.0}); at {} points: ",
                            a.work_budget.unwrap_or(0.0), crate::records::work_of(&v.points), o.validation.points))
                    }
                    @else { (format!("NOT reached: the budget of {} points was spent; at {} points: ", a.budget, o.validation.points)) }
                    @for (k, (q, e)) in o.validation.qoi.iter().enumerate() {
                        @if k > 0 { ", " }
                        (q) (format!(" largest in the box {} (at the points {}, mean {})",
                            percent(e.box_largest.unwrap_or(e.largest)), percent(e.largest), percent(e.mean)))
                    }
                    @for (q, why) in &o.validation.refused {
                        "; " (q) " not fitted: " (why)
                    }
                }
            }
        }
    }
}

/// What the study's audits measured: the points' accuracy, the surface's between them, the time
/// step's and the mesh's errors.
fn audit_paragraphs(v: &StudyView) -> Markup {
    html! {
        @if let Some(a) = &v.accuracy {
            p #accuracy {
                (format!("measured accuracy: {} of {} points re-solved cold at {:.0e}: ", a.audited, a.planned, a.tolerance))
                @for (k, (q, (l, m))) in a.qoi.iter().enumerate() {
                    @if k > 0 { ", " }
                    (q) (format!(" largest {} mean {}", percent(*l), percent(*m)))
                }
                " (of each QoI's largest |value|)"
                @if a.work_cap > 0.0 {
                    (format!("; it cost {:.0} work of its cap {:.0} ({:.0} % of the study's)", a.work, a.work_cap, AUDIT_WORK_FRACTION * 100.0))
                }
            }
        }
        @if let Some(a) = &v.surface_accuracy {
            p #surface-accuracy {
                (format!(
                    "surface between the points: {} of {} held-out points (seed {}) solved cold at {:.0e}, against the surface of {} points: ",
                    a.validated, a.planned, a.seed, a.tolerance, a.fitted
                ))
                @for (k, (q, e)) in a.qoi.iter().enumerate() {
                    @if k > 0 { ", " }
                    (q) (format!(" largest {} mean {} of its spread, within 2 sd at {:.0} % of the points", percent(e.largest), percent(e.mean), e.within_2sd * 100.0))
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
            (discretisation_paragraphs(d))
            @let verdicts = v.verdicts();
            @if !verdicts.is_empty() {
                p #verdict {
                    "which error dominates, QoI by QoI:"
                    @for line in &verdicts { br; (line) }
                }
            }
        }
        @if let Some(t) = &v.record.to_accuracy {
            (to_accuracy_paragraphs(t, v.record.tolerance, v.held_out_check.as_ref()))
        }
    }
}

/// A study to an accuracy: what was asked, what its pilots chose (per QoI the estimate and its
/// parts) and what its held-out points said, in `glissade show`'s words.
fn to_accuracy_paragraphs(
    t: &crate::records::ToAccuracy,
    tolerance: f64,
    check: Option<&crate::coordinator::HeldOutCheck>,
) -> Markup {
    let done = t.reports.iter().flatten().count();
    html! {
        p #to-accuracy {
            (format!("accuracy asked: {} of each QoI's scale (the largest magnitude of its history), tolerance {tolerance:.1e}; ", percent(t.accuracy)))
            (format!("{done} of {} pilots done", t.pilots.len()))
            @if let Some((k, m)) = t.chosen {
                "; " strong { (format!("REACHED at dt / {k}, h / {m}")) } ": the study's points are solved there"
                @for a in &t.above {
                    (format!(" (ABOVE at dt / {}, h / {}, said its held-out check, study {}: solved again one level finer)", a.time_factor, a.mesh_factor, a.check.0))
                }
            } @else if let Some(why) = &t.why_not {
                "; " strong { "NOT REACHED" } (format!(": {why}"))
            }
            @for (name, e) in t.largest_estimates() {
                br;
                (match e.joint {
                    Some(j) => format!(
                        "{name}: {} (dt and h together {}, iterations {}; apart: time step {}, mesh {})",
                        percent(e.total),
                        percent(j),
                        percent(e.iteration),
                        percent(e.time),
                        e.mesh.map_or("not estimated".to_string(), percent)
                    ),
                    None => format!(
                        "{name}: {} (time step {}, mesh {}, iterations {})",
                        percent(e.total),
                        percent(e.time),
                        e.mesh.map_or("not estimated".to_string(), percent),
                        percent(e.iteration)
                    ),
                })
                @if !e.within { strong { " ABOVE" } }
            }
        }
        @if let Some(c) = check {
            p #held-out-check {
                (format!("held-out: {} of {} points re-solved at dt / {}, h / {}", c.done, c.planned, c.time_factor, c.mesh_factor))
                @for (name, d) in &c.difference {
                    (format!(", {name} {}", percent(*d)))
                }
                ": "
                @match c.confirmed {
                    Some(true) => strong { "CONFIRMED" },
                    Some(false) if c.failed > 0 => strong { (format!("NOT CONFIRMED: {} re-solves failed", c.failed)) },
                    Some(false) => strong { "ABOVE" },
                    None => "running once the study has ended",
                }
            }
        }
    }
}

fn discretisation_paragraphs(d: &crate::coordinator::Discretisation) -> Markup {
    html! {
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
                (q) (format!(" change {} error ~{}", percent(e.change), percent(e.error)))
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
            " (of each QoI's largest |value|)"
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
                    (q) (format!(" change {} error ~{}", percent(e.change), percent(e.error)))
                    @if e.below_tolerance { " (below the iterations' noise)" } @else { " (order 2 assumed)" }
                }
                " (of each QoI's largest |value|)"
            }
        }
    }
}

/// The points whose sliding is ill-posed, then those whose slide chatters (docs/verification.md
/// 4d): their answers move as the mesh and the time step are refined whatever the tolerance,
/// and the surface through them with them.
fn contact_paragraphs(v: &StudyView) -> Markup {
    html! {
        (flagged_paragraph(v, "ill-posed", "slide ill-posed", ContactActivity::warning))
        (flagged_paragraph(v, "chatter", "chatter while they slide", ContactActivity::chatter_warning))
    }
}

/// One warning paragraph for the points one of whose contacts `warning` flags, with the first's
/// words.
fn flagged_paragraph(v: &StudyView, id: &str, what: &str, warning: fn(&ContactActivity) -> Option<String>) -> Markup {
    let flagged: Vec<(u64, String)> =
        v.points.iter().filter_map(|p| Some((p.id.0, p.result.as_ref()?.contact.iter().find_map(warning)?))).collect();
    let Some((_, first)) = flagged.first() else { return html! {} };
    let ids: Vec<String> = flagged.iter().map(|(id, _)| format!("#{id}")).collect();
    html! {
        p id=(id) class="warning" {
            (format!("warning: {} of {} points {what} ({}). ", flagged.len(), v.points.len(), ids.join(", ")))
            (first)
        }
    }
}

/// Every point of the study with its state, iterations, eta, QoIs and why it failed (or how its
/// contact slid ill-posed).
fn points_table(
    v: &StudyView,
    qoi: &[String],
    units: &BTreeMap<String, String>,
    resolution: &BTreeMap<String, f64>,
) -> Markup {
    let parameters = &v.record.parameters;
    let digits = qoi_digits(v.record.tolerance);
    html! {
        table #points {
            tr {
                th { "point" }
                @for n in parameters { th { (named(n, units)) } }
                th { "state" } th { "iterations" } th { "eta" }
                @for q in qoi { th { (named(q, units)) } }
                th { "note" }
            }
            @for point in &v.points {
                @let res = point.result.as_ref();
                tr {
                    td { (point.id.0) }
                    @for n in parameters { td { @if let Some(x) = point.parameters.get(n) { (parameter(x)) } } }
                    td { (point_state_word(&point.state)) }
                    td { @if let Some(r) = res { (r.iterations) } }
                    td { @if let Some(r) = res { (glissade_core::text::eta(r.error_indicator)) } }
                    @for q in qoi {
                        td { @if let Some(x) = res.and_then(|r| r.qoi.get(q)) { (qoi_value(*x, digits, resolution[q])) } }
                    }
                    // why it failed (or why its last attempt did)
                    td class="note" {
                        @if let Some(e) = &point.error { (e) }
                        @for c in res.iter().flat_map(|r| &r.contact) {
                            @if c.ill_posed {
                                (format!("ill-posed: '{}' slides on a rigid wall at friction {}", c.interface, c.friction))
                            } @else if c.chatters() {
                                (format!("chatters: '{}' landed {} times while it slid", c.interface, c.landings_while_sliding))
                            }
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::records::PointState;
    use glissade_plot::study::{Picture, Row};
    use std::time::Duration;

    /// A scene of glissade-plot's tests: parameters a in [0, 1] and b in [0, 2] m/s, QoIs ux (m)
    /// and slip (a norm).
    const SCENE: &str = include_str!("../../plot/tests/two-parameters.toml");

    /// The figure of `qoi` over points (a, b) with ux = a + b and slip = a b.
    fn figure(qoi: &str, points: &[(f64, f64)], fixed: &[(String, f64)]) -> String {
        let scene = glissade_core::scene::Scene::parse(SCENE).unwrap();
        let data: Vec<(BTreeMap<String, f64>, BTreeMap<String, f64>)> = points
            .iter()
            .map(|&(a, b)| {
                let p = BTreeMap::from([("a".to_owned(), a), ("b".to_owned(), b)]);
                (p, BTreeMap::from([("ux".to_owned(), a + b), ("slip".to_owned(), a * b)]))
            })
            .collect();
        let rows: Vec<Row> = data.iter().map(|(p, q)| (p, q)).collect();
        let names = ["a".to_owned(), "b".to_owned()];
        let picture = Picture {
            scene: Some(&scene),
            names: &names,
            swept: &names,
            fixed,
            qoi,
            resolution: 0.0,
            tolerance: 0.0,
            title: String::new(),
        };
        surface_figure(&picture.surface(&rows), 5).into_string()
    }

    #[test]
    fn a_study_draws_its_surface_with_a_value_under_each_point() {
        // scattered points, as an adaptive study's
        let points = [(0.1, 0.3), (0.8, 0.2), (0.5, 1.0), (0.2, 1.7), (0.9, 1.5), (0.4, 0.6)];
        let svg = figure("ux", &points, &[]);
        assert!(svg.starts_with("<svg class=\"surface\" data-qoi=\"ux\" data-count=\"6\""), "{svg}");
        assert!(svg.contains("data-surface=\"true\""), "a surface, not rings around the points");
        assert_eq!(svg.matches("<circle class=\"point\"").count(), 6);
        assert!(svg.contains("<title>a=0.1 b=0.3 ux = 4.0000e-1</title>"), "the value under the pointer: {svg}");
        assert!(svg.contains("standard deviation of ux [m]"), "the second panel");
        let contours: usize =
            svg.split("data-contours=\"").nth(1).and_then(|t| t.split('"').next()?.parse().ok()).unwrap();
        assert!(contours >= 5, "{contours}");
        // a slice: the curve over a at b = 1
        let fixed = [("b".to_owned(), 1.0)];
        let curve = figure("slip", &[(0.1, 1.0), (0.5, 1.0), (0.9, 1.0), (0.5, 0.3)], &fixed);
        assert_eq!(curve.matches("<circle class=\"point\"").count(), 3, "{curve}");
        assert!(curve.contains("mean ± 2 sd"));
        // nothing done yet; one point: no surface, and why
        assert!(figure("ux", &[], &[]).contains("ux [m]: no point done yet"));
        let one = figure("ux", &[(0.5, 0.5)], &[]);
        assert!(
            one.contains("data-surface=\"false\"") && one.contains("no surface: a surface needs at least 2 points")
        );
    }

    /// A study's surface of points (a, b) with ux = a + b and slip = a b; `done` of them have values.
    fn study_surface(points: &[(f64, f64)], done: usize) -> Surface {
        let rows = points
            .iter()
            .enumerate()
            .map(|(k, &(a, b))| crate::coordinator::SurfaceRow {
                parameters: DesignPoint::from_pairs([("a", a), ("b", b)]).unwrap(),
                qoi: if k < done {
                    BTreeMap::from([("ux".to_owned(), a + b), ("slip".to_owned(), a * b)])
                } else {
                    BTreeMap::new()
                },
                iterations: 10,
                error_indicator: 1e-4,
                converged: k < done,
                state: if k < done { PointState::Done } else { PointState::Pending },
                tolerance: 1e-4,
            })
            .collect();
        Surface {
            scene_hash: String::new(),
            parameters: vec!["a".into(), "b".into()],
            qoi: vec!["slip".into(), "ux".into()],
            rows,
            predictions: Vec::new(),
            units: Default::default(),
        }
    }

    /// A page that gives up while its pictures are drawn (issue 48: a 2000-point study's page
    /// timed out twice, and each reload drew its surfaces again) leaves them drawn and kept; two
    /// loads at once draw once.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_drawing_a_page_gave_up_on_is_kept_and_two_loads_at_once_draw_once() {
        let scene = Some(Arc::new(glissade_core::scene::Scene::parse(SCENE).unwrap()));
        let cache = Arc::new(FigureCache::default());
        let heavy = LowPriority::start(1).unwrap();
        let points = [(0.1, 0.3), (0.8, 0.2), (0.5, 1.0), (0.2, 1.7), (0.9, 1.5)];
        let resolution = BTreeMap::from([("ux".to_owned(), 0.0), ("slip".to_owned(), 0.0)]);
        let s = Arc::new(study_surface(&points, 4));
        let gave_up = tokio::time::timeout(
            Duration::ZERO,
            cached_figures(&cache, &heavy, StudyId(3), &s, &scene, &[], &resolution),
        )
        .await;
        assert!(gave_up.is_err(), "the page gave up before the pictures were drawn");
        let hash = figures::content_hash(&s, &[], &resolution);
        let waited = std::time::Instant::now();
        while cache.get(StudyId(3), &[], hash).is_none() {
            assert!(waited.elapsed() < Duration::from_secs(30), "the drawing was thrown away");
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        assert!(!cache.drawing(StudyId(3), &[], hash));
        let next = cached_figures(&cache, &heavy, StudyId(3), &s, &scene, &[], &resolution).await.ok().unwrap();
        assert_eq!(cache.stats().0, 1, "the next load found them");
        assert_eq!(*next, surface_figures(&s, scene.as_deref(), &[], &resolution));
        // a point lands and two pages load at once: one drawing
        let landed = Arc::new(study_surface(&points, 5));
        let (a, b) = tokio::join!(
            cached_figures(&cache, &heavy, StudyId(3), &landed, &scene, &[], &resolution),
            cached_figures(&cache, &heavy, StudyId(3), &landed, &scene, &[], &resolution)
        );
        assert!(Arc::ptr_eq(&a.ok().unwrap(), &b.ok().unwrap()));
        assert_eq!(cache.stats().0, 2);
    }

    #[tokio::test]
    async fn a_second_load_draws_nothing_and_a_new_point_draws_again() {
        let scene = Some(Arc::new(glissade_core::scene::Scene::parse(SCENE).unwrap()));
        let cache = Arc::new(FigureCache::default());
        let heavy = LowPriority::start(1).unwrap();
        let points = [(0.1, 0.3), (0.8, 0.2), (0.5, 1.0), (0.2, 1.7), (0.9, 1.5)];
        let resolution = BTreeMap::from([("ux".to_owned(), 0.0), ("slip".to_owned(), 0.0)]);
        let load = |s: Surface, fixed: Vec<(String, f64)>| {
            let (cache, scene, resolution, heavy) = (&cache, &scene, &resolution, &heavy);
            async move {
                cached_figures(cache, heavy, StudyId(3), &Arc::new(s), scene, &fixed, resolution).await.ok().unwrap()
            }
        };
        let first = load(study_surface(&points, 4), vec![]).await;
        assert_eq!(cache.stats().0, 1);
        // the same points again: the same pictures, not drawn again
        let second = load(study_surface(&points, 4), vec![]).await;
        assert!(Arc::ptr_eq(&first, &second));
        assert_eq!(cache.stats().0, 1);
        // the last point leased (its state only): nothing changes on the picture
        let mut leased = study_surface(&points, 4);
        leased.rows[4].state =
            PointState::Leased { pool: "p".into(), lease_id: 1, deadline_unix_ms: 0, init: None, cap: None };
        load(leased, vec![]).await;
        assert_eq!(cache.stats().0, 1);
        // it lands: drawn again, its value on the picture
        let landed = load(study_surface(&points, 5), vec![]).await;
        assert_eq!(cache.stats().0, 2);
        assert!(landed.iter().any(|svg| svg.contains("a=0.9 b=1.5 ux = 2.4000e0")), "the new point's value");
        assert!(first.iter().all(|svg| !svg.contains("a=0.9 b=1.5")));
        // a point's value changes (a tighter re-solve replaces it): drawn again
        let mut moved = study_surface(&points, 5);
        moved.rows[0].qoi.insert("ux".into(), 0.41);
        load(moved, vec![]).await;
        assert_eq!(cache.stats().0, 3);
        // a slice is kept apart from the whole surface
        load(study_surface(&points, 5), vec![("b".into(), 1.5)]).await;
        assert_eq!(cache.stats().0, 4);
        load(study_surface(&points, 5), vec![("b".into(), 1.5)]).await;
        assert_eq!(cache.stats().0, 4);
        // each picture is the drawing of its points, as without a cache
        let fresh = surface_figures(&study_surface(&points, 5), scene.as_deref(), &[], &resolution);
        assert_eq!(*landed, fresh);
    }

    /// A study's JSON and page are built once while it stays as it is, however many read them
    /// (issue 48: every read of a finished 100,000-point study copied its records under the
    /// coordinator's lock and wrote 17.5 MB again), and built again as soon as it changes: what a
    /// reader gets is what a rebuild would give.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_studys_json_and_page_are_built_once_while_it_stays_as_it_is() {
        use crate::coordinator::CoordError;
        use crate::coordinator::tests::{VERSION, diverged, open, pool, solution_file, submit};
        use glissade_core::study::strategy::InitStrategy;
        use tower::ServiceExt;

        let dir = tempfile::tempdir().unwrap();
        let c = Arc::new(open(dir.path(), 60_000, 1));
        pool(&c, "p", VERSION);
        let id = submit(&c, &["f1=0.1:0.2:3"], 1e-3, InitStrategy::Cold);
        let renderings = Arc::new(Renderings::default());
        let web = Web {
            coordinator: c.clone(),
            metrics: Arc::new(Metrics::new(c.clone())),
            token: None,
            secure_cookie: false,
            figures: Arc::default(),
            heavy: Arc::new(LowPriority::start(1).unwrap()),
            renderings: renderings.clone(),
        };
        let app = routes(web);
        let get = |path: String| {
            let app = app.clone();
            async move {
                let request = axum::http::Request::get(path).body(axum::body::Body::empty()).unwrap();
                let response = app.oneshot(request).await.unwrap();
                assert_eq!(response.status(), StatusCode::OK);
                let body = axum::body::to_bytes(response.into_body(), usize::MAX).await.unwrap();
                String::from_utf8(body.to_vec()).unwrap()
            }
        };
        let json = || get(format!("/api/studies/{}", id.0));
        let state = |text: &str| serde_json::from_str::<serde_json::Value>(text).unwrap()["state"].clone();
        let builds = || renderings.stats().0;
        // two points done, the third failed: the study has ended
        for k in 0..3 {
            let grant = c.lease("p").unwrap().unwrap();
            if k < 2 {
                let (done, file) = solution_file(&grant, 5e-4, true);
                c.complete(done, file).unwrap();
            } else {
                c.fail(diverged(&grant)).unwrap();
            }
        }
        let first = json().await;
        assert_eq!(state(&first), "STUDY_STATE_FAILED");
        // the proto's JSON of the study GetStudy returns with its points without their histories
        let got = crate::convert::study(&c.study(id, true).unwrap());
        assert_eq!(serde_json::from_str::<serde_json::Value>(&first).unwrap(), glissade_proto::json::study(&got));
        assert_eq!(json().await, first);
        assert_eq!(builds(), 1, "read twice, built once");
        let page = get(format!("/studies/{}", id.0)).await;
        assert!(page.contains("failed"), "{page}");
        assert_eq!(get(format!("/studies/{}", id.0)).await, page);
        assert_eq!(builds(), 2, "the page too");
        // a retry: the next read is built again, and says so
        c.retry_failed(id).unwrap();
        assert_eq!(state(&json().await), "STUDY_STATE_ACTIVE");
        assert_eq!(builds(), 3);
        // leased: its reports move without a version, so every read is built
        let grant = c.lease("p").unwrap().unwrap();
        assert_eq!(state(&json().await), "STUDY_STATE_ACTIVE");
        json().await;
        assert_eq!(builds(), 3, "none kept while a point is solved");
        let (done, file) = solution_file(&grant, 5e-4, true);
        c.complete(done, file).unwrap();
        let done = json().await;
        assert_eq!(state(&done), "STUDY_STATE_DONE");
        assert_eq!(json().await, done);
        assert_eq!(builds(), 4);
        // another study's work leaves this one's kept
        let other = submit(&c, &["f1=0.13"], 1e-3, InitStrategy::Cold);
        let grant = c.lease("p").unwrap().unwrap();
        assert_eq!(grant.study, other);
        assert_eq!(json().await, done);
        assert_eq!(builds(), 4);
        assert!(matches!(c.study_version(StudyId(99)), Err(CoordError::UnknownStudy(_))));
        // a reader that takes gzip (a browser) gets the kept answer gzipped, and the same JSON
        for path in [format!("/api/studies/{}", id.0), format!("/studies/{}", id.0)] {
            let request = axum::http::Request::get(&path)
                .header(header::ACCEPT_ENCODING, "br;q=1.0, gzip;q=0.8")
                .body(axum::body::Body::empty())
                .unwrap();
            let response = app.clone().oneshot(request).await.unwrap();
            assert_eq!(response.headers()[header::CONTENT_ENCODING], "gzip", "{path}");
            let zipped = axum::body::to_bytes(response.into_body(), usize::MAX).await.unwrap();
            let mut text = String::new();
            std::io::Read::read_to_string(&mut flate2::read::GzDecoder::new(&zipped[..]), &mut text).unwrap();
            assert_eq!(text, get(path.clone()).await, "{path}");
            assert!(zipped.len() < text.len(), "{path}: {} gzipped bytes for {}", zipped.len(), text.len());
        }
        assert_eq!(builds(), 5, "the page kept at the study's last version, gzipped from it");
    }

    #[test]
    fn a_hostile_qoi_name_stays_text() {
        let hostile = "<script>alert(1)</script>";
        let scene = glissade_core::scene::Scene::parse(&SCENE.replace("name = \"ux\"", &format!("name = '{hostile}'")))
            .unwrap();
        let data: Vec<(BTreeMap<String, f64>, BTreeMap<String, f64>)> = [(0.1, 0.3), (0.8, 0.2), (0.5, 1.0)]
            .iter()
            .map(|&(a, b)| {
                (BTreeMap::from([("a".to_owned(), a), ("b".to_owned(), b)]), BTreeMap::from([(hostile.to_owned(), a)]))
            })
            .collect();
        let rows: Vec<Row> = data.iter().map(|(p, q)| (p, q)).collect();
        let names = ["a".to_owned(), "b".to_owned()];
        let picture = Picture {
            scene: Some(&scene),
            names: &names,
            swept: &names,
            fixed: &[],
            qoi: hostile,
            resolution: 0.0,
            tolerance: 0.0,
            title: String::new(),
        };
        let svg = surface_figure(&picture.surface(&rows), 5).into_string();
        assert!(!svg.contains("<script"), "{svg}");
        assert!(svg.contains("&lt;script&gt;alert(1)&lt;/script&gt;"), "{svg}");
    }

    #[test]
    fn the_convergence_plot_has_the_tolerance_line() {
        let series = |h: &[Vec<f64>]| -> Vec<glissade_plot::ConvergenceSeries> {
            h.iter().map(|h| glissade_plot::ConvergenceSeries { label: "#1".into(), history: h.clone() }).collect()
        };
        let svg = convergence_figure(&series(&[vec![1.0, 0.1, 0.01], vec![0.5, 0.05], vec![]]), 1e-2).into_string();
        assert!(svg.contains("data-series=\"2\""), "{svg}");
        assert!(svg.contains("tolerance"), "{svg}");
        assert!(convergence_figure(&[], 1e-2).into_string().contains("no history yet"));
    }
}
