//! `sweptvol verify`: an independent certificate for any swept-volume mesh.
//!
//! Reads the generator and trajectory with the same parsers as `run` and the mesh with the same
//! glTF reader, then checks, in f64 and with no code from the sweep, depth images, voxels or
//! simplifier: mesh health (`health`), containment of every posed generator triangle
//! (`containment`) and a bound on the one-sided Hausdorff distance from the mesh (`deviation`).
//! docs/verify.md states what a pass proves.

pub mod bvh;
pub mod chain;
pub mod containment;
pub mod deviation;
pub mod geom;
pub mod health;
pub mod motion;
pub mod nearest;
pub mod pockets;
pub mod poses;
mod text;
pub mod winding;

use text::{describe_outside, fmt_len, fmt_point};

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64};
use std::time::Instant;

use glam::DVec3;
use serde::Serialize;

use crate::error::{OptionError, OptionKey};
use crate::input::motion::Motion;
use crate::io::{gltf_in, trajectory};
use bvh::Bvh;
use containment::{Containment, Target};
use deviation::Deviation;
use health::Health;
use pockets::Pockets;
use poses::PosedPart;
use winding::Winding;

/// Default covering radius: this fraction of the mesh's bounding-box diagonal.
pub const DEFAULT_SPACING_FRACTION: f64 = 1.0 / 2000.0;
/// `--spacing` is refused when covering the mesh at that radius could take more samples than
/// this (about 10⁴ s at 10⁶ samples/s); the default spacing needs about 10⁷ on a sphere.
pub const MAX_SAMPLES: f64 = 1e10;

/// Where `--bound` must hold.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum BoundScope {
    /// At every mesh point.
    #[default]
    Everywhere,
    /// At every mesh point that sees out of the swept volume along some axis: points whose six
    /// axis rays all come within the bound of the volume lie in filled pockets and are
    /// accepted (the scope of `run`'s `hausdorff_bound`; see `pockets`).
    AxisVisible,
}

/// Progress of the long stages, for a progress bar.
pub trait Progress: Sync {
    fn stage(&self, _name: &str, _total: u64) {}
    fn advance(&self, _done: u64, _total: u64) {}
}

/// Reports nothing.
pub struct Silent;
impl Progress for Silent {}

#[derive(Clone, Debug)]
pub struct VerifyOptions {
    pub generator: PathBuf,
    pub trajectory: PathBuf,
    pub mesh: PathBuf,
    /// Fail unless the deviation bound is at most this (world units).
    pub bound: Option<f64>,
    /// Where `bound` must hold.
    pub bound_scope: BoundScope,
    /// Covering radius of the samples, world units [default: mesh diagonal / 2000] (posed pieces
    /// nearer the mesh split on down to [`containment::finest`] of it).
    pub spacing: Option<f64>,
    /// Search on after the first posed triangle proven outside and count every failure
    /// (default: stop there, the certificate has failed).
    pub all_failures: bool,
    /// Certify the screw motion between rows (the default), or only the listed poses.
    pub motion: Motion,
    /// The run's `relative_to`: the mesh is in this node's frame, and the other parts move
    /// relative to it (the same reading of the inputs as `run`'s, `input::relative`).
    pub relative_to: Option<String>,
    /// What the trajectory's rows are: world-space transforms, or each node's own transform
    /// relative to its parent (`verify::chain`).
    pub rows: crate::input::model::Rows,
    /// Where a robot's `package://` meshes are (`io::urdf`).
    pub package_dir: Vec<PathBuf>,
}

#[derive(Clone, Debug, Serialize)]
pub struct Inputs {
    pub generator: PathBuf,
    pub trajectory: PathBuf,
    pub mesh: PathBuf,
    pub generator_parts: u64,
    pub generator_triangles: u64,
    pub trajectory_rows: u64,
    /// Σ over parts of triangles × poses.
    pub posed_triangles: u64,
    pub mesh_triangles: u64,
}

#[derive(Clone, Debug, Serialize)]
pub struct ContainmentReport {
    /// Every posed triangle certified inside with clearance, and the mesh closed.
    pub holds: bool,
    /// Covering radius of the posed-triangle samples, world units (pieces nearer the mesh are
    /// split on down to `finest`).
    pub spacing: f64,
    /// The finest covering radius those pieces may reach ([`containment::finest`]).
    pub finest: f64,
    #[serde(flatten)]
    pub result: Containment,
}

