//! Runs one job: find and confine its inputs, check their size, read `job.json`, then
//! `pipeline::prepare` and `pipeline::execute`, reporting progress and polling for a cancel.
//! Every ending (done, failed, cancelled, a panic, a shutdown) is written to the status file.

use std::fs;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use super::executor::{Context, Finished, QueuedJob, Runs};
use super::on_cluster;
use super::protocol::{self, ErrorInfo, Fingerprint, JobId, JobOptions, State};
use super::status::StatusFile;
use crate::error::{InputError, OptionError, OptionKey};
use crate::pipeline;
use crate::sweep::backend::{Backend, BackendChoice};
use crate::sweep::{Cancelled, Observer};

/// job.json larger than this is refused before it is parsed.
const MAX_JOB_JSON_BYTES: u64 = 1 << 20;

/// Where each stage starts on the 0..1 progress scale (the sweep fills the span up to
/// classify), and the status message while it runs.
const STAGE_PROGRESS: [(&str, f64, &str); 5] = [
    ("reading", 0.0, "reading the inputs"),
    ("sweep", 0.05, "sweeping the poses"),
    (
        "classify",
        0.85,
        "classifying voxels and extracting the boundary mesh",
    ),
    (
        "simplify",
        0.9,
        "simplifying the mesh within the error bound",
    ),
    ("write", 0.97, "writing the outputs"),
];

/// Run `job` to an end and record it. Returns the state written (`Queued` after a shutdown).
pub fn run(ctx: &Context, job: &QueuedJob) -> State {
    let status = &job.status;
    if ctx.shutdown.load(Ordering::Relaxed) {
        return State::Queued; // stays queued for the next start
    }
    status.running();
    let observer = JobObserver {
        status,
        cancel: job.id.cancel_path(ctx.root),
        shutdown: ctx.shutdown,
        inputs: match &job.id {
            JobId::Drop(_) => Some((ctx.root.to_path_buf(), &job.inputs, true)),
            JobId::Folder(name) => Some((ctx.root.join(name), &job.inputs, false)),
        },
        inputs_changed: AtomicBool::new(false),
        folder: match &job.id {
            JobId::Folder(name) => {
                let dir = ctx.root.join(name);
                identity(&dir).map(|id| (dir, id))
            }
            JobId::Drop(_) => None,
        },
        vanished: AtomicBool::new(false),
    };
    let outcome = catch_unwind(AssertUnwindSafe(|| {
        if observer.cancelled() {
            return Err(Cancelled.into());
        }
        execute(ctx, job, &observer)
    }));
    let (state, message, error) = match outcome {
        Ok(Ok(finished)) => {
            let outputs: Vec<String> = finished
                .outputs
                .iter()
                .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
                .collect();
            status.update(|s| {
                s.outputs = outputs;
                s.timings.stages = finished.stages;
            });
            let message = finished.message;
            (State::Done, message, None)
        }
        Ok(Err(e)) if e.downcast_ref::<Cancelled>().is_some() => {
            if observer.vanished.load(Ordering::Relaxed) {
                // Nothing to record it in: writing the status would need the folder back.
                tracing::info!(
                    "{}: abandoned: the job folder was removed while the job ran; nothing was written",
                    job.id
                );
                return State::Cancelled;
            }
            if observer.inputs_changed.load(Ordering::Relaxed) {
                let m = "the inputs changed while the job ran (still being written?); nothing was published, and the job runs again once they have settled";
                (State::Queued, m.to_string(), None)
            } else if ctx.shutdown.load(Ordering::Relaxed) {
                let m =
                    "interrupted by the daemon's shutdown; it runs again when the daemon starts";
                (State::Queued, m.to_string(), None)
            } else {
                let m = "cancelled: the job folder has a cancel file; nothing was written";
                (State::Cancelled, m.to_string(), None)
            }
        }
        Ok(Err(e)) => {
            let error = e.downcast_ref::<InputError>().map(ErrorInfo::from);
            (
                State::Failed,
                crate::error::worded_chain(&e, protocol::job_spelling),
                error,
            )
        }
        Err(panic) => {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            let m =
                format!("internal error (panic: {what}); please report it with the job's inputs");
            (State::Failed, m, None)
        }
    };
    match state {
        State::Failed => tracing::error!("{}: failed: {message}", job.id),
        _ => tracing::info!("{}: {}: {message}", job.id, state.as_str()),
    }
    status.finish(state, message, error);
    state
}

