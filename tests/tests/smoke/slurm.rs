//! The Slurm batch files under a real Slurm: a one-node cluster on this machine
//! (deploy/slurm/one-node-cluster.sh), the coordinator and a pool array as Slurm jobs, studies
//! through the published URL, a pool cancelled mid-point and one ending idle. Root only (the
//! daemons run as root); skipped elsewhere or without slurm-wlm and munge.

use crate::common::*;
use std::path::PathBuf;
use std::time::Instant;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn on_path(tool: &str) -> bool {
    std::env::var_os("PATH")
        .is_some_and(|p| std::env::split_paths(&p).any(|d| d.join(tool).is_file() || d.join(tool).is_symlink()))
        || ["/usr/sbin", "/sbin"].iter().any(|d| Path::new(d).join(tool).exists())
}

fn is_root() -> bool {
    let out = run_with_timeout(Command::new("id").arg("-u"), LIMIT);
    text(&out.stdout).trim() == "0"
}

/// The one-node cluster of a test: started by `start`, stopped (every job cancelled, the daemons
/// ended, its directory removed) when dropped, a failed test included. It holds a child token
/// all along (the daemons are the test's processes, see `child_token`) and a lock file, so that
/// two test runs on one machine take turns with the Slurm ports.
struct Cluster {
    dir: PathBuf,
    conf: PathBuf,
    _lock: File,
    _token: ChildToken,
}

impl Cluster {
    fn start(dir: &Path) -> Cluster {
        let lock = File::create(std::env::temp_dir().join("glissade-one-node-slurm.lock")).expect("lock file");
        let started = Instant::now();
        while !matches!(lock.try_lock(), Ok(())) {
            assert!(started.elapsed() < Duration::from_secs(300), "another run kept the one-node Slurm cluster 300 s");
            std::thread::sleep(Duration::from_millis(500));
        }
        let token = child_token();
        let out = run_with_timeout(Self::script(dir).arg("start"), LIMIT);
        let conf = dir.join("slurm.conf");
        let cluster = Cluster { dir: dir.to_owned(), conf, _lock: lock, _token: token };
        assert!(out.status.success(), "one-node-cluster.sh start: {}{}", text(&out.stdout), text(&out.stderr));
        cluster
    }

    fn script(dir: &Path) -> Command {
        let mut cmd = Command::new("bash");
        cmd.arg(repo().join("deploy/slurm/one-node-cluster.sh")).env("GLISSADE_SLURM_DIR", dir);
        cmd
    }

    /// A Slurm command (sbatch, squeue, scancel) on this cluster.
    fn command(&self, tool: &str) -> Command {
        let mut cmd = command(Path::new(tool));
        cmd.env("SLURM_CONF", &self.conf);
        cmd
    }

    fn run(&self, tool: &str, args: &[&str]) -> String {
        let out = run_with_timeout(self.command(tool).args(args), LIMIT);
        assert!(out.status.success(), "{tool} {args:?}: {}{}\n{}", text(&out.stdout), text(&out.stderr), self.logs());
        text(&out.stdout)
    }

    /// The job ids in the queue (array tasks as JOB_TASK).
    fn queue(&self) -> Vec<String> {
        self.run("squeue", &["-h", "-o", "%i"]).lines().map(|l| l.trim().to_owned()).collect()
    }

    /// Waits until none of `jobs` is in the queue.
    fn wait_gone(&self, jobs: &[&str], limit: Duration, what: &str) {
        let started = Instant::now();
        loop {
            let queue = self.queue();
            if !queue.iter().any(|j| jobs.contains(&j.as_str())) {
                return;
            }
            assert!(
                started.elapsed() < limit,
                "{what}: {jobs:?} still in squeue {queue:?} after {limit:?}\n{}",
                self.logs()
            );
            std::thread::sleep(Duration::from_millis(250));
        }
    }

    /// The daemons' logs and every job's output, for failure messages.
    fn logs(&self) -> String {
        let mut all = String::new();
        let mut files: Vec<PathBuf> = ["slurmctld.log", "slurmd.log"].iter().map(|f| self.dir.join(f)).collect();
        if let Ok(entries) = std::fs::read_dir(self.dir.join("..")) {
            let mut jobs: Vec<PathBuf> =
                entries.flatten().map(|e| e.path()).filter(|p| p.extension().is_some_and(|x| x == "log")).collect();
            jobs.sort();
            files.extend(jobs);
        }
        for f in files {
            let log = std::fs::read_to_string(&f).unwrap_or_default();
            let tail: Vec<&str> = log.lines().rev().take(40).collect();
            all += &format!("--- {} (last {} lines):\n", f.display(), tail.len());
            for l in tail.iter().rev() {
                all += l;
                all.push('\n');
            }
        }
        all
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        let out = run_with_timeout(Self::script(&self.dir).arg("stop"), LIMIT);
        if !out.status.success() {
            eprintln!("one-node-cluster.sh stop failed: {}{}", text(&out.stdout), text(&out.stderr));
        }
    }
}

