//! Promotions (§5 P1–P3): global keyframes brought back into the local
//! part exactly, from the installed base or, while a rebase is out (R5),
//! from that rebase's inputs.
//!
//! Why it exists: a loop closure needs the covariance of a few global
//! keyframes; a promotion gives it at a cost independent of the global
//! size, where a rebase would cost the square of the map.

use nalgebra::{DMatrix, DVector};

use super::{block_cols, c_cols, Extra, Global, PendingRebase, RebaseJob};
use crate::estimator::{math, Estimator};

impl RebaseJob {
    /// Entries `rows × cols` (scalar columns) of the new base's
    /// `P_G'G'(k)` (§5 R5), from the job's inputs without computing the
    /// base: G2 for those entries only (`P_GG(0) − C̃ᵀ Ψ̃ C̃` between live
    /// keyframes, `(Φ̃ C̃)` rows of the demoted keyframes against live ones,
    /// their own rows of `P(k)` between demoted ones, symmetrised as R2 does).
    /// `O(n_L0 (|rows| + |cols|)(n_L0 + |cols|))`, independent of `n_G`.
    pub(in crate::estimator) fn new_base_block(&self, rows: &[usize], cols: &[usize]) -> DMatrix<f64> {
        // Live keyframes exist only with a parent base (else their entries
        // would silently read as zeros).
        debug_assert!(self.parent.is_some() || self.live_blocks.is_empty());
        // (position in `idx`, old base column or local index), live then demoted.
        type Entries = Vec<(usize, usize)>;
        let split = |idx: &[usize]| -> (Entries, Entries) {
            let (mut live, mut dem) = (Vec::new(), Vec::new());
            for (k, &i) in idx.iter().enumerate() {
                match self.new_base_source(i) {
                    Ok(c) => live.push((k, c)),
                    Err(l) => dem.push((k, l)),
                }
            }
            (live, dem)
        };
        let (r_live, r_dem) = split(rows);
        let (c_live, c_dem) = split(cols);
        let mut out = DMatrix::zeros(rows.len(), cols.len());
        // C̃ columns of the live entries (none without a parent base).
        let ct = |live: &[(usize, usize)]| {
            let old: Vec<usize> = live.iter().map(|x| x.1).collect();
            self.parent.as_ref().map(|b| c_cols(b, &self.extra, &old))
        };
        // A promotion's own block asks for rows == cols: one set of columns.
        let ct_r = ct(&r_live);
        let ct_c_own = if rows == cols { None } else { ct(&c_live) };
        let ct_c = if rows == cols { &ct_r } else { &ct_c_own };
        if let (Some(base), Some(ct_r), Some(ct_c)) = (self.parent.as_ref(), &ct_r, ct_c) {
            // Live × live: P_GG(0) − C̃ᵀ Ψ̃ C̃.
            let red = ct_r.tr_mul(&(&self.Psi * ct_c));
            for (j, &(oc, c0)) in c_live.iter().enumerate() {
                for (i, &(or, r0)) in r_live.iter().enumerate() {
                    out[(or, oc)] = base.P_GG0[(r0, c0)] - red[(i, j)];
                }
            }
        }
        // Demoted × live, and live × demoted by symmetry:
        // P(k)[demoted, G] = (Φ̃ C̃)[demoted rows].
        let mut cross = |dem: &Entries, live: &Entries, ct: &Option<DMatrix<f64>>, swap: bool| {
            let Some(ct) = ct.as_ref().filter(|_| !dem.is_empty()) else {
                return;
            };
            let l: Vec<usize> = dem.iter().map(|x| x.1).collect();
            let v = self.Phi.select_rows(&l) * ct;
            for (j, &(pl, _)) in live.iter().enumerate() {
                for (i, &(pd, _)) in dem.iter().enumerate() {
                    out[if swap { (pl, pd) } else { (pd, pl) }] = v[(i, j)];
                }
            }
        };
        cross(&r_dem, &c_live, ct_c, false);
        cross(&c_dem, &r_live, &ct_r, true);
        // Demoted × demoted: their rows of P(k), symmetrised.
        let g = 6 * self.live_blocks.len();
        for &(oc, lc) in &c_dem {
            for &(or, lr) in &r_dem {
                let (dr, dc) = (rows[or] - g, cols[oc] - g);
                out[(or, oc)] = 0.5 * (self.p_demoted_rows[(dr, lc)] + self.p_demoted_rows[(dc, lr)]);
            }
        }
        out
    }

