//! RTCM3 framing and decoding into the GNSS module's own types.
//!
//! Framing is done by `super::framing` (shared with UBX), over a bounded
//! buffer, so that every bad frame is seen and counted: a frame whose CRC-24Q
//! fails is skipped one byte at a time until the stream resynchronises. The
//! checked frame is decoded by the `rtcm-rs` crate; MSM4–MSM7 (GPS
//! 1074–1077, Galileo 1094–1097) and the ephemerides (1019 GPS, 1045/1046
//! Galileo) are converted to SI units here (the ephemeris mappings are
//! shared with the simulator's encoder).

use std::collections::BTreeMap;

use rtcm_rs::{Message, MessageFrame};

use super::framing;

/// A GLONASS ephemeris as MT1020 carries it.
pub type Msg1020 = rtcm_rs::msg::Msg1020T;

use cmsckf_models::geodesy::C_MPS;
use cmsckf_models::gnss::BroadcastEphemeris;
pub use cmsckf_models::gnss::System;

/// One signal of one satellite.
#[derive(Clone, Debug, PartialEq)]
pub struct SignalObs {
    /// RINEX-style code: band and attribute, e.g. `('1', 'C')`.
    pub band: u8,
    pub attribute: char,
    pub pseudorange_m: Option<f64>,
    /// Range rate from the Doppler (MSM5/MSM7), m/s.
    pub range_rate_mps: Option<f64>,
    /// Carrier-to-noise density; `None` when the message carries none (0 is
    /// "not given", not "no signal").
    pub cnr_dbhz: Option<f64>,
}

/// One satellite of an MSM epoch.
#[derive(Clone, Debug, PartialEq)]
pub struct SatObs {
    pub system: System,
    pub prn: u8,
    pub signals: Vec<SignalObs>,
}

/// One MSM message: one constellation at one epoch.
#[derive(Clone, Debug, PartialEq)]
pub struct MsmEpoch {
    pub system: System,
    pub msg_type: u16,
    pub station_id: u16,
    /// Epoch time of week (s): RTCM's whole milliseconds on the GPS scale
    /// (BeiDou's BDT + 14 s), the receiver's own time tag in UBX; for
    /// GLONASS, UTC (Moscow time − 3 h), see `utc`.
    pub tow_s: f64,
    /// `tow_s` is a UTC time of week (GLONASS): the receiver adds GPS − UTC
    /// of the day, which the message does not carry.
    pub utc: bool,
    /// GLONASS MSM without its day of week (7): `tow_s` is only known modulo
    /// a day, and the receiver places it near its other epochs.
    pub day_unknown: bool,
    /// More MSMs of the same epoch follow.
    pub multiple: bool,
    pub sats: Vec<SatObs>,
}

/// An ephemeris as broadcast, its truncated week still to be resolved: GPS
/// weeks modulo 1024 (1019), Galileo GST weeks modulo 4096 (1045/1046).
#[derive(Clone, Debug, PartialEq)]
pub struct RawEph {
    pub week_field: u16,
    pub eph: BroadcastEphemeris,
}

impl RawEph {
    /// The full GPS week of the ephemeris, the one nearest `hint_week`.
    pub fn full_week(&self, hint_week: u32) -> u32 {
        match self.eph.system {
            System::Gps | System::Qzss | System::Glonass => resolve_week(self.week_field, hint_week),
            // BDT week 0 is GPS week 1356 (2006-01-01); 13 bits. The
            // ephemeris was built from the truncated week: its toe may
            // already have carried into the next GPS week.
            System::BeiDou => {
                let carry = self.eph.week.saturating_sub(self.week_field as u32 + 1356);
                1356 + resolve_mod(self.week_field as u32 % 8192, 8192, hint_week.saturating_sub(1356)) + carry
            }
            // GST week 0 is GPS week 1024 (1999-08-22).
            System::Galileo => 1024 + resolve_mod(self.week_field as u32 % 4096, 4096, hint_week.saturating_sub(1024)),
        }
    }
}

/// A decoded RTCM message.
#[derive(Clone, Debug, PartialEq)]
pub enum GnssMessage {
    Msm(MsmEpoch),
    Eph(RawEph),
    /// A GLONASS ephemeris (MT1020), as broadcast.
    GlonassEph(Box<Msg1020>),
    /// A reference station's antenna position (MT1005/1006): what a base
    /// station sends, so that its observations are told from the rover's.
    Station {
        station_id: u16,
        arp_ecef_m: [f64; 3],
    },
    /// A valid frame of a type this module does not use.
    Other(u16),
}

