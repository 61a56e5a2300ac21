//! The one place that changes the covariance: the state layout, IMU
//! propagation of the active block, cloning and marginalising pose blocks,
//! the EKF update in each mode's form, injecting a correction into the
//! nominal state, and re-initialising states (OpenVINS keeps the same
//! discipline in its `StateHelper`). Updaters build `H`, `r` and call
//! [`Estimator::ekf_update`]; nothing else writes `P` except the compressed
//! machinery of `compressed/`, which owns the global part.

use crate::counters::Counter;
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

use super::math::{self, exp_so3};
use super::propagate;
use super::{Estimator, MatActive, Mode, ACTIVE_DIM, BARO, CLK_B, CLOCK_DIM, GNSS_CLONE_DIM, IMU_DIM, POSE_IDX, TD};

impl Estimator {
    /// Propagates the active block with the transition `f` and noise `q` of
    /// one IMU interval (§2, eq. F2): `P_AA ← F P_AA Fᵀ + Q`, symmetrised;
    /// the cross-covariances wait in `f_acc` for [`Self::sync`]. `P_AA` is
    /// symmetric, so `F P_AA Fᵀ = F (F P_AA)ᵀ`: two of `F`'s structured
    /// left products and a transpose.
    pub(super) fn propagate_covariance(&mut self, f: &propagate::ActiveTransition, q: &MatActive) {
        let paa: MatActive = self.P.fixed_view::<ACTIVE_DIM, ACTIVE_DIM>(0, 0).into_owned();
        let fp = f.mul_left(&paa);
        let fpf = f.mul_left(&fp.transpose());
        // `Q` added and the sum symmetrised as it is written back, without
        // the three more temporaries of the block's size the sum and its
        // transpose took (issue 43's profile: copies were a third of this step).
        let n = self.P.nrows();
        let out = self.P.as_mut_slice();
        for j in 0..ACTIVE_DIM {
            for i in 0..ACTIVE_DIM {
                out[j * n + i] = 0.5 * ((fpf[(i, j)] + fpf[(j, i)]) + (q[(i, j)] + q[(j, i)]));
            }
        }
        self.f_acc = f.mul_left(&self.f_acc);
    }

    /// Applies the accumulated IMU transition to the cross-covariances and
    /// to `Φ` (§2, eq. F4): `P_IX ← F P_IX`, `Φ_I ← F Φ_I`.
    pub fn sync(&mut self) {
        if self.f_acc == MatActive::identity() {
            return;
        }
        let n = self.P.nrows();
        if n > ACTIVE_DIM {
            let cross = self.f_acc * self.P.view((0, ACTIVE_DIM), (ACTIVE_DIM, n - ACTIVE_DIM));
            self.P
                .view_mut((0, ACTIVE_DIM), (ACTIVE_DIM, n - ACTIVE_DIM))
                .copy_from(&cross);
            self.P
                .view_mut((ACTIVE_DIM, 0), (n - ACTIVE_DIM, ACTIVE_DIM))
                .copy_from(&cross.transpose());
        }
        if let Some(g) = self.global.as_mut() {
            let c = g.Phi.ncols();
            let top = self.f_acc * g.Phi.view((0, 0), (ACTIVE_DIM, c));
            g.Phi.view_mut((0, 0), (ACTIVE_DIM, c)).copy_from(&top);
        }
        self.f_acc = MatActive::identity();
    }

    /// Offset of the `local_index`-th local keyframe in `P`.
    pub fn kf_offset(&self, local_index: usize) -> usize {
        ACTIVE_DIM + 6 * local_index
    }

    /// Offset of the first camera clone: after the local keyframes.
    pub fn clones_offset(&self) -> usize {
        ACTIVE_DIM + 6 * self.local_kfs.len()
    }

    /// Where clone `seq` is in the window, if it still is.
    fn clone_index(&self, seq: u64) -> Option<usize> {
        let first = self.clones.front()?.seq;
        let i = usize::try_from(seq.checked_sub(first)?).ok()?;
        (i < self.clones.len()).then_some(i)
    }

