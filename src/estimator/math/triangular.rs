//! Blocked lower-triangular kernels (README §3, U1): the Cholesky factor
//! with its diagonal blocks inverted once ([`LowerSolver`]), the solves
//! with it, `T M` for an upper-triangular `T`, and the symmetric rank-k
//! update `P += α AᵀB` (and `P += α AᵀA` outside a diagonal block, §6).
//!
//! Why it exists: the EKF update and the rebase spend their time in these
//! solves and products; written as matrix products over blocks of
//! `TRI_BLOCK` rows they run several times faster than column-by-column
//! substitution, and they live together because they share the blocking.

use super::block_owned;

/// Rows per block of the blocked triangular solves, and columns per block of
/// the symmetric rank-k update.
const TRI_BLOCK: usize = 32;

/// A lower-triangular factor `L` (`S = L Lᵀ`) with the inverses of its
/// diagonal blocks formed once, so that every solve with it is matrix
/// products only (README §3, U1).
pub struct LowerSolver {
    l: nalgebra::DMatrix<f64>,
    /// `L_kk⁻¹` for each diagonal block of `TRI_BLOCK` rows.
    inv: Vec<nalgebra::DMatrix<f64>>,
}

impl LowerSolver {
    /// `None` if a diagonal entry is zero or not finite.
    pub fn new(l: nalgebra::DMatrix<f64>) -> Option<Self> {
        let n = l.nrows();
        let mut inv = Vec::with_capacity(n.div_ceil(TRI_BLOCK));
        let mut r0 = 0;
        while r0 < n {
            let k = TRI_BLOCK.min(n - r0);
            inv.push(lower_inverse(&l.view((r0, r0), (k, k)))?);
            r0 += k;
        }
        Some(Self { l, inv })
    }

    /// Factors a symmetric positive-definite `S = L Lᵀ` (its lower triangle
    /// is read) by blocks of `TRI_BLOCK`, right-looking: the diagonal block
    /// `L_kk` column by column, its inverse (kept for the solves), the panel
    /// `L_ik = S_ik L_kk⁻ᵀ` and the trailing `S_ii −= L_ik L_ikᵀ` as matrix
    /// products. `None` if `S` is not numerically positive definite.
    pub fn cholesky(mut a: nalgebra::DMatrix<f64>) -> Option<Self> {
        let n = a.nrows();
        debug_assert_eq!(n, a.ncols());
        let mut inv = Vec::with_capacity(n.div_ceil(TRI_BLOCK));
        let mut k0 = 0;
        while k0 < n {
            let kb = TRI_BLOCK.min(n - k0);
            cholesky_unblocked(&mut a, k0, kb)?;
            let li = lower_inverse(&a.view((k0, k0), (kb, kb)))?;
            let rest = n - k0 - kb;
            if rest > 0 {
                let s21 = block_owned(&a, k0 + kb, k0, rest, kb);
                let lit = nalgebra::DMatrixView::from_slice_with_strides(li.as_slice(), kb, kb, kb, 1);
                a.view_mut((k0 + kb, k0), (rest, kb)).gemm(1.0, &s21, &lit, 0.0);
                let l21 = block_owned(&a, k0 + kb, k0, rest, kb);
                let l21t = nalgebra::DMatrixView::from_slice_with_strides(l21.as_slice(), kb, rest, rest, 1);
                // S_22 −= L_21 L_21ᵀ, its lower triangle only: each column
                // block from its diagonal down.
                let mut j0 = 0;
                while j0 < rest {
                    let jb = TRI_BLOCK.min(rest - j0);
                    a.view_mut((k0 + kb + j0, k0 + kb + j0), (rest - j0, jb)).gemm(
                        -1.0,
                        &l21.rows(j0, rest - j0),
                        &l21t.columns(j0, jb),
                        1.0,
                    );
                    j0 += jb;
                }
            }
            inv.push(li);
            k0 += kb;
        }
        // The strict upper triangle still holds S: clear it.
        for j in 1..n {
            a.as_mut_slice()[j * n..j * n + j].fill(0.0);
        }
        Some(Self { l: a, inv })
    }

