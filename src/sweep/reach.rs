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
//! The sweep sets these bits on its way (`cpu::sweep_with_reach`, and `sweep_main` on the GPU
//! when params.flags asks), from the x axis's intervals it computes anyway: that is what a run
//! uses. [`reach`] is the same loop on the x axis alone: the fallback when the bits exceed one
//! GPU buffer, and what the tests hold the GPU to. Memory: nx·ny·nz / 8 bytes.

use super::{cpu, Cancelled, Observer};
use crate::input::posed::SweepInput;
use crate::voxels::VoxelBits;

/// Forwards cancellation only: a pass after the sweep does not move the sweep's progress.
struct CancelOnly<'a>(&'a dyn Observer);

impl Observer for CancelOnly<'_> {
    fn cancelled(&self) -> bool {
        self.0.cancelled()
    }
}

/// The voxels whose centres the rendered offset of some posed triangle covers.
pub fn reach(input: &SweepInput, observer: &dyn Observer) -> Result<VoxelBits, Cancelled> {
    cpu::x_axis_reach(input, &CancelOnly(observer))
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::AtomicU32;

    use crate::sweep::cpu::splat;
    use crate::verify::geom::dist_triangle;
    use crate::voxels::AtomicVoxelBits;
    use glam::DVec3;

    /// The x axis's splat with the reach (what the sweep runs), against the exact f64 distance
    /// to the triangle: every voxel centre inside the offset is set, and none set lies more
    /// than rounding beyond it.
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
            // The x image's depths are not looked at here: any start values serve.
            let image: Vec<AtomicU32> = (0..2 * dims[1] * dims[2])
                .map(|_| AtomicU32::new(0))
                .collect();
            splat(&p, radius, 0, dims, &image, Some(&bits));
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
