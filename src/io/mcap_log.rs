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

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, RecvTimeoutError, SyncSender, TryRecvError, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use serde::Serialize;
use tokio::sync::mpsc;

use crate::io::messages::Outbound;
use crate::io::Counters;
use crate::status::{Degraded, Status};

/// The log's channels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Topic {
    InputImu,
    InputFeatures,
    InputRtcm,
    InputSystemTime,
    InputAutopilot,
    /// Where the fusion loop installed a rebase computed on its worker
    /// thread (an input: replay installs it at the same point).
    InputRebase,
    FilterVision,
    FilterGnss,
    FilterGlobal,
    FilterKeyframes,
    FilterState,
    OutputVpe,
    Pose,
    Transform,
    GnssFix,
    Log,
    /// Every counter (rejections by reason included) and the degraded-state
    /// reasons, once a second of autopilot time and at shutdown.
    Diagnostics,
}

impl Topic {
    pub const ALL: [Topic; 17] = [
        Topic::InputImu,
        Topic::InputFeatures,
        Topic::InputRtcm,
        Topic::InputSystemTime,
        Topic::InputAutopilot,
        Topic::InputRebase,
        Topic::FilterVision,
        Topic::FilterGnss,
        Topic::FilterGlobal,
        Topic::FilterKeyframes,
        Topic::FilterState,
        Topic::OutputVpe,
        Topic::Pose,
        Topic::Transform,
        Topic::GnssFix,
        Topic::Log,
        Topic::Diagnostics,
    ];

    /// `(topic name, schema name, JSON schema)`.
    pub fn spec(self) -> (&'static str, &'static str, &'static str) {
        match self {
            Topic::InputImu => ("/input/imu", "cmsckf.Imu", SCHEMA_IMU),
            Topic::InputFeatures => ("/input/features", "cmsckf.FeatureFrame", SCHEMA_FEATURES),
            Topic::InputRtcm => ("/input/rtcm", "cmsckf.Rtcm", SCHEMA_RTCM),
            Topic::InputSystemTime => ("/input/mavlink/system_time", "cmsckf.SystemTime", SCHEMA_SYSTEM_TIME),
            Topic::InputAutopilot => ("/input/mavlink/autopilot", "cmsckf.AutopilotState", SCHEMA_OBJECT),
            Topic::InputRebase => ("/input/rebase_installed", "cmsckf.RebaseInstalled", SCHEMA_OBJECT),
            Topic::FilterVision => ("/filter/update/vision", "cmsckf.VisionUpdate", SCHEMA_OBJECT),
            Topic::FilterGnss => ("/filter/update/gnss", "cmsckf.GnssUpdate", SCHEMA_OBJECT),
            Topic::FilterGlobal => ("/filter/update/global", "cmsckf.GlobalUpdate", SCHEMA_OBJECT),
            Topic::FilterKeyframes => ("/filter/keyframes", "cmsckf.Keyframe", SCHEMA_OBJECT),
            Topic::FilterState => ("/filter/state", "cmsckf.State", SCHEMA_OBJECT),
            Topic::OutputVpe => (
                "/output/vision_position_estimate",
                "cmsckf.VisionPositionEstimate",
                SCHEMA_OBJECT,
            ),
            Topic::Pose => ("/pose", "foxglove.PoseInFrame", SCHEMA_POSE_IN_FRAME),
            Topic::Transform => ("/tf", "foxglove.FrameTransform", SCHEMA_FRAME_TRANSFORM),
            Topic::GnssFix => ("/gnss/fix", "foxglove.LocationFix", SCHEMA_LOCATION_FIX),
            Topic::Log => ("/log", "foxglove.Log", SCHEMA_LOG),
            Topic::Diagnostics => ("/diagnostics", "cmsckf.Diagnostics", SCHEMA_OBJECT),
        }
    }
}

