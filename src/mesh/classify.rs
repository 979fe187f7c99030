//! Voxel classification by condition ⋆ (paper section 4), streamed slab by slab.
//!
//! Voxel (i, j, k) is inside when its centre (i+½, j+½, k+½) lies in [D⁻, D⁺] of the pixel of
//! each axis image whose ray passes through it. Each pixel's condition is a range of whole voxel
//! indices along its ray, computed exactly once: D⁻ <= i + ½ iff i >= ceil(D⁻ - ½), evaluated
//! in f64 where D⁻ - ½ is exact for any f32 D⁻ below 2^28. So classification never rounds.
//! Memory: three n² tables of index ranges; the n³ grid is never allocated.
//!
//! Every outside voxel is joined to the grid's border by a straight row of outside voxels (the
//! axis whose condition it fails), so the inside set has no enclosed voids: concavities that
//! no axis sees are filled, and no inner shells arise. [`Classifier::carve`] takes out what a
//! flood from outside reaches without crossing the rendered offset (`mesh::flood`): then
//! concavities are kept open wherever the flood gets in, seen by an axis or not.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::depth::{DepthImage, DepthImages};
use crate::voxels::VoxelBits;

/// How voxels are classified.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// `flood` when every part of the generator is closed, else `axes` (the default).
    #[default]
    Auto,
    /// Condition ⋆ less the flood from outside (`mesh::flood`): no blind spots. On an open part
    /// the flood may enter through a hole wider than the offset and hollow the result out (it
    /// still holds every point the part's surface touches).
    Flood,
    /// Condition ⋆ alone (the paper's): concavities no axis looks into are filled.
    Axes,
}

impl Method {
    pub fn name(self) -> &'static str {
        match self {
            Method::Auto => "auto",
            Method::Flood => "flood",
            Method::Axes => "axes",
        }
    }
}

/// Inclusive ranges [lo, hi] of voxel indices along each pixel's ray (lo > hi: empty).
struct RangeImage {
    width: usize,
    lo: Vec<i32>,
    hi: Vec<i32>,
}

impl RangeImage {
    fn new(img: &DepthImage) -> Self {
        let n = img.min.len();
        let (mut lo, mut hi) = (vec![1; n], vec![0; n]);
        for row_from_bottom in 0..img.height {
            for col in 0..img.width {
                let src = img.index(col, row_from_bottom);
                let dst = row_from_bottom as usize * img.width as usize + col as usize;
                if !img.is_empty_at(src) {
                    let a = (img.min[src] as f64 - 0.5).ceil();
                    let b = (img.max[src] as f64 - 0.5).floor();
                    lo[dst] = a.clamp(-1.0, i32::MAX as f64) as i32;
                    hi[dst] = b.clamp(-1.0, i32::MAX as f64) as i32;
                }
            }
        }
        RangeImage {
            width: img.width as usize,
            lo,
            hi,
        }
    }

    /// The inside range along the ray through (col, row_from_bottom), both possibly outside
    /// the image (then empty), cut to the grid's `n` voxels along the ray: both ends in
    /// [-1, n], so callers may shift them by grid offsets without overflow (a depth of 2^31
    /// voxels or more is stored as i32::MAX).
    fn range(&self, col: isize, row_from_bottom: isize, rows: usize, n: usize) -> (i32, i32) {
        let outside = |x: isize, len: usize| x < 0 || x as usize >= len;
        if outside(col, self.width) || outside(row_from_bottom, rows) {
            return (1, 0);
        }
        let i = row_from_bottom as usize * self.width + col as usize;
        (
            self.lo[i].clamp(0, n as i32),
            self.hi[i].clamp(-1, n as i32 - 1),
        )
    }

    /// Whether index `t` along the ray through (col, row_from_bottom) is inside.
    fn contains(&self, col: usize, row_from_bottom: usize, t: usize) -> bool {
        let i = row_from_bottom * self.width + col;
        let t = t as i32;
        self.lo[i] <= t && t <= self.hi[i]
    }
}

