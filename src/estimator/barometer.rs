//! The barometer as a height (README.md §3g). Why this exists: a camera
//! and an IMU hold no height once it has drifted. A climb flown at the
//! wrong scale (the lift-off's first updates set it, §3c) keeps its error
//! for the whole flight, under a σ that says nothing of it. Every
//! autopilot carries a barometer; its height changes are good to a
//! decimetre over minutes, while its zero moves with the weather and the
//! board's temperature. So the filter takes each reading as the height
//! plus an offset it estimates (state [`BARO`], a random walk), and the
//! readings hold the height's changes, not its value.
//!
//! Eq. B1: `h_m = −p_z(t) + b_h + n`, `n ~ N(0, σ_h²)`, `W` being NED.
//! A reading up to [`MAX_BARO_LAG_S`] older or newer than the filter is
//! predicted along the velocity: `p_z(t) = p_z − v_z τ`, `τ = t_filter − t`.
//! Eq. B2: the first reading sets the offset, `b̂_h = h_m + p̂_z(t)`, whose
//! error `δb_h = δp_z(t) − n` is the position's plus the reading's: its
//! covariance row is the position's, its variance `P_zz + σ_h²`. The
//! reading is used once, to set the offset, and not fused.

use nalgebra::{DMatrix, DVector};

use super::propagate::{P, V};
use super::{Estimator, InputError, BARO};
use crate::counters::Counter;

/// A reading older than the filter by more than this (s) is refused as
/// late (a barometer's 10 Hz readings come within a frame's latency); one
/// newer than the filter by up to this is predicted forward to it.
pub const MAX_BARO_LAG_S: f64 = 0.2;
/// A residual this large (m) is no barometer that drifted or stepped but
/// another height altogether (a pressure far off, another sensor): the
/// offset is set afresh from the reading, which is not fused.
pub const BARO_REANCHOR_M: f64 = 10.0;
/// A run of refusals this soon after the offset was set or carried, or
/// the height reset to it (s), blames the barometer (B3).
pub const BARO_SECOND_STRIKE_S: f64 = 10.0;
/// Probability of the reading's χ² gate (one degree of freedom).
const BARO_GATE_PROB: f64 = 0.999;

/// The barometer's offset `b_h` (m) as the filter holds it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(super) struct BaroOffset {
    /// The nominal `b̂_h` (m).
    pub value_m: f64,
    /// Whether a reading has set it (eq. B2).
    pub anchored: bool,
    /// Readings refused by the gate in a row.
    pub refused_in_a_row: u32,
    /// Until when (s) a run of refusals blames the offset first (B3):
    /// for a while after it was set from one reading or carried from a
    /// filter that failed, and after the height was reset to it.
    pub offset_suspect_until_s: f64,
}

/// What became of one reading.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum BaroOutcome {
    /// It set the offset: the first reading of this filter, or one more
    /// than [`BARO_REANCHOR_M`] from the height (`reanchored`, counted
    /// `baro_reanchored`).
    Anchored { offset_m: f64, reanchored: bool },
    /// Fused: its residual (m), the residual's σ (m) and its NIS.
    Fused { residual_m: f64, sigma_m: f64, nis: f64 },
    /// Refused by the χ² gate.
    Refused { residual_m: f64, sigma_m: f64, nis: f64 },
    /// Refused [`super::BaroSettings::refusals_before_height_reset`] in a
    /// row: the height's variance was raised by `added_var_m2` (m², eq.
    /// B3) and the reading fused. `sigma_m` is the residual's σ before.
    HeightReset {
        residual_m: f64,
        sigma_m: f64,
        added_var_m2: f64,
    },
    /// As [`Self::HeightReset`], but the offset was suspect (set or
    /// carried, or the height reset to it, within
    /// [`BARO_SECOND_STRIKE_S`]): the offset took the excess (B3).
    OffsetReset {
        residual_m: f64,
        sigma_m: f64,
        added_var_m2: f64,
    },
}

