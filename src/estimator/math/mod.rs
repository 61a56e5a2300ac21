//! The estimator's numerical kernels: the SO(3) helpers of README §1, and
//! the dense linear algebra the updates are built from (blocked triangular
//! solves and Cholesky, §3 U1, in `triangular`; the Householder
//! triangularisation of §3 N1/Q1 in `qr`; gathers, dot products and
//! finiteness checks here).
//!
//! Why it exists: the filter's cost is in a few dense kernels whose
//! results must not change but by round-off; keeping them here, apart from the
//! filter logic, lets them be tested against nalgebra's references and
//! tuned without touching the equations that use them.

mod kernels;
mod qr;
mod triangular;

pub use qr::householder_in_place;
pub use triangular::{
    add_gram_outside_block, add_symmetric_product, add_symmetric_product_t, cholesky_lower_in_place,
    lower_of_times_upper_t, upper_mul, LowerSolver,
};

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

/// `[v]×`, the cross-product matrix: `[a]× b = a × b`.
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// `Exp(φ)` as a unit quaternion.
pub fn exp_so3(phi: &Vector3<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::from_scaled_axis(*phi)
}

/// Left Jacobian of SO(3) (README §1, eq. J_l):
/// `Exp(φ + ε) ≈ Exp(J_l(φ) ε) Exp(φ)`,
/// `J_l(φ) = I + (1 − cos θ)/θ² [φ]× + (θ − sin θ)/θ³ [φ]×²`.
pub fn left_jacobian(phi: &Vector3<f64>) -> Matrix3<f64> {
    let th = phi.norm();
    let k = skew(phi);
    if th < 1e-6 {
        return Matrix3::identity() + k * 0.5 + k * k / 6.0;
    }
    let th2 = th * th;
    Matrix3::identity() + k * ((1.0 - th.cos()) / th2) + k * k * ((th - th.sin()) / (th2 * th))
}

/// Buffers kept only so that a hot path need not allocate them again: their
/// contents are scratch, so a clone of the filter starts with empty ones
/// (`T::default()`) and its debug form shows none of them.
#[derive(Default)]
pub struct Scratch<T>(pub T);

impl<T: Default> Clone for Scratch<T> {
    fn clone(&self) -> Self {
        Self::default()
    }
}

impl<T> std::fmt::Debug for Scratch<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Scratch")
    }
}

/// `buf` as `len` zeros, its capacity kept.
fn zeroed(buf: &mut Vec<f64>, len: usize) -> &mut [f64] {
    buf.clear();
    buf.resize(len, 0.0);
    buf.as_mut_slice()
}

/// `m` as an `r × c` matrix of zeros, in its own buffer: nothing is
/// allocated once the buffer has grown to `r·c` (the per-track matrices of
/// the gates are reshaped this way, issue 43).
pub fn reshape_zeroed(m: &mut nalgebra::DMatrix<f64>, r: usize, c: usize) {
    let mut buf: Vec<f64> = std::mem::replace(m, nalgebra::DMatrix::zeros(0, 0)).data.into();
    zeroed(&mut buf, r * c);
    *m = nalgebra::DMatrix::from_vec(r, c, buf);
}

/// `v` as `n` zeros, in its own buffer (as [`reshape_zeroed`]).
pub fn reshape_zeroed_vector(v: &mut nalgebra::DVector<f64>, n: usize) {
    let mut buf: Vec<f64> = std::mem::replace(v, nalgebra::DVector::zeros(0)).data.into();
    zeroed(&mut buf, n);
    *v = nalgebra::DVector::from_vec(buf);
}

/// The block of `a` at `(r0, c0)` of size `nr × nc`, copied column by
/// column (nalgebra's `into_owned` of a view goes element by element).
pub fn block_owned(a: &nalgebra::DMatrix<f64>, r0: usize, c0: usize, nr: usize, nc: usize) -> nalgebra::DMatrix<f64> {
    let m = a.nrows();
    let mut out = nalgebra::DMatrix::zeros(nr, nc);
    for (k, dst) in out.as_mut_slice().chunks_exact_mut(nr.max(1)).take(nc).enumerate() {
        let src = (c0 + k) * m + r0;
        dst.copy_from_slice(&a.as_slice()[src..src + nr]);
    }
    out
}

/// `out[..k, ..k] = src[idx, idx]` (`k = idx.len()`), copying runs of
/// consecutive indices as slices: a track's columns are pose blocks of 6
/// with its clones adjacent, and live global blocks are mostly contiguous.
pub fn gather_block(src: &nalgebra::DMatrix<f64>, idx: &[usize], out: &mut nalgebra::DMatrix<f64>) {
    let (ms, mo) = (src.nrows(), out.nrows());
    let (s, o) = (src.as_slice(), out.as_mut_slice());
    for (c, &sc) in idx.iter().enumerate() {
        let mut r = 0;
        while r < idx.len() {
            let mut len = 1;
            while r + len < idx.len() && idx[r + len] == idx[r] + len {
                len += 1;
            }
            let from = sc * ms + idx[r];
            o[c * mo + r..c * mo + r + len].copy_from_slice(&s[from..from + len]);
            r += len;
        }
    }
}

