//! The outputs, paced by autopilot time: the estimate sent at
//! `output.rate_hz` (its messages are `estimate_message.rs`), the
//! `reset_counter` that tells the autopilot of a restart, and the pose,
//! transform, state and estimate records of the log.
//!
//! An estimate is sent whenever the IMU time crosses the next
//! `1/output.rate_hz` tick, predicted to that sample from the filter as it
//! stands (before the sample's measurements), so no update, and no global
//! update, ever delays it.

use cmsckf_models::geodesy::NedFrame;
use nalgebra::Isometry3;
use serde_json::json;
use tokio::sync::mpsc;

use super::estimate_message::{gyro_white_variance, outputs, pose_rpy_covariance, quality, t_us, upper21, OutputState};
use super::records;
use crate::config::{Config, PoseCovariance, PositionCovariance, YawSource};
use crate::counters::{Counter, Counters};
use crate::estimator::imu_covariance::pose_block;
use crate::estimator::{Estimator, ImuMeas, ImuState};
use crate::io::mcap_log::{McapLogger, Topic};
use crate::io::messages::{AutopilotKind, Outbound};
use crate::status::Tracker;

/// The output's pacing and the restarts it tells of.
#[derive(Debug)]
pub(super) struct OutputPacer {
    /// The next output instant (autopilot time, s).
    next_output_t: f64,
    /// The next `/filter/state`, `/tf` and `/location` records (10 Hz).
    next_state_t: f64,
    /// Moved on at every filter reset: the autopilot resets its own fusion
    /// of our estimates.
    reset_counter: u8,
    /// The camera's pose in the body frame, for the log's frame tree.
    T_B_C: Isometry3<f64>,
}

/// What an estimate is made of besides the filter: the config, the
/// autopilot's kind (its frame and covariance encoding), the status (the
/// quality), the world frame (the log's `/location`) and the log.
pub(super) struct OutputCtx<'a> {
    pub(super) cfg: &'a Config,
    pub(super) autopilot: Option<AutopilotKind>,
    /// The autopilot's heading is ours alone, by its parameters
    /// (`daemon/nav_params.rs`; `None`: not known).
    pub(super) heading_ours_alone: Option<bool>,
    pub(super) tracker: &'a Tracker,
    pub(super) frame: Option<NedFrame>,
    pub(super) log: Option<&'a McapLogger>,
}

impl OutputPacer {
    pub(super) fn new(cfg: &Config) -> Self {
        Self {
            next_output_t: f64::NEG_INFINITY,
            next_state_t: f64::NEG_INFINITY,
            reset_counter: 0,
            T_B_C: cmsckf_models::camera::Camera::from_config(&cfg.camera).T_B_C,
        }
    }

    pub(super) fn reset_counter(&self) -> u8 {
        self.reset_counter
    }

    /// A filter reset: the next estimate carries a new `reset_counter`.
    pub(super) fn on_reset(&mut self) {
        self.reset_counter = self.reset_counter.wrapping_add(1);
    }

    /// The autopilot's clock restarted: the pacing starts again.
    pub(super) fn restart_clock(&mut self) {
        self.next_output_t = f64::NEG_INFINITY;
        self.next_state_t = f64::NEG_INFINITY;
    }

