//! Robots in their own formats (`run --robot URDF --joints CSV`): the bundled UR5 description
//! (examples/ur5, unmodified from Gepetto/example-robot-data) swept along a joint path is
//! enclosed at every instant of the joint-linear motion (checked with this file's own forward
//! kinematics from the URDF's numbers and its own STL reading, and by `verify`); primitives are
//! meshed around the true shapes; a step over 180° follows the joint, not the shortest turn;
//! limits are warned about; malformed descriptions and joint files are refused by name with no
//! output written; a mesh file edited after a robot's shards were swept stops their merge.

mod common;

use std::path::{Path, PathBuf};

use common::files::{self, sweptvol};
use common::{winding_number, V3};
use glam::{DMat3, DMat4, DVec3};

fn ur5() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("examples/ur5/example-robot-data/robots/ur_description/urdf/ur5_robot.urdf")
}

fn joints_csv() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/ur5/ur5-joints.csv")
}

/// `sweptvol run --robot urdf --joints csv --out dir` on the CPU, quietly, then `extra`.
fn run(urdf: &Path, csv: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    let mut args: Vec<String> = vec![
        "run".into(),
        "--robot".into(),
        urdf.to_str().unwrap().into(),
        "--joints".into(),
        csv.to_str().unwrap().into(),
        "--out".into(),
        out.to_str().unwrap().into(),
        "--backend".into(),
        "cpu".into(),
        "--quiet".into(),
    ];
    args.extend(extra.iter().map(|s| s.to_string()));
    sweptvol(&args)
}

/// An output mesh as points and triangles for winding numbers.
fn output_mesh(path: &Path) -> (Vec<V3>, Vec<[u32; 3]>) {
    let mesh = sweptvol::io::gltf_in::read_world_triangles(path).unwrap();
    let pos = mesh.iter().flatten().map(|v| v.to_array()).collect();
    let tris = (0..mesh.len() as u32)
        .map(|t| [3 * t, 3 * t + 1, 3 * t + 2])
        .collect();
    (pos, tris)
}

/// The vertices of a binary STL, read here (not by the library).
fn stl_vertices(path: &Path) -> Vec<DVec3> {
    let b = std::fs::read(path).unwrap();
    let n = u32::from_le_bytes(b[80..84].try_into().unwrap()) as usize;
    assert_eq!(b.len(), 84 + 50 * n, "{} is binary STL", path.display());
    let f = |o: usize| f32::from_le_bytes(b[o..o + 4].try_into().unwrap()) as f64;
    (0..n)
        .flat_map(|t| (0..3).map(move |v| 84 + 50 * t + 12 + 12 * v))
        .map(|o| DVec3::new(f(o), f(o + 4), f(o + 8)))
        .collect()
}

/// A joint of a chain: its origin, its axis and its column in the joint CSV (none: fixed).
type Joint = (DMat4, DVec3, Option<usize>);

/// A point of a primitive's surface at two angles.
type Surface<'a> = &'a dyn Fn(f64, f64) -> DVec3;

/// The UR5's chain by this file's own reading of the URDF: for each link with a collision mesh,
/// its mesh vertices and the list of (origin, axis, joint column) from the root.
fn ur5_links() -> Vec<(Vec<DVec3>, Vec<Joint>)> {
    let robot = urdf_rs::read_file(ur5()).unwrap();
    let header = std::fs::read_to_string(joints_csv()).unwrap();
    let columns: Vec<&str> = header.lines().next().unwrap().split(',').collect();
    let meshes = ur5()
        .parent()
        .unwrap()
        .parent()
        .unwrap()
        .join("meshes/ur5/collision");
    let mut out = Vec::new();
    for link in &robot.links {
        let Some(c) = link.collision.first() else {
            continue;
        };
        let vertices = match &c.geometry {
            urdf_rs::Geometry::Mesh { filename, .. } => {
                stl_vertices(&meshes.join(Path::new(filename).file_name().unwrap()))
            }
            urdf_rs::Geometry::Box { size } => (0..8)
                .map(|k| {
                    DVec3::from_array(std::array::from_fn(|a| {
                        size[a] / 2.0 * if k >> a & 1 == 1 { 1.0 } else { -1.0 }
                    }))
                })
                .collect(),
            other => panic!("{other:?}"),
        };
        let mut chain = Vec::new();
        let mut at = link.name.clone();
        while let Some(j) = robot.joints.iter().find(|j| j.child.link == at) {
            let [r, p, y] = *j.origin.rpy;
            let rot =
                DMat3::from_rotation_z(y) * DMat3::from_rotation_y(p) * DMat3::from_rotation_x(r);
            let origin =
                DMat4::from_translation(DVec3::from_array(*j.origin.xyz)) * DMat4::from_mat3(rot);
            let col = columns.iter().position(|c| *c == j.name);
            chain.push((origin, DVec3::from_array(*j.axis.xyz), col));
            at = j.parent.link.clone();
        }
        chain.reverse();
        out.push((vertices, chain));
    }
    out
}

