//! Reads the watched folder into a [`Snapshot`] for the detector: the top-level listing, the
//! inputs inside each committed job folder, and existing status files. Never looks inside
//! `.partial` folders or symlinked folders, and never follows links below the top level.

use std::fs;
use std::path::Path;
use std::time::UNIX_EPOCH;

use super::detector::{Entry, Snapshot};
use super::protocol::{self, FileStamp, Fingerprint, JobId, Role};

/// Deepest folder level read inside a job folder (buffers may sit in subfolders).
const MAX_DEPTH: usize = 4;
/// At most this many files are fingerprinted per job folder.
const MAX_FILES: usize = 10_000;

pub fn mtime_ns(meta: &fs::Metadata) -> i64 {
    meta.modified()
        .ok()
        .and_then(|t| t.duration_since(UNIX_EPOCH).ok())
        .map(|d| d.as_nanos() as i64)
        .unwrap_or(0)
}

/// One look at `root` (canonical). Entries that vanish while being read are left out.
pub fn scan(root: &Path) -> std::io::Result<Snapshot> {
    let mut snap = Snapshot::default();
    for dirent in fs::read_dir(root)? {
        let Ok(dirent) = dirent else { continue };
        let Ok(name) = dirent.file_name().into_string() else {
            continue; // not UTF-8: cannot be a protocol name
        };
        let path = dirent.path();
        let Ok(link_meta) = fs::symlink_metadata(&path) else {
            continue;
        };
        let symlink = link_meta.file_type().is_symlink();
        // A dangling link reads as a file of its own size (it fails confinement when run).
        let meta = if symlink {
            fs::metadata(&path).unwrap_or(link_meta)
        } else {
            link_meta
        };
        let entry = Entry {
            name: name.clone(),
            is_dir: meta.is_dir(),
            symlink,
            size: meta.len(),
            mtime_ns: mtime_ns(&meta),
        };
        match protocol::classify(&name, entry.is_dir) {
            Role::JobFolder if !symlink => {
                snap.folders.insert(name.clone(), folder_inputs(&path));
                record(&mut snap, JobId::Folder(name), root);
            }
            Role::DropGenerator(stem) => record(&mut snap, JobId::Drop(stem), root),
            _ => {}
        }
        snap.entries.push(entry);
    }
    snap.entries.sort_by(|a, b| a.name.cmp(&b.name));
    Ok(snap)
}

fn record(snap: &mut Snapshot, id: JobId, root: &Path) {
    // Only a plain file is read: a planted link would read through to outside the folder.
    let path = id.status_path(root);
    if !fs::symlink_metadata(&path).is_ok_and(|m| m.is_file()) {
        return;
    }
    if let Some(r) = fs::read(&path)
        .ok()
        .and_then(|b| protocol::parse_recorded(&b))
    {
        snap.recorded.insert(id, r);
    }
}

/// Every input file in a job folder: not hidden, not an output, not `cancel`; symlinks are
/// stamped as links (never followed here).
pub fn folder_inputs(dir: &Path) -> Fingerprint {
    let mut out = Vec::new();
    walk(dir, "", 0, &mut out);
    out.sort();
    out
}

fn walk(dir: &Path, prefix: &str, depth: usize, out: &mut Fingerprint) {
    let Ok(read) = fs::read_dir(dir) else { return };
    for dirent in read.flatten() {
        if out.len() >= MAX_FILES {
            return;
        }
        let Ok(name) = dirent.file_name().into_string() else {
            continue;
        };
        if name.starts_with('.')
            || (depth == 0 && (name == protocol::CANCEL || protocol::is_output_name(&name)))
        {
            continue;
        }
        let Ok(meta) = fs::symlink_metadata(dirent.path()) else {
            continue;
        };
        let rel = format!("{prefix}{name}");
        if meta.is_dir() {
            if depth < MAX_DEPTH {
                walk(&dirent.path(), &format!("{rel}/"), depth + 1, out);
            }
        } else {
            out.push(FileStamp {
                file: rel,
                size: meta.len(),
                mtime_ns: mtime_ns(&meta),
            });
        }
    }
}
