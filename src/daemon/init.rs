//! Starting the filter.
//!
//! - The first start is static (roll, pitch and gyro bias from the IMU)
//!   when the vehicle is still, otherwise from the autopilot's attitude and
//!   local velocity (an in-flight start). Its yaw comes from a real source
//!   (`init.yaw_source`): the compass (the autopilot's magnetometer and the
//!   WMM declination, eq. M1 of `cmsckf_models::magnetic`) when there is
//!   one, never ArduPilot's placeholder 0 under external-navigation yaw.
//! - A restart never starts from the autopilot: once our estimates reach
//!   it, its attitude and position may be only their echo (with external
//!   navigation as its only source, they are). It starts from our own last
//!   estimate, [`Carried`], at once (no static window, so no gap in the
//!   outputs), with its covariance inflated for the failure and the time
//!   out; or, when the autopilot has a GNSS fix of its own, from its state.
//!   After an autopilot reboot, whose EKF starts afresh, or when a carried
//!   start fails again, the filter starts as at the first start.

use std::collections::VecDeque;

use cmsckf_models::geodesy::ecef_to_llh;
use cmsckf_models::magnetic;
use nalgebra::{UnitQuaternion, Vector3};
use tokio::sync::mpsc;

use super::autopilot::OriginSend;
use super::fusion::Fusion;
use super::rebase::RebaseExec;
use super::Restart;
use crate::config::YawSource;
use crate::counters::{Counter, Counters};
use crate::estimator::propagate::{BA, BG, P as P_OFF, TH, V};
use crate::estimator::{attitude_from_static, Estimator, ImuMeas, ImuState, Mat15};
use crate::io::messages::Outbound;
use crate::status::Degraded;

/// Our last estimate is carried into a restart for at most this long (s of
/// IMU time): beyond it (a long IMU gap) the motion in between is unknown.
const CARRY_MAX_S: f64 = 5.0;
/// IMU samples kept for a restart to propagate the carried estimate through
/// (s): more than the carried estimate's age at a divergence (1–2 s).
pub(super) const RECENT_IMU_S: f64 = 2.5;
/// A step between IMU samples up to this (s) is covered by them; beyond it,
/// the gap is inflated for.
const RECENT_IMU_MAX_STEP_S: f64 = 0.1;

/// Snapshots of our estimate while the filter is healthy, taken every
/// [`GOOD_PERIOD_S`]: a restart starts from the older one, 1–2 s before the
/// failure, since a filter going wrong passes its checks for a while.
#[derive(Debug, Default)]
pub(crate) struct GoodEstimates {
    recent: Option<Carried>,
    older: Option<Carried>,
}

/// How often a healthy estimate is kept (s of IMU time).
const GOOD_PERIOD_S: f64 = 1.0;

impl GoodEstimates {
    /// Keeps the estimate of `est` at `t_s` if the last one is a period old.
    pub(super) fn offer(&mut self, est: &Estimator, t_s: f64) {
        if self
            .recent
            .as_ref()
            .is_some_and(|r| t_s - r.t_s < GOOD_PERIOD_S && t_s >= r.t_s)
        {
            return;
        }
        self.older = self.recent.take();
        self.recent = Some(Carried::of(est, t_s));
    }

    /// The estimate to restart from (the older if there is one), leaving
    /// none for the next filter, which keeps its own.
    pub(super) fn take_best(&mut self) -> Option<Carried> {
        // `or`'s argument is taken either way: both are left empty.
        self.older.take().or(self.recent.take())
    }
}

/// The autopilot's GNSS fix counts as its own position source for this long
/// after its last `GPS_RAW_INT` with a 3D fix (s).
const AUTOPILOT_FIX_FRESH_S: f64 = 5.0;

/// A restart from our own estimate that fails again within this (s) is not
/// repeated: that estimate was wrong already (a runaway while blind).
const IN_PLACE_RETRY_S: f64 = 10.0;

/// An estimate carried over a restart: the next filter's start.
#[derive(Clone, Debug)]
pub(crate) struct Carried {
    pub(super) t_s: f64,
    pub(super) x: ImuState,
    pub(super) P: Mat15,
}

impl Carried {
    /// The estimate of `est`, predicted to `t_s` (the IMU sample that
    /// restarted it), with its IMU covariance.
    pub(super) fn of(est: &Estimator, t_s: f64) -> Self {
        let t_s = t_s.max(est.time_s());
        Self {
            t_s,
            x: est.predict(t_s),
            P: est.imu_covariance(),
        }
    }

