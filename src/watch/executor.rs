//! What the daemon, the runner and the SLURM path share: where jobs may run ([`Executor`]) and,
//! settled once at start, where they do ([`Runs`]); what every job sees ([`Context`]); a job
//! handed to a worker ([`QueuedJob`]); what a finished one records ([`Finished`]). It imports
//! none of those three modules, so none of them imports another's types.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use super::protocol::{Fingerprint, JobId};
use super::status::StatusFile;
use crate::clearance::Verdict;
use crate::input::grid::Accuracy;
use crate::pipeline::Report;
use crate::sweep::backend::{Backend, BackendChoice};

/// Where the daemon's jobs run.
#[derive(Clone, Debug, Default)]
pub enum Executor {
    /// Here, on the daemon's backend.
    #[default]
    Local,
    /// On a SLURM cluster, each job as `cluster submit` would queue it; the watched folder
    /// must be on a filesystem the nodes share.
    Slurm(SlurmExecutor),
}

#[derive(Clone, Debug)]
pub struct SlurmExecutor {
    pub shards: u32,
    /// The sweptvol the nodes run.
    pub binary: PathBuf,
    /// sbatch options for both jobs of every job.
    pub sbatch: Vec<String>,
    pub retries: u32,
}

/// Where the daemon's jobs run, settled once when it starts: here, on the backend it acquired
/// (one GPU device for the daemon's life), or on SLURM, where the nodes pick their own and
/// nothing is acquired here.
#[derive(Clone, Copy)]
pub enum Runs<'a> {
    Here(&'a Backend),
    Slurm(&'a SlurmExecutor),
}

/// What every job shares.
pub struct Context<'a> {
    /// The watched folder, canonical.
    pub root: &'a Path,
    pub runs: Runs<'a>,
    pub default_accuracy: Accuracy,
    pub max_input_bytes: u64,
    pub shutdown: &'a AtomicBool,
    /// The daemon's --backend, for jobs that run on SLURM.
    pub backend_choice: BackendChoice,
}

/// A job handed to a worker; its status file already says `queued`.
pub struct QueuedJob {
    pub id: JobId,
    pub inputs: Fingerprint,
    pub status: Arc<StatusFile>,
}

/// What the status file records of a finished job.
pub struct Finished {
    /// Output paths.
    pub outputs: Vec<PathBuf>,
    /// The report's timings.
    pub stages: Option<serde_json::Value>,
    pub message: String,
}

impl Finished {
    pub fn of(report: &Report) -> Finished {
        Finished {
            outputs: report.outputs.clone(),
            stages: serde_json::to_value(&report.timings).ok(),
            message: format!(
                "swept {} posed triangles on {}; {} triangles in the mesh{}",
                report.counts.posed_triangles,
                report.backend,
                report.mesh.triangles_final,
                clearance_words(report)
            ),
        }
    }
}

/// The clearance in a finished job's message: how many obstacles, how many may touch or touch,
/// and whether the required clearance is kept ("" without obstacles).
pub fn clearance_words(report: &Report) -> String {
    let Some(c) = &report.clearance else {
        return String::new();
    };
    let count = |v: Verdict| {
        c.obstacles
            .iter()
            .filter(|o| o.clearance.verdict == v)
            .count()
    };
    let least = c
        .obstacles
        .iter()
        .map(|o| o.clearance.lower)
        .fold(f64::INFINITY, f64::min);
    let mut words = format!(
        "; {} obstacle(s): {} clear, {} possible contact, {} CONTACT; clearance at least {least:.4}",
        c.obstacles.len(),
        count(Verdict::Clear),
        count(Verdict::PossibleContact),
        count(Verdict::Contact)
    );
    if let Some(x) = c.required {
        let kept = if c.passes { "kept" } else { "NOT KEPT" };
        words += &format!(" (required {x}: {kept})");
    }
    words
}
