//! The errors a single-point code shares with itself for the whole flight,
//! as states (README.md §8c, eq. DG5′): each satellite's broadcast orbit and
//! clock error `b_i` on its line of sight, and the zenith error `T_z` of the
//! receiver's troposphere model, which every code sees through its mapping
//! `m(el)`.
//!
//! Why states and not a weight: a constant error fused as if white is
//! believed again at every epoch. A window that counts it once per few
//! seconds (DG6) is right for a flight as long as the window's tuning, and
//! about ten times overconfident after an hour once the keyframe map keeps
//! the whole flight's fixes (position NEES 34.4 against 3). As states, each
//! satellite's error is believed once, whatever the rate and the flight's
//! length, and what the filter learns of it is carried through an outage.
//!
//! The block sits after the GNSS clones, `[T_z, b_1 … b_k]`, one state per
//! satellite in order of first use. No camera row sees it, so its random
//! walk's noise is added lazily at each epoch (exact for `F = I`), and a new
//! state enters uncorrelated with everything: zero rows of `Φ̃` in compressed
//! mode. A satellite unused for `range_bias_timeout_s` leaves (A2).

use cmsckf_models::gnss::System;
use nalgebra::DMatrix;

use super::{Estimator, GNSS_CLONE_DIM};

/// The most satellite states the block holds: four constellations in view
/// at once. A satellite beyond them is weighted by DG6's window instead,
/// and counted.
pub(super) const MAX_RANGE_BIAS_STATES: usize = 40;
/// A full block gives the slot of its longest-unused satellite to a new one
/// once that satellite has been unused this long (s): one that has set or
/// is behind a building, against one in view now.
const SLOT_REUSE_AFTER_S: f64 = 10.0;
/// Codes of a satellite refused in a row after which its state starts again
/// (see [`RangeBias::refused_in_a_row`]).
pub(super) const REFUSALS_BEFORE_RESTART: u32 = 5;

/// One satellite's range-bias state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct RangeBias {
    pub system: System,
    pub prn: u8,
    /// The estimate `b̂_i` (m), added to the predicted pseudorange.
    pub value_m: f64,
    /// When a code of it was last fused (s).
    pub last_used_s: f64,
    /// Its codes refused by the χ² gate in a row: a step of its error
    /// (a new ephemeris, another code) that the state's own variance no
    /// longer allows.
    pub refused_in_a_row: u32,
}

/// A satellite's range bias as the filter holds it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RangeBiasEstimate {
    pub system: System,
    pub prn: u8,
    /// The estimate `b̂_i` (m) and its variance (m²).
    pub b_m: f64,
    pub var_m2: f64,
}

/// The block's nominal values and bookkeeping.
#[derive(Clone, Debug, Default, PartialEq)]
pub(super) struct RangeBiasBlock {
    /// The zenith troposphere error `T̂_z` (m), once a single-point epoch has
    /// created it: the block's first state.
    pub tropo_zenith_m: Option<f64>,
    /// The satellites' states, in `P` order after `T_z`.
    pub sats: Vec<RangeBias>,
    /// Time up to which the random walks' noise has been added (s).
    pub noise_t_s: f64,
}

impl RangeBiasBlock {
    /// Index in the block of the first satellite's state: after `T_z`, if
    /// there is one.
    pub fn first_sat(&self) -> usize {
        usize::from(self.tropo_zenith_m.is_some())
    }

    /// States in the block.
    pub fn dim(&self) -> usize {
        self.first_sat() + self.sats.len()
    }

    /// Index of a satellite's state within the block.
    pub fn slot(&self, system: System, prn: u8) -> Option<usize> {
        let first = self.first_sat();
        self.sats
            .iter()
            .position(|b| b.system == system && b.prn == prn)
            .map(|i| first + i)
    }
}

