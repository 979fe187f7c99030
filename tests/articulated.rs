//! Articulated motion (rows in parent space, `Rows::Local`): a chain of links whose joints move
//! joint-linearly between rows is enclosed at every instant. The oracle places each link by its
//! joint values directly, origin·Rot(axis, q) or origin·Trans(axis·q) with q linear in time, not
//! through the library's screws; points of the links at dense instants are tested against the
//! output with generalized winding numbers, and the output's vertices against the dense union.
//! The same motion given as world-space rows (the screw of each link's world pose) misses, so the
//! checks can fail.

mod common;

use common::{box_mesh, dist_triangle, winding_number, Draw, Rng, V3};
use glam::{DMat4, DVec3};
use rayon::prelude::*;
use std::path::Path;
use sweptvol::input::grid::{Accuracy, Overrides};
use sweptvol::input::model::{Generator, Part, Pose, Rows, Trajectory, TreeNode};
use sweptvol::input::motion::Motion;
use sweptvol::input::posed::{self, SweepInput};
use sweptvol::mesh::Mesh;
use sweptvol::simplify::pieces::Pieces;
use sweptvol::simplify::SimplifyOptions;
use sweptvol::surface::{self, Params};
use sweptvol::sweep::{cpu, Silent};

/// One joint of a chain: where it sits in its parent's frame, its axis there (unit), whether it
/// slides, its values at the rows' times, and the link's box in the joint's frame.
struct Joint {
    origin: DMat4,
    axis: DVec3,
    prismatic: bool,
    values: Vec<f64>,
    link: ([f32; 3], [f32; 3]),
}

impl Joint {
    /// The joint's local transform at value q.
    fn local(&self, q: f64) -> DMat4 {
        if self.prismatic {
            self.origin * DMat4::from_translation(self.axis * q)
        } else {
            self.origin * DMat4::from_axis_angle(self.axis, q)
        }
    }
}

/// A chain of joints, each the parent of the next, with one row per joint and time.
struct Chain {
    joints: Vec<Joint>,
    times: Vec<f64>,
}

impl Chain {
    /// Node i is joint i's link; part i its box.
    fn generator(&self) -> Generator {
        let mut g = Generator::default();
        let mut world = DMat4::IDENTITY;
        for (i, j) in self.joints.iter().enumerate() {
            let local = j.local(j.values[0]);
            world *= local;
            g.nodes.push(TreeNode {
                index: i,
                name: Some(format!("link{i}")),
                parent: i.checked_sub(1),
                local,
            });
            let (positions, triangles) = box_mesh(j.link.0, j.link.1);
            g.parts.push(Part {
                node_index: i,
                node_name: Some(format!("link{i}")),
                world,
                positions: positions.into_iter().map(glam::Vec3::from).collect(),
                triangles,
            });
        }
        g
    }

    /// Rows in parent space: each joint's local transform at each time.
    fn local_rows(&self) -> Trajectory {
        let mut poses = Vec::new();
        for (k, &t) in self.times.iter().enumerate() {
            for (i, j) in self.joints.iter().enumerate() {
                poses.push(Pose {
                    line: poses.len() as u64 + 2,
                    frame: Some(t),
                    node: Some(format!("link{i}")),
                    matrix: j.local(j.values[k]),
                });
            }
        }
        Trajectory {
            poses,
            has_node_column: true,
            rows: Rows::Local,
        }
    }

    /// The same rows as world-space poses of each link (v' = M·W·v with W the rest world).
    fn world_rows(&self, g: &Generator) -> Trajectory {
        let mut poses = Vec::new();
        for k in 0..self.times.len() {
            for (i, part) in g.parts.iter().enumerate() {
                poses.push(Pose {
                    line: poses.len() as u64 + 2,
                    frame: Some(self.times[k]),
                    node: Some(format!("link{i}")),
                    matrix: self.world_at(i, k as f64) * part.world.inverse(),
                });
            }
        }
        Trajectory {
            poses,
            has_node_column: true,
            rows: Rows::World,
        }
    }

    /// Link i's world pose at row parameter u (row k at u = k, joint-linear in between).
    fn world_at(&self, i: usize, u: f64) -> DMat4 {
        let k = (u.floor() as usize).min(self.times.len() - 2);
        let s = u - k as f64;
        self.joints[..=i].iter().fold(DMat4::IDENTITY, |m, j| {
            m * j.local(j.values[k] * (1.0 - s) + j.values[k + 1] * s)
        })
    }
}

