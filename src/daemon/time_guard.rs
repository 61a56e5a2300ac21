//! Time sanity for the inputs: one bad time stamp is rejected and counted,
//! and never becomes the reference the next ones are judged by; a genuine
//! jump (an autopilot reboot, a link that was down) is believed once
//! several samples agree on it, and then re-anchors cleanly.
//!
//! Before this, one `HIGHRES_IMU` stamped 0 read as a reboot and reset the
//! filter, and one feature line stamped 10¹⁸ µs made every later frame
//! "backwards" for good.

/// What one time stamp is, judged against the stream's own history.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Verdict {
    /// After the last one, within the largest believable step: take it.
    Next,
    /// At or a little before the last one (a duplicate or reordered
    /// sample): reject it.
    Stale,
    /// Far from the last one, and not (yet) confirmed by others: reject it.
    Outlier,
    /// Far from the last one (`from_s`), and the `confirm`-th in a row to
    /// agree: a genuine jump, the new reference. Take it.
    Jump { from_s: f64 },
}

/// A stream's clock: the last time taken, and a jump being confirmed.
#[derive(Clone, Debug)]
pub(super) struct TimeGuard {
    last_s: f64,
    /// The largest step, forward or back, taken without confirmation (s).
    max_step_s: f64,
    /// Samples in a row that must agree on a jump.
    confirm: u32,
    /// The span of the new clock (s) those samples must cover, with none
    /// on the old clock among them: a genuine reboot runs on, the old clock
    /// silent, while a burst of forged samples (five stamped 1.000–1.004 s
    /// at once) does not.
    confirm_span_s: f64,
    /// A jump being confirmed: its first and latest time and how many
    /// agree so far.
    candidate: Option<(f64, f64, u32)>,
}

impl TimeGuard {
    pub(super) fn new(max_step_s: f64, confirm: u32, confirm_span_s: f64) -> Self {
        Self {
            last_s: f64::NEG_INFINITY,
            max_step_s,
            confirm: confirm.max(1),
            confirm_span_s: confirm_span_s.max(0.0),
            candidate: None,
        }
    }

    /// The last time taken (−∞ before the first).
    #[cfg(test)]
    pub(super) fn last_s(&self) -> f64 {
        self.last_s
    }

    /// Judges `t_s` (finite; a non-finite time is an outlier).
    pub(super) fn check(&mut self, t_s: f64) -> Verdict {
        if !t_s.is_finite() {
            return Verdict::Outlier;
        }
        if !self.last_s.is_finite() {
            self.last_s = t_s;
            return Verdict::Next;
        }
        let step_s = t_s - self.last_s;
        if step_s > 0.0 && step_s <= self.max_step_s {
            // Back on the stream's clock: a pending jump was an outlier.
            self.candidate = None;
            self.last_s = t_s;
            return Verdict::Next;
        }
        if step_s <= 0.0 && step_s >= -self.max_step_s {
            return Verdict::Stale;
        }
        // Far off: does it continue the jump being confirmed?
        let (first_s, agreed) = match self.candidate {
            Some((first_s, c_s, n)) if t_s > c_s && t_s - c_s <= self.max_step_s => (first_s, n + 1),
            _ => (t_s, 1),
        };
        if agreed >= self.confirm && t_s - first_s >= self.confirm_span_s {
            let from_s = self.last_s;
            self.last_s = t_s;
            self.candidate = None;
            Verdict::Jump { from_s }
        } else {
            self.candidate = Some((first_s, t_s, agreed));
            Verdict::Outlier
        }
    }
}

/// A value that should hold still (the autopilot's Unix − boot clock
/// offset): a change beyond `tol` is believed once `confirm` values in a
/// row agree on it within `tol`.
#[derive(Clone, Debug)]
pub(super) struct SteadyValue {
    value: Option<f64>,
    tol: f64,
    confirm: u32,
    candidate: Option<(f64, u32)>,
}

impl SteadyValue {
    pub(super) fn new(tol: f64, confirm: u32) -> Self {
        Self {
            value: None,
            tol,
            confirm: confirm.max(1),
            candidate: None,
        }
    }

    pub(super) fn reset(&mut self) {
        self.value = None;
        self.candidate = None;
    }

