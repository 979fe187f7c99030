//! Independent oracles for the tests: exact f64 geometry that shares no code with the sweep.
#![allow(dead_code)]

pub mod files;

use std::path::Path;

use glam::{DMat4, DVec3, Vec3};
use sweptvol::depth::{DepthImages, COLUMN_AXIS, ROW_AXIS};
use sweptvol::input::grid::{Accuracy, Overrides};
use sweptvol::input::model::{Generator, Part, Trajectory};
use sweptvol::input::motion::Motion;
use sweptvol::input::posed::{self, SweepInput};

pub type V3 = [f64; 3];

fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Distance from p to segment [a, b].
pub fn dist_segment(p: V3, a: V3, b: V3) -> f64 {
    let ab = sub(b, a);
    let l2 = dot(ab, ab);
    let s = if l2 > 0.0 {
        (dot(sub(p, a), ab) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let c = [a[0] + s * ab[0], a[1] + s * ab[1], a[2] + s * ab[2]];
    let d = sub(p, c);
    dot(d, d).sqrt()
}

/// Distance from p to the closed triangle t (any shape, degenerate included): the distance to
/// the plane where p projects inside, else to the nearest edge.
pub fn dist_triangle(p: V3, t: [V3; 3]) -> f64 {
    let n = cross(sub(t[1], t[0]), sub(t[2], t[0]));
    let nn = dot(n, n);
    let edges = (0..3)
        .map(|i| dist_segment(p, t[i], t[(i + 1) % 3]))
        .fold(f64::INFINITY, f64::min);
    if nn > 0.0 {
        let inside = (0..3).all(|i| {
            let e = sub(t[(i + 1) % 3], t[i]);
            dot(cross(e, sub(p, t[i])), n) >= 0.0
        });
        if inside {
            return (dot(sub(p, t[0]), n) / nn.sqrt()).abs().min(edges);
        }
    }
    edges
}

/// The interval of t where point (u, v, t) along axis `axis` (u, v on the other two axes in the
/// order given) is within `d` of triangle `tri`, by minimizing the convex distance along the line
/// and bisecting both sides. None when the line misses the offset.
pub fn line_interval(
    tri: [V3; 3],
    axis: usize,
    uv: [(usize, f64); 2],
    d: f64,
) -> Option<(f64, f64)> {
    let point = |t: f64| {
        let mut p = [0.0; 3];
        p[axis] = t;
        p[uv[0].0] = uv[0].1;
        p[uv[1].0] = uv[1].1;
        p
    };
    let f = |t: f64| dist_triangle(point(t), tri);
    let lo0 = tri.iter().map(|v| v[axis]).fold(f64::INFINITY, f64::min) - d - 1.0;
    let hi0 = tri
        .iter()
        .map(|v| v[axis])
        .fold(f64::NEG_INFINITY, f64::max)
        + d
        + 1.0;
    // Golden-section search for the minimum of a convex function.
    let (mut a, mut b) = (lo0, hi0);
    let g = (5f64.sqrt() - 1.0) / 2.0;
    for _ in 0..120 {
        let c = b - g * (b - a);
        let e = a + g * (b - a);
        if f(c) <= f(e) {
            b = e;
        } else {
            a = c;
        }
    }
    let tm = (a + b) / 2.0;
    if f(tm) > d {
        return None;
    }
    let bisect = |mut inside: f64, mut outside: f64| {
        for _ in 0..80 {
            let mid = (inside + outside) / 2.0;
            if f(mid) <= d {
                inside = mid;
            } else {
                outside = mid;
            }
        }
        inside
    };
    Some((bisect(tm, lo0), bisect(tm, hi0)))
}

/// The tests draw from fastrand's generator with a fixed seed, so failures reproduce from the
/// printed seed; [`Draw`] adds the one draw they need beyond its own.
pub use fastrand::Rng;

pub trait Draw {
    /// Uniform in [lo, hi).
    fn range(&mut self, lo: f64, hi: f64) -> f64;
}

impl Draw for Rng {
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.f64()
    }
}

/// Every posed triangle in grid units (f64, posed exactly from the f64 matrices).
pub fn posed_grid_triangles(g: &Generator, poses: &[DMat4], input: &SweepInput) -> Vec<[V3; 3]> {
    let mut out = Vec::new();
    for m in poses {
        for part in &g.parts {
            let full = *m * part.world;
            for t in &part.triangles {
                out.push(t.map(|i| {
                    let w = full.transform_point3(part.positions[i as usize].as_dvec3());
                    input.grid.to_grid(w).to_array()
                }));
            }
        }
    }
    out
}

/// The property: a point p of a posed triangle, seen by the pixel whose centre is
/// nearest in the image plane (in-plane distance r <= √2/2 voxel), lies on a ray that passes
/// within r of p, so the ray meets the ball B_δ(p) ⊂ O_δ(T) in p_a ± sqrt(δ² - r²).
/// Hence D⁻ <= p_a - sqrt(δ² - r²) and D⁺ >= p_a + sqrt(δ² - r²), with the unrounded δ.
pub fn check_samples(
    input: &SweepInput,
    images: &DepthImages,
    tris: &[[V3; 3]],
    rng: &mut Rng,
) -> usize {
    let d = input.params.delta / input.grid.h;
    let mut checked = 0;
    for t in tris {
        for k in 0..40 {
            let (mut b1, mut b2) = (rng.f64(), rng.f64());
            if b1 + b2 > 1.0 {
                (b1, b2) = (1.0 - b1, 1.0 - b2);
            }
            if k < 3 {
                (b1, b2) = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)][k];
            }
            let p: Vec<f64> = (0..3)
                .map(|c| t[0][c] + b1 * (t[1][c] - t[0][c]) + b2 * (t[2][c] - t[0][c]))
                .collect();
            for img in &images.images {
                let a = img.axis;
                let (cu, rv) = (COLUMN_AXIS[a], ROW_AXIS[a]);
                let (col, rb) = (p[cu].floor(), p[rv].floor());
                let r2 = (p[cu] - col - 0.5).powi(2) + (p[rv] - rb - 0.5).powi(2);
                let m = (d * d - r2).sqrt();
                let i = img.index(col as u32, rb as u32);
                assert!(
                    (img.min[i] as f64) <= p[a] - m && (img.max[i] as f64) >= p[a] + m,
                    "sample {p:?} axis {a}: [{}, {}] misses [{}, {}]",
                    img.min[i],
                    img.max[i],
                    p[a] - m,
                    p[a] + m
                );
                checked += 1;
            }
        }
    }
    checked
}

