//! The daemon's state as the autopilot sees it in `HEARTBEAT`: standby
//! until the filter starts (and while it restarts), then active, or
//! critical while degraded, with the reasons sent as `STATUSTEXT` when they
//! change.
//!
//! The fusion thread judges degradation in autopilot time (so a SITL
//! speed-up changes nothing) and publishes it through [`Status`]; the status
//! task reads it and the wall-clock age of the last IMU sample (a link that
//! went silent has no autopilot time) and sends a `HEARTBEAT` at once on any
//! change, besides the 1 Hz one.

use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};

use crate::counters::Counters;

/// Why the daemon is degraded: bit `1 << reason as u32` of [`Status::degraded`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Degraded {
    /// IMU samples stopped for more than 0.2 s (held 2 s after they resume),
    /// or for 0.5 s of wall time right now.
    ImuGap = 0,
    /// No camera frame processed for 1 s, or none in the 1 s since the
    /// filter started.
    CameraStale = 1,
    /// GNSS was being fused, and no epoch for 3 s.
    GnssStale = 2,
    /// Input rejected in the last 2 s: non-finite or out-of-order samples,
    /// malformed lines, RTCM CRC failures or lost fragments.
    InputRejected = 3,
    /// Two or more pseudoranges rejected in each of two epochs in a row
    /// (held 2 s). One epoch is not enough: the 99% gate alone rejects two
    /// good codes of sixteen in about one epoch of seventy.
    GnssOutliers = 4,
    /// The filter was reset (divergence or an autopilot reboot; held 2 s).
    FilterReset = 5,
    /// Nothing heard from the autopilot for `mavlink.link_timeout_s`'s
    /// warning part (set by the link task, in wall time).
    LinkDown = 6,
    /// The flight log cannot be written (disk full or an I/O error; set by
    /// the log writer, in wall time, until a write succeeds again).
    LogDiskFull = 7,
    /// The filter runs and nothing (a camera frame, a GNSS epoch) has been
    /// fused for [`DEAD_RECKONING_S`]: its position is the IMU's alone, and
    /// its error grows with the cube of the time (ODOMETRY's quality is 1).
    DeadReckoning = 8,
    /// The base station's corrections are not used: its announced antenna
    /// position disagrees with its own fixes, or its corrected codes kept
    /// failing the gate (single point meanwhile).
    GnssBaseRefused = 9,
    /// Three GNSS epochs in a row gave no usable measurement (held 2 s): no
    /// ephemeris, a wrong week, or every code refused.
    GnssUnusable = 10,
    /// Flight-log records are being dropped: the writer cannot keep up, or
    /// its file blocks (a stalled card). Set by the logger in wall time,
    /// cleared when records go through again.
    LogStalled = 11,
}

/// Without a fused measurement for this long, a running filter is dead
/// reckoning (s of autopilot time).
pub const DEAD_RECKONING_S: f64 = 1.0;

impl Degraded {
    pub const ALL: [Degraded; 12] = [
        Degraded::ImuGap,
        Degraded::CameraStale,
        Degraded::GnssStale,
        Degraded::InputRejected,
        Degraded::GnssOutliers,
        Degraded::FilterReset,
        Degraded::LinkDown,
        Degraded::LogDiskFull,
        Degraded::DeadReckoning,
        Degraded::GnssBaseRefused,
        Degraded::GnssUnusable,
        Degraded::LogStalled,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Degraded::ImuGap => "imu_gap",
            Degraded::CameraStale => "camera_stale",
            Degraded::GnssStale => "gnss_stale",
            Degraded::InputRejected => "input_rejected",
            Degraded::GnssOutliers => "gnss_outliers",
            Degraded::FilterReset => "filter_reset",
            Degraded::LinkDown => "link_down",
            Degraded::LogDiskFull => "log_disk_full",
            Degraded::DeadReckoning => "dead_reckoning",
            Degraded::GnssBaseRefused => "gnss_base_refused",
            Degraded::GnssUnusable => "gnss_unusable",
            Degraded::LogStalled => "log_stalled",
        }
    }

    pub fn bit(self) -> u32 {
        1 << self as u32
    }
}

/// The reasons set in `bits`, comma-separated ("" when none).
pub fn describe(bits: u32) -> String {
    Degraded::ALL
        .iter()
        .filter(|d| bits & d.bit() != 0)
        .map(|d| d.name())
        .collect::<Vec<_>>()
        .join(",")
}

/// Shared between the fusion thread and the status task.
#[derive(Debug, Default)]
pub struct Status {
    /// A filter is running (an unhealthy one is restarted at once).
    pub initialised: AtomicBool,
    /// Bits of [`Degraded`] judged by the fusion thread in autopilot time
    /// (rewritten whole by [`Tracker::update`]).
    pub degraded: AtomicU32,
    /// Bits of [`Degraded`] set and cleared by the I/O tasks in wall time
    /// (the link, the log writer): see [`Status::set_io`].
    pub io_degraded: AtomicU32,
    /// Wall time of the last IMU sample, ms since the daemon started.
    pub last_imu_wall_ms: AtomicU64,
}

