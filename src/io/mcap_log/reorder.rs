//! Log-time order: records reach the writer in the order the fusion loop
//! made them, but their sensor times are not in order (a camera frame is
//! stamped when it was taken and fused ~50–100 ms later, a GNSS epoch up
//! to ~0.6 s later, beside IMU samples stamped as they come). Written as
//! they come, a 20 s demo's chunks overlapped 75 of 77 times, and a viewer
//! seeking by time had to decompress them all.
//!
//! [`Reorder`] holds each record until it can go out in log-time order:
//! until the newest log time seen is [`WINDOW_NS`] past it, it has waited
//! [`WAIT`] of wall time (a link that went quiet), [`MAX_ARRIVALS`] newer
//! records have come, or [`MAX_BYTES`] are held. A record that comes later
//! than that (older than one already written) is written at once, out of
//! order, and counted ([`Reorder::late`]).
//!
//! Each record gets a sequence number as it comes, one counter for every
//! channel: the order in which the fusion loop consumed its inputs, which
//! replay restores with [`SequenceOrder`]. Since no record is held past
//! [`MAX_ARRIVALS`] newer ones, at most that many records with a larger
//! sequence are written before it, which bounds what replay must hold.

use std::cmp::Reverse;
use std::collections::{BinaryHeap, VecDeque};
use std::time::{Duration, Instant};

/// A record waits until the newest log time is this far past its own (ns):
/// more than the latest a record comes in the demo (GNSS updates, 0.6 s).
pub(super) const WINDOW_NS: u64 = 1_000_000_000;
/// A record waits at most this long in wall time (the sensor clock may stop).
pub(super) const WAIT: Duration = Duration::from_secs(1);
/// A record is written before this many newer records have come: the bound
/// of how far behind its sequence a record is written ([`SequenceOrder`]).
pub const MAX_ARRIVALS: u32 = 16_384;
/// At most this much record data is held (bytes).
const MAX_BYTES: usize = 16 << 20;

/// A record this far from the stream's log time (ns), ahead of the newest
/// or behind the last written, is off the clock: one glitched stamp, or the
/// first of a jump (a reboot, a Unix time corrected).
pub(super) const JUMP_NS: u64 = 5_000_000_000;
/// Records in a row that must agree on a jump before the order follows it;
/// until then each is written at once, out of order, and counted late.
pub(super) const JUMP_CONFIRM: u32 = 8;

/// One record held, ordered by epoch (a clock that went back starts the
/// next), log time, then sequence.
struct Held<T> {
    epoch: u32,
    log_ns: u64,
    seq: u64,
    bytes: usize,
    item: T,
}

impl<T> Held<T> {
    fn key(&self) -> (u32, u64, u64) {
        (self.epoch, self.log_ns, self.seq)
    }
}

impl<T> PartialEq for Held<T> {
    fn eq(&self, other: &Self) -> bool {
        self.key() == other.key()
    }
}
impl<T> Eq for Held<T> {}
impl<T> PartialOrd for Held<T> {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl<T> Ord for Held<T> {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.key().cmp(&other.key())
    }
}

/// A record ready to be written: its log time and sequence number.
#[derive(Debug, PartialEq)]
pub(super) struct Ready<T> {
    pub log_ns: u64,
    pub seq: u32,
    pub item: T,
}

/// Which way a run of records off the clock goes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Off {
    Ahead,
    Behind,
}

/// The records waiting to be written in log-time order.
pub(super) struct Reorder<T> {
    heap: BinaryHeap<Reverse<Held<T>>>,
    /// The records held, in the order they came: `(epoch, log_ns, seq,
    /// when)`. Entries already written are dropped lazily from the front.
    arrivals: VecDeque<(u32, u64, u32, Instant)>,
    /// The next sequence number (the first is 1: 0 is MCAP's "none").
    next_seq: u32,
    /// The clock's epoch: one more each time it is confirmed to have gone
    /// back (the held records of the epoch before are all due).
    epoch: u32,
    /// The newest log time of this epoch (ns), once one is seen.
    newest_ns: Option<u64>,
    /// The last record written in order: `(epoch, log_ns, seq)`.
    last_out: Option<(u32, u64, u32)>,
    /// Records in a row off the clock, which way, and the last one's time.
    off: Option<(Off, u32, u64)>,
    held_bytes: usize,
    /// Records written out of log-time order (they came too late, or off
    /// the clock).
    pub late: u64,
}

