//! The fusion loop, on its own OS thread, as a router: it takes the inputs
//! in the order they arrive (IMU, camera frames, RTCM, autopilot state) and
//! hands each to the part that owns its state:
//!
//! - `autopilot.rs` ([`AutopilotView`]): what the autopilot says of itself;
//! - `init.rs` ([`Starter`]): starts and restarts of the filter;
//! - `measurements.rs` ([`MeasurementQueue`]): what waits for IMU to cover it;
//! - `output.rs` ([`OutputPacer`]): the estimates sent and `reset_counter`;
//! - `flight_log.rs` ([`FlightLog`]): the log (each input is logged as it
//!   is used, so `cmsckf replay` feeds them back through this same code);
//! - `gnss_input.rs` (`GnssIn`): RTCM to GNSS epochs, the world frame.
//!
//! It keeps the filter itself, the IMU clock and the one restart path
//! (reboot, IMU gap, divergence: [`Fusion::restart`]).

use std::borrow::Cow;
use std::sync::atomic::{AtomicI64, Ordering};
use std::sync::Arc;
use std::time::Instant;

use tokio::sync::mpsc;

use super::autopilot::AutopilotView;
use super::compass::{CompassMean, Pushed, StillSinceStart};
use super::cross_check::VelocityCrossCheck;
use super::flight_log::{FlightLog, Level};
use super::gnss_input::GnssIn;
use super::init::{Start, Starter, Waiting};
use super::measurements::{FuseCtx, MeasurementQueue, Pending};
use super::output::{OutputCtx, OutputPacer};
use super::rebase::{InstallSite, RebaseExec};
use super::time_guard::{TimeGuard, Verdict};
use super::{FusionMsg, Restart, RtcmStream, Shared, MAX_IMU_GAP_S, REBOOT_JUMP_S};
use crate::config::{Config, FeatureClock, GnssSource, YawSource};
use crate::counters::{Counter, Counters};
use crate::estimator::frontend::NormFrame;
use crate::estimator::imu_covariance::velocity_block;
use crate::estimator::{Estimator, ImuMeas};
use crate::io::feature_pipe::FeatureFrame;
use crate::io::mcap_log::input::{FeaturesRecord, ImuRecord, InputRecord, RtcmRecord};
use crate::io::mcap_log::McapLogger;
use crate::io::messages::Outbound;
use crate::status::{self, Degraded, Status};

/// IMU samples in a row that must agree on a jump of their clock (a reboot,
/// or a link that was down) before it is believed.
const IMU_JUMP_CONFIRM: u32 = 5;
/// A camera frame is believed only within this much of the IMU clock:
/// ahead of it (s), and behind it (s; latency and a short IMU stall).
const FRAME_MAX_LEAD_S: f64 = 1.0;
const FRAME_MAX_LAG_S: f64 = 5.0;

/// How far the filter may stay behind the IMU while no measurement moves it
/// on (s): later than this, a frame is late anyway (they arrive within
/// 0.1 s), and GNSS epochs reach back through their clones.
const MAX_FILTER_LAG_S: f64 = 1.0;

/// An estimate counts as good only this soon after a measurement (s).
const GOOD_AIDED_S: f64 = 0.5;

