//! What the autopilot tells us about itself (its attitude, local position,
//! magnetometer, GNSS accuracy, clock, EKF origin) and the link's state,
//! kept for the filter's start and GNSS time and logged for replay; and the
//! one thing we tell it back besides estimates, our origin, until it
//! reports it back.

use cmsckf_models::geodesy::{ecef_to_llh, llh_to_ecef, NedFrame};
use cmsckf_models::geoid;
use tokio::sync::mpsc;

use std::collections::VecDeque;

use nalgebra::Vector3;

use super::flight_log::{FlightLog, Level};
use super::gnss_input::GnssIn;
use super::nav_params::NavParams;
use super::time_guard::SteadyValue;
use super::{FusionMsg, Restart};
use crate::counters::{Counter, Counters};
use crate::estimator::landed::LandedGate;
use crate::io::mcap_log::input::{
    AutopilotRecord, InputRecord, LocalPositionRecord, ParamRecord, SimStateRecord, SystemTimeRecord,
};
use crate::io::messages::AutopilotKind;
use crate::io::messages::Outbound;

/// Magnetometer readings kept for the compass yaw (10 Hz: about 1 s).
const MAG_READINGS: usize = 10;

/// SYSTEM_TIME: a change of the Unix − boot offset beyond this (s) is
/// believed once this many messages agree on it.
const SYSTEM_TIME_TOL_S: f64 = 1.0;
const SYSTEM_TIME_CONFIRM: u32 = 3;
/// The autopilot's GNSS fix counts as its own position source for this long
/// after its last `GPS_RAW_INT` with a 3D fix (s).
const AUTOPILOT_FIX_FRESH_S: f64 = 5.0;
/// The origin is sent again this often until the autopilot reports it (s
/// of autopilot time), at most [`ORIGIN_TRIES`] times.
const ORIGIN_RESEND_S: f64 = 2.0;
const ORIGIN_TRIES: u32 = 30;
/// The autopilot's origin is ours when within this (m).
const ORIGIN_MATCH_M: f64 = 1.0;
/// Without an origin of our own to send: GPS_GLOBAL_ORIGIN is asked for
/// this often (s of autopilot time) until the autopilot reports one, and
/// its absence is said once our filter has run this long, then again this
/// often: ArduPilot without an EKF origin sets no home and will not arm
/// ("AHRS: waiting for home"), and an origin a ground station set before
/// EKF3 started is lost without a word.
const ORIGIN_ASK_S: f64 = 2.0;
const ORIGIN_MISSING_AFTER_S: f64 = 5.0;
const ORIGIN_MISSING_REPEAT_S: f64 = 30.0;

/// Sending our origin: a UDP autopilot is only heard after its first
/// HEARTBEAT, and a message can be lost, so it is sent until the
/// autopilot's `GPS_GLOBAL_ORIGIN` comes back.
#[derive(Debug, Default)]
struct OriginSend {
    /// The autopilot reported an origin (ours, or its own).
    settled: bool,
    /// It reported an origin of its own (not the one we sent): its GNSS,
    /// if it has a fix, places it (see [`AutopilotView::has_own_position`]).
    own: bool,
    next_t_s: f64,
    tries: u32,
    /// With no origin of ours: the first IMU sample's time, the next
    /// request for GPS_GLOBAL_ORIGIN and the next warning of its absence.
    running_since_t_s: Option<f64>,
    next_ask_t_s: f64,
    next_warn_t_s: f64,
}

/// A disarm must last this long (s of autopilot time: two HEARTBEATs and
/// more) before the flight's log ends.
const DISARM_CONFIRM_S: f64 = 2.5;

/// The autopilot's state as it reports it, owned here: what a start reads
/// (attitude, local position, accuracy, magnetometer, date), what the
/// zero-velocity updates and the outputs follow (armed, landed, its kind),
/// its clock's Unix offset, and our origin sent until it reports it back.
#[derive(Debug)]
pub(super) struct AutopilotView {
    /// Roll, pitch, yaw (rad), from `ATTITUDE`.
    attitude: Option<(f64, f64, f64)>,
    /// The autopilot's local position and velocity (NED) and their time (s).
    local: Option<(Vector3<f64>, Vector3<f64>, f64)>,
    /// The autopilot's GNSS accuracy `(horizontal, vertical)` (m, one
    /// sigma), when it reports one.
    gps_accuracy: Option<(f64, f64)>,
    /// The latest magnetometer readings (body frame, ~1 s).
    mag_B: VecDeque<Vector3<f64>>,
    /// Today in Unix days (the companion's clock at start), for the
    /// declination.
    unix_days: Option<i64>,
    /// Its flight mode (logged on change).
    mode: Option<u32>,
    /// When it disarmed after an arming, until the log is rotated.
    disarmed_since: Option<f64>,
    /// Its landed and armed states when it reports them, and the take-off
    /// grace they open (IMU time).
    gate: LandedGate,
    /// Which autopilot its HEARTBEAT says it is.
    kind: Option<AutopilotKind>,
    /// When (IMU time) it last reported a 3D GNSS fix of its own.
    fix_t: Option<f64>,
    /// Its Unix − boot offset (s), from SYSTEM_TIME, changed only when
    /// several messages agree.
    unix_minus_boot: SteadyValue,
    /// Our origin, sent until it reports it back.
    origin: OriginSend,
    /// Its navigation parameters, asked for and judged.
    params: NavParams,
}

