//! Clearance: how far the swept volume stays from obstacles, as a guaranteed interval.
//!
//! The mesh M encloses the swept volume A, every point of M's surface at least `c` (the
//! report's `clearance`) from A and, where the bound holds everywhere (the flood
//! classification), within `B` (`hausdorff_bound`) of A. For an obstacle O that does not meet
//! M, at distance d from M: the segment from a point of O to a point of A crosses M's surface,
//! so dist(O, A) ≥ d + c; and the point of M nearest to O is within B of A, so dist(O, A) ≤
//! d + B. The upper end is also at most the exact distance from O to the part at any listed
//! pose (the part there is in A), which is what proves a contact: a posed part triangle that
//! meets an obstacle triangle, or a posed part inside a closed obstacle (or the reverse).
//! Everything is f64 on the files' f32 vertices; docs/design.md, "Clearance", has the argument.

pub mod map;
pub mod pair;

use std::path::{Path, PathBuf};

use glam::{DMat4, DVec3};
use serde::{Deserialize, Serialize};

use crate::error::InputError;
use crate::input::model::Generator;
use crate::verify::bvh::Bvh;
use pair::Nearest;

/// Triangles per BVH leaf.
const LEAF: usize = 4;

/// One obstacle: a node of an obstacle file, in world coordinates.
pub struct Obstacle {
    /// The node's name (`node N` where it has none).
    pub name: String,
    pub file: PathBuf,
    /// World positions (f64 of the file's f32 under the node's transform) and triangles.
    pub positions: Vec<DVec3>,
    pub triangles: Vec<[u32; 3]>,
    /// A closed surface: its inside counts as the obstacle.
    pub solid: bool,
    pub bvh: Bvh,
}

/// Every node of the glTF file at `path` with triangles, one obstacle each.
pub fn read_obstacles(path: &Path) -> Result<Vec<Obstacle>, InputError> {
    let generator = crate::io::gltf_in::read_generator(path).map_err(|mut e| {
        if e.fix.contains("generator") || e.fix.contains("sweep") {
            e.fix =
                "give each obstacle as glTF 2.0 (.glb or .gltf) with at least one triangle mesh"
                    .into();
        }
        e
    })?;
    obstacles_of(path, &generator)
}

/// The obstacles of a parsed glTF file: one per part with triangles.
pub fn obstacles_of(path: &Path, generator: &Generator) -> Result<Vec<Obstacle>, InputError> {
    let mut out = Vec::new();
    for part in generator.parts.iter().filter(|p| !p.triangles.is_empty()) {
        let positions: Vec<DVec3> = part
            .positions
            .iter()
            .map(|p| part.world.transform_point3(p.as_dvec3()))
            .collect();
        if let Some(bad) = positions.iter().position(|p| !p.is_finite()) {
            return Err(InputError::new(
                path,
                format!("vertex {bad} is not finite after applying the node transforms"),
                "fix the node's transforms (scale or translation overflow) and export again",
            )
            .in_column(format!("nodes[{}]", part.node_index)));
        }
        let tris: Vec<[DVec3; 3]> = part
            .triangles
            .iter()
            .map(|t| t.map(|i| positions[i as usize]))
            .collect();
        out.push(Obstacle {
            name: part
                .node_name
                .clone()
                .unwrap_or_else(|| format!("node {}", part.node_index)),
            file: path.to_path_buf(),
            solid: part.boundary_edges() == 0,
            bvh: Bvh::build(tris, LEAF),
            positions,
            triangles: part.triangles.clone(),
        });
    }
    Ok(out)
}

/// What the swept-volume mesh guarantees, from its report (world units).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Guarantee {
    /// Every point of the mesh's surface is at least this far outside the swept volume.
    pub clearance: f64,
    /// Every point of the surface is within this of the swept volume, where `everywhere`.
    pub bound: f64,
    /// Whether `bound` holds at every surface point (the flood classification) or only where
    /// the concavities are visible along an axis (then the upper end comes from the poses only).
    pub everywhere: bool,
}

/// The swept-volume mesh: its world triangles in a BVH.
pub struct Swept {
    pub bvh: Bvh,
}

impl Swept {
    pub fn new(tris: Vec<[DVec3; 3]>) -> Swept {
        Swept {
            bvh: Bvh::build(tris, LEAF),
        }
    }
}

/// The part at the listed poses (trajectory rows): local triangles and world matrices.
pub struct PosedPart {
    pub name: String,
    pub bvh: Bvh,
    pub solid: bool,
    /// (row, CSV line, matrix: local to world, node transform included); no row for a part
    /// that no row moves.
    pub poses: Vec<(Option<u32>, Option<u64>, DMat4)>,
}

/// The verdict on one obstacle.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Verdict {
    /// The obstacle does not meet the mesh: the swept volume misses it by at least `lower`.
    Clear,
    /// The obstacle meets the mesh, but no listed pose of the part meets it: the motion between
    /// poses, or the mesh's margin, may touch it.
    PossibleContact,
    /// Certain: the part at a listed pose meets the obstacle (`witness`).
    Contact,
}