/// Locate, confine and size-check the inputs, then run the pipeline.
fn execute(ctx: &Context, job: &QueuedJob, observer: &JobObserver) -> anyhow::Result<Finished> {
    let root = ctx.root;
    let (jail, generator, trajectory, job_json) = match &job.id {
        JobId::Folder(name) => {
            let dir = root.join(name);
            let glb = dir.join(protocol::GENERATOR_GLB);
            let gltf = dir.join(protocol::GENERATOR_GLTF);
            let generator = match (exists(&glb), exists(&gltf)) {
                (true, false) => glb,
                (false, true) => gltf,
                (true, true) => {
                    return Err(InputError::new(
                        &dir,
                        "the job folder holds both generator.glb and generator.gltf",
                        "keep only one generator file",
                    )
                    .into())
                }
                (false, false) => {
                    return Err(InputError::new(
                        &dir,
                        "the job folder has no generator.glb or generator.gltf",
                        "put the mesh in the job folder as generator.glb (or generator.gltf with its buffers) before renaming the .partial folder",
                    )
                    .into())
                }
            };
            let trajectory = dir.join(protocol::TRAJECTORY);
            if !exists(&trajectory) {
                return Err(InputError::new(
                    &trajectory,
                    "the job folder has no trajectory.csv",
                    "put the poses in the job folder as trajectory.csv before renaming the .partial folder",
                )
                .into());
            }
            let job_json = Some(dir.join(protocol::JOB_JSON)).filter(|p| exists(p));
            (dir, generator, trajectory, job_json)
        }
        JobId::Drop(stem) => (
            root.to_path_buf(),
            root.join(format!("{stem}.{}", protocol::DROP_GENERATOR_EXT)),
            root.join(format!("{stem}.{}", protocol::DROP_TRAJECTORY_EXT)),
            None,
        ),
    };
    let jail = jail
        .canonicalize()
        .map_err(|e| anyhow::anyhow!("cannot open {}: {e}", jail.display()))?;
    for path in [Some(&generator), Some(&trajectory), job_json.as_ref()]
        .into_iter()
        .flatten()
    {
        confine(path, &jail, &job.id)?;
    }
    check_size(
        &job.id,
        &jail,
        &job.inputs,
        &generator,
        &trajectory,
        ctx.max_input_bytes,
    )?;

    let options = match &job_json {
        Some(path) => {
            if fs::metadata(path)?.len() > MAX_JOB_JSON_BYTES {
                return Err(InputError::new(
                    path,
                    "job.json is larger than 1 MiB",
                    "job.json holds a few options: see docs/exchange-protocol.md",
                )
                .into());
            }
            let bytes = fs::read(path).map_err(|e| {
                InputError::new(path, format!("cannot read: {e}"), "check its permissions")
            })?;
            protocol::parse_job_options(path, &bytes)?
        }
        None => JobOptions::default(),
    };
    if let Some(name) = &options.name {
        let name = name.clone();
        job.status.update(|s| s.name = name);
    }
    let opts = protocol::run_options(
        &options,
        generator,
        trajectory,
        &job.id,
        root,
        ctx.default_accuracy,
    );
    remove_stale_temporaries(&opts, &job.id.status_path(root))?;
    let prepared = pipeline::prepare(&opts).map_err(|e| in_job_terms(e, job_json.as_deref()))?;
    let here = match ctx.runs {
        Runs::Slurm(slurm) => {
            let backend = options.backend.unwrap_or(ctx.backend_choice);
            return on_cluster::run(ctx, job, slurm, &prepared, backend, observer);
        }
        Runs::Here(backend) => backend,
    };
    let cpu;
    let backend = match options.backend {
        None | Some(BackendChoice::Auto) => here,
        Some(BackendChoice::Cpu) => {
            cpu = Backend::Cpu {
                reason: "\"backend\": \"cpu\" in job.json".into(),
            };
            &cpu
        }
        Some(BackendChoice::Gpu) => match here {
            Backend::Gpu(_) => here,
            Backend::Cpu { reason } => {
                let path = job_json.clone().unwrap_or_default();
                return Err(InputError::new(
                    &path,
                    format!("\"backend\": \"gpu\", but this daemon has no GPU ({reason})"),
                    format!(
                        "remove \"backend\" (or set it to \"auto\"), or restart the daemon with {} gpu",
                        OptionKey::Backend.flag()
                    ),
                )
                .into());
            }
        },
    };
    pipeline::execute(&prepared, backend, observer).map(|r| Finished::of(&r))
}

