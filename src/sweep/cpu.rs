//! CPU twin of `shaders/sweep.wgsl`: the same loops, the same f32 formulas, the same encoding
//! and atomic min/max, run on rayon threads. Keep the two in step.

use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Instant;

use rayon::prelude::*;
use wide::f32x8;

use super::offset::PreparedTriangle;
use super::{empty_encoded, Cancelled, Observer};
use crate::depth::encode;
use crate::depth::SLOTS;
use crate::depth::{DepthImages, COLUMN_AXIS, ROW_AXIS};
use crate::input::posed::SweepInput;
use crate::voxels::{AtomicVoxelBits, VoxelBits};

/// Triangles one rayon task renders under one pose.
const TRIANGLES_PER_TASK: usize = 512;
/// Target duration of one batch of poses: how often progress and cancellation are checked.
const BATCH_SECONDS: f64 = 0.25;

/// Render every posed triangle's offset into the six depth images.
pub fn sweep(input: &SweepInput, observer: &dyn Observer) -> Result<DepthImages, Cancelled> {
    render(input, observer, 3, None)
}

/// The same, and the offset's reach (`sweep::reach`) from the x axis's ray casts on the way:
/// the same bits as `reach::reach`, for a few percent more work instead of a second pass.
pub fn sweep_with_reach(
    input: &SweepInput,
    observer: &dyn Observer,
) -> Result<(DepthImages, VoxelBits), Cancelled> {
    let bits = AtomicVoxelBits::new(input.grid.dims.map(|d| d as usize));
    let images = render(input, observer, 3, Some(&bits))?;
    Ok((images, bits.into_bits()))
}

/// The reach alone: the same loop on the x axis only (`sweep::reach`).
pub(super) fn x_axis_reach(
    input: &SweepInput,
    observer: &dyn Observer,
) -> Result<VoxelBits, Cancelled> {
    let bits = AtomicVoxelBits::new(input.grid.dims.map(|d| d as usize));
    render(input, observer, 1, Some(&bits))?;
    Ok(bits.into_bits())
}

/// Render the first `axes` axes' images (1: x only, 3: all), setting `reach` from the x axis.
fn render(
    input: &SweepInput,
    observer: &dyn Observer,
    axes: usize,
    reach: Option<&AtomicVoxelBits>,
) -> Result<DepthImages, Cancelled> {
    let images: [Vec<AtomicU32>; 3] =
        empty_encoded(input).map(|v| v.into_iter().map(AtomicU32::new).collect());
    let dims = input.grid.dims;
    let total = input.posed_triangles();
    let mut done = 0u64;
    // One batch of pose matrices at a time, made on demand: the sub-poses of a motion are never
    // all in memory.
    let mut pose_batch = Vec::new();
    for (index, part) in input.parts.iter().enumerate() {
        let tris =
            &input.triangles[part.tri_start as usize..(part.tri_start + part.tri_count) as usize];
        let count = part.pose_count as u64;
        // Batches of poses sized so that each takes about BATCH_SECONDS: progress and
        // cancellation stay prompt whatever the triangles cost. Starts at ~64k posed triangles
        // and adapts to the measured rate. The result does not depend on batching (atomic
        // min/max).
        let mut batch = (65_536 / tris.len().max(1)).clamp(1, 4096);
        let mut next = 0u64;
        while next < count {
            if observer.cancelled() {
                return Err(Cancelled);
            }
            let end = count.min(next + batch as u64);
            let t0 = Instant::now();
            input.poses.fill(index, next..end, &mut pose_batch);
            next = end;
            pose_batch
                .par_iter()
                .flat_map(|m| tris.par_chunks(TRIANGLES_PER_TASK).map(move |c| (m, c)))
                .for_each(|(m, chunk)| {
                    for t in chunk {
                        let posed = pose_triangle(m, t);
                        for (axis, image) in images.iter().enumerate().take(axes) {
                            let bits = if axis == 0 { reach } else { None };
                            splat(&posed, input.radius, axis, dims, image, bits);
                        }
                    }
                });
            let secs = t0.elapsed().as_secs_f64().max(1e-6);
            let scaled = (pose_batch.len() as f64 * BATCH_SECONDS / secs) as usize;
            batch = scaled.clamp(batch / 2, batch * 2).clamp(1, 4096);
            done += (pose_batch.len() * tris.len()) as u64;
            observer.progress(done, total);
        }
    }
    let encoded = images.map(|v| v.into_iter().map(AtomicU32::into_inner).collect());
    Ok(DepthImages::from_encoded(input.grid, encoded))
}

