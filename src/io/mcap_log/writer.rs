//! The writer thread: it takes records off the queue, puts them in log-time
//! order ([`Reorder`], at most a second behind), gives them to the MCAP
//! writer and closes each chunk on wall time (or sensor-time span, or
//! size), so that a killed writer loses at most about two seconds of the
//! flight.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, TryRecvError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use super::file::{enforce_total, LogFile};
use super::reorder::{Ready, Reorder};
use super::spool::{lock, Spool, SpoolSink};
use super::{expand_path, new_mcap, LogAlarm, LogError, LogHeader, LogLimits, LogSummary, Record, Topic, UNIX_UNKNOWN};

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
/// How long records wait for the Unix time (`SYSTEM_TIME`) before they go
/// out stamped in boot time (an autopilot that never sends it).
const UNIX_WAIT: Duration = Duration::from_secs(5);
/// Records waiting for the Unix time at most.
const UNIX_WAIT_RECORDS: usize = 50_000;

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

/// The daemon's log goes on in a new file past a size, or when asked (a
/// disarm): what it needs to begin the next one.
pub(super) struct Rotation {
    pattern: String,
    limits: LogLimits,
    header: LogHeader,
    /// The number of the file being written (1 for the first).
    part: u32,
    /// The directory and the file-name pattern of the logs that retention
    /// may delete.
    dir: PathBuf,
    name_pattern: String,
}

impl Rotation {
    /// The rotation of the logs named by `pattern`, the first of which is
    /// `first`; enforces the total size at once (a start after a long day).
    pub(super) fn new(pattern: &str, limits: LogLimits, header: &LogHeader, first: &std::path::Path) -> Self {
        let dir = match first.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let r = Self {
            pattern: pattern.to_string(),
            limits,
            header: header.clone(),
            part: 1,
            dir,
            name_pattern: std::path::Path::new(pattern)
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
        };
        r.enforce_total(first);
        r
    }

    fn enforce_total(&self, current: &std::path::Path) {
        if self.limits.max_total_bytes > 0 && !self.name_pattern.is_empty() {
            enforce_total(&self.dir, &self.name_pattern, current, self.limits.max_total_bytes);
        }
    }
}

