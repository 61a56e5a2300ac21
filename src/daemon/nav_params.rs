//! The autopilot's navigation parameters, read and judged.
//!
//! An autopilot's EKF fuses our estimates only as its parameters say, and
//! nothing on the link tells when they say no: with PX4's `EKF2_EV_CTRL =
//! 0` or ArduPilot's `VISO_TYPE = 0` our estimates are dropped, and with
//! `EKF2_EV_NOISE_MD = 1` EKF2 weighs them by its own numbers, not by our
//! covariance. So the daemon asks for the few parameters that decide it
//! (`PARAM_REQUEST_READ`, a round every [`ASK_EVERY_S`], at most
//! [`ROUNDS`]), logs each value that comes (`/input/mavlink/autopilot`,
//! replayed), says each one that is wrong with its fix (`/log`, and a
//! `STATUSTEXT` to the ground station while disarmed), judges again when
//! one changes (a ground station setting it broadcasts the new value), and
//! tells the output whether the autopilot's heading is ours alone: with
//! `output.position_covariance = "auto"` the position's covariance then
//! goes to PX4 given our yaw (estimator README eq. O2).

use super::flight_log::{FlightLog, Level};
use crate::counters::{Counter, Counters};
use crate::io::messages::{AutopilotKind, Outbound, ParamValue};

/// A round of requests for the parameters not yet answered goes out this
/// often (s of autopilot time), [`ROUNDS`] times at most; the parameters
/// are then judged with what came.
const ASK_EVERY_S: f64 = 2.0;
const ROUNDS: u32 = 5;

/// PX4's EKF2 (PX4 v1.14 and later; docs/setup-px4.md says why each).
const PX4: &[&str] = &[
    "EKF2_EV_CTRL",
    "EKF2_GPS_CTRL",
    "EKF2_MAG_TYPE",
    "EKF2_HGT_REF",
    "EKF2_EV_NOISE_MD",
    "EKF2_EV_DELAY",
    "EKF2_RNG_CTRL",
    "EKF2_BARO_CTRL",
];
/// ArduPilot's EKF3 and its visual odometry (docs/setup-ardupilot.md).
const ARDUPILOT: &[&str] = &[
    "VISO_TYPE",
    "AHRS_EKF_TYPE",
    "EK3_SRC1_POSXY",
    "EK3_SRC1_POSZ",
    "EK3_SRC1_YAW",
];

/// Parameters a build may lack: PX4 compiles EKF2's range finder and
/// barometer out on boards short of flash (`CONFIG_EKF2_RANGE_FINDER`,
/// `CONFIG_EKF2_BAROMETER`), and then never answers for them. The verdict
/// waits two rounds for them, not all five, and their silence is not
/// counted as unanswered.
const OPTIONAL: &[&str] = &["EKF2_RNG_CTRL", "EKF2_BARO_CTRL"];

fn is_optional(name: &str) -> bool {
    OPTIONAL.contains(&name)
}

/// Whether `name` is a parameter asked of any autopilot: the others (a
/// ground station's download of all of them, a gimbal's list) are not
/// ours to log or judge.
pub(super) fn is_asked(name: &str) -> bool {
    PX4.iter().chain(ARDUPILOT).any(|n| *n == name)
}

/// The parameters asked of an autopilot of this kind.
fn wanted(kind: AutopilotKind) -> &'static [&'static str] {
    match kind {
        AutopilotKind::Px4 => PX4,
        AutopilotKind::ArduPilot => ARDUPILOT,
        AutopilotKind::Other => &[],
    }
}

/// One thing the parameters say, at the level it matters.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct Finding {
    pub(super) level: Level,
    pub(super) text: String,
}

/// What the parameters say.
#[derive(Clone, Debug, Default, PartialEq)]
pub(super) struct Verdict {
    /// Each parameter that is wrong or worth knowing, with its fix.
    pub(super) findings: Vec<Finding>,
    /// The autopilot's heading is ours alone (`None`: its parameters do not
    /// say, or it is not PX4).
    pub(super) heading_ours_alone: Option<bool>,
}