/// A pair of points, world units.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PointPair {
    pub on_obstacle: [f64; 3],
    pub on_swept: [f64; 3],
    pub distance: f64,
}

/// A certain contact: the part at a listed pose meets the obstacle.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Witness {
    pub part: String,
    /// Trajectory row (0-based) and its CSV line (none for a part no row moves).
    pub row: Option<u32>,
    pub line: Option<u64>,
    /// How they meet: `triangles cross` (then both triangle indices and a common point),
    /// `part inside the obstacle` or `obstacle inside the part` (then a point of the inner one).
    pub how: String,
    pub part_triangle: Option<u32>,
    pub obstacle_triangle: Option<u32>,
    pub point: [f64; 3],
}

/// One obstacle's clearance, world units.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ObstacleClearance {
    pub name: String,
    pub file: PathBuf,
    pub triangles: u64,
    /// Closed: its inside counts as the obstacle.
    pub solid: bool,
    pub verdict: Verdict,
    /// d: the distance from the obstacle to the mesh (0 where they meet).
    pub distance_to_mesh: f64,
    /// The guaranteed interval for the true clearance dist(obstacle, swept volume).
    pub lower: f64,
    /// None where no upper end is known (the bound does not hold everywhere and no pose was
    /// given).
    pub upper: Option<f64>,
    /// Where the upper end comes from: `mesh` (d + bound) or `poses` (the part at a pose).
    pub upper_from: Option<String>,
    /// The closest points of the obstacle and the mesh.
    pub closest: PointPair,
    /// The smallest distance from the obstacle to the part at a listed pose, and where.
    pub nearest_pose: Option<NearestPose>,
    pub witness: Option<Witness>,
}

/// The part at one listed pose nearest to the obstacle.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct NearestPose {
    pub part: String,
    pub row: Option<u32>,
    pub line: Option<u64>,
    pub distance: f64,
    pub points: PointPair,
}

/// The clearance section of a report: the guarantee it rests on, and each obstacle.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClearanceSection {
    pub guarantee: Guarantee,
    /// How the part's listed poses were read (they prove contacts), or why not.
    pub poses: String,
    /// The colour ramp's green end, world units.
    pub scale: f64,
    /// The least clearance asked of every obstacle, world units.
    pub required: Option<f64>,
    /// Every obstacle keeps `required` (a certain contact never does); true when none is asked.
    pub passes: bool,
    pub obstacles: Vec<ObstacleEntry>,
    /// Seconds spent measuring and mapping.
    pub seconds: f64,
}

/// One obstacle's clearance and the map file that shows it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ObstacleEntry {
    #[serde(flatten)]
    pub clearance: ObstacleClearance,
    pub map: PathBuf,
}

/// Whether an obstacle keeps `required`: its lower end is at least that, and no certain contact.
pub fn keeps(c: &ObstacleClearance, required: Option<f64>) -> bool {
    required.is_none_or(|x| c.lower >= x && c.verdict != Verdict::Contact)
}

/// The verdict in words for logs and summaries.
pub fn verdict_words(c: &ObstacleClearance) -> String {
    match (&c.verdict, &c.witness) {
        (Verdict::Contact, Some(w)) => format!(
            "CONTACT: {} {} at {}",
            w.part,
            w.how,
            w.line.map_or("its place".into(), |l| format!("line {l}"))
        ),
        (Verdict::PossibleContact, _) => {
            "possible contact: the obstacle meets the swept-volume mesh".into()
        }
        _ => "clear".into(),
    }
}

/// A relative allowance for the f64 rounding of distances between `swept` and `o`: 1e-12 of
/// the coordinates' magnitude (the computations lose far less than that).
fn rounding_allowance(swept: &Swept, o: &Obstacle) -> f64 {
    let max_abs = |bvh: &Bvh| {
        let n = &bvh.nodes[0];
        n.lo.abs().max(n.hi.abs()).max_element()
    };
    1e-12 * max_abs(&swept.bvh).max(max_abs(&o.bvh)).max(1.0)
}

/// A nearest pair as the report's points, `obstacle_is_a` saying which side the obstacle is.
fn point_pair(n: &Nearest, obstacle_is_a: bool) -> PointPair {
    let (o, s) = if obstacle_is_a {
        (n.a_point, n.b_point)
    } else {
        (n.b_point, n.a_point)
    };
    PointPair {
        on_obstacle: o.to_array(),
        on_swept: s.to_array(),
        distance: n.distance,
    }
}

