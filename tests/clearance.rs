//! Issue 28: the clearance of obstacles from a swept volume, as a guaranteed interval
//! [d + c, d + B] (docs/design.md, "Clearance"). Analytic cases with known true clearances,
//! randomized cases against an independent computation, the clearance map, and bad input.

mod common;

use std::fs;
use std::path::{Path, PathBuf};

use common::box_mesh;
use common::files::{glb, glb_parts, run_args, sweptvol, write};
use serde_json::Value;

/// An open square plate x = x0 (a plane piece facing -x), spanning `half` in y and z.
fn plate_x(x0: f32, half: f32) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let p = vec![
        [x0, -half, -half],
        [x0, half, -half],
        [x0, half, half],
        [x0, -half, half],
    ];
    (p, vec![[0, 1, 2], [0, 2, 3]])
}

/// Rows of pure translations (identity rotation), one per line after the header.
fn translations(rows: &[[f64; 3]]) -> String {
    let mut s = String::from("frame,tx,ty,tz,qw,qx,qy,qz\n");
    for (i, t) in rows.iter().enumerate() {
        s += &format!("{i},{},{},{},1,0,0,0\n", t[0], t[1], t[2]);
    }
    s
}

/// `run` then `clearance` against `obstacle`; the clearance report and the exit code.
fn sweep_and_measure(
    dir: &Path,
    part: &[u8],
    csv: &str,
    obstacle: &[u8],
    run_extra: &[&str],
    extra: &[&str],
) -> (Value, i32, String) {
    let g = write(dir, "part.glb", part);
    let t = write(dir, "part.csv", csv);
    let o = write(dir, "obstacle.glb", obstacle);
    let out = dir.join("out");
    let r = sweptvol(&run_args(&g, &t, &out, run_extra));
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let c = sweptvol(&clearance_args(&out, &o, &[&["--json"], extra].concat()));
    let stderr = String::from_utf8_lossy(&c.stderr).into_owned();
    let v = serde_json::from_slice(&c.stdout).unwrap_or(Value::Null);
    (v, c.status.code().unwrap_or(-1), stderr)
}

/// `sweptvol clearance` of `out/part.swept.glb` (and its report) against `obstacle`, then `extra`.
fn clearance_args(out: &Path, obstacle: &Path, extra: &[&str]) -> Vec<String> {
    let mut args: Vec<String> = [
        "clearance",
        "--mesh",
        out.join("part.swept.glb").to_str().unwrap(),
        "--report",
        out.join("part.report.json").to_str().unwrap(),
        "--against",
        obstacle.to_str().unwrap(),
    ]
    .map(String::from)
    .to_vec();
    args.extend(extra.iter().map(|s| s.to_string()));
    args
}

fn interval(o: &Value) -> (f64, f64) {
    (o["lower"].as_f64().unwrap(), o["upper"].as_f64().unwrap())
}

/// A unit box pushed along x from 0 to 2 past a plate at x = 4: the true clearance is
/// 4 - 3 = 1. The interval holds it and is at most B - c wide (plus the rounding allowance).
#[test]
fn a_box_pushed_past_a_plate_has_its_clearance_in_the_interval() {
    let tmp = tempfile::tempdir().unwrap();
    let (bp, bt) = box_mesh([0.0; 3], [1.0; 3]);
    let (pp, pt) = plate_x(4.0, 3.0);
    let rows: Vec<[f64; 3]> = (0..=8).map(|i| [i as f64 * 0.25, 0.0, 0.0]).collect();
    let (v, code, err) = sweep_and_measure(
        tmp.path(),
        &glb(&bp, &bt),
        &translations(&rows),
        &glb(&pp, &pt),
        &["--motion", "discrete"],
        &[],
    );
    assert_eq!(code, 0, "{err}");
    let g = &v["guarantee"];
    let (c, b) = (
        g["clearance"].as_f64().unwrap(),
        g["bound"].as_f64().unwrap(),
    );
    let o = &v["obstacles"][0];
    assert_eq!(o["verdict"], "clear");
    let (lo, hi) = interval(o);
    assert!(
        lo <= 1.0 && 1.0 <= hi,
        "true clearance 1 outside [{lo}, {hi}]"
    );
    assert!(
        hi - lo <= b - c + 1e-9,
        "[{lo}, {hi}] wider than B - c = {}",
        b - c
    );
    assert!(lo > 0.0);
    // The last row is nearest: its distance is exact and no larger than the mesh's upper end.
    assert_eq!(o["nearest_pose"]["row"], 8);
    assert!((o["nearest_pose"]["distance"].as_f64().unwrap() - 1.0).abs() < 1e-9);
}

