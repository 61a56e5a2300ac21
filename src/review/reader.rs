//! Reading a flight log for the review: one pass over its messages in file
//! order, counting into the [`ReviewSummary`] and keeping, in [`Data`], the
//! series the statistics and the plots need.

use std::collections::BTreeMap;

use serde_json::Value;

use super::timeline::{plausible, Timeline};
use super::ReviewSummary;
use crate::io::mcap_log::input::{AutopilotRecord, InputRecord, SimStateRecord};
use crate::io::mcap_log::Topic;
use crate::io::messages::AutopilotKind;

/// Why a log without truth has no error figure.
pub(super) const NO_REFERENCE_ECHO: &str =
    "none: the log has no truth, and the autopilot's position is fed by our own estimates (an echo, not a reference)";

/// The series kept from the log (times in s of log time).
#[derive(Default)]
pub(super) struct Data {
    pub track: Vec<(f64, f64, f64, [f64; 4], f64)>, // t, n, e, q(wxyz), d
    pub kf_pos: Vec<(f64, f64)>,
    /// The autopilot's local position: `t, n, e, d`. Beside an autopilot
    /// that fuses our output it is largely our own estimate again.
    pub autopilot: Vec<(f64, [f64; 3])>,
    /// A simulator's truth (`SIM_STATE`) in our world frame: `t, n, e, d`.
    pub truth: Vec<(f64, [f64; 3])>,
    /// The autopilot's barometer as the standard atmosphere's height:
    /// `t, h` (m; [`cmsckf_models::atmosphere::isa_height_m`]).
    pub baro: Vec<(f64, f64)>,
    /// The estimate's position σ (north, east, down; m) at each
    /// `/filter/state` record: `t, σ`.
    pub sigma_p: Vec<(f64, [f64; 3])>,
    /// The GNSS single-point fixes in the estimate's NED frame (north,
    /// east), placed through the world origin that `/location` and
    /// `/filter/state` give together ([`Data::place_fixes`]).
    pub fixes_ne: Vec<(f64, f64)>,
    /// `/gnss/fix` as ECEF (m), until the origin is known.
    fixes_ecef: Vec<nalgebra::Vector3<f64>>,
    /// The world origin (ECEF, m) and its NED rotation, from the first
    /// `/location` record at the time of a `/filter/state` record.
    origin: Option<cmsckf_models::geodesy::NedFrame>,
    pub kf_sigma: BTreeMap<u64, Vec<(f64, f64)>>,
    pub vision_t: Vec<f64>,
    pub gnss_t: Vec<f64>,
    pub global_t: Vec<f64>,
    pub nis: Vec<(f64, f64, usize)>,
    pub elapsed: Vec<f64>,
    /// Estimates we sent the autopilot (`/output/...` records).
    pub estimates_sent: u64,
    /// The autopilot EKF's position test ratios of our estimates:
    /// `t, horizontal, vertical` (over 1: rejected).
    pub autopilot_ratios: Vec<(f64, f64, f64)>,
    /// What we sent: `t, quality, speed (m/s)`.
    pub sent: Vec<(f64, f64, f64)>,
    /// The position σ (north, east, down; m) the autopilot read from what we
    /// sent, at each `/output/...` record ([`sent_position_sigma`]): `t, σ`.
    pub sent_sigma_p: Vec<(f64, [f64; 3])>,
    /// GNSS epochs fused: `t, code residual RMS (m), range-rate residual RMS
    /// (m/s)` before the update (NaN when none).
    pub gnss_residuals: Vec<(f64, f64, f64)>,
    /// The flight's events, in log order.
    pub events: Vec<Event>,
    /// The degraded reasons and reset counter of the last `/diagnostics`,
    /// and its time.
    last_degraded: Option<(String, u64)>,
    last_diagnostics_t: Option<f64>,
    /// Seconds spent degraded, by reason (`ReviewSummary::degraded_s`).
    pub degraded_s: BTreeMap<String, f64>,
    /// Whether the last autopilot report rejected us.
    rejected_by_autopilot: bool,
    /// Which autopilot it is (its mode numbers are named).
    autopilot_kind: Option<AutopilotKind>,
    /// The timeline row of a mode logged before the autopilot's kind (as
    /// logs before the daemon logged the kind first have it), and its
    /// number: named once the kind is known.
    unnamed_mode: Option<(usize, u32)>,
}

