//! The MAVLink link to the autopilot: the only module of the `cmsckf`
//! crate that names `mavlink::` types (this folder: the link here, the
//! message conversions in `decode.rs` (inbound) and `encode.rs` (outbound)).
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

mod decode;
mod encode;

use std::collections::VecDeque;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU32, AtomicU8, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use mavlink::dialects::ardupilotmega as apm;
use mavlink::{AsyncMavConnection, MavHeader, Message as _};

use super::messages::{Inbound, Outbound, Source};
use super::udp_peer::{UdpPeer, MAX_DATAGRAM};
use crate::counters::Counter;
use decode::decode;
pub use decode::decode_bytes;
use encode::encode;
pub use encode::encode_bytes;

/// Why a receive did not give a message.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    #[error("link I/O: {0}")]
    Io(#[from] std::io::Error),
    #[error("undecodable MAVLink message: {0}")]
    Parse(String),
    #[error("message rejected: {0}")]
    Rejected(Counter),
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
    Ignored(Counter),
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
            // A link that is not there yet (a TCP server not up, a USB
            // serial adapter still enumerating) is opened later, with the
            // same backoff as after a loss: the daemon does not exit (under
            // systemd, exits in a row end in the unit given up for good).
            None => Transport::Crate {
                address: address.to_string(),
                conn: tokio::sync::RwLock::new(match open_crate(address).await {
                    Ok(c) => Some(Arc::new(c)),
                    Err(e) => {
                        tracing::warn!(%address, error = %e, "MAVLink link not there yet: opening it again with backoff");
                        None
                    }
                }),
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
                return Err(LinkError::Rejected(Counter::MavlinkRejectedGarbageDatagram));
            }
        }
        let Some((raw, from)) = rx.frames.pop_front() else {
            return Err(LinkError::Rejected(Counter::MavlinkRejectedGarbageDatagram));
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
            return Err(LinkError::Rejected(Counter::MavlinkRejectedAutopilotIdFromOtherAddress));
        }
        if learning && id != MSG_ID_HEARTBEAT {
            // udpin before the autopilot's first HEARTBEAT, or after a long
            // silence: only its HEARTBEAT says where it is now.
            self.carry_lost(lost);
            return Ok(Received::Ignored(Counter::MavlinkBeforeAutopilotHeartbeat));
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
            return Err(LinkError::Rejected(Counter::MavlinkRejectedUnsigned));
        };
        if r.incompatibility_flags() & IFLAG_SIGNED == 0 {
            return Err(LinkError::Rejected(Counter::MavlinkRejectedUnsigned));
        }
        if !sd.verify_signature(r) {
            return Err(LinkError::Rejected(Counter::MavlinkRejectedBadSignature));
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
