//! The yaw conditioned on a better compass mean (estimator README §7, eq.
//! H1; `Estimator::condition_yaw_on_compass`), against its definition on a
//! filter that has stood on the ground. The covariance is read through the
//! estimator's inspection surface (`covariance`, `sync`), as the exactness
//! tests read it: the simulator is the tests', never the estimator's.

use cmsckf::config::Config;
use cmsckf::estimator::{Estimator, Mode, YawConditionError};
use cmsckf::eval::{sim_config_for, Runner};
use cmsckf_sitl::dataset::Dataset;

/// A filter that has stood 4 s on the ground (the racetrack's standstill,
/// its frames zero-velocity updates), its cross-covariances brought up to
/// date.
fn standing(mode: Mode) -> Estimator {
    let cfg = Config::default();
    let mut sim = sim_config_for(&cfg);
    sim.standstill_s = 5.0;
    let ds = Dataset::generate("racetrack", 3, Some(4.0), &sim).unwrap();
    let mut run = Runner::new(&ds, &cfg, mode, 3);
    for k in 0..ds.frames.len() {
        run.step_frame(k);
    }
    let mut est = run.est;
    est.sync();
    est
}

/// The only keyframe's id and yaw (rad); it is the first local one, at
/// `kf_offset(0)`.
fn keyframe_yaw(est: &Estimator) -> (u64, f64) {
    let kf = est
        .keyframes()
        .next()
        .expect("a standing filter with a camera has its first keyframe");
    (kf.id, kf.q_W_B().euler_angles().2)
}

/// Eq. H1 against its definition: conditioning on a known shift of the
/// compass mean moves the reference yaw (the oldest keyframe's) by the
/// whole shift and every state by its regression on that yaw, and takes
/// exactly `drop` off that yaw's variance: `P − P e eᵀ P drop / P_ψψ²`.
#[test]
fn conditioning_moves_the_yaw_by_the_shift_and_its_variance_by_the_drop() {
    let mut est = standing(Mode::Compressed);
    assert_eq!(est.keyframes().count(), 1);
    assert_eq!(est.n_global_keyframes(), 0);
    let col = est.kf_offset(0) + 2;
    let p0 = est.covariance().clone();
    let (kf_id, kf_yaw0) = keyframe_yaw(&est);
    let imu_yaw0 = est.imu_state().q_W_B.euler_angles().2;
    let bg0 = est.imu_state().b_g;
    let (shift, drop) = (0.8_f64.to_radians(), 0.8 * p0[(col, col)]);
    est.condition_yaw_on_compass(shift, drop).unwrap();
    let (kf_id1, kf_yaw1) = keyframe_yaw(&est);
    assert_eq!(kf_id1, kf_id);
    let imu_yaw1 = est.imu_state().q_W_B.euler_angles().2;
    // The keyframe's pose holds the start's yaw: it moves by the shift.
    assert!(
        ((kf_yaw1 - kf_yaw0) - shift).abs() < 1e-3 * shift,
        "{} vs {shift}",
        kf_yaw1 - kf_yaw0
    );
    // The body's by its regression on it (its drift since is its own).
    let beta = p0[(2, col)] / p0[(col, col)];
    assert!(beta > 0.5 && beta < 1.01, "regression {beta}");
    assert!(((imu_yaw1 - imu_yaw0) - beta * shift).abs() < 1e-3 * shift);
    let dbg = (est.imu_state().b_g - bg0).z;
    let beta_bg = p0[(11, col)] / p0[(col, col)];
    assert!((dbg - beta_bg * shift).abs() < 1e-9 + 1e-6 * (beta_bg * shift).abs());
    // The covariance: a rank-one downdate along P e.
    let pe = p0.column(col).into_owned();
    let expected = &p0 - &pe * pe.transpose() * (drop / (p0[(col, col)] * p0[(col, col)]));
    let p1 = est.covariance();
    let err = (p1 - &expected).abs().max();
    assert!(err < 1e-12, "P differs from H1 by {err}");
    assert!((p0[(col, col)] - p1[(col, col)] - drop).abs() < 1e-12);
}

/// Bad arguments leave the filter as it was; Schmidt mode refuses.
#[test]
fn conditioning_refuses_what_it_cannot_do() {
    let mut est = standing(Mode::Compressed);
    let before = est.covariance().clone();
    let col = est.kf_offset(0) + 2;
    let var = before[(col, col)];
    assert!(matches!(
        est.condition_yaw_on_compass(f64::NAN, 1e-6),
        Err(YawConditionError::NotFinite { .. })
    ));
    assert!(matches!(
        est.condition_yaw_on_compass(0.01, 0.0),
        Err(YawConditionError::NotFinite { .. })
    ));
    assert!(matches!(
        est.condition_yaw_on_compass(0.01, var),
        Err(YawConditionError::DropTooLarge { .. })
    ));
    assert_eq!(est.covariance(), &before);
    let mut schmidt = standing(Mode::Schmidt);
    assert_eq!(
        schmidt.condition_yaw_on_compass(0.01, 1e-6),
        Err(YawConditionError::Schmidt)
    );
}
