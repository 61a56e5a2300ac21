//! One IMU message is taken (`mavlink.imu_message`), the others ignored and
//! counted. Beside PX4 it is `SCALED_IMU`: PX4's `HIGHRES_IMU` is its IMU
//! less EKF2's bias estimates, which EKF2 learns from our own estimates, so
//! our error would come back to us as input (measured at 0.2-0.4 m/s² on
//! PX4's SITL, whose IMU has no bias). PX4 repeats its last `SCALED_IMU`
//! when only the magnetometer has moved: the repeat is a duplicate, neither
//! a measurement nor a time going back.

mod common;

use std::time::{Duration, Instant};

use cmsckf::config::{Config, ImuMessageChoice};
use common::autopilot::MavPeer;
use mavlink::dialects::ardupilotmega as apm;

const HIGHRES_IMU: u32 = 105;
const SCALED_IMU: u32 = 26;

fn heartbeat(autopilot: apm::MavAutopilot) -> apm::MavMessage {
    apm::MavMessage::HEARTBEAT(apm::HEARTBEAT_DATA {
        mavtype: apm::MavType::MAV_TYPE_QUADROTOR,
        autopilot,
        mavlink_version: 3,
        ..Default::default()
    })
}

/// A still vehicle's `HIGHRES_IMU` at `t_s`, carrying `zacc`.
fn highres(t_s: f64, zacc: f32) -> apm::MavMessage {
    apm::MavMessage::HIGHRES_IMU(apm::HIGHRES_IMU_DATA {
        time_usec: (t_s * 1e6) as u64,
        zacc,
        ..Default::default()
    })
}

/// A still vehicle's `SCALED_IMU` at `t_s` (ms, mG, mrad/s), carrying
/// `zacc` (mG).
fn scaled(t_s: f64, zacc: i16) -> apm::MavMessage {
    scaled_at_ms((t_s * 1e3).round() as u64, zacc)
}

/// The same at `t_ms` since boot, sent as the u32 it is on the wire
/// (wrapping past 2³² ms, 49.7 days).
fn scaled_at_ms(t_ms: u64, zacc: i16) -> apm::MavMessage {
    apm::MavMessage::SCALED_IMU(apm::SCALED_IMU_DATA {
        time_boot_ms: t_ms as u32,
        zacc,
        xgyro: 2,
        ..Default::default()
    })
}

/// What happened beside an autopilot of `kind` that streams both
/// messages for `secs`, each at 50 Hz (half the rate the daemon asks for,
/// so that it asks for the one it takes), every fourth SCALED_IMU sent
/// twice and every seventh followed by another sample at its time (other
/// values): the daemon's interval requests and its counters, with what
/// was sent.
struct Run {
    requests: Vec<(u32, f32)>,
    counters: std::collections::BTreeMap<String, u64>,
    highres_sent: u64,
    scaled_sent: u64,
    repeats_sent: u64,
    conflicts_sent: u64,
}

async fn beside(kind: apm::MavAutopilot, choice: ImuMessageChoice, secs: f64) -> Run {
    beside_sending(kind, choice, secs, |_| true).await
}

