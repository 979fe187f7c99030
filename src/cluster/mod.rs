//! A job on a SLURM cluster: `cluster submit` writes two batch scripts into the job's shard
//! folder (on a filesystem every node shares) and submits an array of shard sweeps
//! (`sweptvol sweep --job job.json --shard I/N`, the job read from a file in the shard folder)
//! and a merge (`sweptvol mesh`) that runs once all succeeded;
//! `cluster status` reads the shard manifests and asks SLURM about the jobs.
//!
//! Only the shards without a finished manifest of the same job are submitted, so a second
//! submission after a failure sweeps only what is missing.

pub mod slurm;

use std::fs;
use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::{Deserialize, Serialize};

use crate::error::InputError;
use crate::io::atomic;
use crate::io::shard_files::ShardId;
use crate::job::JobFile;
use crate::pipeline::shard::ShardProgress;
use crate::pipeline::{self, RunOptions};
use crate::sweep::backend::BackendChoice;

/// Where a job's shards, scripts, logs and submissions go unless asked otherwise: beside its
/// outputs, `<stem>.shards/` (`shards/` for an empty stem).
pub fn default_shard_dir(opts: &RunOptions) -> anyhow::Result<PathBuf> {
    let stem = pipeline::output_stem(opts)?;
    let name = if stem.is_empty() {
        "shards".to_string()
    } else {
        format!("{stem}.shards")
    };
    Ok(opts.out_dir.join(name))
}

/// What `cluster submit` was asked to do.
#[derive(Clone, Debug)]
pub struct SubmitOptions {
    /// The job, as `run` takes it; `out_dir` gets the merged outputs.
    pub run: RunOptions,
    pub shards: u32,
    pub shard_dir: PathBuf,
    /// The sweptvol every node runs (this one by default): a path valid on every node.
    pub binary: PathBuf,
    /// Extra `sbatch` options for both jobs (`--partition=x`), and for each alone.
    pub sbatch: Vec<String>,
    pub sweep_sbatch: Vec<String>,
    pub merge_sbatch: Vec<String>,
    /// Requeues of a failed shard before it counts as failed.
    pub retries: u32,
    /// Where each shard sweeps (on its node).
    pub backend: BackendChoice,
}

/// One submission, as recorded in `submissions.json` in the shard folder.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Submission {
    /// Seconds since the Unix epoch.
    pub at: f64,
    pub shards: u32,
    /// The shards this submission sweeps (1-based); the others were finished.
    pub swept: Vec<u32>,
    /// SLURM's ids: the array job (None when every shard was finished) and the merge.
    pub sweep_job: Option<String>,
    pub merge_job: String,
    pub out_dir: PathBuf,
    /// Posed triangles of the whole job (the unit of progress).
    pub posed_triangles: u64,
}

pub const SUBMISSIONS: &str = "submissions.json";

/// The job file the array's tasks read (`sweptvol sweep --job FILE --shard I/N`), in the shard
/// folder.
pub const JOB_FILE: &str = "job.json";

/// The job file of `run`, sweeping its shards into `shard_dir` on `backend`: the inputs (and
/// obstacle files) made absolute, the options as the run takes them.
pub fn job_file(
    run: &RunOptions,
    shard_dir: &Path,
    backend: BackendChoice,
) -> anyhow::Result<JobFile> {
    let abs = |p: &Path| -> anyhow::Result<PathBuf> {
        Ok(fs::canonicalize(p)
            .map_err(|e| InputError::new(p, format!("cannot open it: {e}"), "check the path"))?)
    };
    let mut options = run.job_options(Some(backend));
    for a in options.against.iter_mut().chain(&mut options.package_dir) {
        *a = abs(a)?;
    }
    Ok(JobFile {
        generator: abs(&run.generator)?,
        trajectory: abs(&run.trajectory)?,
        out: shard_dir.to_path_buf(),
        options,
        no_memory_check: !run.check_memory,
    })
}

/// Check the job here (inputs, options, outputs: errors before anything is queued), write the
/// scripts and submit the missing shards and the merge. Returns the submission.
pub fn submit(o: &SubmitOptions) -> anyhow::Result<Submission> {
    // Everything that can fail because of the user's files fails now, on the login node.
    let job = pipeline::prepare(&o.run)?;
    submit_prepared(o, &job)
}