/// A free TCP port (bound and released: the coordinator job binds it a moment later).
fn free_port() -> u16 {
    std::net::TcpListener::bind("0.0.0.0:0").expect("bind").local_addr().expect("addr").port()
}

/// `sbatch --parsable ARGS`: the job id.
fn sbatch(cluster: &Cluster, env: &[(&str, &Path)], args: &[&str]) -> String {
    let mut cmd = cluster.command("sbatch");
    for (k, v) in env {
        cmd.env(k, v);
    }
    let out = run_with_timeout(cmd.current_dir(repo()).arg("--parsable").args(args), LIMIT);
    assert!(out.status.success(), "sbatch {args:?}: {}{}\n{}", text(&out.stdout), text(&out.stderr), cluster.logs());
    text(&out.stdout).trim().split(';').next().unwrap_or_default().to_owned()
}

#[test]
fn slurm_batch_files_run_the_coordinator_and_pools_under_a_real_one_node_slurm() -> anyhow::Result<()> {
    let name = "slurm_batch_files_run_the_coordinator_and_pools_under_a_real_one_node_slurm";
    if !is_root() {
        println!("SKIPPED {name}: not root (the one-node Slurm cluster's daemons run as root)");
        return Ok(());
    }
    if let Some(tool) = ["munged", "slurmctld", "slurmd", "sbatch", "srun"].into_iter().find(|t| !on_path(t)) {
        println!("SKIPPED {name}: '{tool}' not found (slurm-wlm and munge: bash deploy/install-deps.sh)");
        return Ok(());
    }
    let started = Instant::now();
    let dir = tempfile::tempdir()?;
    // munged wants every directory above its socket searchable by all
    std::fs::set_permissions(dir.path(), std::os::unix::fs::PermissionsExt::from_mode(0o755))?;
    let path = |name: &str| dir.path().join(name);
    let cluster = Cluster::start(&path("slurm"));

    // The coordinator job, on the repository's batch file as users run it; binaries from this
    // build, its database and URL in this test's directory, its tokens where the variables say
    // (issue 47: they went beside the URL file whatever the variables said).
    let port = free_port().to_string();
    let (url_file, user_token, pool_token) =
        (path("home/coordinator.url"), path("secrets/user.token"), path("secrets/pool.token"));
    let server_bin = workspace_bin("glissade-server");
    let worker_bin = workspace_bin("glissade-worker");
    let env: Vec<(&str, &Path)> = vec![
        ("GLISSADE_SERVER_BIN", &server_bin),
        ("GLISSADE_WORKER_BIN", &worker_bin),
        ("GLISSADE_DATA", Path::new(dir.path())),
        ("GLISSADE_URL_FILE", &url_file),
        ("GLISSADE_USER_TOKEN_FILE", &user_token),
        ("GLISSADE_POOL_TOKEN_FILE", &pool_token),
    ];
    let mut coordinator_env = env.clone();
    let db = path("db");
    coordinator_env[2] = ("GLISSADE_DATA", &db);
    let port_path = PathBuf::from(&port);
    coordinator_env.push(("GLISSADE_PORT", &port_path));
    let coordinator_log = path("coordinator-%j.log");
    let coordinator = sbatch(
        &cluster,
        &coordinator_env,
        &["--mem=1G", &format!("--output={}", coordinator_log.display()), "deploy/slurm/coordinator.sbatch"],
    );
    let waited = Instant::now();
    let url = loop {
        if let Ok(url) = std::fs::read_to_string(&url_file)
            && url.ends_with('\n')
        {
            break url.trim().to_owned();
        }
        assert!(
            waited.elapsed() < LIMIT,
            "coordinator job {coordinator} published no URL in {} within {LIMIT:?}\n{}",
            url_file.display(),
            cluster.logs()
        );
        std::thread::sleep(Duration::from_millis(100));
    };
    assert!(url.starts_with("http://") && url.ends_with(&format!(":{port}")), "{url}");
    assert!(user_token.exists() && pool_token.exists(), "the tokens where the variables say");
    assert!(!path("home/user.token").exists() && !path("home/pool.token").exists(), "and nowhere else");

    let glissade = |args: &[&str]| {
        let out = run_with_timeout(
            command(&workspace_bin("glissade"))
                .env("GLISSADE_SERVER", &url)
                .env("GLISSADE_TOKEN_FILE", &user_token)
                .args(args),
            LIMIT,
        );
        assert!(
            out.status.success(),
            "glissade {args:?}: {}{}\n{}",
            text(&out.stdout),
            text(&out.stderr),
            cluster.logs()
        );
        text(&out.stdout)
    };
    let no_audits = ["--audit", "0", "--refine", "0", "--surface-audit", "0"];
    let scene = shipped_scene("three-blocks-tiny.toml");
    let scene = scene.to_str().expect("utf-8");

    // A study, then two pools of one rank each (2 cores here), idle after 5 s: it finishes.
    let mut args = vec!["submit", scene, "--grid", "f1=0.1:0.2:2", "--grid", "f2=0.1:0.2:2", "--tol", "1e-3"];
    args.extend(no_audits);
    let out = glissade(&args);
    assert_eq!(out.trim(), "1", "the study's id");
    let mut pool_env = env.clone();
    let idle = PathBuf::from("5");
    pool_env.push(("GLISSADE_IDLE_EXIT", &idle));
    let pool_log = path("pool-%A_%a.log");
    let pools = sbatch(
        &cluster,
        &pool_env,
        &[
            "--array=1-2",
            "--ntasks=2",
            "--mem=1G",
            &format!("--output={}", pool_log.display()),
            "deploy/slurm/pool.sbatch",
        ],
    );
    let out = glissade(&["watch", "1"]);
    assert!(out.contains("study 1 done: 4/4 done"), "{out}\n{}", cluster.logs());

    // One point solved cold (a scene of its own: no warm start from study 1) at a tight
    // tolerance, about a second alone: the pool that leases it is cancelled mid-point (plain
    // scancel: Slurm's SIGTERM to every process of the job, SIGKILL after KillWait, 30 s); it
    // finishes the point, delivers it and exits.
    let cold = std::fs::read_to_string(scene)?.replacen("title = \"", "title = \"cold copy of ", 1);
    std::fs::write(path("cold.toml"), cold)?;
    let cold_scene = path("cold.toml");
    let mut args = vec!["submit", cold_scene.to_str().expect("utf-8"), "--grid", "f1=0.15", "--tol", "1e-5"];
    args.extend(no_audits);
    let out = glissade(&args);
    assert_eq!(out.trim(), "2", "the study's id");
    let waited = Instant::now();
    let holder = loop {
        let show: serde_json::Value = serde_json::from_str(&glissade(&["show", "2", "--points", "--json"]))?;
        let point = &show["points"][0];
        if point["state"] == "POINT_STATE_LEASED" {
            break point["pool_id"].as_str().expect("pool_id").to_owned();
        }
        assert!(waited.elapsed() < LIMIT, "study 2's point was never leased: {show}\n{}", cluster.logs());
        std::thread::sleep(Duration::from_millis(50));
    };
    let task = holder.strip_prefix(&format!("slurm-{pools}-")).unwrap_or_else(|| panic!("pool id {holder}"));
    let (cancelled, other) = (format!("{pools}_{task}"), format!("{pools}_{}", if task == "1" { 2 } else { 1 }));
    cluster.run("scancel", &[&cancelled]);
    let out = glissade(&["watch", "2"]);
    assert!(out.contains("study 2 done: 1/1 done"), "{out}\n{}", cluster.logs());
    let show: serde_json::Value = serde_json::from_str(&glissade(&["show", "2", "--points", "--json"]))?;
    let point = &show["points"][0];
    assert_eq!(point["pool_id"], holder.as_str(), "delivered by the cancelled pool: {show}\n{}", cluster.logs());
    assert_eq!(point["attempts"], 1, "solved once, not lost: {show}\n{}", cluster.logs());
    cluster.wait_gone(&[&cancelled], LIMIT, "the cancelled pool");
    let log_of_task = |t: &str| std::fs::read_to_string(path(&format!("pool-{pools}_{t}.log"))).unwrap_or_default();
    let log = log_of_task(task);
    let (sigterm, delivered) = (log.find("SIGTERM: stopping after the current point"), log.find("delivered study=2"));
    assert!(
        sigterm.is_some() && delivered.is_some() && sigterm < delivered,
        "SIGTERM mid-point, then delivered:\n{log}"
    );

    // The other pool: idle, it exits by itself and leaves the queue.
    cluster.wait_gone(&[&other], LIMIT, "the idle pool");
    let log = log_of_task(other.rsplit('_').next().unwrap_or_default());
    assert!(log.contains("no work for too long: stopping"), "{log}\n{}", cluster.logs());

    // The coordinator stops on scancel (its batch script's trap) and leaves the queue.
    cluster.run("scancel", &[&coordinator]);
    cluster.wait_gone(&[&coordinator], LIMIT, "the coordinator");
    assert!(cluster.queue().is_empty(), "{:?}", cluster.queue());
    // srun made each pool one MPI job of 2 ranks (without `--mpi=pmi2` MPICH's ranks start
    // as singletons: two pools of one rank under one pool id)
    let coordinator_log = std::fs::read_to_string(path(&format!("coordinator-{coordinator}.log")))?;
    for task in ["1", "2"] {
        let registered = format!("pool registered pool=slurm-{pools}-{task} ranks=2 ");
        assert_eq!(coordinator_log.matches(&registered).count(), 1, "{registered}\n{coordinator_log}");
    }
    drop(cluster);
    println!("{name}: {:.1} s", started.elapsed().as_secs_f64());
    Ok(())
}