impl Default for AutopilotView {
    fn default() -> Self {
        Self {
            attitude: None,
            local: None,
            gps_accuracy: None,
            mag_B: VecDeque::with_capacity(MAG_READINGS),
            unix_days: None,
            mode: None,
            disarmed_since: None,
            gate: LandedGate::default(),
            kind: None,
            fix_t: None,
            unix_minus_boot: SteadyValue::new(SYSTEM_TIME_TOL_S, SYSTEM_TIME_CONFIRM),
            origin: OriginSend::default(),
            params: NavParams::default(),
        }
    }
}

impl AutopilotView {
    /// The autopilot's attitude, local position, clock and origin: kept for
    /// initialisation and GNSS time (`gnss`), and logged for replay at the
    /// last IMU sample's time `t_s`.
    pub(super) fn on_message(
        &mut self,
        msg: FusionMsg,
        t_s: f64,
        gnss: &mut GnssIn,
        log: &FlightLog,
        counters: &Counters,
    ) {
        let log_autopilot = |rec: AutopilotRecord| log.input(t_s, &InputRecord::Autopilot(rec));
        match msg {
            FusionMsg::Attitude { roll, pitch, yaw } => {
                log_autopilot(AutopilotRecord::Attitude([roll, pitch, yaw]));
                self.attitude = Some((roll, pitch, yaw))
            }
            FusionMsg::LocalPosition {
                t_s,
                p_ned_m,
                v_ned_mps,
            } => {
                log_autopilot(AutopilotRecord::LocalPosition(LocalPositionRecord {
                    t_s,
                    p_ned_m: p_ned_m.into(),
                    v_ned_mps: v_ned_mps.into(),
                }));
                self.local = Some((p_ned_m, v_ned_mps, t_s))
            }
            FusionMsg::Pressure(p) => log_autopilot(AutopilotRecord::Pressure(p)),
            FusionMsg::Magnetometer { mag_B } => {
                log_autopilot(AutopilotRecord::Magnetometer(mag_B.into()));
                if self.mag_B.len() == MAG_READINGS {
                    self.mag_B.pop_front();
                }
                self.mag_B.push_back(mag_B);
            }
            FusionMsg::AutopilotText { severity, text } => {
                log_autopilot(AutopilotRecord::StatusText(
                    crate::io::mcap_log::input::StatusTextRecord { severity, text },
                ));
            }
            FusionMsg::VehicleState {
                armed,
                on_ground,
                kind,
                mode,
            } => {
                // The kind first: a reader names the mode's number by it.
                if let Some(k) = kind.filter(|k| Some(*k) != self.kind) {
                    log_autopilot(AutopilotRecord::Autopilot(k));
                    self.kind = kind;
                    self.params.set_kind(k);
                }
                if let Some(m) = mode.filter(|m| Some(*m) != self.mode) {
                    log_autopilot(AutopilotRecord::Mode(m));
                    self.mode = mode;
                }
                // Logged on change only (the HEARTBEAT comes every second).
                if let Some(a) = armed.filter(|a| Some(*a) != self.gate.armed()) {
                    log_autopilot(AutopilotRecord::Armed(a));
                    // A disarm after an arming ends the flight's log, once it
                    // has lasted DISARM_CONFIRM_S: a stale HEARTBEAT copy
                    // between two armed ones must not cut the log.
                    self.disarmed_since = (!a && self.gate.armed() == Some(true)).then_some(t_s);
                    self.gate.set_armed(a);
                }
                if let Some(t0) = self.disarmed_since {
                    if armed == Some(false) && t_s - t0 >= DISARM_CONFIRM_S {
                        self.disarmed_since = None;
                        log.disarmed();
                    }
                }
                if let Some(g) = on_ground {
                    if self.gate.set_on_ground(t_s, g) {
                        log_autopilot(AutopilotRecord::OnGround(g));
                    }
                }
            }
            FusionMsg::Date { unix_days } => {
                log_autopilot(AutopilotRecord::UnixDays(unix_days));
                self.unix_days = Some(unix_days);
            }
            FusionMsg::SimState(crate::io::messages::SimTruth {
                lat_deg,
                lon_deg,
                alt_m,
                q_wxyz,
                v_ned_mps,
            }) => {
                // A simulator's truth, for review only: also placed in our
                // world frame once its origin is known (MSL → ellipsoid as
                // for the origin itself).
                let p_ned_m = gnss.frame().map(|f| {
                    let h_m = geoid::ellipsoid_from_msl(lat_deg, lon_deg, alt_m);
                    let r = llh_to_ecef(lat_deg.to_radians(), lon_deg.to_radians(), h_m);
                    let p = f.R_ecef_ned.transpose() * (r - f.origin_ecef);
                    [p.x, p.y, p.z]
                });
                log_autopilot(AutopilotRecord::SimState(SimStateRecord {
                    lat_deg,
                    lon_deg,
                    alt_m,
                    q_wxyz,
                    v_ned_mps: v_ned_mps.into(),
                    p_ned_m,
                }));
            }
            FusionMsg::EstimatorStatus(s) => {
                // Whether the autopilot took our position: for the review and
                // the counters, never fused.
                if s.pos_horiz_ratio > 1.0 || s.pos_vert_ratio > 1.0 {
                    counters.add(Counter::AutopilotRejectedOurPosition, 1);
                }
                log_autopilot(AutopilotRecord::EstimatorStatus(s));
            }
            FusionMsg::GpsAccuracy { h_acc_m, v_acc_m } => {
                // Logged for replay, kept as the prior of an in-flight start.
                log_autopilot(AutopilotRecord::GpsAccuracy(
                    [h_acc_m, v_acc_m].map(|a| a.is_finite().then_some(a)),
                ));
                self.gps_accuracy = (h_acc_m.is_finite() && v_acc_m.is_finite()).then_some((h_acc_m, v_acc_m));
                self.fix_t = Some(t_s);
            }
            FusionMsg::SystemTime { unix_us, boot_ms } => {
                log.input(
                    boot_ms as f64 * 1e-3,
                    &InputRecord::SystemTime(SystemTimeRecord { unix_us, boot_ms }),
                );
                match self
                    .unix_minus_boot
                    .offer(unix_us as f64 * 1e-6 - boot_ms as f64 * 1e-3)
                {
                    Some(offset_s) => {
                        log.unix_minus_boot(offset_s);
                        gnss.set_unix_minus_boot(Some(offset_s));
                        gnss.set_autopilot_unix_time(unix_us as f64 * 1e-6, counters);
                    }
                    None => {
                        counters.add(Counter::SystemTimeOutlier, 1);
                        tracing::warn!(reason = "system_time_outlier", unix_us, boot_ms, "SYSTEM_TIME rejected");
                    }
                }
            }
            FusionMsg::Origin {
                lat_deg,
                lon_deg,
                alt_m,
            } => {
                log_autopilot(AutopilotRecord::Origin([lat_deg, lon_deg, alt_m]));
                // MAVLink gives the origin's altitude above mean sea level;
                // our frame is on the ellipsoid (EGM96, §geoid).
                let h_m = geoid::ellipsoid_from_msl(lat_deg, lon_deg, alt_m);
                match gnss.frame() {
                    None => {
                        gnss.set_frame(NedFrame::from_llh_deg(lat_deg, lon_deg, h_m));
                        counters.add(Counter::GnssOriginFromAutopilot, 1);
                        self.origin.own = true;
                    }
                    Some(ours) => {
                        let theirs = llh_to_ecef(lat_deg.to_radians(), lon_deg.to_radians(), h_m);
                        let off_m = (theirs - ours.origin_ecef).norm();
                        // Judged at every report, whatever came first (a
                        // PX4 heard before its own origin was withheld
                        // ours): its own unless it is the one we sent.
                        self.origin.own = off_m > ORIGIN_MATCH_M || self.origin.tries == 0;
                        let first = !self.origin.settled;
                        if first && off_m <= ORIGIN_MATCH_M {
                            counters.add(Counter::GpsOriginConfirmed, 1);
                            log.text(Level::Info, t_s, "the autopilot took our origin");
                        } else if first {
                            // An autopilot sets its origin once: its GNSS
                            // (or a ground station) came first.
                            counters.add(Counter::GpsOriginMismatch, 1);
                            let text = format!(
                                "the autopilot's EKF origin is {off_m:.1} m from ours: its global positions \
                                 of our estimates will be off by that"
                            );
                            tracing::warn!(reason = "gps_origin_mismatch", off_m, "{text}");
                            log.text(Level::Warning, t_s, &text);
                        }
                    }
                }
                self.origin.settled = true;
            }
            FusionMsg::LinkState { up, silent_s } => {
                let text = if up {
                    format!("link up: the autopilot is heard again after {silent_s:.1} s")
                } else {
                    format!("link down: the autopilot has been silent for {silent_s:.1} s")
                };
                log.text(if up { Level::Warning } else { Level::Error }, t_s, &text);
            }
            _ => {}
        }
    }

