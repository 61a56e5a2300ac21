//! The feature socket: a Unix-domain stream socket on which one camera front
//! end at a time writes newline-delimited JSON frames,
//! `{"v":1,"t_us":..,"cam":0,"features":[[landmark_id,u_px,v_px],...]}`.
//!
//! Every line is checked here (length, syntax, version, feature count, finite
//! numbers); a bad line is rejected with a reason and the connection goes on.
//! A front end may disconnect and reconnect at any time.

use std::os::unix::fs::{FileTypeExt, PermissionsExt};
use std::path::{Path, PathBuf};

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
    #[error("feature socket '{0}': the path exists and is not a socket; remove it or set features.socket")]
    NotASocket(PathBuf),
    #[error("feature socket '{0}': another process is listening on it; stop it or set features.socket")]
    InUse(PathBuf),
    #[error("feature socket '{path}': {source}")]
    Io { path: PathBuf, source: std::io::Error },
}

/// Binds the socket with mode 0600. An existing path is reused only if it is
/// a stale socket (nobody listening).
pub async fn bind(path: &Path) -> Result<UnixListener, SocketError> {
    let io = |source| SocketError::Io {
        path: path.to_path_buf(),
        source,
    };
    if let Ok(meta) = std::fs::symlink_metadata(path) {
        if !meta.file_type().is_socket() {
            return Err(SocketError::NotASocket(path.to_path_buf()));
        }
        if UnixStream::connect(path).await.is_ok() {
            return Err(SocketError::InUse(path.to_path_buf()));
        }
        std::fs::remove_file(path).map_err(io)?;
    }
    if let Some(dir) = path.parent() {
        if !dir.as_os_str().is_empty() {
            std::fs::create_dir_all(dir).map_err(io)?;
        }
    }
    let listener = UnixListener::bind(path).map_err(io)?;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o600)).map_err(io)?;
    Ok(listener)
}

/// Serves front ends one at a time until `stop` fires, sending each good
/// frame to `out` (a full channel drops the frame and counts it).
pub async fn serve(
    listener: UnixListener,
    max_line_bytes: usize,
    max_features: usize,
    out: mpsc::Sender<FeatureFrame>,
    counters: Counters,
    mut stop: tokio::sync::watch::Receiver<bool>,
) {
    loop {
        let stream = tokio::select! {
            r = listener.accept() => match r {
                Ok((s, _)) => s,
                Err(e) => {
                    tracing::warn!(error = %e, "feature socket accept failed");
                    counters.add("feature_accept_error", 1);
                    tokio::time::sleep(std::time::Duration::from_millis(100)).await;
                    continue;
                }
            },
            _ = stop.changed() => return,
        };
        counters.add("feature_connections", 1);
        tracing::info!("feature front end connected");
        let mut reader = BufReader::with_capacity(64 * 1024, stream);
        let mut line = Vec::with_capacity(max_line_bytes.min(1 << 20));
        loop {
            let r = tokio::select! {
                r = read_bounded_line(&mut reader, &mut line, max_line_bytes) => r,
                _ = stop.changed() => return,
            };
            match r {
                Ok(None) => break,
                Ok(Some(false)) => {
                    let e = LineError::TooLong(max_line_bytes);
                    counters.add(e.reason(), 1);
                    tracing::warn!(reason = e.reason(), "{e}");
                }
                Ok(Some(true)) => {
                    if line.iter().all(|b| b.is_ascii_whitespace()) {
                        continue;
                    }
                    match parse_line(&line, max_features) {
                        Ok(f) => {
                            counters.add("feature_frames", 1);
                            if out.try_send(f).is_err() {
                                counters.add("feature_queue_full", 1);
                            }
                        }
                        Err(e) => {
                            counters.add(e.reason(), 1);
                            tracing::warn!(reason = e.reason(), "rejected feature line: {e}");
                        }
                    }
                }
                Err(e) => {
                    tracing::warn!(error = %e, "feature connection error");
                    break;
                }
            }
        }
        counters.add("feature_disconnects", 1);
        tracing::info!("feature front end disconnected");
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
        // A stale socket (nobody listening) is replaced.
        bind(&q).await.unwrap();
    }
}
