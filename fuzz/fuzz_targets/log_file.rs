//! A flight log file as `review`, `replay` and `log recover` open it: the
//! length check, then every reader they use on what it lets through. No
//! input may panic, abort on an allocation, or hang.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(checked) = cmsckf::io::mcap_log::check_bytes(data.to_vec()) else {
        return;
    };
    let bytes = checked.bytes;
    let _ = cmsckf::io::mcap_log::input::cmsckf_metadata(&bytes);
    let _ = mcap::Summary::read(&bytes);
    if let Ok(stream) = mcap::MessageStream::new_with_options(&bytes, mcap::read::Options::IgnoreEndMagic.into()) {
        for m in stream {
            if m.is_err() {
                break;
            }
        }
    }
});