    /// A `PARAM_VALUE`: logged as it came (with its value decoded for the
    /// autopilot's kind), then judged with the others it belongs to.
    pub(super) fn on_param(
        &mut self,
        p: &crate::io::messages::ParamValue,
        t_s: f64,
        log: &FlightLog,
        counters: &Counters,
        out: &mpsc::Sender<Outbound>,
    ) {
        let record = ParamRecord {
            name: p.name.clone(),
            raw_bits: p.raw.to_bits(),
            param_type: p.param_type,
            value: self.kind.and_then(|k| p.decoded(k)),
        };
        log.input(t_s, &InputRecord::Autopilot(AutopilotRecord::Param(record)));
        let armed = self.armed() == Some(true);
        self.params.on_value(p, t_s, armed, log, counters, &|o| {
            let _ = out.try_send(o);
        });
    }

    /// At each IMU sample: asks for the navigation parameters not yet
    /// answered when a round is due ([`NavParams::poll`]).
    pub(super) fn poll_params(&mut self, t_s: f64, log: &FlightLog, counters: &Counters, out: &mpsc::Sender<Outbound>) {
        let armed = self.armed() == Some(true);
        self.params.poll(t_s, armed, log, counters, &|o| {
            let _ = out.try_send(o);
        });
    }

    /// Whether the autopilot's heading is ours alone, by its parameters
    /// (`None` until they are judged, or when they do not say).
    pub(super) fn heading_ours_alone(&self) -> Option<bool> {
        self.params.heading_ours_alone()
    }

