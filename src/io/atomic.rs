//! Write-then-rename: a reader of the folder never sees a half-written file under its final name.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{SystemTime, UNIX_EPOCH};

use anyhow::Context;

/// Create a fresh temporary sibling of `path` for writing: hidden, same folder (so the rename is
/// atomic on one filesystem), named `.<name>.tmp-<pid>-<n>` with n from a per-process counter
/// and the clock. Created exclusively (O_CREAT|O_EXCL, which never follows a symlink): a name
/// planted in advance, a link included, is skipped rather than written through.
pub fn create_temp(path: &Path) -> std::io::Result<(fs::File, PathBuf)> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy())
        .unwrap_or_default();
    let mut last = None;
    for _ in 0..16 {
        let nanos = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map(|d| d.subsec_nanos() as u64)
            .unwrap_or(0);
        let n = COUNTER.fetch_add(1, Ordering::Relaxed) << 30 | nanos;
        let tmp = path.with_file_name(format!(".{name}.tmp-{}-{n:x}", std::process::id()));
        match fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)
        {
            Ok(f) => return Ok((f, tmp)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => last = Some(e),
            Err(e) => return Err(e),
        }
    }
    Err(last.expect("sixteen tries"))
}

/// Whether files can be made in `dir`, or where it does not exist yet in the nearest folder
/// above it, found by making and removing a probe file (as permissions, a read-only
/// filesystem or a file in the way would refuse an output). Returns why not.
pub fn probe_writable(dir: &Path) -> Result<(), String> {
    let mut at = dir;
    while fs::symlink_metadata(at).is_err() {
        match at.parent() {
            Some(p) if !p.as_os_str().is_empty() => at = p,
            _ => {
                at = Path::new(".");
                break;
            }
        }
    }
    if !fs::metadata(at).is_ok_and(|m| m.is_dir()) {
        return Err(format!("{} is not a folder", at.display()));
    }
    match create_temp(&at.join(".sweptvol-probe")) {
        Ok((_, tmp)) => {
            let _ = fs::remove_file(tmp);
            Ok(())
        }
        Err(e) => Err(format!("cannot create files in {}: {e}", at.display())),
    }
}

/// Write `bytes` to `path` atomically: temporary file, flush, fsync, rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    let (mut f, tmp) =
        create_temp(path).with_context(|| format!("could not write {}", path.display()))?;
    let result = f
        .write_all(bytes)
        .and_then(|_| f.sync_all())
        .and_then(|_| fs::rename(&tmp, path));
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result.with_context(|| format!("could not write {}", path.display()))
}

/// Move a finished temporary file into place (fsync first).
pub fn commit(tmp: &Path, path: &Path) -> anyhow::Result<()> {
    let result = fs::File::open(tmp)
        .and_then(|f| f.sync_all())
        .and_then(|_| fs::rename(tmp, path));
    if result.is_err() {
        let _ = fs::remove_file(tmp);
    }
    result.with_context(|| format!("could not write {}", path.display()))
}

/// A set of outputs written under temporary names and renamed into place, one after another, by
/// [`Staged::commit`] once all are written. Dropped before committing (an error on the way), it removes its
/// temporary files, so a failed job leaves nothing behind. With a marker, a reader (and the
/// next run: [`clear_interrupted`]) can tell a set whose publishing was cut off.
#[derive(Default)]
pub struct Staged {
    /// (temporary, final) pairs not yet committed.
    files: Vec<(PathBuf, PathBuf)>,
    /// Written before the first rename and removed after the last, listing the final names.
    marker: Option<PathBuf>,
    /// Files of an earlier set this one replaces without a file of its own (an output no longer
    /// asked for): removed after the renames, listed in the marker with them.
    retired: Vec<PathBuf>,
}

/// Test hook: with `SWEPTVOL_TEST_ABORT_AFTER_RENAMES=k`, a commit aborts the process after its
/// k-th rename, as a crash or a kill would (tests/hostile.rs shows what the next run does).
const ABORT_AFTER_RENAMES: &str = "SWEPTVOL_TEST_ABORT_AFTER_RENAMES";

/// The final names a marker lists (one per line), if it exists.
fn marker_list(marker: &Path) -> Option<Vec<PathBuf>> {
    let text = fs::read_to_string(marker).ok()?;
    Some(
        text.lines()
            .filter(|l| !l.is_empty())
            .map(PathBuf::from)
            .collect(),
    )
}

/// The outputs an interrupted publish left under their final names: those `marker` lists, when
/// it exists (empty otherwise). They form no complete set, so a new run may replace them.
pub fn interrupted_set(marker: &Path) -> Vec<PathBuf> {
    marker_list(marker).unwrap_or_default()
}

/// Whether process `pid` is alive (signal 0 reaches it, or exists but is not ours).
fn alive(pid: u32) -> bool {
    // SAFETY: kill with signal 0 only checks that the process exists.
    let r = unsafe { libc::kill(pid as libc::pid_t, 0) };
    r == 0 || std::io::Error::last_os_error().raw_os_error() != Some(libc::ESRCH)
}

