//! Articulated motion at the sizes issue 29 names (kept out of CI):
//!
//!     cargo run --release --example bench_articulated -- ROWS N [STEP_MIN_DEG STEP_MAX_DEG]
//!
//! The bundled UR5 (examples/ur5, real collision meshes) along ROWS joint configurations whose
//! joints step by STEP_MIN..STEP_MAX degrees (random signs, fixed seed; default 15..25), swept at
//! resolution N with screw motion two ways: rows in parent space (the joint-linear motion) and
//! the same rows as world poses of each link (the screw of each link's world pose). For each,
//! the posed points of the real motion (every 5th vertex of every link at 24 instants of each
//! interval, the joint values interpolated linearly and the chain composed at each instant: no
//! screw) that lie outside the output, the farthest of them from it, the poses rendered and the
//! seconds. Prints JSON.

use std::io::Write;
use std::path::Path;
use std::time::Instant;

use glam::{DMat4, DVec3};
use sweptvol::input::chain;
use sweptvol::input::grid::{Accuracy, Overrides};
use sweptvol::input::model::{Generator, Pose, Rows, Trajectory};
use sweptvol::input::motion::Motion;
use sweptvol::input::posed;
use sweptvol::io::urdf;
use sweptvol::simplify::SimplifyOptions;
use sweptvol::surface::{self, Params};
use sweptvol::sweep::{cpu, Silent};

const JOINTS: [&str; 6] = [
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
];

/// CSV text of joint rows `q` at times 0, 1, ...
fn csv(q: &[Vec<f64>]) -> String {
    let mut s = format!("time,{}\n", JOINTS.join(","));
    for (k, row) in q.iter().enumerate() {
        let cells: Vec<String> = row.iter().map(|v| format!("{v:.17}")).collect();
        s += &format!("{k},{}\n", cells.join(","));
    }
    s
}

/// Winding number of the closed mesh at p (van Oosterom and Strackee).
fn winding(pos: &[DVec3], tris: &[[u32; 3]], p: DVec3) -> f64 {
    let mut w = 0.0;
    for t in tris {
        let [a, b, c] = t.map(|k| pos[k as usize] - p);
        let (la, lb, lc) = (a.length(), b.length(), c.length());
        let num = a.dot(b.cross(c));
        let den = la * lb * lc + a.dot(b) * lc + b.dot(c) * la + c.dot(a) * lb;
        w += 2.0 * num.atan2(den);
    }
    w / (4.0 * std::f64::consts::PI)
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let rows: usize = args.first().map_or(10, |a| a.parse().unwrap());
    let n: u32 = args.get(1).map_or(256, |a| a.parse().unwrap());
    let lo: f64 = args.get(2).map_or(15.0, |a| a.parse().unwrap());
    let hi: f64 = args.get(3).map_or(25.0, |a| a.parse().unwrap());
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let urdf_path =
        root.join("examples/ur5/example-robot-data/robots/ur_description/urdf/ur5_robot.urdf");
    let dir = tempfile::tempdir().unwrap();
    let mut rng = fastrand::Rng::with_seed(29);
    let mut q = vec![vec![0.0, -1.57, 1.2, -1.2, -1.57, 0.0]];
    for _ in 1..rows {
        let last = q.last().unwrap().clone();
        q.push(
            last.iter()
                .map(|v| {
                    let step = (lo + (hi - lo) * rng.f64()).to_radians();
                    v + if rng.bool() { step } else { -step }
                })
                .collect(),
        );
    }
    let write = |name: &str, text: &str| {
        let p = dir.path().join(name);
        std::fs::File::create(&p)
            .unwrap()
            .write_all(text.as_bytes())
            .unwrap();
        p
    };
    let rows_csv = write("rows.csv", &csv(&q));
    let (generator, local) = urdf::read_inputs(&urdf_path, &rows_csv, &[]).unwrap();
    // The real motion: joint values interpolated linearly, the chain composed at each instant.
    let per = 24;
    let mut dense = Vec::new();
    for w in q.windows(2) {
        for k in 0..per {
            let s = k as f64 / per as f64;
            dense.push(
                w[0].iter()
                    .zip(&w[1])
                    .map(|(a, b)| a + s * (b - a))
                    .collect(),
            );
        }
    }
    dense.push(q.last().unwrap().clone());
    let dense_csv = write("dense.csv", &csv(&dense));
    let (_, dense_traj) = urdf::read_inputs(&urdf_path, &dense_csv, &[]).unwrap();
    let (truth, _) = chain::resolve(
        &generator,
        &dense_traj,
        Path::new("dense.csv"),
        Motion::Discrete,
    )
    .unwrap();
    // The same rows as world poses of each link.
    let (at_rows, _) =
        chain::resolve(&generator, &local, Path::new("rows.csv"), Motion::Discrete).unwrap();
    let mut world_poses = Vec::new();
    for (part, poses, is_static) in &at_rows {
        if *is_static {
            continue;
        }
        let p = &generator.parts[*part];
        for (k, (m, line)) in poses.iter().enumerate() {
            world_poses.push(Pose {
                line: line.unwrap_or(0),
                frame: Some(k as f64),
                node: p.node_name.clone(),
                matrix: *m * p.world.inverse(),
            });
        }
    }
    let world = Trajectory {
        poses: world_poses,
        has_node_column: true,
        rows: Rows::World,
    };
    let mut out = Vec::new();
    for (label, traj) in [("local", &local), ("world", &world)] {
        out.push(measure(label, &generator, traj, n, &truth));
    }
    println!("{}", serde_json::to_string_pretty(&out).unwrap());
}

