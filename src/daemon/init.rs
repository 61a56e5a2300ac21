//! Starting the filter: static (roll, pitch and gyro bias from the IMU, yaw
//! from the autopilot) when the vehicle is still, otherwise from the
//! autopilot's attitude and local velocity (an in-flight start).

use nalgebra::{UnitQuaternion, Vector3};

use super::fusion::Fusion;
use super::rebase::RebaseExec;
use crate::estimator::{attitude_from_static, Estimator, ImuMeas, ImuState, Mat15};
use crate::io::Counters;

/// Mean specific force and angular rate of the buffered samples, and the
/// angular rate's variance.
struct StillWindow {
    acc: Vector3<f64>,
    gyr: Vector3<f64>,
    gyr_var: f64,
}

impl StillWindow {
    fn of<'a>(samples: impl ExactSizeIterator<Item = &'a ImuMeas> + Clone) -> Self {
        let n = samples.len() as f64;
        let acc = samples.clone().map(|s| s.accel_mps2).sum::<Vector3<f64>>() / n;
        let gyr = samples.clone().map(|s| s.gyro_radps).sum::<Vector3<f64>>() / n;
        let gyr_var = samples.map(|s| (s.gyro_radps - gyr).norm_squared()).sum::<f64>() / n;
        Self { acc, gyr, gyr_var }
    }
}

impl Fusion {
    /// Starts the filter once the static window is full and the autopilot's
    /// attitude is known: static when the IMU (and the autopilot's velocity,
    /// when it has one: constant velocity looks static to an IMU) says so,
    /// else in flight from the autopilot's state.
    pub(super) fn try_init(&mut self, m: ImuMeas, counters: &Counters) {
        self.static_buf.push_back(m);
        let window = self.cfg.init.static_window_s;
        while self.static_buf.front().is_some_and(|f| m.t_s - f.t_s > window) {
            self.static_buf.pop_front();
        }
        let Some((roll, pitch, yaw)) = self.attitude else {
            return;
        };
        if self.static_buf.len() < 10 || m.t_s - self.static_buf[0].t_s < 0.9 * window {
            return;
        }
        let w = StillWindow::of(self.static_buf.iter());
        let is_static = w.gyr.norm() < 0.05
            && w.gyr_var < 1e-3
            && (w.acc.norm() - self.cfg.imu.gravity_mps2).abs() < 0.3
            && self.local.is_none_or(|(_, v, _)| v.norm() < 0.3);
        let Some((x0, p0)) = self.initial_state(m.t_s, is_static, &w, [roll, pitch, yaw]) else {
            return;
        };
        self.start_filter(m, x0, &p0, is_static, counters);
    }

    /// The first state and its covariance, or `None` while what it needs is
    /// missing (a static attitude from the IMU; in flight, the autopilot's
    /// local position).
    fn initial_state(
        &self,
        t_s: f64,
        is_static: bool,
        w: &StillWindow,
        [roll, pitch, yaw]: [f64; 3],
    ) -> Option<(ImuState, Mat15)> {
        // The autopilot's position, carried to this sample's time (its
        // LOCAL_POSITION_NED comes at 10 Hz: 1.5 m old at 15 m/s otherwise).
        let (p, v) = match self.local {
            Some((p, v, t)) if (t_s - t).abs() < 1.0 => (p + v * (t_s - t), v),
            Some((p, v, _)) => (p, v),
            None => (Vector3::zeros(), Vector3::zeros()),
        };
        // Priors from their sources (§7, eq. I1): the yaw is the
        // autopilot's (its compass), the position the autopilot's local
        // position with its reported accuracy, or, without one, the world
        // frame's own origin.
        let mut p0 = self.cfg.initial_covariance();
        let yaw_var = self.cfg.init.sigma_yaw_autopilot_deg.to_radians().powi(2);
        p0[(2, 2)] = yaw_var;
        if self.local.is_some() {
            let (h, v) = self.gps_accuracy.unwrap_or((
                self.cfg.init.sigma_position_autopilot_m,
                self.cfg.init.sigma_position_autopilot_m,
            ));
            for (k, s) in [h, h, v].iter().enumerate() {
                p0[(6 + k, 6 + k)] = s * s;
            }
        }
        let (q, b_g, v) = if is_static {
            (attitude_from_static(&w.acc, yaw)?, w.gyr, Vector3::zeros())
        } else {
            self.local?;
            // In flight: the autopilot's attitude, looser.
            for k in 0..3 {
                p0[(k, k)] *= 4.0;
                p0[(3 + k, 3 + k)] = 0.2f64.powi(2);
            }
            (UnitQuaternion::from_euler_angles(roll, pitch, yaw), Vector3::zeros(), v)
        };
        let x0 = ImuState {
            q_W_B: q,
            v_B_in_W: v,
            p_B_in_W: p,
            b_g,
            b_a: Vector3::zeros(),
        };
        Some((x0, p0))
    }

    /// A new estimator from `x0` and `p0` at the sample `m`.
    fn start_filter(&mut self, m: ImuMeas, x0: ImuState, p0: &Mat15, is_static: bool, counters: &Counters) {
        let mut est = Estimator::new(self.cfg.estimator_settings(), m.t_s, x0, p0);
        est.set_async_rebase(!matches!(self.rebase, RebaseExec::Inline));
        self.est_gen += 1;
        let _ = est.add_imu(m);
        self.est = Some(est);
        self.tracker.filter_started(m.t_s);
        self.static_buf.clear();
        self.pending.retain(|(t, _)| *t >= m.t_s);
        counters.add(if is_static { "init_static" } else { "init_in_flight" }, 1);
        self.log_text(
            2,
            m.t_s,
            if is_static {
                "filter initialised (static start)"
            } else {
                "filter initialised in flight"
            },
        );
        tracing::info!(static_start = is_static, t_s = m.t_s, "filter initialised");
    }
}