/// Counts of what the decoder saw.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DecodeStats {
    pub frames_by_type: BTreeMap<u16, u64>,
    pub crc_failures: u64,
    pub undecodable: u64,
    pub bytes_skipped: u64,
    /// Bytes left in the buffer at the end (a truncated last frame).
    pub trailing_bytes: u64,
}

/// Largest RTCM3 frame: 3 header + 1023 payload + 3 CRC.
const MAX_FRAME: usize = 1029;

/// Streaming decoder with a bounded buffer.
#[derive(Default)]
pub struct RtcmDecoder {
    buf: Vec<u8>,
    pub stats: DecodeStats,
}

impl RtcmDecoder {
    pub fn new() -> Self {
        Self {
            buf: Vec::with_capacity(4 * MAX_FRAME),
            stats: DecodeStats::default(),
        }
    }

    /// Bytes held for an incomplete frame (never more than two frames' worth).
    pub fn buffered(&self) -> usize {
        self.buf.len()
    }

    /// Feeds bytes; returns the messages completed by them.
    pub fn push(&mut self, bytes: &[u8], out: &mut Vec<GnssMessage>) {
        self.stats.trailing_bytes = framing::push(self, bytes, out) as u64;
    }
}

/// RTCM3 frames: preamble 0xD3, six reserved bits (zero) and a 10-bit
/// length, the payload and a CRC-24Q. A frame whose CRC fails is counted,
/// but its preamble byte not as skipped.
impl framing::Format for RtcmDecoder {
    type Message = GnssMessage;
    const SYNC: &'static [u8] = &[0xD3];
    const HEADER: usize = 3;
    const MAX_FRAME: usize = MAX_FRAME;
    const COUNT_FAILED_FRAME_SKIPPED: bool = false;

    fn buffer(&mut self) -> &mut Vec<u8> {
        &mut self.buf
    }

    fn bytes_skipped(&mut self) -> &mut u64 {
        &mut self.stats.bytes_skipped
    }

    fn frame_len(&mut self, header: &[u8]) -> Result<usize, usize> {
        if header[1] & 0xFC != 0 {
            // Reserved bits set: not a frame start.
            return Err(1);
        }
        Ok(((((header[1] & 0x03) as usize) << 8) | header[2] as usize) + 6)
    }

    fn frame(&mut self, frame: &[u8], out: &mut Vec<GnssMessage>) -> bool {
        match MessageFrame::new(frame) {
            Ok(checked) => {
                let t = checked.message_number().unwrap_or(0);
                *self.stats.frames_by_type.entry(t).or_default() += 1;
                match convert(t, checked.get_message()) {
                    Some(m) => out.push(m),
                    None => self.stats.undecodable += 1,
                }
                true
            }
            Err(_) => {
                self.stats.crc_failures += 1;
                false
            }
        }
    }
}

/// One MSM4–MSM7 message `$v` (of type `$t`) of system `$sys` as an
/// [`MsmEpoch`] in SI units. The message types differ in their field names
/// (`$epoch`, `$fine`, `$cnr`) and in whether they carry range rates
/// (`rate: yes | no`), hence a macro rather than a function.
macro_rules! msm_epoch {
    ($t:ident, $v:ident, $sys:expr, tow: $tow:expr, $fine:ident, rate: $rate:tt, cnr: $cnr:ident) => {{
        let d = &$v.data_segment;
        let mut sats = Vec::with_capacity(d.satellite_data.len());
        for s in d.satellite_data.iter() {
            let rough_ms = s.gnss_satellite_rough_range_integer_ms.map(|n| n as f64 + s.gnss_satellite_rough_range_mod1ms_ms);
            let rough_rate = msm_epoch!(@rough_rate $rate, s);
            let mut signals = Vec::new();
            for g in d.signal_data.iter().filter(|g| g.satellite_id == s.satellite_id) {
                let pr = match (rough_ms, g.$fine) {
                    (Some(r), Some(f)) => Some((r + f) * C_MPS * 1e-3),
                    _ => None,
                };
                signals.push(SignalObs {
                    band: g.signal_id.band(),
                    attribute: g.signal_id.attribute(),
                    pseudorange_m: pr,
                    range_rate_mps: msm_epoch!(@fine_rate $rate, rough_rate, g),
                    cnr_dbhz: g.$cnr.map(|c| c as f64),
                });
            }
            sats.push(SatObs {
                system: $sys,
                prn: s.satellite_id,
                signals,
            });
        }
        Some(GnssMessage::Msm(MsmEpoch {
            system: $sys,
            msg_type: $t,
            station_id: $v.reference_station_id,
            tow_s: $tow.0,
            utc: $sys == System::Glonass,
            day_unknown: $tow.1,
            multiple: $v.msm_multiple_message_flag != 0,
            sats,
        }))
    }};
    (@rough_rate yes, $s:ident) => { $s.gnss_satellite_rough_phaserange_rates_m_s };
    (@rough_rate no, $s:ident) => { None::<i16> };
    (@fine_rate yes, $r:ident, $g:ident) => {
        match ($r, $g.gnss_signal_fine_phaserange_rate_m_s) {
            (Some(r), Some(f)) => Some(r as f64 + f),
            _ => None,
        }
    };
    (@fine_rate no, $r:ident, $g:ident) => {{ let _ = $r; None }};
}

