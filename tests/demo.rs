//! The demo as the README runs it, on the simulator's default IMU, an armed
//! multirotor's (200 Hz, a turn-on gyro bias of 0.08 rad/s σ, motor
//! vibration at a real vehicle's levels): the daemon starts statically within its window,
//! takes zero-velocity updates on the vibrating ground, flies without a
//! reset, and its report carries the figures a user reads: the first
//! estimate's time, the ZUPTs, the lowest quality, the position NEES as
//! the autopilot reads our covariance, and the NIS per degree of freedom.

use std::process::Command;

#[test]
fn the_demo_flies_on_an_armed_vibrating_imu_and_reports_its_confidence() {
    // Run where a user would, in a directory of its own: the flight log
    // lands there (not in the source tree).
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_cmsckf"))
        .args(["demo", "--duration-s", "40", "--json"])
        .current_dir(dir.path())
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let r: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let logs: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.path().extension().is_some_and(|x| x == "mcap"))
        .collect();
    assert_eq!(logs.len(), 1, "the demo writes one flight log in its working directory");
    let num = |k: &str| r[k].as_f64().unwrap_or_else(|| panic!("{k} missing: {r}"));
    eprintln!(
        "first estimate {:.2} s, ZUPTs {}, resets {}, ATE {:.3} m, position NEES {:.2} ({:.0}% in 95%), NIS/dof {:.2}, lowest quality {}",
        num("time_to_first_estimate_s"),
        num("zupt_updates"),
        num("reset_count"),
        num("ate_m"),
        num("position_nees_mean"),
        100.0 * num("position_nees_in95"),
        num("nis_per_dof"),
        r["quality_min"]
    );
    // A static start in the 1 s window, though every sample shakes.
    assert!(num("time_to_first_estimate_s") < 3.0);
    assert!(num("zupt_updates") > 50.0, "the vibrating ground is still");
    assert_eq!(num("reset_count"), 0.0);
    assert!(num("ate_m") < 2.0);
    assert!(num("position_nees_in95") >= 0.9);
    assert!((0.5..=2.0).contains(&num("nis_per_dof")));
    // ODOMETRY's quality: 1 at the first estimates (nothing fused yet),
    // within its range always.
    let q = r["quality_min"].as_i64().expect("ODOMETRY's quality reported");
    assert!((-1..=100).contains(&q));
}