#[derive(Clone, Debug, Serialize)]
pub struct DeviationReport {
    /// The `--bound` asked for, and whether the deviation bound is within it.
    pub limit: Option<f64>,
    pub within_limit: Option<bool>,
    pub scope: BoundScope,
    #[serde(flatten)]
    pub result: Deviation,
    /// Where the deviation exceeds the limit: whether those places are hidden from all six
    /// axis directions (present only then).
    pub pockets: Option<Pockets>,
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct Timings {
    pub read_inputs: f64,
    pub setup: f64,
    pub health: f64,
    pub containment: f64,
    pub deviation: f64,
    pub pockets: f64,
    pub total: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub sweptvol_version: String,
    pub passed: bool,
    /// One line per failed check; empty when passed.
    pub failures: Vec<String>,
    pub inputs: Inputs,
    pub health: Health,
    /// The motion certified: the model and the poses that stand for it.
    pub motion: motion::MotionCheck,
    pub containment: ContainmentReport,
    pub deviation: DeviationReport,
    /// Seconds per stage.
    pub timings: Timings,
    pub threads: usize,
}

/// Read the inputs (errors are `InputError`s naming file, line and fix) and check the mesh.
pub fn verify(opts: &VerifyOptions, progress: &dyn Progress) -> anyhow::Result<Report> {
    let t0 = Instant::now();
    if let Some(s) = opts.spacing {
        if !(s.is_finite() && s > 0.0) {
            return Err(OptionError::new(
                OptionKey::Spacing,
                format!("$spacing {s} must be a positive number of world units"),
            )
            .into());
        }
    }
    if let Some(b) = opts.bound {
        if !(b.is_finite() && b >= 0.0) {
            return Err(OptionError::new(
                OptionKey::Bound,
                format!("$bound {b} must be a non-negative number of world units"),
            )
            .into());
        }
    }
    let (generator, traj) = if crate::io::urdf::is_robot(&opts.generator) {
        crate::io::urdf::read_inputs(&opts.generator, &opts.trajectory, &opts.package_dir)?
    } else {
        let mut traj = trajectory::read_trajectory(&opts.trajectory)?;
        traj.rows = opts.rows;
        (gltf_in::read_generator(&opts.generator)?, traj)
    };
    let local = traj.rows == crate::input::model::Rows::Local;
    if local && opts.relative_to.is_some() {
        return Err(OptionError::new(
            OptionKey::RelativeTo,
            "$relative_to takes world-space rows, not $rows local",
        )
        .into());
    }
    let (generator, traj) = match &opts.relative_to {
        None => (generator, traj),
        Some(node) => {
            let (g, t, _) =
                crate::input::relative::apply(&generator, &traj, &opts.trajectory, node)?;
            (g, t)
        }
    };
    let mesh = gltf_in::read_world_triangles(&opts.mesh)?;
    let rig = match local {
        true => Some(chain::Rig::new(&generator, &traj, &opts.trajectory)?),
        false => None,
    };
    let assigned = match &rig {
        Some(rig) => rig.listed()?,
        None => poses::assign(&generator, &traj, &opts.trajectory)?,
    };
    let t1 = Instant::now();

    let (lo, hi) = mesh.iter().flatten().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(lo, hi), v| (lo.min(*v), hi.max(*v)),
    );
    let diagonal = (hi - lo).length();
    let spacing = opts
        .spacing
        .unwrap_or(diagonal * DEFAULT_SPACING_FRACTION)
        .max(f64::MIN_POSITIVE);
    if let Some(s) = opts.spacing {
        check_spacing(s, &mesh)?;
    }
    // Continuous motion: middle poses of sub-intervals whose reach is half the covering
    // radius, so a certified ball still has room for the motion around its pose.
    let (assigned, motion) = match (opts.motion, &rig) {
        (Motion::Screw, Some(rig)) => rig.continuous(spacing / 2.0)?,
        (Motion::Screw, None) => {
            motion::continuous(&generator, assigned, spacing / 2.0, &opts.trajectory)?
        }
        (Motion::Discrete, _) => {
            let poses = assigned.iter().map(|p| p.len() as u64).sum();
            let check = motion::MotionCheck {
                model: "discrete",
                poses,
                ..Default::default()
            };
            (assigned, check)
        }
    };
    let parts: Vec<PosedPart> = generator
        .parts
        .iter()
        .zip(assigned)
        .map(|(part, part_poses)| {
            let name = part
                .node_name
                .clone()
                .unwrap_or_else(|| format!("nodes[{}]", part.node_index));
            PosedPart::new(
                part.node_index,
                name,
                poses::local_triangles(part),
                part_poses,
            )
        })
        .collect();
    let scale = lo.abs().max(hi.abs()).max_element().max(diagonal);
    let mesh_bvh = Bvh::build(mesh.clone(), 4);
    let t2 = Instant::now();

