//! One job's `status.json`, replaced atomically (temporary sibling, fsync, rename) at each
//! change. Progress updates are rate-limited; state changes are always written.

use std::path::PathBuf;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use super::protocol::{ErrorInfo, Fingerprint, State, Status, Timings};
use crate::io::atomic;

/// Progress is written at most this often.
const PROGRESS_INTERVAL: Duration = Duration::from_millis(250);

pub use crate::io::clock::unix_now;

/// Writes one job's status. Shared by the threads of a job; the lock also keeps two writes
/// from racing on the same temporary name.
pub struct StatusFile {
    path: PathBuf,
    inner: Mutex<(Status, Option<Instant>)>,
}

impl StatusFile {
    pub fn new(path: PathBuf, name: String, inputs: Fingerprint) -> Self {
        let status = Status {
            state: State::Queued,
            stage: "queued".into(),
            progress: 0.0,
            message: String::new(),
            name,
            sweptvol_version: env!("CARGO_PKG_VERSION").into(),
            timings: Timings::default(),
            error: None,
            inputs,
            outputs: Vec::new(),
            cluster: None,
        };
        StatusFile {
            path,
            inner: Mutex::new((status, None)),
        }
    }

    /// Change the status with `f` and write it; a failed write is logged, not fatal (the job's
    /// outputs matter more than its status).
    pub fn update(&self, f: impl FnOnce(&mut Status)) {
        let mut guard = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        let (status, last) = &mut *guard;
        f(status);
        if let Some(started) = status.timings.started_at {
            let end = status.timings.finished_at.unwrap_or_else(unix_now);
            status.timings.seconds = Some(end - started);
        }
        *last = Some(Instant::now());
        // A job folder removed while its job runs: nothing to write to (the runner abandons
        // the job); the folder is never made again for a status.
        if self.path.parent().is_some_and(|d| !d.is_dir()) {
            return;
        }
        let write = serde_json::to_vec_pretty(status)
            .map_err(anyhow::Error::from)
            .and_then(|bytes| atomic::write_atomic(&self.path, &bytes));
        if let Err(e) = write {
            tracing::error!("could not write the job status: {e:#}");
        }
    }

    /// Progress within the running stage; written only if the last write is old enough.
    pub fn progress(&self, stage: Option<&str>, progress: f64) {
        {
            let guard = self.inner.lock().unwrap_or_else(|e| e.into_inner());
            let recent = guard.1.is_some_and(|t| t.elapsed() < PROGRESS_INTERVAL);
            if recent && stage.is_none() {
                return;
            }
        }
        self.update(|s| {
            if let Some(stage) = stage {
                s.stage = stage.into();
            }
            s.progress = progress.clamp(0.0, 1.0);
        });
    }

    /// A new stage: its name, where it starts on the progress scale, and what it does.
    pub fn stage(&self, stage: &str, progress: f64, message: &str) {
        self.update(|s| {
            s.stage = stage.into();
            s.progress = progress.clamp(0.0, 1.0);
            s.message = message.into();
        });
    }

    pub fn queued(&self, message: &str) {
        self.update(|s| {
            s.state = State::Queued;
            s.stage = "queued".into();
            s.progress = 0.0;
            s.message = message.into();
            s.timings = Timings {
                queued_at: Some(unix_now()),
                ..Timings::default()
            };
            s.error = None;
            s.outputs.clear();
        });
    }

    pub fn running(&self) {
        self.update(|s| {
            s.state = State::Running;
            s.stage = "reading".into();
            s.progress = 0.0;
            s.message = "reading the inputs".into();
            s.timings.started_at = Some(unix_now());
        });
    }

    /// A final state (or `Queued` again after a shutdown).
    pub fn finish(&self, state: State, message: String, error: Option<ErrorInfo>) {
        self.update(|s| {
            s.state = state;
            s.stage = String::new();
            if state == State::Done {
                s.progress = 1.0;
            }
            s.message = message;
            s.error = error;
            if state.is_finished() {
                s.timings.finished_at = Some(unix_now());
            }
        });
    }

    pub fn name(&self) -> String {
        self.inner
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .0
            .name
            .clone()
    }
}
