//! The Householder triangularisation (README §3, N1 and Q1), plain for
//! small matrices and blocked as LAPACK's dgeqrf for large ones, with the
//! column kernels of `kernels.rs` (AVX2 and FMA where the CPU has them).
//!
//! Why it exists: the track update projects onto the left null space of
//! the feature Jacobian (N1) and compresses the stacked rows (Q1) with it;
//! it is the camera update's main cost, and its reflections stay those of
//! the reference convention (dlarfg) on either kernel path, so that the
//! paths differ by round-off only.

use super::kernels::{Kernels, Portable};
use super::zeroed;

/// Columns per panel of the blocked Householder triangularisation.
const QR_BLOCK: usize = 16;
/// Below this many entries the triangularisation is not blocked.
const QR_BLOCKED_MIN_ENTRIES: usize = 4096;

/// The blocked triangularisation's working buffers, kept per thread and
/// reused: the camera update triangularises thousands of stacks a second,
/// and its panels would otherwise allocate seven buffers each (issue 43: no
/// allocation per frame). Each is cleared and zero-filled to the length a
/// panel needs, which keeps its capacity.
#[derive(Default)]
struct Scratch {
    /// The panel's reflectors `V` (rows × jb, column-major).
    v: Vec<f64>,
    tau: Vec<f64>,
    /// dlarft's `T` (jb × jb), its transpose, and one column of its
    /// recurrence.
    t: Vec<f64>,
    t_tr: Vec<f64>,
    t_col: Vec<f64>,
    /// `Vᵀ`, `Vᵀ C` and `Tᵀ (Vᵀ C)`.
    v_tr: Vec<f64>,
    vtc: Vec<f64>,
    t_vtc: Vec<f64>,
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::new(Scratch::default());
}

/// Householder triangularisation (README §3, N1 and Q1). Chooses the
/// reflections `Q = H₀ H₁ … H_{p−1}` that zero the sub-diagonal of the
/// first `p` columns of `a` and applies them to every column, in place:
/// on return `a ← Qᵀ a`, its first `p` columns upper triangular with exact
/// zeros below the diagonal. `Q` is orthogonal, so whitened (unit) noise
/// stays unit.
///
/// Each reflection is `H = I − τ v vᵀ` with `v₀ = 1`, mapping the column
/// `x` to `β e₁`, `β = −sign(x₀) ‖x‖`, `τ = (β − x₀)/β`, `v = x / (x₀ − β)`
/// below the first entry (LAPACK's dlarfg convention). Blocked as LAPACK's
/// dgeqrf: a panel of `QR_BLOCK` reflections is formed column by column,
/// written as `H₀ ⋯ H_{b−1} = I − V T Vᵀ` (T upper triangular, dlarft), and
/// applied to the rest of the matrix as two matrix products,
/// `C ← C − V (Tᵀ (Vᵀ C))`. `O(m p n)`. Allocates nothing once this
/// thread's buffers have grown to the largest panel.
pub fn householder_in_place(a: &mut nalgebra::DMatrix<f64>, p: usize) {
    SCRATCH.with(|s| householder_with(a, p, &mut s.borrow_mut()));
}

/// Runs the triangularisation with AVX2 and FMA where the CPU has them,
/// else with the portable kernels (`kernels.rs` says why).
fn householder_with(a: &mut nalgebra::DMatrix<f64>, p: usize, s: &mut Scratch) {
    #[cfg(target_arch = "x86_64")]
    if let Some(k) = super::kernels::Avx2Fma::detect() {
        // SAFETY: `k` exists only where the CPU has AVX2 and FMA.
        unsafe { householder_avx2_fma(k, a, p, s) };
        return;
    }
    householder_body(Portable, a, p, s);
}

/// The triangularisation compiled with AVX2 and FMA enabled, so that the
/// kernels inline into it. Unsafe only as any such function is: the CPU
/// must have the features, which `k` proves.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn householder_avx2_fma(k: super::kernels::Avx2Fma, a: &mut nalgebra::DMatrix<f64>, p: usize, s: &mut Scratch) {
    householder_body(k, a, p, s);
}

