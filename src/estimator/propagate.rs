//! IMU propagation of the nominal state (RK4), the error-state transition
//! `F` and the discrete process noise `Q` (README.md §2).
//!
//! Error state of the IMU, in this order (15): `[δθ, δv, δp, δb_g, δb_a]`,
//! with the world-frame (left) rotation perturbation `R = Exp(δθ) R̂`.

use nalgebra::{SMatrix, UnitQuaternion, Vector3};

use super::math::{exp_so3, skew};
use crate::config::ImuConfig;

pub type Mat15 = SMatrix<f64, 15, 15>;

/// Offsets of the IMU error-state blocks.
pub const TH: usize = 0;
pub const V: usize = 3;
pub const P: usize = 6;
pub const BG: usize = 9;
pub const BA: usize = 12;
pub const IMU_DIM: usize = 15;

/// Nominal IMU state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuState {
    pub q_W_B: UnitQuaternion<f64>,
    pub v_B_in_W: Vector3<f64>,
    pub p_B_in_W: Vector3<f64>,
    pub b_g: Vector3<f64>,
    pub b_a: Vector3<f64>,
}

/// One IMU measurement in the body frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuMeas {
    pub t_s: f64,
    pub accel_mps2: Vector3<f64>,
    pub gyro_radps: Vector3<f64>,
}

impl ImuMeas {
    /// Linear interpolation between two samples at time `t_s`.
    pub fn lerp(a: &ImuMeas, b: &ImuMeas, t_s: f64) -> ImuMeas {
        let span = b.t_s - a.t_s;
        let f = if span > 0.0 {
            ((t_s - a.t_s) / span).clamp(0.0, 1.0)
        } else {
            1.0
        };
        ImuMeas {
            t_s,
            accel_mps2: a.accel_mps2 + (b.accel_mps2 - a.accel_mps2) * f,
            gyro_radps: a.gyro_radps + (b.gyro_radps - a.gyro_radps) * f,
        }
    }
}

/// Integrates the nominal state from `m0.t_s` to `m1.t_s` with RK4
/// (README §2, eq. N1), the measurements linearly interpolated in between:
/// `Ṙ = R [ω_m − b_g]×`, `v̇ = R (a_m − b_a) + g`, `ṗ = v`.
pub fn integrate(x: &ImuState, m0: &ImuMeas, m1: &ImuMeas, g_W: &Vector3<f64>) -> ImuState {
    let dt = m1.t_s - m0.t_s;
    let w0 = m0.gyro_radps - x.b_g;
    let w1 = m1.gyro_radps - x.b_g;
    let wh = (w0 + w1) * 0.5;
    let a0 = m0.accel_mps2 - x.b_a;
    let a1 = m1.accel_mps2 - x.b_a;
    let ah = (a0 + a1) * 0.5;
    // Rotation over each half step with the mean rate of that half.
    let q0 = x.q_W_B;
    let qh = q0 * exp_so3(&((w0 + wh) * (0.25 * dt)));
    let q1 = qh * exp_so3(&((wh + w1) * (0.25 * dt)));
    let acc = |q: &UnitQuaternion<f64>, a: &Vector3<f64>| q * a + g_W;
    let k1v = acc(&q0, &a0);
    let k1p = x.v_B_in_W;
    let k2v = acc(&qh, &ah);
    let k2p = x.v_B_in_W + k1v * (0.5 * dt);
    let k3v = k2v;
    let k3p = x.v_B_in_W + k2v * (0.5 * dt);
    let k4v = acc(&q1, &a1);
    let k4p = x.v_B_in_W + k3v * dt;
    ImuState {
        q_W_B: q1,
        v_B_in_W: x.v_B_in_W + (k1v + k2v * 2.0 + k3v * 2.0 + k4v) * (dt / 6.0),
        p_B_in_W: x.p_B_in_W + (k1p + k2p * 2.0 + k3p * 2.0 + k4p) * (dt / 6.0),
        b_g: x.b_g,
        b_a: x.b_a,
    }
}

