//! The time a log covers, judged so that a bad stamp cannot fool it.
//!
//! Log time is the autopilot's clock, and a record may carry any time: a
//! far-future stamp from a front end, a record from before a reboot (whose
//! boot clock restarts near 1 s), a frame a little late. The span of the
//! times (latest − earliest) is then wrong by up to 18 billion seconds. So
//! the review follows the clocks instead:
//!
//! - the records are read in file order into *segments*: a record within
//!   [`MAX_STEP_NS`] (10 s) of a segment's latest time belongs to it (the
//!   nearest such, if several), and one that is not starts a new segment;
//! - a segment covers the time from its first record's to its latest
//!   record's: a record inside that adds nothing, a later one adds the step;
//! - the log's duration is the sum of what the segments cover.
//!
//! An isolated bad stamp (or a handful at one instant) makes a segment that
//! covers nothing; after a reboot the new clock is a segment of its own, and
//! its time adds to the old one's; a gap of more than 10 s with no record
//! counts as nothing. A stamp up to 10 s ahead can add at most its lead.
//! For the time axes, a time is *plausible* if it lies in a segment of at
//! least [`MIN_SEGMENT_RECORDS`] records (all are, when no segment has that
//! many); the series of the plots and the TUM export keep only those.

/// The largest step (ns) between a record and its segment's latest time.
pub(super) const MAX_STEP_NS: u64 = 10_000_000_000;
/// Records a segment needs to count on the time axes (a bad stamp brings a
/// handful at most: the input, and what the daemon logged about it).
pub(super) const MIN_SEGMENT_RECORDS: u64 = 50;
/// Segments followed at once; the one touched least recently is forgotten
/// (its time stays counted).
const MAX_OPEN_SEGMENTS: usize = 16;

/// One clock's run of records.
#[derive(Clone, Copy, Debug)]
struct Segment {
    first_ns: u64,
    latest_ns: u64,
    records: u64,
    /// The reader's record count when it was last touched.
    touched: u64,
}

/// The segments of a log's times, fed in file order.
#[derive(Debug, Default)]
pub(super) struct Timeline {
    open: Vec<Segment>,
    /// Segments forgotten but long enough for the time axes: `(first, latest)`.
    kept: Vec<(u64, u64)>,
    covered_ns: u64,
    pushed: u64,
}

impl Timeline {
    /// Takes one record's log time (ns); a time of 0 (none) is skipped.
    pub fn push(&mut self, t_ns: u64) {
        if t_ns == 0 {
            return;
        }
        self.pushed += 1;
        let nearest = self
            .open
            .iter_mut()
            .filter(|s| s.latest_ns.abs_diff(t_ns) <= MAX_STEP_NS)
            .min_by_key(|s| s.latest_ns.abs_diff(t_ns));
        match nearest {
            Some(s) => {
                if t_ns > s.latest_ns {
                    self.covered_ns += t_ns - s.latest_ns;
                    s.latest_ns = t_ns;
                }
                s.first_ns = s.first_ns.min(t_ns);
                s.records += 1;
                s.touched = self.pushed;
            }
            None => {
                if self.open.len() >= MAX_OPEN_SEGMENTS {
                    self.forget_stalest();
                }
                self.open.push(Segment {
                    first_ns: t_ns,
                    latest_ns: t_ns,
                    records: 1,
                    touched: self.pushed,
                });
            }
        }
    }

    /// Forgets the segment touched least recently, keeping its span for the
    /// time axes if it is long enough.
    fn forget_stalest(&mut self) {
        let Some(i) = (0..self.open.len()).min_by_key(|&i| self.open[i].touched) else {
            return;
        };
        let s = self.open.swap_remove(i);
        if s.records >= MIN_SEGMENT_RECORDS {
            self.kept.push((s.first_ns, s.latest_ns));
        }
    }

    /// The time the log covers (s).
    pub fn duration_s(&self) -> f64 {
        self.covered_ns as f64 * 1e-9
    }

    /// The spans (s) of the segments that count on the time axes, or `None`
    /// if none does (a short log: every time is plausible).
    pub fn plausible_spans_s(&self) -> Option<Vec<(f64, f64)>> {
        let spans: Vec<(f64, f64)> = self
            .kept
            .iter()
            .copied()
            .chain(
                self.open
                    .iter()
                    .filter(|s| s.records >= MIN_SEGMENT_RECORDS)
                    .map(|s| (s.first_ns, s.latest_ns)),
            )
            .map(|(a, b)| (a as f64 * 1e-9, b as f64 * 1e-9))
            .collect();
        (!spans.is_empty()).then_some(spans)
    }
}

/// Whether `t_s` lies in one of `spans` (all times do when there are none).
pub(super) fn plausible(spans: Option<&[(f64, f64)]>, t_s: f64) -> bool {
    spans.is_none_or(|v| v.iter().any(|&(a, b)| (a..=b).contains(&t_s)))
}

#[cfg(test)]
mod tests {
    use super::*;

    const S: u64 = 1_000_000_000;

    /// 1 kHz records from `a` s to `b` s.
    fn run(tl: &mut Timeline, a: f64, b: f64) {
        let n = ((b - a) * 1000.0).round() as u64;
        for k in 0..=n {
            tl.push(((a + k as f64 * 1e-3) * 1e9) as u64);
        }
    }

    #[test]
    fn outliers_add_nothing_and_reboots_add_their_time() {
        let mut tl = Timeline::default();
        run(&mut tl, 20.0, 30.0);
        tl.push(u64::MAX); // far future (a saturated stamp)
        tl.push(S); // a stray record at boot + 1 s
        run(&mut tl, 30.001, 40.0);
        assert!((tl.duration_s() - 20.0).abs() < 0.01, "{}", tl.duration_s());
        // A reboot: the clock restarts at 1 s and runs 15 s.
        run(&mut tl, 1.0, 16.0);
        assert!((tl.duration_s() - 35.0).abs() < 0.01, "{}", tl.duration_s());
        let spans = tl.plausible_spans_s().unwrap();
        assert!(plausible(Some(&spans), 25.0) && plausible(Some(&spans), 10.0));
        assert!(!plausible(Some(&spans), 1e10) && !plausible(Some(&spans), 17.0));
    }

    #[test]
    fn late_records_are_not_counted_twice() {
        let mut tl = Timeline::default();
        for k in 0..1000u64 {
            let t = 20 * S + k * 10_000_000;
            tl.push(t);
            // A frame logged 150 ms late, every 5th record.
            if k % 5 == 0 && k > 20 {
                tl.push(t - 150_000_000);
            }
        }
        assert!((tl.duration_s() - 9.99).abs() < 1e-6, "{}", tl.duration_s());
    }

    #[test]
    fn many_stray_stamps_do_not_crowd_out_the_flight() {
        let mut tl = Timeline::default();
        for k in 0..10_000u64 {
            tl.push(100 * S + k * 1_000_000);
            if k % 100 == 0 {
                tl.push((k + 1) * 1_000 * S); // each far from the others
            }
        }
        assert!((tl.duration_s() - 9.999).abs() < 1e-6, "{}", tl.duration_s());
        assert_eq!(tl.plausible_spans_s().unwrap().len(), 1);
    }
}
