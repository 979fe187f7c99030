//! glTF 2.0 in (`.glb` or `.gltf`): the parts of the generator.
//!
//! Buffers come from the GLB binary chunk, base64 `data:` URIs, or files in the
//! folder of the glTF file (never outside it). Images are never read.

use std::borrow::Cow;
use std::collections::hash_map::{Entry, HashMap};
use std::path::{Component, Path, PathBuf};

use base64::engine::{DecodePaddingMode, GeneralPurpose, GeneralPurposeConfig};
use base64::Engine;
use glam::{DMat4, DQuat, DVec3, Vec3};
use gltf::accessor::{Accessor, DataType, Dimensions};
use gltf::buffer::{Source, View};
use gltf::json::validation::Error as ValidationError;
use gltf::mesh::Mode;
use gltf::scene::Transform;
use gltf::{Document, Gltf, Mesh, Node, Semantic};

use crate::error::InputError;
use crate::input::model::{Generator, Part, TreeNode};

/// The fix for a generator file that is not glTF at all.
const NOT_GLTF_FIX: &str = "give the generator as glTF 2.0 (.glb, or .gltf with its buffers); re-export it from the modelling tool";
const REEXPORT: &str = "re-export the file as glTF 2.0";
const EMBED: &str =
    "re-export with embedded buffers (e.g. as .glb), or put the .bin file next to the .gltf file";

/// Base64 as found in data URIs: standard alphabet, padding optional.
const BASE64: GeneralPurpose = GeneralPurpose::new(
    &base64::alphabet::STANDARD,
    GeneralPurposeConfig::new().with_decode_padding_mode(DecodePaddingMode::Indifferent),
);

/// Reads the glTF file at `path` and returns the parts of its scene.
pub fn read_generator(path: &Path) -> Result<Generator, InputError> {
    let bytes = std::fs::read(path).map_err(|e| {
        InputError::new(
            path,
            format!("cannot read the glTF file: {e}"),
            "check the path and the file's permissions",
        )
    })?;
    parse_generator(path, &bytes)
}

/// Parses glTF `bytes`; `path` names the file in messages and locates external buffers.
pub fn parse_generator(path: &Path, bytes: &[u8]) -> Result<Generator, InputError> {
    let gltf = open(path, bytes)?;
    refuse_ignored_geometry(path, &gltf.document)?;
    let buffers = load_buffers(path, &gltf)?;
    let mut generator = Generator::default();
    let roots = scene_roots(&gltf.document, &mut generator.warnings);
    collect_parts(path, &gltf.document, roots, &buffers, &mut generator)?;
    if generator.triangle_count() == 0 {
        return Err(InputError::new(
            path,
            "the scene has no triangles (points and lines are skipped)",
            "export a scene with at least one triangle mesh",
        ));
    }
    Ok(generator)
}

/// Reads any glTF mesh file as world-space triangles (f64): every triangle primitive of the
/// scene with node transforms applied, by the same reader, checks and errors as the generator.
/// Used by `sweptvol verify` for the mesh under test.
pub fn read_world_triangles(path: &Path) -> Result<Vec<[DVec3; 3]>, InputError> {
    // The mesh under test is no generator: a file of another kind gets the mesh's fix.
    let generator = read_generator(path).map_err(|mut e| {
        if e.fix == NOT_GLTF_FIX {
            e.fix = "give the mesh to check as glTF 2.0: the NAME.swept.glb that `sweptvol run` wrote, or a .glb exported from the modelling tool".into();
        }
        e
    })?;
    let mut out = Vec::with_capacity(generator.triangle_count());
    for part in &generator.parts {
        for t in &part.triangles {
            let tri = t.map(|i| {
                part.world
                    .transform_point3(part.positions[i as usize].as_dvec3())
            });
            if !tri.iter().all(|v| v.is_finite()) {
                return Err(InputError::new(
                    path,
                    "a vertex is not finite after applying the node transforms",
                    "fix the node transforms (scale or translation overflow) and re-export",
                )
                .in_column(format!("nodes[{}]", part.node_index)));
            }
            out.push(tri);
        }
    }
    Ok(out)
}

/// Refuse features that move or add geometry the reader would otherwise ignore: a sweep that
/// silently leaves geometry out underestimates.
fn refuse_ignored_geometry(path: &Path, doc: &gltf::Document) -> Result<(), InputError> {
    if doc
        .extensions_used()
        .any(|e| e == "EXT_mesh_gpu_instancing")
    {
        return Err(InputError::new(
            path,
            "the file uses EXT_mesh_gpu_instancing, whose extra mesh copies sweptvol does not read",
            "re-export with instances realized as ordinary nodes",
        )
        .in_column("extensionsUsed"));
    }
    let nonzero = |w: Option<&[f32]>| w.is_some_and(|w| w.iter().any(|x| *x != 0.0));
    for node in doc.nodes() {
        let Some(mesh) = node.mesh() else { continue };
        let morphs = mesh.primitives().any(|p| p.morph_targets().len() > 0);
        if morphs && (nonzero(mesh.weights()) || nonzero(node.weights())) {
            return Err(InputError::new(
                path,
                format!(
                    "mesh {} has morph targets (shape keys) with non-zero weights; only the base shape would be swept",
                    mesh.name().map_or_else(|| mesh.index().to_string(), |n| format!("{n:?}"))
                ),
                "apply the shape keys (or set their weights to 0) before exporting",
            )
            .in_column(format!("nodes[{}]", node.index())));
        }
    }
    Ok(())
}

/// Parses and validates the document. Missing or malformed POSITION `min`/`max`
/// are tolerated: they are required by the spec but never used here.
fn open(path: &Path, bytes: &[u8]) -> Result<Gltf, InputError> {
    check_container(path, bytes)?;
    let gltf = parse_document(path, bytes)?;
    let version = &gltf.document.as_json().asset.version;
    if version.split('.').next() != Some("2") {
        return Err(InputError::new(
            path,
            format!("the file is glTF {version:?}; only glTF 2.0 is supported"),
            "re-export the file as glTF 2.0 (glTF 1.0 files are not read)",
        )
        .in_column("asset.version"));
    }
    Ok(gltf)
}