/// A checked frame's message, of type `t`, in the GNSS module's types:
/// `None` when it cannot be decoded.
fn convert(t: u16, m: Message) -> Option<GnssMessage> {
    match m {
        Message::Msg1074(v) => {
            msm_epoch!(t, v, System::Gps, tow: (v.gps_epoch_time_ms as f64 * 1e-3, false), gnss_signal_fine_pseudorange_ms, rate: no, cnr: gnss_signal_cnr_dbhz)
        }
        Message::Msg1075(v) => {
            msm_epoch!(t, v, System::Gps, tow: (v.gps_epoch_time_ms as f64 * 1e-3, false), gnss_signal_fine_pseudorange_ms, rate: yes, cnr: gnss_signal_cnr_dbhz)
        }
        Message::Msg1076(v) => {
            msm_epoch!(t, v, System::Gps, tow: (v.gps_epoch_time_ms as f64 * 1e-3, false), gnss_signal_fine_pseudorange_ext_ms, rate: no, cnr: gnss_signal_cnr_ext_dbhz)
        }
        Message::Msg1077(v) => {
            msm_epoch!(t, v, System::Gps, tow: (v.gps_epoch_time_ms as f64 * 1e-3, false), gnss_signal_fine_pseudorange_ext_ms, rate: yes, cnr: gnss_signal_cnr_ext_dbhz)
        }
        Message::Msg1084(v) => {
            msm_epoch!(t, v, System::Glonass, tow: glonass_tow(v.glo_day_of_week, v.glo_epoch_time_ms), gnss_signal_fine_pseudorange_ms, rate: no, cnr: gnss_signal_cnr_dbhz)
        }
        Message::Msg1085(v) => {
            msm_epoch!(t, v, System::Glonass, tow: glonass_tow(v.glo_day_of_week, v.glo_epoch_time_ms), gnss_signal_fine_pseudorange_ms, rate: yes, cnr: gnss_signal_cnr_dbhz)
        }
        Message::Msg1086(v) => {
            msm_epoch!(t, v, System::Glonass, tow: glonass_tow(v.glo_day_of_week, v.glo_epoch_time_ms), gnss_signal_fine_pseudorange_ext_ms, rate: no, cnr: gnss_signal_cnr_ext_dbhz)
        }
        Message::Msg1087(v) => {
            msm_epoch!(t, v, System::Glonass, tow: glonass_tow(v.glo_day_of_week, v.glo_epoch_time_ms), gnss_signal_fine_pseudorange_ext_ms, rate: yes, cnr: gnss_signal_cnr_ext_dbhz)
        }
        Message::Msg1094(v) => {
            msm_epoch!(t, v, System::Galileo, tow: (v.gal_epoch_time_ms as f64 * 1e-3, false), gnss_signal_fine_pseudorange_ms, rate: no, cnr: gnss_signal_cnr_dbhz)
        }
        Message::Msg1095(v) => {
            msm_epoch!(t, v, System::Galileo, tow: (v.gal_epoch_time_ms as f64 * 1e-3, false), gnss_signal_fine_pseudorange_ms, rate: yes, cnr: gnss_signal_cnr_dbhz)
        }
        Message::Msg1096(v) => {
            msm_epoch!(t, v, System::Galileo, tow: (v.gal_epoch_time_ms as f64 * 1e-3, false), gnss_signal_fine_pseudorange_ext_ms, rate: no, cnr: gnss_signal_cnr_ext_dbhz)
        }
        Message::Msg1097(v) => {
            msm_epoch!(t, v, System::Galileo, tow: (v.gal_epoch_time_ms as f64 * 1e-3, false), gnss_signal_fine_pseudorange_ext_ms, rate: yes, cnr: gnss_signal_cnr_ext_dbhz)
        }
        Message::Msg1114(v) => {
            msm_epoch!(t, v, System::Qzss, tow: (v.qzss_epoch_time_ms as f64 * 1e-3, false), gnss_signal_fine_pseudorange_ms, rate: no, cnr: gnss_signal_cnr_dbhz)
        }
        Message::Msg1115(v) => {
            msm_epoch!(t, v, System::Qzss, tow: (v.qzss_epoch_time_ms as f64 * 1e-3, false), gnss_signal_fine_pseudorange_ms, rate: yes, cnr: gnss_signal_cnr_dbhz)
        }
        Message::Msg1116(v) => {
            msm_epoch!(t, v, System::Qzss, tow: (v.qzss_epoch_time_ms as f64 * 1e-3, false), gnss_signal_fine_pseudorange_ext_ms, rate: no, cnr: gnss_signal_cnr_ext_dbhz)
        }
        Message::Msg1117(v) => {
            msm_epoch!(t, v, System::Qzss, tow: (v.qzss_epoch_time_ms as f64 * 1e-3, false), gnss_signal_fine_pseudorange_ext_ms, rate: yes, cnr: gnss_signal_cnr_ext_dbhz)
        }
        Message::Msg1124(v) => {
            msm_epoch!(t, v, System::BeiDou, tow: (bdt_to_gps_tow(v.bds_epoch_time_ms), false), gnss_signal_fine_pseudorange_ms, rate: no, cnr: gnss_signal_cnr_dbhz)
        }
        Message::Msg1125(v) => {
            msm_epoch!(t, v, System::BeiDou, tow: (bdt_to_gps_tow(v.bds_epoch_time_ms), false), gnss_signal_fine_pseudorange_ms, rate: yes, cnr: gnss_signal_cnr_dbhz)
        }
        Message::Msg1126(v) => {
            msm_epoch!(t, v, System::BeiDou, tow: (bdt_to_gps_tow(v.bds_epoch_time_ms), false), gnss_signal_fine_pseudorange_ext_ms, rate: no, cnr: gnss_signal_cnr_ext_dbhz)
        }
        Message::Msg1127(v) => {
            msm_epoch!(t, v, System::BeiDou, tow: (bdt_to_gps_tow(v.bds_epoch_time_ms), false), gnss_signal_fine_pseudorange_ext_ms, rate: yes, cnr: gnss_signal_cnr_ext_dbhz)
        }
        // Legacy observations: the code's ambiguity (in 1002/1004 and
        // 1010/1012) makes the full pseudorange; without it (1001/1003,
        // 1009/1011) the code is known only modulo one (GPS) or two
        // (GLONASS) light-milliseconds, and is left out.
        Message::Msg1001(v) => legacy_epoch(
            t,
            LegacyHeader::gps(v.reference_station_id, v.gps_epoch_time_ms, v.synchronous_gnss_msg_flag),
            v.satellites
                .iter()
                .map(|s| LegacySat::gps(s.gps_satellite_id, None, None, None)),
        ),
        Message::Msg1002(v) => legacy_epoch(
            t,
            LegacyHeader::gps(v.reference_station_id, v.gps_epoch_time_ms, v.synchronous_gnss_msg_flag),
            v.satellites.iter().map(|s| {
                let l1 = s.l1_pseudorange_m.map(|p| p + s.l1_pseudorange_amb_m);
                LegacySat::gps(s.gps_satellite_id, l1, None, s.l1_cnr_dbhz)
            }),
        ),
        Message::Msg1003(v) => legacy_epoch(
            t,
            LegacyHeader::gps(v.reference_station_id, v.gps_epoch_time_ms, v.synchronous_gnss_msg_flag),
            v.satellites
                .iter()
                .map(|s| LegacySat::gps(s.gps_satellite_id, None, None, None)),
        ),
        Message::Msg1004(v) => legacy_epoch(
            t,
            LegacyHeader::gps(v.reference_station_id, v.gps_epoch_time_ms, v.synchronous_gnss_msg_flag),
            v.satellites.iter().map(|s| {
                let l1 = s.l1_pseudorange_m.map(|p| p + s.l1_pseudorange_amb_m);
                let l2 = l1.zip(s.l2_l1_pseudorange_diff_m).map(|(p, d)| p + d as f64);
                LegacySat::gps(s.gps_satellite_id, l1, l2, s.l1_cnr_dbhz)
            }),
        ),
        Message::Msg1009(v) => legacy_epoch(
            t,
            LegacyHeader::glonass(v.reference_station_id, v.glo_epoch_time_ms, v.synchronous_gnss_msg_flag),
            v.satellites
                .iter()
                .map(|s| LegacySat::glonass(s.glo_satellite_id, None, None, None)),
        ),
        Message::Msg1010(v) => legacy_epoch(
            t,
            LegacyHeader::glonass(v.reference_station_id, v.glo_epoch_time_ms, v.synchronous_gnss_msg_flag),
            v.satellites.iter().map(|s| {
                let l1 = s.l1_pseudorange_m.map(|p| p + s.l1_pseudorange_amb_m);
                LegacySat::glonass(s.glo_satellite_id, l1, None, s.l1_cnr_dbhz)
            }),
        ),
        Message::Msg1011(v) => legacy_epoch(
            t,
            LegacyHeader::glonass(v.reference_station_id, v.glo_epoch_time_ms, v.synchronous_gnss_msg_flag),
            v.satellites
                .iter()
                .map(|s| LegacySat::glonass(s.glo_satellite_id, None, None, None)),
        ),
        Message::Msg1012(v) => legacy_epoch(
            t,
            LegacyHeader::glonass(v.reference_station_id, v.glo_epoch_time_ms, v.synchronous_gnss_msg_flag),
            v.satellites.iter().map(|s| {
                let l1 = s.l1_pseudorange_m.map(|p| p + s.l1_pseudorange_amb_m);
                let l2 = l1.zip(s.l2_l1_pseudorange_diff_m).map(|(p, d)| p + d as f64);
                LegacySat::glonass(s.glo_satellite_id, l1, l2, s.l1_cnr_dbhz)
            }),
        ),
        // The weeks stay truncated until the receiver resolves them.
        Message::Msg1019(e) => Some(GnssMessage::Eph(RawEph {
            week_field: e.gps_week_number,
            eph: cmsckf_models::gnss::rtcm_eph::ephemeris_from_1019(&e, e.gps_week_number as u32),
        })),
        Message::Msg1045(e) => Some(GnssMessage::Eph(RawEph {
            week_field: e.gal_week_number,
            eph: cmsckf_models::gnss::rtcm_eph::ephemeris_from_1045(&e, e.gal_week_number as u32),
        })),
        Message::Msg1046(e) => Some(GnssMessage::Eph(RawEph {
            week_field: e.gal_week_number,
            eph: cmsckf_models::gnss::rtcm_eph::ephemeris_from_1046(&e, e.gal_week_number as u32),
        })),
        // BeiDou's week on the GPS scale is built from the truncated BDT
        // week here; `RawEph::full_week` moves it to the resolved one.
        Message::Msg1042(e) => Some(GnssMessage::Eph(RawEph {
            week_field: e.bds_week_number,
            eph: cmsckf_models::gnss::rtcm_eph::ephemeris_from_1042(&e, e.bds_week_number as u32),
        })),
        Message::Msg1044(e) => Some(GnssMessage::Eph(RawEph {
            week_field: e.qzss_week_number,
            eph: cmsckf_models::gnss::rtcm_eph::ephemeris_from_1044(&e, e.qzss_week_number as u32),
        })),
        // GLONASS's t_b is a time of the Moscow day: the receiver places it
        // with its own time.
        Message::Msg1020(e) => Some(GnssMessage::GlonassEph(Box::new(e))),
        Message::Msg1005(s) => Some(GnssMessage::Station {
            station_id: s.reference_station_id,
            arp_ecef_m: [
                s.antenna_ref_point_ecef_x_m,
                s.antenna_ref_point_ecef_y_m,
                s.antenna_ref_point_ecef_z_m,
            ],
        }),
        Message::Msg1006(s) => Some(GnssMessage::Station {
            station_id: s.reference_station_id,
            arp_ecef_m: [
                s.antenna_ref_point_ecef_x_m,
                s.antenna_ref_point_ecef_y_m,
                s.antenna_ref_point_ecef_z_m,
            ],
        }),
        Message::Empty | Message::Corrupt => None,
        _ => Some(GnssMessage::Other(t)),
    }
}