/// Undo what an interrupted publish left: the outputs `marker` lists, the temporary siblings of
/// each (`.<name>.tmp-<pid>-<n>` of a process no longer running), then the marker itself.
/// Nothing when there is no marker. Returns the files removed.
pub fn clear_interrupted(marker: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let Some(listed) = marker_list(marker) else {
        return Ok(Vec::new());
    };
    let mut removed = Vec::new();
    for path in &listed {
        if fs::symlink_metadata(path).is_ok_and(|m| !m.is_dir()) {
            fs::remove_file(path)
                .with_context(|| format!("could not remove {}", path.display()))?;
            removed.push(path.clone());
        }
        let (Some(dir), Some(name)) = (path.parent(), path.file_name()) else {
            continue;
        };
        let prefix = format!(".{}.tmp-", name.to_string_lossy());
        for e in fs::read_dir(dir).into_iter().flatten().flatten() {
            let file = e.file_name().to_string_lossy().into_owned();
            let Some(rest) = file.strip_prefix(&prefix) else {
                continue;
            };
            let pid = rest.split('-').next().and_then(|p| p.parse::<u32>().ok());
            if pid.is_some_and(|p| !alive(p)) {
                fs::remove_file(e.path())
                    .with_context(|| format!("could not remove {}", e.path().display()))?;
                removed.push(e.path());
            }
        }
    }
    fs::remove_file(marker).with_context(|| format!("could not remove {}", marker.display()))?;
    Ok(removed)
}

impl Staged {
    /// A set published under `marker` (see [`Staged`]).
    pub fn with_marker(marker: PathBuf) -> Self {
        Staged {
            files: Vec::new(),
            marker: Some(marker),
            retired: Vec::new(),
        }
    }

    /// Remove `path`, if it is a file, once the set is in place: an earlier set's output that
    /// this set does not write must not be read beside it.
    pub fn retire(&mut self, path: &Path) {
        self.retired.push(path.to_path_buf());
    }

    /// A fresh temporary file (see [`create_temp`]) to write `final_path`'s content to.
    pub fn create(&mut self, final_path: &Path) -> anyhow::Result<fs::File> {
        let (f, tmp) = create_temp(final_path)
            .with_context(|| format!("could not write {}", final_path.display()))?;
        self.files.push((tmp, final_path.to_path_buf()));
        Ok(f)
    }

    /// Stage `bytes` for `final_path`.
    pub fn write(&mut self, final_path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
        let mut f = self.create(final_path)?;
        f.write_all(bytes)
            .with_context(|| format!("could not write {}", final_path.display()))
    }

    /// Flush and rename every staged file into place, then flush the folders' entries. A final
    /// name that a rename cannot replace (a folder) is found before anything is renamed; the
    /// marker, if any, stands while the renames run.
    pub fn commit(mut self) -> anyhow::Result<()> {
        for (_, path) in &self.files {
            if fs::symlink_metadata(path).is_ok_and(|m| m.is_dir()) {
                anyhow::bail!(
                    "{} is a folder, so the output cannot take its place; nothing was published: remove or rename the folder",
                    path.display()
                );
            }
        }
        let mut dirs: Vec<PathBuf> = self
            .files
            .iter()
            .filter_map(|(_, p)| p.parent().map(Path::to_path_buf))
            .collect();
        dirs.dedup();
        if let Some(marker) = &self.marker {
            let list: String = self
                .files
                .iter()
                .map(|(_, p)| p)
                .chain(&self.retired)
                .map(|p| format!("{}\n", p.display()))
                .collect();
            write_atomic(marker, list.as_bytes())?;
        }
        let abort_after = std::env::var(ABORT_AFTER_RENAMES)
            .ok()
            .and_then(|v| v.parse::<usize>().ok());
        let mut renamed = 0;
        while let Some((tmp, path)) = self.files.first().cloned() {
            if abort_after == Some(renamed) {
                std::process::abort();
            }
            commit(&tmp, &path)?;
            self.files.remove(0);
            renamed += 1;
        }
        for path in &self.retired {
            if fs::symlink_metadata(path).is_ok_and(|m| !m.is_dir()) {
                fs::remove_file(path)
                    .with_context(|| format!("could not remove {}", path.display()))?;
            }
        }
        sync_dirs(&dirs)?;
        if let Some(marker) = &self.marker {
            fs::remove_file(marker)
                .with_context(|| format!("could not remove {}", marker.display()))?;
            sync_dirs(&dirs)?;
        }
        Ok(())
    }
}

/// Flush the folders' entries (renames and removals) to disk.
fn sync_dirs(dirs: &[PathBuf]) -> anyhow::Result<()> {
    for dir in dirs {
        #[cfg(unix)]
        fs::File::open(dir)
            .and_then(|d| d.sync_all())
            .with_context(|| format!("could not flush the folder {}", dir.display()))?;
    }
    Ok(())
}

impl Drop for Staged {
    fn drop(&mut self) {
        for (tmp, _) in &self.files {
            let _ = fs::remove_file(tmp);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Temporaries are fresh files with unique names, and a final name that is a planted link
    /// is replaced, never written through.
    #[cfg(unix)]
    #[test]
    fn temporaries_are_exclusive_and_links_are_replaced() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.bin");
        let (_, a) = create_temp(&path).unwrap();
        let (_, b) = create_temp(&path).unwrap();
        assert_ne!(a, b);
        assert!(a
            .file_name()
            .unwrap()
            .to_string_lossy()
            .starts_with(".out.bin.tmp-"));
        let outside = tempfile::tempdir().unwrap();
        let target = outside.path().join("victim");
        fs::write(&target, b"keep").unwrap();
        std::os::unix::fs::symlink(&target, &path).unwrap();
        write_atomic(&path, b"new").unwrap();
        assert_eq!(fs::read(&target).unwrap(), b"keep");
        assert_eq!(fs::read(&path).unwrap(), b"new");
        assert!(!fs::symlink_metadata(&path)
            .unwrap()
            .file_type()
            .is_symlink());
    }
}
