//! The feature socket: a Unix-domain stream socket on which one camera front
//! end at a time writes newline-delimited JSON frames,
//! `{"v":1,"t_us":..,"cam":0,"features":[[landmark_id,u_px,v_px],...]}`.
//!
//! It exists to keep everything the front end sends, and everyone else who
//! can reach the socket, at the boundary:
//!
//! - Every line is checked here (length, syntax, version, feature count,
//!   finite numbers); a bad line is rejected with a reason and the
//!   connection goes on. A front end may disconnect and reconnect at any time.
//! - One writer is served at a time. A client that connects while another is
//!   served waits in the listener's accept backlog (it is not accepted, and
//!   what it writes waits in its socket buffer) and is served, in the order
//!   of arrival, when the one served goes away.
//! - A writer is dropped when it has sent no accepted frame for
//!   `features.idle_timeout_s` (wall time) since it connected or since its
//!   last accepted frame — silence, a line never finished and lines that are
//!   all rejected alike (`feature_idle_dropped`, with a warning naming its
//!   pid and uid) — so a client that connected first and never writes cannot
//!   keep the real front end out.
//! - [`bind`] refuses a directory another user could tamper with: it must be
//!   a real directory (not a symlink, and not reached through one), owned by
//!   the daemon's effective user and not writable by group or others. A
//!   missing directory is created with mode 0700.
//! - The socket file's device and inode are kept after binding; at shutdown
//!   the path is removed only if it is still that socket. Anything else found
//!   there is left alone (`feature_socket_replaced`, with a warning).

use std::os::unix::fs::{DirBuilderExt, FileTypeExt, MetadataExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::Deserialize;
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::net::{UnixListener, UnixStream};
use tokio::sync::mpsc;

use super::Counters;

/// One camera frame as received.
#[derive(Clone, Debug, PartialEq)]
pub struct FeatureFrame {
    /// Timestamp in the front end's clock (µs).
    pub t_us: u64,
    pub cam: u32,
    /// `(landmark_id, u_px, v_px)`, distorted pixels.
    pub features: Vec<(u64, f64, f64)>,
}

/// Why a line was rejected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LineError {
    #[error("line longer than {0} bytes")]
    TooLong(usize),
    #[error("not valid JSON for a feature frame: {0}")]
    Syntax(String),
    #[error("unsupported version {0} (expected 1)")]
    Version(u32),
    #[error("{0} features exceed the limit of {1}")]
    TooManyFeatures(usize, usize),
    #[error("non-finite pixel for landmark {0}")]
    NonFinite(u64),
}