/// A bad option value, worded for where it came from: job.json's keys (`"delta"`, the key
/// also in the error's column), or the daemon's flags for a drop (which has no job.json).
fn in_job_terms(e: anyhow::Error, job_json: Option<&Path>) -> anyhow::Error {
    let is_job_key = |k: OptionKey| protocol::JOB_KEY_LIST.contains(&k.name());
    match (e.downcast::<OptionError>(), job_json) {
        (Ok(option), Some(path)) => {
            let error = InputError::new(
                path,
                option.worded(protocol::job_spelling),
                "change that value in job.json; docs/exchange-protocol.md lists the keys and their ranges",
            );
            if is_job_key(option.key) {
                error.in_column(option.key.name()).into()
            } else {
                error.into()
            }
        }
        (Ok(option), None) => anyhow::Error::new(OptionError::new(
            option.key,
            format!(
                "{} (this drop has no job.json, so the daemon's {} or {} applies: restart it with another value, or submit a job folder with a job.json)",
                option.worded(OptionKey::flag),
                OptionKey::Resolution.flag(),
                OptionKey::Tolerance.flag()
            ),
        )),
        (Err(e), _) => e,
    }
}

fn exists(path: &Path) -> bool {
    fs::symlink_metadata(path).is_ok()
}

/// Refuse an input that is not a regular file inside `jail` (symlinks are followed and must
/// stay inside).
fn confine(path: &Path, jail: &Path, id: &JobId) -> Result<(), InputError> {
    let where_ = match id {
        JobId::Folder(_) => "the job folder",
        JobId::Drop(_) => "the watched folder",
    };
    let real = path.canonicalize().map_err(|e| {
        InputError::new(
            path,
            format!("cannot open: {e}"),
            "a symbolic link must point to an existing file; better, copy the file in",
        )
    })?;
    if !real.starts_with(jail) {
        return Err(InputError::new(
            path,
            format!(
                "refused: it is a symbolic link to {}, outside {where_} (nothing outside {} is read)",
                real.display(),
                jail.display()
            ),
            format!("copy the file into {where_} instead of linking to it"),
        ));
    }
    if !real.is_file() {
        return Err(InputError::new(
            path,
            "not a regular file",
            "replace it with the file itself",
        ));
    }
    Ok(())
}

/// Refuse oversized inputs before anything parses them.
fn check_size(
    id: &JobId,
    jail: &Path,
    inputs: &Fingerprint,
    generator: &Path,
    trajectory: &Path,
    limit: u64,
) -> Result<(), InputError> {
    let size = |p: &Path| fs::metadata(p).map(|m| m.len()).unwrap_or(0);
    let total: u64 = match id {
        // Every input in the folder: a .gltf's buffers are parsed too.
        JobId::Folder(_) => inputs.iter().map(|s| size(&jail.join(&s.file))).sum(),
        JobId::Drop(_) => size(generator) + size(trajectory),
    };
    if total > limit {
        let at = match id {
            JobId::Folder(_) => jail.to_path_buf(),
            JobId::Drop(_) => generator.to_path_buf(),
        };
        return Err(InputError::new(
            &at,
            format!("the inputs hold {total} bytes, more than the daemon's limit of {limit} bytes; nothing was parsed"),
            format!(
                "simplify the mesh or shorten the trajectory, or restart the daemon with a larger {}",
                OptionKey::MaxInputBytes.flag()
            ),
        ));
    }
    Ok(())
}