const SCHEMA_OBJECT: &str = r#"{"type":"object"}"#;
const SCHEMA_IMU: &str = r#"{"type":"object","properties":{"t_us":{"type":"integer","description":"autopilot boot time (µs)"},"accel_mps2":{"type":"array","items":{"type":"number"},"description":"specific force, FRD (m/s²)"},"gyro_radps":{"type":"array","items":{"type":"number"},"description":"angular rate, FRD (rad/s)"}}}"#;
const SCHEMA_FEATURES: &str = r#"{"type":"object","properties":{"t_us":{"type":"integer"},"cam":{"type":"integer"},"features":{"type":"array","items":{"type":"array","description":"[landmark_id, u_px, v_px]"}}}}"#;
const SCHEMA_RTCM: &str = r#"{"type":"object","properties":{"bytes":{"type":"array","items":{"type":"integer"},"description":"raw RTCM3 bytes as received"}}}"#;
const SCHEMA_SYSTEM_TIME: &str =
    r#"{"type":"object","properties":{"unix_us":{"type":"integer"},"boot_ms":{"type":"integer"}}}"#;
// Foxglove's well-known schemas (MIT-licensed), in their JSON form.
const SCHEMA_POSE_IN_FRAME: &str = r#"{"title":"foxglove.PoseInFrame","description":"A timestamped pose for an object or reference frame in 3D space","$comment":"Generated by https://github.com/foxglove/schemas","type":"object","properties":{"timestamp":{"type":"object","title":"time","properties":{"sec":{"type":"integer","minimum":0},"nsec":{"type":"integer","minimum":0,"maximum":999999999}},"description":"Timestamp of pose"},"frame_id":{"type":"string","description":"Frame of reference for pose position and orientation"},"pose":{"title":"foxglove.Pose","description":"Pose in 3D space","type":"object","properties":{"position":{"title":"foxglove.Vector3","description":"Point denoting position in 3D space","type":"object","properties":{"x":{"type":"number","description":"x coordinate length"},"y":{"type":"number","description":"y coordinate length"},"z":{"type":"number","description":"z coordinate length"}}},"orientation":{"title":"foxglove.Quaternion","description":"Quaternion denoting orientation in 3D space","type":"object","properties":{"x":{"type":"number","description":"x value"},"y":{"type":"number","description":"y value"},"z":{"type":"number","description":"z value"},"w":{"type":"number","description":"w value"}}}}}}}"#;
const SCHEMA_FRAME_TRANSFORM: &str = r#"{"title":"foxglove.FrameTransform","description":"A transform between two reference frames in 3D space","$comment":"Generated by https://github.com/foxglove/schemas","type":"object","properties":{"timestamp":{"type":"object","title":"time","properties":{"sec":{"type":"integer","minimum":0},"nsec":{"type":"integer","minimum":0,"maximum":999999999}},"description":"Timestamp of transform"},"parent_frame_id":{"type":"string","description":"Name of the parent frame"},"child_frame_id":{"type":"string","description":"Name of the child frame"},"translation":{"title":"foxglove.Vector3","description":"Translation component of the transform","type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}}},"rotation":{"title":"foxglove.Quaternion","description":"Rotation component of the transform","type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"},"w":{"type":"number"}}}}}"#;
const SCHEMA_LOCATION_FIX: &str = r#"{"title":"foxglove.LocationFix","description":"A navigation satellite fix for any Global Navigation Satellite System","$comment":"Generated by https://github.com/foxglove/schemas","type":"object","properties":{"timestamp":{"type":"object","title":"time","properties":{"sec":{"type":"integer","minimum":0},"nsec":{"type":"integer","minimum":0,"maximum":999999999}},"description":"Timestamp of the message"},"frame_id":{"type":"string","description":"Frame for the sensor"},"latitude":{"type":"number","description":"Latitude in degrees"},"longitude":{"type":"number","description":"Longitude in degrees"},"altitude":{"type":"number","description":"Altitude in meters"},"position_covariance":{"type":"array","items":{"type":"number"},"minItems":9,"maxItems":9,"description":"Position covariance (m^2) defined relative to a tangential plane through the reported position. The components are East, North, and Up (ENU), in row-major order."},"position_covariance_type":{"title":"foxglove.PositionCovarianceType","description":"If `position_covariance` is available, `position_covariance_type` must be set to indicate the type of covariance.","oneOf":[{"title":"UNKNOWN","const":0},{"title":"APPROXIMATED","const":1},{"title":"DIAGONAL_KNOWN","const":2},{"title":"KNOWN","const":3}]}}}"#;
const SCHEMA_LOG: &str = r#"{"title":"foxglove.Log","description":"A log message","$comment":"Generated by https://github.com/foxglove/schemas","type":"object","properties":{"timestamp":{"type":"object","title":"time","properties":{"sec":{"type":"integer","minimum":0},"nsec":{"type":"integer","minimum":0,"maximum":999999999}},"description":"Timestamp of log message"},"level":{"title":"foxglove.LogLevel","description":"Log level","oneOf":[{"title":"UNKNOWN","const":0},{"title":"DEBUG","const":1},{"title":"INFO","const":2},{"title":"WARNING","const":3},{"title":"ERROR","const":4},{"title":"FATAL","const":5}]},"message":{"type":"string","description":"Log message"},"name":{"type":"string","description":"Process or node name"},"file":{"type":"string","description":"Filename"},"line":{"type":"integer","minimum":0,"description":"Line number in the file"}}}"#;

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
#[derive(Clone, Debug)]
pub struct LogAlarm {
    pub status: Arc<Status>,
    pub counters: Counters,
    pub out: mpsc::Sender<Outbound>,
}

