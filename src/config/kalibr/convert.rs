//! Kalibr's values into the config's: `T_cam_imu` into `q_B_C_xyzw` and
//! `p_C_in_B_m` (FRD or FLU IMU axes), its distortion models, time shift and
//! IMU noise, and config-check failures mapped back to Kalibr's keys.

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use yaml_rust2::Yaml;

use cmsckf_models::check::{FieldError, Validate};
use cmsckf_models::sensors::{CameraModelKind, ImuConfig};

use super::yaml::{kind, Doc};
use super::{ImportOptions, ImportedImu, ImuFrame, KalibrError, KalibrImport, MAX_TIMESHIFT_S, ORTHONORMAL_TOLERANCE};

const IMUCAM_HINT: &str = " (kalibr_calibrate_cameras' camchain.yaml has no IMU: give the camchain-imucam.yaml \
                           that kalibr_calibrate_imu_camera writes)";

/// One camera of a camchain-imucam.yaml, over `opts.base.camera`.
pub(super) fn parse_camchain(text: &str, origin: &str, opts: &ImportOptions) -> Result<KalibrImport, KalibrError> {
    let doc = Doc { path: origin };
    let root = doc.load(text)?;
    let name = opts.camera;
    let cam = match &root[name] {
        Yaml::BadValue => {
            let cams: Vec<&str> = root
                .as_hash()
                .map(|h| h.keys().filter_map(|k| k.as_str()).collect())
                .unwrap_or_default();
            let hint = if cams.is_empty() {
                " (the file has no keys)".to_string()
            } else {
                format!(" (the file has {}; pick one with --camera)", cams.join(", "))
            };
            return Err(doc.missing(name, hint));
        }
        y if !y.is_hash() => {
            return Err(doc.invalid(name, format!("expected a camera's mapping, found {}", kind(y))));
        }
        y => y,
    };
    let key = |k: &str| format!("{name}.{k}");

    // Projection and distortion.
    let camera_model = doc.string(
        doc.get(cam, "camera_model", &key("camera_model"), "")?,
        &key("camera_model"),
    )?;
    if camera_model != "pinhole" {
        return Err(KalibrError::Unsupported {
            path: origin.to_string(),
            key: key("camera_model"),
            value: camera_model.to_string(),
            supported: "this project models pinhole cameras only (camera_model: pinhole)".into(),
        });
    }
    let intrinsics = doc.numbers::<4>(doc.get(cam, "intrinsics", &key("intrinsics"), "")?, &key("intrinsics"))?;
    let distortion_model = doc.string(
        doc.get(cam, "distortion_model", &key("distortion_model"), "")?,
        &key("distortion_model"),
    )?;
    let (model, distortion) = match distortion_model {
        "radtan" | "equidistant" => {
            let d = doc.numbers::<4>(
                doc.get(cam, "distortion_coeffs", &key("distortion_coeffs"), "")?,
                &key("distortion_coeffs"),
            )?;
            let kind = if distortion_model == "radtan" {
                CameraModelKind::PinholeRadtan
            } else {
                CameraModelKind::PinholeEquidistant
            };
            (kind, d)
        }
        "none" => (CameraModelKind::PinholeRadtan, [0.0; 4]),
        other => {
            return Err(KalibrError::Unsupported {
                path: origin.to_string(),
                key: key("distortion_model"),
                value: other.to_string(),
                supported: "this project models radtan, equidistant or none".into(),
            });
        }
    };
    let resolution = doc.get(cam, "resolution", &key("resolution"), "")?;
    let Yaml::Array(res) = resolution else {
        return Err(doc.invalid(
            &key("resolution"),
            format!("expected [width, height], found {}", kind(resolution)),
        ));
    };
    if res.len() != 2 {
        return Err(doc.invalid(
            &key("resolution"),
            format!("expected [width, height], found {} numbers", res.len()),
        ));
    }
    let width_px = doc.count(&res[0], &format!("{}[0]", key("resolution")))?;
    let height_px = doc.count(&res[1], &format!("{}[1]", key("resolution")))?;

    // Extrinsics: T_B_C = T_B_I T_cam_imu⁻¹.
    let t_key = key("T_cam_imu");
    let t_node = doc.get(cam, "T_cam_imu", &t_key, IMUCAM_HINT)?;
    let Yaml::Array(rows) = t_node else {
        return Err(doc.invalid(&t_key, format!("expected 4 rows of 4 numbers, found {}", kind(t_node))));
    };
    if rows.len() != 4 {
        return Err(doc.invalid(
            &t_key,
            format!("expected 4 rows of 4 numbers, found {} rows", rows.len()),
        ));
    }
    let mut m = [[0.0; 4]; 4];
    for (r, row) in rows.iter().enumerate() {
        m[r] = doc.numbers::<4>(row, &format!("{t_key}[{r}]"))?;
    }
    if (m[3][0].abs() + m[3][1].abs() + m[3][2].abs() + (m[3][3] - 1.0).abs()) > 1e-9 {
        return Err(doc.invalid(
            &format!("{t_key}[3]"),
            format!("a rigid transform's last row is [0, 0, 0, 1], not {:?}", m[3]),
        ));
    }
    let R_CI = Matrix3::from_fn(|r, c| m[r][c]);
    let t_CI = Vector3::new(m[0][3], m[1][3], m[2][3]);
    let deviation = (R_CI.transpose() * R_CI - Matrix3::identity()).abs().max();
    if deviation > ORTHONORMAL_TOLERANCE {
        return Err(doc.invalid(
            &t_key,
            format!(
                "its rotation is not orthonormal: RᵀR differs from the identity by {deviation:.2e} \
                 (at most {ORTHONORMAL_TOLERANCE:e}); check that the matrix was copied whole"
            ),
        ));
    }
    let det = R_CI.determinant();
    if det < 0.0 {
        return Err(doc.invalid(
            &t_key,
            format!("its rotation has determinant {det:.4}: a reflection, not a rotation (a sign is wrong)"),
        ));
    }
    let R_B_I = opts.imu_frame.R_B_I();
    let R_B_C = R_B_I * R_CI.transpose();
    let p_C_in_B = -(R_B_C * t_CI);
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(R_B_C));
    let mut q = UnitQuaternion::new_normalize(q.into_inner());
    if q.w < 0.0 {
        q = UnitQuaternion::new_unchecked(-q.into_inner());
    }

    // Time offset.
    let ts_key = key("timeshift_cam_imu");
    let timeshift = doc.number(doc.get(cam, "timeshift_cam_imu", &ts_key, IMUCAM_HINT)?, &ts_key)?;
    if timeshift.abs() > MAX_TIMESHIFT_S {
        return Err(doc.invalid(
            &ts_key,
            format!(
                "{timeshift} s is more than the {MAX_TIMESHIFT_S} s that estimator.time_offset_s accepts; \
                 a shift that large means the camera and IMU stamps came from different clocks"
            ),
        ));
    }

    let mut camera = opts.base.camera.clone();
    camera.model = model;
    camera.width_px = width_px;
    camera.height_px = height_px;
    camera.intrinsics = intrinsics;
    camera.distortion = distortion;
    camera.p_C_in_B_m = [p_C_in_B.x + 0.0, p_C_in_B.y + 0.0, p_C_in_B.z + 0.0];
    camera.q_B_C_xyzw = [q.i + 0.0, q.j + 0.0, q.k + 0.0, q.w + 0.0];
    camera
        .validate("camera")
        .map_err(|e| doc.invalid(&camera_key(name, &e.field), config_problem(&e)))?;

    let mut warnings = Vec::new();
    // The image's down axis (y_C) in the body frame: a drone's camera looks
    // forward or down, with y_C along +z_B (down) or horizontal.
    let down = R_B_C[(2, 1)];
    if down < -0.5 {
        let (other, what) = match opts.imu_frame {
            ImuFrame::Frd => (ImuFrame::Flu, "in ROS's FLU axes (MAVROS's /mavros/imu/data_raw is)"),
            ImuFrame::Flu => (ImuFrame::Frd, "in the autopilot's own FRD axes"),
        };
        warnings.push(format!(
            "as imported ({} IMU axes), {name}'s image-down axis points up in the body frame \
             (y_C·z_B = {down:.2}): the camera hangs upside down. If the IMU data Kalibr was given were \
             {what}, import with --imu-frame {}",
            opts.imu_frame.name().to_uppercase(),
            other.name()
        ));
    }

    Ok(KalibrImport {
        camchain_path: origin.to_string(),
        camera_name: name.to_string(),
        kalibr_camera_model: camera_model.to_string(),
        kalibr_distortion_model: distortion_model.to_string(),
        imu_frame: opts.imu_frame,
        camera,
        time_offset_s: timeshift + 0.0,
        imu: None,
        warnings,
        base_origin: opts.base_origin.to_string(),
    })
}

