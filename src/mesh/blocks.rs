//! The voxel boundary cut into blocks, so that the mesh stage holds one block's fine mesh at a
//! time and simplifies blocks in parallel (docs/design.md, "Blocks").
//!
//! Coordinates are lattice corners (grid units). A face of the boundary belongs to the block
//! whose half-open box [lo, hi) holds its centre; the last block along an axis reaches n + 1,
//! so the faces on the grid's far planes belong to it. A block's faces form a patch of the
//! boundary whose open edges lie on the block's box and are shared with a neighbour's patch;
//! the vertices of those edges are *locked*: a block's pass never moves or removes them, so the
//! patches still fit together afterwards (`simplify::blocked`).
//!
//! Triangles are those of `extract::extract` (the same quads, split along the same diagonal),
//! so the blocks' patches together are exactly the whole start mesh.

use std::collections::HashMap;
use std::hash::BuildHasherDefault;

use glam::DVec3;

use crate::mesh::classify::VoxelSet;
use crate::mesh::Mesh;
use crate::voxels::{pack_cell, KeyHasher};

/// A box of lattice corners [lo, hi) (grid units).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Block {
    pub lo: [usize; 3],
    pub hi: [usize; 3],
}

impl Block {
    /// Whether point `p` lies in the closed box with every coordinate strictly between the
    /// box's planes (off every face of it).
    pub fn strictly_holds(&self, p: DVec3) -> bool {
        (0..3).all(|a| p[a] > self.lo[a] as f64 && p[a] < self.hi[a] as f64)
    }
}

/// Blocks of `size` voxels along each axis covering a grid of `dims` voxels (corners 0..=n), in
/// z, then y, then x order.
pub fn blocks(dims: [usize; 3], size: usize) -> Vec<Block> {
    assert!(size > 0);
    let starts = |n: usize| {
        (0..=n)
            .step_by(size)
            .map(move |s| (s, (s + size).min(n + 1)))
    };
    let mut out = Vec::new();
    for (z0, z1) in starts(dims[2]) {
        for (y0, y1) in starts(dims[1]) {
            for (x0, x1) in starts(dims[0]) {
                out.push(Block {
                    lo: [x0, y0, z0],
                    hi: [x1, y1, z1],
                });
            }
        }
    }
    out
}

/// One block's part of the voxel boundary: its faces as triangles, and which vertices lie on
/// the patch's open edges (locked).
#[derive(Clone, Debug, Default)]
pub struct Patch {
    pub mesh: Mesh,
    pub locked: Vec<bool>,
}

/// The voxels of a block and the one-voxel layer below it, for the faces the block owns.
struct Cells {
    lo: [isize; 3],
    d: [usize; 3],
    inside: Vec<bool>,
}

impl Cells {
    fn get(&self, i: usize, j: usize, k: usize) -> bool {
        // (i, j, k) in grid voxels; the box starts one below the block.
        let l = [i, j, k].map(|x| x as isize);
        let at = [0, 1, 2].map(|a| (l[a] - self.lo[a]) as usize);
        self.inside[(at[2] * self.d[1] + at[1]) * self.d[0] + at[0]]
    }
}

/// The patch of the boundary of `set` that block `b` owns.
pub fn extract_block(set: &dyn VoxelSet, b: &Block) -> Patch {
    // Voxels lo - 1 .. hi along each axis: faces on planes lo..hi lie between them.
    let lo = b.lo.map(|x| x as isize - 1);
    let hi = b.hi.map(|x| x as isize);
    let d = [0, 1, 2].map(|a| (hi[a] - lo[a]) as usize);
    let mut cells = Cells {
        lo,
        d,
        inside: vec![false; d[0] * d[1] * d[2]],
    };
    set.fill_box(lo, hi, &mut cells.inside);
    let mut out = Builder::default();
    if !cells.inside.iter().any(|&c| c) {
        return Patch::default();
    }
    let [x0, y0, z0] = b.lo;
    let [x1, y1, z1] = b.hi;
    let v = |x: usize| x as isize;
    // Voxel (i, j, k) with i, j, k >= lo - 1; `at` with a possibly negative index reads outside.
    let at = |i: isize, j: isize, k: isize| {
        i >= lo[0] && j >= lo[1] && k >= lo[2] && { cells.get(i as usize, j as usize, k as usize) }
    };
    for k in z0..z1 {
        for j in y0..y1 {
            for i in x0..x1 {
                let here = at(v(i), v(j), v(k));
                // Plane z = k, between voxels (i, j, k - 1) and (i, j, k).
                match (at(v(i), v(j), v(k) - 1), here) {
                    (true, false) => {
                        out.quad([(i, j, k), (i + 1, j, k), (i + 1, j + 1, k), (i, j + 1, k)])
                    }
                    (false, true) => {
                        out.quad([(i, j, k), (i, j + 1, k), (i + 1, j + 1, k), (i + 1, j, k)])
                    }
                    _ => {}
                }
                // Plane x = i, between voxels (i - 1, j, k) and (i, j, k).
                match (at(v(i) - 1, v(j), v(k)), here) {
                    (true, false) => {
                        out.quad([(i, j, k), (i, j + 1, k), (i, j + 1, k + 1), (i, j, k + 1)])
                    }
                    (false, true) => {
                        out.quad([(i, j, k), (i, j, k + 1), (i, j + 1, k + 1), (i, j + 1, k)])
                    }
                    _ => {}
                }
                // Plane y = j, between voxels (i, j - 1, k) and (i, j, k).
                match (at(v(i), v(j) - 1, v(k)), here) {
                    (true, false) => {
                        out.quad([(i, j, k), (i, j, k + 1), (i + 1, j, k + 1), (i + 1, j, k)])
                    }
                    (false, true) => {
                        out.quad([(i, j, k), (i + 1, j, k), (i + 1, j, k + 1), (i, j, k + 1)])
                    }
                    _ => {}
                }
            }
        }
    }
    out.finish()
}

