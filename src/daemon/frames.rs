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

use nalgebra::{Isometry3, Matrix3};
use serde_json::json;

use cmsckf_models::geodesy::{ecef_to_llh, NedFrame};

use super::records::{Quat, Stamp, Transform, Xyz};
use crate::estimator::propagate::P as P_OFF;
use crate::estimator::{ImuState, Mat15};
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
    let p_enu = s * cov.fixed_view::<3, 3>(P_OFF, P_OFF) * s.transpose();
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