/// How much worse a constellation's broadcast orbits and clocks are than
/// GPS's and Galileo's: GLONASS's are about twice as far off.
pub(super) fn broadcast_factor(system: System) -> f64 {
    if system == System::Glonass {
        2.0
    } else {
        1.0
    }
}

impl Estimator {
    /// Offset of the range-bias block: after the GNSS clones.
    pub fn range_bias_offset(&self) -> usize {
        self.gnss_clones_offset() + GNSS_CLONE_DIM * self.gnss_clones.len()
    }

    /// The zenith troposphere error and its variance (m, m²), once created.
    pub fn troposphere_zenith(&self) -> Option<(f64, f64)> {
        let o = self.range_bias_offset();
        self.range_bias.tropo_zenith_m.map(|t| (t, self.P[(o, o)]))
    }

    /// Each satellite's range bias and its variance, in state order.
    pub fn range_biases(&self) -> Vec<RangeBiasEstimate> {
        let o = self.range_bias_offset() + self.range_bias.first_sat();
        self.range_bias
            .sats
            .iter()
            .enumerate()
            .map(|(i, b)| RangeBiasEstimate {
                system: b.system,
                prn: b.prn,
                b_m: b.value_m,
                var_m2: self.P[(o + i, o + i)],
            })
            .collect()
    }

    /// Inserts `vars.len()` new error states at `at`, uncorrelated with the
    /// rest, with variances `vars` (§2, eq. A1 with `J = 0` and its own
    /// prior): `P' = [P, 0; 0, diag(vars)]` placed at `at`, and zero rows of
    /// `Φ̃` (a state the global part has never seen; compressed mode equals
    /// full only with them).
    pub(super) fn insert_independent(&mut self, at: usize, vars: &[f64]) {
        let (n, k) = (self.P.nrows(), vars.len());
        let cross = DMatrix::zeros(n, k);
        let block = DMatrix::from_diagonal(&nalgebra::DVector::from_column_slice(vars));
        self.insert_local(at, &cross, &block);
        if let Some(g) = self.global.as_mut() {
            let phi = std::mem::replace(&mut g.Phi, DMatrix::zeros(0, 0)).insert_rows(at, k, 0.0);
            g.Phi = phi;
        }
    }

    /// The random walks' noise from the last epoch to `t_s` (eq. DG5′):
    /// `P_ii += q² Δt` on the block's diagonal; `Φ̃` is untouched (noise is
    /// no transformation, C1).
    pub(super) fn add_range_bias_noise(&mut self, t_s: f64) {
        let dt_s = t_s - self.range_bias.noise_t_s;
        if dt_s.is_nan() || dt_s <= 0.0 {
            return;
        }
        self.range_bias.noise_t_s = t_s;
        let o = self.range_bias_offset();
        let mut i = o;
        if self.range_bias.tropo_zenith_m.is_some() {
            self.P[(i, i)] += self.s.troposphere_rw_m_per_sqrt_s.powi(2) * dt_s;
            i += 1;
        }
        let q_b = self.s.range_bias_rw_m_per_sqrt_s.powi(2) * dt_s;
        for _ in 0..self.range_bias.sats.len() {
            self.P[(i, i)] += q_b;
            i += 1;
        }
    }

    /// Creates the zenith troposphere state with its prior, if not yet. A
    /// prior of 0 (`troposphere_sigma_m = 0`: the model taken as exact)
    /// makes no state: a state of zero variance would fail the health
    /// check's positive diagonal.
    pub(super) fn ensure_troposphere_state(&mut self, t_s: f64) {
        if self.range_bias.tropo_zenith_m.is_some() || self.s.troposphere_sigma_m <= 0.0 {
            return;
        }
        if self.range_bias.sats.is_empty() {
            self.range_bias.noise_t_s = self.range_bias.noise_t_s.max(t_s);
        }
        let at = self.range_bias_offset();
        self.insert_independent(at, &[self.s.troposphere_sigma_m.powi(2)]);
        self.range_bias.tropo_zenith_m = Some(0.0);
    }

