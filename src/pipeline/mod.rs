//! One job from input files to output files: the API the CLI and the watcher share.
//! Inputs are read and checked completely before anything is written; outputs are written
//! under temporary names and renamed into place, and existing ones are kept unless asked.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context};

pub mod clearance;
mod outputs;
mod report;
pub mod shard;

pub use outputs::{
    output_paths, output_stem, OutputPaths, CLEARANCE_SUFFIX, MESH_SUFFIX, REPORT_SUFFIX,
    START_MESH_SUFFIX,
};
pub use report::{
    ClassificationReport, CountsReport, DepthImagesReport, InputsReport, MeshReport,
    ParametersReport, Report, TimingsReport,
};

use outputs::refuse_outputs_on_inputs;
use report::{HAUSDORFF_SCOPE, HAUSDORFF_SCOPE_FLOOD};

use crate::depth::DepthImages;
use crate::depth::AXIS_NAMES;
use crate::error::{OptionError, OptionKey};
use crate::input::grid::{Accuracy, Overrides};
use crate::input::model::Rows;
use crate::input::posed::{self, SweepInput};
use crate::io::exr_depth::{self, ExtraMeta};
use crate::io::{atomic, gltf_in, gltf_out, trajectory};
use crate::job::{JobFile, JobOptions};
use crate::mesh::classify::Method;
use crate::mesh::Mesh;
use crate::simplify::SimplifyOptions;
use crate::sweep::backend::{Backend, BackendChoice};
use crate::sweep::{Cancelled, Observer};
use crate::voxels::VoxelBits;

/// What `sweptvol run` was asked to do.
#[derive(Clone, Debug)]
pub struct RunOptions {
    pub generator: PathBuf,
    pub trajectory: PathBuf,
    pub out_dir: PathBuf,
    /// The job's options, with the accuracy spelled out (`of_job` fills in the default).
    /// `job.name` is the output stem: the trajectory's when None; empty, bare names
    /// (`depth-xmin.exr`, `report.json`) as inside a watched job folder. `job.backend` is not
    /// read here: the caller settles the backend.
    pub job: JobOptions,
    pub overwrite: bool,
    /// Refuse a run whose estimated memory (`memory::estimate`) exceeds what is available.
    pub check_memory: bool,
}

impl RunOptions {
    /// The run of `job`: `generator` along `trajectory`, outputs into `out_dir`, with
    /// `default_accuracy` where the job gives neither resolution nor tolerance. It replaces no
    /// output and checks its memory estimate until told otherwise.
    pub fn of_job(
        job: &JobOptions,
        generator: PathBuf,
        trajectory: PathBuf,
        out_dir: PathBuf,
        default_accuracy: Accuracy,
    ) -> RunOptions {
        let mut job = job.clone();
        match Accuracy::choose(job.resolution, job.tolerance, default_accuracy) {
            Accuracy::Resolution(n) => (job.resolution, job.tolerance) = (Some(n), None),
            Accuracy::Tolerance(t) => (job.resolution, job.tolerance) = (None, Some(t)),
        }
        RunOptions {
            generator,
            trajectory,
            out_dir,
            job,
            overwrite: false,
            check_memory: true,
        }
    }

    /// The voxel size's setting: the resolution or the tolerance the job gives.
    pub fn accuracy(&self) -> Accuracy {
        Accuracy::choose(self.job.resolution, self.job.tolerance, Accuracy::DEFAULT)
    }

    /// δ and ε as the job gives them, or by its radii.
    pub fn overrides(&self) -> Overrides {
        Overrides {
            delta: self.job.delta,
            epsilon: self.job.epsilon,
            radii: self.job.radii,
        }
    }

    /// The job's options with `backend`: what a job file or a shard manifest records.
    pub fn job_options(&self, backend: Option<BackendChoice>) -> JobOptions {
        JobOptions {
            backend,
            ..self.job.clone()
        }
    }

    /// The run a job file describes (it writes to the file's shard folder).
    pub fn of_job_file(file: &JobFile) -> RunOptions {
        let mut run = RunOptions::of_job(
            &file.options,
            file.generator.clone(),
            file.trajectory.clone(),
            file.out.clone(),
            Accuracy::DEFAULT,
        );
        run.check_memory = !file.no_memory_check;
        run
    }
}

