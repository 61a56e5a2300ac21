//! Fault injection: one SITL flight with every injectable fault. The daemon
//! survives each one, its HEARTBEAT shows it degraded, its estimate stays
//! bounded (or is reset, for the autopilot's reboot), it recovers within 5 s
//! of the fault's end, and the matching rejections are counted.

mod common;

use cmsckf::eval;
use cmsckf_sitl::dataset::Dataset;
use cmsckf_sitl::serve::{serve, Fault, ServeOptions};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_daemon_rides_through_injected_faults() {
    let dir = tempfile::tempdir().unwrap();
    let (mut cfg, port) = common::loopback_config(dir.path());
    cfg.gnss.iono = cmsckf::gnss::IonoMode::Off; // the simulated sky has none
    let (stop_tx, daemon) = common::spawn_daemon(cfg.clone());
    tokio::time::sleep(std::time::Duration::from_millis(200)).await;
    // The durations: a 5 s link drop, a 60 s GNSS outage, a 10 s
    // camera outage, a 1 s IMU gap; one fault at a time.
    let faults: Vec<Fault> = [
        "link_drop@10+5",
        "gnss_outage@22+60",
        "camera_outage@88+10",
        "imu_gap@105+1",
        "nan_imu@110+0.5",
        "rtcm_bad_crc@113+3",
        "pr_outlier@118+5",
        "frontend_restart@125+2",
        "dup_reorder@129+2",
        "clock_jump@134+2",
        "imu_spike@141+1",
    ]
    .iter()
    .map(|f| f.parse().unwrap())
    .collect();
    let ds = Dataset::generate("racetrack", 3, Some(148.0), &eval::sim_config_for(&cfg)).unwrap();
    let report = serve(
        &ServeOptions {
            mavlink: format!("udpout:127.0.0.1:{port}"),
            feature_socket: cfg.features.socket.clone().into(),
            speedup: 10.0,
            faults,
        },
        &ds,
    )
    .await
    .unwrap();
    let _ = stop_tx.send(());
    let summary = daemon.await.unwrap().expect("the daemon survived to the end");
    let c = |k: &str| summary.counters.get(k).copied().unwrap_or(0);
    for t in &report.status_texts {
        eprintln!("STATUSTEXT {:.1} s: {}", t.0, t.1);
    }
    for f in &report.faults {
        eprintln!("{f:?}");
        assert!(
            f.degraded_reported,
            "{}: HEARTBEAT never showed a degraded state",
            f.name
        );
        // Bounded, or reset (a fooled filter may run far before it is caught).
        // Without GNSS the bound is visual-inertial drift: 2% of the ≈15 m/s
        // flown, on top of 5 m.
        let bound = 5.0
            + if f.name == "gnss_outage" {
                0.02 * 15.0 * (f.end_s - f.start_s)
            } else {
                0.0
            };
        assert!(
            f.peak_error_m < bound || f.resets > 0,
            "{}: peak error {} m",
            f.name,
            f.peak_error_m
        );
        assert!(
            f.recovery_s.is_finite() && f.recovery_s <= 5.0,
            "{}: recovery {} s",
            f.name,
            f.recovery_s
        );
    }
    // The reboot, the long link drop and the divergence after the IMU spike
    // are the only resets, and each told the autopilot why.
    let resets: Vec<(&str, u32)> = report.faults.iter().map(|f| (f.name.as_str(), f.resets)).collect();
    // The 5 s link drop is a 5 s IMU gap: the motion is unknown, the filter
    // restarts.
    let expected = |n: &str| u32::from(n == "clock_jump" || n == "imu_spike" || n == "link_drop");
    assert!(resets.iter().all(|(n, r)| *r == expected(n)), "{resets:?}");
    assert_eq!(report.reset_count, 3);
    assert_eq!(c("imu_gap_restart"), 1);
    assert_eq!(c("autopilot_clock_reset"), 1);
    assert_eq!(c("filter_reset"), 1);
    assert!(report.status_texts.iter().any(|t| t.1.contains("reboot")));
    assert!(report.status_texts.iter().any(|t| t.1.contains("reset: divergence")));
    assert!(report.status_texts.iter().any(|t| t.1.contains("degraded")));
    // Over the whole flight, with 60 s of visual-inertial drift and a fooled
    // filter in it.
    assert!(report.ate_m < 3.0, "ATE {}", report.ate_m);
    // Each fault left its trace in the counters.
    assert!(c("imu_gap") >= 2, "link drop and IMU gap");
    assert!(c("mavlink_rejected_non_finite") > 0, "NaN IMU");
    assert!(c("mavlink_rejected_imu_out_of_range") > 0, "absurd IMU");
    assert!(c("rtcm_crc_failure") > 0, "bad RTCM CRC");
    assert!(
        c("gnss_pseudorange_chi2") + c("gnss_pseudorange_outlier") > 0,
        "pseudorange outliers"
    );
    assert!(c("imu_time_backwards") > 0, "duplicate and out-of-order IMU");
    assert!(c("feature_time_backwards") > 0, "duplicate camera lines");
    assert!(c("feature_connections") >= 2, "front end restart");
}
