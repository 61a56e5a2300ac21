//! Tests of the whole logger: a readable log with every channel, chunks that
//! close on wall time whatever the sensor clock, and a full disk (an
//! in-memory one that fills and is freed) raising the alarm and recovering.

use std::time::Duration;

use super::*;
use crate::status::Degraded;

#[test]
fn writes_a_readable_log_with_every_channel() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("t.mcap");
    let log = McapLogger::create(
        File::create(&p).unwrap(),
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
        log.log(
            Topic::InputImu,
            t,
            &serde_json::json!({"t_us": k * 10_000, "accel_mps2": [0.0, 0.0, -9.81], "gyro_radps": [0.0, 0.0, 0.0]}),
        );
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
        // No SYSTEM_TIME in this log: log time is boot time.
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

/// A killed writer loses at most about two seconds of wall time (a second
/// held for log-time order, a second of open chunk), whatever the sensor
/// times: after a far-future stamp and a clock that went back (and stands
/// still, so sensor time never closes a chunk), records still go out after
/// a second and chunks close every second, even when no record comes.
#[test]
fn chunks_close_on_wall_time_whatever_the_sensor_clock() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("t.mcap");
    let log = McapLogger::create(File::create(&p).unwrap(), &p, &header()).unwrap();
    let imu = serde_json::json!({"t_us": 0});
    log.log(Topic::InputImu, 100.0, &imu);
    log.log(Topic::InputFeatures, 1e12, &imu); // far future (ns saturate)
    let t0 = Instant::now();
    let mut sent_by_half_s = 0;
    let mut sent = 2;
    while t0.elapsed() < Duration::from_millis(2500) {
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
        "{n} readable of {sent}, {sent_by_half_s} were sent 2 s before"
    );
    // No record since 2.5 s: the records held go out and the open chunk
    // still closes by itself.
    std::thread::sleep(Duration::from_millis(2200));
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
        Options {
            alarm: Some(alarm),
            spool_max_bytes,
            ..Options::default()
        },
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
    // The last second's records wait to be put in log-time order.
    assert!(before >= 200, "{before}");
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
        Options {
            alarm: Some(alarm),
            spool_max_bytes: 1 << 20,
            ..Options::default()
        },
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
        // The records wait a second to be put in log-time order, and the
        // chunk closes a second after its first record.
        assert!(t0.elapsed() < Duration::from_secs(3), "no alarm");
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

/// The alarm of a daemon test: its status, counters and STATUSTEXT queue.
fn alarm() -> (LogAlarm, Arc<Status>, Counters, mpsc::Receiver<Outbound>) {
    let status = Arc::new(Status::default());
    let counters = Counters::default();
    let (out, out_rx) = mpsc::channel(8);
    let a = LogAlarm {
        status: status.clone(),
        counters: counters.clone(),
        out,
    };
    (a, status, counters, out_rx)
}

fn no_limits() -> LogLimits {
    LogLimits {
        max_file_bytes: 0,
        max_total_bytes: 0,
    }
}

/// The messages of a finished log file, read by the `mcap` crate through its
/// summary.
fn finished_messages(p: &Path) -> usize {
    let bytes = std::fs::read(p).unwrap();
    assert!(
        mcap::Summary::read(&bytes).unwrap().is_some(),
        "{} has no summary",
        p.display()
    );
    mcap::MessageStream::new(&bytes).unwrap().map(Result::unwrap).count()
}

/// The reproducer: with a fixed `log.path`, the next start used to
/// truncate the crash log to 0 bytes. Now it is never opened: the new log
/// takes a suffix.
#[test]
fn a_log_name_that_exists_is_never_written_over() {
    let dir = tempfile::tempdir().unwrap();
    let fixed = dir.path().join("flight.mcap");
    std::fs::write(&fixed, b"a crash log of the last run").unwrap();
    let (a, ..) = alarm();
    let (log, opened) = McapLogger::for_flight(&fixed.display().to_string(), no_limits(), &header(), a, None).unwrap();
    let second = opened.unwrap();
    assert_eq!(second, dir.path().join("flight-1.mcap"));
    log.log(Topic::InputImu, 1.0, &serde_json::json!({"t_us": 1}));
    let s = log.finish().unwrap();
    assert_eq!(s.files, vec![second.clone()]);
    assert_eq!(std::fs::read(&fixed).unwrap(), b"a crash log of the last run");
    assert_eq!(finished_messages(&second), 1);
    // And a third start takes the next suffix.
    let (a, ..) = alarm();
    let (log, opened) = McapLogger::for_flight(&fixed.display().to_string(), no_limits(), &header(), a, None).unwrap();
    assert_eq!(opened.unwrap(), dir.path().join("flight-2.mcap"));
    log.finish().unwrap();
}

/// A log that cannot be created (its directory is a file here; a read-only
/// card alike) does not stop the daemon: the logger starts, the alarm is
/// raised at the first write (status bit, STATUSTEXT, counter), and once the
/// path can be written the whole log so far is there.
#[test]
fn an_unwritable_log_path_flies_with_the_alarm_and_catches_up() {
    let dir = tempfile::tempdir().unwrap();
    let blocker = dir.path().join("logs");
    std::fs::write(&blocker, b"not a directory").unwrap();
    let pattern = blocker.join("f.mcap").display().to_string();
    let (a, status, counters, mut out_rx) = alarm();
    let (log, opened) = McapLogger::for_flight(&pattern, no_limits(), &header(), a, None).unwrap();
    assert!(opened.is_err(), "the directory is a file");
    for k in 0..150u64 {
        log.log(Topic::InputImu, 20.0 + k as f64 * 0.01, &serde_json::json!({"t_us": k}));
    }
    let t0 = Instant::now();
    // The records wait 5 s for the Unix time (no SYSTEM_TIME here), a
    // second to be put in log-time order, and their chunk closes a second
    // after its first record.
    while (status.degraded() & Degraded::LogDiskFull.bit() == 0) && t0.elapsed() < Duration::from_secs(10) {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(
        (status.degraded() & Degraded::LogDiskFull.bit() != 0),
        "the alarm is raised"
    );
    match out_rx.try_recv() {
        Ok(Outbound::StatusText { severity, text }) => {
            assert_eq!(severity, 2);
            assert!(text.starts_with("cmsckf: log"), "{text}");
        }
        other => panic!("no STATUSTEXT: {other:?}"),
    }
    assert!(counters.get(COUNTER_WRITE_FAILED) >= 1);
    // The card comes back.
    std::fs::remove_file(&blocker).unwrap();
    std::fs::create_dir(&blocker).unwrap();
    let t0 = Instant::now();
    while (status.degraded() & Degraded::LogDiskFull.bit() != 0) && t0.elapsed() < Duration::from_secs(5) {
        log.log(Topic::InputImu, 30.0, &serde_json::json!({"t_us": 1}));
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(
        (status.degraded() & Degraded::LogDiskFull.bit() == 0),
        "the alarm clears"
    );
    let s = log.finish().unwrap();
    assert_eq!(s.dropped_write_error, 0);
    assert!(finished_messages(&blocker.join("f.mcap")) as u64 >= 150);
}

/// A directory given as `log.path` holds the logs, named as by default.
#[test]
fn a_directory_as_the_log_path_holds_the_logs() {
    let dir = tempfile::tempdir().unwrap();
    let (a, ..) = alarm();
    let (log, opened) =
        McapLogger::for_flight(&dir.path().display().to_string(), no_limits(), &header(), a, None).unwrap();
    let p = opened.unwrap();
    assert_eq!(p.parent(), Some(dir.path()));
    assert!(p.file_name().unwrap().to_string_lossy().starts_with("cmsckf-"));
    log.finish().unwrap();
}

/// One log per flight and a size limit: each file is whole (its summary),
/// names the one before it, and together they hold every record.
#[test]
fn logs_rotate_on_request_and_past_their_size_each_whole() {
    let dir = tempfile::tempdir().unwrap();
    let pattern = dir.path().join("r.mcap").display().to_string();
    let (a, ..) = alarm();
    let limits = LogLimits {
        max_file_bytes: 64 << 10,
        max_total_bytes: 0,
    };
    let (log, _) = McapLogger::for_flight(&pattern, limits, &header(), a, None).unwrap();
    // The autopilot's SYSTEM_TIME: Unix time is known.
    log.set_unix_minus_boot(1.7e9);
    let rec = |k: u64| serde_json::json!({"t_us": k, "accel_mps2": [k as f64 * 1e-3, 0.1, -9.81], "pad": (0..40u64).map(|i| ((k * 31 + i * 17) * 2_654_435_761 % 1_000_003).to_string()).collect::<String>()});
    for k in 0..200u64 {
        log.log(Topic::InputImu, 20.0 + k as f64 * 0.01, &rec(k));
    }
    std::thread::sleep(Duration::from_millis(1300));
    log.rotate();
    // 1 s of sensor time per chunk: chunks close, and the size limit moves
    // the log on.
    for k in 200..2000u64 {
        log.log(Topic::InputImu, 20.0 + k as f64 * 0.01, &rec(k));
        if k % 100 == 0 {
            std::thread::sleep(Duration::from_millis(20));
        }
    }
    let s = log.finish().unwrap();
    assert!(s.files.len() >= 3, "{:?}", s.files);
    let mut total = 0;
    for (i, f) in s.files.iter().enumerate() {
        total += finished_messages(f);
        let bytes = std::fs::read(f).unwrap();
        let meta = crate::io::mcap_log::input::cmsckf_metadata(&bytes).unwrap().unwrap();
        assert_eq!(meta["part"], (i + 1).to_string());
        if i > 0 {
            assert_eq!(
                meta["previous_log"],
                s.files[i - 1].file_name().unwrap().to_string_lossy()
            );
        }
    }
    assert_eq!(total, 2000);
}

/// The directory is kept under its total: the oldest finished logs go
/// first; a crash log (unfinished) and the one being written are kept.
#[test]
fn the_oldest_finished_logs_are_deleted_past_the_total() {
    let dir = tempfile::tempdir().unwrap();
    let finished = |name: &str| {
        let p = dir.path().join(name);
        let log = McapLogger::create(File::create(&p).unwrap(), &p, &header()).unwrap();
        log.log(Topic::Log, 1.0, &serde_json::json!({"message": "x".repeat(20_000)}));
        log.finish().unwrap();
        std::thread::sleep(Duration::from_millis(20));
        p
    };
    let oldest = finished("cmsckf-2021.mcap");
    let crash = dir.path().join("cmsckf-2022.mcap");
    std::fs::write(&crash, [&MCAP_MAGIC[..], &[0u8; 3000][..]].concat()).unwrap();
    std::thread::sleep(Duration::from_millis(20));
    let middle = finished("cmsckf-2023.mcap");
    let other = dir.path().join("notes.mcap");
    std::fs::write(&other, vec![0u8; 50_000]).unwrap();
    let current = finished("cmsckf-2024.mcap");
    let size = |p: &Path| std::fs::metadata(p).unwrap().len();
    let limit = size(&crash) + size(&middle) + size(&current) + 10;
    let deleted = enforce_total(dir.path(), "cmsckf-%Y.mcap", &current, limit);
    assert_eq!(deleted, vec![oldest.clone()]);
    assert!(!oldest.exists() && crash.exists() && middle.exists() && current.exists() && other.exists());
    // Nothing finished left but the current: the crash log stays.
    let deleted = enforce_total(dir.path(), "cmsckf-%Y.mcap", &current, 1);
    assert_eq!(deleted, vec![middle]);
    assert!(crash.exists() && current.exists());
    // Only the pattern's own names (red-team 05, 06): not a survey plan
    // that starts alike, a recovered copy, or another extension.
    assert!(matches_pattern(
        "cmsckf-20261204-061500.mcap",
        "cmsckf-%Y%m%d-%H%M%S.mcap"
    ));
    assert!(matches_pattern(
        "cmsckf-20261204-061500-3.mcap",
        "cmsckf-%Y%m%d-%H%M%S.mcap"
    ));
    assert!(matches_pattern("20261204.mcap", "%Y%m%d.mcap"));
    assert!(matches_pattern("flight-1.mcap", "flight.mcap"));
    assert!(!matches_pattern("flightplan-survey-2024.mcap", "flight.mcap"));
    assert!(!matches_pattern("flight_crash_recovered.mcap", "flight.mcap"));
    assert!(!matches_pattern(
        "cmsckf-20261204-061500-recovered.mcap",
        "cmsckf-%Y%m%d-%H%M%S.mcap"
    ));
    assert!(!matches_pattern(
        "cmsckf-20261204-061500.html",
        "cmsckf-%Y%m%d-%H%M%S.mcap"
    ));
}

/// A tool never writes over its input, and over another file only when
/// asked.
#[test]
fn a_tools_output_never_overwrites_its_input() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in.mcap");
    std::fs::write(&input, b"log").unwrap();
    let link = dir.path().join("link.mcap");
    std::fs::hard_link(&input, &link).unwrap();
    for out in [&input, &link] {
        for overwrite in [false, true] {
            assert!(matches!(
                create_output(out, &input, overwrite),
                Err(OutputError::IsInput(_))
            ));
        }
    }
    let other = dir.path().join("other.mcap");
    std::fs::write(&other, b"keep").unwrap();
    assert!(matches!(
        create_output(&other, &input, false),
        Err(OutputError::Exists(_))
    ));
    assert_eq!(std::fs::read(&other).unwrap(), b"keep");
    assert!(create_output(&other, &input, true).is_ok());
    assert_eq!(std::fs::read(&input).unwrap(), b"log");
}

/// Log time is Unix time once SYSTEM_TIME gave it, so viewers show the
/// flight's date (the issue: 1970 in Foxglove and PlotJuggler); the boot
/// time stays as the publish time. Records before it wait for it.
#[test]
fn records_are_stamped_in_unix_time_with_boot_time_kept() {
    let dir = tempfile::tempdir().unwrap();
    let pattern = dir.path().join("u.mcap").display().to_string();
    let (a, ..) = alarm();
    let (log, opened) = McapLogger::for_flight(&pattern, no_limits(), &header(), a, None).unwrap();
    let p = opened.unwrap();
    log.log(Topic::InputImu, 20.0, &serde_json::json!({"t_us": 1}));
    std::thread::sleep(Duration::from_millis(300));
    let offset_s = 1_764_800_000.0;
    log.set_unix_minus_boot(offset_s);
    // SYSTEM_TIME's jitter does not move it; a step of over a second does.
    log.set_unix_minus_boot(offset_s + 0.004);
    log.log(Topic::InputImu, 21.0, &serde_json::json!({"t_us": 2}));
    log.finish().unwrap();
    let bytes = std::fs::read(&p).unwrap();
    let times: Vec<(u64, u64)> = mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| {
            let m = m.unwrap();
            (m.log_time, m.publish_time)
        })
        .collect();
    assert_eq!(times.len(), 2);
    for (log_ns, boot_ns) in times {
        assert_eq!(
            log_ns - boot_ns,
            (offset_s * 1e9) as u64,
            "the first record waited for the Unix time"
        );
    }
}

/// Red-team 02/03: a FIFO nobody reads, as the log path or in the log
/// directory, used to hang the daemon's start. Opening it now fails at
/// once (to be tried again) and the scan for crash logs skips it.
#[test]
fn a_fifo_never_blocks_the_log() {
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("pipe.mcap");
    let c = std::ffi::CString::new(fifo.as_os_str().to_string_lossy().as_bytes()).unwrap();
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o644) }, 0);
    let t0 = Instant::now();
    assert!(create_unique(&fifo).is_err(), "no reader: ENXIO, not a hang");
    assert!(unfinished_logs(dir.path(), &dir.path().join("x.mcap"), 3).is_empty());
    assert!(!is_finished(&fifo).unwrap());
    assert!(t0.elapsed() < Duration::from_secs(2));
}

