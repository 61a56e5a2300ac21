//! Rebases (§5 R1–R4, R6): starting one, which demotes keyframes and
//! restarts the accumulation at once; the pure job that computes the new
//! base; and installing its result, with the accumulators' base space
//! shrunk to the global part's columns when those are fewer.
//!
//! Why it exists: the rebase is the one `O(n_L n_G²)` step of the filter;
//! split this way it can run off the real-time path (on another thread)
//! while the local filter goes on, and be installed when ready without
//! changing a number.

use std::collections::BTreeMap;
use std::sync::Arc;

use nalgebra::{DMatrix, DVector};

use super::{block_cols, c_cols, Base, Global, InstallError, PendingRebase, RebaseJob, RebaseResult};
use crate::estimator::covariance::{position_sigma_m, whitening_factor};
use crate::estimator::{math, Estimator, FilterEvent, GlobalReason};

impl RebaseJob {
    /// Global keyframes after the rebase.
    pub fn n_global(&self) -> usize {
        self.ids.len()
    }

    /// The new base's scalar column `i` (§5 R2's order: the live global
    /// keyframes' columns, then the demoted keyframes'): `Ok(old base
    /// column)` for a live one, `Err(local index at the rebase time)` for a
    /// demoted one.
    pub(super) fn new_base_source(&self, i: usize) -> Result<usize, usize> {
        let g = 6 * self.live_blocks.len();
        if i < g {
            Ok(6 * self.live_blocks[i / 6] + i % 6)
        } else {
            Err(self.demoted_idx[i - g])
        }
    }

    /// `X ← W'⁻¹ X`, the new base's whitening (R2: `C' = W'⁻¹ P_L'G'(k)`),
    /// by the blocked solve of U1 (matrix products; a column-by-column
    /// solve over n_G columns is several times slower). `W'` comes from
    /// `whitening_factor`, whose diagonal is positive; were it not finite,
    /// `X` becomes NaN, which the filter's health checks catch.
    pub(super) fn unwhiten_new(&self, x: &mut DMatrix<f64>) {
        match math::LowerSolver::new(self.w_new.clone()) {
            Some(w) => w.solve_in_place(x),
            None => x.fill(f64::NAN),
        }
    }

    /// Computes the new base (§5 R2): the old global part brought to the
    /// rebase time by G1–G3, joined by the demoted keyframes, and whitened
    /// by the new local block. `O(n_L n_G²)`, the only step that is.
    pub fn run(&self) -> RebaseResult {
        let n_live = self.live_blocks.len();
        let (g, o) = (6 * n_live, self.demoted_idx.len());
        let nk = self.keep_idx.len() + o;
        let n_new = g + o;
        let mut p0 = DMatrix::zeros(n_new, n_new);
        let (p_lg, dx_live) = match &self.parent {
            Some(base) if g > 0 => {
                let cols = block_cols(self.live_blocks.iter().copied());
                let ct = c_cols(base, &self.extra, &cols);
                // G1: P_LG(k) = Φ̃ C̃.
                let p_lg = &self.Phi * &ct;
                // G2: P_GG(k) = P_GG(0) − C̃ᵀ Ψ̃ C̃, as one in-place product.
                math::gather_block(&base.P_GG0, &cols, &mut p0);
                // C̃ᵀ Ψ̃ C̃ is symmetric: its lower triangle, mirrored.
                let psi_c = &self.Psi * &ct;
                math::add_symmetric_product(&mut p0, g, -1.0, &ct, &psi_c);
                // G3: δx_G = C̃ᵀ q̃.
                (p_lg, ct.tr_mul(&self.q))
            }
            _ => (DMatrix::zeros(nk, g), DVector::zeros(g)),
        };
        // Demoted keyframes join the global part with their covariance at k.
        if o > 0 {
            let p_og = p_lg.select_rows(&self.demoted_idx);
            p0.view_mut((g, 0), (o, g)).copy_from(&p_og);
            p0.view_mut((0, g), (g, o)).copy_from(&p_og.transpose());
            let p_oo = self.p_demoted_rows.select_columns(&self.demoted_idx);
            p0.view_mut((g, g), (o, o))
                .copy_from(&((&p_oo + p_oo.transpose()) * 0.5));
        }
        // p0 is exactly symmetric: G2's block by mirroring, the demoted
        // rows by construction.
        // R2: C' = W'⁻¹ P_L'G'(k).
        let nl = self.keep_idx.len();
        let mut p_lg_new = DMatrix::zeros(nl, n_new);
        if g > 0 {
            p_lg_new
                .view_mut((0, 0), (nl, g))
                .copy_from(&p_lg.select_rows(&self.keep_idx));
        }
        if o > 0 {
            p_lg_new
                .view_mut((0, g), (nl, o))
                .copy_from(&self.p_demoted_rows.select_columns(&self.keep_idx).transpose());
        }
        let mut c_new = p_lg_new;
        self.unwhiten_new(&mut c_new);
        // R6: with fewer global columns than local states, the base space
        // shrinks to C''s column space: C' = U R, U (n_L' × n_G') with
        // orthonormal columns; the base keeps R and the install maps the
        // accumulators by U.
        let reduce = if n_new < nl {
            let (u, r) = if n_new == 0 {
                (DMatrix::zeros(nl, 0), DMatrix::zeros(0, 0))
            } else {
                let qr = c_new.qr();
                (qr.q(), qr.r())
            };
            c_new = r;
            Some(u)
        } else {
            None
        };
        RebaseResult {
            seq: self.seq,
            base: Base {
                ids: self.ids.clone(),
                C: c_new,
                P_GG0: p0,
            },
            dx_live,
            reduce,
        }
    }
}

