//! Gusts: why this exists is that no multirotor flies the smooth curve it
//! is commanded. Its position controller rejects wind, so the vehicle
//! wanders by decimetres about its path and, since a multirotor tilts to
//! accelerate, its attitude shakes by a few degrees at 0.2–2 Hz. A filter
//! tuned on perfectly smooth flight never sees that motion, and some of what
//! it estimates is observable only through it (the camera–IMU time offset
//! needs changes of angular rate, README §3b).
//!
//! The gust displacement is a sum of sinusoids per axis, drawn from the
//! flight's seed: frequencies log-uniform in `gust_band_hz`, random phases,
//! and amplitudes that give each axis the acceleration RMS `gust_accel_mps2`
//! (the vertical axis half of it, as thrust holds height more stiffly than
//! tilt holds position). It is added to the commanded position, faded in over
//! the first metre of height, so the vehicle is exactly still on the ground.
//! The attitude then follows from the disturbed acceleration (differential
//! flatness), like everything else the truth holds.

use nalgebra::Vector3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use cmsckf_models::check::{Check, FieldError, Validate};

/// The wind's settings (`[wind]` in the simulator's TOML).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct WindConfig {
    /// RMS of the gust acceleration along each horizontal axis (m/s²; the
    /// vertical axis gets half). 0 is calm air: the historical smooth
    /// trajectories exactly.
    pub gust_accel_mps2: f64,
    /// The gusts' frequency band `[low, high]` (Hz).
    pub gust_band_hz: [f64; 2],
}

impl Default for WindConfig {
    /// Light wind: 0.3 m/s² RMS, a tilt of about 2° RMS, at 0.2–2 Hz.
    fn default() -> Self {
        Self {
            gust_accel_mps2: 0.3,
            gust_band_hz: [0.2, 2.0],
        }
    }
}

impl WindConfig {
    /// Calm air: no gusts.
    pub fn calm() -> Self {
        Self {
            gust_accel_mps2: 0.0,
            ..Self::default()
        }
    }
}

impl Validate for WindConfig {
    fn validate(&self, prefix: &str) -> Result<(), FieldError> {
        let c = Check::new(prefix);
        c.range("gust_accel_mps2", self.gust_accel_mps2, 0.0, 5.0)?;
        c.positive("gust_band_hz[0]", self.gust_band_hz[0], 5.0)?;
        // The truth's spline has a knot every 0.1 s: above 2.5 Hz it would
        // smooth the gusts away.
        c.range("gust_band_hz[1]", self.gust_band_hz[1], self.gust_band_hz[0], 2.5)
    }
}

/// Sinusoids per axis.
const TERMS: usize = 8;

/// One flight's gusts: `d(t) = Σ_k A_k sin(2π f_k t + φ_k)` per axis (m).
#[derive(Clone, Debug, Default)]
pub struct GustField {
    /// `(amplitude m, frequency Hz, phase rad)` per axis.
    terms: [Vec<(f64, f64, f64)>; 3],
}

impl GustField {
    /// Draws the gusts from `rng`; calm (`gust_accel_mps2 = 0`) gives none.
    pub fn new(cfg: &WindConfig, rng: &mut ChaCha8Rng) -> Self {
        let mut field = Self::default();
        if cfg.gust_accel_mps2 <= 0.0 {
            return field;
        }
        let [lo, hi] = cfg.gust_band_hz;
        for (axis, terms) in field.terms.iter_mut().enumerate() {
            let rms = if axis == 2 {
                0.5 * cfg.gust_accel_mps2
            } else {
                cfg.gust_accel_mps2
            };
            // Each sinusoid of acceleration amplitude `a` has RMS a/√2, so
            // K of them with `a = rms √(2/K)` give the axis its RMS.
            let accel_amp = rms * (2.0 / TERMS as f64).sqrt();
            for _ in 0..TERMS {
                let f = lo * (hi / lo).powf(rng.random::<f64>());
                let phase = std::f64::consts::TAU * rng.random::<f64>();
                let w = std::f64::consts::TAU * f;
                terms.push((accel_amp / (w * w), f, phase));
            }
        }
        field
    }

    /// Whether there are no gusts.
    pub fn is_calm(&self) -> bool {
        self.terms.iter().all(Vec::is_empty)
    }

