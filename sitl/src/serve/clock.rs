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

/// Maps the daemon's boot-clock stamps back to flight time, in the order
/// they arrive: the inverse of [`boot_us`], switching to the post-reboot
/// clock at the first stamp that falls back by more than 2 s (the daemon
/// cannot stamp anything on the new clock before the reboot).
#[derive(Clone, Copy, Debug)]
pub(super) struct FlightClock {
    reboot_s: Option<f64>,
    after: bool,
    max_boot_s: f64,
}

impl FlightClock {
    pub(super) fn new(reboot_s: Option<f64>) -> Self {
        Self {
            reboot_s,
            after: false,
            max_boot_s: f64::NEG_INFINITY,
        }
    }

    /// Flight time (s) of the next stamp `t_us` (µs of boot clock).
    pub(super) fn flight_s(&mut self, t_us: u64) -> f64 {
        let boot_s = t_us as f64 * 1e-6;
        if self.reboot_s.is_some() && boot_s < self.max_boot_s - 2.0 {
            self.after = true;
        }
        self.max_boot_s = self.max_boot_s.max(boot_s);
        match self.reboot_s {
            Some(rb) if self.after => boot_s + rb - 1.0,
            _ => boot_s - BOOT0_S,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flight_clock_inverts_boot_us_across_a_reboot() {
        let mut c = FlightClock::new(Some(50.0));
        for t in [0.0, 10.0, 49.9] {
            assert!((c.flight_s(boot_us(t, Some(50.0))) - t).abs() < 1e-9);
        }
        for t in [52.0, 60.0] {
            assert!((c.flight_s(boot_us(t, Some(50.0))) - t).abs() < 1e-9);
        }
        let mut plain = FlightClock::new(None);
        assert!((plain.flight_s(boot_us(12.5, None)) - 12.5).abs() < 1e-9);
    }
}
