//! What the autopilot tells us about itself (its attitude, local position,
//! magnetometer, GNSS accuracy, clock, EKF origin) and the link's state,
//! kept for the filter's start and GNSS time and logged for replay; and the
//! one thing we tell it back besides estimates, our origin, until it
//! reports it back.

use cmsckf_models::geodesy::{ecef_to_llh, llh_to_ecef, NedFrame};
use cmsckf_models::geoid;
use tokio::sync::mpsc;

use super::fusion::Fusion;
use super::FusionMsg;
use crate::counters::{Counter, Counters};
use crate::io::mcap_log::input::{AutopilotRecord, InputRecord, LocalPositionRecord, SimStateRecord, SystemTimeRecord};
use crate::io::messages::Outbound;

/// Magnetometer readings kept for the compass yaw (10 Hz: about 1 s).
pub(super) const MAG_READINGS: usize = 10;
/// The origin is sent again this often until the autopilot reports it (s
/// of autopilot time), at most [`ORIGIN_TRIES`] times.
const ORIGIN_RESEND_S: f64 = 2.0;
const ORIGIN_TRIES: u32 = 30;
/// The autopilot's origin is ours when within this (m).
const ORIGIN_MATCH_M: f64 = 1.0;

/// Sending our origin: a UDP autopilot is only heard after its first
/// HEARTBEAT, and a message can be lost, so it is sent until the
/// autopilot's `GPS_GLOBAL_ORIGIN` comes back.
#[derive(Debug, Default)]
pub(super) struct OriginSend {
    /// The autopilot reported an origin (ours, or its own).
    pub(super) settled: bool,
    next_t_s: f64,
    tries: u32,
}

