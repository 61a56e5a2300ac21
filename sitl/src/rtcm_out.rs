//! RTCM3 output of the simulated receiver: MSM7 (1077) observations and
//! 1019 ephemerides, as a u-blox-class receiver would stream them, ready to
//! travel inside MAVLink `GPS_RTCM_DATA`.
//!
//! Encoding and framing (CRC-24Q) are the `rtcm-rs` crate's. The simulated
//! constellation is quantised through 1019 once at start, so the broadcast
//! ephemerides a decoder gets are exactly the orbits the truth uses.

use rtcm_rs::msg::{GpsSigId, Msg1019T, Msg1077Data, Msg1077Sig, Msg1077T, Msm57Sat};
use rtcm_rs::util::DataVec;
use rtcm_rs::{Message, MessageBuilder, MessageFrame};

use crate::geodesy::C_MPS;
use crate::gnss::{GnssEpoch, GpsEphemeris};

const SC: f64 = std::f64::consts::PI;

/// Errors from encoding.
#[derive(Debug, thiserror::Error)]
pub enum RtcmOutError {
    #[error("RTCM encoding failed: {0:?}")]
    Encode(rtcm_rs::rtcm_error::RtcmError),
}

fn msg1019(e: &GpsEphemeris) -> Msg1019T {
    Msg1019T {
        gps_satellite_id: e.prn,
        gps_week_number: (e.week % 1024) as u16,
        ura_index: e.ura_index,
        code_on_l2_ind: 1,
        idot_sc_s: e.idot_radps / SC,
        iode: e.iode,
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

/// Frames a 1019 message for `eph` (full week kept modulo 1024).
pub fn encode_ephemeris(eph: &GpsEphemeris) -> Result<Vec<u8>, RtcmOutError> {
    let mut b = MessageBuilder::new();
    b.build_message(&Message::Msg1019(msg1019(eph)))
        .map(<[u8]>::to_vec)
        .map_err(RtcmOutError::Encode)
}

/// The ephemeris a decoded 1019 carries (semicircles → radians), with the
/// full week `week` (1019 has it modulo 1024: the caller resolves it).
pub fn ephemeris_from_1019(m: &Msg1019T, week: u32) -> GpsEphemeris {
    GpsEphemeris {
        prn: m.gps_satellite_id,
        week,
        iode: m.iode,
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

/// Quantises an ephemeris to what 1019 can carry (encode, then decode).
pub fn quantise(eph: &GpsEphemeris) -> GpsEphemeris {
    let Ok(bytes) = encode_ephemeris(eph) else {
        return eph.clone();
    };
    let Ok(frame) = MessageFrame::new(&bytes) else {
        return eph.clone();
    };
    let Message::Msg1019(m) = frame.get_message() else {
        return eph.clone();
    };
    ephemeris_from_1019(&m, eph.week)
}

/// Frames one epoch as MSM7 (GPS L1 C/A): pseudorange split into rough
/// (1/1024 ms) and fine parts, range rate into whole and fine m/s.
pub fn encode_epoch(ep: &GnssEpoch, station_id: u16) -> Result<Vec<u8>, RtcmOutError> {
    let mut sats: DataVec<Msm57Sat, 64> = DataVec::new();
    let mut sigs: DataVec<Msg1077Sig, 64> = DataVec::new();
    let mut obs: Vec<_> = ep.sats.iter().filter(|s| (1..=64).contains(&s.prn)).collect();
    obs.sort_by_key(|s| s.prn);
    for s in obs {
        let p_ms = s.pseudorange_m / C_MPS * 1e3;
        let rough = (p_ms * 1024.0).round() / 1024.0;
        let int = rough.floor();
        let rate_rough = s.pseudorange_rate_mps.round();
        sats.push(Msm57Sat {
            satellite_id: s.prn,
            gnss_satellite_rough_range_integer_ms: Some(int as u8),
            reserved_8_4: 0,
            gnss_satellite_rough_range_mod1ms_ms: rough - int,
            gnss_satellite_rough_phaserange_rates_m_s: Some(rate_rough as i16),
        });
        sigs.push(Msg1077Sig {
            satellite_id: s.prn,
            signal_id: GpsSigId::new(1, 'C'),
            gnss_signal_fine_pseudorange_ext_ms: Some(p_ms - rough),
            gnss_signal_fine_phaserange_ext_ms: None,
            gnss_phaserange_lock_time_ext_ind: 0,
            half_cycle_ambiguity_ind: 0,
            gnss_signal_cnr_ext_dbhz: Some(s.cn0_dbhz),
            gnss_signal_fine_phaserange_rate_m_s: Some(s.pseudorange_rate_mps - rate_rough),
        });
    }
    let msg = Msg1077T {
        reference_station_id: station_id,
        gps_epoch_time_ms: (ep.tow_s * 1e3).round() as u32,
        msm_multiple_message_flag: 0,
        issue_of_data_station: None,
        reserved_58_7: 0,
        clock_steering_ind: 0,
        external_clock_ind: 0,
        gnss_smoothing_type_ind: 0,
        gnss_smoothing_interval_index: 0,
        data_segment: Msg1077Data {
            satellite_data: sats,
            signal_data: sigs,
        },
    };
    let mut b = MessageBuilder::new();
    b.build_message(&Message::Msg1077(msg))
        .map(<[u8]>::to_vec)
        .map_err(RtcmOutError::Encode)
}
