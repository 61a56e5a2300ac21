//! The compass heading averaged while the vehicle stands before take-off
//! (estimator README §7, eq. H1). Why this exists: the filter starts from
//! the mean heading of the last second's magnetometer readings, and some
//! magnetometers scatter by degrees a reading (PX4's SIH by 1.7-2.9° a 100 ms
//! reading: a 0.6-1.7° error in that mean, up to 0.3 m across a 10 m box).
//! Every reading that comes while the vehicle stands still and disarmed
//! averages that noise down; the compass's bias (hard iron, the
//! declination model) does not average, so the yaw's sigma keeps it. This
//! keeps the running mean, decides which readings may enter it, and says
//! when the filter's yaw should be conditioned on a better one.
//!
//! A reading enters the mean only [`SETTLE_S`] after it came, if the
//! vehicle has stood still and disarmed since: the autopilot says it armed
//! up to a second late (HEARTBEAT at 1 Hz), with its motors already
//! spinning, and the filter sees a turn a frame late.

use std::collections::VecDeque;

use cmsckf_models::magnetic;
use nalgebra::{UnitQuaternion, Vector3};

/// The filter's yaw is conditioned once this many more readings have been
/// averaged (10 Hz: once a second).
const READINGS_PER_STEP: u32 = 10;

/// Fewest readings a start's mean is taken over with its noise measured
/// (their scatter needs a few degrees of freedom); with fewer the start
/// takes their mean direction and the compass's bias sigma alone, as
/// before, and no averaging follows.
const MIN_START_READINGS: usize = 5;

/// A reading enters the mean this long after it came (s of autopilot
/// time), and only if the vehicle has stood disarmed and still since.
pub(super) const SETTLE_S: f64 = 1.5;

/// Readings waiting to settle, at most (10 Hz for 1.5 s is 15).
const MAX_PENDING: usize = 64;

/// Most readings averaged (30 s at 10 Hz): by then the mean's noise is far
/// below the compass's bias, and a standing vehicle's slow changes (a
/// warming board, a car parked beside it) are not noise to average.
const MAX_READINGS: u32 = 300;

/// A reading further from the mean than this many of the readings' sigmas,
/// and at least [`OUTLIER_FLOOR_RAD`], is not the compass's noise (a
/// disturbance): counted, not averaged.
const OUTLIER_SIGMAS: f64 = 5.0;
const OUTLIER_FLOOR_RAD: f64 = 0.1;

/// This many outliers in a row: the compass disagrees with the start's
/// mean (a start taken while the vehicle moved, or a field that changed),
/// and the averaging ends, said in the log.
const OUTLIER_RUN_END: u32 = 10;

/// The vehicle has turned since the start by more than this (rad) of its
/// gyro-propagated yaw, or tilted by more than [`MAX_TILT_RAD`] in roll or
/// pitch (the readings are levelled with the start's tilt): the averaging
/// ends.
pub(super) const MAX_TURN_RAD: f64 = 0.035;
pub(super) const MAX_TILT_RAD: f64 = 0.0175;

/// One conditioning of the filter's yaw (eq. H1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct YawStep {
    /// The better mean less the one the filter holds (rad).
    pub shift_rad: f64,
    /// The drop of the mean's noise variance (rad²).
    pub drop_rad2: f64,
}

/// What a reading did.
#[derive(Clone, Debug, PartialEq)]
pub(super) enum Pushed {
    Nothing,
    /// The filter's yaw is due a conditioning; call
    /// [`CompassMean::held`] once it took it.
    Step(YawStep),
    /// The averaging should end, and why.
    End(String),
}

/// The running mean of the compass's true heading (rad) over the readings
/// since the start, and what the filter holds of it.
#[derive(Clone, Debug)]
pub(super) struct CompassMean {
    /// The body's tilt (rotation without yaw) the readings are levelled
    /// with: the start's, from gravity.
    tilt: UnitQuaternion<f64>,
    declination_rad: f64,
    /// Headings are kept relative to the start's circular mean (wrap-safe
    /// while they scatter by less than half a turn).
    reference_rad: f64,
    /// Welford's running mean and sum of squared deviations, relative to
    /// the reference.
    n: u32,
    mean_rad: f64,
    m2_rad2: f64,
    /// Readings refused as outliers, in all and in a row.
    pub outliers: u32,
    outlier_run: u32,
    /// Readings waiting to settle: (autopilot time (s), heading (rad)).
    pending: VecDeque<(f64, f64)>,
    /// The mean the filter's yaw holds, its noise variance `s²/N` and `N`.
    held_mean_rad: f64,
    held_var_rad2: f64,
    held_n: u32,
    /// The start's mean and its noise variance.
    pub start_yaw_rad: f64,
    pub start_var_rad2: f64,
    /// The sum of the shifts the filter has taken (rad), and how many.
    pub shifted_rad: f64,
    pub steps: u32,
}

