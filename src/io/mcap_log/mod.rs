//! The MCAP flight log: every input and every filter event, as JSON with a
//! JSON schema, in zstd chunks.
//!
//! It exists so that a flight can be reviewed and replayed afterwards, even
//! one that ended badly. The writer runs on its own thread, fed by a bounded
//! channel: logging never blocks the fusion loop. When the channel is full
//! the record is dropped and counted ([`McapLogger::dropped`]); the daemon
//! raises an alarm if any are. Log time and publish time are both the
//! sensor time (autopilot clock).
//!
//! A chunk is closed and written to the file once it has been open for a
//! second of wall time (or its records span a second of sensor time, or it
//! reaches 8 MB), so a killed writer loses at most about a second, whatever
//! the sensor clock did (an autopilot reboot, a far-future stamp): the file
//! is readable up to its last whole chunk. [`McapLogger::finish`] must be
//! called on shutdown (`Drop` cannot report errors).
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

mod failure;
pub mod input;
mod recover;
mod schemas;
mod spool;
#[cfg(test)]
mod tests;
mod topics;
mod writer;

pub use input::{InputRecord, RecordError, LOG_FORMAT};
pub use recover::{is_finished, recover, unfinished_logs, RecoverError, RecoverReport, MCAP_MAGIC};
pub use topics::Topic;

use std::collections::BTreeMap;
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Instant;

use serde::Serialize;
use tokio::sync::mpsc;

use crate::counters::{Counter, Counters};
use crate::io::messages::Outbound;
use crate::status::Status;

use spool::{Spool, SpoolSink, SPOOL_MAX_BYTES};
use writer::{LogWriter, CHUNK_MAX_BYTES};

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
}

/// Records queued at most (about 4 s of a busy flight).
const QUEUE: usize = 16_384;

impl McapLogger {
    /// Creates the file and starts the writer thread.
    pub fn create(path: &Path, header: &LogHeader) -> Result<Self, LogError> {
        Self::open(path, header, None)
    }

    /// As [`Self::create`], raising `alarm` at once when the file cannot be
    /// written (the daemon); the log goes on in memory meanwhile and catches
    /// up if space is freed.
    pub fn create_with_alarm(path: &Path, header: &LogHeader, alarm: LogAlarm) -> Result<Self, LogError> {
        Self::open(path, header, Some(alarm))
    }

    fn open(path: &Path, header: &LogHeader, alarm: Option<LogAlarm>) -> Result<Self, LogError> {
        let file = File::create(path).map_err(|source| LogError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::start(Box::new(file), path, header, alarm, SPOOL_MAX_BYTES)
    }

    /// Writes the header, schemas and channels (to memory: the writer thread
    /// writes them to `file` first) and starts the writer thread, which keeps
    /// up to `spool_max_bytes` in memory while `file` cannot be written.
    fn start(
        file: Box<dyn Write + Send>,
        path: &Path,
        header: &LogHeader,
        alarm: Option<LogAlarm>,
        spool_max_bytes: usize,
    ) -> Result<Self, LogError> {
        let mcap_err = |e: mcap::McapError| LogError::Mcap {
            path: path.to_path_buf(),
            message: e.to_string(),
        };
        let spool = Arc::new(Mutex::new(Spool::default()));
        let mut w = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .compression_threads(1)
            .chunk_size(Some(CHUNK_MAX_BYTES))
            .profile("")
            .library(format!("cmsckf {}", header.version))
            .create(SpoolSink(spool.clone()))
            .map_err(mcap_err)?;
        let mut meta = BTreeMap::new();
        meta.insert("version".to_string(), header.version.clone());
        meta.insert("mode".to_string(), header.mode.clone());
        meta.insert("config_toml".to_string(), header.config_toml.clone());
        meta.insert("log_format".to_string(), LOG_FORMAT.to_string());
        w.write_metadata(&mcap::records::Metadata {
            name: "cmsckf".into(),
            metadata: meta,
        })
        .map_err(mcap_err)?;
        let mut ids = BTreeMap::new();
        for t in Topic::ALL {
            let (topic, schema_name, schema) = t.spec();
            let sid = w
                .add_schema(schema_name, "jsonschema", schema.as_bytes())
                .map_err(mcap_err)?;
            let cid = w.add_channel(sid, topic, "json", &BTreeMap::new()).map_err(mcap_err)?;
            ids.insert(t, cid);
        }
        // The schemas and channels as a whole chunk of their own, so the
        // file is readable from its first write.
        w.flush().map_err(mcap_err)?;
        let (tx, rx) = sync_channel(QUEUE);
        let dropped = Arc::new(AtomicU64::new(0));
        let blocking = Arc::new(AtomicBool::new(false));
        let writer = LogWriter {
            w,
            ids,
            seq: BTreeMap::new(),
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
            summary: LogSummary::default(),
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
        let rec = Record { topic, t_ns, data };
        if self.blocking.load(Ordering::Relaxed) {
            if tx.send(rec).is_err() {
                self.dropped.fetch_add(1, Ordering::Relaxed);
            }
            return;
        }
        match tx.try_send(rec) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => {
                self.dropped.fetch_add(1, Ordering::Relaxed);
            }
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
        match self.thread.take() {
            Some(t) => t.join().map_err(|_| LogError::Thread)?,
            None => Ok(LogSummary::default()),
        }
    }
}

impl Drop for McapLogger {
    fn drop(&mut self) {
        // `finish` is the way out; this only stops the thread cleanly.
        self.tx.take();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
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