/// Two rows far apart with a block between them beside the path: the continuous (screw)
/// motion passes at 0.3 from it, the rows alone at about 3.4. The interval holds 0.3.
#[test]
fn the_motion_between_two_far_rows_is_measured_not_just_the_rows() {
    let tmp = tempfile::tempdir().unwrap();
    let (bp, bt) = box_mesh([0.0; 3], [1.0; 3]);
    // The part goes from x = 0 to x = 10; the block stands at x in [5, 6], y in [1.3, 2.3].
    let (op, ot) = box_mesh([5.0, 1.3, 0.0], [6.0, 2.3, 1.0]);
    let rows = [[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]];
    let (v, code, err) = sweep_and_measure(
        tmp.path(),
        &glb(&bp, &bt),
        &translations(&rows),
        &glb(&op, &ot),
        &["--motion", "screw", "--resolution", "96"],
        &[],
    );
    assert_eq!(code, 0, "{err}");
    let o = &v["obstacles"][0];
    let (lo, hi) = interval(o);
    assert!(
        lo <= 0.3 && 0.3 <= hi,
        "true clearance 0.3 outside [{lo}, {hi}]"
    );
    // No listed pose comes nearer than the mesh's upper end (the rows are about 3.4 away).
    assert!(o["nearest_pose"].is_null(), "{o}");
    assert_eq!(o["upper_from"], "mesh");
    assert!(hi < 3.0, "the upper end {hi} is the rows' distance");
}

/// A part turning inside a ring: a bar of half-length 1 spinning about z in the hole of a
/// square ring whose inner faces stand at 1.5 from the axis: the bar's far corner reaches
/// sqrt(1 + 0.1²) ≈ 1.005, so the true clearance is 1.5 - 1.005.
#[test]
fn a_part_turning_inside_a_ring_keeps_its_gap() {
    let tmp = tempfile::tempdir().unwrap();
    let (bp, bt) = box_mesh([-1.0, -0.1, -0.1], [1.0, 0.1, 0.1]);
    // Four walls of a square ring, inner faces at ±1.5, 0.5 thick, 0.4 high.
    let walls = [
        box_mesh([1.5, -2.0, -0.2], [2.0, 2.0, 0.2]),
        box_mesh([-2.0, -2.0, -0.2], [-1.5, 2.0, 0.2]),
        box_mesh([-1.5, 1.5, -0.2], [1.5, 2.0, 0.2]),
        box_mesh([-1.5, -2.0, -0.2], [1.5, -1.5, 0.2]),
    ];
    let names = ["east", "west", "north", "south"];
    let parts: Vec<common::files::Part> = walls
        .iter()
        .zip(names)
        .map(|((p, t), n)| (n, p.as_slice(), t.as_slice()))
        .collect();
    let mut csv = String::from("frame,tx,ty,tz,qw,qx,qy,qz\n");
    for i in 0..=24 {
        let a = i as f64 * std::f64::consts::PI / 24.0;
        csv += &format!("{i},0,0,0,{},0,0,{}\n", (a / 2.0).cos(), (a / 2.0).sin());
    }
    let (v, code, err) = sweep_and_measure(
        tmp.path(),
        &glb(&bp, &bt),
        &csv,
        &glb_parts(&parts),
        &["--resolution", "64"],
        &[],
    );
    assert_eq!(code, 0, "{err}");
    let truth = 1.5 - (1.0f64 + 0.01).sqrt();
    let obstacles = v["obstacles"].as_array().unwrap();
    assert_eq!(obstacles.len(), 4);
    for (o, n) in obstacles.iter().zip(names) {
        assert_eq!(o["name"], n);
        assert_eq!(o["verdict"], "clear", "{o}");
        let (lo, hi) = interval(o);
        assert!(
            lo <= truth && truth <= hi,
            "{n}: {truth} outside [{lo}, {hi}]"
        );
    }
}

