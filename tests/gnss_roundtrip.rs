//! The simulator's RTCM3 (MSM7 + 1019) decodes back to its measurements, and
//! a single-point solution from the decoded stream lands on the truth.

use cmsckf::config::{Config, IonoMode};
use cmsckf::eval;
use cmsckf::gnss::rtcm::{GnssMessage, RtcmDecoder, System};
use cmsckf::gnss::spp::SppOptions;
use cmsckf::gnss::Receiver;
use cmsckf_sitl::dataset::Dataset;
use cmsckf_sitl::rtcm_out::{encode_ephemeris, encode_epoch};

#[test]
fn simulated_rtcm_round_trips_and_solves() {
    let cfg = Config::default();
    let ds = Dataset::generate("racetrack", 3, Some(10.0), &eval::sim_config_for(&cfg)).unwrap();
    let mut stream = Vec::new();
    for e in &ds.ephemerides {
        stream.extend(encode_ephemeris(e).unwrap());
    }
    for ep in &ds.gnss {
        stream.extend(encode_epoch(ep, 7).unwrap());
    }
    let mut dec = RtcmDecoder::new();
    let mut msgs = Vec::new();
    dec.push(&stream, &mut msgs);
    assert_eq!(dec.stats.crc_failures, 0);
    assert_eq!(dec.stats.frames_by_type[&1019], ds.ephemerides.len() as u64);
    assert_eq!(dec.stats.frames_by_type[&1077], ds.gnss.len() as u64);
    // Pseudoranges and rates come back to the encoding's resolution.
    let first = msgs
        .iter()
        .find_map(|m| if let GnssMessage::Msm(e) = m { Some(e) } else { None })
        .unwrap();
    assert_eq!(first.station_id, 7);
    assert_eq!(first.sats.len(), ds.gnss[0].sats.len());
    for sat in &first.sats {
        let t = ds.gnss[0].sats.iter().find(|s| s.prn == sat.prn).unwrap();
        let g = &sat.signals[0];
        assert!((g.pseudorange_m.unwrap() - t.pseudorange_m).abs() < 1e-3);
        assert!((g.range_rate_mps.unwrap() - t.pseudorange_rate_mps).abs() < 1e-4);
    }
    // Week and solution.
    let mut rx = Receiver::new(
        SppOptions {
            elevation_mask_deg: 10.0,
            iono: IonoMode::Off,
            systems: vec![System::Gps],
        },
        ds.cfg.gnss.start_week,
        7,
    );
    let mut out = Vec::new();
    for m in msgs {
        rx.push(m, &mut out);
    }
    rx.flush(&mut out);
    let o = ds.cfg.gnss.origin_llh;
    let frame = cmsckf_sitl::geodesy::NedFrame::from_llh_deg(o[0], o[1], o[2]);
    let mut errs = Vec::new();
    for (r, ep) in out.iter().zip(&ds.gnss) {
        let Ok(s) = &r.fix else { continue };
        let truth = ds.trajectory.sample(ep.t_s).p_B_in_W;
        errs.push((frame.to_ned(&s.r_ecef_m) - truth).norm());
        assert!(
            (s.clock_bias_m - ep.clock_bias_m).abs() < 60.0,
            "clock {} vs {}",
            s.clock_bias_m,
            ep.clock_bias_m
        );
    }
    assert!(
        errs.len() >= ds.gnss.len() - 1,
        "{} of {} epochs solved",
        errs.len(),
        ds.gnss.len()
    );
    // Single-epoch fixes with RTKLIB's loose weights (σ ≈ 5.6 m without an
    // ionosphere model): metres, and a 30 m multipath outlier can pass RAIM.
    errs.sort_by(|a, b| a.total_cmp(b));
    let median = errs[errs.len() / 2];
    assert!(median < 3.0, "median SPP error {median} m ({errs:?})");
}
