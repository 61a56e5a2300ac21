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

use cmsckf_models::image_wire::{FrameHeader, HEADER_BYTES, MAGIC};

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
    #[error("camera '{0}': no frame for {1} s (frozen?)")]
    Frozen(PathBuf, f64),
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

    /// What the source skipped or survived so far.
    fn problems(&self) -> SourceProblems {
        SourceProblems::default()
    }
}

/// What a camera source skipped or survived, counted for the report.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SourceProblems {
    /// Frames whose header was not one (a bad magic, an impossible size):
    /// the stream was searched for the next header.
    pub bad_headers: u64,
    /// Frames of another size than the camera model's, skipped.
    pub wrong_size: u64,
    /// Times the camera was lost (its process exited, the device went
    /// away, or it sent nothing for [`FROZEN_AFTER`]) and opened again.
    pub camera_lost: u64,
}

impl std::ops::AddAssign for SourceProblems {
    fn add_assign(&mut self, o: Self) {
        self.bad_headers += o.bad_headers;
        self.wrong_size += o.wrong_size;
        self.camera_lost += o.camera_lost;
    }
}

/// A camera that sends nothing for this long is taken as frozen: lost.
pub const FROZEN_AFTER: Duration = Duration::from_secs(2);

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
/// is this source's end ([`Reopening`] connects again).
///
/// A frame that is not one (a bad magic or an impossible size: the stream
/// lost its framing) is skipped by searching the stream for the next
/// header; a frame of another size than the camera model's is read past and
/// skipped. Both are counted ([`SourceProblems`]) and said on stderr.
pub struct SocketSource {
    path: PathBuf,
    stream: UnixStream,
    bytes: Vec<u8>,
    /// The camera model's size: frames of another size are skipped.
    expect: Option<(usize, usize)>,
    problems: SourceProblems,
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
            problems: SourceProblems::default(),
        })
    }

    /// Takes a camera that sends nothing for [`FROZEN_AFTER`] as lost (an
    /// error), rather than waiting for it for ever.
    pub fn frozen_after(self, after: Duration) -> Result<Self, SourceError> {
        self.stream
            .set_read_timeout(Some(after))
            .map_err(|e| SourceError::Socket(self.path.clone(), e))?;
        Ok(self)
    }

    /// Reads exactly `buf`: `Ok(false)` at the stream's end.
    fn read(&mut self, buf: &mut [u8]) -> Result<bool, SourceError> {
        match self.stream.read_exact(buf) {
            Ok(()) => Ok(true),
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => Ok(false),
            Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {
                Err(SourceError::Frozen(self.path.clone(), FROZEN_AFTER.as_secs_f64()))
            }
            Err(e) => Err(SourceError::Socket(self.path.clone(), e)),
        }
    }

    /// Slides `head` a byte at a time until it starts with the magic again
    /// (then fills the rest): `Ok(false)` at the stream's end.
    fn resync(&mut self, head: &mut [u8; HEADER_BYTES]) -> Result<bool, SourceError> {
        let mut byte = [0u8; 1];
        loop {
            head.copy_within(1.., 0);
            if !self.read(&mut byte)? {
                return Ok(false);
            }
            head[HEADER_BYTES - 1] = byte[0];
            if head[..MAGIC.len()] == MAGIC {
                return Ok(true);
            }
        }
    }

    /// Reads `n` bytes and throws them away, through a small buffer.
    fn skip(&mut self, mut n: usize) -> Result<bool, SourceError> {
        let mut scratch = [0u8; 4096];
        while n > 0 {
            let k = n.min(scratch.len());
            if !self.read(&mut scratch[..k])? {
                return Ok(false);
            }
            n -= k;
        }
        Ok(true)
    }
}

