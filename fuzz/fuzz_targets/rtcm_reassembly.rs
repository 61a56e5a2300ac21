//! `GPS_RTCM_DATA` fragments (a flags byte, a length byte, then the data):
//! reassembled messages are never longer than four fragments.
#![no_main]
use cmsckf::gnss::reassembly::{Reassembled, Reassembler};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut r = Reassembler::new();
    let mut rest = data;
    while rest.len() >= 2 {
        let (flags, len) = (rest[0], rest[1] as usize);
        let take = len.min(rest.len() - 2);
        let mut res = r.push(flags, &rest[2..2 + take]);
        rest = &rest[2 + take..];
        loop {
            match res {
                Reassembled::Message(m) => {
                    assert!(m.len() <= 4 * 180);
                    break;
                }
                Reassembled::Dropped { then, .. } => res = *then,
                _ => break,
            }
        }
    }
});