    /// What a promotion while the job is out (§5 R5) needs of the new
    /// base's blocks `blocks`, without computing the base:
    /// `(C'[:, Q], P_G'G'(k)[Q, Q], δx_Q(k))`, the last being the
    /// correction the rebase gives the live ones (G3). Independent of
    /// `n_G`: the columns `P_G'G'(k)[:, Q]` are not formed; the promotion's
    /// rows of `C̃` are read from the new base once it is installed (§5 P2).
    pub(in crate::estimator) fn promotion_columns(
        &self,
        blocks: &[usize],
    ) -> (DMatrix<f64>, DMatrix<f64>, DVector<f64>) {
        let cols = block_cols(blocks.iter().copied());
        let k = cols.len();
        let nk = self.keep_idx.len() + self.demoted_idx.len();
        // P_{L_k, Q}(k): Φ̃ C̃_Q for live columns, the demoted rows of P(k)
        // for demoted ones; and δx_Q = C̃_Qᵀ q̃ for live ones.
        let mut p_l = DMatrix::zeros(nk, k);
        let mut dx = DVector::zeros(k);
        let live: Vec<(usize, usize)> = (cols.iter().enumerate())
            .filter_map(|(j, &i)| self.new_base_source(i).ok().map(|c| (j, c)))
            .collect();
        if let (Some(base), false) = (self.parent.as_ref(), live.is_empty()) {
            let old: Vec<usize> = live.iter().map(|x| x.1).collect();
            let ct = c_cols(base, &self.extra, &old);
            let pl = &self.Phi * &ct;
            let dxl = ct.tr_mul(&self.q);
            for (i, &(j, _)) in live.iter().enumerate() {
                p_l.column_mut(j).copy_from(&pl.column(i));
                dx[j] = dxl[i];
            }
        }
        let g = 6 * self.live_blocks.len();
        for (j, &i) in cols.iter().enumerate() {
            if i >= g {
                p_l.column_mut(j).copy_from(&self.p_demoted_rows.row(i - g).transpose());
            }
        }
        // C'[:, Q] = W'⁻¹ P_{L', Q}(k).
        let mut c = p_l.select_rows(&self.keep_idx);
        self.unwhiten_new(&mut c);
        (c, self.new_base_block(&cols, &cols), dx)
    }
}

impl Estimator {
    /// Brings global keyframes into the local part (§5 P1–P3), exactly and
    /// without a global update, from an installed base or from a pending
    /// rebase's inputs (R5): `O(n_L n_L0 |Q| + n_L²)`, independent of `n_G`.
    /// Returns false (and changes nothing) if an id is not global or is
    /// given twice.
    pub fn promote(&mut self, ids: &[u64]) -> bool {
        let at = self.clones_offset();
        let Some(g) = self.global.as_mut() else {
            return false;
        };
        let blocks: Vec<usize> = ids.iter().filter_map(|id| g.live.get(id).copied()).collect();
        let unique = ids.iter().collect::<std::collections::BTreeSet<_>>().len() == ids.len();
        if blocks.len() != ids.len() || ids.is_empty() || !unique {
            return false;
        }
        let cols = block_cols(blocks.iter().copied());
        let k = cols.len();
        // The columns Q of C̃ (C's, then the earlier promotions' rows) and
        // P_GG(0)[Q, Q], read from an installed base; or, while a rebase is
        // out (R5), the same entries of the base it will install, computed
        // from its inputs, with the correction its keyframes take then.
        // Either way nothing of size n_G is formed.
        let while_pending = g.base.is_none();
        let Some((c_q, base_qq, dx_base)) = promotion_inputs(g, &self.pending, &blocks, &cols) else {
            return false;
        };
        // P1: P_LQ = Φ̃ C̃_Q, P_QQ = P_GG(0)_QQ − C̃_Qᵀ Ψ̃ C̃_Q, δx_Q = C̃_Qᵀ q̃.
        let p_lq = &g.Phi * &c_q;
        let psi_c = &g.Psi * &c_q;
        let mut p_qq = &base_qq - c_q.tr_mul(&psi_c);
        p_qq = (&p_qq + p_qq.transpose()) * 0.5;
        let dx_q = c_q.tr_mul(&g.q) + dx_base;
        // P2: the base-local part grows by Q, whitened by any invertible W_Q:
        // C̃ gains the rows W_Q⁻¹ P_GG(0)[Q, :], Φ̃ the rows [−(Ψ̃ C̃_Q)ᵀ, W_Q],
        // Ψ̃ and q̃ zeros. A diagonal W_Q = diag(√P_QQ now) keeps later Ψ̃
        // near unit scale (as W1) and is applied where the rows are read.
        let w_diag: Vec<f64> = (0..k)
            .map(|i| {
                let v = p_qq[(i, i)].abs().sqrt();
                if v.is_finite() && v > 0.0 {
                    v
                } else {
                    1.0
                }
            })
            .collect();
        let inv_w: Vec<f64> = w_diag.iter().map(|w| 1.0 / w).collect();
        g.extra.push(Extra {
            cols: cols.clone(),
            inv_w,
        });
        g.Phi = grow_phi(&g.Phi, at, &psi_c, &w_diag);
        let n0 = g.Psi.nrows();
        g.Psi.resize_mut(n0 + k, n0 + k, 0.0);
        g.q.resize_vertically_mut(n0 + k, 0.0);
        for id in ids {
            g.live.remove(id);
            g.sigma_m.remove(id);
        }
        // P3: the nominal values take δx_Q; the local covariance gains Q.
        for (j, id) in ids.iter().enumerate() {
            self.correct_keyframe(*id, &dx_q, 6 * j);
        }
        self.insert_local(at, &p_lq, &p_qq);
        self.local_kfs.extend_from_slice(ids);
        self.stats.promotions += ids.len() as u64;
        if while_pending {
            self.stats.promotions_while_pending += ids.len() as u64;
        }
        true
    }
}