/// Error-state transition and discrete noise over one step (README §2,
/// eqs. F1–F3 and Q1). Continuous model: `δθ̇ = −R δb_g − R n_g`,
/// `δv̇ = −[R a]× δθ − R δb_a − R n_a`, `δṗ = δv`, `δḃ_g = n_wg`,
/// `δḃ_a = n_wa`. The transition's blocks are the exact integrals of this
/// model along the step, `F_vθ = −[∫R a]×`, `F_pθ = −[∫(Δt−τ) R a]×`,
/// `F_θb_g = F_vb_a = −∫R`, …, evaluated with Simpson's rule on the start,
/// middle and end of the step.
pub fn transition(x: &ImuState, m0: &ImuMeas, m1: &ImuMeas, imu: &ImuConfig) -> (Mat15, Mat15) {
    let dt = m1.t_s - m0.t_s;
    let w0 = m0.gyro_radps - x.b_g;
    let w1 = m1.gyro_radps - x.b_g;
    let wh = (w0 + w1) * 0.5;
    let a0 = m0.accel_mps2 - x.b_a;
    let a1 = m1.accel_mps2 - x.b_a;
    let ah = (a0 + a1) * 0.5;
    let q0 = x.q_W_B;
    let qh = q0 * exp_so3(&((w0 + wh) * (0.25 * dt)));
    let q1 = qh * exp_so3(&((wh + w1) * (0.25 * dt)));
    let (r0, rh, r1) = (
        q0.to_rotation_matrix().into_inner(),
        qh.to_rotation_matrix().into_inner(),
        q1.to_rotation_matrix().into_inner(),
    );
    let (f0, fh, f1) = (r0 * a0, rh * ah, r1 * a1);
    // ∫R, ∫R a, ∫(Δt−τ) R, ∫(Δt−τ) R a over the step (Simpson).
    let int_r = (r0 + rh * 4.0 + r1) * (dt / 6.0);
    let int_ra = (f0 + fh * 4.0 + f1) * (dt / 6.0);
    let int2_r = (r0 * dt + rh * (2.0 * dt)) * (dt / 6.0);
    let int2_ra = (f0 * dt + fh * (2.0 * dt)) * (dt / 6.0);
    // g(τ) = [R a]×(τ) ∫₀^τ R: the velocity response to a gyro-bias error.
    let g_h = skew(&fh) * ((r0 + rh) * (0.25 * dt));
    let g_1 = skew(&f1) * int_r;
    let f_vbg = (g_h * 4.0 + g_1) * (dt / 6.0);
    let f_pbg = g_h * (dt * dt / 3.0);
    let mut f = Mat15::identity();
    f.fixed_view_mut::<3, 3>(TH, BG).copy_from(&(-int_r));
    f.fixed_view_mut::<3, 3>(V, TH).copy_from(&(-skew(&int_ra)));
    f.fixed_view_mut::<3, 3>(V, BG).copy_from(&f_vbg);
    f.fixed_view_mut::<3, 3>(V, BA).copy_from(&(-int_r));
    f.fixed_view_mut::<3, 3>(P, TH).copy_from(&(-skew(&int2_ra)));
    f.fixed_view_mut::<3, 3>(P, V)
        .copy_from(&(nalgebra::Matrix3::identity() * dt));
    f.fixed_view_mut::<3, 3>(P, BG).copy_from(&f_pbg);
    f.fixed_view_mut::<3, 3>(P, BA).copy_from(&(-int2_r));
    // Q = ∫ F(τ) G Qc Gᵀ F(τ)ᵀ dτ, to the leading order of each block.
    let sg2 = imu.gyro_noise_density.powi(2);
    let sa2 = imu.accel_noise_density.powi(2);
    let swg2 = imu.gyro_random_walk.powi(2);
    let swa2 = imu.accel_random_walk.powi(2);
    let mut q = Mat15::zeros();
    for i in 0..3 {
        q[(TH + i, TH + i)] = sg2 * dt;
        q[(V + i, V + i)] = sa2 * dt;
        q[(P + i, P + i)] = sa2 * dt * dt * dt / 3.0;
        q[(P + i, V + i)] = sa2 * dt * dt / 2.0;
        q[(V + i, P + i)] = sa2 * dt * dt / 2.0;
        q[(BG + i, BG + i)] = swg2 * dt;
        q[(BA + i, BA + i)] = swa2 * dt;
    }
    (f, q)
}