/// Counter of failed writes of the log file ([`LogSummary::write_failures`]).
pub const COUNTER_WRITE_FAILED: &str = "log_write_failed";
/// Counter of records lost to write errors ([`LogSummary::dropped_write_error`]).
pub const COUNTER_DROPPED_WRITE_ERROR: &str = "log_records_dropped_write_error";

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
const CHUNK_MAX_BYTES: u64 = 8 << 20;
/// How often a failed write of the file is retried.
const RETRY_WALL: Duration = Duration::from_secs(1);
/// Bytes kept in memory while the file cannot be written; beyond this,
/// records are dropped (and counted) until a write succeeds.
const SPOOL_MAX_BYTES: usize = 32 << 20;
/// The memory the spool keeps after a failure is over (bytes).
const SPOOL_KEEP_BYTES: usize = 8 << 20;
/// How often the writer's counts are published to the daemon's counters
/// while records are being lost.
const PUBLISH_WALL: Duration = Duration::from_secs(1);

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

/// The bytes the MCAP writer has produced and the file does not have yet.
///
/// The MCAP writer cannot go on after an error of its output (it fails every
/// later call), so it writes to memory, which never fails; the writer thread
/// copies whole chunks to the file. A failed copy leaves the bytes here to be
/// retried, and the file a prefix of a well-formed log.
#[derive(Debug, Default)]
struct Spool {
    buf: Vec<u8>,
    /// Offset in the log of `buf[0]`: the bytes before it are in the file.
    base: u64,
    /// The MCAP writer's position in `buf` (it goes back to fill in a
    /// chunk's header when it closes the chunk).
    pos: usize,
    /// Bytes of `buf` already in the file (a partial write).
    sent: usize,
}

impl Spool {
    /// Bytes not yet in the file.
    fn unsent(&self) -> usize {
        self.buf.len() - self.sent
    }
}

/// Locks the spool (a panic elsewhere poisons nothing the writer needs).
fn lock(spool: &Mutex<Spool>) -> std::sync::MutexGuard<'_, Spool> {
    spool.lock().unwrap_or_else(|p| p.into_inner())
}

/// The MCAP writer's output: the [`Spool`], shared with the writer thread.
struct SpoolSink(Arc<Mutex<Spool>>);

