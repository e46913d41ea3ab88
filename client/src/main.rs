//! `glissade`: the command-line client of the glissade coordinator: submit design grids, watch
//! them run, read and plot response surfaces, fetch fields, or run everything locally (`demo`).

mod commands;
mod demo;
mod sibling;

use glissade_core::text::one_line;
use std::io::IsTerminal;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use glissade_plot as plot;
use tracing_subscriber::filter::{LevelFilter, Targets};
use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::util::SubscriberInitExt;

use commands::convergence::{ConvergenceArgs, convergence};
use commands::health::health;
use commands::show::{accuracy_line, discretisation_line, show, surface_accuracy_line, to_accuracy_lines};
use commands::studies::{cancel, purge_pool, retry, studies};
use commands::submit::{SubmitArgs, submit};
use commands::surface::{SurfaceArgs, surface};
use commands::watch::watch;
use glissade_cli::connect::{Server, User, connect, get_study, get_study_with_histories, refused, user};
use glissade_cli::fields;
use glissade_cli::fields::{FieldsArgs, ServerArgs};

/// Command-line client of glissade, a parametric-study service for transient dynamics with
/// contact and friction.
#[derive(Debug, Parser)]
#[command(
    version,
    after_help = "Examples:\n  \
      glissade demo                                  # everything on this machine, in a minute\n  \
      glissade submit scenes/three-blocks-tiny.toml --grid f1=0.1:0.2:11 --grid f2=0.1:0.2:11 --watch\n  \
      glissade watch 1\n  \
      glissade studies\n  \
      glissade surface 1 --qoi slip_A --png slip_A.png\n  \
      glissade surface 1 --qoi slip_A --fix f2=0.15 --csv slice.csv\n  \
      glissade convergence 1 --png convergence.png\n  \
      glissade fields 1 --point f1=0.12,f2=0.15 --out point.h5   # open point.xdmf in ParaView\n  \
      GLISSADE_SERVER=http://coordinator:50051 glissade health\n\n\
      Logs go to stderr; set RUST_LOG=debug for details."
)]
struct Cli {
    #[command(flatten)]
    server: ServerArgs,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Check that the coordinator is up, and print its status and version.
    Health {
        /// Print one JSON object instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Submit a parametric study of a scene; prints the study id (--watch: then follows it).
    #[command(after_help = "Examples:\n  \
        glissade submit scenes/three-blocks-small.toml --grid f1=0.10:0.20:11 --grid f2=0.10:0.20:11 --watch\n  \
        glissade submit scene.toml --grid f1=0.1,0.15,0.2 --grid v0=lhs:20:7 --tol 1e-4 --strategy linear --k 8\n  \
        glissade submit scene.toml --grid f1=0.1:0.2:5 --json | jq .study_id")]
    Submit(SubmitArgs),
    /// Follow a study until it ends: points done / running / pending, iterations cold vs warm,
    /// ETA; a summary at the end. Without a terminal, one plain line per event.
    Watch {
        /// The study id (from `glissade submit`).
        study: u64,
    },
    /// List the studies with their state and progress (also `glissade list`).
    #[command(visible_alias = "list")]
    Studies {
        /// Print the studies as one JSON array instead of a table: ListStudies' `Study` messages
        /// in the proto's JSON, as the web API's /api/studies serves them.
        #[arg(long)]
        json: bool,
        /// Also list the audits and the pilots' levels as rows of their own (else each is
        /// counted on its study's row).
        #[arg(long)]
        all: bool,
    },
    /// Show a study: its state, progress and (with --points) every design point.
    Show {
        /// The study id.
        study: u64,
        /// List every design point with its parameters, iterations, eta and QoIs.
        #[arg(long)]
        points: bool,
        /// Print one JSON object instead of text: the `Study` GetStudy returns (with --points,
        /// its points) in the proto's JSON, as the web API's /api/studies/ID serves it.
        #[arg(long)]
        json: bool,
    },
    /// Stop handing out a study's points (points being solved still finish and are kept).
    Cancel {
        /// The study id.
        study: u64,
    },
    /// Put a study's failed points back in the queue.
    Retry {
        /// The study id.
        study: u64,
    },
    /// Remove every stored solution a pool sent (no later point starts from one or is answered
    /// by one; the points it solved keep their results): for a pool no longer trusted.
    PurgePool {
        /// The pool's id, as it registered (`show --points` and the server's log name it).
        pool: String,
    },
    /// The response surface of a study: a table, CSV, JSON, or a PNG (a colour map with contour
    /// lines over two parameters, a curve over one).
    #[command(after_help = "Examples:\n  \
        glissade surface 3                                   # every QoI of every point, a table\n  \
        glissade surface 3 --qoi slip_A --png slip_A.png     # colour map over the two swept parameters\n  \
        glissade surface 3 --qoi slip_A --fix f2=0.15 --png slice.png --csv slice.csv   # a curve over f1\n  \
        glissade surface 3 --all-solutions --json            # every stored solution of the scene")]
    Surface(SurfaceArgs),
    /// The error indicator against the iterations of every point of a study (PNG or JSON).
    #[command(after_help = "Examples:\n  \
        glissade convergence 3 --png convergence.png\n  \
        glissade convergence 3 --json | jq '.points[0].eta_history | length'")]
    Convergence(ConvergenceArgs),
    /// The fields of one design point as HDF5 + XDMF (ParaView): displacement, velocity and
    /// stress, and the interfaces' contact pressure, gap and slip; re-solved here from the nearest
    /// stored solution of the study (a few iterations) by glissade-worker, which this runs.
    #[command(after_help = "Examples:\n  \
        glissade fields 3 --point f1=0.15,f2=0.15 --out p.h5          # a point of the study: 1 iteration a stage\n  \
        glissade fields 3 --point f1=0.123,f2=0.187 --out q.h5        # any point: from its nearest neighbour\n\n\
        Then open p.xdmf in ParaView (displacement, velocity and stress at every time step) and \
        p-interfaces.xdmf (contact pressure, gap and slip at the interfaces' nodes).")]
    Fields(FieldsArgs),
    /// Run a small study of the three-blocks scene on this machine, with no set-up: a coordinator
    /// (glissade-server) on a temporary database and one pool (glissade-worker), run beside this
    /// glissade, progress, the response surface and its pictures.
    #[command(after_help = "Examples:\n  \
        glissade demo\n  \
        glissade demo --grid 9 --out /tmp/demo     # 81 points")]
    Demo(demo::DemoArgs),
}

/// `900x700` -> (900, 700), within what a PNG viewer shows.
fn parse_size(text: &str) -> Result<(u32, u32), String> {
    let bad = || format!("`{text}`: expected WIDTHxHEIGHT in pixels, e.g. 900x700");
    let (w, h) = text.split_once(['x', 'X']).ok_or_else(bad)?;
    let (w, h): (u32, u32) = (w.trim().parse().map_err(|_| bad())?, h.trim().parse().map_err(|_| bad())?);
    let (min, max) = (plot::MIN_SIZE, plot::MAX_SIZE);
    if !(min.0..=max.0).contains(&w) || !(min.1..=max.1).contains(&h) {
        return Err(format!("`{text}`: from {}x{} to {}x{} pixels", min.0, min.1, max.0, max.1));
    }
    Ok((w, h))
}

/// Exit status of a command that ran: success, or "ran, but the study did not succeed".
enum Outcome {
    Success,
    StudyFailed,
    /// the exit status of the binary a command was handed to
    Exited(u8),
}

/// A parser error as every other error: one line on stderr, exit status 1 (clap's own is 2); its
/// usage without the options every command takes (`--server <URL>` read as required there).
fn argument_error(e: &clap::Error) -> String {
    let text = e.render().to_string();
    let usage = |line: &str| {
        ["--server <URL>", "--token-file <FILE>", "--ca-cert <FILE>"]
            .iter()
            .fold(line.to_owned(), |l, option| l.replace(&format!(" {option}"), ""))
    };
    let lines: Vec<String> =
        text.lines().map(|l| if l.trim_start().starts_with("Usage:") { usage(l) } else { l.to_owned() }).collect();
    one_line(&lines.join("\n"))
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        // --help and --version: on stdout, success
        Err(e) if !e.use_stderr() => {
            let _ = e.print();
            return ExitCode::SUCCESS;
        }
        // no command at all: the help, as a failure
        Err(e) if e.kind() == clap::error::ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand => {
            let _ = e.print();
            return ExitCode::FAILURE;
        }
        Err(e) => {
            eprintln!("{}", argument_error(&e));
            return ExitCode::FAILURE;
        }
    };
    // RUST_LOG as `target=level` directives (a filter without regular expressions to build)
    let filter = std::env::var("RUST_LOG")
        .ok()
        .and_then(|v| v.parse::<Targets>().ok())
        .unwrap_or_else(|| Targets::new().with_default(LevelFilter::WARN));
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .finish()
        .with(filter)
        .init();
    let result = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the tokio runtime")
        .and_then(|rt| rt.block_on(run(cli)));
    match result {
        Ok(Outcome::Success) => ExitCode::SUCCESS,
        Ok(Outcome::StudyFailed) => ExitCode::from(2),
        Ok(Outcome::Exited(code)) => ExitCode::from(code),
        Err(e) => {
            // A CLI user wants one readable line, not a Debug dump or a backtrace.
            let message = format!("{e:#}");
            eprintln!("error: {}", one_line(&message));
            ExitCode::FAILURE
        }
    }
}

async fn run(cli: Cli) -> Result<Outcome> {
    let server = &cli.server.server()?;
    let done = |r: Result<()>| r.map(|()| Outcome::Success);
    match cli.command {
        Command::Health { json } => done(health(server, json).await),
        Command::Submit(args) => submit(server, args).await,
        Command::Watch { study } => {
            let mut client = user(server).await?;
            watch(&mut client, study).await
        }
        Command::Studies { json, all } => done(studies(server, json, all).await),
        Command::Show { study, points, json } => done(show(server, study, points, json).await),
        Command::Cancel { study } => done(cancel(server, study).await),
        Command::PurgePool { pool } => done(purge_pool(server, &pool).await),
        Command::Retry { study } => done(retry(server, study).await),
        Command::Surface(args) => done(surface(server, args).await),
        Command::Convergence(args) => done(convergence(server, args).await),
        // (the re-solve needs the solver and HDF5: glissade-worker has them)
        Command::Fields(args) => {
            let handed = [vec!["fields".into()], args.to_args(), cli.server.to_args()].concat();
            sibling::run("glissade-worker", &handed, "glissade fields").await
        }
        Command::Demo(args) => demo::demo(args).await,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `glissade list` is what a newcomer types first: it lists the studies, and a mistyped
    /// command gets clap's suggestion.
    #[test]
    fn list_is_the_studies_command() {
        let cli = Cli::try_parse_from(["glissade", "list", "--json"]).expect("list parses");
        assert!(matches!(cli.command, Command::Studies { json: true, all: false }));
        let err = Cli::try_parse_from(["glissade", "studes"]).unwrap_err().to_string();
        assert!(err.contains("studies"), "{err}");
    }
}