impl Status {
    /// Every reason in force: the fusion thread's and the I/O tasks'.
    pub fn degraded(&self) -> u32 {
        self.degraded.load(Ordering::Relaxed) | self.io_degraded.load(Ordering::Relaxed)
    }

    /// Sets (`on`) or clears a reason owned by an I/O task.
    pub fn set_io(&self, why: Degraded, on: bool) {
        if on {
            self.io_degraded.fetch_or(why.bit(), Ordering::Relaxed);
        } else {
            self.io_degraded.fetch_and(!why.bit(), Ordering::Relaxed);
        }
    }
}

/// How long a transient reason stays set (s of autopilot time).
const HOLD_S: f64 = 2.0;
/// The fusion thread's side: held reasons and input freshness, in
/// autopilot time.
#[derive(Clone, Debug)]
pub struct Tracker {
    held_until: [f64; Degraded::ALL.len()],
    /// When the running filter started (`-inf`: none has yet).
    filter_started_t: f64,
    last_frame_t: f64,
    last_gnss_t: f64,
    rejections: u64,
    next_check_t: f64,
    /// Consecutive GNSS epochs with two or more codes rejected.
    bad_epochs: u32,
    /// Consecutive GNSS epochs with nothing usable.
    unusable_epochs: u32,
    /// The reasons last published.
    bits: u32,
}

impl Default for Tracker {
    fn default() -> Self {
        Self {
            held_until: [f64::NEG_INFINITY; Degraded::ALL.len()],
            filter_started_t: f64::NEG_INFINITY,
            last_frame_t: f64::NEG_INFINITY,
            last_gnss_t: f64::NEG_INFINITY,
            rejections: 0,
            next_check_t: f64::NEG_INFINITY,
            bad_epochs: 0,
            unusable_epochs: 0,
            bits: 0,
        }
    }
}

impl Tracker {
    /// Sets a transient reason for [`HOLD_S`] from `t_s`.
    pub fn hold_reason(&mut self, why: Degraded, t_s: f64) {
        self.hold_reason_until(why, t_s + HOLD_S);
    }

    /// Sets a reason until `until_s` (or longer, if already held longer).
    pub fn hold_reason_until(&mut self, why: Degraded, until_s: f64) {
        let held = &mut self.held_until[why as usize];
        *held = held.max(until_s);
    }

    /// A GNSS epoch at `t_s` that gave the filter nothing usable (`true`)
    /// or something: three in a row degrade the HEARTBEAT.
    pub fn gnss_epoch_usable(&mut self, t_s: f64, usable: bool) {
        self.unusable_epochs = if usable { 0 } else { self.unusable_epochs + 1 };
        if self.unusable_epochs >= 3 {
            self.hold_reason(Degraded::GnssUnusable, t_s);
        }
    }

    /// A filter was (re)initialised at `t_s`: from then on, no camera frame
    /// for 1 s is `camera_stale` even if none has ever arrived.
    pub fn filter_started(&mut self, t_s: f64) {
        self.filter_started_t = t_s;
    }

    /// The reasons last published (the fusion thread's own).
    pub fn bits(&self) -> u32 {
        self.bits
    }

    /// Autopilot time of the last frame processed or GNSS epoch fused
    /// (−∞ before the first).
    pub fn last_aided_s(&self) -> f64 {
        self.last_frame_t.max(self.last_gnss_t)
    }

    pub fn frame_processed(&mut self, t_s: f64) {
        self.last_frame_t = t_s;
    }

    pub fn gnss_fused(&mut self, t_s: f64) {
        self.last_gnss_t = t_s;
    }

    /// Pseudoranges rejected (χ² or outlier) in the epoch fused at `t_s`.
    pub fn gnss_codes_rejected(&mut self, t_s: f64, n: u64) {
        self.bad_epochs = if n >= 2 { self.bad_epochs + 1 } else { 0 };
        if self.bad_epochs >= 2 {
            self.hold_reason(Degraded::GnssOutliers, t_s);
        }
    }

    /// Forgets every time kept (after a reset of the autopilot's clock);
    /// the count of rejections seen is not a time and stays, so the restart
    /// itself is not taken for new rejected input.
    pub fn restart_clock(&mut self) {
        *self = Self {
            rejections: self.rejections,
            ..Self::default()
        };
    }

