//! Accuracy and consistency metrics against the simulator's truth.
//!
//! - ATE: position RMSE, unaligned and after a 4-DoF (yaw + translation)
//!   alignment, the gauge freedom of visual-inertial odometry.
//! - Rotation RMSE.
//! - NEES for position, orientation and the 6-DoF pose. Orientation errors use
//!   the project's convention, a world-frame (left) perturbation:
//!   `R_true = Exp(δθ) R_est`, so `δθ = Log(R_true R_estᵀ)`; the pose error is
//!   ordered `[δθ, δp]`.
//! - χ² quantiles for the consistency bounds.

use nalgebra::{Matrix3, Matrix6, UnitQuaternion, Vector3, Vector6};

use cmsckf_models::stats::chi2_quantile;

/// Result of the 4-DoF alignment and the position errors.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ate {
    /// Position RMSE without any alignment (m).
    pub unaligned_m: f64,
    /// Position RMSE after the best yaw + translation (m).
    pub aligned_m: f64,
    /// The aligning yaw (rad) and translation (m): `p ≈ Rz(yaw) p_est + t`.
    pub yaw_rad: f64,
    pub t_m: Vector3<f64>,
}

fn rz(yaw: f64) -> Matrix3<f64> {
    let (s, c) = yaw.sin_cos();
    Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
}

/// Closed-form least-squares 4-DoF alignment of `est` onto `truth`: with
/// centred points `e_i`, `g_i`, `yaw = atan2(Σ e×g·z, Σ e_xy·g_xy)`.
pub fn ate(est: &[Vector3<f64>], truth: &[Vector3<f64>]) -> Ate {
    assert_eq!(est.len(), truth.len(), "ATE needs paired samples");
    let n = est.len().max(1) as f64;
    let rmse = |f: &dyn Fn(usize) -> f64| (est.iter().enumerate().map(|(i, _)| f(i)).sum::<f64>() / n).sqrt();
    let unaligned = rmse(&|i| (est[i] - truth[i]).norm_squared());
    let me = est.iter().sum::<Vector3<f64>>() / n;
    let mg = truth.iter().sum::<Vector3<f64>>() / n;
    let (mut sxy, mut sdot) = (0.0, 0.0);
    for (e, g) in est.iter().zip(truth) {
        let (e, g) = (e - me, g - mg);
        sxy += e.x * g.y - e.y * g.x;
        sdot += e.x * g.x + e.y * g.y;
    }
    let yaw = sxy.atan2(sdot);
    let r = rz(yaw);
    let t = mg - r * me;
    let aligned = rmse(&|i| (r * est[i] + t - truth[i]).norm_squared());
    Ate {
        unaligned_m: unaligned,
        aligned_m: aligned,
        yaw_rad: yaw,
        t_m: t,
    }
}

/// Rotation RMSE (deg), after rotating the estimates by `yaw_rad` about the
/// world z axis (pass 0 for unaligned).
pub fn rotation_rmse_deg(est: &[UnitQuaternion<f64>], truth: &[UnitQuaternion<f64>], yaw_rad: f64) -> f64 {
    assert_eq!(est.len(), truth.len());
    let qz = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_rad);
    let n = est.len().max(1) as f64;
    let s: f64 = est.iter().zip(truth).map(|(e, g)| (qz * e).angle_to(g).powi(2)).sum();
    (s / n).sqrt().to_degrees()
}

/// Orientation error `δθ = Log(R_true R_estᵀ)` (world frame).
pub fn orientation_error(est: &UnitQuaternion<f64>, truth: &UnitQuaternion<f64>) -> Vector3<f64> {
    (truth * est.inverse()).scaled_axis()
}

/// `eᵀ P⁻¹ e` via Cholesky; `None` if `P` is not positive definite.
fn mahalanobis<const D: usize>(e: &nalgebra::SVector<f64, D>, p: &nalgebra::SMatrix<f64, D, D>) -> Option<f64> {
    let ch = nalgebra::Cholesky::new(*p)?;
    Some(e.dot(&ch.solve(e)))
}

