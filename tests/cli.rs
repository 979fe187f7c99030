//! The real binary in fresh temporary folders: a good run, and every kind of bad input giving
//! its clear error while writing nothing.

use std::fs;
use std::path::{Path, PathBuf};

use base64::Engine;

mod common;
use common::files::{run_args, sweptvol, write};

/// A .gltf with the given named nodes, each carrying a one-triangle mesh, buffer as a data URI.
fn write_gltf(dir: &Path, file: &str, node_names: &[&str], uri: Option<&str>) -> PathBuf {
    let mut bin = Vec::new();
    for v in [[0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.5]] {
        for c in v {
            bin.extend_from_slice(&c.to_le_bytes());
        }
    }
    let data_uri = format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(&bin)
    );
    let nodes: Vec<serde_json::Value> = node_names
        .iter()
        .enumerate()
        .map(|(i, n)| serde_json::json!({"name": n, "mesh": 0, "translation": [i as f64 * 2.0, 0.0, 0.0]}))
        .collect();
    let doc = serde_json::json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": (0..node_names.len()).collect::<Vec<_>>()}],
        "nodes": nodes,
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                        "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.5]}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "buffers": [{"byteLength": 36, "uri": uri.unwrap_or(&data_uri)}],
    });
    let path = dir.join(file);
    fs::write(&path, serde_json::to_vec_pretty(&doc).unwrap()).unwrap();
    path
}

const GOOD_CSV: &str =
    "# two poses\nframe,tx,ty,tz,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n1,0.1,0,0,1,0,0,0\n";

#[test]
fn good_run_writes_all_outputs_and_never_overwrites_silently() {
    let dir = tempfile::tempdir().unwrap();
    let g = write_gltf(dir.path(), "part.gltf", &["part"], None);
    let t = write(dir.path(), "part.csv", GOOD_CSV);
    let out = dir.path().join("results");
    let o = sweptvol(&run_args(&g, &t, &out, &[]));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mut names: Vec<String> = fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(
        names,
        [
            "part.depth-xmax.exr",
            "part.depth-xmin.exr",
            "part.depth-ymax.exr",
            "part.depth-ymin.exr",
            "part.depth-zmax.exr",
            "part.depth-zmin.exr",
            "part.report.json",
            "part.swept.glb"
        ]
    );
    let report: serde_json::Value =
        serde_json::from_slice(&fs::read(out.join("part.report.json")).unwrap()).unwrap();
    // One triangle, rendered at each row and at the sub-poses of the screw motion between them.
    assert_eq!(report["motion"]["model"], "screw");
    assert!(report["motion"]["poses_rendered"].as_u64().unwrap() > 2);
    assert_eq!(
        report["counts"]["posed_triangles"],
        report["motion"]["poses_rendered"]
    );
    assert_eq!(report["resolution"], 32);
    assert!(report["parameters"]["rounding"].as_f64().unwrap() > 0.0);
    for key in ["read_inputs", "setup", "sweep", "write_outputs", "total"] {
        assert!(report["timings"][key].as_f64().is_some(), "timing {key}");
    }

    // A second run refuses to overwrite and leaves the files as they were.
    let before = fs::read(out.join("part.depth-zmin.exr")).unwrap();
    let o = sweptvol(&run_args(&g, &t, &out, &[]));
    assert_eq!(
        o.status.code(),
        Some(2),
        "an existing output is a usage error"
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("already exists") && err.contains("--overwrite"),
        "{err}"
    );
    assert_eq!(before, fs::read(out.join("part.depth-zmin.exr")).unwrap());

    // --overwrite replaces them; --name changes the stem.
    let args = run_args(&g, &t, &out, &["--overwrite", "--name", "other"]);
    let o = sweptvol(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.join("other.report.json").exists());
}

/// Run with a bad input; expect exit code 2, every `needle` in stderr, and no output folder.
fn expect_input_error(gltf: &Path, csv: &Path, needles: &[&str]) {
    let out = gltf.parent().unwrap().join("results");
    let o = sweptvol(&run_args(gltf, csv, &out, &[]));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "exit code for {needles:?}: {err}");
    for n in needles {
        assert!(err.contains(n), "stderr lacks {n:?}: {err}");
    }
    assert!(err.contains("fix:"), "no fix in: {err}");
    assert!(
        !out.exists(),
        "an output folder was created for a bad input: {err}"
    );
}