/// The header of a legacy observation message (1001–1004, 1009–1012).
struct LegacyHeader {
    system: System,
    station_id: u16,
    /// Time of week (GPS) or of the day (GLONASS, UTC), and whether the day
    /// is unknown (GLONASS: always).
    tow: (f64, bool),
    /// DF005: more observation messages of this epoch follow.
    synchronous: bool,
}

impl LegacyHeader {
    fn gps(station_id: u16, tow_ms: u32, sync: u8) -> Self {
        LegacyHeader {
            system: System::Gps,
            station_id,
            tow: (tow_ms as f64 * 1e-3, false),
            synchronous: sync != 0,
        }
    }

    /// GLONASS: DF034 is milliseconds of the Moscow day, with no day.
    fn glonass(station_id: u16, tod_ms: u32, sync: u8) -> Self {
        LegacyHeader {
            system: System::Glonass,
            station_id,
            tow: glonass_tow(None, tod_ms),
            synchronous: sync != 0,
        }
    }
}

/// One satellite of a legacy observation message: its full codes (the
/// ambiguity added), as the MSM path's signals.
struct LegacySat {
    system: System,
    /// DF009 (GPS 1–32; 40–58 are SBAS, not used) or DF038 (GLONASS slot).
    id: u8,
    l1_m: Option<f64>,
    l2_m: Option<f64>,
    cnr_dbhz: Option<f32>,
}