    /// On the ground by the autopilot's word ([`LandedGate::landed`]).
    fn landed(&self) -> bool {
        self.gate.landed()
    }

    /// Whether a zero-velocity update may be taken at `t_s` (IMU time):
    /// [`LandedGate::zupt_allowed`].
    pub(super) fn zupt_allowed(&self, t_s: f64) -> bool {
        self.gate.zupt_allowed(t_s)
    }

    /// The camera saw motion at `t_s`: [`LandedGate::camera_moved`]. `true`
    /// when this ended the take-off grace.
    pub(super) fn camera_moved(&mut self, t_s: f64) -> bool {
        self.gate.camera_moved(t_s)
    }

    /// Tells the autopilot our origin once it is known
    /// (`output.set_gps_origin`), again every [`ORIGIN_RESEND_S`] until it
    /// reports an origin back.
    pub(super) fn send_origin(
        &mut self,
        t_s: f64,
        frame: Option<NedFrame>,
        log: &FlightLog,
        counters: &Counters,
        out: &mpsc::Sender<Outbound>,
    ) {
        // Which autopilot it is decides whether it may have our origin:
        // one not yet heard is not sent to.
        if self.origin.settled || t_s < self.origin.next_t_s || self.kind.is_none() {
            return;
        }
        if self.kind == Some(AutopilotKind::Px4) {
            // PX4's EKF2 keeps the vehicle's global position when it takes
            // an origin (`Ekf::setEkfGlobalOrigin`): without a GNSS of its
            // own that is 0° N 0° E at 0 m, so its local position jumps
            // (5227 km north at Zürich) and, fusing our height as its
            // reference, its local heights stay offset by the origin's
            // altitude: measured on its SITL, LOCAL_POSITION_NED 489.4 m
            // below us, and an offboard climb to 5 m became one to 494 m.
            self.origin.settled = true;
            counters.add(Counter::GpsOriginWithheld, 1);
            let text = "output.set_gps_origin: not sent to PX4, which would move its local heights by the \
                        origin's altitude; it flies in our frame without one (docs/setup-px4.md)";
            tracing::warn!(reason = "gps_origin_withheld", "{text}");
            log.text(Level::Warning, t_s, text);
            return;
        }
        if self.origin.tries == ORIGIN_TRIES {
            self.origin.settled = true;
            counters.add(Counter::GpsOriginUnconfirmed, 1);
            let text = "the autopilot never reported our origin back (GPS_GLOBAL_ORIGIN)";
            tracing::warn!(reason = "gps_origin_unconfirmed", "{text}");
            log.text(Level::Warning, t_s, text);
            return;
        }
        if let Some(frame) = frame {
            // MAVLink's altitude is above mean sea level (EGM96), ours above
            // the ellipsoid: tens of metres apart.
            let (lat, lon, h) = ecef_to_llh(&frame.origin_ecef);
            let (lat_deg, lon_deg) = (lat.to_degrees(), lon.to_degrees());
            let msg = Outbound::SetGpsGlobalOrigin {
                lat_deg,
                lon_deg,
                alt_m: geoid::msl_from_ellipsoid(lat_deg, lon_deg, h),
            };
            if out.try_send(msg).is_ok() {
                self.origin.tries += 1;
                self.origin.next_t_s = t_s + ORIGIN_RESEND_S;
                counters.add(Counter::GpsOriginSent, 1);
            }
        }
    }