    pub(super) fn clone_offset_by_seq(&self, seq: u64) -> Option<usize> {
        self.clone_index(seq).map(|i| self.clones_offset() + 6 * i)
    }

    /// Clone `seq`, if it is still in the window.
    pub(super) fn clone_by_seq(&self, seq: u64) -> Option<&super::CloneState> {
        self.clone_index(seq).map(|i| &self.clones[i])
    }

    /// Offset of the first GNSS clone: after the camera clones.
    pub fn gnss_clones_offset(&self) -> usize {
        self.clones_offset() + 6 * self.clones.len()
    }

    /// Inserts new error states `J δx` at `at` (§2, eq. A1): `J` selects the
    /// states `rows` and, with `td_rate = Some(c)`, adds `c δt_d` (the pose
    /// of a camera view at `t_cam + t_d` moves with the time offset, §3b,
    /// eq. T3): `J P = P[rows, :] + c P[TD, :]`,
    /// `P' = [P, PJᵀ; JP, JPJᵀ]` (rows and columns placed at `at`), and
    /// `Φ' = [Φ; JΦ]` in compressed mode.
    pub(super) fn augment(&mut self, at: usize, rows: &[usize], td_rate: Option<&[f64; 6]>) {
        let k = rows.len();
        // P J ᵀ: column j is P[:, rows_j] (+ c_j P[:, TD]); P is symmetric.
        let mut cross = self.P.select_columns(rows);
        if let Some(c) = td_rate {
            let p_td = self.P.column(TD).into_owned();
            for (j, cj) in c.iter().enumerate().take(k) {
                cross.column_mut(j).axpy(*cj, &p_td, 1.0);
            }
        }
        // J P Jᵀ = J (P Jᵀ): row i of J applied to each column of P Jᵀ,
        // symmetrised (the two orders of the sums differ by round-off).
        let mut block = cross.select_rows(rows);
        if let Some(c) = td_rate {
            for i in 0..k {
                for j in 0..k {
                    block[(i, j)] += c[i] * cross[(TD, j)];
                }
            }
            block = (&block + block.transpose()) * 0.5;
        }
        self.insert_local(at, &cross, &block);
        if let Some(g) = self.global.as_mut() {
            let mut jphi = g.Phi.select_rows(rows);
            if let Some(c) = td_rate {
                let phi_td = g.Phi.row(TD).into_owned();
                for (i, ci) in c.iter().enumerate().take(k) {
                    let mut row = jphi.row_mut(i);
                    row += &phi_td * *ci;
                }
            }
            let phi = std::mem::replace(&mut g.Phi, DMatrix::zeros(0, 0)).insert_rows(at, k, 0.0);
            g.Phi = phi;
            g.Phi.view_mut((at, 0), (k, jphi.ncols())).copy_from(&jphi);
        }
    }

    /// The measured body rate about `t_s` (rad/s, the bias not removed),
    /// smoothed by a triangular window of half-width
    /// [`super::RATE_SMOOTHING_HALF_WIDTH_S`] over the gyro samples kept
    /// (those after `t_s` too, queued as the frame came late), its weights
    /// renormalised where samples are missing (eq. T3b); `None` without any
    /// sample in the window.
    pub(super) fn smoothed_rate_radps(&self, t_s: f64) -> Option<Vector3<f64>> {
        let w_half = super::RATE_SMOOTHING_HALF_WIDTH_S;
        let (mut sum, mut weight) = (Vector3::zeros(), 0.0);
        for (t, w) in &self.rate_history {
            let a = 1.0 - (t - t_s).abs() / w_half;
            if a > 0.0 {
                sum += w * a;
                weight += a;
            }
        }
        (weight > 0.0).then(|| sum / weight)
    }

    /// The body rate (rad/s, its bias removed) of the time offset's column
    /// (§3b, T3): smoothed about the frame's instant, as a single sample,
    /// and even the frame interval's mean, carries the motors' vibration
    /// (on an armed IMU the last sample's rate biased t_d by 1.2 ms, 10
    /// sigma, on handheld motion; in calm air the interval's mean left it
    /// 10.8 ms off at 0.8 ms sigma); the last sample's before the first
    /// frame.
    pub fn time_offset_body_rate(&self) -> Vector3<f64> {
        self.frame_rate_B
            .or_else(|| self.last_meas.map(|m| m.gyro_radps - self.imu.b_g))
            .unwrap_or_else(Vector3::zeros)
    }