/// A GLB starts with the magic `glTF` and version 2, a .gltf with a JSON object: anything else
/// is named for what it is rather than reported as a JSON syntax error.
fn check_container(path: &Path, bytes: &[u8]) -> Result<(), InputError> {
    if let Some(header) = bytes.strip_prefix(b"glTF") {
        let version = header
            .get(..4)
            .map(|v| u32::from_le_bytes([v[0], v[1], v[2], v[3]]));
        return match version {
            Some(2) => Ok(()),
            Some(v) => Err(InputError::new(
                path,
                format!(
                    "the GLB container has version {v}; only version 2 (glTF 2.0) is supported"
                ),
                REEXPORT,
            )),
            None => Err(InputError::new(
                path,
                format!(
                    "the file is {} bytes: too short for a GLB header",
                    bytes.len()
                ),
                "the file is truncated: re-export it",
            )),
        };
    }
    let text = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
    if text.iter().find(|b| !b.is_ascii_whitespace()) == Some(&b'{') {
        return Ok(());
    }
    let head = &bytes[..bytes.len().min(8)];
    let hex: Vec<String> = head.iter().map(|b| format!("{b:02x}")).collect();
    let ascii: String = head
        .iter()
        .map(|&b| {
            if b.is_ascii_graphic() || b == b' ' {
                b as char
            } else {
                '.'
            }
        })
        .collect();
    Err(InputError::new(
        path,
        format!(
            "not a glTF or GLB file: it starts with the bytes {} ({ascii:?}); a .glb starts with \"glTF\", a .gltf with a JSON object",
            if hex.is_empty() { "(none: the file is empty)".to_string() } else { hex.join(" ") }
        ),
        NOT_GLTF_FIX,
    ))
}

fn parse_document(path: &Path, bytes: &[u8]) -> Result<Gltf, InputError> {
    use gltf::json::validation::Validate;
    let gltf = Gltf::from_slice_without_validation(bytes).map_err(|e| parse_error(path, e))?;
    let json = gltf.document.as_json();
    // gltf-json 1.4's validation indexes `accessors` by each POSITION attribute without a bounds
    // check (a panic, found by tests/fuzz_readers.rs): refuse such an index first.
    for (m, mesh) in json.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            for (semantic, index) in &prim.attributes {
                if index.value() >= json.accessors.len() {
                    return Err(InputError::new(
                        path,
                        format!(
                            "attribute {semantic:?} names accessor {} but the file has {} accessors",
                            index.value(),
                            json.accessors.len()
                        ),
                        REEXPORT,
                    )
                    .in_column(format!("meshes[{m}].primitives[{p}].attributes")));
                }
            }
        }
    }
    let mut errors = Vec::new();
    json.validate(json, gltf::json::Path::new, &mut |at, e| {
        errors.push((at(), e))
    });
    let tolerated =
        |p: &str| p.ends_with("[\"POSITION\"].min") || p.ends_with("[\"POSITION\"].max");
    errors.retain(|(at, _)| !tolerated(at.as_str()));
    if errors.is_empty() {
        Ok(gltf)
    } else {
        Err(parse_error(path, gltf::Error::Validation(errors)))
    }
}

fn parse_error(path: &Path, error: gltf::Error) -> InputError {
    let gltf::Error::Validation(errors) = error else {
        return InputError::new(
            path,
            format!("not a valid glTF 2.0 file: {error}"),
            REEXPORT,
        );
    };
    let (at, kind) = &errors[0];
    let more = match errors.len() {
        1 => String::new(),
        n => format!(" (and {} more problems)", n - 1),
    };
    let (message, fix) = match kind {
        ValidationError::Missing if at.as_str().ends_with("[\"POSITION\"]") => (
            "the primitive has no POSITION attribute".to_string(),
            "give every mesh primitive vertex positions and re-export",
        ),
        ValidationError::Unsupported => (
            "a required glTF extension is not supported".to_string(),
            "re-export without that extension (mesh compression such as Draco or meshopt is not supported)",
        ),
        _ => (format!("invalid glTF: {kind}"), REEXPORT),
    };
    InputError::new(path, message + &more, fix).in_column(at.to_string())
}

/// The bytes of every buffer, checked against its `byteLength`.
fn load_buffers<'g>(path: &Path, gltf: &'g Gltf) -> Result<Vec<Cow<'g, [u8]>>, InputError> {
    gltf.buffers()
        .map(|buffer| {
            let at = format!("buffers[{}]", buffer.index());
            let data = match buffer.source() {
                Source::Bin => Cow::Borrowed(gltf.blob.as_deref().ok_or_else(|| {
                    InputError::new(
                        path,
                        "the buffer has no URI, but the file has no GLB binary chunk",
                        REEXPORT,
                    )
                    .in_column(&at)
                })?),
                Source::Uri(uri) => Cow::Owned(read_uri(path, uri).map_err(|e| e.in_column(&at))?),
            };
            if data.len() < buffer.length() {
                return Err(InputError::new(
                    path,
                    format!(
                        "the buffer holds {} bytes but its byteLength is {}",
                        data.len(),
                        buffer.length()
                    ),
                    "the buffer data is truncated: re-export the file",
                )
                .in_column(at));
            }
            Ok(data)
        })
        .collect()
}

