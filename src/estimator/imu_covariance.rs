//! The IMU error state's covariance by name: its priors, the blocks the
//! outputs need, and a restart's inflation. The layout
//! `[δθ, δv, δp, δb_g, δb_a]` (`propagate::TH`, `V`, `P`, `BG`, `BA`) is
//! the estimator's own; the daemon and the config ask for blocks and
//! priors here, so no index of it leaves `src/estimator`.

use nalgebra::{Matrix3, Matrix6, SMatrix};

use super::propagate::{BA, BG, P, TH, V};
use super::Mat15;

/// One-sigma priors of the IMU state, each per axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuPrior {
    /// Roll and pitch (rad).
    pub tilt_rad: f64,
    pub yaw_rad: f64,
    pub velocity_mps: f64,
    pub position_m: f64,
    pub gyro_bias_radps: f64,
    pub accel_bias_mps2: f64,
}

impl ImuPrior {
    /// The diagonal covariance of these priors.
    pub fn covariance(&self) -> Mat15 {
        let mut p = Mat15::zeros();
        let sigmas = [
            (TH, [self.tilt_rad, self.tilt_rad, self.yaw_rad]),
            (V, [self.velocity_mps; 3]),
            (P, [self.position_m; 3]),
            (BG, [self.gyro_bias_radps; 3]),
            (BA, [self.accel_bias_mps2; 3]),
        ];
        for (o, s) in sigmas {
            for k in 0..3 {
                p[(o + k, o + k)] = s[k] * s[k];
            }
        }
        p
    }
}

/// Sets the yaw's variance (rad²).
pub fn set_yaw_variance(p: &mut Mat15, var_rad2: f64) {
    p[(TH + 2, TH + 2)] = var_rad2;
}

/// Sets the position's variances, north, east, down (m²).
pub fn set_position_variances(p: &mut Mat15, var_m2: [f64; 3]) {
    for (k, v) in var_m2.into_iter().enumerate() {
        p[(P + k, P + k)] = v;
    }
}

/// An in-flight start's looser prior (§7, eq. I1): the attitude's
/// variances ×4 (the autopilot's attitude, not a still window), the
/// velocity's σ 0.2 m/s (the autopilot's own estimate), and the gyro bias's
/// σ `sigma_gyro_bias_radps` (no still window measured it: the sensor's
/// specification).
pub fn loosen_for_flight(p: &mut Mat15, sigma_gyro_bias_radps: f64) {
    for k in 0..3 {
        p[(TH + k, TH + k)] *= 4.0;
        p[(V + k, V + k)] = 0.2f64.powi(2);
        p[(BG + k, BG + k)] = p[(BG + k, BG + k)].max(sigma_gyro_bias_radps.powi(2));
    }
}

/// A carried estimate's covariance inflated for a restart (eq. I3 of
/// `src/estimator/README.md`): the position by σ_r² + (σ_v·Δt)² and the
/// velocity by σ_v², for the restart sigmas σ_r, σ_v and the time Δt that
/// no IMU sample covers; the tilt by the prior's tilt variance; the biases
/// raised to at least their priors.
pub fn inflate_for_restart(p: &Mat15, prior: &Mat15, dt_s: f64, sigma_r_m: f64, sigma_v_mps: f64) -> Mat15 {
    let mut p = *p;
    for k in 0..3 {
        p[(P + k, P + k)] += sigma_r_m.powi(2) + (sigma_v_mps * dt_s).powi(2);
        p[(V + k, V + k)] += sigma_v_mps.powi(2);
        p[(TH + k, TH + k)] += prior[(TH, TH)];
        for o in [BG, BA] {
            p[(o + k, o + k)] = p[(o + k, o + k)].max(prior[(o + k, o + k)]);
        }
    }
    p
}

/// The body pose's covariance, `[δθ, δp]` (6×6).
pub fn pose_block(p: &Mat15) -> Matrix6<f64> {
    let idx = [TH, TH + 1, TH + 2, P, P + 1, P + 2];
    Matrix6::from_fn(|i, j| p[(idx[i], idx[j])])
}

/// The position's covariance (3×3, world frame).
pub fn position_block(p: &Mat15) -> Matrix3<f64> {
    p.fixed_view::<3, 3>(P, P).into_owned()
}

/// The velocity's covariance (3×3, world frame).
pub fn velocity_block(p: &Mat15) -> Matrix3<f64> {
    p.fixed_view::<3, 3>(V, V).into_owned()
}

/// The covariance of `[δθ, δv, δb_g]` (9×9), which the body velocity and
/// rate's covariance is mapped from.
pub fn attitude_velocity_gyro_bias_block(p: &Mat15) -> SMatrix<f64, 9, 9> {
    let idx = [TH, TH + 1, TH + 2, V, V + 1, V + 2, BG, BG + 1, BG + 2];
    SMatrix::<f64, 9, 9>::from_fn(|i, j| p[(idx[i], idx[j])])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn prior() -> ImuPrior {
        ImuPrior {
            tilt_rad: 0.02,
            yaw_rad: 0.1,
            velocity_mps: 0.5,
            position_m: 1.0,
            gyro_bias_radps: 0.01,
            accel_bias_mps2: 0.1,
        }
    }

    #[test]
    fn blocks_are_the_named_states() {
        let p = Mat15::from_fn(|i, j| (100 * i + j) as f64);
        let pose = pose_block(&p);
        assert_eq!(pose[(0, 0)], p[(TH, TH)]);
        assert_eq!(pose[(3, 5)], p[(P, P + 2)]);
        assert_eq!(pose[(5, 2)], p[(P + 2, TH + 2)]);
        let b = attitude_velocity_gyro_bias_block(&p);
        assert_eq!(b[(4, 7)], p[(V + 1, BG + 1)]);
        assert_eq!(b[(8, 0)], p[(BG + 2, TH)]);
    }

    #[test]
    fn priors_set_and_inflate_their_own_states() {
        let mut p = prior().covariance();
        assert_eq!(p[(TH + 2, TH + 2)], 0.1 * 0.1);
        assert_eq!(p[(BA + 1, BA + 1)], 0.1 * 0.1);
        set_yaw_variance(&mut p, 0.04);
        set_position_variances(&mut p, [4.0, 4.0, 9.0]);
        assert_eq!((p[(TH + 2, TH + 2)], p[(P + 2, P + 2)]), (0.04, 9.0));
        let before = p;
        loosen_for_flight(&mut p, 0.05);
        assert_eq!(p[(TH, TH)], 4.0 * before[(TH, TH)]);
        assert_eq!(p[(BG + 2, BG + 2)], 0.05 * 0.05);
        assert!((p[(V + 1, V + 1)] - 0.04).abs() < 1e-15);
        let small = Mat15::identity() * 1e-8;
        let q = inflate_for_restart(&small, &prior().covariance(), 2.0, 3.0, 0.5);
        assert!((q[(P, P)] - (1e-8 + 9.0 + 1.0)).abs() < 1e-12);
        assert!((q[(V, V)] - (1e-8 + 0.25)).abs() < 1e-12);
        assert_eq!(q[(BG, BG)], 0.01 * 0.01, "raised to its prior");
        assert_eq!(q[(BA + 2, BA + 2)], 0.1 * 0.1);
    }
}
