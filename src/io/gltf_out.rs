//! The swept-volume mesh as glTF 2.0 binary (.glb): one node, one triangle primitive with
//! POSITION and NORMAL (f32, world units and frame of the input) and u32 indices.

use std::path::Path;

use anyhow::{bail, Context};
use serde_json::json;

use crate::input::grid::Grid;
use crate::io::atomic;
use crate::mesh::Mesh;

/// World positions as f32 and the farthest that conversion moved a vertex (Euclidean distance,
/// world units).
pub fn world_positions(mesh: &Mesh, grid: &Grid) -> (Vec<[f32; 3]>, f64) {
    let mut worst: f64 = 0.0;
    let out = mesh
        .positions
        .iter()
        .map(|p| {
            let w = grid.to_world(*p);
            let f = [w.x as f32, w.y as f32, w.z as f32];
            worst = worst.max((glam::Vec3::from(f).as_dvec3() - w).length());
            f
        })
        .collect();
    (out, worst)
}

/// The .glb bytes for `mesh`. `extras` goes into the node's `extras` (the report's key figures).
pub fn glb_bytes(
    mesh: &Mesh,
    grid: &Grid,
    name: &str,
    extras: serde_json::Value,
) -> anyhow::Result<Vec<u8>> {
    if mesh.triangles.is_empty() {
        bail!("the swept volume mesh is empty: nothing to write");
    }
    let (positions, _) = world_positions(mesh, grid);
    let normals: Vec<[f32; 3]> = mesh
        .vertex_normals()
        .iter()
        .map(|n| {
            let f = n.as_vec3().normalize();
            [f.x, f.y, f.z]
        })
        .collect();
    let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for p in &positions {
        for c in 0..3 {
            lo[c] = lo[c].min(p[c]);
            hi[c] = hi[c].max(p[c]);
        }
    }
    let mut bin: Vec<u8> = Vec::new();
    bin.extend_from_slice(bytemuck::cast_slice(&positions));
    let normals_at = bin.len();
    bin.extend_from_slice(bytemuck::cast_slice(&normals));
    let indices_at = bin.len();
    bin.extend_from_slice(bytemuck::cast_slice(&mesh.triangles));
    let vertex_bytes = normals_at;
    let doc = json!({
        "asset": {"version": "2.0", "generator": format!("sweptvol {}", env!("CARGO_PKG_VERSION"))},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"name": name, "mesh": 0, "extras": extras}],
        "meshes": [{"name": name, "primitives": [{
            "attributes": {"POSITION": 0, "NORMAL": 1}, "indices": 2, "mode": 4}]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": positions.len(), "type": "VEC3",
             "min": lo, "max": hi},
            {"bufferView": 1, "componentType": 5126, "count": normals.len(), "type": "VEC3"},
            {"bufferView": 2, "componentType": 5125, "count": 3 * mesh.triangles.len(), "type": "SCALAR"},
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": vertex_bytes, "target": 34962},
            {"buffer": 0, "byteOffset": normals_at, "byteLength": indices_at - normals_at, "target": 34962},
            {"buffer": 0, "byteOffset": indices_at, "byteLength": bin.len() - indices_at, "target": 34963},
        ],
        "buffers": [{"byteLength": bin.len()}],
    });
    pack_glb(&doc, bin)
}

/// A .glb file of `doc` (JSON) and `bin` (its one buffer).
fn pack_glb(doc: &serde_json::Value, mut bin: Vec<u8>) -> anyhow::Result<Vec<u8>> {
    let mut json_bytes = serde_json::to_vec(doc)?;
    while json_bytes.len() % 4 != 0 {
        json_bytes.push(b' ');
    }
    while bin.len() % 4 != 0 {
        bin.push(0);
    }
    let total = 12 + 8 + json_bytes.len() + 8 + bin.len();
    let total32 =
        u32::try_from(total).context("the mesh is too large for one .glb file (4 GiB)")?;
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&total32.to_le_bytes());
    out.extend_from_slice(&(json_bytes.len() as u32).to_le_bytes());
    out.extend_from_slice(&0x4E4F_534Au32.to_le_bytes()); // "JSON"
    out.extend_from_slice(&json_bytes);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(&0x004E_4942u32.to_le_bytes()); // "BIN\0"
    out.extend_from_slice(&bin);
    Ok(out)
}