impl Write for SpoolSink {
    fn write(&mut self, data: &[u8]) -> std::io::Result<usize> {
        let mut guard = lock(&self.0);
        let s = &mut *guard;
        let over = (s.buf.len() - s.pos).min(data.len());
        s.buf[s.pos..s.pos + over].copy_from_slice(&data[..over]);
        s.buf.extend_from_slice(&data[over..]);
        s.pos += data.len();
        Ok(data.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Seek for SpoolSink {
    fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
        let mut s = lock(&self.0);
        let (base, len) = (i128::from(s.base), s.buf.len() as i128);
        let target = match to {
            SeekFrom::Start(n) => i128::from(n),
            SeekFrom::End(d) => base + len + i128::from(d),
            SeekFrom::Current(d) => base + s.pos as i128 + i128::from(d),
        };
        // Only within what the file does not have yet.
        if target < base + s.sent as i128 || target > base + len {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                "MCAP log: seek outside the unwritten part",
            ));
        }
        s.pos = (target - base) as usize;
        Ok(target as u64)
    }
}

/// The chunk being filled.
#[derive(Clone, Copy, Debug)]
struct OpenChunk {
    /// Wall time of its first record.
    opened: Instant,
    /// Its records' earliest and latest sensor times (ns).
    t_min_ns: u64,
    t_max_ns: u64,
}

/// The file cannot be written (since `since`).
#[derive(Debug)]
struct Failure {
    /// The first error of the episode (the reason).
    first: std::io::Error,
    since: Instant,
    next_retry: Instant,
    /// The explicit STATUSTEXT still has to be queued (the queue was full).
    text_pending: bool,
}

/// The writer thread's state.
struct LogWriter {
    w: mcap::Writer<SpoolSink>,
    ids: BTreeMap<Topic, u16>,
    seq: BTreeMap<u16, u32>,
    spool: Arc<Mutex<Spool>>,
    file: Box<dyn Write + Send>,
    path: PathBuf,
    chunk: Option<OpenChunk>,
    failure: Option<Failure>,
    /// Records given to the MCAP writer since the file last took all it was
    /// given: lost if it never does.
    unsaved_records: u64,
    /// Bytes kept in memory while the file cannot be written
    /// ([`SPOOL_MAX_BYTES`]).
    spool_max_bytes: usize,
    /// The reason of the first failure that is over (for the error at the end).
    first_error: Option<std::io::Error>,
    alarm: Option<LogAlarm>,
    /// `(write_failures, dropped_write_error)` already added to the alarm's
    /// counters.
    published: (u64, u64),
    last_publish: Instant,
    summary: LogSummary,
}

