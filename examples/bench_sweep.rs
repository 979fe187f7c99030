//! Sweep throughput benchmark (kept out of CI): posed triangles per second on synthetic workloads.
//!
//!     cargo run --release --example bench_sweep -- vibrating --backend cpu --poses 200
//!     cargo run --release --example bench_sweep -- assembly --backend gpu
//!
//! Workloads (the generator is `examples/dragon-11k.glb`, a copy of `../shared/data`'s, subdivided):
//! - `vibrating`: each edge split in 3 (99,918 triangles), 10,000 poses of small jitter
//!   (rotations up to 0.5°, translations up to 0.2% of the part), like a measured vibration.
//! - `assembly`: each edge split in 5 (277,550 triangles), 200 poses along a long path with
//!   large rotations, like an assembly path.
//!
//! `--poses K` sweeps only the first K poses (the rate is what is measured); `--resolution`
//! defaults to the paper's 1500; `--motion screw` also sweeps the screw motion between
//! consecutive poses (sub-poses, docs/design.md "Continuous motion"; default `discrete`). Prints
//! one JSON line per run, with the motion report (poses rendered, largest steps per interval);
//! `--plan` prints the sweep's size and motion report without sweeping.

use std::path::Path;
use std::time::Instant;

use glam::{DMat4, DQuat, DVec3, Vec3};
use sweptvol::input::grid::{Accuracy, Overrides};
use sweptvol::input::model::{Generator, Trajectory};
use sweptvol::input::motion::Motion;
use sweptvol::input::posed;
use sweptvol::io::gltf_in;
use sweptvol::sweep::backend::{Backend, BackendChoice};
use sweptvol::sweep::Silent;

/// Split every edge of every triangle into `k` parts (k² triangles each).
fn subdivide(g: &mut Generator, k: u32) {
    for part in &mut g.parts {
        let mut positions: Vec<Vec3> = Vec::new();
        let mut triangles = Vec::new();
        for t in &part.triangles {
            let [a, b, c] = t.map(|i| part.positions[i as usize]);
            let base = positions.len() as u32;
            let idx = |i: u32, j: u32| base + i * (2 * k + 3 - i) / 2 + j; // row i has k+1-i points
            for i in 0..=k {
                for j in 0..=(k - i) {
                    let (u, v) = (i as f32 / k as f32, j as f32 / k as f32);
                    positions.push(a + (b - a) * u + (c - a) * v);
                }
            }
            for i in 0..k {
                for j in 0..(k - i) {
                    triangles.push([idx(i, j), idx(i + 1, j), idx(i, j + 1)]);
                    if j + 1 < k - i {
                        triangles.push([idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)]);
                    }
                }
            }
        }
        part.positions = positions;
        part.triangles = triangles;
    }
}

fn poses(workload: &str, size: f64, count: usize) -> Vec<DMat4> {
    // Fixed seed: every run draws the same poses. Uniform in [-1, 1).
    let mut rng = fastrand::Rng::with_seed(0x5EED);
    let mut f = move || rng.f64() * 2.0 - 1.0;
    (0..count)
        .map(|k| match workload {
            "vibrating" => {
                let axis = DVec3::new(f(), f(), f()).normalize_or(DVec3::X);
                let rot = DQuat::from_axis_angle(axis, 0.5f64.to_radians() * f());
                let t = DVec3::new(f(), f(), f()) * 0.002 * size;
                DMat4::from_rotation_translation(rot, t)
            }
            _ => {
                let s = k as f64 / count as f64;
                let rot =
                    DQuat::from_euler(glam::EulerRot::YXZ, 2.0 * s, 0.8 * s, 0.3 * (6.0 * s).sin());
                let t = DVec3::new(3.0 * s, 0.5 * (4.0 * s).sin(), -1.5 * s) * size;
                DMat4::from_rotation_translation(rot, t)
            }
        })
        .collect()
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let workload = args
        .first()
        .map(String::as_str)
        .unwrap_or("vibrating")
        .to_string();
    let flag = |name: &str| {
        args.iter()
            .position(|a| a == name)
            .map(|i| args[i + 1].clone())
    };
    let backend = match flag("--backend").as_deref() {
        Some("gpu") => BackendChoice::Gpu,
        Some("auto") => BackendChoice::Auto,
        _ => BackendChoice::Cpu,
    };
    let resolution: u32 = flag("--resolution").map_or(Ok(1500), |s| s.parse())?;
    let (split, full_poses) = match workload.as_str() {
        "vibrating" => (3, 10_000),
        "assembly" => (5, 200),
        other => anyhow::bail!("unknown workload {other}: vibrating or assembly"),
    };
    let count: usize = flag("--poses").map_or(Ok(full_poses), |s| s.parse())?;
    let motion = match flag("--motion").as_deref() {
        Some("screw") => Motion::Screw,
        None | Some("discrete") => Motion::Discrete,
        Some(other) => anyhow::bail!("unknown motion {other}: screw or discrete"),
    };

    let dragon = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/dragon-11k.glb");
    let mut g = gltf_in::read_generator(&dragon)?;
    subdivide(&mut g, split);
    let lo = g.parts[0]
        .positions
        .iter()
        .fold(Vec3::MAX, |m, p| m.min(*p));
    let hi = g.parts[0]
        .positions
        .iter()
        .fold(Vec3::MIN, |m, p| m.max(*p));
    let size = (hi - lo).max_element() as f64;
    let traj = Trajectory::whole_scene(&poses(&workload, size, count));
    let input = posed::build(
        &g,
        Path::new("dragon"),
        &traj,
        Path::new("bench"),
        Accuracy::Resolution(resolution),
        Overrides::default(),
        motion,
    )?;
    if args.iter().any(|a| a == "--plan") {
        println!(
            "{}",
            serde_json::json!({
                "workload": workload,
                "triangles": input.triangles.len(),
                "poses": count,
                "motion": input.motion,
                "resolution": input.grid.resolution(),
                "voxel_size": input.grid.h,
                "posed_triangles": input.posed_triangles(),
            })
        );
        return Ok(());
    }
    let backend = Backend::acquire(backend)?;
    let t = Instant::now();
    let images = backend.sweep(&input, &Silent)?;
    let secs = t.elapsed().as_secs_f64();
    println!(
        "{}",
        serde_json::json!({
            "workload": workload,
            "backend": backend.describe(),
            "triangles": input.triangles.len(),
            "poses": count,
            "motion": input.motion,
            "resolution": input.grid.resolution(),
            "dims": input.grid.dims,
            "posed_triangles": input.posed_triangles(),
            "seconds": secs,
            "posed_triangles_per_second": input.posed_triangles() as f64 / secs,
            "hit_pixels": images.images.iter().map(|i| i.hit_count()).collect::<Vec<_>>(),
        })
    );
    Ok(())
}