    /// Solves `L X = B` in place: block row `i` is
    /// `X_i = L_ii⁻¹ (B_i − L_i,<i X_<i)`, two matrix products.
    pub fn solve_in_place(&self, b: &mut nalgebra::DMatrix<f64>) {
        let n = self.l.nrows();
        let mut r0 = 0;
        for inv in &self.inv {
            let bs = inv.nrows();
            if r0 > 0 {
                let (done, mut cur) = b.rows_range_pair_mut(0..r0, r0..r0 + bs);
                cur.gemm(-1.0, &self.l.view((r0, 0), (bs, r0)), &done, 1.0);
            }
            let cur = inv * b.rows(r0, bs);
            b.rows_mut(r0, bs).copy_from(&cur);
            r0 += bs;
        }
        debug_assert_eq!(r0, n);
    }
}

/// The lower Cholesky factor of a small symmetric matrix, in place
/// (`a = L Lᵀ`, read from and written to the lower triangle; the upper is
/// left as it was): [`cholesky_unblocked`] over the whole matrix. `false`
/// when `a` is not positive definite (a non-finite entry included); `a` is
/// then half-factored. For the per-track gate's `2m × 2m` matrices, which
/// need no inverses kept; the update's large factor is [`LowerSolver`]'s.
pub fn cholesky_lower_in_place(a: &mut nalgebra::DMatrix<f64>) -> bool {
    let n = a.nrows();
    debug_assert_eq!(n, a.ncols());
    cholesky_unblocked(a, 0, n).is_some()
}

/// Cholesky factor of the diagonal block at `(k0, k0)` of size `kb`, in
/// place in its lower triangle (left-looking, column by column; the block's
/// earlier columns are already final). `None` on a pivot that is not
/// positive and finite.
fn cholesky_unblocked(a: &mut nalgebra::DMatrix<f64>, k0: usize, kb: usize) -> Option<()> {
    let n = a.nrows();
    let data = a.as_mut_slice();
    for j in 0..kb {
        let cj = (k0 + j) * n + k0;
        // s_ij −= Σ_{t<j} L_it L_jt, for i ≥ j.
        for t in 0..j {
            let ct = (k0 + t) * n + k0;
            let ljt = data[ct + j];
            if ljt != 0.0 {
                for i in j..kb {
                    data[cj + i] -= data[ct + i] * ljt;
                }
            }
        }
        let d = data[cj + j];
        if !(d > 0.0 && d.is_finite()) {
            return None;
        }
        let ljj = d.sqrt();
        data[cj + j] = ljj;
        let inv = 1.0 / ljj;
        for x in &mut data[cj + j + 1..cj + kb] {
            *x *= inv;
        }
    }
    Some(())
}

/// The inverse of a small lower-triangular matrix (a diagonal block, at most
/// `TRI_BLOCK` rows) by forward substitution on whole rows: row `i` of
/// `L⁻¹` is `(e_i − Σ_{t<i} L_it row_t) / L_ii`. Rows are fixed-length
/// arrays, so each step is a few full-width vector operations (the zeros
/// right of the diagonal cost less than the branches that would skip them).
/// `None` on a zero or non-finite pivot.
fn lower_inverse(l: &nalgebra::DMatrixView<f64>) -> Option<nalgebra::DMatrix<f64>> {
    let k = l.nrows();
    assert!(
        k <= TRI_BLOCK,
        "lower_inverse takes diagonal blocks of at most {TRI_BLOCK} rows"
    );
    let mut x = [[0.0f64; TRI_BLOCK]; TRI_BLOCK];
    for i in 0..k {
        let d = l[(i, i)];
        if d == 0.0 || !d.is_finite() {
            return None;
        }
        let mut row = [0.0f64; TRI_BLOCK];
        row[i] = 1.0;
        for (t, xt) in x.iter().enumerate().take(i) {
            let c = l[(i, t)];
            for (r, v) in row.iter_mut().zip(xt) {
                *r -= c * v;
            }
        }
        let inv = 1.0 / d;
        for r in &mut row {
            *r *= inv;
        }
        x[i] = row;
    }
    Some(nalgebra::DMatrix::from_fn(k, k, |i, j| x[i][j]))
}