    /// A camera view's pose enters the state at `at` (a clone or a
    /// keyframe): the body pose at the frame's time `t_cam + t̂_d`, with the
    /// time offset's column `c = [R_W_B ω_B; v_B_in_W]` (§3b, eq. T3).
    /// With `vibration_jitter` on, the view's attitude block then gains the
    /// vibration's jitter (§3f, eq. V2): `P_θθ ← P_θθ + R_W_B J_B R_W_Bᵀ`,
    /// `J_B` measured from the gyro (eq. V1), a noise of this view alone.
    pub fn augment_view(&mut self, at: usize) {
        let w_B = self.time_offset_body_rate();
        let w_W = self.imu.q_W_B * w_B;
        let v = self.imu.v_B_in_W;
        let c = [w_W.x, w_W.y, w_W.z, v.x, v.y, v.z];
        self.augment(at, &POSE_IDX, Some(&c));
        if self.s.vibration_jitter {
            // 0 logged while there is no figure (too few samples since a
            // start or a gap), never the last one's.
            self.stats.vibration_jitter_rad = 0.0;
            if let Some(j_B) = super::vibration::jitter_var_rad2(&self.rate_history) {
                let r = self.imu.q_W_B.to_rotation_matrix().into_inner();
                // R J Rᵀ rounds its (i, j) and (j, i) products apart: made
                // exactly symmetric, as the rest of P is kept.
                let j_W = r * Matrix3::from_diagonal(&j_B) * r.transpose();
                let j_W = (j_W + j_W.transpose()) * 0.5;
                let mut blk = self.P.view_mut((at, at), (3, 3));
                blk += j_W;
                self.stats.vibration_jitter_rad = (j_B.sum() / 3.0).sqrt();
            }
        }
    }

    /// Where each position block `δp` starts in `P`: the body's, the local
    /// keyframes' (with `keyframes`), the clones' and the GNSS clones'
    /// (`[δθ, δv, δp, …]`).
    pub(super) fn position_starts(&self, keyframes: bool) -> Vec<usize> {
        let mut starts: Vec<usize> = vec![POSE_IDX[3]];
        if keyframes {
            starts.extend((0..self.local_kfs.len()).map(|j| self.kf_offset(j) + 3));
        }
        let co = self.clones_offset();
        starts.extend((0..self.clones.len()).map(|i| co + 6 * i + 3));
        let go = self.gnss_clones_offset();
        starts.extend((0..self.gnss_clones.len()).map(|i| go + GNSS_CLONE_DIM * i + 6));
        starts
    }

    /// One error of variance `var_m2` common to the states `idx`:
    /// `P += var · u uᵀ`, `u` one at each of them (process noise, so the
    /// local part only).
    pub(super) fn add_common_error(&mut self, idx: &[usize], var_m2: f64) {
        for &a in idx {
            for &b in idx {
                self.P[(a, b)] += var_m2;
            }
        }
    }

    /// The world frame's origin became uncertain by `var_m2` per axis (it
    /// was placed at a single-point fix, §7 eq. I2): every position in the
    /// state, the body's, the clones', the keyframes' and the GNSS clones',
    /// shares that one offset, so each pair of same-axis position entries
    /// gains `var_m2`: `P ← P + σ² Σ_a e_a e_aᵀ` with `e_a` the indicator of
    /// axis `a`'s positions. The barometer's offset, once set, shares the
    /// vertical one (`b_h = h_m + p_z`: its error is `δp_z` plus the
    /// reading's, §3g B2), so it joins the down axis's indicator. Refused
    /// (`false`) once keyframes are in a compressed global part, whose
    /// frozen covariance it cannot reach.
    pub fn add_world_offset_variance(&mut self, var_m2: f64) -> bool {
        if !(var_m2.is_finite() && var_m2 >= 0.0) || self.global.as_ref().is_some_and(|g| !g.live.is_empty()) {
            return false;
        }
        self.sync();
        let starts = self.position_starts(true);
        for a in 0..3 {
            let mut idx: Vec<usize> = starts.iter().map(|&i| i + a).collect();
            if a == 2 && self.baro.anchored {
                idx.push(BARO);
            }
            self.add_common_error(&idx, var_m2);
        }
        true
    }

