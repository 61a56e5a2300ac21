//! The MCAP flight log: every input and every filter event, as JSON with a
//! JSON schema, in zstd chunks.
//!
//! It exists so that a flight can be reviewed and replayed afterwards, even
//! one that ended badly. The writer runs on its own thread, fed by a bounded
//! channel: logging never blocks the fusion loop. When the channel is full
//! the record is dropped and counted ([`McapLogger::dropped`]); the daemon
//! raises an alarm if any are. Publish time is the sensor time (the
//! autopilot's boot clock); log time is the same instant in Unix time once
//! `SYSTEM_TIME` gives it (records wait up to 5 s for it), else boot time.
//!
//! Records are written in log-time order: each waits up to a second of
//! sensor time (or of wall time) for older ones that come after it
//! ([`reorder`]); a record later than that is written at once and counted
//! ([`LogSummary::late`]). Each record's MCAP `sequence` is one counter for
//! every channel, in the order the records came, so that replay can give
//! the fusion loop its inputs in the order it consumed them
//! ([`reorder::SequenceOrder`], [`LOG_FORMAT`] 3).
//!
//! A chunk is closed and written to the file once it has been open for a
//! second of wall time (or its records span a second of sensor time, or it
//! reaches 8 MB), so a killed writer loses at most about two seconds (the
//! reordering's and the chunk's), whatever the sensor clock did (an
//! autopilot reboot, a far-future stamp): the file is readable up to its
//! last whole chunk. [`McapLogger::finish`] must be called on shutdown
//! (`Drop` cannot report errors).
//!
//! A write of the file that fails (a full disk) does not stop the log: the
//! chunks wait in memory (up to 32 MiB, then records are dropped and
//! counted) and the write is retried every second. With a [`LogAlarm`] (the
//! daemon), the first failure sets [`Degraded::LogDiskFull`] at once and
//! queues a critical `STATUSTEXT` "cmsckf: log disk full"; a write that
//! succeeds again clears it. The counters are [`COUNTER_WRITE_FAILED`] and
//! [`COUNTER_DROPPED_WRITE_ERROR`].
//!
//! A log left unfinished (a killed daemon, a power loss) has no summary:
//! [`recover`] rewrites it with indexes and one, and the daemon names such
//! logs at start ([`unfinished_logs`]).
//!
//! [`Degraded::LogDiskFull`]: crate::status::Degraded::LogDiskFull

mod check;
mod failure;
mod file;
pub mod input;
mod recover;
pub mod reorder;
mod schemas;
mod spool;
#[cfg(test)]
mod tests;
mod topics;
mod writer;

pub use check::{check_bytes, read_checked, CheckError, CheckReport, CheckedLog, MAX_CHUNK_UNCOMPRESSED};
pub use file::{create_output, create_unique, enforce_total, matches_pattern, same_file, OutputError};
pub use input::{InputRecord, RecordError, LOG_FORMAT};
pub use recover::{is_finished, recover, unfinished_logs, RecoverError, RecoverReport, MCAP_MAGIC};
pub use topics::Topic;

use std::collections::BTreeMap;
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Instant;

use serde::Serialize;
use tokio::sync::mpsc;

use crate::counters::{Counter, Counters};
use crate::io::messages::Outbound;
use crate::status::Status;

use file::LogFile;
use spool::{Spool, SpoolSink, SPOOL_MAX_BYTES};
use writer::{LogWriter, Rotation, CHUNK_MAX_BYTES};

