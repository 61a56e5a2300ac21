//! The link watchdog: an autopilot that falls silent is said so (HEARTBEAT
//! `link_down`, the log, a UDP link that forgets its address to learn it
//! again), and one silent for long makes the daemon exit so that its service
//! manager restarts it; an autopilot heard but sending no IMU is warned about.

use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;

use super::FusionMsg;
use crate::config::Config;
use crate::counters::{Counter, Counters};
use crate::io::mavlink::Link;
use crate::status::{Degraded, Status};

/// An autopilot heard but without IMU this long after the start is warned
/// about.
const IMU_EXPECTED_WITHIN: Duration = Duration::from_secs(5);

/// What the link watchdog needs.
pub(super) struct Watch {
    pub counters: Counters,
    pub status: Arc<Status>,
    pub fusion_tx: mpsc::Sender<FusionMsg>,
    /// Set, once, to why the daemon must exit.
    pub fatal: watch::Sender<Option<String>>,
    pub start: Instant,
    pub stop: watch::Receiver<bool>,
}

/// The link watchdog, every 100 ms of wall time: an autopilot silent for
/// `mavlink.link_down_after_s` puts `link_down` in the HEARTBEAT, the
/// outage in the log, and makes a UDP link forget its address (to learn it
/// again: the autopilot may come back from another port); silent for
/// `mavlink.link_exit_after_s` (also never heard since the start), the
/// daemon exits non-zero so that its service manager restarts it.
pub(super) fn spawn_watchdog(cfg: &Config, link: Arc<Link>, mut w: Watch) -> JoinHandle<()> {
    let down_after = Duration::from_secs_f64(cfg.mavlink.link_down_after_s);
    let exit_after =
        (cfg.mavlink.link_exit_after_s > 0.0).then(|| Duration::from_secs_f64(cfg.mavlink.link_exit_after_s));
    let address = cfg.mavlink.address.clone();
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(Duration::from_millis(100));
        let mut down_since: Option<Duration> = None;
        let mut imu_warned = false;
        loop {
            tokio::select! { _ = tick.tick() => {}, _ = w.stop.changed() => return }
            let heard = link.silent_for();
            let silent = heard.unwrap_or_else(|| w.start.elapsed());
            if silent >= down_after && down_since.is_none() {
                down_since = Some(silent);
                w.status.set_io(Degraded::LinkDown, true);
                w.counters.add(Counter::LinkDown, 1);
                if link.forget_peer() {
                    w.counters.add(Counter::MavlinkAutopilotAddressStale, 1);
                }
                if heard.is_none() {
                    tracing::error!(
                        %address,
                        silent_s = silent.as_secs_f64(),
                        "no autopilot heard on {address}: check mavlink.address, the wiring, and that the autopilot \
                         sends MAVLink there (ArduPilot: SERIALn_PROTOCOL = 2; or a router's endpoint)"
                    );
                } else {
                    tracing::error!(%address, silent_s = silent.as_secs_f64(), "MAVLink link down: the autopilot is silent");
                }
                let _ = w.fusion_tx.try_send(FusionMsg::LinkState {
                    up: false,
                    silent_s: silent.as_secs_f64(),
                });
            } else if silent < down_after && down_since.is_some() {
                down_since = None;
                w.status.set_io(Degraded::LinkDown, false);
                w.counters.add(Counter::LinkUp, 1);
                tracing::warn!("MAVLink link up again");
                let _ = w.fusion_tx.try_send(FusionMsg::LinkState {
                    up: true,
                    silent_s: silent.as_secs_f64(),
                });
            }
            // Heard, but no IMU in the message taken: the stream requests
            // go unanswered.
            let imu = (w.counters.get(Counter::ImuHighres)
                + w.counters.get(Counter::ImuScaled)
                + w.counters.get(Counter::ImuRaw))
            .saturating_sub(w.counters.get(Counter::ImuMessageIgnored));
            if !imu_warned && heard.is_some() && imu == 0 && w.start.elapsed() > IMU_EXPECTED_WITHIN {
                imu_warned = true;
                w.counters.add(Counter::AutopilotSendsNoImu, 1);
                tracing::error!(
                    %address,
                    "the autopilot on {address} sends no IMU in the message taken (mavlink.imu_message: HIGHRES_IMU, \
                     or SCALED_IMU from PX4) although asked: check its stream rates and that it accepts \
                     MAV_CMD_SET_MESSAGE_INTERVAL"
                );
            }
            if let Some(limit) = exit_after {
                if silent >= limit {
                    let why = format!(
                        "the autopilot has been silent for {:.1} s (mavlink.link_exit_after_s = {:.1})",
                        silent.as_secs_f64(),
                        limit.as_secs_f64()
                    );
                    tracing::error!("{why}: exiting so that the service manager restarts us");
                    let _ = w.fatal.send(Some(why));
                    return;
                }
            }
        }
    })
}