/// A block the part passes through at a listed row: certain contact with a witness at that
/// row, and --require-clearance fails (exit 3) even at 0.
#[test]
fn a_part_through_an_obstacle_at_a_row_is_a_certain_contact() {
    let tmp = tempfile::tempdir().unwrap();
    let (bp, bt) = box_mesh([0.0; 3], [1.0; 3]);
    let (op, ot) = box_mesh([2.5, 0.2, 0.2], [3.0, 0.8, 0.8]);
    let rows: Vec<[f64; 3]> = (0..=4).map(|i| [i as f64, 0.0, 0.0]).collect();
    let (v, code, err) = sweep_and_measure(
        tmp.path(),
        &glb(&bp, &bt),
        &translations(&rows),
        &glb(&op, &ot),
        &[],
        &["--require-clearance", "0"],
    );
    assert_eq!(code, 3, "{err}");
    let o = &v["obstacles"][0];
    assert_eq!(o["verdict"], "contact");
    assert_eq!(interval(o), (0.0, 0.0));
    let w = &o["witness"];
    // Rows 2 (x in [2, 3]) and 3 (x in [3, 4]) meet the block; row 2 is found first.
    assert_eq!(w["row"], 2, "{w}");
    assert_eq!(w["line"], 4);
    assert!(!v["passes"].as_bool().unwrap());
}

/// The clearance map: one .glb per obstacle with `_CLEARANCE` and `COLOR_0` per vertex (the
/// lower end at the vertex, never above the vertex's true distance) and a closest-points line.
#[test]
fn the_clearance_map_holds_a_lower_end_per_vertex() {
    let tmp = tempfile::tempdir().unwrap();
    let (bp, bt) = box_mesh([0.0; 3], [1.0; 3]);
    let (pp, pt) = plate_x(4.0, 3.0);
    let rows = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]];
    let (v, code, err) = sweep_and_measure(
        tmp.path(),
        &glb(&bp, &bt),
        &translations(&rows),
        &glb(&pp, &pt),
        &["--motion", "discrete"],
        &["--clearance-scale", "5"],
    );
    assert_eq!(code, 0, "{err}");
    let map = PathBuf::from(v["obstacles"][0]["map"].as_str().unwrap());
    assert!(
        map.ends_with("part.obstacle.clearance.glb"),
        "{}",
        map.display()
    );
    let file = gltf::Gltf::from_slice(&fs::read(&map).unwrap()).unwrap();
    let buffers = [file.blob.clone().expect("a .glb binary chunk")];
    let doc = file.document;
    let mesh = doc.meshes().next().unwrap();
    let prim = mesh.primitives().next().unwrap();
    let reader = prim.reader(|b| Some(buffers[b.index()].as_slice()));
    let positions: Vec<[f32; 3]> = reader.read_positions().unwrap().collect();
    let colours: Vec<[f32; 4]> = reader.read_colors(0).unwrap().into_rgba_f32().collect();
    let attr = prim
        .attributes()
        .find(|(s, _)| matches!(s, gltf::Semantic::Extras(n) if n == "CLEARANCE"))
        .expect("a _CLEARANCE attribute")
        .1;
    let view = attr.view().unwrap();
    let buf = &buffers[view.buffer().index()];
    let at = view.offset() + attr.offset();
    let values: Vec<f32> = (0..attr.count())
        .map(|i| f32::from_le_bytes(buf[at + 4 * i..at + 4 * i + 4].try_into().unwrap()))
        .collect();
    assert_eq!(values.len(), positions.len());
    for (p, (x, c)) in positions.iter().zip(values.iter().zip(&colours)) {
        // The part's union is [0, 2] x [0, 1] x [0, 1]: the true distance of a plate vertex.
        let dy = (0.0f32 - p[1]).max(p[1] - 1.0).max(0.0);
        let dz = (0.0f32 - p[2]).max(p[2] - 1.0).max(0.0);
        let truth = ((p[0] - 2.0).powi(2) + dy * dy + dz * dz).sqrt();
        assert!(
            *x <= truth + 1e-5,
            "lower end {x} above the true {truth} at {p:?}"
        );
        assert!(*x > 0.0 && c[1] > 0.0, "a clear vertex coloured as contact");
    }
    let nodes: Vec<String> = doc
        .nodes()
        .filter_map(|n| n.name().map(String::from))
        .collect();
    assert!(
        nodes.contains(&"part closest points".to_string()),
        "{nodes:?}"
    );
    // Nothing is overwritten without being asked.
    let again = sweptvol(&clearance_args(
        &tmp.path().join("out"),
        &tmp.path().join("obstacle.glb"),
        &[],
    ));
    assert_eq!(again.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&again.stderr).contains("--overwrite"));
}

