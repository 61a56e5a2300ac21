//! Compressed mode's global part (§5): the base frozen at the last rebase,
//! the exact promotion of global keyframes into the local part (§5 P1–P3,
//! at a cost independent of the global size), and the rebase (global update) split into a
//! pure [`RebaseJob`] that may run on another thread while the local filter
//! goes on (§5 R1–R5).
//!
//! Why it exists: the global update is the only step whose cost grows with
//! the square of the map. Loop closures no longer need one (a promotion
//! serves them), and the one that re-centres the local region can be
//! computed off the real-time path and installed when ready, without
//! changing a single number of the filter.

use std::collections::BTreeMap;
use std::sync::Arc;

use nalgebra::{DMatrix, DVector};

use super::covariance::{position_sigma_m, whitening_factor};
use super::{math, Estimator, FilterEvent, GlobalReason, ACTIVE_DIM};
use crate::estimator::Mode;

/// The global part at the last rebase (time 0), in the whitened coordinates
/// of §5 W1. Immutable once built: a running job shares it through an `Arc`.
#[derive(Debug)]
pub struct Base {
    /// Keyframe id of each 6-column block, in order (promoted or removed
    /// keyframes keep their dead block until the next rebase).
    pub(super) ids: Vec<u64>,
    /// `C = W⁻¹ P_LG(0)` (n_L0 × 6 blocks).
    pub(super) C: DMatrix<f64>,
    /// `P_GG(0)`.
    pub(super) P_GG0: DMatrix<f64>,
}

/// The global part as the filter holds it between rebases.
#[derive(Clone, Debug)]
pub(super) struct Global {
    /// `None` while a rebase job computes it.
    pub(super) base: Option<Arc<Base>>,
    /// Live global keyframe id → its block in the base.
    pub(super) live: BTreeMap<u64, usize>,
    /// Row blocks appended to `C` by promotions, `W_Q⁻¹ P_GG(0)[Q, :]` (§5
    /// P2), one per promotion (appending never copies the others);
    /// `C̃ = [C; extra…]`.
    pub(super) extra: Vec<Extra>,
    /// `Φ̃`: maps the whitened base-local errors to the current local errors.
    pub(super) Phi: DMatrix<f64>,
    /// `Ψ̃ = Σ (HΦ̃)ᵀ S⁻¹ (HΦ̃)`.
    pub(super) Psi: DMatrix<f64>,
    /// `q̃ = Σ (HΦ̃)ᵀ S⁻¹ r`.
    pub(super) q: DVector<f64>,
    /// Position σ (m) of each global keyframe at the last rebase.
    pub(super) sigma_m: BTreeMap<u64, f64>,
}

/// One promotion's rows of `C̃`, `W_Q⁻¹ P_GG(0)[Q, :]` (§5 P2), with a
/// diagonal `W_Q`, read from the base where they are used rather than
/// copied: the base they refer to outlives them (it is the parent of the
/// rebase that consumes them), so a promotion copies nothing of size `n_G`.
/// That base is the installed one, or, for a promotion made while a rebase
/// is out (§5 R5), the one that rebase will install; until then only later
/// promotions read them, through the job ([`RebaseJob::new_base_block`]).
#[derive(Clone, Debug)]
pub(super) struct Extra {
    /// The promoted keyframes' scalar columns in that base.
    cols: Vec<usize>,
    /// `W_Q⁻¹`, the diagonal.
    inv_w: Vec<f64>,
}

impl Extra {
    /// Row `j` of the block at global column `c`: `(W_Q⁻¹ P_GG(0)[Q, :])[j, c]`.
    fn at(&self, base: &Base, c: usize, j: usize) -> f64 {
        base.P_GG0[(c, self.cols[j])] * self.inv_w[j]
    }
}

impl Global {
    fn c_cols(&self, base: &Base, cols: &[usize]) -> DMatrix<f64> {
        c_cols(base, &self.extra, cols)
    }

    /// Live keyframes with their base columns, in block order.
    fn live_in_block_order(&self) -> Vec<(u64, usize)> {
        let mut v: Vec<(u64, usize)> = self.live.iter().map(|(id, b)| (*id, *b)).collect();
        v.sort_unstable_by_key(|x| x.1);
        v
    }
}

