//! No blind spots (issue 17): condition ⋆ fills a concavity that no axis looks into; the flood
//! from outside (`sweep::reach`, `mesh::flood`, `Classifier::carve`) opens it, and stays sound.
//!
//! The analytic case: a solid block 10 units wide, made of closed boxes, with an L-shaped
//! channel: down from the top face, then sideways to a dead end. No axis sees the sideways
//! branch (every axis line through it meets solid on both sides), so ⋆ fills it; the flood
//! enters through the channel and keeps it open. Each check below fails on the other
//! classification, and a reach with a hole lets the flood into the solid, which the
//! conservativeness check catches.

mod common;

use common::{build, dist_triangle, generator, winding_number, Draw, Rng, V3};
use glam::DMat4;
use sweptvol::input::model::Generator;
use sweptvol::input::posed::SweepInput;
use sweptvol::mesh::classify::Classifier;
use sweptvol::mesh::flood::flood;
use sweptvol::mesh::Mesh;
use sweptvol::simplify::pieces::Pieces;
use sweptvol::simplify::SimplifyOptions;
use sweptvol::surface::{self, Params};
use sweptvol::sweep::reach::reach;
use sweptvol::sweep::{cpu, Silent};
use sweptvol::voxels::VoxelBits;

type Box3 = ([f64; 3], [f64; 3]);

/// The block [0, 10]³ less the channel: [4, 6]² × [4, 10] down from the top, then the branch
/// [6, 8] × [4, 6] × [4, 6] sideways (hidden from all six directions).
fn l_channel_boxes() -> Vec<Box3> {
    vec![
        ([0.0, 0.0, 0.0], [10.0, 10.0, 4.0]), // floor
        ([0.0, 0.0, 6.0], [4.0, 10.0, 10.0]), // top layer around the shaft
        ([6.0, 0.0, 6.0], [10.0, 10.0, 10.0]),
        ([4.0, 0.0, 6.0], [6.0, 4.0, 10.0]),
        ([4.0, 6.0, 6.0], [6.0, 10.0, 10.0]),
        ([0.0, 0.0, 4.0], [4.0, 10.0, 6.0]), // middle layer around the shaft's foot and branch
        ([8.0, 0.0, 4.0], [10.0, 10.0, 6.0]),
        ([4.0, 0.0, 4.0], [8.0, 4.0, 6.0]),
        ([4.0, 6.0, 4.0], [8.0, 10.0, 6.0]),
    ]
}

/// One part holding every box as a closed, outward triangle mesh.
fn boxes_generator(boxes: &[Box3]) -> Generator {
    let mut pos: Vec<[f32; 3]> = Vec::new();
    let mut tris = Vec::new();
    for (lo, hi) in boxes {
        let base = pos.len() as u32;
        for k in 0..8 {
            pos.push(std::array::from_fn(|a| {
                (if k >> a & 1 == 1 { hi[a] } else { lo[a] }) as f32
            }));
        }
        for t in common::BOX_TRIANGLES {
            tris.push(t.map(|i| base + i));
        }
    }
    generator(pos, tris)
}

fn centre((lo, hi): &Box3) -> V3 {
    std::array::from_fn(|a| (lo[a] + hi[a]) / 2.0)
}

