//! Will a run fit in memory? An estimate from the grid alone, checked before anything large is
//! allocated, against what the machine and the process's address-space limit leave.
//!
//! Estimate, bytes, with P = dy·dz + dx·dz + dx·dy the pixels of the three image axes and
//! V = dx·dy·dz the voxels:
//! - depth images D⁻ and D⁺, f32: 8 B per pixel; classifier range tables, i32 lo and hi: 8 B;
//! - every voxel's class as one bit (`Classifier::solidify`), and with the flood classification
//!   (`mesh::flood`) one more: the offset's reach, then the flood (V / 4 bytes at the peak;
//!   646 MB for the bunny at n = 1500, 1500 × 1443 × 1193 voxels);
//! - the simplifier, block by block (`simplify::blocked`): each worker thread holds one block's
//!   patch of the voxel boundary and its state, at most about 250 B per triangle for
//!   8.4·B² triangles (B = 256 voxels: 138 MB); the blocks' results, welded, and the seam pass's
//!   state on them (with the welded start kept for a pass done again, about 60 B a triangle
//!   more, within the share's margin over the 2.2-2.4% measured): 250 B per triangle for
//!   `SEAM_SHARE` (4 %) of the start triangles, T ≈ 2.8P
//!   (each hit pixel's ray enters and leaves the volume at least once, two triangles per face;
//!   2.83P measured on the bundled bunny at n = 1024 and 1500);
//! - with --keep-start-mesh, the whole voxel boundary at once and its GLB bytes: 54 B per start
//!   triangle;
//! - the swept volume's pieces for the sweep check (`simplify::pieces`): 48 B each and their
//!   cell index, at most `MAX_PIECES` (2^20: about 80 MB; a few kB on the bundled examples,
//!   one piece per component per row), so not counted;
//! - BASE_BYTES for the program, its threads and the inputs. Poses do not count: the sweep's
//!   input holds the rows and the motion's intervals, and the sub-poses between them are made a
//!   batch at a time (`input::poses`), however many the motion needs.
//!
//! So about 30·P + V / 4 bytes with the flood, plus 138 MB per thread: 1.2 GB estimated for the
//! bunny at n = 1500 on 2 threads, where 0.76 GB was measured (docs/benchmarks.md). An
//! estimate, not a bound: a shape with more boundary per pixel can need more, and a run just
//! under the limit may still fail late.

use crate::error::{OptionError, OptionKey};
use crate::input::grid::Grid;

/// Program, thread stacks, inputs and buffers outside the grid-sized structures (among them the
/// extruded-wall certificate's run cache, 1.5 MB per worker: `simplify::extruded`).
const BASE_BYTES: f64 = 32.0 * 1048576.0;
/// Depth images and classifier ranges, per pixel.
const IMAGE_BYTES_PER_PIXEL: f64 = 16.0;
/// Start-mesh triangles per pixel.
const TRIANGLES_PER_PIXEL: f64 = 2.8;
/// Voxels along a simplification block's edge: must be kept in step with
/// `simplify::blocked::BLOCK_VOXELS` (a test there checks it).
pub const BLOCK_VOXELS: usize = 256;
/// A mesh and the simplifier's state on it, per triangle.
const BYTES_PER_TRIANGLE: f64 = 250.0;
/// The share of the start triangles the blocks leave to the seam pass (2.2-2.4% measured on
/// the bunny at n = 512 and 1500, blocks of 128 voxels; fewer with blocks of 256).
const SEAM_SHARE: f64 = 0.04;
/// One block's start triangles at most, per voxel² of the block's edge (three faces' worth of
/// pixels, 2.8 triangles each).
const BLOCK_TRIANGLES_PER_VOXEL2: f64 = 8.4;
/// The whole start mesh (positions and triangles) and its GLB bytes, per triangle, with
/// --keep-start-mesh.
const START_MESH_BYTES_PER_TRIANGLE: f64 = 54.0;

