//! The global part read back (§5 G1–G3): the reconstructed covariance and
//! correction of global keyframes, and their merge into the local part.
//!
//! Why it exists: the global part is stored implicitly (a frozen base and
//! the accumulated `Φ̃`, `Ψ̃`, `q̃`); everything that needs it explicitly
//! (a keyframe's uncertainty, a change of mode, the local part growing)
//! goes through here.

use nalgebra::{DMatrix, DVector};

use super::{block_cols, Reconstructed};
use crate::estimator::{Estimator, Mode, ACTIVE_DIM};

impl Estimator {
    /// The reconstructed global part over the live keyframes (§5 G1–G3):
    /// `(P_LG, P_GG, δx_G, ids)`. `None` without an installed base.
    pub(in crate::estimator) fn reconstruct(&self) -> Option<Reconstructed> {
        let live = self.global.as_ref()?.live_in_block_order();
        let (p_lg, p_gg, dx) = self.global_blocks(live.iter().map(|x| x.1))?;
        Some((p_lg, p_gg, dx, live.into_iter().map(|x| x.0).collect()))
    }

    /// A global keyframe's covariance now (§5 G2 for one block), if the base
    /// is installed.
    pub(in crate::estimator) fn global_keyframe_covariance(&self, id: u64) -> Option<DMatrix<f64>> {
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
    pub(in crate::estimator) fn merge_global(&mut self) {
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
    pub(in crate::estimator) fn insert_local(&mut self, at: usize, cross: &DMatrix<f64>, block: &DMatrix<f64>) {
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
