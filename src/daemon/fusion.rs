//! The fusion loop, on its own OS thread: it takes the inputs in the order
//! they arrive (IMU, camera frames, RTCM, autopilot state), logs each one it
//! uses (so `cmsckf replay` feeds them back through this same code),
//! holds measurements until IMU covers their time, runs the estimator, and
//! has one restart path (reboot, IMU gap, divergence; `Fusion::restart` in
//! `init.rs`, beside the starts it leads to).

use std::borrow::Cow;
use std::collections::VecDeque;
use std::sync::atomic::{AtomicI64, Ordering};
use std::sync::Arc;
use std::time::Instant;

use cmsckf_models::gnss::SatMeas;
use nalgebra::Vector3;
use serde_json::json;
use tokio::sync::mpsc;

use super::autopilot::{OriginSend, MAG_READINGS};
use super::gnss_input::GnssIn;
use super::init::{Carried, GoodEstimates, RECENT_IMU_S};
use super::rebase::{InstallSite, RebaseExec};
use super::time_guard::{SteadyValue, TimeGuard, Verdict};
use super::{FusionMsg, Restart, RtcmStream, Shared, MAX_IMU_GAP_S, PENDING_FRAMES, REBOOT_JUMP_S};
use crate::config::{Config, FeatureClock};
use crate::counters::{Counter, Counters};
use crate::estimator::frontend::NormFrame;
use crate::estimator::{Estimator, ImuMeas};
use crate::io::feature_pipe::FeatureFrame;
use crate::io::mcap_log::input::{FeaturesRecord, ImuRecord, InputRecord, RtcmRecord};
use crate::io::mcap_log::{McapLogger, Topic};
use crate::io::messages::{AutopilotKind, Outbound};
use crate::status::{self, Degraded, Status};

/// IMU samples in a row that must agree on a jump of their clock (a reboot,
/// or a link that was down) before it is believed.
const IMU_JUMP_CONFIRM: u32 = 5;
/// SYSTEM_TIME: a change of the Unix − boot offset beyond this (s) is
/// believed once this many messages agree on it.
const SYSTEM_TIME_TOL_S: f64 = 1.0;
const SYSTEM_TIME_CONFIRM: u32 = 3;
/// Records held until the first IMU sample gives them a sensor time.
const PRE_IMU_LOG_CAP: usize = 1024;
/// A camera frame is believed only within this much of the IMU clock:
/// ahead of it (s), and behind it (s; latency and a short IMU stall).
const FRAME_MAX_LEAD_S: f64 = 1.0;
const FRAME_MAX_LAG_S: f64 = 5.0;

/// How far the filter may stay behind the IMU while no measurement moves it
/// on (s): later than this, a frame is late anyway (they arrive within
/// 0.1 s), and GNSS epochs reach back through their clones.
const MAX_FILTER_LAG_S: f64 = 1.0;

/// Most IMU samples kept in `recent_imu` (2.5 s at 1.6 kHz): allocated once.
const RECENT_IMU_CAPACITY: usize = 4096;

/// An estimate counts as good only this soon after a measurement (s).
const GOOD_AIDED_S: f64 = 0.5;

/// A measurement waiting for IMU to cover its time.
#[derive(Debug)]
pub(super) enum Pending {
    Frame(NormFrame),
    Gnss(Vec<SatMeas>),
}