/// The bundled UR5 along its joint path: every 7th vertex of every link at 12 instants of each
/// interval of the joint-linear motion lies inside the output, and `verify --robot` passes with
/// the run's bound.
#[test]
fn the_ur5_is_enclosed_along_its_joint_linear_path() {
    let dir = tempfile::tempdir().unwrap();
    let out = run(&ur5(), &joints_csv(), dir.path(), &["--resolution", "48"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mesh_path = dir.path().join("ur5-joints.swept.glb");
    let (pos, tris) = output_mesh(&mesh_path);
    let rows: Vec<Vec<f64>> = std::fs::read_to_string(joints_csv())
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|c| c.parse().unwrap()).collect())
        .collect();
    let links = ur5_links();
    assert_eq!(links.len(), 8, "links with collision meshes");
    let mut outside = 0;
    let mut checked = 0;
    for w in rows.windows(2) {
        for k in 0..=12 {
            let s = k as f64 / 12.0;
            for (vertices, chain) in &links {
                let m = chain
                    .iter()
                    .fold(DMat4::IDENTITY, |m, (origin, axis, col)| {
                        let q = col.map_or(0.0, |c| w[0][c] + s * (w[1][c] - w[0][c]));
                        m * *origin * DMat4::from_axis_angle(axis.normalize(), q)
                    });
                for v in vertices.iter().step_by(7) {
                    checked += 1;
                    let p = m.transform_point3(*v).to_array();
                    if winding_number(&pos, &tris, p) <= 0.99 {
                        outside += 1;
                    }
                }
            }
        }
    }
    println!("UR5: {checked} points of the joint-linear motion checked, {outside} outside");
    assert_eq!(outside, 0);
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("ur5-joints.report.json")).unwrap())
            .unwrap();
    assert_eq!(report["inputs"]["rows"], "local");
    assert_eq!(report["motion"]["model"], "screw");
    let bound = report["mesh"]["hausdorff_bound"]
        .as_f64()
        .unwrap()
        .to_string();
    let (urdf, csv) = (ur5(), joints_csv());
    let args = [
        "verify",
        "--robot",
        urdf.to_str().unwrap(),
        "--joints",
        csv.to_str().unwrap(),
        "--mesh",
        mesh_path.to_str().unwrap(),
        "--bound",
        &bound,
        "--quiet",
    ];
    let v = sweptvol(&args);
    assert!(v.status.success(), "{}", String::from_utf8_lossy(&v.stdout));
}

/// A one-link robot from a URDF of primitives, written here.
fn primitive_robot(dir: &Path, geometry: &str, joint: &str, csv: &str) -> (PathBuf, PathBuf) {
    let urdf = format!(
        r#"<?xml version="1.0"?>
<robot name="r">
  <link name="base"/>
  <link name="arm">
    <collision><origin xyz="0.5 0 0" rpy="0 0 0"/><geometry>{geometry}</geometry></collision>
  </link>
  {joint}
</robot>"#
    );
    (
        files::write(dir, "r.urdf", urdf),
        files::write(dir, "r.csv", csv),
    )
}

