//! What the autopilot hears from us besides estimates: `HEARTBEAT` at 1 Hz
//! and at once on a change of state, the reasons for a degraded state as
//! `STATUSTEXT`; and, every second, the stream requests (while a stream
//! does not flow), a TIMESYNC request and, every 10 s, the counters to the journal.

use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;

use crate::counters::{Counter, Counters};
use crate::io::messages::{self as mav, ImuMessage, Outbound};
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

/// A stream flowing slower than asked is asked again this many times.
const SLOW_ASKS: u32 = 5;

/// The streams asked for (see `wanted` in [`spawn_periodic`]).
const WANTED: usize = 9;

/// How a stream is asked for.
#[derive(Clone, Copy)]
enum Ask {
    /// Until it flows, again when it stops, and again (a few times) while
    /// it flows at under 80 % of the rate asked.
    Always,
    /// Whether the autopilot's EKF takes our estimates, for the log: one of
    /// two messages each autopilot sends, each asked for at most
    /// [`DIAGNOSTIC_ASKS`] times until it flows.
    Diagnostic,
    /// A sensor the autopilot may not have (its barometer): asked for at
    /// most [`DIAGNOSTIC_ASKS`] times until it flows, and made faster as
    /// [`Ask::Always`] while it flows slowly (PX4 sends `SCALED_PRESSURE`
    /// at 1 Hz unasked).
    Optional,
    /// Only made faster, never started: PX4 streams its TIMESYNC requests
    /// at 10 Hz; ArduPilot sends one every few seconds and answers a request
    /// for it with a "No ap_message" on the pilot's screen.
    FasterOnly,
}

/// A [`Ask::FasterOnly`] stream is a stream from this rate (Hz).
const FASTER_ONLY_MIN_HZ: f32 = 5.0;

/// The periodic task: stream requests while the streams do not flow, TIMESYNC,
/// and the counters to the journal every 10 s.
pub(super) fn spawn_periodic(
    out_tx: mpsc::Sender<Outbound>,
    counters: Counters,
    imu_message: Arc<AtomicU8>,
    imu_rate_hz: f64,
    start: Instant,
    mut stop: watch::Receiver<bool>,
) -> JoinHandle<()> {
    let imu_interval_us = 1e6 / imu_rate_hz as f32;
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(Duration::from_secs(1));
        // A stalled runtime's missed ticks are not fired back to back: each
        // tick's counts are over about a second, measured.
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        let mut last_tick = Instant::now();
        let mut n: u64 = 0;
        // Per stream: its count at the last tick, and ticks since it moved.
        let mut seen = [(0u64, 0u32); WANTED];
        // Times each stream has been asked for (bounded for the diagnostic
        // ones, which an autopilot of the other kind never sends).
        let mut asked = [0u32; WANTED];
        // Per stream: asks for more speed since it last stopped, and ticks
        // in a row it has flowed too slowly.
        let mut slow_asks = [0u32; WANTED];
        let mut slow_ticks = [0u32; WANTED];
        let mut imu_was = ImuMessage::from_u8(imu_message.load(Ordering::Relaxed));
        loop {
            tokio::select! { _ = tick.tick() => {}, _ = stop.changed() => return }
            n += 1;
            let tick_s = last_tick.elapsed().as_secs_f32().max(0.1);
            last_tick = Instant::now();
            // The IMU message taken, which the autopilot's kind may have
            // changed: a new stream, asked for afresh.
            let imu = ImuMessage::from_u8(imu_message.load(Ordering::Relaxed));
            if imu != imu_was {
                imu_was = imu;
                (seen[0], asked[0], slow_asks[0], slow_ticks[0]) = ((0, 0), 0, 0, 0);
            }
            // Ask for each stream while it does not flow: until it arrives,
            // and again when it stops for STREAM_STALE_TICKS seconds (a
            // rebooted autopilot forgets the rates it was asked for).
            let wanted = [
                (imu.counter(), imu.message_id(), imu_interval_us, Ask::Always),
                (Counter::Attitude, mav::MSG_ID_ATTITUDE, 100_000.0, Ask::Always),
                (Counter::SystemTime, mav::MSG_ID_SYSTEM_TIME, 1_000_000.0, Ask::Always),
                (
                    Counter::LocalPosition,
                    mav::MSG_ID_LOCAL_POSITION_NED,
                    100_000.0,
                    Ask::Always,
                ),
                (
                    Counter::ExtendedSysState,
                    mav::MSG_ID_EXTENDED_SYS_STATE,
                    500_000.0,
                    Ask::Always,
                ),
                // Whether the autopilot's EKF takes our estimates, for the
                // log: ArduPilot answers the first, PX4 the second. One that
                // never comes is asked for at most `DIAGNOSTIC_ASKS` times.
                (
                    Counter::EstimatorStatus,
                    mav::MSG_ID_EKF_STATUS_REPORT,
                    200_000.0,
                    Ask::Diagnostic,
                ),
                (
                    Counter::EstimatorStatus,
                    mav::MSG_ID_ESTIMATOR_STATUS,
                    200_000.0,
                    Ask::Diagnostic,
                ),
                // The autopilot's barometer: our height's reference
                // (`barometer.fuse`), and the review's height check.
                (Counter::Pressure, mav::MSG_ID_SCALED_PRESSURE, 100_000.0, Ask::Optional),
                // PX4's own TIMESYNC requests, which we answer: it keeps our
                // estimates' stamps only after 500 good round trips
                // (`Timesync::sync_converged`), 50 s at its default 10 Hz,
                // 10 s at 50 Hz.
                (
                    Counter::TimesyncRequestIn,
                    mav::MSG_ID_TIMESYNC,
                    20_000.0,
                    Ask::FasterOnly,
                ),
            ];
            for (k, (counter, id, interval, ask)) in wanted.into_iter().enumerate() {
                let count = counters.get(counter);
                // Over the tick (about 1 s): the stream's rate.
                let rate_hz = count.saturating_sub(seen[k].0) as f32 / tick_s;
                if count != seen[k].0 {
                    seen[k] = (count, 0);
                } else {
                    seen[k].1 += 1;
                }
                if seen[k].1 >= STREAM_STALE_TICKS {
                    // Stopped (a reboot): it may come back at its default
                    // rate, and be asked to go faster again.
                    slow_asks[k] = 0;
                }
                // A stream flowing at a default rate under 80 % of ours
                // (PX4's onboard link sends HIGHRES_IMU at 50 Hz unasked,
                // and its TIMESYNC requests at 10 Hz) for two ticks in a
                // row, by more than a message's jitter (a 2 Hz stream
                // counts 1 or 3 on some ticks), is asked again, a few
                // times: an autopilot may cap it below.
                let too_slow = match ask {
                    Ask::Always | Ask::Optional => rate_hz > 0.0,
                    Ask::Diagnostic => false,
                    Ask::FasterOnly => rate_hz >= FASTER_ONLY_MIN_HZ,
                } && rate_hz < 0.8e6 / interval - 1.0;
                slow_ticks[k] = if too_slow { slow_ticks[k] + 1 } else { 0 };
                if slow_ticks[k] >= 2 && slow_asks[k] < SLOW_ASKS {
                    slow_asks[k] += 1;
                    slow_ticks[k] = 0;
                    let _ = out_tx.try_send(Outbound::SetMessageInterval {
                        message_id: id,
                        interval_us: interval,
                    });
                    continue;
                }
                let max_asks = match ask {
                    Ask::Always => u32::MAX,
                    Ask::Diagnostic | Ask::Optional => DIAGNOSTIC_ASKS,
                    Ask::FasterOnly => 0,
                };
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
