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

use cmsckf_models::geodesy::{ecef_to_llh, NedFrame};
use cmsckf_models::magnetic;
use nalgebra::{UnitQuaternion, Vector3};

use super::autopilot::AutopilotView;
use super::compass::CompassMean;
use super::Restart;
use crate::config::{Config, YawSource};
use crate::counters::{Counter, Counters};
use crate::estimator::imu_covariance::{
    inflate_for_restart, loosen_for_flight, set_position_variances, set_yaw_variance,
};
use crate::estimator::{attitude_from_static, Estimator, ImuMeas, ImuState, Mat15};

/// Our last estimate is carried into a restart for at most this long (s of
/// IMU time): beyond it (a long IMU gap) the motion in between is unknown.
const CARRY_MAX_S: f64 = 5.0;
/// IMU samples kept for a restart to propagate the carried estimate through
/// (s): more than the carried estimate's age at a divergence (1–2 s).
const RECENT_IMU_S: f64 = 2.5;
/// Most IMU samples kept in `recent_imu` (2.5 s at 1.6 kHz): allocated once.
const RECENT_IMU_CAPACITY: usize = 4096;
/// A start that cannot happen says why this often while it lasts (s of IMU
/// time).
const WAITING_REPORT_S: f64 = 5.0;
/// A step between IMU samples up to this (s) is covered by them; beyond it,
/// the gap is inflated for.
const RECENT_IMU_MAX_STEP_S: f64 = 0.1;

/// Snapshots of our estimate while the filter is healthy, taken every
/// [`GOOD_PERIOD_S`]: a restart starts from the older one, 1–2 s before the
/// failure, since a filter going wrong passes its checks for a while.
#[derive(Debug, Default)]
struct GoodEstimates {
    recent: Option<Carried>,
    older: Option<Carried>,
}

/// How often a healthy estimate is kept (s of IMU time).
const GOOD_PERIOD_S: f64 = 1.0;

impl GoodEstimates {
    /// Keeps the estimate of `est` at `t_s` if the last one is a period old.
    fn keep_if_due(&mut self, est: &Estimator, t_s: f64) {
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
    fn take_best(&mut self) -> Option<Carried> {
        // `or`'s argument is taken either way: both are left empty.
        self.older.take().or(self.recent.take())
    }
}

/// A restart from our own estimate that fails again within this (s) is not
/// repeated: that estimate was wrong already (a runaway while blind).
const IN_PLACE_RETRY_S: f64 = 10.0;

/// An estimate carried over a restart: the next filter's start.
#[derive(Clone, Debug)]
struct Carried {
    t_s: f64,
    x: ImuState,
    P: Mat15,
}

impl Carried {
    /// The estimate of `est`, predicted to `t_s` (the IMU sample that
    /// restarted it), with its IMU covariance.
    fn of(est: &Estimator, t_s: f64) -> Self {
        let t_s = t_s.max(est.time_s());
        Self {
            t_s,
            x: est.predict(t_s),
            P: est.imu_covariance(),
        }
    }
}

/// Mean specific force and angular rate of the buffered samples, and how
/// far the means of its quarters stray from them: a still vehicle's slow
/// part is constant however its motors make it vibrate (zero-mean lines
/// that a quarter's mean averages out) and whatever its gyro's bias (a
/// constant), while a vehicle that moves changes its means.
struct StillWindow {
    acc: Vector3<f64>,
    gyr: Vector3<f64>,
    /// Largest |quarter's mean − window's mean| of the rate (rad/s) and of
    /// the specific force (m/s²).
    gyr_spread: f64,
    acc_spread: f64,
    /// What those spreads may be from noise and vibration alone: four
    /// standard errors of a quarter's mean, from the window's own scatter
    /// (rad/s, m/s²).
    gyr_noise: f64,
    acc_noise: f64,
}

/// The quarters' means may stray by this much besides their noise (rad/s,
/// m/s²): residual vibration and the slow wander of a vehicle standing on
/// its legs with its motors running.
const STILL_GYRO_SPREAD_RADPS: f64 = 0.01;
const STILL_ACCEL_SPREAD_MPS2: f64 = 0.1;

impl StillWindow {
    fn of<'a>(samples: impl ExactSizeIterator<Item = &'a ImuMeas> + Clone) -> Self {
        let n = samples.len().max(1);
        // Each quarter's sums (a remainder of up to 3 samples joins none).
        let q = (n / 4).max(1);
        let (mut gyr_q, mut acc_q) = ([Vector3::zeros(); 4], [Vector3::zeros(); 4]);
        for (i, s) in samples.clone().enumerate().filter(|(i, _)| i / q < 4) {
            gyr_q[i / q] += s.gyro_radps;
            acc_q[i / q] += s.accel_mps2;
        }
        let acc = samples.clone().map(|s| s.accel_mps2).sum::<Vector3<f64>>() / n as f64;
        let gyr = samples.clone().map(|s| s.gyro_radps).sum::<Vector3<f64>>() / n as f64;
        let (gyr_var, acc_var) = samples.fold((0.0, 0.0), |(g, a), s| {
            (
                g + (s.gyro_radps - gyr).norm_squared(),
                a + (s.accel_mps2 - acc).norm_squared(),
            )
        });
        let q = q as f64;
        let spread = |sums: &[Vector3<f64>; 4], mean: &Vector3<f64>| {
            sums.iter().map(|s| (s / q - mean).norm()).fold(0.0, f64::max)
        };
        Self {
            acc,
            gyr,
            gyr_spread: spread(&gyr_q, &gyr),
            acc_spread: spread(&acc_q, &acc),
            gyr_noise: 4.0 * (gyr_var / n as f64 / q).sqrt(),
            acc_noise: 4.0 * (acc_var / n as f64 / q).sqrt(),
        }
    }