/// The error `x_true ⊖ x_est` in the IMU error-state order.
pub fn boxminus(x_true: &ImuState, x_est: &ImuState) -> SMatrix<f64, 15, 1> {
    let mut e = SMatrix::<f64, 15, 1>::zeros();
    e.fixed_rows_mut::<3>(TH)
        .copy_from(&(x_true.q_W_B * x_est.q_W_B.inverse()).scaled_axis());
    e.fixed_rows_mut::<3>(V).copy_from(&(x_true.v_B_in_W - x_est.v_B_in_W));
    e.fixed_rows_mut::<3>(P).copy_from(&(x_true.p_B_in_W - x_est.p_B_in_W));
    e.fixed_rows_mut::<3>(BG).copy_from(&(x_true.b_g - x_est.b_g));
    e.fixed_rows_mut::<3>(BA).copy_from(&(x_true.b_a - x_est.b_a));
    e
}

/// `x ⊕ δx` for the IMU block.
pub fn boxplus(x: &ImuState, d: &[f64]) -> ImuState {
    let v3 = |o: usize| Vector3::new(d[o], d[o + 1], d[o + 2]);
    ImuState {
        q_W_B: exp_so3(&v3(TH)) * x.q_W_B,
        v_B_in_W: x.v_B_in_W + v3(V),
        p_B_in_W: x.p_B_in_W + v3(P),
        b_g: x.b_g + v3(BG),
        b_a: x.b_a + v3(BA),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// F against finite differences: perturb the start state along each
    /// error direction, integrate, and take the error at the end.
    #[test]
    fn transition_matches_finite_differences() {
        let x = ImuState {
            q_W_B: UnitQuaternion::from_euler_angles(0.2, -0.3, 1.1),
            v_B_in_W: Vector3::new(12.0, -3.0, 0.5),
            p_B_in_W: Vector3::new(100.0, 20.0, -5.0),
            b_g: Vector3::new(0.01, -0.02, 0.005),
            b_a: Vector3::new(0.1, -0.05, 0.2),
        };
        let g = Vector3::new(0.0, 0.0, 9.81);
        let m0 = ImuMeas {
            t_s: 0.0,
            accel_mps2: Vector3::new(1.0, 2.5, -9.0),
            gyro_radps: Vector3::new(0.3, -0.4, 0.8),
        };
        let m1 = ImuMeas {
            t_s: 0.01,
            accel_mps2: Vector3::new(1.2, 2.2, -9.3),
            gyro_radps: Vector3::new(0.35, -0.38, 0.75),
        };
        let (f, _) = transition(&x, &m0, &m1, &ImuConfig::default());
        let x1 = integrate(&x, &m0, &m1, &g);
        let h = 1e-6;
        for k in 0..15 {
            let mut d = [0.0; 15];
            d[k] = h;
            let xp = integrate(&boxplus(&x, &d), &m0, &m1, &g);
            d[k] = -h;
            let xm = integrate(&boxplus(&x, &d), &m0, &m1, &g);
            let col = (boxminus(&xp, &x1) - boxminus(&xm, &x1)) / (2.0 * h);
            let err = (col - f.column(k)).amax();
            // Within 2e-7: the O(|ω|Δt²) right-Jacobian terms of ∂R/∂b_g are neglected.
            assert!(
                err < 2e-7,
                "column {k}: fd {:?} vs analytic {:?}",
                col.as_slice(),
                f.column(k).iter().collect::<Vec<_>>()
            );
        }
    }
}
