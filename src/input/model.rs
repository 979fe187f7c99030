//! The inputs after parsing: parts of the generator and the poses that move them.
//! Plain data, no I/O. Produced by `io::gltf_in` and `io::trajectory`, consumed by `input::posed`.

use std::path::Path;

use glam::{DMat4, Vec3};

use crate::error::InputError;

/// One glTF node's own mesh: all its TRIANGLES primitives merged.
#[derive(Debug, Clone)]
pub struct Part {
    /// Index of the node in the glTF document.
    pub node_index: usize,
    /// The node's name, if it has one.
    pub node_name: Option<String>,
    /// The node's world matrix W (parents applied), glTF conventions (Y up, metres).
    pub world: DMat4,
    /// Vertex positions exactly as stored in the file (node-local frame, f32).
    pub positions: Vec<Vec3>,
    /// Triangles as indices into `positions`. Degenerate, duplicate and
    /// inconsistently wound triangles are kept: the sweep does not care.
    pub triangles: Vec<[u32; 3]>,
}

/// One node of the glTF node hierarchy (with or without a mesh): the kinematic tree that
/// rows in parent space (`Rows::Local`) move.
#[derive(Debug, Clone)]
pub struct TreeNode {
    /// Index of the node in the glTF document.
    pub index: usize,
    pub name: Option<String>,
    /// The parent's document index; None for a root of the scene.
    pub parent: Option<usize>,
    /// The node's own transform relative to its parent, f64.
    pub local: DMat4,
}

/// The generator: every part of the chosen scene.
#[derive(Debug, Clone, Default)]
pub struct Generator {
    pub parts: Vec<Part>,
    /// Every node of the chosen scene, parents before their children (empty where a generator
    /// is made without a hierarchy: then no row can be in parent space).
    pub nodes: Vec<TreeNode>,
    /// Things skipped while reading (points and lines primitives, ...), for the report and the log.
    pub warnings: Vec<String>,
}

impl Part {
    /// Edges (unordered vertex pairs, by position) that an odd number of this part's triangles
    /// use: the part's boundary. None means the part is closed, so its surface separates an
    /// inside from the outside (a flood from outside cannot reach the inside without crossing
    /// it). Vertices are matched by position, so a seam of duplicated vertices counts as closed.
    pub fn boundary_edges(&self) -> usize {
        let key = |i: u32| {
            let p = self.positions[i as usize];
            [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()]
        };
        let mut odd = std::collections::HashSet::new();
        for t in &self.triangles {
            for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                let (a, b) = (key(a), key(b));
                if a == b {
                    continue; // a degenerate edge bounds nothing
                }
                let e = if a < b { (a, b) } else { (b, a) };
                if !odd.remove(&e) {
                    odd.insert(e);
                }
            }
        }
        odd.len()
    }
}

impl Generator {
    pub fn triangle_count(&self) -> usize {
        self.parts.iter().map(|p| p.triangles.len()).sum()
    }

    /// The one part whose node is called `name`, for the trajectory row at `line` of
    /// `csv_path`; no such node, or more than one, is an error on that row's `node` column.
    pub fn part_named(&self, name: &str, csv_path: &Path, line: u64) -> Result<usize, InputError> {
        let mut hits =
            (0..self.parts.len()).filter(|&i| self.parts[i].node_name.as_deref() == Some(name));
        let (first, count) = (hits.next(), 1 + hits.count());
        let error = match first {
            Some(i) if count == 1 => return Ok(i),
            Some(_) => InputError::new(
                csv_path,
                format!("node name {name:?} is ambiguous: {count} mesh nodes carry it"),
                "give the glTF nodes unique names",
            ),
            None => {
                let known: Vec<&str> = self
                    .parts
                    .iter()
                    .filter_map(|p| p.node_name.as_deref())
                    .collect();
                InputError::new(
                    csv_path,
                    format!("no node named {name:?} carries a mesh in the generator"),
                    format!("use one of the mesh nodes: {}", known.join(", ")),
                )
            }
        };
        Err(error.at_line(line).in_column("node"))
    }
}

/// What a trajectory row's matrix is: a world-space transform of the part where the glTF puts
/// it (`world`, v' = M·W·v), or the node's own transform relative to its parent (`local`,
/// replacing the glTF's), the parents' rows composed along the hierarchy.
#[derive(
    Clone,
    Copy,
    Debug,
    Default,
    PartialEq,
    Eq,
    serde::Serialize,
    serde::Deserialize,
    clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum Rows {
    #[default]
    World,
    Local,
}

impl Rows {
    pub fn name(self) -> &'static str {
        match self {
            Rows::World => "world",
            Rows::Local => "local",
        }
    }
}

/// One row of the trajectory CSV.
#[derive(Debug, Clone, PartialEq)]
pub struct Pose {
    /// 1-based line of the CSV row, for messages.
    pub line: u64,
    /// The `frame` or `time` value, if the file has that column.
    pub frame: Option<f64>,
    /// The node this row moves (`node` column); `None` moves the whole scene.
    pub node: Option<String>,
    /// Affine map M in glTF world coordinates: v' = M·(W·v). Last row is 0 0 0 1,
    /// the upper 3x3 is invertible, every entry finite.
    pub matrix: DMat4,
}

/// The parsed trajectory: poses in file order.
#[derive(Debug, Clone, Default)]
pub struct Trajectory {
    pub poses: Vec<Pose>,
    /// True when the file has a `node` column.
    pub has_node_column: bool,
    /// What the rows' matrices are.
    pub rows: Rows,
}

impl Trajectory {
    /// Poses that each move the whole scene (no `node` column), as if read from lines 2, 3, ...
    pub fn whole_scene(matrices: &[DMat4]) -> Self {
        Trajectory {
            poses: matrices
                .iter()
                .enumerate()
                .map(|(i, m)| Pose {
                    line: i as u64 + 2,
                    frame: None,
                    node: None,
                    matrix: *m,
                })
                .collect(),
            has_node_column: false,
            rows: Rows::World,
        }
    }
}

/// A world pose of a part and the CSV line of the row that gives it (None: the part stands
/// where the glTF puts it).
pub(crate) type LinedPose = (DMat4, Option<u64>);
/// A part (index into the generator's parts), its poses in order, and whether no row names it.
pub(crate) type PartPoses = (usize, Vec<LinedPose>, bool);
