//! Bad input to a running daemon: each kind is rejected with a counted
//! reason, and the daemon keeps producing estimates.
//!
//! The test plays the autopilot with hand-made MAVLink frames on a UDP socket
//! (so it can corrupt them), and the front end on the feature socket.
mod common;

use std::io::Write;
use std::os::unix::net::UnixStream;
use std::time::Duration;

use common::autopilot::{line, MavPeer};
use mavlink::dialects::ardupilotmega as apm;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_input_is_rejected_counted_and_survived() {
    let dir = tempfile::tempdir().unwrap();
    let (mut cfg, port) = common::loopback_config(dir.path());
    cfg.features.max_line_bytes = 1024;
    let (stop_tx, daemon) = common::spawn_daemon(cfg.clone());
    tokio::time::sleep(Duration::from_millis(200)).await;

    let mut p = MavPeer::new(port, 1, 1).await;
    p.hello().await;
    // A static second of IMU initialises the filter.
    let mut t = 10.0;
    p.imu_run(&mut t, 150).await;
    assert!(
        p.drain_for(std::time::Duration::from_millis(20)).await.estimates > 10,
        "no estimates after initialisation"
    );

    // 1. A frame with a bad CRC, then a frame of an unknown message id.
    let mut bad = p.frame(&apm::MavMessage::HIGHRES_IMU(apm::HIGHRES_IMU_DATA::default()));
    let n = bad.len();
    bad[n - 3] ^= 0x55;
    p.sock.send(&bad).await.unwrap();
    let mut unknown = p.frame(&apm::MavMessage::HEARTBEAT(apm::HEARTBEAT_DATA::default()));
    unknown[7] = 0xEE;
    unknown[8] = 0xEE; // message id 61166: not in the dialect
    p.sock.send(&unknown).await.unwrap();
    p.imu(t).await;
    t += 0.01;
    // 2. A lost GPS_RTCM_DATA fragment: fragments 0 and 2 of sequence 3.
    for id in [0u8, 2] {
        p.send(&apm::MavMessage::GPS_RTCM_DATA(apm::GPS_RTCM_DATA_DATA {
            flags: 1 | (id << 1) | (3 << 3),
            len: 180,
            data: [0xD3; 180],
        }))
        .await;
    }
    // 3. Non-finite IMU values.
    p.send(&apm::MavMessage::HIGHRES_IMU(apm::HIGHRES_IMU_DATA {
        time_usec: (t * 1e6) as u64,
        xacc: f32::NAN,
        ..Default::default()
    }))
    .await;
    // 4. The feature socket: garbage, an oversized line, a NaN pixel,
    //    time going backwards, then a disconnect and a reconnect.
    {
        let mut s = UnixStream::connect(&cfg.features.socket).unwrap();
        s.write_all(b"this is not json\n").unwrap();
        s.write_all(&vec![b'x'; 5000]).unwrap();
        s.write_all(b"\n").unwrap();
        s.write_all(b"{\"v\":1,\"t_us\":10500000,\"cam\":0,\"features\":[[1,NaN,2.0]]}\n")
            .unwrap();
        // A σ of zero would weigh its pixel infinitely, and a negative one
        // is no σ: each line is refused whole (a fifth number is syntax).
        s.write_all(line(t + 0.015, "[1,300.0,200.0,0]").as_bytes()).unwrap();
        s.write_all(line(t + 0.016, "[1,300.0,200.0,-0.2]").as_bytes()).unwrap();
        s.write_all(line(t + 0.017, "[1,300.0,200.0,0.1,7]").as_bytes())
            .unwrap();
        s.write_all(line(t + 0.02, "[1,300.0,200.0,0.08]").as_bytes()).unwrap();
        // A frame the filter uses, with one pixel outside the image and one
        // landmark twice: those two features are dropped and counted.
        s.write_all(line(t + 0.03, "[3,-50.0,200.0],[4,300.0,200.0],[4,310.0,210.0]").as_bytes())
            .unwrap();
        // Going backwards in time: the frame is rejected whole, so its
        // outside-image pixel is not counted as well.
        s.write_all(line(t - 0.5, "[1,300.0,200.0],[5,-60.0,10.0]").as_bytes())
            .unwrap();
    }
    tokio::time::sleep(Duration::from_millis(50)).await;
    {
        let mut s = UnixStream::connect(&cfg.features.socket).unwrap();
        s.write_all(line(t + 0.05, "[2,310.0,210.0]").as_bytes()).unwrap();
    }
    // 5. An IMU gap of 1 s, then the stream goes on.
    t += 1.0;
    p.imu_run(&mut t, 100).await;
    let after = p.drain_for(std::time::Duration::from_millis(20)).await.estimates;
    assert!(
        after > 10,
        "the daemon stopped sending estimates after bad input ({after})"
    );
    // 6. The autopilot reboots: its clock restarts from 3 s. Once several
    //    samples agree on the new clock over 0.25 s
    //    (`mavlink.clock_jump_confirm_s`), the filter resets (reset_counter
    //    moves on) and, with the rebooted autopilot's attitude (streamed at
    //    4 Hz), estimates resume.
    let mut t2 = 3.0;
    for k in 0..250 {
        if k % 25 == 10 {
            p.send(&apm::MavMessage::ATTITUDE(apm::ATTITUDE_DATA::default())).await;
        }
        p.imu(t2).await;
        t2 += 0.01;
        tokio::time::sleep(Duration::from_micros(300)).await;
    }
    assert!(
        p.drain_for(std::time::Duration::from_millis(20)).await.estimates > 10,
        "no estimates after the autopilot's clock reset"
    );

    let _ = stop_tx.send(());
    let summary = daemon.await.unwrap().unwrap();
    let c = |k: &str| summary.counters.get(k).copied().unwrap_or(0);
    eprintln!("{:#?}", summary.counters);
    assert!(c("mavlink_frames_lost_or_corrupt") >= 2, "bad CRC + unknown id");
    assert_eq!(c("rtcm_fragment_missing"), 1);
    assert_eq!(c("mavlink_rejected_non_finite"), 1);
    assert_eq!(c("feature_line_syntax"), 3, "garbage, NaN and five numbers");
    assert_eq!(c("feature_bad_sigma"), 2, "a zero and a negative σ");
    assert_eq!(c("feature_line_too_long"), 1);
    assert_eq!(c("feature_time_backwards"), 1);
    assert_eq!(c("feature_outside_image"), 1, "only the fused frame's");
    assert_eq!(c("feature_duplicate_id"), 1);
    assert_eq!(c("feature_connections"), 2);
    assert!(c("imu_gap") >= 1);
    assert_eq!(c("autopilot_clock_reset"), 1);
    assert_eq!(c("init_static"), 2, "initialised again after the reboot");
}
