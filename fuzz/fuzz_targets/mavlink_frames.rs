//! Bytes off the MAVLink link into the adapter: framing, then conversion to
//! SI units (non-finite and out-of-range values rejected).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = cmsckf::io::mavlink::decode_bytes(data);
});