/// `T M` for an upper-triangular `T` (k × k): each block of `TRI_BLOCK` rows
/// takes only the columns of `T` on or right of its diagonal, skipping the
/// zero lower triangle (about a third of the products at k ≈ 70).
pub fn upper_mul(t: &nalgebra::DMatrix<f64>, m: &nalgebra::DMatrix<f64>) -> nalgebra::DMatrix<f64> {
    let k = t.nrows();
    let mut out = nalgebra::DMatrix::zeros(k, m.ncols());
    let mut i0 = 0;
    while i0 < k {
        let ib = TRI_BLOCK.min(k - i0);
        out.view_mut((i0, 0), (ib, m.ncols()))
            .gemm(1.0, &t.view((i0, i0), (ib, k - i0)), &m.rows(i0, k - i0), 0.0);
        i0 += ib;
    }
    out
}

/// The lower triangle of `M Tᵀ` (`M` k × k, `T` upper triangular k × k):
/// what the EKF update's `S = (T P_cc) Tᵀ + I` needs (U1), since its
/// Cholesky factor reads only the lower triangle. Column block
/// `[j0, j0 + b)` takes, on its rows from `j0` down,
/// `M[j0.., j0..] · (T[j0..j0 + b, j0..])ᵀ`: row `j` of `T` is zero left of
/// `j`, so about a third of a full product's multiply-adds. `tt` is `Tᵀ`.
/// Entries above the diagonal are those of `M Tᵀ` within the diagonal
/// blocks and zero beyond them.
pub fn lower_of_times_upper_t(m: &nalgebra::DMatrix<f64>, tt: &nalgebra::DMatrix<f64>) -> nalgebra::DMatrix<f64> {
    let k = m.nrows();
    debug_assert!(m.ncols() == k && tt.nrows() == k && tt.ncols() == k);
    let mut out = nalgebra::DMatrix::zeros(k, k);
    let mut j0 = 0;
    while j0 < k {
        let jb = TRI_BLOCK.min(k - j0);
        out.view_mut((j0, j0), (k - j0, jb)).gemm(
            1.0,
            &m.view((j0, j0), (k - j0, k - j0)),
            &tt.view((j0, j0), (k - j0, jb)),
            0.0,
        );
        j0 += jb;
    }
    out
}

/// Copies the strict lower triangle of the leading `g × g` block onto its
/// upper one, in place.
fn mirror_lower_leading(p: &mut nalgebra::DMatrix<f64>, g: usize) {
    mirror_lower(p, 0..g, 0, g);
}

/// `P[j, i] = P[i, j]` for the columns `j ∈ cols` and the rows
/// `i ∈ [max(j + 1, r_min), r_end)`: part of the strict lower triangle copied
/// onto the upper one, in place, in square tiles so that both sides stay in
/// cache on large matrices.
fn mirror_lower(p: &mut nalgebra::DMatrix<f64>, cols: std::ops::Range<usize>, r_min: usize, r_end: usize) {
    const TILE: usize = 64;
    let ld = p.nrows();
    let data = p.as_mut_slice();
    for j0 in cols.clone().step_by(TILE) {
        let j1 = (j0 + TILE).min(cols.end);
        for i0 in (j0.max(r_min)..r_end).step_by(TILE) {
            // Tile rows i0.., columns j0..: P[j, i] = P[i, j] for i > j.
            for j in j0..j1 {
                for i in i0.max(j + 1)..(i0 + TILE).min(r_end) {
                    data[i * ld + j] = data[j * ld + i];
                }
            }
        }
    }
}

/// `P[..g, ..g] += α Aᵀ B` where `Aᵀ B` (g × g; `A`, `B` k × g) is known to
/// be symmetric (`AᵀA` in U1, `C̃ᵀ (Ψ̃ C̃)` in G2): only the lower
/// triangle's column blocks are computed, about half the products of a full
/// one, then mirrored, so the block leaves exactly symmetric.
pub fn add_symmetric_product(
    p: &mut nalgebra::DMatrix<f64>,
    g: usize,
    alpha: f64,
    a: &nalgebra::DMatrix<f64>,
    b: &nalgebra::DMatrix<f64>,
) {
    let at = a.transpose();
    add_symmetric_product_t(p, g, alpha, at.as_view(), b.as_view());
}

