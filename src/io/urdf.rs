//! A robot in its own formats: a URDF description (parsed by urdf-rs) and a joint CSV
//! (`time,<joint names>`, radians or metres, the layout ROS and MoveIt trajectories export),
//! read as a generator with a node hierarchy and rows in parent space (`input::chain`).
//!
//! The tree: one node per link, its transform relative to the parent link the joint's
//! origin·Rot(axis, q) (revolute, continuous) or origin·Trans(axis·q) (prismatic) or origin
//! (fixed); under each link one node per collision element (the visual ones where a link has
//! no collision geometry) with the element's origin and mesh scale, holding its triangles. A
//! joint row sets the child link's transform at q; between rows the chain moves by the screw
//! of each link in its parent's frame, which for these joints is exactly the joint-linear
//! motion (a step over 90° is split into equal joint-linear rows, so no screw is near a half
//! turn). Primitives are meshed around the true shape (box exact; sphere, cylinder and capsule
//! as polyhedra whose faces lie outside it), so the geometry swept is never smaller.

use std::collections::HashMap;
use std::f64::consts::{FRAC_PI_2, PI};
use std::path::{Path, PathBuf};

use glam::{DMat3, DMat4, DVec3, Vec3};

use crate::error::{num, InputError};
use crate::input::model::{Generator, Part, Pose, Rows, Trajectory, TreeNode};
use crate::io::mesh_files;

/// Sides of the polygons and rings that mesh round primitives.
const ROUND_SIDES: usize = 24;

#[derive(Clone, Copy, Debug, PartialEq)]
enum JointKind {
    Revolute { limited: bool },
    Prismatic,
    Fixed,
}

/// A joint as the rows drive it.
#[derive(Clone, Debug)]
struct Joint {
    name: String,
    kind: JointKind,
    origin: DMat4,
    axis: DVec3,
    /// The child link's name (its node's name).
    child: String,
    limits: (f64, f64),
}

impl Joint {
    fn local(&self, q: f64) -> DMat4 {
        match self.kind {
            JointKind::Revolute { .. } => self.origin * DMat4::from_axis_angle(self.axis, q),
            JointKind::Prismatic => self.origin * DMat4::from_translation(self.axis * q),
            JointKind::Fixed => self.origin,
        }
    }
}

/// A robot read from its URDF: the generator and its joints.
pub struct Robot {
    pub generator: Generator,
    /// The mesh files the elements were read from, in the order read (a shard's manifest
    /// hashes them with the URDF).
    pub files: Vec<PathBuf>,
    joints: Vec<Joint>,
}

fn urdf_error(path: &Path, message: String, fix: &str) -> InputError {
    InputError::new(path, message, fix)
}

/// URDF's origin: translation xyz, then fixed-axis roll (x), pitch (y), yaw (z).
fn pose(p: &urdf_rs::Pose) -> DMat4 {
    let [r, pi, y] = *p.rpy;
    let rot = DMat3::from_rotation_z(y) * DMat3::from_rotation_y(pi) * DMat3::from_rotation_x(r);
    DMat4::from_translation(DVec3::from_array(*p.xyz)) * DMat4::from_mat3(rot)
}

