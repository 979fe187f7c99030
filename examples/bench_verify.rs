//! `sweptvol verify` at the size (kept out of CI): a 100k-triangle generator × 10,000
//! vibration poses against a 30k-triangle swept mesh.
//!
//!     cargo run --release --example bench_verify -- [DIR] [--poses N] [--resolution N]
//!
//! Set-up, cached in DIR (default target/bench-verify): 10,000 poses of small jitter of the
//! bundled bunny (rotations up to 0.5° about its centre, translations up to 0.2% of its size,
//! like `bench_sweep vibrating`); `sweptvol run` on the plain bunny (3,674 triangles) gives the
//! swept mesh, split 1:4 until it has at least 30,000 triangles (same surface); the generator
//! given to verify is the bunny with every edge split in 5 (91,850 triangles, same surface).
//! Prints the verify report's counts and timings as JSON.

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::{DQuat, DVec3, Vec3};
use sweptvol::input::grid::Accuracy;
use sweptvol::input::motion::Motion;
use sweptvol::job::JobOptions;
use sweptvol::pipeline::{self, RunOptions};
use sweptvol::sweep::backend::{Backend, BackendChoice};
use sweptvol::sweep::Silent;
use sweptvol::verify::{self, VerifyOptions};

/// A .glb with one node and one indexed triangle primitive.
fn write_glb(path: &Path, positions: &[Vec3], tris: &[[u32; 3]]) {
    let mut bin: Vec<u8> = positions
        .iter()
        .flat_map(|v| v.to_array())
        .flat_map(f32::to_le_bytes)
        .collect();
    let index_at = bin.len();
    bin.extend_from_slice(bytemuck::cast_slice(tris));
    let doc = serde_json::json!({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"name": "part", "mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": positions.len(), "type": "VEC3",
             "min": [-1e9, -1e9, -1e9], "max": [1e9, 1e9, 1e9]},
            {"bufferView": 1, "componentType": 5125, "count": 3 * tris.len(), "type": "SCALAR"}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": index_at},
            {"buffer": 0, "byteOffset": index_at, "byteLength": bin.len() - index_at}],
        "buffers": [{"byteLength": bin.len()}],
    });
    let mut js = serde_json::to_vec(&doc).unwrap();
    js.resize(js.len().next_multiple_of(4), b' ');
    let mut out = Vec::new();
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&((28 + js.len() + bin.len()) as u32).to_le_bytes());
    out.extend_from_slice(&(js.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&js);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    std::fs::write(path, out).unwrap();
}

/// Every edge split in `k` (k² triangles per triangle, the same surface).
fn subdivide(positions: &[Vec3], tris: &[[u32; 3]], k: u32) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let (mut p, mut t) = (Vec::new(), Vec::new());
    for tri in tris {
        let [a, b, c] = tri.map(|i| positions[i as usize]);
        let base = p.len() as u32;
        let idx = |i: u32, j: u32| base + i * (2 * k + 3 - i) / 2 + j;
        for i in 0..=k {
            for j in 0..=(k - i) {
                let (u, v) = (i as f32 / k as f32, j as f32 / k as f32);
                p.push(a + (b - a) * u + (c - a) * v);
            }
        }
        for i in 0..k {
            for j in 0..(k - i) {
                t.push([idx(i, j), idx(i + 1, j), idx(i, j + 1)]);
                if j + 1 < k - i {
                    t.push([idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)]);
                }
            }
        }
    }
    (p, t)
}