impl<T> Default for Reorder<T> {
    fn default() -> Self {
        Self {
            heap: BinaryHeap::new(),
            arrivals: VecDeque::new(),
            next_seq: 1,
            epoch: 0,
            newest_ns: None,
            last_out: None,
            off: None,
            held_bytes: 0,
            late: 0,
        }
    }
}

impl<T> Reorder<T> {
    /// Whether `log_ns` is off the stream's clock, and which way.
    fn off_clock(&self, log_ns: u64) -> Option<Off> {
        if self.newest_ns.is_some_and(|n| log_ns > n.saturating_add(JUMP_NS)) {
            return Some(Off::Ahead);
        }
        let behind = self
            .last_out
            .filter(|o| o.0 == self.epoch)
            .or_else(|| self.newest_ns.map(|n| (self.epoch, n, 0)));
        behind
            .is_some_and(|(_, t, _)| log_ns.saturating_add(JUMP_NS) < t)
            .then_some(Off::Behind)
    }

    /// Takes a record of `bytes` data: it is held, or handed back to be
    /// written at once (older than a record already written, or off the
    /// clock and not yet confirmed by others).
    pub(super) fn push(&mut self, log_ns: u64, bytes: usize, item: T, now: Instant) -> Option<Ready<T>> {
        let seq = self.next_seq;
        self.next_seq = self.next_seq.wrapping_add(1).max(1);
        match self.off_clock(log_ns) {
            None => self.off = None,
            Some(way) => {
                let n = match self.off {
                    Some((w, n, last)) if w == way && log_ns.abs_diff(last) <= JUMP_NS => n + 1,
                    _ => 1,
                };
                if n < JUMP_CONFIRM {
                    // One glitched stamp must not become the order's
                    // reference: written as it is, counted.
                    self.off = Some((way, n, log_ns));
                    self.late += 1;
                    return Some(Ready { log_ns, seq, item });
                }
                // A jump, confirmed: the order follows the new clock. Back:
                // a new epoch, after everything held of the old one.
                self.off = None;
                if way == Off::Behind {
                    self.epoch += 1;
                    self.newest_ns = None;
                }
            }
        }
        if self.last_out.is_some_and(|(e, t, _)| e == self.epoch && log_ns < t) {
            self.late += 1;
            return Some(Ready { log_ns, seq, item });
        }
        self.newest_ns = Some(self.newest_ns.map_or(log_ns, |n| n.max(log_ns)));
        self.held_bytes += bytes;
        self.heap.push(Reverse(Held {
            epoch: self.epoch,
            log_ns,
            seq: u64::from(seq),
            bytes,
            item,
        }));
        self.arrivals.push_back((self.epoch, log_ns, seq, now));
        None
    }

    /// The next record due to be written at `now`, if any.
    pub(super) fn pop_due(&mut self, now: Instant) -> Option<Ready<T>> {
        let first = &self.heap.peek()?.0;
        let (epoch, min_ns) = (first.epoch, first.log_ns);
        let due = epoch < self.epoch
            || self.newest_ns.is_some_and(|n| min_ns.saturating_add(WINDOW_NS) <= n)
            || self.held_bytes > MAX_BYTES
            || self
                .oldest_arrival()
                .is_some_and(|(seq, when)| now >= when + WAIT || self.next_seq.wrapping_sub(seq) > MAX_ARRIVALS);
        if due {
            self.pop()
        } else {
            None
        }
    }

    /// The next record in log-time order, due or not (at the end of a file).
    pub(super) fn pop(&mut self) -> Option<Ready<T>> {
        let Reverse(h) = self.heap.pop()?;
        self.held_bytes -= h.bytes;
        // Held sequences came from the `u32` counter.
        let seq = h.seq as u32;
        self.last_out = Some((h.epoch, h.log_ns, seq));
        Some(Ready {
            log_ns: h.log_ns,
            seq,
            item: h.item,
        })
    }

