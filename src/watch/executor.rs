//! What the daemon, the runner and the SLURM path share: where jobs run ([`Executor`]), what
//! every job sees ([`Context`]), a job handed to a worker ([`QueuedJob`]) and what a finished
//! one records ([`Finished`]). It imports none of them, so they import no one another.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use super::protocol::{Fingerprint, JobId};
use super::status::StatusFile;
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

/// What every job shares.
pub struct Context<'a> {
    /// The watched folder, canonical.
    pub root: &'a Path,
    /// Acquired once at start (one GPU device for the daemon's life).
    pub backend: &'a Backend,
    pub default_accuracy: Accuracy,
    pub max_input_bytes: u64,
    pub shutdown: &'a AtomicBool,
    /// Where jobs run: here on `backend`, or on SLURM.
    pub executor: &'a Executor,
    /// The daemon's --backend, for jobs that run elsewhere.
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
                "swept {} posed triangles on {}; {} triangles in the mesh",
                report.counts.posed_triangles, report.backend, report.mesh.triangles_final
            ),
        }
    }
}
