//! The sweep against known answers: analytic cases, the f64 oracle, the sample-point
//! conservativeness property, and the GPU path against its CPU twin.

mod common;

use std::path::Path;

use common::{
    build, check_samples, dist_to_set, generator, line_interval, posed_grid_triangles, tetrahedron,
    Draw, Rng, V3,
};
use glam::{DMat4, DVec3};
use sweptvol::depth::{DepthImages, COLUMN_AXIS, ROW_AXIS};
use sweptvol::input::grid::{Accuracy, Overrides, Radii};
use sweptvol::input::model::{Generator, Pose, Trajectory};
use sweptvol::input::motion::Motion;
use sweptvol::input::posed::{self, SweepInput};
use sweptvol::sweep::{cpu, gpu::Gpu, Silent};

/// For every pixel of every image: the computed interval contains the exact interval of the
/// δ-offset (oracle) and lies inside the exact interval of the (δ + 2ρ)-offset.
fn check_against_oracle(input: &SweepInput, images: &DepthImages, tris: &[[V3; 3]]) {
    check_axes_against_oracle(input, images, tris, &[0, 1, 2]);
}

fn check_axes_against_oracle(
    input: &SweepInput,
    images: &DepthImages,
    tris: &[[V3; 3]],
    axes: &[usize],
) {
    let d = input.params.delta / input.grid.h;
    let rho = input.rounding;
    let mut checked_hits = 0;
    for img in images.images.iter().filter(|i| axes.contains(&i.axis)) {
        let a = img.axis;
        let (cu, rv) = (COLUMN_AXIS[a], ROW_AXIS[a]);
        for row in 0..img.height {
            for col in 0..img.width {
                let (u, v) = (col as f64 + 0.5, (img.height - 1 - row) as f64 + 0.5);
                let near = |t: &&[V3; 3], r: f64| {
                    let (lu, hu) = t.iter().fold((f64::MAX, f64::MIN), |m, p| {
                        (m.0.min(p[cu]), m.1.max(p[cu]))
                    });
                    let (lv, hv) = t.iter().fold((f64::MAX, f64::MIN), |m, p| {
                        (m.0.min(p[rv]), m.1.max(p[rv]))
                    });
                    u >= lu - r && u <= hu + r && v >= lv - r && v <= hv + r
                };
                let union = |r: f64| {
                    tris.iter()
                        .filter(|t| near(t, r))
                        .filter_map(|t| line_interval(*t, a, [(cu, u), (rv, v)], r))
                        .fold(None, |acc: Option<(f64, f64)>, (t0, t1)| {
                            Some(acc.map_or((t0, t1), |(a0, a1)| (a0.min(t0), a1.max(t1))))
                        })
                };
                let i = img.index(col, img.height - 1 - row);
                let (got0, got1) = (img.min[i] as f64, img.max[i] as f64);
                if let Some((t0, t1)) = union(d) {
                    checked_hits += 1;
                    assert!(
                        got0 <= t0 && got1 >= t1,
                        "axis {a} pixel ({col},{row}): exact [{t0}, {t1}] not inside [{got0}, {got1}]"
                    );
                }
                if !img.is_empty_at(i) {
                    let (w0, w1) = union(d + 2.0 * rho).unwrap_or_else(|| {
                        panic!("axis {a} pixel ({col},{row}) hit where δ+2ρ misses")
                    });
                    assert!(
                        got0 >= w0 - 1e-6 && got1 <= w1 + 1e-6,
                        "axis {a} pixel ({col},{row}): [{got0}, {got1}] exceeds [{w0}, {w1}]"
                    );
                }
            }
        }
    }
    assert!(
        checked_hits > 50,
        "only {checked_hits} pixels hit: the case tests nothing"
    );
}

fn pixel(images: &DepthImages, axis: usize, u: f64, v: f64) -> (f64, f64) {
    let img = &images.images[axis];
    let i = img.index(u.floor() as u32, v.floor() as u32);
    (img.min[i] as f64, img.max[i] as f64)
}

