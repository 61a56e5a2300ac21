//! The log's frames as Foxglove draws them: why this exists is that the
//! filter lives in NED (z down) and FRD, while Foxglove's 3D panel is z-up,
//! so a vehicle logged only in `ned` appears under the grid, upside down.
//!
//! The tree is `map` (ENU, z up) → `ned` (the filter's world frame) →
//! `base_link` (the body, FRD; `/tf` at the output rate) → `camera` (the
//! camera's extrinsics, `T_B_C`). `map → ned` is the fixed rotation
//! `x_E = y_N, y_E = x_N, z_E = −z_N`: a half turn about `(1, 1, 0)/√2`,
//! the quaternion `(w, x, y, z) = (0, 1/√2, 1/√2, 0)`. The static links
//! are logged at 10 Hz beside `/filter/state`, so a panel opened anywhere
//! in the log finds them.
//!
//! The fused estimate also goes to `/location` as a `foxglove.LocationFix`
//! (the NED position through the world origin to latitude, longitude and
//! ellipsoidal height, its covariance rotated to ENU), so the Map panel
//! draws it beside the single-point fixes of `/gnss/fix`.
//!
//! The 3D scene also gets the keyframes (`/keyframes`, every keyframe's
//! pose in `ned` at each new one) and the landmarks of the tracks fused
//! (`/landmarks`, a point cloud in `ned`, gathered and logged at most 5 times
//! a second, at most [`LandmarkCloud::MAX_POINTS`] at a time).

use nalgebra::{Isometry3, Matrix3, Vector3};
use serde_json::json;

use cmsckf_models::geodesy::{ecef_to_llh, NedFrame};

use super::records::{Quat, Stamp, Transform, Xyz};
use crate::estimator::imu_covariance::position_block;
use crate::estimator::{Estimator, ImuState, Mat15};
use crate::io::mcap_log::{McapLogger, Topic};

/// The static links `map → ned` and `base_link → camera`, to `/tf`.
pub(super) fn log_static_frames(l: &McapLogger, t_s: f64, T_B_C: &Isometry3<f64>) {
    let h = std::f64::consts::FRAC_1_SQRT_2;
    l.log(
        Topic::Transform,
        t_s,
        &Transform {
            timestamp: Stamp::at(t_s),
            parent_frame_id: "map",
            child_frame_id: "ned",
            translation: Xyz { x: 0.0, y: 0.0, z: 0.0 },
            rotation: Quat {
                x: h,
                y: h,
                z: 0.0,
                w: 0.0,
            },
        },
    );
    let q = T_B_C.rotation.coords;
    let p = T_B_C.translation.vector;
    l.log(
        Topic::Transform,
        t_s,
        &Transform {
            timestamp: Stamp::at(t_s),
            parent_frame_id: "base_link",
            child_frame_id: "camera",
            translation: Xyz { x: p.x, y: p.y, z: p.z },
            rotation: Quat {
                x: q.x,
                y: q.y,
                z: q.z,
                w: q.w,
            },
        },
    );
}

/// NED → ENU, as a matrix: `S = [[0,1,0],[1,0,0],[0,0,−1]]`.
fn ned_to_enu() -> Matrix3<f64> {
    Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0)
}

/// The fused estimate as a `foxglove.LocationFix` on `/location`:
/// `r = o + R_en p`, then geodetic; covariance `S P_pp Sᵀ` (ENU, row-major).
pub(super) fn log_location(l: &McapLogger, t_s: f64, x: &ImuState, cov: &Mat15, frame: &NedFrame) {
    let r_ecef = frame.origin_ecef + frame.R_ecef_ned * x.p_B_in_W;
    let (lat, lon, h) = ecef_to_llh(&r_ecef);
    let s = ned_to_enu();
    let p_enu = s * position_block(cov) * s.transpose();
    let c: Vec<f64> = (0..9).map(|k| p_enu[(k / 3, k % 3)]).collect();
    let ts = Stamp::at(t_s);
    l.log(
        Topic::Location,
        t_s,
        &json!({"timestamp": ts, "frame_id": "base_link",
            "latitude": lat.to_degrees(), "longitude": lon.to_degrees(), "altitude": h,
            "position_covariance": c, "position_covariance_type": 3}),
    );
}

/// A pose in `ned` as Foxglove's `{position, orientation}`.
fn pose_json(p: &Vector3<f64>, q: &nalgebra::UnitQuaternion<f64>) -> serde_json::Value {
    json!({"position": {"x": p.x, "y": p.y, "z": p.z},
        "orientation": {"x": q.i, "y": q.j, "z": q.k, "w": q.w}})
}

/// Every keyframe's body pose, to `/keyframes` (`foxglove.PosesInFrame`).
pub(super) fn log_keyframes(l: &McapLogger, t_s: f64, est: &Estimator) {
    let poses: Vec<_> = est.keyframes().map(|k| pose_json(&k.p_B_in_W, &k.q_W_B())).collect();
    l.log(
        Topic::Keyframes,
        t_s,
        &json!({"timestamp": Stamp::at(t_s), "frame_id": "ned", "poses": poses}),
    );
}

/// The landmarks of the fused tracks, gathered between logs.
#[derive(Debug, Default)]
pub(super) struct LandmarkCloud {
    /// `x, y, z` (m, NED) as little-endian `f32`, 12 bytes a point.
    bytes: Vec<u8>,
    next_log_s: f64,
}

impl LandmarkCloud {
    /// The most points one `/landmarks` record carries (36 KB); more in
    /// one fifth of a second are left out.
    pub const MAX_POINTS: usize = 3000;

    /// Adds a frame's landmarks and, at most every 0.2 s, logs those
    /// gathered as a `foxglove.PointCloud` in `ned`.
    pub fn push(&mut self, l: &McapLogger, t_s: f64, points_W: &[Vector3<f64>]) {
        for p in points_W {
            if self.bytes.len() >= 12 * Self::MAX_POINTS {
                break;
            }
            if p.iter().all(|v| v.is_finite()) {
                for v in p.iter() {
                    self.bytes.extend_from_slice(&(*v as f32).to_le_bytes());
                }
            }
        }
        if t_s < self.next_log_s || self.bytes.is_empty() {
            return;
        }
        self.next_log_s = t_s + 0.2;
        // NumericType FLOAT32 = 7.
        let fields: Vec<_> = ["x", "y", "z"]
            .iter()
            .enumerate()
            .map(|(k, n)| json!({"name": n, "offset": 4 * k, "type": 7}))
            .collect();
        l.log(
            Topic::Landmarks,
            t_s,
            &json!({"timestamp": Stamp::at(t_s), "frame_id": "ned",
                "pose": pose_json(&Vector3::zeros(), &nalgebra::UnitQuaternion::identity()),
                "point_stride": 12, "fields": fields, "data": crate::io::base64::encode(&self.bytes)}),
        );
        self.bytes.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{UnitQuaternion, Vector3};

    /// The `map → ned` quaternion is the matrix `S`, so a point 1 m north
    /// and 1 m down in `ned` is 1 m north (y) and 1 m below (z) in `map`.
    #[test]
    fn map_to_ned_is_the_enu_swap() {
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(0.0, h, h, 0.0));
        let r = q.to_rotation_matrix().into_inner();
        assert!((r - ned_to_enu()).norm() < 1e-15, "{r}");
        let p_map = r * Vector3::new(1.0, 0.0, 1.0);
        assert!((p_map - Vector3::new(0.0, 1.0, -1.0)).norm() < 1e-15);
    }
}