fn wrap(a: f64) -> f64 {
    a.sin().atan2(a.cos())
}

impl CompassMean {
    /// The mean of the readings a start takes its yaw from, or `None` with
    /// fewer than [`MIN_START_READINGS`] that give a heading. Every one
    /// counts, about their circular mean (the oldest may predate the still
    /// window: its error shows in the scatter, and so in the sigma).
    pub(super) fn start<'a>(
        readings_B: impl IntoIterator<Item = &'a Vector3<f64>>,
        tilt: &UnitQuaternion<f64>,
        declination_rad: f64,
    ) -> Option<Self> {
        let headings: Vec<f64> = readings_B
            .into_iter()
            .filter_map(|m| magnetic::heading_rad(tilt, m, declination_rad))
            .collect();
        if headings.len() < MIN_START_READINGS {
            return None;
        }
        let (s, c) = headings.iter().fold((0.0, 0.0), |(s, c), h| (s + h.sin(), c + h.cos()));
        let reference_rad = s.atan2(c);
        if !reference_rad.is_finite() {
            return None;
        }
        let mut mean = Self {
            tilt: *tilt,
            declination_rad,
            reference_rad,
            n: 0,
            mean_rad: 0.0,
            m2_rad2: 0.0,
            outliers: 0,
            outlier_run: 0,
            pending: VecDeque::with_capacity(MAX_PENDING),
            held_mean_rad: 0.0,
            held_var_rad2: 0.0,
            held_n: 0,
            start_yaw_rad: 0.0,
            start_var_rad2: 0.0,
            shifted_rad: 0.0,
            steps: 0,
        };
        for h in headings {
            mean.welford(wrap(h - reference_rad));
        }
        mean.held_mean_rad = mean.mean_rad;
        mean.held_var_rad2 = mean.noise_var_rad2();
        mean.held_n = mean.n;
        mean.start_yaw_rad = mean.yaw_rad();
        mean.start_var_rad2 = mean.held_var_rad2;
        Some(mean)
    }

    /// The mean true heading (rad, wrapped to ±π).
    pub(super) fn yaw_rad(&self) -> f64 {
        wrap(self.reference_rad + self.mean_rad)
    }

    /// The mean's noise variance `s²/N` (rad²), `s²` the readings' sample
    /// variance.
    pub(super) fn noise_var_rad2(&self) -> f64 {
        if self.n < 2 {
            return f64::INFINITY;
        }
        self.m2_rad2 / f64::from(self.n - 1) / f64::from(self.n)
    }

    /// Readings averaged, and those the filter's yaw holds.
    pub(super) fn readings(&self) -> (u32, u32) {
        (self.n, self.held_n)
    }

    /// The noise variance of the mean the filter's yaw holds (rad²).
    pub(super) fn held_noise_var_rad2(&self) -> f64 {
        self.held_var_rad2
    }

    /// One reading's scatter, one sigma (rad).
    pub(super) fn reading_sigma_rad(&self) -> f64 {
        (self.noise_var_rad2() * f64::from(self.n)).sqrt()
    }

    fn welford(&mut self, x: f64) {
        self.n += 1;
        let dev = x - self.mean_rad;
        self.mean_rad += dev / f64::from(self.n);
        self.m2_rad2 += dev * (x - self.mean_rad);
    }

    /// A settled heading into the mean; the reason to end on a run of
    /// outliers.
    fn add(&mut self, heading_rad: f64) -> Option<String> {
        let x = wrap(heading_rad - self.reference_rad);
        let gate = (OUTLIER_SIGMAS * self.reading_sigma_rad()).max(OUTLIER_FLOOR_RAD);
        let dev = x - self.mean_rad;
        // NaN is an outlier too.
        if dev.abs() > gate || dev.is_nan() {
            self.outliers += 1;
            self.outlier_run += 1;
            return (self.outlier_run >= OUTLIER_RUN_END).then(|| {
                format!(
                    "{OUTLIER_RUN_END} readings in a row {:.1}° or more from the mean: the compass disagrees with \
                     its start (moved while starting, or a changed field)",
                    gate.to_degrees()
                )
            });
        }
        self.outlier_run = 0;
        self.welford(x);
        None
    }

    /// A magnetometer reading (body frame) that came at `t_s` (autopilot
    /// time); the vehicle has stood still and disarmed up to now (the
    /// caller ends the averaging otherwise). Readings [`SETTLE_S`] old
    /// enter the mean; a step is due every [`READINGS_PER_STEP`] of them,
    /// when the mean's noise variance has dropped (a scatter that grew is
    /// not taken back).
    pub(super) fn push(&mut self, t_s: f64, mag_B: &Vector3<f64>) -> Pushed {
        if let Some(h) = magnetic::heading_rad(&self.tilt, mag_B, self.declination_rad) {
            if self.pending.len() == MAX_PENDING {
                self.pending.pop_front();
            }
            self.pending.push_back((t_s, h));
        }
        while let Some(&(t, h)) = self.pending.front() {
            // A reading from the future (a clock that jumped back) waits
            // no longer than one that settled.
            if t_s - t < SETTLE_S && t <= t_s {
                break;
            }
            self.pending.pop_front();
            if self.n >= MAX_READINGS {
                continue;
            }
            if let Some(why) = self.add(h) {
                return Pushed::End(why);
            }
        }
        if self.n < self.held_n + READINGS_PER_STEP {
            return Pushed::Nothing;
        }
        let drop_rad2 = self.held_var_rad2 - self.noise_var_rad2();
        if drop_rad2 > 1e-9 * self.held_var_rad2 {
            Pushed::Step(YawStep {
                shift_rad: self.mean_rad - self.held_mean_rad,
                drop_rad2,
            })
        } else {
            Pushed::Nothing
        }
    }

    /// The filter took `step`: it now holds the current mean.
    pub(super) fn held(&mut self, step: YawStep) {
        self.held_mean_rad = self.mean_rad;
        self.held_var_rad2 = self.noise_var_rad2();
        self.held_n = self.n;
        self.shifted_rad += step.shift_rad;
        self.steps += 1;
    }
}

