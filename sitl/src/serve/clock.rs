//! The autopilot's boot clock: the stamps the mock autopilot puts on the
//! wire, and the mapping of the daemon's stamps back to flight time, across
//! a simulated reboot.

use std::time::Instant;

use super::receive::Received;
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

/// Flight times of the estimates, in arrival order: their boot-clock stamps
/// mapped back through [`boot_us`], switching to the post-reboot clock at
/// the first stamp that falls back by more than 2 s.
pub(super) fn flight_times(rec: &mut [Received], reboot_s: Option<f64>) {
    let mut after = false;
    let mut max_boot_s = f64::NEG_INFINITY;
    for r in rec {
        let boot_s = r.t_us as f64 * 1e-6;
        if reboot_s.is_some() && boot_s < max_boot_s - 2.0 {
            after = true;
        }
        max_boot_s = max_boot_s.max(boot_s);
        r.t_s = match reboot_s {
            Some(rb) if after => boot_s + rb - 1.0,
            _ => boot_s - BOOT0_S,
        };
    }
}