    /// The wall time at which the oldest record held falls due, if any.
    pub(super) fn next_due(&mut self) -> Option<Instant> {
        self.oldest_arrival().map(|(_, when)| when + WAIT)
    }

    /// The record held longest: `(seq, arrived)`. Drops the written ones
    /// from the front (a record is written once the last one written in
    /// order is at or after it).
    fn oldest_arrival(&mut self) -> Option<(u32, Instant)> {
        if self.heap.is_empty() {
            self.arrivals.clear();
            return None;
        }
        while let Some(&(epoch, log_ns, seq, when)) = self.arrivals.front() {
            if self.last_out.is_some_and(|out| (epoch, log_ns, seq) <= out) {
                self.arrivals.pop_front();
            } else {
                return Some((seq, when));
            }
        }
        None
    }

    /// Nothing held, and the sequence begins again at 1 (a new file).
    pub(super) fn restart(&mut self) {
        debug_assert!(self.is_empty(), "the records held are written first");
        *self = Self {
            late: self.late,
            ..Self::default()
        };
    }

    pub(super) fn is_empty(&self) -> bool {
        self.heap.is_empty()
    }
}

/// Restores the order in which records came (their sequence numbers) from
/// a log written in log-time order: a record is given out once a record
/// [`MAX_ARRIVALS`] past it in sequence has been seen, since every record
/// before it is then in the file before that one. `note` is called for
/// every record of the log (kept or not), `push` for those to restore.
pub struct SequenceOrder<T> {
    heap: BinaryHeap<Reverse<Held<T>>>,
    /// The largest sequence seen, extended past `u32` wrap-arounds.
    max_seen: Option<u64>,
    /// A tie-break so that equal sequences (a corrupt log) keep file order.
    n: u64,
    /// The last sequence given out.
    last_out: Option<u64>,
    /// Items given out at or before the sequence of one given out before
    /// them: the log breaks the writer's rule (joined files, a log sorted
    /// by another tool, repeated sequences), and the order is not the one
    /// consumed.
    pub out_of_sequence: u64,
}

impl<T> Default for SequenceOrder<T> {
    fn default() -> Self {
        Self {
            heap: BinaryHeap::new(),
            max_seen: None,
            n: 0,
            last_out: None,
            out_of_sequence: 0,
        }
    }
}

impl<T> SequenceOrder<T> {
    /// The sequence `seq` of the log, extended to 64 bits near the largest
    /// seen so far.
    fn extend(&self, seq: u32) -> u64 {
        match self.max_seen {
            None => u64::from(seq),
            Some(m) => {
                let d = seq.wrapping_sub(m as u32) as i32;
                m.saturating_add_signed(i64::from(d))
            }
        }
    }

    /// Records a message of the log with sequence `seq` and, if `item` is
    /// given, holds it to be given out in order.
    pub fn push(&mut self, seq: u32, item: Option<T>) {
        let s = self.extend(seq);
        self.max_seen = Some(self.max_seen.map_or(s, |m| m.max(s)));
        if let Some(item) = item {
            self.n += 1;
            // `Held` orders by (log_ns, seq): here (sequence, file order).
            self.heap.push(Reverse(Held {
                epoch: 0,
                log_ns: s,
                seq: self.n,
                bytes: 0,
                item,
            }));
        }
    }

