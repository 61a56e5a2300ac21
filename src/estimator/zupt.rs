//! Standstill (README.md §3c): a drone waits on the ground before take-off
//! and hovers in flight. With no camera motion a track has no parallax, so
//! the MSCKF has nothing to triangulate, and the IMU alone would let the
//! velocity random-walk. So a frame taken while the vehicle is still is a
//! zero-velocity update (`v_B_in_W = 0`) instead of a new clone: it adds no
//! pose to the window, and the tracks wait for the motion that gives them
//! parallax (OpenVINS does the same).
//!
//! Still means all of: every IMU sample since the last frame with a small
//! body rate and a specific force of gravity's size, the features not
//! moving in the image since the last clone, the estimated speed small, and
//! the update itself passing its χ² gate.

use nalgebra::{DMatrix, DVector};

use super::propagate::V;
use super::{Estimator, ImuMeas, NormObs, Stillness};

/// Fewest features seen both now and at the last clone to judge disparity.
const MIN_COMMON_FEATURES: usize = 5;

/// Probability of the zero-velocity update's χ² gate (3 degrees of freedom).
const ZUPT_GATE_PROB: f64 = 0.99;

impl Stillness {
    /// Adds one IMU sample, its biases removed with the current estimate.
    pub(super) fn push(&mut self, m: &ImuMeas, b_g: &nalgebra::Vector3<f64>, b_a: &nalgebra::Vector3<f64>, g: f64) {
        self.samples += 1;
        self.max_gyro_radps = self.max_gyro_radps.max((m.gyro_radps - b_g).norm());
        self.max_accel_dev_mps2 = self.max_accel_dev_mps2.max(((m.accel_mps2 - b_a).norm() - g).abs());
    }
}

impl Estimator {
    /// Median displacement (normalised units) of the features seen both in
    /// `obs` and at their track's last clone; `None` with too few in common.
    fn median_disparity(&self, obs: &[NormObs]) -> Option<f64> {
        let mut d: Vec<f64> = obs
            .iter()
            .filter_map(|o| {
                let last = self.tracks.get(&o.landmark_id)?.obs.last()?;
                Some((o.xn - last.1.xn).norm())
            })
            .collect();
        if d.len() < MIN_COMMON_FEATURES {
            return None;
        }
        cmsckf_models::stats::percentile(&mut d, 0.5)
    }

    /// Takes the frame as a zero-velocity update when the vehicle is still
    /// (§3c, eq. Z1): `z = 0 = v + n`, `n ~ N(0, σ² I)`, so `H = [0 I 0 …]`
    /// on the velocity and `r = −v̂`. Returns whether it did.
    pub(super) fn zero_velocity_update(&mut self, still: &Stillness, obs: &[NormObs]) -> bool {
        let z = self.s.zupt;
        if !z.enabled
            || still.samples == 0
            || still.max_gyro_radps > z.max_gyro_radps
            || still.max_accel_dev_mps2 > z.max_accel_dev_mps2
            || self.imu.v_B_in_W.norm() > z.max_speed_mps
        {
            return false;
        }
        if !self.median_disparity(obs).is_some_and(|d| d <= z.max_disparity) {
            return false;
        }
        let v = self.imu.v_B_in_W;
        let s = self.P.fixed_view::<3, 3>(V, V).into_owned() + nalgebra::Matrix3::identity() * z.sigma_mps.powi(2);
        let Some(ch) = s.cholesky() else {
            return false;
        };
        let nis = v.dot(&ch.solve(&v));
        if !(nis <= cmsckf_models::stats::chi2_quantile(ZUPT_GATE_PROB, 3)) {
            *self.stats.rejected.entry("zupt_chi2").or_default() += 1;
            return false;
        }
        // Whitened: H = I/σ on the velocity columns, r = −v̂/σ.
        let h = DMatrix::identity(3, 3) / z.sigma_mps;
        let r = DVector::from_iterator(3, v.iter().map(|x| -x / z.sigma_mps));
        self.ekf_update(&h, &[V, V + 1, V + 2], &r, false);
        self.stats.zupt_updates += 1;
        true
    }
}
