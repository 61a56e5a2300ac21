//! What the autopilot tells us about itself (its attitude, local position,
//! GNSS accuracy, clock, EKF origin) and the link's state, kept for the
//! filter's start and GNSS time and logged for replay; and the one thing we
//! tell it back besides estimates, our origin.

use cmsckf_models::geodesy::{ecef_to_llh, NedFrame};
use cmsckf_models::geoid;
use serde_json::json;
use tokio::sync::mpsc;

use super::fusion::Fusion;
use super::FusionMsg;
use crate::io::mcap_log::Topic;
use crate::io::messages::Outbound;
use crate::io::Counters;

impl Fusion {
    /// The autopilot's attitude, local position, clock and origin: kept for
    /// initialisation and GNSS time, and logged for replay.
    pub(super) fn on_autopilot(&mut self, msg: FusionMsg, counters: &Counters) {
        match msg {
            FusionMsg::Attitude { roll, pitch, yaw } => {
                self.log(
                    Topic::InputAutopilot,
                    self.last_imu_t,
                    &json!({"attitude_rad": [roll, pitch, yaw]}),
                );
                self.attitude = Some((roll, pitch, yaw))
            }
            FusionMsg::LocalPosition {
                t_s,
                p_ned_m,
                v_ned_mps,
            } => {
                self.log(
                    Topic::InputAutopilot,
                    self.last_imu_t,
                    &json!({"local_position": {"t_s": t_s, "p_ned_m": p_ned_m.as_slice(), "v_ned_mps": v_ned_mps.as_slice()}}),
                );
                self.local = Some((p_ned_m, v_ned_mps, t_s))
            }
            FusionMsg::GpsAccuracy { h_acc_m, v_acc_m } => {
                // Logged for replay, kept as the prior of an in-flight start.
                self.log(
                    Topic::InputAutopilot,
                    self.last_imu_t,
                    &json!({"gps_accuracy_m": [h_acc_m, v_acc_m]}),
                );
                self.gps_accuracy = (h_acc_m.is_finite() && v_acc_m.is_finite()).then_some((h_acc_m, v_acc_m));
            }
            FusionMsg::SystemTime { unix_us, boot_ms } => {
                self.log(
                    Topic::InputSystemTime,
                    boot_ms as f64 * 1e-3,
                    &json!({"unix_us": unix_us, "boot_ms": boot_ms}),
                );
                match self
                    .unix_minus_boot
                    .offer(unix_us as f64 * 1e-6 - boot_ms as f64 * 1e-3)
                {
                    Some(offset_s) => self.gnss.unix_minus_boot_s = Some(offset_s),
                    None => {
                        counters.add("system_time_outlier", 1);
                        tracing::warn!(reason = "system_time_outlier", unix_us, boot_ms, "SYSTEM_TIME rejected");
                    }
                }
            }
            FusionMsg::Origin {
                lat_deg,
                lon_deg,
                alt_m,
            } => {
                self.log(
                    Topic::InputAutopilot,
                    self.last_imu_t,
                    &json!({"origin": [lat_deg, lon_deg, alt_m]}),
                );
                if self.gnss.frame.is_none() {
                    // MAVLink gives the origin's altitude above mean sea
                    // level; our frame is on the ellipsoid (EGM96, §geoid).
                    let h_m = geoid::ellipsoid_from_msl(lat_deg, lon_deg, alt_m);
                    self.gnss.frame = Some(NedFrame::from_llh_deg(lat_deg, lon_deg, h_m));
                    counters.add("gnss_origin_from_autopilot", 1);
                }
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

    /// Tells the autopilot our origin once it is known (`output.set_gps_origin`).
    pub(super) fn send_origin_once(&mut self, counters: &Counters, out: &mpsc::Sender<Outbound>) {
        if !self.cfg.output.set_gps_origin || self.origin_sent {
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
                self.origin_sent = true;
                counters.add("gps_origin_sent", 1);
            }
        }
    }
}
