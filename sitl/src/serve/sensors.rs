//! The autopilot's own MAVLink streams: HEARTBEAT (armed), SYSTEM_TIME,
//! GPS_GLOBAL_ORIGIN and GPS_RAW_INT at 1 Hz, EXTENDED_SYS_STATE (its land
//! detector: on the ground or in the air, `Dataset::landed_at`), ATTITUDE and
//! LOCAL_POSITION_NED (its EKF's view, with that EKF's errors: see
//! [`super::autopilot`]), EKF_STATUS_REPORT (that EKF's test ratios of our
//! estimates), SIM_STATE (the truth, as ArduPilot's SITL sends it, for
//! review) and SCALED_PRESSURE (its barometer, [`crate::barometer`]) at 10 Hz, and HIGHRES_IMU at the IMU rate, with
//! the IMU faults applied. GPS_RAW_INT says the autopilot has a 3D fix of
//! its own (none during a GNSS outage), with its accuracy unknown (0), so
//! the daemon knows the autopilot's position is not only the echo of its
//! own and takes its configured prior for it
//! (`init.sigma_position_autopilot_m`, 3 m, above the EKF's errors here).

use std::time::Instant;

use mavlink::dialects::ardupilotmega as apm;

use super::autopilot::VpeSample;
use super::fault::{imu_order, Active, FaultKind};
use super::stream::Streamer;
use crate::config::GnssSimConfig;
use crate::imu::ImuSample;
use crate::trajectory::TruthSample;
use cmsckf_models::geodesy::{ecef_to_llh, NedFrame};
use cmsckf_models::gnss::{GPS_EPOCH_UNIX_S, GPS_UTC_LEAP_S};