/// Pixels of the three image axes.
fn pixels(grid: &Grid) -> f64 {
    let [x, y, z] = grid.dims.map(f64::from);
    y * z + x * z + x * y
}

/// Estimated peak memory of a run on `grid`, bytes (`flood`: the flood classification), with
/// the simplifier on the current thread pool's workers.
pub fn estimate(grid: &Grid, keep_start_mesh: bool, flood: bool) -> f64 {
    estimate_on(grid, keep_start_mesh, flood, rayon::current_num_threads())
}

/// [`estimate`] on `workers` threads.
pub fn estimate_on(grid: &Grid, keep_start_mesh: bool, flood: bool, workers: usize) -> f64 {
    let triangles = TRIANGLES_PER_PIXEL * pixels(grid);
    let [x, y, z] = grid.dims.map(f64::from);
    let bits = x * y * z / 8.0 * if flood { 2.0 } else { 1.0 };
    let block = BLOCK_VOXELS as f64;
    let blocks = workers as f64 * BYTES_PER_TRIANGLE * BLOCK_TRIANGLES_PER_VOXEL2 * block * block;
    let seams = SEAM_SHARE * triangles * BYTES_PER_TRIANGLE;
    let start = if keep_start_mesh {
        START_MESH_BYTES_PER_TRIANGLE * triangles
    } else {
        0.0
    };
    BASE_BYTES + IMAGE_BYTES_PER_PIXEL * pixels(grid) + bits + blocks + seams + start
}

/// Memory this process can still get, bytes: the least of MemAvailable (/proc/meminfo),
/// RLIMIT_AS less the address space in use (/proc/self/statm) and the cgroup's headroom. None
/// where none is known.
pub fn available() -> Option<f64> {
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok().and_then(|s| {
        s.lines()
            .find_map(|l| l.strip_prefix("MemAvailable:"))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
            .map(|kb| kb * 1024.0)
    });
    let mut lim = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit writes only the struct it is given.
    let limited = unsafe { libc::getrlimit(libc::RLIMIT_AS, &mut lim) } == 0
        && lim.rlim_cur != libc::RLIM_INFINITY;
    let address_space = limited.then(|| {
        // statm's first field: the address space in use, in pages.
        let used = std::fs::read_to_string("/proc/self/statm")
            .ok()
            .and_then(|s| s.split_whitespace().next()?.parse::<f64>().ok())
            .unwrap_or(0.0);
        // SAFETY: sysconf has no preconditions.
        let page = unsafe { libc::sysconf(libc::_SC_PAGESIZE) }.max(4096) as f64;
        (lim.rlim_cur as f64 - used * page).max(0.0)
    });
    [meminfo, address_space, cgroup_headroom()]
        .into_iter()
        .flatten()
        .reduce(f64::min)
}

/// What the process's cgroup (v2) still allows: memory.max less memory.current, bytes; None
/// outside a limited cgroup. Containers see the host's MemAvailable, so this is their limit.
fn cgroup_headroom() -> Option<f64> {
    let own = std::fs::read_to_string("/proc/self/cgroup").ok()?;
    // v2: one line "0::/path".
    let path = own.lines().find_map(|l| l.strip_prefix("0::"))?.trim();
    let dir = std::path::Path::new("/sys/fs/cgroup").join(path.trim_start_matches('/'));
    let read = |name: &str| std::fs::read_to_string(dir.join(name)).ok();
    let max: f64 = read("memory.max")?.trim().parse().ok()?; // "max" (no limit) fails here
    let current: f64 = read("memory.current")?.trim().parse().ok()?;
    Some((max - current).max(0.0))
}