/// State of the fusion loop.
pub struct Fusion {
    pub(super) log: Option<McapLogger>,
    pub(super) rebase: RebaseExec,
    /// Counts estimators started, so a rebase result of a filter since
    /// restarted is recognised and dropped.
    pub(super) est_gen: u64,
    pub(super) next_state_log: f64,
    /// Landmarks gathered for the log's `/landmarks`.
    pub(super) landmarks: super::frames::LandmarkCloud,
    /// The camera's pose in the body frame, for the log's frame tree.
    pub(super) T_B_C: nalgebra::Isometry3<f64>,
    /// Next autopilot time to log the counters at (`/diagnostics`).
    next_diag_t: f64,
    pub(super) cfg: Config,
    pub(super) est: Option<Estimator>,
    pub(super) static_buf: VecDeque<ImuMeas>,
    pub(super) attitude: Option<(f64, f64, f64)>,
    /// The autopilot's local position and velocity (NED) and their time (s).
    pub(super) local: Option<(Vector3<f64>, Vector3<f64>, f64)>,
    /// The autopilot's GNSS accuracy `(horizontal, vertical)` (m, one
    /// sigma), when it reports one.
    pub(super) gps_accuracy: Option<(f64, f64)>,
    pub(super) pending: VecDeque<(f64, Pending)>,
    pub(super) gnss: GnssIn,
    /// Our origin, sent to the autopilot until it reports it back.
    pub(super) origin: OriginSend,
    /// The autopilot's latest magnetometer readings (body frame, ~1 s).
    pub(super) mag_B: VecDeque<Vector3<f64>>,
    /// Today in Unix days (the companion's clock at start), for the
    /// declination.
    pub(super) unix_days: Option<i64>,
    /// The autopilot's armed and landed states, when it reports them.
    pub(super) armed: Option<bool>,
    pub(super) on_ground: Option<bool>,
    /// When (IMU time) the autopilot last reported a 3D GNSS fix of its own.
    pub(super) autopilot_fix_t: Option<f64>,
    /// When the filter was last restarted from our own estimate.
    pub(super) in_place_t: Option<f64>,
    /// Which autopilot its HEARTBEAT says it is.
    pub(super) autopilot_kind: Option<AutopilotKind>,
    /// Our own last estimate across a restart: the next filter starts from
    /// it, never from the autopilot's echo of it.
    pub(super) carried: Option<Carried>,
    /// Our estimate while healthy, 1–2 s back: what `carried` is taken from.
    pub(super) good: GoodEstimates,
    /// The last [`RECENT_IMU_S`] of IMU samples, which a restart propagates
    /// the carried estimate through.
    pub(super) recent_imu: VecDeque<ImuMeas>,
    pub(super) last_imu_t: f64,
    /// Records of inputs that came before any IMU sample (an ephemeris, the
    /// autopilot's origin): they have no sensor time yet, so they wait and
    /// are logged, in order, at the first IMU sample's time rather than at 0.
    pre_imu_log: std::cell::RefCell<Vec<(Topic, serde_json::Value)>>,
    /// The IMU stream's clock: single bad stamps rejected, jumps confirmed.
    imu_clock: TimeGuard,
    /// The autopilot's Unix − boot offset (s), from SYSTEM_TIME, changed
    /// only when several messages agree.
    pub(super) unix_minus_boot: SteadyValue,
    pub(super) last_frame_t: f64,
    pub(super) next_output_t: f64,
    pub(super) reset_counter: u8,
    /// Degraded-state reasons, in autopilot time.
    pub(super) tracker: status::Tracker,
}

/// What the fusion loop writes to: counters, the outbound channel and the
/// flags and clock offset shared with the I/O tasks.
pub struct Ctx {
    pub counters: Counters,
    pub out: mpsc::Sender<Outbound>,
    pub status: Arc<Status>,
    pub mono_offset_us: Arc<AtomicI64>,
    /// The daemon's start (wall clock), for the IMU's wall-time age.
    pub start: Instant,
}

/// Where a rebase result goes: the filter (of generation `est_gen`), its
/// log, and the latest IMU time to log it at.
fn install_site<'a>(
    est: &'a mut Option<Estimator>,
    est_gen: u64,
    log: &'a Option<McapLogger>,
    t_s: f64,
) -> InstallSite<'a> {
    InstallSite {
        est: est.as_mut(),
        est_gen,
        log: log.as_ref(),
        t_s,
    }
}

/// Runs the fusion loop on its own thread until its input channel closes.
pub(super) fn spawn(
    cfg: Config,
    rx: mpsc::Receiver<FusionMsg>,
    out: mpsc::Sender<Outbound>,
    shared: Shared,
    log: Option<McapLogger>,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    std::thread::Builder::new()
        .name("cmsckf-fusion".into())
        .spawn(move || fusion_loop(cfg, rx, out, shared, log))
}

