//! The conversation with the coordinator that every command starts with: where it is, its token
//! and certificate, a user-service client, and one readable line for a refused call.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Result, anyhow};
use glissade_core::text::one_line;
use glissade_proto::auth::{Token, WithToken};
use glissade_proto::v1;
use glissade_proto::v1::user_client::UserClient;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::Channel;

/// How long to wait for the coordinator to accept a connection before giving up.
pub const CONNECT_TIMEOUT: Duration = Duration::from_secs(5);

/// One line for a refused call: what was asked, the server's reason, the status code.
pub fn refused(what: &str, status: tonic::Status) -> anyhow::Error {
    anyhow!("{what}: {} ({:?})", one_line(status.message()), status.code())
}

/// The coordinator a command talks to: its URL and the user token (if it needs one).
pub struct Server {
    pub url: String,
    pub token: Option<Token>,
    /// CA certificate of an `https://` coordinator (else GLISSADE_CA_CERT, else system roots).
    pub ca_cert: Option<PathBuf>,
}

impl std::fmt::Display for Server {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.url)
    }
}

/// A user-service client that presents the token with every call.
pub type User = UserClient<InterceptedService<Channel, WithToken>>;

pub async fn user(server: &Server) -> Result<User> {
    Ok(UserClient::with_interceptor(connect(server).await?, WithToken::new(server.token.as_ref())))
}

/// The study with (when asked) its points, without their eta histories, and its scene text;
/// errors start with `command ID`.
pub async fn get_study(client: &mut User, command: &str, id: u64, points: bool, scene: bool) -> Result<v1::Study> {
    ask_study(client, command, v1::GetStudyRequest { study_id: id, points, scene, without_eta_histories: true }).await
}

/// The study with its points and their eta histories.
pub async fn get_study_with_histories(client: &mut User, command: &str, id: u64) -> Result<v1::Study> {
    ask_study(client, command, v1::GetStudyRequest { study_id: id, points: true, ..Default::default() }).await
}

async fn ask_study(client: &mut User, command: &str, request: v1::GetStudyRequest) -> Result<v1::Study> {
    let id = request.study_id;
    Ok(client.get_study(request).await.map_err(|s| refused(&format!("{command} {id}"), s))?.into_inner())
}

/// Connects to `server`, turning transport errors into one line that says what went wrong.
pub async fn connect(server: &Server) -> Result<Channel> {
    let endpoint =
        glissade_proto::auth::endpoint(&server.url, server.ca_cert.as_deref())?.connect_timeout(CONNECT_TIMEOUT);
    tracing::debug!(server = %server, "connecting");
    glissade_proto::auth::connect(endpoint).await.map_err(|e| {
        tracing::debug!(error = ?e, "connect failed");
        anyhow!("cannot reach glissade server at {server}: {}", root_cause(&e))
    })
}

/// The innermost cause of a transport error, in words (tonic's own message is only
/// "transport error"; the useful part, e.g. "connection refused", sits at the bottom).
fn root_cause(error: &(dyn std::error::Error + 'static)) -> String {
    let mut current = error;
    let mut io_error = current.downcast_ref::<std::io::Error>();
    while let Some(next) = current.source() {
        current = next;
        io_error = current.downcast_ref::<std::io::Error>().or(io_error);
    }
    if let Some(io) = io_error {
        return match io.kind() {
            std::io::ErrorKind::ConnectionRefused => "connection refused".to_owned(),
            std::io::ErrorKind::TimedOut => {
                format!("no answer within {}s", CONNECT_TIMEOUT.as_secs())
            }
            _ => io.to_string(),
        };
    }
    let text = current.to_string();
    // Timeouts surface as a bare "timed out" from tower/hyper without an io::Error.
    if text.contains("timed out") { format!("no answer within {}s", CONNECT_TIMEOUT.as_secs()) } else { text }
}
