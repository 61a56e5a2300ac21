//! The mock autopilot's own EKF: what its `LOCAL_POSITION_NED` and
//! `ATTITUDE` report. A real autopilot only knows its estimate, never the
//! truth, and the daemon starts (and, after a reset, restarts) its filter
//! from exactly these messages: a mock that reports the truth hands every
//! restart a perfect position and attitude, and the fault scores flatter the
//! daemon.
//!
//! The model ([`AutopilotSimConfig`] holds the magnitudes) keeps the
//! autopilot's *error* against the truth, so that the reported state moves
//! with the vehicle:
//!
//! - **Position error** `e_p` (NED, m): a first-order Gauss–Markov process
//!   per axis (stationary σ, correlation time τ of minutes), the slow wander
//!   of a GNSS-aided EKF. While the GNSS is out (the autopilot's receiver is
//!   the one the daemon hears) nothing pulls it back: it is a random walk
//!   with the same diffusion, `σ √(2 Δt / τ)` per step.
//! - **Following the daemon** (`follow_vpe`): ArduPilot's EK3 with external
//!   navigation as its position source fuses each `VISION_POSITION_ESTIMATE`.
//!   Here each estimate, compared at its own time with the truth, gives the
//!   daemon's error `e_v`; the innovation `e_v − e_p` is tested against
//!   `vpe_gate_sigma` times its sigma (the estimate's own variance plus the
//!   drift's, horizontal and vertical separately, as EK3's position gate
//!   does). Accepted, `e_p` moves toward `e_v` by `1 − exp(−Δt / τ_f)`;
//!   rejected, it is ignored. The first estimate, a change of its
//!   `reset_counter`, or `vpe_retry_s` of nothing but rejections reset `e_p`
//!   to `e_v`, as EK3 resets its position to external navigation. So a
//!   daemon that diverges fast (an IMU spike) is gated out, and a daemon
//!   that restarts is believed.
//! - **Attitude**: tilt (rotations about north and east) and yaw (about
//!   down) errors, each Gauss–Markov, applied in the world frame; the yaw is
//!   a compass's, degrees off, and does not follow the daemon.
//! - **Noise**: white noise on each message's position, velocity and
//!   angles.
//!
//! Nothing ever sets the error to zero: through a link drop or a reboot the
//! autopilot keeps estimating, unheard, and then reports where it believes
//! it is. The random draws come from the dataset's seed (its stream 7); what
//! the daemon sends back is not reproducible bit for bit, so neither is the
//! followed part.

use nalgebra::{UnitQuaternion, Vector3};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use crate::config::AutopilotSimConfig;
use crate::imu::gauss3;
use crate::trajectory::TruthSample;

/// The smallest variance the autopilot grants an estimate's position (m²):
/// EK3 floors the external navigation's noise the same way, and a daemon
/// claiming millimetres must not make every innovation fail the gate.
const MIN_VPE_VAR_M2: f64 = 0.1 * 0.1;

/// The variance the autopilot assumes for an estimate without a usable
/// covariance (m²): ArduPilot's VISO_POS_M_NSE default, 0.2 m.
const DEFAULT_VPE_VAR_M2: f64 = 0.2 * 0.2;

/// One `VISION_POSITION_ESTIMATE` as the autopilot fuses it.
#[derive(Clone, Copy, Debug)]
pub(super) struct VpeSample {
    /// Flight time of the estimate (s).
    pub(super) t_s: f64,
    pub(super) p_B_in_W: Vector3<f64>,
    /// Variances of north, east and down (m²), from its covariance.
    pub(super) var_m2: Vector3<f64>,
    pub(super) reset_counter: u8,
}

/// How the autopilot's own estimate fared, for the report.
#[derive(Clone, Debug, Default, Serialize)]
pub struct AutopilotReport {
    /// RMS and largest error of the reported position against the truth,
    /// over the 10 Hz messages (m).
    pub position_error_rms_m: f64,
    pub position_error_max_m: f64,
    /// Largest error of the reported yaw (deg).
    pub yaw_error_max_deg: f64,
    /// Daemon estimates fused, rejected by the gate, and reset to.
    pub vpe_fused: usize,
    pub vpe_rejected: usize,
    pub vpe_resets: usize,
}

