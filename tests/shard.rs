//! A job swept in shards and merged (`sweptvol sweep --shard I/N`, `sweptvol mesh`) gives what
//! `sweptvol run` gives, byte for byte; a shard set that is not one job's complete shards is
//! refused with an error naming the shard, and nothing is written.

use std::fs;
use std::path::{Path, PathBuf};

use fastrand::Rng;

mod common;
use common::files::{glb_parts, run_args, sweep_args, sweptvol, write, Part};

fn mesh_args(from: &[&Path], out: &Path) -> Vec<String> {
    let mut v = vec!["mesh".to_string(), "--quiet".into(), "--from".into()];
    v.extend(from.iter().map(|p| p.to_str().unwrap().to_string()));
    v.extend(["--out".into(), out.to_str().unwrap().into()]);
    v
}

fn ok(args: &[String]) {
    let o = sweptvol(args);
    assert!(
        o.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// The error of a command that must fail as a user error (exit 2), and write no `out`.
fn refused(args: &[String], out: &Path) -> String {
    let o = sweptvol(args);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
    assert!(err.contains("fix:"), "no fix in: {err}");
    assert!(!out.exists(), "{} was written: {err}", out.display());
    err
}

/// A random closed tetrahedron, or (`open`) a single triangle, about `centre`.
fn random_part(rng: &mut Rng, centre: [f32; 3], open: bool) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let pos: Vec<[f32; 3]> = (0..if open { 3 } else { 4 })
        .map(|_| std::array::from_fn(|c| centre[c] + rng.f32() * 2.0 - 1.0))
        .collect();
    let tris = if open {
        vec![[0, 1, 2]]
    } else {
        vec![[0, 1, 2], [0, 3, 1], [1, 3, 2], [2, 3, 0]]
    };
    (pos, tris)
}

/// A random job: 1 to 3 parts (closed, or one open), one of them possibly standing still (no
/// rows), 1 to 9 rows per moving part, screw or discrete motion, resolution 24 to 40.
fn random_job(rng: &mut Rng, dir: &Path) -> (PathBuf, PathBuf, Vec<String>) {
    let parts = 1 + rng.usize(..3);
    let open = rng.bool();
    let names = ["a", "b", "c"];
    let meshes: Vec<_> = (0..parts)
        .map(|i| random_part(rng, [i as f32 * 1.5, 0.0, 0.0], open && i == parts - 1))
        .collect();
    let refs: Vec<Part> = meshes
        .iter()
        .enumerate()
        .map(|(i, (p, t))| (names[i], p.as_slice(), t.as_slice()))
        .collect();
    let g = write(dir, "parts.glb", glb_parts(&refs));
    let mut csv = String::from("node,tx,ty,tz,qw,qx,qy,qz\n");
    let still = (parts > 1 && rng.bool()).then(|| rng.usize(..parts));
    for (i, name) in names.iter().enumerate().take(parts) {
        if still == Some(i) {
            continue;
        }
        for _ in 0..1 + rng.usize(..9) {
            let (ax, ay, az) = (rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() + 0.1);
            let norm = (ax * ax + ay * ay + az * az).sqrt();
            let half = (rng.f64() - 0.5) * 1.5;
            let (s, c) = half.sin_cos();
            csv += &format!(
                "{name},{},{},{},{c},{},{},{}\n",
                rng.f64() - 0.5,
                rng.f64() - 0.5,
                rng.f64() - 0.5,
                s * ax / norm,
                s * ay / norm,
                s * az / norm
            );
        }
    }
    let t = write(dir, "parts.csv", csv);
    let n = (24 + rng.u32(..17)).to_string();
    let motion = if rng.bool() { "screw" } else { "discrete" };
    let extra = ["--resolution", &n, "--motion", motion]
        .map(String::from)
        .to_vec();
    (g, t, extra)
}

/// Every file `run` wrote, with the same bytes from the merge; the reports equal but for the
/// timings, the backend's description and the output folder's name.
fn assert_same_outputs(run: &Path, merged: &Path, case: &str) {
    let mut names: Vec<_> = fs::read_dir(run)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    names.sort();
    let merged_names = fs::read_dir(merged).unwrap().count();
    assert_eq!(names.len(), merged_names, "{case}: other files");
    for name in names {
        let (a, b) = (
            fs::read(run.join(&name)).unwrap(),
            fs::read(merged.join(&name)).unwrap(),
        );
        if name.to_string_lossy().ends_with(".report.json") {
            let clean = |bytes: &[u8], dir: &Path| {
                let text = String::from_utf8(bytes.to_vec()).unwrap();
                let text = text.replace(dir.to_str().unwrap(), "OUT");
                let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
                v["timings"] = serde_json::Value::Null;
                v["backend"] = serde_json::Value::Null;
                v["classification"]["flood_seconds"] = serde_json::Value::Null;
                v
            };
            assert_eq!(clean(&a, run), clean(&b, merged), "{case}: report");
        } else {
            assert!(a == b, "{case}: {} differs", name.to_string_lossy());
        }
    }
}

/// Merging is exact: 1, 2, 3 and 7 shards of random jobs (several parts, one standing still,
/// fewer poses than shards, screw and discrete motion, flood and axes) give `run`'s bytes.
#[test]
fn shards_merge_to_the_runs_bytes() {
    let mut rng = Rng::with_seed(0x5a4d);
    for case in 0..6 {
        let dir = tempfile::tempdir().unwrap();
        let (g, t, extra) = random_job(&mut rng, dir.path());
        let extra: Vec<&str> = extra.iter().map(String::as_str).collect();
        let label = format!("case {case} {extra:?}");
        let run = dir.path().join("run");
        ok(&run_args(&g, &t, &run, &extra));
        let report: serde_json::Value =
            serde_json::from_slice(&fs::read(run.join("parts.report.json")).unwrap()).unwrap();
        let label = format!(
            "{label}: {} parts ({} still), {}",
            report["inputs"]["parts"].as_array().unwrap().len(),
            report["inputs"]["static_parts"].as_array().unwrap().len(),
            report["classification"]["method"]
        );
        eprintln!("{label}");
        for n in [1u32, 2, 3, 7] {
            let shards = dir.path().join(format!("shards-{n}"));
            for i in 1..=n {
                ok(&sweep_args(&g, &t, &shards, &format!("{i}/{n}"), &extra));
            }
            // The shards' windows tile every part's poses: disjoint, in order, complete.
            let mut poses = 0u64;
            let mut next: Vec<u64> = vec![];
            for i in 1..=n {
                let m: serde_json::Value = serde_json::from_slice(
                    &fs::read(shards.join(format!("shard-{i:04}-of-{n:04}.json"))).unwrap(),
                )
                .unwrap();
                poses += m["poses"].as_u64().unwrap();
                let windows = m["windows"].as_array().unwrap();
                next.resize(windows.len(), 0);
                for (p, w) in windows.iter().enumerate() {
                    assert_eq!(
                        w[0].as_u64().unwrap(),
                        next[p],
                        "{label}: shard {i}/{n} part {p}"
                    );
                    next[p] = w[1].as_u64().unwrap();
                }
            }
            let report: serde_json::Value =
                serde_json::from_slice(&fs::read(run.join("parts.report.json")).unwrap()).unwrap();
            assert_eq!(
                poses,
                report["counts"]["poses"].as_u64().unwrap(),
                "{label}: {n} shards"
            );
            let merged = dir.path().join(format!("merged-{n}"));
            ok(&mesh_args(&[&shards], &merged));
            assert_same_outputs(&run, &merged, &format!("{label}, {n} shards"));
        }
    }
}

/// Bad shard sets: each a clear error naming the shard or file, exit 2, no output.
#[test]
fn bad_shard_sets_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut rng = Rng::with_seed(11);
    let (pos, tris) = random_part(&mut rng, [0.0; 3], false);
    let g = write(d, "part.glb", glb_parts(&[("part", &pos, &tris)]));
    let rows = "tx,ty,tz,qw,qx,qy,qz\n0,0,0,1,0,0,0\n0.3,0,0,1,0,0,0\n0.6,0.1,0,1,0,0,0\n0.9,0.2,0,1,0,0,0\n";
    let t = write(d, "part.csv", rows);
    let shards = d.join("shards");
    for i in 1..=4 {
        ok(&sweep_args(&g, &t, &shards, &format!("{i}/4"), &[]));
    }
    let out = d.join("out");
    let shard = |i: u32, ext: &str| shards.join(format!("shard-{i:04}-of-0004.{ext}"));

    // A shard already swept for the same job is kept: its data is not written again.
    let before = fs::metadata(shard(2, "bin")).unwrap().modified().unwrap();
    ok(&sweep_args(&g, &t, &shards, "2/4", &[]));
    assert_eq!(
        fs::metadata(shard(2, "bin")).unwrap().modified().unwrap(),
        before
    );
    // Another job's shard into the same folder: refused unless --overwrite.
    let o = sweptvol(&sweep_args(&g, &t, &shards, "2/4", &["--resolution", "40"]));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("shard-0002-of-0004.json") && err.contains("other options"),
        "{err}"
    );
    assert_eq!(
        fs::metadata(shard(2, "bin")).unwrap().modified().unwrap(),
        before
    );

    // A missing shard.
    let json3 = fs::read(shard(3, "json")).unwrap();
    fs::remove_file(shard(3, "json")).unwrap();
    let err = refused(&mesh_args(&[&shards], &out), &out);
    assert!(err.contains("shard 3 of 4 missing"), "{err}");
    fs::write(shard(3, "json"), &json3).unwrap();

    // A shard of another job (other trajectory) or of other options, in a second folder.
    let other_t = write(
        d,
        "other.csv",
        "tx,ty,tz,qw,qx,qy,qz\n0,0,0,1,0,0,0\n0,0.5,0,1,0,0,0\n",
    );
    let foreign = d.join("foreign");
    ok(&sweep_args(
        &g,
        &other_t,
        &foreign,
        "4/4",
        &["--name", "part"],
    ));
    let err = refused(&mesh_args(&[&shards, &foreign], &out), &out);
    assert!(
        err.contains("foreign/shard-0004-of-0004.json") && err.contains("another job"),
        "{err}"
    );
    let options = d.join("options");
    ok(&sweep_args(
        &g,
        &t,
        &options,
        "4/4",
        &["--resolution", "40"],
    ));
    let err = refused(&mesh_args(&[&shards, &options], &out), &out);
    assert!(
        err.contains("options/shard-0004-of-0004.json") && err.contains("resolution"),
        "{err}"
    );
    // A shard of another split of the same job.
    let split = d.join("split");
    ok(&sweep_args(&g, &t, &split, "1/3", &[]));
    let err = refused(&mesh_args(&[&shards, &split], &out), &out);
    assert!(
        err.contains("split/shard-0001-of-0003.json") && err.contains("of 3"),
        "{err}"
    );
    // The same shard in two folders (a copy) counts once.
    let copy = d.join("copy");
    fs::create_dir(&copy).unwrap();
    for ext in ["json", "bin"] {
        fs::copy(
            shard(1, ext),
            copy.join(format!("shard-0001-of-0004.{ext}")),
        )
        .unwrap();
    }
    let merged = d.join("merged");
    ok(&mesh_args(&[&shards, &copy], &merged));
    assert!(merged.join("part.swept.glb").exists());
    // Issue 30: a corrupt copy was ignored with its folder second and refused with it first.
    // Now it is refused in either order, by its name, with the intact copy left as it is.
    let good = fs::read(copy.join("shard-0001-of-0004.bin")).unwrap();
    let mut bad = good.clone();
    bad[100] ^= 1;
    fs::write(copy.join("shard-0001-of-0004.bin"), &bad).unwrap();
    for order in [[shards.as_path(), &copy], [&copy, &shards]] {
        let err = refused(&mesh_args(&order, &out), &out);
        assert!(
            err.contains("copy/shard-0001-of-0004.bin") && err.contains("hash"),
            "{order:?}: {err}"
        );
    }
    fs::write(copy.join("shard-0001-of-0004.bin"), &good).unwrap();

    // Truncated data, and data of the right length that does not match its hash.
    let bin = fs::read(shard(2, "bin")).unwrap();
    fs::write(shard(2, "bin"), &bin[..bin.len() - 100]).unwrap();
    let err = refused(&mesh_args(&[&shards], &out), &out);
    assert!(
        err.contains("shard-0002-of-0004.bin") && err.contains("truncated"),
        "{err}"
    );
    let mut flipped = bin.clone();
    flipped[100] ^= 1;
    fs::write(shard(2, "bin"), &flipped).unwrap();
    let err = refused(&mesh_args(&[&shards], &out), &out);
    assert!(
        err.contains("shard-0002-of-0004.bin") && err.contains("hash"),
        "{err}"
    );
    fs::write(shard(2, "bin"), &bin).unwrap();
    // A manifest that is not one.
    fs::write(shard(4, "json"), "{\"format\": \"sweptvol-shard\"").unwrap();
    let err = refused(&mesh_args(&[&shards], &out), &out);
    assert!(
        err.contains("shard-0004-of-0004.json") && err.contains("manifest"),
        "{err}"
    );
    fs::remove_file(shard(4, "json")).unwrap();
    ok(&sweep_args(&g, &t, &shards, "4/4", &[]));
    // An input changed after the sweep.
    write(d, "part.csv", format!("{rows}1.2,0.2,0,1,0,0,0\n"));
    let err = refused(&mesh_args(&[&shards], &out), &out);
    assert!(
        err.contains("part.csv") && err.contains("changed since"),
        "{err}"
    );
    write(d, "part.csv", rows);
    // Issue 30: a count beyond the manifests' names is refused as `cluster submit` refuses it,
    // and the shards missing from a large split are summed up, not listed one by one.
    let o = sweptvol(&sweep_args(&g, &t, &d.join("big"), "1/99999", &[]));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("9999"), "{err}");
    let big = d.join("big");
    ok(&sweep_args(&g, &t, &big, "1/9999", &[]));
    ok(&sweep_args(&g, &t, &big, "5/9999", &[]));
    let err = refused(&mesh_args(&[&big], &out), &out);
    assert!(err.contains("9997 shards of 9999: 2-4, 6-9999"), "{err}");
    assert!(err.len() < 1000, "{} bytes: {err}", err.len());
    // The folder is named once, as the place of the error.
    assert_eq!(err.matches(big.to_str().unwrap()).count(), 1, "{err}");
    // No shards at all.
    let empty = d.join("empty");
    fs::create_dir(&empty).unwrap();
    let err = refused(&mesh_args(&[&empty], &out), &out);
    assert!(err.contains("no shard manifests"), "{err}");
    // And the restored set merges.
    ok(&mesh_args(&[&shards], &out));
    assert!(out.join("part.swept.glb").exists());
}

