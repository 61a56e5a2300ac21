//! `cmsckf demo --frontend` end to end, as a user runs it: the SITL renders
//! the camera's images and serves them on a Unix socket, cmsckf-frontend's
//! loop tracks them and writes the daemon's feature socket, the daemon flies
//! on them and answers the SITL autopilot over loopback UDP. A short
//! racetrack (15 s, real time): every rendered frame reaches the front-end
//! and every tracked frame the daemon, which never resets and keeps its
//! 30 Hz output; its accuracy stays within a bound measured on this flight.

use std::process::Command;

#[test]
fn the_demo_flies_on_rendered_images_through_the_front_end() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("front.mcap");
    let out = Command::new(env!("CARGO_BIN_EXE_cmsckf"))
        .args(["demo", "--frontend", "--duration-s", "15", "--json", "--log"])
        .arg(&log)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "demo failed: {stderr}");
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("one JSON report");
    eprintln!("{report}");
    assert_eq!(report["daemon_alive"], true);
    assert_eq!(report["reset_count"], 0);
    // 15 s at 20 Hz, less what the camera's latency leaves past the end.
    let sent = report["frames_sent"].as_u64().unwrap();
    assert!(sent >= 290, "{sent} frames rendered and sent");
    let front = &report["frontend"];
    assert_eq!(front["frames"].as_u64().unwrap(), sent, "every frame tracked");
    assert_eq!(front["frames_not_delivered"], 0);
    assert_eq!(front["frames_out_of_order"], 0);
    assert!(front["features_detected"].as_u64().unwrap() > 1000);
    assert!(report["output_rate_hz"].as_f64().unwrap() > 25.0);
    let ate = report["ate_m"].as_f64().unwrap();
    assert!(ate.is_finite() && ate < 2.0, "ATE {ate} m");
    assert!(log.exists(), "flight log written");
}