#[test]
fn bad_trajectories_are_refused_by_file_line_and_column() {
    let dir = tempfile::tempdir().unwrap();
    let g = write_gltf(dir.path(), "part.gltf", &["part", "twin", "twin"], None);
    let header = "frame,tx,ty,tz,qw,qx,qy,qz\n";
    let cases: &[(&str, String, &[&str])] = &[
        ("nan.csv", format!("{header}0,0,0,0,1,0,0,0\n1,nan,0,0,1,0,0,0\n"), &["nan.csv:3", "tx"]),
        ("quat.csv", format!("{header}0,0,0,0,0.5,0,0,0\n"), &["quat.csv:2", "qw", "unit quaternion"]),
        ("empty.csv", header.to_string(), &["empty.csv", "at least one pose"]),
        ("typo.csv", "frame,tx,ty,tz,qw,qx,qy,qzz\n0,0,0,0,1,0,0,0\n".into(), &["typo.csv:1", "qzz"]),
        (
            "singular.csv",
            "m00,m01,m02,m03,m10,m11,m12,m13,m20,m21,m22,m23,m30,m31,m32,m33\n1,0,0,0,0,1,0,0,0,0,0,0,0,0,0,1\n".into(),
            &["singular.csv:2", "singular"],
        ),
        (
            "lastrow.csv",
            "# comment\nm00,m01,m02,m03,m10,m11,m12,m13,m20,m21,m22,m23,m30,m31,m32,m33\n1,0,0,0,0,1,0,0,0,0,1,0,0,0.5,0,1\n".into(),
            &["lastrow.csv:3", "m31", "0 0 0 1"],
        ),
        ("unknown.csv", format!("node,{header}wheel,0,0,0,0,1,0,0,0\n"), &["unknown.csv:2", "node", "wheel"]),
        ("ambiguous.csv", format!("node,{header}twin,0,0,0,0,1,0,0,0\n"), &["ambiguous.csv:2", "twin", "ambiguous"]),
    ];
    for (file, text, needles) in cases {
        let t = write(dir.path(), file, text);
        expect_input_error(&g, &t, needles);
    }
}

#[test]
fn bad_generators_are_refused_by_file() {
    let dir = tempfile::tempdir().unwrap();
    let t = write(dir.path(), "part.csv", GOOD_CSV);
    let garbage = write(dir.path(), "garbage.glb", "this is not a glTF file");
    expect_input_error(&garbage, &t, &["garbage.glb"]);

    fs::write(dir.path().parent().unwrap().join("outside.bin"), [0u8; 36]).ok();
    let escaping = write_gltf(
        dir.path(),
        "escaping.gltf",
        &["part"],
        Some("../outside.bin"),
    );
    expect_input_error(&escaping, &t, &["escaping.gltf", "../outside.bin"]);

    let missing = write_gltf(dir.path(), "missing.gltf", &["part"], Some("nowhere.bin"));
    expect_input_error(&missing, &t, &["missing.gltf", "nowhere.bin"]);

    let empty = write(
        dir.path(),
        "empty.gltf",
        r#"{"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[0]}],"nodes":[{"name":"empty"}]}"#,
    );
    expect_input_error(&empty, &t, &["empty.gltf", "triangles"]);

    // Geometry the reader would otherwise ignore: shape keys in use, GPU instancing.
    let morph = write_gltf(dir.path(), "morph.gltf", &["part"], None);
    let mut doc: serde_json::Value = serde_json::from_slice(&fs::read(&morph).unwrap()).unwrap();
    let target = doc["accessors"][0].clone();
    doc["accessors"].as_array_mut().unwrap().push(target);
    doc["meshes"][0]["primitives"][0]["targets"] = serde_json::json!([{"POSITION": 1}]);
    doc["meshes"][0]["weights"] = serde_json::json!([1.0]);
    fs::write(&morph, serde_json::to_vec(&doc).unwrap()).unwrap();
    expect_input_error(&morph, &t, &["morph.gltf", "morph targets", "shape keys"]);

    let instanced = write_gltf(dir.path(), "instanced.gltf", &["part"], None);
    let mut doc: serde_json::Value =
        serde_json::from_slice(&fs::read(&instanced).unwrap()).unwrap();
    doc["extensionsUsed"] = serde_json::json!(["EXT_mesh_gpu_instancing"]);
    fs::write(&instanced, serde_json::to_vec(&doc).unwrap()).unwrap();
    expect_input_error(
        &instanced,
        &t,
        &["instanced.gltf", "EXT_mesh_gpu_instancing"],
    );

    // A NaN vertex.
    let nan = write_gltf(dir.path(), "nan.gltf", &["part"], None);
    let mut doc: serde_json::Value = serde_json::from_slice(&fs::read(&nan).unwrap()).unwrap();
    let mut bin = vec![0u8; 36];
    bin[0..4].copy_from_slice(&f32::NAN.to_le_bytes());
    doc["buffers"][0]["uri"] = format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(&bin)
    )
    .into();
    fs::write(&nan, serde_json::to_vec(&doc).unwrap()).unwrap();
    expect_input_error(&nan, &t, &["nan.gltf"]);
}

