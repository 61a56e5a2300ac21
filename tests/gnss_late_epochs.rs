//! Late GNSS epochs (README §8b): an epoch is fused at its own time through
//! the clone taken at its instant, over a whole flight none is dropped, one
//! past the bound is refused and counted, and the epoch grid that places the
//! clones is learnt from the epochs' spacing.

use cmsckf::estimator::{ImuMeas, InputError, Mode, Stats};
use cmsckf::eval;
use cmsckf_models::geodesy::NedFrame;
use cmsckf_models::gnss::{SatMeas, System};
use nalgebra::Vector3;

mod common;
use common::flights::racetrack;

/// A satellite 2e7 m up and 8e6 m east of a Sydney origin, moving, with
/// clock terms (the fixture of the estimator's measurement-model tests).
fn sat(system: System) -> (NedFrame, SatMeas) {
    let frame = NedFrame::from_llh_deg(-33.88, 151.2, 40.0);
    let up = frame.origin_ecef.normalize();
    let east = frame.R_ecef_ned.column(1).into_owned();
    let r_sat = frame.origin_ecef + up * 2.0e7 + east * 8.0e6;
    (
        frame,
        SatMeas {
            system,
            prn: 5,
            r_sat_ecef_m: r_sat,
            v_sat_ecef_mps: Vector3::new(1200.0, -2500.0, 1800.0),
            dts_m: 30.0,
            ddts_mps: 0.01,
            pseudorange_m: None,
            range_rate_mps: None,
            noise_scale: 1.0,
            extra_var_m2: 0.0,
            correction: None,
        },
    )
}

/// A late epoch fused through its clone (§8b) is the same epoch fused on
/// time: from one filter state, (a) propagate to the epoch, fuse it, then
/// propagate 0.5 s; (b) propagate 0.5 s, then fuse the epoch late. They
/// differ only by the propagation's relinearisation at the corrected state.
#[test]
fn a_late_gnss_epoch_is_fused_at_its_own_time() {
    let (ds, cfg) = racetrack(5, 20.0);
    let mut run = eval::Runner::new(&ds, &cfg, Mode::Full, 5).with_gnss_on_time();
    // Through take-off, to 15.3 s, GNSS on time.
    let k_stop = ds.frames.iter().position(|f| f.t_s > 15.3).unwrap();
    for k in 0..k_stop {
        run.step_frame(k);
    }
    let (e, frame, sats) = run.gnss_epoch_after(run.est.time_s()).expect("an epoch ahead");
    let t_e = ds.gnss[e].t_s;
    let mut a = run.est.clone();
    let mut b = run.est.clone();
    // The rest of the IMU to 0.6 s past the epoch (samples the runner has
    // already buffered are refused by both alike).
    let t0 = a.time_s();
    for m in ds.imu.iter().filter(|m| m.t_s > t0 && m.t_s <= t_e + 0.6) {
        let m = ImuMeas {
            t_s: m.t_s,
            accel_mps2: m.accel_mps2,
            gyro_radps: m.gyro_radps,
        };
        let _ = a.add_imu(m);
        let _ = b.add_imu(m);
    }
    a.propagate_to(t_e);
    let rep_a = a.process_gnss(t_e, &frame, &sats).unwrap();
    a.propagate_to(t_e + 0.5);
    b.propagate_to(t_e + 0.5);
    assert_eq!(b.n_gnss_clones(), 1, "a clone waits at the epoch's instant");
    let rep_b = b.process_gnss(t_e, &frame, &sats).unwrap();
    assert!((rep_b.late_s - 0.5).abs() < 1e-9);
    assert_eq!(rep_a.pseudoranges_used, rep_b.pseudoranges_used);
    assert!(rep_b.pseudoranges_used >= 8);
    assert_eq!((a.n_gnss_clones(), b.n_gnss_clones()), (0, 0));
    a.sync();
    b.sync();
    let (sa, sb) = (a.snapshot(), b.snapshot());
    // Every state within 1e-3 of its own σ, every covariance entry within
    // 1e-2 of √(P_ii P_jj): what is left is the propagation over 0.5 s
    // linearised at the corrected state in (a) and at the uncorrected one
    // in (b) (a tilt correction of a milliradian changes `F_vb_a`, and so
    // the velocity's variance, by about as much).
    for i in 0..sa.P.nrows() {
        let sig = sa.P[(i, i)].sqrt();
        for j in 0..sa.P.ncols() {
            let d = (sa.P[(i, j)] - sb.P[(i, j)]).abs() / (sig * sa.P[(j, j)].sqrt());
            assert!(d < 1e-2, "P[{i},{j}] differs by {d:e} of its scale");
        }
    }
    let dp = (a.imu_state().p_B_in_W - b.imu_state().p_B_in_W).norm();
    let dv = (a.imu_state().v_B_in_W - b.imu_state().v_B_in_W).norm();
    let sp = a.covariance()[(6, 6)].sqrt();
    let sv = a.covariance()[(3, 3)].sqrt();
    assert!(dp < 1e-3 * sp && dv < 1e-3 * sv, "dp {dp} (σ {sp}), dv {dv} (σ {sv})");
    // Fused against the current state instead (what dropping the clone
    // would do), the same epoch would pull the position by decimetres.
    let mut wrong = b.clone();
    let mut c = run.est.clone();
    for m in ds.imu.iter().filter(|m| m.t_s > t0 && m.t_s <= t_e + 0.6) {
        let _ = c.add_imu(ImuMeas {
            t_s: m.t_s,
            accel_mps2: m.accel_mps2,
            gyro_radps: m.gyro_radps,
        });
    }
    c.forget_gnss_epoch_grid();
    c.propagate_to(t_e + 0.5);
    let _ = c.process_gnss(t_e + 0.5, &frame, &sats);
    *wrong.imu_state_mut() = *c.imu_state();
    assert!((wrong.imu_state().p_B_in_W - a.imu_state().p_B_in_W).norm() > 10.0 * dp.max(1e-4));
}