    /// Still by the IMU: the means constant within noise and vibration, the
    /// specific force gravity's, and the mean rate within the gyro's bias
    /// specification `gyro_bias_max_radps` (beyond it, a turn).
    fn is_still(&self, gravity_mps2: f64, gyro_bias_max_radps: f64) -> bool {
        self.gyr_spread < STILL_GYRO_SPREAD_RADPS + self.gyr_noise
            && self.acc_spread < STILL_ACCEL_SPREAD_MPS2 + self.acc_noise
            && self.gyr.norm() < gyro_bias_max_radps
            && (self.acc.norm() - gravity_mps2).abs() < 0.3
    }
}

/// The estimate's starts and restarts: the static window, the IMU samples
/// a restart propagates through, our healthy estimates kept 1–2 s back and
/// the one carried over a restart.
#[derive(Debug)]
pub(super) struct Starter {
    static_buf: VecDeque<ImuMeas>,
    /// The last [`RECENT_IMU_S`] of IMU samples, which a restart propagates
    /// the carried estimate through.
    recent_imu: VecDeque<ImuMeas>,
    /// Our own last estimate across a restart: the next filter starts from
    /// it, never from the autopilot's echo of it.
    carried: Option<Carried>,
    /// Our estimate while healthy, 1–2 s back: what `carried` is taken from.
    good: GoodEstimates,
    /// When the filter was last restarted from a carried estimate.
    in_place_t: Option<f64>,
    /// The last reason for waiting reported, and when to report it again.
    reported: Option<(Waiting, f64)>,
    /// The first IMU sample's time: how long a compass start has waited
    /// for a world origin (its declination).
    first_imu_t: Option<f64>,
}

/// A compass start waits this long after the first IMU sample (s) for a
/// world origin to give its declination (a ground station sets
/// ArduPilot's EKF origin, or the autopilot's GNSS does at its first fix),
/// then takes the magnetic heading: a heading many degrees off true north
/// that EKF3, taking our yaw, converges from only slowly once corrected.
const ORIGIN_WAIT_FOR_COMPASS_S: f64 = 20.0;

