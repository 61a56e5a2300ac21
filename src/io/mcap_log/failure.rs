//! What happens when the file cannot be written (a full disk): the chunks wait
//! in the spool and the write is retried every second, while the alarm (status
//! bit, one critical `STATUSTEXT`, counters) tells the daemon at once.

use std::time::{Duration, Instant};

use tokio::sync::mpsc;

use super::spool::write_spool;
use super::writer::{Failure, LogWriter};
use super::{LogAlarm, COUNTER_DROPPED_WRITE_ERROR, COUNTER_WRITE_FAILED};
use crate::io::messages::Outbound;
use crate::status::Degraded;

/// How often a failed write of the file is retried.
const RETRY_WALL: Duration = Duration::from_secs(1);
/// How often the writer's counts are published to the daemon's counters
/// while records are being lost.
const PUBLISH_WALL: Duration = Duration::from_secs(1);

impl LogWriter {
    /// Writes what the file does not have yet (whole chunks: no chunk is
    /// open). While the file cannot be written, only once
    /// [`RETRY_WALL`] has passed since the last try.
    pub(super) fn save(&mut self) {
        let now = Instant::now();
        if self.failure.as_ref().is_some_and(|f| now < f.next_retry) {
            return;
        }
        match write_spool(&self.spool, &mut *self.file) {
            Ok(()) => self.on_saved(now),
            Err(e) => self.on_write_error(e, now),
        }
    }

    /// Everything given so far is in the file: a failure is over.
    fn on_saved(&mut self, now: Instant) {
        self.unsaved_records = 0;
        let Some(f) = self.failure.take() else {
            return;
        };
        tracing::warn!(
            path = %self.path.display(),
            after_s = now.duration_since(f.since).as_secs_f64(),
            lost = self.summary.dropped_write_error,
            "MCAP log can be written again"
        );
        if let Some(a) = &self.alarm {
            a.status.set_io(Degraded::LogDiskFull, false);
        }
        self.first_error.get_or_insert(f.first);
        self.publish();
    }

    /// A write of the file failed: at the first, the alarm (status bit,
    /// STATUSTEXT, error in the journal); at each, a count and a retry
    /// [`RETRY_WALL`] later.
    fn on_write_error(&mut self, e: std::io::Error, now: Instant) {
        self.summary.write_failures += 1;
        let next_retry = now + RETRY_WALL;
        if let Some(f) = &mut self.failure {
            f.next_retry = next_retry;
            tracing::debug!(error = %e, "MCAP log: retried write failed");
            return;
        }
        tracing::error!(
            path = %self.path.display(),
            error = %e,
            "ALARM: the MCAP log cannot be written; records are kept in memory (up to {} MiB) and retried every {} s, then dropped",
            self.spool_max_bytes >> 20,
            RETRY_WALL.as_secs()
        );
        if let Some(a) = &self.alarm {
            a.status.set_io(Degraded::LogDiskFull, true);
        }
        let text_pending = !send_text(self.alarm.as_ref(), &e);
        self.failure = Some(Failure {
            first: e,
            since: now,
            next_retry,
            text_pending,
        });
        self.publish();
    }

    /// Keeps the alarm going: queues a failure's explicit STATUSTEXT if the
    /// queue was full before, and publishes the counts every
    /// [`PUBLISH_WALL`].
    pub(super) fn keep_alarm(&mut self, now: Instant) {
        if let Some(f) = &mut self.failure {
            if f.text_pending {
                f.text_pending = !send_text(self.alarm.as_ref(), &f.first);
            }
        }
        if now >= self.last_publish + PUBLISH_WALL {
            self.publish();
        }
    }

    /// Adds the counts of write failures and records lost since the last
    /// time to the alarm's counters.
    pub(super) fn publish(&mut self) {
        self.last_publish = Instant::now();
        let Some(a) = &self.alarm else { return };
        let now = (self.summary.write_failures, self.summary.dropped_write_error);
        if now.0 > self.published.0 {
            a.counters.add(COUNTER_WRITE_FAILED, now.0 - self.published.0);
        }
        if now.1 > self.published.1 {
            a.counters.add(COUNTER_DROPPED_WRITE_ERROR, now.1 - self.published.1);
        }
        self.published = now;
    }
}

/// Queues the explicit STATUSTEXT of a write failure (critical); false if
/// the queue was full (try again later).
fn send_text(alarm: Option<&LogAlarm>, e: &std::io::Error) -> bool {
    let Some(a) = alarm else { return true };
    let text = match e.kind() {
        std::io::ErrorKind::StorageFull | std::io::ErrorKind::QuotaExceeded => "cmsckf: log disk full".to_string(),
        _ => match e.raw_os_error() {
            Some(n) => format!("cmsckf: log cannot be written (os error {n})"),
            None => "cmsckf: log cannot be written".to_string(),
        },
    };
    !matches!(
        a.out.try_send(Outbound::StatusText { severity: 2, text }),
        Err(mpsc::error::TrySendError::Full(_))
    )
}