/// ArduCopter's flight mode names (its `custom_mode` numbers).
fn copter_mode(m: u32) -> Option<&'static str> {
    Some(match m {
        0 => "STABILIZE",
        1 => "ACRO",
        2 => "ALT_HOLD",
        3 => "AUTO",
        4 => "GUIDED",
        5 => "LOITER",
        6 => "RTL",
        7 => "CIRCLE",
        9 => "LAND",
        11 => "DRIFT",
        13 => "SPORT",
        15 => "AUTOTUNE",
        16 => "POSHOLD",
        17 => "BRAKE",
        20 => "GUIDED_NOGPS",
        21 => "SMART_RTL",
        _ => return None,
    })
}

/// PX4's flight mode names: its `custom_mode` holds the main mode in bits
/// 16-23 and, in AUTO, the sub-mode in bits 24-31 (`px4_custom_mode.h`).
fn px4_mode(m: u32) -> Option<&'static str> {
    let (main, sub) = ((m >> 16) & 0xff, m >> 24);
    Some(match (main, sub) {
        (1, _) => "MANUAL",
        (2, _) => "ALTCTL",
        (3, _) => "POSCTL",
        (4, 1) => "AUTO.READY",
        (4, 2) => "AUTO.TAKEOFF",
        (4, 3) => "AUTO.LOITER",
        (4, 4) => "AUTO.MISSION",
        (4, 5) => "AUTO.RTL",
        (4, 6) => "AUTO.LAND",
        (4, 8) => "AUTO.FOLLOW_TARGET",
        (4, 9) => "AUTO.PRECLAND",
        (5, _) => "ACRO",
        (6, _) => "OFFBOARD",
        (7, _) => "STABILIZED",
        _ => return None,
    })
}

/// A mode change's timeline text: its name by the autopilot's numbering,
/// and the number as that autopilot writes it.
fn mode_text(kind: Option<AutopilotKind>, m: u32) -> String {
    match kind {
        Some(AutopilotKind::ArduPilot) => match copter_mode(m) {
            Some(n) => format!("mode {n} ({m})"),
            None => format!("mode {m}"),
        },
        Some(AutopilotKind::Px4) => match px4_mode(m) {
            Some(n) => format!("mode {n} ({m:#x})"),
            None => format!("mode {m:#x}"),
        },
        _ => format!("mode {m}"),
    }
}

/// The position σ (north, east, down; m) an autopilot reads from the 21
/// pose covariance entries we sent (`pose_covariance_sent`): ArduPilot
/// reduces them to one σ, `cbrt(c₀² + c₆² + c₁₁²)` (estimator README eq.
/// O1, as its releases to 4.6 do), any other autopilot reads the variances
/// `c₀, c₆, c₁₁`, before floors of its own (PX4's `EKF2_EVP_NOISE`). With
/// `output.position_covariance = "given_yaw"`, or `"auto"` towards a PX4
/// whose parameters say its heading is ours alone, they are the position's
/// given our yaw (eq. O2), smaller than the filter's own σ. `None` for a log
/// without them, or entries not finite and non-negative.
fn sent_position_sigma(c: &Value, kind: Option<AutopilotKind>) -> Option<[f64; 3]> {
    let [c0, c6, c11] = [0, 6, 11].map(|k| c[k].as_f64().unwrap_or(f64::NAN));
    if ![c0, c6, c11].iter().all(|x| x.is_finite() && *x >= 0.0) {
        return None;
    }
    Some(if kind == Some(AutopilotKind::ArduPilot) {
        [(c0 * c0 + c6 * c6 + c11 * c11).cbrt(); 3]
    } else {
        [c0.sqrt(), c6.sqrt(), c11.sqrt()]
    })
}

/// What kind of event a timeline row is (its filter in the report).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum EventKind {
    /// The filter started or restarted.
    Filter,
    /// The daemon's degraded reasons changed (its HEARTBEAT and STATUSTEXT).
    Degraded,
    /// Arming, disarming, landed state, the autopilot's kind.
    Vehicle,
    /// The autopilot's EKF began or stopped rejecting our position.
    Autopilot,
    /// A `STATUSTEXT` the autopilot sent.
    AutopilotText,
    /// Another line of the daemon's `/log`.
    Log,
}

