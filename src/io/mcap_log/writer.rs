//! The writer thread: it takes records off the queue, gives them to the MCAP
//! writer and closes each chunk on wall time (or sensor-time span, or size),
//! so that a killed writer loses at most about a second of the flight.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, TryRecvError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use super::spool::{lock, Spool, SpoolSink};
use super::{LogAlarm, LogError, LogSummary, Record, Topic};

/// How long replay's writer pauses after emptying the queue.
const WRITER_PAUSE: Duration = Duration::from_micros(500);
/// A chunk is closed (and written to the file) once it has been open this
/// long in wall time: what a killed writer loses at most, whatever the
/// sensor times say.
const CHUNK_WALL: Duration = Duration::from_secs(1);
/// A chunk is also closed once its records' sensor times span this much
/// (ns): replay and a sped-up SITL run faster than the wall clock. A jump
/// of the sensor clock (a reboot, a far-future stamp) only closes a chunk
/// early.
const CHUNK_SPAN_NS: u64 = 1_000_000_000;
/// The size bound of a chunk (bytes, uncompressed).
pub(super) const CHUNK_MAX_BYTES: u64 = 8 << 20;

/// The chunk being filled.
#[derive(Clone, Copy, Debug)]
pub(super) struct OpenChunk {
    /// Wall time of its first record.
    opened: Instant,
    /// Its records' earliest and latest sensor times (ns).
    t_min_ns: u64,
    t_max_ns: u64,
}

/// The file cannot be written (since `since`).
#[derive(Debug)]
pub(super) struct Failure {
    /// The first error of the episode (the reason).
    pub(super) first: std::io::Error,
    pub(super) since: Instant,
    pub(super) next_retry: Instant,
    /// The explicit STATUSTEXT still has to be queued (the queue was full).
    pub(super) text_pending: bool,
}

/// The writer thread's state.
pub(super) struct LogWriter {
    pub(super) w: mcap::Writer<SpoolSink>,
    pub(super) ids: BTreeMap<Topic, u16>,
    pub(super) seq: BTreeMap<u16, u32>,
    pub(super) spool: Arc<Mutex<Spool>>,
    pub(super) file: Box<dyn Write + Send>,
    pub(super) path: PathBuf,
    pub(super) chunk: Option<OpenChunk>,
    pub(super) failure: Option<Failure>,
    /// Records given to the MCAP writer since the file last took all it was
    /// given: lost if it never does.
    pub(super) unsaved_records: u64,
    /// Bytes kept in memory while the file cannot be written
    /// ([`SPOOL_MAX_BYTES`]).
    ///
    /// [`SPOOL_MAX_BYTES`]: super::spool::SPOOL_MAX_BYTES
    pub(super) spool_max_bytes: usize,
    /// The reason of the first failure that is over (for the error at the end).
    pub(super) first_error: Option<std::io::Error>,
    pub(super) alarm: Option<LogAlarm>,
    /// `(write_failures, dropped_write_error)` already added to the alarm's
    /// counters.
    pub(super) published: (u64, u64),
    pub(super) last_publish: Instant,
    pub(super) summary: LogSummary,
}