/// §5 R6 applied to the accumulators: with `E = [U 0; 0 I]` (`U` over the
/// first `U.nrows()` base coordinates), `Φ̃ ← Φ̃ E`, `Ψ̃ ← Eᵀ Ψ̃ E`,
/// `q̃ ← Eᵀ q̃`. Every product the filter forms, `Φ̃ C̃`, `C̃ᵀ Ψ̃ C̃`, `C̃ᵀ q̃`,
/// is unchanged since `C̃ = E C̃_R` (the new base's `C' = U R`, the
/// promotions' rows as they were), and C1–C3 commute with it.
fn reduce_base_space(g: &mut Global, u: &DMatrix<f64>) {
    let (nl, k) = u.shape();
    let ne = g.Phi.ncols() - nl;
    let n = g.Phi.nrows();
    let mut phi = DMatrix::zeros(n, k + ne);
    phi.columns_mut(0, k).copy_from(&(g.Phi.columns(0, nl) * u));
    phi.columns_mut(k, ne).copy_from(&g.Phi.columns(nl, ne));
    let mut psi = DMatrix::zeros(k + ne, k + ne);
    let psi_11 = u.tr_mul(&(g.Psi.view((0, 0), (nl, nl)) * u));
    // Exactly symmetric, as the accumulation keeps Ψ̃.
    psi.view_mut((0, 0), (k, k))
        .copy_from(&((&psi_11 + psi_11.transpose()) * 0.5));
    if ne > 0 {
        let psi_12 = u.tr_mul(&g.Psi.view((0, nl), (nl, ne)));
        psi.view_mut((0, k), (k, ne)).copy_from(&psi_12);
        psi.view_mut((k, 0), (ne, k)).copy_from(&psi_12.transpose());
        psi.view_mut((k, k), (ne, ne))
            .copy_from(&g.Psi.view((nl, nl), (ne, ne)));
    }
    let mut q = DVector::zeros(k + ne);
    q.rows_mut(0, k).copy_from(&u.tr_mul(&g.q.rows(0, nl)));
    q.rows_mut(k, ne).copy_from(&g.q.rows(nl, ne));
    g.Phi = phi;
    g.Psi = psi;
    g.q = q;
}

impl Estimator {
    /// Whether a rebase job is computing the global part.
    pub fn rebase_pending(&self) -> bool {
        self.pending.is_some()
    }