impl EventKind {
    pub(super) fn name(self) -> &'static str {
        match self {
            EventKind::Filter => "filter",
            EventKind::Degraded => "degraded",
            EventKind::Vehicle => "vehicle",
            EventKind::Autopilot => "autopilot",
            EventKind::AutopilotText => "autopilot says",
            EventKind::Log => "log",
        }
    }
}

/// One row of the timeline.
#[derive(Clone, Debug)]
pub(super) struct Event {
    pub t: f64,
    pub kind: EventKind,
    pub text: String,
}

/// The review's state while it reads the log.
pub(super) struct LogReader {
    pub s: ReviewSummary,
    pub d: Data,
    /// Messages per topic.
    counts: BTreeMap<String, u64>,
    /// The log times' segments: the duration, and which times are plausible.
    timeline: Timeline,
}

impl LogReader {
    pub fn new() -> Self {
        Self {
            s: ReviewSummary::default(),
            d: Data::default(),
            counts: BTreeMap::new(),
            timeline: Timeline::default(),
        }
    }

    /// Counts one message and keeps what it carries.
    pub fn on_message(&mut self, m: &mcap::Message) {
        self.s.messages += 1;
        // The autopilot's boot time (the publish time; the log time is Unix
        // time once SYSTEM_TIME gave it).
        let t = m.publish_time as f64 * 1e-9;
        self.timeline.push(m.publish_time);
        *self.counts.entry(m.channel.topic.clone()).or_default() += 1;
        let Some(topic) = Topic::from_name(&m.channel.topic) else {
            return;
        };
        let (s, d) = (&mut self.s, &mut self.d);
        if topic == Topic::InputAutopilot {
            // A typed input record: the autopilot's position, or the truth.
            match InputRecord::parse(topic, &m.data) {
                Ok(InputRecord::Autopilot(AutopilotRecord::LocalPosition(l))) => d.autopilot.push((t, l.p_ned_m)),
                // At the reading's own time (the autopilot's boot clock, as
                // the log time); one stamped far from its arrival (a clock
                // that restarted between them) is not placed.
                Ok(InputRecord::Autopilot(AutopilotRecord::Pressure(p))) if (p.t_s - t).abs() < 1.0 => d
                    .baro
                    .push((p.t_s, cmsckf_models::atmosphere::isa_height_m(p.p_abs_pa))),
                Ok(InputRecord::Autopilot(AutopilotRecord::Param(p))) => {
                    s.autopilot_params.insert(p.name, p.value);
                }
                Ok(InputRecord::Autopilot(AutopilotRecord::SimState(SimStateRecord { p_ned_m: Some(p), .. }))) => {
                    d.truth.push((t, p))
                }
                Ok(InputRecord::Autopilot(AutopilotRecord::EstimatorStatus(e))) => {
                    d.autopilot_ratios.push((t, e.pos_horiz_ratio, e.pos_vert_ratio));
                    let rejected = e.pos_horiz_ratio > 1.0 || e.pos_vert_ratio > 1.0;
                    if rejected != d.rejected_by_autopilot {
                        d.rejected_by_autopilot = rejected;
                        d.event(
                            t,
                            EventKind::Autopilot,
                            if rejected {
                                format!(
                                    "the autopilot's EKF rejects our position (test ratios {:.2} horizontal, {:.2} vertical)",
                                    e.pos_horiz_ratio, e.pos_vert_ratio
                                )
                            } else {
                                "the autopilot's EKF takes our position again".to_string()
                            },
                        );
                    }
                }
                Ok(InputRecord::Autopilot(AutopilotRecord::Armed(a))) => {
                    d.event(t, EventKind::Vehicle, if a { "armed" } else { "disarmed" }.into())
                }
                Ok(InputRecord::Autopilot(AutopilotRecord::OnGround(g))) => d.event(
                    t,
                    EventKind::Vehicle,
                    if g { "on the ground" } else { "in the air" }.into(),
                ),
                Ok(InputRecord::Autopilot(AutopilotRecord::Autopilot(k))) => {
                    d.autopilot_kind = Some(k);
                    if let Some((row, m)) = d.unnamed_mode.take() {
                        if let Some(e) = d.events.get_mut(row) {
                            e.text = mode_text(Some(k), m);
                        }
                    }
                    d.event(t, EventKind::Vehicle, format!("autopilot: {k:?}"))
                }
                Ok(InputRecord::Autopilot(AutopilotRecord::Mode(m))) => {
                    if d.autopilot_kind.is_none() {
                        d.unnamed_mode = Some((d.events.len(), m));
                    }
                    let text = mode_text(d.autopilot_kind, m);
                    d.event(t, EventKind::Vehicle, text)
                }
                Ok(InputRecord::Autopilot(AutopilotRecord::StatusText(s))) => d.event(
                    t,
                    EventKind::AutopilotText,
                    format!("autopilot says (severity {}): {}", s.severity, s.text),
                ),
                _ => {}
            }
            return;
        }
        let Ok(v) = serde_json::from_slice::<Value>(&m.data) else {
            return;
        };
        match topic {
            Topic::FilterState => d.push_state(t, &v),
            Topic::FilterKeyframes => {
                d.push_keyframe(&v);
                s.keyframes += 1;
            }
            Topic::FilterVision => on_vision_update(s, d, t, &v),
            Topic::FilterGnss => {
                s.gnss_updates += 1;
                d.gnss_t.push(t);
                d.push_sigmas(t, &v);
                d.push_gnss_residuals(t, &v);
            }
            Topic::Log => {
                let text = v["message"].as_str().unwrap_or_default().to_string();
                let kind = if text.starts_with("filter") || text.contains("initialis") || text.contains("started") {
                    EventKind::Filter
                } else {
                    EventKind::Log
                };
                d.event(t, kind, text);
            }
            Topic::FilterGlobal => {
                if v["reason"] == "Promotion" {
                    s.promotions += 1;
                } else {
                    s.global_updates += 1;
                    d.global_t.push(t);
                }
            }
            Topic::OutputVpe => {
                s.estimates += 1;
                d.estimates_sent += 1;
                let q = v["quality"].as_f64().unwrap_or(f64::NAN);
                let speed = v["v_ned_mps"].as_array().map_or(f64::NAN, |a| {
                    a.iter().filter_map(Value::as_f64).map(|x| x * x).sum::<f64>().sqrt()
                });
                d.sent.push((t, q, speed));
                if let Some(sigma) = sent_position_sigma(&v["pose_covariance_sent"], d.autopilot_kind) {
                    d.sent_sigma_p.push((t, sigma));
                }
            }
            Topic::Location => d.push_location(t, &v),
            Topic::GnssFix => d.push_fix(&v),
            Topic::Diagnostics => {
                // The last record holds every counter at its latest.
                if let Some(c) = v["counters"].as_object() {
                    s.counters = c.iter().filter_map(|(k, n)| Some((k.clone(), n.as_u64()?))).collect();
                }
                d.push_diagnostics(t, &v);
            }
            _ => {}
        }
    }

