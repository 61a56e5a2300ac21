//! u-blox UBX input: a receiver on the companion computer that speaks its
//! own binary protocol rather than RTCM3. Its raw measurements (RXM-RAWX on
//! M8/F9, the legacy RXM-RAW on u-blox 5/6) become [`MsmEpoch`]s, and its
//! navigation subframes (RXM-SFRBX, legacy RXM-SFRB) become ephemerides
//! through [`super::lnav`], since u-blox receivers send no RTCM ephemeris.
//!
//! The framing is `super::framing`'s, shared with the RTCM3 decoder:
//! every frame whose Fletcher checksum fails is counted and skipped one byte
//! at a time, and bytes between frames (NMEA sentences on the same port) are
//! counted as skipped. The `ublox` crate was considered for the framing but
//! does not fit: its RXM-RAWX exposes the F9's signal id as a reserved byte
//! (so L1 and L2 of one satellite could not be told apart), it has no
//! legacy RXM-RAW/SFRB, and it neither hands out a packet's payload nor
//! counts skipped bytes.

use std::collections::BTreeMap;

use cmsckf_models::geodesy::C_MPS;

use super::framing;
use super::inav::InavAssembler;
use super::lnav::{LnavAssembler, Subframe};
use super::rtcm::{GnssMessage, MsmEpoch, SatObs, SignalObs, System};

/// Largest payload accepted: RXM-RAWX with 255 measurements (16 + 32·255).
const MAX_PAYLOAD: usize = 16 + 32 * 255;
/// GPS L1 (Hz), for the Doppler's range rate.
const F_L1_HZ: f64 = 1_575.42e6;

/// Counts of what the decoder saw.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct UbxStats {
    /// Frames with a good checksum, by `(class, id)`.
    pub frames_by_id: BTreeMap<(u8, u8), u64>,
    pub checksum_failures: u64,
    /// Frames whose declared length exceeds any raw-data message.
    pub oversize: u64,
    /// RXM frames whose payload is shorter than its own counts say.
    pub malformed: u64,
    pub bytes_skipped: u64,
    /// Bytes left in the buffer at the end (a truncated last frame).
    pub trailing_bytes: u64,
    /// Measurements of constellations this receiver model does not use
    /// (SBAS, BeiDou, QZSS, GLONASS), by UBX gnssId.
    pub unused_measurements: BTreeMap<u8, u64>,
    /// Navigation-data frames (RXM-SFRBX) of signals not decoded (all but
    /// GPS L1 C/A), by UBX gnssId.
    pub nav_not_decoded: BTreeMap<u8, u64>,
    /// GPS subframes without the TLM preamble and Galileo pages whose CRC
    /// failed, and complete subframe or word sets whose issues disagreed.
    pub bad_subframes: u64,
    pub mismatched_issues: u64,
}

/// Streaming UBX decoder with a bounded buffer.
#[derive(Default)]
pub struct UbxDecoder {
    buf: Vec<u8>,
    lnav: LnavAssembler,
    inav: InavAssembler,
    pub stats: UbxStats,
}

/// Little-endian readers over a payload known to be long enough.
fn u16_at(p: &[u8], i: usize) -> u16 {
    u16::from_le_bytes([p[i], p[i + 1]])
}
fn u32_at(p: &[u8], i: usize) -> u32 {
    u32::from_le_bytes([p[i], p[i + 1], p[i + 2], p[i + 3]])
}
fn f32_at(p: &[u8], i: usize) -> f32 {
    f32::from_le_bytes([p[i], p[i + 1], p[i + 2], p[i + 3]])
}
fn f64_at(p: &[u8], i: usize) -> f64 {
    let mut b = [0u8; 8];
    b.copy_from_slice(&p[i..i + 8]);
    f64::from_le_bytes(b)
}

/// The 8-bit Fletcher checksum over class, id, length and payload.
fn checksum(bytes: &[u8]) -> (u8, u8) {
    bytes.iter().fold((0u8, 0u8), |(a, b), x| {
        let a = a.wrapping_add(*x);
        (a, b.wrapping_add(a))
    })
}

