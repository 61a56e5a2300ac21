//! The whole filter state as one vector and one covariance, in a fixed
//! order, for comparing modes (compressed against full, Schmidt against
//! its former formula) to round-off: why it exists is the claim that
//! compressed mode is exact, which tests can only check on a layout that
//! does not depend on how each mode keeps its keyframes.

use std::collections::BTreeMap;

use nalgebra::{DMatrix, DVector, UnitQuaternion};

use super::{Estimator, ACTIVE_DIM, GNSS_CLONE_DIM};

/// Differences within this many ulps of a nominal value's magnitude are its
/// rounding ([`Snapshot::max_rel_diff`]): a keyframe 200 m from the origin
/// has an ulp of 3e-14 m, and its corrections are summed in another order
/// in compressed mode (G3) than in full mode.
const STATE_ULPS: f64 = 64.0;

/// The full state in a fixed order (IMU, clock, time offset, barometer
/// offset, clones,
/// keyframes by id, GNSS clones), for comparing modes: the nominal values
/// (rotations as rotation vectors, one number per error state) and the
/// covariance.
#[derive(Clone, Debug)]
pub struct Snapshot {
    pub x: DVector<f64>,
    pub P: DMatrix<f64>,
}

impl Snapshot {
    /// The largest difference from `other` (the reference), each entry
    /// normalised by its own scale: a covariance entry by `√(P_ii P_jj)` (so
    /// an unobserved state's large variance cannot hide an error
    /// elsewhere), a state by its sigma `√P_ii` once the difference exceeds
    /// the value's own rounding. Infinite if the layouts differ.
    pub fn max_rel_diff(&self, other: &Snapshot) -> f64 {
        let (cov, state) = self.max_rel_diff_parts(other);
        cov.max(state)
    }

    /// [`Self::max_rel_diff`] of the covariance and of the nominal state,
    /// apart.
    pub fn max_rel_diff_parts(&self, other: &Snapshot) -> (f64, f64) {
        let n = self.P.nrows();
        if self.x.len() != other.x.len() || self.P.shape() != other.P.shape() || self.x.len() != n {
            return (f64::INFINITY, f64::INFINITY);
        }
        let sig: Vec<f64> = (0..n).map(|i| other.P[(i, i)].abs().sqrt().max(1e-300)).collect();
        let mut cov = 0.0f64;
        for j in 0..n {
            for i in 0..n {
                cov = cov.max((self.P[(i, j)] - other.P[(i, j)]).abs() / (sig[i] * sig[j]));
            }
        }
        let mut state = 0.0f64;
        for ((a, b), s) in self.x.iter().zip(other.x.iter()).zip(&sig) {
            // A nominal value is summed from its corrections in another
            // order in each mode: differences within its last bits
            // (`STATE_ULPS` of its magnitude) are rounding, not error.
            let d = ((a - b).abs() - STATE_ULPS * f64::EPSILON * a.abs().max(b.abs())).max(0.0) / s;
            state = state.max(d);
        }
        (cov, state)
    }
}

impl Estimator {
    /// The whole state, reconstructed, in a fixed order: IMU, clones,
    /// keyframes by id. Does not change the filter.
    pub fn snapshot(&self) -> Snapshot {
        let mut est = self.clone();
        est.merge_global();
        let kf_pos: BTreeMap<u64, usize> = est
            .local_kfs
            .iter()
            .enumerate()
            .map(|(j, id)| (*id, ACTIVE_DIM + 6 * j))
            .collect();
        let mut idx: Vec<usize> = (0..ACTIVE_DIM).collect();
        let co = est.clones_offset();
        idx.extend(co..co + 6 * est.clones.len());
        for off in kf_pos.values() {
            idx.extend(*off..*off + 6);
        }
        let go = est.gnss_clones_offset();
        idx.extend(go..go + GNSS_CLONE_DIM * est.gnss_clones.len());
        // The range-bias block (DG5′): the troposphere, then the satellites
        // by key, so that two filters' blocks line up whatever order their
        // satellites arrived in.
        let bo = est.range_bias_offset();
        let t_first = est.range_bias.first_sat();
        idx.extend(bo..bo + t_first);
        let mut sats: Vec<(usize, &super::range_bias::RangeBias)> = est.range_bias.sats.iter().enumerate().collect();
        sats.sort_by_key(|(_, b)| (b.system, b.prn));
        idx.extend(sats.iter().map(|(i, _)| bo + t_first + i));
        let P = est.P.select_rows(&idx).select_columns(&idx);
        let mut x = Vec::new();
        // Rotations as rotation vectors, so `x` lines up one to one with
        // the error states of `P`.
        let push_q = |x: &mut Vec<f64>, q: &UnitQuaternion<f64>| {
            x.extend(q.scaled_axis().iter());
        };
        let i = &est.imu;
        push_q(&mut x, &i.q_W_B);
        for v in [i.v_B_in_W, i.p_B_in_W, i.b_g, i.b_a] {
            x.extend(v.iter());
        }
        x.extend(est.clock.iter());
        x.push(est.t_d_s);
        x.push(est.baro.value_m);
        for c in &est.clones {
            push_q(&mut x, &c.q_W_B);
            x.extend(c.p_B_in_W.iter());
        }
        for id in kf_pos.keys() {
            let kf = &est.keyframes[id];
            x.extend(kf.delta.iter());
            x.extend(kf.p_B_in_W.iter());
        }
        for g in &est.gnss_clones {
            push_q(&mut x, &g.nom.imu.q_W_B);
            for v in [g.nom.imu.v_B_in_W, g.nom.imu.p_B_in_W, g.nom.imu.b_g] {
                x.extend(v.iter());
            }
            x.extend(g.nom.clock.iter());
        }
        x.extend(est.range_bias.tropo_zenith_m);
        x.extend(sats.iter().map(|(_, b)| b.value_m));
        Snapshot {
            x: DVector::from_vec(x),
            P,
        }
    }
}