/// The columns `cols` of `C̃ = [C; extra…]`: `C`'s, and below them each
/// promotion's rows read from the base.
fn c_cols(base: &Base, extra: &[Extra], cols: &[usize]) -> DMatrix<f64> {
    let n0 = base.C.nrows();
    let ne: usize = extra.iter().map(|e| e.cols.len()).sum();
    let mut out = DMatrix::zeros(n0 + ne, cols.len());
    for (k, &c) in cols.iter().enumerate() {
        out.view_mut((0, k), (n0, 1)).copy_from(&base.C.column(c));
        let mut r = n0;
        for e in extra {
            for j in 0..e.cols.len() {
                out[(r + j, k)] = e.at(base, c, j);
            }
            r += e.cols.len();
        }
    }
    out
}

/// `(P_LG, P_GG, δx_G, global ids)` of [`Estimator::reconstruct`].
pub(super) type Reconstructed = (DMatrix<f64>, DMatrix<f64>, DVector<f64>, Vec<u64>);

fn block_cols(blocks: impl IntoIterator<Item = usize>) -> Vec<usize> {
    blocks.into_iter().flat_map(|b| 6 * b..6 * b + 6).collect()
}

/// A rebase (global update, §5 R1–R3): everything it needs, owned, so that
/// [`RebaseJob::run`] is a pure function that can run on any thread.
#[derive(Clone, Debug)]
pub struct RebaseJob {
    /// Which rebase of its filter this is; the result must come back to it.
    pub seq: u64,
    parent: Option<Arc<Base>>,
    /// Parent blocks that stay global, in the new base's order.
    live_blocks: Vec<usize>,
    extra: Vec<Extra>,
    Phi: DMatrix<f64>,
    Psi: DMatrix<f64>,
    q: DVector<f64>,
    /// Local covariance rows of the demoted keyframes at the rebase time.
    p_demoted_rows: DMatrix<f64>,
    demoted_idx: Vec<usize>,
    /// Local indices (at the rebase time) of the new local part.
    keep_idx: Vec<usize>,
    /// `W'`: lower factor of the new local block, `P_L'L' = W' W'ᵀ`.
    w_new: DMatrix<f64>,
    /// Keyframe ids of the new base: the live ones, then the demoted ones.
    ids: Vec<u64>,
}

/// The rebase being computed: its job still here, or handed out.
#[derive(Clone, Debug)]
pub(super) enum PendingRebase {
    Held(Box<RebaseJob>),
    /// Handed out by [`Estimator::take_rebase_job`]; the filter keeps a
    /// reference to answer column queries (R5) until the result is installed.
    Dispatched(Arc<RebaseJob>),
}

impl PendingRebase {
    pub(super) fn job(&self) -> &RebaseJob {
        match self {
            PendingRebase::Held(j) => j,
            PendingRebase::Dispatched(j) => j,
        }
    }
    fn seq(&self) -> u64 {
        self.job().seq
    }
}

/// What a [`RebaseJob`] computed: the new base and the correction of the
/// keyframes that were already global (§5 G3).
#[derive(Debug)]
pub struct RebaseResult {
    pub seq: u64,
    base: Base,
    /// `δx_G` for `base.ids[..n_live]`.
    dx_live: DVector<f64>,
}

impl RebaseJob {
    /// Global keyframes after the rebase.
    pub fn n_global(&self) -> usize {
        self.ids.len()
    }

    /// The new base's scalar column `i` (§5 R2's order: the live global
    /// keyframes' columns, then the demoted keyframes'): `Ok(old base
    /// column)` for a live one, `Err(local index at the rebase time)` for a
    /// demoted one.
    fn new_base_source(&self, i: usize) -> Result<usize, usize> {
        let g = 6 * self.live_blocks.len();
        if i < g {
            Ok(6 * self.live_blocks[i / 6] + i % 6)
        } else {
            Err(self.demoted_idx[i - g])
        }
    }