/// The classification chosen for a job, and why (from `RunOptions::classify` and whether every
/// part of the generator is closed).
#[derive(Clone, Debug)]
pub struct ClassifyPlan {
    pub flood: bool,
    pub reason: String,
}

impl ClassifyPlan {
    fn new(asked: Method, generator: &crate::input::model::Generator) -> Self {
        let open: Vec<String> = generator
            .parts
            .iter()
            .filter_map(|p| {
                let edges = p.boundary_edges();
                (edges > 0).then(|| {
                    let name = p
                        .node_name
                        .clone()
                        .unwrap_or_else(|| format!("node {}", p.node_index));
                    format!("{name:?} ({edges} boundary edges)")
                })
            })
            .collect();
        let open_text = |n: usize| {
            let more = if open.len() > n {
                format!(" and {} more", open.len() - n)
            } else {
                String::new()
            };
            format!("{}{more}", open[..open.len().min(n)].join(", "))
        };
        let (flood, reason) = match asked {
            Method::Axes => (false, "asked for ($classify axes): condition ⋆ alone".to_string()),
            Method::Flood if open.is_empty() => (true, "asked for ($classify flood); every part is closed".to_string()),
            Method::Flood => (true, format!("asked for ($classify flood); open parts: {}: where the flood enters one through a hole, the result is a shell around its surface", open_text(3))),
            Method::Auto if open.is_empty() => (true, "every part is closed, so the flood from outside cannot enter a part ($classify auto)".to_string()),
            Method::Auto => (false, format!("open parts: {}: a flood could enter them, so condition ⋆ alone ($classify auto); $classify flood carves hidden pockets anyway", open_text(3))),
        };
        // report.json is read by every shell's users: the options in its plain words.
        let reason = crate::error::plain(&reason);
        ClassifyPlan { flood, reason }
    }
}

/// A job whose inputs are read and checked and whose sweep input is built: everything that can
/// fail because of the user's files has failed by now, and nothing has been written.
pub struct Prepared {
    pub opts: RunOptions,
    pub outputs: OutputPaths,
    pub input: SweepInput,
    /// The simplifier's radii, worked out (and checked) before any sweeping.
    pub band: SimplifyOptions,
    pub classify: ClassifyPlan,
    pub warnings: Vec<String>,
    /// With `relative_to`: the reference part, in its own frame (the frame of the outputs).
    pub reference: Option<crate::input::model::Part>,
    /// The obstacles of each `against` file, read and checked before the sweep (empty in a
    /// shard, which measures nothing).
    pub obstacles: Vec<Vec<crate::clearance::Obstacle>>,
    read_secs: f64,
    setup_secs: f64,
}

/// Read and check the inputs and build the sweep input. Writes nothing.
pub fn prepare(opts: &RunOptions) -> anyhow::Result<Prepared> {
    let outputs = output_paths(opts)?;
    refuse_outputs_on_inputs(opts, &outputs.all())?;
    if !opts.overwrite {
        // Files of a set whose publishing a crash cut off are no complete output: replaced.
        let interrupted = atomic::interrupted_set(&outputs.marker);
        if let Some(existing) = outputs
            .with_stale()
            .iter()
            .find(|p| p.exists() && !interrupted.contains(p))
        {
            return Err(OptionError::new(
                OptionKey::Overwrite,
                format!(
                    "{} already exists; pass $overwrite to replace the outputs, or choose another $out or $name",
                    existing.display()
                ),
            )
            .into());
        }
    }
    // A folder the outputs cannot be written to is found before the sweep, not after it.
    atomic::probe_writable(&opts.out_dir).map_err(|why| {
        OptionError::new(
            OptionKey::Out,
            format!(
                "$out {}: {why}; nothing was written: choose another $out, or make it writable",
                opts.out_dir.display()
            ),
        )
    })?;
    let mut job = build(opts, outputs)?;
    // Obstacles are inputs too: a bad one is refused before the sweep. The reference of a
    // relative motion is the first, where the outputs are: in its own frame.
    if let Some(part) = &job.reference {
        let own = crate::input::model::Generator {
            parts: vec![crate::input::model::Part {
                world: glam::DMat4::IDENTITY,
                ..part.clone()
            }],
            ..Default::default()
        };
        job.obstacles
            .push(crate::clearance::obstacles_of(&opts.generator, &own)?);
    }
    job.obstacles
        .extend(clearance::Asked::of(&opts.job).read()?);
    Ok(job)
}