/// Errors of the log.
#[derive(Debug, thiserror::Error)]
pub enum LogError {
    #[error("MCAP log '{path}': {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("MCAP log '{path}': {message}")]
    Mcap { path: PathBuf, message: String },
    /// Writing the file failed (a full disk, an I/O error): records were
    /// lost, and the file may end before its summary (readable up to its
    /// last whole chunk).
    #[error("MCAP log '{path}': could not be written: {source} ({records_lost} records lost)")]
    Write {
        path: PathBuf,
        records_lost: u64,
        source: std::io::Error,
    },
    #[error("MCAP log writer thread panicked")]
    Thread,
    /// The writer was still blocked on its file at shutdown: the log ends
    /// where it got to (without its summary: `cmsckf log recover`).
    #[error("MCAP log writer still blocked on its file after {waited_s} s; left behind")]
    Stuck { waited_s: u64 },
    #[error(transparent)]
    Output(#[from] OutputError),
    #[error(transparent)]
    Check(#[from] CheckError),
}

/// Where the writer also hands each record, as written (its topic, log
/// time and JSON): the live view. Called on the writer's thread, never the
/// fusion loop's; it must not block.
pub trait RecordTap: Send {
    fn record(&self, topic: Topic, log_time_ns: u64, json: &[u8]);
}

/// Where the daemon's logs go and how much of the disk they may take.
#[derive(Clone, Debug)]
pub struct LogLimits {
    /// A log is closed and the next one begun past this size (bytes; 0:
    /// no limit).
    pub max_file_bytes: u64,
    /// The logs of the directory are kept under this total, deleting the
    /// oldest finished ones (bytes; 0: no limit).
    pub max_total_bytes: u64,
}

/// What goes into the log's header metadata, so that the log alone can be
/// replayed.
#[derive(Clone, Debug)]
pub struct LogHeader {
    pub version: String,
    pub mode: String,
    /// The full config, as TOML.
    pub config_toml: String,
}

/// Totals at the end of a log.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LogSummary {
    pub messages: u64,
    pub chunks: u64,
    /// Records dropped on a full queue (the writer could not keep up).
    pub dropped: u64,
    /// Writes of the file that failed (the first of each episode and each
    /// retry, about one a second while it lasts).
    pub write_failures: u64,
    /// Records lost because the file could not be written.
    pub dropped_write_error: u64,
    /// Records that came later than the reordering's window and were
    /// written out of log-time order ([`reorder`]).
    pub late: u64,
    /// The files written (more than one when the log was rotated).
    pub files: Vec<PathBuf>,
}

/// Where the writer raises the alarm when the file cannot be written: the
/// daemon's status (its HEARTBEAT turns critical, with a `STATUSTEXT` of the
/// reason, while [`Degraded::LogDiskFull`] is set), its counters, and its
/// outbound MAVLink queue for one explicit `STATUSTEXT` when it starts.
/// `cmsckf replay` has none: its write errors come back from
/// [`McapLogger::finish`].
///
/// [`Degraded::LogDiskFull`]: crate::status::Degraded::LogDiskFull
#[derive(Clone, Debug)]
pub struct LogAlarm {
    pub status: Arc<Status>,
    pub counters: Counters,
    pub out: mpsc::Sender<Outbound>,
}

/// Counter of failed writes of the log file ([`LogSummary::write_failures`]).
pub const COUNTER_WRITE_FAILED: Counter = Counter::LogWriteFailed;
/// Counter of records lost to write errors ([`LogSummary::dropped_write_error`]).
pub const COUNTER_DROPPED_WRITE_ERROR: Counter = Counter::LogRecordsDroppedWriteError;

struct Record {
    topic: Topic,
    t_ns: u64,
    /// Unix minus boot time (ns) when the record was logged, on the
    /// logging thread ([`UNIX_UNKNOWN`] before `SYSTEM_TIME`): its log time
    /// does not depend on how far behind the writer runs.
    unix_minus_boot_ns: i64,
    data: Vec<u8>,
}

/// The logger handle (cheap to share behind an `Arc`).
pub struct McapLogger {
    tx: Option<SyncSender<Record>>,
    dropped: Arc<AtomicU64>,
    thread: Option<JoinHandle<Result<LogSummary, LogError>>>,
    /// Replay ([`Self::blocking`]): wait for room rather than drop, and the
    /// writer takes records in batches (shared with it).
    blocking: Arc<AtomicBool>,
    /// Set by [`Self::rotate`], taken by the writer.
    rotate: Arc<AtomicBool>,
    /// Unix time minus the autopilot's boot time (ns; [`UNIX_UNKNOWN`]
    /// until `SYSTEM_TIME` gives it), taken into each record as it is
    /// logged.
    unix_minus_boot_ns: AtomicI64,
    /// The first such offset, shared with the writer: records logged before
    /// it was known are stamped with it.
    first_unix_minus_boot_ns: Arc<AtomicI64>,
    /// The daemon's alarm, raised here when records are dropped (the writer
    /// stalled: it cannot raise anything itself then).
    alarm: Option<LogAlarm>,
    /// Records are being dropped (the alarm is up).
    stalled: AtomicBool,
}

/// How long the daemon's shutdown waits for its log writer (s): a writer
/// whose file blocks must not keep the daemon from ending.
const FINISH_WAIT_S: u64 = 10;

/// [`McapLogger`]'s Unix offset before it is known.
pub(super) const UNIX_UNKNOWN: i64 = i64::MIN;

/// How a log is written beyond its file and header.
struct Options {
    /// The daemon's alarm for a file that cannot be written.
    alarm: Option<LogAlarm>,
    /// Bytes kept in memory while the file cannot be written.
    spool_max_bytes: usize,
    /// The daemon's: the next file past a size or on request.
    rotation: Option<Rotation>,
    /// Records wait for the Unix time (a log that hears SYSTEM_TIME).
    wait_for_unix: bool,
    /// The live view (or any other tap of the records).
    live: Option<Box<dyn RecordTap>>,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            alarm: None,
            spool_max_bytes: SPOOL_MAX_BYTES,
            rotation: None,
            wait_for_unix: false,
            live: None,
        }
    }
}

