//! Starting the filter (README §7): static initialisation recovers roll,
//! pitch and the gyro bias from the stationary start, and placing the world
//! origin at a single-point fix makes every position uncertain together.

use nalgebra::{DMatrix, Vector3};

use cmsckf::config::Config;
use cmsckf::estimator::{attitude_from_static, Mode};
use cmsckf::eval;
use cmsckf_sitl::dataset::Dataset;

mod common;
use common::flights::racetrack;

/// Static initialisation on the hover scenario's stationary start.
#[test]
fn static_initialisation_recovers_roll_pitch_and_gyro_bias() {
    let cfg = Config::default();
    let ds = Dataset::generate("hover", 5, Some(6.0), &eval::sim_config_for(&cfg)).unwrap();
    let window: Vec<_> = ds.imu.iter().take_while(|m| m.t_s < cfg.init.static_window_s).collect();
    let n = window.len() as f64;
    let acc = window.iter().map(|m| m.accel_mps2).sum::<Vector3<f64>>() / n;
    let gyr = window.iter().map(|m| m.gyro_radps).sum::<Vector3<f64>>() / n;
    let truth = &ds.truth[0];
    let yaw = truth.truth.q_W_B.euler_angles().2;
    let q = attitude_from_static(&acc, yaw).unwrap();
    // Tilt error from the accelerometer bias (≈ b_a / g) and noise.
    let err = q.angle_to(&truth.truth.q_W_B).to_degrees();
    let expected = (truth.bias.b_a.xy().norm() / 9.81).to_degrees();
    assert!(err < expected + 0.1, "attitude error {err}° (bias-limited {expected}°)");
    assert!(
        (gyr - truth.bias.b_g).norm() < 1e-3,
        "gyro bias {gyr} vs {}",
        truth.bias.b_g
    );
    assert!(attitude_from_static(&Vector3::new(f64::NAN, 0.0, -9.8), 0.0).is_none());
    assert!(attitude_from_static(&Vector3::zeros(), 0.0).is_none());
}

/// Placing the world origin at a single-point fix (§7, I2) makes every
/// position uncertain by the fix's sigma, all together: absolute position
/// variances grow by σ², relative ones (clone to clone, body to keyframe)
/// do not change.
#[test]
fn a_world_offset_moves_every_position_together() {
    let (ds, cfg) = racetrack(7, 12.0);
    let mut run = eval::Runner::new(&ds, &cfg, Mode::Full, 7);
    for k in 0..ds.frames.len() {
        run.step_frame(k);
    }
    let mut est = run.est.clone();
    est.sync();
    let before = est.covariance().clone();
    assert!(est.add_world_offset_variance(4.0));
    let body = 6;
    let kf = est.kf_offset(0) + 3;
    let clone = est.clones_offset() + 3;
    let p = est.covariance();
    for a in 0..3 {
        let (b, k, c) = (body + a, kf + a, clone + a);
        assert!((p[(b, b)] - before[(b, b)] - 4.0).abs() < 1e-9);
        assert!((p[(k, k)] - before[(k, k)] - 4.0).abs() < 1e-9);
        let rel = |m: &DMatrix<f64>, i: usize, j: usize| m[(i, i)] + m[(j, j)] - 2.0 * m[(i, j)];
        assert!((rel(p, b, k) - rel(&before, b, k)).abs() < 1e-9);
        assert!((rel(p, b, c) - rel(&before, b, c)).abs() < 1e-9);
        // Other axes and other states are untouched.
        assert_eq!(p[(b, (b + 1) % 3 + body)], before[(b, (b + 1) % 3 + body)]);
        assert_eq!(p[(0, b)], before[(0, b)]);
    }
    assert!(est.check_health().is_ok());
}