/// The vehicle's stillness since the compass start, by the filter's
/// attitude: the start's roll, pitch and yaw, the yaw moved on by each
/// step the filter took.
#[derive(Clone, Copy, Debug)]
pub(super) struct StillSinceStart {
    roll0_rad: f64,
    pitch0_rad: f64,
    yaw0_rad: f64,
}

impl StillSinceStart {
    pub(super) fn new(q_W_B: &UnitQuaternion<f64>) -> Self {
        let (roll0_rad, pitch0_rad, yaw0_rad) = q_W_B.euler_angles();
        Self {
            roll0_rad,
            pitch0_rad,
            yaw0_rad,
        }
    }

    /// Why the vehicle is not as it stood at the start, if it is not.
    pub(super) fn moved(&self, q_W_B: &UnitQuaternion<f64>) -> Option<&'static str> {
        let (r, p, y) = q_W_B.euler_angles();
        let beyond = |d: f64, limit: f64| wrap(d).abs() > limit || d.is_nan();
        if beyond(r - self.roll0_rad, MAX_TILT_RAD) || beyond(p - self.pitch0_rad, MAX_TILT_RAD) {
            Some("the vehicle tilted")
        } else if beyond(y - self.yaw0_rad, MAX_TURN_RAD) {
            Some("the vehicle turned")
        } else {
            None
        }
    }

    /// The filter's yaw moved by `d_rad` in a conditioning.
    pub(super) fn yaw_moved_by(&mut self, d_rad: f64) {
        self.yaw0_rad += d_rad;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// A level body's field at true heading `yaw` (rad) with no declination.
    fn field(yaw: f64) -> Vector3<f64> {
        // m_L = (cos(−ψ), sin(−ψ), down): ψ = −atan2(m_y, m_x).
        Vector3::new((-yaw).cos(), (-yaw).sin(), 0.9)
    }

    /// Pushes `fields` at 10 Hz from `t0`, then 2 s more of nothing new;
    /// takes every step.
    fn feed(c: &mut CompassMean, t0: f64, fields: &[Vector3<f64>]) -> (f64, f64, u32, Option<String>) {
        let (mut shift, mut drop, mut steps) = (0.0, 0.0, 0);
        for (k, f) in fields.iter().enumerate() {
            let t = t0 + k as f64 / 10.0;
            match c.push(t, f) {
                Pushed::Step(s) => {
                    shift += s.shift_rad;
                    drop += s.drop_rad2;
                    steps += 1;
                    c.held(s);
                }
                Pushed::End(why) => return (shift, drop, steps, Some(why)),
                Pushed::Nothing => {}
            }
        }
        (shift, drop, steps, None)
    }

    /// The steps telescope: their shifts add up to the final mean less the
    /// start's, their drops to the start's noise variance less the final
    /// one's, and the mean is the plain mean of every settled heading,
    /// across ±π.
    #[test]
    fn steps_add_up_to_the_mean_of_all_readings() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let noise = Normal::new(0.0, 3f64.to_radians()).unwrap();
        let truth = std::f64::consts::PI - 0.01;
        let headings: Vec<f64> = (0..170).map(|_| truth + noise.sample(&mut rng)).collect();
        let fields: Vec<_> = headings.iter().map(|h| field(*h)).collect();
        let level = UnitQuaternion::identity();
        let mut c = CompassMean::start(&fields[..10], &level, 0.0).unwrap();
        let (start_yaw, start_var) = (c.yaw_rad(), c.noise_var_rad2());
        let (shift, drop, steps, end) = feed(&mut c, 0.0, &fields[10..]);
        assert_eq!(end, None);
        assert!(steps >= 10, "{steps} steps");
        // The last 1.5 s (15 readings) have not settled.
        let (n, held) = c.readings();
        assert!((154..=155).contains(&n), "{n} averaged");
        assert_eq!(held, 150);
        let mean_settled = truth + headings[..n as usize].iter().map(|h| wrap(h - truth)).sum::<f64>() / f64::from(n);
        assert!(
            wrap(c.yaw_rad() - mean_settled).abs() < 1e-9,
            "mean {} vs {}",
            c.yaw_rad(),
            mean_settled
        );
        assert!(wrap(start_yaw + shift - c.held_mean_rad - c.reference_rad).abs() < 1e-9);
        assert!((c.shifted_rad - shift).abs() < 1e-15);
        // The drops never exceed what the start held.
        assert!(drop > 0.0 && drop < start_var, "drop {drop} of {start_var}");
        assert!((start_var - drop - c.held_var_rad2).abs() < 1e-15);
        let s = c.reading_sigma_rad().to_degrees();
        assert!((2.4..3.6).contains(&s), "scatter {s}°");
    }

    /// The mean's error shrinks as 1/√N: over many draws the error of the
    /// start's mean (10 readings) and of the final one (150 held) against
    /// their own variances give a NEES near 1 each, the final one's RMS
    /// about √15 times smaller.
    #[test]
    fn the_mean_and_its_variance_agree_over_many_draws() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let noise = Normal::new(0.0, 3f64.to_radians()).unwrap();
        let level = UnitQuaternion::identity();
        let (mut nees0, mut nees1, mut e0, mut e1) = (0.0, 0.0, 0.0, 0.0);
        let trials = 400;
        for _ in 0..trials {
            let fields: Vec<_> = (0..165).map(|_| field(0.3 + noise.sample(&mut rng))).collect();
            let mut c = CompassMean::start(&fields[..10], &level, 0.0).unwrap();
            let err0 = c.yaw_rad() - 0.3;
            nees0 += err0 * err0 / c.noise_var_rad2();
            e0 += err0 * err0;
            feed(&mut c, 0.0, &fields[10..]);
            let err1 = wrap(c.reference_rad + c.held_mean_rad - 0.3);
            nees1 += err1 * err1 / c.held_var_rad2;
            e1 += err1 * err1;
        }
        let (nees0, nees1) = (nees0 / trials as f64, nees1 / trials as f64);
        // 10 readings: the sample variance's own scatter lifts the NEES a
        // little (a Student t with 9 degrees of freedom: 9/7).
        assert!((0.8..1.6).contains(&nees0), "NEES of the start's mean {nees0}");
        assert!((0.8..1.25).contains(&nees1), "NEES of the final mean {nees1}");
        let ratio = (e0 / e1).sqrt();
        assert!((3.2..4.6).contains(&ratio), "RMS ratio {ratio}");
    }

    /// A start whose oldest readings are far off (taken while the vehicle
    /// still moved) is their circular mean, honest about its scatter, not
    /// hostage to them: later readings at the true heading are averaged
    /// and move it there.
    #[test]
    fn a_bad_first_reading_does_not_hold_the_start() {
        let level = UnitQuaternion::identity();
        let h = 0.4;
        let mut start: Vec<_> = vec![field(h + 0.6), field(h + 0.6)];
        start.extend((0..8).map(|k| field(h + 0.002 * f64::from(k % 3))));
        let mut c = CompassMean::start(&start, &level, 0.0).unwrap();
        // The start: off by the two (0.12 rad), and says so (s²/N).
        assert!((c.yaw_rad() - h).abs() < 0.13);
        assert!(c.noise_var_rad2().sqrt() > 0.05, "σ {}", c.noise_var_rad2().sqrt());
        let later: Vec<_> = (0..200).map(|k| field(h + 0.002 * f64::from(k % 3))).collect();
        let (_, _, steps, end) = feed(&mut c, 0.0, &later);
        assert_eq!(end, None);
        assert!(steps >= 5);
        assert_eq!(c.outliers, 0);
        let held = wrap(c.reference_rad + c.held_mean_rad);
        assert!((held - h).abs() < 0.015, "held {held} vs {h}");
    }

    /// Readings far off the mean are counted, not averaged; ten in a row
    /// end the averaging with a reason; a start with fewer than five
    /// readings gives no mean, nor does a vertical field.
    #[test]
    fn outliers_and_too_few_readings() {
        let level = UnitQuaternion::identity();
        let fields: Vec<_> = (0..10).map(|k| field(0.01 * f64::from(k % 2))).collect();
        let mut c = CompassMean::start(&fields, &level, 0.0).unwrap();
        let before = c.yaw_rad();
        let off: Vec<_> = (0..40).map(|_| field(2.0)).collect();
        let (_, _, steps, end) = feed(&mut c, 0.0, &off);
        assert_eq!(steps, 0);
        assert_eq!(c.outliers, 10);
        assert!(end.is_some_and(|w| w.contains("disagrees")));
        assert_eq!(c.yaw_rad(), before);
        assert!(CompassMean::start(&fields[..4], &level, 0.0).is_none());
        let vertical = [Vector3::new(0.0, 0.0, 1.0); 6];
        assert!(CompassMean::start(&vertical, &level, 0.0).is_none());
        let nan = [Vector3::new(f64::NAN, 0.0, 1.0); 6];
        assert!(CompassMean::start(&nan, &level, 0.0).is_none());
    }

    /// A compass stuck at one value has no scatter: no noise to average
    /// away, so no step, and nothing non-finite; past 300 readings nothing
    /// more is averaged.
    #[test]
    fn a_stuck_compass_takes_no_step_and_the_count_is_bounded() {
        let level = UnitQuaternion::identity();
        let same = vec![field(0.2); 400];
        let mut c = CompassMean::start(&same[..10], &level, 0.0).unwrap();
        assert_eq!(c.noise_var_rad2(), 0.0);
        let (_, _, steps, end) = feed(&mut c, 0.0, &same[10..]);
        assert_eq!((steps, end), (0, None));
        assert_eq!(c.readings().0, MAX_READINGS);
        assert!(c.pending.len() <= MAX_PENDING);
    }

    /// Readings of the last 1.5 s wait: when the autopilot says it armed
    /// (up to a second late, its motors spinning) or the vehicle turned,
    /// the caller ends the averaging and they never enter the mean.
    #[test]
    fn the_last_readings_wait_to_settle() {
        let level = UnitQuaternion::identity();
        let h = -0.3;
        let mut readings: Vec<_> = (0..40).map(|k| field(h + 0.001 * f64::from(k % 2))).collect();
        let mut c = CompassMean::start(&readings[..10], &level, 0.0).unwrap();
        // 30 more at h, then 10 at h + 4° (the motors' field, a turn).
        readings.extend((0..10).map(|_| field(h + 0.07)));
        feed(&mut c, 0.0, &readings[10..]);
        let (n, _) = c.readings();
        assert!(n <= 10 + 30, "{n} averaged: a reading of the last 1.5 s entered");
        assert!((c.yaw_rad() - h).abs() < 0.002, "mean {} vs {h}", c.yaw_rad());
        assert!(c.pending.len() >= 14);
    }

    /// The stillness check: a tilt past 1° or a turn past 2° is seen, the
    /// yaw's own conditioning is not a turn.
    #[test]
    fn tilts_and_turns_are_seen() {
        let q = UnitQuaternion::from_euler_angles(0.02, -0.01, 1.0);
        let mut s = StillSinceStart::new(&q);
        assert_eq!(s.moved(&q), None);
        assert_eq!(
            s.moved(&UnitQuaternion::from_euler_angles(0.02, 0.01, 1.0)),
            Some("the vehicle tilted")
        );
        let turned = UnitQuaternion::from_euler_angles(0.02, -0.01, 1.04);
        assert_eq!(s.moved(&turned), Some("the vehicle turned"));
        s.yaw_moved_by(0.04);
        assert_eq!(s.moved(&turned), None);
    }
}
