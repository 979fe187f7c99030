//! Issue 28: motion relative to a moving reference node (`--relative-to`). The outputs are in
//! the reference's frame; checked against independent computations of where the part goes
//! relative to it (here the motions are translations along x, so the relative sweep is a box).

mod common;

use std::fs;
use std::path::Path;

use common::box_mesh;
use common::files::{glb_parts, run_args, sweptvol, verify_args, write};
use serde_json::Value;

/// The base at x in [-3, -2], the arm at x in [0, 1] (unit boxes), as two nodes.
fn base_and_arm(dir: &Path) -> std::path::PathBuf {
    let (bp, bt) = box_mesh([-3.0, 0.0, 0.0], [-2.0, 1.0, 1.0]);
    let (ap, at) = box_mesh([0.0, 0.0, 0.0], [1.0, 1.0, 1.0]);
    write(
        dir,
        "scene.glb",
        glb_parts(&[("base", &bp, &bt), ("arm", &ap, &at)]),
    )
}

/// Rows at times 0..n: the base at x = a·sin, the arm at x = s·a·sin (s = 1 in phase, -1 out
/// of phase), each also rotated by `turn` radians about z (the same for both).
fn vibration(n: usize, a: f64, s: f64, turn: f64) -> String {
    let mut csv = String::from("frame,node,tx,ty,tz,qw,qx,qy,qz\n");
    for i in 0..n {
        let w = (i as f64 / n as f64 * std::f64::consts::TAU).sin();
        let (c, z) = ((turn * i as f64 / 2.0).cos(), (turn * i as f64 / 2.0).sin());
        // Rotating both about the world origin, then shifting each along x.
        csv += &format!("{i},base,{},0,0,{c},0,0,{z}\n", a * w);
        csv += &format!("{i},arm,{},0,0,{c},0,0,{z}\n", s * a * w);
    }
    csv
}

fn mesh_vertices(path: &Path) -> Vec<[f64; 3]> {
    let file = gltf::Gltf::from_slice(&fs::read(path).unwrap()).unwrap();
    let blob = file.blob.clone().unwrap();
    let prim = file
        .document
        .meshes()
        .next()
        .unwrap()
        .primitives()
        .next()
        .unwrap();
    let reader = prim.reader(|_| Some(blob.as_slice()));
    reader
        .read_positions()
        .unwrap()
        .map(|p| p.map(|x| x as f64))
        .collect()
}

fn report(path: &Path) -> Value {
    serde_json::from_slice(&fs::read(path).unwrap()).unwrap()
}

/// Distance from p to the box [lo, hi] (0 inside).
fn box_distance(p: [f64; 3], lo: [f64; 3], hi: [f64; 3]) -> f64 {
    (0..3)
        .map(|c| (lo[c] - p[c]).max(p[c] - hi[c]).max(0.0).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// Sweep, then check the mesh against the relative sweep computed here: the arm's box moved
/// along x by `reach` either way (a box). Every mesh vertex lies outside the true sweep by at
/// least the clearance and within the bound of it; the reference is the first obstacle.
fn check_relative(s: f64, turn: f64, expect_reach: f64) {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let g = base_and_arm(dir);
    let t = write(dir, "moves.csv", vibration(40, 0.5, s, turn));
    let out = dir.join("out");
    let r = sweptvol(&run_args(
        &g,
        &t,
        &out,
        &["--relative-to", "base", "--resolution", "48"],
    ));
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let rep = report(&out.join("moves.report.json"));
    let (c, b) = (
        rep["mesh"]["clearance"].as_f64().unwrap(),
        rep["mesh"]["hausdorff_bound"].as_f64().unwrap(),
    );
    assert_eq!(rep["inputs"]["relative_to"], "base");
    // The arm's relative sweep: x in [-reach, 1 + reach] (the sine's samples reach at most
    // `expect_reach`), y and z in [0, 1].
    let (lo, hi) = ([-expect_reach, 0.0, 0.0], [1.0 + expect_reach, 1.0, 1.0]);
    let verts = mesh_vertices(&out.join("moves.swept.glb"));
    let mut farthest: f64 = 0.0;
    for p in &verts {
        let d = box_distance(*p, lo, hi);
        assert!(
            d <= b + 1e-9,
            "mesh vertex {p:?} is {d} from the relative sweep, bound {b}"
        );
        assert!(
            d >= c - 1e-9,
            "mesh vertex {p:?} is only {d} outside, clearance {c}"
        );
        farthest = farthest.max(d);
    }
    // The base is the natural obstacle: its map is written, and in its own frame the arm keeps
    // 2 - reach from it (base x in [-3, -2]).
    let o = &rep["clearance"]["obstacles"][0];
    assert_eq!(o["name"], "base", "{o}");
    let truth = 2.0 - expect_reach;
    let (l, u) = (o["lower"].as_f64().unwrap(), o["upper"].as_f64().unwrap());
    assert!(
        l <= truth + 1e-9 && truth <= u + 1e-9,
        "{truth} outside [{l}, {u}]"
    );
    assert!(out.join("moves.base.clearance.glb").exists());
    // verify, told the same frame, certifies the mesh with the run's bound.
    let v = sweptvol(&verify_args(
        &g,
        &t,
        &out.join("moves.swept.glb"),
        &[
            "--relative-to",
            "base",
            "--bound",
            &b.to_string(),
            "--quiet",
        ],
    ));
    assert!(v.status.success(), "{}", String::from_utf8_lossy(&v.stdout));
}

/// Moving together (in phase, and turning together): in the base's frame the arm stands still,
/// so the sweep is the arm itself.
#[test]
fn parts_moving_together_sweep_to_the_part_itself() {
    check_relative(1.0, 0.0, 0.0);
    check_relative(1.0, 0.05, 0.0);
}

/// Out of phase the arm moves 2a = 1 either way relative to the base; the samples of the sine
/// at 40 rows reach exactly ±1 (at a quarter and three quarters of the period).
#[test]
fn parts_vibrating_out_of_phase_sweep_twice_the_amplitude() {
    check_relative(-1.0, 0.0, 1.0);
}

/// Bad input: a reference that is not a node, a reference no row moves, a part row at a time
/// the reference has none: exit 2, naming the option or the line.
#[test]
fn bad_references_are_refused_by_name_or_line() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let g = base_and_arm(dir);
    let out = dir.join("out");
    let good = write(dir, "good.csv", vibration(4, 0.5, -1.0, 0.0));
    let cases: Vec<(&str, String, &str)> = vec![
        ("nowhere", fs::read_to_string(&good).unwrap(), "--relative-to \"nowhere\""),
        (
            "base",
            "frame,node,tx,ty,tz,qw,qx,qy,qz\n0,arm,0,0,0,1,0,0,0\n".into(),
            "no row",
        ),
        (
            "base",
            "frame,node,tx,ty,tz,qw,qx,qy,qz\n0,base,0,0,0,1,0,0,0\n0,arm,0,0,0,1,0,0,0\n1,arm,1,0,0,1,0,0,0\n"
                .into(),
            ":4:",
        ),
    ];
    for (node, csv, named) in cases {
        let t = write(dir, "bad.csv", csv);
        let r = sweptvol(&run_args(&g, &t, &out, &["--relative-to", node]));
        let err = String::from_utf8_lossy(&r.stderr);
        assert_eq!(r.status.code(), Some(2), "{named}: {err}");
        assert!(err.contains(named), "{named} not named: {err}");
        assert!(!out.exists(), "{named}: something was written");
    }
}