fn fusion_loop(
    cfg: Config,
    mut rx: mpsc::Receiver<FusionMsg>,
    out: mpsc::Sender<Outbound>,
    shared: Shared,
    log: Option<McapLogger>,
) {
    let Shared {
        counters,
        status,
        mono_offset_us,
        start,
        frames_queued,
        fusion_progress,
    } = shared;
    let mut f = Fusion::new(cfg, log);
    let ctx = Ctx {
        counters,
        out,
        status,
        mono_offset_us,
        start,
    };
    while let Some(msg) = rx.blocking_recv() {
        if matches!(msg, FusionMsg::Frame(..)) {
            let _ = frames_queued.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |n| Some(n.saturating_sub(1)));
        }
        f.handle(msg, &ctx);
        fusion_progress.fetch_add(1, Ordering::Relaxed);
    }
    let counters = ctx.counters;
    f.finish_log(&counters);
}

impl Fusion {
    /// A fusion loop for `cfg`, logging to `log` if given.
    pub fn new(cfg: Config, log: Option<McapLogger>) -> Self {
        Fusion {
            log,
            rebase: RebaseExec::for_config(&cfg),
            est_gen: 0,
            next_state_log: f64::NEG_INFINITY,
            landmarks: Default::default(),
            T_B_C: cmsckf_models::camera::Camera::from_config(&cfg.camera).T_B_C,
            next_diag_t: f64::NEG_INFINITY,
            est: None,
            static_buf: VecDeque::with_capacity(4096),
            attitude: None,
            local: None,
            gps_accuracy: None,
            pending: VecDeque::with_capacity(PENDING_FRAMES),
            origin: OriginSend::default(),
            mag_B: VecDeque::with_capacity(MAG_READINGS),
            unix_days: None,
            armed: None,
            on_ground: None,
            autopilot_kind: None,
            autopilot_fix_t: None,
            in_place_t: None,
            carried: None,
            good: GoodEstimates::default(),
            recent_imu: VecDeque::with_capacity(RECENT_IMU_CAPACITY),
            gnss: GnssIn::new(&cfg),
            last_imu_t: f64::NEG_INFINITY,
            pre_imu_log: std::cell::RefCell::new(Vec::new()),
            imu_clock: TimeGuard::new(REBOOT_JUMP_S, IMU_JUMP_CONFIRM),
            unix_minus_boot: SteadyValue::new(SYSTEM_TIME_TOL_S, SYSTEM_TIME_CONFIRM),
            last_frame_t: f64::NEG_INFINITY,
            next_output_t: f64::NEG_INFINITY,
            reset_counter: 0,
            tracker: status::Tracker::default(),
            cfg,
        }
    }

    /// Finishes the log (on shutdown: `Drop` would swallow its errors),
    /// counting its messages and raising an alarm for dropped records.
    pub fn finish_log(&mut self, counters: &Counters) {
        if self.last_imu_t.is_finite() {
            self.log_diagnostics(self.last_imu_t, counters, 0);
        }
        // A log that never saw an IMU sample still keeps its other inputs.
        if let Some(l) = &self.log {
            for (topic, v) in self.pre_imu_log.get_mut().drain(..) {
                l.log(topic, 0.0, &v);
            }
        }
        let Some(l) = self.log.take() else {
            return;
        };
        let dropped = l.dropped();
        match l.finish() {
            Ok(s) => {
                counters.add(Counter::LogMessages, s.messages);
                counters.add(Counter::LogChunks, s.chunks);
            }
            Err(e) => {
                counters.add(Counter::LogError, 1);
                tracing::error!(error = %e, "the MCAP log could not be finished");
            }
        }
        if dropped > 0 {
            counters.add(Counter::LogDropped, dropped);
            tracing::error!(
                dropped,
                "ALARM: MCAP log records were dropped (writer could not keep up)"
            );
        }
    }

    /// For `cmsckf replay`: rebases are installed where the log says.
    pub fn for_replay(mut self) -> Self {
        self.rebase = self.rebase.for_replay();
        self
    }