pub fn nees_position(est: &Vector3<f64>, truth: &Vector3<f64>, p: &Matrix3<f64>) -> Option<f64> {
    mahalanobis(&(truth - est), p)
}

pub fn nees_orientation(est: &UnitQuaternion<f64>, truth: &UnitQuaternion<f64>, p: &Matrix3<f64>) -> Option<f64> {
    mahalanobis(&orientation_error(est, truth), p)
}

/// 6-DoF pose NEES with the covariance ordered `[δθ, δp]`.
pub fn nees_pose(
    est_q: &UnitQuaternion<f64>,
    est_p: &Vector3<f64>,
    truth_q: &UnitQuaternion<f64>,
    truth_p: &Vector3<f64>,
    p: &Matrix6<f64>,
) -> Option<f64> {
    let d = orientation_error(est_q, truth_q);
    let e = Vector6::new(
        d.x,
        d.y,
        d.z,
        truth_p.x - est_p.x,
        truth_p.y - est_p.y,
        truth_p.z - est_p.z,
    );
    mahalanobis(&e, p)
}

/// Two-sided 95% interval for the mean of `n` NEES samples of `dof` degrees
/// of freedom each (the sum is χ² with `n·dof` dof).
pub fn nees_bounds_95(dof: usize, n: usize) -> (f64, f64) {
    let k = dof * n.max(1);
    (
        chi2_quantile(0.025, k) / n.max(1) as f64,
        chi2_quantile(0.975, k) / n.max(1) as f64,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ate_recovers_a_known_yaw_and_offset() {
        let truth: Vec<_> = (0..50)
            .map(|i| Vector3::new(i as f64, (i as f64 * 0.3).sin() * 10.0, -2.0))
            .collect();
        let r = rz(0.3).transpose();
        let est: Vec<_> = truth.iter().map(|p| r * p + Vector3::new(4.0, -1.0, 0.5)).collect();
        let a = ate(&est, &truth);
        assert!((a.yaw_rad - 0.3).abs() < 1e-12);
        assert!(a.aligned_m < 1e-12);
        assert!(a.unaligned_m > 1.0);
        // A pure offset of 1 m along z gives unaligned RMSE 1 m.
        let est2: Vec<_> = truth.iter().map(|p| p + Vector3::new(0.0, 0.0, 1.0)).collect();
        assert!((ate(&est2, &truth).unaligned_m - 1.0).abs() < 1e-12);
    }

    #[test]
    fn rotation_rmse_and_nees_known_values() {
        let t = vec![UnitQuaternion::identity(); 4];
        let e = vec![UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 2f64.to_radians()); 4];
        assert!((rotation_rmse_deg(&e, &t, 0.0) - 2.0).abs() < 1e-9);
        // δp = (1, 0, 0) with P = diag(4, 1, 1) → NEES 0.25.
        let p = Matrix3::from_diagonal(&Vector3::new(4.0, 1.0, 1.0));
        assert!((nees_position(&Vector3::zeros(), &Vector3::x(), &p).unwrap() - 0.25).abs() < 1e-12);
        // Orientation error of 0.1 rad about z with σ = 0.1 rad → NEES 1.
        let q = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.1);
        let po = Matrix3::identity() * 0.01;
        assert!((nees_orientation(&UnitQuaternion::identity(), &q, &po).unwrap() - 1.0).abs() < 1e-9);
        let p6 = Matrix6::identity() * 0.01;
        let n6 = nees_pose(
            &UnitQuaternion::identity(),
            &Vector3::zeros(),
            &q,
            &Vector3::new(0.0, 0.1, 0.0),
            &p6,
        )
        .unwrap();
        assert!((n6 - 2.0).abs() < 1e-9);
        assert!(nees_position(&Vector3::zeros(), &Vector3::x(), &Matrix3::zeros()).is_none());
    }

    #[test]
    fn nees_bounds() {
        let (lo, hi) = nees_bounds_95(3, 10);
        assert!(lo < 3.0 && hi > 3.0 && (hi - 4.698).abs() < 0.02, "{lo} {hi}");
    }
}
