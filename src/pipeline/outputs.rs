//! The files a run writes, by name: the one place the output names are spelled, and the rule
//! that no output may be an input.

use std::path::{Path, PathBuf};

use super::RunOptions;
use crate::error::{OptionError, OptionKey};
use crate::io::exr_depth::{self, Side};
use crate::job::MeshFormat;

/// The stem used for output names.
pub fn output_stem(opts: &RunOptions) -> anyhow::Result<String> {
    let stem = match &opts.job.name {
        Some(n) => n.clone(),
        None => opts
            .trajectory
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default(),
    };
    if stem.contains(['/', '\\']) || stem.starts_with('.') {
        return Err(OptionError::new(
            OptionKey::Name,
            format!("$name {stem:?} must be a plain file name without slashes or a leading dot"),
        )
        .into());
    }
    if opts.job.name.is_none() && stem.is_empty() {
        return Err(OptionError::new(
            OptionKey::Name,
            format!(
                "cannot derive an output name from {}; pass $name",
                opts.trajectory.display()
            ),
        )
        .into());
    }
    Ok(stem)
}

pub(super) fn with_stem(stem: &str, suffix: &str) -> String {
    if stem.is_empty() {
        suffix.to_string()
    } else {
        format!("{stem}.{suffix}")
    }
}

/// Output names after `<stem>.` (bare in a watched job folder): the one place they are spelled
/// (the watcher's protocol and `sweptvol protocol` take them from here).
pub const MESH_SUFFIX: &str = "swept.glb";
pub const START_MESH_SUFFIX: &str = "start.glb";
pub const REPORT_SUFFIX: &str = "report.json";
/// A clearance map: `<stem>.<obstacle file stem>.clearance.glb`.
pub const CLEARANCE_SUFFIX: &str = "clearance.glb";
/// The hidden marker of a set being published (`.<stem>.incomplete`).
pub const INCOMPLETE_SUFFIX: &str = "incomplete";

/// The extra formats asked for, each once, in `MeshFormat::ALL` order.
fn also_formats(opts: &RunOptions) -> impl Iterator<Item = MeshFormat> + '_ {
    MeshFormat::ALL
        .into_iter()
        .filter(|f| opts.job.also.contains(f))
}

/// Every file a run writes, by role.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OutputPaths {
    pub mesh: PathBuf,
    /// Depth images x, y, z; min, max each.
    pub depth: [PathBuf; 6],
    pub report: PathBuf,
    /// With `keep_start_mesh`: the unsimplified voxel boundary.
    pub start_mesh: Option<PathBuf>,
    /// The `also` formats, in `MeshFormat::ALL` order.
    pub also: Vec<(MeshFormat, PathBuf)>,
    /// One clearance map per `against` file, in order.
    pub clearance_maps: Vec<PathBuf>,
    /// `.<stem>.incomplete`: present while the set is being published, listing its files
    /// (`io::atomic::Staged`); one left behind marks a set a crash cut off.
    pub marker: PathBuf,
    /// Names of the same stem this run does not write but an earlier one may have (the start
    /// mesh, `also` formats not asked for), other than the inputs: with `overwrite` they are
    /// removed as the set is published, so no old mesh is read beside the new one; without,
    /// one that exists stops the run as an existing output does.
    pub stale: Vec<PathBuf>,
}

impl OutputPaths {
    /// All of them, in the report's order: mesh, depth images, report, start mesh, `also`.
    pub fn all(&self) -> Vec<PathBuf> {
        let mut out = vec![self.mesh.clone()];
        out.extend(self.depth.iter().cloned());
        out.push(self.report.clone());
        out.extend(self.start_mesh.iter().cloned());
        out.extend(self.also.iter().map(|(_, p)| p.clone()));
        out.extend(self.clearance_maps.iter().cloned());
        out
    }

    /// Every name of the set: [`OutputPaths::all`], then [`OutputPaths::stale`].
    pub fn with_stale(&self) -> Vec<PathBuf> {
        let mut out = self.all();
        out.extend(self.stale.iter().cloned());
        out
    }
}

/// The clearance map of the `relative_to` node, then of each `against` file:
/// `<stem>.<node name or file stem>.clearance.glb`, the name
/// made of letters, digits, `-` and `_` (others become `_`); two files of one stem are refused.
pub(super) fn clearance_map_paths(
    out_dir: &Path,
    stem: &str,
    relative_to: Option<&str>,
    against: &[PathBuf],
) -> anyhow::Result<Vec<PathBuf>> {
    let mut out: Vec<PathBuf> = Vec::new();
    let pieces = relative_to
        .map(str::to_string)
        .into_iter()
        .chain(against.iter().map(|f| {
            f.file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default()
        }));
    for name in pieces {
        let piece: String = name
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                    c
                } else {
                    '_'
                }
            })
            .collect();
        let piece = if piece.is_empty() {
            "obstacle".to_string()
        } else {
            piece
        };
        let path = out_dir.join(with_stem(stem, &format!("{piece}.{CLEARANCE_SUFFIX}")));
        if out.contains(&path) {
            return Err(OptionError::new(
                OptionKey::Against,
                format!(
                    "two obstacles would share the clearance map {}: give each $against file its own name (and none the $relative_to node's)",
                    path.display()
                ),
            )
            .into());
        }
        out.push(path);
    }
    Ok(out)
}