fn build(g: &Generator, t: &Trajectory, n: u32, motion: Motion) -> SweepInput {
    posed::build(
        g,
        Path::new("arm.glb"),
        t,
        Path::new("arm.csv"),
        Accuracy::Resolution(n),
        Overrides::default(),
        motion,
    )
    .expect("job builds")
}

/// The simplified output (blocks of 8 voxels, so that seams cross the small grids here).
fn sweep(input: &SweepInput) -> Mesh {
    let images = cpu::sweep(input, &Silent).unwrap();
    let opts = SimplifyOptions::for_params(&input.params, input.grid.h, 0).unwrap();
    let params = Params {
        block: 8,
        ..Params::new(opts)
    };
    surface::build(&images, None, Pieces::of(input).as_ref(), &params, &|| {
        false
    })
    .expect("not stopped")
    .mesh
}

fn grid(input: &SweepInput, p: DVec3) -> V3 {
    ((p - DVec3::from_array(input.grid.origin)) / input.grid.h).to_array()
}

/// Sample points of each link (vertices, edge midpoints, face centres of its box) in its frame.
fn samples(g: &Generator, i: usize) -> Vec<DVec3> {
    let part = &g.parts[i];
    let p = |k: u32| part.positions[k as usize].as_dvec3();
    let mut out: Vec<DVec3> = part.positions.iter().map(|v| v.as_dvec3()).collect();
    for t in &part.triangles {
        out.push((p(t[0]) + p(t[1]) + p(t[2])) / 3.0);
        out.push((p(t[0]) + p(t[1])) / 2.0);
    }
    out
}

/// Points of the joint-linear motion, `steps` instants per interval, outside `mesh`, and the
/// posed triangles of every link at those instants (world units).
fn outside(
    chain: &Chain,
    g: &Generator,
    input: &SweepInput,
    mesh: &Mesh,
    steps: usize,
) -> (Vec<(usize, f64)>, Vec<[V3; 3]>) {
    let pos: Vec<V3> = mesh.positions.iter().map(|p| p.to_array()).collect();
    let intervals = chain.times.len() - 1;
    let mut missed = Vec::new();
    let mut union = Vec::new();
    for j in 0..=steps * intervals {
        let u = j as f64 / steps as f64;
        for i in 0..g.parts.len() {
            let m = chain.world_at(i, u);
            for p in samples(g, i) {
                let q = grid(input, m.transform_point3(p));
                if winding_number(&pos, &mesh.triangles, q) <= 0.99 {
                    missed.push((i, u));
                }
            }
            let part = &g.parts[i];
            for t in &part.triangles {
                union.push(t.map(|k| {
                    m.transform_point3(part.positions[k as usize].as_dvec3())
                        .to_array()
                }));
            }
        }
    }
    (missed, union)
}

/// The stated bound of `input`, world units: ε + √3h/2 + δ + μ + 2ρh.
fn bound(input: &SweepInput) -> f64 {
    let h = input.grid.h;
    input.params.epsilon
        + 3f64.sqrt() / 2.0 * h
        + input.params.delta
        + input.motion.mu
        + 2.0 * input.rounding * h
}

/// The farthest output vertex from the dense union of the links, world units.
fn farthest(input: &SweepInput, mesh: &Mesh, union: &[[V3; 3]]) -> f64 {
    mesh.positions
        .par_iter()
        .map(|v| {
            let w = (DVec3::from_array(input.grid.origin) + *v * input.grid.h).to_array();
            union
                .iter()
                .map(|t| dist_triangle(w, *t))
                .fold(f64::INFINITY, f64::min)
        })
        .reduce(|| 0.0, f64::max)
}

/// A two-link planar arm: the shoulder turns 60° and the elbow 90° between two rows.
fn two_link() -> Chain {
    Chain {
        joints: vec![
            Joint {
                origin: DMat4::IDENTITY,
                axis: DVec3::Z,
                prismatic: false,
                values: vec![0.0, 60f64.to_radians()],
                link: ([0.0, -0.05, -0.05], [1.0, 0.05, 0.05]),
            },
            Joint {
                origin: DMat4::from_translation(DVec3::X),
                axis: DVec3::Z,
                prismatic: false,
                values: vec![0.0, 90f64.to_radians()],
                link: ([0.0, -0.05, -0.05], [0.8, 0.05, 0.05]),
            },
        ],
        times: vec![0.0, 1.0],
    }
}

