//! The front-end's loop: frames from a [`FrameSource`] through the
//! [`Tracker`] to a [`Sink`], one protocol line a frame. The binary and
//! `cmsckf demo --frontend` both run this, so the demo flies the code a
//! drone runs.
//!
//! The daemon's socket may go away (the daemon restarts, or drops a silent
//! writer): the sink then drops frames, counts them, and reconnects on the
//! next one, so the front-end outlives the daemon's restarts.

use std::io::Write;
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use crate::image::Gray;
use crate::output;
use crate::source::{monotonic_us, FrameSource, SourceError, Stamp};
use crate::tracker::{TrackStats, Tracker};

/// Where the protocol's lines go.
pub trait Sink {
    /// Writes one line; whether it went out.
    fn send(&mut self, line: &[u8]) -> bool;
    fn flush(&mut self) -> std::io::Result<()>;
}

/// The daemon's feature socket, reconnected after a failure.
pub struct SocketSink {
    path: PathBuf,
    stream: Option<UnixStream>,
    /// Connection failures, for the report.
    pub failures: u64,
}

impl SocketSink {
    /// Connects to the daemon's socket: refused now if it is not there.
    pub fn connect(path: &Path) -> std::io::Result<Self> {
        Ok(Self {
            path: path.to_path_buf(),
            stream: Some(UnixStream::connect(path)?),
            failures: 0,
        })
    }
}

impl Sink for SocketSink {
    fn send(&mut self, line: &[u8]) -> bool {
        if self.stream.is_none() {
            self.stream = UnixStream::connect(&self.path).ok();
        }
        let Some(s) = self.stream.as_mut() else {
            self.failures += 1;
            return false;
        };
        if s.write_all(line).is_ok() {
            return true;
        }
        self.stream = None;
        self.failures += 1;
        false
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.stream.as_mut().map_or(Ok(()), |s| s.flush())
    }
}

/// A file (or anything written), in full or not at all.
pub struct WriteSink<W: Write>(pub W);

impl<W: Write> Sink for WriteSink<W> {
    fn send(&mut self, line: &[u8]) -> bool {
        self.0.write_all(line).is_ok()
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.0.flush()
    }
}

/// What a run did.
#[derive(Clone, Debug, Default)]
pub struct RunReport {
    pub frames: u64,
    /// Frames whose line could not be written.
    pub frames_dropped: u64,
    /// Frames whose stamp did not advance, dropped (the daemon would
    /// refuse them).
    pub frames_out_of_order: u64,
    /// Time spent tracking.
    pub busy: Duration,
    pub tracks: TrackStats,
}

impl RunReport {
    /// Mean tracking time a frame (ms).
    pub fn ms_per_frame(&self) -> f64 {
        self.busy.as_secs_f64() * 1e3 / self.frames.max(1) as f64
    }
}

impl std::fmt::Display for RunReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = &self.tracks;
        write!(
            f,
            "{} frames, {:.2} ms a frame tracking, {} not delivered, {} out of order; features detected {}, lost by Lucas–Kanade {}, by their first window {}, by RANSAC {}, re-identified {} (refused by their landmark's window {}), landmarks of recognised places found again {}",
            self.frames,
            self.ms_per_frame(),
            self.frames_dropped,
            self.frames_out_of_order,
            s.detected,
            s.lost_klt,
            s.lost_anchor,
            s.lost_ransac,
            s.reidentified,
            s.reid_refused,
            s.reacquired
        )
    }
}

/// Tracks every frame of `source` and writes it to `sink` as camera `cam`,
/// stamped as `stamp` says, until the source ends.
pub fn run(
    source: &mut dyn FrameSource,
    tracker: &mut Tracker,
    sink: &mut dyn Sink,
    cam: u32,
    stamp: Stamp,
) -> Result<RunReport, SourceError> {
    let mut report = RunReport::default();
    let (mut img, mut line) = (Gray::new(1, 1), String::new());
    let mut last_t_us = None;
    while let Some(t_source_us) = source.next_frame(&mut img)? {
        let t_us = match stamp {
            Stamp::Source => t_source_us,
            Stamp::Arrival => monotonic_us(),
        };
        report.frames += 1;
        if last_t_us.is_some_and(|t| t_us <= t) {
            report.frames_out_of_order += 1;
            continue;
        }
        last_t_us = Some(t_us);
        let start = Instant::now();
        let feats = tracker.process(&img);
        report.busy += start.elapsed();
        output::frame_line_into(&mut line, t_us, cam, feats);
        if !sink.send(line.as_bytes()) {
            report.frames_dropped += 1;
        }
    }
    let _ = sink.flush();
    report.tracks = tracker.stats;
    Ok(report)
}
