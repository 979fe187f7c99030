//! Joins voxels so that the boundary of the inside set is a closed 2-manifold
//! (docs/design.md, "A 2-manifold start mesh").
//!
//! The boundary of a union of voxels is a disk around a lattice vertex exactly when the faces
//! at the vertex form one cycle in its link ([`DISK`]). Where two inside voxels touch only along
//! an edge (or two outside ones do), that edge has four faces; where they touch only at a corner,
//! the vertex has two fans. At each such vertex the fewest outside voxels of its 2×2×2 block
//! that make it a disk become inside, and the corners of every voxel added are checked again,
//! until no vertex is left. Voxels are only ever added, so everything the plain voxel boundary
//! enclosed stays enclosed; how far an added voxel reaches from the original inside voxels
//! ([`Joined::reach`]) enters the Hausdorff bound.
//!
//! Cost: one streamed pass over the grid (two slabs in memory) finds the pinched vertices;
//! the join itself touches only their neighbourhoods.

use std::collections::{HashSet, VecDeque};

use rayon::prelude::*;

use crate::mesh::classify::VoxelSet;

/// Cell `b` of a vertex's 2×2×2 block is voxel vertex + (b & 1, b >> 1 & 1, b >> 2 & 1) - 1.
const fn cell_offset(b: usize) -> [isize; 3] {
    [
        (b & 1) as isize - 1,
        (b >> 1 & 1) as isize - 1,
        (b >> 2) as isize - 1,
    ]
}

/// Whether the boundary of the block's inside cells (bit b: cell b inside) is empty or one disk
/// at the block's centre vertex. The link of the vertex has the six half-edges along ±x, ±y,
/// ±z as nodes and one arc per boundary face (cells b and b ^ (1 << k) of different classes):
/// the face lies in the plane across axis k, between the half-edges along the other two axes
/// on the sides of b. A disk is a link whose nodes all have degree 0 or 2 and whose arcs form
/// one cycle.
const fn is_disk(config: u8) -> bool {
    // adj[n]: neighbour bits of half-edge node n = 2·axis + side.
    let mut adj = [0u8; 6];
    let mut b = 0;
    while b < 8 {
        let mut k = 0;
        while k < 3 {
            let other = b ^ (1 << k);
            let differs = (config >> b & 1) != (config >> other & 1);
            if b < other && differs {
                let (i, j) = ((k + 1) % 3, (k + 2) % 3);
                let ni = 2 * i + (b >> i & 1);
                let nj = 2 * j + (b >> j & 1);
                adj[ni] |= 1 << nj;
                adj[nj] |= 1 << ni;
            }
            k += 1;
        }
        b += 1;
    }
    let mut used = 0u8;
    let mut n = 0;
    while n < 6 {
        match adj[n].count_ones() {
            0 => {}
            2 => used |= 1 << n,
            _ => return false,
        }
        n += 1;
    }
    if used == 0 {
        return true;
    }
    // One cycle: everything used is reached from the lowest used node.
    let mut reached = used & used.wrapping_neg();
    loop {
        let mut grown = reached;
        let mut n = 0;
        while n < 6 {
            if reached >> n & 1 == 1 {
                grown |= adj[n];
            }
            n += 1;
        }
        if grown == reached {
            return reached == used;
        }
        reached = grown;
    }
}

/// `is_disk` for every configuration of a vertex's block.
pub const DISK: [bool; 256] = {
    let mut t = [false; 256];
    let mut c = 0;
    while c < 256 {
        t[c] = is_disk(c as u8);
        c += 1;
    }
    t
};

/// The configuration of the block around lattice vertex `v` in `set`.
fn block(set: &dyn VoxelSet, v: [isize; 3]) -> u8 {
    (0..8).fold(0u8, |m, b| {
        let o = cell_offset(b);
        let inside = set.inside(v[0] + o[0], v[1] + o[1], v[2] + o[2]);
        m | (inside as u8) << b
    })
}

/// One z-slab as bit rows with a cleared border: bit c + 1 of row r + 1 is cell (c, r), so the
/// cells just outside the grid read as outside.
struct BitSlab {
    words: usize,
    bits: Vec<u64>,
}

