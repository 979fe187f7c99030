//! From parsed inputs to the sweep's input: which poses move which part, the grid around all
//! posed geometry, pose matrices in grid units, and the rounding term that keeps f32 honest.

use std::ops::Range;
use std::path::Path;

use glam::{DMat4, DVec3, Vec3};
use rayon::prelude::*;
use serde::Serialize;

use crate::error::{num, InputError, OptionError, OptionKey};
use crate::input::chain;
use crate::input::grid::{fit_grid, Accuracy, Grid, Overrides, Params};
use crate::input::model::{Generator, LinedPose, Part, Rows, Trajectory};
use crate::input::motion::{self, Motion, MotionReport, MU_VOXELS};
use crate::input::outline;
use crate::input::poses::PoseSource;

/// Unit roundoff of f32.
const U32: f64 = f32::EPSILON as f64 / 2.0;
/// Rounding budget of one ray cast, in units of U32 times the largest grid coordinate. A ray
/// cast evaluates each candidate depth at an explicit point of the offset with about a dozen
/// correctly rounded operations on values bounded by the grid size (see `sweep::offset`); 64 is
/// several times that count, and the randomized oracle tests measure the real error against it.
const RAY_ROUNDING_FACTOR: f64 = 64.0;
/// The rounding term may use at most this fraction of a voxel; beyond it f32 is too coarse.
const MAX_ROUNDING_VOXELS: f64 = 0.1;
/// Writing the mesh's world coordinates as f32 may move a vertex by at most this fraction of a
/// voxel (`pipeline::execute` checks the real rounding against the same limit after the fact).
pub const MAX_OUTPUT_ROUNDING_VOXELS: f64 = 0.01;
/// Largest world coordinate accepted: f32 outputs (mesh, EXR distances up to twice it) stay finite.
const MAX_WORLD_COORDINATE: f64 = f32::MAX as f64 / 4.0;
/// Half the smallest f32 subnormal: the absolute rounding error of f32 near zero.
const F32_ABS_ROUNDING: f64 = 7.006_492_321_624_085e-46;

/// A part as the sweep sees it: its triangles and the poses that move it.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct PartRange {
    pub name: String,
    /// First triangle in [`SweepInput::triangles`], and how many.
    pub tri_start: u32,
    pub tri_count: u32,
    /// First pose in the order of all parts' poses, and how many; [`SweepInput::poses`] makes
    /// them by part and index within the part (0..pose_count).
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
    /// Radius rendered around every posed triangle, grid units: f32 of δ/h + μ/h + ρ, rounded
    /// up.
    pub radius: f32,
    /// The motion between rows and the budget μ it adds to the radius (0 for discrete motion).
    pub motion: MotionReport,
    /// Triangles as 9 floats (three local vertices), all parts concatenated.
    pub triangles: Vec<[f32; 9]>,
    /// Every part's poses as row-major 3x4 f32 matrices mapping its local frame to grid units,
    /// made on demand a batch at a time (the sub-poses of a motion are never all stored).
    pub poses: PoseSource,
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

    /// Shard `index` of `count`'s share of the poses, one range of pose indices per part: the
    /// posed triangles, taken in order (part by part, pose by pose), are cut into `count` runs
    /// of equal length, and a pose goes to the run where its first posed triangle falls. Every
    /// pose lands in exactly one shard, and the shards' work differs by at most one pose's
    /// triangles (plus rounding).
    pub fn shard_windows(&self, index: u32, count: u32) -> Vec<Range<u64>> {
        assert!(index < count);
        let total = self.posed_triangles() as u128;
        let cut = |i: u32| total * i as u128 / count as u128; // posed triangles before shard i
        let (lo, hi) = (cut(index), cut(index + 1));
        let mut before = 0u128; // posed triangles of the parts before this one
        self.parts
            .iter()
            .map(|p| {
                let (t, n) = (p.tri_count as u128, p.pose_count as u64);
                // Pose j starts at before + j·t: the first j with that ≥ x is ⌈(x - before)/t⌉.
                let first = |x: u128| -> u64 {
                    if t == 0 {
                        return if x <= before { 0 } else { n };
                    }
                    (x.saturating_sub(before).div_ceil(t)).min(n as u128) as u64
                };
                let w = first(lo)..first(hi);
                before += t * n as u128;
                w
            })
            .collect()
    }

    /// The same job restricted to `windows` (from [`Self::shard_windows`]): the grid, radii,
    /// rounding term and motion stay those of the whole job, so the shards' images merge into
    /// exactly the whole job's.
    pub fn restricted(&self, windows: Vec<Range<u64>>) -> SweepInput {
        let mut parts = self.parts.clone();
        let mut pose_start = 0u32;
        for (p, w) in parts.iter_mut().zip(&windows) {
            p.pose_start = pose_start;
            p.pose_count = (w.end - w.start) as u32;
            pose_start += p.pose_count;
        }
        SweepInput {
            poses: self.poses.windowed(windows),
            parts,
            ..self.clone()
        }
    }
}

