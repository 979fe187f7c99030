//! The flood from outside: every voxel joined to the outside of the grid by a 6-connected path
//! of voxels that the rendered offset does not reach (`sweep::reach`). Condition ⋆ keeps a
//! concavity that no axis looks into; the flood finds it, so `Classifier::carve` can take it out.
//!
//! Sound: a voxel whose centre lies in the rendered offset is in the reach, so never flooded,
//! and every voxel the paper's argument needs inside stays inside. Where the generator is
//! closed, a path from outside into the part's interior crosses its surface between two
//! neighbouring voxel centres (h apart), and the nearer centre is within h/2 < δ of the
//! surface: in the reach. So the flood never enters a closed part's interior. An open part
//! lets it in through a hole wider than the reach (docs/design.md, "No blind spots").
//!
//! Rows along x are filled word by word with carries (a run of free voxels that holds a seed
//! is filled in one pass up and one pass down); a row whose flood grows queues its four
//! neighbouring rows. Memory: one bit per voxel besides the reach.

use std::collections::VecDeque;

use crate::voxels::VoxelBits;

/// Within one word: the free bits (`free`) of every run of free bits that holds a seed, from the
/// lowest seed of the run upward. `seeds` must be a subset of `free`. (Adding the seeds to
/// `free` carries through each seeded run from its lowest seed; the changed bits are the run's
/// upper part and the bit above it.)
fn fill_up(seeds: u64, free: u64) -> u64 {
    (seeds | (seeds.wrapping_add(free) ^ free)) & free
}

/// Fill the free runs of one row that hold a seed, in both directions. Returns the filled row
/// in `seeds`.
fn fill_row(seeds: &mut [u64], free: &[u64]) {
    // Upward (toward higher x), carrying across words.
    let mut carry = false;
    for (s, &f) in seeds.iter_mut().zip(free) {
        let seed = (*s | carry as u64) & f;
        *s = if seed == 0 { 0 } else { fill_up(seed, f) };
        carry = *s >> 63 == 1;
    }
    // Downward: the same on reversed bits, from the last word.
    let mut carry = false;
    for (s, &f) in seeds.iter_mut().zip(free).rev() {
        let (sr, fr) = (s.reverse_bits(), f.reverse_bits());
        let seed = (sr | carry as u64) & fr;
        let filled = if seed == 0 { 0 } else { fill_up(seed, fr) };
        *s = filled.reverse_bits();
        carry = filled >> 63 == 1;
    }
}