/// Assert a computed depth is the exact value for radius δ, rounded outward within 2ρ.
fn assert_depth(got: f64, exact_delta: f64, exact_wide: f64, what: &str) {
    let (lo, hi) = (exact_delta.min(exact_wide), exact_delta.max(exact_wide));
    // The δ side is where underestimation lives: only f64 rounding of the expected value there.
    let (lo_slack, hi_slack) = if exact_delta <= exact_wide {
        (1e-9, 1e-5)
    } else {
        (1e-5, 1e-9)
    };
    assert!(
        got >= lo - lo_slack && got <= hi + hi_slack,
        "{what}: got {got}, expected within [{lo}, {hi}]"
    );
}

#[test]
fn one_triangle_along_and_across_its_normal() {
    // Right triangle (0,0)-(1,0)-(0,1) in the plane z = 0.3.
    let g = generator(
        vec![[0.0, 0.0, 0.3], [1.0, 0.0, 0.3], [0.0, 1.0, 0.3]],
        vec![[0, 1, 2]],
    );
    let input = build(&g, &[DMat4::IDENTITY], 64);
    let images = cpu::sweep(&input, &Silent).unwrap();
    let grid = input.grid;
    let (h, o) = (grid.h, grid.origin());
    let d = input.params.delta / h;
    let wide = d + 2.0 * input.rounding;
    let gp = |p: DVec3| grid.to_grid(p);

    // Along the normal (z image: columns x, rows y), a ray well inside: the prism caps.
    let c = gp(DVec3::new(0.25, 0.25, 0.3));
    let (z0, z1) = pixel(&images, 2, c.x, c.y);
    assert_depth(z0, c.z - d, c.z - wide, "prism entry");
    assert_depth(z1, c.z + d, c.z + wide, "prism exit");

    // Across the normal (x image: columns z, rows y): rays parallel to the plane at height dz.
    let mut checked = 0;
    for row in 0..grid.dims[1] {
        for col in 0..grid.dims[2] {
            let (zu, yv) = (col as f64 + 0.5, row as f64 + 0.5);
            let y = o.y + yv * h;
            let dz = (o.z + zu * h - 0.3) / h; // grid units
            if !(0.2..0.8).contains(&y) || dz.abs() >= d {
                continue;
            }
            let (x0, x1) = pixel(&images, 0, zu, yv);
            let x_lo = -o.x / h; // the edge x = 0
            let x_hi = (1.0 - y - o.x) / h; // the hypotenuse at this y
            let s = |r: f64| (r * r - dz * dz).sqrt();
            assert_depth(
                x0,
                x_lo - s(d),
                x_lo - s(wide),
                "cylinder entry (edge x = 0)",
            );
            assert_depth(
                x1,
                x_hi + 2f64.sqrt() * s(d),
                x_hi + 2f64.sqrt() * s(wide),
                "cylinder exit (hypotenuse)",
            );
            checked += 1;
        }
    }
    assert!(checked > 20, "only {checked} across-normal rays checked");
    check_against_oracle(
        &input,
        &images,
        &posed_grid_triangles(&g, &[DMat4::IDENTITY], &input),
    );
}

#[test]
fn degenerate_point_triangle_sweeps_a_ball() {
    let p = [0.2f32, -0.1, 0.4];
    let g = generator(vec![p, p, p], vec![[0, 1, 2]]);
    // Zero extent: the tolerance sets the voxel size.
    let input = posed::build(
        &g,
        Path::new("t.glb"),
        &Trajectory::whole_scene(&[DMat4::IDENTITY]),
        Path::new("t.csv"),
        Accuracy::Tolerance(0.05),
        // The paper's δ ≈ 2.47h: a ball wide enough to cover at least 9 pixels per axis.
        Overrides {
            radii: Radii::Paper,
            ..Overrides::default()
        },
        Motion::Discrete,
    )
    .unwrap();
    let images = cpu::sweep(&input, &Silent).unwrap();
    let c = input
        .grid
        .to_grid(DVec3::new(0.2, -0.1, 0.4).as_vec3().as_dvec3());
    let d = input.params.delta / input.grid.h;
    let wide = d + 2.0 * input.rounding;
    let mut hits = 0;
    for axis in 0..3 {
        let img = &images.images[axis];
        let (cu, rv) = (COLUMN_AXIS[axis], ROW_AXIS[axis]);
        for rb in 0..img.height {
            for col in 0..img.width {
                let (u, v) = (col as f64 + 0.5, rb as f64 + 0.5);
                let r2 = (u - c[cu]).powi(2) + (v - c[rv]).powi(2);
                let i = img.index(col, rb);
                if r2 < d * d {
                    assert_depth(
                        img.min[i] as f64,
                        c[axis] - (d * d - r2).sqrt(),
                        c[axis] - (wide * wide - r2).sqrt(),
                        "ball entry",
                    );
                    assert_depth(
                        img.max[i] as f64,
                        c[axis] + (d * d - r2).sqrt(),
                        c[axis] + (wide * wide - r2).sqrt(),
                        "ball exit",
                    );
                    hits += 1;
                } else if r2 > wide * wide {
                    assert!(
                        img.is_empty_at(i),
                        "axis {axis} ({col},{rb}) outside the ball is not empty"
                    );
                }
            }
        }
    }
    assert!(hits >= 3 * 9, "the ball covered only {hits} pixels");
}