/// Pair every part with its poses (world matrices P = M·W), reporting CSV errors by line.
fn assign_poses(
    generator: &Generator,
    trajectory: &Trajectory,
    csv_path: &Path,
) -> Result<Vec<(usize, Vec<LinedPose>, bool)>, InputError> {
    let mut out: Vec<(usize, Vec<LinedPose>, bool)> = Vec::new();
    if !trajectory.has_node_column {
        for (i, part) in generator.parts.iter().enumerate() {
            let poses = trajectory
                .poses
                .iter()
                .map(|p| (p.matrix * part.world, Some(p.line)))
                .collect();
            out.push((i, poses, false));
        }
        return Ok(out);
    }
    let mut by_part: Vec<Vec<LinedPose>> = vec![Vec::new(); generator.parts.len()];
    for pose in &trajectory.poses {
        let name = pose.node.as_deref().unwrap_or_default();
        let i = generator.part_named(name, csv_path, pose.line)?;
        by_part[i].push((pose.matrix * generator.parts[i].world, Some(pose.line)));
    }
    for (i, poses) in by_part.into_iter().enumerate() {
        if poses.is_empty() {
            out.push((i, vec![(generator.parts[i].world, None)], true));
        } else {
            out.push((i, poses, false));
        }
    }
    Ok(out)
}

/// Axis-aligned box of one part's vertices under pose `m`, world units.
fn pose_box(generator: &Generator, part: usize, m: &DMat4) -> (DVec3, DVec3) {
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    for v in &generator.parts[part].positions {
        let p = m.transform_point3(v.as_dvec3());
        lo = lo.min(p);
        hi = hi.max(p);
    }
    (lo, hi)
}

