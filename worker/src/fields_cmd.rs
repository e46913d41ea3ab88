//! `glissade-worker fields` (what `glissade fields` runs): the full fields of one design point,
//! re-solved on this machine from the study's nearest stored solution (the same point's own
//! solution when it is done: then the solve converges at once) and written as HDF5 + XDMF for
//! ParaView.

use glissade_cli::outln;
use glissade_core::point::DesignPoint;
use std::collections::BTreeMap;

use anyhow::{Context, Result, anyhow, bail};
use glissade_core::io::solution_file;
use glissade_core::scene::{Scene, Tolerance};
use glissade_core::study::space::ParameterSpace;
use glissade_core::text::same_parameter;
use glissade_proto::Assembler;
use glissade_proto::v1;
use glissade_solver::run::{SolveRequest, solve_scene};
use glissade_worker::io::fields;

use glissade_cli::connect::{User, get_study, refused};
use glissade_cli::fields::{FieldsArgs, parse_point};
use glissade_cli::names::describe_parameters;

/// Largest solution file accepted from the coordinator (a paper-size scene's is about 100 MB).
const MAX_SOLUTION_BYTES: u64 = 4 << 30;

/// The done point of `study` nearest to `target`, in the scene's normalised parameter space (the
/// distance the coordinator's warm starts use).
fn nearest_done<'a>(scene: &Scene, study: &'a v1::Study, target: &DesignPoint) -> Option<&'a v1::PointStatus> {
    let space = ParameterSpace::from_scene(scene);
    // (a point the coordinator sent that is no design point is no start)
    let distance = |p: &v1::PointStatus| {
        DesignPoint::try_from(p.parameters.clone()).map_or(f64::INFINITY, |p| space.normalised_distance(&p, target))
    };
    let done = study.points.iter().filter(|p| p.state == v1::PointState::Done as i32);
    done.min_by(|a, b| distance(a).total_cmp(&distance(b)))
}

pub async fn fields(client: &mut User, args: FieldsArgs) -> Result<()> {
    if fields::xdmf_path(&args.out) == args.out {
        bail!("--out {}: give the HDF5 file (e.g. point.h5); the .xdmf file is written beside it", args.out.display());
    }
    let study = get_study(client, "fields", args.study, true, true).await?;
    let target = parse_point("--point", &args.point, &study.parameters)?;
    let mut scene = Scene::parse(&study.scene).context("the study's scene")?;
    if !scene.mesh_files().is_empty() {
        let dir = args.meshes.as_ref().ok_or_else(|| {
            let files: Vec<&str> = scene.mesh_files().into_iter().collect();
            anyhow!(
                "study {}: its scene has mesh bodies: give --meshes DIR, where {} are",
                args.study,
                files.join(", ")
            )
        })?;
        scene.attach_meshes(dir).with_context(|| format!("--meshes {}", dir.display()))?;
        if scene.content_hash() != study.scene_hash {
            bail!(
                "--meshes {}: these mesh files are not the study's (scene hash {}, the study's {})",
                dir.display(),
                scene.content_hash(),
                study.scene_hash
            );
        }
    }
    let from = nearest_done(&scene, &study, &target)
        .ok_or_else(|| anyhow!("study {}: no point is done yet, nothing to start from", args.study))?;
    let key = v1::PointKey { study_id: study.study_id, point_id: from.point_id };
    let mut stream = client
        .fetch_solution(v1::FetchSolutionRequest { solution: Some(v1::fetch_solution_request::Solution::Point(key)) })
        .await
        .map_err(|s| refused(&format!("solution of point {}", from.point_id), s))?
        .into_inner();
    let mut assembler: Option<Assembler> = None;
    while let Some(chunk) = stream.message().await.map_err(|s| refused("fetching the solution", s))? {
        let assembler = match &mut assembler {
            Some(a) => a,
            None => assembler.insert(Assembler::new(chunk.total_bytes, MAX_SOLUTION_BYTES)?),
        };
        assembler.push(chunk).context("fetching the solution")?;
    }
    let bytes = assembler.map_or(Ok(Vec::new()), Assembler::finish).context("fetching the solution")?;
    let (meta, init) = solution_file::read_from(&bytes[..]).context("the stored solution")?;
    meta.check_fits(&scene).context("the stored solution")?;
    // the point's own converged solution: one linear stage gives its fields, nothing to iterate
    let own = target.iter().all(|(k, v)| from.parameters.get(k).is_some_and(|&x| same_parameter(x, v)))
        && meta.converged
        && meta.error_indicator <= study.tolerance;
    let request = SolveRequest {
        point: target.clone(),
        tolerance: Some(Tolerance::new("the study's tolerance", study.tolerance)?),
        max_iterations: Some(if own { 1 } else { study.max_iterations as usize }),
        scale: None,
        record_fields: true,
        init_parameters: Some(meta.parameters.clone()),
        progress: None,
    };
    let out = args.out.clone();
    let scene_hash = study.scene_hash.clone();
    // The solve is seconds of CPU: off the async threads.
    let (summary, xdmf) = tokio::task::spawn_blocking(move || -> Result<_> {
        let outcome = solve_scene(&scene, &request, Some(&init))?;
        let fields = outcome.fields.as_ref().ok_or_else(|| anyhow!("the solver returned no fields"))?;
        let xdmf = fields::write(&out, fields, &scene_hash).with_context(|| format!("--out {}", out.display()))?;
        Ok((outcome.summary, xdmf))
    })
    .await
    .context("the solve panicked")??;
    if !summary.converged && !own {
        bail!(
            "the re-solve did not converge: eta = {:.3e} > {:.1e} after {} iterations",
            summary.error_indicator,
            summary.tolerance,
            summary.iterations
        );
    }
    let from_text = describe_parameters(&from.parameters);
    if args.json {
        let value = serde_json::json!({
            "parameters": target,
            "started_from": { "point_id": from.point_id, "parameters": from.parameters },
            "iterations": summary.iterations,
            "dynamic_iterations": summary.history.len(),
            "error_indicator": summary.error_indicator,
            "qoi": summary.qoi.iter().map(|(k, q)| (k.clone(), q.final_value)).collect::<BTreeMap<_, _>>(),
            "h5": args.out,
            "xdmf": xdmf,
        });
        outln!("{value}");
    } else {
        let from_text = if own {
            format!("its own stored solution, point #{} (converged at eta {:.2e})", from.point_id, meta.error_indicator)
        } else {
            format!("stored point #{} ({from_text})", from.point_id)
        };
        let dynamic = summary.history.len();
        let statics = summary.iterations - dynamic;
        outln!(
            "point {}: {dynamic} iteration{} of the dynamic stage{} from {from_text}, eta {:.2e}",
            target,
            if dynamic == 1 { "" } else { "s" },
            if statics > 0 { format!(" (and {statics} of the static one)") } else { String::new() },
            summary.error_indicator
        );
        outln!("wrote {} and {} (open the .xdmf in ParaView)", args.out.display(), xdmf.display());
    }
    Ok(())
}