/// The two-link arm's joint-linear motion lies inside the output, whose vertices stay within the
/// stated bound of it; the same rows as world-space screws leave the elbow's real path outside.
#[test]
fn a_two_link_arm_is_enclosed_in_its_joint_space_and_world_rows_miss_it() {
    let chain = two_link();
    let g = chain.generator();
    let input = build(&g, &chain.local_rows(), 96, Motion::Screw);
    assert_eq!(input.motion.model, "screw");
    // Both links move over the one interval; the distal link's path bound is at least its
    // tip's true path (the arc of the shoulder plus the elbow's turn at 0.8 beyond it).
    assert_eq!(input.motion.intervals, 2);
    assert!(
        input.motion.max_path >= 60f64.to_radians() * 1.8,
        "{:?}",
        input.motion
    );
    let mesh = sweep(&input);
    let (missed, union) = outside(&chain, &g, &input, &mesh, 400);
    assert!(
        missed.is_empty(),
        "{} points outside, first {:?}",
        missed.len(),
        missed[0]
    );
    let far = farthest(&input, &mesh, &union);
    // The dense union misses the true one by at most half a step's travel (1.8 · 2.6 rad / 400).
    let slack = 1.8 * 150f64.to_radians() / 800.0;
    assert!(
        far <= bound(&input) + slack,
        "{far} > {} + {slack}",
        bound(&input)
    );
    println!(
        "two-link arm: farthest vertex {far:.4}, bound {:.4}",
        bound(&input)
    );

    let world = build(&g, &chain.world_rows(&g), 96, Motion::Screw);
    let mesh = sweep(&world);
    let (missed, _) = outside(&chain, &g, &world, &mesh, 400);
    println!(
        "world-space screw rows: {} points of the joint motion outside",
        missed.len()
    );
    assert!(
        !missed.is_empty(),
        "world-space rows held the joint-space motion"
    );
    assert!(
        missed.iter().all(|&(i, _)| i == 1),
        "the proximal link moves by a screw"
    );
}

/// A random chain of 2 to 7 joints (revolute or prismatic, random axes and offsets), steps up
/// to 90° or 0.6 units, 2 or 3 rows.
fn random_chain(rng: &mut Rng) -> Chain {
    let joints = 2 + rng.usize(..6);
    let rows = 2 + rng.usize(..2);
    let unit = |rng: &mut Rng| {
        DVec3::new(
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
        )
        .normalize_or(DVec3::Z)
    };
    let joints = (0..joints)
        .map(|_| {
            let prismatic = rng.f64() < 0.3;
            let step = if prismatic { 0.6 } else { 90f64.to_radians() };
            let mut q = rng.range(-1.0, 1.0);
            let values = (0..rows)
                .map(|k| {
                    if k > 0 {
                        q += rng.range(-step, step);
                    }
                    q
                })
                .collect();
            let length = rng.range(0.2, 0.6) as f32;
            Joint {
                origin: DMat4::from_translation(unit(rng) * rng.range(0.1, 0.6))
                    * DMat4::from_axis_angle(unit(rng), rng.range(-3.0, 3.0)),
                axis: unit(rng),
                prismatic,
                values,
                link: ([0.0, -0.04, -0.04], [length, 0.04, 0.04]),
            }
        })
        .collect();
    Chain {
        joints,
        times: (0..rows).map(|k| k as f64 * 0.5).collect(),
    }
}