    /// The summary so far with the log's duration and input rates, and the
    /// series at plausible times (see `timeline.rs`).
    pub fn finish(self) -> (ReviewSummary, Data) {
        let Self {
            mut s,
            mut d,
            counts,
            timeline,
        } = self;
        s.duration_s = timeline.duration_s();
        s.resets = d.last_degraded.as_ref().map_or(0, |l| l.1);
        s.degraded_s = d.degraded_s.clone();
        d.keep_plausible(timeline.plausible_spans_s().as_deref());
        d.place_fixes();
        for (k, n) in &counts {
            if Topic::from_name(k).is_some_and(Topic::is_input) && s.duration_s > 0.0 {
                s.input_rates_hz.insert(k.clone(), *n as f64 / s.duration_s);
            }
        }
        (s, d)
    }
}

/// A `/filter/update/vision` record: counts, rejections, NIS, timing and σ.
fn on_vision_update(s: &mut ReviewSummary, d: &mut Data, t: f64, v: &Value) {
    s.vision_updates += 1;
    s.tracks_used += v["tracks_used"].as_u64().unwrap_or(0);
    if let Some(r) = v["rejected"].as_object() {
        for (k, n) in r {
            *s.rejected.entry(k.clone()).or_default() += n.as_u64().unwrap_or(0);
        }
    }
    if let Some(a) = v["nis"].as_array() {
        for e in a {
            if let (Some(nis), Some(dof)) = (e[0].as_f64(), e[1].as_u64()) {
                d.nis.push((t, nis, dof as usize));
            }
        }
    }
    if let Some(us) = v["elapsed_us"].as_f64() {
        d.elapsed.push(us);
    }
    if v["tracks_used"].as_u64().unwrap_or(0) > 0 {
        d.vision_t.push(t);
    }
    d.push_sigmas(t, v);
}

