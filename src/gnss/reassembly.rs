//! Reassembles RTCM3 messages from MAVLink `GPS_RTCM_DATA` fragments.
//!
//! Per the MAVLink spec: flags bit 0 = fragmented; bits 1–2 = fragment id;
//! bits 3–7 = sequence id. Fragments carry at most 180 bytes and there are at
//! most 4; a message is complete at the first fragment shorter than 180
//! bytes, or after the 4th. A sequence with a missing fragment is dropped
//! and counted.

use crate::counters::Counter;

/// Largest fragment payload (bytes).
pub const FRAGMENT_LEN: usize = 180;

/// What one fragment did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Reassembled {
    /// A complete message (owned bytes).
    Message(Vec<u8>),
    /// Waiting for more fragments.
    Pending,
    /// A sequence was abandoned because a fragment was missing; the new
    /// fragment was then taken as usual (`then`).
    Dropped { reason: Counter, then: Box<Reassembled> },
    /// The fragment itself is unusable.
    Rejected(Counter),
}

/// The reassembler state (bounded: at most 4 × 180 bytes).
#[derive(Debug, Default)]
pub struct Reassembler {
    seq: Option<u8>,
    /// A sequence already dropped: its later fragments are ignored.
    skip: Option<u8>,
    next_frag: u8,
    buf: Vec<u8>,
}

impl Reassembler {
    pub fn new() -> Self {
        Self {
            seq: None,
            skip: None,
            next_frag: 0,
            buf: Vec::with_capacity(4 * FRAGMENT_LEN),
        }
    }

    /// Feeds one fragment (`data` is the used part, `len` bytes).
    pub fn push(&mut self, flags: u8, data: &[u8]) -> Reassembled {
        if data.len() > FRAGMENT_LEN {
            return Reassembled::Rejected(Counter::RtcmFragmentTooLong);
        }
        if flags & 1 == 0 {
            // Not fragmented: a whole message on its own.
            let dropped = self.abandon();
            let r = Reassembled::Message(data.to_vec());
            return match dropped {
                Some(reason) => Reassembled::Dropped {
                    reason,
                    then: Box::new(r),
                },
                None => r,
            };
        }
        let frag = (flags >> 1) & 0x3;
        let seq = flags >> 3;
        if self.skip == Some(seq) && frag != 0 {
            return Reassembled::Pending;
        }
        self.skip = None;
        let mut dropped = None;
        if self.seq.is_some() && (self.seq != Some(seq) || frag != self.next_frag) {
            let same = self.seq == Some(seq);
            dropped = self.abandon();
            if same {
                // The rest of this sequence is lost with it.
                self.skip = Some(seq);
                return Reassembled::Dropped {
                    reason: Counter::RtcmFragmentMissing,
                    then: Box::new(Reassembled::Pending),
                };
            }
        }
        let r = if self.seq.is_none() && frag != 0 {
            self.skip = Some(seq);
            // The start of this sequence was lost.
            Reassembled::Dropped {
                reason: Counter::RtcmFragmentMissing,
                then: Box::new(Reassembled::Pending),
            }
        } else {
            self.seq = Some(seq);
            self.buf.extend_from_slice(data);
            self.next_frag = frag + 1;
            if data.len() < FRAGMENT_LEN || frag == 3 {
                self.seq = None;
                self.next_frag = 0;
                Reassembled::Message(std::mem::take(&mut self.buf))
            } else {
                Reassembled::Pending
            }
        };
        match dropped {
            Some(reason) => Reassembled::Dropped {
                reason,
                then: Box::new(r),
            },
            None => r,
        }
    }

    fn abandon(&mut self) -> Option<Counter> {
        let had = self.seq.take().is_some();
        self.buf.clear();
        self.next_frag = 0;
        had.then_some(Counter::RtcmFragmentMissing)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frag(seq: u8, id: u8) -> u8 {
        1 | (id << 1) | (seq << 3)
    }

    #[test]
    fn whole_and_fragmented_messages() {
        let mut r = Reassembler::new();
        assert_eq!(r.push(0, &[1, 2, 3]), Reassembled::Message(vec![1, 2, 3]));
        let a = vec![7u8; 180];
        assert_eq!(r.push(frag(5, 0), &a), Reassembled::Pending);
        assert_eq!(r.push(frag(5, 1), &a), Reassembled::Pending);
        let Reassembled::Message(m) = r.push(frag(5, 2), &[9; 10]) else {
            panic!()
        };
        assert_eq!(m.len(), 370);
        // Four full fragments complete a message.
        for i in 0..3 {
            assert_eq!(r.push(frag(6, i), &a), Reassembled::Pending);
        }
        let Reassembled::Message(m) = r.push(frag(6, 3), &a) else {
            panic!()
        };
        assert_eq!(m.len(), 720);
    }

    #[test]
    fn a_lost_fragment_drops_the_sequence() {
        let mut r = Reassembler::new();
        let a = vec![7u8; 180];
        assert_eq!(r.push(frag(1, 0), &a), Reassembled::Pending);
        // Fragment 1 lost; fragment 2 arrives.
        let got = r.push(frag(1, 2), &[1; 5]);
        assert!(
            matches!(
                got,
                Reassembled::Dropped {
                    reason: Counter::RtcmFragmentMissing,
                    ..
                }
            ),
            "{got:?}"
        );
        // A new sequence starts cleanly.
        assert_eq!(r.push(frag(2, 0), &[5; 20]), Reassembled::Message(vec![5; 20]));
        assert_eq!(
            r.push(0, &[0; 181]),
            Reassembled::Rejected(Counter::RtcmFragmentTooLong)
        );
    }
}
