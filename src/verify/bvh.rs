//! Axis-aligned bounding-volume hierarchy over triangles, f64, with exact queries: nearest
//! distance, "anything within r", box overlaps and ray crossings. Each node also carries a
//! bounding ball (centre, radius) that covers every triangle under it.

use glam::DVec3;

use super::geom::{self, Crossing};

#[derive(Clone, Debug)]
pub struct Node {
    pub lo: DVec3,
    pub hi: DVec3,
    /// Every point of every triangle below is within `radius` of `centre`.
    pub centre: DVec3,
    pub radius: f64,
    /// Leaf: triangles `order[first..first + count]`; inner: count = 0, children `left`, `right`.
    pub first: u32,
    pub count: u32,
    pub left: u32,
    pub right: u32,
}

/// A BVH over `tris` (vertex triples). Node 0 is the root.
#[derive(Clone, Debug)]
pub struct Bvh {
    pub tris: Vec<[DVec3; 3]>,
    pub nodes: Vec<Node>,
    /// Triangle indices in leaf order.
    pub order: Vec<u32>,
}

impl Bvh {
    /// Median split on the longest axis of the centroids' box, at most `leaf_size` per leaf.
    pub fn build(tris: Vec<[DVec3; 3]>, leaf_size: usize) -> Bvh {
        assert!(!tris.is_empty(), "a BVH needs at least one triangle");
        let centroids: Vec<DVec3> = tris.iter().map(|t| (t[0] + t[1] + t[2]) / 3.0).collect();
        let mut order: Vec<u32> = (0..tris.len() as u32).collect();
        let mut nodes = Vec::with_capacity(2 * tris.len() / leaf_size.max(1) + 1);
        let mut bvh = Bvh {
            tris,
            nodes: Vec::new(),
            order: Vec::new(),
        };
        build_node(
            &bvh.tris,
            &centroids,
            &mut order,
            0,
            leaf_size.max(1),
            &mut nodes,
        );
        bvh.nodes = nodes;
        bvh.order = order;
        bvh
    }

    /// Triangle indices under node `n`.
    pub fn leaf_tris(&self, n: &Node) -> &[u32] {
        &self.order[n.first as usize..(n.first + n.count) as usize]
    }

    /// Distance from `p` to the nearest triangle, and that triangle.
    pub fn nearest(&self, p: DVec3) -> (f64, u32) {
        let mut best = (f64::INFINITY, u32::MAX);
        let mut stack = vec![(0u32, 0.0f64)];
        while let Some((i, d_box)) = stack.pop() {
            if d_box >= best.0 {
                continue;
            }
            let n = &self.nodes[i as usize];
            if n.count > 0 {
                for &t in self.leaf_tris(n) {
                    let [a, b, c] = self.tris[t as usize];
                    let d = geom::dist_triangle(p, a, b, c);
                    if d < best.0 {
                        best = (d, t);
                    }
                }
                continue;
            }
            let (l, r) = (&self.nodes[n.left as usize], &self.nodes[n.right as usize]);
            let (dl, dr) = (geom::dist_box(p, l.lo, l.hi), geom::dist_box(p, r.lo, r.hi));
            // Nearer child last, so it is popped first.
            if dl < dr {
                stack.push((n.right, dr));
                stack.push((n.left, dl));
            } else {
                stack.push((n.left, dl));
                stack.push((n.right, dr));
            }
        }
        best
    }

    /// Whether some triangle comes within distance `r` of `p` (exact, stops at the first).
    pub fn any_within(&self, p: DVec3, r: f64) -> bool {
        let mut stack = vec![0u32];
        while let Some(i) = stack.pop() {
            let n = &self.nodes[i as usize];
            if geom::dist_box(p, n.lo, n.hi) > r {
                continue;
            }
            if n.count > 0 {
                if self.leaf_tris(n).iter().any(|&t| {
                    let [a, b, c] = self.tris[t as usize];
                    geom::dist_triangle(p, a, b, c) <= r
                }) {
                    return true;
                }
                continue;
            }
            stack.push(n.left);
            stack.push(n.right);
        }
        false
    }

    /// Calls `f` with every triangle whose box overlaps [lo, hi].
    pub fn for_each_overlap(&self, lo: DVec3, hi: DVec3, mut f: impl FnMut(u32)) {
        let mut stack = vec![0u32];
        while let Some(i) = stack.pop() {
            let n = &self.nodes[i as usize];
            if n.lo.cmpgt(hi).any() || n.hi.cmplt(lo).any() {
                continue;
            }
            if n.count > 0 {
                for &t in self.leaf_tris(n) {
                    let tri = &self.tris[t as usize];
                    let (tl, th) = (
                        tri[0].min(tri[1]).min(tri[2]),
                        tri[0].max(tri[1]).max(tri[2]),
                    );
                    if !(tl.cmpgt(hi).any() || th.cmplt(lo).any()) {
                        f(t);
                    }
                }
                continue;
            }
            stack.push(n.left);
            stack.push(n.right);
        }
    }