/// The generator and trajectory as the sweep takes them: rows read as `rows` says; with
/// `relative_to`, the other parts in the reference node's frame, and the reference part itself
/// ([`crate::input::relative`]).
pub fn read_inputs(
    generator: &std::path::Path,
    trajectory: &std::path::Path,
    relative_to: Option<&str>,
    rows: Rows,
    package_dirs: &[PathBuf],
) -> anyhow::Result<(
    crate::input::model::Generator,
    crate::input::model::Trajectory,
    Option<crate::input::model::Part>,
)> {
    if rows == Rows::Local && relative_to.is_some() {
        return Err(OptionError::new(
            OptionKey::RelativeTo,
            "$relative_to takes world-space rows; with $rows local give the reference's motion in the hierarchy instead (make the part a child of the reference node)",
        )
        .into());
    }
    let robot = crate::io::urdf::is_robot(generator);
    if robot && relative_to.is_some() {
        return Err(OptionError::new(
            OptionKey::RelativeTo,
            "$relative_to takes world-space rows, and a robot's joint rows are in parent space",
        )
        .into());
    }
    let (g, t) = if robot {
        crate::io::urdf::read_inputs(generator, trajectory, package_dirs)?
    } else {
        let mut t = trajectory::read_trajectory(trajectory)?;
        t.rows = rows;
        (gltf_in::read_generator(generator)?, t)
    };
    match relative_to {
        None => Ok((g, t, None)),
        Some(node) => {
            let (g, t, reference) = crate::input::relative::apply(&g, &t, trajectory, node)?;
            Ok((g, t, Some(reference)))
        }
    }
}

/// [`prepare`] without looking at the outputs (a shard writes its own files).
fn build(opts: &RunOptions, outputs: OutputPaths) -> anyhow::Result<Prepared> {
    let t0 = Instant::now();
    let (generator, traj, reference) = read_inputs(
        &opts.generator,
        &opts.trajectory,
        opts.job.relative_to.as_deref(),
        opts.job.rows,
        &opts.job.package_dir,
    )?;
    for w in &generator.warnings {
        tracing::warn!("{}: {w}", opts.generator.display());
    }
    let t1 = Instant::now();
    let input = posed::build(
        &generator,
        &opts.generator,
        &traj,
        &opts.trajectory,
        opts.accuracy(),
        opts.overrides(),
        opts.job.motion,
    )?;
    let band = SimplifyOptions::for_params(
        &input.params,
        input.grid.h,
        opts.job.target_triangles.unwrap_or(0),
    )?;
    let classify = ClassifyPlan::new(opts.job.classify, &generator);
    if opts.check_memory {
        crate::input::memory::check(
            &input.grid,
            opts.job.keep_start_mesh,
            classify.flood,
            crate::input::memory::available(),
            opts.job.radii.k_tolerance() + input.motion.mu / input.grid.h,
        )?;
    }
    Ok(Prepared {
        opts: opts.clone(),
        outputs,
        input,
        band,
        classify,
        warnings: generator.warnings,
        reference,
        obstacles: Vec::new(),
        read_secs: (t1 - t0).as_secs_f64(),
        setup_secs: t1.elapsed().as_secs_f64(),
    })
}

/// What the sweep hands the mesh stage: the six depth images, the offset's reach where the
/// classification floods, and where and how long the sweep ran. One machine's sweep
/// ([`sweep`]) or the merge of a job's shards (`shard::merge`) give the same images.
pub struct Swept {
    pub images: DepthImages,
    pub reach: Option<VoxelBits>,
    /// The backend's description (`Backend::describe`), or the shards' backends.
    pub backend: String,
    /// Seconds of sweeping (over all shards for a merge).
    pub seconds: f64,
}

/// Sweep a prepared job and write its outputs: [`sweep`] then [`finish`].
pub fn execute(
    job: &Prepared,
    backend: &Backend,
    observer: &dyn Observer,
) -> anyhow::Result<Report> {
    let swept = sweep(job, backend, observer)?;
    finish(job, swept, observer)
}

