//! Compressed mode's global part (§5): the base frozen at the last rebase,
//! the exact promotion of global keyframes into the local part (§5 P1–P3,
//! at a cost independent of the global size), and the rebase (global update) split into a
//! pure [`RebaseJob`] that may run on another thread while the local filter
//! goes on (§5 R1–R5), its base space no larger than the global part (R6).
//!
//! Why it exists: the global update is the only step whose cost grows with
//! the square of the map. Loop closures no longer need one (a promotion
//! serves them), and the one that re-centres the local region can be
//! computed off the real-time path and installed when ready, without
//! changing a single number of the filter.
//!
//! This file holds the types and the reading of `C̃`; the steps, by concern:
//! - `rebase.rs`: starting a rebase (R1), the job (R2) and installing its
//!   result (R3);
//! - `promote.rs`: promotions (P1–P3), also while a rebase is out (R5);
//! - `reconstruct.rs`: the global part read back (G1–G3) and merged.

use std::collections::BTreeMap;
use std::sync::Arc;

use nalgebra::{DMatrix, DVector};

mod promote;
mod rebase;
mod reconstruct;

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
    /// `U` of §5 R6 when the new global part has fewer columns than the
    /// local part at the rebase (`C' = U R`, `U` orthonormal columns): the
    /// install maps the accumulators into its smaller base space.
    reduce: Option<DMatrix<f64>>,
}

/// Why a rebase result was not installed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum InstallError {
    #[error("rebase result {got} does not match the pending rebase {want:?}")]
    Stale { got: u64, want: Option<u64> },
}
