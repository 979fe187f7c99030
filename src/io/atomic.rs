//! Write-then-rename: a reader of the folder never sees a half-written file under its final name.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::Context;

/// A temporary sibling name for `path`: hidden, unique to this process, same folder (so the
/// rename is atomic on one filesystem).
pub fn temp_sibling(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.tmp-{}", std::process::id()))
}

/// Write `bytes` to `path` atomically: temporary file, flush, fsync, rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    let tmp = temp_sibling(path);
    let result = (|| {
        let mut f = fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        fs::rename(&tmp, path)
    })();
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

/// A set of outputs written under temporary names and renamed into place together by
/// [`Staged::commit`]. Dropped before committing (an error on the way), it removes its
/// temporary files, so a failed job leaves nothing behind.
#[derive(Default)]
pub struct Staged {
    /// (temporary, final) pairs not yet committed.
    files: Vec<(PathBuf, PathBuf)>,
}

impl Staged {
    /// The temporary path to write `final_path`'s content to.
    pub fn path_for(&mut self, final_path: &Path) -> PathBuf {
        let tmp = temp_sibling(final_path);
        self.files.push((tmp.clone(), final_path.to_path_buf()));
        tmp
    }

    /// Stage `bytes` for `final_path`.
    pub fn write(&mut self, final_path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
        let tmp = self.path_for(final_path);
        fs::write(&tmp, bytes).with_context(|| format!("could not write {}", tmp.display()))
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
