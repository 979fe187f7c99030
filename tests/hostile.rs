//! Issue 14, "hostile input": malformed inputs and options against the real binary. Each is
//! refused with exit 2 and a message naming the file (and node or line) and the fix, writes no
//! output and changes no input.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

use base64::Engine;
use serde_json::{json, Value};

mod common;
use common::files::{run_args, verify_args, write};

const BIN: &str = env!("CARGO_BIN_EXE_sweptvol");

/// The binary as a user starts it: no RUST_LOG, so the default log level and colour rules are
/// what these tests see (common::files::sweptvol sets RUST_LOG=warn).
fn sweptvol<S: AsRef<std::ffi::OsStr>>(args: &[S]) -> Output {
    Command::new(BIN)
        .args(args)
        .env_remove("RUST_LOG")
        .output()
        .expect("run sweptvol")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A one-triangle glTF whose node "part" has the given transform properties.
fn gltf_doc(node: Value) -> Value {
    let mut bin = Vec::new();
    for c in [0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.5] {
        bin.extend_from_slice(&c.to_le_bytes());
    }
    let mut n = json!({"name": "part", "mesh": 0});
    n.as_object_mut()
        .unwrap()
        .extend(node.as_object().unwrap().clone());
    json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [n],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                        "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.5]}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "buffers": [{"byteLength": 36, "uri": format!("data:application/octet-stream;base64,{}",
            base64::engine::general_purpose::STANDARD.encode(&bin))}],
    })
}

const CSV: &str = "frame,tx,ty,tz,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n1,0.1,0,0,1,0,0,0\n";

/// Every file under `dir` with its bytes.
fn snapshot(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out: Vec<(PathBuf, Vec<u8>)> = fs::read_dir(dir)
        .unwrap()
        .flatten()
        .filter(|e| e.path().is_file())
        .map(|e| (e.path(), fs::read(e.path()).unwrap()))
        .collect();
    out.sort();
    out
}

/// Exit 2, every needle and a fix in stderr, no output folder, inputs unchanged.
fn expect_refused(dir: &Path, args: &[String], needles: &[&str]) -> String {
    let before = snapshot(dir);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let o = sweptvol(&args);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
    for n in needles {
        assert!(err.contains(n), "stderr lacks {n:?}: {err}");
    }
    assert!(!dir.join("results").exists(), "outputs written: {err}");
    assert_eq!(before, snapshot(dir), "an input changed: {err}");
    err
}

#[test]
fn non_affine_and_singular_node_transforms_are_refused_by_run_and_verify() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let t = write(d, "part.csv", CSV);
    let ok = write(d, "ok.gltf", gltf_doc(json!({})).to_string());
    let identity = [
        1.0, 0., 0., 0., 0., 1., 0., 0., 0., 0., 1., 0., 0., 0., 0., 1.,
    ];
    // Column-major: elements 3, 7, 11, 15 are the last row.
    let cases: [(&str, usize, f64, &str); 3] = [
        ("w2.gltf", 15, 2.0, "0 0 0 2"),
        ("w0.gltf", 15, 0.0, "0 0 0 0"),
        ("projective.gltf", 11, -1.0, "0 0 -1 1"),
    ];
    for (file, k, x, row) in cases {
        let mut m = identity;
        m[k] = x;
        let g = write(d, file, gltf_doc(json!({"matrix": m})).to_string());
        let args = run_args(&g, &t, &d.join("results"), &[]);
        expect_refused(
            d,
            &args,
            &[file, "nodes[0]", "\"part\"", "not affine", row, "fix:"],
        );
    }
    for (file, node) in [
        ("zero-scale.gltf", json!({"scale": [1.0, 0.0, 1.0]})),
        (
            "flat-matrix.gltf",
            json!({"matrix": [1., 0., 0., 0., 2., 0., 0., 0., 0., 0., 1., 0., 0., 0., 0., 1.]}),
        ),
    ] {
        let g = write(d, file, gltf_doc(node).to_string());
        let args = run_args(&g, &t, &d.join("results"), &[]);
        expect_refused(d, &args, &[file, "nodes[0]", "singular", "fix:"]);
        // verify reads the same inputs on its own path: refused too (it used to panic).
        let args: Vec<String> = ["verify", "--generator", g.to_str().unwrap(), "--trajectory"]
            .iter()
            .map(|s| s.to_string())
            .chain([
                t.to_str().unwrap().into(),
                "--mesh".into(),
                ok.to_str().unwrap().into(),
            ])
            .collect();
        expect_refused(d, &args, &[file, "nodes[0]", "singular", "fix:"]);
    }
}

