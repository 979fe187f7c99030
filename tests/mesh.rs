//! The mesh stage against independent checks: the output encloses every posed triangle
//! (generalized winding number), keeps its clearance from the swept volume, stays within the
//! reported Hausdorff bound where concavities are visible, is watertight and outward, and
//! survives the .glb round trip and the Khronos validator.

mod common;

use common::{
    build, dist_to_set, posed_grid_triangles, random_rigid_poses, tetrahedron, winding_number, Rng,
    V3,
};
use glam::{DMat4, DVec3};
use sweptvol::depth::DepthImages;
use sweptvol::input::model::Generator;
use sweptvol::input::posed::SweepInput;
use sweptvol::io::{gltf_in, gltf_out};
use sweptvol::mesh::classify::Classifier;
use sweptvol::mesh::extract::extract;
use sweptvol::mesh::Mesh;
use sweptvol::simplify::pieces::Pieces;
use sweptvol::simplify::SimplifyOptions;
use sweptvol::surface::{self, Params};
use sweptvol::sweep::{cpu, Silent};

/// Sweep `g` along `poses` at resolution `n`: the input, the depth images and the voxel boundary.
fn sweep_mesh(g: &Generator, poses: &[DMat4], n: u32) -> (SweepInput, DepthImages, Mesh) {
    let input = build(g, poses, n);
    let images = cpu::sweep(&input, &Silent).unwrap();
    let mesh = extract(&Classifier::new(&images));
    (input, images, mesh)
}

/// Points on every posed triangle: vertices, edge points and interior points.
fn samples(tris: &[[V3; 3]], rng: &mut Rng, per: usize) -> Vec<V3> {
    let mut out = Vec::new();
    for t in tris {
        out.extend_from_slice(t);
        for _ in 0..per {
            let (mut a, mut b) = (rng.f64(), rng.f64());
            if a + b > 1.0 {
                (a, b) = (1.0 - a, 1.0 - b);
            }
            out.push(std::array::from_fn(|c| {
                t[0][c] + a * (t[1][c] - t[0][c]) + b * (t[2][c] - t[0][c])
            }));
        }
    }
    out
}

/// The simplifier's bands for the input's parameters, as the pipeline sets them.
fn simplify_options(input: &SweepInput) -> SimplifyOptions {
    SimplifyOptions::for_params(&input.params, input.grid.h, 0).expect("default parameters")
}

fn check_mesh(input: &SweepInput, mesh: &Mesh, tris: &[[V3; 3]], visible: bool, rng: &mut Rng) {
    check_mesh_with(input, mesh, tris, visible, rng, 3f64.sqrt() / 2.0);
}

/// `radius`: every mesh point is within this of an outside and of an inside voxel's centre,
/// voxels (the tolerance volume's radius; √3/2 for the unsimplified boundary itself).
fn check_mesh_with(
    input: &SweepInput,
    mesh: &Mesh,
    tris: &[[V3; 3]],
    visible: bool,
    rng: &mut Rng,
    radius: f64,
) {
    assert!(
        mesh.unpaired_edges().is_empty(),
        "mesh is not watertight or not consistently oriented"
    );
    assert!(mesh.volume() > 0.0, "mesh faces inward");
    let pos: Vec<V3> = mesh.positions.iter().map(|p| p.to_array()).collect();
    // Enclosure.
    for p in samples(tris, rng, 6) {
        let w = winding_number(&pos, &mesh.triangles, p);
        assert!(
            w > 0.99,
            "swept point {p:?} has winding number {w}: outside the mesh"
        );
    }
    // Clearance and (where concavities are visible) the Hausdorff bound, grid units.
    let d = input.params.delta / input.grid.h;
    let bound = radius + d + 2.0 * input.rounding;
    let mut worst: f64 = 0.0;
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
        for p in [a, (a + b + c) / 3.0, (a + b) / 2.0] {
            let dist = dist_to_set(p.to_array(), tris);
            assert!(
                dist >= d - radius - 1e-9,
                "mesh point {p} only {dist} voxels from the swept volume"
            );
            worst = worst.max(dist);
        }
    }
    if visible {
        assert!(
            worst <= bound,
            "one-sided Hausdorff {worst} exceeds the bound {bound} (voxels)"
        );
    }
}

#[test]
fn convex_part_at_one_pose() {
    let mut rng = Rng::with_seed(3);
    let g = tetrahedron(&mut rng, 0.5, [0.0; 3]);
    let (input, _, mesh) = sweep_mesh(&g, &[DMat4::IDENTITY], 28);
    let tris = posed_grid_triangles(&g, &[DMat4::IDENTITY], &input);
    check_mesh(&input, &mesh, &tris, true, &mut rng);
}