    /// Marginalises `width` error states at `at` (§2, eq. A2).
    pub(super) fn remove_block(&mut self, at: usize, width: usize) {
        let p = std::mem::replace(&mut self.P, DMatrix::zeros(0, 0));
        self.P = p.remove_rows(at, width).remove_columns(at, width);
        if let Some(g) = self.global.as_mut() {
            let phi = std::mem::replace(&mut g.Phi, DMatrix::zeros(0, 0));
            g.Phi = phi.remove_rows(at, width);
        }
    }

    /// One EKF update with unit measurement noise, in the mode's form (§3
    /// eq. U1; Schmidt §6; compressed §5 eqs. C1–C3).
    /// `h` holds the columns `cols` of the full Jacobian; the rest are zero.
    /// `upper`: `h` is the square upper-triangular `T` of Q1, whose zero
    /// lower triangle the products skip.
    pub fn ekf_update(&mut self, h: &DMatrix<f64>, cols: &[usize], r: &DVector<f64>, upper: bool) {
        let (m, n) = (r.len(), self.P.nrows());
        let h_times = |rows: DMatrix<f64>| if upper { math::upper_mul(h, &rows) } else { h * rows };
        // H P = h P[cols, :] (P symmetric), and S = H P Hᵀ + I.
        let hp = h_times(self.P.select_rows(cols));
        // S's lower triangle is all its factor reads: with T upper
        // triangular (Q1) it takes a third of the product.
        let hp_cc = hp.select_columns(cols);
        let mut s = if upper {
            math::lower_of_times_upper_t(&hp_cc, &h.transpose())
        } else {
            hp_cc * h.transpose()
        };
        for i in 0..m {
            s[(i, i)] += 1.0;
        }
        let Some(solver) = math::LowerSolver::cholesky(s) else {
            *self.stats.rejected.entry(Counter::UpdateNotPd).or_default() += 1;
            return;
        };
        // S = L Lᵀ. One blocked solve of L X = [H P | H Φ̃ | r] gives
        // A = L⁻¹ (H P), B = L⁻¹ (H Φ̃) and w = L⁻¹ r; then
        // δx = K r = (H P)ᵀ S⁻¹ r = Aᵀ w.
        let n0 = self.global.as_ref().map_or(0, |g| g.Phi.ncols());
        let mut x = DMatrix::zeros(m, n + n0 + 1);
        x.columns_mut(0, n).copy_from(&hp);
        if let Some(g) = self.global.as_ref() {
            x.columns_mut(n, n0).copy_from(&h_times(g.Phi.select_rows(cols)));
        }
        x.column_mut(n + n0).copy_from(r);
        drop(hp);
        solver.solve_in_place(&mut x);
        // Xᵀ, once: its rows are Aᵀ, Bᵀ and wᵀ, the left factors of every
        // product below, which read views of X and Xᵀ without copying.
        let xt = x.transpose();
        let (at, a) = (xt.rows(0, n), x.columns(0, n));
        let w = x.column(n + n0);
        let mut dx = at * w;
        // K S Kᵀ = (H P)ᵀ S⁻¹ (H P) = Aᵀ A (symmetric rank-m form).
        if self.s.mode == Mode::Schmidt {
            // Keyframes are nuisance states (S = [k0, k1)), everything else
            // is updated (A: the active block before them, the clones and
            // any pose blocks after them). With A = [A_A | A_S] by columns:
            // K_S = 0, so δx_S = 0 and P_SS unchanged;
            // P_AA ← P_AA − K_A S K_Aᵀ = P_AA − A_Aᵀ A_A;
            // P_AS ← P_AS − K_A (H P)_S = P_AS − A_Aᵀ A_S, P_SA its transpose
            // (§6). The keyframes are touched only through their
            // cross-covariances: O(m·n_A·n), no n × n temporary.
            let (k0, k1) = (ACTIVE_DIM, self.clones_offset());
            dx.rows_mut(k0, k1 - k0).fill(0.0);
            // Tests can swap in the former formula (Aᵀ A formed n × n, its
            // SS block zeroed) to compare whole flights.
            let downdate = self.schmidt_downdate;
            downdate(&mut self.P, -1.0, at, a, k0, k1);
            self.inject(&dx);
            return;
        }
        if let Some(g) = self.global.as_mut() {
            // C2, C3: Ψ̃ += (HΦ̃)ᵀ S⁻¹ (HΦ̃) = Bᵀ B, q̃ += (HΦ̃)ᵀ S⁻¹ r = Bᵀ w,
            // Φ̃ ← Φ̃ − K (HΦ̃) = Φ̃ − Aᵀ B.
            let (bt, b) = (xt.rows(n, n0), x.columns(n, n0));
            math::add_symmetric_product_t(&mut g.Psi, n0, 1.0, bt, b);
            g.q.gemv(1.0, &bt, &w, 1.0);
            g.Phi.gemm(-1.0, &at, &b, 1.0);
        }
        // P ← P − Aᵀ A, exactly symmetric.
        math::add_symmetric_product_t(&mut self.P, n, -1.0, at, a);
        self.inject(&dx);
    }