#[test]
fn an_output_may_never_replace_an_input() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("out");
    fs::create_dir(&out).unwrap();
    // A generator named like the mesh output, in the output folder.
    let g = write(&out, "ok.swept.glb", gltf_doc(json!({})).to_string());
    let t = write(d, "ok.csv", CSV);
    let before = fs::read(&g).unwrap();
    let o = sweptvol(
        &run_args(&g, &t, &out, &["--overwrite"])
            .iter()
            .map(String::as_str)
            .collect::<Vec<_>>(),
    );
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("would replace the input") && err.contains("ok.swept.glb"),
        "{err}"
    );
    assert_eq!(fs::read(&g).unwrap(), before);
    assert_eq!(
        fs::read_dir(&out).unwrap().count(),
        1,
        "outputs were written"
    );

    // A trajectory named like the report, with and without --overwrite.
    let g = write(d, "part.gltf", gltf_doc(json!({})).to_string());
    let t = write(d, "a.report.json", CSV);
    for extra in [&["--name", "a"][..], &["--name", "a", "--overwrite"]] {
        let args = run_args(&g, &t, d, extra);
        expect_refused(d, &args, &["would replace the input", "a.report.json"]);
    }
    // A hard link to the trajectory under an output name.
    let linked = d.join("linked");
    fs::create_dir(&linked).unwrap();
    fs::hard_link(&t, linked.join("b.report.json")).unwrap();
    let args = run_args(&g, &t, &linked, &["--name", "b", "--overwrite"]);
    expect_refused(
        d,
        &args,
        &["would replace the input", "hard or symbolic link"],
    );
}

#[test]
fn numbers_beyond_f32_precision_are_refused_before_the_sweep_by_line() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let g = write(d, "part.gltf", gltf_doc(json!({})).to_string());
    for (file, row, needle) in [
        ("far.csv", "2,1e300,0,0,1,0,0,0", "1e300"),
        // Motion of 1e-3 around 1e6: the voxel is tiny against the coordinates.
        ("offset.csv", "2,1000000.001,0,0,1,0,0,0", "1% of a voxel"),
    ] {
        let lead = if file == "offset.csv" {
            "1000000,0,0"
        } else {
            "0,0,0"
        };
        let text = format!("frame,tx,ty,tz,qw,qx,qy,qz\n# far\n1,{lead},1,0,0,0\n{row}\n");
        let t = write(d, file, text);
        let started = Instant::now();
        let args = run_args(&g, &t, &d.join("results"), &["--resolution", "256"]);
        let err = expect_refused(d, &args, &[&format!("{file}:4"), needle, "fix:"]);
        assert!(
            started.elapsed() < Duration::from_secs(20),
            "refused only after the sweep"
        );
        // Never a number in 300 digits.
        let longest_digits = err
            .split(|c: char| !c.is_ascii_digit())
            .map(str::len)
            .max()
            .unwrap_or(0);
        assert!(longest_digits < 20, "{err}");
    }
}

/// Rows the screw motion cannot follow are refused by line, before the sweep, with the fix; the
/// same rows sweep with `--motion discrete`, which covers only the listed poses.
#[test]
fn motions_the_screw_cannot_follow_are_refused_by_line() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let g = write(d, "part.gltf", gltf_doc(json!({})).to_string());
    let head = "frame,tx,ty,tz,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n";
    for (file, row, needles) in [
        // A half turn about y: which way it turned is not in the rows.
        (
            "half.csv",
            "1,0,0,0,0,0,1,0",
            &[
                "half.csv:3",
                "180",
                "add a row between them",
                "set --motion to discrete",
            ][..],
        ),
        // Back in time.
        (
            "back.csv",
            "-1,0.1,0,0,1,0,0,0",
            &["back.csv:3", "back in time", "sort the rows"][..],
        ),
        // A time that is no number.
        (
            "nan.csv",
            "nan,0.1,0,0,1,0,0,0",
            &["nan.csv:3", "frame"][..],
        ),
    ] {
        let t = write(d, file, format!("{head}{row}\n"));
        let args = run_args(&g, &t, &d.join("results"), &[]);
        expect_refused(d, &args, needles);
        if file != "nan.csv" {
            let args = run_args(&g, &t, &d.join("results"), &["--motion", "discrete"]);
            let o = sweptvol(&args);
            assert!(o.status.success(), "{file} discrete: {}", stderr(&o));
            fs::remove_dir_all(d.join("results")).unwrap();
        }
    }
}