/// Local triangle to grid units: p = M·v with M row-major 3x4 (as `pose_point` in the shader).
pub fn pose_triangle(m: &[f32; 12], t: &[f32; 9]) -> [[f32; 3]; 3] {
    let mut out = [[0f32; 3]; 3];
    for (k, p) in out.iter_mut().enumerate() {
        let (x, y, z) = (t[3 * k], t[3 * k + 1], t[3 * k + 2]);
        for (r, c) in p.iter_mut().enumerate() {
            *c = m[4 * r] * x + m[4 * r + 1] * y + m[4 * r + 2] * z + m[4 * r + 3];
        }
    }
    out
}

/// Ray-cast one posed triangle (grid units) against every pixel of the `axis` image that its
/// offset can cover, and fold the hits into the image with atomic min/max. With `reach` (x axis
/// only: its pixels are the rows of voxel centres along x), also set the voxels whose centres
/// each hit covers, as `reach::mark` does.
pub fn splat(
    p: &[[f32; 3]; 3],
    radius: f32,
    axis: usize,
    dims: [u32; 3],
    image: &[AtomicU32],
    reach: Option<&AtomicVoxelBits>,
) {
    debug_assert!(reach.is_none() || axis == 0);
    let (cu, rv) = (COLUMN_AXIS[axis], ROW_AXIS[axis]);
    let (width, height) = (dims[cu], dims[rv]);
    let Some((c0, c1)) = pixel_span(p[0][cu], p[1][cu], p[2][cu], radius, width) else {
        return;
    };
    let Some((r0, r1)) = pixel_span(p[0][rv], p[1][rv], p[2][rv], radius, height) else {
        return;
    };
    let tri = PreparedTriangle::new(p.map(|v| [v[cu], v[rv], v[axis]]), radius);
    // Eight pixels of a row at a time (bit-identical to `interval_at` per pixel, as the shader).
    let lanes = f32x8::new(std::array::from_fn(|i| i as f32));
    for row in r0..=r1 {
        let pv = row as f32 + 0.5;
        let line = SLOTS * (height - 1 - row) as usize * width as usize;
        for first in (c0..=c1).step_by(8) {
            let pu = f32x8::splat(first as f32 + 0.5) + lanes;
            let (t0, t1) = tri.interval_at_x8(pu, pv);
            let (t0, t1) = (t0.to_array(), t1.to_array());
            for k in 0..(c1 + 1 - first).min(8) as usize {
                if t0[k] <= t1[k] {
                    let i = line + SLOTS * (first as usize + k);
                    fold_min(&image[i], encode(t0[k]));
                    fold_max(&image[i + 1], encode(t1[k]));
                    if let Some(bits) = reach {
                        set_centres(bits, row as usize, first as usize + k, t0[k], t1[k]);
                    }
                }
            }
        }
    }
}

/// Set the voxels of row (j, k) along x whose centres i + ½ lie in [t0, t1] (grid units): i from
/// ⌈t0 - ½⌉ to ⌊t1 - ½⌋, exact in f64 as in `mesh::classify`.
pub fn set_centres(bits: &AtomicVoxelBits, j: usize, k: usize, t0: f32, t1: f32) {
    let clamp = |x: f64| x.clamp(-1.0, i64::MAX as f64 / 2.0) as i64;
    let lo = clamp((t0 as f64 - 0.5).ceil());
    let hi = clamp((t1 as f64 - 0.5).floor());
    bits.set_span(j, k, lo, hi);
}

/// Atomic min that skips the read-modify-write when a plain load shows it cannot lower the
/// value (slots only ever decrease, so a stale load errs toward doing the RMW).
fn fold_min(slot: &AtomicU32, v: u32) {
    if v < slot.load(Ordering::Relaxed) {
        slot.fetch_min(v, Ordering::Relaxed);
    }
}

/// Atomic max, likewise (slots only ever increase).
fn fold_max(slot: &AtomicU32, v: u32) {
    if v > slot.load(Ordering::Relaxed) {
        slot.fetch_max(v, Ordering::Relaxed);
    }
}

/// Pixels whose centres k + ½ lie in [min - r, max + r], clamped to 0..count; None if none do.
pub fn pixel_span(a: f32, b: f32, c: f32, r: f32, count: u32) -> Option<(u32, u32)> {
    let lo = (a.min(b).min(c) - r - 0.5).ceil().max(0.0);
    let hi = (a.max(b).max(c) + r - 0.5).floor().min(count as f32 - 1.0);
    (lo <= hi).then_some((lo as u32, hi as u32))
}
