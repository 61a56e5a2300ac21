//! What the estimator is told: its mode and its settings.
//!
//! The daemon's configuration fills these in (`config/settings.rs`); the
//! estimator itself never reads a configuration file.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use cmsckf_models::sensors::ImuConfig;

use super::feature::{Extrinsic, TriangulationLimits};

/// Estimator mode.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// Sliding window only, no keyframes.
    Msckf,
    /// Every keyframe in the state and updated: the optimal reference.
    Full,
    /// Keyframes as Schmidt nuisance states (never corrected).
    Schmidt,
    /// Local/global partition with compressed global updates.
    Compressed,
}

impl Mode {
    pub const ALL: [Mode; 4] = [Mode::Msckf, Mode::Full, Mode::Schmidt, Mode::Compressed];
    pub fn name(self) -> &'static str {
        match self {
            Mode::Msckf => "msckf",
            Mode::Full => "full",
            Mode::Schmidt => "schmidt",
            Mode::Compressed => "compressed",
        }
    }
}

impl std::str::FromStr for Mode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Mode::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| format!("unknown mode '{s}': expected msckf, full, schmidt or compressed"))
    }
}

/// Estimator settings.
#[derive(Clone, Debug)]
pub struct Settings {
    pub mode: Mode,
    pub max_clones: usize,
    pub min_track_len: usize,
    pub chi2_gate_prob: f64,
    pub tri: TriangulationLimits,
    pub keyframe_interval_s: f64,
    pub keyframe_max: usize,
    pub local_radius_m: f64,
    pub max_local_keyframes: usize,
    pub imu: ImuConfig,
    pub ext: Extrinsic,
    /// Receiver clock bias white-frequency noise (m/√s) and drift random
    /// walk (m/s/√s).
    pub clock_bias_rw: f64,
    pub clock_drift_rw: f64,
    /// Galileo − GPS inter-system bias random walk (m/√s).
    pub isb_rw: f64,
    /// Pseudorange and range-rate sigmas at zenith (m, m/s).
    pub pseudorange_sigma_m: f64,
    pub range_rate_sigma_mps: f64,
    /// Broadcast orbit/clock range error (m) and troposphere model error at
    /// zenith (m) of a single-point code; a differential code has neither
    /// (§8c, eq. DG5).
    pub broadcast_sigma_m: f64,
    pub troposphere_sigma_m: f64,
    /// Single-point codes' persistent errors as states (§8c, DG5′): each
    /// satellite's range bias (prior sigma m, random walk m/√s, dropped
    /// after this long unused, s) and the zenith troposphere error (prior
    /// `troposphere_sigma_m`, random walk m/√s). `false`: DG5/DG6's
    /// windowed weights instead.
    pub range_bias_states: bool,
    pub range_bias_sigma_m: f64,
    pub range_bias_rw_m_per_sqrt_s: f64,
    pub range_bias_timeout_s: f64,
    pub troposphere_rw_m_per_sqrt_s: f64,
    /// The window (s) in which errors that hold and have no state (the
    /// broadcast and troposphere errors without range-bias states, and a
    /// range rate's persistent part, m/s at zenith) count as one
    /// measurement (§8c, eq. DG6).
    pub gnss_correlation_window_s: f64,
    pub range_rate_correlated_sigma_mps: f64,
    /// The window (s) in which a single-frequency code's ionosphere error
    /// counts as one measurement (§8c, eq. DG6′).
    pub ionosphere_window_s: f64,
    /// How well the base's announced antenna position is known, one sigma
    /// per axis (m; §8c, DG9′).
    pub base_position_sigma_m: f64,
    /// How fast a held base correction drifts, one sigma (m/s; §8c, DG2′).
    pub dgnss_correction_rate_sigma_mps: f64,
    pub elevation_mask_deg: f64,
    /// Compressed mode: rebases are computed by whoever takes the job
    /// ([`Estimator::take_rebase_job`]) instead of at once (§5 R4).
    pub async_rebase: bool,
    /// Prior of the camera–IMU time offset `t_d` (s, `t_imu = t_cam + t_d`)
    /// and its sigma (s); estimated online (§3b).
    pub time_offset_s: f64,
    pub time_offset_sigma_s: f64,
    /// GNSS antenna phase centre in the body frame (m, FRD; §8).
    pub p_A_in_B_m: Vector3<f64>,
    /// GNSS epoch period assumed until two epochs show theirs (s).
    pub gnss_period_s: f64,
    /// Latest a GNSS epoch may arrive after its instant and still be fused
    /// at its own time through a clone (s, §8b).
    pub gnss_max_delay_s: f64,
    /// Tracks whose bearings span less than this angle are skipped (rad):
    /// they cannot be triangulated, and say nothing about health.
    pub min_parallax_rad: f64,
    /// Tracks with too little parallax are used at their landmark's
    /// remembered depth, the depth a nuisance (§3e), rather than skipped.
    pub low_parallax_updates: bool,
    /// Each new view's attitude gains the vibration's jitter, measured
    /// from the gyro (§3f, eq. V2).
    pub vibration_jitter: bool,
    pub zupt: ZuptSettings,
    /// The barometer's height (§3g).
    pub baro: BaroSettings,
    /// The motion an IMU gap hides (eq. N3).
    pub imu_gap: super::propagate::GapNoise,
    /// Time after the start during which the divergence monitor does not
    /// judge (s): the first tracks are short and the prior still settling.
    pub health_grace_s: f64,
}

