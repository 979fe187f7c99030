//! Clearance at the sizes issue 28 names (kept out of CI):
//!
//!     cargo run --release --example bench_clearance -- [DIR]
//!
//! 1. A 1,000,000-triangle obstacle against a 20,000-triangle swept mesh: the mesh a closed UV
//!    sphere of radius 1 (a stand-in: the search sees only triangles), the obstacle an open bowl
//!    of radius 1.05 around it (every part of it near the mesh: the hard case for the pair
//!    search and for the map), written to DIR/bowl.glb and read back as `clearance` reads it.
//! 2. The contact witness search over 1,000 poses of a 100,000-triangle part (a closed sphere of
//!    radius 0.3 vibrating by up to 0.02) inside an open bowl of 1M triangles 0.05 away: every
//!    pose near the obstacle all round, the hard case.
//!
//! Prints each stage's seconds as JSON.

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::{DMat4, DQuat, DVec3};
use sweptvol::clearance::{self, map, Guarantee, PosedPart, Swept};
use sweptvol::verify::bvh::Bvh;

/// A UV sphere of radius r about the origin: `rings` latitude bands (the first `skip_top`
/// left out, leaving an open bowl), `segments` around; about 2·rings·segments triangles.
fn sphere(r: f64, rings: u32, segments: u32, skip_top: u32) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let mut p = Vec::new();
    for i in 0..=rings {
        let th = std::f64::consts::PI * i as f64 / rings as f64;
        for j in 0..segments {
            let ph = std::f64::consts::TAU * j as f64 / segments as f64;
            p.push(r * DVec3::new(th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin()));
        }
    }
    let id = |i: u32, j: u32| i * segments + j % segments;
    let mut t = Vec::new();
    for i in skip_top..rings {
        for j in 0..segments {
            let (a, b, c, d) = (id(i, j), id(i, j + 1), id(i + 1, j), id(i + 1, j + 1));
            if i > 0 {
                t.push([a, b, c]);
            }
            if i + 1 < rings {
                t.push([b, d, c]);
            }
        }
    }
    (p, t)
}

fn write_glb(path: &Path, positions: &[DVec3], tris: &[[u32; 3]]) {
    let mut bin: Vec<u8> = positions
        .iter()
        .flat_map(|v| v.as_vec3().to_array())
        .flat_map(f32::to_le_bytes)
        .collect();
    let index_at = bin.len();
    bin.extend_from_slice(bytemuck::cast_slice(tris));
    let doc = serde_json::json!({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"name": "bowl", "mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": positions.len(), "type": "VEC3",
             "min": [-2, -2, -2], "max": [2, 2, 2]},
            {"bufferView": 1, "componentType": 5125, "count": 3 * tris.len(), "type": "SCALAR"}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": index_at},
            {"buffer": 0, "byteOffset": index_at, "byteLength": bin.len() - index_at}],
        "buffers": [{"byteLength": bin.len()}],
    });
    let mut json = serde_json::to_vec(&doc).unwrap();
    while json.len() % 4 != 0 {
        json.push(b' ');
    }
    let mut out = b"glTF".to_vec();
    out.extend(2u32.to_le_bytes());
    out.extend(((28 + json.len() + bin.len()) as u32).to_le_bytes());
    out.extend((json.len() as u32).to_le_bytes());
    out.extend(b"JSON");
    out.extend(&json);
    out.extend((bin.len() as u32).to_le_bytes());
    out.extend(b"BIN\0");
    out.extend(&bin);
    std::fs::write(path, out).unwrap();
}

fn tris_of(p: &[DVec3], t: &[[u32; 3]]) -> Vec<[DVec3; 3]> {
    t.iter().map(|t| t.map(|i| p[i as usize])).collect()
}

