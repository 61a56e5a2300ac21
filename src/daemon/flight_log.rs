//! The fusion loop's flight log: the MCAP logger, the records that came
//! before any IMU sample (they wait for a sensor time), the pacing of
//! `/diagnostics`, and the log's own lines (`/log`). The other parts write
//! through it; none of them holds the logger.

use std::cell::RefCell;

use serde::Serialize;

use super::records::Stamp;
use crate::counters::{Counter, Counters};
use crate::io::mcap_log::{InputRecord, McapLogger, Topic};
use crate::status;

/// Records held until the first IMU sample gives them a sensor time.
const PRE_IMU_LOG_CAP: usize = 1024;

/// `foxglove.Log` levels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Level {
    Info = 2,
    Warning = 3,
    Error = 4,
}

/// The flight log as the fusion loop writes it (`None` inside: no log).
pub(super) struct FlightLog {
    logger: Option<McapLogger>,
    /// Records of inputs that came before any IMU sample (an ephemeris, the
    /// autopilot's origin): they have no sensor time yet, so they wait and
    /// are logged, in order, at the first IMU sample's time rather than at 0.
    pre_imu: RefCell<Vec<(Topic, serde_json::Value)>>,
    /// Next autopilot time to log the counters at (`/diagnostics`).
    next_diag_t: f64,
    /// `log.new_log_on_disarm`: each flight a log of its own.
    new_log_on_disarm: bool,
}

/// A `/diagnostics` record: every counter and the degraded-state reasons.
#[derive(Serialize)]
struct Diagnostics<'a> {
    t_s: f64,
    counters: &'a std::collections::BTreeMap<String, u64>,
    degraded: &'a str,
    reset_counter: u8,
}

/// A `/log` record (`foxglove.Log`).
#[derive(Serialize)]
struct LogLine<'a> {
    timestamp: Stamp,
    level: u8,
    message: &'a str,
    name: &'a str,
    file: &'a str,
    line: u32,
}

impl FlightLog {
    pub(super) fn new(logger: Option<McapLogger>, new_log_on_disarm: bool) -> Self {
        Self {
            logger,
            pre_imu: RefCell::new(Vec::new()),
            next_diag_t: f64::NEG_INFINITY,
            new_log_on_disarm,
        }
    }

    /// The autopilot's Unix time minus its boot time (s), from
    /// `SYSTEM_TIME`: the log's records are stamped in Unix time from it
    /// (their boot time stays their publish time).
    pub(super) fn unix_minus_boot(&self, offset_s: f64) {
        if let Some(l) = &self.logger {
            l.set_unix_minus_boot(offset_s);
        }
    }

    /// The vehicle disarmed: its flight's log is closed (whole, with its
    /// summary) and the next begun, if `log.new_log_on_disarm`. The daemon's
    /// logger only: replay's writes one file.
    pub(super) fn disarmed(&self) {
        if let (true, Some(l)) = (self.new_log_on_disarm, &self.logger) {
            l.rotate();
        }
    }

    /// The logger, for the records written at IMU and camera rate (always
    /// after the first IMU sample); `None` without a log.
    pub(super) fn logger(&self) -> Option<&McapLogger> {
        self.logger.as_ref()
    }

    /// An input, as the fusion loop consumed it (what replay feeds back).
    pub(super) fn input(&self, t_s: f64, rec: &InputRecord<'_>) {
        self.record(rec.topic(), t_s, rec);
    }

    /// A record at `t_s`; before any IMU sample (`t_s` not finite) it
    /// waits for one.
    pub(super) fn record<T: Serialize>(&self, topic: Topic, t_s: f64, v: &T) {
        let Some(l) = &self.logger else { return };
        let mut pending = self.pre_imu.borrow_mut();
        if !t_s.is_finite() {
            // Bounded; past the bound the logger's own stamp, 0, is better
            // than none.
            if pending.len() < PRE_IMU_LOG_CAP {
                if let Ok(v) = serde_json::to_value(v) {
                    pending.push((topic, v));
                    return;
                }
            }
        } else {
            for (topic, v) in pending.drain(..) {
                l.log(topic, t_s, &v);
            }
        }
        l.log(topic, t_s, v);
    }

    /// A line of the log's `/log` (`foxglove.Log`).
    pub(super) fn text(&self, level: Level, t_s: f64, message: &str) {
        let t = t_s.max(0.0);
        self.record(
            Topic::Log,
            t,
            &LogLine {
                timestamp: Stamp::at(t),
                level: level as u8,
                message,
                name: "cmsckf",
                file: file!(),
                line: 0,
            },
        );
    }

    /// The counters and degraded-state reasons to `/diagnostics`, once a
    /// second of autopilot time.
    pub(super) fn diagnostics_if_due(&mut self, t_s: f64, counters: &Counters, degraded: u32, reset_counter: u8) {
        if t_s >= self.next_diag_t {
            self.next_diag_t = t_s + 1.0;
            self.diagnostics(t_s, counters, degraded, reset_counter);
        }
    }

    fn diagnostics(&self, t_s: f64, counters: &Counters, degraded: u32, reset_counter: u8) {
        if self.logger.is_some() {
            let snapshot = counters.snapshot();
            let degraded = status::describe(degraded);
            self.record(
                Topic::Diagnostics,
                t_s,
                &Diagnostics {
                    t_s,
                    counters: &snapshot,
                    degraded: &degraded,
                    reset_counter,
                },
            );
        }
    }

    /// Finishes the log (on shutdown: `Drop` would swallow its errors),
    /// counting its messages and raising an alarm for dropped records.
    /// `last_imu_t` is the last sample's time (−∞: none came).
    pub(super) fn finish(&mut self, last_imu_t: f64, counters: &Counters, reset_counter: u8) {
        if last_imu_t.is_finite() {
            self.diagnostics(last_imu_t, counters, 0, reset_counter);
        }
        // A log that never saw an IMU sample still keeps its other inputs.
        if let Some(l) = &self.logger {
            for (topic, v) in self.pre_imu.get_mut().drain(..) {
                l.log(topic, 0.0, &v);
            }
        }
        let Some(l) = self.logger.take() else {
            return;
        };
        let dropped = l.dropped();
        match l.finish() {
            Ok(s) => {
                counters.add(Counter::LogMessages, s.messages);
                counters.add(Counter::LogChunks, s.chunks);
                counters.add(Counter::LogLateRecords, s.late);
            }
            Err(e) => {
                counters.add(Counter::LogError, 1);
                tracing::error!(error = %e, "the MCAP log could not be finished");
            }
        }
        // Each drop was counted as it happened (`log_dropped`, and the
        // `log_stalled` alarm).
        if dropped > 0 {
            tracing::error!(
                dropped,
                "ALARM: MCAP log records were dropped (writer could not keep up)"
            );
        }
    }
}
