//! The mesh stage block by block (issue 26): where the surface crosses block borders many times
//! (small blocks, thin slabs lying across border planes, parts straddling block corners, blocks
//! holding a voxel or two of surface), the output still encloses every posed point, keeps its
//! clearance, stays within the stated bound, and is a closed 2-manifold without
//! self-intersections, checked independently of the library (f64 winding numbers and
//! distances, `verify`'s health check).

mod common;

use common::{build, dist_to_set, generator, posed_grid_triangles, tetrahedron, winding_number};
use common::{Draw, Rng, V3};
use glam::{DMat4, DVec3};
use sweptvol::input::model::Generator;
use sweptvol::simplify::pieces::Pieces;
use sweptvol::simplify::SimplifyOptions;
use sweptvol::surface::{self, Params, Surface};
use sweptvol::sweep::reach::reach;
use sweptvol::sweep::{cpu, Silent};
use sweptvol::verify::bvh::Bvh;
use sweptvol::verify::health;

/// A closed box [lo, hi] as one part.
fn slab(lo: [f64; 3], hi: [f64; 3]) -> Generator {
    let pos: Vec<[f32; 3]> = (0..8)
        .map(|k| std::array::from_fn(|a| (if k >> a & 1 == 1 { hi[a] } else { lo[a] }) as f32))
        .collect();
    let tris = common::BOX_TRIANGLES.to_vec();
    generator(pos, tris)
}

/// Sweep and build the mesh as the pipeline does (flooded: the parts are closed), with blocks
/// of `block` voxels; then check it. Returns the output's triangle count.
fn check(g: &Generator, poses: &[DMat4], n: u32, block: usize, rng: &mut Rng, what: &str) -> usize {
    let input = build(g, poses, n);
    let images = cpu::sweep(&input, &Silent).unwrap();
    let r = reach(&input, &Silent).unwrap();
    let opts = SimplifyOptions::for_params(&input.params, input.grid.h, 0).unwrap();
    let params = Params {
        block,
        ..Params::new(opts)
    };
    let s: Surface = surface::build(
        &images,
        Some(r),
        Pieces::of(&input).as_ref(),
        &params,
        &|| false,
    )
    .unwrap();
    let m = &s.mesh;
    assert!(s.carved);

    // A closed 2-manifold without self-intersections (verify's own check, in grid units).
    let defects = m.manifold_defects();
    assert!(defects.is_manifold(), "{what}: {defects:?}");
    let tris: Vec<[DVec3; 3]> = m
        .triangles
        .iter()
        .map(|t| t.map(|v| m.positions[v as usize]))
        .collect();
    let (h, _) = health::check(&tris, &Bvh::build(tris.clone(), 8));
    assert!(
        h.watertight_manifold && h.self_intersecting_pairs == 0 && h.degenerate_triangles == 0,
        "{what}: {h:?}"
    );

    // Enclosure: points of every posed triangle have winding number 1.
    let posed = posed_grid_triangles(g, poses, &input);
    let pos: Vec<V3> = m.positions.iter().map(|p| p.to_array()).collect();
    for t in &posed {
        for _ in 0..8 {
            let (mut a, mut b) = (rng.f64(), rng.f64());
            if a + b > 1.0 {
                (a, b) = (1.0 - a, 1.0 - b);
            }
            let p: V3 = std::array::from_fn(|c| {
                t[0][c] + a * (t[1][c] - t[0][c]) + b * (t[2][c] - t[0][c])
            });
            let w = winding_number(&pos, &m.triangles, p);
            assert!(w > 0.99, "{what}: posed point {p:?} has winding number {w}");
        }
    }

    // Clearance and the stated bound (everywhere: the classification floods), grid units.
    let h_ = input.grid.h;
    let d = input.params.delta / h_;
    let r_tol = opts.tolerance.outside;
    let bound = r_tol.max(s.joined_reach) + d + 2.0 * input.rounding;
    for t in &m.triangles {
        let [a, b, c] = t.map(|v| m.positions[v as usize]);
        for p in [a, (a + b + c) / 3.0, (a + b) / 2.0, (a * 4.0 + b + c) / 6.0] {
            let dist = dist_to_set(p.to_array(), &posed);
            assert!(
                dist >= d - r_tol - 1e-9,
                "{what}: {p} only {dist} voxels from the part"
            );
            assert!(
                dist <= bound + 1e-9,
                "{what}: {p} is {dist} voxels away, bound {bound}"
            );
        }
    }
    m.triangles.len()
}