    /// The pending rebase job, once, for running elsewhere (asynchronous
    /// rebases only); install its result with [`Estimator::install_rebase`].
    pub fn take_rebase_job(&mut self) -> Option<Arc<RebaseJob>> {
        match self.pending.take()? {
            PendingRebase::Held(job) => {
                let job: Arc<RebaseJob> = Arc::from(job);
                self.pending = Some(PendingRebase::Dispatched(job.clone()));
                Some(job)
            }
            other => {
                self.pending = Some(other);
                None
            }
        }
    }

    /// Installs a rebase result (§5 R3): the global corrections, and the new
    /// base. `O(n_G)` plus moving the matrices in, and when the base space
    /// shrinks (§5 R6) mapping the accumulators by `U`,
    /// `O(n_L n_L' n_G' + n_L'² n_G')`: local sizes, a few updates' worth.
    /// Returns the job, whose inputs (the old base) the caller may free off
    /// the real-time path.
    pub fn install_rebase(&mut self, res: RebaseResult) -> Result<Option<Arc<RebaseJob>>, InstallError> {
        let want = self.pending.as_ref().map(|p| p.seq());
        if want != Some(res.seq) {
            return Err(InstallError::Stale { got: res.seq, want });
        }
        let job = match self.pending.take() {
            Some(PendingRebase::Dispatched(j)) => Some(j),
            _ => None,
        };
        let Some(g) = self.global.as_ref() else {
            return Ok(job);
        };
        // δx_G for the keyframes still global (promoted ones took theirs).
        let still_global: Vec<(usize, u64)> = (res.base.ids.iter().enumerate())
            .take(res.dx_live.len() / 6)
            .filter(|(_, id)| g.live.contains_key(id))
            .map(|(j, id)| (j, *id))
            .collect();
        for (j, id) in still_global {
            self.correct_keyframe(id, &res.dx_live, 6 * j);
        }
        let Some(g) = self.global.as_mut() else {
            return Ok(job);
        };
        g.sigma_m = (g.live.iter())
            .map(|(id, b)| (*id, position_sigma_m(&res.base.P_GG0, 6 * b)))
            .collect();
        // R6: Φ̃ ← Φ̃ [U 0; 0 I], Ψ̃ ← [U 0; 0 I]ᵀ Ψ̃ [U 0; 0 I], q̃ likewise:
        // the first n_L' base coordinates are the new base's (whitened by
        // W'), any after them those of promotions made while it was
        // computed (§5 R5), which keep their rows of C̃.
        if let Some(u) = &res.reduce {
            reduce_base_space(g, u);
            self.stats.base_space_reductions += 1;
            self.stats.base_space_dims_removed += (u.nrows() - u.ncols()) as u64;
        }
        g.base = Some(Arc::new(res.base));
        self.stats.rebases_installed += 1;
        Ok(job)
    }

    /// Runs and installs a pending rebase here and now.
    pub(in crate::estimator) fn finish_rebase_inline(&mut self) {
        if let Some(p) = &self.pending {
            let res = (self.rebase_runner)(p.job());
            // The result is this job's: installing it cannot be stale.
            let _ = self.install_rebase(res);
        }
    }

    /// Starts a rebase (§5 R1) around the current centre: local keyframes
    /// farther than `local_radius_m` are demoted to the global part, then
    /// the least recently used until half of `max_local_keyframes` remain
    /// (so the next count-triggered rebase is that many keyframes away); the
    /// accumulation restarts (`Φ̃ = W'`, `Ψ̃ = 0`, `q̃ = 0`). The local part
    /// goes on at once; the new base is computed by the job, here
    /// (synchronous filters) or elsewhere. `None` if a rebase is already
    /// pending or there is nothing to do.
    pub(in crate::estimator) fn begin_rebase(&mut self, reason: GlobalReason) -> Option<FilterEvent> {
        if self.pending.is_some() {
            return None;
        }
        self.sync();
        let demote = self.rebase_demotions();
        if self.global.is_none() && demote.is_empty() {
            return None;
        }
        let global_before: Vec<u64> = self
            .global
            .as_ref()
            .map(|g| g.live.keys().copied().collect())
            .unwrap_or_default();
        self.stats.global_updates += 1;
        self.start_rebase_job(&demote);
        if !self.s.async_rebase {
            self.finish_rebase_inline();
        }
        Some(FilterEvent::GlobalUpdate {
            reason,
            global_before,
            local_after: self.local_kfs.clone(),
        })
    }