/// Bad input: an obstacle that is not glTF, has no triangles or a non-finite vertex, and a
/// negative --require-clearance: exit 2, naming the file or option, and nothing written.
#[test]
fn bad_obstacles_and_options_are_refused_by_name() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let (bp, bt) = box_mesh([0.0; 3], [1.0; 3]);
    let g = write(dir, "part.glb", glb(&bp, &bt));
    let t = write(dir, "part.csv", translations(&[[0.0; 3], [1.0, 0.0, 0.0]]));
    let out = dir.join("out");
    assert!(sweptvol(&run_args(&g, &t, &out, &[])).status.success());
    let (pp, pt) = plate_x(4.0, 3.0);
    let good = write(dir, "good.glb", glb(&pp, &pt));
    let cases: Vec<(PathBuf, Vec<&str>, &str)> = vec![
        (
            write(dir, "text.glb", "not a glb at all"),
            vec![],
            "text.glb",
        ),
        (write(dir, "empty.glb", glb(&[], &[])), vec![], "empty.glb"),
        (
            write(
                dir,
                "nan.glb",
                glb(
                    &[[0.0; 3], [1.0, 0.0, 0.0], [0.0, f32::NAN, 0.0]],
                    &[[0, 1, 2]],
                ),
            ),
            vec![],
            "nan.glb",
        ),
        (
            good.clone(),
            vec!["--require-clearance", "-1"],
            "--require-clearance",
        ),
        (
            good.clone(),
            vec!["--clearance-scale", "0"],
            "--clearance-scale",
        ),
    ];
    for (obstacle, extra, named) in cases {
        let r = sweptvol(&clearance_args(&out, &obstacle, &extra));
        let err = String::from_utf8_lossy(&r.stderr);
        assert_eq!(r.status.code(), Some(2), "{named}: {err}");
        assert!(err.contains(named), "{named} not named: {err}");
        assert!(
            !out.join("part.clearance.json").exists(),
            "{named}: a report was written"
        );
    }
    let listing: Vec<String> = fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        !listing.iter().any(|n| n.contains("clearance")),
        "{listing:?}"
    );
}

/// A point of a closed surface's inside, by the generalized winding number.
fn inside(positions: &[common::V3], triangles: &[[u32; 3]], p: common::V3) -> bool {
    common::winding_number(positions, triangles, p).abs() > 0.5
}

/// Points covering triangle `t` to within `r` (a barycentric grid), and the cover radius.
fn cover(t: [common::V3; 3], k: usize) -> (Vec<common::V3>, f64) {
    let mut pts = Vec::new();
    for i in 0..=k {
        for j in 0..=k - i {
            let (s, u) = (i as f64 / k as f64, j as f64 / k as f64);
            pts.push(std::array::from_fn(|c| {
                t[0][c] + (t[1][c] - t[0][c]) * s + (t[2][c] - t[0][c]) * u
            }));
        }
    }
    let len = |a: common::V3, b: common::V3| {
        ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
    };
    let longest = len(t[0], t[1]).max(len(t[1], t[2])).max(len(t[2], t[0]));
    (pts, longest / k as f64)
}