#[test]
fn a_run_that_cannot_fit_in_memory_is_refused_up_front() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let g = write(d, "part.gltf", gltf_doc(json!({})).to_string());
    let t = write(d, "part.csv", CSV);
    let args = run_args(&g, &t, &d.join("results"), &["--resolution", "12288"]);
    let quoted: Vec<String> = args.iter().map(|a| format!("'{a}'")).collect();
    let started = Instant::now();
    let o = Command::new("sh")
        .arg("-c")
        .arg(format!(
            "ulimit -v 4000000 && exec {BIN} {}",
            quoted.join(" ")
        ))
        .output()
        .unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("GiB")
            && err.contains("use --resolution")
            && err.contains("--no-memory-check"),
        "{err}"
    );
    assert!(
        started.elapsed() < Duration::from_secs(10),
        "not refused up front"
    );
    assert!(!d.join("results").exists());
}

#[test]
fn verify_stops_at_the_first_proven_failure_unless_asked_for_all() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let g = write(d, "part.gltf", gltf_doc(json!({})).to_string());
    // 200 poses along x; the tetrahedron below holds those with tx < 0.5 (x + y + z < 2).
    let mut text = String::from("frame,tx,ty,tz,qw,qx,qy,qz\n");
    for i in 0..200 {
        text += &format!("{i},{},0,0,1,0,0,0\n", i as f64 * 0.1);
    }
    let t = write(d, "part.csv", text);
    let mut bin = Vec::new();
    for c in [
        -1f32, -1.0, -1.0, 4.0, -1.0, -1.0, -1.0, 4.0, -1.0, -1.0, -1.0, 4.0,
    ] {
        bin.extend_from_slice(&c.to_le_bytes());
    }
    for i in [0u16, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3] {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    let mesh = json!({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3"},
            {"bufferView": 1, "componentType": 5123, "count": 12, "type": "SCALAR"}],
        "bufferViews": [{"buffer": 0, "byteLength": 48}, {"buffer": 0, "byteOffset": 48, "byteLength": 24}],
        "buffers": [{"byteLength": 72, "uri": format!("data:application/octet-stream;base64,{}",
            base64::engine::general_purpose::STANDARD.encode(&bin))}],
    });
    let m = write(d, "far.gltf", mesh.to_string());
    let report = |extra: &[&str]| -> Value {
        // The listed poses only: this test counts them (continuous motion adds middle poses).
        let base = ["--json", "--motion", "discrete"];
        let o = sweptvol(&verify_args(&g, &t, &m, &[&base[..], extra].concat()));
        assert_eq!(o.status.code(), Some(3), "{}", stderr(&o));
        serde_json::from_slice(&o.stdout).unwrap()
    };
    let all = report(&["--all-failures"]);
    let c = &all["containment"];
    assert_eq!(c["stopped_early"], false);
    assert_eq!(c["posed_triangles"], 200, "{c}");
    let outside = c["outside"].as_u64().unwrap();
    assert!((150..200).contains(&outside), "{c}");
    let fast = report(&[]);
    let c = &fast["containment"];
    assert_eq!(c["stopped_early"], true, "{c}");
    let (found, checked) = (
        c["outside"].as_u64().unwrap(),
        c["ball_tests"].as_u64().unwrap(),
    );
    assert!(found >= 1 && found < outside, "{c}");
    assert!(
        checked < all["containment"]["ball_tests"].as_u64().unwrap(),
        "{c}"
    );
    let failures = fast["failures"].to_string();
    assert!(failures.contains("--all-failures"), "{failures}");
}

