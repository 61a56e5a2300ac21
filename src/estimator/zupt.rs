//! Standstill (README.md §3c): a drone waits on the ground before take-off
//! and hovers in flight. With no camera motion a track has no parallax, so
//! the MSCKF has nothing to triangulate, and the IMU alone would let the
//! velocity random-walk. So a frame taken while the vehicle is still is a
//! zero-velocity update (`v_B_in_W = 0`) instead of a new clone: it adds no
//! pose to the window, and the tracks wait for the motion that gives them
//! parallax (OpenVINS does the same).
//!
//! Still means all of: since the last frame, a mean body rate that is small
//! and a mean specific force equal to gravity's (in size and direction),
//! each within what the samples' own scatter allows (an armed multirotor's
//! motors shake every sample by more than a turn would, but the shaking is
//! zero-mean), and that scatter within a vibration ceiling; the features not
//! moving in the image since the last clone; the estimated speed small; and
//! the update itself passing its χ² gate.

use crate::counters::Counter;
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

use super::propagate::{BG, TH, V};
use super::{math, Estimator, ImuMeas, ImuState, NormObs, Stillness};

/// Z1's block on the attitude error `δθ` (world frame): the body-frame
/// velocity `R_W_Bᵀ v`, rotated back by the estimate's `R̂_W_B`, is
/// `Exp(−δθ) (v̂ + δv)`, whose derivative in `δθ` is `[v]×` (and `I` in
/// `δv`), taken at the velocity's first estimate `v^FE` so that the
/// unobservable yaw `N = [g; −[v^FE]× g]` stays in its null space (§3d F6).
fn body_velocity_theta_jacobian(v_fe: &Vector3<f64>) -> Matrix3<f64> {
    math::skew(v_fe)
}

/// Fewest features seen both now and at the last clone to judge disparity.
const MIN_COMMON_FEATURES: usize = 5;

/// Probability of the zero-velocity update's χ² gate (6 degrees of freedom).
const ZUPT_GATE_PROB: f64 = 0.99;

impl Stillness {
    /// Adds one IMU sample, its biases removed with the current estimate:
    /// at rest `a_m − b_a = −R_W_Bᵀ g_W`, so the departure is
    /// `a_m − b_a + R_W_Bᵀ g_W`.
    pub(super) fn push(&mut self, m: &ImuMeas, dt_s: f64, x: &ImuState, g_W: &Vector3<f64>) {
        self.samples += 1;
        self.gyro_integral_rad += m.gyro_radps * dt_s;
        self.span_s += dt_s;
        let w = m.gyro_radps - x.b_g;
        self.gyro_sum_radps += w;
        self.gyro_sq_sum += w.norm_squared();
        let dev = m.accel_mps2 - x.b_a + x.q_W_B.inverse() * g_W;
        self.accel_dev_sum_mps2 += dev;
        self.accel_dev_sq_sum += dev.norm_squared();
    }

    /// The mean measured rate `(∫ω_m dt)/T` over the interval (rad/s, the
    /// bias not removed); `None` over no time.
    pub(super) fn mean_rate_radps(&self) -> Option<Vector3<f64>> {
        (self.span_s > 0.0).then(|| self.gyro_integral_rad / self.span_s)
    }

    /// `(|mean|, scatter)` of a quantity from its sums: the mean's size and
    /// the samples' RMS about it (summed over the axes).
    fn mean_and_scatter(sum: &Vector3<f64>, sq_sum: f64, n: f64) -> (f64, f64) {
        let mean = sum / n;
        (mean.norm(), (sq_sum / n - mean.norm_squared()).max(0.0).sqrt())
    }

    /// The body rate's `(|mean|, scatter)` (rad/s).
    fn gyro(&self) -> (f64, f64) {
        Self::mean_and_scatter(&self.gyro_sum_radps, self.gyro_sq_sum, f64::from(self.samples.max(1)))
    }

    /// The specific force's departure from gravity: `(|mean|, scatter)` (m/s²).
    fn accel(&self) -> (f64, f64) {
        Self::mean_and_scatter(
            &self.accel_dev_sum_mps2,
            self.accel_dev_sq_sum,
            f64::from(self.samples.max(1)),
        )
    }
}