    /// The next item in sequence order, once it is sure no earlier one is
    /// still to come (or, with `end`, whatever is left). A log the writer
    /// did not make (sequences repeated, or all 0) could hold every record
    /// until its end: past `2 × MAX_ARRIVALS` held (a whole window of
    /// distinct sequences is at most `MAX_ARRIVALS`), the smallest goes.
    pub fn pop(&mut self, end: bool) -> Option<T> {
        let s = self.heap.peek()?.0.log_ns;
        let sure = self
            .max_seen
            .is_some_and(|m| m >= s.saturating_add(u64::from(MAX_ARRIVALS)))
            || self.heap.len() > 2 * MAX_ARRIVALS as usize;
        if !(end || sure) {
            return None;
        }
        let Reverse(h) = self.heap.pop()?;
        if self.last_out.is_some_and(|l| h.log_ns <= l) {
            self.out_of_sequence += 1;
        }
        self.last_out = Some(h.log_ns);
        Some(h.item)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Writes `times` (log times, ns, in arrival order) through a
    /// [`Reorder`] as the writer does, without wall-time waits; returns
    /// `(log_ns, seq)` in file order.
    fn write_all(times: &[u64]) -> (Vec<(u64, u32)>, u64) {
        let now = Instant::now();
        let mut r = Reorder::default();
        let mut out = Vec::new();
        for (i, &t) in times.iter().enumerate() {
            if let Some(x) = r.push(t, 100, i, now) {
                out.push((x.log_ns, x.seq));
            }
            while let Some(x) = r.pop_due(now) {
                out.push((x.log_ns, x.seq));
            }
        }
        while let Some(x) = r.pop() {
            out.push((x.log_ns, x.seq));
        }
        (out, r.late)
    }

    /// Arrival times: a 1 kHz clock, each record stamped up to `lag_ns`
    /// before its arrival.
    fn jittered(n: usize, lag_ns: u64, seed: u64) -> Vec<u64> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        (0..n as u64)
            .map(|i| (i * 1_000_000 + lag_ns).saturating_sub(rng.random_range(0..=lag_ns)))
            .collect()
    }

    #[test]
    fn records_late_by_less_than_the_window_come_out_in_log_time_order() {
        let times = jittered(20_000, 600_000_000, 1);
        let (out, late) = write_all(&times);
        assert_eq!(out.len(), times.len());
        assert_eq!(late, 0);
        assert!(out.windows(2).all(|w| w[0] <= w[1]), "in log-time order");
        // Every record, once, with its arrival's sequence number.
        let mut seqs: Vec<u32> = out.iter().map(|x| x.1).collect();
        seqs.sort_unstable();
        assert_eq!(seqs, (1..=times.len() as u32).collect::<Vec<_>>());
        for &(t, s) in &out {
            assert_eq!(times[s as usize - 1], t);
        }
    }

    #[test]
    fn a_record_later_than_the_window_is_written_at_once_and_counted() {
        let mut times: Vec<u64> = (0..3000u64).map(|i| i * 1_000_000).collect();
        times[2500] = 100_000_000; // 2.4 s late
        let (out, late) = write_all(&times);
        assert_eq!(late, 1);
        assert_eq!(out.len(), times.len());
        let backwards = out.windows(2).filter(|w| w[1].0 < w[0].0).count();
        assert_eq!(backwards, 1, "only the late record is out of order");
    }

    #[test]
    fn a_far_future_record_waits_at_most_max_arrivals_records() {
        // One record stamped an hour ahead, then 40 000 in order: it may not
        // hold back the others, nor be held back itself past the bound.
        let mut times: Vec<u64> = vec![3_600_000_000_000];
        times.extend((0..40_000u64).map(|i| i * 1_000));
        let (out, _) = write_all(&times);
        let pos = out.iter().position(|x| x.1 == 1).unwrap();
        assert!(pos <= MAX_ARRIVALS as usize, "written after {pos} newer records");
    }

    /// Records written out of log-time order in `out`, by the time before.
    fn backwards(out: &[(u64, u32)]) -> usize {
        out.windows(2).filter(|w| w[1].0 < w[0].0).count()
    }

    #[test]
    fn one_far_future_stamp_does_not_end_the_order() {
        // Red-team 1: one IMU sample stamped 10^9 s ahead made every later
        // record late (9 600 out of order). It is written as it is, counted,
        // and the order goes on.
        let mut times = jittered(6000, 600_000_000, 4);
        times[3000] = 1_000_000_000_000_000_000;
        let (out, late) = write_all(&times);
        assert_eq!(out.len(), times.len());
        assert_eq!(late, 1);
        assert!(backwards(&out) <= 1, "{} backwards", backwards(&out));
    }

