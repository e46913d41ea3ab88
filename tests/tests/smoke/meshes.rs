//! Scenes with Gmsh mesh bodies through the service: the files travel with the submission, the
//! coordinator keeps them across a restart, pools fetch them; wrong or oversize files are refused.

use crate::common::*;

/// Two tetrahedral blocks of `solver/tests/data/bar-tet.msh` glued, the top pressed by `p`.
const MESHED_BAR: &str = r#"
dimension = 3
[time]
duration = 4e-5
steps = 40
[parameters]
p = { default = 5e7, unit = "Pa" }
[materials.steel]
E = 200e9
nu = 0.3
rho = 7800
[[bodies]]
name = "lower"
material = "steel"
mesh = { file = "bar.msh", volume = "lower" }
substructures = 2
[[bodies]]
name = "upper"
material = "steel"
mesh = { file = "bar.msh", volume = "upper" }
substructures = 2
[[interfaces]]
name = "joint"
a = "lower.joint"
b = "upper.joint"
law = "perfect"
[[boundary]]
face = "lower.base"
clamped = true
[[loads]]
face = "upper.top"
pressure = "p"
history = [[0, 0], [5e-6, 1], [1e-5, 0]]
[[qoi]]
name = "top_uz"
kind = "displacement"
body = "upper"
point = [0.02, 0.02, 0.04]
component = "z"
"#;

fn mesh_bytes() -> Vec<u8> {
    std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("../solver/tests/data/bar-tet.msh")).expect("test mesh")
}

/// The scene and its mesh in `dir`: the path of the scene file.
fn write_scene(dir: &Path) -> std::path::PathBuf {
    std::fs::write(dir.join("bar.msh"), mesh_bytes()).expect("write mesh");
    let scene = dir.join("bar.toml");
    std::fs::write(&scene, MESHED_BAR).expect("write scene");
    scene
}