    /// Handles one input, in the order the fusion loop received it (replay
    /// feeds the logged inputs through here in the same order).
    pub fn handle(&mut self, msg: FusionMsg, ctx: &Ctx) {
        let site = install_site(&mut self.est, self.est_gen, &self.log, self.last_imu_t);
        self.rebase.poll(site, &ctx.counters);
        match msg {
            FusionMsg::RebaseInstalled { seq } => {
                let site = install_site(&mut self.est, self.est_gen, &self.log, self.last_imu_t);
                self.rebase.on_installed(seq, site, &ctx.counters);
            }
            FusionMsg::Rtcm { bytes, stream } => {
                self.log_input(
                    self.last_imu_t,
                    &InputRecord::Rtcm(RtcmRecord {
                        bytes: Cow::Borrowed(&bytes),
                        stream,
                    }),
                );
                self.on_rtcm(&bytes, stream, &ctx.counters)
            }
            FusionMsg::Frame(fr, norm) => self.on_frame(fr, norm, ctx),
            FusionMsg::Imu(m) => self.on_imu_msg(m, ctx),
            other => self.on_autopilot(other, &ctx.counters),
        }
    }

    /// RTCM from the rover: each completed epoch's measurements wait in
    /// time order for IMU to cover them.
    fn on_rtcm(&mut self, bytes: &[u8], stream: RtcmStream, counters: &Counters) {
        let mut epochs = Vec::new();
        self.gnss.on_rtcm(
            bytes,
            stream,
            self.est.as_ref(),
            self.log.as_ref(),
            counters,
            &mut epochs,
        );
        for (t, sats) in epochs {
            self.enqueue(t, Pending::Gnss(sats), counters);
        }
        // The world origin was just placed at a single-point fix: every
        // position in the filter is now off by that fix's error (§7).
        if let (Some(sigma_m), Some(est)) = (self.gnss.origin_fix_sigma_m.take(), self.est.as_mut()) {
            if est.add_world_offset_variance(sigma_m * sigma_m) {
                counters.add(Counter::PriorFromFix, 1);
            }
        }
    }

    /// A camera frame: mapped to autopilot time, logged, and queued until
    /// IMU covers it; a frame not after the last one is rejected.
    fn on_frame(&mut self, fr: FeatureFrame, norm: NormFrame, ctx: &Ctx) {
        let t_ap_us = match self.cfg.features.clock {
            FeatureClock::Autopilot => fr.t_us as i64,
            FeatureClock::Monotonic => {
                let off = ctx.mono_offset_us.load(Ordering::Relaxed);
                if off == i64::MIN {
                    ctx.counters.add(Counter::FeatureNoTimesync, 1);
                    return;
                }
                fr.t_us as i64 + off
            }
        };
        let t = t_ap_us as f64 * 1e-6;
        self.log_input(
            t,
            &InputRecord::Features(FeaturesRecord {
                t_us: fr.t_us,
                t_ap_us,
                cam: fr.cam,
                features: Cow::Borrowed(&fr.features),
            }),
        );
        // Judged against the autopilot's clock (the IMU's), so that one
        // far-off stamp is rejected and never becomes the reference.
        if !self.last_imu_t.is_finite() {
            // Nothing to judge it by, and nothing to fuse it with yet.
            ctx.counters.add(Counter::FeatureBeforeImu, 1);
            return;
        }
        if !(t <= self.last_imu_t + FRAME_MAX_LEAD_S && t >= self.last_imu_t - FRAME_MAX_LAG_S) {
            ctx.counters.add(Counter::FeatureTimeImplausible, 1);
            tracing::warn!(
                reason = "feature_time_implausible",
                t_s = t,
                imu_t_s = self.last_imu_t,
                "frame rejected: its time is not near the autopilot's"
            );
            return;
        }
        if t <= self.last_frame_t {
            ctx.counters.add(Counter::FeatureTimeBackwards, 1);
            tracing::warn!(
                reason = "feature_time_backwards",
                t_s = t,
                prev_s = self.last_frame_t,
                "frame rejected"
            );
            return;
        }
        self.last_frame_t = t;
        self.enqueue(t, Pending::Frame(norm), &ctx.counters);
    }

