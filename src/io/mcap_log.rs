//! The MCAP flight log: every input and every filter event, as JSON with a
//! JSON schema, in zstd chunks of at most about one second of sensor time.
//!
//! The writer runs on its own thread, fed by a bounded channel: logging never
//! blocks the fusion loop. When the channel is full the record is dropped and
//! counted ([`McapLogger::dropped`]); the daemon raises an alarm if any are.
//! Log time and publish time are both the sensor time (autopilot clock).
//! [`McapLogger::finish`] must be called on shutdown (`Drop` cannot report
//! errors); a log whose writer was killed is readable up to its last chunk.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TryRecvError, TrySendError};
use std::sync::Arc;
use std::thread::JoinHandle;

use serde::Serialize;

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
    pub dropped: u64,
}

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
const WRITER_PAUSE: std::time::Duration = std::time::Duration::from_micros(500);
/// A chunk is closed once it spans this much sensor time (ns).
const CHUNK_SPAN_NS: u64 = 1_000_000_000;

impl McapLogger {
    /// Creates the file and starts the writer thread.
    pub fn create(path: &Path, header: &LogHeader) -> Result<Self, LogError> {
        let file = File::create(path).map_err(|source| LogError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let mcap_err = |e: mcap::McapError| LogError::Mcap {
            path: path.to_path_buf(),
            message: e.to_string(),
        };
        let mut w = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .compression_threads(1)
            .chunk_size(Some(8 << 20))
            .profile("")
            .library(format!("cmsckf {}", header.version))
            .create(BufWriter::new(file))
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
        let (tx, rx) = sync_channel(QUEUE);
        let dropped = Arc::new(AtomicU64::new(0));
        let d2 = dropped.clone();
        let blocking = Arc::new(AtomicBool::new(false));
        let b2 = blocking.clone();
        let p = path.to_path_buf();
        let thread = std::thread::Builder::new()
            .name("cmsckf-mcap".into())
            .spawn(move || writer_loop(w, ids, rx, d2, b2, p))
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

    /// Records dropped so far.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Writes everything queued, the summary and the footer.
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

fn writer_loop(
    mut w: mcap::Writer<BufWriter<File>>,
    ids: BTreeMap<Topic, u16>,
    rx: Receiver<Record>,
    dropped: Arc<AtomicU64>,
    blocking: Arc<AtomicBool>,
    path: PathBuf,
) -> Result<LogSummary, LogError> {
    let err = |e: mcap::McapError| LogError::Mcap {
        path: path.clone(),
        message: e.to_string(),
    };
    let mut seq: BTreeMap<u16, u32> = BTreeMap::new();
    let mut chunk_start: Option<u64> = None;
    let mut summary = LogSummary::default();
    // Takes what is queued; once the queue is empty it blocks for the next
    // record. For replay it first pauses briefly, so that the writer is rarely waiting on
    // the channel and the sender seldom has to wake it (a system call each,
    // about 4 % of a replay). The daemon's writer does not pause: with a
    // worker thread computing rebases on a 2-core machine, the pauses'
    // timer wake-ups took the fusion loop's IMU-to-output latency p99 from
    // 0.56 ms to 1.9 ms.
    loop {
        let r = match rx.try_recv() {
            Ok(r) => r,
            Err(TryRecvError::Disconnected) => break,
            Err(TryRecvError::Empty) => {
                if blocking.load(Ordering::Relaxed) {
                    std::thread::sleep(WRITER_PAUSE);
                }
                match rx.recv() {
                    Ok(r) => r,
                    Err(_) => break,
                }
            }
        };
        let Some(&cid) = ids.get(&r.topic) else { continue };
        // Close the chunk once it spans a second of sensor time, so a killed
        // writer loses at most about that much.
        if let Some(s) = chunk_start {
            if r.t_ns.saturating_sub(s) >= CHUNK_SPAN_NS {
                w.flush().map_err(err)?;
                summary.chunks += 1;
                chunk_start = None;
            }
        }
        chunk_start.get_or_insert(r.t_ns);
        let s = seq.entry(cid).or_insert(0);
        *s = s.wrapping_add(1);
        w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: cid,
                sequence: *s,
                log_time: r.t_ns,
                publish_time: r.t_ns,
            },
            &r.data,
        )
        .map_err(err)?;
        summary.messages += 1;
    }
    w.finish().map_err(err)?;
    summary.chunks += 1;
    summary.dropped = dropped.load(Ordering::Relaxed);
    Ok(summary)
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

    #[test]
    fn path_pattern() {
        let p = expand_path("cmsckf-%Y%m%d-%H%M%S.mcap");
        assert_eq!(p.len(), "cmsckf-20261126-160000.mcap".len());
        assert!(p.starts_with("cmsckf-20"));
    }
}
