//! The simulator's RTCM3 (MSM7 1077/1097, ephemerides 1019/1046) decodes
//! back to its measurements, and a single-point solution from the decoded
//! stream lands on the truth with GPS, Galileo, or both (then with the
//! simulated inter-system bias).

use cmsckf::config::Config;
use cmsckf::eval;
use cmsckf::gnss::rtcm::{GnssMessage, RtcmDecoder, System};
use cmsckf::gnss::spp::SppOptions;
use cmsckf::gnss::IonoMode;
use cmsckf::gnss::Receiver;
use cmsckf_models::gnss::rtcm_eph::encode_ephemeris;
use cmsckf_sitl::dataset::Dataset;
use cmsckf_sitl::rtcm_out::encode_epoch;

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
    let n_gal_eph = ds.ephemerides.iter().filter(|e| e.system == System::Galileo).count() as u64;
    assert_eq!(n_gal_eph, 24);
    assert_eq!(dec.stats.frames_by_type[&1019], ds.ephemerides.len() as u64 - n_gal_eph);
    assert_eq!(dec.stats.frames_by_type[&1046], n_gal_eph);
    assert_eq!(dec.stats.frames_by_type[&1077], ds.gnss.len() as u64);
    assert_eq!(dec.stats.frames_by_type[&1097], ds.gnss.len() as u64);
    // The decoded ephemerides are the simulator's, to the wire's resolution.
    for m in &msgs {
        if let GnssMessage::Eph(raw) = m {
            let mut e = raw.eph.clone();
            e.week = raw.full_week(ds.cfg.gnss.start_week);
            let t = ds
                .ephemerides
                .iter()
                .find(|t| t.system == e.system && t.prn == e.prn)
                .unwrap();
            assert_eq!(&e, t, "{:?} {}", e.system, e.prn);
        }
    }
    // Pseudoranges and rates come back to the encoding's resolution.
    let msms: Vec<_> = msgs
        .iter()
        .filter_map(|m| if let GnssMessage::Msm(e) = m { Some(e) } else { None })
        .collect();
    assert_eq!((msms[0].system, msms[0].multiple), (System::Gps, true));
    assert_eq!((msms[1].system, msms[1].multiple), (System::Galileo, false));
    for first in &msms[..2] {
        assert_eq!(first.station_id, 7);
        let sim: Vec<_> = ds.gnss[0].sats.iter().filter(|s| s.system == first.system).collect();
        assert_eq!(first.sats.len(), sim.len());
        for sat in &first.sats {
            let t = sim.iter().find(|s| s.prn == sat.prn).unwrap();
            let g = &sat.signals[0];
            assert!((g.pseudorange_m.unwrap() - t.pseudorange_m).abs() < 1e-3);
            assert!((g.range_rate_mps.unwrap() - t.pseudorange_rate_mps).abs() < 1e-4);
        }
    }
    // Week and solution, per selection of constellations.
    let o = ds.cfg.gnss.origin_llh;
    let frame = cmsckf_models::geodesy::NedFrame::from_llh_deg(o[0], o[1], o[2]);
    for systems in [
        vec![System::Gps],
        vec![System::Galileo],
        vec![System::Gps, System::Galileo],
    ] {
        let mut rx = Receiver::new(
            SppOptions {
                elevation_mask_deg: 10.0,
                iono: IonoMode::Off,
                systems: systems.clone(),
            },
            ds.cfg.gnss.start_week,
            7,
        );
        let mut out = Vec::new();
        for m in msgs.iter().cloned() {
            rx.push(m, &mut out);
        }
        rx.flush(&mut out);
        let mut errs = Vec::new();
        let mut pdops = Vec::new();
        let mut isb = Vec::new();
        for (r, ep) in out.iter().zip(&ds.gnss) {
            let Ok(s) = &r.fix else { continue };
            assert!(s.sats.iter().all(|(sys, _)| systems.contains(sys)));
            let truth = ds.trajectory.sample(ep.t_s).p_B_in_W;
            errs.push((frame.to_ned(&s.r_ecef_m) - truth).norm());
            pdops.push(s.pdop);
            // The first clock is GPS's, or Galileo's (= GPS + ISB) alone.
            let expected = ep.clock_bias_m
                + if systems == [System::Galileo] {
                    ep.isb_galileo_m
                } else {
                    0.0
                };
            assert!(
                (s.clock_bias_m - expected).abs() < 60.0,
                "clock {} vs {}",
                s.clock_bias_m,
                expected
            );
            if let [(_, g), (_, e)] = s.system_clocks_m[..] {
                isb.push(e - g - ep.isb_galileo_m);
            }
        }
        assert!(
            errs.len() >= ds.gnss.len() - 1,
            "{systems:?}: {} of {} epochs solved",
            errs.len(),
            ds.gnss.len()
        );
        // Single-epoch fixes with RTKLIB's loose weights (σ ≈ 5.6 m without
        // an ionosphere model): metres, and a 30 m multipath outlier can
        // pass RAIM. Each flight draws its own broadcast errors (0.6 m a
        // satellite), constant over these 10 s, which the geometry scales:
        // Galileo alone is a handful of satellites (PDOP about 2.5 against
        // GPS's 1.6), so its bound is twice GPS's.
        errs.sort_by(|a, b| a.total_cmp(b));
        pdops.sort_by(|a, b| a.total_cmp(b));
        let median = errs[errs.len() / 2];
        let pdop = pdops[pdops.len() / 2];
        eprintln!("{systems:?}: median SPP error {median:.2} m, median PDOP {pdop:.2}");
        let bound_m = if systems == [System::Galileo] { 6.0 } else { 3.0 };
        assert!(
            median < bound_m,
            "{systems:?}: median SPP error {median} m, PDOP {pdop:.2} ({errs:?})"
        );
        if systems.len() == 2 {
            // The inter-system bias is estimated, not absorbed.
            isb.sort_by(|a, b| a.total_cmp(b));
            assert_eq!(isb.len(), errs.len());
            assert!(isb[isb.len() / 2].abs() < 2.0, "ISB errors {isb:?}");
        }
    }
}
