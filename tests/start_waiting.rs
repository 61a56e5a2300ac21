//! A start that cannot happen says why, at once and again while it lasts:
//! a vehicle that is turning (so not still) with no LOCAL_POSITION_NED for
//! an in-flight start gets a STATUSTEXT naming both, and `init_waiting`
//! counts it; once the autopilot gives its position, the filter starts in
//! flight and the reports stop.

mod common;

use cmsckf::config::Config;
use cmsckf::counters::Counter;
use cmsckf::daemon::FusionMsg;
use cmsckf::estimator::ImuMeas;
use cmsckf::io::messages::Outbound;
use nalgebra::Vector3;

/// The STATUSTEXTs sent so far, and whether any estimate was.
fn drain(out_rx: &mut tokio::sync::mpsc::Receiver<Outbound>) -> (Vec<String>, bool) {
    let (mut texts, mut estimate) = (Vec::new(), false);
    while let Ok(o) = out_rx.try_recv() {
        if o.is_estimate() {
            estimate = true;
        }
        if let Outbound::StatusText { text, .. } = o {
            texts.push(text);
        }
    }
    (texts, estimate)
}

#[test]
fn a_turning_vehicle_without_a_position_says_why_it_waits_then_starts_in_flight() {
    let cfg = Config::default();
    let (mut f, ctx, mut out_rx) = common::level_fusion(cfg, 0.3);
    // Turning at 0.3 rad/s about the vertical: not still, whatever the bias.
    let imu = |t_s: f64| {
        FusionMsg::Imu(ImuMeas {
            t_s,
            accel_mps2: Vector3::new(0.0, 0.0, -9.80665),
            gyro_radps: Vector3::new(0.0, 0.0, 0.3),
        })
    };
    let t0 = 20.0;
    let rate_hz = 200.0;
    for k in 0..(12.0 * rate_hz) as usize {
        f.handle(imu(t0 + k as f64 / rate_hz), &ctx);
    }
    let (texts, estimate) = drain(&mut out_rx);
    assert!(!estimate, "no filter can start: no estimate is sent");
    let waiting: Vec<_> = texts.iter().filter(|t| t.contains("waiting")).collect();
    assert!(
        waiting
            .iter()
            .all(|t| t.contains("not still") && t.contains("LOCAL_POSITION_NED")),
        "{texts:?}"
    );
    // Said at once (after the static window), then every 5 s: 3 in 12 s.
    assert!((2..=4).contains(&waiting.len()), "{texts:?}");
    let said = ctx.counters.get(Counter::InitWaiting);
    assert_eq!(said, waiting.len() as u64);
    assert_eq!(
        ctx.counters.get(Counter::InitInFlight) + ctx.counters.get(Counter::InitStatic),
        0
    );

    // The autopilot's position arrives: an in-flight start, and silence.
    let t1 = t0 + 12.0;
    f.handle(
        FusionMsg::LocalPosition {
            t_s: t1,
            p_ned_m: Vector3::new(1.0, 2.0, -3.0),
            v_ned_mps: Vector3::zeros(),
        },
        &ctx,
    );
    // The first estimate's body-rate variance: no still window measured the
    // gyro's bias, so its prior is the sensor's specification
    // (`init.sigma_gyro_bias_in_flight_radps`, 0.05 rad/s), not a static
    // start's 0.005.
    let mut first_rate_var = None;
    for k in 0..(3.0 * rate_hz) as usize {
        f.handle(imu(t1 + k as f64 / rate_hz), &ctx);
        if first_rate_var.is_none() {
            while let Ok(o) = out_rx.try_recv() {
                if let Outbound::Odometry {
                    velocity_covariance, ..
                } = o
                {
                    first_rate_var = Some([15, 18, 20].map(|i| velocity_covariance[i] as f64));
                    break;
                }
            }
        }
    }
    let rate_var = first_rate_var.expect("an estimate after the start");
    assert!(
        rate_var
            .iter()
            .all(|v| *v > 0.9 * 0.05f64.powi(2) && *v < 2.0 * 0.05f64.powi(2)),
        "{rate_var:?}"
    );
    let (texts, estimate) = drain(&mut out_rx);
    assert_eq!(ctx.counters.get(Counter::InitInFlight), 1, "{texts:?}");
    assert!(
        estimate || first_rate_var.is_some(),
        "the started filter sends estimates"
    );
    assert_eq!(
        ctx.counters.get(Counter::InitWaiting),
        said,
        "no more waiting: {texts:?}"
    );
}