const HINGE: &str = r#"<joint name="hinge" type="continuous"><parent link="base"/><child link="arm"/><axis xyz="0 0 1"/></joint>"#;

/// Points on the true sphere, cylinder and box lie inside the output of a robot that holds still:
/// the primitives' polyhedra lie around them.
#[test]
fn primitives_are_meshed_around_their_true_shapes() {
    let dir = tempfile::tempdir().unwrap();
    let shapes: [(&str, Surface); 3] = [
        (r#"<sphere radius="0.3"/>"#, &|u, v| {
            DVec3::new(u.cos() * v.cos(), u.sin() * v.cos(), v.sin()) * 0.3
        }),
        (r#"<cylinder radius="0.25" length="0.6"/>"#, &|u, v| {
            DVec3::new(0.25 * u.cos(), 0.25 * u.sin(), 0.3 * v.sin())
        }),
        (r#"<box size="0.4 0.2 0.6"/>"#, &|u, v| {
            DVec3::new(0.2 * u.cos().signum(), 0.1 * u.sin(), 0.3 * v.sin())
        }),
    ];
    for (k, (geometry, surface)) in shapes.iter().enumerate() {
        let (urdf, csv) = primitive_robot(dir.path(), geometry, HINGE, "time,hinge\n0,0\n");
        let out_dir = dir.path().join(format!("out{k}"));
        let out = run(
            &urdf,
            &csv,
            &out_dir,
            &["--resolution", "40", "--motion", "discrete"],
        );
        assert!(
            out.status.success(),
            "{geometry}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let (pos, tris) = output_mesh(&out_dir.join("r.swept.glb"));
        for i in 0..40 {
            for j in 0..20 {
                let (u, v) = (i as f64 * 0.157, j as f64 * 0.157 - 1.5);
                let p = (surface(u, v) + DVec3::new(0.5, 0.0, 0.0)).to_array();
                assert!(
                    winding_number(&pos, &tris, p) > 0.99,
                    "{geometry}: {p:?} outside"
                );
            }
        }
    }
}

