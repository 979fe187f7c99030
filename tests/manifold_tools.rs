//! The output is a solid that downstream tools accept without repair: tests/manifold_check.py
//! (its own edge and fan count, trimesh's `is_watertight`/`is_volume`, manifold3d building a
//! `Manifold` and subtracting a box) on random voxel sets full of pinches, joined, and on the
//! real binary's output for random sweeps. The same check must fail on the plain (unjoined)
//! voxel boundary of pinched sets, so it can fail.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::Rng;
use sweptvol::input::grid::Grid;
use sweptvol::io::gltf_out;
use sweptvol::mesh::classify::DenseSet;
use sweptvol::mesh::extract::extract;
use sweptvol::mesh::manifold::Joined;
use sweptvol::mesh::Mesh;

/// The test Python with trimesh and manifold3d, or a loud skip (a failure under CI's settings).
fn python() -> Option<String> {
    common::test_python(
        "trimesh, manifold3d, numpy",
        "the downstream-tool manifold check",
    )
}

/// Run the checker on `files`; its exit status and output.
fn check(python: &str, files: &[PathBuf]) -> (bool, String) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/manifold_check.py");
    let out = Command::new(python)
        .arg(script)
        .args(files)
        .output()
        .expect("run the checker");
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    (out.status.success(), text)
}

fn write_glb(dir: &Path, name: &str, mesh: &Mesh) -> PathBuf {
    let grid = Grid {
        origin: [0.0; 3],
        h: 1.0,
        dims: [1, 1, 1],
    };
    let bytes = gltf_out::glb_bytes(mesh, &grid, name, serde_json::json!({})).unwrap();
    let path = dir.join(format!("{name}.glb"));
    std::fs::write(&path, bytes).unwrap();
    path
}

/// A random voxel set: sparse ones touch along edges and corners everywhere.
fn random_set(rng: &mut Rng, dims: [usize; 3], density: f64) -> DenseSet {
    let mut set = DenseSet::new(dims);
    for c in set.cells.iter_mut() {
        *c = rng.f64() < density;
    }
    set
}

#[test]
fn joined_voxel_sets_are_solids_to_trimesh_and_manifold3d() {
    let Some(python) = python() else { return };
    let dir = tempfile::tempdir().unwrap();
    let mut rng = Rng::with_seed(0x5eed_1234_abcd_0001);
    let mut sets = vec![
        (
            "edge-pair",
            DenseSet::from_list([4, 4, 3], &[[1, 1, 1], [2, 2, 1]]),
        ),
        (
            "corner-pair",
            DenseSet::from_list([4, 4, 4], &[[1, 1, 1], [2, 2, 2]]),
        ),
    ];
    for (i, density) in [0.2, 0.35, 0.5, 0.65].into_iter().enumerate() {
        let set = random_set(&mut rng, [9, 8, 7], density);
        sets.push((["random-a", "random-b", "random-c", "random-d"][i], set));
    }
    let (mut joined, mut plain) = (Vec::new(), Vec::new());
    for (name, set) in &sets {
        let j = Joined::new(set);
        assert!(!j.added().is_empty(), "{name} had no pinch to join");
        joined.push(write_glb(
            dir.path(),
            &format!("{name}-joined"),
            &extract(&j),
        ));
        plain.push(write_glb(
            dir.path(),
            &format!("{name}-plain"),
            &extract(set),
        ));
    }
    let (ok, out) = check(&python, &joined);
    assert!(ok, "joined voxel sets fail the downstream check:\n{out}");
    for p in &plain {
        let (ok, out) = check(&python, std::slice::from_ref(p));
        assert!(
            !ok,
            "the check passed a pinched voxel boundary, so it cannot fail:\n{out}"
        );
        assert!(out.contains("own count"), "{out}");
    }
    // trimesh, not only the check's own count, refuses a four-face edge.
    let (_, out) = check(&python, &plain[..1]);
    assert!(out.contains("trimesh: not watertight"), "{out}");
}

/// Write a generator (`mesh` at the identity) and a matrix CSV of `poses`.
fn write_job(dir: &Path, name: &str, mesh: &Mesh, poses: &[glam::DMat4]) -> (PathBuf, PathBuf) {
    let g = write_glb(dir, name, mesh);
    let mut csv = String::from("m00,m01,m02,m03,m10,m11,m12,m13,m20,m21,m22,m23,m30,m31,m32,m33\n");
    for m in poses {
        let rows = m.transpose().to_cols_array(); // row-major
        csv += &rows.map(|x| format!("{x:.17}")).join(",");
        csv += "\n";
    }
    let t = dir.join(format!("{name}.csv"));
    std::fs::write(&t, csv).unwrap();
    (g, t)
}

#[test]
fn random_sweeps_are_solids_to_trimesh_and_manifold3d() {
    let Some(python) = python() else { return };
    let dir = tempfile::tempdir().unwrap();
    let mut rng = Rng::with_seed(0x0dd_ba11_2024_0003);
    let mut outputs = Vec::new();
    let mut joined = 0;
    for seed in 0..6 {
        let tet = common::tetrahedron(&mut rng, 1.0, [0.0; 3]);
        let part = &tet.parts[0];
        let mesh = Mesh {
            positions: part.positions.iter().map(|p| p.as_dvec3()).collect(),
            triangles: part.triangles.clone(),
        };
        let poses = common::random_rigid_poses(&mut rng);
        let name = format!("sweep{seed}");
        let (g, t) = write_job(dir.path(), &name, &mesh, &poses);
        let out = dir.path().join(format!("out{seed}"));
        let run = Command::new(env!("CARGO_BIN_EXE_sweptvol"))
            .args(["run", "--backend", "cpu", "--quiet", "--resolution", "40"])
            .arg("--generator")
            .arg(&g)
            .arg("--trajectory")
            .arg(&t)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert!(
            run.status.success(),
            "{}",
            String::from_utf8_lossy(&run.stderr)
        );
        let report: serde_json::Value = serde_json::from_slice(
            &std::fs::read(out.join(format!("{name}.report.json"))).unwrap(),
        )
        .unwrap();
        assert_eq!(report["mesh"]["manifold"], true, "{}", report["mesh"]);
        joined += report["mesh"]["joined_voxels"].as_u64().unwrap();
        outputs.push(out.join(format!("{name}.swept.glb")));
    }
    let (ok, out) = check(&python, &outputs);
    assert!(ok, "sweptvol's outputs fail the downstream check:\n{out}");
    eprintln!("{out}{joined} voxels joined over the six sweeps");
}
