//! Broadcast ephemerides on the wire: RTCM 1019 (GPS LNAV), 1045 (Galileo
//! F/NAV) and 1046 (Galileo I/NAV), both ways.
//!
//! The receiver's decoder turns decoded messages into [`BroadcastEphemeris`]
//! with these, and the simulator quantises its constellations through them
//! once at start, so the ephemerides a decoder gets are exactly the orbits the
//! truth uses. Framing and CRC-24Q are the `rtcm-rs` crate's.

use rtcm_rs::msg::{Msg1019T, Msg1045T, Msg1046T};
use rtcm_rs::{Message, MessageBuilder, MessageFrame};

use super::{BroadcastEphemeris, System};

const SC: f64 = std::f64::consts::PI;

/// Errors from encoding.
#[derive(Debug, thiserror::Error)]
pub enum RtcmEncodeError {
    #[error("RTCM encoding failed: {0:?}")]
    Encode(rtcm_rs::rtcm_error::RtcmError),
    #[error("no ephemeris encoder for system '{0}' (GPS and Galileo only)")]
    Unsupported(char),
}

fn msg1019(e: &BroadcastEphemeris) -> Msg1019T {
    Msg1019T {
        gps_satellite_id: e.prn,
        gps_week_number: (e.week % 1024) as u16,
        ura_index: e.ura_index,
        code_on_l2_ind: 1,
        idot_sc_s: e.idot_radps / SC,
        iode: (e.iode % 256) as u8,
        toc_s: e.toc_s as f32,
        af2_s_s2: e.af2_per_s as f32,
        af1_s_s: e.af1 as f32,
        af0_s: e.af0_s,
        iodc: e.iodc,
        crs_m: e.crs_m as f32,
        delta_n_sc_s: (e.delta_n_radps / SC) as f32,
        m0_sc: e.m0_rad / SC,
        cuc_rad: e.cuc_rad as f32,
        eccentricity: e.e,
        cus_rad: e.cus_rad as f32,
        sqrt_a_sqrt_m: e.sqrt_a,
        toe_s: e.toe_s as f32,
        cic_rad: e.cic_rad as f32,
        omega0_sc: e.omega0_rad / SC,
        cis_rad: e.cis_rad as f32,
        i0_sc: e.i0_rad / SC,
        crc_m: e.crc_m as f32,
        omega_sc: e.omega_rad / SC,
        omegadot_sc_s: e.omega_dot_radps / SC,
        tgd_s: e.tgd_s as f32,
        sv_health_ind: e.health,
        l2_p_data_flag: 0,
        fit_interval_ind: e.fit_interval_4h as u8,
    }
}

/// A Galileo I/NAV ephemeris as 1046: the GST week (GPS week − 1024)
/// modulo 4096; `tgd_s` is BGD(E1, E5b).
fn msg1046(e: &BroadcastEphemeris) -> Msg1046T {
    Msg1046T {
        gal_satellite_id: e.prn,
        gal_week_number: (e.week.saturating_sub(1024) % 4096) as u16,
        iodnav: e.iode % 1024,
        sisa_e1_e5b_index: e.ura_index,
        idot_sc_s: (e.idot_radps / SC) as f32,
        toc_s: e.toc_s as f32,
        af2_s_s2: e.af2_per_s as f32,
        af1_s_s: e.af1,
        af0_s: e.af0_s,
        crs_m: e.crs_m as f32,
        delta_n_sc_s: (e.delta_n_radps / SC) as f32,
        m0_sc: e.m0_rad / SC,
        cuc_rad: e.cuc_rad as f32,
        eccentricity: e.e,
        cus_rad: e.cus_rad as f32,
        sqrt_a_sqrt_m: e.sqrt_a,
        toe_s: e.toe_s as f32,
        cic_rad: e.cic_rad as f32,
        omega0_sc: e.omega0_rad / SC,
        cis_rad: e.cis_rad as f32,
        i0_sc: e.i0_rad / SC,
        crc_m: e.crc_m as f32,
        omega_sc: e.omega_rad / SC,
        omegadot_sc_s: e.omega_dot_radps / SC,
        bgd_e1_e5a_s: e.tgd_s as f32,
        bgd_e1_e5b_s: e.tgd_s as f32,
        e5b_sig_health_ind: e.health,
        e5b_data_validity_flag: 0,
        e1_b_sig_health_ind: e.health,
        e1_b_data_validity_flag: 0,
        reserved_502_2: 0,
    }
}

/// Frames the ephemeris message for `eph`: 1019 for GPS (week modulo 1024),
/// 1046 for Galileo (GST week modulo 4096).
pub fn encode_ephemeris(eph: &BroadcastEphemeris) -> Result<Vec<u8>, RtcmEncodeError> {
    let msg = match eph.system {
        System::Gps => Message::Msg1019(msg1019(eph)),
        System::Galileo => Message::Msg1046(msg1046(eph)),
        other => return Err(RtcmEncodeError::Unsupported(other.letter())),
    };
    let mut b = MessageBuilder::new();
    b.build_message(&msg)
        .map(<[u8]>::to_vec)
        .map_err(RtcmEncodeError::Encode)
}