    /// A satellite's slot in the block, its state created with the prior
    /// `(k_sys σ_b)²` if it has none; `None` when the block is full of
    /// satellites in use.
    pub(super) fn ensure_range_bias_state(&mut self, system: System, prn: u8, t_s: f64) -> Option<usize> {
        if let Some(k) = self.range_bias.slot(system, prn) {
            return Some(k);
        }
        if self.range_bias.sats.len() >= MAX_RANGE_BIAS_STATES {
            let (i, oldest_s) = self
                .range_bias
                .sats
                .iter()
                .enumerate()
                .map(|(i, b)| (i, b.last_used_s))
                .min_by(|a, b| a.1.total_cmp(&b.1))?;
            if t_s - oldest_s < SLOT_REUSE_AFTER_S {
                return None;
            }
            self.remove_range_bias(i);
        }
        let sigma_m = self.s.range_bias_sigma_m * broadcast_factor(system);
        self.add_range_bias(system, prn, sigma_m, t_s);
        self.range_bias.slot(system, prn)
    }

    /// Appends a satellite's state with the prior sigma `sigma_m`.
    fn add_range_bias(&mut self, system: System, prn: u8, sigma_m: f64, t_s: f64) {
        let at = self.range_bias_offset() + self.range_bias.dim();
        self.insert_independent(at, &[sigma_m * sigma_m]);
        self.stats.range_bias_states_created += 1;
        self.range_bias.sats.push(RangeBias {
            system,
            prn,
            value_m: 0.0,
            last_used_s: t_s,
            refused_in_a_row: 0,
        });
    }

    /// Marginalises the `i`-th satellite's state (A2).
    fn remove_range_bias(&mut self, i: usize) {
        let first = self.range_bias.first_sat();
        let at = self.range_bias_offset() + first + i;
        self.remove_block(at, 1);
        self.range_bias.sats.remove(i);
        self.stats.range_bias_states_dropped += 1;
    }

    /// Starts again the state of each satellite whose codes the gate has
    /// refused [`REFUSALS_BEFORE_RESTART`] times in a row: its error
    /// stepped (a new ephemeris or clock upload, another code) beyond what
    /// the state's variance allows, and would lock the satellite out for
    /// good. The new state's prior is one epoch's broadcast sigma
    /// (`broadcast_sigma_m`, the user range accuracy, and at least
    /// `range_bias_sigma_m`), since a step is a new error of any size the
    /// broadcast allows. Returns how many restarted.
    pub(super) fn restart_refused_range_biases(&mut self, t_s: f64) -> u64 {
        let mut restarted = 0;
        let mut i = 0;
        while i < self.range_bias.sats.len() {
            let b = self.range_bias.sats[i];
            if b.refused_in_a_row >= REFUSALS_BEFORE_RESTART {
                self.remove_range_bias(i);
                let sigma_m = self.s.broadcast_sigma_m.max(self.s.range_bias_sigma_m) * broadcast_factor(b.system);
                self.add_range_bias(b.system, b.prn, sigma_m, t_s);
                restarted += 1;
            } else {
                i += 1;
            }
        }
        restarted
    }

    /// Marginalises the states of satellites unused for
    /// `range_bias_timeout_s` (A2): a satellite that has set does not come
    /// back within hours, and one behind a building for less keeps what the
    /// filter knew of it.
    pub(super) fn drop_stale_range_biases(&mut self, t_s: f64) {
        let timeout_s = self.s.range_bias_timeout_s;
        let mut i = 0;
        while i < self.range_bias.sats.len() {
            if t_s - self.range_bias.sats[i].last_used_s > timeout_s {
                self.remove_range_bias(i);
            } else {
                i += 1;
            }
        }
    }

