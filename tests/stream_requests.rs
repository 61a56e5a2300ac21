//! Stream requests follow the streams: the daemon asks for HIGHRES_IMU
//! until it flows, stops asking while it flows, and asks again when it stops
//! (a rebooted autopilot forgets the rates it was asked for).

mod common;

use cmsckf::counters::Counter;
use std::time::{Duration, Instant};

use common::autopilot::{heartbeat, MavPeer};
use mavlink::dialects::ardupilotmega as apm;

const HIGHRES_IMU: u32 = 105;

/// The daemon's MAV_CMD_SET_MESSAGE_INTERVAL requests in one datagram:
/// (message id, interval µs).
fn interval_requests(datagram: &[u8]) -> Vec<(u32, f32)> {
    let mut r = mavlink::MavlinkReader::new(datagram);
    let mut out = Vec::new();
    while let Ok((_, m)) = r.read_any_message::<apm::MavMessage>() {
        if let apm::MavMessage::COMMAND_LONG(c) = m {
            if c.command == apm::MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL {
                out.push((c.param1 as u32, c.param2));
            }
        }
    }
    out
}

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
            for (id, _) in interval_requests(&buf[..n]) {
                if id == HIGHRES_IMU {
                    requests.push(started.elapsed().as_secs_f64());
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

/// What the daemon asked for in `secs` of an autopilot that streams
/// HIGHRES_IMU at `imu_hz` and sends its own TIMESYNC requests at
/// `timesync_hz`: the (message id, interval µs) of each request.
async fn requests_beside(imu_hz: f64, timesync_hz: f64, secs: f64) -> Vec<(u32, f32)> {
    let dir = tempfile::tempdir().unwrap();
    let (cfg, port) = common::loopback_config(dir.path());
    let (stop_tx, daemon) = common::spawn_daemon(cfg);
    tokio::time::sleep(Duration::from_millis(200)).await;
    let mut ap = MavPeer::new(port, 1, 1).await;
    let started = Instant::now();
    let (mut next_hb, mut next_imu, mut next_sync) = (0.0, 0.0, 0.0);
    let mut requests = Vec::new();
    let mut buf = [0u8; 2048];
    while started.elapsed() < Duration::from_secs_f64(secs) {
        let now = started.elapsed().as_secs_f64();
        if now >= next_hb {
            ap.send(&heartbeat()).await;
            next_hb += 0.5;
        }
        if now >= next_imu {
            ap.imu(10.0 + now).await;
            next_imu += 1.0 / imu_hz;
        }
        if now >= next_sync {
            ap.send(&apm::MavMessage::TIMESYNC(apm::TIMESYNC_DATA {
                tc1: 0,
                ts1: (now * 1e9) as i64,
                ..Default::default()
            }))
            .await;
            next_sync += 1.0 / timesync_hz;
        }
        if let Ok(Ok(n)) = tokio::time::timeout(Duration::from_millis(2), ap.sock.recv(&mut buf)).await {
            requests.extend(interval_requests(&buf[..n]));
        }
    }
    let _ = stop_tx.send(());
    let _ = daemon.await;
    requests
}

/// PX4's onboard link streams HIGHRES_IMU at 50 Hz and its TIMESYNC
/// requests at 10 Hz unasked: both flow, too slowly. The daemon asks for
/// the IMU at `mavlink.imu_rate_hz` (100 Hz) and TIMESYNC at 50 Hz (PX4
/// keeps our stamps only after 500 round trips), a few times at most.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn streams_flowing_too_slowly_are_asked_to_go_faster() {
    let requests = requests_beside(50.0, 10.0, 5.0).await;
    eprintln!("requests: {requests:?}");
    let imu: Vec<_> = requests.iter().filter(|(id, _)| *id == 105).collect();
    let sync: Vec<_> = requests.iter().filter(|(id, _)| *id == 111).collect();
    assert!(
        !imu.is_empty() && imu.iter().all(|(_, us)| *us == 10_000.0),
        "{requests:?}"
    );
    assert!(
        !sync.is_empty() && sync.iter().all(|(_, us)| *us == 20_000.0),
        "{requests:?}"
    );
    assert!(imu.len() <= 5 && sync.len() <= 5, "asked without end: {requests:?}");
}

/// ArduPilot sends a TIMESYNC request every few seconds and answers a
/// request for the stream with "No ap_message for mavlink id (111)" on the
/// pilot's screen: it is never asked; an IMU at the rate asked is not asked
/// again either.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_autopilot_without_a_timesync_stream_is_not_asked_for_one() {
    let requests = requests_beside(100.0, 0.3, 5.0).await;
    eprintln!("requests: {requests:?}");
    assert!(!requests.iter().any(|(id, _)| *id == 111), "{requests:?}");
    assert!(!requests.iter().any(|(id, _)| *id == 105), "{requests:?}");
}