    /// Entries `rows × cols` (scalar columns) of the new base's
    /// `P_G'G'(k)` (§5 R5), from the job's inputs without computing the
    /// base: G2 for those entries only (`P_GG(0) − C̃ᵀ Ψ̃ C̃` between live
    /// keyframes, `(Φ̃ C̃)` rows of the demoted keyframes against live ones,
    /// their own rows of `P(k)` between demoted ones, symmetrised as R2 does).
    /// `O(n_L0 (|rows| + |cols|)(n_L0 + |cols|))`, independent of `n_G`.
    pub(super) fn new_base_block(&self, rows: &[usize], cols: &[usize]) -> DMatrix<f64> {
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
    pub(super) fn promotion_columns(&self, blocks: &[usize]) -> (DMatrix<f64>, DMatrix<f64>, DVector<f64>) {
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

    /// `X ← W'⁻¹ X`, the new base's whitening (R2: `C' = W'⁻¹ P_L'G'(k)`),
    /// by the blocked solve of U1 (matrix products; a column-by-column
    /// solve over n_G columns is several times slower). `W'` comes from
    /// `whitening_factor`, whose diagonal is positive; were it not finite,
    /// `X` becomes NaN, which the filter's health checks catch.
    fn unwhiten_new(&self, x: &mut DMatrix<f64>) {
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
        RebaseResult {
            seq: self.seq,
            base: Base {
                ids: self.ids.clone(),
                C: c_new,
                P_GG0: p0,
            },
            dx_live,
        }
    }
}

/// Why a rebase result was not installed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum InstallError {
    #[error("rebase result {got} does not match the pending rebase {want:?}")]
    Stale { got: u64, want: Option<u64> },
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
    /// base. Cheap: `O(n_G)` plus moving the matrices in.
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
        // Promotions made while it was computed keep their rows of C̃.
        g.base = Some(Arc::new(res.base));
        self.stats.rebases_installed += 1;
        Ok(job)
    }

