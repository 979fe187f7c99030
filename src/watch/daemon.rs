//! The daemon loop: folder events (notify, debounced) and a periodic full rescan feed the
//! detector; the jobs it starts go, in order, to a queue served by worker threads sharing one
//! backend. SIGINT/SIGTERM stop intake, stop the running jobs at a safe point (left `queued`
//! so the next start re-runs them) and exit cleanly.
//!
//! Data flow: scan -> Snapshot -> Detector -> Action::Run -> status `queued` -> queue ->
//! worker -> runner::run -> status -> finished id back to the loop -> Detector::finished.

use std::collections::VecDeque;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use anyhow::{bail, Context as _};
use notify_debouncer_mini::{new_debouncer, notify::RecursiveMode};

use super::detector::{Action, Detector};
use super::executor::{Context, Executor, QueuedJob, Runs};
use super::lock;
use super::protocol::JobId;
use super::runner;
use super::scan;
use super::status::StatusFile;
use crate::input::grid::Accuracy;
use crate::sweep::backend::{Backend, BackendChoice};

/// Events closer together than this are handled as one.
const DEBOUNCE: Duration = Duration::from_millis(200);
/// The loop looks at finished jobs and the shutdown flag at least this often.
const TICK: Duration = Duration::from_millis(100);

/// What `sweptvol watch` was asked to do.
#[derive(Clone, Debug)]
pub struct WatchOptions {
    pub dir: PathBuf,
    /// Process what is waiting (including drops still settling), then exit.
    pub once: bool,
    pub settle: Duration,
    pub rescan: Duration,
    pub jobs: usize,
    pub backend: BackendChoice,
    /// For jobs whose job.json names neither resolution nor tolerance, and for drops.
    pub default_accuracy: Accuracy,
    pub max_input_bytes: u64,
    pub executor: Executor,
}

/// The work queue between the loop and the workers.
#[derive(Default)]
struct Queue {
    jobs: VecDeque<QueuedJob>,
    closed: bool,
}