    /// The carried covariance inflated (eq. I3 of `src/estimator/README.md`):
    /// the position by σ_r² + (σ_v·Δt)² and the velocity by σ_v², for the
    /// restart sigmas σ_r, σ_v and the time Δt that no IMU sample covers;
    /// the tilt by the initial tilt sigma; the biases raised to at least
    /// their priors.
    fn inflated(&self, dt: f64, prior: &Mat15, sigma_r_m: f64, sigma_v_mps: f64) -> Mat15 {
        let mut p = self.P;
        for k in 0..3 {
            p[(P_OFF + k, P_OFF + k)] += sigma_r_m.powi(2) + (sigma_v_mps * dt).powi(2);
            p[(V + k, V + k)] += sigma_v_mps.powi(2);
            p[(TH + k, TH + k)] += prior[(TH, TH)];
            for o in [BG, BA] {
                p[(o + k, o + k)] = p[(o + k, o + k)].max(prior[(o + k, o + k)]);
            }
        }
        p
    }
}

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
    /// The autopilot's own state, when it has a position of its own (a GNSS
    /// fix) and its attitude and local position are fresh: a restart's
    /// start with the in-flight priors of eq. I1, keeping our bias
    /// estimates from `good` (the autopilot reports none). `None` without
    /// them (after an IMU gap or a reboot they are dropped as stale).
    pub(super) fn autopilot_start(&self, t_s: f64, good: Option<&Carried>) -> Option<Carried> {
        let (roll, pitch, yaw) = self.attitude?;
        let (_, _, t) = self.local?;
        // Fresh (and finite) only.
        if (t_s - t).abs().partial_cmp(&1.0) != Some(std::cmp::Ordering::Less) {
            return None;
        }
        let (mut x, mut P) = self.initial_state(t_s, None, [roll, pitch, yaw])?;
        P[(TH + 2, TH + 2)] = self.cfg.init.sigma_yaw_autopilot_deg.to_radians().powi(2);
        if let Some(g) = good {
            (x.b_g, x.b_a) = (g.x.b_g, g.x.b_a);
        }
        Some(Carried { t_s, x, P })
    }

    /// Restarts the filter at once from the estimate carried over the
    /// restart (ours, or the autopilot's own), if one is carried and recent
    /// ([`CARRY_MAX_S`]); `false` if not.
    pub(super) fn restart_in_place(&mut self, m: ImuMeas, counters: &Counters) -> bool {
        let Some(c) = self.carried.as_ref() else {
            return false;
        };
        if !(m.t_s - c.t_s).is_finite() || m.t_s - c.t_s > CARRY_MAX_S || m.t_s < c.t_s {
            // Too old to carry (the motion since is unknown): a fresh start.
            self.carried = None;
            return false;
        }
        // The new filter starts at the carried estimate's own time and is
        // propagated through the IMU samples since (kept in `recent_imu`,
        // this one among them); the time that no sample covers (an IMU gap)
        // is inflated for (eq. I3).
        let t0 = c.t_s;
        let mut uncovered_s = 0.0;
        let mut prev = t0;
        for s in self.recent_imu.iter().filter(|s| s.t_s > t0) {
            if s.t_s - prev > RECENT_IMU_MAX_STEP_S {
                uncovered_s += s.t_s - prev;
            }
            prev = s.t_s;
        }
        let i = &self.cfg.init;
        let prior = self.cfg.initial_covariance();
        let p0 = c.inflated(
            uncovered_s,
            &prior,
            i.restart_sigma_position_m,
            i.restart_sigma_velocity_mps,
        );
        let mut est = Estimator::new(self.cfg.estimator_settings(), t0, c.x, &p0);
        for s in self.recent_imu.iter().filter(|s| s.t_s > t0) {
            let _ = est.add_imu(*s);
        }
        est.start_health_grace(m.t_s);
        counters.add(Counter::InitFromCarriedEstimate, 1);
        self.in_place_t = Some(m.t_s);
        self.install_filter(est, m.t_s, false, counters);
        true
    }

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
        let Some((roll, pitch, _)) = self.attitude else {
            return;
        };
        if self.static_buf.len() < 10 || m.t_s - self.static_buf[0].t_s < 0.9 * window {
            return;
        }
        let w = StillWindow::of(self.static_buf.iter());
        let tilt =
            attitude_from_static(&w.acc, 0.0).unwrap_or_else(|| UnitQuaternion::from_euler_angles(roll, pitch, 0.0));
        let Some((yaw, yaw_sigma_deg)) = self.first_yaw(&tilt) else {
            return;
        };
        let is_static = w.gyr.norm() < 0.05
            && w.gyr_var < 1e-3
            && (w.acc.norm() - self.cfg.imu.gravity_mps2).abs() < 0.3
            && self.local.is_none_or(|(_, v, _)| v.norm() < 0.3);
        let Some((x0, mut p0)) = self.initial_state(m.t_s, is_static.then_some(&w), [roll, pitch, yaw]) else {
            return;
        };
        p0[(TH + 2, TH + 2)] = yaw_sigma_deg.to_radians().powi(2);
        self.start_filter(m, x0, &p0, is_static, counters);
    }

    /// The first state and its covariance, static from the `still` window
    /// or else in flight from the autopilot's state, or `None` while what
    /// it needs is missing (a static attitude from the IMU; in flight, the
    /// autopilot's local position).
    fn initial_state(
        &self,
        t_s: f64,
        still: Option<&StillWindow>,
        [roll, pitch, yaw]: [f64; 3],
    ) -> Option<(ImuState, Mat15)> {
        // The autopilot's position, carried to this sample's time (its
        // LOCAL_POSITION_NED comes at 10 Hz: 1.5 m old at 15 m/s otherwise).
        let (p, v) = match self.local {
            Some((p, v, t)) if (t_s - t).abs() < 1.0 => (p + v * (t_s - t), v),
            Some((p, v, _)) => (p, v),
            None => (Vector3::zeros(), Vector3::zeros()),
        };
        // Priors from their sources (§7, eq. I1): the yaw's is set by the
        // caller (compass, autopilot or configured), the position the
        // autopilot's local position with its reported accuracy, or,
        // without one, the world frame's own origin.
        let mut p0 = self.cfg.initial_covariance();
        if self.local.is_some() {
            let (h, v) = self.gps_accuracy.unwrap_or((
                self.cfg.init.sigma_position_autopilot_m,
                self.cfg.init.sigma_position_autopilot_m,
            ));
            for (k, s) in [h, h, v].iter().enumerate() {
                p0[(6 + k, 6 + k)] = s * s;
            }
        }
        let (q, b_g, v) = if let Some(w) = still {
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

    /// The first yaw (rad) and its sigma (deg), from `init.yaw_source`, for
    /// a body whose rotation without yaw is `tilt`; `None` while the source
    /// has nothing to give.
    fn first_yaw(&self, tilt: &UnitQuaternion<f64>) -> Option<(f64, f64)> {
        let i = &self.cfg.init;
        let autopilot = self.attitude.map(|(_, _, yaw)| (yaw, i.sigma_yaw_autopilot_deg));
        match i.yaw_source {
            YawSource::Config => Some((i.yaw_deg.to_radians(), i.sigma_yaw_deg)),
            YawSource::Autopilot => autopilot,
            YawSource::Compass => self.compass_yaw(tilt),
            YawSource::Auto => self.compass_yaw(tilt).or(autopilot),
        }
    }

    /// The compass's true heading (rad) and its sigma (deg): the mean of
    /// the latest magnetometer readings (eq. M1) with the WMM declination
    /// at our origin, today.
    fn compass_yaw(&self, tilt: &UnitQuaternion<f64>) -> Option<(f64, f64)> {
        let frame = self.gnss.frame?;
        let mag_B = mean_direction(&self.mag_B)?;
        let (lat, lon, h) = ecef_to_llh(&frame.origin_ecef);
        let (dec_deg, dec_sigma_deg) =
            magnetic::declination_deg(lat.to_degrees(), lon.to_degrees(), h, self.unix_days?)?;
        let yaw = magnetic::heading_rad(tilt, &mag_B, dec_deg.to_radians())?;
        Some((yaw, self.cfg.init.sigma_yaw_compass_deg.hypot(dec_sigma_deg)))
    }

    /// A new estimator from `x0` and `p0` at the sample `m`.
    fn start_filter(&mut self, m: ImuMeas, x0: ImuState, p0: &Mat15, is_static: bool, counters: &Counters) {
        let mut est = Estimator::new(self.cfg.estimator_settings(), m.t_s, x0, p0);
        let _ = est.add_imu(m);
        let (_, _, yaw) = x0.q_W_B.euler_angles();
        tracing::info!(yaw_deg = yaw.to_degrees(), "initial yaw");
        self.install_filter(est, m.t_s, is_static, counters);
    }

    /// `est` becomes the running filter at the IMU sample time `t_s`.
    fn install_filter(&mut self, mut est: Estimator, t_s: f64, is_static: bool, counters: &Counters) {
        est.set_async_rebase(!matches!(self.rebase, RebaseExec::Inline));
        self.est_gen += 1;
        self.est = Some(est);
        self.tracker.filter_started(t_s);
        self.static_buf.clear();
        self.pending.retain(|(t, _)| *t >= t_s);
        counters.add(
            if is_static {
                Counter::InitStatic
            } else {
                Counter::InitInFlight
            },
            1,
        );
        self.log_text(
            2,
            t_s,
            if is_static {
                "filter initialised (static start)"
            } else {
                "filter initialised in flight"
            },
        );
        tracing::info!(static_start = is_static, t_s, "filter initialised");
    }

    /// Drops the filter so that the next IMU sample starts a fresh one (the
    /// one reset path): `reset_counter` moves on, the autopilot gets a
    /// `STATUSTEXT`, the log a `/log` line, and the status shows
    /// `filter_reset` for 2 s. The next filter starts at once from the
    /// estimate carried over (see below and `init.rs`); without one, as at
    /// the first start. After a reboot or a long IMU gap the autopilot's
    /// attitude and position are stale and are dropped (and, after a
    /// reboot, SYSTEM_TIME must map GPS time again).
    pub(super) fn restart(&mut self, t_s: f64, why: &str, kind: Restart, out: &mpsc::Sender<Outbound>) {
        self.log_text(4, t_s, &format!("filter reset: {why}"));
        let _ = out.try_send(Outbound::StatusText {
            severity: if kind == Restart::Unhealthy { 2 } else { 4 },
            text: format!("cmsckf reset: {why}"),
        });
        self.est = None;
        // Where the next filter starts, at once (eq. I3): from our own
        // estimate when the autopilot has no position of its own (no GNSS
        // fix: with external navigation as its only source, its position is
        // the echo of ours; the best one kept, which ages out after
        // CARRY_MAX_S); from the autopilot's state when it has one, unless
        // a start from it failed again just now; and as at the first start
        // (a static window, the compass) after a reboot (the autopilot's EKF
        // starts afresh too, and the time out is unknown).
        let own_fix = self
            .autopilot_fix_t
            .is_some_and(|t| (t_s - t).abs() < AUTOPILOT_FIX_FRESH_S);
        let failed_again = self.in_place_t.is_some_and(|t| (t_s - t).abs() < IN_PLACE_RETRY_S);
        let good = self.good.take_best();
        if kind != Restart::Unhealthy {
            self.attitude = None;
            self.local = None;
            self.gps_accuracy = None;
        }
        self.carried = if kind == Restart::Reboot {
            None
        } else if own_fix {
            (!failed_again)
                .then(|| self.autopilot_start(t_s, good.as_ref()))
                .flatten()
        } else {
            good.or(self.carried.take())
        };
        self.reset_counter = self.reset_counter.wrapping_add(1);
        self.static_buf.clear();
        if kind == Restart::Reboot {
            // A rebooted autopilot has lost the origin we gave it.
            self.origin = OriginSend::default();
            self.tracker.restart_clock();
            self.gnss.unix_minus_boot_s = None;
            self.unix_minus_boot.reset();
            self.pending.clear();
            self.last_frame_t = f64::NEG_INFINITY;
            self.next_output_t = f64::NEG_INFINITY;
            self.next_state_log = f64::NEG_INFINITY;
            self.last_imu_t = f64::NEG_INFINITY;
        }
        self.tracker.hold(Degraded::FilterReset, t_s);
    }
}

/// The mean direction of the readings (unit vector), or `None` without any.
fn mean_direction(readings: &VecDeque<Vector3<f64>>) -> Option<Vector3<f64>> {
    let sum: Vector3<f64> = readings.iter().filter_map(|m| m.try_normalize(0.0)).sum();
    sum.try_normalize(1e-9)
}