/// The writer thread's state.
pub(super) struct LogWriter {
    pub(super) w: mcap::Writer<SpoolSink>,
    pub(super) ids: BTreeMap<Topic, u16>,
    /// The records waiting to be written in log-time order, and their
    /// sequence numbers (one counter for every channel: the order they came).
    pub(super) order: Reorder<Record>,
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
    /// The daemon's: how to begin the next file.
    pub(super) rotation: Option<Rotation>,
    /// A rotation asked for ([`super::McapLogger::rotate`]).
    pub(super) rotate: Arc<AtomicBool>,
    /// The first Unix minus boot time (ns), [`UNIX_UNKNOWN`] until known:
    /// the log time of records logged before it.
    pub(super) first_unix_minus_boot_ns: Arc<AtomicI64>,
    /// Records waiting for the Unix time, in order, and since when.
    pub(super) waiting: Vec<Record>,
    pub(super) waiting_since: Option<Instant>,
    /// Whether records wait for the Unix time (the daemon's and replay's
    /// logs, which hear `SYSTEM_TIME`), or go out at once.
    pub(super) wait_for_unix: bool,
    /// The live view, if it runs: each record goes there too.
    pub(super) live: Option<Box<dyn super::RecordTap>>,
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
                self.accept(r)?;
            }
            self.tick()?;
        }
        self.release_waiting()?;
        self.flush_order()?;
        self.close_chunk()?;
        self.w.finish().map_err(|e| self.mcap_err(e))?;
        self.summary.dropped = dropped.load(Ordering::Relaxed);
        self.summary.late = self.order.late;
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

    /// Takes one record: while the Unix time is not known yet it waits
    /// (bounded: [`UNIX_WAIT`], [`UNIX_WAIT_RECORDS`]), else it is written
    /// after those waiting.
    fn accept(&mut self, r: Record) -> Result<(), LogError> {
        let known = self.first_unix_minus_boot_ns.load(Ordering::Relaxed) != UNIX_UNKNOWN;
        let since = *self.waiting_since.get_or_insert_with(Instant::now);
        if self.wait_for_unix && !known && since.elapsed() < UNIX_WAIT && self.waiting.len() < UNIX_WAIT_RECORDS {
            self.waiting.push(r);
            return Ok(());
        }
        self.release_waiting()?;
        self.admit(r)
    }

    /// Admits the records that waited for the Unix time, in order.
    fn release_waiting(&mut self) -> Result<(), LogError> {
        for r in std::mem::take(&mut self.waiting) {
            self.admit(r)?;
        }
        Ok(())
    }

    /// Stamps a record with its log time and gives it to the live view at
    /// once, then to the reordering; writes what falls due.
    fn admit(&mut self, r: Record) -> Result<(), LogError> {
        if !self.ids.contains_key(&r.topic) {
            return Ok(());
        }
        let log_ns = self.log_time(&r);
        if let Some(live) = &self.live {
            live.record(r.topic, log_ns, &r.data);
        }
        let now = Instant::now();
        if let Some(late) = self.order.push(log_ns, r.data.len(), r, now) {
            self.write(late)?;
        }
        self.write_due(now)
    }

    /// Writes the records due to go out by `now`, in log-time order.
    fn write_due(&mut self, now: Instant) -> Result<(), LogError> {
        while let Some(x) = self.order.pop_due(now) {
            self.write(x)?;
        }
        Ok(())
    }

    /// Writes every record held, in log-time order (the file ends).
    fn flush_order(&mut self) -> Result<(), LogError> {
        while let Some(x) = self.order.pop() {
            self.write(x)?;
        }
        Ok(())
    }

    /// A record's log time: its boot time plus the Unix offset in force when
    /// it was logged, or the first one known (its boot time is kept as the
    /// publish time).
    fn log_time(&self, r: &Record) -> u64 {
        let off = match r.unix_minus_boot_ns {
            UNIX_UNKNOWN => self.first_unix_minus_boot_ns.load(Ordering::Relaxed),
            off => off,
        };
        match off {
            UNIX_UNKNOWN => r.t_ns,
            off => (r.t_ns as i64).saturating_add(off).max(0) as u64,
        }
    }

    /// Writes one record, closing the open chunk first if the record's
    /// sensor time would make it span more than [`CHUNK_SPAN_NS`]. While the
    /// file cannot be written and `spool_max_bytes` wait in memory, the
    /// record is dropped and counted instead.
    fn write(&mut self, x: Ready<Record>) -> Result<(), LogError> {
        let Ready { log_ns, seq, item: r } = x;
        let Some(&cid) = self.ids.get(&r.topic) else {
            return Ok(());
        };
        if self.failure.is_some() && lock(&self.spool).unsent() >= self.spool_max_bytes {
            self.summary.dropped_write_error += 1;
            return Ok(());
        }
        if let Some(c) = self.chunk {
            if log_ns.max(c.t_max_ns) - log_ns.min(c.t_min_ns) >= CHUNK_SPAN_NS {
                self.close_chunk()?;
            }
        }
        let c = self.chunk.get_or_insert(OpenChunk {
            opened: Instant::now(),
            t_min_ns: log_ns,
            t_max_ns: log_ns,
        });
        c.t_min_ns = c.t_min_ns.min(log_ns);
        c.t_max_ns = c.t_max_ns.max(log_ns);
        let header = mcap::records::MessageHeader {
            channel_id: cid,
            sequence: seq,
            log_time: log_ns,
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
    /// open chunk's closing, a record held too long, or a failed write's
    /// retry.
    fn next_due(&mut self) -> Option<Instant> {
        // Records waiting for the Unix time are looked at every 0.1 s.
        let close = self
            .chunk
            .map(|c| c.opened + CHUNK_WALL)
            .or_else(|| (!self.waiting.is_empty()).then(|| Instant::now() + Duration::from_millis(100)));
        let held = self.order.next_due();
        let retry = self.failure.as_ref().map(|f| f.next_retry);
        [close, held, retry].into_iter().flatten().min()
    }

    /// Closes the chunk open for [`CHUNK_WALL`], retries a failed write
    /// when due, and publishes the counts of a failure.
    fn tick(&mut self) -> Result<(), LogError> {
        let now = Instant::now();
        if !self.waiting.is_empty()
            && (self.first_unix_minus_boot_ns.load(Ordering::Relaxed) != UNIX_UNKNOWN
                || self.waiting_since.is_some_and(|t| now >= t + UNIX_WAIT))
        {
            self.release_waiting()?;
        }
        self.write_due(now)?;
        if self.chunk.is_some_and(|c| now >= c.opened + CHUNK_WALL) {
            self.close_chunk()?;
        } else if self.chunk.is_none() && self.failure.as_ref().is_some_and(|f| now >= f.next_retry) {
            self.save();
        }
        self.keep_alarm(now);
        if self.rotate.load(Ordering::Relaxed) || self.file_full() {
            self.next_file()?;
        }
        Ok(())
    }

    /// The file has reached `log.max_file_mb`.
    fn file_full(&self) -> bool {
        self.rotation
            .as_ref()
            .is_some_and(|r| r.limits.max_file_bytes > 0 && lock(&self.spool).written() >= r.limits.max_file_bytes)
    }

    /// Finishes this file (its summary, so that it is whole) and goes on in
    /// a new one, then keeps the directory under its total. Waits while the
    /// file cannot be written: its bytes are still in memory, and a new file
    /// would most likely fail alike.
    fn next_file(&mut self) -> Result<(), LogError> {
        if self.failure.is_some() {
            return Ok(());
        }
        self.rotate.store(false, Ordering::Relaxed);
        let Some(mut rot) = self.rotation.take() else {
            return Ok(());
        };
        rot.part += 1;
        let (w, ids, spool) = new_mcap(&rot.header, rot.part, Some(&self.path)).map_err(|e| LogError::Mcap {
            path: self.path.clone(),
            message: e.to_string(),
        })?;
        self.flush_order()?;
        self.close_chunk()?;
        self.w.finish().map_err(|e| self.mcap_err(e))?;
        self.save();
        if self.failure.is_some() {
            // The summary did not reach the file: it stays readable up to its
            // last whole chunk (`cmsckf log recover`); what it did not take
            // is lost.
            self.summary.dropped_write_error += self.unsaved_records;
            self.unsaved_records = 0;
            if let Some(f) = self.failure.take() {
                self.first_error.get_or_insert(f.first);
            }
            if let Some(a) = &self.alarm {
                a.status.set_io(crate::status::Degraded::LogDiskFull, false);
            }
        }
        let (file, opened) = LogFile::new(PathBuf::from(expand_path(&rot.pattern)));
        let previous = std::mem::replace(&mut self.path, file.path().to_path_buf());
        if let Err(e) = &opened {
            tracing::error!(path = %self.path.display(), error = %e, "the next flight log could not be created; retrying");
        }
        tracing::info!(previous = %previous.display(), path = %self.path.display(), part = rot.part, "flight log: next file");
        self.w = w;
        self.ids = ids;
        self.spool = spool;
        self.file = Box::new(file);
        self.order.restart();
        self.summary.files.push(self.path.clone());
        rot.enforce_total(&self.path);
        self.rotation = Some(rot);
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