impl LineError {
    /// Short counter name.
    pub fn reason(&self) -> &'static str {
        match self {
            LineError::TooLong(_) => "feature_line_too_long",
            LineError::Syntax(_) => "feature_line_syntax",
            LineError::Version(_) => "feature_line_version",
            LineError::TooManyFeatures(..) => "feature_line_too_many",
            LineError::NonFinite(_) => "feature_non_finite",
        }
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Wire {
    v: u32,
    t_us: u64,
    #[serde(default)]
    cam: u32,
    features: Vec<(u64, f64, f64)>,
}

/// Parses and checks one line (without its newline).
pub fn parse_line(line: &[u8], max_features: usize) -> Result<FeatureFrame, LineError> {
    let w: Wire = serde_json::from_slice(line).map_err(|e| LineError::Syntax(e.to_string()))?;
    if w.v != 1 {
        return Err(LineError::Version(w.v));
    }
    if w.features.len() > max_features {
        return Err(LineError::TooManyFeatures(w.features.len(), max_features));
    }
    if let Some(f) = w.features.iter().find(|f| !f.1.is_finite() || !f.2.is_finite()) {
        return Err(LineError::NonFinite(f.0));
    }
    Ok(FeatureFrame {
        t_us: w.t_us,
        cam: w.cam,
        features: w.features,
    })
}

/// Errors that stop the socket from being served.
#[derive(Debug, thiserror::Error)]
pub enum SocketError {
    #[error("features.socket '{0}': the path exists and is not a socket; remove it or set features.socket")]
    NotASocket(PathBuf),
    #[error("features.socket '{0}': another process is listening on it; stop it or set features.socket")]
    InUse(PathBuf),
    #[error(
        "features.socket '{path}': its directory '{dir}' is a symlink (to '{target}'), which another user could \
         point elsewhere; use a real directory only this user can write, such as /run/cmsckf (systemd \
         RuntimeDirectory=cmsckf), or create one with `install -d -m 0700 -o {euid} DIR`"
    )]
    DirSymlink {
        path: PathBuf,
        dir: PathBuf,
        target: PathBuf,
        euid: u32,
    },
    #[error(
        "features.socket '{path}': its directory '{dir}' resolves to '{resolved}' (through a symlink or `..`); \
         give the socket's real path, under '{resolved}', in features.socket, or use a directory only this \
         user can write, such as /run/cmsckf (systemd RuntimeDirectory=cmsckf)"
    )]
    DirResolves {
        path: PathBuf,
        dir: PathBuf,
        resolved: PathBuf,
    },
    #[error("features.socket '{path}': '{dir}' is not a directory; remove it or set features.socket")]
    DirNotADirectory { path: PathBuf, dir: PathBuf },
    #[error(
        "features.socket '{path}': its directory '{dir}' is owned by uid {owner}, not by this daemon's user \
         (uid {euid}), so another user controls the socket; create it with `install -d -m 0700 -o {euid} \
         {dir}`, or use a directory only this user can write, such as /run/cmsckf (systemd \
         RuntimeDirectory=cmsckf)"
    )]
    DirOwner {
        path: PathBuf,
        dir: PathBuf,
        owner: u32,
        euid: u32,
    },
    #[error(
        "features.socket '{path}': its directory '{dir}' is writable by group or others (mode {mode:04o}), so \
         another user could replace the socket; run `chmod go-w {dir}`, or use a directory only this user can \
         write, such as /run/cmsckf (systemd RuntimeDirectory=cmsckf)"
    )]
    DirWritable { path: PathBuf, dir: PathBuf, mode: u32 },
    #[error("features.socket '{path}': {source}")]
    Io { path: PathBuf, source: std::io::Error },
}

/// The daemon's effective user id.
fn euid() -> u32 {
    // SAFETY: geteuid(2) takes nothing, touches no memory of ours and
    // cannot fail.
    unsafe { libc::geteuid() }
}

/// Checks that the socket's directory is one only this user can change:
/// a real directory (not a symlink, not reached through one), owned by the
/// effective user, not writable by group or others. A missing directory is
/// created (mode 0700, with any missing parents) and then checked.
fn check_dir(path: &Path) -> Result<(), SocketError> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let io = |source| SocketError::Io {
        path: path.to_path_buf(),
        source,
    };
    let meta = match std::fs::symlink_metadata(dir) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            std::fs::DirBuilder::new()
                .recursive(true)
                .mode(0o700)
                .create(dir)
                .map_err(io)?;
            std::fs::symlink_metadata(dir).map_err(io)?
        }
        Err(e) => return Err(io(e)),
    };
    let euid = euid();
    if meta.file_type().is_symlink() {
        return Err(SocketError::DirSymlink {
            path: path.to_path_buf(),
            dir: dir.to_path_buf(),
            target: std::fs::read_link(dir).unwrap_or_default(),
            euid,
        });
    }
    if !meta.is_dir() {
        return Err(SocketError::DirNotADirectory {
            path: path.to_path_buf(),
            dir: dir.to_path_buf(),
        });
    }
    let resolved = std::fs::canonicalize(dir).map_err(io)?;
    if resolved != std::path::absolute(dir).map_err(io)? {
        return Err(SocketError::DirResolves {
            path: path.to_path_buf(),
            dir: dir.to_path_buf(),
            resolved,
        });
    }
    if meta.uid() != euid {
        return Err(SocketError::DirOwner {
            path: path.to_path_buf(),
            dir: dir.to_path_buf(),
            owner: meta.uid(),
            euid,
        });
    }
    let mode = meta.mode() & 0o7777;
    if mode & 0o022 != 0 {
        return Err(SocketError::DirWritable {
            path: path.to_path_buf(),
            dir: dir.to_path_buf(),
            mode,
        });
    }
    Ok(())
}

