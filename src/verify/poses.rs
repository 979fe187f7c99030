//! Which poses move which part (the same rule and the same errors as `sweptvol run`, written
//! again here so the verifier trusts nothing of the sweep's set-up), and a cluster tree over
//! each part's poses so that overlapping poses (vibration) are tested together.

use std::path::Path;

use glam::{DMat4, DVec3};
use serde::Serialize;

use super::bvh::Bvh;
use super::geom;
use crate::error::InputError;
use crate::input::model::{Generator, Trajectory};

/// One world pose of a part: x_world = matrix · x_local (node transform included).
#[derive(Clone, Debug)]
pub struct PartPose {
    pub matrix: DMat4,
    /// Upper bound of the largest singular value of the linear part.
    pub sigma_max: f64,
    /// Lower bound of the smallest singular value of the linear part.
    pub sigma_min: f64,
    /// Index of the trajectory row (0-based), None for a part no row moves.
    pub row: Option<u32>,
    /// CSV line of that row.
    pub line: Option<u64>,
    /// For a pose of the continuous motion between `row` and a later row: every instant this
    /// pose stands for puts every point of the part within `reach` of where this pose puts it
    /// (0 for a row itself; `verify::motion`).
    pub reach: f64,
    pub between: Option<Between>,
}

/// Where a pose of the continuous motion lies: on the way from its row to `to_row`, at s.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Between {
    pub to_row: u32,
    pub to_line: u64,
    pub s: f64,
}

impl PartPose {
    pub fn new(matrix: DMat4, row: Option<u32>, line: Option<u64>) -> PartPose {
        let (sigma_max, sigma_min) = geom::singular_bounds([
            matrix.x_axis.truncate(),
            matrix.y_axis.truncate(),
            matrix.z_axis.truncate(),
        ]);
        PartPose {
            matrix,
            sigma_max,
            sigma_min,
            row,
            line,
            reach: 0.0,
            between: None,
        }
    }
}

/// A part of the generator with its local triangles, BVH and poses.
pub struct PosedPart {
    pub node_index: usize,
    pub name: String,
    pub bvh: Bvh,
    pub poses: Vec<PartPose>,
    pub tree: PoseTree,
}

impl PosedPart {
    /// A part from its local triangles and poses: builds the BVH (one triangle per leaf) and
    /// the pose tree around its root ball.
    pub fn new(
        node_index: usize,
        name: String,
        tris: Vec<[DVec3; 3]>,
        poses: Vec<PartPose>,
    ) -> PosedPart {
        let bvh = Bvh::build(tris, 1);
        let root = &bvh.nodes[0];
        let tree = PoseTree::build(&poses, root.centre, root.radius);
        PosedPart {
            node_index,
            name,
            bvh,
            poses,
            tree,
        }
    }
}

/// Pair every part with its poses: without a `node` column every row moves every part; with
/// it each row moves the one part of that name and parts no row names stay once where they are.
pub fn assign(
    generator: &Generator,
    trajectory: &Trajectory,
    csv_path: &Path,
) -> Result<Vec<Vec<PartPose>>, InputError> {
    let mut by_part: Vec<Vec<PartPose>> = vec![Vec::new(); generator.parts.len()];
    for (row, p) in trajectory.poses.iter().enumerate() {
        let targets: Vec<usize> = if trajectory.has_node_column {
            let name = p.node.as_deref().unwrap_or_default();
            vec![generator.part_named(name, csv_path, p.line)?]
        } else {
            (0..generator.parts.len()).collect()
        };
        for i in targets {
            let m = p.matrix * generator.parts[i].world;
            if let Some(det) = singular(&m) {
                let part = &generator.parts[i];
                return Err(InputError::new(
                    csv_path,
                    format!(
                        "the row's matrix times the world transform of node {} ({:?}) is singular (determinant {det:e}): the posed part is flat",
                        part.node_index,
                        part.node_name.as_deref().unwrap_or("")
                    ),
                    "give the row and the node invertible transforms with non-zero scales",
                )
                .at_line(p.line));
            }
            by_part[i].push(PartPose::new(m, Some(row as u32), Some(p.line)));
        }
    }
    for (i, poses) in by_part.iter_mut().enumerate() {
        if poses.is_empty() {
            poses.push(PartPose::new(generator.parts[i].world, None, None));
        }
    }
    Ok(by_part)
}

