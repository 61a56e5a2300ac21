//! IMU sensor model: specific force and body rate from the truth, plus white
//! noise and bias random walk drawn from continuous-time densities, and an
//! armed multirotor's motor vibration (`[vibration]`; the default config's).
//!
//! Discretisation (sample period `dt`): white noise has standard deviation
//! `σ/√dt`; the bias random walk steps by `σ_b·√dt` per sample. The biases are
//! those in force at the sample time and are part of the truth.

use nalgebra::Vector3;
use rand::Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use cmsckf_models::check::{Check, FieldError, Validate};

use crate::trajectory::{gravity_w, TruthSample};
use cmsckf_models::sensors::ImuConfig;

/// One IMU measurement in the body (FRD) frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuSample {
    pub t_s: f64,
    /// Specific force (m/s²).
    pub accel_mps2: Vector3<f64>,
    /// Angular rate (rad/s).
    pub gyro_radps: Vector3<f64>,
}

/// The true biases at a sample time.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ImuBias {
    pub b_a: Vector3<f64>,
    pub b_g: Vector3<f64>,
}

pub(crate) fn gauss3<R: Rng>(rng: &mut R) -> Vector3<f64> {
    Vector3::new(
        rng.sample(StandardNormal),
        rng.sample(StandardNormal),
        rng.sample(StandardNormal),
    )
}

/// Motor vibration of an armed multirotor (`[vibration]` in the
/// simulator's TOML): lines at the motors' frequencies as the IMU's sampling
/// aliases them, each on every axis with a phase of its own, added to the
/// gyro and the accelerometer. Zero-mean, so a still vehicle stays still on
/// average. `Default` has no line; the simulator's default config
/// (`SimConfig::new`) has `armed_multirotor`'s.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct VibrationConfig {
    /// `[frequency Hz, amplitude rad/s]` of each gyro line, per axis.
    pub gyro_lines: Vec<[f64; 2]>,
    /// `[frequency Hz, amplitude m/s²]` of each accelerometer line, per axis.
    pub accel_lines: Vec<[f64; 2]>,
}

/// Most lines of each sensor.
const MAX_VIBRATION_LINES: usize = 16;

impl VibrationConfig {
    /// An armed multirotor at the levels measured on a real one (an
    /// ADIS16448 at 200 Hz, motors running, on the ground): gyro variance
    /// about 0.007 rad²/s² summed over the axes, the accelerometer 0.76 m/s²
    /// RMS (norm) about its mean; two lines aliased to 37 and 61 Hz.
    pub fn armed_multirotor() -> Self {
        Self {
            gyro_lines: vec![[37.0, 0.06], [61.0, 0.03]],
            accel_lines: vec![[37.0, 0.55], [61.0, 0.3]],
        }
    }
}

impl Validate for VibrationConfig {
    fn validate(&self, prefix: &str) -> Result<(), FieldError> {
        let c = Check::new(prefix);
        for (field, lines, amp_max) in [
            ("gyro_lines", &self.gyro_lines, 10.0),
            ("accel_lines", &self.accel_lines, 50.0),
        ] {
            if lines.len() > MAX_VIBRATION_LINES {
                return Err(c.fail(
                    field,
                    format!("{} lines", lines.len()),
                    format!("give at most {MAX_VIBRATION_LINES}"),
                ));
            }
            for (k, [f_hz, amp]) in lines.iter().enumerate() {
                c.positive(&format!("{field}[{k}][0] (Hz)"), *f_hz, 10_000.0)?;
                c.range(&format!("{field}[{k}][1]"), *amp, 0.0, amp_max)?;
            }
        }
        Ok(())
    }
}

/// One flight's vibration: `(frequency Hz, amplitude, phase rad per axis)`
/// of each line.
#[derive(Clone, Debug, Default)]
struct Vibration {
    gyro: Vec<(f64, f64, [f64; 3])>,
    accel: Vec<(f64, f64, [f64; 3])>,
}

impl Vibration {
    fn new<R: Rng>(cfg: &VibrationConfig, rng: &mut R) -> Self {
        let mut draw = |lines: &[[f64; 2]]| {
            lines
                .iter()
                .map(|[f, a]| {
                    let phase = [0; 3].map(|_| rng.random_range(0.0..std::f64::consts::TAU));
                    (*f, *a, phase)
                })
                .collect()
        };
        Self {
            gyro: draw(&cfg.gyro_lines),
            accel: draw(&cfg.accel_lines),
        }
    }