/// A whole flight with every epoch 0.2–0.6 s late: all fused through their
/// clones, none refused, no clone left behind, and the filter close to one
/// fed the same epochs on time. One past the bound is refused and counted.
#[test]
fn late_gnss_over_a_flight_is_fused_not_dropped() {
    let (ds, cfg) = racetrack(5, 14.0);
    let mut on_time = eval::Runner::new(&ds, &cfg, Mode::Full, 5).with_gnss_on_time();
    let mut late = eval::Runner::new(&ds, &cfg, Mode::Full, 5).with_gnss();
    for k in 0..ds.frames.len() {
        on_time.step_frame(k);
        late.step_frame(k);
    }
    let t_end = ds.frames.last().unwrap().t_s + 0.7;
    on_time.finish_gnss(t_end);
    late.finish_gnss(t_end);
    let (a, b) = (&on_time.est, &late.est);
    // The first epoch only sets the clock (no grid yet); every later one
    // is fused at its own time, late (the last may find the filter not yet
    // past it).
    assert_eq!(b.stats.gnss_epochs_fused as usize, ds.gnss.len() - 1, "{:?}", b.stats);
    assert!(
        b.stats.gnss_epochs_fused_late as usize >= ds.gnss.len() - 2,
        "{:?}",
        b.stats
    );
    assert_eq!(b.stats.gnss_epochs_late, 0);
    assert_eq!(b.n_gnss_clones(), 0, "every clone served its epoch or was dropped");
    let dp = (a.imu_state().p_B_in_W - b.imu_state().p_B_in_W).norm();
    let sigma = a.pose_covariance().fixed_view::<3, 3>(3, 3).trace().sqrt();
    assert!(dp < 0.5 * sigma, "late vs on time: {dp} m apart, σ {sigma} m");

    // Past the bound: refused, counted, nothing changed.
    let mut est = late.est.clone();
    let before = est.snapshot();
    let frame = NedFrame::from_llh_deg(-33.88, 151.2, 40.0);
    let (_, s) = sat(System::Gps);
    let err = est.process_gnss(est.time_s() - 1.5, &frame, &[s]).unwrap_err();
    assert!(matches!(err, InputError::GnssLate { .. }), "{err}");
    assert_eq!(est.stats.gnss_epochs_late, 1);
    assert_eq!(est.stats.rejected.get(&cmsckf::counters::Counter::GnssLate), Some(&1));
    assert_eq!(est.snapshot().max_rel_diff(&before), 0.0);
}

/// A 5 Hz receiver with the filter told 1 Hz (`gnss.epoch_rate_hz`): the
/// grid learns the period from the epochs' spacing, and from then on every
/// epoch, 0.3 s late, is fused through its clone. A non-finite epoch time is
/// refused and counted.
#[test]
fn the_epoch_grid_is_learnt_from_the_epochs() {
    let (ds, cfg) = racetrack(6, 14.0);
    let mut run = eval::Runner::new(&ds, &cfg, Mode::Msckf, 6).with_gnss_on_time();
    let k0 = ds.frames.iter().position(|f| f.t_s > 6.0).unwrap();
    for k in 0..k0 {
        run.step_frame(k);
    }
    // The epoch at 7 s, its measurements re-stamped every 0.2 s: a 5 Hz
    // receiver over a second (the satellites barely move in 0.8 s, and the
    // test is about when the epochs are fused).
    let (_, frame, sats) = run.gnss_epoch_after(6.5).unwrap();
    let mut est = run.est.clone();
    est.stats = Stats::default();
    let imu: Vec<ImuMeas> = ds
        .imu
        .iter()
        .filter(|m| m.t_s > est.time_s() && m.t_s <= 10.0)
        .map(|m| ImuMeas {
            t_s: m.t_s,
            accel_mps2: m.accel_mps2,
            gyro_radps: m.gyro_radps,
        })
        .collect();
    for m in &imu {
        let _ = est.add_imu(*m);
    }
    let mut fused_late = Vec::new();
    for i in 0..12 {
        let t_e = 7.0 + 0.2 * i as f64;
        est.propagate_to(t_e + 0.3);
        let late_before = est.stats.gnss_epochs_fused_late;
        let _ = est.process_gnss(t_e, &frame, &sats);
        fused_late.push(est.stats.gnss_epochs_fused_late > late_before);
    }
    // The first epochs find the 1 s grid (or none); once two 0.2 s apart
    // are seen, every later one has its clone.
    assert!(fused_late[4..].iter().all(|f| *f), "{fused_late:?}");
    assert!(est.n_gnss_clones() <= 6, "clones {}", est.n_gnss_clones());
    // A NaN epoch time: refused, counted, no panic.
    assert!(est.process_gnss(f64::NAN, &frame, &sats).is_err());
    assert_eq!(
        est.stats.rejected.get(&cmsckf::counters::Counter::GnssTimeInvalid),
        Some(&1)
    );
    // A tag a day ahead teaches the grid nothing (its period and last
    // epoch stay), and the filter survives the day of dead reckoning.
    let grid = est.gnss_epoch_grid();
    let mut far = est.clone();
    let _ = far.process_gnss(est.time_s() + 86_400.0, &frame, &sats);
    assert_eq!(far.gnss_epoch_grid(), grid);
}
