//! The nearest posed generator triangle to a query point, over every pose of every part: the
//! search behind the deviation bound.
//!
//! Vibration poses all overlap, so where a pose puts the part prunes nothing; where it puts the
//! *query* does. Pose P maps the query p into the part's frame, q = P⁻¹p, and for every local
//! triangle T, dist(p, P·T) >= σ_min(P)·dist(q, T) (|Px - Py| >= σ_min·|x - y|). The queries of a
//! pose cluster get a box in the part's frame, and the search runs best-first over (pose
//! cluster, BVH node) pairs with the lower bound σ_min(cluster)·dist(query box, node box), at a
//! single triangle also the box's distance to the triangle's plane. Only single (pose, triangle)
//! pairs get exact distances, computed in world space from the posed vertices.
//!
//! The bound is tight where it matters: the distances of all poses differ by how far their
//! queries spread *across* the nearest surface, and a box of queries within `tol` of each other
//! along the normal is settled by one plane test, so a hard query (one that must prove its
//! nearest distance) visits the few clusters at the near side of the query cloud rather than
//! every pose.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use glam::{DMat4, DVec3};

use super::geom;
use super::poses::PosedPart;

/// Nearest posed triangle found.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    /// Exact world distance from the query to the posed triangle.
    pub dist: f64,
    pub part: u32,
    /// Local triangle index.
    pub tri: u32,
    /// Index into the part's poses.
    pub pose: u32,
}

/// Per part: what the search needs beyond [`PosedPart`], built once.
pub struct Frames {
    /// P⁻¹ of each pose, in the pose tree's order (position i holds pose `tree.perm[i]`).
    inverse: Vec<DMat4>,
    /// Per pose: its position in the tree's order.
    position: Vec<u32>,
    /// Per cluster: a lower bound of σ_min over its poses.
    sigma_min: Vec<f64>,
    /// Per cluster: how far a computed q = P⁻¹p may be from the exact one, per unit of |p| + 1
    /// (from the residual of P·P⁻¹ against the identity, widened fourfold).
    inverse_error: Vec<f64>,
    /// Per local triangle: unit normal and offset (n·x = d); a zero normal for degenerate ones.
    planes: Vec<(DVec3, f64)>,
}

impl Frames {
    pub fn new(part: &PosedPart) -> Frames {
        let tree = &part.tree;
        let per_pose: Vec<(DMat4, f64, f64)> = tree
            .perm
            .iter()
            .map(|&k| {
                let pose = &part.poses[k as usize];
                let (m, s_min) = (pose.matrix, pose.sigma_min);
                let inv = m.inverse();
                let residual = m * inv - DMat4::IDENTITY;
                let frob = |a: &DMat4| a.to_cols_array().iter().map(|x| x * x).sum::<f64>().sqrt();
                let err = 4.0 * (frob(&residual) + 1e-14) * frob(&inv);
                (
                    inv,
                    s_min,
                    if err.is_finite() { err } else { f64::INFINITY },
                )
            })
            .collect();
        let (sigma_min, inverse_error) = tree
            .clusters
            .iter()
            .map(|c| {
                per_pose[c.lo as usize..c.hi as usize]
                    .iter()
                    .fold((f64::INFINITY, 0.0f64), |(s, e), p| {
                        (s.min(p.1), e.max(p.2))
                    })
            })
            .unzip();
        let planes = part
            .bvh
            .tris
            .iter()
            .map(|[a, b, c]| {
                let n = (*b - *a).cross(*c - *a);
                let len = n.length();
                if len > 0.0 && len.is_finite() {
                    let n = n / len;
                    (n, n.dot(*a))
                } else {
                    (DVec3::ZERO, 0.0)
                }
            })
            .collect();
        let mut position = vec![0; tree.perm.len()];
        for (i, &k) in tree.perm.iter().enumerate() {
            position[k as usize] = i as u32;
        }
        Frames {
            position,
            inverse: per_pose.into_iter().map(|p| p.0).collect(),
            sigma_min,
            inverse_error,
            planes,
        }
    }
}