impl Data {
    /// Drops the points whose time is not plausible (a far-future or stray
    /// stamp), so that they neither stretch a plot's time axis nor reach the
    /// TUM file. The counts are not changed.
    fn keep_plausible(&mut self, spans: Option<&[(f64, f64)]>) {
        if spans.is_none() {
            return;
        }
        let ok = |t: f64| plausible(spans, t);
        self.track.retain(|p| ok(p.0));
        self.sigma_p.retain(|p| ok(p.0));
        self.autopilot.retain(|p| ok(p.0));
        self.truth.retain(|p| ok(p.0));
        self.baro.retain(|p| ok(p.0));
        self.autopilot_ratios.retain(|p| ok(p.0));
        self.sent.retain(|p| ok(p.0));
        self.sent_sigma_p.retain(|p| ok(p.0));
        self.gnss_residuals.retain(|p| ok(p.0));
        self.events.retain(|e| ok(e.t));
        for v in self.kf_sigma.values_mut() {
            v.retain(|p| ok(p.0));
        }
        self.kf_sigma.retain(|_, v| !v.is_empty());
        self.vision_t.retain(|t| ok(*t));
        self.gnss_t.retain(|t| ok(*t));
        self.global_t.retain(|t| ok(*t));
        self.nis.retain(|p| ok(p.0));
    }

    /// A `/filter/state` record: the pose (NaN where a value is missing)
    /// and the position σ (from the covariance's diagonal, `p` at 6..9).
    fn push_state(&mut self, t: f64, v: &Value) {
        let p = &v["p_B_in_W"];
        let q = &v["q_W_B_wxyz"];
        let f = |x: &Value| x.as_f64().unwrap_or(f64::NAN);
        self.track.push((
            t,
            f(&p[0]),
            f(&p[1]),
            [f(&q[0]), f(&q[1]), f(&q[2]), f(&q[3])],
            f(&p[2]),
        ));
        let c = &v["cov_diag"];
        if c.is_array() {
            self.sigma_p.push((t, [6, 7, 8].map(|k| f(&c[k]).max(0.0).sqrt())));
        }
    }

    /// A `/filter/keyframes` record: the keyframe's north and east.
    fn push_keyframe(&mut self, v: &Value) {
        let p = &v["p_B_in_W"];
        self.kf_pos
            .push((p[0].as_f64().unwrap_or(0.0), p[1].as_f64().unwrap_or(0.0)));
    }

    /// An update's `keyframe_sigma_m`: `[id, σ]` pairs.
    /// A timeline row (bounded: a log that says the same thing a million
    /// times must not fill the page).
    fn event(&mut self, t: f64, kind: EventKind, text: String) {
        const MAX_EVENTS: usize = 2000;
        if self.events.len() < MAX_EVENTS {
            self.events.push(Event { t, kind, text });
        }
    }

    /// A change of the degraded reasons or of the reset counter.
    fn push_diagnostics(&mut self, t: f64, v: &Value) {
        let degraded = v["degraded"].as_str().unwrap_or_default().to_string();
        let resets = v["reset_counter"].as_u64().unwrap_or(0);
        let before = self.last_degraded.replace((degraded.clone(), resets));
        let (was, was_resets) = before.unwrap_or_default();
        // Each record's reasons hold until the next record (once a second);
        // a gap of over 10 s is the log's, not a state's, as in the
        // duration (`timeline.rs`), and a clock that went back starts anew.
        if let Some(dt) = self
            .last_diagnostics_t
            .map(|t0| t - t0)
            .filter(|dt| *dt > 0.0 && *dt <= 10.0)
        {
            for reason in was.split(',').map(str::trim).filter(|r| !r.is_empty()) {
                *self.degraded_s.entry(reason.to_string()).or_default() += dt;
            }
        }
        self.last_diagnostics_t = Some(t);
        if degraded != was {
            let text = if degraded.is_empty() {
                "nominal".to_string()
            } else {
                format!("degraded: {degraded}")
            };
            self.event(t, EventKind::Degraded, text);
        }
        if resets != was_resets && (resets > 0 || was_resets > 0) {
            self.event(t, EventKind::Filter, format!("reset counter {was_resets} → {resets}"));
        }
    }