/// What a promotion of the base blocks `blocks` (scalar columns `cols`)
/// reads of the base: `(C̃_Q, P_GG(0)[Q, Q], δx_Q)`, from the installed base
/// (with no correction), or, while a rebase is out (R5), from the job's
/// inputs. `None` with neither.
fn promotion_inputs(
    g: &Global,
    pending: &Option<PendingRebase>,
    blocks: &[usize],
    cols: &[usize],
) -> Option<(DMatrix<f64>, DMatrix<f64>, DVector<f64>)> {
    let k = cols.len();
    Some(match (&g.base, pending) {
        (Some(base), _) => {
            let mut qq = DMatrix::zeros(k, k);
            math::gather_block(&base.P_GG0, cols, &mut qq);
            (c_cols(base, &g.extra, cols), qq, DVector::zeros(k))
        }
        (None, Some(p)) => {
            let job = p.job();
            let (c_new, qq, dx) = job.promotion_columns(blocks);
            let e_cols: Vec<usize> = g.extra.iter().flat_map(|e| e.cols.iter().copied()).collect();
            let e_inv_w = g.extra.iter().flat_map(|e| e.inv_w.iter().copied());
            let mut e_rows = job.new_base_block(&e_cols, cols);
            for (mut row, s) in e_rows.row_iter_mut().zip(e_inv_w) {
                row *= s;
            }
            let mut c_q = DMatrix::zeros(c_new.nrows() + e_rows.nrows(), k);
            c_q.rows_mut(0, c_new.nrows()).copy_from(&c_new);
            c_q.rows_mut(c_new.nrows(), e_rows.nrows()).copy_from(&e_rows);
            (c_q, qq, dx)
        }
        (None, None) => return None,
    })
}

/// `Φ̃` after a promotion (§5 P2): `k` new rows at `at`, `[−(Ψ̃ C̃_Q)ᵀ, W_Q]`
/// with `W_Q = diag(w)`, and `k` new columns (zero in the old rows), built
/// column by column in one allocation.
fn grow_phi(phi: &DMatrix<f64>, at: usize, psi_c: &DMatrix<f64>, w: &[f64]) -> DMatrix<f64> {
    let (n, n0) = phi.shape();
    let k = w.len();
    debug_assert!(at <= n && psi_c.shape() == (n0, k));
    let m = n + k;
    let mut out = DMatrix::zeros(m, n0 + k);
    let (src, dst) = (phi.as_slice(), out.as_mut_slice());
    for c in 0..n0 {
        let (s, d) = (&src[c * n..(c + 1) * n], &mut dst[c * m..(c + 1) * m]);
        d[..at].copy_from_slice(&s[..at]);
        for j in 0..k {
            d[at + j] = -psi_c[(c, j)];
        }
        d[at + k..].copy_from_slice(&s[at..]);
    }
    for (j, wj) in w.iter().enumerate() {
        dst[(n0 + j) * m + at + j] = *wj;
    }
    out
}
