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
//!
//! Only the autopilot (the configured system and component ids) is heard as
//! the autopilot: its frames alone are sequence-checked and keep the link
//! alive, and on UDP its address is learned from its first HEARTBEAT and
//! kept, so that our outputs go to it and nowhere else (`io::udp_peer`);
//! its ids from another address are rejected. TCP and serial links are
//! opened again, with backoff, when they fail.

use std::collections::VecDeque;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU16, AtomicU32, AtomicU8, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use mavlink::dialects::ardupilotmega as apm;
use mavlink::{AsyncMavConnection, MavHeader, Message as _};
use nalgebra::Vector3;

use super::messages::{Inbound, Outbound, Source};
use super::udp_peer::{UdpPeer, MAX_DATAGRAM};

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

/// What one receive gave.
#[derive(Debug)]
pub enum Received {
    /// A message, its sender, and how many of the autopilot's frames were
    /// lost or dropped as corrupt before it (0 for anyone else's).
    Message { src: Source, msg: Inbound, lost: u32 },
    /// A frame that is fine but not taken now (counted under this name;
    /// not a rejection): the autopilot's data before its first HEARTBEAT
    /// told us where it is.
    Ignored(&'static str),
    /// A TCP or serial link was opened again after it failed.
    Reconnected,
    /// The autopilot's UDP address, learned from its HEARTBEAT.
    PeerLearned(SocketAddr),
}

/// MAVLink 2's "signed" incompatibility flag.
const IFLAG_SIGNED: u8 = 0x01;
/// HEARTBEAT's message id.
const MSG_ID_HEARTBEAT: u32 = 0;
/// Reconnection backoff of a TCP or serial link: first and longest wait.
const BACKOFF_FIRST: Duration = Duration::from_millis(100);
const BACKOFF_MAX: Duration = Duration::from_secs(5);

type Conn = mavlink::AsyncConnection<apm::MavMessage>;

/// How bytes reach the autopilot.
enum Transport {
    /// `udpin:` / `udpout:`, framed here: we send to the autopilot's
    /// address only, and count datagrams that hold no frame.
    Udp {
        peer: UdpPeer,
        rx: tokio::sync::Mutex<UdpRx>,
    },
    /// TCP, serial or UDP broadcast through the crate's connection, opened
    /// again (with backoff) when it fails.
    Crate {
        address: String,
        conn: tokio::sync::RwLock<Option<Arc<Conn>>>,
        backoff: Mutex<Duration>,
    },
}

/// The UDP receive side: one datagram's frames, taken one at a time.
struct UdpRx {
    buf: Vec<u8>,
    frames: VecDeque<(mavlink::MAVLinkMessageRaw, SocketAddr)>,
}

/// A connected link.
pub struct Link {
    transport: Transport,
    header: MavHeader,
    target_system: u8,
    target_component: u8,
    /// The autopilot's ids: only its frames locate it, are sequence-checked
    /// and keep the link alive.
    autopilot: Source,
    autopilot_seq: Mutex<Option<u8>>,
    /// When a frame of the autopilot was last accepted.
    last_heard: Mutex<Option<Instant>>,
    /// An event to report at the next receive.
    event: Mutex<Option<Received>>,
    /// The autopilot's frames lost before frames rejected since: said with
    /// the next message.
    lost_carried: AtomicU32,
    /// Message signing: key, link id and replay state.
    signing: Option<mavlink::SigningData>,
    /// Our sequence number when we frame (and sign) messages ourselves.
    seq: AtomicU8,
}

impl Link {
    /// Opens the link (`udpin:`, `udpout:`, `tcpout:`, `serial:` …) to the
    /// autopilot `(target_system, target_component)`, with message signing
    /// when `signing` gives a key and our link id.
    pub async fn connect(
        address: &str,
        system_id: u8,
        component_id: u8,
        target_system: u8,
        target_component: u8,
        signing: Option<([u8; 32], u8)>,
    ) -> Result<Self, LinkError> {
        let transport = match UdpPeer::open(address).await {
            Some(peer) => Transport::Udp {
                peer: peer?,
                rx: tokio::sync::Mutex::new(UdpRx {
                    buf: vec![0; MAX_DATAGRAM],
                    frames: VecDeque::new(),
                }),
            },
            None => Transport::Crate {
                address: address.to_string(),
                conn: tokio::sync::RwLock::new(Some(Arc::new(open_crate(address).await?))),
                backoff: Mutex::new(BACKOFF_FIRST),
            },
        };
        Ok(Self {
            transport,
            header: MavHeader {
                system_id: system_id as u32,
                component_id,
                sequence: 0,
            },
            target_system,
            target_component,
            autopilot: Source {
                system: target_system as u32,
                component: target_component,
            },
            autopilot_seq: Mutex::new(None),
            last_heard: Mutex::new(None),
            event: Mutex::new(None),
            lost_carried: AtomicU32::new(0),
            signing: signing.map(|(key, link_id)| {
                mavlink::SigningData::from_config(mavlink::SigningConfig::new(key, link_id, true, false))
            }),
            seq: AtomicU8::new(0),
        })
    }