impl LogWriter {
    /// Writes records until the channel closes, then the summary.
    fn run(
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
        if let Some(f) = &mut self.failure {
            if f.text_pending {
                f.text_pending = !send_text(self.alarm.as_ref(), &f.first);
            }
        }
        if now >= self.last_publish + PUBLISH_WALL {
            self.publish();
        }
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

    /// Writes what the file does not have yet (whole chunks: no chunk is
    /// open). While the file cannot be written, only once
    /// [`RETRY_WALL`] has passed since the last try.
    fn save(&mut self) {
        let now = Instant::now();
        if self.failure.as_ref().is_some_and(|f| now < f.next_retry) {
            return;
        }
        match write_spool(&self.spool, &mut *self.file) {
            Ok(()) => self.on_saved(now),
            Err(e) => self.on_write_error(e, now),
        }
    }

    /// Everything given so far is in the file: a failure is over.
    fn on_saved(&mut self, now: Instant) {
        self.unsaved_records = 0;
        let Some(f) = self.failure.take() else {
            return;
        };
        tracing::warn!(
            path = %self.path.display(),
            after_s = now.duration_since(f.since).as_secs_f64(),
            lost = self.summary.dropped_write_error,
            "MCAP log can be written again"
        );
        if let Some(a) = &self.alarm {
            a.status.set_io(Degraded::LogDiskFull, false);
        }
        self.first_error.get_or_insert(f.first);
        self.publish();
    }

    /// A write of the file failed: at the first, the alarm (status bit,
    /// STATUSTEXT, error in the journal); at each, a count and a retry
    /// [`RETRY_WALL`] later.
    fn on_write_error(&mut self, e: std::io::Error, now: Instant) {
        self.summary.write_failures += 1;
        let next_retry = now + RETRY_WALL;
        if let Some(f) = &mut self.failure {
            f.next_retry = next_retry;
            tracing::debug!(error = %e, "MCAP log: retried write failed");
            return;
        }
        tracing::error!(
            path = %self.path.display(),
            error = %e,
            "ALARM: the MCAP log cannot be written; records are kept in memory (up to {} MiB) and retried every {} s, then dropped",
            self.spool_max_bytes >> 20,
            RETRY_WALL.as_secs()
        );
        if let Some(a) = &self.alarm {
            a.status.set_io(Degraded::LogDiskFull, true);
        }
        let text_pending = !send_text(self.alarm.as_ref(), &e);
        self.failure = Some(Failure {
            first: e,
            since: now,
            next_retry,
            text_pending,
        });
        self.publish();
    }

    /// Adds the counts of write failures and records lost since the last
    /// time to the alarm's counters.
    fn publish(&mut self) {
        self.last_publish = Instant::now();
        let Some(a) = &self.alarm else { return };
        let now = (self.summary.write_failures, self.summary.dropped_write_error);
        if now.0 > self.published.0 {
            a.counters.add(COUNTER_WRITE_FAILED, now.0 - self.published.0);
        }
        if now.1 > self.published.1 {
            a.counters.add(COUNTER_DROPPED_WRITE_ERROR, now.1 - self.published.1);
        }
        self.published = now;
    }

    fn mcap_err(&self, e: mcap::McapError) -> LogError {
        LogError::Mcap {
            path: self.path.clone(),
            message: e.to_string(),
        }
    }
}

/// Writes the spool's unsent bytes to `file`; on success the spool is
/// emptied. A partial write is remembered, so a retry goes on from there.
fn write_spool(spool: &Mutex<Spool>, file: &mut dyn Write) -> std::io::Result<()> {
    let mut guard = lock(spool);
    let s = &mut *guard;
    while s.sent < s.buf.len() {
        match file.write(&s.buf[s.sent..]) {
            Ok(0) => return Err(std::io::ErrorKind::WriteZero.into()),
            Ok(n) => s.sent += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    file.flush()?;
    s.base += s.buf.len() as u64;
    s.buf.clear();
    if s.buf.capacity() > SPOOL_KEEP_BYTES {
        s.buf.shrink_to(SPOOL_KEEP_BYTES);
    }
    s.pos = 0;
    s.sent = 0;
    Ok(())
}

/// Queues the explicit STATUSTEXT of a write failure (critical); false if
/// the queue was full (try again later).
fn send_text(alarm: Option<&LogAlarm>, e: &std::io::Error) -> bool {
    let Some(a) = alarm else { return true };
    let text = match e.kind() {
        std::io::ErrorKind::StorageFull | std::io::ErrorKind::QuotaExceeded => "cmsckf: log disk full".to_string(),
        _ => match e.raw_os_error() {
            Some(n) => format!("cmsckf: log write failed (os error {n})"),
            None => "cmsckf: log write failed".to_string(),
        },
    };
    !matches!(
        a.out.try_send(Outbound::StatusText { severity: 2, text }),
        Err(mpsc::error::TrySendError::Full(_))
    )
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_a_readable_log_with_every_channel() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.mcap");
        let log = McapLogger::create(
            &p,
            &LogHeader {
                version: "test".into(),
                mode: "compressed".into(),
                config_toml: "[estimator]\n".into(),
            },
        )
        .unwrap();
        for k in 0..300 {
            let t = k as f64 * 0.01;
            log.log(Topic::InputImu, t, &serde_json::json!({"t_us": k * 10_000, "accel_mps2": [0.0, 0.0, -9.81], "gyro_radps": [0.0, 0.0, 0.0]}));
        }
        log.log(Topic::Log, 1.0, &serde_json::json!({"timestamp": {"sec": 1, "nsec": 0}, "level": 2, "message": "hi", "name": "cmsckf", "file": "", "line": 0}));
        let s = log.finish().unwrap();
        assert_eq!(s.messages, 301);
        assert!(s.chunks >= 3, "{s:?}");
        let bytes = std::fs::read(&p).unwrap();
        let mut topics = std::collections::BTreeSet::new();
        let mut n = 0;
        for m in mcap::MessageStream::new(&bytes).unwrap() {
            let m = m.unwrap();
            topics.insert(m.channel.topic.clone());
            assert_eq!(m.log_time, m.publish_time);
            n += 1;
        }
        assert_eq!(n, 301);
        assert!(topics.contains("/input/imu") && topics.contains("/log"));
        let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
        let names: Vec<_> = summary.schemas.values().map(|s| s.name.clone()).collect();
        assert!(names.contains(&"foxglove.PoseInFrame".to_string()) && names.contains(&"foxglove.Log".to_string()));
        assert_eq!(summary.channels.len(), Topic::ALL.len());
    }

    fn header() -> LogHeader {
        LogHeader {
            version: "test".into(),
            mode: "compressed".into(),
            config_toml: "[estimator]\n".into(),
        }
    }

    /// Messages readable from a log's bytes (up to the first unreadable).
    fn readable(bytes: &[u8]) -> Vec<(String, u64)> {
        let mut v = Vec::new();
        let Ok(stream) = mcap::MessageStream::new(bytes) else {
            return v;
        };
        for m in stream {
            match m {
                Ok(m) => v.push((m.channel.topic.clone(), m.log_time)),
                Err(_) => break,
            }
        }
        v
    }

    /// A killed writer loses at most about a second of wall time, whatever
    /// the sensor times: after a far-future stamp and a clock that went back
    /// (and stands still, so sensor time never closes a chunk), chunks still
    /// close every second, even when no record comes.
    #[test]
    fn chunks_close_on_wall_time_whatever_the_sensor_clock() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.mcap");
        let log = McapLogger::create(&p, &header()).unwrap();
        let imu = serde_json::json!({"t_us": 0});
        log.log(Topic::InputImu, 100.0, &imu);
        log.log(Topic::InputFeatures, 1e12, &imu); // far future (ns saturate)
        let t0 = Instant::now();
        let mut sent_by_half_s = 0;
        let mut sent = 2;
        while t0.elapsed() < Duration::from_millis(1500) {
            // The clock went back to 5 s (a reboot) and stays there.
            log.log(Topic::InputImu, 5.0, &imu);
            sent += 1;
            if t0.elapsed() < Duration::from_millis(500) {
                sent_by_half_s = sent;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        // "Killed" now: the file alone, read while the writer is alive.
        std::thread::sleep(Duration::from_millis(100));
        let n = readable(&std::fs::read(&p).unwrap()).len();
        assert!(
            n >= sent_by_half_s,
            "{n} readable of {sent}, {sent_by_half_s} were sent 1 s before"
        );
        // No record since 1.5 s: the open chunk still closes by itself.
        std::thread::sleep(Duration::from_millis(1100));
        let n = readable(&std::fs::read(&p).unwrap()).len();
        assert_eq!(n, sent, "every record in the file without a new one");
        let s = log.finish().unwrap();
        assert_eq!(s.messages, sent as u64);
        assert_eq!(s.dropped + s.dropped_write_error + s.write_failures, 0);
    }

    /// A disk that fills at `limit` bytes (ENOSPC beyond: a write that
    /// crosses it is partial) and can be freed.
    #[derive(Clone, Default)]
    struct Disk {
        bytes: Arc<Mutex<Vec<u8>>>,
        limit: Arc<AtomicU64>,
    }

    impl Disk {
        fn new() -> Self {
            let d = Self::default();
            d.limit.store(u64::MAX, Ordering::Relaxed);
            d
        }
        fn len(&self) -> usize {
            self.bytes.lock().unwrap().len()
        }
        fn contents(&self) -> Vec<u8> {
            self.bytes.lock().unwrap().clone()
        }
    }

    impl Write for Disk {
        fn write(&mut self, data: &[u8]) -> std::io::Result<usize> {
            let mut b = self.bytes.lock().unwrap();
            let room = self.limit.load(Ordering::Relaxed).saturating_sub(b.len() as u64) as usize;
            if room == 0 {
                return Err(std::io::Error::from_raw_os_error(libc::ENOSPC));
            }
            let n = room.min(data.len());
            b.extend_from_slice(&data[..n]);
            Ok(n)
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    /// The disk fills mid-flight: the alarm is raised at the first failed
    /// write (status bit, one critical STATUSTEXT, counters), logging never
    /// blocks, records beyond the memory bound are dropped and counted, the
    /// file stays readable; when space is freed the log catches up, the bit
    /// clears, and the finished log is whole but for the dropped records.
    #[test]
    fn a_full_disk_raises_the_alarm_at_once_and_the_log_recovers() {
        let disk = Disk::new();
        let status = Arc::new(Status::default());
        let counters = Counters::default();
        let (out, mut out_rx) = mpsc::channel(8);
        let alarm = LogAlarm {
            status: status.clone(),
            counters: counters.clone(),
            out,
        };
        let spool_max_bytes = 64 << 10;
        let log = McapLogger::start(
            Box::new(disk.clone()),
            Path::new("disk.mcap"),
            &header(),
            Some(alarm),
            spool_max_bytes,
        )
        .unwrap();
        // 10 ms apart in sensor time: a chunk closes every 100 records.
        let rec = |k: u64| serde_json::json!({"t_us": k * 10_000, "accel_mps2": [k as f64 * 1e-3, 0.1, -9.81]});
        let t_s = |k: u64| 20.0 + k as f64 * 0.01;
        let mut k = 0;
        while k < 350 {
            log.log(Topic::InputImu, t_s(k), &rec(k));
            k += 1;
        }
        std::thread::sleep(Duration::from_millis(200));
        assert!(disk.len() > 0 && status.degraded() == 0);
        let before = readable(&disk.contents()).len();
        assert!(before >= 300, "{before}");
        // The disk fills 100 bytes on: the next chunk is written in part.
        disk.limit.store(disk.len() as u64 + 100, Ordering::Relaxed);
        let t_fill = Instant::now();
        while k < 500 {
            log.log(Topic::InputImu, t_s(k), &rec(k));
            k += 1;
        }
        while status.degraded() & Degraded::LogDiskFull.bit() == 0 {
            assert!(t_fill.elapsed() < Duration::from_secs(2), "no alarm");
            std::thread::sleep(Duration::from_millis(5));
        }
        eprintln!(
            "alarm {:.0} ms after the disk filled",
            t_fill.elapsed().as_secs_f64() * 1e3
        );
        match out_rx.try_recv() {
            Ok(Outbound::StatusText { severity, text }) => {
                assert_eq!((severity, text.as_str()), (2, "cmsckf: log disk full"));
            }
            other => panic!("no STATUSTEXT: {other:?}"),
        }
        assert!(out_rx.try_recv().is_err(), "one STATUSTEXT only");
        assert_eq!(counters.get(COUNTER_WRITE_FAILED), 1);
        // The file is a readable prefix: nothing after the full disk, and
        // what was readable still is.
        assert_eq!(readable(&disk.contents()).len(), before);
        // Logging goes on without blocking (at 20 000 records/s, ten times a
        // flight's): past the memory bound, records are dropped and counted,
        // not queued.
        let mut logging = Duration::ZERO;
        while k < 20_000 {
            let t = Instant::now();
            for _ in 0..200 {
                log.log(Topic::InputImu, t_s(k), &rec(k));
                k += 1;
            }
            logging += t.elapsed();
            std::thread::sleep(Duration::from_millis(10));
        }
        assert!(
            logging < Duration::from_millis(500),
            "19 500 records took {logging:?} to queue"
        );
        std::thread::sleep(Duration::from_millis(1200));
        assert_eq!(log.dropped(), 0, "the queue never filled");
        let lost = counters.get(COUNTER_DROPPED_WRITE_ERROR); // published once a second
        assert!(lost > 0 && lost < 20_000, "{lost}");
        assert!(counters.get(COUNTER_WRITE_FAILED) >= 2, "retried");
        assert_ne!(status.degraded() & Degraded::LogDiskFull.bit(), 0);
        // Space is freed: the next retry (≤ 1 s) writes what waited.
        disk.limit.store(u64::MAX, Ordering::Relaxed);
        let t_free = Instant::now();
        while status.degraded() & Degraded::LogDiskFull.bit() != 0 {
            assert!(t_free.elapsed() < Duration::from_secs(3), "the bit stays");
            log.log(Topic::InputImu, t_s(k), &rec(k));
            k += 1;
            std::thread::sleep(Duration::from_millis(2));
        }
        let after_free = k;
        for _ in 0..100 {
            log.log(Topic::InputImu, t_s(k), &rec(k));
            k += 1;
        }
        let lost = match log.finish() {
            Err(LogError::Write {
                records_lost, source, ..
            }) => {
                assert_eq!(source.raw_os_error(), Some(libc::ENOSPC));
                assert!(source.to_string().contains("No space left"), "{source}");
                records_lost
            }
            other => panic!("records were lost: {other:?}"),
        };
        assert_eq!(counters.get(COUNTER_DROPPED_WRITE_ERROR), lost);
        // The finished log: whole (summary and all), every record but the
        // dropped ones, in order, the last ones included.
        let bytes = disk.contents();
        let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
        let msgs = readable(&bytes);
        assert_eq!(msgs.len() as u64, k - lost);
        assert_eq!(summary.stats.unwrap().message_count, k - lost);
        let last_t = msgs.iter().map(|m| m.1).max().unwrap();
        assert_eq!(last_t, (t_s(k - 1) * 1e9) as u64);
        assert!(msgs.iter().any(|m| m.1 == (t_s(after_free) * 1e9) as u64));
        assert!(msgs.windows(2).all(|w| w[0].1 < w[1].1), "in order");
    }

    /// A disk full from the start (`/dev/full`-like) and never freed: the
    /// alarm at once, and `finish` names the write error.
    #[test]
    fn a_disk_full_from_the_start_is_reported_and_named_at_the_end() {
        let disk = Disk::new();
        disk.limit.store(0, Ordering::Relaxed);
        let status = Arc::new(Status::default());
        let counters = Counters::default();
        let (out, mut out_rx) = mpsc::channel(8);
        let alarm = LogAlarm {
            status: status.clone(),
            counters: counters.clone(),
            out,
        };
        let log = McapLogger::start(
            Box::new(disk.clone()),
            Path::new("full.mcap"),
            &header(),
            Some(alarm),
            1 << 20,
        )
        .unwrap();
        for k in 0..100 {
            log.log(
                Topic::InputImu,
                20.0 + k as f64 * 0.001,
                &serde_json::json!({"t_us": k}),
            );
        }
        let t0 = Instant::now();
        while status.degraded() == 0 {
            // The chunk closes a second after its first record.
            assert!(t0.elapsed() < Duration::from_secs(2), "no alarm");
            std::thread::sleep(Duration::from_millis(2));
        }
        assert!(matches!(
            out_rx.try_recv(),
            Ok(Outbound::StatusText { severity: 2, .. })
        ));
        match log.finish() {
            Err(e @ LogError::Write { records_lost: 100, .. }) => {
                let msg = e.to_string();
                assert!(
                    msg.contains("No space left on device") && msg.contains("100 records lost"),
                    "{msg}"
                );
                assert!(!msg.contains("keep up"));
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(counters.get(COUNTER_DROPPED_WRITE_ERROR), 100);
        assert!(counters.get(COUNTER_WRITE_FAILED) >= 2, "the first and the last try");
        assert_eq!(disk.len(), 0);
    }

    #[test]
    fn path_pattern() {
        let p = expand_path("cmsckf-%Y%m%d-%H%M%S.mcap");
        assert_eq!(p.len(), "cmsckf-20261126-160000.mcap".len());
        assert!(p.starts_with("cmsckf-20"));
    }
}