    progress.stage("mesh health", mesh.len() as u64);
    let (health, boundary) = health::check(&mesh, &mesh_bvh);
    let winding = Winding::new(&mesh_bvh, &boundary);
    let t3 = Instant::now();

    let posed: u64 = parts
        .iter()
        .map(|p| p.bvh.tris.len() as u64 * p.poses.len() as u64)
        .sum();
    progress.stage("containment (posed triangles)", posed);
    let target = Target {
        bvh: &mesh_bvh,
        winding: &winding,
        abs_margin: 1e-12 * scale,
    };
    let done = AtomicU64::new(0);
    let stop = AtomicBool::new(false);
    let stop = (!opts.all_failures).then_some(&stop);
    let containment = parts
        .iter()
        .map(|p| containment::check(p, &target, spacing, progress, &done, posed, stop))
        .fold(Containment::default(), Containment::merge);
    let t4 = Instant::now();

    progress.stage("deviation (mesh triangles)", mesh.len() as u64);
    let limit = opts.bound.map(|b| (b, motion.max_reach));
    let mut deviation = deviation::check(&parts, &mesh, spacing, limit, progress);
    // Distances to the middle poses bound those to the motion from above (they are instants
    // of it); from below only up to their reach.
    deviation.lower = (deviation.lower - motion.max_reach).max(0.0);
    let t5 = Instant::now();

    // Beyond the limit: are those places filled pockets (hidden from all six axes)?
    let pockets = opts.bound.filter(|b| deviation.bound > *b).map(|b| {
        progress.stage("pockets (mesh triangles beyond --bound)", mesh.len() as u64);
        pockets::classify(&parts, &mesh, b, motion.max_reach, spacing, progress)
    });
    let t6 = Instant::now();