/// 200 random chains: no point of the dense joint-linear motion outside the output, and every
/// output vertex within the stated bound of the dense union (plus its sampling step).
#[test]
fn random_chains_are_enclosed_at_every_instant() {
    let cases = 200u64;
    let results: Vec<(usize, f64)> = (0..cases)
        .into_par_iter()
        .map(|case| {
            let mut rng = Rng::with_seed(7000 + case);
            let chain = random_chain(&mut rng);
            let g = chain.generator();
            let input = build(&g, &chain.local_rows(), 24, Motion::Screw);
            let mesh = sweep(&input);
            let steps = 60;
            let (missed, union) = outside(&chain, &g, &input, &mesh, steps);
            if let Some((i, u)) = missed.first() {
                eprintln!(
                    "case {case}: link {i} at u = {u} outside ({} points)",
                    missed.len()
                );
            }
            // Half the largest step of any vertex between two samples bounds how far the dense
            // union is from the true one (chords of at most 90°/60 arcs: 1.001 covers the arc).
            let mut step: f64 = 0.0;
            for i in 0..g.parts.len() {
                for j in 0..steps * (chain.times.len() - 1) {
                    let (a, b) = (
                        chain.world_at(i, j as f64 / steps as f64),
                        chain.world_at(i, (j + 1) as f64 / steps as f64),
                    );
                    for p in &g.parts[i].positions {
                        let p = p.as_dvec3();
                        step = step.max((a.transform_point3(p) - b.transform_point3(p)).length());
                    }
                }
            }
            let excess = farthest(&input, &mesh, &union) - bound(&input) - 1.001 * step / 2.0;
            if excess > 0.0 {
                eprintln!("case {case}: a vertex {excess} beyond the bound");
            }
            (missed.len(), excess)
        })
        .collect();
    let violations: usize = results.iter().map(|r| r.0).sum();
    let worst = results
        .iter()
        .map(|r| r.1)
        .fold(f64::NEG_INFINITY, f64::max);
    println!("{cases} random chains: {violations} points outside, worst bound excess {worst:.3e}");
    assert_eq!(violations, 0);
    assert!(worst <= 0.0, "{worst}");
}

/// The lemma the sweep rests on, checked directly: every instant of the joint-linear motion puts
/// every sample point of every link within μ of where some rendered pose (row or sub-pose) puts
/// it. (The enclosure tests above have δ to spare; this one has none.)
#[test]
fn every_instant_is_within_mu_of_a_rendered_pose() {
    let mut worst: f64 = 0.0;
    for case in 0..200u64 {
        let mut rng = Rng::with_seed(9000 + case);
        let chain = if case == 0 {
            two_link()
        } else {
            random_chain(&mut rng)
        };
        let g = chain.generator();
        let input = build(&g, &chain.local_rows(), 24, Motion::Screw);
        let mu = input.motion.mu / input.grid.h; // grid units
        let to_grid = DMat4::from_scale(DVec3::splat(1.0 / input.grid.h))
            * DMat4::from_translation(-DVec3::from_array(input.grid.origin));
        let steps = 60;
        for (i, part) in input.parts.iter().enumerate() {
            let rendered: Vec<DMat4> = (0..part.pose_count as u64)
                .map(|k| input.poses.grid_pose(i, k))
                .collect();
            let points = samples(&g, i);
            for j in 0..=steps * (chain.times.len() - 1) {
                let m = to_grid * chain.world_at(i, j as f64 / steps as f64);
                let nearest = rendered
                    .iter()
                    .map(|r| {
                        points
                            .iter()
                            .map(|p| (m.transform_point3(*p) - r.transform_point3(*p)).length())
                            .fold(0.0, f64::max)
                    })
                    .fold(f64::INFINITY, f64::min);
                worst = worst.max(nearest / mu);
                assert!(
                    nearest <= mu * (1.0 + 1e-9),
                    "case {case}, link {i}, instant {j}: {nearest} voxels from every rendered pose, μ = {mu}"
                );
            }
        }
    }
    println!("200 chains: the farthest instant is {worst:.3} μ from a rendered pose");
}

/// Row-major m00..m33 of `m`, comma-separated.
fn matrix_cells(m: DMat4) -> String {
    m.transpose()
        .to_cols_array()
        .iter()
        .map(|x| format!("{x:.17}"))
        .collect::<Vec<_>>()
        .join(",")
}

