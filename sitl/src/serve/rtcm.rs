//! The GNSS receivers' side: the rover's RTCM3 observations (MSM7) and
//! broadcast ephemerides, split into MAVLink `GPS_RTCM_DATA` fragments as an
//! autopilot relays them, or written to a TCP port as a receiver wired to
//! the companion sends them (`receiver_port`); and a base station's
//! observations with its antenna position (MT1005), injected by a ground
//! station into `GPS_RTCM_DATA`.

use mavlink::dialects::ardupilotmega as apm;
use mavlink::{AsyncMavConnection, MavHeader};

use super::fault::{add_pr_outliers, break_crc, drop_first_gps, Active, FaultKind, BASE_MOVED_M};
use super::stream::Streamer;
use super::{GCS_HEADER, HEADER, ROVER_STATION_ID, SECOND_GCS_HEADER};

/// Splits an RTCM message into `GPS_RTCM_DATA` fragments (MAVLink spec):
/// flags bit 0 = fragmented, bits 1–2 = fragment id, bits 3–7 = sequence.
pub fn rtcm_fragments(msg: &[u8], seq: u8) -> Vec<apm::GPS_RTCM_DATA_DATA> {
    let chunks: Vec<&[u8]> = msg.chunks(180).collect();
    let fragmented = chunks.len() > 1;
    chunks
        .iter()
        .enumerate()
        .take(4)
        .map(|(i, c)| {
            let mut data = [0u8; 180];
            data[..c.len()].copy_from_slice(c);
            apm::GPS_RTCM_DATA_DATA {
                flags: if fragmented {
                    1 | ((i as u8) << 1) | ((seq & 0x1f) << 3)
                } else {
                    (seq & 0x1f) << 3
                },
                len: c.len() as u8,
                data,
            }
        })
        .collect()
}

impl Streamer<'_> {
    /// Delivers the next GNSS epoch (in delivery order, at its
    /// `t_delivered_s`): the receiver's MSM7 epoch, as it would relay it,
    /// with the faults in force at delivery applied.
    pub(super) async fn send_gnss_epoch(&mut self, active: &Active<'_>) {
        let Some(ep) = self.next_epoch() else { return };
        let mut ep = ep.clone();
        if active.has(FaultKind::PrOutlier) {
            add_pr_outliers(&mut ep);
        }
        if !active.link_down() && !active.has(FaultKind::GnssOutage) {
            if let Ok(mut bytes) = crate::rtcm_out::encode_epoch(&ep, ROVER_STATION_ID) {
                if active.has(FaultKind::RtcmBadCrc) {
                    break_crc(&mut bytes);
                }
                // Copies go under one sequence number, as a relay repeats.
                for _ in 0..active.copies() {
                    self.send_receiver(&bytes).await;
                }
                self.rtcm_seq = self.rtcm_seq.wrapping_add(1);
            }
        }
        self.k_gnss += 1;
    }

    /// Sends every broadcast ephemeris, as receivers repeat them.
    pub(super) async fn send_ephemerides(&mut self) {
        let ds = self.ds;
        for e in &ds.ephemerides {
            if let Ok(bytes) = cmsckf_models::gnss::rtcm_eph::encode_ephemeris(e) {
                self.send_receiver(&bytes).await;
                self.rtcm_seq = self.rtcm_seq.wrapping_add(1);
            }
        }
    }

    /// Delivers the next base-station epoch (at its `t_delivered_s`): its
    /// MT1005 and MSM7, from the ground station's system id, with the base
    /// faults in force at delivery applied.
    pub(super) async fn send_base_epoch(&mut self, active: &Active<'_>) {
        let Some(ep) = self.next_base_epoch() else { return };
        self.k_base += 1;
        let (Some(mut arp), false) = (self.ds.base_arp_ecef_m, active.link_down()) else {
            return;
        };
        if active.has(FaultKind::BaseSilent) {
            return;
        }
        arp = self.offset_arp(arp, self.ds.cfg.gnss.base.announced_error_m);
        if active.has(FaultKind::BaseMoved) {
            arp = self.offset_arp(arp, [0.0, BASE_MOVED_M, 0.0]);
        }
        let id = self.ds.cfg.gnss.base.station_id;
        let mut ep = ep.clone();
        if active.has(FaultKind::BaseDropsSatellite) {
            drop_first_gps(&mut ep);
        }
        let observations = if self.ds.cfg.gnss.base.legacy {
            crate::rtcm_out::encode_legacy_epoch(&ep, id)
        } else {
            crate::rtcm_out::encode_epoch(&ep, id)
        };
        let mut messages = vec![crate::rtcm_out::encode_station(id, arp), observations];
        if active.has(FaultKind::BaseClaimsRoverId) {
            messages.push(crate::rtcm_out::encode_station(ROVER_STATION_ID, arp));
        }
        let stations: &[MavHeader] = if active.has(FaultKind::BaseDoubled) {
            &[GCS_HEADER, SECOND_GCS_HEADER]
        } else {
            &[GCS_HEADER]
        };
        for bytes in messages.into_iter().flatten() {
            for header in stations {
                self.send_rtcm(header, &bytes).await;
            }
            self.rtcm_seq = self.rtcm_seq.wrapping_add(1);
        }
        let second = self.ds.cfg.gnss.base.second_station_id;
        if second != 0 {
            let wrong = self.offset_arp(arp, [0.0, 40.0, 0.0]);
            let second_messages = [
                crate::rtcm_out::encode_station(second, wrong),
                crate::rtcm_out::encode_epoch(&ep, second),
            ];
            for bytes in second_messages.into_iter().flatten() {
                self.send_rtcm(&SECOND_GCS_HEADER, &bytes).await;
                self.rtcm_seq = self.rtcm_seq.wrapping_add(1);
            }
        }
    }

    /// The base's antenna position `arp` (ECEF, m) moved by `d_ned_m` (NED).
    fn offset_arp(&self, arp: [f64; 3], d_ned_m: [f64; 3]) -> [f64; 3] {
        let o = self.ds.cfg.gnss.origin_llh;
        let frame = cmsckf_models::geodesy::NedFrame::from_llh_deg(o[0], o[1], o[2]);
        let d = frame.to_ecef(&nalgebra::Vector3::from(d_ned_m)) - frame.to_ecef(&nalgebra::Vector3::zeros());
        [arp[0] + d.x, arp[1] + d.y, arp[2] + d.z]
    }

    /// One message of the rover's receiver: to its own port when it has
    /// one, else relayed by the autopilot in `GPS_RTCM_DATA`.
    async fn send_receiver(&self, bytes: &[u8]) {
        match &self.receiver_port {
            Some(port) => port.write(bytes).await,
            None => self.send_rtcm(&HEADER, bytes).await,
        }
    }

    /// Sends one RTCM message in `GPS_RTCM_DATA` under the current sequence
    /// number, from `header`'s system.
    async fn send_rtcm(&self, header: &MavHeader, bytes: &[u8]) {
        for f in rtcm_fragments(bytes, self.rtcm_seq) {
            let _ = self.conn.send(header, &apm::MavMessage::GPS_RTCM_DATA(f)).await;
        }
    }
}