/// Read the robot description at `path`; `package://NAME/...` mesh paths resolve against each
/// of `package_dirs` (as `DIR/NAME/...`), then against a folder called NAME above the URDF.
pub fn read_robot(path: &Path, package_dirs: &[PathBuf]) -> Result<Robot, InputError> {
    let text = std::fs::read_to_string(path).map_err(|e| {
        urdf_error(
            path,
            format!("cannot read the robot description: {e}"),
            "check the path",
        )
    })?;
    let robot = urdf_rs::read_from_string(&text).map_err(|e| {
        urdf_error(
            path,
            format!("not a robot description urdf-rs can read: {e}"),
            "fix the URDF: a <robot> with <link> and <joint> elements (joint types revolute, continuous, prismatic, fixed; expand xacro files first)",
        )
    })?;
    let fix_tree =
        "make the links one tree: every link but the root is the child of exactly one joint";
    let mut link_index: HashMap<&str, usize> = HashMap::new();
    for (i, l) in robot.links.iter().enumerate() {
        if link_index.insert(l.name.as_str(), i).is_some() {
            return Err(urdf_error(
                path,
                format!("two links are named {:?}", l.name),
                "give every link its own name",
            ));
        }
    }
    let mut joints = Vec::new();
    let mut parent_of: HashMap<&str, (&str, usize)> = HashMap::new();
    for (j, joint) in robot.joints.iter().enumerate() {
        let at = format!("joint {:?}", joint.name);
        for link in [&joint.parent.link, &joint.child.link] {
            if !link_index.contains_key(link.as_str()) {
                return Err(urdf_error(
                    path,
                    format!("{at} names link {link:?}, which the robot does not have"),
                    "name an existing link",
                ));
            }
        }
        if let Some((other, _)) =
            parent_of.insert(joint.child.link.as_str(), (joint.parent.link.as_str(), j))
        {
            return Err(urdf_error(path, format!("{at} makes link {:?} a child a second time (of {:?} too): the links form a loop or a graph, not a tree", joint.child.link, other), fix_tree));
        }
        let kind = match joint.joint_type {
            urdf_rs::JointType::Revolute => JointKind::Revolute { limited: true },
            urdf_rs::JointType::Continuous => JointKind::Revolute { limited: false },
            urdf_rs::JointType::Prismatic => JointKind::Prismatic,
            urdf_rs::JointType::Fixed => JointKind::Fixed,
            ref other => {
                return Err(urdf_error(path, format!("{at} is of type {other:?}, which a joint CSV of one value per joint cannot drive"), "use revolute, continuous, prismatic or fixed joints (split a floating or planar joint into prismatic and revolute ones)"));
            }
        };
        let axis = DVec3::from_array(*joint.axis.xyz);
        if kind != JointKind::Fixed && !(axis.is_finite() && axis.length() > 0.0) {
            return Err(urdf_error(
                path,
                format!("{at} has the axis {axis}, not a direction"),
                "give the joint a non-zero <axis xyz=...>",
            ));
        }
        let origin = pose(&joint.origin);
        if !origin.is_finite() {
            return Err(urdf_error(
                path,
                format!("{at} has an origin that is not finite"),
                "fix its <origin xyz rpy>",
            ));
        }
        joints.push(Joint {
            name: joint.name.clone(),
            kind,
            origin,
            axis: axis.normalize_or_zero(),
            child: joint.child.link.clone(),
            limits: (joint.limit.lower, joint.limit.upper),
        });
    }
    let roots: Vec<&str> = robot
        .links
        .iter()
        .map(|l| l.name.as_str())
        .filter(|l| !parent_of.contains_key(l))
        .collect();
    let [root] = roots[..] else {
        return Err(urdf_error(
            path,
            format!(
                "the robot has {} root links ({}): a tree has one",
                roots.len(),
                roots.join(", ")
            ),
            fix_tree,
        ));
    };
    // Links in tree order (parents first); a link not reached hangs in a loop.
    let mut order = vec![root];
    let mut k = 0;
    while k < order.len() {
        let parent = order[k];
        for j in &robot.joints {
            if j.parent.link == parent {
                order.push(j.child.link.as_str());
            }
        }
        k += 1;
    }
    if order.len() != robot.links.len() {
        let lost: Vec<&str> = robot
            .links
            .iter()
            .map(|l| l.name.as_str())
            .filter(|l| !order.contains(l))
            .collect();
        return Err(urdf_error(
            path,
            format!(
                "links {} are not reached from the root {root:?}: their joints form a loop",
                lost.join(", ")
            ),
            fix_tree,
        ));
    }
    let position: HashMap<&str, usize> = order.iter().enumerate().map(|(i, l)| (*l, i)).collect();
    let mut generator = Generator::default();
    for (i, name) in order.iter().enumerate() {
        let (parent, local) = match parent_of.get(name) {
            Some(&(p, j)) => (Some(position[p]), joints[j].local(0.0)),
            None => (None, DMat4::IDENTITY),
        };
        generator.nodes.push(TreeNode {
            index: i,
            name: Some(name.to_string()),
            parent,
            local,
        });
    }
    let mut files = Vec::new();
    for (i, name) in order.iter().enumerate() {
        let link = &robot.links[link_index[name]];
        let (kind, elements): (&str, Vec<(&urdf_rs::Pose, &urdf_rs::Geometry)>) =
            if link.collision.is_empty() {
                (
                    "visual",
                    link.visual
                        .iter()
                        .map(|v| (&v.origin, &v.geometry))
                        .collect(),
                )
            } else {
                (
                    "collision",
                    link.collision
                        .iter()
                        .map(|c| (&c.origin, &c.geometry))
                        .collect(),
                )
            };
        for (e, (origin, geometry)) in elements.into_iter().enumerate() {
            let at = format!("link {name:?}, {kind} {e}");
            let (mesh, scale, file) = geometry_mesh(path, package_dirs, &at, geometry)?;
            files.extend(file);
            if mesh.1.is_empty() {
                return Err(urdf_error(
                    path,
                    format!("{at}: the geometry has no triangles"),
                    "give the link a mesh with triangles, or remove the element",
                ));
            }
            let index = generator.nodes.len();
            let node_name = format!("{name}/{kind}{e}");
            let local = pose(origin) * DMat4::from_scale(scale);
            let world = world_of(&generator.nodes, i) * local;
            generator.nodes.push(TreeNode {
                index,
                name: Some(node_name.clone()),
                parent: Some(i),
                local,
            });
            generator.parts.push(Part {
                node_index: index,
                node_name: Some(node_name),
                world,
                positions: mesh.0.into_iter().map(Vec3::from).collect(),
                triangles: mesh.1,
            });
        }
    }
    if generator.parts.is_empty() {
        return Err(urdf_error(
            path,
            "no link has collision or visual geometry: nothing to sweep".into(),
            "give the links <collision> geometry",
        ));
    }
    Ok(Robot {
        generator,
        files,
        joints,
    })
}