fn dist_box(p: V3, (lo, hi): &Box3) -> f64 {
    (0..3)
        .map(|a| (lo[a] - p[a]).max(p[a] - hi[a]).max(0.0).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// The classifier for `input`'s images: ⋆ alone, or ⋆ less the flood.
fn classify(input: &SweepInput, flooded: bool) -> Classifier {
    let images = cpu::sweep(input, &Silent).unwrap();
    let cls = Classifier::new(&images);
    if !flooded {
        return cls;
    }
    cls.carve(flood(&reach(input, &Silent).unwrap()))
}

/// The mesh stage's output (world units) and its stated bound, as the pipeline makes and
/// states them: ⋆ alone, or ⋆ less the flood (with the reach altered first by `mutate`, for
/// the test that shows a flood through the offset is caught). Blocks of 16 voxels, so seams
/// cross the part.
fn mesh_and_bound(
    input: &SweepInput,
    flooded: bool,
    mutate: impl FnOnce(&mut VoxelBits),
) -> (Mesh, f64) {
    let images = cpu::sweep(input, &Silent).unwrap();
    let r = flooded.then(|| {
        let mut r = reach(input, &Silent).unwrap();
        mutate(&mut r);
        r
    });
    let opts = SimplifyOptions::for_params(&input.params, input.grid.h, 0).unwrap();
    let params = Params {
        block: 16,
        ..Params::new(opts)
    };
    let s = surface::build(&images, r, Pieces::of(input).as_ref(), &params, &|| false)
        .expect("not stopped");
    assert!(s.mesh.manifold_defects().is_manifold());
    let mut out = s.mesh;
    let h = input.grid.h;
    for p in &mut out.positions {
        *p = *p * h + glam::DVec3::from_array(input.grid.origin);
    }
    let bound = (input.params.epsilon + 3f64.sqrt() / 2.0 * h).max(s.joined_reach * h)
        + input.params.delta
        + input.motion.mu
        + 2.0 * input.rounding * h;
    (out, bound)
}

/// Points on every triangle of `m`: its vertices and 10 interior points (a deviation measured at
/// vertices alone would miss the middle of a large flat triangle).
fn face_points(m: &Mesh) -> Vec<V3> {
    let mut out: Vec<V3> = m.positions.iter().map(|p| p.to_array()).collect();
    for t in &m.triangles {
        let [a, b, c] = t.map(|i| m.positions[i as usize]);
        for u in 1..6 {
            for v in 1..(6 - u) {
                let (u, v) = (u as f64 / 6.0, v as f64 / 6.0);
                out.push((a + (b - a) * u + (c - a) * v).to_array());
            }
        }
    }
    out
}

fn inside(mesh: &Mesh, p: V3) -> bool {
    let pos: Vec<V3> = mesh.positions.iter().map(|p| p.to_array()).collect();
    winding_number(&pos, &mesh.triangles, p) > 0.5
}

/// Points of the solid: every box's centre and a 7 × 7 grid on each of its faces. (The centres
/// matter: a flood inside a closed part eats its interior, not the offset around its surface.)
fn solid_points(boxes: &[Box3]) -> Vec<V3> {
    let mut out: Vec<V3> = boxes.iter().map(centre).collect();
    for (lo, hi) in boxes {
        for a in 0..3 {
            for side in [lo[a], hi[a]] {
                for u in 0..=6 {
                    for v in 0..=6 {
                        let (b, c) = ((a + 1) % 3, (a + 2) % 3);
                        let mut p = [0.0; 3];
                        p[a] = side;
                        p[b] = lo[b] + (hi[b] - lo[b]) * u as f64 / 6.0;
                        p[c] = lo[c] + (hi[c] - lo[c]) * v as f64 / 6.0;
                        out.push(p);
                    }
                }
            }
        }
    }
    out
}

#[test]
fn a_hidden_branch_is_kept_open_by_the_flood_and_filled_by_the_axes() {
    let boxes = l_channel_boxes();
    let g = boxes_generator(&boxes);
    assert_eq!(g.parts[0].boundary_edges(), 0, "the boxes are closed");
    let input = build(&g, &[DMat4::IDENTITY], 80);
    let branch = [7.0, 5.0, 5.0];
    let to_voxel = |p: V3| {
        let q = input.grid.to_grid(glam::DVec3::from_array(p));
        [
            q.x.floor() as isize,
            q.y.floor() as isize,
            q.z.floor() as isize,
        ]
    };
    let [i, j, k] = to_voxel(branch);

    let axes = classify(&input, false);
    assert!(
        axes.inside(i, j, k),
        "condition ⋆ should fill the hidden branch"
    );
    let carved = classify(&input, true);
    assert!(
        !carved.inside(i, j, k),
        "the flood should open the hidden branch"
    );
    // The shaft is seen from the top: both open it.
    let [i, j, k] = to_voxel([5.0, 5.0, 8.0]);
    assert!(!axes.inside(i, j, k) && !carved.inside(i, j, k));

    let (flooded_mesh, bound) = mesh_and_bound(&input, true, |_| {});
    let (axes_mesh, axes_bound) = mesh_and_bound(&input, false, |_| {});
    assert!(!inside(&flooded_mesh, branch) && inside(&axes_mesh, branch));

    // Conservative: every point of the block is inside the flooded output.
    let points = solid_points(&boxes);
    let out: Vec<&V3> = points
        .iter()
        .filter(|p| !inside(&flooded_mesh, **p))
        .collect();
    assert!(
        out.is_empty(),
        "{} of {} points of the block outside, e.g. {:?}",
        out.len(),
        points.len(),
        &out[..out.len().min(3)]
    );

    // Tight everywhere: every point of the output's triangles is within the stated bound of the
    // block; the axes' output has its lid over the branch about a unit away, beyond the bound.
    let deviation = |m: &Mesh| {
        face_points(m)
            .iter()
            .map(|p| {
                boxes
                    .iter()
                    .map(|b| dist_box(*p, b))
                    .fold(f64::INFINITY, f64::min)
            })
            .fold(0.0, f64::max)
    };
    let (d_flood, d_axes) = (deviation(&flooded_mesh), deviation(&axes_mesh));
    println!(
        "h = {:.4}: deviation {d_flood:.4} (flood), {d_axes:.4} (axes), bound {bound:.4} / {axes_bound:.4}",
        input.grid.h
    );
    assert!(
        d_flood <= bound,
        "flood: deviation {d_flood} beyond the bound {bound}"
    );
    assert!(
        d_axes > axes_bound,
        "axes: the filled branch should lie beyond the bound ({d_axes} vs {axes_bound})"
    );
}

#[test]
fn a_flood_through_the_offset_is_caught() {
    // The same block with a tunnel cut through the reach along one x row through the middle
    // layer: the flood pours into that box's interior, and the check of the block's points
    // fails (so it can).
    let boxes = l_channel_boxes();
    let input = build(&boxes_generator(&boxes), &[DMat4::IDENTITY], 60);
    let (mesh, _) = mesh_and_bound(&input, true, |r| {
        let [nx, ny, nz] = r.dims;
        let (j, k) = (ny / 2, nz / 2);
        for i in 0..nx {
            // clear one whole x row through the block's middle: a tunnel through the reach
            let row = r.row_index(j, k);
            r.row_mut(row)[i / 64] &= !(1u64 << (i % 64));
        }
        let _ = nz;
    });
    let outside = solid_points(&boxes)
        .into_iter()
        .filter(|p| !inside(&mesh, *p))
        .count();
    assert!(
        outside > 0,
        "a reach with a tunnel should let the flood eat into the block"
    );
}

/// Random closed generators (tetrahedra, boxes) under random rigid poses: the flooded output
/// encloses every sampled point of every posed triangle and of the part's interior, and every
/// point of its triangles is within the stated bound of the posed triangles.
#[test]
fn random_closed_parts_stay_enclosed_and_within_the_bound() {
    let mut rng = Rng::with_seed(0x17);
    for case in 0..12 {
        // The part, and points of its interior (local frame).
        let (g, interior) = if case % 2 == 0 {
            let g = common::tetrahedron(&mut rng, 1.0, [0.0; 3]);
            let c = g.parts[0]
                .positions
                .iter()
                .fold(glam::DVec3::ZERO, |s, p| s + p.as_dvec3());
            (g, vec![(c / 4.0).to_array()])
        } else {
            let a: [f64; 3] = std::array::from_fn(|_| rng.range(-1.0, 0.0));
            let b: [f64; 3] = std::array::from_fn(|c| a[c] + rng.range(0.2, 1.5));
            let boxes = [
                (a, b),
                ([a[0], a[1], b[2]], [b[0] + 0.5, a[1] + 0.3, b[2] + 0.4]),
            ];
            (boxes_generator(&boxes), boxes.iter().map(centre).collect())
        };
        let poses = common::random_rigid_poses(&mut rng);
        let input = build(&g, &poses, 48);
        let (mesh, bound) = mesh_and_bound(&input, true, |_| {});
        let part = &g.parts[0];
        let mut tris: Vec<[V3; 3]> = Vec::new();
        for m in &poses {
            for t in &part.triangles {
                tris.push(t.map(|i| {
                    m.transform_point3(part.positions[i as usize].as_dvec3())
                        .to_array()
                }));
            }
        }
        let mut checked = 0;
        for t in &tris {
            for _ in 0..12 {
                let (mut u, mut v) = (rng.f64(), rng.f64());
                if u + v > 1.0 {
                    (u, v) = (1.0 - u, 1.0 - v);
                }
                let p: V3 = std::array::from_fn(|c| {
                    t[0][c] + u * (t[1][c] - t[0][c]) + v * (t[2][c] - t[0][c])
                });
                assert!(
                    inside(&mesh, p),
                    "case {case}: posed surface point {p:?} outside"
                );
                checked += 1;
            }
        }
        for m in &poses {
            for c in &interior {
                let p = m.transform_point3(glam::DVec3::from_array(*c)).to_array();
                assert!(
                    inside(&mesh, p),
                    "case {case}: interior point {p:?} outside"
                );
            }
        }
        let dists: Vec<f64> = face_points(&mesh)
            .iter()
            .map(|p| {
                tris.iter()
                    .map(|t| dist_triangle(*p, *t))
                    .fold(f64::INFINITY, f64::min)
            })
            .collect();
        let worst = dists.iter().fold(0.0, |a: f64, b| a.max(*b));
        assert!(
            worst <= bound,
            "case {case}: a mesh point {worst} from the posed part, bound {bound}"
        );
        // The clearance the report states, δ - ε - √3h/2, with the default (exact) radii 0.07h.
        let h = input.grid.h;
        let clearance = input.params.delta - input.params.epsilon - 3f64.sqrt() / 2.0 * h;
        assert!((clearance / h - 0.07).abs() < 1e-9);
        let nearest = dists.iter().fold(f64::INFINITY, |a, b| a.min(*b));
        assert!(
            nearest >= clearance - 1e-9 * h,
            "case {case}: a mesh point only {nearest} from the posed part, clearance {clearance}"
        );
        eprintln!(
            "case {case}: deviation {:.3}h (bound {:.3}h), nearest {:.3}h",
            worst / h,
            bound / h,
            nearest / h
        );
        assert!(checked > 0);
    }
}

/// An open part (a box without its top, under a wider lid): `auto` keeps condition ⋆ alone and
/// says why (the box's inside stays filled, the solid a user may have meant), `flood` opens it
/// through the gap under the lid, hollowing the box: its centre is then outside, yet every point
/// of the part's surface is still inside.
#[test]
fn an_open_part_is_flooded_only_when_asked() {
    use common::files::{glb, run_args, sweptvol, write};
    let dir = tempfile::tempdir().unwrap();
    let boxes = [
        ([0.0, 0.0, 0.0], [1.0, 1.0, 1.0]),
        ([-0.2, -0.2, 1.4], [1.2, 1.2, 1.5]),
    ];
    let g = boxes_generator(&boxes);
    let part = &g.parts[0];
    // Drop the box's top face (its two triangles with every vertex at z = 1).
    let tris: Vec<[u32; 3]> = part
        .triangles
        .iter()
        .copied()
        .filter(|t| {
            !t.iter()
                .all(|&i| i < 8 && part.positions[i as usize].z == 1.0)
        })
        .collect();
    assert_eq!(tris.len(), 22);
    let pos: Vec<[f32; 3]> = part.positions.iter().map(|p| p.to_array()).collect();
    let gpath = write(dir.path(), "cup.glb", glb(&pos, &tris));
    let csv = write(
        dir.path(),
        "cup.csv",
        "tx,ty,tz,qw,qx,qy,qz\n0,0,0,1,0,0,0\n",
    );
    let centre = [0.5, 0.5, 0.5];
    let mut surface: Vec<V3> = Vec::new();
    for t in &tris {
        let [a, b, c] = t.map(|i| part.positions[i as usize].as_dvec3());
        for (u, v) in [(0.2, 0.2), (0.6, 0.2), (0.2, 0.6), (0.0, 0.0)] {
            surface.push((a + (b - a) * u + (c - a) * v).to_array());
        }
    }
    for (classify, method, centre_inside) in [("auto", "axes", true), ("flood", "flood", false)] {
        let out = dir.path().join(classify);
        let o = sweptvol(&run_args(
            &gpath,
            &csv,
            &out,
            &["--resolution", "48", "--classify", classify],
        ));
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let report: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("cup.report.json")).unwrap()).unwrap();
        let c = &report["classification"];
        assert_eq!(c["method"], method, "{c}");
        if classify == "auto" {
            let reason = c["reason"].as_str().unwrap();
            assert!(
                reason.contains("open parts") && reason.contains("\"part\" (4 boundary edges)"),
                "{reason}"
            );
        }
        let mesh = sweptvol::io::gltf_in::read_generator(&out.join("cup.swept.glb")).unwrap();
        let m = &mesh.parts[0];
        let positions: Vec<V3> = m
            .positions
            .iter()
            .map(|p| m.world.transform_point3(p.as_dvec3()).to_array())
            .collect();
        let wn = |p: V3| winding_number(&positions, &m.triangles, p);
        assert_eq!(
            wn(centre) > 0.5,
            centre_inside,
            "{classify}: winding {} at the centre",
            wn(centre)
        );
        let outside = surface.iter().filter(|p| wn(**p) < 0.5).count();
        assert_eq!(outside, 0, "{classify}: {outside} surface points outside");
    }
}
