//! A SIGKILL mid-flight leaves an MCAP log that `review` reads up to about a
//! second before the kill: chunks are closed every second of wall time, and
//! sooner when their records span a second of sensor time (this flight runs
//! at 10×). After a jump of the sensor clock: `log_time_jumps.rs`.

mod common;

use std::time::{Duration, Instant};

use cmsckf::eval;
use cmsckf_sitl::dataset::Dataset;
use cmsckf_sitl::serve::{serve, ServeOptions, BOOT0_S};

#[test]
fn sigkill_leaves_a_readable_log() {
    let dir = tempfile::tempdir().unwrap();
    let (mut cfg, port) = common::loopback_config(dir.path());
    let log = dir.path().join("killed.mcap");
    cfg.log.path = log.display().to_string();
    let mut daemon = common::spawn_daemon_binary(&cfg, dir.path());
    let ds = Dataset::generate("racetrack", 2, Some(30.0), &eval::sim_config_for(&cfg)).unwrap();
    let speedup = 10.0;
    let opts = ServeOptions {
        mavlink: format!("udpout:127.0.0.1:{port}"),
        feature_socket: cfg.features.socket.clone().into(),
        speedup,
        faults: Vec::new(),
        gnss_stream: None,
    };
    let start = Instant::now();
    let sitl = std::thread::spawn(move || {
        let rt = tokio::runtime::Runtime::new().unwrap();
        rt.block_on(serve(&opts, &ds)).unwrap()
    });
    // Kill at 1.5 s of wall time = 15 s of flight.
    std::thread::sleep(Duration::from_millis(1500));
    let kill_flight_s = start.elapsed().as_secs_f64() * speedup;
    unsafe {
        libc::kill(daemon.id() as i32, libc::SIGKILL);
    }
    let _ = daemon.wait();
    let _ = sitl.join();

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
}
