//! Temporary files of builds in progress.
//!
//! Every temporary a build writes (the store being written, the level files of
//! a banded build) is named `.<output name>.brickray-partial.<pid>-<seq>` in the
//! output's folder, created exclusively, and recorded in a process-wide
//! registry until it is renamed to the output or removed. So:
//!
//! * [`remove_partial_files`] removes every temporary of the builds in
//!   progress in this process (the CLI calls it on SIGINT, SIGTERM and SIGHUP),
//!   and makes later attempts to create or persist one fail with
//!   [`StoreError::Interrupted`];
//! * a build removes the stale temporaries it finds in its output folder:
//!   those whose process is gone (`/proc/<pid>` does not exist), or that carry
//!   this process's id but belong to none of its builds. Where `/proc` is not
//!   available, those older than a day.

use crate::error::StoreError;
use std::ffi::{OsStr, OsString};
use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, MutexGuard};
use std::time::Duration;

/// The tag between the output's name and `<pid>-<seq>`.
pub(crate) const TAG: &str = ".brickray-partial.";

/// Bytes of the output's name kept in a temporary's name (file names are
/// limited to 255 bytes).
const NAME_BYTES: usize = 160;

/// Age past which a temporary is stale when process ids cannot be checked.
const STALE_AGE: Duration = Duration::from_secs(24 * 3600);

struct Registry {
    paths: Vec<PathBuf>,
    closed: bool,
}

static REGISTRY: Mutex<Registry> = Mutex::new(Registry {
    paths: Vec::new(),
    closed: false,
});
static SEQ: AtomicU64 = AtomicU64::new(0);

fn registry() -> MutexGuard<'static, Registry> {
    REGISTRY.lock().unwrap_or_else(|e| e.into_inner())
}

/// The folder a file at `out` is in.
pub(crate) fn parent_dir(out: &Path) -> &Path {
    out.parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}

/// A temporary file of a build: removed on drop unless persisted.
#[derive(Debug)]
pub(crate) struct PartialFile {
    path: PathBuf,
    file: File,
    persisted: bool,
}

impl PartialFile {
    /// Creates a new temporary for the output `out`, in its folder.
    pub(crate) fn create(out: &Path) -> Result<PartialFile, StoreError> {
        let dir = parent_dir(out);
        let name = truncated_name(out.file_name().unwrap_or(OsStr::new("store")));
        let pid = std::process::id();
        loop {
            let seq = SEQ.fetch_add(1, Ordering::Relaxed);
            let mut n = OsString::from(".");
            n.push(&name);
            n.push(format!("{TAG}{pid}-{seq}"));
            let path = dir.join(n);
            // Created and registered under the lock, so that a signal handler
            // running `remove_partial_files` sees every temporary.
            let mut reg = registry();
            if reg.closed {
                return Err(StoreError::Interrupted);
            }
            match std::fs::OpenOptions::new()
                .read(true)
                .write(true)
                .create_new(true)
                .open(&path)
            {
                Ok(file) => {
                    reg.paths.push(path.clone());
                    return Ok(PartialFile {
                        path,
                        file,
                        persisted: false,
                    });
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
                Err(e) => return Err(StoreError::io(&path, e)),
            }
        }
    }

    pub(crate) fn file(&self) -> &File {
        &self.file
    }

    pub(crate) fn path(&self) -> &Path {
        &self.path
    }

    /// Renames the temporary to `out`. Under the registry's lock: a signal
    /// handler either finds the temporary (and removes it) or finds the
    /// output complete.
    pub(crate) fn persist(mut self, out: &Path) -> Result<(), StoreError> {
        let mut reg = registry();
        if reg.closed {
            return Err(StoreError::Interrupted);
        }
        std::fs::rename(&self.path, out).map_err(|e| StoreError::io(out, e))?;
        reg.paths.retain(|p| p != &self.path);
        self.persisted = true;
        Ok(())
    }
}

impl Drop for PartialFile {
    fn drop(&mut self) {
        if self.persisted {
            return;
        }
        let mut reg = registry();
        let _ = std::fs::remove_file(&self.path);
        reg.paths.retain(|p| p != &self.path);
    }
}

/// Removes the temporary files of every build in progress in this process
/// and makes those builds fail ([`StoreError::Interrupted`]) instead of
/// creating or persisting others. For signal handlers and other shutdown
/// paths: call it just before the process exits. Returns how many files were
/// removed.
pub fn remove_partial_files() -> usize {
    let mut reg = registry();
    reg.closed = true;
    let paths = std::mem::take(&mut reg.paths);
    paths
        .iter()
        .filter(|p| std::fs::remove_file(p).is_ok())
        .count()
}

/// The signals this process ignores (bit `n - 1` for signal `n`), from
/// `/proc/self/status`; none where that cannot be read. A signal ignored at
/// start (`nohup`, a background job of a non-interactive shell) should stay
/// ignored: signal handlers that remove partial files skip those.
pub fn ignored_signals() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("SigIgn:"))
                .and_then(|m| u64::from_str_radix(m.trim(), 16).ok())
        })
        .unwrap_or(0)
}

