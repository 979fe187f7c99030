//! The exchange protocol (docs/exchange-protocol.md): which names in a watched folder mean what,
//! and the schemas of `job.json` (read) and `status.json` (written). Keep the doc in step.

use crate::input::motion::Motion;
use crate::mesh::classify::Method;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::error::{InputError, OptionKey};
use crate::input::grid::{Accuracy, Radii};
use crate::io::exr_depth::{depth_file_name, Side};
use crate::job::MeshFormat;
use crate::pipeline::{self, RunOptions};

/// A folder being written by a client: never read. Renaming it without the suffix commits it.
pub const PARTIAL_SUFFIX: &str = ".partial";
/// The daemon's own folder inside the watched one (lock, heartbeat).
pub const CONTROL_DIR: &str = ".sweptvol";
/// Created by a client in a job folder to ask the daemon to stop that job.
pub const CANCEL: &str = "cancel";
pub const JOB_JSON: &str = "job.json";
pub const TRAJECTORY: &str = "trajectory.csv";
pub const GENERATOR_GLB: &str = "generator.glb";
pub const GENERATOR_GLTF: &str = "generator.gltf";
/// Drop inputs: `<name>.glb` and `<name>.csv` straight in the watched folder.
pub const DROP_GENERATOR_EXT: &str = "glb";
pub const DROP_TRAJECTORY_EXT: &str = "csv";

/// The status file's bare name (`<name>.status.json` for a drop).
pub const STATUS: &str = "status.json";
/// The daemon's heartbeat inside `CONTROL_DIR`.
pub const HEARTBEAT_FILE: &str = "daemon.json";

/// Names the daemon writes (the run's outputs, spelled in `pipeline`, and the status file):
/// bare in a job folder, `<name>.`-prefixed for a drop. A file with one of these names (bare or
/// prefixed) is never taken as an input.
pub fn output_names() -> Vec<String> {
    let mut names: Vec<String> = [
        pipeline::MESH_SUFFIX,
        pipeline::START_MESH_SUFFIX,
        pipeline::REPORT_SUFFIX,
        pipeline::CLEARANCE_SUFFIX,
        STATUS,
    ]
    .map(String::from)
    .to_vec();
    names.extend(MeshFormat::ALL.map(|f| f.suffix().to_string()));
    names.extend(depth_image_names());
    names
}

/// The six depth images' bare names: x, y, z; min, max each.
pub fn depth_image_names() -> Vec<String> {
    (0..3)
        .flat_map(|axis| Side::BOTH.map(|side| depth_file_name("", axis, side)))
        .collect()
}

/// Whether `name` is something the daemon writes (bare or `<stem>.`-prefixed).
pub fn is_output_name(name: &str) -> bool {
    output_names().iter().any(|o| {
        name == o
            || name
                .strip_suffix(o.as_str())
                .is_some_and(|stem| stem.len() > 1 && stem.ends_with('.'))
    })
}

/// Every name of the protocol, for clients in other languages (`sweptvol protocol` prints it;
/// the Blender add-on's tests compare their own constants with it).
pub fn names_json() -> serde_json::Value {
    let also: serde_json::Map<String, serde_json::Value> = MeshFormat::ALL
        .iter()
        .map(|f| {
            let key = serde_json::to_value(f).expect("a name");
            (
                key.as_str().expect("a string").to_string(),
                f.suffix().into(),
            )
        })
        .collect();
    serde_json::json!({
        "partial_suffix": PARTIAL_SUFFIX,
        "control_dir": CONTROL_DIR,
        "heartbeat": HEARTBEAT_FILE,
        "job_files": {
            "generator_glb": GENERATOR_GLB,
            "generator_gltf": GENERATOR_GLTF,
            "trajectory": TRAJECTORY,
            "job_json": JOB_JSON,
            "cancel": CANCEL,
        },
        "outputs": {
            "mesh": pipeline::MESH_SUFFIX,
            "start_mesh": pipeline::START_MESH_SUFFIX,
            "report": pipeline::REPORT_SUFFIX,
            "clearance_map": pipeline::CLEARANCE_SUFFIX,
            "status": STATUS,
            "depth_images": depth_image_names(),
            "also": also,
        },
        "job_keys": JOB_KEY_LIST,
        "motions": [Motion::Screw.name(), Motion::Discrete.name()],
        "classify_methods": [Method::Auto.name(), Method::Flood.name(), Method::Axes.name()],
        "radii": [Radii::Exact.name(), Radii::Paper.name()],
        "states": State::ALL.map(State::as_str),
        "finished_states": State::ALL.into_iter().filter(|s| s.is_finished()).map(State::as_str).collect::<Vec<_>>(),
    })
}