/// The 12 triangles of the box [lo, hi], some wound inconsistently on purpose.
fn box_mesh(lo: [f32; 3], hi: [f32; 3]) -> Generator {
    let mut pos = Vec::new();
    for k in 0..8 {
        pos.push([
            if k & 1 == 0 { lo[0] } else { hi[0] },
            if k & 2 == 0 { lo[1] } else { hi[1] },
            if k & 4 == 0 { lo[2] } else { hi[2] },
        ]);
    }
    let quads = [
        [0, 1, 3, 2],
        [4, 6, 7, 5],
        [0, 4, 5, 1],
        [2, 3, 7, 6],
        [0, 2, 6, 4],
        [1, 5, 7, 3],
    ];
    let mut tris = Vec::new();
    for (i, q) in quads.iter().enumerate() {
        tris.push([q[0], q[1], q[2]]);
        if i % 2 == 0 {
            tris.push([q[0], q[2], q[3]]);
        } else {
            tris.push([q[0], q[3], q[2]]);
        }
    }
    generator(pos, tris)
}

#[test]
fn closed_box_translated_along_a_line() {
    let g = box_mesh([0.0, 0.0, 0.0], [0.2, 0.1, 0.15]);
    let poses: Vec<DMat4> = (0..9)
        .map(|k| DMat4::from_translation(DVec3::new(0.1 * k as f64, 0.05 * k as f64, 0.0)))
        .collect();
    let input = build(&g, &poses, 48);
    let images = cpu::sweep(&input, &Silent).unwrap();
    let grid = input.grid;
    let d = input.params.delta / grid.h;
    let wide = d + 2.0 * input.rounding;
    // Analytic: along z, the ray at (x, y) meets each translated box's offset in
    // [zlo - s, zhi + s] with s = sqrt(d² - r²), r the distance from (x, y) to the box's xy
    // rectangle; the images hold the union over poses.
    let img = &images.images[2];
    let mut hits = 0;
    for rb in 0..img.height {
        for col in 0..img.width {
            let (u, v) = (col as f64 + 0.5, rb as f64 + 0.5);
            let (mut e0, mut e1, mut w0, mut w1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
            for m in &poses {
                let lo = grid.to_grid(m.transform_point3(DVec3::ZERO));
                let hi = grid.to_grid(m.transform_point3(DVec3::new(0.2, 0.1, 0.15)));
                let du = (lo.x - u).max(u - hi.x).max(0.0);
                let dv = (lo.y - v).max(v - hi.y).max(0.0);
                let r2 = du * du + dv * dv;
                if r2 <= d * d {
                    let s = (d * d - r2).sqrt();
                    e0 = e0.min(lo.z - s);
                    e1 = e1.max(hi.z + s);
                }
                if r2 <= wide * wide {
                    let s = (wide * wide - r2).sqrt();
                    w0 = w0.min(lo.z - s);
                    w1 = w1.max(hi.z + s);
                }
            }
            let i = img.index(col, rb);
            if e0 <= e1 {
                assert_depth(img.min[i] as f64, e0, w0, "translated box entry");
                assert_depth(img.max[i] as f64, e1, w1, "translated box exit");
                hits += 1;
            } else if w0 > w1 {
                assert!(img.is_empty_at(i));
            }
        }
    }
    assert!(hits > 200, "only {hits} pixels checked");
    check_against_oracle(&input, &images, &posed_grid_triangles(&g, &poses, &input));
}

#[test]
fn rotation_about_an_axis_matches_the_oracle() {
    let mut rng = Rng::with_seed(7);
    let g = tetrahedron(&mut rng, 0.15, [0.6, 0.0, 0.1]);
    let poses: Vec<DMat4> = (0..24)
        .map(|k| DMat4::from_rotation_y(k as f64 * std::f64::consts::TAU / 24.0))
        .collect();
    let input = build(&g, &poses, 40);
    let images = cpu::sweep(&input, &Silent).unwrap();
    check_against_oracle(&input, &images, &posed_grid_triangles(&g, &poses, &input));
}

/// Random generator (a few triangles, some degenerate) and random affine trajectory.
fn random_case(seed: u64) -> (Generator, Vec<DMat4>) {
    let mut rng = Rng::with_seed(seed * 0x9E37_79B9 + 1);
    let mut positions = Vec::new();
    let mut triangles = Vec::new();
    for k in 0..(2 + rng.u64(..5)) as u32 {
        let base = [
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
        ];
        let s = [0.01, 0.2, 0.8][rng.u64(..3) as usize];
        for _ in 0..3 {
            positions.push([
                (base[0] + rng.range(-s, s)) as f32,
                (base[1] + rng.range(-s, s)) as f32,
                (base[2] + rng.range(-s, s)) as f32,
            ]);
        }
        let t = [3 * k, 3 * k + 1, 3 * k + 2];
        triangles.push(match rng.u64(..6) {
            0 => [t[0], t[0], t[0]],
            1 => [t[0], t[1], t[1]],
            _ => t,
        });
    }
    let poses = (0..(1 + rng.u64(..6)))
        .map(|_| {
            let axis = DVec3::new(
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
                rng.range(0.1, 1.0),
            )
            .normalize();
            let rot = DMat4::from_axis_angle(axis, rng.range(-3.0, 3.0));
            let scale = DMat4::from_scale(DVec3::new(
                rng.range(0.5, 1.5),
                rng.range(0.5, 1.5),
                rng.range(0.5, 1.5),
            ));
            let t = DMat4::from_translation(DVec3::new(
                rng.range(-2.0, 2.0),
                rng.range(-2.0, 2.0),
                rng.range(-2.0, 2.0),
            ));
            t * rot * scale
        })
        .collect();
    (generator(positions, triangles), poses)
}

#[test]
fn random_sweeps_match_the_oracle() {
    for seed in 0..6 {
        let (g, poses) = random_case(seed);
        let input = build(&g, &poses, 24 + 4 * seed as u32);
        let images = cpu::sweep(&input, &Silent).unwrap();
        check_against_oracle(&input, &images, &posed_grid_triangles(&g, &poses, &input));
    }
}

#[test]
fn sampled_points_of_posed_triangles_are_inside_their_pixels() {
    let mut checked = 0;
    for seed in 100..140 {
        let (g, poses) = random_case(seed);
        let input = build(&g, &poses, 32 + seed as u32 % 64);
        let images = cpu::sweep(&input, &Silent).unwrap();
        let mut rng = Rng::with_seed(seed);
        checked += check_samples(
            &input,
            &images,
            &posed_grid_triangles(&g, &poses, &input),
            &mut rng,
        );
    }
    assert!(checked > 10_000);
}

#[test]
fn shader_validates_without_an_adapter() {
    let module =
        naga::front::wgsl::parse_str(sweptvol::sweep::gpu::SHADER_SOURCE).unwrap_or_else(|e| {
            panic!(
                "sweep.wgsl: {}",
                e.emit_to_string(sweptvol::sweep::gpu::SHADER_SOURCE)
            )
        });
    naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::all(),
    )
    .validate(&module)
    .unwrap_or_else(|e| {
        panic!(
            "sweep.wgsl: {}",
            e.emit_to_string(sweptvol::sweep::gpu::SHADER_SOURCE)
        )
    });
}