/// [`submit`] of a job already prepared from `o.run` (the watcher prepares its jobs itself).
pub fn submit_prepared(o: &SubmitOptions, job: &pipeline::Prepared) -> anyhow::Result<Submission> {
    anyhow::ensure!(o.shards >= 1, "a job needs at least one shard");
    let posed_triangles = job.input.posed_triangles();
    let spec = o.run.spec()?;
    let dir = &o.shard_dir;
    fs::create_dir_all(dir.join("logs"))
        .with_context(|| format!("could not create the shard folder {}", dir.display()))?;
    let dir = fs::canonicalize(dir)?;
    let out_dir = {
        fs::create_dir_all(&o.run.out_dir).with_context(|| {
            format!(
                "could not create the output folder {}",
                o.run.out_dir.display()
            )
        })?;
        fs::canonicalize(&o.run.out_dir)?
    };
    // Shards already finished for this very job are kept; any other manifest there is refused.
    let missing = match ShardProgress::read(std::slice::from_ref(&dir)) {
        Err(_) => (1..=o.shards).collect(), // no manifests yet
        Ok(p) => {
            if let Some((path, why)) = p.foreign.first() {
                return Err(InputError::new(
                    path,
                    why.clone(),
                    "give this job its own --shard-dir, or remove the old shards",
                )
                .into());
            }
            let theirs = &p.done[0].1;
            if theirs.job != spec || theirs.shard.count != o.shards {
                return Err(InputError::new(
                    &p.done[0].0,
                    format!(
                        "the shard folder holds shards of another job or split (of {})",
                        theirs.shard.count
                    ),
                    "give this job its own --shard-dir, or remove the old shards",
                )
                .into());
            }
            p.missing
        }
    };
    // Markers of an earlier submission: its merge's exit, and the failures of shards now retried.
    let _ = fs::remove_file(dir.join(slurm::MERGE_EXIT));
    for &i in &missing {
        let stem = ShardId {
            index: i,
            count: o.shards,
        }
        .stem();
        let _ = fs::remove_file(dir.join(format!("{stem}.{}", slurm::FAILED_SUFFIX)));
    }
    // The tasks read the job from a file: nothing turns the options back into arguments.
    let job_path = dir.join(JOB_FILE);
    let file = job_file(&o.run, &dir, o.backend)?;
    atomic::write_atomic(&job_path, &serde_json::to_vec_pretty(&file)?)?;
    let sweep: Vec<String> = vec![
        "sweep".into(),
        "--job".into(),
        job_path.to_string_lossy().into_owned(),
    ];
    let mut mesh: Vec<String> = vec![
        "mesh".into(),
        "--from".into(),
        dir.to_string_lossy().into_owned(),
    ];
    mesh.extend(["--out".into(), out_dir.to_string_lossy().into_owned()]);
    // The merge takes the name the shards were swept with (bare names included).
    if let Some(name) = o.run.job.name.as_deref().filter(|n| !n.is_empty()) {
        mesh.extend(["--name".into(), name.into()]);
    }
    if o.run.overwrite {
        mesh.push("--overwrite".into());
    }
    let sweep_script = dir.join("sweep.sbatch");
    let merge_script = dir.join("merge.sbatch");
    atomic::write_atomic(
        &sweep_script,
        slurm::sweep_script(&o.binary, &sweep, &dir, o.shards, o.retries).as_bytes(),
    )?;
    atomic::write_atomic(
        &merge_script,
        slurm::merge_script(&o.binary, &mesh, &dir).as_bytes(),
    )?;
    let name = format!("sweptvol-{}", pipeline::output_stem(&o.run)?);
    let sweep_job = if missing.is_empty() {
        None
    } else {
        let list: Vec<String> = missing.iter().map(|i| i.to_string()).collect();
        let mut args = vec![
            format!("--array={}", list.join(",")),
            format!("--job-name={name}"),
            format!("--output={}/logs/sweep-%a.log", dir.display()),
            "--open-mode=append".into(),
            "--requeue".into(),
        ];
        args.extend(o.sbatch.iter().chain(&o.sweep_sbatch).cloned());
        Some(slurm::sbatch(&args, &sweep_script)?)
    };
    let mut args = vec![
        format!("--job-name={name}-merge"),
        format!("--output={}/logs/merge.log", dir.display()),
        "--open-mode=append".into(),
    ];
    if let Some(id) = &sweep_job {
        args.push(format!("--dependency=afterok:{id}"));
        args.push("--kill-on-invalid-dep=yes".into());
    }
    args.extend(o.sbatch.iter().chain(&o.merge_sbatch).cloned());
    let merge_job = match slurm::sbatch(&args, &merge_script) {
        Ok(id) => id,
        Err(e) => {
            if let Some(id) = &sweep_job {
                let _ = slurm::cancel(std::slice::from_ref(id));
            }
            return Err(e.context("the merge job was not submitted, so the shards were cancelled"));
        }
    };
    let submission = Submission {
        at: crate::io::clock::unix_now(),
        shards: o.shards,
        swept: missing,
        sweep_job,
        merge_job,
        out_dir,
        posed_triangles,
    };
    let mut all = read_submissions(&dir);
    all.push(submission.clone());
    atomic::write_atomic(&dir.join(SUBMISSIONS), &serde_json::to_vec_pretty(&all)?)?;
    Ok(submission)
}

