//! The compass heading averaged while the vehicle stands before take-off
//! (estimator README §7, eq. H1). Why this exists: the filter starts from
//! the mean heading of the last second's magnetometer readings, and some
//! magnetometers scatter by degrees a reading (PX4's SIH by 3.2°: a 1°
//! error in that mean, 0.3 m across a 10 m box). Every reading that comes
//! while the vehicle stands disarmed averages that noise down; the
//! compass's bias (hard iron, the declination model) does not average, so
//! the yaw's sigma keeps it. This keeps the running mean and says when the
//! filter's yaw should be conditioned on a better one.

use cmsckf_models::magnetic;
use nalgebra::{UnitQuaternion, Vector3};

/// The filter's yaw is conditioned once this many more readings have come
/// (10 Hz: once a second).
const READINGS_PER_STEP: u32 = 10;

/// A reading whose heading is this far from the mean (rad) is not the
/// compass's noise (a disturbance, a vehicle carried round): not averaged.
const OUTLIER_RAD: f64 = 0.5;

/// The vehicle has turned since the start by more than this (rad) of its
/// gyro-propagated yaw: the readings are of another heading, and the
/// averaging stops.
pub(super) const MAX_TURN_RAD: f64 = 0.035;

/// One conditioning of the filter's yaw (eq. H1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct YawStep {
    /// The better mean less the one the filter holds (rad).
    pub shift_rad: f64,
    /// The drop of the mean's noise variance (rad²).
    pub drop_rad2: f64,
}

/// The running mean of the compass's true heading (rad) over the readings
/// since the start, and what the filter holds of it.
#[derive(Clone, Debug)]
pub(super) struct CompassMean {
    /// The body's tilt (rotation without yaw) the readings are levelled
    /// with: the start's, from gravity.
    tilt: UnitQuaternion<f64>,
    declination_rad: f64,
    /// Headings are kept relative to the first (wrap-safe while they
    /// scatter by less than half a turn).
    reference_rad: f64,
    /// Welford's running mean and sum of squared deviations, relative to
    /// the reference.
    n: u32,
    mean_rad: f64,
    m2_rad2: f64,
    /// Readings refused as outliers.
    pub outliers: u32,
    /// The mean the filter's yaw holds, its noise variance `s²/N` and `N`.
    held_mean_rad: f64,
    held_var_rad2: f64,
    held_n: u32,
    /// The sum of the shifts the filter has taken (rad).
    pub shifted_rad: f64,
}

