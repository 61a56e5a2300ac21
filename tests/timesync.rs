//! TIMESYNC both ways (MAVLink's time synchronisation v2): the daemon
//! measures the autopilot's clock with its own requests, and answers the
//! autopilot's requests in that clock, the one its outputs are stamped in,
//! so that an autopilot mapping our stamps through the offset it learns
//! (PX4's `sync_stamp`) learns ≈ 0 and leaves them as they are.

mod common;

use std::time::{Duration, Instant};

use common::autopilot::MavPeer;
use mavlink::dialects::ardupilotmega as apm;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_daemon_answers_timesync_in_the_autopilot_clock() {
    let dir = tempfile::tempdir().unwrap();
    let (cfg, port) = common::loopback_config(dir.path());
    let (stop_tx, daemon) = common::spawn_daemon(cfg);
    tokio::time::sleep(Duration::from_millis(200)).await;
    let mut ap = MavPeer::new(port, 1, 1).await;
    // The autopilot's boot clock: 100 s at our start.
    let booted = Instant::now() - Duration::from_secs(100);
    let boot_ns = || booted.elapsed().as_nanos() as i64;
    ap.send(&apm::MavMessage::HEARTBEAT(apm::HEARTBEAT_DATA::default()))
        .await;
    // Ask before the daemon has measured our clock: no answer yet.
    ap.send(&apm::MavMessage::TIMESYNC(apm::TIMESYNC_DATA {
        tc1: 0,
        ts1: 7,
        ..Default::default()
    }))
    .await;
    let mut buf = [0u8; 2048];
    let (mut answered_theirs, mut replies) = (0, Vec::new());
    let deadline = Instant::now() + Duration::from_secs(4);
    while Instant::now() < deadline && replies.len() < 3 {
        let Ok(Ok(n)) = tokio::time::timeout(Duration::from_millis(100), ap.sock.recv(&mut buf)).await else {
            continue;
        };
        let mut r = mavlink::MavlinkReader::new(&buf[..n]);
        while let Ok((_, m)) = r.read_any_message::<apm::MavMessage>() {
            let apm::MavMessage::TIMESYNC(t) = m else { continue };
            if t.tc1 == 0 {
                // The daemon's request: answer with our boot clock, then ask.
                let reply = apm::MavMessage::TIMESYNC(apm::TIMESYNC_DATA {
                    tc1: boot_ns(),
                    ts1: t.ts1,
                    ..Default::default()
                });
                ap.send(&reply).await;
                answered_theirs += 1;
                tokio::time::sleep(Duration::from_millis(20)).await;
                let ask = apm::MavMessage::TIMESYNC(apm::TIMESYNC_DATA {
                    tc1: 0,
                    ts1: boot_ns(),
                    ..Default::default()
                });
                ap.send(&ask).await;
            } else {
                // Its reply to our request: its time, in our clock.
                replies.push((t.ts1, t.tc1, boot_ns()));
            }
        }
    }
    let _ = stop_tx.send(());
    let summary = daemon.await.unwrap().unwrap();
    let c = |k: &str| summary.counters.get(k).copied().unwrap_or(0);
    assert!(answered_theirs >= 1, "the daemon never asked");
    assert!(!replies.is_empty(), "no reply to our requests: {:?}", summary.counters);
    assert_eq!(
        c("timesync_request_unanswered"),
        1,
        "the request before its clock was known"
    );
    for (ts1, tc1, now) in &replies {
        assert_ne!(*ts1, 7, "the early request was answered");
        // Its tc1 lies between our request and its arrival, in our clock:
        // the offset we would learn is within the round trip.
        let mid = (ts1 + now) / 2;
        let offset_ms = (tc1 - mid) as f64 * 1e-6;
        eprintln!(
            "round trip {:.2} ms, offset {offset_ms:.3} ms",
            (now - ts1) as f64 * 1e-6
        );
        assert!(
            *tc1 >= ts1 - 5_000_000 && *tc1 <= now + 5_000_000,
            "tc1 outside the round trip"
        );
        assert!(offset_ms.abs() < 5.0, "offset {offset_ms} ms");
    }
    assert_eq!(c("timesync_reply") as usize, replies.len());
}