#[test]
fn thin_slabs_across_block_borders() {
    let mut rng = Rng::with_seed(26);
    for case in 0..6 {
        // A slab a few voxels thick, tilted a little, so block planes cut it all along.
        let g = slab([0.0, 0.0, 0.0], [1.0, 0.9, 0.06 + 0.02 * case as f64]);
        let tilt = DMat4::from_axis_angle(
            DVec3::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), 1.0).normalize(),
            rng.range(0.0, 0.3),
        );
        let poses = [
            tilt,
            DMat4::from_translation(DVec3::new(0.02, 0.01, 0.0)) * tilt,
        ];
        for block in [2, 3, 7] {
            let what = format!("slab {case}, blocks of {block}");
            check(&g, &poses, 40, block, &mut rng, &what);
        }
    }
}

#[test]
fn parts_straddling_block_corners() {
    let mut rng = Rng::with_seed(27);
    for case in 0..8 {
        let g = tetrahedron(&mut rng, 0.5, [0.0; 3]);
        let poses = common::random_rigid_poses(&mut rng);
        // Blocks of half the grid and less: their corners meet inside the part.
        for block in [16, 9, 5] {
            let what = format!("tetrahedron {case}, blocks of {block}");
            check(&g, &poses, 32, block, &mut rng, &what);
        }
    }
}

#[test]
fn blocks_holding_a_voxel_or_two_of_surface() {
    // Blocks of one and two voxels: every patch is a few faces, almost all of it seams, so the
    // seam pass does nearly everything; the result still checks out, as coarse as with one
    // block for the whole grid.
    let mut rng = Rng::with_seed(28);
    let g = tetrahedron(&mut rng, 0.5, [0.0; 3]);
    let poses = [DMat4::IDENTITY, DMat4::from_rotation_z(0.4)];
    let whole = check(&g, &poses, 24, 64, &mut rng, "one block");
    for block in [1, 2] {
        let t = check(
            &g,
            &poses,
            24,
            block,
            &mut rng,
            &format!("blocks of {block}"),
        );
        assert!(
            t <= whole * 13 / 10,
            "blocks of {block}: {t} triangles against {whole} in one block"
        );
    }
}

/// The sweep check's pieces (docs/design.md, "The sweep check by pieces"): one per connected
/// component of a part (triangles joined by shared vertex positions) per row, also with the
/// screw motion between rows, each given by points of the posed part.
#[test]
fn pieces_are_the_parts_components_at_each_row() {
    let (a, b, c) = (
        slab([0.0, 0.0, 0.0], [1.0, 1.0, 1.0]),
        slab([3.0, 0.0, 0.0], [4.0, 1.0, 1.0]),
        slab([1.0, 1.0, 1.0], [2.0, 2.0, 2.0]), // shares a corner with a: one component
    );
    let mut g = a.clone();
    for other in [&b, &c] {
        let base = g.parts[0].positions.len() as u32;
        g.parts[0]
            .positions
            .extend(other.parts[0].positions.iter().copied());
        g.parts[0]
            .triangles
            .extend(other.parts[0].triangles.iter().map(|t| t.map(|v| v + base)));
    }
    let poses: Vec<DMat4> = (0..3)
        .map(|k| DMat4::from_translation(DVec3::new(0.3 * k as f64, 0.1, 0.0)))
        .collect();
    for motion in [
        sweptvol::input::motion::Motion::Discrete,
        sweptvol::input::motion::Motion::Screw,
    ] {
        let input = common::build_with(&g, &poses, 24, motion);
        let pieces = Pieces::of(&input).expect("few pieces");
        assert_eq!(pieces.len(), 2 * poses.len(), "{motion:?}");
        let vertices: Vec<V3> = posed_grid_triangles(&g, &poses, &input)
            .into_iter()
            .flatten()
            .collect();
        for p in pieces.points().iter().flatten() {
            assert!(
                vertices
                    .iter()
                    .any(|v| (DVec3::from_array(*v) - *p).length() < 1e-9),
                "{motion:?}: {p} is no posed vertex"
            );
        }
    }
}