/// The clearance of one obstacle from the swept volume that `swept` encloses with `g`, and
/// from the part at its listed poses.
pub fn measure(
    swept: &Swept,
    g: &Guarantee,
    parts: &[PosedPart],
    o: &Obstacle,
) -> ObstacleClearance {
    let allowance = rounding_allowance(swept, o);
    let near = pair::nearest(&o.bvh, None, &swept.bvh, f64::INFINITY)
        .expect("two non-empty triangle sets have a nearest pair");
    // They meet where the surfaces cross, the obstacle lies inside the mesh, or the mesh
    // inside a solid obstacle.
    let meets = near.distance == 0.0
        || pair::inside(&swept.bvh, o.positions[o.triangles[0][0] as usize], None)
        || (o.solid && pair::inside(&o.bvh, swept.bvh.tris[0][0], None));
    let witness = witness(parts, o);
    let mut upper: Option<(f64, &str)> = None;
    if g.everywhere {
        upper = Some((near.distance + g.bound + allowance, "mesh"));
    }
    let nearest_pose = match &witness {
        Some(_) => None,
        None => nearest_pose(parts, o, near.a_point, upper.map_or(f64::INFINITY, |u| u.0)),
    };
    if let Some(p) = &nearest_pose {
        if upper.is_none_or(|(u, _)| p.distance < u) {
            upper = Some((p.distance, "poses"));
        }
    }
    let verdict = if witness.is_some() {
        Verdict::Contact
    } else if meets {
        Verdict::PossibleContact
    } else {
        Verdict::Clear
    };
    let lower = match verdict {
        Verdict::Clear => (near.distance + g.clearance - allowance).max(0.0),
        _ => 0.0,
    };
    if verdict == Verdict::Contact {
        upper = Some((0.0, "poses"));
    }
    ObstacleClearance {
        name: o.name.clone(),
        file: o.file.clone(),
        triangles: o.triangles.len() as u64,
        solid: o.solid,
        verdict,
        distance_to_mesh: if meets { 0.0 } else { near.distance },
        lower,
        upper: upper.map(|u| u.0),
        upper_from: upper.map(|u| u.1.to_string()),
        closest: point_pair(&near, true),
        nearest_pose,
        witness,
    }
}

/// The first listed pose (in part and row order) at which the part meets `o`: triangles that
/// cross, or one inside the other (a closed part or obstacle).
fn witness(parts: &[PosedPart], o: &Obstacle) -> Option<Witness> {
    for part in parts {
        for &(row, line, m) in &part.poses {
            let at = |how: &str, p: DVec3, tris: Option<(u32, u32)>| Witness {
                part: part.name.clone(),
                row,
                line,
                how: how.into(),
                part_triangle: tris.map(|t| t.0),
                obstacle_triangle: tris.map(|t| t.1),
                point: p.to_array(),
            };
            if let Some(n) = pair::meeting(&part.bvh, Some(&m), &o.bvh) {
                return Some(at("triangles cross", n.a_point, Some((n.a_tri, n.b_tri))));
            }
            let part_point = m.transform_point3(part.bvh.tris[0][0]);
            if o.solid && pair::inside(&o.bvh, part_point, None) {
                return Some(at("part inside the obstacle", part_point, None));
            }
            let obstacle_point = o.positions[o.triangles[0][0] as usize];
            if part.solid && pair::inside(&part.bvh, obstacle_point, Some(&m.inverse())) {
                return Some(at("obstacle inside the part", obstacle_point, None));
            }
        }
    }
    None
}

/// Poses whose distance [`nearest_pose`] computes exactly: those nearest to the obstacle's
/// closest point.
const POSES_MEASURED: usize = 8;

/// A listed pose at which the part comes near `o`, if nearer than `cutoff` (the upper end known
/// already): its distance is a true distance to a point of the swept volume, so an upper end.
/// Which poses: the `POSES_MEASURED` nearest to `toward` (the obstacle's point nearest to the
/// mesh) by a point query each, then the exact distance of those; the others are not searched
/// (this tightens the upper end, it is not needed for it).
fn nearest_pose(
    parts: &[PosedPart],
    o: &Obstacle,
    toward: DVec3,
    cutoff: f64,
) -> Option<NearestPose> {
    let mut ranked: Vec<(f64, usize, usize)> = Vec::new();
    for (k, part) in parts.iter().enumerate() {
        for (i, (_, _, m)) in part.poses.iter().enumerate() {
            let (d, _) = part.bvh.nearest(m.inverse().transform_point3(toward));
            ranked.push((d, k, i));
        }
    }
    ranked.sort_by(|x, y| x.0.total_cmp(&y.0).then((x.1, x.2).cmp(&(y.1, y.2))));
    let mut best: Option<NearestPose> = None;
    for &(_, k, i) in ranked.iter().take(POSES_MEASURED) {
        let part = &parts[k];
        let (row, line, m) = part.poses[i];
        let limit = best.as_ref().map_or(cutoff, |b| b.distance);
        if let Some(n) = pair::nearest(&part.bvh, Some(&m), &o.bvh, limit) {
            if best.as_ref().is_none_or(|b| n.distance < b.distance) {
                best = Some(NearestPose {
                    part: part.name.clone(),
                    row,
                    line,
                    distance: n.distance,
                    points: point_pair(&n, false),
                });
            }
        }
    }
    best
}
