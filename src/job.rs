//! The job's options as one typed value, spelled once: [`JobOptions`] *is* job.json's schema
//! (serde: unknown keys refused, defaults for what is left out) and the command line's options
//! (clap flattens it into `run`, `sweep` and `cluster submit`). `pipeline::RunOptions::of_job`
//! turns it, with the inputs and where the outputs go, into the run; every shell (command
//! line, watcher, shard manifests) goes through it.
//!
//! Adding an option: a field here with its help text (which clap shows) and, where a message
//! must name it, an [`OptionKey`] of the same name (a test holds them together).

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::error::OptionKey;
use crate::input::grid::Radii;
use crate::input::model::Rows;
use crate::input::motion::Motion;
use crate::mesh::classify::Method;
use crate::sweep::backend::BackendChoice;

/// What a job asks for beyond its inputs and its output folder.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, clap::Args)]
#[serde(deny_unknown_fields, default)]
pub struct JobOptions {
    /// Voxels along the longest edge of the grid [default: 256 unless --tolerance is given].
    #[arg(long, value_name = "N", conflicts_with = "tolerance")]
    pub resolution: Option<u32>,
    /// The stated Hausdorff bound in world units; sets the voxel size h = t/(k + μ/h): k = 3.29
    /// with the exact radii, 4.88 with the paper's; μ/h = ¼ for screw motion, 0 for discrete.
    #[arg(long, value_name = "T", allow_negative_numbers = true)]
    pub tolerance: Option<f64>,
    /// Offset radius δ in world units [default: by --radii].
    #[arg(long, value_name = "D", allow_negative_numbers = true)]
    pub delta: Option<f64>,
    /// Simplification tolerance ε in world units [default: by --radii].
    #[arg(long, value_name = "E", allow_negative_numbers = true)]
    pub epsilon: Option<f64>,
    /// Where the sweep runs: auto takes a hardware GPU if present, else the CPU [default: auto;
    /// in job.json: the daemon's].
    #[arg(long, value_enum)]
    pub backend: Option<BackendChoice>,
    /// Output file stem [default: the trajectory's file stem].
    #[arg(long, value_parser = file_stem)]
    pub name: Option<String>,
    /// Stop simplifying at this many triangles (the error bound always wins) [default: as far as
    /// the bound allows].
    #[arg(long, value_name = "N")]
    pub target_triangles: Option<usize>,
    /// Also write the unsimplified voxel boundary as NAME.start.glb.
    #[arg(long)]
    pub keep_start_mesh: bool,
    /// Also write the swept mesh as NAME.swept.stl (binary, outward normals), .ply (binary) or
    /// .obj: a comma-separated list.
    #[arg(long, value_enum, value_delimiter = ',', value_name = "FORMATS")]
    pub also: Vec<MeshFormat>,
    /// What moves the part between rows: `screw`, the constant-velocity screw motion from each
    /// row to the next, covered with a derived bound; or `discrete`, only the listed poses.
    #[arg(long, value_enum, default_value_t)]
    pub motion: Motion,
    /// How voxels are classified: `auto` floods from outside where every part is closed, else
    /// `axes`; `flood`: condition ⋆ less what a flood from outside reaches without crossing the
    /// offset (no concavity filled; an open part may come out as a shell around its surface);
    /// `axes`: condition ⋆ alone (the paper's; concavities no axis sees are filled).
    #[arg(long, value_enum, default_value_t)]
    pub classify: Method,
    /// δ and ε where --delta and --epsilon are not given: `exact`, sized for the simplifier's
    /// exact checks (δ ≈ 1.54h, ε = 0.6h; stated bound about 3.2h + μ); `paper`, the
    /// paper's (δ = (2√3+√2)h/2, ε = √3h/2; about 4.17h + μ).
    #[arg(long, value_enum, default_value_t)]
    pub radii: Radii,
    /// An obstacle file (glTF 2.0; every node with triangles is an obstacle): the report gains
    /// each obstacle's clearance, a guaranteed interval and a verdict, and NAME.FILE.clearance.glb
    /// its clearance map. Repeatable.
    #[arg(long, value_name = "FILE")]
    pub against: Vec<PathBuf>,
    /// Fail (exit 3; the outputs are still written) when an obstacle's guaranteed clearance is
    /// below X world units, or a contact is certain.
    #[arg(long, value_name = "X", allow_negative_numbers = true)]
    pub require_clearance: Option<f64>,
    /// The clearance, world units, at which the map's colours reach green (red is contact)
    /// [default: 10 times the stated bound].
    #[arg(long, value_name = "X", allow_negative_numbers = true)]
    pub clearance_scale: Option<f64>,
    /// Sweep every other part in the frame of this moving node: at each row time a part's
    /// pose is the node's pose inverted times its own, and the motion between rows is the screw
    /// in the node's frame (rows of the node and of a part pair by their frame or time). The
    /// outputs are in the node's frame, and the node is an obstacle (so are --against files,
    /// read in the node's frame).
    #[arg(long, value_name = "NODE")]
    pub relative_to: Option<String>,
    /// What a trajectory row's matrix is: `world`, a world-space transform of the part where
    /// the glTF puts it; or `local`, the named node's own transform relative to its parent
    /// (the glTF's node hierarchy is the kinematic tree: between rows each node moves by the
    /// screw in its parent's frame, joint-linear for a revolute or prismatic joint, and rows
    /// of different nodes pair by their frame or time). A --robot job's rows are always local.
    #[arg(long, value_enum, default_value_t)]
    pub rows: Rows,
    /// A folder holding the packages a --robot URDF names (`package://NAME/path` is read as
    /// DIR/NAME/path; a folder called NAME above the URDF is tried too). Repeatable.
    #[arg(long, value_name = "DIR")]
    pub package_dir: Vec<PathBuf>,
}