/// UBX frames: sync 0xB5 0x62, class, id, a little-endian payload length,
/// the payload and a Fletcher checksum over class to payload. A frame whose
/// checksum fails is counted, and its first sync byte as skipped too.
impl framing::Format for UbxDecoder {
    type Message = GnssMessage;
    const SYNC: &'static [u8] = &[0xB5, 0x62];
    const HEADER: usize = 6;
    const MAX_FRAME: usize = MAX_PAYLOAD + 8;
    const COUNT_FAILED_FRAME_SKIPPED: bool = true;

    fn buffer(&mut self) -> &mut Vec<u8> {
        &mut self.buf
    }

    fn bytes_skipped(&mut self) -> &mut u64 {
        &mut self.stats.bytes_skipped
    }

    fn frame_len(&mut self, header: &[u8]) -> Result<usize, usize> {
        let len = u16_at(header, 4) as usize;
        if len > MAX_PAYLOAD {
            // No raw-data message is this long: pass over the sync.
            self.stats.oversize += 1;
            return Err(2);
        }
        Ok(len + 8)
    }

    fn frame(&mut self, frame: &[u8], out: &mut Vec<GnssMessage>) -> bool {
        let len = frame.len() - 8;
        if checksum(&frame[2..6 + len]) != (frame[6 + len], frame[7 + len]) {
            self.stats.checksum_failures += 1;
            return false;
        }
        let (class, id) = (frame[2], frame[3]);
        *self.stats.frames_by_id.entry((class, id)).or_default() += 1;
        self.payload(class, id, &frame[6..6 + len], out);
        true
    }
}

impl UbxDecoder {
    pub fn new() -> Self {
        Self::default()
    }

    /// Bytes held for an incomplete frame.
    pub fn buffered(&self) -> usize {
        self.buf.len()
    }

    /// Feeds bytes; returns the messages completed by them.
    pub fn push(&mut self, bytes: &[u8], out: &mut Vec<GnssMessage>) {
        self.stats.trailing_bytes = framing::push(self, bytes, out) as u64;
    }

    /// One checked frame's payload.
    fn payload(&mut self, class: u8, id: u8, p: &[u8], out: &mut Vec<GnssMessage>) {
        let ok = match (class, id) {
            (0x02, 0x10) => self.rxm_raw(p, out),
            (0x02, 0x15) => self.rxm_rawx(p, out),
            (0x02, 0x11) => self.rxm_sfrb(p, out),
            (0x02, 0x13) => self.rxm_sfrbx(p, out),
            _ => true,
        };
        if !ok {
            self.stats.malformed += 1;
        }
        self.stats.bad_subframes = self.lnav.bad_preamble + self.inav.crc_failures;
        self.stats.mismatched_issues = self.lnav.mismatched_issue + self.inav.mismatched_issue;
    }

    /// RXM-RAW (u-blox 5/6): `iTOW` (ms), week, `numSV`, then per satellite
    /// carrier phase, pseudorange (m), Doppler (Hz), PRN, quality, C/N0, LLI.
    /// GPS L1 C/A only; SBAS (PRN ≥ 120) is counted and skipped.
    fn rxm_raw(&mut self, p: &[u8], out: &mut Vec<GnssMessage>) -> bool {
        if p.len() < 8 || p.len() < 8 + 24 * p[6] as usize {
            return false;
        }
        let itow_ms = u32_at(p, 0) as i32;
        let mut sats = Vec::with_capacity(p[6] as usize);
        for k in 0..p[6] as usize {
            let m = &p[8 + 24 * k..8 + 24 * (k + 1)];
            let prn = m[20];
            if !(1..=32).contains(&prn) {
                *self.stats.unused_measurements.entry(1).or_default() += 1;
                continue;
            }
            let pr = f64_at(m, 8);
            let doppler = f32_at(m, 16) as f64;
            sats.push(SatObs {
                system: System::Gps,
                prn,
                signals: vec![signal(1, 'C', pr, doppler, F_L1_HZ, m[22] as i8 as f64)],
            });
        }
        if itow_ms < 0 {
            return false;
        }
        out.push(epoch(System::Gps, 0x0210, itow_ms as f64 * 1e-3, false, sats));
        true
    }