/// Why no filter has started yet, at this IMU sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Waiting {
    /// The static window is still filling (the first second or so: normal).
    Window,
    /// No `ATTITUDE` from the autopilot yet.
    NoAttitude,
    /// A compass but no world origin yet for its declination (for at most
    /// [`ORIGIN_WAIT_FOR_COMPASS_S`]).
    NoOrigin,
    /// `init.yaw_source` has no yaw to give (no compass reading, no world
    /// origin for the declination, no `ATTITUDE` yaw).
    NoYaw,
    /// The IMU says the vehicle is not still, and the autopilot gives no
    /// local position for an in-flight start.
    NotStillNoPosition,
    /// Still by the IMU, but its specific force gives no attitude.
    NoGravity,
}

impl Waiting {
    /// Why, in words for the pilot (STATUSTEXT, the log, the journal).
    pub(super) fn text(self) -> &'static str {
        match self {
            Waiting::Window => "waiting: filling the static window",
            Waiting::NoAttitude => "waiting: no ATTITUDE from the autopilot",
            Waiting::NoOrigin => {
                "waiting: no world origin for the compass's declination (set the EKF origin, or gnss.origin_llh); \
                 the autopilot's heading is taken 20 s after start"
            }
            Waiting::NoYaw => "waiting: no yaw from init.yaw_source (no compass, origin or ATTITUDE yaw)",
            Waiting::NotStillNoPosition => {
                "waiting: vehicle not still, and no autopilot position (LOCAL_POSITION_NED) for an in-flight start"
            }
            Waiting::NoGravity => "waiting: the accelerometer shows no gravity",
        }
    }
}

/// A filter to run, and how it started.
pub(super) struct Start {
    pub(super) est: Estimator,
    /// A static start (the IMU said the vehicle was still).
    pub(super) is_static: bool,
    /// A static start's compass mean, which the readings while the vehicle
    /// stands improve (`compass.rs`); `None` for any other yaw.
    pub(super) compass: Option<CompassMean>,
}

impl Default for Starter {
    fn default() -> Self {
        Self {
            static_buf: VecDeque::with_capacity(4096),
            recent_imu: VecDeque::with_capacity(RECENT_IMU_CAPACITY),
            carried: None,
            good: GoodEstimates::default(),
            in_place_t: None,
            reported: None,
            first_imu_t: None,
        }
    }
}

impl Starter {
    /// Keeps the IMU sample `m` among the recent ones (bounded).
    pub(super) fn push_imu(&mut self, m: ImuMeas) {
        while self
            .recent_imu
            .front()
            .is_some_and(|f| m.t_s - f.t_s > RECENT_IMU_S || f.t_s >= m.t_s)
            || self.recent_imu.len() == RECENT_IMU_CAPACITY
        {
            self.recent_imu.pop_front();
        }
        self.recent_imu.push_back(m);
    }

    /// Offers the running filter's estimate at `t_s` as a healthy one (only
    /// an estimate that measurements vouch for: a filter carried on the IMU
    /// alone passes its checks however wrong).
    pub(super) fn offer_good(&mut self, est: &Estimator, t_s: f64) {
        self.good.keep_if_due(est, t_s);
    }

    /// A filter to start at the IMU sample `m`, if one can start: at once
    /// from the estimate carried over a restart, else once the static
    /// window is full (see [`Starter::try_init`]). `frame` is the world
    /// frame's origin, for the compass's declination.
    pub(super) fn start_filter(
        &mut self,
        m: ImuMeas,
        cfg: &Config,
        ap: &AutopilotView,
        frame: Option<NedFrame>,
        counters: &Counters,
    ) -> Result<Start, Waiting> {
        let start = match self.restart_in_place(m, cfg) {
            Some(est) => {
                counters.add(Counter::InitFromCarriedEstimate, 1);
                self.in_place_t = Some(m.t_s);
                Start {
                    est,
                    is_static: false,
                    compass: None,
                }
            }
            None => self.try_init(m, cfg, ap, frame)?,
        };
        self.static_buf.clear();
        self.reported = None;
        Ok(start)
    }