#[test]
fn bad_settings_are_refused_before_writing() {
    let dir = tempfile::tempdir().unwrap();
    let g = write_gltf(dir.path(), "part.gltf", &["part"], None);
    let t = write(dir.path(), "part.csv", GOOD_CSV);
    let out = dir.path().join("results");
    for extra in [
        &["--resolution", "4"][..],
        &["--delta", "0.0001"][..],
        &["--name", "../up"][..],
    ] {
        let args = run_args(&g, &t, &out, extra);
        let o = sweptvol(&args);
        assert!(!o.status.success(), "{extra:?} was accepted");
        assert!(!String::from_utf8_lossy(&o.stderr).is_empty());
        assert!(!out.exists(), "{extra:?} created outputs");
    }
}

/// `--also stl,ply,obj` writes the same mesh in those formats beside the .glb, lists them in the
/// report, and keeps the no-overwrite rule for them too; an unknown format is a usage error.
#[test]
fn also_writes_stl_ply_and_obj_of_the_same_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let g = write_gltf(dir.path(), "part.gltf", &["part"], None);
    let t = write(dir.path(), "part.csv", GOOD_CSV);
    let out = dir.path().join("results");
    let args = run_args(&g, &t, &out, &["--also", "obj,stl,ply,stl"]);
    let o = sweptvol(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report: serde_json::Value =
        serde_json::from_slice(&fs::read(out.join("part.report.json")).unwrap()).unwrap();
    let triangles = report["mesh"]["triangles_final"].as_u64().unwrap();
    let outputs: Vec<String> = report["outputs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p.as_str().unwrap().to_string())
        .collect();
    for ext in ["stl", "ply", "obj"] {
        let name = format!("part.swept.{ext}");
        assert_eq!(
            outputs.iter().filter(|p| p.ends_with(&name)).count(),
            1,
            "{outputs:?}"
        );
    }
    let stl = fs::read(out.join("part.swept.stl")).unwrap();
    let facets = u32::from_le_bytes(stl[80..84].try_into().unwrap()) as u64;
    assert_eq!((facets, stl.len() as u64), (triangles, 84 + 50 * triangles));
    // Facet by facet the .glb's triangles, at the .glb's f32 positions.
    let glb = sweptvol::io::gltf_in::read_generator(&out.join("part.swept.glb")).unwrap();
    let part = &glb.parts[0];
    for (f, t) in part.triangles.iter().enumerate() {
        let rec = &stl[84 + 50 * f + 12..84 + 50 * f + 48];
        let corners: Vec<f32> = rec
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
            .collect();
        let want: Vec<f32> = t
            .iter()
            .flat_map(|&v| part.positions[v as usize].to_array())
            .collect();
        assert_eq!(corners, want, "facet {f}");
    }
    let obj = fs::read_to_string(out.join("part.swept.obj")).unwrap();
    assert_eq!(
        obj.lines().filter(|l| l.starts_with("f ")).count() as u64,
        triangles
    );
    let ply = fs::read(out.join("part.swept.ply")).unwrap();
    assert!(String::from_utf8_lossy(&ply[..200]).contains(&format!("element face {triangles}\n")));

    // An existing .stl blocks a run that would write it, and is left as it was.
    fs::remove_file(out.join("part.swept.glb")).unwrap();
    let o = sweptvol(&args);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("already exists"));
    assert_eq!(stl, fs::read(out.join("part.swept.stl")).unwrap());
    assert!(!out.join("part.swept.glb").exists());

    let bad = run_args(&g, &t, &out, &["--also", "step", "--name", "other"]);
    let o = sweptvol(&bad);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("step"));
}

