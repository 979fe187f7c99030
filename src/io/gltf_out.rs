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
    let (lo, hi) = bounds(&positions);
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

/// The box of `points` (an accessor's `min` and `max`).
fn bounds(points: &[[f32; 3]]) -> ([f32; 3], [f32; 3]) {
    let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for p in points {
        for c in 0..3 {
            lo[c] = lo[c].min(p[c]);
            hi[c] = hi[c].max(p[c]);
        }
    }
    (lo, hi)
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

/// One obstacle of a clearance map: world positions (f32), triangles, the lower end of the
/// clearance at each vertex (world units) and its colour, the closest points (on the obstacle,
/// on the swept mesh), and what goes into the node's `extras`.
pub struct MapNode<'a> {
    pub name: &'a str,
    pub positions: Vec<[f32; 3]>,
    pub triangles: &'a [[u32; 3]],
    pub values: Vec<f32>,
    pub colours: Vec<[f32; 3]>,
    pub closest: [[f32; 3]; 2],
    pub extras: serde_json::Value,
}

/// A clearance map as .glb: per obstacle a node with the lower end of the clearance at each
/// vertex in `_CLEARANCE` (f32, world units) and its colour in `COLOR_0`, and a child node
/// `NAME closest points` with a line from the obstacle's closest point to the mesh's.
pub fn clearance_glb(nodes: &[MapNode]) -> anyhow::Result<Vec<u8>> {
    if nodes.is_empty() || nodes.iter().any(|n| n.triangles.is_empty()) {
        bail!("a clearance map needs obstacles with triangles");
    }
    let mut bin: Vec<u8> = Vec::new();
    let (mut views, mut accessors, mut meshes, mut doc_nodes, mut roots) =
        (vec![], vec![], vec![], vec![], vec![]);
    // Appends a buffer view and an accessor over it; returns the accessor's index.
    let mut add = |bin: &mut Vec<u8>, bytes: &[u8], target: u32, accessor: serde_json::Value| {
        let at = bin.len();
        bin.extend_from_slice(bytes);
        let mut a = accessor;
        a["bufferView"] = json!(views.len());
        views.push(
            json!({"buffer": 0, "byteOffset": at, "byteLength": bytes.len(), "target": target}),
        );
        accessors.push(a);
        accessors.len() - 1
    };
    for n in nodes {
        let (lo, hi) = bounds(&n.positions);
        let (mlo, mhi) = bounds(&n.closest);
        let count = n.positions.len();
        let pos = add(
            &mut bin,
            bytemuck::cast_slice(&n.positions),
            34962,
            json!({"componentType": 5126, "count": count, "type": "VEC3", "min": lo, "max": hi}),
        );
        let val = add(
            &mut bin,
            bytemuck::cast_slice(&n.values),
            34962,
            json!({"componentType": 5126, "count": count, "type": "SCALAR"}),
        );
        let col = add(
            &mut bin,
            bytemuck::cast_slice(&n.colours),
            34962,
            json!({"componentType": 5126, "count": count, "type": "VEC3"}),
        );
        let idx = add(
            &mut bin,
            bytemuck::cast_slice(n.triangles),
            34963,
            json!({"componentType": 5125, "count": 3 * n.triangles.len(), "type": "SCALAR"}),
        );
        let line = add(
            &mut bin,
            bytemuck::cast_slice(&n.closest),
            34962,
            json!({"componentType": 5126, "count": 2, "type": "VEC3", "min": mlo, "max": mhi}),
        );
        meshes.push(json!({"name": n.name, "primitives": [{
            "attributes": {"POSITION": pos, "_CLEARANCE": val, "COLOR_0": col}, "indices": idx, "mode": 4}]}));
        meshes.push(json!({"name": format!("{} closest points", n.name),
            "primitives": [{"attributes": {"POSITION": line}, "mode": 1}]}));
        roots.push(doc_nodes.len());
        doc_nodes.push(
            json!({"name": n.name, "mesh": meshes.len() - 2, "extras": n.extras,
            "children": [doc_nodes.len() + 1]}),
        );
        doc_nodes
            .push(json!({"name": format!("{} closest points", n.name), "mesh": meshes.len() - 1}));
    }
    let doc = json!({
        "asset": {"version": "2.0", "generator": format!("sweptvol {}", env!("CARGO_PKG_VERSION"))},
        "scene": 0,
        "scenes": [{"nodes": roots}],
        "nodes": doc_nodes,
        "meshes": meshes,
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": bin.len()}],
    });
    pack_glb(&doc, bin)
}