/// From the files a user has: a glTF hierarchy (the fore link a child of the upper one) and a
/// CSV of local rows. `run --rows local` states local rows in its report, `verify --rows local`
/// certifies its mesh against the joint-space motion, and certifies the mesh of the same motion
/// given as world rows to fail (the verifier's own chain motion sees the miss).
#[test]
fn a_glb_hierarchy_with_local_rows_runs_and_verifies() {
    use common::files::{self, glb_nodes, sweptvol, Node};
    let dir = tempfile::tempdir().unwrap();
    let (upper, upper_t) = box_mesh([0.0, -0.05, -0.05], [1.0, 0.05, 0.05]);
    let (fore, fore_t) = box_mesh([0.0, -0.05, -0.05], [0.8, 0.05, 0.05]);
    let glb = glb_nodes(&[
        Node {
            name: "upper",
            parent: None,
            translation: [0.0; 3],
            mesh: Some((&upper, &upper_t)),
        },
        Node {
            name: "fore",
            parent: Some(0),
            translation: [1.0, 0.0, 0.0],
            mesh: Some((&fore, &fore_t)),
        },
    ]);
    let g = files::write(dir.path(), "arm.glb", glb);
    let chain = two_link();
    let mut local =
        String::from("time,node,m00,m01,m02,m03,m10,m11,m12,m13,m20,m21,m22,m23,m30,m31,m32,m33\n");
    let mut world = local.clone();
    for (k, t) in chain.times.iter().enumerate() {
        for (i, j) in chain.joints.iter().enumerate() {
            local += &format!("{t},link{i},{}\n", matrix_cells(j.local(j.values[k])));
            let rest = if i == 0 {
                DMat4::IDENTITY
            } else {
                DMat4::from_translation(DVec3::X)
            };
            world += &format!(
                "{t},link{i},{}\n",
                matrix_cells(chain.world_at(i, k as f64) * rest.inverse())
            );
        }
    }
    let local = local.replace("link0", "upper").replace("link1", "fore");
    let world = world.replace("link0", "upper").replace("link1", "fore");
    let t_local = files::write(dir.path(), "arm.csv", &local);
    let t_world = files::write(dir.path(), "arm-world.csv", &world);
    for (t, rows) in [(&t_local, "local"), (&t_world, "world")] {
        let out = sweptvol(&files::run_args(
            &g,
            t,
            dir.path(),
            &["--rows", rows, "--resolution", "64"],
        ));
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("arm.report.json")).unwrap())
            .unwrap();
    assert_eq!(report["inputs"]["rows"], "local");
    let bound = report["mesh"]["hausdorff_bound"]
        .as_f64()
        .unwrap()
        .to_string();
    let check = |mesh: &str| {
        let m = dir.path().join(mesh);
        sweptvol(&files::verify_args(
            &g,
            &t_local,
            &m,
            &["--rows", "local", "--bound", &bound, "--quiet"],
        ))
    };
    let own = check("arm.swept.glb");
    assert!(
        own.status.success(),
        "{}{}",
        String::from_utf8_lossy(&own.stdout),
        String::from_utf8_lossy(&own.stderr)
    );
    let other = check("arm-world.swept.glb");
    assert_eq!(
        other.status.code(),
        Some(3),
        "{}",
        String::from_utf8_lossy(&other.stdout)
    );
}

/// Each interval's path bound is at least the fastest speed of every vertex over it (the speed
/// measured by chords of 1/2000 of the interval, which can only understate it): on 200 random
/// chains, a third of them with stretched rows. Both of the chain's bounds are held to it; a
/// second bound without its acceleration term fails here.
#[test]
fn the_path_bound_covers_the_fastest_vertex() {
    let mut worst: f64 = 0.0;
    for case in 0..200u64 {
        let mut rng = Rng::with_seed(11_000 + case);
        let chain = random_chain(&mut rng);
        let g = chain.generator();
        // Every third case stretches each row differently: the bound's stretch terms too.
        let mut rows = chain.local_rows();
        if case % 3 == 0 {
            for pose in &mut rows.poses {
                let s = DVec3::new(
                    rng.range(0.8, 1.2),
                    rng.range(0.8, 1.2),
                    rng.range(0.8, 1.2),
                );
                pose.matrix *= DMat4::from_scale(s);
            }
        }
        let (_, intervals) =
            sweptvol::input::chain::resolve(&g, &rows, Path::new("arm.csv"), Motion::Screw)
                .unwrap();
        for iv in &intervals {
            let steps = 2000;
            let poses: Vec<DMat4> = (0..=steps)
                .map(|j| iv.at(j as f64 / steps as f64))
                .collect();
            for v in &g.parts[iv.part].positions {
                let v = v.as_dvec3();
                let fastest = poses
                    .windows(2)
                    .map(|w| (w[1].transform_point3(v) - w[0].transform_point3(v)).length())
                    .fold(0.0, f64::max)
                    * steps as f64;
                worst = worst.max(fastest / iv.path);
                assert!(
                    fastest <= iv.path * (1.0 + 1e-9),
                    "case {case}: a vertex moves at {fastest}, bound {}",
                    iv.path
                );
            }
        }
    }
    println!("200 chains: the fastest vertex reaches {worst:.4} of its interval's bound");
}
