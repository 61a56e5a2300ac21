//! The outputs: `VISION_POSITION_ESTIMATE` (and `ODOMETRY` if asked) paced
//! by autopilot time, their 21-float covariance, and the pose, transform,
//! state and VPE records of the log.
//!
//! An estimate is sent whenever the IMU time crosses the next
//! `1/output.rate_hz` tick, predicted to that sample from the filter as it
//! stands (before the sample's measurements), so no update, and no global
//! update, ever delays it.

use nalgebra::{Matrix3, Matrix6, UnitQuaternion, Vector3};
use serde_json::json;
use tokio::sync::mpsc;

use super::fusion::Fusion;
use super::records;
use crate::estimator::{Estimator, ImuMeas, ImuState};
use crate::io::mcap_log::{McapLogger, Topic};
use crate::io::messages::Outbound;
use crate::io::Counters;

impl Fusion {
    /// Sends the estimate at the configured rate of autopilot time, predicted
    /// to the latest IMU sample from the filter as it stands (before this
    /// sample's measurements: no update, and no global update, ever delays it).
    pub(super) fn emit_output(&mut self, m: ImuMeas, counters: &Counters, out: &mpsc::Sender<Outbound>) {
        let Some(est) = self.est.as_ref() else { return };
        if m.t_s < self.next_output_t {
            return;
        }
        let period = 1.0 / self.cfg.output.rate_hz;
        self.next_output_t = if self.next_output_t.is_finite() && m.t_s - self.next_output_t < period {
            self.next_output_t + period
        } else {
            m.t_s + period
        };
        let x = est.predict(m.t_s);
        let cov = est.pose_covariance();
        if let Some(l) = &self.log {
            log_pose(l, m.t_s, &x);
            if m.t_s >= self.next_state_log {
                self.next_state_log = m.t_s + 0.1;
                log_state(l, m.t_s, &x, est);
            }
        }
        for o in outputs(&x, &cov, m.t_s, self.reset_counter, self.cfg.output.odometry) {
            if let (Some(l), Outbound::VisionPositionEstimate { .. }) = (&self.log, &o) {
                log_vpe(l, m.t_s, &o);
            }
            if out.try_send(o).is_err() {
                counters.add("output_queue_full", 1);
            }
        }
    }
}

/// `/pose` (foxglove.PoseInFrame) and `/tf` (foxglove.FrameTransform).
fn log_pose(l: &McapLogger, t_s: f64, x: &ImuState) {
    let q = x.q_W_B.coords;
    let (sec, nsec) = (t_s.floor() as u64, ((t_s - t_s.floor()) * 1e9) as u64);
    let timestamp = records::Stamp { sec, nsec };
    let position = records::Xyz {
        x: x.p_B_in_W.x,
        y: x.p_B_in_W.y,
        z: x.p_B_in_W.z,
    };
    let orientation = records::Quat {
        x: q.x,
        y: q.y,
        z: q.z,
        w: q.w,
    };
    l.log(
        Topic::Pose,
        t_s,
        &records::Pose {
            timestamp,
            frame_id: "ned",
            pose: records::PoseBody { position, orientation },
        },
    );
    l.log(
        Topic::Transform,
        t_s,
        &records::Transform {
            timestamp,
            parent_frame_id: "ned",
            child_frame_id: "body_frd",
            translation: position,
            rotation: orientation,
        },
    );
}

/// `/filter/state` (10 Hz): the predicted state, the clock and the IMU
/// block's variances.
fn log_state(l: &McapLogger, t_s: f64, x: &ImuState, est: &Estimator) {
    let q = x.q_W_B.coords;
    let (clock, _) = est.clock();
    l.log(
        Topic::FilterState,
        t_s,
        &json!({"t_s": t_s, "q_W_B_wxyz": [q.w, q.x, q.y, q.z], "v_B_in_W": x.v_B_in_W.as_slice(),
            "p_B_in_W": x.p_B_in_W.as_slice(), "b_g": x.b_g.as_slice(), "b_a": x.b_a.as_slice(),
            "clock": clock.as_slice(), "cov_diag": est.imu_covariance().diagonal().as_slice()}),
    );
}

/// `/output/vision_position_estimate`: the estimate as sent.
fn log_vpe(l: &McapLogger, t_s: f64, o: &Outbound) {
    let Outbound::VisionPositionEstimate {
        t_us,
        p_ned_m,
        rpy_rad,
        covariance,
        reset_counter,
    } = o
    else {
        return;
    };
    l.log(
        Topic::OutputVpe,
        t_s,
        &records::Vpe {
            usec: *t_us,
            p_ned_m: p_ned_m.as_slice(),
            rpy_rad: rpy_rad.as_slice(),
            covariance: covariance.as_slice(),
            reset_counter: *reset_counter,
        },
    );
}

