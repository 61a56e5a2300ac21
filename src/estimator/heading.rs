//! A compass yaw that gets better after the start (README.md §7, eq. H1).
//! Why this exists: the filter's first yaw is the mean of the last second's
//! compass readings, whose noise (several degrees a reading on some
//! magnetometers beside motors) is in it. While the vehicle stands before
//! take-off more readings come; their mean's noise shrinks, its bias does
//! not. The daemon keeps that mean (`daemon/compass.rs`) and conditions the
//! filter's yaw on each improvement, exactly, so the yaw gets the better
//! mean and its sigma loses the noise's share and nothing more. Tested
//! against eq. H1 on a standing flight in `tests/compass_yaw.rs` (the
//! simulator is the tests', never the estimator's).

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