/// Decodes a base64 data URI, or reads a relative file URI confined to the glTF file's folder.
fn read_uri(path: &Path, uri: &str) -> Result<Vec<u8>, InputError> {
    let scheme = uri.split_once(':').map(|(s, _)| s).filter(|s| {
        s.starts_with(|c: char| c.is_ascii_alphabetic())
            && s.chars()
                .all(|c| c.is_ascii_alphanumeric() || "+-.".contains(c))
    });
    if scheme.is_some_and(|s| s.eq_ignore_ascii_case("data")) {
        let (header, data) = uri.split_once(',').unwrap_or((uri, ""));
        if !header.ends_with(";base64") {
            return Err(InputError::new(
                path,
                format!("data URI \"{header},...\" is not base64"),
                EMBED,
            ));
        }
        return BASE64.decode(data).map_err(|e| {
            InputError::new(
                path,
                format!("the base64 data URI is corrupt: {e}"),
                REEXPORT,
            )
        });
    }
    let outside = |why: &str| {
        InputError::new(
            path,
            format!(
                "buffer URI \"{uri}\" points outside the folder of the glTF file ({why}); \
                 buffers must sit in the same folder as the glTF file"
            ),
            EMBED,
        )
    };
    if let Some(s) = scheme {
        return Err(outside(&format!("scheme {s}: is not allowed")));
    }
    let relative = PathBuf::from(percent_decode(uri).ok_or_else(|| {
        InputError::new(
            path,
            format!("buffer URI \"{uri}\" is not a valid URI"),
            EMBED,
        )
    })?);
    let mut depth = 0usize;
    for component in relative.components() {
        match component {
            Component::Normal(_) => depth += 1,
            Component::CurDir => {}
            Component::ParentDir if depth > 0 => depth -= 1,
            Component::ParentDir => return Err(outside("it climbs out with \"..\"")),
            Component::RootDir | Component::Prefix(_) => {
                return Err(outside("it is an absolute path"))
            }
        }
    }
    let folder = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let file = folder.join(&relative);
    let missing = |e: std::io::Error| {
        InputError::new(
            path,
            format!("cannot read buffer file {}: {e}", file.display()),
            format!(
                "put {} next to the glTF file, or re-export with embedded buffers (e.g. as .glb)",
                relative.display()
            ),
        )
    };
    let real_file = file.canonicalize().map_err(missing)?;
    let real_folder = folder.canonicalize().map_err(missing)?;
    if !real_file.starts_with(&real_folder) {
        return Err(outside(&format!("it resolves to {}", real_file.display())));
    }
    // A FIFO or device would block the reader or never end: only plain files are read.
    if !std::fs::metadata(&real_file).map_err(missing)?.is_file() {
        return Err(InputError::new(
            path,
            format!("buffer {} is not a regular file", file.display()),
            "point the buffer URI at a plain .bin file".to_string(),
        ));
    }
    std::fs::read(&real_file).map_err(missing)
}

/// Decodes `%XX` escapes; `None` for a bad escape or non-UTF-8 result.
fn percent_decode(s: &str) -> Option<String> {
    let mut out = Vec::with_capacity(s.len());
    let mut bytes = s.bytes();
    while let Some(b) = bytes.next() {
        if b == b'%' {
            let hex = [bytes.next()?, bytes.next()?];
            out.push(u8::from_str_radix(std::str::from_utf8(&hex).ok()?, 16).ok()?);
        } else {
            out.push(b);
        }
    }
    String::from_utf8(out).ok()
}

/// Root nodes of the default scene, else the first scene, else of the whole node forest.
fn scene_roots<'a>(doc: &'a Document, warnings: &mut Vec<String>) -> Vec<Node<'a>> {
    if let Some(scene) = doc.default_scene().or_else(|| doc.scenes().next()) {
        return scene.nodes().collect();
    }
    let mut is_child = vec![false; doc.nodes().len()];
    for child in doc.nodes().flat_map(|n| n.children()) {
        is_child[child.index()] = true;
    }
    let roots: Vec<Node> = doc.nodes().filter(|n| !is_child[n.index()]).collect();
    warnings.push(format!(
        "the file has no scene: using all {} root nodes (nodes that are no one's child)",
        roots.len()
    ));
    roots
}

/// Positions and triangles of one mesh, all its triangle primitives merged.
#[derive(Clone, Default)]
struct Geometry {
    positions: Vec<Vec3>,
    triangles: Vec<[u32; 3]>,
}