/// Kalibr's imu.yaml (its keys at the top level) or its results file (under
/// `imu0`), over `base`.
pub(super) fn parse_imu(text: &str, origin: &str, base: &ImuConfig) -> Result<ImportedImu, KalibrError> {
    let doc = Doc { path: origin };
    let root = doc.load(text)?;
    let (block, prefix) = if !root["accelerometer_noise_density"].is_badvalue() {
        (&root, "")
    } else if root["imu0"].is_hash() {
        (&root["imu0"], "imu0.")
    } else {
        return Err(doc.missing(
            "accelerometer_noise_density",
            " (Kalibr's imu.yaml has it at the top level, its imu-*.yaml results under imu0)",
        ));
    };
    let positive = |k: &str| -> Result<f64, KalibrError> {
        let full = format!("{prefix}{k}");
        let v = doc.number(doc.get(block, k, &full, "")?, &full)?;
        if v <= 0.0 {
            return Err(doc.invalid(&full, format!("{v} must be greater than zero")));
        }
        Ok(v)
    };
    let mut imu = base.clone();
    imu.accel_noise_density = positive("accelerometer_noise_density")?;
    imu.accel_random_walk = positive("accelerometer_random_walk")?;
    imu.gyro_noise_density = positive("gyroscope_noise_density")?;
    imu.gyro_random_walk = positive("gyroscope_random_walk")?;
    let update_rate_hz = positive("update_rate")?;
    imu.validate("imu")
        .map_err(|e| doc.invalid(&imu_key(prefix, &e.field), config_problem(&e)))?;
    Ok(ImportedImu {
        path: origin.to_string(),
        key_prefix: prefix.to_string(),
        imu,
        update_rate_hz,
    })
}