impl LegacySat {
    fn gps(id: u8, l1_m: Option<f64>, l2_m: Option<f64>, cnr_dbhz: Option<f32>) -> Self {
        LegacySat {
            system: System::Gps,
            id,
            l1_m,
            l2_m,
            cnr_dbhz,
        }
    }

    fn glonass(id: u8, l1_m: Option<f64>, l2_m: Option<f64>, cnr_dbhz: Option<f32>) -> Self {
        LegacySat {
            system: System::Glonass,
            id,
            l1_m,
            l2_m,
            cnr_dbhz,
        }
    }
}

/// A legacy observation message as an [`MsmEpoch`]: L1 C/A (`1C`) and,
/// where present, L2 P (`2P`) codes, no Doppler (the legacy messages carry
/// none). SBAS satellites (GPS ids 40–58) are left out. The lock-time
/// indicators and the phases matter to carrier-phase users only, and are
/// not kept.
fn legacy_epoch(t: u16, h: LegacyHeader, sats: impl Iterator<Item = LegacySat>) -> Option<GnssMessage> {
    let valid_id = |s: &LegacySat| match s.system {
        System::Gps => (1..=32).contains(&s.id),
        _ => (1..=24).contains(&s.id),
    };
    let sats = sats
        .filter(valid_id)
        .map(|s| SatObs {
            system: s.system,
            prn: s.id,
            signals: [(1, 'C', s.l1_m, s.cnr_dbhz), (2, 'P', s.l2_m, None)]
                .into_iter()
                .filter(|(band, _, p, _)| *band == 1 || p.is_some())
                .map(|(band, attribute, pseudorange_m, cnr)| SignalObs {
                    band,
                    attribute,
                    pseudorange_m: pseudorange_m.filter(|p| p.is_finite()),
                    range_rate_mps: None,
                    cnr_dbhz: cnr.map(f64::from),
                })
                .collect(),
        })
        .collect();
    Some(GnssMessage::Msm(MsmEpoch {
        system: h.system,
        msg_type: t,
        station_id: h.station_id,
        tow_s: h.tow.0,
        utc: h.system == System::Glonass,
        day_unknown: h.tow.1,
        multiple: h.synchronous,
        sats,
    }))
}

