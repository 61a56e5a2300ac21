//! The configuration as the estimator takes it: its settings and the initial
//! covariance of the IMU state.

use cmsckf_models::camera::Camera;

use super::Config;
use crate::estimator::feature::{Extrinsic, TriangulationLimits};
use crate::estimator::imu_covariance::ImuPrior;
use crate::estimator::Mat15;
use crate::estimator::{Settings, ZuptSettings};

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
            broadcast_sigma_m: c.gnss.broadcast_sigma_m,
            troposphere_sigma_m: c.gnss.troposphere_sigma_m,
            range_bias_states: c.gnss.range_bias_states,
            range_bias_sigma_m: c.gnss.range_bias_sigma_m,
            range_bias_rw_m_per_sqrt_s: c.gnss.range_bias_rw_m_per_sqrt_s,
            range_bias_timeout_s: c.gnss.range_bias_timeout_s,
            troposphere_rw_m_per_sqrt_s: c.gnss.troposphere_rw_m_per_sqrt_s,
            gnss_correlation_window_s: c.gnss.correlation_window_s,
            dgnss_correction_rate_sigma_mps: c.gnss.dgnss_correction_rate_sigma_mps,
            ionosphere_window_s: c.gnss.ionosphere_window_s,
            base_position_sigma_m: c.gnss.base_position_sigma_m,
            range_rate_correlated_sigma_mps: c.gnss.range_rate_correlated_sigma_mps,
            elevation_mask_deg: c.gnss.elevation_mask_deg,
            async_rebase: false,
            time_offset_s: c.estimator.time_offset_s,
            time_offset_sigma_s: c.estimator.time_offset_sigma_s,
            p_A_in_B_m: nalgebra::Vector3::from(c.gnss.p_A_in_B_m),
            gnss_period_s: 1.0 / c.gnss.epoch_rate_hz,
            gnss_max_delay_s: c.gnss.max_delay_s,
            min_parallax_rad: c.estimator.min_parallax_deg.to_radians(),
            low_parallax_updates: c.estimator.low_parallax_updates,
            vibration_jitter: c.estimator.vibration_jitter,
            zupt: ZuptSettings {
                enabled: c.zupt.enabled,
                max_gyro_radps: c.zupt.max_gyro_radps,
                max_accel_dev_mps2: c.zupt.max_accel_deviation_mps2,
                max_vibration_gyro_radps: c.zupt.max_vibration_gyro_radps,
                max_vibration_accel_mps2: c.zupt.max_vibration_accel_mps2,
                // Pixels to normalised units through the mean focal length.
                max_disparity: c.zupt.max_disparity_px / (0.5 * (c.camera.intrinsics[0] + c.camera.intrinsics[1])),
                max_speed_mps: c.zupt.max_speed_mps,
                sigma_mps: c.zupt.sigma_mps,
            },
            baro: crate::estimator::BaroSettings {
                noise_m: c.barometer.noise_m,
                offset_rw_m_per_sqrt_s: c.barometer.offset_rw_m_per_sqrt_s,
                ..Default::default()
            },
            health_grace_s: c.estimator.health_grace_s,
            imu_gap: crate::estimator::propagate::GapNoise {
                sigma_rate_radps: c.estimator.imu_gap_sigma_rate_radps,
                sigma_accel_mps2: c.estimator.imu_gap_sigma_accel_mps2,
            },
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
        ImuPrior {
            tilt_rad: i.sigma_tilt_deg.to_radians(),
            yaw_rad: i.sigma_yaw_deg.to_radians(),
            velocity_mps: i.sigma_velocity_mps,
            position_m: i.sigma_position_m,
            gyro_bias_radps: i.sigma_gyro_bias_radps,
            accel_bias_mps2: i.sigma_accel_bias_mps2,
        }
        .covariance()
    }
}