/// `sweptvol protocol` names exactly what a run writes (for clients in other languages).
#[test]
fn protocol_names_are_the_files_a_run_writes() {
    let o = sweptvol(&["protocol"]);
    assert!(o.status.success());
    let names: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let out = &names["outputs"];
    let mut want: Vec<String> = ["mesh", "start_mesh", "report"]
        .iter()
        .map(|k| out[k].as_str().unwrap().to_string())
        .collect();
    want.extend(
        out["depth_images"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_str().unwrap().to_string()),
    );
    want.extend(
        out["also"]
            .as_object()
            .unwrap()
            .values()
            .map(|v| v.as_str().unwrap().to_string()),
    );
    want.sort();

    let dir = tempfile::tempdir().unwrap();
    let g = write_gltf(dir.path(), "part.gltf", &["part"], None);
    let t = write(dir.path(), "part.csv", GOOD_CSV);
    let res = dir.path().join("results");
    let args = run_args(
        &g,
        &t,
        &res,
        &["--keep-start-mesh", "--also", "stl,ply,obj"],
    );
    let o = sweptvol(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mut written: Vec<String> = fs::read_dir(&res)
        .unwrap()
        .map(|e| {
            e.unwrap()
                .file_name()
                .to_string_lossy()
                .trim_start_matches("part.")
                .to_string()
        })
        .collect();
    written.sort();
    assert_eq!(written, want);
    assert_eq!(names["job_files"]["job_json"], "job.json");
}

/// The outputs do not depend on the thread count: the bundled example's mesh and depth images
/// are byte-identical on one thread and on two (the report differs in timings only).
#[test]
fn outputs_are_the_same_on_one_thread_and_on_two() {
    let dir = tempfile::tempdir().unwrap();
    let run = |threads: &str| {
        let out = dir.path().join(format!("t{threads}"));
        let status = std::process::Command::new(env!("CARGO_BIN_EXE_sweptvol"))
            .args(run_args(
                Path::new("examples/bunny.glb"),
                Path::new("examples/bunny-vibration.csv"),
                &out,
                &["--resolution", "80", "--also", "stl"],
            ))
            .env("RAYON_NUM_THREADS", threads)
            .env("RUST_LOG", "warn")
            .status()
            .unwrap();
        assert!(status.success());
        let mut files: Vec<(String, Vec<u8>)> = fs::read_dir(&out)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| !p.to_string_lossy().ends_with(".report.json"))
            .map(|p| {
                (
                    p.file_name().unwrap().to_string_lossy().into_owned(),
                    fs::read(&p).unwrap(),
                )
            })
            .collect();
        files.sort();
        files
    };
    let (one, two) = (run("1"), run("2"));
    assert_eq!(
        one.len(),
        8,
        "mesh, STL, six depth images: {:?}",
        one.iter().map(|f| &f.0).collect::<Vec<_>>()
    );
    for ((name, a), (_, b)) in one.iter().zip(&two) {
        assert!(a == b, "{name} differs between one thread and two");
    }
}

/// Issue 27: report.json reads back as the library's typed `Report` (the SLURM path reads the
/// merge's report so, not as untyped JSON), and writes back the same JSON.
#[test]
fn a_report_reads_back_as_the_typed_report() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let g = write_gltf(d, "part.gltf", &["a", "b"], None);
    let t = write(
        d,
        "part.csv",
        "node,tx,ty,tz,qw,qx,qy,qz\na,0,0,0,1,0,0,0\na,0.2,0,0,1,0,0,0\n",
    );
    let out = d.join("out");
    let o = sweptvol(&run_args(
        &g,
        &t,
        &out,
        &["--resolution", "24", "--also", "obj"],
    ));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = fs::read_to_string(out.join("part.report.json")).unwrap();
    let report: sweptvol::pipeline::Report = serde_json::from_str(&text).unwrap();
    let again = serde_json::to_value(&report).unwrap();
    let written: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(again, written);
    assert_eq!(report.inputs.static_parts, ["b"]);
}
