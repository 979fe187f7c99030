//! From parsed inputs to the sweep's input: which poses move which part, the grid around all
//! posed geometry, pose matrices in grid units, and the rounding term that keeps f32 honest.

use std::path::Path;

use glam::{DMat4, DVec3, Vec3};
use rayon::prelude::*;
use serde::Serialize;

use crate::error::InputError;
use crate::grid::{fit_grid, Accuracy, Grid, Overrides, Params};
use crate::model::{Generator, Trajectory};

/// Unit roundoff of f32.
const U32: f64 = f32::EPSILON as f64 / 2.0;
/// Rounding budget of one ray cast, in units of U32 times the largest grid coordinate. A ray
/// cast evaluates each candidate depth at an explicit point of the offset with about a dozen
/// correctly rounded operations on values bounded by the grid size (see `sweep::offset`); 64 is
/// several times that count, and the randomized oracle tests measure the real error against it.
const RAY_ROUNDING_FACTOR: f64 = 64.0;
/// The rounding term may use at most this fraction of a voxel; beyond it f32 is too coarse.
const MAX_ROUNDING_VOXELS: f64 = 0.1;

/// A part as the sweep sees it: its triangles and the poses that move it.
#[derive(Clone, Debug, Serialize)]
pub struct PartRange {
    pub name: String,
    /// First triangle in [`SweepInput::triangles`], and how many.
    pub tri_start: u32,
    pub tri_count: u32,
    /// First pose in [`SweepInput::poses`], and how many.
    pub pose_start: u32,
    pub pose_count: u32,
    /// True when no trajectory row names this part: it is included once where it stands.
    pub is_static: bool,
}

/// Everything the sweep backends consume. All f32 data is in the part's local frame (triangles)
/// or maps it to grid units (poses), so the GPU never sees world coordinates.
#[derive(Clone, Debug)]
pub struct SweepInput {
    pub grid: Grid,
    pub params: Params,
    /// Rounding term ρ added to δ, grid units (see [`rounding_term`]).
    pub rounding: f64,
    /// Radius rendered around every posed triangle, grid units: f32 of δ/h + ρ, rounded up.
    pub radius: f32,
    /// Triangles as 9 floats (three local vertices), all parts concatenated.
    pub triangles: Vec<[f32; 9]>,
    /// Row-major 3x4 matrices mapping a part's local frame to grid units.
    pub poses: Vec<[f32; 12]>,
    pub parts: Vec<PartRange>,
}

impl SweepInput {
    /// Posed triangles in total: the unit of sweep work.
    pub fn posed_triangles(&self) -> u64 {
        self.parts
            .iter()
            .map(|p| p.tri_count as u64 * p.pose_count as u64)
            .sum()
    }
}

/// Pair every part with its poses (world matrices P = M·W), reporting CSV errors by line.
fn assign_poses(
    generator: &Generator,
    trajectory: &Trajectory,
    csv_path: &Path,
) -> Result<Vec<(usize, Vec<DMat4>, bool)>, InputError> {
    let mut out: Vec<(usize, Vec<DMat4>, bool)> = Vec::new();
    if !trajectory.has_node_column {
        for (i, part) in generator.parts.iter().enumerate() {
            let poses = trajectory
                .poses
                .iter()
                .map(|p| p.matrix * part.world)
                .collect();
            out.push((i, poses, false));
        }
        return Ok(out);
    }
    let mut by_part: Vec<Vec<DMat4>> = vec![Vec::new(); generator.parts.len()];
    for pose in &trajectory.poses {
        let name = pose.node.as_deref().unwrap_or_default();
        let hits: Vec<usize> = generator
            .parts
            .iter()
            .enumerate()
            .filter(|(_, p)| p.node_name.as_deref() == Some(name))
            .map(|(i, _)| i)
            .collect();
        match hits.as_slice() {
            [i] => by_part[*i].push(pose.matrix * generator.parts[*i].world),
            [] => {
                let known: Vec<&str> = generator
                    .parts
                    .iter()
                    .filter_map(|p| p.node_name.as_deref())
                    .collect();
                return Err(InputError::new(
                    csv_path,
                    format!("no node named {name:?} carries a mesh in the generator"),
                    format!("use one of the mesh nodes: {}", known.join(", ")),
                )
                .at_line(pose.line)
                .in_column("node"));
            }
            _ => {
                return Err(InputError::new(
                    csv_path,
                    format!(
                        "node name {name:?} is ambiguous: {} mesh nodes carry it",
                        hits.len()
                    ),
                    "give the glTF nodes unique names",
                )
                .at_line(pose.line)
                .in_column("node"))
            }
        }
    }
    for (i, poses) in by_part.into_iter().enumerate() {
        if poses.is_empty() {
            out.push((i, vec![generator.parts[i].world], true));
        } else {
            out.push((i, poses, false));
        }
    }
    Ok(out)
}