#[test]
fn bad_option_values_exit_2_and_bad_files_say_what_they_are() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let g = write(d, "part.gltf", gltf_doc(json!({})).to_string());
    let t = write(d, "part.csv", CSV);
    let out = d.join("results");
    for (extra, needle) in [
        (
            &["--tolerance", "-1"][..],
            "--tolerance -1 must be a positive",
        ),
        (&["--resolution", "4"], "--resolution 4 is outside"),
        (&["--delta", "-0.5"], "--delta -0.5 must be a positive"),
        (
            &["--resolution", "64", "--delta", "1e-9"],
            "raise --delta or lower --epsilon",
        ),
    ] {
        // Each option is named as the command line spells it.
        let args = run_args(&g, &t, &out, extra);
        let err = expect_refused(d, &args, &[]);
        assert!(err.contains(needle), "{needle:?} not in {err}");
    }
    // A file that is no glTF at all: named as such, with its first bytes.
    let zip = write(d, "part.glb", b"PK\x03\x04zipped");
    let args = run_args(&zip, &t, &out, &[]);
    expect_refused(
        d,
        &args,
        &["part.glb", "not a glTF or GLB file", "50 4b 03 04", "fix:"],
    );
    // glTF 1.0.
    let mut doc = gltf_doc(json!({}));
    doc["asset"]["version"] = json!("1.0");
    let old = write(d, "old.gltf", doc.to_string());
    let args = run_args(&old, &t, &out, &[]);
    expect_refused(d, &args, &["old.gltf", "asset.version", "glTF 2.0"]);
    // verify --spacing absurdly fine: refused with the estimate.
    let args = verify_args(&g, &t, &g, &["--spacing", "1e-9"]);
    expect_refused(d, &args, &["--spacing", "samples", "use --spacing"]);
}

#[test]
fn a_quiet_successful_auto_run_prints_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let g = write(d, "part.gltf", gltf_doc(json!({})).to_string());
    let t = write(d, "part.csv", CSV);
    let out = d.join("results");
    let mut args = run_args(&g, &t, &out, &[]);
    let i = args.iter().position(|a| a == "cpu").unwrap();
    args[i] = "auto".into();
    let o = Command::new(BIN)
        .args(&args)
        .env_remove("RUST_LOG")
        .env_remove("XDG_RUNTIME_DIR")
        .env_remove("NODEVICE_SELECT")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(stderr(&o), "", "printed on a quiet success");
    assert!(o.stdout.is_empty());
}

#[test]
fn the_daemon_log_has_no_colour_codes_when_not_a_terminal() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let job = d.join("bad");
    fs::create_dir(&job).unwrap();
    write(&job, "generator.glb", b"not a glb");
    write(&job, "trajectory.csv", CSV);
    let o = sweptvol(&["watch", d.to_str().unwrap(), "--once", "--backend", "cpu"]);
    let err = stderr(&o);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("failed"), "{err}");
    assert!(!err.contains('\u{1b}'), "ANSI codes in the log: {err:?}");
    let status: Value =
        serde_json::from_slice(&fs::read(job.join("status.json")).unwrap()).unwrap();
    assert_eq!(status["state"], "failed");
    assert!(status["message"]
        .as_str()
        .unwrap()
        .contains("not a glTF or GLB file"));
}

/// Damaged files through the real binary: a truncated .glb, a .glb whose chunk length runs past
/// its end, and a .gltf whose triangle names a vertex it does not have.
#[test]
fn truncated_corrupted_and_out_of_range_generators_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let t = write(dir.path(), "part.csv", CSV);
    let out = dir.path().join("results");
    let bunny = fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/examples/bunny.glb")).unwrap();

    let half = write(dir.path(), "half.glb", &bunny[..bunny.len() / 2]);
    expect_refused(dir.path(), &run_args(&half, &t, &out, &[]), &["half.glb"]);

    let mut long = bunny.clone();
    let json_len = u32::from_le_bytes(long[12..16].try_into().unwrap());
    long[12..16].copy_from_slice(&(json_len + 1_000_000).to_le_bytes());
    let long = write(dir.path(), "long.glb", &long);
    expect_refused(dir.path(), &run_args(&long, &t, &out, &[]), &["long.glb"]);

    // Indices [0, 1, 99] into three vertices.
    let mut doc = gltf_doc(json!({}));
    let mut idx = Vec::new();
    for i in [0u32, 1, 99] {
        idx.extend_from_slice(&i.to_le_bytes());
    }
    doc["accessors"]
        .as_array_mut()
        .unwrap()
        .push(json!({"bufferView": 1, "componentType": 5125, "count": 3, "type": "SCALAR"}));
    doc["bufferViews"]
        .as_array_mut()
        .unwrap()
        .push(json!({"buffer": 1, "byteLength": 12}));
    doc["buffers"]
        .as_array_mut()
        .unwrap()
        .push(json!({"byteLength": 12,
        "uri": format!("data:application/octet-stream;base64,{}",
            base64::engine::general_purpose::STANDARD.encode(&idx))}));
    doc["meshes"][0]["primitives"][0]["indices"] = json!(1);
    let bad = write(dir.path(), "index.gltf", serde_json::to_vec(&doc).unwrap());
    expect_refused(
        dir.path(),
        &run_args(&bad, &t, &out, &[]),
        &["index.gltf", "99"],
    );
}