/// The parameters asked for, those answered, and their verdict.
#[derive(Debug, Default)]
pub(super) struct NavParams {
    kind: Option<AutopilotKind>,
    /// Each wanted parameter and its value once answered.
    values: Vec<(&'static str, Option<f64>)>,
    next_ask_t: f64,
    rounds: u32,
    verdict: Option<Verdict>,
    /// The findings of the verdict that have reached the ground station
    /// (those said in the air only in the log): sent once, while disarmed.
    on_ground: Vec<Finding>,
}

impl NavParams {
    /// The autopilot's kind, from its HEARTBEAT: a new kind starts the
    /// questions again.
    pub(super) fn set_kind(&mut self, kind: AutopilotKind) {
        if self.kind != Some(kind) {
            *self = Self {
                kind: Some(kind),
                values: wanted(kind).iter().map(|n| (*n, None)).collect(),
                next_ask_t: f64::NEG_INFINITY,
                ..Self::default()
            };
        }
    }

    /// After the autopilot's reboot: its parameters are asked for again
    /// from the first round (a reboot is when some take effect, and its
    /// clock restarts, so a round due on the old clock would wait as long
    /// as it had been up), and not known until they come.
    pub(super) fn restart_questions(&mut self) {
        if let Some(kind) = self.kind.take() {
            self.set_kind(kind);
        }
    }

    /// Whether the autopilot's heading is ours alone, once judged.
    pub(super) fn heading_ours_alone(&self) -> Option<bool> {
        self.verdict.as_ref().and_then(|v| v.heading_ours_alone)
    }

    /// At each IMU sample `t_s`: asks for the parameters not yet answered
    /// when a round is due, and judges with what came after the last round.
    pub(super) fn poll(
        &mut self,
        t_s: f64,
        armed: bool,
        log: &FlightLog,
        counters: &Counters,
        out: &impl Fn(Outbound),
    ) {
        if self.verdict.is_some() || self.values.is_empty() || t_s < self.next_ask_t {
            return;
        }
        // Every required one answered, and the optional ones still missing
        // asked once more (a request or an answer can be lost): judged
        // without them.
        let required_came = self.values.iter().all(|(n, v)| v.is_some() || is_optional(n));
        if self.rounds < ROUNDS && !(required_came && self.rounds > 1) {
            self.rounds += 1;
            self.next_ask_t = t_s + ASK_EVERY_S;
            for (name, _) in self.values.iter().filter(|(_, v)| v.is_none()) {
                out(Outbound::ParamRequestRead { name });
            }
            return;
        }
        for (name, _) in self.values.iter().filter(|(_, v)| v.is_none()) {
            if is_optional(name) {
                tracing::info!(
                    param = name,
                    "no PARAM_VALUE came in two rounds: not in this autopilot's build, or lost"
                );
                continue;
            }
            counters.add(Counter::AutopilotParamUnanswered, 1);
            tracing::warn!(
                reason = "autopilot_param_unanswered",
                param = name,
                "no PARAM_VALUE came"
            );
        }
        self.judge(t_s, armed, log, counters, out);
    }

    /// A `PARAM_VALUE`: kept if it is one asked for; the parameters are
    /// judged once all have come, and again when one changes.
    pub(super) fn on_value(
        &mut self,
        p: &ParamValue,
        t_s: f64,
        armed: bool,
        log: &FlightLog,
        counters: &Counters,
        out: &impl Fn(Outbound),
    ) {
        let Some(kind) = self.kind else { return };
        let Some(slot) = self.values.iter_mut().find(|(n, _)| *n == p.name) else {
            return;
        };
        let Some(v) = p.decoded(kind) else { return };
        counters.add(Counter::AutopilotParamValue, 1);
        // New or changed: a value that comes after the rounds gave up on it
        // is judged as much as one that changes.
        let changed = slot.1 != Some(v);
        slot.1 = Some(v);
        let complete = self.values.iter().all(|(_, v)| v.is_some());
        if (self.verdict.is_none() && complete) || (self.verdict.is_some() && changed) {
            self.judge(t_s, armed, log, counters, out);
        }
    }

    fn value(&self, name: &str) -> Option<f64> {
        self.values.iter().find(|(n, _)| *n == name).and_then(|(_, v)| *v)
    }