/// Generalized winding number of `mesh` (positions, triangles) at `p`: about 1 inside a closed
/// outward mesh, 0 outside, robust to small defects (Jacobson et al. 2013; solid angles by
/// Van Oosterom and Strackee).
pub fn winding_number(positions: &[V3], triangles: &[[u32; 3]], p: V3) -> f64 {
    let mut total = 0.0;
    for t in triangles {
        let [a, b, c] = t.map(|i| sub(positions[i as usize], p));
        let (la, lb, lc) = (dot(a, a).sqrt(), dot(b, b).sqrt(), dot(c, c).sqrt());
        let num = dot(a, cross(b, c));
        let den = la * lb * lc + dot(a, b) * lc + dot(a, c) * lb + dot(b, c) * la;
        total += 2.0 * num.atan2(den);
    }
    total / (4.0 * std::f64::consts::PI)
}

/// Distance from p to the nearest of `tris`.
pub fn dist_to_set(p: V3, tris: &[[V3; 3]]) -> f64 {
    tris.iter()
        .map(|t| dist_triangle(p, *t))
        .fold(f64::INFINITY, f64::min)
}

/// A one-part generator at the identity, named "part".
pub fn generator(positions: Vec<[f32; 3]>, triangles: Vec<[u32; 3]>) -> Generator {
    Generator {
        nodes: Vec::new(),
        parts: vec![Part {
            node_index: 0,
            node_name: Some("part".into()),
            world: DMat4::IDENTITY,
            positions: positions.into_iter().map(Vec3::from).collect(),
            triangles,
        }],
        warnings: vec![],
    }
}

