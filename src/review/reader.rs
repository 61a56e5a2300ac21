//! Reading a flight log for the review: one pass over its messages in file
//! order, counting into the [`ReviewSummary`] and keeping, in [`Data`], the
//! series the statistics and the plots need.

use std::collections::BTreeMap;

use serde_json::Value;

use super::timeline::{plausible, Timeline};
use super::ReviewSummary;
use crate::io::mcap_log::input::{AutopilotRecord, InputRecord, SimStateRecord};
use crate::io::mcap_log::Topic;

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
        let t = m.log_time as f64 * 1e-9;
        self.timeline.push(m.log_time);
        *self.counts.entry(m.channel.topic.clone()).or_default() += 1;
        let Some(topic) = Topic::from_name(&m.channel.topic) else {
            return;
        };
        let (s, d) = (&mut self.s, &mut self.d);
        if topic == Topic::InputAutopilot {
            // A typed input record: the autopilot's position, or the truth.
            match InputRecord::parse(topic, &m.data) {
                Ok(InputRecord::Autopilot(AutopilotRecord::LocalPosition(l))) => d.autopilot.push((t, l.p_ned_m)),
                Ok(InputRecord::Autopilot(AutopilotRecord::SimState(SimStateRecord { p_ned_m: Some(p), .. }))) => {
                    d.truth.push((t, p))
                }
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
            }
            Topic::FilterGlobal => {
                if v["reason"] == "Promotion" {
                    s.promotions += 1;
                } else {
                    s.global_updates += 1;
                    d.global_t.push(t);
                }
            }
            Topic::OutputVpe => s.estimates += 1,
            Topic::Location => d.push_location(t, &v),
            Topic::GnssFix => d.push_fix(&v),
            Topic::Diagnostics => {
                // The last record holds every counter at its latest.
                if let Some(c) = v["counters"].as_object() {
                    s.counters = c.iter().filter_map(|(k, n)| Some((k.clone(), n.as_u64()?))).collect();
                }
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
    fn push_sigmas(&mut self, t: f64, v: &Value) {
        if let Some(a) = v["keyframe_sigma_m"].as_array() {
            for e in a {
                if let (Some(id), Some(s)) = (e[0].as_u64(), e[1].as_f64()) {
                    self.kf_sigma.entry(id).or_default().push((t, s));
                }
            }
        }
    }

    /// The reference the error is measured against: the simulator's truth
    /// when the log has it, else the autopilot's local position; with its
    /// name.
    pub fn reference(&self) -> (&[(f64, [f64; 3])], &'static str) {
        if self.truth.is_empty() {
            (&self.autopilot, "the autopilot's local position")
        } else {
            (&self.truth, "the truth (SIM_STATE)")
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