/// BeiDou time of week (ms of BDT) on the GPS scale: BDT = GPST − 14 s.
fn bdt_to_gps_tow(ms: u32) -> f64 {
    (ms as f64 * 1e-3 + 14.0).rem_euclid(604_800.0)
}

/// A GLONASS MSM epoch (day of week 0–6, 7 = unknown, and milliseconds of
/// the Moscow day, UTC + 3 h) as a UTC time of week, `day·86400 + tod −
/// 10 800`; whether the day is unknown.
fn glonass_tow(dow: Option<u8>, tod_ms: u32) -> (f64, bool) {
    let dow = dow.unwrap_or(7);
    let day = if dow < 7 { dow as f64 } else { 0.0 };
    let t = day * 86_400.0 + tod_ms as f64 * 1e-3 - 10_800.0;
    (t.rem_euclid(604_800.0), dow >= 7)
}

/// Resolves a 10-bit GPS week against a full-week hint: the full week
/// nearest to the hint with the same value modulo 1024.
pub fn resolve_week(week_mod1024: u16, hint_week: u32) -> u32 {
    resolve_mod(week_mod1024 as u32 % 1024, 1024, hint_week)
}

/// The non-negative integer nearest `hint` that is `field` modulo `modulus`.
fn resolve_mod(field: u32, modulus: u32, hint: u32) -> u32 {
    let (w, m, h) = (field as i64, modulus as i64, hint as i64);
    let base = h - h.rem_euclid(m) + w;
    let best = [base - m, base, base + m]
        .into_iter()
        .min_by_key(|c| (c - h).abs())
        .unwrap_or(base);
    best.max(0) as u32
}

