//! The log records of the output channels written at IMU or camera rate
//! (poses, transforms, the estimate sent), serialised straight from
//! borrowed data: building a `serde_json::Value` first costs an allocation
//! per field. The JSON is that of the channels' schemas (`io::mcap_log`);
//! the inputs' records are `io::mcap_log::input`.

use serde::Serialize;

#[derive(Clone, Copy, Serialize)]
pub struct Stamp {
    pub sec: u64,
    pub nsec: u64,
}

impl Stamp {
    /// The time `t_s` (s) as Foxglove's `{sec, nsec}`.
    pub fn at(t_s: f64) -> Self {
        let t = t_s.max(0.0);
        Stamp {
            sec: t.floor() as u64,
            nsec: ((t - t.floor()) * 1e9) as u64,
        }
    }
}

#[derive(Clone, Copy, Serialize)]
pub struct Xyz {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

#[derive(Clone, Copy, Serialize)]
pub struct Quat {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}

#[derive(Serialize)]
pub struct PoseBody {
    pub position: Xyz,
    pub orientation: Quat,
}

/// foxglove.PoseInFrame.
#[derive(Serialize)]
pub struct Pose<'a> {
    pub timestamp: Stamp,
    pub frame_id: &'a str,
    pub pose: PoseBody,
}

/// foxglove.FrameTransform.
#[derive(Serialize)]
pub struct Transform<'a> {
    pub timestamp: Stamp,
    pub parent_frame_id: &'a str,
    pub child_frame_id: &'a str,
    pub translation: Xyz,
    pub rotation: Quat,
}

/// `/output/vision_position_estimate`: one record per estimate sent, with
/// what the message carried.
#[derive(Serialize)]
pub struct Vpe<'a> {
    pub usec: u64,
    pub p_ned_m: &'a [f64],
    pub rpy_rad: &'a [f64],
    /// Upper triangle of the 6×6 pose covariance (variances, m² and rad²).
    pub covariance: &'a [f32],
    pub reset_counter: u8,
    /// The message that carried it: `odometry` or `vision_position_estimate`.
    pub message: crate::config::OutputMessage,
    /// The pose covariance exactly as the message carried it (ArduPilot's
    /// reading of it differs: `output.covariance`).
    pub pose_covariance_sent: &'a [f32],
    /// `ODOMETRY.quality` (−1 failed … 100 best; with
    /// `VISION_POSITION_ESTIMATE`, which has none, what it would have been).
    pub quality: i8,
    /// The velocity sent (world NED, m/s).
    pub v_ned_mps: &'a [f64],
}
