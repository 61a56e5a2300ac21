//! The MAVLink link to the autopilot: the only file of the `cmsckf` crate
//! that names `mavlink::` types.
//!
//! It converts at the boundary, both ways: MAVLink's messages and scaled
//! integers become [`Inbound`] values in SI units, and [`Outbound`] values
//! become MAVLink messages (those plain types are `io::messages`'s).
//! Transport (UDP, TCP, serial) and framing are the `mavlink` crate's. The
//! crate's reader drops frames with a bad CRC or an unknown id without
//! telling its caller, so the link counts them from the gaps they leave in
//! each sender's sequence numbers.
//!
//! With a signing key (MAVLink 2 message signing), frames are read raw and
//! checked here, so that an unsigned or badly signed one is rejected with
//! its reason and counted (the crate's own check drops them silently), and
//! ours are signed before they are sent.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::Arc;

use mavlink::dialects::ardupilotmega as apm;
use mavlink::{AsyncMavConnection, MavHeader, Message as _};
use nalgebra::Vector3;

use super::messages::{Inbound, Outbound, Source};

/// Standard gravity used by MAVLink's milli-g units (m/s²).
const G0: f64 = 9.80665;

/// Why a receive did not give a message.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    #[error("link I/O: {0}")]
    Io(#[from] std::io::Error),
    #[error("undecodable MAVLink message: {0}")]
    Parse(String),
    #[error("message rejected: {0}")]
    Rejected(&'static str),
}

/// MAVLink 2's "signed" incompatibility flag.
const IFLAG_SIGNED: u8 = 0x01;

/// A connected link.
pub struct Link {
    conn: Arc<mavlink::AsyncConnection<apm::MavMessage>>,
    header: MavHeader,
    target_system: u8,
    target_component: u8,
    last_seq: std::sync::Mutex<BTreeMap<Source, u8>>,
    /// Message signing: key, link id and replay state.
    signing: Option<mavlink::SigningData>,
    /// Our sequence number when we frame (and sign) messages ourselves.
    seq: AtomicU8,
}

impl Link {
    /// Opens the link (`udpin:`, `udpout:`, `tcpout:`, `serial:` …), with
    /// message signing when `signing` gives a key and our link id.
    pub async fn connect(
        address: &str,
        system_id: u8,
        component_id: u8,
        target_system: u8,
        target_component: u8,
        signing: Option<([u8; 32], u8)>,
    ) -> Result<Self, LinkError> {
        let mut conn = mavlink::connect_async::<apm::MavMessage>(address).await?;
        conn.set_protocol_version(mavlink::MavlinkVersion::V2);
        conn.set_allow_recv_any_version(true);
        Ok(Self {
            conn: Arc::new(conn),
            header: MavHeader {
                system_id: system_id as u32,
                component_id,
                sequence: 0,
            },
            target_system,
            target_component,
            last_seq: std::sync::Mutex::new(BTreeMap::new()),
            signing: signing.map(|(key, link_id)| {
                mavlink::SigningData::from_config(mavlink::SigningConfig::new(key, link_id, true, false))
            }),
            seq: AtomicU8::new(0),
        })
    }

    /// The next frame when signing: read raw, its signature checked here.
    async fn recv_signed(&self, sd: &mavlink::SigningData) -> Result<(MavHeader, apm::MavMessage), LinkError> {
        let raw = match self.conn.recv_raw().await {
            Ok(r) => r,
            Err(mavlink::error::MessageReadError::Io(e)) => return Err(LinkError::Io(e)),
            Err(mavlink::error::MessageReadError::Parse(e)) => return Err(LinkError::Parse(e.to_string())),
        };
        let mavlink::MAVLinkMessageRaw::V2(r) = raw else {
            return Err(LinkError::Rejected("unsigned"));
        };
        let h = MavHeader {
            system_id: r.system_id(),
            component_id: r.component_id(),
            sequence: r.sequence(),
        };
        // Its sequence number is seen even if it is rejected, so that a
        // rejection is not counted again as a lost frame.
        self.sequence_gap(&h);
        if r.incompatibility_flags() & IFLAG_SIGNED == 0 {
            return Err(LinkError::Rejected("unsigned"));
        }
        if !sd.verify_signature(&r) {
            return Err(LinkError::Rejected("bad_signature"));
        }
        let msg = apm::MavMessage::parse(mavlink::MavlinkVersion::V2, r.message_id(), r.payload())
            .map_err(|e| LinkError::Parse(e.to_string()))?;
        Ok((h, msg))
    }

    /// Frames lost or dropped since the sender's previous frame, from the
    /// sequence numbers (a large jump is a restarted sender: 0).
    fn sequence_gap(&self, h: &MavHeader) -> u32 {
        let src = Source {
            system: h.system_id,
            component: h.component_id,
        };
        let mut seqs = self.last_seq.lock().unwrap_or_else(|p| p.into_inner());
        let gap = seqs
            .get(&src)
            .map_or(0, |last| h.sequence.wrapping_sub(*last).wrapping_sub(1) as u32);
        seqs.insert(src, h.sequence);
        if gap > 128 {
            0
        } else {
            gap
        }
    }

    /// Receives the next message. Returns, besides the message, how many
    /// frames of that sender were lost or dropped as corrupt since its
    /// previous one (from the sequence numbers).
    pub async fn recv(&self) -> Result<(Source, Inbound, u32), LinkError> {
        if let Some(sd) = &self.signing {
            let (h, msg) = self.recv_signed(sd).await?;
            let src = Source {
                system: h.system_id,
                component: h.component_id,
            };
            return Ok((src, decode(msg)?, 0));
        }
        let (h, msg) = match self.conn.try_recv().await {
            Ok(v) => v,
            Err(mavlink::error::MessageReadError::Io(e)) => return Err(LinkError::Io(e)),
            Err(mavlink::error::MessageReadError::Parse(e)) => return Err(LinkError::Parse(e.to_string())),
        };
        let src = Source {
            system: h.system_id,
            component: h.component_id,
        };
        let gap = self.sequence_gap(&h);
        Ok((src, decode(msg)?, gap))
    }

    /// Sends one message.
    pub async fn send(&self, out: &Outbound) -> Result<(), LinkError> {
        let msg = encode(out, self.target_system, self.target_component);
        let sent = match &self.signing {
            Some(sd) => {
                let mut raw = mavlink::MAVLinkV2MessageRaw::new();
                let header = MavHeader {
                    sequence: self.seq.fetch_add(1, Ordering::Relaxed),
                    ..self.header
                };
                raw.serialize_message_for_signing(header, &msg);
                sd.sign_message(&mut raw);
                self.conn.send_raw(&mavlink::MAVLinkMessageRaw::V2(raw)).await
            }
            None => self.conn.send(&self.header, &msg).await,
        };
        sent.map_err(|e| LinkError::Io(std::io::Error::other(e.to_string())))?;
        Ok(())
    }
}

fn finite3(v: Vector3<f64>) -> Result<Vector3<f64>, LinkError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(v)
    } else {
        Err(LinkError::Rejected("non_finite"))
    }
}

