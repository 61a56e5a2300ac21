//! The camera itself, in place of the feature oracle: each frame rendered
//! ([`crate::render`]) and served as raw grey on a Unix socket
//! (`cmsckf_models::image_wire`), for `cmsckf-frontend` to track. Frames
//! go out at their delivery time, stamped with the camera clock's time of
//! their exposure, exactly as the oracle's feature lines do.
//!
//! A recorded dataset (`euroc:`) serves its own images instead, read from
//! their files in the same way.
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

/// Makes frame `k` (in delivery order) into a buffer: its width and
/// height, or zeros for a frame that could not be made.
type Producer = Box<dyn FnMut(usize, &mut Vec<u8>) -> (u32, u32) + Send>;

/// Frames rendered ahead of their delivery.
const AHEAD: usize = 4;

/// The camera's side of the socket: a listener the front-end connects to,
/// and the rendered frames waiting their turn.
pub(super) struct CameraServer {
    path: PathBuf,
    listener: UnixListener,
    stream: Option<UnixStream>,
    /// Each frame's grey bytes, width and height (none: unreadable).
    frames: mpsc::Receiver<(Vec<u8>, u32, u32)>,
    spent: std_mpsc::Sender<Vec<u8>>,
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
        let times: Vec<f64> = order.iter().map(|&i| ds.frames[i].t_exposure_s).collect();
        let files: Vec<PathBuf> = order.iter().filter_map(|&i| ds.frame_images.get(i).cloned()).collect();
        let (tx, frames) = mpsc::channel(AHEAD);
        let (spent, recycled) = std_mpsc::channel::<Vec<u8>>();
        let produce: Producer = if files.is_empty() {
            let mut renderer = Renderer::for_dataset(ds);
            let traj = ds.trajectory.clone();
            let seed = ds.seed;
            let mut poses = Vec::new();
            Box::new(move |k, img| {
                renderer.exposure_poses(&traj, times[k], &mut poses);
                renderer.render(&poses, seed.wrapping_mul(1_000_003).wrapping_add(k as u64), img);
                (renderer.width() as u32, renderer.height() as u32)
            })
        } else {
            Box::new(move |k, img| match crate::euroc::read_grey_png(&files[k], img) {
                Ok(size) => size,
                Err(e) => {
                    // An unreadable image is a frame the camera dropped.
                    eprintln!("camera: {e}");
                    (0, 0)
                }
            })
        };
        let n = order.len();
        let mut produce = produce;
        std::thread::Builder::new().name("sitl-camera".into()).spawn(move || {
            for k in 0..n {
                let mut img = recycled.try_recv().unwrap_or_default();
                let (w, h) = produce(k, &mut img);
                if tx.blocking_send((img, w, h)).is_err() {
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
            undelivered: 0,
        })
    }

    /// The next frame in delivery order, rendered, sent stamped `t_us` if
    /// `deliver` (else dropped, as by a camera outage). Whether it went out.
    pub(super) async fn send_next(&mut self, t_us: u64, deliver: bool) -> bool {
        let Some((img, width, height)) = self.frames.recv().await else {
            return false;
        };
        let mut sent = false;
        if deliver && width > 0 {
            if self.stream.is_none() {
                // A front-end waiting to connect is taken; none is not waited for.
                if let Ok(Ok((s, _))) = tokio::time::timeout(Duration::ZERO, self.listener.accept()).await {
                    self.stream = Some(s);
                }
            }
            if let Some(s) = self.stream.as_mut() {
                let head = FrameHeader { t_us, width, height }.encode();
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
