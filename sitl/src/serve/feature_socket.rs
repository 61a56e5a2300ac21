//! The camera front end's side: each frame's features written as a JSON line
//! to the daemon's Unix feature socket, reconnecting after a failure, with
//! the camera faults applied.

use std::path::Path;

use tokio::io::AsyncWriteExt;
use tokio::net::UnixStream;

use crate::features::CameraFrame;

/// A connection to the feature socket, opened when first needed.
pub(super) struct FeatureSocket<'a> {
    path: &'a Path,
    stream: Option<UnixStream>,
}

impl<'a> FeatureSocket<'a> {
    pub(super) fn new(path: &'a Path) -> Self {
        Self { path, stream: None }
    }

    /// Drops the connection (the front end has crashed).
    pub(super) fn disconnect(&mut self) {
        self.stream = None;
    }

    /// Writes `bytes`, connecting first if not connected; whether they were
    /// written. A failed write drops the connection.
    pub(super) async fn write(&mut self, bytes: &[u8]) -> bool {
        if self.stream.is_none() {
            self.stream = UnixStream::connect(self.path).await.ok();
        }
        let mut written = false;
        if let Some(s) = self.stream.as_mut() {
            if s.write_all(bytes).await.is_ok() {
                written = true;
            } else {
                self.stream = None;
            }
        }
        written
    }
}

/// One frame as the front end's JSON line, stamped `t_us` on the boot clock.
pub(super) fn feature_line(t_us: u64, f: &CameraFrame) -> String {
    let mut line = format!("{{\"v\":1,\"t_us\":{t_us},\"cam\":0,\"features\":[");
    for (i, o) in f.features.iter().enumerate() {
        if i > 0 {
            line.push(',');
        }
        line += &format!("[{},{:.3},{:.3}]", o.landmark_id, o.u_px, o.v_px);
    }
    line += "]}\n";
    line
}