/// Largest believable IMU reading per axis: 1600 m/s² (163 g) and 70 rad/s,
/// twice the widest MEMS ranges (±32 g is not even reached by ±16 g parts,
/// ±4000 °/s ≈ 70 rad/s).
const MAX_ACCEL_MPS2: f64 = 1600.0;
const MAX_GYRO_RADPS: f64 = 70.0;

/// An IMU sample's accelerometer and gyro, finite and within sensor range.
fn imu_checked(accel: Vector3<f64>, gyro: Vector3<f64>) -> Result<(Vector3<f64>, Vector3<f64>), LinkError> {
    let (a, g) = (finite3(accel)?, finite3(gyro)?);
    if a.amax() > MAX_ACCEL_MPS2 || g.amax() > MAX_GYRO_RADPS {
        return Err(LinkError::Rejected("imu_out_of_range"));
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

/// Encodes an [`Outbound`] as a MAVLink 2 frame (for tests and fuzz seeds).
pub fn encode_bytes(out: &Outbound, seq: u8) -> Vec<u8> {
    let mut buf = Vec::new();
    let h = MavHeader {
        system_id: 1,
        component_id: 1,
        sequence: seq,
    };
    let _ = mavlink::write_versioned_msg(&mut buf, mavlink::MavlinkVersion::V2, h, &encode(out, 1, 1));
    buf
}

/// MAVLink message → [`Inbound`], with units converted here and only here.
/// (`GPS_GLOBAL_ORIGIN` is deprecated but still what autopilots send.)
#[allow(deprecated)]
fn decode(msg: apm::MavMessage) -> Result<Inbound, LinkError> {
    use apm::MavMessage as M;
    Ok(match msg {
        M::HIGHRES_IMU(d) => {
            let (accel_mps2, gyro_radps) = imu_checked(
                Vector3::new(d.xacc as f64, d.yacc as f64, d.zacc as f64),
                Vector3::new(d.xgyro as f64, d.ygyro as f64, d.zgyro as f64),
            )?;
            Inbound::Imu {
                t_us: d.time_usec,
                accel_mps2,
                gyro_radps,
                kind: "highres",
            }
        }
        // SCALED_IMU: mG and mrad/s.
        M::SCALED_IMU(d) => Inbound::Imu {
            t_us: d.time_boot_ms as u64 * 1000,
            accel_mps2: Vector3::new(d.xacc as f64, d.yacc as f64, d.zacc as f64) * (G0 / 1000.0),
            gyro_radps: Vector3::new(d.xgyro as f64, d.ygyro as f64, d.zgyro as f64) / 1000.0,
            kind: "scaled",
        },
        // RAW_IMU: ArduPilot fills it with the same mG and mrad/s scaling.
        M::RAW_IMU(d) => Inbound::Imu {
            t_us: d.time_usec,
            accel_mps2: Vector3::new(d.xacc as f64, d.yacc as f64, d.zacc as f64) * (G0 / 1000.0),
            gyro_radps: Vector3::new(d.xgyro as f64, d.ygyro as f64, d.zgyro as f64) / 1000.0,
            kind: "raw",
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
        M::GPS_RAW_INT(d) if d.h_acc > 0 && d.v_acc > 0 => Inbound::GpsAccuracy {
            h_acc_m: d.h_acc as f64 * 1e-3,
            v_acc_m: d.v_acc as f64 * 1e-3,
        },
        M::GPS_RAW_INT(_) => Inbound::Other("GPS_RAW_INT"),
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
        M::HEARTBEAT(_) => Inbound::Heartbeat,
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

// ---------------------------------------------------------------- outbound

/// [`Outbound`] → MAVLink message. (`SET_GPS_GLOBAL_ORIGIN` is deprecated
/// in favour of `MAV_CMD_DO_SET_GLOBAL_ORIGIN`, but it is what ArduPilot 4.x
/// takes.)
fn encode(out: &Outbound, target_system: u8, target_component: u8) -> apm::MavMessage {
    match out {
        Outbound::Heartbeat { initialised, degraded } => heartbeat(*initialised, *degraded),
        Outbound::StatusText { severity, text } => status_text(*severity, text),
        Outbound::SetMessageInterval {
            message_id,
            interval_us,
        } => set_message_interval(*message_id, *interval_us, target_system, target_component),
        Outbound::TimesyncRequest { ts1_ns } => timesync_request(*ts1_ns, target_system, target_component),
        Outbound::VisionPositionEstimate {
            t_us,
            p_ned_m,
            rpy_rad,
            covariance,
            reset_counter,
        } => vision_position_estimate(*t_us, p_ned_m, rpy_rad, covariance, *reset_counter),
        Outbound::Odometry {
            t_us,
            p_ned_m,
            q_wxyz,
            v_body_mps,
            w_body_radps,
            pose_covariance,
            velocity_covariance,
            reset_counter,
        } => odometry(
            *t_us,
            p_ned_m,
            q_wxyz,
            v_body_mps,
            w_body_radps,
            pose_covariance,
            velocity_covariance,
            *reset_counter,
        ),
        Outbound::SetGpsGlobalOrigin {
            lat_deg,
            lon_deg,
            alt_m,
        } => set_gps_global_origin(*lat_deg, *lon_deg, *alt_m, target_system),
    }
}

/// `HEARTBEAT` of an onboard controller: standby until initialised, then
/// active, or critical while degraded.
fn heartbeat(initialised: bool, degraded: bool) -> apm::MavMessage {
    apm::MavMessage::HEARTBEAT(apm::HEARTBEAT_DATA {
        custom_mode: 0,
        mavtype: apm::MavType::MAV_TYPE_ONBOARD_CONTROLLER,
        autopilot: apm::MavAutopilot::MAV_AUTOPILOT_INVALID,
        base_mode: apm::MavModeFlag::empty(),
        system_status: match (initialised, degraded) {
            (false, _) => apm::MavState::MAV_STATE_STANDBY,
            (true, false) => apm::MavState::MAV_STATE_ACTIVE,
            (true, true) => apm::MavState::MAV_STATE_CRITICAL,
        },
        mavlink_version: 3,
    })
}

/// `STATUSTEXT`, the text cut at a character boundary within 50 bytes.
fn status_text(severity: u8, text: &str) -> apm::MavMessage {
    let mut end = text.len().min(50);
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    apm::MavMessage::STATUSTEXT(apm::STATUSTEXT_DATA {
        severity: mav_severity(severity),
        text: text[..end].into(),
        id: 0,
        chunk_seq: 0,
    })
}

/// An RFC-5424 severity (0 emergency … 7 debug); above 7 is debug.
fn mav_severity(severity: u8) -> apm::MavSeverity {
    match severity {
        0 => apm::MavSeverity::MAV_SEVERITY_EMERGENCY,
        1 => apm::MavSeverity::MAV_SEVERITY_ALERT,
        2 => apm::MavSeverity::MAV_SEVERITY_CRITICAL,
        3 => apm::MavSeverity::MAV_SEVERITY_ERROR,
        4 => apm::MavSeverity::MAV_SEVERITY_WARNING,
        5 => apm::MavSeverity::MAV_SEVERITY_NOTICE,
        6 => apm::MavSeverity::MAV_SEVERITY_INFO,
        _ => apm::MavSeverity::MAV_SEVERITY_DEBUG,
    }
}

/// `COMMAND_LONG` `MAV_CMD_SET_MESSAGE_INTERVAL`: stream `message_id` every
/// `interval_us`.
fn set_message_interval(message_id: u32, interval_us: f32, target_system: u8, target_component: u8) -> apm::MavMessage {
    apm::MavMessage::COMMAND_LONG(apm::COMMAND_LONG_DATA {
        param1: message_id as f32,
        param2: interval_us,
        param3: 0.0,
        param4: 0.0,
        param5: 0.0,
        param6: 0.0,
        param7: 0.0,
        command: apm::MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
        target_system,
        target_component,
        confirmation: 0,
    })
}

/// `TIMESYNC` request: our time `ts1_ns`, `tc1` 0.
fn timesync_request(ts1_ns: i64, target_system: u8, target_component: u8) -> apm::MavMessage {
    apm::MavMessage::TIMESYNC(apm::TIMESYNC_DATA {
        tc1: 0,
        ts1: ts1_ns,
        target_system,
        target_component,
    })
}

/// `VISION_POSITION_ESTIMATE`: position (NED, m), roll, pitch, yaw (rad)
/// and the upper triangle of their covariance.
fn vision_position_estimate(
    t_us: u64,
    p_ned_m: &Vector3<f64>,
    rpy_rad: &Vector3<f64>,
    covariance: &[f32; 21],
    reset_counter: u8,
) -> apm::MavMessage {
    apm::MavMessage::VISION_POSITION_ESTIMATE(apm::VISION_POSITION_ESTIMATE_DATA {
        usec: t_us,
        x: p_ned_m.x as f32,
        y: p_ned_m.y as f32,
        z: p_ned_m.z as f32,
        roll: rpy_rad.x as f32,
        pitch: rpy_rad.y as f32,
        yaw: rpy_rad.z as f32,
        covariance: *covariance,
        reset_counter,
    })
}

/// `ODOMETRY` of a VIO estimator: pose in the local FRD frame, velocity and
/// rate in the body FRD frame, with their covariances.
#[allow(clippy::too_many_arguments)] // the fields of `Outbound::Odometry`
fn odometry(
    t_us: u64,
    p_ned_m: &Vector3<f64>,
    q_wxyz: &[f32; 4],
    v_body_mps: &Vector3<f64>,
    w_body_radps: &Vector3<f64>,
    pose_covariance: &[f32; 21],
    velocity_covariance: &[f32; 21],
    reset_counter: u8,
) -> apm::MavMessage {
    apm::MavMessage::ODOMETRY(apm::ODOMETRY_DATA {
        time_usec: t_us,
        x: p_ned_m.x as f32,
        y: p_ned_m.y as f32,
        z: p_ned_m.z as f32,
        q: *q_wxyz,
        vx: v_body_mps.x as f32,
        vy: v_body_mps.y as f32,
        vz: v_body_mps.z as f32,
        rollspeed: w_body_radps.x as f32,
        pitchspeed: w_body_radps.y as f32,
        yawspeed: w_body_radps.z as f32,
        pose_covariance: *pose_covariance,
        velocity_covariance: *velocity_covariance,
        frame_id: apm::MavFrame::MAV_FRAME_LOCAL_FRD,
        child_frame_id: apm::MavFrame::MAV_FRAME_BODY_FRD,
        reset_counter,
        estimator_type: apm::MavEstimatorType::MAV_ESTIMATOR_TYPE_VIO,
        quality: 100,
    })
}

/// `SET_GPS_GLOBAL_ORIGIN` (deprecated, but what ArduPilot 4.x takes):
/// degrees and metres to 1e-7 deg and mm.
#[allow(deprecated)]
fn set_gps_global_origin(lat_deg: f64, lon_deg: f64, alt_m: f64, target_system: u8) -> apm::MavMessage {
    apm::MavMessage::SET_GPS_GLOBAL_ORIGIN(apm::SET_GPS_GLOBAL_ORIGIN_DATA {
        latitude: (lat_deg * 1e7).round() as i32,
        longitude: (lon_deg * 1e7).round() as i32,
        altitude: (alt_m * 1000.0).round() as i32,
        target_system,
        time_usec: 0,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

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
        assert!(matches!(decode(nan), Err(LinkError::Rejected("non_finite"))));
    }
}
