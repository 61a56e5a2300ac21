//! Whether the base station's corrections are used, and how much each is
//! believed: the daemon's side of differential GNSS, apart from decoding.
//! A base must only ever help. Its corrections are refused while its
//! announced antenna position is unchecked or wrong (`gnss::dgnss` checks
//! it against the base's own fixes); a base whose corrected codes keep
//! failing the filter's gate is set aside for `gnss.base_holdoff_s`, and
//! the rover flies on single point meanwhile, never reset. Each correction
//! is counted as shared by the rover epochs it corrects (estimator README
//! §8c, eq. DG7).

use std::collections::VecDeque;

use crate::counters::{Counter, Counters};
use crate::gnss::dgnss::{BaseCorrections, DgnssError};
use crate::status::{Degraded, Tracker};

/// Differential epochs the rejection judge looks back over, and how many of
/// them must have most of their codes refused to set the base aside.
const JUDGED_EPOCHS: usize = 5;
const BAD_EPOCHS_TO_SET_ASIDE: usize = 3;

/// The daemon's use of a base station.
#[derive(Debug)]
pub(super) struct BaseUse {
    holdoff_s: f64,
    /// Set aside until this autopilot time (s).
    set_aside_until_s: f64,
    /// The last differential epochs fused: whether most of their codes were
    /// refused.
    recent_bad: VecDeque<bool>,
    /// The base station and epoch (time of week) of the last corrections
    /// and the rover epochs they have corrected.
    current: Option<(u16, f64, u32)>,
    /// The rover's last epoch (time of week) and its period (s).
    last_rover_tow_s: Option<f64>,
    rover_period_s: Option<f64>,
    /// The last refusal said, so that it is logged when it changes only.
    last_refusal: Option<String>,
}

impl BaseUse {
    pub(super) fn new(holdoff_s: f64) -> Self {
        BaseUse {
            holdoff_s,
            set_aside_until_s: f64::NEG_INFINITY,
            recent_bad: VecDeque::with_capacity(JUDGED_EPOCHS),
            current: None,
            last_rover_tow_s: None,
            rover_period_s: None,
            last_refusal: None,
        }
    }

    /// Whether the base may correct a rover epoch at autopilot time `t_s`
    /// (not set aside); counted when it may not.
    pub(super) fn usable(&self, t_s: f64, counters: &Counters) -> bool {
        let ok = t_s >= self.set_aside_until_s;
        if !ok {
            counters.add(Counter::GnssBaseSetAsideEpochs, 1);
        }
        ok
    }

    /// The corrections for a rover epoch at time of week `rover_tow_s`, or
    /// why there are none: counted by reason, a refused base degrades the
    /// HEARTBEAT (with its STATUSTEXT) and is logged when the reason
    /// changes. `Some(shared_by)` when the corrections are used (DG7).
    pub(super) fn take(
        &mut self,
        rover_tow_s: f64,
        t_s: f64,
        result: &Result<BaseCorrections, DgnssError>,
        counters: &Counters,
        tracker: &mut Tracker,
    ) -> Option<f64> {
        if let Some(last) = self.last_rover_tow_s {
            let spacing = rover_tow_s - last;
            if spacing > 1e-3 && spacing < 60.0 {
                self.rover_period_s = Some(self.rover_period_s.map_or(spacing, |p: f64| p.min(spacing)));
            }
        }
        self.last_rover_tow_s = Some(rover_tow_s);
        let c = match result {
            Ok(c) if !c.values.is_empty() => c,
            Ok(_) | Err(DgnssError::NoBaseEpoch) | Err(DgnssError::NoBasePosition) | Err(DgnssError::Solve(_)) => {
                counters.add(Counter::GnssDgnssUnavailable, 1);
                return None;
            }
            Err(e) => {
                let counter = match e {
                    DgnssError::BasePositionWrong { .. } => {
                        tracker.hold_reason(Degraded::GnssBaseRefused, t_s);
                        Counter::GnssBasePositionWrong
                    }
                    _ => Counter::GnssBasePositionUnchecked,
                };
                counters.add(counter, 1);
                self.say_refusal(e.to_string());
                return None;
            }
        };
        self.last_refusal = None;
        if c.non_finite > 0 {
            counters.add(Counter::GnssBaseNonFiniteCorrection, c.non_finite);
        }
        let uses = match self.current {
            Some((id, tow, n)) if id == c.station_id && tow == c.base_tow_s => n + 1,
            _ => 1,
        };
        self.current = Some((c.station_id, c.base_tow_s, uses));
        // Shared by the rover epochs between two base epochs at least.
        let per_base_epoch = match (c.base_period_s, self.rover_period_s) {
            (Some(b), Some(r)) if r > 0.0 => b / r,
            _ => 1.0,
        };
        Some(f64::from(uses).max(per_base_epoch).max(1.0))
    }