    /// The gust displacement at `t_s` (m, NED).
    pub fn displacement(&self, t_s: f64) -> Vector3<f64> {
        let axis = |terms: &[(f64, f64, f64)]| {
            terms
                .iter()
                .map(|(a, f, ph)| a * (std::f64::consts::TAU * f * t_s + ph).sin())
                .sum::<f64>()
        };
        Vector3::new(axis(&self.terms[0]), axis(&self.terms[1]), axis(&self.terms[2]))
    }

    /// The commanded position `p_W` (NED) with the gusts added, faded in
    /// over the first metre of height above the ground (`z = 0`).
    pub fn apply(&self, t_s: f64, p_W: Vector3<f64>) -> Vector3<f64> {
        if self.is_calm() {
            return p_W;
        }
        let fade = super::min_jerk(-p_W.z);
        p_W + self.displacement(t_s) * fade
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_gusts_have_the_configured_acceleration() {
        let cfg = WindConfig::default();
        let g = GustField::new(&cfg, &mut crate::rng::rng_for(3, 10));
        // Acceleration by central differences over 200 s.
        let h = 1e-3;
        let (mut sum, mut n) = (Vector3::zeros(), 0.0);
        let mut t = 0.0;
        while t < 200.0 {
            let a = (g.displacement(t + h) - 2.0 * g.displacement(t) + g.displacement(t - h)) / (h * h);
            sum += a.component_mul(&a);
            n += 1.0;
            t += 0.01;
        }
        let rms = (sum / n).map(f64::sqrt);
        for (axis, want) in [(0, 0.3), (1, 0.3), (2, 0.15)] {
            assert!((rms[axis] - want).abs() < 0.15 * want, "axis {axis}: {rms}");
        }
        // On the ground nothing moves; calm air adds nothing.
        assert_eq!(g.apply(5.0, Vector3::zeros()), Vector3::zeros());
        let calm = GustField::new(&WindConfig::calm(), &mut crate::rng::rng_for(3, 10));
        let p = Vector3::new(1.0, 2.0, -5.0);
        assert_eq!(calm.apply(5.0, p), p);
        assert!(cfg.validate("wind").is_ok());
        let bad = WindConfig {
            gust_band_hz: [0.2, 9.0],
            ..cfg
        };
        assert!(bad
            .validate("wind")
            .unwrap_err()
            .to_string()
            .contains("wind.gust_band_hz[1]"));
    }

    /// The default light wind on the racetrack, against calm air: the
    /// attitude shakes by about 2° RMS and the body rate by about 11°/s RMS
    /// (what a multirotor's attitude loop shows in light wind), while the
    /// position stays within a decimetre of its path.
    #[test]
    fn light_wind_shakes_the_attitude_by_degrees() {
        use crate::trajectory::{racetrack, RacetrackParams};
        let g = GustField::new(&WindConfig::default(), &mut crate::rng::rng_for(1, 10));
        let calm = racetrack(&RacetrackParams::default(), 60.0, 5.0, &GustField::default());
        let windy = racetrack(&RacetrackParams::default(), 60.0, 5.0, &g);
        let (mut dw, mut dth, mut dp, mut n) = (0.0, 0.0, 0.0, 0.0);
        for k in 0..4500 {
            let t = 15.0 + 0.01 * f64::from(k);
            let (a, b) = (windy.sample(t), calm.sample(t));
            dw += (a.w_B - b.w_B).norm_squared();
            dth += a.q_W_B.angle_to(&b.q_W_B).powi(2);
            dp += (a.p_B_in_W - b.p_B_in_W).norm_squared();
            n += 1.0;
        }
        let (rate_dps, tilt_deg, wander_m) = (
            (dw / n).sqrt().to_degrees(),
            (dth / n).sqrt().to_degrees(),
            (dp / n).sqrt(),
        );
        eprintln!("rate {rate_dps:.1} °/s, attitude {tilt_deg:.2}°, position {wander_m:.3} m (RMS)");
        assert!((5.0..20.0).contains(&rate_dps), "{rate_dps}");
        assert!((1.0..4.0).contains(&tilt_deg), "{tilt_deg}");
        assert!(wander_m < 0.15, "{wander_m}");
        // Still on the ground before the take-off.
        assert_eq!(windy.sample(2.0).p_B_in_W, calm.sample(2.0).p_B_in_W);
    }
}