/// What an entry at the top of the watched folder is.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Role {
    /// A committed job folder `<job>/`.
    JobFolder,
    /// `<name>.glb` of a drop; holds the stem.
    DropGenerator(String),
    /// `<name>.csv` of a drop; holds the stem.
    DropTrajectory(String),
    /// Hidden names (temporary files, `.sweptvol`), `.partial` folders, outputs, anything else.
    Ignored,
}

/// Classify a top-level entry by name and kind (after following a symlink).
pub fn classify(name: &str, is_dir: bool) -> Role {
    if name.starts_with('.') || name.ends_with(PARTIAL_SUFFIX) {
        return Role::Ignored;
    }
    if is_dir {
        return Role::JobFolder;
    }
    if is_output_name(name) {
        return Role::Ignored;
    }
    match name.rsplit_once('.') {
        Some((stem, ext)) if !stem.is_empty() && ext == DROP_GENERATOR_EXT => {
            Role::DropGenerator(stem.into())
        }
        Some((stem, ext)) if !stem.is_empty() && ext == DROP_TRAJECTORY_EXT => {
            Role::DropTrajectory(stem.into())
        }
        _ => Role::Ignored,
    }
}

/// A job: a committed folder or a drop pair, by name. The two kinds have separate namespaces.
#[derive(Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum JobId {
    Folder(String),
    Drop(String),
}

impl JobId {
    pub fn name(&self) -> &str {
        match self {
            JobId::Folder(n) | JobId::Drop(n) => n,
        }
    }

    /// Where the job's outputs and status go.
    pub fn out_dir(&self, root: &Path) -> PathBuf {
        match self {
            JobId::Folder(n) => root.join(n),
            JobId::Drop(_) => root.to_path_buf(),
        }
    }

    /// The output stem `pipeline` uses: empty (bare names) in a job folder.
    pub fn stem(&self) -> &str {
        match self {
            JobId::Folder(_) => "",
            JobId::Drop(n) => n,
        }
    }

    pub fn status_path(&self, root: &Path) -> PathBuf {
        match self {
            JobId::Folder(n) => root.join(n).join(STATUS),
            JobId::Drop(n) => root.join(format!("{n}.{STATUS}")),
        }
    }

    /// The `cancel` file; drops have none (delete the inputs, or stop the daemon).
    pub fn cancel_path(&self, root: &Path) -> Option<PathBuf> {
        match self {
            JobId::Folder(n) => Some(root.join(n).join(CANCEL)),
            JobId::Drop(_) => None,
        }
    }
}

impl std::fmt::Display for JobId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            JobId::Folder(n) => write!(f, "{n}/"),
            JobId::Drop(n) => write!(f, "{n}.glb + {n}.csv"),
        }
    }
}

/// One input file as last seen: a job is re-run when any of these change.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
pub struct FileStamp {
    /// Relative to the job folder (or the watched folder for a drop), `/`-separated.
    pub file: String,
    pub size: u64,
    /// Modification time, nanoseconds since the Unix epoch.
    pub mtime_ns: i64,
}

/// A job's inputs, sorted by file name: equal fingerprints mean unchanged inputs.
pub type Fingerprint = Vec<FileStamp>;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum State {
    Queued,
    Running,
    Done,
    Failed,
    Cancelled,
}