#[test]
fn part_translated_along_a_staircase_path() {
    let mut rng = Rng::with_seed(4);
    let g = tetrahedron(&mut rng, 0.3, [0.0; 3]);
    let poses: Vec<DMat4> = (0..6)
        .map(|k| DMat4::from_translation(DVec3::new(0.15 * k as f64, 0.1 * k as f64, 0.0)))
        .collect();
    let (input, _, mesh) = sweep_mesh(&g, &poses, 36);
    let tris = posed_grid_triangles(&g, &poses, &input);
    check_mesh(&input, &mesh, &tris, true, &mut rng);
}

#[test]
fn random_parts_and_trajectories_are_enclosed() {
    for seed in 0..4u64 {
        let mut rng = Rng::with_seed(100 + seed);
        let g = tetrahedron(&mut rng, 0.4, [0.0; 3]);
        let poses = random_rigid_poses(&mut rng);
        let (input, _, mesh) = sweep_mesh(&g, &poses, 30);
        let tris = posed_grid_triangles(&g, &poses, &input);
        // Random rotations can hide concavities from all six directions: enclosure and
        // clearance only.
        check_mesh(&input, &mesh, &tris, false, &mut rng);
    }
}

#[test]
fn glb_round_trip_and_khronos_validator() {
    let mut rng = Rng::with_seed(9);
    let g = tetrahedron(&mut rng, 0.5, [0.0; 3]);
    let (input, _, mesh) = sweep_mesh(&g, &[DMat4::IDENTITY, DMat4::from_rotation_z(0.5)], 24);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.swept.glb");
    gltf_out::write_glb(
        &path,
        &mesh,
        &input.grid,
        "t swept volume",
        serde_json::json!({"k": 1}),
    )
    .unwrap();
    let back = gltf_in::read_generator(&path).unwrap();
    assert_eq!(back.parts.len(), 1);
    assert_eq!(back.parts[0].triangles, mesh.triangles);
    let (world, _) = gltf_out::world_positions(&mesh, &input.grid);
    let read: Vec<[f32; 3]> = back.parts[0]
        .positions
        .iter()
        .map(|p| p.to_array())
        .collect();
    assert_eq!(read, world);

    if let Some(j) = common::files::khronos_report(&path) {
        assert_eq!(j["numErrors"], 0, "{j}");
        assert_eq!(j["numWarnings"], 0, "{j}");
    }
}

/// Simplify, then check everything again with the band's bounds.
fn check_simplified(
    g: &Generator,
    poses: &[DMat4],
    n: u32,
    visible: bool,
    seed: u64,
) -> (usize, usize) {
    let (input, images, _) = sweep_mesh(g, poses, n);
    let opts = simplify_options(&input);
    // Blocks of 8 voxels: the grids here are 24 to 36 wide, so seams run everywhere.
    let params = Params {
        block: 8,
        ..Params::new(opts)
    };
    // The sweep check both ways: by the swept volume's pieces (as the pipeline runs it) on even
    // seeds, by the region tests (beyond `MAX_PIECES`) on odd ones.
    let pieces = (seed % 2 == 0).then(|| Pieces::of(&input).expect("few pieces"));
    let s =
        surface::build(&images, None, pieces.as_ref(), &params, &|| false).expect("not stopped");
    let (out, stats) = (s.mesh, s.stats);
    assert!(out.manifold_defects().is_manifold());
    let tris = posed_grid_triangles(g, poses, &input);
    check_mesh_with(
        &input,
        &out,
        &tris,
        visible,
        &mut Rng::with_seed(seed),
        // The radius the report's clearance and bound are derived from, ε + √3h/2 (not the
        // simplifier's own figure: a wrong one there must fail here), or the joined voxels'
        // reach where it is larger.
        (input.params.epsilon / input.grid.h + 3f64.sqrt() / 2.0).max(s.joined_reach),
    );
    assert!(stats.collapses > 0);
    (s.triangles_start as usize, out.triangles.len())
}

#[test]
fn simplified_meshes_keep_enclosure_clearance_and_bound() {
    let mut rng = Rng::with_seed(3);
    let g = tetrahedron(&mut rng, 0.5, [0.0; 3]);
    let (t0, t1) = check_simplified(&g, &[DMat4::IDENTITY], 28, true, 1);
    println!("convex part: {t0} -> {t1} triangles");
    assert!(t1 * 5 < t0, "{t0} -> {t1}: the simplifier barely worked");

    let mut rng = Rng::with_seed(4);
    let g = tetrahedron(&mut rng, 0.3, [0.0; 3]);
    let poses: Vec<DMat4> = (0..6)
        .map(|k| DMat4::from_translation(DVec3::new(0.15 * k as f64, 0.1 * k as f64, 0.0)))
        .collect();
    let (t0, t1) = check_simplified(&g, &poses, 36, true, 2);
    println!("staircase path: {t0} -> {t1} triangles");

    for seed in 0..3u64 {
        let mut rng = Rng::with_seed(100 + seed);
        let g = tetrahedron(&mut rng, 0.4, [0.0; 3]);
        let poses = random_rigid_poses(&mut rng);
        let (t0, t1) = check_simplified(&g, &poses, 30, false, 10 + seed);
        println!("random {seed}: {t0} -> {t1} triangles");
    }
}
