//! Bearer tokens: what a client sends (`authorization: Bearer <token>` metadata) and how the
//! coordinator compares it. Two roles, two tokens: users submit, watch and cancel studies; pools
//! lease and complete points. A token is read from `GLISSADE_TOKEN`, or from the file named by
//! `GLISSADE_TOKEN_FILE` (or a `--token-file` option), the same way by every client.

use std::path::Path;

use tonic::metadata::MetadataValue;
use tonic::service::Interceptor;
use tonic::{Request, Status};

/// Metadata key of a status that asks a pool to register again (its registration was lost, e.g.
/// the coordinator restarted): a typed signal, not a message to search.
pub const REGISTER_AGAIN: &str = "glissade-register-again";

/// Environment variable holding a token.
pub const TOKEN_ENV: &str = "GLISSADE_TOKEN";
/// Environment variable naming a file that holds a token.
pub const TOKEN_FILE_ENV: &str = "GLISSADE_TOKEN_FILE";
/// Shortest token accepted: 128 bits as hex (`openssl rand -hex 16`) or more.
pub const MIN_TOKEN_CHARS: usize = 32;
/// Longest token accepted (it travels in every request's metadata).
pub const MAX_TOKEN_CHARS: usize = 1024;

/// A secret token (never printed by Debug).
#[derive(Clone, PartialEq, Eq)]
pub struct Token(String);

impl std::fmt::Debug for Token {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Token(..)")
    }
}

#[derive(Debug, thiserror::Error)]
pub enum TokenError {
    #[error("cannot read the token file {path}: {source}")]
    Read { path: String, source: std::io::Error },
    #[error(
        "{origin}: a token is {MIN_TOKEN_CHARS} to {MAX_TOKEN_CHARS} printable ASCII characters without spaces, got {len} characters"
    )]
    Malformed { origin: String, len: usize },
}

impl Token {
    /// A token from text (surrounding whitespace and a final newline removed); `origin` names
    /// where it came from, for the error.
    pub fn parse(text: &str, origin: &str) -> Result<Self, TokenError> {
        let t = text.trim();
        let printable = t.bytes().all(|b| b.is_ascii_graphic());
        if !printable || !(MIN_TOKEN_CHARS..=MAX_TOKEN_CHARS).contains(&t.len()) {
            return Err(TokenError::Malformed { origin: origin.into(), len: t.chars().count() });
        }
        Ok(Self(t.to_owned()))
    }

    pub fn from_file(path: &Path) -> Result<Self, TokenError> {
        let text = std::fs::read_to_string(path)
            .map_err(|source| TokenError::Read { path: path.display().to_string(), source })?;
        Self::parse(&text, &format!("token file {}", path.display()))
    }

    /// The client's token: the file given, else `GLISSADE_TOKEN`, else the file named by
    /// `GLISSADE_TOKEN_FILE`, else none (a coordinator on loopback without tokens).
    pub fn for_client(file: Option<&Path>) -> Result<Option<Self>, TokenError> {
        if let Some(path) = file {
            return Self::from_file(path).map(Some);
        }
        if let Ok(text) = std::env::var(TOKEN_ENV) {
            return Self::parse(&text, TOKEN_ENV).map(Some);
        }
        match std::env::var_os(TOKEN_FILE_ENV) {
            Some(path) => Self::from_file(Path::new(&path)).map(Some),
            None => Ok(None),
        }
    }

    /// Compares in time independent of where the first difference is.
    pub fn matches(&self, presented: &str) -> bool {
        let (a, b) = (self.0.as_bytes(), presented.as_bytes());
        a.len() == b.len() && a.iter().zip(b).fold(0u8, |d, (x, y)| d | (x ^ y)) == 0
    }
}

/// The token presented by a request, if any.
pub fn presented<T>(request: &Request<T>) -> Option<&str> {
    request.metadata().get("authorization")?.to_str().ok()?.strip_prefix("Bearer ")
}

/// Adds the token (when there is one) to every request of a client.
#[derive(Clone, Debug, Default)]
pub struct WithToken(Option<MetadataValue<tonic::metadata::Ascii>>);