/// Write `mesh` to `path` as .glb, atomically.
pub fn write_glb(
    path: &Path,
    mesh: &Mesh,
    grid: &Grid,
    name: &str,
    extras: serde_json::Value,
) -> anyhow::Result<()> {
    atomic::write_atomic(path, &glb_bytes(mesh, grid, name, extras)?)
}

/// One obstacle's clearance map as .glb: the obstacle (world positions, f32) with the lower end
/// of the clearance at each vertex in `_CLEARANCE` (f32, world units) and its colour in
/// `COLOR_0`, and a node `closest points` with a line from the obstacle's closest point to the
/// mesh's. `extras` goes into the obstacle node's `extras`.
pub fn clearance_glb(
    name: &str,
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    values: &[f32],
    colours: &[[f32; 3]],
    closest: [[f32; 3]; 2],
    extras: serde_json::Value,
) -> anyhow::Result<Vec<u8>> {
    if triangles.is_empty() {
        bail!("the obstacle {name:?} has no triangles: no clearance map to write");
    }
    let bounds = |ps: &[[f32; 3]]| {
        let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for p in ps {
            for c in 0..3 {
                lo[c] = lo[c].min(p[c]);
                hi[c] = hi[c].max(p[c]);
            }
        }
        (lo, hi)
    };
    let mut bin: Vec<u8> = Vec::new();
    let mut views = Vec::new();
    let mut view = |bin: &mut Vec<u8>, bytes: &[u8], target: u32| {
        let at = bin.len();
        bin.extend_from_slice(bytes);
        views.push(
            json!({"buffer": 0, "byteOffset": at, "byteLength": bytes.len(), "target": target}),
        );
        views.len() - 1
    };
    let (lo, hi) = bounds(positions);
    let (mlo, mhi) = bounds(&closest);
    let v_pos = view(&mut bin, bytemuck::cast_slice(positions), 34962);
    let v_val = view(&mut bin, bytemuck::cast_slice(values), 34962);
    let v_col = view(&mut bin, bytemuck::cast_slice(colours), 34962);
    let v_idx = view(&mut bin, bytemuck::cast_slice(triangles), 34963);
    let v_line = view(&mut bin, bytemuck::cast_slice(&closest), 34962);
    let doc = json!({
        "asset": {"version": "2.0", "generator": format!("sweptvol {}", env!("CARGO_PKG_VERSION"))},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [
            {"name": name, "mesh": 0, "extras": extras},
            {"name": "closest points", "mesh": 1},
        ],
        "meshes": [
            {"name": name, "primitives": [{
                "attributes": {"POSITION": 0, "_CLEARANCE": 1, "COLOR_0": 2}, "indices": 3, "mode": 4}]},
            {"name": "closest points", "primitives": [{"attributes": {"POSITION": 4}, "mode": 1}]},
        ],
        "accessors": [
            {"bufferView": v_pos, "componentType": 5126, "count": positions.len(), "type": "VEC3",
             "min": lo, "max": hi},
            {"bufferView": v_val, "componentType": 5126, "count": values.len(), "type": "SCALAR"},
            {"bufferView": v_col, "componentType": 5126, "count": colours.len(), "type": "VEC3"},
            {"bufferView": v_idx, "componentType": 5125, "count": 3 * triangles.len(), "type": "SCALAR"},
            {"bufferView": v_line, "componentType": 5126, "count": 2, "type": "VEC3",
             "min": mlo, "max": mhi},
        ],
        "bufferViews": views,
        "buffers": [{"byteLength": bin.len()}],
    });
    pack_glb(&doc, bin)
}