impl State {
    pub const ALL: [State; 5] = [
        State::Queued,
        State::Running,
        State::Done,
        State::Failed,
        State::Cancelled,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            State::Queued => "queued",
            State::Running => "running",
            State::Done => "done",
            State::Failed => "failed",
            State::Cancelled => "cancelled",
        }
    }

    /// A finished job is not run again while its inputs stay the same.
    pub fn is_finished(self) -> bool {
        matches!(self, State::Done | State::Failed | State::Cancelled)
    }
}

/// `status.json`: replaced atomically at every change.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Status {
    pub state: State,
    /// "queued", "reading", "sweep", "classify", "simplify", "write", or "" when finished.
    pub stage: String,
    /// 0 to 1.
    pub progress: f64,
    pub message: String,
    /// The job's display name (`name` in job.json, else the folder or drop name).
    pub name: String,
    pub sweptvol_version: String,
    pub timings: Timings,
    /// For a failed job whose input is at fault: where and how to fix it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<ErrorInfo>,
    /// The inputs this status is about; a restart re-runs the job when they differ.
    pub inputs: Fingerprint,
    /// Output file names, relative to the status file's folder (when done).
    #[serde(default)]
    pub outputs: Vec<String>,
    /// A job the daemon handed to SLURM (`watch --executor slurm`): its shards and jobs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cluster: Option<ClusterProgress>,
}

/// `status.json`'s `cluster`: how far a job on SLURM is.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ClusterProgress {
    pub shards: u32,
    /// Shards finished (their manifests written).
    pub shards_done: u32,
    /// SLURM's ids: the shard array (None when every shard was finished) and the merge.
    pub sweep_job: Option<String>,
    pub merge_job: String,
    /// The shard folder, relative to the watched folder.
    pub shard_dir: String,
}

/// Wall-clock times, seconds since the Unix epoch, and durations in seconds.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Timings {
    pub queued_at: Option<f64>,
    pub started_at: Option<f64>,
    pub finished_at: Option<f64>,
    /// From start to finish (or to now while running).
    pub seconds: Option<f64>,
    /// Per-stage seconds from the report (when done).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stages: Option<serde_json::Value>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ErrorInfo {
    pub file: PathBuf,
    pub line: Option<u64>,
    /// CSV column, glTF JSON path, or for job.json the key at fault (`"tolerance"`).
    pub column: Option<String>,
    /// What is wrong, without the file and fix (the status's `message` has them all); in
    /// job.json errors options are spelled as their keys in double quotes.
    pub message: String,
    pub fix: String,
}

impl From<&InputError> for ErrorInfo {
    /// Options named in the message and fix are spelled by [`job_spelling`].
    fn from(e: &InputError) -> Self {
        ErrorInfo {
            file: e.file.clone(),
            line: e.line,
            column: e.column.clone(),
            message: crate::error::word(&e.message, job_spelling),
            fix: crate::error::word(&e.fix, job_spelling),
        }
    }
}

/// How the watcher's texts (status.json) name an option: as its job.json key in double quotes
/// (`"motion"`), which each client words as its own field; an option job.json has not is the
/// daemon's own setting, named by its flag.
pub fn job_spelling(k: OptionKey) -> String {
    if JOB_KEY_LIST.contains(&k.name()) {
        format!("\"{}\"", k.name())
    } else {
        format!("the daemon's {}", k.flag())
    }
}

/// What a restart needs from an existing status file; anything unreadable counts as absent.
#[derive(Clone, Debug, PartialEq, Deserialize)]
pub struct Recorded {
    pub state: State,
    pub inputs: Fingerprint,
}

pub fn parse_recorded(bytes: &[u8]) -> Option<Recorded> {
    serde_json::from_slice(bytes).ok()
}

/// `job.json` is the job's options, one typed value for every shell (`crate::job`).
pub use crate::job::JobOptions;
/// The keys of `job.json`: `JobOptions`'s fields.
pub use crate::job::JOB_KEYS as JOB_KEY_LIST;