/// Each triangle into four at its edge midpoints, computed symmetrically ((a + b) / 2 is the
/// same from both sides of an edge), so the welded mesh stays closed.
fn split_midpoints(p: &[Vec3], tris: &[[u32; 3]]) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let mut out_p = p.to_vec();
    let mut mids = std::collections::HashMap::new();
    let mut mid = |a: u32, b: u32, out_p: &mut Vec<Vec3>| -> u32 {
        *mids.entry((a.min(b), a.max(b))).or_insert_with(|| {
            out_p.push((p[a as usize] + p[b as usize]) * 0.5);
            out_p.len() as u32 - 1
        })
    };
    let mut out_t = Vec::new();
    for &[a, b, c] in tris {
        let (ab, bc, ca) = (
            mid(a, b, &mut out_p),
            mid(b, c, &mut out_p),
            mid(c, a, &mut out_p),
        );
        out_t.extend([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
    }
    (out_p, out_t)
}

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let (mut dir, mut poses, mut resolution) = (PathBuf::from("target/bench-verify"), 10_000, 128);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--poses" => poses = args.next().unwrap().parse()?,
            "--resolution" => resolution = args.next().unwrap().parse()?,
            _ => dir = PathBuf::from(a),
        }
    }
    std::fs::create_dir_all(&dir)?;
    let bunny = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/bunny.glb");
    let g = sweptvol::io::gltf_in::read_generator(&bunny)?;
    assert_eq!(g.parts.len(), 1);
    let part = &g.parts[0];
    let world: Vec<Vec3> = part
        .positions
        .iter()
        .map(|v| part.world.transform_point3(v.as_dvec3()).as_vec3())
        .collect();

    let csv = dir.join(format!("vibration-{poses}.csv"));
    let swept = dir.join(format!("vibration-{poses}.swept.glb"));
    if !swept.exists() {
        let (lo, hi) = world
            .iter()
            .fold((Vec3::MAX, Vec3::MIN), |(l, h), v| (l.min(*v), h.max(*v)));
        let (centre, size) = (((lo + hi) / 2.0).as_dvec3(), (hi - lo).max_element() as f64);
        // Fixed seed: every run draws the same poses. Uniform in [-1, 1).
        let mut rng = fastrand::Rng::with_seed(0x5EED);
        let mut f = move || rng.f64() * 2.0 - 1.0;
        let mut text = String::from("tx,ty,tz,qw,qx,qy,qz\n");
        for _ in 0..poses {
            let axis = DVec3::new(f(), f(), f()).normalize_or(DVec3::X);
            let q = DQuat::from_axis_angle(axis, 0.5f64.to_radians() * f());
            // Rotation about the centre: t = c + jitter - R·c.
            let t = centre + DVec3::new(f(), f(), f()) * 0.002 * size - q * centre;
            text += &format!("{},{},{},{},{},{},{}\n", t.x, t.y, t.z, q.w, q.x, q.y, q.z);
        }
        std::fs::write(&csv, text)?;
        let t0 = Instant::now();
        let job = JobOptions {
            resolution: Some(resolution),
            // verify certifies the listed poses: the benchmark's run renders just those.
            motion: Motion::Discrete,
            ..JobOptions::default()
        };
        let mut opts = RunOptions::of_job(
            &job,
            bunny.clone(),
            csv.clone(),
            dir.clone(),
            Accuracy::DEFAULT,
        );
        opts.overwrite = true;
        let job = pipeline::prepare(&opts)?;
        let report = pipeline::execute(&job, &Backend::acquire(BackendChoice::Cpu)?, &Silent)?;
        eprintln!(
            "run: {} triangles in {:.1} s",
            report.mesh.triangles_final,
            t0.elapsed().as_secs_f64()
        );
    }
    let gen100k = dir.join("bunny-split5.glb");
    let (gp, gt) = subdivide(&world, &part.triangles, 5);
    write_glb(&gen100k, &gp, &gt);
    let m = sweptvol::io::gltf_in::read_generator(&swept)?;
    let mp = &m.parts[0];
    let (mut p, mut t) = (mp.positions.clone(), mp.triangles.clone());
    while t.len() < 25_000 {
        (p, t) = split_midpoints(&p, &t);
    }
    let mesh30k = dir.join("swept-split.glb");
    write_glb(&mesh30k, &p, &t);

    let t0 = Instant::now();
    let report = verify::verify(
        &VerifyOptions {
            package_dir: Vec::new(),
            rows: Default::default(),
            generator: gen100k,
            trajectory: csv,
            mesh: mesh30k,
            bound: None,
            bound_scope: Default::default(),
            spacing: None,
            all_failures: false,
            motion: Motion::Discrete,
            relative_to: None,
        },
        &verify::Silent,
    )?;
    let secs = t0.elapsed().as_secs_f64();
    let c = &report.containment;
    println!(
        "{}",
        serde_json::json!({
            "passed": report.passed,
            "failures": report.failures,
            "inputs": report.inputs,
            "containment": {"holds": c.holds, "certified": c.result.certified,
                "ball_tests": c.result.ball_tests, "winding_evaluations": c.result.winding_evaluations,
                "spacing": c.spacing},
            "deviation": {"bound": report.deviation.result.bound, "lower": report.deviation.result.lower,
                "samples": report.deviation.result.samples},
            "health": {"closed": report.health.closed, "components": report.health.components,
                "self_intersecting_pairs": report.health.self_intersecting_pairs},
            "timings": report.timings,
            "threads": report.threads,
            "wall_seconds": secs,
        })
    );
    Ok(())
}
