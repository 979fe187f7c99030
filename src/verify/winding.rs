//! The generalized winding number of the mesh under test, exact and fast.
//!
//! For a closed mesh (every edge used as often in each direction: a 2-cycle) the generalized
//! winding number w(p) = Σ solid angles / 4π is an integer and equals the signed number of
//! crossings of any ray from p. For a mesh with holes, close it with a cone C from one apex over
//! the unpaired edges (reversed), so S + C is a cycle: w_S(p) = crossings(S + C) - w_C(p), with
//! w_C an exact solid-angle sum over the few cone triangles. Either way each query is one BVH
//! ray cast; a ray that passes too near an edge or starts on a triangle is replaced by another
//! direction, and after 12 tries the plain O(n) solid-angle sum answers.

use glam::DVec3;

use super::bvh::Bvh;
use super::geom::{self, Crossing};

pub struct Winding<'a> {
    bvh: &'a Bvh,
    /// The closing cone: empty for a closed mesh.
    cone: Vec<[DVec3; 3]>,
}

/// Ray directions tried in turn: unit vectors in general position.
fn direction(k: u32) -> DVec3 {
    let mut s = 0x9E37_79B9_7F4A_7C15u64.wrapping_mul(k as u64 + 1) ^ 0xD1B5_4A32_D192_ED03;
    let mut next = || {
        s ^= s >> 31;
        s = s.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        s ^= s >> 29;
        (s >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    loop {
        let d = DVec3::new(next(), next(), next());
        if d.length() > 0.2 && d.abs().min_element() > 0.05 {
            return d.normalize();
        }
    }
}

impl<'a> Winding<'a> {
    /// `boundary`: the mesh's net unpaired directed edges (u, v), one entry per unit of excess.
    pub fn new(bvh: &'a Bvh, boundary: &[(DVec3, DVec3)]) -> Self {
        let apex = if boundary.is_empty() {
            DVec3::ZERO
        } else {
            // Centre of the boundary's box, nudged off any plane of axis-aligned geometry.
            let (lo, hi) = boundary.iter().fold(
                (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
                |(lo, hi), (u, v)| (lo.min(*u).min(*v), hi.max(*u).max(*v)),
            );
            (lo + hi) / 2.0 + (hi - lo).max_element() * DVec3::new(0.0123, 0.0071, 0.0097)
        };
        let cone = boundary.iter().map(|&(u, v)| [v, u, apex]).collect();
        Winding { bvh, cone }
    }

    pub fn is_closed(&self) -> bool {
        self.cone.is_empty()
    }

    /// w(p). Exact for p off the surface (up to f64 rounding in the cone's solid angles).
    pub fn at(&self, p: DVec3) -> f64 {
        'dirs: for k in 0..12 {
            let d = direction(k);
            let Some(mut crossings) = self.bvh.ray_crossings(p, d) else {
                continue;
            };
            for [a, b, c] in &self.cone {
                match geom::ray_crossing(p, d, *a, *b, *c) {
                    Crossing::Miss => {}
                    Crossing::Cross(s) => crossings += s as i64,
                    Crossing::Unsure => continue 'dirs,
                }
            }
            let w_cone: f64 = self
                .cone
                .iter()
                .map(|[a, b, c]| geom::winding_share(p, *a, *b, *c))
                .sum();
            return crossings as f64 - w_cone;
        }
        self.bvh
            .tris
            .iter()
            .map(|[a, b, c]| geom::winding_share(p, *a, *b, *c))
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A closed, outward unit cube as 12 triangles, and an open copy without one triangle.
    fn cube() -> Vec<[DVec3; 3]> {
        geom::box_triangles(DVec3::ZERO, DVec3::ONE)
    }

    fn exact(tris: &[[DVec3; 3]], p: DVec3) -> f64 {
        tris.iter()
            .map(|[a, b, c]| geom::winding_share(p, *a, *b, *c))
            .sum()
    }

    #[test]
    fn closed_and_open_meshes_match_the_solid_angle_sum() {
        let tris = cube();
        assert!((exact(&tris, DVec3::splat(0.5)) - 1.0).abs() < 1e-12);
        let bvh = Bvh::build(tris.clone(), 2);
        let w = Winding::new(&bvh, &[]);
        let mut rng = fastrand::Rng::with_seed(99);
        let mut f = || rng.f64();
        for _ in 0..500 {
            let p = DVec3::new(f(), f(), f()) * 2.0 - DVec3::splat(0.5);
            assert!((w.at(p) - exact(&tris, p)).abs() < 1e-9, "{p}");
        }
        // Remove a triangle: the boundary is its three edges, reversed in the mesh's sense.
        let mut open = tris.clone();
        let gone = open.remove(3);
        let boundary: Vec<(DVec3, DVec3)> = (0..3).map(|i| (gone[(i + 1) % 3], gone[i])).collect();
        let bvh = Bvh::build(open.clone(), 2);
        let w = Winding::new(&bvh, &boundary);
        assert!(!w.is_closed());
        for _ in 0..500 {
            let p = DVec3::new(f(), f(), f()) * 2.0 - DVec3::splat(0.5);
            assert!((w.at(p) - exact(&open, p)).abs() < 1e-9, "{p}");
        }
    }
}
