//! The GNSS receiver's side of the link: RTCM3 observations (MSM7) and
//! broadcast ephemerides, split into MAVLink `GPS_RTCM_DATA` fragments as an
//! autopilot relays them.

use mavlink::dialects::ardupilotmega as apm;

use super::fault::{add_pr_outliers, break_crc, Active, FaultKind};
use super::stream::Streamer;
use super::ROVER_STATION_ID;

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
                for _ in 0..active.copies() {
                    self.send_rtcm(&bytes).await;
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
                self.send_rtcm(&bytes).await;
                self.rtcm_seq = self.rtcm_seq.wrapping_add(1);
            }
        }
    }

    /// Sends one RTCM message under the current sequence number.
    async fn send_rtcm(&self, bytes: &[u8]) {
        for f in rtcm_fragments(bytes, self.rtcm_seq) {
            self.send(apm::MavMessage::GPS_RTCM_DATA(f)).await;
        }
    }
}