    /// How long the autopilot has been silent (`None`: never heard).
    pub fn silent_for(&self) -> Option<Duration> {
        lock(&self.last_heard).map(|t| t.elapsed())
    }

    /// Marks the autopilot's learned UDP address stale after a long silence:
    /// still sent to, and learned again from its next HEARTBEAT. Returns
    /// whether it was marked now.
    pub fn forget_peer(&self) -> bool {
        match &self.transport {
            Transport::Udp { peer, .. } => peer.forget(),
            Transport::Crate { .. } => false,
        }
    }

    /// The local UDP address, if the link is UDP (for tests and logs).
    pub fn local_udp_addr(&self) -> Option<SocketAddr> {
        match &self.transport {
            Transport::Udp { peer, .. } => peer.local_addr().ok(),
            Transport::Crate { .. } => None,
        }
    }

    /// Frames of the autopilot lost or dropped since its previous one, from
    /// the sequence numbers (a large jump is a restarted sender: 0). Other
    /// senders are not tracked: their numbers say nothing about our link,
    /// and a flood of made-up senders would only inflate the count.
    fn sequence_gap(&self, src: Source, sequence: u8) -> u32 {
        if src != self.autopilot {
            return 0;
        }
        let mut last = lock(&self.autopilot_seq);
        let gap = last.map_or(0, |l| sequence.wrapping_sub(l).wrapping_sub(1) as u32);
        *last = Some(sequence);
        if gap > 128 {
            0
        } else {
            gap
        }
    }

    /// Receives the next message, or says why there is none.
    pub async fn recv(&self) -> Result<Received, LinkError> {
        if let Some(e) = lock(&self.event).take() {
            return Ok(e);
        }
        match &self.transport {
            Transport::Udp { peer, rx } => self.recv_udp(peer, rx).await,
            Transport::Crate { address, conn, backoff } => self.recv_crate(address, conn, backoff).await,
        }
    }