#[derive(Default)]
struct Builder {
    mesh: Mesh,
    corners: HashMap<u64, u32, BuildHasherDefault<KeyHasher>>,
}

impl Builder {
    fn corner(&mut self, (i, j, k): (usize, usize, usize)) -> u32 {
        let key = pack_cell([i as i64, j as i64, k as i64]);
        let next = self.mesh.positions.len() as u32;
        let id = *self.corners.entry(key).or_insert(next);
        if id == next {
            self.mesh
                .positions
                .push(DVec3::new(i as f64, j as f64, k as f64));
        }
        id
    }

    /// A unit square with corners counter-clockwise seen from outside (as `extract::extract`).
    fn quad(&mut self, c: [(usize, usize, usize); 4]) {
        let v = c.map(|x| self.corner(x));
        self.mesh.triangles.push([v[0], v[1], v[2]]);
        self.mesh.triangles.push([v[0], v[2], v[3]]);
    }

    /// The patch, with the vertices of its open edges (used by one triangle) locked.
    fn finish(self) -> Patch {
        let mut uses: HashMap<(u32, u32), u8, BuildHasherDefault<KeyHasher>> = HashMap::default();
        for t in &self.mesh.triangles {
            for e in 0..3 {
                let (a, b) = (t[e], t[(e + 1) % 3]);
                *uses.entry((a.min(b), a.max(b))).or_default() += 1;
            }
        }
        let mut locked = vec![false; self.mesh.positions.len()];
        for ((a, b), n) in uses {
            if n == 1 {
                locked[a as usize] = true;
                locked[b as usize] = true;
            }
        }
        Patch {
            mesh: self.mesh,
            locked,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::classify::test_support::random;
    use crate::mesh::extract::extract;
    use crate::mesh::manifold::Joined;

    /// The triangles of `mesh` as sorted position triples, each rotated to start at its least
    /// corner (orientation kept).
    fn keys(mesh: &Mesh) -> Vec<[[i64; 3]; 3]> {
        let mut out: Vec<[[i64; 3]; 3]> = mesh
            .triangles
            .iter()
            .map(|t| {
                let p = t.map(|v| mesh.positions[v as usize].to_array().map(|x| x as i64));
                let first = (0..3).min_by_key(|&i| p[i]).expect("three corners");
                [p[first], p[(first + 1) % 3], p[(first + 2) % 3]]
            })
            .collect();
        out.sort_unstable();
        out
    }

    /// The blocks' patches are the whole start mesh, triangle for triangle; a patch's locked
    /// vertices are exactly those of edges it shares with other blocks.
    #[test]
    fn patches_tile_the_start_mesh() {
        for (seed, size) in [(0, 5), (1, 7), (2, 3), (3, 64)] {
            let cls = random([17, 13, 11], seed);
            let joined = Joined::new(&cls);
            let whole = extract(&joined);
            let mut all = Mesh::default();
            let mut locked_edges = 0;
            for b in blocks([17, 13, 11], size) {
                let patch = extract_block(&joined, &b);
                for t in &patch.mesh.triangles {
                    let off = all.positions.len() as u32;
                    all.triangles.push([off, off + 1, off + 2]);
                    all.positions
                        .extend(t.map(|v| patch.mesh.positions[v as usize]));
                    // A triangle's centroid lies in its block.
                    let c = t
                        .map(|v| patch.mesh.positions[v as usize])
                        .iter()
                        .sum::<DVec3>()
                        / 3.0;
                    assert!((0..3).all(|a| c[a] >= b.lo[a] as f64 - 0.5 && c[a] <= b.hi[a] as f64));
                }
                // Locked vertices lie on the block's box.
                for (v, &l) in patch.locked.iter().enumerate() {
                    let p = patch.mesh.positions[v];
                    if l {
                        locked_edges += 1;
                        assert!(
                            (0..3).any(|a| p[a] == b.lo[a] as f64 || p[a] == b.hi[a] as f64),
                            "seed {seed}: locked vertex {p} inside block {b:?}"
                        );
                    }
                }
            }
            assert_eq!(keys(&all), keys(&whole), "seed {seed}, blocks of {size}");
            if size < 17 {
                assert!(locked_edges > 0, "seed {seed}: no seams");
            }
        }
    }

    #[test]
    fn blocks_cover_every_plane() {
        let b = blocks([10, 4, 1], 4);
        assert_eq!(b.len(), 6, "3 along x, 2 along y, 1 along z");
        assert_eq!(b[2].hi, [11, 4, 2]);
        assert_eq!(b[5].lo, [8, 4, 0]);
    }
}
