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
//!   it, FRD (docs/design.md, "Frames"; `src/io/mavlink.rs` takes
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

use std::fmt::Write as _;
use std::path::Path;

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use yaml_rust2::{Yaml, YamlLoader};

use cmsckf_models::check::{FieldError, Validate};
use cmsckf_models::sensors::{CameraConfig, CameraModelKind, ImuConfig};

use super::Config;

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
    /// The config whose other `[camera]` and `[imu]` keys (`pixel_noise_px`,
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
    /// The `[camera]` section: Kalibr's values, `pixel_noise_px` and
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
fn num(x: f64) -> String {
    format!("{:?}", x + 0.0)
}

fn array(xs: &[f64]) -> String {
    let parts: Vec<String> = xs.iter().map(|&x| num(x)).collect();
    format!("[{}]", parts.join(", "))
}

/// Where errors point: the file.
struct Doc<'a> {
    path: &'a str,
}

impl Doc<'_> {
    fn invalid(&self, key: &str, problem: impl Into<String>) -> KalibrError {
        KalibrError::Invalid {
            path: self.path.to_string(),
            key: key.to_string(),
            problem: problem.into(),
        }
    }

    fn missing(&self, key: &str, hint: impl Into<String>) -> KalibrError {
        KalibrError::Missing {
            path: self.path.to_string(),
            key: key.to_string(),
            hint: hint.into(),
        }
    }

    /// The whole document: one YAML mapping.
    fn load(&self, text: &str) -> Result<Yaml, KalibrError> {
        let not_yaml = |message: String| KalibrError::NotYaml {
            path: self.path.to_string(),
            message,
        };
        let docs = YamlLoader::load_from_str(text).map_err(|e| not_yaml(e.to_string()))?;
        let doc = docs
            .into_iter()
            .next()
            .ok_or_else(|| not_yaml("it holds no YAML document (empty file?)".into()))?;
        if !doc.is_hash() {
            return Err(not_yaml(format!(
                "its top level is {}, not a mapping of keys",
                kind(&doc)
            )));
        }
        Ok(doc)
    }

    /// `map[key]`, which must be there; `full` is its name in errors.
    fn get<'y>(&self, map: &'y Yaml, key: &str, full: &str, hint: &str) -> Result<&'y Yaml, KalibrError> {
        match &map[key] {
            Yaml::BadValue => Err(self.missing(full, hint)),
            y => Ok(y),
        }
    }

    /// A finite number.
    fn number(&self, y: &Yaml, key: &str) -> Result<f64, KalibrError> {
        let v = match y {
            Yaml::Integer(i) => *i as f64,
            Yaml::Real(s) => y
                .as_f64()
                .ok_or_else(|| self.invalid(key, format!("'{s}' is not a number")))?,
            Yaml::String(s) => return Err(self.invalid(key, format!("'{s}' is not a number"))),
            other => return Err(self.invalid(key, format!("expected a number, found {}", kind(other)))),
        };
        if !v.is_finite() {
            return Err(self.invalid(key, format!("{v} is not a finite number")));
        }
        Ok(v)
    }

    /// A list of exactly `N` finite numbers.
    fn numbers<const N: usize>(&self, y: &Yaml, key: &str) -> Result<[f64; N], KalibrError> {
        let Yaml::Array(items) = y else {
            return Err(self.invalid(key, format!("expected a list of {N} numbers, found {}", kind(y))));
        };
        if items.len() != N {
            return Err(self.invalid(
                key,
                format!("expected a list of {N} numbers, found {} of them", items.len()),
            ));
        }
        let mut out = [0.0; N];
        for (i, item) in items.iter().enumerate() {
            out[i] = self.number(item, &format!("{key}[{i}]"))?;
        }
        Ok(out)
    }

    /// A positive whole number (a pixel count).
    fn count(&self, y: &Yaml, key: &str) -> Result<u32, KalibrError> {
        let v = self.number(y, key)?;
        if v.fract() != 0.0 || v < 1.0 || v > u32::MAX as f64 {
            return Err(self.invalid(key, format!("{v} is not a positive whole number")));
        }
        Ok(v as u32)
    }

    fn string<'y>(&self, y: &'y Yaml, key: &str) -> Result<&'y str, KalibrError> {
        match y {
            Yaml::String(s) => Ok(s),
            other => Err(self.invalid(key, format!("expected a name, found {}", kind(other)))),
        }
    }
}

/// What a YAML node is, for messages.
fn kind(y: &Yaml) -> &'static str {
    match y {
        Yaml::Real(_) | Yaml::Integer(_) => "a number",
        Yaml::String(_) => "a string",
        Yaml::Boolean(_) => "a boolean",
        Yaml::Array(_) => "a list",
        Yaml::Hash(_) => "a mapping",
        Yaml::Alias(_) => "an alias",
        Yaml::Null => "nothing (an empty value)",
        Yaml::BadValue => "nothing",
    }
}

const IMUCAM_HINT: &str = " (kalibr_calibrate_cameras' camchain.yaml has no IMU: give the camchain-imucam.yaml \
                           that kalibr_calibrate_imu_camera writes)";

/// One camera of a camchain-imucam.yaml, over `opts.base.camera`.
fn parse_camchain(text: &str, origin: &str, opts: &ImportOptions) -> Result<KalibrImport, KalibrError> {
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
fn parse_imu(text: &str, origin: &str, base: &ImuConfig) -> Result<ImportedImu, KalibrError> {
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
fn camera_key(cam: &str, field: &str) -> String {
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
fn imu_key(prefix: &str, field: &str) -> String {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_map_back_to_kalibr() {
        assert_eq!(camera_key("cam1", "camera.distortion[2]"), "cam1.distortion_coeffs[2]");
        assert_eq!(camera_key("cam0", "camera.width_px"), "cam0.resolution[0]");
        assert_eq!(camera_key("cam0", "camera.p_C_in_B_m[1]"), "cam0.T_cam_imu");
        assert_eq!(imu_key("imu0.", "imu.gyro_random_walk"), "imu0.gyroscope_random_walk");
    }

    #[test]
    fn numbers_print_back_to_the_same_bits() {
        for x in [
            0.1,
            1.76187114e-05,
            -0.0,
            752.0,
            std::f64::consts::FRAC_1_SQRT_2,
            1e-300,
        ] {
            let t: toml::Value = toml::from_str(&format!("x = {}", num(x))).unwrap();
            assert_eq!(t["x"].as_float().unwrap().to_bits(), (x + 0.0).to_bits(), "{x}");
        }
    }
}
