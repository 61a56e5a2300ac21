//! The camera itself, in place of the feature oracle: each frame rendered
//! ([`crate::render`]) and served as raw grey on a Unix socket
//! (`cmsckf_models::image_wire`), for `cmsckf-frontend` to track. Frames
//! go out at their delivery time, stamped with the camera clock's time of
//! their exposure, exactly as the oracle's feature lines do.
//!
//! Rendering runs on its own thread, a few frames ahead in delivery order,
//! so the IMU stream never waits on it while it keeps up. Its buffers
//! travel back to it for reuse.

use std::path::{Path, PathBuf};
use std::sync::mpsc as std_mpsc;
use std::time::Duration;

use tokio::io::AsyncWriteExt;
use tokio::net::{UnixListener, UnixStream};
use tokio::sync::mpsc;

use cmsckf_models::image_wire::FrameHeader;

use crate::dataset::Dataset;
use crate::render::Renderer;

/// Frames rendered ahead of their delivery.
const AHEAD: usize = 4;

/// The camera's side of the socket: a listener the front-end connects to,
/// and the rendered frames waiting their turn.
pub(super) struct CameraServer {
    path: PathBuf,
    listener: UnixListener,
    stream: Option<UnixStream>,
    frames: mpsc::Receiver<Vec<u8>>,
    spent: std_mpsc::Sender<Vec<u8>>,
    width: u32,
    height: u32,
    /// Frames the front-end could not take (not connected, or it failed).
    pub(super) undelivered: usize,
}

impl CameraServer {
    /// Listens at `path` (replacing a stale socket file) and starts
    /// rendering `ds`'s frames in the order of `order` (indices into
    /// `ds.frames`, by delivery).
    pub(super) fn start(path: &Path, ds: &Dataset, order: &[usize]) -> std::io::Result<Self> {
        if path.exists() {
            std::fs::remove_file(path)?;
        }
        let listener = UnixListener::bind(path)?;
        let mut renderer = Renderer::for_dataset(ds);
        let (width, height) = (renderer.width() as u32, renderer.height() as u32);
        let traj = ds.trajectory.clone();
        let times: Vec<f64> = order.iter().map(|&i| ds.frames[i].t_exposure_s).collect();
        let (tx, frames) = mpsc::channel(AHEAD);
        let (spent, recycled) = std_mpsc::channel::<Vec<u8>>();
        let seed = ds.seed;
        std::thread::Builder::new().name("sitl-render".into()).spawn(move || {
            let mut poses = Vec::new();
            for (k, t) in times.into_iter().enumerate() {
                let mut img = recycled.try_recv().unwrap_or_default();
                renderer.exposure_poses(&traj, t, &mut poses);
                renderer.render(&poses, seed.wrapping_mul(1_000_003).wrapping_add(k as u64), &mut img);
                if tx.blocking_send(img).is_err() {
                    return; // the flight is over
                }
            }
        })?;
        Ok(Self {
            path: path.to_path_buf(),
            listener,
            stream: None,
            frames,
            spent,
            width,
            height,
            undelivered: 0,
        })
    }

    /// The next frame in delivery order, rendered, sent stamped `t_us` if
    /// `deliver` (else dropped, as by a camera outage). Whether it went out.
    pub(super) async fn send_next(&mut self, t_us: u64, deliver: bool) -> bool {
        let Some(img) = self.frames.recv().await else { return false };
        let mut sent = false;
        if deliver {
            if self.stream.is_none() {
                // A front-end waiting to connect is taken; none is not waited for.
                if let Ok(Ok((s, _))) = tokio::time::timeout(Duration::ZERO, self.listener.accept()).await {
                    self.stream = Some(s);
                }
            }
            if let Some(s) = self.stream.as_mut() {
                let head = FrameHeader {
                    t_us,
                    width: self.width,
                    height: self.height,
                }
                .encode();
                if s.write_all(&head).await.is_ok() && s.write_all(&img).await.is_ok() {
                    sent = true;
                } else {
                    self.stream = None;
                }
            }
        }
        if !sent {
            self.undelivered += 1;
        }
        let _ = self.spent.send(img);
        sent
    }

    /// Drops the front-end's connection (its crash, by a fault).
    pub(super) fn disconnect(&mut self) {
        self.stream = None;
    }
}

impl Drop for CameraServer {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}
