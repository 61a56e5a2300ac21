//! Interoperability: pymavlink (an independent MAVLink implementation) sends
//! HIGHRES_IMU that the daemon consumes, and decodes the daemon's estimates:
//! ODOMETRY alone by default (finite covariances, a quality in −1..100),
//! or VISION_POSITION_ESTIMATE with VISION_SPEED_ESTIMATE, with their
//! covariance and reset_counter.
//! Needs `python3` with `venv`; `pymavlink` is installed into the tests' own environment (`common::python`).
mod common;

use std::process::Command;
use std::time::Duration;

use cmsckf::config::OutputMessage;

/// Runs the pymavlink autopilot for 3 s against a daemon sending `message`;
/// returns its JSON summary.
async fn exchange(message: OutputMessage, mode: &'static str) -> serde_json::Value {
    let dir = tempfile::tempdir().unwrap();
    let (mut cfg, port) = common::loopback_config(dir.path());
    cfg.output.message = message;
    let (stop_tx, daemon) = common::spawn_daemon(cfg);
    tokio::time::sleep(Duration::from_millis(200)).await;
    let python = common::python_with(&["pymavlink"]);
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/interop_pymavlink.py");
    let out = tokio::task::spawn_blocking(move || {
        Command::new(&python)
            .arg(script)
            .arg(port.to_string())
            .arg("3")
            .arg(mode)
            .output()
    })
    .await
    .unwrap()
    .expect("the tests' Python");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !stderr.contains("No module named"),
        "pymavlink is not installed: {stderr}"
    );
    let _ = stop_tx.send(());
    let summary = daemon.await.unwrap().unwrap();
    assert!(
        out.status.success(),
        "pymavlink check failed ({mode}): {stdout} {stderr}"
    );
    assert!(
        summary.counters.get("imu_highres").copied().unwrap_or(0) > 200,
        "{:?}",
        summary.counters
    );
    eprintln!("{}", stdout.trim());
    serde_json::from_str(stdout.trim()).unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pymavlink_talks_to_the_daemon_both_ways() {
    // The default: ODOMETRY, and never VISION_POSITION_ESTIMATE with it.
    let v = exchange(OutputMessage::Odometry, "odometry").await;
    assert!(v["odometry_received"].as_u64().unwrap() > 20, "{v}");
    assert_eq!(v["vpe_received"].as_u64(), Some(0), "{v}");
    // VISION_POSITION_ESTIMATE, each with its VISION_SPEED_ESTIMATE.
    let v = exchange(OutputMessage::VisionPositionEstimate, "vision_position_estimate").await;
    assert!(v["vpe_received"].as_u64().unwrap() > 20, "{v}");
    assert!(v["speed_received"].as_u64().unwrap() > 20, "{v}");
    assert_eq!(v["odometry_received"].as_u64(), Some(0), "{v}");
}
