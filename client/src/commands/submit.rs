//! `glissade submit`: a scene and its grid (or list, or adaptive box), checked here as the
//! coordinator will, then sent; `--watch` follows it.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, anyhow};
use glissade_cli::outln;
use glissade_core::scene::{Scene, Tolerance};
use glissade_core::study::order::OrderKind;
use glissade_core::study::strategy::StrategyKind;
use glissade_proto::v1;

use super::watch::watch;
use crate::{Outcome, Server, refused, user};

#[derive(Debug, clap::Args)]
#[command(group(clap::ArgGroup::new("adaptive_kind").args(["adaptive", "surface_accuracy"]).multiple(true)))]
pub(crate) struct SubmitArgs {
    /// Scene file (TOML); its text is sent to the coordinator.
    pub(crate) scene: PathBuf,
    /// A swept parameter, NAME=START:STOP:COUNT, NAME=V1,V2,... or NAME=lhs:N:SEED (repeatable;
    /// the study is the product of the grids).
    #[arg(long, value_name = "NAME=SPEC", required_unless_present_any = ["adaptive", "range"], conflicts_with = "adaptive_kind")]
    pub(crate) grid: Vec<String>,
    /// An adaptive study of N points instead of a grid: the first spread over the --range box,
    /// then each where the response surface is least sure (docs/surrogate.md)
    #[arg(long, value_name = "N", requires = "range")]
    pub(crate) adaptive: Option<u32>,
    /// The box of an adaptive study, NAME=LOW:HIGH (repeatable, one per swept parameter)
    #[arg(long, value_name = "NAME=LOW:HIGH", requires = "adaptive_kind")]
    pub(crate) range: Vec<String>,
    /// An adaptive study over the --range box that adds points until the largest error anywhere
    /// in the box, as every QoI's surface estimates it, is within this share of the QoI's spread (0.02: 2 %), or its
    /// budget (--adaptive N; default 100) is spent, and says which (`glissade show`); its points
    /// are solved to --tol, default this / 300 (docs/surrogate.md, "Adaptive to a target")
    #[arg(long, value_name = "SHARE", requires = "range")]
    pub(crate) surface_accuracy: Option<f64>,
    /// An adaptive study chooses no point once its points' work (dynamic iterations + static
    /// iterations / steps, summed: `show --points`) reaches W; with a target it then ends NOT
    /// REACHED (the points in flight finish): e.g. the work of the grid it replaces
    #[arg(long, value_name = "W", requires = "range")]
    pub(crate) work_budget: Option<f64>,
    /// Solve the study to this accuracy (0.05: every QoI within 5 % of its scale): pilot points
    /// solved on ladders of time steps and meshes choose dt, h and the tolerance (A / 50) first,
    /// then the grid is solved there (docs/accuracy.md, "A study to an accuracy")
    #[arg(long, value_name = "A", conflicts_with_all = ["tol", "adaptive_kind", "refine", "refine_mesh", "audit", "surface_audit"])]
    pub(crate) accuracy: Option<f64>,
    /// With --accuracy: how many pilots (the box's centre, then its corners; 1 to 16)
    #[arg(long, value_name = "N", requires = "accuracy")]
    pub(crate) pilots: Option<u32>,
    /// Tolerance on the error indicator (default: the scene's).
    #[arg(long, value_name = "T")]
    pub(crate) tol: Option<f64>,
    /// Iteration limit per point (default: the scene's).
    #[arg(long, value_name = "N")]
    pub(crate) max_iter: Option<u32>,
    /// Where each point's iterations start (default: linear, a fit of the solved neighbours).
    #[arg(long, value_enum)]
    pub(crate) strategy: Option<StrategyKind>,
    /// Neighbours a blend (or a linear fit) combines (default: 3).
    #[arg(long, value_name = "K", default_value_t = 0, hide_default_value = true)]
    pub(crate) k: u32,
    /// Which pending point goes to the next free pool.
    #[arg(long, value_enum, default_value = "greedy")]
    pub(crate) order: OrderKind,
    /// Free text shown with the study.
    #[arg(long, default_value = "")]
    pub(crate) label: String,
    /// Points re-solved cold at 1/100 of the tolerance when pools are idle, to measure the
    /// accuracy the study got (`glissade show`); default: 10 % of the points, at least 2; 0: none
    #[arg(long, value_name = "N")]
    pub(crate) audit: Option<u32>,
    /// Points re-solved cold with the time step halved when pools are idle, to measure the
    /// discretisation error beside the iterations' (`glissade show`); default: 2; 0: none; at
    /// most 8
    #[arg(long, value_name = "N")]
    pub(crate) refine: Option<u32>,
    /// Levels of that discretisation audit, the study's own included: 2 (dt / 2, order 2
    /// assumed) or 3 (dt / 2 and dt / 4, order observed)
    #[arg(long, value_name = "2|3", default_value_t = 2)]
    pub(crate) refine_levels: u32,
    /// Those points also re-solved cold on the mesh refined once (box bodies: elements x 2 along
    /// each axis; about 2^dim x a point or more): the mesh's error beside the time step's
    #[arg(long)]
    pub(crate) refine_mesh: bool,
    /// Points held out of the study's response surface (random in its box), solved cold at 1/100
    /// of the tolerance when pools are idle, against the surface's predictions made before: how
    /// good the surface is between the points (`glissade show`); default: 5 % of the points, at
    /// least 5, at most a quarter; 0: none
    #[arg(long, value_name = "N")]
    pub(crate) surface_audit: Option<u32>,
    /// Follow the study until it ends (as `glissade watch`).
    #[arg(long)]
    pub(crate) watch: bool,
    /// Print one JSON object instead of the study id (not with --watch: its lines are for people).
    #[arg(long, conflicts_with = "watch")]
    pub(crate) json: bool,
}