impl BitSlab {
    fn new(nx: usize, ny: usize) -> Self {
        let words = (nx + 2).div_ceil(64);
        BitSlab {
            words,
            bits: vec![0; words * (ny + 2)],
        }
    }

    /// z-slab `k` of `set`: its bit rows shifted by the border's bit where it has them
    /// ([`VoxelSet::row_bits`]), else through `scratch` (nx·ny bools).
    fn read(&mut self, set: &dyn VoxelSet, k: isize, scratch: &mut [bool]) {
        let [nx, ny, nz] = set.dims();
        let in_grid = (0..nz as isize).contains(&k) && ny > 0;
        if !in_grid || set.row_bits(0, k as usize).is_none() {
            set.slab(k, scratch);
            return self.fill(scratch, nx);
        }
        self.bits.fill(0);
        for j in 0..ny {
            let row = set
                .row_bits(j, k as usize)
                .expect("a set has bit rows or none");
            let at = (j + 1) * self.words;
            for (w, &x) in row.iter().enumerate() {
                self.bits[at + w] |= x << 1;
                if x >> 63 != 0 {
                    self.bits[at + w + 1] |= x >> 63;
                }
            }
        }
    }

    fn fill(&mut self, slab: &[bool], nx: usize) {
        self.bits.fill(0);
        for (j, row) in slab.chunks_exact(nx.max(1)).enumerate() {
            let at = (j + 1) * self.words;
            for (i, _) in row.iter().enumerate().filter(|(_, &c)| c) {
                self.bits[at + (i + 1) / 64] |= 1 << ((i + 1) % 64);
            }
        }
    }

    /// Padded cell (column, row).
    fn get(&self, col: usize, row: usize) -> bool {
        self.bits[row * self.words + col / 64] >> (col % 64) & 1 == 1
    }
}

/// The lattice vertices (corners of voxels, 0..=n per axis) where `set`'s boundary is not a
/// disk, in scan order (z, then y, then x). Streams the set slab by slab; 64 vertices at a time
/// are skipped where their blocks are all one class, so only the boundary's vertices are looked
/// at one by one.
pub fn pinched_vertices(set: &dyn VoxelSet) -> Vec<[isize; 3]> {
    /// Vertex planes per parallel task (each reads one slab more than it scans).
    const PLANES: usize = 16;
    let nz = set.dims()[2];
    let starts: Vec<usize> = (0..=nz).step_by(PLANES).collect();
    let parts: Vec<Vec<[isize; 3]>> = starts
        .par_iter()
        .map(|&k0| pinched_in(set, k0..(k0 + PLANES).min(nz + 1)))
        .collect();
    parts.concat()
}

/// [`pinched_vertices`] on the vertex planes `planes`, in scan order.
fn pinched_in(set: &dyn VoxelSet, planes: std::ops::Range<usize>) -> Vec<[isize; 3]> {
    let [nx, ny, _] = set.dims();
    let mut slab = vec![false; nx * ny];
    let (mut below, mut here) = (BitSlab::new(nx, ny), BitSlab::new(nx, ny));
    // The slab below the first plane (all outside below the grid).
    below.read(set, planes.start as isize - 1, &mut slab);
    let words = below.words;
    let mut out = Vec::new();
    for k in planes {
        here.read(set, k as isize, &mut slab);
        // Vertex (i, j) of plane k: padded columns i, i + 1 and rows j, j + 1 of both slabs.
        for j in 0..=ny {
            let word =
                |s: &BitSlab, r: usize, w: usize| s.bits.get(r * words + w).copied().unwrap_or(0);
            for w in 0..words {
                let cells = |w: usize| {
                    let rows = [
                        word(&below, j, w),
                        word(&below, j + 1, w),
                        word(&here, j, w),
                        word(&here, j + 1, w),
                    ];
                    let or = rows.iter().fold(0, |a, r| a | r);
                    let and = rows.iter().fold(!0, |a, r| a & r);
                    (or, and)
                };
                let (or, and) = cells(w);
                let (or_next, and_next) = if w + 1 < words { cells(w + 1) } else { (0, 0) };
                // Column c mixed: its four cells differ. Vertex p mixed: column p or p + 1 is,
                // or the two columns differ.
                let mixed = or ^ and;
                let next = |x: u64, x_next: u64| x >> 1 | x_next << 63;
                let mut candidates =
                    mixed | next(mixed, or_next ^ and_next) | (and ^ next(and, and_next));
                while candidates != 0 {
                    let i = w * 64 + candidates.trailing_zeros() as usize;
                    candidates &= candidates - 1;
                    if i > nx {
                        break;
                    }
                    let mut config = 0u8;
                    for b in 0..8 {
                        let s = if b >> 2 == 0 { &below } else { &here };
                        config |= (s.get(i + (b & 1), j + (b >> 1 & 1)) as u8) << b;
                    }
                    if !DISK[config as usize] {
                        out.push([i as isize, j as isize, k as isize]);
                    }
                }
            }
        }
        std::mem::swap(&mut below, &mut here);
    }
    out
}