impl FrameSource for SocketSource {
    fn next_frame(&mut self, img: &mut Gray) -> Result<Option<u64>, SourceError> {
        let mut head = [0u8; HEADER_BYTES];
        if !self.read(&mut head)? {
            return Ok(None);
        }
        loop {
            let h = match FrameHeader::decode(&head) {
                Ok(h) => h,
                Err(e) => {
                    self.problems.bad_headers += 1;
                    warn_every(self.problems.bad_headers, || {
                        format!(
                            "camera socket '{}': {e}; looking for the next frame",
                            self.path.display()
                        )
                    });
                    if !self.resync(&mut head)? {
                        return Ok(None);
                    }
                    continue;
                }
            };
            if let Some((w, hh)) = self.expect {
                if (h.width as usize, h.height as usize) != (w, hh) {
                    self.problems.wrong_size += 1;
                    warn_every(self.problems.wrong_size, || {
                        format!(
                            "camera socket '{}': a {}x{} image, but the camera model is {w}x{hh}: skipped \
                             (give the front-end the camera's own config)",
                            self.path.display(),
                            h.width,
                            h.height
                        )
                    });
                    if !self.skip(h.pixels())? || !self.read(&mut head)? {
                        return Ok(None);
                    }
                    continue;
                }
            }
            // Bounded by the header's check (each side ≤ MAX_SIDE_PX) and,
            // with a camera model, by its size; reused from frame to frame.
            let mut bytes = std::mem::take(&mut self.bytes);
            bytes.resize(h.pixels(), 0);
            let whole = self.read(&mut bytes);
            self.bytes = bytes;
            if !whole? {
                return Ok(None);
            }
            // The header's sides give the byte count just read.
            img.set_from_u8(h.width as usize, h.height as usize, &self.bytes);
            return Ok(Some(h.t_us));
        }
    }

    fn problems(&self) -> SourceProblems {
        self.problems
    }
}

/// Says a recurring problem on stderr (the journal): its first ten times,
/// then every hundredth.
pub fn warn_every(count: u64, text: impl FnOnce() -> String) {
    if count <= 10 || count.is_multiple_of(100) {
        eprintln!("cmsckf-frontend: {} ({count} so far)", text());
    }
}

/// Opens a camera again whenever it is lost, for ever: a camera process
/// that exits or restarts, a USB camera unplugged, a frozen one. A live
/// camera has no end, so the front-end stops only when it is told to
/// (SIGTERM). Each loss is counted and said; attempts back off from 0.1 s
/// to 2 s.
pub struct Reopening {
    open: Box<dyn FnMut() -> Result<Box<dyn FrameSource>, SourceError>>,
    current: Option<Box<dyn FrameSource>>,
    /// What the sources closed so far met.
    closed: SourceProblems,
    backoff: Duration,
    failed_opens: u64,
}

impl Reopening {
    pub fn new(open: Box<dyn FnMut() -> Result<Box<dyn FrameSource>, SourceError>>) -> Self {
        Self {
            open,
            current: None,
            closed: SourceProblems::default(),
            backoff: Duration::from_millis(100),
            failed_opens: 0,
        }
    }
}

impl FrameSource for Reopening {
    fn next_frame(&mut self, img: &mut Gray) -> Result<Option<u64>, SourceError> {
        loop {
            let Some(src) = self.current.as_mut() else {
                match (self.open)() {
                    Ok(s) => {
                        if self.failed_opens > 0 || self.closed.camera_lost > 0 {
                            eprintln!("cmsckf-frontend: camera open again");
                        }
                        self.current = Some(s);
                        self.failed_opens = 0;
                    }
                    Err(e) => {
                        self.failed_opens += 1;
                        warn_every(self.failed_opens, || format!("{e}; trying again"));
                        std::thread::sleep(self.backoff);
                        self.backoff = (self.backoff * 2).min(Duration::from_secs(2));
                    }
                }
                continue;
            };
            let why = match src.next_frame(img) {
                Ok(Some(t)) => {
                    self.backoff = Duration::from_millis(100);
                    return Ok(Some(t));
                }
                Ok(None) => "the camera's stream ended".to_string(),
                Err(e) => e.to_string(),
            };
            self.closed += src.problems();
            self.closed.camera_lost += 1;
            self.current = None;
            warn_every(self.closed.camera_lost, || {
                format!("camera lost: {why}; opening it again")
            });
        }
    }

    fn problems(&self) -> SourceProblems {
        let mut p = self.closed;
        if let Some(s) = &self.current {
            p += s.problems();
        }
        p
    }
}
