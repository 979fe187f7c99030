//! `sweptvol watch`: the real binary on real temporary folders. Every test checks at the end
//! that the inputs are byte-for-byte unchanged. Jobs are small (`--backend cpu`, n = 32) except
//! where a test needs one long enough to interrupt.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use serde_json::Value;
use sweptvol::io::{exr_depth, gltf_in};

mod common;
use common::files::glb;

const BIN: &str = env!("CARGO_BIN_EXE_sweptvol");
const OUTPUTS: [&str; 8] = [
    "swept.glb",
    "depth-xmin.exr",
    "depth-xmax.exr",
    "depth-ymin.exr",
    "depth-ymax.exr",
    "depth-zmin.exr",
    "depth-zmax.exr",
    "report.json",
];

// ---- inputs ----

/// A tetrahedron (a cheap shape for the simplifier: at n = 16 a job takes about 0.5 s).
fn tet_glb() -> Vec<u8> {
    let p = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
    ];
    glb(&p, &[[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
}

/// `poses` rows moving along x by 0.01 each.
fn csv(poses: usize) -> String {
    let mut s = String::from("frame,tx,ty,tz,qw,qx,qy,qz\n");
    for i in 0..poses {
        s += &format!("{i},{},0,0,1,0,0,0\n", i as f64 * 0.01);
    }
    s
}

/// The bundled bunny along its 200 poses, `repeat` times over: a job of several seconds.
fn long_job_files(repeat: usize) -> (Vec<u8>, String) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples");
    let g = fs::read(root.join("bunny.glb")).unwrap();
    let text = fs::read_to_string(root.join("bunny-vibration.csv")).unwrap();
    let (head, rows): (Vec<&str>, Vec<&str>) = text
        .lines()
        .partition(|l| l.starts_with('#') || l.starts_with("frame"));
    let mut s = head.join("\n") + "\n";
    // Frames numbered on through the repeats: the rows of a part must not go back in time.
    let mut frame = 0;
    for _ in 0..repeat {
        for r in &rows {
            let (_, rest) = r.split_once(',').expect("frame,...");
            s += &format!("{frame},{rest}\n");
            frame += 1;
        }
    }
    (g, s)
}

/// Write a job folder the protocol's way: `<name>.partial/`, then rename.
fn submit(dir: &Path, name: &str, files: &[(&str, &[u8])]) -> PathBuf {
    let partial = dir.join(format!("{name}.partial"));
    fs::create_dir(&partial).unwrap();
    for (f, bytes) in files {
        fs::write(partial.join(f), bytes).unwrap();
    }
    let job = dir.join(name);
    fs::rename(&partial, &job).unwrap();
    job
}

fn small_job(dir: &Path, name: &str) -> PathBuf {
    submit(
        dir,
        name,
        &[
            ("generator.glb", &tet_glb()),
            ("trajectory.csv", csv(3).as_bytes()),
            ("job.json", br#"{"resolution": 16}"#),
        ],
    )
}

/// Every regular file under `dir` that is not an output: path and bytes.
fn input_files(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in fs::read_dir(&d).unwrap().flatten() {
            let (p, name) = (e.path(), e.file_name().to_string_lossy().into_owned());
            let meta = fs::symlink_metadata(&p).unwrap();
            if name.starts_with('.') || name == "cancel" {
                continue;
            }
            if meta.is_dir() {
                stack.push(p);
            } else if meta.is_file()
                && !OUTPUTS
                    .iter()
                    .chain(&["status.json"])
                    .any(|o| name == *o || name.ends_with(&format!(".{o}")))
            {
                out.push((p.clone(), fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

// ---- the daemon ----

struct Daemon {
    child: Child,
    log: PathBuf,
}

fn daemon_command(dir: &Path, extra: &[&str]) -> Command {
    let mut c = Command::new(BIN);
    c.arg("watch")
        .arg(dir)
        .args(["--backend", "cpu", "--rescan", "1"])
        .args(extra);
    if !extra.contains(&"--resolution") {
        c.args(["--resolution", "16"]); // for drops and jobs without job.json
    }
    c.env("RUST_LOG", "info")
        .stdin(Stdio::null())
        .stdout(Stdio::null());
    c
}

impl Daemon {
    /// Start `sweptvol watch dir`; its log goes to `dir/../<log>`, outside the watched folder.
    fn start(dir: &Path, log: &str, extra: &[&str]) -> Daemon {
        let log = dir.parent().unwrap().join(log);
        let child = daemon_command(dir, extra)
            .stderr(fs::File::create(&log).unwrap())
            .spawn()
            .expect("start sweptvol watch");
        Daemon { child, log }
    }

    fn log(&self) -> String {
        fs::read_to_string(&self.log).unwrap_or_default()
    }

    fn signal(&self, sig: i32) {
        // SAFETY: kill(2) on the pid of a child this test started and has not reaped.
        assert_eq!(unsafe { libc::kill(self.child.id() as i32, sig) }, 0);
    }

    fn wait(&mut self, limit: Duration) -> ExitStatus {
        let t0 = Instant::now();
        loop {
            if let Some(s) = self.child.try_wait().unwrap() {
                return s;
            }
            assert!(
                t0.elapsed() < limit,
                "daemon still running:\n{}",
                self.log()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// `sweptvol watch dir --once`: exit status and log.
fn once(dir: &Path, extra: &[&str]) -> (ExitStatus, String) {
    let mut d = Daemon::start(dir, "once.log", &[&["--once"], extra].concat());
    let status = d.wait(Duration::from_secs(90));
    (status, d.log())
}

fn wait_until(limit: Duration, what: &str, mut f: impl FnMut() -> bool) {
    let t0 = Instant::now();
    while !f() {
        assert!(t0.elapsed() < limit, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn status(path: &Path) -> Option<Value> {
    fs::read(path)
        .ok()
        .map(|b| serde_json::from_slice(&b).expect("status.json parses"))
}

fn state(path: &Path) -> String {
    status(path)
        .map(|s| s["state"].as_str().unwrap().to_string())
        .unwrap_or_default()
}

/// Every final output name that is visible must be a complete file.
fn check_visible_outputs(dir: &Path, prefix: &str) -> usize {
    let mut seen = 0;
    for o in OUTPUTS {
        let p = dir.join(format!("{prefix}{o}"));
        let Ok(bytes) = fs::read(&p) else { continue };
        seen += 1;
        if o.ends_with(".glb") {
            gltf_in::read_generator(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
        } else if o.ends_with(".exr") {
            exr_depth::read_depth_exr(&p).unwrap_or_else(|e| panic!("{}: {e:#}", p.display()));
        } else {
            serde_json::from_slice::<Value>(&bytes).unwrap();
        }
    }
    seen
}

fn watched() -> (tempfile::TempDir, PathBuf) {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("watched");
    fs::create_dir(&dir).unwrap();
    (tmp, dir)
}

fn unix_now() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_secs_f64()
}

// ---- tests ----

#[test]
fn job_folder_produces_all_outputs_and_done() {
    let (_tmp, dir) = watched();
    let job = small_job(&dir, "bracket");
    let before = input_files(&dir);
    let (code, log) = once(&dir, &[]);
    assert!(code.success(), "{log}");
    let s = status(&job.join("status.json")).expect("status.json");
    assert_eq!(s["state"], "done", "{s:#}");
    assert_eq!(s["progress"], 1.0);
    assert_eq!(s["sweptvol_version"], env!("CARGO_PKG_VERSION"));
    assert!(s["timings"]["seconds"].as_f64().unwrap() > 0.0);
    assert_eq!(s["inputs"].as_array().unwrap().len(), 3);
    assert_eq!(check_visible_outputs(&job, ""), OUTPUTS.len());
    let report: Value =
        serde_json::from_slice(&fs::read(job.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["resolution"], 16);
    let daemon: Value =
        serde_json::from_slice(&fs::read(dir.join(".sweptvol/daemon.json")).unwrap()).unwrap();
    assert_eq!(daemon["state"], "stopped");
    // No temporary file is left anywhere.
    for e in fs::read_dir(&job).unwrap().flatten() {
        assert!(!e.file_name().to_string_lossy().contains(".tmp-"), "{e:?}");
    }

    // A second start skips the finished job: the status is not rewritten.
    let mtime = fs::metadata(job.join("status.json"))
        .unwrap()
        .modified()
        .unwrap();
    let (code, log) = once(&dir, &[]);
    assert!(code.success(), "{log}");
    assert!(!log.contains("running"), "{log}");
    assert_eq!(
        fs::metadata(job.join("status.json"))
            .unwrap()
            .modified()
            .unwrap(),
        mtime
    );
    assert_eq!(input_files(&dir), before);
}

/// A writer stalling longer than --settle: the job starts on half the CSV (cut at a row
/// boundary, so it parses). The rest arrives while it runs: that run publishes nothing and is
/// requeued, and only the complete trajectory's result ever becomes visible (issue 14).
#[test]
fn a_drop_changed_during_its_run_publishes_nothing_and_runs_again() {
    let (_tmp, dir) = watched();
    let (g, full) = long_job_files(2);
    let lines: Vec<&str> = full.lines().collect();
    let (head, rows): (Vec<&str>, Vec<&str>) = lines
        .iter()
        .partition(|l| l.starts_with('#') || l.starts_with("frame"));
    let half = head.join("\n") + "\n" + &rows[..rows.len() / 2].join("\n") + "\n";
    let rest = rows[rows.len() / 2..].join("\n") + "\n";
    let mut d = Daemon::start(
        &dir,
        "daemon.log",
        &["--settle", "0.3", "--resolution", "48"],
    );
    fs::write(dir.join("part.glb"), &g).unwrap();
    fs::write(dir.join("part.csv"), &half).unwrap();
    let status_path = dir.join("part.status.json");
    wait_until(Duration::from_secs(30), "the run on the half file", || {
        state(&status_path) == "running"
    });
    use std::io::Write;
    let mut f = fs::OpenOptions::new()
        .append(true)
        .open(dir.join("part.csv"))
        .unwrap();
    f.write_all(rest.as_bytes()).unwrap();
    drop(f);
    let mut requeued = false;
    wait_until(
        Duration::from_secs(120),
        "the complete drop to finish",
        || {
            let s = status(&status_path);
            let st = s.as_ref().and_then(|s| s["state"].as_str()).unwrap_or("");
            if st == "queued" && !requeued {
                let m = s.as_ref().unwrap()["message"].as_str().unwrap_or("");
                requeued = m.contains("inputs changed");
            }
            if let Ok(bytes) = fs::read(dir.join("part.report.json")) {
                let r: Value = serde_json::from_slice(&bytes).unwrap();
                // One part moved by every row: one interval between each two.
                assert_eq!(
                    r["motion"]["intervals"],
                    rows.len() - 1,
                    "a half result was published"
                );
            }
            st == "done"
        },
    );
    assert!(requeued, "the first run was not requeued:\n{}", d.log());
    assert_eq!(check_visible_outputs(&dir, "part."), OUTPUTS.len());
    assert_eq!(fs::read(dir.join("part.glb")).unwrap(), g);
    assert_eq!(fs::read_to_string(dir.join("part.csv")).unwrap(), full);
    d.signal(libc::SIGTERM);
    assert!(d.wait(Duration::from_secs(20)).success(), "{}", d.log());
}

/// status.json names the stage the pipeline is in, and its message follows it.
#[test]
fn status_message_follows_the_stage() {
    let (_tmp, dir) = watched();
    let (g, c) = long_job_files(2);
    let mut d = Daemon::start(&dir, "daemon.log", &["--resolution", "48"]);
    let job = submit(
        &dir,
        "job",
        &[("generator.glb", &g), ("trajectory.csv", c.as_bytes())],
    );
    let status_path = job.join("status.json");
    wait_until(Duration::from_secs(60), "the sweep stage", || {
        status(&status_path).is_some_and(|s| s["stage"] == "sweep")
    });
    let s = status(&status_path).unwrap();
    assert!(s["message"].as_str().unwrap().contains("sweeping"), "{s}");
    d.signal(libc::SIGTERM);
    assert!(d.wait(Duration::from_secs(30)).success(), "{}", d.log());
}

#[test]
fn slow_chunked_drop_is_not_started_before_it_is_complete() {
    let (_tmp, dir) = watched();
    let mut d = Daemon::start(&dir, "daemon.log", &["--settle", "1.5"]);
    let g = tet_glb();
    let c = csv(5);
    let status_path = dir.join("part.status.json");
    // The glb in four chunks, then the csv in two, 0.6 s apart: about 3.6 s of copying.
    let mut f = fs::File::create(dir.join("part.glb")).unwrap();
    let chunks: Vec<&[u8]> = g.chunks(g.len().div_ceil(4)).collect();
    use std::io::Write;
    for chunk in chunks {
        f.write_all(chunk).unwrap();
        f.flush().unwrap();
        std::thread::sleep(Duration::from_millis(600));
        assert!(!status_path.exists(), "started during the glb copy");
    }
    let mut f = fs::File::create(dir.join("part.csv")).unwrap();
    let (a, b) = c.as_bytes().split_at(c.len() / 2);
    for chunk in [a, b] {
        f.write_all(chunk).unwrap();
        f.flush().unwrap();
        std::thread::sleep(Duration::from_millis(600));
        assert!(!status_path.exists(), "started during the csv copy");
    }
    let last_write = unix_now() - 0.6;
    drop(f);
    wait_until(Duration::from_secs(30), "the drop to finish", || {
        state(&status_path) == "done"
    });
    let s = status(&status_path).unwrap();
    let queued_at = s["timings"]["queued_at"].as_f64().unwrap();
    assert!(
        queued_at >= last_write + 1.4,
        "queued {queued_at} vs last write {last_write}"
    );
    let report: Value =
        serde_json::from_slice(&fs::read(dir.join("part.report.json")).unwrap()).unwrap();
    assert_eq!(report["counts"]["poses"], 5, "the complete csv was read");
    assert_eq!(check_visible_outputs(&dir, "part."), OUTPUTS.len());
    assert_eq!(fs::read(dir.join("part.glb")).unwrap(), g);
    assert_eq!(fs::read_to_string(dir.join("part.csv")).unwrap(), c);

    d.signal(libc::SIGTERM);
    assert!(d.wait(Duration::from_secs(20)).success(), "{}", d.log());
}

#[test]
fn malformed_inputs_fail_with_their_message_and_the_next_job_completes() {
    let (_tmp, dir) = watched();
    let g = tet_glb();
    let bad_csv = "frame,tx,ty,tz,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n1,0,0,0,0.5,0,0,0\n";
    let a = submit(
        &dir,
        "a-bad-csv",
        &[
            ("generator.glb", &g),
            ("trajectory.csv", bad_csv.as_bytes()),
        ],
    );
    let b = submit(
        &dir,
        "b-bad-json",
        &[
            ("generator.glb", &g),
            ("trajectory.csv", csv(2).as_bytes()),
            ("job.json", b"{\n  \"resolutoin\": 32\n}\n"),
        ],
    );
    let c = submit(&dir, "c-no-csv", &[("generator.glb", &g)]);
    let e = submit(
        &dir,
        "e-garbage",
        &[
            ("generator.glb", b"not a glb"),
            ("trajectory.csv", csv(2).as_bytes()),
        ],
    );
    let good = small_job(&dir, "z-good");
    let before = input_files(&dir);
    let (code, log) = once(&dir, &[]);
    assert!(code.success(), "{log}");

    let failed = |job: &Path| {
        let s = status(&job.join("status.json")).unwrap();
        assert_eq!(s["state"], "failed", "{s:#}");
        s
    };
    let s = failed(&a);
    let m = s["message"].as_str().unwrap();
    assert!(m.contains("trajectory.csv:3") && m.contains("fix:"), "{m}");
    assert_eq!(s["error"]["line"], 3);
    let s = failed(&b);
    let m = s["message"].as_str().unwrap();
    assert!(
        m.contains("job.json:2") && m.contains("resolutoin") && m.contains("fix:"),
        "{m}"
    );
    let s = failed(&c);
    assert!(
        s["message"].as_str().unwrap().contains("no trajectory.csv"),
        "{s:#}"
    );
    let s = failed(&e);
    assert!(
        s["message"].as_str().unwrap().contains("generator.glb"),
        "{s:#}"
    );
    for job in [&a, &b, &c, &e] {
        assert_eq!(
            check_visible_outputs(job, ""),
            0,
            "a failed job writes no output"
        );
    }
    assert_eq!(state(&good.join("status.json")), "done", "{log}");
    assert_eq!(input_files(&dir), before);
}

#[test]
fn kill_9_during_a_job_then_restart_completes_without_partial_outputs() {
    let (_tmp, dir) = watched();
    let (g, c) = long_job_files(3);
    let job = submit(
        &dir,
        "long",
        &[("generator.glb", &g), ("trajectory.csv", c.as_bytes())],
    );
    let before = input_files(&dir);
    let status_path = job.join("status.json");
    let mut d = Daemon::start(&dir, "first.log", &["--resolution", "32"]);
    wait_until(Duration::from_secs(30), "the job to run", || {
        check_visible_outputs(&job, "");
        state(&status_path) == "running"
    });
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_millis(800) {
        assert_eq!(
            check_visible_outputs(&job, ""),
            0,
            "outputs before the job ended"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    d.signal(libc::SIGKILL);
    d.wait(Duration::from_secs(10));
    assert_eq!(state(&status_path), "running", "{}", d.log());
    assert_eq!(check_visible_outputs(&job, ""), 0);

    // The restart takes the lock the dead daemon held and re-runs the job.
    let mut d = Daemon::start(&dir, "second.log", &["--once", "--resolution", "32"]);
    let t0 = Instant::now();
    while d.child.try_wait().unwrap().is_none() {
        check_visible_outputs(&job, ""); // whatever is visible is complete
        assert!(t0.elapsed() < Duration::from_secs(120), "{}", d.log());
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(d.wait(Duration::from_secs(1)).success(), "{}", d.log());
    assert_eq!(state(&status_path), "done", "{}", d.log());
    assert_eq!(check_visible_outputs(&job, ""), OUTPUTS.len());
    for e in fs::read_dir(&job).unwrap().flatten() {
        assert!(
            !e.file_name().to_string_lossy().contains(".tmp-"),
            "left over: {e:?}"
        );
    }
    assert_eq!(input_files(&dir), before);
}

#[test]
fn twenty_jobs_dropped_at_once_all_complete_each_once() {
    let (_tmp, dir) = watched();
    let mut d = Daemon::start(&dir, "daemon.log", &["--jobs", "2", "--settle", "0.5"]);
    std::thread::sleep(Duration::from_millis(300));
    let g = tet_glb();
    let mut jobs = Vec::new();
    for i in 0..10 {
        jobs.push(small_job(&dir, &format!("job{i:02}")).join("status.json"));
    }
    for i in 0..10 {
        fs::write(dir.join(format!("drop{i:02}.glb")), &g).unwrap();
        fs::write(dir.join(format!("drop{i:02}.csv")), csv(2)).unwrap();
        jobs.push(dir.join(format!("drop{i:02}.status.json")));
    }
    let before = input_files(&dir);
    wait_until(Duration::from_secs(90), "twenty jobs done", || {
        jobs.iter().all(|s| state(s) == "done")
    });
    // Give the rescans (every second) a chance to start anything twice.
    std::thread::sleep(Duration::from_millis(1500));
    d.signal(libc::SIGINT);
    assert!(d.wait(Duration::from_secs(20)).success());
    let log = d.log();
    for i in 0..10 {
        for name in [
            format!("job{i:02}/: running"),
            format!("drop{i:02}.glb + drop{i:02}.csv: running"),
        ] {
            assert_eq!(log.matches(&name).count(), 1, "{name}\n{log}");
        }
    }
    assert_eq!(input_files(&dir), before);
}

#[test]
fn escaping_uris_symlinks_and_oversized_inputs_are_refused() {
    let (tmp, dir) = watched();
    let outside = tmp.path().join("outside");
    fs::create_dir(&outside).unwrap();
    let g = tet_glb();
    fs::write(outside.join("secret.glb"), &g).unwrap();
    fs::write(outside.join("secret.bin"), [0u8; 96]).unwrap();
    fs::write(outside.join("generator.glb"), &g).unwrap();
    fs::write(outside.join("trajectory.csv"), csv(2)).unwrap();

    // A .gltf whose buffer climbs out of the job folder.
    let gltf = serde_json::json!({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}], "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3"}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "buffers": [{"byteLength": 36, "uri": "../../outside/secret.bin"}],
    });
    let uri = submit(
        &dir,
        "uri",
        &[
            ("generator.gltf", gltf.to_string().as_bytes()),
            ("trajectory.csv", csv(2).as_bytes()),
        ],
    );
    // A generator that is a link to a file outside.
    let link = submit(&dir, "link", &[("trajectory.csv", csv(2).as_bytes())]);
    std::os::unix::fs::symlink(outside.join("secret.glb"), link.join("generator.glb")).unwrap();
    // A dropped glb that is a link to a file outside.
    std::os::unix::fs::symlink(outside.join("secret.glb"), dir.join("drop.glb")).unwrap();
    fs::write(dir.join("drop.csv"), csv(2)).unwrap();
    // A job folder that is a link to a folder outside.
    std::os::unix::fs::symlink(&outside, dir.join("linked-folder")).unwrap();
    // Too large for --max-input-bytes.
    let big = submit(
        &dir,
        "big",
        &[
            ("generator.glb", &[&g[..], &vec![0u8; 4096]].concat()),
            ("trajectory.csv", csv(2).as_bytes()),
        ],
    );
    let good = small_job(&dir, "good");

    let before = input_files(&dir);
    let outside_before = input_files(&outside);
    let (code, log) = once(&dir, &["--settle", "0.3", "--max-input-bytes", "3000"]);
    assert!(code.success(), "{log}");

    let message = |p: &Path| {
        let s = status(p).unwrap_or_else(|| panic!("no {}\n{log}", p.display()));
        assert_eq!(s["state"], "failed", "{s:#}");
        s["message"].as_str().unwrap().to_string()
    };
    let m = message(&uri.join("status.json"));
    assert!(
        m.contains("outside the folder") && m.contains("secret.bin"),
        "{m}"
    );
    let m = message(&link.join("status.json"));
    assert!(
        m.contains("symbolic link") && m.contains("outside the job folder"),
        "{m}"
    );
    let m = message(&dir.join("drop.status.json"));
    assert!(
        m.contains("symbolic link") && m.contains("outside the watched folder"),
        "{m}"
    );
    let m = message(&big.join("status.json"));
    assert!(
        m.contains("more than the daemon's limit of 3000 bytes"),
        "{m}"
    );
    assert!(log.contains("linked-folder: refused"), "{log}");
    assert_eq!(state(&good.join("status.json")), "done");
    // Nothing was written outside, or through the linked folder.
    assert_eq!(input_files(&outside), outside_before);
    assert_eq!(fs::read_dir(&outside).unwrap().count(), 4);
    assert_eq!(input_files(&dir), before);
}

/// A long job "long" (`long_job_files(repeat)`) and a daemon started on it, once the job is
/// sweeping; with the input files as they were before the daemon started.
fn daemon_on_a_sweeping_job(
    dir: &Path,
    repeat: usize,
) -> (PathBuf, Vec<(PathBuf, Vec<u8>)>, Daemon) {
    let (g, c) = long_job_files(repeat);
    let job = submit(
        dir,
        "long",
        &[("generator.glb", &g), ("trajectory.csv", c.as_bytes())],
    );
    let before = input_files(dir);
    let status_path = job.join("status.json");
    let d = Daemon::start(dir, "daemon.log", &["--resolution", "32"]);
    wait_until(Duration::from_secs(30), "the sweep", || {
        status(&status_path).is_some_and(|s| s["stage"] == "sweep")
    });
    (job, before, d)
}

#[test]
fn sigterm_leaves_the_running_job_queued_and_the_next_start_runs_it() {
    let (_tmp, dir) = watched();
    let (job, before, mut d) = daemon_on_a_sweeping_job(&dir, 3);
    let status_path = job.join("status.json");
    d.signal(libc::SIGTERM);
    let code = d.wait(Duration::from_secs(30));
    assert!(code.success(), "{}", d.log());
    let s = status(&status_path).unwrap();
    assert_eq!(s["state"], "queued", "{s:#}");
    assert!(s["message"].as_str().unwrap().contains("shutdown"), "{s:#}");
    assert_eq!(check_visible_outputs(&job, ""), 0);
    let daemon: Value =
        serde_json::from_slice(&fs::read(dir.join(".sweptvol/daemon.json")).unwrap()).unwrap();
    assert_eq!(daemon["state"], "stopped");

    let (code, log) = once(&dir, &["--resolution", "16"]);
    assert!(code.success(), "{log}");
    assert_eq!(state(&status_path), "done", "{log}");
    assert_eq!(input_files(&dir), before);
}

#[test]
fn cancel_file_stops_the_job_and_marks_it_cancelled() {
    let (_tmp, dir) = watched();
    let (job, before, mut d) = daemon_on_a_sweeping_job(&dir, 4);
    let status_path = job.join("status.json");
    fs::write(job.join("cancel"), b"").unwrap();
    let t0 = Instant::now();
    wait_until(Duration::from_secs(20), "cancelled", || {
        state(&status_path) == "cancelled"
    });
    // Sweep batches take about 0.25 s (more while other tests load the cores).
    assert!(
        t0.elapsed() < Duration::from_secs(4),
        "cancel took {:?}",
        t0.elapsed()
    );
    assert_eq!(check_visible_outputs(&job, ""), 0);
    d.signal(libc::SIGTERM);
    assert!(d.wait(Duration::from_secs(20)).success());
    assert_eq!(input_files(&dir), before);
}

#[test]
fn a_second_daemon_on_the_same_folder_refuses_to_start() {
    let (_tmp, dir) = watched();
    let mut first = Daemon::start(&dir, "first.log", &[]);
    wait_until(
        Duration::from_secs(20),
        "the first daemon's heartbeat",
        || dir.join(".sweptvol/daemon.json").exists(),
    );
    let (code, log) = once(&dir, &[]);
    assert_eq!(code.code(), Some(1), "{log}");
    assert!(
        log.contains("already running") && log.contains(&first.child.id().to_string()),
        "{log}"
    );
    first.signal(libc::SIGTERM);
    assert!(first.wait(Duration::from_secs(20)).success());
    let (code, log) = once(&dir, &[]);
    assert!(code.success(), "after the first stopped: {log}");
}

/// The control folder must not lead outside DIR, and a planted status.json link is not read
/// through (review findings).
#[test]
fn control_folder_and_status_links_never_lead_outside() {
    let (_tmp, dir) = watched();
    let outside = tempfile::tempdir().unwrap();
    std::os::unix::fs::symlink(outside.path(), dir.join(".sweptvol")).unwrap();
    let (code, log) = once(&dir, &[]);
    assert_eq!(code.code(), Some(1), "{log}");
    assert!(
        log.contains(".sweptvol") && log.contains("not a folder"),
        "{log}"
    );
    assert_eq!(std::fs::read_dir(outside.path()).unwrap().count(), 0);
    std::fs::remove_file(dir.join(".sweptvol")).unwrap();

    // A job whose status.json is a link to a file outside: that file is neither read as the
    // job's record nor written (the status write replaces the link).
    let secret = outside.path().join("secret.json");
    std::fs::write(&secret, br#"{"state": "done"}"#).unwrap();
    let job = small_job(&dir, "linked");
    std::os::unix::fs::symlink(&secret, job.join("status.json")).unwrap();
    let (code, log) = once(&dir, &[]);
    assert!(code.success(), "{log}");
    assert_eq!(state(&job.join("status.json")), "done", "{log}");
    assert!(job.join("swept.glb").exists(), "the job ran: {log}");
    assert_eq!(std::fs::read(&secret).unwrap(), br#"{"state": "done"}"#);
}

/// job.json with absurd values (not unknown keys): each job fails with a message that names
/// job.json and the fix, writes no output, and the good job after them still completes.
#[test]
fn absurd_job_json_values_fail_their_job_by_name() {
    let (_tmp, dir) = watched();
    let g = tet_glb();
    let t = csv(2);
    let cases: [(&str, &[u8], &str); 7] = [
        (
            "a-huge-resolution",
            br#"{"resolution": 1000000000}"#,
            "resolution",
        ),
        ("b-zero-resolution", br#"{"resolution": 0}"#, "resolution"),
        (
            "c-negative-resolution",
            br#"{"resolution": -3}"#,
            "resolution",
        ),
        ("d-negative-tolerance", br#"{"tolerance": -1}"#, "tolerance"),
        (
            "e-nan-tolerance",
            br#"{"tolerance": "NaN"}"#,
            "expected f64",
        ),
        ("f-unknown-backend", br#"{"backend": "quantum"}"#, "backend"),
        ("g-bad-format", br#"{"also": ["step"]}"#, "step"),
    ];
    let jobs: Vec<(PathBuf, &str)> = cases
        .iter()
        .map(|(name, json, needle)| {
            let job = submit(
                &dir,
                name,
                &[
                    ("generator.glb", &g),
                    ("trajectory.csv", t.as_bytes()),
                    ("job.json", json),
                ],
            );
            (job, *needle)
        })
        .collect();
    let good = small_job(&dir, "z-good");
    let before = input_files(&dir);
    let (code, log) = once(&dir, &[]);
    assert!(code.success(), "{log}");
    for (job, needle) in &jobs {
        let s = status(&job.join("status.json")).unwrap();
        assert_eq!(s["state"], "failed", "{}: {s:#}", job.display());
        let m = s["message"].as_str().unwrap();
        assert!(
            m.contains(needle) && m.contains("fix") && (m.contains("job.json") || m.contains("\"")),
            "{}: {m}",
            job.display()
        );
        assert_eq!(check_visible_outputs(job, ""), 0, "{}", job.display());
        // A value the library refuses is named by its job.json key, never by a CLI flag, and
        // the key is the error's column (the add-on words it by its panel field).
        if [
            "a-huge-resolution",
            "b-zero-resolution",
            "d-negative-tolerance",
        ]
        .iter()
        .any(|n| job.ends_with(n))
        {
            assert_eq!(s["error"]["column"], *needle, "{s:#}");
            let quoted = format!("\"{needle}\"");
            let e = s["error"]["message"].as_str().unwrap();
            assert!(e.contains(&quoted) && !m.contains("--"), "{s:#}");
        }
    }
    assert_eq!(state(&good.join("status.json")), "done", "{log}");
    assert_eq!(input_files(&dir), before);
}

/// Issue 30, defect 2: `watch DIR --once 2>&1 | head -1` hung with one job (a log line written
/// to the closed pipe panicked a worker). With stderr closed after the first line, the job
/// still runs to "done" and the daemon exits 0.
#[test]
fn a_closed_log_pipe_neither_hangs_nor_loses_the_job() {
    use std::io::BufRead;
    let (_tmp, dir) = watched();
    let job = small_job(&dir, "bracket");
    let mut child = Command::new(env!("CARGO_BIN_EXE_sweptvol"))
        .args(["watch", dir.to_str().unwrap(), "--once"])
        .env("RUST_LOG", "info")
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    std::io::BufReader::new(child.stderr.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    // The reader is gone now: every later log line meets a closed pipe.
    let t0 = Instant::now();
    let code = loop {
        if let Some(code) = child.try_wait().unwrap() {
            break code;
        }
        if t0.elapsed() > Duration::from_secs(120) {
            child.kill().unwrap();
            panic!("the daemon hung after its log pipe closed");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(code.success(), "{code}");
    let s = status(&job.join("status.json")).expect("status.json");
    assert_eq!(s["state"], "done", "{s:#}");
}

/// Issue 30, defect 5: `.sweptvol/lock` planted as a symbolic link made the daemon create the
/// link's target outside the folder. It now refuses, naming the link, and writes nothing
/// outside.
#[test]
fn a_lock_planted_as_a_link_writes_nothing_outside() {
    let (tmp, dir) = watched();
    let outside = tmp.path().join("outside");
    fs::create_dir(&outside).unwrap();
    let target = outside.join("created-by-the-daemon");
    fs::create_dir(dir.join(".sweptvol")).unwrap();
    std::os::unix::fs::symlink(&target, dir.join(".sweptvol/lock")).unwrap();
    let (code, log) = once(&dir, &[]);
    assert!(!code.success(), "{log}");
    assert!(log.contains("symbolic link"), "{log}");
    assert!(!target.exists(), "the daemon created {}", target.display());
    assert_eq!(fs::read_dir(&outside).unwrap().count(), 0);
}

/// Issue 30, defect 3: a job folder removed while its job ran kept the daemon sweeping (with an
/// error per status write), then was made again and filled with outputs and "done". Now the
/// job is abandoned at the next check, nothing is written, and the folder stays gone.
#[test]
fn a_job_folder_removed_while_it_runs_is_abandoned_and_not_recreated() {
    let (_tmp, dir) = watched();
    let (job, _, mut d) = daemon_on_a_sweeping_job(&dir, 4);
    fs::remove_dir_all(&job).unwrap();
    let t0 = Instant::now();
    wait_until(Duration::from_secs(20), "the job abandoned", || {
        d.log().contains("abandoned")
    });
    assert!(
        t0.elapsed() < Duration::from_secs(4),
        "abandoning took {:?}",
        t0.elapsed()
    );
    // Two rescans later the folder is still gone and nothing failed.
    std::thread::sleep(Duration::from_millis(2500));
    assert!(!job.exists(), "the job folder was made again:\n{}", d.log());
    let log = d.log();
    assert!(!log.contains("could not write the job status"), "{log}");
    assert!(!log.contains("failed"), "{log}");
    d.signal(libc::SIGTERM);
    assert!(d.wait(Duration::from_secs(20)).success());
}

/// Issue 30, weak spot: a job folder's inputs rewritten while its job ran were not watched
/// (only drops were), so the result of the old trajectory was published as the new one's.
/// Now the run stops, publishes nothing, and the job runs again on the inputs as they are.
#[test]
fn a_job_folders_inputs_changed_during_its_run_publish_nothing_and_run_again() {
    let (_tmp, dir) = watched();
    let (job, _, mut d) = daemon_on_a_sweeping_job(&dir, 4);
    let status_path = job.join("status.json");
    let (_, short) = long_job_files(1);
    let rows = short
        .lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with("frame"))
        .count();
    fs::write(job.join("trajectory.csv"), &short).unwrap();
    wait_until(
        Duration::from_secs(120),
        "the rewritten job to finish",
        || {
            let s = status(&status_path);
            s.as_ref().and_then(|s| s["state"].as_str()) == Some("done")
        },
    );
    // The requeue is read from the log: its "queued" status may last only milliseconds, too
    // short for a poll to see.
    let log = d.log();
    assert!(
        log.contains("queued: the inputs changed while the job ran"),
        "the first run was not requeued:\n{log}"
    );
    let r: Value = serde_json::from_slice(&fs::read(job.join("report.json")).unwrap()).unwrap();
    assert_eq!(
        r["motion"]["intervals"],
        rows - 1,
        "the old trajectory's result was published"
    );
    d.signal(libc::SIGTERM);
    assert!(d.wait(Duration::from_secs(20)).success());
}

/// Issue 27: a watched job's texts name options as job.json keys, never as command-line flags
/// (report.json said "--classify auto" and "--backend cpu"; a refused motion said "pass
/// --motion discrete" in status.json). A done job's report and status, and a failed job's
/// message and fix, hold no flag, and the failure names the key.
#[test]
fn a_watched_jobs_texts_name_job_keys_not_flags() {
    let (_tmp, dir) = watched();
    let ok = small_job(&dir, "fine");
    let turn = submit(
        &dir,
        "turn",
        &[
            ("generator.glb", &tet_glb()),
            (
                "trajectory.csv",
                b"frame,tx,ty,tz,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n1,0,0,0,0,0,1,0\n",
            ),
            ("job.json", br#"{"resolution": 16}"#),
        ],
    );
    let (code, log) = once(&dir, &[]);
    assert!(code.success(), "{log}");
    assert_eq!(state(&ok.join("status.json")), "done", "{log}");
    for file in ["report.json", "status.json"] {
        let text = fs::read_to_string(ok.join(file)).unwrap();
        assert!(!text.contains("--"), "{file} names a flag:\n{text}");
    }
    let s = status(&turn.join("status.json")).unwrap();
    assert_eq!(s["state"], "failed", "{s:#}");
    let message = s["message"].as_str().unwrap();
    let fix = s["error"]["fix"].as_str().unwrap();
    assert!(!message.contains("--") && !fix.contains("--"), "{s:#}");
    assert!(fix.contains("set \"motion\" to discrete"), "{s:#}");
}

/// Issue 28: a job folder may name obstacle files of the folder in job.json's `against`: the
/// report gains their clearance, the map is written beside the outputs (and is no input: the
/// job runs once), and a name that leads out of the folder fails the job by its key.
#[test]
fn a_job_folders_obstacles_are_measured_once_and_never_read_outside() {
    let (_tmp, dir) = watched();
    let wall = glb(
        &[
            [3.0, -2.0, -2.0],
            [3.0, 2.0, -2.0],
            [3.0, 2.0, 2.0],
            [3.0, -2.0, 2.0],
        ],
        &[[0, 1, 2], [0, 2, 3]],
    );
    let near = submit(
        &dir,
        "near",
        &[
            ("generator.glb", &tet_glb()),
            ("trajectory.csv", csv(3).as_bytes()),
            ("wall.glb", &wall),
            (
                "job.json",
                br#"{"resolution": 16, "against": ["wall.glb"], "require_clearance": 100}"#,
            ),
        ],
    );
    fs::write(dir.join("secret.glb"), &wall).unwrap();
    let out = submit(
        &dir,
        "out",
        &[
            ("generator.glb", &tet_glb()),
            ("trajectory.csv", csv(3).as_bytes()),
            (
                "job.json",
                br#"{"resolution": 16, "against": ["../secret.glb"]}"#,
            ),
        ],
    );
    let mut d = Daemon::start(&dir, "obstacles.log", &[]);
    wait_until(Duration::from_secs(60), "both jobs to finish", || {
        ["done", "failed"].contains(&state(&near.join("status.json")).as_str())
            && ["done", "failed"].contains(&state(&out.join("status.json")).as_str())
    });
    // Two rescans later the job with a map has still run once.
    std::thread::sleep(Duration::from_millis(2500));
    let log = d.log();
    assert_eq!(state(&near.join("status.json")), "done", "{log}");
    assert_eq!(log.matches("near/: running").count(), 1, "{log}");
    let report: Value =
        serde_json::from_slice(&fs::read(near.join("report.json")).unwrap()).unwrap();
    let o = &report["clearance"]["obstacles"][0];
    assert_eq!(o["verdict"], "clear", "{o}");
    assert!(near.join("wall.clearance.glb").exists());
    // The status says it too: the obstacle clear, the (absurd) required clearance not kept.
    let message = status(&near.join("status.json")).unwrap()["message"]
        .as_str()
        .unwrap()
        .to_string();
    assert!(
        message.contains("1 obstacle(s): 1 clear") && message.contains("required 100: NOT KEPT"),
        "{message}"
    );
    let s = status(&out.join("status.json")).unwrap();
    assert_eq!(s["state"], "failed", "{s:#}");
    assert_eq!(s["error"]["column"], "against", "{s:#}");
    d.signal(libc::SIGTERM);
    assert!(d.wait(Duration::from_secs(20)).success());
}
