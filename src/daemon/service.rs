//! Telling the service manager how we are (systemd's `Type=notify`):
//! `READY=1` once every task runs, and, when the unit sets `WatchdogSec=`,
//! `WATCHDOG=1` at half that period for as long as the fusion thread keeps
//! taking its input. A hung fusion thread (input waiting, none taken for a
//! whole half-period) stops the pings, and systemd restarts the daemon.
//! Outside systemd (`NOTIFY_SOCKET` unset) nothing is sent.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use sd_notify::NotifyState;
use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;

use super::FusionMsg;
use crate::counters::{Counter, Counters};

/// Says `READY=1` and spawns the watchdog pinger (a task that ends at once
/// when no watchdog is set). `progress` counts the inputs the fusion thread
/// has taken.
pub(super) fn spawn_notifier(
    progress: Arc<AtomicU64>,
    fusion_tx: mpsc::WeakSender<FusionMsg>,
    counters: Counters,
    mut stop: watch::Receiver<bool>,
) -> JoinHandle<()> {
    if let Err(e) = sd_notify::notify(&[NotifyState::Ready]) {
        tracing::warn!(error = %e, "could not tell the service manager we are ready");
    }
    let watchdog = sd_notify::watchdog_enabled();
    tokio::spawn(async move {
        let Some(period) = watchdog else { return };
        tracing::info!(period_s = period.as_secs_f64(), "systemd watchdog on");
        let mut tick = tokio::time::interval(period / 2);
        let mut last = progress.load(Ordering::Relaxed);
        loop {
            tokio::select! { _ = tick.tick() => {}, _ = stop.changed() => break }
            let now = progress.load(Ordering::Relaxed);
            let waiting = fusion_tx.upgrade().map_or(0, |tx| tx.max_capacity() - tx.capacity());
            if now == last && waiting > 0 {
                counters.add(Counter::WatchdogWithheld, 1);
                tracing::error!(waiting, "the fusion thread takes no input: the watchdog is not pinged");
                continue;
            }
            last = now;
            if sd_notify::notify(&[NotifyState::Watchdog]).is_ok() {
                counters.add(Counter::WatchdogPings, 1);
            }
        }
        let _ = sd_notify::notify(&[NotifyState::Stopping]);
    })
}
