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
            Ok(m) => last = last.max(m.log_time),
            Err(_) => break,
        }
    }
    let last_flight_s = last as f64 * 1e-9 - BOOT0_S;
    eprintln!(
        "killed at ≈{kill_flight_s:.2} s of flight; log readable to {last_flight_s:.2} s; {:?}",
        r.messages
    );
    // Up to about a second before the kill (a chunk spans ≤ 1 s; allow the
    // writer's queue and the SITL's pacing another second).
    assert!(
        last_flight_s > kill_flight_s - 2.5,
        "lost {:.2} s",
        kill_flight_s - last_flight_s
    );

    // Unfinished: a reader that seeks through the summary finds none.
    common::python_modules(&["mcap"]);
    let seeking = |path: &std::path::Path| {
        std::process::Command::new("python3")
            .arg(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/read_mcap.py"))
            .arg("--seeking")
            .arg(path)
            .output()
            .expect("python3 is needed for this test")
    };
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
    let py_last_s = py["last_log_time_ns"].as_u64().unwrap() as f64 * 1e-9 - BOOT0_S;
    assert!(
        py_last_s > kill_flight_s - 2.5,
        "recovered to {py_last_s:.2} s of {kill_flight_s:.2} s"
    );
    // Recovering a finished log changes nothing it holds.
    let again = dir.path().join("again.mcap");
    let r2 = cmsckf::io::mcap_log::recover(&fixed, &again).unwrap();
    assert!(r2.input_was_complete && r2.tail_bytes_dropped == 0 && r2.messages_kept == kept);

    // The next start names the unfinished log.
    let next = dir.path().join("next.mcap");
    assert_eq!(
        cmsckf::io::mcap_log::unfinished_logs(dir.path(), &next, 3),
        vec![log.clone()]
    );
}
