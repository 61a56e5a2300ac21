//! A SIGKILL after the sensor clock jumped still leaves a log readable to
//! about a second of wall time before the kill: log chunks close on the wall
//! clock (and on sensor-time span), never only on a sensor clock that can go
//! back or leap ahead.
//!
//! One flight carries both jumps of the review's finding: a far-future
//! feature line (its stamp saturates the log's nanoseconds) before the
//! flight, and an autopilot reboot (`clock_jump`: its boot clock restarts
//! near 1 s) mid-flight. Before the fix, the first chunk opened at the
//! far-future stamp never closed: a kill lost the whole flight (and without
//! that line, everything after the reboot: 20 s of flight here).

mod common;

use std::io::Write;
use std::time::Duration;

use cmsckf::eval;
use cmsckf_sitl::dataset::Dataset;
use cmsckf_sitl::serve::{ServeOptions, BOOT0_S};

use common::harness;

/// Flight time of the reboot (the `clock_jump` fault's start, s).
const REBOOT_S: f64 = 5.0;
const SPEEDUP: f64 = 10.0;

#[test]
fn sigkill_after_clock_jumps_loses_at_most_about_a_second() {
    let dir = tempfile::tempdir().unwrap();
    let (mut cfg, port) = common::loopback_config(dir.path());
    let log = dir.path().join("jumps.mcap");
    cfg.log.path = log.display().to_string();
    let journal = dir.path().join("journal.txt");
    let mut daemon = common::spawn_daemon_binary_journal(&cfg, dir.path(), "info", &journal);
    // The far-future line, from a front end that comes and goes before the
    // camera's own (served first: nobody else is connected yet).
    {
        let mut s = std::os::unix::net::UnixStream::connect(&cfg.features.socket).unwrap();
        s.write_all(b"{\"v\":1,\"t_us\":1000000000000000000,\"cam\":0,\"features\":[[1,320.0,240.0]]}\n")
            .unwrap();
    }
    std::thread::sleep(Duration::from_millis(200));
    let ds = Dataset::generate("racetrack", 4, Some(32.0), &eval::sim_config_for(&cfg)).unwrap();
    let opts = ServeOptions {
        faults: vec![format!("clock_jump@{REBOOT_S}+1").parse().unwrap()],
        ..harness::serve_options(&cfg, port, SPEEDUP)
    };
    let sitl = harness::fly_in_background(opts, ds);
    // Kill at 2.5 s of wall time = 25 s of flight, 20 s after the reboot.
    let kill_flight_s = harness::sigkill_after(&mut daemon, sitl, Duration::from_millis(2500), SPEEDUP);

    // The readable records, in file order.
    let bytes = std::fs::read(&log).unwrap();
    let mut far_future_line = false;
    let mut imu_boot_s = Vec::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let Ok(m) = m else { break };
        match m.channel.topic.as_str() {
            "/input/features" if m.publish_time == u64::MAX => far_future_line = true,
            "/input/imu" => imu_boot_s.push(m.publish_time as f64 * 1e-9),
            _ => {}
        }
    }
    if !far_future_line {
        eprintln!("{}", std::fs::read_to_string(&journal).unwrap_or_default());
    }
    assert!(
        far_future_line,
        "the far-future line is in the log (the case under test)"
    );
    // The IMU's boot times back to flight time: `BOOT0_S` ahead before the
    // reboot, 1 s at the reboot after it (the first step back).
    let mut rebooted = false;
    let mut last_flight_s = f64::NEG_INFINITY;
    for w in imu_boot_s.windows(2) {
        rebooted |= w[1] < w[0] - 2.0;
        let flight_s = if rebooted {
            w[1] - 1.0 + REBOOT_S
        } else {
            w[1] - BOOT0_S
        };
        last_flight_s = last_flight_s.max(flight_s);
    }
    let lost_wall_s = (kill_flight_s - last_flight_s) / SPEEDUP;
    eprintln!(
        "killed at ≈{kill_flight_s:.2} s of flight; {} IMU records readable, the last at {last_flight_s:.2} s of flight \
         (after the reboot: {rebooted}); lost ≈{lost_wall_s:.2} s of wall time",
        imu_boot_s.len()
    );
    assert!(rebooted, "no IMU record after the reboot is readable");
    // A chunk is open a second of wall time at most; allow the queues and
    // the SITL's pacing another 0.5 s.
    assert!(lost_wall_s < 1.5, "lost {lost_wall_s:.2} s of wall time");
    let r = cmsckf::review::review(&log, None, None, None).unwrap();
    assert!(r.truncated, "a killed writer leaves no summary");
    assert!(
        r.duration_s > 0.8 * last_flight_s - 1.0 && r.duration_s < kill_flight_s,
        "review's duration {} s",
        r.duration_s
    );
}
