//! Clearance on files: obstacles read and checked before a run's sweep, measured against the
//! run's mesh as it is written (`run --against`), or against a mesh already made (`sweptvol
//! clearance`); the maps staged with the other outputs, so a set is published whole.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::report::Report;
use crate::clearance::{
    self, map, verdict_words, ClearanceSection, Guarantee, Obstacle, ObstacleEntry, PosedPart,
    Swept,
};
use crate::error::{InputError, OptionError, OptionKey};
use crate::input::model::Rows;
use crate::io::atomic::{self, Staged};
use crate::io::gltf_in;
use crate::io::gltf_out::{self, MapNode};
use crate::verify::{bvh::Bvh, poses};

/// What a clearance check is asked, beyond the mesh.
#[derive(Clone, Debug, Default)]
pub struct Asked {
    /// Obstacle files: every node with triangles is an obstacle.
    pub against: Vec<PathBuf>,
    /// The least clearance every obstacle must keep, world units.
    pub require: Option<f64>,
    /// The lower end at which the colour ramp reaches green [default: 10 bounds].
    pub scale: Option<f64>,
}

impl Asked {
    /// What a job's options ask.
    pub fn of(job: &crate::job::JobOptions) -> Asked {
        Asked {
            against: job.against.clone(),
            require: job.require_clearance,
            scale: job.clearance_scale,
        }
    }

    /// The options' own checks: a required clearance of at least 0, a positive scale.
    pub fn check(&self) -> Result<(), OptionError> {
        if let Some(x) = self.require {
            if !(x.is_finite() && x >= 0.0) {
                return Err(OptionError::new(
                    OptionKey::RequireClearance,
                    format!(
                        "$require_clearance {x} is not a distance: give 0 or more, in world units"
                    ),
                ));
            }
        }
        if let Some(x) = self.scale {
            if !(x.is_finite() && x > 0.0) {
                return Err(OptionError::new(
                    OptionKey::ClearanceScale,
                    format!("$clearance_scale {x} must be a positive distance (world units) at which the colours reach green"),
                ));
            }
        }
        Ok(())
    }

    /// Every obstacle of every file, per file, read and checked (before any sweeping).
    pub fn read(&self) -> anyhow::Result<Vec<Vec<Obstacle>>> {
        self.check()?;
        let mut out = Vec::new();
        for path in &self.against {
            out.push(clearance::read_obstacles(path)?);
        }
        Ok(out)
    }
}

/// The guarantee a run's report states.
pub fn guarantee_of(report: &Report) -> Guarantee {
    Guarantee {
        clearance: report.mesh.clearance,
        bound: report.mesh.hausdorff_bound,
        everywhere: report.classification.method == "flood",
    }
}

/// The parts at the listed poses of a generator and trajectory, or why they could not be read.
pub fn parts_at_poses(
    generator: &Path,
    trajectory: &Path,
    relative_to: Option<&str>,
    rows: Rows,
    package_dirs: &[PathBuf],
) -> Result<Vec<PosedPart>, String> {
    let (g, traj, _) = super::read_inputs(generator, trajectory, relative_to, rows, package_dirs)
        .map_err(|e| format!("{e:#}"))?;
    let assigned = match traj.rows {
        Rows::World => poses::assign(&g, &traj, trajectory),
        Rows::Local => {
            crate::verify::chain::Rig::new(&g, &traj, trajectory).and_then(|r| r.listed())
        }
    }
    .map_err(|e| e.to_string())?;
    Ok(g.parts
        .iter()
        .zip(assigned)
        .filter(|(p, _)| !p.triangles.is_empty())
        .map(|(part, poses)| PosedPart {
            name: part
                .node_name
                .clone()
                .unwrap_or_else(|| format!("node {}", part.node_index)),
            bvh: Bvh::build(poses::local_triangles(part), 4),
            solid: part.boundary_edges() == 0,
            poses: poses.iter().map(|p| (p.row, p.line, p.matrix)).collect(),
        })
        .collect())
}