    /// Sends the estimate at the configured rate of autopilot time, predicted
    /// to the latest IMU sample `m` from the filter as it stands (before this
    /// sample's measurements: no update, and no global update, ever delays it).
    pub(super) fn emit(
        &mut self,
        m: ImuMeas,
        est: &Estimator,
        cx: OutputCtx<'_>,
        counters: &Counters,
        out: &mpsc::Sender<Outbound>,
    ) {
        if m.t_s < self.next_output_t {
            return;
        }
        let cfg = cx.cfg;
        let period = 1.0 / cfg.output.rate_hz;
        self.next_output_t = if self.next_output_t.is_finite() && m.t_s - self.next_output_t < period {
            self.next_output_t + period
        } else {
            m.t_s + period
        };
        let x = est.predict(m.t_s);
        let imu_cov = est.imu_covariance();
        if let Some(l) = cx.log {
            log_pose(l, m.t_s, &x);
            if m.t_s >= self.next_state_t {
                self.next_state_t = m.t_s + 0.1;
                log_state(l, m.t_s, &x, est);
                super::frames::log_static_frames(l, m.t_s, &self.T_B_C);
                if let Some(frame) = &cx.frame {
                    super::frames::log_location(l, m.t_s, &x, &imu_cov, frame);
                }
            }
        }
        let ardupilot = cx.autopilot == Some(AutopilotKind::ArduPilot);
        let snap = OutputState {
            pose_covariance: match cfg.output.covariance {
                PoseCovariance::Auto if ardupilot => PoseCovariance::ArdupilotCbrt,
                PoseCovariance::Auto => PoseCovariance::Variances,
                other => other,
            },
            // North-referenced unless the first yaw was a configured one.
            frame_ned: cx.autopilot == Some(AutopilotKind::Px4) && cfg.init.yaw_source != YawSource::Config,
            position_given_yaw: match cfg.output.position_covariance {
                PositionCovariance::Absolute => false,
                PositionCovariance::GivenYaw => true,
                // Measured beside PX4 only (docs/setup-px4.md); ArduPilot's
                // EKF3 reduces the covariance to one number (eq. O1).
                PositionCovariance::Auto => {
                    cx.autopilot == Some(AutopilotKind::Px4) && cx.heading_ours_alone == Some(true)
                }
            },
            t_s: m.t_s,
            x,
            imu_cov,
            gyro_radps: m.gyro_radps,
            gyro_var: gyro_white_variance(cfg.imu.gyro_noise_density, cfg.mavlink.imu_rate_hz),
            reset_counter: self.reset_counter,
            quality: quality(&x, &imu_cov, m.t_s - cx.tracker.last_aided_s(), cx.tracker.bits() != 0),
        };
        if let Some(l) = cx.log {
            log_estimate(l, &snap, cfg.output.message);
        }
        for o in outputs(&snap, cfg.output.message) {
            if out.try_send(o).is_err() {
                counters.add(Counter::OutputQueueFull, 1);
            }
        }
    }
}

/// `/pose` (foxglove.PoseInFrame) and `/tf` (foxglove.FrameTransform).
fn log_pose(l: &McapLogger, t_s: f64, x: &ImuState) {
    let q = x.q_W_B.coords;
    let timestamp = super::records::Stamp::at(t_s);
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
            child_frame_id: "base_link",
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
    let cov = est.imu_covariance();
    // The pose block is [δθ, δp]: its last three variances are the position's.
    let pose = pose_block(&cov);
    let sigma_p_m = [3, 4, 5].map(|k| pose[(k, k)].max(0.0).sqrt());
    l.log(
        Topic::FilterState,
        t_s,
        &json!({"t_s": t_s, "q_W_B_wxyz": [q.w, q.x, q.y, q.z], "v_B_in_W": x.v_B_in_W.as_slice(),
            "p_B_in_W": x.p_B_in_W.as_slice(), "b_g": x.b_g.as_slice(), "b_a": x.b_a.as_slice(),
            "clock": clock.as_slice(), "cov_diag": cov.diagonal().as_slice(),
            "sigma_p_m": sigma_p_m}),
    );
}

/// `/output/vision_position_estimate`: the pose of each estimate sent,
/// whichever message carried it (`ODOMETRY` carries the same position,
/// attitude, pose covariance and `reset_counter`), one record per output
/// instant.
fn log_estimate(l: &McapLogger, s: &OutputState, message: crate::config::OutputMessage) {
    let (rpy, covariance) = pose_rpy_covariance(&s.x, &s.imu_cov);
    let (_, sent) = super::estimate_message::sent_pose(s);
    let sent = super::estimate_message::pose_covariance21(&sent, s.pose_covariance);
    l.log(
        Topic::OutputVpe,
        s.t_s,
        &records::Vpe {
            usec: t_us(s.t_s),
            p_ned_m: s.x.p_B_in_W.as_slice(),
            rpy_rad: rpy.as_slice(),
            covariance: upper21(&covariance).as_slice(),
            reset_counter: s.reset_counter,
            message,
            pose_covariance_sent: sent.as_slice(),
            quality: s.quality,
            v_ned_mps: s.x.v_B_in_W.as_slice(),
        },
    );
}
