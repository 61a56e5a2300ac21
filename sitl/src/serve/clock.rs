//! The autopilot's boot clock: the stamps the mock autopilot puts on the
//! wire, across a simulated reboot (the report maps the daemon's stamps back
//! to flight time the same way).

use std::time::Instant;

use super::BOOT0_S;

/// The autopilot's boot clock (µs) at flight time `t_s`: `BOOT0_S` at the
/// start, or 1 s at a reboot at `reboot_s` and counting from there.
pub(super) fn boot_us(t_s: f64, reboot_s: Option<f64>) -> u64 {
    match reboot_s {
        Some(r) if t_s >= r => ((t_s - r + 1.0) * 1e6).round() as u64,
        _ => ((t_s + BOOT0_S) * 1e6).round() as u64,
    }
}

/// The boot clock (ns) by the wall clock, `started` being the start of the
/// flight: what TIMESYNC answers.
pub(super) fn boot_ns(started: Instant) -> i64 {
    ((BOOT0_S * 1e9) as i64) + started.elapsed().as_nanos() as i64
}
