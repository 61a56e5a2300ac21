//! Flying blind: with no camera frame and no GNSS epoch for 70 s, the
//! fusion loop carries the filter along behind the IMU. The covariance in
//! the outputs grows as dead reckoning's error does (it stayed frozen at the
//! last update's), and the IMU buffer never overflows (after 41 s it did,
//! and the output ran kilometres off).

mod common;

use cmsckf::config::Config;
use cmsckf::daemon::FusionMsg;
use cmsckf::estimator::ImuMeas;
use cmsckf::io::messages::Outbound;
use nalgebra::Vector3;

#[test]
fn seventy_seconds_blind_grow_the_covariance_and_lose_no_imu() {
    let cfg = Config::default();
    let (mut f, ctx, mut out_rx) = common::level_fusion(cfg, 0.0);
    // (time, x variance) of each estimate sent.
    let mut var_x: Vec<(f64, f64)> = Vec::new();
    let t0 = 10.0;
    for k in 0..7000 {
        let t_s = t0 + 0.01 * k as f64;
        f.handle(
            FusionMsg::Imu(ImuMeas {
                t_s,
                accel_mps2: Vector3::new(0.0, 0.0, -9.80665),
                gyro_radps: Vector3::zeros(),
            }),
            &ctx,
        );
        while let Ok(m) = out_rx.try_recv() {
            // ODOMETRY (the default) or VPE: the same [x y z r p y] layout.
            if let Outbound::Odometry {
                t_us,
                pose_covariance: covariance,
                ..
            }
            | Outbound::VisionPositionEstimate { t_us, covariance, .. } = m
            {
                var_x.push((t_us as f64 * 1e-6, covariance[0] as f64));
            }
        }
    }
    let c = |k: &str| ctx.counters.get_by_name(k);
    assert_eq!(c("imu_rejected"), 0, "the IMU buffer overflowed");
    assert_eq!(c("filter_reset"), 0);
    let at = |t: f64| {
        var_x
            .iter()
            .find(|(u, _)| *u >= t)
            .map(|v| v.1)
            .unwrap_or_else(|| panic!("no estimate at {t} s"))
    };
    let (early, late) = (at(t0 + 5.0), at(t0 + 65.0));
    eprintln!(
        "σx at 5 s {:.3} m, at 65 s {:.3} m; {} estimates",
        early.sqrt(),
        late.sqrt(),
        var_x.len()
    );
    // Estimates all the way, at the output rate.
    assert!(var_x.len() as f64 > 0.9 * 30.0 * 68.0, "{} estimates", var_x.len());
    // Unobserved, the position's σ grows: by far more than the 1 s the
    // filter may lag the IMU could explain.
    assert!(
        late > 4.0 * early,
        "σx {:.3} m at 5 s, {:.3} m at 65 s",
        early.sqrt(),
        late.sqrt()
    );
    // And it grows steadily, never frozen for long: over each 10 s.
    for w in 0..6 {
        let (a, b) = (at(t0 + 5.0 + 10.0 * w as f64), at(t0 + 15.0 + 10.0 * w as f64));
        assert!(b > a, "σx frozen between {} and {} s", 5 + 10 * w, 15 + 10 * w);
    }
}