/// Parse `job.json` bytes; `path` names the file in errors (with serde_json's line and column).
pub fn parse_job_options(path: &Path, bytes: &[u8]) -> Result<JobOptions, InputError> {
    // serde would take a JSON array for the struct too, by position: refused by name.
    let first = bytes.iter().find(|b| !b.is_ascii_whitespace());
    if first.is_some_and(|&b| b != b'{') {
        return Err(InputError::new(
            path,
            "the job options are not a JSON object",
            format!(
                "write one JSON object, {{\"resolution\": 256}} for instance, using only the keys {}",
                JOB_KEY_LIST.join(", ")
            ),
        ));
    }
    let opts: JobOptions = serde_json::from_slice(bytes).map_err(|e| {
        InputError::new(
            path,
            format!("invalid job options: {e}"),
            format!(
                "write one JSON object using only the keys {} (docs/exchange-protocol.md)",
                JOB_KEY_LIST.join(", ")
            ),
        )
        .at_line(e.line() as u64)
        .in_column(format!("column {}", e.column()))
    })?;
    // Obstacles are files of the job folder, by name: nothing outside the watched folder is
    // read, and nothing that could be an output.
    for a in &opts.against {
        let name = a.to_str().unwrap_or_default();
        let plain = !name.is_empty()
            && !name.starts_with('.')
            && !name.contains(['/', '\\'])
            && (name.ends_with(".glb") || name.ends_with(".gltf"))
            && !name.ends_with(".clearance.glb")
            && !name.ends_with(".swept.glb")
            && !name.ends_with(".start.glb");
        if !plain {
            return Err(InputError::new(
                path,
                format!("\"against\": {name:?} is not the name of an obstacle file in the job folder"),
                "put the obstacle .glb (or .gltf) into the job folder and give its plain file name, such as \"housing.glb\" (no folder, no leading dot, not an output's name)",
            )
            .in_column("against"));
        }
    }
    // A robot's package folders are folders of the job folder: nothing outside it is read.
    for d in &opts.package_dir {
        let inside = d.components().count() > 0
            && d.components().all(|c| {
                matches!(c, std::path::Component::Normal(n) if !n.to_string_lossy().starts_with('.'))
            });
        if !inside {
            return Err(InputError::new(
                path,
                format!("\"package_dir\": {:?} is not a folder inside the job folder", d.display().to_string()),
                "put the robot's packages into a folder of the job folder and give its relative path, such as \"packages\" (no leading dot, no ..)",
            )
            .in_column("package_dir"));
        }
    }
    if opts.resolution.is_some() && opts.tolerance.is_some() {
        return Err(InputError::new(
            path,
            "both \"resolution\" and \"tolerance\" are given",
            "keep one of them: each sets the voxel size",
        ));
    }
    Ok(opts)
}