    /// An IMU sample: logged as it came (so that replay judges it the same
    /// way), then its time judged by [`TimeGuard`]. A confirmed jump back
    /// is a reboot and one forward past `MAX_IMU_GAP_S` a gap: either
    /// restarts the filter. Then the sample is fused, and the status and
    /// diagnostics follow it.
    fn on_imu_msg(&mut self, m: ImuMeas, ctx: &Ctx) {
        self.log_input(
            m.t_s,
            &InputRecord::Imu(ImuRecord {
                t_us: (m.t_s * 1e6).round() as u64,
                accel_mps2: m.accel_mps2.into(),
                gyro_radps: m.gyro_radps.into(),
            }),
        );
        match self.imu_clock.check(m.t_s) {
            Verdict::Next => {}
            Verdict::Stale => {
                ctx.counters.add(Counter::ImuTimeBackwards, 1);
                return;
            }
            Verdict::Outlier => {
                // One sample off the autopilot's clock (or the first of a
                // jump not yet confirmed): never the new reference.
                ctx.counters.add(Counter::ImuTimeOutlier, 1);
                tracing::warn!(
                    reason = "imu_time_outlier",
                    t_s = m.t_s,
                    last_s = self.last_imu_t,
                    "IMU sample rejected"
                );
                return;
            }
            Verdict::Jump { from_s } if m.t_s < from_s => {
                // The autopilot's boot clock restarted (a reboot), as
                // several samples in a row agree: start over.
                ctx.counters.add(Counter::AutopilotClockReset, 1);
                tracing::error!(
                    from_s,
                    to_s = m.t_s,
                    "autopilot clock jumped back: resetting the filter"
                );
                self.restart(m.t_s, "autopilot reboot seen", Restart::Reboot, &ctx.out);
            }
            Verdict::Jump { .. } => {}
        }
        if self.est.is_some() && m.t_s - self.last_imu_t > MAX_IMU_GAP_S {
            // Seconds without IMU: the motion in between is unknown.
            ctx.counters.add(Counter::ImuGapRestart, 1);
            tracing::error!(
                gap_s = m.t_s - self.last_imu_t,
                "IMU gap too long: resetting the filter"
            );
            self.restart(m.t_s, "IMU gap", Restart::Gap, &ctx.out);
        }
        if self.last_imu_t.is_finite() && m.t_s - self.last_imu_t > 0.2 {
            self.tracker.hold(Degraded::ImuGap, m.t_s);
            if m.t_s - self.last_imu_t > 0.5 {
                ctx.counters.add(Counter::ImuGap, 1);
                tracing::warn!(reason = "imu_gap", gap_s = m.t_s - self.last_imu_t, "IMU gap");
            }
        }
        self.last_imu_t = m.t_s;
        ctx.counters.add(Counter::ImuSamples, 1);
        while self
            .recent_imu
            .front()
            .is_some_and(|f| m.t_s - f.t_s > RECENT_IMU_S || f.t_s >= m.t_s)
            || self.recent_imu.len() == RECENT_IMU_CAPACITY
        {
            self.recent_imu.pop_front();
        }
        self.recent_imu.push_back(m);
        self.on_imu(m, &ctx.counters, &ctx.out);
        let st = &ctx.status;
        // An unhealthy filter was restarted in `on_imu`: a running
        // filter is a healthy one.
        st.initialised.store(self.est.is_some(), Ordering::Relaxed);
        st.last_imu_wall_ms
            .store(ctx.start.elapsed().as_millis() as u64, Ordering::Relaxed);
        self.tracker.update(m.t_s, self.est.is_some(), &ctx.counters, st);
        if m.t_s >= self.next_diag_t {
            self.next_diag_t = m.t_s + 1.0;
            self.log_diagnostics(m.t_s, &ctx.counters, st.degraded());
        }
    }

    /// An input, as the fusion loop consumed it (what replay feeds back).
    pub(super) fn log_input(&self, t_s: f64, rec: &InputRecord<'_>) {
        self.log(rec.topic(), t_s, rec);
    }

