//! Broadcast ephemerides on the wire: RTCM 1019 (GPS LNAV), 1045 (Galileo
//! F/NAV) and 1046 (Galileo I/NAV), both ways; 1020 (GLONASS), 1042
//! (BeiDou) and 1044 (QZSS), decoded only.
//!
//! The receiver's decoder turns decoded messages into [`BroadcastEphemeris`]
//! with these, and the simulator quantises its constellations through them
//! once at start, so the ephemerides a decoder gets are exactly the orbits the
//! truth uses. Framing and CRC-24Q are the `rtcm-rs` crate's.

use nalgebra::Vector3;
use rtcm_rs::msg::{Msg1019T, Msg1020T, Msg1042T, Msg1044T, Msg1045T, Msg1046T};
use rtcm_rs::{Message, MessageBuilder, MessageFrame};

use super::ephemeris::{bdt_to_gps, BDT_GPS_OFFSET_S};
use super::glonass::{glonass_tb_to_gps, GlonassEphemeris};
use super::{BroadcastEphemeris, System, WEEK_S};

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

/// The fields GPS LNAV (1019) and QZSS (1044) share: the same message
/// layout, field for field, in types of their own.
macro_rules! lnav_eph {
    ($m:expr, $system:expr, $prn:ident, $week:expr) => {{
        let m = $m;
        BroadcastEphemeris {
            system: $system,
            prn: m.$prn,
            week: $week,
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
    }};
}

/// The ephemeris a decoded 1019 carries (semicircles → radians), with the
/// full week `week` (1019 has it modulo 1024: the caller resolves it).
pub fn ephemeris_from_1019(m: &Msg1019T, week: u32) -> BroadcastEphemeris {
    lnav_eph!(m, System::Gps, gps_satellite_id, week)
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

/// The GLONASS ephemeris a decoded 1020 carries, its t_b put on the GPS
/// scale nearest the receiver's current GPS time `ref_week`, `ref_tow_s`
/// ([`glonass_tb_to_gps`]).
///
/// Units as rtcm-rs decodes them (its data-field table applies the RTCM
/// resolutions): positions (DF112/115/118, 2⁻¹¹ km) in km, velocities
/// (DF111/114/117, 2⁻²⁰ km/s) in km/s and lunisolar accelerations
/// (DF113/116/119, 2⁻³⁰ km/s²) in km/s², all × 1000 here; t_b (DF110) in
/// minutes of the Moscow day, its 15-minute units multiplied out; τn (DF124,
/// 2⁻³⁰ s) in s; γn (DF121, 2⁻⁴⁰) dimensionless; the channel (DF040)
/// already offset to −7..=6; En (DF126) in days.
///
/// Health, 0 = healthy: bit 0 the MSB of Bn (DF108, all RTKLIB looks at);
/// bit 1 ln of string 3 (DF123, GLONASS-M); bit 2 ln of string 5 (DF136,
/// only when DF131 says the GLONASS-M fields are valid); bit 3 the almanac's
/// Cn = 0, "non-operational" (DF104, only when DF105 says it is available).
pub fn glonass_from_1020(m: &Msg1020T, ref_week: u32, ref_tow_s: f64) -> GlonassEphemeris {
    let (week, toe_s) = glonass_tb_to_gps(m.tb_min as f64, ref_week, ref_tow_s);
    let km = 1e3;
    let bn = m.glo_eph_health_flag & 1;
    let ln3 = (m.glo_m_3str_ln_flag & 1) << 1;
    let ln5 = u8::from(m.additional_data_flag != 0 && m.glo_m_5str_ln_flag != 0) << 2;
    let cn = u8::from(m.glo_alm_health_avail_flag != 0 && m.glo_alm_health_flag == 0) << 3;
    GlonassEphemeris {
        slot: m.glo_satellite_id,
        freq_channel: m.glo_satellite_freq_chan_number,
        week,
        toe_s,
        r_m: Vector3::new(m.xn_km, m.yn_km, m.zn_km) * km,
        v_mps: Vector3::new(m.xn_first_deriv_km_s, m.yn_first_deriv_km_s, m.zn_first_deriv_km_s) * km,
        a_mps2: Vector3::new(
            m.xn_second_deriv_km_s2 as f64,
            m.yn_second_deriv_km_s2 as f64,
            m.zn_second_deriv_km_s2 as f64,
        ) * km,
        tau_n_s: m.tau_n_s,
        gamma_n: m.gamma_n as f64,
        health: bn | ln3 | ln5 | cn,
        age_days: m.en_d,
    }
}

/// The BeiDou ephemeris a decoded 1042 carries, stored on the GPS scale:
/// toe and toc (DF505, DF493: BDT seconds of week, their 8 s units
/// multiplied out) become BDT + 14 s, and `week` is the GPS week of toe,
/// `bdt_week_full` + 1356, or one more when the 14 s carry toe into the next
/// GPS week ([`bdt_to_gps`]). `bdt_week_full` is DF489 (BDT week modulo
/// 8192) resolved by the caller, taken as the week of toe.
///
/// Angles semicircles → radians; a0, a1, a2 in s, s/s, s/s²; the group
/// delay is TGD1 (DF513, B1I, s); health SatH1; URA index DF490; AODE and
/// AODC are kept as IODE and IODC. `prn` is the BeiDou PRN (1–63), GEO for
/// 1–5 and 59–63.
pub fn ephemeris_from_1042(m: &Msg1042T, bdt_week_full: u32) -> BroadcastEphemeris {
    let (week, toe_s) = bdt_to_gps(bdt_week_full, m.toe_s as f64);
    let toc_s = (m.toc_s as f64 + BDT_GPS_OFFSET_S).rem_euclid(WEEK_S);
    BroadcastEphemeris {
        system: System::BeiDou,
        prn: m.bds_satellite_id,
        week,
        iode: m.aode as u16,
        iodc: m.aodc as u16,
        toc_s,
        af0_s: m.a0_s,
        af1: m.a1_s_s,
        af2_per_s: m.a2_s_s2 as f64,
        toe_s,
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
        tgd_s: m.tgd1_s as f64,
        health: m.sv_health_flag,
        ura_index: m.ura_index,
        fit_interval_4h: false,
    }
}

/// The QZSS ephemeris a decoded 1044 carries (semicircles → radians), with
/// the full GPS week `week` (DF452 is modulo 1024: the caller resolves it;
/// QZSS time is GPS time). `prn` is the RTCM QZSS satellite ID (DF429,
/// 1–10 for PRN 193–202), the numbering of the QZSS MSM satellite mask too,
/// so ephemerides and observations match. QZSS's fit-interval flag means
/// "more than 2 h" (IS-QZSS-PNT), kept in `fit_interval_4h`.
pub fn ephemeris_from_1044(m: &Msg1044T, week: u32) -> BroadcastEphemeris {
    lnav_eph!(m, System::Qzss, qzss_satellite_id, week)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geodesy::C_MPS;

    /// 1020: units (km → m), t_b on the GPS scale, and the health bits.
    #[test]
    #[allow(clippy::inconsistent_digit_grouping, clippy::excessive_precision)]
    fn glonass_1020_fields() {
        let m = Msg1020T {
            glo_satellite_id: 2,
            glo_satellite_freq_chan_number: -4,
            tb_min: 15,
            xn_km: 9_364.739_257_81,
            yn_km: -15_908.797_363_3,
            zn_km: -17_614.389_648_4,
            xn_first_deriv_km_s: -0.267_867_088_318,
            yn_first_deriv_km_s: 2.398_531_913_76,
            zn_first_deriv_km_s: -2.307_656_288_15,
            yn_second_deriv_km_s2: 1.862_645_149e-9,
            zn_second_deriv_km_s2: -2.793_967_724e-9,
            tau_n_s: -2.067_629_247_9e-5,
            gamma_n: -2.728_484_105e-12,
            en_d: 3,
            ..Default::default()
        };
        // Wednesday 21:00 UTC (GPS − UTC = 18 s) is Thursday 00:00 Moscow
        // time: t_b 00:15 MSK is Wednesday 21:15 UTC.
        let day = 86_400.0;
        let e = glonass_from_1020(&m, 2300, 3.0 * day + 75_600.0 + 18.0);
        assert_eq!((e.slot, e.freq_channel, e.age_days, e.health), (2, -4, 3, 0));
        assert_eq!(e.week, 2300);
        assert!((e.toe_s - (3.0 * day + 76_500.0 + 18.0)).abs() < 1e-6);
        let r = Vector3::new(9_364_739.257_81, -15_908_797.363_3, -17_614_389.648_4);
        assert!((e.r_m - r).norm() < 1e-6, "{:?}", e.r_m - r);
        assert!((e.v_mps.y - 2_398.531_913_76).abs() < 1e-9);
        assert!((e.a_mps2.z - -2.793_967_724e-6).abs() < 1e-12, "{}", e.a_mps2.z);
        assert_eq!(e.a_mps2.x, 0.0);
        assert_eq!(e.tau_n_s, -2.067_629_247_9e-5);
        assert!((e.gamma_n - -2.728_484_105e-12).abs() < 1e-18);

        let health = |f: fn(&mut Msg1020T)| {
            let mut m = m.clone();
            f(&mut m);
            glonass_from_1020(&m, 2300, 0.0).health
        };
        assert_eq!(health(|m| m.glo_eph_health_flag = 1), 1);
        assert_eq!(health(|m| m.glo_m_3str_ln_flag = 1), 2);
        // ln of string 5 counts only when the GLONASS-M fields are valid.
        assert_eq!(health(|m| m.glo_m_5str_ln_flag = 1), 0);
        assert_eq!(
            health(|m| {
                m.glo_m_5str_ln_flag = 1;
                m.additional_data_flag = 1;
            }),
            4
        );
        // Cn = 0 means non-operational, when the almanac health is there.
        assert_eq!(health(|m| m.glo_alm_health_avail_flag = 1), 8);
        assert_eq!(
            health(|m| {
                m.glo_alm_health_avail_flag = 1;
                m.glo_alm_health_flag = 1;
            }),
            0
        );
    }

    /// BeiDou C02 (GEO) as a 1042 carries it (semicircles, f32 fields),
    /// from the Skydel RINEX shipped with INSTINCT (BDT week 888, toe
    /// 36 000 s BDT), lands on Skydel's truth at the 36 300 s GPST epoch as
    /// the direct ephemeris does (see `ephemeris.rs`): toe and week are
    /// moved to the GPS scale, and the GEO rotation applies.
    #[test]
    #[allow(clippy::inconsistent_digit_grouping, clippy::excessive_precision)] // values as published
    fn beidou_1042_to_skydel_truth() {
        let m = Msg1042T {
            bds_satellite_id: 2,
            bds_week_number: 888,
            idot_sc_s: 5.325221816864e-10 / SC,
            toc_s: 36_000.0,
            a1_s_s: -1.344755418131e-10,
            a0_s: -6.993988063186e-5,
            crs_m: -657.25,
            delta_n_sc_s: (-2.415814914102e-9 / SC) as f32,
            m0_sc: -5.156079508322e-1 / SC,
            cuc_rad: -2.160156145692e-5,
            eccentricity: 9.540994651616e-4,
            cus_rad: 2.393499016762e-7,
            sqrt_a_sqrt_m: 6.493481067657e3,
            toe_s: 36_000.0,
            cic_rad: -1.117587089539e-8,
            omega0_sc: -5.011557524058e-1 / SC,
            cis_rad: 9.080395102501e-8,
            i0_sc: 1.125395887542e-1 / SC,
            crc_m: -4.96875,
            omega_sc: -1.175464677199 / SC,
            omegadot_sc_s: 3.626579633027e-9 / SC,
            tgd1_s: 1.4e-9,
            tgd2_s: -1.42e-8,
            ..Default::default()
        };
        let e = ephemeris_from_1042(&m, 888);
        assert_eq!((e.system, e.prn, e.week), (System::BeiDou, 2, 2244));
        assert_eq!((e.toe_s, e.toc_s), (36_014.0, 36_014.0));
        assert!(e.is_beidou_geo());
        let st = e.state(36_300.0 - 36_948_927.97992 / C_MPS);
        let want = Vector3::new(4_456_433.905018, 41_880_148.90687, -1_054_098.955061);
        assert!((st.r_ecef_m - want).norm() < 0.05, "{:?}", st.r_ecef_m - want);
        assert!((st.dt_s - -6.997_841_600_047e-5).abs() < 1e-13, "{}", st.dt_s);

        // A toe 8 s before the end of the BDT week is 6 s into the next GPS
        // week.
        let late = Msg1042T {
            toe_s: 604_792.0,
            toc_s: 604_792.0,
            ..m
        };
        let e = ephemeris_from_1042(&late, 888);
        assert_eq!((e.week, e.toe_s, e.toc_s), (2245, 6.0, 6.0));
    }

    /// 1044: QZSS in GPS's model, the RTCM satellite ID kept as `prn`.
    #[test]
    fn qzss_1044_fields() {
        let m = Msg1044T {
            qzss_satellite_id: 3,
            toc_s: 7_200.0,
            toe_s: 7_200.0,
            af0_s: 1e-5,
            af1_s_s: 2e-12,
            m0_sc: 0.25,
            i0_sc: 0.5,
            omega0_sc: -0.75,
            omega_sc: 0.125,
            omegadot_sc_s: -1e-9,
            idot_sc_s: 2e-11,
            delta_n_sc_s: 1e-9,
            sqrt_a_sqrt_m: 6_493.0,
            eccentricity: 0.075,
            qzss_week_number: 196,
            ura_index: 1,
            sv_health_ind: 0,
            tgd_s: -3e-9,
            iode: 17,
            iodc: 273,
            fit_interval_ind: 1,
            ..Default::default()
        };
        let e = ephemeris_from_1044(&m, 2244);
        assert_eq!(
            (e.system, e.prn, e.week, e.iode, e.iodc),
            (System::Qzss, 3, 2244, 17, 273)
        );
        assert_eq!((e.toe_s, e.toc_s), (7_200.0, 7_200.0));
        let pi = std::f64::consts::PI;
        assert_eq!(
            (e.m0_rad, e.i0_rad, e.omega0_rad, e.omega_rad),
            (0.25 * pi, 0.5 * pi, -0.75 * pi, 0.125 * pi)
        );
        assert!((e.omega_dot_radps - -1e-9 * pi).abs() < 1e-24);
        assert!((e.delta_n_radps - 1e-9 * pi).abs() < 1e-15);
        assert!((e.tgd_s - -3e-9).abs() < 1e-15);
        assert!(e.fit_interval_4h && !e.is_beidou_geo());
        assert_eq!(e.accuracy_m(), 3.4);
    }
}