/// A part, its poses (with their CSV lines) and whether it stands still.
type Posed = (usize, Vec<(DMat4, Option<u64>)>, bool);

fn measure(
    label: &str,
    generator: &Generator,
    traj: &Trajectory,
    n: u32,
    truth: &[Posed],
) -> serde_json::Value {
    let t0 = Instant::now();
    let input = posed::build(
        generator,
        Path::new("ur5.urdf"),
        traj,
        Path::new("rows.csv"),
        Accuracy::Resolution(n),
        Overrides::default(),
        Motion::Screw,
    )
    .unwrap();
    let t1 = Instant::now();
    let images = cpu::sweep(&input, &Silent).unwrap();
    let t2 = Instant::now();
    let opts = SimplifyOptions::for_params(&input.params, input.grid.h, 0).unwrap();
    let pieces = sweptvol::simplify::pieces::Pieces::of(&input);
    let mesh = surface::build(&images, None, pieces.as_ref(), &Params::new(opts), &|| {
        false
    })
    .unwrap()
    .mesh;
    let t3 = Instant::now();
    let h = input.grid.h;
    let origin = DVec3::from_array(input.grid.origin);
    let pos: Vec<DVec3> = mesh.positions.iter().map(|p| origin + *p * h).collect();
    let (mut checked, mut outside, mut farthest) = (0u64, 0u64, 0.0f64);
    for (part, poses, _) in truth {
        for (m, _) in poses {
            for v in generator.parts[*part].positions.iter().step_by(5) {
                let p = m.transform_point3(v.as_dvec3());
                checked += 1;
                if winding(&pos, &mesh.triangles, p) < 0.5 {
                    outside += 1;
                    let d = mesh
                        .triangles
                        .iter()
                        .map(|t| {
                            let tri = t.map(|k| pos[k as usize]);
                            (sweptvol::closest::closest_on_triangle(p, tri) - p).length()
                        })
                        .fold(f64::INFINITY, f64::min);
                    farthest = farthest.max(d);
                }
            }
        }
    }
    serde_json::json!({
        "rows": label, "n": n, "h": h, "stated_bound_voxels": 3.45,
        "poses_rendered": input.motion.poses_rendered, "max_path": input.motion.max_path,
        "points_checked": checked, "points_outside": outside,
        "farthest_outside_voxels": farthest / h,
        "seconds": {"setup": (t1 - t0).as_secs_f64(), "sweep": (t2 - t1).as_secs_f64(),
                    "mesh_stage": (t3 - t2).as_secs_f64()},
        "triangles": mesh.triangles.len(),
    })
}
