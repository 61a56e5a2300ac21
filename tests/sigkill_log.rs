//! A SIGKILL mid-flight leaves an MCAP log that `review` reads up to about a
//! second before the kill: chunks are closed every second of wall time, and
//! sooner when their records span a second of sensor time (this flight runs
//! at 10×). `cmsckf log recover` then rewrites it with indexes and a
//! summary, and the independent Python reader reads it the way seeking
//! readers (PlotJuggler) do. A daemon started again names the unfinished
//! log. After a jump of the sensor clock: `log_time_jumps.rs`.

mod common;

use std::time::Duration;

use cmsckf::eval;
use cmsckf_sitl::dataset::Dataset;
use cmsckf_sitl::serve::BOOT0_S;

use common::harness;

#[test]
fn sigkill_leaves_a_readable_log() {
    let dir = tempfile::tempdir().unwrap();
    let (mut cfg, port) = common::loopback_config(dir.path());
    let log = dir.path().join("killed.mcap");
    cfg.log.path = log.display().to_string();
    let mut daemon = common::spawn_daemon_binary(&cfg, dir.path());
    let ds = Dataset::generate("racetrack", 2, Some(30.0), &eval::sim_config_for(&cfg)).unwrap();
    let speedup = 10.0;
    let sitl = harness::fly_in_background(harness::serve_options(&cfg, port, speedup), ds);
    // Kill at 1.5 s of wall time = 15 s of flight.
    let kill_flight_s = harness::sigkill_after(&mut daemon, sitl, Duration::from_millis(1500), speedup);

    let r = cmsckf::review::review(&log, None, None, None).unwrap();
    assert!(r.truncated, "a killed writer leaves no summary");
    // Sensor time of the last readable record, relative to the flight start.
    let bytes = std::fs::read(&log).unwrap();
    let mut last = 0u64;
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        match m {
            Ok(m) => last = last.max(m.publish_time),
            Err(_) => break,
        }
    }
    let last_flight_s = last as f64 * 1e-9 - BOOT0_S;
    eprintln!(
        "killed at ≈{kill_flight_s:.2} s of flight; log readable to {last_flight_s:.2} s; {:?}",
        r.messages
    );
    // Up to about two seconds before the kill: records wait up to a second
    // of log time to be written in order, and a chunk spans ≤ 1 s (2.03 s
    // lost in a run here); allow the writer's queue and the SITL's pacing
    // another second, and a loaded machine's scheduling half a second more
    // (3.02 s lost in a clean-clone CI run on 2026-12-06, in an hour when
    // this machine ran its benches 1.5-2x slower).
    assert!(
        last_flight_s > kill_flight_s - 3.5,
        "lost {:.2} s",
        kill_flight_s - last_flight_s
    );

    // Unfinished: a reader that seeks through the summary finds none.
    let seeking = |path: &std::path::Path| common::read_mcap(&[std::ffi::OsStr::new("--seeking"), path.as_os_str()]);
    assert!(!seeking(&log).status.success(), "a killed log has no summary");
    assert!(!cmsckf::io::mcap_log::is_finished(&log).unwrap());

    // Recovered by the command a user runs.
    let fixed = dir.path().join("recovered.mcap");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_cmsckf"))
        .args(["log", "recover"])
        .arg(&log)
        .arg(&fixed)
        .arg("--json")
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let rep: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    eprintln!("recover: {rep}");
    assert_eq!(rep["input_was_complete"], false);
    assert_eq!(rep["chunks_dropped"], 0);
    assert!(cmsckf::io::mcap_log::is_finished(&fixed).unwrap());
    // Every message review read from the killed log is kept.
    let kept = rep["messages_kept"].as_u64().unwrap();
    assert_eq!(kept, r.messages);
    let py = seeking(&fixed);
    assert!(
        py.status.success(),
        "Python seeking reader: {} {}",
        String::from_utf8_lossy(&py.stdout),
        String::from_utf8_lossy(&py.stderr)
    );
    let py: serde_json::Value = serde_json::from_slice(&py.stdout).unwrap();
    let py_total: u64 = py["counts"]
        .as_object()
        .unwrap()
        .values()
        .map(|v| v.as_u64().unwrap())
        .sum();
    assert_eq!(py_total, kept);
    let py_last_s = py["last_publish_time_ns"].as_u64().unwrap() as f64 * 1e-9 - BOOT0_S;
    assert!(
        py_last_s > kill_flight_s - 3.0,
        "recovered to {py_last_s:.2} s of {kill_flight_s:.2} s"
    );
    // Recovering a finished log changes nothing it holds.
    let again = dir.path().join("again.mcap");
    let r2 = cmsckf::io::mcap_log::recover(&fixed, &again, false).unwrap();
    assert!(r2.input_was_complete && r2.tail_bytes_dropped == 0 && r2.messages_kept == kept);

    // The next start names the unfinished log.
    let next = dir.path().join("next.mcap");
    assert_eq!(
        cmsckf::io::mcap_log::unfinished_logs(dir.path(), &next, 3),
        vec![log.clone()]
    );

    // The reproducer: a restart under the same fixed `log.path`
    // (systemd's Restart=on-failure, a second later) used to truncate the
    // crash log to 0 bytes. It now logs to a new name and leaves it whole.
    let crash = std::fs::read(&log).unwrap();
    let mut again = common::spawn_daemon_binary(&cfg, dir.path());
    let second = dir.path().join("killed-1.mcap");
    for _ in 0..100 {
        if second.exists() {
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    harness::sigterm(&mut again);
    assert!(second.exists(), "the restarted daemon logs to killed-1.mcap");
    assert_eq!(std::fs::read(&log).unwrap(), crash, "the crash log is untouched");
}

/// A log path that cannot be written (here its directory is a file; a
/// card remounted read-only alike) used to stop the daemon at start. It now
/// flies, and says so: a critical STATUSTEXT and HEARTBEAT degraded.
#[test]
fn an_unwritable_log_path_does_not_ground_the_vehicle() {
    let dir = tempfile::tempdir().unwrap();
    let (mut cfg, port) = common::loopback_config(dir.path());
    let blocker = dir.path().join("card");
    std::fs::write(&blocker, b"a file where the log directory should be").unwrap();
    cfg.log.path = blocker.join("flight.mcap").display().to_string();
    let mut daemon = common::spawn_daemon_binary(&cfg, dir.path());
    let ds = Dataset::generate("racetrack", 2, Some(15.0), &eval::sim_config_for(&cfg)).unwrap();
    let report = harness::fly(&harness::serve_options(&cfg, port, 5.0), &ds);
    let status = harness::sigterm(&mut daemon);
    eprintln!(
        "estimates {} ATE {:.2} m; status texts {:?}",
        report.estimates_received, report.ate_m, report.status_texts
    );
    assert!(report.estimates_received > 300, "the daemon flew");
    assert!(report.ate_m < 1.5, "and well: {:.2} m", report.ate_m);
    assert!(
        report.status_texts.iter().any(|(_, t)| t.starts_with("cmsckf: log")),
        "the pilot is told: {:?}",
        report.status_texts
    );
    assert!(
        status.code().is_some(),
        "the daemon exited by itself on SIGTERM: {status:?}"
    );
}