/// A set of voxels on an nx × ny × nz grid, read voxel by voxel or one z-slab at a time.
pub trait VoxelSet: Sync {
    fn dims(&self) -> [usize; 3];
    /// Whether voxel (i, j, k) is in the set; false outside the grid.
    fn inside(&self, i: isize, j: isize, k: isize) -> bool;
    /// Fill `out` with the voxels of the box [lo, hi) (index ((k - lo₂)·dy + j - lo₁)·dx + i - lo₀,
    /// d = hi - lo); voxels outside the grid are false.
    fn fill_box(&self, lo: [isize; 3], hi: [isize; 3], out: &mut [bool]) {
        fill_box_voxel_by_voxel(self, lo, hi, out)
    }

    /// Row (j, k) along x as bits (voxel i at bit i % 64 of word i / 64, none past nx), where
    /// the set holds its rows so; None where it does not (then read it by [`Self::slab`]).
    fn row_bits(&self, _j: usize, _k: usize) -> Option<&[u64]> {
        None
    }

    /// Fill `slab` (nx·ny, index j·nx + i) with the voxels of z-slab `k`; all false when `k` is
    /// outside the grid.
    fn slab(&self, k: isize, slab: &mut [bool]) {
        let [nx, ny, _] = self.dims();
        debug_assert_eq!(slab.len(), nx * ny);
        for j in 0..ny {
            for i in 0..nx {
                slab[j * nx + i] = self.inside(i as isize, j as isize, k);
            }
        }
    }
}

/// [`VoxelSet::fill_box`] by single voxels.
fn fill_box_voxel_by_voxel<S: VoxelSet + ?Sized>(
    set: &S,
    lo: [isize; 3],
    hi: [isize; 3],
    out: &mut [bool],
) {
    let d = [0, 1, 2].map(|a| (hi[a] - lo[a]).max(0) as usize);
    debug_assert_eq!(out.len(), d[0] * d[1] * d[2]);
    let mut at = 0;
    for k in lo[2]..hi[2] {
        for j in lo[1]..hi[1] {
            for i in lo[0]..hi[0] {
                out[at] = set.inside(i, j, k);
                at += 1;
            }
        }
    }
}

/// The inside/outside classification of a whole grid, queried slab by slab.
pub struct Classifier {
    pub dims: [usize; 3],
    /// Ranges along x (image columns z, rows y), along y (columns x, rows z), along z
    /// (columns x, rows y): see `depth::COLUMN_AXIS` / `ROW_AXIS`.
    x: RangeImage,
    y: RangeImage,
    z: RangeImage,
    /// Voxels taken out of condition ⋆: reached by the flood from outside (`mesh::flood`).
    carved: Option<VoxelBits>,
    /// Every voxel's class, once [`Self::solidify`] has worked it out (the carving applied).
    solid: Option<VoxelBits>,
    /// Whether a flood carved the classification (kept when `carved` goes into `solid`).
    flooded: bool,
}

impl Classifier {
    pub fn new(images: &DepthImages) -> Self {
        let d = images.grid.dims;
        Classifier {
            dims: [d[0] as usize, d[1] as usize, d[2] as usize],
            x: RangeImage::new(&images.images[0]),
            y: RangeImage::new(&images.images[1]),
            z: RangeImage::new(&images.images[2]),
            carved: None,
            solid: None,
            flooded: false,
        }
    }

    /// Works out every voxel's class once, as one bit per voxel (rows in parallel), so that
    /// [`Self::inside`] and [`Self::block5`] read a bit instead of three ranges and the carving.
    /// The same answers; memory: nx·ny·nz / 8 bytes, the carving's bits are freed.
    pub fn solidify(mut self) -> Self {
        let [nx, ny, nz] = self.dims;
        let mut bits = VoxelBits::new(self.dims);
        let words = bits.words;
        if nx * ny * nz > 0 {
            let me = &self;
            bits.words_raw_mut()
                .par_chunks_mut(words * ny)
                .enumerate()
                .for_each_init(
                    || vec![0u64; words],
                    |local, (k, slab)| {
                        for (j, row) in slab.chunks_mut(words).enumerate() {
                            // Built aside and written once: the row's first touch is a write,
                            // so a fresh page is mapped once, not as the zero page first.
                            local.fill(0);
                            let (lo, hi) = me.x.range(k as isize, j as isize, ny, nx);
                            for i in lo.max(0)..=hi {
                                let i = i as usize;
                                let bit = me.y.contains(i, k, j) & me.z.contains(i, j, k);
                                local[i / 64] |= (bit as u64) << (i % 64);
                            }
                            if let Some(c) = &me.carved {
                                let carved = c.row(c.row_index(j, k));
                                for (w, c) in local.iter_mut().zip(carved) {
                                    *w &= !c;
                                }
                            }
                            row.copy_from_slice(local);
                        }
                    },
                );
        }
        self.solid = Some(bits);
        self.carved = None;
        self
    }

