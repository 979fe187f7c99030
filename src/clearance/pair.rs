//! The nearest pair of points between two triangle sets, f64: exact triangle-triangle distance
//! and a traversal of two BVHs, one of them under an affine pose.

use glam::{DMat4, DVec3};

use crate::verify::bvh::{Bvh, Node};
use crate::verify::geom;

/// The closest points of two triangle sets and the triangles they lie on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Nearest {
    /// |a_point - b_point|; 0 when the triangles meet.
    pub distance: f64,
    pub a_tri: u32,
    pub b_tri: u32,
    pub a_point: DVec3,
    pub b_point: DVec3,
}

/// The point of the closed triangle [a, b, c] nearest to `p` (Ericson, Real-Time Collision
/// Detection 5.1.5, by Voronoi regions; a degenerate triangle falls back to its edges).
pub fn closest_on_triangle(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> DVec3 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    if ab.cross(ac).length_squared() == 0.0 {
        return [(a, b), (b, c), (c, a)]
            .map(|(s, t)| closest_on_segment(p, s, t))
            .into_iter()
            .min_by(|x, y| (*x - p).length().total_cmp(&(*y - p).length()))
            .expect("three edges");
    }
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

/// The point of segment [a, b] nearest to `p`.
pub fn closest_on_segment(p: DVec3, a: DVec3, b: DVec3) -> DVec3 {
    let ab = b - a;
    let l2 = ab.length_squared();
    if l2 == 0.0 {
        return a;
    }
    a + ab * ((p - a).dot(ab) / l2).clamp(0.0, 1.0)
}

/// The closest points of segments [p1, q1] and [p2, q2] (Ericson 5.1.9).
pub fn closest_segments(p1: DVec3, q1: DVec3, p2: DVec3, q2: DVec3) -> (DVec3, DVec3) {
    let (d1, d2, r) = (q1 - p1, q2 - p2, p1 - p2);
    let (a, e, f) = (d1.length_squared(), d2.length_squared(), d2.dot(r));
    if a == 0.0 && e == 0.0 {
        return (p1, p2);
    }
    if a == 0.0 {
        return (p1, p2 + d2 * (f / e).clamp(0.0, 1.0));
    }
    let c = d1.dot(r);
    if e == 0.0 {
        return (p1 + d1 * (-c / a).clamp(0.0, 1.0), p2);
    }
    let b = d1.dot(d2);
    let denom = a * e - b * b;
    let mut s = if denom > 0.0 {
        ((b * f - c * e) / denom).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let mut t = (b * s + f) / e;
    if t < 0.0 {
        t = 0.0;
        s = (-c / a).clamp(0.0, 1.0);
    } else if t > 1.0 {
        t = 1.0;
        s = ((b - c) / a).clamp(0.0, 1.0);
    }
    (p1 + d1 * s, p2 + d2 * t)
}

/// Where segment [p, q] meets the plane of [a, b, c] (the segment crosses it).
fn plane_point(p: DVec3, q: DVec3, a: DVec3, b: DVec3, c: DVec3) -> DVec3 {
    let n = (b - a).cross(c - a);
    let (dp, dq) = (n.dot(p - a), n.dot(q - a));
    p + (q - p) * (dp / (dp - dq))
}

/// The closest points of triangles `t` and `u` (closed, any shape). Two triangles that do not
/// cross have their closest pair at a vertex of one and the other triangle, or on two edges:
/// the minimum over those 15 features is exact. Crossing triangles (an edge of one through the
/// interior of the other) are at distance 0 at the crossing point.
pub fn triangle_pair(t: &[DVec3; 3], u: &[DVec3; 3]) -> (f64, DVec3, DVec3) {
    for (x, y) in [(t, u), (u, t)] {
        for i in 0..3 {
            let (p, q) = (x[i], x[(i + 1) % 3]);
            if geom::segment_crosses_triangle(p, q, y[0], y[1], y[2]) {
                let m = plane_point(p, q, y[0], y[1], y[2]);
                return (0.0, m, m);
            }
        }
    }
    let mut best = (f64::INFINITY, DVec3::ZERO, DVec3::ZERO);
    let mut take = |a: DVec3, b: DVec3| {
        let d = (a - b).length();
        if d < best.0 {
            best = (d, a, b);
        }
    };
    for &v in t {
        take(v, closest_on_triangle(v, u[0], u[1], u[2]));
    }
    for &v in u {
        take(closest_on_triangle(v, t[0], t[1], t[2]), v);
    }
    for i in 0..3 {
        for j in 0..3 {
            let (a, b) = closest_segments(t[i], t[(i + 1) % 3], u[j], u[(j + 1) % 3]);
            take(a, b);
        }
    }
    best
}

/// The world box of node `n` under `pose` (an affine map): the image of its centre plus the
/// absolute linear part times its half extents, which holds the image of every point of it.
fn posed_box(n: &Node, pose: Option<&DMat4>) -> (DVec3, DVec3) {
    let Some(m) = pose else {
        return (n.lo, n.hi);
    };
    let (c, e) = ((n.lo + n.hi) / 2.0, (n.hi - n.lo) / 2.0);
    let wc = m.transform_point3(c);
    let abs = [m.x_axis, m.y_axis, m.z_axis].map(|col| col.truncate().abs());
    let we = abs[0] * e.x + abs[1] * e.y + abs[2] * e.z;
    // Rounding of the transform: a relative 1e-12 of the box's reach.
    let pad = DVec3::splat(1e-12 * (wc.abs().max_element() + we.max_element()));
    (wc - we - pad, wc + we + pad)
}

fn box_gap(a: (DVec3, DVec3), b: (DVec3, DVec3)) -> f64 {
    (a.0 - b.1).max(b.0 - a.1).max(DVec3::ZERO).length()
}

/// The nearest pair between `a`'s triangles under `pose` (None: as they are) and `b`'s, when
/// nearer than `cutoff` (None otherwise). Stops at the first pair of meeting triangles.
pub fn nearest(a: &Bvh, pose: Option<&DMat4>, b: &Bvh, cutoff: f64) -> Option<Nearest> {
    let place = |t: u32| -> [DVec3; 3] {
        let tri = a.tris[t as usize];
        match pose {
            Some(m) => tri.map(|v| m.transform_point3(v)),
            None => tri,
        }
    };
    let mut best: Option<Nearest> = None;
    let mut limit = cutoff;
    let root = (posed_box(&a.nodes[0], pose), (b.nodes[0].lo, b.nodes[0].hi));
    let mut stack = vec![(0u32, 0u32, box_gap(root.0, root.1))];
    while let Some((i, j, gap)) = stack.pop() {
        if gap >= limit {
            continue;
        }
        let (na, nb) = (&a.nodes[i as usize], &b.nodes[j as usize]);
        if na.count > 0 && nb.count > 0 {
            for &s in a.leaf_tris(na) {
                let ts = place(s);
                for &t in b.leaf_tris(nb) {
                    let (d, p, q) = triangle_pair(&ts, &b.tris[t as usize]);
                    if d < limit {
                        limit = d;
                        best = Some(Nearest {
                            distance: d,
                            a_tri: s,
                            b_tri: t,
                            a_point: p,
                            b_point: q,
                        });
                        if d == 0.0 {
                            return best;
                        }
                    }
                }
            }
            continue;
        }
        // Open the larger node (or the one that is not a leaf).
        let size = |n: &Node| (n.hi - n.lo).length();
        let open_a = nb.count > 0 || (na.count == 0 && size(na) >= size(nb));
        let pairs: [(u32, u32); 2] = if open_a {
            [(na.left, j), (na.right, j)]
        } else {
            [(i, nb.left), (i, nb.right)]
        };
        let gaps = pairs.map(|(x, y)| {
            let bx = posed_box(&a.nodes[x as usize], pose);
            let n = &b.nodes[y as usize];
            box_gap(bx, (n.lo, n.hi))
        });
        // The nearer pair last, so it is taken first.
        let order = if gaps[0] <= gaps[1] { [1, 0] } else { [0, 1] };
        for k in order {
            if gaps[k] < limit {
                stack.push((pairs[k].0, pairs[k].1, gaps[k]));
            }
        }
    }
    best
}

/// Whether `p` lies inside the closed surface of `bvh` (a non-zero winding number along a ray;
/// rays that graze an edge are cast again in another direction). `to_local` maps `p` into the
/// BVH's frame.
pub fn inside(bvh: &Bvh, p: DVec3, to_local: Option<&DMat4>) -> bool {
    let p = to_local.map_or(p, |m| m.transform_point3(p));
    const DIRECTIONS: [[f64; 3]; 6] = [
        [0.5773, 0.5774, 0.5775],
        [-0.3122, 0.8127, 0.4919],
        [0.7072, -0.0913, -0.7011],
        [-0.6133, -0.5407, 0.5757],
        [0.1234, -0.9811, 0.1490],
        [-0.8501, 0.2213, -0.4779],
    ];
    for d in DIRECTIONS {
        if let Some(w) = bvh.ray_crossings(p, DVec3::from(d)) {
            return w != 0;
        }
    }
    // Every ray grazed an edge: p is on (or within rounding of) the surface, so it touches it.
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rng_tri(rng: &mut fastrand::Rng, centre: DVec3, size: f64) -> [DVec3; 3] {
        let mut v = || DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5) * size;
        [centre + v(), centre + v(), centre + v()]
    }

    /// Sampling both triangles on a barycentric grid of k steps gives distances no smaller
    /// than the exact one, and no larger than it plus the cells' reach.
    #[test]
    fn triangle_pairs_match_dense_sampling() {
        let mut rng = fastrand::Rng::with_seed(11);
        let k = 40;
        let samples = |t: &[DVec3; 3]| -> Vec<DVec3> {
            let mut out = Vec::new();
            for i in 0..=k {
                for j in 0..=k - i {
                    let (s, r) = (i as f64 / k as f64, j as f64 / k as f64);
                    out.push(t[0] + (t[1] - t[0]) * s + (t[2] - t[0]) * r);
                }
            }
            out
        };
        let reach = |t: &[DVec3; 3]| {
            let e = [
                (t[1] - t[0]).length(),
                (t[2] - t[1]).length(),
                (t[0] - t[2]).length(),
            ];
            e.iter().fold(0.0f64, |m, x| m.max(*x)) / k as f64
        };
        let mut zero = 0;
        for case in 0..300 {
            let t = rng_tri(&mut rng, DVec3::ZERO, 1.0);
            let off = if case % 3 == 0 { 0.2 } else { 1.2 };
            let u = rng_tri(&mut rng, DVec3::new(off, 0.1, -0.1), 1.0);
            let (d, p, q) = triangle_pair(&t, &u);
            assert!(((p - q).length() - d).abs() < 1e-12);
            assert!(geom::dist_triangle(p, t[0], t[1], t[2]) < 1e-9);
            assert!(geom::dist_triangle(q, u[0], u[1], u[2]) < 1e-9);
            let (st, su) = (samples(&t), samples(&u));
            let mut sampled = f64::INFINITY;
            for a in &st {
                for b in &su {
                    sampled = sampled.min((*a - *b).length());
                }
            }
            assert!(d <= sampled + 1e-12, "case {case}: {d} > sampled {sampled}");
            assert!(
                sampled <= d + reach(&t) + reach(&u) + 1e-12,
                "case {case}: {d} far below sampled {sampled}"
            );
            zero += (d == 0.0) as u32;
        }
        assert!(zero > 20, "only {zero} crossing pairs tried");
    }

    /// The BVH pair search finds the brute-force minimum, posed or not.
    #[test]
    fn nearest_pairs_match_brute_force() {
        let mut rng = fastrand::Rng::with_seed(3);
        for case in 0..40 {
            let a: Vec<[DVec3; 3]> = (0..60)
                .map(|_| {
                    let c = DVec3::new(rng.f64(), rng.f64(), rng.f64()) * 3.0;
                    rng_tri(&mut rng, c, 0.4)
                })
                .collect();
            let b: Vec<[DVec3; 3]> = (0..80)
                .map(|_| {
                    let c = DVec3::new(rng.f64() + 3.5, rng.f64(), rng.f64()) * 3.0;
                    rng_tri(&mut rng, c, 0.4)
                })
                .collect();
            let pose = DMat4::from_rotation_translation(
                glam::DQuat::from_axis_angle(DVec3::new(1.0, 2.0, 0.5).normalize(), case as f64),
                DVec3::new(case as f64 * 0.2, 0.0, 0.3),
            ) * DMat4::from_scale(DVec3::new(1.0, 1.3, 0.8));
            let (ba, bb) = (Bvh::build(a.clone(), 2), Bvh::build(b.clone(), 3));
            let brute = a
                .iter()
                .flat_map(|s| {
                    let s = s.map(|v| pose.transform_point3(v));
                    b.iter().map(move |t| triangle_pair(&s, t).0)
                })
                .fold(f64::INFINITY, f64::min);
            let found = nearest(&ba, Some(&pose), &bb, f64::INFINITY).unwrap();
            assert_eq!(found.distance, brute, "case {case}");
            assert!(nearest(&ba, Some(&pose), &bb, brute).is_none());
        }
    }
}