/// The bound socket: its listener, and the device and inode of the socket
/// file it made, so that only that file is ever removed (at shutdown, or
/// when this is dropped).
#[derive(Debug)]
pub struct FeatureSocket {
    listener: UnixListener,
    path: PathBuf,
    dev: u64,
    ino: u64,
    /// The path has been dealt with (removed, or found not to be ours).
    closed: bool,
}

impl FeatureSocket {
    /// The socket's path, as configured.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Removes the socket file if the path still is the socket bound here
    /// (same device and inode); anything else found there is left alone,
    /// counted in `counters` (`feature_socket_replaced`) and logged. Returns
    /// whether the file was removed. Only the first call does anything.
    pub fn close(&mut self, counters: Option<&Counters>) -> bool {
        if std::mem::replace(&mut self.closed, true) {
            return false;
        }
        let path = self.path.display();
        let reason = match std::fs::symlink_metadata(&self.path) {
            Ok(m) if m.file_type().is_socket() && m.dev() == self.dev && m.ino() == self.ino => {
                return match std::fs::remove_file(&self.path) {
                    Ok(()) => true,
                    Err(e) => {
                        tracing::warn!(socket = %path, error = %e, "cannot remove the feature socket");
                        false
                    }
                };
            }
            Ok(_) => "feature_socket_replaced",
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => "feature_socket_gone",
            Err(e) => {
                tracing::warn!(socket = %path, error = %e, "cannot check the feature socket; left in place");
                "feature_socket_replaced"
            }
        };
        if let Some(c) = counters {
            c.add(reason, 1);
        }
        tracing::warn!(
            reason,
            socket = %path,
            "the feature socket's path is no longer the socket this daemon bound (replaced or removed by \
             someone else); left alone"
        );
        false
    }
}

impl Drop for FeatureSocket {
    fn drop(&mut self) {
        self.close(None);
    }
}

/// Binds the socket with mode 0600 in a directory that `check_dir` accepts. An
/// existing path is reused only if it is a stale socket (nobody listening).
pub async fn bind(path: &Path) -> Result<FeatureSocket, SocketError> {
    let io = |source| SocketError::Io {
        path: path.to_path_buf(),
        source,
    };
    check_dir(path)?;
    if let Ok(meta) = std::fs::symlink_metadata(path) {
        if !meta.file_type().is_socket() {
            return Err(SocketError::NotASocket(path.to_path_buf()));
        }
        if UnixStream::connect(path).await.is_ok() {
            return Err(SocketError::InUse(path.to_path_buf()));
        }
        std::fs::remove_file(path).map_err(io)?;
    }
    let listener = UnixListener::bind(path).map_err(io)?;
    let meta = std::fs::symlink_metadata(path).map_err(io)?;
    let socket = FeatureSocket {
        listener,
        path: path.to_path_buf(),
        dev: meta.dev(),
        ino: meta.ino(),
        closed: false,
    };
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o600)).map_err(io)?;
    Ok(socket)
}

/// Limits on what one front end may do.
#[derive(Clone, Copy, Debug)]
pub struct Limits {
    /// Longest accepted line (bytes).
    pub max_line_bytes: usize,
    /// Most features accepted in one frame.
    pub max_features: usize,
    /// A writer with no accepted frame for this long is dropped.
    pub idle_timeout: Duration,
}

/// The longest idle timeout honoured (a day), so a deadline never overflows.
const MAX_IDLE_TIMEOUT: Duration = Duration::from_secs(86_400);

/// How one front end's connection ended.
enum End {
    /// It closed the connection (or it failed).
    Left,
    /// It sent no accepted frame for `idle_timeout`; `lines_rejected` lines
    /// came meanwhile.
    Idle { lines_rejected: u64 },
    /// The daemon is stopping.
    Stop,
}

