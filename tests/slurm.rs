//! On a real SLURM (scripts/slurm-local.sh starts one on this machine; scripts/test-all.sh does
//! that and sets SWEPTVOL_REQUIRE_SLURM=1): `cluster submit` of the bundled example as 4 shards
//! plus the merge gives `run`'s bytes; a shard that crashes is requeued by SLURM and the result
//! is the same; `watch --executor slurm` completes a job folder the same way. Without a
//! reachable SLURM these tests say so loudly, and fail where SLURM is required.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

mod common;
use common::files::sweptvol;

fn example(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("examples")
        .join(name)
}

/// True when `sinfo` reaches a controller with a node that takes jobs.
fn slurm_ready() -> bool {
    let ok = Command::new("sinfo")
        .args(["-h", "-o", "%t"])
        .output()
        .is_ok_and(|o| {
            o.status.success()
                && String::from_utf8_lossy(&o.stdout)
                    .lines()
                    .any(|l| ["idle", "mix", "alloc"].iter().any(|s| l.starts_with(s)))
        });
    if !ok {
        let required = std::env::var("SWEPTVOL_REQUIRE_SLURM").is_ok_and(|v| v == "1");
        eprintln!(
            "SKIPPED: no SLURM cluster answers `sinfo` (start one with `eval $(scripts/slurm-local.sh start)`){}",
            if required { "; SWEPTVOL_REQUIRE_SLURM=1, so this fails" } else { "" }
        );
        assert!(
            !required,
            "SLURM is required (SWEPTVOL_REQUIRE_SLURM=1) but does not answer"
        );
    }
    ok
}

const RESOLUTION: &str = "64";

fn job_args(out: &Path) -> Vec<String> {
    [
        "--generator",
        example("bunny.glb").to_str().unwrap(),
        "--trajectory",
        example("bunny-vibration.csv").to_str().unwrap(),
        "--resolution",
        RESOLUTION,
        "--backend",
        "cpu",
        "--out",
        out.to_str().unwrap(),
    ]
    .map(String::from)
    .to_vec()
}