impl Streamer<'_> {
    /// The 1 Hz messages at flight time `t`, and every 30 s the broadcast
    /// ephemerides.
    pub(super) async fn send_1hz(&mut self, t: f64, active: &Active<'_>) {
        self.next_1hz += 1.0;
        self.send(heartbeat()).await;
        let g = &self.ds.cfg.gnss;
        self.send(system_time(g, t, self.boot(t))).await;
        self.send(gps_global_origin(g, self.boot(t))).await;
        let fix = !active.has(FaultKind::GnssOutage);
        self.send(apm::MavMessage::GPS_RAW_INT(apm::GPS_RAW_INT_DATA {
            time_usec: self.boot(t),
            fix_type: if fix {
                apm::GpsFixType::GPS_FIX_TYPE_3D_FIX
            } else {
                apm::GpsFixType::GPS_FIX_TYPE_NO_FIX
            },
            satellites_visible: if fix { 12 } else { 0 },
            ..Default::default()
        }))
        .await;
        // Broadcast ephemerides every 30 s, as receivers repeat them; every
        // 5 s from a receiver on its own port, whose reader may connect
        // after the first ones went out.
        let every = if self.receiver_port.is_some() { 5 } else { 30 };
        if (t as u64).is_multiple_of(every) {
            self.send_ephemerides().await;
        }
    }

    /// The 10 Hz attitude and position at flight time `t`: the EKF's.
    pub(super) async fn send_10hz(&mut self, t: f64, active: &Active<'_>) {
        self.next_slow += 0.1;
        self.step_ekf(t, active);
        let s = self.ds.trajectory.sample(t);
        let (r, p, y) = self.ekf.attitude(&s.q_W_B);
        let (p_B_in_W, v_B_in_W) = self.ekf.local_position(&s);
        let ms = (self.boot(t) / 1000) as u32;
        // Its land detector's verdict, as ArduPilot and PX4 stream it: "in
        // the air" while the motors spin up, before the vehicle rises.
        self.send(apm::MavMessage::EXTENDED_SYS_STATE(apm::EXTENDED_SYS_STATE_DATA {
            vtol_state: apm::MavVtolState::MAV_VTOL_STATE_UNDEFINED,
            landed_state: if self.ds.landed_at(t) {
                apm::MavLandedState::MAV_LANDED_STATE_ON_GROUND
            } else {
                apm::MavLandedState::MAV_LANDED_STATE_IN_AIR
            },
        }))
        .await;
        self.send(apm::MavMessage::ATTITUDE(apm::ATTITUDE_DATA {
            time_boot_ms: ms,
            roll: r as f32,
            pitch: p as f32,
            yaw: y as f32,
            rollspeed: s.w_B.x as f32,
            pitchspeed: s.w_B.y as f32,
            yawspeed: s.w_B.z as f32,
        }))
        .await;
        self.send(apm::MavMessage::LOCAL_POSITION_NED(apm::LOCAL_POSITION_NED_DATA {
            time_boot_ms: ms,
            x: p_B_in_W.x as f32,
            y: p_B_in_W.y as f32,
            z: p_B_in_W.z as f32,
            vx: v_B_in_W.x as f32,
            vy: v_B_in_W.y as f32,
            vz: v_B_in_W.z as f32,
        }))
        .await;
        // The truth's place, once for the two messages that carry it.
        let llh = truth_llh(&self.ds.cfg.gnss, &s);
        self.send(sim_state(&s, llh)).await;
        let step_m = if active.has(FaultKind::BaroStep) {
            super::fault::BARO_STEP_M
        } else {
            0.0
        };
        let p_pa = self.baro.read_pa(t, llh.2 + step_m);
        self.send(apm::MavMessage::SCALED_PRESSURE(apm::SCALED_PRESSURE_DATA {
            time_boot_ms: ms,
            press_abs: (p_pa * 0.01) as f32,
            press_diff: 0.0,
            temperature: 2_000,
            ..Default::default()
        }))
        .await;
        // As ArduPilot's EKF_STATUS_REPORT: the square roots of the position
        // test ratios of the estimates it tested (0 when none were).
        let (h, v) = self.ekf.take_ratios().unwrap_or((0.0, 0.0));
        self.send(apm::MavMessage::EKF_STATUS_REPORT(apm::EKF_STATUS_REPORT_DATA {
            velocity_variance: 0.0,
            pos_horiz_variance: h as f32,
            pos_vert_variance: v as f32,
            compass_variance: 0.0,
            terrain_alt_variance: 0.0,
            flags: apm::EkfStatusFlags::EKF_ATTITUDE
                | apm::EkfStatusFlags::EKF_VELOCITY_HORIZ
                | apm::EkfStatusFlags::EKF_VELOCITY_VERT
                | apm::EkfStatusFlags::EKF_POS_HORIZ_REL
                | apm::EkfStatusFlags::EKF_POS_HORIZ_ABS
                | apm::EkfStatusFlags::EKF_POS_VERT_ABS,
            ..Default::default()
        }))
        .await;
    }

    /// One step of the autopilot's EKF at flight time `t`: its errors move
    /// on (walking freely while the GNSS is out), then it fuses the daemon's
    /// estimates received since the last step, each against the truth at
    /// its own time.
    pub(super) fn step_ekf(&mut self, t: f64, active: &Active<'_>) {
        self.ekf.advance(t, active.has(FaultKind::GnssOutage));
        let new: Vec<(u64, VpeSample)> = match self.inbox.received.lock() {
            Ok(v) => v
                .iter()
                .skip(self.estimates_seen)
                .map(|r| {
                    // As ArduPilot reduces it: one sigma for every axis.
                    let pos_err_m = r.ardupilot_position_sigma_m();
                    let var_m2 = nalgebra::Vector3::repeat(pos_err_m * pos_err_m);
                    (
                        r.t_us,
                        VpeSample {
                            t_s: f64::NAN,
                            p_B_in_W: r.p,
                            var_m2,
                            reset_counter: r.reset_counter,
                        },
                    )
                })
                .collect(),
            Err(_) => Vec::new(),
        };
        self.estimates_seen += new.len();
        for (t_us, mut v) in new {
            v.t_s = self.vpe_clock.flight_s(t_us);
            let p_true = self.ds.trajectory.sample(v.t_s).p_B_in_W;
            self.ekf.fuse(&v, &p_true);
        }
    }

    /// The next IMU sample (or, duplicated and reordered, the next two),
    /// with the IMU faults in force; stamps the wall time of first sending.
    pub(super) async fn send_imu(&mut self, active: &Active<'_>) {
        if active.has(FaultKind::ImuGap) {
            self.k_imu += 1;
            return;
        }
        let nan = active.has(FaultKind::NanImu);
        let spike = if active.has(FaultKind::ImuSpike) { 50.0 } else { 0.0 };
        let k_imu = self.k_imu;
        let order = imu_order(active.copies(), k_imu + 1 < self.ds.imu.len());
        for &j in order {
            let k = k_imu + j;
            self.send(highres_imu(
                &self.ds.imu[k],
                k,
                self.boot(self.ds.imu[k].t_s),
                nan,
                spike,
            ))
            .await;
            if !nan && self.sent_wall[k].is_none() {
                self.sent_wall[k] = Some(Instant::now());
            }
        }
        self.k_imu += order.iter().max().map_or(1, |m| m + 1);
    }
}

/// The autopilot's heartbeat: an active ArduPilot quadrotor, armed (its
/// motors run from the start: the simulated IMU vibrates throughout).
fn heartbeat() -> apm::MavMessage {
    apm::MavMessage::HEARTBEAT(apm::HEARTBEAT_DATA {
        custom_mode: 0,
        mavtype: apm::MavType::MAV_TYPE_QUADROTOR,
        autopilot: apm::MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
        base_mode: apm::MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | apm::MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED,
        system_status: apm::MavState::MAV_STATE_ACTIVE,
        mavlink_version: 3,
    })
}