/// A whole job as one file, as `cluster submit` writes it for its array tasks (`sweep --job
/// FILE --shard I/N`): the inputs (absolute paths, valid on every node), where the shards go,
/// and the options resolved as the run takes them. Nothing is turned back into arguments.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JobFile {
    pub generator: PathBuf,
    pub trajectory: PathBuf,
    /// The shard folder the sweep writes to.
    pub out: PathBuf,
    pub options: JobOptions,
    /// Run even when the memory estimate exceeds what is available.
    #[serde(default)]
    pub no_memory_check: bool,
}

/// The keys of job.json: [`JobOptions`]'s fields, in order (a test holds them to the struct).
pub const JOB_KEYS: [&str; 18] = [
    "resolution",
    "tolerance",
    "delta",
    "epsilon",
    "backend",
    "name",
    "target_triangles",
    "keep_start_mesh",
    "also",
    "motion",
    "classify",
    "radii",
    "against",
    "require_clearance",
    "clearance_scale",
    "relative_to",
    "rows",
    "package_dir",
];

/// An output file stem: a name, not empty and not a path.
pub fn file_stem(s: &str) -> Result<String, String> {
    if s.is_empty() || s == "." || s == ".." || s.contains('/') || s.contains('\0') {
        return Err("must be a file name stem such as part (not empty, no folder)".into());
    }
    Ok(s.to_string())
}

/// The option key of job.json key `key`, where messages can name it.
pub fn option_key(key: &str) -> Option<OptionKey> {
    OptionKey::ALL.into_iter().find(|k| k.name() == key)
}

/// An extra output format (`--also`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum MeshFormat {
    /// Binary STL: one facet per triangle with its outward unit normal.
    Stl,
    /// Binary little-endian PLY: welded vertices, triangle faces.
    Ply,
    /// Wavefront OBJ: welded vertices (f32, printed so they read back exactly), triangle faces.
    Obj,
}

impl MeshFormat {
    pub const ALL: [MeshFormat; 3] = [MeshFormat::Stl, MeshFormat::Ply, MeshFormat::Obj];

    /// The name `--also` and job.json take: `stl`, `ply`, `obj`.
    pub fn name(self) -> &'static str {
        &self.suffix()["swept.".len()..]
    }

    /// The file name suffix after the stem: `swept.stl`, ...
    pub fn suffix(self) -> &'static str {
        match self {
            MeshFormat::Stl => "swept.stl",
            MeshFormat::Ply => "swept.ply",
            MeshFormat::Obj => "swept.obj",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// JOB_KEYS are the struct's fields, each with an option key, so every shell can word it.
    #[test]
    fn every_job_key_is_a_field_and_an_option_key() {
        let json = serde_json::to_value(JobOptions::default()).unwrap();
        let fields: Vec<&str> = json
            .as_object()
            .unwrap()
            .keys()
            .map(String::as_str)
            .collect();
        let mut keys = JOB_KEYS.to_vec();
        keys.sort();
        let mut sorted = fields.clone();
        sorted.sort();
        assert_eq!(sorted, keys);
        for key in JOB_KEYS {
            assert!(option_key(key).is_some(), "no OptionKey for {key:?}");
        }
    }

    /// What job.json leaves out takes the command line's defaults, and unknown keys fail.
    #[test]
    fn job_json_defaults_are_the_command_lines() {
        use clap::Parser;
        #[derive(Parser)]
        struct Cli {
            #[command(flatten)]
            job: JobOptions,
        }
        let from_json: JobOptions = serde_json::from_str("{}").unwrap();
        let from_cli = Cli::parse_from(["x"]).job;
        assert_eq!(from_json, from_cli);
        let both: JobOptions =
            serde_json::from_str(r#"{"motion": "discrete", "also": ["stl", "obj"]}"#).unwrap();
        let cli = Cli::parse_from(["x", "--motion", "discrete", "--also", "stl,obj"]).job;
        assert_eq!(both, cli);
        assert!(serde_json::from_str::<JobOptions>(r#"{"resolutoin": 64}"#).is_err());
    }
}
