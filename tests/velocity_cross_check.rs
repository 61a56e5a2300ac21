//! D4 (README §9): our velocity against the autopilot's own. A filter
//! standing still while the autopilot, with a GNSS fix of its own, says the
//! vehicle flies at 8 m/s has diverged, though it has no tracks to say so:
//! the daemon resets it after 2 s of disagreement and tells the autopilot
//! why. Without a fix (the autopilot's velocity may be our echo), or when
//! they agree, nothing happens.

mod common;

use cmsckf::config::Config;
use cmsckf::counters::Counter;
use cmsckf::daemon::FusionMsg;
use cmsckf::estimator::ImuMeas;
use cmsckf::io::messages::Outbound;
use nalgebra::Vector3;

/// Stands for 3 s (a static start), then for 4 s hears the autopilot's
/// LOCAL_POSITION_NED at 10 Hz with velocity `v_ap` (and, with `fix`, its
/// GNSS accuracy, which says it has a fix of its own). Returns the resets
/// and the STATUSTEXTs, with the time of the first reset.
fn stand_while_the_autopilot_says(v_ap: Vector3<f64>, fix: bool) -> (u64, Vec<String>, Option<f64>) {
    let (mut f, ctx, mut out_rx) = common::level_fusion(Config::default(), 0.0);
    let imu = |t_s: f64| {
        FusionMsg::Imu(ImuMeas {
            t_s,
            accel_mps2: Vector3::new(0.0, 0.0, -9.80665),
            gyro_radps: Vector3::zeros(),
        })
    };
    let rate_hz = 200.0;
    let mut texts = Vec::new();
    let mut first_reset = None;
    for k in 0..(7.0 * rate_hz) as usize {
        let t = 10.0 + k as f64 / rate_hz;
        if t >= 13.0 && k % 20 == 0 {
            if fix {
                // A fix of its own, and the EKF origin its GNSS set: its
                // own position (`has_own_position`).
                f.handle(
                    FusionMsg::GpsAccuracy {
                        h_acc_m: 1.0,
                        v_acc_m: 1.5,
                    },
                    &ctx,
                );
                f.handle(
                    FusionMsg::Origin {
                        lat_deg: 47.3977432,
                        lon_deg: 8.5455942,
                        alt_m: 489.4,
                    },
                    &ctx,
                );
            }
            f.handle(
                FusionMsg::LocalPosition {
                    t_s: t,
                    p_ned_m: v_ap * (t - 13.0),
                    v_ned_mps: v_ap,
                },
                &ctx,
            );
        }
        f.handle(imu(t), &ctx);
        while let Ok(o) = out_rx.try_recv() {
            if let Outbound::StatusText { text, .. } = o {
                if first_reset.is_none() && text.contains("reset") {
                    first_reset = Some(t);
                }
                texts.push(text);
            }
        }
    }
    assert_eq!(ctx.counters.get(Counter::InitStatic), 1, "{texts:?}");
    (ctx.counters.get(Counter::FilterReset), texts, first_reset)
}

#[test]
fn a_velocity_far_from_the_autopilots_own_is_a_divergence() {
    let (resets, texts, t) = stand_while_the_autopilot_says(Vector3::new(8.0, 0.0, 0.0), true);
    assert!(resets >= 1, "{texts:?}");
    let t = t.expect("a reset said to the autopilot");
    assert!(
        (15.0..15.2).contains(&t),
        "reset at {t:.2} s, 2 s after the disagreement began at 13 s"
    );
    assert!(
        texts.iter().any(|s| s.contains("reset: divergence: velocity")),
        "{texts:?}"
    );
}

#[test]
fn no_fix_or_agreement_is_no_divergence() {
    // Without a fix of its own the autopilot's velocity may be our echo.
    let (resets, texts, _) = stand_while_the_autopilot_says(Vector3::new(8.0, 0.0, 0.0), false);
    assert_eq!(resets, 0, "{texts:?}");
    // With a fix, agreeing: standing.
    let (resets, texts, _) = stand_while_the_autopilot_says(Vector3::new(0.1, 0.0, 0.0), true);
    assert_eq!(resets, 0, "{texts:?}");
}
