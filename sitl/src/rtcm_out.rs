//! RTCM3 output of the simulated receiver: MSM7 observations (1077 GPS,
//! 1097 Galileo) and ephemerides (1019 GPS, 1046 Galileo I/NAV), as a
//! u-blox-class receiver would stream them, ready to travel inside MAVLink
//! `GPS_RTCM_DATA`.
//!
//! Encoding and framing (CRC-24Q) are the `rtcm-rs` crate's. The simulated
//! constellations are quantised through 1019/1046 once at start, so the
//! broadcast ephemerides a decoder gets are exactly the orbits the truth
//! uses; that mapping, both ways, is `cmsckf_models::gnss::rtcm_eph`'s, which
//! the daemon's decoder uses too.

use rtcm_rs::msg::{
    GalSigId, GpsSigId, Msg1004Sat, Msg1004T, Msg1077Data, Msg1077Sig, Msg1077T, Msg1097Data, Msg1097Sig, Msg1097T,
    Msm57Sat,
};
use rtcm_rs::util::DataVec;
use rtcm_rs::{Message, MessageBuilder};

use cmsckf_models::geodesy::C_MPS;
use cmsckf_models::gnss::rtcm_eph::RtcmEncodeError;
use cmsckf_models::gnss::System;

use crate::gnss::GnssEpoch;

/// MSM7's satellite and signal cells of one satellite: pseudorange split
/// into rough (1/1024 ms) and fine parts, range rate into whole and fine m/s.
fn msm7_cells(s: &crate::gnss::SatObs) -> (Msm57Sat, f64, f64) {
    let p_ms = s.pseudorange_m / C_MPS * 1e3;
    let rough = (p_ms * 1024.0).round() / 1024.0;
    let int = rough.floor();
    let rate_rough = s.pseudorange_rate_mps.round();
    (
        Msm57Sat {
            satellite_id: s.prn,
            gnss_satellite_rough_range_integer_ms: Some(int as u8),
            reserved_8_4: 0,
            gnss_satellite_rough_range_mod1ms_ms: rough - int,
            gnss_satellite_rough_phaserange_rates_m_s: Some(rate_rough as i16),
        },
        p_ms - rough,
        s.pseudorange_rate_mps - rate_rough,
    )
}

/// Frames one epoch as MSM7: 1077 (GPS L1 C/A) and, when Galileo satellites
/// are in view, 1097 (Galileo E1C), the first flagged "more MSMs of this
/// epoch follow" so that a decoder groups them.
pub fn encode_epoch(ep: &GnssEpoch, station_id: u16) -> Result<Vec<u8>, RtcmEncodeError> {
    let mut gps: Vec<_> = ep
        .sats
        .iter()
        .filter(|s| s.system == System::Gps && (1..=64).contains(&s.prn))
        .collect();
    let mut gal: Vec<_> = ep
        .sats
        .iter()
        .filter(|s| s.system == System::Galileo && (1..=64).contains(&s.prn))
        .collect();
    gps.sort_by_key(|s| s.prn);
    gal.sort_by_key(|s| s.prn);
    let epoch_ms = (ep.tow_s * 1e3).round() as u32;
    let mut b = MessageBuilder::new();
    let mut out = Vec::new();

    let msg = gps_msm7(&gps, station_id, epoch_ms, !gal.is_empty());
    out.extend_from_slice(
        b.build_message(&Message::Msg1077(msg))
            .map_err(RtcmEncodeError::Encode)?,
    );
    if gal.is_empty() {
        return Ok(out);
    }

    let msg = galileo_msm7(&gal, station_id, epoch_ms);
    out.extend_from_slice(
        b.build_message(&Message::Msg1097(msg))
            .map_err(RtcmEncodeError::Encode)?,
    );
    Ok(out)
}

/// One light-millisecond (m): the unit of MT1004's code ambiguity (DF014).
const LIGHT_MS_M: f64 = 299_792.458;

/// Frames one epoch's GPS satellites as the legacy MT1004 (L1 C/A code with
/// its ambiguity, CNR; no L2, no phase), as older bases and many CORS
/// casters send it. Legacy RTCM has no Galileo message: a legacy base
/// serves GPS only.
pub fn encode_legacy_epoch(ep: &GnssEpoch, station_id: u16) -> Result<Vec<u8>, RtcmEncodeError> {
    let mut gps: Vec<_> = ep
        .sats
        .iter()
        .filter(|s| s.system == System::Gps && (1..=32).contains(&s.prn))
        .collect();
    gps.sort_by_key(|s| s.prn);
    let mut sats: DataVec<Msg1004Sat, 31> = DataVec::new();
    for s in gps.into_iter().take(31) {
        let ambiguity = (s.pseudorange_m / LIGHT_MS_M).floor();
        sats.push(Msg1004Sat {
            gps_satellite_id: s.prn,
            l1_pseudorange_m: Some(s.pseudorange_m - ambiguity * LIGHT_MS_M),
            l1_pseudorange_amb_m: ambiguity * LIGHT_MS_M,
            l1_cnr_dbhz: Some(s.cn0_dbhz as f32),
            ..Default::default()
        });
    }
    let msg = Msg1004T {
        reference_station_id: station_id,
        gps_epoch_time_ms: (ep.tow_s * 1e3).round() as u32,
        satellites: sats,
        ..Default::default()
    };
    let mut b = MessageBuilder::new();
    b.build_message(&Message::Msg1004(msg))
        .map(<[u8]>::to_vec)
        .map_err(RtcmEncodeError::Encode)
}