impl Estimator {
    /// Whether zero-velocity updates may be taken at all: the caller knows
    /// what the IMU and camera cannot tell apart, a vehicle on the ground
    /// from one hovering (which drifts at centimetres per second, and a
    /// zero-velocity update would pin it). True by default.
    pub(super) fn allow_zupt(&mut self, allowed: bool) {
        self.zupt_allowed = allowed;
    }

    /// Median displacement (normalised units) of the features seen both in
    /// `obs` and at their track's last clone; `None` with too few in common.
    /// Reuses the estimator's buffer: no allocation once it has grown.
    fn median_disparity(&mut self, obs: &[NormObs]) -> Option<f64> {
        let mut d = std::mem::take(&mut self.disparity_buf);
        d.clear();
        d.extend(obs.iter().filter_map(|o| {
            let last = self.tracks.get(&o.landmark_id)?.obs.last()?;
            Some((o.xn - last.1.xn).norm())
        }));
        let median = if d.len() < MIN_COMMON_FEATURES {
            None
        } else {
            cmsckf_models::stats::percentile(&mut d, 0.5)
        };
        self.disparity_buf = d;
        median
    }

    /// The frame's median feature displacement since the last clone, when
    /// zero-velocity updates may be taken (`None` otherwise, or with too
    /// few features in common); and the camera's own verdict that the
    /// vehicle moved (past `zupt.max_disparity`), counted whatever the
    /// IMU's tests say: what tells the caller a vehicle has begun to move
    /// (a take-off's end of the spin-up, `daemon::autopilot`).
    pub(super) fn camera_disparity(&mut self, obs: &[NormObs]) -> (Option<f64>, bool) {
        let z = self.s.zupt;
        let disparity = if z.enabled && self.zupt_allowed {
            self.median_disparity(obs)
        } else {
            None
        };
        let moved = disparity.is_some_and(|d| d > z.max_disparity);
        if moved {
            self.stats.zupt_camera_moved += 1;
        }
        (disparity, moved)
    }