impl CompassMean {
    /// The mean of the readings a start takes its yaw from, or `None` with
    /// fewer than two that give a heading (their noise unknown).
    pub(super) fn start<'a>(
        readings_B: impl IntoIterator<Item = &'a Vector3<f64>>,
        tilt: &UnitQuaternion<f64>,
        declination_rad: f64,
    ) -> Option<Self> {
        let mut mean: Option<Self> = None;
        for m in readings_B {
            let Some(h) = magnetic::heading_rad(tilt, m, declination_rad) else {
                continue;
            };
            match mean.as_mut() {
                Some(c) => {
                    c.add(h);
                }
                None => {
                    mean = Some(Self {
                        tilt: *tilt,
                        declination_rad,
                        reference_rad: h,
                        n: 1,
                        mean_rad: 0.0,
                        m2_rad2: 0.0,
                        outliers: 0,
                        held_mean_rad: 0.0,
                        held_var_rad2: 0.0,
                        held_n: 1,
                        shifted_rad: 0.0,
                    })
                }
            }
        }
        let mut c = mean.filter(|c| c.n >= 2)?;
        c.held_mean_rad = c.mean_rad;
        c.held_var_rad2 = c.noise_var_rad2();
        c.held_n = c.n;
        Some(c)
    }

    /// The mean true heading (rad, wrapped to ±π).
    pub(super) fn yaw_rad(&self) -> f64 {
        let y = self.reference_rad + self.mean_rad;
        y.sin().atan2(y.cos())
    }

    /// The mean's noise variance `s²/N` (rad²), `s²` the readings' sample
    /// variance.
    pub(super) fn noise_var_rad2(&self) -> f64 {
        if self.n < 2 {
            return f64::INFINITY;
        }
        self.m2_rad2 / f64::from(self.n - 1) / f64::from(self.n)
    }

    /// Readings averaged.
    pub(super) fn readings(&self) -> u32 {
        self.n
    }

    /// One reading's scatter, one sigma (rad).
    pub(super) fn reading_sigma_rad(&self) -> f64 {
        (self.noise_var_rad2() * f64::from(self.n)).sqrt()
    }

    /// Adds a heading (rad); `false` for an outlier.
    fn add(&mut self, heading_rad: f64) -> bool {
        let d = heading_rad - self.reference_rad;
        let x = d.sin().atan2(d.cos());
        let dev = x - self.mean_rad;
        if self.n >= 2 && dev.abs() > OUTLIER_RAD {
            self.outliers += 1;
            return false;
        }
        self.n += 1;
        self.mean_rad += dev / f64::from(self.n);
        self.m2_rad2 += dev * (x - self.mean_rad);
        true
    }

    /// Adds a magnetometer reading (body frame); the step to condition the
    /// filter's yaw with when one is due (every [`READINGS_PER_STEP`]
    /// readings, and only when the mean's noise variance has dropped: a
    /// scatter that grew is not taken back). Call [`Self::held`] once the
    /// filter has taken it.
    pub(super) fn push(&mut self, mag_B: &Vector3<f64>) -> Option<YawStep> {
        let h = magnetic::heading_rad(&self.tilt, mag_B, self.declination_rad)?;
        if !self.add(h) || self.n < self.held_n + READINGS_PER_STEP {
            return None;
        }
        let var = self.noise_var_rad2();
        let drop_rad2 = self.held_var_rad2 - var;
        (drop_rad2 > 0.0).then_some(YawStep {
            shift_rad: self.mean_rad - self.held_mean_rad,
            drop_rad2,
        })
    }

    /// The filter took `step`: it now holds the current mean.
    pub(super) fn held(&mut self, step: YawStep) {
        self.held_mean_rad = self.mean_rad;
        self.held_var_rad2 = self.noise_var_rad2();
        self.held_n = self.n;
        self.shifted_rad += step.shift_rad;
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

    /// The steps telescope: their shifts add up to the final mean less the
    /// start's, their drops to the start's noise variance less the final
    /// one's (a scatter that does not change), and the mean is the plain
    /// mean of every heading, across ±π.
    #[test]
    fn steps_add_up_to_the_mean_of_all_readings() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let noise = Normal::new(0.0, 3f64.to_radians()).unwrap();
        let truth = std::f64::consts::PI - 0.01;
        let headings: Vec<f64> = (0..150).map(|_| truth + noise.sample(&mut rng)).collect();
        let fields: Vec<_> = headings.iter().map(|h| field(*h)).collect();
        let level = UnitQuaternion::identity();
        let mut c = CompassMean::start(&fields[..10], &level, 0.0).unwrap();
        let (start_yaw, start_var) = (c.yaw_rad(), c.noise_var_rad2());
        let (mut shift, mut drop, mut steps) = (0.0, 0.0, 0);
        for f in &fields[10..] {
            if let Some(s) = c.push(f) {
                shift += s.shift_rad;
                drop += s.drop_rad2;
                steps += 1;
                c.held(s);
            }
        }
        assert!(steps >= 5, "{steps} steps");
        let wrap = |a: f64| a.sin().atan2(a.cos());
        let mean_all = truth + headings.iter().map(|h| wrap(h - truth)).sum::<f64>() / 150.0;
        assert!(
            wrap(c.yaw_rad() - mean_all).abs() < 1e-9,
            "mean {} vs {}",
            c.yaw_rad(),
            mean_all
        );
        assert!(wrap(start_yaw + shift - c.yaw_rad()).abs() < 1e-9);
        assert!((c.shifted_rad - shift).abs() < 1e-15);
        // The drops never exceed what the start held.
        assert!(drop > 0.0 && drop < start_var, "drop {drop} of {start_var}");
        assert!((start_var - drop - c.held_var_rad2).abs() < 1e-15);
        // The scatter is the readings' own: 3° within the sample's error.
        let s = c.reading_sigma_rad().to_degrees();
        assert!((2.4..3.6).contains(&s), "scatter {s}°");
        assert_eq!(c.readings(), 150);
    }

    /// The mean's error shrinks as 1/√N: over many draws the error of the
    /// start's mean (10 readings) and of the final one (150) against their
    /// own variances give a NEES near 1 each, the final one's RMS about
    /// √15 times smaller.
    #[test]
    fn the_mean_and_its_variance_agree_over_many_draws() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let noise = Normal::new(0.0, 3f64.to_radians()).unwrap();
        let level = UnitQuaternion::identity();
        let (mut nees0, mut nees1, mut e0, mut e1) = (0.0, 0.0, 0.0, 0.0);
        let trials = 400;
        for _ in 0..trials {
            let fields: Vec<_> = (0..150).map(|_| field(0.3 + noise.sample(&mut rng))).collect();
            let mut c = CompassMean::start(&fields[..10], &level, 0.0).unwrap();
            let err0 = c.yaw_rad() - 0.3;
            nees0 += err0 * err0 / c.noise_var_rad2();
            e0 += err0 * err0;
            for f in &fields[10..] {
                if let Some(s) = c.push(f) {
                    c.held(s);
                }
            }
            let err1 = c.yaw_rad() - 0.3;
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

    /// A reading far off the mean is counted, not averaged; a start with
    /// one reading gives no mean (its noise unknown); a vertical field
    /// gives no heading.
    #[test]
    fn outliers_and_too_few_readings() {
        let level = UnitQuaternion::identity();
        let fields: Vec<_> = (0..10).map(|k| field(0.01 * f64::from(k))).collect();
        let mut c = CompassMean::start(&fields, &level, 0.0).unwrap();
        let before = c.yaw_rad();
        assert_eq!(c.push(&field(2.0)), None);
        assert_eq!(c.outliers, 1);
        assert_eq!(c.yaw_rad(), before);
        assert!(CompassMean::start(&fields[..1], &level, 0.0).is_none());
        let vertical = [Vector3::new(0.0, 0.0, 1.0), Vector3::new(0.0, 0.0, 1.0)];
        assert!(CompassMean::start(&vertical, &level, 0.0).is_none());
    }
}