/// The world transform of node `i` (parents before children in `nodes`).
fn world_of(nodes: &[TreeNode], i: usize) -> DMat4 {
    let mut m = nodes[i].local;
    let mut at = nodes[i].parent;
    while let Some(p) = at {
        m = nodes[p].local * m;
        at = nodes[p].parent;
    }
    m
}

/// An element's triangles, its mesh scale and the mesh file it was read from (None for a
/// primitive).
fn geometry_mesh(
    path: &Path,
    package_dirs: &[PathBuf],
    at: &str,
    geometry: &urdf_rs::Geometry,
) -> Result<(mesh_files::Mesh, DVec3, Option<PathBuf>), InputError> {
    let positive = |what: &str, v: f64| {
        if v.is_finite() && v > 0.0 {
            Ok(v)
        } else {
            Err(urdf_error(
                path,
                format!("{at}: the {what} {} is not a positive number", num(v)),
                "fix the primitive's size",
            ))
        }
    };
    Ok(match geometry {
        urdf_rs::Geometry::Box { size } => {
            let h = [
                positive("box size", size[0])? / 2.0,
                positive("box size", size[1])? / 2.0,
                positive("box size", size[2])? / 2.0,
            ];
            (boxed(h), DVec3::ONE, None)
        }
        urdf_rs::Geometry::Sphere { radius } => {
            (sphere(positive("radius", *radius)?, 0.0), DVec3::ONE, None)
        }
        urdf_rs::Geometry::Cylinder { radius, length } => (
            cylinder(positive("radius", *radius)?, positive("length", *length)?),
            DVec3::ONE,
            None,
        ),
        urdf_rs::Geometry::Capsule { radius, length } => (
            sphere(positive("radius", *radius)?, positive("length", *length)?),
            DVec3::ONE,
            None,
        ),
        urdf_rs::Geometry::Mesh { filename, scale } => {
            let scale = scale
                .as_ref()
                .map_or(DVec3::ONE, |s| DVec3::from_array(**s));
            if !(scale.is_finite() && scale.min_element().abs() > 0.0) {
                return Err(urdf_error(
                    path,
                    format!("{at}: the mesh scale {scale} flattens or breaks the mesh"),
                    "give the mesh a non-zero scale",
                ));
            }
            let file = resolve(path, package_dirs, filename).ok_or_else(|| {
                urdf_error(path, format!("{at}: the mesh {filename:?} is not found"), "give $package_dir the folder that holds the package (package://NAME/... is read as DIR/NAME/...), or a path relative to the URDF")
            })?;
            (read_mesh(&file)?, scale, Some(file))
        }
    })
}

/// Where a URDF mesh reference points.
fn resolve(urdf: &Path, package_dirs: &[PathBuf], filename: &str) -> Option<PathBuf> {
    let folder = urdf.parent().unwrap_or(Path::new("."));
    if let Some(rest) = filename.strip_prefix("package://") {
        let (package, inner) = rest.split_once('/')?;
        let mut candidates: Vec<PathBuf> = package_dirs
            .iter()
            .map(|d| d.join(package).join(inner))
            .collect();
        let absolute = std::fs::canonicalize(folder).ok()?;
        candidates.extend(
            absolute
                .ancestors()
                .filter(|a| a.file_name().is_some_and(|n| n == package))
                .map(|a| a.join(inner)),
        );
        return candidates.into_iter().find(|c| c.is_file());
    }
    let plain = filename.strip_prefix("file://").unwrap_or(filename);
    let p = folder.join(plain);
    p.is_file().then_some(p)
}