/// A voxel set with the voxels added that make its boundary a 2-manifold.
pub struct Joined<'a> {
    base: &'a dyn VoxelSet,
    added: HashSet<[isize; 3]>,
    /// `added`, sorted by (k, j, i), for slabs.
    sorted: Vec<[isize; 3]>,
}

impl<'a> Joined<'a> {
    /// Join `base` at every pinched vertex. Deterministic: vertices are fixed in scan order,
    /// then in the order their neighbourhoods changed.
    pub fn new(base: &'a dyn VoxelSet) -> Self {
        let mut joined = Joined {
            base,
            added: HashSet::new(),
            sorted: Vec::new(),
        };
        let mut queue: VecDeque<[isize; 3]> = pinched_vertices(base).into();
        let mut queued: HashSet<[isize; 3]> = queue.iter().copied().collect();
        while let Some(v) = queue.pop_front() {
            queued.remove(&v);
            for cell in joined.fix(v) {
                // The blocks of the added cell's eight corners changed.
                for b in 0..8 {
                    let o = cell_offset(b);
                    let corner = [cell[0] - o[0], cell[1] - o[1], cell[2] - o[2]];
                    if queued.insert(corner) {
                        queue.push_back(corner);
                    }
                }
            }
        }
        joined.sorted = joined.added.iter().copied().collect();
        joined.sorted.sort_unstable_by_key(|c| [c[2], c[1], c[0]]);
        joined
    }

    /// Make vertex `v` a disk by adding the fewest outside cells of its block that lie in the
    /// grid; among those, the fewest added cells without an originally inside face neighbour in
    /// the block, then the lowest mask. Returns the cells added.
    fn fix(&mut self, v: [isize; 3]) -> Vec<[isize; 3]> {
        let config = block(&*self, v);
        if DISK[config as usize] {
            return Vec::new();
        }
        let [nx, ny, nz] = self.base.dims();
        let cell = |b: usize| {
            let o = cell_offset(b);
            [v[0] + o[0], v[1] + o[1], v[2] + o[2]]
        };
        let in_grid =
            |c: [isize; 3]| (0..3).all(|a| c[a] >= 0 && (c[a] as usize) < [nx, ny, nz][a]);
        let original = block(self.base, v);
        let free = (0..8)
            .filter(|&b| config >> b & 1 == 0 && in_grid(cell(b)))
            .fold(0u8, |m, b| m | 1 << b);
        let lonely = |m: u8| {
            (0..8)
                .filter(|&b| m >> b & 1 == 1)
                .filter(|&b| (0..3).all(|k| original >> (b ^ 1 << k) & 1 == 0))
                .count()
        };
        // The whole block's grid cells inside is always a disk (a full block, half, quarter or
        // eighth of one), so some subset of `free` works.
        let best = (1..=255u8)
            .filter(|&m| m & !free == 0 && DISK[(config | m) as usize])
            .min_by_key(|&m| (m.count_ones(), lonely(m), m))
            .expect("filling a block's grid cells always makes its vertex a disk");
        let cells: Vec<[isize; 3]> = (0..8).filter(|&b| best >> b & 1 == 1).map(cell).collect();
        self.added.extend(cells.iter().copied());
        cells
    }

    /// The voxels added, sorted by (k, j, i).
    pub fn added(&self) -> &[[isize; 3]] {
        &self.sorted
    }