/// [`add_symmetric_product`] given `Aᵀ` (g × k) rather than `A`, both as
/// views: the EKF update (U1) takes `Aᵀ` and `Bᵀ` as rows of one transposed
/// solve, so nothing is copied or transposed again per product.
pub fn add_symmetric_product_t(
    p: &mut nalgebra::DMatrix<f64>,
    g: usize,
    alpha: f64,
    at: nalgebra::DMatrixView<'_, f64>,
    b: nalgebra::DMatrixView<'_, f64>,
) {
    let block = TRI_BLOCK.max(g / 16);
    let mut j0 = 0;
    while j0 < g {
        let jb = block.min(g - j0);
        p.view_mut((j0, j0), (g - j0, jb))
            .gemm(alpha, &at.rows(j0, g - j0), &b.columns(j0, jb), 1.0);
        j0 += jb;
    }
    mirror_lower_leading(p, g);
}

/// `P += α AᵀA` (`A` k × n, given as `Aᵀ` and `A` views, `P` n × n) on
/// every entry outside the diagonal block `[s0, s1)²`, which is left as it
/// is: the Schmidt update (README §6) with `[s0, s1)` the nuisance states.
/// Only the lower triangle outside that block is computed (the columns
/// before `s0` and from `s1` on from their diagonal down, by column blocks;
/// the columns of `[s0, s1)` on the rows from `s1` on, one product), then
/// mirrored, so `P` leaves exactly symmetric if it came so. With
/// `n_A = n − (s1 − s0)` the cost is at most `k · n_A · n` multiply–adds,
/// and nothing of size n × n is allocated.
pub fn add_gram_outside_block(
    p: &mut nalgebra::DMatrix<f64>,
    alpha: f64,
    at: nalgebra::DMatrixView<'_, f64>,
    a: nalgebra::DMatrixView<'_, f64>,
    s0: usize,
    s1: usize,
) {
    let n = p.nrows();
    assert!(s0 <= s1 && s1 <= n, "nuisance block [{s0}, {s1}) outside 0..{n}");
    debug_assert!(p.ncols() == n && at.nrows() == n && a.ncols() == n && at.ncols() == a.nrows());
    let block = TRI_BLOCK.max(n / 16);
    for (c0, c1) in [(0, s0), (s1, n)] {
        let mut j0 = c0;
        while j0 < c1 {
            let jb = block.min(c1 - j0);
            p.view_mut((j0, j0), (n - j0, jb))
                .gemm(alpha, &at.rows(j0, n - j0), &a.columns(j0, jb), 1.0);
            j0 += jb;
        }
    }
    if s1 > s0 && n > s1 {
        p.view_mut((s1, s0), (n - s1, s1 - s0))
            .gemm(alpha, &at.rows(s1, n - s1), &a.columns(s0, s1 - s0), 1.0);
    }
    mirror_lower(p, 0..s0, 0, n);
    mirror_lower(p, s0..s1, s1, n);
    mirror_lower(p, s1..n, 0, n);
}

