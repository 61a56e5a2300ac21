//! A full log disk is loud at once and does not stop the flight: the daemon
//! logs to `/dev/full` (every write fails with ENOSPC). Its first write (the
//! first chunk, a moment after the first input) raises `log_disk_full`: a
//! critical HEARTBEAT with its `STATUSTEXT` reason, and the explicit
//! "cmsckf: log disk full". Estimates go on at their rate; the write
//! failures and the records lost are counted; at SIGTERM the journal names
//! the write error, not "writer could not keep up".

mod common;

use std::time::{Duration, Instant};

use cmsckf::eval;
use cmsckf_sitl::dataset::Dataset;
use cmsckf_sitl::serve::{serve, ServeOptions};

/// The value of counter `name` in the journal's "cmsckf stopped" line
/// (`counters={"name": n, ...}`).
fn counter(journal: &str, name: &str) -> Option<u64> {
    let line = journal.lines().find(|l| l.contains("cmsckf stopped"))?;
    let rest = &line[line.find(&format!("\"{name}\": "))? + name.len() + 4..];
    rest.split(|c: char| !c.is_ascii_digit()).next()?.parse().ok()
}

#[test]
fn a_full_log_disk_is_loud_at_once_and_the_flight_goes_on() {
    let dir = tempfile::tempdir().unwrap();
    let (mut cfg, port) = common::loopback_config(dir.path());
    cfg.log.path = "/dev/full".into();
    let journal_path = dir.path().join("journal.txt");
    let mut daemon = common::spawn_daemon_binary_journal(&cfg, dir.path(), "info", &journal_path);
    let ds = Dataset::generate("racetrack", 5, Some(20.0), &eval::sim_config_for(&cfg)).unwrap();
    let opts = ServeOptions {
        mavlink: format!("udpout:127.0.0.1:{port}"),
        feature_socket: cfg.features.socket.clone().into(),
        speedup: 10.0,
        faults: Vec::new(),
        gnss_stream: None,
        camera_socket: None,
    };
    let report = tokio::runtime::Runtime::new()
        .unwrap()
        .block_on(serve(&opts, &ds))
        .unwrap();
    // The SIGTERM of the incident, after the flight.
    unsafe {
        libc::kill(daemon.id() as i32, libc::SIGTERM);
    }
    let t_term = Instant::now();
    let status = loop {
        if let Some(s) = daemon.try_wait().unwrap() {
            break Some(s);
        }
        if t_term.elapsed() > Duration::from_secs(5) {
            let _ = daemon.kill();
            break None;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let journal = std::fs::read_to_string(&journal_path).unwrap();
    for t in &report.status_texts {
        eprintln!("STATUSTEXT {:.1} s: {}", t.0, t.1);
    }
    let relevant: Vec<&str> = journal
        .lines()
        .filter(|l| l.contains("MCAP") || l.contains("log") && l.contains("ERROR") || l.contains("stopped"))
        .collect();
    eprintln!("{}", relevant.join("\n"));
    assert!(
        status.is_some_and(|s| s.success()),
        "the daemon stops cleanly on SIGTERM: {status:?}"
    );

    // Loud at once: the explicit STATUSTEXT and the degraded reason, within
    // five seconds of flight (0.5 s of wall time) of the start; the incident's
    // took 31 s, and came at SIGTERM.
    let explicit = report.status_texts.iter().find(|t| t.1 == "cmsckf: log disk full");
    let degraded = report
        .status_texts
        .iter()
        .find(|t| t.1.starts_with("cmsckf degraded:") && t.1.contains("log_disk_full"));
    let (Some(explicit), Some(degraded)) = (explicit, degraded) else {
        panic!("no disk-full STATUSTEXT: {:?}", report.status_texts);
    };
    assert!(explicit.0 < 5.0 && degraded.0 < 5.0, "late: {explicit:?} {degraded:?}");
    // The flight goes on: estimates at their rate, the whole flight long.
    eprintln!(
        "{} estimates, {:.1} Hz, ATE {:.2} m",
        report.estimates_received, report.output_rate_hz, report.ate_m
    );
    assert!(report.output_rate_hz > 25.0, "{} Hz", report.output_rate_hz);
    // Counted, and the journal names the write error, also at shutdown.
    let failed = counter(&journal, "log_write_failed").unwrap_or(0);
    let lost = counter(&journal, "log_records_dropped_write_error").unwrap_or(0);
    assert!(failed >= 2, "log_write_failed {failed}");
    assert!(lost > 1000, "log_records_dropped_write_error {lost}");
    assert_eq!(counter(&journal, "log_dropped"), None, "no queue overflow");
    assert!(journal.contains("ALARM: the MCAP log cannot be written"));
    let shutdown = journal
        .lines()
        .find(|l| l.contains("could not be finished"))
        .expect("the shutdown says why the log is not whole");
    assert!(shutdown.contains("No space left on device"), "{shutdown}");
    assert!(!journal.contains("could not keep up"));
}
