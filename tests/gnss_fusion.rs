//! The tight GNSS update on the simulated racetrack: the position becomes
//! absolute (unaligned ATE ≤ 1 m), the clock bias and the Galileo
//! inter-system bias track the truth, the
//! filter stays consistent, and compressed still equals full.

use cmsckf::config::Config;
use cmsckf::estimator::Mode;
use cmsckf::eval;
use cmsckf_sitl::metrics::nees_bounds_95;

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
            seeds,
            duration_s: Some(40.0),
            gnss: true,
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
