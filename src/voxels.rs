//! One bit per voxel of the grid: the reach of the rendered offset (`sweep::reach`) and the
//! voxels a flood from outside carves out of condition ⋆ (`mesh::flood`).
//!
//! Layout: rows along x, row (j, k) at index k·ny + j, each row `words` u64 words, voxel i at
//! bit i % 64 of word i / 64. Memory: nx·ny·nz / 8 bytes (96 MB at 1500 × 600 × 850).

use std::hash::Hasher;
use std::sync::atomic::{AtomicU64, Ordering};

#[derive(Clone, Debug, PartialEq, Eq)]
pub struct VoxelBits {
    pub dims: [usize; 3],
    /// u64 words per row along x.
    pub words: usize,
    data: Vec<u64>,
}

impl VoxelBits {
    pub fn new(dims: [usize; 3]) -> Self {
        let words = dims[0].div_ceil(64);
        VoxelBits {
            dims,
            words,
            data: vec![0; words * dims[1] * dims[2]],
        }
    }

    /// From raw words in this layout (the GPU's read-back).
    pub fn from_words(dims: [usize; 3], data: Vec<u64>) -> Self {
        let words = dims[0].div_ceil(64);
        assert_eq!(
            data.len(),
            words * dims[1] * dims[2],
            "words for another grid"
        );
        VoxelBits { dims, words, data }
    }

    /// The words, rows along x in (j, k) order (the layout [`Self::from_words`] takes).
    pub fn words_raw(&self) -> &[u64] {
        &self.data
    }

    pub fn words_raw_mut(&mut self) -> &mut [u64] {
        &mut self.data
    }

    /// Row index of (j, k).
    pub fn row_index(&self, j: usize, k: usize) -> usize {
        k * self.dims[1] + j
    }

    pub fn row(&self, r: usize) -> &[u64] {
        &self.data[r * self.words..(r + 1) * self.words]
    }

    pub fn row_mut(&mut self, r: usize) -> &mut [u64] {
        let w = self.words;
        &mut self.data[r * w..(r + 1) * w]
    }

    /// Whether voxel (i, j, k) is set; false outside the grid.
    pub fn get(&self, i: isize, j: isize, k: isize) -> bool {
        let [nx, ny, nz] = self.dims;
        if i < 0 || j < 0 || k < 0 || i as usize >= nx || j as usize >= ny || k as usize >= nz {
            return false;
        }
        let (i, r) = (i as usize, self.row_index(j as usize, k as usize));
        self.data[r * self.words + i / 64] >> (i % 64) & 1 == 1
    }

    /// How many voxels in a row past `p` along axis `a`, stepping by `dir` (±1), read `value`
    /// (false outside the grid), up to `limit`: the t < `limit` whose voxel p + (t + 1)·dir
    /// along a is the first not `value`, else `limit`. One column read by strides, not voxel
    /// by voxel through [`Self::get`].
    pub fn alike_past(
        &self,
        p: [isize; 3],
        a: usize,
        dir: isize,
        limit: usize,
        value: bool,
    ) -> usize {
        let dims = self.dims.map(|d| d as isize);
        let off_grid = (0..3).any(|b| b != a && !(0..dims[b]).contains(&p[b]));
        if off_grid {
            return if value { 0 } else { limit };
        }
        // Word and bit of voxel p with p[a] = 0, and the step along a: one bit along x, a row of
        // words along y, a slab of rows along z.
        let mut q = p;
        q[a] = 0;
        let row = self.row_index(q[1] as usize, q[2] as usize);
        let (word, step) = match a {
            0 => (row * self.words, 0),
            1 => (row * self.words + q[0] as usize / 64, self.words),
            _ => (
                row * self.words + q[0] as usize / 64,
                self.words * self.dims[1],
            ),
        };
        let bit = |c: usize| match a {
            0 => self.data[word + c / 64] >> (c % 64) & 1 == 1,
            _ => self.data[word + c * step] >> (q[0] as usize % 64) & 1 == 1,
        };
        for t in 0..limit {
            let c = p[a] + (t as isize + 1) * dir;
            let set = (0..dims[a]).contains(&c) && bit(c as usize);
            if set != value {
                return t;
            }
            if !value && !(0..dims[a]).contains(&c) && (c < 0) == (dir < 0) {
                return limit; // off the grid for good: false from here on
            }
        }
        limit
    }

    /// Bits i0..i0 + len of row (j, k) (len <= 64; bit t of the result is voxel i0 + t), false
    /// outside the grid.
    pub fn run(&self, i0: isize, j: isize, k: isize, len: usize) -> u64 {
        let [nx, ny, nz] = self.dims;
        debug_assert!(len <= 64);
        if j < 0 || k < 0 || j as usize >= ny || k as usize >= nz || len == 0 {
            return 0;
        }
        let row = self.row(self.row_index(j as usize, k as usize));
        let (lo, hi) = (i0.max(0), (i0 + len as isize).min(nx as isize));
        if lo >= hi {
            return 0;
        }
        // Bits lo..hi of the row, shifted to start at bit lo - i0.
        let (w, b) = (lo as usize / 64, lo as usize % 64);
        let mut bits = row[w] >> b;
        if b > 0 && w + 1 < row.len() {
            bits |= row[w + 1] << (64 - b);
        }
        let n = (hi - lo) as usize;
        if n < 64 {
            bits &= (1u64 << n) - 1;
        }
        bits << (lo - i0)
    }

    pub fn set(&mut self, i: usize, j: usize, k: usize) {
        let r = self.row_index(j, k);
        self.data[r * self.words + i / 64] |= 1 << (i % 64);
    }

    /// Number of voxels set.
    pub fn count(&self) -> u64 {
        self.data.iter().map(|w| w.count_ones() as u64).sum()
    }