/// Euler (ZYX) angles of `q` and the map `M` from `[droll, dpitch, dyaw]` to
/// the world-frame rotation error: `δθ = dyaw ẑ + dpitch Rz ŷ + droll Rz Ry x̂`.
fn euler_and_map(q: &UnitQuaternion<f64>) -> (Vector3<f64>, Matrix3<f64>) {
    let (r, p, y) = q.euler_angles();
    let rz = UnitQuaternion::from_euler_angles(0.0, 0.0, y);
    let rzy = UnitQuaternion::from_euler_angles(0.0, p, y);
    let m = Matrix3::from_columns(&[rzy * Vector3::x(), rz * Vector3::y(), Vector3::z()]);
    (Vector3::new(r, p, y), m)
}

/// Upper triangle, row-major, of a 6×6 matrix (MAVLink's 21-float layout).
pub fn upper21(c: &Matrix6<f64>) -> [f32; 21] {
    let mut out = [0.0f32; 21];
    let mut k = 0;
    for i in 0..6 {
        for j in i..6 {
            out[k] = c[(i, j)] as f32;
            k += 1;
        }
    }
    out
}

/// The messages for one output instant: `VISION_POSITION_ESTIMATE` (and
/// `ODOMETRY` if asked). `cov` is the pose covariance `[δθ, δp]`.
pub fn outputs(x: &ImuState, cov: &Matrix6<f64>, t_s: f64, reset_counter: u8, odometry: bool) -> Vec<Outbound> {
    let (rpy, m) = euler_and_map(&x.q_W_B);
    let minv = m.try_inverse().unwrap_or_else(Matrix3::identity);
    // Covariance of [x y z roll pitch yaw] from that of [δθ, δp].
    let mut t = Matrix6::zeros();
    t.fixed_view_mut::<3, 3>(0, 3).copy_from(&Matrix3::identity());
    t.fixed_view_mut::<3, 3>(3, 0).copy_from(&minv);
    let c = t * cov * t.transpose();
    let t_us = (t_s * 1e6).round() as u64;
    let mut v = vec![Outbound::VisionPositionEstimate {
        t_us,
        p_ned_m: x.p_B_in_W,
        rpy_rad: rpy,
        covariance: upper21(&c),
        reset_counter,
    }];
    if odometry {
        // ODOMETRY wants its pose covariance in the same [x y z r p y] order.
        let q = x.q_W_B.coords;
        v.push(Outbound::Odometry {
            t_us,
            p_ned_m: x.p_B_in_W,
            q_wxyz: [q.w as f32, q.x as f32, q.y as f32, q.z as f32],
            v_body_mps: x.q_W_B.inverse_transform_vector(&x.v_B_in_W),
            w_body_radps: Vector3::zeros(),
            pose_covariance: upper21(&c),
            velocity_covariance: [f32::NAN; 21],
            reset_counter,
        });
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The Euler-angle map against finite differences.
    #[test]
    fn euler_map_matches_finite_differences() {
        let q = UnitQuaternion::from_euler_angles(0.2, -0.3, 1.2);
        let (rpy, m) = euler_and_map(&q);
        let h = 1e-6;
        for k in 0..3 {
            let mut d = rpy;
            d[k] += h;
            let qp = UnitQuaternion::from_euler_angles(d.x, d.y, d.z);
            let dth = (qp * q.inverse()).scaled_axis() / h;
            assert!((dth - m.column(k)).norm() < 1e-5, "{k}: {dth} vs {}", m.column(k));
        }
        let o = outputs(
            &ImuState {
                q_W_B: q,
                v_B_in_W: Vector3::zeros(),
                p_B_in_W: Vector3::new(1.0, 2.0, 3.0),
                b_g: Vector3::zeros(),
                b_a: Vector3::zeros(),
            },
            &(Matrix6::identity() * 0.01),
            1.5,
            2,
            false,
        );
        let Outbound::VisionPositionEstimate {
            t_us,
            covariance,
            reset_counter,
            ..
        } = &o[0]
        else {
            panic!()
        };
        assert_eq!(*t_us, 1_500_000);
        assert_eq!(*reset_counter, 2);
        // Position variances come first.
        assert!((covariance[0] - 0.01).abs() < 1e-9 && covariance.iter().all(|v| v.is_finite()));
    }
}
