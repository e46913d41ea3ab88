//! `glissade surface`: a study's response surface as a table, CSV, JSON or PNG, with predictions
//! between its points (`--at`).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use glissade_cli::surface::{Predictions, SurfaceTable, parse_fixed};
use glissade_cli::{out, outln};
use glissade_core::scene::Scene;
use glissade_plot::study::Picture;
use glissade_plot::{self as plot};
use glissade_proto::v1;

use crate::{Server, fields, get_study, parse_size, refused, user};

#[derive(Debug, clap::Args)]
pub(crate) struct SurfaceArgs {
    /// The study id.
    pub(crate) study: u64,
    /// The quantity of interest (default: every QoI in the table; required for --png).
    #[arg(long, value_name = "NAME")]
    pub(crate) qoi: Option<String>,
    /// Keep only the points where a swept parameter has this value (repeatable): a slice.
    #[arg(long, value_name = "NAME=VALUE")]
    pub(crate) fix: Vec<String>,
    /// Every stored solution of the study's scene (any study), not only this study's points.
    #[arg(long)]
    pub(crate) all_solutions: bool,
    /// Write the surface as CSV to FILE ("-": stdout).
    #[arg(long, value_name = "FILE")]
    pub(crate) csv: Option<PathBuf>,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub(crate) json: bool,
    /// Draw the surface to a PNG file.
    #[arg(long, value_name = "FILE")]
    pub(crate) png: Option<PathBuf>,
    /// Picture size, WIDTHxHEIGHT in pixels (two panels side by side: the mean and its standard
    /// deviation).
    #[arg(long, value_name = "WxH", default_value = "1200x560", value_parser = parse_size)]
    pub(crate) size: (u32, u32),
    /// Predict the QoIs at this point, with a standard deviation (repeatable): a Gaussian process
    /// fitted to the surface's points, e.g. --at f1=0.137,f2=0.151
    #[arg(long, value_name = "NAME=VALUE,...")]
    pub(crate) at: Vec<String>,
}

/// Writes `text` to `path`, or to stdout for "-".
pub(crate) fn write_output(path: &Path, text: &str) -> Result<()> {
    if path == Path::new("-") {
        out!("{text}");
        return Ok(());
    }
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}

pub(crate) async fn surface(server: &Server, args: SurfaceArgs) -> Result<()> {
    let mut client = user(server).await?;
    // the scene's text for the units (the picture's axes; QoIs of one unit set their resolution)
    let study = get_study(&mut client, "surface", args.study, false, true).await?;
    let fixed = args.fix.iter().map(|f| parse_fixed(f, &study.parameters)).collect::<Result<Vec<_>, _>>()?;
    let source = if args.all_solutions {
        v1::query_surface_request::Source::SceneHash(study.scene_hash.clone())
    } else {
        v1::query_surface_request::Source::StudyId(study.study_id)
    };
    let swept = &study.parameters;
    let predict_at = args
        .at
        .iter()
        .map(|spec| Ok(v1::ParameterPoint { parameters: fields::parse_point("--at", spec, swept)?.into() }))
        .collect::<Result<Vec<_>>>()?;
    let reply = client
        .query_surface(v1::QuerySurfaceRequest {
            source: Some(source),
            fixed: fixed.iter().cloned().collect(),
            qoi: vec![],
            predict_at,
        })
        .await
        .map_err(|s| refused(&format!("surface {}", args.study), s))?
        .into_inner();
    if reply.points.is_empty() && !fixed.is_empty() {
        // no point in the slice: say which values there are, not that the QoI is unknown
        let all = get_study(&mut client, "surface", args.study, true, false).await?;
        let points: Vec<&std::collections::BTreeMap<String, f64>> = all.points.iter().map(|p| &p.parameters).collect();
        bail!("--fix: {}", glissade_core::study::space::slice_miss(&fixed, points));
    }
    let scene = Scene::parse(&study.scene).ok();
    let mut table = SurfaceTable::new(&reply, args.qoi.as_deref())?;
    if args.all_solutions {
        // Every parameter comes back; keep the study's swept ones as columns.
        table = table.restricted_to(&study.parameters);
    }
    if let Some(path) = &args.csv {
        write_output(path, &table.to_csv())?;
    }
    if let Some(path) = &args.png {
        let Some(qoi) = &args.qoi else {
            bail!("--png: say which QoI to draw with --qoi (one of {})", reply.qoi.join(", "))
        };
        let fixed_text = fixed.iter().map(|(n, v)| format!("{n}={v}")).collect::<Vec<_>>().join(", ");
        let title = format!(
            "study {}: {qoi}{}",
            args.study,
            if fixed_text.is_empty() { String::new() } else { format!(" at {fixed_text}") }
        );
        // the surface of `--at`, fitted here to the same points
        let rows: Vec<plot::study::Row> = reply.points.iter().map(|p| (&p.parameters, &p.qoi)).collect();
        let picture = Picture {
            scene: scene.as_ref(),
            names: &reply.parameters,
            swept: &study.parameters,
            fixed: &fixed,
            qoi,
            resolution: table.resolution[0],
            tolerance: study.tolerance,
            title,
        };
        let surface = picture.surface(&rows);
        plot::surface_png(path, &surface, args.size).with_context(|| format!("--png {}", path.display()))?;
        eprintln!("wrote {} ({}x{})", path.display(), args.size.0, args.size.1);
    }
    if !args.at.is_empty() {
        let mut predictions = Predictions::new(&reply, &table);
        predictions.norms =
            table.qoi.iter().filter(|q| scene.as_ref().is_some_and(|s| s.qoi_is_norm(q))).cloned().collect();
        if args.json {
            outln!("{}", predictions.to_json());
        } else {
            out!("{}", predictions.to_text());
        }
        return Ok(());
    }
    if args.json {
        outln!("{}", table.to_json());
    } else if args.csv.is_none() && args.png.is_none() {
        out!("{}", table.to_text());
    }
    Ok(())
}
