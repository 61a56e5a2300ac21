//! An estimate as the autopilot gets it: `ODOMETRY`, or
//! `VISION_POSITION_ESTIMATE` with `VISION_SPEED_ESTIMATE`
//! (`output.message`; one source of the pose, never two), their
//! covariances (mapped from the filter's through the Jacobians below, and
//! written as ArduPilot or PX4 read them) and `ODOMETRY.quality`.

use nalgebra::{Matrix3, Matrix6, SMatrix, UnitQuaternion, Vector3};

use crate::config::{OutputMessage, PoseCovariance};
use crate::estimator::imu_covariance::{attitude_velocity_gyro_bias_block, pose_block, velocity_block};
use crate::estimator::math::skew;
use crate::estimator::{ImuState, Mat15};
use crate::io::messages::Outbound;
// Nothing fused for this long: dead reckoning, as the status says it.
use crate::status::DEAD_RECKONING_S;

/// Euler (ZYX) angles of `q` and the map `M` from `[droll, dpitch, dyaw]` to
/// the world-frame rotation error: `δθ = dyaw ẑ + dpitch Rz ŷ + droll Rz Ry x̂`.
fn euler_and_map(q: &UnitQuaternion<f64>) -> (Vector3<f64>, Matrix3<f64>) {
    let (r, p, y) = q.euler_angles();
    let rz = UnitQuaternion::from_euler_angles(0.0, 0.0, y);
    let rzy = UnitQuaternion::from_euler_angles(0.0, p, y);
    let m = Matrix3::from_columns(&[rzy * Vector3::x(), rz * Vector3::y(), Vector3::z()]);
    (Vector3::new(r, p, y), m)
}

/// Upper triangle, row-major, of a 6×6 matrix (MAVLink's 21-float layout).
pub fn upper21(c: &Matrix6<f64>) -> [f32; 21] {
    let mut out = [0.0f32; 21];
    let mut k = 0;
    for i in 0..6 {
        for j in i..6 {
            out[k] = c[(i, j)] as f32;
            k += 1;
        }
    }
    out
}

/// The filter at one output instant: what the messages are made of.
#[derive(Clone, Debug)]
pub struct OutputState {
    /// Autopilot time of the IMU sample the estimate is predicted to (s).
    pub t_s: f64,
    /// The state predicted to `t_s`.
    pub x: ImuState,
    /// The IMU block of the covariance, `[δθ δv δp δb_g δb_a]` (rotation
    /// errors in the world frame, `R = Exp(δθ) R̂`).
    pub imu_cov: Mat15,
    /// That sample's gyro reading (rad/s, body FRD).
    pub gyro_radps: Vector3<f64>,
    /// The white-noise variance of one gyro reading, per axis (rad²/s²).
    pub gyro_var: f64,
    pub reset_counter: u8,
    /// `ODOMETRY.quality`: see [`quality`].
    pub quality: i8,
    /// How the pose covariance is written (`Variances` or `ArdupilotCbrt`).
    pub pose_covariance: PoseCovariance,
    /// `ODOMETRY` in `MAV_FRAME_LOCAL_NED` (towards PX4) rather than
    /// `MAV_FRAME_LOCAL_FRD` (ArduPilot's only accepted frame).
    pub frame_ned: bool,
    /// The pose covariance sent is conditioned on the yaw ([`given_yaw`]).
    pub position_given_yaw: bool,
}

/// The covariance `c` of the pose error `[δθ, δp]` (world frame) with the
/// position given the yaw error `δθ_z`, the turn about the vertical
/// (estimator README eq. O2): the covariance of `[δθ, δp − K δθ_z]`,
/// `K = C_pz / C_zz`, that is `T c Tᵀ` with `T = I − K e_zᵀ` on the position's
/// rows. The position's block becomes `C_p|z = C_pp − C_pz C_zz⁻¹ C_zp`,
/// uncorrelated with `δθ_z`; the attitude's block is `c`'s, so roll, pitch
/// and yaw go out as they would whole. It is taken on the world rotation
/// error, not on an Euler yaw: near a pitch of ±90° an Euler yaw holds a
/// tilt error too, which is no turn of the frame. Symmetrised, its diagonal
/// floored at 0 (round-off); a yaw variance not positive and finite, or a
/// result not finite, leaves `c` as it is.
pub fn given_yaw(c: &Matrix6<f64>) -> Matrix6<f64> {
    const Z: usize = 2;
    let var_z = c[(Z, Z)];
    if !(var_z.is_finite() && var_z > 0.0) {
        return *c;
    }
    let mut t = Matrix6::identity();
    for k in 3..6 {
        t[(k, Z)] = -c[(k, Z)] / var_z;
    }
    let mut out = t * c * t.transpose();
    out = (out + out.transpose()) * 0.5;
    for k in 0..6 {
        out[(k, k)] = out[(k, k)].max(0.0);
    }
    if out.iter().all(|x| x.is_finite()) {
        out
    } else {
        *c
    }
}