/// The true clearance between a closed obstacle (or an open one: `solid` false) and one posed
/// closed part, bracketed independently: [lo, hi] from exact point-triangle distances of a
/// dense cover of the obstacle's surface, 0 where one lies inside the other.
fn bracket(
    o: &(Vec<common::V3>, Vec<[u32; 3]>),
    solid: bool,
    part: &(Vec<common::V3>, Vec<[u32; 3]>),
) -> (f64, f64) {
    let part_tris: Vec<[common::V3; 3]> = part
        .1
        .iter()
        .map(|t| t.map(|i| part.0[i as usize]))
        .collect();
    if inside(&part.0, &part.1, o.0[0]) || solid && inside(&o.0, &o.1, part.0[0]) {
        return (0.0, 0.0);
    }
    let (mut hi, mut reach) = (f64::INFINITY, 0.0f64);
    for t in &o.1 {
        let (pts, r) = cover(t.map(|i| o.0[i as usize]), 24);
        reach = reach.max(r);
        for p in pts {
            hi = hi.min(common::dist_to_set(p, &part_tris));
        }
    }
    // Vertices of the part against the obstacle: catches a part corner poking at a face.
    let o_tris: Vec<[common::V3; 3]> = o.1.iter().map(|t| t.map(|i| o.0[i as usize])).collect();
    for p in &part.0 {
        hi = hi.min(common::dist_to_set(*p, &o_tris));
    }
    ((hi - reach).max(0.0), hi)
}

