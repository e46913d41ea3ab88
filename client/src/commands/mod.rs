//! One module a command (`glissade COMMAND`); `demo` and `fields` stand beside this folder.

pub mod convergence;
pub mod health;
pub mod show;
pub mod studies;
pub mod submit;
pub mod surface;
pub mod watch;
