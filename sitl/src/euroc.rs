//! A EuRoC/ASL dataset folder as a flight to serve: why this exists is that
//! a user with a public visual-inertial sequence should fly the whole chain
//! on it, the mock autopilot sending the sequence's own IMU over MAVLink and
//! its camera's own images on the camera socket (for `cmsckf-frontend`),
//! both on one clock, and scoring the daemon against the sequence's ground
//! truth (`cmsckf-sitl serve --scenario euroc:DIR --camera-socket PATH`).
//!
//! Read from `mav0/`:
//! - `imu0/data.csv`: `t_ns, ω_x, ω_y, ω_z (rad/s), a_x, a_y, a_z (m/s²)` in
//!   the IMU frame, which is the body frame;
//! - `cam0/data.csv`: `t_ns, file` and `cam0/data/*.png` (8-bit grey);
//! - `state_groundtruth_estimate0/data.csv`: `t_ns, p (m), q (w x y z), …`,
//!   the body in a z-up world (turned into NED as TUM files are).
//!
//! Flight time 0 is the first ground-truth pose; the IMU and frames before
//! it are dropped. The sensors are hardware-synchronised, so each frame's
//! exposure is its stamp; it is delivered after the simulator's camera
//! latency (its lower bound). No GNSS is served.

use std::path::{Path, PathBuf};

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

use crate::config::SimConfig;
use crate::features::{CameraFrame, TrackStats};
use crate::flight::{Dataset, TruthRow};
use crate::imu::{ImuBias, ImuSample};
use crate::trajectory::tum::{from_rows, TumRow};
use crate::trajectory::TrajectoryError;

/// The rows of a EuRoC CSV file: its numbers, comments and blank lines
/// skipped, each row checked to have `min_cols` finite numbers (a text
/// column, the image file, is kept apart).
fn read_csv(path: &Path, min_cols: usize) -> Result<Vec<(Vec<f64>, String)>, TrajectoryError> {
    let text = std::fs::read_to_string(path).map_err(|source| TrajectoryError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let mut rows = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let l = line.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let bad = |reason: String| TrajectoryError::BadRow {
            path: path.to_path_buf(),
            line: i + 1,
            reason,
        };
        let mut nums = Vec::new();
        let mut text_col = String::new();
        for cell in l.split(',').map(str::trim) {
            match cell.parse::<f64>() {
                Ok(v) if v.is_finite() => nums.push(v),
                Ok(_) => return Err(bad("non-finite value".into())),
                Err(_) => text_col = cell.to_string(),
            }
        }
        if nums.len() < min_cols {
            return Err(bad(format!("expected {min_cols} numbers, found {}", nums.len())));
        }
        if let Some((last, _)) = rows.last() {
            let last: &Vec<f64> = last;
            if nums[0] <= last[0] {
                return Err(bad(format!("time {} ns does not increase", nums[0])));
            }
        }
        rows.push((nums, text_col));
    }
    Ok(rows)
}

/// Loads the EuRoC folder `root` (the one holding `mav0/`) as a dataset to
/// serve, with `cfg` for the simulator's settings (camera latency, the mock
/// autopilot's EKF); its GNSS is switched off.
pub fn load(root: &Path, cfg: &SimConfig) -> Result<Dataset, TrajectoryError> {
    let mav = root.join("mav0");
    let gt_path = mav.join("state_groundtruth_estimate0").join("data.csv");
    let gt = read_csv(&gt_path, 8)?;
    let Some((first, _)) = gt.first() else {
        return Err(TrajectoryError::TooShort {
            path: gt_path,
            reason: "no poses".into(),
        });
    };
    let t0_ns = first[0];
    let rel = move |t_ns: f64| (t_ns - t0_ns) * 1e-9;
    let rows: Vec<TumRow> = gt
        .iter()
        .map(|(v, _)| {
            let q = UnitQuaternion::from_quaternion(Quaternion::new(v[4], v[5], v[6], v[7]));
            (rel(v[0]), Vector3::new(v[1], v[2], v[3]), q)
        })
        .collect();
    let traj = from_rows(format!("euroc:{}", root.display()), &gt_path, &rows, None)?;
    let duration = traj.duration_s;
    let in_flight = |t: f64| (0.0..=duration).contains(&t);

    let imu: Vec<ImuSample> = read_csv(&mav.join("imu0").join("data.csv"), 7)?
        .into_iter()
        .map(|(v, _)| ImuSample {
            t_s: rel(v[0]),
            gyro_radps: Vector3::new(v[1], v[2], v[3]),
            accel_mps2: Vector3::new(v[4], v[5], v[6]),
        })
        .filter(|m| in_flight(m.t_s))
        .collect();
    let cam_dir = mav.join("cam0");
    let mut frames = Vec::new();
    let mut frame_images: Vec<PathBuf> = Vec::new();
    for (v, file) in read_csv(&cam_dir.join("data.csv"), 1)? {
        let t = rel(v[0]);
        if !in_flight(t) {
            continue;
        }
        frames.push(CameraFrame {
            t_s: t,
            t_exposure_s: t,
            t_delivered_s: t + cfg.camera_latency_s[0],
            features: Vec::new(),
        });
        frame_images.push(cam_dir.join("data").join(file));
    }
    let truth = imu
        .iter()
        .map(|m| TruthRow {
            truth: traj.sample(m.t_s),
            bias: ImuBias::default(),
        })
        .collect();
    let mut cfg = cfg.clone();
    cfg.gnss.enabled = false;
    if imu.len() > 1 {
        cfg.imu_rate_hz = (imu.len() - 1) as f64 / (imu[imu.len() - 1].t_s - imu[0].t_s).max(1e-9);
    }
    Ok(Dataset {
        scenario: traj.name.clone(),
        seed: 0,
        duration_s: duration,
        cfg,
        truth,
        imu,
        frames,
        frame_images,
        gnss: Vec::new(),
        base_gnss: Vec::new(),
        base_arp_ecef_m: None,
        ephemerides: Vec::new(),
        track_stats: TrackStats::default(),
        true_camera: None,
        trajectory: traj,
    })
}

/// Reads an 8-bit grey PNG (EuRoC's cameras write these) into `out`;
/// returns its width and height.
pub fn read_grey_png(path: &Path, out: &mut Vec<u8>) -> Result<(u32, u32), String> {
    let file = std::fs::File::open(path).map_err(|e| format!("'{}': {e}", path.display()))?;
    let mut dec = png::Decoder::new(std::io::BufReader::new(file));
    dec.set_transformations(png::Transformations::STRIP_16 | png::Transformations::EXPAND);
    let mut reader = dec.read_info().map_err(|e| format!("'{}': {e}", path.display()))?;
    let (w, h) = (reader.info().width, reader.info().height);
    if w == 0 || h == 0 || w > 8192 || h > 8192 {
        return Err(format!("'{}': {w}x{h} px is not a camera image", path.display()));
    }
    let mut buf = vec![0u8; reader.output_buffer_size()];
    let info = reader
        .next_frame(&mut buf)
        .map_err(|e| format!("'{}': {e}", path.display()))?;
    if info.color_type != png::ColorType::Grayscale || info.bit_depth != png::BitDepth::Eight {
        return Err(format!(
            "'{}': {:?} {:?}; expected 8-bit grey",
            path.display(),
            info.color_type,
            info.bit_depth
        ));
    }
    out.clear();
    out.extend_from_slice(&buf[..(w * h) as usize]);
    Ok((w, h))
}