/// Red-team 11/04: a missing log directory (a card not mounted yet) is not
/// created on the root filesystem; the log waits, with the alarm, and goes
/// into the directory once it appears, under the default name when the
/// path names a directory.
#[test]
fn a_missing_log_directory_is_waited_for_not_created() {
    let dir = tempfile::tempdir().unwrap();
    let card = dir.path().join("card");
    let (a, status, ..) = alarm();
    let pattern = format!("{}/logs/", card.display());
    let (log, opened) = McapLogger::for_flight(&pattern, no_limits(), &header(), a, None).unwrap();
    assert!(opened.is_err());
    log.set_unix_minus_boot(1.7e9);
    for k in 0..50u64 {
        log.log(Topic::InputImu, 20.0 + k as f64 * 0.01, &serde_json::json!({"t_us": k}));
    }
    let t0 = Instant::now();
    while (status.degraded() & Degraded::LogDiskFull.bit() == 0) && t0.elapsed() < Duration::from_secs(5) {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(
        status.degraded() & Degraded::LogDiskFull.bit() != 0,
        "the alarm is raised"
    );
    assert!(!card.exists(), "nothing was created where the card mounts");
    // The card mounts.
    std::fs::create_dir_all(card.join("logs")).unwrap();
    let t0 = Instant::now();
    while (status.degraded() & Degraded::LogDiskFull.bit() != 0) && t0.elapsed() < Duration::from_secs(5) {
        log.log(Topic::InputImu, 30.0, &serde_json::json!({"t_us": 1}));
        std::thread::sleep(Duration::from_millis(50));
    }
    let s = log.finish().unwrap();
    let files: Vec<_> = std::fs::read_dir(card.join("logs"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(files.len(), 1, "{files:?}");
    assert!(files[0].file_name().unwrap().to_string_lossy().starts_with("cmsckf-"));
    assert!(finished_messages(&files[0]) >= 50);
    assert_eq!(s.dropped_write_error, 0);
}

/// Red-team 10: the daemon's own new log, named relatively, is not an
/// unfinished log of an earlier run.
#[test]
fn the_new_log_is_not_its_own_crash_log() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("new.mcap");
    std::fs::write(&p, MCAP_MAGIC).unwrap();
    let same = dir.path().join(".").join("new.mcap");
    assert!(unfinished_logs(dir.path(), &same, 3).is_empty());
}

/// The "72 of 77 chunks overlap": records come in the order the
/// fusion loop makes them (a frame fused 80 ms after it was taken, a GNSS
/// epoch 600 ms after), and go into the file in log-time order, chunks that
/// do not overlap, and sequence numbers that give back the order they came.
#[test]
fn records_are_written_in_log_time_order_and_keep_their_arrival_order() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("order.mcap");
    let log = McapLogger::create(File::create(&p).unwrap(), &p, &header())
        .unwrap()
        .blocking();
    let mut sent = 0u64;
    for k in 0..6000u64 {
        let t = k as f64 * 0.001;
        let mut send = |topic: Topic, t_s: f64| {
            log.log(topic, t_s, &serde_json::json!({ "arrival": sent }));
            sent += 1;
        };
        send(Topic::InputImu, t);
        if k % 50 == 0 && t >= 0.08 {
            send(Topic::InputFeatures, t - 0.08);
        }
        if k % 200 == 0 && t >= 0.6 {
            send(Topic::GnssFix, t - 0.6);
        }
    }
    let s = log.finish().unwrap();
    assert_eq!((s.messages, s.late), (sent, 0));
    let bytes = std::fs::read(&p).unwrap();
    let mut last_log_time = 0;
    let mut by_sequence = Vec::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        assert!(m.log_time >= last_log_time, "log time goes back in the file");
        last_log_time = m.log_time;
        let v: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
        by_sequence.push((m.sequence, v["arrival"].as_u64().unwrap()));
    }
    by_sequence.sort_unstable();
    let arrivals: Vec<u64> = by_sequence.iter().map(|x| x.1).collect();
    assert_eq!(arrivals, (0..sent).collect::<Vec<_>>(), "sequence is the arrival order");
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let mut chunks: Vec<_> = summary.chunk_indexes.iter().collect();
    assert!(chunks.len() >= 5, "{} chunks", chunks.len());
    chunks.sort_by_key(|c| c.chunk_start_offset);
    for w in chunks.windows(2) {
        assert!(
            w[1].message_start_time >= w[0].message_end_time,
            "chunks overlap: {:?} then {:?}",
            (w[0].message_start_time, w[0].message_end_time),
            (w[1].message_start_time, w[1].message_end_time)
        );
    }
}
