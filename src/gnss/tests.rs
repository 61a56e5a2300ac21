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