/// A GPU adapter for the tests, or a loud skip. With SWEPTVOL_REQUIRE_GPU=1 (CI, which installs
/// lavapipe) a missing adapter fails the test instead.
fn test_gpu() -> Option<Gpu> {
    match Gpu::acquire(true).expect("GPU device") {
        Some(g) => {
            eprintln!("GPU tests run on {}", g.describe());
            Some(g)
        }
        None if std::env::var("SWEPTVOL_REQUIRE_GPU").as_deref() == Ok("1") => {
            panic!("SWEPTVOL_REQUIRE_GPU=1 but no GPU adapter found (install mesa-vulkan-drivers libvulkan1)")
        }
        None => {
            eprintln!("\n*** SKIPPED: no GPU adapter (Vulkan/Metal/DX12) found; the GPU path was NOT tested. Install lavapipe (mesa-vulkan-drivers libvulkan1). ***\n");
            None
        }
    }
}

/// GPU and CPU agree: both empty, or both hit with every depth within the rounding term ρ of
/// each other (each is within ρ of exact); a pixel hit by one only must be a grazing hit.
fn assert_same(gpu: &DepthImages, cpu: &DepthImages, rho: f64, radius: f64) -> usize {
    let mut hits = 0;
    for (g, c) in gpu.images.iter().zip(&cpu.images) {
        for i in 0..g.min.len() {
            match (g.is_empty_at(i), c.is_empty_at(i)) {
                (true, true) => {}
                (false, false) => {
                    hits += 1;
                    let d0 = (g.min[i] - c.min[i]).abs() as f64;
                    let d1 = (g.max[i] - c.max[i]).abs() as f64;
                    assert!(
                        d0 <= rho && d1 <= rho,
                        "axis {} pixel {i}: gpu [{}, {}] cpu [{}, {}]",
                        g.axis,
                        g.min[i],
                        g.max[i],
                        c.min[i],
                        c.max[i]
                    );
                }
                (ge, _) => {
                    let (lo, hi) = if ge {
                        (c.min[i], c.max[i])
                    } else {
                        (g.min[i], g.max[i])
                    };
                    let graze = 2.0 * (2.0 * radius * rho).sqrt();
                    assert!(
                        ((hi - lo) as f64) <= graze,
                        "axis {} pixel {i}: hit [{lo}, {hi}] by one backend only",
                        g.axis
                    );
                }
            }
        }
    }
    hits
}