/// Walks the node trees depth first, one `Part` per node with triangles.
fn collect_parts(
    path: &Path,
    doc: &Document,
    roots: Vec<Node>,
    buffers: &[Cow<[u8]>],
    generator: &mut Generator,
) -> Result<(), InputError> {
    let mut seen = vec![false; doc.nodes().len()];
    let mut meshes: HashMap<usize, Geometry> = HashMap::new();
    let mut stack: Vec<(Node, DMat4, Option<usize>)> = roots
        .into_iter()
        .rev()
        .map(|n| (n, DMat4::IDENTITY, None))
        .collect();
    while let Some((node, parent, parent_index)) = stack.pop() {
        let at = format!("nodes[{}]", node.index());
        if std::mem::replace(&mut seen[node.index()], true) {
            return Err(InputError::new(
                path,
                "the node is reached twice: the node hierarchy has a cycle or a node with two parents",
                "repair the hierarchy (every node has at most one parent) and re-export",
            )
            .in_column(at));
        }
        let label = match node.name() {
            Some(name) => format!("{at} ({name:?})"),
            None => at.clone(),
        };
        if let Transform::Matrix { matrix } = node.transform() {
            // Column-major: the last row is element 3 of each column.
            let last_row = matrix.map(|column| column[3]);
            if last_row != [0.0, 0.0, 0.0, 1.0] {
                return Err(InputError::new(
                    path,
                    format!(
                        "the node's matrix is not affine: its last row is {} {} {} {}, not 0 0 0 1 (projective transforms are not supported)",
                        last_row[0], last_row[1], last_row[2], last_row[3]
                    ),
                    "give the node an affine matrix (column-major elements 3, 7, 11, 15 = 0, 0, 0, 1) or translation/rotation/scale, then re-export",
                )
                .in_column(label));
            }
        }
        let local = local_matrix(&node);
        let world = parent * local;
        if !world.is_finite() {
            return Err(InputError::new(
                path,
                "the node's world transform is not finite (NaN, infinity or a zero quaternion)",
                "fix the transforms of the node and its parents, then re-export",
            )
            .in_column(at));
        }
        if let Some(mesh) = node.mesh() {
            if let Some(det) = singular(&world) {
                return Err(InputError::new(
                    path,
                    format!(
                        "the node's world transform is singular (its 3x3 part has determinant {}): a zero scale or a degenerate matrix flattens the mesh",
                        crate::error::num(det)
                    ),
                    "give the node and its parents non-zero scales and invertible matrices, then re-export (an object hidden by scaling it to zero must be deleted or left out of the export instead)",
                )
                .in_column(label));
            }
            if node.skin().is_some() {
                generator.warnings.push(format!(
                    "{at}: skinning is ignored; the mesh is placed by the node transform"
                ));
            }
            let geometry = match meshes.entry(mesh.index()) {
                Entry::Occupied(cached) => cached.get().clone(),
                Entry::Vacant(slot) => slot
                    .insert(read_mesh(path, &mesh, buffers, &mut generator.warnings)?)
                    .clone(),
            };
            if !geometry.triangles.is_empty() {
                generator.parts.push(Part {
                    node_index: node.index(),
                    node_name: node.name().map(str::to_string),
                    world,
                    positions: geometry.positions,
                    triangles: geometry.triangles,
                });
            }
        }
        generator.nodes.push(TreeNode {
            index: node.index(),
            name: node.name().map(str::to_string),
            parent: parent_index,
            local,
        });
        let children: Vec<Node> = node.children().collect();
        stack.extend(
            children
                .into_iter()
                .rev()
                .map(|c| (c, world, Some(node.index()))),
        );
    }
    Ok(())
}

/// The determinant of `m`'s 3x3 part when it is singular, by the trajectory reader's rule:
/// |det| at most 1e-12 times the product of the column lengths (or a zero column).
fn singular(m: &DMat4) -> Option<f64> {
    let linear = glam::DMat3::from_mat4(*m);
    let det = linear.determinant();
    let scale = linear.x_axis.length() * linear.y_axis.length() * linear.z_axis.length();
    (scale == 0.0 || det.abs() <= 1e-12 * scale || !det.is_finite()).then_some(det)
}

/// The node's local matrix in f64 (TRS composed in f64, quaternion normalised).
fn local_matrix(node: &Node) -> DMat4 {
    match node.transform() {
        Transform::Matrix { matrix } => {
            DMat4::from_cols_array_2d(&matrix.map(|c| c.map(f64::from)))
        }
        Transform::Decomposed {
            translation,
            rotation,
            scale,
        } => DMat4::from_scale_rotation_translation(
            DVec3::from_array(scale.map(f64::from)),
            DQuat::from_array(rotation.map(f64::from)).normalize(),
            DVec3::from_array(translation.map(f64::from)),
        ),
    }
}

/// Reads every triangle-like primitive of `mesh`; points and lines are skipped with a warning.
fn read_mesh(
    path: &Path,
    mesh: &Mesh,
    buffers: &[Cow<[u8]>],
    warnings: &mut Vec<String>,
) -> Result<Geometry, InputError> {
    let mut geometry = Geometry::default();
    let label = match mesh.name() {
        Some(name) => format!("mesh \"{name}\""),
        None => format!("mesh {}", mesh.index()),
    };
    for prim in mesh.primitives() {
        let at = format!("meshes[{}].primitives[{}]", mesh.index(), prim.index());
        let err = |message: String, fix: &str| InputError::new(path, message, fix).in_column(&at);
        let mode = prim.mode();
        if matches!(
            mode,
            Mode::Points | Mode::Lines | Mode::LineLoop | Mode::LineStrip
        ) {
            warnings.push(format!(
                "{at} ({label}): {mode:?} primitive skipped, only triangles are swept"
            ));
            continue;
        }
        let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &**d));
        let unreadable = |acc: &Accessor| {
            err(
                format!(
                    "cannot read accessor {}: its buffer view lies outside its buffer",
                    acc.index()
                ),
                REEXPORT,
            )
        };

        let positions: Vec<Vec3> = {
            let acc = prim.get(&Semantic::Positions).ok_or_else(|| {
                err(
                    format!("{label}: the primitive has no POSITION attribute"),
                    "give every mesh primitive vertex positions and re-export",
                )
            })?;
            if acc.data_type() != DataType::F32 || acc.dimensions() != Dimensions::Vec3 {
                return Err(err(
                    format!(
                        "{label}: POSITION is {:?} {:?}, not float VEC3 (quantized positions)",
                        acc.dimensions(),
                        acc.data_type()
                    ),
                    "export float positions (turn off vertex quantization / KHR_mesh_quantization)",
                ));
            }
            check_accessor(&acc).map_err(|m| err(m, REEXPORT))?;
            let read = reader.read_positions().ok_or_else(|| unreadable(&acc))?;
            read.map(Vec3::from_array).collect()
        };
        if let Some(v) = positions.iter().position(|p| !p.is_finite()) {
            return Err(err(
                format!(
                    "{label}: vertex {v} has a non-finite position {}",
                    positions[v]
                ),
                "remove or correct the vertex (NaN or infinity) in the modelling tool and re-export",
            ));
        }

        let indices: Vec<u32> = match prim.indices() {
            None => (0..positions.len() as u32).collect(),
            Some(acc) => {
                if !matches!(
                    acc.data_type(),
                    DataType::U8 | DataType::U16 | DataType::U32
                ) || acc.dimensions() != Dimensions::Scalar
                {
                    return Err(err(
                        format!(
                            "{label}: indices are {:?} {:?}, not unsigned integer SCALAR",
                            acc.dimensions(),
                            acc.data_type()
                        ),
                        REEXPORT,
                    ));
                }
                check_accessor(&acc).map_err(|m| err(m, REEXPORT))?;
                let read = reader.read_indices().ok_or_else(|| unreadable(&acc))?;
                read.into_u32().collect()
            }
        };
        if let Some(k) = indices.iter().position(|&i| i as usize >= positions.len()) {
            return Err(err(
                format!(
                    "{label}: index {} (entry {k} of the index list) is out of range: the primitive has {} vertices",
                    indices[k],
                    positions.len()
                ),
                "the index data is corrupt: re-export the file",
            ));
        }

        if geometry.positions.len() + positions.len() > u32::MAX as usize {
            return Err(err(
                format!("{label} has 2^32 vertices or more"),
                "split the mesh",
            ));
        }
        let base = geometry.positions.len() as u32;
        let triangles: Vec<[u32; 3]> = match mode {
            Mode::TriangleStrip => (0..indices.len().saturating_sub(2))
                .map(|i| {
                    let t = [indices[i], indices[i + 1], indices[i + 2]];
                    if i % 2 == 1 {
                        [t[1], t[0], t[2]]
                    } else {
                        t
                    }
                })
                .collect(),
            Mode::TriangleFan => (1..indices.len().saturating_sub(1))
                .map(|i| [indices[0], indices[i], indices[i + 1]])
                .collect(),
            _ => {
                if indices.len() % 3 != 0 {
                    warnings.push(format!(
                        "{at} ({label}): the index count {} is not a multiple of 3; the last {} are ignored",
                        indices.len(),
                        indices.len() % 3
                    ));
                }
                let chunks = indices.chunks_exact(3);
                chunks.map(|t| [t[0], t[1], t[2]]).collect()
            }
        };
        geometry
            .triangles
            .extend(triangles.into_iter().map(|t| t.map(|i| i + base)));
        geometry.positions.extend(positions);
    }
    Ok(geometry)
}