/// The Kalibr key behind a `[camera]` field.
pub(super) fn camera_key(cam: &str, field: &str) -> String {
    let f = field.strip_prefix("camera.").unwrap_or(field);
    match f {
        "width_px" => format!("{cam}.resolution[0]"),
        "height_px" => format!("{cam}.resolution[1]"),
        _ if f.starts_with("intrinsics") => format!("{cam}.{f}"),
        _ if f.starts_with("distortion") => format!("{cam}.distortion_coeffs{}", &f["distortion".len()..]),
        _ if f.starts_with("p_C_in_B_m") || f.starts_with("q_B_C_xyzw") => format!("{cam}.T_cam_imu"),
        _ => field.to_string(),
    }
}

/// The Kalibr key behind an `[imu]` field.
pub(super) fn imu_key(prefix: &str, field: &str) -> String {
    let k = match field.strip_prefix("imu.").unwrap_or(field) {
        "accel_noise_density" => "accelerometer_noise_density",
        "accel_random_walk" => "accelerometer_random_walk",
        "gyro_noise_density" => "gyroscope_noise_density",
        "gyro_random_walk" => "gyroscope_random_walk",
        _ => return field.to_string(),
    };
    format!("{prefix}{k}")
}

/// A config check's failure, said from the Kalibr side.
fn config_problem(e: &FieldError) -> String {
    format!(
        "it gives `{}`, which the config refuses: {}; {}",
        e.field, e.problem, e.fix
    )
}