/// Render every posed triangle of `job.input` (all of the job's poses, or one shard's share)
/// into the depth images, and the reach where the job floods.
pub fn sweep(job: &Prepared, backend: &Backend, observer: &dyn Observer) -> anyhow::Result<Swept> {
    let input = &job.input;
    let t0 = Instant::now();
    tracing::info!(
        "grid {}x{}x{} voxels of {:.6} (n = {}); {} posed triangles on {}",
        input.grid.dims[0],
        input.grid.dims[1],
        input.grid.dims[2],
        input.grid.h,
        input.grid.resolution(),
        input.posed_triangles(),
        backend.describe()
    );
    checkpoint(observer, "sweep")?;
    observer.begin(crate::sweep::total_poses(input), input.posed_triangles());
    // With the flood classification the sweep also sets the offset's reach (its x rays).
    let (images, reach) = if job.classify.flood {
        let (images, reach) = backend.sweep_with_reach(input, observer)?;
        (images, Some(reach))
    } else {
        (backend.sweep(input, observer)?, None)
    };
    Ok(Swept {
        images,
        reach,
        backend: backend.describe(),
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// Classify, extract, simplify and write the outputs of a job whose images are swept.
pub fn finish(job: &Prepared, swept: Swept, observer: &dyn Observer) -> anyhow::Result<Report> {
    let (opts, input) = (&job.opts, &job.input);
    let t_sweep = Instant::now();
    let Swept {
        images,
        reach,
        backend,
        seconds: sweep_secs,
    } = swept;

    checkpoint(observer, "classify")?;
    tracing::info!("classifying voxels, simplifying the boundary block by block");
    let h = input.grid.h;
    let band = job.band;
    if reach.is_some() {
        tracing::info!("flooding from outside: {}", job.classify.reason);
    }
    let params = crate::surface::Params {
        keep_start_mesh: opts.job.keep_start_mesh,
        ..crate::surface::Params::new(band)
    };
    let pieces = crate::simplify::pieces::Pieces::of(input);
    if pieces.is_none() {
        tracing::info!(
            "more than {} pieces of the swept volume (parts' components times rows): the sweep check takes the region tests",
            crate::simplify::pieces::MAX_PIECES
        );
    }
    let surface = crate::surface::build(&images, reach, pieces.as_ref(), &params, &|| {
        observer.cancelled()
    })
    .ok_or(Cancelled)?;
    let classification = ClassificationReport {
        method: if job.classify.flood {
            Method::Flood
        } else {
            Method::Axes
        }
        .name()
        .into(),
        asked: opts.job.classify.name().into(),
        reason: job.classify.reason.clone(),
        reach_voxels: surface.reach_voxels,
        flooded_voxels: surface.flooded_voxels,
        flood_seconds: surface.flood_seconds,
    };
    let triangles_start = surface.triangles_start;
    let start_glb = match &surface.start_mesh {
        Some(start) => {
            let name = format!("{} voxel boundary", output_stem(opts)?);
            let extras = serde_json::json!({"sweptvol_version": env!("CARGO_PKG_VERSION"), "triangles": triangles_start});
            Some(gltf_out::glb_bytes(start, &input.grid, &name, extras)?)
        }
        None => None,
    };
    let (joined_voxels, join_reach) = (surface.joined_voxels, surface.joined_reach);
    let (mesh, simplify_stats) = (surface.mesh, surface.stats);
    let carved = surface.carved;
    let t_extract = t_sweep + std::time::Duration::from_secs_f64(surface.classify_seconds);
    // Checked on the f32 world positions the files hold: rounding could merge vertices.
    let (written, output_rounding) = gltf_out::world_positions(&mesh, &input.grid);
    let manifold = Mesh {
        positions: written
            .iter()
            .map(|p| glam::Vec3::from(*p).as_dvec3())
            .collect(),
        triangles: mesh.triangles.clone(),
    }
    .manifold_defects();
    drop(written);
    let mut warnings = job.warnings.clone();
    if !manifold.is_manifold() {
        // An invariant of the simplifier on a manifold start mesh: report it, never hide it.
        let w = format!("internal error: the output mesh is not a 2-manifold ({manifold:?}); it is still conservative; please report this input");
        tracing::warn!("{w}");
        warnings.push(w);
    }
    // The mesh keeps a clearance of δ - √3h/2 - ε (about 0.71h at the defaults) from the swept
    // volume; f32 output must not spend a noticeable part of it.
    if output_rounding > 0.01 * input.grid.h {
        bail!(
            "writing the mesh as f32 would move vertices by {output_rounding:e}, more than 1% of the voxel size {}; the part sits too far from the world origin for its size: move it nearer the origin",
            input.grid.h
        );
    }
    let t_mesh = Instant::now();

    checkpoint(observer, "write")?;
    let mu = input.motion.mu;
    let extra = ExtraMeta {
        // The offset radius the images hold (before rounding): δ + μ.
        delta: input.params.delta + mu,
        rounding: input.rounding * h,
    };
    std::fs::create_dir_all(&opts.out_dir).with_context(|| {
        format!(
            "could not create the output folder {}",
            opts.out_dir.display()
        )
    })?;
    let stem = output_stem(opts)?;
    // What a publish cut off by a crash left (outputs, temporary files, the marker) goes first.
    let cleared = atomic::clear_interrupted(&job.outputs.marker)?;
    if !cleared.is_empty() {
        tracing::warn!(
            "{} files of an earlier run whose publishing was cut off were removed from {}",
            cleared.len(),
            opts.out_dir.display()
        );
    }
    // Every output is staged under a temporary name and all are renamed together at the end,
    // under a marker: an error leaves nothing behind and never mixes old and new outputs, and a
    // crash between renames leaves the marker for the next run.
    let mut staged = atomic::Staged::with_marker(job.outputs.marker.clone());
    for old in &job.outputs.stale {
        staged.retire(old);
    }
    let files = exr_depth::stage_all(&mut staged, &opts.out_dir, &stem, &images, &extra)?;
    debug_assert_eq!(files, job.outputs.depth);
    let secs = |a: Instant, b: Instant| (b - a).as_secs_f64();
    let mesh_report = MeshReport {
        file: job.outputs.mesh.clone(),
        triangles_start,
        triangles_final: mesh.triangles.len() as u64,
        vertices: mesh.positions.len() as u64,
        simplified: true,
        simplification: simplify_stats,
        volume: mesh.volume() * h * h * h,
        manifold: manifold.is_manifold(),
        manifold_defects: manifold,
        joined_voxels,
        joined_voxel_reach: join_reach * h,
        // A mesh point lies in the tolerance volume (a new triangle: within `inside` of an
        // inside voxel's centre), or on a face of an inside voxel: √3h/2 from an original
        // voxel's centre, or `join_reach` from one for a joined voxel. Each such centre is
        // within δ + μ + 2ρ of a rendered pose, and every rendered pose (a row or a sub-pose)
        // is a pose of the motion.
        hausdorff_bound: band.tolerance.inside.max(join_reach) * h
            + input.params.delta
            + mu
            + 2.0 * input.rounding * h
            + output_rounding,
        hausdorff_bound_scope: if carved {
            HAUSDORFF_SCOPE_FLOOD
        } else {
            HAUSDORFF_SCOPE
        }
        .into(),
        // Every mesh point is within `outside` of an outside voxel's centre, which is farther
        // than δ from every rendered pose.
        clearance: input.params.delta - band.tolerance.outside * h - output_rounding,
        output_rounding,
    };
    let extras = serde_json::json!({
        "sweptvol_version": env!("CARGO_PKG_VERSION"),
        "hausdorff_bound": mesh_report.hausdorff_bound,
        "clearance": mesh_report.clearance,
        "voxel_size": h,
        "triangles_start": mesh_report.triangles_start,
        "triangles_final": mesh_report.triangles_final,
    });
    let glb = gltf_out::glb_bytes(
        &mesh,
        &input.grid,
        format!("{stem} swept volume").trim_start(),
        extras,
    )?;
    staged.write(&job.outputs.mesh, &glb)?;
    if let (Some(start_glb), Some(path)) = (start_glb, &job.outputs.start_mesh) {
        staged.write(path, &start_glb)?;
    }
    for (f, path) in &job.outputs.also {
        let name = format!("{stem} swept volume");
        staged.write(path, &f.bytes(&mesh, &input.grid, name.trim_start()))?;
    }
    let clearance = if job.obstacles.is_empty() {
        None
    } else {
        checkpoint(observer, "clearance")?;
        // The mesh as the file holds it (f32 world positions).
        let (world, _) = gltf_out::world_positions(&mesh, &input.grid);
        let tris = mesh
            .triangles
            .iter()
            .map(|t| t.map(|i| glam::Vec3::from(world[i as usize]).as_dvec3()))
            .collect();
        let g = crate::clearance::Guarantee {
            clearance: mesh_report.clearance,
            bound: mesh_report.hausdorff_bound,
            everywhere: carved,
        };
        Some(clearance::measure_all(
            &crate::clearance::Swept::new(tris),
            &g,
            clearance::parts_at_poses(
                &opts.generator,
                &opts.trajectory,
                opts.job.relative_to.as_deref(),
                opts.job.rows,
                &opts.job.package_dir,
            ),
            &job.obstacles,
            &job.outputs.clearance_maps,
            &clearance::Asked::of(&opts.job),
            &mut staged,
        )?)
    };
    let t_write = Instant::now();

    let report = Report {
        sweptvol_version: env!("CARGO_PKG_VERSION").into(),
        inputs: InputsReport {
            generator: opts.generator.clone(),
            trajectory: opts.trajectory.clone(),
            relative_to: opts.job.relative_to.clone(),
            rows: if crate::io::urdf::is_robot(&opts.generator) {
                Rows::Local
            } else {
                opts.job.rows
            },
            package_dir: opts.job.package_dir.clone(),
            static_parts: input
                .parts
                .iter()
                .filter(|p| p.is_static)
                .map(|p| p.name.clone())
                .collect(),
            parts: input.parts.clone(),
        },
        grid: input.grid,
        resolution: input.grid.resolution(),
        parameters: ParametersReport {
            radii: opts.job.radii,
            voxel_size: h,
            delta: input.params.delta,
            epsilon: input.params.epsilon,
            sigma: input.params.sigma,
            rounding: input.rounding * h,
            delta_rendered: input.params.delta + mu + input.rounding * h,
            delta_upper: input.params.delta + mu + 2.0 * input.rounding * h,
            epsilon_global: input.params.epsilon + input.params.delta + input.params.sigma + mu,
            tolerance_radius: band.tolerance.outside * h,
            sweep_radius: band.sweep * h,
        },
        motion: input.motion.clone(),
        classification,
        backend,
        counts: CountsReport {
            triangles: input.triangles.len() as u64,
            poses: crate::sweep::total_poses(input),
            posed_triangles: input.posed_triangles(),
            hit_pixels: images.images.clone().map(|i| i.hit_count() as u64),
        },
        timings: TimingsReport {
            read_inputs: job.read_secs,
            setup: job.setup_secs,
            sweep: sweep_secs,
            mesh: secs(t_sweep, t_extract),
            simplify: secs(t_extract, t_mesh),
            write_outputs: secs(t_mesh, t_write),
            total: job.read_secs + job.setup_secs + sweep_secs + secs(t_sweep, Instant::now()),
            posed_triangles_per_second: input.posed_triangles() as f64 / sweep_secs.max(1e-9),
        },
        outputs: job.outputs.all(),
        depth_images: DepthImagesReport {
            layout: format!(
                "one EXR per axis and side; channel Z = world distance from the camera plane (the grid face the image is named after) along the view direction, rounded toward the camera; channel Y = 1 - Z / grid extent for viewers; columns along {} and rows (top first) along {} for axes x, y, z",
                crate::depth::COLUMN_AXIS.map(|a| AXIS_NAMES[a]).join("/"),
                crate::depth::ROW_AXIS.map(|a| AXIS_NAMES[a]).join("/")
            ),
            empty_pixels: "Z = +inf, Y = 0 (no offset on that ray)".into(),
            files,
        },
        mesh: mesh_report,
        clearance,
        warnings,
    };
    let json = serde_json::to_vec_pretty(&report)?;
    staged.write(&job.outputs.report, &json)?;
    if !opts.overwrite {
        // Checked again: a long sweep gives another process time to write the same names.
        if let Some(existing) = job.outputs.with_stale().iter().find(|p| p.exists()) {
            return Err(OptionError::new(
                OptionKey::Overwrite,
                format!(
                    "{} appeared while sweeping; nothing was written (pass $overwrite to replace it)",
                    existing.display()
                ),
            )
            .into());
        }
    }
    // Last chance to stop: dropping `staged` removes every temporary file.
    if observer.cancelled() {
        return Err(Cancelled.into());
    }
    staged.commit()?;
    Ok(report)
}

/// Between stages: stop if the observer asks to, else announce the next stage. Inside a stage
/// only the sweep checks; a cancel waits at most for the stage in progress to end.
fn checkpoint(observer: &dyn Observer, stage: &'static str) -> anyhow::Result<()> {
    if observer.cancelled() {
        return Err(Cancelled.into());
    }
    observer.stage(stage);
    Ok(())
}