    /// RXM-RAWX (M8/F9): receiver time of week (s), then 32 bytes per
    /// signal: pseudorange (valid when `trkStat` bit 0), Doppler, gnssId,
    /// svId, sigId (F9; 0 on M8), C/N0. GPS and Galileo signals become one
    /// MSM-like epoch per constellation.
    fn rxm_rawx(&mut self, p: &[u8], out: &mut Vec<GnssMessage>) -> bool {
        if p.len() < 16 || p.len() < 16 + 32 * p[11] as usize {
            return false;
        }
        let tow_s = f64_at(p, 0);
        if !(0.0..604_800.0).contains(&tow_s) {
            return false;
        }
        let mut by_system: BTreeMap<System, Vec<SatObs>> = BTreeMap::new();
        for k in 0..p[11] as usize {
            let m = &p[16 + 32 * k..16 + 32 * (k + 1)];
            let (gnss_id, sv, sig) = (m[20], m[21], m[22]);
            let (system, band, attribute, f_hz) = match (gnss_id, sig) {
                (0, 0) => (System::Gps, 1, 'C', F_L1_HZ),
                (0, 3) => (System::Gps, 2, 'L', 1_227.60e6),
                (0, 4) => (System::Gps, 2, 'S', 1_227.60e6),
                (0, 6) => (System::Gps, 5, 'I', 1_176.45e6),
                (0, 7) => (System::Gps, 5, 'Q', 1_176.45e6),
                (2, 0) => (System::Galileo, 1, 'C', F_L1_HZ),
                (2, 1) => (System::Galileo, 1, 'B', F_L1_HZ),
                (2, 3) => (System::Galileo, 5, 'I', 1_176.45e6),
                (2, 4) => (System::Galileo, 5, 'Q', 1_176.45e6),
                (2, 5) => (System::Galileo, 7, 'I', 1_207.14e6),
                (2, 6) => (System::Galileo, 7, 'Q', 1_207.14e6),
                _ => {
                    *self.stats.unused_measurements.entry(gnss_id).or_default() += 1;
                    continue;
                }
            };
            let pr = if m[30] & 1 == 1 { f64_at(m, 0) } else { f64::NAN };
            let g = signal(band, attribute, pr, f32_at(m, 16) as f64, f_hz, m[26] as f64);
            let sats = by_system.entry(system).or_default();
            match sats.iter_mut().find(|s| s.prn == sv) {
                Some(s) => s.signals.push(g),
                None => sats.push(SatObs {
                    system,
                    prn: sv,
                    signals: vec![g],
                }),
            }
        }
        let n = by_system.len();
        if n == 0 {
            out.push(epoch(System::Gps, 0x0215, tow_s, false, Vec::new()));
        }
        for (k, (system, sats)) in by_system.into_iter().enumerate() {
            out.push(epoch(system, 0x0215, tow_s, k + 1 < n, sats));
        }
        true
    }

    /// RXM-SFRB (u-blox 5/6): channel, PRN, ten words with the 24 data bits
    /// in bits 23–0 (the upper byte is not zero on every receiver: masked).
    fn rxm_sfrb(&mut self, p: &[u8], out: &mut Vec<GnssMessage>) -> bool {
        if p.len() < 42 {
            return false;
        }
        let prn = p[1];
        if !(1..=32).contains(&prn) {
            return true; // SBAS messages
        }
        let sf: Subframe = std::array::from_fn(|k| u32_at(p, 2 + 4 * k) & 0x00FF_FFFF);
        out.extend(self.lnav.push(prn, sf).map(GnssMessage::Eph));
        true
    }