#[inline(always)]
fn householder_body<K: Kernels>(k: K, a: &mut nalgebra::DMatrix<f64>, p: usize, s: &mut Scratch) {
    let (m, n) = a.shape();
    let p = p.min(m).min(n);
    // Small matrices (a track's null-space projection) take each reflection
    // straight to every column: there the products' set-up would cost more.
    let blocked = m * n >= QR_BLOCKED_MIN_ENTRIES;
    let mut j0 = 0;
    while j0 < p {
        let jb = if blocked { QR_BLOCK.min(p - j0) } else { p - j0 };
        let apply_end = if blocked { j0 + jb } else { n };
        let rows = m - j0;
        let v = zeroed(&mut s.v, rows * jb);
        let tau = zeroed(&mut s.tau, jb);
        if !reduce_panel(k, a, j0, jb, apply_end, v, tau) {
            return;
        }
        let rest = n - apply_end;
        if rest > 0 {
            apply_block_reflector(k, a, j0, rest, s);
        }
        j0 += jb;
    }
}

/// Forms the `jb` reflections of the panel starting at column `j0`, column
/// by column, each applied at once to the panel's later columns up to
/// `apply_end` (the whole matrix when not blocked), into `v` (`m − j0` ×
/// `jb`, column-major, unit diagonal; zeros on entry) and `tau` (zeros on
/// entry). `false` after poisoning with NaN everything still to be reduced,
/// on a non-finite or overflowing column.
#[inline(always)]
fn reduce_panel<K: Kernels>(
    k: K,
    a: &mut nalgebra::DMatrix<f64>,
    j0: usize,
    jb: usize,
    apply_end: usize,
    v: &mut [f64],
    tau: &mut [f64],
) -> bool {
    let (m, n) = a.shape();
    let rows = m - j0;
    let data = a.as_mut_slice();
    for jj in 0..jb {
        let j = j0 + jj;
        let col = &data[j * m + j..(j + 1) * m];
        let alpha = col[0];
        let sigma = k.dot(&col[1..], &col[1..]);
        let norm = (alpha * alpha + sigma).sqrt();
        if !norm.is_finite() {
            // Non-finite or overflowing entries: poison everything
            // still to be reduced, so the caller's finiteness check
            // rejects the result instead of using a half-reduced one.
            for k in j..n {
                data[k * m + j..(k + 1) * m].fill(f64::NAN);
            }
            return false;
        }
        if sigma == 0.0 {
            // Zero below the diagonal (or underflowing): H = I
            // (τ = 0), and the entries are set to exact zeros.
            data[j * m + j + 1..(j + 1) * m].fill(0.0);
            continue;
        }
        let beta = if alpha <= 0.0 { norm } else { -norm };
        let inv_v0 = 1.0 / (alpha - beta);
        let t = (beta - alpha) / beta;
        tau[jj] = t;
        let vj = &mut v[jj * rows + jj..(jj + 1) * rows];
        vj[0] = 1.0;
        for (vi, ci) in vj[1..].iter_mut().zip(&col[1..]) {
            *vi = ci * inv_v0;
        }
        data[j * m + j] = beta;
        data[j * m + j + 1..(j + 1) * m].fill(0.0);
        // The rest of the panel (or of the matrix), four columns at a
        // time (one pass over `v` serves four), then one by one.
        let vj = &v[jj * rows + jj..(jj + 1) * rows];
        let rest = &mut data[(j + 1) * m..apply_end * m];
        let mut quads = rest.chunks_exact_mut(4 * m);
        for quad in &mut quads {
            let (c01, c23) = quad.split_at_mut(2 * m);
            let (c0, c1) = c01.split_at_mut(m);
            let (c2, c3) = c23.split_at_mut(m);
            let (c0, c1, c2, c3) = (&mut c0[j..], &mut c1[j..], &mut c2[j..], &mut c3[j..]);
            let d = k.dot4(vj, [c0, c1, c2, c3]);
            k.axpy4(d.map(|x| -t * x), vj, [c0, c1, c2, c3]);
        }
        for col in quads.into_remainder().chunks_exact_mut(m) {
            let c = &mut col[j..];
            let s = t * k.dot(vj, c);
            k.axpy(-s, vj, c);
        }
    }
    true
}

