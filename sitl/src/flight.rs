//! A flight's record, whatever made it: the truth at every IMU sample, the
//! IMU, camera frames and GNSS epochs, and the trajectory itself. Why it
//! exists: the simulator (`dataset`) generates one and `euroc` loads one, so
//! the record sits below them both.

use crate::config::SimConfig;
use crate::features::{CameraFrame, TrackStats};
use crate::gnss::GnssEpoch;
use crate::imu::{ImuBias, ImuSample};
use crate::trajectory::{Trajectory, TruthSample};
use cmsckf_models::gnss::BroadcastEphemeris;

/// Truth at one IMU sample, with the biases in force.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TruthRow {
    pub truth: TruthSample,
    pub bias: ImuBias,
}

/// The simulated flight.
#[derive(Clone, Debug)]
pub struct Dataset {
    pub scenario: String,
    pub seed: u64,
    pub duration_s: f64,
    pub cfg: SimConfig,
    pub truth: Vec<TruthRow>,
    pub imu: Vec<ImuSample>,
    pub frames: Vec<CameraFrame>,
    /// Each frame's image file, for a recorded dataset (`euroc:`); empty
    /// when the camera is simulated (then it is rendered, if served).
    pub frame_images: Vec<std::path::PathBuf>,
    pub gnss: Vec<GnssEpoch>,
    /// The base station's epochs (`gnss.base.enabled`), delivered late by
    /// its own link, and its antenna position (ECEF, m).
    pub base_gnss: Vec<GnssEpoch>,
    pub base_arp_ecef_m: Option<[f64; 3]>,
    pub ephemerides: Vec<BroadcastEphemeris>,
    pub track_stats: TrackStats,
    /// The camera as it really is: `cfg.camera`, the calibration the daemon
    /// is given, moved by a draw of `cfg.lens` (`crate::lens`). Features
    /// are projected and images rendered through it. `None` for a recorded
    /// flight, whose real lens is unknown.
    pub true_camera: Option<cmsckf_models::sensors::CameraConfig>,
    /// The ground truth itself, for sampling at any time.
    pub trajectory: Trajectory,
}
