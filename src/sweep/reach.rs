//! The reach of the rendered offset: one bit per voxel, set where the voxel's centre lies in the
//! offset (radius `SweepInput::radius` = δ + μ + ρ) of some posed triangle. The flood from
//! outside (`mesh::flood`) may not cross it.
//!
//! Every row of voxel centres along x is a ray of the x image, so the sweep's own ray cast
//! (`offset::PreparedTriangle`, eight pixels at a time, the same f32 formulas and radius) gives
//! each posed triangle's interval [t0, t1] on it, and the voxels i with i + ½ in it are set:
//! i from ⌈t0 - ½⌉ to ⌊t1 - ½⌋, exact in f64 as in `mesh::classify`. So a voxel centre inside
//! the exact offset of radius δ + μ is in the reach, by the same rounding argument as the
//! images' (docs/design.md, "Why the sweep is conservative in floating point").
//!
//! The sweep sets the same bits on its way (`cpu::sweep_with_reach`, and `sweep_main` on the
//! GPU when params.flags asks), from the x axis's intervals it computes anyway: that is what a
//! run uses. This separate pass is the reference the tests hold both to, and the fallback when
//! the bits exceed one GPU buffer. Memory: nx·ny·nz / 8 bytes.

use rayon::prelude::*;
use wide::f32x8;

use super::cpu::{pixel_span, pose_triangle, set_centres};
use super::offset::PreparedTriangle;
use super::{Cancelled, Observer};
use crate::depth::{COLUMN_AXIS, ROW_AXIS};
use crate::input::posed::SweepInput;
use crate::voxels::{AtomicVoxelBits, VoxelBits};

/// Triangles one rayon task marks under one pose.
const TRIANGLES_PER_TASK: usize = 512;
/// Poses per batch between cancellation checks (fewer for big parts).
const POSED_TRIANGLES_PER_BATCH: usize = 1 << 20;

/// The voxels whose centres the rendered offset of some posed triangle covers.
pub fn reach(input: &SweepInput, observer: &dyn Observer) -> Result<VoxelBits, Cancelled> {
    let d = input.grid.dims;
    let bits = AtomicVoxelBits::new([d[0] as usize, d[1] as usize, d[2] as usize]);
    let mut pose_batch = Vec::new();
    for (index, part) in input.parts.iter().enumerate() {
        let tris =
            &input.triangles[part.tri_start as usize..(part.tri_start + part.tri_count) as usize];
        let batch = (POSED_TRIANGLES_PER_BATCH / tris.len().max(1)).clamp(1, 4096) as u64;
        let count = part.pose_count as u64;
        let mut next = 0u64;
        while next < count {
            if observer.cancelled() {
                return Err(Cancelled);
            }
            let end = count.min(next + batch);
            input.poses.fill(index, next..end, &mut pose_batch);
            next = end;
            pose_batch
                .par_iter()
                .flat_map(|m| tris.par_chunks(TRIANGLES_PER_TASK).map(move |c| (m, c)))
                .for_each(|(m, chunk)| {
                    for t in chunk {
                        mark(&pose_triangle(m, t), input.radius, d, &bits);
                    }
                });
        }
    }
    Ok(bits.into_bits())
}

/// Set the voxels of every x row whose centres lie in the offset of one posed triangle (grid
/// units).
pub fn mark(p: &[[f32; 3]; 3], radius: f32, dims: [u32; 3], bits: &AtomicVoxelBits) {
    let (cu, rv) = (COLUMN_AXIS[0], ROW_AXIS[0]); // z (k), y (j)
    let Some((c0, c1)) = pixel_span(p[0][cu], p[1][cu], p[2][cu], radius, dims[cu]) else {
        return;
    };
    let Some((r0, r1)) = pixel_span(p[0][rv], p[1][rv], p[2][rv], radius, dims[rv]) else {
        return;
    };
    let tri = PreparedTriangle::new(p.map(|v| [v[cu], v[rv], v[0]]), radius);
    let lanes = f32x8::new(std::array::from_fn(|i| i as f32));
    for j in r0..=r1 {
        let pv = j as f32 + 0.5;
        for first in (c0..=c1).step_by(8) {
            let pu = f32x8::splat(first as f32 + 0.5) + lanes;
            let (t0, t1) = tri.interval_at_x8(pu, pv);
            let (t0, t1) = (t0.to_array(), t1.to_array());
            for lane in 0..(c1 + 1 - first).min(8) as usize {
                if t0[lane] <= t1[lane] {
                    let k = (first + lane as u32) as usize;
                    set_centres(bits, j as usize, k, t0[lane], t1[lane]);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::verify::geom::dist_triangle;
    use glam::DVec3;

    /// Against the exact f64 distance to the triangle: every voxel centre inside the offset is
    /// set, and none set lies more than rounding beyond it.
    #[test]
    fn reach_is_the_offset_at_voxel_centres() {
        let mut rng = fastrand::Rng::with_seed(0x5eac);
        let dims = [37u32, 29, 23];
        let (mut inside, mut set) = (0u64, 0u64);
        for case in 0..300 {
            let radius = 0.3 + 3.0 * rng.f32();
            let p: [[f32; 3]; 3] = std::array::from_fn(|_| {
                let small = case % 3 == 0;
                std::array::from_fn(|a| {
                    let span = if small { 2.0 } else { dims[a] as f32 };
                    (dims[a] as f32 - span) / 2.0 + span * rng.f32() * 1.2 - 0.1 * span
                })
            });
            let bits = AtomicVoxelBits::new(dims.map(|x| x as usize));
            mark(&p, radius, dims, &bits);
            let bits = bits.into_bits();
            let v = p.map(|q| DVec3::new(q[0] as f64, q[1] as f64, q[2] as f64));
            for k in 0..dims[2] as usize {
                for j in 0..dims[1] as usize {
                    for i in 0..dims[0] as usize {
                        let c = DVec3::new(i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5);
                        let d = dist_triangle(c, v[0], v[1], v[2]);
                        let got = bits.get(i as isize, j as isize, k as isize);
                        if d <= radius as f64 - 1e-4 {
                            inside += 1;
                            assert!(
                                got,
                                "case {case}: centre {c} at {d} within {radius} not set"
                            );
                        }
                        if got {
                            set += 1;
                            assert!(
                                d <= radius as f64 + 1e-3,
                                "case {case}: centre {c} at {d} beyond {radius} set"
                            );
                        }
                    }
                }
            }
        }
        assert!(
            inside > 100_000 && set >= inside,
            "{inside} inside, {set} set"
        );
    }
}
