//! The tight GNSS update on the simulated racetrack: the position becomes
//! absolute (unaligned ATE ≤ 1 m), the clock bias and the Galileo
//! inter-system bias track the truth, the
//! filter stays consistent, and compressed still equals full. It runs in
//! every mode, and every constellation gets its own inter-system bias.

use cmsckf::config::Config;
use cmsckf::estimator::Mode;
use cmsckf::eval;
use cmsckf_models::gnss::{SatMeas, System};
use cmsckf_sitl::dataset::Dataset;
use cmsckf_sitl::metrics::nees_bounds_95;

mod common;
use common::flights::racetrack;

#[test]
fn gnss_makes_the_position_absolute_and_stays_consistent() {
    let cfg = Config::default();
    let sim = eval::sim_config_for(&cfg);
    let seeds = 4;
    let modes = [Mode::Msckf, Mode::Full, Mode::Compressed];
    let ev = eval::evaluate(
        &eval::EvalSpec {
            scenario: "racetrack".into(),
            modes: modes.to_vec(),
            seeds: eval::Seeds::UpTo(seeds),
            duration_s: Some(40.0),
            gnss: true,
            landed_state: true,
        },
        &cfg,
        &sim,
        |_| {},
    )
    .unwrap();
    eprintln!("{}", ev.table());
    let (_, hi) = nees_bounds_95(6, seeds as usize);
    for m in ["msckf", "full", "compressed"] {
        let r = &ev.modes[m];
        assert!(r.ate_unaligned_m <= 1.0, "{m}: unaligned ATE {} m", r.ate_unaligned_m);
        let clock = r.clock_bias_rmse_m.expect("clock errors recorded");
        assert!(clock <= 1.5, "{m}: clock bias RMSE {clock} m");
        // The simulated receiver tracks Galileo too, 6 m apart from GPS.
        let isb = r.isb_galileo_rmse_m.expect("ISB errors recorded");
        assert!(isb <= 1.0, "{m}: Galileo ISB RMSE {isb} m");
        assert!(r.nees_mean <= hi && r.nees_mean >= 2.0, "{m}: NEES {}", r.nees_mean);
    }
    let d = ev.modes["compressed"].max_rel_diff_vs_full.unwrap();
    assert!(d <= 1e-9, "compressed vs full {d:e}");
}

/// The GNSS update runs in every mode and touches only the active states:
/// keyframes and clones are changed only through their correlations.
#[test]
fn gnss_update_in_every_mode() {
    let cfg = Config::default();
    let ds = Dataset::generate("racetrack", 6, Some(12.0), &eval::sim_config_for(&cfg)).unwrap();
    for mode in Mode::ALL {
        let r = eval::run(&ds, &cfg, mode, 6, true);
        assert!(r.stats.updates > 0);
        assert!(!r.clock_errors.is_empty(), "{mode:?}: no GNSS epoch fused");
        let last = r.clock_errors.last().unwrap().1;
        assert!(last.abs() < 3.0, "{mode:?}: clock error {last} m");
    }
}

/// §8 K1, K4: GLONASS and BeiDou codes get inter-system biases of their own.
/// The simulator's Galileo satellites are relabelled BeiDou with 7 m more
/// bias, and its odd-numbered GPS ones GLONASS with 5 m less: each ISB
/// starts from its constellation's first epoch and tracks its truth, and
/// the position ends as close to the truth as with the simulator's labels.
#[test]
fn every_constellation_gets_its_own_inter_system_bias() {
    fn relabel(sats: &mut [SatMeas]) {
        for s in sats {
            let (system, offset_m) = match s.system {
                System::Galileo => (System::BeiDou, 7.0),
                System::Gps if s.prn % 2 == 1 => (System::Glonass, -5.0),
                other => (other, 0.0),
            };
            s.system = system;
            s.pseudorange_m = s.pseudorange_m.map(|p| p + offset_m);
        }
    }
    let (ds, cfg) = racetrack(3, 30.0);
    let mut plain = eval::Runner::new(&ds, &cfg, Mode::Full, 3).with_gnss();
    let mut mapped = eval::Runner::new(&ds, &cfg, Mode::Full, 3)
        .with_gnss()
        .with_measurement_map(relabel);
    for k in 0..ds.frames.len() {
        plain.step_frame(k);
        mapped.step_frame(k);
    }
    let isb_galileo_m = ds.gnss[0].isb_galileo_m;
    let (c, var) = mapped.est.clock();
    assert!(!mapped.est.isb_initialised(System::Galileo), "no Galileo code was seen");
    for (system, slot, truth_m) in [(System::Glonass, 3, -5.0), (System::BeiDou, 4, isb_galileo_m + 7.0)] {
        assert!(mapped.est.isb_initialised(system), "{system:?}");
        let err = c[slot] - truth_m;
        eprintln!(
            "{system:?} ISB {:.3} m, truth {truth_m} m, σ {:.3} m",
            c[slot],
            var[slot].sqrt()
        );
        assert!(
            err.abs() < 1.0 && err.abs() < 4.0 * var[slot].sqrt(),
            "{system:?}: ISB error {err} m"
        );
    }
    let t = mapped.est.time_s();
    let truth = ds
        .truth
        .iter()
        .min_by(|a, b| (a.truth.t_s - t).abs().total_cmp(&(b.truth.t_s - t).abs()))
        .unwrap();
    let e_mapped = (mapped.est.imu_state().p_B_in_W - truth.truth.p_B_in_W).norm();
    let e_plain = (plain.est.imu_state().p_B_in_W - truth.truth.p_B_in_W).norm();
    eprintln!("position error at {t:.1} s: {e_mapped:.3} m relabelled, {e_plain:.3} m as simulated");
    assert!(
        e_mapped < 1.0 && e_mapped < 2.0 * e_plain + 0.2,
        "{e_mapped} m against {e_plain} m"
    );
}