#[test]
fn gpu_matches_cpu_twin_on_random_sweeps() {
    let Some(gpu) = test_gpu() else { return };
    let mut hits = 0;
    for seed in 200..212 {
        let (g, poses) = random_case(seed);
        let input = build(&g, &poses, 40 + 8 * (seed as u32 % 5));
        let c = cpu::sweep(&input, &Silent).unwrap();
        let gi = gpu.sweep(&input, &Silent).unwrap();
        hits += assert_same(&gi, &c, input.rounding, input.radius as f64);
        let mut rng = Rng::with_seed(seed);
        check_samples(
            &input,
            &gi,
            &posed_grid_triangles(&g, &poses, &input),
            &mut rng,
        );
    }
    // A larger case: many poses of a closed mesh, several dispatches' worth of work.
    let mut rng = Rng::with_seed(99);
    let g = tetrahedron(&mut rng, 0.3, [0.2, 0.1, 0.0]);
    let poses: Vec<DMat4> = (0..500)
        .map(|k| {
            let a = k as f64 * 0.0125;
            DMat4::from_translation(DVec3::new(a.cos(), a.sin(), 0.3 * a))
                * DMat4::from_rotation_z(a)
        })
        .collect();
    let input = build(&g, &poses, 128);
    let c = cpu::sweep(&input, &Silent).unwrap();
    let gi = gpu.sweep(&input, &Silent).unwrap();
    hits += assert_same(&gi, &c, input.rounding, input.radius as f64);
    assert!(hits > 5000, "only {hits} pixels compared");
}

