//! Inbound: MAVLink messages and their scaled integers become [`Inbound`]
//! values in SI units, checked (finite, within any sensor's range) here and
//! only here.

use mavlink::dialects::ardupilotmega as apm;
use nalgebra::Vector3;

use super::LinkError;
use crate::counters::Counter;
use crate::io::messages::{AutopilotKind, ImuMessage, Inbound, SimTruth};

/// Standard gravity used by MAVLink's milli-g units (m/s²).
const G0: f64 = 9.80665;

fn finite3(v: Vector3<f64>) -> Result<Vector3<f64>, LinkError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(v)
    } else {
        Err(LinkError::Rejected(Counter::MavlinkRejectedNonFinite))
    }
}

/// A finite `f32` as `f64`, else the message is rejected as non-finite.
fn finite(x: f32) -> Result<f64, LinkError> {
    if x.is_finite() {
        Ok(x as f64)
    } else {
        Err(LinkError::Rejected(Counter::MavlinkRejectedNonFinite))
    }
}

/// A magnetometer reading, or `None` when the autopilot has none to give
/// (zeros before its compass is ready) or sends something non-finite: a
/// missing field must not stop the IMU sample it came with.
fn field(v: Vector3<f64>) -> Option<Vector3<f64>> {
    (v.iter().all(|x| x.is_finite()) && v.norm() > 0.0).then_some(v)
}

/// Largest believable IMU reading per axis: 1600 m/s² (163 g) and 70 rad/s,
/// twice the widest MEMS ranges (±32 g is not even reached by ±16 g parts,
/// ±4000 °/s ≈ 70 rad/s).
const MAX_ACCEL_MPS2: f64 = 1600.0;
const MAX_GYRO_RADPS: f64 = 70.0;

/// Believable barometric pressure (Pa): 300 hPa is 9 km above sea level,
/// 1100 hPa below the Dead Sea's shore; a margin either side.
const MIN_PRESSURE_PA: f64 = 10_000.0;
const MAX_PRESSURE_PA: f64 = 120_000.0;

/// An IMU sample's accelerometer and gyro, finite and within sensor range.
fn imu_checked(accel: Vector3<f64>, gyro: Vector3<f64>) -> Result<(Vector3<f64>, Vector3<f64>), LinkError> {
    let (a, g) = (finite3(accel)?, finite3(gyro)?);
    if a.amax() > MAX_ACCEL_MPS2 || g.amax() > MAX_GYRO_RADPS {
        return Err(LinkError::Rejected(Counter::MavlinkRejectedImuOutOfRange));
    }
    Ok((a, g))
}

/// Decodes every MAVLink frame in `bytes` as the link would (the crate's
/// framing, then [`decode`]): the input to the adapter's fuzz tests.
pub fn decode_bytes(bytes: &[u8]) -> Vec<Result<Inbound, LinkError>> {
    let mut r = mavlink::MavlinkReader::new(bytes);
    let mut out = Vec::new();
    // Bounded: a frame takes at least 8 bytes.
    for _ in 0..bytes.len() / 8 + 1 {
        match r.read_any_message::<apm::MavMessage>() {
            Ok((_, m)) => out.push(decode(m)),
            Err(mavlink::error::MessageReadError::Io(_)) => break,
            Err(mavlink::error::MessageReadError::Parse(e)) => out.push(Err(LinkError::Parse(e.to_string()))),
        }
    }
    out
}

