//! A compass yaw that gets better after the start (README.md §7, eq. H1).
//! Why this exists: the filter's first yaw is the mean of the last second's
//! compass readings, whose noise (several degrees a reading on some
//! magnetometers beside motors) is in it. While the vehicle stands before
//! take-off more readings come; their mean's noise shrinks, its bias does
//! not. The daemon keeps that mean (`daemon/compass.rs`) and conditions the
//! filter's yaw on each improvement, exactly, so the yaw gets the better
//! mean and its sigma loses the noise's share and nothing more.

use nalgebra::{DMatrix, DVector};

use super::propagate::TH;
use super::{Estimator, Mode};

/// Why the yaw was not conditioned.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum YawConditionError {
    #[error("the yaw's shift {shift_rad} rad or its variance drop {drop_rad2} rad² is not finite and positive")]
    NotFinite { shift_rad: f64, drop_rad2: f64 },
    #[error("the variance drop {drop_rad2} rad² is not below the yaw's variance {var_rad2} rad²")]
    DropTooLarge { drop_rad2: f64, var_rad2: f64 },
    #[error("Schmidt mode's keyframes take no corrections: the map would keep the old yaw")]
    Schmidt,
}

impl Estimator {
    /// Conditions the world yaw on a better compass mean (§7, eq. H1).
    ///
    /// The start's yaw error is `e = b + ē_prev`: the compass's bias and the
    /// noise of the mean it was taken from (`N_prev` readings). A mean over
    /// `N > N_prev` readings (the first `N_prev` among them) moves by
    /// `shift_rad = ē_N − ē_prev`, a known number, uncorrelated with the new
    /// error `b + ē_N` and of variance `drop_rad2 = σ_n² (1/N_prev − 1/N)`.
    /// Conditioning on it moves the yaw by the whole shift and lowers its
    /// variance by exactly the drop. Every other state moves by its
    /// regression on the reference yaw: the oldest local keyframe's (a
    /// pose frozen at the start, whose yaw error is exactly `e` while the
    /// vehicle stands), else the body's (whose error also holds the gyro's
    /// drift since the start). As one EKF row `H = e_ψᵀ` on that yaw:
    /// `r = shift P_ψψ / drop` and `R = P_ψψ (P_ψψ − drop) / drop` give the
    /// gain `P e_ψ / P_ψψ · drop / P_ψψ` times `r`, i.e. `δx = P e_ψ shift /
    /// P_ψψ`, and `P ← P − P e_ψ e_ψᵀ P drop / P_ψψ²`.
    pub fn condition_yaw_on_compass(&mut self, shift_rad: f64, drop_rad2: f64) -> Result<(), YawConditionError> {
        if !(shift_rad.is_finite() && drop_rad2.is_finite() && drop_rad2 > 0.0) {
            return Err(YawConditionError::NotFinite { shift_rad, drop_rad2 });
        }
        if self.s.mode == Mode::Schmidt {
            return Err(YawConditionError::Schmidt);
        }
        self.sync();
        // The attitude error δθ is in the world frame (§1): its z is the yaw.
        let col = self
            .local_kfs
            .iter()
            .enumerate()
            .min_by_key(|(_, id)| **id)
            .map_or(TH + 2, |(j, _)| self.kf_offset(j) + 2);
        let var = self.P[(col, col)];
        if !var.is_finite() || drop_rad2 >= var {
            return Err(YawConditionError::DropTooLarge {
                drop_rad2,
                var_rad2: var,
            });
        }
        // Whitened: H = 1/√R, r = (shift P_ψψ / drop)/√R.
        let noise = var * (var - drop_rad2) / drop_rad2;
        let sqrt_r = noise.sqrt();
        let h = DMatrix::from_element(1, 1, 1.0 / sqrt_r);
        let r = DVector::from_element(1, shift_rad * var / drop_rad2 / sqrt_r);
        self.ekf_update(&h, &[col], &r, false);
        Ok(())
    }
}

#[cfg(all(test, feature = "sim"))]
mod tests {
    use super::*;
    use crate::config::Config;
    use crate::eval::{sim_config_for, Runner};
    use cmsckf_sitl::dataset::Dataset;