impl LogWriter {
    /// Writes records until the channel closes, then the summary.
    pub(super) fn run(
        mut self,
        rx: Receiver<Record>,
        dropped: Arc<AtomicU64>,
        blocking: Arc<AtomicBool>,
    ) -> Result<LogSummary, LogError> {
        // The header, schemas and channels wait for the first chunk: the
        // first write, and so a full disk's alarm, comes with the first input,
        // when the autopilot is there to hear it.
        //
        // Takes what is queued; once the queue is empty it waits for the
        // next record, or until the open chunk is due to close or a failed
        // write to be retried. For replay it first pauses briefly, so that
        // the writer is rarely waiting on the channel and the sender seldom
        // has to wake it (a system call each, about 4 % of a replay). The
        // daemon's writer does not pause: with a worker thread computing
        // rebases on a 2-core machine, the pauses' timer wake-ups took the
        // fusion loop's IMU-to-output latency p99 from 0.56 ms to 1.9 ms (its
        // wait for a due chunk wakes it at most once a second).
        loop {
            let r = match rx.try_recv() {
                Ok(r) => Some(r),
                Err(TryRecvError::Disconnected) => break,
                Err(TryRecvError::Empty) => {
                    if blocking.load(Ordering::Relaxed) {
                        std::thread::sleep(WRITER_PAUSE);
                    }
                    match self.next_due() {
                        None => match rx.recv() {
                            Ok(r) => Some(r),
                            Err(_) => break,
                        },
                        Some(due) => match rx.recv_timeout(due.saturating_duration_since(Instant::now())) {
                            Ok(r) => Some(r),
                            Err(RecvTimeoutError::Timeout) => None,
                            Err(RecvTimeoutError::Disconnected) => break,
                        },
                    }
                }
            };
            if let Some(r) = r {
                self.write(r)?;
            }
            self.tick()?;
        }
        self.close_chunk()?;
        self.w.finish().map_err(|e| self.mcap_err(e))?;
        self.summary.dropped = dropped.load(Ordering::Relaxed);
        // One last try, whatever the retry timer says.
        if let Some(f) = &mut self.failure {
            f.next_retry = Instant::now();
        }
        self.save();
        if self.failure.is_some() {
            self.summary.dropped_write_error += self.unsaved_records;
            self.unsaved_records = 0;
        }
        self.publish();
        let lost = self.summary.dropped_write_error;
        let unfinished = self.failure.is_some();
        let first = self.failure.take().map(|f| f.first).or_else(|| self.first_error.take());
        match first {
            Some(source) if lost > 0 || unfinished => {
                tracing::error!(path = %self.path.display(), lost, error = %source,
                    "MCAP log: records were lost because the file could not be written");
                Err(LogError::Write {
                    path: self.path,
                    records_lost: lost,
                    source,
                })
            }
            _ => Ok(self.summary),
        }
    }

    /// Writes one record, closing the open chunk first if the record's
    /// sensor time would make it span more than [`CHUNK_SPAN_NS`]. While the
    /// file cannot be written and `spool_max_bytes` wait in memory, the
    /// record is dropped and counted instead.
    fn write(&mut self, r: Record) -> Result<(), LogError> {
        let Some(&cid) = self.ids.get(&r.topic) else {
            return Ok(());
        };
        if self.failure.is_some() && lock(&self.spool).unsent() >= self.spool_max_bytes {
            self.summary.dropped_write_error += 1;
            return Ok(());
        }
        if let Some(c) = self.chunk {
            if r.t_ns.max(c.t_max_ns) - r.t_ns.min(c.t_min_ns) >= CHUNK_SPAN_NS {
                self.close_chunk()?;
            }
        }
        let c = self.chunk.get_or_insert(OpenChunk {
            opened: Instant::now(),
            t_min_ns: r.t_ns,
            t_max_ns: r.t_ns,
        });
        c.t_min_ns = c.t_min_ns.min(r.t_ns);
        c.t_max_ns = c.t_max_ns.max(r.t_ns);
        let s = self.seq.entry(cid).or_insert(0);
        *s = s.wrapping_add(1);
        let header = mcap::records::MessageHeader {
            channel_id: cid,
            sequence: *s,
            log_time: r.t_ns,
            publish_time: r.t_ns,
        };
        if let Err(e) = self.w.write_to_known_channel(&header, &r.data) {
            return Err(self.mcap_err(e));
        }
        self.summary.messages += 1;
        self.unsaved_records += 1;
        Ok(())
    }

    /// The wall time the writer must wake at even if no record comes: the
    /// open chunk's closing, or a failed write's retry.
    fn next_due(&self) -> Option<Instant> {
        let close = self.chunk.map(|c| c.opened + CHUNK_WALL);
        let retry = self.failure.as_ref().map(|f| f.next_retry);
        match (close, retry) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// Closes the chunk open for [`CHUNK_WALL`], retries a failed write
    /// when due, and publishes the counts of a failure.
    fn tick(&mut self) -> Result<(), LogError> {
        let now = Instant::now();
        if self.chunk.is_some_and(|c| now >= c.opened + CHUNK_WALL) {
            self.close_chunk()?;
        } else if self.chunk.is_none() && self.failure.as_ref().is_some_and(|f| now >= f.next_retry) {
            self.save();
        }
        self.keep_alarm(now);
        Ok(())
    }

    /// Closes the open chunk, if any, and writes it to the file.
    fn close_chunk(&mut self) -> Result<(), LogError> {
        if self.chunk.take().is_none() {
            return Ok(());
        }
        if let Err(e) = self.w.flush() {
            return Err(self.mcap_err(e));
        }
        self.summary.chunks += 1;
        self.save();
        Ok(())
    }

    fn mcap_err(&self, e: mcap::McapError) -> LogError {
        LogError::Mcap {
            path: self.path.clone(),
            message: e.to_string(),
        }
    }
}