    /// Adds `δx[o..o+6] = [δθ, δp]` to a keyframe's nominal pose, if it
    /// still exists (global corrections G3 and P1).
    pub(super) fn correct_keyframe(&mut self, id: u64, dx: &DVector<f64>, o: usize) {
        if let Some(kf) = self.keyframes.get_mut(&id) {
            kf.delta += dx.fixed_rows::<3>(o);
            kf.p_B_in_W += dx.fixed_rows::<3>(o + 3);
        }
    }

    /// The body position's first estimate (§3d, F5/C5): its value before
    /// the updates not yet stepped past, the one the propagated null space
    /// holds; what a new clone or keyframe takes as its own.
    pub(super) fn p_first_estimate(&self) -> Vector3<f64> {
        self.imu.p_B_in_W - self.fej_dp
    }

    /// Applies a correction to the local nominal state.
    pub(super) fn inject(&mut self, dx: &DVector<f64>) {
        self.imu = propagate::boxplus(&self.imu, &dx.as_slice()[..IMU_DIM]);
        self.fej_dv += dx.fixed_rows::<3>(propagate::V);
        self.fej_dp += dx.fixed_rows::<3>(propagate::P);
        self.clock += dx.fixed_rows::<CLOCK_DIM>(CLK_B);
        self.t_d_s += dx[TD];
        self.baro.value_m += dx[BARO];
        for (j, id) in self.local_kfs.clone().iter().enumerate() {
            let o = self.kf_offset(j);
            let kf = self.keyframes.get_mut(id).expect("local keyframe exists");
            kf.delta += dx.fixed_rows::<3>(o);
            kf.p_B_in_W += dx.fixed_rows::<3>(o + 3);
        }
        let co = self.clones_offset();
        for (i, c) in self.clones.iter_mut().enumerate() {
            let o = co + 6 * i;
            c.q_W_B = exp_so3(&dx.fixed_rows::<3>(o).into_owned()) * c.q_W_B;
            c.p_B_in_W += dx.fixed_rows::<3>(o + 3);
        }
        let go = self.gnss_clones_offset();
        for (i, g) in self.gnss_clones.iter_mut().enumerate() {
            g.nom
                .correct(&dx.as_slice()[go + GNSS_CLONE_DIM * i..go + GNSS_CLONE_DIM * (i + 1)]);
        }
        self.inject_range_bias(dx);
    }