    /// Condition ⋆ less the voxels of `flooded` (same grid): the classification with no blind
    /// spots, where the flood from outside reaches every concavity the generator leaves open.
    pub fn carve(mut self, flooded: VoxelBits) -> Self {
        assert_eq!(flooded.dims, self.dims, "the flood is of another grid");
        assert!(self.solid.is_none(), "carve before solidify");
        self.carved = Some(flooded);
        self.flooded = true;
        self
    }

    /// Whether the classification is carved by a flood (no blind spots).
    pub fn is_carved(&self) -> bool {
        self.flooded
    }

    /// Condition ⋆ for voxel (i, j, k); false outside the grid.
    pub fn inside(&self, i: isize, j: isize, k: isize) -> bool {
        let [nx, ny, nz] = self.dims;
        if i < 0 || j < 0 || k < 0 || i as usize >= nx || j as usize >= ny || k as usize >= nz {
            return false;
        }
        if let Some(solid) = &self.solid {
            return solid.get(i, j, k);
        }
        let carved = self.carved.as_ref().is_some_and(|c| c.get(i, j, k));
        let (i, j, k) = (i as usize, j as usize, k as usize);
        self.x.contains(k, j, i) && self.y.contains(i, k, j) && self.z.contains(i, j, k) && !carved
    }
}

impl Classifier {
    /// [`VoxelBits::alike_past`] for condition ⋆: how many voxels past `p` along axis `a`,
    /// stepping by `dir` (±1), have class `inside` without a break, up to `limit`.
    pub fn alike_past(
        &self,
        p: [isize; 3],
        a: usize,
        dir: isize,
        limit: usize,
        inside: bool,
    ) -> usize {
        if let Some(solid) = &self.solid {
            return solid.alike_past(p, a, dir, limit, inside);
        }
        let mut q = p;
        (0..limit)
            .find(|&t| {
                q[a] = p[a] + (t as isize + 1) * dir;
                self.inside(q[0], q[1], q[2]) != inside
            })
            .unwrap_or(limit)
    }

    /// The voxels of the 5×5×5 block with lowest corner `lo`: bit 25·dk + 5·dj + di set when
    /// voxel lo + (di, dj, dk) is inside (as [`Self::inside`]). Reads the 75 pixel ranges of
    /// the block's rays once instead of three per voxel.
    pub fn block5(&self, lo: [isize; 3]) -> u128 {
        let [nx, ny, nz] = self.dims;
        let [i0, j0, k0] = lo;
        if let Some(solid) = &self.solid {
            let mut m = 0u128;
            for dk in 0..5 {
                for dj in 0..5 {
                    let run = solid.run(i0, j0 + dj, k0 + dk, 5) as u128;
                    m |= run << (25 * dk + 5 * dj);
                }
            }
            return m;
        }
        // Ranges along x of the rays (col k, row j), along y (col i, row k), along z (col i,
        // row j), relative to the block's corner.
        let mut rx = [(0i32, 0i32); 25];
        let mut ry = [(0i32, 0i32); 25];
        let mut rz = [(0i32, 0i32); 25];
        let shift = |(a, b): (i32, i32), by: isize| (a - by as i32, b - by as i32);
        for u in 0..5 {
            for w in 0..5 {
                let (du, dw) = (u as isize, w as isize);
                // x: u = dj, w = dk; y: u = di, w = dk; z: u = di, w = dj.
                rx[5 * u + w] = shift(self.x.range(k0 + dw, j0 + du, ny, nx), i0);
                ry[5 * u + w] = shift(self.y.range(i0 + du, k0 + dw, nz, ny), j0);
                rz[5 * u + w] = shift(self.z.range(i0 + du, j0 + dw, ny, nz), k0);
            }
        }
        let within = |(a, b): (i32, i32), t: i32| a <= t && t <= b;
        let mut m = 0u128;
        for dk in 0..5 {
            for dj in 0..5 {
                for di in 0..5 {
                    if within(rx[5 * dj + dk], di as i32)
                        && within(ry[5 * di + dk], dj as i32)
                        && within(rz[5 * di + dj], dk as i32)
                    {
                        m |= 1 << (25 * dk + 5 * dj + di);
                    }
                }
            }
        }
        if let Some(c) = &self.carved {
            for bit in 0..125 {
                if m >> bit & 1 == 1 {
                    let (di, dj, dk) = (bit % 5, bit / 5 % 5, bit / 25);
                    if c.get(i0 + di, j0 + dj, k0 + dk) {
                        m &= !(1 << bit);
                    }
                }
            }
        }
        m
    }
}

