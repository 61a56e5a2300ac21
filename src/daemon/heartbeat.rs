//! What the autopilot hears from us besides estimates: `HEARTBEAT` at 1 Hz
//! and at once on a change of state, the reasons for a degraded state as
//! `STATUSTEXT`; and, every second, the stream requests (while a stream
//! does not flow), a TIMESYNC request and, every 10 s, the counters to the journal.

use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;

use crate::counters::{Counter, Counters};
use crate::io::messages::{self as mav, Outbound};
use crate::status::{self, Degraded, Status};

/// The status task: HEARTBEAT at 1 Hz and at once on a change, with the
/// reasons for a degraded state as STATUSTEXT.
pub(super) fn spawn_status(
    out_tx: mpsc::Sender<Outbound>,
    status: Arc<Status>,
    start: Instant,
    mut stop: watch::Receiver<bool>,
) -> JoinHandle<()> {
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(Duration::from_millis(50));
        let mut last: Option<(bool, u32)> = None;
        let mut last_sent = Instant::now();
        loop {
            tokio::select! { _ = tick.tick() => {}, _ = stop.changed() => return }
            let initialised = status.initialised.load(Ordering::Relaxed);
            let mut degraded = status.degraded();
            let since_imu_ms =
                (start.elapsed().as_millis() as u64).saturating_sub(status.last_imu_wall_ms.load(Ordering::Relaxed));
            if initialised && since_imu_ms > 500 {
                degraded |= Degraded::ImuGap.bit();
            }
            let now = (initialised, degraded);
            if last == Some(now) && last_sent.elapsed() < Duration::from_secs(1) {
                continue;
            }
            if last.map(|l| l.1) != Some(degraded) && (degraded != 0 || last.is_some()) {
                send_status_text(&out_tx, degraded);
            }
            let _ = out_tx.try_send(Outbound::Heartbeat {
                initialised,
                degraded: degraded != 0,
            });
            last = Some(now);
            last_sent = Instant::now();
        }
    })
}

/// `cmsckf: nominal`, or the reasons for a degraded state.
fn send_status_text(out_tx: &mpsc::Sender<Outbound>, degraded: u32) {
    let text = if degraded == 0 {
        "cmsckf: nominal".to_string()
    } else {
        format!("cmsckf degraded: {}", status::describe(degraded))
    };
    tracing::warn!(degraded = %status::describe(degraded), "status changed");
    let severity = if degraded == 0 { 6 } else { 4 };
    let _ = out_tx.try_send(Outbound::StatusText { severity, text });
}

/// A diagnostic stream that never comes is asked for this many times.
const DIAGNOSTIC_ASKS: u32 = 10;

/// A stream silent for this many ticks (s) is asked for again.
const STREAM_STALE_TICKS: u32 = 3;

/// The periodic task: stream requests while the streams do not flow, TIMESYNC,
/// and the counters to the journal every 10 s.
pub(super) fn spawn_periodic(
    out_tx: mpsc::Sender<Outbound>,
    counters: Counters,
    imu_rate_hz: f64,
    start: Instant,
    mut stop: watch::Receiver<bool>,
) -> JoinHandle<()> {
    let imu_interval_us = 1e6 / imu_rate_hz as f32;
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(Duration::from_secs(1));
        let mut n: u64 = 0;
        // Per stream: its count at the last tick, and ticks since it moved.
        let mut seen = [(0u64, 0u32); 7];
        // Times each stream has been asked for (bounded for the diagnostic
        // ones, which an autopilot of the other kind never sends).
        let mut asked = [0u32; 7];
        loop {
            tokio::select! { _ = tick.tick() => {}, _ = stop.changed() => return }
            n += 1;
            // Ask for each stream while it does not flow: until it arrives,
            // and again when it stops for STREAM_STALE_TICKS seconds (a
            // rebooted autopilot forgets the rates it was asked for).
            let wanted = [
                (Counter::ImuHighres, mav::MSG_ID_HIGHRES_IMU, imu_interval_us, u32::MAX),
                (Counter::Attitude, mav::MSG_ID_ATTITUDE, 100_000.0, u32::MAX),
                (Counter::SystemTime, mav::MSG_ID_SYSTEM_TIME, 1_000_000.0, u32::MAX),
                (
                    Counter::LocalPosition,
                    mav::MSG_ID_LOCAL_POSITION_NED,
                    100_000.0,
                    u32::MAX,
                ),
                (
                    Counter::ExtendedSysState,
                    mav::MSG_ID_EXTENDED_SYS_STATE,
                    500_000.0,
                    u32::MAX,
                ),
                // Whether the autopilot's EKF takes our estimates, for the
                // log: ArduPilot answers the first, PX4 the second. One that
                // never comes is asked for at most `DIAGNOSTIC_ASKS` times.
                (
                    Counter::EstimatorStatus,
                    mav::MSG_ID_EKF_STATUS_REPORT,
                    200_000.0,
                    DIAGNOSTIC_ASKS,
                ),
                (
                    Counter::EstimatorStatus,
                    mav::MSG_ID_ESTIMATOR_STATUS,
                    200_000.0,
                    DIAGNOSTIC_ASKS,
                ),
            ];
            for (k, (counter, id, interval, max_asks)) in wanted.into_iter().enumerate() {
                let count = counters.get(counter);
                if count != seen[k].0 {
                    seen[k] = (count, 0);
                } else {
                    seen[k].1 += 1;
                }
                if (count == 0 || seen[k].1 >= STREAM_STALE_TICKS) && asked[k] < max_asks {
                    asked[k] += 1;
                    if count > 0 && seen[k].1 == STREAM_STALE_TICKS {
                        counters.add(Counter::StreamRequestedAgain, 1);
                        tracing::warn!(stream = %counter, "a stream stopped: asking for it again");
                    }
                    let _ = out_tx.try_send(Outbound::SetMessageInterval {
                        message_id: id,
                        interval_us: interval,
                    });
                }
            }
            let _ = out_tx.try_send(Outbound::TimesyncRequest {
                ts1_ns: start.elapsed().as_nanos() as i64,
            });
            if n.is_multiple_of(10) {
                tracing::info!(counters = ?counters.snapshot(), "cmsckf counters");
            }
        }
    })
}