    /// Adds the block's part of a correction `δx` to its nominal values.
    pub(super) fn inject_range_bias(&mut self, dx: &nalgebra::DVector<f64>) {
        let mut i = self.range_bias_offset();
        if let Some(t) = self.range_bias.tropo_zenith_m.as_mut() {
            *t += dx[i];
            i += 1;
        }
        for b in self.range_bias.sats.iter_mut() {
            b.value_m += dx[i];
            i += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimator::propagate::tests::state;
    use crate::estimator::Mat15;

    fn estimator() -> Estimator {
        let s = crate::config::Config::default().estimator_settings();
        let mut p0 = Mat15::identity() * 0.01;
        p0[(0, 1)] = 0.002;
        p0[(1, 0)] = 0.002;
        Estimator::new(s, 0.0, state(), &p0)
    }

    /// States enter uncorrelated with their priors, take their random walk's
    /// noise lazily, and leave after the timeout unused, each change leaving
    /// the rest of `P` exactly as it was.
    #[test]
    fn range_bias_states_enter_wander_and_leave() {
        let mut est = estimator();
        let before = est.P.clone();
        est.ensure_troposphere_state(0.0);
        let g = est.ensure_range_bias_state(System::Gps, 5, 0.0);
        let r = est.ensure_range_bias_state(System::Glonass, 7, 0.0);
        let e = est.ensure_range_bias_state(System::Galileo, 11, 0.0);
        assert_eq!((g, r, e), (Some(1), Some(2), Some(3)));
        // Asking again gives the same slot and no new state.
        assert_eq!(est.ensure_range_bias_state(System::Gps, 5, 1.0), Some(1));
        let n = before.nrows();
        assert_eq!(est.P.nrows(), n + 4);
        assert_eq!(est.P.view((0, 0), (n, n)), before);
        assert!(est.P.view((0, n), (n, 4)).iter().all(|x| *x == 0.0));
        let sb = est.s.range_bias_sigma_m;
        let prior = [est.s.troposphere_sigma_m.powi(2), sb * sb, (2.0 * sb).powi(2), sb * sb];
        for (k, v) in prior.iter().enumerate() {
            assert_eq!(est.P[(n + k, n + k)], *v, "prior of state {k}");
        }
        // The random walks over 100 s, added in ten steps or one.
        let mut stepwise = est.clone();
        for k in 1..=10 {
            stepwise.add_range_bias_noise(10.0 * k as f64);
        }
        est.add_range_bias_noise(100.0);
        let q_t = est.s.troposphere_rw_m_per_sqrt_s.powi(2) * 100.0;
        let q_b = est.s.range_bias_rw_m_per_sqrt_s.powi(2) * 100.0;
        assert!((est.P[(n, n)] - prior[0] - q_t).abs() < 1e-15);
        for k in 1..4 {
            assert!((est.P[(n + k, n + k)] - prior[k] - q_b).abs() < 1e-15);
            assert!((est.P[(n + k, n + k)] - stepwise.P[(n + k, n + k)]).abs() < 1e-15);
        }
        // Time going back adds nothing.
        let held = est.P.clone();
        est.add_range_bias_noise(50.0);
        assert_eq!(est.P, held);
        // GLONASS 7 fused at 200 s; at 301 s the other two are 301 s unused.
        est.range_bias.sats[1].last_used_s = 200.0;
        let kept = est.P[(n + 2, n + 2)];
        est.drop_stale_range_biases(301.0);
        assert_eq!(est.range_biases().len(), 1);
        assert_eq!(est.range_bias.slot(System::Glonass, 7), Some(1));
        assert_eq!(est.P.nrows(), n + 2);
        assert_eq!(est.P[(n + 1, n + 1)], kept);
        assert_eq!(est.P.view((0, 0), (n, n)), before);
        assert_eq!(
            (est.stats.range_bias_states_created, est.stats.range_bias_states_dropped),
            (3, 2)
        );
        // The troposphere stays for the flight.
        assert!(est.troposphere_zenith().is_some());
    }

    /// A correction reaches the block's nominal values, in state order.
    #[test]
    fn a_correction_moves_the_blocks_estimates() {
        let mut est = estimator();
        est.ensure_troposphere_state(0.0);
        est.ensure_range_bias_state(System::Gps, 3, 0.0);
        est.ensure_range_bias_state(System::Gps, 9, 0.0);
        let n = est.P.nrows();
        let mut dx = nalgebra::DVector::zeros(n);
        dx[n - 3] = 0.05;
        dx[n - 2] = -0.3;
        dx[n - 1] = 0.7;
        est.inject_range_bias(&dx);
        assert_eq!(est.troposphere_zenith().map(|t| t.0), Some(0.05));
        let b: Vec<f64> = est.range_biases().iter().map(|b| b.b_m).collect();
        assert_eq!(b, vec![-0.3, 0.7]);
    }

    /// `troposphere_sigma_m = 0` takes the model as exact: no zenith state
    /// (one of zero variance would fail the health check), and the
    /// satellites' states index from 0.
    #[test]
    fn a_zero_troposphere_prior_makes_no_state() {
        let mut est = estimator();
        est.s.troposphere_sigma_m = 0.0;
        est.ensure_troposphere_state(0.0);
        assert_eq!(est.troposphere_zenith(), None);
        assert_eq!(est.ensure_range_bias_state(System::Gps, 5, 0.0), Some(0));
        assert!(est.check_health().is_ok(), "{:?}", est.check_health());
    }

    /// A full block gives the slot of a satellite unused for 10 s to a new
    /// one, and refuses while all are in use.
    #[test]
    fn a_full_block_reuses_the_slot_of_a_satellite_gone() {
        let mut est = estimator();
        for prn in 0..MAX_RANGE_BIAS_STATES as u8 {
            assert!(est.ensure_range_bias_state(System::Gps, prn + 1, 0.0).is_some());
        }
        for b in est.range_bias.sats.iter_mut().skip(1) {
            b.last_used_s = 8.0;
        }
        assert_eq!(est.ensure_range_bias_state(System::Galileo, 3, 9.0), None);
        assert!(est.ensure_range_bias_state(System::Galileo, 3, 10.5).is_some());
        assert_eq!(
            est.range_bias.slot(System::Gps, 1),
            None,
            "the longest unused gave its slot"
        );
        assert_eq!(est.range_biases().len(), MAX_RANGE_BIAS_STATES);
        assert_eq!(est.stats.range_bias_states_dropped, 1);
    }

    /// A satellite whose codes the gate refused five times in a row starts
    /// again, uncorrelated, at one epoch's broadcast sigma; the others keep
    /// their states exactly.
    #[test]
    fn a_satellite_the_gate_keeps_refusing_starts_again() {
        let mut est = estimator();
        est.ensure_troposphere_state(0.0);
        est.ensure_range_bias_state(System::Gps, 5, 0.0);
        est.ensure_range_bias_state(System::Gps, 9, 0.0);
        let n = est.P.nrows();
        est.range_bias.sats[0].value_m = 0.4;
        est.range_bias.sats[0].refused_in_a_row = REFUSALS_BEFORE_RESTART - 1;
        assert_eq!(est.restart_refused_range_biases(1.0), 0);
        est.range_bias.sats[0].refused_in_a_row = REFUSALS_BEFORE_RESTART;
        let kept = est.P[(n - 1, n - 1)];
        assert_eq!(est.restart_refused_range_biases(1.0), 1);
        assert_eq!(est.P.nrows(), n);
        let b = est.range_biases();
        assert_eq!((b[0].prn, b[1].prn), (9, 5), "the restarted state goes last");
        assert_eq!(b[0].var_m2, kept);
        assert_eq!(b[1].b_m, 0.0);
        assert_eq!(b[1].var_m2, est.s.broadcast_sigma_m.powi(2));
        assert!(est.P.row(n - 1).iter().take(n - 1).all(|x| *x == 0.0));
    }
}
