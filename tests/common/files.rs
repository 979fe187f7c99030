//! The binary and its input files, for the tests that run `sweptvol` itself.

use std::ffi::OsStr;
use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Run the binary under test with `RUST_LOG=warn`, so stderr holds warnings and errors only.
pub fn sweptvol<S: AsRef<OsStr>>(args: &[S]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_sweptvol"))
        .args(args)
        .env("RUST_LOG", "warn")
        .output()
        .expect("run sweptvol")
}

/// Write `bytes` to `dir/file` and return the path.
pub fn write(dir: &Path, file: &str, bytes: impl AsRef<[u8]>) -> PathBuf {
    let p = dir.join(file);
    fs::write(&p, bytes).unwrap();
    p
}

/// `sweptvol run` of `g` along `t` into `out` on the CPU backend, quietly, then `extra`; at
/// resolution 32 unless `extra` sets the accuracy.
pub fn run_args(g: &Path, t: &Path, out: &Path, extra: &[&str]) -> Vec<String> {
    let mut v: Vec<String> = [
        "run",
        "--generator",
        g.to_str().unwrap(),
        "--trajectory",
        t.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--backend",
        "cpu",
        "--quiet",
    ]
    .map(String::from)
    .to_vec();
    if !extra
        .iter()
        .any(|a| *a == "--resolution" || *a == "--tolerance")
    {
        v.extend(["--resolution".into(), "32".into()]);
    }
    v.extend(extra.iter().map(|s| s.to_string()));
    v
}

/// `sweptvol sweep --shard i/n` with [`run_args`]'s arguments.
pub fn sweep_args(g: &Path, t: &Path, out: &Path, shard: &str, extra: &[&str]) -> Vec<String> {
    let mut v = run_args(g, t, out, extra);
    v[0] = "sweep".into();
    v.extend(["--shard".into(), shard.into()]);
    v
}

/// `sweptvol verify` of mesh `m` against `g` along `t`, then `extra`.
pub fn verify_args(g: &Path, t: &Path, m: &Path, extra: &[&str]) -> Vec<String> {
    let mut v: Vec<String> = [
        "verify",
        "--generator",
        g.to_str().unwrap(),
        "--trajectory",
        t.to_str().unwrap(),
        "--mesh",
        m.to_str().unwrap(),
    ]
    .map(String::from)
    .to_vec();
    v.extend(extra.iter().map(|s| s.to_string()));
    v
}

/// A .glb with one node "part" holding one indexed triangle primitive (u32 indices); the
/// accessor's min and max are the positions' box.
pub fn glb(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Vec<u8> {
    glb_parts(&[("part", positions, triangles)])
}

/// One part of [`glb_parts`]: node name, positions, triangles.
pub type Part<'a> = (&'a str, &'a [[f32; 3]], &'a [[u32; 3]]);

/// A .glb with one node per part, each with its own mesh, as [`glb`].
pub fn glb_parts(parts: &[Part]) -> Vec<u8> {
    let nodes: Vec<Node> = parts
        .iter()
        .map(|&(name, positions, triangles)| Node {
            name,
            parent: None,
            translation: [0.0; 3],
            mesh: Some((positions, triangles)),
        })
        .collect();
    glb_nodes(&nodes)
}

/// Positions and triangles of one mesh.
pub type Mesh<'a> = (&'a [[f32; 3]], &'a [[u32; 3]]);

/// One node of [`glb_nodes`]: its name, its parent (an earlier node), its translation, and its
/// mesh if it has one.
pub struct Node<'a> {
    pub name: &'a str,
    pub parent: Option<usize>,
    pub translation: [f32; 3],
    pub mesh: Option<Mesh<'a>>,
}

/// A .glb with a node hierarchy; the roots form the scene.
pub fn glb_nodes(tree: &[Node]) -> Vec<u8> {
    let mut bin: Vec<u8> = Vec::new();
    let (mut accessors, mut views, mut meshes, mut nodes) = (vec![], vec![], vec![], vec![]);
    for node in tree {
        let mut json = serde_json::json!({"name": node.name, "translation": node.translation});
        if let Some((positions, triangles)) = node.mesh {
            let i = meshes.len();
            let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
            for p in positions.iter() {
                for c in 0..3 {
                    lo[c] = lo[c].min(p[c]);
                    hi[c] = hi[c].max(p[c]);
                }
            }
            let at = bin.len();
            bin.extend(positions.iter().flatten().flat_map(|x| x.to_le_bytes()));
            let index_at = bin.len();
            bin.extend(triangles.iter().flatten().flat_map(|i| i.to_le_bytes()));
            views.push(
                serde_json::json!({"buffer": 0, "byteOffset": at, "byteLength": index_at - at}),
            );
            views.push(serde_json::json!({"buffer": 0, "byteOffset": index_at, "byteLength": bin.len() - index_at}));
            accessors.push(
                serde_json::json!({"bufferView": 2 * i, "componentType": 5126,
                "count": positions.len(), "type": "VEC3", "min": lo, "max": hi}),
            );
            accessors.push(
                serde_json::json!({"bufferView": 2 * i + 1, "componentType": 5125,
                "count": 3 * triangles.len(), "type": "SCALAR"}),
            );
            meshes.push(serde_json::json!({"primitives": [{"attributes": {"POSITION": 2 * i}, "indices": 2 * i + 1}]}));
            json["mesh"] = i.into();
        }
        nodes.push(json);
    }
    for (i, node) in tree.iter().enumerate() {
        if let Some(p) = node.parent {
            let children = nodes[p]
                .as_object_mut()
                .unwrap()
                .entry("children")
                .or_insert(serde_json::json!([]));
            children.as_array_mut().unwrap().push(i.into());
        }
    }
    let roots: Vec<usize> = (0..tree.len())
        .filter(|&i| tree[i].parent.is_none())
        .collect();
    let doc = serde_json::json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": roots}],
        "nodes": nodes,
        "meshes": meshes,
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": bin.len()}],
    });
    let mut json = serde_json::to_vec(&doc).unwrap();
    while json.len() % 4 != 0 {
        json.push(b' ');
    }
    let total = 12 + 8 + json.len() + 8 + bin.len();
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    out
}

/// The Khronos glTF validator's report on `path` (its first JSON line), or None, said loudly,
/// where the validator is not installed and `SWEPTVOL_REQUIRE_VALIDATOR` is not 1 (CI sets it,
/// and then a missing validator fails the test).
pub fn khronos_report(path: &Path) -> Option<serde_json::Value> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/gltf-validator");
    if !root.join("node_modules/gltf-validator").exists() {
        if std::env::var("SWEPTVOL_REQUIRE_VALIDATOR").as_deref() == Ok("1") {
            panic!("SWEPTVOL_REQUIRE_VALIDATOR=1 but tools/gltf-validator is not installed (scripts/test-all.sh runs npm ci there)");
        }
        eprintln!("\n*** SKIPPED: the Khronos glTF validator is not installed (cd tools/gltf-validator && npm ci); {} was NOT validated. ***\n", path.display());
        return None;
    }
    let out = Command::new("node")
        .arg(root.join("validate.mjs"))
        .arg(path)
        .output()
        .expect("node");
    let report = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "validator: {report} {}",
        String::from_utf8_lossy(&out.stderr)
    );
    Some(serde_json::from_str(report.lines().next().unwrap()).unwrap())
}