/// The run of a watched job: `options` with `default_accuracy` where the job names none, into
/// the job's output folder under its own stem. The daemon owns the output names, so it replaces
/// its own earlier outputs.
pub fn run_options(
    options: &JobOptions,
    generator: PathBuf,
    trajectory: PathBuf,
    id: &JobId,
    root: &Path,
    default_accuracy: Accuracy,
) -> RunOptions {
    let mut run = RunOptions::of_job(
        options,
        generator,
        trajectory,
        id.out_dir(root),
        default_accuracy,
    );
    run.job.name = Some(id.stem().to_string());
    // job.json names obstacles by file name in the job folder (checked when it was parsed).
    run.job.against = options
        .against
        .iter()
        .map(|a| id.out_dir(root).join(a))
        .collect();
    run.job.package_dir = options
        .package_dir
        .iter()
        .map(|d| id.out_dir(root).join(d))
        .collect();
    run.overwrite = true;
    run
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 30: a job.json that is a JSON array was taken position by position (and `[1,2,3]`
    /// named internal types); anything but an object is refused by name.
    #[test]
    fn job_options_must_be_an_object() {
        let path = Path::new("job/job.json");
        for bytes in [&b"[256]"[..], b"  [1, 2, 3]", b"256", b"\"x\""] {
            let e = parse_job_options(path, bytes).unwrap_err().to_string();
            assert!(e.contains("not a JSON object"), "{e}");
            assert!(!e.contains("struct"), "{e}");
        }
        assert!(parse_job_options(path, br#" {"resolution": 64}"#).is_ok());
    }

    #[test]
    fn output_names_are_never_inputs() {
        for name in [
            "swept.glb",
            "a.swept.glb",
            "a.b.depth-zmax.exr",
            "a.status.json",
            "a.report.json",
        ] {
            assert!(is_output_name(name), "{name}");
        }
        for name in ["aswept.glb", ".swept.glb", "a.glb", "report.csv"] {
            assert!(!is_output_name(name), "{name}");
        }
        assert_eq!(classify("a.swept.glb", false), Role::Ignored);
        assert_eq!(
            classify("a.b.glb", false),
            Role::DropGenerator("a.b".into())
        );
        assert_eq!(classify("a.csv", false), Role::DropTrajectory("a".into()));
        assert_eq!(classify(".a.glb.tmp-12", false), Role::Ignored);
        assert_eq!(classify("job.partial", true), Role::Ignored);
        assert_eq!(classify(".sweptvol", true), Role::Ignored);
        assert_eq!(classify("job", true), Role::JobFolder);
        assert_eq!(classify("notes.txt", false), Role::Ignored);
    }

    #[test]
    fn job_json_unknown_key_names_line_and_column() {
        let p = Path::new("job/job.json");
        let e =
            parse_job_options(p, b"{\n  \"resolution\": 32,\n  \"resolutoin\": 64\n}").unwrap_err();
        assert_eq!(e.line, Some(3), "{e}");
        assert!(e.message.contains("resolutoin"), "{e}");
        assert!(e.fix.contains("tolerance"), "{e}");
        assert!(parse_job_options(p, br#"{"resolution": 32, "tolerance": 0.1}"#).is_err());
        let ok =
            parse_job_options(p, br#"{"resolution": 32, "backend": "cpu", "name": "x"}"#).unwrap();
        assert_eq!(ok.backend, Some(crate::sweep::backend::BackendChoice::Cpu));
        let also = parse_job_options(p, br#"{"also": ["stl", "obj"]}"#).unwrap();
        assert_eq!(also.also, vec![MeshFormat::Stl, MeshFormat::Obj]);
        assert!(parse_job_options(p, br#"{"also": ["step"]}"#).is_err());
        for f in MeshFormat::ALL {
            assert!(is_output_name(f.suffix()), "{f:?}");
        }
        // Every key the protocol lists is one job.json takes (serde's names of JobOptions).
        for key in JOB_KEY_LIST {
            let value = match key {
                "backend" => "\"cpu\"",
                "name" => "\"x\"",
                "keep_start_mesh" => "true",
                "also" => "[\"stl\"]",
                "motion" => "\"discrete\"",
                "classify" => "\"axes\"",
                "radii" => "\"paper\"",
                "against" => "[\"housing.glb\"]",
                "relative_to" => "\"frame\"",
                "rows" => "\"local\"",
                "package_dir" => "[\"packages\"]",
                _ => "1",
            };
            let json = format!("{{\"{key}\": {value}}}");
            assert!(parse_job_options(p, json.as_bytes()).is_ok(), "{json}");
        }
        // Obstacles are plain file names of the job folder: no path out of it, no output.
        for bad in [
            "../x.glb",
            "/etc/x.glb",
            "sub/x.glb",
            ".x.glb",
            "x.swept.glb",
            "x.csv",
            "",
        ] {
            let json = format!("{{\"against\": [{bad:?}]}}");
            let e = parse_job_options(p, json.as_bytes()).unwrap_err();
            assert_eq!(e.column.as_deref(), Some("against"), "{bad}: {e}");
        }
    }
}