    /// A filter that has stood 4 s on the ground (the racetrack's standstill,
    /// its frames zero-velocity updates).
    fn standing(mode: Mode) -> Estimator {
        let cfg = Config::default();
        let mut sim = sim_config_for(&cfg);
        sim.standstill_s = 5.0;
        let ds = Dataset::generate("racetrack", 3, Some(4.0), &sim).unwrap();
        let mut run = Runner::new(&ds, &cfg, mode, 3);
        for k in 0..ds.frames.len() {
            run.step_frame(k);
        }
        run.est
    }

    /// Eq. H1 against its definition: conditioning on a known shift of the
    /// compass mean moves the reference yaw (the oldest keyframe's) by the
    /// whole shift and every state by its regression on that yaw, and takes
    /// exactly `drop` off that yaw's variance: `P − P e eᵀ P drop / P_ψψ²`.
    #[test]
    fn conditioning_moves_the_yaw_by_the_shift_and_its_variance_by_the_drop() {
        let mut est = standing(Mode::Compressed);
        assert!(
            !est.local_kfs.is_empty(),
            "a standing filter with a camera has its first keyframe"
        );
        est.sync();
        let col = est.kf_offset(0) + 2;
        let p0 = est.P.clone();
        let kf_id = est.local_kfs[0];
        let kf_yaw0 = est.keyframes[&kf_id].q_W_B().euler_angles().2;
        let imu_yaw0 = est.imu.q_W_B.euler_angles().2;
        let bg0 = est.imu.b_g;
        let (shift, drop) = (0.8_f64.to_radians(), 0.8 * p0[(col, col)]);
        est.condition_yaw_on_compass(shift, drop).unwrap();
        let kf_yaw1 = est.keyframes[&kf_id].q_W_B().euler_angles().2;
        let imu_yaw1 = est.imu.q_W_B.euler_angles().2;
        // The keyframe's pose holds the start's yaw: it moves by the shift.
        assert!(
            ((kf_yaw1 - kf_yaw0) - shift).abs() < 1e-3 * shift,
            "{} vs {shift}",
            kf_yaw1 - kf_yaw0
        );
        // The body's by its regression on it (its drift since is its own).
        let beta = p0[(2, col)] / p0[(col, col)];
        assert!(beta > 0.5 && beta < 1.01, "regression {beta}");
        assert!(((imu_yaw1 - imu_yaw0) - beta * shift).abs() < 1e-3 * shift);
        let dbg = (est.imu.b_g - bg0).z;
        let beta_bg = p0[(11, col)] / p0[(col, col)];
        assert!((dbg - beta_bg * shift).abs() < 1e-9 + 1e-6 * (beta_bg * shift).abs());
        // The covariance: a rank-one downdate along P e.
        let pe = p0.column(col).into_owned();
        let expected = &p0 - &pe * pe.transpose() * (drop / (p0[(col, col)] * p0[(col, col)]));
        let err = (&est.P - &expected).abs().max();
        assert!(err < 1e-12, "P differs from H1 by {err}");
        assert!((p0[(col, col)] - est.P[(col, col)] - drop).abs() < 1e-12);
    }

    /// Bad arguments leave the filter as it was; Schmidt mode refuses.
    #[test]
    fn conditioning_refuses_what_it_cannot_do() {
        let mut est = standing(Mode::Compressed);
        est.sync();
        let before = est.P.clone();
        let var = est.P[(est.kf_offset(0) + 2, est.kf_offset(0) + 2)];
        assert!(matches!(
            est.condition_yaw_on_compass(f64::NAN, 1e-6),
            Err(YawConditionError::NotFinite { .. })
        ));
        assert!(matches!(
            est.condition_yaw_on_compass(0.01, 0.0),
            Err(YawConditionError::NotFinite { .. })
        ));
        assert!(matches!(
            est.condition_yaw_on_compass(0.01, var),
            Err(YawConditionError::DropTooLarge { .. })
        ));
        assert_eq!(est.P, before);
        let mut schmidt = standing(Mode::Schmidt);
        assert_eq!(
            schmidt.condition_yaw_on_compass(0.01, 1e-6),
            Err(YawConditionError::Schmidt)
        );
    }
}