    /// The sum of `lines` at time `t_s`, per axis.
    fn at(lines: &[(f64, f64, [f64; 3])], t_s: f64) -> Vector3<f64> {
        let mut v = Vector3::zeros();
        for (f_hz, amp, phase) in lines {
            for k in 0..3 {
                v[k] += amp * (std::f64::consts::TAU * f_hz * t_s + phase[k]).sin();
            }
        }
        v
    }
}

/// Stateful IMU model (the bias walks between samples).
pub struct ImuModel {
    cfg: ImuConfig,
    dt_s: f64,
    bias: ImuBias,
    vibration: Vibration,
}

impl ImuModel {
    pub fn new(cfg: &ImuConfig, rate_hz: f64, bias0: ImuBias) -> Self {
        Self {
            cfg: cfg.clone(),
            dt_s: 1.0 / rate_hz,
            bias: bias0,
            vibration: Vibration::default(),
        }
    }

    /// The same, shaken by `vibration` (its phases drawn from `rng`).
    pub fn with_vibration<R: Rng>(mut self, vibration: &VibrationConfig, rng: &mut R) -> Self {
        self.vibration = Vibration::new(vibration, rng);
        self
    }

    pub fn bias(&self) -> ImuBias {
        self.bias
    }

    /// The noise-free measurement: `f_B = R_W_Bᵀ (a_W − g_W)`, `ω_B`.
    pub fn ideal(truth: &TruthSample, gravity_mps2: f64) -> ImuSample {
        ImuSample {
            t_s: truth.t_s,
            accel_mps2: truth
                .q_W_B
                .inverse_transform_vector(&(truth.a_B_in_W - gravity_w(gravity_mps2))),
            gyro_radps: truth.w_B,
        }
    }