    /// Runs and installs a pending rebase here and now.
    pub(super) fn finish_rebase_inline(&mut self) {
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
    pub(super) fn begin_rebase(&mut self, reason: GlobalReason) -> Option<FilterEvent> {
        if self.pending.is_some() {
            return None;
        }
        self.sync();
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
        if self.global.is_none() && demote.is_empty() {
            return None;
        }
        let global_before: Vec<u64> = self
            .global
            .as_ref()
            .map(|g| g.live.keys().copied().collect())
            .unwrap_or_default();
        self.stats.global_updates += 1;
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
        for (j, id) in &demote {
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
        if !self.s.async_rebase {
            self.finish_rebase_inline();
        }
        Some(FilterEvent::GlobalUpdate {
            reason,
            global_before,
            local_after: self.local_kfs.clone(),
        })
    }

    /// Brings global keyframes into the local part (§5 P1–P3), exactly and
    /// without a global update, from an installed base or from a pending
    /// rebase's inputs (R5): `O(n_L n_L0 |Q| + n_L²)`, independent of `n_G`.
    /// Returns false (and changes nothing) if an id is not global or is
    /// given twice.
    pub(super) fn promote(&mut self, ids: &[u64]) -> bool {
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
        let (c_q, base_qq, dx_base) = match (&g.base, &self.pending) {
            (Some(base), _) => {
                let mut qq = DMatrix::zeros(k, k);
                math::gather_block(&base.P_GG0, &cols, &mut qq);
                (c_cols(base, &g.extra, &cols), qq, DVector::zeros(k))
            }
            (None, Some(p)) => {
                let job = p.job();
                let (c_new, qq, dx) = job.promotion_columns(&blocks);
                let e_cols: Vec<usize> = g.extra.iter().flat_map(|e| e.cols.iter().copied()).collect();
                let e_inv_w = g.extra.iter().flat_map(|e| e.inv_w.iter().copied());
                let mut e_rows = job.new_base_block(&e_cols, &cols);
                for (mut row, s) in e_rows.row_iter_mut().zip(e_inv_w) {
                    row *= s;
                }
                let mut c_q = DMatrix::zeros(c_new.nrows() + e_rows.nrows(), k);
                c_q.rows_mut(0, c_new.nrows()).copy_from(&c_new);
                c_q.rows_mut(c_new.nrows(), e_rows.nrows()).copy_from(&e_rows);
                (c_q, qq, dx)
            }
            (None, None) => return false,
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

    /// The reconstructed global part over the live keyframes (§5 G1–G3):
    /// `(P_LG, P_GG, δx_G, ids)`. `None` without an installed base.
    pub(super) fn reconstruct(&self) -> Option<Reconstructed> {
        let live = self.global.as_ref()?.live_in_block_order();
        let (p_lg, p_gg, dx) = self.global_blocks(live.iter().map(|x| x.1))?;
        Some((p_lg, p_gg, dx, live.into_iter().map(|x| x.0).collect()))
    }

    /// A global keyframe's covariance now (§5 G2 for one block), if the base
    /// is installed.
    pub(super) fn global_keyframe_covariance(&self, id: u64) -> Option<DMatrix<f64>> {
        let b = *self.global.as_ref()?.live.get(&id)?;
        self.global_blocks([b]).map(|x| x.1)
    }

    /// G1–G3 for some blocks of an installed base: `(P_LG, P_GG, δx_G)`,
    /// `P_GG` symmetrised.
    fn global_blocks(
        &self,
        blocks: impl IntoIterator<Item = usize>,
    ) -> Option<(DMatrix<f64>, DMatrix<f64>, DVector<f64>)> {
        let g = self.global.as_ref()?;
        let base = g.base.as_ref()?;
        let cols = block_cols(blocks);
        let c = g.c_cols(base, &cols);
        let p_lg = &g.Phi * &c;
        let mut p_gg = base.P_GG0.select_rows(&cols).select_columns(&cols) - c.tr_mul(&(&g.Psi * &c));
        p_gg = (&p_gg + p_gg.transpose()) * 0.5;
        Some((p_lg, p_gg, c.tr_mul(&g.q)))
    }

    /// The same filter in another mode (`full` or `schmidt`), with every
    /// keyframe in the state: compressed's global part merged (§5 G1–G3).
    /// For comparing modes on one state, as the scaling benchmark does.
    pub fn into_mode(mut self, mode: Mode) -> Estimator {
        self.merge_global();
        self.s.mode = mode;
        self
    }

    /// Moves the whole global part into the local one (G1–G3, after any
    /// pending rebase): every keyframe then lives in `P`.
    pub(super) fn merge_global(&mut self) {
        self.finish_rebase_inline();
        self.sync();
        if let Some((p_lg, p_gg, dx, ids)) = self.reconstruct() {
            for (j, id) in ids.iter().enumerate() {
                self.correct_keyframe(*id, &dx, 6 * j);
            }
            // Global keyframes go after the local ones, before the clones.
            let at = self.clones_offset();
            self.insert_local(at, &p_lg, &p_gg);
            self.local_kfs.extend(ids);
        }
        self.global = None;
    }

    /// Inserts states with covariance `block` and cross-covariance `cross`
    /// (rows: the current local states) at index `at` of the local part,
    /// copying whole column runs (`P` is column-major).
    pub(super) fn insert_local(&mut self, at: usize, cross: &DMatrix<f64>, block: &DMatrix<f64>) {
        let n = self.P.nrows();
        let k = block.nrows();
        debug_assert!(at <= n && cross.shape() == (n, k) && block.shape() == (k, k));
        let m = n + k;
        let mut p = DMatrix::zeros(m, m);
        {
            let (src, dst) = (self.P.as_slice(), p.as_mut_slice());
            let (xs, bs) = (cross.as_slice(), block.as_slice());
            // Old column c goes to column c (c < at) or c + k; within it the
            // rows split the same way around the k new rows, which hold
            // cross[c, :].
            for c in 0..n {
                let mc = if c < at { c } else { c + k };
                let (s, d) = (&src[c * n..(c + 1) * n], &mut dst[mc * m..(mc + 1) * m]);
                d[..at].copy_from_slice(&s[..at]);
                for j in 0..k {
                    d[at + j] = xs[j * n + c];
                }
                d[at + k..].copy_from_slice(&s[at..]);
            }
            // The new columns: cross[:, j] around block[:, j].
            for j in 0..k {
                let (x, d) = (&xs[j * n..(j + 1) * n], &mut dst[(at + j) * m..(at + j + 1) * m]);
                d[..at].copy_from_slice(&x[..at]);
                d[at..at + k].copy_from_slice(&bs[j * k..(j + 1) * k]);
                d[at + k..].copy_from_slice(&x[at..]);
            }
        }
        self.P = p;
        debug_assert!(self.P.nrows() >= ACTIVE_DIM);
    }
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