/// The voxels reachable from outside the grid through voxels not in `reach`.
pub fn flood(reach: &VoxelBits) -> VoxelBits {
    let [nx, ny, nz] = reach.dims;
    let words = reach.words;
    let mut out = VoxelBits::new(reach.dims);
    if nx == 0 || ny == 0 || nz == 0 {
        return out;
    }
    // Bits past nx in the last word are never free.
    let tail = if nx % 64 == 0 {
        u64::MAX
    } else {
        (1u64 << (nx % 64)) - 1
    };
    let free = |r: usize, w: usize| {
        let f = !reach.row(r)[w];
        if w + 1 == words {
            f & tail
        } else {
            f
        }
    };
    let ends = |w: usize| {
        let mut m = 0;
        if w == 0 {
            m |= 1;
        }
        if w == (nx - 1) / 64 {
            m |= 1 << ((nx - 1) % 64);
        }
        m
    };
    let rows = ny * nz;
    let mut queued = vec![true; rows];
    let mut queue: VecDeque<usize> = (0..rows).collect();
    let mut row_free = vec![0u64; words];
    let mut grown = vec![0u64; words];
    while let Some(r) = queue.pop_front() {
        queued[r] = false;
        let (j, k) = (r % ny, r / ny);
        let border = j == 0 || k == 0 || j + 1 == ny || k + 1 == nz;
        let neighbours = [
            (j > 0).then(|| r - 1),
            (j + 1 < ny).then(|| r + 1),
            (k > 0).then(|| r - ny),
            (k + 1 < nz).then(|| r + ny),
        ];
        for w in 0..words {
            row_free[w] = free(r, w);
            // Seeds: the row's own flood, the outside of the grid (a border row's every free
            // voxel, each row's two ends), and the flood of the four neighbouring rows.
            let mut s = out.row(r)[w] | if border { u64::MAX } else { ends(w) };
            for &n in neighbours.iter().flatten() {
                s |= out.row(n)[w];
            }
            grown[w] = s & row_free[w];
        }
        fill_row(&mut grown, &row_free);
        if grown.as_slice() != out.row(r) {
            out.row_mut(r).copy_from_slice(&grown);
            for n in neighbours.into_iter().flatten() {
                if !queued[n] {
                    queued[n] = true;
                    queue.push_back(n);
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The same flood, voxel by voxel (breadth-first from every free border voxel).
    fn flood_oracle(reach: &VoxelBits) -> Vec<bool> {
        let [nx, ny, nz] = reach.dims;
        let id = |i: usize, j: usize, k: usize| (k * ny + j) * nx + i;
        let free = |i: usize, j: usize, k: usize| !reach.get(i as isize, j as isize, k as isize);
        let mut seen = vec![false; nx * ny * nz];
        let mut queue = VecDeque::new();
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    let border = i == 0 || j == 0 || k == 0 || i + 1 == nx || j + 1 == ny;
                    if (border || k + 1 == nz) && free(i, j, k) {
                        seen[id(i, j, k)] = true;
                        queue.push_back([i, j, k]);
                    }
                }
            }
        }
        while let Some([i, j, k]) = queue.pop_front() {
            for (d, axis) in [(-1isize, 0usize), (1, 0), (-1, 1), (1, 1), (-1, 2), (1, 2)] {
                let mut v = [i as isize, j as isize, k as isize];
                v[axis] += d;
                let dims = [nx, ny, nz];
                if (0..3).any(|a| v[a] < 0 || v[a] as usize >= dims[a]) {
                    continue;
                }
                let [a, b, c] = v.map(|x| x as usize);
                if free(a, b, c) && !seen[id(a, b, c)] {
                    seen[id(a, b, c)] = true;
                    queue.push_back([a, b, c]);
                }
            }
        }
        seen
    }

    #[test]
    fn fill_up_fills_seeded_runs_only() {
        let mut rng = fastrand::Rng::with_seed(3);
        for _ in 0..20_000 {
            let free = rng.u64(..) & rng.u64(..).rotate_left(rng.u32(0..64));
            let seeds = free & rng.u64(..) & rng.u64(..) & rng.u64(..);
            let mut want = 0u64;
            let mut on = false;
            for b in 0..64 {
                let bit = 1u64 << b;
                on = free & bit != 0 && (on || seeds & bit != 0);
                if on {
                    want |= bit;
                }
            }
            assert_eq!(
                fill_up(seeds, free),
                want,
                "free {free:#x} seeds {seeds:#x}"
            );
        }
    }

    #[test]
    fn flood_matches_a_voxel_by_voxel_search() {
        let mut rng = fastrand::Rng::with_seed(11);
        for case in 0..300 {
            let dims = [rng.usize(1..150), rng.usize(1..9), rng.usize(1..9)];
            let mut reach = VoxelBits::new(dims);
            let density = rng.f64() * 0.7;
            for k in 0..dims[2] {
                for j in 0..dims[1] {
                    for i in 0..dims[0] {
                        if rng.f64() < density {
                            reach.set(i, j, k);
                        }
                    }
                }
            }
            let got = flood(&reach);
            let want = flood_oracle(&reach);
            for k in 0..dims[2] {
                for j in 0..dims[1] {
                    for i in 0..dims[0] {
                        let w = want[(k * dims[1] + j) * dims[0] + i];
                        let g = got.get(i as isize, j as isize, k as isize);
                        assert_eq!(g, w, "case {case} dims {dims:?} voxel {i} {j} {k}");
                    }
                }
            }
        }
    }

    #[test]
    fn a_closed_shell_keeps_its_inside() {
        // A 1-voxel shell around [3, 7)³ in a 10³ grid: nothing inside it is flooded.
        let mut reach = VoxelBits::new([10, 10, 10]);
        for k in 2..8 {
            for j in 2..8 {
                for i in 2..8 {
                    if [i, j, k].iter().any(|&x| x == 2 || x == 7) {
                        reach.set(i, j, k);
                    }
                }
            }
        }
        let f = flood(&reach);
        assert_eq!(f.count(), 1000 - 6 * 6 * 6);
        assert!(!f.get(5, 5, 5) && f.get(0, 0, 0) && f.get(9, 5, 5));
        // One hole in the shell lets the flood in.
        let mut holed = reach.clone();
        holed.row_mut(holed.row_index(5, 5))[0] &= !(1 << 7);
        assert_eq!(flood(&holed).count(), 1000 - 6 * 6 * 6 + 1 + 4 * 4 * 4);
    }
}