impl VoxelSet for Classifier {
    fn dims(&self) -> [usize; 3] {
        self.dims
    }

    fn inside(&self, i: isize, j: isize, k: isize) -> bool {
        Classifier::inside(self, i, j, k)
    }

    fn row_bits(&self, j: usize, k: usize) -> Option<&[u64]> {
        let solid = self.solid.as_ref()?;
        Some(solid.row(solid.row_index(j, k)))
    }

    fn slab(&self, k: isize, slab: &mut [bool]) {
        let [nx, ny, _] = self.dims;
        if self.solid.is_none() {
            for j in 0..ny {
                for i in 0..nx {
                    slab[j * nx + i] = self.inside(i as isize, j as isize, k);
                }
            }
            return;
        }
        self.fill_box([0, 0, k], [nx as isize, ny as isize, k + 1], slab);
    }

    fn fill_box(&self, lo: [isize; 3], hi: [isize; 3], out: &mut [bool]) {
        let Some(solid) = &self.solid else {
            return fill_box_voxel_by_voxel(self, lo, hi, out);
        };
        let dx = (hi[0] - lo[0]).max(0) as usize;
        let mut at = 0;
        for k in lo[2]..hi[2] {
            for j in lo[1]..hi[1] {
                for i0 in (0..dx).step_by(64) {
                    let len = (dx - i0).min(64);
                    let run = solid.run(lo[0] + i0 as isize, j, k, len);
                    for t in 0..len {
                        out[at + i0 + t] = run >> t & 1 == 1;
                    }
                }
                at += dx;
            }
        }
    }
}

/// A voxel set stored voxel by voxel: for tests of the mesh stages on arbitrary sets (pinches
/// included), which condition ⋆ cannot express. Memory: one byte per voxel.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DenseSet {
    pub dims: [usize; 3],
    /// Index (k·ny + j)·nx + i.
    pub cells: Vec<bool>,
}

impl DenseSet {
    /// The empty set on an nx × ny × nz grid.
    pub fn new(dims: [usize; 3]) -> Self {
        DenseSet {
            dims,
            cells: vec![false; dims[0] * dims[1] * dims[2]],
        }
    }

    /// The set of the listed voxels.
    pub fn from_list(dims: [usize; 3], voxels: &[[usize; 3]]) -> Self {
        let mut set = DenseSet::new(dims);
        for &v in voxels {
            set.insert(v);
        }
        set
    }

    /// A copy of any voxel set.
    pub fn copy_of(set: &dyn VoxelSet) -> Self {
        let dims = set.dims();
        let mut out = DenseSet::new(dims);
        let plane = dims[0] * dims[1];
        for k in 0..dims[2] {
            set.slab(k as isize, &mut out.cells[k * plane..(k + 1) * plane]);
        }
        out
    }

    pub fn insert(&mut self, [i, j, k]: [usize; 3]) {
        let [nx, ny, _] = self.dims;
        self.cells[(k * ny + j) * nx + i] = true;
    }

