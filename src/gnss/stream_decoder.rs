//! A receiver's byte stream in whichever format it speaks: why it exists is
//! that one port may carry RTCM3 and UBX together, and each decoder must
//! see every byte.

use super::rtcm::{self, GnssMessage};
use super::ubx;

/// A receiver's byte stream in whichever format it speaks, recognised from
/// the bytes: RTCM3 and UBX frames are both looked for in every byte (a
/// u-blox F9 can send both on one port, with NMEA between them), each by
/// its own checksum, so neither can take the other's frames.
#[derive(Default)]
pub struct StreamDecoder {
    pub rtcm: rtcm::RtcmDecoder,
    pub ubx: ubx::UbxDecoder,
}

impl StreamDecoder {
    /// Feeds bytes; returns the messages completed by them, each decoder's
    /// in the order of its frames (feed small pieces, as a port delivers
    /// them, to keep the two formats' frames in stream order too).
    pub fn push(&mut self, bytes: &[u8], out: &mut Vec<GnssMessage>) {
        self.rtcm.push(bytes, out);
        self.ubx.push(bytes, out);
    }

    /// Whether the RTCM3 decoder's counts mean anything: it has found
    /// frames, or nothing has (in a UBX-only stream its CRC failures and
    /// skipped bytes are just UBX and NMEA bytes).
    pub fn rtcm_in_use(&self) -> bool {
        !self.rtcm.stats.frames_by_type.is_empty() || self.ubx.stats.frames_by_id.is_empty()
    }

    /// The formats seen so far, by their good frames.
    pub fn formats(&self) -> &'static str {
        let rtcm = !self.rtcm.stats.frames_by_type.is_empty();
        let ubx = !self.ubx.stats.frames_by_id.is_empty();
        match (rtcm, ubx) {
            (true, true) => "RTCM3 and UBX",
            (true, false) => "RTCM3",
            (false, true) => "UBX",
            (false, false) => "none recognised",
        }
    }
}