/// A random closed tetrahedron within `size` of `centre`.
pub fn tetrahedron(rng: &mut Rng, size: f64, centre: [f64; 3]) -> Generator {
    let pos: Vec<[f32; 3]> = (0..4)
        .map(|_| std::array::from_fn(|c| (centre[c] + rng.range(-size, size)) as f32))
        .collect();
    generator(pos, vec![[0, 1, 2], [0, 3, 1], [1, 3, 2], [2, 3, 0]])
}

/// 2 to 6 random rigid poses: rotations about random axes, translations within 1.
pub fn random_rigid_poses(rng: &mut Rng) -> Vec<DMat4> {
    (0..(2 + rng.u64(..5)))
        .map(|_| {
            let axis = DVec3::new(
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
                rng.range(0.1, 1.0),
            )
            .normalize();
            let t = DVec3::new(
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
            );
            DMat4::from_translation(t) * DMat4::from_axis_angle(axis, rng.range(-3.0, 3.0))
        })
        .collect()
}

/// The sweep input for `g` at the listed `poses` only (discrete motion), at resolution `n`.
pub fn build(g: &Generator, poses: &[DMat4], n: u32) -> SweepInput {
    build_with(g, poses, n, Motion::Discrete)
}

/// The sweep input for `g` moved whole along `poses` by `motion`, at resolution `n`.
pub fn build_with(g: &Generator, poses: &[DMat4], n: u32, motion: Motion) -> SweepInput {
    posed::build(
        g,
        Path::new("test.glb"),
        &Trajectory::whole_scene(poses),
        Path::new("test.csv"),
        Accuracy::Resolution(n),
        Overrides::default(),
        motion,
    )
    .expect("job builds")
}

/// The Python that scripts/test-all.sh sets up (`SWEPTVOL_TEST_PYTHON`, else `python3`) if it
/// can import `modules` (comma-separated), else a loud skip; with SWEPTVOL_REQUIRE_PYTHON=1 its
/// absence is a failure. `what` names the check that would not run.
pub fn test_python(modules: &str, what: &str) -> Option<String> {
    let python = std::env::var("SWEPTVOL_TEST_PYTHON").unwrap_or_else(|_| "python3".into());
    let ok = std::process::Command::new(&python)
        .args(["-c", &format!("import {modules}")])
        .status()
        .map(|s| s.success())
        .unwrap_or(false);
    if ok {
        return Some(python);
    }
    if std::env::var("SWEPTVOL_REQUIRE_PYTHON").as_deref() == Ok("1") {
        panic!("SWEPTVOL_REQUIRE_PYTHON=1 but {python} cannot import {modules} (scripts/test-all.sh sets them up)");
    }
    eprintln!("\n*** SKIPPED: no Python with {modules} ({python}); {what} was NOT run. Run scripts/test-all.sh. ***\n");
    None
}

/// The 12 outward-wound triangles of a box whose corner k is (x, y, z) = (lo or hi by bits 0, 1,
/// 2 of k).
pub const BOX_TRIANGLES: [[u32; 3]; 12] = [
    [0, 2, 1],
    [1, 2, 3],
    [4, 5, 6],
    [5, 7, 6],
    [0, 1, 4],
    [1, 5, 4],
    [2, 6, 3],
    [3, 6, 7],
    [0, 4, 2],
    [2, 4, 6],
    [1, 3, 5],
    [3, 7, 5],
];

/// A closed box [lo, hi]: positions (corner k by the bits of k) and [`BOX_TRIANGLES`].
pub fn box_mesh(lo: [f32; 3], hi: [f32; 3]) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let pos = (0..8)
        .map(|k| std::array::from_fn(|a| if k >> a & 1 == 1 { hi[a] } else { lo[a] }))
        .collect();
    (pos, BOX_TRIANGLES.to_vec())
}