/// Temporary files left by a daemon killed mid-write (`.<output>.tmp-<pid>-<n>`): removed before
/// the job writes its own, so nothing stale lingers. The status file's temporaries of this
/// process may be in use and are kept.
fn remove_stale_temporaries(opts: &pipeline::RunOptions, status: &Path) -> anyhow::Result<()> {
    let mut outputs = pipeline::output_paths(opts)?.all();
    outputs.push(status.to_path_buf());
    let prefixes: Vec<String> = outputs
        .iter()
        .filter_map(|p| p.file_name())
        .map(|n| format!(".{}.tmp-", n.to_string_lossy()))
        .collect();
    // This process's temporaries (`.<name>.tmp-<pid>-<n>`) may be in use by a status write;
    // a planted file under such a name is harmless, since temporaries are created exclusively.
    let ours = format!(".tmp-{}-", std::process::id());
    let Ok(read) = fs::read_dir(&opts.out_dir) else {
        return Ok(());
    };
    for dirent in read.flatten() {
        let name = dirent.file_name().to_string_lossy().into_owned();
        if prefixes.iter().any(|p| name.starts_with(p)) && !name.contains(&ours) {
            let _ = fs::remove_file(dirent.path());
        }
    }
    Ok(())
}

/// Reports stages and sweep progress to the status file; a cancel file or a shutdown stops
/// the job at the next check (between sweep batches and between stages).
struct JobObserver<'a> {
    status: &'a StatusFile,
    cancel: Option<PathBuf>,
    shutdown: &'a AtomicBool,
    /// A drop's folder and the inputs it was started with: a writer slower than --settle may
    /// still be appending, so a change (size or mtime) stops the job before it publishes.
    /// The folder the inputs' names are relative to, their stamps, and whether a stamp follows a
    /// link (drops: as `scan` stamps them; a job folder's links are stamped as links).
    inputs: Option<(PathBuf, &'a Fingerprint, bool)>,
    /// Set when `inputs` changed: the job is requeued, not failed or cancelled.
    inputs_changed: AtomicBool,
    /// A job folder and its (device, inode) when the job started: once it is gone (or another
    /// folder took its name) the job is abandoned and nothing is written or re-created there.
    folder: Option<(PathBuf, (u64, u64))>,
    /// Set when `folder` vanished.
    vanished: AtomicBool,
}

fn stage_start(stage: &str) -> f64 {
    STAGE_PROGRESS
        .iter()
        .find(|(s, _, _)| *s == stage)
        .map_or(0.0, |(_, p, _)| *p)
}

/// (device, inode) of what `path` names, not following a link.
fn identity(path: &Path) -> Option<(u64, u64)> {
    use std::os::unix::fs::MetadataExt;
    fs::symlink_metadata(path)
        .ok()
        .filter(|m| m.is_dir())
        .map(|m| (m.dev(), m.ino()))
}

impl JobObserver<'_> {
    /// Whether the job's folder is gone or replaced since the job started.
    fn folder_gone(&self) -> bool {
        let Some((dir, was)) = &self.folder else {
            return false;
        };
        let gone = identity(dir) != Some(*was);
        if gone {
            self.vanished.store(true, Ordering::Relaxed);
        }
        gone
    }

    /// Whether a drop's inputs differ from the fingerprint it was started with (two stats).
    fn inputs_changed(&self) -> bool {
        let Some((root, inputs, follow)) = &self.inputs else {
            return false;
        };
        let stat = |p: &Path| {
            if *follow {
                fs::metadata(p)
            } else {
                fs::symlink_metadata(p)
            }
        };
        let changed = inputs.iter().any(|f| match stat(&root.join(&f.file)) {
            Ok(m) => m.len() != f.size || super::scan::mtime_ns(&m) != f.mtime_ns,
            Err(_) => true,
        });
        if changed {
            self.inputs_changed.store(true, Ordering::Relaxed);
        }
        changed
    }
}

impl Observer for JobObserver<'_> {
    fn stage(&self, stage: &'static str) {
        let message = STAGE_PROGRESS
            .iter()
            .find(|(s, _, _)| *s == stage)
            .map_or(stage, |(_, _, m)| *m);
        self.status.stage(stage, stage_start(stage), message);
    }

    fn progress(&self, done: u64, total: u64) {
        let (lo, hi) = (stage_start("sweep"), stage_start("classify"));
        let f = done as f64 / total.max(1) as f64;
        self.status.progress(None, lo + (hi - lo) * f);
    }

    /// Also true once a drop's inputs changed: `pipeline::execute` asks this last, after
    /// staging every output and before renaming them into place, so a changed input means
    /// nothing is published.
    fn cancelled(&self) -> bool {
        self.shutdown.load(Ordering::Relaxed)
            || self.folder_gone()
            || self.cancel.as_deref().is_some_and(exists)
            || self.inputs_changed()
    }
}