#[cfg(test)]
mod tri_tests {
    use super::*;
    use crate::estimator::math::{all_finite, gather_block};
    use nalgebra::{DMatrix, DVector};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The blocked solve agrees with nalgebra's column-by-column one, over
    /// sizes that cross block edges; the symmetric rank-k form with the
    /// full product.
    #[test]
    fn blocked_triangular_solve_and_gram_update_match_the_reference() {
        for &n in &[1usize, 7, 32, 33, 64, 70, 131] {
            let m = DMatrix::from_fn(n, n, |i, j| ((i * 7 + j * 13) % 17) as f64 / 17.0 - 0.4);
            let spd = &m * m.transpose() + DMatrix::identity(n, n) * (n as f64);
            let l = spd.clone().cholesky().unwrap().l();
            let b = DMatrix::from_fn(n, 9, |i, j| ((i * 3 + j * 5) % 11) as f64 - 5.0);
            let mut x = b.clone();
            LowerSolver::new(l.clone()).unwrap().solve_in_place(&mut x);
            let want = l.solve_lower_triangular(&b).unwrap();
            assert!((&x - &want).abs().max() <= 1e-12 * want.abs().max().max(1.0), "n {n}");
            // The blocked factorisation gives the same factor and solves.
            let ours = LowerSolver::cholesky(spd.clone()).unwrap();
            assert!((&ours.l - &l).abs().max() <= 1e-12 * l.abs().max(), "n {n}");
            let mut y = b.clone();
            ours.solve_in_place(&mut y);
            assert!((&y - &want).abs().max() <= 1e-12 * want.abs().max().max(1.0), "n {n}");
            // The lower triangle of M Tᵀ for the upper-triangular T = Lᵀ
            // (Tᵀ = L is what it takes).
            let full = &m * &l;
            let lower = lower_of_times_upper_t(&m, &l);
            for j in 0..n {
                for i in j..n {
                    assert!(
                        (lower[(i, j)] - full[(i, j)]).abs() <= 1e-12 * full.abs().max(),
                        "n {n}"
                    );
                }
            }
            // Only the lower triangle is read: garbage above it changes nothing.
            let mut upper = spd.clone();
            for j in 1..n {
                for i in 0..j {
                    upper[(i, j)] = if (i + j) % 2 == 0 { f64::NAN } else { 1e300 };
                }
            }
            assert_eq!(LowerSolver::cholesky(upper).unwrap().l, ours.l, "n {n}");
            // Not positive definite: refused, whichever block holds the bad pivot.
            let mut bad = spd.clone();
            bad[(n - 1, n - 1)] = -1.0;
            assert!(LowerSolver::cholesky(bad).is_none(), "n {n}");
            let mut nan = spd.clone();
            nan[(n / 2, n / 2)] = f64::NAN;
            assert!(LowerSolver::cholesky(nan).is_none(), "n {n}");
            // Non-finite below the diagonal, in the last block.
            if n > 1 {
                for bad in [f64::NAN, f64::INFINITY] {
                    let mut b = spd.clone();
                    b[(n - 1, 0)] = bad;
                    assert!(LowerSolver::cholesky(b).is_none(), "n {n} {bad}");
                }
            }
            let a = DMatrix::from_fn(5, n, |i, j| ((i * 11 + j * 3) % 7) as f64 - 3.0);
            let mut p = spd.clone();
            add_symmetric_product(&mut p, n, -0.25, &a, &a);
            let want = &spd - a.transpose() * &a * 0.25;
            assert!((&p - &want).abs().max() <= 1e-12 * want.abs().max(), "n {n}");
            assert_eq!(p, p.transpose());
            let c = DMatrix::from_fn(4, n, |i, j| ((i * 5 + j * 7) % 9) as f64 - 4.0);
            let psi = DMatrix::from_fn(4, 4, |i, j| if i == j { 2.0 } else { 0.5 });
            let psi_c = &psi * &c;
            for g in [n, n.saturating_sub(3)] {
                let mut q = spd.clone();
                add_symmetric_product(
                    &mut q,
                    g,
                    -1.0,
                    &c.columns(0, g).into_owned(),
                    &psi_c.columns(0, g).into_owned(),
                );
                let mut want = spd.clone();
                let d = c.columns(0, g).transpose() * psi_c.columns(0, g);
                want.view_mut((0, 0), (g, g)).zip_apply(&d, |w, x| *w -= x);
                assert!((&q - &want).abs().max() <= 1e-12 * want.abs().max(), "n {n} g {g}");
                assert_eq!(q, q.transpose());
            }
            let t = l.transpose();
            let um = upper_mul(&t, &b);
            let want = &t * &b;
            assert!((&um - &want).abs().max() <= 1e-12 * want.abs().max().max(1.0), "n {n}");
        }
        let empty = LowerSolver::cholesky(DMatrix::zeros(0, 0)).unwrap();
        let mut none = DMatrix::<f64>::zeros(0, 4);
        empty.solve_in_place(&mut none);
        // gather_block: P[idx, idx] for runs, gaps, repeats and nothing,
        // into an exact and into a larger output (its leading block).
        let p = DMatrix::from_fn(9, 9, |i, j| (10 * i + j) as f64);
        for idx in [vec![0usize, 1, 2, 6, 7, 8], vec![3], vec![5, 4, 4, 8], vec![]] {
            let k = idx.len();
            let want = DMatrix::from_fn(k, k, |i, j| p[(idx[i], idx[j])]);
            let mut got = DMatrix::zeros(k, k);
            gather_block(&p, &idx, &mut got);
            assert_eq!(got, want, "{idx:?}");
            let mut big = DMatrix::from_element(k + 2, k + 1, -1.0);
            gather_block(&p, &idx, &mut big);
            assert_eq!(big.view((0, 0), (k, k)), want, "{idx:?} leading block");
            assert!(
                big.rows(k, 2).iter().all(|&x| x == -1.0),
                "{idx:?} rows below untouched"
            );
        }
        let mut z = DMatrix::<f64>::identity(3, 3);
        z[(1, 1)] = 0.0;
        assert!(LowerSolver::new(z.clone()).is_none());
        assert!(LowerSolver::cholesky(z).is_none());
        let mut v = vec![1.0; 21];
        assert!(all_finite(&v));
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            for at in [0, 7, 8, 20] {
                v[at] = bad;
                assert!(!all_finite(&v), "{bad} at {at}");
                v[at] = 1.0;
            }
        }
    }

    /// A random symmetric positive-definite matrix whose scales span four
    /// decades, exactly symmetric.
    fn random_spd(rng: &mut ChaCha8Rng, n: usize) -> DMatrix<f64> {
        let m = DMatrix::from_fn(n, n + 5, |_, _| rng.random_range(-1.0..1.0));
        let s = DVector::from_fn(n, |_, _| 10f64.powf(rng.random_range(-3.0..1.0)));
        let mut p = &m * m.transpose() / (n as f64) + DMatrix::identity(n, n) * 0.05;
        for j in 0..n {
            for i in 0..n {
                p[(i, j)] *= s[i] * s[j];
            }
        }
        (&p + p.transpose()) * 0.5
    }

    /// The kernel against a dense reference, at the edges: no nuisance block,
    /// one at the start, one at the end, the whole matrix, and sizes across
    /// the block (32) and tile (64) edges.
    #[test]
    fn schmidt_gram_kernel_matches_the_dense_reference() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for &(n, s0, s1) in &[
            (1usize, 0usize, 0usize),
            (7, 0, 7),
            (30, 0, 0),
            (30, 12, 12),
            (70, 0, 36),
            (70, 18, 70),
            (70, 18, 66),
            (140, 18, 78),
            (333, 18, 267),
        ] {
            let p0 = random_spd(&mut rng, n);
            for k in [1usize, 5, 40] {
                let a = DMatrix::from_fn(k, n, |_, _| rng.random_range(-1.0..1.0));
                let at = a.transpose();
                let mut p = p0.clone();
                add_gram_outside_block(&mut p, -0.5, at.as_view(), a.as_view(), s0, s1);
                let mut want = &p0 - at.clone() * &a * 0.5;
                want.view_mut((s0, s0), (s1 - s0, s1 - s0))
                    .copy_from(&p0.view((s0, s0), (s1 - s0, s1 - s0)));
                let scale = want.abs().max().max(1.0);
                let d = (&p - &want).abs().max() / scale;
                assert!(d <= 1e-13, "n {n} [{s0}, {s1}) k {k}: {d:e}");
                assert_eq!(p, p.transpose(), "n {n} [{s0}, {s1}) k {k}: not symmetric");
                assert_eq!(
                    p.view((s0, s0), (s1 - s0, s1 - s0)),
                    p0.view((s0, s0), (s1 - s0, s1 - s0)),
                    "n {n} [{s0}, {s1}) k {k}: nuisance block changed"
                );
            }
        }
    }
}
