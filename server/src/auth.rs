//! Who may call what: the user service takes the user token, the pool service the pool token
//! (glissade_proto::auth). Health and reflection stay open (monitoring, grpcurl).

use glissade_proto::auth::{Token, presented};
use tonic::service::Interceptor;
use tonic::{Request, Status};

/// The tokens of a coordinator; none on a coordinator that listens on loopback only.
#[derive(Debug, Clone)]
pub struct Tokens {
    pub user: Token,
    pub pool: Token,
}

/// Checks the token of every request to one service.
#[derive(Debug, Clone)]
pub struct RequireToken {
    role: &'static str,
    accept: Option<Token>,
    /// the other role's token: presenting it is PERMISSION_DENIED, not UNAUTHENTICATED
    other: Option<(&'static str, Token)>,
}

impl RequireToken {
    pub fn users(tokens: Option<&Tokens>) -> Self {
        Self { role: "user", accept: tokens.map(|t| t.user.clone()), other: tokens.map(|t| ("pool", t.pool.clone())) }
    }

    pub fn pools(tokens: Option<&Tokens>) -> Self {
        Self { role: "pool", accept: tokens.map(|t| t.pool.clone()), other: tokens.map(|t| ("user", t.user.clone())) }
    }
}

impl Interceptor for RequireToken {
    fn call(&mut self, request: Request<()>) -> Result<Request<()>, Status> {
        let Some(accept) = &self.accept else { return Ok(request) };
        match presented(&request) {
            Some(t) if accept.matches(t) => Ok(request),
            Some(t) if self.other.as_ref().is_some_and(|(_, o)| o.matches(t)) => {
                let other = self.other.as_ref().map_or("other", |(r, _)| r);
                Err(Status::permission_denied(format!(
                    "a {other} token cannot call the {} service (it needs the {} token)",
                    self.role, self.role
                )))
            }
            Some(_) => Err(Status::unauthenticated(format!("wrong {} token", self.role))),
            None => Err(Status::unauthenticated(format!(
                "this coordinator needs a {} token (set GLISSADE_TOKEN or GLISSADE_TOKEN_FILE, or --token-file)",
                self.role
            ))),
        }
    }
}