/// Roll, pitch, yaw and the pose covariance as sent at `s`: the filter's
/// `[δθ, δp]` block, given the yaw ([`given_yaw`]) when asked, through the
/// Euler map ([`rpy_covariance`]).
pub(super) fn sent_pose(s: &OutputState) -> (Vector3<f64>, Matrix6<f64>) {
    let cov = pose_block(&s.imu_cov);
    let cov = if s.position_given_yaw { given_yaw(&cov) } else { cov };
    rpy_covariance(&s.x, &cov)
}

/// The 21 entries of the pose covariance `c` (`[x y z roll pitch yaw]`) as
/// `encoding` writes them (see [`PoseCovariance::ArdupilotCbrt`]: eq. O1
/// of `src/estimator/README.md`).
pub fn pose_covariance21(c: &Matrix6<f64>, encoding: PoseCovariance) -> [f32; 21] {
    if encoding != PoseCovariance::ArdupilotCbrt {
        return upper21(c);
    }
    let sigma_p = c[(0, 0)].max(c[(1, 1)]).max(c[(2, 2)]).max(0.0).sqrt();
    let sigma_yaw = c[(5, 5)].max(0.0).sqrt();
    let entry = |sigma: f64| (sigma.powf(1.5) / 3f64.sqrt()) as f32;
    let mut out = [0.0f32; 21];
    // Diagonal positions in MAVLink's row-major upper triangle.
    for (k, sigma) in [
        (0, sigma_p),
        (6, sigma_p),
        (11, sigma_p),
        (15, sigma_yaw),
        (18, sigma_yaw),
        (20, sigma_yaw),
    ] {
        out[k] = entry(sigma);
    }
    out
}

/// The variance of one gyro reading's white noise at `rate_hz` from the
/// continuous density (rad/s/√Hz): `σ² = σ_c² · rate`, the noise of a
/// sample whose bandwidth is the Nyquist frequency.
pub fn gyro_white_variance(noise_density: f64, rate_hz: f64) -> f64 {
    noise_density * noise_density * rate_hz
}
/// Measurements sparser than this: degraded (s).
const SPARSE_AIDING_S: f64 = 0.5;

/// `ODOMETRY.quality` ("−1 = failed, 0 = unknown, 1 = worst, 100 = best"),
/// from the filter's health at the output instant, with
/// `aided_age_s` how long ago a measurement (frame, GNSS epoch, ZUPT) last
/// moved the filter:
/// - −1: failed: the predicted state or its covariance is not finite
///   (a filter that fails its health check is reset before its next
///   output, and none is sent while a new one starts);
/// - 1: dead reckoning: nothing fused for [`DEAD_RECKONING_S`] (camera and
///   GNSS both out; the position error grows with the cube of time);
/// - 50: aiding sparse or degraded: nothing fused for [`SPARSE_AIDING_S`]
///   (frames late or lost, GNSS alone), or a degraded reason in the
///   HEARTBEAT (input rejected, a reset just now, GNSS outliers …);
/// - 100: nominal.
///
/// ArduPilot ignores estimates below `VISO_QUAL_MIN` (0 by default: only
/// −1 is dropped; 2 drops dead reckoning as well), PX4 below `EKF2_EV_QMIN`.
///
/// `aided_age_s` is the time since the last frame or GNSS epoch was fused
/// (∞ before the first: dead reckoning).
pub fn quality(x: &ImuState, imu_cov: &Mat15, aided_age_s: f64, degraded: bool) -> i8 {
    let finite = [x.p_B_in_W, x.v_B_in_W, x.b_g]
        .iter()
        .all(|v| v.iter().all(|c| c.is_finite()))
        && x.q_W_B.coords.iter().all(|c| c.is_finite())
        && imu_cov.iter().all(|c| c.is_finite());
    if !finite || aided_age_s.is_nan() {
        -1
    } else if aided_age_s >= DEAD_RECKONING_S {
        1
    } else if aided_age_s >= SPARSE_AIDING_S || degraded {
        50
    } else {
        100
    }
}

