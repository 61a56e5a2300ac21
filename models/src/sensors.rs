//! Sensor descriptions: the IMU's noise model and the camera's intrinsics,
//! distortion and mounting.
//!
//! They are shared on purpose: the simulator draws measurements with them and
//! the estimator models the same sensors with them, so the two cannot drift
//! apart. Every field carries its unit in its name or doc, and [`Validate`]
//! rejects non-finite or out-of-range values with a message that names the
//! field and the fix.

use serde::{Deserialize, Serialize};

use crate::check::{Check, FieldError, Validate};

/// Standard gravity used by default (m/s²).
pub const DEFAULT_GRAVITY_MPS2: f64 = 9.81;

/// IMU noise model (continuous-time densities, as in Kalibr / OpenVINS).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct ImuConfig {
    /// Accelerometer white noise density (m/s²/√Hz).
    pub accel_noise_density: f64,
    /// Accelerometer bias random walk (m/s³/√Hz).
    pub accel_random_walk: f64,
    /// Gyroscope white noise density (rad/s/√Hz).
    pub gyro_noise_density: f64,
    /// Gyroscope bias random walk (rad/s²/√Hz).
    pub gyro_random_walk: f64,
    /// Gravity magnitude (m/s²).
    pub gravity_mps2: f64,
}

impl Default for ImuConfig {
    fn default() -> Self {
        // OpenVINS's simulator values, typical of a MEMS IMU.
        Self {
            accel_noise_density: 2.0e-3,
            accel_random_walk: 3.0e-3,
            gyro_noise_density: 1.6968e-4,
            gyro_random_walk: 1.9393e-5,
            gravity_mps2: DEFAULT_GRAVITY_MPS2,
        }
    }
}

impl Validate for ImuConfig {
    fn validate(&self, prefix: &str) -> Result<(), FieldError> {
        let c = Check::new(prefix);
        c.positive("accel_noise_density", self.accel_noise_density, 1.0)?;
        c.positive("accel_random_walk", self.accel_random_walk, 1.0)?;
        c.positive("gyro_noise_density", self.gyro_noise_density, 1.0)?;
        c.positive("gyro_random_walk", self.gyro_random_walk, 1.0)?;
        c.range("gravity_mps2", self.gravity_mps2, 9.7, 9.9)
    }
}

/// Lens distortion model.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum CameraModelKind {
    /// Pinhole with radial-tangential distortion `[k1, k2, p1, p2]`.
    PinholeRadtan,
    /// Pinhole with equidistant (fisheye) distortion `[k1, k2, k3, k4]`.
    PinholeEquidistant,
}

/// Camera intrinsics, distortion, resolution and extrinsics.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct CameraConfig {
    /// `pinhole-radtan` or `pinhole-equidistant`.
    pub model: CameraModelKind,
    /// Image width (px).
    pub width_px: u32,
    /// Image height (px).
    pub height_px: u32,
    /// Focal lengths and principal point `[fx, fy, cx, cy]` (px).
    pub intrinsics: [f64; 4],
    /// Distortion coefficients (unitless); meaning depends on `model`.
    pub distortion: [f64; 4],
    /// Camera position in the body frame, `p_C_in_B` (m).
    pub p_C_in_B_m: [f64; 3],
    /// Camera orientation in the body frame, `q_B_C` as `[x, y, z, w]`
    /// (Hamilton; rotates camera vectors into the body frame).
    pub q_B_C_xyzw: [f64; 4],
    /// Pixel measurement noise, one sigma (px), of a feature that comes
    /// without a σ of its own.
    pub pixel_noise_px: f64,
    /// Whether each feature is weighed by the σ its front-end sends with it
    /// (`cmsckf-frontend` sends one), with `model_noise_px` added in
    /// quadrature (on); off (the default), every feature is weighed with
    /// `pixel_noise_px`. A feature sent without a σ is weighed with
    /// `pixel_noise_px` either way. On, the simulator's rendered flights
    /// read a NIS per dof of 0.55–0.59 where 1 px gives 0.015, but beside
    /// PX4's SITL the tracks of a vertical take-off slid by more than their
    /// σ and one flight in five climbed 6.5 m off under a σ of 0.13 m, no NIS
    /// or restart seeing it; off, none did (docs/frontend.md, "Why the σ is
    /// off by default").
    pub frontend_sigma: bool,
    /// The error of each feature's position that its front-end's σ does not
    /// hold and that differs from frame to frame (px, one sigma): added in
    /// quadrature to each σ a front-end sends. Not the calibration's
    /// reprojection RMS: a lens off its calibration errs smoothly over the
    /// image, and a track's landmark and views absorb it (a simulated lens
    /// 0.1–0.8 px RMS off left the NIS unchanged; 0.8 px bent the path,
    /// which no model noise covers: calibrate). 0.01 by default, the
    /// least accepted; raise it for what a frame's stamp or a rolling
    /// shutter adds (docs/frontend.md says how to measure it on a log).
    pub model_noise_px: f64,
    /// Frame rate (Hz).
    pub rate_hz: f64,
}

impl Default for CameraConfig {
    fn default() -> Self {
        // Forward-looking camera: optical axis = body x, image right = body y,
        // image down = body z. R_B_C has columns x_C = y_B, y_C = z_B, z_C = x_B.
        Self {
            model: CameraModelKind::PinholeRadtan,
            width_px: 752,
            height_px: 480,
            intrinsics: [458.654, 457.296, 367.215, 248.375],
            distortion: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05],
            p_C_in_B_m: [0.10, 0.0, 0.02],
            q_B_C_xyzw: [0.5, 0.5, 0.5, 0.5],
            pixel_noise_px: 1.0,
            frontend_sigma: false,
            model_noise_px: 0.01,
            rate_hz: 30.0,
        }
    }
}

impl Validate for CameraConfig {
    fn validate(&self, prefix: &str) -> Result<(), FieldError> {
        let c = Check::new(prefix);
        c.within("width_px", self.width_px as u64, 16, 16384, "set 16..16384")?;
        c.within("height_px", self.height_px as u64, 16, 16384, "set 16..16384")?;
        c.all_finite("intrinsics", &self.intrinsics, 1.0, 1e5)?;
        c.all_finite("distortion", &self.distortion, -10.0, 10.0)?;
        c.all_finite("p_C_in_B_m", &self.p_C_in_B_m, -10.0, 10.0)?;
        c.all_finite("q_B_C_xyzw", &self.q_B_C_xyzw, -1.0, 1.0)?;
        let n = self.q_B_C_xyzw.iter().map(|x| x * x).sum::<f64>().sqrt();
        if (n - 1.0).abs() > 1e-3 {
            return Err(c.fail(
                "q_B_C_xyzw",
                format!("norm {n:.6} is not 1"),
                "give a unit quaternion [x, y, z, w]",
            ));
        }
        c.positive("pixel_noise_px", self.pixel_noise_px, 100.0)?;
        c.range("model_noise_px", self.model_noise_px, 0.01, 100.0)?;
        c.positive("rate_hz", self.rate_hz, 1000.0)
    }
}
