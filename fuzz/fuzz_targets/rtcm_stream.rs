//! An RTCM3 byte stream, fed in pieces: framing, CRC-24Q and decoding, with
//! the decoder's buffer bounded.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut dec = cmsckf::gnss::rtcm::RtcmDecoder::new();
    let mut out = Vec::new();
    let cut = data.first().map_or(1, |b| *b as usize + 1);
    for piece in data.chunks(cut) {
        dec.push(piece, &mut out);
        assert!(dec.buffered() <= 3 * 1029);
    }
});