/// As [`beside`], with HIGHRES_IMU sent only while `highres_on(t)` (s).
async fn beside_sending(
    kind: apm::MavAutopilot,
    choice: ImuMessageChoice,
    secs: f64,
    highres_on: fn(f64) -> bool,
) -> Run {
    let dir = tempfile::tempdir().unwrap();
    let (mut cfg, port): (Config, u16) = common::loopback_config(dir.path());
    cfg.mavlink.imu_message = choice;
    let (stop_tx, daemon) = common::spawn_daemon(cfg);
    tokio::time::sleep(Duration::from_millis(200)).await;
    let mut ap = MavPeer::new(port, 1, 1).await;
    let started = Instant::now();
    let (mut next_hb, mut next_highres, mut next_scaled) = (0.0, 0.0, 0.0);
    let mut run = Run {
        requests: Vec::new(),
        counters: Default::default(),
        highres_sent: 0,
        scaled_sent: 0,
        repeats_sent: 0,
        conflicts_sent: 0,
    };
    let mut buf = [0u8; 2048];
    while started.elapsed() < Duration::from_secs_f64(secs) {
        let now = started.elapsed().as_secs_f64();
        if now >= next_hb {
            ap.send(&heartbeat(kind)).await;
            next_hb += 0.5;
        }
        if now >= next_highres && !highres_on(now) {
            next_highres += 0.02;
        }
        if now >= next_highres {
            // PX4's: EKF2's bias estimate taken out, here a large one, so
            // that taking it would show.
            ap.send(&highres(10.0 + next_highres, -9.81 + 3.0)).await;
            run.highres_sent += 1;
            next_highres += 0.02;
        }
        if now >= next_scaled {
            let m = scaled(10.0 + next_scaled, -1000);
            ap.send(&m).await;
            run.scaled_sent += 1;
            if run.scaled_sent.is_multiple_of(4) {
                ap.send(&m).await;
                run.repeats_sent += 1;
            }
            if run.scaled_sent.is_multiple_of(7) {
                ap.send(&scaled(10.0 + next_scaled, -990)).await;
                run.conflicts_sent += 1;
            }
            next_scaled += 0.02;
        }
        if let Ok(Ok(n)) = tokio::time::timeout(Duration::from_millis(2), ap.sock.recv(&mut buf)).await {
            let mut r = mavlink::MavlinkReader::new(&buf[..n]);
            while let Ok((_, m)) = r.read_any_message::<apm::MavMessage>() {
                if let apm::MavMessage::COMMAND_LONG(c) = m {
                    if c.command == apm::MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL {
                        run.requests.push((c.param1 as u32, c.param2));
                    }
                }
            }
        }
    }
    let _ = stop_tx.send(());
    let summary = daemon.await.unwrap().unwrap();
    run.counters = summary.counters;
    run
}

impl Run {
    fn count(&self, name: &str) -> u64 {
        self.counters.get(name).copied().unwrap_or(0)
    }

