//! Small SO(3) helpers used throughout the estimator (see README.md, §1).

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

#[cfg(test)]
mod tests {
    use super::*;

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

/// Rows per block of the blocked triangular solves.
const TRI_BLOCK: usize = 32;

/// Solves `L X = B` in place (`L` lower triangular with a nonzero diagonal).
/// Blocked: each block of rows is one matrix product (matrixmultiply) and a
/// small triangular solve, several times faster than solving column by
/// column when `B` has many columns.
pub fn solve_lower_in_place(l: &nalgebra::DMatrix<f64>, b: &mut nalgebra::DMatrix<f64>) {
    let n = l.nrows();
    let mut r0 = 0;
    while r0 < n {
        let bs = TRI_BLOCK.min(n - r0);
        if r0 > 0 {
            // B_i ← B_i − L_i,<i X_<i
            let (done, mut cur) = b.rows_range_pair_mut(0..r0, r0..r0 + bs);
            cur.gemm(-1.0, &l.view((r0, 0), (bs, r0)), &done, 1.0);
        }
        apply_block_inverse(&l.view((r0, r0), (bs, bs)).into_owned(), b, r0, false);
        r0 += bs;
    }
}

/// `B[r0..r0+k] ← L_kk⁻¹ B[r0..r0+k]` (or `L_kk⁻ᵀ`) for a diagonal block:
/// the block's inverse (a k×k triangular solve) applied as one product.
fn apply_block_inverse(lkk: &nalgebra::DMatrix<f64>, b: &mut nalgebra::DMatrix<f64>, r0: usize, transpose: bool) {
    let k = lkk.nrows();
    let eye = nalgebra::DMatrix::identity(k, k);
    let inv = if transpose {
        lkk.tr_solve_lower_triangular(&eye)
    } else {
        lkk.solve_lower_triangular(&eye)
    };
    // A zero pivot: leave the rows (the caller's Cholesky factor has none).
    let Some(inv) = inv else { return };
    let cur = &inv * b.rows(r0, k);
    b.rows_mut(r0, k).copy_from(&cur);
}

/// Solves `Lᵀ X = B` in place (`L` lower triangular with a nonzero
/// diagonal), blocked as [`solve_lower_in_place`].
pub fn solve_lower_transpose_in_place(l: &nalgebra::DMatrix<f64>, b: &mut nalgebra::DMatrix<f64>) {
    let n = l.nrows();
    let mut r1 = n;
    while r1 > 0 {
        let bs = TRI_BLOCK.min(r1);
        let r0 = r1 - bs;
        if r1 < n {
            // B_i ← B_i − (L_>i,i)ᵀ X_>i
            let lt = l.view((r1, r0), (n - r1, bs)).transpose();
            let (mut cur, done) = b.rows_range_pair_mut(r0..r1, r1..n);
            cur.gemm(-1.0, &lt, &done, 1.0);
        }
        apply_block_inverse(&l.view((r0, r0), (bs, bs)).into_owned(), b, r0, true);
        r1 = r0;
    }
}

#[cfg(test)]
mod tri_tests {
    use super::*;
    use nalgebra::DMatrix;

    /// The blocked solves agree with nalgebra's column-by-column ones, over
    /// sizes that cross block edges.
    #[test]
    fn blocked_triangular_solves_match_the_reference() {
        for &n in &[1usize, 7, 32, 33, 70, 131] {
            let m = DMatrix::from_fn(n, n, |i, j| ((i * 7 + j * 13) % 17) as f64 / 17.0 - 0.4);
            let spd = &m * m.transpose() + DMatrix::identity(n, n) * (n as f64);
            let l = spd.cholesky().unwrap().l();
            let b = DMatrix::from_fn(n, 9, |i, j| ((i * 3 + j * 5) % 11) as f64 - 5.0);
            let mut x = b.clone();
            solve_lower_in_place(&l, &mut x);
            let want = l.solve_lower_triangular(&b).unwrap();
            assert!((&x - &want).abs().max() <= 1e-12 * want.abs().max().max(1.0), "n {n}");
            let mut y = b.clone();
            solve_lower_transpose_in_place(&l, &mut y);
            let want = l.tr_solve_lower_triangular(&b).unwrap();
            assert!((&y - &want).abs().max() <= 1e-12 * want.abs().max().max(1.0), "n {n}");
        }
    }
}