/// `run`'s outputs of the example, named `<name>.swept.glb`, ... (bare names for "").
fn run_outputs(dir: &Path, name: &str) -> PathBuf {
    let out = dir.join("run");
    let mut args = vec!["run".to_string(), "--quiet".into()];
    if name.is_empty() {
        args.push("--bare-names".into()); // as a watched job's shards are swept
    } else {
        args.extend(["--name".into(), name.into()]);
    }
    args.extend(job_args(&out));
    let o = sweptvol(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out
}

/// Wait up to `limit` for `path` to exist.
fn wait_for(path: &Path, limit: Duration, what: &str, shard_dir: &Path) {
    let t0 = Instant::now();
    while !path.exists() {
        if t0.elapsed() > limit {
            let status = sweptvol(&["cluster", "status", shard_dir.to_str().unwrap()]);
            panic!(
                "{what}: no {} after {limit:?}; cluster status:\n{}{}",
                path.display(),
                String::from_utf8_lossy(&status.stdout),
                String::from_utf8_lossy(&status.stderr)
            );
        }
        std::thread::sleep(Duration::from_millis(500));
    }
}

/// The mesh and depth images equal `run`'s byte for byte (`prefix` is the output stem and dot
/// in both, or empty for a job folder's bare names).
fn assert_same(run: &Path, other: &Path, prefix: &str) {
    for suffix in [
        "swept.glb",
        "depth-xmin.exr",
        "depth-xmax.exr",
        "depth-ymin.exr",
        "depth-ymax.exr",
        "depth-zmin.exr",
        "depth-zmax.exr",
    ] {
        let a = fs::read(run.join(format!("{prefix}{suffix}"))).unwrap();
        let b = fs::read(other.join(format!("{prefix}{suffix}"))).unwrap_or_else(|e| {
            panic!("{}: {e}", other.join(format!("{prefix}{suffix}")).display())
        });
        assert!(a == b, "{prefix}{suffix} differs from run's");
    }
}

#[test]
fn cluster_submit_gives_runs_bytes() {
    if !slurm_ready() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let run = run_outputs(dir.path(), "bunny-vibration");
    let out = dir.path().join("cluster");
    let mut args = vec![
        "cluster".to_string(),
        "submit".into(),
        "--shards".into(),
        "4".into(),
    ];
    args.extend(job_args(&out));
    let o = sweptvol(&args);
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{said}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(said.contains("shards 1-4 of 4 as array job"), "{said}");
    let shards = out.join("bunny-vibration.shards");
    wait_for(
        &shards.join("merge.exit"),
        Duration::from_secs(300),
        "cluster submit",
        &shards,
    );
    assert_eq!(
        fs::read_to_string(shards.join("merge.exit"))
            .unwrap()
            .trim(),
        "0"
    );
    assert_same(&run, &out, "bunny-vibration.");
    let status = sweptvol(&["cluster", "status", shards.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&status.stdout);
    assert!(
        text.contains("shards: 4 of 4 done") && text.contains("merged"),
        "{text}"
    );
    // Submitting again sweeps nothing: every shard is finished; only the merge runs.
    fs::remove_file(out.join("bunny-vibration.swept.glb")).unwrap();
    let mut again = args.clone();
    again.push("--overwrite".into());
    let o = sweptvol(&again);
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(
        said.contains("every shard is finished"),
        "{said}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    wait_for(
        &shards.join("merge.exit"),
        Duration::from_secs(300),
        "second submit",
        &shards,
    );
    assert_same(&run, &out, "bunny-vibration.");
}

#[test]
fn a_crashed_shard_is_requeued_by_slurm() {
    if !slurm_ready() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let run = run_outputs(dir.path(), "bunny-vibration");
    // A binary whose shard 2 crashes on its first try (exit 1, as a killed node would leave it).
    let marker = dir.path().join("crashed-once");
    let flaky = dir.path().join("flaky.sh");
    fs::write(
        &flaky,
        format!(
            "#!/bin/bash\nif [[ \" $* \" == *\" --shard 2/\"* ]] && [ ! -e '{m}' ]; then touch '{m}'; echo 'flaky: crashing once' >&2; exit 1; fi\nexec '{b}' \"$@\"\n",
            m = marker.display(),
            b = env!("CARGO_BIN_EXE_sweptvol")
        ),
    )
    .unwrap();
    Command::new("chmod")
        .arg("+x")
        .arg(&flaky)
        .status()
        .unwrap();
    let out = dir.path().join("cluster");
    let mut args = vec![
        "cluster".to_string(),
        "submit".into(),
        "--shards".into(),
        "3".into(),
        "--binary".into(),
        flaky.to_str().unwrap().into(),
    ];
    args.extend(job_args(&out));
    let o = sweptvol(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let shards = out.join("bunny-vibration.shards");
    // SLURM holds a requeued job back about two minutes before it runs it again.
    wait_for(
        &shards.join("merge.exit"),
        Duration::from_secs(420),
        "requeue",
        &shards,
    );
    assert!(
        marker.exists(),
        "shard 2 never crashed: the test tested nothing"
    );
    let log = fs::read_to_string(shards.join("logs/sweep-2.log")).unwrap();
    assert!(
        log.contains("requeueing") && log.contains("try 2 of 3"),
        "{log}"
    );
    assert_same(&run, &out, "bunny-vibration.");
}

#[test]
fn watch_hands_a_job_folder_to_slurm() {
    if !slurm_ready() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let run = run_outputs(dir.path(), "");
    let root = dir.path().join("watched");
    let partial = root.join("bunny.partial");
    fs::create_dir_all(&partial).unwrap();
    fs::copy(example("bunny.glb"), partial.join("generator.glb")).unwrap();
    fs::copy(
        example("bunny-vibration.csv"),
        partial.join("trajectory.csv"),
    )
    .unwrap();
    fs::write(
        partial.join("job.json"),
        format!("{{\"resolution\": {RESOLUTION}, \"backend\": \"cpu\"}}"),
    )
    .unwrap();
    fs::rename(&partial, root.join("bunny")).unwrap();
    let o = sweptvol(&[
        "watch",
        root.to_str().unwrap(),
        "--once",
        "--executor",
        "slurm",
        "--shards",
        "3",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let status: serde_json::Value =
        serde_json::from_slice(&fs::read(root.join("bunny/status.json")).unwrap()).unwrap();
    assert_eq!(status["state"], "done", "{status:#}");
    assert_eq!(status["cluster"]["shards"], 3, "{status:#}");
    assert_eq!(status["cluster"]["shards_done"], 3, "{status:#}");
    assert!(
        status["message"].as_str().unwrap().contains("on SLURM"),
        "{status:#}"
    );
    assert_same(&run, &root.join("bunny"), "");
}