fn read_mesh(file: &Path) -> Result<mesh_files::Mesh, InputError> {
    let ext = file
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or_default()
        .to_ascii_lowercase();
    let bytes = || {
        std::fs::read(file)
            .map_err(|e| urdf_error(file, format!("cannot read the mesh: {e}"), "check the file"))
    };
    match ext.as_str() {
        "stl" => mesh_files::read_stl(file, &bytes()?),
        "obj" => mesh_files::read_obj(file, &bytes()?),
        "glb" | "gltf" => {
            let g = crate::io::gltf_in::read_generator(file)?;
            let mut out: mesh_files::Mesh = (Vec::new(), Vec::new());
            for part in &g.parts {
                let base = out.0.len() as u32;
                out.0.extend(part.positions.iter().map(|p| {
                    part.world
                        .transform_point3(p.as_dvec3())
                        .as_vec3()
                        .to_array()
                }));
                out.1
                    .extend(part.triangles.iter().map(|t| t.map(|k| k + base)));
            }
            Ok(out)
        }
        _ => Err(urdf_error(
            file,
            format!("meshes of type {ext:?} are not read"),
            "give the link a collision mesh in STL, OBJ or glTF (COLLADA .dae is not read)",
        )),
    }
}

/// The box [-h, h].
fn boxed(h: [f64; 3]) -> mesh_files::Mesh {
    let positions = (0..8)
        .map(|k| {
            std::array::from_fn(|a| {
                if k >> a & 1 == 1 {
                    h[a] as f32
                } else {
                    -h[a] as f32
                }
            })
        })
        .collect();
    let quads = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    let triangles = quads
        .iter()
        .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        .collect();
    (positions, triangles)
}

/// Rounded up to the next f32 away from zero: the polyhedra below must not shrink in f32.
fn outward(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64).abs() >= x.abs() {
        f
    } else if x > 0.0 {
        f.next_up()
    } else {
        f.next_down()
    }
}

/// A closed convex polyhedron around the capsule of radius r whose segment runs along z over
/// [-length/2, length/2] (a sphere for length 0): a latitude-longitude sphere split at the
/// equator, its halves moved apart by the length. Its radius is r over the smallest distance
/// from the centre to a face plane of the unit one (measured here), so every face of a cap is at
/// least r from its end of the segment, and the band between them at least r from the axis.
fn sphere(r: f64, length: f64) -> mesh_files::Mesh {
    let (unit, triangles) = lat_long(1.0, 0.0);
    let nearest = triangles
        .iter()
        .filter_map(|t| {
            let [a, b, c] = t.map(|k| unit[k as usize]);
            let n = (b - a).cross(c - a);
            (n.length() > 1e-9).then(|| n.dot(a).abs() / n.length())
        })
        .fold(f64::INFINITY, f64::min);
    // 1e-6: room for the outward rounding to f32 (relative 6e-8 per coordinate).
    let (positions, triangles) = lat_long(r / nearest * (1.0 + 1e-6), length);
    let positions = positions
        .iter()
        .map(|p| p.to_array().map(outward))
        .collect();
    (positions, triangles)
}

/// The latitude-longitude sphere of radius `big` (ROUND_SIDES steps around, half as many
/// from pole to pole), its lower half moved down by length/2 and its upper half up.
fn lat_long(big: f64, length: f64) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let n = ROUND_SIDES;
    let rings = n / 2;
    let mut positions = Vec::new();
    let mut ring_start = Vec::new();
    for i in 0..=rings {
        // The equator twice: once for each half.
        for half in 0..=usize::from(i == rings / 2) {
            let lat = PI * i as f64 / rings as f64 - FRAC_PI_2;
            let lower = i < rings / 2 || (i == rings / 2 && half == 0);
            let z = big * lat.sin() + if lower { -length / 2.0 } else { length / 2.0 };
            ring_start.push(positions.len() as u32);
            for k in 0..n {
                let lon = 2.0 * PI * k as f64 / n as f64;
                let c = big * lat.cos();
                positions.push(DVec3::new(c * lon.cos(), c * lon.sin(), z));
            }
        }
    }
    let mut triangles = Vec::new();
    for w in ring_start.windows(2) {
        for k in 0..n as u32 {
            let k1 = (k + 1) % n as u32;
            let (a, b, c, d) = (w[0] + k, w[0] + k1, w[1] + k1, w[1] + k);
            triangles.push([a, b, c]);
            triangles.push([a, c, d]);
        }
    }
    (positions, triangles)
}