/// The 1077 message (GPS L1 C/A) of the satellites `gps`, in PRN order;
/// `more_follow` sets the multiple-message flag.
fn gps_msm7(gps: &[&crate::gnss::SatObs], station_id: u16, epoch_ms: u32, more_follow: bool) -> Msg1077T {
    let mut sats: DataVec<Msm57Sat, 64> = DataVec::new();
    let mut sigs: DataVec<Msg1077Sig, 64> = DataVec::new();
    for &s in gps {
        let (sat, fine_ms, fine_rate) = msm7_cells(s);
        sats.push(sat);
        sigs.push(Msg1077Sig {
            satellite_id: s.prn,
            signal_id: GpsSigId::new(1, 'C'),
            gnss_signal_fine_pseudorange_ext_ms: Some(fine_ms),
            gnss_signal_fine_phaserange_ext_ms: None,
            gnss_phaserange_lock_time_ext_ind: 0,
            half_cycle_ambiguity_ind: 0,
            gnss_signal_cnr_ext_dbhz: Some(s.cn0_dbhz),
            gnss_signal_fine_phaserange_rate_m_s: Some(fine_rate),
        });
    }
    Msg1077T {
        reference_station_id: station_id,
        gps_epoch_time_ms: epoch_ms,
        msm_multiple_message_flag: u8::from(more_follow),
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
    }
}

/// The 1097 message (Galileo E1C) of the satellites `gal`, in PRN order,
/// the last MSM of its epoch.
fn galileo_msm7(gal: &[&crate::gnss::SatObs], station_id: u16, epoch_ms: u32) -> Msg1097T {
    let mut sats: DataVec<Msm57Sat, 64> = DataVec::new();
    let mut sigs: DataVec<Msg1097Sig, 64> = DataVec::new();
    for &s in gal {
        let (sat, fine_ms, fine_rate) = msm7_cells(s);
        sats.push(sat);
        sigs.push(Msg1097Sig {
            satellite_id: s.prn,
            signal_id: GalSigId::new(1, 'C'),
            gnss_signal_fine_pseudorange_ext_ms: Some(fine_ms),
            gnss_signal_fine_phaserange_ext_ms: None,
            gnss_phaserange_lock_time_ext_ind: 0,
            half_cycle_ambiguity_ind: 0,
            gnss_signal_cnr_ext_dbhz: Some(s.cn0_dbhz),
            gnss_signal_fine_phaserange_rate_m_s: Some(fine_rate),
        });
    }
    Msg1097T {
        reference_station_id: station_id,
        gal_epoch_time_ms: epoch_ms,
        msm_multiple_message_flag: 0,
        issue_of_data_station: None,
        reserved_58_7: 0,
        clock_steering_ind: 0,
        external_clock_ind: 0,
        gnss_smoothing_type_ind: 0,
        gnss_smoothing_interval_index: 0,
        data_segment: Msg1097Data {
            satellite_data: sats,
            signal_data: sigs,
        },
    }
}

/// Frames a reference station's antenna position as MT1005 (station id,
/// GPS and Galileo in service, ARP in ECEF to 0.1 mm): what a base station
/// sends beside its observations, and what tells it from a rover.
pub fn encode_station(station_id: u16, arp_ecef_m: [f64; 3]) -> Result<Vec<u8>, RtcmEncodeError> {
    let msg = rtcm_rs::msg::Msg1005T {
        reference_station_id: station_id,
        reserved_24_6: 0,
        gps_flag: 1,
        glonass_flag: 0,
        galileo_flag: 1,
        reference_station_ind: 0,
        antenna_ref_point_ecef_x_m: arp_ecef_m[0],
        single_receiver_osc_ind: 0,
        reserved_73_1: 0,
        antenna_ref_point_ecef_y_m: arp_ecef_m[1],
        quarter_cycle_ind: 0,
        antenna_ref_point_ecef_z_m: arp_ecef_m[2],
    };
    let mut b = MessageBuilder::new();
    b.build_message(&Message::Msg1005(msg))
        .map(<[u8]>::to_vec)
        .map_err(RtcmEncodeError::Encode)
}