pub(super) fn t_us(t_s: f64) -> u64 {
    (t_s * 1e6).round() as u64
}

/// Roll, pitch, yaw of the state and the covariance of `[x y z roll pitch
/// yaw]`, from that of the pose `[δθ, δp]`.
pub(super) fn pose_rpy_covariance(x: &ImuState, imu_cov: &Mat15) -> (Vector3<f64>, Matrix6<f64>) {
    rpy_covariance(x, &pose_block(imu_cov))
}

/// Roll, pitch, yaw of the state and the covariance of `[x y z roll pitch
/// yaw]` from `cov`, that of the pose error `[δθ, δp]`.
fn rpy_covariance(x: &ImuState, cov: &Matrix6<f64>) -> (Vector3<f64>, Matrix6<f64>) {
    let (rpy, m) = euler_and_map(&x.q_W_B);
    let minv = m.try_inverse().unwrap_or_else(Matrix3::identity);
    let mut t = Matrix6::zeros();
    t.fixed_view_mut::<3, 3>(0, 3).copy_from(&Matrix3::identity());
    t.fixed_view_mut::<3, 3>(3, 0).copy_from(&minv);
    (rpy, t * cov * t.transpose())
}

/// Covariance of `[v_B, ω_B]`, body velocity and rate (FRD), the layout of
/// `ODOMETRY.velocity_covariance`:
/// - velocity: `v_B = R̂ᵀ Exp(−δθ)(v̂ + δv) ≈ v̂_B + R̂ᵀ[v̂]× δθ + R̂ᵀ δv`, the
///   filter's attitude and velocity errors rotated into the body;
/// - rate: `ω = ω_m − b̂_g` errs by the gyro's white noise (`gyro_var`,
///   [`gyro_white_variance`]) and the bias error `−δb_g` (whose
///   correlation with `δθ`, `δv` is kept).
pub fn body_velocity_rate_covariance(x: &ImuState, imu_cov: &Mat15, gyro_var: f64) -> Matrix6<f64> {
    let p9 = attitude_velocity_gyro_bias_block(imu_cov);
    let rt = x.q_W_B.to_rotation_matrix().into_inner().transpose();
    let mut a = SMatrix::<f64, 6, 9>::zeros();
    a.fixed_view_mut::<3, 3>(0, 0).copy_from(&(rt * skew(&x.v_B_in_W)));
    a.fixed_view_mut::<3, 3>(0, 3).copy_from(&rt);
    a.fixed_view_mut::<3, 3>(3, 6).copy_from(&(-Matrix3::identity()));
    let mut c = a * p9 * a.transpose();
    for k in 3..6 {
        c[(k, k)] += gyro_var;
    }
    // Exactly symmetric, as MAVLink's upper triangle assumes.
    (c + c.transpose()) * 0.5
}

