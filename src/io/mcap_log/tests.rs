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