/// The determinant of `m`'s 3x3 part if it is singular: |det| at most 1e-12 times the product
/// of its column lengths (the rule of the trajectory reader, written again here).
fn singular(m: &DMat4) -> Option<f64> {
    let cols = [
        m.x_axis.truncate(),
        m.y_axis.truncate(),
        m.z_axis.truncate(),
    ];
    let det = cols[0].dot(cols[1].cross(cols[2]));
    let scale = cols.iter().map(|c| c.length()).product::<f64>();
    (scale == 0.0 || !det.is_finite() || det.abs() <= 1e-12 * scale).then_some(det)
}

/// A set of poses tested together: a contiguous range of [`PoseTree::perm`], a reference pose,
/// and how far any pose of the set moves a local point x from where the reference puts it:
/// |P_i x - P_ref x| <= alpha·|x - origin| + beta.
#[derive(Clone, Debug)]
pub struct Cluster {
    pub lo: u32,
    pub hi: u32,
    /// Index into the part's poses.
    pub reference: u32,
    /// max_i ‖A_i - A_ref‖_F (Frobenius bounds the spectral norm).
    pub alpha: f64,
    /// max_i |P_i(origin) - P_ref(origin)|.
    pub beta: f64,
    /// The largest reach of the set's poses ([`PartPose::reach`]).
    pub reach: f64,
    /// Children (inner clusters only).
    pub left: u32,
    pub right: u32,
}

impl Cluster {
    pub fn is_leaf(&self) -> bool {
        self.hi - self.lo == 1
    }
    pub fn pose_count(&self) -> u32 {
        self.hi - self.lo
    }
    /// Bound on |P(y) - P_ref y| for every pose i of the set, every instant P that pose stands
    /// for (its reach), and y in the local ball (c, r).
    pub fn spread(&self, origin: DVec3, c: DVec3, r: f64) -> f64 {
        if self.is_leaf() {
            self.reach
        } else {
            (self.alpha * ((c - origin).length() + r) + self.beta) * (1.0 + 1e-12) + self.reach
        }
    }
}

/// Binary tree of pose sets, split at the median of the widest feature (where the pose puts
/// the part's centre, and its linear part scaled by the part's radius) down to single poses.
pub struct PoseTree {
    pub perm: Vec<u32>,
    pub clusters: Vec<Cluster>,
    /// The part's local bounding-box centre.
    pub origin: DVec3,
}

impl PoseTree {
    pub fn build(poses: &[PartPose], origin: DVec3, radius: f64) -> PoseTree {
        let features: Vec<[f64; 12]> = poses
            .iter()
            .map(|p| {
                let m = p.matrix;
                let t = m.transform_point3(origin);
                let cols = [m.x_axis, m.y_axis, m.z_axis];
                std::array::from_fn(|k| {
                    if k < 3 {
                        t[k]
                    } else {
                        cols[(k - 3) / 3][(k - 3) % 3] * radius
                    }
                })
            })
            .collect();
        let mut tree = PoseTree {
            perm: (0..poses.len() as u32).collect(),
            clusters: Vec::with_capacity(2 * poses.len()),
            origin,
        };
        let mut perm = std::mem::take(&mut tree.perm);
        tree.node(poses, &features, &mut perm, 0);
        tree.perm = perm;
        tree
    }