/// Checks what gltf's reader assumes (and would panic on otherwise): `1 <= count <= u32::MAX`,
/// strides at least the element size, byte ranges inside their buffer views without overflow.
fn check_accessor(acc: &Accessor) -> Result<(), String> {
    let fits = |view: View, offset: usize, count: usize, elem: usize| {
        let stride = view.stride().unwrap_or(elem);
        let end = (count.checked_sub(1))
            .and_then(|c| c.checked_mul(stride))
            .and_then(|s| s.checked_add(offset))
            .and_then(|s| s.checked_add(elem));
        stride >= elem
            && end.is_some_and(|end| end <= view.length())
            && view.offset().checked_add(view.length()).is_some()
    };
    let count = acc.count();
    let ok = (1..=u32::MAX as usize).contains(&count)
        && acc
            .view()
            .is_none_or(|v| fits(v, acc.offset(), count, acc.size()))
        && acc.sparse().is_none_or(|s| {
            let (indices, values) = (s.indices(), s.values());
            fits(
                indices.view(),
                indices.offset(),
                s.count(),
                indices.index_type().size(),
            ) && fits(values.view(), values.offset(), s.count(), acc.size())
        });
    if ok {
        Ok(())
    } else {
        Err(format!(
            "accessor {} is malformed: its count, offset or stride does not fit its buffer view",
            acc.index()
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::{json, Value};

    /// Accumulates binary data, buffer views and accessors for a test document.
    #[derive(Default)]
    struct Builder {
        bin: Vec<u8>,
        views: Vec<Value>,
        accessors: Vec<Value>,
    }

    impl Builder {
        fn view(&mut self, bytes: &[u8]) -> usize {
            self.views.push(
                json!({"buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len()}),
            );
            self.bin.extend_from_slice(bytes);
            self.bin.resize(self.bin.len().next_multiple_of(4), 0);
            self.views.len() - 1
        }

        fn accessor(&mut self, accessor: Value) -> usize {
            self.accessors.push(accessor);
            self.accessors.len() - 1
        }

        fn positions(&mut self, p: &[[f32; 3]]) -> usize {
            let bytes: Vec<u8> = p.iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
            let view = self.view(&bytes);
            self.accessor(
                json!({"bufferView": view, "componentType": 5126, "count": p.len(),
                "type": "VEC3", "min": [-1e9, -1e9, -1e9], "max": [1e9, 1e9, 1e9]}),
            )
        }

        fn indices(&mut self, i: &[u32]) -> usize {
            let bytes: Vec<u8> = i.iter().flat_map(|x| x.to_le_bytes()).collect();
            let view = self.view(&bytes);
            self.accessor(json!({"bufferView": view, "componentType": 5125, "count": i.len(), "type": "SCALAR"}))
        }

        /// The document: `rest` (meshes, nodes, scenes, ...) plus the buffer, views and accessors.
        fn finish(self, rest: Value) -> (Value, Vec<u8>) {
            let mut doc = json!({
                "asset": {"version": "2.0"},
                "buffers": [{"byteLength": self.bin.len()}],
                "bufferViews": self.views,
                "accessors": self.accessors,
            });
            for (k, v) in rest.as_object().unwrap() {
                doc[k] = v.clone();
            }
            (doc, self.bin)
        }
    }

    const TRI: [[f32; 3]; 3] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];

    /// One indexed triangle mesh on one node in one scene.
    fn one_triangle() -> (Value, Vec<u8>) {
        let mut b = Builder::default();
        let pos = b.positions(&TRI);
        let idx = b.indices(&[0, 1, 2]);
        b.finish(json!({
            "meshes": [{"primitives": [{"attributes": {"POSITION": pos}, "indices": idx}]}],
            "nodes": [{"mesh": 0, "name": "tri"}],
            "scenes": [{"nodes": [0]}],
        }))
    }

    /// Writes `name.gltf` with the buffer in `bin_name` next to it.
    fn write_external(dir: &Path, mut doc: Value, bin: &[u8], bin_name: &str) -> PathBuf {
        doc["buffers"][0]["uri"] = json!(bin_name);
        std::fs::write(dir.join(bin_name.replace("%20", " ")), bin).unwrap();
        let path = dir.join("scene.gltf");
        std::fs::write(&path, doc.to_string()).unwrap();
        path
    }

    fn with_data_uri(mut doc: Value, bin: &[u8]) -> Vec<u8> {
        let uri = format!(
            "data:application/octet-stream;base64,{}",
            BASE64.encode(bin)
        );
        doc["buffers"][0]["uri"] = json!(uri);
        doc.to_string().into_bytes()
    }

    /// A GLB container: header, JSON chunk (space padded), BIN chunk (zero padded).
    fn glb(doc: &Value, bin: &[u8]) -> Vec<u8> {
        let mut json = doc.to_string().into_bytes();
        json.resize(json.len().next_multiple_of(4), b' ');
        let mut bin = bin.to_vec();
        bin.resize(bin.len().next_multiple_of(4), 0);
        let total = 12 + 8 + json.len() + 8 + bin.len();
        let mut out = Vec::with_capacity(total);
        out.extend_from_slice(b"glTF");
        out.extend_from_slice(&2u32.to_le_bytes());
        out.extend_from_slice(&(total as u32).to_le_bytes());
        for (chunk, ty) in [(&json, 0x4E4F534Au32), (&bin, 0x004E4942)] {
            out.extend_from_slice(&(chunk.len() as u32).to_le_bytes());
            out.extend_from_slice(&ty.to_le_bytes());
            out.extend_from_slice(chunk);
        }
        out
    }

    fn parse(bytes: &[u8]) -> Result<Generator, InputError> {
        parse_generator(Path::new("/nonexistent/test.gltf"), bytes)
    }

    fn parse_err(bytes: &[u8]) -> InputError {
        parse(bytes).expect_err("expected an error")
    }

    fn assert_mat(a: DMat4, b: DMat4) {
        assert!(a.abs_diff_eq(b, 1e-12), "{a} != {b}");
    }

    #[test]
    fn hierarchy_composes_world_matrices_in_f64() {
        let mut b = Builder::default();
        let pos = b.positions(&TRI);
        let (r, c) = (
            std::f32::consts::FRAC_1_SQRT_2,
            std::f32::consts::FRAC_1_SQRT_2,
        );
        let mut child_matrix = [0.0f32; 16];
        child_matrix[0] = 1.0;
        child_matrix[5] = 1.0;
        child_matrix[10] = 1.0;
        child_matrix[15] = 1.0;
        child_matrix[12] = 1.0; // column-major: translation (1, 0, 0)
        let (doc, bin) = b.finish(json!({
            "meshes": [{"primitives": [{"attributes": {"POSITION": pos}}]}],
            "nodes": [
                {"name": "parent", "children": [1], "mesh": 0, "translation": [1.0, 2.0, 3.0],
                 "rotation": [0.0, 0.0, r, c], "scale": [2.0, 2.0, 2.0]},
                {"name": "child", "mesh": 0, "matrix": child_matrix},
            ],
            "scenes": [{"nodes": [0]}],
        }));
        let dir = tempfile::tempdir().unwrap();
        let path = write_external(dir.path(), doc, &bin, "my%20mesh.bin");
        let g = read_generator(&path).unwrap();
        assert_eq!(g.parts.len(), 2);
        let (parent, child) = (&g.parts[0], &g.parts[1]);
        assert_eq!((parent.node_index, child.node_index), (0, 1));
        assert_eq!(child.node_name.as_deref(), Some("child"));
        let rot = DMat4::from_rotation_z(std::f64::consts::FRAC_PI_2);
        let expected_parent = DMat4::from_translation(DVec3::new(1.0, 2.0, 3.0))
            * rot
            * DMat4::from_scale(DVec3::splat(2.0));
        assert_mat(parent.world, expected_parent);
        assert_mat(
            child.world,
            expected_parent * DMat4::from_translation(DVec3::X),
        );
        // (1,0,0) scaled to (2,0,0), rotated to (0,2,0), translated to (1,4,3).
        let origin = child.world.transform_point3(DVec3::ZERO);
        assert!(
            origin.abs_diff_eq(DVec3::new(1.0, 4.0, 3.0), 1e-12),
            "{origin}"
        );
        // Positions stay in the local frame.
        assert_eq!(child.positions, TRI.map(Vec3::from_array).to_vec());
        assert_eq!(child.triangles, vec![[0, 1, 2]]);
        assert!(g.warnings.is_empty(), "{:?}", g.warnings);
    }

    #[test]
    fn mesh_instanced_twice_gives_two_parts() {
        let (mut doc, bin) = one_triangle();
        doc["nodes"] = json!([
            {"mesh": 0, "name": "a", "translation": [5.0, 0.0, 0.0]},
            {"mesh": 0, "name": "b", "translation": [-5.0, 0.0, 0.0]},
        ]);
        doc["scenes"] = json!([{"nodes": [0, 1]}]);
        let g = parse(&with_data_uri(doc, &bin)).unwrap();
        assert_eq!(g.parts.len(), 2);
        assert_eq!(g.triangle_count(), 2);
        assert_eq!(g.parts[0].positions, g.parts[1].positions);
        assert_eq!(g.parts[1].node_name.as_deref(), Some("b"));
        assert_eq!(g.parts[1].world.w_axis.x, -5.0);
    }

    #[test]
    fn gltf_buffer_mime_type_is_accepted() {
        let (mut doc, bin) = one_triangle();
        doc["buffers"][0]["uri"] = json!(format!(
            "data:application/gltf-buffer;base64,{}",
            BASE64.encode(&bin)
        ));
        assert_eq!(
            parse(doc.to_string().as_bytes()).unwrap().triangle_count(),
            1
        );
    }

    #[test]
    fn strips_fans_and_points_in_glb() {
        let mut b = Builder::default();
        let five: Vec<[f32; 3]> = (0..5).map(|i| [i as f32, (i % 2) as f32, 0.0]).collect();
        let strip_pos = b.positions(&five);
        let strip_idx = b.indices(&[0, 1, 2, 3, 4]);
        let fan_pos = b.positions(&five);
        let points_pos = b.positions(&TRI);
        let (doc, bin) = b.finish(json!({
            "meshes": [{"name": "mixed", "primitives": [
                {"attributes": {"POSITION": strip_pos}, "indices": strip_idx, "mode": 5},
                {"attributes": {"POSITION": points_pos}, "mode": 0},
                {"attributes": {"POSITION": fan_pos}, "mode": 6},
            ]}],
            "nodes": [{"mesh": 0}],
            "scenes": [{"nodes": [0]}],
        }));
        let g = parse(&glb(&doc, &bin)).unwrap();
        assert_eq!(g.parts.len(), 1);
        let part = &g.parts[0];
        assert_eq!(part.positions.len(), 10, "points positions are not merged");
        assert_eq!(
            part.triangles,
            vec![
                [0, 1, 2],
                [2, 1, 3],
                [2, 3, 4],
                [5, 6, 7],
                [5, 7, 8],
                [5, 8, 9]
            ]
        );
        assert_eq!(g.warnings.len(), 1);
        assert!(
            g.warnings[0].contains("meshes[0].primitives[1]"),
            "{}",
            g.warnings[0]
        );
        assert!(g.warnings[0].contains("Points"), "{}", g.warnings[0]);
    }

    #[test]
    fn non_indexed_triangles_keep_degenerate_and_duplicate_ones() {
        let mut b = Builder::default();
        let p = [TRI, TRI, [[0.0; 3]; 3]].concat();
        let pos = b.positions(&p);
        let (doc, bin) = b.finish(json!({
            "meshes": [{"primitives": [{"attributes": {"POSITION": pos}}]}],
            "nodes": [{"mesh": 0}],
            "scenes": [{"nodes": [0]}],
        }));
        let g = parse(&glb(&doc, &bin)).unwrap();
        assert_eq!(g.parts[0].triangles, vec![[0, 1, 2], [3, 4, 5], [6, 7, 8]]);
        assert_eq!(g.parts[0].positions.len(), 9);
    }

    #[test]
    fn default_scene_is_chosen() {
        let (mut doc, bin) = one_triangle();
        doc["nodes"] = json!([{"mesh": 0, "name": "first"}, {"mesh": 0, "name": "second"}]);
        doc["scenes"] = json!([{"nodes": [0]}, {"nodes": [1]}]);
        doc["scene"] = json!(1);
        let g = parse(&with_data_uri(doc.clone(), &bin)).unwrap();
        assert_eq!(g.parts.len(), 1);
        assert_eq!(g.parts[0].node_name.as_deref(), Some("second"));

        doc.as_object_mut().unwrap().remove("scene");
        let g = parse(&with_data_uri(doc, &bin)).unwrap();
        assert_eq!(g.parts[0].node_name.as_deref(), Some("first"));
    }

    #[test]
    fn without_scenes_all_root_nodes_are_used_with_a_warning() {
        let (mut doc, bin) = one_triangle();
        doc["nodes"] = json!([{"mesh": 0, "children": [1]}, {"mesh": 0}, {"mesh": 0}]);
        doc.as_object_mut().unwrap().remove("scenes");
        let g = parse(&with_data_uri(doc, &bin)).unwrap();
        let nodes: Vec<usize> = g.parts.iter().map(|p| p.node_index).collect();
        assert_eq!(nodes, vec![0, 1, 2]);
        assert_eq!(g.warnings.len(), 1);
        assert!(g.warnings[0].contains("no scene"), "{}", g.warnings[0]);
    }

    #[test]
    fn node_cycle_is_an_error() {
        let (mut doc, bin) = one_triangle();
        doc["nodes"] = json!([{"mesh": 0, "children": [1]}, {"children": [0]}]);
        let e = parse(&with_data_uri(doc, &bin)).unwrap_err();
        assert!(e.message.contains("cycle"), "{e}");
    }

    #[test]
    fn uris_leaving_the_folder_are_refused() {
        let outer = tempfile::tempdir().unwrap();
        let dir = outer.path().join("model");
        std::fs::create_dir(&dir).unwrap();
        let (doc, bin) = one_triangle();
        let outside_bin = outer.path().join("x.bin");
        std::fs::write(&outside_bin, &bin).unwrap();
        std::os::unix::fs::symlink(&outside_bin, dir.join("link.bin")).unwrap();
        let absolute = outside_bin.to_str().unwrap().to_string();
        for uri in [
            "../x.bin",
            "sub/../../x.bin",
            "%2e%2e/x.bin",
            &absolute,
            "http://example.com/x.bin",
            "file:///tmp/x.bin",
            "link.bin",
        ] {
            let mut doc = doc.clone();
            doc["buffers"][0]["uri"] = json!(uri);
            let path = dir.join("scene.gltf");
            std::fs::write(&path, doc.to_string()).unwrap();
            let e = read_generator(&path).expect_err(uri);
            assert!(e.message.contains("outside"), "{uri}: {e}");
            assert!(e.message.contains("same folder"), "{uri}: {e}");
            assert_eq!(e.column.as_deref(), Some("buffers[0]"));
        }
    }

    /// A FIFO would block the reader forever (the watcher's review): refused, not opened.
    #[test]
    fn buffers_that_are_not_plain_files_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let (doc, bin) = one_triangle();
        let path = write_external(dir.path(), doc, &bin, "mesh.bin");
        std::fs::remove_file(dir.path().join("mesh.bin")).unwrap();
        let made = std::process::Command::new("mkfifo")
            .arg(dir.path().join("mesh.bin"))
            .status()
            .expect("mkfifo runs");
        assert!(made.success());
        let e = read_generator(&path).unwrap_err();
        assert!(e.message.contains("not a regular file"), "{e}");
    }

    #[test]
    fn missing_and_short_buffers_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        let (doc, bin) = one_triangle();
        let path = write_external(dir.path(), doc.clone(), &bin, "mesh.bin");
        std::fs::remove_file(dir.path().join("mesh.bin")).unwrap();
        let e = read_generator(&path).unwrap_err();
        assert!(e.message.contains("mesh.bin"), "{e}");

        let path = write_external(dir.path(), doc.clone(), &bin[..bin.len() - 4], "mesh.bin");
        let e = read_generator(&path).unwrap_err();
        assert!(e.message.contains("byteLength"), "{e}");

        let e = parse_err(&glb(&doc, &bin[..8]));
        assert!(e.message.contains("byteLength"), "{e}");
    }

    #[test]
    fn bad_geometry_is_named() {
        let mut b = Builder::default();
        let pos = b.positions(&[[0.0; 3], [f32::NAN, 0.0, 0.0], [1.0; 3]]);
        let (doc, bin) = b.finish(json!({
            "meshes": [{"name": "bad", "primitives": [{"attributes": {"POSITION": pos}}]}],
            "nodes": [{"mesh": 0}],
        }));
        let e = parse_err(&glb(&doc, &bin));
        assert_eq!(e.column.as_deref(), Some("meshes[0].primitives[0]"));
        assert!(
            e.message.contains("vertex 1") && e.message.contains("\"bad\""),
            "{e}"
        );

        let mut b = Builder::default();
        let pos = b.positions(&TRI);
        let idx = b.indices(&[0, 1, 7]);
        let (doc, bin) = b.finish(json!({
            "meshes": [{"primitives": [{"attributes": {"POSITION": pos}, "indices": idx}]}],
            "nodes": [{"mesh": 0}],
        }));
        let e = parse_err(&glb(&doc, &bin));
        assert!(
            e.message.contains("index 7") && e.message.contains("mesh 0"),
            "{e}"
        );
    }

    #[test]
    fn missing_or_quantized_positions_are_errors() {
        let (mut doc, bin) = one_triangle();
        doc["meshes"][0]["primitives"][0]["attributes"] = json!({"NORMAL": 0});
        let e = parse_err(&glb(&doc, &bin));
        assert!(e.message.contains("POSITION"), "{e}");

        let (mut doc, bin) = one_triangle();
        doc["accessors"][0]["componentType"] = json!(5123);
        doc["accessors"][0]["normalized"] = json!(true);
        let e = parse_err(&glb(&doc, &bin));
        assert!(e.message.contains("float VEC3"), "{e}");
        assert!(e.fix.contains("float positions"), "{e}");
    }

    #[test]
    fn position_bounds_are_optional_and_sparse_is_read() {
        let (mut doc, mut bin) = one_triangle();
        let accessor = doc["accessors"][0].as_object_mut().unwrap();
        accessor.remove("min");
        accessor.remove("max");
        // Sparse: vertex 2 replaced by (0, 0, 5).
        let at = bin.len();
        bin.extend(2u32.to_le_bytes());
        bin.extend([0.0f32, 0.0, 5.0].iter().flat_map(|x| x.to_le_bytes()));
        doc["buffers"][0]["byteLength"] = json!(bin.len());
        doc["bufferViews"].as_array_mut().unwrap().extend([
            json!({"buffer": 0, "byteOffset": at, "byteLength": 4}),
            json!({"buffer": 0, "byteOffset": at + 4, "byteLength": 12}),
        ]);
        doc["accessors"][0]["sparse"] = json!({"count": 1,
            "indices": {"bufferView": 2, "componentType": 5125}, "values": {"bufferView": 3}});
        let g = parse(&glb(&doc, &bin)).unwrap();
        assert_eq!(g.parts[0].positions[2], Vec3::new(0.0, 0.0, 5.0));
    }

    #[test]
    fn no_triangles_and_garbage_are_errors() {
        let (mut doc, bin) = one_triangle();
        doc["meshes"][0]["primitives"][0]["mode"] = json!(1);
        let e = parse_err(&glb(&doc, &bin));
        assert!(e.message.contains("no triangles"), "{e}");

        for garbage in [
            &b"\x00\x01garbage"[..],
            b"glTF\x02\x00\x00\x00garbage",
            b"{\"asset\": 3}",
        ] {
            let e = parse_err(garbage);
            assert!(e.fix.contains("re-export"), "{e}");
            assert_eq!(e.file, Path::new("/nonexistent/test.gltf"));
        }
    }

    #[test]
    fn malformed_accessor_is_an_error_not_a_panic() {
        let (mut doc, bin) = one_triangle();
        doc["accessors"][0]["count"] = json!(u64::MAX / 2);
        let e = parse_err(&glb(&doc, &bin));
        assert!(e.message.contains("accessor 0"), "{e}");
        doc["accessors"][0]["count"] = json!(0);
        assert!(parse_err(&glb(&doc, &bin)).message.contains("accessor 0"));
    }

    /// A real mesh bundled in examples/ (copies of ../shared/data, so the crate tests alone).
    fn real_mesh(name: &str) -> Generator {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("examples")
            .join(name);
        read_generator(&path).unwrap()
    }

    #[test]
    fn real_meshes_load() {
        assert_eq!(real_mesh("bunny.glb").triangle_count(), 3674);
        assert_eq!(real_mesh("dragon-11k.glb").triangle_count(), 11102);
    }
}