/// Issue 30, defect 1: a closed stderr (`run ... 2>&1 | head -1`) panicked and lost the whole
/// computation, and a closed stdout panicked `protocol`. Now a run whose log reader went away
/// after one line still writes every output and exits 0; so does `mesh --from`; `protocol`
/// into a closed pipe exits 0 quietly.
#[test]
fn closed_pipes_end_quietly_and_lose_nothing() {
    use std::io::BufRead;
    use std::process::Stdio;
    let dir = tempfile::tempdir().unwrap();
    let with_log_closed = |args: &[String]| {
        let mut child = Command::new(BIN)
            .args(args)
            .env("RUST_LOG", "info")
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let mut line = String::new();
        std::io::BufReader::new(child.stderr.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        assert!(!line.is_empty(), "no log line to read");
        child.wait().unwrap()
    };
    let g = Path::new("examples/bunny.glb");
    let t = Path::new("examples/bunny-vibration.csv");
    let out = dir.path().join("run");
    let mut args = run_args(g, t, &out, &["--resolution", "24"]);
    args.retain(|a| a != "--quiet");
    let code = with_log_closed(&args);
    assert!(code.success(), "run: {code}");
    assert_eq!(
        fs::read_dir(&out).unwrap().count(),
        8,
        "run: an output is missing"
    );

    // The same job as one shard, merged with the log closed.
    let shards = dir.path().join("shards");
    let mut sweep = run_args(g, t, &shards, &["--resolution", "24", "--shard", "1/1"]);
    sweep[0] = "sweep".into();
    assert!(sweptvol(&sweep).status.success());
    let merged = dir.path().join("merged");
    let code = with_log_closed(&[
        "mesh".into(),
        "--from".into(),
        shards.to_string_lossy().into_owned(),
        "--out".into(),
        merged.to_string_lossy().into_owned(),
    ]);
    assert!(code.success(), "mesh: {code}");
    assert_eq!(
        fs::read_dir(&merged).unwrap().count(),
        8,
        "mesh: an output is missing"
    );

    // stdout closed before anything is read.
    let mut child = Command::new(BIN)
        .arg("protocol")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let o = child.wait_with_output().unwrap();
    assert!(o.status.success(), "protocol: {} {}", o.status, stderr(&o));
    assert!(!stderr(&o).contains("panicked"), "{}", stderr(&o));
}

/// The files of `dir`: (outputs under final names, temporary files, markers).
fn published(dir: &Path) -> (Vec<String>, Vec<String>, Vec<String>) {
    let mut names: Vec<String> = fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    let tmp = names
        .iter()
        .filter(|n| n.contains(".tmp-"))
        .cloned()
        .collect();
    let marker = names
        .iter()
        .filter(|n| n.ends_with(".incomplete"))
        .cloned()
        .collect();
    let outputs = names.into_iter().filter(|n| !n.starts_with('.')).collect();
    (outputs, tmp, marker)
}

/// Issue 30, defect 7: a crash between the renames of the publish step left part of a set
/// under final names and temporary files that a later run kept. Killed after each of its
/// eight renames (an injected abort), a run leaves a marker; the next run, with or without
/// --overwrite, leaves exactly one complete set, no temporary file and no marker.
#[test]
fn a_run_killed_at_any_rename_is_completed_by_the_next() {
    let g = Path::new("examples/bunny.glb");
    let t = Path::new("examples/bunny-vibration.csv");
    for k in 0..8 {
        for overwrite in [false, true] {
            let dir = tempfile::tempdir().unwrap();
            let out = dir.path().join("out");
            let mut crash = run_args(g, t, &out, &["--resolution", "20"]);
            if overwrite {
                crash.push("--overwrite".into());
            }
            let o = Command::new(BIN)
                .args(&crash)
                .env("SWEPTVOL_TEST_ABORT_AFTER_RENAMES", k.to_string())
                .output()
                .unwrap();
            assert!(
                !o.status.success(),
                "k = {k}: the injected abort did not happen"
            );
            let (outputs, tmp, marker) = published(&out);
            assert_eq!(outputs.len(), k, "k = {k}: {outputs:?}");
            assert_eq!(marker.len(), 1, "k = {k}: no marker of the cut-off set");
            assert_eq!(tmp.len(), 8 - k, "k = {k}: {tmp:?}");

            let o = sweptvol(&crash);
            assert!(
                o.status.success(),
                "k = {k}, overwrite {overwrite}: {}",
                stderr(&o)
            );
            let (outputs, tmp, marker) = published(&out);
            assert_eq!(outputs.len(), 8, "k = {k}: {outputs:?}");
            assert!(
                tmp.is_empty() && marker.is_empty(),
                "k = {k}: {tmp:?} {marker:?}"
            );
        }
    }
}

/// Issue 30, defect 4: with --overwrite and NAME.report.json a folder, the mesh and the six
/// depth images were published before the run failed. Now it fails before any rename: nothing
/// is published, no temporary file or marker is left, and the folder is untouched.
#[test]
fn an_output_that_is_a_folder_stops_the_run_before_anything_is_published() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    fs::create_dir_all(out.join("bunny-vibration.report.json/inside")).unwrap();
    let args = run_args(
        Path::new("examples/bunny.glb"),
        Path::new("examples/bunny-vibration.csv"),
        &out,
        &["--resolution", "20", "--overwrite"],
    );
    let o = sweptvol(&args);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("is a folder"), "{}", stderr(&o));
    let (outputs, tmp, marker) = published(&out);
    assert_eq!(outputs, ["bunny-vibration.report.json"], "{outputs:?}");
    assert!(tmp.is_empty() && marker.is_empty(), "{tmp:?} {marker:?}");
    assert!(out.join("bunny-vibration.report.json/inside").is_dir());
}