    /// The local keyframes a rebase demotes (§5 R1), `(local index, id)` in
    /// local order: those outside the region, and more of the least recently
    /// used until at most half of `max_local_keyframes` remain.
    fn rebase_demotions(&self) -> Vec<(usize, u64)> {
        // (local index, id, last used, outside the region)
        let mut cand: Vec<(usize, u64, f64, bool)> = self
            .local_kfs
            .iter()
            .enumerate()
            .filter_map(|(j, id)| {
                let kf = self.keyframes.get(id)?;
                let out = (kf.p_B_in_W - self.centre_W).norm() > self.s.local_radius_m;
                Some((j, *id, kf.last_used_s, out))
            })
            .collect();
        // Outside the region first, then the least recently used.
        cand.sort_by(|a, b| b.3.cmp(&a.3).then(a.2.total_cmp(&b.2)));
        let keep_at_most = self.s.max_local_keyframes / 2;
        let n_out = cand.iter().filter(|c| c.3).count();
        let n_demote = n_out.max(cand.len().saturating_sub(keep_at_most));
        let mut demote: Vec<(usize, u64)> = cand.iter().take(n_demote).map(|c| (c.0, c.1)).collect();
        demote.sort_unstable();
        demote
    }

    /// R1 for the chosen demotions: the job gets everything the new base
    /// needs, the local part keeps the other states, and the accumulation
    /// restarts (`Φ̃ = W'`, `Ψ̃ = 0`, `q̃ = 0`) over the base still to come.
    fn start_rebase_job(&mut self, demote: &[(usize, u64)]) {
        let n = self.P.nrows();
        let demoted_idx: Vec<usize> = demote
            .iter()
            .flat_map(|(j, _)| self.kf_offset(*j)..self.kf_offset(*j) + 6)
            .collect();
        let keep_idx: Vec<usize> = (0..n).filter(|i| !demoted_idx.contains(i)).collect();
        let p_demoted_rows = self.P.select_rows(&demoted_idx);
        let new_p = self.P.select_rows(&keep_idx).select_columns(&keep_idx);
        let w_new = whitening_factor(&new_p);
        let old = self.global.take();
        let (parent, live, extra, phi, psi, q, mut sigma_m) = match old {
            Some(g) => {
                let live = g.live_in_block_order();
                (g.base, live, g.extra, g.Phi, g.Psi, g.q, g.sigma_m)
            }
            None => (
                None,
                Vec::new(),
                Vec::new(),
                DMatrix::zeros(n, 0),
                DMatrix::zeros(0, 0),
                DVector::zeros(0),
                BTreeMap::new(),
            ),
        };
        let mut ids: Vec<u64> = live.iter().map(|x| x.0).collect();
        for (j, id) in demote {
            sigma_m.insert(*id, position_sigma_m(&self.P, self.kf_offset(*j)));
            ids.push(*id);
        }
        self.rebase_seq += 1;
        let job = RebaseJob {
            seq: self.rebase_seq,
            parent,
            live_blocks: live.iter().map(|x| x.1).collect(),
            extra,
            Phi: phi,
            Psi: psi,
            q,
            p_demoted_rows,
            demoted_idx,
            keep_idx,
            w_new: w_new.clone(),
            ids: ids.clone(),
        };
        let l = new_p.nrows();
        self.P = new_p;
        self.local_kfs.retain(|id| !demote.iter().any(|d| d.1 == *id));
        self.global = Some(Global {
            base: None,
            live: ids.iter().enumerate().map(|(b, id)| (*id, b)).collect(),
            extra: Vec::new(),
            Phi: w_new,
            Psi: DMatrix::zeros(l, l),
            q: DVector::zeros(l),
            sigma_m,
        });
        self.pending = Some(PendingRebase::Held(Box::new(job)));
    }
}
