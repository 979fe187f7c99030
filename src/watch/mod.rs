//! `sweptvol watch DIR`: a folder as the interface to sweptvol (docs/exchange-protocol.md).
//!
//! `protocol` owns the names and file schemas, `scan` reads the folder, `detector` (pure)
//! decides which jobs are ready, `runner` runs one job, `status` writes its status file, `lock`
//! keeps one daemon per folder, `on_cluster` hands a job to SLURM instead of running it here, and `daemon` ties them into the event loop.

pub mod daemon;
pub mod detector;
pub mod executor;
pub mod lock;
pub mod on_cluster;
pub mod protocol;
pub mod runner;
pub mod scan;
pub mod status;

pub use daemon::{run, WatchOptions};
pub use executor::{Executor, SlurmExecutor};
