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

use glam::DVec3;

use crate::mesh::classify::VoxelSet;
use crate::mesh::Mesh;

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

    /// Whether point `p` lies on one of the box's planes (a coordinate equal to a bound).
    pub fn on_faces(&self, p: DVec3) -> bool {
        (0..3).any(|a| p[a] == self.lo[a] as f64 || p[a] == self.hi[a] as f64)
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

/// `list` (with each block's `cost`) after splitting every block that holds more than half the
/// total cost into its half-size children (eight, fewer where an axis is narrower than
/// `2 * min` voxels and so not halved), in z, y, x order in its place, again until none does.
/// Such a block would run alone while every other worker idles (a flat part whose one block holds two
/// thirds of the surface: docs/perf-log.md, "The second case"). The rule reads costs
/// only, so the blocks, and the result, do not depend on the thread count.
pub fn split_dominant(
    mut list: Vec<Block>,
    mut cost: Vec<usize>,
    min: usize,
    cost_of: impl Fn(&Block) -> usize,
) -> (Vec<Block>, Vec<usize>) {
    assert_eq!(list.len(), cost.len(), "a cost per block");
    loop {
        let total: usize = cost.iter().sum();
        let halves = |b: &Block| -> [Vec<(usize, usize)>; 3] {
            std::array::from_fn(|a| {
                let (lo, hi) = (b.lo[a], b.hi[a]);
                if hi - lo >= 2 * min {
                    let mid = lo + (hi - lo) / 2;
                    vec![(lo, mid), (mid, hi)]
                } else {
                    vec![(lo, hi)]
                }
            })
        };
        let Some(i) = (0..list.len())
            .find(|&i| 2 * cost[i] > total && halves(&list[i]).iter().any(|h| h.len() == 2))
        else {
            return (list, cost);
        };
        let [xs, ys, zs] = halves(&list[i]);
        let mut children = Vec::with_capacity(8);
        for &(z0, z1) in &zs {
            for &(y0, y1) in &ys {
                for &(x0, x1) in &xs {
                    children.push(Block {
                        lo: [x0, y0, z0],
                        hi: [x1, y1, z1],
                    });
                }
            }
        }
        let costs: Vec<usize> = children.iter().map(&cost_of).collect();
        list.splice(i..=i, children);
        cost.splice(i..=i, costs);
    }
}

/// About how many faces of the voxel boundary block `b` owns, from every fourth slab: the
/// faces across x and y in the slabs k = const and those across z in the slabs j = const, with k
/// and j multiples of `ESTIMATE_STRIDE`, scaled by it. Each kind of face is counted where its
/// plane is crossed by the sampled slabs, so a flat wall is seen at that rate wherever it lies:
/// rows on a lattice of 4 along both y and z (the rule before) saw a wall across y or z 16
/// times over or not at all (the gear at n = 512: a block of 373,924 start triangles estimated
/// at 97,104 faces, its neighbours within 35%). For ordering the blocks' work, costliest
/// first, and splitting a block that holds most of it; a few per cent of extracting them.
pub fn faces_estimate(set: &dyn VoxelSet, b: &Block) -> usize {
    const ESTIMATE_STRIDE: usize = 4;
    let (x0, x1) = (b.lo[0] as isize - 1, b.hi[0] as isize);
    let len = (x1 - x0) as usize;
    let (mut row, mut before) = (vec![false; len], vec![false; len]);
    let differ = |a: &[bool], b: &[bool]| a.iter().zip(b).filter(|(a, b)| a != b).count();
    let lo = b.lo.map(|x| x as isize);
    let hi = b.hi.map(|x| x as isize);
    let mut faces = 0;
    // Slabs k = const: rows along y in turn, each against the one before it (element 0 is the
    // voxel before the block: faces on plane x = lo are the block's, as are those on y = lo).
    for k in (lo[2]..hi[2]).step_by(ESTIMATE_STRIDE) {
        set.fill_box([x0, lo[1] - 1, k], [x1, lo[1], k + 1], &mut before);
        for j in lo[1]..hi[1] {
            set.fill_box([x0, j, k], [x1, j + 1, k + 1], &mut row);
            faces += differ(&row[..len - 1], &row[1..]) + differ(&row[1..], &before[1..]);
            std::mem::swap(&mut row, &mut before);
        }
    }
    // Slabs j = const: rows along z in turn, for the faces across z.
    for j in (lo[1]..hi[1]).step_by(ESTIMATE_STRIDE) {
        set.fill_box([x0, j, lo[2] - 1], [x1, j + 1, lo[2]], &mut before);
        for k in lo[2]..hi[2] {
            set.fill_box([x0, j, k], [x1, j + 1, k + 1], &mut row);
            faces += differ(&row[1..], &before[1..]);
            std::mem::swap(&mut row, &mut before);
        }
    }
    faces * ESTIMATE_STRIDE
}

/// One block's part of the voxel boundary: its faces as triangles, and which vertices lie on
/// the patch's open edges (locked).
#[derive(Clone, Debug, Default)]
pub struct Patch {
    pub mesh: Mesh,
    pub locked: Vec<bool>,
}

/// The patch of the boundary of `set` that block `b` owns.
pub fn extract_block(set: &dyn VoxelSet, b: &Block) -> Patch {
    // Voxels lo - 1 .. hi along each axis: faces on planes lo..hi lie between them.
    let lo = b.lo.map(|x| x as isize - 1);
    let hi = b.hi.map(|x| x as isize);
    let d = [0, 1, 2].map(|a| (hi[a] - lo[a]) as usize);
    let mut inside = vec![false; d[0] * d[1] * d[2]];
    set.fill_box(lo, hi, &mut inside);
    if !inside.iter().any(|&c| c) {
        return Patch::default();
    }
    let [x0, y0, z0] = b.lo;
    let [x1, y1, z1] = b.hi;
    let mut out = Builder::new(b);
    // Row (y0 - 1 + j, z0 - 1 + k) of `inside`: element t is voxel (x0 - 1 + t, ..).
    let row = |j: usize, k: usize| {
        let at = (k * d[1] + j) * d[0];
        &inside[at..at + d[0]]
    };
    for k in z0..z1 {
        out.slab(k);
        for j in y0..y1 {
            let (jj, kk) = (j + 1 - y0, k + 1 - z0);
            let (here, below_z, below_y) = (row(jj, kk), row(jj, kk - 1), row(jj - 1, kk));
            // A row and the two below it all of one class hold no face.
            if here == below_z && here == below_y && here.iter().all(|&c| c == here[0]) {
                continue;
            }
            for i in x0..x1 {
                let t = i + 1 - x0;
                let h = here[t];
                // Plane z = k, between voxels (i, j, k - 1) and (i, j, k).
                match (below_z[t], h) {
                    (true, false) => {
                        out.quad([(i, j, k), (i + 1, j, k), (i + 1, j + 1, k), (i, j + 1, k)])
                    }
                    (false, true) => {
                        out.quad([(i, j, k), (i, j + 1, k), (i + 1, j + 1, k), (i + 1, j, k)])
                    }
                    _ => {}
                }
                // Plane x = i, between voxels (i - 1, j, k) and (i, j, k).
                match (here[t - 1], h) {
                    (true, false) => {
                        out.quad([(i, j, k), (i, j + 1, k), (i, j + 1, k + 1), (i, j, k + 1)])
                    }
                    (false, true) => {
                        out.quad([(i, j, k), (i, j, k + 1), (i, j + 1, k + 1), (i, j + 1, k)])
                    }
                    _ => {}
                }
                // Plane y = j, between voxels (i, j - 1, k) and (i, j, k).
                match (below_y[t], h) {
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

/// The patch as it is built: corners numbered in order of first use, found through the two
/// z-planes of corners the current layer of voxels touches, and each unit edge's uses counted
/// (open edges, used by one face, lie on the block's box).
struct Builder {
    mesh: Mesh,
    /// The block's lowest corner and its corner planes' width.
    lo: [usize; 3],
    w: usize,
    /// Corner ids on planes z = `z` and z + 1 (u32::MAX: none yet).
    planes: [Vec<u32>; 2],
    z: usize,
    /// Per corner and axis: the unit edge from it along the axis, its far corner and its uses.
    edges: Vec<[(u32, u8); 3]>,
}

impl Builder {
    fn new(b: &Block) -> Self {
        let (w, h) = (b.hi[0] - b.lo[0] + 1, b.hi[1] - b.lo[1] + 1);
        Builder {
            mesh: Mesh::default(),
            lo: b.lo,
            w,
            planes: [vec![u32::MAX; w * h], vec![u32::MAX; w * h]],
            z: b.lo[2],
            edges: Vec::new(),
        }
    }

    /// The layer of voxels at z = `k` is next: its faces' corners lie on planes k and k + 1.
    fn slab(&mut self, k: usize) {
        if k != self.z {
            debug_assert_eq!(k, self.z + 1);
            self.planes.swap(0, 1);
            self.planes[1].fill(u32::MAX);
            self.z = k;
        }
    }

    fn corner(&mut self, (i, j, k): (usize, usize, usize)) -> u32 {
        let at = (j - self.lo[1]) * self.w + i - self.lo[0];
        let slot = &mut self.planes[k - self.z][at];
        if *slot == u32::MAX {
            *slot = self.mesh.positions.len() as u32;
            self.mesh
                .positions
                .push(DVec3::new(i as f64, j as f64, k as f64));
            self.edges.push([(u32::MAX, 0); 3]);
        }
        *slot
    }

    /// A unit square with corners counter-clockwise seen from outside (as `extract::extract`).
    fn quad(&mut self, c: [(usize, usize, usize); 4]) {
        let v = c.map(|x| self.corner(x));
        self.mesh.triangles.push([v[0], v[1], v[2]]);
        self.mesh.triangles.push([v[0], v[2], v[3]]);
        for m in 0..4 {
            let (p, q) = (c[m], c[(m + 1) % 4]);
            let (a, b) = ([p.0, p.1, p.2], [q.0, q.1, q.2]);
            let axis = (0..3).find(|&x| a[x] != b[x]).expect("a unit edge");
            let (low, high) = if a[axis] < b[axis] {
                (m, (m + 1) % 4)
            } else {
                ((m + 1) % 4, m)
            };
            let e = &mut self.edges[v[low] as usize][axis];
            *e = (v[high], e.1 + 1);
        }
    }

    /// The patch, with the vertices of its open edges (used by one face) locked.
    fn finish(self) -> Patch {
        let mut locked = vec![false; self.mesh.positions.len()];
        for (v, edges) in self.edges.iter().enumerate() {
            for &(far, uses) in edges {
                if uses == 1 {
                    locked[v] = true;
                    locked[far as usize] = true;
                }
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

    /// A block holding more than half the cost is split into its children in its place, and again
    /// while one does; blocks of balanced cost, and axes narrower than twice the least width,
    /// are left whole; the split blocks still tile the grid.
    #[test]
    fn a_dominant_block_is_split_in_place() {
        let list = blocks([256, 100, 300], 128); // 2 × 1 × 3 blocks
        let volume = |b: &Block| (0..3).map(|a| b.hi[a] - b.lo[a]).product::<usize>();
        // Balanced: nothing changes.
        let cost: Vec<usize> = list.iter().map(volume).collect();
        let (same, _) = split_dominant(list.clone(), cost, 32, volume);
        assert_eq!(same, list);
        // The surface all within 20 voxels of the grid's origin: the first block, then its
        // first child, hold all of it; splitting stops at the least width.
        let near_origin = |b: &Block| usize::from(b.lo.iter().all(|&x| x < 20)) * 1000;
        let cost: Vec<usize> = list.iter().map(near_origin).collect();
        let (split, costs) = split_dominant(list.clone(), cost, 32, near_origin);
        assert_eq!(split[0].lo, [0, 0, 0]);
        // x and z halved twice (128 → 32), y (101 wide) once: 50 is under twice 32.
        assert_eq!(split[0].hi, [32, 50, 32]);
        assert_eq!(split.len(), costs.len());
        assert!(costs
            .iter()
            .all(|&c| 2 * c <= costs.iter().sum::<usize>() || c == costs[0]));
        // Still a tiling of the grid's corners 0..=n: the volumes add up, no two overlap.
        let whole: usize = list.iter().map(volume).sum();
        assert_eq!(split.iter().map(volume).sum::<usize>(), whole);
        for (i, a) in split.iter().enumerate() {
            for b in &split[i + 1..] {
                assert!(
                    (0..3).any(|k| a.hi[k] <= b.lo[k] || b.hi[k] <= a.lo[k]),
                    "{a:?} {b:?}"
                );
            }
        }
        // The last block along an axis keeps its far bound (n + 1).
        assert!(split.iter().any(|b| b.hi == [257, 101, 301]));
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
                // Locked vertices are those of the patch's open edges (one triangle each), and
                // lie on the block's box.
                let mut uses: std::collections::HashMap<(u32, u32), usize> = Default::default();
                for t in &patch.mesh.triangles {
                    for e in 0..3 {
                        let (a, b) = (t[e], t[(e + 1) % 3]);
                        *uses.entry((a.min(b), a.max(b))).or_default() += 1;
                    }
                }
                let mut open = vec![false; patch.locked.len()];
                for ((a, b), n) in uses {
                    if n == 1 {
                        (open[a as usize], open[b as usize]) = (true, true);
                    }
                }
                assert_eq!(open, patch.locked, "seed {seed}, blocks of {size}");
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

    /// The estimate of a block's faces follows their count: within 30% of it for the blocks
    /// with many faces of a ball, 10% over all, and none for a block the surface misses.
    #[test]
    fn the_faces_estimate_follows_the_faces() {
        let dims = [96, 90, 84];
        let cls = crate::mesh::classify::test_support::ball(dims, [47.3, 44.1, 41.7], 38.2);
        let (mut estimated, mut counted) = (0, 0);
        for b in blocks(dims.map(|x| x as usize), 32) {
            let faces = extract_block(&cls, &b).mesh.triangles.len() / 2;
            let guess = faces_estimate(&cls, &b);
            if faces == 0 {
                assert_eq!(guess, 0, "{b:?}");
            } else if faces >= 1000 {
                let ratio = guess as f64 / faces as f64;
                assert!((0.7..1.3).contains(&ratio), "{b:?}: {guess} for {faces}");
            }
            (estimated, counted) = (estimated + guess, counted + faces);
        }
        let ratio = estimated as f64 / counted as f64;
        assert!((0.9..1.1).contains(&ratio), "{estimated} for {counted}");
    }

    /// Flat walls across y and z are counted wherever they lie: a box with its faces on planes
    /// off every lattice of 2 or 4 is estimated within 15% in each block it crosses.
    #[test]
    fn the_faces_estimate_sees_flat_walls_anywhere() {
        let dims = [64, 64, 64];
        for (lo, hi) in [([3, 5, 6], [57, 59, 61]), ([9, 13, 7], [55, 43, 51])] {
            let inside = |v: [usize; 3]| (0..3).all(|a| (lo[a]..hi[a]).contains(&v[a]));
            let cls = crate::mesh::classify::test_support::from_voxels(dims, inside);
            for b in blocks(dims.map(|x| x as usize), 32) {
                let faces = extract_block(&cls, &b).mesh.triangles.len() / 2;
                let guess = faces_estimate(&cls, &b);
                if faces == 0 {
                    assert_eq!(guess, 0, "{b:?}");
                    continue;
                }
                let ratio = guess as f64 / faces as f64;
                assert!((0.85..1.15).contains(&ratio), "{b:?}: {guess} for {faces}");
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