/// Refuse a run whose estimate exceeds `available` bytes, naming the estimate and the largest
/// resolution (and the matching tolerance: `tolerance_voxels` voxel edges, what a tolerance is
/// divided by for the voxel size) that would fit.
pub fn check(
    grid: &Grid,
    keep_start_mesh: bool,
    flood: bool,
    available: Option<f64>,
    tolerance_voxels: f64,
) -> Result<(), OptionError> {
    let need = estimate(grid, keep_start_mesh, flood);
    let Some(avail) = available else {
        return Ok(());
    };
    if need <= avail {
        return Ok(());
    }
    let n = grid.resolution();
    // The largest resolution whose scaled grid fits (memory grows with n², and with n³ for the
    // flood's bits): a binary search, since the estimate grows with the resolution.
    let scaled = |m: u32| Grid {
        dims: grid
            .dims
            .map(|d| ((d as u64 * m as u64).div_ceil(n as u64) as u32).max(1)),
        ..*grid
    };
    let (mut fit, mut too_big) = (1u32, n);
    while too_big - fit > 1 {
        let mid = fit + (too_big - fit) / 2;
        if estimate(&scaled(mid), keep_start_mesh, flood) <= avail {
            fit = mid;
        } else {
            too_big = mid;
        }
    }
    let gib = |b: f64| b / 1073741824.0;
    Err(OptionError::new(OptionKey::Resolution, format!(
        "resolution {n} needs an estimated {:.1} GiB of memory (grid {}x{}x{}: depth images, classifier ranges, a bit per voxel, the simplifier's blocks and seams over about {:.2e} start-mesh triangles), but only {:.1} GiB is available (MemAvailable, RLIMIT_AS, cgroup memory.max); nothing was allocated: use $resolution {fit} or less, or $tolerance {:.3e} or more (the estimate is made for parts that fill their box; for a thin or sparse part, $no_memory_check runs anyway)",
        gib(need),
        grid.dims[0],
        grid.dims[1],
        grid.dims[2],
        TRIANGLES_PER_PIXEL * pixels(grid),
        gib(avail),
        tolerance_voxels * grid.h * n as f64 / fit as f64,
    )))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(n: u32) -> Grid {
        Grid {
            origin: [0.0; 3],
            h: 1.0 / n as f64,
            dims: [n, n, n],
        }
    }

    #[test]
    fn estimate_grows_with_the_grid_and_the_suggestion_fits() {
        // On two workers: each holds a block (138 MB at B = 256), the same at every n.
        let (a, b) = (
            estimate_on(&grid(2048), false, false, 2),
            estimate_on(&grid(4096), false, false, 2),
        );
        // Between n² (images, meshes) and n³ (the voxel bits).
        assert!(b / a > 4.0 && b / a < 8.0, "{a} -> {b}");
        assert!(
            estimate_on(&grid(1024), false, false, 8) > estimate_on(&grid(1024), false, false, 2)
        );
        assert!(estimate_on(&grid(2048), true, false, 2) > a);
        assert!(estimate_on(&grid(2048), false, true, 2) > a);
        let avail = 4e9;
        for flood in [false, true] {
            let e = check(&grid(12288), false, flood, Some(avail), 3.5).unwrap_err();
            let fit: u32 = e
                .worded(OptionKey::flag)
                .split("--resolution ")
                .nth(1)
                .and_then(|s| s.split(' ').next())
                .and_then(|s| s.parse().ok())
                .expect("a resolution in the message");
            assert!(estimate(&grid(fit), false, flood) <= avail, "{}", e);
            assert!(estimate(&grid(fit + 2), false, flood) > avail, "{}", e);
            // The tolerance named gives that resolution's voxel: 3.5 voxel edges of 1/fit.
            let tolerance: f64 = e
                .worded(OptionKey::flag)
                .split("--tolerance ")
                .nth(1)
                .and_then(|s| s.split(' ').next())
                .and_then(|s| s.parse().ok())
                .expect("a tolerance in the message");
            assert!((tolerance * fit as f64 / 3.5 - 1.0).abs() < 1e-3, "{}", e);
            assert!(check(&grid(256), false, flood, Some(avail), 3.5).is_ok());
            assert!(check(&grid(12288), false, flood, None, 3.5).is_ok());
        }
    }
}