#[cfg(test)]
mod tests {
    use super::*;

    fn data(name: &str) -> Vec<u8> {
        std::fs::read(
            std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("tests/data")
                .join(name),
        )
        .unwrap()
    }

    #[test]
    fn week_rollover() {
        assert_eq!(resolve_week(292, 1316), 1316);
        assert_eq!(resolve_week(293, 1316), 1317);
        assert_eq!(resolve_week(292, 2340), 2340);
        assert_eq!(resolve_week(1023, 2048), 2047);
        assert_eq!(resolve_week(0, 2047), 2048);
        // Galileo's 12-bit GST week starts at GPS week 1024 (1999-08-22) and
        // rolls over at GPS week 5120 (2078).
        let gal = |field: u16, hint: u32| {
            let mut eph = cmsckf_sitl::gnss::galileo_constellation(hint, 0.0).remove(0);
            eph.week = field as u32;
            RawEph { week_field: field, eph }.full_week(hint)
        };
        assert_eq!(gal(1419, 2443), 2443);
        assert_eq!(gal(4095, 5119), 5119);
        assert_eq!(gal(0, 5119), 5120);
        assert_eq!(gal(4095, 5121), 5119);
    }

    #[test]
    fn decodes_the_3040_stream_and_counts_its_frames() {
        let mut d = RtcmDecoder::new();
        let mut out = Vec::new();
        d.push(&data("3040_msm7.rtcm3"), &mut out);
        assert_eq!(d.stats.frames_by_type.get(&1077), Some(&120));
        assert_eq!(d.stats.frames_by_type.get(&1019), Some(&164));
        assert_eq!(d.stats.crc_failures, 0);
        let Some(GnssMessage::Msm(e)) = out.iter().find(|m| matches!(m, GnssMessage::Msm(_))) else {
            panic!()
        };
        assert_eq!(e.station_id, 3040);
        assert!(e.sats.len() >= 6);
        let pr = e.sats[0].signals[0].pseudorange_m.unwrap();
        assert!((1.9e7..2.7e7).contains(&pr), "{pr}");
        assert!(e.sats[0].signals.iter().any(|s| s.band == 1 && s.attribute == 'C'));
    }

    #[test]
    fn crc_failures_and_truncation_are_counted_and_resynchronised() {
        let mut bytes = data("3040_msm7.rtcm3");
        // Corrupt a byte inside the second frame.
        let second = bytes
            .iter()
            .enumerate()
            .skip(1)
            .find(|(_, b)| **b == 0xD3)
            .map(|(i, _)| i)
            .unwrap();
        bytes[second + 10] ^= 0xFF;
        bytes.truncate(bytes.len() - 7);
        let mut d = RtcmDecoder::new();
        let mut out = Vec::new();
        // In small pieces, as a serial port delivers them.
        for c in bytes.chunks(37) {
            d.push(c, &mut out);
        }
        assert!(d.stats.crc_failures >= 1);
        let total: u64 = d.stats.frames_by_type.values().sum();
        assert_eq!(total, 120 + 164 - 2, "one corrupted, one truncated");
        assert!(d.stats.trailing_bytes > 0);
    }
}