#[test]
fn node_rows_move_only_their_own_part_and_static_parts_stay() {
    let mut rng = Rng::with_seed(31);
    let mut g = tetrahedron(&mut rng, 0.2, [0.0, 0.0, 0.0]);
    let mut other = tetrahedron(&mut rng, 0.2, [0.0, 0.0, 0.0]).parts.remove(0);
    other.node_name = Some("fixed".into());
    other.node_index = 1;
    other.world = DMat4::from_translation(DVec3::new(1.5, 0.0, 0.0)); // W, applied once
    g.parts.push(other);
    let moves: Vec<DMat4> = (0..5)
        .map(|k| DMat4::from_translation(DVec3::new(0.0, 0.3 * k as f64, 0.0)))
        .collect();
    let traj = Trajectory {
        rows: Default::default(),
        poses: moves
            .iter()
            .enumerate()
            .map(|(i, m)| Pose {
                line: i as u64 + 2,
                frame: None,
                node: Some("part".into()),
                matrix: *m,
            })
            .collect(),
        has_node_column: true,
    };
    let input = posed::build(
        &g,
        Path::new("t.glb"),
        &traj,
        Path::new("t.csv"),
        Accuracy::Resolution(48),
        Overrides::default(),
        Motion::Discrete,
    )
    .unwrap();
    assert_eq!(input.parts.len(), 2);
    assert_eq!(
        (input.parts[0].pose_count, input.parts[0].is_static),
        (5, false)
    );
    assert_eq!(
        (input.parts[1].pose_count, input.parts[1].is_static),
        (1, true)
    );
    let images = cpu::sweep(&input, &Silent).unwrap();
    // Expected geometry: "part" at each of its poses, "fixed" once at W.
    let moved = Generator {
        nodes: Vec::new(),
        parts: vec![g.parts[0].clone()],
        warnings: vec![],
    };
    let fixed = Generator {
        nodes: Vec::new(),
        parts: vec![g.parts[1].clone()],
        warnings: vec![],
    };
    let mut tris = posed_grid_triangles(&moved, &moves, &input);
    tris.extend(posed_grid_triangles(&fixed, &[DMat4::IDENTITY], &input));
    check_against_oracle(&input, &images, &tris);
}

/// Review finding: a long box tilted by a tiny angle, so its long edges are almost parallel to
/// the z rays; the lateral cylinder entry was dropped and D⁺ came 233 voxels short.
#[test]
fn regression_slightly_tilted_pillar_on_both_backends() {
    let g = box_mesh([0.0, 0.0, 0.0], [0.1, 0.1, 10.0]);
    let axis = DVec3::new(0.935416766526622, 0.35354698825033026, 0.0);
    let pose =
        DMat4::from_translation(DVec3::new(0.008763278934523335, 0.0007434786152714668, 0.0))
            * DMat4::from_axis_angle(axis, 3.9213888566876635e-4);
    let input = build(&g, &[pose], 1000);
    let tris = posed_grid_triangles(&g, &[pose], &input);
    check_axes_against_oracle(&input, &cpu::sweep(&input, &Silent).unwrap(), &tris, &[2]);
    if let Some(gpu) = test_gpu() {
        check_axes_against_oracle(&input, &gpu.sweep(&input, &Silent).unwrap(), &tris, &[2]);
    }
}

/// The continuous motion's sub-poses on the GPU: made on demand and uploaded one dispatch at a
/// time, they render exactly as the CPU twin renders them (within ρ, as every GPU-vs-CPU test
/// here). Two parts: one turns back and forth through 150° about the world's z axis a unit
/// away while rising, so that no two of its poses coincide (over 65,535 poses: more than one
/// dispatch and upload, each of which must send its own poses), the other slides six units in
/// two screw steps, turning about its own axis.
#[test]
fn gpu_matches_cpu_twin_on_sub_poses() {
    let Some(gpu) = test_gpu() else { return };
    let mut rng = Rng::with_seed(16);
    let mut g = tetrahedron(&mut rng, 0.15, [1.0, 0.0, 0.0]);
    let mut slider = tetrahedron(&mut rng, 0.2, [0.0, 0.0, 0.0]).parts.remove(0);
    slider.node_name = Some("slider".into());
    slider.node_index = 1;
    g.parts.push(slider);
    let turns = 1500;
    let mut rows: Vec<(&str, DMat4)> = (0..turns)
        .map(|k| {
            let side = if k % 2 == 0 { -1.0 } else { 1.0 };
            let m = DMat4::from_translation(DVec3::new(0.0, 0.0, 0.002 * k as f64))
                * DMat4::from_rotation_z(side * 75f64.to_radians());
            ("part", m)
        })
        .collect();
    for k in 0..3 {
        let m = DMat4::from_translation(DVec3::new(-3.0 + 3.0 * k as f64, 2.5, 0.0))
            * DMat4::from_rotation_z(1.2 * k as f64);
        rows.push(("slider", m));
    }
    let traj = Trajectory {
        rows: Default::default(),
        poses: rows
            .iter()
            .enumerate()
            .map(|(i, (node, m))| Pose {
                line: i as u64 + 2,
                frame: None,
                node: Some(node.to_string()),
                matrix: *m,
            })
            .collect(),
        has_node_column: true,
    };
    let input = posed::build(
        &g,
        Path::new("t.glb"),
        &traj,
        Path::new("t.csv"),
        Accuracy::Resolution(64),
        Overrides::default(),
        Motion::Screw,
    )
    .unwrap();
    let spinner = &input.parts[0];
    assert!(
        input.motion.poses_rendered > 20 * rows.len() as u64,
        "{} poses for {} rows",
        input.motion.poses_rendered,
        rows.len()
    );
    assert!(
        spinner.pose_count > 65_535 && input.parts[1].pose_count > 100,
        "{} and {} poses: the case should take several dispatches",
        spinner.pose_count,
        input.parts[1].pose_count
    );
    let c = cpu::sweep(&input, &Silent).unwrap();
    let gi = gpu.sweep(&input, &Silent).unwrap();
    let hits = assert_same(&gi, &c, input.rounding, input.radius as f64);
    assert!(hits > 1000, "only {hits} pixels compared");
    // Half way between two rows the spinner stands at angle 0, far from every row: only
    // sub-poses cover the ray through its centroid there.
    let centroid = g.parts[0]
        .positions
        .iter()
        .fold(DVec3::ZERO, |s, p| s + p.as_dvec3())
        / 4.0;
    let p = input.grid.to_grid(centroid);
    let (lo, hi) = pixel(&gi, 2, p[COLUMN_AXIS[2]], p[ROW_AXIS[2]]);
    assert!(
        lo <= hi,
        "the ray through the turn's middle is empty on the GPU"
    );
}