/// The mock autopilot's EKF error state.
pub(super) struct AutopilotEkf {
    cfg: AutopilotSimConfig,
    rng: ChaCha8Rng,
    /// Reported minus true position, before white noise (NED, m).
    e_p_m: Vector3<f64>,
    /// Attitude error, a rotation vector in the world frame: tilt about
    /// north and east, yaw about down (rad).
    e_theta_W_rad: Vector3<f64>,
    /// Flight time of the last step (s).
    t_s: f64,
    /// `reset_counter` and flight time of the last estimate fused or reset to.
    last_fused: Option<(u8, f64)>,
    /// Flight time of the first of the current run of rejected estimates.
    rejecting_since_s: Option<f64>,
    sum_sq_error_m2: f64,
    reports: usize,
    pub(super) report: AutopilotReport,
    /// The largest position test ratios (horizontal, vertical) of the
    /// estimates tested since the last `EKF_STATUS_REPORT`, as EK3 reports
    /// them: `√(ν²/(g² S))`, over 1 when the estimate was rejected.
    ratios: Option<(f64, f64)>,
}

impl AutopilotEkf {
    /// The EKF at flight time 0, its errors drawn from their stationary
    /// distributions with `rng`.
    pub(super) fn new(cfg: &AutopilotSimConfig, mut rng: ChaCha8Rng) -> Self {
        let tilt = cfg.tilt_bias_sigma_deg.to_radians();
        let yaw = cfg.yaw_bias_sigma_deg.to_radians();
        let e_p_m = gauss3(&mut rng) * cfg.position_drift_sigma_m;
        let n = gauss3(&mut rng);
        let e_theta_W_rad = Vector3::new(n.x * tilt, n.y * tilt, n.z * yaw);
        Self {
            cfg: cfg.clone(),
            rng,
            e_p_m,
            e_theta_W_rad,
            t_s: 0.0,
            last_fused: None,
            rejecting_since_s: None,
            ratios: None,
            sum_sq_error_m2: 0.0,
            reports: 0,
            report: AutopilotReport::default(),
        }
    }

    /// Moves the error processes on to flight time `t_s`; `gnss_out`: the
    /// autopilot has no GNSS, so its position error walks freely.
    pub(super) fn advance(&mut self, t_s: f64, gnss_out: bool) {
        let dt = t_s - self.t_s;
        // Not forward (or NaN): nothing to do.
        if dt.is_nan() || dt <= 0.0 {
            return;
        }
        self.t_s = t_s;
        let c = &self.cfg;
        let n = gauss3(&mut self.rng);
        self.e_p_m = if gnss_out {
            self.e_p_m + n * c.position_drift_sigma_m * (2.0 * dt / c.position_drift_time_s).sqrt()
        } else {
            gauss_markov(self.e_p_m, n, c.position_drift_sigma_m, c.position_drift_time_s, dt)
        };
        let n = gauss3(&mut self.rng);
        let tilt = gauss_markov(
            self.e_theta_W_rad,
            n,
            c.tilt_bias_sigma_deg.to_radians(),
            c.tilt_bias_time_s,
            dt,
        );
        let yaw = gauss_markov(
            self.e_theta_W_rad,
            n,
            c.yaw_bias_sigma_deg.to_radians(),
            c.yaw_bias_time_s,
            dt,
        );
        self.e_theta_W_rad = Vector3::new(tilt.x, tilt.y, yaw.z);
    }

    /// Fuses one of the daemon's estimates, `p_true` being the truth at its
    /// time (see the module's doc for the gate and the resets).
    pub(super) fn fuse(&mut self, v: &VpeSample, p_true: &Vector3<f64>) {
        if !self.cfg.follow_vpe {
            return;
        }
        let e_v = v.p_B_in_W - p_true;
        if !(e_v.iter().all(|x| x.is_finite()) && v.t_s.is_finite()) {
            self.report.vpe_rejected += 1;
            return;
        }
        let reset = match self.last_fused {
            None => true,
            Some((counter, _)) => counter != v.reset_counter,
        } || self
            .rejecting_since_s
            .is_some_and(|t0| v.t_s - t0 >= self.cfg.vpe_retry_s);
        if reset {
            self.e_p_m = e_v;
            self.last_fused = Some((v.reset_counter, v.t_s));
            self.rejecting_since_s = None;
            self.report.vpe_resets += 1;
            return;
        }
        if !self.passes_gate(&(e_v - self.e_p_m), &v.var_m2) {
            self.rejecting_since_s.get_or_insert(v.t_s);
            self.report.vpe_rejected += 1;
            return;
        }
        let t_prev = self.last_fused.map_or(v.t_s, |(_, t)| t);
        let dt = (v.t_s - t_prev).clamp(0.0, 1.0);
        let k = 1.0 - (-dt / self.cfg.follow_time_s).exp();
        self.e_p_m += k * (e_v - self.e_p_m);
        self.last_fused = Some((v.reset_counter, v.t_s.max(t_prev)));
        self.rejecting_since_s = None;
        self.report.vpe_fused += 1;
    }