/// The fusion loop: the filter, and the parts that own the rest.
pub struct Fusion {
    cfg: Config,
    est: Option<Estimator>,
    /// Counts estimators started, so a rebase result of a filter since
    /// restarted is recognised and dropped.
    est_gen: u64,
    /// The running filter started with no world origin known, so with no
    /// declination for a compass yaw (see `on_located`).
    started_unlocated: bool,
    /// The origin came after such a start: the filter starts again at the
    /// next sample that finds the vehicle disarmed on the ground.
    located_pending: bool,
    rebase: RebaseExec,
    gnss: GnssIn,
    /// The IMU stream's clock: single bad stamps rejected, jumps confirmed.
    imu_clock: TimeGuard,
    last_imu_t: f64,
    /// Degraded-state reasons, in autopilot time.
    tracker: status::Tracker,
    autopilot: AutopilotView,
    starter: Starter,
    queue: MeasurementQueue,
    pacer: OutputPacer,
    /// Our velocity against the autopilot's own, when it has a fix.
    cross_check: VelocityCrossCheck,
    /// A compass start's running mean while the vehicle stands, and the
    /// attitude it stood at (`on_magnetometer`).
    compass: Option<(CompassMean, StillSinceStart)>,
    /// The barometer's offset `(m, m², s)` a filter restarted in flight
    /// had learned, for the next one (estimator README §3g, B4).
    baro_carry: Option<(f64, f64, f64)>,
    /// The last barometer reading's time (s): one at or before it is a
    /// duplicate or out of order.
    last_baro_t: f64,
    log: FlightLog,
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
    log: Option<&'a McapLogger>,
    t_s: f64,
) -> InstallSite<'a> {
    InstallSite {
        est: est.as_mut(),
        est_gen,
        log,
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
            rebase: RebaseExec::for_config(&cfg),
            est: None,
            est_gen: 0,
            started_unlocated: false,
            located_pending: false,
            gnss: GnssIn::new(&cfg),
            imu_clock: TimeGuard::new(REBOOT_JUMP_S, IMU_JUMP_CONFIRM, cfg.mavlink.clock_jump_confirm_s),
            last_imu_t: f64::NEG_INFINITY,
            tracker: status::Tracker::default(),
            autopilot: AutopilotView::default(),
            starter: Starter::default(),
            queue: MeasurementQueue::default(),
            pacer: OutputPacer::new(&cfg),
            cross_check: VelocityCrossCheck::default(),
            compass: None,
            baro_carry: None,
            last_baro_t: f64::NEG_INFINITY,
            log: FlightLog::new(log, cfg.log.new_log_on_disarm),
            cfg,
        }
    }

    /// Finishes the log (on shutdown: `Drop` would swallow its errors),
    /// counting its messages and raising an alarm for dropped records.
    pub fn finish_log(&mut self, counters: &Counters) {
        self.log.finish(self.last_imu_t, counters, self.pacer.reset_counter());
    }

    /// For `cmsckf replay`: rebases are installed where the log says.
    pub fn for_replay(mut self) -> Self {
        self.rebase = self.rebase.for_replay();
        self
    }

    /// Handles one input, in the order the fusion loop received it (replay
    /// feeds the logged inputs through here in the same order).
    pub fn handle(&mut self, msg: FusionMsg, ctx: &Ctx) {
        let site = install_site(&mut self.est, self.est_gen, self.log.logger(), self.last_imu_t);
        self.rebase.poll(site, &ctx.counters);
        // The world origin can come with any input: the autopilot's
        // GPS_GLOBAL_ORIGIN, or our own receiver's first fix.
        let had_frame = self.gnss.frame().is_some();
        match msg {
            FusionMsg::RebaseInstalled { seq } => {
                let site = install_site(&mut self.est, self.est_gen, self.log.logger(), self.last_imu_t);
                self.rebase.on_installed(seq, site, &ctx.counters);
            }
            FusionMsg::Rtcm { bytes, stream } => self.on_rtcm(&bytes, stream, &ctx.counters),
            FusionMsg::Frame(fr, norm) => self.on_frame(fr, norm, ctx),
            FusionMsg::Imu(m) => self.on_imu(m, ctx),
            // The autopilot's view keeps (and logs) the reading first; the
            // compass averaging then takes it.
            FusionMsg::Magnetometer { mag_B } => {
                self.autopilot.on_message(
                    FusionMsg::Magnetometer { mag_B },
                    self.last_imu_t,
                    &mut self.gnss,
                    &self.log,
                    &ctx.counters,
                );
                self.on_magnetometer(&mag_B, &ctx.counters);
            }
            // Logged whether or not it is fused; fused in time order once
            // IMU covers it (§3g).
            FusionMsg::Pressure(p) => {
                self.autopilot.on_message(
                    FusionMsg::Pressure(p),
                    self.last_imu_t,
                    &mut self.gnss,
                    &self.log,
                    &ctx.counters,
                );
                self.on_pressure(&p, &ctx.counters);
            }
            FusionMsg::AutopilotParam(p) => {
                self.autopilot
                    .on_param(&p, self.last_imu_t, &self.log, &ctx.counters, &ctx.out)
            }
            other => self
                .autopilot
                .on_message(other, self.last_imu_t, &mut self.gnss, &self.log, &ctx.counters),
        }
        if !had_frame && self.gnss.frame().is_some() {
            self.on_located(&ctx.out);
        }
    }

    /// The world frame's origin came after the filter started (the
    /// autopilot's GPS_GLOBAL_ORIGIN, set late by a ground station): a yaw
    /// taken then from the compass, or from the autopilot's own compass
    /// heading, had no declination (ArduPilot's is 0 until it knows where it
    /// is). On the ground a restart takes the compass with the WMM
    /// declination; in the air the yaw is kept, and said to be magnetic.
    fn on_located(&mut self, out: &mpsc::Sender<Outbound>) {
        let i = &self.cfg.init;
        let compass_now = matches!(i.yaw_source, YawSource::Auto | YawSource::Compass)
            && self.autopilot.mag_direction_B().is_some()
            && self.autopilot.unix_days().is_some();
        if self.est.is_none() || !self.started_unlocated || !compass_now {
            return;
        }
        self.started_unlocated = false;
        // Restarted at the next IMU sample that finds the vehicle disarmed
        // on the ground (now, or after the landing).
        self.located_pending = true;
        if !self.autopilot.disarmed_on_ground() {
            let t_s = self.last_imu_t;
            let text =
                "the origin came in flight: our yaw stays magnetic (no declination) until disarmed on the ground";
            tracing::warn!(reason = "yaw_without_declination", "{text}");
            self.log.text(Level::Warning, t_s, text);
            let _ = out.try_send(Outbound::StatusText {
                severity: 4,
                text: "cmsckf: yaw magnetic until landed (origin late)".to_string(),
            });
        }
    }

    /// A barometer reading to fuse (`barometer.fuse`), queued at its time:
    /// one stamped more than [`FRAME_MAX_LAG_S`] behind the IMU or
    /// [`FRAME_MAX_LEAD_S`] ahead of it (another clock) is refused and
    /// counted, as is one whose pressure gives no finite height, and one at
    /// or before the last (a duplicate, or out of order).
    fn on_pressure(&mut self, p: &crate::io::mcap_log::input::PressureRecord, counters: &Counters) {
        if !self.cfg.barometer.fuse || self.est.is_none() {
            return;
        }
        let h_m = cmsckf_models::atmosphere::isa_height_m(p.p_abs_pa);
        let dt_s = p.t_s - self.last_imu_t;
        if !(h_m.is_finite() && dt_s.is_finite() && dt_s < FRAME_MAX_LEAD_S && dt_s > -FRAME_MAX_LAG_S) {
            counters.add(Counter::BaroTimeOff, 1);
            return;
        }
        if p.t_s <= self.last_baro_t {
            counters.add(Counter::BaroOutOfOrder, 1);
            return;
        }
        self.last_baro_t = p.t_s;
        self.queue.enqueue(p.t_s, Pending::Baro(h_m), counters);
    }

    /// RTCM: logged, then each completed epoch's measurements wait in time
    /// order for IMU to cover them.
    fn on_rtcm(&mut self, bytes: &[u8], stream: RtcmStream, counters: &Counters) {
        self.log.input(
            self.last_imu_t,
            &InputRecord::Rtcm(RtcmRecord {
                bytes: Cow::Borrowed(bytes),
                stream,
            }),
        );
        let epochs = self.gnss.on_rtcm(
            bytes,
            stream,
            self.est.as_ref(),
            self.log.logger(),
            counters,
            &mut self.tracker,
        );
        for (t, sats) in epochs {
            self.queue.enqueue(t, Pending::Gnss(sats), counters);
        }
        // The world origin was just placed at a single-point fix: every
        // position in the filter is now off by that fix's error (§7).
        if let (Some(sigma_m), Some(est)) = (self.gnss.take_origin_fix_sigma(), self.est.as_mut()) {
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
        self.log.input(
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
        if t <= self.queue.last_frame_t() {
            ctx.counters.add(Counter::FeatureTimeBackwards, 1);
            tracing::warn!(
                reason = "feature_time_backwards",
                t_s = t,
                prev_s = self.queue.last_frame_t(),
                "frame rejected"
            );
            return;
        }
        self.queue.push_frame(t, norm, &ctx.counters);
    }

    /// An IMU sample: logged as it came (so that replay judges it the same
    /// way), then its time judged by [`TimeGuard`]. A confirmed jump back
    /// is a reboot and one forward past `MAX_IMU_GAP_S` a gap: either
    /// restarts the filter. Then the sample is fused, and the status and
    /// diagnostics follow it.
    fn on_imu(&mut self, m: ImuMeas, ctx: &Ctx) {
        self.log.input(
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
            self.tracker.hold_reason(Degraded::ImuGap, m.t_s);
            if m.t_s - self.last_imu_t > 0.5 {
                ctx.counters.add(Counter::ImuGap, 1);
                tracing::warn!(reason = "imu_gap", gap_s = m.t_s - self.last_imu_t, "IMU gap");
            }
        }
        self.last_imu_t = m.t_s;
        ctx.counters.add(Counter::ImuSamples, 1);
        self.starter.push_imu(m);
        self.fuse_imu(m, &ctx.counters, &ctx.out);
        let st = &ctx.status;
        // An unhealthy filter was restarted in `fuse_imu`: a running filter
        // is a healthy one.
        st.initialised.store(self.est.is_some(), Ordering::Relaxed);
        st.last_imu_wall_ms
            .store(ctx.start.elapsed().as_millis() as u64, Ordering::Relaxed);
        self.tracker.update(m.t_s, self.est.is_some(), &ctx.counters, st);
        self.log
            .diagnostics_if_due(m.t_s, &ctx.counters, st.degraded(), self.pacer.reset_counter());
    }

    /// One IMU sample through the filter: the origin to the autopilot once
    /// known, a start when none runs, the output, then the measurements it
    /// covers, and a health check.
    fn fuse_imu(&mut self, m: ImuMeas, counters: &Counters, out: &mpsc::Sender<Outbound>) {
        if self.cfg.output.set_gps_origin && self.gnss.frame().is_some() {
            self.autopilot
                .send_origin(m.t_s, self.gnss.frame(), &self.log, counters, out);
        } else {
            // No origin yet: the autopilot's is asked for from the first
            // IMU sample on (a compass start waits for it), and its absence
            // said unless one of ours is coming (our own receiver's first
            // fix gives one, sent with `output.set_gps_origin`).
            let ours_coming = self.cfg.output.set_gps_origin && self.cfg.gnss.source != GnssSource::Off;
            self.autopilot
                .watch_origin(m.t_s, !ours_coming, &self.log, counters, out);
        }
        self.autopilot.poll_params(m.t_s, &self.log, counters, out);
        if self.located_pending && self.autopilot.disarmed_on_ground() {
            self.located_pending = false;
            counters.add(Counter::RestartLocated, 1);
            self.restart(
                m.t_s,
                "the origin came: yaw again, with the compass's declination",
                Restart::Located,
                out,
            );
        }
        let Some(est) = self.est.as_mut() else {
            match self
                .starter
                .start_filter(m, &self.cfg, &self.autopilot, self.gnss.frame(), counters)
            {
                Ok(start) => self.install_filter(start, m.t_s, counters),
                Err(why) => self.say_waiting(why, m.t_s, counters, out),
            }
            return;
        };
        if est.add_imu(m).is_err() {
            counters.add(Counter::ImuRejected, 1);
        }
        let cx = OutputCtx {
            cfg: &self.cfg,
            autopilot: self.autopilot.kind(),
            heading_ours_alone: self.autopilot.heading_ours_alone(),
            tracker: &self.tracker,
            frame: self.gnss.frame(),
            log: self.log.logger(),
        };
        self.pacer.emit(m, est, cx, counters, out);
        est.set_zupt_allowed(self.autopilot.zupt_allowed(m.t_s));
        let cx = FuseCtx {
            rebase: &mut self.rebase,
            est_gen: self.est_gen,
            tracker: &mut self.tracker,
            log: self.log.logger(),
            frame: self.gnss.frame(),
            counters,
            base: self.gnss.base_use_mut(),
        };
        let fused = self.queue.fuse_covered(m.t_s, est, cx);
        if fused.camera_moved && self.autopilot.camera_moved(m.t_s) {
            self.log.text(
                Level::Info,
                m.t_s,
                "take-off: the camera sees motion; the zero-velocity updates kept through the spin-up end",
            );
        }
        // Without measurements (camera and GNSS both out) nothing moved the
        // filter on: carry it behind the IMU, so that the covariance in the
        // outputs grows as the error does and the IMU buffer never fills.
        if est.time_s() < m.t_s - MAX_FILTER_LAG_S {
            est.propagate_to(m.t_s - MAX_FILTER_LAG_S);
        }
        // Once per IMU sample, after this sample's measurements (a GNSS-only
        // divergence is caught as soon as a vision one); then our velocity
        // against the autopilot's own, when it has a fix (D4).
        let health = est.check_health().and_then(|()| {
            let autopilot_v = (self.autopilot.has_own_position(m.t_s))
                .then(|| self.autopilot.local())
                .flatten()
                .map(|(_, v, t)| (v, t));
            self.cross_check.judge(m.t_s, autopilot_v, || {
                (est.imu_state().v_B_in_W, velocity_block(&est.imu_covariance()))
            })
        });
        if let Err(why) = health {
            counters.add(Counter::FilterReset, 1);
            tracing::error!(reason = %why, "filter unhealthy: resetting");
            self.restart(m.t_s, &why, Restart::Unhealthy, out);
        } else if m.t_s - self.tracker.last_aided_s() < GOOD_AIDED_S {
            // Only an estimate that measurements vouch for: a filter
            // carried on the IMU alone passes its checks however wrong.
            self.starter.offer_good(est, m.t_s);
        }
    }

    /// No filter can start yet: says why, at once and then every few seconds
    /// while it lasts (a STATUSTEXT to the autopilot, a `/log` line, the
    /// journal and `init_waiting`); the HEARTBEAT stays STANDBY meanwhile.
    fn say_waiting(&mut self, why: Waiting, t_s: f64, counters: &Counters, out: &mpsc::Sender<Outbound>) {
        if !self.starter.report_waiting(why, t_s) {
            return;
        }
        counters.add(Counter::InitWaiting, 1);
        tracing::warn!(reason = ?why, "{}", why.text());
        self.log.text(Level::Warning, t_s, why.text());
        let _ = out.try_send(Outbound::StatusText {
            severity: 4,
            text: format!("cmsckf {}", why.text()),
        });
    }

    /// `start`'s filter becomes the running one at the IMU sample time `t_s`.
    fn install_filter(&mut self, start: Start, t_s: f64, counters: &Counters) {
        let Start {
            mut est,
            is_static,
            compass,
        } = start;
        // Not in Schmidt mode, whose keyframes take no corrections (§6).
        self.compass = compass
            .filter(|_| est.mode() != crate::estimator::Mode::Schmidt)
            .map(|c| (c, StillSinceStart::new(&est.imu_state().q_W_B)));
        est.set_async_rebase(!matches!(self.rebase, RebaseExec::Inline));
        if let Some((b, var, t0)) = self.baro_carry.take() {
            // What the offset walked while no filter held it.
            let walk = self.cfg.barometer.offset_rw_m_per_sqrt_s.powi(2) * (t_s - t0).max(0.0);
            est.carry_baro_offset(b, var + walk);
        }
        self.est_gen += 1;
        self.est = Some(est);
        self.started_unlocated = self.gnss.frame().is_none();
        self.located_pending = false;
        self.tracker.filter_started(t_s);
        self.queue.drop_before(t_s);
        counters.add(
            if is_static {
                Counter::InitStatic
            } else {
                Counter::InitInFlight
            },
            1,
        );
        self.log.text(
            Level::Info,
            t_s,
            if is_static {
                "filter initialised (static start)"
            } else {
                "filter initialised in flight"
            },
        );
        tracing::info!(static_start = is_static, t_s, "filter initialised");
        self.start_compass_mean(t_s);
    }

    /// A magnetometer reading while the vehicle stands disarmed on the
    /// ground since a compass start: the mean's noise averages down, and
    /// the filter's yaw is conditioned on each better mean (estimator
    /// README eq. H1, `compass.rs`). Arming, leaving the ground, a tilt or
    /// a turn (the filter's attitude against the start's), or a run of
    /// readings far off the mean ends it for this filter; an autopilot that
    /// has not yet said whether it is armed holds it.
    fn on_magnetometer(&mut self, mag_B: &nalgebra::Vector3<f64>, counters: &Counters) {
        let (Some((mean, still)), Some(est)) = (self.compass.as_mut(), self.est.as_mut()) else {
            return;
        };
        if self.autopilot.armed().is_none() {
            return;
        }
        let t_s = self.last_imu_t;
        let q = est.predict(t_s).q_W_B;
        let why = if !self.autopilot.disarmed_on_ground() {
            Some("armed or off the ground".to_string())
        } else if let Some(moved) = still.moved(&q) {
            Some(moved.to_string())
        } else {
            let outliers = mean.outliers;
            let pushed = mean.push(t_s, mag_B);
            counters.add(Counter::CompassOutlier, u64::from(mean.outliers - outliers));
            match pushed {
                Pushed::Nothing => None,
                Pushed::End(why) => Some(why),
                Pushed::Step(step) => match est.condition_yaw_on_compass(step.shift_rad, step.drop_rad2) {
                    Ok(()) => {
                        let yaw_after = est.predict(t_s).q_W_B.euler_angles().2;
                        still.yaw_moved_by(yaw_after - q.euler_angles().2);
                        mean.held(step);
                        counters.add(Counter::CompassYawConditioned, 1);
                        None
                    }
                    Err(e) => Some(e.to_string()),
                },
            }
        };
        if let Some(why) = why {
            self.end_compass_mean(t_s, &why);
        }
    }

    /// Says in the log where a compass start's yaw came from, and that
    /// readings while the vehicle stands will refine it.
    fn start_compass_mean(&mut self, t_s: f64) {
        let (Some((mean, _)), Some(est)) = (self.compass.as_ref(), self.est.as_ref()) else {
            return;
        };
        let text = format!(
            "compass: the start's yaw {:.2}° (σ {:.2}°) is the mean of {} readings, one scattering by {:.2}°; \
             readings while the vehicle stands still and disarmed refine it",
            mean.start_yaw_rad.to_degrees(),
            est.imu_covariance()[(2, 2)].sqrt().to_degrees(),
            mean.readings().0,
            mean.reading_sigma_rad().to_degrees(),
        );
        tracing::info!("{text}");
        self.log.text(Level::Info, t_s, &text);
    }

    /// Ends the compass averaging (if any) and says in the log what it did.
    fn end_compass_mean(&mut self, t_s: f64, why: &str) {
        let Some((mean, _)) = self.compass.take() else {
            return;
        };
        let (averaged, held) = mean.readings();
        let sigma = self
            .est
            .as_ref()
            .map_or(f64::NAN, |e| e.imu_covariance()[(2, 2)].sqrt().to_degrees());
        let text = format!(
            "compass: the yaw holds the mean of {held} readings ({averaged} averaged, one scattering by {:.2}°, \
             {} refused): {} steps moved it {:+.2}° from the start's (the mean's noise σ {:.2}° → {:.2}°; the \
             yaw's σ now {sigma:.2}°); averaging ended: {why}",
            mean.reading_sigma_rad().to_degrees(),
            mean.outliers,
            mean.steps,
            mean.shifted_rad.to_degrees(),
            mean.start_var_rad2.sqrt().to_degrees(),
            mean.held_noise_var_rad2().sqrt().to_degrees(),
        );
        tracing::info!(held, averaged, "{text}");
        self.log.text(Level::Info, t_s, &text);
    }

    /// Drops the filter so that the next IMU sample starts a fresh one (the
    /// one reset path): `reset_counter` moves on, the autopilot gets a
    /// `STATUSTEXT`, the log a `/log` line, and the status shows
    /// `filter_reset` for 2 s. Where the next filter starts is the
    /// [`Starter`]'s (`plan_restart`). After a reboot or a long IMU gap the
    /// autopilot's attitude and position are stale and are dropped (and,
    /// after a reboot, SYSTEM_TIME must map GPS time again and every clock
    /// starts over).
    fn restart(&mut self, t_s: f64, why: &str, kind: Restart, out: &mpsc::Sender<Outbound>) {
        self.log.text(Level::Error, t_s, &format!("filter reset: {why}"));
        let _ = out.try_send(Outbound::StatusText {
            severity: if kind == Restart::Unhealthy { 2 } else { 4 },
            text: format!("cmsckf reset: {why}"),
        });
        self.end_compass_mean(t_s, "the filter restarted");
        // The barometer's offset is the sensor's: kept through a restart in
        // the same world frame and clock (not a reboot's, not a new origin's).
        self.baro_carry = match kind {
            Restart::Reboot | Restart::Located => None,
            Restart::Gap | Restart::Unhealthy => self
                .est
                .as_ref()
                .and_then(|e| e.baro_offset())
                .map(|(b, var)| (b, var, t_s)),
        };
        self.est = None;
        self.cross_check.reset();
        self.starter.plan_restart(t_s, kind, &self.cfg, &self.autopilot);
        self.autopilot.forget_for_restart(kind);
        self.pacer.on_reset();
        if kind == Restart::Reboot {
            self.tracker.restart_clock();
            self.gnss.set_unix_minus_boot(None);
            self.queue.clear();
            self.pacer.restart_clock();
            self.last_imu_t = f64::NEG_INFINITY;
            self.last_baro_t = f64::NEG_INFINITY;
        }
        self.tracker.hold_reason(Degraded::FilterReset, t_s);
    }
}
