//! What a satellite measures (README.md §8): the predicted pseudorange and
//! range rate of the antenna at `p_A_in_B_m` on the body, and their
//! Jacobians over the GNSS row order `[δθ, δv, δp, δb_g, δb, δḃ, δisb_E,R,C]`.
//! The antenna sits at `r = o + R_en (p_B_in_W + R_W_B p_A_in_B)` in ECEF,
//! with `o` the world origin and `R_en` the NED→ECEF rotation, and moves
//! with `v_B_in_W + R_W_B (ω_B × p_A_in_B)`: the rows have attitude and
//! gyro-bias columns as well as velocity, position and clock ones. How an
//! epoch is gated and fused is `gnss_update.rs`'s.

use nalgebra::{Matrix3, RowVector3, Vector3};

use cmsckf_models::geodesy::{ecef_to_llh, elevation_azimuth, NedFrame, C_MPS, OMEGA_E_RADPS};
use cmsckf_models::gnss::{saastamoinen_m, SatMeas};

use super::math::skew;
use super::propagate::{boxplus, ImuState, IMU_DIM};
use super::{isb_slot, ClockVec, CLK_B, CLK_D, CLK_E, CLOCK_DIM};

/// Error-state size of a GNSS clone, and the column order of every GNSS
/// row: `[δθ, δv, δp, δb_g, δb, δḃ, δisb_E, δisb_R, δisb_C]`.
pub const GNSS_CLONE_DIM: usize = 12 + CLOCK_DIM;

/// The active states a GNSS row involves, in the row's column order.
pub(super) const GNSS_COLS: [usize; GNSS_CLONE_DIM] = [
    0,
    1,
    2,
    3,
    4,
    5,
    6,
    7,
    8,
    9,
    10,
    11,
    CLK_B,
    CLK_D,
    CLK_E,
    CLK_E + 1,
    CLK_E + 2,
];
/// Row offsets of the blocks within a GNSS row.
pub(super) const G_TH: usize = 0;
pub(super) const G_V: usize = 3;
pub(super) const G_P: usize = 6;
pub(super) const G_BG: usize = 9;
pub(super) const G_B: usize = 12;
pub(super) const G_D: usize = 13;
pub(super) const G_E: usize = 14;

/// The states a GNSS epoch is predicted from: the live ones, or a clone's.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GnssNominal {
    /// Attitude, velocity, position and gyro bias (the accelerometer bias
    /// is not used).
    pub imu: ImuState,
    /// The measured body rate at the instant (rad/s).
    pub gyro_radps: Vector3<f64>,
    /// `[c·δt_G (m), c·δṫ (m/s), isb_E, isb_R, isb_C (m)]`.
    pub clock: ClockVec,
}

impl GnssNominal {
    /// `x ⊕ δx` in the GNSS row order: `[δθ, δv, δp, δb_g]` are the IMU
    /// error state's first twelve, so the IMU part is [`boxplus`]'s.
    pub fn correct(&mut self, d: &[f64]) {
        let mut d_imu = [0.0; IMU_DIM];
        d_imu[..G_B].copy_from_slice(&d[..G_B]);
        self.imu = boxplus(&self.imu, &d_imu);
        self.clock += ClockVec::from_column_slice(&d[G_B..G_B + CLOCK_DIM]);
    }
}

/// A satellite's predicted measurements and their Jacobians over the GNSS
/// row order.
#[derive(Clone, Copy, Debug)]
pub struct SatPrediction {
    pub pseudorange_m: f64,
    pub h_pseudorange: [f64; GNSS_CLONE_DIM],
    pub range_rate_mps: f64,
    pub h_range_rate: [f64; GNSS_CLONE_DIM],
    pub elevation_rad: f64,
    /// The troposphere's mapping `m(el) = T(el) / T(90°)` at the antenna
    /// (Saastamoinen's ratio, eq. DG5′): the pseudorange's column for the
    /// zenith troposphere error.
    pub tropo_map: f64,
}

