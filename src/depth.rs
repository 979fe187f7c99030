//! The six depth images: the contract between the sweep and the mesh stage.
//!
//! One image per axis holds both D⁻ (`min`) and D⁺ (`max`) of every pixel: the rays of the
//! `-min` and `-max` images of an axis are the same rays. Depths are grid coordinates along
//! the axis (world = origin\[axis\] + t·h). The writers round every value outward and the mesh
//! stage compares them with voxel centres (k + ½) exactly.
//!
//! Pixel layout (also in the EXR headers): for axis a the columns run along `COLUMN_AXIS[a]`
//! and the rows along `ROW_AXIS[a]`, row 0 at the top (the high end of the row axis), so an
//! image tool shows a Y-up scene upright in the x and z views. Pixel (col, row) is the ray
//! through grid point (u, v) = (col + ½, height - 1 - row + ½).
//! An empty pixel (no offset met) has min = +inf and max = -inf.

use crate::input::grid::Grid;

/// Image-plane axes per ray axis: columns along these...
pub const COLUMN_AXIS: [usize; 3] = [2, 0, 0];
/// ...and rows along these (row 0 at the high end).
pub const ROW_AXIS: [usize; 3] = [1, 2, 1];
pub const AXIS_NAMES: [&str; 3] = ["x", "y", "z"];

#[derive(Clone, Debug, PartialEq)]
pub struct DepthImage {
    /// The ray axis: 0, 1, 2 for x, y, z.
    pub axis: usize,
    pub width: u32,
    pub height: u32,
    /// D⁻ per pixel, row-major from the top row: least grid coordinate where the ray enters.
    pub min: Vec<f32>,
    /// D⁺ per pixel: greatest grid coordinate where the ray leaves.
    pub max: Vec<f32>,
}

impl DepthImage {
    pub fn empty(grid: &Grid, axis: usize) -> Self {
        let (width, height) = image_size(grid, axis);
        let n = width as usize * height as usize;
        DepthImage {
            axis,
            width,
            height,
            min: vec![f32::INFINITY; n],
            max: vec![f32::NEG_INFINITY; n],
        }
    }

    /// Index of the pixel whose ray passes through grid point (col + ½, row_from_bottom + ½).
    pub fn index(&self, col: u32, row_from_bottom: u32) -> usize {
        (self.height - 1 - row_from_bottom) as usize * self.width as usize + col as usize
    }

    pub fn is_empty_at(&self, i: usize) -> bool {
        let (lo, hi) = (self.min[i], self.max[i]);
        lo.is_nan() || hi.is_nan() || lo > hi
    }

    pub fn hit_count(&self) -> usize {
        (0..self.min.len())
            .filter(|&i| !self.is_empty_at(i))
            .count()
    }
}

/// (width, height) of the image of `axis`.
pub fn image_size(grid: &Grid, axis: usize) -> (u32, u32) {
    (grid.dims[COLUMN_AXIS[axis]], grid.dims[ROW_AXIS[axis]])
}

/// The six depth images on their grid.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthImages {
    pub grid: Grid,
    pub images: [DepthImage; 3],
}

impl DepthImages {
    pub fn empty(grid: Grid) -> Self {
        DepthImages {
            grid,
            images: [0, 1, 2].map(|a| DepthImage::empty(&grid, a)),
        }
    }

    /// Decode images from the sweep's atomic buffers: per axis, pairs (enc(min), enc(max)) in
    /// pixel order (see [`encode`]).
    pub fn from_encoded(grid: Grid, encoded: [Vec<u32>; 3]) -> Self {
        let mut out = DepthImages::empty(grid);
        for (img, enc) in out.images.iter_mut().zip(encoded) {
            assert_eq!(enc.len(), 2 * img.min.len(), "encoded buffer size");
            for (i, pair) in enc.chunks_exact(2).enumerate() {
                img.min[i] = decode(pair[0]);
                img.max[i] = decode(pair[1]);
            }
        }
        out
    }
}

/// The sweep's encoded buffers, per image: [`SLOTS`] u32 per pixel, enc(D⁻) then enc(D⁺).
pub const SLOTS: usize = 2;
/// Encoded value an empty D⁻ slot starts at (enc(+inf)); D⁺ starts at enc(-inf).
pub const EMPTY_MIN: u32 = 0xFF80_0000;
pub const EMPTY_MAX: u32 = 0x007F_FFFF;

/// Order-preserving map from f32 to u32: a < b (as floats, no NaN) iff enc(a) < enc(b) (as u32).
/// Lets atomic min/max on u32 act as min/max on depths. Same as `encode_depth` in the shader.
pub fn encode(x: f32) -> u32 {
    let b = x.to_bits();
    if b & 0x8000_0000 != 0 {
        !b
    } else {
        b | 0x8000_0000
    }
}

/// Inverse of [`encode`].
pub fn decode(e: u32) -> f32 {
    if e & 0x8000_0000 != 0 {
        f32::from_bits(e & 0x7FFF_FFFF)
    } else {
        f32::from_bits(!e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encoding_preserves_order() {
        let xs = [
            f32::NEG_INFINITY,
            -1e30,
            -2.5,
            -1e-40,
            -0.0,
            0.0,
            1e-40,
            0.5,
            3.0,
            1e30,
            f32::INFINITY,
        ];
        for w in xs.windows(2) {
            assert!(encode(w[0]) <= encode(w[1]), "{} vs {}", w[0], w[1]);
            assert_eq!(decode(encode(w[1])).to_bits(), w[1].to_bits());
        }
    }
}