    /// How many voxels are in the set.
    pub fn len(&self) -> usize {
        self.cells.iter().filter(|&&c| c).count()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

impl VoxelSet for DenseSet {
    fn dims(&self) -> [usize; 3] {
        self.dims
    }

    fn inside(&self, i: isize, j: isize, k: isize) -> bool {
        let [nx, ny, nz] = self.dims;
        let within = |x: isize, n: usize| x >= 0 && (x as usize) < n;
        within(i, nx)
            && within(j, ny)
            && within(k, nz)
            && self.cells[(k as usize * ny + j as usize) * nx + i as usize]
    }
}

/// Voxel sets for unit tests of the mesh stages.
#[cfg(test)]
pub(crate) mod test_support {
    use super::Classifier;
    use crate::depth::{DepthImages, COLUMN_AXIS, ROW_AXIS};
    use crate::input::grid::Grid;

    /// A classifier (unit voxels, origin 0) from each pixel's depth range: `range(axis, u, v)`
    /// for the pixel centre at (u, v) along the image's column and row axes.
    pub fn from_ranges(
        dims: [u32; 3],
        range: impl Fn(usize, f32, f32) -> Option<(f32, f32)>,
    ) -> Classifier {
        let grid = Grid {
            origin: [0.0; 3],
            h: 1.0,
            dims,
        };
        let mut images = DepthImages::empty(grid);
        for img in images.images.iter_mut() {
            for rb in 0..img.height {
                for col in 0..img.width {
                    if let Some((lo, hi)) = range(img.axis, col as f32 + 0.5, rb as f32 + 0.5) {
                        let i = img.index(col, rb);
                        (img.min[i], img.max[i]) = (lo, hi);
                    }
                }
            }
        }
        Classifier::new(&images)
    }

    /// A classifier whose inside set is the box of voxels [lo, hi): every ray through the box's
    /// footprint gets the box's range, slightly inset.
    pub fn boxed(dims: [u32; 3], lo: [f32; 3], hi: [f32; 3]) -> Classifier {
        from_ranges(dims, |a, u, v| {
            let (cu, rv) = (COLUMN_AXIS[a], ROW_AXIS[a]);
            (u > lo[cu] && u < hi[cu] && v > lo[rv] && v < hi[rv])
                .then_some((lo[a] + 0.1, hi[a] - 0.1))
        })
    }

    /// The voxels of `dims` whose centres lie in the ball of radius `r` about `c` (the depth
    /// images of a sphere).
    pub fn ball(dims: [u32; 3], c: [f32; 3], r: f32) -> Classifier {
        from_ranges(dims, |a, u, v| {
            let (cu, rv) = (COLUMN_AXIS[a], ROW_AXIS[a]);
            let d2 = (u - c[cu]).powi(2) + (v - c[rv]).powi(2);
            (d2 < r * r).then(|| {
                let half = (r * r - d2).sqrt();
                (c[a] - half, c[a] + half)
            })
        })
    }

    /// A classifier (unit voxels, origin 0) whose inside voxels are those `inside` names: any
    /// voxel set, not only what depth images can describe.
    pub fn from_voxels(dims: [u32; 3], inside: impl Fn([usize; 3]) -> bool) -> Classifier {
        let grid = Grid {
            origin: [0.0; 3],
            h: 1.0,
            dims,
        };
        let mut cls = Classifier::new(&DepthImages::empty(grid));
        let mut bits = crate::voxels::VoxelBits::new(cls.dims);
        let [nx, ny, nz] = cls.dims;
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    if inside([i, j, k]) {
                        bits.set(i, j, k);
                    }
                }
            }
        }
        cls.solid = Some(bits);
        cls
    }

    /// A classifier whose pixels get random depth ranges around the middle 60% of each axis
    /// (one in a hundred none): the inside set is a rough block with deep parts, tunnels and many
    /// concavities, random but reproducible from `seed`.
    pub fn random(dims: [u32; 3], seed: u64) -> Classifier {
        let grid = Grid {
            origin: [0.0; 3],
            h: 1.0,
            dims,
        };
        let mut rng = fastrand::Rng::with_seed(seed);
        let mut unit = move || rng.f32();
        let mut images = DepthImages::empty(grid);
        for img in images.images.iter_mut() {
            let n = dims[img.axis] as f32;
            for i in 0..img.min.len() {
                if unit() < 0.99 {
                    img.min[i] = n * 0.2 + 2.0 * unit();
                    img.max[i] = n * 0.8 - 2.0 * unit();
                }
            }
        }
        Classifier::new(&images)
    }
}