    fn node(&mut self, poses: &[PartPose], f: &[[f64; 12]], perm: &mut [u32], lo: u32) -> u32 {
        let n = perm.len();
        let mut mean = [0.0; 12];
        for &i in perm.iter() {
            for k in 0..12 {
                mean[k] += f[i as usize][k] / n as f64;
            }
        }
        let dist2 = |i: u32| -> f64 { (0..12).map(|k| (f[i as usize][k] - mean[k]).powi(2)).sum() };
        let reference = *perm
            .iter()
            .min_by(|a, b| dist2(**a).total_cmp(&dist2(**b)))
            .expect("a cluster has poses");
        let r = poses[reference as usize].matrix;
        let r_origin = r.transform_point3(self.origin);
        let (mut alpha, mut beta, mut reach) = (0.0f64, 0.0f64, 0.0f64);
        for &i in perm.iter() {
            reach = reach.max(poses[i as usize].reach);
            let m = poses[i as usize].matrix;
            let d = [
                m.x_axis - r.x_axis,
                m.y_axis - r.y_axis,
                m.z_axis - r.z_axis,
            ];
            let frob = d
                .iter()
                .map(|c| c.truncate().length_squared())
                .sum::<f64>()
                .sqrt();
            alpha = alpha.max(frob);
            beta = beta.max((m.transform_point3(self.origin) - r_origin).length());
        }
        let index = self.clusters.len() as u32;
        self.clusters.push(Cluster {
            lo,
            hi: lo + n as u32,
            reference,
            alpha,
            beta,
            reach,
            left: 0,
            right: 0,
        });
        if n == 1 {
            return index;
        }
        let widest = (0..12)
            .max_by(|&a, &b| {
                let ext = |k: usize| {
                    let (lo, hi) = perm
                        .iter()
                        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &i| {
                            (l.min(f[i as usize][k]), h.max(f[i as usize][k]))
                        });
                    hi - lo
                };
                ext(a).total_cmp(&ext(b))
            })
            .unwrap_or(0);
        let mid = n / 2;
        perm.select_nth_unstable_by(mid, |a, b| {
            f[*a as usize][widest].total_cmp(&f[*b as usize][widest])
        });
        let (a, b) = perm.split_at_mut(mid);
        let left = self.node(poses, f, a, lo);
        let right = self.node(poses, f, b, lo + mid as u32);
        let c = &mut self.clusters[index as usize];
        c.left = left;
        c.right = right;
        index
    }
}

/// Local-frame triangles of a part, f64 (exact from the file's f32).
pub fn local_triangles(part: &crate::input::model::Part) -> Vec<[DVec3; 3]> {
    part.triangles
        .iter()
        .map(|t| t.map(|i| part.positions[i as usize].as_dvec3()))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cluster_spread_bounds_every_pose() {
        let mut rng = fastrand::Rng::with_seed(5);
        let mut f = || rng.f64() - 0.5;
        let poses: Vec<PartPose> = (0..200)
            .map(|_| {
                let m = DMat4::from_cols(
                    (DVec3::X + 0.1 * DVec3::new(f(), f(), f())).extend(0.0),
                    (DVec3::Y + 0.1 * DVec3::new(f(), f(), f())).extend(0.0),
                    (DVec3::Z + 0.1 * DVec3::new(f(), f(), f())).extend(0.0),
                    DVec3::new(f(), f(), f()).extend(1.0),
                );
                PartPose::new(m, None, None)
            })
            .collect();
        let origin = DVec3::new(0.3, -0.2, 0.1);
        let tree = PoseTree::build(&poses, origin, 1.0);
        assert_eq!(tree.clusters.len(), 2 * poses.len() - 1);
        for c in &tree.clusters {
            let r = poses[c.reference as usize].matrix;
            for _ in 0..20 {
                let y = DVec3::new(f(), f(), f()) * 4.0;
                let bound = c.spread(origin, y, 0.0);
                for &i in &tree.perm[c.lo as usize..c.hi as usize] {
                    let m = poses[i as usize].matrix;
                    let d = (m.transform_point3(y) - r.transform_point3(y)).length();
                    assert!(d <= bound + 1e-12, "{d} > {bound}");
                }
            }
        }
    }
}