/// A log's name in a directory given as `log.path`.
pub const DEFAULT_NAME: &str = "cmsckf-%Y%m%d-%H%M%S.mcap";

/// Records queued at most (about 4 s of a busy flight).
const QUEUE: usize = 16_384;

impl McapLogger {
    /// A tool's log (`cmsckf replay`) to `file`, already created at `path`
    /// (see [`create_output`]).
    pub fn create(file: File, path: &Path, header: &LogHeader) -> Result<Self, LogError> {
        Self::start(Box::new(file), path, header, Options::default())
    }

    /// As [`Self::create`], for a log that replays `SYSTEM_TIME`
    /// (`cmsckf replay`): its records wait for the Unix time, as the
    /// daemon's do, so that the replayed log is stamped as the original.
    pub fn create_stamped(file: File, path: &Path, header: &LogHeader) -> Result<Self, LogError> {
        Self::start(
            Box::new(file),
            path,
            header,
            Options {
                wait_for_unix: true,
                ..Options::default()
            },
        )
    }

    /// The daemon's log: a new file named from `pattern` (its `%Y%m%d…`
    /// fields expanded), never one that exists (a suffix is added), rotated
    /// past `limits.max_file_bytes` or on [`Self::rotate`], with the
    /// directory kept under `limits.max_total_bytes`. A file that cannot be
    /// created does not stop the daemon: the log waits in memory, `alarm` is
    /// raised at the first write, and creating it is retried every second.
    /// Returns the logger and the file's path, or why it could not be created
    /// yet.
    pub fn for_flight(
        pattern: &str,
        limits: LogLimits,
        header: &LogHeader,
        alarm: LogAlarm,
        live: Option<Box<dyn RecordTap>>,
    ) -> Result<(Self, Result<PathBuf, std::io::Error>), LogError> {
        // A directory given as the path (one that exists, or a path ending
        // in `/`: a card not mounted yet): the logs go into it, named as by
        // default.
        let pattern = if pattern.ends_with('/') || Path::new(&expand_path(pattern)).is_dir() {
            Path::new(pattern).join(DEFAULT_NAME).display().to_string()
        } else {
            pattern.to_string()
        };
        let pattern = pattern.as_str();
        let wanted = PathBuf::from(expand_path(pattern));
        let (file, opened) = LogFile::new(wanted.clone());
        let path = opened.as_ref().map_or(wanted, Clone::clone);
        let rotation = Rotation::new(pattern, limits, header, &path);
        let l = Self::start(
            Box::new(file),
            &path,
            header,
            Options {
                alarm: Some(alarm),
                rotation: Some(rotation),
                wait_for_unix: true,
                live,
                ..Options::default()
            },
        )?;
        Ok((l, opened))
    }

    /// Asks the writer to close this log and begin the next (a disarm: one
    /// log per flight). Never blocks.
    pub fn rotate(&self) {
        self.rotate.store(true, Ordering::Relaxed);
    }