/// Serves front ends one at a time until `stop` fires, sending each good
/// frame to `out` (a full channel drops the frame and counts it), then
/// removes the socket file if it still is ours ([`FeatureSocket::close`]).
pub async fn serve(
    mut socket: FeatureSocket,
    limits: Limits,
    out: mpsc::Sender<FeatureFrame>,
    counters: Counters,
    mut stop: tokio::sync::watch::Receiver<bool>,
) {
    let limits = Limits {
        idle_timeout: limits.idle_timeout.min(MAX_IDLE_TIMEOUT),
        ..limits
    };
    let mut line = Vec::with_capacity(limits.max_line_bytes.min(1 << 20));
    loop {
        let stream = tokio::select! {
            r = socket.listener.accept() => match r {
                Ok((s, _)) => s,
                Err(e) => {
                    tracing::warn!(reason = "feature_accept_error", error = %e, "feature socket accept failed");
                    counters.add("feature_accept_error", 1);
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                }
            },
            _ = stop.changed() => break,
        };
        let (pid, uid) = match stream.peer_cred() {
            Ok(c) => (c.pid(), Some(c.uid())),
            Err(_) => (None, None),
        };
        counters.add("feature_connections", 1);
        tracing::info!(?pid, ?uid, "feature front end connected");
        let mut reader = BufReader::with_capacity(64 * 1024, stream);
        match serve_one(&mut reader, &mut line, &limits, &out, &counters, &mut stop).await {
            End::Left => {
                counters.add("feature_disconnects", 1);
                tracing::info!(?pid, ?uid, "feature front end disconnected");
            }
            End::Idle { lines_rejected } => {
                counters.add("feature_idle_dropped", 1);
                tracing::warn!(
                    reason = "feature_idle_dropped",
                    ?pid,
                    ?uid,
                    idle_timeout_s = limits.idle_timeout.as_secs_f64(),
                    lines_rejected,
                    "dropped a feature front end that sent no accepted frame for features.idle_timeout_s, \
                     so that the next one can connect"
                );
            }
            End::Stop => break,
        }
    }
    socket.close(Some(&counters));
}

/// Reads one front end's lines until it leaves, falls idle or `stop` fires.
async fn serve_one<R: tokio::io::AsyncBufRead + Unpin>(
    reader: &mut R,
    line: &mut Vec<u8>,
    limits: &Limits,
    out: &mpsc::Sender<FeatureFrame>,
    counters: &Counters,
    stop: &mut tokio::sync::watch::Receiver<bool>,
) -> End {
    let idle = tokio::time::sleep(limits.idle_timeout);
    tokio::pin!(idle);
    let mut lines_rejected = 0u64;
    loop {
        let r = tokio::select! {
            r = read_bounded_line(reader, line, limits.max_line_bytes) => r,
            () = idle.as_mut() => return End::Idle { lines_rejected },
            _ = stop.changed() => return End::Stop,
        };
        match r {
            Ok(None) => return End::Left,
            Ok(Some(false)) => {
                let e = LineError::TooLong(limits.max_line_bytes);
                counters.add(e.reason(), 1);
                tracing::warn!(reason = e.reason(), "{e}");
                lines_rejected += 1;
            }
            Ok(Some(true)) => {
                if line.iter().all(|b| b.is_ascii_whitespace()) {
                    continue;
                }
                match parse_line(line, limits.max_features) {
                    Ok(f) => {
                        counters.add("feature_frames", 1);
                        idle.as_mut().reset(tokio::time::Instant::now() + limits.idle_timeout);
                        lines_rejected = 0;
                        if out.try_send(f).is_err() {
                            counters.add("feature_queue_full", 1);
                        }
                    }
                    Err(e) => {
                        counters.add(e.reason(), 1);
                        tracing::warn!(reason = e.reason(), "rejected feature line: {e}");
                        lines_rejected += 1;
                    }
                }
            }
            Err(e) => {
                tracing::warn!(error = %e, "feature connection error");
                return End::Left;
            }
        }
    }
}