    /// Whether to say why no filter starts (`why`, at `t_s`): at once when
    /// the reason is new, then every [`WAITING_REPORT_S`] while it lasts.
    /// The static window filling is no reason to report.
    pub(super) fn report_waiting(&mut self, why: Waiting, t_s: f64) -> bool {
        if why == Waiting::Window {
            return false;
        }
        let due = match self.reported {
            Some((last, next_t)) => last != why || t_s >= next_t || t_s < next_t - WAITING_REPORT_S,
            None => true,
        };
        if due {
            self.reported = Some((why, t_s + WAITING_REPORT_S));
        }
        due
    }

    /// The autopilot's own state, when it has a position of its own (a GNSS
    /// fix) and its attitude and local position are fresh: a restart's
    /// start with the in-flight priors of eq. I1, keeping our bias
    /// estimates from `good` (the autopilot reports none). `None` without
    /// them (after an IMU gap or a reboot they are dropped as stale).
    fn autopilot_start(t_s: f64, cfg: &Config, ap: &AutopilotView, good: Option<&Carried>) -> Option<Carried> {
        let (roll, pitch, yaw) = ap.attitude()?;
        let (_, _, t) = ap.local()?;
        // Fresh (and finite) only.
        if (t_s - t).abs().partial_cmp(&1.0) != Some(std::cmp::Ordering::Less) {
            return None;
        }
        let (mut x, mut P) = initial_state(t_s, cfg, ap, None, [roll, pitch, yaw])?;
        set_yaw_variance(&mut P, cfg.init.sigma_yaw_autopilot_deg.to_radians().powi(2));
        if let Some(g) = good {
            (x.b_g, x.b_a) = (g.x.b_g, g.x.b_a);
        }
        Some(Carried { t_s, x, P })
    }