    /// How far any point of an added voxel lies from the centre of the nearest voxel of the base
    /// set, in voxels (0 when none was added). A point of added voxel a is at most
    /// √(Σ (|a - o| + ½)²) from the centre of base voxel o (per axis, a's farther face); the
    /// reach is the largest over added voxels of the smallest over base voxels. For an added
    /// voxel sharing a face with a base voxel it is √11/2 ≈ 1.658.
    pub fn reach(&self) -> f64 {
        let metric = |d: [isize; 3]| {
            d.map(|x| (x.abs() as f64 + 0.5).powi(2))
                .iter()
                .sum::<f64>()
        };
        let mut worst: f64 = 0.0;
        for a in &self.sorted {
            // Grow the search cube until no base voxel beyond it can beat the best found: one at
            // Chebyshev distance r + 1 has metric at least (r + 1.5)² + ½.
            let mut best = f64::INFINITY;
            for r in 1isize.. {
                for dk in -r..=r {
                    for dj in -r..=r {
                        for di in -r..=r {
                            let m = metric([di, dj, dk]);
                            if m < best && self.base.inside(a[0] + di, a[1] + dj, a[2] + dk) {
                                best = m;
                            }
                        }
                    }
                }
                let everywhere = self.base.dims().iter().all(|&n| r as usize > n);
                if best <= (r as f64 + 1.5).powi(2) + 0.5 || everywhere {
                    break;
                }
            }
            worst = worst.max(best.sqrt());
        }
        worst
    }
}