    /// Offers `v`: `Some(value)` if it is taken (the first one, one close to
    /// the current value, or a confirmed change), `None` if rejected.
    pub(super) fn offer(&mut self, v: f64) -> Option<f64> {
        if !v.is_finite() {
            return None;
        }
        match self.value {
            Some(cur) if (v - cur).abs() > self.tol => {
                let agreed = match self.candidate {
                    Some((c, n)) if (v - c).abs() <= self.tol => n + 1,
                    _ => 1,
                };
                if agreed >= self.confirm {
                    self.candidate = None;
                    self.value = Some(v);
                    Some(v)
                } else {
                    self.candidate = Some((v, agreed));
                    None
                }
            }
            _ => {
                self.candidate = None;
                self.value = Some(v);
                Some(v)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_single_far_stamp_is_rejected_and_never_becomes_the_reference() {
        let mut g = TimeGuard::new(2.0, 5, 0.0);
        assert_eq!(g.check(100.0), Verdict::Next);
        assert_eq!(g.check(0.0), Verdict::Outlier, "one stamp of 0 is not a reboot");
        assert_eq!(g.check(1e12), Verdict::Outlier, "nor is one from the far future");
        assert_eq!(g.check(100.01), Verdict::Next, "the stream goes on on its own clock");
        assert_eq!(g.check(100.01), Verdict::Stale);
        assert_eq!(g.check(99.5), Verdict::Stale, "reordered");
        assert_eq!(g.check(f64::NAN), Verdict::Outlier);
        assert_eq!(g.last_s(), 100.01);
    }

    #[test]
    fn a_jump_that_several_samples_agree_on_is_believed() {
        let mut g = TimeGuard::new(2.0, 5, 0.0);
        g.check(100.0);
        // A reboot: the clock restarts at 1 s and runs on.
        for k in 0..4 {
            assert_eq!(g.check(1.0 + 0.01 * k as f64), Verdict::Outlier);
        }
        assert_eq!(g.check(1.04), Verdict::Jump { from_s: 100.0 });
        assert_eq!(g.check(1.05), Verdict::Next);
        // A link that was down for 5 s: forward, confirmed the same way.
        for k in 0..4 {
            assert_eq!(g.check(6.05 + 0.01 * k as f64), Verdict::Outlier);
        }
        assert_eq!(g.check(6.09), Verdict::Jump { from_s: 1.05 });
        // Outliers that disagree with each other never confirm anything.
        for k in 0..20 {
            let t = if k % 2 == 0 { 0.0 } else { 1e9 };
            assert_eq!(g.check(t), Verdict::Outlier);
        }
        assert_eq!(g.check(6.1), Verdict::Next);
    }

    #[test]
    fn a_steady_value_changes_only_when_confirmed() {
        let mut v = SteadyValue::new(1.0, 3);
        assert_eq!(v.offer(1.7e9), Some(1.7e9));
        assert_eq!(v.offer(1.7e9 + 0.001), Some(1.7e9 + 0.001));
        assert_eq!(v.offer(0.0), None, "one bad SYSTEM_TIME");
        assert_eq!(v.offer(1.7e9), Some(1.7e9));
        assert_eq!(v.offer(1.8e9), None);
        assert_eq!(v.offer(1.8e9), None);
        assert_eq!(v.offer(1.8e9), Some(1.8e9), "three agree: a new clock");
        assert_eq!(v.offer(f64::INFINITY), None);
    }

    #[test]
    fn a_burst_of_forged_samples_is_not_a_reboot() {
        // The autopilot's samples at 100 s, 200 Hz; five forged ones
        // stamped 1.000–1.004 s arrive at once, between two of them, again
        // and again: never believed, and the real stream goes on.
        let mut g = TimeGuard::new(2.0, 5, 0.25);
        let mut t = 100.0;
        assert_eq!(g.check(t), Verdict::Next);
        for _ in 0..13 {
            for k in 0..5 {
                assert_eq!(g.check(1.0 + k as f64 * 1e-3), Verdict::Outlier);
            }
            for _ in 0..40 {
                t += 0.005;
                assert_eq!(g.check(t), Verdict::Next);
            }
        }
        // A genuine reboot: the old clock falls silent and the new one runs
        // on; believed once it has run for 0.25 s.
        let mut taken_at = None;
        for k in 0..100 {
            let t_new = 1.0 + k as f64 * 0.005;
            match g.check(t_new) {
                Verdict::Outlier => {}
                Verdict::Jump { from_s } => {
                    assert_eq!(from_s, t);
                    taken_at = Some(t_new);
                    break;
                }
                v => panic!("{v:?}"),
            }
        }
        let taken_at = taken_at.expect("the reboot was believed");
        assert!((taken_at - 1.25).abs() < 1e-9, "{taken_at}");
    }
}