/// Axis-aligned box of all posed vertices, world units (f64, exact up to f64 rounding).
fn posed_bounds(generator: &Generator, assigned: &[(usize, Vec<DMat4>, bool)]) -> (DVec3, DVec3) {
    assigned
        .par_iter()
        .flat_map(|(i, poses, _)| poses.par_iter().map(move |m| (*i, *m)))
        .map(|(i, m)| {
            let mut lo = DVec3::splat(f64::INFINITY);
            let mut hi = DVec3::splat(f64::NEG_INFINITY);
            for v in &generator.parts[i].positions {
                let p = m.transform_point3(v.as_dvec3());
                lo = lo.min(p);
                hi = hi.max(p);
            }
            (lo, hi)
        })
        .reduce(
            || (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |a, b| (a.0.min(b.0), a.1.max(b.1)),
        )
}

/// Bound on the rounding of one posed triangle's depths, grid units.
///
/// Pose: the f32 matrix Â = fl(A) has |Â - A| <= u|A| entrywise, and the shader's
/// Â·v (three products, three sums) errs by at most γ₄·S per coordinate with
/// S = Σ_j |A_ij||v_j| + |A_i3| (Higham, ch. 3). Together <= 6u·S; over three coordinates
/// √3·6u·S in length, and every point of the posed triangle moves by no more than its vertices.
/// Ray cast: RAY_ROUNDING_FACTOR·u·B where B bounds every grid coordinate of the offset.
pub fn rounding_term(pose_s_max: f64, grid: &Grid, delta_voxels: f64) -> f64 {
    let b = grid.resolution() as f64 + 2.0 * delta_voxels;
    3f64.sqrt() * 6.0 * U32 * pose_s_max + RAY_ROUNDING_FACTOR * U32 * b
}

/// Build the sweep input. The paths name the inputs in errors.
pub fn build(
    generator: &Generator,
    gltf_path: &Path,
    trajectory: &Trajectory,
    csv_path: &Path,
    accuracy: Accuracy,
    overrides: Overrides,
) -> anyhow::Result<SweepInput> {
    let assigned = assign_poses(generator, trajectory, csv_path)?;
    let (lo, hi) = posed_bounds(generator, &assigned);
    let (grid, params) = fit_grid(lo, hi, accuracy, overrides).map_err(anyhow::Error::msg)?;
    let to_grid =
        DMat4::from_scale(DVec3::splat(1.0 / grid.h)) * DMat4::from_translation(-grid.origin());

    let mut triangles = Vec::with_capacity(generator.triangle_count());
    let mut poses = Vec::new();
    let mut parts = Vec::new();
    let mut pose_s_max: f64 = 0.0;
    for (i, part_poses, is_static) in &assigned {
        let part = &generator.parts[*i];
        let tri_start = triangles.len() as u32;
        for t in &part.triangles {
            let v = |k: usize| part.positions[t[k] as usize];
            let [a, b, c]: [Vec3; 3] = [v(0), v(1), v(2)];
            triangles.push([a.x, a.y, a.z, b.x, b.y, b.z, c.x, c.y, c.z]);
        }
        // Largest |coordinate| of the part's vertices, per axis (for the pose bound).
        let vmax = part
            .positions
            .iter()
            .fold(DVec3::ZERO, |m, v| m.max(v.as_dvec3().abs()));
        let pose_start = poses.len() as u32;
        for m in part_poses {
            let a = to_grid * *m;
            let rows = a.transpose().to_cols_array(); // row-major 4x4
            for r in 0..3 {
                let s: f64 = (0..3).map(|j| rows[4 * r + j].abs() * vmax[j]).sum::<f64>()
                    + rows[4 * r + 3].abs();
                pose_s_max = pose_s_max.max(s);
            }
            let mut m12 = [0f32; 12];
            for (k, x) in m12.iter_mut().enumerate() {
                *x = rows[k] as f32;
            }
            poses.push(m12);
        }
        parts.push(PartRange {
            name: part
                .node_name
                .clone()
                .unwrap_or_else(|| format!("node {}", part.node_index)),
            tri_start,
            tri_count: triangles.len() as u32 - tri_start,
            pose_start,
            pose_count: poses.len() as u32 - pose_start,
            is_static: *is_static,
        });
    }
    let delta_voxels = params.delta / grid.h;
    let rounding = rounding_term(pose_s_max, &grid, delta_voxels);
    if rounding > MAX_ROUNDING_VOXELS {
        let grid_only = rounding_term(0.0, &grid, delta_voxels);
        if grid_only > MAX_ROUNDING_VOXELS / 2.0 {
            anyhow::bail!(
                "f32 rounding would reach {rounding:.3} voxels at resolution {}; use a resolution of at most 8192",
                grid.resolution()
            );
        }
        return Err(InputError::new(
            gltf_path,
            format!(
                "f32 rounding would reach {rounding:.3} voxels: the generator's local coordinates are too large for this voxel size"
            ),
            "move the mesh's vertices near its node origin (apply the transform to the node), or use a coarser grid",
        )
        .into());
    }
    let radius = round_up_f32(delta_voxels + rounding);
    Ok(SweepInput {
        grid,
        params,
        rounding,
        radius,
        triangles,
        poses,
        parts,
    })
}

/// The least f32 that is >= x.
pub fn round_up_f32(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64) < x {
        f.next_up()
    } else {
        f
    }
}
