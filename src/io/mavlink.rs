//! The MAVLink link to the autopilot: the only module of the `cmsckf` crate
//! that names `mavlink::` types (this file and `mavlink/encode.rs`).
//!
//! It converts at the boundary, both ways: MAVLink's messages and scaled
//! integers become [`Inbound`] values in SI units, and [`Outbound`] values
//! become MAVLink messages. Transport (UDP, TCP, serial) and framing are the
//! `mavlink` crate's. The crate's reader drops frames with a bad CRC or an
//! unknown id without telling its caller, so the link counts them from the
//! gaps they leave in each sender's sequence numbers.
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

mod encode;
use encode::encode;

/// Standard gravity used by MAVLink's milli-g units (m/s²).
const G0: f64 = 9.80665;

/// Who sent a message.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct Source {
    pub system: u32,
    pub component: u8,
}

/// A message from the autopilot, in SI units.
#[derive(Clone, Debug, PartialEq)]
pub enum Inbound {
    /// IMU sample: boot time (µs), specific force (m/s², FRD), rate (rad/s).
    Imu {
        t_us: u64,
        accel_mps2: Vector3<f64>,
        gyro_radps: Vector3<f64>,
        /// `highres`, `scaled` or `raw`.
        kind: &'static str,
    },
    /// Attitude (rad) at boot time (ms).
    Attitude {
        t_boot_ms: u32,
        roll_rad: f64,
        pitch_rad: f64,
        yaw_rad: f64,
    },
    /// The autopilot's local position and velocity (NED, m and m/s).
    LocalPosition {
        t_boot_ms: u32,
        p_ned_m: Vector3<f64>,
        v_ned_mps: Vector3<f64>,
    },
    SystemTime {
        unix_us: u64,
        boot_ms: u32,
    },
    Timesync {
        tc1_ns: i64,
        ts1_ns: i64,
    },
    /// One `GPS_RTCM_DATA` fragment.
    RtcmFragment {
        flags: u8,
        data: Vec<u8>,
    },
    Heartbeat,
    /// The autopilot's EKF origin (deg, deg, m above the ellipsoid... as
    /// MAVLink gives it: AMSL).
    GpsGlobalOrigin {
        lat_deg: f64,
        lon_deg: f64,
        alt_m: f64,
    },
    /// `VISION_POSITION_ESTIMATE` (when the peer is another estimator, or
    /// for the SITL scorer's own tests).
    Other(&'static str),
}

/// A message to the autopilot.
#[derive(Clone, Debug, PartialEq)]
pub enum Outbound {
    /// `MAV_STATE_STANDBY` until initialised, then `ACTIVE`, or `CRITICAL`
    /// while degraded (an input stale or being rejected, or just restarted).
    Heartbeat {
        initialised: bool,
        degraded: bool,
    },
    /// A `STATUSTEXT` (RFC-5424 severity: 2 critical, 4 warning, 6 info);
    /// the text is cut to MAVLink's 50 bytes.
    StatusText {
        severity: u8,
        text: String,
    },
    SetMessageInterval {
        message_id: u32,
        interval_us: f32,
    },
    TimesyncRequest {
        ts1_ns: i64,
    },
    VisionPositionEstimate {
        t_us: u64,
        p_ned_m: Vector3<f64>,
        rpy_rad: Vector3<f64>,
        /// Upper triangle of the 6×6 covariance of `[x y z roll pitch yaw]`.
        covariance: [f32; 21],
        reset_counter: u8,
    },
    Odometry {
        t_us: u64,
        p_ned_m: Vector3<f64>,
        q_wxyz: [f32; 4],
        v_body_mps: Vector3<f64>,
        w_body_radps: Vector3<f64>,
        pose_covariance: [f32; 21],
        velocity_covariance: [f32; 21],
        reset_counter: u8,
    },
    SetGpsGlobalOrigin {
        lat_deg: f64,
        lon_deg: f64,
        alt_m: f64,
    },
}

/// Message ids the daemon asks streams for.
pub const MSG_ID_HIGHRES_IMU: u32 = 105;
pub const MSG_ID_ATTITUDE: u32 = 30;
pub const MSG_ID_SYSTEM_TIME: u32 = 2;
pub const MSG_ID_LOCAL_POSITION_NED: u32 = 32;

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
