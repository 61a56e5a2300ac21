//! Kalibr's calibration → this project's config (`cmsckf calib import-kalibr`).
//!
//! Kalibr's `kalibr_calibrate_imu_camera` writes `camchain-imucam.yaml`: for
//! each camera `camN`, `camera_model`, `intrinsics`, `distortion_model`,
//! `distortion_coeffs`, `resolution`, `T_cam_imu` and `timeshift_cam_imu`.
//! The IMU's noise is in the `imu.yaml` it was given (or under `imu0` in its
//! `imu-*.yaml` results). This module reads both and gives the `[camera]`
//! section, the `[imu]` noise densities and `estimator.time_offset_s`, as
//! values ([`KalibrImport`]) and as TOML ready to paste
//! ([`KalibrImport::to_toml`]).
//!
//! Conventions, each from the code that uses the value:
//!
//! - **Frames.** The body frame `B` is the IMU frame as the autopilot reports
//!   it, FRD (docs/design.md, "Frames"; `src/io/mavlink/decode.rs` takes
//!   `HIGHRES_IMU`'s axes as they come). Kalibr's IMU frame `I` is the frame
//!   of the IMU data in its bag: FRD when the autopilot's samples were
//!   recorded as they are, ROS's FLU (`base_link`) when they came through
//!   MAVROS (`/mavros/imu/data_raw`), which turns them by 180° about x.
//!   [`ImuFrame`] says which, and has no default: the wrong one mounts the
//!   camera upside down (a warning says so when the result looks it). An IMU
//!   other than the autopilot's (a camera's own) is not the one the filter
//!   reads, and its calibration does not apply.
//! - **Extrinsics.** `T_cam_imu` takes IMU-frame points into the camera
//!   frame: `p_C = R_CI p_I + t_CI`. The config's `q_B_C_xyzw` and
//!   `p_C_in_B_m` are the camera's pose in the body frame, `T_B_C`
//!   (`p_B = R_B_C p_C + p_C_in_B`: `models/src/camera.rs`,
//!   `src/estimator/feature.rs`). So `T_B_C = T_B_I T_cam_imu⁻¹`:
//!   `R_B_C = R_B_I R_CIᵀ` and `p_C_in_B = −R_B_I R_CIᵀ t_CI`, with
//!   `R_B_I = I` (FRD) or `diag(1, −1, −1)` (FLU). The quaternion is
//!   Hamilton `[x, y, z, w]` with `w ≥ 0`.
//! - **Time.** Kalibr: `t_imu = t_cam + timeshift_cam_imu`. Here:
//!   `t_imu = t_cam + t_d` (`Estimator::process_frame` fuses a frame stamped
//!   `t_cam` at `t_cam + t_d`). The same sign:
//!   `estimator.time_offset_s = timeshift_cam_imu`. It is the offset between
//!   the stamps in Kalibr's bag; the daemon's may differ (another clock or
//!   stamping point), which is one reason the filter keeps estimating `t_d`
//!   from this prior.
//! - **IMU noise.** Kalibr's densities are continuous-time (m/s²/√Hz,
//!   m/s³/√Hz, rad/s/√Hz, rad/s²/√Hz), and so are the config's (the
//!   propagation discretises them as `σ² Δt`, `src/estimator/propagate.rs`):
//!   copied unchanged. Kalibr's `update_rate` discretises them inside Kalibr
//!   only; the filter uses each sample's own interval.
//! - **Distortion.** Kalibr's `radtan` `[k1, k2, r1, r2]` (OpenCV's
//!   plumb-bob) is `pinhole-radtan` `[k1, k2, p1, p2]`; `equidistant`
//!   `[k1, k2, k3, k4]` (Kannala–Brandt, OpenCV's fisheye) is
//!   `pinhole-equidistant`; `none` is `pinhole-radtan` with zeros. `fov`, and
//!   projections other than `pinhole` (`omni`, `ds`, `eucm`), are refused.

mod convert;
mod print;
#[cfg(test)]
mod tests;
mod yaml;

use std::path::Path;

use nalgebra::{Matrix3, Vector3};

use cmsckf_models::sensors::{CameraConfig, ImuConfig};

use super::Config;
use convert::{parse_camchain, parse_imu};

/// Largest entry of `RᵀR − I` accepted for `T_cam_imu`'s rotation. Kalibr
/// writes full doubles; this still takes a matrix typed with 5 digits.
pub const ORTHONORMAL_TOLERANCE: f64 = 1e-4;
/// Largest `|timeshift_cam_imu|` (s): what `estimator.time_offset_s` accepts.
pub const MAX_TIMESHIFT_S: f64 = 0.5;

/// A Kalibr file that cannot be imported. Each names the file and, past
/// reading and parsing, the key (`cam0.T_cam_imu[1][2]`).
#[derive(Debug, thiserror::Error)]
pub enum KalibrError {
    #[error("cannot read Kalibr file '{path}': {source}")]
    Io { path: String, source: std::io::Error },
    #[error("Kalibr file '{path}' is not YAML: {message}")]
    NotYaml { path: String, message: String },
    #[error("Kalibr file '{path}': key `{key}` is missing{hint}")]
    Missing { path: String, key: String, hint: String },
    #[error("Kalibr file '{path}': key `{key}`: {problem}")]
    Invalid { path: String, key: String, problem: String },
    #[error("Kalibr file '{path}': key `{key}` is '{value}', which is not supported: {supported}")]
    Unsupported {
        path: String,
        key: String,
        value: String,
        supported: String,
    },
}