    /// The reasons at autopilot time `t_s` (`initialised`: the filter runs),
    /// published to `status` at most every 0.1 s.
    pub fn update(&mut self, t_s: f64, initialised: bool, counters: &Counters, status: &Status) {
        if t_s < self.next_check_t {
            return;
        }
        self.next_check_t = t_s + 0.1;
        let rejections = counters.input_rejections();
        if rejections > self.rejections {
            self.hold_reason(Degraded::InputRejected, t_s);
        }
        self.rejections = rejections;
        let mut bits = 0;
        for d in Degraded::ALL {
            if t_s < self.held_until[d as usize] {
                bits |= d.bit();
            }
        }
        // The last frame, or the filter's start if no frame has come since
        // the clock began (a front end that never wrote is stale too).
        let frame_ref_t = if self.last_frame_t.is_finite() {
            self.last_frame_t
        } else {
            self.filter_started_t
        };
        if initialised && frame_ref_t.is_finite() && t_s - frame_ref_t > 1.0 {
            bits |= Degraded::CameraStale.bit();
        }
        if self.last_gnss_t.is_finite() && t_s - self.last_gnss_t > 3.0 {
            bits |= Degraded::GnssStale.bit();
        }
        // The last measurement fused, or the filter's start if none has been.
        let aided_ref_t = match self.last_aided_s() {
            t if t.is_finite() => t,
            _ => self.filter_started_t,
        };
        if initialised && aided_ref_t.is_finite() && t_s - aided_ref_t > DEAD_RECKONING_S {
            bits |= Degraded::DeadReckoning.bit();
        }
        self.bits = bits;
        status.degraded.store(bits, Ordering::Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reasons_are_held_and_input_goes_stale() {
        let (c, s) = (Counters::default(), Status::default());
        let mut t = Tracker::default();
        t.frame_processed(0.0);
        t.gnss_fused(0.0);
        t.update(0.5, true, &c, &s);
        assert_eq!(s.degraded(), 0);
        t.update(1.5, true, &c, &s);
        assert_eq!(describe(s.degraded()), "camera_stale,dead_reckoning");
        t.frame_processed(1.55);
        c.add(crate::counters::Counter::RtcmCrcFailure, 1);
        t.update(1.6, true, &c, &s);
        assert_eq!(describe(s.degraded()), "input_rejected");
        t.frame_processed(3.7);
        t.gnss_fused(3.7);
        t.update(3.7, true, &c, &s);
        assert_eq!(s.degraded(), 0, "the hold ends after 2 s");
        t.gnss_codes_rejected(3.9, 2);
        t.gnss_codes_rejected(3.95, 1);
        t.gnss_codes_rejected(3.97, 3);
        t.update(3.97, true, &c, &s);
        assert_eq!(s.degraded(), 0, "one bad epoch at a time is noise");
        t.gnss_codes_rejected(4.0, 2);
        t.update(4.1, true, &c, &s);
        assert_eq!(describe(s.degraded()), "gnss_outliers");
        t.update(7.0, true, &c, &s);
        assert_eq!(describe(s.degraded()), "camera_stale,gnss_stale,dead_reckoning");
        // Updates within 0.1 s of the last are skipped (cheap per sample).
        t.frame_processed(7.0);
        t.update(7.05, true, &c, &s);
        assert_eq!(describe(s.degraded()), "camera_stale,gnss_stale,dead_reckoning");
        // A frame fused ends the dead reckoning; GNSS stays stale.
        t.update(7.2, true, &c, &s);
        assert_eq!(describe(s.degraded()), "gnss_stale");
    }

    #[test]
    fn no_frame_ever_is_camera_stale_a_second_after_the_filter_starts() {
        let (c, s) = (Counters::default(), Status::default());
        let mut t = Tracker::default();
        // No filter yet, no frame: standby, not stale.
        t.update(0.5, false, &c, &s);
        t.update(5.0, false, &c, &s);
        assert_eq!(s.degraded(), 0);
        t.filter_started(5.0);
        t.update(5.9, true, &c, &s);
        assert_eq!(s.degraded(), 0, "within 1 s of the start");
        t.update(6.1, true, &c, &s);
        assert_eq!(
            describe(s.degraded()),
            "camera_stale,dead_reckoning",
            "no frame at all since the start"
        );
        t.frame_processed(6.15);
        t.update(6.2, true, &c, &s);
        assert_eq!(s.degraded(), 0, "a frame clears it");
        t.update(7.3, true, &c, &s);
        assert_eq!(describe(s.degraded()), "camera_stale,dead_reckoning");
        // A reboot forgets every time: the new filter's start counts again.
        t.restart_clock();
        t.update(1.0, false, &c, &s);
        assert_eq!(s.degraded(), 0, "no filter, no clock: nothing stale");
        t.filter_started(1.0);
        t.update(1.5, true, &c, &s);
        assert_eq!(s.degraded(), 0);
        t.update(2.2, true, &c, &s);
        assert_eq!(describe(s.degraded()), "camera_stale,dead_reckoning");
    }
}
