//! The conservative sweep (paper section 4): render the δ-offset of every posed triangle into
//! the six depth images, never clearing them. Two backends compute the same definition: the
//! wgpu compute path (`gpu`) and its CPU twin (`cpu`), which is also the test oracle.

pub mod backend;
pub mod cpu;
pub mod gpu;
pub mod offset;
pub mod reach;

use crate::depth::{EMPTY_MAX, EMPTY_MIN, SLOTS};
use crate::input::posed::SweepInput;

/// Watches a long job: progress, and a way to stop early. `pipeline::execute` also reports its
/// later stages and checks `cancelled` between them.
pub trait Observer: Sync {
    /// A stage of `pipeline::execute` begins: "sweep", "classify", "simplify" or "write".
    fn stage(&self, _stage: &'static str) {}
    /// The sweep is about to render `poses` poses, `posed_triangles` posed triangles in all.
    fn begin(&self, _poses: u64, _posed_triangles: u64) {}
    /// `done` of `total` posed triangles are rendered.
    fn progress(&self, _done: u64, _total: u64) {}
    /// Checked between sweep batches and between pipeline stages; true stops with [`Cancelled`].
    fn cancelled(&self) -> bool {
        false
    }
}

/// An observer that ignores everything.
pub struct Silent;
impl Observer for Silent {}

/// The sweep stopped because the observer asked it to.
#[derive(Debug, thiserror::Error)]
#[error("cancelled")]
pub struct Cancelled;

/// Buffers of encoded (D⁻, D⁺) pairs, one per axis, all slots empty.
pub fn empty_encoded(input: &SweepInput) -> [Vec<u32>; 3] {
    [0, 1, 2].map(|a| {
        let (w, h) = crate::depth::image_size(&input.grid, a);
        let mut v = Vec::with_capacity(SLOTS * w as usize * h as usize);
        for _ in 0..(w as usize * h as usize) {
            v.push(EMPTY_MIN);
            v.push(EMPTY_MAX);
        }
        v
    })
}

/// Total poses over all parts (the progress unit).
pub fn total_poses(input: &SweepInput) -> u64 {
    input.parts.iter().map(|p| p.pose_count as u64).sum()
}
