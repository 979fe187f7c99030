//! A job of the watched folder run on SLURM (`watch --executor slurm`): submitted as
//! `cluster submit` would (shards into `.sweptvol/shards/<job>/` of the watched folder, the merge
//! writing the outputs into the job's usual place), then watched until the merge ends. A cancel
//! or a shutdown cancels the SLURM jobs; finished shards stay and a re-run skips them.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, Context as _};

use super::executor::{Context, Finished, QueuedJob, SlurmExecutor};
use super::protocol::{ClusterProgress, JobId};
use crate::cluster::{self, slurm, SubmitOptions};
use crate::pipeline::{Prepared, Report};
use crate::sweep::backend::BackendChoice;
use crate::sweep::{Cancelled, Observer};

/// How often the shard folder is read, and SLURM asked whether the jobs still exist.
const POLL: Duration = Duration::from_millis(500);
const ASK_SLURM: Duration = Duration::from_secs(10);

/// The shard folder of a job: hidden in the watched folder's own `.sweptvol/`.
pub fn shard_dir(root: &Path, id: &JobId) -> PathBuf {
    let name = match id {
        JobId::Folder(n) => format!("folder-{n}"),
        JobId::Drop(n) => format!("drop-{n}"),
    };
    root.join(".sweptvol").join("shards").join(name)
}

/// Submit the prepared job and wait for its merge; the outputs are then in place as a local run leaves them.
pub fn run(
    ctx: &Context,
    job: &QueuedJob,
    slurm_opts: &SlurmExecutor,
    prepared: &Prepared,
    backend: BackendChoice,
    observer: &dyn Observer,
) -> anyhow::Result<Finished> {
    let opts = &prepared.opts;
    let dir = shard_dir(ctx.root, &job.id);
    observer.stage("sweep");
    let submit = SubmitOptions {
        run: opts.clone(),
        shards: slurm_opts.shards,
        shard_dir: dir.clone(),
        binary: slurm_opts.binary.clone(),
        sbatch: slurm_opts.sbatch.clone(),
        sweep_sbatch: Vec::new(),
        merge_sbatch: Vec::new(),
        retries: slurm_opts.retries,
        backend,
    };
    let submission = cluster::submit_prepared(&submit, prepared)?;
    let ids: Vec<String> = submission
        .sweep_job
        .iter()
        .chain([&submission.merge_job])
        .cloned()
        .collect();
    tracing::info!(
        "{}: on SLURM: shards {:?} as array job {}, merge job {}",
        job.id,
        submission.swept,
        submission.sweep_job.as_deref().unwrap_or("(none)"),
        submission.merge_job
    );
    let relative = dir
        .strip_prefix(ctx.root)
        .unwrap_or(&dir)
        .to_string_lossy()
        .into_owned();
    let mut progress = ClusterProgress {
        shards: submission.shards,
        shards_done: 0,
        sweep_job: submission.sweep_job.clone(),
        merge_job: submission.merge_job.clone(),
        shard_dir: relative,
    };
    job.status.update(|s| {
        s.message = format!(
            "on SLURM: {} shards as array job {}, merge job {}",
            submission.shards,
            submission.sweep_job.as_deref().unwrap_or("(all finished)"),
            submission.merge_job
        );
        s.cluster = Some(progress.clone());
    });
    let mut asked = Instant::now();
    loop {
        std::thread::sleep(POLL);
        if observer.cancelled() {
            slurm::cancel(&ids)?;
            return Err(Cancelled.into());
        }
        let ask = asked.elapsed() >= ASK_SLURM;
        if ask {
            asked = Instant::now();
        }
        let st = cluster::status(&dir, ask)?;
        if st.done.len() as u32 != progress.shards_done {
            progress.shards_done = st.done.len() as u32;
            job.status.update(|s| s.cluster = Some(progress.clone()));
            let share = st.posed_triangles_done as f64 / st.posed_triangles.max(1) as f64;
            observer.progress((share * 1e6) as u64, 1_000_000);
        }
        if let Some(rc) = st.merge_exit {
            if rc != 0 {
                bail!(
                    "the merge on SLURM (job {}) failed with exit {rc}: {}",
                    submission.merge_job,
                    log_tail(&dir.join("logs/merge.log"))
                );
            }
            // The merge wrote the outputs `prepare` named, the report among them.
            let path = &prepared.outputs.report;
            let report: Report = serde_json::from_slice(&std::fs::read(path)?)
                .with_context(|| format!("the merge's report {} is unreadable", path.display()))?;
            let mut finished = Finished::of(&report);
            finished.message = format!(
                "swept {} posed triangles on SLURM ({}); {} triangles in the mesh{}",
                report.counts.posed_triangles,
                report.backend,
                report.mesh.triangles_final,
                super::executor::clearance_words(&report)
            );
            return Ok(finished);
        }
        if let Some((i, why)) = st.failed.first() {
            let _ = slurm::cancel(&ids);
            bail!("shard {i} of {} failed on SLURM: {why}", st.shards);
        }
        if ask && st.queue.is_empty() {
            // SLURM knows none of the jobs; the merge may have written its exit code just now.
            std::thread::sleep(POLL);
            if cluster::status(&dir, false)?.merge_exit.is_none() {
                bail!(
                    "SLURM no longer has the jobs ({}) and the merge did not run (cancelled outside sweptvol?); logs in {}",
                    ids.join(", "),
                    dir.join("logs").display()
                );
            }
        }
    }
}

/// The last lines of a log, for an error message.
fn log_tail(path: &Path) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let lines: Vec<&str> = text.lines().rev().take(3).collect();
    if lines.is_empty() {
        format!("no log at {}", path.display())
    } else {
        format!(
            "{} (from {})",
            lines.into_iter().rev().collect::<Vec<_>>().join(" / "),
            path.display()
        )
    }
}