/// Per-thread working memory of the search (reused between queries), and the last hit as a
/// first guess for the next query (neighbouring samples usually share their nearest pose).
#[derive(Default)]
pub struct Scratch {
    /// Per cluster of the part being filled: box of the queries q = P⁻¹p of its poses.
    boxes: Vec<Vec<(DVec3, DVec3)>>,
    heap: BinaryHeap<Reverse<(u64, u32, u32, u32)>>,
    last: Option<(u32, u32)>,
}

/// The query's nearest posed triangle, with two ways to stop early:
/// - a posed triangle within `threshold` of `p` is returned as soon as one is found (the second
///   value is then meaningless);
/// - otherwise the result is at most `tol` farther than the nearest, and the second value is a
///   proven lower bound of the nearest distance, at least `threshold`.
pub fn nearest(
    parts: &[PosedPart],
    frames: &[Frames],
    scratch: &mut Scratch,
    p: DVec3,
    threshold: f64,
    tol: f64,
) -> (Hit, f64) {
    let mut best = Hit {
        dist: f64::INFINITY,
        part: 0,
        tri: 0,
        pose: 0,
    };
    // First guess: the last query's pose, nearest triangle in its frame (an exact distance to a
    // real posed triangle, so a sound upper bound of the minimum whatever the pose's shape).
    if let Some((pi, pose)) = scratch.last {
        if let (Some(part), Some(f)) = (parts.get(pi as usize), frames.get(pi as usize)) {
            let q = f.inverse[f.position[pose as usize] as usize].transform_point3(p);
            // A degenerate pose (no finite inverse) gives no q and no triangle: no guess.
            let (_, tri) = part.bvh.nearest(q);
            if (tri as usize) < part.bvh.tris.len() {
                best = exact(part, pi, pose, tri, p);
            }
        }
    }
    if best.dist > threshold {
        search(parts, frames, scratch, p, threshold, tol, &mut best);
    }
    scratch.last = Some((best.part, best.pose));
    let lower = threshold.max(best.dist - tol).max(0.0);
    (best, lower)
}

/// Exact world distance from `p` to local triangle `tri` of `part` under pose `pose`.
fn exact(part: &PosedPart, part_index: u32, pose: u32, tri: u32, p: DVec3) -> Hit {
    let m = part.poses[pose as usize].matrix;
    let [a, b, c] = part.bvh.tris[tri as usize].map(|v| m.transform_point3(v));
    Hit {
        dist: geom::dist_triangle(p, a, b, c),
        part: part_index,
        tri,
        pose,
    }
}

/// Best-first branch and bound; `best` holds the guess on entry and the answer on return.
fn search(
    parts: &[PosedPart],
    frames: &[Frames],
    scratch: &mut Scratch,
    p: DVec3,
    threshold: f64,
    tol: f64,
    best: &mut Hit,
) {
    scratch.boxes.resize_with(parts.len(), Vec::new);
    let mut heap = std::mem::take(&mut scratch.heap);
    heap.clear();
    let p_scale = p.abs().max_element() + 1.0;
    for (pi, (part, f)) in parts.iter().zip(frames).enumerate() {
        query_boxes(part, f, p, &mut scratch.boxes[pi]);
        let lb = pair_bound(part, f, &scratch.boxes[pi], p_scale, 0, 0);
        heap.push(Reverse((lb.to_bits(), pi as u32, 0, 0)));
    }
    while let Some(Reverse((lb_bits, pi, cluster, node))) = heap.pop() {
        let lb = f64::from_bits(lb_bits);
        // Everything left has a bound at least `lb`: stop once that settles the answer.
        if best.dist <= threshold || lb >= threshold.max(best.dist - tol) || lb >= best.dist {
            break;
        }
        let (part, f, boxes) = (
            &parts[pi as usize],
            &frames[pi as usize],
            &scratch.boxes[pi as usize],
        );
        let c = &part.tree.clusters[cluster as usize];
        let n = &part.bvh.nodes[node as usize];
        if c.is_leaf() && n.count > 0 {
            let pose = part.tree.perm[c.lo as usize];
            for &t in part.bvh.leaf_tris(n) {
                let hit = exact(part, pi, pose, t, p);
                if hit.dist < best.dist {
                    *best = hit;
                }
            }
            continue;
        }
        // Split the side with the larger extent (a leaf side cannot split).
        let (cb_lo, cb_hi) = boxes[cluster as usize];
        let pose_extent = (cb_hi - cb_lo).length();
        let node_extent = (n.hi - n.lo).length();
        let split_node = n.count == 0 && (c.is_leaf() || node_extent >= pose_extent);
        let children = if split_node {
            [(cluster, n.left), (cluster, n.right)]
        } else {
            [(c.left, node), (c.right, node)]
        };
        for (cc, nn) in children {
            let child = pair_bound(part, f, boxes, p_scale, cc, nn).max(lb);
            if child < best.dist && child < threshold.max(best.dist - tol) {
                heap.push(Reverse((child.to_bits(), pi, cc, nn)));
            }
        }
    }
    scratch.heap = heap;
}

