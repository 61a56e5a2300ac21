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

    /// How far the features moved (normalised units) since their track's
    /// last clone (README §3c, eq. Z0), from two medians over the features
    /// seen now and then: `s` as seen and `r` with the camera's rotation
    /// since the clone taken out, `max(min(s, r), s / 2)`. `None` with too
    /// few features in common. Reuses the estimator's buffer: no allocation
    /// once it has grown.
    ///
    /// Only a translation says the vehicle moved, or a turn larger than a
    /// vehicle on its legs makes. A multirotor spinning up on the ground
    /// rocks at up to 0.1 rad/s: beside PX4's SIH, with the ground 0.3 m
    /// from the camera, `s` passed 3 px (3.5 px) 0.5 s before the vehicle
    /// rose, ended the take-off's zero-velocity grace, and the IMU alone then
    /// carried a velocity 2× the truth's into the first tracks (their depths
    /// and the climb's scale 1.6× the truth's, 1.5 m off at 12 σ). `r`
    /// alone is no better: the gyro's attitude since an old clone is off by
    /// as much as the rocking (2 px after 0.3 s of an armed multirotor's
    /// gyro), and it hides a take-off whose first motion is its tilt when
    /// the features are far (the simulator's: `s` 7–11 px, `r` 2.4 px).
    fn median_disparity(&mut self, obs: &[NormObs]) -> Option<f64> {
        self.disparity_medians(obs)
            .map(|(seen, derotated)| seen.min(derotated).max(0.5 * seen))
    }

    /// [`Self::median_disparity`]'s two medians, `(s, r)`: as seen, and
    /// with the camera's rotation since each track's last clone taken out.
    fn disparity_medians(&mut self, obs: &[NormObs]) -> Option<(f64, f64)> {
        let (mut seen, mut derotated) = std::mem::take(&mut self.disparity_buf);
        seen.clear();
        derotated.clear();
        // Z0: the last clone's bearing seen from now, `R_C_C' [x'; 1]` with
        // `R_C_C' = R_B_Cᵀ R_W_Bᵀ R_W_B' R_B_C` (the attitude propagated to
        // the frame's instant), projected back to `z = 1`. Most tracks share
        // the last clone: `R_C_C'` is kept for the clone it was made for.
        let R_B_C = &self.s.ext.R_B_C;
        let R_C_W = R_B_C.transpose() * self.imu.q_W_B.to_rotation_matrix().inverse().matrix();
        let mut R_C_Cl: Option<(u64, Matrix3<f64>)> = None;
        for o in obs {
            let Some((seq, last)) = self.tracks.get(&o.landmark_id).and_then(|t| t.obs.last()) else {
                continue;
            };
            let Some(c) = self.clone_by_seq(*seq) else {
                continue;
            };
            let R = match R_C_Cl {
                Some((s, R)) if s == *seq => R,
                _ => {
                    let R = R_C_W * c.q_W_B.to_rotation_matrix().matrix() * R_B_C;
                    R_C_Cl = Some((*seq, R));
                    R
                }
            };
            let b = R * Vector3::new(last.xn.x, last.xn.y, 1.0);
            seen.push((o.xn - last.xn).norm());
            derotated.push(if b.z > 0.0 {
                (o.xn - b.xy() / b.z).norm()
            } else {
                f64::INFINITY
            });
        }
        let medians = if seen.len() < MIN_COMMON_FEATURES {
            None
        } else {
            let s = cmsckf_models::stats::percentile(&mut seen, 0.5);
            let r = cmsckf_models::stats::percentile(&mut derotated, 0.5);
            s.zip(r)
        };
        self.disparity_buf = (seen, derotated);
        medians
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

    /// Z0: a camera that only turns a little since the last clone (a
    /// multirotor rocking on its legs as its motors spin up) has not moved,
    /// though its features slid past the bound; one that turns as a
    /// take-off tilts, or that moves, turned or not, has. The features lie 0.4–6 m ahead, as a camera sees
    /// the ground from a landed drone.
    #[test]
    fn only_a_translation_moves_the_features_a_turn_does_not() {
        use super::super::{CloneState, Track};
        use nalgebra::{UnitQuaternion, Vector2};
        let s = crate::config::Config::default().estimator_settings();
        let px = 0.5 * (458.654 + 457.296);
        let max_disparity_px = s.zupt.max_disparity * px;
        let mut est = Estimator::new(
            s,
            0.0,
            crate::estimator::propagate::tests::state(),
            &(crate::estimator::Mat15::identity() * 0.01),
        );
        let q0 = est.imu.q_W_B;
        let p0 = est.imu.p_B_in_W;
        let ext = est.s.ext;
        // World points ahead of the camera at the clone.
        let points: Vec<Vector3<f64>> = (0..40)
            .map(|k| {
                let (u, v) = (f64::from(k % 8) * 0.1 - 0.35, f64::from(k / 8) * 0.1 - 0.2);
                let depth_m = 0.4 + f64::from(k % 5) * 1.4;
                let p_C = Vector3::new(u * depth_m, v * depth_m, depth_m);
                p0 + q0 * (ext.R_B_C * p_C + ext.p_C_in_B)
            })
            .collect();
        let seen = |q: UnitQuaternion<f64>, p: Vector3<f64>| -> Vec<NormObs> {
            points
                .iter()
                .enumerate()
                .map(|(k, p_W)| {
                    let p_C = ext.R_B_C.transpose() * (q.inverse() * (p_W - p) - ext.p_C_in_B);
                    NormObs {
                        landmark_id: k as u64,
                        xn: Vector2::new(p_C.x / p_C.z, p_C.y / p_C.z),
                        W: nalgebra::Matrix2::identity() * px,
                    }
                })
                .collect()
        };
        est.clones.push_back(CloneState {
            seq: 0,
            q_W_B: q0,
            p_B_in_W: p0,
            p_fej_in_W: p0,
        });
        for o in seen(q0, p0) {
            est.tracks.insert(o.landmark_id, Track { obs: vec![(0, o)] });
        }
        let medians_px = |est: &mut Estimator, obs: &[NormObs]| {
            let (s, r) = est.disparity_medians(obs).unwrap();
            (s * px, r * px, est.median_disparity(obs).unwrap() * px)
        };
        // Still: nothing moved either way.
        est.imu.q_W_B = q0;
        let (s_px, r_px, _) = medians_px(&mut est, &seen(q0, p0));
        assert!(s_px < 1e-9 && r_px < 1e-9, "still: {s_px} {r_px} px");
        // A turn of 0.4° about each axis, as a rocking on the legs makes:
        // more than the bound as seen; derotated, only the camera's own
        // shift as the body turns about the IMU (its lever arm `p_C_in_B`,
        // 0.7 mm); the displacement is then `s/2`, under the bound.
        let turned = q0 * UnitQuaternion::from_scaled_axis(Vector3::new(0.007, -0.007, 0.005));
        est.imu.q_W_B = turned;
        let obs = seen(turned, p0);
        let (s_px, r_px, d_px) = medians_px(&mut est, &obs);
        assert!(s_px > max_disparity_px, "the turn moves the features {s_px} px");
        assert!(r_px < 0.2, "derotated, a turn leaves {r_px} px");
        assert!(
            (d_px - 0.5 * s_px).abs() < 1e-9 && d_px < max_disparity_px,
            "a turn alone: {d_px} px of {s_px}"
        );
        assert!(!est.camera_disparity(&obs).1, "a turn alone said moved");
        // A turn of 1.5°, as a take-off's tilt begins: moved (`s/2` passes).
        let tilted = q0 * UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.026, 0.0));
        est.imu.q_W_B = tilted;
        let obs = seen(tilted, p0);
        assert!(
            est.camera_disparity(&obs).1,
            "a take-off's tilt: {:?} px",
            medians_px(&mut est, &obs)
        );
        // 4 cm up and forward, without a turn: both medians alike, moved.
        est.imu.q_W_B = q0;
        let p = p0 + Vector3::new(0.04, 0.0, -0.04);
        let obs = seen(q0, p);
        let (s_px, r_translated_px, d_px) = medians_px(&mut est, &obs);
        assert!(
            (s_px - r_translated_px).abs() < 1e-9 && d_px == s_px && d_px > max_disparity_px,
            "{s_px} {r_translated_px} {d_px}"
        );
        assert!(est.camera_disparity(&obs).1);
        // The same translation with the small turn: derotated, the
        // translation's displacement again (to the lever arm's shift); the
        // smaller median counts (here the one as seen, which the turn
        // partly cancels); moved.
        est.imu.q_W_B = turned;
        let obs = seen(turned, p);
        let (s_px, r_px, d_px) = medians_px(&mut est, &obs);
        assert!(
            (r_px - r_translated_px).abs() < 0.3,
            "derotated {r_px} px against {r_translated_px}"
        );
        assert!(
            d_px == s_px.min(r_px) && (s_px - r_px).abs() > 1.0,
            "{s_px} {r_px} {d_px}"
        );
        assert!(d_px > max_disparity_px && est.camera_disparity(&obs).1);
    }
}