    /// Writes the header, schemas and channels (to memory: the writer thread
    /// writes them to `file` first) and starts the writer thread, which keeps
    /// up to `spool_max_bytes` in memory while `file` cannot be written.
    fn start(file: Box<dyn Write + Send>, path: &Path, header: &LogHeader, opts: Options) -> Result<Self, LogError> {
        let Options {
            alarm,
            spool_max_bytes,
            rotation,
            wait_for_unix,
            live,
        } = opts;
        let (w, ids, spool) = new_mcap(header, 1, None).map_err(|e| LogError::Mcap {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        let (tx, rx) = sync_channel(QUEUE);
        let dropped = Arc::new(AtomicU64::new(0));
        let blocking = Arc::new(AtomicBool::new(false));
        let rotate = Arc::new(AtomicBool::new(false));
        let first_unix_minus_boot_ns = Arc::new(AtomicI64::new(UNIX_UNKNOWN));
        let stall_alarm = alarm.clone();
        let writer = LogWriter {
            w,
            ids,
            order: reorder::Reorder::default(),
            spool,
            file,
            path: path.to_path_buf(),
            chunk: None,
            failure: None,
            first_error: None,
            unsaved_records: 0,
            spool_max_bytes,
            alarm,
            published: (0, 0),
            last_publish: Instant::now(),
            summary: LogSummary {
                files: vec![path.to_path_buf()],
                ..LogSummary::default()
            },
            rotation,
            rotate: rotate.clone(),
            first_unix_minus_boot_ns: first_unix_minus_boot_ns.clone(),
            waiting: Vec::new(),
            waiting_since: None,
            wait_for_unix,
            live,
        };
        let (d2, b2) = (dropped.clone(), blocking.clone());
        let thread = std::thread::Builder::new()
            .name("cmsckf-mcap".into())
            .spawn(move || writer.run(rx, d2, b2))
            .map_err(|source| LogError::Io {
                path: path.to_path_buf(),
                source,
            })?;
        Ok(Self {
            tx: Some(tx),
            dropped,
            thread: Some(thread),
            blocking,
            rotate,
            unix_minus_boot_ns: AtomicI64::new(UNIX_UNKNOWN),
            first_unix_minus_boot_ns,
            alarm: stall_alarm,
            stalled: AtomicBool::new(false),
        })
    }

    /// Waits for room instead of dropping when the queue is full, and lets
    /// the writer take records in batches: for `cmsckf replay`, which has no
    /// real time to keep and must not lose a record however fast it runs.
    pub fn blocking(self) -> Self {
        self.blocking.store(true, Ordering::Relaxed);
        self
    }

    /// Queues one record; never blocks (unless made [`Self::blocking`]). A
    /// full queue drops it and counts.
    pub fn log<T: Serialize>(&self, topic: Topic, t_s: f64, value: &T) {
        let Some(tx) = &self.tx else { return };
        let Ok(data) = serde_json::to_vec(value) else {
            self.dropped.fetch_add(1, Ordering::Relaxed);
            return;
        };
        let t_ns = if t_s.is_finite() && t_s > 0.0 {
            (t_s * 1e9) as u64
        } else {
            0
        };
        let rec = Record {
            topic,
            t_ns,
            unix_minus_boot_ns: self.unix_minus_boot_ns.load(Ordering::Relaxed),
            data,
        };
        if self.blocking.load(Ordering::Relaxed) {
            if tx.send(rec).is_err() {
                self.dropped.fetch_add(1, Ordering::Relaxed);
            }
            return;
        }
        match tx.try_send(rec) {
            Ok(()) => {
                if self.stalled.load(Ordering::Relaxed) && self.stalled.swap(false, Ordering::Relaxed) {
                    if let Some(a) = &self.alarm {
                        a.status.set_io(crate::status::Degraded::LogStalled, false);
                    }
                }
            }
            Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => {
                self.dropped.fetch_add(1, Ordering::Relaxed);
                if let Some(a) = &self.alarm {
                    a.counters.add(crate::counters::Counter::LogDropped, 1);
                    if !self.stalled.swap(true, Ordering::Relaxed) {
                        a.status.set_io(crate::status::Degraded::LogStalled, true);
                        let _ = a.out.try_send(Outbound::StatusText {
                            severity: 2,
                            text: "cmsckf: log stalled, records dropped".into(),
                        });
                    }
                }
            }
        }
    }

    /// The autopilot's Unix time minus its boot time (s), from its
    /// `SYSTEM_TIME`. Records are stamped with log time = boot time + this
    /// (so that viewers show the flight's date), and keep their boot time as
    /// publish time, which `review` and `replay` read. Records logged before
    /// it is known wait for it (up to 5 s of wall time, then go out in boot
    /// time). It is taken once, and again only if it moves by more than a
    /// second (an autopilot reboot, a clock step), so that log times do not
    /// jitter with SYSTEM_TIME's.
    pub fn set_unix_minus_boot(&self, offset_s: f64) {
        if !offset_s.is_finite() || offset_s <= 0.0 {
            return;
        }
        let ns = (offset_s * 1e9) as i64;
        let now = self.unix_minus_boot_ns.load(Ordering::Relaxed);
        if now == UNIX_UNKNOWN || (now - ns).abs() > 1_000_000_000 {
            self.unix_minus_boot_ns.store(ns, Ordering::Relaxed);
            let _ =
                self.first_unix_minus_boot_ns
                    .compare_exchange(UNIX_UNKNOWN, ns, Ordering::Relaxed, Ordering::Relaxed);
        }
    }

    /// Records dropped so far because the queue was full (the writer could
    /// not keep up); records lost to write errors are counted apart.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Writes everything queued, the summary and the footer. An error if the
    /// file could not be written, or if records were lost to write errors.
    pub fn finish(mut self) -> Result<LogSummary, LogError> {
        self.tx.take();
        let Some(t) = self.thread.take() else {
            return Ok(LogSummary::default());
        };
        // The daemon's shutdown waits a bounded time: a file that blocks
        // must not keep it from ending (replay waits for its whole log).
        if self.alarm.is_some() {
            let deadline = Instant::now() + std::time::Duration::from_secs(FINISH_WAIT_S);
            while !t.is_finished() {
                if Instant::now() >= deadline {
                    return Err(LogError::Stuck {
                        waited_s: FINISH_WAIT_S,
                    });
                }
                std::thread::sleep(std::time::Duration::from_millis(20));
            }
        }
        t.join().map_err(|_| LogError::Thread)?
    }
}

impl Drop for McapLogger {
    fn drop(&mut self) {
        // `finish` is the way out; this only stops the thread cleanly (a
        // daemon's writer stuck on its file is left behind).
        self.tx.take();
        if let Some(t) = self.thread.take() {
            if self.alarm.is_none() || t.is_finished() {
                let _ = t.join();
            }
        }
    }
}

/// The MCAP writer of one log file, on a spool of its own: the header
/// metadata (this is `part` of a flight's logs, after `previous`), every
/// schema and channel, flushed as a chunk of their own so that the file is
/// readable from its first write.
type NewMcap = (mcap::Writer<SpoolSink>, BTreeMap<Topic, u16>, Arc<Mutex<Spool>>);

fn new_mcap(header: &LogHeader, part: u32, previous: Option<&Path>) -> Result<NewMcap, mcap::McapError> {
    let spool = Arc::new(Mutex::new(Spool::default()));
    let mut w = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .compression_threads(1)
        .chunk_size(Some(CHUNK_MAX_BYTES))
        .profile("")
        .library(format!("cmsckf {}", header.version))
        .create(SpoolSink(spool.clone()))?;
    let mut meta = BTreeMap::new();
    meta.insert("version".to_string(), header.version.clone());
    meta.insert("mode".to_string(), header.mode.clone());
    meta.insert("config_toml".to_string(), header.config_toml.clone());
    meta.insert("log_format".to_string(), LOG_FORMAT.to_string());
    meta.insert("part".to_string(), part.to_string());
    if let Some(p) = previous.and_then(Path::file_name) {
        meta.insert("previous_log".to_string(), p.to_string_lossy().into_owned());
    }
    w.write_metadata(&mcap::records::Metadata {
        name: "cmsckf".into(),
        metadata: meta,
    })?;
    let mut ids = BTreeMap::new();
    for t in Topic::ALL {
        let (topic, schema_name, schema) = t.spec();
        let sid = w.add_schema(schema_name, "jsonschema", schema.as_bytes())?;
        let cid = w.add_channel(sid, topic, "json", &BTreeMap::new())?;
        ids.insert(t, cid);
    }
    w.flush()?;
    Ok((w, ids, spool))
}

/// Expands `%Y %m %d %H %M %S` in a log path with the current UTC time.
pub fn expand_path(pattern: &str) -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs() as i64)
        .unwrap_or(0);
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // Civil date from days since 1970-01-01 (Hinnant).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + (m <= 2) as i64;
    pattern
        .replace("%Y", &format!("{y:04}"))
        .replace("%m", &format!("{m:02}"))
        .replace("%d", &format!("{d:02}"))
        .replace("%H", &format!("{:02}", rem / 3600))
        .replace("%M", &format!("{:02}", rem % 3600 / 60))
        .replace("%S", &format!("{:02}", rem % 60))
}
