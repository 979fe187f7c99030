//! Memory for the sweep's poses stays O(rows + intervals + one batch) (issue 16): the sub-poses
//! of a continuous motion are made on the fly, never stored all at once. A counting allocator
//! (this test binary's own) measures the peak of building the sweep input and sweeping it on the
//! CPU twin for the same rows at two voxel sizes, four times as many sub-poses at the finer one.
//! Storing the sub-poses (48 bytes each as f32 matrices, more as the f64 list they were made
//! from) fails both checks.

use std::alloc::{GlobalAlloc, Layout, System};
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

use glam::{DMat4, DVec3, Vec3};
use sweptvol::input::grid::{Accuracy, Overrides};
use sweptvol::input::model::{Generator, Part, Trajectory};
use sweptvol::input::motion::Motion;
use sweptvol::input::posed;
use sweptvol::sweep::{cpu, Silent};

struct Counting;

static CURRENT: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

fn grew(size: usize) {
    let now = CURRENT.fetch_add(size, Ordering::Relaxed) + size;
    PEAK.fetch_max(now, Ordering::Relaxed);
}

// SAFETY: every call forwards to the system allocator unchanged; only the counters are extra.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = System.alloc(layout);
        if !p.is_null() {
            grew(layout.size());
        }
        p
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        let p = System.alloc_zeroed(layout);
        if !p.is_null() {
            grew(layout.size());
        }
        p
    }
    unsafe fn dealloc(&self, p: *mut u8, layout: Layout) {
        System.dealloc(p, layout);
        CURRENT.fetch_sub(layout.size(), Ordering::Relaxed);
    }
    unsafe fn realloc(&self, p: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let q = System.realloc(p, layout, new_size);
        if !q.is_null() {
            CURRENT.fetch_sub(layout.size(), Ordering::Relaxed);
            grew(new_size);
        }
        q
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Build and sweep `g` along `rows` (screw motion) at resolution `n`: the poses rendered, and
/// the peak of live heap bytes above what was live before, bytes.
fn peak_of_sweep(g: &Generator, traj: &Trajectory, n: u32) -> (u64, usize) {
    let before = CURRENT.load(Ordering::Relaxed);
    PEAK.store(before, Ordering::Relaxed);
    let input = posed::build(
        g,
        Path::new("t.glb"),
        traj,
        Path::new("t.csv"),
        Accuracy::Resolution(n),
        Overrides::default(),
        Motion::Screw,
    )
    .expect("job builds");
    let images = cpu::sweep(&input, &Silent).expect("not cancelled");
    assert!(images.images.iter().any(|i| i.hit_count() > 0));
    let poses = input.motion.poses_rendered;
    drop((input, images));
    (poses, PEAK.load(Ordering::Relaxed) - before)
}

#[test]
fn pose_memory_does_not_grow_with_the_sub_poses() {
    // A small triangle pushed 10 units back and forth between 4500 rows: each interval needs
    // about 2n steps at resolution n.
    let g = Generator {
        nodes: Vec::new(),
        parts: vec![Part {
            node_index: 0,
            node_name: Some("chip".into()),
            world: DMat4::IDENTITY,
            positions: vec![
                Vec3::ZERO,
                Vec3::new(0.02, 0.0, 0.0),
                Vec3::new(0.0, 0.02, 0.01),
            ],
            triangles: vec![[0, 1, 2]],
        }],
        warnings: vec![],
    };
    let rows: Vec<DMat4> = (0..4500)
        .map(|i| DMat4::from_translation(DVec3::new(10.0 * (i % 2) as f64, 0.0, 0.0)))
        .collect();
    let traj = Trajectory::whole_scene(&rows);
    // Warm up: the rayon pool and everything else that is allocated once.
    peak_of_sweep(&g, &Trajectory::whole_scene(&rows[..3]), 16);

    let (coarse_poses, coarse_peak) = peak_of_sweep(&g, &traj, 32);
    let (fine_poses, fine_peak) = peak_of_sweep(&g, &traj, 128);
    eprintln!("{coarse_poses} poses: peak {coarse_peak} B; {fine_poses} poses: peak {fine_peak} B");
    assert!(
        fine_poses > 1_000_000 && fine_poses > 3 * coarse_poses,
        "{coarse_poses} and {fine_poses} poses"
    );
    // Storing the fine motion's poses alone would take 48 B each.
    let stored = 48 * fine_poses as usize;
    assert!(
        fine_peak < stored / 4,
        "peak {fine_peak} B for {fine_poses} poses (storing them: {stored} B)"
    );
    // Three quarters of a million more sub-poses cost (next to) nothing: the grids differ by a
    // few kilobytes of depth images, and a batch is at most 4096 poses.
    let extra = 48 * (fine_poses - coarse_poses) as usize;
    assert!(
        fine_peak < coarse_peak + extra / 16,
        "peak {coarse_peak} B -> {fine_peak} B for {} more poses",
        fine_poses - coarse_poses
    );
}