fn main() {
    let dir = std::env::args()
        .nth(1)
        .map_or(PathBuf::from("target/bench-clearance"), PathBuf::from);
    std::fs::create_dir_all(&dir).unwrap();
    let g = Guarantee {
        clearance: 0.001,
        bound: 0.02,
        everywhere: true,
    };
    // 1. The mesh (about 20k triangles) and the bowl (about 1M).
    let (mp, mt) = sphere(1.0, 100, 100, 0);
    let (bp, bt) = sphere(1.05, 720, 720, 72);
    let bowl = dir.join("bowl.glb");
    write_glb(&bowl, &bp, &bt);
    let t0 = Instant::now();
    let swept = Swept::new(tris_of(&mp, &mt));
    let t_mesh = t0.elapsed().as_secs_f64();
    let t0 = Instant::now();
    let obstacles = clearance::read_obstacles(&bowl).unwrap();
    let t_read = t0.elapsed().as_secs_f64();
    let o = &obstacles[0];
    let t0 = Instant::now();
    let c = clearance::measure(&swept, &g, &[], o);
    let t_measure = t0.elapsed().as_secs_f64();
    let t0 = Instant::now();
    let lows = map::lower_ends(&swept, &g, o, c.verdict);
    let t_map = t0.elapsed().as_secs_f64();
    let t0 = Instant::now();
    let bytes = sweptvol::io::gltf_out::clearance_glb(&[sweptvol::io::gltf_out::MapNode {
        name: "bowl",
        positions: o.positions.iter().map(|p| p.as_vec3().to_array()).collect(),
        triangles: &o.triangles,
        values: lows.iter().map(|&x| x as f32).collect(),
        colours: lows.iter().map(|&x| map::colour(x, 0.2)).collect(),
        closest: [[0.0; 3], [0.0; 3]],
        extras: serde_json::Value::Null,
    }])
    .unwrap();
    std::fs::write(dir.join("bowl.clearance.glb"), bytes).unwrap();
    let t_write = t0.elapsed().as_secs_f64();
    assert!((c.distance_to_mesh - 0.05).abs() < 0.01, "{c:?}");

    // 2. The witness search: a 100k-triangle sphere, 1,000 poses near a plate.
    let (pp, pt) = sphere(0.3, 224, 224, 0);
    let mut rng = fastrand::Rng::with_seed(28);
    let poses: Vec<(Option<u32>, Option<u64>, DMat4)> = (0..1000u32)
        .map(|i| {
            let j = |rng: &mut fastrand::Rng| (rng.f64() - 0.5) * 0.04;
            let rot = DQuat::from_euler(glam::EulerRot::XYZ, j(&mut rng), j(&mut rng), j(&mut rng));
            let t = DVec3::new(j(&mut rng), j(&mut rng), j(&mut rng));
            (
                Some(i),
                Some(i as u64 + 2),
                DMat4::from_rotation_translation(rot, t),
            )
        })
        .collect();
    let part = PosedPart {
        name: "ball".into(),
        bvh: Bvh::build(tris_of(&pp, &pt), 4),
        solid: true,
        poses,
    };
    // The obstacle hugs the part: a bowl of radius 0.35 (about 1M triangles) around it, and
    // the part's swept mesh stands in as a sphere of radius 0.32.
    let (lp, lt) = sphere(0.35, 720, 720, 72);
    let hug = clearance::Obstacle {
        name: "hug".into(),
        file: PathBuf::from("hug"),
        bvh: Bvh::build(tris_of(&lp, &lt), 4),
        positions: lp,
        triangles: lt,
        solid: false,
    };
    let (sp, st) = sphere(0.32, 100, 100, 0);
    let big = Swept::new(tris_of(&sp, &st));
    let t0 = Instant::now();
    let w = clearance::measure(&big, &g, std::slice::from_ref(&part), &hug);
    let t_witness = t0.elapsed().as_secs_f64();
    println!(
        "{}",
        serde_json::to_string_pretty(&serde_json::json!({
            "mesh_triangles": mt.len(),
            "obstacle_triangles": bt.len(),
            "seconds": {
                "mesh_bvh": t_mesh,
                "read_obstacle_and_bvh": t_read,
                "interval_and_verdict": t_measure,
                "map_lower_ends": t_map,
                "map_write": t_write,
                "total": t_mesh + t_read + t_measure + t_map + t_write,
            },
            "distance_to_mesh": c.distance_to_mesh,
            "witness_search": {
                "part_triangles": pt.len(),
                "poses": 1000,
                "seconds": t_witness,
                "nearest_pose": w.nearest_pose.map(|p| p.distance),
                "verdict": w.verdict,
            },
            "threads": rayon::current_num_threads(),
        }))
        .unwrap()
    );
}