/// 200 random cases: a random tetrahedron moved by random rows (discrete, or translations with
/// the screw motion between them), a random box or plate near its path. The true clearance,
/// bracketed by an independent computation over the rows (and for the screw, over densely
/// sampled instants, widened by what the sampling can miss), lies in the interval every
/// time; every certain contact has a witness that really meets the obstacle.
#[test]
fn random_parts_motions_and_obstacles_never_leave_the_interval() {
    use common::Draw;
    let mut rng = common::Rng::with_seed(28);
    let tmp = tempfile::tempdir().unwrap();
    let mut verdicts = std::collections::BTreeMap::new();
    let mut violations = Vec::new();
    for case in 0..200 {
        let dir = tmp.path().join(format!("case{case}"));
        fs::create_dir_all(&dir).unwrap();
        let screw = case % 2 == 1;
        // The part: a tetrahedron within 0.5 of the origin, wound outward.
        let mut pos: Vec<common::V3> = (0..4)
            .map(|_| std::array::from_fn(|_| rng.range(-0.5, 0.5)))
            .collect();
        let (a, b, c, d) = (pos[0], pos[1], pos[2], pos[3]);
        let e = |x: common::V3, y: common::V3| [y[0] - x[0], y[1] - x[1], y[2] - x[2]];
        let (u, v, w) = (e(a, b), e(a, c), e(a, d));
        let vol = u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0])
            + u[2] * (v[0] * w[1] - v[1] * w[0]);
        if vol.abs() < 0.01 {
            pos[3] = [0.0, 0.0, if vol >= 0.0 { 0.8 } else { -0.8 }];
        }
        let tris = vec![[0u32, 1, 2], [0, 3, 1], [1, 3, 2], [2, 3, 0]];
        let part32: Vec<[f32; 3]> = pos.iter().map(|p| p.map(|x| x as f32)).collect();
        // Exact f64 of what the file holds.
        let pos: Vec<common::V3> = part32.iter().map(|p| p.map(|x| x as f64)).collect();
        // Rows: 2 to 5 poses along a random path.
        let rows: Vec<(common::V3, [f64; 4])> = (0..rng.usize(2..6))
            .map(|i| {
                let t = [
                    i as f64 * rng.range(0.3, 1.0),
                    rng.range(-0.3, 0.3),
                    rng.range(-0.3, 0.3),
                ];
                let q = if screw {
                    [1.0, 0.0, 0.0, 0.0]
                } else {
                    let q: [f64; 4] = std::array::from_fn(|_| rng.range(-1.0, 1.0));
                    let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
                    q.map(|x| x / n)
                };
                (t, q)
            })
            .collect();
        let mut csv = String::from("frame,tx,ty,tz,qw,qx,qy,qz\n");
        for (i, (t, q)) in rows.iter().enumerate() {
            csv += &format!(
                "{i},{},{},{},{},{},{},{}\n",
                t[0], t[1], t[2], q[0], q[1], q[2], q[3]
            );
        }
        // The obstacle: a box or a plate somewhere near the path.
        let centre = [
            rng.range(-0.5, 3.5),
            rng.range(-1.5, 1.5),
            rng.range(-1.5, 1.5),
        ];
        let size = rng.range(0.1, 0.8);
        let solid = rng.bool();
        let (op, ot) = if solid {
            box_mesh(
                centre.map(|x| (x - size) as f32),
                centre.map(|x| (x + size) as f32),
            )
        } else {
            let n: [f64; 3] = std::array::from_fn(|_| rng.range(-1.0, 1.0));
            let a = [n[1], -n[0], 0.0];
            let b = [n[0] * n[2], n[1] * n[2], -(n[0] * n[0] + n[1] * n[1])];
            let na = (a[0] * a[0] + a[1] * a[1]).sqrt().max(1e-9);
            let nb = b.iter().map(|x| x * x).sum::<f64>().sqrt().max(1e-9);
            let corner = |s: f64, t: f64| -> [f32; 3] {
                std::array::from_fn(|k| (centre[k] + size * (s * a[k] / na + t * b[k] / nb)) as f32)
            };
            (
                vec![
                    corner(-1.0, -1.0),
                    corner(1.0, -1.0),
                    corner(1.0, 1.0),
                    corner(-1.0, 1.0),
                ],
                vec![[0, 1, 2], [0, 2, 3]],
            )
        };
        let o = (
            op.iter().map(|p| p.map(|x| x as f64)).collect::<Vec<_>>(),
            ot.clone(),
        );
        let motion = if screw { "screw" } else { "discrete" };
        let (rep, code, err) = sweep_and_measure(
            &dir,
            &glb(&part32, &tris),
            &csv,
            &glb(&op, &ot),
            &["--motion", motion, "--resolution", "20"],
            &[],
        );
        assert_eq!(code, 0, "case {case}: {err}");
        let ob = &rep["obstacles"][0];
        let verdict = ob["verdict"].as_str().unwrap().to_string();
        *verdicts.entry(verdict.clone()).or_insert(0) += 1;
        let lower = ob["lower"].as_f64().unwrap();
        let upper = ob["upper"].as_f64().unwrap_or(f64::INFINITY);
        // The part at an instant s of the way from row i to i + 1 (rotations only at rows).
        let place = |t: common::V3, q: [f64; 4]| -> Vec<common::V3> {
            let rot = glam::DQuat::from_xyzw(q[1], q[2], q[3], q[0]);
            pos.iter()
                .map(|p| (rot * glam::DVec3::from(*p) + glam::DVec3::from(t)).to_array())
                .collect()
        };
        let mut instants: Vec<(Vec<common::V3>, f64)> = Vec::new();
        let steps = if screw { 40 } else { 1 };
        for i in 0..rows.len() {
            let (t0, q) = rows[i];
            if i + 1 == rows.len() || !screw {
                instants.push((place(t0, q), 0.0));
                continue;
            }
            let t1 = rows[i + 1].0;
            let step =
                ((t1[0] - t0[0]).powi(2) + (t1[1] - t0[1]).powi(2) + (t1[2] - t0[2]).powi(2))
                    .sqrt()
                    / steps as f64;
            for k in 0..steps {
                let s = k as f64 / steps as f64;
                let t = std::array::from_fn(|c| t0[c] + (t1[c] - t0[c]) * s);
                // Any instant is within half a step of a sampled one.
                instants.push((place(t, q), step / 2.0));
            }
        }
        let (mut lo_true, mut hi_true) = (f64::INFINITY, f64::INFINITY);
        for (posed, miss) in &instants {
            let (lo, hi) = bracket(&o, solid, &(posed.clone(), tris.clone()));
            lo_true = lo_true.min((lo - miss).max(0.0));
            hi_true = hi_true.min(hi);
        }
        // A violation is certain when the interval lies wholly beside the true bracket.
        if lower > hi_true + 1e-9 || upper < lo_true - 1e-9 {
            violations.push(format!(
                "case {case} ({motion}, {verdict}): interval [{lower}, {upper}], true in [{lo_true}, {hi_true}]"
            ));
        }
        if verdict == "contact" {
            let w = &ob["witness"];
            let row = w["row"].as_u64().unwrap() as usize;
            let posed = place(rows[row].0, rows[row].1);
            let p: common::V3 = serde_json::from_value(w["point"].clone()).unwrap();
            let on = |pts: &[common::V3], tris: &[[u32; 3]]| {
                let ts: Vec<[common::V3; 3]> =
                    tris.iter().map(|t| t.map(|i| pts[i as usize])).collect();
                common::dist_to_set(p, &ts) < 1e-9 || inside(pts, tris, p)
            };
            assert!(
                on(&posed, &tris) && on(&o.0, &o.1),
                "case {case}: the witness {w} does not meet both"
            );
        }
    }
    assert!(
        violations.is_empty(),
        "{} violations:\n{}",
        violations.len(),
        violations.join("\n")
    );
    for v in ["clear", "possible-contact", "contact"] {
        assert!(
            verdicts.get(v).copied().unwrap_or(0) >= 5,
            "too few {v}: {verdicts:?}"
        );
    }
    eprintln!("200 cases, 0 violations; verdicts {verdicts:?}");
}