/// Whether `name` is a clearance map of `stem`: `<stem>.<piece>.clearance.glb` with a piece
/// as [`clearance_map_paths`] makes them (not empty, no dot).
fn is_clearance_map(name: &str, stem: &str) -> bool {
    name.strip_prefix(&with_stem(stem, ""))
        .and_then(|rest| rest.strip_suffix(&format!(".{CLEARANCE_SUFFIX}")))
        .is_some_and(|piece| !piece.is_empty() && !piece.contains('.'))
}

/// Every file `run` writes.
pub fn output_paths(opts: &RunOptions) -> anyhow::Result<OutputPaths> {
    let stem = output_stem(opts)?;
    let at = |suffix: &str| opts.out_dir.join(with_stem(&stem, suffix));
    // x, y, z; min, max each: the order of `exr_depth::stage_all`.
    let depth = std::array::from_fn(|i| {
        let side = [Side::Min, Side::Max][i % 2];
        opts.out_dir
            .join(exr_depth::depth_file_name(&stem, i / 2, side))
    });
    let inputs: Vec<Option<PathBuf>> = [&opts.generator, &opts.trajectory]
        .into_iter()
        .chain(&opts.job.against)
        .map(|p| p.canonicalize().ok())
        .collect();
    let is_input = |p: &PathBuf| {
        let real = p.canonicalize().ok();
        real.is_some() && inputs.contains(&real)
    };
    let clearance_maps = clearance_map_paths(
        &opts.out_dir,
        &stem,
        opts.job.relative_to.as_deref(),
        &opts.job.against,
    )?;
    // Maps of an earlier run against other files: `<stem>.*.clearance.glb` in the folder.
    let old_maps: Vec<PathBuf> = std::fs::read_dir(&opts.out_dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| is_clearance_map(n, &stem))
        })
        .filter(|p| !clearance_maps.contains(p))
        .collect();
    let stale = (!opts.job.keep_start_mesh)
        .then(|| at(START_MESH_SUFFIX))
        .into_iter()
        .chain(
            MeshFormat::ALL
                .into_iter()
                .filter(|f| !opts.job.also.contains(f))
                .map(|f| at(f.suffix())),
        )
        .chain(old_maps)
        .filter(|p| !is_input(p))
        .collect();
    Ok(OutputPaths {
        mesh: at(MESH_SUFFIX),
        depth,
        report: at(REPORT_SUFFIX),
        start_mesh: opts.job.keep_start_mesh.then(|| at(START_MESH_SUFFIX)),
        also: also_formats(opts).map(|f| (f, at(f.suffix()))).collect(),
        clearance_maps,
        marker: opts
            .out_dir
            .join(format!(".{}", with_stem(&stem, INCOMPLETE_SUFFIX))),
        stale,
    })
}

/// No output may be an input, with or without `--overwrite`: the rename would replace it. Paths
/// are compared canonicalized (the output's folder resolved, since the output may not exist
/// yet); an existing output is also compared by device and inode (hard links, symlinks).
pub(super) fn refuse_outputs_on_inputs(
    opts: &RunOptions,
    outputs: &[PathBuf],
) -> anyhow::Result<()> {
    use std::os::unix::fs::MetadataExt;
    type Identity = Option<(u64, u64)>; // (device, inode)
    let inputs: Vec<(&PathBuf, Option<PathBuf>, Identity)> = [&opts.generator, &opts.trajectory]
        .into_iter()
        .map(|p| {
            let id = std::fs::metadata(p).ok().map(|m| (m.dev(), m.ino()));
            (p, p.canonicalize().ok(), id)
        })
        .collect();
    for out in outputs {
        let resolved = match (out.parent(), out.file_name()) {
            (Some(dir), Some(name)) => {
                let dir = if dir.as_os_str().is_empty() {
                    std::path::Path::new(".")
                } else {
                    dir
                };
                dir.canonicalize().ok().map(|d| d.join(name))
            }
            _ => None,
        };
        let id = std::fs::metadata(out).ok().map(|m| (m.dev(), m.ino()));
        for (input, real, input_id) in &inputs {
            let same_path = resolved.is_some() && resolved == *real;
            let same_file = id.is_some() && id == *input_id;
            if same_path || same_file {
                return Err(OptionError::new(
                    OptionKey::Out,
                    format!(
                        "output {} would replace the input {}{}; nothing was written: choose another $out or $name, or rename the input",
                        out.display(),
                        input.display(),
                        if same_path { "" } else { " (the same file by a hard or symbolic link)" }
                    ),
                )
                .into());
            }
        }
    }
    Ok(())
}