    /// The RMS of an epoch's code and range-rate residuals.
    fn push_gnss_residuals(&mut self, t: f64, v: &Value) {
        let Some(a) = v["residuals"].as_array() else { return };
        let rms = |k: usize| {
            let x: Vec<f64> = a.iter().filter_map(|r| r[k].as_f64()).collect();
            if x.is_empty() {
                f64::NAN
            } else {
                (x.iter().map(|e| e * e).sum::<f64>() / x.len() as f64).sqrt()
            }
        };
        self.gnss_residuals.push((t, rms(1), rms(2)));
    }

    fn push_sigmas(&mut self, t: f64, v: &Value) {
        if let Some(a) = v["keyframe_sigma_m"].as_array() {
            for e in a {
                if let (Some(id), Some(s)) = (e[0].as_u64(), e[1].as_f64()) {
                    self.kf_sigma.entry(id).or_default().push((t, s));
                }
            }
        }
    }

    /// The reference the error is measured against, with its name: the
    /// simulator's truth when the log has it. Else the autopilot's local
    /// position, but only when we sent the autopilot nothing: fed our
    /// estimates (external navigation), its position is an echo of our own,
    /// and an error against it would flatter us (a replay's 0.20 m against
    /// the autopilot was 0.78 m against the truth). Then there is none.
    pub fn reference(&self) -> (&[(f64, [f64; 3])], &'static str) {
        if !self.truth.is_empty() {
            (&self.truth, "the truth (SIM_STATE)")
        } else if self.estimates_sent == 0 {
            (&self.autopilot, "the autopilot's local position (we sent it nothing)")
        } else {
            (&[], NO_REFERENCE_ECHO)
        }
    }

    /// A `/location` record: the fused estimate through the world origin
    /// `o` (`r = o + R_en(o) p`). Paired with the `/filter/state` record of
    /// the same time, it gives `o = r − R_en(o) p`, solved by fixed point
    /// (`R_en` at `r` first; twice is exact to well under a millimetre for
    /// a flight of kilometres).
    fn push_location(&mut self, t: f64, v: &Value) {
        use cmsckf_models::geodesy::NedFrame;
        if self.origin.is_some() {
            return;
        }
        let Some(&(ts, n, e, _, d)) = self.track.last() else {
            return;
        };
        let Some(r) = location_ecef(v) else {
            return;
        };
        let p = nalgebra::Vector3::new(n, e, d);
        if ts != t || !p.iter().all(|x| x.is_finite()) {
            return;
        }
        let mut frame = NedFrame::from_ecef(&r);
        for _ in 0..2 {
            frame = NedFrame::from_ecef(&(r - frame.R_ecef_ned * p));
        }
        self.origin = Some(frame);
    }

    /// A `/gnss/fix` record, kept as ECEF until the origin is known.
    fn push_fix(&mut self, v: &Value) {
        if let Some(r) = location_ecef(v) {
            self.fixes_ecef.push(r);
        }
    }

    /// The fixes in the estimate's NED frame, once the origin is known.
    fn place_fixes(&mut self) {
        let Some(o) = &self.origin else { return };
        self.fixes_ne = self
            .fixes_ecef
            .iter()
            .map(|r| {
                let p = o.R_ecef_ned.transpose() * (r - o.origin_ecef);
                (p.x, p.y)
            })
            .filter(|(n, e)| n.is_finite() && e.is_finite())
            .collect();
    }
}

/// A `foxglove.LocationFix` record's position as ECEF (m).
fn location_ecef(v: &Value) -> Option<nalgebra::Vector3<f64>> {
    let (lat, lon, h) = (
        v["latitude"].as_f64()?,
        v["longitude"].as_f64()?,
        v["altitude"].as_f64()?,
    );
    Some(cmsckf_models::geodesy::llh_to_ecef(
        lat.to_radians(),
        lon.to_radians(),
        h,
    ))
}

#[cfg(test)]
mod reference_tests {
    use super::*;

