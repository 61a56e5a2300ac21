//! A feature-socket line: parsed or rejected, never a panic; accepted lines
//! are within the limits and finite.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(f) = cmsckf::io::feature_pipe::parse_line(data, 100) {
        assert!(f.features.len() <= 100);
        assert!(f.features.iter().all(|x| x.1.is_finite() && x.2.is_finite()));
    }
});