impl Estimator {
    /// One barometer reading (eqs. B1, B2): `h_m` the standard
    /// atmosphere's height (m, up) at `t_s`.
    pub(super) fn update_with_baro(&mut self, t_s: f64, h_m: f64) -> Result<BaroOutcome, InputError> {
        if !(t_s.is_finite() && h_m.is_finite()) {
            return Err(InputError::NonFiniteBaro { t_s, h_m });
        }
        // A reading is not a reason to move the filter on: camera frames
        // stamped before it may still be on their way (their tracking
        // takes longer than a barometer's message), and a filter moved past
        // them would drop them as late. One ahead of the filter is
        // predicted forward along the velocity, as a late one back (B1);
        // only one more than `MAX_BARO_LAG_S` ahead moves the filter, to
        // that far behind it (frames later than that are late anyway).
        if t_s - self.t_s > MAX_BARO_LAG_S {
            self.propagate_filter_to(t_s - MAX_BARO_LAG_S);
        }
        let lag_s = self.t_s - t_s;
        if lag_s > MAX_BARO_LAG_S {
            *self.stats.rejected.entry(Counter::BaroLate).or_default() += 1;
            return Err(InputError::BaroLate {
                t_s,
                late_s: lag_s,
                max_s: MAX_BARO_LAG_S,
            });
        }
        self.sync();
        let (h_pred_m, cols, h_x) = self.baro_height_model(lag_s);
        let noise_var = self.s.baro.noise_m.powi(2);
        let residual_m = h_m - (h_pred_m + self.baro.value_m);
        if !self.baro.anchored || residual_m.abs() > BARO_REANCHOR_M {
            let reanchored = self.baro.anchored;
            if reanchored {
                *self.stats.rejected.entry(Counter::BaroReanchored).or_default() += 1;
            }
            self.anchor_baro(&cols, &h_x, noise_var);
            self.baro = BaroOffset {
                value_m: h_m - h_pred_m,
                anchored: true,
                refused_in_a_row: 0,
                offset_suspect_until_s: t_s + BARO_SECOND_STRIKE_S,
            };
            return Ok(BaroOutcome::Anchored {
                offset_m: self.baro.value_m,
                reanchored,
            });
        }
        // S = H P Hᵀ + σ², H = [h_x on cols, 1 on BARO].
        let all = [cols[0], cols[1], BARO];
        let hv = [h_x[0], h_x[1], 1.0];
        let s = self.row_variance(&all, &hv) + noise_var;
        if !(s.is_finite() && s > 0.0) {
            *self.stats.rejected.entry(Counter::UpdateNotPd).or_default() += 1;
            return Ok(BaroOutcome::Refused {
                residual_m,
                sigma_m: f64::NAN,
                nis: f64::NAN,
            });
        }
        let nis = residual_m * residual_m / s;
        let sigma_m = s.sqrt();
        let mut outcome = BaroOutcome::Fused {
            residual_m,
            sigma_m,
            nis,
        };
        if nis > cmsckf_models::stats::chi2_quantile(BARO_GATE_PROB, 1) {
            self.baro.refused_in_a_row += 1;
            if self.baro.refused_in_a_row < self.s.baro.refusals_before_height_reset {
                *self.stats.rejected.entry(Counter::BaroRefused).or_default() += 1;
                return Ok(BaroOutcome::Refused {
                    residual_m,
                    sigma_m,
                    nis,
                });
            }
            // Eq. B3: the barometer has disagreed beyond its gate for
            // half a second, more than its noise and its offset's walk
            // allow. Whatever was not told of it holds the residual's
            // excess over its predicted variance, `E[r²] = S + Δ`: added
            // as process noise to that state's variance, the reading is
            // fused at NIS 1 and that state goes most of the way. The
            // height (a climb integrated at the wrong scale; EKF2 resets
            // its height to its height reference alike), unless the offset
            // is suspect: set from one reading or carried from a failed
            // filter within `BARO_SECOND_STRIKE_S`, or the height already
            // reset to it that recently (then it is the barometer that
            // moved: another one switched in, the rotor wash).
            let added_var_m2 = residual_m * residual_m - s;
            let (counter, reset) = if t_s < self.baro.offset_suspect_until_s {
                self.baro.offset_suspect_until_s = f64::NEG_INFINITY;
                self.P[(BARO, BARO)] += added_var_m2;
                (
                    Counter::BaroOffsetReset,
                    BaroOutcome::OffsetReset {
                        residual_m,
                        sigma_m,
                        added_var_m2,
                    },
                )
            } else {
                self.baro.offset_suspect_until_s = t_s + BARO_SECOND_STRIKE_S;
                self.add_window_height_variance(added_var_m2);
                (
                    Counter::BaroHeightReset,
                    BaroOutcome::HeightReset {
                        residual_m,
                        sigma_m,
                        added_var_m2,
                    },
                )
            };
            outcome = reset;
            *self.stats.rejected.entry(counter).or_default() += 1;
        }
        self.baro.refused_in_a_row = 0;
        // Whitened (unit noise): H/σ_h, r/σ_h.
        let sd = noise_var.sqrt();
        let h = DMatrix::from_row_slice(1, 3, &[hv[0] / sd, hv[1] / sd, hv[2] / sd]);
        let r = DVector::from_element(1, residual_m / sd);
        self.ekf_update(&h, &all, &r, false);
        self.stats.baro_updates += 1;
        Ok(outcome)
    }

