//! Binding the feature socket: the checks that its directory is one only this
//! user can change, a stale socket replaced, and at shutdown the removal of
//! the socket file bound here only (same device and inode), nothing else.

use std::os::unix::fs::{DirBuilderExt, FileTypeExt, MetadataExt, PermissionsExt};
use std::path::{Path, PathBuf};

use tokio::net::{UnixListener, UnixStream};

use crate::counters::{Counter, Counters};

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
/// The directory the socket `path` lives in (`.` for a bare name).
fn socket_dir(path: &Path) -> &Path {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    }
}

/// created (mode 0700, with any missing parents) and then checked.
fn check_dir(path: &Path) -> Result<(), SocketError> {
    let dir = socket_dir(path);
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
    pub(super) listener: UnixListener,
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
            Ok(_) => Counter::FeatureSocketReplaced,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Counter::FeatureSocketGone,
            Err(e) => {
                tracing::warn!(socket = %path, error = %e, "cannot check the feature socket; left in place");
                Counter::FeatureSocketReplaced
            }
        };
        if let Some(c) = counters {
            c.add(reason, 1);
        }
        tracing::warn!(
            reason = %reason,
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

/// Binds the socket in a directory that `check_dir` accepts. Its mode
/// follows the directory: 0600, or, when the directory lets its group in
/// and no one else (`RuntimeDirectoryMode=0750`: a front-end running as
/// another user of that group), 0660 with the directory's group. An existing path is reused
/// only if it is a stale socket (nobody listening).
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
    let dir_meta = std::fs::metadata(socket_dir(path)).map_err(io)?;
    // Group in, others out (0750, 0770): the group was meant. A directory
    // open to all (0755) keeps the socket to us.
    let mode = if dir_meta.mode() & 0o050 == 0o050 && dir_meta.mode() & 0o007 == 0 {
        std::os::unix::fs::chown(path, None, Some(dir_meta.gid())).map_err(io)?;
        0o660
    } else {
        0o600
    };
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(mode)).map_err(io)?;
    Ok(socket)
}

#[cfg(test)]
mod tests {
    use super::*;

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

    #[tokio::test]
    async fn the_socket_lets_its_directorys_group_in_when_the_directory_does() {
        let dir = tempfile::tempdir().unwrap();
        let shared = dir_with_mode(dir.path(), "shared", 0o750);
        let p = shared.join("f.sock");
        let _l = bind(&p).await.unwrap();
        let meta = std::fs::metadata(&p).unwrap();
        assert_eq!(meta.permissions().mode() & 0o777, 0o660);
        assert_eq!(meta.gid(), std::fs::metadata(&shared).unwrap().gid());
        for (name, mode) in [("private", 0o700), ("open", 0o755)] {
            let d = dir_with_mode(dir.path(), name, mode);
            let q = d.join("f.sock");
            let _m = bind(&q).await.unwrap();
            assert_eq!(
                std::fs::metadata(&q).unwrap().permissions().mode() & 0o777,
                0o600,
                "{name}"
            );
        }
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
        assert_eq!(c.get(Counter::FeatureSocketReplaced), 1);
        drop(theirs);
        std::fs::remove_file(&p).unwrap();
        let mut ours = bind(&p).await.unwrap();
        std::fs::remove_file(&p).unwrap();
        assert!(!ours.close(Some(&c)));
        assert_eq!(c.get(Counter::FeatureSocketGone), 1);
    }
}
