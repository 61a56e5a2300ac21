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