    /// RXM-SFRBX (M8/F9): gnssId, svId, the number of words, then the words.
    /// GPS L1 C/A: ten 30-bit words in bits 29–0, data bits 29–6 (parity in
    /// 5–0). Galileo E1-B I/NAV: eight (or nine) words of one page, even
    /// and odd parts ([`super::inav`]). Other signals' navigation data are
    /// counted, not decoded.
    fn rxm_sfrbx(&mut self, p: &[u8], out: &mut Vec<GnssMessage>) -> bool {
        if p.len() < 8 || p.len() < 8 + 4 * p[4] as usize {
            return false;
        }
        let (gnss_id, prn, n) = (p[0], p[1], p[4] as usize);
        let words: Vec<u32> = (0..n).map(|k| u32_at(p, 8 + 4 * k)).collect();
        match (gnss_id, n) {
            (0, 10) => {
                let sf: Subframe = std::array::from_fn(|k| (words[k] >> 6) & 0x00FF_FFFF);
                out.extend(self.lnav.push(prn, sf).map(GnssMessage::Eph));
            }
            (2, 8..) => out.extend(self.inav.push(prn, &words).map(GnssMessage::Eph)),
            _ => *self.stats.nav_not_decoded.entry(gnss_id).or_default() += 1,
        }
        true
    }
}

/// One signal: pseudorange `pr` (NaN or out of range: none), Doppler (Hz,
/// positive approaching) on `f_hz` as a range rate, C/N0 (0: not given).
fn signal(band: u8, attribute: char, pr: f64, doppler_hz: f64, f_hz: f64, cnr: f64) -> SignalObs {
    SignalObs {
        band,
        attribute,
        pseudorange_m: Some(pr).filter(|p| p.is_finite() && (1.0e7..=4.0e7).contains(p)),
        range_rate_mps: Some(-doppler_hz * C_MPS / f_hz).filter(|r| r.is_finite() && r.abs() < 1.0e4),
        cnr_dbhz: Some(cnr).filter(|c| *c > 0.0),
    }
}

