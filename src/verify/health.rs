//! Mesh health: edge pairing (watertight, consistently oriented), connected components,
//! self-intersections and signed volume. Vertices are welded by exact position first, so a
//! file that splits vertices for normals or UVs is judged by its geometry.

use std::collections::HashMap;

use glam::DVec3;
use rayon::prelude::*;
use serde::Serialize;

use super::bvh::Bvh;
use super::geom;
use crate::union_find::UnionFind;

/// How many self-intersecting pairs are listed by index (all are counted).
const LISTED_PAIRS: usize = 10;

#[derive(Clone, Debug, Serialize)]
pub struct Health {
    pub triangles: u64,
    /// Distinct vertex positions.
    pub vertices: u64,
    /// Triangles with zero area (repeated or collinear vertices).
    pub degenerate_triangles: u64,
    /// Edges of exactly one triangle.
    pub open_edges: u64,
    /// Edges of more than two triangles.
    pub non_manifold_edges: u64,
    /// Edges whose two triangles run along them in the same direction.
    pub misoriented_edges: u64,
    /// Vertices (welded by position) whose triangles are not one closed fan: two cones meeting
    /// at a point, or two vertices of the file at one place (on an open mesh, every boundary
    /// vertex too).
    pub non_manifold_vertices: u64,
    /// Every edge is used as often in each direction: the surface bounds a solid and the
    /// winding number is an integer off it. What the containment proof needs.
    pub closed: bool,
    /// Closed and a 2-manifold: every edge in two triangles of opposite directions, every
    /// vertex one fan.
    pub watertight_manifold: bool,
    /// Connected by shared vertices.
    pub components: u64,
    /// Pairs of triangles without a shared vertex where an edge of one crosses the other.
    pub self_intersecting_pairs: u64,
    /// Up to ten such pairs (triangle indices in file order).
    pub self_intersection_examples: Vec<[u32; 2]>,
    /// Signed enclosed volume, world units³ (positive for an outward mesh).
    pub signed_volume: f64,
}