    /// A differential epoch fused at `t_s` with `used` codes and `refused`
    /// ones: a base whose codes keep being refused is set aside.
    pub(super) fn on_fused(&mut self, t_s: f64, used: usize, refused: u64, counters: &Counters, tracker: &mut Tracker) {
        if self.recent_bad.len() == JUDGED_EPOCHS {
            self.recent_bad.pop_front();
        }
        self.recent_bad.push_back(refused >= 2 && refused as usize > used);
        if self.recent_bad.iter().filter(|b| **b).count() < BAD_EPOCHS_TO_SET_ASIDE {
            return;
        }
        self.recent_bad.clear();
        self.set_aside_until_s = t_s + self.holdoff_s;
        tracker.hold_reason_until(Degraded::GnssBaseRefused, self.set_aside_until_s);
        counters.add(Counter::GnssBaseSetAside, 1);
        tracing::warn!(
            reason = "gnss_base_set_aside",
            holdoff_s = self.holdoff_s,
            "most of the base's corrected codes fail the filter's gate: single point for {} s",
            self.holdoff_s
        );
    }

    fn say_refusal(&mut self, why: String) {
        if self.last_refusal.as_deref() != Some(why.as_str()) {
            tracing::warn!(
                reason = "gnss_base_refused",
                "base station's corrections not used: {why}"
            );
            self.last_refusal = Some(why);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn corrections(base_tow_s: f64, base_period_s: Option<f64>) -> BaseCorrections {
        BaseCorrections {
            station_id: 100,
            base_tow_s,
            age_s: 0.5,
            base_period_s,
            reference_steps_m: Vec::new(),
            values: vec![((crate::gnss::rtcm::System::Gps, 1), 0.3)],
            non_finite: 0,
        }
    }

    #[test]
    fn a_correction_is_shared_by_the_rover_epochs_it_corrects() {
        let (c, mut t) = (Counters::default(), Tracker::default());
        let mut b = BaseUse::new(30.0);
        // A 5 Hz rover on a 1 Hz base: each correction serves five epochs.
        let mut shared = Vec::new();
        for k in 0..10 {
            let rover = 100.0 + 0.2 * k as f64;
            let base = 100.0 + (0.2 * k as f64).floor();
            shared.push(
                b.take(rover, rover, &Ok(corrections(base, Some(1.0))), &c, &mut t)
                    .unwrap(),
            );
        }
        assert_eq!(shared[0], 1.0, "the rover's period is not known yet");
        assert!(shared[2..].iter().all(|s| (*s - 5.0).abs() < 1e-9), "{shared:?}");
        // A silent base: its last correction serves on, believed less each time.
        let held: Vec<f64> = (0..20)
            .map(|k| {
                let rover = 102.0 + 0.2 * k as f64;
                b.take(rover, rover, &Ok(corrections(101.0, Some(1.0))), &c, &mut t)
                    .unwrap()
            })
            .collect();
        assert!(held.windows(2).all(|w| w[1] >= w[0]) && held[19] > 20.0, "{held:?}");
    }

    #[test]
    fn a_base_whose_codes_keep_failing_is_set_aside_for_the_holdoff() {
        let (c, mut t) = (Counters::default(), Tracker::default());
        let mut b = BaseUse::new(30.0);
        // Two bad epochs of five: kept.
        for (k, bad) in [false, true, false, true, false].into_iter().enumerate() {
            b.on_fused(k as f64, if bad { 3 } else { 8 }, if bad { 6 } else { 1 }, &c, &mut t);
        }
        assert!(b.usable(5.0, &c));
        b.on_fused(5.0, 3, 9, &c, &mut t);
        assert!(!b.usable(5.5, &c), "three bad epochs of the last five");
        assert_eq!(c.get(Counter::GnssBaseSetAside), 1);
        assert_eq!(c.get(Counter::GnssBaseSetAsideEpochs), 1);
        assert!(!b.usable(34.9, &c));
        assert!(b.usable(35.0, &c), "tried again after the hold-off");
    }

    #[test]
    fn refusals_are_counted_by_reason() {
        let (c, mut t) = (Counters::default(), Tracker::default());
        let mut b = BaseUse::new(30.0);
        let wrong = Err(DgnssError::BasePositionWrong {
            horizontal_m: 28.0,
            vertical_m: 3.0,
            limit_m: 10.0,
        });
        assert_eq!(b.take(1.0, 1.0, &wrong, &c, &mut t), None);
        assert_eq!(
            b.take(2.0, 2.0, &Err(DgnssError::BasePositionUnchecked), &c, &mut t),
            None
        );
        assert_eq!(b.take(3.0, 3.0, &Err(DgnssError::NoBaseEpoch), &c, &mut t), None);
        assert_eq!(
            [
                Counter::GnssBasePositionWrong,
                Counter::GnssBasePositionUnchecked,
                Counter::GnssDgnssUnavailable
            ]
            .map(|k| c.get(k)),
            [1, 1, 1]
        );
    }
}