fn epoch(system: System, msg_type: u16, tow_s: f64, multiple: bool, sats: Vec<SatObs>) -> GnssMessage {
    GnssMessage::Msm(MsmEpoch {
        system,
        msg_type,
        station_id: 0,
        tow_s,
        utc: false,
        day_unknown: false,
        multiple,
        sats,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A UBX frame around `payload`.
    fn frame(class: u8, id: u8, payload: &[u8]) -> Vec<u8> {
        let mut f = vec![0xB5, 0x62, class, id];
        f.extend_from_slice(&(payload.len() as u16).to_le_bytes());
        f.extend_from_slice(payload);
        let (a, b) = checksum(&f[2..]);
        f.extend_from_slice(&[a, b]);
        f
    }

    /// One RXM-RAWX measurement.
    fn meas(pr: f64, doppler: f32, gnss: u8, sv: u8, sig: u8, trk: u8) -> Vec<u8> {
        let mut m = Vec::new();
        m.extend_from_slice(&pr.to_le_bytes());
        m.extend_from_slice(&0f64.to_le_bytes());
        m.extend_from_slice(&doppler.to_le_bytes());
        m.extend_from_slice(&[gnss, sv, sig, 0, 0, 0, 42, 0, 0, 0, trk, 0]);
        m
    }

    /// An F9's RXM-RAWX with GPS L1 C/A and L2 CL of one satellite, a
    /// Galileo E1 and a BeiDou signal, among NMEA and after a frame with a
    /// bad checksum: one epoch per constellation at the receiver's exact
    /// time tag, L1 and L2 on one satellite, the Doppler as a range rate,
    /// an invalid pseudorange dropped, BeiDou counted.
    #[test]
    fn rawx_signals_by_constellation() {
        let tow: f64 = 345_600.123_456_7;
        let mut p = Vec::new();
        p.extend_from_slice(&tow.to_le_bytes());
        p.extend_from_slice(&2400u16.to_le_bytes());
        p.extend_from_slice(&[18, 5, 0, 1, 0, 0]);
        p.extend(meas(2.1e7, 1000.0, 0, 7, 0, 1));
        p.extend(meas(2.1e7 + 3.0, 779.0, 0, 7, 3, 1));
        p.extend(meas(2.4e7, -500.0, 2, 11, 1, 1));
        p.extend(meas(2.2e7, 0.0, 0, 9, 0, 0));
        p.extend(meas(3.8e7, 0.0, 3, 20, 0, 1));
        let mut bytes = b"$GPGGA,junk*00\r\n".to_vec();
        let mut bad = frame(0x02, 0x15, &p);
        bad[10] ^= 1;
        bytes.extend(bad);
        bytes.extend(frame(0x02, 0x15, &p));
        let mut d = UbxDecoder::new();
        let mut out = Vec::new();
        for piece in bytes.chunks(7) {
            d.push(piece, &mut out);
        }
        assert_eq!(d.stats.checksum_failures, 1);
        assert_eq!(d.stats.unused_measurements.get(&3), Some(&1));
        assert_eq!(out.len(), 2);
        let GnssMessage::Msm(gps) = &out[0] else { panic!() };
        let GnssMessage::Msm(gal) = &out[1] else { panic!() };
        assert_eq!((gps.system, gps.tow_s, gps.multiple), (System::Gps, tow, true));
        assert_eq!((gal.system, gal.multiple), (System::Galileo, false));
        let g7 = gps.sats.iter().find(|s| s.prn == 7).unwrap();
        assert_eq!(g7.signals.len(), 2);
        assert_eq!((g7.signals[1].band, g7.signals[1].attribute), (2, 'L'));
        let rate = g7.signals[0].range_rate_mps.unwrap();
        assert!((rate + 1000.0 * C_MPS / F_L1_HZ).abs() < 1e-9, "{rate}");
        let g9 = gps.sats.iter().find(|s| s.prn == 9).unwrap();
        assert_eq!(g9.signals[0].pseudorange_m, None, "trkStat bit 0 clear");
        assert_eq!(gal.sats[0].signals[0].attribute, 'B');
    }

    /// RXM-SFRBX words carry the 24 data bits in bits 29–6: three GPS
    /// subframes so framed make the ephemeris whose fields were written.
    #[test]
    fn sfrbx_subframes_make_an_ephemeris() {
        use crate::gnss::lnav::tests::put;
        let mut sfs = [[0u32; 10]; 3];
        for (k, sf) in sfs.iter_mut().enumerate() {
            put(sf, 0, 8, 0x8B);
            put(sf, 43, 3, k as i64 + 1);
        }
        put(&mut sfs[0], 24, 17, 57_600); // HOW TOW: 345 600 s
        put(&mut sfs[0], 48, 10, 352); // week 2400 mod 1024
        put(&mut sfs[0], 168, 8, 33);
        put(&mut sfs[0], 216, 22, -1000); // af0
        put(&mut sfs[1], 48, 8, 33);
        put(&mut sfs[1], 184, 32, 2_702_000_000); // √A·2¹⁹
        put(&mut sfs[1], 216, 16, 21_825); // toe 349 200 s
        put(&mut sfs[2], 216, 8, 33);
        put(&mut sfs[2], 112, 32, 0x2000_0000); // i0 = 0.25 semicircles
        let mut bytes = Vec::new();
        for sf in &sfs {
            let mut p = vec![0, 12, 0, 0, 10, 3, 2, 0];
            for w in sf {
                // Data bits 29..6, made-up parity in 5..0.
                p.extend_from_slice(&((w << 6) | 0x2A).to_le_bytes());
            }
            bytes.extend(frame(0x02, 0x13, &p));
        }
        let mut d = UbxDecoder::new();
        let mut out = Vec::new();
        d.push(&bytes, &mut out);
        let [GnssMessage::Eph(raw)] = &out[..] else {
            panic!("{out:?}")
        };
        assert_eq!((raw.eph.prn, raw.week_field, raw.full_week(2400)), (12, 352, 2400));
        assert_eq!((raw.eph.iode, raw.eph.iodc, raw.eph.toe_s), (33, 33, 349_200.0));
        assert!((raw.eph.af0_s + 1000.0 * 2f64.powi(-31)).abs() < 1e-20);
        assert!((raw.eph.sqrt_a - 2_702_000_000.0 / 524_288.0).abs() < 1e-9);
        assert!((raw.eph.i0_rad - 0.25 * std::f64::consts::PI).abs() < 1e-12);
    }
}
