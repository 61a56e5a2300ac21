//! What the estimator is told: its mode and its settings.
//!
//! The daemon's configuration fills these in (`config/settings.rs`); the
//! estimator itself never reads a configuration file.

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
    pub elevation_mask_deg: f64,
    /// Compressed mode: rebases are computed by whoever takes the job
    /// ([`Estimator::take_rebase_job`]) instead of at once (§5 R4).
    pub async_rebase: bool,
}
