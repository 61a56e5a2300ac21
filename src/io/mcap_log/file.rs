//! The log's file on disk: why this exists is that a flight log must never
//! be lost or written over. A log is always a new file (`create_new`): a
//! name already taken, a crash log from the last run under a fixed
//! `log.path` say, gets a suffix (`-1`, `-2`, …) instead of being truncated.
//! A file that cannot be created (a read-only card, a missing mount) is
//! tried again at each write, so the daemon flies without its log, raises
//! the alarm, and starts writing as soon as it can. Old finished logs are
//! deleted, oldest first, to keep the directory under a total size, as
//! ArduPilot's and PX4's loggers do; an unfinished log (a crash) is never
//! deleted here.

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Suffixes tried for a name that is taken.
const MAX_SUFFIX: u32 = 999;

/// Creates `path` as a new file, or the first of `stem-1.ext`, `stem-2.ext`,
/// … that does not exist yet; never opens an existing regular file. A
/// missing directory is not created: it is most likely a card not mounted
/// yet, and a log written to the root filesystem under its mount point would
/// be hidden once it mounts; the error raises the alarm and the daemon tries
/// again. An existing device or pipe (`/dev/full`, a FIFO to another logger)
/// is a stream, not a file to keep: it is opened without blocking (a FIFO
/// nobody reads fails, to be tried again, rather than hang the daemon).
///
/// A directory at `path` (one that appeared since the daemon started: a
/// card mounted late) holds the log under the default name.
pub fn create_unique(path: &Path) -> std::io::Result<(File, PathBuf)> {
    if path.is_dir() {
        return create_unique(&path.join(super::expand_path(super::DEFAULT_NAME)));
    }
    if let Ok(m) = std::fs::metadata(path) {
        if !m.is_file() {
            use std::os::unix::fs::OpenOptionsExt;
            return OpenOptions::new()
                .write(true)
                .custom_flags(libc::O_NONBLOCK)
                .open(path)
                .map(|f| (f, path.to_path_buf()));
        }
    }
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        if !dir.is_dir() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::NotFound,
                format!(
                    "the log directory '{}' does not exist (a card not mounted?)",
                    dir.display()
                ),
            ));
        }
    }
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let ext = path
        .extension()
        .map(|e| format!(".{}", e.to_string_lossy()))
        .unwrap_or_default();
    for n in 0..=MAX_SUFFIX {
        let candidate = if n == 0 {
            path.to_path_buf()
        } else {
            path.with_file_name(format!("{stem}-{n}{ext}"))
        };
        match OpenOptions::new().write(true).create_new(true).open(&candidate) {
            Ok(f) => return Ok((f, candidate)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(e),
        }
    }
    Err(std::io::Error::new(
        std::io::ErrorKind::AlreadyExists,
        format!("'{}' and {MAX_SUFFIX} suffixed names are all taken", path.display()),
    ))
}

/// The flight log's file: created on first use under a unique name, and
/// tried again at each write while it cannot be (the writer's failure path
/// keeps the bytes in memory meanwhile and raises the alarm).
pub(super) struct LogFile {
    /// The name asked for.
    wanted: PathBuf,
    file: Option<(File, PathBuf)>,
}

impl LogFile {
    /// Tries to create the file at once, so that its name is known and
    /// said at start; a failure is only remembered (see [`Self::path`]).
    pub(super) fn new(wanted: PathBuf) -> (Self, Result<PathBuf, std::io::Error>) {
        let mut f = Self { wanted, file: None };
        let opened = f.file().map(|_| ()).map(|()| f.path().to_path_buf());
        (f, opened)
    }

    /// The file's path: the name it was created under, else the one wanted.
    pub(super) fn path(&self) -> &Path {
        self.file.as_ref().map_or(&self.wanted, |(_, p)| p)
    }

    /// The file, created now if it was not yet.
    fn file(&mut self) -> std::io::Result<&mut File> {
        if self.file.is_none() {
            let (file, path) = create_unique(&self.wanted)?;
            if path != self.wanted {
                tracing::warn!(wanted = %self.wanted.display(), path = %path.display(),
                    "the log's name is taken (a log of an earlier run): writing to a new name, never over it");
            }
            self.file = Some((file, path));
        }
        match &mut self.file {
            Some((f, _)) => Ok(f),
            None => Err(std::io::ErrorKind::NotFound.into()),
        }
    }
}

impl Write for LogFile {
    fn write(&mut self, data: &[u8]) -> std::io::Result<usize> {
        self.file()?.write(data)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.file()?.flush()
    }
}

