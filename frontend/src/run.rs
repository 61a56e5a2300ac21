//! The front-end's loop: frames from a [`FrameSource`] through the
//! [`Tracker`] to a [`Sink`], one protocol line a frame. The binary and
//! `cmsckf demo --frontend` both run this, so the demo flies the code a
//! drone runs.
//!
//! The daemon's socket may go away (the daemon restarts, or drops a silent
//! writer), or not be there yet: the sink then drops frames, counts them,
//! and connects on the next one, so the front-end outlives the daemon's
//! restarts and may start before it.
//!
//! Stamps are guarded ([`StampGuard`]): one frame stamped far ahead (a
//! glitch, `u64::MAX`) must not make every later frame look out of order,
//! and a camera clock that restarts must not blind the front-end.

use std::io::Write;
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use crate::image::Gray;
use crate::output;
use crate::source::{monotonic_us, warn_every, FrameSource, SourceError, SourceProblems, Stamp};
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

    /// The daemon's socket, connected on the first frame (and again after
    /// each failure): the front-end may start before the daemon.
    pub fn lazy(path: &Path) -> Self {
        Self {
            path: path.to_path_buf(),
            stream: None,
            failures: 0,
        }
    }
}

impl Sink for SocketSink {
    fn send(&mut self, line: &[u8]) -> bool {
        if self.stream.is_none() {
            self.stream = UnixStream::connect(&self.path).ok();
        }
        let Some(s) = self.stream.as_mut() else {
            self.failures += 1;
            warn_every(self.failures, || {
                format!(
                    "the daemon's socket '{}' is not there: frame dropped",
                    self.path.display()
                )
            });
            return false;
        };
        if s.write_all(line).is_ok() {
            return true;
        }
        self.stream = None;
        self.failures += 1;
        warn_every(self.failures, || {
            format!("the daemon's socket '{}' closed: frame dropped", self.path.display())
        });
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
    /// Frames whose stamp did not advance from the last one, or leapt
    /// ahead of it, dropped (the daemon would refuse them).
    pub frames_out_of_order: u64,
    /// Times the camera's clock was taken to have restarted (or jumped):
    /// its new stamps, once they ran on steadily, were followed.
    pub clock_restarts: u64,
    /// What the source skipped or survived.
    pub source: SourceProblems,
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
            "{} frames, {:.2} ms a frame tracking, {} not delivered, {} out of order, {} camera clock restarts, \
             {} bad headers, {} of the wrong size, camera lost {} times; features detected {}, lost by Lucas–Kanade {}, by their first window {}, by its warp's stretch {}, by RANSAC {}, re-identified {} (refused by their landmark's window {}), landmarks of recognised places found again {}",
            self.frames,
            self.ms_per_frame(),
            self.frames_dropped,
            self.frames_out_of_order,
            self.clock_restarts,
            self.source.bad_headers,
            self.source.wrong_size,
            self.source.camera_lost,
            s.detected,
            s.lost_klt,
            s.lost_anchor,
            s.lost_warp,
            s.lost_ransac,
            s.reidentified,
            s.reid_refused,
            s.reacquired
        )
    }
}

/// A stamp more than this far ahead of the last one (µs) is not believed
/// at once: a camera paused this long is rare, a glitched stamp is not.
const MAX_STEP_US: u64 = 2_000_000;
/// Frames that must run on steadily from a new clock (each within
/// [`MAX_STEP_US`] of the one before) before it is followed.
const ADOPT_FRAMES: u32 = 5;

/// Keeps the frames' stamps going forward. A frame stamped at or before the
/// last one, or more than [`MAX_STEP_US`] after it, is dropped; if the
/// dropped frames' own stamps run on steadily for [`ADOPT_FRAMES`] frames
/// (a camera clock that restarted, or jumped), the guard follows them.
#[derive(Debug, Default)]
pub struct StampGuard {
    last_us: Option<u64>,
    /// A new clock seen: its last stamp and how many frames ran on it.
    candidate: Option<(u64, u32)>,
}

/// What the guard made of a stamp.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StampVerdict {
    Accept,
    /// The camera's clock restarted or jumped; this frame is on the new one.
    Restarted,
    Drop,
}

impl StampGuard {
    pub fn check(&mut self, t_us: u64) -> StampVerdict {
        let Some(last) = self.last_us else {
            self.last_us = Some(t_us);
            return StampVerdict::Accept;
        };
        if t_us > last && t_us - last <= MAX_STEP_US {
            self.last_us = Some(t_us);
            self.candidate = None;
            return StampVerdict::Accept;
        }
        let n = match self.candidate {
            Some((c, n)) if t_us > c && t_us - c <= MAX_STEP_US => n + 1,
            _ => 1,
        };
        if n >= ADOPT_FRAMES {
            self.last_us = Some(t_us);
            self.candidate = None;
            return StampVerdict::Restarted;
        }
        self.candidate = Some((t_us, n));
        StampVerdict::Drop
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
    let mut guard = StampGuard::default();
    while let Some(t_source_us) = source.next_frame(&mut img)? {
        let t_us = match stamp {
            Stamp::Source => t_source_us,
            Stamp::Arrival => monotonic_us(),
        };
        report.frames += 1;
        match guard.check(t_us) {
            StampVerdict::Accept => {}
            StampVerdict::Restarted => {
                report.clock_restarts += 1;
                eprintln!("cmsckf-frontend: the camera's clock restarted or jumped (now {t_us} µs): following it");
            }
            StampVerdict::Drop => {
                report.frames_out_of_order += 1;
                warn_every(report.frames_out_of_order, || {
                    format!("a frame stamped {t_us} µs is out of order: dropped")
                });
                continue;
            }
        }
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
    report.source = source.problems();
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn verdicts(stamps: &[u64]) -> Vec<StampVerdict> {
        let mut g = StampGuard::default();
        stamps.iter().map(|&t| g.check(t)).collect()
    }

    #[test]
    fn one_far_future_stamp_is_dropped_and_the_stream_goes_on() {
        use StampVerdict::*;
        let v = verdicts(&[1_000_000, 1_050_000, u64::MAX, 1_100_000, 1_150_000]);
        assert_eq!(v, [Accept, Accept, Drop, Accept, Accept]);
    }

    #[test]
    fn a_restarted_camera_clock_is_followed_after_five_steady_frames() {
        use StampVerdict::*;
        let mut stamps = vec![500_000_000, 500_050_000];
        stamps.extend((0..6).map(|k| 10_000 + k * 50_000));
        let v = verdicts(&stamps);
        assert_eq!(v, [Accept, Accept, Drop, Drop, Drop, Drop, Restarted, Accept]);
    }

    #[test]
    fn repeated_or_scattered_stamps_are_never_followed() {
        // The same stamp again and again, and stamps that jump about: no
        // steady new clock, so nothing is adopted.
        let mut g = StampGuard::default();
        assert_eq!(g.check(1_000_000), StampVerdict::Accept);
        for _ in 0..20 {
            assert_eq!(g.check(1_000_000), StampVerdict::Drop);
        }
        for k in 0..20u64 {
            let t = if k % 2 == 0 { 0 } else { 900_000_000 } + k;
            assert_eq!(g.check(t), StampVerdict::Drop);
        }
        assert_eq!(g.check(1_050_000), StampVerdict::Accept);
    }
}
