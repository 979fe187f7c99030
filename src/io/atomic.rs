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
/// temporary files, so a failed job leaves nothing behind.
#[derive(Default)]
pub struct Staged {
    /// (temporary, final) pairs not yet committed.
    files: Vec<(PathBuf, PathBuf)>,
}

impl Staged {
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

    /// Flush and rename every staged file into place, then flush the folders' entries.
    pub fn commit(mut self) -> anyhow::Result<()> {
        let dirs: Vec<PathBuf> = self
            .files
            .iter()
            .filter_map(|(_, p)| p.parent().map(Path::to_path_buf))
            .collect();
        while let Some((tmp, path)) = self.files.first().cloned() {
            commit(&tmp, &path)?;
            self.files.remove(0);
        }
        for dir in dirs {
            #[cfg(unix)]
            fs::File::open(&dir)
                .and_then(|d| d.sync_all())
                .with_context(|| format!("could not flush the folder {}", dir.display()))?;
        }
        Ok(())
    }
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
