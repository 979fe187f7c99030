//! The boundary between inside and outside voxels as a triangle mesh (paper section 5): every
//! face between an inside voxel and an outside one (or the grid's border) becomes two triangles,
//! oriented outward. Vertices are voxel corners, welded through two rolling (nx+1)·(ny+1) corner
//! maps (planes z = k and z = k + 1), so memory is O(n²) plus the output.
//!
//! The result is watertight, without T-junctions (all faces are unit squares on one lattice) and
//! consistently oriented; it is "mostly manifold": where voxels touch only along an edge or at a
//! corner, an edge has four faces or a vertex two fans. The pipeline extracts the set
//! `manifold::Joined` makes of the classifier's voxels, which has no such places.

use glam::DVec3;

use crate::mesh::classify::VoxelSet;
use crate::mesh::Mesh;

const NONE: u32 = u32::MAX;

struct Builder {
    nx: usize,
    mesh: Mesh,
    /// Corner indices on planes z = k (0) and z = k + 1 (1); NONE where not created yet.
    planes: [Vec<u32>; 2],
    k: usize,
}

impl Builder {
    fn corner(&mut self, i: usize, j: usize, z: usize) -> u32 {
        let p = z - self.k;
        let slot = j * (self.nx + 1) + i;
        if self.planes[p][slot] == NONE {
            self.planes[p][slot] = self.mesh.positions.len() as u32;
            self.mesh
                .positions
                .push(DVec3::new(i as f64, j as f64, z as f64));
        }
        self.planes[p][slot]
    }

    /// A unit square with corners in counter-clockwise order seen from outside.
    fn quad(&mut self, c: [(usize, usize, usize); 4]) {
        let v = c.map(|(i, j, z)| self.corner(i, j, z));
        self.mesh.triangles.push([v[0], v[1], v[2]]);
        self.mesh.triangles.push([v[0], v[2], v[3]]);
    }

    fn next_plane(&mut self) {
        self.planes.swap(0, 1);
        self.planes[1].fill(NONE);
        self.k += 1;
    }
}

/// Extract the boundary mesh of the voxels in `set`.
pub fn extract(set: &dyn VoxelSet) -> Mesh {
    let [nx, ny, nz] = set.dims();
    let plane = (nx + 1) * (ny + 1);
    let mut b = Builder {
        nx,
        mesh: Mesh::default(),
        planes: [vec![NONE; plane], vec![NONE; plane]],
        k: 0,
    };
    let mut below = vec![false; nx * ny];
    let mut here = vec![false; nx * ny];
    for k in 0..=nz {
        set.slab(k as isize, &mut here); // all false for k = nz
                                         // Faces on the plane z = k, between slab k-1 (below) and slab k.
        for j in 0..ny {
            for i in 0..nx {
                match (below[j * nx + i], here[j * nx + i]) {
                    (true, false) => {
                        b.quad([(i, j, k), (i + 1, j, k), (i + 1, j + 1, k), (i, j + 1, k)])
                    }
                    (false, true) => {
                        b.quad([(i, j, k), (i, j + 1, k), (i + 1, j + 1, k), (i + 1, j, k)])
                    }
                    _ => {}
                }
            }
        }
        if k == nz {
            break;
        }
        // Faces across x and y inside slab k.
        let at = |i: isize, j: isize| {
            i >= 0
                && j >= 0
                && (i as usize) < nx
                && (j as usize) < ny
                && here[j as usize * nx + i as usize]
        };
        for j in 0..ny {
            for i in 0..nx {
                if !here[j * nx + i] {
                    continue;
                }
                let (si, sj) = (i as isize, j as isize);
                let z = k + 1;
                if !at(si + 1, sj) {
                    b.quad([
                        (i + 1, j, k),
                        (i + 1, j + 1, k),
                        (i + 1, j + 1, z),
                        (i + 1, j, z),
                    ]);
                }
                if !at(si - 1, sj) {
                    b.quad([(i, j, k), (i, j, z), (i, j + 1, z), (i, j + 1, k)]);
                }
                if !at(si, sj + 1) {
                    b.quad([
                        (i, j + 1, k),
                        (i, j + 1, z),
                        (i + 1, j + 1, z),
                        (i + 1, j + 1, k),
                    ]);
                }
                if !at(si, sj - 1) {
                    b.quad([(i, j, k), (i + 1, j, k), (i + 1, j, z), (i, j, z)]);
                }
            }
        }
        std::mem::swap(&mut below, &mut here);
        b.next_plane();
    }
    b.mesh
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::classify::DenseSet;

    fn check(set: DenseSet, triangles: usize, vertices: usize) {
        let voxels = set.len() as f64;
        let m = extract(&set);
        assert_eq!(
            (m.triangles.len(), m.positions.len()),
            (triangles, vertices)
        );
        assert!(m.unpaired_edges().is_empty(), "not watertight");
        assert!(
            (m.volume() - voxels).abs() < 1e-12,
            "volume {} for {voxels} voxels",
            m.volume()
        );
    }

    #[test]
    fn one_voxel_is_a_cube() {
        check(DenseSet::from_list([3, 3, 3], &[[1, 1, 1]]), 12, 8);
    }

    #[test]
    fn voxels_on_the_grid_border_are_closed_too() {
        check(DenseSet::from_list([1, 1, 1], &[[0, 0, 0]]), 12, 8);
        check(
            DenseSet::from_list([2, 1, 1], &[[0, 0, 0], [1, 0, 0]]),
            20,
            12,
        );
    }

    #[test]
    fn shared_faces_disappear() {
        // A 2x2x2 block: a cube of 24 unit squares, 26 distinct corners.
        let block: Vec<[usize; 3]> = (0..8)
            .map(|b| [1 + (b & 1), 1 + (b >> 1 & 1), 1 + (b >> 2)])
            .collect();
        check(DenseSet::from_list([4, 4, 4], &block), 48, 26);
    }

    #[test]
    fn voxels_touching_along_an_edge_share_it_with_four_faces() {
        // Non-manifold edge: still every directed edge is paired, vertices are welded.
        check(
            DenseSet::from_list([3, 3, 2], &[[0, 0, 0], [1, 1, 0]]),
            24,
            14,
        );
    }

    #[test]
    fn voxels_touching_at_a_corner_share_one_vertex() {
        check(
            DenseSet::from_list([2, 2, 2], &[[0, 0, 0], [1, 1, 1]]),
            24,
            15,
        );
    }
}
