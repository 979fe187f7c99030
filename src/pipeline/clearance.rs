//! `sweptvol clearance`: the clearance of obstacles from a swept-volume mesh already made,
//! files in to files out: the mesh, its report (the guarantee, and the inputs whose listed
//! poses can prove a contact) and obstacle files in; `NAME.clearance.json` and one clearance
//! map per obstacle out, published as one set.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::report::Report;
use crate::clearance::{self, map, Guarantee, Obstacle, ObstacleClearance, PosedPart, Swept};
use crate::error::{InputError, OptionError, OptionKey};
use crate::io::{atomic, gltf_in, gltf_out, trajectory};
use crate::verify::poses;

/// What `clearance` is asked.
#[derive(Clone, Debug)]
pub struct ClearanceOptions {
    /// The swept-volume mesh (NAME.swept.glb) and its report (NAME.report.json).
    pub mesh: PathBuf,
    pub report: PathBuf,
    /// Obstacle files: every node with triangles is an obstacle.
    pub against: Vec<PathBuf>,
    /// Where the outputs go (default: the mesh's folder).
    pub out_dir: Option<PathBuf>,
    /// The lower end, world units, at which the colour ramp reaches green (default 10 bounds).
    pub scale: Option<f64>,
    /// The least clearance every obstacle must keep, world units.
    pub require: Option<f64>,
    pub overwrite: bool,
}

/// `NAME.clearance.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ClearanceReport {
    pub sweptvol_version: String,
    pub mesh: PathBuf,
    pub report: PathBuf,
    pub guarantee: Guarantee,
    /// How the listed poses were read, or why not.
    pub poses: String,
    /// The colour ramp's green end, world units.
    pub scale: f64,
    pub required: Option<f64>,
    /// Every obstacle keeps `required` (a certain contact never does); true when none is
    /// required.
    pub passes: bool,
    pub obstacles: Vec<ObstacleEntry>,
    pub seconds: f64,
}

/// One obstacle's clearance and its map file.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ObstacleEntry {
    #[serde(flatten)]
    pub clearance: ObstacleClearance,
    pub map: PathBuf,
}

/// The guarantee a run's report states.
pub fn guarantee_of(report: &Report) -> Guarantee {
    Guarantee {
        clearance: report.mesh.clearance,
        bound: report.mesh.hausdorff_bound,
        everywhere: report.classification.method == "flood",
    }
}