    /// A filter restarted at once from the estimate carried over the
    /// restart (ours, or the autopilot's own), if one is carried and recent
    /// ([`CARRY_MAX_S`]); `None` if not.
    fn restart_in_place(&mut self, m: ImuMeas, cfg: &Config) -> Option<Estimator> {
        let c = self.carried.as_ref()?;
        if !(m.t_s - c.t_s).is_finite() || m.t_s - c.t_s > CARRY_MAX_S || m.t_s < c.t_s {
            // Too old to carry (the motion since is unknown): a fresh start.
            self.carried = None;
            return None;
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
        let i = &cfg.init;
        let prior = cfg.initial_covariance();
        let p0 = inflate_for_restart(
            &c.P,
            &prior,
            uncovered_s,
            i.restart_sigma_position_m,
            i.restart_sigma_velocity_mps,
        );
        let mut est = Estimator::new(cfg.estimator_settings(), t0, c.x, &p0);
        for s in self.recent_imu.iter().filter(|s| s.t_s > t0) {
            let _ = est.add_imu(*s);
        }
        est.start_health_grace(m.t_s);
        Some(est)
    }

    /// A filter once the static window is full and the autopilot's
    /// attitude is known: static when the IMU (and the autopilot's velocity,
    /// when it has one: constant velocity looks static to an IMU) says so,
    /// else in flight from the autopilot's state.
    fn try_init(
        &mut self,
        m: ImuMeas,
        cfg: &Config,
        ap: &AutopilotView,
        frame: Option<NedFrame>,
    ) -> Result<Start, Waiting> {
        self.static_buf.push_back(m);
        let first_imu_t = *self.first_imu_t.get_or_insert(m.t_s);
        let window = cfg.init.static_window_s;
        while self.static_buf.front().is_some_and(|f| m.t_s - f.t_s > window) {
            self.static_buf.pop_front();
        }
        if self.static_buf.len() < 10 || m.t_s - self.static_buf[0].t_s < 0.9 * window {
            return Err(Waiting::Window);
        }
        let (roll, pitch, _) = ap.attitude().ok_or(Waiting::NoAttitude)?;
        let w = StillWindow::of(self.static_buf.iter());
        // Constant velocity looks still to an IMU: the autopilot's velocity
        // says otherwise.
        let is_static = w.is_still(cfg.imu.gravity_mps2, cfg.init.gyro_bias_max_radps)
            && ap.local().is_none_or(|(_, v, _)| v.norm() < 0.3);
        // The tilt the compass is levelled with: gravity's direction when
        // still; in flight the accelerometer points along the thrust, so the
        // autopilot's attitude.
        let tilt = is_static
            .then(|| attitude_from_static(&w.acc, 0.0))
            .flatten()
            .unwrap_or_else(|| UnitQuaternion::from_euler_angles(roll, pitch, 0.0));
        // Only a static start on `auto` waits (`compass` waits for the
        // origin anyway; an in-flight start must not leave the autopilot
        // without our estimates).
        if is_static
            && frame.is_none()
            && cfg.init.yaw_source == YawSource::Auto
            && ap.mag_direction_B().is_some()
            && m.t_s - first_imu_t < ORIGIN_WAIT_FOR_COMPASS_S
        {
            return Err(Waiting::NoOrigin);
        }
        let (yaw, yaw_sigma_deg, compass) = first_yaw(cfg, ap, frame, &tilt).ok_or(Waiting::NoYaw)?;
        let (x0, mut p0) =
            initial_state(m.t_s, cfg, ap, is_static.then_some(&w), [roll, pitch, yaw]).ok_or(if is_static {
                Waiting::NoGravity
            } else {
                Waiting::NotStillNoPosition
            })?;
        set_yaw_variance(&mut p0, yaw_sigma_deg.to_radians().powi(2));
        let mut est = Estimator::new(cfg.estimator_settings(), m.t_s, x0, &p0);
        let _ = est.add_imu(m);
        let (_, _, yaw) = x0.q_W_B.euler_angles();
        tracing::info!(yaw_deg = yaw.to_degrees(), "initial yaw");
        // Only a static start's readings average: the vehicle stands.
        let compass = compass.filter(|_| is_static);
        Ok(Start {
            est,
            is_static,
            compass,
        })
    }

    /// Where the next filter starts after a restart of `kind` at `t_s` (the
    /// one reset path), at once (eq. I3): from our own estimate when the
    /// autopilot has no position of its own (no GNSS fix: with external
    /// navigation as its only source, its position is the echo of ours; the
    /// best one kept, which ages out after [`CARRY_MAX_S`]); from the
    /// autopilot's state when it has one, unless a start from it failed
    /// again just now; and as at the first start (a static window, the
    /// compass) after a reboot (the autopilot's EKF starts afresh too, and
    /// the time out is unknown). Call it before `ap` forgets what the
    /// restart makes stale.
    pub(super) fn plan_restart(&mut self, t_s: f64, kind: Restart, cfg: &Config, ap: &AutopilotView) {
        let own_fix = ap.has_own_position(t_s);
        let failed_again = self.in_place_t.is_some_and(|t| (t_s - t).abs() < IN_PLACE_RETRY_S);
        let good = self.good.take_best();
        // An IMU gap or a reboot makes the autopilot's state stale.
        let fresh_ap = kind == Restart::Unhealthy;
        // A reboot's clock starts over: the wait for an origin is timed
        // afresh (the fusion loop's time guard lets no sample of a clock
        // gone back reach the starter before this).
        if kind == Restart::Reboot {
            self.first_imu_t = None;
        }
        self.carried = if matches!(kind, Restart::Reboot | Restart::Located) {
            None
        } else if own_fix {
            (!failed_again && fresh_ap)
                .then(|| Self::autopilot_start(t_s, cfg, ap, good.as_ref()))
                .flatten()
        } else {
            good.or(self.carried.take())
        };
        self.static_buf.clear();
    }
}

/// The first state and its covariance, static from the `still` window or
/// else in flight from the autopilot's state, or `None` while what it needs
/// is missing (a static attitude from the IMU; in flight, the autopilot's
/// local position).
fn initial_state(
    t_s: f64,
    cfg: &Config,
    ap: &AutopilotView,
    still: Option<&StillWindow>,
    [roll, pitch, yaw]: [f64; 3],
) -> Option<(ImuState, Mat15)> {
    // The autopilot's position, carried to this sample's time (its
    // LOCAL_POSITION_NED comes at 10 Hz: 1.5 m old at 15 m/s otherwise).
    let local = ap.local();
    let (p, v) = match local {
        Some((p, v, t)) if (t_s - t).abs() < 1.0 => (p + v * (t_s - t), v),
        Some((p, v, _)) => (p, v),
        None => (Vector3::zeros(), Vector3::zeros()),
    };
    // Priors from their sources (§7, eq. I1): the yaw's is set by the
    // caller (compass, autopilot or configured), the position the
    // autopilot's local position with its reported accuracy, or, without
    // one, the world frame's own origin.
    let mut p0 = cfg.initial_covariance();
    if local.is_some() {
        // Its GNSS's accuracy only when its GNSS places it (PX4 with
        // `EKF2_GPS_CTRL = 0` reports a fix it does not fuse).
        let (h, v) = ap
            .gps_accuracy()
            .filter(|_| ap.has_own_position(t_s))
            .unwrap_or((cfg.init.sigma_position_autopilot_m, cfg.init.sigma_position_autopilot_m));
        set_position_variances(&mut p0, [h * h, h * h, v * v]);
    }
    let (q, b_g, v) = if let Some(w) = still {
        (attitude_from_static(&w.acc, yaw)?, w.gyr, Vector3::zeros())
    } else {
        local?;
        // In flight: the autopilot's attitude, looser, and the gyro bias as
        // uncertain as the sensor's specification says.
        loosen_for_flight(&mut p0, cfg.init.sigma_gyro_bias_in_flight_radps);
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

/// The first yaw (rad), its sigma (deg) and, from the compass, the mean
/// the readings while the vehicle stands improve; from `init.yaw_source`,
/// for a body whose rotation without yaw is `tilt`; `None` while the source
/// has nothing to give.
fn first_yaw(
    cfg: &Config,
    ap: &AutopilotView,
    frame: Option<NedFrame>,
    tilt: &UnitQuaternion<f64>,
) -> Option<(f64, f64, Option<CompassMean>)> {
    let i = &cfg.init;
    let autopilot = ap.attitude().map(|(_, _, yaw)| (yaw, i.sigma_yaw_autopilot_deg, None));
    let compass = || compass_yaw(cfg, ap, frame, tilt);
    match i.yaw_source {
        YawSource::Config => Some((i.yaw_deg.to_radians(), i.sigma_yaw_deg, None)),
        YawSource::Autopilot => autopilot,
        YawSource::Compass => compass(),
        YawSource::Auto => compass().or(autopilot),
    }
}

/// The compass's true heading (rad) and its sigma (deg), with the WMM
/// declination at our origin, today (eq. M1): the mean heading of the
/// latest magnetometer readings, whose sigma holds the compass's bias
/// (`init.sigma_yaw_compass_deg`), the declination model's and the mean's
/// own noise, `s²/N` from the readings' scatter (eq. H1); with fewer than
/// five readings their mean direction's heading, without that noise.
fn compass_yaw(
    cfg: &Config,
    ap: &AutopilotView,
    frame: Option<NedFrame>,
    tilt: &UnitQuaternion<f64>,
) -> Option<(f64, f64, Option<CompassMean>)> {
    let frame = frame?;
    let (lat, lon, h) = ecef_to_llh(&frame.origin_ecef);
    let (dec_deg, dec_sigma_deg) = magnetic::declination_deg(lat.to_degrees(), lon.to_degrees(), h, ap.unix_days()?)?;
    let bias_sigma_deg = cfg.init.sigma_yaw_compass_deg.hypot(dec_sigma_deg);
    if let Some(mean) = CompassMean::start(ap.mag_readings_B(), tilt, dec_deg.to_radians()) {
        let sigma_deg = bias_sigma_deg.hypot(mean.noise_var_rad2().sqrt().to_degrees());
        return Some((mean.yaw_rad(), sigma_deg, Some(mean)));
    }
    let mag_B = ap.mag_direction_B()?;
    let yaw = magnetic::heading_rad(tilt, &mag_B, dec_deg.to_radians())?;
    Some((yaw, bias_sigma_deg, None))
}