    /// With no origin of ours to send (`output.set_gps_origin` off, or no
    /// frame yet): asks for the autopilot's GPS_GLOBAL_ORIGIN until it
    /// reports one, and [`ORIGIN_MISSING_AFTER_S`] after the first IMU
    /// sample without it, says on STATUSTEXT, in the log and the journal
    /// that the autopilot has no EKF origin and what to do, again every
    /// [`ORIGIN_MISSING_REPEAT_S`].
    /// `warn`: no origin of ours is coming (our own receiver's first fix
    /// would give one), so its absence is worth saying.
    pub(super) fn watch_origin(
        &mut self,
        t_s: f64,
        warn: bool,
        log: &FlightLog,
        counters: &Counters,
        out: &mpsc::Sender<Outbound>,
    ) {
        let o = &mut self.origin;
        if o.settled {
            return;
        }
        let since = *o.running_since_t_s.get_or_insert(t_s);
        if t_s >= o.next_ask_t_s {
            o.next_ask_t_s = t_s + ORIGIN_ASK_S;
            let _ = out.try_send(Outbound::RequestMessage { message_id: 49 });
        }
        // An autopilot with a GNSS receiver of its own sets its origin at
        // its first fix: nothing to say. The words are ArduPilot's case (no
        // home, no arming); other autopilots are only asked.
        let own_gnss = self.gps_accuracy.is_some();
        let ardupilot = self.kind == Some(AutopilotKind::ArduPilot);
        if warn && ardupilot && !own_gnss && t_s - since >= ORIGIN_MISSING_AFTER_S && t_s >= o.next_warn_t_s {
            o.next_warn_t_s = t_s + ORIGIN_MISSING_REPEAT_S;
            counters.add(Counter::AutopilotOriginMissing, 1);
            let text = "the autopilot reports no EKF origin (GPS_GLOBAL_ORIGIN): it cannot set home or arm; \
                        set the EKF origin from the ground station now, or give gnss.origin_llh with \
                        output.set_gps_origin = true";
            tracing::warn!(reason = "autopilot_origin_missing", "{text}");
            log.text(Level::Warning, t_s, text);
            // To the pilot's screen on the ground; in the air only the log.
            if self.armed() != Some(true) {
                let _ = out.try_send(Outbound::StatusText {
                    severity: 4,
                    text: "cmsckf: autopilot has no EKF origin: set it".to_string(),
                });
            }
        }
    }

    /// Disarmed and on the ground, by what the autopilot last said.
    pub(super) fn disarmed_on_ground(&self) -> bool {
        self.armed() == Some(false) && self.landed()
    }

    /// Whether it is armed, once its HEARTBEAT has said.
    pub(super) fn armed(&self) -> Option<bool> {
        self.gate.armed()
    }

    /// Roll, pitch, yaw (rad), as `ATTITUDE` last said.
    pub(super) fn attitude(&self) -> Option<(f64, f64, f64)> {
        self.attitude
    }

    /// The local position and velocity (NED) and their time (s).
    pub(super) fn local(&self) -> Option<(Vector3<f64>, Vector3<f64>, f64)> {
        self.local
    }

    /// The GNSS accuracy `(horizontal, vertical)` (m, 1σ) it reports.
    pub(super) fn gps_accuracy(&self) -> Option<(f64, f64)> {
        self.gps_accuracy
    }

    /// The mean direction of the latest magnetometer readings (body frame,
    /// unit vector), or `None` without any.
    pub(super) fn mag_direction_B(&self) -> Option<Vector3<f64>> {
        let sum: Vector3<f64> = self.mag_B.iter().filter_map(|m| m.try_normalize(0.0)).sum();
        sum.try_normalize(1e-9)
    }

    /// The latest magnetometer readings (body frame), oldest first.
    pub(super) fn mag_readings_B(&self) -> impl Iterator<Item = &Vector3<f64>> {
        self.mag_B.iter()
    }

    pub(super) fn unix_days(&self) -> Option<i64> {
        self.unix_days
    }

    pub(super) fn kind(&self) -> Option<AutopilotKind> {
        self.kind
    }

    /// It has a position source of its own: a 3D GNSS fix reported in the
    /// last [`AUTOPILOT_FIX_FRESH_S`], and an EKF origin of its own.
    ///
    /// An autopilot whose EKF fuses its GNSS sets its origin at its first
    /// fix; one with no origin, or that took ours, has none, so its receiver
    /// (if any) is not what places it: PX4 with `EKF2_GPS_CTRL = 0` still
    /// reports SIH's or a real receiver's 3D fix, and its local position is
    /// wherever its EKF started. Worse, PX4 re-projects its local position
    /// when it takes an origin, from a reference at 0° N 0° E: its
    /// LOCAL_POSITION_NED jumps by thousands of kilometres (5227 km north
    /// at Zürich, measured on its SITL) and stays there until it fuses our
    /// estimates. Its position is then no prior for a start, nor its
    /// velocity a check of ours.
    pub(super) fn has_own_position(&self, t_s: f64) -> bool {
        self.origin.own && self.fix_t.is_some_and(|t| (t_s - t).abs() < AUTOPILOT_FIX_FRESH_S)
    }