/// Whether an obstacle keeps `required`: its lower end is at least that, and no certain contact.
pub fn keeps(c: &ObstacleClearance, required: Option<f64>) -> bool {
    required.is_none_or(|x| c.lower >= x && c.verdict != clearance::Verdict::Contact)
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

/// The parts at the report's listed poses, or why they could not be read.
fn posed_parts(report: &Report) -> Result<Vec<PosedPart>, String> {
    let generator = gltf_in::read_generator(&report.inputs.generator).map_err(|e| e.to_string())?;
    let traj = trajectory::read_trajectory(&report.inputs.trajectory).map_err(|e| e.to_string())?;
    let assigned =
        poses::assign(&generator, &traj, &report.inputs.trajectory).map_err(|e| e.to_string())?;
    Ok(generator
        .parts
        .iter()
        .zip(assigned)
        .filter(|(p, _)| !p.triangles.is_empty())
        .map(|(part, poses)| PosedPart {
            name: part
                .node_name
                .clone()
                .unwrap_or_else(|| format!("node {}", part.node_index)),
            bvh: crate::verify::bvh::Bvh::build(poses::local_triangles(part), 4),
            solid: part.boundary_edges() == 0,
            poses: poses.iter().map(|p| (p.row, p.line, p.matrix)).collect(),
        })
        .collect())
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

/// An obstacle's name as a file-name piece: letters, digits, `-`, `_`; others become `_`.
fn file_piece(name: &str) -> String {
    let s: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if s.is_empty() {
        "obstacle".into()
    } else {
        s
    }
}

/// The options' own checks: obstacles given, a required clearance of at least 0, a positive
/// scale.
pub fn check_options(opts: &ClearanceOptions) -> Result<(), OptionError> {
    if opts.against.is_empty() {
        return Err(OptionError::new(
            OptionKey::Against,
            "no obstacle given: name at least one obstacle file with $against",
        ));
    }
    if let Some(x) = opts.require {
        if !(x.is_finite() && x >= 0.0) {
            return Err(OptionError::new(
                OptionKey::RequireClearance,
                format!("$require_clearance {x} is not a distance: give 0 or more, in the mesh's world units"),
            ));
        }
    }
    if let Some(x) = opts.scale {
        if !(x.is_finite() && x > 0.0) {
            return Err(OptionError::new(
                OptionKey::ClearanceScale,
                format!("$clearance_scale {x} must be a positive distance (world units) at which the colours reach green"),
            ));
        }
    }
    Ok(())
}

/// Measure every obstacle and publish the report and the maps.
pub fn run(opts: &ClearanceOptions) -> anyhow::Result<ClearanceReport> {
    let t0 = Instant::now();
    check_options(opts)?;
    let report = read_report(&opts.report)?;
    let g = guarantee_of(&report);
    let tris = gltf_in::read_world_triangles(&opts.mesh)?;
    let swept = Swept::new(tris);
    let mut obstacles: Vec<Obstacle> = Vec::new();
    for path in &opts.against {
        obstacles.extend(clearance::read_obstacles(path)?);
    }
    let (parts, poses_read) = match posed_parts(&report) {
        Ok(parts) => {
            let n: usize = parts.iter().map(|p| p.poses.len()).sum();
            (parts, format!("{n} listed poses of the report's inputs"))
        }
        Err(e) => {
            tracing::warn!("the part's poses are not read, so no contact can be proven: {e}");
            (Vec::new(), format!("not read: {e}"))
        }
    };
    let scale = opts.scale.unwrap_or(10.0 * g.bound);
    let dir = opts
        .out_dir
        .clone()
        .or_else(|| opts.mesh.parent().map(Path::to_path_buf))
        .unwrap_or_default();
    let stem = mesh_stem(&opts.mesh);
    let json_path = dir.join(format!("{stem}.clearance.json"));
    let mut used: Vec<String> = Vec::new();
    let mut map_paths = Vec::new();
    for o in &obstacles {
        let mut piece = file_piece(&o.name);
        let base = piece.clone();
        let mut k = 2;
        while used.contains(&piece) {
            piece = format!("{base}-{k}");
            k += 1;
        }
        used.push(piece.clone());
        map_paths.push(dir.join(format!("{stem}.{piece}.clearance.glb")));
    }
    if !opts.overwrite {
        if let Some(p) = std::iter::once(&json_path)
            .chain(&map_paths)
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
    let mut entries = Vec::new();
    for (o, map_path) in obstacles.iter().zip(map_paths) {
        let c = clearance::measure(&swept, &g, &parts, o);
        tracing::info!(
            "{}: {} (clearance in [{}, {}])",
            o.name,
            verdict_words(&c),
            c.lower,
            c.upper.map_or("unknown".into(), |u| u.to_string())
        );
        let lows = map::lower_ends(&swept, &g, o, c.verdict);
        let f32s = |v: &[glam::DVec3]| -> Vec<[f32; 3]> {
            v.iter().map(|p| p.as_vec3().to_array()).collect()
        };
        let values: Vec<f32> = lows.iter().map(|&x| x as f32).collect();
        let colours: Vec<[f32; 3]> = lows.iter().map(|&x| map::colour(x, scale)).collect();
        let closest = [
            glam::DVec3::from(c.closest.on_obstacle)
                .as_vec3()
                .to_array(),
            glam::DVec3::from(c.closest.on_swept).as_vec3().to_array(),
        ];
        let extras = serde_json::json!({
            "sweptvol_verdict": c.verdict,
            "sweptvol_clearance_lower": c.lower,
            "sweptvol_clearance_upper": c.upper,
            "sweptvol_clearance_scale": scale,
        });
        let bytes = gltf_out::clearance_glb(
            &o.name,
            &f32s(&o.positions),
            &o.triangles,
            &values,
            &colours,
            closest,
            extras,
        )?;
        staged.write(&map_path, &bytes)?;
        entries.push(ObstacleEntry {
            clearance: c,
            map: map_path,
        });
    }
    let passes = entries.iter().all(|e| keeps(&e.clearance, opts.require));
    let out = ClearanceReport {
        sweptvol_version: env!("CARGO_PKG_VERSION").into(),
        mesh: opts.mesh.clone(),
        report: opts.report.clone(),
        guarantee: g,
        poses: poses_read,
        scale,
        required: opts.require,
        passes,
        obstacles: entries,
        seconds: t0.elapsed().as_secs_f64(),
    };
    staged.write(&json_path, &serde_json::to_vec_pretty(&out)?)?;
    staged.commit()?;
    Ok(out)
}

/// The verdict in words for logs and summaries.
pub fn verdict_words(c: &ObstacleClearance) -> String {
    match (&c.verdict, &c.witness) {
        (clearance::Verdict::Contact, Some(w)) => format!(
            "CONTACT: {} {} at {}",
            w.part,
            w.how,
            w.line.map_or("its place".into(), |l| format!("line {l}"))
        ),
        (clearance::Verdict::PossibleContact, _) => {
            "possible contact: the obstacle meets the swept-volume mesh".into()
        }
        _ => "clear".into(),
    }
}