    /// UDP: the next frame of the current datagram, or of the next one.
    async fn recv_udp(&self, peer: &UdpPeer, rx: &tokio::sync::Mutex<UdpRx>) -> Result<Received, LinkError> {
        let mut rx = rx.lock().await;
        if rx.frames.is_empty() {
            let UdpRx { buf, frames } = &mut *rx;
            let (n, from) = peer.recv(buf).await?;
            let mut reader = mavlink::MavlinkReader::new(&buf[..n]);
            // Bounded: a frame takes at least 8 bytes of the datagram.
            for _ in 0..n / 8 + 1 {
                match reader.read_any_raw_message::<apm::MavMessage>() {
                    Ok(raw) => frames.push_back((raw, from)),
                    Err(_) => break,
                }
            }
            if frames.is_empty() {
                return Err(LinkError::Rejected("garbage_datagram"));
            }
        }
        let Some((raw, from)) = rx.frames.pop_front() else {
            return Err(LinkError::Rejected("garbage_datagram"));
        };
        drop(rx);
        let (src, sequence, id) = raw_header(&raw);
        let from_autopilot = src == self.autopilot;
        let learning = from_autopilot && peer.learning();
        let at_its_address = learning || peer.peer() == Some(from);
        // The autopilot's number is seen even if the frame is rejected
        // below, so that a rejected frame is not counted again as lost.
        let lost = if from_autopilot && at_its_address {
            self.sequence_gap(src, sequence)
        } else {
            0
        };
        let msg = self.accept_raw(&raw).inspect_err(|_| self.carry_lost(lost))?;
        if from_autopilot && !at_its_address {
            return Err(LinkError::Rejected("autopilot_id_from_other_address"));
        }
        if learning && id != MSG_ID_HEARTBEAT {
            // udpin before the autopilot's first HEARTBEAT, or after a long
            // silence: only its HEARTBEAT says where it is now.
            self.carry_lost(lost);
            return Ok(Received::Ignored("mavlink_before_autopilot_heartbeat"));
        }
        if from_autopilot {
            if learning && peer.learn(from) {
                // Said at the next receive; the HEARTBEAT itself now.
                *lock(&self.event) = Some(Received::PeerLearned(from));
            }
            self.heard();
        }
        self.message(src, msg, lost)
    }

    /// The message as the caller takes it, with the autopilot's frames lost
    /// before it (including those before frames rejected since).
    fn message(&self, src: Source, msg: apm::MavMessage, lost: u32) -> Result<Received, LinkError> {
        let msg = decode(msg).inspect_err(|_| self.carry_lost(lost))?;
        Ok(Received::Message {
            src,
            msg,
            lost: lost + self.lost_carried.swap(0, Ordering::Relaxed),
        })
    }

    /// Keeps `lost` for the next message: its frame was rejected.
    fn carry_lost(&self, lost: u32) {
        self.lost_carried.fetch_add(lost, Ordering::Relaxed);
    }

    /// TCP, serial, broadcast: the crate's next message; a failed link is
    /// opened again with backoff.
    async fn recv_crate(
        &self,
        address: &str,
        conn: &tokio::sync::RwLock<Option<Arc<Conn>>>,
        backoff: &Mutex<Duration>,
    ) -> Result<Received, LinkError> {
        let current = conn.read().await.clone();
        let Some(c) = current else {
            let wait = *lock(backoff);
            tokio::time::sleep(wait).await;
            return match open_crate(address).await {
                Ok(c) => {
                    *conn.write().await = Some(Arc::new(c));
                    *lock(backoff) = BACKOFF_FIRST;
                    Ok(Received::Reconnected)
                }
                Err(e) => {
                    *lock(backoff) = (wait * 2).min(BACKOFF_MAX);
                    Err(e)
                }
            };
        };
        let got = match &self.signing {
            Some(sd) => self.recv_crate_signed(&c, sd).await,
            None => match c.try_recv().await {
                Ok((h, msg)) => {
                    let src = Source {
                        system: h.system_id,
                        component: h.component_id,
                    };
                    Ok((src, msg, self.sequence_gap(src, h.sequence)))
                }
                Err(mavlink::error::MessageReadError::Io(e)) => Err(LinkError::Io(e)),
                Err(mavlink::error::MessageReadError::Parse(e)) => Err(LinkError::Parse(e.to_string())),
            },
        };
        if let Err(LinkError::Io(_)) = &got {
            // Drop it: the next receive opens it again.
            *conn.write().await = None;
        }
        let (src, msg, lost) = got?;
        if src == self.autopilot {
            self.heard();
        }
        self.message(src, msg, lost)
    }

