//! The service's other binaries, which the CLI hands work to instead of linking what they link
//! (the solver, HDF5, MPI, the coordinator's database): `glissade-worker` re-solves a point for
//! `fields`, and `demo` runs `glissade-server` and a `glissade-worker` pool as a deployment does.

use std::ffi::OsString;
use std::path::PathBuf;

use anyhow::{Context, Result, bail};

use crate::Outcome;

/// Where binary `name` is: beside this `glissade` (as `cargo build` and `cargo install` put
/// them), else on the PATH.
pub fn find(name: &str) -> Result<PathBuf> {
    let here = std::env::current_exe().ok().and_then(|exe| Some(exe.parent()?.join(name)));
    if let Some(path) = here.filter(|p| p.is_file()) {
        return Ok(path);
    }
    let on_path = std::env::var_os("PATH")
        .and_then(|paths| std::env::split_paths(&paths).map(|dir| dir.join(name)).find(|p| p.is_file()));
    match on_path {
        Some(path) => Ok(path),
        None => bail!(
            "{name} is neither beside this glissade nor on the PATH: build it (cargo build --release builds every \
             binary of the workspace) or install it where glissade is"
        ),
    }
}

/// Runs `name` with `args`, its output this command's, and ends with its exit status.
pub async fn run(name: &str, args: &[OsString], command: &str) -> Result<Outcome> {
    let path = find(name).with_context(|| command.to_owned())?;
    let mut child = tokio::process::Command::new(&path);
    child.args(args).kill_on_drop(true);
    let status = child.status().await.with_context(|| format!("{command}: running {}", path.display()))?;
    Ok(match status.code() {
        Some(0) => Outcome::Success,
        Some(code) => Outcome::Exited(u8::try_from(code).unwrap_or(1)),
        None => bail!("{command}: {} was stopped by a signal", path.display()),
    })
}