/// The troposphere's mapping at the antenna `p_A_in_W` for a satellite at
/// `el_rad`: `m = T_S(el) / T_S(90°)` (eq. DG5′), the factor by which a
/// zenith error of the model shows on that line of sight.
pub fn troposphere_mapping(frame: &NedFrame, p_A_in_W: &Vector3<f64>, el_rad: f64) -> f64 {
    // Floored at sin el = 0.1 (5.7°), as the codes' weights are: Saastamoinen's
    // 1/cos z is unbounded at the horizon, and one multipath code there
    // would move the zenith state by as much as every good code together.
    let floor_rad = 0.1f64.asin();
    let el_rad = el_rad.max(floor_rad);
    let (lat, _, h) = ecef_to_llh(&frame.to_ecef(p_A_in_W));
    let zenith_m = saastamoinen_m(lat, h, std::f64::consts::FRAC_PI_2);
    if zenith_m > 0.0 {
        saastamoinen_m(lat, h, el_rad) / zenith_m
    } else {
        1.0 / el_rad.sin()
    }
}

/// The pseudorange and range rate of `s` seen by the antenna at
/// `p_A_in_B_m` (§8, eqs. K2, K3, L1, L2). With `R = Exp(δθ) R̂`:
/// `∂p_A/∂δθ = −[R p_A_in_B]×`, `∂v_A/∂δθ = −[R (ω × p_A_in_B)]×` and
/// `∂v_A/∂δb_g = R [p_A_in_B]×` (as `ω = ω_m − b_g`).
pub fn predict_sat(frame: &NedFrame, nom: &GnssNominal, p_A_in_B_m: &Vector3<f64>, s: &SatMeas) -> SatPrediction {
    let r_wb = nom.imu.q_W_B.to_rotation_matrix().into_inner();
    let lever_W = r_wb * p_A_in_B_m;
    let w_B = nom.gyro_radps - nom.imu.b_g;
    let spin_W = r_wb * w_B.cross(p_A_in_B_m);
    let p_A = nom.imu.p_B_in_W + lever_W;
    let v_A = nom.imu.v_B_in_W + spin_W;
    // Each constellation's own bias: GPS's plus its inter-system bias.
    let slot = isb_slot(s.system);
    let bias_m = nom.clock[0] + slot.map_or(0.0, |k| nom.clock[2 + k]);
    let (pr, hp, el) = pseudorange(frame, &p_A, bias_m, s);
    let (rate, hv, hpr) = range_rate(frame, &p_A, &v_A, nom.clock.y, s);
    let dpa_dth = -skew(&lever_W);
    let dva_dth = -skew(&spin_W);
    let dva_dbg = r_wb * skew(p_A_in_B_m);
    let mut h_pr = [0.0; GNSS_CLONE_DIM];
    let mut h_rate = [0.0; GNSS_CLONE_DIM];
    let put = |h: &mut [f64; GNSS_CLONE_DIM], o: usize, v: RowVector3<f64>| {
        h[o..o + 3].copy_from_slice(v.as_slice());
    };
    put(&mut h_pr, G_TH, hp * dpa_dth);
    put(&mut h_pr, G_P, hp);
    h_pr[G_B] = 1.0;
    if let Some(k) = slot {
        h_pr[G_E + k] = 1.0;
    }
    put(&mut h_rate, G_TH, hv * dva_dth + hpr * dpa_dth);
    put(&mut h_rate, G_V, hv);
    put(&mut h_rate, G_P, hpr);
    put(&mut h_rate, G_BG, hv * dva_dbg);
    h_rate[G_D] = 1.0;
    SatPrediction {
        pseudorange_m: pr,
        h_pseudorange: h_pr,
        range_rate_mps: rate,
        h_range_rate: h_rate,
        elevation_rad: el,
        tropo_map: troposphere_mapping(frame, &p_A, el),
    }
}