/// Reads one line into `buf` without ever holding more than `max` bytes.
/// `Ok(Some(true))`: a line; `Ok(Some(false))`: a line that was too long
/// (discarded); `Ok(None)`: end of stream.
async fn read_bounded_line<R: tokio::io::AsyncBufRead + Unpin>(
    r: &mut R,
    buf: &mut Vec<u8>,
    max: usize,
) -> std::io::Result<Option<bool>> {
    buf.clear();
    let mut too_long = false;
    loop {
        let chunk = r.fill_buf().await?;
        if chunk.is_empty() {
            return Ok(if buf.is_empty() && !too_long {
                None
            } else {
                Some(!too_long)
            });
        }
        let (take, done) = match chunk.iter().position(|&b| b == b'\n') {
            Some(i) => (i + 1, true),
            None => (chunk.len(), false),
        };
        let body = if done { &chunk[..take - 1] } else { &chunk[..take] };
        if !too_long {
            if buf.len() + body.len() > max {
                too_long = true;
                buf.clear();
            } else {
                buf.extend_from_slice(body);
            }
        }
        r.consume(take);
        if done {
            return Ok(Some(!too_long));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_are_checked() {
        let ok = br#"{"v":1,"t_us":1000,"cam":0,"features":[[1,10.5,20.0],[2,30,40]]}"#;
        let f = parse_line(ok, 10).unwrap();
        assert_eq!(f.features.len(), 2);
        assert_eq!(parse_line(ok, 1).unwrap_err().reason(), "feature_line_too_many");
        assert_eq!(parse_line(b"garbage", 10).unwrap_err().reason(), "feature_line_syntax");
        let v2 = br#"{"v":2,"t_us":1,"features":[]}"#;
        assert_eq!(parse_line(v2, 10).unwrap_err().reason(), "feature_line_version");
        let nan = br#"{"v":1,"t_us":1,"features":[[1,NaN,2]]}"#;
        assert!(parse_line(nan, 10).is_err());
        let huge = br#"{"v":1,"t_us":1,"features":[[1,1e999,2]]}"#;
        assert!(parse_line(huge, 10).is_err());
        let neg_t = br#"{"v":1,"t_us":-5,"features":[]}"#;
        assert!(parse_line(neg_t, 10).is_err());
    }

    #[tokio::test]
    async fn bounded_lines() {
        let data: &[u8] = b"short\nthis line is far too long\nok\npartial";
        let mut r = BufReader::with_capacity(4, data);
        let mut buf = Vec::new();
        assert_eq!(read_bounded_line(&mut r, &mut buf, 10).await.unwrap(), Some(true));
        assert_eq!(buf, b"short");
        assert_eq!(read_bounded_line(&mut r, &mut buf, 10).await.unwrap(), Some(false));
        assert_eq!(read_bounded_line(&mut r, &mut buf, 10).await.unwrap(), Some(true));
        assert_eq!(buf, b"ok");
        assert_eq!(read_bounded_line(&mut r, &mut buf, 10).await.unwrap(), Some(true));
        assert_eq!(buf, b"partial");
        assert_eq!(read_bounded_line(&mut r, &mut buf, 10).await.unwrap(), None);
    }

    #[tokio::test]
    async fn refuses_a_path_that_is_not_a_socket() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("f.sock");
        std::fs::write(&p, "x").unwrap();
        assert!(matches!(bind(&p).await, Err(SocketError::NotASocket(_))));
        let q = dir.path().join("g.sock");
        let l = bind(&q).await.unwrap();
        let mode = std::fs::metadata(&q).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, 0o600);
        assert!(matches!(bind(&q).await, Err(SocketError::InUse(_))));
        drop(l);
        assert!(!q.exists(), "our own socket is removed when dropped");
        // A stale socket (nobody listening) is replaced.
        drop(std::os::unix::net::UnixListener::bind(&q).unwrap());
        assert!(q.exists());
        bind(&q).await.unwrap();
    }

    fn dir_with_mode(parent: &Path, name: &str, mode: u32) -> PathBuf {
        let d = parent.join(name);
        std::fs::create_dir(&d).unwrap();
        std::fs::set_permissions(&d, std::fs::Permissions::from_mode(mode)).unwrap();
        d
    }

    #[tokio::test]
    async fn refuses_a_directory_others_could_tamper_with() {
        let top = tempfile::tempdir().unwrap();
        // A private directory, and a missing one (made 0700), are fine.
        let ok = dir_with_mode(top.path(), "ok", 0o755);
        drop(bind(&ok.join("f.sock")).await.unwrap());
        let made = top.path().join("new/sub");
        drop(bind(&made.join("f.sock")).await.unwrap());
        let mode = std::fs::metadata(&made).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode & 0o077, 0, "created private: {mode:o}");
        // Writable by group, by others, or sticky and world-writable like /tmp.
        for (name, mode) in [("g", 0o775), ("o", 0o757), ("t", 0o1777)] {
            let d = dir_with_mode(top.path(), name, mode);
            let e = bind(&d.join("f.sock")).await.unwrap_err();
            assert!(matches!(e, SocketError::DirWritable { .. }), "{e}");
            let msg = e.to_string();
            assert!(msg.contains("features.socket") && msg.contains("chmod go-w"), "{msg}");
            assert!(!d.join("f.sock").exists());
        }
        // A symlink to a directory, and a directory reached through one.
        let link = top.path().join("link");
        std::os::unix::fs::symlink(&ok, &link).unwrap();
        let e = bind(&link.join("f.sock")).await.unwrap_err();
        assert!(matches!(e, SocketError::DirSymlink { .. }), "{e}");
        assert!(e.to_string().contains("features.socket"), "{e}");
        dir_with_mode(&ok, "inner", 0o700);
        let e = bind(&link.join("inner/f.sock")).await.unwrap_err();
        assert!(matches!(e, SocketError::DirResolves { .. }), "{e}");
        // Not a directory at all.
        let file = top.path().join("file");
        std::fs::write(&file, "x").unwrap();
        let e = bind(&file.join("f.sock")).await.unwrap_err();
        assert!(
            matches!(e, SocketError::DirNotADirectory { .. } | SocketError::Io { .. }),
            "{e}"
        );
        // Owned by another user (only root can make one).
        if euid() == 0 {
            let theirs = dir_with_mode(top.path(), "theirs", 0o755);
            std::os::unix::fs::chown(&theirs, Some(65534), None).unwrap();
            let e = bind(&theirs.join("f.sock")).await.unwrap_err();
            assert!(matches!(e, SocketError::DirOwner { owner: 65534, .. }), "{e}");
            assert!(e.to_string().contains("install -d -m 0700 -o 0"), "{e}");
        }
    }

    #[tokio::test]
    async fn only_our_own_socket_is_removed() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("f.sock");
        let c = Counters::default();
        let mut ours = bind(&p).await.unwrap();
        assert!(ours.close(Some(&c)));
        assert!(!p.exists());
        let mut ours = bind(&p).await.unwrap();
        std::fs::remove_file(&p).unwrap();
        let theirs = std::os::unix::net::UnixListener::bind(&p).unwrap();
        assert!(!ours.close(Some(&c)));
        assert!(!ours.close(Some(&c)), "closed once");
        drop(ours);
        assert!(std::os::unix::net::UnixStream::connect(&p).is_ok(), "theirs is left");
        assert_eq!(c.get("feature_socket_replaced"), 1);
        drop(theirs);
        std::fs::remove_file(&p).unwrap();
        let mut ours = bind(&p).await.unwrap();
        std::fs::remove_file(&p).unwrap();
        assert!(!ours.close(Some(&c)));
        assert_eq!(c.get("feature_socket_gone"), 1);
    }

    #[tokio::test]
    async fn one_writer_at_a_time_and_a_silent_one_is_dropped() {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("f.sock");
        let socket = bind(&p).await.unwrap();
        let c = Counters::default();
        let (tx, mut rx) = mpsc::channel(8);
        let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
        let limits = Limits {
            max_line_bytes: 1024,
            max_features: 10,
            idle_timeout: Duration::from_millis(200),
        };
        let task = tokio::spawn(serve(socket, limits, tx, c.clone(), stop_rx));
        let mut silent = UnixStream::connect(&p).await.unwrap();
        while c.get("feature_connections") == 0 {
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        let mut front = UnixStream::connect(&p).await.unwrap();
        front
            .write_all(b"{\"v\":1,\"t_us\":5,\"features\":[[1,2.0,3.0]]}\n")
            .await
            .unwrap();
        let started = std::time::Instant::now();
        let f = tokio::time::timeout(Duration::from_secs(2), rx.recv())
            .await
            .unwrap()
            .unwrap();
        assert_eq!(f.t_us, 5);
        assert!(
            started.elapsed() >= Duration::from_millis(150),
            "served only after the silent one left"
        );
        let mut b = [0u8; 1];
        assert_eq!(silent.read(&mut b).await.unwrap(), 0, "the silent one was closed");
        assert_eq!(c.get("feature_idle_dropped"), 1);
        assert_eq!(c.get("feature_connections"), 2);
        stop_tx.send(true).unwrap();
        task.await.unwrap();
        assert!(!p.exists(), "removed at stop");
        drop(front);
    }
}
