//! Files as the readers open them: regular files only (a FIFO or a device
//! would block or never end), headers read within a bound, and data files a
//! header names resolved inside the header's folder.

use crate::{IoError, ReadOptions};
use std::path::{Path, PathBuf};

/// What a path names when it is not a regular file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum FileKind {
    /// A directory.
    Directory,
    /// A named pipe (FIFO).
    Fifo,
    /// A socket.
    Socket,
    /// A character device (`/dev/null`, a terminal, ...).
    CharDevice,
    /// A block device.
    BlockDevice,
    /// Anything else that is not a regular file.
    Other,
}

impl FileKind {
    /// The kind of a file type, `None` for a regular file.
    pub fn of(ft: std::fs::FileType) -> Option<FileKind> {
        if ft.is_file() {
            return None;
        }
        if ft.is_dir() {
            return Some(FileKind::Directory);
        }
        #[cfg(unix)]
        {
            use std::os::unix::fs::FileTypeExt;
            if ft.is_fifo() {
                return Some(FileKind::Fifo);
            }
            if ft.is_socket() {
                return Some(FileKind::Socket);
            }
            if ft.is_char_device() {
                return Some(FileKind::CharDevice);
            }
            if ft.is_block_device() {
                return Some(FileKind::BlockDevice);
            }
        }
        Some(FileKind::Other)
    }
}

impl std::fmt::Display for FileKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            FileKind::Directory => "directory",
            FileKind::Fifo => "FIFO (named pipe)",
            FileKind::Socket => "socket",
            FileKind::CharDevice => "character device",
            FileKind::BlockDevice => "block device",
            FileKind::Other => "special file",
        })
    }
}

/// The metadata of `path` (following symbolic links) if it names a regular
/// file, else [`IoError::NotRegularFile`]. It never opens the path, so a FIFO
/// is refused at once instead of blocking the caller.
pub fn regular_file_metadata(path: &Path) -> Result<std::fs::Metadata, IoError> {
    let md = std::fs::metadata(path).map_err(|e| IoError::io(path, e))?;
    match FileKind::of(md.file_type()) {
        None => Ok(md),
        Some(kind) => Err(IoError::NotRegularFile {
            path: path.to_owned(),
            kind,
        }),
    }
}

/// Opens a regular file for reading: its metadata is checked first (opening a
/// FIFO would block), and the opened file again (the path may have changed in
/// between).
pub(crate) fn open_regular(path: &Path) -> Result<std::fs::File, IoError> {
    regular_file_metadata(path)?;
    let f = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
    let md = f.metadata().map_err(|e| IoError::io(path, e))?;
    match FileKind::of(md.file_type()) {
        None => Ok(f),
        Some(kind) => Err(IoError::NotRegularFile {
            path: path.to_owned(),
            kind,
        }),
    }
}

/// Longest JSON sidecar or NRRD header read (a forged file cannot make a
/// reader buffer gigabytes of "header").
pub(crate) const MAX_HEADER: usize = 1 << 20;

/// The data file `name` (as written in the header or sidecar `header`),
/// relative to the header's folder. Unless `opts` allows otherwise it must
/// resolve inside that folder: no absolute path or `..` leading out, and, when
/// it exists, its canonical path (symbolic links followed) must lie in the
/// folder's.
pub(crate) fn resolve_data_file(
    header: &Path,
    name: &Path,
    opts: &ReadOptions,
) -> Result<PathBuf, IoError> {
    let dir = header
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let data = dir.join(name);
    if opts.allow_outside_dir {
        return Ok(data);
    }
    let outside = || IoError::OutsideDir {
        path: header.to_owned(),
        data: data.clone(),
        dir: dir.to_owned(),
    };
    match (dir.canonicalize(), data.canonicalize()) {
        (Ok(cdir), Ok(cdata)) => {
            if cdata.starts_with(&cdir) {
                Ok(data)
            } else {
                Err(outside())
            }
        }
        // The folder exists (it holds the header) but the data file does not
        // resolve: judge the name alone, so that the error does not tell
        // whether a file outside the folder exists.
        _ => {
            let mut depth = 0i64;
            for c in name.components() {
                match c {
                    std::path::Component::Normal(_) => depth += 1,
                    std::path::Component::CurDir => {}
                    std::path::Component::ParentDir => depth -= 1,
                    std::path::Component::RootDir | std::path::Component::Prefix(_) => {
                        return Err(outside());
                    }
                }
                if depth < 0 {
                    return Err(outside());
                }
            }
            Ok(data)
        }
    }
}