    async fn recv_crate_signed(
        &self,
        c: &Conn,
        sd: &mavlink::SigningData,
    ) -> Result<(Source, apm::MavMessage, u32), LinkError> {
        let raw = match c.recv_raw().await {
            Ok(r) => r,
            Err(mavlink::error::MessageReadError::Io(e)) => return Err(LinkError::Io(e)),
            Err(mavlink::error::MessageReadError::Parse(e)) => return Err(LinkError::Parse(e.to_string())),
        };
        let (src, sequence, _) = raw_header(&raw);
        let lost = self.sequence_gap(src, sequence);
        let msg = self.check_signed(&raw, sd).inspect_err(|_| self.carry_lost(lost))?;
        Ok((src, msg, lost))
    }

    /// A raw frame checked (signature, when signing) and parsed.
    fn accept_raw(&self, raw: &mavlink::MAVLinkMessageRaw) -> Result<apm::MavMessage, LinkError> {
        if let Some(sd) = &self.signing {
            return self.check_signed(raw, sd);
        }
        let (version, id, payload) = match raw {
            mavlink::MAVLinkMessageRaw::V1(r) => (mavlink::MavlinkVersion::V1, r.message_id() as u32, r.payload()),
            mavlink::MAVLinkMessageRaw::V2(r) => (mavlink::MavlinkVersion::V2, r.message_id(), r.payload()),
        };
        apm::MavMessage::parse(version, id, payload).map_err(|e| LinkError::Parse(e.to_string()))
    }

    /// A frame that must be signed: MAVLink 2, signed, with a valid
    /// signature (checked here so that each rejection is counted with its
    /// reason; the crate's own check drops them silently).
    fn check_signed(
        &self,
        raw: &mavlink::MAVLinkMessageRaw,
        sd: &mavlink::SigningData,
    ) -> Result<apm::MavMessage, LinkError> {
        let mavlink::MAVLinkMessageRaw::V2(r) = raw else {
            return Err(LinkError::Rejected("unsigned"));
        };
        if r.incompatibility_flags() & IFLAG_SIGNED == 0 {
            return Err(LinkError::Rejected("unsigned"));
        }
        if !sd.verify_signature(r) {
            return Err(LinkError::Rejected("bad_signature"));
        }
        apm::MavMessage::parse(mavlink::MavlinkVersion::V2, r.message_id(), r.payload())
            .map_err(|e| LinkError::Parse(e.to_string()))
    }

    fn heard(&self) {
        *lock(&self.last_heard) = Some(Instant::now());
    }

    /// Sends one message (a long STATUSTEXT as its chunks). `Ok(false)`:
    /// not sent, because the autopilot's address is not known yet (UDP) or
    /// the link is being reopened.
    pub async fn send(&self, out: &Outbound) -> Result<bool, LinkError> {
        for msg in encode(out, self.target_system, self.target_component) {
            if !self.send_message(msg).await? {
                return Ok(false);
            }
        }
        Ok(true)
    }