/// The axes of the IMU data Kalibr was given.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImuFrame {
    /// The autopilot's own FRD axes (its `HIGHRES_IMU` as it is): Kalibr's
    /// IMU frame is the body frame.
    Frd,
    /// ROS's FLU (`base_link`), as MAVROS republishes the autopilot's IMU
    /// (`/mavros/imu/data_raw`): 180° about x from the body frame.
    Flu,
}

impl ImuFrame {
    /// The name the command line takes (`frd`, `flu`).
    pub fn name(self) -> &'static str {
        match self {
            ImuFrame::Frd => "frd",
            ImuFrame::Flu => "flu",
        }
    }

    /// `R_B_I`: Kalibr's IMU axes into the body frame (FRD).
    pub fn R_B_I(self) -> Matrix3<f64> {
        match self {
            ImuFrame::Frd => Matrix3::identity(),
            ImuFrame::Flu => Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0)),
        }
    }
}

/// What to import and what the imported values complete.
#[derive(Clone, Copy, Debug)]
pub struct ImportOptions<'a> {
    /// The camera of the chain: `cam0`, `cam1`, ...
    pub camera: &'a str,
    /// The axes of Kalibr's IMU data.
    pub imu_frame: ImuFrame,
    /// The config whose other `[camera]` and `[imu]` keys (`pixel_noise_px`, `model_noise_px`,
    /// `rate_hz`, `gravity_mps2`: not in Kalibr's files) are kept.
    pub base: &'a Config,
    /// Where `base` came from, for the printed comments ("the defaults").
    pub base_origin: &'a str,
}

/// Kalibr's IMU noise, in the config's terms.
#[derive(Clone, Debug, PartialEq)]
pub struct ImportedImu {
    /// The file it came from.
    pub path: String,
    /// `""` for Kalibr's `imu.yaml`, `"imu0."` for its results file.
    pub key_prefix: String,
    /// The `[imu]` section: Kalibr's four densities, `gravity_mps2` from the
    /// base config.
    pub imu: ImuConfig,
    /// Kalibr's `update_rate` (Hz): its discretisation only.
    pub update_rate_hz: f64,
}

/// One camera of Kalibr's chain (and its IMU noise) in the config's terms.
#[derive(Clone, Debug, PartialEq)]
pub struct KalibrImport {
    /// The camchain file it came from.
    pub camchain_path: String,
    /// `cam0`, `cam1`, ...
    pub camera_name: String,
    /// Kalibr's `camera_model` and `distortion_model`, as written.
    pub kalibr_camera_model: String,
    pub kalibr_distortion_model: String,
    pub imu_frame: ImuFrame,
    /// The `[camera]` section: Kalibr's values, `pixel_noise_px`, `model_noise_px` and
    /// `rate_hz` from the base config.
    pub camera: CameraConfig,
    /// `estimator.time_offset_s` (s): Kalibr's `timeshift_cam_imu`.
    pub time_offset_s: f64,
    /// With an IMU file: the `[imu]` section.
    pub imu: Option<ImportedImu>,
    /// Whatever looks wrong without being an error (an upside-down camera).
    pub warnings: Vec<String>,
    base_origin: String,
}

impl KalibrImport {
    /// Reads Kalibr's camchain (and IMU) file and converts them.
    pub fn load(camchain: &Path, imu: Option<&Path>, opts: &ImportOptions) -> Result<Self, KalibrError> {
        let read = |p: &Path| {
            std::fs::read_to_string(p).map_err(|source| KalibrError::Io {
                path: p.display().to_string(),
                source,
            })
        };
        let cam_text = read(camchain)?;
        let imu_text = match imu {
            Some(p) => Some((read(p)?, p.display().to_string())),
            None => None,
        };
        Self::from_text(
            &cam_text,
            &camchain.display().to_string(),
            imu_text.as_ref().map(|(t, o)| (t.as_str(), o.as_str())),
            opts,
        )
    }

    /// [`Self::load`] from the files' text; `origin`s name them in errors.
    pub fn from_text(
        camchain_text: &str,
        camchain_origin: &str,
        imu: Option<(&str, &str)>,
        opts: &ImportOptions,
    ) -> Result<Self, KalibrError> {
        let mut out = parse_camchain(camchain_text, camchain_origin, opts)?;
        if let Some((text, origin)) = imu {
            out.imu = Some(parse_imu(text, origin, &opts.base.imu)?);
        }
        Ok(out)
    }

    /// Sets the imported sections in `cfg`.
    pub fn apply(&self, cfg: &mut Config) {
        cfg.camera = self.camera.clone();
        cfg.estimator.time_offset_s = self.time_offset_s;
        if let Some(imu) = &self.imu {
            cfg.imu = imu.imu.clone();
        }
    }
}