/// MAVLink message → [`Inbound`], with units converted here and only here.
/// (`GPS_GLOBAL_ORIGIN` is deprecated but still what autopilots send.)
#[allow(deprecated)]
pub(super) fn decode(msg: apm::MavMessage) -> Result<Inbound, LinkError> {
    use apm::MavMessage as M;
    Ok(match msg {
        M::HIGHRES_IMU(d) => {
            let (accel_mps2, gyro_radps) = imu_checked(
                Vector3::new(d.xacc as f64, d.yacc as f64, d.zacc as f64),
                Vector3::new(d.xgyro as f64, d.ygyro as f64, d.zgyro as f64),
            )?;
            // fields_updated bits 6–8: xmag, ymag, zmag.
            let mag = Vector3::new(d.xmag as f64, d.ymag as f64, d.zmag as f64);
            Inbound::Imu {
                t_us: d.time_usec,
                accel_mps2,
                gyro_radps,
                kind: ImuMessage::Highres,
                mag_B: (d.fields_updated.bits() & 0x1C0 == 0x1C0)
                    .then_some(mag)
                    .and_then(field),
            }
        }
        // SCALED_IMU: mG and mrad/s.
        M::SCALED_IMU(d) => Inbound::Imu {
            t_us: d.time_boot_ms as u64 * 1000,
            accel_mps2: Vector3::new(d.xacc as f64, d.yacc as f64, d.zacc as f64) * (G0 / 1000.0),
            gyro_radps: Vector3::new(d.xgyro as f64, d.ygyro as f64, d.zgyro as f64) / 1000.0,
            kind: ImuMessage::Scaled,
            mag_B: field(Vector3::new(d.xmag as f64, d.ymag as f64, d.zmag as f64)),
        },
        // RAW_IMU: ArduPilot fills it with the same mG and mrad/s scaling.
        M::RAW_IMU(d) => Inbound::Imu {
            t_us: d.time_usec,
            accel_mps2: Vector3::new(d.xacc as f64, d.yacc as f64, d.zacc as f64) * (G0 / 1000.0),
            gyro_radps: Vector3::new(d.xgyro as f64, d.ygyro as f64, d.zgyro as f64) / 1000.0,
            kind: ImuMessage::Raw,
            mag_B: field(Vector3::new(d.xmag as f64, d.ymag as f64, d.zmag as f64)),
        },
        M::ATTITUDE(d) => {
            let v = finite3(Vector3::new(d.roll as f64, d.pitch as f64, d.yaw as f64))?;
            Inbound::Attitude {
                t_boot_ms: d.time_boot_ms,
                roll_rad: v.x,
                pitch_rad: v.y,
                yaw_rad: v.z,
            }
        }
        M::LOCAL_POSITION_NED(d) => Inbound::LocalPosition {
            t_boot_ms: d.time_boot_ms,
            p_ned_m: finite3(Vector3::new(d.x as f64, d.y as f64, d.z as f64))?,
            v_ned_mps: finite3(Vector3::new(d.vx as f64, d.vy as f64, d.vz as f64))?,
        },
        // h_acc and v_acc (mm) are MAVLink 2 extensions: 0 = not reported.
        // A 3D fix: the autopilot has a position of its own; its accuracy
        // (0 = unknown: NaN), when given, is the prior of an in-flight start.
        M::GPS_RAW_INT(d) if d.fix_type as u8 >= apm::GpsFixType::GPS_FIX_TYPE_3D_FIX as u8 => Inbound::GpsAccuracy {
            h_acc_m: if d.h_acc > 0 { d.h_acc as f64 * 1e-3 } else { f64::NAN },
            v_acc_m: if d.v_acc > 0 { d.v_acc as f64 * 1e-3 } else { f64::NAN },
        },
        M::GPS_RAW_INT(_) => Inbound::Other("GPS_RAW_INT"),
        M::EKF_STATUS_REPORT(d) => Inbound::EstimatorStatus(crate::io::messages::EstimatorStatus {
            source: crate::io::messages::EstimatorSource::EkfStatusReport,
            vel_ratio: d.velocity_variance.is_finite().then_some(d.velocity_variance as f64),
            pos_horiz_ratio: finite(d.pos_horiz_variance)?,
            pos_vert_ratio: finite(d.pos_vert_variance)?,
            mag_ratio: d.compass_variance.is_finite().then_some(d.compass_variance as f64),
            flags: d.flags.bits(),
        }),
        M::ESTIMATOR_STATUS(d) => Inbound::EstimatorStatus(crate::io::messages::EstimatorStatus {
            source: crate::io::messages::EstimatorSource::EstimatorStatus,
            vel_ratio: d.vel_ratio.is_finite().then_some(d.vel_ratio as f64),
            pos_horiz_ratio: finite(d.pos_horiz_ratio)?,
            pos_vert_ratio: finite(d.pos_vert_ratio)?,
            mag_ratio: d.mag_ratio.is_finite().then_some(d.mag_ratio as f64),
            flags: d.flags.bits(),
        }),
        // The MAVLink 2 extensions lat_int/lon_int (degE7, about 1 cm) when
        // set; the f32 degrees (about 0.3 m) otherwise.
        M::SIM_STATE(d) => {
            let (lat_deg, lon_deg) = if d.lat_int != 0 || d.lon_int != 0 {
                (d.lat_int as f64 * 1e-7, d.lon_int as f64 * 1e-7)
            } else {
                (d.lat as f64, d.lon as f64)
            };
            let q = [d.q1, d.q2, d.q3, d.q4].map(f64::from);
            let ok = lat_deg.abs() <= 90.0
                && lon_deg.abs() <= 180.0
                && (d.alt as f64).is_finite()
                && q.iter().all(|x| x.is_finite());
            if !ok {
                return Err(LinkError::Rejected(Counter::MavlinkRejectedOther));
            }
            Inbound::SimState(SimTruth {
                lat_deg,
                lon_deg,
                alt_m: d.alt as f64,
                q_wxyz: q,
                v_ned_mps: finite3(Vector3::new(d.vn as f64, d.ve as f64, d.vd as f64))?,
            })
        }
        // A parameter's name is ASCII up to its first NUL (16 bytes at most,
        // no NUL when it fills them: `CharArray::to_str` stops there);
        // anything else is no name of ours.
        M::PARAM_VALUE(d) => {
            let name = match d.param_id.to_str() {
                Ok(n) if !n.is_empty() && n.bytes().all(|b| b.is_ascii_graphic()) => n,
                _ => return Err(LinkError::Rejected(Counter::MavlinkRejectedOther)),
            };
            Inbound::ParamValue(crate::io::messages::ParamValue {
                name: name.to_string(),
                raw: d.param_value,
                param_type: d.param_type as u8,
            })
        }
        // hPa and c°C on the wire. PX4 and ArduPilot send this message
        // for their airspeed sensor too, with 0 where no barometer reading
        // is: no reading, not a malformed one.
        M::SCALED_PRESSURE(d) if d.press_abs == 0.0 => Inbound::Other("SCALED_PRESSURE without a barometer reading"),
        M::SCALED_PRESSURE(d) => {
            let p_abs_pa = finite(d.press_abs)? * 100.0;
            if !(MIN_PRESSURE_PA..=MAX_PRESSURE_PA).contains(&p_abs_pa) {
                return Err(LinkError::Rejected(Counter::MavlinkRejectedPressureOutOfRange));
            }
            Inbound::Pressure {
                t_boot_ms: d.time_boot_ms,
                p_abs_pa,
                temperature_c: f64::from(d.temperature) * 0.01,
            }
        }
        M::SYSTEM_TIME(d) => Inbound::SystemTime {
            unix_us: d.time_unix_usec,
            boot_ms: d.time_boot_ms,
        },
        M::TIMESYNC(d) => Inbound::Timesync {
            tc1_ns: d.tc1,
            ts1_ns: d.ts1,
        },
        M::GPS_RTCM_DATA(d) => {
            let len = (d.len as usize).min(d.data.len());
            Inbound::RtcmFragment {
                flags: d.flags,
                data: d.data[..len].to_vec(),
            }
        }
        M::STATUSTEXT(d) => Inbound::AutopilotText {
            severity: d.severity as u8,
            text: String::from_utf8_lossy(d.text.as_slice())
                .trim_end_matches('\0')
                .chars()
                .take(50)
                .collect(),
        },
        M::HEARTBEAT(d) => Inbound::Heartbeat {
            mode: d.custom_mode,
            armed: d.base_mode.contains(apm::MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED),
            kind: match d.autopilot {
                apm::MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA => AutopilotKind::ArduPilot,
                apm::MavAutopilot::MAV_AUTOPILOT_PX4 => AutopilotKind::Px4,
                _ => AutopilotKind::Other,
            },
        },
        M::EXTENDED_SYS_STATE(d) => Inbound::LandedState {
            on_ground: match d.landed_state {
                apm::MavLandedState::MAV_LANDED_STATE_UNDEFINED => None,
                apm::MavLandedState::MAV_LANDED_STATE_ON_GROUND => Some(true),
                _ => Some(false),
            },
        },
        M::GPS_GLOBAL_ORIGIN(d) => Inbound::GpsGlobalOrigin {
            lat_deg: d.latitude as f64 * 1e-7,
            lon_deg: d.longitude as f64 * 1e-7,
            alt_m: d.altitude as f64 * 1e-3,
        },
        M::VISION_POSITION_ESTIMATE(_) => Inbound::Other("VISION_POSITION_ESTIMATE"),
        M::COMMAND_LONG(_) => Inbound::Other("COMMAND_LONG"),
        M::COMMAND_ACK(_) => Inbound::Other("COMMAND_ACK"),
        _ => Inbound::Other("other"),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `SCALED_PRESSURE` in SI units; one that is not a number, or no
    /// barometer's reading (an absurd value), is refused and counted; 0
    /// (the message sent for an airspeed sensor, with no barometer reading)
    /// is no reading, neither taken nor refused.
    #[test]
    fn a_barometer_reading_is_taken_in_pascals_and_a_wrong_one_refused() {
        let m = |press_abs: f32| {
            apm::MavMessage::SCALED_PRESSURE(apm::SCALED_PRESSURE_DATA {
                time_boot_ms: 12_345,
                press_abs,
                press_diff: 0.0,
                temperature: 2_150,
                ..Default::default()
            })
        };
        let Ok(Inbound::Pressure {
            t_boot_ms,
            p_abs_pa,
            temperature_c,
        }) = decode(m(1013.25))
        else {
            panic!("not taken")
        };
        assert_eq!(t_boot_ms, 12_345);
        assert!((p_abs_pa - 101_325.0).abs() < 0.01, "{p_abs_pa}");
        assert!((temperature_c - 21.5).abs() < 1e-12);
        let refused = |x: f32, why: Counter| {
            assert!(
                matches!(decode(m(x)), Err(LinkError::Rejected(c)) if c == why),
                "{x} hPa: {:?}",
                decode(m(x))
            )
        };
        refused(f32::NAN, Counter::MavlinkRejectedNonFinite);
        refused(f32::INFINITY, Counter::MavlinkRejectedNonFinite);
        refused(-1013.0, Counter::MavlinkRejectedPressureOutOfRange);
        refused(50.0, Counter::MavlinkRejectedPressureOutOfRange);
        refused(5_000.0, Counter::MavlinkRejectedPressureOutOfRange);
        assert!(matches!(decode(m(0.0)), Ok(Inbound::Other(_))), "{:?}", decode(m(0.0)));
    }

    /// Red-team 08: a NaN in a field we do not use (the compass ratio) used
    /// to drop an EKF_STATUS_REPORT that said the EKF rejected our position.
    #[test]
    fn an_ekf_report_keeps_its_position_ratios_whatever_its_other_fields() {
        let m = apm::MavMessage::EKF_STATUS_REPORT(apm::EKF_STATUS_REPORT_DATA {
            pos_horiz_variance: 2.0,
            pos_vert_variance: 0.5,
            compass_variance: f32::NAN,
            velocity_variance: f32::INFINITY,
            ..Default::default()
        });
        let Inbound::EstimatorStatus(s) = decode(m).unwrap() else {
            panic!("not kept")
        };
        assert_eq!((s.pos_horiz_ratio, s.pos_vert_ratio), (2.0, 0.5));
        assert_eq!((s.mag_ratio, s.vel_ratio), (None, None));
        // A position ratio that is not a number is refused, counted.
        let m = apm::MavMessage::EKF_STATUS_REPORT(apm::EKF_STATUS_REPORT_DATA {
            pos_horiz_variance: f32::NAN,
            ..Default::default()
        });
        assert!(decode(m).is_err());
    }

    #[test]
    fn scaled_imu_units_are_converted_at_the_boundary() {
        let m = apm::MavMessage::SCALED_IMU(apm::SCALED_IMU_DATA {
            time_boot_ms: 1500,
            xacc: 0,
            yacc: 0,
            zacc: -1000,
            xgyro: 100,
            ygyro: 0,
            zgyro: 0,
            ..Default::default()
        });
        let Inbound::Imu {
            t_us,
            accel_mps2,
            gyro_radps,
            ..
        } = decode(m).unwrap()
        else {
            panic!("not an IMU sample")
        };
        assert_eq!(t_us, 1_500_000);
        assert!((accel_mps2.z + G0).abs() < 1e-12);
        assert!((gyro_radps.x - 0.1).abs() < 1e-12);
        let nan = apm::MavMessage::HIGHRES_IMU(apm::HIGHRES_IMU_DATA {
            xacc: f32::NAN,
            ..Default::default()
        });
        assert!(matches!(
            decode(nan),
            Err(LinkError::Rejected(Counter::MavlinkRejectedNonFinite))
        ));
    }
}