/// Issue 30, weak spots: an empty or path-like --name, `watch --jobs 0` and `cluster status`
/// on a folder that does not exist were accepted (the last with exit 0); each is now refused
/// with exit 2, saying what is wrong.
#[test]
fn empty_names_zero_jobs_and_missing_shard_folders_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    for name in ["", "a/b", ".."] {
        let mut args = run_args(
            Path::new("examples/bunny.glb"),
            Path::new("examples/bunny-vibration.csv"),
            &out,
            &["--resolution", "16"],
        );
        args.extend(["--name".to_string(), name.to_string()]);
        let o = sweptvol(&args);
        assert_eq!(o.status.code(), Some(2), "--name {name:?}: {}", stderr(&o));
        assert!(stderr(&o).contains("file name stem"), "{}", stderr(&o));
        assert!(!out.exists(), "--name {name:?} wrote {}", out.display());
    }
    let o = sweptvol(&[
        "watch",
        dir.path().to_str().unwrap(),
        "--jobs",
        "0",
        "--once",
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("at least 1"), "{}", stderr(&o));

    let missing = dir.path().join("no-such-shards");
    let o = sweptvol(&["cluster", "status", missing.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("no-such-shards") && stderr(&o).contains("not a folder"),
        "{}",
        stderr(&o)
    );
}

/// Issue 30, weak spot: an --out that cannot be written (here a file stands where its folder
/// would be) was found only after the whole sweep, with exit 1. Now it is refused before the
/// sweep as a wrong option (exit 2), naming the folder, and nothing is written.
#[test]
fn an_unwritable_out_is_refused_before_the_sweep() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let blocker = write(d, "results", "a file, not a folder");
    let args = run_args(
        Path::new("examples/bunny.glb"),
        Path::new("examples/bunny-vibration.csv"),
        &blocker.join("sub"),
        &["--resolution", "64"],
    );
    let o = sweptvol(&args);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("--out") && err.contains("results is not a folder"),
        "{err}"
    );
    assert_eq!(fs::read(&blocker).unwrap(), b"a file, not a folder");
    // A folder where no file can be made, whoever runs the tests (root writes through a 0555
    // folder, but not into /proc).
    let args = run_args(
        Path::new("examples/bunny.glb"),
        Path::new("examples/bunny-vibration.csv"),
        Path::new("/proc/sweptvol-out"),
        &["--resolution", "64"],
    );
    let o = sweptvol(&args);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("cannot create files in /proc"),
        "{}",
        stderr(&o)
    );
}