    pub(super) fn log<T: serde::Serialize>(&self, topic: Topic, t_s: f64, v: &T) {
        let Some(l) = &self.log else { return };
        let mut pending = self.pre_imu_log.borrow_mut();
        if !t_s.is_finite() {
            // Before any IMU sample: wait for a sensor time (bounded; past
            // the bound the logger's own stamp, 0, is better than none).
            if pending.len() < PRE_IMU_LOG_CAP {
                if let Ok(v) = serde_json::to_value(v) {
                    pending.push((topic, v));
                    return;
                }
            }
        } else {
            for (topic, v) in pending.drain(..) {
                l.log(topic, t_s, &v);
            }
        }
        l.log(topic, t_s, v);
    }

    /// The counters and degraded-state reasons, to `/diagnostics`.
    fn log_diagnostics(&self, t_s: f64, counters: &Counters, degraded: u32) {
        if self.log.is_some() {
            self.log(
                Topic::Diagnostics,
                t_s,
                &json!({"t_s": t_s, "counters": counters.snapshot(), "degraded": status::describe(degraded),
                    "reset_counter": self.reset_counter}),
            );
        }
    }

    /// A `foxglove.Log` line (level: 2 info, 3 warning, 4 error).
    pub(super) fn log_text(&self, level: u8, t_s: f64, message: &str) {
        let t = t_s.max(0.0);
        self.log(
            Topic::Log,
            t,
            &json!({"timestamp": {"sec": t.floor() as u64, "nsec": ((t - t.floor()) * 1e9) as u64},
                "level": level, "message": message, "name": "cmsckf", "file": file!(), "line": 0}),
        );
    }

    /// Queues a measurement in time order (bounded; the oldest is dropped).
    pub(super) fn enqueue(&mut self, t: f64, item: Pending, counters: &Counters) {
        if self.pending.len() == PENDING_FRAMES {
            self.pending.pop_front();
            counters.add(Counter::PendingOverflow, 1);
        }
        let at = self.pending.partition_point(|(u, _)| *u <= t);
        self.pending.insert(at, (t, item));
    }

    /// One IMU sample through the filter: the origin to the autopilot once
    /// known, initialisation, the output, then the measurements it covers,
    /// and a health check.
    fn on_imu(&mut self, m: ImuMeas, counters: &Counters, out: &mpsc::Sender<Outbound>) {
        self.send_origin(m.t_s, counters, out);
        let Some(est) = self.est.as_mut() else {
            if !self.restart_in_place(m, counters) {
                self.try_init(m, counters);
            }
            return;
        };
        if est.add_imu(m).is_err() {
            counters.add(Counter::ImuRejected, 1);
        }
        self.emit_output(m, counters, out);
        let zupt_allowed = self.zupt_allowed();
        let Some(est) = self.est.as_mut() else {
            return;
        };
        est.set_zupt_allowed(zupt_allowed);
        self.fuse_covered(m.t_s, counters);
        // Without measurements (camera and GNSS both out) nothing moved the
        // filter on: carry it behind the IMU, so that the covariance in the
        // outputs grows as the error does and the IMU buffer never fills.
        if let Some(est) = self.est.as_mut() {
            if est.time_s() < m.t_s - MAX_FILTER_LAG_S {
                est.propagate_to(m.t_s - MAX_FILTER_LAG_S);
            }
        }
        // Once per IMU sample, after this sample's measurements (a GNSS-only
        // divergence is caught as soon as a vision one).
        let Some(est) = self.est.as_ref() else { return };
        if let Err(why) = est.check_health() {
            counters.add(Counter::FilterReset, 1);
            tracing::error!(reason = %why, "filter unhealthy: resetting");
            self.restart(m.t_s, &why, Restart::Unhealthy, out);
        } else if m.t_s - self.tracker.last_aided_s() < GOOD_AIDED_S {
            // Only an estimate that measurements vouch for: a filter
            // carried on the IMU alone passes its checks however wrong.
            self.good.offer(est, m.t_s);
        }
    }
}
