//! Exact f64 point, segment and triangle geometry for the verifier. Shares nothing with the
//! sweep: every function here is written from the textbook definitions.

use glam::DVec3;

/// Distance from `p` to the segment [a, b] (a point when a = b).
pub fn dist_segment(p: DVec3, a: DVec3, b: DVec3) -> f64 {
    let ab = b - a;
    let l2 = ab.length_squared();
    let s = if l2 > 0.0 {
        ((p - a).dot(ab) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p - (a + s * ab)).length()
}

/// Distance from `p` to the closed triangle [a, b, c], any shape (degenerate included): the
/// plane distance where p projects inside, else the nearest edge.
pub fn dist_triangle(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> f64 {
    let n = (b - a).cross(c - a);
    let nn = n.length_squared();
    if nn > 0.0 {
        let inside = (b - a).cross(p - a).dot(n) >= 0.0
            && (c - b).cross(p - b).dot(n) >= 0.0
            && (a - c).cross(p - c).dot(n) >= 0.0;
        if inside {
            return (p - a).dot(n).abs() / nn.sqrt();
        }
    }
    dist_segment(p, a, b)
        .min(dist_segment(p, b, c))
        .min(dist_segment(p, c, a))
}

/// Distance from `p` to the box [lo, hi] (0 inside).
pub fn dist_box(p: DVec3, lo: DVec3, hi: DVec3) -> f64 {
    (lo - p).max(p - hi).max(DVec3::ZERO).length()
}

/// Signed solid angle of triangle [a, b, c] seen from `p`, divided by 4π (Van Oosterom and
/// Strackee): the triangle's share of the generalized winding number at p.
pub fn winding_share(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> f64 {
    let (a, b, c) = (a - p, b - p, c - p);
    let (la, lb, lc) = (a.length(), b.length(), c.length());
    let num = a.dot(b.cross(c));
    let den = la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la;
    num.atan2(den) / (2.0 * std::f64::consts::PI)
}

/// Centroid of a triangle and its covering radius: every point of the triangle is within the
/// radius of the centroid (the farthest point of a convex hull from any point is a vertex).
pub fn ball(t: &[DVec3; 3]) -> (DVec3, f64) {
    let c = (t[0] + t[1] + t[2]) / 3.0;
    let r = t.iter().map(|v| (*v - c).length()).fold(0.0, f64::max);
    (c, r)
}

/// The four midpoint sub-triangles (same orientation). Covering radii halve.
pub fn split4(t: &[DVec3; 3]) -> [[DVec3; 3]; 4] {
    let [a, b, c] = *t;
    let (ab, bc, ca) = ((a + b) / 2.0, (b + c) / 2.0, (c + a) / 2.0);
    [[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]
}

/// What a ray from an origin meets in one triangle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Crossing {
    Miss,
    /// Crosses the interior: +1 leaving (along the normal (b-a)×(c-a)), -1 entering.
    Cross(i32),
    /// Too close to an edge, a vertex or the origin to decide in f64: try another ray.
    Unsure,
}

/// Relative tolerance of the crossing decisions (f64 rounding is about 1e-16).
const RAY_TOL: f64 = 1e-9;

/// Signed crossing of the ray o + t·d (t > 0) with triangle [a, b, c] (Möller and Trumbore,
/// with an explicit band of doubt around edges and the origin).
pub fn ray_crossing(o: DVec3, d: DVec3, a: DVec3, b: DVec3, c: DVec3) -> Crossing {
    let (e1, e2) = (b - a, c - a);
    let pvec = d.cross(e2);
    let det = e1.dot(pvec);
    let scale = e1.length() * e2.length() * d.length();
    if det.abs() <= RAY_TOL * scale {
        // The ray is (nearly) parallel to the plane: it crosses nothing, unless it runs
        // through the triangle, in which case a neighbour's edge test reports doubt. A
        // degenerate triangle has det = 0 for every ray and never contributes.
        if scale == 0.0 || !near_plane_inside(o, d, a, b, c) {
            return Crossing::Miss;
        }
        return Crossing::Unsure;
    }
    let inv = 1.0 / det;
    let tvec = o - a;
    let u = tvec.dot(pvec) * inv;
    let qvec = tvec.cross(e1);
    let v = d.dot(qvec) * inv;
    if u < -RAY_TOL || v < -RAY_TOL || u + v > 1.0 + RAY_TOL {
        return Crossing::Miss;
    }
    let t = e2.dot(qvec) * inv; // in units of |d|
    let size = e1.length().max(e2.length()) / d.length();
    if t < -RAY_TOL * size {
        return Crossing::Miss;
    }
    if u <= RAY_TOL || v <= RAY_TOL || u + v >= 1.0 - RAY_TOL || t <= RAY_TOL * size {
        return Crossing::Unsure;
    }
    // det = -d·n: det < 0 means the ray leaves along the normal.
    Crossing::Cross(if det < 0.0 { 1 } else { -1 })
}

/// Whether the ray passes within a small band of the triangle's box (for near-parallel rays).
fn near_plane_inside(o: DVec3, d: DVec3, a: DVec3, b: DVec3, c: DVec3) -> bool {
    let lo = a.min(b).min(c);
    let hi = a.max(b).max(c);
    let pad = DVec3::splat((hi - lo).max_element() * 1e-6);
    ray_hits_box(o, d.recip(), lo - pad, hi + pad, f64::INFINITY)
}

/// Slab test: does the ray o + t·d, 0 <= t <= t_max, meet the box? `inv_d` = 1/d per axis.
pub fn ray_hits_box(o: DVec3, inv_d: DVec3, lo: DVec3, hi: DVec3, t_max: f64) -> bool {
    let t1 = (lo - o) * inv_d;
    let t2 = (hi - o) * inv_d;
    // NaN (0·inf on a slab face) counts as "inside the slab": conservative for a traversal.
    let near = t1.min(t2);
    let far = t1.max(t2);
    let t_near = [near.x, near.y, near.z, 0.0]
        .into_iter()
        .filter(|x| !x.is_nan())
        .fold(f64::NEG_INFINITY, f64::max);
    let t_far = [far.x, far.y, far.z, t_max]
        .into_iter()
        .filter(|x| !x.is_nan())
        .fold(f64::INFINITY, f64::min);
    t_near <= t_far * (1.0 + 1e-12) + 1e-300
}

/// 6 × signed volume of the tetrahedron (a, b, c, d): positive when d is on the side of the
/// triangle [a, b, c]'s normal... negated, as the classic orient3d.
fn orient(a: DVec3, b: DVec3, c: DVec3, d: DVec3) -> f64 {
    (a - d).dot((b - d).cross(c - d))
}

/// Whether segment [p, q] crosses the interior of triangle [a, b, c] strictly (touching,
/// grazing and coplanar cases are not counted).
pub fn segment_crosses_triangle(p: DVec3, q: DVec3, a: DVec3, b: DVec3, c: DVec3) -> bool {
    let (op, oq) = (orient(a, b, c, p), orient(a, b, c, q));
    if !(op > 0.0 && oq < 0.0 || op < 0.0 && oq > 0.0) {
        return false;
    }
    let s1 = orient(p, q, a, b);
    let s2 = orient(p, q, b, c);
    let s3 = orient(p, q, c, a);
    s1 > 0.0 && s2 > 0.0 && s3 > 0.0 || s1 < 0.0 && s2 < 0.0 && s3 < 0.0
}

/// Whether two triangles intersect in a way a strict edge-through-interior test can see: some
/// edge of one crosses the interior of the other. Coplanar overlaps are not detected.
pub fn triangles_cross(t: &[DVec3; 3], u: &[DVec3; 3]) -> bool {
    (0..3).any(|i| segment_crosses_triangle(t[i], t[(i + 1) % 3], u[0], u[1], u[2]))
        || (0..3).any(|i| segment_crosses_triangle(u[i], u[(i + 1) % 3], t[0], t[1], t[2]))
}

/// Whether some axis separates triangles `t` and `u` by more than `gap`: either normal or the
/// cross product of an edge of each (the axes that separate two triangles in general position).
/// A yes proves every point within `gap` of t off u; a no proves nothing (coplanar pairs, for
/// one, are never separated here). The projections are computed about t's centroid and
/// widened by a relative 1e-9 of the coordinates' size there, far above their rounding.
pub fn apart(t: &[DVec3; 3], u: &[DVec3; 3], gap: f64) -> bool {
    let o = (t[0] + t[1] + t[2]) / 3.0;
    let (t, u) = (t.map(|v| v - o), u.map(|v| v - o));
    let size = (t.iter().chain(&u)).fold(0.0f64, |m, v| m.max(v.abs().max_element()));
    let edges = |x: &[DVec3; 3]| [x[1] - x[0], x[2] - x[1], x[0] - x[2]];
    let (te, ue) = (edges(&t), edges(&u));
    let span = |x: &[DVec3; 3], a: DVec3| {
        let d = x.map(|v| a.dot(v));
        (d[0].min(d[1]).min(d[2]), d[0].max(d[1]).max(d[2]))
    };
    let separates = |a: DVec3| {
        let len = a.length();
        let ((tlo, thi), (ulo, uhi)) = (span(&t, a), span(&u, a));
        let slack = len * (gap + 1e-9 * size);
        len > 0.0 && (ulo - thi > slack || tlo - uhi > slack)
    };
    separates(te[0].cross(te[1]))
        || separates(ue[0].cross(ue[1]))
        || te
            .iter()
            .any(|&e| ue.iter().any(|&f| separates(e.cross(f))))
}

/// Largest and smallest singular values of the 3x3 matrix with columns `m`, as a sound upper
/// bound of σ_max and lower bound of σ_min (eigenvalues of MᵀM by the trigonometric formula,
/// widened by a relative 1e-9 against rounding; σ_max also capped by the Frobenius norm).
pub fn singular_bounds(m: [DVec3; 3]) -> (f64, f64) {
    let g = |i: usize, j: usize| m[i].dot(m[j]);
    let (a11, a22, a33, a12, a13, a23) = (g(0, 0), g(1, 1), g(2, 2), g(0, 1), g(0, 2), g(1, 2));
    let frob2 = a11 + a22 + a33;
    let q = frob2 / 3.0;
    let p1 = a12 * a12 + a13 * a13 + a23 * a23;
    let p2 = (a11 - q).powi(2) + (a22 - q).powi(2) + (a33 - q).powi(2) + 2.0 * p1;
    let (l_max, l_min) = if p2 <= 1e-30 * frob2 * frob2 {
        (q, q)
    } else {
        let p = (p2 / 6.0).sqrt();
        let b = |x: f64| x / p;
        let (b11, b22, b33, b12, b13, b23) =
            (b(a11 - q), b(a22 - q), b(a33 - q), b(a12), b(a13), b(a23));
        let det = b11 * (b22 * b33 - b23 * b23) - b12 * (b12 * b33 - b23 * b13)
            + b13 * (b12 * b23 - b22 * b13);
        let phi = (det / 2.0).clamp(-1.0, 1.0).acos() / 3.0;
        let l1 = q + 2.0 * p * phi.cos();
        let l3 = q + 2.0 * p * (phi + 2.0 * std::f64::consts::PI / 3.0).cos();
        (l1, l3)
    };
    let slack = 1e-9 * frob2;
    let s_max = (l_max + slack)
        .max(0.0)
        .sqrt()
        .min(frob2.sqrt() * (1.0 + 1e-12));
    let s_min = (l_min - slack).max(0.0).sqrt();
    (s_max, s_min)
}

/// The box [lo, hi] as 12 outward triangles (tests).
#[cfg(test)]
pub(crate) fn box_triangles(lo: DVec3, hi: DVec3) -> Vec<[DVec3; 3]> {
    let v = |i: usize| {
        DVec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        )
    };
    let quads = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    quads
        .iter()
        .flat_map(|q| [[v(q[0]), v(q[1]), v(q[2])], [v(q[0]), v(q[2]), v(q[3])]])
        .collect()
}

/// The verifier's tests draw from fastrand's generator with a fixed seed; this adds points.
#[cfg(test)]
pub(crate) use fastrand::Rng;

/// A uniform point of the cube [-s, s)³.
#[cfg(test)]
pub(crate) fn cube_point(rng: &mut Rng, s: f64) -> DVec3 {
    DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5) * 2.0 * s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn triangle_distance_is_the_minimum_over_dense_samples() {
        let mut rng = Rng::with_seed(7);
        for _ in 0..300 {
            let t = [
                cube_point(&mut rng, 1.0),
                cube_point(&mut rng, 1.0),
                cube_point(&mut rng, 1.0),
            ];
            let p = cube_point(&mut rng, 2.0);
            let d = dist_triangle(p, t[0], t[1], t[2]);
            let mut best = f64::INFINITY;
            let n = 60;
            for i in 0..=n {
                for j in 0..=(n - i) {
                    let (u, v) = (i as f64 / n as f64, j as f64 / n as f64);
                    let x = t[0] + u * (t[1] - t[0]) + v * (t[2] - t[0]);
                    best = best.min((p - x).length());
                }
            }
            // The samples are within 2/60 of an edge length of every point.
            assert!(d <= best + 1e-12, "{d} > {best}");
            assert!(best - d <= 0.08, "{d} vs {best}");
        }
    }

    /// A separating axis is never claimed where the triangles come within the gap (distance
    /// by dense samples along each one's edges against the other, exact point-triangle
    /// distances, 0 where they cross), and stacked copies are told apart up to their distance.
    #[test]
    fn triangles_apart_are_farther_than_the_gap() {
        let mut rng = Rng::with_seed(19);
        let tri = |rng: &mut Rng, s: f64, at: DVec3| [0, 1, 2].map(|_| at + cube_point(rng, s));
        let edge_distance = |t: &[DVec3; 3], u: &[DVec3; 3]| {
            let n = 2000;
            (0..3)
                .flat_map(|k| (0..=n).map(move |i| (k, i as f64 / n as f64)))
                .map(|(k, s)| t[k] + s * (t[(k + 1) % 3] - t[k]))
                .map(|x| dist_triangle(x, u[0], u[1], u[2]))
                .fold(f64::INFINITY, f64::min)
        };
        let (mut apart_seen, mut pairs) = (0, 0);
        for k in 0..600 {
            let t = tri(&mut rng, 1.0, DVec3::ZERO);
            let at = cube_point(&mut rng, 1.2);
            let u = tri(&mut rng, 0.6, at);
            let gap = [0.0, 0.05, 0.2][k % 3];
            let d = if triangles_cross(&t, &u) {
                0.0
            } else {
                edge_distance(&t, &u).min(edge_distance(&u, &t))
            };
            pairs += 1;
            if apart(&t, &u, gap) {
                apart_seen += 1;
                assert!(d > gap, "pair {k}: apart by {gap} at distance {d}");
            }
        }
        assert!(
            apart_seen > pairs / 4,
            "{apart_seen} of {pairs} apart: no power"
        );
        for _ in 0..200 {
            let t = tri(&mut rng, 1.0, DVec3::ZERO);
            let d = 1e-6 + rng.f64();
            let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize();
            let u = t.map(|v| v + d * n);
            assert!(apart(&t, &u, 0.99 * d) && apart(&u, &t, 0.99 * d), "at {d}");
            assert!(
                !apart(&t, &u, 1.01 * d),
                "apart by more than their distance {d}"
            );
        }
    }

    #[test]
    fn singular_bounds_enclose_stretch_on_random_affine_maps() {
        let mut rng = Rng::with_seed(11);
        for k in 0..500 {
            let mut m = [
                cube_point(&mut rng, 3.0),
                cube_point(&mut rng, 3.0),
                cube_point(&mut rng, 3.0),
            ];
            if k % 5 == 0 {
                m[2] = m[0] * 0.5 + m[1] * 1e-7; // nearly singular
            }
            let (s_max, s_min) = singular_bounds(m);
            let apply = |x: DVec3| m[0] * x.x + m[1] * x.y + m[2] * x.z;
            let (mut hi, mut lo) = (0.0f64, f64::INFINITY);
            for _ in 0..2000 {
                let x = cube_point(&mut rng, 1.0).normalize();
                let s = apply(x).length();
                hi = hi.max(s);
                lo = lo.min(s);
            }
            assert!(s_max >= hi && s_min <= lo, "{s_min} {s_max} vs {lo} {hi}");
            // And tight: random directions come near the extremes.
            assert!(s_max <= hi * 1.05 + 1e-9, "{s_max} vs {hi}");
        }
    }

    #[test]
    fn crossings_of_a_closed_tetrahedron_give_its_winding_number() {
        let t = [
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(1.0, 0.0, 0.0),
            DVec3::new(0.0, 1.0, 0.0),
            DVec3::new(0.0, 0.0, 1.0),
        ];
        let faces = [[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]];
        let mut rng = Rng::with_seed(3);
        for _ in 0..200 {
            let p = cube_point(&mut rng, 1.0) + DVec3::splat(0.3);
            let d = cube_point(&mut rng, 1.0);
            let mut sum = 0;
            let mut sure = true;
            let mut w = 0.0;
            for f in faces {
                let [a, b, c] = f.map(|i| t[i]);
                w += winding_share(p, a, b, c);
                match ray_crossing(p, d, a, b, c) {
                    Crossing::Cross(s) => sum += s,
                    Crossing::Unsure => sure = false,
                    Crossing::Miss => {}
                }
            }
            if sure {
                assert!((w - sum as f64).abs() < 1e-9, "{w} vs {sum} at {p}");
            }
        }
    }

    #[test]
    fn crossing_triangles_are_seen_and_separate_ones_are_not() {
        let t = [DVec3::ZERO, DVec3::X, DVec3::Y];
        let u = [
            DVec3::new(0.2, 0.2, -1.0),
            DVec3::new(0.2, 0.2, 1.0),
            DVec3::new(2.0, 2.0, 0.0),
        ];
        assert!(triangles_cross(&t, &u));
        let far = u.map(|v| v + DVec3::new(5.0, 0.0, 0.0));
        assert!(!triangles_cross(&t, &far));
    }
}