/// Issue 30, weak spots: one pose at 1e20 was "zero extent" and rows at ±1e308 a "non-finite
/// bounding box", neither with file or line; `--delta 1e300` was blamed on the generator (with
/// its node named twice). Now each names the CSV line of the pose, or the option.
#[test]
fn far_poses_and_huge_offsets_name_their_line_or_option() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let g = write(d, "part.gltf", gltf_doc(json!({})).to_string());
    for (file, rows) in [
        ("far.csv", "0,1e20,1e20,1e20,1,0,0,0\n"),
        ("huge.csv", "0,1e308,0,0,1,0,0,0\n1,-1e308,0,0,1,0,0,0\n"),
    ] {
        let t = write(d, file, format!("frame,tx,ty,tz,qw,qx,qy,qz\n{rows}"));
        for motion in ["screw", "discrete"] {
            let args = run_args(&g, &t, &d.join("results"), &["--motion", motion]);
            let err = expect_refused(d, &args, &[&format!("{file}:2"), "f32", "fix:"]);
            assert!(
                !err.contains("zero extent") && !err.contains("non-finite"),
                "{err}"
            );
        }
    }
    let t = write(d, "part.csv", CSV);
    let args = run_args(&g, &t, &d.join("results"), &["--delta", "1e300"]);
    let err = expect_refused(d, &args, &["δ = 1e300", "f32", "pick a smaller --delta"]);
    assert!(!err.contains("part.gltf"), "blamed on the generator: {err}");
    // A node far out in the glTF itself is named once, as the place of the error.
    let far = write(
        d,
        "far.gltf",
        gltf_doc(json!({"translation": [3e38, 0.0, 0.0]})).to_string(),
    );
    let args = run_args(&far, &t, &d.join("results"), &[]);
    let err = expect_refused(d, &args, &["far.gltf", "nodes[0]"]);
    assert_eq!(err.matches("nodes[0]").count(), 1, "{err}");
}

/// Issue 30, weak spot: `verify --mesh` of a file that is not glTF told the user to re-export
/// the generator. Now the fix is about the mesh under test.
#[test]
fn verify_of_a_mesh_that_is_not_gltf_says_what_mesh_to_give() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let g = write(d, "part.gltf", gltf_doc(json!({})).to_string());
    let t = write(d, "part.csv", CSV);
    let args = verify_args(&g, &t, &t, &[]);
    let err = expect_refused(d, &args, &["part.csv", "not a glTF", "mesh to check"]);
    assert!(!err.contains("generator"), "{err}");
}

/// Issue 30, weak spot: a run with --overwrite left an earlier run's `.swept.stl` and
/// `.start.glb` beside its new mesh, where a reader takes them for this run's. Now they are
/// removed as the new set is published; without --overwrite one that is left stops the run.
#[test]
fn an_overwrite_run_removes_the_outputs_it_no_longer_writes() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let (g, t) = (
        Path::new("examples/bunny.glb"),
        Path::new("examples/bunny-vibration.csv"),
    );
    let first = run_args(
        g,
        t,
        &out,
        &["--resolution", "16", "--also", "stl", "--keep-start-mesh"],
    );
    let o = sweptvol(&first);
    assert!(o.status.success(), "{}", stderr(&o));
    let (stl, start) = (
        out.join("bunny-vibration.swept.stl"),
        out.join("bunny-vibration.start.glb"),
    );
    assert!(stl.exists() && start.exists());
    let o = sweptvol(&run_args(
        g,
        t,
        &out,
        &["--resolution", "20", "--overwrite"],
    ));
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!stl.exists() && !start.exists(), "stale outputs left");
    let (outputs, tmp, marker) = published(&out);
    assert_eq!(outputs.len(), 8, "{outputs:?}");
    assert!(tmp.is_empty() && marker.is_empty(), "{tmp:?} {marker:?}");
    // A lone earlier output of the same name is an existing output.
    for f in &outputs {
        fs::remove_file(out.join(f)).unwrap();
    }
    fs::write(&stl, b"solid old").unwrap();
    let o = sweptvol(&run_args(g, t, &out, &["--resolution", "16"]));
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("bunny-vibration.swept.stl") && stderr(&o).contains("--overwrite"),
        "{}",
        stderr(&o)
    );
    assert_eq!(fs::read(&stl).unwrap(), b"solid old");
}
