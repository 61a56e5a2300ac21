//! A config file: loaded and validated, or rejected with a message.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        if let Ok(cfg) = cmsckf::config::Config::from_toml(text, "fuzz") {
            assert!(cfg.validate().is_ok());
        }
    }
});