/// At most `NAME_BYTES` bytes of a file name (on a character boundary where
/// the name is UTF-8).
fn truncated_name(name: &OsStr) -> OsString {
    #[cfg(unix)]
    {
        use std::os::unix::ffi::OsStrExt;
        let b = name.as_bytes();
        if b.len() <= NAME_BYTES {
            return name.to_owned();
        }
        let mut end = NAME_BYTES;
        if let Ok(s) = std::str::from_utf8(b) {
            while !s.is_char_boundary(end) {
                end -= 1;
            }
        }
        OsStr::from_bytes(&b[..end]).to_owned()
    }
    #[cfg(not(unix))]
    {
        let s = name.to_string_lossy();
        let mut end = s.len().min(NAME_BYTES);
        while !s.is_char_boundary(end) {
            end -= 1;
        }
        OsString::from(&s[..end])
    }
}

/// The process id of a temporary's file name, `None` when the name is not one.
pub(crate) fn temporary_pid(name: &OsStr) -> Option<u32> {
    let b = name.as_encoded_bytes();
    let tag = TAG.as_bytes();
    if b.first() != Some(&b'.') || b.len() < tag.len() {
        return None;
    }
    let at = (0..=b.len() - tag.len())
        .rev()
        .find(|&i| &b[i..i + tag.len()] == tag)?;
    let tail = std::str::from_utf8(&b[at + tag.len()..]).ok()?;
    let (pid, seq) = tail.split_once('-')?;
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|c| c.is_ascii_digit());
    if !digits(pid) || !digits(seq) {
        return None;
    }
    pid.parse().ok()
}

/// Whether process `pid` exists; `None` when that cannot be told.
fn process_alive(pid: u32) -> Option<bool> {
    let proc = Path::new("/proc");
    if !proc.join("self").exists() {
        return None;
    }
    Some(proc.join(pid.to_string()).exists())
}

/// Removes the stale temporaries in `dir` (see the module docs). Returns how
/// many were removed. Errors are ignored: this is housekeeping.
pub(crate) fn remove_stale(dir: &Path) -> usize {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    let me = std::process::id();
    let mut removed = 0;
    for entry in entries.flatten() {
        let Some(pid) = temporary_pid(&entry.file_name()) else {
            continue;
        };
        // Only regular files (never a link, a folder or a device).
        let Ok(md) = entry.path().symlink_metadata() else {
            continue;
        };
        if !md.is_file() {
            continue;
        }
        let path = entry.path();
        let stale = if pid == me {
            // Ours only if one of this process's builds has it open.
            let reg = registry();
            !reg.paths
                .iter()
                .any(|p| p.file_name() == path.file_name() && same_dir(parent_dir(p), dir))
        } else {
            match process_alive(pid) {
                Some(alive) => !alive,
                None => md
                    .modified()
                    .ok()
                    .and_then(|t| t.elapsed().ok())
                    .is_some_and(|age| age > STALE_AGE),
            }
        };
        if stale && std::fs::remove_file(&path).is_ok() {
            removed += 1;
        }
    }
    removed
}

fn same_dir(a: &Path, b: &Path) -> bool {
    a == b || matches!((a.canonicalize(), b.canonicalize()), (Ok(x), Ok(y)) if x == y)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn temporary_names_parse() {
        let ok = |s: &str| temporary_pid(OsStr::new(s));
        assert_eq!(ok(".v.brs.brickray-partial.123-0"), Some(123));
        assert_eq!(ok("..brickray-partial.7-99"), Some(7));
        assert_eq!(ok(".a.brickray-partial.b.brickray-partial.5-1"), Some(5));
        for bad in [
            "v.brs.brickray-partial.123-0",
            ".v.brs.brickray-partial.123",
            ".v.brs.brickray-partial.-0",
            ".v.brs.brickray-partial.12a-0",
            ".v.brs.brickray-partial.12-",
            ".v.brs.brickray-partial.99999999999-0",
            ".v.brs",
        ] {
            assert_eq!(ok(bad), None, "{bad}");
        }
    }

    #[test]
    fn long_names_are_truncated_on_a_boundary() {
        let long = "é".repeat(200);
        let t = truncated_name(OsStr::new(&long));
        assert!(t.len() <= NAME_BYTES);
        assert!(t.to_str().is_some());
        assert_eq!(truncated_name(OsStr::new("v.brs")), "v.brs");
    }
}
