//! One daemon per folder: an exclusive `flock` on `DIR/.sweptvol/lock` (released by the kernel
//! when the process dies, `kill -9` included) and a heartbeat in `DIR/.sweptvol/daemon.json`
//! that clients read to tell whether a daemon is alive.

use std::fs::{self, File, OpenOptions};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use anyhow::{bail, Context};
use serde::{Deserialize, Serialize};

use super::protocol::CONTROL_DIR;
use super::status::unix_now;
use crate::io::atomic;

/// daemon.json is rewritten this often; a heartbeat older than three intervals means no daemon.
pub const HEARTBEAT: Duration = Duration::from_secs(2);

/// `DIR/.sweptvol/daemon.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct DaemonInfo {
    /// "running", or "stopped" after a clean exit.
    pub state: String,
    pub pid: u32,
    pub sweptvol_version: String,
    /// Seconds since the Unix epoch.
    pub started_at: f64,
    pub heartbeat_at: f64,
    pub heartbeat_interval_s: f64,
}

/// Held while the daemon runs: the lock file stays open and the heartbeat thread runs until
/// [`DaemonLock::release`] (or drop).
pub struct DaemonLock {
    _file: File,
    info_path: PathBuf,
    info: DaemonInfo,
    stop: Arc<AtomicBool>,
    heartbeat: Option<JoinHandle<()>>,
}

/// Take the folder's lock or say who holds it.
pub fn acquire(root: &Path) -> anyhow::Result<DaemonLock> {
    let dir = root.join(CONTROL_DIR);
    // The control folder must be a real folder of DIR: a link would put the lock and the
    // heartbeat outside it.
    if fs::symlink_metadata(&dir).is_ok_and(|m| !m.is_dir()) {
        anyhow::bail!(
            "{} is not a folder (a symbolic link or a file): remove it, and sweptvol watch creates the folder it needs",
            dir.display()
        );
    }
    fs::create_dir_all(&dir).with_context(|| format!("could not create {}", dir.display()))?;
    let lock_path = dir.join("lock");
    // O_NOFOLLOW: a lock planted as a symbolic link must not make the daemon create or touch
    // the link's target outside DIR (opening a link with it fails with ELOOP).
    let file = OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .custom_flags(libc::O_NOFOLLOW)
        .open(&lock_path)
        .map_err(|e| {
            if fs::symlink_metadata(&lock_path).is_ok_and(|m| m.file_type().is_symlink()) {
                anyhow::anyhow!(
                    "{} is a symbolic link: sweptvol watch writes nothing outside {}; remove the link and start again",
                    lock_path.display(),
                    root.display()
                )
            } else {
                anyhow::Error::new(e).context(format!("could not open {}", lock_path.display()))
            }
        })?;
    let info_path = dir.join(super::protocol::HEARTBEAT_FILE);
    if !try_lock(&file).with_context(|| format!("could not lock {}", lock_path.display()))? {
        let holder = fs::read(&info_path)
            .ok()
            .and_then(|b| serde_json::from_slice::<DaemonInfo>(&b).ok())
            .map(|i| format!(" (pid {}, sweptvol {})", i.pid, i.sweptvol_version))
            .unwrap_or_default();
        bail!(
            "another sweptvol watch is already running on {}{holder}; stop it first (SIGTERM), or watch another folder",
            root.display()
        );
    }
    let now = unix_now();
    let info = DaemonInfo {
        state: "running".into(),
        pid: std::process::id(),
        sweptvol_version: env!("CARGO_PKG_VERSION").into(),
        started_at: now,
        heartbeat_at: now,
        heartbeat_interval_s: HEARTBEAT.as_secs_f64(),
    };
    write_info(&info_path, &info)?;
    let stop = Arc::new(AtomicBool::new(false));
    let heartbeat = {
        let (stop, path, mut info) = (stop.clone(), info_path.clone(), info.clone());
        std::thread::Builder::new()
            .name("heartbeat".into())
            .spawn(move || {
                let tick = Duration::from_millis(100);
                let mut waited = Duration::ZERO;
                while !stop.load(Ordering::Relaxed) {
                    std::thread::sleep(tick);
                    waited += tick;
                    if waited >= HEARTBEAT {
                        waited = Duration::ZERO;
                        info.heartbeat_at = unix_now();
                        if let Err(e) = write_info(&path, &info) {
                            tracing::warn!("heartbeat: {e:#}");
                        }
                    }
                }
            })?
    };
    Ok(DaemonLock {
        _file: file,
        info_path,
        info,
        stop,
        heartbeat: Some(heartbeat),
    })
}

fn write_info(path: &Path, info: &DaemonInfo) -> anyhow::Result<()> {
    atomic::write_atomic(path, &serde_json::to_vec_pretty(info)?)
}

impl DaemonLock {
    /// Stop the heartbeat and mark daemon.json stopped; the lock goes with the file.
    pub fn release(mut self) {
        self.stop_heartbeat();
        self.info.state = "stopped".into();
        self.info.heartbeat_at = unix_now();
        if let Err(e) = write_info(&self.info_path, &self.info) {
            tracing::warn!("{e:#}");
        }
    }

    fn stop_heartbeat(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.heartbeat.take() {
            let _ = h.join();
        }
    }
}

impl Drop for DaemonLock {
    fn drop(&mut self) {
        self.stop_heartbeat();
    }
}

/// Exclusive, non-blocking: Ok(false) when another process holds it.
#[cfg(unix)]
fn try_lock(file: &File) -> std::io::Result<bool> {
    use std::os::unix::io::AsRawFd;
    // SAFETY: flock on a file descriptor this `File` owns and keeps open.
    let r = unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) };
    if r == 0 {
        return Ok(true);
    }
    let e = std::io::Error::last_os_error();
    if e.raw_os_error() == Some(libc::EWOULDBLOCK) {
        Ok(false)
    } else {
        Err(e)
    }
}

#[cfg(not(unix))]
fn try_lock(_file: &File) -> std::io::Result<bool> {
    Err(std::io::Error::other(
        "sweptvol watch needs flock (Linux, macOS)",
    ))
}