impl VoxelSet for Joined<'_> {
    fn dims(&self) -> [usize; 3] {
        self.base.dims()
    }

    fn inside(&self, i: isize, j: isize, k: isize) -> bool {
        self.base.inside(i, j, k) || self.added.contains(&[i, j, k])
    }

    fn fill_box(&self, lo: [isize; 3], hi: [isize; 3], out: &mut [bool]) {
        self.base.fill_box(lo, hi, out);
        let d = [0, 1, 2].map(|a| (hi[a] - lo[a]).max(0));
        let from = self.sorted.partition_point(|c| c[2] < lo[2]);
        for c in self.sorted[from..].iter().take_while(|c| c[2] < hi[2]) {
            if (0..2).all(|a| c[a] >= lo[a] && c[a] < hi[a]) {
                let at = ((c[2] - lo[2]) * d[1] + c[1] - lo[1]) * d[0] + c[0] - lo[0];
                out[at as usize] = true;
            }
        }
    }

    fn slab(&self, k: isize, slab: &mut [bool]) {
        self.base.slab(k, slab);
        let nx = self.base.dims()[0];
        let from = self.sorted.partition_point(|c| c[2] < k);
        for c in self.sorted[from..].iter().take_while(|c| c[2] == k) {
            slab[c[1] as usize * nx + c[0] as usize] = true;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::classify::DenseSet;
    use crate::mesh::extract::extract;

    /// The table agrees with an independent test of the extracted mesh (every edge two
    /// triangles, every vertex one fan) on each of the 256 blocks, alone in a 4×4×4 grid.
    #[test]
    fn disk_table_matches_the_extracted_mesh() {
        let mut disks = 0;
        for (c, &disk) in DISK.iter().enumerate() {
            let cells: Vec<[usize; 3]> = (0..8)
                .filter(|b| c >> b & 1 == 1)
                .map(|b| [1 + (b & 1), 1 + (b >> 1 & 1), 1 + (b >> 2)])
                .collect();
            let set = DenseSet::from_list([4, 4, 4], &cells);
            let defects = extract(&set).manifold_defects();
            assert_eq!(disk, defects.is_manifold(), "block {c:08b}: {defects:?}");
            assert_eq!(pinched_vertices(&set).is_empty(), disk, "block {c:08b}");
            disks += disk as usize;
        }
        // Exactly the blocks whose inside cells and whose outside cells are each connected
        // through shared faces (or empty): half of them.
        assert_eq!(disks, 128);
    }

    /// The streamed, word-skipping scan finds exactly the vertices a block-by-block look finds.
    #[test]
    fn the_scan_matches_vertex_by_vertex_blocks() {
        for seed in 1..=30u64 {
            // Widths across word boundaries (62..=66 padded bits and more).
            let dims = [
                60 + seed as usize % 9,
                3 + seed as usize % 4,
                2 + seed as usize % 3,
            ];
            let set = random_set(dims, [0.05, 0.3, 0.6][seed as usize % 3], seed);
            let [nx, ny, nz] = dims.map(|d| d as isize);
            let mut want = Vec::new();
            for k in 0..=nz {
                for j in 0..=ny {
                    for i in 0..=nx {
                        if !DISK[block(&set, [i, j, k]) as usize] {
                            want.push([i, j, k]);
                        }
                    }
                }
            }
            assert_eq!(pinched_vertices(&set), want, "seed {seed}");
        }
    }

    /// The scan reads a solidified classifier by its bit rows (shifted by the border's bit)
    /// and finds what it finds reading the same voxels one by one.
    #[test]
    fn bit_rows_and_voxels_give_the_same_scan() {
        for seed in 0..12u64 {
            // Widths around one and two words (x ends at word boundaries and inside words).
            let nx: u32 = [62, 63, 64, 65, 127, 128, 129, 70][seed as usize % 8];
            let dims = [nx, 5 + seed as u32 % 3, 6 + seed as u32 % 4];
            let set = crate::mesh::classify::test_support::random(dims, seed).solidify();
            assert!(
                set.row_bits(0, 0).is_some(),
                "a solidified set has bit rows"
            );
            let copy = DenseSet::copy_of(&set);
            assert!(copy.row_bits(0, 0).is_none());
            let (by_bits, by_voxels) = (pinched_vertices(&set), pinched_vertices(&copy));
            assert!(
                !by_voxels.is_empty(),
                "seed {seed}: a scan with nothing to find"
            );
            assert_eq!(by_bits, by_voxels, "seed {seed}");
        }
        // Sets that reach the grid's last column (nx a multiple of 64 carries into the padded
        // row's extra word): a box and two boxes meeting along an edge (a pinch to find).
        for nx in [63u32, 64, 65, 128] {
            let box_at = |lo: [f32; 3], hi: [f32; 3]| {
                crate::mesh::classify::test_support::boxed([nx, 6, 6], lo, hi).solidify()
            };
            let n = nx as f32;
            for set in [
                box_at([-1.0, 1.0, 1.0], [n + 1.0, 5.0, 5.0]),
                box_at([n - 3.0, 0.0, 0.0], [n + 1.0, 3.0, 3.0]),
            ] {
                let copy = DenseSet::copy_of(&set);
                assert!(
                    copy.inside(nx as isize - 1, 2, 2),
                    "nx {nx}: the last column is inside"
                );
                assert_eq!(pinched_vertices(&set), pinched_vertices(&copy), "nx {nx}");
            }
        }
    }

    /// A random voxel set, reproducible from `seed`.
    fn random_set(dims: [usize; 3], density: f64, seed: u64) -> DenseSet {
        let mut rng = fastrand::Rng::with_seed(seed);
        let mut set = DenseSet::new(dims);
        for c in set.cells.iter_mut() {
            *c = rng.f64() < density;
        }
        set
    }

    /// The farthest any point of an added voxel is from a base voxel's centre, by brute force.
    fn reach_brute_force(base: &DenseSet, added: &[[isize; 3]]) -> f64 {
        let [nx, ny, nz] = base.dims;
        let mut worst: f64 = 0.0;
        for a in added {
            let mut best = f64::INFINITY;
            for k in 0..nz as isize {
                for j in 0..ny as isize {
                    for i in 0..nx as isize {
                        if base.inside(i, j, k) {
                            let d = [a[0] - i, a[1] - j, a[2] - k];
                            let m: f64 = d.iter().map(|x| (x.abs() as f64 + 0.5).powi(2)).sum();
                            best = best.min(m.sqrt());
                        }
                    }
                }
            }
            worst = worst.max(best);
        }
        worst
    }

    fn check_joined(base: &DenseSet, must_add: bool) {
        let joined = Joined::new(base);
        let mesh = extract(&joined);
        let defects = mesh.manifold_defects();
        assert!(defects.is_manifold(), "{defects:?}");
        assert!(pinched_vertices(&joined).is_empty());
        assert!(mesh.unpaired_edges().is_empty());
        let dense = DenseSet::copy_of(&joined);
        let grown = base.cells.iter().zip(&dense.cells).all(|(b, j)| !b || *j);
        assert!(grown, "a voxel of the base set was dropped");
        assert_eq!(dense.len(), base.len() + joined.added().len());
        assert!((mesh.volume() - dense.len() as f64).abs() < 1e-9);
        for a in joined.added() {
            assert!(
                !base.inside(a[0], a[1], a[2]),
                "added {a:?} was inside already"
            );
        }
        assert!((joined.reach() - reach_brute_force(base, joined.added())).abs() < 1e-12);
        // The plain boundary of a set that needed joining is not a manifold: the check can fail.
        assert_eq!(!extract(base).manifold_defects().is_manifold(), must_add);
        assert_eq!(!joined.added().is_empty(), must_add);
    }

    #[test]
    fn voxels_touching_along_an_edge_are_joined_by_one_voxel() {
        let base = DenseSet::from_list([4, 4, 3], &[[1, 1, 1], [2, 2, 1]]);
        check_joined(&base, true);
        let joined = Joined::new(&base);
        assert_eq!(joined.added().len(), 1);
        assert!((joined.reach() - 11f64.sqrt() / 2.0).abs() < 1e-12);
    }

    #[test]
    fn voxels_touching_at_a_corner_are_joined_by_a_path_of_two() {
        let base = DenseSet::from_list([4, 4, 4], &[[1, 1, 1], [2, 2, 2]]);
        check_joined(&base, true);
        let joined = Joined::new(&base);
        assert_eq!(joined.added().len(), 2);
        assert!((joined.reach() - 11f64.sqrt() / 2.0).abs() < 1e-12);
    }

    /// Pinches against the grid's border, where some cells of a block lie outside the grid and
    /// cannot be added.
    #[test]
    fn pinches_on_the_grid_border_are_joined_inside_the_grid() {
        check_joined(
            &DenseSet::from_list([2, 2, 1], &[[0, 0, 0], [1, 1, 0]]),
            true,
        );
        check_joined(
            &DenseSet::from_list([2, 2, 2], &[[0, 0, 0], [1, 1, 1]]),
            true,
        );
        check_joined(
            &DenseSet::from_list([2, 1, 2], &[[0, 0, 1], [1, 0, 0]]),
            true,
        );
    }

    #[test]
    fn outside_voxels_touching_along_an_edge_or_corner_are_filled() {
        for holes in [
            vec![[2, 2, 2], [3, 3, 2]],
            vec![[2, 2, 2], [3, 3, 3]],
            vec![[2, 2, 2], [3, 3, 3], [2, 3, 3]],
        ] {
            let mut base = DenseSet::new([6, 6, 6]);
            for k in 1..5 {
                for j in 1..5 {
                    for i in 1..5 {
                        if !holes.contains(&[i, j, k]) {
                            base.insert([i, j, k]);
                        }
                    }
                }
            }
            check_joined(&base, true);
        }
    }

    #[test]
    fn sets_without_pinches_are_left_alone() {
        let cube = DenseSet::from_list([3, 3, 3], &[[1, 1, 1]]);
        check_joined(&cube, false);
        let bar = DenseSet::from_list([4, 3, 3], &[[1, 1, 1], [2, 1, 1]]);
        check_joined(&bar, false);
    }

    /// Random sets from sparse (many diagonal contacts) to dense, on grids whose border they
    /// touch: always a 2-manifold afterwards, never a voxel lost, the reach as stated.
    #[test]
    fn random_sets_become_manifold() {
        let mut joined_any = 0;
        for seed in 1..=60u64 {
            let density = [0.15, 0.3, 0.5, 0.7][seed as usize % 4];
            let dims = [5 + seed as usize % 4, 6, 4 + seed as usize % 3];
            let base = random_set(dims, density, seed.wrapping_mul(0x9e37_79b9_7f4a_7c15));
            let pinched = !extract(&base).manifold_defects().is_manifold();
            check_joined(&base, pinched);
            joined_any += pinched as usize;
        }
        assert!(joined_any > 40, "only {joined_any} of 60 sets had pinches");
    }
}