/// A closed prism around the cylinder of radius r along z over [-length/2, length/2]: its
/// n-gon's edges touch the circle (vertices at r / cos(π/n)).
fn cylinder(r: f64, length: f64) -> mesh_files::Mesh {
    let n = ROUND_SIDES as u32;
    let big = r / (PI / n as f64).cos();
    let mut positions = Vec::new();
    for z in [-length / 2.0, length / 2.0] {
        for k in 0..n {
            let a = 2.0 * PI * k as f64 / n as f64;
            positions.push([outward(big * a.cos()), outward(big * a.sin()), outward(z)]);
        }
    }
    positions.push([0.0, 0.0, outward(-length / 2.0)]);
    positions.push([0.0, 0.0, outward(length / 2.0)]);
    let mut triangles = Vec::new();
    for k in 0..n {
        let k1 = (k + 1) % n;
        triangles.push([k, k1, n + k1]);
        triangles.push([k, n + k1, n + k]);
        triangles.push([2 * n, k1, k]);
        triangles.push([2 * n + 1, n + k, n + k1]);
    }
    (positions, triangles)
}

/// Read the joint CSV at `path` for `robot`: rows in parent space, one per moving joint named
/// in the header and per time (steps over 90° split into joint-linear rows), and a warning
/// per joint value beyond its limits.
pub fn joint_rows(robot: &Robot, path: &Path) -> Result<(Trajectory, Vec<String>), InputError> {
    let text = std::fs::read_to_string(path).map_err(|e| {
        InputError::new(
            path,
            format!("cannot read the joint trajectory: {e}"),
            "check the path",
        )
    })?;
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let fix_header = "start the joint CSV with a header `time,<joint names>` (radians or metres, one column per joint that moves)";
    let Some((_, header)) = lines.next() else {
        return Err(InputError::new(
            path,
            "the joint trajectory is empty",
            fix_header,
        ));
    };
    let names: Vec<&str> = header.split(',').map(str::trim).collect();
    let Some(time_col) = names.iter().position(|n| *n == "time") else {
        return Err(InputError::new(path, "the header has no time column", fix_header).at_line(1));
    };
    let movable: Vec<&str> = robot
        .joints
        .iter()
        .filter(|j| j.kind != JointKind::Fixed)
        .map(|j| j.name.as_str())
        .collect();
    let mut columns: Vec<(usize, &Joint)> = Vec::new();
    for (c, name) in names.iter().enumerate() {
        if c == time_col {
            continue;
        }
        let joint = robot
            .joints
            .iter()
            .find(|j| j.name == *name)
            .filter(|j| j.kind != JointKind::Fixed);
        let Some(joint) = joint else {
            return Err(InputError::new(
                path,
                format!("the robot has no moving joint named {name:?}"),
                format!("name the robot's joints: {}", movable.join(", ")),
            )
            .at_line(1)
            .in_column(name.to_string()));
        };
        if columns.iter().any(|(_, j)| j.name == joint.name) {
            return Err(InputError::new(
                path,
                format!("joint {name:?} has two columns"),
                "keep one",
            )
            .at_line(1)
            .in_column(name.to_string()));
        }
        columns.push((c, joint));
    }
    let mut rows: Vec<(u64, f64, Vec<f64>)> = Vec::new();
    for (i, line) in lines {
        let line_no = i as u64 + 1;
        let cells: Vec<&str> = line.split(',').map(str::trim).collect();
        if cells.len() != names.len() {
            return Err(InputError::new(
                path,
                format!("{} values for {} columns", cells.len(), names.len()),
                "give every row one value per header column",
            )
            .at_line(line_no));
        }
        let value = |c: usize| -> Result<f64, InputError> {
            cells[c]
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    InputError::new(
                        path,
                        format!("{:?} is not a finite number", cells[c]),
                        "write joint values in radians or metres, and the time in seconds",
                    )
                    .at_line(line_no)
                    .in_column(names[c].to_string())
                })
        };
        let t = value(time_col)?;
        if let Some((l, before, _)) = rows.last() {
            if t <= *before {
                return Err(InputError::new(
                    path,
                    format!(
                        "time {} does not come after {} (line {l})",
                        num(t),
                        num(*before)
                    ),
                    "sort the rows by strictly increasing time",
                )
                .at_line(line_no)
                .in_column("time"));
            }
        }
        let q = columns
            .iter()
            .map(|(c, _)| value(*c))
            .collect::<Result<Vec<f64>, _>>()?;
        rows.push((line_no, t, q));
    }
    if rows.is_empty() {
        return Err(InputError::new(
            path,
            "the joint trajectory has a header but no rows",
            "add at least one row",
        )
        .at_line(1));
    }
    let mut warnings = Vec::new();
    for (line, _, q) in &rows {
        for ((_, j), v) in columns.iter().zip(q) {
            let limited = matches!(
                j.kind,
                JointKind::Revolute { limited: true } | JointKind::Prismatic
            );
            if limited && j.limits.0 < j.limits.1 && !(j.limits.0..=j.limits.1).contains(v) {
                warnings.push(format!(
                    "{}:{line}: joint {:?} = {} is beyond its limits [{}, {}]",
                    path.display(),
                    j.name,
                    num(*v),
                    num(j.limits.0),
                    num(j.limits.1)
                ));
            }
        }
    }
    // Steps over 90° become equal joint-linear steps: exact for the joint-linear motion.
    let mut poses = Vec::new();
    let mut push = |line: u64, t: f64, q: &[f64]| {
        for ((_, j), v) in columns.iter().zip(q) {
            poses.push(Pose {
                line,
                frame: Some(t),
                node: Some(j.child.clone()),
                matrix: j.local(*v),
            });
        }
    };
    push(rows[0].0, rows[0].1, &rows[0].2);
    for w in rows.windows(2) {
        let ((_, t0, q0), (line, t1, q1)) = (&w[0], &w[1]);
        let turn = columns
            .iter()
            .zip(q0.iter().zip(q1))
            .filter(|((_, j), _)| matches!(j.kind, JointKind::Revolute { .. }))
            .map(|(_, (a, b))| (b - a).abs())
            .fold(0.0, f64::max);
        let pieces = (turn / FRAC_PI_2).ceil().max(1.0) as usize;
        for k in 1..=pieces {
            let s = k as f64 / pieces as f64;
            let q: Vec<f64> = q0.iter().zip(q1).map(|(a, b)| a + s * (b - a)).collect();
            let t = if k == pieces { *t1 } else { t0 + s * (t1 - t0) };
            push(*line, t, &q);
        }
    }
    Ok((
        Trajectory {
            poses,
            has_node_column: true,
            rows: Rows::Local,
        },
        warnings,
    ))
}