/// The submissions recorded in a shard folder, oldest first (none if unreadable).
pub fn read_submissions(dir: &Path) -> Vec<Submission> {
    fs::read(dir.join(SUBMISSIONS))
        .ok()
        .and_then(|b| serde_json::from_slice(&b).ok())
        .unwrap_or_default()
}

/// Where a cluster job stands, from the shard folder (and SLURM where it still knows the jobs).
#[derive(Clone, Debug, Serialize)]
pub struct ClusterStatus {
    pub shard_dir: PathBuf,
    pub shards: u32,
    pub done: Vec<u32>,
    pub missing: Vec<u32>,
    /// Posed triangles swept by the finished shards, and in the whole job (0 when no shard
    /// finished and no submission is recorded).
    pub posed_triangles_done: u64,
    pub posed_triangles: u64,
    /// Shards whose last try failed: (index, what the script recorded).
    pub failed: Vec<(u32, String)>,
    /// Manifests of another job in the folder, and why.
    pub foreign: Vec<(PathBuf, String)>,
    pub last_submission: Option<Submission>,
    /// SLURM's view of the last submission's jobs: (id, state, reason).
    pub queue: Vec<(String, String, String)>,
    /// The merge's exit code, once it ran.
    pub merge_exit: Option<i32>,
}

impl ClusterStatus {
    /// True when the merge ran and succeeded.
    pub fn merged(&self) -> bool {
        self.merge_exit == Some(0)
    }
}

/// Read the status of the job whose shards are in `dir`. `shards` gives the count when no
/// shard has finished yet (else the last submission's, else 0).
pub fn status(dir: &Path, ask_slurm: bool) -> anyhow::Result<ClusterStatus> {
    let last = read_submissions(dir).pop();
    let progress = ShardProgress::read(&[dir.to_path_buf()]).ok();
    let count = progress
        .as_ref()
        .and_then(|p| p.done.first().map(|(_, m)| m.shard.count))
        .or(last.as_ref().map(|s| s.shards))
        .unwrap_or(0);
    let done: Vec<u32> = progress
        .as_ref()
        .map(|p| p.done.iter().map(|(_, m)| m.shard.index).collect())
        .unwrap_or_default();
    let failed = (1..=count)
        .filter_map(|i| {
            let path = dir.join(format!(
                "{}.{}",
                ShardId { index: i, count }.stem(),
                slurm::FAILED_SUFFIX
            ));
            fs::read_to_string(path)
                .ok()
                .map(|t| (i, t.trim().to_string()))
        })
        .collect();
    let queue = match (&last, ask_slurm) {
        (Some(s), true) => {
            let ids: Vec<String> = s.sweep_job.iter().chain([&s.merge_job]).cloned().collect();
            slurm::queue_states(&ids).unwrap_or_default()
        }
        _ => Vec::new(),
    };
    let merge_exit = fs::read_to_string(dir.join(slurm::MERGE_EXIT))
        .ok()
        .and_then(|t| t.trim().parse().ok());
    Ok(ClusterStatus {
        shard_dir: dir.to_path_buf(),
        shards: count,
        missing: (1..=count).filter(|i| !done.contains(i)).collect(),
        posed_triangles_done: progress
            .as_ref()
            .map(|p| p.done.iter().map(|(_, m)| m.posed_triangles).sum())
            .unwrap_or(0),
        posed_triangles: progress
            .as_ref()
            .and_then(|p| p.done.first().map(|(_, m)| m.job_posed_triangles))
            .or(last.as_ref().map(|s| s.posed_triangles))
            .unwrap_or(0),
        done,
        failed,
        foreign: progress.map(|p| p.foreign).unwrap_or_default(),
        last_submission: last,
        queue,
        merge_exit,
    })
}