/// Reads a scene file and the mesh files it names (next to it), as `glissade-worker solve` does.
pub(crate) fn read_scene(path: &Path) -> Result<(String, Scene)> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read scene {}", path.display()))?;
    let mut scene = Scene::parse(&text).with_context(|| format!("scene {}", path.display()))?;
    scene.attach_meshes(path.parent().unwrap_or(Path::new(""))).with_context(|| format!("scene {}", path.display()))?;
    Ok((text, scene))
}

pub(crate) async fn submit(server: &Server, args: SubmitArgs) -> Result<Outcome> {
    // checked as the coordinator will, before connecting
    let tolerance = args.tol.map(|t| Tolerance::new("--tol", t)).transpose()?;
    if let Some(a) = args.accuracy {
        glissade_core::refine::Accuracy::new("--accuracy", a)?;
    }
    let (scene, parsed) = read_scene(&args.scene)?;
    if args.adaptive.is_some() || args.surface_accuracy.is_some() {
        let space = glissade_core::study::space::ParameterSpace::from_scene(&parsed);
        let budget = args.adaptive.map_or(glissade_core::study::adaptive::TARGET_BUDGET, |n| n as usize);
        glissade_core::study::adaptive::AdaptiveDesign::parse(
            &args.range,
            budget,
            args.surface_accuracy,
            &space,
            glissade_core::study::space::DEFAULT_MAX_POINTS,
        )
        .map_err(|e| anyhow!("--range / --adaptive / --surface-accuracy: {e}"))?;
        if let Some(w) = args.work_budget.filter(|w| !(w.is_finite() && *w > 0.0)) {
            return Err(anyhow!("--work-budget {w}: must be a finite number above 0"));
        }
    } else {
        glissade_core::study::space::check_grid(&parsed, &args.grid).map_err(|e| anyhow!("--grid: {e}"))?;
    }
    // the mesh files travel with the scene, each with its digest (the coordinator checks both)
    let meshes = parsed
        .meshes
        .iter()
        .map(|(file, bytes)| v1::MeshFile {
            file: file.clone(),
            data: bytes.to_vec(),
            sha256: parsed.mesh_digests[file].clone(),
        })
        .collect();
    let request = v1::SubmitStudyRequest {
        scene,
        meshes,
        ranges: args.range,
        adaptive_points: args.adaptive.unwrap_or(0),
        grid: args.grid,
        points: Vec::new(),
        tolerance: tolerance.map(Tolerance::get),
        // none named: the coordinator's default (core's StrategyKind::DEFAULT)
        strategy: match args.strategy {
            None => v1::InitStrategy::Unspecified,
            Some(StrategyKind::Cold) => v1::InitStrategy::Cold,
            Some(StrategyKind::Previous) => v1::InitStrategy::Previous,
            Some(StrategyKind::Nearest) => v1::InitStrategy::Nearest,
            Some(StrategyKind::Blend) => v1::InitStrategy::Blend,
            Some(StrategyKind::Linear) => v1::InitStrategy::Linear,
        }
        .into(),
        order: match args.order {
            OrderKind::Asc => v1::PointOrder::Ascending,
            OrderKind::Desc => v1::PointOrder::Descending,
            OrderKind::Greedy => v1::PointOrder::Greedy,
        }
        .into(),
        max_iterations: args.max_iter,
        label: args.label,
        blend_neighbours: args.k,
        audit_points: args.audit,
        refine_points: args.refine,
        refine_levels: args.refine_levels,
        refine_mesh: args.refine_mesh,
        surface_audit_points: args.surface_audit,
        surface_accuracy: args.surface_accuracy,
        work_budget: args.work_budget,
        accuracy: args.accuracy,
        accuracy_pilots: args.pilots,
    };
    let mut client = user(server).await?;
    let reply = client
        .submit_study(request)
        .await
        .map_err(|s| refused(&format!("submit {}", args.scene.display()), s))?
        .into_inner();
    if args.json {
        let value = serde_json::json!({
            "study_id": reply.study_id,
            "points": reply.points,
            "scene_hash": reply.scene_hash,
        });
        outln!("{value}");
    } else if args.watch {
        let adaptive = args.adaptive.is_some() || args.surface_accuracy.is_some();
        outln!("{}", submitted_line(reply.study_id, reply.points, adaptive));
    } else {
        outln!("{}", reply.study_id);
    }
    if args.watch { watch(&mut client, reply.study_id).await } else { Ok(Outcome::Success) }
}

/// What `submit --watch` says first: an adaptive study's count is its budget, which it may not
/// spend (issue 47: "submitted: 20 points", then 17 of 17 shown).
fn submitted_line(study: u64, points: u32, adaptive: bool) -> String {
    if adaptive {
        format!("study {study} submitted: up to {points} points, chosen as it goes")
    } else {
        format!("study {study} submitted: {points} points")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_adaptive_study_says_its_count_is_a_budget() {
        assert_eq!(submitted_line(3, 9, false), "study 3 submitted: 9 points");
        assert_eq!(submitted_line(4, 20, true), "study 4 submitted: up to 20 points, chosen as it goes");
    }
}