    /// Resets the clock states `ks` to `values`, uncorrelated with the rest,
    /// with the variances `var` (§8, eq. K4). A GNSS clone's copy of a reset
    /// state becomes the same value, fully correlated with the live one (the
    /// clock moves by its drift and noise in the clone's fraction of a
    /// second, far below the reset's variance).
    pub(super) fn reset_clock_states(&mut self, ks: &[usize], values: &[f64], var: &[f64]) {
        let go = self.gnss_clones_offset();
        for ((&k, &x), &v) in ks.iter().zip(values).zip(var) {
            // Every copy of the state: live, and one in each GNSS clone.
            let mut copies = vec![k];
            for (i, c) in self.gnss_clones.iter_mut().enumerate() {
                c.nom.clock[k - CLK_B] = x;
                copies.push(go + GNSS_CLONE_DIM * i + 12 + (k - CLK_B));
            }
            self.clock[k - CLK_B] = x;
            for &a in &copies {
                self.P.row_mut(a).fill(0.0);
                self.P.column_mut(a).fill(0.0);
                if let Some(g) = self.global.as_mut() {
                    g.Phi.row_mut(a).fill(0.0);
                }
            }
            // One value known to `v` held by all its copies: `P = v u uᵀ` on
            // them, `u` one at each. With the clone-to-clone terms left at 0
            // (as before) two clones made P indefinite, and fusing through
            // both drove the state's variance to −v (a reset each time a
            // 10 Hz receiver switched to differential codes).
            for &a in &copies {
                for &b in &copies {
                    self.P[(a, b)] = v;
                }
            }
        }
    }
}

impl Estimator {
    /// Moves the clock bias by `delta_m`, live and in every GNSS clone, and
    /// adds a common error of variance `var_m2` to all of them (§8c, eq. DG4): `P
    /// += var · u uᵀ`, `u` one at each copy of the bias. Like process noise,
    /// it touches the local part only.
    pub(super) fn shift_clock_bias(&mut self, delta_m: f64, var_m2: f64) {
        self.shift_clock_state(CLK_B, delta_m);
        self.add_clock_state_variance(CLK_B, var_m2);
    }

    /// Moves clock state `k` by `delta_m`, live and in every GNSS clone.
    pub(super) fn shift_clock_state(&mut self, k: usize, delta_m: f64) {
        self.clock[k - CLK_B] += delta_m;
        for c in self.gnss_clones.iter_mut() {
            c.nom.clock[k - CLK_B] += delta_m;
        }
    }

    /// Adds a common error of variance `var_m2` to clock state `k`, live
    /// and in every GNSS clone alike: `P += var · u uᵀ`, `u` one at each
    /// copy of the state (process noise: the local part only).
    pub(super) fn add_clock_state_variance(&mut self, k: usize, var_m2: f64) {
        let go = self.gnss_clones_offset();
        let mut idx = vec![k];
        for i in 0..self.gnss_clones.len() {
            idx.push(go + GNSS_CLONE_DIM * i + 12 + (k - CLK_B));
        }
        self.add_common_error(&idx, var_m2);
    }
}

/// Position σ (m, `√trace`) of the pose block `[δθ, δp]` starting at `o`.
pub(super) fn position_sigma_m(p: &DMatrix<f64>, o: usize) -> f64 {
    let o = o + 3;
    (p[(o, o)] + p[(o + 1, o + 1)] + p[(o + 2, o + 2)]).max(0.0).sqrt()
}

/// A lower-triangular `L` with `L Lᵀ ≈ P` and a positive diagonal: the
/// Cholesky factor of `P + λ diag(P)` for the smallest `λ ∈ {0, 1e-12, …}`
/// that works, else `diag(√P_ii)`.
pub(super) fn whitening_factor(p: &DMatrix<f64>) -> DMatrix<f64> {
    let d = DMatrix::from_diagonal(&p.diagonal().map(|v| v.abs().max(1e-300)));
    let mut lambda = 0.0;
    for _ in 0..8 {
        if let Some(ch) = (p + &d * lambda).cholesky() {
            let l = ch.l();
            if l.diagonal().iter().all(|v| *v > 0.0 && v.is_finite()) {
                return l;
            }
        }
        lambda = if lambda == 0.0 { 1e-12 } else { lambda * 100.0 };
    }
    d.map(f64::sqrt)
}