    let mut failures = Vec::new();
    if !health.closed {
        failures.push(format!(
            "mesh is not closed ({} open, {} misoriented, {} non-manifold edges): it bounds no solid, so containment cannot be proven",
            health.open_edges, health.misoriented_edges, health.non_manifold_edges
        ));
    }
    if health.closed && !health.watertight_manifold {
        failures.push(format!(
            "mesh is not a 2-manifold: {} edges with more than two triangles, {} vertices whose triangles are not one fan (pinches, or two vertices at one place); downstream tools (slicers, CAD import, booleans) refuse such meshes",
            health.non_manifold_edges, health.non_manifold_vertices
        ));
    }
    if containment.outside > 0 {
        let w = containment.worst_outside.as_ref();
        let of = if containment.stopped_early {
            format!(
                "at least {} of {posed} posed triangles have points outside the mesh (the search stopped at the first proven one; --all-failures lists them all)",
                containment.outside
            )
        } else {
            format!(
                "{} of {} posed triangles have points outside the mesh",
                containment.outside, containment.posed_triangles
            )
        };
        failures.push(format!(
            "containment: {of}{}",
            w.map(|w| format!(
                " (worst {} outside, {})",
                fmt_len(w.distance),
                describe_outside(w)
            ))
            .unwrap_or_default()
        ));
    }
    if containment.too_close > 0 {
        failures.push(format!(
            "containment: {} of {} posed triangles come too close to the mesh surface to certify down to covering radius {}",
            containment.too_close,
            containment.posed_triangles,
            fmt_len(containment::finest(spacing))
        ));
    }
    let within = opts.bound.map(|b| deviation.bound <= b);
    if let (Some(b), Some(p)) = (opts.bound, &pockets) {
        let strays = format!(
            "deviation: the mesh strays up to {} from the swept volume, more than --bound {}{}",
            fmt_len(deviation.bound),
            fmt_len(b),
            deviation
                .place
                .as_ref()
                .map(|p| format!(
                    " (at {}, mesh triangle {})",
                    fmt_point(p.point),
                    p.mesh_triangle
                ))
                .unwrap_or_default()
        );
        match opts.bound_scope {
            BoundScope::Everywhere if p.holds() => failures.push(format!(
                "{strays}; all {} pieces beyond it lie in pockets hidden from the six axis directions (filled, as `run`'s hausdorff_bound_scope says; --bound-scope axis-visible accepts them)",
                p.pieces_beyond
            )),
            BoundScope::Everywhere => failures.push(strays),
            BoundScope::AxisVisible => {}
        }
        if let Some(v) = &p.first_visible {
            failures.push(format!(
                "deviation: a mesh point beyond --bound {} sees out of the swept volume along an axis: at least {} from it at {} (mesh triangle {}), looking along {}; not a hidden pocket, so the bound of `run` is broken there",
                fmt_len(b),
                fmt_len(v.distance),
                fmt_point(v.point),
                v.mesh_triangle,
                v.direction
            ));
        }
        if p.undetermined > 0 {
            failures.push(format!(
                "deviation: {} of {} mesh pieces beyond --bound {} could not be settled down to covering radius {}: neither shown hidden from the six axis directions nor seeing out along one (their distance is within that radius of the bound, or their rays graze the volume); a finer --spacing may settle them",
                p.undetermined,
                p.pieces_beyond,
                fmt_len(b),
                fmt_len(pockets::finest(spacing))
            ));
        }
    }
    let holds = health.closed && containment.holds();
    Ok(Report {
        sweptvol_version: env!("CARGO_PKG_VERSION").into(),
        passed: failures.is_empty(),
        failures,
        motion,
        inputs: Inputs {
            generator: opts.generator.clone(),
            trajectory: opts.trajectory.clone(),
            mesh: opts.mesh.clone(),
            generator_parts: parts.len() as u64,
            generator_triangles: generator.triangle_count() as u64,
            trajectory_rows: traj.poses.len() as u64,
            posed_triangles: posed,
            mesh_triangles: mesh.len() as u64,
        },
        health,
        containment: ContainmentReport {
            holds,
            spacing,
            finest: containment::finest(spacing),
            result: containment,
        },
        deviation: DeviationReport {
            limit: opts.bound,
            within_limit: within,
            scope: opts.bound_scope,
            result: deviation,
            pockets,
        },
        timings: Timings {
            read_inputs: (t1 - t0).as_secs_f64(),
            setup: (t2 - t1).as_secs_f64(),
            health: (t3 - t2).as_secs_f64(),
            containment: (t4 - t3).as_secs_f64(),
            deviation: (t5 - t4).as_secs_f64(),
            pockets: (t6 - t5).as_secs_f64(),
            total: (t6 - t0).as_secs_f64(),
        },
        threads: rayon::current_num_threads(),
    })
}

/// Refuse a `--spacing` whose samples could not be computed in a sane time. The deviation stage
/// covers the whole mesh with pieces of covering radius s, and a triangle of area A takes at
/// least A / ((3√3/4)·s²) of them (an equilateral piece with circumradius s has the largest
/// area): a lower bound on the work, so nothing that could finish is refused. (Containment
/// refines only near the surface, so the posed generator's area says nothing certain.)
fn check_spacing(s: f64, mesh: &[[DVec3; 3]]) -> Result<(), OptionError> {
    let area = |t: &[DVec3; 3]| (t[1] - t[0]).cross(t[2] - t[0]).length() / 2.0;
    let mesh_area: f64 = mesh.iter().map(area).sum();
    let piece = 3f64.sqrt() * 3.0 / 4.0 * s * s;
    let samples = mesh_area / piece;
    if samples > MAX_SAMPLES {
        let fits = (mesh_area / (MAX_SAMPLES * 3f64.sqrt() * 3.0 / 4.0)).sqrt();
        return Err(OptionError::new(OptionKey::Spacing, format!(
            "$spacing {s:e} would need at least {samples:.1e} samples over the mesh (area {mesh_area:.3e}), more than the limit of {MAX_SAMPLES:.0e}; use $spacing {fits:.3e} or more, or leave it out (default: mesh diagonal / 2000)"
        )));
    }
    Ok(())
}