/// UTC (from the GNSS start time of `g`) and boot time at flight time `t`.
fn system_time(g: &GnssSimConfig, t: f64, boot_us: u64) -> apm::MavMessage {
    let unix_s = GPS_EPOCH_UNIX_S + g.start_week as f64 * 604_800.0 + g.start_tow_s + t - GPS_UTC_LEAP_S;
    apm::MavMessage::SYSTEM_TIME(apm::SYSTEM_TIME_DATA {
        time_unix_usec: (unix_s * 1e6).round() as u64,
        time_boot_ms: (boot_us / 1000) as u32,
    })
}

/// The EKF origin: the simulation's geodetic origin, its altitude above
/// mean sea level as MAVLink defines it (the simulation's is above the
/// ellipsoid; EGM96 between them).
#[allow(deprecated)]
fn gps_global_origin(g: &GnssSimConfig, boot_us: u64) -> apm::MavMessage {
    let o = g.origin_llh;
    let alt_msl_m = cmsckf_models::geoid::msl_from_ellipsoid(o[0], o[1], o[2]);
    apm::MavMessage::GPS_GLOBAL_ORIGIN(apm::GPS_GLOBAL_ORIGIN_DATA {
        latitude: (o[0] * 1e7).round() as i32,
        longitude: (o[1] * 1e7).round() as i32,
        altitude: (alt_msl_m * 1e3).round() as i32,
        time_usec: boot_us,
    })
}

/// The truth's latitude, longitude (deg) and height above mean sea level
/// (m).
fn truth_llh(g: &GnssSimConfig, s: &TruthSample) -> (f64, f64, f64) {
    let o = g.origin_llh;
    let frame = NedFrame::from_llh_deg(o[0], o[1], o[2]);
    let (lat, lon, h) = ecef_to_llh(&(frame.origin_ecef + frame.R_ecef_ned * s.p_B_in_W));
    let (lat_deg, lon_deg) = (lat.to_degrees(), lon.to_degrees());
    (
        lat_deg,
        lon_deg,
        cmsckf_models::geoid::msl_from_ellipsoid(lat_deg, lon_deg, h),
    )
}

/// The truth as `SIM_STATE`, as ArduPilot's SITL sends it: for review
/// only (the daemon logs it and never fuses it), at `llh` ([`truth_llh`]).
/// Latitude and longitude in the MAVLink 2 extensions `lat_int`/`lon_int`
/// (degE7) as well as the f32 degrees; the altitude above mean sea level.
fn sim_state(s: &TruthSample, (lat_deg, lon_deg, alt_msl_m): (f64, f64, f64)) -> apm::MavMessage {
    let q = s.q_W_B;
    let (roll, pitch, yaw) = q.euler_angles();
    apm::MavMessage::SIM_STATE(apm::SIM_STATE_DATA {
        q1: q.w as f32,
        q2: q.i as f32,
        q3: q.j as f32,
        q4: q.k as f32,
        roll: roll as f32,
        pitch: pitch as f32,
        yaw: yaw as f32,
        xgyro: s.w_B.x as f32,
        ygyro: s.w_B.y as f32,
        zgyro: s.w_B.z as f32,
        lat: lat_deg as f32,
        lon: lon_deg as f32,
        alt: alt_msl_m as f32,
        vn: s.v_B_in_W.x as f32,
        ve: s.v_B_in_W.y as f32,
        vd: s.v_B_in_W.z as f32,
        lat_int: (lat_deg * 1e7).round() as i32,
        lon_int: (lon_deg * 1e7).round() as i32,
        ..Default::default()
    })
}

/// IMU sample `m` (index `k`) stamped `time_usec`; with `nan`, its x
/// acceleration is NaN (even `k`) or 1e5 m/s² (odd `k`), else `spike` is
/// added to it.
fn highres_imu(m: &ImuSample, k: usize, time_usec: u64, nan: bool, spike: f64) -> apm::MavMessage {
    let bad = if k.is_multiple_of(2) { f32::NAN } else { 1e5 };
    apm::MavMessage::HIGHRES_IMU(apm::HIGHRES_IMU_DATA {
        time_usec,
        xacc: if nan { bad } else { (m.accel_mps2.x + spike) as f32 },
        yacc: m.accel_mps2.y as f32,
        zacc: m.accel_mps2.z as f32,
        xgyro: m.gyro_radps.x as f32,
        ygyro: m.gyro_radps.y as f32,
        zgyro: m.gyro_radps.z as f32,
        fields_updated: apm::HighresImuUpdatedFlags::from_bits_truncate(0x3f),
        ..Default::default()
    })
}
