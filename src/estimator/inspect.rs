//! The filter's insides, opened for verification from outside: why it
//! exists is that the exactness and consistency tests (`tests/`) fly the
//! simulator, which the estimator must not depend on, and check what the
//! public face does not show: the local covariance as stored, the global
//! part's keyframes, the GNSS epoch grid, a state knocked off its estimate
//! behind the covariance's back, and the Schmidt update against the formula
//! it replaced. The daemon uses none of it.

use nalgebra::{DMatrix, DMatrixView};

use super::{Estimator, ImuMeas, ImuState};

/// The Schmidt update's downdate: `P += α AᵀA` outside the keyframe block
/// `[k0, k1)²` (`(P, α, Aᵀ, A, k0, k1)`), as
/// [`super::math::add_gram_outside_block`] does it.
pub type SchmidtDowndate = fn(&mut DMatrix<f64>, f64, DMatrixView<'_, f64>, DMatrixView<'_, f64>, usize, usize);

impl Estimator {
    /// The local covariance `P` as stored: `[active | local keyframes |
    /// clones | GNSS clones]`, the active block's cross-covariances waiting
    /// for [`Estimator::sync`] (§2, eq. F4).
    pub fn covariance(&self) -> &DMatrix<f64> {
        &self.P
    }

    /// Replaces `P` as stored (the same layout; states past the GNSS clones
    /// are updated like clones), to check an update on covariances that no
    /// flight gives.
    pub fn set_covariance(&mut self, P: DMatrix<f64>) {
        self.P = P;
    }

    /// The nominal IMU state, to change behind the covariance's back: a
    /// start moved by an ulp, a state knocked off the truth.
    pub fn imu_state_mut(&mut self) -> &mut ImuState {
        &mut self.imu
    }

    /// The last IMU measurement integrated, if any.
    pub fn last_imu(&self) -> Option<ImuMeas> {
        self.last_meas
    }

    /// The keyframes of the global part (compressed mode), in id order.
    pub fn global_keyframe_ids(&self) -> Vec<u64> {
        self.global
            .as_ref()
            .map(|g| g.live.keys().copied().collect())
            .unwrap_or_default()
    }

    /// Where GNSS epochs are expected: `(period_s, last_epoch_s)`, once an
    /// epoch has placed the grid.
    pub fn gnss_epoch_grid(&self) -> Option<(f64, f64)> {
        self.gnss_grid.map(|g| (g.period_s, g.last_epoch_s))
    }

    /// Forgets the GNSS epoch grid: no clone is taken until an epoch places
    /// it again, so the next epoch is fused against the current state.
    pub fn forget_gnss_epoch_grid(&mut self) {
        self.gnss_grid = None;
    }

    /// The downdate the Schmidt update runs ([`SchmidtDowndate`]); tests
    /// give it the former formula to compare single updates and whole
    /// flights.
    pub fn set_schmidt_downdate(&mut self, f: SchmidtDowndate) {
        self.schmidt_downdate = f;
    }
}
