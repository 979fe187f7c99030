//! The mesh stage (paper sections 4 and 5): the six depth images become a closed 2-manifold
//! triangle mesh, the simplifier's start. [`classify`] decides each voxel by condition ⋆ (less
//! what [`flood`] reaches from outside, where the generator is closed),
//! [`manifold`] adds the voxels that join pinches, [`extract`] writes the boundary between inside
//! and outside voxels. [`Mesh`] is the triangle mesh every later stage passes on, in grid units,
//! with the checks every stage's output must pass.

pub mod blocks;
pub mod classify;
pub mod extract;
pub mod flood;
pub mod manifold;

use std::collections::HashMap;

use glam::DVec3;
use serde::Serialize;

/// An indexed triangle mesh. Positions are grid units (world = origin + p·h).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    pub positions: Vec<DVec3>,
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    /// Signed volume (grid units³): positive when the triangles face outward.
    pub fn volume(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.positions[i as usize]);
                a.dot(b.cross(c)) / 6.0
            })
            .sum()
    }

    /// Directed edges without their opposite: empty for a watertight, consistently oriented mesh
    /// (each edge a→b matched by as many b→a; an edge may have four faces).
    pub fn unpaired_edges(&self) -> Vec<(u32, u32)> {
        let mut count: HashMap<(u32, u32), i64> = HashMap::new();
        for t in &self.triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                if a < b {
                    *count.entry((a, b)).or_default() += 1;
                } else {
                    *count.entry((b, a)).or_default() -= 1;
                }
            }
        }
        count
            .into_iter()
            .filter(|(_, c)| *c != 0)
            .map(|(e, _)| e)
            .collect()
    }

    /// Area-weighted vertex normals, unit length; a vertex whose face normals cancel (possible
    /// at non-manifold vertices) takes the normal of its largest face.
    pub fn vertex_normals(&self) -> Vec<DVec3> {
        let mut sum = vec![DVec3::ZERO; self.positions.len()];
        let mut largest = vec![(0.0f64, DVec3::Z); self.positions.len()];
        for t in &self.triangles {
            let [a, b, c] = t.map(|i| self.positions[i as usize]);
            let n = (b - a).cross(c - a);
            let area = n.length();
            for &i in t {
                sum[i as usize] += n;
                if area > largest[i as usize].0 {
                    largest[i as usize] = (area, n / area);
                }
            }
        }
        sum.iter()
            .zip(&largest)
            .map(|(s, l)| s.try_normalize().unwrap_or(l.1))
            .collect()
    }

    /// What keeps the mesh from being a closed, oriented 2-manifold: all zero exactly when every
    /// edge has two triangles that run along it in opposite directions, every vertex's
    /// triangles form one closed fan, and no two vertices share a position.
    pub fn manifold_defects(&self) -> ManifoldDefects {
        let mut edges: HashMap<(u32, u32), (u32, u32)> = HashMap::new();
        for t in &self.triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                let e = edges.entry((a.min(b), a.max(b))).or_default();
                if a < b {
                    e.0 += 1;
                } else {
                    e.1 += 1;
                }
            }
        }
        let bad_edges = edges.values().filter(|&&uses| uses != (1, 1)).count();

        // Each vertex's corners as (previous, next) vertex; one closed fan when walking from a
        // corner's `next` to the corner whose `previous` it is visits every corner once.
        let mut start = vec![0usize; self.positions.len() + 1];
        for t in &self.triangles {
            for &v in t {
                start[v as usize + 1] += 1;
            }
        }
        for v in 0..self.positions.len() {
            start[v + 1] += start[v];
        }
        let mut fill = start.clone();
        let mut corners = vec![(0u32, 0u32); 3 * self.triangles.len()];
        for t in &self.triangles {
            for k in 0..3 {
                let v = t[k] as usize;
                corners[fill[v]] = (t[(k + 2) % 3], t[(k + 1) % 3]);
                fill[v] += 1;
            }
        }
        // Corners sorted by `previous`, so each step of the walk is a binary search: a vertex
        // with a huge fan costs O(k log k), not O(k²). A repeated `previous` is no fan.
        let one_fan = |fan: &mut [(u32, u32)]| {
            fan.sort_unstable();
            if fan.windows(2).any(|w| w[0].0 == w[1].0) {
                return false;
            }
            let mut at = 0;
            for step in 1..=fan.len() {
                let next = fan[at].1;
                let Ok(n) = fan.binary_search_by_key(&next, |c| c.0) else {
                    return false;
                };
                at = n;
                if at == 0 {
                    return step == fan.len();
                }
            }
            false
        };
        let bad_vertices = (0..self.positions.len())
            .filter(|&v| {
                let fan = &mut corners[start[v]..start[v + 1]];
                !fan.is_empty() && !one_fan(fan)
            })
            .count();

        let mut seen = std::collections::HashSet::new();
        let duplicates = self
            .positions
            .iter()
            .filter(|p| !seen.insert(p.to_array().map(f64::to_bits)))
            .count();
        ManifoldDefects {
            edges: bad_edges as u64,
            vertices: bad_vertices as u64,
            duplicate_positions: duplicates as u64,
        }
    }
}

/// Counts of what keeps a mesh from being a closed, oriented 2-manifold ([`Mesh::manifold_defects`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, serde::Deserialize)]
pub struct ManifoldDefects {
    /// Edges not used exactly once in each direction (open, four-face or misoriented edges).
    pub edges: u64,
    /// Vertices whose triangles are not one closed fan (pinched vertices).
    pub vertices: u64,
    /// Vertices at the position of an earlier vertex.
    pub duplicate_positions: u64,
}

impl ManifoldDefects {
    pub fn is_manifold(&self) -> bool {
        *self == ManifoldDefects::default()
    }
}
