//! The nearest pair of points between two triangle sets, f64: exact triangle-triangle distance
//! and a traversal of two BVHs, one of them under an affine pose.

use std::collections::BinaryHeap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

use glam::{DMat4, DVec3};
use rayon::prelude::*;

use crate::closest::{closest_on_triangle, closest_segments};
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
        take(v, closest_on_triangle(v, *u));
    }
    for &v in u {
        take(closest_on_triangle(v, *t), v);
    }
    for i in 0..3 {
        for j in 0..3 {
            let (a, b) = closest_segments(t[i], t[(i + 1) % 3], u[j], u[(j + 1) % 3]);
            take(a, b);
        }
    }
    best
}

/// A lower bound of the distance between triangles `t` and `u`: how far `u` lies wholly to one
/// side of `t`'s plane (0 where it reaches the plane, or `t` is degenerate).
fn plane_gap(t: &[DVec3; 3], u: &[DVec3; 3]) -> f64 {
    let n = (t[1] - t[0]).cross(t[2] - t[0]);
    let len = n.length();
    if len == 0.0 {
        return 0.0;
    }
    let s = u.map(|v| n.dot(v - t[0]));
    let (lo, hi) = (s[0].min(s[1]).min(s[2]), s[0].max(s[1]).max(s[2]));
    // Relative rounding of the products, kept on the safe side.
    let gap = if lo > 0.0 {
        lo
    } else if hi < 0.0 {
        -hi
    } else {
        0.0
    };
    (gap / len) * (1.0 - 1e-9)
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

/// The two BVHs of a search, `a`'s under a pose.
struct Pair<'a> {
    a: &'a Bvh,
    pose: Option<&'a DMat4>,
    b: &'a Bvh,
}

impl Pair<'_> {
    fn tri_a(&self, t: u32) -> [DVec3; 3] {
        let tri = self.a.tris[t as usize];
        match self.pose {
            Some(m) => tri.map(|v| m.transform_point3(v)),
            None => tri,
        }
    }

    fn gap(&self, i: u32, j: u32) -> f64 {
        let n = &self.b.nodes[j as usize];
        box_gap(
            posed_box(&self.a.nodes[i as usize], self.pose),
            (n.lo, n.hi),
        )
    }

    fn is_leaf(&self, i: u32, j: u32) -> bool {
        self.a.nodes[i as usize].count > 0 && self.b.nodes[j as usize].count > 0
    }

    /// The children of pair (i, j): the larger node (or the one that is not a leaf) opened.
    fn children(&self, i: u32, j: u32) -> [(u32, u32); 2] {
        let (na, nb) = (&self.a.nodes[i as usize], &self.b.nodes[j as usize]);
        let size = |n: &Node| (n.hi - n.lo).length();
        if nb.count > 0 || (na.count == 0 && size(na) >= size(nb)) {
            [(na.left, j), (na.right, j)]
        } else {
            [(i, nb.left), (i, nb.right)]
        }
    }

    /// About `want` pairs that cover (i, j) (breadth first), for the threads to share.
    fn frontier(&self, want: usize) -> Vec<(u32, u32)> {
        let mut out = vec![(0u32, 0u32)];
        while out.len() < want {
            let Some(k) = out.iter().position(|&(i, j)| !self.is_leaf(i, j)) else {
                break;
            };
            let (i, j) = out.swap_remove(k);
            out.extend(self.children(i, j));
        }
        out
    }
}

/// The best pair so far, shared by the threads: the distance's bits for quick pruning (f64 bits
/// of non-negative numbers order as the numbers do), the pair itself under a lock.
struct Best {
    bits: AtomicU64,
    pair: Mutex<Option<Nearest>>,
}

impl Best {
    fn limit(&self) -> f64 {
        f64::from_bits(self.bits.load(Ordering::Relaxed))
    }

    /// Keep `n` if it is nearer, or as near with smaller triangle indices: the result is the
    /// least (distance, a_tri, b_tri), whatever the threads' order.
    fn offer(&self, n: Nearest) {
        let mut best = self.pair.lock().expect("no thread panics holding it");
        let better =
            best.is_none_or(|b| (n.distance, n.a_tri, n.b_tri) < (b.distance, b.a_tri, b.b_tri));
        if better {
            *best = Some(n);
            self.bits.fetch_min(n.distance.to_bits(), Ordering::Relaxed);
        }
    }
}