/// Axis-aligned box of all posed vertices, world units (f64, exact up to f64 rounding).
fn posed_bounds(
    generator: &Generator,
    assigned: &[(usize, Vec<LinedPose>, bool)],
) -> (DVec3, DVec3) {
    assigned
        .par_iter()
        .flat_map(|(i, poses, _)| poses.par_iter().map(move |m| (*i, m.0)))
        .map(|(i, m)| pose_box(generator, i, &m))
        .reduce(
            || (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |a, b| (a.0.min(b.0), a.1.max(b.1)),
        )
}

/// The pose putting a part farthest from the world origin: (part, its CSV line, the largest
/// |world coordinate| of its posed vertices); a reach that is not a number counts as infinite.
fn farthest_pose(
    generator: &Generator,
    assigned: &[(usize, Vec<LinedPose>, bool)],
) -> (usize, Option<u64>, f64) {
    assigned
        .iter()
        .flat_map(|(i, poses, _)| poses.iter().map(move |(m, line)| (*i, m, *line)))
        .map(|(i, m, line)| {
            let (a, b) = pose_box(generator, i, m);
            let reach = a.abs().max(b.abs()).max_element();
            (i, line, if reach.is_nan() { f64::INFINITY } else { reach })
        })
        .fold((0, None, f64::NEG_INFINITY), |best, c| {
            if c.2 > best.2 {
                c
            } else {
                best
            }
        })
}

/// An error about posed coordinates, blamed on the farthest pose: its CSV line (the message
/// then names the node), or the glTF node of a part no row moves or whose own placement
/// already reaches half as far. `what` gives, from the pose's reach, the message and the fix.
fn blame_farthest(
    generator: &Generator,
    gltf_path: &Path,
    csv_path: &Path,
    assigned: &[(usize, Vec<LinedPose>, bool)],
    what: impl FnOnce(f64) -> (String, &'static str),
) -> InputError {
    let (index, line, reach) = farthest_pose(generator, assigned);
    let part = &generator.parts[index];
    let (a, b) = pose_box(generator, index, &part.world);
    let line = line.filter(|_| a.abs().max(b.abs()).max_element() < reach / 2.0);
    let node = match &part.node_name {
        Some(name) => format!("nodes[{}] ({name:?})", part.node_index),
        None => format!("nodes[{}]", part.node_index),
    };
    let (message, fix) = what(reach);
    match line {
        Some(line) => {
            InputError::new(csv_path, format!("{message} (node {node})"), fix).at_line(line)
        }
        None => InputError::new(gltf_path, message, fix).in_column(node),
    }
}

const FIX_FAR: &str =
    "move the part nearer the world origin (subtract a common offset from the translations), or use a coarser grid ($tolerance)";

/// Refuse, before any grid is fitted, posed coordinates that f32 outputs cannot hold or that
/// no grid fitted by resolution could tell apart (the box's extent at or below f32's rounding
/// of its distance from the origin: the part, far out, would be one point): blamed on the
/// pose's CSV line or the glTF node, never reported as a box without a place.
fn check_posed_range(
    generator: &Generator,
    gltf_path: &Path,
    csv_path: &Path,
    assigned: &[(usize, Vec<LinedPose>, bool)],
    (lo, hi): (DVec3, DVec3),
    accuracy: Accuracy,
    overrides: Overrides,
) -> Result<(), InputError> {
    let x = lo.abs().max(hi.abs()).max_element();
    let extent = (hi - lo).max_element();
    let blame = |message: &dyn Fn(f64) -> String| {
        Err(blame_farthest(
            generator,
            gltf_path,
            csv_path,
            assigned,
            |reach| (message(reach), FIX_FAR),
        ))
    };
    if !(x.is_finite() && extent.is_finite()) || x > MAX_WORLD_COORDINATE {
        return blame(&|reach| {
            format!(
                "f32 cannot hold the result: posed coordinates reach {} world units, beyond the {} that f32 outputs can hold",
                num(reach),
                num(MAX_WORLD_COORDINATE)
            )
        });
    }
    // With --resolution the voxel is a share of the extent (with no fixed --delta), and
    // check_world_range needs u·x <= 1% of it: an extent within u·x fails that at every
    // resolution; a zero extent leaves --resolution nothing to divide.
    let unresolved = extent == 0.0 || (overrides.delta.is_none() && extent <= U32 * x);
    if matches!(accuracy, Accuracy::Resolution(_)) && x > 0.0 && unresolved {
        return blame(&|reach| {
            format!(
                "f32 cannot hold the result: posed coordinates reach {} world units while all the posed geometry spans {}: that far out, f32 cannot tell its points apart",
                num(reach),
                num(extent)
            )
        });
    }
    Ok(())
}

/// Refuse, before the sweep, a grid whose world coordinates f32 cannot hold to a small part of
/// a voxel. The mesh lies in the grid box, so writing a vertex as f32 moves it by at most
/// u·X + 2⁻¹⁵⁰ (u = 2⁻²⁴, X the box's largest |world coordinate|, 2⁻¹⁵⁰ below the normal
/// range); that must stay under MAX_OUTPUT_ROUNDING_VOXELS·h, the limit `pipeline` checks on
/// the real mesh. The posed coordinates passed [`check_posed_range`], so a box beyond f32's
/// range was pushed there by the offset around them: blamed on `margin_key` ($delta, or the
/// $tolerance δ follows). Otherwise the error names the pose putting the part farthest out.
fn check_world_range(
    generator: &Generator,
    gltf_path: &Path,
    csv_path: &Path,
    assigned: &[(usize, Vec<LinedPose>, bool)],
    grid: &Grid,
    delta: f64,
    margin_key: OptionKey,
) -> anyhow::Result<()> {
    let lo = grid.origin();
    let hi = grid.to_world(DVec3::from_array(grid.dims.map(f64::from)));
    let x = lo.abs().max(hi.abs()).max_element();
    let rounding = U32 * x + F32_ABS_ROUNDING;
    let limit = MAX_OUTPUT_ROUNDING_VOXELS * grid.h;
    if rounding <= limit && x <= MAX_WORLD_COORDINATE {
        return Ok(());
    }
    if x > MAX_WORLD_COORDINATE {
        return Err(OptionError::new(
            margin_key,
            format!(
                "the offset radius δ = {} puts the grid's box {} world units from the origin, beyond the {} that f32 outputs can hold; pick a smaller {}",
                num(delta),
                num(x),
                num(MAX_WORLD_COORDINATE),
                if margin_key == OptionKey::Delta { "$delta" } else { "$tolerance" }
            ),
        )
        .into());
    }
    let h = grid.h;
    Err(blame_farthest(generator, gltf_path, csv_path, assigned, |reach| {
        let message = format!(
            "f32 cannot hold the result: posed coordinates reach {} world units while the voxel is {}; written as f32 the mesh could move by {}, more than {}% of a voxel",
            num(reach),
            num(h),
            num(rounding),
            MAX_OUTPUT_ROUNDING_VOXELS * 100.0
        );
        let fix = if reach > 1e6 * h {
            FIX_FAR
        } else {
            "scale the part up (use smaller units): its size is below f32 precision"
        };
        (message, fix)
    })
    .into())
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

/// Build the sweep input. The paths name the inputs in errors. With [`Motion::Screw`] the poses
/// include the sub-poses between rows that leave every point of the motion within μ of one
/// (`input::motion`), and the radius grows by μ.
pub fn build(
    generator: &Generator,
    gltf_path: &Path,
    trajectory: &Trajectory,
    csv_path: &Path,
    accuracy: Accuracy,
    overrides: Overrides,
    motion: Motion,
) -> anyhow::Result<SweepInput> {
    // The bounds over every row (box, path lengths, world range) are maxima of convex
    // functions of the vertex, so the parts' outlines give the same ones (`input::outline`).
    let outlined = Generator {
        parts: generator
            .parts
            .iter()
            .map(|p| Part {
                node_index: p.node_index,
                node_name: p.node_name.clone(),
                world: p.world,
                positions: outline::outline(&p.positions),
                triangles: Vec::new(),
            })
            .collect(),
        nodes: generator.nodes.clone(),
        warnings: Vec::new(),
    };
    // Rows in parent space give the poses and the intervals together (`input::chain`).
    let (assigned, chain_intervals) = match trajectory.rows {
        Rows::World => (assign_poses(generator, trajectory, csv_path)?, None),
        Rows::Local => {
            let (assigned, intervals) = chain::resolve(&outlined, trajectory, csv_path, motion)?;
            (assigned, Some(intervals))
        }
    };
    let (mut lo, mut hi) = posed_bounds(&outlined, &assigned);
    check_posed_range(
        &outlined,
        gltf_path,
        csv_path,
        &assigned,
        (lo, hi),
        accuracy,
        overrides,
    )?;
    let intervals = match (motion, chain_intervals) {
        (_, Some(intervals)) => intervals,
        (Motion::Screw, None) => motion::intervals(&outlined, trajectory, csv_path, &assigned)?,
        (Motion::Discrete, None) => Vec::new(),
    };
    // The grid holds every instant of the motion (the sweep would clip what lies outside).
    let motion_box = (!intervals.is_empty())
        .then(|| motion::motion_box(&outlined, &intervals, (hi - lo).max_element()));
    let finite = |(a, b): (DVec3, DVec3)| a.is_finite() && b.is_finite();
    if let Some(m) = motion_box.filter(|&m| finite(m)) {
        (lo, hi) = (lo.min(m.0), hi.max(m.1));
    }
    let mu_voxels = if intervals.is_empty() { 0.0 } else { MU_VOXELS };
    let (grid, params) = fit_grid(lo, hi, accuracy, overrides, mu_voxels)?;
    // Rows too far out for f32 are refused by line first; a motion box that overflowed
    // otherwise would leave instants outside the grid: refused too, never clipped.
    let margin_key = if overrides.delta.is_some() {
        OptionKey::Delta
    } else {
        OptionKey::Tolerance
    };
    check_world_range(
        &outlined,
        gltf_path,
        csv_path,
        &assigned,
        &grid,
        params.delta,
        margin_key,
    )?;
    if motion_box.is_some_and(|m| !finite(m)) {
        return Err(OptionError::new(
            OptionKey::Motion,
            "the continuous motion's bounding box overflows f64: move the part nearer the world origin, or set $motion to discrete",
        )
        .into());
    }
    let (steps, mut motion_report) = if intervals.is_empty() {
        let poses = assigned.iter().map(|(_, p, _)| p.len() as u64).sum();
        (Vec::new(), motion::discrete_report(poses))
    } else {
        motion::sub_pose_steps(generator, &assigned, &intervals, mu_voxels * grid.h)?
    };
    motion_report.model = motion.name().into();
    let to_grid =
        DMat4::from_scale(DVec3::splat(1.0 / grid.h)) * DMat4::from_translation(-grid.origin());

    let mut triangles = Vec::with_capacity(generator.triangle_count());
    let mut parts = Vec::new();
    // Each part's rows and the intervals between them with their steps (none when discrete).
    let mut motions = Vec::with_capacity(assigned.len());
    let mut next = intervals.into_iter().zip(steps);
    let mut pose_start = 0u32;
    // Largest |coordinate| of each part's vertices, per axis (for the pose bound).
    let mut vmax = Vec::with_capacity(assigned.len());
    for (i, part_poses, is_static) in assigned {
        let part = &generator.parts[i];
        let tri_start = triangles.len() as u32;
        for t in &part.triangles {
            let v = |k: usize| part.positions[t[k] as usize];
            let [a, b, c]: [Vec3; 3] = [v(0), v(1), v(2)];
            triangles.push([a.x, a.y, a.z, b.x, b.y, b.z, c.x, c.y, c.z]);
        }
        vmax.push(
            part.positions
                .iter()
                .fold(DVec3::ZERO, |m, v| m.max(v.as_dvec3().abs())),
        );
        let rows: Vec<DMat4> = part_poses.into_iter().map(|(m, _)| m).collect();
        let part_intervals: Vec<_> = if motion_report.intervals == 0 {
            Vec::new()
        } else {
            next.by_ref().take(rows.len() - 1).collect()
        };
        let pose_count: u64 =
            rows.len() as u64 + part_intervals.iter().map(|(_, k)| k - 1).sum::<u64>();
        // u32 by construction: `sub_pose_steps` refuses more poses in all.
        let pose_count = u32::try_from(pose_count).expect("pose count checked");
        motions.push((rows, part_intervals));
        parts.push(PartRange {
            name: part
                .node_name
                .clone()
                .unwrap_or_else(|| format!("node {}", part.node_index)),
            tri_start,
            tri_count: triangles.len() as u32 - tri_start,
            pose_start,
            pose_count,
            is_static,
        });
        pose_start += pose_count;
    }
    let poses = PoseSource::new(to_grid, motions);
    // The pose bound S (see [`rounding_term`]) over every pose, sub-poses included, each as the
    // sweep will render it: one streamed pass, nothing stored.
    let pose_s_max = vmax
        .iter()
        .enumerate()
        .map(|(index, vmax)| {
            poses.max_over(index, |rows| {
                (0..3)
                    .map(|r| {
                        (0..3).map(|j| rows[4 * r + j].abs() * vmax[j]).sum::<f64>()
                            + rows[4 * r + 3].abs()
                    })
                    .fold(0.0, f64::max)
            })
        })
        .fold(0.0, f64::max);
    let delta_voxels = params.delta / grid.h + mu_voxels;
    let rounding = rounding_term(pose_s_max, &grid, delta_voxels);
    if rounding > MAX_ROUNDING_VOXELS {
        let grid_only = rounding_term(0.0, &grid, delta_voxels);
        if grid_only > MAX_ROUNDING_VOXELS / 2.0 {
            return Err(OptionError::new(
                OptionKey::Resolution,
                format!(
                    "f32 rounding would reach {rounding:.3} voxels at resolution {}; use a $resolution of at most 8192",
                    grid.resolution()
                ),
            )
            .into());
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
        motion: motion_report,
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