    /// The largest position test ratios (horizontal, vertical) since the
    /// last call, `None` when no estimate was tested (`EKF_STATUS_REPORT`'s
    /// `pos_horiz_variance` and `pos_vert_variance`, which ArduPilot fills
    /// with the square roots of its test ratios).
    pub(super) fn take_ratios(&mut self) -> Option<(f64, f64)> {
        self.ratios.take()
    }

    /// EK3's position gate: the squared innovation within `gate²` times its
    /// variance (the estimate's, floored, or VISO_POS_M_NSE's when it is
    /// not finite, plus the drift's), horizontally and vertically. Keeps the
    /// test ratios for the status report.
    fn passes_gate(&mut self, innovation_m: &Vector3<f64>, var_m2: &Vector3<f64>) -> bool {
        let own = self.cfg.position_drift_sigma_m.powi(2);
        let s = var_m2.map(|v| {
            if v.is_finite() {
                v.max(MIN_VPE_VAR_M2)
            } else {
                DEFAULT_VPE_VAR_M2
            }
        }) + Vector3::repeat(own);
        let g2 = self.cfg.vpe_gate_sigma.powi(2);
        let ratio_h = (innovation_m.x.powi(2) + innovation_m.y.powi(2)) / (g2 * (s.x + s.y));
        let ratio_v = innovation_m.z.powi(2) / (g2 * s.z);
        let (h, v) = self.ratios.unwrap_or((0.0, 0.0));
        self.ratios = Some((h.max(ratio_h.sqrt()), v.max(ratio_v.sqrt())));
        ratio_h <= 1.0 && ratio_v <= 1.0
    }

    /// The reported position and velocity for the truth `s`, with white noise.
    pub(super) fn local_position(&mut self, s: &TruthSample) -> (Vector3<f64>, Vector3<f64>) {
        let p = s.p_B_in_W + self.e_p_m + gauss3(&mut self.rng) * self.cfg.position_noise_m;
        let v = s.v_B_in_W + gauss3(&mut self.rng) * self.cfg.velocity_noise_mps;
        let e = (p - s.p_B_in_W).norm();
        self.sum_sq_error_m2 += e * e;
        self.reports += 1;
        self.report.position_error_max_m = self.report.position_error_max_m.max(e);
        self.report.position_error_rms_m = (self.sum_sq_error_m2 / self.reports as f64).sqrt();
        (p, v)
    }