/// Predicted pseudorange (K2): `|r_s − r| + ω_e (x_s y − y_s x)/c + b − c·δt_s + T`,
/// with its Jacobians with respect to the position in the world frame and
/// the clock bias (1). Also returns the elevation.
pub fn pseudorange(
    frame: &NedFrame,
    p_B_in_W: &Vector3<f64>,
    clock_bias_m: f64,
    s: &SatMeas,
) -> (f64, RowVector3<f64>, f64) {
    let r = frame.to_ecef(p_B_in_W);
    let d = s.r_sat_ecef_m - r;
    let rho = d.norm();
    let u = d / rho;
    let sagnac = OMEGA_E_RADPS * (s.r_sat_ecef_m.x * r.y - s.r_sat_ecef_m.y * r.x) / C_MPS;
    let (el, _) = elevation_azimuth(&r, &s.r_sat_ecef_m);
    let (lat, _, h) = ecef_to_llh(&r);
    let trop = saastamoinen_m(lat, h, el);
    // ∂ρ/∂r = −uᵀ + (ω_e/c)(−y_s, x_s, 0); the troposphere varies with height
    // (down = −height), its slope taken by a ±1 m difference of the model; its
    // variation with elevation is below 1e-6 m/m and neglected.
    let drho = -u.transpose() + RowVector3::new(-s.r_sat_ecef_m.y, s.r_sat_ecef_m.x, 0.0) * (OMEGA_E_RADPS / C_MPS);
    let dtrop_dh = (saastamoinen_m(lat, h + 1.0, el) - saastamoinen_m(lat, h - 1.0, el)) / 2.0;
    let h_p = drho * frame.R_ecef_ned + RowVector3::new(0.0, 0.0, -dtrop_dh);
    (rho + sagnac + clock_bias_m - s.dts_m + trop, h_p, el)
}