    /// Bytes of the bits of a grid of `dims` (rows padded to whole u64 words), without making it.
    pub fn bytes_for(dims: [usize; 3]) -> u64 {
        8 * dims[0].div_ceil(64) as u64 * dims[1] as u64 * dims[2] as u64
    }
}

/// [`VoxelBits`] that many threads set at once (bits are only ever set).
pub struct AtomicVoxelBits {
    pub dims: [usize; 3],
    words: usize,
    data: Vec<AtomicU64>,
}

impl AtomicVoxelBits {
    pub fn new(dims: [usize; 3]) -> Self {
        let words = dims[0].div_ceil(64);
        AtomicVoxelBits {
            dims,
            words,
            data: (0..words * dims[1] * dims[2])
                .map(|_| AtomicU64::new(0))
                .collect(),
        }
    }

    /// Set voxels lo..=hi of row (j, k); lo and hi are clamped to the row, nothing is set
    /// when the clamped range is empty.
    pub fn set_span(&self, j: usize, k: usize, lo: i64, hi: i64) {
        let nx = self.dims[0] as i64;
        let (lo, hi) = (lo.max(0), hi.min(nx - 1));
        if lo > hi {
            return;
        }
        let base = (k * self.dims[1] + j) * self.words;
        let (lo, hi) = (lo as usize, hi as usize);
        for w in lo / 64..=hi / 64 {
            let first = if w == lo / 64 { lo % 64 } else { 0 };
            let last = if w == hi / 64 { hi % 64 } else { 63 };
            let mask = (u64::MAX >> (63 - last)) & (u64::MAX << first);
            let word = &self.data[base + w];
            // A plain load first: most spans are already set by a neighbouring triangle.
            if word.load(Ordering::Relaxed) & mask != mask {
                word.fetch_or(mask, Ordering::Relaxed);
            }
        }
    }

    pub fn into_bits(self) -> VoxelBits {
        VoxelBits {
            dims: self.dims,
            words: self.words,
            data: self.data.into_iter().map(AtomicU64::into_inner).collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spans_set_exactly_their_voxels() {
        let mut rng = fastrand::Rng::with_seed(17);
        for _ in 0..200 {
            let nx = rng.usize(1..300);
            let bits = AtomicVoxelBits::new([nx, 3, 2]);
            let mut want = vec![false; nx];
            for _ in 0..rng.usize(0..4) {
                let lo = rng.i64(-5..nx as i64 + 5);
                let hi = rng.i64(-5..nx as i64 + 5);
                bits.set_span(2, 1, lo, hi);
                for (i, w) in want.iter_mut().enumerate() {
                    *w |= lo <= i as i64 && i as i64 <= hi;
                }
            }
            let bits = bits.into_bits();
            for (i, &w) in want.iter().enumerate() {
                assert_eq!(bits.get(i as isize, 2, 1), w, "nx {nx} i {i}");
                assert!(!bits.get(i as isize, 1, 1) && !bits.get(i as isize, 2, 0));
            }
            assert_eq!(bits.count(), want.iter().filter(|&&w| w).count() as u64);
            assert_eq!(8 * bits.data.len() as u64, VoxelBits::bytes_for([nx, 3, 2]));
            assert!(!bits.get(-1, 2, 1) && !bits.get(nx as isize, 2, 1));
        }
    }

    /// Runs read by strides are those read voxel by voxel: every axis and direction, from
    /// inside and outside the grid, on grids wider than a word and of mostly one class.
    #[test]
    fn runs_along_an_axis_are_read_as_voxel_by_voxel() {
        let mut rng = fastrand::Rng::with_seed(5);
        for _ in 0..40 {
            let dims = [rng.usize(1..150), rng.usize(1..12), rng.usize(1..12)];
            let mut bits = VoxelBits::new(dims);
            let fill = rng.f64();
            for k in 0..dims[2] {
                for j in 0..dims[1] {
                    for i in 0..dims[0] {
                        if rng.f64() < fill {
                            bits.set(i, j, k);
                        }
                    }
                }
            }
            for _ in 0..500 {
                let p = dims.map(|d| rng.isize(-3..d as isize + 3));
                let (a, dir, limit) = (rng.usize(0..3), [-1, 1][rng.usize(0..2)], rng.usize(0..40));
                let value = rng.bool();
                let by_voxel = (0..limit)
                    .find(|&t| {
                        let mut q = p;
                        q[a] += (t as isize + 1) * dir;
                        bits.get(q[0], q[1], q[2]) != value
                    })
                    .unwrap_or(limit);
                let got = bits.alike_past(p, a, dir, limit, value);
                assert_eq!(got, by_voxel, "{dims:?} {p:?} axis {a} dir {dir} {value}");
            }
        }
    }
}

/// A voxel or hash cell (each index in -2..2^21 - 2: the grid is at most 12288 voxels wide) as one
/// u64 key: i + 2, j + 2, k + 2 in 21 bits each.
pub fn pack_cell(c: [i64; 3]) -> u64 {
    (c[0] + 2) as u64 | ((c[1] + 2) as u64) << 21 | ((c[2] + 2) as u64) << 42
}

/// Multiplicative hash for packed voxel keys (the std SipHash dominated the profile).
#[derive(Default)]
pub struct KeyHasher(u64);

impl Hasher for KeyHasher {
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(b as u64);
        }
    }
    fn write_u32(&mut self, x: u32) {
        self.write_u64(x as u64);
    }
    fn write_u64(&mut self, x: u64) {
        self.0 = (self.0.rotate_left(5) ^ x).wrapping_mul(0x517c_c1b7_2722_0a95);
    }
    fn finish(&self) -> u64 {
        self.0.rotate_left(26)
    }
}