/// A continuous joint turning 270° in one step sweeps the long way round (the joint's way),
/// split into joint-linear rows: the arm's tip at 135° is inside, at -45° it is not.
#[test]
fn a_long_turn_follows_the_joint() {
    let dir = tempfile::tempdir().unwrap();
    let (urdf, csv) = primitive_robot(
        dir.path(),
        r#"<box size="0.8 0.1 0.1"/>"#,
        HINGE,
        "time,hinge\n0,0\n1,4.71238898\n",
    );
    let out = run(&urdf, &csv, dir.path(), &["--resolution", "48"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let (pos, tris) = output_mesh(&dir.path().join("r.swept.glb"));
    let at = |deg: f64| {
        let a = deg.to_radians();
        winding_number(&pos, &tris, [0.8 * a.cos(), 0.8 * a.sin(), 0.0]) > 0.5
    };
    assert!(at(135.0) && at(200.0) && at(260.0), "the long way is swept");
    assert!(!at(-45.0), "the short way is not swept");
}

/// A joint value beyond its limits is a warning in the report, not a clamp.
#[test]
fn joint_limits_are_warned_about() {
    let dir = tempfile::tempdir().unwrap();
    let joint = r#"<joint name="hinge" type="revolute"><parent link="base"/><child link="arm"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>"#;
    let (urdf, csv) = primitive_robot(
        dir.path(),
        r#"<box size="0.8 0.1 0.1"/>"#,
        joint,
        "time,hinge\n0,0\n1,1.5\n",
    );
    let out = run(&urdf, &csv, dir.path(), &["--resolution", "24"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report = std::fs::read_to_string(dir.path().join("r.report.json")).unwrap();
    assert!(
        report.contains("beyond its limits") && report.contains(":3: joint \\\"hinge\\\" = 1.5"),
        "{report}"
    );
}

/// Malformed robots and joint files: exit 2, the file and the element or line named, and
/// nothing written.
#[test]
fn malformed_robots_and_joint_files_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let box_ = r#"<box size="0.8 0.1 0.1"/>"#;
    let loop_joints = format!(
        "{HINGE}{}",
        r#"<joint name="back" type="fixed"><parent link="arm"/><child link="base"/></joint>"#
    );
    let cases: Vec<(&str, String, String, &str, &[&str])> = vec![
        (
            "loop",
            box_.into(),
            loop_joints,
            "time,hinge\n0,0\n",
            &["r.urdf", "root links"],
        ),
        (
            "missing mesh",
            r#"<mesh filename="package://nowhere/arm.stl"/>"#.into(),
            HINGE.into(),
            "time,hinge\n0,0\n",
            &["r.urdf", "link \"arm\"", "not found", "--package-dir"],
        ),
        (
            "unknown joint type",
            box_.into(),
            HINGE.replace("continuous", "twisty"),
            "time,hinge\n0,0\n",
            &["r.urdf", "twisty"],
        ),
        (
            "floating joint",
            box_.into(),
            HINGE.replace("continuous", "floating"),
            "time,hinge\n0,0\n",
            &["r.urdf", "joint \"hinge\"", "Floating"],
        ),
        (
            "unknown column",
            box_.into(),
            HINGE.into(),
            "time,hinge,elbow\n0,0,0\n",
            &["r.csv:1", "elbow", "hinge"],
        ),
        (
            "non-finite value",
            box_.into(),
            HINGE.into(),
            "time,hinge\n0,0\n1,nan\n",
            &["r.csv:3", "hinge", "finite"],
        ),
        (
            "no time",
            box_.into(),
            HINGE.into(),
            "hinge\n0\n",
            &["r.csv", "time column"],
        ),
    ];
    for (what, geometry, joints, csv, words) in cases {
        let (urdf, csv) = primitive_robot(dir.path(), &geometry, &joints, csv);
        let out_dir = dir.path().join("out");
        let out = run(&urdf, &csv, &out_dir, &["--resolution", "24"]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{what}: {err}");
        for w in words {
            assert!(err.contains(w), "{what}: {w:?} not in {err}");
        }
        assert!(
            !out_dir.exists() || std::fs::read_dir(&out_dir).unwrap().next().is_none(),
            "{what}: outputs written"
        );
    }
}

/// A robot swept in shards: the manifests' hash covers the mesh files the URDF names, so a mesh
/// changed after the shards were swept stops the merge (naming the URDF and its meshes, nothing
/// written); restored, the shards merge.
#[test]
fn a_mesh_changed_after_the_shards_stops_the_merge() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let tetra = |x: f32| {
        let v = [
            [0.0, 0.0, 0.0],
            [x, 0.0, 0.0],
            [0.0, 0.3, 0.0],
            [0.0, 0.0, 0.3],
        ];
        let mut s = String::from("solid t\n");
        for t in [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]] {
            s += "facet normal 0 0 0\nouter loop\n";
            for k in t {
                let p: [f32; 3] = v[k];
                s += &format!("vertex {} {} {}\n", p[0], p[1], p[2]);
            }
            s += "endloop\nendfacet\n";
        }
        s + "endsolid t\n"
    };
    files::write(d, "part.stl", tetra(0.3));
    let (urdf, csv) = primitive_robot(
        d,
        r#"<mesh filename="part.stl"/>"#,
        HINGE,
        "time,hinge\n0,0\n1,0.5\n2,1.0\n",
    );
    let shards = d.join("shards");
    let sweep = |shard: &str| {
        let o = sweptvol(&files::sweep_args(&urdf, &csv, &shards, shard, &[]));
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    };
    sweep("1/2");
    sweep("2/2");
    let out = d.join("merged");
    let merge = || {
        sweptvol(&[
            "mesh",
            "--quiet",
            "--from",
            shards.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
    };
    files::write(d, "part.stl", tetra(0.35));
    let o = merge();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("r.urdf") && err.contains("mesh file it names"),
        "{err}"
    );
    assert!(!out.exists(), "the refused merge wrote {}", out.display());
    files::write(d, "part.stl", tetra(0.3));
    let o = merge();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.join("r.swept.glb").is_file());
}