    /// Takes the frame as a zero-velocity update when the vehicle is still
    /// (§3c, eqs. Z1, Z2): the body-frame velocity `0 = R_W_Bᵀ v + n`,
    /// `n ~ N(0, σ_z² I)` (whitened: `H = [[v^FE]×, I]` on `[δθ, δv]`,
    /// `r = −v̂`, §3d F6), and the mean gyro rate `ω̄_m = b_g + n̄`,
    /// `n̄ ~ N(0, σ_g²/T)` (`H = I` on the gyro bias, `r = ω̄_m − b̂_g`): at
    /// rest the gyro measures its bias, which holds the attitude still.
    /// `disparity` is the frame's [`Self::camera_disparity`]. Returns
    /// whether it did.
    pub(super) fn zero_velocity_update(&mut self, still: &Stillness, disparity: Option<f64>) -> bool {
        let z = self.s.zupt;
        let n = f64::from(still.samples.max(1));
        let (gyro_mean, gyro_scatter) = still.gyro();
        let (accel_mean, accel_scatter) = still.accel();
        // The means may be off by noise and vibration (two standard errors,
        // scatter / √n), by the filter's own bias error (three sigmas of
        // the gyro bias), and, for the specific force, by a tilt error θ,
        // which makes gravity seem off by g·θ (three sigmas of the tilt).
        let tilt_sigma = self.P[(0, 0)].max(self.P[(1, 1)]).max(0.0).sqrt();
        let bg_sigma = self.P[(BG, BG)]
            .max(self.P[(BG + 1, BG + 1)])
            .max(self.P[(BG + 2, BG + 2)])
            .max(0.0)
            .sqrt();
        let gyro_bound = z.max_gyro_radps + 3.0 * bg_sigma + 2.0 * gyro_scatter / n.sqrt();
        let accel_bound = z.max_accel_dev_mps2 + 3.0 * self.g_W.norm() * tilt_sigma + 2.0 * accel_scatter / n.sqrt();
        if !z.enabled
            || !self.zupt_allowed
            || still.samples == 0
            || gyro_mean > gyro_bound
            || accel_mean > accel_bound
            || gyro_scatter > z.max_vibration_gyro_radps
            || accel_scatter > z.max_vibration_accel_mps2
            || self.imu.v_B_in_W.norm() > z.max_speed_mps
        {
            return false;
        }
        if !disparity.is_some_and(|d| d <= z.max_disparity) {
            return false;
        }
        // Z1: the body-frame velocity is zero, 0 = R_W_Bᵀ v + n_v, σ_z,
        // whitened by R_W_B (isotropic noise): H = [[v^FE]× on δθ, I on δv],
        // r = −v̂. Its δθ column keeps the unobservable yaw unobservable
        // (§3d, eq. F6): with N_θ = g, N_v = −[v^FE]× g, H N = 0. Z2:
        // ω̄_m = b_g + n̄_g, the mean rate over the interval, with the white
        // gyro noise averaged: σ_g / √T.
        let v = self.imu.v_B_in_W;
        let v_fe = v - self.fej_dv;
        let Some(w_mean) = still.mean_rate_radps() else {
            return false;
        };
        // Its noise is the white gyro noise averaged, σ_g / √T, or the
        // vibration's, the per-axis scatter over √n, whichever is larger.
        let sigma_w = (self.s.imu.gyro_noise_density / still.span_s.sqrt()).max(gyro_scatter / (3.0 * n).sqrt());
        let cols = [TH, TH + 1, TH + 2, V, V + 1, V + 2, BG, BG + 1, BG + 2];
        let mut h = DMatrix::zeros(6, 9);
        h.view_mut((0, 0), (3, 3))
            .copy_from(&(body_velocity_theta_jacobian(&v_fe) / z.sigma_mps));
        let mut r = DVector::zeros(6);
        for k in 0..3 {
            h[(k, 3 + k)] = 1.0 / z.sigma_mps;
            r[k] = -v[k] / z.sigma_mps;
            h[(3 + k, 6 + k)] = 1.0 / sigma_w;
            r[3 + k] = (w_mean[k] - self.imu.b_g[k]) / sigma_w;
        }
        if !(still.span_s > 0.0 && math::all_finite(r.as_slice())) {
            return false;
        }
        // The gate: rᵀ (H P Hᵀ + I)⁻¹ r on the whitened rows.
        let mut p_sub = DMatrix::zeros(9, 9);
        math::gather_block(&self.P, &cols, &mut p_sub);
        let s = &h * p_sub * h.transpose() + DMatrix::identity(6, 6);
        let Some(ch) = s.clone().cholesky() else {
            return false;
        };
        let nis = r.dot(&ch.solve(&r));
        if nis.is_nan() || nis > cmsckf_models::stats::chi2_quantile(ZUPT_GATE_PROB, 6) {
            *self.stats.rejected.entry(Counter::ZuptChi2).or_default() += 1;
            // For the monitor (§9, D3), only a refusal by the gyro rows
            // alone: a still gyro measuring a rate its bias estimate cannot
            // explain. A hover's slow drift fails the velocity rows, and is
            // no divergence (ZUPTs are allowed in the air when the autopilot
            // reports no landed state).
            let s_gyro = s.view((3, 3), (3, 3)).into_owned();
            let r_gyro = r.rows(3, 3).into_owned();
            let nis_gyro = s_gyro.cholesky().map_or(f64::NAN, |c| r_gyro.dot(&c.solve(&r_gyro)));
            let gyro_passes = nis_gyro <= cmsckf_models::stats::chi2_quantile(ZUPT_GATE_PROB, 3);
            if !gyro_passes {
                self.monitor.push_zupt(self.t_s, true);
            }
            return false;
        }
        self.monitor.push_zupt(self.t_s, false);
        self.ekf_update(&h, &cols, &r, false);
        self.stats.zupt_updates += 1;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Z1's attitude block against central differences of
    /// `Exp(−δθ) v`, and the yaw's null space: `H_θ g + H_v (−[v]× g) = 0`.
    #[test]
    fn body_velocity_jacobian_matches_finite_differences_and_keeps_the_yaw_unobservable() {
        let v = Vector3::new(0.3, -0.12, 0.05);
        let h_th = body_velocity_theta_jacobian(&v);
        let step = 1e-6;
        for k in 0..3 {
            let mut d = Vector3::zeros();
            d[k] = step;
            let f = |s: f64| math::exp_so3(&(-d * s)) * v;
            let col = (f(1.0) - f(-1.0)) / (2.0 * step);
            assert!(
                (col - h_th.column(k)).norm() < 1e-9,
                "column {k}: {col} vs {}",
                h_th.column(k)
            );
        }
        let g = Vector3::new(0.0, 0.0, 9.81);
        let n_v = -v.cross(&g);
        assert!((h_th * g + n_v).norm() < 1e-12);
    }
}
