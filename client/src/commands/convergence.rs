//! `glissade convergence`: the error indicator against the iterations of every point (PNG, JSON).

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use glissade_cli::names::{describe_parameters, point_state_name};
use glissade_cli::outln;
use glissade_plot::{self as plot, ConvergenceSeries};

use crate::{Server, get_study_with_histories, parse_size, user};

#[derive(Debug, clap::Args)]
pub(crate) struct ConvergenceArgs {
    /// The study id.
    pub(crate) study: u64,
    /// Draw eta against the iterations of every point to a PNG file.
    #[arg(long, value_name = "FILE")]
    pub(crate) png: Option<PathBuf>,
    /// Print every point's history as JSON.
    #[arg(long)]
    pub(crate) json: bool,
    /// Picture size, WIDTHxHEIGHT in pixels.
    #[arg(long, value_name = "WxH", default_value = "900x600", value_parser = parse_size)]
    pub(crate) size: (u32, u32),
}

pub(crate) async fn convergence(server: &Server, args: ConvergenceArgs) -> Result<()> {
    if args.png.is_none() && !args.json {
        bail!("say where the histories go: --png FILE and/or --json");
    }
    let mut client = user(server).await?;
    let study = get_study_with_histories(&mut client, "convergence", args.study).await?;
    let series: Vec<ConvergenceSeries> = study
        .points
        .iter()
        .filter(|p| !p.eta_history.is_empty())
        .map(|p| ConvergenceSeries {
            label: format!("#{} {}", p.point_id, describe_parameters(&p.parameters)),
            history: p.eta_history.clone(),
        })
        .collect();
    if let Some(path) = &args.png {
        if series.is_empty() {
            bail!(
                "study {}: no point has iterated yet (or every point was answered from a stored solution)",
                args.study
            );
        }
        let title = format!("study {}: error indicator of the dynamic stage", args.study);
        plot::convergence_png(path, &series, Some(study.tolerance), &title, args.size)
            .with_context(|| format!("--png {}", path.display()))?;
        eprintln!("wrote {} ({} points, {}x{})", path.display(), series.len(), args.size.0, args.size.1);
    }
    if args.json {
        let points: Vec<serde_json::Value> = study
            .points
            .iter()
            .map(|p| {
                serde_json::json!({
                    "point_id": p.point_id,
                    "parameters": p.parameters,
                    "state": point_state_name(p.state),
                    "started_from": p.started_from.as_ref().map(|f| &f.parameters),
                    "eta_history": p.eta_history,
                })
            })
            .collect();
        outln!("{}", serde_json::json!({ "study_id": study.study_id, "tolerance": study.tolerance, "points": points }));
    }
    Ok(())
}