    #[test]
    fn a_clock_that_goes_back_is_followed_after_eight_records() {
        // An autopilot reboot before the Unix time is known again: the log
        // time restarts 100 s back. The first eight on the new clock go out
        // at once (late), then the order follows the new clock.
        let mut times: Vec<u64> = (0..3000u64).map(|i| 100_000_000_000 + i * 1_000_000).collect();
        times.extend(jittered(3000, 500_000_000, 5));
        let (out, late) = write_all(&times);
        assert_eq!(out.len(), times.len());
        assert_eq!(late, u64::from(JUMP_CONFIRM) - 1);
        let after: Vec<_> = out.iter().filter(|x| x.0 < 50_000_000_000).copied().collect();
        assert!(
            backwards(&after) <= JUMP_CONFIRM as usize,
            "{} backwards",
            backwards(&after)
        );
    }

    #[test]
    fn a_record_waits_at_most_a_second_of_wall_time() {
        let t0 = Instant::now();
        let mut r = Reorder::default();
        assert!(r.push(5, 10, (), t0).is_none());
        assert!(r.pop_due(t0).is_none(), "held while nothing newer came");
        assert_eq!(r.next_due(), Some(t0 + WAIT));
        assert!(r.pop_due(t0 + WAIT).is_some(), "written a second later");
        assert!(r.next_due().is_none() && r.is_empty());
    }

    #[test]
    fn sequence_order_restores_arrival_order_from_any_file_the_writer_makes() {
        // Hostile arrivals: jitter, records seconds late, far-future stamps,
        // and a clock that jumps back (a reboot).
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
        let mut times = jittered(60_000, 900_000_000, 3);
        for _ in 0..50 {
            let i = rng.random_range(0..times.len());
            times[i] = match rng.random_range(0..3) {
                0 => times[i].saturating_sub(5_000_000_000),
                1 => times[i] + 3_600_000_000_000,
                _ => rng.random_range(0..1_000_000),
            };
        }
        for (i, t) in times.iter_mut().enumerate().skip(45_000) {
            *t = (i as u64 - 45_000) * 1_000_000; // rebooted clock
        }
        let (out, _) = write_all(&times);
        // Replay keeps every third record (its inputs) and must give them
        // back in the order they came.
        let mut order = SequenceOrder::default();
        let mut got = Vec::new();
        for &(_, seq) in &out {
            order.push(seq, (seq % 3 == 0).then_some(seq));
            while let Some(s) = order.pop(false) {
                got.push(s);
            }
        }
        while let Some(s) = order.pop(true) {
            got.push(s);
        }
        let want: Vec<u32> = (1..=times.len() as u32).filter(|s| s % 3 == 0).collect();
        assert_eq!(got, want);
    }

    #[test]
    fn sequence_order_holds_a_bounded_number_of_a_hostile_logs_records() {
        // Every sequence 0 (a log from another writer): records still come
        // out as they are read, never more than 2 × MAX_ARRIVALS held.
        let mut order = SequenceOrder::default();
        let (mut out, n) = (0usize, 100_000usize);
        for k in 0..n {
            order.push(0, Some(k));
            while order.pop(false).is_some() {
                out += 1;
            }
            assert!(k + 1 - out <= 2 * MAX_ARRIVALS as usize + 1);
        }
        while order.pop(true).is_some() {
            out += 1;
        }
        assert_eq!(out, n);
        assert_eq!(order.out_of_sequence, n as u64 - 1, "every repeat is counted");
    }

    #[test]
    fn sequence_order_survives_the_u32_wrap() {
        let mut order = SequenceOrder::default();
        let seqs = [u32::MAX - 2, u32::MAX, u32::MAX - 1, 1, 2];
        for s in seqs {
            order.push(s, Some(s));
        }
        let mut got = Vec::new();
        while let Some(s) = order.pop(true) {
            got.push(s);
        }
        assert_eq!(got, vec![u32::MAX - 2, u32::MAX - 1, u32::MAX, 1, 2]);
    }
}