    /// PX4's modes as SIH's reported them in tests/px4_sitl.rs: POSCTL
    /// standing, OFFBOARD, then the landing.
    #[test]
    fn px4_modes_are_named_from_main_and_sub_mode() {
        assert_eq!(px4_mode(0x0003_0000), Some("POSCTL"));
        assert_eq!(px4_mode(0x0006_0000), Some("OFFBOARD"));
        assert_eq!(px4_mode(0x0604_0000), Some("AUTO.LAND"));
        assert_eq!(px4_mode(0x0004_0000), None);
    }

    /// One autopilot record at `t_s`, as the log holds it.
    fn autopilot_message(rec: &AutopilotRecord, t_s: f64) -> mcap::Message<'static> {
        let channel = std::sync::Arc::new(mcap::Channel {
            id: 1,
            topic: Topic::InputAutopilot.name().to_string(),
            schema: None,
            message_encoding: "json".into(),
            metadata: BTreeMap::new(),
        });
        let ns = (t_s * 1e9) as u64;
        mcap::Message {
            channel,
            sequence: 0,
            log_time: ns,
            publish_time: ns,
            data: serde_json::to_vec(rec).unwrap().into(),
        }
    }

    /// A log written before the daemon logged the autopilot's kind ahead of
    /// its first mode has PX4's first mode unnamed until the kind: the row
    /// is named once the kind comes; in the order the daemon now writes,
    /// named at once.
    #[test]
    fn a_mode_logged_before_the_autopilots_kind_is_named() {
        for kind_first in [false, true] {
            let mut r = LogReader::new();
            let (mode, kind) = (
                AutopilotRecord::Mode(0x0003_0000),
                AutopilotRecord::Autopilot(AutopilotKind::Px4),
            );
            let order = if kind_first { [&kind, &mode] } else { [&mode, &kind] };
            for (i, rec) in order.into_iter().enumerate() {
                r.on_message(&autopilot_message(rec, 1.0 + i as f64));
            }
            r.on_message(&autopilot_message(&AutopilotRecord::Mode(0x0006_0000), 3.0));
            let texts: Vec<_> = r.d.events.iter().map(|e| e.text.clone()).collect();
            assert!(texts.contains(&"mode POSCTL (0x30000)".to_string()), "{texts:?}");
            assert!(texts.contains(&"mode OFFBOARD (0x60000)".to_string()), "{texts:?}");
        }
    }

    /// What the autopilot weighs us by: PX4 reads the variances axis by
    /// axis, ArduPilot its cube-root reduction of them (eq. O1); a log
    /// without the entries gives nothing.
    #[test]
    fn the_sigma_sent_is_read_as_the_autopilot_reads_it() {
        let mut c = vec![0.0f64; 21];
        (c[0], c[6], c[11]) = (0.09, 0.04, 0.01);
        let v = serde_json::json!(c);
        let px4 = sent_position_sigma(&v, Some(AutopilotKind::Px4)).unwrap();
        assert!((px4[0] - 0.3).abs() < 1e-12 && (px4[1] - 0.2).abs() < 1e-12 && (px4[2] - 0.1).abs() < 1e-12);
        // ArduPilot's encoding of σ = 0.3 m: each entry σ^(3/2)/√3.
        let e = 0.3f64.powf(1.5) / 3f64.sqrt();
        (c[0], c[6], c[11]) = (e, e, e);
        let ap = sent_position_sigma(&serde_json::json!(c), Some(AutopilotKind::ArduPilot)).unwrap();
        assert!(ap.iter().all(|s| (s - 0.3).abs() < 1e-12), "{ap:?}");
        assert_eq!(sent_position_sigma(&Value::Null, Some(AutopilotKind::Px4)), None);
        c[6] = -1.0;
        assert_eq!(sent_position_sigma(&serde_json::json!(c), None), None);
    }

    /// The reproducer: a replayed log scored 0.20 m against the
    /// autopilot's position, 0.78 m against the truth. The autopilot's
    /// position is a reference only when we sent it nothing.
    #[test]
    fn the_autopilots_echo_of_our_estimates_is_no_reference() {
        let mut d = Data::default();
        d.autopilot.push((1.0, [0.0; 3]));
        assert_eq!(d.reference().0.len(), 1, "nothing sent: the autopilot's own position");
        d.estimates_sent = 10;
        assert!(d.reference().0.is_empty());
        assert_eq!(d.reference().1, NO_REFERENCE_ECHO);
        d.truth.push((1.0, [0.0; 3]));
        assert_eq!(d.reference().1, "the truth (SIM_STATE)");
    }
}