/// The flood's reach on the GPU (set by `sweep_main`'s x axis) against its CPU twin
/// (`sweep::reach`): the same
/// voxels, except where a voxel centre lies within rounding of the offset's surface (the two ray
/// casts may differ by ρ there, as the images' depths may).
#[test]
fn gpu_reach_matches_cpu_twin() {
    let Some(gpu) = test_gpu() else { return };
    let (mut set, mut grazing) = (0u64, 0usize);
    for seed in 300..310 {
        let (g, poses) = random_case(seed);
        let input = build(&g, &poses, 40 + 8 * (seed as u32 % 5));
        let c = sweptvol::sweep::reach::reach(&input, &Silent).unwrap();
        let (gi, gr) = gpu.sweep_with_reach(&input, &Silent).unwrap();
        let gr = gr.expect("fits one buffer");
        // Setting the reach changes nothing in the images.
        assert_eq!(gi, gpu.sweep(&input, &Silent).unwrap(), "seed {seed}");
        assert_eq!(gr.dims, c.dims);
        set += c.count();
        let tris = posed_grid_triangles(&g, &poses, &input);
        let [nx, ny, nz] = c.dims;
        for k in 0..nz {
            for j in 0..ny {
                let r = c.row_index(j, k);
                if c.row(r) == gr.row(r) {
                    continue;
                }
                for i in 0..nx {
                    let (a, b) = (i as isize, j as isize);
                    if c.get(a, b, k as isize) != gr.get(a, b, k as isize) {
                        let p = [i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5];
                        let d = dist_to_set(p, &tris);
                        let slack = (4.0 * input.rounding).max(1e-4);
                        assert!(
                            (d - input.radius as f64).abs() <= slack,
                            "seed {seed}: voxel {i} {j} {k} at {d} from the part differs (radius {}, slack {slack})",
                            input.radius
                        );
                        grazing += 1;
                    }
                }
            }
        }
    }
    eprintln!("reach: {set} voxels set, {grazing} grazing differences");
    assert!(
        set > 10_000,
        "the cases set too few voxels ({set}) to test anything"
    );
}

/// The CPU sweep that sets the reach on the way gives the same images as the plain sweep and
/// the same bits as the separate reach pass, exactly.
#[test]
fn reach_set_by_the_sweep_is_the_reach() {
    for seed in 320..332 {
        let (g, poses) = random_case(seed);
        let input = build(&g, &poses, 36 + 8 * (seed as u32 % 4));
        let (images, bits) = cpu::sweep_with_reach(&input, &Silent).unwrap();
        assert_eq!(images, cpu::sweep(&input, &Silent).unwrap(), "seed {seed}");
        let separate = sweptvol::sweep::reach::reach(&input, &Silent).unwrap();
        assert_eq!(bits, separate, "seed {seed}");
        assert!(bits.count() > 0, "seed {seed}: nothing set");
    }
}