/// The nearest pair between `a`'s triangles under `pose` (None: as they are) and `b`'s, when
/// no farther than `cutoff` (None otherwise). Best-first over pairs of nodes, on all threads
/// from a shared frontier; pairs whose boxes are farther apart than the best so far are
/// skipped. Ties go to the smaller triangle indices, so the result does not depend on the
/// number of threads.
pub fn nearest(a: &Bvh, pose: Option<&DMat4>, b: &Bvh, cutoff: f64) -> Option<Nearest> {
    let pair = Pair { a, pose, b };
    let best = Best {
        bits: AtomicU64::new(cutoff.max(0.0).to_bits()),
        pair: Mutex::new(None),
    };
    let mut frontier: Vec<(f64, u32, u32)> = pair
        .frontier(64)
        .into_iter()
        .map(|(i, j)| (pair.gap(i, j), i, j))
        .collect();
    frontier.sort_by(|x, y| x.0.total_cmp(&y.0));
    frontier.par_iter().for_each(|&(gap, i, j)| {
        if gap <= best.limit() {
            search(&pair, &best, i, j, gap);
        }
    });
    best.pair.into_inner().expect("no thread panicked")
}

/// A node pair's boxes' gap, for the best-first heap (smallest first).
#[derive(PartialEq)]
struct Open(f64, u32, u32);

impl Eq for Open {}
impl PartialOrd for Open {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Open {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        other.0.total_cmp(&self.0)
    }
}

fn search(pair: &Pair, best: &Best, i: u32, j: u32, gap: f64) {
    let mut heap = BinaryHeap::new();
    heap.push(Open(gap, i, j));
    while let Some(Open(gap, i, j)) = heap.pop() {
        if gap > best.limit() {
            return; // every pair left is at least as far
        }
        if pair.is_leaf(i, j) {
            let (na, nb) = (&pair.a.nodes[i as usize], &pair.b.nodes[j as usize]);
            for &s in pair.a.leaf_tris(na) {
                let ts = pair.tri_a(s);
                for &t in pair.b.leaf_tris(nb) {
                    let u = &pair.b.tris[t as usize];
                    // Most pairs of two near, nearly parallel surfaces are farther apart along
                    // a plane's normal than the best so far: skip them without the full test.
                    if plane_gap(&ts, u).max(plane_gap(u, &ts)) > best.limit() {
                        continue;
                    }
                    let (d, p, q) = triangle_pair(&ts, u);
                    if d <= best.limit() {
                        best.offer(Nearest {
                            distance: d,
                            a_tri: s,
                            b_tri: t,
                            a_point: p,
                            b_point: q,
                        });
                    }
                }
            }
            continue;
        }
        for (x, y) in pair.children(i, j) {
            let g = pair.gap(x, y);
            if g <= best.limit() {
                heap.push(Open(g, x, y));
            }
        }
    }
}

/// The first pair (in a fixed order) of a triangle of `a` under `pose` and one of `b` that
/// cross, or meet as [`triangle_pair`] decides (distance 0): only pairs of overlapping boxes
/// are opened, so it is fast where the sets stay apart.
pub fn meeting(a: &Bvh, pose: Option<&DMat4>, b: &Bvh) -> Option<Nearest> {
    let pair = Pair { a, pose, b };
    let mut stack = vec![(0u32, 0u32)];
    while let Some((i, j)) = stack.pop() {
        if pair.gap(i, j) > 0.0 {
            continue;
        }
        if pair.is_leaf(i, j) {
            let (na, nb) = (&a.nodes[i as usize], &b.nodes[j as usize]);
            for &s in a.leaf_tris(na) {
                let ts = pair.tri_a(s);
                for &t in b.leaf_tris(nb) {
                    let (d, p, q) = triangle_pair(&ts, &b.tris[t as usize]);
                    if d == 0.0 {
                        return Some(Nearest {
                            distance: 0.0,
                            a_tri: s,
                            b_tri: t,
                            a_point: p,
                            b_point: q,
                        });
                    }
                }
            }
            continue;
        }
        let [x, y] = pair.children(i, j);
        stack.push(y);
        stack.push(x);
    }
    None
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
            assert!(nearest(&ba, Some(&pose), &bb, brute * (1.0 - 1e-12)).is_none());
            assert_eq!(meeting(&ba, Some(&pose), &bb).is_some(), brute == 0.0);
            // The same pair on one thread as on all.
            let one = rayon::ThreadPoolBuilder::new()
                .num_threads(1)
                .build()
                .unwrap();
            assert_eq!(
                one.install(|| nearest(&ba, Some(&pose), &bb, f64::INFINITY)),
                Some(found)
            );
        }
    }
}
