//! A hand-made MAVLink peer on a UDP socket connected to the daemon: the
//! autopilot (or a stranger) of the tests that need to shape each frame,
//! and what the daemon sent back.

use std::time::Duration;

use mavlink::dialects::ardupilotmega as apm;
use mavlink::{MavHeader, MavlinkVersion, SigningData};
use tokio::net::UdpSocket;

/// A MAVLink sender with its own sequence numbers (and signing key, if any).
pub struct MavPeer {
    pub sock: UdpSocket,
    pub sys: u8,
    pub comp: u8,
    pub seq: u8,
    pub signer: Option<SigningData>,
}

/// What the daemon sent to a peer.
#[derive(Default, Debug)]
pub struct Inbox {
    pub bytes: usize,
    /// Estimates: ODOMETRY (the default) or VISION_POSITION_ESTIMATE.
    pub estimates: usize,
    pub states: Vec<apm::MavState>,
    pub texts: Vec<String>,
}

impl MavPeer {
    /// A peer speaking as `(sys, comp)` to the daemon's UDP `port`.
    pub async fn new(port: u16, sys: u8, comp: u8) -> Self {
        let sock = UdpSocket::bind("127.0.0.1:0").await.unwrap();
        sock.connect(("127.0.0.1", port)).await.unwrap();
        Self {
            sock,
            sys,
            comp,
            seq: 0,
            signer: None,
        }
    }

    /// `msg` framed as MAVLink 2 from `(sys, comp)`, signed if a key is set.
    pub fn frame_as(&mut self, sys: u8, comp: u8, msg: &apm::MavMessage) -> Vec<u8> {
        let h = MavHeader {
            system_id: sys as u32,
            component_id: comp,
            sequence: self.seq,
        };
        self.seq = self.seq.wrapping_add(1);
        let mut buf = Vec::new();
        match &self.signer {
            Some(sd) => mavlink::write_v2_msg_signed(&mut buf, h, msg, Some(sd)).unwrap(),
            None => mavlink::write_versioned_msg(&mut buf, MavlinkVersion::V2, h, msg).unwrap(),
        };
        buf
    }

    pub fn frame(&mut self, msg: &apm::MavMessage) -> Vec<u8> {
        self.frame_as(self.sys, self.comp, msg)
    }

    pub async fn send(&mut self, msg: &apm::MavMessage) {
        let f = self.frame(msg);
        self.sock.send(&f).await.unwrap();
    }

    pub async fn send_as(&mut self, sys: u8, comp: u8, msg: &apm::MavMessage) {
        let f = self.frame_as(sys, comp, msg);
        self.sock.send(&f).await.unwrap();
    }

    /// A still IMU sample at `t_s`.
    pub async fn imu(&mut self, t_s: f64) {
        self.send(&imu(t_s, -9.81)).await;
    }

    /// `n` still IMU samples at 100 Hz from `*t_s` on (which it advances),
    /// 0.3 ms apart on the wire: a second of them starts the filter.
    pub async fn imu_run(&mut self, t_s: &mut f64, n: usize) {
        for _ in 0..n {
            self.imu(*t_s).await;
            *t_s += 0.01;
            tokio::time::sleep(Duration::from_micros(300)).await;
        }
    }

    /// The autopilot's first words: where it is, its attitude and position.
    pub async fn hello(&mut self) {
        self.send(&heartbeat()).await;
        self.send(&apm::MavMessage::ATTITUDE(apm::ATTITUDE_DATA::default()))
            .await;
        self.send(&apm::MavMessage::LOCAL_POSITION_NED(
            apm::LOCAL_POSITION_NED_DATA::default(),
        ))
        .await;
    }

    /// What the daemon sent us until it is quiet for `quiet`.
    pub async fn drain_for(&self, quiet: Duration) -> Inbox {
        let mut inbox = Inbox::default();
        let mut buf = [0u8; 4096];
        while let Ok(Ok(len)) = tokio::time::timeout(quiet, self.sock.recv(&mut buf)).await {
            inbox.bytes += len;
            let mut r = mavlink::MavlinkReader::new(&buf[..len]);
            while let Ok((_, m)) = r.read_any_message::<apm::MavMessage>() {
                match m {
                    apm::MavMessage::ODOMETRY(_) | apm::MavMessage::VISION_POSITION_ESTIMATE(_) => inbox.estimates += 1,
                    apm::MavMessage::HEARTBEAT(h) => inbox.states.push(h.system_status),
                    apm::MavMessage::STATUSTEXT(t) => inbox.texts.push(
                        t.text
                            .to_str()
                            .unwrap_or("(not UTF-8)")
                            .trim_end_matches('\0')
                            .to_string(),
                    ),
                    _ => {}
                }
            }
        }
        inbox
    }

    pub async fn drain(&self) -> Inbox {
        self.drain_for(Duration::from_millis(30)).await
    }
}

/// A HIGHRES_IMU at `t_s` with only `zacc` set.
pub fn imu(t_s: f64, zacc: f32) -> apm::MavMessage {
    apm::MavMessage::HIGHRES_IMU(apm::HIGHRES_IMU_DATA {
        time_usec: (t_s * 1e6) as u64,
        zacc,
        ..Default::default()
    })
}

/// An ArduPilot quadrotor's HEARTBEAT.
pub fn heartbeat() -> apm::MavMessage {
    apm::MavMessage::HEARTBEAT(apm::HEARTBEAT_DATA {
        mavtype: apm::MavType::MAV_TYPE_QUADROTOR,
        autopilot: apm::MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
        mavlink_version: 3,
        ..Default::default()
    })
}

/// A feature-socket line at `t_s` with `features` (`[id,u,v],…`).
pub fn line(t_s: f64, features: &str) -> String {
    format!(
        "{{\"v\":1,\"t_us\":{},\"cam\":0,\"features\":[{features}]}}\n",
        (t_s * 1e6) as u64
    )
}