    /// Every IMU message was fused once, ignored as the message not taken,
    /// or dropped as a repeat: none lost, none fused twice.
    fn assert_each_fused_once_or_ignored(&self) {
        assert_eq!(
            self.count("imu_samples"),
            self.count("imu_scaled") + self.count("imu_highres")
                - self.count("imu_message_ignored")
                - self.count("imu_duplicate")
                - self.count("imu_conflicting_duplicate"),
            "{:?}",
            self.counters
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn beside_px4_scaled_imu_is_taken_and_highres_imu_ignored() {
    let run = beside(apm::MavAutopilot::MAV_AUTOPILOT_PX4, ImuMessageChoice::Auto, 3.0).await;
    eprintln!("requests {:?}\ncounters {:?}", run.requests, run.counters);
    // Asked for SCALED_IMU at the configured rate (100 Hz), never for
    // HIGHRES_IMU.
    assert!(run.requests.contains(&(SCALED_IMU, 10_000.0)), "{:?}", run.requests);
    assert!(!run.requests.iter().any(|r| r.0 == HIGHRES_IMU), "{:?}", run.requests);
    // Every HIGHRES_IMU the daemon heard was ignored, none fused.
    assert!(run.count("imu_highres") > 0);
    assert_eq!(run.count("imu_message_ignored"), run.count("imu_highres"));
    // The repeats are duplicates: never a time going back, which would
    // have shown the autopilot an input_rejected state.
    assert!(run.count("imu_duplicate") + 2 >= run.repeats_sent, "{:?}", run.counters);
    assert_eq!(run.count("imu_time_backwards"), 0, "{:?}", run.counters);
    // Another sample at a time already taken is refused as that, not as a
    // time going back, and the first stands.
    assert!(
        run.count("imu_conflicting_duplicate") + 2 >= run.conflicts_sent,
        "{:?}",
        run.counters
    );
    assert!(
        run.count("imu_conflicting_duplicate") <= run.conflicts_sent,
        "{:?}",
        run.counters
    );
    // What was fused is every SCALED_IMU once.
    assert_eq!(
        run.count("imu_samples"),
        run.count("imu_scaled") - run.count("imu_duplicate") - run.count("imu_conflicting_duplicate"),
        "{:?}",
        run.counters
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn beside_ardupilot_highres_imu_is_taken_unless_the_config_says_otherwise() {
    let run = beside(
        apm::MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
        ImuMessageChoice::Auto,
        2.0,
    )
    .await;
    eprintln!("requests {:?}\ncounters {:?}", run.requests, run.counters);
    assert!(!run.requests.iter().any(|r| r.0 == SCALED_IMU), "{:?}", run.requests);
    assert_eq!(run.count("imu_message_ignored"), run.count("imu_scaled"));
    assert!(run.count("imu_scaled") > 0);
    assert_eq!(run.count("imu_duplicate"), 0);

    let run = beside(
        apm::MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
        ImuMessageChoice::Scaled,
        2.0,
    )
    .await;
    assert!(run.requests.iter().any(|r| r.0 == SCALED_IMU), "{:?}", run.requests);
    assert_eq!(run.count("imu_message_ignored"), run.count("imu_highres"));
    assert!(run.count("imu_duplicate") > 0);
}

/// ArduPilot on a 1 MB board has no HIGHRES_IMU: `auto` takes the IMU
/// message that does come once HIGHRES_IMU has not come for 0.5 s (well
/// inside the 2 s gap that would restart the filter), asks for it at the
/// configured rate, and says so once.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn without_highres_imu_another_imu_message_is_taken() {
    let run = beside_sending(
        apm::MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
        ImuMessageChoice::Auto,
        5.0,
        |_| false,
    )
    .await;
    eprintln!("requests {:?}\ncounters {:?}", run.requests, run.counters);
    assert_eq!(run.count("imu_message_switched"), 1, "{:?}", run.counters);
    assert!(run.requests.contains(&(SCALED_IMU, 10_000.0)), "{:?}", run.requests);
    // About the first 0.5 s of it ignored, the rest fused once each.
    let ignored = run.count("imu_message_ignored");
    assert!((15..=60).contains(&ignored), "{:?}", run.counters);
    assert_eq!(
        run.count("imu_samples"),
        run.count("imu_scaled") - ignored - run.count("imu_duplicate") - run.count("imu_conflicting_duplicate"),
        "{:?}",
        run.counters
    );
}

/// A HIGHRES_IMU that trickles at 2.5 Hz (a link that lets one in 20
/// through) beside a SCALED_IMU at 50 Hz: the trickle is no IMU stream,
/// so the SCALED_IMU is taken once 0.5 s have passed without HIGHRES_IMU
/// flowing, and the trickle never takes it back (it had kept the filter at
/// 2.5 Hz: each of its samples came within the 0.5 s wait).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn highres_imu_trickling_is_not_taken() {
    let run = beside_sending(
        apm::MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
        ImuMessageChoice::Auto,
        5.0,
        |t| t % 0.4 < 0.02,
    )
    .await;
    eprintln!("counters {:?}", run.counters);
    assert_eq!(run.count("imu_message_switched"), 1, "{:?}", run.counters);
    assert_eq!(run.count("imu_gap_restart"), 0, "{:?}", run.counters);
    // Every message is fused once or ignored, and only about the first
    // 0.5 s of SCALED_IMU (25) and the trickle after the switch are ignored.
    run.assert_each_fused_once_or_ignored();
    assert!(run.count("imu_message_ignored") <= 50, "{:?}", run.counters);
}

/// A HIGHRES_IMU in 1 s bursts with 2.5 s gaps, beside a SCALED_IMU that
/// never stops: taken over once, never given back to the bursts (it must
/// flow 3 s first), so the filter meets one gap of 0.5 s, at the switch,
/// and none of the 2 s that would restart it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn highres_imu_in_bursts_does_not_flap_the_message_taken() {
    let run = beside_sending(
        apm::MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
        ImuMessageChoice::Auto,
        8.0,
        |t| t % 3.5 < 1.0,
    )
    .await;
    eprintln!("counters {:?}", run.counters);
    assert_eq!(run.count("imu_message_switched"), 1, "{:?}", run.counters);
    assert!(run.count("imu_gap") <= 1, "{:?}", run.counters);
    assert_eq!(run.count("imu_gap_restart"), 0, "{:?}", run.counters);
    assert_eq!(run.count("imu_time_backwards"), 0, "{:?}", run.counters);
    // After the switch every SCALED_IMU is fused once: the bursts are not.
    run.assert_each_fused_once_or_ignored();
}

/// PX4's `SCALED_IMU` carries a u32 of milliseconds since boot, which wraps
/// after 49.7 days of uptime: the samples across the wrap are fused in
/// order, with no reboot read into it (a filter restart in flight) and none
/// refused; `SYSTEM_TIME`'s boot time runs on with them.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scaled_imu_time_runs_on_across_its_wrap() {
    let dir = tempfile::tempdir().unwrap();
    let (cfg, port): (Config, u16) = common::loopback_config(dir.path());
    let (stop_tx, daemon) = common::spawn_daemon(cfg);
    tokio::time::sleep(Duration::from_millis(200)).await;
    let mut ap = MavPeer::new(port, 1, 1).await;
    // 1.5 s before the wrap, for 3 s at 50 Hz.
    let t0_ms: u64 = (1u64 << 32) - 1500;
    let started = Instant::now();
    let (mut next_hb, mut k, mut after_wrap) = (0.0, 0u64, 0u64);
    while started.elapsed() < Duration::from_secs(3) {
        let now = started.elapsed().as_secs_f64();
        if now >= next_hb {
            ap.send(&heartbeat(apm::MavAutopilot::MAV_AUTOPILOT_PX4)).await;
            // Its Unix time against its boot time, across the wrap too.
            let boot_ms = t0_ms + (now * 1e3) as u64;
            ap.send(&apm::MavMessage::SYSTEM_TIME(apm::SYSTEM_TIME_DATA {
                time_unix_usec: 1_796_000_000_000_000 + boot_ms * 1000,
                time_boot_ms: boot_ms as u32,
            }))
            .await;
            next_hb += 0.5;
        }
        if now >= k as f64 * 0.02 {
            let t_ms = t0_ms + 20 * k;
            after_wrap += u64::from(t_ms >= 1 << 32);
            ap.send(&scaled_at_ms(t_ms, -1000)).await;
            k += 1;
        }
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    let _ = stop_tx.send(());
    let summary = daemon.await.unwrap().unwrap();
    let c = |n: &str| summary.counters.get(n).copied().unwrap_or(0);
    eprintln!("{k} sent, {after_wrap} after the wrap: {:?}", summary.counters);
    assert!(after_wrap > 20, "{after_wrap} samples after the wrap");
    // SYSTEM_TIME's boot time is unwrapped with it: Unix time less boot
    // time stays put, no sample of it refused (GNSS time hangs on it).
    assert!(c("system_time") >= 5, "{:?}", summary.counters);
    for bad in [
        "autopilot_clock_reset",
        "imu_time_outlier",
        "imu_time_backwards",
        "imu_gap_restart",
        "system_time_outlier",
    ] {
        assert_eq!(c(bad), 0, "{bad}: {:?}", summary.counters);
    }
    assert_eq!(
        c("imu_samples"),
        c("imu_scaled") - c("imu_duplicate"),
        "{:?}",
        summary.counters
    );
    assert!(
        c("imu_samples") + 5 >= k,
        "{} of {k} fused: {:?}",
        c("imu_samples"),
        summary.counters
    );
}