    /// Sum of signed crossings of the ray o + t·d (t > 0) with all triangles, or None when
    /// some crossing is too close to an edge or to the origin to decide.
    pub fn ray_crossings(&self, o: DVec3, d: DVec3) -> Option<i64> {
        let inv = d.recip();
        let mut sum = 0i64;
        let mut stack = vec![0u32];
        while let Some(i) = stack.pop() {
            let n = &self.nodes[i as usize];
            let pad = DVec3::splat((n.hi - n.lo).max_element() * 1e-9 + 1e-300);
            if !geom::ray_hits_box(o, inv, n.lo - pad, n.hi + pad, f64::INFINITY) {
                continue;
            }
            if n.count > 0 {
                for &t in self.leaf_tris(n) {
                    let [a, b, c] = self.tris[t as usize];
                    match geom::ray_crossing(o, d, a, b, c) {
                        Crossing::Miss => {}
                        Crossing::Cross(s) => sum += s as i64,
                        Crossing::Unsure => return None,
                    }
                }
                continue;
            }
            stack.push(n.left);
            stack.push(n.right);
        }
        Some(sum)
    }
}

fn build_node(
    tris: &[[DVec3; 3]],
    centroids: &[DVec3],
    order: &mut [u32],
    first: usize,
    leaf_size: usize,
    nodes: &mut Vec<Node>,
) -> u32 {
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for &t in order.iter() {
        for v in &tris[t as usize] {
            lo = lo.min(*v);
            hi = hi.max(*v);
        }
    }
    let centre = (lo + hi) / 2.0;
    let radius = order
        .iter()
        .flat_map(|&t| tris[t as usize].iter())
        .map(|v| (*v - centre).length())
        .fold(0.0, f64::max);
    let index = nodes.len() as u32;
    nodes.push(Node {
        lo,
        hi,
        centre,
        radius,
        first: first as u32,
        count: order.len() as u32,
        left: 0,
        right: 0,
    });
    if order.len() <= leaf_size {
        return index;
    }
    let (mut clo, mut chi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for &t in order.iter() {
        clo = clo.min(centroids[t as usize]);
        chi = chi.max(centroids[t as usize]);
    }
    let ext = chi - clo;
    let axis = if ext.x >= ext.y && ext.x >= ext.z {
        0
    } else if ext.y >= ext.z {
        1
    } else {
        2
    };
    let mid = order.len() / 2;
    order.select_nth_unstable_by(mid, |a, b| {
        centroids[*a as usize][axis].total_cmp(&centroids[*b as usize][axis])
    });
    let (left_half, right_half) = order.split_at_mut(mid);
    let left = build_node(tris, centroids, left_half, first, leaf_size, nodes);
    let right = build_node(tris, centroids, right_half, first + mid, leaf_size, nodes);
    let n = &mut nodes[index as usize];
    n.count = 0;
    n.left = left;
    n.right = right;
    index
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_and_any_within_match_brute_force() {
        let mut rng = crate::verify::geom::Rng::with_seed(0x1234_5678_9abc_def1);
        let mut v = |sc: f64| crate::verify::geom::cube_point(&mut rng, sc / 2.0);
        let tris: Vec<[DVec3; 3]> = (0..400)
            .map(|_| {
                let c = v(10.0);
                [c + v(1.0), c + v(1.0), c + v(1.0)]
            })
            .collect();
        let bvh = Bvh::build(tris.clone(), 4);
        for _ in 0..300 {
            let p = v(14.0);
            let brute = tris
                .iter()
                .map(|t| geom::dist_triangle(p, t[0], t[1], t[2]))
                .fold(f64::INFINITY, f64::min);
            let (d, t) = bvh.nearest(p);
            assert_eq!(d, brute);
            let tri = tris[t as usize];
            assert_eq!(geom::dist_triangle(p, tri[0], tri[1], tri[2]), brute);
            assert!(bvh.any_within(p, brute));
            assert!(!bvh.any_within(p, brute * 0.999));
        }
        // Every node's ball covers its triangles.
        for n in &bvh.nodes {
            let mut stack = vec![n];
            while let Some(m) = stack.pop() {
                if m.count > 0 {
                    for &t in bvh.leaf_tris(m) {
                        for x in &bvh.tris[t as usize] {
                            assert!((*x - n.centre).length() <= n.radius * (1.0 + 1e-12));
                        }
                    }
                } else {
                    stack.push(&bvh.nodes[m.left as usize]);
                    stack.push(&bvh.nodes[m.right as usize]);
                }
            }
        }
    }
}