/// Applies a panel's reflections `H₀ ⋯ H_{b−1} = I − V T Vᵀ` (`V` and `τ`
/// in `s`, `b = τ.len()`, the panel starting at column `j0`) to the `rest`
/// columns right of it, as two matrix products.
#[inline(always)]
fn apply_block_reflector<K: Kernels>(kern: K, a: &mut nalgebra::DMatrix<f64>, j0: usize, rest: usize, s: &mut Scratch) {
    use nalgebra::{DMatrixView, DMatrixViewMut};
    let rows = a.nrows() - j0;
    let Scratch {
        v,
        tau,
        t,
        t_tr,
        t_col,
        v_tr,
        vtc,
        t_vtc,
    } = s;
    let jb = tau.len();
    let v = &v[..rows * jb];
    // T (dlarft, forward, columnwise), column-major: T_ii = τ_i,
    // T[0..i, i] = −τ_i T[0..i, 0..i] V[:, 0..i]ᵀ v_i.
    let t = zeroed(t, jb * jb);
    for i in 0..jb {
        t[i + i * jb] = tau[i];
        if i == 0 || tau[i] == 0.0 {
            continue;
        }
        // V[:, 0..i]ᵀ v_i, four columns of V to a pass over v_i.
        let vi = &v[i * rows..(i + 1) * rows];
        let w = zeroed(t_col, i);
        let col = |k: usize| &v[k * rows..(k + 1) * rows];
        let mut k = 0;
        while k + 4 <= i {
            let d = kern.dot4(vi, [col(k), col(k + 1), col(k + 2), col(k + 3)]);
            for (wk, dk) in w[k..k + 4].iter_mut().zip(d) {
                *wk = -tau[i] * dk;
            }
            k += 4;
        }
        for (kk, wk) in w.iter_mut().enumerate().skip(k) {
            *wk = -tau[i] * kern.dot(col(kk), vi);
        }
        for r in 0..i {
            t[r + i * jb] = (r..i).map(|k| t[r + k * jb] * w[k]).sum();
        }
    }
    // C ← (I − V T Vᵀ)ᵀ C = C − V (Tᵀ (Vᵀ C)), the transposes formed
    // first so that each product is a plain one (matrixmultiply's kernel).
    let v = DMatrixView::from_slice(v, rows, jb);
    let mut v_tr = DMatrixViewMut::from_slice(zeroed(v_tr, jb * rows), jb, rows);
    v.transpose_to(&mut v_tr);
    let t = DMatrixView::from_slice(t, jb, jb);
    let mut t_tr = DMatrixViewMut::from_slice(zeroed(t_tr, jb * jb), jb, jb);
    t.transpose_to(&mut t_tr);
    let mut c = a.view_mut((j0, j0 + jb), (rows, rest));
    let mut w = DMatrixViewMut::from_slice(zeroed(vtc, jb * rest), jb, rest);
    w.gemm(1.0, &v_tr, &c, 0.0);
    let mut tw = DMatrixViewMut::from_slice(zeroed(t_vtc, jb * rest), jb, rest);
    tw.gemm(1.0, &t_tr, &w, 0.0);
    c.gemm(-1.0, &v, &tw, 1.0);
}

#[cfg(test)]
mod householder_tests {
    use super::*;
    use crate::estimator::math::all_finite;
    use nalgebra::DMatrix;