/// Predicted range rate (K3), the time derivative of K2:
/// `(v_s − v)·u + ω_e (ẋ_s y + x_s ẏ − ẏ_s x − y_s ẋ)/c + ḃ − c·δṫ_s` (the
/// second term is the Sagnac term's rate, a few mm/s), with Jacobians with
/// respect to the world-frame velocity and position.
pub fn range_rate(
    frame: &NedFrame,
    p_B_in_W: &Vector3<f64>,
    v_B_in_W: &Vector3<f64>,
    clock_drift_mps: f64,
    s: &SatMeas,
) -> (f64, RowVector3<f64>, RowVector3<f64>) {
    let r = frame.to_ecef(p_B_in_W);
    let v = frame.R_ecef_ned * v_B_in_W;
    let d = s.r_sat_ecef_m - r;
    let rho = d.norm();
    let u = d / rho;
    let dv = s.v_sat_ecef_mps - v;
    let (rs, vs) = (&s.r_sat_ecef_m, &s.v_sat_ecef_mps);
    let k = OMEGA_E_RADPS / C_MPS;
    let sagnac_rate = k * (vs.x * r.y + rs.x * v.y - vs.y * r.x - rs.y * v.x);
    // ∂u/∂r = −(I − uuᵀ)/ρ.
    let du_dr: Matrix3<f64> = -(Matrix3::identity() - u * u.transpose()) / rho;
    let h_v = (-u.transpose() + RowVector3::new(-rs.y, rs.x, 0.0) * k) * frame.R_ecef_ned;
    let h_p = (dv.transpose() * du_dr + RowVector3::new(-vs.y, vs.x, 0.0) * k) * frame.R_ecef_ned;
    (dv.dot(&u) + sagnac_rate + clock_drift_mps - s.ddts_mps, h_v, h_p)
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::estimator::propagate::tests::state;
    use cmsckf_models::gnss::System;

    /// A satellite 2e7 m up and 8e6 m east of a Sydney origin, moving, with
    /// clock terms: the fixture of the measurement-model tests.
    pub(in crate::estimator) fn sat_of(system: System) -> (NedFrame, SatMeas) {
        let frame = NedFrame::from_llh_deg(-33.88, 151.2, 40.0);
        let up = frame.origin_ecef.normalize();
        let east = frame.R_ecef_ned.column(1).into_owned();
        let r_sat = frame.origin_ecef + up * 2.0e7 + east * 8.0e6;
        (
            frame,
            SatMeas {
                system,
                prn: 5,
                r_sat_ecef_m: r_sat,
                v_sat_ecef_mps: Vector3::new(1200.0, -2500.0, 1800.0),
                dts_m: 30.0,
                ddts_mps: 0.01,
                pseudorange_m: None,
                range_rate_mps: None,
                noise_scale: 1.0,
                extra_var_m2: 0.0,
                correction: None,
            },
        )
    }

    /// Jacobians of the pseudorange and range rate against central
    /// differences.
    #[test]
    fn gnss_jacobians_match_finite_differences() {
        let (frame, s) = sat_of(System::Gps);
        let p = Vector3::new(120.0, -40.0, -8.0);
        let v = Vector3::new(14.0, 3.0, -0.5);
        let (_, hp, _) = pseudorange(&frame, &p, 100.0, &s);
        let (_, hv, hp_rate) = range_rate(&frame, &p, &v, 2.0, &s);
        let h = 1e-3;
        for k in 0..3 {
            let mut d = Vector3::zeros();
            d[k] = h;
            let fd =
                (pseudorange(&frame, &(p + d), 100.0, &s).0 - pseudorange(&frame, &(p - d), 100.0, &s).0) / (2.0 * h);
            assert!((fd - hp[k]).abs() < 1e-5, "pr/p{k}: {fd} vs {}", hp[k]);
            let fd =
                (range_rate(&frame, &p, &(v + d), 2.0, &s).0 - range_rate(&frame, &p, &(v - d), 2.0, &s).0) / (2.0 * h);
            assert!((fd - hv[k]).abs() < 1e-9, "rate/v{k}");
            let hh = 1.0;
            let mut dp = Vector3::zeros();
            dp[k] = hh;
            let fd = (range_rate(&frame, &(p + dp), &v, 2.0, &s).0 - range_rate(&frame, &(p - dp), &v, 2.0, &s).0)
                / (2.0 * hh);
            assert!((fd - hp_rate[k]).abs() < 1e-9, "rate/p{k}: {fd} vs {}", hp_rate[k]);
        }
        // Clock terms enter with unit slope.
        assert!((pseudorange(&frame, &p, 101.0, &s).0 - pseudorange(&frame, &p, 100.0, &s).0 - 1.0).abs() < 1e-9);
        assert!((range_rate(&frame, &p, &v, 3.0, &s).0 - range_rate(&frame, &p, &v, 2.0, &s).0 - 1.0).abs() < 1e-12);
    }

    /// §8, eqs. L1–L2: the pseudorange and range-rate rows over
    /// `[δθ, δv, δp, δb_g, δb, δḃ, δisb_E,R,C]` for every constellation, with a 0.3 m lever arm turning at
    /// 1 rad/s, against central differences of the prediction.
    #[test]
    fn lever_arm_rows_match_finite_differences() {
        for system in [
            System::Gps,
            System::Galileo,
            System::Glonass,
            System::BeiDou,
            System::Qzss,
        ] {
            let (frame, s) = sat_of(system);
            let nom = GnssNominal {
                imu: state(),
                gyro_radps: Vector3::new(0.6, -0.5, 0.7),
                clock: ClockVec::from_column_slice(&[120.0, 3.0, 6.0, -4.0, 9.0]),
            };
            let lever = Vector3::new(0.2, -0.1, -0.2);
            let p = predict_sat(&frame, &nom, &lever, &s);
            for k in 0..GNSS_CLONE_DIM {
                // Steps of 1e-3 (rad, rad/s, m, m/s): the pseudorange is 2e7 m,
                // so smaller ones drown in round-off.
                let h = 1e-3;
                let mut d = [0.0; GNSS_CLONE_DIM];
                d[k] = h;
                let mut plus = nom;
                plus.correct(&d);
                d[k] = -h;
                let mut minus = nom;
                minus.correct(&d);
                let pp = predict_sat(&frame, &plus, &lever, &s);
                let pm = predict_sat(&frame, &minus, &lever, &s);
                let fd_pr = (pp.pseudorange_m - pm.pseudorange_m) / (2.0 * h);
                let fd_rate = (pp.range_rate_mps - pm.range_rate_mps) / (2.0 * h);
                assert!(
                    (fd_pr - p.h_pseudorange[k]).abs() < 2e-5,
                    "{system:?} pseudorange column {k}: fd {fd_pr} vs {}",
                    p.h_pseudorange[k]
                );
                assert!(
                    (fd_rate - p.h_range_rate[k]).abs() < 2e-5,
                    "{system:?} range-rate column {k}: fd {fd_rate} vs {}",
                    p.h_range_rate[k]
                );
            }
            // The lever arm matters: the antenna is not the body origin.
            let at_origin = predict_sat(&frame, &nom, &Vector3::zeros(), &s);
            assert!((at_origin.pseudorange_m - p.pseudorange_m).abs() > 0.01);
            assert!((at_origin.range_rate_mps - p.range_rate_mps).abs() > 0.01);
        }
    }

    /// §8c, eq. DG5′: the mapping `m(el)` of the zenith troposphere error
    /// (the row's `T_z` column; `gnss_update`'s test checks the columns
    /// against the filter's model), and the slope of `m(el(p)) T_z` with the
    /// position, which the row leaves out: below 1e-7 m/m at `T_z` = 0.15 m,
    /// far below the code's metre of noise.
    #[test]
    fn troposphere_mapping_and_its_left_out_slope() {
        for system in [System::Gps, System::Galileo, System::Glonass, System::BeiDou] {
            let (frame, s) = sat_of(system);
            let nom = GnssNominal {
                imu: state(),
                gyro_radps: Vector3::new(0.1, -0.2, 0.3),
                clock: ClockVec::from_column_slice(&[120.0, 3.0, 6.0, -4.0, 9.0]),
            };
            let lever = Vector3::new(0.2, -0.1, -0.2);
            let p = predict_sat(&frame, &nom, &lever, &s);
            let (b, t_z) = (0.4, 0.15);
            let code = |pred: &SatPrediction, b: f64, t_z: f64| pred.pseudorange_m + b + pred.tropo_map * t_z;
            let h = 1e-3;
            let fd_b = (code(&p, b + h, t_z) - code(&p, b - h, t_z)) / (2.0 * h);
            let fd_t = (code(&p, b, t_z + h) - code(&p, b, t_z - h)) / (2.0 * h);
            assert!((fd_b - 1.0).abs() < 1e-5, "{system:?} b column: {fd_b}");
            assert!(
                (fd_t - p.tropo_map).abs() < 1e-5,
                "{system:?} T_z column: {fd_t} vs {}",
                p.tropo_map
            );
            // The mapping is Saastamoinen's own ratio: 1 at zenith, 1/sin el
            // near it, larger low down.
            assert!(
                p.tropo_map >= 1.0 && p.tropo_map < 12.0,
                "{system:?} m = {}",
                p.tropo_map
            );
            // The left-out slope: m(el(p)) T_z moved by 10 m of position.
            for k in 0..3 {
                let mut d = [0.0; GNSS_CLONE_DIM];
                d[G_P + k] = 10.0;
                let mut plus = nom;
                plus.correct(&d);
                d[G_P + k] = -10.0;
                let mut minus = nom;
                minus.correct(&d);
                let slope = (predict_sat(&frame, &plus, &lever, &s).tropo_map
                    - predict_sat(&frame, &minus, &lever, &s).tropo_map)
                    * t_z
                    / 20.0;
                assert!(slope.abs() < 1e-7, "{system:?} ∂(m T_z)/∂p{k} = {slope}");
            }
        }
    }

    /// The range rate is the time derivative of the pseudorange, Sagnac term
    /// included (§8, K3): move the receiver along its velocity and the
    /// satellite along its own, and difference the predicted pseudoranges.
    #[test]
    fn range_rate_is_the_pseudoranges_derivative() {
        let (frame, s) = sat_of(System::Gps);
        let p = Vector3::new(120.0, -40.0, -8.0);
        let v = Vector3::new(14.0, 3.0, -0.5);
        let (rate, _, _) = range_rate(&frame, &p, &v, 0.0, &s);
        let h = 1e-3;
        let at = |dt: f64| {
            let mut sd = s;
            sd.r_sat_ecef_m += s.v_sat_ecef_mps * dt;
            // The satellite clock's own drift is in the rate only.
            pseudorange(&frame, &(p + v * dt), 0.0, &sd).0
        };
        let fd = (at(h) - at(-h)) / (2.0 * h) - s.ddts_mps;
        // The troposphere's change with elevation is not in the rate model
        // (below 1 mm/s at this geometry).
        assert!((fd - rate).abs() < 1e-3, "fd {fd} vs model {rate}");
    }
}