    /// B1 without the offset: the height `−(p_z − v_z τ)` a reading `τ`
    /// older than the filter predicts, the error-state columns it reads
    /// and its Jacobian on them (`∂h/∂δp_z = −1`, `∂h/∂δv_z = τ`).
    fn baro_height_model(&self, lag_s: f64) -> (f64, [usize; 2], [f64; 2]) {
        let h_pred_m = -self.imu.p_B_in_W.z + lag_s * self.imu.v_B_in_W.z;
        (h_pred_m, [P + 2, V + 2], [-1.0, lag_s])
    }

    /// B3's height: the body's and its sliding window's heights (the
    /// camera clones', and the GNSS clones', copies of the body's) gain one
    /// common error of variance `var_m2`, `P += var · u uᵀ` with `u` one at
    /// each of their vertical positions. A climb integrated at the wrong
    /// scale left the whole window high or low together; raising the body's
    /// alone, the tracks through the window's views pull it back to the
    /// window's (measured beside PX4: back to 0.6 m off within 0.7 s, at
    /// 8 σ). The keyframes, the map, keep theirs. Process noise
    /// on the local part only.
    fn add_window_height_variance(&mut self, var_m2: f64) {
        let heights: Vec<usize> = self.position_starts(false).iter().map(|&i| i + 2).collect();
        self.add_common_error(&heights, var_m2);
    }

    /// `h P hᵀ` of one row `h` on the states `cols`.
    fn row_variance(&self, cols: &[usize], h: &[f64]) -> f64 {
        cols.iter()
            .zip(h)
            .map(|(&i, &hi)| {
                cols.iter()
                    .zip(h)
                    .map(|(&j, &hj)| hi * hj * self.P[(i, j)])
                    .sum::<f64>()
            })
            .sum()
    }

    /// Eq. B2's covariance: `δb_h = −H_x δx − n`, so the offset's row is
    /// `−H_x P` (here the position's, and the velocity's times the lag) and
    /// its variance `H_x P H_xᵀ + σ_h²`; in compressed mode its row of `Φ̃`
    /// is `−H_x Φ̃` alike. Whatever it held before is forgotten.
    fn anchor_baro(&mut self, cols: &[usize; 2], h_x: &[f64; 2], noise_var: f64) {
        self.P.row_mut(BARO).fill(0.0);
        self.P.column_mut(BARO).fill(0.0);
        let n = self.P.nrows();
        let mut row = DVector::zeros(n);
        for (&c, &h) in cols.iter().zip(h_x) {
            row -= self.P.column(c) * h;
        }
        row[BARO] = self.row_variance(cols, h_x) + noise_var;
        self.P.row_mut(BARO).copy_from(&row.transpose());
        self.P.column_mut(BARO).copy_from(&row);
        if let Some(g) = self.global.as_mut() {
            let mut phi_row = g.Phi.row(cols[0]) * -h_x[0];
            phi_row -= g.Phi.row(cols[1]) * h_x[1];
            g.Phi.row_mut(BARO).copy_from(&phi_row);
        }
    }