/// The messages for one output instant: `ODOMETRY`, or
/// `VISION_POSITION_ESTIMATE` and `VISION_SPEED_ESTIMATE` (a different
/// quantity, the velocity, at the same instant): never two messages of the
/// same pose.
pub fn outputs(s: &OutputState, message: OutputMessage) -> Vec<Outbound> {
    let x = &s.x;
    let (rpy, c) = sent_pose(s);
    let t_us = t_us(s.t_s);
    match message {
        OutputMessage::Odometry => {
            let q = x.q_W_B.coords;
            vec![Outbound::Odometry {
                t_us,
                p_ned_m: x.p_B_in_W,
                q_wxyz: [q.w as f32, q.x as f32, q.y as f32, q.z as f32],
                v_body_mps: x.q_W_B.inverse_transform_vector(&x.v_B_in_W),
                w_body_radps: s.gyro_radps - x.b_g,
                // The same [x y z roll pitch yaw] layout as VPE's.
                pose_covariance: pose_covariance21(&c, s.pose_covariance),
                velocity_covariance: upper21(&body_velocity_rate_covariance(x, &s.imu_cov, s.gyro_var)),
                reset_counter: s.reset_counter,
                quality: s.quality,
                frame_ned: s.frame_ned,
            }]
        }
        OutputMessage::VisionPositionEstimate => {
            let pv = velocity_block(&s.imu_cov);
            let mut covariance = [0.0f32; 9];
            for (k, v) in covariance.iter_mut().enumerate() {
                *v = (0.5 * (pv[(k / 3, k % 3)] + pv[(k % 3, k / 3)])) as f32;
            }
            vec![
                Outbound::VisionPositionEstimate {
                    t_us,
                    p_ned_m: x.p_B_in_W,
                    rpy_rad: rpy,
                    // Written as ODOMETRY's: ArduPilot reduces both alike.
                    covariance: pose_covariance21(&c, s.pose_covariance),
                    reset_counter: s.reset_counter,
                },
                Outbound::VisionSpeedEstimate {
                    t_us,
                    v_ned_mps: x.v_B_in_W,
                    covariance,
                    reset_counter: s.reset_counter,
                },
            ]
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimator::propagate::{BG, P as P_OFF, TH, V};

    fn state(q: UnitQuaternion<f64>) -> ImuState {
        ImuState {
            q_W_B: q,
            v_B_in_W: Vector3::new(3.0, -1.0, 0.5),
            p_B_in_W: Vector3::new(1.0, 2.0, 3.0),
            b_g: Vector3::new(0.01, -0.02, 0.03),
            b_a: Vector3::zeros(),
        }
    }

    /// A symmetric positive-definite IMU covariance with correlations.
    fn imu_cov() -> Mat15 {
        let l = Mat15::from_fn(|i, j| {
            if i >= j {
                0.01 * (1.0 + ((i * 7 + j * 3) % 5) as f64)
            } else {
                0.0
            }
        });
        l * l.transpose() + Mat15::identity() * 1e-4
    }

    fn output_state(q: UnitQuaternion<f64>) -> OutputState {
        OutputState {
            t_s: 1.5,
            x: state(q),
            imu_cov: imu_cov(),
            gyro_radps: Vector3::new(0.1, 0.2, -0.3),
            gyro_var: gyro_white_variance(1.7e-4, 200.0),
            reset_counter: 2,
            pose_covariance: PoseCovariance::Variances,
            frame_ned: false,
            position_given_yaw: false,
            quality: 100,
        }
    }

    /// The Euler-angle map against finite differences.
    #[test]
    fn euler_map_matches_finite_differences() {
        let q = UnitQuaternion::from_euler_angles(0.2, -0.3, 1.2);
        let (rpy, m) = euler_and_map(&q);
        let h = 1e-6;
        for k in 0..3 {
            let mut d = rpy;
            d[k] += h;
            let qp = UnitQuaternion::from_euler_angles(d.x, d.y, d.z);
            let dth = (qp * q.inverse()).scaled_axis() / h;
            assert!((dth - m.column(k)).norm() < 1e-5, "{k}: {dth} vs {}", m.column(k));
        }
    }

    /// `vision_position_estimate`: VPE and VISION_SPEED_ESTIMATE at the same
    /// instant, and never ODOMETRY.
    #[test]
    fn vpe_comes_with_its_speed_estimate_and_never_odometry() {
        let s = output_state(UnitQuaternion::from_euler_angles(0.2, -0.3, 1.2));
        let o = outputs(&s, OutputMessage::VisionPositionEstimate);
        assert_eq!(o.len(), 2, "{o:?}");
        assert!(!o.iter().any(|m| matches!(m, Outbound::Odometry { .. })));
        let Outbound::VisionPositionEstimate {
            t_us,
            p_ned_m,
            covariance,
            reset_counter,
            ..
        } = &o[0]
        else {
            panic!("{o:?}")
        };
        assert_eq!((*t_us, *reset_counter, *p_ned_m), (1_500_000, 2, s.x.p_B_in_W));
        // Position variances come first.
        assert!((covariance[0] as f64 - s.imu_cov[(P_OFF, P_OFF)]).abs() < 1e-6);
        assert!(covariance.iter().all(|v| v.is_finite()));
        let Outbound::VisionSpeedEstimate {
            t_us,
            v_ned_mps,
            covariance,
            reset_counter,
        } = &o[1]
        else {
            panic!("{o:?}")
        };
        assert_eq!((*t_us, *reset_counter, *v_ned_mps), (1_500_000, 2, s.x.v_B_in_W));
        for k in 0..9 {
            let want = s.imu_cov[(V + k / 3, V + k % 3)];
            assert!((covariance[k] as f64 - want).abs() < 1e-7, "{k}");
        }
    }

    /// `odometry`: one ODOMETRY and nothing else, its rate the gyro minus
    /// the bias, its covariances finite, its quality as judged.
    #[test]
    fn odometry_alone_with_rates_covariances_and_quality() {
        let mut s = output_state(UnitQuaternion::from_euler_angles(0.2, -0.3, 1.2));
        s.quality = 50;
        let o = outputs(&s, OutputMessage::Odometry);
        assert_eq!(o.len(), 1, "{o:?}");
        let Outbound::Odometry {
            t_us,
            p_ned_m,
            q_wxyz,
            v_body_mps,
            w_body_radps,
            pose_covariance,
            velocity_covariance,
            reset_counter,
            quality,
            frame_ned,
        } = &o[0]
        else {
            panic!("{o:?}")
        };
        assert_eq!(
            (*t_us, *reset_counter, *quality, *p_ned_m),
            (1_500_000, 2, 50, s.x.p_B_in_W)
        );
        assert_eq!(*w_body_radps, s.gyro_radps - s.x.b_g);
        assert!(!frame_ned, "LOCAL_FRD unless the autopilot is PX4");
        assert!((s.x.q_W_B * v_body_mps - s.x.v_B_in_W).norm() < 1e-12);
        let q = s.x.q_W_B.coords;
        assert_eq!(*q_wxyz, [q.w as f32, q.x as f32, q.y as f32, q.z as f32]);
        assert!(pose_covariance
            .iter()
            .chain(velocity_covariance.iter())
            .all(|v| v.is_finite()));
        // Diagonal entries of the upper triangle: 0, 6, 11, 15, 18, 20; the
        // rates' include the gyro noise.
        for (k, &d) in [0, 6, 11, 15, 18, 20].iter().enumerate() {
            assert!(velocity_covariance[d] > 0.0, "{k}");
            if k >= 3 {
                assert!(velocity_covariance[d] as f64 >= s.gyro_var, "{k}");
            }
        }
    }

    /// The body velocity and rate covariance against the numerical
    /// Jacobian of `[R(δθ)ᵀ (v + δv), ω_m − (b_g + δb_g)]`.
    #[test]
    fn body_velocity_covariance_matches_numerical_jacobian() {
        let s = output_state(UnitQuaternion::from_euler_angles(0.4, 0.1, -2.0));
        let (x, w_m) = (&s.x, s.gyro_radps);
        let f = |e: &SMatrix<f64, 9, 1>| -> SMatrix<f64, 6, 1> {
            let r = UnitQuaternion::from_scaled_axis(Vector3::new(e[0], e[1], e[2])) * x.q_W_B;
            let v = r.inverse_transform_vector(&(x.v_B_in_W + Vector3::new(e[3], e[4], e[5])));
            let w = w_m - (x.b_g + Vector3::new(e[6], e[7], e[8]));
            SMatrix::<f64, 6, 1>::from_iterator(v.iter().chain(w.iter()).copied())
        };
        let h = 1e-6;
        let mut j = SMatrix::<f64, 6, 9>::zeros();
        for k in 0..9 {
            let mut e = SMatrix::<f64, 9, 1>::zeros();
            e[k] = h;
            j.set_column(k, &((f(&e) - f(&-e)) / (2.0 * h)));
        }
        let idx = [TH, TH + 1, TH + 2, V, V + 1, V + 2, BG, BG + 1, BG + 2];
        let p9 = SMatrix::<f64, 9, 9>::from_fn(|a, b| s.imu_cov[(idx[a], idx[b])]);
        let mut want = j * p9 * j.transpose();
        for k in 3..6 {
            want[(k, k)] += s.gyro_var;
        }
        let got = body_velocity_rate_covariance(x, &s.imu_cov, s.gyro_var);
        assert!((got - want).abs().max() < 1e-7 * want.abs().max(), "{got} vs {want}");
    }

    /// ArduPilot's reduction (GCS_Common.cpp before PR #32084) applied to
    /// what `ardupilot_cbrt` writes gives back the largest position σ and
    /// the yaw σ (eq. O1); measured on ArduPilot's own SITL (its `VISP.PErr`
    /// logged 3.634 for c₀ = c₆ = c₁₁ = 4, i.e. cbrt(3·4²)).
    #[test]
    fn ardupilot_cbrt_covariance_survives_the_reduction() {
        let reduce = |c: &[f32; 21], [a, b, d]: [usize; 3]| {
            ((c[a] as f64).powi(2) + (c[b] as f64).powi(2) + (c[d] as f64).powi(2)).cbrt()
        };
        let mut cov = Matrix6::zeros();
        for (k, sigma) in [0.12, 0.3, 0.2, 0.01, 0.02, 0.05].iter().enumerate() {
            cov[(k, k)] = sigma * sigma;
        }
        cov[(0, 1)] = 0.001;
        cov[(1, 0)] = 0.001;
        let enc = pose_covariance21(&cov, PoseCovariance::ArdupilotCbrt);
        assert!(
            (reduce(&enc, [0, 6, 11]) - 0.3).abs() < 1e-6,
            "position: {}",
            reduce(&enc, [0, 6, 11])
        );
        assert!(
            (reduce(&enc, [15, 18, 20]) - 0.05).abs() < 1e-6,
            "yaw: {}",
            reduce(&enc, [15, 18, 20])
        );
        assert_eq!(enc.iter().filter(|&&c| c != 0.0).count(), 6, "only the diagonal");
        // The MAVLink encoding is the plain upper triangle, and under the
        // same reduction it is wrong (3^(1/3)·σ^(4/3) for equal axes).
        let plain = pose_covariance21(&cov, PoseCovariance::Variances);
        assert_eq!(plain, upper21(&cov));
        assert!(
            (reduce(&plain, [0, 6, 11]) - 0.3).abs() > 0.05,
            "{}",
            reduce(&plain, [0, 6, 11])
        );
    }

    /// VISION_POSITION_ESTIMATE's pose covariance is written as ODOMETRY's:
    /// towards ArduPilot, the cube-root reduction it applies to both
    /// (`cbrt(c0² + c6² + c11²)`, and the same of the rotations) gives back
    /// our σ (the variances PX4 reads would not).
    #[test]
    fn vpe_covariance_survives_ardupilots_reduction_as_odometry_does() {
        let reduce = |c: &[f32; 21], [a, b, d]: [usize; 3]| {
            ((c[a] as f64).powi(2) + (c[b] as f64).powi(2) + (c[d] as f64).powi(2)).cbrt()
        };
        let mut s = output_state(UnitQuaternion::identity());
        s.pose_covariance = PoseCovariance::ArdupilotCbrt;
        let mut p = Mat15::identity() * 1e-6;
        for (k, sigma) in [3.0f64, 2.0, 1.0].into_iter().enumerate() {
            p[(P_OFF + k, P_OFF + k)] = sigma * sigma;
        }
        p[(TH + 2, TH + 2)] = 0.05f64.powi(2);
        s.imu_cov = p;
        for message in [OutputMessage::Odometry, OutputMessage::VisionPositionEstimate] {
            let cov = match outputs(&s, message).first() {
                Some(Outbound::Odometry { pose_covariance, .. }) => *pose_covariance,
                Some(Outbound::VisionPositionEstimate { covariance, .. }) => *covariance,
                other => panic!("{other:?}"),
            };
            let (pos, yaw) = (reduce(&cov, [0, 6, 11]), reduce(&cov, [15, 18, 20]));
            assert!((pos - 3.0).abs() < 1e-5, "{message:?}: position {pos}");
            assert!((yaw - 0.05).abs() < 1e-6, "{message:?}: yaw {yaw}");
        }
        s.pose_covariance = PoseCovariance::Variances;
        let Some(Outbound::VisionPositionEstimate { covariance, .. }) =
            outputs(&s, OutputMessage::VisionPositionEstimate).into_iter().next()
        else {
            panic!("no VPE")
        };
        // As variances (PX4's reading), ArduPilot's reduction would take
        // cbrt(9² + 4² + 1²) = 4.61 m for our 3 m.
        let plain = reduce(&covariance, [0, 6, 11]);
        assert!((plain - 98f64.cbrt()).abs() < 1e-4, "{plain}");
    }

    /// Eq. O2: the position's block is the Schur complement
    /// `C_pp − C_pz C_zp / C_zz`, uncorrelated with the yaw error; the
    /// attitude's block is untouched; the position's correlation with the
    /// tilt is `C_pθ − K C_zθ`.
    #[test]
    fn given_yaw_is_the_covariance_of_the_position_less_its_yaw_share() {
        let l = Matrix6::from_fn(|i, j| {
            if i >= j {
                0.1 * (1.0 + ((i * 5 + j * 3) % 7) as f64)
            } else {
                0.0
            }
        });
        let c = l * l.transpose() + Matrix6::identity() * 1e-3;
        let z = 2;
        let got = given_yaw(&c);
        for i in 3..6 {
            let k_i = c[(i, z)] / c[(z, z)];
            for j in 3..6 {
                let schur = c[(i, j)] - c[(i, z)] * c[(z, j)] / c[(z, z)];
                assert!(
                    (got[(i, j)] - schur).abs() < 1e-12,
                    "({i},{j}): {} against {schur}",
                    got[(i, j)]
                );
            }
            for a in 0..3 {
                let cross = c[(i, a)] - k_i * c[(z, a)];
                assert!((got[(i, a)] - cross).abs() < 1e-12 && (got[(a, i)] - cross).abs() < 1e-12);
            }
            assert!(got[(i, z)].abs() < 1e-12, "uncorrelated with the yaw");
            // Conditioning never adds uncertainty.
            assert!(got[(i, i)] <= c[(i, i)]);
        }
        assert_eq!(
            got.fixed_view::<3, 3>(0, 0),
            c.fixed_view::<3, 3>(0, 0),
            "the attitude's block"
        );
        // No yaw variance to condition on, or a non-finite one: unchanged.
        let mut flat = c;
        flat[(z, z)] = 0.0;
        assert_eq!(given_yaw(&flat), flat);
        flat[(z, z)] = f64::NAN;
        assert!(given_yaw(&flat)[(3, 3)] == c[(3, 3)]);
        // A yaw variance so small that the division overflows: unchanged.
        let mut tiny = c;
        tiny[(z, z)] = 1e-320;
        assert_eq!(given_yaw(&tiny), tiny);
        // A pure turn, conditioned: the round-off leaves no negative variance.
        let g = nalgebra::Vector6::new(0.0, 0.0, 1.0, -6.5, 10.0, 0.0);
        let turn = g * g.transpose() * 1e-3;
        assert!(given_yaw(&turn).diagonal().iter().all(|v| *v >= 0.0));
    }

    /// A filter's covariance whose only yaw is a turn of its whole frame
    /// (the unobservable direction: `δθ = ẑ δψ`, `δv = ẑ×v δψ`,
    /// `δp = ẑ×p δψ`) on top of an uncorrelated one: given the yaw, the
    /// position's covariance is the uncorrelated one's, and the body-frame
    /// velocity's covariance is the same with the turn or without it. A
    /// yaw error of another origin would be conditioned on too (its share
    /// of the position is what it is): this is the case where the whole
    /// share is the turn's.
    #[test]
    fn a_turn_of_the_whole_frame_leaves_nothing_given_the_yaw() {
        let q = UnitQuaternion::from_euler_angles(0.1, -0.2, 0.7);
        let mut s = output_state(q);
        s.x.p_B_in_W = Vector3::new(10.0, 6.5, -5.0);
        s.x.v_B_in_W = Vector3::new(-0.5, 4.0, 0.2);
        // No yaw error of its own, so that every yaw error is the turn's;
        // a tilt of its own, uncorrelated.
        let base = Mat15::from_diagonal(&nalgebra::SVector::<f64, 15>::from_fn(|i, _| {
            if i == TH + 2 {
                0.0
            } else {
                1e-3 * (1 + i % 4) as f64
            }
        }));
        let mut g = nalgebra::SVector::<f64, 15>::zeros();
        g[TH + 2] = 1.0;
        g.fixed_rows_mut::<3>(V).copy_from(&Vector3::z().cross(&s.x.v_B_in_W));
        g.fixed_rows_mut::<3>(P_OFF)
            .copy_from(&Vector3::z().cross(&s.x.p_B_in_W));
        let sigma_yaw = 3f64.to_radians();
        s.imu_cov = base + g * g.transpose() * sigma_yaw * sigma_yaw;

        let (_, absolute) = pose_rpy_covariance(&s.x, &s.imu_cov);
        // 3° at 12 m: 0.6 m of the east's σ is the turn's.
        assert!(absolute[(1, 1)].sqrt() > 0.5, "{}", absolute[(1, 1)].sqrt());
        s.position_given_yaw = true;
        let (_, sent) = sent_pose(&s);
        let (_, base_pose) = pose_rpy_covariance(&s.x, &base);
        for i in 0..3 {
            for j in 0..3 {
                assert!((sent[(i, j)] - base_pose[(i, j)]).abs() < 1e-12, "({i},{j}): {sent}");
            }
        }
        assert!(
            (sent[(5, 5)] - absolute[(5, 5)]).abs() < 1e-15,
            "the yaw's variance is sent whole"
        );
        let Some(Outbound::Odometry { pose_covariance, .. }) = outputs(&s, OutputMessage::Odometry).into_iter().next()
        else {
            panic!("no ODOMETRY")
        };
        assert_eq!(pose_covariance, upper21(&sent));

        let with_turn = body_velocity_rate_covariance(&s.x, &s.imu_cov, 0.0);
        let without = body_velocity_rate_covariance(&s.x, &base, 0.0);
        assert!(
            (with_turn - without).abs().max() < 1e-12,
            "{with_turn} against {without}"
        );
    }

    /// A tilt error correlated with the position is no turn of the frame:
    /// conditioned on the world yaw error it stays whole, even at a pitch
    /// of 80°, where the Euler yaw's error holds `tan(pitch)` of the tilt.
    #[test]
    fn a_tilt_error_is_not_taken_for_the_yaw_near_a_vertical_pitch() {
        let mut s = output_state(UnitQuaternion::from_euler_angles(0.0, 80f64.to_radians(), 0.3));
        let mut p = Mat15::identity() * 1e-4;
        // The tilt about the heading's horizontal axis (a roll, level),
        // 1°, correlated 0.9 with the north position (σ 0.3 m); the yaw 3°,
        // uncorrelated with both.
        let axis = UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3) * Vector3::x();
        let sigma_tilt = 1f64.to_radians();
        for i in 0..3 {
            for j in 0..3 {
                p[(TH + i, TH + j)] = axis[i] * axis[j] * sigma_tilt * sigma_tilt;
            }
            p[(TH + i, P_OFF)] = axis[i] * 0.9 * sigma_tilt * 0.3;
            p[(P_OFF, TH + i)] = p[(TH + i, P_OFF)];
        }
        p[(TH + 2, TH + 2)] += 3f64.to_radians().powi(2);
        p[(P_OFF, P_OFF)] = 0.09;
        s.imu_cov = p;
        s.position_given_yaw = true;
        let (_, sent) = sent_pose(&s);
        let (_, absolute) = pose_rpy_covariance(&s.x, &s.imu_cov);
        assert!(
            (sent[(0, 0)] - absolute[(0, 0)]).abs() < 1e-12,
            "north σ {} sent against {}",
            sent[(0, 0)].sqrt(),
            absolute[(0, 0)].sqrt()
        );
        // Roll, pitch and yaw go out as they would whole.
        let (a, b) = (sent.fixed_view::<3, 3>(3, 3), absolute.fixed_view::<3, 3>(3, 3));
        assert!((a - b).abs().max() < 1e-15, "{a} against {b}");
    }

    #[test]
    fn quality_is_failed_dead_reckoning_sparse_or_nominal() {
        let x = state(UnitQuaternion::identity());
        let cov = imu_cov();
        assert_eq!(quality(&x, &cov, 0.05, false), 100);
        assert_eq!(quality(&x, &cov, 0.05, true), 50, "degraded");
        assert_eq!(quality(&x, &cov, 0.7, false), 50);
        assert_eq!(quality(&x, &cov, 1.0, false), 1);
        assert_eq!(quality(&x, &cov, f64::INFINITY, false), 1);
        let mut bad = cov;
        bad[(4, 4)] = f64::NAN;
        assert_eq!(quality(&x, &bad, 0.05, false), -1, "a non-finite covariance");
        let mut bad = x;
        bad.v_B_in_W.x = f64::INFINITY;
        assert_eq!(quality(&bad, &cov, 0.05, false), -1, "a non-finite state");
        assert_eq!(quality(&x, &cov, f64::NAN, false), -1);
    }
}
