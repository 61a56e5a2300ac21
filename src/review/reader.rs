//! Reading a flight log for the review: one pass over its messages in file
//! order, counting into the [`ReviewSummary`] and keeping, in [`Data`], the
//! series the statistics and the plots need.

use std::collections::BTreeMap;

use serde_json::Value;

use super::timeline::{plausible, Timeline};
use super::ReviewSummary;

/// The series kept from the log (times in s of log time).
#[derive(Default)]
pub(super) struct Data {
    pub track: Vec<(f64, f64, f64, [f64; 4], f64)>, // t, n, e, q(wxyz), d
    pub kf_pos: Vec<(f64, f64)>,
    /// The autopilot's local position (in SITL, the ground truth).
    pub autopilot: Vec<(f64, f64)>,
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
        let Ok(v) = serde_json::from_slice::<Value>(&m.data) else {
            return;
        };
        let (s, d) = (&mut self.s, &mut self.d);
        match m.channel.topic.as_str() {
            "/filter/state" => d.push_state(t, &v),
            "/filter/keyframes" => {
                d.push_keyframe(&v);
                s.keyframes += 1;
            }
            "/filter/update/vision" => on_vision_update(s, d, t, &v),
            "/filter/update/gnss" => {
                s.gnss_updates += 1;
                d.gnss_t.push(t);
                d.push_sigmas(t, &v);
            }
            "/filter/update/global" => {
                if v["reason"] == "Promotion" {
                    s.promotions += 1;
                } else {
                    s.global_updates += 1;
                    d.global_t.push(t);
                }
            }
            "/output/vision_position_estimate" => s.estimates += 1,
            "/input/mavlink/autopilot" => d.push_autopilot(&v),
            "/diagnostics" => {
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
        for (k, n) in &counts {
            if k.starts_with("/input/") && s.duration_s > 0.0 {
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
        for v in self.kf_sigma.values_mut() {
            v.retain(|p| ok(p.0));
        }
        self.kf_sigma.retain(|_, v| !v.is_empty());
        self.vision_t.retain(|t| ok(*t));
        self.gnss_t.retain(|t| ok(*t));
        self.global_t.retain(|t| ok(*t));
        self.nis.retain(|p| ok(p.0));
    }

    /// A `/filter/state` record: the pose (NaN where a value is missing).
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

    /// An autopilot record with a local position: its north and east.
    fn push_autopilot(&mut self, v: &Value) {
        if let Some(p) = v["local_position"]["p_ned_m"].as_array() {
            if let (Some(n), Some(e)) = (p[0].as_f64(), p[1].as_f64()) {
                self.autopilot.push((n, e));
            }
        }
    }
}