/// Measure every obstacle against `swept` (the mesh as written) and stage one map per file.
#[allow(clippy::too_many_arguments)]
pub fn measure_all(
    swept: &Swept,
    g: &Guarantee,
    parts: Result<Vec<PosedPart>, String>,
    files: &[Vec<Obstacle>],
    maps: &[PathBuf],
    asked: &Asked,
    staged: &mut Staged,
) -> anyhow::Result<ClearanceSection> {
    let t0 = Instant::now();
    let (parts, poses_read) = match parts {
        Ok(parts) => {
            let n: usize = parts.iter().map(|p| p.poses.len()).sum();
            (parts, format!("{n} listed poses of the part"))
        }
        Err(e) => {
            tracing::warn!("the part's poses are not read, so no contact can be proven: {e}");
            (Vec::new(), format!("not read: {e}"))
        }
    };
    let scale = asked.scale.unwrap_or(10.0 * g.bound);
    let mut entries = Vec::new();
    for (obstacles, map_path) in files.iter().zip(maps) {
        let mut nodes = Vec::new();
        for o in obstacles {
            let c = clearance::measure(swept, g, &parts, o);
            tracing::info!(
                "{}: {} (clearance in [{}, {}])",
                o.name,
                verdict_words(&c),
                c.lower,
                c.upper.map_or("unknown".into(), |u| u.to_string())
            );
            let lows = map::lower_ends(swept, g, o, c.verdict);
            let f = |p: [f64; 3]| glam::DVec3::from(p).as_vec3().to_array();
            nodes.push(MapNode {
                name: &o.name,
                positions: o.positions.iter().map(|p| p.as_vec3().to_array()).collect(),
                triangles: &o.triangles,
                values: lows.iter().map(|&x| x as f32).collect(),
                colours: lows.iter().map(|&x| map::colour(x, scale)).collect(),
                closest: [f(c.closest.on_obstacle), f(c.closest.on_swept)],
                extras: serde_json::json!({
                    "sweptvol_verdict": c.verdict,
                    "sweptvol_clearance_lower": c.lower,
                    "sweptvol_clearance_upper": c.upper,
                    "sweptvol_clearance_scale": scale,
                }),
            });
            entries.push(ObstacleEntry {
                clearance: c,
                map: map_path.clone(),
            });
        }
        staged.write(map_path, &gltf_out::clearance_glb(&nodes)?)?;
    }
    Ok(ClearanceSection {
        guarantee: *g,
        poses: poses_read,
        scale,
        required: asked.require,
        passes: entries
            .iter()
            .all(|e| clearance::keeps(&e.clearance, asked.require)),
        obstacles: entries,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// What `sweptvol clearance` is asked.
#[derive(Clone, Debug)]
pub struct ClearanceOptions {
    /// The swept-volume mesh (NAME.swept.glb) and its report (NAME.report.json).
    pub mesh: PathBuf,
    pub report: PathBuf,
    pub asked: Asked,
    /// Where the outputs go (default: the mesh's folder).
    pub out_dir: Option<PathBuf>,
    pub overwrite: bool,
}

/// `NAME.clearance.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ClearanceReport {
    pub sweptvol_version: String,
    pub mesh: PathBuf,
    pub report: PathBuf,
    #[serde(flatten)]
    pub clearance: ClearanceSection,
}

fn read_report(path: &Path) -> anyhow::Result<Report> {
    let bytes = std::fs::read(path).map_err(|e| {
        InputError::new(
            path,
            format!("cannot read the report: {e}"),
            "give the NAME.report.json that the run wrote beside the mesh",
        )
    })?;
    serde_json::from_slice(&bytes).map_err(|e| {
        InputError::new(
            path,
            format!("not a sweptvol report (line {}: {e})", e.line()),
            "give the NAME.report.json that the run of this mesh wrote (this sweptvol's)",
        )
        .into()
    })
}

/// The file stem of a swept mesh: `part` of `part.swept.glb`.
fn mesh_stem(mesh: &Path) -> String {
    let name = mesh
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "mesh".into());
    for suffix in [".swept.glb", ".glb", ".gltf"] {
        if let Some(stem) = name.strip_suffix(suffix) {
            return stem.to_string();
        }
    }
    name
}

/// Measure every obstacle against a mesh already made and publish `NAME.clearance.json` and
/// the maps (`NAME.FILE.clearance.glb`, as `run` names them) as one set.
pub fn run(opts: &ClearanceOptions) -> anyhow::Result<ClearanceReport> {
    if opts.asked.against.is_empty() {
        return Err(OptionError::new(
            OptionKey::Against,
            "no obstacle given: name at least one obstacle file with $against",
        )
        .into());
    }
    let report = read_report(&opts.report)?;
    let files = opts.asked.read()?;
    let swept = Swept::new(gltf_in::read_world_triangles(&opts.mesh)?);
    let dir = opts
        .out_dir
        .clone()
        .or_else(|| opts.mesh.parent().map(Path::to_path_buf))
        .unwrap_or_default();
    let stem = mesh_stem(&opts.mesh);
    let maps = super::outputs::clearance_map_paths(&dir, &stem, None, &opts.asked.against)?;
    let json_path = dir.join(format!("{stem}.clearance.json"));
    if !opts.overwrite {
        if let Some(p) = std::iter::once(&json_path)
            .chain(&maps)
            .find(|p| p.exists())
        {
            return Err(InputError::new(
                p,
                "an output of an earlier clearance check is here",
                "pass $overwrite to replace it, or give another output folder",
            )
            .into());
        }
    }
    std::fs::create_dir_all(&dir).map_err(|e| {
        InputError::new(
            &dir,
            format!("cannot create the output folder: {e}"),
            "check the folder",
        )
    })?;
    let mut staged = atomic::Staged::with_marker(dir.join(format!(".{stem}.clearance.incomplete")));
    let g = guarantee_of(&report);
    let parts = parts_at_poses(
        &report.inputs.generator,
        &report.inputs.trajectory,
        report.inputs.relative_to.as_deref(),
        report.inputs.rows,
        &report.inputs.package_dir,
    );
    let section = measure_all(&swept, &g, parts, &files, &maps, &opts.asked, &mut staged)?;
    let out = ClearanceReport {
        sweptvol_version: env!("CARGO_PKG_VERSION").into(),
        mesh: opts.mesh.clone(),
        report: opts.report.clone(),
        clearance: section,
    };
    staged.write(&json_path, &serde_json::to_vec_pretty(&out)?)?;
    staged.commit()?;
    Ok(out)
}
