//! The configuration as the estimator takes it: its settings and the initial
//! covariance of the IMU state.

use cmsckf_models::camera::Camera;

use super::Config;
use crate::estimator::feature::{Extrinsic, TriangulationLimits};
use crate::estimator::propagate::{Mat15, BA, BG, P, TH, V};
use crate::estimator::Settings;

impl Config {
    /// The estimator's settings.
    pub fn estimator_settings(&self) -> Settings {
        let c = self;
        let cam = Camera::from_config(&c.camera);
        Settings {
            mode: c.estimator.mode,
            max_clones: c.estimator.max_clones,
            min_track_len: c.estimator.min_track_len,
            chi2_gate_prob: c.estimator.chi2_gate_prob,
            tri: TriangulationLimits {
                min_depth_m: c.estimator.min_depth_m,
                max_depth_m: c.estimator.max_depth_m,
                max_cond: c.estimator.max_triangulation_cond,
            },
            keyframe_interval_s: c.keyframe.interval_s,
            keyframe_max: c.keyframe.max,
            local_radius_m: c.compressed.local_radius_m,
            max_local_keyframes: c.compressed.max_local_keyframes,
            imu: c.imu.clone(),
            clock_bias_rw: c.gnss.clock_bias_rw_m_per_sqrt_s,
            clock_drift_rw: c.gnss.clock_drift_rw_mps_per_sqrt_s,
            isb_rw: c.gnss.isb_rw_m_per_sqrt_s,
            pseudorange_sigma_m: c.gnss.pseudorange_sigma_m,
            range_rate_sigma_mps: c.gnss.range_rate_sigma_mps,
            elevation_mask_deg: c.gnss.elevation_mask_deg,
            async_rebase: false,
            ext: Extrinsic {
                R_B_C: cam.T_B_C.rotation.to_rotation_matrix().into_inner(),
                p_C_in_B: cam.T_B_C.translation.vector,
            },
        }
    }
}

impl Config {
    /// The initial covariance of the IMU block from `[init]`.
    pub fn initial_covariance(&self) -> Mat15 {
        let i = &self.init;
        let mut p = Mat15::zeros();
        let set = |p: &mut Mat15, o: usize, s: [f64; 3]| {
            for k in 0..3 {
                p[(o + k, o + k)] = s[k] * s[k];
            }
        };
        let tilt = i.sigma_tilt_deg.to_radians();
        set(&mut p, TH, [tilt, tilt, i.sigma_yaw_deg.to_radians()]);
        set(&mut p, V, [i.sigma_velocity_mps; 3]);
        set(&mut p, P, [i.sigma_position_m; 3]);
        set(&mut p, BG, [i.sigma_gyro_bias_radps; 3]);
        set(&mut p, BA, [i.sigma_accel_bias_mps2; 3]);
        p
    }
}