/// The ephemeris a decoded 1019 carries (semicircles → radians), with the
/// full week `week` (1019 has it modulo 1024: the caller resolves it).
pub fn ephemeris_from_1019(m: &Msg1019T, week: u32) -> BroadcastEphemeris {
    BroadcastEphemeris {
        system: System::Gps,
        prn: m.gps_satellite_id,
        week,
        iode: m.iode as u16,
        iodc: m.iodc,
        toc_s: m.toc_s as f64,
        af0_s: m.af0_s,
        af1: m.af1_s_s as f64,
        af2_per_s: m.af2_s_s2 as f64,
        toe_s: m.toe_s as f64,
        sqrt_a: m.sqrt_a_sqrt_m,
        e: m.eccentricity,
        m0_rad: m.m0_sc * SC,
        delta_n_radps: m.delta_n_sc_s as f64 * SC,
        omega0_rad: m.omega0_sc * SC,
        omega_dot_radps: m.omegadot_sc_s * SC,
        i0_rad: m.i0_sc * SC,
        idot_radps: m.idot_sc_s * SC,
        omega_rad: m.omega_sc * SC,
        cuc_rad: m.cuc_rad as f64,
        cus_rad: m.cus_rad as f64,
        crc_m: m.crc_m as f64,
        crs_m: m.crs_m as f64,
        cic_rad: m.cic_rad as f64,
        cis_rad: m.cis_rad as f64,
        tgd_s: m.tgd_s as f64,
        health: m.sv_health_ind,
        ura_index: m.ura_index,
        fit_interval_4h: m.fit_interval_ind != 0,
    }
}

/// The Galileo fields 1045 (F/NAV) and 1046 (I/NAV) share.
macro_rules! galileo_eph {
    ($m:expr, $week:expr, $bgd:expr, $sisa:expr, $health:expr) => {{
        let m = $m;
        BroadcastEphemeris {
            system: System::Galileo,
            prn: m.gal_satellite_id,
            week: $week,
            iode: m.iodnav,
            iodc: 0,
            toc_s: m.toc_s as f64,
            af0_s: m.af0_s,
            af1: m.af1_s_s,
            af2_per_s: m.af2_s_s2 as f64,
            toe_s: m.toe_s as f64,
            sqrt_a: m.sqrt_a_sqrt_m,
            e: m.eccentricity,
            m0_rad: m.m0_sc * SC,
            delta_n_radps: m.delta_n_sc_s as f64 * SC,
            omega0_rad: m.omega0_sc * SC,
            omega_dot_radps: m.omegadot_sc_s * SC,
            i0_rad: m.i0_sc * SC,
            idot_radps: m.idot_sc_s as f64 * SC,
            omega_rad: m.omega_sc * SC,
            cuc_rad: m.cuc_rad as f64,
            cus_rad: m.cus_rad as f64,
            crc_m: m.crc_m as f64,
            crs_m: m.crs_m as f64,
            cic_rad: m.cic_rad as f64,
            cis_rad: m.cis_rad as f64,
            tgd_s: $bgd as f64,
            health: $health,
            ura_index: $sisa,
            fit_interval_4h: false,
        }
    }};
}

/// The ephemeris a decoded 1046 (Galileo I/NAV) carries, with the full GPS
/// week `week` (the caller resolves the 12-bit GST week). The E1 user's
/// group delay is BGD(E1, E5b); the satellite is healthy when both E1-B
/// and E5b report signal OK and data valid (OS SIS ICD 5.1.9.3).
pub fn ephemeris_from_1046(m: &Msg1046T, week: u32) -> BroadcastEphemeris {
    let health = m.e1_b_sig_health_ind | m.e1_b_data_validity_flag | m.e5b_sig_health_ind | m.e5b_data_validity_flag;
    galileo_eph!(m, week, m.bgd_e1_e5b_s, m.sisa_e1_e5b_index, health)
}

/// The ephemeris a decoded 1045 (Galileo F/NAV) carries; its group delay is
/// BGD(E1, E5a).
pub fn ephemeris_from_1045(m: &Msg1045T, week: u32) -> BroadcastEphemeris {
    let health = m.e5a_sig_health_ind | m.e5a_data_validity_flag;
    galileo_eph!(m, week, m.bgd_e1_e5a_s, m.sisa_e1_e5a_index, health)
}

/// Quantises an ephemeris to what its RTCM message can carry (encode, then
/// decode).
pub fn quantise(eph: &BroadcastEphemeris) -> BroadcastEphemeris {
    let Ok(bytes) = encode_ephemeris(eph) else {
        return eph.clone();
    };
    let Ok(frame) = MessageFrame::new(&bytes) else {
        return eph.clone();
    };
    match frame.get_message() {
        Message::Msg1019(m) => ephemeris_from_1019(&m, eph.week),
        Message::Msg1046(m) => ephemeris_from_1046(&m, eph.week),
        _ => eph.clone(),
    }
}
