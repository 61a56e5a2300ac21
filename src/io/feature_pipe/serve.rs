//! Serving the feature socket: one front end at a time, its lines read with a
//! bound on their length and checked, and a writer dropped when it sends no
//! accepted frame for the idle timeout, so that it cannot keep the real front
//! end out.

use std::time::Duration;

use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::sync::mpsc;

use super::{parse_line, FeatureFrame, FeatureSocket, LineError};
use crate::counters::{Counter, Counters};

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
                    counters.add(Counter::FeatureAcceptError, 1);
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
        counters.add(Counter::FeatureConnections, 1);
        tracing::info!(?pid, ?uid, "feature front end connected");
        let mut reader = BufReader::with_capacity(64 * 1024, stream);
        match serve_one(&mut reader, &mut line, &limits, &out, &counters, &mut stop).await {
            End::Left => {
                counters.add(Counter::FeatureDisconnects, 1);
                tracing::info!(?pid, ?uid, "feature front end disconnected");
            }
            End::Idle { lines_rejected } => {
                counters.add(Counter::FeatureIdleDropped, 1);
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
                tracing::warn!(reason = %e.reason(), "{e}");
                lines_rejected += 1;
            }
            Ok(Some(true)) => {
                if line.iter().all(|b| b.is_ascii_whitespace()) {
                    continue;
                }
                match parse_line(line, limits.max_features) {
                    Ok(f) => {
                        counters.add(Counter::FeatureFrames, 1);
                        idle.as_mut().reset(tokio::time::Instant::now() + limits.idle_timeout);
                        lines_rejected = 0;
                        if out.try_send(f).is_err() {
                            counters.add(Counter::FeatureQueueFull, 1);
                        }
                    }
                    Err(e) => {
                        counters.add(e.reason(), 1);
                        tracing::warn!(reason = %e.reason(), "rejected feature line: {e}");
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
    use crate::io::feature_pipe::bind;
    use tokio::net::UnixStream;

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
        while c.get(Counter::FeatureConnections) == 0 {
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
        assert_eq!(c.get(Counter::FeatureIdleDropped), 1);
        assert_eq!(c.get(Counter::FeatureConnections), 2);
        stop_tx.send(true).unwrap();
        task.await.unwrap();
        assert!(!p.exists(), "removed at stop");
        drop(front);
    }
}