    /// Gives a filter that has had no reading yet the offset a filter
    /// before it learned (m, and its variance m², uncorrelated with the
    /// rest): the offset is the barometer's, not the filter's, and a
    /// restart in flight keeps it, so that the readings bring the new
    /// filter's height back to the old one's ground (eq. B4). `false`
    /// (nothing changed) once a reading has set one, or for a value or
    /// variance not finite and positive.
    pub fn carry_baro_offset(&mut self, value_m: f64, var_m2: f64) -> bool {
        if self.baro.anchored || !(value_m.is_finite() && var_m2.is_finite() && var_m2 > 0.0) {
            return false;
        }
        self.sync();
        self.P.row_mut(BARO).fill(0.0);
        self.P.column_mut(BARO).fill(0.0);
        if let Some(g) = self.global.as_mut() {
            g.Phi.row_mut(BARO).fill(0.0);
        }
        self.P[(BARO, BARO)] = var_m2;
        self.baro = BaroOffset {
            value_m,
            anchored: true,
            refused_in_a_row: 0,
            offset_suspect_until_s: self.t_s + BARO_SECOND_STRIKE_S,
        };
        true
    }

    /// The barometer's offset (m) and its variance (m²); `None` before a
    /// reading set it.
    pub fn baro_offset(&self) -> Option<(f64, f64)> {
        self.baro.anchored.then(|| (self.baro.value_m, self.P[(BARO, BARO)]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimator::{ImuState, Mat15, ACTIVE_DIM, GNSS_CLONE_DIM};
    use nalgebra::{UnitQuaternion, Vector3};

    /// A filter at rest at 3 m up, climbing at 1.2 m/s, with a full
    /// covariance on its IMU states (correlated, so a wrong row shows).
    fn estimator() -> Estimator {
        let s = crate::config::Config::default().estimator_settings();
        let x = ImuState {
            q_W_B: UnitQuaternion::from_euler_angles(0.05, -0.03, 0.4),
            v_B_in_W: Vector3::new(0.3, -0.2, -1.2),
            p_B_in_W: Vector3::new(1.0, 2.0, -3.0),
            b_g: Vector3::zeros(),
            b_a: Vector3::zeros(),
        };
        let a = Mat15::from_fn(|i, j| ((i * 7 + j * 3) % 5) as f64 * 0.01);
        let p0 = a * a.transpose() + Mat15::identity() * 0.02;
        Estimator::new(s, 0.0, x, &p0)
    }

    /// The height model's Jacobian against finite differences of the
    /// prediction over every active error state (B1).
    #[test]
    fn the_height_jacobian_matches_finite_differences() {
        let est = estimator();
        for lag_s in [0.0, 0.15] {
            let (h0, cols, h_x) = est.baro_height_model(lag_s);
            for k in 0..ACTIVE_DIM {
                let eps = 1e-6;
                let mut e = est.clone();
                let mut dx = DVector::zeros(e.P.nrows());
                dx[k] = eps;
                e.inject(&dx);
                let fd = (e.baro_height_model(lag_s).0 - h0) / eps;
                let analytic = cols
                    .iter()
                    .zip(&h_x)
                    .filter(|(c, _)| **c == k)
                    .map(|(_, h)| *h)
                    .sum::<f64>();
                assert!(
                    (fd - analytic).abs() < 1e-6,
                    "state {k}, lag {lag_s}: fd {fd}, analytic {analytic}"
                );
            }
        }
    }

    /// B2: the first reading sets the offset and is not fused; the
    /// offset's covariance row is the height's (`−H_x P`) and its
    /// variance the height's plus the reading's. The second reading is
    /// then fused with the residual it should have.
    #[test]
    fn the_first_reading_sets_the_offset_with_the_heights_covariance() {
        let mut est = estimator();
        let p_before = est.P.clone();
        let out = est.process_baro(0.0, 503.0).unwrap();
        assert_eq!(
            out,
            BaroOutcome::Anchored {
                offset_m: 500.0,
                reanchored: false
            }
        );
        let noise_var = est.s.baro.noise_m.powi(2);
        let pz = P + 2;
        for j in 0..est.P.nrows() {
            let want = if j == BARO {
                p_before[(pz, pz)] + noise_var
            } else {
                est.P[(pz, j)]
            };
            assert!((est.P[(BARO, j)] - want).abs() < 1e-15, "row {j}");
            assert_eq!(est.P[(BARO, j)], est.P[(j, BARO)]);
        }
        // Nothing else moved: the reading was not fused.
        assert_eq!(est.imu_state().p_B_in_W, Vector3::new(1.0, 2.0, -3.0));
        let (b, var) = est.baro_offset().unwrap();
        assert_eq!(b, 500.0);
        assert!((var - (p_before[(pz, pz)] + noise_var)).abs() < 1e-15);
        // A second reading 0.2 m higher: residual 0.2 m (the filter held
        // still, its IMU queue empty, so no motion predicted).
        match est.process_baro(0.0, 503.2).unwrap() {
            BaroOutcome::Fused {
                residual_m,
                sigma_m,
                nis,
            } => {
                assert!((residual_m - 0.2).abs() < 1e-9, "{residual_m}");
                // S = var(−δp_z + δb) + σ² = σ² + σ² (δb = δp_z − n₀).
                assert!((sigma_m - (2.0 * noise_var).sqrt()).abs() < 1e-9, "{sigma_m}");
                assert!((nis - 0.04 / (2.0 * noise_var)).abs() < 1e-9);
            }
            other => panic!("{other:?}"),
        }
    }

    /// A reading older or newer than the filter is predicted along the
    /// velocity without moving the filter (frames stamped before it may
    /// still come); beyond `MAX_BARO_LAG_S` behind it is refused as late,
    /// beyond it ahead the filter is moved to that far behind it; a
    /// non-finite one is refused.
    #[test]
    fn late_and_non_finite_readings() {
        let mut est = estimator();
        est.t_s = 1.0;
        assert!(matches!(est.process_baro(0.5, 3.0), Err(InputError::BaroLate { .. })));
        assert!(matches!(
            est.process_baro(1.0, f64::NAN),
            Err(InputError::NonFiniteBaro { .. })
        ));
        assert!(matches!(
            est.process_baro(f64::INFINITY, 3.0),
            Err(InputError::NonFiniteBaro { .. })
        ));
        assert!(est.baro_offset().is_none());
        // 0.1 s late at 1.2 m/s up: the vehicle was 0.12 m lower then;
        // 0.1 s early, 0.12 m higher; neither moves the filter's clock.
        est.process_baro(1.0, 10.0).unwrap();
        for (t_s, h_m) in [(0.9, 10.0 - 0.12), (1.1, 10.0 + 0.12)] {
            match est.process_baro(t_s, h_m).unwrap() {
                BaroOutcome::Fused { residual_m, .. } => assert!(residual_m.abs() < 1e-6, "{residual_m}"),
                other => panic!("{other:?}"),
            }
            assert_eq!(est.time_s(), 1.0);
        }
        // One more than 0.2 s ahead moves the filter to 0.2 s behind it.
        est.process_baro(2.0, 10.0 + 1.2).unwrap();
        assert!((est.time_s() - 1.8).abs() < 1e-12, "{}", est.time_s());
    }

    /// B3: a barometer 3 m away from the height the filter holds (set
    /// more than 10 s before) is refused four times, and the fifth time the
    /// height's variance is raised by the residual's excess and the reading
    /// fused, which takes the height most of the way to it. Disagreeing
    /// again within 10 s, it is the barometer that moved: its offset takes
    /// the excess.
    #[test]
    fn five_refusals_in_a_row_raise_the_heights_variance() {
        let mut est = estimator();
        est.process_baro(0.0, 3.0).unwrap();
        for _ in 0..20 {
            est.process_baro(0.0, 3.0).unwrap();
        }
        est.t_s = 11.0;
        let z0 = est.imu_state().p_B_in_W.z;
        for k in 0..4 {
            assert!(
                matches!(est.process_baro(11.0, 6.0).unwrap(), BaroOutcome::Refused { .. }),
                "reading {k}"
            );
        }
        assert_eq!(est.imu_state().p_B_in_W.z, z0);
        match est.process_baro(11.0, 6.0).unwrap() {
            BaroOutcome::HeightReset {
                residual_m,
                sigma_m,
                added_var_m2,
            } => {
                assert!((added_var_m2 - (residual_m * residual_m - sigma_m * sigma_m)).abs() < 1e-9);
            }
            other => panic!("{other:?}"),
        }
        let climbed_m = z0 - est.imu_state().p_B_in_W.z;
        assert!(climbed_m > 2.0 && climbed_m < 3.0, "{climbed_m}");
        assert_eq!(est.stats.rejected.get(&Counter::BaroRefused), Some(&4));
        assert_eq!(est.stats.rejected.get(&Counter::BaroHeightReset), Some(&1));
        // The count starts again: the next reading agrees.
        assert!(matches!(
            est.process_baro(11.0, 6.0).unwrap(),
            BaroOutcome::Fused { .. }
        ));
        // The second strike: 3 m more within 10 s of the height's reset.
        // The offset takes it; the height stays within a decimetre.
        let (b0, _) = est.baro_offset().unwrap();
        let z1 = est.imu_state().p_B_in_W.z;
        for _ in 0..4 {
            assert!(matches!(
                est.process_baro(11.0, 9.0).unwrap(),
                BaroOutcome::Refused { .. }
            ));
        }
        assert!(matches!(
            est.process_baro(11.0, 9.0).unwrap(),
            BaroOutcome::OffsetReset { .. }
        ));
        let (b1, _) = est.baro_offset().unwrap();
        assert!(b1 - b0 > 2.0 && b1 - b0 < 3.0, "offset moved {}", b1 - b0);
        assert!((est.imu_state().p_B_in_W.z - z1).abs() < 0.1);
        assert_eq!(est.stats.rejected.get(&Counter::BaroOffsetReset), Some(&1));
    }

    /// B3 past the suspect window: a new disagreement 11 s after a height
    /// reset is the height's again.
    #[test]
    fn a_disagreement_long_after_a_height_reset_is_the_heights_again() {
        let mut est = estimator();
        est.process_baro(0.0, 3.0).unwrap();
        est.t_s = 11.0;
        for k in 0..5 {
            let out = est.process_baro(11.0, 6.0).unwrap();
            assert_eq!(matches!(out, BaroOutcome::HeightReset { .. }), k == 4, "{out:?}");
        }
        est.t_s = 22.0;
        let z = -est.imu_state().p_B_in_W.z;
        let off = est.baro_offset().unwrap().0;
        for k in 0..5 {
            let out = est.process_baro(22.0, z + off + 3.0).unwrap();
            assert_eq!(matches!(out, BaroOutcome::HeightReset { .. }), k == 4, "{out:?}");
        }
    }

    /// A first reading 5 m off (a spike) sets the offset wrong; the
    /// readings that follow within 10 s disagree, and it is the offset, not
    /// the height, that takes it (B3).
    #[test]
    fn a_spiked_first_reading_is_the_offsets_fault() {
        let mut est = estimator();
        est.process_baro(0.0, 8.0).unwrap();
        let z0 = est.imu_state().p_B_in_W.z;
        let mut outcomes = Vec::new();
        for _ in 0..5 {
            est.t_s += 0.1;
            outcomes.push(est.process_baro(est.t_s, 3.0).unwrap());
        }
        assert!(matches!(outcomes[4], BaroOutcome::OffsetReset { .. }), "{outcomes:?}");
        assert!((est.imu_state().p_B_in_W.z - z0).abs() < 0.1);
        let (b, _) = est.baro_offset().unwrap();
        assert!((b - 0.0).abs() < 1.0, "offset {b}");
    }

    /// A reading more than 10 m from the height (a pressure far off) sets
    /// the offset afresh and moves nothing; the readings after it are
    /// fused against the new offset.
    #[test]
    fn a_reading_kilometres_off_sets_the_offset_afresh() {
        let mut est = estimator();
        est.process_baro(0.0, 3.0).unwrap();
        let z0 = est.imu_state().p_B_in_W.z;
        assert!(matches!(
            est.process_baro(0.0, 1003.0).unwrap(),
            BaroOutcome::Anchored { reanchored: true, .. }
        ));
        assert_eq!(est.imu_state().p_B_in_W.z, z0);
        assert_eq!(est.stats.rejected.get(&Counter::BaroReanchored), Some(&1));
        assert!(matches!(
            est.process_baro(0.0, 1003.0).unwrap(),
            BaroOutcome::Fused { .. }
        ));
    }

    /// The world origin placed at a fix moves every position by one
    /// unknown offset, and the barometer's offset with the height (B2):
    /// the reading's residual and its σ are unchanged by it.
    #[test]
    fn the_offset_moves_with_the_worlds_origin() {
        let mut est = estimator();
        est.process_baro(0.0, 3.0).unwrap();
        let mut before = est.clone();
        let pz = P + 2;
        let cross = est.P[(BARO, pz)];
        assert!(est.add_world_offset_variance(4.0));
        assert!((est.P[(BARO, pz)] - cross - 4.0).abs() < 1e-12);
        assert!((est.P[(BARO, BARO)] - before.P[(BARO, BARO)] - 4.0).abs() < 1e-12);
        let (a, b) = (
            est.process_baro(0.0, 3.2).unwrap(),
            before.process_baro(0.0, 3.2).unwrap(),
        );
        match (a, b) {
            (
                BaroOutcome::Fused {
                    residual_m: r1,
                    sigma_m: s1,
                    ..
                },
                BaroOutcome::Fused {
                    residual_m: r2,
                    sigma_m: s2,
                    ..
                },
            ) => {
                assert!((r1 - r2).abs() < 1e-12 && (s1 - s2).abs() < 1e-9, "{r1} {r2} {s1} {s2}");
            }
            other => panic!("{other:?}"),
        }
    }

    /// B3's height: on a filter in flight, with clones and a GNSS clone,
    /// the body's height and each clone's gain one common error, and
    /// nothing else moves (the keyframes, the offset, every other state).
    #[test]
    fn a_height_reset_raises_the_windows_heights_together() {
        let cfg = crate::config::Config::default();
        let sim = crate::eval::sim_config_for(&cfg);
        let ds = cmsckf_sitl::dataset::Dataset::generate("racetrack", 1, Some(15.0), &sim).unwrap();
        let mut r = crate::eval::Runner::new(&ds, &cfg, crate::estimator::Mode::Full, 1).with_gnss();
        let mut k = 0;
        while k < ds.frames.len() && !(ds.frames[k].t_s > 10.0 && r.est.n_gnss_clones() > 0) {
            r.step_frame(k);
            k += 1;
        }
        let est = &mut r.est;
        assert!(est.n_clones() > 3 && est.n_gnss_clones() > 0 && est.keyframes().count() > 0);
        let before = est.P.clone();
        est.add_window_height_variance(0.5);
        let co = est.clones_offset();
        let go = est.gnss_clones_offset();
        let mut heights = vec![P + 2];
        heights.extend((0..est.n_clones()).map(|i| co + 6 * i + 5));
        heights.extend((0..est.n_gnss_clones()).map(|i| go + GNSS_CLONE_DIM * i + 8));
        let n = est.P.nrows();
        for i in 0..n {
            for j in 0..n {
                let want = if heights.contains(&i) && heights.contains(&j) {
                    0.5
                } else {
                    0.0
                };
                let got = est.P[(i, j)] - before[(i, j)];
                assert!((got - want).abs() < 1e-12, "P[{i}, {j}] moved by {got}, not {want}");
            }
        }
    }

    /// B4: a fresh filter takes a carried offset once, and not after a
    /// reading set its own; a carried value that is not finite is refused.
    #[test]
    fn a_carried_offset_is_taken_once_by_a_fresh_filter() {
        let mut est = estimator();
        assert!(!est.carry_baro_offset(f64::NAN, 0.01));
        assert!(!est.carry_baro_offset(500.0, 0.0));
        assert!(est.carry_baro_offset(500.0, 0.01));
        assert_eq!(est.baro_offset(), Some((500.0, 0.01)));
        // The first reading is fused against it at once: the filter is
        // at 3 m, the barometer says 503.5 − 500 = 3.5 m.
        match est.process_baro(0.0, 503.5).unwrap() {
            BaroOutcome::Fused { residual_m, .. } => assert!((residual_m - 0.5).abs() < 1e-9),
            other => panic!("{other:?}"),
        }
        assert!(!est.carry_baro_offset(400.0, 0.01));
        let mut fresh = estimator();
        fresh.process_baro(0.0, 503.0).unwrap();
        assert!(!fresh.carry_baro_offset(400.0, 0.01));
    }
}