/// The status as a few lines for a person.
pub fn describe(st: &ClusterStatus) -> String {
    let list = |v: &[u32]| {
        v.iter()
            .map(|i| i.to_string())
            .collect::<Vec<_>>()
            .join(", ")
    };
    let mut out = format!("shard folder: {}\n", st.shard_dir.display());
    if st.shards == 0 {
        out += "no shard has finished and no submission is recorded here\n";
        return out;
    }
    let share = if st.posed_triangles > 0 {
        format!(
            " ({:.1}% of the posed triangles)",
            100.0 * st.posed_triangles_done as f64 / st.posed_triangles as f64
        )
    } else {
        String::new()
    };
    out += &format!("shards: {} of {} done{share}\n", st.done.len(), st.shards);
    if !st.missing.is_empty() {
        out += &format!("missing: {}\n", list(&st.missing));
    }
    for (i, why) in &st.failed {
        out += &format!("failed: shard {i}: {why}\n");
    }
    for (p, why) in &st.foreign {
        out += &format!("not of this job: {}: {why}\n", p.display());
    }
    if let Some(s) = &st.last_submission {
        out += &format!(
            "last submission: shards {} as array job {}, merge job {}\n",
            list(&s.swept),
            s.sweep_job.as_deref().unwrap_or("(none: all finished)"),
            s.merge_job
        );
        if st.queue.is_empty() {
            out += "SLURM: none of these jobs is queued or running\n";
        }
        for (id, state, reason) in &st.queue {
            let reason = if reason.is_empty() || reason == "None" {
                String::new()
            } else {
                format!(" ({reason})")
            };
            out += &format!("SLURM: job {id}: {state}{reason}\n");
        }
        out += &match st.merge_exit {
            Some(0) => format!("merged: outputs in {}\n", s.out_dir.display()),
            Some(rc) => format!(
                "the merge failed (exit {rc}): see {}\n",
                st.shard_dir.join("logs/merge.log").display()
            ),
            None => "not merged yet\n".to_string(),
        };
    }
    out
}

/// Shard indices as ranges: "1-3, 5" (`shard::index_ranges`).
pub fn list(v: &[u32]) -> String {
    crate::pipeline::shard::index_ranges(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The array tasks may run in another folder: every input path of the job file is absolute,
    /// the obstacle files' too.
    #[test]
    fn job_files_hold_absolute_paths_only() {
        let tmp = tempfile::tempdir().unwrap();
        let here = tmp.path().canonicalize().unwrap();
        for f in ["g.glb", "t.csv", "wall.glb"] {
            fs::write(here.join(f), b"x").unwrap();
        }
        let rel = |f: &str| here.join(".").join(f);
        let mut run = RunOptions::of_job(
            &crate::job::JobOptions {
                against: vec![rel("wall.glb")],
                ..Default::default()
            },
            rel("g.glb"),
            rel("t.csv"),
            here.join("out"),
            crate::input::grid::Accuracy::DEFAULT,
        );
        run.check_memory = true;
        let file = job_file(&run, &here, BackendChoice::Cpu).unwrap();
        assert_eq!(file.generator, here.join("g.glb"));
        assert_eq!(file.trajectory, here.join("t.csv"));
        assert_eq!(file.options.against, vec![here.join("wall.glb")]);
        run.job.against = vec![here.join("missing.glb")];
        assert!(job_file(&run, &here, BackendChoice::Cpu).is_err());
    }
}