/// `run --against`: the report gains the clearance section and the map is published with the
/// other outputs; --require-clearance fails with exit 3 after writing them; a later run against
/// another file retires the earlier map with --overwrite.
#[test]
fn run_against_reports_and_maps_with_the_other_outputs() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let (bp, bt) = box_mesh([0.0; 3], [1.0; 3]);
    let g = write(dir, "part.glb", glb(&bp, &bt));
    let t = write(dir, "part.csv", translations(&[[0.0; 3], [1.0, 0.0, 0.0]]));
    let (pp, pt) = plate_x(4.0, 3.0);
    let wall = write(dir, "wall.glb", glb_parts(&[("wall", &pp, &pt)]));
    let out = dir.join("out");
    let r = sweptvol(&run_args(
        &g,
        &t,
        &out,
        &[
            "--against",
            wall.to_str().unwrap(),
            "--require-clearance",
            "10",
        ],
    ));
    assert_eq!(
        r.status.code(),
        Some(3),
        "{}",
        String::from_utf8_lossy(&r.stderr)
    );
    let report: Value =
        serde_json::from_slice(&fs::read(out.join("part.report.json")).unwrap()).unwrap();
    let c = &report["clearance"];
    assert_eq!(c["passes"], false);
    let o = &c["obstacles"][0];
    assert_eq!(o["name"], "wall");
    let (lo, hi) = interval(o);
    assert!(
        lo <= 2.0 && 2.0 <= hi,
        "true clearance 2 outside [{lo}, {hi}]"
    );
    let map = out.join("part.wall.clearance.glb");
    assert!(map.exists());
    assert!(report["outputs"]
        .as_array()
        .unwrap()
        .contains(&Value::from(map.to_str().unwrap())));
    assert!(!out.join(".part.incomplete").exists());
    // Against another file: the old map goes with --overwrite, and the run passes.
    let fence = write(dir, "fence.glb", glb_parts(&[("fence", &pp, &pt)]));
    let r = sweptvol(&run_args(
        &g,
        &t,
        &out,
        &["--against", fence.to_str().unwrap(), "--overwrite"],
    ));
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(out.join("part.fence.clearance.glb").exists());
    assert!(
        !map.exists(),
        "the earlier run's map was left beside the new outputs"
    );
    // A bad obstacle is refused before the sweep: nothing written.
    let bad = write(dir, "bad.glb", "not glTF");
    let fresh = dir.join("fresh");
    let r = sweptvol(&run_args(
        &g,
        &t,
        &fresh,
        &["--against", bad.to_str().unwrap()],
    ));
    assert_eq!(r.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&r.stderr).contains("bad.glb"));
    assert!(!fresh.exists() || fs::read_dir(&fresh).unwrap().next().is_none());
}
