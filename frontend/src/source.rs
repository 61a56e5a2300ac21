//! Where the front-end's images come from, and when they were taken: why
//! this exists is that one tracking loop must serve a dataset on disk, a
//! camera process on a socket (the SITL's renderer, or a user's driver) and
//! a V4L2 camera alike.
//!
//! Each source gives frames in time order with their stamp (µs). A stamp is
//! the source's own (the dataset's, or the camera process's, on the clock
//! that the daemon's `features.clock` names), or, with [`Stamp::Arrival`],
//! the companion's `CLOCK_MONOTONIC` when the frame arrived, for a camera
//! that stamps nothing (then set `features.clock = "monotonic"`: the daemon
//! maps it onto the autopilot's clock through TIMESYNC, and the filter
//! estimates what is left of the offset).

use std::io::Read;
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use cmsckf_models::image_wire::{FrameHeader, FrameHeaderError, HEADER_BYTES};

use crate::euroc::{self, EurocError, FrameEntry};
use crate::image::Gray;

/// Which time a frame is stamped with.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Stamp {
    /// The source's own stamp.
    Source,
    /// `CLOCK_MONOTONIC` at the frame's arrival.
    Arrival,
}

/// Errors that end a source.
#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    #[error(transparent)]
    Euroc(#[from] EurocError),
    #[error("camera socket '{0}': {1}")]
    Socket(PathBuf, std::io::Error),
    #[error("camera socket '{0}': {1}")]
    Header(PathBuf, FrameHeaderError),
    #[error("camera '{0}': {1}")]
    Device(PathBuf, String),
    #[error("camera socket '{path}': a {got_w}x{got_h} image, but the camera model is {want_w}x{want_h}: give the front-end the camera's own config")]
    Size {
        path: PathBuf,
        got_w: u32,
        got_h: u32,
        want_w: usize,
        want_h: usize,
    },
}

/// A stream of grey frames.
pub trait FrameSource {
    /// The next frame into `img`, and its stamp (µs); `None` at the end.
    fn next_frame(&mut self, img: &mut Gray) -> Result<Option<u64>, SourceError>;
}

/// `CLOCK_MONOTONIC` now (µs).
pub fn monotonic_us() -> u64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: clock_gettime writes the timespec it is given, and
    // CLOCK_MONOTONIC exists on every Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000 + ts.tv_nsec as u64 / 1000
}

/// A EuRoC/ASL camera folder, optionally paced by its stamps.
pub struct EurocSource {
    frames: Vec<FrameEntry>,
    next: usize,
    realtime: Option<Instant>,
}

impl EurocSource {
    pub fn open(root: &Path, cam: u32, realtime: bool) -> Result<Self, SourceError> {
        Ok(Self {
            frames: euroc::frames(root, cam)?,
            next: 0,
            realtime: realtime.then(Instant::now),
        })
    }

    pub fn len(&self) -> usize {
        self.frames.len()
    }

    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }
}

impl FrameSource for EurocSource {
    fn next_frame(&mut self, img: &mut Gray) -> Result<Option<u64>, SourceError> {
        let Some(f) = self.frames.get(self.next) else {
            return Ok(None);
        };
        self.next += 1;
        if let Some(start) = self.realtime {
            let due = Duration::from_nanos(f.t_ns.saturating_sub(self.frames[0].t_ns));
            if let Some(wait) = due.checked_sub(start.elapsed()) {
                std::thread::sleep(wait);
            }
        }
        *img = euroc::read_png(&f.path)?;
        Ok(Some(f.t_ns / 1000))
    }
}

/// A camera process on a Unix socket, writing `image_wire` frames. The
/// front-end connects (waiting for the camera to come up); the stream's end
/// is the run's end.
pub struct SocketSource {
    path: PathBuf,
    stream: UnixStream,
    bytes: Vec<u8>,
    /// The camera model's size: frames of another size are refused.
    expect: Option<(usize, usize)>,
}

impl SocketSource {
    /// Connects to `path`, retrying for up to `wait`.
    pub fn connect(path: &Path, wait: Duration, expect: Option<(usize, usize)>) -> Result<Self, SourceError> {
        let start = Instant::now();
        let stream = loop {
            match UnixStream::connect(path) {
                Ok(s) => break s,
                Err(e) if start.elapsed() >= wait => return Err(SourceError::Socket(path.to_path_buf(), e)),
                Err(_) => std::thread::sleep(Duration::from_millis(50)),
            }
        };
        Ok(Self {
            path: path.to_path_buf(),
            stream,
            bytes: Vec::new(),
            expect,
        })
    }
}

impl FrameSource for SocketSource {
    fn next_frame(&mut self, img: &mut Gray) -> Result<Option<u64>, SourceError> {
        let io = |e| SourceError::Socket(self.path.clone(), e);
        let mut head = [0u8; HEADER_BYTES];
        match self.stream.read_exact(&mut head) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(None),
            Err(e) => return Err(io(e)),
        }
        let h = FrameHeader::decode(&head).map_err(|e| SourceError::Header(self.path.clone(), e))?;
        if let Some((w, hh)) = self.expect {
            if (h.width as usize, h.height as usize) != (w, hh) {
                return Err(SourceError::Size {
                    path: self.path.clone(),
                    got_w: h.width,
                    got_h: h.height,
                    want_w: w,
                    want_h: hh,
                });
            }
        }
        // Bounded by the header's check (each side ≤ MAX_SIDE_PX) and, with
        // a camera model, by its size; reused from frame to frame.
        self.bytes.resize(h.pixels(), 0);
        match self.stream.read_exact(&mut self.bytes) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(None),
            Err(e) => return Err(io(e)),
        }
        // The header's sides give the byte count just read.
        img.set_from_u8(h.width as usize, h.height as usize, &self.bytes);
        Ok(Some(h.t_us))
    }
}