impl WithToken {
    pub fn new(token: Option<&Token>) -> Self {
        // Token::parse admits printable ASCII only, which is always a valid metadata value.
        Self(token.map(|t| format!("Bearer {}", t.0).parse().expect("printable ASCII")))
    }
}

impl Interceptor for WithToken {
    fn call(&mut self, mut request: Request<()>) -> Result<Request<()>, Status> {
        if let Some(v) = &self.0 {
            request.metadata_mut().insert("authorization", v.clone());
        }
        Ok(request)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_are_checked_and_compared_whole() {
        let t = Token::parse("0123456789abcdef0123456789abcdef\n", "test").unwrap();
        assert!(t.matches("0123456789abcdef0123456789abcdef"));
        assert!(!t.matches("0123456789abcdef0123456789abcdee"));
        assert!(!t.matches("0123456789abcdef0123456789abcdef0"));
        assert!(!t.matches(""));
        assert!(Token::parse("short", "test").unwrap_err().to_string().contains("32 to 1024"));
        assert!(Token::parse(&"a b".repeat(20), "test").is_err());
        assert_eq!(format!("{t:?}"), "Token(..)");
        let mut with = WithToken::new(Some(&t));
        let r = with.call(Request::new(())).unwrap();
        assert_eq!(presented(&r), Some("0123456789abcdef0123456789abcdef"));
    }
}

/// Environment variable naming the PEM file of the certificate authority that signed the
/// coordinator's certificate (for `https://` URLs; without it the system's roots are used).
pub const CA_CERT_ENV: &str = "GLISSADE_CA_CERT";

#[derive(Debug, thiserror::Error)]
pub enum EndpointError {
    #[error("invalid coordinator URL `{0}` (expected http://host:port or https://host:port)")]
    Url(String),
    #[error("cannot read the CA certificate {path}: {source}")]
    Ca { path: String, source: std::io::Error },
    #[error("TLS settings for {url}: {source}")]
    Tls { url: String, source: tonic::transport::Error },
}

/// A channel to `endpoint`. Boxed at this crate's edge so that the connection's machinery
/// (hyper, h2, rustls: the future's body and the tasks it spawns) is compiled once, here, and
/// not again in every crate that awaits a connection.
pub fn connect(
    endpoint: tonic::transport::Endpoint,
) -> std::pin::Pin<Box<dyn Future<Output = Result<tonic::transport::Channel, tonic::transport::Error>> + Send>> {
    Box::pin(async move { endpoint.connect().await })
}

/// The endpoint of a coordinator URL: plain for `http://`, TLS for `https://` (verified against
/// the CA file given, else `GLISSADE_CA_CERT`, else the system's roots).
pub fn endpoint(url: &str, ca_file: Option<&Path>) -> Result<tonic::transport::Endpoint, EndpointError> {
    use tonic::transport::{Certificate, ClientTlsConfig, Endpoint};
    let endpoint = Endpoint::from_shared(url.to_owned()).map_err(|_| EndpointError::Url(url.into()))?;
    // `Endpoint` accepts relative URIs such as `localhost:50051`; refuse them before connecting.
    let uri = endpoint.uri().clone();
    let Some(host) = uri.host() else { return Err(EndpointError::Url(url.into())) };
    match uri.scheme_str() {
        Some("http") => Ok(endpoint),
        Some("https") => {
            let ca = ca_file.map(Path::to_path_buf).or_else(|| std::env::var_os(CA_CERT_ENV).map(Into::into));
            let mut tls = ClientTlsConfig::new().domain_name(host.trim_start_matches('[').trim_end_matches(']'));
            tls = match ca {
                Some(path) => {
                    let pem = std::fs::read(&path)
                        .map_err(|source| EndpointError::Ca { path: path.display().to_string(), source })?;
                    tls.ca_certificate(Certificate::from_pem(pem))
                }
                None => tls.with_native_roots(),
            };
            endpoint.tls_config(tls).map_err(|source| EndpointError::Tls { url: url.into(), source })
        }
        _ => Err(EndpointError::Url(url.into())),
    }
}