/// Creates `path` for a tool's output (`replay --out`, `log recover`):
/// refused if it is the input, and, unless `overwrite`, if it exists.
pub fn create_output(path: &Path, input: &Path, overwrite: bool) -> Result<File, OutputError> {
    if same_file(path, input) {
        return Err(OutputError::IsInput(path.to_path_buf()));
    }
    let mut o = OpenOptions::new();
    o.write(true);
    if overwrite {
        o.create(true).truncate(true);
    } else {
        o.create_new(true);
    }
    o.open(path).map_err(|source| match source.kind() {
        std::io::ErrorKind::AlreadyExists => OutputError::Exists(path.to_path_buf()),
        _ => OutputError::Io {
            path: path.to_path_buf(),
            source,
        },
    })
}

/// Whether `a` and `b` name the same existing file (by canonical path; on
/// Unix also by device and inode, which sees through hard links).
pub fn same_file(a: &Path, b: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        if let (Ok(x), Ok(y)) = (std::fs::metadata(a), std::fs::metadata(b)) {
            return x.dev() == y.dev() && x.ino() == y.ino();
        }
    }
    matches!((a.canonicalize(), b.canonicalize()), (Ok(x), Ok(y)) if x == y)
}

/// Why a tool's output file was refused.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    #[error("'{0}' is the input: a tool never writes over the log it reads; give another output path")]
    IsInput(PathBuf),
    #[error("'{0}' exists: give another output path, or --force to replace it")]
    Exists(PathBuf),
    #[error("'{path}': {source}")]
    Io { path: PathBuf, source: std::io::Error },
}

/// Whether the file name `name` is one the log name pattern `pattern` (a
/// file name, with `%Y` four digits and `%m %d %H %M %S` two) writes,
/// with or without a `-N` suffix before its extension.
pub fn matches_pattern(name: &str, pattern: &str) -> bool {
    let split = |s: &str| match s.rsplit_once('.') {
        Some((a, b)) => (a.to_string(), b.to_string()),
        None => (s.to_string(), String::new()),
    };
    let ((stem, ext), (pstem, pext)) = (split(name), split(pattern));
    if ext != pext {
        return false;
    }
    let fits = |s: &str| -> bool {
        let (mut a, mut p) = (s.as_bytes(), pstem.as_bytes());
        while let Some(&c) = p.first() {
            if c == b'%' && p.len() >= 2 {
                let n = if p[1] == b'Y' { 4 } else { 2 };
                if a.len() < n || !a[..n].iter().all(u8::is_ascii_digit) {
                    return false;
                }
                a = &a[n..];
                p = &p[2..];
            } else {
                if a.first() != Some(&c) {
                    return false;
                }
                a = &a[1..];
                p = &p[1..];
            }
        }
        a.is_empty()
    };
    fits(&stem)
        || stem
            .rsplit_once('-')
            .is_some_and(|(base, n)| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()) && fits(base))
}

/// Deletes the oldest finished logs in `dir` whose names the log name
/// pattern `pattern` writes (see [`matches_pattern`]), other than `keep`,
/// until the logs there take at most `max_total_bytes`. Unfinished logs
/// (crash logs) count towards the total but are never deleted. Returns the
/// files deleted.
pub fn enforce_total(dir: &Path, pattern: &str, keep: &Path, max_total_bytes: u64) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut logs: Vec<(std::time::SystemTime, u64, PathBuf, bool)> = entries
        .filter_map(Result::ok)
        .take(100_000)
        .filter(|e| {
            let n = e.file_name();
            matches_pattern(&n.to_string_lossy(), pattern)
        })
        .filter_map(|e| {
            let m = e.metadata().ok()?;
            m.is_file().then_some(())?;
            let p = e.path();
            let finished = matches!(super::is_finished(&p), Ok(true));
            Some((m.modified().ok()?, m.len(), p, finished))
        })
        .collect();
    let mut total: u64 = logs.iter().map(|l| l.1).sum();
    logs.sort_by_key(|l| l.0);
    let mut deleted = Vec::new();
    for (_, len, p, finished) in logs {
        if total <= max_total_bytes {
            break;
        }
        if !finished || same_file(&p, keep) {
            continue;
        }
        match std::fs::remove_file(&p) {
            Ok(()) => {
                total = total.saturating_sub(len);
                tracing::info!(path = %p.display(), bytes = len, "deleted the oldest finished flight log (log.max_total_mb)");
                deleted.push(p);
            }
            Err(e) => tracing::warn!(path = %p.display(), error = %e, "could not delete an old flight log"),
        }
    }
    if total > max_total_bytes {
        tracing::warn!(
            total_mb = total >> 20,
            limit_mb = max_total_bytes >> 20,
            "the flight logs exceed log.max_total_mb with nothing finished left to delete (unfinished crash logs are kept)"
        );
    }
    deleted
}
