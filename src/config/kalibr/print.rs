//! Rendering a [`KalibrImport`] as the config's TOML sections, each value
//! commented with the Kalibr key it came from. Kept apart from the parsing so
//! the wording of the output can change without touching the conversions.

use std::fmt::Write as _;

use cmsckf_models::sensors::CameraModelKind;

use super::{ImuFrame, KalibrImport};

impl KalibrImport {
    /// The config sections as TOML, each value with where it came from:
    /// `[camera]` and `[imu]` whole, `[estimator]` with `time_offset_s`
    /// alone. Numbers are printed to round-trip exactly.
    pub fn to_toml(&self) -> String {
        let mut s = String::new();
        let c = &self.camera;
        let cam = &self.camera_name;
        let kept = format!("not in Kalibr's files: kept from {}", self.base_origin);
        let _ = writeln!(s, "# cmsckf config sections from Kalibr (cmsckf calib import-kalibr).");
        let _ = writeln!(
            s,
            "# camchain: {}, camera {cam} ({}, {})",
            self.camchain_path, self.kalibr_camera_model, self.kalibr_distortion_model
        );
        match &self.imu {
            Some(imu) => {
                let block = imu.key_prefix.trim_end_matches('.');
                let block = if block.is_empty() {
                    String::new()
                } else {
                    format!(", block {block}")
                };
                let _ = writeln!(s, "# imu: {}{block}", imu.path);
            }
            None => {
                let _ = writeln!(
                    s,
                    "# imu: no file given, so no [imu] section (add Kalibr's imu.yaml to import the noise)"
                );
            }
        }
        let _ = match self.imu_frame {
            ImuFrame::Frd => writeln!(
                s,
                "# Kalibr's IMU frame taken as FRD, the body frame (--imu-frame frd): T_B_C = T_cam_imu^-1."
            ),
            ImuFrame::Flu => writeln!(
                s,
                "# Kalibr's IMU frame taken as ROS FLU (--imu-frame flu): T_B_C = Rx(180 deg) T_cam_imu^-1, into FRD."
            ),
        };
        let sections = match self.imu {
            Some(_) => "[camera] and [imu] sections",
            None => "[camera] section",
        };
        let _ = writeln!(s, "# Replace your {sections} with these, and set time_offset_s in");
        let _ = writeln!(s, "# your [estimator] section (its other keys are not Kalibr's).");
        for w in &self.warnings {
            let _ = writeln!(s, "# WARNING: {w}");
        }

        let _ = writeln!(s, "\n[camera]");
        let model = match c.model {
            CameraModelKind::PinholeRadtan => "pinhole-radtan",
            CameraModelKind::PinholeEquidistant => "pinhole-equidistant",
        };
        line(
            &mut s,
            "model",
            format!("\"{model}\""),
            &format!(
                "Kalibr {cam}.camera_model {}, distortion_model {}",
                self.kalibr_camera_model, self.kalibr_distortion_model
            ),
        );
        line(&mut s, "width_px", c.width_px.to_string(), "Kalibr resolution[0] (px)");
        line(
            &mut s,
            "height_px",
            c.height_px.to_string(),
            "Kalibr resolution[1] (px)",
        );
        line(
            &mut s,
            "intrinsics",
            array(&c.intrinsics),
            "[fx, fy, cx, cy] (px) = Kalibr intrinsics [fu, fv, pu, pv]",
        );
        let dist = match self.kalibr_distortion_model.as_str() {
            "none" => "no distortion (Kalibr distortion_model none)",
            "equidistant" => "[k1, k2, k3, k4] = Kalibr distortion_coeffs (equidistant)",
            _ => "[k1, k2, p1, p2] = Kalibr distortion_coeffs (radtan)",
        };
        line(&mut s, "distortion", array(&c.distortion), dist);
        line(
            &mut s,
            "p_C_in_B_m",
            array(&c.p_C_in_B_m),
            "camera position in the body frame, FRD (m): translation of T_B_C",
        );
        line(
            &mut s,
            "q_B_C_xyzw",
            array(&c.q_B_C_xyzw),
            "camera-to-body rotation, Hamilton [x, y, z, w]: rotation of T_B_C",
        );
        line(&mut s, "pixel_noise_px", num(c.pixel_noise_px), &kept);
        line(&mut s, "frontend_sigma", c.frontend_sigma.to_string(), &kept);
        line(&mut s, "model_noise_px", num(c.model_noise_px), &kept);
        line(&mut s, "rate_hz", num(c.rate_hz), &kept);

        if let Some(imu) = &self.imu {
            let i = &imu.imu;
            let _ = writeln!(s, "\n[imu]");
            line(
                &mut s,
                "accel_noise_density",
                num(i.accel_noise_density),
                "Kalibr accelerometer_noise_density (m/s²/√Hz; continuous-time, unchanged)",
            );
            line(
                &mut s,
                "accel_random_walk",
                num(i.accel_random_walk),
                "Kalibr accelerometer_random_walk (m/s³/√Hz)",
            );
            line(
                &mut s,
                "gyro_noise_density",
                num(i.gyro_noise_density),
                "Kalibr gyroscope_noise_density (rad/s/√Hz)",
            );
            line(
                &mut s,
                "gyro_random_walk",
                num(i.gyro_random_walk),
                "Kalibr gyroscope_random_walk (rad/s²/√Hz)",
            );
            line(&mut s, "gravity_mps2", num(i.gravity_mps2), &kept);
            let _ = writeln!(
                s,
                "# Kalibr update_rate = {} Hz discretised these inside Kalibr only: the filter uses each",
                num(imu.update_rate_hz)
            );
            let _ = writeln!(
                s,
                "# IMU sample's own interval ([mavlink] imu_rate_hz is the rate asked of the autopilot)."
            );
        }

        let _ = writeln!(s, "\n[estimator]");
        line(
            &mut s,
            "time_offset_s",
            num(self.time_offset_s),
            "Kalibr timeshift_cam_imu (s): t_imu = t_cam + shift, the sign of t_d; a prior, estimated online",
        );
        s
    }
}

/// `key = value` and its comment, aligned.
fn line(s: &mut String, key: &str, value: String, comment: &str) {
    let kv = format!("{key} = {value}");
    let _ = writeln!(s, "{kv:<38} # {comment}");
}

/// A float as TOML that parses back to the same bits (Rust's shortest
/// round-trip form; `-0.0` as `0.0`).
pub(super) fn num(x: f64) -> String {
    format!("{:?}", x + 0.0)
}

fn array(xs: &[f64]) -> String {
    let parts: Vec<String> = xs.iter().map(|&x| num(x)).collect();
    format!("[{}]", parts.join(", "))
}
