//! Interoperability: pymavlink (an independent MAVLink implementation) sends
//! HIGHRES_IMU that the daemon consumes, and decodes the daemon's
//! VISION_POSITION_ESTIMATE with its covariance and reset_counter.
//! Needs `python3` with `pymavlink` (CI installs it).
mod common;

use std::process::Command;
use std::time::Duration;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pymavlink_talks_to_the_daemon_both_ways() {
    let dir = tempfile::tempdir().unwrap();
    let (cfg, port) = common::loopback_config(dir.path());
    let (stop_tx, daemon) = common::spawn_daemon(cfg);
    tokio::time::sleep(Duration::from_millis(200)).await;
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/interop_pymavlink.py");
    let out = tokio::task::spawn_blocking(move || {
        Command::new("python3")
            .arg(script)
            .arg(port.to_string())
            .arg("3")
            .output()
    })
    .await
    .unwrap()
    .expect("python3 is needed for this test");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !stderr.contains("No module named"),
        "pymavlink is not installed: {stderr}"
    );
    let _ = stop_tx.send(());
    let summary = daemon.await.unwrap().unwrap();
    assert!(out.status.success(), "pymavlink check failed: {stdout} {stderr}");
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    assert!(v["vpe_received"].as_u64().unwrap() > 20, "{v}");
    assert!(
        summary.counters.get("imu_highres").copied().unwrap_or(0) > 200,
        "{:?}",
        summary.counters
    );
}
