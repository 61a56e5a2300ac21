//! GNSS at receiver rates (README §8c, eqs. DG5′, DG6): the broadcast orbit
//! and clock and the troposphere errors hold for the whole flight, so a 5 or
//! 10 Hz receiver repeats them more often, not more independently. As states
//! they are believed once at any rate; the position NEES stays honest at 1,
//! 5 and 10 Hz, and the faster receivers are no less accurate.
//!
//! With the errors fused as white noise at every epoch (3 seeds, when every
//! seed shared one week's broadcast draw):
//! position NEES 3.96 at 1 Hz, 11.35 at 5 Hz (16.7 in the second half) and
//! 21.8 at 10 Hz (34.2), with 30% and 17% of frames inside their 95% bound
//! at 5 and 10 Hz.

use cmsckf::config::Config;
use cmsckf::estimator::Mode;
use cmsckf::eval;

/// The racetrack, compressed, 6 seeds of 70 s with the GNSS at `rate_hz`.
fn at_rate(rate_hz: f64) -> eval::ModeSummary {
    let cfg = Config::default();
    let mut sim = eval::sim_config_for(&cfg);
    sim.gnss.rate_hz = rate_hz;
    let ev = eval::evaluate(
        &eval::EvalSpec {
            scenario: "racetrack".into(),
            modes: vec![Mode::Compressed],
            seeds: eval::Seeds::UpTo(6),
            duration_s: Some(70.0),
            gnss: true,
            landed_state: true,
        },
        &cfg,
        &sim,
        |_| {},
    )
    .unwrap();
    ev.modes["compressed"].clone()
}

#[test]
fn position_nees_is_honest_at_1_5_and_10_hz() {
    let one = at_rate(1.0);
    for rate_hz in [1.0, 5.0, 10.0] {
        let m = if rate_hz == 1.0 { one.clone() } else { at_rate(rate_hz) };
        eprintln!(
            "{rate_hz} Hz: ATE {:.3} m, position NEES {:.2} (second half {:.2}), {:.0}% of frames in 95%, pose NEES {:.2}",
            m.ate_unaligned_m,
            m.nees_position_mean,
            m.nees_position_mean_second_half,
            100.0 * m.nees_position_in_bounds_per_time,
            m.nees_mean
        );
        // 3 dof; the 95% interval of a 6-seed mean is about [1.3, 5.2]:
        // the issue asks for 4.4 at most over the flight. The second half at
        // 5 Hz is 4.47: GNSS makes the yaw observable and its NEES 1.9 on
        // 1 dof in that half, the same with DG6's windows (docs/status.md),
        // which hid it in the position by weakening every code to a 2.4 m
        // error counted per window (2.81 then, at an ATE of 0.22 m against
        // 0.21 m).
        assert!(
            (0.9..=4.4).contains(&m.nees_position_mean),
            "{rate_hz} Hz: position NEES {:.2}",
            m.nees_position_mean
        );
        let half = m.nees_position_mean_second_half;
        assert!(
            (0.9..=5.0).contains(&half),
            "{rate_hz} Hz: second half's position NEES {half:.2}"
        );
        assert!(m.nees_position_in_bounds_per_time >= 0.8, "{rate_hz} Hz");
        assert!(
            m.ate_unaligned_m <= 1.1 * one.ate_unaligned_m,
            "{rate_hz} Hz: ATE {:.3} m",
            m.ate_unaligned_m
        );
    }
}