    /// The reported attitude for the true `q_W_B`, with white noise: roll,
    /// pitch and yaw (rad).
    pub(super) fn attitude(&mut self, q_W_B: &UnitQuaternion<f64>) -> (f64, f64, f64) {
        let tilt = self.cfg.tilt_noise_deg.to_radians();
        let yaw = self.cfg.yaw_noise_deg.to_radians();
        let n = gauss3(&mut self.rng);
        let e = self.e_theta_W_rad + Vector3::new(n.x * tilt, n.y * tilt, n.z * yaw);
        let (r, p, y) = (UnitQuaternion::from_scaled_axis(e) * q_W_B).euler_angles();
        let dy = (y - q_W_B.euler_angles().2 + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
            - std::f64::consts::PI;
        self.report.yaw_error_max_deg = self.report.yaw_error_max_deg.max(dy.abs().to_degrees());
        (r, p, y)
    }
}

/// One step `dt` of a first-order Gauss–Markov process with stationary
/// sigma `sigma` and correlation time `tau_s`, from `x` with the standard
/// normal draws `n`: the variance stays `sigma²` at every step size.
fn gauss_markov(x: Vector3<f64>, n: Vector3<f64>, sigma: f64, tau_s: f64, dt: f64) -> Vector3<f64> {
    let phi = (-dt / tau_s).exp();
    x * phi + n * sigma * (1.0 - phi * phi).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn rng() -> ChaCha8Rng {
        ChaCha8Rng::seed_from_u64(7)
    }

    fn vpe(t_s: f64, p: Vector3<f64>, counter: u8) -> VpeSample {
        VpeSample {
            t_s,
            p_B_in_W: p,
            var_m2: Vector3::repeat(0.04),
            reset_counter: counter,
        }
    }

    #[test]
    fn gauss_markov_keeps_its_stationary_variance() {
        let mut r = rng();
        let (mut sum, mut n) = (0.0, 0);
        let mut x = Vector3::zeros();
        for k in 0..200_000 {
            x = gauss_markov(x, gauss3(&mut r), 0.5, 120.0, 0.1);
            if k > 20_000 {
                sum += x.norm_squared() / 3.0;
                n += 1;
            }
        }
        let sigma = (sum / n as f64).sqrt();
        assert!((sigma - 0.5).abs() < 0.1, "{sigma}");
    }

    #[test]
    fn truth_config_reports_the_truth() {
        let mut ap = AutopilotEkf::new(&AutopilotSimConfig::truth(), rng());
        ap.advance(10.0, false);
        ap.fuse(&vpe(9.9, Vector3::new(5.0, 0.0, 0.0), 0), &Vector3::zeros());
        let s = TruthSample {
            t_s: 10.0,
            p_B_in_W: Vector3::new(1.0, 2.0, 3.0),
            v_B_in_W: Vector3::new(0.5, 0.0, 0.0),
            a_B_in_W: Vector3::zeros(),
            q_W_B: UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3),
            w_B: Vector3::zeros(),
        };
        let (p, v) = ap.local_position(&s);
        assert_eq!(p, s.p_B_in_W);
        assert_eq!(v, s.v_B_in_W);
        let (r, pi, y) = ap.attitude(&s.q_W_B);
        assert!((r - 0.1).abs() < 1e-12 && (pi - 0.2).abs() < 1e-12 && (y - 0.3).abs() < 1e-12);
    }

    #[test]
    fn follows_the_daemon_gates_a_runaway_and_believes_a_reset() {
        let cfg = AutopilotSimConfig {
            position_drift_sigma_m: 0.0,
            ..AutopilotSimConfig::default()
        };
        let mut ap = AutopilotEkf::new(&cfg, rng());
        let zero = Vector3::zeros();
        // The first estimate is a reset; then the error follows a steady
        // 1 m offset within a few time constants.
        ap.fuse(&vpe(0.0, Vector3::new(0.2, 0.0, 0.0), 0), &zero);
        assert!((ap.e_p_m.x - 0.2).abs() < 1e-12);
        for k in 1..=150 {
            ap.fuse(&vpe(k as f64 / 30.0, Vector3::new(1.0, 0.0, 0.0), 0), &zero);
        }
        assert!((ap.e_p_m.x - 1.0).abs() < 0.05, "{}", ap.e_p_m.x);
        // A runaway (50 m/s² for a second) is followed only while it is
        // within the gate: the autopilot stays within metres.
        for k in 1..=30 {
            let t = k as f64 / 30.0;
            ap.fuse(&vpe(5.0 + t, Vector3::new(1.0 + 25.0 * t * t, 0.0, 0.0), 0), &zero);
        }
        assert!(ap.e_p_m.x < 5.0 && ap.report.vpe_rejected > 10, "{:?}", ap.e_p_m);
        // The daemon resets (a new counter) near the autopilot's estimate:
        // believed at once.
        ap.fuse(&vpe(7.0, Vector3::new(2.0, 0.0, 0.0), 1), &zero);
        assert_eq!(ap.e_p_m.x, 2.0);
        assert_eq!(ap.report.vpe_resets, 2);
    }

    #[test]
    fn holds_and_walks_without_the_daemon_or_gnss() {
        let mut ap = AutopilotEkf::new(&AutopilotSimConfig::default(), rng());
        let zero = Vector3::zeros();
        ap.fuse(&vpe(0.0, Vector3::new(3.0, 0.0, 0.0), 0), &zero);
        // Five seconds unheard (a link drop): still about 3 m off, not the truth.
        for k in 1..=50 {
            ap.advance(k as f64 * 0.1, false);
        }
        assert!((ap.e_p_m.x - 3.0).abs() < 0.6, "{}", ap.e_p_m.x);
        // A long GNSS outage from the truth: a random walk that wanders
        // off (σ ≈ 1.6 m per axis after 10 min), not pulled back to zero.
        ap.e_p_m = zero;
        let mut far = 0.0f64;
        for k in 51..=6000 {
            ap.advance(k as f64 * 0.1, true);
            far = far.max(ap.e_p_m.norm());
        }
        assert!(far > 1.0, "{far}");
    }
}
