//! Unit tests of the receiver model: epochs, stream recognition, measurement policy.

use super::*;
use cmsckf_models::gnss::Klobuchar;

use super::raw_sat::F_L2_HZ;
use super::rtcm::System;
use super::spp::EphStore;
use rand::SeedableRng;

fn pol(mode: IonoMode) -> IonoPolicy<'static> {
    IonoPolicy {
        mode,
        klobuchar: None,
        rx_ecef_m: None,
    }
}

/// Klobuchar against a separate evaluation of IS-GPS-200's algorithm
/// (a Python transcription, RTKLIB's default parameters, 45°N 0°E,
/// satellite due south at 30°, 14:00 local): 6.635 m; and the 5 ns
/// night floor times the obliquity at 02:00.
#[test]
fn klobuchar_model() {
    let k = Klobuchar {
        alpha: [0.1118e-07, -0.7451e-08, -0.5961e-07, 0.1192e-06],
        beta: [0.1167e+06, -0.2294e+06, -0.1311e+06, 0.1049e+07],
    };
    let d = k.delay_m(
        45f64.to_radians(),
        0.0,
        std::f64::consts::PI,
        30f64.to_radians(),
        14.0 * 3600.0,
    );
    let floor = 5e-9 * cmsckf_models::geodesy::C_MPS;
    assert!((d - 6.634965).abs() < 1e-4, "{d}");
    let night = k.delay_m(
        45f64.to_radians(),
        0.0,
        std::f64::consts::PI,
        30f64.to_radians(),
        2.0 * 3600.0,
    );
    let f = 1.0 + 16.0 * (0.53f64 - 30.0 / 180.0).powi(3);
    assert!((night - f * floor).abs() < 1e-9, "{night}");
    // Lower satellites see a longer slant path.
    assert!(k.delay_m(45f64.to_radians(), 0.0, 0.0, 10f64.to_radians(), 14.0 * 3600.0) > d);
}

#[test]
fn ionosphere_handling_of_filter_measurements() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let mut ephs = EphStore::default();
    let c = cmsckf_sitl::gnss::constellation(2443, 345_600.0, &mut rng);
    for e in &c {
        ephs.insert(e.clone());
    }
    let raw = RawSat {
        system: System::Gps,
        prn: c[0].prn,
        l1_pseudorange_m: Some(2.2e7),
        l2_pseudorange: Some((2.2e7 + 3.0, F_L2_HZ)),
        l1_range_rate_mps: Some(100.0),
    };
    let tow = 345_600.0;
    let auto = &sat_measurements(&ephs, 2443, tow, pol(IonoMode::Auto), [raw])[0];
    // P_IF = (P2 − γP1)/(1 − γ) = P1 − 3 m/(γ − 1) with γ = (f1/f2)².
    let g = (1575.42f64 / 1227.60).powi(2);
    assert!((auto.pseudorange_m.unwrap() - (2.2e7 - 3.0 / (g - 1.0))).abs() < 1e-6);
    assert_eq!((auto.noise_scale, auto.extra_var_m2), (3.0, 0.0));
    let off = &sat_measurements(&ephs, 2443, tow, pol(IonoMode::Off), [raw])[0];
    assert_eq!(off.pseudorange_m, Some(2.2e7));
    assert_eq!((off.noise_scale, off.extra_var_m2), (1.0, 0.0));
    // The iono-free clock has no TGD: the two differ by exactly c·TGD.
    assert!((auto.dts_m - off.dts_m - c[0].tgd_s * cmsckf_models::geodesy::C_MPS).abs() < 1e-3);
    let single = RawSat {
        l2_pseudorange: None,
        ..raw
    };
    let inflated = &sat_measurements(&ephs, 2443, tow, pol(IonoMode::Auto), [single])[0];
    assert_eq!(inflated.extra_var_m2, 25.0);
    assert!(sat_measurements(&ephs, 2443, tow, pol(IonoMode::IonoFree), [single])[0]
        .pseudorange_m
        .is_none());
}

/// One GPS MSM of station `id` at `tow_s` with one satellite, the last of
/// its epoch.
fn base_msm(id: u16, tow_s: f64) -> super::rtcm::MsmEpoch {
    super::rtcm::MsmEpoch {
        system: System::Gps,
        msg_type: 1077,
        station_id: id,
        tow_s,
        utc: false,
        day_unknown: false,
        multiple: false,
        sats: vec![super::rtcm::SatObs {
            system: System::Gps,
            prn: 1,
            signals: Vec::new(),
        }],
    }
}

/// A base epoch stamped far ahead (a bad tag, or a hostile ground station)
/// was held as the newest, and every real epoch after it refused as older:
/// the base was lost for the flight. Three in a row make it a stray,
/// forgotten; an impossible time of week is refused outright; copies are
/// dropped.
#[test]
fn a_stray_future_base_epoch_is_forgotten() {
    let mut b = super::dgnss::BaseStation::default();
    let sys = [System::Gps];
    let week = |_: f64| 2443;
    let kept = |b: &mut super::dgnss::BaseStation, tow: f64| b.push_msm(base_msm(100, tow), &sys, week).len();
    assert_eq!(kept(&mut b, 1000.0), 1);
    assert_eq!(kept(&mut b, 1000.0), 0, "a copy");
    assert_eq!(kept(&mut b, 2000.0), 1, "the stray, ahead");
    assert_eq!(kept(&mut b, 1001.0), 0);
    assert_eq!(kept(&mut b, 1002.0), 0);
    assert_eq!(kept(&mut b, 1003.0), 1, "the third in a row forgets the stray");
    assert_eq!(kept(&mut b, 1004.0), 1);
    assert_eq!(kept(&mut b, 700_000.0), 0, "not a time of week");
    assert_eq!(kept(&mut b, 1005.0), 1);
    assert_eq!((b.stats.duplicate_epochs, b.stats.out_of_order_epochs), (1, 3));
}

