//! A real IMU on an armed multirotor standing on the ground: its gyro off by
//! 0.088 rad/s (an uncompensated bias), its motors shaking both sensors
//! (gyro variance 0.007 rad²/s², the accelerometer 0.76 m/s² RMS about its
//! mean: the levels measured on a real vehicle). The vehicle is still all
//! the same: the filter starts statically within the static window, with
//! and without the autopilot's local position, and takes the bias from the
//! mean (the rate it sends is the vibration alone, about zero on average).
//! A vehicle turning at 0.3 rad/s, beyond any gyro's bias, is not still.

mod common;

use cmsckf::config::Config;
use cmsckf::counters::Counter;
use cmsckf::daemon::FusionMsg;
use cmsckf::estimator::ImuMeas;
use cmsckf::io::messages::Outbound;
use nalgebra::Vector3;

const RATE_HZ: f64 = 200.0;
const GRAVITY_MPS2: f64 = 9.80665;

/// Motor vibration as two lines per axis (aliased into the 200 Hz samples)
/// with their phases, and the IMU's own white noise, deterministic.
fn vibrating_sample(t_s: f64, k: usize, gyro_bias: Vector3<f64>, turn_radps: f64) -> ImuMeas {
    let line = |amp: f64, f_hz: f64, phase: f64| amp * (2.0 * std::f64::consts::PI * f_hz * t_s + phase).sin();
    let axis = |a: usize, amps: [f64; 2]| {
        let p = a as f64 * 1.3;
        line(amps[0], 37.0, p) + line(amps[1], 61.0, 2.0 * p + 0.7)
    };
    // A deterministic pseudo-noise (a hash of the sample index), ±1.
    let noise = |a: usize| {
        let h = ((k * 3 + a) as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15).rotate_left(17);
        (h as f64 / u64::MAX as f64) * 2.0 - 1.0
    };
    let gyro = Vector3::from_fn(|a, _| axis(a, [0.06, 0.03]) + 0.004 * noise(a)) + gyro_bias;
    let accel =
        Vector3::from_fn(|a, _| axis(a, [0.55, 0.3]) + 0.05 * noise(a + 3)) + Vector3::new(0.0, 0.0, -GRAVITY_MPS2);
    ImuMeas {
        t_s,
        accel_mps2: accel,
        gyro_radps: gyro + Vector3::new(0.0, 0.0, turn_radps),
    }
}

/// The estimates sent: when the first went out (s after `t0`), and the
/// mean of their body rates.
struct Sent {
    t0: f64,
    first: Option<f64>,
    w_sum: Vector3<f64>,
    n: f64,
}

impl Sent {
    fn new(t0: f64) -> Self {
        Self {
            t0,
            first: None,
            w_sum: Vector3::zeros(),
            n: 0.0,
        }
    }

    /// Takes what the fusion loop sent since the last call.
    fn take(&mut self, out_rx: &mut tokio::sync::mpsc::Receiver<Outbound>) {
        while let Ok(o) = out_rx.try_recv() {
            if let Outbound::Odometry { t_us, w_body_radps, .. } = o {
                self.first.get_or_insert(t_us as f64 * 1e-6 - self.t0);
                self.w_sum += w_body_radps;
                self.n += 1.0;
            }
        }
    }

    fn w_mean(&self) -> Vector3<f64> {
        self.w_sum / self.n.max(1.0)
    }
}

/// Flies `seconds` of the standing vehicle; returns the time of the first
/// estimate sent (after `t0`), and the mean body rate of the estimates.
fn stand(
    with_position: bool,
    turn_radps: f64,
    seconds: f64,
) -> (Option<f64>, Vector3<f64>, cmsckf::counters::Counters) {
    let (mut f, ctx, mut out_rx) = common::level_fusion(Config::default(), 1.0);
    let t0 = 30.0;
    let bias = Vector3::new(0.08, -0.03, 0.02);
    let mut sent = Sent::new(t0);
    for k in 0..(seconds * RATE_HZ) as usize {
        let t_s = t0 + k as f64 / RATE_HZ;
        if with_position && k % 20 == 0 {
            f.handle(
                FusionMsg::LocalPosition {
                    t_s,
                    p_ned_m: Vector3::new(0.5, -0.2, 0.0),
                    v_ned_mps: Vector3::zeros(),
                },
                &ctx,
            );
        }
        f.handle(FusionMsg::Imu(vibrating_sample(t_s, k, bias, turn_radps)), &ctx);
        sent.take(&mut out_rx);
    }
    (sent.first, sent.w_mean(), ctx.counters)
}