#[cfg(test)]
mod tests {
    use super::test_support::from_ranges;
    use super::Classifier;
    use crate::voxels::VoxelBits;

    /// `block5` agrees with `inside` voxel by voxel, on random ranges that run past the grid's
    /// ends and blocks that hang over every face and corner of it.
    #[test]
    fn blocks_agree_with_single_voxels() {
        let mut rng = fastrand::Rng::with_seed(0x2545_f491_4f6c_dd1d);
        let mut unit = move || rng.f32();
        let dims = [7, 6, 5];
        // Some rays' ranges start or end beyond 2^31 voxels (stored as i32::MAX).
        let ranges: Vec<Option<(f32, f32)>> = (0..3 * 64)
            .map(|_| {
                let a = unit() * 5.0 - 2.0;
                let far = unit() < 0.1;
                let b = if far { 1e30 } else { a + 2.0 + unit() * 6.0 };
                let a = if far && unit() < 0.5 { 1e30 } else { a };
                (unit() < 0.95).then_some((a, b))
            })
            .collect();
        let cls = from_ranges(dims, |axis, u, v| {
            ranges[64 * axis + 8 * (u as usize) + v as usize]
        });
        let before = blocks_agree(&cls);
        assert!(
            before.0 > 3000 && before.1 > 3000,
            "{} inside, {} outside",
            before.0,
            before.1
        );
        // Carved by a random flood: the blocks leave out exactly the carved voxels too.
        let mut flooded = VoxelBits::new([7, 6, 5]);
        let mut rng = fastrand::Rng::with_seed(5);
        for k in 0..5 {
            for j in 0..6 {
                for i in 0..7 {
                    if rng.bool() {
                        flooded.set(i, j, k);
                    }
                }
            }
        }
        let carved = cls.carve(flooded.clone());
        assert!(carved.is_carved());
        let after = blocks_agree(&carved);
        // Worked out as bits: the same voxels and blocks.
        let plain = from_ranges(dims, |axis, u, v| {
            ranges[64 * axis + 8 * (u as usize) + v as usize]
        })
        .carve(flooded.clone());
        let solid = plain.solidify();
        assert!(solid.is_carved());
        assert_eq!(blocks_agree(&solid), after);
        for k in -2..7 {
            for j in -2..8 {
                for i in -2..9 {
                    assert_eq!(solid.inside(i, j, k), carved.inside(i, j, k), "{i},{j},{k}");
                }
            }
        }
        // Runs along each axis: by strides on the bits, voxel by voxel on the ranges.
        for (t, p) in [[-2, 0, 3], [3, 2, 1], [8, 5, 6], [1, -1, 2], [6, 3, 0]]
            .iter()
            .enumerate()
        {
            for a in 0..3 {
                for (dir, value) in [(1, true), (1, false), (-1, true), (-1, false)] {
                    let limit = 2 + 3 * t;
                    assert_eq!(
                        solid.alike_past(*p, a, dir, limit, value),
                        carved.alike_past(*p, a, dir, limit, value),
                        "{p:?} axis {a} dir {dir} {value}"
                    );
                }
            }
        }
        assert!(after.0 < before.0 && after.0 > 0, "{after:?} vs {before:?}");
        for k in 0..5 {
            for j in 0..6 {
                for i in 0..7 {
                    if flooded.get(i, j, k) {
                        assert!(!carved.inside(i, j, k));
                    }
                }
            }
        }
    }

    /// Checks `block5` against `inside` on blocks over and around the grid; (inside, outside).
    fn blocks_agree(cls: &Classifier) -> (usize, usize) {
        let (mut inside, mut outside) = (0, 0);
        for k0 in -5..7 {
            for j0 in -5..8 {
                for i0 in -5..9 {
                    let block = cls.block5([i0, j0, k0]);
                    for n in 0..125 {
                        let (di, dj, dk) = (n % 5, n / 5 % 5, n / 25);
                        let want = cls.inside(i0 + di, j0 + dj, k0 + dk);
                        assert_eq!(block >> n & 1 == 1, want, "block {i0},{j0},{k0} bit {n}");
                        if want {
                            inside += 1;
                        } else {
                            outside += 1;
                        }
                    }
                }
            }
        }
        (inside, outside)
    }
}