    /// Forgets what a restart of `kind` makes stale: after an IMU gap or a
    /// reboot, its attitude and position; after a reboot, also our origin
    /// (a rebooted autopilot has lost it), its clock's Unix offset, and its
    /// navigation parameters (asked for again: [`NavParams::restart_questions`]).
    pub(super) fn forget_for_restart(&mut self, kind: Restart) {
        if matches!(kind, Restart::Reboot | Restart::Gap) {
            self.attitude = None;
            self.local = None;
            self.gps_accuracy = None;
        }
        if kind == Restart::Reboot {
            self.origin = OriginSend::default();
            self.unix_minus_boot.reset();
            self.params.restart_questions();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimator::landed::{LANDED_CONFIRM_S, TAKEOFF_GRACE_S};

    /// What the watch sent over `secs` of IMU at 100 Hz (its absence
    /// worth saying: no origin of ours coming).
    fn watch(ap: &mut AutopilotView, from_s: f64, secs: f64, counters: &Counters) -> Vec<Outbound> {
        watch_saying(ap, from_s, secs, true, counters)
    }

    fn watch_saying(ap: &mut AutopilotView, from_s: f64, secs: f64, warn: bool, counters: &Counters) -> Vec<Outbound> {
        let (tx, mut rx) = mpsc::channel(1024);
        let log = FlightLog::new(None, false);
        let n = (secs * 100.0) as usize;
        for k in 0..n {
            ap.watch_origin(from_s + k as f64 * 0.01, warn, &log, counters, &tx);
        }
        drain(&mut rx)
    }

    /// What has been sent so far.
    fn drain(rx: &mut mpsc::Receiver<Outbound>) -> Vec<Outbound> {
        let mut sent = Vec::new();
        while let Ok(m) = rx.try_recv() {
            sent.push(m);
        }
        sent
    }

    #[test]
    fn a_missing_origin_is_asked_for_and_said_and_an_origin_ends_both() {
        let counters = Counters::default();
        let mut ap = AutopilotView {
            kind: Some(AutopilotKind::ArduPilot),
            ..Default::default()
        };
        let sent = watch(&mut ap, 100.0, 4.9, &counters);
        // Asked for every 2 s; nothing said in the first 5 s.
        let asks = sent
            .iter()
            .filter(|m| matches!(m, Outbound::RequestMessage { message_id: 49 }))
            .count();
        assert_eq!(asks, 3, "{sent:?}");
        assert!(!sent.iter().any(|m| matches!(m, Outbound::StatusText { .. })));
        // At 5 s it is said, once, then again only after 30 s.
        let sent = watch(&mut ap, 104.9, 30.0, &counters);
        let said: Vec<_> = sent
            .iter()
            .filter_map(|m| match m {
                Outbound::StatusText { text, severity } => Some((text.clone(), *severity)),
                _ => None,
            })
            .collect();
        assert_eq!(said.len(), 1, "{said:?}");
        assert!(said[0].0.contains("no EKF origin") && said[0].1 == 4, "{said:?}");
        assert_eq!(counters.get(Counter::AutopilotOriginMissing), 1);
        let sent = watch(&mut ap, 134.9, 1.0, &counters);
        assert!(sent.iter().any(|m| matches!(m, Outbound::StatusText { .. })));
        assert_eq!(counters.get(Counter::AutopilotOriginMissing), 2);

        // The autopilot's origin: no more asking, nothing more said.
        let mut gnss = GnssIn::new(&crate::config::Config::default());
        let log = FlightLog::new(None, false);
        ap.on_message(
            FusionMsg::Origin {
                lat_deg: -35.36,
                lon_deg: 149.16,
                alt_m: 584.0,
            },
            136.0,
            &mut gnss,
            &log,
            &counters,
        );
        assert!(gnss.frame().is_some());
        assert!(watch(&mut ap, 136.0, 60.0, &counters).is_empty());
    }

    /// The landed state turning to "in the air" after `LANDED_CONFIRM_S` on
    /// the ground leaves zero-velocity updates allowed for
    /// `TAKEOFF_GRACE_S` (the spin-up on the ground) or until the camera
    /// sees motion, then not; landing again allows them at once. A
    /// disarmed vehicle's "on the ground" stays the autopilot's word alone.
    #[test]
    fn zero_velocity_updates_outlast_the_land_detector_by_the_take_off_grace() {
        let counters = Counters::default();
        let mut gnss = GnssIn::new(&crate::config::Config::default());
        let log = FlightLog::new(None, false);
        let mut ap = AutopilotView::default();
        let mut state = |ap: &mut AutopilotView, t_s: f64, armed: bool, on_ground: bool| {
            ap.on_message(
                FusionMsg::VehicleState {
                    armed: Some(armed),
                    on_ground: Some(on_ground),
                    kind: Some(AutopilotKind::Px4),
                    mode: None,
                },
                t_s,
                &mut gnss,
                &log,
                &counters,
            );
        };
        // Never on the ground by its word: no grace (no landing to leave).
        state(&mut ap, 1.0, true, false);
        assert!(!ap.zupt_allowed(1.5));
        state(&mut ap, 2.0, false, true);
        assert!(ap.zupt_allowed(2.0) && ap.disarmed_on_ground());
        state(&mut ap, 10.0, true, true);
        assert!(ap.zupt_allowed(10.5) && !ap.disarmed_on_ground());
        state(&mut ap, 12.0, true, false);
        assert!(ap.zupt_allowed(12.0) && ap.zupt_allowed(12.0 + TAKEOFF_GRACE_S - 0.01));
        assert!(!ap.zupt_allowed(12.0 + TAKEOFF_GRACE_S));
        // A time before the turn (an IMU sample stamped earlier) is not in it.
        assert!(!ap.zupt_allowed(11.9));
        // The same state repeated does not restart the grace.
        state(&mut ap, 20.0, true, false);
        assert!(!ap.zupt_allowed(20.5));
        state(&mut ap, 40.0, true, true);
        assert!(ap.zupt_allowed(40.0));
        // A second on the ground (a touch-and-go, ground effect's flicker, a
        // stale copy) opens no grace.
        state(&mut ap, 41.0, true, false);
        assert!(!ap.zupt_allowed(41.5));
        // After LANDED_CONFIRM_S on the ground it does, until the camera
        // sees motion, which ends it for good.
        state(&mut ap, 42.0, true, true);
        let t0 = 42.0 + LANDED_CONFIRM_S;
        state(&mut ap, t0, true, false);
        assert!(ap.zupt_allowed(t0 + 0.1));
        assert!(ap.camera_moved(t0 + 0.3));
        assert!(!ap.zupt_allowed(t0 + 0.4) && !ap.camera_moved(t0 + 0.4));
        // On the ground by its word, motion changes nothing.
        state(&mut ap, 60.0, true, true);
        assert!(!ap.camera_moved(60.5) && ap.zupt_allowed(60.5));
    }

    #[test]
    fn an_autopilot_with_its_own_gnss_is_asked_but_not_warned() {
        let counters = Counters::default();
        let mut ap = AutopilotView {
            kind: Some(AutopilotKind::ArduPilot),
            gps_accuracy: Some((2.0, 3.0)),
            ..Default::default()
        };
        let sent = watch(&mut ap, 0.0, 20.0, &counters);
        assert!(sent.iter().any(|m| matches!(m, Outbound::RequestMessage { .. })));
        assert!(!sent.iter().any(|m| matches!(m, Outbound::StatusText { .. })));
        assert_eq!(counters.get(Counter::AutopilotOriginMissing), 0);
    }

    #[test]
    fn px4_and_an_origin_of_ours_coming_are_asked_but_not_warned() {
        let counters = Counters::default();
        let mut px4 = AutopilotView {
            kind: Some(AutopilotKind::Px4),
            ..Default::default()
        };
        let sent = watch(&mut px4, 0.0, 20.0, &counters);
        assert!(sent.iter().any(|m| matches!(m, Outbound::RequestMessage { .. })));
        assert!(!sent.iter().any(|m| matches!(m, Outbound::StatusText { .. })));
        let mut ap = AutopilotView {
            kind: Some(AutopilotKind::ArduPilot),
            ..Default::default()
        };
        let sent = watch_saying(&mut ap, 0.0, 20.0, false, &counters);
        assert!(!sent.iter().any(|m| matches!(m, Outbound::StatusText { .. })));
        assert_eq!(counters.get(Counter::AutopilotOriginMissing), 0);
    }

    /// Our origin over `secs` of IMU at 100 Hz.
    fn send(ap: &mut AutopilotView, secs: f64, counters: &Counters) -> Vec<Outbound> {
        let (tx, mut rx) = mpsc::channel(1024);
        let log = FlightLog::new(None, false);
        let frame = NedFrame::from_llh_deg(47.3977432, 8.5455942, 537.0);
        for k in 0..(secs * 100.0) as usize {
            ap.send_origin(k as f64 * 0.01, Some(frame), &log, counters, &tx);
        }
        drain(&mut rx)
    }

    /// The autopilot reboots (its clock restarts): its navigation
    /// parameters are asked for again at once, not when the new clock
    /// reaches the round due on the old one, and the heading is not taken
    /// as ours alone until they have come again (a reboot is when a
    /// parameter set since takes effect).
    #[test]
    fn navigation_parameters_are_asked_again_after_a_reboot() {
        let counters = Counters::default();
        let log = FlightLog::new(None, false);
        let (tx, mut rx) = mpsc::channel(1024);
        let asked = |rx: &mut mpsc::Receiver<Outbound>| {
            drain(rx)
                .iter()
                .filter(|m| matches!(m, Outbound::ParamRequestRead { .. }))
                .count()
        };
        let mut ap = AutopilotView {
            kind: Some(AutopilotKind::Px4),
            ..Default::default()
        };
        ap.params.set_kind(AutopilotKind::Px4);
        // Up 600 s: the first round asks for all eight, none answers yet.
        ap.poll_params(600.0, &log, &counters, &tx);
        assert_eq!(asked(&mut rx), 8);
        // It reboots in the middle of the rounds: its clock starts again.
        ap.forget_for_restart(Restart::Reboot);
        ap.poll_params(1.0, &log, &counters, &tx);
        assert_eq!(asked(&mut rx), 8, "asked again on the new clock");
        // All eight come, as PX4 sends them: the heading is ours alone.
        for (name, v) in [
            ("EKF2_EV_CTRL", 15),
            ("EKF2_GPS_CTRL", 0),
            ("EKF2_MAG_TYPE", 5),
            ("EKF2_HGT_REF", 3),
            ("EKF2_EV_NOISE_MD", 0),
            ("EKF2_EV_DELAY", 0),
            ("EKF2_RNG_CTRL", 0),
            ("EKF2_BARO_CTRL", 0),
        ] {
            let p = crate::io::messages::ParamValue {
                name: name.into(),
                raw: f32::from_bits(v as u32),
                param_type: 6,
            };
            ap.on_param(&p, 1.5, &log, &counters, &tx);
        }
        assert_eq!(ap.heading_ours_alone(), Some(true));
        // Another reboot: not known until they come again, and asked for.
        ap.forget_for_restart(Restart::Reboot);
        assert_eq!(ap.heading_ours_alone(), None);
        ap.poll_params(0.5, &log, &counters, &tx);
        assert_eq!(asked(&mut rx), 8);
        // An IMU gap is no reboot: nothing asked, the verdict kept.
        ap.forget_for_restart(Restart::Gap);
        ap.poll_params(0.6, &log, &counters, &tx);
        assert_eq!(asked(&mut rx), 0);
    }

    #[test]
    fn our_origin_waits_for_the_autopilots_kind_and_is_never_sent_to_px4() {
        let is_origin = |m: &Outbound| matches!(m, Outbound::SetGpsGlobalOrigin { .. });
        let counters = Counters::default();
        let mut unheard = AutopilotView::default();
        assert!(send(&mut unheard, 5.0, &counters).is_empty());
        let mut ardupilot = AutopilotView {
            kind: Some(AutopilotKind::ArduPilot),
            ..Default::default()
        };
        // Until it reports it back: every ORIGIN_RESEND_S.
        assert_eq!(
            send(&mut ardupilot, 5.0, &counters)
                .iter()
                .filter(|m| is_origin(m))
                .count(),
            3
        );
        let mut px4 = AutopilotView {
            kind: Some(AutopilotKind::Px4),
            ..Default::default()
        };
        assert!(!send(&mut px4, 5.0, &counters).iter().any(is_origin));
        assert_eq!(counters.get(Counter::GpsOriginWithheld), 1);
    }

    /// GPS_GLOBAL_ORIGIN at `frame`'s origin.
    fn origin_of(frame: &NedFrame) -> FusionMsg {
        let (lat, lon, h) = ecef_to_llh(&frame.origin_ecef);
        let (lat_deg, lon_deg) = (lat.to_degrees(), lon.to_degrees());
        FusionMsg::Origin {
            lat_deg,
            lon_deg,
            alt_m: geoid::msl_from_ellipsoid(lat_deg, lon_deg, h),
        }
    }

    #[test]
    fn only_an_autopilot_with_a_fix_and_an_origin_of_its_own_has_a_position() {
        let counters = Counters::default();
        let log = FlightLog::new(None, false);
        let (tx, _rx) = mpsc::channel(1024);
        let frame = NedFrame::from_llh_deg(47.3977432, 8.5455942, 537.0);
        for sent_ours_first in [false, true] {
            let mut ap = AutopilotView {
                kind: Some(AutopilotKind::ArduPilot),
                ..Default::default()
            };
            let mut gnss = GnssIn::new(&crate::config::Config::default());
            gnss.set_frame(frame);
            if sent_ours_first {
                ap.send_origin(0.0, Some(frame), &log, &counters, &tx);
            }
            let fix = FusionMsg::GpsAccuracy {
                h_acc_m: 0.9,
                v_acc_m: 1.8,
            };
            ap.on_message(fix, 1.0, &mut gnss, &log, &counters);
            // A fix without an origin: an EKF that does not fuse it.
            assert!(!ap.has_own_position(1.5));
            let origin = origin_of(&frame);
            ap.on_message(origin, 1.0, &mut gnss, &log, &counters);
            // Its own origin (the same place): its fix places it.
            assert_eq!(ap.has_own_position(1.5), !sent_ours_first);
        }
        // PX4, heard before its own origin came: ours withheld, then its
        // origin, 50 m away (its GNSS's), and its fix: its own position.
        let mut px4 = AutopilotView {
            kind: Some(AutopilotKind::Px4),
            ..Default::default()
        };
        let mut gnss = GnssIn::new(&crate::config::Config::default());
        gnss.set_frame(frame);
        px4.send_origin(0.0, Some(frame), &log, &counters, &tx);
        let fix = FusionMsg::GpsAccuracy {
            h_acc_m: 0.9,
            v_acc_m: 1.8,
        };
        px4.on_message(fix, 1.0, &mut gnss, &log, &counters);
        let elsewhere = NedFrame::from_llh_deg(47.3982, 8.5456, 537.0);
        px4.on_message(origin_of(&elsewhere), 1.0, &mut gnss, &log, &counters);
        assert!(px4.has_own_position(1.5));
    }
}