/// `b ← L⁻¹ b` for the lower-triangular `l` of [`cholesky_lower_in_place`]
/// (forward substitution, column by column of `b`).
pub fn solve_lower_in_place(l: &nalgebra::DMatrix<f64>, b: &mut nalgebra::DMatrix<f64>) {
    let n = l.nrows();
    let ls = l.as_slice();
    for col in b.as_mut_slice().chunks_exact_mut(n.max(1)) {
        for j in 0..n {
            let x = col[j] / ls[j * n + j];
            col[j] = x;
            if x != 0.0 {
                axpy(-x, &ls[j * n + j + 1..(j + 1) * n], &mut col[j + 1..]);
            }
        }
    }
}

/// Whether every entry is finite, without an early exit so that it runs
/// as vector code: `x · 0` is zero for a finite `x` and NaN otherwise.
pub fn all_finite(x: &[f64]) -> bool {
    let mut acc = [0.0f64; 8];
    let c = x.chunks_exact(8);
    let rest = c.remainder();
    for v in c {
        for k in 0..8 {
            acc[k] += v[k] * 0.0;
        }
    }
    acc.iter().chain(rest).all(|a| (a * 0.0) == 0.0)
}

/// `Σ aᵢ bᵢ` over the common length, with eight partial sums so the
/// compiler can keep them in vector registers.
#[inline]
pub fn dot(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [0.0f64; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for k in 0..8 {
            acc[k] += x[k] * y[k];
        }
    }
    let mut s = ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7]));
    for (x, y) in ra.iter().zip(rb) {
        s += x * y;
    }
    s
}

/// `y ← y + α x` over the common length.
#[inline]
pub fn axpy(alpha: f64, x: &[f64], y: &mut [f64]) {
    for (yi, xi) in y.iter_mut().zip(x) {
        *yi += alpha * xi;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The gate's small Cholesky: `L Lᵀ` gives back the lower triangle of
    /// an SPD matrix, the forward solve inverts `L`, and a matrix that is
    /// not positive definite (indefinite, or with a NaN) is refused.
    #[test]
    fn small_cholesky_factors_solves_and_refuses() {
        for n in [1usize, 2, 5, 22, 37] {
            let g = nalgebra::DMatrix::from_fn(n, n, |i, j| ((i * 7 + j * 13) % 17) as f64 / 9.0 - 0.8);
            let a = &g * g.transpose() + nalgebra::DMatrix::identity(n, n);
            // The upper triangle is neither read nor written: NaN there.
            let mut l = a.lower_triangle();
            for j in 1..n {
                for i in 0..j {
                    l[(i, j)] = f64::NAN;
                }
            }
            assert!(cholesky_lower_in_place(&mut l), "n = {n}");
            let b = nalgebra::DMatrix::from_fn(n, 3, |i, j| (i + 2 * j) as f64 - 1.5);
            let mut x = b.clone();
            solve_lower_in_place(&l, &mut x);
            for j in 1..n {
                for i in 0..j {
                    assert!(l[(i, j)].is_nan(), "n = {n}: ({i}, {j}) written");
                }
            }
            let l = l.lower_triangle();
            assert!((&l * l.transpose() - &a).amax() <= 1e-12 * a.amax(), "n = {n}");
            assert!((&l * &x - &b).amax() <= 1e-11 * b.amax().max(1.0), "n = {n}");
            let mut bad = a.clone();
            bad[(n - 1, n - 1)] = -1.0;
            assert!(!cholesky_lower_in_place(&mut bad), "indefinite, n = {n}");
            let mut nan = a.clone();
            nan[(n / 2, 0)] = f64::NAN;
            nan[(0, n / 2)] = f64::NAN;
            assert!(!cholesky_lower_in_place(&mut nan), "NaN, n = {n}");
        }
    }

    #[test]
    fn left_jacobian_matches_finite_differences() {
        for phi in [
            Vector3::new(0.3, -0.2, 0.1),
            Vector3::new(1e-8, 0.0, 2e-8),
            Vector3::new(-1.0, 2.0, 0.5),
        ] {
            let jl = left_jacobian(&phi);
            let base = exp_so3(&phi);
            let h = 1e-6;
            for k in 0..3 {
                let mut e = Vector3::zeros();
                e[k] = h;
                // Exp(φ+ε) Exp(φ)ᵀ = Exp(J_l ε)
                let plus = (exp_so3(&(phi + e)) * base.inverse()).scaled_axis();
                let minus = (exp_so3(&(phi - e)) * base.inverse()).scaled_axis();
                let col = (plus - minus) / (2.0 * h);
                assert!((col - jl.column(k)).norm() < 1e-8, "{col} vs {}", jl.column(k));
            }
        }
    }
}
