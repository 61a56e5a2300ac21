//! Stream requests follow the streams: the daemon asks for HIGHRES_IMU
//! until it flows, stops asking while it flows, and asks again when it stops
//! (a rebooted autopilot forgets the rates it was asked for).

mod common;

use cmsckf::counters::Counter;
use std::time::{Duration, Instant};

use common::autopilot::{heartbeat, MavPeer};
use mavlink::dialects::ardupilotmega as apm;

const HIGHRES_IMU: f32 = 105.0;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stream_that_stops_is_asked_for_again() {
    let dir = tempfile::tempdir().unwrap();
    let (cfg, port) = common::loopback_config(dir.path());
    let (stop_tx, daemon) = common::spawn_daemon(cfg);
    tokio::time::sleep(Duration::from_millis(200)).await;
    let mut ap = MavPeer::new(port, 1, 1).await;
    // Phases: 0–2.5 s IMU flows; 2.5–7 s it stops (heartbeats go on).
    let started = Instant::now();
    let (mut t, mut next_hb) = (10.0, 0.0);
    let mut requests: Vec<f64> = Vec::new();
    let mut buf = [0u8; 2048];
    while started.elapsed() < Duration::from_secs(7) {
        let now = started.elapsed().as_secs_f64();
        if now >= next_hb {
            ap.send(&heartbeat()).await;
            next_hb += 0.5;
        }
        if now < 2.5 {
            ap.imu(t).await;
            t += 0.01;
        }
        if let Ok(Ok(n)) = tokio::time::timeout(Duration::from_millis(10), ap.sock.recv(&mut buf)).await {
            let mut r = mavlink::MavlinkReader::new(&buf[..n]);
            while let Ok((_, m)) = r.read_any_message::<apm::MavMessage>() {
                if let apm::MavMessage::COMMAND_LONG(c) = m {
                    if c.command == apm::MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL && c.param1 == HIGHRES_IMU {
                        requests.push(started.elapsed().as_secs_f64());
                    }
                }
            }
        }
    }
    let _ = stop_tx.send(());
    let summary = daemon.await.unwrap().unwrap();
    eprintln!("HIGHRES_IMU requested at {requests:?} s");
    let flowing = requests.iter().filter(|&&r| (1.5..2.5).contains(&r)).count();
    assert_eq!(flowing, 0, "asked while it flowed: {requests:?}");
    assert!(
        requests.iter().any(|&r| (3.5..7.0).contains(&r)),
        "not asked again after it stopped: {requests:?}"
    );
    assert!(
        summary
            .counters
            .get(Counter::StreamRequestedAgain.as_str())
            .copied()
            .unwrap_or(0)
            >= 1
    );
}