/// `glissade submit` sends the mesh; the study hashes as the scene read locally; the coordinator,
/// killed and restarted before any pool came, still has the mesh; a pool of two ranks fetches it
/// and solves each point as `glissade-worker solve` does here.
#[test]
fn a_meshed_scene_travels_with_its_files_and_survives_a_restart() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let scene = write_scene(dir.path());
    let data = dir.path().join("db");
    let (mut server, addr) = start_server(&data, &dir.path().join("server.log"));
    let url = format!("http://{addr}");
    let scene_arg = scene.to_str().expect("utf-8 path");
    let out =
        glissade(Some(&url), &["submit", scene_arg, "--grid", "p=4e7,6e7", "--tol", "1e-4", "--audit", "0", "--json"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let reply: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    let local = glissade_core::scene::Scene::read(&scene)?;
    assert_eq!(reply["scene_hash"].as_str(), Some(local.content_hash().as_str()), "{reply}");
    let id = reply["study_id"].to_string();

    // SIGKILL: only what was committed survives
    server.0.kill()?;
    server.0.wait()?;
    drop(server);
    let (_server, addr) = start_server(&data, &dir.path().join("server2.log"));
    let url = format!("http://{addr}");
    let pool_log = dir.path().join("pool.log");
    let _pool = start_pool(&url, "meshes", &pool_log);
    let out = glissade(Some(&url), &["watch", &id]);
    assert!(
        out.status.success(),
        "{}\npool log:\n{}",
        text(&out.stderr),
        std::fs::read_to_string(&pool_log).unwrap_or_default()
    );
    let out = glissade(Some(&url), &["show", &id, "--points", "--json"]);
    let shown: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    assert_eq!(shown["progress"]["done"], 2, "{shown}");
    // the first point starts cold, as a direct solve of it does: the same numbers
    let first =
        shown["points"].as_array().expect("points").iter().find(|p| p["parameters"]["p"] == 4e7).expect("p=4e7");
    let direct =
        worker_solve(dir.path(), &[os("bar.toml"), os("--set"), os("p=4e7"), os("--tol"), os("1e-4"), os("--json")]);
    let direct = converged_json(&direct);
    let (service, local) =
        (first["qoi"]["top_uz"].as_f64().unwrap(), direct["qoi"]["top_uz"]["final"].as_f64().unwrap());
    assert!((service - local).abs() <= 1e-12 * local.abs(), "service {service}, direct {local}");
    assert!(service.abs() > 0.0);

    // the fields of a point: the meshes come from the user's directory, checked by the hash
    let h5 = dir.path().join("point.h5");
    let h5_arg = h5.to_str().expect("utf-8 path");
    let fields = |extra: &[&str]| {
        let mut args = vec!["fields", &id, "--point", "p=6e7", "--out", h5_arg];
        args.extend_from_slice(extra);
        glissade(Some(&url), &args)
    };
    assert_one_line_error(&fields(&[]), "give --meshes DIR, where bar.msh are");
    let other = dir.path().join("other");
    std::fs::create_dir(&other)?;
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../solver/tests/data/bar-hex.msh"),
        other.join("bar.msh"),
    )?;
    assert_one_line_error(&fields(&["--meshes", other.to_str().unwrap()]), "are not the study's");
    let out = fields(&["--meshes", dir.path().to_str().unwrap()]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(h5.exists());
    Ok(())
}

/// A client that sends what the CLI would not: each wrong set of files is INVALID_ARGUMENT naming
/// the file, a message over the bound is refused while decoding, and the coordinator still serves.
#[test]
fn wrong_or_oversize_mesh_files_are_refused_by_name() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let (_server, addr) = start_server(&dir.path().join("db"), &dir.path().join("server.log"));
    let url = format!("http://{addr}");
    let rt = runtime();
    rt.block_on(async {
        let mut client = user(&url).await?;
        let request = |meshes: Vec<v1::MeshFile>| v1::SubmitStudyRequest {
            scene: MESHED_BAR.into(),
            grid: vec!["p=5e7".into()],
            meshes,
            ..Default::default()
        };
        let mesh =
            |file: &str, data: Vec<u8>, sha256: &str| v1::MeshFile { file: file.into(), data, sha256: sha256.into() };
        let good = mesh_bytes();
        let digest = glissade_core::scene::mesh_digest(&good);
        let bound = glissade_core::scene::MAX_MESH_FILE_BYTES as usize;
        let cases = [
            (vec![], "mesh file 'bar.msh' is named by the scene but was not given".to_string()),
            (
                vec![mesh("bar.msh", good.clone(), ""), mesh("/etc/passwd", vec![1], "")],
                "mesh file '/etc/passwd' was given but the scene names no such file".into(),
            ),
            (
                vec![mesh("bar.msh", good.clone(), &"0".repeat(64))],
                format!("mesh file 'bar.msh': its bytes have SHA-256 {digest}, {} was announced", "0".repeat(64)),
            ),
            (
                vec![mesh("bar.msh", good.clone(), ""), mesh("bar.msh", good.clone(), "")],
                "mesh file 'bar.msh' was given twice".into(),
            ),
            (
                vec![mesh("bar.msh", b"$MeshFormat\n4.1 0 8\n$EndMeshFormat\n".to_vec(), "")],
                "bar.msh: no physical volume 'lower'".into(),
            ),
            (
                vec![mesh("bar.msh", vec![0; bound + 1], "")],
                format!("{} bytes, more than the {bound} allowed", bound + 1),
            ),
        ];
        for (meshes, expected) in cases {
            let status = client.submit_study(request(meshes)).await.expect_err("must be refused");
            assert_eq!(status.code(), Code::InvalidArgument, "{status:?}");
            assert!(status.message().contains(&expected), "expected {expected}, got {}", status.message());
        }
        // over the message bound (128 MiB of meshes + 4 MiB): refused as it is decoded
        let half = vec![0u8; bound / 2 + (3 << 20)];
        let status = client
            .submit_study(request(vec![mesh("bar.msh", half.clone(), ""), mesh("other.msh", half, "")]))
            .await
            .expect_err("must be refused");
        assert!(status.message().contains("too large"), "{status:?}");
        // the coordinator is unharmed, has stored nothing, and takes a proper submission
        let studies = client.list_studies(v1::ListStudiesRequest::default()).await?.into_inner().studies;
        assert!(studies.is_empty(), "{studies:?}");
        let reply = client.submit_study(request(vec![mesh("bar.msh", good, &digest)])).await?.into_inner();
        assert_eq!(reply.points, 1);
        anyhow::Ok(())
    })?;
    Ok(())
}