    /// Frames (and signs) one MAVLink message and sends it.
    async fn send_message(&self, msg: apm::MavMessage) -> Result<bool, LinkError> {
        let header = MavHeader {
            sequence: self.seq.fetch_add(1, Ordering::Relaxed),
            ..self.header
        };
        let raw = self.signing.as_ref().map(|sd| {
            let mut raw = mavlink::MAVLinkV2MessageRaw::new();
            raw.serialize_message_for_signing(header, &msg);
            sd.sign_message(&mut raw);
            raw
        });
        match &self.transport {
            Transport::Udp { peer, .. } => {
                let mut buf = Vec::new();
                match &raw {
                    Some(raw) => buf.extend_from_slice(raw.raw_bytes()),
                    None => {
                        mavlink::write_versioned_msg(&mut buf, mavlink::MavlinkVersion::V2, header, &msg)
                            .map_err(|e| LinkError::Io(std::io::Error::other(e.to_string())))?;
                    }
                }
                Ok(peer.send(&buf).await?)
            }
            Transport::Crate { conn, .. } => {
                let Some(c) = conn.read().await.clone() else {
                    return Ok(false);
                };
                let sent = match raw {
                    Some(raw) => c.send_raw(&mavlink::MAVLinkMessageRaw::V2(raw)).await,
                    None => c.send(&header, &msg).await,
                };
                sent.map_err(|e| LinkError::Io(std::io::Error::other(e.to_string())))?;
                Ok(true)
            }
        }
    }
}

/// Opens a link through the crate (any scheme but our UDP ones).
async fn open_crate(address: &str) -> Result<Conn, LinkError> {
    let mut conn = mavlink::connect_async::<apm::MavMessage>(address).await?;
    conn.set_protocol_version(mavlink::MavlinkVersion::V2);
    conn.set_allow_recv_any_version(true);
    Ok(conn)
}

/// A raw frame's sender, sequence number and message id.
fn raw_header(raw: &mavlink::MAVLinkMessageRaw) -> (Source, u8, u32) {
    match raw {
        mavlink::MAVLinkMessageRaw::V1(r) => (
            Source {
                system: r.system_id() as u32,
                component: r.component_id(),
            },
            r.sequence(),
            r.message_id() as u32,
        ),
        mavlink::MAVLinkMessageRaw::V2(r) => (
            Source {
                system: r.system_id(),
                component: r.component_id(),
            },
            r.sequence(),
            r.message_id(),
        ),
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
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

/// Encodes an [`Outbound`] as MAVLink 2 frames, numbered from `seq` (one
/// frame, or a long STATUSTEXT's chunks; for tests and fuzz seeds).
pub fn encode_bytes(out: &Outbound, seq: u8) -> Vec<u8> {
    let mut buf = Vec::new();
    for (k, msg) in encode(out, 1, 1).iter().enumerate() {
        let h = MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: seq.wrapping_add(k as u8),
        };
        let _ = mavlink::write_versioned_msg(&mut buf, mavlink::MavlinkVersion::V2, h, msg);
    }
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

/// [`Outbound`] → MAVLink messages: one, or a long STATUSTEXT's chunks.
/// (`SET_GPS_GLOBAL_ORIGIN` is deprecated in favour of
/// `MAV_CMD_DO_SET_GLOBAL_ORIGIN`, but it is what ArduPilot 4.x takes.)
fn encode(out: &Outbound, target_system: u8, target_component: u8) -> Vec<apm::MavMessage> {
    let one = match out {
        Outbound::StatusText { severity, text } => return status_text(*severity, text),
        Outbound::Heartbeat { initialised, degraded } => heartbeat(*initialised, *degraded),
        Outbound::SetMessageInterval {
            message_id,
            interval_us,
        } => set_message_interval(*message_id, *interval_us, target_system, target_component),
        Outbound::TimesyncRequest { ts1_ns } => timesync_request(*ts1_ns, target_system, target_component),
        Outbound::TimesyncReply { tc1_ns, ts1_ns } => apm::MavMessage::TIMESYNC(apm::TIMESYNC_DATA {
            tc1: *tc1_ns,
            ts1: *ts1_ns,
            target_system,
            target_component,
        }),
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
            quality,
        } => odometry(
            *t_us,
            p_ned_m,
            q_wxyz,
            v_body_mps,
            w_body_radps,
            pose_covariance,
            velocity_covariance,
            *reset_counter,
            *quality,
        ),
        Outbound::VisionSpeedEstimate {
            t_us,
            v_ned_mps,
            covariance,
            reset_counter,
        } => vision_speed_estimate(*t_us, v_ned_mps, covariance, *reset_counter),
        Outbound::SetGpsGlobalOrigin {
            lat_deg,
            lon_deg,
            alt_m,
        } => set_gps_global_origin(*lat_deg, *lon_deg, *alt_m, target_system),
    };
    vec![one]
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

/// Bytes of text in one `STATUSTEXT`.
const STATUSTEXT_LEN: usize = 50;
/// Most `STATUSTEXT` messages one text is sent as; a longer text is cut,
/// ending with [`STATUSTEXT_CUT`].
const STATUSTEXT_MAX_CHUNKS: usize = 4;
const STATUSTEXT_CUT: &str = "…";

/// The id of the next chunked `STATUSTEXT`: 1, 2, … 65535, 1, … (never 0,
/// which marks a text sent whole).
fn next_status_text_id() -> u16 {
    static NEXT: AtomicU16 = AtomicU16::new(0);
    loop {
        let id = NEXT.fetch_add(1, Ordering::Relaxed).wrapping_add(1);
        if id != 0 {
            return id;
        }
    }
}

/// The largest character boundary of `s` at or before byte `n`.
fn floor_char_boundary(s: &str, n: usize) -> usize {
    let mut end = n.min(s.len());
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    end
}

/// The pieces `text` is sent as, MAVLink 2's chunked `STATUSTEXT`
/// (common.xml): up to 50 bytes, one piece (sent with `id` 0). Longer, up
/// to [`STATUSTEXT_MAX_CHUNKS`] pieces of one `id`, where a NUL in a piece
/// marks the last: each but the last fills its 50 bytes, cut at a
/// character boundary so that every piece is valid UTF-8 on its own (a
/// character that would straddle the cut moves to the next piece, and the
/// 1–3 bytes it leaves are padded with spaces, since a NUL there would end
/// the text); the last is shorter than 50 bytes, or is an empty piece
/// after a text that fills its last piece exactly. A text that does not
/// fit is cut at a character boundary and ends with "…".
fn status_text_pieces(text: &str) -> Vec<String> {
    if text.len() <= STATUSTEXT_LEN {
        return vec![text.to_string()];
    }
    let mut pieces = Vec::new();
    let mut rest = text;
    while !rest.is_empty() {
        if pieces.len() == STATUSTEXT_MAX_CHUNKS - 1 && rest.len() >= STATUSTEXT_LEN {
            // The last piece allowed: it must hold its NUL.
            let keep = floor_char_boundary(rest, STATUSTEXT_LEN - 1 - STATUSTEXT_CUT.len());
            pieces.push(format!("{}{STATUSTEXT_CUT}", &rest[..keep]));
            return pieces;
        }
        let cut = floor_char_boundary(rest, STATUSTEXT_LEN);
        let mut piece = rest[..cut].to_string();
        rest = &rest[cut..];
        if !rest.is_empty() {
            while piece.len() < STATUSTEXT_LEN {
                piece.push(' ');
            }
        }
        pieces.push(piece);
    }
    if pieces.last().is_some_and(|p| p.len() == STATUSTEXT_LEN) {
        // Exactly filled: an empty piece (all NUL) ends the text.
        pieces.push(String::new());
    }
    pieces
}

/// `STATUSTEXT`: the text whole (`id` 0), or in chunks of one new `id`
/// with `chunk_seq` 0, 1, … (see [`status_text_pieces`]).
fn status_text(severity: u8, text: &str) -> Vec<apm::MavMessage> {
    let pieces = status_text_pieces(text);
    let id = if pieces.len() > 1 { next_status_text_id() } else { 0 };
    pieces
        .iter()
        .enumerate()
        .map(|(k, piece)| {
            apm::MavMessage::STATUSTEXT(apm::STATUSTEXT_DATA {
                severity: mav_severity(severity),
                text: piece.as_str().into(),
                id,
                chunk_seq: k as u8,
            })
        })
        .collect()
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

/// `VISION_SPEED_ESTIMATE`: velocity (NED, m/s) and its 3×3 covariance,
/// row-major.
fn vision_speed_estimate(
    t_us: u64,
    v_ned_mps: &Vector3<f64>,
    covariance: &[f32; 9],
    reset_counter: u8,
) -> apm::MavMessage {
    apm::MavMessage::VISION_SPEED_ESTIMATE(apm::VISION_SPEED_ESTIMATE_DATA {
        usec: t_us,
        x: v_ned_mps.x as f32,
        y: v_ned_mps.y as f32,
        z: v_ned_mps.z as f32,
        covariance: *covariance,
        reset_counter,
    })
}

/// `ODOMETRY` of a VIO estimator: pose in the local FRD frame (our NED
/// coordinates: what ArduPilot takes), velocity and rate in the body FRD
/// frame, with their covariances, and the quality.
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
    quality: i8,
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
        quality,
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

    /// The frames of `out`, parsed back.
    fn frames(out: &Outbound) -> Vec<apm::MavMessage> {
        let bytes = encode_bytes(out, 7);
        let mut r = mavlink::MavlinkReader::new(&bytes[..]);
        let mut v = Vec::new();
        while let Ok((_, m)) = r.read_any_message::<apm::MavMessage>() {
            v.push(m);
        }
        v
    }

    /// A receiver that reassembles as common.xml says (as pymavlink's and
    /// MAVProxy's do): `id` 0 is a whole text; otherwise chunks of one `id`
    /// in `chunk_seq` order until one holds a NUL. Returns the texts and
    /// the chunks' `(id, chunk_seq)`.
    fn reassemble(msgs: &[apm::MavMessage]) -> (Vec<String>, Vec<(u16, u8)>) {
        let mut texts = Vec::new();
        let mut seen = Vec::new();
        let mut open: Option<(u16, Vec<u8>)> = None;
        for m in msgs {
            let apm::MavMessage::STATUSTEXT(st) = m else {
                panic!("not a STATUSTEXT: {m:?}")
            };
            seen.push((st.id, st.chunk_seq));
            let bytes: [u8; 50] = st.text.into();
            let end = bytes.iter().position(|&b| b == 0);
            let text = &bytes[..end.unwrap_or(50)];
            // Each chunk is valid UTF-8 on its own.
            assert!(std::str::from_utf8(text).is_ok(), "{text:?}");
            if st.id == 0 {
                texts.push(String::from_utf8(text.to_vec()).unwrap());
                continue;
            }
            let (id, mut acc) = open.take().unwrap_or((st.id, Vec::new()));
            assert_eq!(id, st.id, "chunks of two texts interleaved");
            acc.extend_from_slice(text);
            if end.is_some() {
                texts.push(String::from_utf8(acc).unwrap());
            } else {
                open = Some((id, acc));
            }
        }
        assert!(open.is_none(), "a text was left unterminated");
        (texts, seen)
    }

    fn sent_text(text: &str) -> (String, Vec<(u16, u8)>) {
        let (texts, seen) = reassemble(&frames(&Outbound::StatusText {
            severity: 4,
            text: text.to_string(),
        }));
        assert_eq!(texts.len(), 1, "{texts:?}");
        (texts[0].clone(), seen)
    }

    /// Chunk ids and sequence numbers: `[(0, 0)]` for a whole text, else
    /// one non-zero id with 0, 1, … .
    fn chunked(seen: &[(u16, u8)], n: usize) {
        assert_eq!(seen.len(), n, "{seen:?}");
        assert!(seen.iter().all(|&(id, _)| id != 0 && id == seen[0].0), "{seen:?}");
        assert!(seen.iter().enumerate().all(|(k, &(_, c))| c as usize == k), "{seen:?}");
    }

    #[test]
    fn status_text_is_chunked_as_mavlink_2_says() {
        // Short, and exactly 50 bytes: one message, id 0.
        assert_eq!(sent_text("cmsckf: nominal"), ("cmsckf: nominal".into(), vec![(0, 0)]));
        let t50 = "x".repeat(50);
        assert_eq!(sent_text(&t50), (t50.clone(), vec![(0, 0)]));
        // 51 and 120 bytes: 2 and 3 chunks of one non-zero id.
        let t51 = format!("{}y", "x".repeat(50));
        let (got, seen) = sent_text(&t51);
        assert_eq!(got, t51);
        chunked(&seen, 2);
        let t120: String = (0..120).map(|k| (b'a' + (k % 26) as u8) as char).collect();
        let (got, seen) = sent_text(&t120);
        assert_eq!(got, t120);
        chunked(&seen, 3);
        // An exact multiple of 50: an empty chunk ends it.
        let t100 = "z".repeat(100);
        let (got, seen) = sent_text(&t100);
        assert_eq!(got, t100);
        chunked(&seen, 3);
        // Two long texts have two ids.
        let (_, again) = sent_text(&t51);
        assert_ne!(again[0].0, seen[0].0);
    }

    #[test]
    fn status_text_chunks_cut_at_character_boundaries() {
        // "é" (2 bytes) and "€" (3 bytes) across byte 50: each moves to the
        // next chunk, and the chunk it leaves is padded with spaces (a NUL
        // would end the text there).
        for (head, ch) in [(49, "é"), (48, "€"), (47, "€"), (50, "é")] {
            let text = format!("{}{ch}{}", "a".repeat(head), "b".repeat(10));
            let (got, seen) = sent_text(&text);
            chunked(&seen, 2);
            let pad = 50 - head.min(50);
            let pad = if head + ch.len() <= 50 { 0 } else { pad };
            assert_eq!(
                got,
                format!("{}{}{ch}{}", "a".repeat(head), " ".repeat(pad), "b".repeat(10))
            );
        }
    }

    #[test]
    fn an_over_long_status_text_is_cut_with_an_ellipsis() {
        let text: String = "cmsckf degraded: imu_gap,camera_stale,gnss_stale,input_rejected ".repeat(8);
        let (got, seen) = sent_text(&text);
        chunked(&seen, STATUSTEXT_MAX_CHUNKS);
        assert!(got.ends_with('…') && got.len() < 200, "{got}");
        assert!(text.starts_with(got.trim_end_matches('…')), "{got}");
        // Exactly 200 bytes does not fit either (it would need a fifth,
        // empty chunk); 199 does.
        let (got, seen) = sent_text(&"q".repeat(200));
        chunked(&seen, 4);
        assert!(got.ends_with('…'));
        let (got, seen) = sent_text(&"q".repeat(199));
        chunked(&seen, 4);
        assert_eq!(got, "q".repeat(199));
        // Multibyte near the cut: still valid UTF-8 (checked in reassemble).
        let (got, _) = sent_text(&"ü".repeat(150));
        assert!(got.ends_with('…'));
    }

    #[test]
    fn odometry_and_speed_estimate_carry_their_fields() {
        let odo = Outbound::Odometry {
            t_us: 5,
            p_ned_m: Vector3::new(1.0, 2.0, 3.0),
            q_wxyz: [1.0, 0.0, 0.0, 0.0],
            v_body_mps: Vector3::new(0.5, 0.0, 0.0),
            w_body_radps: Vector3::new(0.0, 0.0, 0.25),
            pose_covariance: [0.1; 21],
            velocity_covariance: [0.01; 21],
            reset_counter: 3,
            quality: -1,
        };
        let [apm::MavMessage::ODOMETRY(d)] = &frames(&odo)[..] else {
            panic!("not one ODOMETRY")
        };
        assert_eq!((d.quality, d.reset_counter, d.yawspeed, d.vx), (-1, 3, 0.25, 0.5));
        assert_eq!(d.estimator_type, apm::MavEstimatorType::MAV_ESTIMATOR_TYPE_VIO);
        assert_eq!(
            (d.frame_id, d.child_frame_id),
            (apm::MavFrame::MAV_FRAME_LOCAL_FRD, apm::MavFrame::MAV_FRAME_BODY_FRD)
        );
        assert!(d.velocity_covariance.iter().all(|c| *c == 0.01));
        let vse = Outbound::VisionSpeedEstimate {
            t_us: 5,
            v_ned_mps: Vector3::new(1.0, -2.0, 0.5),
            covariance: [0.04; 9],
            reset_counter: 3,
        };
        let [apm::MavMessage::VISION_SPEED_ESTIMATE(d)] = &frames(&vse)[..] else {
            panic!("not one VISION_SPEED_ESTIMATE")
        };
        assert_eq!((d.usec, d.x, d.y, d.z, d.reset_counter), (5, 1.0, -2.0, 0.5, 3));
        assert_eq!(d.covariance, [0.04; 9]);
    }
}
