//! A part's outline: a subset of its vertices that holds every vertex of its convex hull, so
//! the largest value over the part of any convex function of the point (a coordinate under an
//! affine pose, the path length of `motion::intervals`) is the largest over the outline. The
//! grid fit and the motion bounds look at every vertex under every row; on a job of tens of
//! thousands of rows that is most of a shard's set-up, and the outline cuts it several-fold.
//!
//! The filter (Akl and Toussaint's): the vertices extreme along a fixed set of directions span
//! a polytope Q inside the hull; a vertex strictly inside Q by a margin is inside the hull and
//! is dropped (a convex f has f(p) ≤ max f over Q's vertices, which are kept). Q's facet planes
//! are found by brute force: every plane through three extreme points with all of them on one
//! side within `tol`. Every true facet passes (its points lie on one side exactly, and the f64
//! evaluation errs by far less than `tol`); a plane that passes but leans by up to `tol` only
//! shrinks the region of dropped vertices, since the margin is twice `tol`. Coplanar extreme
//! points give both sides of their plane, and nothing is dropped.

use glam::{DVec3, Vec3};

/// Parts with fewer vertices are kept whole: the filter would cost more than it saves.
const MIN_VERTICES: usize = 2048;
/// Directions besides the 26 of the axes and diagonals, spread over the sphere.
const SPIRAL_DIRECTIONS: usize = 74;

/// The 26 axis and diagonal directions and a Fibonacci spiral of [`SPIRAL_DIRECTIONS`].
fn directions() -> Vec<DVec3> {
    let mut out = Vec::with_capacity(26 + SPIRAL_DIRECTIONS);
    for x in -1..=1 {
        for y in -1..=1 {
            for z in -1..=1 {
                if (x, y, z) != (0, 0, 0) {
                    out.push(DVec3::new(x as f64, y as f64, z as f64));
                }
            }
        }
    }
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    for i in 0..SPIRAL_DIRECTIONS {
        let z = 1.0 - 2.0 * (i as f64 + 0.5) / SPIRAL_DIRECTIONS as f64;
        let r = (1.0 - z * z).sqrt();
        let a = golden * i as f64;
        out.push(DVec3::new(r * a.cos(), r * a.sin(), z));
    }
    out
}

/// The vertices of `points` that may lie on its convex hull, in their original order (all of
/// them for a small part).
pub fn outline(points: &[Vec3]) -> Vec<Vec3> {
    if points.len() < MIN_VERTICES {
        return points.to_vec();
    }
    let p: Vec<DVec3> = points.iter().map(|v| v.as_dvec3()).collect();
    let mut extreme: Vec<usize> = directions()
        .iter()
        .map(|d| {
            (0..p.len())
                .max_by(|&a, &b| d.dot(p[a]).total_cmp(&d.dot(p[b])))
                .expect("non-empty")
        })
        .collect();
    extreme.sort_unstable();
    extreme.dedup();
    let e: Vec<DVec3> = extreme.iter().map(|&i| p[i]).collect();
    let scale = p.iter().fold(0.0f64, |m, q| m.max(q.abs().max_element()));
    if !scale.is_finite() || scale == 0.0 {
        return points.to_vec();
    }
    let tol = 1e-9 * scale;
    // Facet planes (unit normal n, offset c: n·x ≤ c on Q).
    let mut planes: Vec<(DVec3, f64)> = Vec::new();
    for a in 0..e.len() {
        for b in a + 1..e.len() {
            for c in b + 1..e.len() {
                let n = (e[b] - e[a]).cross(e[c] - e[a]);
                let len = n.length();
                if len.is_nan() || len <= 1e-12 * scale * scale {
                    continue;
                }
                let n = n / len;
                let off = n.dot(e[a]);
                let (mut below, mut above) = (true, true);
                for q in &e {
                    let s = n.dot(*q) - off;
                    below &= s <= tol;
                    above &= s >= -tol;
                }
                if below {
                    planes.push((n, off));
                }
                if above {
                    planes.push((-n, -off));
                }
            }
        }
    }
    if planes.is_empty() {
        return points.to_vec();
    }
    let margin = 2.0 * tol;
    points
        .iter()
        .zip(&p)
        .filter(|(_, q)| planes.iter().any(|(n, off)| n.dot(**q) - off >= -margin))
        .map(|(v, _)| *v)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On random clouds (a ball, a box, a flat disc, a thin needle), the outline gives the same
    /// maximum as all points along many random directions and of a convex non-linear function,
    /// and it drops points where it can.
    #[test]
    fn the_outline_keeps_every_maximum() {
        let mut rng = fastrand::Rng::with_seed(0x0171);
        let mut dropped = 0usize;
        for case in 0..40 {
            let n = 2048 + rng.usize(..4000);
            let shape = case % 4;
            let points: Vec<Vec3> = (0..n)
                .map(|_| {
                    let v = Vec3::new(rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5);
                    let v = match shape {
                        0 => v.normalize_or_zero() * rng.f32().cbrt(),
                        1 => v,
                        2 => Vec3::new(v.x, v.y, 0.0),
                        _ => Vec3::new(v.x * 1e-3, v.y * 1e-3, v.z),
                    };
                    v * 100.0 + Vec3::new(1000.0, -5.0, 3.0)
                })
                .collect();
            let kept = outline(&points);
            assert!(kept.iter().all(|k| points.contains(k)));
            dropped += points.len() - kept.len();
            let max = |set: &[Vec3], f: &dyn Fn(DVec3) -> f64| {
                set.iter()
                    .map(|v| f(v.as_dvec3()))
                    .fold(f64::NEG_INFINITY, f64::max)
            };
            for _ in 0..200 {
                let d = DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5);
                let w = DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5);
                let linear = |q: DVec3| d.dot(q);
                let path = |q: DVec3| (w.cross(q) + d).length() + (q * d).length();
                for f in [&linear as &dyn Fn(DVec3) -> f64, &path] {
                    let (a, b) = (max(&kept, f), max(&points, f));
                    // Equal but for the rounding of f where a dropped point ties the maximum.
                    assert!(
                        a <= b && a >= b - 1e-12 * b.abs().max(1.0),
                        "case {case}: {a} vs {b}"
                    );
                }
            }
        }
        assert!(dropped > 0, "the filter never dropped a point");
    }
}