/// Fills `boxes` (one per cluster) with the boxes of q = P⁻¹p over each cluster's poses.
fn query_boxes(part: &PosedPart, f: &Frames, p: DVec3, boxes: &mut Vec<(DVec3, DVec3)>) {
    let clusters = &part.tree.clusters;
    boxes.clear();
    boxes.resize(clusters.len(), (DVec3::ZERO, DVec3::ZERO));
    // Clusters are stored parent first, so children come after their parent: fill backwards.
    for (i, c) in clusters.iter().enumerate().rev() {
        boxes[i] = if c.is_leaf() {
            let q = f.inverse[c.lo as usize].transform_point3(p);
            (q, q)
        } else {
            let (a, b) = (boxes[c.left as usize], boxes[c.right as usize]);
            (a.0.min(b.0), a.1.max(b.1))
        };
    }
}

/// Lower bound of the world distance from p to any triangle under BVH node `node` posed by any
/// pose of cluster `cluster`, from the query box in the part's frame.
fn pair_bound(
    part: &PosedPart,
    f: &Frames,
    boxes: &[(DVec3, DVec3)],
    p_scale: f64,
    cluster: u32,
    node: u32,
) -> f64 {
    let (q_lo, q_hi) = boxes[cluster as usize];
    let n = &part.bvh.nodes[node as usize];
    let mut local = box_gap(q_lo, q_hi, n.lo, n.hi);
    if n.count > 0 {
        // Every triangle of the leaf is at least its plane's distance away.
        let plane = part
            .bvh
            .leaf_tris(n)
            .iter()
            .map(|&t| {
                let (normal, d) = f.planes[t as usize];
                let centre = (q_lo + q_hi) / 2.0;
                let half = (q_hi - q_lo) / 2.0;
                (normal.dot(centre) - d).abs() - normal.abs().dot(half)
            })
            .fold(f64::INFINITY, f64::min);
        local = local.max(plane);
    }
    // Widen for the rounding of q (inverse error) and of the bound itself.
    let local = local - f.inverse_error[cluster as usize] * p_scale;
    (f.sigma_min[cluster as usize] * local * (1.0 - 1e-12)).max(0.0)
}