impl Fusion {
    /// The autopilot's attitude, local position, clock and origin: kept for
    /// initialisation and GNSS time, and logged for replay.
    pub(super) fn on_autopilot(&mut self, msg: FusionMsg, counters: &Counters) {
        match msg {
            FusionMsg::Attitude { roll, pitch, yaw } => {
                self.log_autopilot(AutopilotRecord::Attitude([roll, pitch, yaw]));
                self.attitude = Some((roll, pitch, yaw))
            }
            FusionMsg::LocalPosition {
                t_s,
                p_ned_m,
                v_ned_mps,
            } => {
                self.log_autopilot(AutopilotRecord::LocalPosition(LocalPositionRecord {
                    t_s,
                    p_ned_m: p_ned_m.into(),
                    v_ned_mps: v_ned_mps.into(),
                }));
                self.local = Some((p_ned_m, v_ned_mps, t_s))
            }
            FusionMsg::Magnetometer { mag_B } => {
                self.log_autopilot(AutopilotRecord::Magnetometer(mag_B.into()));
                if self.mag_B.len() == MAG_READINGS {
                    self.mag_B.pop_front();
                }
                self.mag_B.push_back(mag_B);
            }
            FusionMsg::VehicleState { armed, on_ground, kind } => {
                if let Some(k) = kind.filter(|k| Some(*k) != self.autopilot_kind) {
                    self.log_autopilot(AutopilotRecord::Autopilot(k));
                    self.autopilot_kind = kind;
                }
                // Logged on change only (the HEARTBEAT comes every second).
                if let Some(a) = armed.filter(|a| Some(*a) != self.armed) {
                    self.log_autopilot(AutopilotRecord::Armed(a));
                    self.armed = armed;
                }
                if let Some(g) = on_ground.filter(|g| Some(*g) != self.on_ground) {
                    self.log_autopilot(AutopilotRecord::OnGround(g));
                    self.on_ground = on_ground;
                }
            }
            FusionMsg::Date { unix_days } => {
                self.log_autopilot(AutopilotRecord::UnixDays(unix_days));
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
                let p_ned_m = self.gnss.frame.map(|f| {
                    let h_m = geoid::ellipsoid_from_msl(lat_deg, lon_deg, alt_m);
                    let r = llh_to_ecef(lat_deg.to_radians(), lon_deg.to_radians(), h_m);
                    let p = f.R_ecef_ned.transpose() * (r - f.origin_ecef);
                    [p.x, p.y, p.z]
                });
                self.log_autopilot(AutopilotRecord::SimState(SimStateRecord {
                    lat_deg,
                    lon_deg,
                    alt_m,
                    q_wxyz,
                    v_ned_mps: v_ned_mps.into(),
                    p_ned_m,
                }));
            }
            FusionMsg::GpsAccuracy { h_acc_m, v_acc_m } => {
                // Logged for replay, kept as the prior of an in-flight start.
                self.log_autopilot(AutopilotRecord::GpsAccuracy(
                    [h_acc_m, v_acc_m].map(|a| a.is_finite().then_some(a)),
                ));
                self.gps_accuracy = (h_acc_m.is_finite() && v_acc_m.is_finite()).then_some((h_acc_m, v_acc_m));
                self.autopilot_fix_t = Some(self.last_imu_t);
            }
            FusionMsg::SystemTime { unix_us, boot_ms } => {
                self.log_input(
                    boot_ms as f64 * 1e-3,
                    &InputRecord::SystemTime(SystemTimeRecord { unix_us, boot_ms }),
                );
                match self
                    .unix_minus_boot
                    .offer(unix_us as f64 * 1e-6 - boot_ms as f64 * 1e-3)
                {
                    Some(offset_s) => self.gnss.unix_minus_boot_s = Some(offset_s),
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
                self.log_autopilot(AutopilotRecord::Origin([lat_deg, lon_deg, alt_m]));
                // MAVLink gives the origin's altitude above mean sea level;
                // our frame is on the ellipsoid (EGM96, §geoid).
                let h_m = geoid::ellipsoid_from_msl(lat_deg, lon_deg, alt_m);
                match self.gnss.frame {
                    None => {
                        self.gnss.frame = Some(NedFrame::from_llh_deg(lat_deg, lon_deg, h_m));
                        counters.add(Counter::GnssOriginFromAutopilot, 1);
                    }
                    Some(ours) if !self.origin.settled => {
                        let theirs = llh_to_ecef(lat_deg.to_radians(), lon_deg.to_radians(), h_m);
                        let off_m = (theirs - ours.origin_ecef).norm();
                        if off_m <= ORIGIN_MATCH_M {
                            counters.add(Counter::GpsOriginConfirmed, 1);
                            self.log_text(2, self.last_imu_t, "the autopilot took our origin");
                        } else {
                            // An autopilot sets its origin once: its GNSS
                            // (or a ground station) came first.
                            counters.add(Counter::GpsOriginMismatch, 1);
                            let text = format!(
                                "the autopilot's EKF origin is {off_m:.1} m from ours: its global positions \
                                 of our estimates will be off by that"
                            );
                            tracing::warn!(reason = "gps_origin_mismatch", off_m, "{text}");
                            self.log_text(3, self.last_imu_t, &text);
                        }
                    }
                    Some(_) => {}
                }
                self.origin.settled = true;
            }
            FusionMsg::LinkState { up, silent_s } => {
                let text = if up {
                    format!("link up: the autopilot is heard again after {silent_s:.1} s")
                } else {
                    format!("link down: the autopilot has been silent for {silent_s:.1} s")
                };
                self.log_text(if up { 3 } else { 4 }, self.last_imu_t, &text);
            }
            _ => {}
        }
    }

    /// What the autopilot said, logged at the last IMU sample's time.
    fn log_autopilot(&self, rec: AutopilotRecord) {
        self.log_input(self.last_imu_t, &InputRecord::Autopilot(rec));
    }

    /// Whether a zero-velocity update may be taken: on the ground, by the
    /// autopilot's landed state, else by its being disarmed; with neither
    /// known (an autopilot that says nothing), by the IMU and camera alone.
    pub(super) fn zupt_allowed(&self) -> bool {
        match (self.on_ground, self.armed) {
            (Some(on_ground), _) => on_ground,
            (None, Some(armed)) => !armed,
            (None, None) => true,
        }
    }

    /// Tells the autopilot our origin once it is known
    /// (`output.set_gps_origin`), again every [`ORIGIN_RESEND_S`] until it
    /// reports an origin back.
    pub(super) fn send_origin(&mut self, t_s: f64, counters: &Counters, out: &mpsc::Sender<Outbound>) {
        if !self.cfg.output.set_gps_origin || self.origin.settled || t_s < self.origin.next_t_s {
            return;
        }
        if self.origin.tries == ORIGIN_TRIES {
            self.origin.settled = true;
            counters.add(Counter::GpsOriginUnconfirmed, 1);
            let text = "the autopilot never reported our origin back (GPS_GLOBAL_ORIGIN)";
            tracing::warn!(reason = "gps_origin_unconfirmed", "{text}");
            self.log_text(3, t_s, text);
            return;
        }
        if let Some(frame) = self.gnss.frame {
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
}