    /// Each kernel path this CPU can run, as a triangularisation: the
    /// portable one always, AVX2+FMA where detected (so that a CI machine
    /// with AVX2 still tests the path an Atom or arm64 board takes).
    type Triangularise = Box<dyn Fn(&mut DMatrix<f64>, usize)>;

    fn paths() -> Vec<(&'static str, Triangularise)> {
        let mut v: Vec<(&'static str, Triangularise)> = vec![(
            "portable",
            Box::new(|a: &mut DMatrix<f64>, p: usize| householder_body(Portable, a, p, &mut Scratch::default())),
        )];
        #[cfg(target_arch = "x86_64")]
        if let Some(k) = super::super::kernels::Avx2Fma::detect() {
            v.push((
                "avx2+fma",
                Box::new(move |a: &mut DMatrix<f64>, p: usize| {
                    // SAFETY: `k` exists only where the CPU has AVX2 and FMA.
                    unsafe { householder_avx2_fma(k, a, p, &mut Scratch::default()) }
                }),
            ));
        }
        v
    }

    /// `Qᵀ A` keeps `AᵀA` (Q orthogonal), is upper triangular in the
    /// chosen columns, and leaves nothing to the rest: checked against
    /// nalgebra's QR on tall, square, wide and rank-deficient matrices, on
    /// every kernel path; and the paths agree with each other to round-off.
    #[test]
    fn householder_triangularises_and_preserves_the_gram_matrix() {
        for (name, qr) in paths() {
            check_triangularisation(name, &*qr);
        }
        let all = paths();
        if let [(_, a), (_, b), ..] = &all[..] {
            let m0 = DMatrix::from_fn(145, 73, |i, j| (((i * 13 + j * 7) % 19) as f64 - 9.0) / 5.0);
            let (mut x, mut y) = (m0.clone(), m0.clone());
            a(&mut x, 72);
            b(&mut y, 72);
            let err = (&x - &y).abs().max();
            assert!(
                err <= 1e-11 * m0.abs().max() * 145.0,
                "the kernel paths differ by {err}"
            );
        }
    }

    fn check_triangularisation(name: &str, householder: &dyn Fn(&mut DMatrix<f64>, usize)) {
        let cases = [
            (145usize, 73usize, 72usize, false),
            (145, 73, 72, true),
            (22, 67, 3, false),
            (9, 9, 9, true),
            (5, 8, 5, false),
            (40, 10, 10, false),
            (40, 41, 40, false),
            (30, 31, 30, true),
        ];
        for &(m, n, p, deficient) in &cases {
            let mut a = DMatrix::from_fn(m, n, |i, j| {
                (((i * 31 + j * 17) % 23) as f64 - 11.0) / 7.0 + (i as f64 * 0.1).sin()
            });
            if deficient {
                // a repeated column: rank-deficient
                let c0 = a.column(0).into_owned();
                a.column_mut(2).copy_from(&c0);
            }
            let mut q = a.clone();
            householder(&mut q, p);
            for j in 0..p.min(m) {
                for i in j + 1..m {
                    assert_eq!(q[(i, j)], 0.0, "{name}: ({i}, {j}) of {m}×{n}");
                }
            }
            let mut big = a.clone();
            big[(m - 1, 0)] = 1e200;
            householder(&mut big, p);
            assert!(
                !all_finite(big.as_slice()),
                "{name}: {m}×{n}: an overflowing column must poison the result"
            );
            let g0 = a.transpose() * &a;
            let g1 = q.transpose() * &q;
            assert!(
                (&g0 - &g1).abs().max() <= 1e-12 * g0.abs().max(),
                "{name}: {m}×{n}: Gram matrix changed"
            );
            if p + 1 >= n && m >= n && !deficient {
                // |R| agrees with nalgebra's R row by row (signs may differ).
                let r = a.clone().qr().r();
                for i in 0..p {
                    for j in 0..n {
                        assert!((r[(i, j)].abs() - q[(i, j)].abs()).abs() <= 1e-10 * g0.abs().max().sqrt());
                    }
                }
            }
        }
    }
}