/// The barometer as a height with an offset the filter estimates (§3g).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BaroSettings {
    /// Each reading's white noise (m, 1σ).
    pub noise_m: f64,
    /// The offset's random walk (m/√s): temperature and weather move a
    /// barometer's zero by decimetres over minutes.
    pub offset_rw_m_per_sqrt_s: f64,
    /// Readings refused by the χ² gate in a row after which the height is
    /// taken to be what was wrong (eq. B3): its variance is raised by the
    /// residual's excess and the reading fused.
    pub refusals_before_height_reset: u32,
}

impl Default for BaroSettings {
    fn default() -> Self {
        Self {
            noise_m: 0.15,
            offset_rw_m_per_sqrt_s: 0.02,
            refusals_before_height_reset: 5,
        }
    }
}

/// When a frame is a zero-velocity update instead of a clone (§3c): the
/// IMU still since the last frame, the features not moving, and the
/// estimated speed small.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ZuptSettings {
    pub enabled: bool,
    /// Largest mean body rate since the last frame, beyond what the
    /// samples' scatter and the bias's sigma allow (rad/s).
    pub max_gyro_radps: f64,
    /// Largest `|mean(a_m − b_a + R_W_Bᵀ g_W)|` since the last frame, beyond
    /// what the scatter and the tilt's sigma allow (m/s²): the specific
    /// force's departure from gravity's, in any direction (a norm test alone
    /// misses a gentle horizontal acceleration).
    pub max_accel_dev_mps2: f64,
    /// Largest RMS scatter of the body rate about its mean (rad/s): more
    /// shaking than a vehicle standing with its motors running.
    pub max_vibration_gyro_radps: f64,
    /// Largest RMS scatter of the specific force about its mean (m/s²).
    pub max_vibration_accel_mps2: f64,
    /// Largest median feature displacement since the last clone
    /// (normalised image units: pixels / focal length).
    pub max_disparity: f64,
    /// Largest estimated speed (m/s).
    pub max_speed_mps: f64,
    /// Sigma of the zero-velocity measurement (m/s).
    pub sigma_mps: f64,
}

impl Default for ZuptSettings {
    fn default() -> Self {
        Self {
            enabled: true,
            max_gyro_radps: 0.02,
            max_accel_dev_mps2: 0.1,
            max_vibration_gyro_radps: 0.5,
            max_vibration_accel_mps2: 5.0,
            max_disparity: 3.0 / 450.0,
            max_speed_mps: 0.5,
            sigma_mps: 0.01,
        }
    }
}