/// The mesh's health and its net unpaired directed edges (for the winding number's cone).
pub fn check(tris: &[[DVec3; 3]], bvh: &Bvh) -> (Health, Vec<(DVec3, DVec3)>) {
    // Weld by exact position.
    let mut ids: HashMap<[u64; 3], u32> = HashMap::new();
    let mut points: Vec<DVec3> = Vec::new();
    let welded: Vec<[u32; 3]> = tris
        .iter()
        .map(|t| {
            t.map(|v| {
                *ids.entry(v.to_array().map(f64::to_bits))
                    .or_insert_with(|| {
                        points.push(v);
                        points.len() as u32 - 1
                    })
            })
        })
        .collect();

    // Per undirected edge (a < b): uses a→b and uses b→a.
    let mut edges: HashMap<(u32, u32), (u32, u32)> = HashMap::new();
    let mut degenerate = 0u64;
    for t in &welded {
        if t[0] == t[1] || t[1] == t[2] || t[2] == t[0] {
            degenerate += 1;
        } else {
            let [a, b, c] = t.map(|i| points[i as usize]);
            if (b - a).cross(c - a) == DVec3::ZERO {
                degenerate += 1;
            }
        }
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            if a == b {
                continue;
            }
            let e = edges.entry((a.min(b), a.max(b))).or_default();
            if a < b {
                e.0 += 1;
            } else {
                e.1 += 1;
            }
        }
    }
    let (mut open, mut non_manifold, mut misoriented) = (0u64, 0u64, 0u64);
    let mut boundary = Vec::new();
    for (&(a, b), &(fw, bw)) in &edges {
        match fw + bw {
            1 => open += 1,
            2 if fw != bw => misoriented += 1,
            2 => {}
            _ => non_manifold += 1,
        }
        let (pa, pb) = (points[a as usize], points[b as usize]);
        for _ in bw..fw {
            boundary.push((pa, pb));
        }
        for _ in fw..bw {
            boundary.push((pb, pa));
        }
    }
    boundary.sort_by(|x, y| {
        (x.0.to_array(), x.1.to_array())
            .partial_cmp(&(y.0.to_array(), y.1.to_array()))
            .unwrap()
    });

    let non_manifold_vertices = count_pinched_vertices(&welded, points.len());

    // Components by shared vertices.
    let mut sets = UnionFind::new(points.len());
    for t in &welded {
        for k in 1..3 {
            sets.join(t[0], t[k]);
        }
    }
    let mut used = vec![false; points.len()];
    for t in &welded {
        for &i in t {
            used[i as usize] = true;
        }
    }
    let components = (0..points.len() as u32)
        .filter(|&i| used[i as usize] && sets.find(i) == i)
        .count() as u64;

    // Self-intersections: boxes from the BVH, exact-ish edge-through-interior tests.
    let mut pairs: Vec<[u32; 2]> = (0..tris.len() as u32)
        .into_par_iter()
        .flat_map_iter(|i| {
            let t = &tris[i as usize];
            let (lo, hi) = (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2]));
            let mut hits = Vec::new();
            bvh.for_each_overlap(lo, hi, |j| {
                if j <= i {
                    return;
                }
                let (wi, wj) = (&welded[i as usize], &welded[j as usize]);
                if wi.iter().any(|v| wj.contains(v)) {
                    return;
                }
                if geom::triangles_cross(t, &tris[j as usize]) {
                    hits.push([i, j]);
                }
            });
            hits
        })
        .collect();
    pairs.sort_unstable();
    let self_intersecting_pairs = pairs.len() as u64;
    pairs.truncate(LISTED_PAIRS);

    let signed_volume = tris.iter().map(|[a, b, c]| a.dot(b.cross(*c)) / 6.0).sum();
    let closed = boundary.is_empty();
    let health = Health {
        triangles: tris.len() as u64,
        vertices: points.len() as u64,
        degenerate_triangles: degenerate,
        open_edges: open,
        non_manifold_edges: non_manifold,
        misoriented_edges: misoriented,
        closed,
        non_manifold_vertices,
        watertight_manifold: closed
            && open == 0
            && non_manifold == 0
            && misoriented == 0
            && non_manifold_vertices == 0,
        components,
        self_intersecting_pairs,
        self_intersection_examples: pairs,
        signed_volume,
    };
    (health, boundary)
}

/// Vertices whose corners do not chain into one closed fan: at vertex v each triangle (v, a, b)
/// (in its winding order) leads to the triangle whose corner at v starts at b; one fan when that
/// walk from any corner visits all of v's corners and returns. On an open mesh every boundary
/// vertex counts (its fan does not close). Corners are sorted by their first vertex, so a vertex
/// with k triangles costs O(k log k) (hostile files may have one vertex in every triangle).
fn count_pinched_vertices(welded: &[[u32; 3]], vertices: usize) -> u64 {
    let mut corners: Vec<Vec<(u32, u32)>> = vec![Vec::new(); vertices];
    for t in welded {
        if t[0] == t[1] || t[1] == t[2] || t[2] == t[0] {
            continue;
        }
        for k in 0..3 {
            corners[t[k] as usize].push((t[(k + 1) % 3], t[(k + 2) % 3]));
        }
    }
    for c in corners.iter_mut() {
        c.sort_unstable();
    }
    corners
        .iter()
        .filter(|c| !c.is_empty())
        .filter(|c| {
            if c.windows(2).any(|w| w[0].0 == w[1].0) {
                return true;
            }
            let mut at = 0usize;
            for step in 1..=c.len() {
                match c.binary_search_by_key(&c[at].1, |&(from, _)| from) {
                    Ok(n) => at = n,
                    Err(_) => return true,
                }
                if at == 0 {
                    return step != c.len();
                }
            }
            true
        })
        .count() as u64
}