#[test]
fn a_vibrating_vehicle_with_a_biased_gyro_starts_still_and_takes_the_bias_from_the_mean() {
    for with_position in [false, true] {
        let (first, w_mean, counters) = stand(with_position, 0.0, 4.0);
        let first = first.unwrap_or_else(|| panic!("no start (position: {with_position}): {:?}", counters.snapshot()));
        assert!(
            first < 3.0,
            "started {first:.2} s after standing (position: {with_position})"
        );
        assert_eq!(counters.get(Counter::InitStatic), 1, "{:?}", counters.snapshot());
        assert_eq!(counters.get(Counter::InitInFlight), 0);
        // The rate sent is the gyro less the estimated bias: the bias came
        // from the mean, so what is left averages to about nothing.
        assert!(
            w_mean.norm() < 0.01,
            "mean body rate sent {w_mean:?} (the raw gyro's mean is 0.088 rad/s)"
        );
    }
}

#[test]
fn a_turn_beyond_any_gyro_bias_is_not_still() {
    let (first, _, counters) = stand(false, 0.3, 3.0);
    assert_eq!(first, None, "a turning vehicle without a position must not start");
    assert_eq!(counters.get(Counter::InitStatic), 0);
    assert!(counters.get(Counter::InitWaiting) >= 1, "and it says why");
}

/// A real IMU: PX4's `sensor_combined` on an armed CubeOrange standing on
/// the ground (`tests/data/px4_armed_ground_imu.csv`, from pyulog's test
/// logs, BSD-3; 5.5 s at 205 Hz with a 161 ms logger gap after the first
/// sample; its accelerometer reads 0.18 m/s² below g). It is still, and
/// the filter starts statically on it.
#[test]
fn a_real_armed_px4_imu_standing_on_the_ground_starts_still() {
    let csv = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/px4_armed_ground_imu.csv"
    ))
    .expect("tests/data/px4_armed_ground_imu.csv");
    let samples: Vec<ImuMeas> = csv
        .lines()
        .skip(1)
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.parse().expect("a number")).collect();
            ImuMeas {
                t_s: v[0] * 1e-6,
                gyro_radps: Vector3::new(v[1], v[2], v[3]),
                accel_mps2: Vector3::new(v[4], v[5], v[6]),
            }
        })
        .collect();
    assert!(samples.len() > 1000);
    let gyro_mean = samples.iter().map(|s| s.gyro_radps).sum::<Vector3<f64>>() / samples.len() as f64;
    let (mut f, ctx, mut out_rx) = common::level_fusion(Config::default(), 0.5);
    let t0 = samples[0].t_s;
    let mut sent = Sent::new(t0);
    for s in &samples {
        f.handle(FusionMsg::Imu(*s), &ctx);
        sent.take(&mut out_rx);
    }
    let first = sent.first;
    let counters = &ctx.counters;
    let first = first.unwrap_or_else(|| panic!("no start: {:?}", counters.snapshot()));
    assert!(first < 3.0, "started {first:.2} s after the first sample");
    assert_eq!(counters.get(Counter::InitStatic), 1, "{:?}", counters.snapshot());
    // The bias is the mean (4.7 mrad/s here): what is sent averages to less.
    let w_mean = sent.w_mean();
    assert!(
        w_mean.norm() < 0.3 * gyro_mean.norm(),
        "mean rate sent {w_mean:?}, the gyro's mean {gyro_mean:?}"
    );
}
