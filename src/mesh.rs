//! Triangle meshes in grid units, and the checks every stage's output must pass.

use std::collections::HashMap;

use glam::DVec3;

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
}
