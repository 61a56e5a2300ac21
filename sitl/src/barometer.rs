//! The simulated barometer: the truth's height through the standard
//! atmosphere, with what a MEMS barometer adds (white noise of 0.1 m a
//! reading, as a CubeOrange's armed on the ground in PX4's sample log, and
//! an offset that wanders as temperature and weather move it: a random
//! walk of 0.01 m/√s, decimetres over minutes). The mock autopilot sends
//! it as `SCALED_PRESSURE`; the evaluation gives [`readings`] to the
//! filter directly. The daemon fuses it with `barometer.fuse` (estimator
//! README §3g) and the review sets our height beside it.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use cmsckf_models::atmosphere::isa_pressure_pa;

/// One reading's noise (m, 1σ).
const NOISE_M: f64 = 0.1;
/// The offset's random walk (m/√s).
const OFFSET_RW_M_PER_SQRT_S: f64 = 0.01;

pub struct Barometer {
    rng: ChaCha8Rng,
    offset_m: f64,
    last_t_s: Option<f64>,
}

impl Barometer {
    pub fn new(rng: ChaCha8Rng) -> Self {
        Self {
            rng,
            offset_m: 0.0,
            last_t_s: None,
        }
    }

    /// The pressure (Pa) it reads at flight time `t_s` at the true height
    /// `alt_msl_m` (m above mean sea level).
    pub fn read_pa(&mut self, t_s: f64, alt_msl_m: f64) -> f64 {
        let dt_s = self.last_t_s.map_or(0.0, |last| (t_s - last).max(0.0));
        self.last_t_s = Some(t_s);
        self.offset_m += OFFSET_RW_M_PER_SQRT_S * dt_s.sqrt() * self.rng.sample::<f64, _>(StandardNormal);
        isa_pressure_pa(alt_msl_m + self.offset_m + NOISE_M * self.rng.sample::<f64, _>(StandardNormal))
    }
}

/// A flight's barometer at `rate_hz` as the standard atmosphere's height
/// above the world origin `(t_s, h_m)`, up (the origin's own height cancels
/// in the filter's offset), from its own random stream.
pub fn readings(ds: &crate::flight::Dataset, rate_hz: f64) -> Vec<(f64, f64)> {
    use cmsckf_models::atmosphere::isa_height_m;
    let mut b = Barometer::new(crate::rng::rng_for(ds.seed, 13));
    let (Some(first), Some(last)) = (ds.truth.first(), ds.truth.last()) else {
        return Vec::new();
    };
    let period_s = 1.0 / rate_hz;
    // Read at a nominal 500 m above sea level, the height taken back off.
    const ALT0_M: f64 = 500.0;
    let mut out = Vec::with_capacity(((last.truth.t_s - first.truth.t_s) * rate_hz) as usize + 1);
    let mut i = 0;
    let mut t_s = first.truth.t_s + period_s;
    while t_s <= last.truth.t_s {
        while i + 1 < ds.truth.len() && ds.truth[i + 1].truth.t_s <= t_s {
            i += 1;
        }
        let h_true_m = -ds.truth[i].truth.p_B_in_W.z;
        out.push((t_s, isa_height_m(b.read_pa(t_s, ALT0_M + h_true_m)) - ALT0_M));
        t_s += period_s;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use cmsckf_models::atmosphere::isa_height_m;

    /// Read at 10 Hz for 10 minutes at a fixed height: each reading within
    /// a few noise σ of the height, the offset wandering by decimetres, not
    /// metres (its σ after 600 s is 0.25 m).
    #[test]
    fn it_reads_the_height_with_noise_and_a_wandering_offset() {
        let mut b = Barometer::new(crate::rng::rng_for(1, 13));
        let (mut worst_m, mut last_m) = (0.0f64, 0.0);
        for k in 0..6000 {
            let h_m = isa_height_m(b.read_pa(k as f64 * 0.1, 500.0)) - 500.0;
            worst_m = worst_m.max(h_m.abs());
            last_m = h_m;
        }
        assert!(worst_m > 0.2 && worst_m < 1.5, "{worst_m}");
        assert!(last_m.abs() < 1.2, "{last_m}");
    }
}