/// Run the daemon until `--once` has nothing left, or a signal. Ok on a clean exit.
pub fn run(opts: &WatchOptions) -> anyhow::Result<()> {
    let root = opts
        .dir
        .canonicalize()
        .with_context(|| format!("cannot watch {}: the folder must exist", opts.dir.display()))?;
    if !root.is_dir() {
        bail!("cannot watch {}: not a folder", root.display());
    }
    let lock = lock::acquire(&root)?;

    let shutdown = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        // A second signal while shutting down exits at once (code 1).
        signal_hook::flag::register_conditional_shutdown(signal, 1, shutdown.clone())?;
        signal_hook::flag::register(signal, shutdown.clone())?;
    }

    // The one place the daemon's backend is settled: acquired here, or none on SLURM (the
    // nodes pick their own; this machine only waits).
    let backend = match &opts.executor {
        Executor::Slurm(_) => None,
        Executor::Local => Some(Backend::acquire(opts.backend)?),
    };
    if let Some(Backend::Cpu { reason }) = &backend {
        if opts.backend == BackendChoice::Auto {
            tracing::warn!("{reason}");
        }
    }
    let runs = match (&backend, &opts.executor) {
        (_, Executor::Slurm(s)) => Runs::Slurm(s),
        (Some(b), Executor::Local) => Runs::Here(b),
        (None, Executor::Local) => unreachable!("a local daemon acquired its backend"),
    };
    let place = match runs {
        Runs::Here(b) => b.describe(),
        Runs::Slurm(s) => format!("SLURM in {} shards each", s.shards),
    };
    let workers = match runs {
        Runs::Here(Backend::Gpu(_)) if opts.jobs > 1 => {
            tracing::warn!(
                "--jobs {} ignored: jobs share one GPU, one at a time",
                opts.jobs
            );
            1
        }
        _ => opts.jobs.max(1),
    };
    tracing::info!(
        "watching {} on {} ({workers} job{} at a time){}",
        root.display(),
        place,
        if workers == 1 { "" } else { "s" },
        if opts.once { "; --once" } else { "" }
    );

    let (event_tx, events) = mpsc::channel();
    let mut debouncer = new_debouncer(DEBOUNCE, event_tx)?;
    debouncer
        .watcher()
        .watch(&root, RecursiveMode::NonRecursive)
        .with_context(|| format!("cannot watch {} for changes", root.display()))?;

    let queue = (Mutex::new(Queue::default()), Condvar::new());
    let (done_tx, done) = mpsc::channel::<JobId>();
    let ctx = Context {
        root: &root,
        runs,
        default_accuracy: opts.default_accuracy,
        max_input_bytes: opts.max_input_bytes,
        shutdown: &shutdown,
        backend_choice: opts.backend,
    };
    let start = Instant::now();
    let mut detector = Detector::new(opts.settle);
    let mut in_flight = 0usize;
    let mut fatal = None;

    std::thread::scope(|s| {
        for i in 0..workers {
            let (queue, ctx, done_tx) = (&queue, &ctx, done_tx.clone());
            std::thread::Builder::new()
                .name(format!("job-{i}"))
                .spawn_scoped(s, move || worker(queue, ctx, done_tx))
                .expect("spawn a worker thread");
        }

        let mut next_rescan = Instant::now(); // a full scan at start
        loop {
            if shutdown.load(Ordering::Relaxed) {
                tracing::info!("shutting down: stopping the running jobs at a safe point");
                break;
            }
            while let Ok(id) = done.try_recv() {
                detector.finished(&id);
                in_flight -= 1;
                next_rescan = Instant::now(); // --once decides after a fresh look
            }
            let mut changed = false;
            while let Ok(event) = events.try_recv() {
                match event {
                    Ok(_) => changed = true,
                    // Lost events (queue overflow): the rescan is the safety net.
                    Err(e) => {
                        tracing::warn!("watching: {e}; rescanning");
                        changed = true;
                    }
                }
            }
            let now = Instant::now();
            let due = detector.next_deadline().is_some_and(|d| start + d <= now);
            if changed || due || now >= next_rescan {
                next_rescan = now + opts.rescan;
                let snap = match scan::scan(&root) {
                    Ok(snap) => snap,
                    Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                        fatal = Some(anyhow::anyhow!(
                            "the watched folder {} is gone",
                            root.display()
                        ));
                        shutdown.store(true, Ordering::Relaxed); // stop the running jobs too
                        break;
                    }
                    Err(e) => {
                        tracing::error!("cannot read {}: {e}", root.display());
                        std::thread::sleep(TICK);
                        continue;
                    }
                };
                let actions = detector.observe(start.elapsed(), &snap);
                let started = actions.len();
                for action in actions {
                    match action {
                        Action::Run { id, inputs } => {
                            tracing::info!("{id}: queued");
                            let status = StatusFile::new(
                                id.status_path(&root),
                                id.name().to_string(),
                                inputs.clone(),
                            );
                            status.queued("");
                            in_flight += 1;
                            let job = QueuedJob {
                                id,
                                inputs,
                                status: Arc::new(status),
                            };
                            queue.0.lock().expect("queue").jobs.push_back(job);
                            queue.1.notify_one();
                        }
                        Action::Refuse { name, reason } => {
                            tracing::error!("{}: refused: {reason}", root.join(name).display());
                        }
                    }
                }
                if opts.once && started == 0 && in_flight == 0 && detector.is_idle() {
                    tracing::info!("--once: nothing left to do");
                    break;
                }
            }
            // Sleep until an event, a settle deadline, the next rescan or the next tick.
            let mut wake = next_rescan.min(Instant::now() + TICK);
            if let Some(d) = detector.next_deadline() {
                wake = wake.min(start + d);
            }
            if let Ok(event) = events.recv_timeout(wake.saturating_duration_since(Instant::now())) {
                if let Err(e) = event {
                    tracing::warn!("watching: {e}");
                }
                next_rescan = Instant::now(); // something changed: look now
            }
        }
        // Jobs not started stay `queued` on disk: the next start picks them up.
        let mut q = queue.0.lock().expect("queue");
        q.closed = true;
        q.jobs.clear();
        drop(q);
        queue.1.notify_all();
    });
    drop(debouncer);
    lock.release();
    tracing::info!("stopped");
    fatal.map_or(Ok(()), Err)
}

/// Take jobs in order until the queue closes; a job's panic is caught in `runner::run`.
fn worker(queue: &(Mutex<Queue>, Condvar), ctx: &Context, done: mpsc::Sender<JobId>) {
    loop {
        let job = {
            let mut q = queue.0.lock().expect("queue");
            loop {
                if let Some(job) = q.jobs.pop_front() {
                    break job;
                }
                if q.closed {
                    return;
                }
                q = queue.1.wait(q).expect("queue");
            }
        };
        tracing::info!("{}: running", job.id);
        runner::run(ctx, &job);
        let _ = done.send(job.id);
    }
}