/// Issue 27: `cluster submit`'s tasks read the job from a file (`sweep --job FILE --shard I/N`)
/// instead of options turned back into arguments; the shards they write merge to `run`'s bytes,
/// and a file that is not a job file is refused by name.
#[test]
fn shards_swept_from_a_job_file_merge_to_the_runs_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut rng = Rng::with_seed(27);
    let (g, t, extra) = random_job(&mut rng, d);
    let extra: Vec<&str> = extra.iter().map(String::as_str).collect();
    let run = d.join("run");
    ok(&run_args(&g, &t, &run, &extra));
    // The options as `cluster::job_file` writes them: resolution and motion from `extra`.
    let n: u32 = extra[1].parse().unwrap();
    let shards = d.join("shards");
    let job = serde_json::json!({
        "generator": fs::canonicalize(&g).unwrap(),
        "trajectory": fs::canonicalize(&t).unwrap(),
        "out": shards,
        "options": {"resolution": n, "motion": extra[3], "backend": "cpu"},
    });
    let file = write(d, "job.json", serde_json::to_vec_pretty(&job).unwrap());
    for i in 1..=3 {
        ok(&[
            "sweep".to_string(),
            "--job".into(),
            file.to_str().unwrap().into(),
            "--shard".into(),
            format!("{i}/3"),
        ]);
    }
    let merged = d.join("merged");
    ok(&mesh_args(&[&shards], &merged));
    assert_same_outputs(&run, &merged, "job file, 3 shards");

    let bad = write(
        d,
        "bad.json",
        r#"{"generator": "g", "trajectory": "t", "out": "o", "options": {}, "shards": 3}"#,
    );
    let o = sweptvol(&["sweep", "--job", bad.to_str().unwrap(), "--shard", "1/3"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("bad.json") && err.contains("not a sweptvol job file"),
        "{err}"
    );
}