/// Whether `path` names a robot description (by its extension).
pub fn is_robot(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("urdf"))
}

/// The generator and trajectory of a robot run, its warnings in the generator's.
pub fn read_inputs(
    urdf: &Path,
    joints: &Path,
    package_dirs: &[PathBuf],
) -> Result<(Generator, Trajectory), InputError> {
    let robot = read_robot(urdf, package_dirs)?;
    let (trajectory, warnings) = joint_rows(&robot, joints)?;
    let mut generator = robot.generator;
    generator.warnings.extend(warnings);
    Ok((generator, trajectory))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every face of the round primitives' polyhedra (f32 vertices) lies at least the radius
    /// from the segment (capsule), the point (sphere) or the axis within the caps (cylinder):
    /// the polyhedra contain the true shapes.
    #[test]
    fn round_primitives_lie_around_the_true_shapes() {
        let check = |(positions, triangles): mesh_files::Mesh, r: f64, half: f64, caps: bool| {
            let p: Vec<DVec3> = positions
                .iter()
                .map(|v| Vec3::from(*v).as_dvec3())
                .collect();
            for t in &triangles {
                let [a, b, c] = t.map(|k| p[k as usize]);
                let n = (b - a).cross(c - a);
                if n.length() < 1e-12 {
                    continue;
                }
                let n = n.normalize();
                // The shape's farthest point along n: the segment's end (or, for a cylinder,
                // the rim) plus r outward.
                let reach = if caps {
                    let radial = DVec3::new(n.x, n.y, 0.0).length();
                    r * radial + half * n.z.abs()
                } else {
                    r + half * n.z.abs()
                };
                let plane = n.dot(a);
                assert!(
                    plane >= reach * (1.0 - 1e-12),
                    "face {t:?}: {plane} < {reach}"
                );
            }
        };
        check(sphere(0.3, 0.0), 0.3, 0.0, false);
        check(sphere(0.05, 0.4), 0.05, 0.2, false);
        check(cylinder(0.25, 0.6), 0.25, 0.3, true);
    }
}