/// A Galileo ephemeris's 12-bit week settles a hint 1024 weeks off, but not
/// a week the autopilot's clock gave (a ground station's ephemeris may
/// carry any week).
#[test]
fn a_galileo_week_overrules_a_hint_but_not_the_autopilots_clock() {
    let eph = |week: u32| {
        let mut e = cmsckf_sitl::gnss::galileo_constellation(week, 0.0).remove(0);
        let field = (week - 1024) as u16;
        e.week = field as u32;
        super::rtcm::GnssMessage::Eph(super::rtcm::RawEph {
            week_field: field,
            eph: e,
        })
    };
    let opts = || super::spp::SppOptions {
        elevation_mask_deg: 10.0,
        iono: IonoMode::Off,
        systems: vec![System::Gps, System::Galileo],
    };
    let mut rx = Receiver::new(opts(), 1419, 0);
    rx.push(eph(2443), &mut Vec::new());
    assert_eq!((rx.week_hint, rx.stats.week_from_galileo), (2443, 1));
    let mut rx = Receiver::new(opts(), 2443, 0);
    rx.week_from_clock = true;
    rx.push(eph(2443 + 1024), &mut Vec::new());
    assert_eq!((rx.week_hint, rx.stats.week_from_galileo), (2443, 0));
}

/// A ground station's ephemeris fills in a satellite the rover's stream has
/// not given, never displaces the rover's (a shifted one reset the filter),
/// and gives way to the rover's own when it comes.
#[test]
fn another_stations_ephemeris_only_fills_in() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let good = cmsckf_sitl::gnss::constellation(2443, 345_600.0, &mut rng).remove(0);
    let mut shifted = good.clone();
    shifted.toe_s += 16.0;
    shifted.iode += 1;
    let (sys, prn, week, tow) = (good.system, good.prn, 2443, good.toe_s);
    let mut store = EphStore::default();
    store.insert(good.clone());
    assert!(!store.insert_from_other(shifted.clone()), "the rover's own stands");
    assert_eq!(store.select(sys, prn, week, tow + 16.0).unwrap().iode, good.iode);
    let mut store = EphStore::default();
    assert!(
        store.insert_from_other(shifted.clone()),
        "a satellite the rover has not given"
    );
    assert_eq!(store.select(sys, prn, week, tow).unwrap().iode, shifted.iode);
    store.insert(good.clone());
    assert_eq!(
        store.select(sys, prn, week, tow + 16.0).unwrap().iode,
        good.iode,
        "the rover's replaces it"
    );
}

/// A second station on the link (a second ground station with its own
/// position, or another station's epochs in a flood) used to clear the
/// base's checks or push its epochs out of a shared buffer: the base was
/// lost. Each station is kept apart; the base used is the lowest-numbered
/// one whose position checks out.
#[test]
fn a_second_station_never_displaces_a_good_base() {
    use nalgebra::Vector3;
    let mut b = super::dgnss::BaseStation::default();
    let sys = [System::Gps];
    let week = |_: f64| 2443;
    let arp = [-4_646_000.0, 2_553_000.0, -3_534_000.0];
    let far = [arp[0] + 40.0, arp[1], arp[2]];
    b.set_position(200, far);
    b.set_position(100, arp);
    for k in 0..5 {
        let tow = 1000.0 + k as f64;
        // A flood of a third station's epochs between the base's.
        for j in 0..10 {
            b.push_msm(base_msm(300, tow + 0.05 * j as f64), &sys, week);
        }
        for id in [100, 200] {
            assert_eq!(b.push_msm(base_msm(id, tow), &sys, week).len(), 1);
            // Each station's own fix: 2 m from the base's announced
            // position, and so 40 m from the other's.
            b.record_fix(id, &(Vector3::from(arp) + Vector3::new(2.0, 0.0, 0.0)));
        }
    }
    let limits = super::dgnss::BaseLimits::default();
    let chosen = b.base_for(2443, 1004.5, limits).unwrap();
    assert_eq!(
        (chosen.station_id, chosen.newest.tow_s, chosen.before.map(|e| e.tow_s)),
        (100, 1004.0, Some(1003.0))
    );
    // The good base alone announcing a wrong position: nothing is used.
    let mut lone = super::dgnss::BaseStation::default();
    lone.set_position(200, far);
    for k in 0..3 {
        lone.push_msm(base_msm(200, 1000.0 + k as f64), &sys, week);
        lone.record_fix(200, &Vector3::from(arp));
    }
    assert!(matches!(
        lone.base_for(2443, 1002.5, limits),
        Err(super::dgnss::DgnssError::BasePositionWrong { .. })
    ));
}
