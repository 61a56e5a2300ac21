//! Zero-velocity updates (README §3c): a still vehicle is held by them.

use cmsckf::config::Config;
use cmsckf::estimator::Mode;
use cmsckf::eval;
use cmsckf_sitl::dataset::Dataset;

/// A still vehicle: the frames become zero-velocity updates, the window
/// takes no clones, no track counts against health, and the position
/// stays put: under 5 cm over 30 s on the ground (§3c), with GNSS.
#[test]
fn standstill_is_held_by_zero_velocity_updates() {
    let cfg = Config::default();
    let mut sim = eval::sim_config_for(&cfg);
    sim.standstill_s = 32.0;
    let ds = Dataset::generate("racetrack", 2, Some(32.0), &sim).unwrap();
    let mut run = eval::Runner::new(&ds, &cfg, Mode::Compressed, 2).with_gnss();
    let mut p1 = None;
    let mut inconsistent = 0;
    for k in 0..ds.frames.len() {
        let (_, rep) = run.step_frame(k);
        inconsistent += [
            cmsckf::estimator::Reject::Chi2,
            cmsckf::estimator::Reject::BadDepth,
            cmsckf::estimator::Reject::NotConverged,
        ]
        .iter()
        .filter_map(|r| rep.rejected.get(r))
        .sum::<u64>();
        if p1.is_none() && run.est.time_s() >= 1.0 {
            p1 = Some(run.est.imu_state().p_B_in_W);
        }
        assert!(run.est.check_health().is_ok(), "{:?}", run.est.check_health());
    }
    let st = &run.est.stats;
    assert!(st.zupt_updates as usize > ds.frames.len() * 9 / 10, "{st:?}");
    assert_eq!(inconsistent, 0);
    assert!(run.est.n_clones() <= 2, "clones {}", run.est.n_clones());
    let moved = (run.est.imu_state().p_B_in_W - p1.unwrap()).norm();
    eprintln!("moved {moved:.4} m over 31 s standing; {} ZUPTs", st.zupt_updates);
    assert!(moved < 0.05, "moved {moved} m while standing");
    // The gyro bias is held by Z2: within 3σ of the truth.
    let b_true = ds.truth.last().unwrap().bias.b_g;
    let sig = run
        .est
        .imu_covariance()
        .fixed_view::<3, 3>(9, 9)
        .diagonal()
        .map(f64::sqrt);
    let err = run.est.imu_state().b_g - b_true;
    assert!(
        (0..3).all(|k| err[k].abs() < 3.0 * sig[k]),
        "gyro bias error {err:?}, σ {sig:?}"
    );
}