    /// Measures the truth, then advances the bias random walk by one sample.
    pub fn measure<R: Rng>(&mut self, truth: &TruthSample, rng: &mut R) -> (ImuSample, ImuBias) {
        let ideal = Self::ideal(truth, self.cfg.gravity_mps2);
        let sq = self.dt_s.sqrt();
        let bias = self.bias;
        let s = ImuSample {
            t_s: truth.t_s,
            accel_mps2: ideal.accel_mps2
                + bias.b_a
                + gauss3(rng) * (self.cfg.accel_noise_density / sq)
                + Vibration::at(&self.vibration.accel, truth.t_s),
            gyro_radps: ideal.gyro_radps
                + bias.b_g
                + gauss3(rng) * (self.cfg.gyro_noise_density / sq)
                + Vibration::at(&self.vibration.gyro, truth.t_s),
        };
        self.bias.b_a += gauss3(rng) * (self.cfg.accel_random_walk * sq);
        self.bias.b_g += gauss3(rng) * (self.cfg.gyro_random_walk * sq);
        (s, bias)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trajectory::{racetrack, GustField, RacetrackParams};
    use nalgebra::UnitQuaternion;

    /// The armed vibration at 200 Hz has the levels it is set to, and is
    /// zero-mean: a still vehicle's IMU averages to its truth and bias.
    #[test]
    fn armed_vibration_has_its_levels_and_no_mean() {
        use crate::rng::rng_for;
        let still = TruthSample {
            t_s: 0.0,
            p_B_in_W: Vector3::zeros(),
            v_B_in_W: Vector3::zeros(),
            a_B_in_W: Vector3::zeros(),
            q_W_B: nalgebra::UnitQuaternion::identity(),
            w_B: Vector3::zeros(),
        };
        let cfg = ImuConfig::default();
        let mut rng = rng_for(1, 2);
        let mut m = ImuModel::new(&cfg, 200.0, ImuBias::default())
            .with_vibration(&VibrationConfig::armed_multirotor(), &mut rng_for(1, 7));
        let n = 2000;
        let samples: Vec<ImuSample> = (0..n)
            .map(|k| {
                let t = TruthSample {
                    t_s: k as f64 / 200.0,
                    ..still
                };
                m.measure(&t, &mut rng).0
            })
            .collect();
        let mean = |f: &dyn Fn(&ImuSample) -> Vector3<f64>| samples.iter().map(f).sum::<Vector3<f64>>() / n as f64;
        let g_mean = mean(&|s| s.gyro_radps);
        let a_mean = mean(&|s| s.accel_mps2);
        let g_var = samples
            .iter()
            .map(|s| (s.gyro_radps - g_mean).norm_squared())
            .sum::<f64>()
            / n as f64;
        let a_rms = (samples
            .iter()
            .map(|s| (s.accel_mps2 - a_mean).norm_squared())
            .sum::<f64>()
            / n as f64)
            .sqrt();
        assert!((0.006..0.0085).contains(&g_var), "gyro variance {g_var}");
        assert!((0.7..0.85).contains(&a_rms), "accelerometer RMS {a_rms}");
        assert!(g_mean.norm() < 2e-3, "gyro mean {g_mean:?}");
        let ideal = ImuModel::ideal(&still, cfg.gravity_mps2).accel_mps2;
        assert!((a_mean - ideal).norm() < 0.02, "accelerometer mean {a_mean:?}");
        assert!(VibrationConfig::armed_multirotor().validate("vibration").is_ok());
        let bad = VibrationConfig {
            gyro_lines: vec![[-1.0, 0.1]],
            ..Default::default()
        };
        assert!(bad.validate("vibration").is_err());
    }

    /// Integrates noise-free IMU samples (biases known, here zero) with RK4
    /// on (q, v, p) and checks the drift against the truth.
    #[test]
    fn integrating_ideal_imu_reproduces_the_trajectory() {
        let tr = racetrack(&RacetrackParams::default(), 70.0, 0.0, &GustField::default());
        let g = 9.81;
        let rate = 400.0;
        let dt = 1.0 / rate;
        let s0 = tr.sample(0.0);
        let (mut q, mut v, mut p) = (s0.q_W_B, s0.v_B_in_W, s0.p_B_in_W);
        let n = (60.0 * rate) as usize;
        let meas = |k: usize| ImuModel::ideal(&tr.sample(k as f64 * dt), g);
        let mid = |k: usize| ImuModel::ideal(&tr.sample((k as f64 + 0.5) * dt), g);
        let mut max_p_err: f64 = 0.0;
        let mut max_r_err: f64 = 0.0;
        for k in 0..n {
            let (m0, mh, m1) = (meas(k), mid(k), meas(k + 1));
            // RK4 on q̇ = ½ q ⊗ ω, v̇ = R f + g, ṗ = v.
            let deriv =
                |q: &UnitQuaternion<f64>, v: &Vector3<f64>, m: &ImuSample| (q * m.accel_mps2 + gravity_w(g), *v);
            let rot = |q: &UnitQuaternion<f64>, w: &Vector3<f64>, h: f64| q * UnitQuaternion::from_scaled_axis(w * h);
            let q_h = rot(&q, &((m0.gyro_radps + mh.gyro_radps) * 0.5), 0.5 * dt);
            let q_1 = rot(&q_h, &((mh.gyro_radps + m1.gyro_radps) * 0.5), 0.5 * dt);
            let (a1, v1) = deriv(&q, &v, &m0);
            let (a2, v2) = deriv(&q_h, &(v + a1 * 0.5 * dt), &mh);
            let (a3, v3) = deriv(&q_h, &(v + a2 * 0.5 * dt), &mh);
            let (a4, v4) = deriv(&q_1, &(v + a3 * dt), &m1);
            p += (v1 + 2.0 * v2 + 2.0 * v3 + v4) * (dt / 6.0);
            v += (a1 + 2.0 * a2 + 2.0 * a3 + a4) * (dt / 6.0);
            q = q_1;
            let t = tr.sample((k + 1) as f64 * dt);
            max_p_err = max_p_err.max((p - t.p_B_in_W).norm());
            max_r_err = max_r_err.max(q.angle_to(&t.q_W_B));
        }
        // Stated bound: after 60 s of a 15 m/s racetrack at 400 Hz, the
        // integrated ideal IMU stays within 1 cm and 1e-5 rad of the truth.
        assert!(max_p_err < 0.01, "position drift {max_p_err} m");
        assert!(max_r_err < 1e-5, "rotation drift {max_r_err} rad");
    }
}