/// Distance between two boxes (0 where they overlap).
fn box_gap(a_lo: DVec3, a_hi: DVec3, b_lo: DVec3, b_hi: DVec3) -> f64 {
    (a_lo - b_hi).max(b_lo - a_hi).max(DVec3::ZERO).length()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::verify::geom::{cube_point, Rng};
    use crate::verify::poses::PartPose;

    /// A random part: `n` small triangles scattered in the unit cube, posed by `poses` random
    /// affine maps near a common one (vibration-like, every pose overlapping).
    fn random_part(rng: &mut Rng, n: usize, poses: usize, shear: f64) -> PosedPart {
        let tris: Vec<[DVec3; 3]> = (0..n)
            .map(|_| {
                let c = cube_point(rng, 1.0);
                [
                    c,
                    c + 0.2 * cube_point(rng, 1.0),
                    c + 0.2 * cube_point(rng, 1.0),
                ]
            })
            .collect();
        let base = DMat4::from_rotation_translation(
            glam::DQuat::from_axis_angle(cube_point(rng, 1.0).normalize(), 1.0),
            cube_point(rng, 1.0),
        );
        let poses: Vec<PartPose> = (0..poses)
            .map(|_| {
                let jitter = DMat4::from_cols(
                    (DVec3::X + shear * cube_point(rng, 1.0)).extend(0.0),
                    (DVec3::Y + shear * cube_point(rng, 1.0)).extend(0.0),
                    (DVec3::Z + shear * cube_point(rng, 1.0)).extend(0.0),
                    (0.05 * cube_point(rng, 1.0)).extend(1.0),
                );
                PartPose::new(base * jitter, None, None)
            })
            .collect();
        PosedPart::new(0, "part".into(), tris, poses)
    }

    fn brute_force(part: &PosedPart, p: DVec3) -> f64 {
        let mut best = f64::INFINITY;
        for pose in &part.poses {
            for t in &part.bvh.tris {
                let [a, b, c] = t.map(|v| pose.matrix.transform_point3(v));
                best = best.min(geom::dist_triangle(p, a, b, c));
            }
        }
        best
    }

    #[test]
    fn nearest_matches_brute_force_within_tolerance() {
        let mut rng = Rng::with_seed(11);
        for (shear, tol) in [(0.0, 0.0), (0.02, 0.0), (0.1, 0.01), (0.3, 0.05)] {
            let parts = vec![random_part(&mut rng, 60, 50, shear)];
            let frames: Vec<Frames> = parts.iter().map(Frames::new).collect();
            let mut scratch = Scratch::default();
            for _ in 0..60 {
                let p = 2.0 * cube_point(&mut rng, 1.0);
                let truth = brute_force(&parts[0], p);
                let (hit, lower) =
                    nearest(&parts, &frames, &mut scratch, p, f64::NEG_INFINITY, tol);
                // The hit is a real posed triangle at the distance it says.
                let again = exact(&parts[0], 0, hit.pose, hit.tri, p).dist;
                assert_eq!(hit.dist, again);
                assert!(hit.dist >= truth);
                assert!(
                    hit.dist <= truth + tol + 1e-12,
                    "{} > {truth} + {tol}",
                    hit.dist
                );
                assert!(lower <= truth + 1e-12, "lower {lower} > {truth}");
                assert!(lower >= hit.dist - tol - 1e-12);
            }
        }
    }

    /// A zero-scale pose has no inverse: the search still answers (exactly, since it falls back
    /// to visiting every pair) instead of indexing past the triangles (issue 14).
    #[test]
    fn singular_poses_do_not_panic() {
        let mut rng = Rng::with_seed(3);
        let mut part = random_part(&mut rng, 20, 4, 0.0);
        for pose in &mut part.poses {
            *pose = PartPose::new(DMat4::from_scale(DVec3::new(1.0, 0.0, 1.0)), None, None);
        }
        let part = PosedPart::new(0, "flat".into(), part.bvh.tris.clone(), part.poses);
        let parts = vec![part];
        let frames: Vec<Frames> = parts.iter().map(Frames::new).collect();
        let mut scratch = Scratch::default();
        for _ in 0..20 {
            let p = 2.0 * cube_point(&mut rng, 1.0);
            let (hit, _) = nearest(&parts, &frames, &mut scratch, p, f64::NEG_INFINITY, 0.0);
            assert!((hit.dist - brute_force(&parts[0], p)).abs() <= 1e-12);
        }
    }

    #[test]
    fn threshold_queries_stop_at_a_close_enough_triangle_or_prove_none() {
        let mut rng = Rng::with_seed(5);
        let parts = vec![random_part(&mut rng, 40, 80, 0.05)];
        let frames: Vec<Frames> = parts.iter().map(Frames::new).collect();
        let mut scratch = Scratch::default();
        for _ in 0..100 {
            let p = 2.0 * cube_point(&mut rng, 1.0);
            let truth = brute_force(&parts[0], p);
            let threshold = truth + 0.3 * (2.0 * rng.f64() - 1.0);
            let (hit, lower) = nearest(&parts, &frames, &mut scratch, p, threshold, 0.0);
            if truth <= threshold {
                assert!(hit.dist <= threshold, "{} > {threshold}", hit.dist);
            } else {
                assert!(lower >= threshold && lower <= truth + 1e-12);
                assert!((hit.dist - truth).abs() <= 1e-12);
            }
        }
    }
}