    /// Judges the parameters as they stand and says what they say.
    fn judge(&mut self, t_s: f64, armed: bool, log: &FlightLog, counters: &Counters, out: &impl Fn(Outbound)) {
        let Some(kind) = self.kind else { return };
        let verdict = verdict(kind, &|n| self.value(n));
        let values = self
            .values
            .iter()
            .map(|(n, v)| match v {
                Some(v) => format!("{n} = {v}"),
                None => format!("{n} unanswered"),
            })
            .collect::<Vec<_>>()
            .join(", ");
        log.text(
            Level::Info,
            t_s,
            &format!("the autopilot's navigation parameters: {values}"),
        );
        tracing::info!(%values, "the autopilot's navigation parameters");
        if let Some(alone) = verdict.heading_ours_alone {
            let text = if alone {
                "the autopilot's heading is ours alone: with output.position_covariance = \"auto\" our \
                 position's covariance goes to it given our yaw (eq. O2)"
            } else {
                "the autopilot has a heading or a position of its own: our position's covariance goes to it \
                 whole"
            };
            log.text(Level::Info, t_s, text);
            tracing::info!("{text}");
        }
        let mut on_ground = Vec::new();
        for f in &verdict.findings {
            log.text(f.level, t_s, &f.text);
            if f.level == Level::Info {
                tracing::info!("{}", f.text);
                continue;
            }
            // Said once: judged again for another value (one that came late,
            // or a ground station setting another), a wrong value already
            // said is not counted again, nor sent to the ground again once
            // it has reached it.
            if !self.verdict.as_ref().is_some_and(|v| v.findings.contains(f)) {
                counters.add(Counter::AutopilotParamMisconfigured, 1);
                tracing::warn!(reason = "autopilot_param_misconfigured", "{}", f.text);
            }
            // To the pilot's screen on the ground; in the air only the log.
            if self.on_ground.contains(f) {
                on_ground.push(f.clone());
            } else if !armed {
                let severity = if f.level == Level::Error { 3 } else { 4 };
                out(Outbound::StatusText {
                    severity,
                    text: format!("cmsckf: {}", f.text),
                });
                on_ground.push(f.clone());
            }
        }
        self.on_ground = on_ground;
        self.verdict = Some(verdict);
    }
}

/// Bit `b` of an integer parameter.
fn bit(v: f64, b: u32) -> bool {
    (v as i64 >> b) & 1 == 1
}

/// What an autopilot's navigation parameters say (`value`: a parameter's
/// value, `None` when unanswered).
pub(super) fn verdict(kind: AutopilotKind, value: &dyn Fn(&str) -> Option<f64>) -> Verdict {
    match kind {
        AutopilotKind::Px4 => px4_verdict(value),
        AutopilotKind::ArduPilot => ardupilot_verdict(value),
        AutopilotKind::Other => Verdict::default(),
    }
}

fn finding(level: Level, text: String) -> Finding {
    Finding { level, text }
}

/// PX4's EKF2 (`src/modules/ekf2/params_external_vision.yaml`;
/// docs/setup-px4.md).
fn px4_verdict(value: &dyn Fn(&str) -> Option<f64>) -> Verdict {
    let mut findings = Vec::new();
    let ev_ctrl = value("EKF2_EV_CTRL");
    match ev_ctrl {
        Some(c) if c as i64 & 0b1111 == 0 => findings.push(finding(
            Level::Error,
            format!("EKF2_EV_CTRL = {c}: EKF2 fuses none of our estimates; set it to 15"),
        )),
        Some(c) if !bit(c, 0) => findings.push(finding(
            Level::Warning,
            format!("EKF2_EV_CTRL = {c}: EKF2 does not fuse our horizontal position (bit 0); set it to 15"),
        )),
        _ => {}
    }
    if let (Some(3.0), Some(c)) = (value("EKF2_HGT_REF"), ev_ctrl) {
        if !bit(c, 1) {
            findings.push(finding(
                Level::Warning,
                format!("EKF2_HGT_REF = 3 (vision) but EKF2_EV_CTRL = {c} fuses no vertical position (bit 1)"),
            ));
        }
    }
    if value("EKF2_EV_NOISE_MD") == Some(1.0) {
        findings.push(finding(
            Level::Warning,
            "EKF2_EV_NOISE_MD = 1: EKF2 ignores the covariance we send and weighs us by its EKF2_EV*_NOISE; \
             set it to 0"
                .to_string(),
        ));
    }
    if let Some(d) = value("EKF2_EV_DELAY").filter(|d| *d > 0.0) {
        findings.push(finding(
            Level::Info,
            format!(
                "EKF2_EV_DELAY = {d} ms: once TIMESYNC has converged our stamps are each estimate's own time, \
                 and EKF2 moves each {d} ms earlier; 0 is right then (docs/setup-px4.md)"
            ),
        ));
    }
    // Height sources of EKF2's own beside ours (`params_range_finder.yaml`,
    // `params_barometer.yaml`): not wrong, but its height is then a blend,
    // and a review that finds PX4's height off ours must know it. PX4's
    // SIH has a range finder that reads the truth: with `EKF2_RNG_CTRL = 1`
    // EKF2 made a terrain estimate from it in each of `tests/px4_sitl.rs`'s
    // flights until that test set 0 (docs/setup-px4.md).
    if let Some(c) = value("EKF2_RNG_CTRL").filter(|c| *c != 0.0) {
        findings.push(finding(
            Level::Info,
            format!(
                "EKF2_RNG_CTRL = {c}: EKF2 also fuses a range finder if one is fitted (its terrain, and with 1 \
                 its height when low and slow), so its height is not ours alone; 0 takes it out of EKF2's height"
            ),
        ));
    }
    if let Some(c) = value("EKF2_BARO_CTRL").filter(|c| *c != 0.0) {
        findings.push(finding(
            Level::Info,
            format!(
                "EKF2_BARO_CTRL = {c}: EKF2 also fuses its barometer, with an offset it learns against our \
                 height, so its height is not ours alone; 0 takes it out of EKF2's height"
            ),
        ));
    }
    // Our yaw is EKF2's heading when it fuses it and has no other: no GNSS
    // position, velocity or dual-antenna heading (`EKF2_GPS_CTRL` bits 0, 2,
    // 3: each ties EKF2's frame to north; velocity alone aligns its yaw by
    // the EKF-GSF and resets it in flight) and no compass.
    let heading_ours_alone = match (ev_ctrl, value("EKF2_GPS_CTRL"), value("EKF2_MAG_TYPE")) {
        (Some(ev), Some(gps), Some(mag)) => {
            Some(bit(ev, 3) && !bit(gps, 0) && !bit(gps, 2) && !bit(gps, 3) && mag == 5.0)
        }
        _ => None,
    };
    Verdict {
        findings,
        heading_ours_alone,
    }
}

/// ArduPilot's EKF3 and its visual odometry (docs/setup-ardupilot.md).
fn ardupilot_verdict(value: &dyn Fn(&str) -> Option<f64>) -> Verdict {
    let mut findings = Vec::new();
    if value("VISO_TYPE") == Some(0.0) {
        findings.push(finding(
            Level::Error,
            "VISO_TYPE = 0: ArduPilot ignores our estimates; set it to 1 (MAVLink) and reboot".to_string(),
        ));
    }
    if let Some(t) = value("AHRS_EKF_TYPE").filter(|t| *t != 3.0) {
        findings.push(finding(
            Level::Warning,
            format!("AHRS_EKF_TYPE = {t}: only EKF3 fuses external navigation; set it to 3"),
        ));
    }
    if let Some(s) = value("EK3_SRC1_POSXY").filter(|s| *s != 6.0) {
        findings.push(finding(
            Level::Info,
            format!(
                "EK3_SRC1_POSXY = {s}: EKF3's first source set does not take our horizontal position \
                 (6 = ExternalNav); ours is used only when a source set with 6 is selected"
            ),
        ));
    }
    Verdict {
        findings,
        heading_ours_alone: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::cell::RefCell;

    fn px4(values: &[(&str, f64)]) -> Verdict {
        verdict(AutopilotKind::Px4, &|n| {
            values.iter().find(|(k, _)| *k == n).map(|(_, v)| *v)
        })
    }

    const SITL: [(&str, f64); 8] = [
        ("EKF2_EV_CTRL", 15.0),
        ("EKF2_GPS_CTRL", 0.0),
        ("EKF2_MAG_TYPE", 5.0),
        ("EKF2_HGT_REF", 3.0),
        ("EKF2_EV_NOISE_MD", 0.0),
        ("EKF2_EV_DELAY", 0.0),
        ("EKF2_RNG_CTRL", 0.0),
        ("EKF2_BARO_CTRL", 0.0),
    ];

    #[test]
    fn px4_set_up_for_vision_alone_has_its_heading_from_us_and_nothing_to_say() {
        let v = px4(&SITL);
        assert_eq!(v.findings, vec![]);
        assert_eq!(v.heading_ours_alone, Some(true));
    }

    #[test]
    fn each_px4_parameter_that_drops_or_misweighs_us_is_said_with_its_fix() {
        let with = |name: &str, value: f64| {
            let mut p = SITL.to_vec();
            p.iter_mut().find(|(n, _)| *n == name).unwrap().1 = value;
            px4(&p)
        };
        let v = with("EKF2_EV_CTRL", 0.0);
        assert_eq!(v.findings.len(), 2, "{v:?}"); // none fused, and no height under HGT_REF 3
        assert_eq!(v.findings[0].level, Level::Error);
        assert!(v.findings[0].text.contains("EKF2_EV_CTRL = 0") && v.findings[0].text.contains("15"));
        assert_eq!(v.heading_ours_alone, Some(false));
        let v = with("EKF2_EV_CTRL", 14.0);
        assert!(v.findings[0].text.contains("horizontal"), "{v:?}");
        assert_eq!(v.findings[0].level, Level::Warning);
        let v = with("EKF2_EV_CTRL", 13.0);
        assert!(v.findings[0].text.contains("vertical"), "{v:?}");
        let v = with("EKF2_EV_NOISE_MD", 1.0);
        assert!(v.findings[0].text.contains("ignores the covariance"), "{v:?}");
        let v = with("EKF2_EV_DELAY", 50.0);
        assert_eq!(v.findings[0].level, Level::Info);
        // EKF2's own height sources: said, as facts, not counted as wrong.
        for (name, value) in [("EKF2_RNG_CTRL", 1.0), ("EKF2_RNG_CTRL", 2.0), ("EKF2_BARO_CTRL", 1.0)] {
            let v = with(name, value);
            assert_eq!(v.findings.len(), 1, "{v:?}");
            assert_eq!(v.findings[0].level, Level::Info);
            assert!(
                v.findings[0].text.contains(name) && v.findings[0].text.contains("not ours alone"),
                "{v:?}"
            );
            assert_eq!(v.heading_ours_alone, Some(true));
        }
        // Another heading source: EKF2's frame is not ours alone.
        assert_eq!(with("EKF2_GPS_CTRL", 7.0).heading_ours_alone, Some(false));
        assert_eq!(with("EKF2_MAG_TYPE", 0.0).heading_ours_alone, Some(false));
        assert_eq!(with("EKF2_EV_CTRL", 7.0).heading_ours_alone, Some(false));
        // Not known without all three.
        assert_eq!(px4(&SITL[..2]).heading_ours_alone, None);
    }

    #[test]
    fn ardupilot_ignoring_us_is_said() {
        let ap = |values: &[(&str, f64)]| {
            verdict(AutopilotKind::ArduPilot, &|n| {
                values.iter().find(|(k, _)| *k == n).map(|(_, v)| *v)
            })
        };
        let good = [
            ("VISO_TYPE", 1.0),
            ("AHRS_EKF_TYPE", 3.0),
            ("EK3_SRC1_POSXY", 6.0),
            ("EK3_SRC1_POSZ", 1.0),
            ("EK3_SRC1_YAW", 6.0),
        ];
        assert_eq!(ap(&good).findings, vec![]);
        assert_eq!(ap(&good).heading_ours_alone, None);
        let v = ap(&[("VISO_TYPE", 0.0), ("AHRS_EKF_TYPE", 2.0), ("EK3_SRC1_POSXY", 3.0)]);
        let levels: Vec<_> = v.findings.iter().map(|f| f.level).collect();
        assert_eq!(levels, vec![Level::Error, Level::Warning, Level::Info], "{v:?}");
    }

    /// Asks in rounds for what has not come, judges once all have come,
    /// again on a change, and with what came when the rounds run out.
    #[test]
    fn parameters_are_asked_in_rounds_and_judged_when_complete_or_given_up() {
        let log = FlightLog::new(None, false);
        let counters = Counters::default();
        let sent = RefCell::new(Vec::new());
        let out = |o: Outbound| sent.borrow_mut().push(o);
        let mut p = NavParams::default();
        p.poll(0.0, false, &log, &counters, &out);
        assert!(sent.borrow().is_empty(), "nothing asked before the kind is known");
        p.set_kind(AutopilotKind::Px4);
        p.poll(0.0, false, &log, &counters, &out);
        assert_eq!(sent.borrow().len(), PX4.len());
        p.poll(1.0, false, &log, &counters, &out);
        assert_eq!(sent.borrow().len(), PX4.len(), "the next round waits its turn");
        // Answers as PX4 sends integers: their bits in the f32.
        let answer = |p: &mut NavParams, name: &str, v: i32| {
            let raw = ParamValue {
                name: name.to_string(),
                raw: f32::from_bits(v as u32),
                param_type: 6,
            };
            p.on_value(&raw, 2.5, false, &log, &counters, &out);
        };
        for (name, v) in SITL.iter().filter(|(n, _)| *n != "EKF2_EV_DELAY") {
            answer(&mut p, name, *v as i32);
        }
        sent.borrow_mut().clear();
        p.poll(2.0, false, &log, &counters, &out);
        let asked: Vec<_> = sent.borrow().clone();
        assert!(
            matches!(asked.as_slice(), [Outbound::ParamRequestRead { name: "EKF2_EV_DELAY" }]),
            "only the missing one asked again: {asked:?}"
        );
        assert_eq!(p.heading_ours_alone(), None, "not judged before all have come");
        p.on_value(
            &ParamValue {
                name: "EKF2_EV_DELAY".into(),
                raw: 0.0,
                param_type: 9,
            },
            3.0,
            false,
            &log,
            &counters,
            &out,
        );
        assert_eq!(p.heading_ours_alone(), Some(true));
        // A ground station turns EV yaw off: judged again at once, and said.
        sent.borrow_mut().clear();
        answer(&mut p, "EKF2_EV_CTRL", 0);
        assert_eq!(p.heading_ours_alone(), Some(false));
        assert!(sent
            .borrow()
            .iter()
            .any(|o| matches!(o, Outbound::StatusText { severity: 3, .. })));
        assert_eq!(counters.get(Counter::AutopilotParamMisconfigured), 2);
        // An autopilot that never answers: judged after the last round.
        let mut q = NavParams::default();
        q.set_kind(AutopilotKind::ArduPilot);
        for k in 0..=ROUNDS {
            q.poll(k as f64 * ASK_EVERY_S, false, &log, &counters, &out);
        }
        assert!(q.verdict.is_some());
        assert_eq!(counters.get(Counter::AutopilotParamUnanswered), ARDUPILOT.len() as u64);
        // A value that is no parameter of ours, or not finite, is ignored.
        let before = counters.get(Counter::AutopilotParamValue);
        for (name, raw) in [("SYS_AUTOSTART", 1.0f32), ("VISO_TYPE", f32::NAN)] {
            let v = ParamValue {
                name: name.into(),
                raw,
                param_type: 9,
            };
            q.on_value(&v, 20.0, false, &log, &counters, &out);
        }
        assert_eq!(counters.get(Counter::AutopilotParamValue), before);
    }

    /// A PX4 `PARAM_VALUE` as PX4 sends an `INT32`: its bits in the float.
    fn px4_int(name: &str, v: i32) -> ParamValue {
        ParamValue {
            name: name.to_string(),
            raw: f32::from_bits(v as u32),
            param_type: 6,
        }
    }

    /// An answer that comes after the rounds gave up on it (a slow link, an
    /// autopilot still booting) is judged: a wrong value is said, and the
    /// heading's verdict, unknown without it, is given.
    #[test]
    fn a_value_that_comes_after_the_rounds_gave_up_is_judged() {
        let log = FlightLog::new(None, false);
        let counters = Counters::default();
        let sent = RefCell::new(Vec::new());
        let out = |o: Outbound| sent.borrow_mut().push(o);
        let mut p = NavParams::default();
        p.set_kind(AutopilotKind::Px4);
        // Every value but EKF2_EV_CTRL comes; the rounds run out.
        for (name, v) in SITL.iter().skip(1) {
            p.on_value(&px4_int(name, *v as i32), 0.5, false, &log, &counters, &out);
        }
        for k in 0..=ROUNDS {
            p.poll(k as f64 * ASK_EVERY_S, false, &log, &counters, &out);
        }
        assert_eq!(counters.get(Counter::AutopilotParamUnanswered), 1);
        assert_eq!(p.heading_ours_alone(), None, "EKF2_EV_CTRL not known");
        // It comes late, as 0: EKF2 drops us. Said, counted, and the heading
        // known not to be ours.
        sent.borrow_mut().clear();
        p.on_value(&px4_int("EKF2_EV_CTRL", 0), 30.0, false, &log, &counters, &out);
        assert_eq!(
            counters.get(Counter::AutopilotParamMisconfigured),
            2,
            "EV_CTRL 0, and no vision height"
        );
        assert!(sent
            .borrow()
            .iter()
            .any(|o| matches!(o, Outbound::StatusText { severity: 3, text } if text.contains("EKF2_EV_CTRL = 0"))));
        assert_eq!(p.heading_ours_alone(), Some(false));
        // The same value again (a ground station's list download): nothing
        // new to say.
        p.on_value(&px4_int("EKF2_EV_CTRL", 0), 31.0, false, &log, &counters, &out);
        assert_eq!(counters.get(Counter::AutopilotParamMisconfigured), 2);
        // Set to 15 in flight: judged again, the heading now ours alone.
        p.on_value(&px4_int("EKF2_EV_CTRL", 15), 32.0, true, &log, &counters, &out);
        assert_eq!(p.heading_ours_alone(), Some(true));
        assert_eq!(counters.get(Counter::AutopilotParamMisconfigured), 2);
    }

    /// A PX4 built without EKF2's range finder and barometer never answers
    /// for their parameters: asked once more once the required ones came,
    /// then judged (not after all five rounds), those two not counted as
    /// unanswered; one of them that comes later is judged then.
    #[test]
    fn a_px4_without_the_optional_parameters_is_judged_a_round_later() {
        let log = FlightLog::new(None, false);
        let counters = Counters::default();
        let sent = RefCell::new(Vec::new());
        let out = |o: Outbound| sent.borrow_mut().push(o);
        let mut p = NavParams::default();
        p.set_kind(AutopilotKind::Px4);
        p.poll(0.0, false, &log, &counters, &out);
        assert_eq!(sent.borrow().len(), PX4.len(), "the optional ones asked too");
        for (name, v) in SITL.iter().filter(|(n, _)| !is_optional(n)) {
            p.on_value(&px4_int(name, *v as i32), 0.5, false, &log, &counters, &out);
        }
        assert_eq!(p.heading_ours_alone(), None, "waits a round for the optional ones");
        sent.borrow_mut().clear();
        p.poll(1.0, false, &log, &counters, &out);
        assert_eq!(p.heading_ours_alone(), None, "the next round is not due yet");
        p.poll(ASK_EVERY_S, false, &log, &counters, &out);
        assert_eq!(p.heading_ours_alone(), None, "the optional ones asked once more");
        assert_eq!(sent.borrow().len(), OPTIONAL.len(), "{:?}", sent.borrow());
        sent.borrow_mut().clear();
        p.poll(2.0 * ASK_EVERY_S, false, &log, &counters, &out);
        assert_eq!(p.heading_ours_alone(), Some(true), "judged without them");
        assert!(sent.borrow().is_empty(), "nothing asked again: {:?}", sent.borrow());
        assert_eq!(counters.get(Counter::AutopilotParamUnanswered), 0);
        assert_eq!(counters.get(Counter::AutopilotParamMisconfigured), 0);
        // A required one missing is still asked for five rounds and counted.
        let mut q = NavParams::default();
        q.set_kind(AutopilotKind::Px4);
        for (name, v) in SITL.iter().skip(1).filter(|(n, _)| !is_optional(n)) {
            q.on_value(&px4_int(name, *v as i32), 0.5, false, &log, &counters, &out);
        }
        for k in 0..=ROUNDS {
            q.poll(k as f64 * ASK_EVERY_S, false, &log, &counters, &out);
        }
        assert_eq!(counters.get(Counter::AutopilotParamUnanswered), 1, "EKF2_EV_CTRL alone");
        // The range finder's parameter comes late, as 1: said, as information.
        p.on_value(&px4_int("EKF2_RNG_CTRL", 1), 30.0, false, &log, &counters, &out);
        let v = p.verdict.as_ref().unwrap();
        assert_eq!(v.findings.len(), 1, "{v:?}");
        assert_eq!(v.findings[0].level, Level::Info);
        assert_eq!(counters.get(Counter::AutopilotParamMisconfigured), 0);
    }

    /// Judged again for another value, a wrong value already said is not
    /// said again: each late answer (or a ground station setting another
    /// parameter) would otherwise repeat every finding to the ground.
    #[test]
    fn a_wrong_value_is_said_once_however_often_judged() {
        let log = FlightLog::new(None, false);
        let counters = Counters::default();
        let sent = RefCell::new(Vec::new());
        let out = |o: Outbound| sent.borrow_mut().push(o);
        let mut p = NavParams::default();
        p.set_kind(AutopilotKind::Px4);
        let mut with_noise_md = SITL;
        with_noise_md[4].1 = 1.0;
        for (name, v) in with_noise_md {
            p.on_value(&px4_int(name, v as i32), 1.0, false, &log, &counters, &out);
        }
        assert_eq!(counters.get(Counter::AutopilotParamMisconfigured), 1);
        // EKF2_EV_DELAY set, then set back: judged twice, NOISE_MD not said again.
        for d in [20, 0] {
            p.on_value(&px4_int("EKF2_EV_DELAY", d), 2.0, false, &log, &counters, &out);
        }
        assert_eq!(counters.get(Counter::AutopilotParamMisconfigured), 1);
        let texts = sent
            .borrow()
            .iter()
            .filter(|o| matches!(o, Outbound::StatusText { .. }))
            .count();
        assert_eq!(texts, 1, "{:?}", sent.borrow());
        // A new wrong value is said.
        p.on_value(&px4_int("EKF2_EV_CTRL", 14), 3.0, false, &log, &counters, &out);
        assert_eq!(counters.get(Counter::AutopilotParamMisconfigured), 2);
        // One found in the air is counted then, and reaches the ground at
        // the first judgement on it (not counted again), once.
        sent.borrow_mut().clear();
        p.on_value(&px4_int("EKF2_HGT_REF", 3), 4.0, true, &log, &counters, &out);
        p.on_value(&px4_int("EKF2_EV_CTRL", 13), 5.0, true, &log, &counters, &out);
        assert_eq!(
            counters.get(Counter::AutopilotParamMisconfigured),
            3,
            "EV_CTRL 13: no vision height"
        );
        assert!(sent.borrow().is_empty(), "{:?}", sent.borrow());
        for d in [20, 0] {
            p.on_value(&px4_int("EKF2_EV_DELAY", d), 6.0, false, &log, &counters, &out);
        }
        assert_eq!(counters.get(Counter::AutopilotParamMisconfigured), 3);
        let texts: Vec<_> = sent
            .borrow()
            .iter()
            .filter_map(|o| match o {
                Outbound::StatusText { text, .. } => Some(text.clone()),
                _ => None,
            })
            .collect();
        assert_eq!(texts.len(), 1, "{texts:?}");
        assert!(texts[0].contains("EKF2_HGT_REF = 3"), "{texts:?}");
    }

    /// EKF2 with GNSS velocity alone (`EKF2_GPS_CTRL` bit 2: it aligns and
    /// resets its yaw by the EKF-GSF from it, `gps_control.cpp`) or a
    /// dual-antenna heading (bit 3) has a north of its own: its heading is
    /// not ours alone, whatever its position source. Height alone (bit 1)
    /// ties nothing to north.
    #[test]
    fn px4_with_gnss_velocity_or_heading_has_a_heading_of_its_own() {
        let with_gps = |gps: f64| {
            let mut p = SITL.to_vec();
            p[1] = ("EKF2_GPS_CTRL", gps);
            px4(&p).heading_ours_alone
        };
        assert_eq!(with_gps(0.0), Some(true));
        assert_eq!(with_gps(2.0), Some(true), "GNSS height alone");
        for gps in [1.0, 4.0, 8.0, 6.0, 12.0, 7.0, 15.0] {
            assert_eq!(with_gps(gps), Some(false), "EKF2_GPS_CTRL = {gps}");
        }
    }

    #[test]
    fn integers_are_decoded_as_each_autopilot_encodes_them() {
        let v = |raw: f32, t: u8| ParamValue {
            name: "X".into(),
            raw,
            param_type: t,
        };
        // PX4 copies an int32's bits into the float.
        assert_eq!(v(f32::from_bits(15), 6).decoded(AutopilotKind::Px4), Some(15.0));
        assert_eq!(
            v(f32::from_bits(-1i32 as u32), 6).decoded(AutopilotKind::Px4),
            Some(-1.0)
        );
        assert_eq!(v(f32::from_bits(0xff), 2).decoded(AutopilotKind::Px4), Some(-1.0));
        // ArduPilot casts.
        assert_eq!(v(6.0, 2).decoded(AutopilotKind::ArduPilot), Some(6.0));
        assert_eq!(v(0.5, 9).decoded(AutopilotKind::ArduPilot), Some(0.5));
        assert_eq!(v(f32::INFINITY, 9).decoded(AutopilotKind::Px4), None);
        assert_eq!(v(1.0, 8).decoded(AutopilotKind::Px4), None);
    }
}
